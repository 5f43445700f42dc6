//! Newport SMC100 / CONEX-CC against its emulator, in virtual time: every record command as the
//! controller takes it (in millimetres, 0.0001 mm per step), its state machine seen through
//! MSTA, its refusals as controller errors, and no sequence of commands that yields a frame
//! the controller cannot read.

mod common;

use common::{bring_up, command, controller_errors, last_status, loopback, run_until_done, written_since};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{
    CommandError, ControllerConfig, ControllerEvent, Loopback, ProtocolKind, ProtocolOptions, Refusal,
};
use zmotor_core::{DeviceStatus, Instant, SimSetting};
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::{DriverCommand, Gain, Value};

const SMC: ProtocolKind = ProtocolKind::NewportSmc100;
const TICK: Duration = Duration::from_millis(10);

fn go(position: f64, relative: bool) -> DriverCommand {
    // 2 mm/s, 20 mm/s² at 0.0001 mm per step.
    DriverCommand::Move { position, relative, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 }
}

fn jog(velocity: f64) -> DriverCommand {
    DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: velocity, acceleration: 200_000.0 }
}

fn home() -> DriverCommand {
    DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 10_000.0, acceleration: 100_000.0 }
}

/// Put the carriage of `channel` at `mm` by hand.
fn push_carriage(lb: &mut Loopback, channel: usize, mm: f64) {
    let axis = lb.link.emulator().axis(channel).expect("a controller at this address");
    axis.apply(SimSetting::Position, &Value::Float(mm)).expect("a position");
}

/// Command, then run until done; the statuses on the way.
fn carry_out(lb: &mut Loopback, channel: usize, command: &DriverCommand) -> Vec<DeviceStatus> {
    lb.command(channel, command);
    run_until_done(lb, channel, TICK, Duration::from_secs(30))
}

/// Home `channel` and check it arrived.
fn homed(lb: &mut Loopback, channel: usize) {
    let statuses = carry_out(lb, channel, &home());
    let at_home = statuses.last().expect("done");
    assert_eq!(at_home.msta & (msta::HOMED | msta::HOME | msta::POSITION), msta::HOMED | msta::HOME | msta::POSITION);
    assert_eq!(at_home.position, 0.0);
}

#[test]
fn a_new_connection_clears_old_errors_polls_and_moves_nothing() {
    let mut lb = loopback(SMC, &[1, 2], Faults::default());
    push_carriage(&mut lb, 2, 4.0);
    let events = bring_up(&mut lb);
    assert_eq!(written_since(&lb, 0), ["1TE\r\n", "2TE\r\n", "1TS\r\n", "1TP\r\n", "2TS\r\n", "2TP\r\n"]);
    let status = last_status(&events, 2);
    assert_eq!(status.position, 40_000.0);
    // Just powered up: not referenced, enabled (it takes a home), nothing wrong.
    let bits = msta::DONE | msta::HOMED | msta::POSITION | msta::PROBLEM;
    assert_eq!(status.msta & bits, msta::DONE | msta::POSITION);
    // A connection lost and found again sends no reset and no home.
    lb.link.set_faults(Faults { close_after: Some(1), ..Faults::default() });
    lb.run_for(Duration::from_secs(2));
    lb.link.set_faults(Faults::default());
    lb.run_for(Duration::from_secs(2));
    assert!(lb.controller.is_up());
    let sent = written_since(&lb, 0);
    assert!(sent.iter().all(|s| s.ends_with("TE\r\n") || s.ends_with("TP\r\n") || s.ends_with("TS\r\n")), "{sent:?}");
    assert_eq!(lb.link.emulator().axis(2).expect("controller 2").physical_position(), 4.0);
}

#[test]
fn a_move_before_the_home_is_refused_before_it_is_sent_saying_why() {
    let mut lb = loopback(SMC, &[1], Faults::default());
    bring_up(&mut lb);
    let start = lb.written().len();
    for command in [go(50_000.0, false), go(50_000.0, true), jog(10_000.0)] {
        lb.command(1, &command);
        lb.run_for(Duration::from_millis(300));
        let events = lb.take_events();
        let refused = ControllerEvent::Refused { channel: 1, why: Refusal::NotReferenced };
        assert!(events.contains(&refused), "{command:?}: {events:?}");
        let status = last_status(&events, 1);
        assert_eq!(status.msta & (msta::PROBLEM | msta::DONE), msta::PROBLEM | msta::DONE);
        assert_eq!(status.position, 0.0);
    }
    let sent = written_since(&lb, start);
    assert!(sent.iter().all(|s| !s.contains("PA") && !s.contains("PR")), "{sent:?}");
    // The problem lasts until the next command.
    homed(&mut lb, 1);
    lb.run_for(Duration::from_millis(300));
    assert_eq!(last_status(&lb.take_events(), 1).msta & msta::PROBLEM, 0);
}

#[test]
fn a_home_search_ends_at_the_home_switch_resetting_first_when_already_referenced() {
    let mut lb = loopback(SMC, &[1], Faults::default());
    bring_up(&mut lb);
    push_carriage(&mut lb, 1, 3.0);
    let start = lb.written().len();
    let statuses = carry_out(&mut lb, 1, &home());
    assert!(statuses.iter().any(|s| s.msta & msta::MOVING != 0), "a home search shows as moving: {statuses:?}");
    let at_home = statuses.last().expect("done");
    assert_eq!(at_home.position, 0.0);
    assert_eq!(at_home.msta & (msta::HOME | msta::HOMED), msta::HOME | msta::HOMED);
    let sent = written_since(&lb, start);
    assert_eq!(sent[..3], ["1TS\r\n", "1OR\r\n", "1TE\r\n"], "not referenced: OR at once");
    assert!(!sent.contains(&"1RS\r\n".to_string()));
    // Referenced: a reset first, OR once the controller is back, and home again.
    carry_out(&mut lb, 1, &go(50_000.0, false));
    let start = lb.written().len();
    let statuses = carry_out(&mut lb, 1, &home());
    assert!(statuses.iter().take_while(|s| s.msta & msta::DONE == 0).count() > 5, "{statuses:?}");
    assert_eq!(statuses.last().map(|s| s.position), Some(0.0));
    let sent = written_since(&lb, start);
    let reset = sent.iter().position(|s| s == "1RS\r\n").expect("a reset");
    let or = sent.iter().position(|s| s == "1OR\r\n").expect("a home");
    assert!(reset < or, "{sent:?}");
    assert!(controller_errors(&lb.take_events()).is_empty());
}

#[test]
fn moves_land_where_asked_in_millimetres() {
    let mut lb = loopback(SMC, &[1], Faults::default());
    bring_up(&mut lb);
    homed(&mut lb, 1);
    let start = lb.written().len();
    let statuses = carry_out(&mut lb, 1, &go(50_000.0, false));
    assert!(statuses.iter().any(|s| s.msta & (msta::MOVING | msta::DIRECTION) == msta::MOVING | msta::DIRECTION));
    let there = statuses.last().expect("done");
    assert_eq!(there.position, 50_000.0);
    assert_eq!(there.msta & (msta::HOME | msta::HOMED | msta::PROBLEM), msta::HOMED, "moved off home");
    assert_eq!(written_since(&lb, start)[..4], ["1VA2.000000\r\n", "1AC20.000000\r\n", "1PA5.000000\r\n", "1TE\r\n"]);
    let statuses = carry_out(&mut lb, 1, &go(-12_345.0, true));
    assert_eq!(statuses.last().map(|s| s.position), Some(37_655.0));
    let carriage = lb.link.emulator().axis(1).expect("controller 1").physical_position();
    assert!((carriage - 3.7655).abs() < 1e-9, "{carriage} mm");
}

#[test]
fn a_target_beyond_the_software_limits_is_refused_by_the_controller() {
    let mut lb = loopback(SMC, &[1], Faults::default());
    bring_up(&mut lb);
    homed(&mut lb, 1);
    lb.command(1, &go(130_000.0, false));
    lb.run_for(Duration::from_millis(300));
    let events = lb.take_events();
    assert_eq!(controller_errors(&events), [(Some(1), "G".to_string(), "Displacement out of limits".to_string())]);
    assert_eq!(last_status(&events, 1).position, 0.0);
}

#[test]
fn a_jog_runs_until_stopped_and_otherwise_to_the_software_limit() {
    let mut lb = loopback(SMC, &[1], Faults::default());
    bring_up(&mut lb);
    homed(&mut lb, 1);
    lb.command(1, &jog(10_000.0));
    lb.run_for(Duration::from_secs(1));
    let status = last_status(&lb.take_events(), 1);
    assert_eq!(status.msta & (msta::DONE | msta::MOVING), msta::MOVING);
    assert!(status.position > 5_000.0, "{status:?}");
    lb.command(1, &DriverCommand::Stop { acceleration: 200_000.0 });
    let stopped = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(2)).last().expect("done");
    assert!(stopped.position > 5_000.0 && stopped.position < 15_000.0, "stopped soon after the stop: {stopped:?}");
    assert_eq!(stopped.msta & (msta::HOMED | msta::PLUS_LS), msta::HOMED);
    // Left running down, it ends on SL (-12.5 mm), short of the end-of-run switch (-13 mm).
    let start = lb.written().len();
    let statuses = carry_out(&mut lb, 1, &jog(-50_000.0));
    let at_limit = statuses.last().expect("done");
    assert_eq!(at_limit.position, -125_000.0);
    assert_eq!(at_limit.msta & (msta::HOMED | msta::MINUS_LS | msta::PROBLEM), msta::HOMED);
    let sent = written_since(&lb, start);
    assert_eq!(sent[..5], ["1VA5.000000\r\n", "1AC20.000000\r\n", "1SL?\r\n", "1PA-12.500000\r\n", "1TE\r\n"]);
}

#[test]
fn a_jog_past_the_end_of_run_switch_stops_on_it_and_needs_a_home() {
    let mut lb = loopback(SMC, &[1], Faults::default());
    bring_up(&mut lb);
    homed(&mut lb, 1);
    // The controller's software limit set beyond the switch (13 mm), by the lab's own hand:
    // the switch stops the stage.
    carry_out(&mut lb, 1, &DriverCommand::Raw { text: "1SR14".into() });
    let statuses = carry_out(&mut lb, 1, &jog(50_000.0));
    let on_switch = statuses.last().expect("done");
    assert_eq!(on_switch.position, 130_000.0);
    assert_eq!(on_switch.msta & (msta::PLUS_LS | msta::HOMED), msta::PLUS_LS, "not referenced");
    assert!(controller_errors(&lb.take_events()).is_empty());
    homed(&mut lb, 1);
}

#[test]
fn the_controllers_low_limit_is_where_a_jog_down_stops_and_the_records_limits_leave_it_alone() {
    let mut lb = loopback(SMC, &[1], Faults::default());
    bring_up(&mut lb);
    homed(&mut lb, 1);
    let start = lb.written().len();
    // The record's "no limits" (both 0) reaches the driver as limits of 0: nothing is sent.
    lb.command(1, &DriverCommand::SetHighLimit { position: 0.0 });
    lb.command(1, &DriverCommand::SetLowLimit { position: 0.0 });
    lb.run_for(Duration::from_millis(300));
    assert!(written_since(&lb, start).iter().all(|s| !s.contains("SR") && !s.contains("SL")));
    carry_out(&mut lb, 1, &DriverCommand::Raw { text: "1SL-2".into() });
    let statuses = carry_out(&mut lb, 1, &jog(-20_000.0));
    assert_eq!(statuses.last().map(|s| s.position), Some(-20_000.0));
}

#[test]
fn set_position_is_refused_and_sends_nothing() {
    let mut lb = loopback(SMC, &[1], Faults::default());
    bring_up(&mut lb);
    let start = lb.written().len();
    lb.command(1, &DriverCommand::SetPosition { position: 1000.0 });
    let events = lb.take_events();
    assert!(events.iter().any(|e| matches!(
        e,
        ControllerEvent::Refused { channel: 1, why: Refusal::Command(CommandError::Unsupported { .. }) }
    )));
    assert_ne!(last_status(&events, 1).msta & msta::PROBLEM, 0);
    assert!(written_since(&lb, start).is_empty());
}

#[test]
fn a_disabled_servo_does_not_move_and_takes_gains() {
    let mut lb = loopback(SMC, &[1], Faults::default());
    bring_up(&mut lb);
    homed(&mut lb, 1);
    // Gains are refused while the servo is on.
    lb.command(1, &DriverCommand::SetGain { gain: Gain::Proportional, value: 0.01 });
    lb.run_for(Duration::from_millis(300));
    let refused = controller_errors(&lb.take_events());
    assert_eq!(refused, [(Some(1), "K".to_string(), "Command not allowed in READY state".to_string())]);
    lb.command(1, &DriverCommand::Enable { on: false });
    lb.run_for(Duration::from_millis(1100));
    let off = last_status(&lb.take_events(), 1);
    assert_eq!(off.msta & (msta::POSITION | msta::HOMED | msta::PROBLEM), msta::HOMED);
    lb.command(1, &DriverCommand::SetGain { gain: Gain::Derivative, value: 0.002 });
    lb.command(1, &go(10_000.0, true));
    lb.run_for(Duration::from_millis(500));
    let events = lb.take_events();
    let still = last_status(&events, 1);
    assert_eq!((still.position, still.msta & msta::DONE), (0.0, msta::DONE));
    let errors = controller_errors(&events);
    assert_eq!(
        errors,
        [(Some(1), "J".to_string(), "Command not allowed in DISABLE state".to_string())],
        "the gain went"
    );
    assert!(lb.written().iter().any(|w| w.as_slice() == b"1KD2000.000000\r\n"));
    lb.command(1, &DriverCommand::Enable { on: true });
    let statuses = carry_out(&mut lb, 1, &go(10_000.0, true));
    assert_eq!(statuses.last().map(|s| s.position), Some(10_000.0));
    assert_ne!(statuses.last().map_or(0, |s| s.msta) & msta::POSITION, 0);
}

#[test]
fn a_following_error_reaches_the_axis_as_a_controller_error_and_a_problem() {
    let mut lb = loopback(SMC, &[1], Faults::default());
    bring_up(&mut lb);
    homed(&mut lb, 1);
    lb.command(1, &go(100_000.0, false));
    lb.run_for(Duration::from_millis(500));
    assert!(lb.link.emulator().raise_error(1));
    lb.run_for(Duration::from_millis(300));
    let events = lb.take_events();
    assert_eq!(controller_errors(&events), [(Some(1), "0020".to_string(), "following error".to_string())]);
    let status = last_status(&events, 1);
    let bits = msta::PROBLEM | msta::SLIP_STALL | msta::DONE | msta::POSITION;
    assert_eq!(status.msta & bits, msta::PROBLEM | msta::SLIP_STALL | msta::DONE, "the servo dropped out");
    assert!(status.position > 0.0 && status.position < 100_000.0);
    // Enabled again: the fault is cleared, the axis moves.
    lb.command(1, &DriverCommand::Enable { on: true });
    lb.run_for(Duration::from_millis(1100));
    assert_eq!(
        last_status(&lb.take_events(), 1).msta & (msta::PROBLEM | msta::SLIP_STALL | msta::POSITION),
        msta::POSITION
    );
    let statuses = carry_out(&mut lb, 1, &go(100_000.0, false));
    assert_eq!(statuses.last().map(|s| s.position), Some(100_000.0));
}

#[test]
fn each_controller_on_the_chain_answers_for_itself() {
    let mut lb = loopback(SMC, &[1, 3], Faults::default());
    bring_up(&mut lb);
    homed(&mut lb, 3);
    let statuses = carry_out(&mut lb, 3, &go(-20_000.0, false));
    assert_eq!(statuses.last().map(|s| s.position), Some(-20_000.0));
    lb.run_for(Duration::from_millis(1100));
    let events = lb.take_events();
    assert_eq!(last_status(&events, 1).msta & msta::HOMED, 0, "controller 1 was neither homed nor moved");
    assert_eq!(last_status(&events, 1).position, 0.0);
    assert_eq!(lb.link.malformed(), 0);
}

#[test]
fn millimetres_per_step_follow_the_launch_file() {
    let options = ProtocolOptions { units_per_step: Some(0.00005), ..ProtocolOptions::default() };
    let config = ControllerConfig::for_channels(vec![1]);
    let controller = SMC.controller(&options, config, Instant::ZERO);
    let mut lb = Loopback::new(controller, common::emulator(SMC, 2), Faults::default());
    bring_up(&mut lb);
    homed(&mut lb, 1);
    let statuses = carry_out(&mut lb, 1, &go(100_000.0, false));
    assert_eq!(statuses.last().map(|s| s.position), Some(100_000.0));
    assert_eq!(lb.link.emulator().axis(1).expect("controller 1").physical_position(), 5.0);
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    let run = |chunk: usize| {
        let mut lb = loopback(SMC, &[1, 2], Faults::default()).with_chunks(chunk);
        bring_up(&mut lb);
        push_carriage(&mut lb, 2, 1.5);
        lb.command(2, &home());
        lb.run_for(Duration::from_secs(2));
        // Beyond the software limit (the controller's error), then a move it takes.
        lb.command(2, &go(130_000.0, false));
        lb.run_for(Duration::from_millis(300));
        lb.command(2, &go(-30_000.0, false));
        lb.command(1, &DriverCommand::Poll);
        lb.run_for(Duration::from_secs(3));
        let events = lb.take_events();
        (
            Loopback::statuses(&events, 1),
            Loopback::statuses(&events, 2),
            controller_errors(&events),
            lb.written().to_vec(),
        )
    };
    let whole = run(usize::MAX);
    assert!(whole.1.iter().any(|s| s.position == -30_000.0 && s.msta & msta::DONE != 0));
    assert_eq!(whole.2.len(), 1, "the target beyond the software limit: {:?}", whole.2);
    assert_eq!(run(1), whole);
}

#[test]
fn the_driver_sends_what_the_epics_driver_sends() {
    common::golden::driver_sends_the_transcripts(SMC)
}

#[test]
fn the_emulator_answers_what_the_epics_driver_sends() {
    common::golden::emulator_answers_the_transcripts(SMC)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_frame(
        commands in proptest::collection::vec((0usize..2, command(), 0u64..300), 1..12)
    ) {
        common::no_malformed_frames(SMC, &[1, 3], common::Start::Homed, &commands);
    }
}
