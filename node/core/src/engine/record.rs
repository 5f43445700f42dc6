//! The motor record as a pure state machine. Section numbers (§) refer to
//! ../shared/spec/motor-record-behaviour.md, which this file follows step by step:
//! `process` is §8, `do_work` §9, `post_process` §10, `maybe_retry` §11, `alarm` §12,
//! `monitor` §13; helpers are §5, initialisation §6 and field writes §7.
//!
//! Inputs: `write` (a field put), `callback` (fresh device status), `delay_expired` (DLY timer).
//! Outputs: `Output`s (monitor posts, device transactions, timer requests, completion), drained
//! by the caller. The engine never reads a clock and performs no I/O.

use super::commands::{DeviceStatus, Inaction, MotorCommand, Output, WriteError};
use super::marks::Marks;
use super::maths::nint;
use zmotor_msgs::bits::{mip, msta};
use zmotor_msgs::menus::{choice, severity};
use zmotor_msgs::{Access, Field, Fields, Value};

mod do_work;
mod helpers;
mod init;
mod legs;
mod monitor;
mod post_process;
mod process;
mod retry;
mod special;

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
    refusal: Option<Inaction>,
    /// Departure Z9: a move was paused; its target is held and resumed by Go or Move.
    resume_on_go: bool,
    /// Departure Z17: a new target was accepted while a motion ran; the retry that goes to it
    /// starts a fresh retry budget.
    retargeted: bool,
    /// The latest value of the RDBL readback link (None: not readable).
    readback_link: Option<f64>,
    /// The latest value of the DOL desired-output link (None: not readable yet).
    desired: Option<f64>,
    /// The latest value of the SDIS link as DISA (None: no link, or not read yet).
    disable_link: Option<i16>,
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
            retargeted: false,
            readback_link: None,
            desired: None,
            disable_link: None,
            status_refresh: true,
        };
        record.check_speed_and_resolution();
        record.enforce_min_rdbd();
        record.outputs.clear();
        record
    }

    /// Soft Channel device support refuses GET_INFO, so STUP snaps back to OFF.
    #[must_use]
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

    /// SDIS read `value`: DISA takes it now and at every processing (as dbProcess reads SDIS
    /// into DISA, a short), so a DISA written meanwhile does not outlast the link's value.
    pub fn disable_value(&mut self, value: f64) {
        self.disable_link = Some(value.clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16);
        self.follow_disable_link();
    }

    /// SDIS now names another key (or none): its last value no longer sets DISA.
    pub fn forget_disable_value(&mut self) {
        self.disable_link = None;
    }

    /// DOL now names another key (or none): its last value is no longer the desired one.
    pub fn forget_desired_value(&mut self) {
        self.desired = None;
    }

    /// Soft Channel: the driven motor moved on its own (or the first readback arrived): the
    /// target will be re-synchronised at the next completion (§16.2).
    pub fn external_motion(&mut self) {
        self.f.dmov = 0;
        self.post(Field::DMOV);
        self.f.pp = 1;
        self.post(Field::PP);
    }

    /// A motion phase is open: DMOV is 0 and MIP names something under way (not only a request
    /// held by SPMG).
    pub fn motion_open(&self) -> bool {
        self.f.dmov == 0 && self.f.mip & !mip::JOG_REQ != mip::DONE
    }

    /// Every field's current value.
    pub fn fields(&self) -> &Fields {
        &self.f
    }

    /// One field's current value.
    pub fn get(&self, field: Field) -> Value {
        self.f.get(field)
    }

    /// Take everything the engine produced since the last call.
    pub fn drain_outputs(&mut self) -> std::vec::Drain<'_, Output> {
        self.outputs.drain(..)
    }

    /// The outputs so far, moved into `into` (empty: its room serves the next ones).
    pub(crate) fn take_outputs(&mut self, into: &mut Vec<Output>) {
        debug_assert!(into.is_empty());
        std::mem::swap(&mut self.outputs, into);
    }

    // ------------------------------------------------------------------ inputs

    /// A put to a field (§0.1 and §7): refused when read-only or when special() says so,
    /// otherwise stored, handled, posted and (for process-passive fields) processed.
    pub fn write(&mut self, field: Field, value: &Value) -> Result<(), WriteError> {
        let access = field.def().access;
        if access == Access::RO {
            return Err(WriteError::ReadOnly(field));
        }
        if field == Field::ACKS {
            self.acknowledge(value);
            return Ok(());
        }
        self.follow_disable_link();
        // Departure Z24: a disabled record is not processed, so the reference leaves a motion
        // under way that nobody may stop; here a write that stops one (STOP, SPMG Stop or Pause,
        // a jog let go) stops the motor (a node's own stops, of a released hold or a shutdown,
        // are writes of STOP). Departure Z25: one that would start a motion once the record is
        // enabled is refused (the reference keeps it and moves when no one is asking).
        let stops_while_disabled = self.processing_disabled() && self.ends_motion(field, value);
        if self.processing_disabled() && !stops_while_disabled && Self::starts_motion_later(field, value) {
            // Refused, but the record was asked to process: it says it is disabled.
            self.process_disabled();
            return Err(WriteError::RecordDisabled { field });
        }
        self.special_before(field, value)?;
        self.f.set(field, value);
        if field == Field::VAL {
            self.f.udf = 0;
        }
        if let Err(e) = self.special_after(field) {
            // Stored, but no post and no processing (§0.1 step 5).
            self.flush_posts_between_processings();
            return Err(e);
        }
        if field != Field::VAL {
            self.post(field);
        }
        self.refusal = None;
        if stops_while_disabled {
            let drops_held = match field {
                Field::STOP => true,
                Field::SPMG => value.as_f64() == Some(f64::from(choice::SPMG_STOP)),
                _ => false,
            };
            self.stop_while_disabled(drops_held);
        } else if access == Access::PP {
            self.process();
        } else {
            self.flush_posts_between_processings();
        }
        match self.refusal.take() {
            Some(reason) => Err(WriteError::NotActedUpon { field, reason }),
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

    // ------------------------------------------------------------------ small pieces

    fn dirsign(&self) -> f64 {
        if self.f.dir == choice::DIR_POS {
            1.0
        } else {
            -1.0
        }
    }

    /// An acknowledgement of alarms up to severity `value` (dbAccess's putAcks, what a
    /// DBR_PUT_ACKS does): ACKS clears when it is at least ACKS; the value is not stored.
    fn acknowledge(&mut self, value: &Value) {
        let severity = value.as_f64().unwrap_or(0.0);
        if severity >= f64::from(self.f.acks) {
            self.f.acks = severity::NO_ALARM;
            self.post(Field::ACKS);
        }
    }

    /// DISA as SDIS last read it, if it has.
    fn follow_disable_link(&mut self) {
        if let Some(disa) = self.disable_link.filter(|disa| *disa != self.f.disa) {
            self.f.disa = disa;
            self.post(Field::DISA);
        }
    }

    /// A write that would start a motion at the record's next processing: a target, a jog or
    /// home button pressed, SPMG Move or Go.
    fn starts_motion_later(field: Field, value: &Value) -> bool {
        let pressed = value.as_f64() != Some(0.0);
        match field {
            _ if field.sets_target() => true,
            Field::HOMF | Field::HOMR | Field::JOGF | Field::JOGR => pressed,
            Field::SPMG => matches!(value.as_f64().map(|v| v as u16), Some(choice::SPMG_MOVE | choice::SPMG_GO)),
            _ => false,
        }
    }

    /// Whether the record is disabled (DISA = DISV): it is not processed.
    fn processing_disabled(&self) -> bool {
        self.f.disa == self.f.disv
    }

    /// A write that ends a motion: STOP, SPMG Stop or Pause, or a jog's button let go while it
    /// jogs.
    fn ends_motion(&self, field: Field, value: &Value) -> bool {
        let jogging = self.f.mip & (mip::JOGF | mip::JOGR) != 0;
        let spmg = value.as_f64().map(|v| v as u16);
        match field {
            Field::STOP => value.as_f64() != Some(0.0),
            Field::SPMG => matches!(spmg, Some(choice::SPMG_STOP | choice::SPMG_PAUSE)),
            Field::JOGF | Field::JOGR => jogging && value.as_f64() == Some(0.0),
            _ => false,
        }
    }

    /// Departure Z24: stop the motor of a disabled record, without processing it (its MOVN and
    /// readback are as the last processing left them): during a motion, MIP STOP and PP, so that
    /// the first processing once enabled ends it where it stopped (no retry toward the target),
    /// the buttons cleared; at rest, a STOP (not a pause) drops a held target, as it does
    /// enabled.
    fn stop_while_disabled(&mut self, drops_held: bool) {
        let at_rest = self.f.mip == mip::DONE || (self.f.mip & mip::STOP != 0 && self.f.movn == 0);
        match self.f.mip {
            // At rest, or paused and stopped: a STOP ends what was held where the motor stands.
            _ if at_rest && drops_held => self.drop_held_target(),
            // Stopping already: a STOP drops what a pause held; the end comes once enabled.
            m if m & mip::STOP != 0 => self.resume_on_go &= !drops_held,
            mip::DONE => {}
            _ => {
                self.f.pp = 1;
                self.clear_buttons();
                if self.f.mip & mip::DELAY_REQ == 0 {
                    self.set_mip(mip::STOP);
                }
            }
        }
        self.send(vec![MotorCommand::StopAxis]);
        if self.f.stop != 0 {
            self.f.stop = 0;
            self.mark(Field::STOP);
        }
        self.flush_posts_between_processings();
    }

    /// Departures Z9/Z14: a stop at rest drops a target held by SPMG (a paused move's, or one
    /// written while stopped): the axis stays where it is.
    fn drop_held_target(&mut self) {
        let held = self.f.mip == mip::DONE && self.f.dval != self.f.ldvl;
        if std::mem::take(&mut self.resume_on_go) || held {
            self.sync_target_position();
            self.set_mip(mip::DONE);
            self.f.dmov = 1;
            self.mark(Field::DMOV);
        }
    }

    /// Departure Z11: a servo whose control is disabled (CNEN = Disable) is not asked to move;
    /// the reference sends the move to a dead amplifier.
    fn disabled_refusal(&self) -> Option<Inaction> {
        (self.f.msta & msta::GAIN_SUPPORT != 0 && self.f.cnen == 0).then_some(Inaction::Disabled)
    }

    /// Departure Z12: a target held by SPMG Stop/Pause (or behind a held home) shows in VAL,
    /// DVAL and RVAL alike while it waits; the reference converts only the field written.
    /// `dval_before` is DVAL as the processing found it: DVAL is posted once, when it changes.
    fn keep_held_target_consistent(&mut self, dval_before: f64) {
        if self.f.val != self.f.lval {
            self.f.dval = (self.f.val - self.f.off) / self.dirsign();
        } else if self.f.rval != self.f.lrvl {
            self.f.dval = f64::from(self.f.rval) * self.f.mres;
        }
        let (val, rval) = (self.f.dval * self.dirsign() + self.f.off, nint(self.f.dval / self.f.mres));
        for (field, changed) in [
            (Field::VAL, val != self.f.val),
            (Field::RVAL, rval != self.f.rval),
            (Field::DVAL, self.f.dval != dval_before),
        ] {
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
