//! §7 special(): what a write to each field does before and after it is stored.

use super::MotorRecord;
use crate::engine::commands::{Adjustment, Busy, MotorCommand, Unusable, WriteError};
use crate::engine::maths::MoveMaths;
use zmotor_msgs::bits::{mip, msta};
use zmotor_msgs::menus::choice;
use zmotor_msgs::{Field, Fields, Value};

impl MotorRecord {
    // One arm per field, as the table of §7 reads; guards folded into patterns would hide it.
    #[allow(clippy::collapsible_match)]
    pub(super) fn special_before(&mut self, field: Field, value: &Value) -> Result<(), WriteError> {
        use Field::*;
        match field {
            _ if field.sets_target() => {
                // Departure Z12: the reference accepts a target during the backlash takeout after
                // a jog and then forgets it, leaving VAL away from the position; refuse it instead.
                if self.f.mip & (mip::JOG_STOP | mip::JOG_BL1 | mip::JOG_BL2) != 0 {
                    return Err(WriteError::Refused { field, reason: Busy::JogBacklashTakeout });
                }
                // A disabled record is not processed: no motion starts, so no DMOV pulse (§7.1).
                if self.f.dmov == 1 && !self.processing_disabled() {
                    self.f.dmov = 0;
                    self.post(DMOV);
                }
            }
            HOMF | HOMR if self.f.mip & mip::HOME_GROUP != 0 => {
                return Err(WriteError::Refused { field, reason: Busy::HomeInProgress });
            }
            // Departure Z15: as the manual says, writing 0 is an error (the reference accepts
            // it, D7); a home is aborted with STOP.
            HOMF | HOMR if value.as_f64() == Some(0.0) => {
                return Err(WriteError::Refused { field, reason: Busy::ZeroDoesNotAbortHome });
            }
            // Departure Z21: the reference takes a resolution of 0 (only its boot corrects it to
            // 1) and is then left with speeds and soft limits of 0 and targets it cannot convert.
            MRES | UREV => {
                if let Some(reason) = Unusable::of(field, value) {
                    return Err(WriteError::Unusable { field, reason });
                }
            }
            STUP if self.f.stup != choice::STUP_OFF => {
                return Err(WriteError::Refused { field, reason: Busy::StatusUpdateInProgress });
            }
            _ => {}
        }
        Ok(())
    }

    #[allow(clippy::collapsible_match)]
    pub(super) fn special_after(&mut self, field: Field) -> Result<(), WriteError> {
        use Field::*;
        match field {
            // dbAccess's putAckt: transient alarms no longer held for acknowledgement.
            ACKT if self.f.ackt == choice::NO && self.f.acks > self.f.sevr => {
                self.f.acks = self.f.sevr;
                self.post(ACKS);
            }
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
                    return Err(WriteError::Adjusted { field, reason: Adjustment::StupStaysOff });
                }
            }
            NTMF => {
                if self.f.ntmf < 2 {
                    self.f.ntmf = 2;
                    self.post(NTMF);
                    return Err(WriteError::Adjusted { field, reason: Adjustment::NtmfRaisedTo2 });
                }
            }
            _ => {}
        }
        Ok(())
    }

    pub(super) fn clamp_negative(&mut self, field: Field) {
        if self.f.get(field).as_f64().unwrap_or(0.0) < 0.0 {
            self.f.set(field, &Value::Float(0.0));
            self.post(field);
        }
    }

    /// §7.2: after a write to one member of a speed pair (EGU/s, rev/s), the other follows
    /// with |UREV|; the rev/s member only when UREV is set, as in the reference.
    pub(super) fn follow_speed_pair(&mut self, written: Field, egu: Field, rev: Field) {
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
    pub(super) fn recheck_velocities(&mut self) {
        self.range_check(Field::VELO, self.f.vbas, self.f.vmax);
        self.follow_speed_pair(Field::VELO, Field::VELO, Field::S);
        self.range_check(Field::BVEL, self.f.vbas, self.f.vmax);
        self.follow_speed_pair(Field::BVEL, Field::BVEL, Field::SBAK);
        self.range_check(Field::JVEL, self.f.vbas, self.f.vmax);
        self.range_check(Field::HVEL, self.f.vbas, self.f.vmax);
    }

    /// The velocity/limit rescale after an MRES or UREV write (§7.2): raw limits are kept.
    pub(super) fn rescale_for_resolution(&mut self) {
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
}
