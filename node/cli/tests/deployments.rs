//! Deployments end to end, as separate `zmotor` processes driven through the CLI: an EPICS
//! database launched and moved, a clean shutdown saving state, a node killed with SIGKILL
//! mid-move restarting from its saved state under each RSTM mode, and a multi-host deployment
//! across network namespaces (a router, two axis hosts and a client, each with its own address).
//! Endpoints are on 127.0.0.1 (or on the namespaces' private link); waits are bounded polls.

mod common;

use common::{repo_file, slow_stage, Host, Namespaces, Pki, Running, PATIENCE};
use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};
use zmotor_client::free_local_endpoint;

/// The saved position of an axis, read from its autosave file.
fn saved_dval(state_dir: &Path, axis: &str) -> f64 {
    let text = std::fs::read_to_string(state_dir.join("motor").join(format!("{axis}.toml"))).unwrap();
    let saved: toml::Table = toml::from_str(&text).unwrap();
    saved["position"]["DVAL"].as_float().unwrap()
}

#[test]
fn the_seed_database_is_launched_moved_and_shut_down_cleanly() {
    let state = tempfile::tempdir().unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let db = repo_file("launch/tangent-arm.db");
    let here = Host::default();
    let node = here.spawn(&["launch", db.to_str().unwrap(), "-m", "user=db", "--listen", &endpoint], state.path());
    here.wait_for(&endpoint, "db:rotary", "DMOV", |v| v == 1.0);
    let answer = here.put(&endpoint, "db:rotary", "VAL", "10", true).unwrap();
    assert!(answer.contains("reached=1"), "{answer}");
    let linear = here.answer(&endpoint, "db:linear", "RBV");
    assert!((linear - 176.327).abs() < 0.01, "TAN(10°)·1000 mm, got {linear}");
    let (status, log) = node.terminate();
    assert!(status.success(), "{status}: {log}");
    assert!(log.contains("OMS VME58"), "the simulated hardware is named in a warning: {log}");
    assert!((saved_dval(state.path(), "db:rotary") - 10.0).abs() < 0.01);
    assert!((saved_dval(state.path(), "db:linear") - 176.327).abs() < 0.01);
}

#[test]
fn a_clean_shutdown_stops_a_moving_axis_and_saves_where_it_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("slow.toml");
    // Autosave would wait a minute: only the shutdown saves.
    std::fs::write(&file, slow_stage("NearZero", 60.0)).unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let here = Host::default();
    let node = here.spawn(&["launch", file.to_str().unwrap(), "--listen", &endpoint], dir.path());
    here.wait_for(&endpoint, "m1", "DMOV", |v| v == 1.0);
    here.put(&endpoint, "m1", "VAL", "50", false).unwrap();
    here.wait_for(&endpoint, "m1", "RBV", |v| v > 0.3);
    let (status, log) = node.terminate();
    assert!(status.success(), "{status}: {log}");
    let stopped_at = saved_dval(dir.path(), "m1");
    assert!(stopped_at > 0.3 && stopped_at < 5.0, "saved where it stopped, not the target: {stopped_at}");
}

/// Kill a node mid-move, restart it, and report (RBV, VELO) after the restart.
fn kill_mid_move_and_restart(rstm: &str) -> (f64, f64) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("slow.toml");
    std::fs::write(&file, slow_stage(rstm, 0.1)).unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let args = ["launch", file.to_str().unwrap(), "--listen", &endpoint];
    let here = Host::default();
    let node = here.spawn(&args, dir.path());
    here.wait_for(&endpoint, "m1", "DMOV", |v| v == 1.0);
    here.put(&endpoint, "m1", "VELO", "2", false).unwrap();
    here.put(&endpoint, "m1", "VAL", "40", false).unwrap();
    here.wait_for(&endpoint, "m1", "RBV", |v| v > 0.2);
    // The move's DVAL and the new VELO reach the file within the 0.1 s autosave delay.
    let deadline = Instant::now() + PATIENCE;
    while Instant::now() < deadline && std::fs::metadata(dir.path().join("motor/m1.toml")).is_err() {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(saved_dval(dir.path(), "m1"), 40.0);
    node.kill();
    let node = here.spawn(&args, dir.path());
    here.wait_for(&endpoint, "m1", "DMOV", |v| v == 1.0);
    let rbv = here.answer(&endpoint, "m1", "RBV");
    let velo = here.answer(&endpoint, "m1", "VELO");
    // It moves nothing on its own.
    std::thread::sleep(Duration::from_millis(500));
    let later = here.answer(&endpoint, "m1", "RBV");
    assert_eq!(later, rbv, "RSTM {rstm}: the axis moved after the restart");
    assert_eq!(here.answer(&endpoint, "m1", "DMOV"), 1.0);
    drop(node);
    (rbv, velo)
}

#[test]
fn a_node_killed_mid_move_restarts_from_its_saved_state_under_each_restore_mode() {
    let modes = ["Never", "Always", "NearZero", "Conditional"];
    let outcomes: Vec<_> = std::thread::scope(|scope| {
        let runs: Vec<_> = modes.iter().map(|mode| scope.spawn(move || kill_mid_move_and_restart(mode))).collect();
        runs.into_iter().map(|run| run.join().unwrap()).collect()
    });
    for (mode, (rbv, velo)) in modes.iter().zip(outcomes) {
        assert_eq!(velo, 2.0, "RSTM {mode}: the VELO setting survives");
        // The simulated controller lives in the node's process, so it powers up at 0 like a
        // motorSim controller after an IOC restart; RSTM decides whether the saved DVAL (the
        // move's target, as autosave keeps it) is loaded into it.
        let expected = if *mode == "Never" { 0.0 } else { 40.0 };
        assert_eq!(rbv, expected, "RSTM {mode}");
    }
}

#[test]
fn a_deployment_split_across_hosts_moves_monitors_and_runs_the_tangent_arm() {
    let hosts = [("zmr", "10.77.0.1"), ("zma", "10.77.0.2"), ("zmb", "10.77.0.3"), ("zmc", "10.77.0.4")];
    let Some(net) = Namespaces::create(&hosts) else {
        let test = "a_deployment_split_across_hosts_moves_monitors_and_runs_the_tangent_arm";
        return zmotor_tests::environment::untestable(test, "network namespaces", common::NETNS_NEEDS);
    };
    let (router, host_a, host_b, mut client) = (net.host(0), net.host(1), net.host(2), net.host(3));
    // QUIC, as the README advises between hosts: Zenoh 1.10's `tls/` link can reset when it
    // reads and writes at once (eclipse-zenoh/zenoh#2557), which a steady readback does.
    let router_endpoint = "quic/10.77.0.1:7447";
    let dir = tempfile::tempdir().unwrap();
    // Every link runs over mutual TLS (in QUIC), with certificates of an authority made here:
    // the router's names its address, the nodes and the client show theirs.
    let pki = Pki::new("zmotor test authority");
    let router_file = dir.path().join("router.toml");
    std::fs::write(&router_file, pki.launch_section(&pki.issue("router", &["10.77.0.1"]))).unwrap();
    let node = pki.issue("node", &[]);
    client.client_args = pki.client_args(&node);
    // The tangent arm split: the linear stage and the drive calc on host a, the soft rotary
    // motor and the readback calc on host b; both reach each other through the router.
    let text = std::fs::read_to_string(repo_file("launch/two-hosts.toml")).unwrap();
    let file = dir.path().join("two-hosts-tls.toml");
    std::fs::write(&file, text + &pki.launch_section(&node)).unwrap();
    let router_args = ["router", "--listen", router_endpoint, "--launch", router_file.to_str().unwrap()];
    let _router = router.spawn(&router_args, dir.path());
    let file = file.to_str().unwrap();
    let _a = host_a.spawn(&["launch", file, "--host", "optics", "--connect", router_endpoint], &dir.path().join("a"));
    let _b = host_b.spawn(&["launch", file, "--host", "user", "--connect", router_endpoint], &dir.path().join("b"));
    client.wait_for(router_endpoint, "linear", "DMOV", |v| v == 1.0);
    client.wait_for(router_endpoint, "rotary", "DMOV", |v| v == 1.0);

    // Monitor from the client host while moving the hard axis.
    let mut monitor = client
        .zmotor(&["monitor", "linear", "DMOV", "RBV", "--connect", router_endpoint])
        .args(&client.client_args)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let lines = common::Lines::of(&mut monitor);
    let _monitor = Running(Some(monitor));
    let dmov = |value| move |line: &str| common::monitored(line) == Some(("linear.DMOV", value));
    assert!(lines.wait_for(PATIENCE, dmov("1")).is_some(), "the monitor starts with the current DMOV");
    let answer = client.put(router_endpoint, "linear", "VAL", "5", true).unwrap();
    assert!(answer.contains("reached=1"), "{answer}");
    assert!(lines.wait_for(PATIENCE, dmov("0")).is_some(), "the monitor saw the move start");
    assert!(lines.wait_for(PATIENCE, dmov("1")).is_some(), "the monitor saw the move end");

    // The composite motor across hosts: rotary (host b) drives linear (host a), commanded
    // right after the linear's own move, while the rotary may still be following it.
    let answer = client.put(router_endpoint, "rotary", "VAL", "20", true).unwrap();
    assert!(answer.contains("reached=1"), "{answer}");
    let linear = client.answer(router_endpoint, "linear", "RBV");
    assert!(
        (linear - 363.970).abs() < 0.01,
        "TAN(20°)·1000 mm, got {linear}; linear DVAL {:?}, rotary {answer}",
        client.get(router_endpoint, "linear", "DVAL")
    );
    let rotary = client.wait_for(router_endpoint, "rotary", "RBV", |v| (v - 20.0).abs() < 0.01);
    assert!((rotary - 20.0).abs() < 0.01);

    // A client with no certificate, or trusting no authority, or on plain TCP, does not get in.
    for (args, endpoint) in [
        (vec!["--ca", pki.ca().to_str().unwrap()], router_endpoint),
        (vec![], "tcp/10.77.0.1:7447"),
        (vec![], "quic/10.77.0.1:7447"),
    ] {
        let output = client.zmotor(&["get", "linear", "RBV", "--connect", endpoint]).args(args).output().unwrap();
        assert!(!output.status.success(), "{endpoint}: {}", String::from_utf8_lossy(&output.stdout));
    }
}

#[test]
fn a_put_wait_whose_node_dies_says_the_node_vanished() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("slow.toml");
    std::fs::write(&file, slow_stage("Never", 60.0)).unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let here = Host::default();
    let node = here.spawn(&["launch", file.to_str().unwrap(), "--listen", &endpoint], dir.path());
    here.wait_for(&endpoint, "m1", "DMOV", |v| v == 1.0);
    let waiting = here.put_wait_under_way(&endpoint, "m1", "50");
    node.kill();
    let started = Instant::now();
    let output = waiting.wait_with_output().unwrap();
    let said = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(said.contains("the node serving m1 vanished before answering"), "{said}");
    assert!(started.elapsed() < Duration::from_secs(10), "told at once, not at the timeout");
    let nobody = here.put(&endpoint, "m1", "VAL", "1", true).unwrap_err();
    assert!(nobody.contains("nothing answers at"), "{nobody}");
}

/// `zmotor monitor m1 RBV` through `endpoint`, its lines as they come.
fn monitor_rbv(endpoint: &str) -> (Running, common::Lines) {
    let mut child = Host::default()
        .zmotor(&["monitor", "m1", "RBV", "--connect", endpoint])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let lines = common::Lines::of(&mut child);
    // A monitor prints the current value first, once it follows the axis.
    let first =
        lines.wait_for(PATIENCE, |line| common::monitored(line).is_some_and(|(channel, _)| channel == "m1.RBV"));
    assert!(first.is_some(), "the monitor printed m1.RBV's current value");
    (Running(Some(child)), lines)
}

/// Whether `lines` show m1's readback at `value` within PATIENCE.
fn shows_rbv(lines: &common::Lines, value: &str) -> bool {
    lines.wait_for(PATIENCE, |line| common::monitored(line) == Some(("m1.RBV", value))).is_some()
}

#[test]
fn a_router_restarted_between_client_and_node_brings_both_back_and_moves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("slow.toml");
    std::fs::write(&file, slow_stage("Never", 60.0)).unwrap();
    let router_endpoint = free_local_endpoint().unwrap();
    let here = Host::default();
    let router_args = ["router", "--listen", router_endpoint.as_str()];
    let router = here.spawn(&router_args, dir.path());
    let node_args = ["launch", file.to_str().unwrap(), "--mode", "client", "--connect", &router_endpoint];
    let _node = here.spawn(&node_args, dir.path());
    here.wait_for(&router_endpoint, "m1", "DMOV", |v| v == 1.0);
    let (_monitor, lines) = monitor_rbv(&router_endpoint);
    here.put(&router_endpoint, "m1", "VAL", "0.5", true).unwrap();
    assert!(shows_rbv(&lines, "0.5"), "the monitor saw the move");
    router.kill();
    std::thread::sleep(Duration::from_millis(500));
    let _router = here.spawn(&router_args, dir.path());
    // Both sides reconnect by themselves; the node kept its state and moved nothing.
    let rbv = here.wait_for(&router_endpoint, "m1", "RBV", |_| true);
    assert_eq!((rbv, here.answer(&router_endpoint, "m1", "DMOV")), (0.5, 1.0));
    // A move of a few seconds: the monitor, reconnecting on its own schedule, sees its end.
    let deadline = Instant::now() + PATIENCE;
    let mut moved = here.put(&router_endpoint, "m1", "VAL", "4", true);
    while moved.is_err() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(200));
        moved = here.put(&router_endpoint, "m1", "VAL", "4", true);
    }
    assert!(moved.unwrap().contains("reached=1"));
    assert!(shows_rbv(&lines, "4"), "the monitor's subscription came back with the router");
}

#[test]
fn a_node_restarted_under_a_monitoring_client_is_monitored_again() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("slow.toml");
    std::fs::write(&file, slow_stage("Always", 0.1)).unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let here = Host::default();
    let args = ["launch", file.to_str().unwrap(), "--listen", endpoint.as_str()];
    let node = here.spawn(&args, dir.path());
    here.wait_for(&endpoint, "m1", "DMOV", |v| v == 1.0);
    let (_monitor, lines) = monitor_rbv(&endpoint);
    here.put(&endpoint, "m1", "VAL", "0.3", true).unwrap();
    assert!(shows_rbv(&lines, "0.3"));
    let (status, _) = node.terminate();
    assert!(status.success());
    let _node = here.spawn(&args, dir.path());
    here.wait_for(&endpoint, "m1", "DMOV", |v| v == 1.0);
    assert_eq!(here.answer(&endpoint, "m1", "RBV"), 0.3, "restored, not moved");
    // A move of a few seconds: the monitor, reconnecting on its own schedule, sees its end.
    let moved = here.put(&endpoint, "m1", "VAL", "4", true).unwrap();
    assert!(moved.contains("reached=1"));
    assert!(shows_rbv(&lines, "4"), "the monitor resumed with the node");
}

#[test]
fn a_node_that_cannot_listen_says_where_and_why_and_exits() {
    let dir = tempfile::tempdir().unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let taken = std::net::TcpListener::bind(endpoint.trim_start_matches("tcp/")).unwrap();
    let here = Host::default();
    let file = repo_file("launch/sim-axis.toml");
    let mut node = here.spawn(&["launch", file.to_str().unwrap(), "--listen", &endpoint], dir.path());
    let deadline = Instant::now() + PATIENCE;
    let status = loop {
        if let Some(status) = node.0.as_mut().unwrap().try_wait().unwrap() {
            break status;
        }
        assert!(Instant::now() < deadline, "the node still runs on a port in use");
        std::thread::sleep(Duration::from_millis(50));
    };
    let mut said = String::new();
    std::io::Read::read_to_string(node.0.as_mut().unwrap().stderr.as_mut().unwrap(), &mut said).unwrap();
    assert!(!status.success());
    assert!(said.contains(&format!("zmotor: cannot listen on {endpoint}: ")), "{said}");
    drop(taken);
}

#[test]
fn schema_writes_the_schemas_or_names_the_path_it_cannot_write() {
    let dir = tempfile::tempdir().unwrap();
    let here = Host::default();
    let out = dir.path().join("schemas");
    assert!(here.run(&["schema", out.to_str().unwrap()]).status.success());
    assert!(out.join("fields.json").is_file() && out.join("completion.schema.json").is_file());
    let file = dir.path().join("a-file");
    std::fs::write(&file, "").unwrap();
    let refused = here.run(&["schema", file.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(1), "{said}");
    assert!(said.contains(&format!("{}: ", file.display())), "{said}");
}
