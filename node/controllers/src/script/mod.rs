//! The script driver: motorScriptMotor's Lua scripts, run unchanged on the controller layer.
//!
//! Each axis has a Lua state of its own (`lua.rs`); each driver call (`move`, `home`, `poll`,
//! ...) runs as a coroutine. `asyn.write`, `asyn.read` and `asyn.writeread` yield the bytes to
//! send, and the call resumes with the reply, so a script call is a chain of ordinary requests:
//! the layer keeps one in flight, with its priorities, timeouts, retries and comm-loss handling,
//! and a script is tested byte for byte in virtual time like any protocol. A call starts only
//! when the layer is about to send it (`Protocol::prepare`): calls run one after the other, as
//! under the EPICS controller's lock. Writes without a read are gathered into the next
//! exchange's bytes.
//!
//! Where zmotor differs from motorScriptMotor:
//! - a reply that does not come in time is the layer's business (retried, then the link lost),
//!   not a `nil` handed to the script; the call is abandoned;
//! - the status a poll's parameters make is reported when `poll()` returns
//!   (`asyn.callParamCallbacks` elsewhere posts nothing: a move that posted its axis's last
//!   DONE would end itself);
//! - `epics.get(name)`/`epics.put(name, value)` read and write the node's key space (`Lane::Keys`,
//!   carried out by the runner): `axis.FIELD` is `<prefix>/axis/FIELD` (a PV's record.FIELD),
//!   `axis` its VAL, a name with `/` the key itself; a write is confirmed, and a read or write
//!   that fails is a Lua error naming why;
//! - `MOTOR_REC_RESOLUTION` is the axis's MRES as the launch file gives it;
//! - a script error is a driver error naming the script's file and line (the axis shows a
//!   problem), never a crash; a call running 20 million instructions without an exchange is
//!   stopped;
//! - a stop does not wait behind a motion call of its axis (`move`, `moveVelocity`, `home`)
//!   that is still exchanging (a `move()` that asks until its motion ends): that call is given
//!   up once the reply in flight is in, and `stop()` runs next (under motorScriptMotor's lock
//!   the stop would wait for it). Another axis's stop, and every poll, still wait behind it, as
//!   under that lock.

mod lua;

use crate::keys::KeyReply;
use crate::protocol::{
    line_frame, CommandError, Frame, Lane, Prepared, Protocol, ProtocolOptions, Purpose, ReloadError, ReplyError,
    ReplyEvent, Request, VendorError,
};
use crate::scale::Scale;
use crate::script_source::{ScriptError, ScriptSource};
use lua::{AxisLua, Ran};
use zmotor_core::DeviceStatus;
use zmotor_msgs::{DriverCommand, Gain};

pub(crate) const NAME: &str = "script";

/// What a script sets at its top level for the controller's polls (motorScriptMotor reads them
/// once, from the first axis's state).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ScriptSettings {
    /// `IdlePollPeriod`, seconds.
    pub idle_poll: Option<f64>,
    /// `MovingPollPeriod`, seconds.
    pub moving_poll: Option<f64>,
    /// `ForcedFastPolls`.
    pub forced_fast_polls: Option<f64>,
}

impl ScriptSettings {
    /// The script loaded as axis 0 loads it (its top level run, its macros given), and what it
    /// sets: a script that does not load is refused here, with its file and line, and so is one
    /// without `poll` (a function a script lacks succeeds doing nothing, as motorScriptMotor's;
    /// without poll its axes could never report a position or the end of a motion).
    pub fn of(source: &ScriptSource) -> Result<Self, ScriptError> {
        let axis = AxisLua::new(source, 0)?;
        if !axis.defines(Call::Poll.function()) {
            let message = "defines no function poll(): its axes could never report a position or the end of a motion";
            return Err(ScriptError::Load { script: source.path.clone(), message: message.into() });
        }
        Ok(Self {
            idle_poll: axis.number("IdlePollPeriod"),
            moving_poll: axis.number("MovingPollPeriod"),
            forced_fast_polls: axis.number("ForcedFastPolls"),
        })
    }
}

/// A number as a step keeps it: its bits, so that steps compare exactly.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Number(u64);

impl Number {
    fn new(value: f64) -> Self {
        Number(value.to_bits())
    }

    fn get(self) -> f64 {
        f64::from_bits(self.0)
    }
}

/// A driver call, as the script's function and its arguments.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Call {
    Poll,
    Move { position: Number, relative: bool, min: Number, max: Number, acceleration: Number },
    MoveVelocity { min: Number, max: Number, acceleration: Number },
    Home { min: Number, max: Number, acceleration: Number, forward: bool },
    Stop { acceleration: Number },
    SetPosition(Number),
    SetEncoderRatio(Number),
    SetHighLimit(Number),
    SetLowLimit(Number),
    SetGain(Gain, Number),
    SetClosedLoop(bool),
}

impl Call {
    /// Whether it starts a motion (what a stop of its axis ends).
    fn moves(self) -> bool {
        matches!(self, Call::Move { .. } | Call::MoveVelocity { .. } | Call::Home { .. })
    }

    /// The script function motorScriptMotor calls for it.
    fn function(self) -> &'static str {
        match self {
            Call::Poll => "poll",
            Call::Move { .. } => "move",
            Call::MoveVelocity { .. } => "moveVelocity",
            Call::Home { .. } => "home",
            Call::Stop { .. } => "stop",
            Call::SetPosition(_) => "setPosition",
            Call::SetEncoderRatio(_) => "setEncoderRatio",
            Call::SetHighLimit(_) => "setHighLimit",
            Call::SetLowLimit(_) => "setLowLimit",
            Call::SetGain(Gain::Proportional, _) => "setPGain",
            Call::SetGain(Gain::Integral, _) => "setIGain",
            Call::SetGain(Gain::Derivative, _) => "setDGain",
            Call::SetClosedLoop(_) => "setClosedLoop",
        }
    }

    fn start(self, axis: &mut AxisLua) -> Result<Option<Ran>, String> {
        let name = self.function();
        match self {
            Call::Poll => axis.start(name, ()),
            Call::Move { position, relative, min, max, acceleration } => {
                axis.start(name, (position.get(), relative, min.get(), max.get(), acceleration.get()))
            }
            Call::MoveVelocity { min, max, acceleration } => {
                axis.start(name, (min.get(), max.get(), acceleration.get()))
            }
            Call::Home { min, max, acceleration, forward } => {
                axis.start(name, (min.get(), max.get(), acceleration.get(), forward))
            }
            Call::Stop { acceleration: n }
            | Call::SetPosition(n)
            | Call::SetEncoderRatio(n)
            | Call::SetHighLimit(n)
            | Call::SetLowLimit(n)
            | Call::SetGain(_, n) => axis.start(name, n.get()),
            Call::SetClosedLoop(on) => axis.start(name, on),
        }
    }
}

/// Which part of a call a request is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Part {
    /// The call, not started: it starts when the layer sends it.
    Start(Call),
    /// An exchange of a call under way.
    Exchange(Call),
}

/// A script request: a part of call number `call` on `channel`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ScriptStep {
    channel: usize,
    call: u64,
    part: Part,
}

/// The call under way.
#[derive(Clone, Copy, Debug)]
struct Current {
    channel: usize,
    number: u64,
    call: Call,
    /// A stop of its axis waits: the call ends at the reply in flight.
    given_up: bool,
}

/// The script driver (see the module documentation).
pub(crate) struct Script {
    source: Option<ScriptSource>,
    axes: Vec<(usize, Result<AxisLua, ScriptError>)>,
    calls: u64,
    current: Option<Current>,
    /// Where the reply to the exchange in flight ends: the `InTerminator` of its call.
    terminator: Vec<u8>,
}

impl Script {
    pub(crate) fn new(options: &ProtocolOptions) -> Self {
        Self { source: options.script.clone(), axes: Vec::new(), calls: 0, current: None, terminator: Vec::new() }
    }

    /// The Lua state of `channel`'s axis, made the first time (`AXIS` is the channel).
    fn axis(&mut self, channel: usize) -> &mut Result<AxisLua, ScriptError> {
        if let Some(at) = self.axes.iter().position(|(c, _)| *c == channel) {
            return &mut self.axes[at].1;
        }
        let state = match &self.source {
            Some(source) => AxisLua::new(source, channel),
            None => Err(ScriptError::Missing),
        };
        if let Err(e) = &state {
            tracing::error!(channel, "{e}");
        }
        self.axes.push((channel, state));
        &mut self.axes.last_mut().expect("just pushed").1
    }

    fn placeholder(&mut self, channel: usize, call: Call) -> Request<ScriptStep> {
        self.calls += 1;
        Request::silent(Vec::new(), ScriptStep { channel, call: self.calls, part: Part::Start(call) })
    }

    /// What a call that ran to an exchange or its end, or failed, means for the layer: the
    /// requests to send next, in order, and what to report.
    fn carry_on(
        &mut self,
        current: Current,
        ran: Result<Option<Ran>, ScriptError>,
    ) -> (Vec<Request<ScriptStep>>, Vec<ReplyEvent<ScriptStep>>) {
        let channel = current.channel;
        let step = ScriptStep { channel, call: current.number, part: Part::Exchange(current.call) };
        let ran = match ran {
            Ok(Some(ran)) => ran,
            // A function the script does not have: the call succeeds (motorScriptMotor's).
            Ok(None) => Ran::Returned { written: Vec::new() },
            Err(error) => {
                self.current = None;
                // Reported, not logged here: the node's log names an error once, with its repeats.
                let error = VendorError { channel: Some(channel), code: NAME.into(), meaning: error.to_string() };
                let event = if current.call == Call::Poll {
                    ReplyEvent::ControllerError(error)
                } else {
                    ReplyEvent::Refused(error)
                };
                return (Vec::new(), vec![event]);
            }
        };
        match ran {
            Ran::Exchange { bytes, terminator } => {
                self.terminator = terminator;
                (vec![Request::query(bytes, step)], Vec::new())
            }
            Ran::Key { access, written } => {
                let written = (!written.is_empty()).then(|| Request::silent(written, step));
                (written.into_iter().chain([Request::key(&access, step)]).collect(), Vec::new())
            }
            Ran::Returned { written } => {
                self.current = None;
                let last = (!written.is_empty()).then(|| Request::silent(written, step)).into_iter().collect();
                let mut events = Vec::new();
                if current.call == Call::Poll {
                    if let Ok(axis) = self.axis(channel) {
                        let params = axis.params();
                        let status = DeviceStatus {
                            position: params.double("MOTOR_POSITION"),
                            encoder_position: params.double("MOTOR_ENCODER_POSITION"),
                            velocity: params.double("MOTOR_ACT_VELOCITY"),
                            msta: params.msta,
                            readback: None,
                        };
                        events.push(ReplyEvent::Status { channel, status });
                    }
                }
                (last, events)
            }
        }
    }
}

impl Protocol for Script {
    type Step = ScriptStep;

    fn name(&self) -> &'static str {
        NAME
    }

    fn purpose(step: ScriptStep) -> Purpose {
        let (Part::Start(call) | Part::Exchange(call)) = step.part;
        match call {
            Call::Poll => Purpose::Poll { channel: step.channel },
            _ => Purpose::Command { channel: step.channel },
        }
    }

    fn frame(&self, buffer: &[u8]) -> Frame {
        if self.terminator.is_empty() {
            unterminated_frame(buffer)
        } else {
            line_frame(buffer, &self.terminator)
        }
    }

    fn init(&mut self, channels: &[usize]) -> Vec<Request<ScriptStep>> {
        for &channel in channels {
            let _ = self.axis(channel);
        }
        Vec::new()
    }

    fn poll(&mut self, channels: &[usize]) -> Vec<Request<ScriptStep>> {
        channels.iter().map(|&channel| self.placeholder(channel, Call::Poll)).collect()
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<ScriptStep>>, CommandError> {
        let n = Number::new;
        let call = match *command {
            DriverCommand::Move { position, relative, min_velocity, max_velocity, acceleration } => Call::Move {
                position: n(position),
                relative,
                min: n(min_velocity),
                max: n(max_velocity),
                acceleration: n(acceleration),
            },
            DriverCommand::MoveVelocity { min_velocity, max_velocity, acceleration } => {
                Call::MoveVelocity { min: n(min_velocity), max: n(max_velocity), acceleration: n(acceleration) }
            }
            DriverCommand::Home { forward, min_velocity, max_velocity, acceleration } => {
                Call::Home { min: n(min_velocity), max: n(max_velocity), acceleration: n(acceleration), forward }
            }
            DriverCommand::Stop { acceleration } => Call::Stop { acceleration: n(acceleration) },
            DriverCommand::SetPosition { position } => Call::SetPosition(n(position)),
            DriverCommand::Enable { on } => Call::SetClosedLoop(on),
            DriverCommand::SetEncoderRatio { ratio } => Call::SetEncoderRatio(n(ratio)),
            DriverCommand::SetHighLimit { position } => Call::SetHighLimit(n(position)),
            DriverCommand::SetLowLimit { position } => Call::SetLowLimit(n(position)),
            DriverCommand::SetGain { gain, value } => Call::SetGain(gain, n(value)),
            DriverCommand::Poll => Call::Poll,
            DriverCommand::Raw { .. } => {
                return Err(CommandError::Unsupported { protocol: NAME, what: "send raw text (the script speaks)" })
            }
        };
        if let (Call::Stop { .. }, Some(current)) = (call, self.current.as_mut()) {
            // A motion of the stop's own axis: a setting (a position set, a limit, a gain) is no
            // motion a stop ends, and another axis's call is left to end as it would.
            if current.channel == channel && current.call.moves() {
                current.given_up = true;
            }
        }
        Ok(vec![self.placeholder(channel, call)])
    }

    fn prepare(&mut self, request: Request<ScriptStep>) -> Prepared<ScriptStep> {
        let ScriptStep { channel, call: number, part: Part::Start(call) } = request.step else {
            return Prepared { request: Some(request), events: Vec::new() };
        };
        let current = Current { channel, number, call, given_up: false };
        self.current = Some(current);
        let ran = match self.axis(channel) {
            Ok(axis) => call.start(axis).map_err(|message| ScriptError::Call { function: call.function(), message }),
            Err(e) => Err(e.clone()),
        };
        let (requests, mut events) = self.carry_on(current, ran);
        let mut requests = requests.into_iter();
        let request = requests.next();
        let after: Vec<_> = requests.collect();
        if !after.is_empty() {
            events.push(ReplyEvent::FollowUp(after));
        }
        Prepared { request, events }
    }

    fn check_reload(&self, options: &ProtocolOptions) -> Result<(), ReloadError> {
        let source = options.script.as_ref().ok_or(ScriptError::Missing)?;
        ScriptSettings::of(source)?;
        Ok(())
    }

    fn reload(&mut self, options: &ProtocolOptions) {
        // Each axis's state is made again, from the new script, at its next call.
        self.source = options.script.clone();
        self.axes.clear();
        self.current = None;
    }

    fn scale(&self, _channel: usize) -> Scale {
        // The script's steps: what one is in EGU is the script's and the lab's business.
        Scale::motor_steps()
    }

    fn reply(
        &mut self,
        request: &Request<ScriptStep>,
        frame: &[u8],
    ) -> Result<Vec<ReplyEvent<ScriptStep>>, ReplyError> {
        let step = request.step;
        let current = self.current.filter(|c| c.channel == step.channel && c.number == step.call);
        let (Some(current), Part::Exchange(_)) = (current, step.part) else {
            return Err(ReplyError::new(request, frame, "the script call it answers was given up"));
        };
        if current.given_up {
            // Its answer is in: the call ends here, and the stop that waits goes next.
            self.current = None;
            return Ok(Vec::new());
        }
        let key_reply = match request.lane {
            Lane::Keys => {
                let reply = KeyReply::decode(frame);
                Some(reply.ok_or_else(|| ReplyError::new(request, frame, "not an answer of the key space"))?)
            }
            _ => None,
        };
        let terminator = self.terminator.clone();
        let ran = match self.axis(step.channel) {
            Ok(axis) => match key_reply {
                Some(reply) => axis.resume_key(reply),
                None => axis.resume(frame.strip_suffix(terminator.as_slice()).unwrap_or(frame)),
            }
            .map(Some)
            .map_err(|message| ScriptError::Call { function: current.call.function(), message }),
            Err(e) => Err(e.clone()),
        };
        let (next, mut events) = self.carry_on(current, ran);
        if !next.is_empty() {
            events.push(ReplyEvent::FollowUp(next));
        }
        Ok(events)
    }
}

/// A reply read without a terminator (asyn reads what comes): one JSON value when it begins as
/// one (a JSON-RPC controller's), otherwise all that has arrived.
fn unterminated_frame(buffer: &[u8]) -> Frame {
    let blank = buffer.iter().take_while(|b| b.is_ascii_whitespace()).count();
    if blank > 0 {
        return Frame::Junk(blank);
    }
    match buffer.first() {
        None => Frame::Incomplete,
        Some(b'{' | b'[') => json_value_end(buffer).map_or(Frame::Incomplete, Frame::Complete),
        Some(_) => Frame::Complete(buffer.len()),
    }
}

/// Where the JSON object or array at the start of `buffer` ends, if it is complete.
fn json_value_end(buffer: &[u8]) -> Option<usize> {
    let (mut depth, mut in_string, mut escaped) = (0usize, false, false);
    for (at, &byte) in buffer.iter().enumerate() {
        if in_string {
            match byte {
                _ if escaped => escaped = false,
                b'\\' => escaped = true,
                b'"' => in_string = false,
                _ => {}
            }
            continue;
        }
        match byte {
            b'"' => in_string = true,
            b'{' | b'[' => depth += 1,
            b'}' | b']' => {
                depth = depth.saturating_sub(1);
                if depth == 0 {
                    return Some(at + 1);
                }
            }
            _ => {}
        }
    }
    None
}

#[cfg(test)]
mod tests;
