//! The lecture's configuration (baseline K: VELO 10, ACCL 1, BVEL 2, BACC 1.5, BDST 24, MRES 1)
//! with moves among 48, 72 and 96: backlash with and without FRAC, absolute and relative,
//! forward and reverse; jogs with backlash; retries in each RMOD.

use super::*;

const BACC_STEPS: f64 = 4.0 / 3.0;

fn slew(p: f64) -> Vec<MotorCommand> {
    move_abs(10.0, 0.0, 10.0, p)
}

fn approach(p: f64) -> Vec<MotorCommand> {
    vec![SetVelocity(2.0), SetAccel(BACC_STEPS), MoveAbs(p), Go]
}

fn single_approach(p: f64) -> Vec<MotorCommand> {
    vec![SetVelocity(2.0), SetVelBase(0.0), SetAccel(BACC_STEPS), MoveAbs(p), Go]
}

fn rel(velocity: f64, base: bool, p: f64) -> Vec<MotorCommand> {
    let accel = if velocity == 10.0 { 10.0 } else { BACC_STEPS };
    let mut cmds = vec![SetVelocity(velocity)];
    if base {
        cmds.push(SetVelBase(0.0));
    }
    cmds.extend([SetAccel(accel), MoveRel(p), Go]);
    cmds
}

fn encoder_k() -> Fields {
    Fields { ueip: 1, eres: 1.0, ..baseline_k() }
}

#[test]
fn forward_moves_within_the_backlash_distance_are_single_approaches() {
    let mut rig = Rig::boot(baseline_k(), 48.0);
    for target in [72.0, 96.0] {
        rig.put(Field::VAL, target).unwrap();
        assert_cmds_close(&rig.take(), &single_approach(target));
        rig.cb(target);
        assert_eq!((rig.f().dmov, rig.f().rbv), (1, target));
    }
}

#[test]
fn reverse_moves_overshoot_by_bdst_then_approach() {
    let mut rig = Rig::boot(baseline_k(), 96.0);
    for (target, start) in [(72.0, 48.0), (48.0, 24.0)] {
        rig.put(Field::VAL, target).unwrap();
        assert_eq!(rig.take(), slew(start));
        assert_eq!(rig.f().cdir, 0);
        rig.cb(start);
        assert_cmds_close(&rig.take(), &approach(target));
        assert_eq!((rig.f().cdir, rig.f().mip), (1, mip::MOVE_BL));
        rig.cb(target);
        assert_eq!(rig.f().dmov, 1);
    }
}

#[test]
fn a_long_forward_move_goes_to_the_backlash_start_first() {
    let mut rig = Rig::boot(baseline_k(), 48.0);
    rig.put(Field::VAL, 96.0).unwrap();
    assert_eq!(rig.take(), slew(72.0));
    rig.cb(72.0);
    assert_cmds_close(&rig.take(), &approach(96.0));
    rig.cb(96.0);
    assert_eq!(rig.f().dmov, 1);
}

#[test]
fn frac_on_an_absolute_backlash_move_never_converges_and_runs_out_of_retries() {
    let mut rig = Rig::boot(Fields { frac: 0.5, rtry: 2, ..baseline_k() }, 48.0);
    rig.put(Field::VAL, 96.0).unwrap();
    assert_eq!(rig.take(), slew(72.0));
    for rcnt in 0..=2 {
        if rcnt > 0 {
            assert_eq!(rig.take(), slew(72.0), "retry {rcnt} repeats the backlash start");
        }
        rig.cb(72.0);
        assert_cmds_close(&rig.take(), &approach(84.0));
        assert_eq!(rig.f().rval, 84, "RVAL shows the fractional leg (Q20)");
        rig.cb(84.0);
    }
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().rcnt, rig.f().miss, rig.f().dmov), (3, 1, 1));
}

#[test]
fn frac_on_a_reverse_move_shortens_the_final_approach() {
    let mut rig = Rig::boot(Fields { frac: 0.5, rtry: 0, ..baseline_k() }, 96.0);
    rig.put(Field::VAL, 48.0).unwrap();
    assert_eq!(rig.take(), slew(24.0));
    rig.cb(24.0);
    assert_cmds_close(&rig.take(), &approach(36.0));
    rig.cb(36.0);
    assert_eq!((rig.f().dmov, rig.f().miss, rig.f().diff), (1, 0, 12.0));
}

#[test]
fn relative_moves_forward_and_reverse() {
    let mut rig = Rig::boot_encoder(encoder_k(), 48.0, 48.0);
    rig.put(Field::VAL, 96.0).unwrap();
    assert_cmds_close(&rig.take(), &rel(10.0, true, 24.0));
    rig.cb_encoder(72.0, 72.0);
    assert_cmds_close(&rig.take(), &rel(2.0, false, 24.0));
    rig.cb_encoder(96.0, 96.0);
    assert_eq!(rig.f().dmov, 1);
    rig.put(Field::VAL, 48.0).unwrap();
    assert_cmds_close(&rig.take(), &rel(10.0, true, -72.0));
    assert_eq!(rig.f().cdir, 0);
    rig.cb_encoder(24.0, 24.0);
    assert_cmds_close(&rig.take(), &rel(2.0, false, 24.0));
    rig.cb_encoder(48.0, 48.0);
    assert_eq!(rig.f().dmov, 1);
}

#[test]
fn relative_moves_with_frac_converge_by_retries() {
    let mut rig = Rig::boot_encoder(Fields { frac: 0.5, ..encoder_k() }, 48.0, 48.0);
    rig.put(Field::VAL, 96.0).unwrap();
    assert_cmds_close(&rig.take(), &rel(10.0, true, 24.0));
    rig.cb_encoder(72.0, 72.0);
    assert_cmds_close(&rig.take(), &rel(2.0, false, 12.0));
    rig.cb_encoder(84.0, 84.0);
    // Retry: preferred and within the backlash range ⇒ one approach at BVEL, FRAC of DIFF.
    assert_cmds_close(&rig.take(), &rel(2.0, true, 6.0));
    rig.cb_encoder(90.0, 90.0);
    assert_cmds_close(&rig.take(), &rel(2.0, true, 3.0));
    assert_eq!(rig.f().rcnt, 2);
}

#[test]
fn jog_forward_with_backlash() {
    let mut rig = Rig::boot(baseline_k(), 0.0);
    assert_eq!((rig.f().jvel, rig.f().jar), (10.0, 10.0));
    rig.put(Field::JOGF, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelBase(0.0), SetAccel(10.0), Jog(10.0)]);
    rig.cb_moving(40.0);
    rig.put(Field::JOGF, 0.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    rig.cb(60.0);
    assert_eq!(rig.take(), slew(36.0));
    assert_eq!((rig.f().val, rig.f().mip, rig.f().cdir), (60.0, mip::JOG_BL1, 0));
    rig.cb(36.0);
    assert_cmds_close(&rig.take(), &approach(60.0));
    assert_eq!(rig.f().mip, mip::JOG_BL2);
    rig.cb(60.0);
    assert_eq!((rig.f().mip, rig.f().dmov), (0, 1));
}

#[test]
fn jog_reverse_with_backlash_approaches_from_below() {
    let mut rig = Rig::boot(baseline_k(), 96.0);
    rig.put(Field::JOGR, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelBase(0.0), SetAccel(10.0), Jog(-10.0)]);
    rig.put(Field::JOGR, 0.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    rig.cb(30.0);
    assert_eq!(rig.take(), slew(6.0));
    rig.cb(6.0);
    assert_cmds_close(&rig.take(), &approach(30.0));
    rig.cb(30.0);
    assert_eq!((rig.f().val, rig.f().dmov), (30.0, 1));
}

#[test]
fn absolute_retries_ignore_rmod_scaling() {
    for rmod in [0, 1, 2] {
        let mut rig = Rig::boot(Fields { rmod, ..baseline_k() }, 48.0);
        rig.put(Field::VAL, 60.0).unwrap();
        assert_cmds_close(&rig.take(), &single_approach(60.0));
        rig.cb(55.0);
        assert_eq!(rig.take(), slew(36.0), "rmod {rmod}");
        rig.cb(36.0);
        assert_cmds_close(&rig.take(), &approach(60.0));
        rig.cb(60.0);
        assert_eq!((rig.f().dmov, rig.f().rcnt), (1, 1));
    }
}

#[test]
fn in_position_retries_wait_for_the_readback() {
    let mut rig = Rig::boot(Fields { rmod: 3, dly: 0.1, ..baseline_k() }, 48.0);
    rig.put(Field::VAL, 60.0).unwrap();
    rig.take();
    rig.cb(55.0);
    rig.timer();
    assert_eq!(rig.take(), vec![GetInfo]);
    rig.cb(55.0);
    assert!(rig.take().is_empty(), "In-Position retries send nothing");
    assert_eq!((rig.f().rcnt, rig.f().mip), (1, mip::RETRY | mip::DELAY_REQ));
    rig.timer();
    rig.cb(60.0);
    assert_eq!((rig.f().dmov, rig.f().rcnt), (1, 1));
}

#[test]
fn relative_retries_scale_with_rmod() {
    for (rmod, distances) in [(0, [8.0, 8.0]), (1, [8.0, 6.0]), (2, [8.0, 4.0])] {
        let mut rig = Rig::boot_encoder(Fields { rmod, rtry: 4, ..encoder_k() }, 48.0, 48.0);
        rig.put(Field::VAL, 60.0).unwrap();
        assert_cmds_close(&rig.take(), &rel(2.0, true, 12.0));
        for d in distances {
            rig.cb_encoder(60.0, 52.0);
            assert_cmds_close(&rig.take(), &rel(2.0, true, d));
        }
    }
}
