//! Phytron phyMOTION against its emulator (two modules of two axes: channels 11, 12, 21, 22),
//! in virtual time: every record command as the controller takes it, the batched poll, the
//! controller's errors, and no sequence of commands that yields a frame it cannot read.

mod common;

use common::{bring_up, command, controller_errors, go, last_status, loopback, run_until_done};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{Loopback, ProtocolKind};
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const PHYTRON: ProtocolKind = ProtocolKind::Phytron;
const CHANNELS: [usize; 4] = [11, 12, 21, 22];
const TICK: Duration = Duration::from_millis(10);

/// The commands of a request frame: `STX '0' <payload> ':' <XOR> ETX`.
fn payload(frame: &[u8]) -> String {
    assert_eq!((frame.first(), frame.get(1), frame.last()), (Some(&2), Some(&b'0'), Some(&3)), "{frame:?}");
    String::from_utf8_lossy(&frame[2..frame.len() - 4]).into_owned()
}

fn written_payloads(lb: &Loopback, from: usize) -> Vec<String> {
    lb.written()[from..].iter().map(|f| payload(f)).collect()
}

#[test]
fn a_new_connection_reads_the_encoder_types_then_polls_every_axis_in_one_frame_and_moves_nothing() {
    let mut lb = loopback(PHYTRON, &CHANNELS, Faults::default());
    let events = bring_up(&mut lb);
    assert_eq!(
        written_payloads(&lb, 0),
        [
            "M1.1P34R M1.2P34R M2.1P34R M2.2P34R",
            "SE1.1 M1.1P20R M1.1P22R SE1.2 M1.2P20R M1.2P22R SE2.1 M2.1P20R M2.1P22R SE2.2 M2.2P20R M2.2P22R",
        ]
    );
    for channel in CHANNELS {
        let status = last_status(&events, channel);
        let expected = msta::DONE | msta::POSITION | msta::PRESENT | msta::HOME;
        assert_eq!(status.msta, expected, "channel {channel}: at rest on the center switch, powered, an encoder");
        assert_eq!(Loopback::statuses(&events, channel).len(), 1, "one status a poll");
    }
    for channel in CHANNELS {
        let axis = lb.link.emulator().axis(channel).expect("an emulated axis");
        assert_eq!(axis.physical_position(), 0.0);
    }
}

#[test]
fn a_reconnection_reads_and_polls_again_and_moves_nothing() {
    let mut lb = loopback(PHYTRON, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(12, &go(-4000.0, false));
    run_until_done(&mut lb, 12, TICK, Duration::from_secs(2));
    lb.set_reachable(false);
    lb.run_for(Duration::from_secs(1));
    let start = lb.written().len();
    lb.set_reachable(true);
    lb.run_for(Duration::from_secs(3));
    let events = lb.take_events();
    assert!(lb.controller.is_up());
    let after = written_payloads(&lb, start);
    assert_eq!(after[0], "M1.1P34R M1.2P34R M2.1P34R M2.2P34R");
    assert!(after[1..].iter().all(|p| p.starts_with("SE1.1 M1.1P20R")), "polls only: {after:?}");
    assert_eq!(last_status(&events, 12).position, -4000.0);
    assert_eq!(lb.link.emulator().axis(12).map(|a| a.physical_position()), Some(-4000.0));
}

#[test]
fn moves_land_where_asked_absolute_and_relative() {
    let mut lb = loopback(PHYTRON, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    let start = lb.written().len();
    lb.command(11, &go(12_345.4, false));
    assert_eq!(
        written_payloads(&lb, start)[0],
        "M1.1P14=20000.000000 M1.1P04=1.000000 M1.1P15=200000.000000 M1.1MA M1.1A12345"
    );
    lb.command(22, &go(-2500.0, true));
    run_until_done(&mut lb, 11, TICK, Duration::from_secs(3));
    let statuses = run_until_done(&mut lb, 22, TICK, Duration::from_secs(3));
    assert_eq!(statuses.last().map(|s| (s.position, s.encoder_position)), Some((-2500.0, -2500.0)));
    lb.command(22, &go(-2500.0, true));
    let statuses = run_until_done(&mut lb, 22, TICK, Duration::from_secs(3));
    assert_eq!(statuses.last().map(|s| s.position), Some(-5000.0));
    lb.run_for(Duration::from_millis(1100));
    assert_eq!(last_status(&lb.take_events(), 11).position, 12_345.0);
    assert_eq!(lb.link.emulator().axis(11).map(|a| a.physical_position()), Some(12_345.0));
    assert_eq!(lb.link.emulator().axis(12).map(|a| a.physical_position()), Some(0.0), "the others stayed");
}

#[test]
fn a_jog_runs_until_stopped_and_meets_the_limit_switch_if_not_which_the_next_motion_clears() {
    let mut lb = loopback(PHYTRON, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(12, &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -5000.0, acceleration: 50_000.0 });
    lb.run_for(Duration::from_secs(1));
    let status = last_status(&lb.take_events(), 12);
    assert_eq!(status.msta & (msta::DONE | msta::MOVING | msta::DIRECTION), msta::MOVING, "running down");
    assert!(status.position < -4000.0, "{status:?}");
    let start = lb.written().len();
    lb.command(12, &DriverCommand::Stop { acceleration: 50_000.0 });
    assert_eq!(written_payloads(&lb, start)[0], "M1.2P15=50000.000000 M1.2S");
    let statuses = run_until_done(&mut lb, 12, TICK, Duration::from_secs(2));
    let stopped = statuses.last().expect("done");
    assert!(stopped.position > -6000.0, "stopped soon after the stop: {stopped:?}");
    // Left running, a jog ends on the minus limit switch at -200000 steps.
    lb.command(
        12,
        &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -100_000.0, acceleration: 500_000.0 },
    );
    let statuses = run_until_done(&mut lb, 12, TICK, Duration::from_secs(5));
    let at_limit = statuses.last().expect("done");
    assert_eq!(at_limit.msta & (msta::MINUS_LS | msta::PROBLEM), msta::MINUS_LS, "{at_limit:?}");
    assert_eq!(at_limit.position, -200_000.0);
    let start = lb.written().len();
    lb.command(12, &go(-150_000.0, false));
    assert!(written_payloads(&lb, start)[0].starts_with("SEC1.2 M1.2P14="), "the limit-switch error cleared first");
    let statuses = run_until_done(&mut lb, 12, TICK, Duration::from_secs(3));
    let away = statuses.last().expect("done");
    assert_eq!((away.position, away.msta & msta::MINUS_LS), (-150_000.0, 0));
}

#[test]
fn a_home_search_ends_on_the_center_switch_and_the_axis_initialised() {
    let mut lb = loopback(PHYTRON, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(21, &go(30_000.0, false));
    let statuses = run_until_done(&mut lb, 21, TICK, Duration::from_secs(3));
    assert_eq!(statuses.last().map(|s| s.msta & (msta::HOME | msta::HOMED)), Some(0));
    let start = lb.written().len();
    lb.command(
        21,
        &DriverCommand::Home { forward: false, min_velocity: 500.0, max_velocity: 20_000.0, acceleration: 200_000.0 },
    );
    assert_eq!(
        written_payloads(&lb, start)[0],
        "M2.1P08=20000.000000 M2.1P10=500.000000 M2.1P09=200000.000000 M2.1MA M2.1R-C"
    );
    let statuses = run_until_done(&mut lb, 21, TICK, Duration::from_secs(10));
    let home = statuses.last().expect("done");
    assert_eq!(home.msta & (msta::HOME | msta::HOMED), msta::HOME | msta::HOMED, "{home:?}");
    assert_eq!(home.position, 0.0);
    assert_eq!(lb.link.emulator().axis(21).map(|a| a.physical_position()), Some(0.0));
}

#[test]
fn set_position_redefines_the_counters_without_moving() {
    let mut lb = loopback(PHYTRON, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    let start = lb.written().len();
    lb.command(22, &DriverCommand::SetPosition { position: 5000.0 });
    assert_eq!(written_payloads(&lb, start), ["M2.2P20=5000.000000"]);
    lb.run_for(Duration::from_millis(1100));
    let status = last_status(&lb.take_events(), 22);
    assert_eq!((status.position, status.encoder_position), (5000.0, 5000.0));
    assert_eq!(lb.link.emulator().axis(22).map(|a| a.physical_position()), Some(0.0));
}

#[test]
fn a_drive_switched_off_refuses_to_move_until_switched_on() {
    let mut lb = loopback(PHYTRON, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(11, &DriverCommand::Enable { on: false });
    lb.run_for(Duration::from_millis(1100));
    assert_eq!(last_status(&lb.take_events(), 11).msta & msta::POSITION, 0, "power stage not ready");
    lb.command(11, &go(100.0, true));
    let statuses = run_until_done(&mut lb, 11, TICK, Duration::from_secs(2));
    assert_eq!(statuses.last().map(|s| s.position), Some(0.0));
    assert_eq!(lb.link.emulator().axis(11).map(|a| a.physical_position()), Some(0.0));
    lb.run_for(Duration::from_millis(10));
    let written: Vec<String> = written_payloads(&lb, 0);
    assert!(written.iter().any(|w| w == "M1.1P14=20000.000000 M1.1P04=1.000000 M1.1P15=200000.000000 M1.1+100"));
    lb.command(11, &DriverCommand::Enable { on: true });
    lb.command(11, &go(100.0, true));
    let statuses = run_until_done(&mut lb, 11, TICK, Duration::from_secs(2));
    let moved = statuses.last().expect("done");
    assert_eq!((moved.position, moved.msta & msta::POSITION), (100.0, msta::POSITION));
}

#[test]
fn a_refused_motion_reaches_the_record_as_the_controllers_error() {
    let mut lb = loopback(PHYTRON, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(11, &DriverCommand::Enable { on: false });
    lb.run_for(Duration::from_millis(100));
    lb.take_events();
    lb.command(11, &go(100.0, false));
    lb.run_for(Duration::from_millis(100));
    let events = lb.take_events();
    assert_eq!(
        controller_errors(&events),
        [(Some(11), "NAK".to_string(), "the controller refused M1.1A100".to_string())]
    );
    assert_ne!(last_status(&events, 11).msta & msta::PROBLEM, 0);
}

#[test]
fn a_power_stage_error_reaches_the_record_with_its_meaning_until_cleared() {
    let mut lb = loopback(PHYTRON, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    assert!(lb.link.emulator().raise_error(21));
    lb.run_for(Duration::from_millis(1100));
    let events = lb.take_events();
    assert_eq!(controller_errors(&events), [(Some(21), "SE 0x2000".to_string(), "power-stage error".to_string())]);
    let status = last_status(&events, 21);
    assert_eq!(status.msta & (msta::PROBLEM | msta::POSITION), msta::PROBLEM, "{status:?}");
    assert_eq!(last_status(&events, 22).msta & msta::PROBLEM, 0, "the other axes are fine");
    lb.run_for(Duration::from_millis(1000));
    let events = lb.take_events();
    assert!(controller_errors(&events).is_empty(), "reported once: {events:?}");
    assert_ne!(last_status(&events, 21).msta & msta::PROBLEM, 0, "still a problem");
    // Cleared by hand, as an operator would: `SEC2.1`.
    lb.command(21, &DriverCommand::Raw { text: "SEC2.1".into() });
    lb.run_for(Duration::from_millis(1100));
    let status = last_status(&lb.take_events(), 21);
    assert_eq!(status.msta & (msta::PROBLEM | msta::POSITION), msta::POSITION);
}

/// A script of every kind of command on two axes, and the statuses it yields.
fn script(lb: &mut Loopback) -> Vec<Vec<zmotor_core::DeviceStatus>> {
    bring_up(lb);
    lb.command(11, &go(3000.0, false));
    lb.command(22, &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: 8000.0, acceleration: 80_000.0 });
    lb.run_for(Duration::from_millis(400));
    lb.command(22, &DriverCommand::Stop { acceleration: 80_000.0 });
    lb.run_for(Duration::from_millis(400));
    lb.command(
        11,
        &DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 9000.0, acceleration: 90_000.0 },
    );
    lb.command(12, &DriverCommand::SetPosition { position: -77.0 });
    lb.run_for(Duration::from_secs(2));
    let events = lb.take_events();
    CHANNELS.iter().map(|c| Loopback::statuses(&events, *c)).collect()
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    let whole = script(&mut loopback(PHYTRON, &CHANNELS, Faults::default()));
    let mut split = loopback(PHYTRON, &CHANNELS, Faults::default()).with_chunks(1);
    let pieces = script(&mut split);
    assert_eq!(pieces, whole);
    assert!(whole.iter().all(|statuses| statuses.len() > 5), "every axis reported all along");
    assert_eq!(whole[0].last().map(|s| (s.position, s.msta & msta::HOMED)), Some((0.0, msta::HOMED)));
    assert_eq!(whole[1].last().map(|s| s.position), Some(-77.0));
}

#[test]
fn positions_are_whole_steps_as_the_controller_counts() {
    let mut lb = loopback(PHYTRON, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(12, &go(1234.6, false));
    let statuses = run_until_done(&mut lb, 12, TICK, Duration::from_secs(2));
    assert_eq!(statuses.last().map(|s| s.position), Some(1235.0));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_frame(
        commands in proptest::collection::vec((0usize..4, command(), 0u64..300), 1..12)
    ) {
        common::no_malformed_frames(PHYTRON, &CHANNELS, common::Start::AsPoweredUp, &commands);
    }
}

#[test]
fn the_driver_sends_what_the_epics_driver_sends() {
    common::golden::driver_sends_the_transcripts(PHYTRON)
}

#[test]
fn the_emulator_answers_what_the_epics_driver_sends() {
    common::golden::emulator_answers_the_transcripts(PHYTRON)
}
