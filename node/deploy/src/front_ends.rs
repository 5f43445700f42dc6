//! Where the front-ends serve: Channel Access (`[channel_access]`, `zmotor ca`), the motor
//! screens (`[web]`, `zmotor web`) and the ROS 2 joints (`[ros2]`, `zmotor ros2`).

use std::net::{IpAddr, SocketAddr};
use std::time::Duration;
use zmotor_ros2_proto::Distribution;

/// Where and how the Channel Access front-end serves.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CaConfig {
    /// Prepended to every channel name (`<P><axis>.<FIELD>`).
    pub pv_prefix: String,
    /// The address to listen on.
    pub address: IpAddr,
    /// The UDP port searches come to, and the TCP port of circuits (5064 in EPICS).
    pub port: u16,
}

impl Default for CaConfig {
    /// No prefix, on 127.0.0.1 (a lab serves on 0.0.0.0 or an interface's address), port 5064.
    fn default() -> Self {
        Self { pv_prefix: String::new(), address: IpAddr::from([127, 0, 0, 1]), port: 5064 }
    }
}

/// Where the motor screens are served.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WebConfig {
    /// The HTTP address (127.0.0.1:8080 by default: only this host's browsers).
    pub address: SocketAddr,
    /// Host names browsers may reach the screens by, beside IP addresses, `localhost` and this
    /// machine's name: a page served under any other name (DNS rebinding) is refused.
    pub names: Vec<String>,
}

impl Default for WebConfig {
    fn default() -> Self {
        Self { address: SocketAddr::from(([127, 0, 0, 1], 8080)), names: Vec::new() }
    }
}

/// One axis as a ROS joint.
#[derive(Clone, Debug, PartialEq)]
pub struct JointConfig {
    /// The joint's ROS name.
    pub name: String,
    /// The axis.
    pub axis: String,
    /// SI units (m or rad) per EGU, when not from the axis's EGU.
    pub factor: Option<f64>,
}

/// The ROS 2 node the axes' joints make (`[ros2]`, `zmotor ros2`).
#[derive(Clone, Debug, PartialEq)]
pub struct Ros2Config {
    /// The ROS domain id (ROS_DOMAIN_ID).
    pub domain_id: u32,
    /// The node's namespace, `/` for none.
    pub namespace: String,
    /// The node's name.
    pub node_name: String,
    /// Whose keys: Jazzy's type hashes or Humble's none.
    pub distribution: Distribution,
    /// The joints.
    pub joints: Vec<JointConfig>,
    /// How often the joints' state is published at rest.
    pub rest_period: Duration,
    /// The most joint states a second while joints move (Hz).
    pub max_rate: f64,
}

impl Default for Ros2Config {
    /// Domain 0, the node `/zmotor`, Jazzy, no joints, state every second at rest and at most
    /// 100 times a second while moving.
    fn default() -> Self {
        Self {
            domain_id: 0,
            namespace: "/".into(),
            node_name: "zmotor".into(),
            distribution: Distribution::Jazzy,
            joints: Vec::new(),
            rest_period: Duration::from_secs(1),
            max_rate: 100.0,
        }
    }
}

/// A `[ros2]` configuration ROS would not accept.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Ros2ConfigError {
    /// Not a ROS name: letters, digits and `_`, not starting with a digit.
    #[error("node_name: '{0}' is not a ROS name (letters, digits and _, not starting with a digit)")]
    NodeName(String),
    /// Not a ROS namespace: `/`, or `/`-separated ROS names.
    #[error("namespace: '{0}' is not a ROS namespace ('/' or '/name/...')")]
    Namespace(String),
    /// A joint without a name, or named twice.
    #[error("joint '{0}': a joint needs a name of its own")]
    JointName(String),
    /// A factor that is no positive number.
    #[error("joint '{0}': factor must be a positive number")]
    Factor(String),
    /// No joints.
    #[error("no joints: name at least one axis as a joint")]
    NoJoints,
    /// A rest period that is not a positive number of seconds.
    #[error("rest_period: must be a positive number of seconds")]
    RestPeriod,
    /// A rate that is not a positive number.
    #[error("max_rate: must be a positive number of messages a second")]
    MaxRate,
}

/// Whether `name` is a ROS name token.
fn ros_name(name: &str) -> bool {
    name.chars().next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
}

impl Ros2Config {
    /// The configuration checked: names ROS accepts, joints named once, factors positive.
    pub fn check(&self) -> Result<(), Ros2ConfigError> {
        if !ros_name(&self.node_name) {
            return Err(Ros2ConfigError::NodeName(self.node_name.clone()));
        }
        let namespace_ok =
            self.namespace == "/" || (self.namespace.starts_with('/') && self.namespace[1..].split('/').all(ros_name));
        if !namespace_ok {
            return Err(Ros2ConfigError::Namespace(self.namespace.clone()));
        }
        if self.joints.is_empty() {
            return Err(Ros2ConfigError::NoJoints);
        }
        for (i, joint) in self.joints.iter().enumerate() {
            if joint.name.is_empty() || self.joints[..i].iter().any(|j| j.name == joint.name) {
                return Err(Ros2ConfigError::JointName(joint.name.clone()));
            }
            if joint.factor.is_some_and(|f| !(f.is_finite() && f > 0.0)) {
                return Err(Ros2ConfigError::Factor(joint.name.clone()));
            }
        }
        if self.rest_period.is_zero() {
            return Err(Ros2ConfigError::RestPeriod);
        }
        if !(self.max_rate.is_finite() && self.max_rate > 0.0) {
            return Err(Ros2ConfigError::MaxRate);
        }
        Ok(())
    }
}
