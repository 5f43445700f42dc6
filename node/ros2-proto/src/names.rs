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

/// The ROS 2 distribution whose conventions the keys follow.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Distribution {
    /// Jazzy (and later): REP-2016 type hashes in keys and tokens.
    #[default]
    Jazzy,
    /// Humble: its rmw_zenoh writes `TypeHashNotSupported` where the hash goes.
    Humble,
}

impl Distribution {
    /// By its name (`jazzy`, `humble`).
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "jazzy" => Some(Distribution::Jazzy),
            "humble" => Some(Distribution::Humble),
            _ => None,
        }
    }
}

impl TypeInfo {
    /// The type as `distribution` names it.
    #[must_use]
    pub fn in_distribution(self, distribution: Distribution) -> Self {
        match distribution {
            Distribution::Jazzy => self,
            Distribution::Humble => Self { hash: "TypeHashNotSupported", ..self },
        }
    }
}

/// `sensor_msgs/msg/JointState` in Jazzy (the hash `ros2 topic info -v` shows for it).
pub const JOINT_STATE: TypeInfo = TypeInfo {
    dds_name: "sensor_msgs::msg::dds_::JointState_",
    hash: "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
};

/// `trajectory_msgs/msg/JointTrajectory` in Jazzy (joint_trajectory_controller's topic).
pub const JOINT_TRAJECTORY: TypeInfo = TypeInfo {
    dds_name: "trajectory_msgs::msg::dds_::JointTrajectory_",
    hash: "RIHS01_179b33eba59d676f6d967ac71fe35e7ca2f64b2f3928f4a018cec115e213796e",
};

/// `control_msgs/msg/JointTrajectoryControllerState` in Jazzy (joint_trajectory_controller's
/// `~/controller_state`; control_msgs 5.3 and later, with `speed_scaling_factor`).
pub const CONTROLLER_STATE: TypeInfo = TypeInfo {
    dds_name: "control_msgs::msg::dds_::JointTrajectoryControllerState_",
    hash: "RIHS01_51d8dd89cc624cbe9daaeeb4d80d6de9b86168ffdc3be41fefc0953e3c26e480",
};

/// `control_msgs/action/FollowJointTrajectory`'s `send_goal` service.
pub const SEND_GOAL: TypeInfo = TypeInfo {
    dds_name: "control_msgs::action::dds_::FollowJointTrajectory_SendGoal_",
    hash: "RIHS01_b13789dddc325a7a962825c45e28c77d37237ec129dd0c34dc5994562938c57f",
};

/// `control_msgs/action/FollowJointTrajectory`'s `get_result` service.
pub const GET_RESULT: TypeInfo = TypeInfo {
    dds_name: "control_msgs::action::dds_::FollowJointTrajectory_GetResult_",
    hash: "RIHS01_e3ceb38e3e1867c8dc0f46014df26e90eb93422f27e9e97f936e07f94be4bc8b",
};

/// `control_msgs/action/FollowJointTrajectory`'s `feedback` topic.
pub const FEEDBACK: TypeInfo = TypeInfo {
    dds_name: "control_msgs::action::dds_::FollowJointTrajectory_FeedbackMessage_",
    hash: "RIHS01_80398fcb9674a79081a9906e2ccf0c804dd7cb15e22e362e606ee87186beab71",
};

/// Every action's `cancel_goal` service, `action_msgs/srv/CancelGoal`.
pub const CANCEL_GOAL: TypeInfo = TypeInfo {
    dds_name: "action_msgs::srv::dds_::CancelGoal_",
    hash: "RIHS01_573d8b0a534451d7bc2ac8c5ffde8ac14b8593b7001175d0cd6516dcbeb8689a",
};

/// Every action's `status` topic, `action_msgs/msg/GoalStatusArray`.
pub const GOAL_STATUS_ARRAY: TypeInfo = TypeInfo {
    dds_name: "action_msgs::msg::dds_::GoalStatusArray_",
    hash: "RIHS01_6c1684b00f177d37438febe6e709fc4e2b0d4248dca4854946f9ed8b30cda83e",
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
        assert_eq!(
            topic_key(0, "/joint_states", &JOINT_STATE.in_distribution(Distribution::Humble)),
            "0/joint_states/sensor_msgs::msg::dds_::JointState_/TypeHashNotSupported"
        );
    }
}
