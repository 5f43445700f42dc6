//! `zmotor ca` serves a node's axes to stock EPICS clients (pyepics, ophyd under bluesky,
//! caproto): tests/python/ca_clients.py, run against a node and the front-end on 127.0.0.1.

mod common;

use common::{repo_file, time_to_release, Host, Lines, Namespaces, Running, RELEASE_MARGIN, RELEASE_PROMISE};
use std::process::Command;
use std::process::Stdio;
use std::time::Duration;
use zmotor_client::free_local_endpoint;
use zmotor_tests::environment;

/// The client script at `stage`, pointed at the front-end on `port`.
fn script(port: u16, stage: &str) -> Command {
    let mut command = environment::python_script("ca_clients.py");
    command.arg(stage).env("EPICS_CA_ADDR_LIST", format!("127.0.0.1:{port}")).env("EPICS_CA_AUTO_ADDR_LIST", "NO");
    command
}

fn clients(port: u16, stage: &str) -> String {
    let output = environment::run_script(&mut script(port, stage));
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    assert!(output.status.success(), "{stage}: {stdout}\n{}", String::from_utf8_lossy(&output.stderr));
    stdout
}

/// A node of launch/sim-axis.toml and the front-end before it, run by `zmotor ca` or by the
/// launch file's `[channel_access]`: the processes, the node's endpoint, the front-end's port.
fn served(dir: &std::path::Path, by_launch_file: bool) -> (Running, Option<Running>, String, u16) {
    let endpoint = free_local_endpoint().unwrap();
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let here = Host::default();
    let mut launch = std::fs::read_to_string(repo_file("launch/sim-axis.toml")).unwrap();
    if by_launch_file {
        launch += &format!("\n[channel_access]\nport = {port}\n");
    }
    let file = dir.join("axis.toml");
    std::fs::write(&file, launch).unwrap();
    let node = here.spawn(&["launch", file.to_str().unwrap(), "--listen", &endpoint], dir);
    here.wait_for(&endpoint, "m1", "DMOV", |v| v == 1.0);
    let ca = (!by_launch_file).then(|| here.spawn(&["ca", "--port", &port.to_string(), "--connect", &endpoint], dir));
    (node, ca, endpoint, port)
}

#[test]
fn stock_channel_access_clients_read_move_monitor_and_scan_an_axis() {
    let dir = tempfile::tempdir().unwrap();
    let (node, _ca, _, port) = served(dir.path(), false);

    let seen = clients(port, "clients") + &clients(port, "ophyd");
    for check in [
        "reads",
        "put-callback waits",
        "control limits are re-posted",
        "answer as an IOC would",
        "ERR reads in full",
        "DISP (a char channel) disables every put",
        "ALH's alarm acknowledgement",
        "reaches a DBE_ALARM monitor as one event",
        "dbCommon's SCAN",
        "long-string channel (DESC$)",
        "caproto",
        "moves nothing posts DMOV 0 then 1",
        "waits for it to complete",
        "moves past ADEL",
        "ophyd",
    ] {
        assert!(seen.lines().any(|l| l.starts_with("ok") && l.contains(check)), "'{check}' not passed:\n{seen}");
    }

    // The node goes: its axis is no longer served.
    node.kill();
    assert!(clients(port, "gone").contains("ok a vanished axis"));
}

#[test]
fn an_imported_databases_ao_and_calc_records_are_served_to_stock_clients() {
    let dir = tempfile::tempdir().unwrap();
    // The motor only tells when the node serves.
    let database = r#"
record(motor, "m1") { field(DTYP, "Soft Channel") }
record(ao, "length") { field(VAL, "1000") }
record(calc, "half") { field(CALC, "A/2") field(INPA, "length CP") }
record(calc, "waiting") { field(CALC, "A") field(INPA, "nobody CP") }
"#;
    let file = dir.path().join("records.db");
    std::fs::write(&file, database).unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let here = Host::default();
    let _node = here.spawn(&["launch", file.to_str().unwrap(), "--listen", &endpoint], dir.path());
    here.wait_for(&endpoint, "m1", "DMOV", |v| v == 1.0);
    let _ca = here.spawn(&["ca", "--port", &port.to_string(), "--connect", &endpoint], dir.path());
    assert!(clients(port, "bridge").lines().any(|l| l.starts_with("ok bridge records")));
}

#[test]
fn a_jog_from_a_channel_access_client_that_is_killed_ends_within_a_second() {
    let dir = tempfile::tempdir().unwrap();
    // The front-end of a launch file's [channel_access], in the node's process.
    let (_node, _, endpoint, port) = served(dir.path(), true);
    let mut jogger = script(port, "jog").stdout(Stdio::piped()).stderr(Stdio::null()).spawn().unwrap();
    let lines = Lines::of(&mut jogger);
    let jogger = Running(Some(jogger));
    let took = time_to_release(&Host::default(), &endpoint, || {
        assert!(lines.wait_for(common::PATIENCE, |l| l == "jogging").is_some(), "the client jogs");
        jogger.kill();
    });
    assert!(took < RELEASE_MARGIN, "released {took:?} after the client was killed (promised: {RELEASE_PROMISE:?})");
}

#[test]
fn a_jog_from_a_channel_access_client_cut_off_by_the_network_ends_within_about_two_seconds() {
    let hosts = [("zcan", "10.79.0.1"), ("zcac", "10.79.0.2")];
    let Some(net) = Namespaces::create(&hosts) else {
        let test = "a_jog_from_a_channel_access_client_cut_off_by_the_network_ends_within_about_two_seconds";
        return environment::untestable(test, "network namespaces", common::NETNS_NEEDS);
    };
    let (server, client) = (net.host(0), net.host(1));
    let endpoint = "tcp/10.79.0.1:7447";
    let dir = tempfile::tempdir().unwrap();
    let launch = std::fs::read_to_string(repo_file("launch/sim-axis.toml")).unwrap()
        + "\n[channel_access]\naddress = \"10.79.0.1\"\nport = 5064\n";
    let file = dir.path().join("axis.toml");
    std::fs::write(&file, launch).unwrap();
    let _node = server.spawn(&["launch", file.to_str().unwrap(), "--listen", endpoint], dir.path());
    server.wait_for(endpoint, "m1", "DMOV", |v| v == 1.0);
    let namespace = client.netns.clone().unwrap();
    let jogger = Command::new("ip")
        .args(["netns", "exec", &namespace])
        .arg(environment::python())
        .arg(repo_file("tests/python/ca_clients.py"))
        .arg("jog")
        .env("EPICS_CA_ADDR_LIST", "10.79.0.1:5064")
        .env("EPICS_CA_AUTO_ADDR_LIST", "NO")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let jogger = Running(Some(jogger));
    // The client's link is pulled: no FIN, no RST reaches the front-end.
    let took = time_to_release(&server, endpoint, || assert!(net.cut(1), "the link is cut"));
    jogger.kill();
    // A CA client that sends nothing is found gone by TCP keep-alive, whose clock ticks in whole
    // seconds (a probe after 1 s of silence, dropped 0.5 s later at most): about 2 s, not the
    // 1 s a Zenoh client's lease gives (README says so).
    // The test allows several times that.
    assert!(took < Duration::from_secs(8), "released {took:?} after the client was cut off");
}
