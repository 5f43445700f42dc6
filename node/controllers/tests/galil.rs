//! Galil DMC-40x0 against its emulator, in virtual time: every record command as the controller
//! takes it, every axis read in one data record, the controller's refusals with their reasons,
//! and no sequence of commands that yields a line it cannot read.

mod common;

use common::{
    bring_up, command, controller_errors, go, last_status, loopback, run_until_done, switched_on, written_since,
};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{Loopback, ProtocolKind};
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const GALIL: ProtocolKind = ProtocolKind::Galil;
const CHANNELS: [usize; 2] = [0, 1];
const TICK: Duration = Duration::from_millis(10);

#[test]
fn the_driver_sends_what_the_epics_driver_sends() {
    common::golden::driver_sends_the_transcripts(GALIL)
}

#[test]
fn the_emulator_answers_what_the_epics_driver_sends() {
    common::golden::emulator_answers_the_transcripts(GALIL)
}

#[test]
fn a_new_connection_reads_switches_the_servos_on_once_and_polls_every_axis_in_one_record() {
    let channels = [0, 1, 2, 3];
    let mut lb = loopback(GALIL, &channels, Faults::default());
    let events = bring_up(&mut lb);
    let sent = written_since(&lb, 0);
    assert_eq!(sent[..7], ["\u{12}\u{16}\r", "QZ\r", "MTA=?\r", "MTB=?\r", "MTC=?\r", "MTD=?\r", "SHABCD\r"]);
    assert!(sent[7..].iter().all(|l| l == "QR\r"), "one record a poll: {sent:?}");
    for channel in channels {
        assert!(!Loopback::statuses(&events, channel).is_empty(), "axis {channel} reported");
    }
}

#[test]
fn a_move_arrives_where_asked_and_a_relative_one_from_there() {
    let mut lb = switched_on(GALIL, &CHANNELS);
    common::a_move_arrives_where_asked_and_a_relative_one_from_there(&mut lb, 1, go);
}

#[test]
fn a_jog_runs_until_stopped_and_meets_the_limit_switch_if_not() {
    let mut lb = switched_on(GALIL, &CHANNELS);
    common::a_jog_runs_until_stopped_or_the_limit_switch(&mut lb, 0);
}

#[test]
fn a_home_is_the_controllers_and_ends_homed_at_zero() {
    let mut lb = switched_on(GALIL, &CHANNELS);
    lb.command(0, &go(30_000.0, false));
    run_until_done(&mut lb, 0, TICK, Duration::from_secs(5));
    let from = lb.written().len();
    lb.command(
        0,
        &DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 },
    );
    let home = *run_until_done(&mut lb, 0, TICK, Duration::from_secs(20)).last().expect("done");
    assert_eq!(home.msta & msta::HOMED, msta::HOMED, "{home:?}");
    assert!(home.position.abs() < 1.0, "{home:?}");
    let sent = written_since(&lb, from);
    assert_eq!(sent[..5], ["ACA=199680\r", "DCA=199680\r", "SPA=20000\r", "HMA\r", "BGA\r"]);
    // A move afterwards keeps it homed; a new connection does not know.
    lb.command(0, &go(100.0, false));
    let moved = *run_until_done(&mut lb, 0, TICK, Duration::from_secs(5)).last().expect("done");
    assert_ne!(moved.msta & msta::HOMED, 0);
}

#[test]
fn a_refused_begin_reaches_the_record_with_the_controllers_reason() {
    let mut lb = loopback(GALIL, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(1, &DriverCommand::Enable { on: false });
    lb.run_for(Duration::from_millis(100));
    lb.take_events();
    lb.command(1, &go(1000.0, false));
    lb.run_for(Duration::from_millis(1100));
    let events = lb.take_events();
    let errors = controller_errors(&events);
    assert_eq!(errors.len(), 1, "{events:?}");
    assert_eq!(errors[0].0, Some(1));
    assert!(!errors[0].1.is_empty() && !errors[0].2.is_empty(), "a code and its text: {errors:?}");
    assert_ne!(last_status(&events, 1).msta & msta::PROBLEM, 0);
    assert_eq!(lb.link.emulator().axis(1).map(|a| a.physical_position()), Some(0.0), "nothing moved");
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    common::replies_in_pieces_give_the_same_statuses(GALIL, &CHANNELS);
}

#[test]
fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing() {
    let mut lb = switched_on(GALIL, &CHANNELS);
    let reads = |l: &str| l.ends_with("=?\r") || l == "QR\r" || l == "QZ\r" || l == "\u{12}\u{16}\r";
    common::a_move_goes_once_and_a_new_connection_only_reads(&mut lb, 0, common::text, |l| l.starts_with("PAA"), reads);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_line(
        commands in proptest::collection::vec((0usize..2, command(), 0u64..300), 1..12)
    ) {
        common::no_malformed_frames(GALIL, &CHANNELS, common::Start::AsPoweredUp, &commands);
    }
}

#[test]
fn a_setting_of_the_initialisation_whose_reply_is_lost_is_not_sent_twice_on_one_connection() {
    // The fifth reply, SHAB's (after the firmware's, QZ's and two MT?'s), is lost: the link is
    // given up and opened again (after 1.5 s here), never the servos switched on twice in a row.
    let mut lb = loopback(GALIL, &CHANNELS, Faults { drop_every: Some(5), ..Faults::default() });
    lb.run_for(Duration::from_millis(1400));
    let servos_on = lb.written().iter().filter(|w| w.starts_with(b"SHAB")).count();
    assert_eq!(servos_on, 1, "{:?}", lb.written());
}
