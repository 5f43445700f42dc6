//! §12 alarm_sub() and §13 monitor(): STAT/SEVR and what is posted at the end of a processing.

use super::MotorRecord;
use zmotor_msgs::bits::msta;
use zmotor_msgs::menus::{choice, severity, status};
use zmotor_msgs::{past_deadband, Field};

impl MotorRecord {
    /// Compute STAT/SEVR; says which changed.
    pub(super) fn alarm(&mut self) -> AlarmChange {
        let f = &self.f;
        let (mut nsta, mut nsev) = (status::NO_ALARM, severity::NO_ALARM);
        let limits_on = !(f.dhlm == 0.0 && f.dllm == 0.0);
        if f.udf != 0 {
            (nsta, nsev) = (status::UDF, severity::INVALID);
        // Departure Z4: the target is compared with the soft limits only while they are on (Q8).
        } else if f.hlsv != severity::NO_ALARM && (f.hls != 0 || (limits_on && f.dval > f.dhlm)) {
            (nsta, nsev) = (status::HIGH, f.hlsv);
        } else if f.hlsv != severity::NO_ALARM && (f.lls != 0 || (limits_on && f.dval < f.dllm)) {
            (nsta, nsev) = (status::LOW, f.hlsv);
        } else {
            // Departure Z18: the comm-error bit stays in MSTA, where clients look for the cause.
            if f.msta & msta::COMM_ERR != 0 {
                (nsta, nsev) = (status::COMM, severity::INVALID);
            }
            if f.msta & (msta::SLIP_STALL | msta::PROBLEM) != 0 && nsev < severity::MAJOR {
                (nsta, nsev) = (status::STATE, severity::MAJOR);
            }
        }
        let change = AlarmChange { status: nsta != self.f.stat, severity: nsev != self.f.sevr };
        self.f.stat = nsta;
        self.f.sevr = nsev;
        change
    }

    /// §13, in the record's order: SEVR and STAT when they changed (as recGblResetAlarms posts
    /// them), RBV, the readback group, then the marked fields of `POSTED_IF_MARKED`.
    pub(super) fn monitor(&mut self, alarm: AlarmChange) {
        use Field::*;
        if alarm.severity {
            self.post(SEVR);
        }
        let alarm_changed = alarm.status || alarm.severity;
        if alarm_changed {
            self.post(STAT);
            // recGblResetAlarms: the severity to acknowledge rises with the alarm, and follows
            // it down when transient alarms need no acknowledgement (ACKT NO).
            if self.f.ackt == choice::NO || self.f.sevr >= self.f.acks {
                self.f.acks = self.f.sevr;
                self.post(ACKS);
            }
        }
        let rbv_marked = self.marks.contains(RBV);
        self.marks.clear(RBV);
        let rbv = self.f.rbv;
        let rbv_due = if self.f.mdel == 0.0 && self.f.adel == 0.0 {
            rbv_marked || alarm_changed
        } else if rbv_marked {
            let mut due = alarm_changed;
            if past_deadband(self.f.mdel, self.f.mlst, rbv) {
                due = true;
                self.f.mlst = rbv;
            }
            if past_deadband(self.f.adel, self.f.alst, rbv) {
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
        self.flush_posts();
    }

    /// The posts of a write the record does not process (a field not process-passive, a stop
    /// of a disabled record): the marks §9.2 acts on, of a resolution written while the record
    /// was disabled, wait for its next processing.
    pub(super) fn flush_posts_between_processings(&mut self) {
        const ACTED_ON: [Field; 3] = [Field::MRES, Field::ERES, Field::UEIP];
        let pending = ACTED_ON.map(|field| self.marks.contains(field));
        self.flush_posts();
        for (field, pending) in ACTED_ON.into_iter().zip(pending) {
            if pending {
                self.mark(field);
            }
        }
    }

    /// Post every field still marked, in the record's order, then clear the marks.
    pub(super) fn flush_posts(&mut self) {
        let raw_sense = (self.f.dir == choice::DIR_POS) == (self.f.mres >= 0.0);
        for field in POSTED_IF_MARKED {
            if !self.marks.contains(field) {
                continue;
            }
            self.marks.clear(field);
            self.post(field);
            // The raw switch is posted with the user switch it feeds.
            match (field, raw_sense) {
                (Field::HLS, true) | (Field::LLS, false) => self.post(Field::RHLS),
                (Field::HLS, false) | (Field::LLS, true) => self.post(Field::RLLS),
                _ => {}
            }
        }
        // Every field the engine marks is in the list; anything else is still posted, last.
        for field in self.marks.take() {
            self.post(field);
        }
    }
}

/// Which of STAT and SEVR an `alarm` evaluation changed.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct AlarmChange {
    pub(super) status: bool,
    pub(super) severity: bool,
}

/// The fields §13 posts when marked, after the readback group, in the record's order.
const POSTED_IF_MARKED: [Field; 36] = {
    use Field::*;
    [
        VAL, DVAL, RVAL, TDIR, MIP, HLM, LLM, SPMG, RCNT, RLV, OFF, DHLM, DLLM, HLS, LLS, ATHM, MRES, ERES, UEIP, LVIO,
        STOP, SBAS, SREV, UREV, VELO, VBAS, MISS, MOVN, DMOV, STUP, JOGF, JOGR, HOMF, HOMR, RHLM, RLLM,
    ]
};
