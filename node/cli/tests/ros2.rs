//! `zmotor ros2` makes a node's axes the joints of a ROS 2 node on rmw_zenoh's conventions: a
//! peer written in Python from rmw_zenoh's rules (tests/python/ros2_peer.py, eclipse-zenoh,
//! no zmotor code) finds it in the ROS graph, reads joint_states and moves a joint through
//! joint_commands. 127.0.0.1 only, a free port.

mod common;

use common::{repo_file, Host};
use zmotor_client::free_local_endpoint;
use zmotor_tests::environment;

#[test]
fn a_ros_2_peer_sees_the_joint_and_moves_it() {
    let dir = tempfile::tempdir().unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let here = Host::default();
    let file = dir.path().join("axis.toml");
    std::fs::copy(repo_file("launch/sim-axis.toml"), &file).unwrap();
    let _node = here.spawn(&["launch", file.to_str().unwrap(), "--listen", &endpoint], dir.path());
    here.wait_for(&endpoint, "m1", "DMOV", |v| v == 1.0);
    let _ros2 = here.spawn(&["ros2", "--joint", "lift=m1", "--connect", &endpoint], dir.path());
    let output = environment::python_script("ros2_peer.py").args([&endpoint, "lift"]).output().unwrap();
    let said = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success() && said.contains("ros2 peer ok"), "{said}");
}
