//! A launch file as written: the TOML model serde reads (every section and its choices), and
//! the errors that name the file, line and key at fault.

use crate::front_ends::{CaConfig, JointConfig, Ros2Config, Ros2ConfigError, WebConfig};
use crate::network::{Mode, TlsConfig, ZenohConfig};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;
use zmotor_core::SimConfig;
use zmotor_msgs::keys;
use zmotor_ros2_proto::Distribution;

/// Highest readback rate while moving, Hz.
pub const MAX_READBACK_RATE: f64 = 1000.0;

/// A launch file that cannot be used: where, and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}{}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
#[non_exhaustive]
pub struct LaunchError {
    /// The file at fault.
    pub file: String,
    /// The line, when it is known.
    pub line: Option<usize>,
    /// What is wrong, naming the key.
    pub message: String,
}

/// The most a launch, database or script file may hold: a deployment's text is kilobytes, and a
/// path to a device (`/dev/zero`) or a wrong file must not fill the memory.
const LARGEST_FILE: u64 = 16 << 20;

/// The text of a regular file of at most `LARGEST_FILE` bytes.
pub(crate) fn read_bounded(path: &Path) -> std::io::Result<String> {
    use std::io::{Error, ErrorKind, Read};
    let file = std::fs::File::open(path)?;
    if !file.metadata()?.is_file() {
        return Err(Error::new(ErrorKind::InvalidInput, "not a regular file"));
    }
    let mut text = String::new();
    file.take(LARGEST_FILE + 1).read_to_string(&mut text)?;
    if text.len() as u64 > LARGEST_FILE {
        return Err(Error::new(ErrorKind::InvalidData, format!("larger than {} MiB", LARGEST_FILE >> 20)));
    }
    Ok(text)
}

/// The text of a launch or database file; an error names the file.
pub(crate) fn read_text(path: &Path) -> Result<String, LaunchError> {
    read_bounded(path).map_err(|e| LaunchError {
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
    /// A ROS 2 node whose joints are axes (`[ros2]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ros2: Option<Ros2Section>,
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

/// The `[ros2]` section: `zmotor ros2` run by the launch (on its host, when given), making the
/// axes it names joints of a ROS 2 node.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Ros2Section {
    /// ROS_DOMAIN_ID.
    pub domain_id: u32,
    /// The node's namespace (`/` for none).
    pub namespace: String,
    /// The node's name.
    pub node_name: String,
    /// `jazzy` (type hashes in keys) or `humble` (none).
    pub distribution: String,
    /// Seconds between the joints' state messages at rest.
    pub rest_period: f64,
    /// The most joint state messages a second while joints move.
    pub max_rate: f64,
    /// The joints (`[[ros2.joint]]`).
    #[serde(rename = "joint")]
    pub joints: Vec<JointSection>,
    /// The host that runs it (with `[hosts]`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
}

impl Default for Ros2Section {
    fn default() -> Self {
        let config = Ros2Config::default();
        Self {
            domain_id: config.domain_id,
            namespace: config.namespace,
            node_name: config.node_name,
            distribution: "jazzy".into(),
            rest_period: config.rest_period.as_secs_f64(),
            max_rate: config.max_rate,
            joints: Vec::new(),
            host: None,
        }
    }
}

/// A `[[ros2.joint]]`: an axis of the launch as a ROS joint.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct JointSection {
    /// The joint's ROS name.
    pub name: String,
    /// The axis.
    pub axis: String,
    /// SI units (m or rad) per EGU, when the axis's EGU is no unit of length or angle or is to
    /// be overridden.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub factor: Option<f64>,
}

impl Ros2Section {
    /// The ROS 2 node's configuration, checked; an error names the key.
    pub(crate) fn config(&self) -> Result<Ros2Config, (&'static str, String)> {
        let distribution = Distribution::from_name(&self.distribution)
            .ok_or(("distribution", format!("distribution: '{}' is not jazzy or humble", self.distribution)))?;
        if !(self.rest_period.is_finite() && self.rest_period > 0.0) {
            return Err(("rest_period", Ros2ConfigError::RestPeriod.to_string()));
        }
        let config = Ros2Config {
            domain_id: self.domain_id,
            namespace: self.namespace.clone(),
            node_name: self.node_name.clone(),
            distribution,
            joints: self
                .joints
                .iter()
                .map(|j| JointConfig { name: j.name.clone(), axis: j.axis.clone(), factor: j.factor })
                .collect(),
            rest_period: Duration::from_secs_f64(self.rest_period),
            max_rate: self.max_rate,
        };
        config.check().map_err(|e| {
            let key = match e {
                Ros2ConfigError::NodeName(_) => "node_name",
                Ros2ConfigError::Namespace(_) => "namespace",
                Ros2ConfigError::RestPeriod => "rest_period",
                Ros2ConfigError::MaxRate => "max_rate",
                _ => "joint",
            };
            (key, e.to_string())
        })?;
        Ok(config)
    }
}

/// The `[web]` section: `zmotor web` run by the launch (on its host, when given).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct WebSection {
    /// The HTTP address.
    pub address: std::net::SocketAddr,
    /// Host names browsers reach it by, beside IP addresses, `localhost` and the machine's name.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub names: Vec<String>,
    /// The host that runs it (with `[hosts]`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
}

impl Default for WebSection {
    fn default() -> Self {
        Self { address: WebConfig::default().address, names: Vec::new(), host: None }
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
    /// With `[hosts]`: the host that runs its records.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
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
    /// The host's TLS settings over `[zenoh.tls]`'s (its own certificate and key, most often).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tls: Option<HostTls>,
}

/// A host's `[hosts.<name>.tls]`: each key given replaces `[zenoh.tls]`'s, the others stay (a
/// host that names its own certificate keeps the authority and mutual TLS: leaving `mutual`
/// out never turns it off there).
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HostTls {
    /// PEM file of the certificate authority, instead of `[zenoh.tls]`'s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ca: Option<String>,
    /// PEM file of the host's certificate.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub certificate: Option<String>,
    /// PEM file of its private key.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub key: Option<String>,
    /// Mutual TLS on this host, instead of `[zenoh.tls]`'s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mutual: Option<bool>,
}

impl HostTls {
    /// `[zenoh.tls]` (`base`) with this host's keys over it; `None` when neither names an
    /// authority.
    pub(crate) fn over(&self, base: Option<TlsConfig>) -> Option<TlsConfig> {
        let base = base.unwrap_or_default();
        let ca = self.ca.clone().or((!base.ca.is_empty()).then_some(base.ca))?;
        Some(TlsConfig {
            ca,
            certificate: self.certificate.clone().or(base.certificate),
            key: self.key.clone().or(base.key),
            mutual: self.mutual.unwrap_or(base.mutual),
        })
    }
}

/// Where an item was written: which file of the launch, and its index in that file's array.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Origin {
    pub(crate) source: usize,
    pub(crate) index: usize,
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
#[non_exhaustive]
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
    /// Seconds between polls while an axis moves (0.1, or a script's `MovingPollPeriod`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub moving_poll: Option<f64>,
    /// Seconds between polls while every axis is idle (1, or a script's `IdlePollPeriod`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub idle_poll: Option<f64>,
    /// Seconds a reply may take.
    #[serde(default = "default_timeout")]
    pub timeout: f64,
    /// Times a query without a good reply is sent again.
    #[serde(default = "default_retries")]
    pub retries: u32,
    /// The controller's units per record step, where the protocol has units (see README).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub units_per_step: Option<f64>,
    /// The controller's own names of its channels' axes, by channel (an XPS's positioners,
    /// `GROUP.POSITIONER`), where they are not the protocol's defaults.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub axis_names: BTreeMap<String, String>,
    /// Only observe it: connect, initialise read-only and poll; refuse every command that
    /// would move, enable or reconfigure (commissioning, or beside a running IOC).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub observe: bool,
    /// The Lua script of a `script` controller (motorScriptMotor's), relative to this file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub script: Option<String>,
    /// Globals its script sees, as `ScriptControllerConfig`'s macros (`{ PORT = "VMC" }`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub macros: BTreeMap<String, toml::Value>,
    /// Each channel's own globals, over the controller's, as `ScriptAxisConfig`'s
    /// (`{ 0 = { OPEN_LOOP = "NO" } }`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub axis_macros: BTreeMap<String, BTreeMap<String, toml::Value>>,
    #[serde(skip)]
    /// The script's files, read when the launch file was.
    pub script_files: Option<ScriptFiles>,
    #[serde(skip)]
    /// Where it was written.
    pub origin: Origin,
}

/// A controller script as read from disk: its text and the `.lua` files beside it, all that
/// its `require` may load.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ScriptFiles {
    /// The script's path, as given (relative to the working directory or absolute).
    pub path: String,
    /// Its text.
    pub text: String,
    /// The other `.lua` files of its directory, by module name (`json` for `json.lua`).
    pub modules: BTreeMap<String, String>,
}

impl ScriptFiles {
    /// The script at `path` and the modules beside it.
    pub fn read(path: &Path) -> Result<Self, String> {
        let text = read_bounded(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let directory = match path.parent() {
            Some(parent) if !parent.as_os_str().is_empty() => parent.to_path_buf(),
            _ => Path::new(".").to_path_buf(),
        };
        let entries = std::fs::read_dir(&directory).map_err(|e| format!("{}: {e}", directory.display()))?;
        let mut modules = BTreeMap::new();
        for entry in entries.flatten() {
            let file = entry.path();
            let is_lua = file.extension().is_some_and(|e| e == "lua");
            let (Some(stem), true) = (file.file_stem().and_then(|s| s.to_str()), is_lua) else { continue };
            if file.file_name() == path.file_name() {
                continue;
            }
            let module = read_bounded(&file).map_err(|e| format!("{}: {e}", file.display()))?;
            modules.insert(stem.to_string(), module);
        }
        Ok(Self { path: path.display().to_string(), text, modules })
    }
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

/// Seconds between polls while an axis moves, unless the launch file or the script says.
pub(crate) const DEFAULT_MOVING_POLL: f64 = 0.1;

/// Seconds between polls while every axis is idle, unless the launch file or the script says.
pub(crate) const DEFAULT_IDLE_POLL: f64 = 1.0;

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

pub(crate) fn default_readback_rate() -> f64 {
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
    /// Inputs A–P (a calcout's A–L, a transform's fields to P): a key (CP: recompute on each update) or `{ key = "...", mode = "npp" }`.
    #[serde(default)]
    pub inputs: BTreeMap<String, CalcInput>,
    /// Values of inputs before any update, e.g. `{ B = 1000 }` (the record's fields A–P).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub constants: BTreeMap<String, f64>,
    /// Key the result is written to.
    pub output: String,
    /// `every` (write every time, the default) or `on_change`.
    #[serde(default)]
    pub option: CalcOption,
    /// Keys whose every write processes it, as EPICS forward links into it do (not read when it
    /// starts): `bridge/<name>/PROC` for a motor's FLNK, a value's key for the value's FLNK.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub processed_by: Vec<String>,
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
