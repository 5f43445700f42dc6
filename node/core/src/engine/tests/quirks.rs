//! The code quirks of spec §18.1 and the finer rules of §5.10, §8, §9.1, §11, §12 and
//! §14.7–§14.9 that no other test pins down, one test each (two where an item has two distinct
//! behaviours).

use super::*;
use zmotor_msgs::menus::{severity, status};

fn jog_b() -> Fields {
    Fields { jvel: 2.0, jar: 4.0, ..baseline_b() }
}

// ---------------------------------------------------------------- §18.1 quirks

/// Q7: the jog button is not re-read while jogging, so any processing during a jog (here a
/// write to HLSV, a process-passive field with nothing to do with motion) stops it: STOP_AXIS,
/// MIP JOG_STOP, JOGF left as it was.
#[test]
fn q7_any_processing_during_a_jog_stops_it() {
    let mut rig = Rig::boot(jog_b(), 0.0);
    rig.put(Field::JOGF, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelBase(0.0), SetAccel(400.0), Jog(200.0)]);
    rig.cb_moving(100.0);
    rig.put(Field::HLSV, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().mip, rig.f().jogf, rig.f().dmov), (mip::JOG_STOP, 1, 0));
}

/// Q7: a VAL written during a jog stops the jog and is then overwritten by the readback when
/// the jog has stopped: no move to it.
#[test]
fn q7_a_target_written_during_a_jog_is_overwritten_by_the_readback() {
    let mut rig = Rig::boot(jog_b(), 0.0);
    rig.put(Field::JOGF, 1.0).unwrap();
    rig.cb_moving(150.0);
    rig.take();
    rig.put(Field::VAL, 5.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!(rig.f().mip, mip::JOG_STOP);
    rig.cb(310.0);
    assert!(rig.take().is_empty(), "the written target is not moved to");
    let f = rig.f();
    assert_eq!((f.val, f.dval, f.rval, f.mip, f.dmov), (3.1, 3.1, 310, 0, 1));
}

/// Q9: HIHI/HIGH/LOW/LOLO and HHSV/HSV/LSV/LLSV are never evaluated: readbacks beyond all of
/// them raise no alarm, and writing one merely processes the record (the automatic refresh).
#[test]
fn q9_the_analog_alarm_limits_are_never_evaluated() {
    let fields = Fields {
        hihi: 0.5,
        high: 0.2,
        low: -0.2,
        lolo: -0.5,
        hhsv: severity::INVALID,
        hsv: severity::MAJOR,
        lsv: severity::MAJOR,
        llsv: severity::INVALID,
        ..baseline_b()
    };
    let mut rig = Rig::boot(fields, 100.0);
    assert_eq!((rig.f().rbv, rig.f().stat, rig.f().sevr), (1.0, status::NO_ALARM, severity::NO_ALARM));
    rig.put(Field::VAL, -1.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, -100.0));
    rig.cb(-100.0);
    assert_eq!((rig.f().rbv, rig.f().dmov, rig.f().stat, rig.f().sevr), (-1.0, 1, 0, 0));
    rig.put(Field::HIHI, -2.0).unwrap();
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!((rig.f().stat, rig.f().sevr), (0, 0));
    assert!(rig.posted(Field::SEVR).is_empty() && rig.posted(Field::STAT).is_empty());
}

/// Q14: CDIR, PP, LVAL/LDVL/LRVL (set by a move) and LSPG (set by an SPMG write) change
/// without monitor posts.
#[test]
fn q14_bookkeeping_fields_change_without_posts() {
    let mut rig = Rig::boot(baseline_k(), 48.0);
    let f = rig.f();
    assert_eq!((f.cdir, f.pp, f.lval, f.ldvl, f.lrvl, f.lspg), (0, 0, 48.0, 48.0, 48, 3));
    rig.put(Field::VAL, 96.0).unwrap();
    assert_eq!(rig.take(), move_abs(10.0, 0.0, 10.0, 72.0));
    let f = rig.f();
    assert_eq!((f.cdir, f.pp, f.lval, f.ldvl, f.lrvl), (1, 1, 96.0, 96.0, 96));
    for field in [Field::CDIR, Field::PP, Field::LVAL, Field::LDVL, Field::LRVL] {
        assert!(rig.posted(field).is_empty(), "{field} posted");
    }
    rig.put(Field::SPMG, 1.0).unwrap();
    assert_eq!(rig.f().lspg, 1);
    assert_eq!(rig.posted(Field::SPMG), vec![Value::Int(1)]);
    assert!(rig.posted(Field::LSPG).is_empty());
}

/// Q16: the relative "within backlash range" test is in raw steps (BDST ≥ 0: relbpos ≤ +1;
/// BDST < 0: relbpos ≥ +1), so with MRES < 0 it is inverted: long preferred-direction moves are
/// made as one leg at BVEL/BACC (case B) instead of going to the backlash start first.
#[test]
fn q16_relative_backlash_range_test_is_inverted_with_negative_mres() {
    let fields = Fields { mres: -0.01, ueip: 1, eres: -0.01, rdbd: 0.02, bdst: 0.5, ..baseline_b() };
    let mut rig = Rig::boot_encoder(fields.clone(), 0.0, 0.0);
    // Dial 0 → 2 (4 × BDST): relbpos = (1.5 − 0)/−0.01 = −150 ≤ 1 ⇒ case B.
    rig.put(Field::VAL, 2.0).unwrap();
    assert_cmds_close(&rig.take(), &[SetVelocity(50.0), SetVelBase(0.0), SetAccel(100.0), MoveRel(-200.0), Go]);
    assert_eq!((rig.f().pp, rig.f().mip, rig.f().cdir), (0, mip::MOVE, 0));
    rig.cb_encoder(-200.0, -200.0);
    assert!(rig.take().is_empty(), "no backlash leg follows");
    assert_eq!(rig.f().dmov, 1);
    // BDST < 0, dial 2 → 1: relbpos = ((1 + 0.5) − 2)/−0.01 = 50 ≥ 1 ⇒ case B again.
    let mut rig = Rig::boot_encoder(Fields { bdst: -0.5, ..fields }, -200.0, -200.0);
    assert_eq!(rig.f().drbv, 2.0);
    rig.put(Field::VAL, 1.0).unwrap();
    assert_cmds_close(&rig.take(), &[SetVelocity(50.0), SetVelBase(0.0), SetAccel(100.0), MoveRel(100.0), Go]);
    assert_eq!(rig.f().pp, 0);
}

/// Q19: the boot-time LVIO test `DRBV > DHLM + MRES or DRBV < DLLM − MRES` uses signed MRES:
/// the one-step tolerance becomes a one-step tightening when MRES < 0.
#[test]
fn q19_boot_lvio_tolerance_uses_signed_mres() {
    let lvio =
        |mres: f64, steps: f64| Rig::boot(Fields { mres, dhlm: 10.0, dllm: -10.0, ..baseline_b() }, steps).f().lvio;
    // MRES > 0: at DHLM is fine (one step of tolerance); two steps beyond are not.
    assert_eq!((lvio(0.01, 1000.0), lvio(0.01, 1002.0)), (0, 1));
    // MRES < 0: at DHLM (raw −1000) or at DLLM (raw 1000) is already a violation.
    assert_eq!((lvio(-0.01, -1000.0), lvio(-0.01, 1000.0)), (1, 1));
    assert_eq!((lvio(-0.01, -998.0), lvio(-0.01, 998.0)), (0, 0));
}

/// Q21: a Set-mode VAL write (FOFF Variable) forces MIP = DONE and DMOV = 1 even while a move
/// runs; nothing is stopped, so the next moving callback looks like external motion.
#[test]
fn q21_set_mode_val_write_ends_a_running_move_on_the_record() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 5.0).unwrap();
    rig.cb_moving(100.0);
    rig.put(Field::SSET, 1.0).unwrap();
    rig.put(Field::VAL, 3.0).unwrap();
    assert!(rig.take().is_empty(), "no stop is sent");
    let f = rig.f();
    assert_eq!((f.mip, f.dmov, f.off, f.val, f.dval, f.rbv), (mip::DONE, 1, -2.0, 3.0, 5.0, -1.0));
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(1)]);
    assert_eq!(rig.done_count, 1);
    rig.cb_moving(200.0);
    assert_eq!((rig.f().mip, rig.f().dmov), (mip::EXTERNAL, 0));
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(0)]);
}

/// Q22: a limit-switch end with MIP ≠ DONE while idle (here MIP = STOP after a Pause) sets
/// DMOV 0 and unmarks it: the 1→0 change is never posted, only the 1 that follows.
#[test]
fn q22_a_silent_dmov_0_at_a_limit_switch_while_idle() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::SPMG, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().mip, rig.f().dmov), (mip::STOP, 1));
    let at_minus_switch = DeviceStatus { msta: msta::DONE | msta::MINUS_LS, ..idle(0.0) };
    rig.status(at_minus_switch);
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!((rig.f().dmov, rig.f().mip, rig.f().lls), (0, mip::DONE, 1));
    assert!(rig.posted(Field::DMOV).is_empty(), "DMOV 0 is not posted");
    assert_eq!(rig.done_count, 0);
    rig.status(at_minus_switch);
    assert_eq!(rig.f().dmov, 1);
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(1)]);
    assert_eq!(rig.done_count, 1);
}

/// Q28: at boot a non-zero ACCS overrides ACCL whatever ACCU says (here "Use ACCL").
#[test]
fn q28_a_non_zero_accs_sets_accl_at_boot_whatever_accu() {
    let mut rig = Rig::boot(Fields { velo: 10.0, accl: 2.0, accs: 20.0, accu: 0, ..baseline_b() }, 0.0);
    assert_eq!((rig.f().accl, rig.f().accs), (0.5, 20.0));
    rig.put(Field::VAL, 1.0).unwrap();
    assert_eq!(rig.take(), move_abs(1000.0, 0.0, 2000.0, 100.0));
}

/// Q28: home and backlash accelerations ignore ACCU: with "Use ACCS" the slew leg accelerates
/// at ACCS, the backlash leg at (BVEL − VBAS)/BACC and the home at (HVEL − VBAS)/ACCL.
#[test]
fn q28_home_and_backlash_accelerations_ignore_accu() {
    let fields = Fields { velo: 10.0, accs: 20.0, accu: 1, hvel: 5.0, bdst: 0.5, ..baseline_b() };
    let mut rig = Rig::boot(fields, 0.0);
    assert_eq!(rig.f().accl, 0.5);
    rig.put(Field::VAL, 2.0).unwrap();
    assert_cmds_close(&rig.take(), &move_abs(1000.0, 0.0, 2000.0, 150.0));
    rig.cb(150.0);
    assert_cmds_close(&rig.take(), &[SetVelocity(50.0), SetAccel(100.0), MoveAbs(200.0), Go]);
    rig.cb(200.0);
    assert_eq!(rig.f().dmov, 1);
    rig.put(Field::HOMF, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelocity(500.0), SetVelBase(0.0), SetAccel(1000.0), HomeFor, Go]);
}

/// Q29: the "speed ≤ base speed" fix (VBAS + 1 step/s) applies only to post-processed legs: the
/// final backlash leg (T2) at BVEL = VBAS goes at vbase + 1, a case-B move (T1) at BVEL = VBAS
/// is sent unchanged.
#[test]
fn q29_base_speed_fix_only_on_post_processed_legs() {
    let mut rig = Rig::boot(Fields { vbas: 0.5, bdst: 0.5, ..baseline_b() }, 0.0);
    assert_eq!((rig.f().bvel, rig.f().vbas), (0.5, 0.5));
    rig.put(Field::VAL, 2.0).unwrap();
    assert_cmds_close(&rig.take(), &move_abs(100.0, 50.0, 100.0, 150.0));
    rig.cb(150.0);
    assert_cmds_close(&rig.take(), &[SetVelocity(51.0), SetAccel(100.0), MoveAbs(200.0), Go]);
    rig.cb(200.0);
    assert_eq!(rig.f().dmov, 1);
    // Case B, 30 steps within the 51-step backlash range: one T1 leg at BVEL as it is.
    rig.put(Field::VAL, 2.3).unwrap();
    assert_cmds_close(&rig.take(), &move_abs(50.0, 50.0, 100.0, 230.0));
}

/// Q30: the jog start always sends SET_ACCEL, even 0 (JAR = VELO/ACCL = 0 at boot); a move
/// omits SET_ACCEL when its acceleration is 0.
#[test]
fn q30_jog_start_always_sends_set_accel() {
    let mut rig = Rig::boot(Fields { velo: 0.0, jvel: 2.0, ..baseline_b() }, 0.0);
    assert_eq!((rig.f().jar, rig.f().jvel, rig.f().accs), (0.0, 2.0, 0.0));
    rig.put(Field::JOGF, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelBase(0.0), SetAccel(0.0), Jog(200.0)]);
    rig.put(Field::JOGF, 0.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    rig.cb(100.0);
    assert_eq!(rig.f().dmov, 1);
    rig.put(Field::VAL, 5.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelocity(0.0), SetVelBase(0.0), MoveAbs(500.0), Go]);
}

/// Q32: re-writing the same VAL re-issues the move when the readback is a step or more away
/// (here after a stall with RTRY 0) and outside SPDB; inside SPDB it is too small (DMOV 0→1).
#[test]
fn q32_rewriting_the_same_val_moves_again() {
    let mut rig = Rig::boot(Fields { rtry: 0, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 2.0).unwrap();
    rig.take();
    rig.cb(150.0);
    assert_eq!((rig.f().dmov, rig.f().val, rig.f().drbv, rig.f().miss), (1, 2.0, 1.5, 0));
    rig.put(Field::VAL, 2.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 200.0));
    assert_eq!((rig.f().mip, rig.f().dmov, rig.f().cdir), (mip::MOVE, 0, 1));
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(0)]);

    let mut rig = Rig::boot(Fields { rtry: 0, spdb: 0.6, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 2.0).unwrap();
    rig.cb(150.0);
    rig.put(Field::VAL, 2.0).unwrap();
    assert!(rig.take().is_empty(), "1.5 lies within 2 ± SPDB");
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(0), Value::Int(1)]);
}

/// Q36: a resolution change rescales VELO, VBAS, BVEL and VMAX (keeping S, SBAS, SBAK, SMAX)
/// but leaves JVEL, HVEL, JAR, ACCL and ACCS alone.
#[test]
fn q36_resolution_change_leaves_jog_home_and_acceleration_fields() {
    let fields = Fields { vbas: 0.1, vmax: 2.0, jvel: 1.5, jar: 3.0, hvel: 0.5, ..baseline_b() };
    let mut rig = Rig::boot(fields, 100.0);
    let kept = |f: &Fields| (f.s, f.sbas, f.sbak, f.smax, f.jvel, f.hvel, f.jar, f.accl, f.accs);
    let before = kept(rig.f());
    assert_eq!((before.0, before.3, before.4, before.5, before.6, before.7), (0.5, 1.0, 1.5, 0.5, 3.0, 0.5));
    assert!(approx(before.1, 0.05) && approx(before.2, 0.25) && approx(before.8, 1.8), "{before:?}");
    rig.put(Field::MRES, 0.02).unwrap();
    let f = rig.f();
    assert!(approx(f.velo, 2.0) && approx(f.vbas, 0.2) && approx(f.bvel, 1.0) && approx(f.vmax, 4.0), "{f:?}");
    assert_eq!(kept(f), before);
}

/// Q39: the URIP readback (RDBL) is ignored at init (DRBV comes from the motor steps) and
/// needs RRES ≠ 0: with the default RRES 0 the readback is 0.
#[test]
fn q39_urip_readback_ignored_at_init_and_zero_without_rres() {
    let fields = Fields { urip: 1, rdbl: "lab/readback".into(), ..baseline_b() };
    let reading = DeviceStatus { readback: Some(0.123), ..idle(500.0) };
    let mut rig = Rig::boot_with(fields, reading);
    let f = rig.f();
    assert_eq!((f.rrbv, f.drbv, f.rbv, f.val), (500, 5.0, 5.0, 5.0));
    rig.status(reading);
    let f = rig.f();
    assert_eq!((f.rrbv, f.drbv, f.rbv), (0, 0.0, 0.0));
    rig.put(Field::RRES, 1.0).unwrap();
    rig.status(reading);
    assert_eq!((rig.f().rrbv, rig.f().drbv), (12, 0.12));
}

/// Q40: the callback that finds a retry due runs do_work, which re-evaluates the soft limits:
/// a target the limits now exclude (DHLM lowered during the move) ends the motion with
/// DMOV 1, RCNT 1 and nothing sent, instead of retrying.
#[test]
fn q40_a_retry_re_evaluates_the_soft_limits_on_the_callback() {
    let mut rig = Rig::boot(Fields { dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 5.0).unwrap();
    rig.cb_moving(100.0);
    rig.take();
    let _ = rig.put(Field::DHLM, 3.0);
    assert_cmds_close(&rig.take(), &[SetHighLimit(300.0)]);
    assert_eq!((rig.f().lvio, rig.f().mip, rig.f().dmov), (1, mip::MOVE, 0), "the move runs on");
    rig.cb(250.0);
    assert!(rig.take().is_empty(), "no retry");
    let f = rig.f();
    assert_eq!((f.dmov, f.mip, f.rcnt, f.miss, f.lvio, f.val, f.dval), (1, mip::DONE, 1, 0, 1, 5.0, 5.0));
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(1)]);
}

// ---------------------------------------------------------------- §14.7 SPMG and STOP

/// §14.7: STOP while a move is commanded but not yet reported moving (MOVN 0) syncs the targets
/// to the readback at once, MIP = STOP, STOP_AXIS; the stop then ends with DMOV 1.
#[test]
fn stop_before_the_motion_is_reported_syncs_the_targets_at_once() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 5.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 500.0));
    rig.put(Field::STOP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    let f = rig.f();
    assert_eq!((f.val, f.dval, f.rval, f.mip, f.dmov, f.stop), (0.0, 0.0, 0, mip::STOP, 0, 0));
    rig.cb(0.0);
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().mip, rig.f().dmov, rig.f().val), (mip::DONE, 1, 0.0));
}

/// §14.7: a jog paused by SPMG Pause stops (MIP STOP), is synced to the readback when it has
/// stopped (DMOV 1) and keeps JOGF = 1, so SPMG Go restarts it.
#[test]
fn a_paused_jog_keeps_its_button_and_restarts_on_go() {
    let mut rig = Rig::boot(jog_b(), 0.0);
    rig.put(Field::JOGF, 1.0).unwrap();
    rig.cb_moving(100.0);
    rig.take();
    rig.put(Field::SPMG, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().mip, rig.f().jogf), (mip::STOP, 1));
    rig.cb(150.0);
    assert!(rig.take().is_empty());
    let f = rig.f();
    assert_eq!((f.val, f.dval, f.dmov, f.jogf, f.mip), (1.5, 1.5, 1, 1, mip::DONE));
    rig.put(Field::SPMG, 3.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelBase(0.0), SetAccel(400.0), Jog(200.0)]);
    assert_eq!((rig.f().mip, rig.f().dmov), (mip::JOGF, 0));
}

// ---------------------------------------------------------------- §14.8 DLY

/// §14.8: STOP during the DLY wait keeps the DELAY bits (MIP not set to STOP), so the sequence
/// still ends: timer ⇒ GET_INFO, next callback ⇒ DMOV 1.
#[test]
fn stop_during_the_settling_delay_keeps_the_delay_running() {
    let mut rig = Rig::boot(Fields { dly: 1.0, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    rig.cb(100.0);
    assert_eq!((rig.f().mip, rig.delays.clone()), (mip::MOVE | mip::DELAY_REQ, vec![1.0]));
    rig.put(Field::STOP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().mip, rig.f().dmov), (mip::MOVE | mip::DELAY_REQ, 0));
    rig.timer();
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!(rig.f().mip, mip::MOVE | mip::DELAY_REQ | mip::DELAY_ACK);
    rig.cb(100.0);
    assert_eq!((rig.f().mip, rig.f().dmov, rig.f().val, rig.done_count), (mip::DONE, 1, 1.0, 1));
}

/// §14.8: no settling delay after a limit-switch stop in the commanded direction or after a
/// set position (LOAD_POS): DMOV 1 at the callback, no timer.
#[test]
fn no_settling_delay_after_a_limit_switch_stop_or_a_set_position() {
    let mut rig = Rig::boot(Fields { dly: 1.0, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 10.0).unwrap();
    rig.status(DeviceStatus { msta: msta::DIRECTION | msta::PLUS_LS, ..moving(300.0) });
    assert_eq!(rig.take(), vec![GetInfo]);
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS, ..idle(302.0) });
    assert!(rig.delays.is_empty() && rig.take().is_empty());
    assert_eq!((rig.f().dmov, rig.f().mip, rig.f().val, rig.done_count), (1, mip::DONE, 3.02, 1));

    let mut rig = Rig::boot(Fields { dly: 1.0, ..baseline_b() }, 200.0);
    rig.put(Field::SSET, 1.0).unwrap();
    rig.put(Field::DVAL, 7.0).unwrap();
    assert_eq!(rig.take(), vec![LoadPos(700.0), GetInfo]);
    rig.cb(700.0);
    assert!(rig.delays.is_empty() && rig.take().is_empty());
    assert_eq!((rig.f().dmov, rig.f().mip, rig.done_count), (1, mip::DONE, 1));
}

// ---------------------------------------------------------------- §14.9 STUP and SYNC

/// §14.9: SYNC written while the record is busy stays 1 and is served by the callback that
/// ends the motion (VAL = DVAL = readback, SYNC 0 posted).
#[test]
fn sync_during_a_move_is_served_when_the_move_ends() {
    let mut rig = Rig::boot(Fields { rtry: 0, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 2.0).unwrap();
    rig.cb_moving(100.0);
    rig.take();
    rig.put(Field::SYNC, 1.0).unwrap();
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().sync, rig.f().val, rig.f().dval), (1, 2.0, 2.0));
    rig.cb(150.0);
    assert!(rig.take().is_empty());
    let f = rig.f();
    assert_eq!((f.val, f.dval, f.rval, f.sync, f.dmov), (1.5, 1.5, 150, 0, 1));
    assert_eq!(rig.posted(Field::SYNC), vec![Value::Int(0)]);
}

/// §14.9: while STUP is BUSY the "motor stopped" logic of §8 is skipped: the callback answering
/// the refresh ends nothing (DMOV stays 0, MIP MOVE), it only sets STUP OFF.
#[test]
fn a_callback_while_stup_is_busy_does_not_end_the_motion() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    rig.take();
    rig.put(Field::STUP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!(rig.f().stup, 2);
    rig.cb(100.0);
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().dmov, rig.f().mip, rig.f().stup, rig.done_count), (0, mip::MOVE, 0, 0));
    assert_eq!(rig.posted(Field::STUP), vec![Value::Int(0)]);
    rig.cb(100.0);
    assert_eq!((rig.f().dmov, rig.f().mip, rig.done_count), (1, mip::DONE, 1));
}

// ---------------------------------------------------------------- §11, §9.1 retries

/// Drive an axis (RTRY 1) to a miss at raw 90 of a target of 100: RCNT 2, MISS 1.
fn missed() -> Rig {
    let mut rig = Rig::boot(Fields { rtry: 1, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 100.0));
    rig.cb(90.0);
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 100.0));
    rig.cb(90.0);
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().rcnt, rig.f().miss, rig.f().dmov), (2, 1, 1));
    rig
}

/// §11: MISS stays 1 when the next move starts (RCNT is reset) and is cleared, and posted,
/// by the next successful end.
#[test]
fn miss_is_cleared_by_the_next_successful_end() {
    let mut rig = missed();
    rig.put(Field::VAL, 2.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 200.0));
    assert_eq!((rig.f().rcnt, rig.f().miss), (0, 1));
    assert_eq!(rig.posted(Field::RCNT), vec![Value::Int(0)]);
    rig.cb(200.0);
    assert_eq!((rig.f().miss, rig.f().dmov), (0, 1));
    assert_eq!(rig.posted(Field::MISS), vec![Value::Int(0)]);
}

/// §9.1: only SPMG = Move resets RCNT (marked); an explicit status update (STUP) and SPMG Stop
/// leave it.
#[test]
fn only_spmg_move_resets_rcnt() {
    let mut rig = missed();
    rig.put(Field::STUP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![GetInfo]);
    rig.cb(90.0);
    assert_eq!((rig.f().rcnt, rig.f().stup), (2, 0));
    rig.put(Field::SPMG, 0.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!(rig.f().rcnt, 2);
    rig.put(Field::SPMG, 2.0).unwrap();
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!((rig.f().rcnt, rig.f().mip, rig.f().miss), (0, mip::DONE, 1));
    assert_eq!(rig.posted(Field::RCNT), vec![Value::Int(0)]);
}

// ---------------------------------------------------------------- §8 process()

/// §8: a new target that arrived during a leg with PP = 1 (a case-C first leg) skips
/// postProcess at the stop: no final approach to the old target, a fresh move to the new one
/// is evaluated in the same processing (DMOV posted 0, not 1).
#[test]
fn a_new_target_during_a_backlash_first_leg_skips_post_process() {
    let mut rig = Rig::boot(Fields { ntm: 0, ..baseline_k() }, 48.0);
    rig.put(Field::VAL, 96.0).unwrap();
    assert_eq!(rig.take(), move_abs(10.0, 0.0, 10.0, 72.0));
    rig.cb_moving(60.0);
    rig.put(Field::VAL, 50.0).unwrap();
    assert!(rig.take().is_empty());
    rig.cb(72.0);
    // 50 is not the preferred direction from the previous target 96: case C to 50 − 24.
    assert_eq!(rig.take(), move_abs(10.0, 0.0, 10.0, 26.0));
    let f = rig.f();
    assert_eq!((f.mip, f.pp, f.dmov, f.cdir, f.rcnt, f.ldvl), (mip::MOVE, 1, 0, 0, 0, 50.0));
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(0)]);
    assert_eq!(rig.done_count, 0);
    rig.cb(26.0);
    assert_cmds_close(&rig.take(), &[SetVelocity(2.0), SetAccel(4.0 / 3.0), MoveAbs(50.0), Go]);
    rig.cb(50.0);
    assert_eq!((rig.f().dmov, rig.f().val), (1, 50.0));
}

/// §8: a jog that the controller ends by itself (stopped, MIP == JOGF, no switch) ends like a
/// limit-switch stop: MIP DONE, buttons cleared (JOGF 0 posted), targets synced, no backlash.
#[test]
fn a_jog_ended_by_the_controller_clears_the_button_without_backlash() {
    let mut rig = Rig::boot(Fields { bdst: 0.5, ..jog_b() }, 0.0);
    rig.put(Field::JOGF, 1.0).unwrap();
    rig.cb_moving(100.0);
    rig.take();
    rig.cb(300.0);
    assert!(rig.take().is_empty(), "no backlash takeout");
    let f = rig.f();
    assert_eq!((f.mip, f.jogf, f.val, f.dval, f.dmov), (mip::DONE, 0, 3.0, 3.0, 1));
    assert_eq!(rig.posted(Field::JOGF), vec![Value::Int(0)]);
}

// ---------------------------------------------------------------- §5.10, §12

/// §5.10: ATHM follows the encoder home bit (EA_HOME) when UEIP = Yes, the motor's home switch
/// (RA_HOME) otherwise.
#[test]
fn athm_follows_the_encoder_home_with_ueip() {
    let home = |rig: &mut Rig, bit: u32| {
        rig.status(DeviceStatus { msta: msta::DONE | msta::PRESENT | bit, ..idle(0.0) });
        rig.f().athm
    };
    let mut rig = Rig::boot_encoder(Fields { ueip: 1, eres: 0.01, ..baseline_b() }, 0.0, 0.0);
    assert_eq!(rig.f().ueip, 1);
    assert_eq!(home(&mut rig, msta::HOME), 0);
    assert_eq!(home(&mut rig, msta::ENCODER_HOME), 1);
    assert_eq!(rig.posted(Field::ATHM), vec![Value::Int(1)]);
    let mut rig = Rig::boot_encoder(Fields { eres: 0.01, ..baseline_b() }, 0.0, 0.0);
    assert_eq!(home(&mut rig, msta::ENCODER_HOME), 0);
    assert_eq!(home(&mut rig, msta::HOME), 1);
}

/// §12: with HLSV set, a target (DVAL) above DHLM raises HIGH and one below DLLM LOW, with
/// severity HLSV; LLS is the user-sense switch (the raw plus switch with DIR Neg); and the
/// limit alarm returns early, so a driver PROBLEM (MAJOR) does not raise it further.
#[test]
fn hlsv_alarms_from_the_target_and_the_user_sense_switches() {
    let limits = Fields { dhlm: 10.0, dllm: -10.0, ..baseline_b() };
    let rig = Rig::boot(Fields { hlsv: severity::MINOR, ..limits.clone() }, 1200.0);
    assert_eq!((rig.f().dval, rig.f().stat, rig.f().sevr), (12.0, status::HIGH, severity::MINOR));
    let rig = Rig::boot(Fields { hlsv: severity::MAJOR, ..limits }, -1200.0);
    assert_eq!((rig.f().stat, rig.f().sevr), (status::LOW, severity::MAJOR));

    let mut rig = Rig::boot(Fields { hlsv: severity::MAJOR, dir: 1, ..baseline_b() }, 0.0);
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS, ..idle(0.0) });
    assert_eq!((rig.f().lls, rig.f().hls, rig.f().stat, rig.f().sevr), (1, 0, status::LOW, severity::MAJOR));

    let mut rig = Rig::boot(Fields { hlsv: severity::MINOR, ..baseline_b() }, 0.0);
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS | msta::PROBLEM, ..idle(0.0) });
    assert_eq!((rig.f().stat, rig.f().sevr), (status::HIGH, severity::MINOR));
}

/// §12: UDF comes first: an undefined record (DOL a link, not yet read) is UDF/INVALID even at
/// an active switch with HLSV; a VAL put clears UDF and the switch alarm shows.
#[test]
fn udf_alarm_comes_before_the_limit_alarm() {
    let fields = Fields { hlsv: severity::MAJOR, dol: "lab/setpoint".into(), ..baseline_b() };
    let mut rig = Rig::boot(fields, 0.0);
    assert_eq!((rig.f().udf, rig.f().stat, rig.f().sevr), (1, status::UDF, severity::INVALID));
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS, ..idle(0.0) });
    assert_eq!((rig.f().hls, rig.f().stat, rig.f().sevr), (1, status::UDF, severity::INVALID));
    rig.put(Field::VAL, 0.0).unwrap();
    assert_eq!((rig.f().udf, rig.f().stat, rig.f().sevr), (0, status::HIGH, severity::MAJOR));
    assert_eq!(rig.posted(Field::SEVR), vec![Value::Int(i64::from(severity::MAJOR))]);
}

// ---------------------------------------------------------------- Q33 a disabled record

/// Q33: while DISA = DISV the record is not processed: a setting written is stored, device
/// status is not taken (RBV stays), and the first processing raises STAT DISABLE at severity
/// DISS with VAL posted. Enabled again (DISA, not process-passive, processes nothing), the next
/// processing takes the status and clears the alarm. (A target written meanwhile: Z25.)
#[test]
fn q33_a_disabled_record_is_not_processed_until_enabled() {
    let mut rig = Rig::boot(Fields { diss: severity::MAJOR, ..baseline_b() }, 0.0);
    rig.put(Field::DISA, 1.0).unwrap();
    assert!(rig.take().is_empty());
    assert_eq!(rig.posted(Field::DISA), vec![Value::Int(1)]);
    rig.put(Field::HLSV, 1.0).unwrap();
    assert!(rig.take().is_empty(), "nothing is sent");
    let f = rig.f();
    assert_eq!((f.hlsv, f.dmov, f.mip, f.stat, f.sevr), (1, 1, mip::DONE, status::DISABLE, severity::MAJOR));
    assert_eq!(rig.posted(Field::STAT), vec![Value::Int(status::DISABLE.into())]);
    assert_eq!(rig.posted(Field::VAL), vec![Value::Float(0.0)]);
    assert_eq!((rig.writes_completed, rig.done_count), (1, 0), "put-callbacks complete; no FLNK");
    // Status while disabled: not taken, and the alarm is not raised again.
    rig.cb(40.0);
    assert_eq!((rig.f().rbv, rig.f().rmp), (0.0, 0));
    assert!(rig.posted(Field::STAT).is_empty() && rig.posted(Field::RBV).is_empty());
    // Enabled: nothing until the next processing, which takes the status.
    rig.put(Field::DISA, 0.0).unwrap();
    assert_eq!(rig.f().stat, status::DISABLE);
    rig.cb(40.0);
    assert_eq!(rig.f().rbv, 0.4);
    assert_eq!((rig.f().stat, rig.f().sevr), (status::NO_ALARM, severity::NO_ALARM));
    assert_eq!(rig.posted(Field::STAT), vec![Value::Int(0)]);
    rig.put(Field::VAL, 5.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 500.0));
}

/// Q33 and SDIS: the link's value is DISA (cut to a short), and is read again at every
/// processing and write: a DISA written while the link reads DISV does not enable the record.
#[test]
fn q33_sdis_sets_disa_at_every_processing() {
    let mut rig = Rig::boot(Fields { disv: 2, ..baseline_b() }, 0.0);
    rig.rec.disable_value(2.9);
    rig.collect();
    assert_eq!((rig.f().disa, rig.posted(Field::DISA)), (2, vec![Value::Int(2)]));
    rig.put(Field::DISA, 0.0).unwrap();
    assert_eq!(rig.put(Field::VAL, 1.0), Err(WriteError::RecordDisabled { field: Field::VAL }));
    assert_eq!(rig.f().disa, 2, "SDIS read again");
    assert!(rig.take().is_empty());
    rig.rec.disable_value(0.0);
    rig.collect();
    rig.put(Field::VAL, 1.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 100.0));
    // SDIS relinked: its last value (0) no longer holds DISA.
    rig.rec.forget_disable_value();
    rig.put(Field::DISA, 2.0).unwrap();
    assert_eq!(rig.put(Field::VAL, 2.0), Err(WriteError::RecordDisabled { field: Field::VAL }));
    assert_eq!(rig.f().disa, 2);
}

/// Q33: a resolution written while disabled is stored, and the first put once enabled does
/// what §9.2 does for it (the position reloaded at the new resolution): the marks of the write
/// wait for the record's next processing (a stop meanwhile keeps them).
#[test]
fn q33_a_resolution_written_while_disabled_is_acted_upon_once_enabled() {
    let mut rig = Rig::boot(Fields { dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 100.0);
    rig.put(Field::DISA, 1.0).unwrap();
    rig.put(Field::MRES, 0.02).unwrap();
    assert!(rig.take().is_empty());
    rig.put(Field::STOP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis], "a stop at rest meanwhile");
    rig.put(Field::DISA, 0.0).unwrap();
    rig.put(Field::HLSV, 1.0).unwrap();
    assert_eq!(rig.take(), vec![LoadPos(50.0), GetInfo]);
}

// ---------------------------------------------------------------- dbCommon ACKT / ACKS

/// recGblResetAlarms and dbAccess's putAcks/putAckt: with ACKT YES (the default) ACKS holds
/// the highest severity since the last acknowledgement, the alarm gone or not; a write of
/// ACKS at least as high clears it (a lower one does nothing; the value is never stored);
/// ACKT NO makes ACKS follow the alarm, and writing it brings ACKS down to the severity now.
#[test]
fn acks_holds_the_alarm_until_acknowledged_unless_transients_need_none() {
    let mut rig = Rig::boot(Fields { hlsv: severity::MAJOR, ..baseline_b() }, 0.0);
    assert_eq!((rig.f().ackt, rig.f().acks), (1, 0));
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS, ..idle(0.0) });
    assert_eq!((rig.f().sevr, rig.f().acks), (severity::MAJOR, severity::MAJOR));
    assert_eq!(rig.posted(Field::ACKS), vec![Value::Int(2)]);
    rig.status(idle(0.0));
    assert_eq!((rig.f().sevr, rig.f().acks), (severity::NO_ALARM, severity::MAJOR), "held");
    rig.put(Field::ACKS, 1.0).unwrap();
    assert_eq!(rig.f().acks, severity::MAJOR, "MINOR acknowledges no MAJOR");
    assert!(rig.posted(Field::ACKS).is_empty());
    rig.put(Field::ACKS, 2.0).unwrap();
    assert_eq!(rig.f().acks, severity::NO_ALARM);
    assert_eq!(rig.posted(Field::ACKS), vec![Value::Int(0)]);
    // Transients need no acknowledgement: ACKS follows the alarm.
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS, ..idle(0.0) });
    rig.put(Field::ACKT, 0.0).unwrap();
    assert_eq!(rig.f().acks, severity::MAJOR, "the alarm is still on");
    rig.status(idle(0.0));
    assert_eq!(rig.f().acks, severity::NO_ALARM);
    // Written back to YES with a held acknowledgement, then NO: brought down to the alarm now.
    rig.put(Field::ACKT, 1.0).unwrap();
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS, ..idle(0.0) });
    rig.status(idle(0.0));
    assert_eq!(rig.f().acks, severity::MAJOR);
    rig.put(Field::ACKT, 0.0).unwrap();
    assert_eq!(rig.f().acks, severity::NO_ALARM);
    assert_eq!(rig.posted(Field::ACKS).last(), Some(&Value::Int(0)));
}
