//! The stock `eclipse-zenoh` Python client interoperates with a node (tests/python/interop.py),
//! with the Python `tests/run` installs (zmotor_tests::environment).

use zmotor_tests::{environment, fast_axis, TestNode};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_python_client_drives_an_axis() {
    let node = TestNode::start(vec![fast_axis("m1")]).await;
    let mut command = environment::python_script("interop.py");
    command.arg(&node.endpoint);
    let output = tokio::task::spawn_blocking(move || environment::run_script(&mut command)).await.unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "interop.py failed:\n{stdout}\n{stderr}");
    assert!(stdout.contains("python interop: ok"), "{stdout}");
}
