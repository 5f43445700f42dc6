//! A ROS 2 implementation no one here wrote meets zmotor's ROS 2 face: hiroz (ZettaScale's native
//! Rust ROS 2 on Zenoh, rmw_zenoh-compatible) as a ROS node of its own. It finds zmotor's node,
//! topics and action in the ROS graph, follows joint_states during a move, moves two axes with a
//! joint command and with a trajectory on joint_trajectory, and calls FollowJointTrajectory to
//! its result and to a cancel. The messages are
//! declared here from their .msg and .action definitions, and hiroz derives the type hashes of
//! the `msg` ones itself (REP-2016), so a topic whose hash differed from zmotor's would reach
//! nothing. The action's hashes (hiroz derives none for `action` types) are written out as
//! `ros2 interface` gives them for Jazzy. 127.0.0.1, a free port.

mod common;

use common::{serve_shipped, Host};
use hiroz::action::{GoalStatus, ZAction};
use hiroz::context::ZContextBuilder;
use hiroz::entity::{TypeHash, TypeInfo};
use hiroz::qos::{QosHistory, QosProfile};
use hiroz::{Builder, MessageTypeInfo};
use serde::{Deserialize, Serialize};
use std::time::{Duration, Instant};

/// A ROS message's CDR, by serde.
macro_rules! cdr_by_serde {
    ($($name:ident)*) => {$(
        impl hiroz::msg::ZMessage for $name {
            type Serdes = hiroz::msg::SerdeCdrSerdes<$name>;
        }
    )*};
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "builtin_interfaces/msg/Time")]
struct Time {
    sec: i32,
    nanosec: u32,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "builtin_interfaces/msg/Duration")]
struct RosDuration {
    sec: i32,
    nanosec: u32,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "std_msgs/msg/Header")]
struct Header {
    stamp: Time,
    frame_id: String,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "sensor_msgs/msg/JointState")]
struct JointState {
    header: Header,
    name: Vec<String>,
    position: Vec<f64>,
    velocity: Vec<f64>,
    effort: Vec<f64>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "unique_identifier_msgs/msg/UUID")]
struct Uuid {
    uuid: [u8; 16],
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "geometry_msgs/msg/Vector3")]
struct Vector3 {
    x: f64,
    y: f64,
    z: f64,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "geometry_msgs/msg/Quaternion")]
struct Quaternion {
    x: f64,
    y: f64,
    z: f64,
    w: f64,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "geometry_msgs/msg/Transform")]
struct Transform {
    translation: Vector3,
    rotation: Quaternion,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "geometry_msgs/msg/Twist")]
struct Twist {
    linear: Vector3,
    angular: Vector3,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "trajectory_msgs/msg/JointTrajectoryPoint")]
struct JointTrajectoryPoint {
    positions: Vec<f64>,
    velocities: Vec<f64>,
    accelerations: Vec<f64>,
    effort: Vec<f64>,
    time_from_start: RosDuration,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "trajectory_msgs/msg/JointTrajectory")]
struct JointTrajectory {
    header: Header,
    joint_names: Vec<String>,
    points: Vec<JointTrajectoryPoint>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "trajectory_msgs/msg/MultiDOFJointTrajectoryPoint")]
struct MultiDofPoint {
    transforms: Vec<Transform>,
    velocities: Vec<Twist>,
    accelerations: Vec<Twist>,
    time_from_start: RosDuration,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "trajectory_msgs/msg/MultiDOFJointTrajectory")]
struct MultiDofTrajectory {
    header: Header,
    joint_names: Vec<String>,
    points: Vec<MultiDofPoint>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "control_msgs/msg/JointTolerance")]
struct JointTolerance {
    name: String,
    position: f64,
    velocity: f64,
    acceleration: f64,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "control_msgs/msg/JointComponentTolerance")]
struct JointComponentTolerance {
    joint_name: String,
    component: u16,
    position: f64,
    velocity: f64,
    acceleration: f64,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "action_msgs/msg/GoalInfo")]
struct GoalInfo {
    goal_id: Uuid,
    stamp: Time,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "action_msgs/msg/GoalStatus")]
struct GoalStatusEntry {
    goal_info: GoalInfo,
    status: i8,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "action_msgs/msg/GoalStatusArray")]
struct GoalStatusArray {
    status_list: Vec<GoalStatusEntry>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, MessageTypeInfo)]
#[ros_msg(type_name = "control_msgs/msg/JointTrajectoryControllerState")]
struct ControllerState {
    header: Header,
    joint_names: Vec<String>,
    reference: JointTrajectoryPoint,
    feedback: JointTrajectoryPoint,
    error: JointTrajectoryPoint,
    output: JointTrajectoryPoint,
    multi_dof_joint_names: Vec<String>,
    multi_dof_reference: MultiDofPoint,
    multi_dof_feedback: MultiDofPoint,
    multi_dof_error: MultiDofPoint,
    multi_dof_output: MultiDofPoint,
    speed_scaling_factor: f64,
}

// The action's own types (hiroz derives no hash for `action` types; their hashes are in the
// services' and the feedback topic's type information below).
/// `control_msgs/action/FollowJointTrajectory_Goal`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
struct Goal {
    trajectory: JointTrajectory,
    multi_dof_trajectory: MultiDofTrajectory,
    path_tolerance: Vec<JointTolerance>,
    component_path_tolerance: Vec<JointComponentTolerance>,
    goal_tolerance: Vec<JointTolerance>,
    component_goal_tolerance: Vec<JointComponentTolerance>,
    goal_time_tolerance: RosDuration,
}

/// `control_msgs/action/FollowJointTrajectory_Result`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
struct TrajectoryResult {
    error_code: i32,
    error_string: String,
}

/// `control_msgs/action/FollowJointTrajectory_Feedback`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
struct Feedback {
    header: Header,
    joint_names: Vec<String>,
    desired: JointTrajectoryPoint,
    actual: JointTrajectoryPoint,
    error: JointTrajectoryPoint,
    multi_dof_joint_names: Vec<String>,
    multi_dof_desired: MultiDofPoint,
    multi_dof_actual: MultiDofPoint,
    multi_dof_error: MultiDofPoint,
}

cdr_by_serde!(JointState JointTrajectory ControllerState Goal TrajectoryResult Feedback);

/// `control_msgs/action/FollowJointTrajectory`, its services and topics typed as in Jazzy.
struct FollowJointTrajectory;

/// A type as `ros2 interface` hashes it for Jazzy.
fn service(dds_name: &str, rihs: &str) -> TypeInfo {
    TypeInfo::new(dds_name, TypeHash::from_rihs_string(rihs).expect("a RIHS01 hash"))
}

impl ZAction for FollowJointTrajectory {
    type Goal = Goal;
    type Result = TrajectoryResult;
    type Feedback = Feedback;

    fn name() -> &'static str {
        "control_msgs/action/FollowJointTrajectory"
    }

    fn send_goal_type_info() -> TypeInfo {
        service(
            "control_msgs::action::dds_::FollowJointTrajectory_SendGoal_",
            "RIHS01_b13789dddc325a7a962825c45e28c77d37237ec129dd0c34dc5994562938c57f",
        )
    }

    fn get_result_type_info() -> TypeInfo {
        service(
            "control_msgs::action::dds_::FollowJointTrajectory_GetResult_",
            "RIHS01_e3ceb38e3e1867c8dc0f46014df26e90eb93422f27e9e97f936e07f94be4bc8b",
        )
    }

    fn cancel_goal_type_info() -> TypeInfo {
        service(
            "action_msgs::srv::dds_::CancelGoal_",
            "RIHS01_573d8b0a534451d7bc2ac8c5ffde8ac14b8593b7001175d0cd6516dcbeb8689a",
        )
    }

    fn feedback_type_info() -> TypeInfo {
        service(
            "control_msgs::action::dds_::FollowJointTrajectory_FeedbackMessage_",
            "RIHS01_80398fcb9674a79081a9906e2ccf0c804dd7cb15e22e362e606ee87186beab71",
        )
    }

    fn status_type_info() -> TypeInfo {
        TypeInfo::new(GoalStatusArray::type_name(), GoalStatusArray::type_hash())
    }
}

fn at(seconds: f64) -> RosDuration {
    RosDuration { sec: seconds.trunc() as i32, nanosec: (seconds.fract() * 1e9).round() as u32 }
}

fn trajectory(names: &[&str], points: &[(f64, &[f64])]) -> Goal {
    let points = points
        .iter()
        .map(|(t, positions)| JointTrajectoryPoint {
            positions: positions.to_vec(),
            time_from_start: at(*t),
            ..JointTrajectoryPoint::default()
        })
        .collect();
    let names = names.iter().map(|n| n.to_string()).collect();
    Goal { trajectory: JointTrajectory { joint_names: names, points, ..JointTrajectory::default() }, ..Goal::default() }
}

/// The positions of the last joint state, by joint.
fn positions(state: &JointState) -> Vec<(String, f64)> {
    state.name.iter().cloned().zip(state.position.iter().copied()).collect()
}

/// The messages declared here are Jazzy's: hiroz's hashes of them are the ones in zmotor's keys
/// (joint_states, joint_commands, the action's status) and inside its trajectories.
#[test]
fn the_messages_declared_here_hash_as_jazzys() {
    let rihs = |hash: TypeHash| hash.to_rihs_string();
    assert_eq!(
        rihs(JointState::type_hash()),
        "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
    );
    assert_eq!(
        rihs(GoalStatusArray::type_hash()),
        "RIHS01_6c1684b00f177d37438febe6e709fc4e2b0d4248dca4854946f9ed8b30cda83e"
    );
    assert_eq!(
        rihs(JointTrajectory::type_hash()),
        "RIHS01_179b33eba59d676f6d967ac71fe35e7ca2f64b2f3928f4a018cec115e213796e"
    );
    assert_eq!(
        rihs(ControllerState::type_hash()),
        "RIHS01_51d8dd89cc624cbe9daaeeb4d80d6de9b86168ffdc3be41fefc0953e3c26e480"
    );
}

#[test]
fn a_hiroz_node_finds_the_joints_follows_them_commands_them_and_runs_trajectories() {
    let dir = tempfile::tempdir().unwrap();
    let (_node, endpoint) = serve_shipped(&Host::default(), "launch/ros2-joints.toml", "m2", dir.path());
    let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    runtime.block_on(ros_peer(&endpoint)).unwrap();
}

async fn ros_peer(endpoint: &str) -> hiroz::Result<()> {
    let context = ZContextBuilder::default()
        .with_mode("client")
        .with_connect_endpoints([endpoint])
        .with_json("scouting/multicast/enabled", false)
        .build()?;
    let node = context.create_node("hiroz_peer").build()?;

    // The graph: the node, its topics with their types, its action.
    let deadline = Instant::now() + Duration::from_secs(20);
    let wanted_topics = [
        ("/arm/joint_states", "sensor_msgs::msg::dds_::JointState_"),
        ("/arm/joint_commands", "sensor_msgs::msg::dds_::JointState_"),
        ("/arm/joint_trajectory", "trajectory_msgs::msg::dds_::JointTrajectory_"),
        ("/arm/controller_state", "control_msgs::msg::dds_::JointTrajectoryControllerState_"),
    ];
    let (mut nodes, mut topics, mut actions) = (Vec::new(), Vec::new(), Vec::new());
    let listed = |topics: &[(String, String)], (topic, type_name): (&str, &str)| {
        topics.iter().any(|(t, ty)| t == topic && ty == type_name)
    };
    while Instant::now() < deadline {
        nodes = node.graph().get_node_names();
        topics = node.graph().get_topic_names_and_types();
        actions = node.graph().get_action_names_and_types();
        let all_topics = wanted_topics.iter().all(|wanted| listed(&topics, *wanted));
        if nodes.iter().any(|(n, _)| n == "zmotor") && all_topics && !actions.is_empty() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    assert!(nodes.contains(&("zmotor".to_string(), "/arm".to_string())), "{nodes:?}");
    for wanted in wanted_topics {
        assert!(listed(&topics, wanted), "{wanted:?} in {topics:?}");
    }
    // hiroz names an action's type by its feedback message's.
    let action =
        |(a, ty): &(String, String)| a == "/arm/follow_joint_trajectory" && ty.contains("FollowJointTrajectory_");
    assert!(actions.iter().any(action), "{actions:?}");

    // joint_states followed, joint_commands moving two axes.
    let states = node.create_sub::<JointState>("/arm/joint_states").build()?;
    let commands = node.create_pub::<JointState>("/arm/joint_commands").build()?;
    assert!(commands.wait_for_subscription(1, Duration::from_secs(10)).await, "zmotor subscribes joint_commands");
    let command =
        JointState { name: vec!["lift".into(), "turn".into()], position: vec![0.003, 0.2], ..JointState::default() };
    commands.async_publish(&command).await?;
    let mut last = JointState::default();
    let mut moving_seen = false;
    let deadline = Instant::now() + Duration::from_secs(15);
    while Instant::now() < deadline {
        let Ok(state) = states.recv_timeout(Duration::from_secs(2)) else { continue };
        moving_seen |= state.velocity.iter().any(|v| *v != 0.0);
        last = state;
        let at = positions(&last);
        if (at[0].1 - 0.003).abs() < 1.5e-6 && (at[1].1 - 0.2).abs() < 2.7e-5 {
            break;
        }
    }
    assert_eq!(last.name, ["lift", "turn"]);
    assert!((last.position[0] - 0.003).abs() < 1.5e-6 && (last.position[1] - 0.2).abs() < 2.7e-5, "{last:?}");
    assert!(moving_seen, "joint_states carried velocities while the joints moved");

    // A trajectory on joint_trajectory, as joint_trajectory_controller takes one.
    let trajectories = node.create_pub::<JointTrajectory>("/arm/joint_trajectory").build()?;
    assert!(trajectories.wait_for_subscription(1, Duration::from_secs(10)).await, "zmotor subscribes joint_trajectory");
    trajectories.async_publish(&trajectory(&["lift", "turn"], &[(0.5, &[0.002, 0.25])]).trajectory).await?;
    let deadline = Instant::now() + Duration::from_secs(15);
    while Instant::now() < deadline {
        let Ok(state) = states.recv_timeout(Duration::from_secs(2)) else { continue };
        last = state;
        let at = positions(&last);
        if (at[0].1 - 0.002).abs() < 1.5e-6 && (at[1].1 - 0.25).abs() < 2.7e-5 {
            break;
        }
    }
    assert!((last.position[0] - 0.002).abs() < 1.5e-6 && (last.position[1] - 0.25).abs() < 2.7e-5, "{last:?}");

    // A three-point trajectory to its result.
    let client = node.create_action_client::<FollowJointTrajectory>("/arm/follow_joint_trajectory").build()?;
    assert!(client.wait_for_server(Duration::from_secs(10)).await, "the action server is found");
    let goal = trajectory(&["lift", "turn"], &[(1.0, &[0.006, 0.4]), (2.0, &[0.009, 0.3]), (3.0, &[0.004, 0.6])]);
    // Every state kept (hiroz's default keeps the last 10), read once the goal has ended.
    let every = QosProfile { history: QosHistory::KeepAll, ..QosProfile::default() };
    let controller = node.create_sub::<ControllerState>("/arm/controller_state").with_qos(every).build()?;
    while controller.recv_timeout(Duration::from_millis(100)).is_ok() {}
    let started = Instant::now();
    let mut handle = client.send_goal(goal).await?;
    let mut feedback = handle.feedback().expect("a feedback stream");
    let result = handle.result_with_timeout(Duration::from_secs(60)).await?;
    assert_eq!(result, TrajectoryResult { error_code: 0, error_string: String::new() });
    assert!(started.elapsed() > Duration::from_millis(2500), "the points took their time: {:?}", started.elapsed());
    let seen = feedback.try_recv().expect("feedback while it ran");
    assert_eq!(seen.joint_names, ["lift", "turn"]);
    // The controller's state while it ran: the lift's reference on the trajectory's lines (from
    // 2 mm: 4, 3 and -5 mm/s), moving with its stamp at its line's velocity, and ahead of the
    // lift at some time (the record ramps up); each error its reference − feedback; at the end
    // the last point held.
    let slopes = [0.004, 0.003, -0.005];
    let (mut states_seen, mut ahead, mut lines, mut last_state) = (0, false, Vec::new(), ControllerState::default());
    let stamp = |s: &ControllerState| f64::from(s.header.stamp.sec) + f64::from(s.header.stamp.nanosec) * 1e-9;
    while let Ok(state) = controller.recv_timeout(Duration::from_millis(100)) {
        assert_eq!(state.joint_names, ["lift", "turn"]);
        for k in 0..2 {
            let error = state.reference.positions[k] - state.feedback.positions[k];
            assert!((state.error.positions[k] - error).abs() < 1e-12, "{state:?}");
        }
        let speed = state.reference.velocities[0];
        if let Some(line) = slopes.iter().position(|slope| (speed - slope).abs() < 1e-5) {
            let before = (last_state.reference.velocities.first() == Some(&speed)).then_some(&last_state);
            if let Some(before) = before {
                let moved = state.reference.positions[0] - before.reference.positions[0];
                let expected = speed * (stamp(&state) - stamp(before));
                assert!((moved - expected).abs() < 1e-7, "along its line: {moved} for {expected}: {state:?}");
            }
            if !lines.contains(&line) {
                lines.push(line);
            }
        }
        ahead |= state.error.positions[0].abs() > 1e-4;
        states_seen += 1;
        last_state = state;
    }
    assert!(states_seen > 10 && ahead, "{states_seen} controller states, the reference ahead of the lift: {ahead}");
    assert!(lines.len() >= 2, "the reference followed the trajectory's lines: {lines:?}");
    let ended = &last_state.reference.positions;
    assert!((ended[0] - 0.004).abs() < 1e-9 && (ended[1] - 0.6).abs() < 1e-6, "{last_state:?}");

    // A long one, cancelled on the way: the lift stops short.
    let mut handle = client.send_goal(trajectory(&["lift"], &[(20.0, &[0.050])])).await?;
    let mut status = handle.status_watch().expect("a status watch");
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let cancel = handle.cancel().await?;
    assert_eq!(cancel.return_code, 0, "the cancel is taken");
    let deadline = Instant::now() + Duration::from_secs(15);
    while *status.borrow() != GoalStatus::Canceled && Instant::now() < deadline {
        let _ = tokio::time::timeout(Duration::from_millis(500), status.changed()).await;
    }
    assert_eq!(*status.borrow(), GoalStatus::Canceled);
    tokio::time::sleep(Duration::from_secs(1)).await;
    while states.recv_timeout(Duration::from_millis(100)).is_ok() {}
    let stopped = states.recv_timeout(Duration::from_secs(3))?;
    assert!(stopped.position[0] > 0.005 && stopped.position[0] < 0.04, "{stopped:?}");
    Ok(())
}
