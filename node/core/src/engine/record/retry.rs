//! §11 maybe_retry(): the end-of-motion evaluation of retries, MISS and SPMG Move.

use super::MotorRecord;
use zmotor_msgs::bits::{mip, msta};
use zmotor_msgs::menus::choice;
use zmotor_msgs::Field;

impl MotorRecord {
    pub(super) fn maybe_retry(&mut self) {
        let same_sense = (self.f.dir == choice::DIR_POS) == (self.f.mres >= 0.0);
        let user_cdir = if same_sense { self.f.cdir } else { 1 - self.f.cdir };
        let stopped_by_switch = (self.f.hls != 0 && user_cdir == 1) || (self.f.lls != 0 && user_cdir == 0);
        if self.f.diff.abs() >= self.f.rdbd && !stopped_by_switch {
            if self.f.rtry == 0 {
                self.f.mip &= mip::JOG_REQ;
            } else {
                // Departure Z17: a target accepted during the motion gets the whole budget; the
                // reference counts each re-target as a retry, so a stream of setpoints ends off
                // its last one with MISS 1.
                if std::mem::take(&mut self.retargeted) && self.f.rcnt != 0 {
                    self.f.rcnt = 0;
                }
                self.f.rcnt += 1;
                // Departure Z19: no retry while the controller cannot be reached (it would be
                // refused, or worse, run when the link comes back): the motion ends, missed.
                let unreachable = self.f.msta & msta::COMM_ERR != 0;
                if self.f.rcnt > self.f.rtry || unreachable {
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
            self.retargeted = false;
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
}
