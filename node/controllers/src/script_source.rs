//! What a script controller is given, as plain data (the deployment reads the files; the
//! protocol, `script/`, runs them), and why a script cannot run: shared by `protocol` (its
//! options and reload errors) and the script driver.

use std::collections::BTreeMap;

/// A controller's script and what the launch file gives it (motorScriptMotor's
/// `ScriptControllerConfig` and `ScriptAxisConfig`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ScriptSource {
    /// Where it was read, as messages name it (`scripts/vmc.lua`).
    pub path: String,
    /// Its text.
    pub text: String,
    /// The other `.lua` files of its directory, by module name (`json` for `json.lua`): all
    /// that `require` may load.
    pub modules: BTreeMap<String, String>,
    /// The port name `DRIVER` holds: the controller's name.
    pub driver: String,
    /// Globals every axis's script sees (`PORT`, ...).
    pub macros: BTreeMap<String, MacroValue>,
    /// Each channel's own globals, over the controller's (`OPEN_LOOP`, ...).
    pub axis_macros: BTreeMap<usize, BTreeMap<String, MacroValue>>,
    /// Each channel's axis's MRES, the `MOTOR_REC_RESOLUTION` parameter its script reads (as
    /// the record's device support gives it).
    pub record_resolution: BTreeMap<usize, f64>,
}

impl ScriptSource {
    /// The directory part of `path`, with its trailing slash (empty for none).
    pub(crate) fn directory(&self) -> String {
        match self.path.rfind('/') {
            Some(at) => self.path[..=at].to_string(),
            None => String::new(),
        }
    }
}

/// A macro's value, as Lua sees it.
#[derive(Clone, Debug, PartialEq)]
pub enum MacroValue {
    /// A string.
    Text(String),
    /// An integer.
    Integer(i64),
    /// A float.
    Number(f64),
    /// A boolean.
    Boolean(bool),
}

/// A script that cannot run.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ScriptError {
    /// It does not load: a syntax error, or an error at its top level.
    #[error("the script {script} does not load: {message}")]
    Load {
        /// The script.
        script: String,
        /// The Lua error, with the file and line.
        message: String,
    },
    /// A call failed.
    #[error("{function}() failed: {message}")]
    Call {
        /// The script's function.
        function: &'static str,
        /// The Lua error, with the file and line.
        message: String,
    },
    /// The controller has no script.
    #[error("no script: a script controller needs script = \"path.lua\"")]
    Missing,
}
