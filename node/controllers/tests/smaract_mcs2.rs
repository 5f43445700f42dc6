//! SmarAct MCS2 against its emulator, in virtual time: every record command as the controller
//! takes it (in picometres, one step a nanometre), its error queue reaching the record, and no
//! sequence of commands that yields a line the controller cannot read.

mod common;

use common::{bring_up, command, controller_errors, go, last_status, loopback, run_until_done, written_since};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{ControllerConfig, ControllerEvent, Loopback, ProtocolKind, ProtocolOptions, VendorError};
use zmotor_core::Instant;
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const MCS2: ProtocolKind = ProtocolKind::SmaractMcs2;
const TICK: Duration = Duration::from_millis(10);

#[test]
fn moves_land_where_asked_to_the_picometre() {
    let mut lb = loopback(MCS2, &[0], Faults::default());
    bring_up(&mut lb);
    let start = lb.written().len();
    lb.command(0, &go(1234.567, false));
    assert_eq!(
        written_since(&lb, start)[..4],
        [":CHAN0:MMOD 0\r\n", ":CHAN0:ACC 200000000\r\n", ":CHAN0:VEL 20000000\r\n", ":MOVE0 1234567\r\n"]
    );
    let statuses = run_until_done(&mut lb, 0, TICK, Duration::from_secs(2));
    assert!(statuses.iter().any(|s| s.msta & msta::MOVING != 0), "moving was seen: {statuses:?}");
    assert_eq!(statuses.last().map(|s| s.position), Some(1234.567));
    lb.command(0, &go(-234.567, true));
    let statuses = run_until_done(&mut lb, 0, TICK, Duration::from_secs(2));
    let done = statuses.last().expect("done");
    assert_eq!((done.position, done.encoder_position), (1000.0, 1000.0));
    assert_eq!(lb.link.emulator().axis(0).map(|a| a.physical_position()), Some(1_000_000.0), "in picometres");
    assert!(lb.take_events().iter().all(|e| !matches!(e, ControllerEvent::ControllerError(VendorError { .. }))));
}

#[test]
fn a_jog_runs_until_stopped_and_meets_the_end_stop_if_not() {
    let mut lb = loopback(MCS2, &[1], Faults::default());
    bring_up(&mut lb);
    lb.command(1, &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -5000.0, acceleration: 50_000.0 });
    lb.run_for(Duration::from_secs(1));
    let status = last_status(&lb.take_events(), 1);
    assert_eq!(status.msta & (msta::DONE | msta::MOVING | msta::DIRECTION), msta::MOVING, "moving down");
    assert!(status.position < -4000.0, "{status:?}");
    lb.command(1, &DriverCommand::Stop { acceleration: 50_000.0 });
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(2));
    let stopped = statuses.last().expect("done");
    assert!(stopped.position > -6000.0, "stopped soon after the stop: {stopped:?}");
    assert_eq!(stopped.msta & (msta::PLUS_LS | msta::MINUS_LS), 0);
    // A jog left running ends on the end stop at -200000 nm: the limit on its own side only.
    lb.command(
        1,
        &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -100_000.0, acceleration: 500_000.0 },
    );
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(5));
    let at_end = statuses.last().expect("done");
    assert_eq!(at_end.msta & (msta::PLUS_LS | msta::MINUS_LS), msta::MINUS_LS, "{at_end:?}");
    assert_eq!(at_end.position, -200_000.0);
    // Away from it, the end stop is behind.
    lb.command(1, &go(1000.0, true));
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(2));
    assert_eq!(statuses.last().map(|s| s.msta & (msta::PLUS_LS | msta::MINUS_LS)), Some(0));
}

#[test]
fn a_reference_search_ends_on_the_mark_with_the_position_zeroed() {
    let mut lb = loopback(MCS2, &[0], Faults::default());
    let events = bring_up(&mut lb);
    assert_eq!(last_status(&events, 0).msta & msta::HOMED, 0, "not referenced at power-up");
    lb.command(0, &go(50_000.0, false));
    run_until_done(&mut lb, 0, TICK, Duration::from_secs(5));
    lb.command(0, &DriverCommand::SetPosition { position: 80_000.0 });
    let start = lb.written().len();
    lb.command(
        0,
        &DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 },
    );
    assert_eq!(
        written_since(&lb, start)[..5],
        [
            ":CHAN0:REF:OPT 5\r\n",
            ":CHAN0:HOLD -1\r\n",
            ":CHAN0:ACC 200000000\r\n",
            ":CHAN0:VEL 20000000\r\n",
            ":REF0\r\n"
        ]
    );
    let statuses = run_until_done(&mut lb, 0, TICK, Duration::from_secs(10));
    assert!(statuses.iter().any(|s| s.msta & msta::MOVING != 0), "{statuses:?}");
    let home = statuses.last().expect("done");
    assert_eq!(home.msta & (msta::HOME | msta::HOMED), msta::HOME | msta::HOMED, "{home:?}");
    assert_eq!(home.position, 0.0, "AUTO_ZERO");
    assert_eq!(lb.link.emulator().axis(0).map(|a| a.physical_position()), Some(0.0));
}

#[test]
fn a_set_position_redefines_the_position_without_moving() {
    let mut lb = loopback(MCS2, &[0], Faults::default());
    bring_up(&mut lb);
    lb.command(0, &DriverCommand::SetPosition { position: -1500.5 });
    lb.run_for(Duration::from_millis(1100));
    let status = last_status(&lb.take_events(), 0);
    assert_eq!((status.position, status.msta & msta::DONE), (-1500.5, msta::DONE));
    let axis = lb.link.emulator().axis(0).expect("channel 0");
    assert_eq!((axis.physical_position(), axis.is_moving()), (0.0, false));
    // Absolute targets count from the new position.
    lb.command(0, &go(-500.5, false));
    let statuses = run_until_done(&mut lb, 0, TICK, Duration::from_secs(2));
    assert_eq!(statuses.last().map(|s| s.position), Some(-500.5));
    assert_eq!(lb.link.emulator().axis(0).map(|a| a.physical_position()), Some(1_000_000.0));
}

#[test]
fn with_the_amplifier_off_the_controller_refuses_a_move_and_the_record_sees_why() {
    let mut lb = loopback(MCS2, &[0], Faults::default());
    let events = bring_up(&mut lb);
    assert_ne!(last_status(&events, 0).msta & msta::POSITION, 0, "amplifier on at power-up");
    lb.command(0, &DriverCommand::Enable { on: false });
    lb.run_for(Duration::from_millis(1100));
    let events = lb.take_events();
    assert_eq!(last_status(&events, 0).msta & (msta::POSITION | msta::PROBLEM), 0);
    lb.command(0, &go(100.0, true));
    lb.run_for(Duration::from_millis(300));
    let events = lb.take_events();
    assert_eq!(controller_errors(&events), [(Some(0), "262".to_string(), "Amplifier disabled".to_string())]);
    let status = last_status(&events, 0);
    assert_eq!(status.msta & (msta::PROBLEM | msta::DONE), msta::PROBLEM | msta::DONE);
    assert_eq!(status.position, 0.0);
    assert!(!lb.link.emulator().axis(0).expect("channel 0").is_moving());
    // Back on, the next move runs and the problem is gone.
    lb.command(0, &DriverCommand::Enable { on: true });
    lb.command(0, &go(100.0, true));
    let statuses = run_until_done(&mut lb, 0, TICK, Duration::from_secs(2));
    let done = statuses.last().expect("done");
    assert_eq!((done.position, done.msta & (msta::PROBLEM | msta::POSITION)), (100.0, msta::POSITION));
}

#[test]
fn an_error_in_the_controllers_queue_reaches_every_channel_with_its_meaning_until_commanded() {
    let mut lb = loopback(MCS2, &[0, 1], Faults::default());
    bring_up(&mut lb);
    assert!(lb.link.emulator().raise_error(0));
    lb.run_for(Duration::from_millis(1100));
    let events = lb.take_events();
    // The queue is the device's: it names no channel.
    assert_eq!(controller_errors(&events), [(None, "272".to_string(), "Movement overridden".to_string())]);
    for channel in [0, 1] {
        assert_ne!(last_status(&events, channel).msta & msta::PROBLEM, 0, "channel {channel}");
    }
    lb.command(0, &go(10.0, true));
    run_until_done(&mut lb, 0, TICK, Duration::from_secs(2));
    lb.run_for(Duration::from_millis(1100));
    let events = lb.take_events();
    assert_eq!(last_status(&events, 0).msta & msta::PROBLEM, 0, "commanded since");
    assert_ne!(last_status(&events, 1).msta & msta::PROBLEM, 0, "not commanded since");
    assert!(controller_errors(&events).is_empty(), "the queue was read to its end");
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    let run = |chunk: usize| {
        let mut lb = loopback(MCS2, &[0, 1], Faults::default()).with_chunks(chunk);
        bring_up(&mut lb);
        lb.command(1, &go(-3000.0, false));
        lb.link.emulator().raise_error(0);
        lb.run_for(Duration::from_secs(2));
        let events = lb.take_events();
        (
            Loopback::statuses(&events, 0),
            Loopback::statuses(&events, 1),
            controller_errors(&events),
            lb.written().to_vec(),
        )
    };
    let whole = run(usize::MAX);
    assert!(whole.1.iter().any(|s| s.position == -3000.0 && s.msta & msta::DONE != 0));
    assert_eq!(whole.2.len(), 1);
    assert_eq!(run(1), whole);
    assert_eq!(run(3), whole);
}

#[test]
fn connecting_and_reconnecting_move_nothing() {
    let mut lb = loopback(MCS2, &[0, 2], Faults::default());
    bring_up(&mut lb);
    let first = written_since(&lb, 0);
    assert_eq!(
        first,
        [
            ":DEV:SNUM?\r\n",
            ":SYST:ERR?\r\n",
            ":CHAN0:HOLD -1\r\n",
            ":CHAN2:HOLD -1\r\n",
            ":SYST:ERR?\r\n",
            ":CHAN0:STAT?\r\n",
            ":CHAN0:POS?\r\n",
            ":CHAN0:AMPL?\r\n",
            ":CHAN2:STAT?\r\n",
            ":CHAN2:POS?\r\n",
            ":CHAN2:AMPL?\r\n",
            ":SYST:ERR?\r\n"
        ]
    );
    lb.command(0, &go(2000.0, false));
    run_until_done(&mut lb, 0, TICK, Duration::from_secs(2));
    // The connection drops and comes back: initialised and polled again, nothing else.
    lb.link.set_faults(Faults { close_after: Some(1), ..Faults::default() });
    lb.run_for(Duration::from_millis(200));
    assert!(lb.take_events().contains(&ControllerEvent::Disconnect));
    lb.link.set_faults(Faults::default());
    let start = lb.written().len();
    lb.run_for(Duration::from_secs(3));
    assert!(lb.controller.is_up());
    let again = written_since(&lb, start);
    assert!(again.starts_with(&first[..5]), "{again:?}");
    assert!(again.iter().all(|line| line.ends_with("?\r\n") || line.ends_with(":HOLD -1\r\n")), "{again:?}");
    let axis = lb.link.emulator().axis(0).expect("channel 0");
    assert_eq!((axis.physical_position(), axis.is_moving()), (2_000_000.0, false));
}

#[test]
fn the_scale_is_the_launch_files() {
    let options = ProtocolOptions { units_per_step: Some(1.0), ..ProtocolOptions::default() };
    let controller = MCS2.controller(&options, ControllerConfig::for_channels(vec![0]), Instant::ZERO);
    let mut lb = Loopback::new(controller, common::emulator(MCS2, 1), Faults::default());
    bring_up(&mut lb);
    lb.command(0, &go(1500.0, false));
    let statuses = run_until_done(&mut lb, 0, TICK, Duration::from_secs(2));
    assert_eq!(statuses.last().map(|s| s.position), Some(1500.0));
    assert_eq!(lb.link.emulator().axis(0).map(|a| a.physical_position()), Some(1500.0), "1500 pm");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_frame(
        commands in proptest::collection::vec((0usize..2, command(), 0u64..300), 1..12)
    ) {
        common::no_malformed_frames(MCS2, &[0, 3], common::Start::AsPoweredUp, &commands);
    }
}

#[test]
fn an_error_reported_during_a_motion_shows_a_problem_but_does_not_end_it() {
    let mut lb = loopback(MCS2, &[0], Faults::default());
    bring_up(&mut lb);
    // An error waits in the queue: the move's own error read reports it, before any poll has
    // seen the stage move (the last status read says "done").
    assert!(lb.link.emulator().raise_error(0));
    // 100 µm at 20 µm/s: five seconds of motion.
    lb.command(0, &go(100_000.0, false));
    lb.run_for(Duration::from_millis(500));
    let events = lb.take_events();
    assert!(!controller_errors(&events).is_empty(), "the error was read: {events:?}");
    let statuses = Loopback::statuses(&events, 0);
    assert!(statuses.iter().any(|s| s.msta & msta::PROBLEM != 0), "{statuses:?}");
    assert!(statuses.iter().all(|s| s.msta & msta::DONE == 0), "the motion goes on: {statuses:?}");
}

#[test]
fn the_driver_sends_what_the_epics_driver_sends() {
    common::golden::driver_sends_the_transcripts(MCS2)
}

#[test]
fn the_emulator_answers_what_the_epics_driver_sends() {
    common::golden::emulator_answers_the_transcripts(MCS2)
}
