//! Delta Tau Turbo PMAC2 and Geo Brick over Ethernet (TCP port 1025), as the EPICS driver of
//! Diamond Light Source (DiamondLightSource/pmac: pmacController.cpp, pmacAxis.cpp and the asyn
//! port pmacAsynIPPort.c that frames its bytes) speaks it.
//!
//! # Wire format
//! A request is an 8-byte header and an ASCII command line: RequestType `VR_DOWNLOAD` (0x40),
//! Request `VR_PMAC_GETRESPONSE` (0xBF), wValue 0, wIndex 0, wLength (big-endian) the length
//! of the line, then the line with no terminator. Several commands go on one line, separated
//! by spaces. The reply is every value the line reports, each ended by `\r`, then ACK (0x06); a
//! line that reports nothing is answered by a lone ACK. An error (I6=1, as the lab's
//! controllers and Delta Tau's own tools set it) ends the reply as BEL `ERRnnn` `\r`, without
//! ACK: the commands after the failing one were not run. A reply that is not one value per key
//! asked, or a value that does not parse, is a `ReplyError`.
//!
//! # Channels and units
//! Channel = the motor number `#n`, 1 to 32. Positions are counts; one record step is
//! `ProtocolOptions::units_per_step` counts, by default 1 (the EPICS driver's axis scale,
//! inverted). Targets go out as counts with two decimals (the driver's `%.2f`), the speed as
//! Ixx22 in counts/ms and the acceleration as Ixx20, the time in ms to reach that speed
//! (`%f`). A target beyond what the commanded-position register holds (48 bits of 1/(32·Ixx08)
//! count at the default Ixx08 = 96) or a value that is not a number is refused, never clamped.
//!
//! # Record commands (motor 1)
//! - move: `I122=<counts/ms> I120=<ms> #1 J=<counts>` (relative `J^<counts>`, from the actual
//!   position), one line; a speed or acceleration of zero leaves its I-variable as it is;
//! - jog: `I122=<counts/ms> I120=<ms> #1 J+` (or `J-`), until stopped or a limit;
//! - home: `#1 HOME`: the controller's home search, its speed and direction Ixx23 as the lab
//!   configured them (HOMF and HOMR both start it, as in the EPICS driver);
//! - stop: `#1 J/`, sent only while the amplifier is enabled: `J/` closes the loop of a killed
//!   motor, and a stop must not power anything;
//! - set position: `#1K M161=<n>*32*I108 M162=<n>*32*I108`, then `#1J/` if the amplifier was
//!   enabled: Delta Tau's suggested M-variables Mxx61/Mxx62 (commanded and actual position
//!   registers, 1/(32·Ixx08) count), which the EPICS driver relies on, the motor killed for
//!   the instant of the redefinition;
//! - enable: `#1 J/` (closed loop, amplifier on) / `#1 K` (killed);
//! - raw text: sent as one line;
//! - soft limits, gains, encoder ratio, status refresh: nothing is sent. Ixx13/Ixx14 and the
//!   gains are the lab's configuration of the controller; the record keeps its own limits.
//!
//! # Polls and status
//! Initialisation reads the card ID (`cid`, 603382 a Geo Brick) and its CPU (`cpu`), then each
//! motor's software limits and gains `I113 I114 I130 I131 I133` (the limits, counts, are
//! logged as its travel when both are set). Nothing is written. A poll reads, for up to ten
//! motors a line (40 keys, the EPICS driver's batch), `#1P #1F i124 #1?`: the actual
//! position, the following error, the flag mode Ixx24 (`$` hex) and the two 24-bit status
//! words (12 hex digits). As the EPICS driver reads them: the record's position is the
//! commanded one, P + F, and the encoder's the actual P; done is in position, or not
//! activated, or amplifier off; then
//!
//! | bit | meaning | MSTA |
//! |---|---|---|
//! | word 1, 21 / 22 | positive / negative end limit | PLUS_LS / MINUS_LS |
//! | word 1, 19 | amplifier enabled | POSITION |
//! | word 2, 10 | home complete | HOMED |
//! | word 2, 2 | fatal following error | SLIP_STALL, PROBLEM |
//! | word 2, 3 / 12 | amplifier fault / stopped on a software limit | PROBLEM |
//! | Ixx24 bit 17 | hardware limits disabled | PROBLEM |
//!
//! A fatal following error or an amplifier fault that was not set at the previous poll is also
//! reported as a controller error. PRESENT (an encoder: P is the actual position) and
//! GAIN_SUPPORT are always set; DIRECTION follows the position between polls.

use crate::protocol::{CommandError, Frame, Protocol, ProtocolOptions, Purpose, ReplyError, ReplyEvent, Request};
use crate::protocol::{Finding, VendorError};
use crate::scale::{ControllerUnit, Scale, ScaleSource};
use zmotor_core::DeviceStatus;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

/// The protocol's name in launch files.
pub(crate) const NAME: &str = "pmac";

/// Counts in one record step unless the launch file says otherwise.
const DEFAULT_UNITS_PER_STEP: f64 = 1.0;

/// `VR_DOWNLOAD`, the request type of a command.
const VR_DOWNLOAD: u8 = 0x40;
/// `VR_PMAC_GETRESPONSE`: send a line, get its response.
const VR_PMAC_GETRESPONSE: u8 = 0xBF;
/// Ends a reply.
const ACK: u8 = 0x06;
/// Begins an error.
const BEL: u8 = 0x07;
/// The longest line one packet carries (Acc-54E: 1492 bytes of data).
const MAX_LINE: usize = 1492;
/// Keys read by one poll line, as the EPICS driver batches them.
const KEYS_PER_LINE: usize = 40;
/// The keys of one motor's poll.
const KEYS_PER_MOTOR: usize = 4;
/// The largest target in counts: 2^47 units of 1/(32·96) count in the commanded-position register.
const MAX_COUNTS: f64 = 140_737_488_355_328.0 / (32.0 * 96.0);

/// Word 1 of `#n?`.
mod word1 {
    pub(super) const ACTIVATED: u32 = 1 << 23;
    pub(super) const NEGATIVE_LIMIT: u32 = 1 << 22;
    pub(super) const POSITIVE_LIMIT: u32 = 1 << 21;
    pub(super) const AMPLIFIER_ENABLED: u32 = 1 << 19;
}

/// Word 2 of `#n?`.
mod word2 {
    pub(super) const SOFT_LIMIT_STOP: u32 = 1 << 12;
    pub(super) const HOME_COMPLETE: u32 = 1 << 10;
    pub(super) const AMPLIFIER_FAULT: u32 = 1 << 3;
    pub(super) const FATAL_FOLLOWING_ERROR: u32 = 1 << 2;
    pub(super) const IN_POSITION: u32 = 1 << 0;
}

/// Ixx24 bit 17: the hardware overtravel limits are ignored.
const LIMITS_DISABLED: u32 = 0x2_0000;

/// A request of the PMAC.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Step {
    /// `cid`.
    CardId,
    /// `cpu`.
    Cpu,
    /// A motor's software limits and gains.
    Limits {
        /// The motor.
        channel: usize,
    },
    /// A poll line: its motors are read back from its keys.
    Poll,
    /// A command line of one motor.
    Command {
        /// The motor.
        channel: usize,
    },
}

/// What the last poll said of a motor.
#[derive(Clone, Copy, Debug, Default)]
struct Seen {
    position: f64,
    amplifier_enabled: bool,
    faults: u32,
}

/// The Turbo PMAC protocol.
#[derive(Debug)]
pub(crate) struct Pmac {
    units_per_step: f64,
    scale_source: ScaleSource,
    model: Option<String>,
    seen: Vec<(usize, Seen)>,
}

impl Pmac {
    /// A protocol with `options.units_per_step` counts a record step.
    pub(crate) fn new(options: &ProtocolOptions) -> Self {
        let (units_per_step, scale_source) = match options.units_per_step {
            Some(units) => (units, ScaleSource::Installation),
            None => (DEFAULT_UNITS_PER_STEP, ScaleSource::ProtocolDefault),
        };
        Self { units_per_step, scale_source, model: None, seen: Vec::new() }
    }

    fn seen(&self, channel: usize) -> Seen {
        self.seen.iter().find(|(c, _)| *c == channel).map(|(_, s)| *s).unwrap_or_default()
    }

    fn remember(&mut self, channel: usize, seen: Seen) {
        match self.seen.iter_mut().find(|(c, _)| *c == channel) {
            Some(entry) => entry.1 = seen,
            None => self.seen.push((channel, seen)),
        }
    }

    /// A target in counts with two decimals.
    fn counts(&self, what: &'static str, steps: f64) -> Result<String, CommandError> {
        let counts = steps * self.units_per_step;
        if counts.is_finite() && counts.abs() <= MAX_COUNTS {
            Ok(format!("{counts:.2}"))
        } else {
            Err(CommandError::OutOfRange { what, value: steps })
        }
    }

    /// `Ixx22=<counts/ms> Ixx20=<ms> `, each left out when its value is zero, as the EPICS
    /// driver writes them before a motion.
    fn speed(&self, channel: usize, velocity: f64, acceleration: f64) -> Result<String, CommandError> {
        if !velocity.is_finite() || !acceleration.is_finite() {
            let value = if velocity.is_finite() { acceleration } else { velocity };
            return Err(CommandError::OutOfRange { what: "speed", value });
        }
        let mut text = String::new();
        if velocity != 0.0 {
            text += &format!("I{channel}22={:.6} ", velocity.abs() * self.units_per_step / 1000.0);
            if acceleration != 0.0 {
                text += &format!("I{channel}20={:.6} ", (velocity / acceleration).abs() * 1000.0);
            }
        }
        Ok(text)
    }

    fn commands(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<String>, CommandError> {
        let enabled = self.seen(channel).amplifier_enabled;
        Ok(match command {
            DriverCommand::Move { position, relative, max_velocity, acceleration, .. } => {
                let speed = self.speed(channel, *max_velocity, *acceleration)?;
                let verb = if *relative { "J^" } else { "J=" };
                vec![format!("{speed}#{channel} {verb}{}", self.counts("target", *position)?)]
            }
            DriverCommand::MoveVelocity { max_velocity, acceleration, .. } => {
                let speed = self.speed(channel, *max_velocity, *acceleration)?;
                vec![format!("{speed}#{channel} {}", if *max_velocity < 0.0 { "J-" } else { "J+" })]
            }
            DriverCommand::Home { .. } => vec![format!("#{channel} HOME")],
            DriverCommand::Stop { .. } if enabled => vec![format!("#{channel} J/")],
            DriverCommand::Stop { .. } => Vec::new(),
            DriverCommand::SetPosition { position } => {
                let counts = (position * self.units_per_step + 0.5).floor();
                if !(counts.is_finite() && counts.abs() <= MAX_COUNTS) {
                    return Err(CommandError::OutOfRange { what: "position", value: *position });
                }
                let n = channel;
                let mut lines = vec![format!("#{n}K M{n}61={counts}*32*I{n}08 M{n}62={counts}*32*I{n}08")];
                if enabled {
                    lines.push(format!("#{n}J/"));
                }
                lines
            }
            DriverCommand::Enable { on } => vec![format!("#{channel} {}", if *on { "J/" } else { "K" })],
            DriverCommand::Raw { text } => vec![text.clone()],
            DriverCommand::SetEncoderRatio { .. }
            | DriverCommand::SetHighLimit { .. }
            | DriverCommand::SetLowLimit { .. }
            | DriverCommand::SetGain { .. }
            | DriverCommand::Poll => Vec::new(),
        })
    }

    /// The status of each motor of a poll line, from its values.
    fn statuses(&mut self, keys: &[&str], values: &[&str]) -> Result<Vec<ReplyEvent<Step>>, &'static str> {
        let mut events = Vec::new();
        for (motor_keys, motor_values) in keys.chunks(KEYS_PER_MOTOR).zip(values.chunks(KEYS_PER_MOTOR)) {
            let channel = poll_channel(motor_keys).ok_or("not the keys of a motor's poll")?;
            let [actual, following, flags, words] = motor_values else { return Err("fewer than four values") };
            let actual: f64 = actual.trim().parse().map_err(|_| "a position that is not a number")?;
            let following: f64 = following.trim().parse().map_err(|_| "a following error that is not a number")?;
            let flags = hex_value(flags).ok_or("Ixx24 that is not a number")?;
            let words = words.trim();
            if words.len() != 12 {
                return Err("a status that is not 12 hex digits");
            }
            let word = |range: std::ops::Range<usize>| u32::from_str_radix(&words[range], 16).ok();
            let (Some(w1), Some(w2)) = (word(0..6), word(6..12)) else { return Err("a status that is not hex") };

            let seen = self.seen(channel);
            let position = (actual + following) / self.units_per_step;
            let amplifier = w1 & word1::AMPLIFIER_ENABLED != 0;
            let done = w2 & word2::IN_POSITION != 0 || w1 & word1::ACTIVATED == 0 || !amplifier;
            let faults = w2 & (word2::FATAL_FOLLOWING_ERROR | word2::AMPLIFIER_FAULT);
            let mut bits = msta::PRESENT | msta::GAIN_SUPPORT;
            let mut set = |on: bool, bit: u32| bits |= if on { bit } else { 0 };
            set(done, msta::DONE);
            set(!done, msta::MOVING);
            set(!done && position > seen.position, msta::DIRECTION);
            set(w1 & word1::POSITIVE_LIMIT != 0, msta::PLUS_LS);
            set(w1 & word1::NEGATIVE_LIMIT != 0, msta::MINUS_LS);
            set(amplifier, msta::POSITION);
            set(w2 & word2::HOME_COMPLETE != 0, msta::HOMED);
            set(w2 & word2::FATAL_FOLLOWING_ERROR != 0, msta::SLIP_STALL);
            let problem = faults != 0 || w2 & word2::SOFT_LIMIT_STOP != 0 || flags & LIMITS_DISABLED != 0;
            set(problem, msta::PROBLEM);
            let status = DeviceStatus {
                position,
                encoder_position: actual / self.units_per_step,
                msta: bits,
                ..Default::default()
            };
            events.push(ReplyEvent::Status { channel, status });
            for (bit, code, meaning) in [
                (
                    word2::FATAL_FOLLOWING_ERROR,
                    "fatal following error",
                    "the motor was killed: following error beyond Ixx11",
                ),
                (word2::AMPLIFIER_FAULT, "amplifier fault", "the amplifier reported a fault and the motor was killed"),
            ] {
                if faults & bit != 0 && seen.faults & bit == 0 {
                    let (code, meaning) = (format!("#{channel}? {code}"), meaning.to_string());
                    events.push(ReplyEvent::ControllerError(VendorError { channel: Some(channel), code, meaning }));
                }
            }
            self.remember(channel, Seen { position, amplifier_enabled: amplifier, faults });
        }
        Ok(events)
    }
}

/// The header and `line`, one request.
fn packet(line: &str) -> Vec<u8> {
    let length = u16::try_from(line.len()).unwrap_or(u16::MAX).to_be_bytes();
    let mut bytes = vec![VR_DOWNLOAD, VR_PMAC_GETRESPONSE, 0, 0, 0, 0, length[0], length[1]];
    bytes.extend_from_slice(line.as_bytes());
    bytes
}

/// The command line of a request, without its header.
fn line_of(request: &Request<Step>) -> &str {
    std::str::from_utf8(request.bytes.get(8..).unwrap_or_default()).unwrap_or_default()
}

/// The motor whose poll keys `#nP #nF inn24 #n?` these are.
fn poll_channel(keys: &[&str]) -> Option<usize> {
    let channel: usize = keys.first()?.strip_prefix('#')?.strip_suffix('P')?.parse().ok()?;
    (keys == poll_keys(channel)).then_some(channel)
}

fn poll_keys(channel: usize) -> [String; KEYS_PER_MOTOR] {
    [format!("#{channel}P"), format!("#{channel}F"), format!("i{channel}24"), format!("#{channel}?")]
}

/// `$hex` or a decimal, as the PMAC reports a variable.
fn hex_value(text: &str) -> Option<u32> {
    let text = text.trim();
    match text.strip_prefix('$') {
        Some(hex) => u32::from_str_radix(hex, 16).ok(),
        None => text.parse::<f64>().ok().filter(|v| *v >= 0.0 && *v <= f64::from(u32::MAX)).map(|v| v as u32),
    }
}

/// What the Turbo SRM says an error code means.
fn meaning(code: &str) -> &'static str {
    match code {
        "ERR001" => "command not allowed during program execution",
        "ERR002" => "password error",
        "ERR003" => "data error or unrecognized command",
        "ERR004" => "illegal character",
        "ERR005" => "command not allowed unless a buffer is open",
        "ERR006" => "no room in buffer for command",
        "ERR007" => "buffer already in use",
        "ERR008" => "MACRO auxiliary communications error",
        "ERR009" => "program structural error",
        "ERR010" => "both overtravel limits set for a motor in the coordinate system",
        "ERR011" => "previous move not completed",
        "ERR012" => "a motor in the coordinate system is open-loop",
        "ERR013" => "a motor in the coordinate system is not activated",
        "ERR014" => "no motors in the coordinate system",
        "ERR015" => "not pointing to a valid program buffer",
        "ERR016" => "running an improperly structured program",
        "ERR017" => "trying to resume after H or Q with motors out of stopped position",
        "ERR018" => "phase reference during a move, a move during phase reference, or a phase clock error",
        "ERR019" => "illegal position-change command while moves are stored in CCBUFFER",
        _ => "an error code the Turbo SRM does not list",
    }
}

/// A reply's values, or the error that ended it: (values, error code).
fn split_reply(frame: &[u8]) -> Result<(Vec<&str>, Option<&str>), &'static str> {
    let text = std::str::from_utf8(frame).map_err(|_| "not ASCII")?;
    let (body, error) = match text.find(char::from(BEL)) {
        Some(at) => {
            let code = text[at + 1..].strip_suffix('\r').ok_or("an error without its CR")?;
            if !(code.len() == 6 && code.starts_with("ERR") && code[3..].bytes().all(|b| b.is_ascii_digit())) {
                return Err("an error that is not ERRnnn");
            }
            (&text[..at], Some(code))
        }
        None => (text.strip_suffix(char::from(ACK)).ok_or("a reply without ACK")?, None),
    };
    if !(body.is_empty() || body.ends_with('\r')) {
        return Err("a value without its CR");
    }
    Ok((body.split_terminator('\r').collect(), error))
}

impl Protocol for Pmac {
    type Step = Step;

    fn name(&self) -> &'static str {
        NAME
    }

    fn purpose(step: Step) -> Purpose {
        match step {
            Step::CardId | Step::Cpu | Step::Limits { .. } => Purpose::Init,
            Step::Poll => Purpose::PollMany,
            Step::Command { channel } => Purpose::Command { channel },
        }
    }

    fn frame(&self, buffer: &[u8]) -> Frame {
        match buffer.iter().position(|b| *b == ACK || *b == BEL || *b == 0) {
            // A NUL is what an Acc-54E sends when it is busy: not a reply.
            Some(0) if buffer[0] == 0 => Frame::Junk(1),
            Some(at) if buffer[at] == ACK => Frame::Complete(at + 1),
            Some(at) if buffer[at] == BEL => match buffer[at..].iter().position(|b| *b == b'\r') {
                Some(cr) => Frame::Complete(at + cr + 1),
                None => Frame::Incomplete,
            },
            Some(at) => Frame::Junk(at + 1),
            None => Frame::Incomplete,
        }
    }

    fn init(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        let mut requests = vec![Request::query(packet("cid"), Step::CardId), Request::query(packet("cpu"), Step::Cpu)];
        for &n in channels {
            requests.push(Request::query(
                packet(&format!("I{n}13 I{n}14 I{n}30 I{n}31 I{n}33")),
                Step::Limits { channel: n },
            ));
        }
        requests
    }

    fn poll(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        channels
            .chunks(KEYS_PER_LINE / KEYS_PER_MOTOR)
            .map(|motors| {
                let keys: Vec<String> = motors.iter().flat_map(|&n| poll_keys(n)).collect();
                Request::query(packet(&keys.join(" ")), Step::Poll)
            })
            .collect()
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        let lines = self.commands(channel, command)?;
        if let Some(long) = lines.iter().find(|line| line.len() > MAX_LINE) {
            return Err(CommandError::OutOfRange { what: "line length", value: long.len() as f64 });
        }
        Ok(lines.iter().map(|line| Request::query(packet(line), Step::Command { channel })).collect())
    }

    fn scale(&self, _channel: usize) -> Scale {
        // Counts: what a count is in EGU is the lab's encoder, nothing the controller says.
        Scale { units_per_step: self.units_per_step, unit: ControllerUnit::Steps, source: self.scale_source }
    }

    fn reply(&mut self, request: &Request<Step>, frame: &[u8]) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let (values, error) = split_reply(frame).map_err(|why| ReplyError::new(request, frame, why))?;
        let channel = match request.step {
            Step::Command { channel } | Step::Limits { channel } => Some(channel),
            Step::CardId | Step::Cpu | Step::Poll => None,
        };
        if let Some(code) = error {
            let meaning = format!("{} (to {})", meaning(code), line_of(request));
            return Ok(vec![ReplyEvent::ControllerError(VendorError { channel, code: code.to_string(), meaning })]);
        }
        let one = || match values[..] {
            [value] => Ok(value.trim()),
            _ => Err(ReplyError::new(request, frame, "not one value")),
        };
        match request.step {
            Step::CardId => {
                let cid = one()?;
                let model = match cid {
                    "603382" => "Geo Brick (3U Turbo PMAC2)",
                    "602404" => "Turbo PMAC2 Clipper",
                    "602413" => "Turbo PMAC2-VME",
                    _ => "a controller of unknown card ID",
                };
                self.model = Some(format!("{model}, cid {cid}"));
                Ok(Vec::new())
            }
            Step::Cpu => {
                let model = self.model.take().unwrap_or_else(|| "a PMAC".to_string());
                Ok(vec![ReplyEvent::Found(Finding::Identity(format!("{model}, CPU {}", one()?)))])
            }
            Step::Limits { channel } => {
                let limit = |at: usize| values.get(at).and_then(|v| v.trim().parse::<f64>().ok());
                let (Some(max), Some(min)) = (limit(0), limit(1)) else {
                    return Err(ReplyError::new(request, frame, "not the motor's software limits"));
                };
                // Zero is no limit.
                let travel = (max != 0.0 && min != 0.0).then_some(Finding::Travel { channel, min, max });
                Ok(travel.map(ReplyEvent::Found).into_iter().collect())
            }
            Step::Poll => {
                let keys: Vec<&str> = line_of(request).split(' ').collect();
                if keys.len() != values.len() {
                    return Err(ReplyError::new(request, frame, "not one value per key"));
                }
                self.statuses(&keys, &values).map_err(|why| ReplyError::new(request, frame, why))
            }
            Step::Command { .. } => Ok(Vec::new()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(requests: &[Request<Step>]) -> Vec<&str> {
        requests
            .iter()
            .map(|r| {
                let length = usize::from(u16::from_be_bytes([r.bytes[6], r.bytes[7]]));
                assert_eq!(r.bytes[..6], [0x40, 0xBF, 0, 0, 0, 0], "the GETRESPONSE header");
                assert_eq!(r.bytes.len(), 8 + length, "wLength is the line's length");
                line_of(r)
            })
            .collect()
    }

    fn pmac() -> Pmac {
        Pmac::new(&ProtocolOptions::default())
    }

    fn enabled(p: &mut Pmac, channel: usize) {
        let poll = p.poll(&[channel]);
        p.reply(&poll[0], b"0\r0\r$800001\r880000018401\r\x06").unwrap();
    }

    #[test]
    fn motions_set_speed_then_jog_on_one_line() {
        let mut p = pmac();
        let go = DriverCommand::Move {
            position: 12000.0,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 2000.0,
            acceleration: 20_000.0,
        };
        assert_eq!(lines(&p.command(1, &go).unwrap()), ["I122=2.000000 I120=100.000000 #1 J=12000.00"]);
        let by = DriverCommand::Move {
            position: -2.5,
            relative: true,
            min_velocity: 0.0,
            max_velocity: 0.0,
            acceleration: 20_000.0,
        };
        assert_eq!(lines(&p.command(3, &by).unwrap()), ["#3 J^-2.50"]);
        let jog = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -500.0, acceleration: 5000.0 };
        assert_eq!(lines(&p.command(2, &jog).unwrap()), ["I222=0.500000 I220=100.000000 #2 J-"]);
        let home = DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 1.0, acceleration: 1.0 };
        assert_eq!(lines(&p.command(2, &home).unwrap()), ["#2 HOME"]);
        let far = DriverCommand::Move {
            position: 1e15,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 1.0,
            acceleration: 1.0,
        };
        assert!(matches!(p.command(1, &far), Err(CommandError::OutOfRange { .. })), "refused, not clamped");
        let nan = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: f64::NAN, acceleration: 1.0 };
        assert!(p.command(1, &nan).is_err());
    }

    #[test]
    fn a_stop_or_a_redefinition_closes_no_loop_the_controller_has_opened() {
        let mut p = pmac();
        let stop = DriverCommand::Stop { acceleration: 1.0 };
        assert!(p.command(1, &stop).unwrap().is_empty(), "amplifier off (nothing polled yet)");
        let set = DriverCommand::SetPosition { position: 1000.4 };
        assert_eq!(lines(&p.command(1, &set).unwrap()), ["#1K M161=1000*32*I108 M162=1000*32*I108"]);
        enabled(&mut p, 1);
        assert_eq!(lines(&p.command(1, &stop).unwrap()), ["#1 J/"]);
        assert_eq!(lines(&p.command(1, &set).unwrap()), ["#1K M161=1000*32*I108 M162=1000*32*I108", "#1J/"]);
        assert_eq!(lines(&p.command(1, &DriverCommand::Enable { on: false }).unwrap()), ["#1 K"]);
    }

    #[test]
    fn a_poll_reads_ten_motors_a_line_and_maps_their_status_words() {
        let mut p = pmac();
        let channels: Vec<usize> = (1..=12).collect();
        let poll = p.poll(&channels);
        let sent = lines(&poll);
        assert_eq!(sent.len(), 2);
        assert!(sent[0].starts_with("#1P #1F i124 #1? #2P") && sent[0].ends_with("#10P #10F i1024 #10?"));
        assert_eq!(sent[1], "#11P #11F i1124 #11? #12P #12F i1224 #12?");
        // Motor 11 moving up on the + limit, motor 12 homed, in position, limits disabled.
        let events =
            p.reply(&poll[1], b"100.5\r-0.5\r$800001\rA80000000000\r-3\r0\r$820001\r880000008401\r\x06").unwrap();
        let [ReplyEvent::Status { channel: 11, status: moving }, ReplyEvent::Status { channel: 12, status: homed }] =
            &events[..]
        else {
            panic!("{events:?}")
        };
        assert_eq!((moving.position, moving.encoder_position), (100.0, 100.5), "P + F and P");
        let common = msta::PRESENT | msta::GAIN_SUPPORT | msta::POSITION;
        assert_eq!(moving.msta, common | msta::MOVING | msta::DIRECTION | msta::PLUS_LS);
        assert_eq!(homed.msta, common | msta::DONE | msta::HOMED | msta::PROBLEM);
        assert!(p.reply(&poll[1], b"1\r2\r\x06").is_err(), "not a value per key");
    }

    #[test]
    fn a_new_fault_is_reported_once_with_its_meaning() {
        let mut p = pmac();
        let poll = p.poll(&[4]);
        let faulted = b"0\r0\r$800001\r800000000004\r\x06";
        let events = p.reply(&poll[0], faulted).unwrap();
        let [ReplyEvent::Status { status, .. }, ReplyEvent::ControllerError(error)] = &events[..] else {
            panic!("{events:?}")
        };
        assert_eq!(
            status.msta & (msta::SLIP_STALL | msta::PROBLEM | msta::DONE),
            msta::SLIP_STALL | msta::PROBLEM | msta::DONE
        );
        assert_eq!((error.channel, error.code.as_str()), (Some(4), "#4? fatal following error"));
        assert_eq!(p.reply(&poll[0], faulted).unwrap().len(), 1, "reported once");
    }

    #[test]
    fn replies_end_at_ack_or_after_an_error_and_errors_name_their_meaning() {
        let p = pmac();
        assert_eq!(p.frame(b"1.947\r\x06"), Frame::Complete(7));
        assert_eq!(p.frame(b"\x06\x06"), Frame::Complete(1));
        assert_eq!(p.frame(b"12\r\x07ERR0"), Frame::Incomplete);
        assert_eq!(p.frame(b"12\r\x07ERR003\r"), Frame::Complete(11));
        assert_eq!(p.frame(b"\x00\x06"), Frame::Junk(1));
        let mut p = pmac();
        let request = p.command(1, &DriverCommand::Raw { text: "#1 FOO".into() }).unwrap().remove(0);
        let events = p.reply(&request, b"\x07ERR003\r").unwrap();
        let [ReplyEvent::ControllerError(VendorError { channel: Some(1), code, meaning })] = &events[..] else {
            panic!("{events:?}")
        };
        assert_eq!((code.as_str(), meaning.as_str()), ("ERR003", "data error or unrecognized command (to #1 FOO)"));
        assert!(p.reply(&request, b"\x07ERR\r").is_err());
    }

    #[test]
    fn initialisation_reads_the_card_and_each_motors_limits_and_writes_nothing() {
        let mut p = pmac();
        let init = p.init(&[1, 2]);
        assert_eq!(lines(&init), ["cid", "cpu", "I113 I114 I130 I131 I133", "I213 I214 I230 I231 I233"]);
        assert_eq!(p.reply(&init[0], b"603382\r\x06").unwrap(), []);
        let found = p.reply(&init[1], b"DSP56321\r\x06").unwrap();
        assert_eq!(
            found,
            [ReplyEvent::Found(Finding::Identity("Geo Brick (3U Turbo PMAC2), cid 603382, CPU DSP56321".into()))]
        );
        let travel = p.reply(&init[2], b"50000\r-50000\r2000\r1000\r0\r\x06").unwrap();
        assert_eq!(travel, [ReplyEvent::Found(Finding::Travel { channel: 1, min: -50000.0, max: 50000.0 })]);
        assert_eq!(p.reply(&init[3], b"0\r0\r2000\r1000\r0\r\x06").unwrap(), [], "no software limits");
    }
}
