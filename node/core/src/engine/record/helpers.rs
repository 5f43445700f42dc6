//! §5 helper procedures used by several paths: readbacks from device data, sync and load of
//! positions, limits, range checks, acceleration bookkeeping.

use super::MotorRecord;
use crate::engine::commands::{Inaction, MotorCommand};
use crate::engine::maths::{nint, raw_position};
use zmotor_msgs::bits::{mip, msta};
use zmotor_msgs::menus::choice;
use zmotor_msgs::{Field, Value};

impl MotorRecord {
    /// §5.10 process_motor_info
    pub(super) fn process_motor_info(&mut self, initcall: bool) {
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
    pub(super) fn limit_switch_hit(&self) -> bool {
        (self.f.rhls != 0 && self.f.cdir == 1) || (self.f.rlls != 0 && self.f.cdir == 0)
    }

    /// §5.7
    pub(super) fn sync_target_position(&mut self) {
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

    /// Departure Z16: at the end of every processing DIFF and RDIF follow DVAL and DRBV, also
    /// when DVAL was set outside a status callback (a refused move restores it, a sync or a held
    /// target sets it); the reference leaves them stale until the next callback, which may
    /// never come at rest.
    pub(super) fn follow_diff(&mut self) {
        let diff = self.f.dval - self.f.drbv;
        if diff != self.f.diff {
            self.f.diff = diff;
            self.mark(Field::DIFF);
        }
        let rdif = nint(diff / self.f.mres);
        if rdif != self.f.rdif {
            self.f.rdif = rdif;
            self.mark(Field::RDIF);
        }
    }

    /// §5.8
    pub(super) fn load_pos(&mut self) {
        use Field::*;
        let newpos = self.f.dval / self.f.mres;
        // Departure Z20: a position the driver cannot hold (beyond 32 bits) is not sent.
        if raw_position(newpos).is_none() {
            self.refusal =
                Some(Inaction::PositionBeyondRawRange { dial: self.f.dval, mres: self.f.mres, steps: newpos.round() });
            return;
        }
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
    pub(super) fn readback_violates_limits(&self) -> bool {
        let f = &self.f;
        !(f.dhlm == 0.0 && f.dllm == 0.0) && (f.drbv > f.dhlm + f.mres || f.drbv < f.dllm - f.mres || f.dllm > f.dhlm)
    }

    /// STUP → BUSY and GET_INFO, or straight back to OFF when the device refuses GET_INFO.
    pub(super) fn request_status_refresh(&mut self) {
        self.f.stup = choice::STUP_BUSY;
        self.mark(Field::STUP);
        if self.status_refresh {
            self.send(vec![MotorCommand::GetInfo]);
        } else {
            self.f.stup = choice::STUP_OFF;
        }
    }

    /// §5.1
    pub(super) fn enforce_min_rdbd(&mut self) {
        if self.f.rdbd < self.f.mres.abs() {
            self.f.rdbd = self.f.mres.abs();
            self.post(Field::RDBD);
        }
    }

    /// §5.2: clamp to min, and to max unless max is 0 ("no maximum"); post if changed.
    pub(super) fn range_check(&mut self, field: Field, min: f64, max: f64) {
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
    pub(super) fn clear_buttons(&mut self) {
        use Field::*;
        for field in [JOGF, JOGR, HOMF, HOMR] {
            if self.f.get(field) != Value::Int(0) {
                self.f.set(field, &Value::Int(0));
                self.mark(field);
            }
        }
    }

    /// §5.4
    pub(super) fn set_userlimits(&mut self) {
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
    pub(super) fn set_dial_limit(&mut self, high: bool) {
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
    pub(super) fn set_user_limit(&mut self, high: bool) {
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
    pub(super) fn send_raw_limit(&mut self, high: bool, raw: f64) {
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
    pub(super) fn accs_from_accl(&mut self) {
        let accs = self.velocity_above_base() / self.f.accl;
        if accs != self.f.accs {
            self.f.accs = accs;
            self.post(Field::ACCS);
        }
    }

    pub(super) fn accl_from_accs(&mut self) {
        if self.f.accs > 0.0 {
            let accl = self.velocity_above_base() / self.f.accs;
            if accl != self.f.accl {
                self.f.accl = accl;
                self.post(Field::ACCL);
            }
        }
    }

    pub(super) fn acc_pair_from_velo(&mut self) {
        if self.f.accu == choice::ACCU_USE_ACCS {
            self.accl_from_accs();
        } else {
            self.accs_from_accl();
        }
    }

    pub(super) fn velocity_above_base(&self) -> f64 {
        if self.f.velo > self.f.vbas {
            self.f.velo - self.f.vbas
        } else {
            self.f.velo
        }
    }
}
