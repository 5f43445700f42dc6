//! Galil DMC-40x0, DMC-41x3 and DMC-30010 over Ethernet (TCP port 23) or a serial line: ASCII
//! commands ended by `\r`, answered by `:` (done), `data\r\n:` (a query) or a bare `?` (refused;
//! `TC1` then says why: `22 Begin not possible due to Limit Switch`). Status comes from the
//! binary data record `QR`, every axis in one exchange. The reference driver is motorapp/Galil
//! (GalilController.cpp, GalilAxis.cpp), whose bytes the golden transcripts hold; where it homes
//! through a program it downloads to the controller, zmotor uses the controller's own commands.
//!
//! # Channels and units
//! Channel = the axis, 0 to 7 for A to H. Positions are counts, one record step being
//! `units_per_step` counts (default 1). Speeds (`SP`, `JG`) are counts/s, rounded to the
//! controller's resolution of 2; accelerations (`AC`, `DC`) counts/s², rounded to its resolution
//! of 1024 (at least 1024). A value beyond what the controller takes (a target beyond 32 bits, an
//! acceleration beyond 1,073,740,800, a speed beyond 22,000,000) is refused, never clamped.
//!
//! # Record commands (axis A), one exchange each
//! - move: `ACA=<a>`, `DCA=<a>`, `SPA=<v>`, `PAA=<n>` (relative `PRA=<n>`), `BGA`;
//! - jog: `ACA=<a>`, `DCA=<a>`, `JGA=<±v>`, `BGA`;
//! - home: `ACA=<a>`, `DCA=<a>`, `SPA=<v>`, `HMA`, `BGA`: the controller's homing (to the home
//!   switch's transition, then the index, where the position becomes 0; stop code 10);
//! - stop `STA`; set position `DPA=<n>`; enable `SHA` / `MOA`; raw text as one line;
//! - soft limits, gains, encoder ratio, status refresh: nothing is sent (the controller keeps
//!   its `FL`/`BL`, which a motion stops at).
//!
//! A `?` is followed by `TC1`, whose code and text reach the axis's ERR; a refused command's
//! rest is not sent (a `BG` after a refused `SP`, `AC` or `PA` would start a motion at the former
//! speed or to the former target; motorapp's driver sends it regardless).
//!
//! # Polls and status
//! Initialisation reads the firmware (Ctrl-R Ctrl-V), the record's layout (`QZ`: axes, general,
//! coordinated and axis block sizes) and each axis's motor type (`MTA=?`). At a node run's first
//! connection only (not under `observe`, not after a reconnection) the servos are switched on,
//! `SHAB`, as PI's servos and the ESP300's motors are: a DMC powers up with its motors off unless
//! its own program switches them on. Nothing else is written; a motor switched off since stays
//! off.
//! A poll is one `QR`: a 4-byte header (byte 0 with bit 7 set, byte 2–3 the length,
//! little-endian), then the general and coordinated blocks, then one block per axis:
//!
//! | axis block | MSTA |
//! |---|---|
//! | +0 status bit 15, move in progress | MOVING, else DONE |
//! | +0 status bit 0, motor off | not POSITION |
//! | +2 switches bit 3 / bit 2, forward / reverse limit (0 = active) | PLUS_LS / MINUS_LS |
//! | +2 switches bit 1, home input | HOME |
//! | +3 stop code 10 (homing ended) after zmotor's `HM` | HOMED, until the connection closes |
//! | +3 stop code 8 / 15 (off on error / amplifier fault) | PROBLEM (8 also SLIP_STALL) |
//!
//! The position is the main encoder `TP` (+8) on a servo, the step count `TD` (+16) on a
//! stepper (`MT` ±2, ±2.5), and the encoder `TP` on both.

use crate::protocol::{
    whole_steps, CommandError, Finding, Frame, Protocol, ProtocolOptions, Purpose, ReplyError, ReplyEvent, Request,
    UnitIdentities, VendorError,
};
use crate::scale::{ControllerUnit, Scale, ScaleSource};
use zmotor_core::DeviceStatus;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

/// The protocol's name in launch files.
pub(crate) const NAME: &str = "galil";

/// The controller's acceleration resolution, counts/s².
const ACCELERATION_STEP: f64 = 1024.0;
/// The largest acceleration a DMC-40x0, 41x3 or 30010 takes, counts/s².
const MAX_ACCELERATION: f64 = 1_073_740_800.0;
/// The largest speed, counts/s (a servo's; a stepper's is lower, and the controller says so).
const MAX_SPEED: f64 = 22_000_000.0;
/// The record layout a DMC-40x0 reports unless `QZ` says otherwise: general and coordinated
/// block sizes, axis block size.
const DEFAULT_LAYOUT: Layout = Layout { general: 52, coordinated: 26, axis: 36 };
/// Stop codes.
const STOPPED_BY_HOMING: u8 = 10;
const OFF_ON_ERROR: u8 = 8;
const AMPLIFIER_FAULT: u8 = 15;

/// The data record's block sizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Layout {
    general: usize,
    coordinated: usize,
    axis: usize,
}

/// A request of the Galil.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Step {
    /// Ctrl-R Ctrl-V.
    Firmware,
    /// `QZ`.
    Layout,
    /// `MTA=?`.
    MotorType {
        /// The axis.
        channel: usize,
    },
    /// `QR`.
    Record,
    /// A command of an axis.
    Command {
        /// The axis.
        channel: usize,
        /// It starts a home search.
        home: bool,
    },
    /// The servos switched on, at a node run's first connection.
    ServosOn,
    /// `TC1` after a `?`.
    WhyRefused {
        /// The axis commanded, if a command was refused.
        channel: Option<usize>,
        /// A command was refused: the rest of it is not sent.
        halts: bool,
    },
}

/// What the protocol knows of an axis.
#[derive(Clone, Copy, Debug, Default)]
struct Axis {
    stepper: bool,
    /// A home search was commanded and has not ended.
    homing: bool,
    homed: bool,
    position: f64,
}

/// The Galil protocol.
#[derive(Debug)]
pub(crate) struct Galil {
    units_per_step: f64,
    source: ScaleSource,
    layout: Layout,
    axes: [Axis; 8],
    servos_switched_on: bool,
    /// The firmware as the initialisation read it (`sync`).
    identity: UnitIdentities,
}

impl Galil {
    /// A protocol with `options.units_per_step` counts a record step (1 by default).
    pub(crate) fn new(options: &ProtocolOptions) -> Self {
        let (units_per_step, source) = match options.units_per_step {
            Some(units) => (units, ScaleSource::Installation),
            None => (1.0, ScaleSource::ProtocolDefault),
        };
        Self {
            units_per_step,
            source,
            layout: DEFAULT_LAYOUT,
            axes: [Axis::default(); 8],
            servos_switched_on: false,
            identity: UnitIdentities::default(),
        }
    }

    fn counts(&self, what: &'static str, steps: f64) -> Result<i32, CommandError> {
        whole_steps(what, steps * self.units_per_step)
    }

    /// `value` counts/s or counts/s² at the controller's `resolution`, at most `max`.
    fn rate(&self, what: &'static str, value: f64, resolution: f64, max: f64) -> Result<i64, CommandError> {
        let rate = (value.abs() * self.units_per_step / resolution).round().max(1.0) * resolution;
        if rate.is_finite() && rate <= max {
            Ok(rate as i64)
        } else {
            Err(CommandError::OutOfRange { what, value })
        }
    }

    fn commands(&self, channel: usize, command: &DriverCommand) -> Result<Vec<String>, CommandError> {
        let a =
            letter(channel).ok_or(CommandError::OutOfRange { what: "channel (axis A to H)", value: channel as f64 })?;
        let ramps = |acceleration: f64| -> Result<Vec<String>, CommandError> {
            let rate = self.rate("acceleration", acceleration, ACCELERATION_STEP, MAX_ACCELERATION)?;
            Ok(vec![format!("AC{a}={rate}"), format!("DC{a}={rate}")])
        };
        let speed = |velocity: f64| self.rate("speed", velocity, 2.0, MAX_SPEED);
        Ok(match command {
            DriverCommand::Move { position, relative, max_velocity, acceleration, .. } => {
                let target = self.counts("target", *position)?;
                let mut lines = ramps(*acceleration)?;
                lines.push(format!("SP{a}={}", speed(*max_velocity)?));
                lines.push(format!("{}{a}={target}", if *relative { "PR" } else { "PA" }));
                lines.push(format!("BG{a}"));
                lines
            }
            DriverCommand::MoveVelocity { max_velocity, acceleration, .. } => {
                let mut lines = ramps(*acceleration)?;
                let sign = if *max_velocity < 0.0 { "-" } else { "" };
                lines.push(format!("JG{a}={sign}{}", speed(*max_velocity)?));
                lines.push(format!("BG{a}"));
                lines
            }
            DriverCommand::Home { max_velocity, acceleration, .. } => {
                let mut lines = ramps(*acceleration)?;
                lines.push(format!("SP{a}={}", speed(*max_velocity)?));
                lines.extend([format!("HM{a}"), format!("BG{a}")]);
                lines
            }
            DriverCommand::Stop { .. } => vec![format!("ST{a}")],
            DriverCommand::SetPosition { position } => vec![format!("DP{a}={}", self.counts("position", *position)?)],
            DriverCommand::Enable { on } => vec![format!("{}{a}", if *on { "SH" } else { "MO" })],
            DriverCommand::Raw { text } => vec![text.clone()],
            DriverCommand::SetEncoderRatio { .. }
            | DriverCommand::SetHighLimit { .. }
            | DriverCommand::SetLowLimit { .. }
            | DriverCommand::SetGain { .. }
            | DriverCommand::Poll => Vec::new(),
        })
    }

    /// Each axis's status from a data record.
    fn statuses(&mut self, record: &[u8]) -> Result<Vec<ReplyEvent<Step>>, &'static str> {
        let length = usize::from(u16::from_le_bytes([record[2], record[3]]));
        if record.len() != length {
            return Err("a record whose length is not its header's");
        }
        let present = record[1];
        let base = 4 + self.layout.general + self.layout.coordinated;
        let mut events = Vec::new();
        for channel in (0..8).filter(|c| present & (1 << c) != 0) {
            // Blocks follow each other for the axes present, A first.
            let before = (u16::from(present) & ((1 << channel) - 1)).count_ones() as usize;
            let at = base + self.layout.axis * before;
            let block = record
                .get(at..at + self.layout.axis)
                .filter(|b| b.len() >= 20)
                .ok_or("an axis block beyond the record")?;
            let long = |offset: usize| {
                f64::from(i32::from_le_bytes([block[offset], block[offset + 1], block[offset + 2], block[offset + 3]]))
            };
            let status_word = u16::from_le_bytes([block[0], block[1]]);
            let (switches, stop_code) = (block[2], block[3]);
            let axis = &mut self.axes[channel];
            let moving = status_word & 0x8000 != 0;
            let encoder = long(8) / self.units_per_step;
            let position = if axis.stepper { long(16) } else { long(8) } / self.units_per_step;
            if axis.homing && !moving {
                axis.homing = false;
                axis.homed = stop_code == STOPPED_BY_HOMING;
            }
            let mut bits = 0;
            let mut set = |on: bool, bit: u32| bits |= if on { bit } else { 0 };
            set(!moving, msta::DONE);
            set(moving, msta::MOVING);
            set(moving && position > axis.position, msta::DIRECTION);
            set(switches & 0x08 == 0, msta::PLUS_LS);
            set(switches & 0x04 == 0, msta::MINUS_LS);
            set(switches & 0x02 != 0, msta::HOME);
            set(status_word & 0x0001 == 0, msta::POSITION);
            set(axis.homed, msta::HOMED);
            set(!moving && matches!(stop_code, OFF_ON_ERROR | AMPLIFIER_FAULT), msta::PROBLEM);
            set(!moving && stop_code == OFF_ON_ERROR, msta::SLIP_STALL);
            set(true, msta::PRESENT | msta::GAIN_SUPPORT);
            axis.position = position;
            let status = DeviceStatus { position, encoder_position: encoder, msta: bits, ..Default::default() };
            events.push(ReplyEvent::Status { channel, status });
        }
        Ok(events)
    }
}

/// The axis letter of a channel.
fn letter(channel: usize) -> Option<char> {
    (channel < 8).then(|| char::from(b'A' + channel as u8))
}

fn line(text: &str) -> Vec<u8> {
    format!("{text}\r").into_bytes()
}

/// A query's data: the text before `\r\n:`.
fn data(frame: &[u8]) -> Option<&str> {
    let text = std::str::from_utf8(frame.strip_suffix(b":")?).ok()?;
    Some(text.trim())
}

impl Protocol for Galil {
    type Step = Step;

    fn name(&self) -> &'static str {
        NAME
    }

    fn purpose(step: Step) -> Purpose {
        match step {
            Step::Firmware | Step::Layout | Step::MotorType { .. } => Purpose::Init,
            Step::ServosOn => Purpose::Setup,
            Step::Record => Purpose::PollMany,
            Step::Command { channel, .. } => Purpose::Command { channel },
            Step::WhyRefused { channel, .. } => {
                channel.map_or(Purpose::PollMany, |channel| Purpose::Command { channel })
            }
        }
    }

    fn frame(&self, buffer: &[u8]) -> Frame {
        match buffer.first() {
            None => Frame::Incomplete,
            // A data record: its header gives its length; a `:` follows it.
            Some(first) if first & 0x80 != 0 => {
                let Some(&[low, high]) = buffer.get(2..4) else { return Frame::Incomplete };
                let length = usize::from(u16::from_le_bytes([low, high]));
                if length < 4 {
                    return Frame::Junk(1);
                }
                match buffer.get(length) {
                    None => Frame::Incomplete,
                    Some(b':') => Frame::Complete(length + 1),
                    Some(_) => Frame::Junk(1),
                }
            }
            // A line end left by a former reply is not one.
            Some(b'\r' | b'\n') => Frame::Junk(1),
            Some(_) => match buffer.iter().position(|b| *b == b':' || *b == b'?') {
                Some(at) => Frame::Complete(at + 1),
                None => Frame::Incomplete,
            },
        }
    }

    fn init(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        // Read afresh: the controller may have been changed or upgraded.
        self.identity.clear();
        for axis in &mut self.axes {
            // A new connection may be a controller that was power-cycled.
            axis.homed = false;
            axis.homing = false;
        }
        let mut requests =
            vec![Request::query(b"\x12\x16\r".to_vec(), Step::Firmware), Request::query(line("QZ"), Step::Layout)];
        for &channel in channels {
            if let Some(a) = letter(channel) {
                requests.push(Request::query(line(&format!("MT{a}=?")), Step::MotorType { channel }));
            }
        }
        let letters: String = channels.iter().filter_map(|c| letter(*c)).collect();
        if !self.servos_switched_on && !letters.is_empty() {
            requests.push(Request::query(line(&format!("SH{letters}")), Step::ServosOn));
        }
        requests
    }

    fn sync(&mut self) -> Option<Request<Step>> {
        self.identity.next()?;
        Some(Request::query(b"\x12\x16\r".to_vec(), Step::Firmware))
    }

    /// The firmware, "DMC4040 Rev 1.2", as read at connection: no other reply names it.
    fn is_sync_reply(&self, frame: &[u8]) -> bool {
        data(frame).is_some_and(|d| self.identity.is_answer(d))
    }

    fn poll(&mut self, _channels: &[usize]) -> Vec<Request<Step>> {
        vec![Request::query(line("QR"), Step::Record)]
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        let home = matches!(command, DriverCommand::Home { .. });
        let lines = self.commands(channel, command)?;
        Ok(lines
            .iter()
            .map(|text| Request::query(line(text), Step::Command { channel, home: home && text.starts_with("BG") }))
            .collect())
    }

    fn scale(&self, _channel: usize) -> Scale {
        // Counts: what one is in EGU is the lab's encoder.
        Scale { units_per_step: self.units_per_step, unit: ControllerUnit::Steps, source: self.source }
    }

    fn reply(&mut self, request: &Request<Step>, frame: &[u8]) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let error = |why| ReplyError::new(request, frame, why);
        if frame == b"?" {
            let channel = match request.step {
                Step::Command { channel, .. } | Step::MotorType { channel } => Some(channel),
                _ => None,
            };
            let halts = matches!(request.step, Step::Command { .. });
            return match request.step {
                // The reason of a refusal that cannot be told: said as it is.
                Step::WhyRefused { .. } => Err(error("TC1 refused")),
                _ => Ok(vec![ReplyEvent::FollowUp(vec![Request::query(
                    line("TC1"),
                    Step::WhyRefused { channel, halts },
                )])]),
            };
        }
        match request.step {
            Step::Firmware => {
                let firmware =
                    data(frame).filter(|d| d.starts_with("DMC")).ok_or_else(|| error("not a Galil's firmware"))?;
                self.identity.read(0, firmware);
                Ok(vec![ReplyEvent::Found(Finding::Identity(firmware.to_string()))])
            }
            Step::Layout => {
                let sizes: Vec<usize> = data(frame)
                    .map(|d| d.split(',').filter_map(|n| n.trim().parse().ok()).collect())
                    .unwrap_or_default();
                let [_, general, coordinated, axis] = sizes[..] else { return Err(error("not four block sizes")) };
                self.layout = Layout { general, coordinated, axis };
                Ok(Vec::new())
            }
            Step::MotorType { channel } => {
                let kind: f64 = data(frame).and_then(|d| d.parse().ok()).ok_or_else(|| error("not a motor type"))?;
                self.axes[channel].stepper = kind.abs() >= 2.0;
                Ok(Vec::new())
            }
            Step::Record => {
                let record =
                    frame.strip_suffix(b":").filter(|r| r.len() >= 4).ok_or_else(|| error("not a data record"))?;
                self.statuses(record).map_err(error)
            }
            Step::ServosOn => {
                if frame != b":" {
                    return Err(error("neither : nor ?"));
                }
                self.servos_switched_on = true;
                Ok(Vec::new())
            }
            Step::Command { channel, home } => {
                if frame != b":" {
                    return Err(error("neither : nor ?"));
                }
                if home {
                    self.axes[channel].homing = true;
                }
                Ok(Vec::new())
            }
            Step::WhyRefused { channel, halts } => {
                let text = data(frame).ok_or_else(|| error("not an error"))?;
                let (code, meaning) = text.split_once(' ').unwrap_or((text, ""));
                let error = VendorError { channel, code: code.to_string(), meaning: meaning.trim().to_string() };
                Ok(vec![if halts { ReplyEvent::Refused(error) } else { ReplyEvent::ControllerError(error) }])
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sent(requests: &[Request<Step>]) -> Vec<String> {
        requests.iter().map(|r| String::from_utf8_lossy(&r.bytes).into_owned()).collect()
    }

    /// A data record of a DMC-4040's layout with axes A and B present: B moving up at 2500
    /// counts, on its forward limit; A at rest, motor off, stopped by homing.
    fn record() -> Vec<u8> {
        let length = 4 + 52 + 26 + 2 * 36;
        let mut bytes = vec![0u8; length];
        bytes[..4].copy_from_slice(&[0x87, 0b11, length as u8, (length >> 8) as u8]);
        let a = 82;
        bytes[a..a + 2].copy_from_slice(&0x0001u16.to_le_bytes());
        bytes[a + 2] = 0x0C | 0x02;
        bytes[a + 3] = STOPPED_BY_HOMING;
        let b = 82 + 36;
        bytes[b..b + 2].copy_from_slice(&0x8000u16.to_le_bytes());
        bytes[b + 2] = 0x04;
        bytes[b + 8..b + 12].copy_from_slice(&2500i32.to_le_bytes());
        bytes.push(b':');
        bytes
    }

    #[test]
    fn a_data_record_is_framed_by_its_length_and_text_by_its_terminator() {
        let p = Galil::new(&ProtocolOptions::default());
        let record = record();
        assert_eq!(p.frame(&record[..100]), Frame::Incomplete);
        assert_eq!(p.frame(&record), Frame::Complete(record.len()));
        assert_eq!(p.frame(b": 1000\r\n:"), Frame::Complete(1));
        assert_eq!(p.frame(b" 1000.0000\r\n:"), Frame::Complete(13));
        assert_eq!(p.frame(b"?"), Frame::Complete(1));
        assert_eq!(p.frame(b"\r\n:"), Frame::Junk(1));
    }

    #[test]
    fn a_record_gives_every_axis_its_status() {
        let mut p = Galil::new(&ProtocolOptions::default());
        let poll = p.poll(&[0, 1]);
        assert_eq!(sent(&poll), ["QR\r"]);
        p.axes[0].homing = true;
        let events = p.reply(&poll[0], &record()).unwrap();
        let [ReplyEvent::Status { channel: 0, status: a }, ReplyEvent::Status { channel: 1, status: b }] = &events[..]
        else {
            panic!("{events:?}")
        };
        assert_eq!(a.msta, msta::DONE | msta::HOME | msta::HOMED | msta::PRESENT | msta::GAIN_SUPPORT);
        let up = msta::MOVING | msta::DIRECTION | msta::PLUS_LS | msta::POSITION | msta::PRESENT | msta::GAIN_SUPPORT;
        assert_eq!((b.position, b.msta), (2500.0, up));
        let mut short = record();
        short.remove(10);
        assert!(p.reply(&poll[0], &short).is_err(), "a length that is not the header's");
    }

    #[test]
    fn commands_go_one_an_exchange_and_a_refusal_asks_why() {
        let mut p = Galil::new(&ProtocolOptions::default());
        let jog = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -2001.0, acceleration: 9000.0 };
        assert_eq!(sent(&p.command(2, &jog).unwrap()), ["ACC=9216\r", "DCC=9216\r", "JGC=-2002\r", "BGC\r"]);
        let far = DriverCommand::Move {
            position: 3e9,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 1.0,
            acceleration: 1.0,
        };
        assert!(matches!(p.command(0, &far), Err(CommandError::OutOfRange { .. })), "refused, not clamped");
        let hard = DriverCommand::Move {
            position: 1.0,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 1.0,
            acceleration: 2e9,
        };
        assert!(p.command(0, &hard).is_err());
        let begin = p.command(2, &jog).unwrap().pop().unwrap();
        let events = p.reply(&begin, b"?").unwrap();
        let [ReplyEvent::FollowUp(why)] = &events[..] else { panic!("{events:?}") };
        assert_eq!(sent(why), ["TC1\r"]);
        let events = p.reply(&why[0], b"20 Begin not valid with motor off\r\n:").unwrap();
        // A command refused: the rest of it (a BG after a refused speed) is not sent.
        let [ReplyEvent::Refused(VendorError { channel: Some(2), code, meaning })] = &events[..] else {
            panic!("{events:?}")
        };
        assert_eq!((code.as_str(), meaning.as_str()), ("20", "Begin not valid with motor off"));
        let speed = p.command(2, &jog).unwrap().remove(2);
        let [ReplyEvent::FollowUp(why)] = &p.reply(&speed, b"?").unwrap()[..] else { panic!("a TC1 follows") };
        let events = p.reply(&why[0], b"6 Number out of range\r\n:").unwrap();
        assert!(matches!(&events[..], [ReplyEvent::Refused(_)]), "JG refused, BG not sent: {events:?}");
        // A motor type refused at connection is only said.
        let kind = p.init(&[0]).into_iter().find(|r| r.bytes.starts_with(b"MT")).unwrap();
        let [ReplyEvent::FollowUp(why)] = &p.reply(&kind, b"?").unwrap()[..] else { panic!("a TC1 follows") };
        let events = p.reply(&why[0], b"1 Unrecognized command\r\n:").unwrap();
        assert!(matches!(&events[..], [ReplyEvent::ControllerError(_)]), "{events:?}");
    }
}
