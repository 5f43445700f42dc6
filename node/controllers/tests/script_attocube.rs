//! motorScriptMotor's own `Attocube_AMC.lua` (and the `json.lua` it requires), unchanged,
//! driving the attocube AMC100's emulator (written from attocube's interface manual and clients,
//! apart from the script) over JSON-RPC, in virtual time.

mod common;

use common::{bring_up, run_until_done, script_loopback, script_source, written_since};
use std::time::Duration;
use zmotor_controllers::{ControllerEvent, Loopback, MacroValue, ScriptSource};
use zmotor_emulators::{Faults, Model};
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const TICK: Duration = Duration::from_millis(250);

/// As st.cmd.Attocube_AMC configures it: `PORT='AMC-1_IP'`, axis 0 closed loop, axis 1 open.
fn amc() -> ScriptSource {
    let macros = [("PORT", MacroValue::Text("AMC-1_IP".into()))];
    let mut source =
        script_source("node/controllers/tests/scripts/motorScriptMotor/Attocube_AMC.lua", "AMC-1", &macros);
    source.axis_macros.insert(0, [("OPEN_LOOP".to_string(), MacroValue::Text("NO".into()))].into());
    source.axis_macros.insert(1, [("OPEN_LOOP".to_string(), MacroValue::Text("YES".into()))].into());
    source
}

fn loopback() -> Loopback {
    let mut lb = script_loopback(&amc(), Model::AttocubeAmc, &[0, 1], Faults::default());
    bring_up(&mut lb);
    lb
}

fn go(position: f64, relative: bool) -> DriverCommand {
    DriverCommand::Move { position, relative, min_velocity: 0.0, max_velocity: 1000.0, acceleration: 1e4 }
}

#[test]
fn a_poll_is_two_json_rpc_calls_as_the_script_encodes_them() {
    let mut lb = loopback();
    let polls = written_since(&lb, 0);
    // json.lua writes a table's members in Lua's order, which each Lua state seeds apart.
    for (line, method) in polls.iter().zip(["move.getPosition", "status.getFullCombinedStatus"]) {
        let members = [r#""api":2"#, r#""id":0"#, r#""jsonrpc":"2.0""#, r#""params":[0]"#];
        let method = format!(r#""method":"com.attocube.amc.{method}""#);
        assert!(line.starts_with('{') && line.ends_with('}'), "one JSON object, no terminator: {line}");
        assert!(members.iter().all(|m| line.contains(m)) && line.contains(&method), "{line}");
    }
    lb.run_for(Duration::from_secs(2));
    let events = lb.take_events();
    assert!(
        !events.iter().any(|e| matches!(e, ControllerEvent::Failed { .. } | ControllerEvent::ControllerError(_))),
        "{events:?}"
    );
    assert_eq!(common::last_status(&events, 0).msta & msta::DONE, msta::DONE);
}

#[test]
fn a_closed_loop_move_reaches_its_target_range_and_a_relative_one_from_there() {
    let mut lb = loopback();
    lb.command(0, &go(5000.0, false));
    let arrived = *run_until_done(&mut lb, 0, TICK, Duration::from_secs(20)).last().expect("done");
    assert!((arrived.position - 5000.0).abs() <= 100.0, "within the 100 nm target range: {arrived:?}");
    assert_eq!(arrived.encoder_position, arrived.position);
    lb.command(0, &go(-2000.0, true));
    let back = *run_until_done(&mut lb, 0, TICK, Duration::from_secs(20)).last().expect("done");
    assert!((back.position - (arrived.position - 2000.0)).abs() <= 100.0, "{back:?}");
}

#[test]
fn an_open_loop_axis_steps_and_counts_its_steps_as_its_position() {
    let mut lb = loopback();
    let from = lb.written().len();
    lb.command(1, &go(300.0, false));
    lb.run_for(Duration::from_secs(2));
    let sent = written_since(&lb, from);
    let steps = |l: &&String| {
        l.contains(r#""method":"com.attocube.amc.move.setNSteps""#) && l.contains(r#""params":[1,0,300]"#)
    };
    assert!(sent.iter().any(|l| steps(&l)), "{sent:?}");
    let status = common::last_status(&lb.take_events(), 1);
    assert_eq!(status.position, 300.0, "{status:?}");
}

#[test]
fn a_stop_ends_the_approach() {
    let mut lb = loopback();
    lb.command(0, &go(50_000.0, false));
    lb.run_for(Duration::from_secs(3));
    lb.command(0, &DriverCommand::Stop { acceleration: 1e4 });
    let stopped = *run_until_done(&mut lb, 0, TICK, Duration::from_secs(5)).last().expect("done");
    assert!(stopped.position > 1000.0 && stopped.position < 10_000.0, "{stopped:?}");
}

#[test]
fn a_home_the_controller_refuses_is_its_error_with_the_script_s_line() {
    let mut lb = loopback();
    let home = DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 1000.0, acceleration: 1e4 };
    lb.command(0, &home);
    lb.run_for(Duration::from_secs(2));
    let events = lb.take_events();
    let errors = common::controller_errors(&events);
    assert!(
        errors.iter().any(|(channel, _, meaning)| *channel == Some(0)
            && meaning.contains("Attocube_AMC.lua:")
            && meaning.contains("Error code: 2")),
        "moveReference without a reference: {events:?}"
    );
    assert_ne!(common::last_status(&events, 0).msta & msta::PROBLEM, 0);
}
