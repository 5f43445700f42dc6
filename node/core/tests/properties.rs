//! Properties of an axis (record + device support + simulator) in virtual time, for any
//! sequence of writes: no move leg ends beyond the dial soft limits unless it starts beyond
//! them and heads back; DMOV returns to 1 once the simulator can reach the target; and
//! VAL = DVAL·dirsign + OFF, DIFF = DVAL − DRBV, RDIF = NINT(DIFF/MRES) whenever it is idle.

use proptest::prelude::*;
use std::time::Duration;
use zmotor_core::{Axis, AxisEvent, Driver, Instant, PollRates, SimAxis, SimConfig};
use zmotor_msgs::{DriverCommand, Field, Fields, Value};

const MRES: f64 = 0.01;
const LIMIT: f64 = 100.0;

#[derive(Clone, Debug)]
enum Op {
    Write(Field, Value),
    Wait(f64),
}

fn float(field: Field, range: std::ops::Range<f64>) -> impl Strategy<Value = Op> {
    range.prop_map(move |x| Op::Write(field, Value::Float(x)))
}

fn int(field: Field, range: std::ops::RangeInclusive<i64>) -> impl Strategy<Value = Op> {
    range.prop_map(move |i| Op::Write(field, Value::Int(i)))
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        6 => float(Field::VAL, -130.0..130.0),
        2 => float(Field::DVAL, -130.0..130.0),
        2 => float(Field::RLV, -60.0..60.0),
        1 => float(Field::TWV, -20.0..20.0),
        1 => int(Field::TWF, 1..=1),
        1 => int(Field::TWR, 1..=1),
        2 => int(Field::STOP, 1..=1),
        2 => int(Field::SPMG, 0..=3),
        1 => int(Field::JOGF, 0..=1),
        1 => int(Field::JOGR, 0..=1),
        1 => int(Field::HOMF, 1..=1),
        1 => int(Field::HOMR, 1..=1),
        2 => float(Field::BDST, -5.0..5.0),
        1 => float(Field::FRAC, 0.1..1.5),
        1 => float(Field::VELO, 1.0..50.0),
        // BVEL ≤ VBAS crawls at one step per second (Q29): legal, but beyond any time budget.
        1 => float(Field::BVEL, 0.5..20.0),
        1 => int(Field::DIR, 0..=1),
        1 => float(Field::OFF, -20.0..20.0),
        1 => int(Field::RTRY, 0..=5),
        1 => int(Field::RMOD, 0..=3),
        1 => int(Field::UEIP, 0..=1),
        1 => float(Field::DLY, 0.0..0.3),
        1 => int(Field::SSET, 1..=1),
        2 => int(Field::SUSE, 1..=1),
        1 => int(Field::NTM, 0..=1),
        8 => (0.01f64..3.0).prop_map(Op::Wait),
    ]
}

fn new_axis() -> Axis {
    let fields = Fields {
        mres: MRES,
        velo: 10.0,
        accl: 0.2,
        dhlm: LIMIT,
        dllm: -LIMIT,
        jvel: 10.0,
        jar: 100.0,
        hvel: 10.0,
        bvel: 5.0,
        ..Fields::default()
    };
    let sim = SimConfig {
        high_limit_switch: Some(110.0 / MRES),
        low_limit_switch: Some(-110.0 / MRES),
        encoder_counts_per_step: Some(1.0),
        ..SimConfig::default()
    };
    // Completion is event-driven, so a slow poll only thins the readback.
    Axis::new(
        fields,
        Box::new(SimAxis::new(sim)),
        PollRates { moving: Duration::from_millis(500), idle: Duration::from_secs(5) },
        Instant::ZERO,
    )
}

/// Distance of a raw position outside the soft limits (0 inside).
fn outside(steps: f64) -> f64 {
    let (lo, hi) = (-LIMIT / MRES, LIMIT / MRES);
    (lo - steps).max(steps - hi).max(0.0)
}

/// Check every move leg just issued; the carriage has not moved since (no time passed).
fn check_moves(axis: &mut Axis) -> Result<(), TestCaseError> {
    let events: Vec<AxisEvent> = axis.drain_events().collect();
    let here = axis.simulation().expect("simulated").status().position;
    for event in events {
        if let AxisEvent::Driver { command: DriverCommand::Move { position, relative, .. }, .. } = event {
            let end = if relative { here + position } else { position };
            // One step of slack: readbacks are whole steps while a set-position may leave the
            // controller's counter between two.
            prop_assert!(
                outside(end) <= outside(here) + 1.0,
                "a move from {here} to {end} steps ends beyond the soft limits (±{} steps)",
                LIMIT / MRES
            );
        }
    }
    Ok(())
}

/// VAL = DVAL·dirsign + OFF, DIFF = DVAL − DRBV and RDIF = NINT(DIFF/MRES) whenever the axis
/// is idle: every derived field agrees with its sources, after any refusal too.
fn check_idle_coordinates(axis: &Axis) -> Result<(), TestCaseError> {
    let f = axis.fields();
    if f.dmov == 1 && f.mip == 0 {
        let diff = f.dval - f.drbv;
        prop_assert!(
            (f.diff - diff).abs() <= 1e-9 * (1.0 + diff.abs()),
            "idle DIFF {} ≠ DVAL − DRBV = {}",
            f.diff,
            diff
        );
        prop_assert_eq!(f.rdif, zmotor_core::nint(f.diff / f.mres), "idle RDIF ≠ NINT(DIFF/MRES)");
        let dirsign = if f.dir == 0 { 1.0 } else { -1.0 };
        let expected = f.dval * dirsign + f.off;
        prop_assert!(
            (f.val - expected).abs() <= 1e-9 * (1.0 + expected.abs()),
            "idle VAL {} ≠ DVAL·dirsign + OFF = {}",
            f.val,
            expected
        );
    }
    Ok(())
}

/// Advance virtual time by `seconds`, tick by tick, checking every leg.
fn wait(axis: &mut Axis, seconds: f64) -> Result<(), TestCaseError> {
    let end = axis.now() + Duration::from_secs_f64(seconds);
    for _ in 0..100_000 {
        let t = axis.poll_timeout().map_or(end, |t| t.min(end));
        axis.handle_timeout(t);
        check_moves(axis)?;
        if t >= end {
            return Ok(());
        }
    }
    Err(TestCaseError::fail("time did not advance"))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn any_sequence_of_writes_keeps_the_axis_safe_and_consistent(ops in proptest::collection::vec(op(), 1..40)) {
        let mut axis = new_axis();
        check_moves(&mut axis)?;
        for op in ops {
            match op {
                Op::Write(field, value) => {
                    let now = axis.now();
                    let _ = axis.write(now, field, &value);
                    check_moves(&mut axis)?;
                }
                Op::Wait(seconds) => wait(&mut axis, seconds)?,
            }
            check_idle_coordinates(&axis)?;
        }
        // Release every hold; the simulator can reach any target inside its switches.
        for (field, value) in [(Field::JOGF, 0), (Field::JOGR, 0), (Field::SPMG, 3)] {
            let now = axis.now();
            let _ = axis.write(now, field, &Value::Int(value));
            check_moves(&mut axis)?;
        }
        for _ in 0..400 {
            if !axis.is_busy() {
                break;
            }
            wait(&mut axis, 50.0)?;
        }
        let f = axis.fields();
        prop_assert_eq!((f.dmov, f.movn), (1, 0), "still busy: MIP {:#x}", f.mip);
        check_idle_coordinates(&axis)?;
    }
}
