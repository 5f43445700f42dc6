//! The ROS graph on Zenoh: each node and each of its publishers, subscriptions and services is a
//! liveliness token whose key says what it is (rmw_zenoh_cpp `liveliness_utils.cpp`:
//! `Entity::Entity` builds the key, `mangle_name` the `%` escaping, `qos_to_keyexpr` the QoS
//! string, `Entity::Entity` again the GID). ROS tools list the graph from these tokens.

use crate::names::TypeInfo;

/// What an entity is, by the code its token carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EntityKind {
    /// A node (`NN`).
    Node,
    /// A publisher (`MP`).
    Publisher,
    /// A subscription (`MS`).
    Subscription,
    /// A service server (`SS`).
    ServiceServer,
    /// A service client (`SC`).
    ServiceClient,
}

impl EntityKind {
    fn code(self) -> &'static str {
        match self {
            EntityKind::Node => "NN",
            EntityKind::Publisher => "MP",
            EntityKind::Subscription => "MS",
            EntityKind::ServiceServer => "SS",
            EntityKind::ServiceClient => "SC",
        }
    }
}

/// Whether samples may be lost.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reliability {
    /// Every sample (rmw's RELIABLE, 1; rmw_zenoh's default).
    Reliable,
    /// Samples may be lost (BEST_EFFORT, 2).
    BestEffort,
}

/// Whether a late subscriber gets samples published before it came.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Durability {
    /// It gets the publisher's last `depth` samples (TRANSIENT_LOCAL, 1).
    TransientLocal,
    /// It does not (VOLATILE, 2; rmw_zenoh's default).
    Volatile,
}

/// The QoS an entity declares (history is always KEEP_LAST; deadline, lifespan and
/// liveliness are the defaults: infinite, automatic).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Qos {
    /// Reliability.
    pub reliability: Reliability,
    /// Durability.
    pub durability: Durability,
    /// History depth (KEEP_LAST).
    pub depth: u32,
}

/// rmw_zenoh's default depth: a value equal to it is left out of the token.
const DEFAULT_DEPTH: u32 = 42;

impl Qos {
    /// rclcpp's `QoS(depth)`: reliable, volatile.
    pub fn keep_last(depth: u32) -> Self {
        Self { reliability: Reliability::Reliable, durability: Durability::Volatile, depth }
    }

    /// The token's QoS string, `R:D:H,depth:DLs,DLns:LSs,LSns:LV,LVs,LVns`, each value written
    /// only where it differs from rmw_zenoh's defaults (`QoS(10)` is `::,10:,:,:,,`).
    pub fn token_text(&self) -> String {
        let reliability = match self.reliability {
            Reliability::Reliable => "",
            Reliability::BestEffort => "2",
        };
        let durability = match self.durability {
            Durability::Volatile => "",
            Durability::TransientLocal => "1",
        };
        let depth = if self.depth == DEFAULT_DEPTH || self.depth == 0 { String::new() } else { self.depth.to_string() };
        format!("{reliability}:{durability}:,{depth}:,:,:,,")
    }
}

/// An entity's GID: XXH3-128 (seed 0) of its token key, the low 64 bits first, little-endian.
pub type Gid = [u8; 16];

/// A node, or one of its topics' or services' ends, as the graph names it.
#[derive(Clone, Debug, PartialEq)]
pub struct GraphEntity {
    /// The ROS domain id.
    pub domain: u32,
    /// The Zenoh session's id, as Zenoh prints it (lowercase hex).
    pub zid: String,
    /// The node's id in the session.
    pub node_id: u64,
    /// This entity's id in the session (a node's is its node id).
    pub id: u64,
    /// What it is.
    pub kind: EntityKind,
    /// The security enclave, `/` by default.
    pub enclave: String,
    /// The node's namespace, `/` for none.
    pub namespace: String,
    /// The node's name.
    pub node: String,
    /// A topic's or service's fully qualified name, type and QoS (none for a node).
    pub endpoint: Option<(String, TypeInfo, Qos)>,
}

/// `/` as rmw_zenoh writes it inside a token field.
fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

impl GraphEntity {
    /// The liveliness token's key:
    /// `@ros2_lv/<domain>/<zid>/<nid>/<id>/<kind>/<enclave>/<namespace>/<node>` and, for a
    /// topic or service, `/<name>/<type>/<hash>/<qos>`; `/` inside a field written `%`.
    pub fn token_key(&self) -> String {
        let mut key = format!(
            "@ros2_lv/{}/{}/{}/{}/{}/{}/{}/{}",
            self.domain,
            self.zid,
            self.node_id,
            self.id,
            self.kind.code(),
            mangle(&self.enclave),
            mangle(&self.namespace),
            mangle(&self.node)
        );
        if let Some((name, type_info, qos)) = &self.endpoint {
            let fields = [mangle(name), mangle(type_info.dds_name), mangle(type_info.hash), qos.token_text()];
            for field in fields {
                key.push('/');
                key.push_str(&field);
            }
        }
        key
    }

    /// Its GID, which every sample's attachment carries.
    #[must_use]
    pub fn gid(&self) -> Gid {
        xxhash_rust::xxh3::xxh3_128(self.token_key().as_bytes()).to_le_bytes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::names::JOINT_STATE;

    const ZID: &str = "1f2e3d4c5b6a79880a1b2c3d4e5f6071";

    fn entity(id: u64, kind: EntityKind, endpoint: Option<(String, TypeInfo, Qos)>) -> GraphEntity {
        GraphEntity {
            domain: 0,
            zid: ZID.into(),
            node_id: 0,
            id,
            kind,
            enclave: "/".into(),
            namespace: "/".into(),
            node: "zmotor".into(),
            endpoint,
        }
    }

    fn hex(bytes: &[u8]) -> String {
        bytes.iter().map(|b| format!("{b:02x}")).collect()
    }

    #[test]
    fn qos_strings_leave_rmw_zenohs_defaults_out() {
        assert_eq!(Qos::keep_last(10).token_text(), "::,10:,:,:,,");
        let status = Qos { reliability: Reliability::Reliable, durability: Durability::TransientLocal, depth: 1 };
        assert_eq!(status.token_text(), ":1:,1:,:,:,,");
        let lossy = Qos { reliability: Reliability::BestEffort, durability: Durability::Volatile, depth: 5 };
        assert_eq!(lossy.token_text(), "2::,5:,:,:,,");
        assert_eq!(Qos::keep_last(42).token_text(), "::,:,:,:,,", "the default depth left out");
    }

    /// Keys and GIDs as rmw_zenoh_cpp 0.2.10 builds them (its xxh3 over the same keys).
    #[test]
    fn a_nodes_and_a_publishers_tokens_and_gids_are_rmw_zenohs() {
        let node = entity(0, EntityKind::Node, None);
        assert_eq!(node.token_key(), format!("@ros2_lv/0/{ZID}/0/0/NN/%/%/zmotor"));
        assert_eq!(hex(&node.gid()), "0f1c2dbf8d80e1c989cbcc87b8d39fda");
        let publisher =
            entity(1, EntityKind::Publisher, Some(("/joint_states".into(), JOINT_STATE, Qos::keep_last(10))));
        assert_eq!(
            publisher.token_key(),
            format!(
                "@ros2_lv/0/{ZID}/0/1/MP/%/%/zmotor/%joint_states/sensor_msgs::msg::dds_::JointState_/\
                 RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e/::,10:,:,:,,"
            )
        );
        assert_eq!(hex(&publisher.gid()), "d3b34c37c1b7e033a7ef012982b20e33");
    }
}
