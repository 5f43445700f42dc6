//! PI GCS 2 against its emulated C-884, in virtual time: every record command as the controller
//! takes it, its errors with PI's meaning, and no sequence of commands that yields a frame the
//! controller cannot read. One step is 0.1 µm (the emulator's 10000 counts per mm); its stages
//! stand at 5 mm (counting 0 there at power-up), with limit switches at ±20 mm, the reference
//! switch at 0 and a travel range of ±19.5 mm.

mod common;

use common::{bring_up, command, controller_errors, last_status, loopback, run_until_done, written_since};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{
    ControllerConfig, ControllerEvent, Finding, Loopback, ProtocolKind, ProtocolOptions, RecordUnits, Refusal,
    ScaleCheck,
};
use zmotor_core::Instant;
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const PI: ProtocolKind = ProtocolKind::PiGcs2;
const TICK: Duration = Duration::from_millis(10);

/// A move at 10 mm/s, 100 mm/s².
fn go(position: f64, relative: bool) -> DriverCommand {
    DriverCommand::Move { position, relative, min_velocity: 0.0, max_velocity: 100_000.0, acceleration: 1_000_000.0 }
}

fn jog(velocity: f64) -> DriverCommand {
    DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: velocity, acceleration: 1_000_000.0 }
}

fn home(forward: bool) -> DriverCommand {
    DriverCommand::Home { forward, min_velocity: 0.0, max_velocity: 50_000.0, acceleration: 1_000_000.0 }
}

fn physical(lb: &mut Loopback, channel: usize) -> f64 {
    lb.link.emulator().axis(channel).expect("an axis").physical_position()
}

/// Up, with `channel`'s position set to `steps` (which also makes the axis count as
/// referenced, so that it may move).
fn up_with_position(channels: &[usize], channel: usize, steps: f64) -> Loopback {
    let mut lb = loopback(PI, channels, Faults::default());
    bring_up(&mut lb);
    lb.command(channel, &DriverCommand::SetPosition { position: steps });
    // As the record follows a position set with GET_INFO.
    lb.command(channel, &DriverCommand::Poll);
    lb.run_for(Duration::from_millis(100));
    let status = last_status(&lb.take_events(), channel);
    assert_eq!((status.position, status.msta & msta::HOMED), (steps, msta::HOMED), "{status:?}");
    lb
}

#[test]
fn a_connection_reads_the_controller_switches_servo_on_and_moves_nothing() {
    let mut lb = loopback(PI, &[1, 3], Faults::default());
    let events = bring_up(&mut lb);
    let sent = written_since(&lb, 0);
    assert_eq!(sent[..4], ["*IDN?\n", "SAI?\n", "TRS? 1\n", "LIM? 1\n"]);
    let servo = sent.iter().position(|s| s == "SVO 1 1 3 1\n").expect("servo on");
    assert_eq!(sent[servo + 1..servo + 6], ["ERR?\n", "SRG? 1 1\n", "POS? 1\n", "FRF? 1\n", "SRG? 3 1\n"]);
    assert!(sent.iter().all(|s| !["MOV", "MVR", "FRF ", "FNL", "FPL"].iter().any(|verb| s.starts_with(verb))));
    for channel in [1, 3] {
        let status = last_status(&events, channel);
        let shown = msta::DONE | msta::POSITION | msta::HOMED | msta::PROBLEM | msta::MOVING;
        assert_eq!(status.msta & shown, msta::DONE | msta::POSITION, "servo on, not referenced: {status:?}");
        assert_eq!(status.position, 0.0, "counting from 0 where it stands");
        assert_eq!(physical(&mut lb, channel), 5.0);
    }
    assert!(controller_errors(&events).is_empty());
}

#[test]
fn moves_absolute_and_relative_land_where_asked() {
    let mut lb = up_with_position(&[1], 1, 0.0);
    let start = lb.written().len();
    lb.command(1, &go(123_456.0, false));
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(5));
    assert!(statuses.iter().any(|s| s.msta & msta::MOVING != 0 && s.msta & msta::DIRECTION != 0));
    assert_eq!(statuses.last().map(|s| s.position), Some(123_456.0));
    assert!((physical(&mut lb, 1) - 17.3456).abs() < 1e-9);
    lb.command(1, &go(-23_456.0, true));
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(5));
    let last = statuses.last().expect("done");
    assert_eq!((last.position, last.msta & (msta::PROBLEM | msta::DIRECTION)), (100_000.0, 0));
    let sent = written_since(&lb, start);
    assert!(sent.contains(&"MOV 1 12.345600\n".to_string()) && sent.contains(&"MVR 1 -2.345600\n".to_string()));
    assert!(controller_errors(&lb.take_events()).is_empty());
}

#[test]
fn a_move_of_an_unreferenced_axis_is_refused_before_it_is_sent_saying_why() {
    let mut lb = loopback(PI, &[1], Faults::default());
    bring_up(&mut lb);
    let start = lb.written().len();
    for command in [go(10_000.0, false), go(10_000.0, true), jog(10_000.0)] {
        lb.command(1, &command);
        lb.run_for(Duration::from_millis(100));
        let events = lb.take_events();
        let refused = ControllerEvent::Refused { channel: 1, why: Refusal::NotReferenced };
        assert!(events.contains(&refused), "{command:?}: {events:?}");
        assert_eq!(last_status(&events, 1).msta & (msta::PROBLEM | msta::DONE), msta::PROBLEM | msta::DONE);
    }
    let sent = written_since(&lb, start);
    assert!(sent.iter().all(|s| !s.starts_with("MOV") && !s.starts_with("MVR")), "{sent:?}");
    assert_eq!(physical(&mut lb, 1), 5.0);
    // A position set makes it referenced: the move right behind it is the controller's to judge.
    lb.command(1, &DriverCommand::SetPosition { position: 0.0 });
    lb.command(1, &go(10_000.0, false));
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(2));
    assert_eq!(statuses.last().map(|s| (s.position, s.msta & msta::PROBLEM)), Some((10_000.0, 0)));
}

#[test]
fn a_move_the_controller_refuses_is_a_controller_error_with_its_meaning_and_a_problem() {
    let mut lb = up_with_position(&[1], 1, 0.0);
    // Referenced, but beyond the travel range.
    lb.command(1, &go(250_000.0, false));
    lb.run_for(Duration::from_millis(100));
    let events = lb.take_events();
    assert_eq!(controller_errors(&events), [(Some(1), "7".to_string(), "Position out of limits".to_string())]);
    assert_ne!(last_status(&events, 1).msta & msta::PROBLEM, 0);
    assert_eq!(physical(&mut lb, 1), 5.0);
    // The next command clears it.
    lb.command(1, &go(1000.0, false));
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(2));
    assert_eq!(statuses.last().map(|s| (s.position, s.msta & msta::PROBLEM)), Some((1000.0, 0)));
}

#[test]
fn a_jog_runs_until_stopped_and_the_stop_is_no_problem() {
    let mut lb = up_with_position(&[1], 1, 0.0);
    let start = lb.written().len();
    lb.command(1, &jog(50_000.0));
    lb.run_for(Duration::from_secs(1));
    let status = last_status(&lb.take_events(), 1);
    assert_eq!(status.msta & (msta::DONE | msta::MOVING), msta::MOVING);
    assert!(status.position > 40_000.0, "{status:?}");
    lb.command(1, &DriverCommand::Stop { acceleration: 1_000_000.0 });
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(2));
    let stopped = statuses.last().expect("done");
    assert!(stopped.position < 60_000.0, "stopped soon after the stop: {stopped:?}");
    assert_eq!(stopped.msta & msta::PROBLEM, 0, "error 10 after HLT is what a stop leaves");
    let sent = written_since(&lb, start);
    assert!(sent.contains(&"MOV 1 19.500000\n".to_string()), "a jog is a move to the end of travel: {sent:?}");
    assert!(sent.windows(2).any(|w| w == ["HLT 1\n", "ERR?\n"]));
    assert!(controller_errors(&lb.take_events()).is_empty());
}

#[test]
fn a_jog_left_running_ends_on_the_limit_switch() {
    // -10 mm where the stage stands at 5: the end of travel (19.5) lies beyond the switch (20
    // mm, read as 5 mm).
    let mut lb = up_with_position(&[2], 2, -100_000.0);
    lb.command(2, &jog(100_000.0));
    let statuses = run_until_done(&mut lb, 2, TICK, Duration::from_secs(5));
    let at_limit = statuses.last().expect("done");
    assert_ne!(at_limit.msta & msta::PLUS_LS, 0, "{at_limit:?}");
    assert_eq!(at_limit.position, 50_000.0);
    assert_eq!(physical(&mut lb, 2), 20.0);
    lb.command(2, &jog(-100_000.0));
    lb.run_for(Duration::from_millis(200));
    assert_eq!(last_status(&lb.take_events(), 2).msta & msta::PLUS_LS, 0, "backs off the switch");
}

#[test]
fn a_home_references_the_axis_at_its_reference_switch() {
    let mut lb = loopback(PI, &[1], Faults::default());
    bring_up(&mut lb);
    let start = lb.written().len();
    lb.command(1, &home(false));
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(10));
    assert!(statuses.iter().any(|s| s.msta & msta::MOVING != 0));
    let homed = statuses.last().expect("done");
    assert_eq!(homed.msta & (msta::HOMED | msta::DONE | msta::PROBLEM), msta::HOMED | msta::DONE, "{homed:?}");
    assert_eq!(homed.position, 0.0, "0 at the reference switch");
    assert!(lb.link.emulator().axis(1).expect("axis 1").on_home_switch());
    assert_eq!(
        written_since(&lb, start)[..6],
        ["SPA 1 0x50 5.000000\n", "ERR?\n", "SVO 1 1\n", "ERR?\n", "FRF 1\n", "ERR?\n"]
    );
    // Forward alike: the controller finds the switch from its side.
    lb.command(1, &go(50_000.0, false));
    run_until_done(&mut lb, 1, TICK, Duration::from_secs(2));
    let start = lb.written().len();
    lb.command(1, &home(true));
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(10));
    assert_eq!(statuses.last().map(|s| s.position), Some(0.0));
    assert!(written_since(&lb, start).contains(&"FRF 1\n".to_string()));
}

#[test]
fn set_position_redefines_the_position_without_moving() {
    let mut lb = up_with_position(&[1], 1, 30_000.0);
    assert_eq!(physical(&mut lb, 1), 5.0);
    lb.run_for(Duration::from_secs(2));
    assert_eq!(last_status(&lb.take_events(), 1).position, 30_000.0);
}

#[test]
fn servo_off_then_a_move_does_not_move() {
    let mut lb = up_with_position(&[1], 1, 0.0);
    lb.command(1, &DriverCommand::Enable { on: false });
    lb.run_for(Duration::from_millis(1100));
    let status = last_status(&lb.take_events(), 1);
    assert_eq!(status.msta & (msta::POSITION | msta::PROBLEM), 0, "off on request: no problem");
    lb.command(1, &go(50_000.0, false));
    lb.run_for(Duration::from_secs(1));
    let events = lb.take_events();
    assert_eq!(controller_errors(&events).first().map(|e| e.1.as_str()), Some("5"));
    assert_eq!(last_status(&events, 1).position, 0.0);
    assert_eq!(physical(&mut lb, 1), 5.0);
    lb.command(1, &DriverCommand::Enable { on: true });
    lb.command(1, &go(50_000.0, false));
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(2));
    let last = statuses.last().expect("done");
    assert_eq!((last.position, last.msta & (msta::POSITION | msta::PROBLEM)), (50_000.0, msta::POSITION));
}

#[test]
fn a_motion_error_is_reported_with_its_meaning_and_stays_a_problem_until_the_servo_is_on_again() {
    let mut lb = up_with_position(&[1], 1, 0.0);
    lb.command(1, &go(150_000.0, false));
    lb.run_for(Duration::from_millis(500));
    assert!(lb.link.emulator().raise_error(1));
    lb.run_for(Duration::from_millis(200));
    let events = lb.take_events();
    let errors = controller_errors(&events);
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert_eq!(errors[0].1, "1024");
    assert!(errors[0].2.contains("servo is switched off"), "{errors:?}");
    let status = last_status(&events, 1);
    assert_eq!(status.msta & (msta::PROBLEM | msta::POSITION | msta::DONE), msta::PROBLEM | msta::DONE);
    // A command that does not switch the servo on leaves it a problem.
    lb.command(1, &DriverCommand::SetPosition { position: 0.0 });
    lb.run_for(Duration::from_secs(2));
    assert_ne!(last_status(&lb.take_events(), 1).msta & msta::PROBLEM, 0);
    lb.command(1, &DriverCommand::Enable { on: true });
    lb.command(1, &DriverCommand::Poll);
    lb.run_for(Duration::from_millis(100));
    let status = last_status(&lb.take_events(), 1);
    assert_eq!(status.msta & (msta::PROBLEM | msta::POSITION), msta::POSITION);
}

#[test]
fn a_reconnection_leaves_the_servo_as_it_finds_it() {
    let mut lb = loopback(PI, &[1], Faults::default());
    bring_up(&mut lb);
    // The servo goes off (a motion error), then the link drops and comes back.
    lb.link.emulator().raise_error(1);
    lb.link.set_faults(Faults { close_after: Some(1), ..Faults::default() });
    let start = lb.written().len();
    lb.run_for(Duration::from_millis(1100));
    lb.link.set_faults(Faults::default());
    lb.run_for(Duration::from_secs(1));
    assert!(lb.controller.is_up());
    let events = lb.take_events();
    assert!(events.contains(&ControllerEvent::Disconnect), "{events:?}");
    let sent = written_since(&lb, start);
    assert!(sent.contains(&"*IDN?\n".to_string()), "initialised again: {sent:?}");
    assert!(!sent.iter().any(|s| s.starts_with("SVO")), "not switched on behind the user's back: {sent:?}");
    let status = last_status(&events, 1);
    assert_eq!(status.msta & (msta::PROBLEM | msta::POSITION | msta::COMM_ERR), msta::PROBLEM);
}

#[test]
fn an_mres_that_disagrees_with_the_controllers_scale_moves_nothing_and_says_what_agrees() {
    // The controller counts 10000 per mm (0.1 µm a step); axis 1 says 1 µm a step, axis 2 agrees.
    let mut config = ControllerConfig::for_channels(vec![1, 2]);
    let units = |egu: &str, mres: f64| RecordUnits { egu: egu.into(), mres };
    config.record_units = [(1, units("mm", 0.001)), (2, units("um", 0.1))].into();
    let controller = PI.controller(&ProtocolOptions::default(), config, Instant::ZERO);
    let mut lb = Loopback::new(controller, common::emulator(PI, 3), Faults::default());
    let events = bring_up(&mut lb);
    let checks: Vec<(usize, ScaleCheck)> = events
        .iter()
        .filter_map(|e| match e {
            ControllerEvent::Scale { channel, scale, check } => {
                assert!((scale.units_per_step - 0.0001).abs() < 1e-12, "{scale:?}");
                Some((*channel, check.clone()))
            }
            _ => None,
        })
        .collect();
    assert_eq!(checks.len(), 2, "{events:?}");
    assert_eq!(checks[1], (2, ScaleCheck::Agrees));
    let ScaleCheck::Disagrees(mismatch) = &checks[0].1 else { panic!("{checks:?}") };
    assert!((mismatch.expected_mres - 0.0001).abs() < 1e-12 && (mismatch.ratio - 10.0).abs() < 1e-9);
    assert!(events.iter().any(|e| matches!(e, ControllerEvent::Found(Finding::Identity(i)) if i.contains("C-884"))));
    // Referenced by a position set (no motion), then every motion of axis 1 is refused unsent.
    lb.command(1, &DriverCommand::SetPosition { position: 0.0 });
    lb.run_for(Duration::from_millis(200));
    lb.take_events();
    let start = lb.written().len();
    for command in [go(1000.0, false), jog(1000.0), home(true)] {
        lb.command(1, &command);
        lb.run_for(Duration::from_millis(100));
        let events = lb.take_events();
        let refused = ControllerEvent::Refused { channel: 1, why: Refusal::ScaleMismatch(mismatch.clone()) };
        assert!(events.contains(&refused), "{command:?}: {events:?}");
    }
    let sent = written_since(&lb, start);
    assert!(sent.iter().all(|s| !["MOV", "MVR", "FRF ", "FNL", "FPL"].iter().any(|v| s.starts_with(v))), "{sent:?}");
    assert_eq!(physical(&mut lb, 1), 5.0);
}

#[test]
fn units_given_by_the_installation_replace_the_controllers() {
    // One step of 1 µm.
    let options = ProtocolOptions { units_per_step: Some(0.001), ..ProtocolOptions::default() };
    let config = ControllerConfig::for_channels(vec![1]);
    let controller = PI.controller(&options, config, Instant::ZERO);
    let mut lb = Loopback::new(controller, common::emulator(PI, 2), Faults::default());
    bring_up(&mut lb);
    assert!(!written_since(&lb, 0).iter().any(|s| s.starts_with("SPA?")));
    lb.command(1, &DriverCommand::SetPosition { position: 0.0 });
    lb.command(1, &go(1234.0, false));
    let statuses = run_until_done(&mut lb, 1, TICK, Duration::from_secs(5));
    assert_eq!(statuses.last().map(|s| s.position), Some(1234.0));
    assert!((physical(&mut lb, 1) - 6.234).abs() < 1e-9);
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    let run = |chunk: usize| {
        let mut lb = loopback(PI, &[1, 2], Faults::default()).with_chunks(chunk);
        bring_up(&mut lb);
        lb.command(2, &DriverCommand::SetPosition { position: 0.0 });
        lb.command(2, &go(-30_000.0, false));
        lb.run_for(Duration::from_secs(2));
        let events = lb.take_events();
        (Loopback::statuses(&events, 1), Loopback::statuses(&events, 2), lb.written().to_vec())
    };
    let whole = run(usize::MAX);
    assert!(whole.1.iter().any(|s| s.position == -30_000.0 && s.msta & msta::DONE != 0));
    assert_eq!(run(1), whole);
    assert_eq!(run(2), whole);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_frame(
        commands in proptest::collection::vec((0usize..2, command(), 0u64..300), 1..12)
    ) {
        common::no_malformed_frames(PI, &[1, 4], common::Start::Homed, &commands);
    }
}

#[test]
fn the_driver_sends_what_the_epics_driver_sends() {
    common::golden::driver_sends_the_transcripts(ProtocolKind::PiGcs2)
}

#[test]
fn the_emulator_answers_what_the_epics_driver_sends() {
    common::golden::emulator_answers_the_transcripts(ProtocolKind::PiGcs2)
}
