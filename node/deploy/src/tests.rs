//! The launch model checked against files as users write them.

use crate::*;
use std::path::Path;
use std::time::Duration;
use zmotor_bridge::InputMode;
use zmotor_controllers::{MacroValue, ProtocolKind};
use zmotor_controllers::{Parity, Transport};
use zmotor_core::DriverPlan;

const WIRING: &str = r#"
        [[axis]]
        name = "lin"
        [[axis]]
        name = "rot"
        driver = "soft"
        [axis.fields]
        OUT = "bridge/drive/A"
        RDBL = "bridge/readback"
        DINP = "motor/lin/DMOV"
        STOO = "motor/lin/STOP"
        URIP = "Yes"
        [[calc]]
        name = "drive"
        expression = "TAN(A/57.296)*1000"
        inputs = { A = "bridge/drive/A" }
        output = "motor/lin/DVAL"
        [[calc]]
        name = "readback"
        expression = "ATAN(A/1000)*57.296"
        inputs = { A = "motor/lin/DRBV" }
        output = "bridge/readback"
    "#;

#[test]
fn the_tangent_arm_wiring_is_accepted() {
    let deployment = Launch::parse(WIRING).unwrap().deployment(None).unwrap();
    assert_eq!(deployment.contents.calcs[0].inputs[0].mode, InputMode::Process);
    assert_eq!(deployment.contents.plans[1].driver, DriverPlan::Soft);
    assert_eq!(deployment.contents.plans[1].fields.dtyp, "Soft Channel");
}

#[test]
fn broken_wiring_is_refused_at_start() {
    let cycle = WIRING
        .replace(r#"inputs = { A = "motor/lin/DRBV" }"#, r#"inputs = { A = "motor/lin/DVAL" }"#)
        .replace(r#"output = "bridge/readback""#, r#"output = "bridge/drive/A""#);
    assert_eq!(
        Launch::parse(&cycle).unwrap_err().message,
        "calc links form a loop with no motor in between: drive → readback → drive"
    );
    let read_only = WIRING.replace(r#"output = "motor/lin/DVAL""#, r#"output = "motor/lin/RBV""#);
    assert_eq!(Launch::parse(&read_only).unwrap_err().message, "calc 'drive' output: motor/lin/RBV: RBV is read-only");
    let unknown = WIRING.replace("motor/lin/DRBV", "motor/lin/DRBX");
    assert_eq!(
        Launch::parse(&unknown).unwrap_err().message,
        "calc 'readback' input A: motor/lin/DRBX: 'DRBX' is not a field of a motor"
    );
    let unknown_axis_link = WIRING.replace(r#"DINP = "motor/lin/DMOV""#, r#"DINP = "motor/lin/DONE""#);
    assert!(Launch::parse(&unknown_axis_link).unwrap_err().message.starts_with("axis 'rot' DINP: motor/lin/DONE"));
    let npp = WIRING.replace(
        r#"inputs = { A = "motor/lin/DRBV" }"#,
        r#"inputs = { A = { key = "motor/lin/DRBV", mode = "sometimes" } }"#,
    );
    assert!(Launch::parse(&npp).unwrap_err().message.contains("'sometimes' is not one of cp, npp"));
}

const GOOD: &str = r#"
        [zenoh]
        listen = ["tcp/127.0.0.1:7447"]
        [[axis]]
        name = "m1"
        readback_rate = 50
        [axis.fields]
        MRES = 0.001
        VELO = 10
        DIR = "Neg"
        EGU = "mm"
        [axis.sim]
        high_limit_switch = 105000
    "#;

#[test]
fn a_good_file_builds_its_axes() {
    let deployment = Launch::parse(GOOD).unwrap().deployment(None).unwrap();
    assert_eq!(deployment.zenoh.mode, Mode::Peer);
    assert!(!deployment.zenoh.multicast_scouting);
    let plans = deployment.contents.plans;
    let f = &plans[0].fields;
    assert_eq!((f.mres, f.velo, f.dir, f.egu.as_str(), f.name.as_str()), (0.001, 10.0, 1, "mm", "m1"));
    assert!(matches!(&plans[0].driver, DriverPlan::Sim(sim) if sim.high_limit_switch == Some(105000.0)));
    assert_eq!(plans[0].rates.moving, Duration::from_millis(20));
}

#[test]
fn access_rules_and_tls_files_are_checked_and_resolved_against_the_launch_file() {
    let text = "[zenoh]\nlisten = [\"tls/127.0.0.1:7447\"]\n\
                    [zenoh.tls]\nca = \"certs/ca.pem\"\ncertificate = \"/etc/node.pem\"\nkey = \"node.key\"\nmutual = true\n\
                    [[zenoh.access]]\nname = \"operators\"\nmay = [\"drive\", \"configure\"]\ncert_common_names = [\"op\"]\n";
    let launch = Launch::from_text("lab.toml", text, Path::new("/srv/lab")).unwrap();
    let deployment = launch.deployment(None).unwrap();
    let tls = deployment.zenoh.tls.as_ref().unwrap();
    assert_eq!((tls.ca.as_str(), tls.certificate.as_deref()), ("/srv/lab/certs/ca.pem", Some("/etc/node.pem")));
    assert!(deployment.contents.guarded);
    assert!(!Launch::parse("").unwrap().deployment(None).unwrap().contents.guarded);

    let bad = |rule: &str| Launch::parse(&format!("[[zenoh.access]]\n{rule}")).unwrap_err().to_string();
    assert!(bad("name = \"x\"\nmay = []\nusernames = [\"u\"]").contains("zenoh.access 'x': grants nothing"));
    assert!(bad("name = \"x\"\nmay = [\"read\"]").contains("zenoh.access 'x': has no members"));
    assert!(bad("name = \"x\"\nmay = [\"fly\"]\nusernames = [\"u\"]").contains("unknown variant `fly`"));
    let twice = "name = \"x\"\nmay = [\"read\"]\nusernames = [\"u\"]\n";
    assert!(bad(&format!("{twice}[[zenoh.access]]\n{twice}")).contains("zenoh.access 'x': is defined twice"));
}

#[test]
fn a_hosts_tls_keys_go_over_the_networks_and_never_turn_mutual_tls_off_unsaid() {
    let text = "[zenoh]\nlisten = [\"quic/127.0.0.1:7447\"]\n\
                [zenoh.tls]\nca = \"ca.pem\"\ncertificate = \"node.pem\"\nkey = \"node.key\"\nmutual = true\n\
                [hosts.optics.tls]\ncertificate = \"optics.pem\"\nkey = \"optics.key\"\n\
                [hosts.open.tls]\nmutual = false\n\
                [[axis]]\nname = \"m1\"\nhost = \"optics\"\n[[axis]]\nname = \"m2\"\nhost = \"open\"\n";
    let launch = Launch::from_text("lab.toml", text, Path::new("/srv/lab")).unwrap();
    let tls = |host| launch.deployment(Some(host)).unwrap().zenoh.tls.unwrap();
    let optics = tls("optics");
    assert_eq!((optics.ca.as_str(), optics.certificate.as_deref()), ("/srv/lab/ca.pem", Some("/srv/lab/optics.pem")));
    assert!(optics.mutual, "a host naming its own certificate keeps mutual TLS");
    let open = tls("open");
    assert_eq!((open.certificate.as_deref(), open.mutual), (Some("/srv/lab/node.pem"), false));
    let orphan = "[hosts.a.tls]\ncertificate = \"a.pem\"\n[[axis]]\nname = \"m1\"\nhost = \"a\"\n";
    let error = Launch::parse(orphan).unwrap().deployment(Some("a")).unwrap_err();
    assert_eq!(error.message, "hosts.a.tls: ca: no certificate authority here nor in [zenoh.tls]");
}

#[test]
fn a_channel_access_section_runs_on_its_host() {
    let text = "[hosts.a]\n[hosts.b]\n[channel_access]\npv_prefix = \"bl1:\"\nport = 5070\nhost = \"b\"\n";
    let launch = Launch::parse(text).unwrap();
    assert_eq!(launch.deployment(Some("a")).unwrap().channel_access, None);
    let ca = launch.deployment(Some("b")).unwrap().channel_access.unwrap();
    assert_eq!((ca.pv_prefix.as_str(), ca.port, ca.address.to_string()), ("bl1:", 5070, "127.0.0.1".into()));
    let unknown = Launch::parse("[channel_access]\nhost = \"c\"\n").unwrap_err().to_string();
    assert!(unknown.contains("channel_access.host: 'c' is not declared"), "{unknown}");
    let web = Launch::parse("[web]\naddress = \"0.0.0.0:8081\"\nnames = [\"bl1-screen\"]\n").unwrap();
    let web = web.deployment(None).unwrap().web.unwrap();
    assert_eq!((web.address.to_string(), web.names), ("0.0.0.0:8081".into(), vec!["bl1-screen".to_string()]));
    let unknown = Launch::parse("[web]\nhost = \"c\"\n").unwrap_err().to_string();
    assert!(unknown.contains("web.host: 'c' is not declared"), "{unknown}");
    let nowhere = Launch::parse("[hosts.a]\n[hosts.b]\n[web]\n").unwrap_err().to_string();
    assert_eq!(nowhere, "<launch>:3: [web] names no host, and this launch declares hosts");
}

#[test]
fn a_ros2_section_makes_joints_of_the_launchs_axes_and_bad_ones_are_named() {
    let axes = "[[axis]]\nname = \"m1\"\n[[axis]]\nname = \"m2\"\n";
    let text = format!(
        "[ros2]\ndomain_id = 7\nnamespace = \"/arm\"\ndistribution = \"humble\"\nrest_period = 0.5\nmax_rate = 20.0\n\
         [[ros2.joint]]\nname = \"lift\"\naxis = \"m1\"\n[[ros2.joint]]\nname = \"turn\"\naxis = \"m2\"\nfactor = 0.5\n{axes}"
    );
    let ros2 = Launch::parse(&text).unwrap().deployment(None).unwrap().ros2.unwrap();
    assert_eq!((ros2.domain_id, ros2.namespace.as_str(), ros2.node_name.as_str()), (7, "/arm", "zmotor"));
    assert_eq!((ros2.distribution, ros2.rest_period), (Distribution::Humble, Duration::from_millis(500)));
    assert_eq!(ros2.max_rate, 20.0);
    assert_eq!(ros2.joints[1], JointConfig { name: "turn".into(), axis: "m2".into(), factor: Some(0.5) });
    let bad = |section: &str| Launch::parse(&format!("[ros2]\n{section}\n{axes}")).unwrap_err().to_string();
    let joint = "[[ros2.joint]]\nname = \"lift\"\naxis = \"m1\"";
    assert!(bad(&format!("{joint}\n[[ros2.joint]]\nname = \"x\"\naxis = \"m9\""))
        .contains(":2: joint 'x': no axis 'm9' in this launch (known: m1, m2)"));
    assert!(bad(&format!("node_name = \"9lives\"\n{joint}")).contains("node_name: '9lives' is not a ROS name"));
    assert!(bad(&format!("namespace = \"arm\"\n{joint}")).contains("namespace: 'arm' is not a ROS namespace"));
    assert!(bad(&format!("distribution = \"iron\"\n{joint}")).contains("distribution: 'iron' is not jazzy or humble"));
    assert!(bad(&format!("{joint}\n{joint}")).contains("joint 'lift': a joint needs a name of its own"));
    assert!(bad(&format!("{joint}\nfactor = -1.0")).contains("joint 'lift': factor must be a positive number"));
    assert!(bad("").contains("no joints"));
    assert!(bad(&format!("{joint}\nunits = \"m\"")).contains("unknown field `units`"));
    let guarded = format!(
        "[zenoh]\nlisten = [\"tcp/127.0.0.1:7447\"]\n[[zenoh.access]]\nname = \"ops\"\nmay = [\"drive\"]\n\
         usernames = [\"ops\"]\n[ros2]\n{joint}\n{axes}"
    );
    let refused = Launch::parse(&guarded).unwrap_err().to_string();
    assert!(refused.contains("[ros2] cannot run under [[zenoh.access]] rules yet"), "{refused}");
}

#[test]
fn errors_name_the_axis_and_key() {
    let bad = |text: &str| Launch::parse(text).unwrap_err().to_string();
    assert!(bad("[[axis]]\nname = \"m1\"\n[axis.fields]\nNOPE = 1").contains("axis 'm1': fields.NOPE: no such field"));
    assert!(bad("[[axis]]\nname = \"m1\"\n[axis.fields]\nRBV = 1").contains("fields.RBV: read-only"));
    assert!(bad("[[axis]]\nname = \"m1\"\n[axis.fields]\nDIR = \"Up\"").contains("'Up' is not a choice"));
    assert!(bad("[[axis]]\nname = \"m1\"\n[axis.fields]\nVELO = \"fast\"").contains("VELO: wrong type"));
    assert!(bad("[[axis]]\nname = \"m/1\"").contains("axis 'm/1': name"));
    assert!(bad("[[axis]]\nname = \"m1\"\ndriver = \"xps\"").contains("not a known driver"));
    assert!(bad("[[calc]]\nname = \"c\"\nexpression = \"A+\"\noutput = \"x\"")
        .contains("calc 'c': expression 'A+': column 3"));
    assert!(bad("[[calc]]\nname = \"c\"\nexpression = \"A\"\noutput = \"x\"\ninputs = { Q = \"y\" }")
        .contains("inputs are A to P"));
    assert!(bad("[[calc]]\nname = \"c\"\nexpression = \"A\"\noutput = \"x/*\"").contains("not a plain key"));
    assert!(bad("[[axis]]\nname = \"m1\"\nreadback_rate = 5000").contains("readback_rate"));
    assert!(bad("[[axis]]\nname = \"m1\"\n[[axis]]\nname = \"m1\"").contains("defined twice"));
    assert!(bad("[zenoh]\nmode = \"server\"").contains("zenoh.mode"));
    assert!(bad("[[axis]]\nname = \"m1\"\nspeed = 3").contains("unknown field"));
    assert!(bad("[[axis]\nname = ").starts_with("<launch>:1: "));
}

#[test]
fn a_launch_file_configures_an_axis_and_never_commands_it() {
    let bad = |fields: &str| Launch::parse(&format!("[[axis]]\nname = \"m1\"\n[axis.fields]\n{fields}")).map(|_| ());
    // Each would act at the axis's first write (a home, a tweak, a stop, a held target).
    for command in ["HOMF = 1", "TWF = 1", "STOP = 1", "JOGR = 1", "SPMG = \"Stop\"", "RLV = 2", "SYNC = 1"] {
        let error = bad(command).expect_err(command).to_string();
        assert!(error.contains("a command, not a setting"), "{command}: {error}");
    }
    for start in ["VAL = 5", "RVAL = 50000"] {
        assert!(bad(start).expect_err(start).to_string().contains("DVAL sets its position"), "{start}");
    }
    // Validated as writes are: a resolution of 0, a flag to a speed, a number to a link.
    for refused in ["MRES = 0", "UREV = 0.0", "VELO = true", "OUT = 5"] {
        assert!(bad(refused).is_err(), "{refused}");
    }
    for setting in ["DVAL = 5", "TWV = 2", "CNEN = 1", "VELO = 2", "MRES = 0.001"] {
        assert!(bad(setting).is_ok(), "{setting}: {:?}", bad(setting));
    }
}

#[test]
fn a_value_holder_keeps_out_of_the_axes_keys() {
    let holder = |key: &str| Launch::parse(&format!("[[value]]\nname = \"r\"\n{key}")).map(|_| ());
    for taken in ["key = \"motor/m1/VAL\"", "key = \"motor/r\"", "key = \"motor\""] {
        let error = holder(taken).expect_err(taken).to_string();
        assert!(error.contains("a value holder there would answer for an axis"), "{taken}: {error}");
    }
    let bridge = Launch::parse("[zenoh]\nprefix = \"bridge\"\n[[value]]\nname = \"r\"").map(|_| ());
    assert!(bridge.unwrap_err().to_string().contains("'bridge/r/VAL', its key by default, is under"));
    for free in ["", "key = \"lab/r\"", "key = \"motors/m1/VAL\""] {
        assert!(holder(free).is_ok(), "{free}: {:?}", holder(free));
    }
}

#[test]
fn errors_found_after_parsing_point_at_their_line() {
    let text = "[zenoh]\nprefix = \"motor\"\n\n[[axis]]\nname = \"m1\"\n\n[[axis]]\nname = \"m2\"\n[axis.fields]\nVELO = 2\nNOPE = 1\n";
    assert_eq!(Launch::parse(text).unwrap_err().to_string(), "<launch>:11: axis 'm2': fields.NOPE: no such field");
    let wiring = WIRING.replace(r#"output = "motor/lin/DVAL""#, r#"output = "motor/lin/RBV""#);
    let error = Launch::parse(&wiring).unwrap_err();
    assert_eq!(error.line, Some(WIRING.lines().position(|l| l.contains("name = \"drive\"")).unwrap()));
    let mode = Launch::parse("[zenoh]\nlisten = []\nmode = \"server\"").unwrap_err();
    assert_eq!(mode.to_string(), "<launch>:3: zenoh.mode: 'server' is not one of peer, client, router");
    // A value of the wrong type is named by its key, as the errors found after parsing are.
    let typed = Launch::parse("[[axis]]\nname = \"m1\"\ndriver = \"sim\"\nreadback_rate = \"x\"\n").unwrap_err();
    assert_eq!(typed.to_string(), "<launch>:4: axis 'm1': readback_rate: invalid type: string \"x\", expected f64");
    // The simulator's model: positions that are numbers, an encoder of counts; a sim's only.
    let sim = |table: &str| {
        let text = format!("[[axis]]\nname = \"m1\"\ndriver = \"soft\"\n[axis.sim]\n{table}\n");
        let text = if table.contains("servo") { text } else { text.replace("driver = \"soft\"\n", "") };
        Launch::parse(&text).map(drop).map_err(|e| e.to_string())
    };
    assert_eq!(
        sim("position = nan"),
        Err("<launch>:3: axis 'm1': sim: position: NaN is not a finite number of steps".into())
    );
    assert_eq!(
        sim("high_limit_switch = inf"),
        Err("<launch>:3: axis 'm1': sim: high_limit_switch: inf is not a finite number of steps".into())
    );
    let no_counts = sim("encoder_counts_per_step = 0").unwrap_err();
    assert!(
        no_counts.ends_with("0 is not a number of counts more than 0 (leave it out for no encoder)"),
        "{no_counts}"
    );
    assert_eq!(sim("position = 5"), Ok(()));
    let soft = sim("servo = true").unwrap_err();
    assert!(soft.ends_with("axis 'm1': sim: the simulator's model, for driver = \"sim\" only"), "{soft}");
    // The prefix every key starts with is one plain key.
    for (prefix, reason) in [("", "it is empty"), ("motor/*", "wildcards select many keys"), ("lab/", "an empty chunk")]
    {
        let text = format!("[zenoh]\nprefix = \"{prefix}\"\n\n[[axis]]\nname = \"m1\"\n");
        let error = Launch::parse(&text).unwrap_err().to_string();
        assert!(error.starts_with(&format!("<launch>:2: zenoh.prefix: '{prefix}' is not a plain key: ")), "{error}");
        assert!(error.contains(reason), "{error}");
    }
}

const CONTROLLED: &str = r#"[[controller]]
name = "mcb"
protocol = "acs_mcb4b"
tcp = "127.0.0.1:4001"
moving_poll = 0.05

[[axis]]
name = "x"
driver = "controller"
controller = "mcb"
channel = 2

[[axis]]
name = "y"
driver = "controller"
controller = "mcb"
channel = 0
"#;

#[test]
fn a_path_to_a_device_or_a_huge_file_is_refused_without_reading_it_all() {
    let error = Launch::load(std::path::Path::new("/dev/zero")).unwrap_err().to_string();
    assert!(error.contains("/dev/zero") && error.contains("not a regular file"), "{error}");
    let dir = tempfile::tempdir().unwrap();
    let huge = dir.path().join("huge.toml");
    std::fs::write(&huge, vec![b'#'; (16 << 20) + 1]).unwrap();
    let error = Launch::load(&huge).unwrap_err().to_string();
    assert!(error.contains("larger than 16 MiB"), "{error}");
}

#[test]
fn a_launch_that_serves_nothing_says_so() {
    let empty = Launch::parse("# nothing yet\n").unwrap();
    assert_eq!(empty.warnings(), ["<launch>: no axis, calc link, value holder or controller: nothing to serve"]);
    assert!(Launch::parse("[[axis]]\nname = \"m1\"").unwrap().warnings().is_empty());
}

#[test]
fn two_controllers_on_one_connection_are_refused() {
    let second = |connection: &str| {
        format!("{CONTROLLED}\n[[controller]]\nname = \"again\"\nprotocol = \"acs_mcb4b\"\n{connection}\n")
    };
    let error = Launch::parse(&second("tcp = \"127.0.0.1:4001\"")).unwrap_err().to_string();
    assert!(error.contains("controller 'again': tcp: tcp 127.0.0.1:4001 is already controller 'mcb'"), "{error}");
    assert!(Launch::parse(&second("tcp = \"127.0.0.1:4002\"")).is_ok(), "another connection");
}

#[test]
fn a_controller_drives_the_channels_of_its_axes() {
    let deployment = Launch::parse(CONTROLLED).unwrap().deployment(None).unwrap();
    let [mcb] = &deployment.contents.controllers[..] else { panic!("one controller") };
    assert_eq!(
        (mcb.protocol, &mcb.transport),
        (ProtocolKind::AcsMcb4b, &Transport::Tcp { address: "127.0.0.1:4001".into() })
    );
    assert_eq!((mcb.config.channels.clone(), mcb.config.moving_poll), (vec![2, 0], Duration::from_millis(50)));
    let x = &deployment.contents.plans[0];
    assert_eq!(x.driver, DriverPlan::Controller { controller: "mcb".into(), channel: 2 });
    assert_eq!(x.fields.dtyp, "asynMotor");
    let serial = CONTROLLED.replace(
        r#"tcp = "127.0.0.1:4001""#,
        r#"serial = { device = "/dev/ttyS0", baud = 19200, parity = "even", stop_bits = 2 }"#,
    );
    let deployment = Launch::parse(&serial).unwrap().deployment(None).unwrap();
    let Transport::Serial(line) = &deployment.contents.controllers[0].transport else { panic!("a serial line") };
    assert_eq!((line.baud, line.parity, line.data_bits, line.stop_bits), (19200, Parity::Even, 8, 2));
    assert!(!mcb.config.observe, "a controller is driven unless said otherwise");
    let observed = CONTROLLED.replace("moving_poll = 0.05", "moving_poll = 0.05\nobserve = true");
    let deployment = Launch::parse(&observed).unwrap().deployment(None).unwrap();
    assert!(deployment.contents.controllers[0].config.observe);
}

#[test]
fn units_per_step_on_a_controller_that_counts_motor_steps_is_an_error() {
    let scaled = CONTROLLED.replace("moving_poll = 0.05", "moving_poll = 0.05\nunits_per_step = 0.001");
    let error = Launch::parse(&scaled).unwrap_err().to_string();
    assert!(error.contains("units_per_step: acs_mcb4b counts motor steps"), "{error}");
}

#[test]
fn an_xps_on_a_serial_line_is_an_error_at_load() {
    let serial = CONTROLLED
        .replace("protocol = \"acs_mcb4b\"", "protocol = \"newport_xps\"")
        .replace("tcp = \"127.0.0.1:4001\"\n", "")
        .replace(
            "moving_poll = 0.05\n",
            "moving_poll = 0.05\n[controller.serial]\ndevice = \"/dev/ttyS0\"\nbaud = 9600\n",
        )
        .replace("channel = 0", "channel = 1");
    let error = Launch::parse(&serial).unwrap_err().to_string();
    assert!(error.contains("newport_xps opens a connection for each axis's motion"), "{error}");
    let tcp = CONTROLLED
        .replace("protocol = \"acs_mcb4b\"", "protocol = \"newport_xps\"")
        .replace("channel = 0", "channel = 1");
    assert!(Launch::parse(&tcp).is_ok(), "over TCP it loads");
}

#[test]
fn an_xps_takes_its_positioners_names_and_no_other_controller_does() {
    let xps = CONTROLLED
        .replace("protocol = \"acs_mcb4b\"", "protocol = \"newport_xps\"")
        .replace("channel = 0", "channel = 1");
    let named = xps.replace("moving_poll = 0.05\n", "moving_poll = 0.05\naxis_names = { 2 = \"FINE.X\" }\n");
    let deployment = Launch::parse(&named).unwrap().deployment(None).unwrap();
    assert_eq!(deployment.contents.controllers[0].options.names, [(2, "FINE.X".to_string())].into());
    let bad = xps.replace("moving_poll = 0.05\n", "moving_poll = 0.05\naxis_names = { 2 = \"FINE X\" }\n");
    let error = Launch::parse(&bad).unwrap_err().to_string();
    assert!(error.contains("axis_names") && error.contains("GROUP.POSITIONER"), "{error}");
    let acs = CONTROLLED.replace("moving_poll = 0.05\n", "moving_poll = 0.05\naxis_names = { 2 = \"A.B\" }\n");
    let error = Launch::parse(&acs).unwrap_err().to_string();
    assert!(error.contains("axis_names: acs_mcb4b numbers its axes"), "{error}");
}

#[test]
fn a_controller_knows_its_axes_units_to_compare_with_its_scale() {
    let units = CONTROLLED.replace("channel = 2\n", "channel = 2\n[axis.fields]\nEGU = \"um\"\nMRES = 0.5\n");
    let deployment = Launch::parse(&units).unwrap().deployment(None).unwrap();
    let record_units = &deployment.contents.controllers[0].config.record_units;
    assert_eq!(record_units[&2], zmotor_controllers::RecordUnits { egu: "um".into(), mres: 0.5 });
    assert_eq!(record_units[&0], zmotor_controllers::RecordUnits { egu: String::new(), mres: 0.0 }, "the defaults");
}

#[test]
fn controller_errors_name_the_file_line_and_key() {
    let refused = |from: &str, to: &str| Launch::parse(&CONTROLLED.replacen(from, to, 1)).unwrap_err().to_string();
    assert_eq!(
        refused("acs_mcb4b", "acme"),
        format!(
            "<launch>:3: controller 'mcb': protocol: 'acme' is not a known protocol (known: {})",
            ProtocolKind::known()
        )
    );
    assert_eq!(
        refused("127.0.0.1:4001", "127.0.0.1"),
        "<launch>:4: controller 'mcb': tcp: '127.0.0.1' is not host:port"
    );
    assert_eq!(
        refused("moving_poll = 0.05", "moving_poll = 0"),
        "<launch>:5: controller 'mcb': moving_poll: 0 s is outside [0.001, 10] s"
    );
    assert!(refused("moving_poll = 0.05", "parity = \"odd\"").starts_with("<launch>:5: unknown field `parity`"));
    assert_eq!(
        refused("tcp = \"127.0.0.1:4001\"", "tcp = \"h:1\"\nserial = { device = \"/dev/ttyS0\" }"),
        "<launch>:2: controller 'mcb': name: give one of tcp = \"host:port\" or a [controller.serial] port, not both"
    );
    assert_eq!(
        refused("tcp = \"127.0.0.1:4001\"", ""),
        "<launch>:2: controller 'mcb': name: give one of tcp = \"host:port\" or a [controller.serial] port (only a script may have neither)"
    );
    assert_eq!(
        refused("controller = \"mcb\"", "controller = \"other\""),
        "<launch>:10: axis 'x': controller: no [[controller]] 'other' (known: mcb)"
    );
    assert_eq!(
        refused("channel = 2", "channel = 4"),
        "<launch>:11: axis 'x': channel: channel 4: acs_mcb4b numbers its axes 0 to 3"
    );
    assert_eq!(
        refused("channel = 2", "channel = 0"),
        "<launch>:17: axis 'y': channel: channel 0 of controller 'mcb' is already axis 'x'"
    );
    assert_eq!(
        refused("driver = \"controller\"", "driver = \"sim\""),
        "<launch>:10: axis 'x': controller: only with driver = \"controller\""
    );
    assert_eq!(
        refused("channel = 2\n", ""),
        "<launch>:7: axis 'x': channel: the controller's number for the axis is missing"
    );
}

#[test]
fn a_database_of_asyn_motors_runs_on_the_launch_files_controllers() {
    let dir = tempfile::tempdir().unwrap();
    let db = r#"record(motor, "$(P)m1") { field(DTYP, "asynMotor") field(OUT, "@asyn(mcb,3)") field(MRES, "0.01") }"#;
    std::fs::write(dir.path().join("motors.db"), db).unwrap();
    let main = "[[database]]\nfile = \"motors.db\"\nmacros = { P = \"bl:\" }\n\n[[controller]]\nname = \"mcb\"\nprotocol = \"acs_mcb4b\"\ntcp = \"h:4001\"\n";
    std::fs::write(dir.path().join("main.toml"), main).unwrap();
    let launch = Launch::load(&dir.path().join("main.toml")).unwrap();
    let deployment = launch.deployment(None).unwrap();
    let axis = &deployment.contents.plans[0];
    assert_eq!((axis.name.as_str(), axis.fields.mres), ("bl:m1", 0.01));
    assert_eq!(axis.driver, DriverPlan::Controller { controller: "mcb".into(), channel: 3 });
    assert_eq!(deployment.contents.controllers[0].config.channels, [3]);
    std::fs::write(dir.path().join("motors.db"), db.replace("mcb,3", "mcb,9")).unwrap();
    let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
    assert!(error.file.ends_with("motors.db"), "the database is named: {error}");
    assert!(error.message.contains("acs_mcb4b numbers its axes 0 to 3"), "{error}");
}

#[test]
fn a_database_loaded_under_a_prefix_links_its_motors_there() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("arm.db"), include_str!("../../../launch/tangent-arm.db")).unwrap();
    let main = "[zenoh]\nprefix = \"lab\"\n\n[[database]]\nfile = \"arm.db\"\nmacros = { user = \"me\" }\n";
    std::fs::write(dir.path().join("main.toml"), main).unwrap();
    let deployment = Launch::load(&dir.path().join("main.toml")).unwrap().deployment(None).unwrap();
    let rotary = deployment.contents.plans.iter().find(|p| p.name == "me:rotary").unwrap();
    assert_eq!(
        (rotary.fields.stoo.as_str(), rotary.fields.dinp.as_str()),
        ("lab/me:linear/STOP", "lab/me:linear/DMOV")
    );
    let outputs: Vec<&str> = deployment.contents.calcs.iter().map(|c| c.output.as_str()).collect();
    assert!(outputs.contains(&"lab/me:linear/DVAL"), "{outputs:?}");
    // A macro's value is taken whole, its comma too.
    std::fs::write(dir.path().join("slit.db"), r#"record(motor, "m1") { field(DESC, "$(D)") }"#).unwrap();
    let main = "[[database]]\nfile = \"slit.db\"\nmacros = { D = \"slit, coarse\" }\n";
    std::fs::write(dir.path().join("main.toml"), main).unwrap();
    let deployment = Launch::load(&dir.path().join("main.toml")).unwrap().deployment(None).unwrap();
    assert_eq!(deployment.contents.plans[0].fields.desc, "slit, coarse");
}

const HOSTS: &str = r#"
        [zenoh]
        connect = ["tcp/10.0.0.1:7447"]
        [hosts.optics]
        listen = ["tcp/10.0.0.2:7447"]
        [hosts.detector]
        mode = "client"
        [[axis]]
        name = "m1"
        host = "optics"
        [[axis]]
        name = "m2"
        host = "detector"
        [[calc]]
        name = "c"
        host = "detector"
        expression = "A*2"
        inputs = { A = "motor/m1/RBV" }
        output = "bridge/c/VAL"
    "#;

#[test]
fn a_databases_records_run_on_its_host() {
    let dir = tempfile::tempdir().unwrap();
    let db = r#"record(motor, "$(P)m1") { field(DTYP, "asynMotor") field(OUT, "@asyn(mcb,3)") }
record(motor, "$(P)soft") { field(DTYP, "Soft Channel") field(RDBL, "$(P)m1.RBV") }
record(ao, "$(P)gap") { field(VAL, "2") }"#;
    std::fs::write(dir.path().join("motors.db"), db).unwrap();
    let main = "[hosts.optics]\n[hosts.user]\n[[axis]]\nname = \"u1\"\nhost = \"user\"\n\
                [[database]]\nfile = \"motors.db\"\nmacros = { P = \"bl:\" }\nhost = \"optics\"\n\
                [[controller]]\nname = \"mcb\"\nprotocol = \"acs_mcb4b\"\ntcp = \"h:4001\"\nhost = \"optics\"\n";
    std::fs::write(dir.path().join("main.toml"), main).unwrap();
    let launch = Launch::load(&dir.path().join("main.toml")).unwrap();
    let optics = launch.deployment(Some("optics")).unwrap();
    let names: Vec<&str> = optics.contents.plans.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["bl:m1", "bl:soft"]);
    assert_eq!((optics.contents.values.len(), optics.contents.controllers.len()), (1, 1));
    let user = launch.deployment(Some("user")).unwrap();
    assert_eq!(user.contents.plans.iter().map(|p| p.name.as_str()).collect::<Vec<_>>(), ["u1"]);
    assert!(user.contents.values.is_empty() && user.contents.controllers.is_empty());
    std::fs::write(dir.path().join("main.toml"), main.replace("host = \"optics\"\n[[controller]]", "[[controller]]"))
        .unwrap();
    let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
    assert!(error.file.ends_with("motors.db"), "{error}");
    assert_eq!(
        error.message,
        "axis 'bl:m1': names no host, and this launch declares hosts (its [[database]] entry names the host of its \
         records)"
    );
    std::fs::write(
        dir.path().join("main.toml"),
        main.replace("host = \"optics\"\n[[controller]]", "host = \"user\"\n[[controller]]"),
    )
    .unwrap();
    let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
    assert!(error.message.contains("controller 'mcb' runs on another host"), "{error}");
}

#[test]
fn each_host_starts_only_its_part() {
    let launch = Launch::parse(HOSTS).unwrap();
    let optics = launch.deployment(Some("optics")).unwrap();
    let names = |d: &Deployment| d.contents.plans.iter().map(|p| p.name.clone()).collect::<Vec<_>>();
    assert_eq!((names(&optics), optics.contents.calcs.len()), (vec!["m1".to_string()], 0));
    assert_eq!(optics.zenoh.listen, ["tcp/10.0.0.2:7447"]);
    assert_eq!(
        (optics.zenoh.mode.name(), optics.zenoh.connect.as_slice()),
        ("peer", &["tcp/10.0.0.1:7447".to_string()][..])
    );
    let detector = launch.deployment(Some("detector")).unwrap();
    assert_eq!(
        (names(&detector), detector.contents.calcs.len(), detector.zenoh.mode.name()),
        (vec!["m2".to_string()], 1, "client")
    );
    assert_eq!(names(&launch.deployment(None).unwrap()), ["m1", "m2"], "no --host: everything in one process");
    assert_eq!(
        launch.deployment(Some("sample")).unwrap_err().message,
        "--host sample: no such host (known: detector, optics)"
    );
    let stray = HOSTS.replace("host = \"detector\"\n        [[calc]]", "[[calc]]");
    assert!(Launch::parse(&stray).unwrap_err().message.contains("axis 'm2': names no host"));
    let undeclared = HOSTS.replace("host = \"optics\"", "host = \"sample\"");
    let error = Launch::parse(&undeclared).unwrap_err();
    assert_eq!(error.message, "axis 'm1': host 'sample' is not declared under [hosts] (known: detector, optics)");
    assert_eq!(error.line, Some(10));
}

#[test]
fn included_files_add_items_and_errors_name_the_included_file() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, text: &str| std::fs::write(dir.path().join(name), text).unwrap();
    write("main.toml", "include = [\"hutch/axes.toml\"]\n[[axis]]\nname = \"m0\"\n");
    std::fs::create_dir(dir.path().join("hutch")).unwrap();
    write("hutch/axes.toml", "include = [\"more.toml\"]\n[[axis]]\nname = \"m1\"\n");
    write("hutch/more.toml", "[[axis]]\nname = \"m2\"\n[axis.fields]\nVELO = \"fast\"\n");
    let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
    assert!(error.file.ends_with("hutch/more.toml"), "{error}");
    assert_eq!(error.line, Some(4));
    assert!(error.message.starts_with("axis 'm2': fields.VELO: wrong type: "), "the field is named once: {error}");
    write("hutch/more.toml", "[[axis]]\nname = \"m2\"\n");
    let launch = Launch::load(&dir.path().join("main.toml")).unwrap();
    let names: Vec<String> = launch.deployment(None).unwrap().contents.plans.into_iter().map(|p| p.name).collect();
    assert_eq!(names, ["m0", "m1", "m2"]);
    write("hutch/more.toml", "[zenoh]\nmode = \"client\"\n");
    let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
    assert_eq!((error.line, error.message.as_str()), (Some(1), "zenoh may only be set in the main launch file"));
    // A front-end in an included file would be dropped unsaid: refused, as the network is.
    write("hutch/more.toml", "[[axis]]\nname = \"m2\"\n\n[web]\n");
    let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
    assert_eq!((error.line, error.message.as_str()), (Some(4), "web may only be set in the main launch file"));
    write("hutch/more.toml", "include = [\"../main.toml\"]\n");
    let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
    assert!(error.file.ends_with("more.toml") && error.message.contains("main.toml is included twice"), "{error}");
    write("hutch/more.toml", "include = [\"missing.toml\"]\n");
    let error = Launch::load(&dir.path().join("main.toml")).unwrap_err();
    assert!(error.file.ends_with("more.toml") && error.message.contains("missing.toml"), "{error}");
}

#[test]
fn every_shipped_launch_file_loads() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../launch");
    let mut loaded = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let launch = Launch::load(&path).unwrap_or_else(|e| panic!("{e}"));
            for host in launch.hosts().map(str::to_string).collect::<Vec<_>>() {
                launch.deployment(Some(&host)).unwrap();
            }
            loaded += 1;
        }
    }
    assert!(loaded >= 4, "{loaded} launch files in {}", dir.display());
    let reference = Launch::load(&dir.join("reference.toml")).unwrap();
    let optics = reference.deployment(Some("optics")).unwrap();
    let names: Vec<&str> = optics.contents.plans.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["m1", "slit_top", "slit_bottom"], "the included slits run on the optics host");
    let user = reference.deployment(Some("user")).unwrap();
    assert_eq!((user.contents.calcs.len(), user.contents.values.len(), user.zenoh.mode.name()), (1, 1, "client"));
    assert_eq!(user.contents.calcs[0].processed_by, ["bridge/x_with_offset/PROC"]);
}

#[test]
fn state_dir_is_relative_to_the_launch_file() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("l.toml"), "state_dir = \"state\"\n[autosave]\ndelay = 0.2\n").unwrap();
    let deployment = Launch::load(&dir.path().join("l.toml")).unwrap().deployment(None).unwrap();
    assert_eq!(deployment.state_dir, Some(dir.path().join("state")));
    assert_eq!(deployment.autosave, AutosaveSection { enabled: true, delay: 0.2 });
    assert!(Launch::parse("[autosave]\ndelay = -1").unwrap_err().message.contains("autosave.delay"));
    for empty in ["\"\"", "\" \""] {
        let error = Launch::parse(&format!("state_dir = {empty}")).unwrap_err().to_string();
        assert!(error.contains("state_dir: empty"), "{error}");
    }
}

/// A script controller's launch file beside its script (and a module the script requires).
fn script_launch(script: &str, controller_extra: &str) -> (tempfile::TempDir, Result<Launch, LaunchError>) {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("scripts")).unwrap();
    std::fs::write(dir.path().join("scripts/ctl.lua"), script).unwrap();
    std::fs::write(dir.path().join("scripts/helper.lua"), "return { answer = 42 }").unwrap();
    let launch = format!(
        "[[controller]]\nname = \"ctl\"\nprotocol = \"script\"\ntcp = \"127.0.0.1:31337\"\nscript = \"scripts/ctl.lua\"\n{controller_extra}\n\
         [[axis]]\nname = \"x\"\ndriver = \"controller\"\ncontroller = \"ctl\"\nchannel = 0\n"
    );
    let path = dir.path().join("launch.toml");
    std::fs::write(&path, launch).unwrap();
    let loaded = Launch::load(&path);
    (dir, loaded)
}

#[test]
fn a_script_controller_carries_its_script_modules_macros_and_poll_periods() {
    let script = "h = require('helper')\nIdlePollPeriod = 2.0\nMovingPollPeriod = 0.25\nForcedFastPolls = 3\nfunction poll() end\n";
    let extra = "macros = { PORT = \"VMC\", GAIN = 2 }\naxis_macros = { 0 = { OPEN_LOOP = \"YES\" } }";
    let (_dir, launch) = script_launch(script, extra);
    let deployment = launch.unwrap().deployment(None).unwrap();
    let [ctl] = &deployment.contents.controllers[..] else { panic!("one controller") };
    let source = ctl.options.script.as_ref().expect("the script");
    assert!(source.path.ends_with("scripts/ctl.lua") && source.text == script, "{source:?}");
    assert_eq!(source.modules.keys().collect::<Vec<_>>(), ["helper"]);
    assert_eq!(source.driver, "ctl");
    assert_eq!(source.macros["PORT"], MacroValue::Text("VMC".into()));
    assert_eq!(source.macros["GAIN"], MacroValue::Integer(2));
    assert_eq!(source.axis_macros[&0]["OPEN_LOOP"], MacroValue::Text("YES".into()));
    let periods = (ctl.config.idle_poll, ctl.config.moving_poll, ctl.config.fast_polls);
    assert_eq!(periods, (Duration::from_secs(2), Duration::from_millis(250), 3), "the script's, as EPICS reads them");
    let (_dir, launch) = script_launch(script, "moving_poll = 0.05");
    let config = &launch.unwrap().deployment(None).unwrap().contents.controllers[0].config;
    assert_eq!(config.moving_poll, Duration::from_millis(50), "the launch file's over the script's");
}

#[test]
fn a_broken_or_missing_script_is_refused_at_load_naming_its_file_and_line() {
    let (_dir, launch) = script_launch("function move(\n", "");
    let error = launch.unwrap_err().to_string();
    assert!(error.contains("controller 'ctl': script:") && error.contains("scripts/ctl.lua:2:"), "{error}");
    let (dir, _) = script_launch("", "");
    let missing = std::fs::read_to_string(dir.path().join("launch.toml")).unwrap().replace("ctl.lua", "none.lua");
    std::fs::write(dir.path().join("launch.toml"), missing).unwrap();
    let error = Launch::load(&dir.path().join("launch.toml")).unwrap_err().to_string();
    assert!(error.contains("script:") && error.contains("none.lua"), "{error}");
    let (_dir, launch) = script_launch("", "macros = { PORT = [1, 2] }");
    let error = launch.unwrap_err().to_string();
    assert!(error.contains("macros: PORT is a array"), "{error}");
    let no_script = CONTROLLED.replace("protocol = \"acs_mcb4b\"", "protocol = \"script\"");
    let error = Launch::parse(&no_script).unwrap_err().to_string();
    assert!(error.contains("give the Lua script"), "{error}");
    let stray = CONTROLLED.replace("moving_poll = 0.05\n", "macros = { PORT = \"A\" }\n");
    let error = Launch::parse(&stray).unwrap_err().to_string();
    assert!(error.contains("only a script controller"), "{error}");
}
