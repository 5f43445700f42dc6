//! motorScriptMotor's own `vmc.lua`, unchanged, driving the Virtual Motor Controller's emulator
//! (written from the VMC's sources, apart from the script) in virtual time: the bytes it writes,
//! motion through the record's commands, comm loss, and no command sequence that makes a line
//! the VMC cannot read.

mod common;

use common::{bring_up, go, run_until_done, script_loopback, script_source, written_since};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{ControllerEvent, Loopback, MacroValue, ScriptSource};
use zmotor_emulators::{Faults, Model};
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const CHANNELS: [usize; 2] = [0, 1];
const TICK: Duration = Duration::from_millis(50);

/// vmc.lua as st.cmd.script configures it: `ScriptControllerConfig("VMC_MOTOR", 1, "vmc.lua", "PORT=VMC")`.
fn vmc() -> ScriptSource {
    let macros = [("PORT", MacroValue::Text("VMC".into()))];
    script_source("node/controllers/tests/scripts/motorScriptMotor/vmc.lua", "VMC_MOTOR", &macros)
}

fn loopback(faults: Faults) -> Loopback {
    script_loopback(&vmc(), Model::Vmc, &CHANNELS, faults)
}

#[test]
fn a_poll_writes_what_vmc_lua_writes_and_reads_position_and_status() {
    let mut lb = loopback(Faults::default());
    bring_up(&mut lb);
    let polls = written_since(&lb, 0);
    assert_eq!(polls[..4], ["1 POS?\r\n", "1 ST?\r\n", "2 POS?\r\n", "2 ST?\r\n"], "{polls:?}");
    lb.run_for(Duration::from_secs(3));
    let status = common::last_status(&lb.take_events(), 1);
    assert_eq!(status.msta & (msta::DONE | msta::MOVING), msta::DONE, "{status:?}");
}

#[test]
fn a_move_arrives_where_asked_and_a_relative_one_from_there() {
    let mut lb = loopback(Faults::default());
    bring_up(&mut lb);
    let from = lb.written().len();
    common::a_move_arrives_where_asked_and_a_relative_one_from_there(&mut lb, 1, go);
    let sent = written_since(&lb, from);
    let motion: Vec<&String> = sent.iter().filter(|l| !l.ends_with("?\r\n")).collect();
    assert_eq!(
        motion[..4],
        ["2 BAS 0.000000\r\n", "2 VEL 20000.000000\r\n", "2 ACC 200000.000000\r\n", "2 MV 12345\r\n"],
        "{sent:?}"
    );
    assert!(sent.contains(&"2 MR -2345\r\n".to_string()), "{sent:?}");
}

#[test]
fn a_jog_runs_until_stopped() {
    let mut lb = loopback(Faults::default());
    bring_up(&mut lb);
    let jog = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -5000.0, acceleration: 50_000.0 };
    lb.command(0, &jog);
    lb.run_for(Duration::from_secs(1));
    let status = common::last_status(&lb.take_events(), 0);
    assert_eq!(status.msta & (msta::DONE | msta::MOVING), msta::MOVING, "{status:?}");
    assert!(status.position < -2000.0, "{status:?}");
    let from = lb.written().len();
    lb.command(0, &DriverCommand::Stop { acceleration: 50_000.0 });
    let stopped = *run_until_done(&mut lb, 0, TICK, Duration::from_secs(3)).last().expect("done");
    assert!(stopped.position > -8000.0, "stopped soon after the stop: {stopped:?}");
    assert_eq!(written_since(&lb, from)[0], "1 AB\r\n");
}

#[test]
fn a_stop_does_not_wait_behind_a_move_that_asks_until_its_motion_ends() {
    // vmc.lua with a move() that waits for the end of its motion, asking all along.
    let mut source = vmc();
    source.text += r#"
function move(position, relative, minVel, maxVel, accel)
	sendAccelAndVelocity(minVel, maxVel, accel)
	asyn.writeread(string.format("%d MV %d", AXIS + 1, math.floor(position)), PORT)
	repeat until (tonumber(asyn.writeread(string.format("%d ST?", AXIS + 1), PORT)) & 2) == 2
end
"#;
    // A controller that answers in 2 ms, as one on a network does.
    let faults = Faults { delay: Duration::from_millis(2), ..Faults::default() };
    let mut lb = script_loopback(&source, Model::Vmc, &CHANNELS, faults);
    bring_up(&mut lb);
    // Hours of motion at 1,000 steps/s.
    lb.command(
        0,
        &DriverCommand::Move {
            position: 1e7,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 1000.0,
            acceleration: 1e4,
        },
    );
    lb.run_for(Duration::from_secs(1));
    let from = lb.written().len();
    assert!(written_since(&lb, from - 1)[0] == "1 ST?\r\n", "the move asks: {:?}", written_since(&lb, 0));
    lb.command(0, &DriverCommand::Stop { acceleration: 1e4 });
    let stopped = run_until_done(&mut lb, 0, TICK, Duration::from_secs(3));
    let sent = written_since(&lb, from);
    assert_eq!(sent.iter().filter(|l| *l == "1 AB\r\n").count(), 1, "{sent:?}");
    assert!(
        sent.iter().take_while(|l| *l != "1 AB\r\n").count() <= 1,
        "the stop goes after the reply in flight: {sent:?}"
    );
    let position = stopped.last().expect("done").position;
    assert!(position > 500.0 && position < 1500.0, "stopped where it was: {position}");
}

#[test]
fn a_home_the_script_does_not_define_sends_nothing_and_ends_at_the_next_poll() {
    let mut lb = loopback(Faults::default());
    bring_up(&mut lb);
    let from = lb.written().len();
    let home = DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 1000.0, acceleration: 1e4 };
    lb.command(0, &home);
    let done = run_until_done(&mut lb, 0, TICK, Duration::from_secs(2));
    assert_eq!(done.last().map(|s| s.position), Some(0.0));
    assert!(
        written_since(&lb, from).iter().all(|l| l.ends_with("?\r\n")),
        "only polls: {:?}",
        written_since(&lb, from)
    );
}

#[test]
fn a_position_set_is_the_vmc_s_pos() {
    let mut lb = loopback(Faults::default());
    bring_up(&mut lb);
    let from = lb.written().len();
    lb.command(1, &DriverCommand::SetPosition { position: -77.0 });
    lb.run_for(Duration::from_secs(2));
    assert_eq!(written_since(&lb, from)[0], "2 POS -77\r\n");
    let status = common::last_status(&lb.take_events(), 1);
    assert_eq!(status.position, -77.0);
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    common::replies_in_pieces_give_the_same_statuses_on(
        |chunk| loopback(Faults::default()).with_chunks(chunk),
        &CHANNELS,
    );
}

#[test]
fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing() {
    let mut lb = loopback(Faults::default());
    bring_up(&mut lb);
    let is_move = |l: &str| l.contains(" MV ");
    let is_read = |l: &str| l.ends_with("?\r\n");
    common::a_move_goes_once_and_a_new_connection_only_reads(&mut lb, 1, common::text, is_move, is_read);
    let events = lb.take_events();
    assert!(!events.iter().any(|e| matches!(e, ControllerEvent::Failed { .. })), "{events:?}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_line(
        commands in proptest::collection::vec((0usize..2, common::command(), 0u64..300), 1..10)
    ) {
        common::no_malformed_frames_on(loopback(Faults::default()), &CHANNELS, common::Start::AsPoweredUp, &commands);
    }
}

#[test]
fn a_reload_during_a_move_stops_it_first_then_runs_the_new_script_and_a_broken_one_is_refused() {
    let mut lb = loopback(Faults::default());
    bring_up(&mut lb);
    lb.command(0, &go(30_000.0, false));
    lb.run_for(Duration::from_millis(500));
    assert!(lb.link.emulator().axis(1).expect("axis 1").is_moving());
    // The new script sends the speed only (no BAS, no ACC) before a move.
    let mut new = vmc();
    new.text.push_str(
        "\nfunction sendAccelAndVelocity(minVel, maxVel, accel)\n  asyn.writeread(string.format(\"%d VEL %f\", AXIS + 1, maxVel), PORT)\nend\n",
    );
    let broken = ScriptSource { text: "function move(".into(), ..vmc() };
    let refused = lb
        .controller
        .reload(lb.now(), &zmotor_controllers::ProtocolOptions { script: Some(broken), ..Default::default() });
    assert!(refused.as_ref().is_err_and(|e| e.to_string().contains("vmc.lua:1:")), "{refused:?}");
    assert!(lb.link.emulator().axis(1).expect("axis 1").is_moving(), "a refused reload stops nothing");
    let from = lb.written().len();
    let options = zmotor_controllers::ProtocolOptions { script: Some(new), ..Default::default() };
    lb.controller.reload(lb.now(), &options).expect("the new script loads");
    let stopped = *run_until_done(&mut lb, 0, TICK, Duration::from_secs(5)).last().expect("done");
    assert!(stopped.position < 30_000.0, "stopped on the way: {stopped:?}");
    assert_eq!(written_since(&lb, from)[0], "1 AB\r\n", "the stop goes first, by the old script");
    let from = lb.written().len();
    lb.command(0, &go(0.0, false));
    let back = *run_until_done(&mut lb, 0, TICK, Duration::from_secs(10)).last().expect("done");
    assert_eq!(back.position, 0.0);
    let motion: Vec<String> = written_since(&lb, from).into_iter().filter(|l| !l.ends_with("?\r\n")).collect();
    assert_eq!(motion[..2], ["1 VEL 20000.000000\r\n", "1 MV 0\r\n"], "the new script's move");
}

/// Found by the property above: a move at 13,660 steps/s, then at once a move at 100 steps/s²
/// (answered `Busy`, but its `ACC 100` set), then a stop: `AB` decelerates at `ACC`, over two
/// minutes, as the VMC does; the stop must still end with the axis done.
#[test]
fn a_stop_after_a_slow_acceleration_was_set_mid_move_ends_done() {
    let move_to = |position, max_velocity, acceleration| DriverCommand::Move {
        position,
        relative: false,
        min_velocity: 0.0,
        max_velocity,
        acceleration,
    };
    let commands = [(1, move_to(-141_798.3, 13_660.1, 281_807.2), 0), (1, move_to(0.0, 10.0, 100.0), 0)];
    common::no_malformed_frames_on(loopback(Faults::default()), &CHANNELS, common::Start::AsPoweredUp, &commands);
}
