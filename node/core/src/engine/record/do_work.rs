//! §9 do_work(): acting on requests: STOP/SPMG, resolution changes, the source of the target,
//! the buttons (home, jog, tweak, relative, raw) and the move evaluation.

use super::legs::{at_least_one_step, Leg};
use super::{MotorRecord, Reason};
use crate::engine::commands::{Inaction, LimitSwitch, MotorCommand};
use crate::engine::maths::{nint, raw_position, MoveMaths};
use zmotor_msgs::bits::{mip, msta};
use zmotor_msgs::menus::choice;
use zmotor_msgs::{Field, Value};

impl MotorRecord {
    pub(super) fn do_work(&mut self, reason: Reason) {
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
                if (self.f.spmg == choice::SPMG_STOP || stop_req) && self.stop_request() {
                    return;
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
        let dval_before = self.f.dval;
        if self.f.val != self.f.lval {
            self.mark(VAL);
            if self.set_mode() && self.f.foff == choice::FOFF_VARIABLE {
                // Departure Z12: a target held by SPMG is dropped; the calibration is of the dial
                // position the record stands at.
                if self.f.dval != self.f.ldvl {
                    (self.f.dval, self.f.rval) = (self.f.ldvl, self.f.lrvl);
                    self.mark(DVAL);
                    self.mark(RVAL);
                }
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
                self.keep_held_target_consistent(dval_before);
                // Departure Z14: a held target keeps DMOV 0, also when this very processing
                // ended the motion before it (a relative target written while a jog stopped).
                if self.f.dval != self.f.ldvl && self.f.dmov == 1 {
                    self.f.dmov = 0;
                    if self.marks.contains(DMOV) {
                        // Set to 1 in this processing and not posted yet: clients still have 0.
                        self.marks.clear(DMOV);
                    } else {
                        self.mark(DMOV);
                    }
                }
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

    /// §9.1 STOP (or SPMG Stop): at rest, STOP_AXIS and the end of what was held (true: nothing
    /// more to do); during a motion, its end prepared (false: MIP STOP and STOP_AXIS follow).
    fn stop_request(&mut self) -> bool {
        let m = self.f.mip;
        // Departure Z22: a retry leg under way stops as any motion does (DMOV 1 once the motor
        // has stopped); the reference ends it at once, DMOV 1 while it decelerates.
        let retry_at_rest = m & mip::RETRY != 0 && self.f.movn == 0;
        if m == mip::DONE || m & mip::STOP != 0 || retry_at_rest {
            self.drop_held_target();
            if m & mip::RETRY != 0 {
                self.set_mip(mip::DONE);
                self.f.dmov = 1;
                self.mark(Field::DMOV);
            }
            self.send(vec![MotorCommand::StopAxis]);
            return true;
        }
        if self.f.movn != 0 {
            self.f.pp = 1;
            self.clear_buttons();
        } else {
            self.sync_target_position();
        }
        false
    }

    /// §9.3 home, jog, tweak, relative and raw requests; true when do_work is over.
    pub(super) fn handle_buttons(&mut self, stop_or_pause: bool) -> bool {
        use Field::*;
        let dir_pos = self.f.dir == choice::DIR_POS;
        let fwd_blocked = if dir_pos { self.f.hls } else { self.f.lls } != 0;
        let rev_blocked = if dir_pos { self.f.lls } else { self.f.hls } != 0;
        // Departure Z6: a home refused by an active switch is reset and reported, never
        // started later (the reference latches it, Q25).
        for (button, blocked, switch) in [(HOMF, fwd_blocked, LimitSwitch::High), (HOMR, rev_blocked, LimitSwitch::Low)]
        {
            if blocked && self.f.get(button) != Value::Int(0) && self.f.mip & mip::HOME_GROUP == 0 {
                self.f.set(button, &Value::Int(0));
                self.mark(button);
                self.refusal = Some(Inaction::SwitchActive { button, switch });
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
                self.refusal = Some(Inaction::JogNearSoftLimit);
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
    pub(super) fn evaluate_move(&mut self, lvio_at_entry: i16) {
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
            self.retargeted = false;
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
        // Departure Z20: a target whose raw position the driver cannot hold (32 bits, as RVAL) is
        // refused; the reference clamps it and drives the carriage towards the clamped position.
        let raw_target = self.f.dval / self.f.mres;
        let refusal = if lvio {
            Some(Inaction::SoftLimits { dial_target: self.f.dval, dllm: self.f.dllm, dhlm: self.f.dhlm })
        } else if raw_position(raw_target).is_none() {
            Some(Inaction::TargetBeyondRawRange {
                dial_target: self.f.dval,
                mres: self.f.mres,
                steps: raw_target.round(),
            })
        } else if self.f.urip == choice::YES && self.readback_link.is_none() {
            Some(Inaction::ReadbackUnreadable { link: self.f.rdbl.clone() })
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

        if self.f.mip != mip::DONE && self.f.mip != mip::RETRY {
            // A new target while a motion runs: nothing is sent now (§14.6).
            self.retargeted |= self.f.dval != self.f.ldvl;
        } else {
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
}
