//! `zmotor bench --smoke` runs every part of the benchmark in seconds (the soak too). Not a timed test: it
//! proves the harness works (through `zmotor bench`, which runs this crate's program) and
//! prints what it measured.

use std::path::Path;
use std::process::Command;

#[test]
fn the_benchmark_runs_in_smoke_mode() {
    // `zmotor bench` runs the `zmotor-bench` beside it; `cargo test --workspace` builds both.
    let zmotor = Path::new(env!("CARGO_BIN_EXE_zmotor-bench")).with_file_name("zmotor");
    assert!(
        zmotor.exists(),
        "{} is not built: `cargo build -p zmotor` (cargo test --workspace builds it)",
        zmotor.display()
    );
    // Minutes on a loaded machine; bounded, so that a benchmark that hangs fails this test.
    let mut bench = Command::new(&zmotor);
    bench.args(["bench", "--smoke"]).env("RUST_LOG", "error");
    let output = zmotor_tests::environment::run_within(&mut bench, std::time::Duration::from_secs(900));
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&output.stderr));
    for part in [
        "1. command latency",
        "Zenoh round trip",
        "3. scale",
        "Zenoh alone",
        "4. the load of the EPICS figure",
        "5. start-up",
        "every axis's liveliness token seen",
        "Zenoh alone, a process declaring",
        "target: every token seen in < 2 s",
        "6. controllers",
        "acs_mcb4b",
        "newport_smc100",
        "pi_gcs2",
        "smaract_mcs2",
        "phytron",
        "pmac",
        "newport_esp300",
        "galil",
        "mclennan_pm304",
        "newport_xps",
        "ims_mdrive",
        "oms_maxnet",
        "kohzu_sc",
        "micronix_mmc",
        "newfocus_8742",
        "piezojena_nv40",
        "faulhaber_mc",
        "vmc",
        "7. a storm of writes",
        "8. Channel Access beside Zenoh",
        "caput -c VAL, one step",
        "zmotor put b0 VAL x --wait",
        "a Zenoh client process",
        "9. the jog deadman",
        "2 kills",
        "10. ROS 2",
        "JointState arrival − RBV arrival",
        "with [ros2], 10 joints",
        "11. the soak",
        "12. fast readback",
        "latency, arrival − the node's stamp",
        "target: growth after the warm-up",
    ] {
        assert!(stdout.contains(part), "missing '{part}' in:\n{stdout}");
    }
    assert!(!stdout.contains("failed"), "{stdout}");
    // The scale part's axes all got their writes (plain puts), at 1 and 10 axes.
    let handled: Vec<&str> = stdout.lines().filter(|l| l.contains("every axis's write handled")).collect();
    assert_eq!(handled.len(), 2, "{stdout}");
    assert!(handled.iter().all(|l| l.ends_with(" met")), "{handled:?}");
    // Each row says when its last axis was first heard (every axis moved).
    let rows: Vec<&str> = stdout.lines().filter(|l| l.contains(" axes heard, ")).collect();
    assert_eq!(rows.len(), 10, "five rows at each of two scales:\n{stdout}");
    assert!(rows.iter().all(|l| l.contains(", all in ")), "{rows:?}");
    // The EPICS load really moved the axes: the subscriber saw moves end.
    let ended: f64 = stdout
        .split("moves/s ended ")
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no 'moves/s ended' figure in:\n{stdout}"));
    assert!(ended > 0.0, "no move ended under the EPICS load:\n{stdout}");
    // After a storm of writes the last target is reached on every axis.
    for axes in [1, 100] {
        let storm = format!("{axes} axes ×");
        let line = stdout
            .lines()
            .find(|l| l.trim_start().starts_with(&storm))
            .unwrap_or_else(|| panic!("no storm line for {axes} axes in:\n{stdout}"));
        assert!(line.ends_with(&format!("reached on {axes}/{axes} axes")), "{line}");
        assert!(line.contains("(none lost)"), "every write sent was taken: {line}");
    }
    // The stock client's figures, where the test environment has it (tests/run sets it up).
    if std::env::var_os("ZMOTOR_PYTHON").is_some() {
        assert!(stdout.contains("pyepics PV.get RBV"), "pyepics measured:\n{stdout}");
    }
    println!("{stdout}");
}

/// The processes whose parent is `parent`, from /proc.
fn children_of(parent: u32) -> Vec<u32> {
    let Ok(entries) = std::fs::read_dir("/proc") else { return Vec::new() };
    entries
        .filter_map(|entry| entry.ok()?.file_name().to_str()?.parse::<u32>().ok())
        .filter(|pid| {
            // /proc/PID/stat: "pid (comm) state ppid ...", comm possibly holding spaces.
            let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
            let after_comm = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
            after_comm.split_whitespace().nth(1).and_then(|ppid| ppid.parse::<u32>().ok()) == Some(parent)
        })
        .collect()
}

#[test]
fn a_benchmark_stopped_by_sigterm_stops_the_nodes_it_started() {
    use std::time::{Duration, Instant};
    let zmotor = Path::new(env!("CARGO_BIN_EXE_zmotor-bench")).with_file_name("zmotor");
    let state = tempfile::tempdir().unwrap();
    // `zmotor bench` becomes the benchmark: the signal goes to the process the user started.
    let mut bench = Command::new(&zmotor)
        .args(["bench", "--parts", "soak", "--minutes", "30"])
        .env("RUST_LOG", "off")
        .env("XDG_STATE_HOME", state.path())
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    let node = loop {
        if let Some(&node) = children_of(bench.id()).first() {
            break node;
        }
        assert!(Instant::now() < deadline, "the soak started no node within 60 s");
        assert!(bench.try_wait().unwrap().is_none(), "the benchmark ended before starting a node");
        std::thread::sleep(Duration::from_millis(20));
    };
    let node_alive = || Path::new(&format!("/proc/{node}")).exists();
    assert!(node_alive());
    assert!(Command::new("kill").args(["-TERM", &bench.id().to_string()]).status().unwrap().success());
    let deadline = Instant::now() + Duration::from_secs(30);
    let status = loop {
        if let Some(status) = bench.try_wait().unwrap() {
            break status;
        }
        if Instant::now() > deadline {
            bench.kill().unwrap();
            panic!("the benchmark did not stop within 30 s of SIGTERM");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(!status.success(), "an interrupted benchmark says so by its exit status");
    if node_alive() {
        // Left running, re-parented: this test started it, so it stops it, by its id.
        let _ = Command::new("kill").args(["-KILL", &node.to_string()]).status();
        panic!("node {node} outlived the benchmark that started it");
    }
}

#[test]
fn counts_and_lengths_a_figure_cannot_be_made_of_are_refused_before_anything_runs() {
    let zmotor = Path::new(env!("CARGO_BIN_EXE_zmotor-bench")).with_file_name("zmotor");
    for (option, value, said) in [
        ("--moves", "0", "a figure needs at least one"),
        ("--scales", "1000,0", "a figure needs at least one"),
        ("--minutes=-1", "", "-1 is not a length more than 0"),
        ("--storm", "nan", "NaN is not a length more than 0"),
    ] {
        let args = ["bench", option, value].into_iter().filter(|a| !a.is_empty());
        let output = Command::new(&zmotor).args(args).env("RUST_LOG", "off").output().unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{option} {value}: {stderr}");
        assert!(stderr.contains(said), "{option} {value}: {stderr}");
    }
}
