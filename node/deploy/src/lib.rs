//! zmotor-deploy: what a deployment runs, as plain data, with no network, no runtime and no
//! clock. Launch files are a TOML description of a deployment (the Zenoh side, controllers,
//! axes, calc links, value holders, autosave, the front-ends), possibly spread over included
//! files and split between hosts. Every value is checked before anything starts; an error names
//! the file, the line and the key. EPICS databases (`.db`) are imported into the same model.
//! A checked launch gives a `Deployment` per host: what its node serves (`NodeContents`), how
//! it joins the network (`ZenohConfig`), and where its front-ends serve.

mod db;
mod deployment;
mod file;
mod front_ends;
mod launch;
mod locate;
mod network;
mod plans;
mod problem;
#[cfg(test)]
mod tests;

pub use db::{import_db, import_db_text, simulated_without_controllers, MacroError, Macros};
pub use deployment::{Deployment, NodeContents, ValueSpec};
pub use file::{
    AutosaveSection, AxisSection, CalcInput, CalcOption, CalcSection, ChannelAccessSection, ControllerSection,
    DatabaseSection, DriverKind, FlowControlChoice, HostSection, HostTls, InputLinkMode, JogHoldChoice, JointSection,
    LaunchError, LaunchFile, Origin, ParityChoice, Ros2Section, ScriptFiles, SerialSection, UnknownChoice,
    ValueSection, WebSection, MAX_READBACK_RATE,
};
pub use front_ends::{CaConfig, JointConfig, Ros2Config, Ros2ConfigError, WebConfig};
pub use launch::Launch;
pub use network::{
    AccessRule, LoginConfig, Mode, Permission, TlsConfig, UnknownMode, ZenohConfig, CLIENT_LEASE, COMMAND_LEASE,
    NODE_LEASE,
};
pub use zmotor_ros2_proto::Distribution;
