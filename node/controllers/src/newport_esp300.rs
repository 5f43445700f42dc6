//! Newport ESP300 / ESP301 (and the MM4000 family's command set): ASCII over a serial line
//! (19200 8N1, RTS/CTS as the controller's factory setting), commands ended by `\r`, replies by
//! `\r\n`, as the EPICS driver motorNewport (devESP300.cc, drvESP300.cc) speaks it.
//!
//! # Wire format
//! A command is the axis in two digits, two letters and a parameter: `01PA5.000000`. Several go
//! on one line separated by `;`. A command answers nothing; a query (`01TP?`) answers one line.
//! Errors wait in the controller's buffer, read oldest first by `TB?` (`code, timestamp,
//! MESSAGE`; code 0 when empty); an axis's error carries the axis as its hundreds digit (`113`:
//! axis 1, motor not enabled).
//!
//! # Channels and units
//! Channel = the axis number, 1 to 3. Positions, speeds and accelerations are in the stage's
//! unit (`SN?`: mm, µm, degrees…), one record step being `units_per_step` of them: read at
//! connection as the EPICS driver reads its drive resolution (the encoder resolution `SU?`, or
//! the full step `FR?` over the microsteps `QS?` for a stepper without encoder feedback, as
//! `ZB?` says), unless the launch file gives it. Values go out with six decimals (`%f`); a value
//! that is not a number is refused, never clamped.
//!
//! # Record commands (axis 1), each one line, then `TB?` until the buffer is empty
//! - move: `01VA<v>;01VB<v0>;01AC<a>;01AG<a>;01PA<p>` (relative `01PR<d>`): the record's
//!   SET_VELOCITY, SET_VEL_BASE, SET_ACCEL, MOVE_ABS as devESP300.cc builds them;
//! - jog: `01VB<v0>;01AC<a>;01AG<a>;01VA<|v|>;01MV+` (or `MV-`);
//! - home: `01VA<v>;01VB<v0>;01AC<a>;01AG<a>;01OR` (the controller's origin search, HOMF and
//!   HOMR alike, as in the EPICS driver);
//! - stop `01ST`; set position `01DH<p>` (define home); enable `01MO` / `01MF`;
//! - raw text: sent as one line;
//! - soft limits, gains, encoder ratio, status refresh: nothing is sent (the controller keeps
//!   its `SR`/`SL`, which a target beyond is refused by, error x07 on ERR).
//!
//! The `TB?` after each command is zmotor's: a refusal reaches the axis's ERR with its command,
//! not a poll later.
//!
//! # Polls and status
//! Initialisation reads `VE?` (logged), then each axis's unit `SN?` and feedback `ZB?` and the
//! resolution; nothing is stopped or moved (the EPICS driver stops every axis at connection).
//! At a node run's first connection only (not under `observe`, not after a reconnection) the
//! motors are switched on, `01MO;02MO`, as PI's servos are: the ESP300 powers up with its
//! motors off, which takes no motion. A motor switched off since stays off. A poll reads, per axis, `01MD?` (motion done), `01TP?` (position), `01MO?`
//! (motor power), then once `PH` (the limit and home switches of every axis) and `TB?` (not
//! under `observe`: it empties the error buffer, which is then the IOC's beside):
//!
//! | reading | MSTA |
//! |---|---|
//! | `MD?` 1 / 0 | DONE / MOVING |
//! | `PH` first word, bit n−1 / n+7 | PLUS_LS / MINUS_LS of axis n |
//! | `PH` second word, bit n−1 | HOME |
//! | `MO?` 1 | POSITION |
//! | an error in `TB?` | PROBLEM (and the error on ERR) |
//!
//! PRESENT and GAIN_SUPPORT follow the encoder feedback `ZB?` reports; the encoder position is
//! the position (the controller has one position query). The controller has no "homed" state
//! to read: HOMED is never set, HOME is the switch.

use crate::protocol::{
    line_frame, line_text, set_bit, state_of, CommandError, Finding, Frame, Protocol, ProtocolOptions, Purpose,
    ReplyError, ReplyEvent, Request, UnitIdentities, VendorError,
};
use crate::scale::{ControllerUnit, Scale, ScaleSource};
use zmotor_core::DeviceStatus;
use zmotor_msgs::bits::msta;
use zmotor_msgs::{DriverCommand, Unit};

/// The protocol's name in launch files.
pub(crate) const NAME: &str = "newport_esp300";

/// Ends a command line.
const OUTPUT_TERMINATOR: &str = "\r";
/// Ends a reply.
const INPUT_TERMINATOR: &[u8] = b"\r\n";
/// Errors read after one command at most, the buffer's depth being unknown: a controller that
/// never says 0 is not asked forever.
const ERRORS_PER_COMMAND: u32 = 10;

/// A request of the ESP300.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Step {
    /// `VE?`.
    Version,
    /// The motors switched on, at a node run's first connection.
    MotorsOn,
    /// `TB?` after them.
    MotorsOnErrors,
    /// A reading of an axis's configuration at connection.
    Config {
        /// The axis.
        channel: usize,
        /// Which.
        item: ConfigItem,
    },
    /// A reading of an axis's poll.
    Read {
        /// The axis.
        channel: usize,
        /// Which.
        reading: Reading,
    },
    /// `PH`: every axis's switches; the last of a poll but the errors.
    Switches,
    /// `TB?` after a poll.
    PollErrors,
    /// A command line of an axis.
    Command {
        /// The axis.
        channel: usize,
    },
    /// `TB?` after a command, the `n`-th.
    CommandErrors {
        /// The axis.
        channel: usize,
        /// How many were read before it.
        n: u32,
    },
}

/// An axis's configuration, read at connection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ConfigItem {
    /// `SN?`: the unit.
    Unit,
    /// `ZB?`: the feedback configuration.
    Feedback,
    /// `SU?`: the encoder resolution.
    EncoderResolution,
    /// `FR?`: a stepper's full step.
    FullStep,
    /// `QS?`: a stepper's microsteps per full step.
    Microsteps,
}

/// The readings of an axis's poll, in order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Reading {
    /// `MD?`.
    Done,
    /// `TP?`.
    Position,
    /// `MO?`.
    Power,
}

/// What the protocol knows of an axis.
#[derive(Clone, Copy, Debug, Default)]
struct Axis {
    unit: Option<Unit>,
    encoder: bool,
    /// Read at connection: (units per step, the queries).
    resolution: Option<(f64, &'static str)>,
    full_step: Option<f64>,
    status: DeviceStatus,
    /// Read by the poll under way, not reported yet.
    fresh: bool,
}

/// The ESP300 protocol.
#[derive(Debug)]
pub(crate) struct Esp300 {
    units_per_step: Option<f64>,
    axes: Vec<(usize, Axis)>,
    motors_switched_on: bool,
    /// Observed beside an IOC: its error buffer, which `TB?` empties, is the IOC's.
    observed: bool,
    /// The firmware version as the initialisation read it (`sync`).
    identity: UnitIdentities,
}

impl Esp300 {
    /// A protocol scaled by `options.units_per_step`, or by what each axis says at connection.
    pub(crate) fn new(options: &ProtocolOptions) -> Self {
        Self {
            units_per_step: options.units_per_step,
            axes: Vec::new(),
            motors_switched_on: false,
            observed: false,
            identity: UnitIdentities::default(),
        }
    }

    fn axis(&mut self, channel: usize) -> &mut Axis {
        state_of(&mut self.axes, channel)
    }

    fn units_per_step(&self, channel: usize) -> f64 {
        let read = self.axes.iter().find(|(c, _)| *c == channel).and_then(|(_, a)| a.resolution);
        self.units_per_step.or(read.map(|(units, _)| units)).unwrap_or(DEFAULT_UNITS_PER_STEP)
    }

    /// `value` steps in the controller's units, six decimals.
    fn units(&self, channel: usize, what: &'static str, steps: f64) -> Result<String, CommandError> {
        let units = steps * self.units_per_step(channel);
        if units.is_finite() {
            Ok(format!("{units:.6}"))
        } else {
            Err(CommandError::OutOfRange { what, value: steps })
        }
    }

    /// `VA`, `VB`, `AC` and `AG` as a motion sets them, in the record's order; no acceleration
    /// of zero (the record sends none: "Don't SET_ACCEL = 0.0").
    fn speeds(&self, n: usize, velocity: f64, base: f64, acceleration: f64) -> Result<Vec<String>, CommandError> {
        let mut parts = vec![
            format!("{n:02}VA{}", self.units(n, "velocity", velocity.abs())?),
            format!("{n:02}VB{}", self.units(n, "base velocity", base.abs())?),
        ];
        if acceleration != 0.0 {
            let a = self.units(n, "acceleration", acceleration.abs())?;
            parts.extend([format!("{n:02}AC{a}"), format!("{n:02}AG{a}")]);
        }
        Ok(parts)
    }

    fn commands(&self, n: usize, command: &DriverCommand) -> Result<Vec<String>, CommandError> {
        Ok(match command {
            DriverCommand::Move { position, relative, min_velocity, max_velocity, acceleration } => {
                let mut line = self.speeds(n, *max_velocity, *min_velocity, *acceleration)?;
                let verb = if *relative { "PR" } else { "PA" };
                line.push(format!("{n:02}{verb}{}", self.units(n, "target", *position)?));
                line
            }
            DriverCommand::MoveVelocity { min_velocity, max_velocity, acceleration } => {
                let mut line = self.speeds(n, *max_velocity, *min_velocity, *acceleration)?;
                // The jog's order: base velocity and acceleration, then the speed and the motion.
                line.rotate_left(1);
                line.push(format!("{n:02}MV{}", if *max_velocity < 0.0 { '-' } else { '+' }));
                line
            }
            DriverCommand::Home { min_velocity, max_velocity, acceleration, .. } => {
                let mut line = self.speeds(n, *max_velocity, *min_velocity, *acceleration)?;
                line.push(format!("{n:02}OR"));
                line
            }
            DriverCommand::Stop { .. } => vec![format!("{n:02}ST")],
            DriverCommand::SetPosition { position } => {
                vec![format!("{n:02}DH{}", self.units(n, "position", *position)?)]
            }
            DriverCommand::Enable { on } => vec![format!("{n:02}{}", if *on { "MO" } else { "MF" })],
            DriverCommand::Raw { text } => vec![text.clone()],
            DriverCommand::SetEncoderRatio { .. }
            | DriverCommand::SetHighLimit { .. }
            | DriverCommand::SetLowLimit { .. }
            | DriverCommand::SetGain { .. }
            | DriverCommand::Poll => Vec::new(),
        })
    }
}

/// A record step when nothing says otherwise: 0.1 µm, the resolution of Newport's common
/// encoded stages.
const DEFAULT_UNITS_PER_STEP: f64 = 0.0001;

fn line(text: &str) -> Vec<u8> {
    format!("{text}{OUTPUT_TERMINATOR}").into_bytes()
}

/// `SN?`'s codes that are units zmotor knows.
fn unit_of(code: u32) -> Option<Unit> {
    let name = match code {
        2 => "mm",
        3 => "um",
        7 => "deg",
        9 => "rad",
        10 => "mrad",
        11 => "urad",
        _ => return None,
    };
    Unit::parse(name)
}

/// A hex number as the ESP300 writes it, `13H` or `13`.
fn hex(text: &str) -> Option<u32> {
    let text = text.trim();
    u32::from_str_radix(text.strip_suffix(['H', 'h']).unwrap_or(text), 16).ok()
}

/// An error of `TB?`: (code, message), None for "no error".
fn buffered_error(text: &str) -> Option<Result<(u32, String), ()>> {
    let mut parts = text.splitn(3, ',');
    let code = match parts.next().map(str::trim).map(str::parse::<u32>) {
        Some(Ok(code)) => code,
        _ => return Some(Err(())),
    };
    if code == 0 {
        return None;
    }
    let message = parts.nth(1).map(str::trim).unwrap_or("").to_string();
    Some(Ok((code, message)))
}

impl Protocol for Esp300 {
    type Step = Step;

    fn name(&self) -> &'static str {
        NAME
    }

    fn purpose(step: Step) -> Purpose {
        match step {
            Step::Version | Step::Config { .. } => Purpose::Init,
            Step::MotorsOn | Step::MotorsOnErrors => Purpose::Setup,
            Step::Read { channel, .. } => Purpose::Poll { channel },
            Step::Switches | Step::PollErrors => Purpose::PollMany,
            Step::Command { channel } | Step::CommandErrors { channel, .. } => Purpose::Command { channel },
        }
    }

    fn frame(&self, buffer: &[u8]) -> Frame {
        match line_frame(buffer, INPUT_TERMINATOR) {
            // A line end alone is not a reply.
            Frame::Complete(2) => Frame::Junk(2),
            frame => frame,
        }
    }

    fn init(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        // Read afresh: the controller may have been changed or upgraded.
        self.identity.clear();
        let mut requests = vec![Request::query(line("VE?"), Step::Version)];
        for &channel in channels {
            for (query, item) in [("SN?", ConfigItem::Unit), ("ZB?", ConfigItem::Feedback)] {
                requests.push(Request::query(line(&format!("{channel:02}{query}")), Step::Config { channel, item }));
            }
        }
        if !self.motors_switched_on && !channels.is_empty() {
            let on: Vec<String> = channels.iter().map(|n| format!("{n:02}MO")).collect();
            requests.push(Request::silent(line(&on.join(";")), Step::MotorsOn));
            requests.push(Request::query(line("TB?"), Step::MotorsOnErrors));
        }
        requests
    }

    fn poll(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        let mut requests = Vec::new();
        for &channel in channels {
            for (query, reading) in [("MD?", Reading::Done), ("TP?", Reading::Position), ("MO?", Reading::Power)] {
                requests.push(Request::query(line(&format!("{channel:02}{query}")), Step::Read { channel, reading }));
            }
        }
        requests.push(Request::query(line("PH"), Step::Switches));
        if !self.observed {
            requests.push(Request::query(line("TB?"), Step::PollErrors));
        }
        requests
    }

    fn observe_only(&mut self) {
        self.observed = true;
    }

    fn sync(&mut self) -> Option<Request<Step>> {
        self.identity.next()?;
        Some(Request::query(line("VE?"), Step::Version))
    }

    /// "ESP300 Version 3.08 09/09/02", as read at connection: no other reply has words.
    fn is_sync_reply(&self, frame: &[u8]) -> bool {
        self.identity.is_answer(line_text(frame, INPUT_TERMINATOR).trim())
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        let parts = self.commands(channel, command)?;
        if parts.is_empty() {
            return Ok(Vec::new());
        }
        Ok(vec![
            Request::silent(line(&parts.join(";")), Step::Command { channel }),
            Request::query(line("TB?"), Step::CommandErrors { channel, n: 0 }),
        ])
    }

    fn scale(&self, channel: usize) -> Scale {
        let axis = self.axes.iter().find(|(c, _)| *c == channel).map(|(_, a)| *a).unwrap_or_default();
        let unit = axis.unit.map_or(ControllerUnit::Steps, ControllerUnit::Known);
        let source = match (self.units_per_step, axis.resolution) {
            (Some(_), _) => ScaleSource::Installation,
            (None, Some((_, queries))) => ScaleSource::Controller(queries),
            (None, None) => ScaleSource::ProtocolDefault,
        };
        Scale { units_per_step: self.units_per_step(channel), unit, source }
    }

    fn reply(&mut self, request: &Request<Step>, frame: &[u8]) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let text = line_text(frame, INPUT_TERMINATOR);
        let text = text.trim();
        let error = |why| ReplyError::new(request, frame, why);
        let number = || text.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| error("not a number"));
        let flag = || match text {
            "0" => Ok(false),
            "1" => Ok(true),
            _ => Err(error("neither 0 nor 1")),
        };
        match request.step {
            // "ESP300 Version 3.08 09/09/02": anything else is not this controller's answer.
            Step::Version if text.to_ascii_lowercase().contains("version") => {
                self.identity.read(0, text);
                Ok(vec![ReplyEvent::Found(Finding::Identity(text.to_string()))])
            }
            Step::Version => Err(error("not a firmware version")),
            Step::Config { channel, item } => {
                let query = |suffix: &str, item| {
                    Request::query(line(&format!("{channel:02}{suffix}")), Step::Config { channel, item })
                };
                match item {
                    ConfigItem::Unit => {
                        let code = text.parse::<u32>().map_err(|_| error("not a unit code"))?;
                        self.axis(channel).unit = unit_of(code);
                        Ok(Vec::new())
                    }
                    ConfigItem::Feedback => {
                        let feedback = hex(text).ok_or_else(|| error("not a hex word"))?;
                        // Bit 8: encoder feedback; bit 9: a stepper's closed-loop positioning.
                        self.axis(channel).encoder = feedback & 0x300 != 0;
                        let next = match feedback & 0x300 {
                            0x200 => vec![query("FR?", ConfigItem::FullStep), query("QS?", ConfigItem::Microsteps)],
                            0 => vec![query("FR?", ConfigItem::FullStep)],
                            _ => vec![query("SU?", ConfigItem::EncoderResolution)],
                        };
                        Ok(vec![ReplyEvent::FollowUp(next)])
                    }
                    ConfigItem::EncoderResolution => {
                        self.axis(channel).resolution = Some((number()?, "SU?, the encoder resolution"));
                        Ok(Vec::new())
                    }
                    ConfigItem::FullStep => {
                        let full_step = number()?;
                        let axis = self.axis(channel);
                        axis.full_step = Some(full_step);
                        axis.resolution = Some((full_step, "FR?, the full step"));
                        Ok(Vec::new())
                    }
                    ConfigItem::Microsteps => {
                        let microsteps = number()?;
                        let axis = self.axis(channel);
                        match axis.full_step.filter(|_| microsteps >= 1.0) {
                            Some(full) => axis.resolution = Some((full / microsteps, "FR? over QS?, the microstep")),
                            None => return Err(error("not a count of microsteps")),
                        }
                        Ok(Vec::new())
                    }
                }
            }
            Step::Read { channel, reading } => {
                let units_per_step = self.units_per_step(channel);
                let value = match reading {
                    Reading::Done | Reading::Power => f64::from(u8::from(flag()?)),
                    Reading::Position => number()?,
                };
                let axis = self.axis(channel);
                let status = &mut axis.status;
                match reading {
                    Reading::Done => {
                        set_bit(&mut status.msta, msta::DONE, value == 1.0);
                        set_bit(&mut status.msta, msta::MOVING, value == 0.0);
                    }
                    Reading::Position => {
                        let position = value / units_per_step;
                        let moving = status.msta & msta::MOVING != 0;
                        set_bit(&mut status.msta, msta::DIRECTION, moving && position > status.position);
                        status.position = position;
                        status.encoder_position = position;
                    }
                    Reading::Power => {
                        set_bit(&mut status.msta, msta::POSITION, value == 1.0);
                        axis.fresh = true;
                    }
                }
                let encoder = axis.encoder;
                set_bit(&mut axis.status.msta, msta::PRESENT | msta::GAIN_SUPPORT, encoder);
                Ok(Vec::new())
            }
            Step::Switches => {
                let (limits, home) = text.split_once(',').ok_or_else(|| error("not two hex words"))?;
                let (Some(limits), Some(home)) = (hex(limits), hex(home)) else { return Err(error("not hex")) };
                // Only the axes this poll read: another's status is as old as its last poll.
                Ok(self
                    .axes
                    .iter_mut()
                    .filter_map(|(channel, axis)| std::mem::take(&mut axis.fresh).then_some((channel, axis)))
                    .map(|(channel, axis)| {
                        let bit = 1 << (*channel - 1);
                        set_bit(&mut axis.status.msta, msta::PLUS_LS, limits & bit != 0);
                        set_bit(&mut axis.status.msta, msta::MINUS_LS, limits & (bit << 8) != 0);
                        set_bit(&mut axis.status.msta, msta::HOME, home & bit != 0);
                        ReplyEvent::Status { channel: *channel, status: axis.status }
                    })
                    .collect())
            }
            Step::PollErrors | Step::CommandErrors { .. } | Step::MotorsOnErrors => {
                if request.step == Step::MotorsOnErrors {
                    self.motors_switched_on = true;
                }
                buffer_errors(request, frame, text)
            }
            Step::Command { .. } | Step::MotorsOn => Ok(Vec::new()),
        }
    }
}

/// What a `TB?` reply says: an error, and after a command the next `TB?`.
fn buffer_errors(request: &Request<Step>, frame: &[u8], text: &str) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
    match buffered_error(text) {
        None => Ok(Vec::new()),
        Some(Ok((code, meaning))) => {
            let axis = usize::try_from(code / 100).ok().filter(|a| *a > 0);
            let mut events =
                vec![ReplyEvent::ControllerError(VendorError { channel: axis, code: code.to_string(), meaning })];
            // The buffer may hold more: read on after a command, at the next poll else.
            if let Step::CommandErrors { channel, n } = request.step {
                if n + 1 < ERRORS_PER_COMMAND {
                    let next = Step::CommandErrors { channel, n: n + 1 };
                    events.push(ReplyEvent::FollowUp(vec![Request::query(line("TB?"), next)]));
                }
            }
            Ok(events)
        }
        Some(Err(())) => Err(ReplyError::new(request, frame, "not an error of the buffer")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sent(requests: &[Request<Step>]) -> Vec<String> {
        requests.iter().map(|r| String::from_utf8_lossy(&r.bytes).into_owned()).collect()
    }

    /// A protocol that read a 0.1 µm encoder on `channel`.
    fn configured(channel: usize) -> Esp300 {
        let mut p = Esp300::new(&ProtocolOptions::default());
        let init = p.init(&[channel]);
        p.reply(&init[1], b"2\r\n").unwrap();
        let events = p.reply(&init[2], b"100H\r\n").unwrap();
        let [ReplyEvent::FollowUp(next)] = &events[..] else { panic!("{events:?}") };
        assert_eq!(sent(next), [format!("{channel:02}SU?\r")]);
        p.reply(&next[0], b"0.0001\r\n").unwrap();
        p
    }

    #[test]
    fn commands_are_one_line_in_the_stages_units_then_the_error_buffer() {
        let mut p = configured(1);
        let go = DriverCommand::Move {
            position: 50_000.0,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 10_000.0,
            acceleration: 100_000.0,
        };
        assert_eq!(
            sent(&p.command(1, &go).unwrap()),
            ["01VA1.000000;01VB0.000000;01AC10.000000;01AG10.000000;01PA5.000000\r", "TB?\r"]
        );
        let jog = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -10_000.0, acceleration: 0.0 };
        assert_eq!(sent(&p.command(1, &jog).unwrap())[0], "01VB0.000000;01VA1.000000;01MV-\r", "no AC of zero");
        assert_eq!(sent(&p.command(1, &DriverCommand::SetPosition { position: -25.0 }).unwrap())[0], "01DH-0.002500\r");
        assert!(p.command(1, &DriverCommand::SetHighLimit { position: 1.0 }).unwrap().is_empty());
        let nan = DriverCommand::Move {
            position: f64::NAN,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 1.0,
            acceleration: 1.0,
        };
        assert!(matches!(p.command(1, &nan), Err(CommandError::OutOfRange { .. })));
        let scale = p.scale(1);
        assert_eq!((scale.units_per_step, scale.unit), (0.0001, ControllerUnit::Known(Unit::MM)));
    }

    #[test]
    fn a_poll_reads_each_axis_then_every_switch_and_reports_only_the_axes_it_read() {
        let mut p = configured(1);
        // Axis 2 is known, and not read by this poll.
        p.axis(2);
        let poll = p.poll(&[1]);
        assert_eq!(sent(&poll), ["01MD?\r", "01TP?\r", "01MO?\r", "PH\r", "TB?\r"]);
        for (request, reply) in poll.iter().zip([&b"0\r\n"[..], b"1.25\r\n", b"1\r\n"]) {
            assert_eq!(p.reply(request, reply).unwrap(), []);
        }
        // Axis 1 on its + limit and axis 2's home switch: only axis 1 was read.
        let events = p.reply(&poll[3], b"1H, 2H\r\n").unwrap();
        let [ReplyEvent::Status { channel: 1, status }] = &events[..] else { panic!("{events:?}") };
        assert_eq!(status.position, 12_500.0);
        let bits = msta::MOVING | msta::DIRECTION | msta::POSITION | msta::PLUS_LS | msta::PRESENT | msta::GAIN_SUPPORT;
        assert_eq!(status.msta, bits);
        assert!(p.reply(&poll[3], b"1H\r\n").is_err());
    }

    #[test]
    fn a_buffered_error_names_its_axis_and_after_a_command_the_next_is_read() {
        let mut p = configured(2);
        let requests = p.command(2, &DriverCommand::Stop { acceleration: 1.0 }).unwrap();
        let events = p.reply(&requests[1], b"213, 451322, MOTOR NOT ENABLED\r\n").unwrap();
        let [ReplyEvent::ControllerError(error), ReplyEvent::FollowUp(next)] = &events[..] else {
            panic!("{events:?}")
        };
        assert_eq!((error.channel, error.code.as_str(), error.meaning.as_str()), (Some(2), "213", "MOTOR NOT ENABLED"));
        assert_eq!(sent(next), ["TB?\r"]);
        assert_eq!(p.reply(&next[0], b"0, 451400, NO ERROR DETECTED\r\n").unwrap(), []);
        let poll = p.poll(&[2]);
        let events = p.reply(&poll[4], b"6, 1, COMMAND DOES NOT EXIST\r\n").unwrap();
        assert!(matches!(&events[..], [ReplyEvent::ControllerError(VendorError { channel: None, .. })]), "{events:?}");
        assert!(p.reply(&poll[4], b"garbage\r\n").is_err());
    }

    #[test]
    fn the_motors_are_switched_on_at_the_first_connection_only() {
        let mut p = configured(1);
        let init = p.init(&[1, 3]);
        assert!(p.reply(&init[0], b"0, 451322, NO ERROR DETECTED\r\n").is_err(), "a stale line is no version");
        let identity = p.reply(&init[0], b"ESP300 Version 3.08 09/09/02\r\n").unwrap();
        assert_eq!(identity, [ReplyEvent::Found(Finding::Identity("ESP300 Version 3.08 09/09/02".into()))]);
        let setup: Vec<_> = init.iter().filter(|r| Esp300::purpose(r.step) == Purpose::Setup).collect();
        assert_eq!(sent(&setup.iter().map(|r| (*r).clone()).collect::<Vec<_>>()), ["01MO;03MO\r", "TB?\r"]);
        p.reply(setup[1], b"0, 5, NO ERROR DETECTED\r\n").unwrap();
        assert!(p.init(&[1, 3]).iter().all(|r| Esp300::purpose(r.step) == Purpose::Init), "not again");
    }
}
