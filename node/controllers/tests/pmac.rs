//! Delta Tau Turbo PMAC / Geo Brick against its emulator, in virtual time: every record command
//! as the controller takes it, every axis read in one exchange, the controller's faults, and no
//! sequence of commands that yields a packet it cannot read.

mod common;

use common::{bring_up, command, controller_errors, go, last_status, loopback, run_until_done};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{Loopback, ProtocolKind};
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const PMAC: ProtocolKind = ProtocolKind::Pmac;
const CHANNELS: [usize; 2] = [1, 2];
const TICK: Duration = Duration::from_millis(10);

/// The command line behind a request's 8-byte header.
fn line(packet: &[u8]) -> String {
    assert_eq!(packet[..2], [0x40, 0xBF], "a GETRESPONSE packet: {packet:?}");
    String::from_utf8_lossy(&packet[8..]).into_owned()
}

fn lines_since(lb: &Loopback, from: usize) -> Vec<String> {
    lb.written()[from..].iter().map(|p| line(p)).collect()
}

#[test]
fn the_driver_sends_what_the_epics_driver_sends() {
    common::golden::driver_sends_the_transcripts(PMAC)
}

#[test]
fn the_emulator_answers_what_the_epics_driver_sends() {
    common::golden::emulator_answers_the_transcripts(PMAC)
}

#[test]
fn a_new_connection_identifies_the_card_then_reads_every_axis_in_one_exchange_and_writes_nothing() {
    let channels: Vec<usize> = (1..=8).collect();
    let mut lb = loopback(PMAC, &channels, Faults::default());
    bring_up(&mut lb);
    let sent = lines_since(&lb, 0);
    assert_eq!(sent[..2], ["cid", "cpu"]);
    assert!(sent[2..10].iter().all(|l| l.starts_with('I') && !l.contains('=')), "reads only: {sent:?}");
    let polls: Vec<&String> = sent.iter().filter(|l| l.starts_with("#1P")).collect();
    assert!(!polls.is_empty() && polls.iter().all(|l| l.ends_with("#8P #8F i824 #8?")), "{polls:?}");
    assert!(sent.iter().all(|l| !l.contains('=')), "nothing written: {sent:?}");
}

#[test]
fn a_move_arrives_in_counts_with_the_commanded_position_as_readback() {
    let mut lb = loopback(PMAC, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(2, &go(1234.5, false));
    let statuses = run_until_done(&mut lb, 2, TICK, Duration::from_secs(2));
    let arrived = statuses.last().expect("done");
    assert_eq!((arrived.position, arrived.encoder_position), (1234.5, 1234.5));
    assert!(statuses.iter().any(|s| s.msta & (msta::MOVING | msta::DIRECTION) == msta::MOVING | msta::DIRECTION));
    lb.command(2, &go(-234.5, true));
    let statuses = run_until_done(&mut lb, 2, TICK, Duration::from_secs(2));
    assert_eq!(statuses.last().map(|s| s.position), Some(1000.0));
}

#[test]
fn a_jog_runs_until_stopped_and_meets_the_limit_switch_if_not() {
    let mut lb = loopback(PMAC, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::a_jog_runs_until_stopped_or_the_limit_switch(&mut lb, 1);
}

#[test]
fn a_home_search_is_the_controllers_and_ends_home_complete() {
    let mut lb = loopback(PMAC, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(1, &DriverCommand::SetPosition { position: 30_000.0 });
    lb.run_for(Duration::from_millis(1100));
    assert_eq!(last_status(&lb.take_events(), 1).position, 30_000.0);
    let from = lb.written().len();
    lb.command(
        1,
        &DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 1.0 },
    );
    let home = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(20)).last().expect("done");
    assert_eq!(home.msta & msta::HOMED, msta::HOMED, "{home:?}");
    assert_eq!(lines_since(&lb, from)[0], "#1 HOME");
}

#[test]
fn a_killed_motor_stays_killed_through_a_stop_and_enabling_closes_its_loop() {
    let mut lb = loopback(PMAC, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(1, &DriverCommand::Enable { on: false });
    lb.run_for(Duration::from_millis(1100));
    let killed = last_status(&lb.take_events(), 1);
    assert_eq!(killed.msta & (msta::POSITION | msta::DONE), msta::DONE, "{killed:?}");
    let from = lb.written().len();
    lb.command(1, &DriverCommand::Stop { acceleration: 1.0 });
    lb.run_for(Duration::from_millis(1100));
    assert!(lines_since(&lb, from).iter().all(|l| !l.contains("J/")), "no stop closes the loop");
    assert_eq!(last_status(&lb.take_events(), 1).msta & msta::POSITION, 0);
    lb.command(1, &DriverCommand::Enable { on: true });
    lb.run_for(Duration::from_millis(1100));
    assert_ne!(last_status(&lb.take_events(), 1).msta & msta::POSITION, 0, "enabled again");
}

#[test]
fn the_stop_owed_after_a_lost_link_leaves_a_motor_killed_meanwhile_killed() {
    // Both motors jog when the link is lost; while it is down a fatal following error kills
    // motor 1. Back, the stop owed to each is made from what the new link reads: motor 2 is
    // stopped (J/), motor 1 is not closed again by one.
    let mut lb = loopback(PMAC, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    for channel in CHANNELS {
        lb.command(
            channel,
            &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: 1000.0, acceleration: 1e5 },
        );
    }
    lb.run_for(Duration::from_millis(300));
    lb.set_reachable(false);
    lb.run_for(Duration::from_secs(2));
    assert!(lb.link.emulator().raise_error(1));
    let from = lb.written().len();
    lb.set_reachable(true);
    lb.run_for(Duration::from_secs(2));
    assert!(lb.controller.is_up());
    let sent = lines_since(&lb, from);
    assert!(sent.iter().any(|l| l.contains("#2 J/")), "the jog still running is stopped: {sent:?}");
    assert!(sent.iter().all(|l| !l.contains("#1 J/")), "the killed motor's loop is not closed: {sent:?}");
    let now = lb.now();
    for (channel, moving) in [(1, false), (2, false)] {
        let axis = lb.link.emulator().axis(channel).expect("an emulated motor");
        zmotor_core::Driver::advance(axis, now);
        assert_eq!(axis.is_moving(), moving, "motor {channel}");
    }
    assert_eq!(last_status(&lb.take_events(), 1).msta & msta::POSITION, 0, "motor 1 stays killed");
}

#[test]
fn a_fatal_following_error_reaches_the_record_once_with_its_meaning() {
    let mut lb = loopback(PMAC, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    assert!(lb.link.emulator().raise_error(2));
    lb.run_for(Duration::from_millis(1100));
    let events = lb.take_events();
    let errors = controller_errors(&events);
    assert_eq!(errors.len(), 1, "{events:?}");
    assert_eq!((errors[0].0, errors[0].1.as_str()), (Some(2), "#2? fatal following error"));
    let status = last_status(&events, 2);
    assert_eq!(status.msta & (msta::PROBLEM | msta::SLIP_STALL | msta::POSITION), msta::PROBLEM | msta::SLIP_STALL);
    assert_eq!(last_status(&events, 1).msta & msta::PROBLEM, 0, "the other motor is fine");
    lb.run_for(Duration::from_millis(1100));
    assert!(controller_errors(&lb.take_events()).is_empty(), "reported once");
}

#[test]
fn an_unknown_command_is_the_controllers_error_and_the_link_stays_up() {
    let mut lb = loopback(PMAC, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::an_unknown_command_is_an_error_and_the_link_stays_up(&mut lb, 1, "#1 FOO", (Some(1), "ERR003"));
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    common::replies_in_pieces_give_the_same_statuses(PMAC, &CHANNELS);
}

#[test]
fn through_lost_and_garbled_replies_a_move_goes_once_and_a_new_connection_moves_nothing() {
    let mut lb = loopback(PMAC, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    let reads = |l: &str| !l.contains('=') && !l.contains("J/");
    common::a_move_goes_once_and_a_new_connection_only_reads(&mut lb, 1, line, |l| l.contains("J="), reads);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_packet(
        commands in proptest::collection::vec((0usize..2, command(), 0u64..300), 1..12)
    ) {
        common::no_malformed_frames(PMAC, &CHANNELS, common::Start::AsPoweredUp, &commands);
    }
}
