//! Further worked scenarios of spec §19 and the field behaviours of §7, one test each.

use super::*;

fn encoder_b() -> Fields {
    Fields { ueip: 1, eres: 0.01, rdbd: 0.02, ..baseline_b() }
}

/// Moves of an encoder axis: the driver steps to `steps` but the encoder reads `counts`.
fn retries_from(rig: &mut Rig, steps: f64, counts: f64) -> Vec<MotorCommand> {
    rig.cb_encoder(steps, counts);
    rig.take()
}

fn move_rel(p: f64) -> Vec<MotorCommand> {
    vec![SetVelocity(100.0), SetVelBase(0.0), SetAccel(200.0), MoveRel(p), Go]
}

#[test]
fn w18_arithmetic_retries() {
    let mut rig = Rig::boot_encoder(Fields { rtry: 4, rmod: 1, ..encoder_b() }, 0.0, 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    assert_eq!(rig.take(), move_rel(100.0));
    for (rcnt, dist) in [(1, 8.0), (2, 6.0), (3, 4.0), (4, 2.0)] {
        assert_cmds_close(&retries_from(&mut rig, 100.0, 92.0), &move_rel(dist));
        assert_eq!(rig.f().rcnt, rcnt);
    }
    assert!(retries_from(&mut rig, 100.0, 92.0).is_empty());
    assert_eq!((rig.f().rcnt, rig.f().miss, rig.f().dmov), (5, 1, 1));
}

#[test]
fn w19_geometric_retries() {
    let mut rig = Rig::boot_encoder(Fields { rtry: 4, rmod: 2, ..encoder_b() }, 0.0, 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    rig.take();
    for dist in [8.0, 4.0, 2.0, 1.0] {
        assert_cmds_close(&retries_from(&mut rig, 100.0, 92.0), &move_rel(dist));
    }
    assert!(retries_from(&mut rig, 100.0, 92.0).is_empty());
    assert_eq!((rig.f().rcnt, rig.f().miss), (5, 1));
}

#[test]
fn w20_in_position_retries_wait_without_moving() {
    let mut rig = Rig::boot_encoder(Fields { rmod: 3, dly: 0.5, rtry: 3, ..encoder_b() }, 0.0, 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 100.0));
    rig.cb_encoder(100.0, 95.0);
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().mip, rig.f().dmov, rig.delays.clone()), (0x420, 0, vec![0.5]));
    rig.timer();
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!(rig.f().mip, 0xC20);
    rig.cb_encoder(100.0, 96.0);
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().rcnt, rig.f().mip, rig.delays.clone()), (1, 0x440, vec![0.5]));
    rig.timer();
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!(rig.f().mip, 0xC40);
    rig.cb_encoder(100.0, 99.0);
    assert_eq!((rig.f().mip, rig.f().dmov, rig.f().rcnt), (0, 1, 1));
}

#[test]
fn w22_frac_relative_converges_geometrically() {
    let mut rig = Rig::boot_encoder(Fields { frac: 0.5, ..encoder_b() }, 0.0, 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    assert_cmds_close(&rig.take(), &move_rel(50.0));
    for (counts, dist) in [(50.0, 25.0), (75.0, 12.5), (88.0, 6.0), (94.0, 3.0), (97.0, 1.5), (98.0, 1.0)] {
        assert_cmds_close(&retries_from(&mut rig, 0.0, counts), &move_rel(dist));
    }
    assert_eq!(rig.f().rcnt, 6);
    assert!(retries_from(&mut rig, 0.0, 99.0).is_empty());
    assert_eq!(rig.f().dmov, 1);
}

#[test]
fn w23_relative_backlash() {
    let fields = Fields { bdst: 0.5, ..encoder_b() };
    let mut rig = Rig::boot_encoder(fields.clone(), 0.0, 0.0);
    rig.put(Field::VAL, 2.0).unwrap();
    assert_cmds_close(&rig.take(), &move_rel(150.0));
    assert_cmds_close(&retries_from(&mut rig, 0.0, 150.0), &[SetVelocity(50.0), SetAccel(100.0), MoveRel(50.0), Go]);
    assert_eq!(rig.f().mip, mip::MOVE_BL);
    assert!(retries_from(&mut rig, 0.0, 200.0).is_empty());
    assert_eq!(rig.f().dmov, 1);
    rig.put(Field::VAL, 2.3).unwrap();
    assert_cmds_close(&rig.take(), &[SetVelocity(50.0), SetVelBase(0.0), SetAccel(100.0), MoveRel(30.0), Go]);

    let mut rig = Rig::boot_encoder(Fields { bdst: -0.5, ..fields }, 0.0, 200.0);
    rig.put(Field::VAL, 1.0).unwrap();
    assert_cmds_close(&rig.take(), &move_rel(-50.0));
    assert_eq!(rig.f().cdir, 0);
    assert_cmds_close(&retries_from(&mut rig, 0.0, 150.0), &[SetVelocity(50.0), SetAccel(100.0), MoveRel(-50.0), Go]);
    retries_from(&mut rig, 0.0, 100.0);
    rig.put(Field::VAL, 0.7).unwrap();
    assert_cmds_close(&rig.take(), &[SetVelocity(50.0), SetVelBase(0.0), SetAccel(100.0), MoveRel(-30.0), Go]);
}

#[test]
fn w26_jog_reverse_without_backlash() {
    let mut rig = Rig::boot(Fields { jvel: 2.0, jar: 4.0, ..baseline_b() }, 0.0);
    rig.put(Field::JOGR, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelBase(0.0), SetAccel(400.0), Jog(-200.0)]);
    assert_eq!(rig.f().cdir, 0);
    rig.put(Field::JOGR, 0.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!(rig.f().mip, mip::JOG_STOP);
    rig.cb(-210.0);
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().val, rig.f().dval, rig.f().mip, rig.f().dmov), (-2.1, -2.1, 0, 1));
}

#[test]
fn w27b_releasing_a_refused_jog_then_moving() {
    let mut rig = Rig::boot(Fields { jvel: 2.0, jar: 4.0, dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 850.0);
    assert!(rig.put(Field::JOGF, 1.0).is_err());
    rig.put(Field::JOGF, 0.0).unwrap();
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!((rig.f().mip, rig.f().stup), (0, 2));
    rig.cb(850.0);
    rig.put(Field::VAL, 5.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 500.0));
    assert_eq!(rig.f().lvio, 0);
}

#[test]
fn w28_jog_into_the_soft_limit_zone_stops_without_backlash() {
    let mut rig = Rig::boot(Fields { jvel: 2.0, jar: 4.0, bdst: 0.5, dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 0.0);
    rig.put(Field::JOGF, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelBase(0.0), SetAccel(400.0), Jog(200.0)]);
    rig.cb_moving(700.0);
    assert!(rig.take().is_empty());
    rig.cb_moving(801.0);
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().lvio, rig.f().stop, rig.f().jogf, rig.f().mip), (1, 0, 0, mip::STOP));
    rig.cb(830.0);
    assert!(rig.take().is_empty(), "no backlash after a soft-limit stop");
    assert_eq!((rig.f().val, rig.f().dval, rig.f().mip, rig.f().dmov, rig.f().lvio), (8.3, 8.3, 0, 1, 1));
}

#[test]
fn w29_jog_onto_the_plus_limit_switch() {
    let mut rig = Rig::boot(Fields { jvel: 2.0, bdst: 0.5, ..baseline_b() }, 0.0);
    rig.put(Field::JOGF, 1.0).unwrap();
    rig.take();
    rig.status(DeviceStatus { msta: msta::DIRECTION | msta::PLUS_LS, ..moving(500.0) });
    assert!(rig.take().is_empty());
    let f = rig.f();
    assert_eq!((f.movn, f.jogf, f.mip, f.val, f.dval, f.hls, f.dmov), (0, 0, 0, 5.0, 5.0, 1, 1));
    // A jog towards the active switch is not even requested.
    rig.put(Field::JOGF, 1.0).unwrap();
    assert_eq!(rig.f().mip, 0);
}

#[test]
fn w31_home_forward() {
    let mut rig = Rig::boot(Fields { vbas: 0.1, hvel: 0.5, ..baseline_b() }, 123.0);
    rig.put(Field::HOMF, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelocity(50.0), SetVelBase(10.0), SetAccel(80.0), HomeFor, Go]);
    assert_eq!((rig.f().mip, rig.f().dmov, rig.f().cdir, rig.f().rcnt), (mip::HOMF, 0, 1, 0));
    assert!(matches!(rig.put(Field::HOMF, 1.0), Err(WriteError::Refused { .. })));
    rig.cb_moving(50.0);
    assert!(rig.take().is_empty());
    rig.cb(0.0);
    assert!(rig.take().is_empty(), "no retry, no backlash after a home");
    let f = rig.f();
    assert_eq!((f.val, f.dval, f.homf, f.mip, f.dmov, f.lvio), (0.0, 0.0, 0, 0, 1, 0));
    assert_eq!(rig.posted(Field::HOMF), vec![Value::Int(0)]);
}

#[test]
fn w32_home_reverse_with_negative_mres_homes_raw_forward() {
    let mut rig = Rig::boot(Fields { mres: -0.01, vbas: 0.1, hvel: 0.5, ..baseline_b() }, 0.0);
    rig.put(Field::HOMR, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelocity(50.0), SetVelBase(10.0), SetAccel(80.0), HomeFor, Go]);
    assert_eq!((rig.f().mip, rig.f().cdir), (mip::HOMR, 1));
}

#[test]
fn w33_home_while_moving_stops_first() {
    let mut rig = Rig::boot(Fields { hvel: 0.5, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 5.0).unwrap();
    rig.cb_moving(100.0);
    rig.put(Field::HOMF, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!(rig.f().mip, mip::HOMF | mip::STOP);
    rig.cb(120.0);
    assert_eq!(rig.take(), vec![SetVelocity(50.0), SetVelBase(0.0), SetAccel(100.0), HomeFor, Go]);
    assert_eq!((rig.f().mip, rig.f().val, rig.f().dmov), (mip::HOMF, 1.2, 0));
    rig.cb(0.0);
    assert_eq!((rig.f().val, rig.f().homf, rig.f().dmov), (0.0, 0, 1));
}

#[test]
fn w40_ntm_no_completes_then_retries_to_the_new_target() {
    let mut rig = Rig::boot(Fields { ntm: 0, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 10.0).unwrap();
    rig.cb_moving(500.0);
    rig.put(Field::VAL, 2.0).unwrap();
    rig.cb_moving(510.0);
    assert!(rig.take().is_empty());
    rig.cb(1000.0);
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 200.0));
    assert_eq!(rig.f().rcnt, 1);
}

#[test]
fn w42_w43_new_targets_in_the_same_direction() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 10.0).unwrap();
    rig.cb_moving(300.0);
    rig.put(Field::VAL, 15.0).unwrap();
    rig.cb_moving(400.0);
    assert!(rig.take().is_empty(), "further along: no stop");
    rig.cb(1000.0);
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 1500.0));
    assert_eq!((rig.f().rcnt, rig.f().mip), (1, mip::RETRY | mip::MOVE));

    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 10.0).unwrap();
    rig.cb_moving(500.0);
    rig.put(Field::VAL, 6.0).unwrap();
    rig.cb_moving(590.0);
    assert!(rig.take().is_empty(), "target still ahead");
    rig.cb_moving(605.0);
    assert_eq!(rig.take(), vec![StopAxis]);
    rig.cb(650.0);
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 600.0));
    assert_eq!((rig.f().cdir, rig.f().rcnt), (0, 1));
}

#[test]
fn w46_set_mode_dial_write_loads_the_position() {
    let mut rig = Rig::boot(Fields { off: 3.0, dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 200.0);
    rig.put(Field::SSET, 1.0).unwrap();
    rig.put(Field::DVAL, 7.0).unwrap();
    assert_eq!(rig.take(), vec![LoadPos(700.0), GetInfo]);
    let f = rig.f();
    assert_eq!((f.off, f.hlm, f.llm, f.val, f.rval, f.mip, f.dmov), (-2.0, 8.0, -12.0, 5.0, 700, mip::LOAD_P, 0));
    rig.cb(700.0);
    let f = rig.f();
    assert_eq!((f.drbv, f.rbv, f.mip, f.dmov), (7.0, 5.0, 0, 1));
    rig.put(Field::SUSE, 1.0).unwrap();
    assert_eq!(rig.f().set, 0);
}

#[test]
fn w47_set_mode_with_frozen_offset() {
    let mut rig = Rig::boot(Fields { off: 3.0, ..baseline_b() }, 200.0);
    rig.put(Field::SSET, 1.0).unwrap();
    rig.put(Field::FOF, 1.0).unwrap();
    assert_eq!(rig.f().foff, 1);
    rig.put(Field::VAL, 6.0).unwrap();
    assert_eq!(rig.take(), vec![LoadPos(300.0), GetInfo]);
    assert_eq!((rig.f().dval, rig.f().off), (3.0, 3.0));
    rig.cb(300.0);
    assert_eq!((rig.f().rbv, rig.f().dmov), (6.0, 1));
    rig.put(Field::VOF, 1.0).unwrap();
    assert_eq!(rig.f().foff, 0);
}

#[test]
fn w49_mres_change_in_set_mode_recomputes_the_position() {
    let mut rig = Rig::boot(baseline_b(), 100.0);
    rig.put(Field::SSET, 1.0).unwrap();
    rig.put(Field::MRES, 0.02).unwrap();
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!(rig.f().pp, 1);
    rig.cb(100.0);
    assert_eq!((rig.f().val, rig.f().dval, rig.f().drbv), (2.0, 2.0, 2.0));
}

#[test]
fn encoder_ratio_is_sent_when_the_resolution_changes_with_an_encoder() {
    let mut rig = Rig::boot_encoder(Fields { eres: 0.005, ..baseline_b() }, 0.0, 0.0);
    rig.put(Field::ERES, 0.002).unwrap();
    assert_eq!(rig.take(), vec![SetEncRatio(500_000.0, 100_000.0), LoadPos(0.0), GetInfo]);
}

#[test]
fn ueip_and_urip_are_mutually_exclusive() {
    let mut rig = Rig::boot_encoder(baseline_b(), 0.0, 0.0);
    rig.put(Field::UEIP, 1.0).unwrap();
    rig.put(Field::URIP, 1.0).unwrap();
    assert_eq!((rig.f().urip, rig.f().ueip), (1, 0));
    rig.put(Field::UEIP, 1.0).unwrap();
    assert_eq!((rig.f().urip, rig.f().ueip), (0, 1));
    assert_eq!(rig.posted(Field::URIP), vec![Value::Int(0)]);
}

#[test]
fn jog_velocity_changes_on_the_fly() {
    let mut rig = Rig::boot(Fields { jvel: 2.0, jar: 4.0, vmax: 5.0, ..baseline_b() }, 0.0);
    rig.put(Field::JOGF, 1.0).unwrap();
    rig.take();
    rig.put(Field::JVEL, 3.0).unwrap();
    assert_eq!(rig.take(), vec![SetAccel(400.0), JogVelocity(300.0)]);
    rig.put(Field::JVEL, 9.0).unwrap();
    assert_eq!(rig.f().jvel, 5.0, "clamped to VMAX");
    rig.put(Field::JAR, -1.0).unwrap();
    assert_eq!(rig.f().jar, 50.0);
    // The record does not post its correction; the write's own post carries the stored value.
    assert_eq!(rig.posted(Field::JAR), vec![Value::Float(50.0)]);
}

#[test]
fn jog_with_negative_direction_and_resolution() {
    let mut rig = Rig::boot(Fields { dir: 1, mres: -0.01, jvel: 2.0, jar: 4.0, ..baseline_b() }, 0.0);
    rig.put(Field::JOGF, 1.0).unwrap();
    // User forward, dial reverse, raw forward: JVEL·dirsign/MRES = 2·(−1)/(−0.01).
    assert_eq!(rig.take(), vec![SetVelBase(0.0), SetAccel(400.0), Jog(200.0)]);
    assert_eq!(rig.f().cdir, 1);
}

#[test]
fn speed_pairs_and_ranges_of_backlash_home_and_acceleration() {
    let mut rig = Rig::boot(Fields { vbas: 0.2, vmax: 2.0, ..baseline_b() }, 0.0);
    rig.put(Field::SBAK, 2.0).unwrap();
    assert_eq!((rig.f().sbak, rig.f().bvel), (1.0, 2.0), "SBAK clamped to SMAX");
    rig.put(Field::BVEL, 0.1).unwrap();
    assert!(approx(rig.f().bvel, 0.2) && approx(rig.f().sbak, 0.1));
    rig.put(Field::HVEL, 7.0).unwrap();
    assert_eq!(rig.f().hvel, 2.0);
    rig.put(Field::ACCS, 4.0).unwrap();
    assert!(approx(rig.f().accl, 0.2), "{}", rig.f().accl);
    rig.put(Field::ACCS, -1.0).unwrap();
    assert!(approx(rig.f().accs, 4.0), "replaced by the value derived from ACCL");
    rig.put(Field::BACC, 0.0).unwrap();
    assert_eq!(rig.f().bacc, 0.1);
    rig.put(Field::FRAC, 2.0).unwrap();
    assert_eq!(rig.f().frac, 1.5);
    rig.put(Field::RDBD, 0.0).unwrap();
    assert_eq!(rig.f().rdbd, 0.01);
    assert!(matches!(rig.put(Field::NTMF, 1.0), Err(WriteError::Adjusted { .. })));
    assert_eq!(rig.f().ntmf, 2);
}

#[test]
fn gains_and_enable_reach_only_a_servo_driver() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::PCOF, 0.5).unwrap();
    assert!(rig.take().is_empty(), "no GAIN_SUPPORT: nothing sent");
    let servo = DeviceStatus { msta: msta::DONE | msta::GAIN_SUPPORT | msta::POSITION, ..idle(0.0) };
    let mut rig = Rig::boot_with(baseline_b(), servo);
    assert_eq!(rig.f().cnen, 1, "CNEN mirrors EA_POSITION");
    rig.put(Field::PCOF, 2.0).unwrap();
    assert_eq!(rig.take(), vec![SetPGain(1.0)]);
    assert_eq!(rig.f().pcof, 1.0);
    rig.put(Field::DCOF, 0.25).unwrap();
    assert_eq!(rig.take(), vec![SetDGain(0.25)]);
    rig.put(Field::CNEN, 0.0).unwrap();
    assert_eq!(rig.take()[0], DisableTorque);
}

#[test]
fn readback_deadband_limits_rbv_posts() {
    let mut rig = Rig::boot(Fields { mdel: 0.05, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    rig.cb_moving(3.0);
    assert!(rig.posted(Field::RBV).is_empty(), "0.03 is within MDEL");
    rig.cb_moving(6.0);
    assert_eq!(rig.posted(Field::RBV), vec![Value::Float(0.06)]);
    assert_eq!(rig.f().mlst, 0.06);
    rig.cb_moving(8.0);
    assert!(rig.posted(Field::RBV).is_empty());
    assert_eq!(rig.posted(Field::DRBV), vec![Value::Float(0.08)], "only RBV has a deadband");
}

#[test]
fn status_fields_follow_the_driver() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    rig.status(DeviceStatus { position: 40.4, velocity: 99.7, msta: msta::DIRECTION, ..DeviceStatus::default() });
    let f = rig.f();
    assert_eq!((f.rmp, f.rvel, f.tdir, f.movn, f.msta), (40, 99, 1, 1, msta::DIRECTION));
    assert_eq!(rig.posted(Field::RVEL), vec![Value::Int(99)]);
    assert_eq!((f.lval, f.ldvl, f.lrvl, f.lrlv), (1.0, 1.0, 100, 0.0));
    rig.status(DeviceStatus { position: 100.0, msta: msta::DONE | msta::HOME, ..DeviceStatus::default() });
    assert_eq!((rig.f().athm, rig.f().tdir, rig.f().dmov), (1, 0, 1));
}
