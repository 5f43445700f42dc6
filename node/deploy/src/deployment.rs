//! What one process runs, as plain data: the result of a checked launch for one host.

use crate::file::AutosaveSection;
use crate::front_ends::{CaConfig, Ros2Config, WebConfig};
use crate::network::ZenohConfig;
use std::path::PathBuf;
use zmotor_bridge::CalcLinkSpec;
use zmotor_controllers::ControllerSpec;
use zmotor_core::AxisPlan;

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
    /// The ROS 2 node this process runs, if any.
    pub ros2: Option<Ros2Config>,
}

/// What a node serves.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NodeContents {
    /// Its axes.
    pub plans: Vec<AxisPlan>,
    /// Its calc links.
    pub calcs: Vec<CalcLinkSpec>,
    /// Its value holders.
    pub values: Vec<ValueSpec>,
    /// The controllers its axes are on.
    pub controllers: Vec<ControllerSpec>,
    /// Under access control: a confirmed write is taken on a write key only
    /// (`KeyLayout::write`), which the rules can tell from a read.
    pub guarded: bool,
}

/// A value holder ready to start: its key and the value it holds before any write.
#[derive(Clone, Debug, PartialEq)]
pub struct ValueSpec {
    /// The key it holds the value of.
    pub key: String,
    /// The value before anything is written.
    pub initial: f64,
}
