//! IMS MDrive Plus motors against their emulator, in virtual time: every record command as the
//! motors take it, their refusals, the homed flag, and no sequence of commands that yields a
//! line they cannot read.

mod common;

use common::{bring_up, command, go, loopback, run_until_done, written_since};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{Loopback, ProtocolKind};
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const MDRIVE: ProtocolKind = ProtocolKind::ImsMdrive;
const CHANNELS: [usize; 2] = [1, 2];
const TICK: Duration = Duration::from_millis(10);

fn is_read(line: &str) -> bool {
    line.get(1..).is_some_and(|code| code.starts_with("PR "))
}

#[test]
fn the_driver_sends_what_the_epics_driver_sends() {
    common::golden::driver_sends_the_transcripts(MDRIVE)
}

#[test]
fn the_emulator_answers_what_the_epics_driver_sends() {
    common::golden::emulator_answers_the_transcripts(MDRIVE)
}

#[test]
fn a_new_connection_reads_each_motor_and_writes_nothing() {
    let mut lb = loopback(MDRIVE, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    let sent = written_since(&lb, 0);
    assert_eq!(sent[..2], ["1PR VR\r\n", "1PR EE\r\n"]);
    assert!(sent.iter().all(|l| is_read(l)), "reads only: {sent:?}");
    assert!(sent.contains(&"2PR I3\r\n".to_string()), "the minus limit input found and polled: {sent:?}");
}

#[test]
fn a_move_arrives_where_asked_and_a_relative_one_from_there() {
    let mut lb = loopback(MDRIVE, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::a_move_arrives_where_asked_and_a_relative_one_from_there(&mut lb, 2, go);
}

#[test]
fn a_jog_runs_until_stopped_and_meets_the_limit_switch_if_not() {
    let mut lb = loopback(MDRIVE, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::a_jog_runs_until_stopped_or_the_limit_switch(&mut lb, 1);
}

#[test]
fn a_home_search_ends_homed_and_a_stopped_one_does_not() {
    let mut lb = loopback(MDRIVE, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(1, &go(30_000.0, false));
    run_until_done(&mut lb, 1, TICK, Duration::from_secs(5));
    let home =
        DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 };
    lb.command(1, &home);
    lb.run_for(Duration::from_millis(300));
    lb.command(1, &DriverCommand::Stop { acceleration: 200_000.0 });
    let stopped = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(5)).last().expect("done");
    lb.run_for(Duration::from_secs(2));
    let later = common::last_status(&lb.take_events(), 1);
    assert_eq!((stopped.msta | later.msta) & msta::HOMED, 0, "an aborted search homed nothing: {later:?}");
    let from = lb.written().len();
    lb.command(1, &home);
    let homed = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(20)).last().expect("done");
    lb.run_for(Duration::from_secs(2));
    let homed_later = common::last_status(&lb.take_events(), 1);
    assert_eq!(homed_later.msta & msta::HOMED, msta::HOMED, "{homed:?} then {homed_later:?}");
    assert_eq!(homed_later.position, 0.0);
    let sent = written_since(&lb, from);
    assert!(sent.contains(&"1HM 1\r\n".to_string()) && sent.contains(&"1R1=1\r\n".to_string()), "{sent:?}");
}

#[test]
fn a_home_stopped_before_its_error_check_is_answered_homes_nothing() {
    // The stop comes while the home's `PR ER` is on its way (replies 5 ms late).
    let mut lb = loopback(MDRIVE, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(1, &go(30_000.0, false));
    run_until_done(&mut lb, 1, TICK, Duration::from_secs(5));
    lb.link.set_faults(Faults { delay: Duration::from_millis(5), ..Faults::default() });
    let home =
        DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 };
    lb.command(1, &home);
    lb.command(1, &DriverCommand::Stop { acceleration: 200_000.0 });
    run_until_done(&mut lb, 1, TICK, Duration::from_secs(5));
    lb.run_for(Duration::from_secs(2));
    let events = lb.take_events();
    let homed = Loopback::statuses(&events, 1).iter().any(|s| s.msta & msta::HOMED != 0);
    assert!(!homed, "a stopped search homed nothing: {events:?}");
}

#[test]
fn a_refused_command_is_the_motors_error_named_once_and_cleared() {
    let mut lb = loopback(MDRIVE, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    // A base speed above the top speed: the motor refuses VI (error 22 or 23).
    let go = DriverCommand::Move {
        position: 100.0,
        relative: false,
        min_velocity: 30_000.0,
        max_velocity: 20_000.0,
        acceleration: 200_000.0,
    };
    let from = lb.written().len();
    lb.command(2, &go);
    lb.run_for(Duration::from_millis(500));
    let events = lb.take_events();
    let errors = common::controller_errors(&events);
    assert_eq!(errors.len(), 1, "{events:?}");
    assert_eq!(errors[0].0, Some(2));
    assert!(["22", "23"].contains(&errors[0].1.as_str()), "{errors:?}");
    assert!(written_since(&lb, from).contains(&"2ER=0\r\n".to_string()));
    // Cleared: the next command draws no error.
    lb.command(2, &DriverCommand::SetPosition { position: 5.0 });
    lb.run_for(Duration::from_millis(300));
    assert!(common::controller_errors(&lb.take_events()).is_empty());
}

#[test]
fn an_unknown_command_is_the_motors_error_and_the_link_stays_up() {
    let mut lb = loopback(MDRIVE, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::an_unknown_command_is_an_error_and_the_link_stays_up(&mut lb, 2, "XX", (Some(2), "20"));
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    common::replies_in_pieces_give_the_same_statuses(MDRIVE, &CHANNELS);
}

#[test]
fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing() {
    let mut lb = loopback(MDRIVE, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    common::a_move_goes_once_and_a_new_connection_only_reads(
        &mut lb,
        1,
        common::text,
        |l| l.starts_with("1MA"),
        is_read,
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_line(
        commands in proptest::collection::vec((0usize..2, command(), 0u64..300), 1..12)
    ) {
        common::no_malformed_frames(MDRIVE, &CHANNELS, common::Start::AsPoweredUp, &commands);
    }
}

#[test]
fn a_refused_home_homes_nothing_and_a_jog_to_a_limit_is_no_error() {
    let mut lb = loopback(MDRIVE, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    lb.command(1, &go(150_000.0, false));
    lb.run_for(Duration::from_millis(200));
    // A home while moving: refused (85), named once; the move's end homes nothing.
    let home =
        DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 };
    lb.command(1, &home);
    lb.run_for(Duration::from_millis(300));
    let errors = common::controller_errors(&lb.take_events());
    assert_eq!(errors.iter().map(|(_, code, _)| code.as_str()).collect::<Vec<_>>(), ["85"], "{errors:?}");
    let done = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(20)).last().expect("done");
    lb.run_for(Duration::from_secs(2));
    let events = lb.take_events();
    assert!(common::controller_errors(&events).is_empty(), "{events:?}");
    assert_eq!((done.msta | common::last_status(&events, 1).msta) & msta::HOMED, 0, "{done:?}");
    // A jog left to run ends on the minus limit switch: the limit bit says it, ERR stays quiet.
    let jog = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -40_000.0, acceleration: 400_000.0 };
    lb.command(1, &jog);
    let end = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(20)).last().expect("done");
    lb.run_for(Duration::from_secs(2));
    let events = lb.take_events();
    assert_ne!(end.msta & msta::MINUS_LS, 0, "{end:?}");
    assert!(common::controller_errors(&events).is_empty(), "{events:?}");
}
