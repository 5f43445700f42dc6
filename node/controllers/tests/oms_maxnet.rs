//! OMS MAXnet against its emulator, in virtual time: every record command as the controller takes
//! it, a poll of every axis in four exchanges, the end of a motion however it comes (its done
//! flag, a limit switch, or never), and no sequence of commands that yields a line it cannot read.

mod common;

use common::{bring_up, command, go, loopback, run_until_done, written_since};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::ProtocolKind;
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const MAXNET: ProtocolKind = ProtocolKind::OmsMaxnet;
const CHANNELS: [usize; 2] = [0, 2];
const TICK: Duration = Duration::from_millis(10);

fn is_read(line: &str) -> bool {
    ["WY\n", "AM;RI;\n", "AM PP;\n", "AM;RV;\n", "AM;QL;\n"].contains(&line)
        || line.ends_with("PS?\n")
        || line.ends_with("LT?\n")
}

#[test]
fn the_driver_sends_what_the_epics_driver_sends() {
    common::golden::driver_sends_the_transcripts(MAXNET)
}

#[test]
fn the_emulator_answers_what_the_epics_driver_sends() {
    common::golden::emulator_answers_the_transcripts(MAXNET)
}

#[test]
fn a_new_connection_reads_and_polls_every_axis_in_four_exchanges() {
    let mut lb = loopback(MAXNET, &CHANNELS, Faults::default());
    let events = bring_up(&mut lb);
    let sent = written_since(&lb, 0);
    assert_eq!(sent[..5], ["WY\n", "AX PS?\n", "AX LT?\n", "AZ PS?\n", "AZ LT?\n"]);
    assert_eq!(sent[5..], ["AM;RI;\n", "AM PP;\n", "AM;RV;\n", "AM;QL;\n"]);
    for channel in CHANNELS {
        let status = common::last_status(&events, channel);
        assert_eq!(status.msta & (msta::DONE | msta::PLUS_LS | msta::MINUS_LS), msta::DONE, "{status:?}");
    }
}

#[test]
fn a_move_arrives_where_asked_and_a_relative_one_from_there() {
    let mut lb = loopback(MAXNET, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::a_move_arrives_where_asked_and_a_relative_one_from_there(&mut lb, 2, go);
}

#[test]
fn a_jog_runs_until_stopped_and_meets_the_limit_switch_if_not() {
    let mut lb = loopback(MAXNET, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::a_jog_runs_until_stopped_or_the_limit_switch(&mut lb, 0);
}

#[test]
fn a_home_ends_at_zero_on_the_switch() {
    let mut lb = loopback(MAXNET, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(0, &go(30_000.0, false));
    run_until_done(&mut lb, 0, TICK, Duration::from_secs(5));
    let home =
        DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 };
    lb.command(0, &home);
    let end = *run_until_done(&mut lb, 0, TICK, Duration::from_secs(20)).last().expect("done");
    assert_eq!((end.position, end.msta & (msta::HOME | msta::PROBLEM)), (0.0, msta::HOME), "{end:?}");
}

#[test]
fn a_motion_that_never_says_done_ends_as_a_problem_after_five_polls() {
    let mut lb = loopback(MAXNET, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    // A move to where the axis stands ends at once; another client (here, straight at the
    // emulator) reads the done flag before the driver's poll can: the poll finds only a rest.
    lb.command(0, &go(0.0, false));
    let now = lb.now();
    let emulator = lb.link.emulator();
    emulator.handle_input(now, b"AX RI\n");
    while emulator.poll_transmit().is_some() {}
    let statuses = run_until_done(&mut lb, 0, TICK, Duration::from_secs(5));
    let end = statuses.last().expect("done");
    assert_eq!(end.msta & (msta::DONE | msta::PROBLEM), msta::DONE | msta::PROBLEM, "{statuses:?}");
    let waiting = statuses.iter().filter(|s| s.msta & msta::DONE == 0).count();
    assert!(waiting >= 4, "five polls at rest before giving up: {statuses:?}");
}

#[test]
fn a_stop_without_a_deceleration_brakes_as_motoromsasyn_does_and_raw_queries_are_refused() {
    let mut lb = loopback(MAXNET, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    let from = lb.written().len();
    lb.command(2, &DriverCommand::Stop { acceleration: 0.0 });
    lb.run_for(Duration::from_millis(100));
    assert_eq!(written_since(&lb, from)[0], "AZ AC200000; ST ID;\n");
    let from = lb.written().len();
    lb.command(2, &DriverCommand::Raw { text: "RP".into() });
    let events = lb.take_events();
    assert!(events.iter().any(|e| matches!(e, zmotor_controllers::ControllerEvent::Refused { channel: 2, .. })));
    assert!(written_since(&lb, from).iter().all(|l| is_read(l)));
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    common::replies_in_pieces_give_the_same_statuses(MAXNET, &CHANNELS);
}

#[test]
fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing() {
    let mut lb = loopback(MAXNET, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::a_move_goes_once_and_a_new_connection_only_reads(&mut lb, 0, common::text, |l| l.contains("GO"), is_read);
}

#[test]
fn a_target_beyond_the_controllers_range_is_refused_unsent() {
    let mut lb = loopback(MAXNET, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    let from = lb.written().len();
    lb.command(0, &go(70_000_000.0, false));
    let events = lb.take_events();
    assert!(events.iter().any(|e| matches!(e, zmotor_controllers::ControllerEvent::Refused { channel: 0, .. })));
    assert!(written_since(&lb, from).iter().all(|l| is_read(l)));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_line(
        commands in proptest::collection::vec((0usize..2, command(), 0u64..300), 1..12)
    ) {
        common::no_malformed_frames(MAXNET, &CHANNELS, common::Start::AsPoweredUp, &commands);
    }
}

#[test]
fn an_unknown_command_is_the_controllers_command_error_and_the_link_stays_up() {
    let mut lb = loopback(MAXNET, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::an_unknown_command_is_an_error_and_the_link_stays_up(&mut lb, 2, "XX", (Some(2), "command error"));
}
