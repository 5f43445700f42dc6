//! Names on the wire: rmw_zenoh's data key expression and DDS-style type names
//! (`liveliness_utils.cpp`, `Entity` constructor: `topic_keyexpr_`; `type_support_common.cpp`).

/// A ROS type as the graph names it: its DDS-style name and its REP-2016 hash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TypeInfo {
    /// `<package>::<msg|srv|action>::dds_::<Name>_`.
    pub dds_name: &'static str,
    /// `RIHS01_` and 64 lowercase hex digits.
    pub hash: &'static str,
}

/// `sensor_msgs/msg/JointState` in Jazzy (the hash `ros2 topic info -v` shows for it).
pub const JOINT_STATE: TypeInfo = TypeInfo {
    dds_name: "sensor_msgs::msg::dds_::JointState_",
    hash: "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
};

/// The key expression of a topic's (or a service's) samples: `<domain>/<name>/<type>/<hash>`,
/// the fully qualified name with one leading and one trailing slash stripped, inner slashes
/// kept (`/ns/joint_states` → `0/ns/joint_states/...`).
pub fn topic_key(domain: u32, name: &str, type_info: &TypeInfo) -> String {
    format!("{domain}/{}/{}/{}", strip_slashes(name), type_info.dds_name, type_info.hash)
}

/// One leading and one trailing `/` removed, as rmw_zenoh's `strip_slashes`.
pub(crate) fn strip_slashes(name: &str) -> &str {
    let name = name.strip_prefix('/').unwrap_or(name);
    name.strip_suffix('/').unwrap_or(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_topics_key_is_its_domain_name_type_and_hash() {
        assert_eq!(
            topic_key(0, "/joint_states", &JOINT_STATE),
            "0/joint_states/sensor_msgs::msg::dds_::JointState_/\
             RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
        );
        assert!(topic_key(7, "/robot/arm/joint_states", &JOINT_STATE).starts_with("7/robot/arm/joint_states/"));
    }
}
