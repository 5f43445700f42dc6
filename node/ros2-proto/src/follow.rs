//! The messages of `control_msgs/action/FollowJointTrajectory` (Jazzy, control_msgs 5) and of
//! the action protocol around it (`action_msgs`: goal ids, statuses, cancel), laid out as their
//! `.msg`, `.srv` and `.action` files declare them, field for field, so the CDR matches what
//! MoveIt and ros2_control send. An action on rmw_zenoh is three services and two topics under
//! `<action>/_action/`; the request and response of each service are these structs.

use crate::messages::{encode, Header, Time};
use crate::names::Distribution;
use serde::{Deserialize, Serialize};

/// `builtin_interfaces/msg/Duration`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RosDuration {
    /// Whole seconds (may be negative).
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl RosDuration {
    /// As a `Duration`, none when negative.
    #[must_use]
    pub fn to_duration(self) -> Option<std::time::Duration> {
        let sec = u64::try_from(self.sec).ok()?;
        Some(std::time::Duration::new(sec, 0) + std::time::Duration::from_nanos(u64::from(self.nanosec)))
    }
}

/// `unique_identifier_msgs/msg/UUID`: a goal's id, 16 bytes with no length before them.
pub type GoalId = [u8; 16];

/// `trajectory_msgs/msg/JointTrajectoryPoint`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointTrajectoryPoint {
    /// One position per joint (m or rad).
    pub positions: Vec<f64>,
    /// Velocities, empty or one per joint.
    pub velocities: Vec<f64>,
    /// Accelerations, empty or one per joint.
    pub accelerations: Vec<f64>,
    /// Efforts, empty or one per joint.
    pub effort: Vec<f64>,
    /// When the point is to be reached, from the trajectory's start.
    pub time_from_start: RosDuration,
}

/// `trajectory_msgs/msg/JointTrajectory`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointTrajectory {
    /// Its stamp says when it starts (zero: at once).
    pub header: Header,
    /// The joints, in the order of each point's values.
    pub joint_names: Vec<String>,
    /// The points, in time order.
    pub points: Vec<JointTrajectoryPoint>,
}

/// `geometry_msgs/msg/Vector3`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

/// `geometry_msgs/msg/Transform`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    /// Translation.
    pub translation: Vector3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `geometry_msgs/msg/Twist`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    /// Linear.
    pub linear: Vector3,
    /// Angular.
    pub angular: Vector3,
}

/// `trajectory_msgs/msg/MultiDOFJointTrajectoryPoint`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MultiDofJointTrajectoryPoint {
    /// Transforms.
    pub transforms: Vec<Transform>,
    /// Velocities.
    pub velocities: Vec<Twist>,
    /// Accelerations.
    pub accelerations: Vec<Twist>,
    /// When.
    pub time_from_start: RosDuration,
}

/// `trajectory_msgs/msg/MultiDOFJointTrajectory`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MultiDofJointTrajectory {
    /// Stamp and frame.
    pub header: Header,
    /// Joints.
    pub joint_names: Vec<String>,
    /// Points.
    pub points: Vec<MultiDofJointTrajectoryPoint>,
}

/// `control_msgs/msg/JointTolerance`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointTolerance {
    /// The joint.
    pub name: String,
    /// Position tolerance (0: the controller's default, negative: none).
    pub position: f64,
    /// Velocity tolerance.
    pub velocity: f64,
    /// Acceleration tolerance.
    pub acceleration: f64,
}

/// `control_msgs/msg/JointComponentTolerance`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointComponentTolerance {
    /// The joint.
    pub joint_name: String,
    /// Which component (X_AXIS = 1 …).
    pub component: u16,
    /// Position tolerance.
    pub position: f64,
    /// Velocity tolerance.
    pub velocity: f64,
    /// Acceleration tolerance.
    pub acceleration: f64,
}

/// `control_msgs/action/FollowJointTrajectory` goal.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrajectoryGoal {
    /// The joints' trajectory.
    pub trajectory: JointTrajectory,
    /// A multi-DOF trajectory (zmotor's joints are single axes: must be empty).
    pub multi_dof_trajectory: MultiDofJointTrajectory,
    /// Tolerances along the way.
    pub path_tolerance: Vec<JointTolerance>,
    /// The same for multi-DOF joints.
    pub component_path_tolerance: Vec<JointComponentTolerance>,
    /// Tolerances at the end.
    pub goal_tolerance: Vec<JointTolerance>,
    /// The same for multi-DOF joints.
    pub component_goal_tolerance: Vec<JointComponentTolerance>,
    /// How late the end may be.
    pub goal_time_tolerance: RosDuration,
}

/// `control_msgs/action/FollowJointTrajectory` result.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrajectoryResult {
    /// 0 SUCCESSFUL, -1 INVALID_GOAL, -2 INVALID_JOINTS, -3 OLD_HEADER_TIMESTAMP,
    /// -4 PATH_TOLERANCE_VIOLATED, -5 GOAL_TOLERANCE_VIOLATED.
    pub error_code: i32,
    /// What went wrong, in words.
    pub error_string: String,
}

/// `control_msgs/action/FollowJointTrajectory` feedback.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrajectoryFeedback {
    /// When.
    pub header: Header,
    /// The joints.
    pub joint_names: Vec<String>,
    /// Where they should be now.
    pub desired: JointTrajectoryPoint,
    /// Where they are.
    pub actual: JointTrajectoryPoint,
    /// desired − actual (reference − feedback).
    pub error: JointTrajectoryPoint,
    /// Multi-DOF joints (none).
    pub multi_dof_joint_names: Vec<String>,
    /// Their desired state.
    pub multi_dof_desired: MultiDofJointTrajectoryPoint,
    /// Their actual state.
    pub multi_dof_actual: MultiDofJointTrajectoryPoint,
    /// Their error.
    pub multi_dof_error: MultiDofJointTrajectoryPoint,
}

/// The `send_goal` request.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SendGoalRequest {
    /// The id the client chose.
    pub goal_id: GoalId,
    /// The goal.
    pub goal: TrajectoryGoal,
}

/// The `send_goal` response.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SendGoalResponse {
    /// Whether the goal was accepted.
    pub accepted: bool,
    /// When.
    pub stamp: Time,
}

/// The `get_result` request.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct GetResultRequest {
    /// The goal.
    pub goal_id: GoalId,
}

/// The `get_result` response, sent when the goal has ended.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GetResultResponse {
    /// Its final status (`GoalStatus`'s codes; 0 for a goal not known).
    pub status: i8,
    /// Its result.
    pub result: TrajectoryResult,
}

/// The `feedback` topic's message.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FeedbackMessage {
    /// The goal.
    pub goal_id: GoalId,
    /// Its feedback.
    pub feedback: TrajectoryFeedback,
}

/// `control_msgs/msg/JointTrajectoryControllerState` (Jazzy, control_msgs 5.3 and later), what
/// joint_trajectory_controller publishes on `~/controller_state`: where the joints should be, where
/// they are, and the difference. `ControllerState::encode` lays it out for a distribution.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ControllerState {
    /// When.
    pub header: Header,
    /// Every joint of the controller.
    pub joint_names: Vec<String>,
    /// Where they should be (the trajectory's sample, or the position held).
    pub reference: JointTrajectoryPoint,
    /// Where they are.
    pub feedback: JointTrajectoryPoint,
    /// reference − feedback.
    pub error: JointTrajectoryPoint,
    /// What the hardware was commanded: where each joint's axis is sent (its VAL).
    pub output: JointTrajectoryPoint,
    /// Multi-DOF joints (none).
    pub multi_dof_joint_names: Vec<String>,
    /// Their reference.
    pub multi_dof_reference: MultiDofJointTrajectoryPoint,
    /// Their feedback.
    pub multi_dof_feedback: MultiDofJointTrajectoryPoint,
    /// Their error.
    pub multi_dof_error: MultiDofJointTrajectoryPoint,
    /// Their output.
    pub multi_dof_output: MultiDofJointTrajectoryPoint,
    /// The speed scaling in force (1: none).
    pub speed_scaling_factor: f64,
}

/// Humble's `JointTrajectoryControllerState` (control_msgs 4): `desired` and `actual` beside
/// `reference` and `feedback` (its controller fills both pairs alike), no speed scaling.
#[derive(Serialize)]
struct HumbleControllerState<'a> {
    header: &'a Header,
    joint_names: &'a [String],
    reference: &'a JointTrajectoryPoint,
    feedback: &'a JointTrajectoryPoint,
    error: &'a JointTrajectoryPoint,
    output: &'a JointTrajectoryPoint,
    desired: &'a JointTrajectoryPoint,
    actual: &'a JointTrajectoryPoint,
    multi_dof_joint_names: &'a [String],
    multi_dof_reference: &'a MultiDofJointTrajectoryPoint,
    multi_dof_feedback: &'a MultiDofJointTrajectoryPoint,
    multi_dof_error: &'a MultiDofJointTrajectoryPoint,
    multi_dof_output: &'a MultiDofJointTrajectoryPoint,
    multi_dof_desired: &'a MultiDofJointTrajectoryPoint,
    multi_dof_actual: &'a MultiDofJointTrajectoryPoint,
}

impl ControllerState {
    /// The message as a ROS payload of `distribution`'s layout.
    #[must_use]
    pub fn encode(&self, distribution: Distribution) -> Vec<u8> {
        match distribution {
            Distribution::Jazzy => encode(self),
            Distribution::Humble => encode(&HumbleControllerState {
                header: &self.header,
                joint_names: &self.joint_names,
                reference: &self.reference,
                feedback: &self.feedback,
                error: &self.error,
                output: &self.output,
                desired: &self.reference,
                actual: &self.feedback,
                multi_dof_joint_names: &self.multi_dof_joint_names,
                multi_dof_reference: &self.multi_dof_reference,
                multi_dof_feedback: &self.multi_dof_feedback,
                multi_dof_error: &self.multi_dof_error,
                multi_dof_output: &self.multi_dof_output,
                multi_dof_desired: &self.multi_dof_reference,
                multi_dof_actual: &self.multi_dof_feedback,
            }),
        }
    }
}

/// `action_msgs/msg/GoalInfo`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct GoalInfo {
    /// The goal.
    pub goal_id: GoalId,
    /// When it was accepted.
    pub stamp: Time,
}

/// `action_msgs/msg/GoalStatus`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct GoalStatusEntry {
    /// The goal.
    pub goal_info: GoalInfo,
    /// Its status.
    pub status: i8,
}

/// `action_msgs/msg/GoalStatusArray`, the `status` topic's message.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct GoalStatusArray {
    /// Every goal the server knows.
    pub status_list: Vec<GoalStatusEntry>,
}

/// `action_msgs/srv/CancelGoal` request: a zero id and stamp cancel every goal, a zero id and
/// a stamp those accepted at or before it, an id that goal (and those before the stamp).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CancelGoalRequest {
    /// Which goals.
    pub goal_info: GoalInfo,
}

/// `action_msgs/srv/CancelGoal` response.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CancelGoalResponse {
    /// 0 NONE, 1 REJECTED, 2 UNKNOWN_GOAL_ID, 3 GOAL_TERMINATED.
    pub return_code: i8,
    /// The goals now cancelling.
    pub goals_canceling: Vec<GoalInfo>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::messages::{decode, encode};

    /// A goal's CDR written by hand from the rules (`messages` has them): the 16 id bytes
    /// unprefixed, then the trajectory, each sequence its count first, each f64 aligned to 8
    /// from after the encapsulation header.
    #[test]
    fn a_send_goal_request_is_cdr_field_for_field() {
        let request = SendGoalRequest {
            goal_id: [7; 16],
            goal: TrajectoryGoal {
                trajectory: JointTrajectory {
                    header: Header::default(),
                    joint_names: vec!["j".into()],
                    points: vec![JointTrajectoryPoint {
                        positions: vec![0.5],
                        time_from_start: RosDuration { sec: 2, nanosec: 0 },
                        ..JointTrajectoryPoint::default()
                    }],
                },
                ..TrajectoryGoal::default()
            },
        };
        let expected: Vec<u8> = [
            &[0x00, 0x01, 0x00, 0x00][..],
            &[7; 16],                     // goal_id
            &[0; 8],                      // stamp
            &[1, 0, 0, 0, 0, 0, 0, 0],    // frame_id "": its length, its NUL, padding
            &[1, 0, 0, 0],                // one joint name
            &[2, 0, 0, 0, b'j', 0, 0, 0], // "j", padding
            &[1, 0, 0, 0],                // one point
            &[1, 0, 0, 0],                // one position
            &[0; 4],                      // padding: the f64 at 56
            &0.5f64.to_le_bytes(),
            &[0; 12],                  // no velocities, accelerations, effort
            &[2, 0, 0, 0, 0, 0, 0, 0], // time_from_start
            &[0; 8],                   // multi-DOF: stamp
            &[1, 0, 0, 0, 0, 0, 0, 0], // its frame_id ""
            &[0; 8],                   // no names, no points
            &[0; 16],                  // four empty tolerance lists
            &[0; 8],                   // goal_time_tolerance
        ]
        .concat();
        assert_eq!(encode(&request), expected);
        assert_eq!(decode::<SendGoalRequest>(&expected, "SendGoal request").unwrap(), request);
    }
}
