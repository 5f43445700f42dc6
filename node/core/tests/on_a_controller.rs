//! An axis on a controller's channel ("model 3"): the controller polls, the axis keeps the last
//! status it reported; a motion command is "not done" at once, and DMOV 1 follows the report
//! that says the motion is over. A controller not reached puts the axis in COMM alarm and its
//! autosaved position is not restored onto a stage nobody can see.

use zmotor_core::{Axis, AxisEvent, DeviceStatus, Instant, PollRates};
use zmotor_msgs::bits::msta;
use zmotor_msgs::menus::{severity, status};
use zmotor_msgs::{DriverCommand, Field, Fields, Value};

fn at(seconds: f64) -> Instant {
    Instant::from_secs_f64(seconds)
}

fn stage() -> Fields {
    Fields { mres: 0.001, velo: 10.0, accl: 0.2, dhlm: 100.0, dllm: -100.0, ..Fields::default() }
}

fn report(position: f64, done: bool) -> DeviceStatus {
    let bits = if done { msta::DONE } else { msta::MOVING };
    DeviceStatus { position, encoder_position: position, msta: bits | msta::POSITION, ..DeviceStatus::default() }
}

fn dmov_posts(events: &[AxisEvent]) -> Vec<Value> {
    events.iter().filter_map(|e| if let AxisEvent::Post(Field::DMOV, v) = e { Some(v.clone()) } else { None }).collect()
}

fn driver_commands(events: &[AxisEvent]) -> Vec<DriverCommand> {
    events
        .iter()
        .filter_map(|e| if let AxisEvent::Driver { command, .. } = e { Some(command.clone()) } else { None })
        .collect()
}

#[test]
fn a_move_is_done_when_the_controller_says_so_not_before() {
    let mut axis = Axis::new_on_controller(stage(), Some(report(2000.0, true)), PollRates::default(), Instant::ZERO);
    assert_eq!(axis.fields().rbv, 2.0);
    axis.drain_events().count();
    assert_eq!(axis.poll_timeout(), None, "the controller polls, not the axis");

    axis.write(at(1.0), Field::VAL, &Value::Float(5.0)).unwrap();
    let events: Vec<AxisEvent> = axis.drain_events().collect();
    assert!(
        matches!(driver_commands(&events)[..], [DriverCommand::Move { position, relative: false, .. }] if position == 5000.0)
    );
    assert_eq!(dmov_posts(&events), [Value::Int(0)]);

    // A report from a poll while moving, then an unchanged one: the record stays in motion.
    axis.controller_status(at(1.1), report(3000.0, false), 1);
    axis.controller_status(at(1.2), report(3000.0, false), 1);
    let events: Vec<AxisEvent> = axis.drain_events().collect();
    assert!(dmov_posts(&events).is_empty());
    assert_eq!((axis.fields().rbv, axis.fields().dmov, axis.fields().movn), (3.0, 0, 1));

    axis.controller_status(at(1.4), report(5000.0, true), 1);
    let events: Vec<AxisEvent> = axis.drain_events().collect();
    assert_eq!(dmov_posts(&events), [Value::Int(1)]);
    assert!(events.iter().any(|e| matches!(e, AxisEvent::Done(_))));
    assert_eq!(axis.fields().rbv, 5.0);
}

#[test]
fn a_stale_done_between_the_command_and_the_next_report_does_not_end_the_move() {
    let mut axis = Axis::new_on_controller(stage(), Some(report(0.0, true)), PollRates::default(), Instant::ZERO);
    axis.write(at(0.0), Field::VAL, &Value::Float(1.0)).unwrap();
    axis.drain_events().count();
    // Nothing reported yet: the axis itself keeps "not done".
    axis.handle_timeout(at(5.0));
    assert_eq!(axis.fields().dmov, 0);
}

#[test]
fn a_status_read_before_the_move_reached_the_controller_does_not_end_it() {
    let mut axis = Axis::new_on_controller(stage(), Some(report(0.0, true)), PollRates::default(), Instant::ZERO);
    axis.write(at(0.0), Field::VAL, &Value::Float(1.0)).unwrap();
    axis.drain_events().count();
    // Read by the controller before it had the move (its count of motions is 0): crossed it.
    axis.controller_status(at(0.01), report(0.0, true), 0);
    assert_eq!(axis.fields().dmov, 0);
    axis.controller_status(at(0.2), report(1000.0, true), 1);
    assert_eq!((axis.fields().dmov, axis.fields().rbv), (1, 1.0));
}

#[test]
fn an_axis_whose_controller_is_not_reached_boots_in_comm_alarm_and_restores_nothing() {
    let autosaved = Fields { dval: 7.0, val: 7.0, ..stage() };
    let mut axis = Axis::new_on_controller(autosaved, None, PollRates::default(), Instant::ZERO);
    let events: Vec<AxisEvent> = axis.drain_events().collect();
    assert!(driver_commands(&events).iter().all(|c| !matches!(c, DriverCommand::SetPosition { .. })), "{events:?}");
    let f = axis.fields();
    assert_eq!((f.stat, f.sevr), (status::COMM, severity::INVALID));
    assert_ne!(f.msta & msta::COMM_ERR, 0);
    // Reached: the alarm clears and the readback is the controller's.
    axis.controller_status(at(2.0), report(1500.0, true), 0);
    let f = axis.fields();
    assert_eq!((f.stat, f.sevr, f.rbv), (status::NO_ALARM, severity::NO_ALARM, 1.5));
    assert_eq!(f.msta & msta::COMM_ERR, 0);
}

#[test]
fn an_autosaved_position_is_restored_onto_a_controller_that_lost_its_own() {
    let autosaved = Fields { dval: 7.0, val: 7.0, ..stage() };
    let mut axis = Axis::new_on_controller(autosaved, Some(report(0.0, true)), PollRates::default(), Instant::ZERO);
    let events: Vec<AxisEvent> = axis.drain_events().collect();
    assert!(driver_commands(&events).contains(&DriverCommand::SetPosition { position: 7000.0 }), "{events:?}");
}

#[test]
fn losing_the_controller_during_a_move_ends_it_in_comm_alarm() {
    let mut axis = Axis::new_on_controller(stage(), Some(report(0.0, true)), PollRates::default(), Instant::ZERO);
    axis.write(at(0.0), Field::VAL, &Value::Float(50.0)).unwrap();
    axis.controller_status(at(0.1), report(100.0, false), 1);
    axis.drain_events().count();
    let lost = DeviceStatus { msta: msta::COMM_ERR | msta::DONE | msta::POSITION, ..report(100.0, true) };
    axis.controller_status(at(3.0), lost, 1);
    let events: Vec<AxisEvent> = axis.drain_events().collect();
    assert_eq!(dmov_posts(&events), [Value::Int(1)]);
    let f = axis.fields();
    assert_eq!((f.stat, f.sevr, f.miss), (status::COMM, severity::INVALID, 1));
    assert!(events.iter().any(|e| matches!(e, AxisEvent::Post(Field::SEVR, Value::Int(3)))));
    assert!(driver_commands(&events).is_empty(), "no retry is sent to a controller out of reach: {events:?}");
}
