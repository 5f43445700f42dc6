//! Launch files: a TOML description of a deployment (the Zenoh side, the axes, calc links and
//! value holders, autosave), possibly spread over included files and split between hosts.
//! Every value is checked before anything starts; an error names the file, the line and the key.
//! EPICS databases (`.db`) are imported into the same model (`db`).

mod db;
mod locate;

pub use db::{import_db, MacroError, Macros};

use locate::{line_of, Seg};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Duration;
use zmotor_bridge::link::{find_cycle, input_index, CalcLinkSpec, InputMode, InputSpec, OutputOption};
use zmotor_core::axis::{AxisPlan, DriverPlan, PollRates};
use zmotor_core::driver::sim::SimConfig;
use zmotor_msgs::toml_value::field_value;
use zmotor_msgs::{keys, Access, Field, Fields, KeyLayout, Kind, LinkKeyError, Value};
use zmotor_zenoh::{Mode, ValueSpec, ZenohConfig};

/// Highest readback rate while moving, Hz.
pub const MAX_READBACK_RATE: f64 = 1000.0;

/// A launch file that cannot be used: where, and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}{}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
pub struct LaunchError {
    /// The file at fault.
    pub file: String,
    /// The line, when it is known.
    pub line: Option<usize>,
    /// What is wrong, naming the key.
    pub message: String,
}

/// The text of a launch or database file; an error names the file.
fn read_text(path: &Path) -> Result<String, LaunchError> {
    std::fs::read_to_string(path).map_err(|e| LaunchError {
        file: path.display().to_string(),
        line: None,
        message: format!("cannot read: {e}"),
    })
}

/// One launch file as written. Only the main file may configure the Zenoh side, the state
/// directory and autosave; included files add hosts, axes, calc links and value holders.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LaunchFile {
    /// Further launch files, relative to this one.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub include: Vec<String>,
    /// Where autosave keeps state (relative to this file); `ZMOTOR_STATE_DIR` overrides it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub state_dir: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    /// Autosave settings.
    pub autosave: Option<AutosaveSection>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    /// How the processes join the network.
    pub zenoh: Option<ZenohConfig>,
    /// Per-host overrides of `[zenoh]`; with hosts, every item names the host that runs it.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub hosts: BTreeMap<String, HostSection>,
    #[serde(default, rename = "axis", skip_serializing_if = "Vec::is_empty")]
    /// The axes (`[[axis]]`).
    pub axes: Vec<AxisSection>,
    #[serde(default, rename = "calc", skip_serializing_if = "Vec::is_empty")]
    /// The calc links (`[[calc]]`).
    pub calcs: Vec<CalcSection>,
    #[serde(default, rename = "value", skip_serializing_if = "Vec::is_empty")]
    /// The value holders (`[[value]]`).
    pub values: Vec<ValueSection>,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
/// The `[autosave]` section.
pub struct AutosaveSection {
    /// Whether axes are saved and restored.
    pub enabled: bool,
    /// Seconds a change may wait before it is written (changes meanwhile are written together).
    pub delay: f64,
}

impl Default for AutosaveSection {
    fn default() -> Self {
        Self { enabled: true, delay: 1.0 }
    }
}

/// What differs on one host: how it joins the network.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HostSection {
    /// The host's Zenoh mode, instead of `[zenoh]`'s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mode: Option<Mode>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    /// Endpoints the host listens on, instead of `[zenoh]`'s.
    pub listen: Option<Vec<String>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    /// Endpoints the host connects to, instead of `[zenoh]`'s.
    pub connect: Option<Vec<String>>,
}

/// Where an item was written: which file of the launch, and its index in that file's array.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Origin {
    source: usize,
    index: usize,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
/// An `[[axis]]` entry.
pub struct AxisSection {
    /// The axis's name: its key chunk.
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    /// The host that runs it (with `[hosts]`).
    pub host: Option<String>,
    /// `sim` (the simulator) or `soft` (Soft Channel: the axis drives other keys).
    #[serde(default)]
    pub driver: DriverKind,
    /// Readback publications per second while moving.
    #[serde(default = "default_readback_rate")]
    pub readback_rate: f64,
    /// Initial field values, by EPICS field name.
    #[serde(default)]
    pub fields: BTreeMap<String, toml::Value>,
    #[serde(default, skip_serializing_if = "is_default")]
    /// The simulator's mechanics (`driver = "sim"`).
    pub sim: SimConfig,
    #[serde(skip)]
    /// Where it was written.
    pub origin: Origin,
}

fn is_default<T: Default + PartialEq>(value: &T) -> bool {
    *value == T::default()
}

/// A name that is not one of a setting's choices.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct UnknownChoice(String);

/// Declares an enum of a launch file's named choices: serde reads and writes it by name
/// (ignoring case), and a name that is not a choice is refused with `$refusal`, in which
/// `{given}` is the name written and `{known}` the choices.
macro_rules! choices {
    ($(#[$meta:meta])* $name:ident, $refusal:literal { $($(#[$vmeta:meta])* $variant:ident = $text:literal),+ $(,)? }) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
        pub enum $name {
            $($(#[$vmeta])* $variant),+
        }

        impl $name {
            /// The name a launch file uses.
            pub fn name(self) -> &'static str {
                match self {
                    $($name::$variant => $text),+
                }
            }

            /// The choice named `given`.
            pub fn from_name(given: &str) -> Result<Self, UnknownChoice> {
                [$($name::$variant),+].into_iter().find(|choice| choice.name().eq_ignore_ascii_case(given)).ok_or_else(|| {
                    UnknownChoice(format!($refusal, given = given, known = [$($text),+].join(", ")))
                })
            }
        }

        impl Serialize for $name {
            fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
                serializer.serialize_str(self.name())
            }
        }

        impl<'de> Deserialize<'de> for $name {
            fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
                $name::from_name(&String::deserialize(deserializer)?).map_err(serde::de::Error::custom)
            }
        }
    };
}

choices!(
    /// What drives an axis.
    DriverKind, "'{given}' is not a known driver (known: {known})" {
        /// The physical simulator.
        #[default]
        Sim = "sim",
        /// Soft Channel: the axis drives other keys.
        Soft = "soft",
    }
);

choices!(
    /// When a calc link writes its output (the calcout's OOPT).
    CalcOption, "'{given}' is not one of {known}" {
        /// Every time it is computed.
        #[default]
        Every = "every",
        /// When the result changes.
        OnChange = "on_change",
    }
);

choices!(
    /// What an update of a calc input does (the EPICS link's CP/NPP).
    InputLinkMode, "'{given}' is not one of {known}" {
        /// Recompute and write on each update.
        #[default]
        Cp = "cp",
        /// Only keep the latest value.
        Npp = "npp",
    }
);

fn default_readback_rate() -> f64 {
    10.0
}

/// A calc link, shaped like a calcout record.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CalcSection {
    /// The calc link's name.
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    /// The host that runs it (with `[hosts]`).
    pub host: Option<String>,
    /// The CALC expression.
    pub expression: String,
    /// Inputs A–L: a key (CP: recompute on each update) or `{ key = "...", mode = "npp" }`.
    #[serde(default)]
    pub inputs: BTreeMap<String, CalcInput>,
    /// Values of inputs before any update, e.g. `{ B = 1000 }` (the record's fields A–L).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub constants: BTreeMap<String, f64>,
    /// Key the result is written to.
    pub output: String,
    /// `every` (write every time, the default) or `on_change`.
    #[serde(default)]
    pub option: CalcOption,
    #[serde(skip)]
    /// Where it was written.
    pub origin: Origin,
}

/// A calc input as written: a key (CP), or a key with its mode.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(untagged, try_from = "WrittenCalcInput")]
pub enum CalcInput {
    /// A key, CP.
    Key(String),
    /// A key and how its updates are taken.
    Linked {
        /// The key.
        key: String,
        /// cp or npp.
        mode: InputLinkMode,
    },
}

/// A calc input before its mode is checked, so that a mode that is not a choice is refused by
/// name rather than lost in "no variant matched".
#[derive(Deserialize)]
#[serde(untagged)]
enum WrittenCalcInput {
    Key(String),
    Linked { key: String, mode: String },
}

impl TryFrom<WrittenCalcInput> for CalcInput {
    type Error = UnknownChoice;

    fn try_from(written: WrittenCalcInput) -> Result<Self, UnknownChoice> {
        Ok(match written {
            WrittenCalcInput::Key(key) => CalcInput::Key(key),
            WrittenCalcInput::Linked { key, mode } => CalcInput::Linked { key, mode: InputLinkMode::from_name(&mode)? },
        })
    }
}

/// A value holder, like an EPICS ao/ai record that only holds a value: it keeps the latest
/// number written to its key and answers reads of it.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ValueSection {
    /// The value holder's name.
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    /// The host that runs it (with `[hosts]`).
    pub host: Option<String>,
    /// Its key; `bridge/<name>/VAL` when omitted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub key: Option<String>,
    /// The value before anything is written.
    #[serde(default)]
    pub value: f64,
    #[serde(skip)]
    /// Where it was written.
    pub origin: Origin,
}

impl ValueSection {
    /// Its key: `key`, or `bridge/<name>/VAL`.
    pub fn key(&self) -> String {
        self.key.clone().unwrap_or_else(|| format!("{}/{}/VAL", keys::BRIDGE_PREFIX, self.name))
    }
}

/// What one process runs: the Zenoh side for its host, and its part of the items.
#[derive(Clone, Debug, PartialEq)]
pub struct Deployment {
    /// How this process joins the network.
    pub zenoh: ZenohConfig,
    /// Its axes.
    pub plans: Vec<AxisPlan>,
    /// Its calc links.
    pub calcs: Vec<CalcLinkSpec>,
    /// Its value holders.
    pub values: Vec<ValueSpec>,
    /// The launch file's state directory, resolved against the file's directory.
    pub state_dir: Option<PathBuf>,
    /// Autosave settings.
    pub autosave: AutosaveSection,
}

/// A file that took part in a launch, kept to point errors at their line.
#[derive(Clone, Debug, PartialEq)]
struct Source {
    name: String,
    text: String,
}

/// A problem found while checking: where (file, path of keys) and what.
#[derive(Debug)]
struct Problem {
    source: usize,
    path: Vec<Seg>,
    message: String,
}

impl Problem {
    fn at(source: usize, path: Vec<Seg>, message: impl Into<String>) -> Self {
        Self { source, path, message: message.into() }
    }

    /// A problem of an item, at a key inside it.
    fn in_item(table: &str, origin: Origin, inner: &[&str], message: impl Into<String>) -> Self {
        let mut path = vec![Seg::Key(table.into()), Seg::Index(origin.index)];
        path.extend(inner.iter().map(|k| Seg::Key((*k).into())));
        Self::at(origin.source, path, message)
    }
}

/// A whole launch: the main file with its includes merged, checked.
#[derive(Clone, Debug, PartialEq)]
pub struct Launch {
    /// Every item, the includes merged in.
    pub file: LaunchFile,
    /// Directory relative paths of the main file are resolved against.
    base: PathBuf,
    sources: Vec<Source>,
}

impl Launch {
    /// Read and check a launch file and everything it includes.
    pub fn load(path: &Path) -> Result<Self, LaunchError> {
        let name = path.display().to_string();
        let text = read_text(path)?;
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Self::build(&name, &text, &base, std::fs::canonicalize(path).ok())
    }

    /// Check a launch file's text; includes are resolved against `base`.
    pub fn from_text(name: &str, text: &str, base: &Path) -> Result<Self, LaunchError> {
        Self::build(name, text, base, None)
    }

    /// `canonical`: the main file's own path, so that including it is found out.
    fn build(name: &str, text: &str, base: &Path, canonical: Option<PathBuf>) -> Result<Self, LaunchError> {
        let mut launch = Self { file: LaunchFile::default(), base: base.to_path_buf(), sources: Vec::new() };
        let main = launch.read_source(name, text)?;
        if let Some(zenoh) = main.zenoh.clone() {
            launch.file.zenoh = Some(zenoh);
        }
        launch.file.state_dir = main.state_dir.clone();
        launch.file.autosave = main.autosave.clone();
        let mut visited: BTreeSet<PathBuf> = canonical.into_iter().collect();
        launch.merge(main, base, &mut visited)?;
        launch.check().map_err(|p| launch.error(p))?;
        Ok(launch)
    }

    /// A launch built in memory (an imported database): checked like a file.
    pub fn from_file(name: &str, file: LaunchFile) -> Result<Self, LaunchError> {
        let text = toml::to_string(&file).unwrap_or_default();
        Self::from_text(name, &text, Path::new(""))
    }

    /// Check a launch file's text with no includes and no name (tests, examples).
    pub fn parse(text: &str) -> Result<Self, LaunchError> {
        Self::from_text("<launch>", text, Path::new(""))
    }

    fn read_source(&mut self, name: &str, text: &str) -> Result<LaunchFile, LaunchError> {
        self.sources.push(Source { name: name.to_string(), text: text.to_string() });
        toml::from_str(text).map_err(|e: toml::de::Error| LaunchError {
            file: name.to_string(),
            line: e.span().map(|span| locate::line_at(text, span.start)),
            message: e.message().trim().to_string(),
        })
    }

    /// Append a file's items (and, depth first, those of its includes).
    fn merge(&mut self, file: LaunchFile, dir: &Path, visited: &mut BTreeSet<PathBuf>) -> Result<(), LaunchError> {
        let source = self.sources.len() - 1;
        let origin = |index| Origin { source, index };
        self.file.hosts.extend(file.hosts);
        self.file.axes.extend(file.axes.into_iter().enumerate().map(|(i, a)| AxisSection { origin: origin(i), ..a }));
        self.file.calcs.extend(file.calcs.into_iter().enumerate().map(|(i, c)| CalcSection { origin: origin(i), ..c }));
        self.file
            .values
            .extend(file.values.into_iter().enumerate().map(|(i, v)| ValueSection { origin: origin(i), ..v }));
        for (index, include) in file.include.iter().enumerate() {
            let at = |message: String| {
                self.error(Problem::at(source, vec![Seg::Key("include".into()), Seg::Index(index)], message))
            };
            let path = dir.join(include);
            let canonical = std::fs::canonicalize(&path).map_err(|e| at(format!("{}: {e}", path.display())))?;
            if !visited.insert(canonical) {
                return Err(at(format!("{} is included twice (or includes itself)", path.display())));
            }
            let text = std::fs::read_to_string(&path).map_err(|e| at(format!("{}: {e}", path.display())))?;
            let included = self.read_source(&path.display().to_string(), &text)?;
            let included_source = self.sources.len() - 1;
            for (key, present) in [
                ("zenoh", included.zenoh.is_some()),
                ("state_dir", included.state_dir.is_some()),
                ("autosave", included.autosave.is_some()),
            ] {
                if present {
                    let message = format!("{key} may only be set in the main launch file");
                    return Err(self.error(Problem::at(included_source, vec![Seg::Key(key.into())], message)));
                }
            }
            let included_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
            self.merge(included, &included_dir, visited)?;
        }
        Ok(())
    }

    fn error(&self, problem: Problem) -> LaunchError {
        let source = &self.sources[problem.source];
        LaunchError { file: source.name.clone(), line: line_of(&source.text, &problem.path), message: problem.message }
    }

    /// The `[zenoh]` section, or its defaults.
    pub fn zenoh(&self) -> ZenohConfig {
        self.file.zenoh.clone().unwrap_or_default()
    }

    fn check(&self) -> Result<(), Problem> {
        let zenoh = self.zenoh();
        if let Some(autosave) = &self.file.autosave {
            if !(autosave.delay >= 0.0 && autosave.delay <= 3600.0) {
                let message = format!("autosave.delay: {} s is outside [0, 3600]", autosave.delay);
                return Err(Problem::at(0, keys_path(&["autosave", "delay"]), message));
            }
        }
        let items = self.items();
        let mut seen = BTreeMap::new();
        for (table, name, host, origin) in &items {
            if seen.insert((*table, *name), origin).is_some() {
                return Err(Problem::in_item(table, *origin, &["name"], format!("{table} '{name}' is defined twice")));
            }
            match host {
                Some(host) if !self.file.hosts.contains_key(*host) => {
                    let known = self.file.hosts.keys().cloned().collect::<Vec<_>>().join(", ");
                    let message =
                        format!("{table} '{name}': host '{host}' is not declared under [hosts] (known: {known})");
                    return Err(Problem::in_item(table, *origin, &["host"], message));
                }
                None if !self.file.hosts.is_empty() => {
                    let message = format!("{table} '{name}': names no host, and this launch declares hosts");
                    return Err(Problem::in_item(table, *origin, &["name"], message));
                }
                _ => {}
            }
        }
        let plans = self.file.axes.iter().map(AxisSection::plan).collect::<Result<Vec<_>, _>>()?;
        let calcs = self.file.calcs.iter().map(CalcSection::spec).collect::<Result<Vec<_>, _>>()?;
        for value in &self.file.values {
            keys::validate_plain_key(&value.key())
                .map_err(|e| Problem::in_item("value", value.origin, &["key"], e.to_string()))?;
            if !value.value.is_finite() {
                return Err(Problem::in_item("value", value.origin, &["value"], "must be a finite number"));
            }
        }
        let axis_origins: Vec<Origin> = self.file.axes.iter().map(|a| a.origin).collect();
        let calc_origins: Vec<Origin> = self.file.calcs.iter().map(|c| c.origin).collect();
        check_wiring(&KeyLayout::new(&zenoh.prefix), &plans, &axis_origins, &calcs, &calc_origins)
    }

    /// (table, name, host, origin) of every item.
    fn items(&self) -> Vec<(&'static str, &str, Option<&str>, Origin)> {
        let f = &self.file;
        let axes = f.axes.iter().map(|a| ("axis", a.name.as_str(), a.host.as_deref(), a.origin));
        let calcs = f.calcs.iter().map(|c| ("calc", c.name.as_str(), c.host.as_deref(), c.origin));
        let values = f.values.iter().map(|v| ("value", v.name.as_str(), v.host.as_deref(), v.origin));
        axes.chain(calcs).chain(values).collect()
    }

    /// The names of the hosts under `[hosts]`.
    pub fn hosts(&self) -> impl Iterator<Item = &str> {
        self.file.hosts.keys().map(String::as_str)
    }

    /// What the process for `host` runs (everything when `host` is None).
    pub fn deployment(&self, host: Option<&str>) -> Result<Deployment, LaunchError> {
        let mut zenoh = self.zenoh();
        if let Some(host) = host {
            let Some(section) = self.file.hosts.get(host) else {
                let known = self.hosts().collect::<Vec<_>>().join(", ");
                let message = if known.is_empty() {
                    format!("--host {host}: this launch declares no hosts")
                } else {
                    format!("--host {host}: no such host (known: {known})")
                };
                return Err(LaunchError { file: self.sources[0].name.clone(), line: None, message });
            };
            zenoh.mode = section.mode.unwrap_or(zenoh.mode);
            zenoh.listen = section.listen.clone().unwrap_or(zenoh.listen);
            zenoh.connect = section.connect.clone().unwrap_or(zenoh.connect);
        }
        let runs_here = |item_host: &Option<String>| host.is_none() || item_host.as_deref() == host;
        let plan = |a: &AxisSection| a.plan().map_err(|p| self.error(p));
        let spec = |c: &CalcSection| c.spec().map_err(|p| self.error(p));
        Ok(Deployment {
            zenoh,
            plans: self.file.axes.iter().filter(|a| runs_here(&a.host)).map(plan).collect::<Result<_, _>>()?,
            calcs: self.file.calcs.iter().filter(|c| runs_here(&c.host)).map(spec).collect::<Result<_, _>>()?,
            values: self
                .file
                .values
                .iter()
                .filter(|v| runs_here(&v.host))
                .map(|v| ValueSpec { key: v.key(), initial: v.value })
                .collect(),
            state_dir: self.file.state_dir.as_ref().map(|dir| self.base.join(dir)),
            autosave: self.file.autosave.clone().unwrap_or_default(),
        })
    }

    /// The launch as one TOML file (includes merged).
    pub fn to_toml(&self) -> String {
        toml::to_string(&self.file).expect("a checked launch serialises")
    }
}

fn keys_path(keys: &[&str]) -> Vec<Seg> {
    keys.iter().map(|k| Seg::Key((*k).into())).collect()
}

impl AxisSection {
    fn plan(&self) -> Result<AxisPlan, Problem> {
        let at = |inner: &[&str], message: String| {
            let key = inner.join(".");
            Problem::in_item("axis", self.origin, inner, format!("axis '{}': {key}: {message}", self.name))
        };
        keys::validate_axis_name(&self.name).map_err(|e| at(&["name"], e.to_string()))?;
        let driver = match self.driver {
            DriverKind::Sim => DriverPlan::Sim(self.sim.clone()),
            DriverKind::Soft => DriverPlan::Soft,
        };
        if !(self.readback_rate > 0.0 && self.readback_rate <= MAX_READBACK_RATE) {
            let message = format!("{} Hz is outside (0, {MAX_READBACK_RATE}]", self.readback_rate);
            return Err(at(&["readback_rate"], message));
        }
        let dtyp = if driver == DriverPlan::Soft { "Soft Channel" } else { "Sim Motor" };
        let mut fields = Fields { name: self.name.clone(), dtyp: dtyp.into(), ..Fields::default() };
        for (name, raw) in &self.fields {
            let inner = ["fields", name.as_str()];
            let field = Field::from_name(name).ok_or_else(|| {
                let hint = Field::from_name_any_case(name).map(|f| format!(" (field names are upper case: {f})"));
                at(&inner, format!("no such field{}", hint.unwrap_or_default()))
            })?;
            // Raw soft limits may be given, as in a database file; other read-only fields not.
            if field.def().access == Access::RO && !matches!(field, Field::RHLM | Field::RLLM) {
                return Err(at(&inner, "read-only, cannot be configured".into()));
            }
            fields.set(field, &field_value(field, raw).map_err(|e| at(&inner, e.to_string()))?);
        }
        let rates = PollRates { moving: Duration::from_secs_f64(1.0 / self.readback_rate), ..PollRates::default() };
        Ok(AxisPlan { name: self.name.clone(), fields, driver, rates })
    }
}

impl CalcSection {
    fn spec(&self) -> Result<CalcLinkSpec, Problem> {
        let at = |inner: &[&str], message: String| {
            let key = inner.join(".");
            Problem::in_item("calc", self.origin, inner, format!("calc '{}': {key}: {message}", self.name))
        };
        let option = match self.option {
            CalcOption::Every => OutputOption::EveryTime,
            CalcOption::OnChange => OutputOption::OnChange,
        };
        let mut inputs = Vec::new();
        for (letter, input) in &self.inputs {
            let inner = ["inputs", letter.as_str()];
            let index = input_index(letter).ok_or_else(|| at(&inner, "inputs are A to L".into()))?;
            let (key, mode) = match input {
                CalcInput::Key(key) => (key.clone(), InputMode::Process),
                CalcInput::Linked { key, mode: InputLinkMode::Cp } => (key.clone(), InputMode::Process),
                CalcInput::Linked { key, mode: InputLinkMode::Npp } => (key.clone(), InputMode::NoProcess),
            };
            keys::validate_plain_key(&key).map_err(|e| at(&inner, e.to_string()))?;
            inputs.push(InputSpec { index, key, mode });
        }
        let mut constants = Vec::new();
        for (letter, value) in &self.constants {
            let inner = ["constants", letter.as_str()];
            let index = input_index(letter).ok_or_else(|| at(&inner, "inputs are A to L".into()))?;
            if !value.is_finite() {
                return Err(at(&inner, "must be a finite number".into()));
            }
            constants.push((index, *value));
        }
        keys::validate_plain_key(&self.output).map_err(|e| at(&["output"], e.to_string()))?;
        let spec = CalcLinkSpec {
            name: self.name.clone(),
            expression: self.expression.clone(),
            inputs,
            constants,
            output: self.output.clone(),
            option,
        };
        zmotor_bridge::CalcLink::new(spec.clone())
            .map_err(|e| Problem::in_item("calc", self.origin, &["expression"], e.to_string()))?;
        Ok(spec)
    }
}

/// Refuse wiring that cannot work: calc links that feed themselves (a cycle of keys without a
/// motor in between), links to unknown fields, and writes to read-only fields. `axes` and `calcs`
/// are in the order of the launch's items, so each problem points at its item.
fn check_wiring(
    layout: &KeyLayout,
    axes: &[AxisPlan],
    axis_origins: &[Origin],
    calcs: &[CalcLinkSpec],
    calc_origins: &[Origin],
) -> Result<(), Problem> {
    if let Some(cycle) = find_cycle(calcs) {
        let first = calcs.iter().position(|c| c.name == cycle[0]).unwrap_or(0);
        let message = format!("calc links form a loop with no motor in between: {}", cycle.join(" → "));
        return Err(Problem::in_item("calc", calc_origins[first], &[], message));
    }
    // The calc links' keys were checked to be plain where they were read.
    for (calc, origin) in calcs.iter().zip(calc_origins) {
        let problem = |who: String, e: LinkKeyError| Problem::in_item("calc", *origin, &[], format!("{who}: {e}"));
        for input in &calc.inputs {
            let letter = zmotor_bridge::link::input_name(input.index);
            let who = format!("calc '{}' input {letter}", calc.name);
            layout.check_link(&input.key, false, None).map_err(|e| problem(who, e))?;
        }
        let who = format!("calc '{}' output", calc.name);
        layout.check_link(&calc.output, true, None).map_err(|e| problem(who, e))?;
    }
    for (axis, origin) in axes.iter().zip(axis_origins) {
        for field in Field::all().filter(|f| f.def().kind == Kind::Link) {
            let Value::Text(key) = axis.fields.get(field) else { continue };
            if key.is_empty() {
                continue;
            }
            match layout.check_link(&key, field.is_output_link(), Some(&axis.name)) {
                Ok(()) => {}
                Err(LinkKeyError::NotPlain(e)) => {
                    let inner = ["fields", field.name()];
                    let message = format!("axis '{}': fields.{field}: {e}", axis.name);
                    return Err(Problem::in_item("axis", *origin, &inner, message));
                }
                Err(e) => {
                    return Err(Problem::in_item("axis", *origin, &[], format!("axis '{}' {field}: {e}", axis.name)))
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const WIRING: &str = r#"
        [[axis]]
        name = "lin"
        [[axis]]
        name = "rot"
        driver = "soft"
        [axis.fields]
        OUT = "bridge/drive/A"
        RDBL = "bridge/readback"
        DINP = "motor/lin/DMOV"
        STOO = "motor/lin/STOP"
        URIP = "Yes"
        [[calc]]
        name = "drive"
        expression = "TAN(A/57.296)*1000"
        inputs = { A = "bridge/drive/A" }
        output = "motor/lin/DVAL"
        [[calc]]
        name = "readback"
        expression = "ATAN(A/1000)*57.296"
        inputs = { A = "motor/lin/DRBV" }
        output = "bridge/readback"
    "#;

    #[test]
    fn the_tangent_arm_wiring_is_accepted() {
        let deployment = Launch::parse(WIRING).unwrap().deployment(None).unwrap();
        assert_eq!(deployment.calcs[0].inputs[0].mode, InputMode::Process);
        assert_eq!(deployment.plans[1].driver, DriverPlan::Soft);
        assert_eq!(deployment.plans[1].fields.dtyp, "Soft Channel");
    }

    #[test]
    fn broken_wiring_is_refused_at_start() {
        let cycle = WIRING
            .replace(r#"inputs = { A = "motor/lin/DRBV" }"#, r#"inputs = { A = "motor/lin/DVAL" }"#)
            .replace(r#"output = "bridge/readback""#, r#"output = "bridge/drive/A""#);
        assert_eq!(
            Launch::parse(&cycle).unwrap_err().message,
            "calc links form a loop with no motor in between: drive → readback → drive"
        );
        let read_only = WIRING.replace(r#"output = "motor/lin/DVAL""#, r#"output = "motor/lin/RBV""#);
        assert_eq!(
            Launch::parse(&read_only).unwrap_err().message,
            "calc 'drive' output: motor/lin/RBV: RBV is read-only"
        );
        let unknown = WIRING.replace("motor/lin/DRBV", "motor/lin/DRBX");
        assert_eq!(
            Launch::parse(&unknown).unwrap_err().message,
            "calc 'readback' input A: motor/lin/DRBX: 'DRBX' is not a field of a motor"
        );
        let unknown_axis_link = WIRING.replace(r#"DINP = "motor/lin/DMOV""#, r#"DINP = "motor/lin/DONE""#);
        assert!(Launch::parse(&unknown_axis_link).unwrap_err().message.starts_with("axis 'rot' DINP: motor/lin/DONE"));
        let npp = WIRING.replace(
            r#"inputs = { A = "motor/lin/DRBV" }"#,
            r#"inputs = { A = { key = "motor/lin/DRBV", mode = "sometimes" } }"#,
        );
        assert!(Launch::parse(&npp).unwrap_err().message.contains("'sometimes' is not one of cp, npp"));
    }

    const GOOD: &str = r#"
        [zenoh]
        listen = ["tcp/127.0.0.1:7447"]
        [[axis]]
        name = "m1"
        readback_rate = 50
        [axis.fields]
        MRES = 0.001
        VELO = 10
        DIR = "Neg"
        EGU = "mm"
        [axis.sim]
        high_limit_switch = 105000
    "#;

    #[test]
    fn a_good_file_builds_its_axes() {
        let deployment = Launch::parse(GOOD).unwrap().deployment(None).unwrap();
        assert_eq!(deployment.zenoh.mode, Mode::Peer);
        assert!(!deployment.zenoh.multicast_scouting);
        let plans = deployment.plans;
        let f = &plans[0].fields;
        assert_eq!((f.mres, f.velo, f.dir, f.egu.as_str(), f.name.as_str()), (0.001, 10.0, 1, "mm", "m1"));
        assert!(matches!(&plans[0].driver, DriverPlan::Sim(sim) if sim.high_limit_switch == Some(105000.0)));
        assert_eq!(plans[0].rates.moving, Duration::from_millis(20));
    }

    #[test]
    fn errors_name_the_axis_and_key() {
        let bad = |text: &str| Launch::parse(text).unwrap_err().to_string();
        assert!(
            bad("[[axis]]\nname = \"m1\"\n[axis.fields]\nNOPE = 1").contains("axis 'm1': fields.NOPE: no such field")
        );
        assert!(bad("[[axis]]\nname = \"m1\"\n[axis.fields]\nRBV = 1").contains("fields.RBV: read-only"));
        assert!(bad("[[axis]]\nname = \"m1\"\n[axis.fields]\nDIR = \"Up\"").contains("'Up' is not a choice"));
        assert!(bad("[[axis]]\nname = \"m1\"\n[axis.fields]\nVELO = \"fast\"").contains("VELO: wrong type"));
        assert!(bad("[[axis]]\nname = \"m/1\"").contains("axis 'm/1': name"));
        assert!(bad("[[axis]]\nname = \"m1\"\ndriver = \"xps\"").contains("not a known driver"));
        assert!(bad("[[calc]]\nname = \"c\"\nexpression = \"A+\"\noutput = \"x\"")
            .contains("calc 'c': expression 'A+': column 3"));
        assert!(bad("[[calc]]\nname = \"c\"\nexpression = \"A\"\noutput = \"x\"\ninputs = { M = \"y\" }")
            .contains("inputs are A to L"));
        assert!(bad("[[calc]]\nname = \"c\"\nexpression = \"A\"\noutput = \"x/*\"").contains("not a plain key"));
        assert!(bad("[[axis]]\nname = \"m1\"\nreadback_rate = 5000").contains("readback_rate"));
        assert!(bad("[[axis]]\nname = \"m1\"\n[[axis]]\nname = \"m1\"").contains("defined twice"));
        assert!(bad("[zenoh]\nmode = \"server\"").contains("zenoh.mode"));
        assert!(bad("[[axis]]\nname = \"m1\"\nspeed = 3").contains("unknown field"));
        assert!(bad("[[axis]\nname = ").starts_with("<launch>:1: "));
    }

    #[test]
    fn errors_found_after_parsing_point_at_their_line() {
        let text = "[zenoh]\nprefix = \"motor\"\n\n[[axis]]\nname = \"m1\"\n\n[[axis]]\nname = \"m2\"\n[axis.fields]\nVELO = 2\nNOPE = 1\n";
        assert_eq!(Launch::parse(text).unwrap_err().to_string(), "<launch>:11: axis 'm2': fields.NOPE: no such field");
        let wiring = WIRING.replace(r#"output = "motor/lin/DVAL""#, r#"output = "motor/lin/RBV""#);
        let error = Launch::parse(&wiring).unwrap_err();
        assert_eq!(error.line, Some(WIRING.lines().position(|l| l.contains("name = \"drive\"")).unwrap()));
        let mode = Launch::parse("[zenoh]\nlisten = []\nmode = \"server\"").unwrap_err();
        assert_eq!(mode.to_string(), "<launch>:3: zenoh.mode: 'server' is not one of peer, client, router");
    }

    const HOSTS: &str = r#"
        [zenoh]
        connect = ["tcp/10.0.0.1:7447"]
        [hosts.optics]
        listen = ["tcp/10.0.0.2:7447"]
        [hosts.detector]
        mode = "client"
        [[axis]]
        name = "m1"
        host = "optics"
        [[axis]]
        name = "m2"
        host = "detector"
        [[calc]]
        name = "c"
        host = "detector"
        expression = "A*2"
        inputs = { A = "motor/m1/RBV" }
        output = "bridge/c/VAL"
    "#;

    #[test]
    fn each_host_starts_only_its_part() {
        let launch = Launch::parse(HOSTS).unwrap();
        let optics = launch.deployment(Some("optics")).unwrap();
        let names = |d: &Deployment| d.plans.iter().map(|p| p.name.clone()).collect::<Vec<_>>();
        assert_eq!((names(&optics), optics.calcs.len()), (vec!["m1".to_string()], 0));
        assert_eq!(optics.zenoh.listen, ["tcp/10.0.0.2:7447"]);
        assert_eq!(
            (optics.zenoh.mode.name(), optics.zenoh.connect.as_slice()),
            ("peer", &["tcp/10.0.0.1:7447".to_string()][..])
        );
        let detector = launch.deployment(Some("detector")).unwrap();
        assert_eq!(
            (names(&detector), detector.calcs.len(), detector.zenoh.mode.name()),
            (vec!["m2".to_string()], 1, "client")
        );
        assert_eq!(names(&launch.deployment(None).unwrap()), ["m1", "m2"], "no --host: everything in one process");
        assert_eq!(
            launch.deployment(Some("sample")).unwrap_err().message,
            "--host sample: no such host (known: detector, optics)"
        );
        let stray = HOSTS.replace("host = \"detector\"\n        [[calc]]", "[[calc]]");
        assert!(Launch::parse(&stray).unwrap_err().message.contains("axis 'm2': names no host"));
        let undeclared = HOSTS.replace("host = \"optics\"", "host = \"sample\"");
        let error = Launch::parse(&undeclared).unwrap_err();
        assert_eq!(error.message, "axis 'm1': host 'sample' is not declared under [hosts] (known: detector, optics)");
        assert_eq!(error.line, Some(10));
    }

    #[test]
    fn included_files_add_items_and_errors_name_the_included_file() {
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, text: &str| std::fs::write(dir.path().join(name), text).unwrap();
        write("main.toml", "include = [\"hutch/axes.toml\"]\n[[axis]]\nname = \"m0\"\n");
        std::fs::create_dir(dir.path().join("hutch")).unwrap();
        write("hutch/axes.toml", "include = [\"more.toml\"]\n[[axis]]\nname = \"m1\"\n");
        write("hutch/more.toml", "[[axis]]\nname = \"m2\"\n[axis.fields]\nVELO = \"fast\"\n");
        let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
        assert!(error.file.ends_with("hutch/more.toml"), "{error}");
        assert_eq!(error.line, Some(4));
        assert!(error.message.starts_with("axis 'm2': fields.VELO: "), "{error}");
        write("hutch/more.toml", "[[axis]]\nname = \"m2\"\n");
        let launch = Launch::load(&dir.path().join("main.toml")).unwrap();
        let names: Vec<String> = launch.deployment(None).unwrap().plans.into_iter().map(|p| p.name).collect();
        assert_eq!(names, ["m0", "m1", "m2"]);
        write("hutch/more.toml", "[zenoh]\nmode = \"client\"\n");
        let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
        assert_eq!((error.line, error.message.as_str()), (Some(1), "zenoh may only be set in the main launch file"));
        write("hutch/more.toml", "include = [\"../main.toml\"]\n");
        let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
        assert!(error.file.ends_with("more.toml") && error.message.contains("main.toml is included twice"), "{error}");
        write("hutch/more.toml", "include = [\"missing.toml\"]\n");
        let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
        assert!(error.file.ends_with("more.toml") && error.message.contains("missing.toml"), "{error}");
    }

    #[test]
    fn every_shipped_launch_file_loads() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../launch");
        let mut loaded = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                let launch = Launch::load(&path).unwrap_or_else(|e| panic!("{e}"));
                for host in launch.hosts().map(str::to_string).collect::<Vec<_>>() {
                    launch.deployment(Some(&host)).unwrap();
                }
                loaded += 1;
            }
        }
        assert!(loaded >= 4, "{loaded} launch files in {}", dir.display());
        let reference = Launch::load(&dir.join("reference.toml")).unwrap();
        let optics = reference.deployment(Some("optics")).unwrap();
        let names: Vec<&str> = optics.plans.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["m1", "slit_top", "slit_bottom"], "the included slits run on the optics host");
        let user = reference.deployment(Some("user")).unwrap();
        assert_eq!((user.calcs.len(), user.values.len(), user.zenoh.mode.name()), (1, 1, "client"));
    }

    #[test]
    fn state_dir_is_relative_to_the_launch_file() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("l.toml"), "state_dir = \"state\"\n[autosave]\ndelay = 0.2\n").unwrap();
        let deployment = Launch::load(&dir.path().join("l.toml")).unwrap().deployment(None).unwrap();
        assert_eq!(deployment.state_dir, Some(dir.path().join("state")));
        assert_eq!(deployment.autosave, AutosaveSection { enabled: true, delay: 0.2 });
        assert!(Launch::parse("[autosave]\ndelay = -1").unwrap_err().message.contains("autosave.delay"));
    }
}
