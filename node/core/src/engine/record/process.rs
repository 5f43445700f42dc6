//! §8 process(): the top-level processing, its callback part and the entry into do_work.

use super::{Flow, MotorRecord, Reason};
use crate::engine::commands::{MotorCommand, Output};
use crate::time::seconds;
use zmotor_msgs::bits::mip;
use zmotor_msgs::menus::{choice, status};
use zmotor_msgs::{Field, Value};

impl MotorRecord {
    pub(super) fn process(&mut self) {
        self.follow_disable_link();
        match self.processing_disabled() {
            true => self.process_disabled(),
            false => self.process_enabled(),
        }
    }

    /// The record's own processing, §8.
    pub(super) fn process_enabled(&mut self) {
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
        self.follow_diff();
        let alarm = self.alarm();
        self.monitor(alarm);
        if self.f.dmov != 0 {
            self.outputs.push(Output::Done);
        }
    }

    /// A processing of a disabled record (DISA = DISV), as dbProcess does it: nothing is
    /// processed (the device's status, and what writes marked, wait for the next processing),
    /// the DISABLE alarm at severity DISS is raised once, with VAL posted, and waiting writes
    /// complete.
    pub(super) fn process_disabled(&mut self) {
        if self.f.stat != status::DISABLE {
            (self.f.stat, self.f.sevr) = (status::DISABLE, self.f.diss);
            self.post(Field::STAT);
            self.post(Field::SEVR);
            self.post(Field::VAL);
        }
        self.outputs.push(Output::WritesCompleted);
    }

    /// §15.3 update_values: copy the device's pending status into the record.
    pub(super) fn update_values(&mut self) -> Reason {
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

    pub(super) fn callback_phase(&mut self) -> Flow {
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
                        self.outputs.push(Output::StartDelay(seconds(self.f.dly)));
                    }
                }
            } else if dmov_just_set {
                if self.f.mip & mip::DELAY_REQ == 0 {
                    self.set_mip(self.f.mip | mip::DELAY_REQ);
                    self.outputs.push(Output::StartDelay(seconds(self.f.dly)));
                }
                self.f.dmov = 0;
                self.marks.clear(Field::DMOV);
                return Flow::Exit;
            }
        }
        Flow::DoWork
    }

    pub(super) fn enter_do_work(&mut self, reason: Reason, lvio_at_entry: i16) {
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
}
