//! Engine scenarios in virtual time: each starts from stated fields, performs writes and device
//! callbacks, and asserts the exact device commands and field values. Scenario names (Wn) are
//! the worked scenarios of the behaviour specification, §19.

mod departures;
mod lecture;
mod quirks;
mod scenarios;

use super::*;
use zmotor_msgs::bits::{mip, msta};
use zmotor_msgs::{Field, Fields, Value};
use MotorCommand::*;

/// A record under test plus what it has produced.
struct Rig {
    rec: MotorRecord,
    sent: Vec<MotorCommand>,
    posts: Vec<(Field, Value)>,
    delays: Vec<f64>,
    done_count: usize,
    /// Processings of the disabled record (each completes the writes waiting).
    writes_completed: usize,
    encoder: bool,
}

impl Rig {
    fn boot(fields: Fields, controller_steps: f64) -> Self {
        Self::boot_with(fields, idle(controller_steps))
    }

    /// Boot on a controller with an encoder (MSTA EA_PRESENT) reading `counts`.
    fn boot_encoder(fields: Fields, steps: f64, counts: f64) -> Self {
        let mut status = idle(steps);
        status.msta |= msta::PRESENT;
        status.encoder_position = counts;
        let mut rig = Self::boot_with(fields, status);
        rig.encoder = true;
        rig
    }

    fn boot_with(fields: Fields, status: DeviceStatus) -> Self {
        let mut rec = MotorRecord::new(fields);
        let _ = rec.restore_commands(status.position);
        rec.init(status);
        let mut rig = Rig {
            rec,
            sent: vec![],
            posts: vec![],
            delays: vec![],
            done_count: 0,
            writes_completed: 0,
            encoder: false,
        };
        rig.collect();
        rig.clear();
        rig
    }

    fn collect(&mut self) {
        for out in self.rec.drain_outputs() {
            match out {
                Output::Post(f, v) => self.posts.push((f, v)),
                Output::Transaction(t) => self.sent.extend(t),
                Output::StartDelay(d) => self.delays.push(d.as_secs_f64()),
                Output::Done => self.done_count += 1,
                Output::WritesCompleted => self.writes_completed += 1,
                Output::ReadbackLink(_) => {}
            }
        }
    }

    fn clear(&mut self) {
        self.sent.clear();
        self.posts.clear();
        self.delays.clear();
        self.done_count = 0;
    }

    fn put(&mut self, field: Field, value: f64) -> Result<(), WriteError> {
        self.clear();
        let v = match field.def().kind {
            zmotor_msgs::Kind::Double | zmotor_msgs::Kind::Float => Value::Float(value),
            _ => Value::Int(value as i64),
        };
        let r = self.rec.write(field, &v);
        self.collect();
        r
    }

    fn status(&mut self, status: DeviceStatus) {
        self.clear();
        self.rec.callback(status);
        self.collect();
    }

    /// The driver reports "stopped at raw position p".
    fn cb(&mut self, p: f64) {
        self.status(self.with_encoder(idle(p), p));
    }

    /// The driver reports "moving at p".
    fn cb_moving(&mut self, p: f64) {
        self.status(self.with_encoder(moving(p), p));
    }

    fn cb_encoder(&mut self, p: f64, enc: f64) {
        let mut s = idle(p);
        s.encoder_position = enc;
        s.msta |= msta::PRESENT;
        self.status(s);
    }

    fn with_encoder(&self, mut s: DeviceStatus, enc: f64) -> DeviceStatus {
        if self.encoder {
            s.msta |= msta::PRESENT;
            s.encoder_position = enc;
        }
        s
    }

    fn timer(&mut self) {
        self.clear();
        self.rec.delay_expired();
        self.collect();
    }

    fn f(&self) -> &Fields {
        self.rec.fields()
    }

    fn posted(&self, field: Field) -> Vec<Value> {
        self.posts.iter().filter(|(f, _)| *f == field).map(|(_, v)| v.clone()).collect()
    }

    fn take(&mut self) -> Vec<MotorCommand> {
        std::mem::take(&mut self.sent)
    }
}

fn idle(p: f64) -> DeviceStatus {
    DeviceStatus { position: p, msta: msta::DONE, ..DeviceStatus::default() }
}

fn moving(p: f64) -> DeviceStatus {
    DeviceStatus { position: p, velocity: 100.0, msta: msta::DIRECTION, ..DeviceStatus::default() }
}

/// Baseline B of §19.0.
fn baseline_b() -> Fields {
    Fields { mres: 0.01, velo: 1.0, accl: 0.5, bvel: 0.5, bacc: 0.5, rstm: 0, ..Fields::default() }
}

/// Baseline K of §19.0: the lecture's configuration.
fn baseline_k() -> Fields {
    Fields { mres: 1.0, velo: 10.0, accl: 1.0, bvel: 2.0, bacc: 1.5, bdst: 24.0, rstm: 0, ..Fields::default() }
}

fn move_abs(v: f64, vbase: f64, acc: f64, p: f64) -> Vec<MotorCommand> {
    vec![SetVelocity(v), SetVelBase(vbase), SetAccel(acc), MoveAbs(p), Go]
}

fn approx(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9 * (1.0 + b.abs())
}

fn assert_cmds_close(got: &[MotorCommand], want: &[MotorCommand]) {
    assert_eq!(got.len(), want.len(), "got {got:?}, want {want:?}");
    for (g, w) in got.iter().zip(want) {
        let same = match (g, w) {
            (SetAccel(a), SetAccel(b))
            | (SetVelocity(a), SetVelocity(b))
            | (MoveAbs(a), MoveAbs(b))
            | (MoveRel(a), MoveRel(b)) => approx(*a, *b),
            _ => g == w,
        };
        assert!(same, "got {got:?}, want {want:?}");
    }
}

// ---------------------------------------------------------------- boot and coordinates

#[test]
fn boot_derives_speeds_and_sends_limits() {
    let mut rec = MotorRecord::new(baseline_b());
    assert_eq!(rec.restore_commands(0.0), vec![SetEncRatio(1.0, 1.0)]);
    rec.init(idle(0.0));
    let sent: Vec<_> = rec
        .drain_outputs()
        .filter_map(|o| if let Output::Transaction(t) = o { Some(t) } else { None })
        .flatten()
        .collect();
    assert_eq!(sent, vec![SetHighLimit(0.0), SetLowLimit(0.0)]);
    let f = rec.fields();
    assert_eq!(
        (f.urev, f.s, f.accs, f.sbak, f.rdbd, f.jvel, f.jar, f.hvel),
        (2.0, 0.5, 2.0, 0.25, 0.01, 1.0, 2.0, 0.0)
    );
    assert_eq!((f.dmov, f.lvio, f.stat, f.sevr, f.vers), (1, 0, 0, 0, 7.4));
}

#[test]
fn w60_pair_reconciliation_at_boot() {
    let fields = Fields {
        urev: 5.0,
        srev: 1000,
        mres: 0.0,
        s: 2.0,
        velo: 7.0,
        vbas: 1.0,
        vmax: 20.0,
        accl: 0.0,
        bacc: 0.0,
        ..Fields::default()
    };
    let rig = Rig::boot(fields, 0.0);
    let f = rig.f();
    assert_eq!(f.mres, 0.005);
    assert_eq!((f.velo, f.sbas, f.smax, f.bvel, f.sbak), (10.0, 0.2, 4.0, 1.0, 0.2));
    assert_eq!((f.accl, f.bacc, f.jvel, f.hvel, f.rdbd), (0.1, 0.1, 10.0, 1.0, 0.005));
    assert!(approx(f.accs, 90.0) && approx(f.jar, 100.0), "{} {}", f.accs, f.jar);
    let rig = Rig::boot(Fields { srev: -5, velo: 50.0, vmax: 10.0, ..Fields::default() }, 0.0);
    assert_eq!((rig.f().srev, rig.f().velo), (200, 10.0));
}

#[test]
fn w61_raw_soft_limits_at_boot() {
    let rig = Rig::boot(Fields { mres: 0.01, dhlm: 10.0, dllm: -3.0, rhlm: 500.0, ..Fields::default() }, 0.0);
    let f = rig.f();
    assert!(approx(f.dhlm, 5.0) && approx(f.rllm, -300.0) && approx(f.hlm, 5.0) && approx(f.llm, -3.0));
    let rig = Rig::boot(Fields { mres: -0.01, dhlm: 10.0, dllm: -5.0, ..Fields::default() }, 0.0);
    let f = rig.f();
    assert!(approx(f.rhlm, 500.0) && approx(f.rllm, -1000.0) && f.lvio == 0, "{f:?}");
}

#[test]
fn init_takes_the_controller_position_and_flags_a_readback_outside_the_limits() {
    // W15: controller at 1200 with DHLM 10 ⇒ LVIO 1 at boot.
    let rig = Rig::boot(Fields { dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 1200.0);
    let f = rig.f();
    assert_eq!((f.val, f.dval, f.rval, f.rbv, f.lvio), (12.0, 12.0, 1200, 12.0, 1));
}

#[test]
fn w59_restore_modes() {
    let saved = |rstm| Fields { dval: 12.5, rstm, ..baseline_b() };
    let rec = MotorRecord::new(saved(2));
    assert_eq!(rec.restore_commands(0.0), vec![SetEncRatio(1.0, 1.0), LoadPos(1250.0)]);
    assert_eq!(rec.restore_commands(5.0), vec![SetEncRatio(1.0, 1.0)]);
    assert_eq!(MotorRecord::new(saved(0)).restore_commands(0.0).len(), 1);
    assert_eq!(MotorRecord::new(saved(1)).restore_commands(777.0)[1], LoadPos(1250.0));
    let conditional = |rtry| MotorRecord::new(Fields { urip: 1, rtry, ..saved(3) }).restore_commands(777.0).len();
    assert_eq!((conditional(10), conditional(0)), (2, 1));
}

// ---------------------------------------------------------------- plain moves

#[test]
fn w1_simple_move_with_dmov_pulse() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 100.0));
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(0)]);
    let f = rig.f();
    assert_eq!((f.dval, f.rval, f.mip, f.cdir, f.lval, f.ldvl, f.rdif), (1.0, 100, mip::MOVE, 1, 1.0, 1.0, 100));
    assert_eq!(rig.done_count, 0);
    rig.cb_moving(50.0);
    assert!(rig.take().is_empty());
    assert_eq!(rig.posted(Field::RBV), vec![Value::Float(0.5)]);
    assert_eq!(rig.posted(Field::MOVN), vec![Value::Int(1)]);
    assert!(rig.posted(Field::DMOV).is_empty());
    assert_eq!((rig.f().rrbv, rig.f().drbv), (50, 0.5));
    rig.cb(100.0);
    assert!(rig.take().is_empty());
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(1)]);
    assert_eq!(rig.posted(Field::MOVN), vec![Value::Int(0)]);
    assert_eq!(rig.done_count, 1);
    let f = rig.f();
    assert_eq!((f.mip, f.diff, f.rdif, f.rcnt, f.miss, f.rbv), (0, 0.0, 0, 0, 0, 1.0));
}

#[test]
fn w12_move_to_the_current_position_still_pulses_dmov() {
    let mut rig = Rig::boot(baseline_b(), 100.0);
    rig.put(Field::VAL, 1.004).unwrap();
    assert!(rig.take().is_empty());
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(0), Value::Int(1)]);
    assert_eq!(rig.done_count, 1);
    let f = rig.f();
    assert_eq!((f.rval, f.lval, f.val), (100, 1.004, 1.004));
    // Exactly the current position.
    rig.put(Field::VAL, 1.0).unwrap();
    assert!(rig.take().is_empty());
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(0), Value::Int(1)]);
}

#[test]
fn w13_set_point_deadband() {
    let mut rig = Rig::boot(Fields { spdb: 0.05, ..baseline_b() }, 100.0);
    rig.put(Field::VAL, 1.03).unwrap();
    assert!(rig.take().is_empty());
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(0), Value::Int(1)]);
    rig.put(Field::VAL, 1.06).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 106.0));
}

#[test]
fn w8_w9_w10_tweak_relative_and_raw_requests() {
    let mut rig = Rig::boot(Fields { twv: 0.5, ..baseline_b() }, 100.0);
    rig.put(Field::TWF, 1.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 150.0));
    assert_eq!((rig.f().val, rig.f().twf), (1.5, 0));
    assert_eq!(rig.posted(Field::TWF).last(), Some(&Value::Int(0)));
    rig.cb(150.0);
    rig.put(Field::TWR, 1.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 100.0));
    assert_eq!(rig.f().cdir, 0);
    rig.cb(100.0);

    rig.put(Field::RLV, -0.25).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 75.0));
    assert_eq!((rig.f().val, rig.f().rlv, rig.f().cdir), (0.75, 0.0, 0));
    assert_eq!(rig.posted(Field::RLV).last(), Some(&Value::Float(0.0)));
    rig.cb(75.0);

    rig.put(Field::RVAL, 250.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 250.0));
    assert_eq!((rig.f().dval, rig.f().val), (2.5, 2.5));
}

#[test]
fn w11_dial_write_with_negative_direction_and_offset() {
    let mut rig = Rig::boot(Fields { dir: 1, off: 10.0, ..baseline_b() }, 0.0);
    assert_eq!((rig.f().val, rig.f().hlm, rig.f().llm), (10.0, 10.0, 10.0));
    rig.put(Field::DVAL, 3.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 300.0));
    let f = rig.f();
    assert_eq!((f.val, f.rval, f.cdir), (7.0, 300, 1));
    rig.cb(300.0);
    let f = rig.f();
    assert_eq!((f.drbv, f.rbv, f.dmov), (3.0, 7.0, 1));
    // VAL = DVAL * dirsign + OFF holds when idle.
    assert_eq!(f.val, -f.dval + f.off);
}

#[test]
fn encoder_readback_chain_uses_rep_and_eres() {
    let mut rig = Rig::boot(Fields { ueip: 1, eres: 0.002, ..baseline_b() }, 0.0);
    // No encoder present at boot: UEIP falls back to No.
    assert_eq!(rig.f().ueip, 0);
    rig.put(Field::UEIP, 1.0).unwrap();
    assert_eq!(rig.posted(Field::UEIP).last(), Some(&Value::Int(0)));
    assert_eq!(rig.f().ueip, 0, "refused without EA_PRESENT");
    rig.cb_encoder(10.0, 40.0);
    rig.put(Field::UEIP, 1.0).unwrap();
    rig.cb_encoder(10.0, 40.0);
    let f = rig.f();
    assert_eq!((f.ueip, f.rrbv, f.rep, f.rmp), (1, 40, 40, 10));
    assert!(approx(f.drbv, 0.08) && approx(f.rbv, 0.08));
}

// ---------------------------------------------------------------- backlash (lecture configuration)

#[test]
fn w2_backlash_preferred_direction_outside_range() {
    let mut rig = Rig::boot(baseline_k(), 48.0);
    rig.put(Field::VAL, 96.0).unwrap();
    assert_eq!(rig.take(), move_abs(10.0, 0.0, 10.0, 72.0));
    assert_eq!((rig.f().mip, rig.f().pp, rig.f().cdir), (mip::MOVE, 1, 1));
    rig.cb(72.0);
    assert_cmds_close(&rig.take(), &[SetVelocity(2.0), SetAccel(4.0 / 3.0), MoveAbs(96.0), Go]);
    assert_eq!(rig.f().mip, mip::MOVE_BL);
    assert!(rig.posted(Field::DMOV).is_empty(), "DMOV is not posted between legs");
    rig.cb(96.0);
    assert!(rig.take().is_empty());
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(1)]);
    assert_eq!((rig.f().val, rig.f().dval, rig.f().rval, rig.f().mip), (96.0, 96.0, 96, 0));
}

#[test]
fn w3_w4_w5_w6_backlash_cases() {
    let mut rig = Rig::boot(baseline_k(), 96.0);
    rig.put(Field::VAL, 48.0).unwrap();
    assert_eq!(rig.take(), move_abs(10.0, 0.0, 10.0, 24.0));
    assert_eq!(rig.f().cdir, 0);
    rig.cb(24.0);
    assert_cmds_close(&rig.take(), &[SetVelocity(2.0), SetAccel(4.0 / 3.0), MoveAbs(48.0), Go]);
    assert_eq!((rig.f().cdir, rig.f().mip), (1, mip::MOVE_BL));
    rig.cb(48.0);
    assert_eq!(rig.f().dmov, 1);

    // W4: preferred, inside the backlash range ⇒ one move at BVEL.
    rig.put(Field::VAL, 60.0).unwrap();
    assert_cmds_close(&rig.take(), &[SetVelocity(2.0), SetVelBase(0.0), SetAccel(4.0 / 3.0), MoveAbs(60.0), Go]);
    assert_eq!(rig.f().pp, 0);
    rig.cb(60.0);
    assert_eq!(rig.f().dmov, 1);

    // W5 boundary: 25 steps is case B, 26 steps case C.
    let mut rig = Rig::boot(baseline_k(), 48.0);
    rig.put(Field::VAL, 73.0).unwrap();
    assert_cmds_close(&rig.take(), &[SetVelocity(2.0), SetVelBase(0.0), SetAccel(4.0 / 3.0), MoveAbs(73.0), Go]);
    let mut rig = Rig::boot(baseline_k(), 48.0);
    rig.put(Field::VAL, 74.0).unwrap();
    assert_eq!(rig.take(), move_abs(10.0, 0.0, 10.0, 50.0));

    // W6: identical slew and backlash parameters ⇒ case A.
    let mut rig = Rig::boot(Fields { bvel: 10.0, bacc: 1.0, ..baseline_k() }, 48.0);
    rig.put(Field::VAL, 96.0).unwrap();
    assert_eq!(rig.take(), move_abs(10.0, 0.0, 10.0, 96.0));
}

#[test]
fn w7_negative_backlash_distance() {
    let mut rig = Rig::boot(Fields { bdst: -24.0, ..baseline_k() }, 96.0);
    rig.put(Field::VAL, 48.0).unwrap();
    assert_eq!(rig.take(), move_abs(10.0, 0.0, 10.0, 72.0));
    assert_eq!(rig.f().cdir, 0);
    rig.cb(72.0);
    assert_cmds_close(&rig.take(), &[SetVelocity(2.0), SetAccel(4.0 / 3.0), MoveAbs(48.0), Go]);
    assert_eq!(rig.f().cdir, 0);
    rig.cb(48.0);
    assert_eq!(rig.f().dmov, 1);
}

// ---------------------------------------------------------------- soft limits

#[test]
fn w14_request_outside_the_limits_moves_nothing_and_restores_targets() {
    let mut rig = Rig::boot(Fields { dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 500.0);
    let f = rig.f();
    assert_eq!((f.rhlm, f.rllm, f.hlm, f.llm, f.lvio), (1000.0, -1000.0, 10.0, -10.0, 0));
    let err = rig.put(Field::VAL, 12.0).unwrap_err();
    assert!(matches!(err, WriteError::NotActedUpon { .. }), "{err}");
    assert!(rig.take().is_empty());
    let f = rig.f();
    assert_eq!((f.lvio, f.val, f.dval, f.rval), (1, 5.0, 5.0, 500));
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(0), Value::Int(1)]);
    assert_eq!(rig.posted(Field::VAL), vec![Value::Float(5.0)]);
    rig.put(Field::VAL, 9.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 900.0));
    assert_eq!(rig.f().lvio, 0);
}

#[test]
fn w15_moving_back_towards_the_valid_range_is_allowed() {
    let mut rig = Rig::boot(Fields { dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 1200.0);
    assert!(rig.put(Field::VAL, 13.0).is_err());
    assert_eq!(rig.f().val, 12.0);
    rig.put(Field::VAL, 11.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 1100.0));
    assert_eq!((rig.f().lvio, rig.f().cdir), (0, 0));
}

#[test]
fn limits_stay_consistent_in_user_dial_and_raw() {
    // W52 (a): DIR Neg, OFF 1.
    let mut rig = Rig::boot(Fields { dir: 1, off: 1.0, dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 0.0);
    assert_eq!((rig.f().hlm, rig.f().llm), (11.0, -9.0));
    rig.put(Field::HLM, 5.0).unwrap();
    assert_eq!(rig.take(), vec![SetLowLimit(-400.0), GetInfo]);
    let f = rig.f();
    assert_eq!((f.dllm, f.rllm, f.llm), (-4.0, -400.0, -9.0));
    // W52 (b): MRES negative.
    let mut rig = Rig::boot(Fields { mres: -0.01, dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 0.0);
    rig.put(Field::HLM, 5.0).unwrap();
    assert_eq!(rig.take(), vec![SetLowLimit(-500.0), GetInfo]);
    assert_eq!((rig.f().dhlm, rig.f().rllm), (5.0, -500.0));
    // While the status refresh is outstanding (STUP BUSY) a put triggers no second refresh.
    rig.put(Field::DLLM, -4.0).unwrap();
    assert_eq!(rig.take(), vec![SetHighLimit(400.0)]);
    rig.cb(0.0);
    rig.put(Field::DLLM, -4.0).unwrap();
    assert_eq!(rig.take(), vec![SetHighLimit(400.0), GetInfo]);
    assert_eq!((rig.f().rhlm, rig.f().llm), (400.0, -4.0));
    // Dial limit writes follow into user limits with DIR Pos and an offset.
    let mut rig = Rig::boot(Fields { off: 2.0, ..baseline_b() }, 0.0);
    rig.put(Field::DHLM, 7.0).unwrap();
    assert_eq!(rig.take(), vec![SetHighLimit(700.0), GetInfo]);
    assert_eq!((rig.f().hlm, rig.f().rhlm), (9.0, 700.0));
}

// ---------------------------------------------------------------- switches

#[test]
fn w30_move_onto_the_plus_limit_switch() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 10.0).unwrap();
    rig.status(DeviceStatus { msta: msta::DIRECTION | msta::PLUS_LS, ..moving(300.0) });
    assert_eq!(rig.take(), vec![GetInfo]);
    let f = rig.f();
    assert_eq!((f.mip, f.dmov, f.hls, f.rhls, f.movn), (0, 0, 1, 1, 0));
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS, ..idle(302.0) });
    let f = rig.f();
    assert_eq!((f.val, f.dval, f.dmov, f.rcnt), (3.02, 3.02, 1, 0));
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(1)]);
}

#[test]
fn limit_switches_map_to_user_sense() {
    let mut rig = Rig::boot(Fields { dir: 1, ..baseline_b() }, 0.0);
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS, ..idle(0.0) });
    assert_eq!((rig.f().rhls, rig.f().hls, rig.f().lls), (1, 0, 1));
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.status(DeviceStatus { msta: msta::DONE | msta::MINUS_LS | msta::HOME, ..idle(0.0) });
    assert_eq!((rig.f().rlls, rig.f().lls, rig.f().hls, rig.f().athm), (1, 1, 0, 1));
}

// ---------------------------------------------------------------- STOP and SPMG

#[test]
fn w34_stop_during_a_move_syncs_targets_to_the_readback() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 5.0).unwrap();
    rig.cb_moving(100.0);
    rig.put(Field::STOP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().mip, rig.f().stop), (mip::STOP, 0));
    assert_eq!(rig.posted(Field::STOP).last(), Some(&Value::Int(0)));
    rig.cb(130.0);
    let f = rig.f();
    assert_eq!((f.val, f.dval, f.rval, f.mip, f.dmov, f.rcnt), (1.3, 1.3, 130, 0, 1, 0));
    assert!(rig.take().is_empty());
}

#[test]
fn stop_while_idle_only_sends_stop() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::STOP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().mip, rig.f().dmov), (0, 1));
}

#[test]
fn w37_move_mode_pauses_after_each_motion() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::SPMG, 1.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!(rig.f().mip, mip::STOP);
    rig.put(Field::VAL, 2.0).unwrap();
    assert!(rig.take().is_empty());
    assert_eq!(rig.f().dmov, 0);
    rig.put(Field::SPMG, 2.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 200.0));
    rig.cb(200.0);
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!((rig.f().dmov, rig.f().spmg, rig.f().mip), (1, 1, mip::STOP));
    assert_eq!(rig.posted(Field::SPMG), vec![Value::Int(1)]);
    rig.put(Field::VAL, 3.0).unwrap();
    assert!(rig.take().is_empty());
}

#[test]
fn w38_stop_then_go() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 5.0).unwrap();
    rig.cb_moving(100.0);
    rig.put(Field::SPMG, 0.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    rig.cb(130.0);
    assert_eq!((rig.f().val, rig.f().dmov), (1.3, 1));
    rig.put(Field::SPMG, 3.0).unwrap();
    assert_eq!(rig.take(), vec![GetInfo]);
}

#[test]
fn a_target_written_while_stopped_is_held_then_executed_on_go() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::SPMG, 0.0).unwrap();
    rig.take();
    rig.put(Field::VAL, 2.0).unwrap();
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().dmov, rig.f().dval), (0, 2.0));
    rig.put(Field::SPMG, 3.0).unwrap();
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 200.0));
}

// ---------------------------------------------------------------- retries, NTM, DLY

#[test]
fn w16_w17_encoder_retries_with_relative_moves() {
    let encoder = Fields { ueip: 1, eres: 0.01, rtry: 3, rdbd: 0.02, ..baseline_b() };
    let mut rig = Rig::boot(encoder.clone(), 0.0);
    rig.encoder = true;
    rig.cb(0.0);
    rig.put(Field::UEIP, 1.0).unwrap();
    rig.cb(0.0); // the status refresh the UEIP put asked for
    rig.put(Field::VAL, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelocity(100.0), SetVelBase(0.0), SetAccel(200.0), MoveRel(100.0), Go]);
    rig.cb_encoder(100.0, 95.0);
    assert_cmds_close(&rig.take(), &[SetVelocity(100.0), SetVelBase(0.0), SetAccel(200.0), MoveRel(5.0), Go]);
    assert_eq!((rig.f().rcnt, rig.f().mip, rig.f().dmov), (1, mip::RETRY | mip::MOVE, 0));
    rig.cb_encoder(105.0, 99.0);
    assert_eq!((rig.f().mip, rig.f().dmov, rig.f().rcnt, rig.f().miss), (0, 1, 1, 0));

    let mut rig = Rig::boot(Fields { rtry: 2, ..encoder }, 0.0);
    rig.encoder = true;
    rig.cb(0.0);
    rig.put(Field::UEIP, 1.0).unwrap();
    rig.cb(0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    for expected_rcnt in 1..=2 {
        rig.cb_encoder(100.0, 95.0);
        assert_cmds_close(&rig.take(), &[SetVelocity(100.0), SetVelBase(0.0), SetAccel(200.0), MoveRel(5.0), Go]);
        assert_eq!(rig.f().rcnt, expected_rcnt);
    }
    rig.cb_encoder(100.0, 95.0);
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().rcnt, rig.f().miss, rig.f().mip, rig.f().dmov), (3, 1, 0, 1));
}

#[test]
fn w21_frac_absolute() {
    let fields = Fields { mres: 1.0, velo: 10.0, accl: 1.0, frac: 0.5, ..Fields { rstm: 0, ..Fields::default() } };
    let mut rig = Rig::boot(fields.clone(), 0.0);
    rig.put(Field::VAL, 10.0).unwrap();
    assert_eq!(rig.take(), move_abs(10.0, 0.0, 10.0, 5.0));
    rig.cb(5.0);
    assert_eq!(rig.take(), move_abs(10.0, 0.0, 10.0, 10.0));
    assert_eq!((rig.f().rcnt, rig.f().mip), (1, mip::RETRY | mip::MOVE));
    rig.cb(10.0);
    assert_eq!(rig.f().dmov, 1);
    let mut rig = Rig::boot(Fields { rtry: 0, ..fields }, 0.0);
    rig.put(Field::VAL, 10.0).unwrap();
    rig.cb(5.0);
    assert_eq!((rig.f().dmov, rig.f().dval, rig.f().diff, rig.f().miss), (1, 10.0, 5.0, 0));
}

#[test]
fn w39_w41_new_target_behind_the_motor() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::VAL, 10.0).unwrap();
    rig.cb_moving(500.0);
    rig.put(Field::VAL, 2.0).unwrap();
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().val, rig.f().dval, rig.f().lval, rig.f().ldvl), (2.0, 2.0, 10.0, 10.0));
    rig.cb_moving(510.0);
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!(rig.f().mip, mip::STOP | mip::MOVE);
    rig.cb(530.0);
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 200.0));
    assert_eq!((rig.f().mip, rig.f().cdir, rig.f().dmov, rig.f().rcnt), (mip::RETRY | mip::MOVE, 0, 0, 1));
    rig.cb(200.0);
    assert_eq!((rig.f().dmov, rig.f().rcnt), (1, 1));

    let mut rig = Rig::boot(Fields { rtry: 0, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 10.0).unwrap();
    rig.cb_moving(500.0);
    rig.put(Field::VAL, 2.0).unwrap();
    rig.cb_moving(510.0);
    rig.cb(530.0);
    assert_eq!(rig.take(), move_abs(100.0, 0.0, 200.0, 200.0));
    assert_eq!((rig.f().rcnt, rig.f().mip, rig.f().dmov), (0, mip::MOVE, 0));
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(0)]);
}

#[test]
fn w44_settling_delay() {
    let mut rig = Rig::boot(Fields { dly: 1.0, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 1.0).unwrap();
    rig.cb(100.0);
    assert!(rig.take().is_empty());
    assert_eq!(rig.delays, vec![1.0]);
    assert_eq!((rig.f().mip, rig.f().dmov, rig.done_count), (mip::MOVE | mip::DELAY_REQ, 0, 0));
    rig.cb(100.0);
    assert!(rig.take().is_empty() && rig.delays.is_empty());
    assert_eq!(rig.f().dmov, 0);
    rig.timer();
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!(rig.f().mip, mip::MOVE | mip::DELAY_REQ | mip::DELAY_ACK);
    assert_eq!(rig.done_count, 0);
    rig.cb(100.0);
    assert_eq!((rig.f().mip, rig.f().dmov, rig.done_count), (0, 1, 1));
}

// ---------------------------------------------------------------- calibration, speeds, status

#[test]
fn w45_set_mode_val_write_redefines_the_offset() {
    let mut rig = Rig::boot(Fields { dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 200.0);
    rig.put(Field::SSET, 1.0).unwrap();
    assert_eq!(rig.posted(Field::SET), vec![Value::Int(1)]);
    rig.put(Field::VAL, 5.0).unwrap();
    assert!(rig.take().is_empty());
    let f = rig.f();
    assert_eq!((f.off, f.rbv, f.hlm, f.llm, f.dval), (3.0, 5.0, 13.0, -7.0, 2.0));
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(0), Value::Int(1)]);
}

#[test]
fn w51_dir_and_off_writes_move_nothing() {
    let mut rig = Rig::boot(Fields { off: 2.0, ..baseline_b() }, 300.0);
    assert_eq!(rig.f().val, 5.0);
    rig.put(Field::DIR, 1.0).unwrap();
    assert_eq!(rig.take(), vec![GetInfo]);
    let f = rig.f();
    assert_eq!((f.off, f.val, f.rbv, f.hlm, f.llm), (8.0, 5.0, 5.0, 8.0, 8.0));
    let mut rig = Rig::boot(Fields { off: 2.0, foff: 1, ..baseline_b() }, 300.0);
    rig.put(Field::DIR, 1.0).unwrap();
    assert_eq!((rig.f().val, rig.f().rbv, rig.f().off), (-1.0, -1.0, 2.0));
    let mut rig = Rig::boot(Fields { dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 300.0);
    rig.put(Field::OFF, 5.0).unwrap();
    assert_eq!(rig.take(), vec![GetInfo]);
    let f = rig.f();
    assert_eq!((f.val, f.rbv, f.hlm, f.llm), (8.0, 8.0, 15.0, -5.0));
}

#[test]
fn w48_mres_change_keeps_raw_limits_and_reloads_the_position() {
    let mut rig = Rig::boot(Fields { dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 100.0);
    rig.put(Field::MRES, 0.02).unwrap();
    assert_eq!(rig.take(), vec![LoadPos(50.0), GetInfo]);
    let f = rig.f();
    assert_eq!((f.urev, f.velo, f.bvel, f.dhlm, f.dllm, f.hlm, f.llm), (4.0, 2.0, 1.0, 20.0, -20.0, 20.0, -20.0));
    assert_eq!((f.rhlm, f.rllm, f.rdbd, f.mip, f.dmov, f.accs), (1000.0, -1000.0, 0.02, mip::LOAD_P, 0, 2.0));
    rig.cb(50.0);
    assert_eq!((rig.f().dmov, rig.f().mip), (1, 0));
}

#[test]
fn w50_srev_change() {
    let mut rig = Rig::boot(Fields { dhlm: 10.0, ..baseline_b() }, 100.0);
    rig.put(Field::SREV, 400.0).unwrap();
    assert_eq!(rig.take(), vec![LoadPos(200.0), GetInfo]);
    let f = rig.f();
    assert_eq!((f.mres, f.urev, f.velo, f.s, f.rhlm, f.dhlm), (0.005, 2.0, 1.0, 0.5, 1000.0, 10.0));
}

#[test]
fn w56_velocity_clamps_keep_pairs_consistent() {
    let mut rig = Rig::boot(Fields { vbas: 1.0, vmax: 5.0, velo: 3.0, bvel: 2.0, ..baseline_b() }, 0.0);
    let f = rig.f();
    assert_eq!((f.s, f.sbas, f.smax, f.accs, f.jvel, f.hvel), (1.5, 0.5, 2.5, 4.0, 3.0, 1.0));
    rig.put(Field::VELO, 10.0).unwrap();
    assert_eq!((rig.f().velo, rig.f().s, rig.f().accs), (5.0, 2.5, 8.0));
    assert!(rig.take().is_empty(), "VELO does not process the record");
    rig.put(Field::VBAS, 8.0).unwrap();
    let f = rig.f();
    assert_eq!(
        (f.sbas, f.vmax, f.smax, f.velo, f.s, f.bvel, f.sbak, f.jvel, f.hvel, f.accs),
        (4.0, 8.0, 4.0, 8.0, 4.0, 8.0, 4.0, 8.0, 8.0, 10.0)
    );
    rig.put(Field::VMAX, 4.0).unwrap();
    let f = rig.f();
    assert_eq!((f.smax, f.vbas, f.sbas, f.velo, f.bvel, f.jvel, f.hvel), (2.0, 4.0, 2.0, 4.0, 4.0, 4.0, 4.0));
    // Rev/s members drive their EGU/s pairs.
    rig.put(Field::S, 1.0).unwrap();
    assert_eq!((rig.f().s, rig.f().velo), (2.0, 4.0), "S clamped to [SBAS, SMAX]");
    rig.put(Field::SMAX, 3.0).unwrap();
    assert_eq!(rig.f().vmax, 6.0);
    rig.put(Field::UREV, 4.0).unwrap();
    assert_eq!((rig.f().mres, rig.f().vmax, rig.f().velo), (0.02, 12.0, 8.0));
}

#[test]
fn w57_acceleration_pairs() {
    let mut rig = Rig::boot(Fields { velo: 10.0, accs: 20.0, accu: 1, ..baseline_b() }, 0.0);
    assert_eq!(rig.f().accl, 0.5);
    rig.put(Field::VAL, 1.0).unwrap();
    assert_eq!(rig.take(), move_abs(1000.0, 0.0, 2000.0, 100.0));
    rig.cb(100.0);
    rig.put(Field::VELO, 5.0).unwrap();
    assert_eq!(rig.f().accl, 0.25);
    rig.put(Field::ACCL, 2.0).unwrap();
    assert_eq!(rig.f().accs, 2.5);
    rig.put(Field::ACCL, -1.0).unwrap();
    assert_eq!(rig.f().accl, 0.1);
}

#[test]
fn w53_status_update_requests() {
    let mut rig = Rig::boot(baseline_b(), 0.0);
    rig.put(Field::STUP, 1.0).unwrap();
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!(rig.f().stup, 2);
    assert!(matches!(rig.put(Field::STUP, 1.0), Err(WriteError::Refused { .. })));
    rig.cb(0.0);
    assert_eq!(rig.f().stup, 0);
    assert!(matches!(rig.put(Field::STUP, 0.0), Err(WriteError::Adjusted { .. })));
    assert!(rig.take().is_empty());
    rig.put(Field::HLSV, 0.0).unwrap();
    assert_eq!(rig.take(), vec![GetInfo]);
    assert_eq!(rig.f().stup, 2);
}

#[test]
fn w54_sync_and_w55_external_motion() {
    let mut rig = Rig::boot(Fields { rtry: 0, ..baseline_b() }, 0.0);
    rig.put(Field::VAL, 2.0).unwrap();
    rig.cb(150.0);
    assert_eq!((rig.f().dmov, rig.f().dval, rig.f().drbv), (1, 2.0, 1.5));
    rig.put(Field::SYNC, 1.0).unwrap();
    assert!(rig.take().is_empty());
    assert_eq!((rig.f().val, rig.f().dval, rig.f().rval, rig.f().sync), (1.5, 1.5, 150, 0));

    let mut rig = Rig::boot(baseline_b(), 100.0);
    rig.cb_moving(150.0);
    assert_eq!(rig.posted(Field::DMOV), vec![Value::Int(0)]);
    assert_eq!((rig.f().mip, rig.f().val), (mip::EXTERNAL, 1.0));
    rig.cb(200.0);
    assert_eq!((rig.f().val, rig.f().dval, rig.f().mip, rig.f().dmov), (2.0, 2.0, 0, 1));
}

#[test]
fn alarms_follow_limits_and_driver_problems() {
    let mut rig = Rig::boot(Fields { hlsv: 2, dhlm: 10.0, dllm: -10.0, ..baseline_b() }, 0.0);
    assert_eq!((rig.f().stat, rig.f().sevr), (0, 0));
    rig.status(DeviceStatus { msta: msta::DONE | msta::PLUS_LS, ..idle(0.0) });
    assert_eq!((rig.f().stat, rig.f().sevr), (4, 2));
    assert_eq!(rig.posted(Field::SEVR), vec![Value::Int(2)]);
    rig.cb(0.0);
    assert_eq!((rig.f().stat, rig.f().sevr), (0, 0));
    rig.status(DeviceStatus { msta: msta::DONE | msta::PROBLEM, ..idle(0.0) });
    assert_eq!((rig.f().stat, rig.f().sevr), (7, 2));
    rig.status(DeviceStatus { msta: msta::DONE | msta::COMM_ERR, ..idle(0.0) });
    assert_eq!((rig.f().stat, rig.f().sevr), (9, 3));
    // Departure Z18: the reference clears the bit; zmotor keeps it for clients to see why.
    assert_ne!(rig.f().msta & msta::COMM_ERR, 0, "MSTA shows the comm error");
}

#[test]
fn read_only_fields_and_busy_homes_are_refused_without_change() {
    let mut rig = Rig::boot(Fields { hvel: 0.5, ..baseline_b() }, 123.0);
    assert_eq!(rig.put(Field::RBV, 3.0), Err(WriteError::ReadOnly(Field::RBV)));
    assert_eq!(rig.put(Field::DMOV, 0.0), Err(WriteError::ReadOnly(Field::DMOV)));
    assert_eq!(rig.f().dmov, 1);
    rig.put(Field::HOMF, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelocity(50.0), SetVelBase(0.0), SetAccel(100.0), HomeFor, Go]);
    assert!(matches!(rig.put(Field::HOMF, 1.0), Err(WriteError::Refused { .. })));
    rig.cb(0.0);
    assert_eq!((rig.f().homf, rig.f().mip, rig.f().dmov, rig.f().val), (0, 0, 1, 0.0));
}

#[test]
fn w25_jog_forward_with_backlash() {
    let mut rig = Rig::boot(Fields { jvel: 2.0, jar: 4.0, bdst: 0.5, dhlm: 100.0, dllm: -100.0, ..baseline_b() }, 0.0);
    rig.put(Field::JOGF, 1.0).unwrap();
    assert_eq!(rig.take(), vec![SetVelBase(0.0), SetAccel(400.0), Jog(200.0)]);
    assert_eq!((rig.f().mip, rig.f().dmov, rig.f().cdir), (mip::JOGF, 0, 1));
    rig.cb_moving(150.0);
    assert!(rig.take().is_empty());
    rig.put(Field::JOGF, 0.0).unwrap();
    assert_eq!(rig.take(), vec![StopAxis]);
    assert_eq!(rig.f().mip, mip::JOG_STOP);
    rig.cb(310.0);
    assert_cmds_close(&rig.take(), &move_abs(100.0, 0.0, 200.0, 260.0));
    assert_eq!((rig.f().val, rig.f().mip), (3.1, mip::JOG_BL1));
    rig.cb(260.0);
    assert_cmds_close(&rig.take(), &[SetVelocity(50.0), SetAccel(100.0), MoveAbs(310.0), Go]);
    assert_eq!(rig.f().mip, mip::JOG_BL2);
    rig.cb(310.0);
    assert_eq!((rig.f().mip, rig.f().dmov), (0, 1));
}
