//! Each ready controller launch file (launch/<vendor>.toml) runs as it is against its
//! emulator (`zmotor sim-controller`), and a stock Python Zenoh client moves, jogs, stops and
//! homes an axis through motor/<axis>/... keys; then the emulator is killed (the axis goes to
//! COMM alarm, a move goes nowhere) and started again (the alarm clears, nothing moves by
//! itself). Separate processes, 127.0.0.1 only, a free port for everything.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use zmotor_zenoh::free_local_endpoint;

/// A process of this test, killed when dropped.
struct Running(Child);

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn repo_file(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(path)
}

fn zmotor(args: &[&str]) -> Running {
    let child = Command::new(env!("CARGO_BIN_EXE_zmotor"))
        .args(args)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("zmotor runs");
    Running(child)
}

fn python_has_zenoh() -> bool {
    Command::new("python3").args(["-c", "import zenoh, cbor2"]).output().is_ok_and(|o| o.status.success())
}

/// One phase of tests/python/controller_client.py; panics with what it said if it failed.
fn client(phase: &str, endpoint: &str, axis: &str) {
    let script = repo_file("tests/python/controller_client.py");
    let output = Command::new("python3").arg(script).args([phase, endpoint, axis]).output().expect("python3 runs");
    let said = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success() && said.contains(&format!("{phase} ok")), "{said}");
}

/// The launch file `launch`, whose controller is at `address`, against its emulator.
fn drive_through_loss_and_recovery(protocol: &str, launch: &str, address: &str, axis: &str) {
    if !python_has_zenoh() {
        assert!(std::env::var_os("CI").is_none(), "CI must install eclipse-zenoh and cbor2 for Python (see .ci/run)");
        eprintln!("SKIPPED: python3 with eclipse-zenoh and cbor2 is not installed");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let controller_endpoint = free_local_endpoint().unwrap();
    let controller_address = controller_endpoint.trim_start_matches("tcp/").to_string();
    let text = std::fs::read_to_string(repo_file(launch)).unwrap();
    assert!(text.contains(address), "{launch} names its controller at {address}");
    let file = dir.path().join("launch.toml");
    std::fs::write(&file, text.replace(address, &controller_address)).unwrap();
    let endpoint = free_local_endpoint().unwrap();

    let emulate = || zmotor(&["sim-controller", protocol, "--listen", &controller_address]);
    let emulator = emulate();
    let node = Command::new(env!("CARGO_BIN_EXE_zmotor"))
        .args(["launch", file.to_str().unwrap(), "--listen", &endpoint])
        .env("ZMOTOR_STATE_DIR", dir.path())
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let _node = Running(node);

    client("motion", &endpoint, axis);
    drop(emulator);
    client("lost", &endpoint, axis);
    let _emulator = emulate();
    client("recovered", &endpoint, axis);
}

#[test]
fn acs_mcb4b() {
    drive_through_loss_and_recovery("acs_mcb4b", "launch/acs-mcb4b.toml", "127.0.0.1:4001", "acs1");
}
