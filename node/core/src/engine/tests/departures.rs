//! Departures from the reference (README "Departures"): each decided one, with its test.
//! Z-numbers match the README's list; Q-numbers are the reference quirks of spec §18.

use super::*;

fn jog_fields() -> Fields {
    Fields { jvel: 2.0, jar: 4.0, dhlm: 10.0, dllm: -10.0, ..baseline_b() }
}

#[test]
fn z1_a_refused_jog_leaves_no_request_behind() {
    let mut rig = Rig::boot(jog_fields(), 850.0);
    let err = rig.put(Field::JOGF, 1.0).unwrap_err();
    assert!(err.to_string().starts_with("JOGF: limit violation"), "{err}");
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().lvio, rig.f().jogf, rig.f().mip), (1, 0, mip::DONE));
    // The reference would now start a reverse jog (Q1, W27a); zmotor moves to the target.
    rig.put(Field::VAL, 5.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 500.0));
}

#[test]
fn z2_igset_keeps_the_soft_limit_stop_of_a_jog() {
    let mut rig = Rig::boot(Fields { igset: 1, ..jog_fields() }, 0.0);
    rig.put(Field::JOGF, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelBase(0.0), SetAccel(400.0), Jog(200.0)]);
    rig.cb_moving(801.0);
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().lvio, rig.f().jogf, rig.f().mip), (1, 0, mip::STOP));
}

#[test]
fn z3_restored_raw_limits_keep_their_sign_with_negative_mres() {
    let fields = Fields { mres: -0.01, dhlm: 10.0, dllm: -5.0, rllm: -1000.0, rhlm: 500.0, ..Fields::default() };
    let rig = Rig::boot(fields, 0.0);
    let f = rig.f();
    assert!(approx(f.dhlm, 10.0) && approx(f.dllm, -5.0), "{} {}", f.dhlm, f.dllm);
    assert!(approx(f.rllm, -1000.0) && approx(f.rhlm, 500.0));
    assert_eq!(f.lvio, 0);
}

#[test]
fn z4_no_limit_alarm_while_soft_limits_are_off() {
    let mut rig = Rig::boot(Fields { hlsv: 2, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    rig.cb(100.0);
    assert_eq!((rig.f().stat, rig.f().sevr), (0, 0));
    // The switch itself still raises the alarm.
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS, ..idle(100.0) });
    assert_eq!((rig.f().stat, rig.f().sevr), (4, 2));
}

#[test]
fn z5_a_jog_requested_during_a_move_stops_then_jogs() {
    let mut rig = Rig::boot(Fields { jvel: 2.0, jar: 4.0, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 5.0).unwrap();
    rig.cb_moving(100.0);
    rig.put(Field::JOGF, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!(rig.f().mip, mip::JOGF | mip::STOP);
    rig.cb(120.0);
    assert_eq!(rig.take(), vec![SetVelBase(0.0), SetAccel(400.0), Jog(200.0)]);
    assert_eq!((rig.f().mip, rig.f().dmov, rig.f().val), (mip::JOGF, 0, 1.2));
    rig.cb_moving(300.0);
    rig.put(Field::JOGF, 0.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    rig.cb(320.0);
    assert_eq!((rig.f().mip, rig.f().dmov, rig.f().val), (0, 1, 3.2));
}

#[test]
fn z6_a_home_refused_at_a_limit_switch_is_reset_and_never_starts_later() {
    let mut rig = Rig::boot(Fields { hvel: 0.5, ..baseline_b() }, 0.0);
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS, ..idle(0.0) });
    let err = rig.put(Field::HOMF, 1.0).unwrap_err();
    assert_eq!(err.to_string(), "HOMF: home (HOMF) refused: the high limit switch is active");
    assert_eq!(rig.f().homf, 0);
    assert_eq!(rig.posted(Field::HOMF).last(), Some(&Value::Int(0)));
    assert!(!rig.take().iter().any(|c| matches!(c, HomeFor | HomeRev)));
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS, ..idle(0.0) }); // the status refresh
                                                                                // Off the switch, the next move ends without a home (the reference homes then, Q25).
    rig.put(Field::VAL, -1.0).unwrap();
    rig.cb(-100.0);
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().dmov, rig.f().mip), (1, 0));
}

#[test]
fn z7_cdir_follows_the_leg_actually_travelled() {
    // W24: a retry from 55 with BDST > 0 first goes down to 36; the reference keeps CDIR 1.
    let mut rig = Rig::boot(baseline_k(), 48.0);
    rig.put(Field::VAL, 60.0).unwrap();
    rig.cb(55.0);
    assert_eq!(rig.take(), move_abs(10.0, 0.0, 10.0, 36.0));
    assert_eq!((rig.f().cdir, rig.f().mip, rig.f().rcnt), (0, mip::RETRY | mip::MOVE, 1));
    // So a minus switch met on the way down is recognised as a switch in the direction of motion.
    rig.status(DeviceStatus { msta: msta::MINUS_LS, ..moving(40.0) });
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!((rig.f().movn, rig.f().mip), (0, mip::DONE));
}

#[test]
fn z8_lvio_follows_limit_writes() {
    let mut rig = Rig::boot(Fields { dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 500.0);
    assert_eq!(rig.f().lvio, 0);
    rig.put(Field::DHLM, 4.0).unwrap();
    assert_eq!(rig.f().lvio, 1);
    assert_eq!(rig.posted(Field::LVIO).first(), Some(&Value::Int(1)));
    rig.put(Field::HLM, 6.0).unwrap();
    assert_eq!(rig.f().lvio, 0);
}

#[test]
fn z9_pause_then_go_resumes_to_the_target() {
    for rtry in [10, 0] {
        let mut rig = Rig::boot(Fields { rtry, ..baseline_b() }, 0.0);
        rig.put(Field::VAL, 5.0).unwrap();
        rig.cb_moving(100.0);
        rig.put(Field::SPMG, 1.0).unwrap();
        assert_eq!(rig.take(), vec![StopAxis]);
        rig.cb(130.0);
        assert!(rig.take().is_empty());
        assert_eq!((rig.f().dmov, rig.f().val, rig.f().dval, rig.f().rcnt), (0, 5.0, 5.0, 0), "rtry {rtry}");
        assert!(rig.posted(Field::DMOV).is_empty());
        rig.put(Field::SPMG, 3.0).unwrap();
        assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 500.0), "rtry {rtry}");
        rig.cb(500.0);
        assert_eq!((rig.f().dmov, rig.f().rcnt, rig.f().rbv), (1, 0, 5.0));
    }
}

#[test]
fn z9_a_paused_backlash_move_resumes_with_its_backlash_takeout() {
    let mut rig = Rig::boot(baseline_k(), 48.0);
    rig.put(Field::VAL, 96.0).unwrap();
    rig.take();
    rig.cb_moving(60.0);
    rig.put(Field::SPMG, 1.0).unwrap();
    rig.cb(62.0);
    assert_eq!(rig.f().dmov, 0);
    rig.put(Field::SPMG, 3.0).unwrap();
    assert_eq!(rig.take(), move_abs(10.0, 0.0, 10.0, 72.0));
    rig.cb(72.0);
    assert_cmds_close(&rig.take(), &[SetVelocity(2.0), SetAccel(4.0 / 3.0), MoveAbs(96.0), Go]);
    rig.cb(96.0);
    assert_eq!(rig.f().dmov, 1);
}

#[test]
fn z9_stop_while_paused_ends_the_motion_where_it_is() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 5.0).unwrap();
    rig.cb_moving(100.0);
    rig.put(Field::SPMG, 1.0).unwrap();
    rig.cb(130.0);
    rig.put(Field::SPMG, 0.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().dmov, rig.f().val, rig.f().dval), (1, 1.3, 1.3));
    rig.put(Field::SPMG, 3.0).unwrap();
    assert_eq!(rig.take(), vec![GetInfo]);
}

#[test]
fn z10_a_fractional_leg_never_ends_beyond_the_soft_limits() {
    let mut rig = Rig::boot(Fields { frac: 1.5, dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 9.0).unwrap();
    // 0 + 1.5·(900 − 0) = 1350 steps would pass DHLM (1000 steps).
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 1000.0));
    // Moving back towards the range from outside is still allowed (W15).
    let mut rig = Rig::boot(Fields { dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 1200.0);
    rig.put(Field::VAL, 11.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 1100.0));
}

#[test]
fn z11_a_disabled_servo_refuses_moves_with_a_clear_error() {
    let servo = |on: bool| DeviceStatus {
        msta: msta::DONE | msta::GAIN_SUPPORT | if on { msta::POSITION } else { 0 },
        ..idle(0.0)
    };
    let mut rig = Rig::boot_with(Fields { hvel: 0.5, ..baseline_b() }, servo(true));
    assert_eq!(rig.f().cnen, 1);
    rig.put(Field::CNEN, 0.0).unwrap();
    assert_eq!(rig.take(), vec![DisableTorque, GetInfo]);
    rig.status(servo(false));
    assert_eq!(rig.f().cnen, 0);
    let err = rig.put(Field::VAL, 1.0).unwrap_err();
    assert!(err.to_string().starts_with("VAL: motor disabled"), "{err}");
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().val, rig.f().dmov, rig.f().lvio), (0.0, 1, 0));
    assert!(rig.put(Field::JOGF, 1.0).unwrap_err().to_string().starts_with("JOGF: motor disabled"));
    assert_eq!((rig.f().jogf, rig.f().mip), (0, 0));
    assert!(rig.put(Field::HOMR, 1.0).is_err());
    assert_eq!(rig.f().homr, 0);
    rig.put(Field::CNEN, 1.0).unwrap();
    assert_eq!(rig.take()[0], EnableTorque);
    rig.status(servo(true));
    rig.put(Field::VAL, 1.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 100.0));
}

#[test]
fn z12_a_held_target_shows_in_val_dval_and_rval_alike() {
    let mut rig = Rig::boot(Fields { off: 1.0, ..baseline_b() }, 0.0);
    rig.put(Field::SPMG, 0.0).unwrap();
    rig.put(Field::DVAL, 2.0).unwrap();
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().val, rig.f().rval, rig.f().dmov), (3.0, 200, 0));
    rig.put(Field::SPMG, 3.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 200.0));
}

#[test]
fn z12_a_target_written_while_a_home_is_held_is_converted() {
    let mut rig = Rig::boot(Fields { hvel: 0.5, ..baseline_b() }, 0.0);
    rig.put(Field::SPMG, 0.0).unwrap();
    rig.put(Field::HOMF, 1.0).unwrap();
    rig.put(Field::VAL, 2.0).unwrap();
    assert_eq!((rig.f().val, rig.f().dval, rig.f().dmov), (2.0, 2.0, 0));
}

#[test]
fn z12_a_target_during_the_jog_backlash_takeout_is_refused() {
    let mut rig = Rig::boot(Fields { jvel: 2.0, jar: 4.0, bdst: 0.5, ..baseline_b() }, 0.0);
    rig.put(Field::JOGF, 1.0).unwrap();
    rig.put(Field::JOGF, 0.0).unwrap();
    rig.cb(310.0);
    assert_eq!(rig.f().mip, mip::JOG_BL1);
    assert!(matches!(rig.put(Field::VAL, 7.0), Err(WriteError::Refused { field: Field::VAL, .. })));
    assert_eq!((rig.f().val, rig.f().dval), (3.1, 3.1));
}

#[test]
fn z12_a_set_mode_calibration_is_not_held_by_spmg() {
    let mut rig = Rig::boot(baseline_b(), 200.0);
    rig.put(Field::SPMG, 0.0).unwrap();
    rig.put(Field::SSET, 1.0).unwrap();
    rig.put(Field::DVAL, 7.0).unwrap();
    assert_eq!(rig.take(), vec![LoadPos(700.0), GetInfo]);
    rig.cb(700.0);
    assert_eq!((rig.f().dmov, rig.f().off, rig.f().val), (1, -5.0, 2.0));
}

#[test]
fn z13_a_refused_move_restores_val_consistently_after_a_direction_change() {
    let mut rig = Rig::boot(Fields { dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 300.0);
    rig.put(Field::DIR, 1.0).unwrap();
    assert_eq!((rig.f().val, rig.f().off), (3.0, 6.0));
    assert!(rig.put(Field::VAL, -20.0).is_err());
    let f = rig.f();
    assert_eq!((f.val, f.dval, f.dmov), (3.0, 3.0, 1));
    assert_eq!(f.val, -f.dval + f.off);
}

#[test]
fn z14_a_held_request_keeps_dmov_0_whatever_status_arrives() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::SPMG, 1.0).unwrap();
    rig.put(Field::VAL, 2.0).unwrap();
    rig.cb(0.0);
    rig.cb(1.0);
    assert_eq!(rig.f().dmov, 0);
    assert!(rig.posted(Field::DMOV).is_empty());
    rig.put(Field::SPMG, 3.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 200.0));
}

#[test]
fn z15_writing_0_to_a_home_button_is_an_error() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    let err = rig.put(Field::HOMR, 0.0).unwrap_err();
    assert_eq!(err.to_string(), "HOMR refused: writing 0 does not abort a home; write STOP 1");
    assert!(rig.take().is_empty(), "no processing");
}

#[test]
fn z16_a_refused_move_leaves_diff_and_rdif_at_the_restored_target() {
    let mut rig = Rig::boot(Fields { dhlm: 100.0, dllm: -100.0, ..baseline_b() }, 0.0);
    rig.put(Field::SPMG, 1.0).unwrap();
    rig.put(Field::VAL, 500.0).unwrap();
    assert_eq!((rig.f().val, rig.f().dval), (500.0, 500.0), "held while paused");
    let err = rig.put(Field::SPMG, 3.0).unwrap_err();
    assert!(err.to_string().starts_with("SPMG: limit violation"), "{err}");
    let f = rig.f();
    assert_eq!((f.val, f.dval, f.drbv, f.dmov), (0.0, 0.0, 0.0, 1));
    // The reference leaves DIFF 500 and RDIF 50000 here.
    assert_eq!((f.diff, f.rdif), (0.0, 0));
    assert_eq!(rig.posted(Field::DIFF).last(), Some(&Value::Float(0.0)));
}

#[test]
fn z17_a_stream_of_new_targets_ends_at_the_last_one() {
    // RTRY 3: the reference would run out after three re-targets and end with MISS 1.
    let mut rig = Rig::boot(Fields { rtry: 3, rdbd: 0.05, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 5.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 500.0));
    let mut position = 0.0;
    for target in [1.0, 2.0, 1.5, 0.5, 1.0, 0.8] {
        // A new target behind the moving motor: NTM stops it, the stop ends, the new target is
        // approached as a retry.
        position += 20.0;
        rig.cb_moving(position);
        rig.put(Field::VAL, target).unwrap();
        rig.cb_moving(position + 1.0);
        rig.cb(position + 2.0);
        let sent = rig.take();
        let Some(MoveAbs(raw)) = sent.iter().find(|c| matches!(c, MoveAbs(_))) else { panic!("{sent:?}") };
        assert_eq!(*raw, target * 100.0, "each new target is moved to");
        assert_eq!((rig.f().rcnt, rig.f().miss, rig.f().mip), (1, 0, mip::RETRY | mip::MOVE));
        position = *raw - 5.0;
        rig.cb_moving(position);
    }
    rig.cb(80.0);
    let f = rig.f();
    assert_eq!((f.dmov, f.miss, f.rbv, f.val), (1, 0, 0.8, 0.8));
}

#[test]
fn z9_a_stop_drops_a_target_held_by_spmg() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::SPMG, 0.0).unwrap();
    rig.put(Field::VAL, 2.0).unwrap();
    assert_eq!((rig.f().dval, rig.f().dmov), (2.0, 0), "held");
    rig.put(Field::STOP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    let f = rig.f();
    assert_eq!((f.val, f.dval, f.diff, f.dmov), (0.0, 0.0, 0.0, 1));
    // Go later does not run the dropped target.
    rig.put(Field::SPMG, 3.0).unwrap();
    assert!(rig.take().iter().all(|c| !matches!(c, MoveAbs(_) | MoveRel(_))));
}

#[test]
fn z20_a_target_beyond_the_raw_range_is_refused_not_clamped() {
    // Soft limits off (DHLM = DLLM = 0), as after MRES 0: nothing else stops 2^70.
    let mut rig = Rig::boot(baseline_b(), 0.0);
    let err = rig.put(Field::VAL, 2f64.powi(70)).unwrap_err();
    assert!(err.to_string().starts_with("VAL: target out of range"), "{err}");
    assert!(rig.take().iter().all(|c| !matches!(c, MoveAbs(_) | MoveRel(_))), "nothing is sent");
    let f = rig.f();
    assert_eq!((f.val, f.dval, f.rval, f.dmov), (0.0, 0.0, 0, 1));
    // A resolution so fine that a millimetre is beyond 32 bits: a target there is refused too.
    // (A new resolution loads the position, 0 steps here, and a callback completes it.)
    rig.put(Field::MRES, 1e-300).unwrap();
    assert_eq!(rig.take(), vec![LoadPos(0.0), GetInfo]);
    rig.cb(0.0);
    let err = rig.put(Field::VAL, 1.0).unwrap_err();
    assert!(err.to_string().starts_with("VAL: target out of range"), "{err}");
    assert!(rig.take().iter().all(|c| !matches!(c, MoveAbs(_) | MoveRel(_))), "nothing is sent");
    assert_eq!((rig.f().val, rig.f().dval, rig.f().dmov), (0.0, 0.0, 1));
    rig.put(Field::MRES, 0.01).unwrap();
    assert_eq!(rig.take(), vec![LoadPos(0.0), GetInfo]);
    rig.cb(0.0);
    // The largest raw position that fits is a target like any other.
    rig.put(Field::VAL, f64::from(i32::MAX - 1000) * 0.01).unwrap();
    assert!(rig.take().iter().any(|c| matches!(c, MoveAbs(_))));
}

#[test]
fn z21_a_resolution_of_0_is_refused_and_changes_nothing() {
    let mut rig = Rig::boot(Fields { dhlm: 100.0, dllm: -100.0, ..baseline_b() }, 0.0);
    let before = rig.f().clone();
    // MRES = UREV / SREV: either at 0 would leave speeds and soft limits of 0 and positions of
    // infinitely many steps (the reference stores it).
    for field in [Field::MRES, Field::UREV] {
        let err = rig.put(field, 0.0).unwrap_err();
        assert_eq!(
            err.to_string(),
            format!("{field} refused: a resolution of 0 makes every position infinitely many steps")
        );
        assert_eq!(err.kind(), zmotor_msgs::RefusalKind::BadValue);
        assert!(rig.take().is_empty(), "nothing sent");
        assert_eq!(rig.f(), &before, "nothing changed");
    }
    rig.put(Field::VAL, 5.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 500.0), "the axis moves as before");
}

#[test]
fn z22_a_stop_during_a_retry_leg_under_way_keeps_dmov_0_until_the_motor_has_stopped() {
    // A new target behind the moving motor is approached as a retry leg (as in z17).
    let mut rig = Rig::boot(Fields { rtry: 3, rdbd: 0.05, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 5.0).unwrap();
    rig.cb_moving(20.0);
    rig.put(Field::VAL, 1.0).unwrap();
    rig.cb_moving(21.0);
    rig.cb(22.0);
    rig.cb_moving(40.0);
    assert_eq!((rig.f().mip, rig.f().movn, rig.f().dmov), (mip::RETRY | mip::MOVE, 1, 0));
    rig.take();
    rig.put(Field::STOP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    // The reference sets DMOV 1 here, while the motor decelerates.
    assert_eq!((rig.f().dmov, rig.f().mip), (0, mip::STOP));
    rig.cb_moving(45.0);
    assert_eq!(rig.f().dmov, 0);
    rig.cb(47.0);
    let f = rig.f();
    assert_eq!((f.dmov, f.movn), (1, 0));
    assert!(approx(f.rbv, 0.47) && approx(f.val, 0.47), "done where it stopped: {} {}", f.rbv, f.val);
    assert!(rig.take().iter().all(|c| !matches!(c, MoveAbs(_) | MoveRel(_))));
}

/// Z24: a disabled record is not processed, so the reference cannot stop a motion under way
/// (STOP is stored and waits); here STOP is processed all the same: the motor is stopped and,
/// once it has, the motion ends where it is (no retry toward the target after enabling).
#[test]
fn z24_stop_stops_a_motion_of_a_disabled_record() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 5.0).unwrap();
    rig.cb_moving(100.0);
    rig.take();
    rig.put(Field::DISA, 1.0).unwrap();
    rig.put(Field::STOP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().stop, rig.f().mip), (0, mip::STOP));
    rig.cb(150.0);
    assert!(rig.take().is_empty());
    assert_eq!(rig.f().dmov, 0, "disabled: the end is not processed");
    rig.put(Field::DISA, 0.0).unwrap();
    rig.cb(150.0);
    assert!(rig.take().is_empty(), "no retry toward 5");
    let f = rig.f();
    assert_eq!((f.dmov, f.mip, f.val, f.rbv), (1, mip::DONE, 1.5, 1.5));
}

/// Z24: a jog let go, or SPMG Pause, while the record is disabled stops the motion; a setting
/// written is stored, not processed.
#[test]
fn z24_a_jog_let_go_or_a_pause_while_disabled_stops() {
    let jogging = || {
        let mut rig = Rig::boot(jog_fields(), 0.0);
        rig.put(Field::JOGF, 1.0).unwrap();
        rig.cb_moving(100.0);
        rig.take();
        rig.put(Field::DISA, 1.0).unwrap();
        rig.put(Field::HLSV, 1.0).unwrap();
        assert!(rig.take().is_empty());
        assert_eq!(rig.f().hlsv, 1, "stored");
        rig
    };
    let mut rig = jogging();
    rig.put(Field::JOGF, 0.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    let mut rig = jogging();
    rig.put(Field::SPMG, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
}

/// Z24: a stop at rest while disabled drops a target held by a pause, as it does enabled:
/// SPMG Go once enabled resumes nothing.
#[test]
fn z24_a_stop_while_disabled_drops_a_paused_target() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 5.0).unwrap();
    rig.cb_moving(100.0);
    rig.put(Field::SPMG, 1.0).unwrap();
    rig.cb(150.0);
    assert_eq!((rig.f().dmov, rig.f().dval), (0, 5.0), "paused, the target held");
    rig.take();
    rig.put(Field::DISA, 1.0).unwrap();
    rig.put(Field::STOP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().dmov, rig.f().val, rig.f().dval), (1, 1.5, 1.5));
    rig.put(Field::DISA, 0.0).unwrap();
    rig.put(Field::SPMG, 3.0).unwrap();
    assert_eq!(rig.take(), vec![GetInfo], "nothing to resume");
}

/// Z25: while the record is disabled, a write that would start a motion once it is enabled (a
/// target, a jog or home button, SPMG Move or Go) is refused and changes nothing: the reference
/// keeps it and moves at the first processing after the record is enabled (spec Q33), when no
/// one is asking any more (a jog pressed then has no one to let it go).
#[test]
fn z25_a_motion_asked_while_disabled_is_refused_and_never_starts() {
    let mut rig = Rig::boot(jog_fields(), 0.0);
    rig.put(Field::SPMG, 1.0).unwrap();
    rig.put(Field::DISA, 1.0).unwrap();
    let before = rig.f().clone();
    for (field, value) in
        [(Field::VAL, 5.0), (Field::TWF, 1.0), (Field::JOGF, 1.0), (Field::HOMF, 1.0), (Field::SPMG, 3.0)]
    {
        assert_eq!(rig.put(field, value), Err(WriteError::RecordDisabled { field }), "{field}");
    }
    let mut after = rig.f().clone();
    assert_eq!((after.stat, after.sevr), (18, 0), "STAT DISABLE (DISS 0): the processing asked for raises it");
    (after.stat, after.sevr) = (before.stat, before.sevr);
    assert_eq!(after, before, "nothing else changed");
    rig.put(Field::DISA, 0.0).unwrap();
    rig.put(Field::SPMG, 3.0).unwrap();
    rig.cb(0.0);
    assert!(rig.take().iter().all(|c| matches!(c, GetInfo)), "nothing moves once enabled");
}

/// Z24: a stop while disabled just after a retry leg was sent (the record has not seen it
/// move: MOVN 0) keeps DMOV 0 until the motor is seen stopped, once enabled, and retries no
/// more.
#[test]
fn z24_a_stop_while_disabled_during_a_retry_leg_waits_for_the_motor() {
    let mut rig = Rig::boot(Fields { rtry: 3, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    rig.take();
    rig.cb(90.0);
    assert_eq!((rig.take(), rig.f().mip & mip::RETRY != 0), (move_abs(100.0, 0.0, 200.0, 100.0), true));
    rig.put(Field::DISA, 1.0).unwrap();
    rig.put(Field::STOP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().dmov, rig.f().mip), (0, mip::STOP), "the leg may be under way");
    rig.put(Field::DISA, 0.0).unwrap();
    rig.cb(95.0);
    assert!(rig.take().is_empty(), "no retry");
    assert_eq!((rig.f().dmov, rig.f().mip), (1, mip::DONE));
    assert!(approx(rig.f().val, 0.95), "ended where it stopped: {}", rig.f().val);
}
