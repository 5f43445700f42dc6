//! Newport ESP300 against its emulator, in virtual time: every record command as the
//! controller takes it, the error buffer, and no sequence of commands that yields a line it
//! cannot read.

mod common;

use common::{
    bring_up, command, controller_errors, go, last_status, loopback, run_until_done, switched_on, written_since,
};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{ControllerEvent, ProtocolKind};
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const ESP: ProtocolKind = ProtocolKind::NewportEsp300;
const CHANNELS: [usize; 2] = [1, 2];
const TICK: Duration = Duration::from_millis(10);

#[test]
fn the_driver_sends_what_the_epics_driver_sends() {
    common::golden::driver_sends_the_transcripts(ESP)
}

#[test]
fn the_emulator_answers_what_the_epics_driver_sends() {
    common::golden::emulator_answers_the_transcripts(ESP)
}

#[test]
fn a_new_connection_reads_the_configuration_and_stops_nothing() {
    let mut lb = loopback(ESP, &CHANNELS, Faults::default());
    let events = bring_up(&mut lb);
    let sent = written_since(&lb, 0);
    assert_eq!(sent[0], "VE?\r");
    let writes: Vec<&String> = sent.iter().filter(|l| !(l.ends_with("?\r") || *l == "PH\r")).collect();
    assert_eq!(writes, ["01MO;02MO\r"], "queries, and the motors switched on (the first connection)");
    let scales: Vec<_> = events.iter().filter(|e| matches!(e, ControllerEvent::Scale { .. })).collect();
    assert_eq!(scales.len(), 2, "{events:?}");
    let ControllerEvent::Scale { scale, .. } = scales[0] else { unreachable!() };
    assert!(scale.units_per_step > 0.0, "read from the controller: {scale:?}");
}

#[test]
fn a_move_arrives_where_asked_in_the_stages_units() {
    let mut lb = switched_on(ESP, &CHANNELS);
    common::a_move_arrives_where_asked_and_a_relative_one_from_there(&mut lb, 2, go);
}

#[test]
fn a_jog_runs_until_stopped_and_meets_the_limit_switch_if_not() {
    let mut lb = switched_on(ESP, &CHANNELS);
    common::a_jog_runs_until_stopped_or_the_limit_switch(&mut lb, 1);
}

#[test]
fn a_home_search_ends_on_the_home_switch() {
    let mut lb = switched_on(ESP, &CHANNELS);
    lb.command(1, &go(30_000.0, false));
    run_until_done(&mut lb, 1, TICK, Duration::from_secs(5));
    lb.command(
        1,
        &DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 },
    );
    let home = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(20)).last().expect("done");
    assert_ne!(home.msta & msta::HOME, 0, "{home:?}");
}

#[test]
fn a_motion_the_controller_refuses_reaches_the_record_with_its_error() {
    let mut lb = loopback(ESP, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(1, &DriverCommand::Enable { on: false });
    lb.run_for(Duration::from_millis(200));
    lb.take_events();
    lb.command(1, &go(1000.0, false));
    lb.run_for(Duration::from_millis(500));
    let events = lb.take_events();
    let errors = controller_errors(&events);
    assert!(!errors.is_empty() && errors.iter().all(|(channel, ..)| *channel == Some(1)), "{events:?}");
    assert_ne!(last_status(&events, 1).msta & msta::PROBLEM, 0);
    assert_eq!(lb.link.emulator().axis(1).map(|a| a.physical_position()), Some(0.0), "nothing moved");
}

#[test]
fn an_unknown_command_is_the_controllers_error_and_the_link_stays_up() {
    let mut lb = switched_on(ESP, &CHANNELS);
    common::an_unknown_command_is_an_error_and_the_link_stays_up(&mut lb, 2, "02XX", (None, "6"));
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    common::replies_in_pieces_give_the_same_statuses(ESP, &CHANNELS);
}

#[test]
fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing() {
    let mut lb = switched_on(ESP, &CHANNELS);
    let reads = |l: &str| l.ends_with("?\r") || l == "PH\r";
    common::a_move_goes_once_and_a_new_connection_only_reads(&mut lb, 1, common::text, |l| l.contains("PA"), reads);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_line(
        commands in proptest::collection::vec((0usize..2, command(), 0u64..300), 1..12)
    ) {
        common::no_malformed_frames(ESP, &CHANNELS, common::Start::AsPoweredUp, &commands);
    }
}
