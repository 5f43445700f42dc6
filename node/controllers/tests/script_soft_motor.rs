//! motorScriptMotor's own `softMotor.lua`, unchanged: a soft motor over `epics.get`/`epics.put`,
//! here on the loopback's key space (the node's, in a deployment), in virtual time. Its PVs are
//! zmotor names: `gap.VAL` is the key `motor/gap/VAL`.

mod common;

use common::{bring_up, controller_errors, go, last_status, script_loopback, script_source};
use std::time::Duration;
use zmotor_controllers::{KeyAccess, KeyValue, Loopback, MacroValue};
use zmotor_emulators::{Faults, Model};
use zmotor_msgs::bits::msta;

const SOFT_MOTOR: &str = "node/controllers/tests/scripts/motorScriptMotor/softMotor.lua";

/// softMotor.lua on channel 0, its axis's MRES 0.001, reading `readback` and driving `gap.VAL`;
/// the readback key holds 0. The loopback's controller (a VMC's emulator) is never written to.
fn soft_motor(readback: &str) -> Loopback {
    let macros = [("DRIVE_PV", MacroValue::Text("gap.VAL".into())), ("READBACK_PV", MacroValue::Text(readback.into()))];
    let mut source = script_source(SOFT_MOTOR, "SOFT", &macros);
    source.record_resolution = [(0, 0.001)].into();
    let mut lb = script_loopback(&source, Model::Vmc, &[0], Faults::default());
    lb.keys.insert("motor/gap/RBV".into(), KeyValue::Number(0.0));
    lb
}

/// Every request written is a key access: what each is.
fn accesses(lb: &Loopback) -> Vec<KeyAccess> {
    lb.written()
        .iter()
        .map(|bytes| KeyAccess::decode(bytes).unwrap_or_else(|| panic!("not a key access: {bytes:?}")))
        .collect()
}

#[test]
fn a_poll_reads_the_readback_key_and_reports_it_in_steps_of_the_axis_mres() {
    let mut lb = soft_motor("gap.RBV");
    lb.keys.insert("motor/gap/RBV".into(), KeyValue::Number(0.25));
    let events = bring_up(&mut lb);
    assert!(controller_errors(&events).is_empty(), "{events:?}");
    let status = last_status(&events, 0);
    assert!((status.position - 250.0).abs() < 1e-9, "{status:?}");
    let read = KeyAccess::Get(zmotor_controllers::KeyName::parse("gap.RBV").unwrap());
    assert!(accesses(&lb).iter().all(|a| *a == read), "{:?}", accesses(&lb));
}

#[test]
fn a_move_writes_the_drive_key_and_ends_once_the_readback_is_there() {
    let mut lb = soft_motor("gap.RBV");
    bring_up(&mut lb);
    lb.command(0, &go(2000.0, false));
    lb.run_for(Duration::from_millis(10));
    assert_eq!(lb.keys.get("motor/gap/VAL"), Some(&KeyValue::Number(2.0)), "the target, in EGU");
    lb.take_events();
    lb.run_for(Duration::from_secs(1));
    let moving = last_status(&lb.take_events(), 0);
    assert_eq!(moving.msta & (msta::DONE | msta::MOVING), msta::MOVING, "not done before the readback: {moving:?}");
    lb.keys.insert("motor/gap/RBV".into(), KeyValue::Number(2.0));
    lb.run_for(Duration::from_secs(1));
    let arrived = last_status(&lb.take_events(), 0);
    assert_eq!(arrived.msta & (msta::DONE | msta::MOVING), msta::DONE, "{arrived:?}");
    assert!((arrived.position - 2000.0).abs() < 1e-9, "{arrived:?}");
}

#[test]
fn a_stop_writes_where_the_axis_is_to_the_drive_key() {
    let mut lb = soft_motor("gap.RBV");
    bring_up(&mut lb);
    lb.command(0, &go(2000.0, false));
    lb.keys.insert("motor/gap/RBV".into(), KeyValue::Number(0.75));
    lb.run_for(Duration::from_secs(1));
    lb.command(0, &zmotor_msgs::DriverCommand::Stop { acceleration: 1000.0 });
    lb.run_for(Duration::from_millis(10));
    // softMotor.lua's stop writes MOTOR_POSITION (in steps) as it is: the script's own unit slip.
    assert_eq!(lb.keys.get("motor/gap/VAL"), Some(&KeyValue::Number(750.0)));
}

#[test]
fn a_key_nobody_serves_is_a_problem_naming_the_key_the_script_and_its_line() {
    let mut lb = soft_motor("slit.RBV");
    lb.run_for(Duration::from_millis(100));
    let errors = controller_errors(&lb.take_events());
    let (channel, _, meaning) = errors.first().expect("an error");
    assert_eq!(*channel, Some(0));
    assert!(
        meaning.contains("softMotor.lua:36:")
            && meaning.contains("epics.get(slit.RBV): nothing answers for motor/slit/RBV"),
        "{meaning}"
    );
}

#[test]
fn a_name_that_is_no_key_is_an_error_and_nothing_is_asked() {
    let mut lb = soft_motor("gap RBV");
    lb.run_for(Duration::from_millis(100));
    let errors = controller_errors(&lb.take_events());
    assert!(errors.iter().any(|(_, _, m)| m.contains("'gap RBV' is not a key")), "{errors:?}");
    assert!(lb.written().is_empty(), "{:?}", accesses(&lb));
}
