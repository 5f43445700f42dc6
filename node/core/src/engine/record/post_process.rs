//! §10 postProcess(): what happens when a commanded phase has finished (backlash legs, homes,
//! jog backlash takeout, the end of a move).

use super::legs::Leg;
use super::MotorRecord;
use crate::engine::maths::{nint, MoveMaths};
use zmotor_msgs::bits::mip;
use zmotor_msgs::menus::choice;
use zmotor_msgs::Field;

impl MotorRecord {
    pub(super) fn post_process(&mut self) {
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
    pub(super) fn fractional_backlash_target(&mut self, m: &MoveMaths) -> f64 {
        let p = m.bpos + f64::from(self.f.frac) * (m.newpos - m.bpos);
        self.f.rval = nint(p);
        p
    }
}
