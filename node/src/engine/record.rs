//! The motor record as a pure state machine. Section numbers (§) refer to
//! ../shared/spec/motor-record-behaviour.md, which this file follows step by step:
//! `process` is §8, `do_work` §9, `post_process` §10, `maybe_retry` §11, `alarm` §12,
//! `monitor` §13; helpers are §5, initialisation §6 and field writes §7.
//!
//! Inputs: `write` (a field put), `callback` (fresh device status), `delay_expired` (DLY timer).
//! Outputs: `Output`s (monitor posts, device transactions, timer requests, completion), drained
//! by the caller. The engine never reads a clock and performs no I/O.

use super::commands::{DeviceStatus, MotorCommand, Output, WriteError};
use super::marks::Marks;
use super::maths::{nint, MoveMaths};
use zmotor_msgs::bits::{mip, msta};
use zmotor_msgs::menus::{choice, severity, status};
use zmotor_msgs::{Access, Field, Fields, Value};

/// Record version reported in VERS.
const VERSION: f32 = 7.4;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Reason {
    NothingDone,
    Callback,
}

/// Where §8 continues after the callback part.
enum Flow {
    DoWork,
    Exit,
}

/// One motor record.
#[derive(Clone, Debug)]
pub struct MotorRecord {
    f: Fields,
    marks: Marks,
    outputs: Vec<Output>,
    /// Device data delivered by `callback`, consumed by the next `update_values`.
    pending_status: Option<DeviceStatus>,
    /// Why the last move request was refused, reported to the writer.
    refusal: Option<String>,
    /// Departure Z9: a move was paused; its target is held and resumed by Go or Move.
    resume_on_go: bool,
    /// The latest value of the RDBL readback link (None: not readable).
    readback_link: Option<f64>,
    /// The latest value of the DOL desired-output link (None: not readable yet).
    desired: Option<f64>,
    /// Whether the device answers GET_INFO (Soft Channel does not).
    status_refresh: bool,
}

impl MotorRecord {
    /// A record with the given configured field values; `check_speed_and_resolution` and
    /// `enforce_min_rdbd` (§6.2 steps 3–4) run here. Call `restore_commands` and `init` next.
    pub fn new(mut fields: Fields) -> Self {
        fields.vers = VERSION;
        let mut record = Self {
            f: fields,
            marks: Marks::default(),
            outputs: Vec::new(),
            pending_status: None,
            refusal: None,
            resume_on_go: false,
            readback_link: None,
            desired: None,
            status_refresh: true,
        };
        record.check_speed_and_resolution();
        record.enforce_min_rdbd();
        record.outputs.clear();
        record
    }

    /// Soft Channel device support refuses GET_INFO, so STUP snaps back to OFF.
    pub fn without_status_refresh(mut self) -> Self {
        self.status_refresh = false;
        self
    }

    /// A new value of the DOL link: in closed-loop mode it becomes the target (a processing).
    pub fn desired_value(&mut self, value: f64) {
        self.desired = Some(value);
        if self.f.omsl == choice::OMSL_CLOSED_LOOP {
            self.process();
        }
    }

    /// Soft Channel: the driven motor moved on its own (or the first readback arrived): the
    /// target will be re-synchronised at the next completion (§16.2).
    pub fn external_motion(&mut self) {
        self.f.dmov = 0;
        self.post(Field::DMOV);
        self.f.pp = 1;
        self.post(Field::PP);
    }

    pub fn fields(&self) -> &Fields {
        &self.f
    }

    pub fn get(&self, field: Field) -> Value {
        self.f.get(field)
    }

    /// Take everything the engine produced since the last call.
    pub fn drain_outputs(&mut self) -> std::vec::Drain<'_, Output> {
        self.outputs.drain(..)
    }

    // ------------------------------------------------------------------ §6 initialisation

    /// §6.4 step 3–4: what device support writes before the record reads any status: the encoder
    /// ratio, and the restored dial position if RSTM says so. `controller_steps` is the motor
    /// position the controller reports at boot.
    pub fn restore_commands(&self, controller_steps: f64) -> Vec<MotorCommand> {
        let f = &self.f;
        let mut cmds = vec![if f.eres == 0.0 {
            MotorCommand::SetEncRatio(1.0, 1.0)
        } else {
            MotorCommand::SetEncRatio(f.mres, f.eres)
        }];
        let rdbd_eff = f.rdbd.abs().max(f.mres.abs());
        let use_rel = f.rtry != 0 && f.rmod != choice::RMOD_IN_POSITION && (f.ueip != 0 || f.urip != 0);
        let near_zero = f.dval.abs() > rdbd_eff && f.mres != 0.0 && (controller_steps * f.mres).abs() < rdbd_eff;
        let load = match f.rstm {
            1 => true,
            2 => near_zero,
            3 => near_zero || use_rel,
            _ => false,
        };
        if load {
            cmds.push(MotorCommand::LoadPos(f.dval / f.mres));
        }
        cmds
    }

    /// §6.2 steps 6–14, with the first status read from the device.
    pub fn init(&mut self, status: DeviceStatus) {
        self.f.udf = 0; // DOL is a constant link: the normal case
        self.pending_status = Some(status);
        self.update_values();
        if self.f.eres == 0.0 {
            self.f.eres = self.f.mres;
        }
        self.process_motor_info(true);
        if self.f.omsl != choice::OMSL_CLOSED_LOOP {
            self.f.val = self.f.rbv;
            self.f.dval = self.f.drbv;
            self.f.rval = nint(self.f.dval / self.f.mres);
        }
        self.set_dial_limit(true);
        self.set_dial_limit(false);
        let f = &mut self.f;
        f.dmov = 1;
        f.movn = 0;
        f.spmg = choice::SPMG_GO;
        f.lspg = choice::SPMG_GO;
        f.diff = f.dval - f.drbv;
        f.rdif = nint(f.diff / f.mres);
        f.lval = f.val;
        f.ldvl = f.dval;
        f.lrvl = f.rval;
        self.f.lvio = i16::from(self.readback_violates_limits());
        self.mark(Field::MSTA);
        for field in [Field::VAL, Field::DVAL, Field::RVAL, Field::DMOV, Field::LVIO, Field::DIFF, Field::RDIF] {
            self.mark(field);
        }
        let alarm_changed = self.alarm();
        self.monitor(alarm_changed);
    }

    /// §6.3
    fn check_speed_and_resolution(&mut self) {
        let f = &mut self.f;
        if f.srev <= 0 {
            f.srev = 200;
        }
        if f.urev != 0.0 {
            f.mres = f.urev / f64::from(f.srev);
        }
        if f.mres == 0.0 {
            f.mres = 1.0;
        }
        if f.urev != f.mres * f64::from(f.srev) {
            f.urev = f.mres * f64::from(f.srev);
        }
        let u = f.urev.abs();
        if f.smax > 0.0 {
            f.vmax = f.smax * u;
        } else if f.vmax > 0.0 {
            f.smax = f.vmax / u;
        } else {
            f.smax = 0.0;
            f.vmax = 0.0;
        }
        if f.sbas != 0.0 {
            self.range_check(Field::SBAS, 0.0, self.f.smax);
            self.f.vbas = self.f.sbas * u;
        } else {
            self.range_check(Field::VBAS, 0.0, self.f.vmax);
            self.f.sbas = self.f.vbas / u;
        }
        if self.f.s != 0.0 {
            self.range_check(Field::S, self.f.sbas, self.f.smax);
            self.f.velo = self.f.s * u;
        } else {
            self.range_check(Field::VELO, self.f.vbas, self.f.vmax);
            self.f.s = self.f.velo / u;
        }
        // Raw limits win at boot. Departure Z3: with MRES < 0 the raw low limit is the dial high
        // limit with its sign (the reference drops the sign, Q3).
        let f = &mut self.f;
        let (raw_for_high, raw_for_low) = if f.mres > 0.0 { (f.rhlm, f.rllm) } else { (f.rllm, f.rhlm) };
        if raw_for_high != 0.0 {
            f.dhlm = raw_for_high * f.mres;
        }
        if raw_for_low != 0.0 {
            f.dllm = raw_for_low * f.mres;
        }
        (f.rhlm, f.rllm) =
            if f.mres > 0.0 { (f.dhlm / f.mres, f.dllm / f.mres) } else { (f.dllm / f.mres, f.dhlm / f.mres) };
        if self.f.sbak != 0.0 {
            self.range_check(Field::SBAK, self.f.sbas, self.f.smax);
            self.f.bvel = self.f.sbak * u;
        } else {
            self.range_check(Field::BVEL, self.f.vbas, self.f.vmax);
            self.f.sbak = self.f.bvel / u;
        }
        if self.f.accs > 0.0 {
            self.accl_from_accs();
        } else {
            if self.f.accl == 0.0 {
                self.f.accl = 0.1;
            }
            self.accs_from_accl();
        }
        let f = &mut self.f;
        if f.bacc == 0.0 {
            f.bacc = 0.1;
        }
        if f.jvel == 0.0 {
            f.jvel = f.velo;
        } else {
            self.range_check(Field::JVEL, self.f.vbas, self.f.vmax);
        }
        let f = &mut self.f;
        if f.jar == 0.0 {
            f.jar = f.velo / f.accl;
        }
        if f.hvel == 0.0 {
            f.hvel = f.vbas;
        } else {
            self.range_check(Field::HVEL, self.f.vbas, self.f.vmax);
        }
    }

    // ------------------------------------------------------------------ inputs

    /// A put to a field (§0.1 and §7): refused when read-only or when special() says so,
    /// otherwise stored, handled, posted and (for process-passive fields) processed.
    pub fn write(&mut self, field: Field, value: &Value) -> Result<(), WriteError> {
        let access = field.def().access;
        if access == Access::RO {
            return Err(WriteError::ReadOnly(field));
        }
        self.special_before(field, value)?;
        self.f.set(field, value);
        if field == Field::VAL {
            self.f.udf = 0;
        }
        if let Err(e) = self.special_after(field) {
            // Stored, but no post and no processing (§0.1 step 5).
            self.flush_posts();
            return Err(e);
        }
        if field != Field::VAL {
            self.post(field);
        }
        self.refusal = None;
        if access == Access::PP {
            self.process();
        } else {
            self.flush_posts();
        }
        match self.refusal.take() {
            Some(reason) => Err(WriteError::NotActedUpon(reason)),
            None => Ok(()),
        }
    }

    /// Fresh status from the device: a callback processing.
    pub fn callback(&mut self, status: DeviceStatus) {
        self.pending_status = Some(status);
        self.process();
    }

    /// The DLY timer fired (§5.11).
    pub fn delay_expired(&mut self) {
        if self.f.mip & mip::DELAY_REQ != 0 {
            self.f.mip = (self.f.mip & !mip::DELAY_REQ) | mip::DELAY_ACK;
            self.process();
        }
    }

    // ------------------------------------------------------------------ §7 special()

    // One arm per field, as the table of §7 reads; guards folded into patterns would hide it.
    #[allow(clippy::collapsible_match)]
    fn special_before(&mut self, field: Field, value: &Value) -> Result<(), WriteError> {
        use Field::*;
        match field {
            VAL | DVAL | RVAL | RLV | TWF | TWR => {
                // Departure Z12: the reference accepts a target during the backlash takeout after
                // a jog and then forgets it, leaving VAL away from the position; refuse it instead.
                if self.f.mip & (mip::JOG_STOP | mip::JOG_BL1 | mip::JOG_BL2) != 0 {
                    return Err(WriteError::Refused {
                        field,
                        reason: "a jog is finishing its backlash takeout; write the target once DMOV is 1".into(),
                    });
                }
                if self.f.dmov == 1 {
                    self.f.dmov = 0;
                    self.post(DMOV);
                }
            }
            HOMF | HOMR if self.f.mip & mip::HOME_GROUP != 0 => {
                return Err(WriteError::Refused { field, reason: "a home is in progress".into() });
            }
            // Departure Z15: as the manual says, writing 0 is an error (the reference accepts
            // it, D7); a home is aborted with STOP.
            HOMF | HOMR if value.as_f64() == Some(0.0) => {
                return Err(WriteError::Refused {
                    field,
                    reason: "writing 0 does not abort a home; write STOP 1".into(),
                });
            }
            STUP if self.f.stup != choice::STUP_OFF => {
                return Err(WriteError::Refused { field, reason: "a status update is in progress".into() });
            }
            _ => {}
        }
        Ok(())
    }

    #[allow(clippy::collapsible_match)]
    fn special_after(&mut self, field: Field) -> Result<(), WriteError> {
        use Field::*;
        match field {
            VBAS | SBAS => {
                self.clamp_negative(field);
                self.follow_speed_pair(field, VBAS, SBAS);
                self.acc_pair_from_velo();
                if self.f.vmax != 0.0 && self.f.vbas > self.f.vmax {
                    self.f.vmax = self.f.vbas;
                    self.post(VMAX);
                    self.f.smax = self.f.sbas;
                    self.post(SMAX);
                }
                self.recheck_velocities();
            }
            VMAX | SMAX => {
                self.clamp_negative(field);
                self.follow_speed_pair(field, VMAX, SMAX);
                if self.f.vmax != 0.0 && self.f.vmax < self.f.vbas {
                    self.f.vbas = self.f.vmax;
                    self.mark(VBAS);
                    self.f.sbas = self.f.smax;
                    self.mark(SBAS);
                }
                self.recheck_velocities();
            }
            VELO => {
                self.range_check(VELO, self.f.vbas, self.f.vmax);
                self.acc_pair_from_velo();
                self.follow_speed_pair(VELO, VELO, S);
            }
            S => {
                self.range_check(S, self.f.sbas, self.f.smax);
                self.follow_speed_pair(S, VELO, S);
                self.acc_pair_from_velo();
            }
            BVEL => {
                self.range_check(BVEL, self.f.vbas, self.f.vmax);
                self.follow_speed_pair(BVEL, BVEL, SBAK);
            }
            SBAK => {
                self.range_check(SBAK, self.f.sbas, self.f.smax);
                self.follow_speed_pair(SBAK, BVEL, SBAK);
            }
            ACCL => {
                if self.f.accl <= 0.0 {
                    self.f.accl = 0.1;
                    self.post(ACCL);
                }
                self.accs_from_accl();
            }
            ACCS => {
                if self.f.accs <= 0.0 {
                    self.accs_from_accl();
                }
                self.accl_from_accs();
            }
            BACC => {
                if self.f.bacc <= 0.0 {
                    self.f.bacc = 0.1;
                    self.post(BACC);
                }
            }
            RDBD | BDST => self.enforce_min_rdbd(),
            DIR => {
                let dirsign = self.dirsign();
                if self.f.foff == choice::FOFF_FROZEN {
                    self.f.val = self.f.dval * dirsign + self.f.off;
                    self.mark(VAL);
                } else {
                    self.f.off = self.f.val - self.f.dval * dirsign;
                    self.mark(OFF);
                }
                self.f.rbv = self.f.drbv * dirsign + self.f.off;
                self.mark(RBV);
                self.set_userlimits();
            }
            OFF => {
                let dirsign = self.dirsign();
                self.f.val = self.f.dval * dirsign + self.f.off;
                self.f.lval = self.f.ldvl * dirsign + self.f.off;
                self.f.rbv = self.f.drbv * dirsign + self.f.off;
                self.mark(VAL);
                self.mark(RBV);
                self.set_userlimits();
            }
            HLM | LLM | DHLM | DLLM => {
                match field {
                    HLM => self.set_user_limit(true),
                    LLM => self.set_user_limit(false),
                    DHLM => self.set_dial_limit(true),
                    _ => self.set_dial_limit(false),
                }
                // Departure Z8: LVIO follows the new limits (the reference waits for a move, D8).
                let lvio = i16::from(self.readback_violates_limits());
                if lvio != self.f.lvio {
                    self.f.lvio = lvio;
                    self.mark(LVIO);
                }
            }
            FRAC => {
                let clamped = self.f.frac.clamp(0.1, 1.5);
                if clamped != self.f.frac {
                    self.f.frac = clamped;
                    self.post(FRAC);
                }
            }
            MRES => {
                self.mark(MRES);
                let urev = self.f.mres * f64::from(self.f.srev);
                if self.f.urev != urev {
                    self.f.urev = urev;
                    self.mark(UREV);
                }
                self.rescale_for_resolution();
            }
            UREV => {
                let mres = self.f.urev / f64::from(self.f.srev);
                if self.f.mres != mres {
                    self.f.mres = mres;
                    self.mark(MRES);
                }
                self.rescale_for_resolution();
            }
            SREV => {
                if self.f.srev <= 0 {
                    self.f.srev = 200;
                    self.mark(SREV);
                }
                let mres = self.f.urev / f64::from(self.f.srev);
                if self.f.mres != mres {
                    self.f.mres = mres;
                    self.mark(MRES);
                }
            }
            ERES => {
                if self.f.eres == 0.0 {
                    self.f.eres = self.f.mres;
                }
                self.mark(ERES);
            }
            UEIP => {
                if self.f.ueip == choice::YES {
                    if self.f.msta & msta::PRESENT != 0 {
                        if self.f.urip == choice::YES {
                            self.f.urip = choice::NO;
                            self.post(URIP);
                        }
                    } else {
                        self.f.ueip = choice::NO;
                        self.mark(UEIP);
                    }
                }
            }
            URIP => {
                if self.f.urip == choice::YES && self.f.ueip == choice::YES {
                    self.f.ueip = choice::NO;
                    self.mark(UEIP);
                }
            }
            SSET | SUSE => {
                self.f.set = u16::from(field == SSET);
                self.post(SET);
            }
            FOF | VOF => {
                self.f.foff = if field == FOF { choice::FOFF_FROZEN } else { choice::FOFF_VARIABLE };
                self.post(FOFF);
            }
            PCOF | ICOF | DCOF => {
                if self.f.msta & msta::GAIN_SUPPORT != 0 {
                    let value = self.f.get(field).as_f64().unwrap_or(0.0);
                    let clamped = value.clamp(0.0, 1.0);
                    self.f.set(field, &Value::Float(clamped));
                    let cmd = match field {
                        PCOF => MotorCommand::SetPGain(clamped),
                        ICOF => MotorCommand::SetIGain(clamped),
                        _ => MotorCommand::SetDGain(clamped),
                    };
                    self.send(vec![cmd]);
                    if clamped != value {
                        self.post(field);
                    }
                }
            }
            CNEN => {
                if self.f.msta & msta::GAIN_SUPPORT != 0 {
                    let cmd = if self.f.cnen != 0 { MotorCommand::EnableTorque } else { MotorCommand::DisableTorque };
                    self.send(vec![cmd]);
                }
            }
            JOGF | JOGR => {
                let (pressed, blocked) =
                    if field == JOGF { (self.f.jogf, self.f.hls) } else { (self.f.jogr, self.f.lls) };
                // Departure Z5: also accepted while a move runs (the reference needs MIP = DONE);
                // not while jogging or homing.
                let busy = mip::JOG_GROUP | mip::JOG_STOP | mip::JOG_REQ | mip::HOME_GROUP;
                if pressed == 0 {
                    self.f.mip &= !mip::JOG_REQ;
                } else if self.f.mip & busy == 0 && blocked == 0 {
                    self.f.mip |= mip::JOG_REQ;
                }
            }
            JVEL => {
                self.range_check(JVEL, self.f.vbas, self.f.vmax);
                if self.f.mip & (mip::JOGF | mip::JOGR) != 0 {
                    let maths = MoveMaths::new(&self.f);
                    let mut jogv = self.f.jvel * self.dirsign() / self.f.mres;
                    if self.f.jogr != 0 {
                        jogv = -jogv;
                    }
                    self.send(vec![MotorCommand::SetAccel(maths.jacc), MotorCommand::JogVelocity(jogv)]);
                }
            }
            JAR => {
                if self.f.jar <= 0.0 {
                    self.f.jar = self.f.jvel / 0.1;
                }
            }
            HVEL => self.range_check(HVEL, self.f.vbas, self.f.vmax),
            STUP => {
                if self.f.stup != choice::STUP_ON {
                    self.f.stup = choice::STUP_OFF;
                    self.post(STUP);
                    return Err(WriteError::Adjusted {
                        field,
                        reason: "only ON may be written; STUP stays OFF".into(),
                    });
                }
            }
            NTMF => {
                if self.f.ntmf < 2 {
                    self.f.ntmf = 2;
                    self.post(NTMF);
                    return Err(WriteError::Adjusted { field, reason: "NTMF must be at least 2; set to 2".into() });
                }
            }
            _ => {}
        }
        Ok(())
    }

    fn clamp_negative(&mut self, field: Field) {
        if self.f.get(field).as_f64().unwrap_or(0.0) < 0.0 {
            self.f.set(field, &Value::Float(0.0));
            self.post(field);
        }
    }

    /// §7.2: after a write to one member of a speed pair (EGU/s, rev/s), the other follows
    /// with |UREV|; the rev/s member only when UREV is set, as in the reference.
    fn follow_speed_pair(&mut self, written: Field, egu: Field, rev: Field) {
        let u = self.f.urev.abs();
        let value = |f: &Fields, field: Field| f.get(field).as_f64().unwrap_or(0.0);
        let (target, follower) = if written == egu {
            if self.f.urev == 0.0 {
                return;
            }
            (value(&self.f, egu) / u, rev)
        } else {
            (u * value(&self.f, rev), egu)
        };
        if value(&self.f, follower) != target {
            self.f.set(follower, &Value::Float(target));
            self.post(follower);
        }
    }

    /// RV of §7.2, the part shared by the base and maximum speed writes.
    fn recheck_velocities(&mut self) {
        self.range_check(Field::VELO, self.f.vbas, self.f.vmax);
        self.follow_speed_pair(Field::VELO, Field::VELO, Field::S);
        self.range_check(Field::BVEL, self.f.vbas, self.f.vmax);
        self.follow_speed_pair(Field::BVEL, Field::BVEL, Field::SBAK);
        self.range_check(Field::JVEL, self.f.vbas, self.f.vmax);
        self.range_check(Field::HVEL, self.f.vbas, self.f.vmax);
    }

    /// The velocity/limit rescale after an MRES or UREV write (§7.2): raw limits are kept.
    fn rescale_for_resolution(&mut self) {
        let u = self.f.urev.abs();
        let velo = u * self.f.s;
        if velo != self.f.velo {
            self.f.velo = velo;
            self.mark(Field::VELO);
        }
        self.f.vbas = u * self.f.sbas;
        self.mark(Field::VBAS);
        self.f.bvel = u * self.f.sbak;
        self.post(Field::BVEL);
        self.f.vmax = u * self.f.smax;
        self.post(Field::VMAX);
        let (dhlm, dllm) = if self.f.mres > 0.0 {
            (self.f.rhlm * self.f.mres, self.f.rllm * self.f.mres)
        } else {
            (self.f.rllm * self.f.mres, self.f.rhlm * self.f.mres)
        };
        if dhlm != self.f.dhlm {
            self.f.dhlm = dhlm;
            self.post(Field::DHLM);
        }
        if dllm != self.f.dllm {
            self.f.dllm = dllm;
            self.post(Field::DLLM);
        }
        self.set_userlimits();
        self.post(Field::HLM);
        self.post(Field::LLM);
    }

    // ------------------------------------------------------------------ §8 process()

    fn process(&mut self) {
        let lvio_at_entry = self.f.lvio;
        let msta_at_entry = self.f.msta;
        let mut reason = self.update_values();
        if self.f.msta != msta_at_entry {
            self.mark(Field::MSTA);
        }
        let mut flow = Flow::DoWork;
        if reason == Reason::Callback || self.f.mip & mip::DELAY_ACK != 0 {
            reason = Reason::Callback;
            flow = self.callback_phase();
        }
        if let Flow::DoWork = flow {
            self.enter_do_work(reason, lvio_at_entry);
        }
        // EXIT
        if reason == Reason::Callback && self.f.stup == choice::STUP_BUSY {
            self.f.stup = choice::STUP_OFF;
            self.mark(Field::STUP);
        }
        let alarm_changed = self.alarm();
        self.monitor(alarm_changed);
        if self.f.dmov != 0 {
            self.outputs.push(Output::Done);
        }
    }

    /// §15.3 update_values: copy the device's pending status into the record.
    fn update_values(&mut self) -> Reason {
        let Some(status) = self.pending_status.take() else {
            return Reason::NothingDone;
        };
        let rmp = (status.position + 0.5).floor() as i32;
        let rep = (status.encoder_position + 0.5).floor() as i32;
        let rvel = status.velocity.floor() as i32;
        for (field, old, new) in
            [(Field::RMP, self.f.rmp, rmp), (Field::REP, self.f.rep, rep), (Field::RVEL, self.f.rvel, rvel)]
        {
            if old != new {
                self.f.set(field, &Value::Int(new.into()));
                self.post(field);
            }
        }
        self.f.msta = status.msta;
        self.readback_link = status.readback;
        Reason::Callback
    }

    fn callback_phase(&mut self) -> Flow {
        self.process_motor_info(false);
        if self.f.movn != 0 {
            let sign_rdif = i16::from(self.f.rdif >= 0);
            let ntm_deadband = f64::from(self.f.ntmf) * (self.f.bdst.abs() + self.f.rdbd);
            if self.f.dmov != 0 {
                self.f.dmov = 0;
                self.mark(Field::DMOV);
                self.f.mip |= mip::EXTERNAL;
                self.mark(Field::MIP);
                self.f.pp = 1;
            }
            if self.f.ntm == choice::YES
                && sign_rdif != self.f.cdir
                && self.f.diff.abs() > ntm_deadband
                && self.f.mip & (mip::MOVE | mip::RETRY) != 0
                && self.f.mip & mip::STOP == 0
            {
                tracing::debug!(tdir = self.f.tdir, "new target behind the motor: stopping");
                self.send(vec![MotorCommand::StopAxis]);
                self.f.mip |= mip::STOP;
                self.mark(Field::MIP);
                self.f.pp = 0;
            }
            return Flow::DoWork;
        }
        if self.f.stup == choice::STUP_BUSY {
            return Flow::DoWork;
        }
        if self.f.dmov == 0 {
            if self.request_held() {
                return Flow::DoWork;
            }
            self.f.dmov = 1;
            self.mark(Field::DMOV);
            if self.f.mip == mip::JOGF || self.f.mip == mip::JOGR {
                self.set_mip(mip::DONE);
                self.clear_buttons();
                self.f.pp = 1;
            }
        }
        if self.resume_on_go && self.f.mip == mip::STOP {
            // Paused mid-move (Z9): the target stays, DMOV stays 0 until Go.
            self.set_mip(mip::DONE);
            self.f.dmov = 0;
            self.marks.clear(Field::DMOV);
            return Flow::Exit;
        }
        if self.f.mip != mip::DONE && self.limit_switch_hit() {
            self.f.dmov = 0;
            self.marks.clear(Field::DMOV);
            self.send(vec![MotorCommand::GetInfo]);
            self.f.pp = 1;
            self.set_mip(mip::DONE);
            return Flow::Exit;
        }
        if self.f.pp != 0 {
            if self.f.val != self.f.lval && self.f.mip & mip::STOP == 0 && self.f.mip & mip::JOG_STOP == 0 {
                // A new target arrived while the previous sequence was running.
                if self.f.mip == mip::HOMF || self.f.mip == mip::HOMR {
                    self.clear_buttons();
                }
                self.f.mip = mip::DONE;
                return Flow::DoWork;
            }
            self.post_process();
        }
        if self.limit_switch_hit() || self.f.mip == mip::LOAD_P {
            self.set_mip(mip::DONE);
        } else if self.f.dmov != 0 {
            let dmov_just_set = self.marks.contains(Field::DMOV);
            if self.f.mip & mip::DELAY_ACK != 0 || self.f.dly <= 0.0 {
                if self.f.mip & mip::DELAY_ACK != 0 && self.f.mip & mip::DELAY_REQ == 0 {
                    self.f.mip |= mip::DELAY_REQ | mip::DELAY_ACK;
                    self.send(vec![MotorCommand::GetInfo]);
                    self.f.dmov = 0;
                    self.marks.clear(Field::DMOV);
                    return Flow::Exit;
                } else if self.f.stup != choice::STUP_ON && self.f.mip != mip::DONE {
                    self.set_mip(self.f.mip & !mip::DELAY_GROUP);
                    self.maybe_retry();
                    if self.f.mip == mip::RETRY && self.f.rmod == choice::RMOD_IN_POSITION {
                        self.set_mip(self.f.mip | mip::DELAY_REQ);
                        self.outputs.push(Output::StartDelay(self.f.dly));
                    }
                }
            } else if dmov_just_set {
                if self.f.mip & mip::DELAY_REQ == 0 {
                    self.set_mip(self.f.mip | mip::DELAY_REQ);
                    self.outputs.push(Output::StartDelay(self.f.dly));
                }
                self.f.dmov = 0;
                self.marks.clear(Field::DMOV);
                return Flow::Exit;
            }
        }
        Flow::DoWork
    }

    fn enter_do_work(&mut self, reason: Reason, lvio_at_entry: i16) {
        let f = &self.f;
        if f.dhlm == 0.0 && f.dllm == 0.0 {
            self.f.lvio = 0;
        } else if f.mip & mip::JOG_GROUP != 0 {
            let lvio =
                (f.jogf != 0 && f.rbv > f.hlm - f.jvel) || (f.jogr != 0 && f.rbv < f.llm + f.jvel) || f.dllm > f.dhlm;
            self.f.lvio = i16::from(lvio);
        } else if f.mip & mip::HOME_GROUP != 0 {
            self.f.lvio = 0;
        }
        if self.f.lvio != lvio_at_entry {
            self.mark(Field::LVIO);
            // Departure Z2: IGSET means "behave as Use", so it keeps the stop (the reference drops it, Q2).
            if self.f.lvio != 0 && !self.set_mode() {
                self.f.stop = 1;
                self.mark(Field::STOP);
                self.clear_buttons();
            }
        }
        let f = &self.f;
        if f.stop != 0
            || f.spmg == choice::SPMG_STOP
            || f.spmg == choice::SPMG_PAUSE
            || reason != Reason::Callback
            || f.dmov != 0
            || f.mip & mip::RETRY != 0
        {
            self.do_work(reason);
        }
        if !self.f.rlnk.is_empty() {
            self.outputs.push(Output::ReadbackLink(self.f.rbv));
        }
    }

    // ------------------------------------------------------------------ §9 do_work()

    fn do_work(&mut self, reason: Reason) {
        use Field::*;
        let stop_or_pause = self.f.spmg == choice::SPMG_STOP || self.f.spmg == choice::SPMG_PAUSE;
        let lvio_at_entry = self.f.lvio;

        // §9.1 explicit status update and the STOP / SPMG switch
        if self.f.stup == choice::STUP_ON {
            self.request_status_refresh();
        }
        if self.f.spmg != self.f.lspg || self.f.stop != 0 {
            let stop_req = self.f.stop != 0;
            if self.f.spmg != self.f.lspg {
                self.f.lspg = self.f.spmg;
            } else {
                self.f.stop = 0;
                self.mark(STOP);
            }
            if stop_or_pause || stop_req {
                if self.f.spmg == choice::SPMG_STOP || stop_req {
                    let m = self.f.mip;
                    if m == mip::DONE || m & mip::STOP != 0 || m & mip::RETRY != 0 {
                        if std::mem::take(&mut self.resume_on_go) {
                            self.sync_target_position();
                            self.set_mip(mip::DONE);
                            self.f.dmov = 1;
                            self.mark(DMOV);
                        }
                        if m & mip::RETRY != 0 {
                            self.set_mip(mip::DONE);
                            self.f.dmov = 1;
                            self.mark(DMOV);
                        }
                        self.send(vec![MotorCommand::StopAxis]);
                        return;
                    } else if self.f.movn != 0 {
                        self.f.pp = 1;
                        self.clear_buttons();
                    } else {
                        self.sync_target_position();
                    }
                }
                if self.f.mip & mip::HOME_GROUP != 0 {
                    self.clear_buttons();
                }
                let moving_to_target = self.f.mip & (mip::MOVE | mip::MOVE_BL | mip::RETRY) != 0
                    && self.f.mip & (mip::JOG_GROUP | mip::HOME_GROUP) == 0;
                if self.f.spmg == choice::SPMG_PAUSE && !stop_req && moving_to_target {
                    // Departure Z9: hold the target instead of ending the motion off-target (Q11).
                    self.resume_on_go = true;
                    self.f.pp = 0;
                }
                if self.f.mip & mip::DELAY_REQ == 0 {
                    self.set_mip(mip::STOP);
                }
                self.send(vec![MotorCommand::StopAxis]);
                return;
            } else if self.f.spmg == choice::SPMG_GO {
                self.resume_on_go = false;
                if (self.f.jogf != 0 && self.f.hls == 0) || (self.f.jogr != 0 && self.f.lls == 0) {
                    self.set_mip(mip::JOG_REQ);
                } else if self.f.mip == mip::STOP {
                    self.set_mip(mip::DONE);
                }
            } else {
                self.resume_on_go = false;
                self.set_mip(mip::DONE);
                self.f.rcnt = 0;
                self.mark(RCNT);
            }
        }

        // §9.2 resolution / encoder changes
        if self.marks.contains(MRES) || self.marks.contains(ERES) || self.marks.contains(UEIP) {
            let mut ratio = None;
            if self.f.msta & msta::PRESENT != 0 {
                if self.f.mres.abs() < 1e-9 {
                    self.f.mres = 1.0;
                    self.mark(MRES);
                }
                if self.f.eres == 0.0 {
                    self.f.eres = self.f.mres;
                    self.mark(ERES);
                }
                let mut m: i64 = 10_000_000;
                while m > 1 && ((m as f64 / self.f.eres).abs() > 1e6 || (m as f64 / self.f.mres).abs() > 1e6) {
                    m /= 10;
                }
                ratio = Some((m as f64 / self.f.eres, m as f64 / self.f.mres));
            }
            self.enforce_min_rdbd();
            if let Some((enc, mot)) = ratio {
                self.send(vec![MotorCommand::SetEncRatio(enc, mot)]);
            }
            if self.set_mode() {
                self.f.pp = 1;
                self.send(vec![MotorCommand::GetInfo]);
            } else if self.f.mip & mip::LOAD_P == 0 {
                self.load_pos();
            }
            return;
        }

        // §9.3 the source of the target: closed loop (DOL) or the buttons
        if self.f.omsl == choice::OMSL_CLOSED_LOOP && !self.f.dol.is_empty() {
            match self.desired {
                Some(value) => {
                    self.f.val = value;
                    self.f.udf = 0;
                }
                None => {
                    self.f.udf = 1;
                    return;
                }
            }
        } else if self.handle_buttons(stop_or_pause) {
            return;
        }

        // §9.4 VAL → DVAL, and the Set-mode offset redefinition
        if self.f.val != self.f.lval {
            self.mark(VAL);
            if self.set_mode() && self.f.foff == choice::FOFF_VARIABLE {
                let dirsign = self.dirsign();
                self.f.off = self.f.val - self.f.dval * dirsign;
                self.f.rbv = self.f.drbv * dirsign + self.f.off;
                self.mark(OFF);
                self.mark(RBV);
                self.set_userlimits();
                self.f.lval = self.f.val;
                self.set_mip(mip::DONE);
                self.f.dmov = 1;
                self.mark(DMOV);
                return;
            }
            self.f.dval = (self.f.val - self.f.off) / self.dirsign();
        }
        if stop_or_pause {
            if !self.set_mode() {
                self.keep_held_target_consistent();
            } else if self.f.dval != self.f.ldvl && self.f.mip & mip::LOAD_P == 0 {
                // Departure Z12: a Set-mode calibration moves nothing, so SPMG does not hold it.
                self.load_pos();
            }
            return;
        }

        // §9.5 move evaluation
        if self.f.dval != self.f.ldvl || self.f.dmov == 0 {
            self.evaluate_move(lvio_at_entry);
        } else if self.f.sync != 0 && self.f.mip == mip::DONE {
            // §9.6
            self.sync_target_position();
            self.f.sync = 0;
            self.post(SYNC);
        } else if reason == Reason::NothingDone && self.f.stup == choice::STUP_OFF {
            self.request_status_refresh();
        }
    }

    /// §9.3 home, jog, tweak, relative and raw requests; true when do_work is over.
    fn handle_buttons(&mut self, stop_or_pause: bool) -> bool {
        use Field::*;
        let dir_pos = self.f.dir == choice::DIR_POS;
        let fwd_blocked = if dir_pos { self.f.hls } else { self.f.lls } != 0;
        let rev_blocked = if dir_pos { self.f.lls } else { self.f.hls } != 0;
        // Departure Z6: a home refused by an active switch is reset and reported, never
        // started later (the reference latches it, Q25).
        for (button, blocked, switch) in [(HOMF, fwd_blocked, "high"), (HOMR, rev_blocked, "low")] {
            if blocked && self.f.get(button) != Value::Int(0) && self.f.mip & mip::HOME_GROUP == 0 {
                self.f.set(button, &Value::Int(0));
                self.mark(button);
                self.refusal = Some(format!("{button} refused: the {switch} limit switch is active"));
            }
        }
        let home_requested = (self.f.homf != 0 && self.f.mip & mip::HOMF == 0 && !fwd_blocked)
            || (self.f.homr != 0 && self.f.mip & mip::HOMR == 0 && !rev_blocked);
        let jog_requested = self.f.mip & mip::JOG_GROUP == 0 && !stop_or_pause && self.f.mip & mip::JOG_REQ != 0;
        if home_requested || jog_requested {
            if let Some(reason) = self.disabled_refusal() {
                self.refusal = Some(reason);
                self.set_mip(self.f.mip & !mip::JOG_REQ);
                self.clear_buttons();
                return true;
            }
        }
        if home_requested && stop_or_pause {
            // Held until Go; the rest of the request is still taken in (Z12: the reference
            // returns here and leaves a target written meanwhile half converted).
            self.f.dmov = 0;
            self.mark(DMOV);
        } else if home_requested {
            self.set_mip(if self.f.homf != 0 { mip::HOMF } else { mip::HOMR });
            self.f.pp = 1;
            if self.f.movn != 0 {
                self.set_mip(self.f.mip | mip::STOP);
                self.send(vec![MotorCommand::StopAxis]);
            } else {
                if self.f.eres == 0.0 {
                    self.f.eres = self.f.mres;
                    self.mark(ERES);
                }
                self.start_home();
            }
            return true;
        }

        if jog_requested {
            let f = &self.f;
            if !(f.dhlm == 0.0 && f.dllm == 0.0)
                && ((f.jogf != 0 && f.val > f.hlm - f.jvel)
                    || (f.jogr != 0 && f.val < f.llm + f.jvel)
                    || f.dllm > f.dhlm)
            {
                self.f.lvio = 1;
                self.mark(LVIO);
                if self.f.jogf != 0 {
                    self.f.jogf = 0;
                    self.mark(JOGF);
                }
                if self.f.jogr != 0 {
                    self.f.jogr = 0;
                    self.mark(JOGR);
                }
                // Departure Z1: no request is left behind (the reference keeps JOG_REQ, Q1).
                self.set_mip(self.f.mip & !mip::JOG_REQ);
                self.refusal = Some("limit violation: jog refused within one second of travel of a soft limit".into());
                return true;
            }
            self.set_mip(if self.f.jogf != 0 { mip::JOGF } else { mip::JOGR });
            if self.f.movn != 0 {
                self.f.pp = 1;
                self.set_mip(self.f.mip | mip::STOP);
                self.send(vec![MotorCommand::StopAxis]);
            } else {
                self.start_jog();
            }
            return true;
        }

        if self.f.mip & mip::JOG_REQ == 0 && self.f.mip & (mip::JOGF | mip::JOGR) != 0 {
            // Any do_work during a jog stops it (Q7); MIP is not marked here.
            self.f.pp = 1;
            self.f.mip = (self.f.mip | mip::JOG_STOP) & !(mip::JOGF | mip::JOGR);
            self.send(vec![MotorCommand::StopAxis]);
            return true;
        } else if self.f.mip & (mip::JOG_STOP | mip::JOG_BL1 | mip::JOG_BL2) != 0 {
            return true;
        }

        if self.f.twf != 0 || self.f.twr != 0 {
            self.f.val += self.f.twv * if self.f.twf != 0 { 1.0 } else { -1.0 };
            if self.f.twf != 0 {
                self.f.twf = 0;
                self.post(TWF);
            }
            if self.f.twr != 0 {
                self.f.twr = 0;
                self.post(TWR);
            }
        }
        if self.f.rlv != self.f.lrlv {
            self.f.val += self.f.rlv;
            self.f.rlv = 0.0;
            self.mark(RLV);
            self.f.lrlv = 0.0;
        }
        if self.f.rval != self.f.lrvl {
            self.f.dval = f64::from(self.f.rval) * self.f.mres;
        }
        false
    }

    /// §9.5
    fn evaluate_move(&mut self, lvio_at_entry: i16) {
        use Field::*;
        if self.f.dval != self.f.ldvl {
            self.mark(DVAL);
        }
        let diff = self.f.dval - self.f.drbv;
        if diff != self.f.diff {
            self.f.diff = diff;
            self.mark(DIFF);
        }
        self.f.rdif = nint(self.f.diff / self.f.mres);
        self.mark(RDIF);
        if self.set_mode() {
            if self.f.mip & mip::LOAD_P == 0 {
                self.load_pos();
            }
            return;
        }
        let mut m = MoveMaths::new(&self.f);
        let use_rel = self.use_relative();
        self.f.val = self.f.dval * self.dirsign() + self.f.off;
        if self.f.val != self.f.lval {
            self.mark(VAL);
        }
        self.f.rval = nint(self.f.dval / self.f.mres);
        if self.f.rval != self.f.lrvl {
            self.mark(RVAL);
        }

        let (rpos, npos) = (nint(m.rbvpos), nint(m.newpos));
        let steps_away = (i64::from(npos) - i64::from(rpos)).abs();
        let retrying = self.f.mip & mip::RETRY != 0;
        let too_small = if !retrying {
            let spdb = self.f.spdb;
            steps_away < 1 || (spdb > 0.0 && (self.f.dval - spdb) < self.f.drbv && self.f.drbv < (self.f.dval + spdb))
        } else {
            steps_away < i64::from(m.rdbdpos)
        };
        if too_small {
            if self.f.dmov == 0 && (self.f.mip == mip::DONE || self.f.mip == mip::RETRY) {
                self.f.dmov = 1;
                self.mark(DMOV);
                if self.f.mip != mip::DONE {
                    self.set_mip(mip::DONE);
                }
            }
            self.f.ldvl = self.f.dval;
            self.f.lval = self.f.val;
            self.f.lrvl = self.f.rval;
            return;
        }

        if !retrying {
            if self.f.rcnt != 0 {
                self.mark(RCNT);
            }
            self.f.rcnt = 0;
        } else {
            let factor = match self.f.rmod {
                choice::RMOD_ARITHMETIC => {
                    Some((f64::from(self.f.rtry) - f64::from(self.f.rcnt) + 1.0) / f64::from(self.f.rtry))
                }
                choice::RMOD_GEOMETRIC => Some(1.0 / 2f64.powi(i32::from(self.f.rcnt) - 1)),
                choice::RMOD_IN_POSITION => return,
                _ => None,
            };
            if let Some(factor) = factor {
                m.relpos = at_least_one_step(m.relpos * factor);
                m.relbpos = at_least_one_step(m.relbpos * factor);
            }
        }

        let f = &self.f;
        let preferred = if use_rel { (f.diff > 0.0) == (f.bdst > 0.0) } else { (f.dval > f.ldvl) == (f.bdst > 0.0) };
        let lvio = if f.dhlm == 0.0 && f.dllm == 0.0 {
            false
        } else if f.dllm > f.dhlm {
            true
        } else if (f.dval > f.dhlm && f.dval < f.ldvl) || (f.dval < f.dllm && f.dval > f.ldvl) {
            false
        } else if preferred {
            f.dval > f.dhlm || f.dval < f.dllm
        } else {
            (f.dval - f.bdst) > f.dhlm || (f.dval - f.bdst) < f.dllm
        };
        self.f.lvio = i16::from(lvio);
        if self.f.lvio != lvio_at_entry {
            self.mark(LVIO);
        }
        let refusal = if lvio {
            Some(format!(
                "limit violation: dial target {} is outside the soft limits [{}, {}] (DLLM, DHLM)",
                self.f.dval, self.f.dllm, self.f.dhlm
            ))
        } else if self.f.urip == choice::YES && self.readback_link.is_none() {
            Some(format!("the readback link RDBL ({}) cannot be read", self.f.rdbl))
        } else {
            self.disabled_refusal()
        };
        if let Some(reason) = refusal {
            self.refusal = Some(reason);
            // Departure Z13: VAL is restored from the restored dial target; the reference restores
            // LVAL, which is stale after a DIR change or a Set-mode calibration.
            self.f.val = self.f.ldvl * self.dirsign() + self.f.off;
            self.f.dval = self.f.ldvl;
            self.f.rval = self.f.lrvl;
            self.mark(VAL);
            self.mark(DVAL);
            self.mark(RVAL);
            if self.f.mip & mip::RETRY != 0 {
                self.set_mip(mip::DONE);
            }
            if self.f.mip == mip::DONE && self.f.dmov == 0 {
                self.f.dmov = 1;
                self.mark(DMOV);
            }
            return;
        }

        if self.f.mip == mip::DONE || self.f.mip == mip::RETRY {
            self.set_mip(self.f.mip | mip::MOVE);
            if self.f.dmov != 0 {
                self.f.dmov = 0;
                self.mark(DMOV);
            }
            self.f.ldvl = self.f.dval;
            self.f.lval = self.f.val;
            self.f.lrvl = self.f.rval;
            let f = &self.f;
            let frac = f64::from(f.frac);
            let fractional_target = if use_rel { m.relpos * frac } else { m.currpos + frac * (m.newpos - m.currpos) };
            let backlash_off = f.bdst.abs() < f.mres.abs() || (preferred && f.bvel == f.velo && f.bacc == f.accl);
            let within_backlash = preferred
                && ((use_rel && ((f.bdst >= 0.0 && m.relbpos <= 1.0) || (f.bdst < 0.0 && m.relbpos >= 1.0)))
                    || (!use_rel && (m.newpos - m.currpos).abs() <= m.rbdst1));
            let (velocity, accel, position) = if backlash_off {
                (m.vel, m.acc, fractional_target)
            } else if within_backlash {
                (m.bvel, m.bacc, fractional_target)
            } else {
                self.f.pp = 1;
                (m.vel, m.acc, if use_rel { m.relbpos } else { m.bpos })
            };
            self.send_leg(Leg { velocity, base: Some(m.vbase), accel, position, relative: use_rel });
        }
    }

    // ------------------------------------------------------------------ §10 postProcess()

    fn post_process(&mut self) {
        use Field::*;
        self.f.pp = 0;
        if self.f.omsl != choice::OMSL_CLOSED_LOOP
            && self.f.mip & (mip::MOVE | mip::MOVE_BL | mip::JOG_BL1 | mip::JOG_BL2) == 0
        {
            self.f.val = self.f.rbv;
            self.f.dval = self.f.drbv;
            self.f.rval = nint(self.f.dval / self.f.mres);
            self.f.diff = 0.0;
            self.f.rdif = 0;
            for field in [VAL, DVAL, RVAL, DIFF, RDIF] {
                self.mark(field);
            }
        }
        let use_rel = self.use_relative();
        let frac = f64::from(self.f.frac);
        if self.f.mip & mip::LOAD_P != 0 {
            self.f.mip = mip::DONE;
        } else if self.f.mip & mip::HOME_GROUP != 0 {
            if self.f.mip & mip::STOP != 0 {
                self.f.mip &= !mip::STOP;
                self.start_home();
                self.f.pp = 1;
            } else if self.f.mip & mip::HOMF != 0 {
                self.f.mip &= !mip::HOMF;
                self.f.homf = 0;
                self.mark(HOMF);
            } else {
                self.f.mip &= !mip::HOMR;
                self.f.homr = 0;
                self.mark(HOMR);
            }
        } else if self.f.mip & (mip::JOG_STOP | mip::MOVE) != 0 {
            if self.backlash_enabled() {
                let m = MoveMaths::new(&self.f);
                self.f.dmov = 0;
                self.marks.clear(DMOV);
                if self.f.mip & mip::JOG_STOP != 0 {
                    // T3: to the backlash start at the slew speed.
                    let velocity = if m.vel <= m.vbase { m.vbase + 1.0 } else { m.vel };
                    let position = if use_rel { m.relbpos } else { m.bpos };
                    self.send_leg(Leg { velocity, base: Some(m.vbase), accel: m.acc, position, relative: use_rel });
                    self.f.mip = mip::JOG_BL1;
                } else {
                    let position = if use_rel { m.relpos * frac } else { self.fractional_backlash_target(&m) };
                    self.send_leg(Leg::backlash(&m, position, use_rel));
                    self.f.mip = mip::MOVE_BL;
                }
                self.f.pp = 1;
            }
            self.f.mip &= !(mip::JOG_STOP | mip::MOVE);
        } else if self.f.mip & mip::JOG_BL1 != 0 {
            let m = MoveMaths::new(&self.f);
            let position = if use_rel { (m.relpos - m.relbpos) * frac } else { self.fractional_backlash_target(&m) };
            self.f.dmov = 0;
            self.marks.clear(DMOV);
            self.send_leg(Leg::backlash(&m, position, use_rel));
            self.f.mip = mip::JOG_BL2;
            self.f.pp = 1;
        } else if self.f.mip & (mip::JOGF | mip::JOGR) != 0 && self.f.mip & mip::STOP != 0 {
            // Departure Z5: the move that was running when the jog was asked for has stopped; jog now.
            self.start_jog();
        }
        self.f.lval = self.f.val;
        self.f.ldvl = self.f.dval;
        self.f.lrvl = self.f.rval;
        self.set_mip(self.f.mip & !mip::STOP);
    }

    /// The absolute final approach: FRAC of the way from the backlash start to the target.
    /// RVAL follows the intermediate raw position, unposted (Q20).
    fn fractional_backlash_target(&mut self, m: &MoveMaths) -> f64 {
        let p = m.bpos + f64::from(self.f.frac) * (m.newpos - m.bpos);
        self.f.rval = nint(p);
        p
    }

    /// Send one move leg (T1–T4). Departure Z7: CDIR is the direction this leg actually
    /// travels (the reference uses the direction to the final target, Q15). Departure Z10:
    /// a leg that starts within the soft limits never ends beyond them (FRAC > 1).
    fn send_leg(&mut self, leg: Leg) {
        let position = self.keep_within_soft_limits(leg.position, leg.relative);
        let here = self.f.drbv / self.f.mres;
        let upwards = if leg.relative { position >= 0.0 } else { position >= here };
        self.f.cdir = i16::from(upwards);
        let mut txn = vec![MotorCommand::SetVelocity(leg.velocity)];
        txn.extend(leg.base.map(MotorCommand::SetVelBase));
        if leg.accel > 0.0 {
            txn.push(MotorCommand::SetAccel(leg.accel));
        }
        txn.push(if leg.relative { MotorCommand::MoveRel(position) } else { MotorCommand::MoveAbs(position) });
        txn.push(MotorCommand::Go);
        self.send(txn);
    }

    fn keep_within_soft_limits(&self, position: f64, relative: bool) -> f64 {
        let f = &self.f;
        if f.dhlm == 0.0 && f.dllm == 0.0 {
            return position;
        }
        let here = f.drbv / f.mres;
        let (a, b) = (f.dllm / f.mres, f.dhlm / f.mres);
        // Moving back towards the valid range from outside stays allowed.
        let (lo, hi) = (a.min(b).min(here), a.max(b).max(here));
        let target = if relative { here + position } else { position };
        if (lo..=hi).contains(&target) {
            return position;
        }
        let kept = target.clamp(lo, hi);
        if relative {
            kept - here
        } else {
            kept
        }
    }

    /// T6: start jogging in the direction of the pressed button.
    fn start_jog(&mut self) {
        self.f.dmov = 0;
        self.mark(Field::DMOV);
        self.f.pp = 1;
        let maths = MoveMaths::new(&self.f);
        let mut jogv = self.f.jvel * self.dirsign() / self.f.mres;
        if self.f.jogf == 0 {
            jogv = -jogv;
        }
        self.f.cdir = i16::from(jogv >= 0.0);
        self.send(vec![
            MotorCommand::SetVelBase(maths.vbase),
            MotorCommand::SetAccel(maths.jacc),
            MotorCommand::Jog(jogv),
        ]);
    }

    /// T5 plus the bookkeeping shared by §9.3 and §10.
    fn start_home(&mut self) {
        let m = MoveMaths::new(&self.f);
        let forward = (self.f.homf != 0 && self.f.mres > 0.0) || (self.f.homr != 0 && self.f.mres < 0.0);
        let mut txn = vec![MotorCommand::SetVelocity(m.hvel), MotorCommand::SetVelBase(m.vbase)];
        if m.hacc > 0.0 {
            txn.push(MotorCommand::SetAccel(m.hacc));
        }
        txn.push(if forward { MotorCommand::HomeFor } else { MotorCommand::HomeRev });
        txn.push(MotorCommand::Go);
        self.send(txn);
        self.f.dmov = 0;
        self.mark(Field::DMOV);
        self.f.rcnt = 0;
        self.mark(Field::RCNT);
        let cdir = i16::from(self.f.homf != 0);
        self.f.cdir = if self.f.mres < 0.0 { 1 - cdir } else { cdir };
    }

    // ------------------------------------------------------------------ §11 maybe_retry()

    fn maybe_retry(&mut self) {
        let same_sense = (self.f.dir == choice::DIR_POS) == (self.f.mres >= 0.0);
        let user_cdir = if same_sense { self.f.cdir } else { 1 - self.f.cdir };
        let stopped_by_switch = (self.f.hls != 0 && user_cdir == 1) || (self.f.lls != 0 && user_cdir == 0);
        if self.f.diff.abs() >= self.f.rdbd && !stopped_by_switch {
            if self.f.rtry == 0 {
                self.f.mip &= mip::JOG_REQ;
            } else {
                self.f.rcnt += 1;
                if self.f.rcnt > self.f.rtry {
                    self.f.mip = mip::DONE;
                    if (self.f.jogf != 0 && self.f.hls == 0) || (self.f.jogr != 0 && self.f.lls == 0) {
                        self.f.mip |= mip::JOG_REQ;
                    }
                    self.f.lval = self.f.val;
                    self.f.ldvl = self.f.dval;
                    self.f.lrvl = self.f.rval;
                    self.f.miss = 1;
                    self.mark(Field::MISS);
                } else {
                    self.f.dmov = 0;
                    self.marks.clear(Field::DMOV);
                    self.f.mip = mip::RETRY;
                }
                self.mark(Field::RCNT);
            }
        } else {
            self.f.mip &= mip::JOG_REQ;
            if self.f.miss != 0 {
                self.f.miss = 0;
                self.mark(Field::MISS);
            }
            if self.f.spmg == choice::SPMG_MOVE {
                self.f.spmg = choice::SPMG_PAUSE;
                self.mark(Field::SPMG);
            }
        }
        self.mark(Field::MIP);
    }

    // ------------------------------------------------------------------ §12 alarms, §13 monitors

    /// Compute STAT/SEVR; true if either changed.
    fn alarm(&mut self) -> bool {
        let f = &self.f;
        let (mut nsta, mut nsev) = (status::NO_ALARM, severity::NO_ALARM);
        let limits_on = !(f.dhlm == 0.0 && f.dllm == 0.0);
        let mut comm_error = false;
        if f.udf != 0 {
            (nsta, nsev) = (status::UDF, severity::INVALID);
        // Departure Z4: the target is compared with the soft limits only while they are on (Q8).
        } else if f.hlsv != severity::NO_ALARM && (f.hls != 0 || (limits_on && f.dval > f.dhlm)) {
            (nsta, nsev) = (status::HIGH, f.hlsv);
        } else if f.hlsv != severity::NO_ALARM && (f.lls != 0 || (limits_on && f.dval < f.dllm)) {
            (nsta, nsev) = (status::LOW, f.hlsv);
        } else {
            if f.msta & msta::COMM_ERR != 0 {
                comm_error = true;
                (nsta, nsev) = (status::COMM, severity::INVALID);
            }
            if f.msta & (msta::SLIP_STALL | msta::PROBLEM) != 0 && nsev < severity::MAJOR {
                (nsta, nsev) = (status::STATE, severity::MAJOR);
            }
        }
        if comm_error {
            self.f.msta &= !msta::COMM_ERR;
            self.mark(Field::MSTA);
        }
        let changed = nsta != self.f.stat || nsev != self.f.sevr;
        self.f.stat = nsta;
        self.f.sevr = nsev;
        changed
    }

    fn monitor(&mut self, alarm_changed: bool) {
        use Field::*;
        let rbv_marked = self.marks.contains(RBV);
        self.marks.clear(RBV);
        let rbv = self.f.rbv;
        let rbv_due = if self.f.mdel == 0.0 && self.f.adel == 0.0 {
            rbv_marked || alarm_changed
        } else if rbv_marked {
            let mut due = alarm_changed;
            if self.f.mdel == 0.0 || (self.f.mlst - rbv).abs() > self.f.mdel {
                due = true;
                self.f.mlst = rbv;
            }
            if self.f.adel == 0.0 || (self.f.alst - rbv).abs() > self.f.adel {
                self.f.alst = rbv;
            }
            due
        } else {
            false
        };
        if rbv_due {
            self.post(RBV);
        }
        for field in [RRBV, DRBV, DIFF, RDIF, MSTA] {
            if self.marks.contains(field) || alarm_changed {
                self.marks.clear(field);
                self.post(field);
                if field == MSTA && self.f.msta & msta::GAIN_SUPPORT != 0 {
                    let cnen = u16::from(self.f.msta & msta::POSITION != 0);
                    if cnen != self.f.cnen {
                        self.f.cnen = cnen;
                        self.post(CNEN);
                    }
                }
            }
        }
        if alarm_changed {
            self.post(STAT);
            self.post(SEVR);
        }
        self.flush_posts();
    }

    /// Post every field still marked, then clear the marks.
    fn flush_posts(&mut self) {
        for field in self.marks.take() {
            self.post(field);
        }
    }

    // ------------------------------------------------------------------ §5 helpers

    /// §5.10 process_motor_info
    fn process_motor_info(&mut self, initcall: bool) {
        use Field::*;
        let old = (self.f.drbv, self.f.rbv, self.f.rrbv, self.f.tdir, self.f.movn, self.f.hls, self.f.lls, self.f.athm);
        if self.f.ueip == choice::YES && self.f.msta & msta::PRESENT == 0 {
            self.f.ueip = choice::NO;
            self.post(UEIP);
        }
        if self.f.ueip == choice::YES {
            self.f.rrbv = self.f.rep;
            self.f.drbv = f64::from(self.f.rrbv) * self.f.eres;
        } else if self.f.urip == choice::YES && !initcall {
            match self.readback_link {
                Some(value) => {
                    self.f.rrbv = nint(value * self.f.rres / self.f.mres);
                    self.f.drbv = f64::from(self.f.rrbv) * self.f.mres;
                }
                // An unreadable readback freezes; a motion in progress is stopped.
                None if self.f.mip != mip::DONE => {
                    self.clear_buttons();
                    self.f.stop = 1;
                    self.mark(STOP);
                }
                None => {}
            }
        } else {
            self.f.rrbv = self.f.rmp;
            self.f.drbv = f64::from(self.f.rrbv) * self.f.mres;
        }
        if self.f.rrbv != old.2 {
            self.mark(RRBV);
        }
        if self.f.drbv != old.0 {
            self.mark(DRBV);
        }
        self.f.rbv = self.dirsign() * self.f.drbv + self.f.off;
        if self.f.rbv != old.1 {
            self.mark(RBV);
        }
        self.f.tdir = i16::from(self.f.msta & msta::DIRECTION != 0);
        if self.f.tdir != old.3 {
            self.mark(TDIR);
        }
        self.f.rhls = i16::from(self.f.msta & msta::PLUS_LS != 0);
        self.f.rlls = i16::from(self.f.msta & msta::MINUS_LS != 0);
        let ls_active = self.limit_switch_hit();
        let same_sense = (self.f.dir == choice::DIR_POS) == (self.f.mres >= 0.0);
        (self.f.hls, self.f.lls) = if same_sense { (self.f.rhls, self.f.rlls) } else { (self.f.rlls, self.f.rhls) };
        if self.f.hls != old.5 {
            self.mark(HLS);
        }
        if self.f.lls != old.6 {
            self.mark(LLS);
        }
        if ls_active || self.f.msta & (msta::DONE | msta::PROBLEM) != 0 {
            self.f.movn = 0;
            if ls_active || self.f.msta & msta::PROBLEM != 0 {
                self.clear_buttons();
            }
        } else {
            self.f.movn = 1;
        }
        if self.f.movn != old.4 {
            self.mark(MOVN);
        }
        self.f.athm =
            i16::from(self.f.msta & if self.f.ueip == choice::YES { msta::ENCODER_HOME } else { msta::HOME } != 0);
        if self.f.athm != old.7 {
            self.mark(ATHM);
        }
        self.f.diff = self.f.dval - self.f.drbv;
        self.mark(DIFF);
        self.f.rdif = nint(self.f.diff / self.f.mres);
        self.mark(RDIF);
    }

    /// A raw limit switch active in the commanded raw direction.
    fn limit_switch_hit(&self) -> bool {
        (self.f.rhls != 0 && self.f.cdir == 1) || (self.f.rlls != 0 && self.f.cdir == 0)
    }

    /// §5.7
    fn sync_target_position(&mut self) {
        use Field::*;
        if self.f.ueip == choice::YES {
            self.f.rrbv = self.f.rep;
            self.f.drbv = f64::from(self.f.rrbv) * self.f.eres;
        } else if self.f.urip == choice::YES {
            if let Some(value) = self.readback_link {
                self.f.rrbv = nint(value * self.f.rres / self.f.mres);
                self.f.drbv = f64::from(self.f.rrbv) * self.f.mres;
            }
        } else {
            self.f.rrbv = self.f.rmp;
            self.f.drbv = f64::from(self.f.rrbv) * self.f.mres;
        }
        self.mark(RRBV);
        self.mark(DRBV);
        self.f.rbv = self.f.drbv * self.dirsign() + self.f.off;
        self.mark(RBV);
        self.f.val = self.f.rbv;
        self.f.lval = self.f.rbv;
        self.f.dval = self.f.drbv;
        self.f.ldvl = self.f.drbv;
        self.f.rval = nint(self.f.dval / self.f.mres);
        self.f.lrvl = self.f.rval;
        for field in [VAL, DVAL, RVAL] {
            self.mark(field);
        }
    }

    /// §5.8
    fn load_pos(&mut self) {
        use Field::*;
        let newpos = self.f.dval / self.f.mres;
        self.f.ldvl = self.f.dval;
        self.f.lval = self.f.val;
        if self.f.rval != nint(newpos) {
            self.mark(RVAL);
        }
        self.f.rval = nint(newpos);
        self.f.lrvl = self.f.rval;
        let pos = self.f.dir == choice::DIR_POS;
        if self.f.foff == choice::FOFF_FROZEN {
            self.f.val = if pos { self.f.off + self.f.dval } else { self.f.off - self.f.dval };
            self.mark(VAL);
            self.f.lval = self.f.val;
        } else {
            self.f.off = if pos { self.f.val - self.f.dval } else { self.f.val + self.f.dval };
            self.mark(OFF);
            self.set_userlimits();
        }
        self.set_mip(mip::LOAD_P);
        if self.f.dmov != 0 {
            self.f.dmov = 0;
            self.mark(DMOV);
        }
        self.send(vec![MotorCommand::LoadPos(newpos)]);
        self.send(vec![MotorCommand::GetInfo]);
    }

    /// §6.2 step 13: the readback lies more than one step outside the soft limits, or the limits
    /// are inverted (signed MRES as in the reference, Q19); never while limits are off.
    fn readback_violates_limits(&self) -> bool {
        let f = &self.f;
        !(f.dhlm == 0.0 && f.dllm == 0.0) && (f.drbv > f.dhlm + f.mres || f.drbv < f.dllm - f.mres || f.dllm > f.dhlm)
    }

    /// STUP → BUSY and GET_INFO, or straight back to OFF when the device refuses GET_INFO.
    fn request_status_refresh(&mut self) {
        self.f.stup = choice::STUP_BUSY;
        self.mark(Field::STUP);
        if self.status_refresh {
            self.send(vec![MotorCommand::GetInfo]);
        } else {
            self.f.stup = choice::STUP_OFF;
        }
    }

    /// §5.1
    fn enforce_min_rdbd(&mut self) {
        if self.f.rdbd < self.f.mres.abs() {
            self.f.rdbd = self.f.mres.abs();
            self.post(Field::RDBD);
        }
    }

    /// §5.2: clamp to min, and to max unless max is 0 ("no maximum"); post if changed.
    fn range_check(&mut self, field: Field, min: f64, max: f64) {
        let value = self.f.get(field).as_f64().unwrap_or(0.0);
        let mut clamped = value;
        if clamped < min {
            clamped = min;
        }
        if max != 0.0 && clamped > max {
            clamped = max;
        }
        if clamped != value {
            self.f.set(field, &Value::Float(clamped));
            self.post(field);
        }
    }

    /// §5.3
    fn clear_buttons(&mut self) {
        use Field::*;
        for field in [JOGF, JOGR, HOMF, HOMR] {
            if self.f.get(field) != Value::Int(0) {
                self.f.set(field, &Value::Int(0));
                self.mark(field);
            }
        }
    }

    /// §5.4
    fn set_userlimits(&mut self) {
        let f = &mut self.f;
        if f.dir == choice::DIR_POS {
            f.hlm = f.dhlm + f.off;
            f.llm = f.dllm + f.off;
        } else {
            f.hlm = -f.dllm + f.off;
            f.llm = -f.dhlm + f.off;
        }
        self.mark(Field::HLM);
        self.mark(Field::LLM);
    }

    /// §5.5 set_dial_high_limit / set_dial_low_limit: send the dial limit to the controller in
    /// raw units (high and low swap when MRES < 0) and derive the user limit it bounds.
    fn set_dial_limit(&mut self, high: bool) {
        let dial = if high { self.f.dhlm } else { self.f.dllm };
        self.send_raw_limit(high == (self.f.mres >= 0.0), dial / self.f.mres);
        let user = self.dirsign() * dial + self.f.off;
        // With DIR Neg the dial high limit bounds the user low limit.
        let user_field = if high == (self.f.dir == choice::DIR_POS) { Field::HLM } else { Field::LLM };
        self.f.set(user_field, &Value::Float(user));
        self.mark(user_field);
        self.mark(if high { Field::DHLM } else { Field::DLLM });
    }

    /// §5.6 set_user_high_limit / set_user_low_limit (the controller always accepts limits here).
    fn set_user_limit(&mut self, high: bool) {
        let pos = self.f.dir == choice::DIR_POS;
        let user = if high { self.f.hlm } else { self.f.llm };
        let dial = if pos { user - self.f.off } else { -user + self.f.off };
        // A user high limit is a dial high limit when DIR is Pos.
        let dial_high = high == pos;
        self.send_raw_limit(dial_high == (self.f.mres >= 0.0), dial / self.f.mres);
        if dial_high {
            self.f.dhlm = dial;
            self.mark(Field::DHLM);
        } else {
            self.f.dllm = dial;
            self.mark(Field::DLLM);
        }
        self.mark(if high { Field::HLM } else { Field::LLM });
    }

    /// SET_HIGH_LIMIT or SET_LOW_LIMIT, remembered in RHLM or RLLM.
    fn send_raw_limit(&mut self, high: bool, raw: f64) {
        if high {
            self.send(vec![MotorCommand::SetHighLimit(raw)]);
            self.f.rhlm = raw;
            self.mark(Field::RHLM);
        } else {
            self.send(vec![MotorCommand::SetLowLimit(raw)]);
            self.f.rllm = raw;
            self.mark(Field::RLLM);
        }
    }

    /// §5.9
    fn accs_from_accl(&mut self) {
        let accs = self.velocity_above_base() / self.f.accl;
        if accs != self.f.accs {
            self.f.accs = accs;
            self.post(Field::ACCS);
        }
    }

    fn accl_from_accs(&mut self) {
        if self.f.accs > 0.0 {
            let accl = self.velocity_above_base() / self.f.accs;
            if accl != self.f.accl {
                self.f.accl = accl;
                self.post(Field::ACCL);
            }
        }
    }

    fn acc_pair_from_velo(&mut self) {
        if self.f.accu == choice::ACCU_USE_ACCS {
            self.accl_from_accs();
        } else {
            self.accs_from_accl();
        }
    }

    fn velocity_above_base(&self) -> f64 {
        if self.f.velo > self.f.vbas {
            self.f.velo - self.f.vbas
        } else {
            self.f.velo
        }
    }

    // ------------------------------------------------------------------ small pieces

    fn dirsign(&self) -> f64 {
        if self.f.dir == choice::DIR_POS {
            1.0
        } else {
            -1.0
        }
    }

    /// Departure Z11: a servo whose control is disabled (CNEN = Disable) is not asked to move;
    /// the reference sends the move to a dead amplifier.
    fn disabled_refusal(&self) -> Option<String> {
        (self.f.msta & msta::GAIN_SUPPORT != 0 && self.f.cnen == 0)
            .then(|| "motor disabled: closed-loop control is off (CNEN = Disable); write CNEN Enable first".to_string())
    }

    /// Departure Z12: a target held by SPMG Stop/Pause (or behind a held home) shows in VAL,
    /// DVAL and RVAL alike while it waits; the reference converts only the field written.
    fn keep_held_target_consistent(&mut self) {
        if self.f.val != self.f.lval {
            self.f.dval = (self.f.val - self.f.off) / self.dirsign();
        } else if self.f.rval != self.f.lrvl {
            self.f.dval = f64::from(self.f.rval) * self.f.mres;
        }
        let (val, rval) = (self.f.dval * self.dirsign() + self.f.off, nint(self.f.dval / self.f.mres));
        for (field, changed) in
            [(Field::VAL, val != self.f.val), (Field::RVAL, rval != self.f.rval), (Field::DVAL, true)]
        {
            if changed {
                self.mark(field);
            }
        }
        (self.f.val, self.f.rval) = (val, rval);
    }

    /// Departure Z14: a request held by SPMG Stop/Pause keeps DMOV 0 until it runs, whatever
    /// status arrives meanwhile (the manual's DMOV; the reference lets a callback set DMOV 1).
    fn request_held(&self) -> bool {
        let f = &self.f;
        (f.spmg == choice::SPMG_STOP || f.spmg == choice::SPMG_PAUSE)
            && f.mip & !(mip::JOG_REQ | mip::STOP) == mip::DONE
            && (f.dval != f.ldvl || self.resume_on_go || f.homf != 0 || f.homr != 0 || f.mip & mip::JOG_REQ != 0)
    }

    /// Effective Set mode: SET = Set and IGSET = 0.
    fn set_mode(&self) -> bool {
        self.f.set == 1 && self.f.igset == 0
    }

    fn backlash_enabled(&self) -> bool {
        self.f.bdst.abs() >= self.f.mres.abs()
    }

    /// Relative moves: retries enabled, not In-Position, and a readback other than the step count.
    fn use_relative(&self) -> bool {
        self.f.rtry != 0
            && self.f.rmod != choice::RMOD_IN_POSITION
            && (self.f.ueip == choice::YES || self.f.urip == choice::YES)
    }

    fn set_mip(&mut self, value: u16) {
        self.f.mip = value;
        self.mark(Field::MIP);
    }

    fn mark(&mut self, field: Field) {
        self.marks.insert(field);
    }

    /// Post a field now, with its current value.
    fn post(&mut self, field: Field) {
        self.outputs.push(Output::Post(field, self.f.get(field)));
    }

    fn send(&mut self, transaction: Vec<MotorCommand>) {
        self.outputs.push(Output::Transaction(transaction));
    }
}

/// Scaled retry distances keep a magnitude of at least one step (sign(0) counts as negative).
fn at_least_one_step(steps: f64) -> f64 {
    if steps.abs() < 1.0 {
        if steps > 0.0 {
            1.0
        } else {
            -1.0
        }
    } else {
        steps
    }
}

/// One move leg for the device: speeds in steps/s, acceleration in steps/s², position in steps.
struct Leg {
    velocity: f64,
    /// SET_VEL_BASE, or None to keep the driver's last base velocity (T2/T4).
    base: Option<f64>,
    accel: f64,
    position: f64,
    relative: bool,
}

impl Leg {
    /// T2/T4: the final backlash approach at BVEL/BACC (VBAS + 1 step/s if BVEL ≤ VBAS, Q29).
    fn backlash(m: &MoveMaths, position: f64, relative: bool) -> Self {
        let velocity = if m.bvel <= m.vbase { m.vbase + 1.0 } else { m.bvel };
        Self { velocity, base: None, accel: m.bacc, position, relative }
    }
}
