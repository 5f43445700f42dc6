//! What a user at the command line sees: the live axes listed, several axes read at once, values
//! shown as caget shows them, and a monitor that starts with the current values and prints as
//! camonitor does or one JSON object a line.

mod common;

use common::{Host, Lines, Running, PATIENCE};
use std::process::Stdio;
use zmotor_client::free_local_endpoint;

const TWO_AXES: &str = r#"
[[axis]]
name = "m1"
driver = "sim"
[axis.fields]
DESC = "slit top"
EGU = "mm"
VELO = 1
MRES = 0.001

[[axis]]
name = "m2"
driver = "sim"
[axis.fields]
DESC = "slit bottom"
EGU = "deg"
VELO = 10
MRES = 0.001
"#;

fn stdout(host: &Host, args: &[&str]) -> String {
    String::from_utf8_lossy(&host.run(args).stdout).into_owned()
}

/// A node of `TWO_AXES`, both answering: its state directory, its endpoint, the process.
fn two_axes(here: &Host) -> (tempfile::TempDir, String, Running) {
    let dir = tempfile::tempdir().unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let file = dir.path().join("two.toml");
    std::fs::write(&file, TWO_AXES).unwrap();
    let node = here.spawn(&["launch", file.to_str().unwrap(), "--listen", &endpoint], dir.path());
    for axis in ["m1", "m2"] {
        here.wait_for(&endpoint, axis, "DMOV", |v| v == 1.0);
    }
    (dir, endpoint, node)
}

#[test]
fn list_get_of_several_axes_and_monitors_show_what_is_live() {
    let here = Host::default();
    let (dir, endpoint, node) = two_axes(&here);

    let listed = stdout(&here, &["list", "--connect", &endpoint]);
    let rows: Vec<Vec<&str>> = listed.lines().map(|l| l.split("  ").filter(|c| !c.is_empty()).collect()).collect();
    assert_eq!(rows.len(), 3, "{listed}");
    assert_eq!(rows[0].iter().map(|c| c.trim()).collect::<Vec<_>>(), ["AXIS", "DESC", "EGU", "RBV", "STATE"]);
    assert_eq!(rows[1].iter().map(|c| c.trim()).collect::<Vec<_>>(), ["m1", "slit top", "mm", "0", "idle"]);
    assert_eq!(rows[2].iter().map(|c| c.trim()).collect::<Vec<_>>(), ["m2", "slit bottom", "deg", "0", "idle"]);

    assert_eq!(
        stdout(&here, &["get", "m1,m2", "DESC", "--connect", &endpoint]),
        "m1.DESC slit top\nm2.DESC slit bottom\n"
    );
    // Axes named by a pattern, each line naming its axis; a field pattern in any case.
    assert_eq!(stdout(&here, &["get", "*", "DESC", "--connect", &endpoint]), "m1.DESC slit top\nm2.DESC slit bottom\n");
    assert_eq!(stdout(&here, &["get", "m*2", "eg*", "--connect", &endpoint]), "m2.EGU deg\n");
    let written = here.zmotor(&["put", "m*", "VAL", "1", "--connect", &endpoint]).output().unwrap();
    assert_eq!(written.status.code(), Some(2), "a write names one axis: {written:?}");
    assert!(String::from_utf8_lossy(&written.stderr).contains("axis name 'm*' contains '*'"), "{written:?}");
    // A monitor follows one axis or a pattern: a list is refused, not waited on as an axis named so.
    let listed = here.zmotor(&["monitor", "m1,m2", "RBV", "--connect", &endpoint]).output().unwrap();
    assert_eq!(listed.status.code(), Some(2), "a monitor of a list: {listed:?}");
    assert!(String::from_utf8_lossy(&listed.stderr).contains("m1,m2: a monitor takes one axis"), "{listed:?}");
    let prefixed = here.zmotor(&["get", "m1", "RBV", "--prefix", "motor/*", "--connect", &endpoint]).output().unwrap();
    assert_eq!(prefixed.status.code(), Some(2), "a prefix with a wildcard: {prefixed:?}");
    assert!(String::from_utf8_lossy(&prefixed.stderr).contains("'motor/*' is not a plain key"), "{prefixed:?}");
    let mut every =
        here.zmotor(&["monitor", "*", "EGU", "--connect", &endpoint]).stdout(Stdio::piped()).spawn().unwrap();
    let lines = Lines::of(&mut every);
    let _every = Running(Some(every));
    let seen = std::cell::RefCell::new(Vec::new());
    lines.wait_for(PATIENCE, |l| {
        seen.borrow_mut().extend(common::monitored(l).map(|(pv, value)| format!("{pv} {value}")));
        seen.borrow().len() == 2
    });
    seen.borrow_mut().sort();
    assert_eq!(*seen.borrow(), ["m1.EGU mm", "m2.EGU deg"]);

    // As caget shows them: a menu by its choice, a double at the axis's precision.
    assert_eq!(stdout(&here, &["get", "m1", "SPMG", "--connect", &endpoint]), "Go\n");
    here.put(&endpoint, "m1", "SPMG", "Pause", false).unwrap();
    assert_eq!(stdout(&here, &["get", "m1", "SPMG", "--connect", &endpoint]), "Pause\n");
    here.put(&endpoint, "m1", "SPMG", "Go", false).unwrap();
    // ERR, no field but the axis's messages: its last one, nothing while it has none.
    assert_eq!(stdout(&here, &["get", "m2", "ERR", "--connect", &endpoint]), "\n");
    let plain = here.zmotor(&["put", "m2", "VELO", "fast", "--plain", "--connect", &endpoint]).output().unwrap();
    assert!(plain.status.success(), "{plain:?}");
    let deadline = std::time::Instant::now() + PATIENCE;
    let message = loop {
        let message = stdout(&here, &["get", "m2", "err", "--connect", &endpoint]);
        if message != "\n" || std::time::Instant::now() > deadline {
            break message;
        }
    };
    assert!(message.starts_with("VELO: ") && message.contains("'fast'"), "{message}");
    here.put(&endpoint, "m2", "PREC", "3", false).unwrap();
    here.put(&endpoint, "m2", "VAL", "6.991", true).unwrap();
    assert_eq!(stdout(&here, &["get", "m2", "RBV", "--connect", &endpoint]), "6.991\n");
    let listed = stdout(&here, &["list", "--connect", &endpoint]);
    assert!(listed.lines().any(|l| l.starts_with("m2 ") && l.contains("  6.991  ")), "at PREC 3: {listed}");
    assert_eq!(stdout(&here, &["get", "m2", "VELO", "--connect", &endpoint]), "10.000\n");

    // A move seen by a camonitor-style monitor and a JSON one.
    let monitor = |json: bool| {
        let mut args = vec!["monitor", "m1", "RBV", "DMOV", "--connect", &endpoint];
        if json {
            args.push("--json");
        }
        let mut child = here.zmotor(&args).stdout(Stdio::piped()).stderr(Stdio::null()).spawn().unwrap();
        let lines = Lines::of(&mut child);
        (Running(Some(child)), lines)
    };
    let ((_plain, plain), (_json, json)) = (monitor(false), monitor(true));
    // A monitor starts with the current values, as camonitor does, once it follows the axis.
    assert!(plain.wait_for(PATIENCE, |l| common::monitored(l) == Some(("m1.DMOV", "1"))).is_some(), "current DMOV");
    assert!(json.wait_for(PATIENCE, |l| l.contains(r#""field":"DMOV""#)).is_some(), "current DMOV, as JSON");
    let moving = stdout(&here, &["list", "--connect", &endpoint]);
    assert!(!moving.contains("moving"), "{moving}");
    here.put(&endpoint, "m1", "VAL", "0.2", false).unwrap();
    assert!(stdout(&here, &["list", "--connect", &endpoint]).lines().nth(1).unwrap().ends_with("moving"));
    assert!(plain.wait_for(PATIENCE, |l| common::monitored(l) == Some(("m1.RBV", "0.2"))).is_some(), "the last RBV");
    assert!(
        plain.wait_for(PATIENCE, |l| common::monitored(l) == Some(("m1.DMOV", "1"))).is_some(),
        "DMOV 1 after the last RBV"
    );
    let ended = json.wait_for(PATIENCE, |line| {
        let object: serde_json::Value = serde_json::from_str(line).unwrap();
        assert_eq!(object["axis"], "m1");
        assert!(object["time"].as_str().unwrap().ends_with('Z'), "{line}");
        object["field"] == "RBV" && object["value"] == 0.2
    });
    assert!(ended.is_some(), "the JSON monitor saw RBV reach 0.2");

    // The node goes: a monitor says so, as camonitor does; when it is back, the current values.
    let started = std::time::SystemTime::now();
    let mut watching =
        here.zmotor(&["monitor", "m1", "EGU", "--connect", &endpoint]).stdout(Stdio::piped()).spawn().unwrap();
    let watched = Lines::of(&mut watching);
    let _watching = Running(Some(watching));
    let first = std::cell::RefCell::new(String::new());
    let egu = |l: &str| common::monitored(l) == Some(("m1.EGU", "mm")) && first.replace(l.to_string()).is_empty();
    assert!(watched.wait_for(PATIENCE, egu).is_some());
    // Its time is the node's, as camonitor shows an IOC's: the axis's last post, the move's end.
    let first = first.into_inner();
    let time: Vec<&str> = first.split_whitespace().skip(1).take(2).collect();
    let time = humantime::parse_rfc3339_weak(&time.join(" ")).unwrap();
    assert!(time < started, "{first}: a time after the monitor began");
    // A monitor of the messages alone says so too. (A message has no current value: a refused
    // plain put shows it follows.)
    let mut messages =
        here.zmotor(&["monitor", "m1", "ERR", "--connect", &endpoint]).stdout(Stdio::piped()).spawn().unwrap();
    let said = Lines::of(&mut messages);
    let _messages = Running(Some(messages));
    let refused = |l: &str| l.starts_with("m1.ERR ") && l.contains("VELO: ");
    let (deadline, mut heard) = (std::time::Instant::now() + PATIENCE, false);
    while !heard && std::time::Instant::now() < deadline {
        here.zmotor(&["put", "m1", "VELO", "fast", "--plain", "--connect", &endpoint]).output().unwrap();
        heard = said.wait_for(std::time::Duration::from_millis(500), refused).is_some();
    }
    assert!(heard, "the monitor of ERR showed no refusal");
    drop(node);
    assert!(watched.wait_for(PATIENCE, |l| l.starts_with("m1 ") && l.ends_with("*** disconnected")).is_some());
    assert!(said.wait_for(PATIENCE, |l| l.starts_with("m1 ") && l.ends_with("*** disconnected")).is_some());
    let gone = here.zmotor(&["list", "--connect", &endpoint]).output().unwrap();
    assert!(!gone.status.success() || String::from_utf8_lossy(&gone.stdout).is_empty());
    let file = dir.path().join("two.toml");
    let _again = here.spawn(&["launch", file.to_str().unwrap(), "--listen", &endpoint], dir.path());
    assert!(watched.wait_for(PATIENCE, |l| l.starts_with("m1 ") && l.ends_with("*** connected")).is_some());
    assert!(said.wait_for(PATIENCE, |l| l.starts_with("m1 ") && l.ends_with("*** connected")).is_some());
    assert!(watched.wait_for(PATIENCE, |l| common::monitored(l) == Some(("m1.EGU", "mm"))).is_some());
}

#[test]
fn a_put_wait_that_does_not_reach_its_target_fails_and_a_timeout_is_a_number_of_seconds() {
    let here = Host::default();
    let (_dir, endpoint, _node) = two_axes(&here);

    for timeout in ["nan", "inf", "-1", "0", "1e30"] {
        let option = format!("--timeout={timeout}");
        let refused = here.zmotor(&["put", "m1", "VAL", "1", "--connect", &endpoint, &option]).output().unwrap();
        assert_eq!(refused.status.code(), Some(2), "{option}: {refused:?}");
    }
    assert_eq!(stdout(&here, &["get", "m1", "RBV", "--connect", &endpoint]), "0\n", "nothing was sent");

    // A monitor of an axis nobody serves says so, and waits for it.
    let mut nobody =
        here.zmotor(&["monitor", "m9", "RBV", "--connect", &endpoint]).stderr(Stdio::piped()).spawn().unwrap();
    let said = Lines::of_stderr(&mut nobody);
    let _nobody = Running(Some(nobody));
    assert!(said.wait_for(PATIENCE, |l| l.contains("no node serves m9 now")).is_some());

    // m1 runs at 1 mm/s: stopped on its way to 5 mm, the write did not reach its target.
    let waiting = here.put_wait_under_way(&endpoint, "m1", "5");
    here.put(&endpoint, "m1", "STOP", "1", false).unwrap();
    let output = waiting.wait_with_output().unwrap();
    let (said, complained) = (String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(said.contains("reached=0") && said.contains("DMOV=1"), "{said}");
    assert_eq!(output.status.code(), Some(1), "{said}{complained}");
    assert!(complained.contains("m1 did not reach the target"), "{complained}");

    // A motion that outlasts --timeout (4.7 mm at 1 mm/s, 0.3 s): the command says what it
    // knows, not Zenoh's bare "Timeout".
    let args = ["put", "m1", "VAL", "5", "--wait", "--timeout", "0.3", "--connect", &endpoint];
    let started = std::time::Instant::now();
    let timed_out = here.zmotor(&args).output().unwrap();
    // Said at its time (the process's start and connection beside), not seconds after.
    let took = started.elapsed();
    assert!(took < std::time::Duration::from_secs(3), "the timed-out write answered after {took:?}");
    let complained = String::from_utf8_lossy(&timed_out.stderr);
    assert_eq!(timed_out.status.code(), Some(1), "{complained}");
    assert!(complained.contains("m1 is served but did not answer within 0.3 s"), "{complained}");
    assert!(complained.contains("the write of VAL may have been taken, and a motion"), "{complained}");
    here.put(&endpoint, "m1", "STOP", "1", false).unwrap();

    // A target held by SPMG waits for Go, as on an IOC: the command says why it waits.
    here.put(&endpoint, "m1", "SPMG", "Pause", false).unwrap();
    let args = ["put", "m1", "VAL", "0", "--wait", "--timeout", "3", "--connect", &endpoint];
    let held = here.zmotor(&args).output().unwrap();
    let complained = String::from_utf8_lossy(&held.stderr);
    assert_eq!(held.status.code(), Some(1), "{complained}");
    assert!(complained.contains("m1 is held by SPMG Pause: the motion waits until SPMG is Go or Move"), "{complained}");
}
