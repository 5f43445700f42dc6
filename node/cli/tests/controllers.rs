//! Each ready controller launch file (launch/<vendor>.toml) runs as it is against its
//! emulator (`zmotor sim-controller`), and a stock Python Zenoh client moves, jogs, stops and
//! homes an axis through motor/<axis>/... keys; then the emulator is killed (the axis goes to
//! COMM alarm, a move goes nowhere) and started again (the alarm clears, nothing moves by
//! itself). Separate processes, 127.0.0.1 only, a free port for everything.

mod common;

use std::process::{Child, Command, Stdio};
use zmotor_client::free_local_endpoint;
use zmotor_tests::environment;

/// A process of this test, killed when dropped.
struct Running(Child);

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
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

/// `zmotor launch FILE --listen ENDPOINT`, its state in `state` and its log in `state/node.log`
/// (a failure shows it).
fn launch_node(file: &std::path::Path, endpoint: &str, state: &std::path::Path) -> Running {
    let log = std::fs::File::create(state.join("node.log")).unwrap();
    let node = Command::new(env!("CARGO_BIN_EXE_zmotor"))
        .args(["launch", file.to_str().unwrap(), "--listen", endpoint])
        .env("ZMOTOR_STATE_DIR", state)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .unwrap();
    Running(node)
}

/// One phase of tests/python/controller_client.py against the node whose state is in `state`;
/// panics with what the client said and the node logged if it failed.
fn client_with(phase: &str, endpoint: &str, axis: &str, more: &[&str], state: &std::path::Path) {
    let output = environment::run_script(
        environment::python_script("controller_client.py").args([phase, endpoint, axis]).args(more),
    );
    let said = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    if !(output.status.success() && said.contains(&format!("{phase} ok"))) {
        let log = std::fs::read_to_string(state.join("node.log")).unwrap_or_default();
        panic!("{said}\nthe node logged:\n{log}");
    }
}

/// How a launch file reaches its controller: the TCP address or serial device it names.
enum Reach {
    Tcp(&'static str),
    Pty(&'static str),
}

/// The launch file `launch`, whose controller is reached as `reach` says, against its emulator.
fn drive_through_loss_and_recovery(protocol: &str, launch: &str, reach: Reach, axis: &str) {
    drive_through_loss_and_recovery_with(protocol, launch, reach, axis, &[]);
}

/// `drive_through_loss_and_recovery`, the motion phase given `more` arguments (`--no-home`).
fn drive_through_loss_and_recovery_with(protocol: &str, launch: &str, reach: Reach, axis: &str, more: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let (named, here, flag) = match reach {
        Reach::Tcp(address) => {
            let free = free_local_endpoint().unwrap().trim_start_matches("tcp/").to_string();
            (address, free, "--listen")
        }
        Reach::Pty(device) => (device, dir.path().join("tty").to_str().unwrap().to_string(), "--pty"),
    };
    let text = std::fs::read_to_string(common::repo_file(launch)).unwrap();
    assert!(text.contains(named), "{launch} names its controller at {named}");
    // The copy runs elsewhere: a script it names is found where the original finds it.
    let beside = common::repo_file(launch).parent().unwrap().display().to_string();
    let text = text.replace("script = \"", &format!("script = \"{beside}/"));
    let file = dir.path().join("launch.toml");
    std::fs::write(&file, text.replace(named, &here)).unwrap();
    let endpoint = free_local_endpoint().unwrap();

    let emulate = || zmotor(&["sim-controller", protocol, flag, &here]);
    let emulator = emulate();
    let _node = launch_node(&file, &endpoint, dir.path());

    client_with("motion", &endpoint, axis, more, dir.path());
    drop(emulator);
    client_with("lost", &endpoint, axis, &[], dir.path());
    let _emulator = emulate();
    client_with("recovered", &endpoint, axis, &[], dir.path());
}

#[test]
fn acs_mcb4b() {
    drive_through_loss_and_recovery("acs_mcb4b", "launch/acs-mcb4b.toml", Reach::Tcp("127.0.0.1:4001"), "acs1");
}

#[test]
fn newport_smc100_on_a_serial_line() {
    let reach = Reach::Pty("/tmp/zmotor-smc100");
    drive_through_loss_and_recovery("newport_smc100", "launch/newport-smc100.toml", reach, "smc1");
}

#[test]
fn pi_gcs2() {
    drive_through_loss_and_recovery("pi_gcs2", "launch/pi-gcs2.toml", Reach::Tcp("127.0.0.1:50000"), "pi1");
}

#[test]
fn smaract_mcs2() {
    drive_through_loss_and_recovery("smaract_mcs2", "launch/smaract-mcs2.toml", Reach::Tcp("127.0.0.1:55551"), "mcs0");
}

#[test]
fn phytron() {
    drive_through_loss_and_recovery("phytron", "launch/phytron.toml", Reach::Tcp("127.0.0.1:22222"), "phy11");
}

#[test]
fn newport_esp300_on_a_serial_line() {
    let reach = Reach::Pty("/tmp/zmotor-esp300");
    drive_through_loss_and_recovery("newport_esp300", "launch/newport-esp300.toml", reach, "esp1");
}

#[test]
fn galil() {
    drive_through_loss_and_recovery("galil", "launch/galil.toml", Reach::Tcp("127.0.0.1:2323"), "galA");
}

#[test]
fn mclennan_pm304_on_a_serial_line() {
    let reach = Reach::Pty("/tmp/zmotor-pm304");
    drive_through_loss_and_recovery("mclennan_pm304", "launch/mclennan-pm304.toml", reach, "pm1");
}

#[test]
fn newport_xps() {
    drive_through_loss_and_recovery("newport_xps", "launch/newport-xps.toml", Reach::Tcp("127.0.0.1:5001"), "xps1");
}

#[test]
fn ims_mdrive_on_a_serial_line() {
    let reach = Reach::Pty("/tmp/zmotor-mdrive");
    drive_through_loss_and_recovery("ims_mdrive", "launch/ims-mdrive.toml", reach, "mdrive1");
}

#[test]
fn oms_maxnet() {
    drive_through_loss_and_recovery("oms_maxnet", "launch/oms-maxnet.toml", Reach::Tcp("127.0.0.1:2023"), "omsX");
}

#[test]
fn vmc_lua_of_motor_script_motor_unchanged() {
    let vmc = Reach::Tcp("127.0.0.1:31337");
    drive_through_loss_and_recovery_with("vmc", "launch/vmc.toml", vmc, "vmc1", &["--no-home"]);
}

#[test]
fn a_script_reloaded_during_a_move_stops_it_and_runs_and_a_broken_one_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let original = common::repo_file("node/controllers/tests/scripts/motorScriptMotor/vmc.lua");
    let script = dir.path().join("vmc.lua");
    std::fs::copy(original, &script).unwrap();
    let here = free_local_endpoint().unwrap().trim_start_matches("tcp/").to_string();
    let text = std::fs::read_to_string(common::repo_file("launch/vmc.toml")).unwrap();
    let text = text
        .replace("../node/controllers/tests/scripts/motorScriptMotor/vmc.lua", script.to_str().unwrap())
        .replace("127.0.0.1:31337", &here);
    let file = dir.path().join("launch.toml");
    std::fs::write(&file, text).unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let _emulator = zmotor(&["sim-controller", "vmc", "--listen", &here]);
    let _node = launch_node(&file, &endpoint, dir.path());
    let args = [endpoint.as_str(), "vmc1", "VMC_MOTOR", script.to_str().unwrap()];
    let output = environment::run_script(environment::python_script("script_reload.py").args(args));
    let said = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success() && said.contains("script reload ok"), "{said}");
}

/// motorScriptMotor's `softMotor.lua`, unchanged, on a controller without a connection: its
/// `epics.put`/`epics.get` drive another axis of the node by its keys. A move of soft1 writes
/// gap.VAL, and soft1 is done, where gap is, once gap.RBV says it arrived. (Its `stop` writes
/// MOTOR_POSITION, in steps, as a target in EGU: the script's own slip, shown in virtual time.)
#[test]
fn soft_motor_lua_of_motor_script_motor_drives_another_axis_by_its_keys() {
    let dir = tempfile::tempdir().unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let original = common::repo_file("launch/soft-motor-script.toml");
    let beside = original.parent().unwrap().display().to_string();
    let text = std::fs::read_to_string(&original).unwrap();
    let text = text.replace("script = \"", &format!("script = \"{beside}/")).replace("tcp/127.0.0.1:7447", &endpoint);
    let file = dir.path().join("launch.toml");
    std::fs::write(&file, text).unwrap();
    let _node = launch_node(&file, &endpoint, dir.path());
    let host = common::Host::default();
    // Out of its COMM alarm once its script has read gap.RBV (gap is served after the first poll).
    const COMM_ERR: u32 = 0x1000;
    host.wait_for(&endpoint, "soft1", "MSTA", |msta| (msta as u32) & COMM_ERR == 0);
    let put = |args: &[&str]| {
        let output = host.zmotor(&["put", "soft1"]).args(args).args(["--connect", &endpoint]).output().unwrap();
        String::from_utf8_lossy(&output.stdout).into_owned() + &String::from_utf8_lossy(&output.stderr)
    };
    let said = put(&["VAL", "2", "--wait"]);
    let log = || std::fs::read_to_string(dir.path().join("node.log")).unwrap_or_default();
    assert!(said.contains("reached=1") && said.contains("RBV=2 "), "{said}\nthe node logged:\n{}", log());
    assert_eq!(host.get(&endpoint, "gap", "RBV"), Some(2.0), "gap is where soft1 went");
    let said = put(&["VAL", "-1.5", "--wait"]);
    assert!(said.contains("reached=1") && said.contains("RBV=-1.5 "), "{said}\nthe node logged:\n{}", log());
    assert_eq!(host.get(&endpoint, "gap", "RBV"), Some(-1.5));
}

#[test]
fn kohzu_sc_by_script_on_a_serial_line() {
    drive_through_loss_and_recovery("kohzu_sc", "launch/kohzu-sc.toml", Reach::Pty("/tmp/zmotor-kohzu"), "kohzu1");
}

#[test]
fn micronix_mmc_by_script_on_a_serial_line() {
    drive_through_loss_and_recovery("micronix_mmc", "launch/micronix-mmc.toml", Reach::Pty("/tmp/zmotor-mmc"), "mmc1");
}

#[test]
fn piezojena_nv40_by_script_on_a_serial_line() {
    let nv40 = Reach::Pty("/tmp/zmotor-nv40");
    let flags = ["--no-home", "--settles-at-once"];
    drive_through_loss_and_recovery_with("piezojena_nv40", "launch/piezojena-nv40.toml", nv40, "piezo0", &flags);
}

#[test]
fn faulhaber_mc_by_script_on_a_serial_line() {
    let mcdc = Reach::Pty("/tmp/zmotor-faulhaber");
    drive_through_loss_and_recovery("faulhaber_mc", "launch/faulhaber-mc.toml", mcdc, "fau1");
}

#[test]
fn newfocus_8742_by_script() {
    let pico = Reach::Tcp("127.0.0.1:2323");
    drive_through_loss_and_recovery_with("newfocus_8742", "launch/newfocus-8742.toml", pico, "pico1", &["--no-home"]);
}

#[test]
fn pmac() {
    drive_through_loss_and_recovery("pmac", "launch/pmac.toml", Reach::Tcp("127.0.0.1:1025"), "pmac1");
}

/// A stock third-party SMC100 client, yaqd-newport's daemon (tests/python/smc100_workflow.py),
/// resets, homes and moves a stage of the emulator served on a pseudo-terminal: the emulator
/// speaks the controller's bytes to software that was written for the real one.
#[test]
fn newport_smc100_for_a_third_party_client() {
    third_party_client_on_a_pseudo_terminal("newport_smc100", "smc100_workflow.py", "smc100 workflow ok");
}

/// `script DEVICE` against `protocol`'s emulator on a pseudo-terminal; panics with what it said
/// unless it ended saying `done`.
fn third_party_client_on_a_pseudo_terminal(protocol: &str, script: &str, done: &str) {
    let dir = tempfile::tempdir().unwrap();
    let tty = dir.path().join("tty");
    let _emulator = zmotor(&["sim-controller", protocol, "--pty", tty.to_str().unwrap()]);
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
    while !tty.exists() {
        assert!(std::time::Instant::now() < deadline, "the emulator made no pseudo-terminal at {}", tty.display());
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let output = environment::run_script(environment::python_script(script).arg(&tty));
    let said = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success() && said.contains(done), "{said}");
}

/// pymeasure's ESP300 instrument (a third party's, on PyPI) runs its users' workflow against
/// `zmotor sim-controller newport_esp300` on a pseudo-terminal (tests/python/esp300_pymeasure.py).
#[test]
fn newport_esp300_for_a_third_party_client() {
    third_party_client_on_a_pseudo_terminal("newport_esp300", "esp300_pymeasure.py", "esp300 workflow ok");
}

/// PI's own Python library (pipython) runs a PI user's workflow against `zmotor sim-controller
/// pi_gcs2`: the emulator answers what PI's software sends and parses (tests/python/pi_workflow.py).
#[test]
fn pi_gcs2_through_pipython() {
    vendor_software_against_the_emulator("pi_gcs2", "pi_workflow.py", "pi workflow ok");
}

/// Diamond's dls-pmaclib, the library of its PMAC tools, runs a Delta Tau user's workflow
/// against `zmotor sim-controller pmac` over the Ethernet protocol (tests/python/pmac_pmaclib.py).
#[test]
fn pmac_through_dls_pmaclib() {
    vendor_software_against_the_emulator("pmac", "pmac_pmaclib.py", "pmac workflow ok");
}

/// Newport's own Python driver for the XPS, as the `newportxps` package ships it (its
/// low-level `XPS` class): two sockets, a move one waits on aborted from the other.
#[test]
fn newport_xps_through_newportxps() {
    vendor_software_against_the_emulator("newport_xps", "xps_newportxps.py", "xps workflow ok");
}

/// `script HOST PORT` against `protocol`'s emulator on a free port; panics with what it said
/// unless it ended saying `done`.
fn vendor_software_against_the_emulator(protocol: &str, script: &str, done: &str) {
    let address = free_local_endpoint().unwrap().trim_start_matches("tcp/").to_string();
    let (host, port) = address.rsplit_once(':').expect("host:port");
    let _emulator = zmotor(&["sim-controller", protocol, "--listen", &address]);
    let mut said = String::new();
    // The emulator takes a moment to listen.
    for _ in 0..50 {
        let output = environment::run_script(environment::python_script(script).args([host, port]));
        said = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
        if output.status.success() && said.contains(done) {
            return;
        }
        if !said.contains("Connection refused") && !said.contains("connection refused") {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    panic!("{said}");
}

/// A controller's error reaches the client, not only the node's log. A move of a PI axis that
/// was never referenced is refused before it is sent, saying how to reference it; once homed, a
/// target beyond the controller's travel range (the record's limits set wider) is refused by
/// the controller itself (PI error 7). `zmotor monitor pi1 ERR` shows both, and the answer of
/// the `zmotor put … --wait` that caused each names it once.
#[test]
fn a_controllers_error_reaches_the_axis_err() {
    let dir = tempfile::tempdir().unwrap();
    let here = free_local_endpoint().unwrap().trim_start_matches("tcp/").to_string();
    let text =
        std::fs::read_to_string(common::repo_file("launch/pi-gcs2.toml")).unwrap().replace("127.0.0.1:50000", &here);
    let file = dir.path().join("launch.toml");
    std::fs::write(&file, text).unwrap();
    let endpoint = free_local_endpoint().unwrap();
    let _emulator = zmotor(&["sim-controller", "pi_gcs2", "--listen", &here]);
    let _node = launch_node(&file, &endpoint, dir.path());
    // Served, and its controller reached (the emulator may start listening after the node).
    const COMM_ERR: u32 = 0x1000;
    common::Host::default().wait_for(&endpoint, "pi1", "MSTA", |msta| (msta as u32) & COMM_ERR == 0);
    let mut monitor = Command::new(env!("CARGO_BIN_EXE_zmotor"))
        .args(["monitor", "pi1", "DMOV", "ERR", "--connect", &endpoint])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let lines = common::Lines::of(&mut monitor);
    let _monitor = Running(monitor);
    // The monitor is live once it showed DMOV's current value.
    assert!(lines.wait_for(common::PATIENCE, |l| l.starts_with("pi1.DMOV")).is_some(), "the monitor started");
    let put = |args: &[&str]| {
        let output = Command::new(env!("CARGO_BIN_EXE_zmotor"))
            .args(["put", "pi1"])
            .args(args)
            .args(["--connect", &endpoint])
            .output()
            .unwrap();
        String::from_utf8_lossy(&output.stdout).into_owned() + &String::from_utf8_lossy(&output.stderr)
    };
    let said_once = |said: &str, line: &str| said.lines().filter(|l| l.starts_with(line)).count() == 1;

    let said = put(&["VAL", "1", "--wait"]);
    let why = "not referenced: home the axis first (HOMF or HOMR)";
    let err = |l: &str| l.starts_with("pi1.ERR") && l.contains(why);
    assert!(lines.wait_for(common::PATIENCE, err).is_some(), "ERR said why before trying; the put said {said}");
    assert!(said.contains("reached=0") && said_once(&said, &format!("ERR: c884: {why}")), "{said}");

    // Homed without alarm (MISS stays as the refused move left it: no retry check follows a
    // home, as in the record), at the reference switch, which counts 0.
    let said = put(&["HOMF", "1", "--wait"]);
    assert!(said.contains("SEVR=0") && said.contains("RBV=0 "), "homed: {said}");
    const HOMED: u32 = 0x4000;
    common::Host::default().wait_for(&endpoint, "pi1", "MSTA", |msta| (msta as u32) & HOMED != 0);
    put(&["DHLM", "19.8"]);
    let said = put(&["VAL", "19.7", "--wait"]);
    let err = |l: &str| l.starts_with("pi1.ERR") && l.contains("controller error 7: Position out of limits");
    assert!(lines.wait_for(common::PATIENCE, err).is_some(), "ERR named PI's error 7; the put said {said}");
    assert!(said.contains("reached=0"), "{said}");
    assert!(said_once(&said, "ERR: c884: controller error 7: Position out of limits"), "once: {said}");
}

#[test]
fn an_emulator_whose_port_is_taken_says_which_address_it_could_not_listen_on() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let address = taken.local_addr().unwrap().to_string();
    let output = Command::new(env!("CARGO_BIN_EXE_zmotor"))
        .args(["sim-controller", "acs_mcb4b", "--listen", &address])
        .env("RUST_LOG", "off")
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{said}");
    assert!(said.contains(&format!("cannot listen on {address} (--listen): ")), "{said}");
}
