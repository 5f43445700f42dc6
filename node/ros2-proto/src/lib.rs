//! ROS 2 over Zenoh for zmotor axes, sans-IO: what a ROS 2 Jazzy graph on rmw_zenoh expects of a
//! node, so that `ros2 node list`, `ros2 topic echo`, RViz and ros2_control see zmotor's axes as
//! joints with no bridge. The conventions are rmw_zenoh_cpp's (Jazzy release 0.2.10, source
//! `rmw_zenoh_cpp/src/detail/`), cited where each is built:
//!
//! - `names`: the data key expression of a topic or service (`<domain>/<name>/<type>/<hash>`),
//!   DDS-style type names and the REP-2016 type hashes (RIHS01) of the types zmotor uses;
//! - `graph`: the liveliness tokens by which a node and its publishers, subscriptions and
//!   services appear in the ROS graph, their QoS strings, and the GID derived from a token;
//! - `attachment`: the 33 bytes every sample carries (sequence number, source time, GID);
//! - `messages`: the ROS messages as CDR (little-endian, with the encapsulation header);
//! - `joints`: axes as joints: their readbacks as `JointState` in SI units, at the readback
//!   rate while any moves and at a slow rate at rest, and joint commands as axis targets;
//! - `follow`: the messages of `control_msgs/action/FollowJointTrajectory` and `action_msgs`, and
//!   joint_trajectory_controller's `JointTrajectoryControllerState` (Jazzy's and Humble's layouts);
//! - `trajectory`: that action's server: goals checked, executed as timed moves, cancelled;
//! - `lanes`: the writes of both, ordered per axis (a stop never overtaken by a move asked before it).
//!
//! The gateway moves these onto a Zenoh session; nothing here touches one.

mod attachment;
mod follow;
mod graph;
mod joints;
mod lanes;
mod messages;
mod names;
mod trajectory;

pub use attachment::{Attachment, AttachmentError};
pub use follow::{
    CancelGoalRequest, CancelGoalResponse, ControllerState, FeedbackMessage, GetResultRequest, GetResultResponse,
    GoalId, GoalInfo, GoalStatusArray, GoalStatusEntry, JointComponentTolerance, JointTolerance, JointTrajectory,
    JointTrajectoryPoint, MultiDofJointTrajectory, MultiDofJointTrajectoryPoint, Quaternion, RosDuration,
    SendGoalRequest, SendGoalResponse, TrajectoryFeedback, TrajectoryGoal, TrajectoryResult, Transform, Twist, Vector3,
};
pub use graph::{Durability, EntityKind, Gid, GraphEntity, Qos, Reliability};
pub use joints::{Joint, JointCommandError, JointError, JointReading, JointStates, Ramp, Travel};
pub use lanes::{Answered, LaneEvent, LaneWrite, WriteAnswer, WriteId, WriteLanes};
pub use messages::{decode, encode, CdrError, Header, JointState, Time};
pub use names::{
    topic_key, Distribution, TypeInfo, CANCEL_GOAL, CONTROLLER_STATE, FEEDBACK, GET_RESULT, GOAL_STATUS_ARRAY,
    JOINT_STATE, JOINT_TRAJECTORY, SEND_GOAL,
};
pub use trajectory::{status, FollowJointTrajectory, GoalRejection, JointCommand, MoveEnd};
