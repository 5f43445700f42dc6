//! `zmotor ros2`, and `[ros2]` in a launch file, make axes the joints of a ROS 2 node on
//! rmw_zenoh's conventions: peers written in Python from rmw_zenoh's rules and the ROS message
//! definitions (tests/python/ros2_*.py, eclipse-zenoh, no zmotor code) find it in the ROS
//! graph, read joint_states, move joints through joint_commands and run FollowJointTrajectory
//! goals to their result and to a cancel. 127.0.0.1 only, a free port.

mod common;

use common::{serve_shipped, Host};
use zmotor_tests::environment;

#[test]
fn a_ros_2_peer_sees_the_joint_and_moves_it() {
    let dir = tempfile::tempdir().unwrap();
    let here = Host::default();
    let (_node, endpoint) = serve_shipped(&here, "launch/sim-axis.toml", "m1", dir.path());
    let ros2 = ["ros2", "--joint", "lift=m1", "--rest-period", "30", "--connect", &endpoint];
    let _ros2 = here.spawn(&ros2, dir.path());
    let output = environment::run_script(environment::python_script("ros2_peer.py").args([&endpoint, "lift"]));
    let said = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success() && said.contains("ros2 peer ok"), "{said}");
}

#[test]
fn a_launch_files_ros_2_joints_follow_commands_and_trajectories_and_stop_on_cancel() {
    let dir = tempfile::tempdir().unwrap();
    let here = Host::default();
    let (_node, endpoint) = serve_shipped(&here, "launch/ros2-joints.toml", "m2", dir.path());
    let output = environment::run_script(environment::python_script("ros2_trajectory.py").args([&endpoint, "/arm"]));
    let said = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success() && said.contains("ros2 trajectory peer ok"), "{said}");
    for (axis, speed) in [("m1", 10.0), ("m2", 30.0)] {
        assert_eq!(here.get(&endpoint, axis, "VELO"), Some(speed), "{axis}: the trajectories' speeds were undone");
    }
}

#[test]
fn a_launch_files_ros_2_joints_of_another_hosts_axes_follow_them() {
    // The shipped file split over two hosts on 127.0.0.1: the ROS face and m1 on "arm" (the
    // router), m2 on "base", started after "arm" serves and its ROS face waits for m2.
    let dir = tempfile::tempdir().unwrap();
    let here = Host::default();
    let (arm, base) = (zmotor_client::free_local_endpoint().unwrap(), zmotor_client::free_local_endpoint().unwrap());
    let text = std::fs::read_to_string(common::repo_file("launch/ros2-joints.toml")).unwrap();
    let split = text
        .replace("[ros2]\n", "[ros2]\nhost = \"arm\"\n")
        .replace("name = \"m1\"\n", "name = \"m1\"\nhost = \"arm\"\n")
        .replace("name = \"m2\"\n", "name = \"m2\"\nhost = \"base\"\n")
        + &format!(
            "\n[hosts.arm]\nmode = \"router\"\nlisten = [\"{arm}\"]\n\
             [hosts.base]\nlisten = [\"{base}\"]\nconnect = [\"{arm}\"]\n"
        );
    let file = dir.path().join("ros2-two-hosts.toml");
    std::fs::write(&file, split).unwrap();
    let file = file.to_str().unwrap();
    let _arm = here.spawn(&["launch", file, "--host", "arm"], &dir.path().join("arm"));
    here.wait_for(&arm, "m1", "DMOV", |v| v == 1.0);
    let _base = here.spawn(&["launch", file, "--host", "base"], &dir.path().join("base"));
    let output = environment::run_script(environment::python_script("ros2_trajectory.py").args([&arm, "/arm"]));
    let said = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success() && said.contains("ros2 trajectory peer ok"), "{said}");
    for (axis, speed) in [("m1", 10.0), ("m2", 30.0)] {
        assert_eq!(here.get(&arm, axis, "VELO"), Some(speed), "{axis}: the trajectories' speeds were undone");
    }
}
