//! What a client sees, and when: the order of the posts of one processing (spec §13, as the
//! record posts them), the end of a motion reported when the motion ends (not at the next
//! readback poll), and the simulator's direction and home bits as motorSim reports them. All in
//! virtual time on the physical simulator.

use std::time::Duration;
use zmotor_core::{Axis, AxisEvent, Instant, PollRates, SimAxis, SimConfig};
use zmotor_msgs::{Field, Fields, Value};

/// The demo's stage (launch/sim-axis.toml): 1 µm steps, 10 mm/s, 0.2 s ramps, ±100 mm.
fn stage() -> Fields {
    Fields { mres: 0.001, velo: 10.0, accl: 0.2, dhlm: 100.0, dllm: -100.0, ..Fields::default() }
}

fn axis_with(fields: Fields, rates: PollRates) -> Axis {
    let sim =
        SimConfig { high_limit_switch: Some(105_000.0), low_limit_switch: Some(-105_000.0), ..SimConfig::default() };
    let mut axis = Axis::new(fields, Box::new(SimAxis::new(sim)), rates, Instant::ZERO);
    axis.drain_events().count();
    axis
}

fn axis(fields: Fields) -> Axis {
    axis_with(fields, PollRates::default())
}

/// One processing's worth of posts, in order (or several, when the caller runs time).
type Posts = Vec<(Field, Value)>;

fn posts(axis: &mut Axis) -> Posts {
    axis.drain_events().filter_map(|e| if let AxisEvent::Post(f, v) = e { Some((f, v)) } else { None }).collect()
}

/// Run virtual time until the axis is idle; every post on the way, and when DMOV went 1.
fn run(axis: &mut Axis) -> (Posts, Option<Instant>) {
    let (mut all, mut done_at) = (Vec::new(), None);
    for _ in 0..100_000 {
        let batch = posts(axis);
        if batch.contains(&(Field::DMOV, Value::Int(1))) {
            done_at.get_or_insert(axis.now());
        }
        all.extend(batch);
        if !axis.is_busy() {
            break;
        }
        let t = axis.poll_timeout().expect("a simulated axis is polled");
        axis.handle_timeout(t);
    }
    (all, done_at)
}

/// The posts of `wanted` fields, in order.
fn only(posts: &Posts, wanted: &[Field]) -> Posts {
    posts.iter().filter(|(f, _)| wanted.contains(f)).cloned().collect()
}

fn int(field: Field, v: i64) -> (Field, Value) {
    (field, Value::Int(v))
}

#[test]
fn the_end_of_a_move_posts_mip_movn_then_dmov_and_dmov_is_last() {
    let mut axis = axis(stage());
    axis.write(Instant::ZERO, Field::VAL, &Value::Float(1.0)).unwrap();
    let (all, _) = run(&mut axis);
    let ending = only(&all, &[Field::MIP, Field::MOVN, Field::DMOV]);
    assert_eq!(ending[ending.len() - 3..], [int(Field::MIP, 0), int(Field::MOVN, 0), int(Field::DMOV, 1)]);
    assert_eq!(all.last(), Some(&int(Field::DMOV, 1)), "DMOV 1 is the last post of the motion: {all:?}");
}

#[test]
fn a_backlash_leg_boundary_posts_mip_then_movn() {
    let mut axis = axis(Fields { bdst: 0.5, bvel: 5.0, ..stage() });
    axis.write(Instant::ZERO, Field::VAL, &Value::Float(5.0)).unwrap();
    let (all, _) = run(&mut axis);
    let legs = only(&all, &[Field::MIP, Field::MOVN]);
    let boundary = legs.iter().position(|p| *p == int(Field::MIP, 256)).expect("a MOVE_BL leg");
    assert_eq!(legs[boundary..boundary + 3], [int(Field::MIP, 256), int(Field::MOVN, 0), int(Field::MOVN, 1)]);
}

#[test]
fn a_refused_move_posts_lvio_before_dmov() {
    let mut axis = axis(stage());
    assert!(axis.write(Instant::ZERO, Field::VAL, &Value::Float(500.0)).is_err());
    let refused = only(&posts(&mut axis), &[Field::LVIO, Field::DMOV]);
    assert_eq!(refused, [int(Field::DMOV, 0), int(Field::LVIO, 1), int(Field::DMOV, 1)]);
}

#[test]
fn a_jog_and_a_home_post_mip_before_dmov() {
    let mut axis = axis(Fields { hvel: 5.0, ..stage() });
    axis.write(Instant::ZERO, Field::JOGF, &Value::Int(1)).unwrap();
    assert_eq!(only(&posts(&mut axis), &[Field::MIP, Field::DMOV]), [int(Field::MIP, 1), int(Field::DMOV, 0)]);
    axis.write(Instant::from_secs_f64(0.5), Field::JOGF, &Value::Int(0)).unwrap();
    run(&mut axis);
    axis.write(axis.now(), Field::HOMF, &Value::Int(1)).unwrap();
    let home = only(&posts(&mut axis), &[Field::MIP, Field::RCNT, Field::DMOV]);
    assert_eq!(home, [int(Field::MIP, 8), int(Field::RCNT, 0), int(Field::DMOV, 0)]);
}

#[test]
fn a_direction_change_posts_the_user_limits_then_the_offset() {
    let mut axis = axis(stage());
    axis.write(Instant::ZERO, Field::DIR, &Value::Int(1)).unwrap();
    let posted: Vec<Field> = posts(&mut axis).into_iter().map(|(f, _)| f).collect();
    let order: Vec<Field> = posted.into_iter().filter(|f| matches!(f, Field::HLM | Field::LLM | Field::OFF)).collect();
    assert_eq!(order, [Field::HLM, Field::LLM, Field::OFF]);
}

#[test]
fn the_limit_switch_posts_carry_the_raw_switch_with_them() {
    let mut axis = axis(Fields { dhlm: 0.0, dllm: 0.0, jvel: 50.0, ..stage() });
    axis.write(Instant::ZERO, Field::JOGF, &Value::Int(1)).unwrap();
    let (all, _) = run(&mut axis);
    let switches = only(&all, &[Field::HLS, Field::RHLS]);
    assert_eq!(switches, [int(Field::HLS, 1), int(Field::RHLS, 1)]);
}

#[test]
fn dmov_1_follows_the_end_of_motion_whatever_the_readback_rate() {
    for readback_hz in [10.0, 3.0, 0.5] {
        let rates = PollRates { moving: Duration::from_secs_f64(1.0 / readback_hz), idle: Duration::from_secs(1) };
        let mut axis = axis_with(stage(), rates);
        // 0.01 mm: a triangular move of 2·√(10 steps / 50,000 steps/s²) ≈ 28.3 ms.
        axis.write(Instant::ZERO, Field::VAL, &Value::Float(0.01)).unwrap();
        let (_, done_at) = run(&mut axis);
        let motion = 2.0 * (10.0f64 / 50_000.0).sqrt();
        let done_at = done_at.expect("DMOV 1").as_secs_f64();
        assert!((done_at - motion).abs() < 1e-6, "{readback_hz} Hz: DMOV 1 at {done_at} s, motion ends at {motion} s");
    }
}

#[test]
fn a_target_held_by_pause_is_posted_once() {
    let mut axis = axis(stage());
    axis.write(Instant::ZERO, Field::SPMG, &Value::Int(1)).unwrap();
    axis.write(Instant::ZERO, Field::VAL, &Value::Float(5.0)).unwrap();
    let mut all = posts(&mut axis);
    // Three seconds of polls while the target waits.
    while axis.now() < Instant::from_secs_f64(3.0) {
        let t = axis.poll_timeout().expect("polled");
        axis.handle_timeout(t);
        all.extend(posts(&mut axis));
    }
    assert_eq!(only(&all, &[Field::DVAL]), [(Field::DVAL, Value::Float(5.0))]);
    assert_eq!(axis.fields().dmov, 0, "still held");
}

#[test]
fn the_simulator_reports_direction_only_while_moving_and_no_home_after_a_home_search() {
    let mut axis = axis(Fields { hvel: 5.0, ..stage() });
    assert_eq!((axis.fields().tdir, axis.fields().athm), (0, 1), "at power-up, at rest on the home position");
    axis.write(Instant::ZERO, Field::VAL, &Value::Float(2.0)).unwrap();
    let (all, _) = run(&mut axis);
    assert_eq!(only(&all, &[Field::TDIR]), [int(Field::TDIR, 1), int(Field::TDIR, 0)]);
    assert_eq!((axis.fields().tdir, axis.fields().athm), (0, 0));
    axis.write(axis.now(), Field::HOMR, &Value::Int(1)).unwrap();
    run(&mut axis);
    let f = axis.fields();
    assert_eq!((f.rbv, f.dmov, f.athm, f.tdir), (0.0, 1, 0, 0), "ATHM 0 after a home, as with motorSim");
    axis.write(axis.now(), Field::VAL, &Value::Float(1.0)).unwrap();
    run(&mut axis);
    axis.write(axis.now(), Field::VAL, &Value::Float(0.0)).unwrap();
    run(&mut axis);
    assert_eq!(axis.fields().athm, 1, "a move onto the home position lands on it");
}
