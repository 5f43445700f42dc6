//! One axis as a sans-IO unit: the motor record, its device support and its driver (or its
//! Soft Channel links), on one injected clock. The caller feeds writes, link updates and time
//! (`write`, `link_update`, `handle_timeout`), asks when to call again (`poll_timeout`) and takes
//! `AxisEvent`s (field posts, driver commands, puts to other keys, completions). The Zenoh
//! adapter is a thin loop around this.

use crate::device::DeviceSupport;
use crate::driver::soft::{InputLink, Reaction, SoftChannel};
use crate::driver::{execute, Driver};
use crate::engine::{DeviceStatus, MotorCommand, MotorRecord, Output, WriteError};
use crate::time::Instant;
use std::time::Duration;
use zmotor_msgs::bits::msta;
use zmotor_msgs::menus::choice;
use zmotor_msgs::{DriverCommand, Field, Fields, Value};

/// How long a Soft Channel axis waits after DINP reports "done" before acting on it, so that
/// the readback, which often comes through a calc link (one hop more), arrives first. The
/// reference gets the same order from task priorities (spec §20.8).
pub const SOFT_DONE_SETTLE: Duration = Duration::from_millis(50);

/// Bound on callback rounds after one input: each round is a transaction that asked for fresh
/// status; the record never chains more than a few.
const MAX_CALLBACK_ROUNDS: usize = 16;

/// The n-th processing of an axis that ended with DMOV = 1, counted from its boot. A write's
/// motion ends with the first completion after the one its `WriteAccepted` names.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Completion(u64);

/// A write the axis took in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WriteAccepted {
    /// The last completion before the write was processed: whatever the write started has
    /// finished at the first `AxisEvent::Done` after it (a put-callback's answer).
    pub after: Completion,
    /// Where a write of a target (`Field::sets_target`) asked the axis to go: VAL as the record
    /// took it, before the driver said anything (a motion stopped at once by a limit switch
    /// sets VAL back to where it stopped).
    pub target: Option<f64>,
}

impl WriteAccepted {
    /// Whether `done` ends what this write started.
    pub fn is_ended_by(&self, done: Completion) -> bool {
        done > self.after
    }
}

/// Something the outside world must hear about.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq)]
pub enum AxisEvent {
    /// A field's new value.
    Post(Field, Value),
    /// A command delivered to the driver, at `at`.
    Driver {
        /// The command, in raw units.
        command: DriverCommand,
        /// When it was delivered.
        at: Instant,
    },
    /// A processing ended with DMOV = 1 (forward link, put-with-completion).
    Done(Completion),
    /// A processing of a disabled record: the writes waiting before it are answered, as an
    /// IOC completes a put-callback; nothing ended (holds still hold a motion under way).
    WritesCompleted(Completion),
    /// A plain write of `value` to another key: an output link (OUT, STOO, RLNK, FLNK) or a
    /// device directive's put (`@PUT(key, value)@` in PREM or POST).
    Put {
        /// The key written to.
        key: String,
        /// The value, as text.
        value: String,
    },
}

/// Motion commands waiting for a PREM delay to pass.
struct HeldMotion {
    due: Instant,
    commands: Vec<DriverCommand>,
    wants_callback: bool,
}

/// Polling periods of the status loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PollRates {
    /// Time between status polls while the axis moves (the readback period).
    pub moving: Duration,
    /// Time between status polls while idle (to notice external changes).
    pub idle: Duration,
}

impl Default for PollRates {
    fn default() -> Self {
        Self { moving: Duration::from_millis(100), idle: Duration::from_secs(1) }
    }
}

/// An axis ready to be built: its name, configured fields, what drives it, poll rates.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisPlan {
    /// The axis's name, its key chunk.
    pub name: String,
    /// Field values to boot with (launch file, restored state).
    pub fields: Fields,
    /// What stands behind the record.
    pub driver: DriverPlan,
    /// Status poll periods.
    pub rates: PollRates,
    /// Whether it jogs only under a hold (the jog deadman).
    pub jog_hold: JogHold,
}

/// Whether an axis jogs only under a hold (the jog deadman).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum JogHold {
    /// A plain JOGF/JOGR = 1 is taken, as the record takes it (with a warning, once).
    #[default]
    Optional,
    /// A JOGF/JOGR = 1 without a hold is refused.
    Required,
}

/// What drives an axis.
#[derive(Clone, Debug, PartialEq)]
pub enum DriverPlan {
    /// The physical simulator with these mechanics.
    Sim(crate::driver::sim::SimConfig),
    /// Soft Channel device support: the axis drives other keys through its links.
    Soft,
    /// A channel of a motor controller, which polls it and reports its status.
    Controller {
        /// The controller's name in the deployment.
        controller: String,
        /// The controller's own number for the axis.
        channel: usize,
    },
}

impl AxisPlan {
    /// Boot the axis at `now`. An axis on a controller boots on the status its controller last
    /// reported (None: not reached yet).
    pub fn build(self, now: Instant, controller_status: Option<DeviceStatus>) -> Axis {
        match self.driver {
            DriverPlan::Sim(sim) => {
                Axis::new(self.fields, Box::new(crate::driver::sim::SimAxis::new(sim)), self.rates, now)
            }
            DriverPlan::Soft => Axis::new_soft(self.fields, self.rates, now),
            DriverPlan::Controller { .. } => Axis::new_on_controller(self.fields, controller_status, self.rates, now),
        }
    }

    /// The record's input links that are set, with the key each follows.
    pub fn input_links(&self) -> Vec<(InputLink, String)> {
        InputLink::ALL
            .into_iter()
            .filter_map(|link| match self.fields.get(link.field()) {
                Value::Text(key) if !key.is_empty() => Some((link, key)),
                _ => None,
            })
            .collect()
    }
}

/// What stands behind the record.
enum Device {
    /// asyn-style device support in front of a driver the axis polls (the simulator).
    Driver { support: DeviceSupport, driver: Box<dyn Driver> },
    /// asyn-style device support in front of a controller channel ("model 3"): the controller
    /// polls, the axis keeps the status it last reported, and a motion command makes it "not
    /// done" at once. The commands leave as `AxisEvent::Driver` for the controller.
    Controller {
        support: DeviceSupport,
        status: DeviceStatus,
        /// A status arrived that the record has not been shown yet.
        reported: bool,
        /// Motion commands sent: a status the controller read before the last of them is old.
        motions: u64,
    },
    /// Soft Channel device support: the axis drives other keys.
    Soft(SoftChannel),
}

/// The record, its device and their shared clock (see the module documentation).
pub struct Axis {
    record: MotorRecord,
    device: Device,
    /// The latest RDBL value; None until the link has delivered one. An axis without RDBL
    /// reads it as a constant 0, as EPICS reads a constant link.
    readback_link: Option<f64>,
    now: Instant,
    last_status: DeviceStatus,
    delay_deadline: Option<Instant>,
    /// The next status poll; None for a device that is never polled (Soft Channel).
    next_poll: Option<Instant>,
    rates: PollRates,
    events: Vec<AxisEvent>,
    /// The record's outputs being handled, kept for their room (an axis polls a hundred times a second).
    record_outputs: Vec<Output>,
    held: Option<HeldMotion>,
    /// DMOV 0 has been posted and DMOV 1 not yet: a motion is under way.
    motion_posted: bool,
    /// A command that starts motion went out (PREM with it) since DMOV 0: its end sends POST. A
    /// refused move pulses DMOV with nothing sent, and sends neither.
    motion_commanded: bool,
    /// When a DINP "done" is to be acted upon (Soft Channel).
    done_due: Option<Instant>,
    /// The last completion posted.
    completed: Completion,
}

impl Axis {
    /// Boot an axis on a driver (§6): restore decision, first status, record initialisation.
    pub fn new(fields: Fields, mut driver: Box<dyn Driver>, rates: PollRates, now: Instant) -> Self {
        driver.advance(now);
        let device = Device::Driver { support: DeviceSupport::default(), driver };
        let mut axis = Self::assemble(MotorRecord::new(fields), device, rates, now);
        let init = axis.record.fields().init.clone();
        axis.run_primitive(&init);
        let restore = axis.record.restore_commands(axis.device_status().position);
        axis.deliver(&restore);
        axis.boot()
    }

    /// Boot an axis on a controller's channel, on the status the controller last reported. An
    /// axis whose controller has not been reached boots with a communication error, at 0, and
    /// does not restore an autosaved position (it cannot know where the stage is).
    pub fn new_on_controller(fields: Fields, status: Option<DeviceStatus>, rates: PollRates, now: Instant) -> Self {
        let known = status.filter(|s| s.msta & msta::COMM_ERR == 0);
        let status = status.unwrap_or(DeviceStatus { msta: msta::DONE | msta::COMM_ERR, ..DeviceStatus::default() });
        let device = Device::Controller { support: DeviceSupport::default(), status, reported: false, motions: 0 };
        let mut axis = Self::assemble(MotorRecord::new(fields), device, rates, now);
        let init = axis.record.fields().init.clone();
        axis.run_primitive(&init);
        if let Some(known) = known {
            let restore = axis.record.restore_commands(known.position);
            axis.deliver(&restore);
        }
        axis.boot()
    }

    /// What the axis's controller reported at `now` for its channel, read after `motions`
    /// motion commands of the axis had reached it: processed as the record's device callback
    /// (when it changed, or while a motion is open). A status read before the axis's last motion
    /// command reached the controller (it crossed that command on the way) is dropped: it would
    /// end a motion that has not begun.
    pub fn controller_status(&mut self, now: Instant, status: DeviceStatus, motions: u64) {
        if let Device::Controller { status: kept, reported, motions: sent, .. } = &mut self.device {
            if motions < *sent {
                return;
            }
            *kept = status;
            *reported = true;
        }
        self.tick(now, false);
    }

    /// Boot a Soft Channel axis (§16.1): it drives its OUT key and reads RDBL/RINP/DINP.
    pub fn new_soft(fields: Fields, rates: PollRates, now: Instant) -> Self {
        let soft = SoftChannel::new(&fields.out, &fields.stoo, &fields.dinp, fields.dmov);
        let record = MotorRecord::new(fields).without_status_refresh();
        Self::assemble(record, Device::Soft(soft), rates, now).boot()
    }

    fn assemble(record: MotorRecord, device: Device, rates: PollRates, now: Instant) -> Self {
        let readback_link = record.fields().rdbl.is_empty().then_some(0.0);
        Self {
            record,
            device,
            readback_link,
            now,
            last_status: DeviceStatus::default(),
            delay_deadline: None,
            next_poll: None,
            rates,
            events: Vec::new(),
            record_outputs: Vec::new(),
            held: None,
            motion_posted: false,
            motion_commanded: false,
            done_due: None,
            completed: Completion::default(),
        }
    }

    fn boot(mut self) -> Self {
        self.last_status = self.device_status();
        self.record.init(self.last_status);
        self.pump();
        if matches!(self.device, Device::Driver { .. }) {
            self.next_poll = Some(self.now + self.rates.idle);
        }
        self
    }

    /// The record, for reads of any field.
    pub fn record(&self) -> &MotorRecord {
        &self.record
    }

    /// The record's fields.
    pub fn fields(&self) -> &Fields {
        self.record.fields()
    }

    /// The latest time the axis was given.
    pub fn now(&self) -> Instant {
        self.now
    }

    /// A field write at time `now`. What was due before it is acted on first (a Soft Channel
    /// "done" still settling ends the motion before it, as the reference processes the DINP
    /// callback before a later put), and the write acts on the readback of this moment, not
    /// of the last poll: a relative move from a stale readback would miss by the distance since.
    #[must_use = "a refusal is to be reported, and the WriteAccepted tells the end of the write's own motion"]
    pub fn write(&mut self, now: Instant, field: Field, value: &Value) -> Result<WriteAccepted, WriteError> {
        self.advance(now);
        if self.done_due.take().is_some() {
            self.apply_link(InputLink::Done, 1.0);
        }
        let status = self.device_status();
        if self.polled() && self.held.is_none() && status != self.last_status {
            self.callback(status);
        }
        let after = self.completed;
        let result = self.record.write(field, value);
        let accepted = WriteAccepted { after, target: field.sets_target().then(|| self.record.fields().val) };
        if result.is_ok() && field.def().kind == zmotor_msgs::Kind::Link {
            self.relinked(field);
        }
        self.pump();
        self.schedule_poll();
        result.map(|()| accepted)
    }

    /// A link field took a new key at run time: what the device and the record knew of the
    /// old one goes. (Output links are read from their field at each use.)
    fn relinked(&mut self, field: Field) {
        let f = self.record.fields();
        match field {
            Field::RDBL => self.readback_link = f.rdbl.is_empty().then_some(0.0),
            Field::DOL => self.record.forget_desired_value(),
            Field::SDIS => self.record.forget_disable_value(),
            _ => {}
        }
        let f = self.record.fields();
        if let Device::Soft(soft) = &mut self.device {
            soft.relink(&f.out, &f.stoo, &f.dinp);
        }
    }

    /// A new value on one of the record's input links (RDBL, RINP, DINP, DOL, SDIS) at time `now`.
    pub fn link_update(&mut self, now: Instant, link: InputLink, value: f64) {
        self.advance(now);
        match link {
            InputLink::Desired => {
                self.record.desired_value(value);
                self.pump();
                return;
            }
            InputLink::Disable => {
                self.record.disable_value(value);
                self.pump();
                return;
            }
            InputLink::Readback => self.readback_link = Some(value),
            InputLink::Done if matches!(self.device, Device::Soft(_)) => {
                if value != 0.0 {
                    self.done_due = Some(self.now + SOFT_DONE_SETTLE);
                    return;
                }
                self.done_due = None;
            }
            _ => {}
        }
        self.apply_link(link, value);
    }

    /// A link's value found when the link connected, or when its source came back, at `now`: as
    /// an update, but DOL's, which is not acted upon: in closed loop it would start a motion, and
    /// a motion never comes from a (re)connection (the next update of DOL drives the axis, as an
    /// NPP DOL is read only when the record processes).
    pub fn link_read(&mut self, now: Instant, link: InputLink, value: f64) {
        if link != InputLink::Desired {
            self.link_update(now, link, value);
        }
    }

    /// The source of an input link is gone (the node serving it stopped): RDBL cannot be read,
    /// as a link whose PV disconnected (spec §5.10): a soft motor's motion under way is stopped
    /// now, a driven one's at its next poll, and no move starts until RDBL is read again. The
    /// other links keep their last value.
    pub fn link_lost(&mut self, now: Instant, link: InputLink) {
        self.advance(now);
        if link != InputLink::Readback || self.readback_link.is_none() {
            return;
        }
        self.readback_link = None;
        if matches!(self.device, Device::Soft(_)) {
            let status = self.device_status();
            self.callback(status);
        } else {
            self.pump();
        }
    }

    fn apply_link(&mut self, link: InputLink, value: f64) {
        let f = self.record.fields();
        let (dmov, locked, mres) = (f.dmov, f.lock == choice::YES, f.mres);
        let reaction = match &mut self.device {
            Device::Soft(soft) => soft.update(link, value, dmov, locked, mres),
            // With a driver, the readback link is read at the next processing.
            Device::Driver { .. } | Device::Controller { .. } => Reaction::Nothing,
        };
        if matches!(reaction, Reaction::ExternalMotion | Reaction::ExternalMotionThenCallback) {
            self.record.external_motion();
        }
        if matches!(reaction, Reaction::Callback | Reaction::ExternalMotionThenCallback) {
            let status = self.device_status();
            self.callback(status);
        } else {
            self.pump();
        }
    }

    /// Time passed to `now`: whatever was due (a PREM delay, a Soft Channel "done", the DLY
    /// timer, a poll, the simulator's end of motion) happens.
    pub fn handle_timeout(&mut self, now: Instant) {
        self.tick(now, false);
    }

    /// The driver's state changed from outside the record (a simulator setting): read and
    /// process its status now.
    pub fn refresh_status(&mut self, now: Instant) {
        self.tick(now, true);
    }

    fn tick(&mut self, now: Instant, force_poll: bool) {
        // Read before advancing: advancing past the end of a motion ends it, and the driver then
        // no longer announces it.
        let motion_event_due = self.next_event().is_some_and(|t| now >= t);
        self.advance(now);
        if self.held.as_ref().is_some_and(|h| self.now >= h.due) {
            let held = self.held.take().expect("checked above");
            self.execute_all(held.commands);
            if held.wants_callback {
                let status = self.device_status();
                self.callback(status);
            }
        }
        if self.done_due.is_some_and(|d| self.now >= d) {
            self.done_due = None;
            self.apply_link(InputLink::Done, 1.0);
        }
        if self.delay_deadline.is_some_and(|d| self.now >= d) {
            self.delay_deadline = None;
            self.record.delay_expired();
            self.pump();
        }
        let reported = match &mut self.device {
            Device::Controller { reported, .. } => std::mem::take(reported),
            _ => false,
        };
        let poll_due = reported || self.next_poll.is_some_and(|t| self.now >= t);
        // While a PREM delay holds a motion back, status would only look stale "done".
        if self.polled() && self.held.is_none() && (force_poll || poll_due || motion_event_due) {
            let status = self.device_status();
            // While a motion phase is open every poll is a callback, as a controller's poller
            // would report: an end of motion that arrived while the record ignored it (STUP
            // BUSY) is then still seen. A request held by SPMG is not a motion: it waits quietly.
            if status != self.last_status || force_poll || self.record.motion_open() {
                self.callback(status);
            }
            self.schedule_poll();
        }
    }

    /// When `handle_timeout` should be called next; None when nothing is due (a Soft Channel
    /// axis waiting for its links).
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        let due =
            [self.next_poll, self.delay_deadline, self.next_event(), self.held.as_ref().map(|h| h.due), self.done_due];
        due.into_iter().flatten().min().map(|t| t.max(self.now))
    }

    /// When something happens by itself next, apart from the periodic polls: the simulator's
    /// end of motion, the DLY deadline, a PREM delay, a Soft Channel "done". A runner may keep
    /// these on a finer clock than the polls (the end of a motion is reported when it happens).
    #[must_use]
    pub fn event_timeout(&self) -> Option<Instant> {
        let due = [self.delay_deadline, self.next_event(), self.held.as_ref().map(|h| h.due), self.done_due];
        due.into_iter().flatten().min().map(|t| t.max(self.now))
    }

    /// A motion sequence is open or the motor moves.
    pub fn is_busy(&self) -> bool {
        self.record.fields().dmov == 0 || self.record.fields().movn != 0
    }

    /// Take the events produced since the last call, in order.
    pub fn drain_events(&mut self) -> std::vec::Drain<'_, AxisEvent> {
        self.events.drain(..)
    }

    /// The events so far, moved into `into` (empty: its room serves the next ones).
    pub(crate) fn take_events(&mut self, into: &mut Vec<AxisEvent>) {
        debug_assert!(into.is_empty());
        std::mem::swap(&mut self.events, into);
    }

    /// The simulator behind this axis, if it is simulated.
    pub fn simulation(&mut self) -> Option<&mut crate::driver::sim::SimAxis> {
        match &mut self.device {
            Device::Driver { driver, .. } => driver.simulation(),
            Device::Controller { .. } | Device::Soft(_) => None,
        }
    }

    fn device_status(&self) -> DeviceStatus {
        let status = match &self.device {
            Device::Driver { driver, .. } => driver.status(),
            Device::Controller { status, .. } => *status,
            Device::Soft(soft) => soft.status(),
        };
        let status = DeviceStatus { readback: self.readback_link, ..status };
        // Garbage from a device (a position or speed that is no number, or beyond the record's
        // 32-bit raw range) is a failed exchange, never a position: the last one stands, under
        // a communication error, until the device reports one again.
        let raw = |x: f64| x.is_finite() && (f64::from(i32::MIN)..=f64::from(i32::MAX)).contains(&x.round());
        if raw(status.position) && raw(status.encoder_position) && raw(status.velocity) {
            return status;
        }
        let last = self.last_status;
        DeviceStatus {
            position: last.position,
            encoder_position: last.encoder_position,
            velocity: last.velocity,
            msta: status.msta | msta::COMM_ERR,
            ..status
        }
    }

    /// Status reaches a record on a driver or a controller from the device; a Soft Channel
    /// record only hears its links.
    fn polled(&self) -> bool {
        !matches!(self.device, Device::Soft(_))
    }

    fn next_event(&self) -> Option<Instant> {
        match &self.device {
            Device::Driver { driver, .. } => driver.next_event(),
            Device::Controller { .. } | Device::Soft(_) => None,
        }
    }

    fn advance(&mut self, now: Instant) {
        self.now = self.now.max(now);
        if let Device::Driver { driver, .. } = &mut self.device {
            driver.advance(self.now);
        }
    }

    fn schedule_poll(&mut self) {
        let Some(next_poll) = self.next_poll else { return };
        let period =
            if self.is_busy() || self.last_status.msta & msta::DONE == 0 { self.rates.moving } else { self.rates.idle };
        // A poller keeps its cadence: a poll that ran a little late does not delay the next ones.
        let on_cadence = next_poll + period;
        self.next_poll =
            Some(if self.now >= next_poll && on_cadence > self.now { on_cadence } else { self.now + period });
    }

    /// Process the record as a device callback with `status`, then carry out what it asks.
    fn callback(&mut self, status: DeviceStatus) {
        self.last_status = status;
        self.record.callback(status);
        self.pump();
    }

    /// Deliver one transaction; true if the record must now be processed with fresh status.
    /// PREM runs before anything that starts motion, and its PUT delay holds the motion back.
    fn deliver(&mut self, transaction: &[MotorCommand]) -> bool {
        let translation = match &mut self.device {
            Device::Driver { support, .. } | Device::Controller { support, .. } => support.translate(transaction),
            Device::Soft(soft) => {
                let (puts, wants_callback) = soft.translate(transaction, self.record.fields().dval);
                for (key, value) in puts {
                    self.events.push(AxisEvent::Put { key, value: value.to_string() });
                }
                return wants_callback;
            }
        };
        let starts_motion = translation.commands.iter().any(DriverCommand::starts_motion);
        if translation.commands.iter().any(|c| matches!(c, DriverCommand::Stop { .. })) {
            self.held = None;
        }
        if starts_motion {
            self.motion_commanded = true;
            let prem = self.record.fields().prem.clone();
            let delay = self.run_primitive(&prem);
            if delay > Duration::ZERO {
                self.held = Some(HeldMotion {
                    due: self.now + delay,
                    commands: translation.commands,
                    wants_callback: translation.wants_callback,
                });
                return false;
            }
        }
        self.execute_all(translation.commands);
        translation.wants_callback
    }

    fn execute_all(&mut self, commands: Vec<DriverCommand>) {
        for command in commands {
            match &mut self.device {
                Device::Driver { driver, .. } => execute(driver.as_mut(), &command),
                // As asyn's model 3: "not done" from the moment motion is commanded, until a
                // poll says otherwise. A problem is the last command's: the controller layer
                // clears it with the next command, and a stale one would end this motion at once.
                Device::Controller { status, motions, .. } if command.starts_motion() => {
                    *motions += 1;
                    status.msta &= !(msta::DONE | msta::PROBLEM);
                }
                Device::Controller { .. } => {}
                Device::Soft(_) => return,
            }
            self.events.push(AxisEvent::Driver { command, at: self.now });
        }
    }

    /// Carry out an INIT/PREM/POST string: its puts as events, its text to the driver.
    /// Returns the longest PUT delay.
    fn run_primitive(&mut self, source: &str) -> Duration {
        if source.is_empty() {
            return Duration::ZERO;
        }
        let primitive = crate::primitives::parse(source);
        for put in &primitive.puts {
            self.events.push(AxisEvent::Put { key: put.key.clone(), value: put.value.clone() });
        }
        if let Some(text) = primitive.text.clone() {
            self.execute_all(vec![DriverCommand::Raw { text }]);
        }
        primitive.delay()
    }

    /// A motion has finished (DMOV 0 → 1) or met a limit switch: POST if it was commanded.
    fn motion_finished(&mut self, completed: bool) {
        if self.motion_commanded {
            let post = self.record.fields().post.clone();
            self.run_primitive(&post);
        }
        if completed {
            self.motion_commanded = false;
        }
    }

    /// Carry out the record's outputs; a transaction that asks for fresh status gets a
    /// callback processing, as asyn device support does when the driver write returns.
    fn pump(&mut self) {
        let mut outputs = std::mem::take(&mut self.record_outputs);
        for _ in 0..MAX_CALLBACK_ROUNDS {
            self.record.take_outputs(&mut outputs);
            let mut wants_callback = false;
            for output in outputs.drain(..) {
                match output {
                    Output::Post(field, value) => {
                        let completed = field == Field::DMOV
                            && value == Value::Int(1)
                            && std::mem::replace(&mut self.motion_posted, false);
                        let switch_met =
                            matches!(field, Field::HLS | Field::LLS) && value == Value::Int(1) && self.motion_posted;
                        if field == Field::DMOV && value == Value::Int(0) {
                            self.motion_posted = true;
                        }
                        self.events.push(AxisEvent::Post(field, value));
                        if completed || switch_met {
                            self.motion_finished(completed);
                        }
                    }
                    Output::Transaction(transaction) => wants_callback |= self.deliver(&transaction),
                    Output::StartDelay(delay) => self.delay_deadline = Some(self.now + delay),
                    Output::WritesCompleted => {
                        self.completed = Completion(self.completed.0 + 1);
                        self.events.push(AxisEvent::WritesCompleted(self.completed));
                    }
                    Output::Done => {
                        self.completed = Completion(self.completed.0 + 1);
                        self.events.push(AxisEvent::Done(self.completed));
                        // The forward link fires at every processing that ends with DMOV 1 (a
                        // motion's end, a put that moves nothing, a status change at rest), as
                        // the record's does (spec Q35).
                        let flnk = self.record.fields().flnk.clone();
                        if !flnk.is_empty() {
                            self.events.push(AxisEvent::Put { key: flnk, value: "1".into() });
                        }
                    }
                    Output::ReadbackLink(rbv) => {
                        let key = self.record.fields().rlnk.clone();
                        self.events.push(AxisEvent::Put { key, value: rbv.to_string() });
                    }
                }
            }
            if !wants_callback {
                self.record_outputs = outputs;
                return;
            }
            self.last_status = self.device_status();
            self.record.callback(self.last_status);
        }
        self.record_outputs = outputs;
        tracing::warn!("status callbacks kept asking for more status; stopped after {MAX_CALLBACK_ROUNDS} rounds");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::driver::sim::{SimAxis, SimConfig, SimSetting};
    use zmotor_msgs::menus::{severity, status};

    fn at(seconds: f64) -> Instant {
        Instant::from_secs_f64(seconds)
    }

    #[test]
    fn a_position_that_is_no_number_or_beyond_the_raw_range_is_a_communication_error_not_a_position() {
        for garbage in [f64::NAN, f64::INFINITY, 1e300, 3e9] {
            let sim = SimAxis::new(SimConfig { position: garbage, ..SimConfig::default() });
            let axis = Axis::new(demo_fields(), Box::new(sim), PollRates::default(), Instant::ZERO);
            let f = axis.fields();
            assert_eq!((f.rmp, f.rbv), (0, 0.0), "{garbage}: not clamped into a position");
            assert_eq!((f.stat, f.sevr), (status::COMM, severity::INVALID), "{garbage}");
            assert_ne!(f.msta & msta::COMM_ERR, 0, "{garbage}");
        }
    }

    fn sim_axis(fields: Fields) -> Axis {
        let sim = SimAxis::new(SimConfig {
            high_limit_switch: Some(110_000.0),
            low_limit_switch: Some(-110_000.0),
            ..SimConfig::default()
        });
        Axis::new(fields, Box::new(sim), PollRates::default(), Instant::ZERO)
    }

    fn demo_fields() -> Fields {
        Fields { mres: 0.001, velo: 10.0, accl: 0.2, dhlm: 100.0, dllm: -100.0, ..Fields::default() }
    }

    #[test]
    fn a_motion_posts_only_fields_a_node_declares_ahead() {
        // A plain move, there and back, after a first one (which also clears the boot's UDF
        // alarm and LVIO, once in the axis's life): every field posted from the write to the end.
        let mut axis = sim_axis(demo_fields());
        axis.write(Instant::ZERO, Field::VAL, &Value::Float(1.0)).expect("within the limits");
        run(&mut axis, 10.0);
        let mut posted = std::collections::BTreeSet::new();
        for target in [5.0, 0.0] {
            axis.write(axis.now(), Field::VAL, &Value::Float(target)).expect("within the limits");
            for _ in 0..100_000 {
                posted.extend(axis.drain_events().filter_map(|e| match e {
                    AxisEvent::Post(field, _) => Some(field),
                    _ => None,
                }));
                if !axis.is_busy() {
                    break;
                }
                let t = axis.poll_timeout().expect("a simulated axis is polled");
                axis.handle_timeout(t);
            }
        }
        let not_ahead: Vec<Field> = posted.iter().copied().filter(|f| !f.posted_by_every_motion()).collect();
        assert!(not_ahead.is_empty(), "posted by a motion, not declared ahead: {not_ahead:?}");
        assert!(posted.contains(&Field::RBV) && posted.contains(&Field::DMOV), "{posted:?}");
    }

    /// Run virtual time until the axis is idle or `limit` seconds pass; return the DMOV posts.
    fn run(axis: &mut Axis, limit: f64) -> Vec<Value> {
        let mut dmov = Vec::new();
        for _ in 0..100_000 {
            for e in axis.drain_events() {
                if let AxisEvent::Post(Field::DMOV, v) = e {
                    dmov.push(v);
                }
            }
            if !axis.is_busy() || axis.now().as_secs_f64() >= limit {
                break;
            }
            let t = axis.poll_timeout().expect("a simulated axis is polled");
            axis.handle_timeout(t);
        }
        dmov
    }

    #[test]
    fn a_move_on_the_simulator_completes_in_the_planned_time() {
        let mut axis = sim_axis(demo_fields());
        axis.drain_events().count();
        axis.write(at(0.0), Field::VAL, &Value::Float(10.0)).unwrap();
        let dmov = run(&mut axis, 100.0);
        assert_eq!(dmov, vec![Value::Int(0), Value::Int(1)]);
        let f = axis.fields();
        assert_eq!((f.rbv, f.drbv, f.rrbv, f.dmov, f.movn), (10.0, 10.0, 10_000, 1, 0));
        // 10 mm at 10 mm/s with 0.2 s ramps: 1.2 s, reported when the sim finishes, not at a poll.
        assert!((axis.now().as_secs_f64() - 1.2).abs() < 1e-9, "{:?}", axis.now());
    }

    #[test]
    fn readback_is_published_while_moving_at_the_poll_rate() {
        let mut axis = sim_axis(demo_fields());
        axis.drain_events().count();
        axis.write(at(0.0), Field::VAL, &Value::Float(10.0)).unwrap();
        let mut rbv_posts = 0;
        for _ in 0..1000 {
            let t = axis.poll_timeout().expect("a simulated axis is polled");
            axis.handle_timeout(t);
            rbv_posts += axis.drain_events().filter(|e| matches!(e, AxisEvent::Post(Field::RBV, _))).count();
            if !axis.is_busy() {
                break;
            }
        }
        // 1.2 s at 10 Hz: 12 polls while moving, the last one at the end of motion.
        assert!((11..=13).contains(&rbv_posts), "{rbv_posts}");
    }

    #[test]
    fn late_ticks_do_not_slow_the_poll_rate() {
        let sim = Box::new(SimAxis::new(SimConfig::default()));
        let mut axis = Axis::new(
            demo_fields(),
            sim,
            PollRates { moving: Duration::from_millis(10), idle: Duration::from_secs(1) },
            Instant::ZERO,
        );
        axis.write(at(0.0), Field::VAL, &Value::Float(50.0)).unwrap();
        axis.drain_events().count();
        let mut rbv_posts = 0;
        // A timer that always fires 4 ms late (a loaded host) for one second of a long move.
        while axis.now() < at(1.0) {
            let t = axis.poll_timeout().unwrap() + Duration::from_millis(4);
            axis.handle_timeout(t);
            rbv_posts += axis.drain_events().filter(|e| matches!(e, AxisEvent::Post(Field::RBV, _))).count();
        }
        // 100 Hz kept: ~100 polls, not the 71 of a 14 ms period.
        assert!((98..=101).contains(&rbv_posts), "{rbv_posts}");
    }

    #[test]
    fn a_write_acts_on_the_readback_of_that_moment() {
        let mut axis = sim_axis(demo_fields());
        axis.write(at(0.0), Field::VAL, &Value::Float(10.0)).unwrap();
        // No poll since the start: the write itself brings the readback up to date.
        axis.write(at(0.55), Field::DESC, &Value::Text("x".into())).unwrap();
        let physical = axis.simulation().unwrap().physical_position();
        assert!((axis.fields().drbv - physical * 0.001).abs() < 0.001, "{} vs {physical}", axis.fields().drbv);
        assert!(axis.fields().drbv > 4.0);
    }

    #[test]
    fn jog_stops_on_the_hard_limit_switch() {
        let mut axis = sim_axis(Fields { jvel: 50.0, dhlm: 0.0, dllm: 0.0, ..demo_fields() });
        axis.write(at(0.0), Field::JOGF, &Value::Int(1)).unwrap();
        run(&mut axis, 10.0);
        let f = axis.fields();
        assert_eq!((f.hls, f.jogf, f.dmov, f.rbv), (1, 0, 1, 110.0));
    }

    #[test]
    fn settling_delay_runs_on_virtual_time() {
        let mut axis = sim_axis(Fields { dly: 0.5, ..demo_fields() });
        axis.write(at(0.0), Field::VAL, &Value::Float(1.0)).unwrap();
        run(&mut axis, 10.0);
        assert_eq!(axis.fields().dmov, 1);
        // A triangular 1 mm move takes 2·sqrt(1/50) ≈ 0.283 s; DMOV waits DLY more.
        let motion = 2.0 * (1.0f64 / 50.0).sqrt();
        assert!(axis.now() >= at(motion + 0.5 - 1e-9), "{:?}", axis.now());
    }

    #[test]
    fn command_primitives_and_directives_run_around_each_motion() {
        let fields = Fields {
            init: "@DPM_ON@ HE".into(),
            prem: "@PUT(lab/shutter/VAL, 1, 0.25)@ PRE".into(),
            post: "@PUT(lab/shutter/VAL, 0)@ AFTER".into(),
            ..demo_fields()
        };
        let mut axis = sim_axis(fields);
        axis.drain_events().count();
        axis.write(at(0.0), Field::VAL, &Value::Float(1.0)).unwrap();
        let events: Vec<AxisEvent> = axis.drain_events().collect();
        assert!(events.contains(&AxisEvent::Put { key: "lab/shutter/VAL".into(), value: "1".into() }));
        let is_move = |e: &AxisEvent| matches!(e, AxisEvent::Driver { command: DriverCommand::Move { .. }, .. });
        assert!(!events.iter().any(is_move), "held by the PREM delay");
        axis.handle_timeout(at(0.2));
        assert!(!axis.drain_events().any(|e| is_move(&e)), "still held at 0.2 s");
        axis.handle_timeout(at(0.25));
        assert!(axis.drain_events().any(|e| is_move(&e)));
        let mut puts = Vec::new();
        for _ in 0..1000 {
            let t = axis.poll_timeout().expect("a simulated axis is polled");
            axis.handle_timeout(t);
            puts.extend(axis.drain_events().filter(|e| matches!(e, AxisEvent::Put { .. })));
            if !axis.is_busy() {
                break;
            }
        }
        assert_eq!(puts, vec![AxisEvent::Put { key: "lab/shutter/VAL".into(), value: "0".into() }]);
        assert_eq!(axis.simulation().unwrap().raw_commands(), ["HE", "PRE", "AFTER"]);
        assert_eq!(axis.fields().rbv, 1.0);
    }

    #[test]
    fn a_refused_move_sends_neither_prem_nor_post() {
        let fields = Fields {
            prem: "@PUT(lab/shutter/VAL, 1)@ PRE".into(),
            post: "@PUT(lab/shutter/VAL, 0)@ AFTER".into(),
            dhlm: 100.0,
            dllm: -100.0,
            ..demo_fields()
        };
        let mut axis = sim_axis(fields);
        axis.drain_events().count();
        let err = axis.write(at(0.0), Field::VAL, &Value::Float(500.0)).unwrap_err();
        assert!(err.to_string().starts_with("VAL: limit violation"), "{err}");
        let events: Vec<AxisEvent> = axis.drain_events().collect();
        let dmov: Vec<&AxisEvent> = events.iter().filter(|e| matches!(e, AxisEvent::Post(Field::DMOV, _))).collect();
        assert_eq!(dmov.len(), 2, "the refusal pulses DMOV, as EPICS: {events:?}");
        assert!(!events.iter().any(|e| matches!(e, AxisEvent::Put { .. })), "{events:?}");
        assert!(axis.simulation().unwrap().raw_commands().is_empty());
    }

    #[test]
    fn a_disabled_servo_refuses_and_an_enabled_one_moves() {
        let sim = SimAxis::new(SimConfig { servo: true, ..SimConfig::default() });
        let mut axis = Axis::new(demo_fields(), Box::new(sim), PollRates::default(), Instant::ZERO);
        assert_eq!(axis.fields().cnen, 1);
        axis.write(at(0.0), Field::PCOF, &Value::Float(0.3)).unwrap();
        assert_eq!(axis.simulation().unwrap().gains(), [0.3, 0.0, 0.0]);
        axis.write(at(0.0), Field::CNEN, &Value::Int(0)).unwrap();
        assert_eq!(axis.fields().cnen, 0);
        let err = axis.write(at(0.1), Field::VAL, &Value::Float(1.0)).unwrap_err();
        assert!(err.to_string().starts_with("VAL: motor disabled"), "{err}");
        axis.write(at(0.2), Field::CNEN, &Value::Int(1)).unwrap();
        axis.write(at(0.3), Field::VAL, &Value::Float(1.0)).unwrap();
        run(&mut axis, 10.0);
        assert_eq!(axis.fields().rbv, 1.0);
    }

    #[test]
    fn an_inch_worm_sim_is_retried_until_within_the_deadband() {
        let mut axis = sim_axis(Fields { rdbd: 0.01, ..demo_fields() });
        axis.simulation().unwrap().apply(SimSetting::Fraction, &Value::Float(0.9)).unwrap();
        axis.write(at(0.0), Field::VAL, &Value::Float(10.0)).unwrap();
        run(&mut axis, 60.0);
        let f = axis.fields();
        assert_eq!((f.dmov, f.miss), (1, 0));
        assert!(f.rcnt >= 2 && (f.drbv - 10.0).abs() < 0.01, "rcnt {} drbv {}", f.rcnt, f.drbv);
    }
}
