//! The jog deadman: a jog held by its client's liveliness token ends, as JOGF = 0 would,
//! within a second of the client vanishing: killed (SIGKILL), or cut off by the network (its
//! link pulled in a network namespace); an axis that requires the hold refuses a plain jog.
//! Separate processes; times are taken from a monitor's lines as they arrive.

mod common;

use common::{time_to_release, Host, Namespaces, Running, RELEASE_MARGIN, RELEASE_PROMISE};
use std::process::{Command, Stdio};
use zmotor_client::free_local_endpoint;
use zmotor_tests::environment;

/// A slow jog (1 mm/s) on a long stage, jog_hold as given.
fn jog_stage(jog_hold: &str) -> String {
    format!(
        "[autosave]\nenabled = false\n[[axis]]\nname = \"m1\"\njog_hold = \"{jog_hold}\"\n[axis.fields]\n\
         MRES = 0.001\nVELO = 1\nJVEL = 1\nACCL = 0.1\nDHLM = 1000\nDLLM = -1000\n"
    )
}

/// A node of `jog_stage(jog_hold)` on this host, up: its state directory, process, endpoint.
fn node_here(jog_hold: &str) -> (tempfile::TempDir, Running, String) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("jog.toml");
    std::fs::write(&file, jog_stage(jog_hold)).unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let here = Host::default();
    let node = here.spawn(&["launch", file.to_str().unwrap(), "--listen", &endpoint], dir.path());
    here.wait_for(&endpoint, "m1", "DMOV", |v| v == 1.0);
    (dir, node, endpoint)
}

#[test]
fn a_jog_whose_client_is_killed_ends_within_a_second() {
    let (_dir, _node, endpoint) = node_here("optional");
    let here = Host::default();
    let mut jogger = here.zmotor(&["jog", "m1", "+", "--connect", &endpoint]).stderr(Stdio::null()).spawn().unwrap();
    let pid = jogger.id().to_string();
    let took = time_to_release(&here, &endpoint, || kill(&pid));
    let _ = jogger.wait();
    assert!(took < RELEASE_MARGIN, "released {took:?} after the client was killed (promised: {RELEASE_PROMISE:?})");
}

#[test]
fn a_stock_python_client_holding_a_jog_and_killed_has_its_jog_ended_within_a_second() {
    let (_dir, _node, endpoint) = node_here("required");
    let here = Host::default();
    let mut jogger =
        environment::python_script("hold_jog.py").args([&endpoint, "m1"]).stdout(Stdio::null()).spawn().unwrap();
    let pid = jogger.id().to_string();
    let took = time_to_release(&here, &endpoint, || kill(&pid));
    let _ = jogger.wait();
    assert!(took < RELEASE_MARGIN, "released {took:?} after the client was killed (promised: {RELEASE_PROMISE:?})");
}

/// SIGKILL to a process this test started.
fn kill(pid: &str) {
    Command::new("kill").args(["-KILL", pid]).status().unwrap();
}

#[test]
fn a_jog_whose_client_is_cut_off_ends_within_a_second() {
    let hosts = [("zmn", "10.78.0.1"), ("zmj", "10.78.0.2")];
    let Some(net) = Namespaces::create(&hosts) else {
        return environment::untestable(
            "a_jog_whose_client_is_cut_off_ends_within_a_second",
            "network namespaces",
            common::NETNS_NEEDS,
        );
    };
    let (node_host, client_host) = (net.host(0), net.host(1));
    let endpoint = "tcp/10.78.0.1:7447";
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("jog.toml");
    std::fs::write(&file, jog_stage("required")).unwrap();
    let _node = node_host.spawn(&["launch", file.to_str().unwrap(), "--listen", endpoint], dir.path());
    node_host.wait_for(endpoint, "m1", "DMOV", |v| v == 1.0);
    let mut jogger =
        client_host.zmotor(&["jog", "m1", "+", "--connect", endpoint]).stderr(Stdio::null()).spawn().unwrap();
    let took = time_to_release(&node_host, endpoint, || assert!(net.cut(1), "the link is cut"));
    let _ = jogger.kill();
    let _ = jogger.wait();
    assert!(took < RELEASE_MARGIN, "released {took:?} after the client was cut off (promised: {RELEASE_PROMISE:?})");
}

#[test]
fn an_axis_that_requires_a_hold_refuses_a_plain_jog_and_takes_a_held_one() {
    let (_dir, _node, endpoint) = node_here("required");
    let here = Host::default();
    let refused = here.put(&endpoint, "m1", "JOGF", "1", false).unwrap_err();
    assert!(refused.contains("JOGF: this axis jogs only under a hold"), "{refused}");
    assert_eq!(here.answer(&endpoint, "m1", "MOVN"), 0.0);
    let mut jogger = here.zmotor(&["jog", "m1", "+", "--connect", &endpoint]);
    let jogger = Running(Some(jogger.stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap()));
    here.wait_for(&endpoint, "m1", "MOVN", |v| v == 1.0);
    let (status, _) = jogger.terminate();
    assert!(status.success(), "zmotor jog ends cleanly on SIGTERM");
    here.wait_for(&endpoint, "m1", "DMOV", |v| v == 1.0);
}
