//! ACS MCB-4B against its emulator, in virtual time: every record command as the controller
//! takes it, and no sequence of commands that yields a frame the controller cannot read.

mod common;

use common::{bring_up, command, last_status, loopback, run_until_done};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{Loopback, ProtocolKind};
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const ACS: ProtocolKind = ProtocolKind::AcsMcb4b;
const TICK: Duration = Duration::from_millis(10);

#[test]
fn the_driver_sends_what_the_epics_driver_sends() {
    common::golden::driver_sends_the_transcripts(ACS)
}

#[test]
fn the_emulator_answers_what_the_epics_driver_sends() {
    common::golden::emulator_answers_the_transcripts(ACS)
}

#[test]
fn a_jog_runs_until_stopped_and_meets_the_limit_switch_if_not() {
    let mut lb = loopback(ACS, &[1], Faults::default());
    bring_up(&mut lb);
    common::a_jog_runs_until_stopped_or_the_limit_switch(&mut lb, 1);
}

#[test]
fn a_home_search_ends_at_the_home_switch() {
    let mut lb = loopback(ACS, &[0], Faults::default());
    bring_up(&mut lb);
    lb.command(0, &DriverCommand::SetPosition { position: 30_000.0 });
    lb.run_for(Duration::from_millis(100));
    lb.command(
        0,
        &DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 },
    );
    let statuses = run_until_done(&mut lb, 0, TICK, Duration::from_secs(10));
    let home = statuses.last().expect("done");
    assert_eq!(home.msta & msta::HOME, msta::HOME, "{home:?}");
    assert!(lb.written().iter().any(|w| w.as_slice() == b"#00H-\r"));
}

#[test]
fn drive_power_follows_enable_and_a_powered_off_axis_does_not_move() {
    let mut lb = loopback(ACS, &[0], Faults::default());
    bring_up(&mut lb);
    lb.command(0, &DriverCommand::Enable { on: false });
    lb.run_for(Duration::from_millis(1100));
    assert_eq!(last_status(&lb.take_events(), 0).msta & msta::POSITION, 0);
    lb.command(
        0,
        &DriverCommand::Move {
            position: 100.0,
            relative: true,
            min_velocity: 0.0,
            max_velocity: 1000.0,
            acceleration: 10_000.0,
        },
    );
    let statuses = run_until_done(&mut lb, 0, TICK, Duration::from_secs(2));
    assert_eq!(statuses.last().map(|s| s.position), Some(0.0));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_frame(
        commands in proptest::collection::vec((0usize..2, command(), 0u64..300), 1..12)
    ) {
        common::no_malformed_frames(ACS, &[0, 3], common::Start::AsPoweredUp, &commands);
    }
}

#[test]
fn positions_are_whole_steps_as_the_controller_counts() {
    let mut lb = loopback(ACS, &[0], Faults::default());
    bring_up(&mut lb);
    lb.command(
        0,
        &DriverCommand::Move {
            position: 1234.6,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 5000.0,
            acceleration: 50_000.0,
        },
    );
    let statuses = run_until_done(&mut lb, 0, TICK, Duration::from_secs(2));
    assert_eq!(statuses.last().map(|s| s.position), Some(1235.0));
    assert!(Loopback::statuses(&lb.take_events(), 0).is_empty());
}
