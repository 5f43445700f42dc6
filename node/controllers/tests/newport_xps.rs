//! Newport XPS against its emulator, in virtual time: motion calls on their own connections,
//! answered when the motion ends, while polls and stops go on; every record command as the
//! controller takes it; and no sequence of commands that yields a call it cannot read.

mod common;

use common::{bring_up, command, go, home_and_wait, loopback, run_until_done, written_since};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{ControllerEvent, Loopback, ProtocolKind};
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const XPS: ProtocolKind = ProtocolKind::NewportXps;
const CHANNELS: [usize; 2] = [1, 2];
const TICK: Duration = Duration::from_millis(10);

fn homed() -> Loopback {
    let mut lb = loopback(XPS, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    for channel in CHANNELS {
        home_and_wait(&mut lb, channel);
    }
    lb.take_events();
    lb
}

fn is_read(line: &str) -> bool {
    ["FirmwareVersionGet", "PositionerSGammaParametersGet", "PositionerUserTravelLimitsGet", "GroupStatusGet"]
        .iter()
        .chain(&[
            "GroupPositionCurrentGet",
            "GroupPositionSetpointGet",
            "PositionerErrorGet",
            "GroupVelocityCurrentGet",
        ])
        .any(|read| line.starts_with(read))
}

#[test]
fn the_driver_sends_what_the_epics_driver_sends() {
    common::golden::driver_sends_the_transcripts(XPS)
}

#[test]
fn the_emulator_answers_what_the_epics_driver_sends() {
    common::golden::emulator_answers_the_transcripts(XPS)
}

#[test]
fn the_first_connection_initialises_the_groups_powered_up_and_moves_nothing() {
    let mut lb = loopback(XPS, &CHANNELS, Faults::default());
    let events = bring_up(&mut lb);
    assert_eq!(lb.controller.lanes().len(), 3, "the main connection and one per channel");
    let sent = written_since(&lb, 0);
    assert_eq!(sent[0], "FirmwareVersionGet (char *)");
    let changes: Vec<&String> = sent.iter().filter(|l| !is_read(l)).collect();
    assert_eq!(changes, ["GroupInitialize (GROUP1)", "GroupInitialize (GROUP2)"]);
    let status = common::last_status(&events, 1);
    assert_eq!(status.msta & (msta::POSITION | msta::HOMED | msta::PROBLEM), msta::POSITION, "{status:?}");
    assert!(!lb.link.emulator().axis(1).expect("the channel").is_moving());
}

#[test]
fn a_move_is_refused_unsent_before_the_home_and_a_home_initialises_a_killed_group_first() {
    let mut lb = loopback(XPS, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    let from = lb.written().len();
    lb.command(1, &go(1000.0, false));
    let events = lb.take_events();
    assert!(events.iter().any(|e| matches!(e, ControllerEvent::Refused { channel: 1, .. })), "{events:?}");
    assert!(written_since(&lb, from).iter().all(|l| is_read(l)));
    home_and_wait(&mut lb, 1);
    let home: Vec<String> = written_since(&lb, from).into_iter().filter(|l| !is_read(l)).collect();
    assert_eq!(home, ["GroupHomeSearch (GROUP1)"], "initialised at connection: the search alone");
    // Homed, then killed (not initialised, state 7): a home initialises it first.
    lb.command(1, &DriverCommand::Raw { text: "GroupKill (GROUP1)".into() });
    lb.run_for(Duration::from_millis(200));
    let from = lb.written().len();
    home_and_wait(&mut lb, 1);
    let home: Vec<String> = written_since(&lb, from).into_iter().filter(|l| !is_read(l)).collect();
    assert_eq!(home, ["GroupInitialize (GROUP1)", "GroupHomeSearch (GROUP1)"]);
}

#[test]
fn a_move_arrives_where_asked_while_polls_go_on_beside_it() {
    let mut lb = homed();
    lb.command(2, &go(60_000.0, false));
    let statuses = run_until_done(&mut lb, 2, TICK, Duration::from_secs(10));
    // The motion call answers only at the end: the statuses on the way came from polls on the
    // main connection, the carriage between its start and its target.
    let on_the_way: Vec<_> = statuses.iter().filter(|s| s.msta & msta::MOVING != 0).collect();
    assert!(on_the_way.len() > 5, "{statuses:?}");
    assert!(on_the_way.iter().any(|s| s.position > 10_000.0 && s.position < 50_000.0), "{on_the_way:?}");
    let end = statuses.last().expect("done");
    assert!((end.position - 60_000.0).abs() < 1e-6, "{end:?}");
    lb.command(2, &go(-5_000.0, true));
    let end = *run_until_done(&mut lb, 2, TICK, Duration::from_secs(10)).last().expect("done");
    assert!((end.position - 55_000.0).abs() < 1e-6, "{end:?}");
}

#[test]
fn two_channels_move_at_once_each_on_its_own_connection() {
    let mut lb = homed();
    lb.command(1, &go(40_000.0, false));
    lb.command(2, &go(-40_000.0, false));
    lb.run_for(Duration::from_millis(500));
    let moving = |lb: &mut Loopback, channel| lb.link.emulator().axis(channel).expect("the channel").is_moving();
    assert!(moving(&mut lb, 1) && moving(&mut lb, 2), "both move: neither call waits for the other's end");
    run_until_done(&mut lb, 1, TICK, Duration::from_secs(10));
    let end = *run_until_done(&mut lb, 2, TICK, Duration::from_secs(10)).last().expect("done");
    assert!((end.position + 40_000.0).abs() < 1e-6, "{end:?}");
}

#[test]
fn a_stop_aborts_the_move_and_its_aborted_answer_is_no_error() {
    let mut lb = homed();
    lb.command(1, &go(150_000.0, false));
    lb.run_for(Duration::from_millis(500));
    let from = lb.written().len();
    lb.command(1, &DriverCommand::Stop { acceleration: 200_000.0 });
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(3));
    let end = statuses.last().expect("done");
    assert!(end.position < 20_000.0, "stopped soon: {end:?}");
    assert_eq!(end.msta & msta::PROBLEM, 0, "{end:?}");
    assert!(written_since(&lb, from).contains(&"GroupMoveAbort (GROUP1)".to_string()));
    lb.run_for(Duration::from_secs(1));
    let events = lb.take_events();
    assert!(common::controller_errors(&events).is_empty(), "-27 after a stop is expected: {events:?}");
    // The group is ready again: the next move goes.
    lb.command(1, &go(0.0, false));
    let end = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(10)).last().expect("done");
    assert!(end.position.abs() < 1e-6, "{end:?}");
}

#[test]
fn a_move_beyond_the_travel_is_the_controllers_error_on_its_channel() {
    let mut lb = homed();
    // The stage's travel ends 0.1 mm inside its limit switches (±200,000 steps).
    lb.command(1, &go(250_000.0, false));
    lb.run_for(Duration::from_millis(500));
    let events = lb.take_events();
    let errors = common::controller_errors(&events);
    assert_eq!(errors.len(), 1, "{events:?}");
    assert_eq!((errors[0].0, errors[0].1.as_str()), (Some(1), "-35"), "{errors:?}");
    assert!(errors[0].2.contains("GroupMoveAbsolute"), "names the call: {errors:?}");
    assert!(lb.controller.is_up());
}

#[test]
fn a_jog_runs_until_stopped_and_ends_at_the_travel_limit_if_not_then_a_move_goes() {
    let mut lb = homed();
    let jog = |velocity: f64| DriverCommand::MoveVelocity {
        min_velocity: 0.0,
        max_velocity: velocity,
        acceleration: 400_000.0,
    };
    lb.command(1, &jog(-5000.0));
    lb.run_for(Duration::from_secs(1));
    let status = common::last_status(&lb.take_events(), 1);
    assert_eq!(status.msta & (msta::DONE | msta::MOVING), msta::MOVING, "{status:?}");
    lb.command(1, &DriverCommand::Stop { acceleration: 400_000.0 });
    let stopped = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(3)).last().expect("done");
    assert!(stopped.position > -7000.0, "stopped soon after the stop: {stopped:?}");
    // Unstopped, the XPS ends the jog at its travel limit (0.1 mm inside the switch) and stays in
    // jog mode: done all the same, and the next move leaves jog mode first.
    lb.command(1, &jog(-40_000.0));
    let end = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(10)).last().expect("done");
    assert!((end.position + 199_000.0).abs() < 1e-6, "{end:?}");
    let from = lb.written().len();
    lb.command(1, &go(0.0, false));
    let end = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(20)).last().expect("done");
    assert!(end.position.abs() < 1e-6, "{end:?}");
    assert_eq!(written_since(&lb, from)[0], "GroupJogModeDisable (GROUP1)");
}

#[test]
fn a_position_set_is_read_back_and_leaves_the_group_ready() {
    let mut lb = homed();
    lb.command(2, &DriverCommand::SetPosition { position: 12_345.0 });
    lb.run_for(Duration::from_millis(500));
    let status = common::last_status(&lb.take_events(), 2);
    assert!((status.position - 12_345.0).abs() < 1e-6, "{status:?}");
    assert_eq!(status.msta & (msta::HOMED | msta::PROBLEM), msta::HOMED, "{status:?}");
}

#[test]
fn an_unknown_call_is_the_controllers_error_and_the_link_stays_up() {
    let mut lb = homed();
    common::an_unknown_command_is_an_error_and_the_link_stays_up(&mut lb, 2, "Unknown (GROUP2)", (Some(2), "-4"));
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    let script = |chunk: usize| {
        let mut lb = homed().with_chunks(chunk);
        lb.command(1, &go(30_000.0, false));
        lb.command(2, &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: 8000.0, acceleration: 80_000.0 });
        lb.run_for(Duration::from_millis(400));
        lb.command(2, &DriverCommand::Stop { acceleration: 80_000.0 });
        lb.run_for(Duration::from_secs(2));
        lb.command(1, &DriverCommand::SetPosition { position: -77.0 });
        lb.run_for(Duration::from_secs(1));
        let events = lb.take_events();
        [Loopback::statuses(&events, 1), Loopback::statuses(&events, 2)]
    };
    let whole = script(usize::MAX);
    assert_eq!(script(1), whole);
    assert!(whole[0].last().is_some_and(|s| (s.position + 77.0).abs() < 1e-6), "{:?}", whole[0].last());
    assert!(whole[1].last().is_some_and(|s| s.msta & msta::DONE != 0 && s.position > 0.0), "{:?}", whole[1].last());
}

#[test]
fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing() {
    let mut lb = homed();
    let moves = |l: &str| l.starts_with("GroupMoveAbsolute");
    common::a_move_goes_once_and_a_new_connection_only_reads(&mut lb, 1, common::text, moves, is_read);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_call(
        commands in proptest::collection::vec((0usize..2, command(), 0u64..300), 1..12)
    ) {
        common::no_malformed_frames(XPS, &CHANNELS, common::Start::Homed, &commands);
    }
}

#[test]
fn a_stop_right_after_a_move_ends_it_whenever_the_calls_were_under_way() {
    // Replies 30 ms late: the stop comes while the move's settings call is still unanswered,
    // so the move's motion call is dropped unsent, or just sent and not yet started.
    for stop_after_ms in [0, 10, 35, 70] {
        let mut lb = homed();
        lb.link.set_faults(Faults { delay: Duration::from_millis(30), ..Faults::default() });
        lb.command(1, &go(100_000.0, false));
        lb.run_for(Duration::from_millis(stop_after_ms));
        lb.command(1, &DriverCommand::Stop { acceleration: 200_000.0 });
        let end = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(5)).last().expect("done");
        lb.run_for(Duration::from_millis(2500));
        let events = lb.take_events();
        let after = common::last_status(&events, 1);
        assert!(common::controller_errors(&events).is_empty(), "after {stop_after_ms} ms: {events:?}");
        assert_eq!(after.msta & (msta::DONE | msta::PROBLEM), msta::DONE, "after {stop_after_ms} ms: {after:?}");
        assert!(end.position < 20_000.0, "stopped, not run to the target: {end:?}");
        assert!(!lb.link.emulator().axis(1).expect("the channel").is_moving());
    }
}

#[test]
fn a_refused_speed_sends_no_move() {
    let mut lb = homed();
    let from = lb.written().len();
    // 20 mm/s: beyond the stage's 10 mm/s, which the XPS refuses (-17).
    let fast = DriverCommand::Move {
        position: 10_000.0,
        relative: false,
        min_velocity: 0.0,
        max_velocity: 200_000.0,
        acceleration: 200_000.0,
    };
    lb.command(1, &fast);
    lb.run_for(Duration::from_millis(500));
    let events = lb.take_events();
    let errors = common::controller_errors(&events);
    assert_eq!(errors.len(), 1, "{events:?}");
    assert!(errors[0].2.contains("PositionerSGammaParametersSet"), "{errors:?}");
    let sent = written_since(&lb, from);
    assert!(!sent.iter().any(|l| l.starts_with("GroupMoveAbsolute")), "the move went at the old speed: {sent:?}");
    assert!(!lb.link.emulator().axis(1).expect("the channel").is_moving());
}

#[test]
fn a_reconnection_initialises_nothing_a_group_killed_stays_killed() {
    let mut lb = homed();
    lb.command(1, &DriverCommand::Raw { text: "GroupKill (GROUP1)".into() });
    lb.run_for(Duration::from_millis(300));
    lb.link.set_faults(Faults { close_after: Some(1), ..Faults::default() });
    lb.run_for(Duration::from_millis(1200));
    assert!(lb.take_events().contains(&zmotor_controllers::ControllerEvent::Disconnect));
    lb.link.set_faults(Faults::default());
    let from = lb.written().len();
    lb.run_for(Duration::from_secs(3));
    assert!(lb.controller.is_up());
    let sent = written_since(&lb, from);
    assert!(sent.iter().all(|l| is_read(l)), "reads only at a reconnection: {sent:?}");
    let status = common::last_status(&lb.take_events(), 1);
    assert_eq!(status.msta & (msta::HOMED | msta::POSITION), 0, "killed: unpowered, not referenced: {status:?}");
}

#[test]
fn a_poll_that_reached_the_controller_before_the_motion_call_does_not_end_it() {
    // Replies 10 ms late (a poll of five exchanges takes 50 ms), and the motion connection of
    // channel 1 (the controller's connection 1) 15 ms slower than the main one: the poll written
    // after the home call reads the group not yet homing, and ends after the home's answer (the
    // stage is on its home switch: the search ends at once). The home must end homed all the
    // same, and the move after it go.
    let mut lb = loopback(XPS, &CHANNELS, Faults::default());
    bring_up(&mut lb);
    let late = Faults {
        delay: Duration::from_millis(10),
        late_connection: Some((1, Duration::from_millis(15))),
        ..Faults::default()
    };
    lb.link.set_faults(late);
    let home =
        DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 };
    lb.command(1, &home);
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(20));
    let done = statuses.last().expect("done");
    assert_ne!(done.msta & msta::HOMED, 0, "done only once homed: {statuses:?}");
    lb.command(1, &go(20_000.0, false));
    let end = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(10)).last().expect("done");
    assert!((end.position - 20_000.0).abs() < 1e-6, "{end:?}");
}

#[test]
fn a_stop_while_a_home_reads_its_group_starts_nothing_after_it() {
    // The stop comes while the home's `GroupStatusGet` is on its way: what its answer would
    // have asked for next (a kill, an initialisation, the search) is not sent.
    let mut lb = loopback(XPS, &CHANNELS, Faults { delay: Duration::from_millis(5), ..Faults::default() });
    bring_up(&mut lb);
    let start = lb.written().len();
    let home =
        DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 };
    lb.command(1, &home);
    lb.command(1, &DriverCommand::Stop { acceleration: 200_000.0 });
    lb.run_for(Duration::from_secs(2));
    let sent = written_since(&lb, start);
    assert!(sent.first().is_some_and(|l| l.starts_with("GroupStatusGet")), "the home's reading went: {sent:?}");
    let started = ["GroupKill", "GroupInitialize", "GroupHomeSearch"];
    assert!(
        !sent.iter().any(|l| started.iter().any(|s| l.starts_with(s))),
        "nothing of the home after the stop: {sent:?}"
    );
    let now = lb.now();
    let axis = lb.link.emulator().axis(1).expect("an emulated positioner");
    zmotor_core::Driver::advance(axis, now);
    assert!(!axis.is_moving());
}
