//! McLennan PM304 against its emulator, in virtual time: every record command as the controller
//! takes it, its refusals, and no sequence of commands that yields a line it cannot read.

mod common;

use common::{bring_up, command, go, loopback, run_until_done, written_since};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::ProtocolKind;
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const PM304: ProtocolKind = ProtocolKind::McLennanPm304;
const CHANNELS: [usize; 2] = [1, 2];
const TICK: Duration = Duration::from_millis(10);

#[test]
fn the_driver_sends_what_the_epics_driver_sends() {
    common::golden::driver_sends_the_transcripts(PM304)
}

#[test]
fn the_emulator_answers_what_the_epics_driver_sends() {
    common::golden::emulator_answers_the_transcripts(PM304)
}

#[test]
fn a_new_connection_identifies_each_axis_and_writes_nothing() {
    let mut lb = loopback(PM304, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    let sent = written_since(&lb, 0);
    assert_eq!(sent[..2], ["1ID\r", "2ID\r"]);
    assert!(sent[2..].iter().all(|l| l.ends_with("OS\r") || l.ends_with("OA\r")), "reads only: {sent:?}");
}

#[test]
fn a_move_arrives_where_asked_and_a_relative_one_from_there() {
    let mut lb = loopback(PM304, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::a_move_arrives_where_asked_and_a_relative_one_from_there(&mut lb, 2, go);
}

#[test]
fn a_jog_runs_until_stopped_and_meets_the_limit_switch_if_not() {
    let mut lb = loopback(PM304, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::a_jog_runs_until_stopped_or_the_limit_switch(&mut lb, 1);
}

#[test]
fn a_datum_search_ends_at_zero_and_homed() {
    let mut lb = loopback(PM304, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(1, &go(30_000.0, false));
    run_until_done(&mut lb, 1, TICK, Duration::from_secs(5));
    let from = lb.written().len();
    lb.command(
        1,
        &DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 },
    );
    let home = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(20)).last().expect("done");
    assert_eq!((home.position, home.msta & msta::HOMED), (0.0, msta::HOMED), "{home:?}");
    assert_eq!(written_since(&lb, from)[3], "1IX-1\r");
}

#[test]
fn an_unknown_command_is_the_controllers_error_and_the_link_stays_up() {
    let mut lb = loopback(PM304, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::an_unknown_command_is_an_error_and_the_link_stays_up(&mut lb, 2, "2XX", (Some(2), "!"));
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    common::replies_in_pieces_give_the_same_statuses(PM304, &CHANNELS);
}

#[test]
fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing() {
    let mut lb = loopback(PM304, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    let reads = |l: &str| l.ends_with("ID\r") || l.ends_with("OS\r") || l.ends_with("OA\r");
    common::a_move_goes_once_and_a_new_connection_only_reads(&mut lb, 1, common::text, |l| l.contains("MA"), reads);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_line(
        commands in proptest::collection::vec((0usize..2, command(), 0u64..300), 1..12)
    ) {
        common::no_malformed_frames(PM304, &CHANNELS, common::Start::AsPoweredUp, &commands);
    }
}
