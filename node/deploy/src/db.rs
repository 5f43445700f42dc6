//! EPICS database import: `record`/`grecord` of type motor, calcout (and calc), ao/ai (and
//! longout/longin, bo/bi, mbbo/mbbi) that only hold values, and dfanout, with `$(macro)`
//! substitution and link modifiers. Records become launch items on the key layout:
//!   motor `R`          → axis `R`, fields on `<prefix>/R/<FIELD>`
//!   calcout/calc `R`   → calc link `R`; its fields are `bridge/R/<FIELD>` (`A`…`L`, `VAL`)
//!   ao/ai/bo/... `R`   → value holder on `bridge/R/VAL` (a motor's own `_able` bo: none)
//!   dfanout `R`        → value holder on `bridge/R/VAL`, a calc link `R.OUTx` per output
//! A link `R.FIELD PP MS` becomes the key of R's field; PP/NPP/CP decide whether an update
//! recomputes a calc link. A forward link (FLNK) processes the record it names: a motor's
//! writes that record's PROC; into a calc, the calc is processed by the signal (`processed_by`);
//! one that would close a loop of processing is not followed. Motors with a hardware DTYP become simulated axes, with a
//! warning.

use crate::file::{
    default_readback_rate, read_text, AxisSection, CalcInput, CalcOption, CalcSection, DriverKind, InputLinkMode,
    LaunchError, LaunchFile, ValueSection,
};
use std::collections::BTreeMap;
use std::path::Path;
use zmotor_bridge::TRANSFORM_FIELDS;
use zmotor_msgs::{decode_scalar, keys, unmodelled_common_field, Field, Kind, PayloadEncoding};
use zmotor_msgs::{field_value, to_toml};

/// Macro definitions, `-m user=me,P=xxx:` as for dbLoadRecords.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Macros(BTreeMap<String, String>);

impl Macros {
    /// Parse `name=value` pairs separated by commas; later definitions win.
    pub fn parse(definitions: &[String]) -> Result<Self, MacroError> {
        let mut macros = BTreeMap::new();
        for pair in definitions.iter().flat_map(|d| d.split(',')).filter(|p| !p.trim().is_empty()) {
            let (name, value) = pair.split_once('=').ok_or_else(|| MacroError(pair.to_string()))?;
            macros.insert(name.trim().to_string(), value.trim().to_string());
        }
        Ok(Self(macros))
    }
}

impl From<BTreeMap<String, String>> for Macros {
    /// Definitions given one by one (a launch file's `macros = { DESC = "x, coarse" }`): a
    /// value is taken whole, commas and all.
    fn from(definitions: BTreeMap<String, String>) -> Self {
        Self(definitions)
    }
}

/// A macro definition that is not `name=value`.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("macro definition '{0}' is not name=value")]
#[non_exhaustive]
pub struct MacroError(pub String);

/// Import a database file whose motors are served under `prefix` (their links name their keys
/// there); the warnings say what was simulated or ignored.
pub fn import_db(path: &Path, macros: &Macros, prefix: &str) -> Result<(LaunchFile, Vec<String>), LaunchError> {
    let text = read_text(path)?;
    import_db_text(&path.display().to_string(), &text, macros, prefix)
}

/// Import a database's text, its motors served under `prefix`; errors name `file`.
pub fn import_db_text(
    file: &str,
    text: &str,
    macros: &Macros,
    prefix: &str,
) -> Result<(LaunchFile, Vec<String>), LaunchError> {
    import_text(text, macros, prefix).map_err(|failure| LaunchError {
        file: file.to_string(),
        line: Some(failure.line),
        message: failure.message,
    })
}

/// A database launched on its own has no controller: its asyn motors, each naming a port no
/// launch file defines, run as simulated axes, each with a warning (in a launch file's
/// `[[database]]` they run on its `[[controller]]`s, and a port it lacks is an error).
pub fn simulated_without_controllers(file: &mut LaunchFile) -> Vec<String> {
    let mut warnings = Vec::new();
    for axis in file.axes.iter_mut().filter(|a| a.driver == DriverKind::Controller) {
        let port = axis.controller.take().unwrap_or_default();
        axis.channel = None;
        axis.driver = DriverKind::Sim;
        warnings.push(format!(
            "motor '{}': DTYP 'asynMotor' on port '{port}', which no launch file defines here; it runs as a \
             simulated axis (a launch file's [[database]] runs it on its [[controller]] '{port}')",
            axis.name
        ));
    }
    warnings
}

/// What is wrong in a database, and on which line.
#[derive(Debug, PartialEq)]
pub(super) struct Failure {
    line: usize,
    message: String,
}

impl Failure {
    fn at(line: usize, message: impl Into<String>) -> Self {
        Self { line, message: message.into() }
    }
}

/// One record of the file (records of the same name are merged, as EPICS does).
#[derive(Debug)]
struct Record {
    kind: String,
    name: String,
    line: usize,
    /// (field, value, line), in file order.
    fields: Vec<(String, String, usize)>,
}

impl Record {
    fn field(&self, name: &str) -> Option<&(String, String, usize)> {
        self.fields.iter().rev().find(|(f, ..)| f == name)
    }
}

pub(super) fn import_text(
    text: &str,
    macros: &Macros,
    axis_prefix: &str,
) -> Result<(LaunchFile, Vec<String>), Failure> {
    let mut warnings = Vec::new();
    let records = parse(text, macros, &mut warnings)?;
    let kinds: BTreeMap<&str, &str> = records.iter().map(|r| (r.name.as_str(), r.kind.as_str())).collect();
    let linker = Linker { kinds: &kinds, axis_prefix };
    let mut launch = LaunchFile::default();
    // Writes into calc inputs from other records' output links: (calc, letter) → mode.
    let mut written_inputs: BTreeMap<(String, String), InputLinkMode> = BTreeMap::new();
    // Forward links of motors and value holders.
    let mut forward_links = Vec::new();
    // Each dfanout's calc links, one per output link, and each transform's, one per field it
    // computes or writes out: a record processed as one.
    let mut fanouts: BTreeMap<String, Vec<String>> = BTreeMap::new();
    // The fields each transform computes.
    let mut computed_fields: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for record in &records {
        // A motor's disabling is modelled; the records that become calc links and values are not.
        if RUN_KINDS.contains(&record.kind.as_str()) && record.kind != "motor" {
            warnings.extend(processing_disabled(record));
        }
        match record.kind.as_str() {
            "motor" => {
                launch.axes.push(motor(record, &linker, &mut warnings, &mut written_inputs, &mut forward_links)?)
            }
            "calcout" | "calc" => launch.calcs.push(calc(record, &linker, &mut warnings, &mut written_inputs)?),
            // motor.db's Enable/Disable record beside a motor of this database: served as its DISP.
            "bo" if is_motors_able(record, &kinds) => {}
            "ao" | "ai" | "longout" | "longin" | "bo" | "bi" | "mbbo" | "mbbi" => {
                launch.values.push(value_holder(record, &mut warnings, &mut forward_links)?)
            }
            "transform" => {
                if let Some((fields, computed)) = transform(record, &linker, &mut warnings, &mut written_inputs)? {
                    fanouts.insert(record.name.clone(), fields.iter().map(|c| c.name.clone()).collect());
                    computed_fields.insert(record.name.clone(), computed);
                    launch.calcs.extend(fields);
                }
            }
            "dfanout" => {
                if let Some((value, outputs)) = dfanout(record, &linker, &mut warnings, &mut written_inputs)? {
                    launch.values.push(value);
                    fanouts.insert(record.name.clone(), outputs.iter().map(|c| c.name.clone()).collect());
                    launch.calcs.extend(outputs);
                }
            }
            other => warnings.push(format!(
                "line {}: record '{}' of type {other} is not supported and was skipped",
                record.line, record.name
            )),
        }
    }
    for ((calc_name, letter), mode) in written_inputs {
        if computed_fields.get(&calc_name).is_some_and(|computed| computed.contains(&letter)) {
            // Its own key carries what the record computes: a write there (EPICS keeps it for
            // one processing, COPT Conditional, and a PP one processes the record) is neither.
            warnings.push(format!(
                "transform '{calc_name}': a write into {letter}, which it computes, is neither kept nor processes it \
                 (EPICS keeps it for the next processing, COPT Conditional); not modelled"
            ));
            continue;
        }
        // A calc's input, or a field of every calc link of a transform.
        let fields = fanouts.get(&calc_name).filter(|_| kinds.get(calc_name.as_str()) == Some(&"transform"));
        for calc in
            launch.calcs.iter_mut().filter(|c| c.name == calc_name || fields.is_some_and(|f| f.contains(&c.name)))
        {
            let key = keys::bridge_key(&calc_name, &letter);
            calc.inputs.entry(letter.clone()).or_insert(CalcInput::Linked { key, mode });
        }
    }
    let mut processing = Processing::of(&launch.axes, &launch.calcs);
    for link in forward_links {
        let forwarded = match processing.loop_through(&link.target, &link.from) {
            Some(records) => Forwarded::Ignored(format!(
                "line {}: record '{}': FLNK '{}' would close a loop of processing ({} → {}); EPICS ends one at \
                 the record already processing, zmotor would not: this forward link is not followed",
                link.line,
                link.from,
                link.target,
                link.from,
                records.join(" → ")
            )),
            None => forward_link(&mut launch.calcs, &kinds, &fanouts, &link),
        };
        match forwarded {
            Forwarded::Followed(said) => {
                processing.add(&link.from, &link.target);
                warnings.extend(said);
            }
            Forwarded::Ignored(why) => {
                if let Some(axis) = launch.axes.iter_mut().find(|a| a.name == link.from) {
                    axis.fields.remove("FLNK");
                }
                warnings.push(why);
            }
        }
    }
    Ok((launch, warnings))
}

/// The record a record's FLNK names (its last FLNK; the field a link names does not matter to
/// a forward link), and the line; none for an empty or constant one.
fn forward_target(record: &Record) -> Option<(String, usize)> {
    let (_, text, line) = record.field("FLNK")?;
    let target = text.split_whitespace().next()?;
    let target = target.split_once('.').map_or(target, |(record, _)| record);
    (target.parse::<f64>().is_err()).then(|| (target.to_string(), *line))
}

/// Which record's processing makes which other's: the forward links followed so far, each
/// motor into the records its output links write (OUT, STOO, RLNK: RLNK at every processing),
/// each calc into the record its output writes, and each record a calc follows CP or is
/// processed by into the calc. (A motor's input links are left out: it posts a value only when
/// it changes, so a loop through one settles.)
struct Processing {
    next: BTreeMap<String, Vec<String>>,
}

impl Processing {
    fn of(axes: &[AxisSection], calcs: &[CalcSection]) -> Self {
        let mut processing = Self { next: BTreeMap::new() };
        let record = |key: &str| key.rsplit('/').nth(1).map(str::to_string);
        for axis in axes {
            for field in [Field::OUT, Field::STOO, Field::RLNK] {
                if let Some(written) = axis.fields.get(field.name()).and_then(|k| k.as_str()).and_then(record) {
                    processing.add(&axis.name, &written);
                }
            }
        }
        for calc in calcs {
            if let Some(written) = record(&calc.output) {
                processing.add(&calc.name, &written);
            }
            for input in calc.inputs.values() {
                let followed = match input {
                    CalcInput::Key(key) | CalcInput::Linked { key, mode: InputLinkMode::Cp } => record(key),
                    CalcInput::Linked { mode: InputLinkMode::Npp, .. } => None,
                };
                if let Some(followed) = followed {
                    processing.add(&followed, &calc.name);
                }
            }
            for key in &calc.processed_by {
                if let Some(writer) = record(key) {
                    processing.add(&writer, &calc.name);
                }
            }
        }
        processing
    }

    fn add(&mut self, from: &str, to: &str) {
        self.next.entry(from.to_string()).or_default().push(to.to_string());
    }

    /// The records from `start` on whose processing leads to `end`'s, if any does.
    fn loop_through(&self, start: &str, end: &str) -> Option<Vec<String>> {
        let mut paths = vec![vec![start.to_string()]];
        let mut seen = std::collections::BTreeSet::new();
        while let Some(path) = paths.pop() {
            let at = path.last().expect("a path has a record");
            if at == end {
                return Some(path);
            }
            if !seen.insert(at.clone()) {
                continue;
            }
            for next in self.next.get(at).into_iter().flatten() {
                paths.push([path.clone(), vec![next.clone()]].concat());
            }
        }
        None
    }
}

/// A record's FLNK: the record it names is processed after this one.
struct ForwardLink {
    /// The record whose FLNK it is.
    from: String,
    /// What kind of record that is.
    source: Source,
    /// The record it processes.
    target: String,
    line: usize,
    /// What tells the node that `from` processed: a motor writes 1 to the target's PROC key at
    /// each processing that ends with DMOV = 1; a value holder is processed by each write of
    /// its key.
    signal: String,
}

/// Whose forward link it is.
#[derive(Clone, Copy, PartialEq)]
enum Source {
    /// A motor's: it writes 1 to the target's PROC, which processes a motor too.
    Motor,
    /// A value holder's: processed by each write of its value, it writes nothing itself.
    Value,
}

/// What became of a forward link.
enum Forwarded {
    /// Followed; what was made of it, where that needs saying.
    Followed(Option<String>),
    /// Not followed, and why.
    Ignored(String),
}

/// A forward link into a calc: the calc is processed at each update of the link's signal, not
/// on the value it finds at start (`processed_by`), said in the warnings. Into a motor (a write
/// of 1 to its PROC), nothing to say; into anything else it is not modelled, and said so.
fn forward_link(
    calcs: &mut [CalcSection],
    kinds: &BTreeMap<&str, &str>,
    fanouts: &BTreeMap<String, Vec<String>>,
    link: &ForwardLink,
) -> Forwarded {
    let ForwardLink { from, source, target, line, signal } = link;
    let whose = format!("line {line}: record '{from}': FLNK '{target}'");
    if let Some(outputs) = fanouts.get(target) {
        // A dfanout or a transform: its calc links are processed together.
        if outputs.is_empty() {
            return Forwarded::Ignored(format!("{whose}: '{target}' writes nothing here; ignored"));
        }
        for calc in calcs.iter_mut().filter(|c| outputs.contains(&c.name) && !c.processed_by.contains(signal)) {
            calc.processed_by.push(signal.clone());
        }
        let what = match kinds.get(target.as_str()) {
            Some(&"transform") => "computes its fields",
            _ => "writes its value out",
        };
        return Forwarded::Followed(Some(format!(
            "{whose}: '{target}' {what} at each write of {signal} (processed_by)"
        )));
    }
    let Some(calc) = calcs.iter_mut().find(|c| c.name == *target) else {
        // A motor's write of its target's PROC processes a motor, here or elsewhere.
        return match kinds.get(target.as_str()) {
            Some(&"motor") | None if *source == Source::Motor => Forwarded::Followed(None),
            Some(kind) => Forwarded::Ignored(format!(
                "{whose}: processing {kind} '{target}' by a forward link is not modelled; ignored"
            )),
            None => Forwarded::Ignored(format!("{whose}: no such record in this database; ignored")),
        };
    };
    if !calc.processed_by.contains(signal) {
        calc.processed_by.push(signal.clone());
    }
    Forwarded::Followed(Some(format!("{whose}: '{target}' is processed at each write of {signal} (processed_by)")))
}

/// The fields that disable a record's processing: a motor's are modelled, other records'
/// (calc links and values) are not, and `processing_disabled` says so where they would act.
const DISABLING_FIELDS: &[&str] = &["SDIS", "DISA", "DISV", "DISS"];

/// What a database says of disabling the processing of a record that is not a motor (SDIS,
/// DISA, DISV), which zmotor does not model for it: an interlock wired that way would not hold,
/// so the import says so.
fn processing_disabled(record: &Record) -> Option<String> {
    let set = |name: &str| record.field(name).map(|(_, text, line)| (text.trim(), *line));
    let number = |name: &str, default: f64| set(name).and_then(|(text, _)| text.parse::<f64>().ok()).unwrap_or(default);
    let whose = format!("{} '{}'", record.kind, record.name);
    match set("SDIS") {
        Some((link, line)) if !link.is_empty() && link.parse::<f64>().is_err() => Some(format!(
            "line {line}: {whose}: SDIS '{link}' disables its processing when it reads DISV; zmotor does not model \
             that but for motors: the record processes whatever the link holds"
        )),
        // A constant SDIS sets nothing (dbConstLink reads no value).
        _ => {
            let disa = number("DISA", 0.0);
            let line = set("DISA").or(set("DISV")).map_or(record.line, |(_, line)| line);
            (disa == number("DISV", 1.0)).then(|| {
                format!(
                    "line {line}: {whose}: DISA = DISV disables its processing; zmotor does not model that but \
                     for motors: the record processes"
                )
            })
        }
    }
}

/// The record types an import runs: motors as axes, calcs as calc links, a dfanout as a value
/// and a calc link per output, a transform as a calc link per field it computes or writes out,
/// the rest as values (a binary or multi-bit record's value is its state's number).
const RUN_KINDS: &[&str] =
    &["motor", "calcout", "calc", "ao", "ai", "longout", "longin", "bo", "bi", "mbbo", "mbbi", "dfanout", "transform"];

/// Whether a bo is motor.db's Enable/Disable record of a motor of the database (`<motor>_able`,
/// its OUT writing the motor's DISP), which zmotor serves as that DISP.
fn is_motors_able(record: &Record, kinds: &BTreeMap<&str, &str>) -> bool {
    let Some(motor) = record.name.strip_suffix("_able") else { return false };
    let writes_disp = record.fields.iter().any(|(name, text, _)| {
        name == "OUT" && text.split_whitespace().next() == Some(format!("{motor}.DISP").as_str())
    });
    writes_disp && kinds.get(motor) == Some(&"motor")
}

/// Link modifiers of EPICS database links.
const MODIFIERS: &[&str] = &["PP", "NPP", "CP", "CPP", "MS", "NMS", "MSS", "MSI", "CA"];

/// What an EPICS link field holds.
#[derive(Debug, PartialEq)]
enum Link {
    None,
    Constant(f64),
    /// A hardware address (`#C0 S0 @`, `@asyn(...)`): meaningless on a simulated axis.
    Hardware,
    Key {
        key: String,
        record: String,
        field: String,
        process: bool,
        continuous: bool,
    },
}

struct Linker<'a> {
    kinds: &'a BTreeMap<&'a str, &'a str>,
    /// Where the motors are served (`[zenoh] prefix`): a link to one names its key there.
    axis_prefix: &'a str,
}

impl Linker<'_> {
    fn link(&self, text: &str, line: usize, warnings: &mut Vec<String>) -> Result<Link, Failure> {
        let text = text.trim();
        if text.is_empty() {
            return Ok(Link::None);
        }
        if text.starts_with(['#', '@']) {
            return Ok(Link::Hardware);
        }
        if let Ok(x) = text.parse::<f64>() {
            return Ok(Link::Constant(x));
        }
        let mut words = text.split_whitespace();
        let target = words.next().unwrap_or_default();
        let modifiers: Vec<&str> = words.collect();
        if let Some(bad) = modifiers.iter().find(|m| !MODIFIERS.contains(m)) {
            return Err(Failure::at(
                line,
                format!("link '{text}': '{bad}' is not a link modifier (known: {})", MODIFIERS.join(" ")),
            ));
        }
        let (record, field) = target.split_once('.').unwrap_or((target, "VAL"));
        let prefix = match self.kinds.get(record) {
            Some(&"motor") => self.axis_prefix,
            Some(kind) if !RUN_KINDS.contains(kind) => {
                warnings.push(format!(
                    "line {line}: link '{text}': record '{record}' is a {kind}, which zmotor does not run: nothing \
                     serves {}/{record}/{field}",
                    keys::BRIDGE_PREFIX
                ));
                keys::BRIDGE_PREFIX
            }
            Some(_) => keys::BRIDGE_PREFIX,
            None => {
                warnings.push(format!(
                    "line {line}: link '{text}': record '{record}' is not in this database; taken as an axis elsewhere"
                ));
                self.axis_prefix
            }
        };
        Ok(Link::Key {
            key: format!("{prefix}/{record}/{field}"),
            record: record.to_string(),
            field: field.to_string(),
            process: modifiers.iter().any(|m| matches!(*m, "PP" | "CP" | "CPP")),
            continuous: modifiers.iter().any(|m| matches!(*m, "CP" | "CPP")),
        })
    }
}

fn motor(
    record: &Record,
    linker: &Linker,
    warnings: &mut Vec<String>,
    written_inputs: &mut BTreeMap<(String, String), InputLinkMode>,
    forward_links: &mut Vec<ForwardLink>,
) -> Result<AxisSection, Failure> {
    let dtyp = record.field("DTYP").map(|(_, v, _)| v.as_str()).unwrap_or("");
    let soft = dtyp == "Soft Channel";
    let on_controller = match record.field("OUT") {
        Some((_, out, line)) if dtyp == "asynMotor" => Some(asyn_address(out).ok_or_else(|| {
            Failure::at(*line, format!("motor '{}': OUT '{out}' is not @asyn(PORT,AXIS)", record.name))
        })?),
        _ => None,
    };
    if !soft && on_controller.is_none() {
        warnings.push(format!(
            "line {}: motor '{}': DTYP '{dtyp}' is hardware zmotor cannot drive; it runs as a simulated axis",
            record.line, record.name
        ));
    }
    let mut fields = BTreeMap::new();
    // Each field's last value and its line: what the record starts with (a later field() wins).
    let mut last = BTreeMap::new();
    for (name, text, line) in &record.fields {
        let at = |message: String| Failure::at(*line, format!("motor '{}': field {name}: {message}", record.name));
        if name == "DTYP" || unmodelled_common_field(name).is_some() {
            continue;
        }
        let field = Field::from_name(name)
            .filter(|f| f.name() == name)
            .ok_or_else(|| at("not a field of the motor record".into()))?;
        if field == Field::FLNK {
            continue;
        }
        // A launch file refuses them: a database's are dropped, with a word.
        if field.is_command() || field.starts_at_readback() {
            warnings.push(format!(
                "line {line}: motor '{}': field {name} commands the record (or is where it starts, its \
                 readback), not a setting; ignored",
                record.name
            ));
            continue;
        }
        // motor.db's SDIS reads the motor's own Enable/Disable record, whose OUT writes DISP:
        // zmotor serves that record as DISP (`_able`), which refuses puts while the motor is
        // disabled; its processing is not disabled as well.
        let own_able = format!("{}_able", record.name);
        if field == Field::SDIS
            && text.split_whitespace().next().is_some_and(|t| t.split('.').next() == Some(&own_able))
        {
            continue;
        }
        let value = match field.def().kind {
            Kind::Link => match linker.link(text, *line, warnings)? {
                // A constant is no value to read (a constant SDIS sets nothing, as dbConstLink).
                Link::None | Link::Constant(_) => continue,
                Link::Hardware if !soft => continue,
                Link::Hardware => return Err(at(format!("'{text}' is a hardware address, not a link"))),
                Link::Key { key, record: target, field: target_field, process, .. } => {
                    if field.is_output_link() {
                        note_calc_write(linker, &target, &target_field, process, written_inputs);
                    }
                    toml::Value::String(key)
                }
            },
            Kind::Str(_) => toml::Value::String(text.clone()),
            _ if text.trim().is_empty() => continue,
            _ => to_toml(decode_scalar(text.as_bytes(), PayloadEncoding::Text).map_err(|e| at(e.detail))?),
        };
        // Checked as the launch checks it, here where the error can name the database's line: a
        // value the field cannot hold at once (as an IOC's dbLoadRecords), one the record
        // cannot start with once the last value is known.
        let checked =
            field_value(field, &value).map_err(|e| Failure::at(*line, format!("motor '{}': {e}", record.name)))?;
        last.insert(field, (checked, *line));
        fields.insert(name.clone(), value);
    }
    for (field, (value, line)) in &last {
        if let Some(why) = zmotor_core::Unusable::of(*field, value) {
            return Err(Failure::at(*line, format!("motor '{}': field {}: {why}", record.name, field.name())));
        }
    }
    // A forward link processes the record it names, whatever field it says: the motor writes 1
    // to that record's PROC (to its VAL, it would move a motor to 1). Kept or not once every
    // record is known (`forward_links`).
    if let Some((target, line)) = forward_target(record) {
        if let Link::Key { key, .. } = linker.link(&target, line, warnings)? {
            let record_key = key.rsplit_once('/').map_or(key.as_str(), |(record, _)| record);
            let signal = format!("{record_key}/{}", Field::PROC.name());
            fields.insert("FLNK".to_string(), toml::Value::String(signal.clone()));
            forward_links.push(ForwardLink { from: record.name.clone(), source: Source::Motor, target, line, signal });
        }
    }
    let driver = match (&on_controller, soft) {
        (Some(_), _) => DriverKind::Controller,
        (None, true) => DriverKind::Soft,
        (None, false) => DriverKind::Sim,
    };
    let (controller, channel) = on_controller.unzip();
    Ok(AxisSection {
        name: record.name.clone(),
        host: None,
        driver,
        controller,
        channel,
        jog_hold: Default::default(),
        readback_rate: default_readback_rate(),
        fields,
        sim: Default::default(),
        origin: Default::default(),
    })
}

/// The port and axis of an asyn motor address, `@asyn(PORT,AXIS[,timeout])`: the port is the
/// name of a `[[controller]]` of the launch that loads the database.
fn asyn_address(out: &str) -> Option<(String, usize)> {
    let inside = out.trim().strip_prefix("@asyn(")?.strip_suffix(')')?;
    let mut parts = inside.split(',').map(str::trim);
    let port = parts.next().filter(|p| !p.is_empty())?;
    let axis = parts.next()?.parse().ok()?;
    Some((port.to_string(), axis))
}

/// An output link into a calc record's input A–L, or a transform's field A–P, feeds that input
/// (PP: and processes the record).
fn note_calc_write(
    linker: &Linker,
    record: &str,
    field: &str,
    process: bool,
    written_inputs: &mut BTreeMap<(String, String), InputLinkMode>,
) {
    let letters = match linker.kinds.get(record) {
        Some(&"calcout") | Some(&"calc") => zmotor_bridge::INPUTS,
        Some(&"transform") => TRANSFORM_FIELDS,
        _ => 0,
    };
    if zmotor_bridge::input_index(field).is_some_and(|index| index < letters) {
        written_inputs.insert(
            (record.to_string(), field.to_string()),
            if process { InputLinkMode::Cp } else { InputLinkMode::Npp },
        );
    }
}

fn calc(
    record: &Record,
    linker: &Linker,
    warnings: &mut Vec<String>,
    written_inputs: &mut BTreeMap<(String, String), InputLinkMode>,
) -> Result<CalcSection, Failure> {
    let mut section = CalcSection {
        name: record.name.clone(),
        host: None,
        expression: String::new(),
        inputs: BTreeMap::new(),
        constants: BTreeMap::new(),
        output: keys::bridge_key(&record.name, "VAL"),
        option: CalcOption::default(),
        processed_by: Vec::new(),
        origin: Default::default(),
    };
    for (name, text, line) in &record.fields {
        let at =
            |message: String| Failure::at(*line, format!("{} '{}': field {name}: {message}", record.kind, record.name));
        // A calc record's inputs are A–L (a transform's go on to P).
        let calc_letter = |letter: &str| zmotor_bridge::input_index(letter).filter(|&i| i < zmotor_bridge::INPUTS);
        let input = name.strip_prefix("INP").filter(|l| calc_letter(l).is_some());
        match name.as_str() {
            "CALC" => section.expression = text.clone(),
            "OUT" => match linker.link(text, *line, warnings)? {
                Link::Key { key, record: target, field, process, .. } => {
                    note_calc_write(linker, &target, &field, process, written_inputs);
                    section.output = key;
                }
                Link::None => {}
                _ => return Err(at(format!("'{text}' is not a link to a record"))),
            },
            "OOPT" => {
                section.option = match text.as_str() {
                    "Every Time" => CalcOption::Every,
                    "On Change" => CalcOption::OnChange,
                    other => {
                        warnings.push(format!(
                            "line {line}: {} '{}': OOPT '{other}' is not supported; writing every time",
                            record.kind, record.name
                        ));
                        CalcOption::Every
                    }
                }
            }
            "DOPT" if text != "Use CALC" => warnings.push(format!(
                "line {line}: {} '{}': DOPT '{text}' is not supported; the CALC result is written",
                record.kind, record.name
            )),
            _ if input.is_some() => {
                let letter = input.unwrap_or_default().to_string();
                match linker.link(text, *line, warnings)? {
                    Link::None => {}
                    Link::Constant(x) => {
                        section.constants.insert(letter, x);
                    }
                    Link::Key { key, continuous, .. } => {
                        let mode = if continuous { InputLinkMode::Cp } else { InputLinkMode::Npp };
                        section.inputs.insert(letter, CalcInput::Linked { key, mode });
                    }
                    Link::Hardware => return Err(at(format!("'{text}' is not a link to a record"))),
                }
            }
            _ if calc_letter(name).is_some() => {
                let x = text.trim().parse::<f64>().map_err(|_| at(format!("'{text}' is not a number")))?;
                section.constants.insert(name.clone(), x);
            }
            "DESC" | "PREC" | "EGU" | "HOPR" | "LOPR" | "DOPT" => {}
            _ if unmodelled_common_field(name).is_some() || DISABLING_FIELDS.contains(&name.as_str()) => {}
            _ => warnings.push(format!(
                "line {line}: {} '{}': field {name} is not used by zmotor and was ignored",
                record.kind, record.name
            )),
        }
    }
    if section.expression.is_empty() {
        return Err(Failure::at(record.line, format!("{} '{}': no CALC expression", record.kind, record.name)));
    }
    Ok(section)
}

fn value_holder(
    record: &Record,
    warnings: &mut Vec<String>,
    forward_links: &mut Vec<ForwardLink>,
) -> Result<ValueSection, Failure> {
    let mut value = 0.0;
    for (name, text, line) in &record.fields {
        let number = text.trim().parse::<f64>();
        match name.as_str() {
            "VAL" => {
                value = number.map_err(|_| {
                    Failure::at(*line, format!("{} '{}': VAL '{text}' is not a number", record.kind, record.name))
                })?;
            }
            // A constant input link is the record's value, as EPICS reads it at initialisation.
            "DOL" | "INP" if number.is_ok() => value = number.unwrap_or(value),
            "DOL" | "OUT" | "INP" if !text.trim().is_empty() => warnings.push(format!(
                "line {line}: {} '{}': {name} '{text}' is ignored; the record only holds a value",
                record.kind, record.name
            )),
            _ => {}
        }
    }
    let section = ValueSection { name: record.name.clone(), host: None, key: None, value, origin: Default::default() };
    if let Some((target, line)) = forward_target(record) {
        // Processed at each write of its value.
        let source = Source::Value;
        forward_links.push(ForwardLink { from: record.name.clone(), source, target, line, signal: section.key() });
    }
    Ok(section)
}

/// A dfanout `R`: its value on `bridge/R/VAL`, and for each output link OUTA–OUTH a calc link
/// `R.OUTx` that writes each write of that value there, as the record writes VAL to every output
/// link each time it is processed (SELM All; a write of its VAL processes it; nothing is written
/// at start). Another selection (Specified, Mask: the outputs SELN picks) is not modelled: the
/// record is skipped, said in the warnings, rather than write where it would not.
fn dfanout(
    record: &Record,
    linker: &Linker,
    warnings: &mut Vec<String>,
    written_inputs: &mut BTreeMap<(String, String), InputLinkMode>,
) -> Result<Option<(ValueSection, Vec<CalcSection>)>, Failure> {
    let whose = format!("dfanout '{}'", record.name);
    if let Some((_, selm, line)) = record.field("SELM") {
        match selm.trim() {
            "" | "All" | "0" => {}
            "Specified" | "Mask" | "1" | "2" => {
                warnings.push(format!(
                    "line {line}: {whose}: SELM '{selm}' (the outputs SELN picks) is not modelled; the record was \
                     skipped"
                ));
                return Ok(None);
            }
            _ => return Err(Failure::at(*line, format!("{whose}: SELM '{selm}' is not one of All, Specified, Mask"))),
        }
    }
    let number = |(name, text, line): &(String, String, usize)| {
        text.trim().parse::<f64>().map_err(|_| Failure::at(*line, format!("{whose}: {name} '{text}' is not a number")))
    };
    for (name, _, line) in &record.fields {
        let read = matches!(name.as_str(), "VAL" | "DOL" | "SELM" | "FLNK")
            || matches!(name.as_bytes(), [b'O', b'U', b'T', b'A'..=b'H'])
            || matches!(name.as_str(), "OMSL" | "SELN" | "SELL" | "DESC" | "PREC" | "EGU" | "HOPR" | "LOPR")
            || unmodelled_common_field(name).is_some()
            || DISABLING_FIELDS.contains(&name.as_str());
        if !read {
            warnings.push(format!("line {line}: {whose}: field {name} is not used by zmotor and was ignored"));
        }
    }
    // VAL, or a constant DOL, as EPICS loads one at initialisation.
    let mut value = record.field("VAL").map(number).transpose()?.unwrap_or(0.0);
    match record.field("DOL") {
        Some(dol) if number(dol).is_ok() => value = number(dol)?,
        Some((_, dol, line)) if !dol.trim().is_empty() => warnings.push(format!(
            "line {line}: {whose}: DOL '{dol}' is not modelled and was ignored; a write of its VAL fans it out"
        )),
        _ => {}
    }
    if let Some((target, line)) = forward_target(record) {
        warnings.push(format!("line {line}: {whose}: FLNK '{target}' is not followed; ignored"));
    }
    let held = ValueSection { name: record.name.clone(), host: None, key: None, value, origin: Default::default() };
    let key = held.key();
    // Processed by a write of its VAL or its PROC (a motor's forward link into it writes there).
    let processed_by = vec![key.clone(), keys::bridge_key(&record.name, Field::PROC.name())];
    let mut outputs = Vec::new();
    for letter in ['A', 'B', 'C', 'D', 'E', 'F', 'G', 'H'] {
        let field = format!("OUT{letter}");
        let Some((_, text, line)) = record.field(&field) else { continue };
        let output = match linker.link(text, *line, warnings)? {
            // A constant output link writes nothing, as in EPICS.
            Link::None | Link::Constant(_) => continue,
            Link::Key { key, record: target, field: target_field, process, .. } => {
                note_calc_write(linker, &target, &target_field, process, written_inputs);
                key
            }
            Link::Hardware => {
                return Err(Failure::at(*line, format!("{whose}: field {field}: '{text}' is not a link to a record")))
            }
        };
        outputs.push(CalcSection {
            name: format!("{}.{field}", record.name),
            host: None,
            expression: "A".into(),
            inputs: BTreeMap::from([("A".into(), CalcInput::Linked { key: key.clone(), mode: InputLinkMode::Npp })]),
            constants: BTreeMap::new(),
            output,
            option: CalcOption::Every,
            processed_by: processed_by.clone(),
            origin: Default::default(),
        });
    }
    Ok(Some((held, outputs)))
}

/// A transform's calc links, and the letters of the fields it computes.
type TransformLinks = (Vec<CalcSection>, Vec<String>);

/// A transform record (synApps calc): sixteen fields A–P, each with an input link (INPx), an
/// expression (CLCx) and an output link (OUTx). At each processing its input links are read,
/// the fields with an expression and no input link are computed in order, A to P, each from the
/// fields as they stand (those computed before it already new), and every output link is
/// written. Here a calc link per field it computes or writes out, `R.X`, each the chain of the
/// fields computed before it (`F:=C+D;A+(B*D)/(E*F)`) over the record's input links and values,
/// writing to OUTX or else to the field's own key `bridge/R/X` (which a soft motor's RDBL reads);
/// all processed together, by its PROC, its CP inputs and the forward links into it. Not
/// modelled, and the record skipped with a word: an expression that reads a field computed
/// after it, or itself (the value of the last processing), and COPT Always on a field with an
/// input link and an expression. A value written into a field it computes is not kept as
/// EPICS's Conditional option keeps it: the next processing computes it.
fn transform(
    record: &Record,
    linker: &Linker,
    warnings: &mut Vec<String>,
    written_inputs: &mut BTreeMap<(String, String), InputLinkMode>,
) -> Result<Option<TransformLinks>, Failure> {
    let whose = format!("transform '{}'", record.name);
    let mut inputs: [Option<CalcInput>; TRANSFORM_FIELDS] = Default::default();
    let mut expressions: [String; TRANSFORM_FIELDS] = Default::default();
    let mut outputs: [Option<String>; TRANSFORM_FIELDS] = Default::default();
    let mut values = [0.0; TRANSFORM_FIELDS];
    let mut always = false;
    let letter_of = |name: &str, prefix: &str| {
        name.strip_prefix(prefix).and_then(zmotor_bridge::input_index).filter(|&i| i < TRANSFORM_FIELDS)
    };
    for (name, text, line) in &record.fields {
        let at = |message: String| Failure::at(*line, format!("{whose}: field {name}: {message}"));
        if let Some(index) = letter_of(name, "INP") {
            match linker.link(text, *line, warnings)? {
                Link::None => {}
                Link::Constant(x) => values[index] = x,
                Link::Key { key, continuous, .. } => {
                    let mode = if continuous { InputLinkMode::Cp } else { InputLinkMode::Npp };
                    inputs[index] = Some(CalcInput::Linked { key, mode });
                }
                Link::Hardware => return Err(at(format!("'{text}' is not a link to a record"))),
            }
        } else if let Some(index) = letter_of(name, "CLC") {
            expressions[index] = text.trim().to_string();
        } else if let Some(index) = letter_of(name, "OUT") {
            match linker.link(text, *line, warnings)? {
                Link::None | Link::Constant(_) => {}
                Link::Key { key, record: target, field, process, .. } => {
                    note_calc_write(linker, &target, &field, process, written_inputs);
                    outputs[index] = Some(key);
                }
                Link::Hardware => return Err(at(format!("'{text}' is not a link to a record"))),
            }
        } else if let Some(index) = letter_of(name, "") {
            values[index] = text.trim().parse::<f64>().map_err(|_| at(format!("'{text}' is not a number")))?;
        } else {
            match name.as_str() {
                "COPT" => {
                    always = match text.trim() {
                        "" | "Conditional" | "0" => false,
                        "Always" | "1" => true,
                        other => return Err(at(format!("'{other}' is not one of Conditional, Always"))),
                    }
                }
                "FLNK" if forward_target(record).is_some() => {
                    warnings.push(format!("line {line}: {whose}: FLNK '{text}' is not followed; ignored"));
                }
                "IVLA" | "DESC" | "PREC" | "EGU" | "FLNK" => {}
                _ if letter_of(name, "CMT").is_some() => {}
                _ if unmodelled_common_field(name).is_some() || DISABLING_FIELDS.contains(&name.as_str()) => {}
                _ => warnings.push(format!("line {line}: {whose}: field {name} is not used by zmotor and was ignored")),
            }
        }
    }
    let skipped = |why: String| format!("line {}: {whose}: {why}; not modelled, the record was skipped", record.line);
    let mut computed = [false; TRANSFORM_FIELDS];
    for index in 0..TRANSFORM_FIELDS {
        if expressions[index].is_empty() {
            continue;
        }
        let letter = zmotor_bridge::input_name(index);
        if inputs[index].is_some() {
            if always {
                warnings.push(skipped(format!("field {letter} has an input link and an expression under COPT Always")));
                return Ok(None);
            }
            // Conditional: a field with an input link takes the link's value; its expression is not used.
            continue;
        }
        // An expression that does not parse (sCalc's strings, a comment field's macros) leaves
        // the record uncomputed, as an IOC flags its CLC invalid.
        let expression = match zmotor_bridge::Expression::parse_over(&expressions[index], TRANSFORM_FIELDS) {
            Ok(expression) => expression,
            Err(e) => {
                warnings.push(skipped(format!("CLC{letter} '{}': {e}", expressions[index])));
                return Ok(None);
            }
        };
        if expressions[index].contains(';') || expressions[index].contains(":=") {
            warnings.push(skipped(format!("CLC{letter} has statements or assignments of its own")));
            return Ok(None);
        }
        let later = (index..TRANSFORM_FIELDS)
            .find(|&j| (expression.inputs_used() & (1 << j)) != 0 && !expressions[j].is_empty() && inputs[j].is_none());
        if let Some(later) = later {
            let what = if later == index {
                "itself".to_string()
            } else {
                format!("field {}", zmotor_bridge::input_name(later))
            };
            warnings.push(skipped(format!(
                "CLC{letter} reads {what}, computed after it (its value of the last processing)"
            )));
            return Ok(None);
        }
        computed[index] = true;
    }
    let mut fields = Vec::new();
    for index in 0..TRANSFORM_FIELDS {
        if !computed[index] && outputs[index].is_none() {
            continue;
        }
        let letter = zmotor_bridge::input_name(index);
        let mut chain: Vec<String> = (0..index)
            .filter(|&before| computed[before])
            .map(|before| format!("{}:=({})", zmotor_bridge::input_name(before), expressions[before]))
            .collect();
        chain.push(if computed[index] { expressions[index].clone() } else { letter.to_string() });
        let chain = chain.join(";");
        if let Err(e) = zmotor_bridge::Expression::parse_over(&chain, TRANSFORM_FIELDS) {
            warnings.push(skipped(format!("field {letter} chained with the fields before it: {e}")));
            return Ok(None);
        }
        let letters = || (0..TRANSFORM_FIELDS).map(|i| (i, zmotor_bridge::input_name(i).to_string()));
        fields.push(CalcSection {
            name: format!("{}.{letter}", record.name),
            host: None,
            expression: chain,
            inputs: letters().filter_map(|(i, l)| inputs[i].clone().map(|input| (l, input))).collect(),
            constants: letters()
                .filter(|&(i, _)| inputs[i].is_none() && values[i] != 0.0)
                .map(|(i, l)| (l, values[i]))
                .collect(),
            output: outputs[index].clone().unwrap_or_else(|| keys::bridge_key(&record.name, &letter.to_string())),
            option: CalcOption::Every,
            // Processed as one: by its PROC (a client's, a motor's forward link), and by the
            // forward links into it.
            processed_by: vec![keys::bridge_key(&record.name, Field::PROC.name())],
            origin: Default::default(),
        });
    }
    if fields.is_empty() {
        warnings.push(format!("line {}: {whose}: computes and writes nothing; skipped", record.line));
        return Ok(None);
    }
    let computed =
        (0..TRANSFORM_FIELDS).filter(|&i| computed[i]).map(|i| zmotor_bridge::input_name(i).to_string()).collect();
    Ok(Some((fields, computed)))
}

// ---- the file itself ----

/// Substitute `$(name)`, `${name}` and `$(name=default)`; an undefined macro is an error.
fn expand(line_text: &str, line: usize, macros: &Macros) -> Result<String, Failure> {
    let mut out = String::with_capacity(line_text.len());
    let mut rest = line_text;
    while let Some(start) = rest.find('$') {
        out.push_str(&rest[..start]);
        let after = &rest[start + 1..];
        let close = match after.chars().next() {
            Some('(') => ')',
            Some('{') => '}',
            _ => {
                out.push('$');
                rest = after;
                continue;
            }
        };
        let end = after
            .find(close)
            .ok_or_else(|| Failure::at(line, format!("unterminated macro in '{}'", line_text.trim())))?;
        let body = &after[1..end];
        let (name, default) = match body.split_once('=') {
            Some((name, default)) => (name, Some(default)),
            None => (body, None),
        };
        let value =
            macros.0.get(name).map(String::as_str).or(default).ok_or_else(|| {
                Failure::at(line, format!("macro $({name}) is not defined (give it with -m {name}=...)"))
            })?;
        out.push_str(value);
        rest = &after[end + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

#[derive(Clone, Debug, PartialEq)]
enum Token {
    Word(String),
    Quoted(String),
    Punct(char),
}

fn tokenize(text: &str, macros: &Macros, warnings: &mut Vec<String>) -> Result<Vec<(Token, usize)>, Failure> {
    let mut tokens = Vec::new();
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        if raw.trim_start().starts_with('#') {
            // A comment: its macros are not expanded (one it names need not be defined).
            continue;
        }
        let expanded = expand(raw, line, macros)?;
        let mut chars = expanded.chars().peekable();
        while let Some(c) = chars.next() {
            match c {
                '#' => break,
                c if c.is_whitespace() => {}
                '(' | ')' | '{' | '}' | ',' => tokens.push((Token::Punct(c), line)),
                // A table border left in a database copied from a document: not EPICS syntax.
                '|' => warnings.push(format!("line {line}: stray '|' ignored")),
                '"' => {
                    let mut s = String::new();
                    loop {
                        match chars.next() {
                            Some('"') => break,
                            Some('\\') => s.extend(chars.next()),
                            Some(c) => s.push(c),
                            None => return Err(Failure::at(line, "a quoted string is not closed on its line")),
                        }
                    }
                    tokens.push((Token::Quoted(s), line));
                }
                c if c.is_alphanumeric() || "_-+:.[]<>;".contains(c) => {
                    let mut word = String::from(c);
                    while let Some(&next) = chars.peek() {
                        if next.is_alphanumeric() || "_-+:.[]<>;".contains(next) {
                            word.push(next);
                            chars.next();
                        } else {
                            break;
                        }
                    }
                    tokens.push((Token::Word(word), line));
                }
                other => return Err(Failure::at(line, format!("unexpected character '{other}'"))),
            }
        }
    }
    Ok(tokens)
}

/// Parse the records of a database text.
fn parse(text: &str, macros: &Macros, warnings: &mut Vec<String>) -> Result<Vec<Record>, Failure> {
    let mut parser = Parser { tokens: tokenize(text, macros, warnings)?, at: 0 };
    let mut records: Vec<Record> = Vec::new();
    while let Some((token, line)) = parser.tokens.get(parser.at).cloned() {
        parser.at += 1;
        match token {
            Token::Word(w) if w == "record" || w == "grecord" => {
                let (kind, name) = parser.pair("record")?;
                let fields = if parser.peek() == Some(&Token::Punct('{')) {
                    parser.at += 1;
                    parser.body()?
                } else {
                    Vec::new()
                };
                match records.iter_mut().find(|r| r.name == name) {
                    Some(existing) if existing.kind == kind || kind == "*" => existing.fields.extend(fields),
                    Some(existing) => {
                        let message =
                            format!("record '{name}' is already a {} and cannot become a {kind}", existing.kind);
                        return Err(Failure::at(line, message));
                    }
                    None => records.push(Record { kind, name, line, fields }),
                }
            }
            Token::Word(w) if w == "alias" => {
                parser.pair("alias")?;
                warnings.push(format!("line {line}: alias ignored"));
            }
            other => {
                return Err(Failure::at(
                    line,
                    format!("expected record, grecord or alias, found {}", describe(&other)),
                ));
            }
        }
    }
    Ok(records)
}

struct Parser {
    tokens: Vec<(Token, usize)>,
    at: usize,
}

impl Parser {
    fn peek(&self) -> Option<&Token> {
        self.tokens.get(self.at).map(|(t, _)| t)
    }

    fn next(&mut self, what: &str) -> Result<(Token, usize), Failure> {
        let last_line = self.tokens.last().map_or(1, |(_, line)| *line);
        let token = self
            .tokens
            .get(self.at)
            .cloned()
            .ok_or_else(|| Failure::at(last_line, format!("the file ends where {what} should be")))?;
        self.at += 1;
        Ok(token)
    }

    fn expect(&mut self, c: char, what: &str) -> Result<(), Failure> {
        let (token, line) = self.next(&format!("'{c}'"))?;
        if token == Token::Punct(c) {
            Ok(())
        } else {
            Err(Failure::at(line, format!("{what}: expected '{c}', found {}", describe(&token))))
        }
    }

    fn text(&mut self, what: &str) -> Result<String, Failure> {
        match self.next("a name or a quoted string")? {
            (Token::Word(w) | Token::Quoted(w), _) => Ok(w),
            (other, line) => Err(Failure::at(
                line,
                format!("{what}: expected a name or a quoted string, found {}", describe(&other)),
            )),
        }
    }

    /// `( a , b )` as two strings.
    fn pair(&mut self, what: &str) -> Result<(String, String), Failure> {
        self.expect('(', what)?;
        let a = self.text(what)?;
        self.expect(',', what)?;
        let b = self.text(what)?;
        self.expect(')', what)?;
        Ok((a, b))
    }

    /// The fields of a record body, up to its closing brace.
    fn body(&mut self) -> Result<Vec<(String, String, usize)>, Failure> {
        let mut fields = Vec::new();
        loop {
            let (token, line) = self.next("'field' or '}'")?;
            match token {
                Token::Punct('}') => return Ok(fields),
                Token::Word(w) if w == "field" => {
                    let (name, value) = self.pair("field")?;
                    fields.push((name, value, line));
                }
                Token::Word(w) if w == "info" => {
                    self.pair("info")?;
                }
                Token::Word(w) if w == "alias" => {
                    self.expect('(', "alias")?;
                    self.text("alias")?;
                    self.expect(')', "alias")?;
                }
                other => {
                    return Err(Failure::at(line, format!("expected 'field' or '}}', found {}", describe(&other))))
                }
            }
        }
    }
}

fn describe(token: &Token) -> String {
    match token {
        Token::Word(w) => format!("'{w}'"),
        Token::Quoted(q) => format!("\"{q}\""),
        Token::Punct(c) => format!("'{c}'"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Launch;
    use zmotor_bridge::InputMode;
    use zmotor_core::DriverPlan;

    fn macros(text: &str) -> Macros {
        Macros::parse(&[text.to_string()]).unwrap()
    }

    fn import(text: &str) -> Result<(LaunchFile, Vec<String>), Failure> {
        import_text(text, &macros("user=me"), keys::DEFAULT_PREFIX)
    }

    const SEED: &str = include_str!("../../../launch/tangent-arm.db");

    #[test]
    fn the_seed_tangent_arm_becomes_two_axes_and_two_calc_links() {
        let (file, warnings) = import(SEED).unwrap();
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(warnings[0].contains("motor 'me:linear': DTYP 'OMS VME58' is hardware"), "{warnings:?}");
        let deployment = Launch::from_file("seed", file).unwrap().deployment(None).unwrap();
        let rotary = &deployment.contents.plans[0];
        assert_eq!((rotary.name.as_str(), &rotary.driver), ("me:rotary", &DriverPlan::Soft));
        let f = &rotary.fields;
        assert_eq!(f.out, "bridge/me:convertDriveValue/A");
        assert_eq!((f.rdbl.as_str(), f.stoo.as_str()), ("bridge/me:convertReadbackValue/VAL", "motor/me:linear/STOP"));
        assert_eq!(
            (f.dinp.as_str(), f.urip, f.mres, f.dhlm, f.egu.as_str()),
            ("motor/me:linear/DMOV", 1, 0.001, 45.0, "deg.")
        );
        let linear = &deployment.contents.plans[1];
        assert!(matches!(linear.driver, DriverPlan::Sim(_)));
        assert_eq!((linear.fields.velo, linear.fields.out.as_str()), (25.0, ""), "a hardware address is dropped");
        let drive = &deployment.contents.calcs[0];
        assert_eq!(
            (drive.output.as_str(), drive.inputs[0].key.as_str()),
            ("motor/me:linear/DVAL", "bridge/me:convertDriveValue/A")
        );
        assert_eq!(drive.inputs[0].mode, InputMode::Process, "rotary's OUT is PP: each write recomputes");
        let readback = &deployment.contents.calcs[1];
        assert_eq!(
            (readback.output.as_str(), readback.inputs[0].key.as_str()),
            ("bridge/me:convertReadbackValue/VAL", "motor/me:linear/DRBV")
        );
        assert_eq!(readback.inputs[0].mode, InputMode::Process, "INPA is CP");
    }

    #[test]
    fn a_copy_with_table_borders_still_loads() {
        let bordered = SEED.replace("}\n", "} | \n");
        let (file, warnings) = import(&bordered).unwrap();
        assert_eq!((file.axes.len(), file.calcs.len()), (2, 2));
        assert!(warnings.iter().any(|w| w.ends_with("stray '|' ignored")));
    }

    #[test]
    fn a_comment_line_may_name_a_macro_that_is_not_defined() {
        let text = "# built for $(IOC)\nrecord(motor, \"$(P)m1\") {\n # $(OLD) was here\n field(DESC, \"x\")\n}\n";
        let (file, _) = import_text(text, &macros("P=bl1:"), keys::DEFAULT_PREFIX).unwrap();
        assert_eq!(
            (file.axes[0].name.as_str(), &file.axes[0].fields["DESC"]),
            ("bl1:m1", &toml::Value::String("x".into()))
        );
    }

    #[test]
    fn macros_take_defaults_and_undefined_ones_are_errors_with_their_line() {
        let text = "\n\nrecord(motor, \"$(P)m$(N=1)\") {\n field(DESC, \"${P}\")\n}\n";
        let (file, _) = import_text(text, &macros("P=bl1:"), keys::DEFAULT_PREFIX).unwrap();
        assert_eq!(file.axes[0].name, "bl1:m1");
        assert_eq!(file.axes[0].fields["DESC"], toml::Value::String("bl1:".into()));
        assert_eq!(
            import_text(text, &Macros::default(), keys::DEFAULT_PREFIX).unwrap_err(),
            Failure::at(3, "macro $(P) is not defined (give it with -m P=...)")
        );
    }

    #[test]
    fn errors_name_the_line_and_the_field() {
        let bad_field = "record(motor, \"m1\") {\n  field(VELO, \"2\")\n  field(SPEED, \"3\")\n}";
        assert_eq!(
            import(bad_field).unwrap_err(),
            Failure::at(3, "motor 'm1': field SPEED: not a field of the motor record")
        );
        let bad_link = "record(motor, \"m1\") {\n field(DTYP, \"Soft Channel\")\n field(OUT, \"c.A PP XX\")\n}";
        assert!(import(bad_link).unwrap_err().message.contains("'XX' is not a link modifier"));
        assert_eq!(import("record(motor \"m1\")").unwrap_err(), Failure::at(1, "record: expected ',', found \"m1\""));
        assert_eq!(import("record(motor, \"m1\") {\n field(VELO, \"2\")\n").unwrap_err().line, 2);
        assert!(import("device(motor, VME_IO, x, \"y\")").unwrap_err().message.contains("found 'device'"));
        // A value the launch would refuse, refused at the database's line.
        let bad_value = "record(motor, \"m1\") {\n field(DTYP, \"Soft Channel\")\n\n field(VELO, \"fast\")\n}";
        assert_eq!(
            import(bad_value).unwrap_err(),
            Failure::at(4, "motor 'm1': VELO: wrong type: expected a number, got text 'fast'")
        );
        let infinite = bad_value.replace("fast", "1e999");
        assert_eq!(import(&infinite).unwrap_err().line, 4);
        let unusable = bad_value.replace("VELO, \"fast", "MRES, \"0");
        let error = import(&unusable).unwrap_err();
        assert_eq!(error.line, 4, "{error:?}");
        assert!(error.message.starts_with("motor 'm1': field MRES: a resolution of 0"), "{error:?}");
        // The record starts with a field's last value: an earlier one it would not start with is
        // no error.
        let overridden = unusable.replace("\n}", "\n field(MRES, \"0.001\")\n}");
        assert!(import(&overridden).is_ok(), "{:?}", import(&overridden));
    }

    #[test]
    fn records_of_the_same_name_merge_and_common_fields_are_ignored() {
        let text = "record(motor, m1) { field(VELO, 2) field(SCAN, \"Passive\") field(SDIS, \"m1_able\") }\n\
                    record(motor, m1) { field(VELO, 3) field(DISP, 1) }";
        let (file, _) = import(text).unwrap();
        assert_eq!(file.axes.len(), 1);
        assert_eq!(file.axes[0].fields["VELO"], toml::Value::Integer(3));
        // DISP (puts disabled) is modelled; SCAN is not; SDIS reads its own Enable/Disable
        // record, which is DISP.
        assert_eq!(file.axes[0].fields["DISP"], toml::Value::Integer(1));
        assert!(!file.axes[0].fields.contains_key("SCAN") && !file.axes[0].fields.contains_key("SDIS"));
        assert!(import("record(motor, m1) {}\nrecord(ai, m1) {}").unwrap_err().message.contains("already a motor"));
    }

    #[test]
    fn a_databases_commands_are_dropped_with_a_word() {
        let (file, warnings) =
            import("record(motor, m1) { field(HOMF, 1) field(SPMG, \"Stop\") field(VAL, 3) field(TWV, 2) }").unwrap();
        let fields: Vec<&str> = file.axes[0].fields.keys().map(String::as_str).collect();
        assert_eq!(fields, ["TWV"]);
        let dropped: Vec<&String> = warnings.iter().filter(|w| w.contains("not a setting; ignored")).collect();
        assert_eq!(dropped.len(), 3, "{warnings:?}");
    }

    #[test]
    fn a_record_whose_processing_the_database_disables_is_reported() {
        let warned = |text: &str| {
            let (_, warnings) = import(text).unwrap();
            warnings.into_iter().filter(|w| w.contains("disables its processing")).collect::<Vec<_>>()
        };
        let interlock = warned("record(calcout, c) {\n field(CALC, \"A\")\n field(SDIS, \"interlock.VAL NPP\")\n}");
        assert_eq!(interlock.len(), 1, "{interlock:?}");
        assert!(interlock[0].starts_with("line 3: calcout 'c': SDIS 'interlock.VAL NPP'"), "{interlock:?}");
        assert_eq!(warned("record(calcout, c) { field(CALC, \"A\") field(DISA, 1) }").len(), 1);
        assert_eq!(warned("record(ao, v) { field(DISV, 0) }").len(), 1, "DISA starts at 0");
        // Enabled as written (a constant SDIS reads nothing), or a motor (whose disabling is
        // modelled): nothing to say.
        for enabled in [
            "record(ao, v) { field(DISA, 0) field(DISV, 1) }",
            "record(ao, v) { field(SDIS, \"\") field(SCAN, \"Passive\") }",
            "record(ao, v) { field(SDIS, 1) }",
            "record(ao, v) { field(SDIS, 2) field(DISV, 2) }",
            "record(ao, v) { field(DISA, 1) field(DISV, 2) }",
            "record(motor, m1) { field(SDIS, \"interlock.VAL NPP\") field(DISA, 1) }",
        ] {
            assert_eq!(warned(enabled), Vec::<String>::new(), "{enabled}");
        }
        // A motor's: its fields, an SDIS link as its key; a constant SDIS sets nothing.
        let (file, _) =
            import("record(motor, m1) { field(SDIS, \"lab:interlock CP\") field(DISV, 0) field(DISS, \"MAJOR\") }")
                .unwrap();
        let fields = &file.axes[0].fields;
        assert_eq!(fields["SDIS"], toml::Value::String("motor/lab:interlock/VAL".into()));
        assert_eq!(
            (&fields["DISV"], &fields["DISS"]),
            (&toml::Value::Integer(0), &toml::Value::String("MAJOR".into()))
        );
        let (file, _) = import("record(motor, m1) { field(DISA, 0) field(SDIS, 1) }").unwrap();
        assert_eq!(file.axes[0].fields["DISA"], toml::Value::Integer(0), "a constant SDIS sets nothing");
        assert!(!file.axes[0].fields.contains_key("SDIS"));
        // motor.db's own Enable/Disable record: served as DISP, no link and nothing to say.
        let stock =
            "record(motor, m1) { field(SDIS, \"m1_able.VAL\") }\nrecord(bo, m1_able) { field(OUT, \"m1.DISP\") }";
        let (file, warnings) = import(stock).unwrap();
        assert!(file.values.is_empty(), "the _able bo is no value holder: {:?}", file.values);
        assert!(
            !file.axes[0].fields.contains_key("SDIS")
                && !warnings.iter().any(|w| w.contains("SDIS") || w.contains("m1_able.VAL")),
            "{warnings:?}"
        );
        // An interlock of a record type zmotor does not run: nothing serves it, said.
        let (file, warnings) =
            import("record(stringin, lock) {}\nrecord(motor, m1) { field(SDIS, \"lock CP\") }").unwrap();
        assert_eq!(file.axes[0].fields["SDIS"], toml::Value::String("bridge/lock/VAL".into()));
        assert!(
            warnings.iter().any(|w| w.contains("record 'lock' is a stringin, which zmotor does not run")),
            "{warnings:?}"
        );
        // A bi's is its value, held (0 or 1, written by anyone).
        let (file, warnings) = import("record(bi, lock) {}\nrecord(motor, m1) { field(SDIS, \"lock CP\") }").unwrap();
        assert_eq!(file.axes[0].fields["SDIS"], toml::Value::String("bridge/lock/VAL".into()));
        assert_eq!((file.values[0].name.as_str(), file.values[0].value), ("lock", 0.0));
        assert!(!warnings.iter().any(|w| w.contains("lock")), "{warnings:?}");
        // A bo's initial state is its constant DOL, as PINI sets it (softMotorTest.db's Done).
        let (file, _) = import("record(bo, done) { field(PINI, \"YES\") field(DOL, \"1\") }").unwrap();
        assert_eq!((file.values[0].name.as_str(), file.values[0].value), ("done", 1.0));
    }

    #[test]
    fn calc_constants_links_and_value_holders() {
        let text = r#"
            record(ao, "offset") { field(VAL, "2.5") field(DOL, "other.VAL") }
            record(calcout, "sum") {
                field(CALC, "A+B+C")
                field(INPA, "offset NPP")
                field(INPB, "1000")
                field(C, "7")
                field(OOPT, "On Change")
                field(OUT, "m1.VAL PP")
            }
            record(motor, "m1") { field(DTYP, "OMS VME58") field(OUT, "@C0 S0") }
            record(stringin, "note") {}
        "#;
        let (file, warnings) = import(text).unwrap();
        assert_eq!((file.values[0].key(), file.values[0].value), ("bridge/offset/VAL".to_string(), 2.5));
        let sum = &file.calcs[0];
        assert_eq!(sum.inputs["A"], CalcInput::Linked { key: "bridge/offset/VAL".into(), mode: InputLinkMode::Npp });
        assert_eq!((sum.constants["B"], sum.constants["C"]), (1000.0, 7.0));
        assert_eq!((sum.output.as_str(), sum.option), ("motor/m1/VAL", CalcOption::OnChange));
        assert!(warnings.iter().any(|w| w.contains("DOL 'other.VAL' is ignored")), "{warnings:?}");
        assert!(warnings.iter().any(|w| w.contains("type stringin is not supported")), "{warnings:?}");
        assert!(warnings.iter().any(|w| w.contains("DTYP 'OMS VME58'")), "{warnings:?}");
        Launch::from_file("db", file).unwrap();
    }

    #[test]
    fn a_value_holders_forward_link_processes_the_calc_it_names_on_each_write() {
        let text = r#"
            record(ao, "x") { field(FLNK, "double") }
            record(calcout, "double") { field(INPA, "x NPP") field(CALC, "A*2") field(OUT, "m1.VAL PP") }
            record(ao, "go") { field(FLNK, "sum.PROC") }
            record(ao, "b") {}
            record(calcout, "sum") { field(INPA, "b NPP") field(CALC, "A+C") field(C, "1") field(OUT, "m1.VAL PP") }
            record(ao, "lost") { field(FLNK, "m1.VAL") }
            record(ao, "gone") { field(FLNK, "nowhere") }
            record(motor, "m1") { field(DTYP, "Soft Channel") }
        "#;
        let (file, warnings) = import(text).unwrap();
        let calc = |name: &str| file.calcs.iter().find(|c| c.name == name).unwrap();
        // Processed by each write of the value; its inputs stay as they are.
        assert_eq!(calc("double").processed_by, ["bridge/x/VAL"]);
        assert_eq!(
            calc("double").inputs["A"],
            CalcInput::Linked { key: "bridge/x/VAL".into(), mode: InputLinkMode::Npp }
        );
        assert_eq!(calc("sum").processed_by, ["bridge/go/VAL"]);
        assert_eq!(calc("sum").inputs.len(), 1);
        let said = |part: &str| warnings.iter().any(|w| w.contains(part));
        assert!(said("record 'x': FLNK 'double': 'double' is processed at each write of bridge/x/VAL"), "{warnings:?}");
        assert!(
            said("record 'lost': FLNK 'm1': processing motor 'm1' by a forward link is not modelled; ignored"),
            "{warnings:?}"
        );
        assert!(said("record 'gone': FLNK 'nowhere': no such record in this database; ignored"));
        // As the node runs it: the value found at start is held; a write to `go` recomputes `sum`.
        let deployment = Launch::from_file("db", file).unwrap().deployment(None).unwrap();
        let spec = |name: &str| deployment.contents.calcs.iter().find(|c| c.name == name).unwrap().clone();
        let mut sum = zmotor_bridge::CalcLink::new(spec("sum")).unwrap();
        assert!(!sum.update("bridge/b/VAL", 4.0), "b is NPP");
        sum.processed_by("bridge/go/VAL", 1.0);
        assert_eq!(sum.process_with(&[]), Some(5.0), "the forward link's write processes it");
        let mut double = zmotor_bridge::CalcLink::new(spec("double")).unwrap();
        assert!(!double.update("bridge/x/VAL", 3.0), "x as found at start: nothing written");
        double.processed_by("bridge/x/VAL", 4.0);
        assert_eq!(double.process_with(&[]), Some(8.0), "a write of x, with its own value");
    }

    /// launch/sum-diff.db: motorApp's sumDiff2D.db records with two soft motors.
    const SUM_DIFF: &str = include_str!("../../../launch/sum-diff.db");

    #[test]
    fn a_transform_becomes_a_calc_link_per_field_it_computes_or_writes_out_processed_as_one() {
        let (file, warnings) = import(SUM_DIFF).unwrap();
        let refused = |w: &&String| w.contains("skipped") || w.contains("ignored") || w.contains("not modelled");
        assert!(!warnings.iter().any(|w| refused(&w)), "{warnings:?}");
        assert!(warnings
            .iter()
            .any(|w| w.contains("'tDrive' computes its fields at each write of bridge/sumDVAL/VAL")));
        let calc = |name: &str| file.calcs.iter().find(|c| c.name == name).unwrap_or_else(|| panic!("{name}"));
        let npp = |key: &str| CalcInput::Linked { key: key.into(), mode: InputLinkMode::Npp };
        let g = calc("tDrive.G");
        assert_eq!(g.expression, "F:=(C+D);A+(B*D)/(E*F)", "the fields computed before it, in order");
        assert_eq!((g.output.as_str(), g.inputs["A"].clone()), ("motor/m1/VAL", npp("motor/sum/DVAL")));
        assert_eq!(g.inputs["C"], npp("bridge/sumC1/VAL"));
        // Processed as one: by its PROC and by the forward links of the soft motors' DVAL records.
        for field in ["tDrive.F", "tDrive.G", "tDrive.H"] {
            assert_eq!(
                calc(field).processed_by,
                ["bridge/tDrive/PROC", "bridge/sumDVAL/VAL", "bridge/diffDVAL/VAL"],
                "{field}"
            );
        }
        assert_eq!(calc("tDrive.H").output, "motor/m2/VAL");
        // The readback: computed on the real motors' readbacks, each field on its own key, which
        // the soft motors' RDBL read.
        let readback = calc("tReadback.G");
        assert_eq!(readback.expression, "F:=(C+D);((A*C) + (B*D))/F");
        assert_eq!(readback.output, "bridge/tReadback/G");
        assert_eq!(readback.inputs["A"], CalcInput::Linked { key: "motor/m1/RBV".into(), mode: InputLinkMode::Cp });
        let sum = file.axes.iter().find(|a| a.name == "sum").unwrap();
        assert_eq!(sum.fields["RDBL"], toml::Value::String("bridge/tReadback/G".into()));
        // As the node runs them: the drive's G from the soft motors' dial values and the constants.
        let deployment = Launch::from_file("db", file.clone()).unwrap().deployment(None).unwrap();
        let spec = |name: &str| deployment.contents.calcs.iter().find(|c| c.name == name).unwrap().clone();
        let mut g = zmotor_bridge::CalcLink::new(spec("tDrive.G")).unwrap();
        g.processed_by("bridge/sumDVAL/VAL", 2.0);
        let read: Vec<(usize, f64)> = vec![(0, 2.0), (1, 1.0), (2, 1.0), (3, 1.0), (4, 1.0)];
        assert_eq!(g.process_with(&read), Some(2.5), "sum + diff * C2 / (E * (C1 + C2))");
        let mut h = zmotor_bridge::CalcLink::new(spec("tDrive.H")).unwrap();
        h.processed_by("bridge/tDrive/PROC", 1.0);
        assert_eq!(h.process_with(&read), Some(1.5));
    }

    #[test]
    fn coord_trans_2d_transforms_import_whole() {
        // The transforms of motorApp's coordTrans2D.db, as it writes them.
        let text = r#"
            record(transform, "tDrive") {
                field(INPA, "mx.DVAL NPP NMS") field(INPB, "my.DVAL NPP NMS") field(INPC, "mxC1.VAL NPP NMS")
                field(INPD, "myC1.VAL NPP NMS") field(INPE, "myC2.VAL NPP NMS")
                field(CLCF, "0.0174533 * E") field(CLCG, "C+A*COS(F)-B*SIN(F)") field(OUTG, "m1 PP MS")
                field(CLCH, "D+A*SIN(F)+B*COS(F)") field(OUTH, "m2 PP MS") }
            record(transform, "tsynch") {
                field(INPA, "m1 NPP NMS") field(INPB, "m2 NPP NMS") field(CLCC, "A") field(OUTC, "mxC1.VAL PP MS")
                field(CLCD, "B") field(OUTD, "myC1.VAL PP MS") }
            record(ao, "mxC1") {}
            record(ao, "myC1") {}
        "#;
        let (file, warnings) = import(text).unwrap();
        assert!(!warnings.iter().any(|w| w.contains("skipped") || w.contains("not modelled")), "{warnings:?}");
        let names: Vec<&str> = file.calcs.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(names, ["tDrive.F", "tDrive.G", "tDrive.H", "tsynch.C", "tsynch.D"]);
        assert_eq!(file.calcs[2].expression, "F:=(0.0174533 * E);G:=(C+A*COS(F)-B*SIN(F));D+A*SIN(F)+B*COS(F)");
        assert_eq!((file.calcs[3].expression.as_str(), file.calcs[3].output.as_str()), ("A", "bridge/mxC1/VAL"));
        Launch::from_file("db", file).unwrap().deployment(None).expect("the links parse and wire");
    }

    #[test]
    fn transforms_that_read_a_later_field_or_compute_an_input_under_always_are_skipped_with_a_word() {
        let (file, warnings) = import(
            r#"
            record(transform, "later") { field(CLCA, "B+1") field(CLCB, "2") }
            record(transform, "itself") { field(CLCA, "A+1") field(OUTA, "x.VAL PP") }
            record(transform, "always") { field(COPT, "Always") field(INPA, "x.VAL") field(CLCA, "A*2") }
            record(transform, "fine") { field(COPT, "Always") field(CLCA, "2") field(INPB, "x.VAL") field(OUTB, "y") }
            record(ao, "x") {}
            record(ao, "y") {}
            record(motor, "m1") { field(DTYP, "Soft Channel") field(OUT, "fine.C PP") }
            record(motor, "m2") { field(DTYP, "Soft Channel") field(OUT, "fine.A PP") }
        "#,
        )
        .unwrap();
        let said = |part: &str| warnings.iter().any(|w| w.contains(part));
        assert!(said("transform 'later': CLCA reads field B, computed after it"), "{warnings:?}");
        assert!(said("transform 'itself': CLCA reads itself"), "{warnings:?}");
        assert!(said("transform 'always': field A has an input link and an expression under COPT Always"));
        let names: Vec<&str> = file.calcs.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(names, ["fine.A", "fine.B"]);
        // A field with an input link and an output link passes its value on; a motor's output
        // link into a field processes the record.
        assert_eq!((file.calcs[1].expression.as_str(), file.calcs[1].output.as_str()), ("A:=(2);B", "bridge/y/VAL"));
        for calc in &file.calcs {
            assert_eq!(calc.inputs["C"], CalcInput::Linked { key: "bridge/fine/C".into(), mode: InputLinkMode::Cp });
            assert!(!calc.inputs.contains_key("A") && !calc.processed_by.contains(&"bridge/fine/A".to_string()));
        }
        assert!(said("transform 'fine': a write into A, which it computes, is neither kept nor processes it"));
        let (file, warnings) = import(
            r#"record(transform, "t") { field(CLCA, "1+") }
            record(transform, "u") { field(CLCA, "B:=2;B+1") field(CLCC, "B") }"#,
        )
        .unwrap();
        assert!(file.calcs.is_empty(), "{:?}", file.calcs);
        let said = |part: &str| warnings.iter().any(|w| w.contains(part));
        assert!(said("transform 't': CLCA '1+': column 3"), "{warnings:?}");
        assert!(said("transform 'u': CLCA has statements or assignments of its own"), "{warnings:?}");
    }

    /// The FLNK key an imported motor was given, if any.
    fn forward_link_of(file: &LaunchFile, axis: &str) -> Option<String> {
        let axis = file.axes.iter().find(|a| a.name == axis).unwrap();
        axis.fields.get("FLNK").map(|f| f.as_str().unwrap().to_string())
    }

    #[test]
    fn a_motors_forward_link_processes_the_record_it_names_and_never_writes_its_value() {
        let text = r#"
            record(motor, "m1") { field(DTYP, "Soft Channel") field(FLNK, "m2") }
            record(motor, "m2") { field(DTYP, "Soft Channel") field(FLNK, "after.VAL") }
            record(calcout, "after") { field(CALC, "A+1") field(INPA, "count NPP") field(OUT, "count PP") }
            record(ao, "count") {}
            record(motor, "m3") { field(DTYP, "Soft Channel") field(FLNK, "count") }
            record(motor, "m4") { field(DTYP, "Soft Channel") field(FLNK, "elsewhere") }
        "#;
        let (file, warnings) = import(text).unwrap();
        let flnk = |axis: &str| forward_link_of(&file, axis);
        // Processing a motor is a write of its PROC; its VAL would move it to 1.
        assert_eq!(flnk("m1").unwrap(), "motor/m2/PROC");
        assert_eq!(flnk("m4").unwrap(), "motor/elsewhere/PROC");
        // Into a calc: the calc is processed by each write of its PROC key.
        assert_eq!(flnk("m2").unwrap(), "bridge/after/PROC");
        let after = file.calcs.iter().find(|c| c.name == "after").unwrap();
        assert_eq!(after.processed_by, ["bridge/after/PROC"]);
        assert_eq!(after.inputs.len(), 1);
        let said = |part: &str| warnings.iter().any(|w| w.contains(part));
        assert!(
            said("record 'm2': FLNK 'after': 'after' is processed at each write of bridge/after/PROC"),
            "{warnings:?}"
        );
        assert_eq!(flnk("m3"), None, "into a value: nothing written");
        assert!(
            said("record 'm3': FLNK 'count': processing ao 'count' by a forward link is not modelled; ignored"),
            "{warnings:?}"
        );
        assert!(!said("FLNK 'm2'") && !said("FLNK 'elsewhere': "), "{warnings:?}");
        Launch::from_file("db", file).unwrap();
    }

    #[test]
    fn forward_links_that_would_loop_are_cut_and_only_a_records_last_flnk_counts() {
        let text = r#"
            record(motor, "m1") { field(DTYP, "Soft Channel") field(FLNK, "m2") }
            record(motor, "m2") { field(DTYP, "Soft Channel") field(FLNK, "m1.VAL") }
            record(motor, "self") { field(DTYP, "Soft Channel") field(FLNK, "self") }
            record(ao, "x") { field(FLNK, "bump") }
            record(calcout, "bump") { field(INPA, "x NPP") field(CALC, "A+1") field(OUT, "x PP") }
            record(motor, "m3") { field(DTYP, "Soft Channel") field(FLNK, "again") }
            record(calcout, "again") { field(INPA, "m3.RBV NPP") field(CALC, "A+1") field(OUT, "m3.VAL PP") }
            record(motor, "m4") { field(DTYP, "Soft Channel") field(FLNK, "m1") }
            record(motor, "m4") { field(FLNK, "m2") }
            record(motor, "m5") { field(DTYP, "Soft Channel") field(FLNK, "m1") }
            record(motor, "m5") { field(FLNK, "") }
            record(ao, "zero") { field(FLNK, "0") }
            record(motor, "m6") { field(DTYP, "Soft Channel") field(RLNK, "seen PP") }
            record(ao, "seen") { field(FLNK, "track") }
            record(calcout, "track") { field(INPA, "seen NPP") field(CALC, "A") field(OUT, "m6.VAL PP") }
        "#;
        let (file, warnings) = import(text).unwrap();
        let flnk = |axis: &str| forward_link_of(&file, axis);
        let said = |part: &str| warnings.iter().any(|w| w.contains(part));
        // m1 → m2 is followed; m2 → m1 would close the loop: EPICS stops at m1, still active.
        assert_eq!((flnk("m1").as_deref(), flnk("m2")), (Some("motor/m2/PROC"), None));
        assert!(said("record 'm2': FLNK 'm1' would close a loop of processing (m2 → m1 → m2)"), "{warnings:?}");
        assert_eq!(flnk("self"), None);
        assert!(said("record 'self': FLNK 'self' would close a loop of processing (self → self)"), "{warnings:?}");
        // Through a calc's output: the value it writes processes it again, and so would a move.
        let bump = file.calcs.iter().find(|c| c.name == "bump").unwrap();
        assert!(bump.processed_by.is_empty());
        assert!(said("record 'x': FLNK 'bump' would close a loop of processing (x → bump → x)"), "{warnings:?}");
        assert_eq!(flnk("m3"), None);
        assert!(said("record 'm3': FLNK 'again' would close a loop of processing (m3 → again → m3)"), "{warnings:?}");
        // A record's last FLNK is its forward link; an empty one is none, a constant one too.
        assert_eq!(flnk("m4").as_deref(), Some("motor/m2/PROC"));
        assert_eq!(flnk("m5"), None);
        assert!(!said("'zero'"), "{warnings:?}");
        // Through a motor's output link: RLNK writes at every processing, the calc moves it.
        assert!(
            said("record 'seen': FLNK 'track' would close a loop of processing (seen → track → m6 → seen)"),
            "{warnings:?}"
        );
        assert!(file.calcs.iter().find(|c| c.name == "track").unwrap().processed_by.is_empty());
        Launch::from_file("db", file).unwrap();
    }

    #[test]
    fn a_dfanout_writes_each_write_of_its_value_to_every_output_link() {
        let text = r#"
            record(motor, "soft") { field(DTYP, "Soft Channel") field(STOO, "stopall PP MS") }
            record(dfanout, "stopall") { field(VAL, "1") field(OUTA, "m1.STOP PP") field(OUTB, "m2.STOP PP") field(OUTC, "") }
            record(dfanout, "picky") { field(SELM, "Specified") field(SELN, "1") field(OUTA, "m1.VAL PP") }
            record(dfanout, "typo") { field(OUTI, "m1.VAL PP") }
            record(dfanout, "spread") { field(DOL, "0.5") field(OUTA, "sum.B PP") field(OUTB, "3") field(FLNK, "sum") }
            record(ao, "go") { field(FLNK, "spread") }
            record(calcout, "sum") { field(CALC, "A+B") field(OUT, "m1.VAL PP") }
            record(motor, "m1") { field(DTYP, "OMS VME58") }
            record(motor, "m2") { field(DTYP, "OMS VME58") }
        "#;
        let (file, warnings) = import(text).unwrap();
        let soft = file.axes.iter().find(|a| a.name == "soft").unwrap();
        assert_eq!(soft.fields["STOO"].as_str(), Some("bridge/stopall/VAL"));
        let value = |name: &str| file.values.iter().find(|v| v.name == name).map(|v| (v.key(), v.value));
        assert_eq!(value("stopall"), Some(("bridge/stopall/VAL".to_string(), 1.0)));
        assert_eq!(value("spread"), Some(("bridge/spread/VAL".to_string(), 0.5)), "a constant DOL is its value");
        let outputs: Vec<(&str, &str)> = file.calcs.iter().map(|c| (c.name.as_str(), c.output.as_str())).collect();
        assert_eq!(
            outputs,
            [
                ("stopall.OUTA", "motor/m1/STOP"),
                ("stopall.OUTB", "motor/m2/STOP"),
                ("spread.OUTA", "bridge/sum/B"),
                ("sum", "motor/m1/VAL")
            ],
            "a constant output link writes nothing"
        );
        let calc = |name: &str| file.calcs.iter().find(|c| c.name == name).unwrap();
        // Processed by writes of its value and PROC, and by a value's forward link into it.
        let processed = ["bridge/spread/VAL", "bridge/spread/PROC", "bridge/go/VAL"];
        assert_eq!(calc("spread.OUTA").processed_by, processed);
        // Its output into a calc's input, PP, is that input, CP.
        assert_eq!(calc("sum").inputs["B"], CalcInput::Linked { key: "bridge/sum/B".into(), mode: InputLinkMode::Cp });
        let said = |part: &str| warnings.iter().any(|w| w.contains(part));
        assert!(
            said("record 'go': FLNK 'spread': 'spread' writes its value out at each write of bridge/go/VAL"),
            "{warnings:?}"
        );
        assert!(
            said("dfanout 'picky': SELM 'Specified' (the outputs SELN picks) is not modelled; the record was skipped"),
            "{warnings:?}"
        );
        assert!(said("dfanout 'spread': FLNK 'sum' is not followed; ignored"), "{warnings:?}");
        assert!(said("dfanout 'typo': field OUTI is not used by zmotor and was ignored"), "{warnings:?}");
        let bad = import(r#"record(dfanout, "d") { field(SELM, "Some") }"#).unwrap_err();
        assert_eq!(bad, Failure::at(1, "dfanout 'd': SELM 'Some' is not one of All, Specified, Mask"));
        let bad = import(r#"record(dfanout, "d") { field(VAL, "x") }"#).unwrap_err();
        assert_eq!(bad, Failure::at(1, "dfanout 'd': VAL 'x' is not a number"));
        assert!(file.values.iter().all(|v| v.name != "picky"));
        // As the node runs it: the value found at start is not written out; each write is, and
        // a PROC writes the value held.
        let launch = Launch::from_file("db", file).unwrap();
        let deployment = launch.deployment(None).unwrap();
        assert_eq!(Launch::parse(&launch.to_toml()).unwrap().deployment(None).unwrap(), deployment, "converted");
        let mut out = zmotor_bridge::CalcLink::new(deployment.contents.calcs[0].clone()).unwrap();
        assert!(!out.update("bridge/stopall/VAL", 1.0));
        out.processed_by("bridge/stopall/VAL", 2.0);
        assert_eq!(out.process_with(&[]), Some(2.0));
        out.processed_by("bridge/stopall/PROC", 1.0);
        assert_eq!(out.process_with(&[]), Some(2.0));
    }

    #[test]
    fn asyn_motors_of_a_database_launched_alone_are_simulated_with_a_warning() {
        let text = r#"record(motor, "x") { field(DTYP, "asynMotor") field(OUT, "@asyn(MCB, 1, 1.0)") }"#;
        let (mut file, _) = import_text(text, &Macros::default(), keys::DEFAULT_PREFIX).unwrap();
        let warnings = simulated_without_controllers(&mut file);
        assert_eq!((file.axes[0].driver, file.axes[0].controller.as_deref()), (DriverKind::Sim, None));
        assert!(warnings[0].starts_with("motor 'x': DTYP 'asynMotor' on port 'MCB'"), "{warnings:?}");
        Launch::from_file("db", file).unwrap().deployment(None).unwrap();
    }

    #[test]
    fn asyn_motors_run_on_the_controller_their_port_names() {
        let macros = Macros::parse(&["P=bl1:".to_string()]).unwrap();
        let bad = "\nrecord(motor, \"$(P)bad\") { field(DTYP, \"asynMotor\") field(OUT, \"@asyn(MCB)\") }";
        let failure = import_text(bad, &macros, keys::DEFAULT_PREFIX).unwrap_err();
        assert_eq!(failure.line, 2);
        assert!(failure.message.contains("'@asyn(MCB)' is not @asyn(PORT,AXIS)"), "{}", failure.message);
        let good = r#"record(motor, "$(P)x") { field(DTYP, "asynMotor") field(OUT, "@asyn(MCB, 1, 1.0)") }"#;
        let (file, warnings) = import_text(good, &macros, keys::DEFAULT_PREFIX).unwrap();
        assert!(warnings.is_empty(), "an asyn motor is not simulated: {warnings:?}");
        let x = &file.axes[0];
        assert_eq!(x.name, "bl1:x");
        assert_eq!((x.driver, x.controller.as_deref(), x.channel), (DriverKind::Controller, Some("MCB"), Some(1)));
        // Alone, the database names a controller nobody defined.
        let alone = Launch::from_file("motors.db", file).unwrap_err();
        assert!(alone.message.contains("no [[controller]] 'MCB'"), "{alone}");
    }

    #[test]
    fn the_converted_toml_loads_to_the_same_deployment() {
        let (file, _) = import(SEED).unwrap();
        let launch = Launch::from_file("seed", file).unwrap();
        let again = Launch::parse(&launch.to_toml()).unwrap();
        assert_eq!(again.deployment(None).unwrap(), launch.deployment(None).unwrap());
    }
}
