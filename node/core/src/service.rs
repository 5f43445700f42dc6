//! The request semantics of the wire contract for one axis, with no network in sight: a plain
//! put (a refusal is reported on ERR), a confirmed write (answered with the field's new value or
//! the reason it was refused), a put-with-completion (`?wait`: answered when the motion the
//! write started has finished), reads of one field or of a selection, and the simulator's keys.
//! Every publication is stamped with the state marker here. The Zenoh adapter turns samples and
//! queries into these calls and sends what `poll_output` hands back; `R` is its reply handle
//! (a Zenoh query), a plain value in tests.

use crate::axis::{Axis, AxisEvent, JogHold, WriteAccepted};
use crate::driver::sim::{SimSetting, SimSettingError};
use crate::driver::soft::InputLink;
use crate::engine::{DeviceStatus, WriteError};
use crate::time::Instant;
use std::collections::VecDeque;
use zmotor_msgs::keys::PlainKeyError;
use zmotor_msgs::menus::severity;
use zmotor_msgs::{
    decode_scalar, excerpt, keys, CodecError, Completion, DriverCommand, DriverTrace, Field, Fields, Hold, KeyLayout,
    Kind, LinkKeyError, MalformedHold, MalformedPayload, PayloadEncoding, Readback, RefusalKind, SimState, StateMarker,
    Value,
};

/// Why a request was refused. The message says it in plain words and names the field.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RequestError {
    /// No field has this name.
    #[error("{0}: unknown field")]
    UnknownField(String),
    /// A write to a key with wildcards (the key).
    #[error("{0}: a write names one field of one axis; this key has wildcards")]
    Wildcard(String),
    /// A Zenoh delete of a key (the key): it carries no value, and nothing is ever removed.
    #[error("{0}: a delete is not a write; put a value to write the field")]
    Delete(String),
    /// The name is a field's in another case; keys are exact.
    #[error("{given}: unknown field; field names are upper case: {field}")]
    WrongCase {
        /// The name as written.
        given: String,
        /// The field it resembles.
        field: Field,
    },
    /// DISP is not 0: the axis takes no writes but to DISP and STOP.
    #[error("{0}: puts are disabled (DISP is not 0); write DISP 0 to enable them")]
    PutsDisabled(Field),
    /// The payload does not hold a valid value for the field.
    #[error(transparent)]
    Payload(#[from] CodecError),
    /// The record refused or did not act on the write.
    #[error(transparent)]
    Record(#[from] WriteError),
    /// A simulator key was given a payload that does not decode.
    #[error("{key}: {source}")]
    SimPayload {
        /// The simulator key written.
        key: String,
        /// What was wrong with the payload.
        source: MalformedPayload,
    },
    /// A simulator setting was refused.
    #[error("{key}: {source}")]
    SimSetting {
        /// The simulator key written.
        key: String,
        /// Why the setting was refused.
        source: SimSettingError,
    },
    /// The axis has no simulator.
    #[error("{0}: this axis is not simulated")]
    NotSimulated(String),
    /// A jog without a hold on an axis that jogs only under one (the jog deadman).
    #[error(
        "{0}: this axis jogs only under a hold (the jog deadman): attach {{kind: \"hold\", token: <your \
         liveliness token>}} to the write (README: Holding a motion)"
    )]
    HoldRequired(Field),
    /// A hold whose token is not a key a liveliness token can have.
    #[error("{field}: the hold's token: {source}")]
    HoldToken {
        /// The field written.
        field: Field,
        /// Why the token is no plain key.
        source: PlainKeyError,
    },
    /// A hold that names no token.
    #[error("{field}: {source}")]
    HoldMalformed {
        /// The field written.
        field: Field,
        /// What the hold lacks.
        source: MalformedHold,
    },
    /// A hold whose token is not one of this axis's hold tokens.
    #[error("{field}: the hold's token {token} is not under {space} (a hold names a token of this axis's hold space)")]
    HoldElsewhere {
        /// The field written.
        field: Field,
        /// The token named.
        token: String,
        /// Where this axis's hold tokens are.
        space: String,
    },
    /// A link field was given a key it cannot be wired to.
    #[error("{field}: {source}")]
    Link {
        /// The link field written.
        field: Field,
        /// Why the key cannot be wired.
        source: LinkKeyError,
    },
}

impl RequestError {
    /// What kind of refusal this is, as clients are told.
    pub fn kind(&self) -> RefusalKind {
        match self {
            RequestError::UnknownField(_) | RequestError::WrongCase { .. } => RefusalKind::UnknownField,
            RequestError::Wildcard(_) => RefusalKind::Wildcard,
            RequestError::Payload(_)
            | RequestError::SimPayload { .. }
            | RequestError::SimSetting { .. }
            | RequestError::Link { .. }
            | RequestError::Delete(_) => RefusalKind::BadValue,
            RequestError::Record(e) => e.kind(),
            RequestError::PutsDisabled(_) => RefusalKind::PutsDisabled,
            RequestError::NotSimulated(_) => RefusalKind::NotSimulated,
            RequestError::HoldRequired(_) => RefusalKind::HoldRequired,
            RequestError::HoldToken { .. }
            | RequestError::HoldElsewhere { .. }
            | RequestError::HoldMalformed { .. } => RefusalKind::BadHold,
        }
    }
}

/// The answer to a confirmed write or a read. Not `#[non_exhaustive]`: the adapter must send
/// every kind of answer, and a new one must stop the build of an adapter that would drop it.
#[derive(Clone, Debug, PartialEq)]
pub enum Reply {
    /// A field's value: the result of a confirmed write, or one field of a read.
    Value(Field, Value),
    /// The end of the motion a `?wait` write started.
    Completion(Field, Completion),
    /// The request was refused; nothing changed.
    Refused(RequestError),
    /// The axis's last message on ERR (a refusal, a controller's report) and its kind, if any.
    Message(Option<(RefusalKind, String)>),
    /// The simulator's physical state (`sim/<axis>/state`).
    SimState(SimState),
    /// One simulator setting (`sim/<axis>/<setting>`).
    SimSetting(SimSetting, Value),
}

/// An answer and the request it answers.
#[derive(Clone, Debug, PartialEq)]
pub struct Answer<R> {
    /// The request's reply handle.
    pub to: R,
    /// The answer.
    pub reply: Reply,
}

/// How a publication must reach subscribers when a link cannot carry every sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Delivery {
    /// A readback of a poll during a motion: the next poll's supersedes it, so it may be dropped
    /// where a link is congested rather than delay what follows (a robot's readback stream).
    Stream,
    /// A change of state (a write's effect, a motion's start or end, an alarm, a readback of an
    /// axis at rest): its last value must arrive, in order with the axis's other posts, however
    /// slow a link; values a slow link has not taken yet may be replaced by newer ones.
    Event,
}

/// What the adapter must send, in order. Not `#[non_exhaustive]`: each is an action the adapter
/// must carry out, and a new one must stop the build of an adapter that would drop it.
#[derive(Clone, Debug, PartialEq)]
pub enum ServiceOutput<R> {
    /// Publish a field's new value on `<prefix>/<axis>/<FIELD>`, with its state marker.
    Publish {
        /// The field.
        field: Field,
        /// Its new value.
        value: Value,
        /// The attachment that marks the sample as state.
        marker: StateMarker,
        /// Whether it may be dropped on a congested link: `Stream` when every post of the input
        /// is a readback stream (`Field::is_readback_stream`) and the axis still moves after it.
        delivery: Delivery,
    },
    /// The input posted one or more of the readback bundle's fields (`Readback::FIELDS`): the
    /// bundle on `<prefix>/<axis>/@readback` is `Readback::encode(AxisService::fields(),
    /// marker.seq)`, the state after them, with the marker of the last. One per input, after
    /// its posts; the adapter sends it only while someone subscribes to it.
    Readback {
        /// The marker of the last readback field posted.
        marker: StateMarker,
        /// As the input's posts'.
        delivery: Delivery,
    },
    /// Publish why a write was refused on `<prefix>/<axis>/ERR`, the kind as the schema of its
    /// encoding (`RefusalKind::mime`).
    Refusal {
        /// What kind of refusal.
        kind: RefusalKind,
        /// The reason, in plain words.
        message: String,
        /// The attachment that marks the sample as state.
        marker: StateMarker,
    },
    /// Answer a request. Boxed: a publication, many times more frequent, moves through the
    /// outputs in a value as large as the largest (measured: copying a request's handle inline
    /// was 8 % of a node's CPU at a thousand moving axes).
    Reply(Box<Answer<R>>),
    /// A command delivered to the driver: traced on `@driver/cmd` if anyone listens
    /// (`AxisService::stamp_trace` numbers it).
    DriverCommand {
        /// The command, in raw units.
        command: DriverCommand,
        /// When it was delivered.
        at: Instant,
    },
    /// An input link now names `key` ("" to follow nothing): follow it instead of the old one,
    /// asking for its current value once, as at start.
    Follow {
        /// Which link.
        link: InputLink,
        /// Its new key.
        key: String,
    },
    /// A motion is held by the liveliness token `token`: watch it, and call
    /// `AxisService::hold_released` when it goes (or is not there).
    WatchHold {
        /// The token's key.
        token: String,
    },
    /// Nothing is held by `token` any more: stop watching it.
    ForgetHold {
        /// The token's key.
        token: String,
    },
    /// A plain write of `value` (text) to another key: an output link or a directive.
    Put {
        /// The key written to.
        key: String,
        /// The value, as text.
        value: String,
    },
}

/// A write as it arrives: the field's name, the payload and its encoding, and the hold that
/// the writer holds what it starts by, if any.
#[derive(Clone, Debug, PartialEq)]
pub struct WriteRequest<'a> {
    /// The field's name, as the key spells it.
    pub name: &'a str,
    /// The payload.
    pub payload: &'a [u8],
    /// How it is encoded.
    pub encoding: PayloadEncoding,
    /// The write's hold (its attachment), if it has one: a hold that names no token is refused.
    pub hold: Option<Result<Hold, MalformedHold>>,
}

impl<'a> WriteRequest<'a> {
    /// A write without a hold.
    pub fn new(name: &'a str, payload: &'a [u8], encoding: PayloadEncoding) -> Self {
        Self { name, payload, encoding, hold: None }
    }

    /// The same write, held by `hold`.
    #[must_use]
    pub fn held(self, hold: Option<Result<Hold, MalformedHold>>) -> Self {
        Self { hold, ..self }
    }
}

/// How a held motion ends when its hold goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Release {
    /// As JOGF or JOGR = 0 would end it (with its backlash).
    Unjog(Field),
    /// As STOP would.
    Stop,
}

/// A motion under way that lasts only while `token` lives.
#[derive(Clone, Debug, PartialEq)]
struct Held {
    token: String,
    release: Release,
}

/// A `?wait` write waiting for the end of its motion.
struct Waiter<R> {
    to: R,
    field: Field,
    accepted: WriteAccepted,
    /// What the controller reported while the motion ran, each once.
    controller_messages: Vec<String>,
}

/// Distinct controller messages a completion carries at most.
const MESSAGES_PER_COMPLETION: usize = 8;

/// One axis behind the wire contract (see the module documentation).
pub struct AxisService<R> {
    layout: KeyLayout,
    name: String,
    axis: Axis,
    /// Per-axis sequence number of publications and traces.
    seq: u64,
    waiting: Vec<Waiter<R>>,
    outputs: VecDeque<ServiceOutput<R>>,
    /// The axis's events being handled, kept for their room (an axis polls a hundred times a second).
    events: Vec<AxisEvent>,
    /// A field autosave keeps changed since `take_unsaved_change`.
    unsaved: bool,
    jog_hold: JogHold,
    /// Motions under way that their writers hold.
    held: Vec<Held>,
    /// A plain jog has been warned about.
    warned_unheld_jog: bool,
    /// The last message posted on ERR, and its kind: what a read of ERR answers.
    last_message: Option<(RefusalKind, String)>,
}

impl<R: Clone> AxisService<R> {
    /// Serve `axis` under the name `name`. What its boot produced is not published:
    /// initialisation posts no monitors, as in EPICS; clients read the initial state.
    pub fn new(layout: &KeyLayout, name: &str, mut axis: Axis) -> Self {
        axis.drain_events().count();
        Self {
            layout: layout.clone(),
            name: name.to_string(),
            axis,
            seq: 0,
            waiting: Vec::new(),
            outputs: VecDeque::new(),
            events: Vec::new(),
            // Boot may have changed the position (RSTM): the saved state follows what is.
            unsaved: true,
            jog_hold: JogHold::Optional,
            held: Vec::new(),
            warned_unheld_jog: false,
            last_message: None,
        }
    }

    /// The same service, jogging only under a hold if `rule` says so.
    #[must_use]
    pub fn with_jog_hold(self, rule: JogHold) -> Self {
        Self { jog_hold: rule, ..self }
    }

    /// The liveliness token `token` went (or was never there): whatever it held ends, a jog as
    /// JOGF/JOGR = 0 would end it, another motion as STOP.
    pub fn hold_released(&mut self, now: Instant, token: &str) {
        let (released, kept): (Vec<Held>, Vec<Held>) = self.held.drain(..).partition(|h| h.token == token);
        self.held = kept;
        if !released.is_empty() {
            self.outputs.push_back(ServiceOutput::ForgetHold { token: token.to_string() });
        }
        for held in released {
            let f = self.axis.fields();
            let ending = match held.release {
                Release::Unjog(field) if f.get(field) != Value::Int(0) => Some((field, Value::Int(0))),
                Release::Stop if f.dmov == 0 => Some((Field::STOP, Value::Int(1))),
                _ => None,
            };
            if let Some((field, value)) = ending {
                tracing::warn!(axis = %self.name, token, "the hold went: {field} = {value}");
                if let Err(e) = self.axis.write(now, field, &value) {
                    tracing::error!(axis = %self.name, "the end of a released hold was refused: {e}");
                }
            }
        }
        self.collect();
    }

    /// The axis's name (its key chunk).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The record's fields.
    pub fn fields(&self) -> &Fields {
        self.axis.fields()
    }

    /// The next thing to send, if any.
    #[must_use]
    pub fn poll_output(&mut self) -> Option<ServiceOutput<R>> {
        self.outputs.pop_front()
    }

    /// When `handle_timeout` is due next; None while nothing is.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.axis.poll_timeout()
    }

    /// When the next event apart from the periodic polls is due (see `Axis::event_timeout`).
    #[must_use]
    pub fn event_timeout(&self) -> Option<Instant> {
        self.axis.event_timeout()
    }

    /// Time passed to `now`.
    pub fn handle_timeout(&mut self, now: Instant) {
        self.axis.handle_timeout(now);
        self.collect();
    }

    /// What the axis's controller reported for its channel, after `motions` motion commands.
    pub fn controller_status(&mut self, now: Instant, status: DeviceStatus, motions: u64) {
        self.axis.controller_status(now, status, motions);
        self.collect();
    }

    /// The axis's controller reported an error, or did not send a command (`message` names
    /// the vendor's code and meaning): published on ERR, as a refused write is.
    pub fn controller_message(&mut self, message: String) {
        // The writes waiting for the motion's end carry it in their answer.
        for waiter in &mut self.waiting {
            let known = waiter.controller_messages.contains(&message);
            if !known && waiter.controller_messages.len() < MESSAGES_PER_COMPLETION {
                waiter.controller_messages.push(message.clone());
            }
        }
        self.report(RefusalKind::Controller, message);
    }

    /// A new value on one of the record's input links.
    pub fn link_update(&mut self, now: Instant, link: InputLink, value: f64) {
        self.axis.link_update(now, link, value);
        self.collect();
    }

    /// A link's value found when the link connected or its source came back (`Axis::link_read`:
    /// DOL's is not acted upon).
    pub fn link_read(&mut self, now: Instant, link: InputLink, value: f64) {
        self.axis.link_read(now, link, value);
        self.collect();
    }

    /// The source of one of the record's input links is gone.
    pub fn link_lost(&mut self, now: Instant, link: InputLink) {
        self.axis.link_lost(now, link);
        self.collect();
    }

    /// Whether a field autosave keeps has changed since the last call.
    #[must_use = "the change is forgotten once taken"]
    pub fn take_unsaved_change(&mut self) -> bool {
        std::mem::take(&mut self.unsaved)
    }

    /// A plain put: applied, or refused with the reason on ERR.
    pub fn put(&mut self, now: Instant, request: WriteRequest) {
        let name = request.name;
        if let Err(refusal) = self.apply(now, request) {
            tracing::warn!(axis = %self.name, field = name, "write refused: {refusal}");
            self.refuse(&refusal);
        }
        self.collect();
    }

    /// A plain write to `key`, a key with wildcards that covers this axis: refused and reported
    /// on ERR, for a write names one field of one axis.
    pub fn wildcard_put(&mut self, key: &str) {
        self.refuse_plain(RequestError::Wildcard(excerpt(key)));
    }

    /// A delete of `key`, one of this axis's (a Zenoh delete, not a put): refused on ERR, as a
    /// plain write with no value would be; nothing changes.
    pub fn delete(&mut self, key: &str) {
        self.refuse_plain(RequestError::Delete(excerpt(key)));
    }

    fn refuse_plain(&mut self, refusal: RequestError) {
        tracing::warn!(axis = %self.name, "write refused: {refusal}");
        self.refuse(&refusal);
    }

    /// A confirmed write to the field named `name`: answered with the field's new value, or,
    /// with `wait`, with the `Completion` once the motion the write started has finished; a
    /// refusal is answered (and reported on ERR) with the reason.
    pub fn write(&mut self, now: Instant, request: WriteRequest, wait: bool, to: R) {
        let name = request.name;
        let reply = match self.apply(now, request) {
            Err(refusal) => {
                tracing::warn!(axis = %self.name, field = name, "confirmed write refused: {refusal}");
                self.refuse(&refusal);
                Reply::Refused(refusal)
            }
            Ok((field, accepted)) if wait && self.axis.fields().dmov == 0 => {
                self.waiting.push(Waiter { to, field, accepted, controller_messages: Vec::new() });
                self.collect();
                return;
            }
            Ok((field, accepted)) if wait => {
                Reply::Completion(field, self.completion(field, accepted.target, Vec::new()))
            }
            Ok((field, _)) => Reply::Value(field, self.axis.record().get(field)),
        };
        // The write's posts go before its answer: a writer that follows the fields has what the
        // write did once it has the answer (a Channel Access read after a put-callback).
        self.collect();
        self.answer(to, reply);
    }

    /// A read of the field named `name` (exactly as the catalogue spells it), or of ERR.
    pub fn read(&mut self, name: &str, to: R) {
        let reply = match field_named(name) {
            Ok(field) => Reply::Value(field, self.axis.record().get(field)),
            Err(_) if name == keys::ERR_KEY => Reply::Message(self.last_message.clone()),
            Err(unknown) => Reply::Refused(unknown),
        };
        self.answer(to, reply);
    }

    /// A read of every field `selects` (a wildcard read): one reply per field.
    pub fn read_selected(&mut self, selects: impl Fn(Field) -> bool, to: R) {
        for field in Field::all().filter(|f| selects(*f)) {
            let reply = Reply::Value(field, self.axis.record().get(field));
            self.answer(to.clone(), reply);
        }
    }

    /// A put to the simulator key `sim/<axis>/<name>`; a refusal is reported on ERR.
    pub fn sim_write(&mut self, now: Instant, name: &str, payload: &[u8], encoding: PayloadEncoding) {
        if let Err(refusal) = self.apply_sim(now, name, payload, encoding) {
            tracing::warn!(axis = %self.name, "{refusal}");
            self.refuse(&refusal);
        }
        self.collect();
    }

    /// A confirmed write to the simulator key `sim/<axis>/<name>`: answered with the setting's
    /// new value, or refused (and reported on ERR) with the reason.
    pub fn sim_write_confirmed(&mut self, now: Instant, name: &str, payload: &[u8], encoding: PayloadEncoding, to: R) {
        let reply = match self.apply_sim(now, name, payload, encoding) {
            Ok(setting) => match self.axis.simulation() {
                Some(sim) => Reply::SimSetting(setting, sim.setting(setting)),
                None => return,
            },
            Err(refusal) => {
                tracing::warn!(axis = %self.name, "{refusal}");
                self.refuse(&refusal);
                Reply::Refused(refusal)
            }
        };
        self.collect();
        self.answer(to, reply);
    }

    /// Apply a write of the simulator setting `name`.
    fn apply_sim(
        &mut self,
        now: Instant,
        name: &str,
        payload: &[u8],
        encoding: PayloadEncoding,
    ) -> Result<SimSetting, RequestError> {
        let key = keys::sim_key(&self.name, name);
        self.axis.handle_timeout(now);
        let value =
            decode_scalar(payload, encoding).map_err(|source| RequestError::SimPayload { key: key.clone(), source })?;
        let sim = self.axis.simulation().ok_or_else(|| RequestError::NotSimulated(key.clone()))?;
        let setting = SimSetting::from_name(name)
            .ok_or_else(|| SimSettingError::Unknown(excerpt(name)))
            .and_then(|setting| sim.apply(setting, &value).map(|()| setting))
            .map_err(|source| RequestError::SimSetting { key, source })?;
        self.axis.refresh_status(now);
        Ok(setting)
    }

    /// A read of the simulator's keys whose names `selects` (`state` and every setting).
    pub fn sim_read(&mut self, now: Instant, selects: impl Fn(&str) -> bool, to: R) {
        self.axis.handle_timeout(now);
        self.collect();
        let Some(sim) = self.axis.simulation() else { return };
        let mut replies = Vec::new();
        if selects(keys::SIM_STATE_KEY) {
            replies.push(Reply::SimState(sim.state()));
        }
        for setting in SimSetting::ALL.into_iter().filter(|s| selects(s.name())) {
            replies.push(Reply::SimSetting(setting, sim.setting(setting)));
        }
        for reply in replies {
            self.answer(to.clone(), reply);
        }
    }

    /// A shutdown, or a reload of its controller's script: a moving axis is told to stop, as a STOP
    /// write would.
    pub fn stop_motion(&mut self, now: Instant) {
        if self.axis.fields().dmov == 0 {
            if let Err(e) = self.axis.write(now, Field::STOP, &Value::Int(1)) {
                tracing::warn!(axis = %self.name, "stop refused: {e}");
            }
            self.collect();
        }
    }

    /// Number a driver command for the trace (the adapter calls this only when it publishes).
    #[must_use]
    pub fn stamp_trace(&mut self, command: DriverCommand, at: Instant) -> DriverTrace {
        DriverTrace { command, t: at.as_secs_f64(), seq: self.next_seq() }
    }

    /// Decode and apply one write.
    fn apply(&mut self, now: Instant, request: WriteRequest) -> Result<(Field, WriteAccepted), RequestError> {
        let field = field_named(request.name)?;
        // Checked before the value, as an IOC's dbPutField checks DISP first; the record's own
        // writes (a released hold's end, a shutdown's stop) are not puts and pass.
        if self.axis.fields().disp != 0 && !field.taken_while_puts_disabled() {
            return Err(RequestError::PutsDisabled(field));
        }
        // Before the value too: no value is taken, and a writer told its payload was wrong
        // would only try another.
        if field.def().access == zmotor_msgs::Access::RO {
            return Err(WriteError::ReadOnly(field).into());
        }
        let value = zmotor_msgs::decode_write(field.def(), request.payload, request.encoding)?;
        let starts_jog = field.is_jog() && value != Value::Int(0);
        match &request.hold {
            Some(Err(source)) => return Err(RequestError::HoldMalformed { field, source: *source }),
            Some(Ok(hold)) => {
                keys::validate_plain_key(&hold.token).map_err(|source| RequestError::HoldToken { field, source })?;
                // Only a token in the hold space: another key (the axis's own token, say) would
                // hold the motion by something that does not go with its client.
                let space = self.layout.hold(&self.name, "");
                if hold.token.strip_prefix(&space).is_none_or(|client| client.is_empty()) {
                    return Err(RequestError::HoldElsewhere { field, token: hold.token.clone(), space });
                }
            }
            None if starts_jog && self.jog_hold == JogHold::Required => return Err(RequestError::HoldRequired(field)),
            None if starts_jog && !std::mem::replace(&mut self.warned_unheld_jog, true) => tracing::warn!(
                axis = %self.name,
                "a jog without a hold keeps running if its client vanishes (README: Holding a motion); said once"
            ),
            None => {}
        }
        let key = match &value {
            Value::Text(key) if field.def().kind == Kind::Link => Some(key.clone()),
            _ => None,
        };
        if let Some(key) = key.as_deref().filter(|key| !key.is_empty()) {
            let writes = field.is_output_link();
            self.layout
                .check_link(key, writes, Some(&self.name))
                .map_err(|source| RequestError::Link { field, source })?;
        }
        let accepted = self.axis.write(now, field, &value)?;
        self.unsaved |= field.autosave().is_some();
        if let Some(Ok(hold)) = request.hold.filter(|_| self.axis.fields().dmov == 0) {
            self.hold(hold.token, if starts_jog { Release::Unjog(field) } else { Release::Stop });
        }
        if let (Some(link), Some(key)) = (InputLink::of(field), key) {
            self.outputs.push_back(ServiceOutput::Follow { link, key });
        }
        Ok((field, accepted))
    }

    /// A motion under way is held by `token`.
    fn hold(&mut self, token: String, release: Release) {
        if !self.held.iter().any(|h| h.token == token) {
            self.outputs.push_back(ServiceOutput::WatchHold { token: token.clone() });
        }
        self.held.push(Held { token, release });
    }

    fn answer(&mut self, to: R, reply: Reply) {
        self.outputs.push_back(ServiceOutput::Reply(Box::new(Answer { to, reply })));
    }

    fn refuse(&mut self, refusal: &RequestError) {
        self.report(refusal.kind(), refusal.to_string());
    }

    /// Post `message` on ERR, and keep it for a read of ERR.
    fn report(&mut self, kind: RefusalKind, message: String) {
        let marker = self.marker();
        self.last_message = Some((kind, message.clone()));
        self.outputs.push_back(ServiceOutput::Refusal { kind, message, marker });
    }

    /// The sequence number of the last publication or trace (0 before the first).
    #[must_use]
    pub fn last_seq(&self) -> u64 {
        self.seq
    }

    fn next_seq(&mut self) -> u64 {
        self.seq += 1;
        self.seq
    }

    fn marker(&mut self) -> StateMarker {
        let seq = self.next_seq();
        let f = self.axis.fields();
        StateMarker::new(seq, f.stat, f.sevr)
    }

    /// The answer to a `?wait` write: the field, the readback and whether the target was reached:
    /// no major alarm and, after a write of a `target`, no retries run out and the readback within
    /// the retry deadband of it (a motion stopped, or ended on a limit switch or short of it with
    /// no retries, did not reach it, whatever MISS says). MISS speaks of the last target: a home
    /// or a write of VELO is not answered with an earlier move's. LVIO is not asked: a target
    /// beyond the soft limits is refused, and one too close to move to leaves an earlier target's
    /// LVIO standing (as the record does), though the axis is there.
    fn completion(&self, field: Field, target: Option<f64>, controller_messages: Vec<String>) -> Completion {
        let f = self.axis.fields();
        let deadband = f.rdbd.max(f.mres.abs());
        let on_target = target.is_none_or(|target| f.miss == 0 && (f.rbv - target).abs() <= deadband);
        let reached = f.sevr < severity::MAJOR && on_target;
        Completion {
            written: [(field.name().to_string(), self.axis.record().get(field))].into(),
            rbv: f.rbv,
            dmov: f.dmov.into(),
            miss: f.miss.into(),
            lvio: f.lvio.into(),
            stat: f.stat.into(),
            sevr: f.sevr.into(),
            reached: reached.into(),
            err: controller_messages,
        }
    }

    /// Answer the waiting writes `done` ends, with their completion.
    fn answer_waiters(&mut self, done: crate::axis::Completion) {
        let (ended, waiting) =
            std::mem::take(&mut self.waiting).into_iter().partition(|w: &Waiter<R>| w.accepted.is_ended_by(done));
        self.waiting = waiting;
        for waiter in ended {
            let target = waiter.accepted.target;
            let completion = self.completion(waiter.field, target, waiter.controller_messages);
            let reply = Reply::Completion(waiter.field, completion);
            self.answer(waiter.to, reply);
        }
    }

    /// Turn what the axis produced into outputs; a completion answers the writes it ends.
    fn collect(&mut self) {
        let mut events = std::mem::take(&mut self.events);
        self.axis.take_events(&mut events);
        let streams = |event: &AxisEvent| match event {
            AxisEvent::Post(field, _) => field.is_readback_stream(),
            _ => true,
        };
        let delivery = match self.axis.fields().dmov == 0 && events.iter().all(streams) {
            true => Delivery::Stream,
            false => Delivery::Event,
        };
        let mut readback = None;
        for event in events.drain(..) {
            match event {
                AxisEvent::Post(field, value) => {
                    self.unsaved |= field.autosave().is_some();
                    let marker = self.marker();
                    if Readback::FIELDS.contains(&field) {
                        readback = Some(marker.clone());
                    }
                    self.outputs.push_back(ServiceOutput::Publish { field, value, marker, delivery });
                }
                AxisEvent::Driver { command, at } => {
                    self.outputs.push_back(ServiceOutput::DriverCommand { command, at })
                }
                AxisEvent::Put { key, value } => self.outputs.push_back(ServiceOutput::Put { key, value }),
                AxisEvent::Done(done) => {
                    // The motion is over: what held it holds nothing now.
                    let mut tokens: Vec<String> = self.held.drain(..).map(|h| h.token).collect();
                    tokens.dedup();
                    for token in tokens {
                        self.outputs.push_back(ServiceOutput::ForgetHold { token });
                    }
                    self.answer_waiters(done);
                }
                AxisEvent::WritesCompleted(done) => self.answer_waiters(done),
            }
        }
        self.events = events;
        if let Some(marker) = readback {
            self.outputs.push_back(ServiceOutput::Readback { marker, delivery });
        }
    }
}

/// The field a key chunk names, exactly; a name in the wrong case is refused naming the field.
fn field_named(name: &str) -> Result<Field, RequestError> {
    Field::from_name(name).ok_or_else(|| match Field::from_name_any_case(name) {
        Some(field) => RequestError::WrongCase { given: name.to_string(), field },
        None => RequestError::UnknownField(excerpt(name)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::axis::PollRates;
    use crate::driver::sim::{SimAxis, SimConfig};
    use zmotor_msgs::menus::choice;
    use PayloadEncoding::Text;

    /// Requests in these tests are told apart by a number.
    type Service = AxisService<u32>;

    fn at(seconds: f64) -> Instant {
        Instant::from_secs_f64(seconds)
    }

    fn demo_fields() -> Fields {
        Fields { mres: 0.001, velo: 10.0, accl: 0.2, dhlm: 100.0, dllm: -100.0, ..Fields::default() }
    }

    fn service() -> Service {
        service_on(demo_fields(), SimConfig::default())
    }

    fn service_on(fields: Fields, sim: SimConfig) -> Service {
        let axis = Axis::new(fields, Box::new(SimAxis::new(sim)), PollRates::default(), Instant::ZERO);
        AxisService::new(&KeyLayout::default(), "m1", axis)
    }

    fn drain(service: &mut Service) -> Vec<ServiceOutput<u32>> {
        std::iter::from_fn(|| service.poll_output()).collect()
    }

    fn replies(outputs: &[ServiceOutput<u32>]) -> Vec<(u32, Reply)> {
        outputs
            .iter()
            .filter_map(|o| match o {
                ServiceOutput::Reply(answer) => Some((answer.to, answer.reply.clone())),
                _ => None,
            })
            .collect()
    }

    /// The answers, each a refusal (any other answer fails the test).
    fn refused_answers(outputs: &[ServiceOutput<u32>]) -> Vec<RequestError> {
        replies(outputs)
            .into_iter()
            .map(|(_, reply)| match reply {
                Reply::Refused(e) => e,
                other => panic!("{other:?}"),
            })
            .collect()
    }

    fn published(outputs: &[ServiceOutput<u32>], wanted: Field) -> Vec<Value> {
        outputs
            .iter()
            .filter_map(|o| match o {
                ServiceOutput::Publish { field, value, .. } if *field == wanted => Some(value.clone()),
                _ => None,
            })
            .collect()
    }

    fn refusals(outputs: &[ServiceOutput<u32>]) -> Vec<String> {
        outputs
            .iter()
            .filter_map(|o| match o {
                ServiceOutput::Refusal { message, .. } => Some(message.clone()),
                _ => None,
            })
            .collect()
    }

    /// Run virtual time until the axis is idle, collecting every output.
    fn run_until_idle(service: &mut Service) -> Vec<ServiceOutput<u32>> {
        let mut outputs = drain(service);
        for _ in 0..10_000 {
            if service.fields().dmov == 1 && service.fields().movn == 0 {
                break;
            }
            let t = service.poll_timeout().expect("a simulated axis is polled");
            service.handle_timeout(t);
            outputs.extend(drain(service));
        }
        outputs
    }

    #[test]
    fn a_wait_write_whose_motion_is_stopped_short_did_not_reach_its_target() {
        let mut s = service();
        s.write(at(0.0), WriteRequest::new("VAL", b"5", Text), true, 7);
        let mut outputs = drain(&mut s);
        for _ in 0..10_000 {
            if s.fields().rbv > 0.5 {
                break;
            }
            let t = s.poll_timeout().expect("a simulated axis is polled");
            s.handle_timeout(t);
            outputs.extend(drain(&mut s));
        }
        let now = s.poll_timeout().expect("moving");
        s.put(now, WriteRequest::new("STOP", b"1", Text));
        outputs.extend(run_until_idle(&mut s));
        let answers = replies(&outputs);
        let [(7, Reply::Completion(Field::VAL, completion))] = &answers[..] else { panic!("{answers:?}") };
        // The record stops where it is: no retries ran out, no limit, no alarm, VAL follows RBV.
        assert_eq!((completion.miss, completion.lvio, completion.sevr, completion.dmov), (0, 0, 0, 1));
        assert!(completion.rbv > 0.5 && completion.rbv < 4.0, "{completion:?}");
        assert_eq!(completion.reached, 0, "stopped {} short of 5", 5.0 - completion.rbv);
    }

    #[test]
    fn a_wait_write_toward_an_active_limit_switch_did_not_reach_its_target() {
        // The plus switch at 2 mm (2,000 steps): a move to 3 stops on it; a move further plus
        // then stops at once, and the record sets VAL back to where the carriage stands.
        let sim = SimConfig { high_limit_switch: Some(2000.0), ..SimConfig::default() };
        let mut s = service_on(demo_fields(), sim);
        let mut now = at(0.0);
        for (id, target) in [(1, "3"), (2, "4")] {
            s.write(now, WriteRequest::new("VAL", target.as_bytes(), Text), true, id);
            let outputs = run_until_idle(&mut s);
            let answers = replies(&outputs);
            let [(to, Reply::Completion(Field::VAL, completion))] = &answers[..] else { panic!("{outputs:?}") };
            assert_eq!(*to, id);
            assert_eq!((s.fields().hls, completion.dmov), (1, 1), "{completion:?}");
            assert!((completion.rbv - 2.0).abs() < 0.01 && s.fields().val == completion.rbv, "{completion:?}");
            assert_eq!(completion.reached, 0, "VAL {target}: stopped on the switch, {completion:?}");
            now = s.poll_timeout().expect("polled");
        }
    }

    #[test]
    fn a_wait_write_to_where_the_axis_stands_reached_it_whatever_an_earlier_target_left_in_lvio() {
        let mut s = service();
        s.write(at(0.0), WriteRequest::new("VAL", b"500", Text), false, 1);
        assert_eq!(s.fields().lvio, 1, "beyond the soft limits");
        s.write(at(0.1), WriteRequest::new("VAL", b"0", Text), true, 2);
        let outputs = run_until_idle(&mut s);
        let [(1, Reply::Refused(_)), (2, Reply::Completion(Field::VAL, completion))] = &replies(&outputs)[..] else {
            panic!("{outputs:?}")
        };
        // Too close to move: the record leaves LVIO as the refused target set it.
        assert_eq!((completion.rbv, completion.lvio, completion.reached), (0.0, 1, 1), "{completion:?}");
    }

    #[test]
    fn a_wait_write_is_answered_when_the_record_is_disabled_and_processed_as_an_ioc_completes_it() {
        let mut s = service();
        s.write(at(0.0), WriteRequest::new("VAL", b"50", Text), true, 1);
        s.write(at(0.1), WriteRequest::new("DISA", b"1", Text), false, 2);
        assert_eq!(replies(&drain(&mut s)).iter().map(|(to, _)| *to).collect::<Vec<_>>(), [2], "still moving");
        // A processing of the disabled record (a setting of a process-passive field).
        s.write(at(0.2), WriteRequest::new("HLSV", b"MINOR", Text), false, 3);
        let answers = replies(&drain(&mut s));
        let [(1, Reply::Completion(Field::VAL, completion)), (3, Reply::Value(..))] = &answers[..] else {
            panic!("{answers:?}")
        };
        assert_eq!((completion.dmov, completion.reached, completion.stat), (0, 0, 18), "{completion:?}");
    }

    #[test]
    fn a_wait_write_of_a_speed_is_not_answered_with_an_earlier_targets_limit_violation() {
        let mut s = service();
        s.write(at(0.0), WriteRequest::new("DHLM", b"10", Text), false, 1);
        s.write(at(0.0), WriteRequest::new("DLLM", b"-10", Text), false, 2);
        s.put(at(0.0), WriteRequest::new("VAL", b"50", Text));
        assert_eq!(s.fields().lvio, 1);
        drain(&mut s);
        s.write(at(0.1), WriteRequest::new("VELO", b"2", Text), true, 3);
        let answers = replies(&drain(&mut s));
        let [(3, Reply::Completion(Field::VELO, completion))] = &answers[..] else { panic!("{answers:?}") };
        assert_eq!((completion.lvio, completion.reached), (1, 1));
    }

    #[test]
    fn a_home_is_not_answered_with_an_earlier_moves_miss() {
        let mut s = service_on(Fields { rtry: 1, rdbd: 0.01, ..demo_fields() }, SimConfig::default());
        s.sim_write(at(0.0), "fraction", b"0.5", Text);
        s.write(at(0.0), WriteRequest::new("VAL", b"4", Text), true, 1);
        let outputs = run_until_idle(&mut s);
        let [(1, Reply::Completion(_, missed))] = &replies(&outputs)[..] else { panic!("{outputs:?}") };
        assert_eq!((missed.miss, missed.reached), (1, 0), "retries ran out short of 4");
        let now = s.poll_timeout().expect("polled");
        s.sim_write(now, "fraction", b"1", Text);
        s.write(now, WriteRequest::new("HOMF", b"1", Text), true, 2);
        let outputs = run_until_idle(&mut s);
        let [(2, Reply::Completion(Field::HOMF, homed))] = &replies(&outputs)[..] else { panic!("{outputs:?}") };
        assert_eq!((homed.miss, homed.sevr, homed.reached), (1, 0, 1), "MISS is the earlier move's: {homed:?}");
    }

    #[test]
    fn a_confirmed_write_of_a_simulator_setting_is_answered_with_its_value_or_refused() {
        let mut s = service();
        s.sim_write_confirmed(at(0.0), "fraction", b"0.5", Text, 1);
        s.sim_write_confirmed(at(0.0), "fraction", b"5", Text, 2);
        s.sim_write_confirmed(at(0.0), "nope", b"1", Text, 3);
        let answers = replies(&drain(&mut s));
        let [(1, Reply::SimSetting(SimSetting::Fraction, Value::Float(half))), (2, Reply::Refused(out_of_range)), (3, Reply::Refused(unknown))] =
            &answers[..]
        else {
            panic!("{answers:?}")
        };
        assert_eq!(*half, 0.5);
        assert!(matches!(out_of_range, RequestError::SimSetting { .. }), "{out_of_range}");
        assert!(unknown.to_string().contains("nope"), "{unknown}");
        s.sim_read(at(0.1), |name| name == "fraction", 4);
        assert_eq!(replies(&drain(&mut s)), vec![(4, Reply::SimSetting(SimSetting::Fraction, Value::Float(0.5)))]);
    }

    #[test]
    fn a_read_of_err_answers_the_last_message_posted_there() {
        let mut s = service();
        s.read("ERR", 1);
        s.put(at(0.0), WriteRequest::new("VELO", b"fast", Text));
        s.controller_message("E2: following error".into());
        s.read("ERR", 2);
        let answers = replies(&drain(&mut s));
        let [(1, Reply::Message(None)), (2, Reply::Message(Some((RefusalKind::Controller, words))))] = &answers[..]
        else {
            panic!("{answers:?}")
        };
        assert_eq!(words, "E2: following error");
    }

    #[test]
    fn a_plain_write_to_a_key_with_wildcards_is_reported_on_err() {
        let mut s = service();
        s.wildcard_put("motor/m1/*");
        let outputs = drain(&mut s);
        let [ServiceOutput::Refusal { kind: RefusalKind::Wildcard, message, .. }] = &outputs[..] else {
            panic!("{outputs:?}")
        };
        assert_eq!(message, "motor/m1/*: a write names one field of one axis; this key has wildcards");
    }

    #[test]
    fn a_delete_of_a_field_is_reported_on_err_and_changes_nothing() {
        let mut s = service();
        s.put(at(0.0), WriteRequest::new("DESC", b"slit", Text));
        drain(&mut s);
        s.delete("motor/m1/DESC");
        let outputs = drain(&mut s);
        let [ServiceOutput::Refusal { kind: RefusalKind::BadValue, message, .. }] = &outputs[..] else {
            panic!("{outputs:?}")
        };
        assert_eq!(message, "motor/m1/DESC: a delete is not a write; put a value to write the field");
        s.read("DESC", 1);
        let answers = replies(&drain(&mut s));
        assert_eq!(answers, [(1, Reply::Value(Field::DESC, Value::Text("slit".into())))]);
    }

    #[test]
    fn an_unknown_field_is_named_by_its_start_when_its_name_is_long() {
        let mut s = service();
        let name = "N".repeat(5000);
        s.write(at(0.0), WriteRequest::new(&name, b"1", Text), false, 1);
        let [(1, Reply::Refused(refusal))] = &replies(&drain(&mut s))[..] else { panic!("an unknown field was taken") };
        assert_eq!(refusal.to_string(), format!("{}... (5000 bytes): unknown field", "N".repeat(40)));
    }

    #[test]
    fn a_confirmed_write_is_answered_with_the_value_it_left() {
        let mut s = service();
        s.write(at(0.0), WriteRequest::new("VELO", b"5", Text), false, 1);
        assert_eq!(replies(&drain(&mut s)), vec![(1, Reply::Value(Field::VELO, Value::Float(5.0)))]);
    }

    #[test]
    fn a_wait_write_is_answered_when_its_motion_ends_and_not_before() {
        let mut s = service();
        s.write(at(0.0), WriteRequest::new("VAL", b"1", Text), true, 7);
        let first = drain(&mut s);
        assert!(replies(&first).is_empty(), "answered before the motion: {first:?}");
        assert_eq!(published(&first, Field::DMOV), vec![Value::Int(0)]);
        let rest = run_until_idle(&mut s);
        let answers = replies(&rest);
        assert_eq!(answers.len(), 1, "{answers:?}");
        let (to, Reply::Completion(field, completion)) = &answers[0] else { panic!("{answers:?}") };
        assert_eq!((*to, *field), (7, Field::VAL));
        assert_eq!((completion.rbv, completion.dmov, completion.reached), (1.0, 1, 1));
        assert_eq!(completion.written["VAL"], Value::Float(1.0));
        // The completion comes after the DMOV 1 it reports.
        let dmov_at = rest.iter().position(|o| matches!(o, ServiceOutput::Publish { field: Field::DMOV, .. }));
        let reply_at = rest.iter().position(|o| matches!(o, ServiceOutput::Reply(_)));
        assert!(dmov_at < reply_at, "{rest:?}");
    }

    #[test]
    fn a_confirmed_writes_answer_comes_after_its_posts() {
        let mut s = service();
        let _ = drain(&mut s);
        s.write(at(0.0), WriteRequest::new("VELO", b"4", Text), false, 3);
        let out = drain(&mut s);
        let posted = out.iter().position(|o| matches!(o, ServiceOutput::Publish { field: Field::VELO, .. }));
        let answered = out.iter().position(|o| matches!(o, ServiceOutput::Reply(_)));
        assert!(posted.is_some() && posted < answered, "{out:?}");
        // A limit violation: the record's LVIO, then the refusal.
        s.write(at(0.1), WriteRequest::new("VAL", b"1e9", Text), false, 4);
        let out = drain(&mut s);
        let posted = out.iter().position(|o| matches!(o, ServiceOutput::Publish { field: Field::LVIO, .. }));
        let answered = out.iter().position(|o| matches!(o, ServiceOutput::Reply(_)));
        assert!(posted.is_some() && posted < answered, "{out:?}");
    }

    #[test]
    fn a_wait_write_that_moves_nothing_is_answered_at_once() {
        let mut s = service();
        s.write(at(0.0), WriteRequest::new("VELO", b"4", Text), true, 3);
        let answers = replies(&drain(&mut s));
        assert!(matches!(&answers[..], [(3, Reply::Completion(Field::VELO, c))] if c.dmov == 1), "{answers:?}");
    }

    #[test]
    fn a_wait_is_not_answered_by_the_end_of_the_motion_before_it() {
        let mut s = service();
        s.write(at(0.0), WriteRequest::new("VAL", b"1", Text), false, 1);
        drain(&mut s);
        // Written when the first move has ended on the simulator but before any poll saw it:
        // the processing that notices the end comes first and must not answer this write.
        s.write(at(5.0), WriteRequest::new("VAL", b"2", Text), true, 2);
        let outputs = drain(&mut s);
        assert_eq!(published(&outputs, Field::DMOV), vec![Value::Int(1), Value::Int(0)]);
        assert!(replies(&outputs).iter().all(|(to, _)| *to == 1), "{outputs:?}");
        let answers = replies(&run_until_idle(&mut s));
        assert!(matches!(&answers[..], [(2, Reply::Completion(_, c))] if c.rbv == 2.0), "{answers:?}");
    }

    #[test]
    fn z23_while_disp_disables_puts_only_disp_and_stop_are_taken() {
        let mut s = service();
        s.write(at(0.0), WriteRequest::new("VAL", b"5", Text), false, 1);
        s.write(at(0.1), WriteRequest::new("DISP", b"1", Text), false, 2);
        let before = drain(&mut s);
        assert_eq!(published(&before, Field::DISP), vec![Value::Int(1)]);
        // A target, a setting, a read-only field and a bad value: each refused as puts disabled,
        // before anything else is looked at, as an IOC's dbPutField does.
        for (n, (name, payload)) in
            [("VAL", "-3"), ("VELO", "2"), ("RBV", "1"), ("HOMF", "ten")].into_iter().enumerate()
        {
            s.write(at(0.2), WriteRequest::new(name, payload.as_bytes(), Text), false, 10 + n as u32);
        }
        s.put(at(0.2), WriteRequest::new("JOGF", b"1", Text));
        let outputs = drain(&mut s);
        let kinds: Vec<RefusalKind> = refused_answers(&outputs).iter().map(RequestError::kind).collect();
        assert_eq!(kinds, vec![RefusalKind::PutsDisabled; 4]);
        assert_eq!(refusals(&outputs).len(), 5, "each refusal is reported on ERR");
        assert!(refusals(&outputs)[0].starts_with("VAL: puts are disabled (DISP is not 0)"), "{outputs:?}");
        assert_eq!((s.fields().val, s.fields().velo, s.fields().jogf), (5.0, 10.0, 0));
        // STOP is taken (departure Z23): the move to 5 ends where the motor stops.
        s.put(at(0.2), WriteRequest::new("STOP", b"1", Text));
        run_until_idle(&mut s);
        assert!(s.fields().rbv > 0.0 && s.fields().rbv < 5.0, "stopped short: {}", s.fields().rbv);
        // DISP 0 enables puts again.
        s.put(at(1.0), WriteRequest::new("DISP", b"0", Text));
        s.write(at(1.0), WriteRequest::new("VAL", b"-3", Text), false, 20);
        assert!(matches!(&replies(&drain(&mut s))[..], [(20, Reply::Value(Field::VAL, _))]));
        run_until_idle(&mut s);
        assert_eq!(s.fields().rbv, -3.0);
    }

    #[test]
    fn refusals_are_answered_and_reported_on_err_and_change_nothing() {
        let mut s = service();
        s.write(at(0.0), WriteRequest::new("RBV", b"3", Text), false, 1);
        s.write(at(0.0), WriteRequest::new("NOPE", b"3", Text), false, 2);
        s.write(at(0.0), WriteRequest::new("VAL", b"ten", Text), true, 3);
        s.put(at(0.0), WriteRequest::new("VAL", b"NaN", Text));
        let outputs = drain(&mut s);
        let messages: Vec<String> = refused_answers(&outputs).iter().map(ToString::to_string).collect();
        assert_eq!(messages[0], "RBV is read-only");
        assert_eq!(messages[1], "NOPE: unknown field");
        assert!(messages[2].starts_with("VAL: wrong type"), "{}", messages[2]);
        assert_eq!(refusals(&outputs).len(), 4, "each refusal is reported on ERR");
        assert!(published(&outputs, Field::DMOV).is_empty(), "nothing moved");
        assert_eq!(s.fields().val, 0.0);
    }

    #[test]
    fn a_limit_violation_is_a_refusal_of_the_write() {
        let mut s = service();
        s.write(at(0.0), WriteRequest::new("VAL", b"500", Text), true, 1);
        let outputs = drain(&mut s);
        let answers = replies(&outputs);
        let [(1, Reply::Refused(RequestError::Record(WriteError::NotActedUpon { reason, .. })))] = &answers[..] else {
            panic!("{answers:?}")
        };
        assert!(reason.to_string().starts_with("limit violation"), "{reason}");
        assert_eq!(published(&outputs, Field::DMOV), vec![Value::Int(0), Value::Int(1)]);
    }

    /// What a client does in `every_refusal_says_its_kind_in_the_words_it_always_had`.
    enum Act {
        /// A plain put of text, to prepare the case.
        Put(&'static str, &'static str),
        /// A confirmed write of text.
        Write(&'static str, &'static str),
        /// A confirmed write of text under a hold naming this token.
        Held(&'static str, &'static str, &'static str),
        /// A put of text to a simulator key.
        Sim(&'static str, &'static str),
    }

    #[test]
    fn every_refusal_says_its_kind_in_the_words_it_always_had() {
        use Act::*;
        use RefusalKind::*;
        let unlimited = || service_on(Fields { dhlm: 0.0, dllm: 0.0, ..demo_fields() }, SimConfig::default());
        let near_the_high_limit =
            service_on(Fields { jvel: 1.0, ..demo_fields() }, SimConfig { position: 99_500.0, ..SimConfig::default() });
        let servo = service_on(demo_fields(), SimConfig { servo: true, ..SimConfig::default() });
        let beyond_the_high_switch =
            SimConfig { high_limit_switch: Some(1000.0), position: 2000.0, ..SimConfig::default() };
        let reading_rdbl = Fields { urip: choice::YES, rdbl: "lab/encoder".into(), ..demo_fields() };
        let soft = Axis::new_soft(demo_fields(), PollRates::default(), Instant::ZERO);
        let cases: Vec<(Service, &[Act], RefusalKind, &str)> = vec![
            (service(), &[Write("NOPE", "3")], UnknownField, "NOPE: unknown field"),
            (service(), &[Write("val", "3")], UnknownField, "val: unknown field; field names are upper case: VAL"),
            (service(), &[Write("RBV", "3")], ReadOnly, "RBV is read-only"),
            (service(), &[Write("RBV", "abc")], ReadOnly, "RBV is read-only"),
            (service(), &[Write("VAL", "ten")], BadValue, "VAL: wrong type: expected a number, got text 'ten'"),
            (
                service(),
                &[Write("RDBL", "a//b")],
                BadValue,
                "RDBL: 'a//b' is not a plain key: it has an empty chunk (a leading, trailing or doubled '/')",
            ),
            (
                service(),
                &[Sim("fraction", "x")],
                BadValue,
                "sim/m1/fraction: fraction: a finite number is required, got 'x'",
            ),
            (service(), &[Sim("fraction", "3")], BadValue, "sim/m1/fraction: fraction 3 is outside [0, 2]"),
            (service(), &[Write("HOMF", "0")], Busy, "HOMF refused: writing 0 does not abort a home; write STOP 1"),
            (service(), &[Write("STUP", "0")], Adjusted, "STUP adjusted: only ON may be written; STUP stays OFF"),
            (service(), &[Write("NTMF", "1")], Adjusted, "NTMF adjusted: NTMF must be at least 2; set to 2"),
            (
                service(),
                &[Write("VAL", "500")],
                LimitViolation,
                "VAL: limit violation: dial target 500 is outside the soft limits [-100, 100] (DLLM, DHLM)",
            ),
            (
                near_the_high_limit,
                &[Write("JOGF", "1")],
                LimitViolation,
                "JOGF: limit violation: jog refused within one second of travel of a soft limit",
            ),
            (
                servo,
                &[Put("CNEN", "0"), Write("VAL", "1")],
                Disabled,
                "VAL: motor disabled: closed-loop control is off (CNEN = Disable); write CNEN Enable first",
            ),
            (
                service_on(demo_fields(), beyond_the_high_switch),
                &[Write("HOMF", "1")],
                SwitchActive,
                "HOMF: home (HOMF) refused: the high limit switch is active",
            ),
            (
                unlimited(),
                &[Write("VAL", "1e10")],
                BeyondRawRange,
                "VAL: target out of range: dial target 10000000000 at MRES 0.001 is 10000000000000 steps, beyond the \
                 32-bit raw position",
            ),
            (
                unlimited(),
                &[Put("SET", "1"), Write("DVAL", "1e10")],
                BeyondRawRange,
                "DVAL: the position is not set: dial 10000000000 at MRES 0.001 is 10000000000000 steps, beyond the \
                 32-bit raw position",
            ),
            (
                service_on(reading_rdbl, SimConfig::default()),
                &[Write("VAL", "1")],
                ReadbackUnreadable,
                "VAL: the readback link RDBL (lab/encoder) cannot be read",
            ),
            (
                AxisService::new(&KeyLayout::default(), "m1", soft),
                &[Sim("position", "1")],
                NotSimulated,
                "sim/m1/position: this axis is not simulated",
            ),
            (
                service().with_jog_hold(JogHold::Required),
                &[Write("JOGF", "1")],
                HoldRequired,
                "JOGF: this axis jogs only under a hold (the jog deadman): attach {kind: \"hold\", token: <your \
                 liveliness token>} to the write (README: Holding a motion)",
            ),
            (
                service(),
                &[Held("VAL", "1", "motor/*/x")],
                BadHold,
                "VAL: the hold's token: 'motor/*/x' is not a plain key: wildcards select many keys",
            ),
            (
                service(),
                &[Held("JOGF", "1", "motor/m1")],
                BadHold,
                "JOGF: the hold's token motor/m1 is not under motor/m1/@hold/ (a hold names a token of this axis's \
                 hold space)",
            ),
        ];
        for (mut s, acts, kind, words) in cases {
            for act in acts {
                match act {
                    Put(name, text) => s.put(at(0.0), WriteRequest::new(name, text.as_bytes(), Text)),
                    Write(name, text) => s.write(at(0.0), WriteRequest::new(name, text.as_bytes(), Text), false, 1),
                    Held(name, text, token) => {
                        let request = WriteRequest::new(name, text.as_bytes(), Text).held(Some(Ok(Hold::new(token))));
                        s.write(at(0.0), request, false, 1);
                    }
                    Sim(name, text) => s.sim_write(at(0.0), name, text.as_bytes(), Text),
                }
            }
            let outputs = drain(&mut s);
            let published: Vec<(RefusalKind, &str)> = outputs
                .iter()
                .filter_map(|o| match o {
                    ServiceOutput::Refusal { kind, message, .. } => Some((*kind, message.as_str())),
                    _ => None,
                })
                .collect();
            assert_eq!(published, [(kind, words)], "on ERR");
            for (_, reply) in replies(&outputs) {
                let Reply::Refused(refusal) = reply else { panic!("{words}: answered {reply:?}") };
                assert_eq!((refusal.kind(), refusal.to_string().as_str()), (kind, words), "in the reply");
            }
        }
    }

    #[test]
    fn field_names_are_exact_and_the_wrong_case_is_refused_naming_the_field() {
        let mut s = service();
        s.put(at(0.0), WriteRequest::new("val", b"5", Text));
        s.write(at(0.0), WriteRequest::new("Val", b"5", Text), false, 1);
        s.read("rbv", 2);
        let outputs = drain(&mut s);
        assert_eq!(
            refusals(&outputs),
            [
                "val: unknown field; field names are upper case: VAL",
                "Val: unknown field; field names are upper case: VAL"
            ]
        );
        let answers = replies(&outputs);
        assert!(matches!(&answers[1], (2, Reply::Refused(RequestError::WrongCase { field: Field::RBV, .. }))));
        assert!(published(&outputs, Field::DMOV).is_empty(), "nothing moved");
    }

    #[test]
    fn reads_answer_one_field_or_every_selected_one() {
        let mut s = service();
        s.read("VELO", 1);
        s.read_selected(|f| f.name().starts_with("DR"), 2);
        let answers = replies(&drain(&mut s));
        assert_eq!(answers[0], (1, Reply::Value(Field::VELO, Value::Float(10.0))));
        let selected: Vec<Field> = answers[1..]
            .iter()
            .map(|(to, r)| match r {
                Reply::Value(f, _) if *to == 2 => *f,
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(selected, vec![Field::DRBV]);
    }

    #[test]
    fn each_input_that_posts_a_readback_field_ends_with_one_bundle_of_the_last_ones_marker() {
        let mut s = service();
        s.put(at(0.0), WriteRequest::new("VAL", b"10", Text));
        let mut inputs = vec![drain(&mut s)];
        while s.fields().dmov == 0 {
            let t = s.poll_timeout().expect("a simulated axis is polled");
            s.handle_timeout(t);
            inputs.push(drain(&mut s));
        }
        // An input that posts none of the fields (VELO) has no bundle.
        s.put(at(60.0), WriteRequest::new("VELO", b"5", Text));
        inputs.push(drain(&mut s));
        let mut bundles = 0;
        for outputs in &inputs {
            let last_readback = outputs.iter().rev().find_map(|o| match o {
                ServiceOutput::Publish { field, marker, .. } if Readback::FIELDS.contains(field) => Some(marker),
                _ => None,
            });
            let bundle: Vec<_> = outputs
                .iter()
                .enumerate()
                .filter_map(|(i, o)| match o {
                    ServiceOutput::Readback { marker, .. } => Some((i, marker)),
                    _ => None,
                })
                .collect();
            match last_readback {
                None => assert!(bundle.is_empty(), "{outputs:?}"),
                Some(last) => {
                    assert_eq!(bundle.len(), 1, "{outputs:?}");
                    let (index, marker) = bundle[0];
                    assert_eq!(marker, last);
                    let publishes = outputs.iter().rposition(|o| matches!(o, ServiceOutput::Publish { .. }));
                    assert!(publishes.is_some_and(|p| p < index), "after the input's posts: {outputs:?}");
                    bundles += 1;
                }
            }
        }
        assert!(bundles > 5 && inputs.last().is_some_and(|o| !o.is_empty()), "{bundles} bundles");
    }

    #[test]
    fn only_the_readback_polls_of_a_moving_axis_may_be_dropped_the_start_and_end_must_arrive() {
        let mut s = service();
        s.put(at(0.0), WriteRequest::new("VAL", b"10", Text));
        let mut inputs = vec![(drain(&mut s), s.fields().dmov)];
        while s.fields().dmov == 0 {
            let t = s.poll_timeout().expect("a simulated axis is polled");
            s.handle_timeout(t);
            inputs.push((drain(&mut s), s.fields().dmov));
        }
        let deliveries: Vec<Vec<Delivery>> = inputs
            .iter()
            .map(|(outputs, _)| {
                outputs
                    .iter()
                    .filter_map(|o| match o {
                        ServiceOutput::Publish { delivery, .. } | ServiceOutput::Readback { delivery, .. } => {
                            Some(*delivery)
                        }
                        _ => None,
                    })
                    .collect()
            })
            .collect();
        for ((outputs, dmov), delivery) in inputs.iter().zip(&deliveries) {
            let posted = outputs.iter().filter_map(|o| match o {
                ServiceOutput::Publish { field, .. } => Some(field),
                _ => None,
            });
            let expected = match *dmov == 0 && posted.clone().all(|f| f.is_readback_stream()) {
                true => Delivery::Stream,
                false => Delivery::Event,
            };
            assert!(delivery.iter().all(|d| *d == expected), "{outputs:?}");
        }
        assert_eq!(deliveries[0][0], Delivery::Event, "the move's start");
        assert_eq!(deliveries.last().unwrap()[0], Delivery::Event, "the move's end");
        let streamed = deliveries.iter().filter(|d| d.first() == Some(&Delivery::Stream)).count();
        assert!(streamed > 5, "{streamed} polls in motion streamed");
    }

    #[test]
    fn publications_carry_growing_sequence_numbers_and_the_alarm() {
        let mut s = service();
        s.put(at(0.0), WriteRequest::new("VAL", b"1", Text));
        let seqs: Vec<u64> = drain(&mut s)
            .iter()
            .filter_map(|o| match o {
                ServiceOutput::Publish { marker, .. } => Some(marker.seq),
                _ => None,
            })
            .collect();
        assert!(seqs.len() > 3 && seqs.windows(2).all(|w| w[0] < w[1]), "{seqs:?}");
    }

    #[test]
    fn a_link_written_at_run_time_is_followed_and_a_bad_one_refused_naming_the_field() {
        let mut s = service();
        s.write(at(0.0), WriteRequest::new("DOL", b"lab/setpoint", Text), false, 1);
        let outputs = drain(&mut s);
        let follows: Vec<&ServiceOutput<u32>> =
            outputs.iter().filter(|o| matches!(o, ServiceOutput::Follow { .. })).collect();
        assert_eq!(follows, [&ServiceOutput::Follow { link: InputLink::Desired, key: "lab/setpoint".into() }]);
        for (field, key, why) in [
            ("RDBL", "a//b", "RDBL: 'a//b' is not a plain key"),
            ("OUT", "x/*y", "OUT: 'x/*y' is not a plain key"),
            ("FLNK", "motor/m1/PROC", "FLNK: motor/m1/PROC: axis 'm1' would link to its own PROC"),
            ("OUT", "motor/m2/RBV", "OUT: motor/m2/RBV: RBV is read-only"),
            ("DINP", "motor/m2/DONE", "DINP: motor/m2/DONE: 'DONE' is not a field of a motor"),
        ] {
            s.write(at(0.0), WriteRequest::new(field, key.as_bytes(), Text), false, 2);
            let answers = replies(&drain(&mut s));
            let [(2, Reply::Refused(refusal))] = &answers[..] else { panic!("{answers:?}") };
            assert!(refusal.to_string().starts_with(why), "{refusal}");
        }
        assert_eq!(
            (s.fields().rdbl.as_str(), s.fields().out.as_str(), s.fields().dol.as_str()),
            ("", "", "lab/setpoint")
        );
        s.write(at(0.0), WriteRequest::new("DOL", b"", Text), false, 3);
        let unlinked = drain(&mut s);
        assert!(unlinked.contains(&ServiceOutput::Follow { link: InputLink::Desired, key: String::new() }));
    }

    #[test]
    fn simulator_keys_are_read_and_written_through_the_table() {
        let mut s = service();
        s.sim_write(at(0.0), "position", b"2500", Text);
        assert!(refusals(&drain(&mut s)).is_empty());
        assert_eq!(s.fields().rbv, 2.5, "the readback follows the carriage at once");
        s.sim_write(at(0.0), "fraction", b"3", Text);
        s.sim_write(at(0.0), "warp", b"1", Text);
        assert_eq!(
            refusals(&drain(&mut s)),
            vec!["sim/m1/fraction: fraction 3 is outside [0, 2]", "sim/m1/warp: unknown simulator key 'warp'"]
        );
        s.sim_read(at(0.0), |name| name == "state" || name == "fraction", 9);
        let answers = replies(&drain(&mut s));
        assert!(matches!(&answers[0], (9, Reply::SimState(state)) if state.position == 2500.0), "{answers:?}");
        assert_eq!(answers[1], (9, Reply::SimSetting(SimSetting::Fraction, Value::Float(1.0))));
    }

    const TOKEN: &str = "motor/m1/@hold/client-1";

    fn held(name: &'static str, payload: &'static [u8]) -> WriteRequest<'static> {
        WriteRequest::new(name, payload, Text).held(Some(Ok(Hold::new(TOKEN))))
    }

    fn watched(outputs: &[ServiceOutput<u32>]) -> Vec<&str> {
        outputs
            .iter()
            .filter_map(|o| match o {
                ServiceOutput::WatchHold { token } => Some(token.as_str()),
                _ => None,
            })
            .collect()
    }

    /// Run virtual time until the axis is at rest (or 30 s); the outputs on the way.
    fn until_rest(s: &mut Service, from: f64) -> Vec<ServiceOutput<u32>> {
        let mut outputs = Vec::new();
        let mut now = from;
        while s.fields().dmov == 0 && now < from + 30.0 {
            now += 0.01;
            s.handle_timeout(at(now));
            outputs.extend(drain(s));
        }
        outputs
    }

    #[test]
    fn a_held_jog_ends_as_a_release_of_the_button_when_its_token_goes() {
        let mut s = service();
        s.write(at(0.0), held("JOGF", b"1"), false, 1);
        assert_eq!(watched(&drain(&mut s)), [TOKEN]);
        s.handle_timeout(at(0.5));
        assert_eq!((s.fields().jogf, s.fields().dmov), (1, 0));
        s.hold_released(at(0.5), TOKEN);
        assert_eq!(s.fields().jogf, 0, "released as JOGF = 0 would");
        assert!(drain(&mut s).iter().any(|o| matches!(o, ServiceOutput::ForgetHold { token } if token == TOKEN)));
        until_rest(&mut s, 0.5);
        assert_eq!(s.fields().movn, 0);
    }

    #[test]
    fn a_held_move_stops_when_its_token_goes_and_a_finished_one_is_forgotten() {
        let mut s = service();
        s.write(at(0.0), held("VAL", b"50"), false, 1);
        drain(&mut s);
        s.handle_timeout(at(0.5));
        s.hold_released(at(0.5), TOKEN);
        until_rest(&mut s, 0.5);
        assert!(s.fields().rbv < 10.0, "stopped on the way: {}", s.fields().rbv);
        // A held move that ends by itself forgets its hold; the token's going then does nothing.
        s.write(at(40.0), held("VAL", b"0.01"), false, 2);
        let outputs = until_rest(&mut s, 40.0);
        assert!(outputs.iter().any(|o| matches!(o, ServiceOutput::ForgetHold { .. })));
        s.hold_released(at(45.0), TOKEN);
        assert!(drain(&mut s).iter().all(|o| !matches!(o, ServiceOutput::Publish { field: Field::STOP, .. })));
    }

    #[test]
    fn an_axis_that_requires_a_hold_refuses_a_plain_jog() {
        let mut s = service().with_jog_hold(JogHold::Required);
        s.write(at(0.0), WriteRequest::new("JOGR", b"1", Text), false, 1);
        let outputs = drain(&mut s);
        let [(1, Reply::Refused(RequestError::HoldRequired(Field::JOGR)))] = &replies(&outputs)[..] else {
            panic!("{outputs:?}")
        };
        assert_eq!((s.fields().jogr, s.fields().dmov), (0, 1), "nothing moved");
        s.write(at(0.1), held("JOGR", b"1"), false, 2);
        assert_eq!(s.fields().jogr, 1);
        drain(&mut s);
        // A hold whose token is no key is refused.
        let bad = WriteRequest::new("VAL", b"1", Text).held(Some(Ok(Hold::new("motor/*/x"))));
        s.write(at(0.2), bad, false, 3);
        assert!(matches!(&replies(&drain(&mut s))[..], [(3, Reply::Refused(RequestError::HoldToken { .. }))]));
        // A hold by a token outside the axis's hold space (its own liveliness token) is refused.
        let elsewhere = WriteRequest::new("JOGF", b"1", Text).held(Some(Ok(Hold::new("motor/m1"))));
        s.write(at(0.3), elsewhere, false, 4);
        let [(4, Reply::Refused(refusal @ RequestError::HoldElsewhere { .. }))] = &replies(&drain(&mut s))[..] else {
            panic!("a hold outside the hold space was taken")
        };
        assert!(refusal.to_string().contains("not under motor/m1/@hold/"), "{refusal}");
        assert_eq!(s.fields().jogf, 0, "nothing moved");
        // A hold that names no token holds nothing: refused, as a confirmed write and as a put.
        let unheld = WriteRequest::new("JOGF", b"1", Text).held(Some(Err(MalformedHold)));
        s.write(at(0.4), unheld.clone(), false, 5);
        let [(5, Reply::Refused(refusal @ RequestError::HoldMalformed { .. }))] = &replies(&drain(&mut s))[..] else {
            panic!("a hold without a token was taken")
        };
        assert_eq!(refusal.kind(), RefusalKind::BadHold);
        s.put(at(0.5), unheld);
        let refused = drain(&mut s);
        assert!(refused.iter().any(|o| matches!(o, ServiceOutput::Refusal { kind: RefusalKind::BadHold, .. })));
        assert_eq!(s.fields().jogf, 0, "nothing moved");
    }
}
