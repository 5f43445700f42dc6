//! Launch files: a TOML description of a deployment (the Zenoh side, the axes, calc links and
//! value holders, autosave), possibly spread over included files and split between hosts.
//! Every value is checked before anything starts; an error names the file, the line and the key.
//! EPICS databases (`.db`) are imported into the same model (`db`).

mod db;
mod locate;

pub use db::{import_db, import_db_text, MacroError, Macros};

use locate::{line_of, Seg};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Duration;
use zmotor_bridge::link::{find_cycle, input_index, CalcLinkSpec, InputMode, InputSpec, OutputOption};
use zmotor_controllers::spec::{self, ControllerSpec, SerialSettings, Transport};
use zmotor_controllers::{ControllerConfig, ProtocolKind, ProtocolOptions};
use zmotor_core::axis::{AxisPlan, DriverPlan, PollRates};
use zmotor_core::driver::sim::SimConfig;
use zmotor_core::service::JogHold;
use zmotor_msgs::toml_value::field_value;
use zmotor_msgs::{keys, Access, Field, Fields, KeyLayout, Kind, LinkKeyError, Value};
use zmotor_web::WebConfig;
use zmotor_zenoh::channel_access::CaConfig;
use zmotor_zenoh::{Mode, NodeContents, TlsConfig, ValueSpec, ZenohConfig};

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
    /// EPICS databases whose records join this launch (`[[database]]`); their asyn motors
    /// (`OUT "@asyn(PORT,N)"`) run on this launch's `[[controller]]` named PORT.
    #[serde(default, rename = "database", skip_serializing_if = "Vec::is_empty")]
    pub databases: Vec<DatabaseSection>,
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
    /// A web server of motor screens (`[web]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub web: Option<WebSection>,
    /// A Channel Access front-end serving the axes (`[channel_access]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channel_access: Option<ChannelAccessSection>,
    #[serde(default, rename = "controller", skip_serializing_if = "Vec::is_empty")]
    /// The motor controllers (`[[controller]]`).
    pub controllers: Vec<ControllerSection>,
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

/// The `[channel_access]` section: `zmotor ca` run by the launch (on its host, when given).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ChannelAccessSection {
    /// `<P>`, prepended to every channel name.
    pub pv_prefix: String,
    /// Address to serve on.
    pub address: std::net::IpAddr,
    /// Port of searches and circuits.
    pub port: u16,
    /// The host that runs it (with `[hosts]`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
}

impl Default for ChannelAccessSection {
    fn default() -> Self {
        let CaConfig { pv_prefix, address, port } = CaConfig::default();
        Self { pv_prefix, address, port, host: None }
    }
}

/// The `[web]` section: `zmotor web` run by the launch (on its host, when given).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct WebSection {
    /// The HTTP address.
    pub address: std::net::SocketAddr,
    /// The host that runs it (with `[hosts]`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
}

impl Default for WebSection {
    fn default() -> Self {
        Self { address: WebConfig::default().address, host: None }
    }
}

/// A `[[database]]` entry: an EPICS database loaded with its macros, as dbLoadRecords does.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DatabaseSection {
    /// The `.db` file, relative to this launch file.
    pub file: String,
    /// Macro definitions, e.g. `{ P = "bl1:" }`.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub macros: BTreeMap<String, String>,
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
    /// The host's TLS certificate and key, instead of `[zenoh.tls]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tls: Option<TlsConfig>,
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
    /// `sim` (the simulator), `soft` (Soft Channel: the axis drives other keys) or
    /// `controller` (a channel of a `[[controller]]`).
    #[serde(default)]
    pub driver: DriverKind,
    /// The controller (`driver = "controller"`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub controller: Option<String>,
    /// The controller's own number for the axis (`driver = "controller"`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channel: Option<usize>,
    /// Readback publications per second while moving.
    #[serde(default = "default_readback_rate")]
    pub readback_rate: f64,
    /// `required`: a jog is taken only under a hold (the jog deadman); `optional` (the default):
    /// a plain jog too, as the record takes it.
    #[serde(default, skip_serializing_if = "is_default")]
    pub jog_hold: JogHoldChoice,
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
        /// A channel of a motor controller.
        Controller = "controller",
    }
);

choices!(
    /// Whether an axis jogs only under a hold.
    JogHoldChoice, "'{given}' is not one of {known}" {
        /// A plain jog is taken too.
        #[default]
        Optional = "optional",
        /// A jog without a hold is refused.
        Required = "required",
    }
);

choices!(
    /// A serial line's parity.
    ParityChoice, "'{given}' is not a parity (known: {known})" {
        /// No parity bit.
        #[default]
        None = "none",
        /// Odd.
        Odd = "odd",
        /// Even.
        Even = "even",
    }
);

choices!(
    /// A serial line's flow control.
    FlowControlChoice, "'{given}' is not a flow control (known: {known})" {
        /// None.
        #[default]
        None = "none",
        /// XON/XOFF.
        Software = "software",
        /// RTS/CTS.
        Hardware = "hardware",
    }
);

/// A `[[controller]]` entry: a motor controller, how to reach it, how to poll it.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ControllerSection {
    /// The controller's name; its axes name it.
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    /// The host that runs it (with `[hosts]`); its axes run there too.
    pub host: Option<String>,
    /// The protocol it speaks (`acs_mcb4b`, ...).
    pub protocol: String,
    /// `host:port` of a TCP connection (an Ethernet controller or a terminal server).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tcp: Option<String>,
    /// A serial port, instead of `tcp`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub serial: Option<SerialSection>,
    /// Seconds between polls while an axis moves.
    #[serde(default = "default_moving_poll")]
    pub moving_poll: f64,
    /// Seconds between polls while every axis is idle.
    #[serde(default = "default_idle_poll")]
    pub idle_poll: f64,
    /// Seconds a reply may take.
    #[serde(default = "default_timeout")]
    pub timeout: f64,
    /// Times a query without a good reply is sent again.
    #[serde(default = "default_retries")]
    pub retries: u32,
    /// The controller's units per record step, where the protocol has units (see README).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub units_per_step: Option<f64>,
    #[serde(skip)]
    /// Where it was written.
    pub origin: Origin,
}

/// A serial port's settings.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SerialSection {
    /// The device, e.g. `/dev/ttyUSB0`.
    pub device: String,
    /// Bits per second.
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// `none`, `odd` or `even`.
    #[serde(default)]
    pub parity: ParityChoice,
    /// 5 to 8.
    #[serde(default = "default_data_bits")]
    pub data_bits: u8,
    /// 1 or 2.
    #[serde(default = "default_stop_bits")]
    pub stop_bits: u8,
    /// `none`, `software` or `hardware`.
    #[serde(default)]
    pub flow_control: FlowControlChoice,
}

fn default_moving_poll() -> f64 {
    0.1
}

fn default_idle_poll() -> f64 {
    1.0
}

fn default_timeout() -> f64 {
    1.0
}

fn default_retries() -> u32 {
    1
}

fn default_baud() -> u32 {
    9600
}

fn default_data_bits() -> u8 {
    8
}

fn default_stop_bits() -> u8 {
    1
}

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
    /// What it serves: axes, calc links, value holders, controllers.
    pub contents: NodeContents,
    /// The launch file's state directory, resolved against the file's directory.
    pub state_dir: Option<PathBuf>,
    /// Autosave settings.
    pub autosave: AutosaveSection,
    /// The Channel Access front-end this process runs, if any.
    pub channel_access: Option<CaConfig>,
    /// The web server this process runs, if any.
    pub web: Option<WebConfig>,
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
    /// What importing its databases warned of.
    warnings: Vec<String>,
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
        let mut launch =
            Self { file: LaunchFile::default(), base: base.to_path_buf(), sources: Vec::new(), warnings: Vec::new() };
        let main = launch.read_source(name, text)?;
        if let Some(zenoh) = main.zenoh.clone() {
            launch.file.zenoh = Some(zenoh);
        }
        launch.file.state_dir = main.state_dir.clone();
        launch.file.autosave = main.autosave.clone();
        launch.file.channel_access = main.channel_access.clone();
        launch.file.web = main.web.clone();
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
        self.file.controllers.extend(
            file.controllers.into_iter().enumerate().map(|(i, c)| ControllerSection { origin: origin(i), ..c }),
        );
        self.file.axes.extend(file.axes.into_iter().enumerate().map(|(i, a)| AxisSection { origin: origin(i), ..a }));
        self.file.calcs.extend(file.calcs.into_iter().enumerate().map(|(i, c)| CalcSection { origin: origin(i), ..c }));
        self.file
            .values
            .extend(file.values.into_iter().enumerate().map(|(i, v)| ValueSection { origin: origin(i), ..v }));
        for database in &file.databases {
            let path = dir.join(&database.file);
            let definitions: Vec<String> = database.macros.iter().map(|(k, v)| format!("{k}={v}")).collect();
            let macros =
                Macros::parse(&definitions).map_err(|e| self.error(Problem::at(source, vec![], e.to_string())))?;
            let (imported, warnings) = import_db(&path, &macros)?;
            let name = path.display().to_string();
            self.warnings.extend(warnings.into_iter().map(|w| format!("{name}: {w}")));
            // Errors found later in its records name the database (its lines are its own).
            self.sources.push(Source { name, text: String::new() });
            let imported = LaunchFile { include: Vec::new(), databases: Vec::new(), ..imported };
            self.merge(imported, dir, visited)?;
        }
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

    /// What importing the launch's databases warned of (hardware simulated, records skipped).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
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
        for (index, rule) in zenoh.access.iter().enumerate() {
            let at = |key: &str, message: String| {
                let path =
                    vec![Seg::Key("zenoh".into()), Seg::Key("access".into()), Seg::Index(index), Seg::Key(key.into())];
                Problem::at(0, path, format!("zenoh.access '{}': {message}", rule.name))
            };
            if rule.may.is_empty() {
                return Err(at("may", "grants nothing: say what its members may (read, drive, configure, all)".into()));
            }
            if rule.cert_common_names.is_empty() && rule.usernames.is_empty() && rule.interfaces.is_empty() {
                let message = "has no members: name cert_common_names, usernames or interfaces".to_string();
                return Err(at("name", message));
            }
            if zenoh.access[..index].iter().any(|r| r.name == rule.name) {
                return Err(at("name", "is defined twice".into()));
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
        for controller in &self.file.controllers {
            controller.spec(Vec::new())?;
        }
        let front_ends = [
            ("channel_access", self.file.channel_access.as_ref().and_then(|ca| ca.host.as_ref())),
            ("web", self.file.web.as_ref().and_then(|web| web.host.as_ref())),
        ];
        for (section, host) in front_ends {
            if let Some(host) = host.filter(|h| !self.file.hosts.contains_key(*h)) {
                let message = format!("{section}.host: '{host}' is not declared under [hosts]");
                return Err(Problem::at(0, keys_path(&[section, "host"]), message));
            }
        }
        self.check_axes_on_controllers()?;
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
        let controllers = f.controllers.iter().map(|c| ("controller", c.name.as_str(), c.host.as_deref(), c.origin));
        let axes = f.axes.iter().map(|a| ("axis", a.name.as_str(), a.host.as_deref(), a.origin));
        let calcs = f.calcs.iter().map(|c| ("calc", c.name.as_str(), c.host.as_deref(), c.origin));
        let values = f.values.iter().map(|v| ("value", v.name.as_str(), v.host.as_deref(), v.origin));
        controllers.chain(axes).chain(calcs).chain(values).collect()
    }

    /// Every axis on a controller names one of this launch, on its host, by a channel the
    /// protocol has and no other axis of that controller uses.
    fn check_axes_on_controllers(&self) -> Result<(), Problem> {
        let mut taken: BTreeMap<(&str, usize), &str> = BTreeMap::new();
        for axis in &self.file.axes {
            let at = |key: &str, message: String| {
                Problem::in_item("axis", axis.origin, &[key], format!("axis '{}': {key}: {message}", axis.name))
            };
            let (Some(name), Some(channel)) = (&axis.controller, axis.channel) else { continue };
            let Some(controller) = self.file.controllers.iter().find(|c| c.name == *name) else {
                let known: Vec<&str> = self.file.controllers.iter().map(|c| c.name.as_str()).collect();
                return Err(at("controller", format!("no [[controller]] '{name}' (known: {})", known.join(", "))));
            };
            if controller.host != axis.host {
                let message = format!("controller '{name}' runs on another host: an axis runs where its controller is");
                return Err(at("host", message));
            }
            if let Some(protocol) = ProtocolKind::from_name(&controller.protocol) {
                protocol.check_channel(channel).map_err(|e| at("channel", e.to_string()))?;
            }
            if let Some(other) = taken.insert((name.as_str(), channel), axis.name.as_str()) {
                return Err(at(
                    "channel",
                    format!("channel {channel} of controller '{name}' is already axis '{other}'"),
                ));
            }
        }
        Ok(())
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
            zenoh.tls = section.tls.clone().or(zenoh.tls);
        }
        self.resolve_files(&mut zenoh);
        let runs_here = |item_host: &Option<String>| host.is_none() || item_host.as_deref() == host;
        let plan = |a: &AxisSection| a.plan().map_err(|p| self.error(p));
        let spec = |c: &CalcSection| c.spec().map_err(|p| self.error(p));
        let controller = |c: &ControllerSection| {
            let channels = self.file.axes.iter().filter(|a| a.controller.as_ref() == Some(&c.name));
            c.spec(channels.filter_map(|a| a.channel).collect()).map_err(|p| self.error(p))
        };
        let contents = NodeContents {
            plans: self.file.axes.iter().filter(|a| runs_here(&a.host)).map(plan).collect::<Result<_, _>>()?,
            calcs: self.file.calcs.iter().filter(|c| runs_here(&c.host)).map(spec).collect::<Result<_, _>>()?,
            values: self
                .file
                .values
                .iter()
                .filter(|v| runs_here(&v.host))
                .map(|v| ValueSpec { key: v.key(), initial: v.value })
                .collect(),
            controllers: self
                .file
                .controllers
                .iter()
                .filter(|c| runs_here(&c.host))
                .map(controller)
                .collect::<Result<_, _>>()?,
            guarded: zenoh.guarded(),
        };
        Ok(Deployment {
            zenoh,
            contents,
            state_dir: self.file.state_dir.as_ref().map(|dir| self.base.join(dir)),
            autosave: self.file.autosave.clone().unwrap_or_default(),
            channel_access: self.file.channel_access.as_ref().filter(|ca| runs_here(&ca.host)).map(|ca| CaConfig {
                pv_prefix: ca.pv_prefix.clone(),
                address: ca.address,
                port: ca.port,
            }),
            web: self.file.web.as_ref().filter(|w| runs_here(&w.host)).map(|w| WebConfig { address: w.address }),
        })
    }

    /// The files `[zenoh]` names (certificates, keys, users), relative to the launch file.
    fn resolve_files(&self, zenoh: &mut ZenohConfig) {
        let resolve = |file: &mut String| *file = self.base.join(&*file).display().to_string();
        if let Some(tls) = &mut zenoh.tls {
            resolve(&mut tls.ca);
            tls.certificate.iter_mut().chain(tls.key.iter_mut()).for_each(resolve);
        }
        if let Some(users) = zenoh.login.as_mut().and_then(|l| l.users_file.as_mut()) {
            resolve(users);
        }
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
        let driver = match (self.driver, &self.controller, self.channel) {
            (DriverKind::Controller, Some(controller), Some(channel)) => {
                DriverPlan::Controller { controller: controller.clone(), channel }
            }
            (DriverKind::Controller, None, _) => return Err(at(&["controller"], "names no [[controller]]".into())),
            (DriverKind::Controller, _, None) => {
                return Err(at(&["channel"], "the controller's number for the axis is missing".into()))
            }
            (_, Some(_), _) => return Err(at(&["controller"], "only with driver = \"controller\"".into())),
            (_, _, Some(_)) => return Err(at(&["channel"], "only with driver = \"controller\"".into())),
            (DriverKind::Sim, None, None) => DriverPlan::Sim(self.sim.clone()),
            (DriverKind::Soft, None, None) => DriverPlan::Soft,
        };
        if !(self.readback_rate > 0.0 && self.readback_rate <= MAX_READBACK_RATE) {
            let message = format!("{} Hz is outside (0, {MAX_READBACK_RATE}]", self.readback_rate);
            return Err(at(&["readback_rate"], message));
        }
        let dtyp = match driver {
            DriverPlan::Soft => "Soft Channel",
            DriverPlan::Sim(_) => "Sim Motor",
            DriverPlan::Controller { .. } => "asynMotor",
        };
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
        let jog_hold = match self.jog_hold {
            JogHoldChoice::Optional => JogHold::Optional,
            JogHoldChoice::Required => JogHold::Required,
        };
        Ok(AxisPlan { name: self.name.clone(), fields, driver, rates, jog_hold })
    }
}

impl ControllerSection {
    /// The controller, driving `channels`; every setting checked.
    fn spec(&self, channels: Vec<usize>) -> Result<ControllerSpec, Problem> {
        let at = |inner: &[&str], message: String| {
            let key = inner.join(".");
            Problem::in_item("controller", self.origin, inner, format!("controller '{}': {key}: {message}", self.name))
        };
        if self.name.trim().is_empty() {
            return Err(at(&["name"], "must not be empty".into()));
        }
        let protocol = ProtocolKind::from_name(&self.protocol).ok_or_else(|| {
            at(&["protocol"], format!("'{}' is not a known protocol (known: {})", self.protocol, ProtocolKind::known()))
        })?;
        let transport = match (&self.tcp, &self.serial) {
            (Some(address), None) => {
                let (host, port) = address.rsplit_once(':').unwrap_or((address, ""));
                if host.is_empty() || port.parse::<u16>().map_or(true, |p| p == 0) {
                    return Err(at(&["tcp"], format!("'{address}' is not host:port")));
                }
                Transport::Tcp { address: address.clone() }
            }
            (None, Some(serial)) => {
                let settings = SerialSettings {
                    device: serial.device.clone(),
                    baud: serial.baud,
                    parity: match serial.parity {
                        ParityChoice::None => spec::Parity::None,
                        ParityChoice::Odd => spec::Parity::Odd,
                        ParityChoice::Even => spec::Parity::Even,
                    },
                    data_bits: serial.data_bits,
                    stop_bits: serial.stop_bits,
                    flow_control: match serial.flow_control {
                        FlowControlChoice::None => spec::FlowControl::None,
                        FlowControlChoice::Software => spec::FlowControl::Software,
                        FlowControlChoice::Hardware => spec::FlowControl::Hardware,
                    },
                };
                settings.check().map_err(|e| at(&["serial"], e.to_string()))?;
                Transport::Serial(settings)
            }
            _ => return Err(at(&["name"], "give one of tcp = \"host:port\" or a [controller.serial] port".into())),
        };
        let options = ProtocolOptions { units_per_step: self.units_per_step };
        options.check().map_err(|e| at(&["units_per_step"], e.to_string()))?;
        let period = |key: &'static str, seconds: f64, min: f64, max: f64| {
            spec::period(key, seconds, min, max).map_err(|e| at(&[key], e.to_string()))
        };
        let config = ControllerConfig {
            moving_poll: period("moving_poll", self.moving_poll, 0.001, 10.0)?,
            idle_poll: period("idle_poll", self.idle_poll, 0.001, 60.0)?,
            timeout: period("timeout", self.timeout, 0.001, 60.0)?,
            retries: self.retries,
            ..ControllerConfig::for_channels(channels)
        };
        if self.retries > 10 {
            return Err(at(&["retries"], format!("{} is more than 10", self.retries)));
        }
        Ok(ControllerSpec { name: self.name.clone(), protocol, options, transport, config })
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
        assert_eq!(deployment.contents.calcs[0].inputs[0].mode, InputMode::Process);
        assert_eq!(deployment.contents.plans[1].driver, DriverPlan::Soft);
        assert_eq!(deployment.contents.plans[1].fields.dtyp, "Soft Channel");
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
        let plans = deployment.contents.plans;
        let f = &plans[0].fields;
        assert_eq!((f.mres, f.velo, f.dir, f.egu.as_str(), f.name.as_str()), (0.001, 10.0, 1, "mm", "m1"));
        assert!(matches!(&plans[0].driver, DriverPlan::Sim(sim) if sim.high_limit_switch == Some(105000.0)));
        assert_eq!(plans[0].rates.moving, Duration::from_millis(20));
    }

    #[test]
    fn access_rules_and_tls_files_are_checked_and_resolved_against_the_launch_file() {
        let text = "[zenoh]\nlisten = [\"tls/127.0.0.1:7447\"]\n\
                    [zenoh.tls]\nca = \"certs/ca.pem\"\ncertificate = \"/etc/node.pem\"\nkey = \"node.key\"\nmutual = true\n\
                    [[zenoh.access]]\nname = \"operators\"\nmay = [\"drive\", \"configure\"]\ncert_common_names = [\"op\"]\n";
        let launch = Launch::from_text("lab.toml", text, Path::new("/srv/lab")).unwrap();
        let deployment = launch.deployment(None).unwrap();
        let tls = deployment.zenoh.tls.as_ref().unwrap();
        assert_eq!((tls.ca.as_str(), tls.certificate.as_deref()), ("/srv/lab/certs/ca.pem", Some("/etc/node.pem")));
        assert!(deployment.contents.guarded);
        assert!(!Launch::parse("").unwrap().deployment(None).unwrap().contents.guarded);

        let bad = |rule: &str| Launch::parse(&format!("[[zenoh.access]]\n{rule}")).unwrap_err().to_string();
        assert!(bad("name = \"x\"\nmay = []\nusernames = [\"u\"]").contains("zenoh.access 'x': grants nothing"));
        assert!(bad("name = \"x\"\nmay = [\"read\"]").contains("zenoh.access 'x': has no members"));
        assert!(bad("name = \"x\"\nmay = [\"fly\"]\nusernames = [\"u\"]").contains("unknown variant `fly`"));
        let twice = "name = \"x\"\nmay = [\"read\"]\nusernames = [\"u\"]\n";
        assert!(bad(&format!("{twice}[[zenoh.access]]\n{twice}")).contains("zenoh.access 'x': is defined twice"));
    }

    #[test]
    fn a_channel_access_section_runs_on_its_host() {
        let text = "[hosts.a]\n[hosts.b]\n[channel_access]\npv_prefix = \"bl1:\"\nport = 5070\nhost = \"b\"\n";
        let launch = Launch::parse(text).unwrap();
        assert_eq!(launch.deployment(Some("a")).unwrap().channel_access, None);
        let ca = launch.deployment(Some("b")).unwrap().channel_access.unwrap();
        assert_eq!((ca.pv_prefix.as_str(), ca.port, ca.address.to_string()), ("bl1:", 5070, "127.0.0.1".into()));
        let unknown = Launch::parse("[channel_access]\nhost = \"c\"\n").unwrap_err().to_string();
        assert!(unknown.contains("channel_access.host: 'c' is not declared"), "{unknown}");
        let web = Launch::parse("[web]\naddress = \"0.0.0.0:8081\"\n").unwrap().deployment(None).unwrap().web;
        assert_eq!(web.map(|w| w.address.to_string()), Some("0.0.0.0:8081".into()));
        let unknown = Launch::parse("[web]\nhost = \"c\"\n").unwrap_err().to_string();
        assert!(unknown.contains("web.host: 'c' is not declared"), "{unknown}");
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

    const CONTROLLED: &str = r#"[[controller]]
name = "mcb"
protocol = "acs_mcb4b"
tcp = "127.0.0.1:4001"
moving_poll = 0.05

[[axis]]
name = "x"
driver = "controller"
controller = "mcb"
channel = 2

[[axis]]
name = "y"
driver = "controller"
controller = "mcb"
channel = 0
"#;

    #[test]
    fn a_controller_drives_the_channels_of_its_axes() {
        let deployment = Launch::parse(CONTROLLED).unwrap().deployment(None).unwrap();
        let [mcb] = &deployment.contents.controllers[..] else { panic!("one controller") };
        assert_eq!(
            (mcb.protocol, &mcb.transport),
            (ProtocolKind::AcsMcb4b, &Transport::Tcp { address: "127.0.0.1:4001".into() })
        );
        assert_eq!((mcb.config.channels.clone(), mcb.config.moving_poll), (vec![2, 0], Duration::from_millis(50)));
        let x = &deployment.contents.plans[0];
        assert_eq!(x.driver, DriverPlan::Controller { controller: "mcb".into(), channel: 2 });
        assert_eq!(x.fields.dtyp, "asynMotor");
        let serial = CONTROLLED.replace(
            r#"tcp = "127.0.0.1:4001""#,
            r#"serial = { device = "/dev/ttyS0", baud = 19200, parity = "even", stop_bits = 2 }"#,
        );
        let deployment = Launch::parse(&serial).unwrap().deployment(None).unwrap();
        let Transport::Serial(line) = &deployment.contents.controllers[0].transport else { panic!("a serial line") };
        assert_eq!((line.baud, line.parity, line.data_bits, line.stop_bits), (19200, spec::Parity::Even, 8, 2));
    }

    #[test]
    fn controller_errors_name_the_file_line_and_key() {
        let refused = |from: &str, to: &str| Launch::parse(&CONTROLLED.replacen(from, to, 1)).unwrap_err().to_string();
        assert_eq!(
            refused("acs_mcb4b", "acme"),
            format!(
                "<launch>:3: controller 'mcb': protocol: 'acme' is not a known protocol (known: {})",
                ProtocolKind::known()
            )
        );
        assert_eq!(
            refused("127.0.0.1:4001", "127.0.0.1"),
            "<launch>:4: controller 'mcb': tcp: '127.0.0.1' is not host:port"
        );
        assert_eq!(
            refused("moving_poll = 0.05", "moving_poll = 0"),
            "<launch>:5: controller 'mcb': moving_poll: 0 s is outside [0.001, 10] s"
        );
        assert!(refused("moving_poll = 0.05", "parity = \"odd\"").starts_with("<launch>:5: unknown field `parity`"));
        assert_eq!(
            refused("tcp = \"127.0.0.1:4001\"", "tcp = \"h:1\"\nserial = { device = \"/dev/ttyS0\" }"),
            "<launch>:2: controller 'mcb': name: give one of tcp = \"host:port\" or a [controller.serial] port"
        );
        assert_eq!(
            refused("controller = \"mcb\"", "controller = \"other\""),
            "<launch>:10: axis 'x': controller: no [[controller]] 'other' (known: mcb)"
        );
        assert_eq!(
            refused("channel = 2", "channel = 4"),
            "<launch>:11: axis 'x': channel: channel 4: acs_mcb4b numbers its axes 0 to 3"
        );
        assert_eq!(
            refused("channel = 2", "channel = 0"),
            "<launch>:17: axis 'y': channel: channel 0 of controller 'mcb' is already axis 'x'"
        );
        assert_eq!(
            refused("driver = \"controller\"", "driver = \"sim\""),
            "<launch>:10: axis 'x': controller: only with driver = \"controller\""
        );
        assert_eq!(
            refused("channel = 2\n", ""),
            "<launch>:7: axis 'x': channel: the controller's number for the axis is missing"
        );
    }

    #[test]
    fn a_database_of_asyn_motors_runs_on_the_launch_files_controllers() {
        let dir = tempfile::tempdir().unwrap();
        let db =
            r#"record(motor, "$(P)m1") { field(DTYP, "asynMotor") field(OUT, "@asyn(mcb,3)") field(MRES, "0.01") }"#;
        std::fs::write(dir.path().join("motors.db"), db).unwrap();
        let main = "[[database]]\nfile = \"motors.db\"\nmacros = { P = \"bl:\" }\n\n[[controller]]\nname = \"mcb\"\nprotocol = \"acs_mcb4b\"\ntcp = \"h:4001\"\n";
        std::fs::write(dir.path().join("main.toml"), main).unwrap();
        let launch = Launch::load(&dir.path().join("main.toml")).unwrap();
        let deployment = launch.deployment(None).unwrap();
        let axis = &deployment.contents.plans[0];
        assert_eq!((axis.name.as_str(), axis.fields.mres), ("bl:m1", 0.01));
        assert_eq!(axis.driver, DriverPlan::Controller { controller: "mcb".into(), channel: 3 });
        assert_eq!(deployment.contents.controllers[0].config.channels, [3]);
        std::fs::write(dir.path().join("motors.db"), db.replace("mcb,3", "mcb,9")).unwrap();
        let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
        assert!(error.file.ends_with("motors.db"), "the database is named: {error}");
        assert!(error.message.contains("acs_mcb4b numbers its axes 0 to 3"), "{error}");
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
        let names = |d: &Deployment| d.contents.plans.iter().map(|p| p.name.clone()).collect::<Vec<_>>();
        assert_eq!((names(&optics), optics.contents.calcs.len()), (vec!["m1".to_string()], 0));
        assert_eq!(optics.zenoh.listen, ["tcp/10.0.0.2:7447"]);
        assert_eq!(
            (optics.zenoh.mode.name(), optics.zenoh.connect.as_slice()),
            ("peer", &["tcp/10.0.0.1:7447".to_string()][..])
        );
        let detector = launch.deployment(Some("detector")).unwrap();
        assert_eq!(
            (names(&detector), detector.contents.calcs.len(), detector.zenoh.mode.name()),
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
        let names: Vec<String> = launch.deployment(None).unwrap().contents.plans.into_iter().map(|p| p.name).collect();
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
        let names: Vec<&str> = optics.contents.plans.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["m1", "slit_top", "slit_bottom"], "the included slits run on the optics host");
        let user = reference.deployment(Some("user")).unwrap();
        assert_eq!((user.contents.calcs.len(), user.contents.values.len(), user.zenoh.mode.name()), (1, 1, "client"));
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
