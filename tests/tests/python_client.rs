//! The stock `eclipse-zenoh` Python client interoperates with a node (tests/python/interop.py).
//! `.ci/run` installs the Python packages; elsewhere the test says it is skipped unless they
//! are installed, and under CI their absence is a failure.

use std::process::Command;
use zmotor_tests::{fast_axis, TestNode};

fn python_has_zenoh() -> bool {
    Command::new("python3").args(["-c", "import zenoh, cbor2"]).output().is_ok_and(|o| o.status.success())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_python_client_drives_an_axis() {
    if !python_has_zenoh() {
        assert!(std::env::var_os("CI").is_none(), "CI must install eclipse-zenoh and cbor2 for Python (see .ci/run)");
        eprintln!(
            "SKIPPED: python3 with eclipse-zenoh and cbor2 is not installed (pip install eclipse-zenoh==1.10.2 cbor2)"
        );
        return;
    }
    let node = TestNode::start(vec![fast_axis("m1")]).await;
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/python/interop.py");
    let endpoint = node.endpoint.clone();
    let output = tokio::task::spawn_blocking(move || Command::new("python3").arg(script).arg(endpoint).output())
        .await
        .unwrap()
        .expect("python3 runs");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "interop.py failed:\n{stdout}\n{stderr}");
    assert!(stdout.contains("python interop: ok"), "{stdout}");
}
