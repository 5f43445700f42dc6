//! SmarAct MCS2: the controller's SCPI-like ASCII interface over TCP (port 55551), as the EPICS
//! driver smarActMCS2MotorDriver.cpp drives it. Every request is one line ended by `\r\n` (the
//! EPICS driver's output terminator); replies are one line ended by `\r\n` (a bare `\n` is taken
//! too). Only queries (`…?`) are answered; setters and actions are silent, and a command the
//! controller refuses leaves an entry in its error queue, read with `:SYST:ERR?` as
//! `<code>,"<text>"` (`0,"No error"` when empty). Channels are 0-based: `:CHAN<n>:<property>`,
//! and `:MOVE<n>`, `:STOP<n>`, `:REF<n>` for the actions.
//!
//! **Units.** A linear positioner counts picometres: positions are signed 64-bit integers in
//! pm, velocities pm/s, accelerations pm/s². One record step is `ProtocolOptions::units_per_step`
//! picometres, default [`DEFAULT_PICOMETRES_PER_STEP`] (1000: one step is one nanometre, as the
//! EPICS driver's PULSES_PER_STEP). Values go out as whole picometres (the EPICS driver prints
//! `%f`; the controller takes integers for these int64 properties), rounded half away from zero;
//! a position, speed or acceleration beyond 64 bits is refused, never clamped.
//!
//! **Commands.** Each command's setters go out back to back and end with one `:SYST:ERR?`, so a
//! refusal (an amplifier switched off, a value out of range) is reported at once as a controller
//! error of that channel; further queue entries are read with follow-ups until the queue answers
//! 0 (at most [`MAX_ERRORS_PER_DRAIN`] in a row, the rest at the next read).
//! - move: `:CHAN<n>:MMOD 0` (absolute) or `1` (relative), `:CHAN<n>:ACC <pm/s²>`,
//!   `:CHAN<n>:VEL <pm/s>`, `:MOVE<n> <pm>`. The base velocity is not used. A speed of 0 turns
//!   the controller's velocity control off (it moves at full speed), as in the EPICS driver.
//! - jog: the MCS2 has no move at constant velocity; a jog is a relative move of
//!   ±[`JOG_DISTANCE_PM`] at the jog speed, ended by a stop (as the PSI variant of the driver). A
//!   jog speed that rounds to 0 pm/s (full speed) is refused.
//! - home: `:CHAN<n>:REF:OPT <4|5>` (AUTO_ZERO, and START_DIR to search backwards for HOMR),
//!   `:CHAN<n>:HOLD -1`, ACC, VEL, `:REF<n>`: the reference mark search, the position set to 0
//!   at the mark.
//! - stop: `:STOP<n>`. Set position: `:CHAN<n>:POS <pm>`. Enable: `:CHAN<n>:AMPL <1|0>` (the
//!   amplifier). Raw text: sent as given, a query if it ends with `?` (its answer is not used).
//! - soft limits, encoder ratio, gains: nothing is sent (see below).
//!
//! A positioner without a sensor (SENSOR_PRESENT clear at the last poll) takes no motion and no
//! set position: those are refused (open-loop stepping is left out).
//!
//! **Poll.** Per channel `:CHAN<n>:STAT?` (the channel state word), then `:CHAN<n>:POS?` when a
//! sensor is present (asked as a follow-up, as the EPICS driver reads it only then), then
//! `:CHAN<n>:AMPL?`; after every channel one `:SYST:ERR?`, whose entries (the queue is the
//! device's, it names no channel) are errors of every channel. Init sends `:DEV:SNUM?`, drains
//! the error queue (entries from before this connection are logged, not reported),
//! `:CHAN<n>:HOLD -1` for each channel (closed-loop moves hold their target), and reads the
//! queue again (reported). Nothing in init moves, references or powers anything. Under
//! `observe` the error queue is never read (a read empties it, and it is the IOC's beside).
//!
//! **Status.** From the state word: DONE = !ACTIVELY_MOVING, MOVING = ACTIVELY_MOVING,
//! PRESENT and GAIN_SUPPORT = SENSOR_PRESENT, HOMED = IS_REFERENCED, HOME = REFERENCE_MARK,
//! SLIP_STALL = FOLLOWING_LIMIT_REACHED, PROBLEM = MOVEMENT_FAILED, POSITIONER_OVERLOAD,
//! OVER_TEMPERATURE or POSITIONER_FAULT. POSITION = `AMPL?` ≠ 0. The position and the encoder
//! position are both the sensor's `POS?`. The MCS2 has no limit switches: END_STOP_REACHED (a
//! mechanical end stop) and RANGE_LIMIT_REACHED (its software range) set the limit bit on the
//! side of the last motion this protocol commanded; the EPICS driver sets both limit bits,
//! which would refuse every move, jog and home until the next move clears the bit, so both are
//! set only when that side is unknown. DIRECTION is the commanded direction while moving.
//!
//! **Left out.** Open-loop (step and scan) moves and sensorless positioners; rotary units
//! (they work as numbers: ndeg instead of pm); the controller's range limits (`RLIM`: the
//! EPICS driver does not write them, and the record keeps its own soft limits); gains and
//! encoder ratio (the sensor counts the position itself); `POS:TARG?` (a jog's target is 100 mm
//! away: the record is given where the stage is); calibration, positioner type, MCLF, hold-time
//! and step settings of the EPICS driver's extra records. Replies carry no channel, so a reply
//! is checked by its form only.

use crate::protocol::{
    line_frame, CommandError, Finding, Frame, Protocol, ProtocolOptions, Purpose, ReplyError, ReplyEvent, Request,
    UnitIdentities, VendorError,
};
use crate::scale::{ControllerUnit, Scale, ScaleSource};
use std::collections::BTreeMap;
use zmotor_core::DeviceStatus;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;
use zmotor_msgs::Unit;

/// The protocol's name in launch files.
pub(crate) const NAME: &str = "smaract_mcs2";

/// Picometres per record step unless the launch file says otherwise: one step is one nanometre.
pub(crate) const DEFAULT_PICOMETRES_PER_STEP: f64 = 1000.0;

/// How far a jog goes, in picometres (100 mm, beyond any positioner's travel): the controller
/// has no move at constant velocity.
pub(crate) const JOG_DISTANCE_PM: i64 = 100_000_000_000;

/// `:CHAN<n>:HOLD` value that keeps the control loop holding the target forever.
pub(crate) const HOLD_FOREVER: i64 = -1;

/// Error-queue entries read one after another before the rest waits for the next read: a
/// controller that never answered 0 would otherwise hold the line forever.
pub(crate) const MAX_ERRORS_PER_DRAIN: u32 = 32;

/// Bits of the channel state word (`:CHAN<n>:STAT?`).
// The whole word, as the manual defines it: a reference of what a reply may carry, the bits
// the driver does not read included.
#[allow(dead_code)]
pub(crate) mod state {
    /// Any motion: a move, a calibration or a reference search.
    pub(crate) const ACTIVELY_MOVING: u32 = 1 << 0;
    /// The control loop is active (moving closed loop, or holding).
    pub(crate) const CLOSED_LOOP_ACTIVE: u32 = 1 << 1;
    /// A sensor calibration is running.
    pub(crate) const CALIBRATING: u32 = 1 << 2;
    /// A reference mark search is running.
    pub(crate) const REFERENCING: u32 = 1 << 3;
    /// The start of a move is delayed (waiting for the sensor or a trigger).
    pub(crate) const MOVE_DELAYED: u32 = 1 << 4;
    /// A positioner with a position sensor is connected.
    pub(crate) const SENSOR_PRESENT: u32 = 1 << 5;
    /// The sensor's calibration data are valid.
    pub(crate) const IS_CALIBRATED: u32 = 1 << 6;
    /// The physical position is known (a reference mark was found).
    pub(crate) const IS_REFERENCED: u32 = 1 << 7;
    /// A mechanical end stop stopped the last closed-loop move.
    pub(crate) const END_STOP_REACHED: u32 = 1 << 8;
    /// The software range limit stopped the last move.
    pub(crate) const RANGE_LIMIT_REACHED: u32 = 1 << 9;
    /// The following error exceeded its limit.
    pub(crate) const FOLLOWING_LIMIT_REACHED: u32 = 1 << 10;
    /// The last movement failed (`:CHAN<n>:ERR?` tells why).
    pub(crate) const MOVEMENT_FAILED: u32 = 1 << 11;
    /// The channel takes part in trajectory streaming.
    pub(crate) const IS_STREAMING: u32 = 1 << 12;
    /// Overload of an electromagnetic drive; the control loop is off.
    pub(crate) const POSITIONER_OVERLOAD: u32 = 1 << 13;
    /// Over temperature; the amplifier is off until it cools.
    pub(crate) const OVER_TEMPERATURE: u32 = 1 << 14;
    /// The positioner stands at a reference mark.
    pub(crate) const REFERENCE_MARK: u32 = 1 << 15;
    /// An electromagnetic positioner is phased.
    pub(crate) const IS_PHASED: u32 = 1 << 16;
    /// A positioner fault (electrical).
    pub(crate) const POSITIONER_FAULT: u32 = 1 << 17;
    /// The amplifier is enabled.
    pub(crate) const AMPLIFIER_ENABLED: u32 = 1 << 18;
    /// Within the in-position window.
    pub(crate) const IN_POSITION: u32 = 1 << 19;
    /// The brake is engaged.
    pub(crate) const BRAKE_ENABLED: u32 = 1 << 20;
}

/// Move modes (`:CHAN<n>:MMOD`) this protocol uses.
pub(crate) mod move_mode {
    /// `:MOVE` takes the absolute target, pm.
    pub(crate) const CLOSED_LOOP_ABSOLUTE: i64 = 0;
    /// `:MOVE` takes the distance, pm.
    pub(crate) const CLOSED_LOOP_RELATIVE: i64 = 1;
}

/// Reference search options (`:CHAN<n>:REF:OPT`) this protocol uses.
pub(crate) mod reference_option {
    /// Start the search backwards (towards negative positions).
    pub(crate) const START_DIRECTION: i64 = 0x01;
    /// Set the position to 0 at the reference mark.
    pub(crate) const AUTO_ZERO: i64 = 0x04;
}

/// What an MCS2 error code means, for the codes the EPICS driver decodes and those the emulator
/// reports (negative: SCPI parser errors; positive: the device's own, as the SDK numbers them).
pub(crate) fn error_text(code: i64) -> Option<&'static str> {
    Some(match code {
        0 => "No error",
        -101 => "Invalid character",
        -103 => "Invalid separator",
        -104 => "Data type error",
        -108 => "Parameter not allowed",
        -109 => "Missing parameter",
        -113 => "Undefined header",
        -151 => "Invalid string data",
        -350 => "Queue overflow",
        -363 => "Input buffer overrun",
        19 => "Invalid parameter",
        34 => "Invalid channel index",
        259 => "No sensor present",
        262 => "Amplifier disabled",
        272 => "Movement overridden",
        _ => return None,
    })
}

/// A request of the MCS2.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Step {
    /// `:DEV:SNUM?` at initialisation.
    SerialNumber,
    /// The error queue as a new connection finds it: entries from before it.
    StaleErrors,
    /// `:CHAN<n>:HOLD` at initialisation: silent.
    Hold,
    /// The error queue after the initialisation.
    InitErrors,
    /// One reading of a channel's poll.
    Read {
        /// The channel polled.
        channel: usize,
        /// Which reading.
        reading: Reading,
    },
    /// The error queue after a poll, read with the last channel's poll.
    PollErrors {
        /// The last channel polled.
        channel: usize,
    },
    /// A setter of a command: silent.
    Setter {
        /// The channel commanded.
        channel: usize,
    },
    /// Raw text with a `?`: only that its answer came counts.
    RawQuery {
        /// The channel it goes with.
        channel: usize,
    },
    /// The error queue after a command: its errors are the channel's.
    CommandErrors {
        /// The channel commanded.
        channel: usize,
    },
}

/// The readings of a channel's poll.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Reading {
    /// `:CHAN<n>:STAT?`: the channel state word.
    State,
    /// `:CHAN<n>:POS?`, asked when the state says a sensor is present.
    Position,
    /// `:CHAN<n>:AMPL?`: the amplifier; it completes the poll.
    Amplifier,
}

/// Which way a channel was last sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Travel {
    Up,
    Down,
}

impl Travel {
    fn of(upwards: bool) -> Travel {
        if upwards {
            Travel::Up
        } else {
            Travel::Down
        }
    }
}

/// What the protocol knows of one channel.
#[derive(Clone, Copy, Debug, Default)]
struct Channel {
    /// The state word of the poll under way (or the last one).
    state: Option<u32>,
    /// The last position read, pm.
    position: Option<i64>,
    /// The side of the last motion commanded, for the end stop.
    travel: Option<Travel>,
}

/// The MCS2 protocol (see the module documentation).
#[derive(Debug)]
pub(crate) struct Mcs2 {
    picometres_per_step: f64,
    /// Where `picometres_per_step` comes from.
    source: ScaleSource,
    channels: BTreeMap<usize, Channel>,
    /// Error-queue entries read in a row without reaching 0.
    errors_in_a_row: u32,
    /// Observed beside an IOC: the device's error queue, which a read empties, is the IOC's.
    observed: bool,
    /// The serial number's reply as the initialisation read it (`sync`).
    identity: UnitIdentities,
}

impl Mcs2 {
    /// A protocol with the installation's scale (`units_per_step`: picometres per step).
    pub(crate) fn new(options: &ProtocolOptions) -> Self {
        Self {
            picometres_per_step: options.units_per_step.unwrap_or(DEFAULT_PICOMETRES_PER_STEP),
            source: if options.units_per_step.is_some() {
                ScaleSource::Installation
            } else {
                ScaleSource::ProtocolDefault
            },
            channels: BTreeMap::new(),
            errors_in_a_row: 0,
            observed: false,
            identity: UnitIdentities::default(),
        }
    }

    /// `steps` (or steps/s, steps/s²) in whole picometres, refused beyond 64 bits or with a
    /// scale that is no scale.
    fn picometres(&self, what: &'static str, steps: f64) -> Result<i64, CommandError> {
        let scale = self.picometres_per_step;
        if !(scale.is_finite() && scale > 0.0) {
            return Err(CommandError::OutOfRange { what: "picometres per step", value: scale });
        }
        let pm = (steps * scale).round();
        // i64::MAX as f64 is 2^63, one past the largest i64.
        if pm.is_finite() && pm >= i64::MIN as f64 && pm < i64::MAX as f64 {
            Ok(pm as i64)
        } else {
            Err(CommandError::OutOfRange { what, value: steps })
        }
    }

    /// A speed or an acceleration (the controller takes magnitudes), pm/s or pm/s².
    fn rate(&self, what: &'static str, per_second: f64) -> Result<i64, CommandError> {
        self.picometres(what, per_second.abs())
    }

    fn channel(&mut self, channel: usize) -> &mut Channel {
        self.channels.entry(channel).or_default()
    }

    /// Motion and set position need the sensor: the positions are its readings.
    fn require_sensor(&self, channel: usize) -> Result<(), CommandError> {
        let sensorless =
            self.channels.get(&channel).and_then(|c| c.state).is_some_and(|s| s & state::SENSOR_PRESENT == 0);
        if sensorless {
            return Err(CommandError::Unsupported {
                protocol: NAME,
                what: "move or set the position of a positioner without a sensor (open-loop steps)",
            });
        }
        Ok(())
    }

    /// The requests of a closed-loop move: mode, acceleration, velocity, go.
    fn closed_loop_move(channel: usize, mode: i64, acceleration: i64, velocity: i64, value: i64) -> Vec<Request<Step>> {
        vec![
            setter(format!(":CHAN{channel}:MMOD {mode}"), channel),
            setter(format!(":CHAN{channel}:ACC {acceleration}"), channel),
            setter(format!(":CHAN{channel}:VEL {velocity}"), channel),
            setter(format!(":MOVE{channel} {value}"), channel),
        ]
    }

    /// One error-queue entry: a controller error (of `channel`, or of every channel) and a
    /// follow-up for the next, or the end of the queue.
    fn error_entry(
        &mut self,
        request: &Request<Step>,
        frame: &[u8],
        channel: Option<usize>,
    ) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let (code, text) = parse_error_entry(&reply_text(frame))
            .ok_or_else(|| ReplyError::new(request, frame, "not code,\"text\""))?;
        if code == 0 {
            self.errors_in_a_row = 0;
            return Ok(Vec::new());
        }
        self.errors_in_a_row += 1;
        let meaning = if text.is_empty() { error_text(code).unwrap_or("unknown error").to_string() } else { text };
        let mut events = Vec::new();
        if request.step == Step::StaleErrors {
            tracing::warn!(code, meaning, "MCS2 error queue entry from before this connection");
        } else {
            events.push(ReplyEvent::ControllerError(VendorError { channel, code: code.to_string(), meaning }));
        }
        if self.errors_in_a_row < MAX_ERRORS_PER_DRAIN {
            events.push(ReplyEvent::FollowUp(vec![request.clone()]));
        } else {
            self.errors_in_a_row = 0;
        }
        Ok(events)
    }

    /// The channel's status once its poll is complete.
    fn status(&self, channel: usize, amplifier: bool) -> DeviceStatus {
        let known = self.channels.get(&channel).copied().unwrap_or_default();
        let position = known.position.map_or(0.0, |pm| pm as f64 / self.picometres_per_step);
        DeviceStatus {
            position,
            encoder_position: position,
            msta: msta_of(known.state.unwrap_or(0), amplifier, known.travel),
            ..DeviceStatus::default()
        }
    }
}

/// A silent request, part of a command to `channel`.
fn setter(line: String, channel: usize) -> Request<Step> {
    Request::silent(format!("{line}\r\n"), Step::Setter { channel })
}

/// A query line.
fn query(line: String, step: Step) -> Request<Step> {
    Request::query(format!("{line}\r\n"), step)
}

/// One reading of `channel`'s poll.
fn read(channel: usize, reading: Reading) -> Request<Step> {
    let property = match reading {
        Reading::State => "STAT",
        Reading::Position => "POS",
        Reading::Amplifier => "AMPL",
    };
    query(format!(":CHAN{channel}:{property}?"), Step::Read { channel, reading })
}

/// The error-queue read.
fn error_query(step: Step) -> Request<Step> {
    query(":SYST:ERR?".to_string(), step)
}

/// A reply's text, without its line end.
fn reply_text(frame: &[u8]) -> String {
    let line = frame.strip_suffix(b"\n").unwrap_or(frame);
    let line = line.strip_suffix(b"\r").unwrap_or(line);
    String::from_utf8_lossy(line).trim().to_string()
}

/// A decimal integer as the controller writes it: an optional sign and digits, nothing else.
fn parse_integer(text: &str) -> Option<i64> {
    let digits = text.strip_prefix(['+', '-']).unwrap_or(text);
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    text.strip_prefix('+').unwrap_or(text).parse().ok()
}

/// `<code>,"<text>"`.
fn parse_error_entry(text: &str) -> Option<(i64, String)> {
    let (code, message) = text.split_once(',')?;
    let message = message.trim().strip_prefix('"')?.strip_suffix('"')?;
    Some((parse_integer(code.trim())?, message.to_string()))
}

/// MSTA of a channel state word (see the module documentation).
fn msta_of(word: u32, amplifier: bool, travel: Option<Travel>) -> u32 {
    let on = |bit: u32| word & bit != 0;
    let moving = on(state::ACTIVELY_MOVING);
    let sensor = on(state::SENSOR_PRESENT);
    let at_limit = on(state::END_STOP_REACHED) || on(state::RANGE_LIMIT_REACHED);
    let fault = state::MOVEMENT_FAILED | state::POSITIONER_OVERLOAD | state::OVER_TEMPERATURE | state::POSITIONER_FAULT;
    let mut bits = 0;
    let mut set = |bit: u32, condition: bool| {
        if condition {
            bits |= bit;
        }
    };
    set(msta::DONE, !moving);
    set(msta::MOVING, moving);
    set(msta::DIRECTION, moving && travel == Some(Travel::Up));
    set(msta::PRESENT | msta::GAIN_SUPPORT, sensor);
    set(msta::HOMED, on(state::IS_REFERENCED));
    set(msta::HOME, on(state::REFERENCE_MARK));
    set(msta::SLIP_STALL, on(state::FOLLOWING_LIMIT_REACHED));
    set(msta::PROBLEM, word & fault != 0);
    set(msta::POSITION, amplifier);
    set(msta::PLUS_LS, at_limit && travel != Some(Travel::Down));
    set(msta::MINUS_LS, at_limit && travel != Some(Travel::Up));
    bits
}

impl Protocol for Mcs2 {
    type Step = Step;

    fn name(&self) -> &'static str {
        NAME
    }

    fn scale(&self, _channel: usize) -> Scale {
        // Positions are picometres on a linear positioner, nanodegrees on a rotary one.
        let unit = ControllerUnit::Physical { linear: Unit::PM, rotary: Unit::NDEG };
        Scale { units_per_step: self.picometres_per_step, unit, source: self.source }
    }

    fn purpose(step: Step) -> Purpose {
        match step {
            Step::SerialNumber | Step::StaleErrors | Step::InitErrors => Purpose::Init,
            Step::Hold => Purpose::Setup,
            Step::Read { channel, .. } | Step::PollErrors { channel } => Purpose::Poll { channel },
            Step::Setter { channel } | Step::RawQuery { channel } | Step::CommandErrors { channel } => {
                Purpose::Command { channel }
            }
        }
    }

    fn frame(&self, buffer: &[u8]) -> Frame {
        match line_frame(buffer, b"\n") {
            // An empty line is not a reply.
            Frame::Complete(n) if buffer[..n].iter().all(u8::is_ascii_whitespace) => Frame::Junk(n),
            frame => frame,
        }
    }

    fn init(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        // What the last connection knew may be stale: the controller may have been restarted.
        self.channels.clear();
        self.errors_in_a_row = 0;
        self.identity.clear();
        let mut requests = vec![query(":DEV:SNUM?".to_string(), Step::SerialNumber)];
        if self.observed {
            return requests;
        }
        requests.push(error_query(Step::StaleErrors));
        for channel in channels {
            let line = format!(":CHAN{channel}:HOLD {HOLD_FOREVER}\r\n");
            requests.push(Request::silent(line, Step::Hold));
        }
        requests.push(error_query(Step::InitErrors));
        requests
    }

    fn observe_only(&mut self) {
        self.observed = true;
    }

    fn sync(&mut self) -> Option<Request<Step>> {
        self.identity.next()?;
        Some(query(":DEV:SNUM?".to_string(), Step::SerialNumber))
    }

    /// The serial number, a quoted SCPI string no other reply is.
    fn is_sync_reply(&self, frame: &[u8]) -> bool {
        self.identity.is_answer(&reply_text(frame))
    }

    fn poll(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        let mut requests = Vec::new();
        for &channel in channels {
            requests.push(read(channel, Reading::State));
            requests.push(read(channel, Reading::Amplifier));
        }
        if let Some(&channel) = channels.last().filter(|_| !self.observed) {
            requests.push(error_query(Step::PollErrors { channel }));
        }
        requests
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        let mut requests = match command {
            DriverCommand::Move { position, relative, max_velocity, acceleration, .. } => {
                self.require_sensor(channel)?;
                let value = self.picometres("target", *position)?;
                let (acceleration, velocity) =
                    (self.rate("acceleration", *acceleration)?, self.rate("velocity", *max_velocity)?);
                let known = self.channel(channel);
                let (mode, travel) = if *relative {
                    (move_mode::CLOSED_LOOP_RELATIVE, Some(Travel::of(value >= 0)))
                } else {
                    let from = known.position;
                    (move_mode::CLOSED_LOOP_ABSOLUTE, from.map(|from| Travel::of(value >= from)))
                };
                known.travel = travel;
                Self::closed_loop_move(channel, mode, acceleration, velocity, value)
            }
            DriverCommand::MoveVelocity { max_velocity, acceleration, .. } => {
                self.require_sensor(channel)?;
                let velocity = self.rate("jog velocity", *max_velocity)?;
                if velocity == 0 {
                    // VEL 0 is the controller's full speed, not a standstill.
                    return Err(CommandError::OutOfRange { what: "jog velocity", value: *max_velocity });
                }
                let acceleration = self.rate("acceleration", *acceleration)?;
                let travel = Travel::of(*max_velocity >= 0.0);
                self.channel(channel).travel = Some(travel);
                let distance = if travel == Travel::Up { JOG_DISTANCE_PM } else { -JOG_DISTANCE_PM };
                Self::closed_loop_move(channel, move_mode::CLOSED_LOOP_RELATIVE, acceleration, velocity, distance)
            }
            DriverCommand::Home { forward, max_velocity, acceleration, .. } => {
                self.require_sensor(channel)?;
                let (acceleration, velocity) =
                    (self.rate("acceleration", *acceleration)?, self.rate("velocity", *max_velocity)?);
                let options =
                    reference_option::AUTO_ZERO | if *forward { 0 } else { reference_option::START_DIRECTION };
                self.channel(channel).travel = Some(Travel::of(*forward));
                vec![
                    setter(format!(":CHAN{channel}:REF:OPT {options}"), channel),
                    setter(format!(":CHAN{channel}:HOLD {HOLD_FOREVER}"), channel),
                    setter(format!(":CHAN{channel}:ACC {acceleration}"), channel),
                    setter(format!(":CHAN{channel}:VEL {velocity}"), channel),
                    setter(format!(":REF{channel}"), channel),
                ]
            }
            DriverCommand::Stop { .. } => vec![setter(format!(":STOP{channel}"), channel)],
            DriverCommand::SetPosition { position } => {
                self.require_sensor(channel)?;
                let value = self.picometres("position", *position)?;
                // Absolute targets are compared with the new position from now on.
                self.channel(channel).position = Some(value);
                vec![setter(format!(":CHAN{channel}:POS {value}"), channel)]
            }
            DriverCommand::Enable { on } => vec![setter(format!(":CHAN{channel}:AMPL {}", u8::from(*on)), channel)],
            DriverCommand::Raw { text } => {
                if text.contains(['\r', '\n']) {
                    // A second line would be answered out of turn.
                    return Err(CommandError::Unsupported { protocol: NAME, what: "send raw text of several lines" });
                }
                if text.trim_end().ends_with('?') {
                    vec![query(text.clone(), Step::RawQuery { channel })]
                } else {
                    vec![setter(text.clone(), channel)]
                }
            }
            // No range limits written, no gains, no encoder ratio (see the module
            // documentation); a status refresh is a poll.
            DriverCommand::SetEncoderRatio { .. }
            | DriverCommand::SetHighLimit { .. }
            | DriverCommand::SetLowLimit { .. }
            | DriverCommand::SetGain { .. }
            | DriverCommand::Poll => return Ok(Vec::new()),
        };
        requests.push(error_query(Step::CommandErrors { channel }));
        Ok(requests)
    }

    fn reply(&mut self, request: &Request<Step>, frame: &[u8]) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let text = reply_text(frame);
        match request.step {
            Step::SerialNumber => {
                self.identity.read(0, &text);
                let serial = text.trim_matches('"');
                Ok(vec![ReplyEvent::Found(Finding::Identity(format!("MCS2, serial number {serial}")))])
            }
            Step::StaleErrors | Step::InitErrors | Step::PollErrors { .. } => self.error_entry(request, frame, None),
            Step::CommandErrors { channel } => self.error_entry(request, frame, Some(channel)),
            // The answer is the user's to read in the controller's log; only that it came counts.
            Step::RawQuery { .. } => Ok(Vec::new()),
            Step::Read { channel, reading: Reading::State } => {
                let word = parse_integer(&text)
                    .and_then(|word| u32::try_from(word).ok())
                    .ok_or_else(|| ReplyError::new(request, frame, "not a channel state word"))?;
                self.channel(channel).state = Some(word);
                if word & state::SENSOR_PRESENT == 0 {
                    return Ok(Vec::new());
                }
                Ok(vec![ReplyEvent::FollowUp(vec![read(channel, Reading::Position)])])
            }
            Step::Read { channel, reading: Reading::Position } => {
                let pm = parse_integer(&text).ok_or_else(|| ReplyError::new(request, frame, "not a position in pm"))?;
                self.channel(channel).position = Some(pm);
                Ok(Vec::new())
            }
            Step::Read { channel, reading: Reading::Amplifier } => {
                let amplifier = match text.as_str() {
                    "0" => false,
                    "1" => true,
                    _ => return Err(ReplyError::new(request, frame, "not 0 or 1")),
                };
                Ok(vec![ReplyEvent::Status { channel, status: self.status(channel, amplifier) }])
            }
            Step::Hold | Step::Setter { .. } => Err(ReplyError::new(request, frame, "no reply was expected")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(requests: &[Request<Step>]) -> Vec<String> {
        requests.iter().map(|r| String::from_utf8_lossy(&r.bytes).into_owned()).collect()
    }

    fn answered(requests: &[Request<Step>]) -> Vec<bool> {
        requests.iter().map(|r| r.answered).collect()
    }

    fn mcs2() -> Mcs2 {
        Mcs2::new(&ProtocolOptions::default())
    }

    fn go(position: f64, relative: bool) -> DriverCommand {
        DriverCommand::Move { position, relative, min_velocity: 10.0, max_velocity: 2000.0, acceleration: 50_000.5 }
    }

    /// Feed a whole poll of `channel` with the replies to its state, (position,) amplifier.
    fn polled(p: &mut Mcs2, channel: usize, state_word: &str, position: Option<&str>, amplifier: &str) -> DeviceStatus {
        let poll = p.poll(&[channel]);
        let events = p.reply(&poll[0], format!("{state_word}\r\n").as_bytes()).unwrap();
        if let Some(position) = position {
            let [ReplyEvent::FollowUp(follow)] = &events[..] else { panic!("{events:?}") };
            assert_eq!(lines(follow), [format!(":CHAN{channel}:POS?\r\n")]);
            assert_eq!(p.reply(&follow[0], format!("{position}\r\n").as_bytes()).unwrap(), []);
        } else {
            assert_eq!(events, [], "no position without a sensor");
        }
        let events = p.reply(&poll[1], format!("{amplifier}\r\n").as_bytes()).unwrap();
        let [ReplyEvent::Status { channel: c, status }] = &events[..] else { panic!("{events:?}") };
        assert_eq!(*c, channel);
        *status
    }

    #[test]
    fn moves_set_mode_acceleration_and_velocity_in_picometres_then_go_then_read_the_error_queue() {
        let mut p = mcs2();
        let absolute = p.command(0, &go(1234.5678, false)).unwrap();
        assert_eq!(
            lines(&absolute),
            [
                ":CHAN0:MMOD 0\r\n",
                ":CHAN0:ACC 50000500\r\n",
                ":CHAN0:VEL 2000000\r\n",
                ":MOVE0 1234568\r\n",
                ":SYST:ERR?\r\n"
            ]
        );
        assert_eq!(answered(&absolute), [false, false, false, false, true], "setters are silent");
        let relative = p.command(5, &go(-0.4, true)).unwrap();
        assert_eq!(lines(&relative)[0], ":CHAN5:MMOD 1\r\n");
        assert_eq!(lines(&relative)[3], ":MOVE5 -400\r\n");
        let jog = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -300.0, acceleration: 1000.0 };
        assert_eq!(
            lines(&p.command(1, &jog).unwrap()),
            [
                ":CHAN1:MMOD 1\r\n",
                ":CHAN1:ACC 1000000\r\n",
                ":CHAN1:VEL 300000\r\n",
                ":MOVE1 -100000000000\r\n",
                ":SYST:ERR?\r\n"
            ]
        );
        let up = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: 300.0, acceleration: 1000.0 };
        assert_eq!(lines(&p.command(1, &up).unwrap())[3], ":MOVE1 100000000000\r\n");
    }

    #[test]
    fn home_stop_set_position_enable_and_raw_text_send_the_driver_lines() {
        let mut p = mcs2();
        let home = |forward| DriverCommand::Home { forward, min_velocity: 0.0, max_velocity: 500.0, acceleration: 0.0 };
        assert_eq!(
            lines(&p.command(2, &home(false)).unwrap()),
            [
                ":CHAN2:REF:OPT 5\r\n",
                ":CHAN2:HOLD -1\r\n",
                ":CHAN2:ACC 0\r\n",
                ":CHAN2:VEL 500000\r\n",
                ":REF2\r\n",
                ":SYST:ERR?\r\n"
            ]
        );
        assert_eq!(lines(&p.command(2, &home(true)).unwrap())[0], ":CHAN2:REF:OPT 4\r\n");
        let stop = p.command(2, &DriverCommand::Stop { acceleration: 1e6 }).unwrap();
        assert_eq!(
            (lines(&stop), answered(&stop)),
            (vec![":STOP2\r\n".into(), ":SYST:ERR?\r\n".into()], vec![false, true])
        );
        let set = DriverCommand::SetPosition { position: -2.5 };
        assert_eq!(lines(&p.command(0, &set).unwrap()), [":CHAN0:POS -2500\r\n", ":SYST:ERR?\r\n"]);
        assert_eq!(lines(&p.command(0, &DriverCommand::Enable { on: false }).unwrap())[0], ":CHAN0:AMPL 0\r\n");
        assert_eq!(lines(&p.command(0, &DriverCommand::Enable { on: true }).unwrap())[0], ":CHAN0:AMPL 1\r\n");
        let raw = p.command(0, &DriverCommand::Raw { text: ":CHAN0:PTYP?".into() }).unwrap();
        assert_eq!(
            (lines(&raw), answered(&raw)),
            (vec![":CHAN0:PTYP?\r\n".into(), ":SYST:ERR?\r\n".into()], vec![true, true])
        );
        assert_eq!(p.reply(&raw[0], b"300\r\n").unwrap(), []);
        let raw = p.command(0, &DriverCommand::Raw { text: ":CAL0".into() }).unwrap();
        assert_eq!(answered(&raw), [false, true]);
        for nothing in [
            DriverCommand::SetHighLimit { position: 1.0 },
            DriverCommand::SetLowLimit { position: -1.0 },
            DriverCommand::SetEncoderRatio { ratio: 2.0 },
            DriverCommand::SetGain { gain: zmotor_msgs::Gain::Proportional, value: 0.5 },
            DriverCommand::Poll,
        ] {
            assert_eq!(p.command(0, &nothing).unwrap(), [], "{nothing:?}");
        }
    }

    #[test]
    fn the_scale_is_the_installations_and_values_beyond_64_bits_are_refused() {
        let mut picometre_steps =
            Mcs2::new(&ProtocolOptions { units_per_step: Some(1.0), ..ProtocolOptions::default() });
        assert_eq!(lines(&picometre_steps.command(0, &go(1234.5, false)).unwrap())[3], ":MOVE0 1235\r\n");
        let mut p = mcs2();
        for refused in [go(1e17, false), go(-1e17, true), go(f64::NAN, false)] {
            assert!(
                matches!(p.command(0, &refused), Err(CommandError::OutOfRange { what: "target", .. })),
                "{refused:?}"
            );
        }
        let fast = DriverCommand::Move {
            position: 0.0,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 1e17,
            acceleration: 0.0,
        };
        assert!(matches!(p.command(0, &fast), Err(CommandError::OutOfRange { what: "velocity", .. })));
        // The largest pm the controller holds is taken; one more is not.
        let mut pm = Mcs2::new(&ProtocolOptions { units_per_step: Some(1.0), ..ProtocolOptions::default() });
        let lowest = pm.command(0, &go(i64::MIN as f64, false)).unwrap();
        assert_eq!(lines(&lowest)[3], ":MOVE0 -9223372036854775808\r\n");
        assert!(pm.command(0, &go(-(i64::MIN as f64), false)).is_err(), "2^63 pm");
        let still = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: 0.0004, acceleration: 1.0 };
        assert!(
            matches!(p.command(0, &still), Err(CommandError::OutOfRange { what: "jog velocity", .. })),
            "not full speed"
        );
        let mut unscaled = Mcs2::new(&ProtocolOptions { units_per_step: Some(0.0), ..ProtocolOptions::default() });
        assert!(matches!(
            unscaled.command(0, &go(1.0, false)),
            Err(CommandError::OutOfRange { what: "picometres per step", .. })
        ));
        let two_lines = DriverCommand::Raw { text: ":STOP0\n:STOP1".into() };
        assert!(matches!(p.command(0, &two_lines), Err(CommandError::Unsupported { .. })));
    }

    #[test]
    fn init_reads_the_serial_number_drains_the_queue_and_holds_every_channel_moving_nothing() {
        let mut p = mcs2();
        let init = p.init(&[0, 2]);
        assert_eq!(
            lines(&init),
            [":DEV:SNUM?\r\n", ":SYST:ERR?\r\n", ":CHAN0:HOLD -1\r\n", ":CHAN2:HOLD -1\r\n", ":SYST:ERR?\r\n"]
        );
        assert_eq!(answered(&init), [true, true, false, false, true]);
        let identity = Finding::Identity("MCS2, serial number MCS2-00001234".into());
        assert_eq!(p.reply(&init[0], b"\"MCS2-00001234\"\r\n").unwrap(), [ReplyEvent::Found(identity)]);
        // Entries from before the connection are read to the end but not reported.
        assert_eq!(
            p.reply(&init[1], b"-113,\"Undefined header\"\r\n").unwrap(),
            [ReplyEvent::FollowUp(vec![init[1].clone()])]
        );
        assert_eq!(p.reply(&init[1], b"0,\"No error\"\r\n").unwrap(), []);
        let events = p.reply(&init[4], b"34,\"Invalid channel index\"\r\n").unwrap();
        assert_eq!(
            events[0],
            ReplyEvent::ControllerError(VendorError {
                channel: None,
                code: "34".into(),
                meaning: "Invalid channel index".into()
            })
        );
    }

    #[test]
    fn a_poll_reads_the_state_the_position_when_a_sensor_is_present_and_the_amplifier_then_the_queue() {
        let mut p = mcs2();
        assert_eq!(
            lines(&p.poll(&[0, 2])),
            [":CHAN0:STAT?\r\n", ":CHAN0:AMPL?\r\n", ":CHAN2:STAT?\r\n", ":CHAN2:AMPL?\r\n", ":SYST:ERR?\r\n"]
        );
        assert_eq!(p.poll(&[0, 2])[4].step, Step::PollErrors { channel: 2 });
        // Idle, sensor present, calibrated, referenced, holding: 226.
        let idle = polled(&mut p, 0, "226", Some("-1500250"), "1");
        assert_eq!((idle.position, idle.encoder_position), (-1500.25, -1500.25));
        assert_eq!(idle.msta, msta::DONE | msta::PRESENT | msta::GAIN_SUPPORT | msta::HOMED | msta::POSITION);
        // Moving closed loop after a move up, amplifier reported off.
        p.command(0, &go(0.0, false)).unwrap();
        let moving = polled(&mut p, 0, "227", Some("-1000000"), "0");
        assert_eq!(moving.position, -1000.0);
        assert_eq!(moving.msta, msta::MOVING | msta::DIRECTION | msta::PRESENT | msta::GAIN_SUPPORT | msta::HOMED);
        // At a reference mark, with a following error and a failed movement.
        let troubled = polled(&mut p, 0, &(0x8000 | 0x800 | 0x400 | 0x60).to_string(), Some("0"), "1");
        assert_eq!(
            troubled.msta,
            msta::DONE
                | msta::HOME
                | msta::SLIP_STALL
                | msta::PROBLEM
                | msta::PRESENT
                | msta::GAIN_SUPPORT
                | msta::POSITION
        );
        for fault in [state::POSITIONER_OVERLOAD, state::OVER_TEMPERATURE, state::POSITIONER_FAULT] {
            assert_ne!(polled(&mut p, 0, &(fault | 0x60).to_string(), Some("0"), "1").msta & msta::PROBLEM, 0);
        }
    }

    #[test]
    fn an_end_stop_is_the_limit_on_the_side_of_the_last_motion_and_both_when_unknown() {
        let mut p = mcs2();
        let end_stop = (state::END_STOP_REACHED | state::SENSOR_PRESENT).to_string();
        let limits = |status: DeviceStatus| status.msta & (msta::PLUS_LS | msta::MINUS_LS);
        assert_eq!(limits(polled(&mut p, 1, &end_stop, Some("5"), "1")), msta::PLUS_LS | msta::MINUS_LS);
        let down = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -1.0, acceleration: 1.0 };
        p.command(1, &down).unwrap();
        assert_eq!(limits(polled(&mut p, 1, &end_stop, Some("5"), "1")), msta::MINUS_LS);
        // An absolute move above the last position read goes up.
        p.command(1, &go(1.0, false)).unwrap();
        assert_eq!(limits(polled(&mut p, 1, &end_stop, Some("5"), "1")), msta::PLUS_LS);
        let range_limit = (state::RANGE_LIMIT_REACHED | state::SENSOR_PRESENT).to_string();
        p.command(1, &go(-1.0, true)).unwrap();
        assert_eq!(limits(polled(&mut p, 1, &range_limit, Some("5"), "1")), msta::MINUS_LS);
        let home = DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 1.0, acceleration: 1.0 };
        p.command(1, &home).unwrap();
        assert_eq!(limits(polled(&mut p, 1, &end_stop, Some("5"), "1")), msta::PLUS_LS);
        // A new position redefines what "above" means.
        p.command(1, &DriverCommand::SetPosition { position: 10.0 }).unwrap();
        p.command(1, &go(9.0, false)).unwrap();
        assert_eq!(limits(polled(&mut p, 1, &end_stop, Some("10000"), "1")), msta::MINUS_LS);
    }

    #[test]
    fn a_positioner_without_a_sensor_reports_no_position_and_takes_no_motion() {
        let mut p = mcs2();
        // Idle after power-up without a sensor: amplifier on, nothing else.
        let status = polled(&mut p, 0, "0", None, "1");
        assert_eq!(status.msta, msta::DONE | msta::POSITION);
        assert!(matches!(p.command(0, &go(1.0, false)), Err(CommandError::Unsupported { .. })));
        let home = DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 1.0, acceleration: 1.0 };
        assert!(matches!(p.command(0, &home), Err(CommandError::Unsupported { .. })));
        assert!(p.command(0, &DriverCommand::Stop { acceleration: 1.0 }).is_ok(), "a stop is always sent");
        assert!(p.command(1, &go(1.0, false)).is_ok(), "another channel has its own sensor");
    }

    #[test]
    fn the_error_queue_is_read_until_it_answers_zero_and_named_after_the_command() {
        let mut p = mcs2();
        let requests = p.command(3, &DriverCommand::Enable { on: true }).unwrap();
        let read = &requests[1];
        assert_eq!(
            p.reply(read, b"262,\"Amplifier disabled\"\r\n").unwrap(),
            [
                ReplyEvent::ControllerError(VendorError {
                    channel: Some(3),
                    code: "262".into(),
                    meaning: "Amplifier disabled".into()
                }),
                ReplyEvent::FollowUp(vec![read.clone()])
            ]
        );
        // No text from the controller: the code's own meaning.
        let events = p.reply(read, b"-113,\"\"\r\n").unwrap();
        assert_eq!(
            events[0],
            ReplyEvent::ControllerError(VendorError {
                channel: Some(3),
                code: "-113".into(),
                meaning: "Undefined header".into()
            })
        );
        assert_eq!(p.reply(read, b"0,\"No error\"\r\n").unwrap(), []);
        let poll = p.poll(&[3]);
        let events = p.reply(&poll[2], b"272,\"Movement overridden\"\r\n").unwrap();
        assert_eq!(
            events[0],
            ReplyEvent::ControllerError(VendorError {
                channel: None,
                code: "272".into(),
                meaning: "Movement overridden".into()
            })
        );
        // A queue that never empties is read MAX_ERRORS_PER_DRAIN entries in a row, no more.
        assert_eq!(p.reply(read, b"0,\"No error\"\r\n").unwrap(), []);
        let followed: Vec<bool> = (0..MAX_ERRORS_PER_DRAIN)
            .map(|_| {
                let events = p.reply(read, b"-350,\"Queue overflow\"\r\n").unwrap();
                events.iter().any(|e| matches!(e, ReplyEvent::FollowUp(_)))
            })
            .collect();
        assert!(followed[..followed.len() - 1].iter().all(|f| *f));
        assert_eq!(followed.last(), Some(&false));
    }

    #[test]
    fn replies_that_are_not_of_the_asked_form_are_refused() {
        let mut p = mcs2();
        let poll = p.poll(&[0]);
        for bad in ["abc", "-1", "4294967296", "1.5", "", "0x20", "226 1"] {
            assert!(p.reply(&poll[0], format!("{bad}\r\n").as_bytes()).is_err(), "state {bad:?}");
        }
        let events = p.reply(&poll[0], b"32\r\n").unwrap();
        let [ReplyEvent::FollowUp(position)] = &events[..] else { panic!("{events:?}") };
        for bad in ["12.5", "x", "0,\"No error\"", "--5"] {
            assert!(p.reply(&position[0], format!("{bad}\r\n").as_bytes()).is_err(), "position {bad:?}");
        }
        for bad in ["2", "on", "-1"] {
            assert!(p.reply(&poll[1], format!("{bad}\r\n").as_bytes()).is_err(), "amplifier {bad:?}");
        }
        for bad in ["226", "-113 Undefined header", "x,\"y\"", "5,unquoted", "5,\"open"] {
            assert!(p.reply(&poll[2], format!("{bad}\r\n").as_bytes()).is_err(), "error entry {bad:?}");
        }
        let setter = &p.command(0, &DriverCommand::Stop { acceleration: 1.0 }).unwrap()[0];
        assert!(p.reply(setter, b"0\r\n").is_err(), "a setter has no reply");
    }

    #[test]
    fn replies_are_lines_whole_at_every_byte_boundary_and_empty_lines_are_junk() {
        let p = mcs2();
        let stream = b"226\r\n-1500\r\n1\r\n";
        for cut in 0..stream.len() {
            let expected = if cut < 5 { Frame::Incomplete } else { Frame::Complete(5) };
            assert_eq!(p.frame(&stream[..cut]), expected, "{cut} bytes");
        }
        assert_eq!(p.frame(&stream[5..]), Frame::Complete(7));
        assert_eq!(p.frame(b"\r\n226\r\n"), Frame::Junk(2));
        assert_eq!(p.frame(b"\n"), Frame::Junk(1));
        assert_eq!(p.frame(b"226\n"), Frame::Complete(4), "a bare line feed ends a line too");
        assert_eq!(reply_text(b"226\n"), "226");
        assert_eq!(p.frame(b"\r"), Frame::Incomplete);
    }
}
