//! Phytron phyMOTION (MCM01 main module with I1AM/I1EM axis modules): the "minilog" ASCII
//! protocol over TCP (port 22222 in Phytron's examples) or a serial line (115200 8N1), as the
//! EPICS driver motorPhytron (phytronAxisMotor.cpp) speaks it.
//!
//! # Wire format
//! A request is one frame: `STX '0' <payload> ':' <XOR> ETX`. `'0'` is the controller's
//! address (a phyMOTION is always 0); `<XOR>` is the XOR of every byte from the address up to
//! and including the `:`, as two uppercase hex digits (`\x02` `0SE1.1:32` `\x03`). The payload
//! is one command or several separated by single spaces, at most 42 of them and 994 bytes. The
//! reply is one frame `STX <sub-replies> ':' <XOR> ETX` with no address: one sub-reply per
//! command, each an ACK (0x06) or NAK (0x15) followed by its data (`\x02\x06\x061234:3E\x03`
//! answers `M1.1A1000 M1.1P20R`). The reply's XOR covers the bytes from the first ACK/NAK up to
//! and including the `:`; a checksum of `XX` means none, and a reply without one is taken as
//! the EPICS driver takes it. A wrong checksum, a reply whose count of sub-replies is not the
//! count of commands, or data that does not parse is a `ReplyError`; a NAK is the controller
//! refusing a command (`ReplyEvent::ControllerError`, code `NAK`). Replies name no axis: they are
//! checked against the commands asked, one by one.
//!
//! # Channels and units
//! Channel = module × 10 + axis: channel 11 is `M1.1`, channel 23 is `M2.3` (the `ADDR` of the
//! EPICS substitutions). A channel whose module or axis digit is 0 names no axis (its commands
//! are refused with `CommandError::OutOfRange`). Positions are in the controller's units of P02,
//! which the EPICS driver takes as steps: one record step is `ProtocolOptions::units_per_step`
//! controller units, by default 1 ([`DEFAULT_UNITS_PER_STEP`]). Targets are whole record steps
//! (a value beyond 32 bits is refused, never clamped), sent as integers when the factor is 1 (as
//! the driver's `NINT`) and as decimals otherwise. Velocities and accelerations are frequencies
//! (Hz, steps/s and steps/s²) whatever P02 says: they are not scaled. As the EPICS driver does,
//! they are clamped to what the controller takes (velocities 1–500000 Hz by absolute value,
//! ramps 4000–500000 Hz/s); a value that is not a number is refused.
//!
//! # Record commands (channel 11)
//! Each command is one frame, its parts batched as the driver's parallel poll modes batch them:
//! - move: `M1.1P14=<velocity> M1.1P04=<base velocity> M1.1P15=<acceleration> M1.1MA M1.1A<n>`
//!   (relative: `M1.1+<n>` / `M1.1-<n>`, a zero distance `-0` as the driver sends it);
//! - jog: the same parameters, then `M1.1L+` or `M1.1L-` (the controller runs at P14 until
//!   stopped or a limit switch);
//! - home: `M1.1P08=<velocity> M1.1P10=<base velocity> M1.1P09=<acceleration> M1.1MA` then the
//!   reference run to the center (home) switch, `M1.1R+C` forward or `M1.1R-C` reverse (the
//!   driver's homing procedure "Center"); the controller then moves by its P11/P12 offset and
//!   sets the axis initialised;
//! - stop: `M1.1P15=<deceleration> M1.1S`;
//! - set position: `M1.1P20=<position>` (six decimals, as the driver's `std::to_string`);
//! - enable: `M1.1MA` (power stage on) / `M1.1MD` (off). `MA` goes with every motion as the
//!   driver's first move sends it, unless the record switched the drive off: then a motion is
//!   sent without it and the controller refuses it (its power stage is off);
//! - encoder ratio (encoder counts per step): `M1.1P39=<1/ratio>`, the controller's encoder
//!   conversion factor, and the encoder counter P22 read back is multiplied by the ratio;
//! - raw text: sent as the payload of one frame (spaces separate its commands), every reply
//!   checked for NAK;
//! - soft limits, gains, status refresh: nothing is sent (the EPICS driver leaves P23/P24 to the
//!   motor record; a stepper has no gains; a refresh is a poll).
//!
//! After a status reported the limit-switch error (SE bit 12, left by a run into a limit
//! switch), the next motion of that axis clears it first with `SEC1.1` in the same frame, as the
//! driver's `clearAxisStatus` option does.
//!
//! # Polls and status
//! Initialisation reads every axis's encoder type, `M1.1P34R M1.2P34R …` (0: none); nothing
//! moves, nothing is reset or powered (the driver's `CR` at boot is left out). A poll is the
//! driver's "controller-parallel" method: one frame for every axis,
//! `SE1.1 M1.1P20R M1.1P22R SE1.2 M1.2P20R M1.2P22R …` (14 axes a frame at most), answered by
//! the extended status word, the position counter P20 and the encoder counter P22 of each;
//! one `ReplyEvent::Status` per channel. The status word maps to MSTA as follows:
//!
//! | SE bit | meaning | MSTA |
//! |---|---|---|
//! | 0 | axis busy | MOVING, not DONE |
//! | 3 | axis initialised (reference run done) | HOMED |
//! | 4 / 5 | limit switch + / − | PLUS_LS / MINUS_LS |
//! | 6 | center (home) switch | HOME |
//! | 9 | power stage ready | POSITION (drive power) |
//! | 11, 13, 14, 15 | internal, power-stage, SFI, EnDat error | PROBLEM (14 also SLIP_STALL) |
//!
//! An error bit that was not set at the previous poll is also reported as a controller error
//! with its meaning (code `SE 0x2000` for a power-stage error, ...). PRESENT follows the encoder
//! type read at initialisation; DIRECTION follows the position counter between polls while the
//! axis is busy; velocity is not read (0). The EPICS driver puts bit 3 in RA_HOME and bit 6 in
//! its "at home" parameter; here RA_HOME is the switch itself (bit 6) and bit 3 is HOMED.
//!
//! # Left out
//! The MCC-1/MCC-2 variant (no checksum, address switch, `S` setter, `SUI` limits); homing
//! procedures other than "Center" (to a limit switch, to the encoder index, reference-center);
//! the controller reset `CR` and axis reset `C`; brake outputs; fake-homed registers R1001…;
//! the driver's parameter records (currents, step resolution, boost, limit-switch type, ...);
//! the I/O modules; velocity readback.

use crate::protocol::{
    state_of, whole_steps, CommandError, Frame, Protocol, ProtocolOptions, Purpose, ReplyError, ReplyEvent, Request,
    VendorError,
};
use crate::scale::{ControllerUnit, Scale, ScaleSource};
use std::collections::HashMap;
use std::ops::RangeInclusive;
use zmotor_core::DeviceStatus;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

/// The protocol's name in launch files.
pub(crate) const NAME: &str = "phytron";

/// Start of a frame.
pub(crate) const STX: u8 = 0x02;
/// End of a frame.
pub(crate) const ETX: u8 = 0x03;
/// A sub-reply's mark: the command was carried out.
pub(crate) const ACK: u8 = 0x06;
/// A sub-reply's mark: the command was refused.
pub(crate) const NAK: u8 = 0x15;
/// The address character of a phyMOTION (always 0).
pub(crate) const ADDRESS: u8 = b'0';

/// Commands in one request frame at most, as the EPICS driver batches them.
pub(crate) const MAX_COMMANDS: usize = 42;
/// Payload bytes in one request frame at most (the controller takes 1000 bytes with framing).
pub(crate) const MAX_PAYLOAD: usize = 994;
/// Bytes of a reply frame at most (the controller sends up to 2000): a longer run without ETX
/// is noise.
pub(crate) const MAX_REPLY: usize = 2010;

/// Run and start/stop frequencies the controller takes, Hz (steps/s).
pub(crate) const FREQUENCIES: RangeInclusive<f64> = 1.0..=500_000.0;
/// Ramps the controller takes, Hz/s (steps/s²).
pub(crate) const RAMPS: RangeInclusive<f64> = 4_000.0..=500_000.0;

/// Controller units per record step unless the launch file says otherwise: P02 = steps.
pub(crate) const DEFAULT_UNITS_PER_STEP: f64 = 1.0;

/// Bits of the extended axis status word `SE<m.a>` (decimal on the wire).
pub(crate) mod status_bit {
    /// The axis is busy (running, or in its recovery time).
    pub(crate) const BUSY: u32 = 1 << 0;
    /// The axis is initialised: a reference run completed.
    pub(crate) const INITIALISED: u32 = 1 << 3;
    /// The + limit switch is active.
    pub(crate) const PLUS_LIMIT: u32 = 1 << 4;
    /// The − limit switch is active.
    pub(crate) const MINUS_LIMIT: u32 = 1 << 5;
    /// The center (reference, home) switch is active.
    pub(crate) const CENTER_SWITCH: u32 = 1 << 6;
    /// The power stage is ready (switched on, no error).
    pub(crate) const POWER_STAGE_READY: u32 = 1 << 9;
    /// Axis internal error.
    pub(crate) const INTERNAL_ERROR: u32 = 1 << 11;
    /// A limit switch was hit; cleared by `SEC<m.a>`.
    pub(crate) const LIMIT_SWITCH_ERROR: u32 = 1 << 12;
    /// Power-stage error.
    pub(crate) const POWER_STAGE_ERROR: u32 = 1 << 13;
    /// SFI error: motor and encoder positions differ by more than P37.
    pub(crate) const SFI_ERROR: u32 = 1 << 14;
    /// EnDat (absolute encoder) error.
    pub(crate) const ENDAT_ERROR: u32 = 1 << 15;
    /// The errors that make a problem (the EPICS driver's mask 0xE800).
    pub(crate) const PROBLEMS: u32 = INTERNAL_ERROR | POWER_STAGE_ERROR | SFI_ERROR | ENDAT_ERROR;
}

/// What the error bits of a status word mean, in words.
pub(crate) fn error_meaning(bits: u32) -> String {
    let names = [
        (status_bit::INTERNAL_ERROR, "axis internal error"),
        (status_bit::POWER_STAGE_ERROR, "power-stage error"),
        (status_bit::SFI_ERROR, "SFI error (motor and encoder positions differ)"),
        (status_bit::ENDAT_ERROR, "EnDat encoder error"),
    ];
    let found: Vec<&str> = names.iter().filter(|(bit, _)| bits & bit != 0).map(|(_, name)| *name).collect();
    found.join(", ")
}

/// The XOR of `bytes`, the protocol's checksum.
pub(crate) fn checksum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0, |sum, byte| sum ^ byte)
}

/// `bytes` followed by `:` and their XOR (including the `:`) in two uppercase hex digits.
fn with_checksum(mut bytes: Vec<u8>) -> Vec<u8> {
    bytes.push(b':');
    let sum = checksum(&bytes);
    bytes.extend_from_slice(format!("{sum:02X}").as_bytes());
    bytes
}

/// The request frame that carries `payload` (commands separated by spaces).
pub(crate) fn request_frame(payload: &str) -> Vec<u8> {
    let mut content = vec![ADDRESS];
    content.extend_from_slice(payload.as_bytes());
    let mut frame = vec![STX];
    frame.extend(with_checksum(content));
    frame.push(ETX);
    frame
}

/// The reply frame that carries `sub_replies` (each an ACK or NAK and its data), as the
/// controller sends it (for the tests: the emulator frames its own).
#[cfg(test)]
pub(crate) fn reply_frame(sub_replies: &[u8]) -> Vec<u8> {
    let mut frame = vec![STX];
    frame.extend(with_checksum(sub_replies.to_vec()));
    frame.push(ETX);
    frame
}

/// The content of a frame (between STX and ETX) without its checksum, which is checked. A
/// content without one is taken as it is; `XX` stands for no checksum.
pub(crate) fn without_checksum(content: &[u8]) -> Result<&[u8], &'static str> {
    let Some(colon) = content.len().checked_sub(3).filter(|at| content[*at] == b':') else {
        return Ok(content);
    };
    let (checked, sum) = (&content[..=colon], &content[colon + 1..]);
    if sum.eq_ignore_ascii_case(b"XX") {
        return Ok(&content[..colon]);
    }
    let digit = |b: u8| char::from(b).to_digit(16);
    let (Some(high), Some(low)) = (digit(sum[0]), digit(sum[1])) else {
        return Err("checksum not two hex digits");
    };
    if u32::from(checksum(checked)) != high * 16 + low {
        return Err("bad checksum");
    }
    Ok(&content[..colon])
}

/// The axis of `channel` as commands name it, without the `M`: `1.1` for channel 11. None when
/// the channel names no axis (module or axis digit 0).
pub(crate) fn axis_token(channel: usize) -> Option<String> {
    let (module, axis) = (channel / 10, channel % 10);
    (module >= 1 && axis >= 1).then(|| format!("{module}.{axis}"))
}

/// The channel an axis token at the start of `text` names, and the rest: `1.1P20R` → (11,
/// `P20R`).
pub(crate) fn split_axis(text: &str) -> Option<(usize, &str)> {
    let dot = text.find('.')?;
    let module_digits = &text[..dot];
    if module_digits.is_empty() || !module_digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let module: usize = module_digits.parse().ok().filter(|m| *m >= 1)?;
    let axis = text.as_bytes().get(dot + 1).filter(|b| (b'1'..=b'9').contains(b))?;
    let channel = module.checked_mul(10)?.checked_add(usize::from(axis - b'0'))?;
    Some((channel, &text[dot + 2..]))
}

/// The sub-replies of a reply frame: whether each was acknowledged, and its data.
pub(crate) fn sub_replies(frame: &[u8]) -> Result<Vec<(bool, &str)>, &'static str> {
    let content =
        frame.strip_prefix(&[STX]).and_then(|rest| rest.strip_suffix(&[ETX])).ok_or("not one STX … ETX frame")?;
    let body = without_checksum(content)?;
    if !matches!(body.first(), Some(&ACK | &NAK)) {
        return Err("no ACK or NAK");
    }
    let mut replies = Vec::new();
    let starts: Vec<usize> = (0..body.len()).filter(|i| matches!(body[*i], ACK | NAK)).collect();
    for (n, start) in starts.iter().enumerate() {
        let end = starts.get(n + 1).copied().unwrap_or(body.len());
        let data = &body[start + 1..end];
        if !data.iter().all(|b| b.is_ascii_graphic() || *b == b' ') {
            return Err("data that is not printable text");
        }
        let text = std::str::from_utf8(data).map_err(|_| "data that is not printable text")?;
        replies.push((body[*start] == ACK, text));
    }
    Ok(replies)
}

/// The commands a request frame of this protocol carries.
fn commands_of(request: &Request<Step>) -> Vec<String> {
    // STX and the address before, `:XX` and ETX after.
    let payload = request.bytes.get(2..request.bytes.len().saturating_sub(4)).unwrap_or_default();
    String::from_utf8_lossy(payload).split(' ').map(str::to_string).collect()
}

/// A value in the controller's units as a command writes it: an integer when it is one,
/// otherwise up to six decimals.
fn units_text(value: f64) -> String {
    let text = format!("{value:.6}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    if text == "-0" {
        "0".to_string()
    } else {
        text.to_string()
    }
}

/// A velocity as the controller takes it: its magnitude within [`FREQUENCIES`].
fn frequency(what: &'static str, velocity: f64) -> Result<f64, CommandError> {
    if velocity.is_finite() {
        Ok(velocity.abs().clamp(*FREQUENCIES.start(), *FREQUENCIES.end()))
    } else {
        Err(CommandError::OutOfRange { what, value: velocity })
    }
}

/// An acceleration as the controller takes it: within [`RAMPS`].
fn ramp(acceleration: f64) -> Result<f64, CommandError> {
    if acceleration.is_finite() {
        Ok(acceleration.clamp(*RAMPS.start(), *RAMPS.end()))
    } else {
        Err(CommandError::OutOfRange { what: "acceleration", value: acceleration })
    }
}

/// A request of the phyMOTION: one frame of commands, each answered in the reply frame. What
/// the frame asks is in its bytes; the step tells readings from commands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Step {
    /// Readings at initialisation: which axes have an encoder.
    EncoderTypes,
    /// The readings of one channel's poll.
    Poll {
        /// The channel polled.
        channel: usize,
    },
    /// The readings of a poll of several channels.
    PollMany,
    /// Commands to one channel (their replies are checked alike).
    Command {
        /// The channel commanded.
        channel: usize,
    },
}

/// A reading a poll or the initialisation asks for.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Reading {
    StatusWord,
    Position,
    Encoder,
    EncoderType,
}

/// Which reading `command` asks for, and of which channel.
fn reading_of(command: &str) -> Option<(usize, Reading)> {
    if let Some(rest) = command.strip_prefix("SE") {
        return split_axis(rest).filter(|(_, tail)| tail.is_empty()).map(|(channel, _)| (channel, Reading::StatusWord));
    }
    let (channel, tail) = split_axis(command.strip_prefix('M')?)?;
    let reading = match tail {
        "P20R" => Reading::Position,
        "P22R" => Reading::Encoder,
        "P34R" => Reading::EncoderType,
        _ => return None,
    };
    Some((channel, reading))
}

/// The readings of one channel in a poll reply.
#[derive(Debug, Default)]
struct Polled {
    word: Option<u32>,
    position: Option<f64>,
    encoder: Option<f64>,
    refused: bool,
}

/// What the protocol remembers of an axis between requests.
#[derive(Debug)]
struct Axis {
    /// The position counter at the last poll, record steps.
    last_position: Option<f64>,
    /// The counter went up between the last polls of this motion.
    moving_up: bool,
    /// The error bits of the last status word.
    errors: u32,
    /// The last status word had the limit-switch error: the next motion clears it.
    limit_switch_error: bool,
    /// The axis has an encoder (P34 ≠ 0).
    encoder_present: bool,
    /// The record switched the power stage off: motions do not switch it on.
    drive_off: bool,
    /// Encoder counts per step, as last set.
    encoder_ratio: f64,
}

impl Default for Axis {
    fn default() -> Self {
        Self {
            last_position: None,
            moving_up: false,
            errors: 0,
            limit_switch_error: false,
            encoder_present: false,
            drive_off: false,
            encoder_ratio: 1.0,
        }
    }
}

/// The phyMOTION protocol (see the module documentation).
#[derive(Debug)]
pub(crate) struct Phymotion {
    units_per_step: f64,
    /// Where `units_per_step` comes from.
    source: ScaleSource,
    axes: HashMap<usize, Axis>,
}

impl Phymotion {
    /// The protocol with the installation's options (`units_per_step` defaults to 1).
    pub(crate) fn new(options: &ProtocolOptions) -> Self {
        let (units_per_step, source) = match options.units_per_step {
            Some(units) if units.is_finite() && units > 0.0 => (units, ScaleSource::Installation),
            Some(units) => {
                tracing::warn!(units, "phytron: units_per_step must be a positive number; using 1");
                (DEFAULT_UNITS_PER_STEP, ScaleSource::ProtocolDefault)
            }
            None => (DEFAULT_UNITS_PER_STEP, ScaleSource::ProtocolDefault),
        };
        Self { units_per_step, source, axes: HashMap::new() }
    }

    fn axis(&mut self, channel: usize) -> &mut Axis {
        self.axes.entry(channel).or_default()
    }

    /// What every motion sends before its motion command: the limit-switch error cleared if
    /// the axis has one, its velocities and ramp, the power stage switched on.
    fn motion_start(
        &mut self,
        channel: usize,
        token: &str,
        [(run, run_velocity), (start, start_velocity), (ramp_parameter, acceleration)]: [(&str, f64); 3],
    ) -> Result<Vec<String>, CommandError> {
        let run_velocity = frequency("velocity", run_velocity)?;
        let start_velocity = frequency("base velocity", start_velocity)?;
        let acceleration = ramp(acceleration)?;
        let axis = self.axis(channel);
        let mut commands = Vec::new();
        if std::mem::take(&mut axis.limit_switch_error) {
            commands.push(format!("SEC{token}"));
        }
        commands.push(format!("M{token}{run}={run_velocity:.6}"));
        commands.push(format!("M{token}{start}={start_velocity:.6}"));
        commands.push(format!("M{token}{ramp_parameter}={acceleration:.6}"));
        if !axis.drive_off {
            commands.push(format!("M{token}MA"));
        }
        Ok(commands)
    }

    /// The commands that carry out `command` on the axis `token`.
    fn commands(&mut self, channel: usize, token: &str, command: &DriverCommand) -> Result<Vec<String>, CommandError> {
        let units = self.units_per_step;
        let commands = match command {
            DriverCommand::Move { position, relative, min_velocity, max_velocity, acceleration } => {
                let steps = whole_steps("target", *position)?;
                let parameters = [("P14", *max_velocity), ("P04", *min_velocity), ("P15", *acceleration)];
                let mut commands = self.motion_start(channel, token, parameters)?;
                let amount = f64::from(steps) * units;
                commands.push(match (relative, steps > 0) {
                    (false, _) => format!("M{token}A{}", units_text(amount)),
                    (true, true) => format!("M{token}+{}", units_text(amount)),
                    // As the driver: a zero distance is sent as `-0`.
                    (true, false) => format!("M{token}-{}", units_text(-amount)),
                });
                commands
            }
            DriverCommand::MoveVelocity { min_velocity, max_velocity, acceleration } => {
                let parameters = [("P14", *max_velocity), ("P04", *min_velocity), ("P15", *acceleration)];
                let mut commands = self.motion_start(channel, token, parameters)?;
                commands.push(format!("M{token}{}", if *max_velocity < 0.0 { "L-" } else { "L+" }));
                commands
            }
            DriverCommand::Home { forward, min_velocity, max_velocity, acceleration } => {
                let parameters = [("P08", *max_velocity), ("P10", *min_velocity), ("P09", *acceleration)];
                let mut commands = self.motion_start(channel, token, parameters)?;
                commands.push(format!("M{token}{}", if *forward { "R+C" } else { "R-C" }));
                commands
            }
            DriverCommand::Stop { acceleration } => {
                // A stop is never refused: a deceleration that is no number stops as hard as the
                // controller can.
                let ramp = ramp(*acceleration).unwrap_or(*RAMPS.end());
                vec![format!("M{token}P15={ramp:.6}"), format!("M{token}S")]
            }
            DriverCommand::SetPosition { position } => {
                let steps = whole_steps("position", *position)?;
                vec![format!("M{token}P20={:.6}", f64::from(steps) * units)]
            }
            DriverCommand::Enable { on } => {
                self.axis(channel).drive_off = !on;
                vec![format!("M{token}{}", if *on { "MA" } else { "MD" })]
            }
            DriverCommand::SetEncoderRatio { ratio } => {
                let factor = 1.0 / ratio;
                // Six decimals are all the controller is sent: a smaller factor would be 0.
                if !(ratio.is_finite() && *ratio > 0.0 && factor >= 5e-7) {
                    return Err(CommandError::OutOfRange { what: "encoder ratio", value: *ratio });
                }
                self.axis(channel).encoder_ratio = *ratio;
                vec![format!("M{token}P39={factor:.6}")]
            }
            DriverCommand::Raw { text } => {
                let commands: Vec<String> = text.split_whitespace().map(str::to_string).collect();
                let payload = commands.join(" ");
                if !payload.bytes().all(|b| b.is_ascii_graphic() || b == b' ') {
                    return Err(CommandError::Unsupported { protocol: NAME, what: "send control or non-ASCII bytes" });
                }
                if payload.len() > MAX_PAYLOAD {
                    return Err(CommandError::Unsupported {
                        protocol: NAME,
                        what: "send more than 994 bytes in a frame",
                    });
                }
                commands
            }
            // The driver leaves soft limits to the motor record; a stepper has no gains; a status
            // refresh is a poll.
            DriverCommand::SetHighLimit { .. }
            | DriverCommand::SetLowLimit { .. }
            | DriverCommand::SetGain { .. }
            | DriverCommand::Poll => Vec::new(),
        };
        Ok(commands)
    }

    /// A command frame's replies: the first refusal, if any, is the controller's error.
    fn acknowledgements(channel: usize, asked: &[String], replies: &[(bool, &str)]) -> Vec<ReplyEvent<Step>> {
        asked
            .iter()
            .zip(replies)
            .find(|(_, (acknowledged, _))| !acknowledged)
            .map(|(command, _)| {
                ReplyEvent::ControllerError(VendorError {
                    channel: Some(channel),
                    code: "NAK".to_string(),
                    meaning: format!("the controller refused {command}"),
                })
            })
            .into_iter()
            .collect()
    }

    /// A poll's or the initialisation's replies: the readings of every channel asked, and a
    /// status for each channel fully read.
    fn readings(&mut self, asked: &[String], replies: &[(bool, &str)]) -> Result<Vec<ReplyEvent<Step>>, &'static str> {
        let mut events = Vec::new();
        let mut polled: Vec<(usize, Polled)> = Vec::new();
        for (command, (acknowledged, data)) in asked.iter().zip(replies) {
            let (channel, reading) = reading_of(command).ok_or("a reply to a reading this protocol does not ask")?;
            let entry = state_of(&mut polled, channel);
            if !acknowledged {
                if !std::mem::replace(&mut entry.refused, true) {
                    events.push(ReplyEvent::ControllerError(VendorError {
                        channel: Some(channel),
                        code: "NAK".to_string(),
                        meaning: format!("the controller refused {command}: no such axis?"),
                    }));
                }
                continue;
            }
            let number = || data.trim().parse::<f64>().ok().filter(|x| x.is_finite());
            match reading {
                Reading::StatusWord => {
                    entry.word = Some(data.trim().parse().map_err(|_| "a status word not a number")?)
                }
                Reading::Position => entry.position = Some(number().ok_or("a position not a number")?),
                Reading::Encoder => entry.encoder = Some(number().ok_or("an encoder count not a number")?),
                Reading::EncoderType => {
                    let kind = number().ok_or("an encoder type not a number")?;
                    self.axis(channel).encoder_present = kind != 0.0;
                }
            }
        }
        for (channel, reading) in polled {
            if let (Some(word), Some(position), Some(encoder)) = (reading.word, reading.position, reading.encoder) {
                events.extend(self.status(channel, word, position, encoder));
            }
        }
        Ok(events)
    }

    /// The status of `channel` from its status word and counters (controller units): a
    /// controller error first if an error bit is new.
    fn status(&mut self, channel: usize, word: u32, position: f64, encoder: f64) -> Vec<ReplyEvent<Step>> {
        let units = self.units_per_step;
        let axis = self.axis(channel);
        let position = position / units;
        let busy = word & status_bit::BUSY != 0;
        match axis.last_position {
            Some(last) if position > last => axis.moving_up = true,
            Some(last) if position < last => axis.moving_up = false,
            _ => {}
        }
        // The direction bit tells the current motion, not the last one.
        if !busy {
            axis.moving_up = false;
        }
        axis.last_position = Some(position);
        axis.limit_switch_error = word & status_bit::LIMIT_SWITCH_ERROR != 0;
        let errors = word & status_bit::PROBLEMS;
        let new_errors = errors & !axis.errors;
        axis.errors = errors;
        let mut bits = 0;
        for (on, bit) in [
            (!busy, msta::DONE),
            (busy, msta::MOVING),
            (axis.moving_up, msta::DIRECTION),
            (word & status_bit::PLUS_LIMIT != 0, msta::PLUS_LS),
            (word & status_bit::MINUS_LIMIT != 0, msta::MINUS_LS),
            (word & status_bit::CENTER_SWITCH != 0, msta::HOME),
            (word & status_bit::INITIALISED != 0, msta::HOMED),
            (word & status_bit::POWER_STAGE_READY != 0, msta::POSITION),
            (word & status_bit::SFI_ERROR != 0, msta::SLIP_STALL),
            (errors != 0, msta::PROBLEM),
            (axis.encoder_present, msta::PRESENT),
        ] {
            if on {
                bits |= bit;
            }
        }
        let status = DeviceStatus {
            position,
            encoder_position: encoder / units * axis.encoder_ratio,
            velocity: 0.0,
            msta: bits,
            readback: None,
        };
        let mut events = Vec::new();
        if new_errors != 0 {
            events.push(ReplyEvent::ControllerError(VendorError {
                channel: Some(channel),
                code: format!("SE 0x{new_errors:04X}"),
                meaning: error_meaning(new_errors),
            }));
        }
        events.push(ReplyEvent::Status { channel, status });
        events
    }
}

/// Frames of at most [`MAX_COMMANDS`] commands, `per_axis` commands for each of `channels`
/// that names an axis, with the channels each frame reads.
fn batches(
    channels: &[usize],
    per_axis: impl Fn(&str) -> String,
    commands_per_axis: usize,
) -> Vec<(Vec<usize>, String)> {
    let axes: Vec<(usize, String)> = channels.iter().filter_map(|&c| axis_token(c).map(|t| (c, t))).collect();
    axes.chunks(MAX_COMMANDS / commands_per_axis)
        .map(|chunk| {
            let payload: Vec<String> = chunk.iter().map(|(_, token)| per_axis(token)).collect();
            (chunk.iter().map(|(c, _)| *c).collect(), payload.join(" "))
        })
        .collect()
}

impl Protocol for Phymotion {
    type Step = Step;

    fn name(&self) -> &'static str {
        NAME
    }

    fn scale(&self, _channel: usize) -> Scale {
        // In the unit the module's parameter P02 was set to, which this driver does not read.
        Scale { units_per_step: self.units_per_step, unit: ControllerUnit::Steps, source: self.source }
    }

    fn purpose(step: Step) -> Purpose {
        match step {
            Step::EncoderTypes => Purpose::Init,
            Step::Poll { channel } => Purpose::Poll { channel },
            Step::PollMany => Purpose::PollMany,
            Step::Command { channel } => Purpose::Command { channel },
        }
    }

    fn frame(&self, buffer: &[u8]) -> Frame {
        let Some(start) = buffer.iter().position(|b| *b == STX) else {
            return if buffer.is_empty() { Frame::Incomplete } else { Frame::Junk(buffer.len()) };
        };
        if start > 0 {
            return Frame::Junk(start);
        }
        match buffer[1..].iter().position(|b| *b == ETX || *b == STX) {
            Some(end) if buffer[1 + end] == ETX => Frame::Complete(end + 2),
            // A new frame starts before this one ended: what came before it is a broken frame.
            Some(next) => Frame::Junk(next + 1),
            None if buffer.len() > MAX_REPLY => Frame::Junk(buffer.len()),
            None => Frame::Incomplete,
        }
    }

    fn init(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        // Reads only: the driver's `CR` at boot would lose every position.
        batches(channels, |token| format!("M{token}P34R"), 1)
            .into_iter()
            .map(|(_, payload)| Request::query(request_frame(&payload), Step::EncoderTypes))
            .collect()
    }

    fn poll(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        batches(channels, |token| format!("SE{token} M{token}P20R M{token}P22R"), 3)
            .into_iter()
            .map(|(polled, payload)| {
                let step = match polled[..] {
                    [channel] => Step::Poll { channel },
                    _ => Step::PollMany,
                };
                Request::query(request_frame(&payload), step)
            })
            .collect()
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        let token = axis_token(channel)
            .ok_or(CommandError::OutOfRange { what: "channel (module × 10 + axis)", value: channel as f64 })?;
        let commands = self.commands(channel, &token, command)?;
        if commands.is_empty() {
            return Ok(Vec::new());
        }
        Ok(vec![Request::query(request_frame(&commands.join(" ")), Step::Command { channel })])
    }

    fn reply(&mut self, request: &Request<Step>, frame: &[u8]) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let replies = sub_replies(frame).map_err(|why| ReplyError::new(request, frame, why))?;
        let asked = commands_of(request);
        if replies.len() != asked.len() {
            return Err(ReplyError::new(request, frame, "not one reply per command"));
        }
        match request.step {
            Step::Command { channel } => Ok(Self::acknowledgements(channel, &asked, &replies)),
            Step::EncoderTypes | Step::Poll { .. } | Step::PollMany => {
                self.readings(&asked, &replies).map_err(|why| ReplyError::new(request, frame, why))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn protocol() -> Phymotion {
        Phymotion::new(&ProtocolOptions::default())
    }

    /// The payload of each request, checking its framing on the way.
    fn payloads(requests: &[Request<Step>]) -> Vec<String> {
        requests
            .iter()
            .map(|r| {
                let content =
                    r.bytes.strip_prefix(&[STX, ADDRESS]).and_then(|c| c.strip_suffix(&[ETX])).expect("framed");
                let mut addressed = vec![ADDRESS];
                addressed.extend_from_slice(content);
                let payload = without_checksum(&addressed).expect("a good checksum");
                assert_ne!(payload.len(), addressed.len(), "a checksum is sent");
                String::from_utf8_lossy(&payload[1..]).into_owned()
            })
            .collect()
    }

    fn go(position: f64, relative: bool) -> DriverCommand {
        DriverCommand::Move { position, relative, min_velocity: 200.0, max_velocity: 2000.0, acceleration: 10_000.0 }
    }

    fn ack(data: &[&str]) -> Vec<u8> {
        let mut body = Vec::new();
        for d in data {
            body.push(ACK);
            body.extend_from_slice(d.as_bytes());
        }
        reply_frame(&body)
    }

    #[test]
    fn frames_carry_the_address_and_the_xor_of_address_payload_and_colon() {
        assert_eq!(request_frame("M1.1P20R"), b"\x020M1.1P20R:69\x03");
        assert_eq!(request_frame("SE1.1"), b"\x020SE1.1:32\x03");
        assert_eq!(request_frame("M1.1A1000"), b"\x020M1.1A1000:29\x03");
        assert_eq!(request_frame("SE1.1 M1.1P20R M1.1P22R"), b"\x020SE1.1 M1.1P20R M1.1P22R:30\x03");
        assert_eq!(request_frame("CR"), b"\x020CR:1B\x03");
        assert_eq!(request_frame("IM0"), b"\x020IM0:3E\x03");
        assert_eq!(reply_frame(b"\x06"), b"\x02\x06:3C\x03");
        assert_eq!(reply_frame(b"\x061234"), b"\x02\x061234:38\x03");
        assert_eq!(reply_frame(b"\x06E"), b"\x02\x06E:79\x03");
        assert_eq!(reply_frame(b"\x15"), b"\x02\x15:2F\x03");
    }

    #[test]
    fn channels_are_module_times_ten_plus_axis() {
        assert_eq!(
            (axis_token(11), axis_token(23), axis_token(101)),
            (Some("1.1".into()), Some("2.3".into()), Some("10.1".into()))
        );
        assert_eq!((axis_token(10), axis_token(3)), (None, None));
        assert_eq!(split_axis("1.1P20R"), Some((11, "P20R")));
        assert_eq!(split_axis("10.2"), Some((102, "")));
        assert_eq!(
            (split_axis("1.0A5"), split_axis(".1A"), split_axis("+1.1"), split_axis("0.1")),
            (None, None, None, None)
        );
        assert!(matches!(protocol().command(10, &go(1.0, false)), Err(CommandError::OutOfRange { .. })));
    }

    #[test]
    fn motions_set_velocities_and_ramp_switch_the_power_stage_on_and_go_in_one_frame() {
        let mut p = protocol();
        let requests = p.command(11, &go(1000.0, false)).unwrap();
        assert_eq!(requests.len(), 1);
        assert_eq!(requests[0].step, Step::Command { channel: 11 });
        assert_eq!(
            requests[0].bytes,
            request_frame("M1.1P14=2000.000000 M1.1P04=200.000000 M1.1P15=10000.000000 M1.1MA M1.1A1000")
        );
        let last = |p: &mut Phymotion, channel, command| {
            let sent = payloads(&p.command(channel, &command).unwrap());
            sent[0].rsplit(' ').next().unwrap().to_string()
        };
        assert_eq!(last(&mut p, 11, go(-500.4, false)), "M1.1A-500");
        assert_eq!(last(&mut p, 23, go(250.0, true)), "M2.3+250");
        assert_eq!(last(&mut p, 23, go(-250.5, true)), "M2.3-251");
        assert_eq!(last(&mut p, 23, go(0.2, true)), "M2.3-0", "a zero distance as the driver sends it");
        let jog = |v: f64| DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: v, acceleration: 1e6 };
        assert_eq!(
            payloads(&p.command(12, &jog(-3000.0)).unwrap()),
            ["M1.2P14=3000.000000 M1.2P04=1.000000 M1.2P15=500000.000000 M1.2MA M1.2L-"],
            "velocities and ramps clamped to what the controller takes, as the driver does"
        );
        assert_eq!(last(&mut p, 12, jog(3000.0)), "M1.2L+");
        let home =
            |forward| DriverCommand::Home { forward, min_velocity: 100.0, max_velocity: 1500.0, acceleration: 100.0 };
        assert_eq!(
            payloads(&p.command(21, &home(false)).unwrap()),
            ["M2.1P08=1500.000000 M2.1P10=100.000000 M2.1P09=4000.000000 M2.1MA M2.1R-C"]
        );
        assert_eq!(last(&mut p, 21, home(true)), "M2.1R+C");
        let far = go(3e9, false);
        assert!(matches!(p.command(11, &far), Err(CommandError::OutOfRange { .. })), "refused, not clamped");
        let nan_speed = DriverCommand::Move {
            position: 1.0,
            relative: false,
            min_velocity: 0.0,
            max_velocity: f64::NAN,
            acceleration: 1.0,
        };
        assert!(matches!(p.command(11, &nan_speed), Err(CommandError::OutOfRange { .. })));
    }

    #[test]
    fn stop_set_position_enable_ratio_and_raw_text_are_one_frame_each() {
        let mut p = protocol();
        let sent = |p: &mut Phymotion, command: DriverCommand| payloads(&p.command(11, &command).unwrap());
        assert_eq!(sent(&mut p, DriverCommand::Stop { acceleration: 20_000.0 }), ["M1.1P15=20000.000000 M1.1S"]);
        assert_eq!(sent(&mut p, DriverCommand::SetPosition { position: -1234.4 }), ["M1.1P20=-1234.000000"]);
        assert_eq!(sent(&mut p, DriverCommand::Enable { on: true }), ["M1.1MA"]);
        assert_eq!(sent(&mut p, DriverCommand::Enable { on: false }), ["M1.1MD"]);
        assert_eq!(sent(&mut p, DriverCommand::SetEncoderRatio { ratio: 4.0 }), ["M1.1P39=0.250000"]);
        assert!(p.command(11, &DriverCommand::SetEncoderRatio { ratio: 0.0 }).is_err());
        assert!(p.command(11, &DriverCommand::SetEncoderRatio { ratio: 1e7 }).is_err(), "1/ratio would be sent as 0");
        assert_eq!(sent(&mut p, DriverCommand::Raw { text: " SEC1.1  M1.1P45R ".into() }), ["SEC1.1 M1.1P45R"]);
        assert!(p.command(11, &DriverCommand::Raw { text: "M1.1\x03S".into() }).is_err());
        assert!(p.command(11, &DriverCommand::Raw { text: String::new() }).unwrap().is_empty());
        for nothing in [
            DriverCommand::SetHighLimit { position: 1.0 },
            DriverCommand::SetLowLimit { position: -1.0 },
            DriverCommand::SetGain { gain: zmotor_msgs::Gain::Proportional, value: 1.0 },
            DriverCommand::Poll,
        ] {
            assert!(p.command(11, &nothing).unwrap().is_empty(), "{nothing:?}");
        }
    }

    #[test]
    fn a_drive_switched_off_is_not_switched_on_by_a_motion() {
        let mut p = protocol();
        p.command(11, &DriverCommand::Enable { on: false }).unwrap();
        assert_eq!(
            payloads(&p.command(11, &go(5.0, false)).unwrap()),
            ["M1.1P14=2000.000000 M1.1P04=200.000000 M1.1P15=10000.000000 M1.1A5"]
        );
        assert!(payloads(&p.command(12, &go(5.0, false)).unwrap())[0].contains("M1.2MA"), "other axes as they were");
        p.command(11, &DriverCommand::Enable { on: true }).unwrap();
        assert!(payloads(&p.command(11, &go(5.0, false)).unwrap())[0].contains("M1.1MA"));
    }

    #[test]
    fn a_poll_is_one_frame_for_every_axis_and_gives_one_status_each() {
        let mut p = protocol();
        let poll = p.poll(&[11, 12, 21]);
        assert_eq!(payloads(&poll), ["SE1.1 M1.1P20R M1.1P22R SE1.2 M1.2P20R M1.2P22R SE2.1 M2.1P20R M2.1P22R"]);
        assert_eq!(poll[0].step, Step::PollMany);
        // 11: running up, ready; 12: at rest on the + limit after hitting it, homed; 21: on the
        // center switch, power stage off.
        let reply = ack(&["66049", "1500", "1498", "529944", "200000", "200000", "524352", "0", "0"]);
        let events = p.reply(&poll[0], &reply).unwrap();
        let statuses: Vec<(usize, DeviceStatus)> = events
            .iter()
            .map(|e| match e {
                ReplyEvent::Status { channel, status } => (*channel, *status),
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(statuses.iter().map(|(c, _)| *c).collect::<Vec<_>>(), [11, 12, 21]);
        assert_eq!(statuses[0].1.msta, msta::MOVING | msta::POSITION);
        assert_eq!((statuses[0].1.position, statuses[0].1.encoder_position), (1500.0, 1498.0));
        assert_eq!(statuses[1].1.msta, msta::DONE | msta::PLUS_LS | msta::HOMED | msta::POSITION);
        assert_eq!(statuses[2].1.msta, msta::DONE | msta::HOME);
        // The next poll of 11 sees the counter go up: DIRECTION, until done.
        let poll_one = p.poll(&[11]);
        assert_eq!(poll_one[0].step, Step::Poll { channel: 11 });
        let events = p.reply(&poll_one[0], &ack(&["66049", "1600", "1600"])).unwrap();
        let [ReplyEvent::Status { status, .. }] = &events[..] else { panic!("{events:?}") };
        assert_eq!(status.msta, msta::MOVING | msta::POSITION | msta::DIRECTION);
        let events = p.reply(&poll_one[0], &ack(&["524800", "1700", "1700"])).unwrap();
        let [ReplyEvent::Status { status, .. }] = &events[..] else { panic!("{events:?}") };
        assert_eq!(status.msta, msta::DONE | msta::POSITION);
    }

    #[test]
    fn polls_batch_fourteen_axes_a_frame_and_skip_channels_that_name_no_axis() {
        let mut p = protocol();
        let channels: Vec<usize> = (1..=3).flat_map(|m| (1..=5).map(move |a| m * 10 + a)).chain([10]).collect();
        let poll = p.poll(&channels);
        assert_eq!(poll.len(), 2);
        assert_eq!(payloads(&poll)[0].split(' ').count(), 42);
        assert_eq!(payloads(&poll)[1], "SE3.5 M3.5P20R M3.5P22R");
        assert_eq!(poll[1].step, Step::Poll { channel: 35 });
        assert!(poll.iter().all(|r| r.bytes.len() <= MAX_PAYLOAD + 6));
    }

    #[test]
    fn errors_in_the_status_word_are_a_problem_and_reported_once_when_they_appear() {
        let mut p = protocol();
        let poll = p.poll(&[22]);
        let events = p.reply(&poll[0], &ack(&["8704", "10", "10"])).unwrap();
        let [ReplyEvent::ControllerError(VendorError { channel: Some(22), code, meaning }), ReplyEvent::Status { status, .. }] =
            &events[..]
        else {
            panic!("{events:?}")
        };
        assert_eq!((code.as_str(), meaning.as_str()), ("SE 0x2000", "power-stage error"));
        assert_eq!(status.msta & msta::PROBLEM, msta::PROBLEM);
        let events = p.reply(&poll[0], &ack(&["8704", "10", "10"])).unwrap();
        let [ReplyEvent::Status { status, .. }] = &events[..] else { panic!("{events:?}") };
        assert_eq!(status.msta & msta::PROBLEM, msta::PROBLEM, "still a problem, not reported again");
        let events = p.reply(&poll[0], &ack(&["16896", "10", "10"])).unwrap();
        let [ReplyEvent::ControllerError(VendorError { code, .. }), ReplyEvent::Status { status, .. }] = &events[..]
        else {
            panic!("{events:?}")
        };
        assert_eq!(code, "SE 0x4000");
        assert_eq!(status.msta & (msta::PROBLEM | msta::SLIP_STALL), msta::PROBLEM | msta::SLIP_STALL);
    }

    #[test]
    fn a_limit_switch_error_is_cleared_by_the_next_motion() {
        let mut p = protocol();
        let poll = p.poll(&[11]);
        p.reply(&poll[0], &ack(&["4640", "-200000", "-200000"])).unwrap();
        let first = payloads(&p.command(11, &go(0.0, false)).unwrap());
        assert!(first[0].starts_with("SEC1.1 M1.1P14="), "{first:?}");
        let second = payloads(&p.command(11, &go(0.0, false)).unwrap());
        assert!(second[0].starts_with("M1.1P14="), "once: {second:?}");
    }

    #[test]
    fn a_refused_command_is_the_controllers_error() {
        let mut p = protocol();
        let requests = p.command(11, &go(100.0, false)).unwrap();
        assert_eq!(p.reply(&requests[0], &ack(&["", "", "", "", ""])).unwrap(), []);
        let refused = reply_frame(b"\x06\x06\x06\x06\x15");
        let events = p.reply(&requests[0], &refused).unwrap();
        assert_eq!(
            events,
            [ReplyEvent::ControllerError(VendorError {
                channel: Some(11),
                code: "NAK".into(),
                meaning: "the controller refused M1.1A100".into()
            })]
        );
    }

    #[test]
    fn a_refused_reading_is_an_error_of_its_axis_and_the_others_still_report() {
        let mut p = protocol();
        let poll = p.poll(&[11, 31]);
        let reply = reply_frame(b"\x060\x060\x060\x15\x15\x15");
        let events = p.reply(&poll[0], &reply).unwrap();
        assert!(
            matches!(&events[0], ReplyEvent::ControllerError(VendorError { channel: Some(31), code, .. }) if code == "NAK")
        );
        assert!(matches!(&events[1], ReplyEvent::Status { channel: 11, .. }));
        assert_eq!(events.len(), 2);
    }

    #[test]
    fn replies_that_cannot_be_trusted_are_refused() {
        let mut p = protocol();
        let poll = p.poll(&[11]);
        let good = ack(&["0", "5", "5"]);
        assert!(p.reply(&poll[0], &good).is_ok());
        let mut bad_sum = good.clone();
        let at = bad_sum.len() - 2;
        bad_sum[at] = if bad_sum[at] == b'0' { b'1' } else { b'0' };
        assert_eq!(p.reply(&poll[0], &bad_sum).unwrap_err().why, "bad checksum");
        assert_eq!(p.reply(&poll[0], &ack(&["0", "5"])).unwrap_err().why, "not one reply per command");
        assert!(p.reply(&poll[0], &ack(&["zero", "5", "5"])).is_err());
        assert!(p.reply(&poll[0], &ack(&["0", "5", "five"])).is_err());
        assert!(p.reply(&poll[0], b"\x02\x06:3C").is_err(), "no ETX");
        assert!(p.reply(&poll[0], &reply_frame(b"0\x065\x065")).is_err(), "no ACK first");
        assert!(p.reply(&poll[0], b"\x02\x060\x065\x065:XX\x03").is_ok(), "XX: no checksum");
        assert!(p.reply(&poll[0], b"\x02\x060\x065\x065\x03").is_ok(), "none at all, as the driver takes it");
        assert!(p.reply(&poll[0], b"\x02\x060\x065\x065:G1\x03").is_err());
    }

    #[test]
    fn frames_are_found_whatever_the_pieces_and_noise_before_them_is_dropped() {
        let p = protocol();
        let frame = ack(&["524800", "-12", "-12"]);
        for cut in 0..frame.len() {
            assert_eq!(p.frame(&frame[..cut]), Frame::Incomplete, "{cut} bytes");
        }
        assert_eq!(p.frame(&frame), Frame::Complete(frame.len()));
        let mut two = frame.clone();
        two.extend_from_slice(&frame);
        assert_eq!(p.frame(&two), Frame::Complete(frame.len()));
        let mut noisy = b"~\x03\x06".to_vec();
        noisy.extend_from_slice(&frame);
        assert_eq!(p.frame(&noisy), Frame::Junk(3));
        assert_eq!(p.frame(b"\x03\x06"), Frame::Junk(2));
        // A frame cut short by a new one: the broken start is noise.
        let mut broken = b"\x02\x0612".to_vec();
        broken.extend_from_slice(&frame);
        assert_eq!(p.frame(&broken), Frame::Junk(4));
        let mut endless = vec![STX];
        endless.extend([b'1'; MAX_REPLY]);
        assert_eq!(p.frame(&endless), Frame::Junk(MAX_REPLY + 1), "no reply is that long");
    }

    #[test]
    fn replies_split_at_every_byte_are_the_same_frames() {
        let p = protocol();
        let frames = [ack(&["524800", "-12", "-12"]), reply_frame(b"\x06\x15"), ack(&[""])];
        let stream: Vec<u8> = frames.iter().flatten().copied().collect();
        let mut buffer = Vec::new();
        let mut found = Vec::new();
        for byte in stream {
            buffer.push(byte);
            loop {
                match p.frame(&buffer) {
                    Frame::Incomplete => break,
                    Frame::Junk(n) | Frame::Notice(n) => panic!("junk or notice {n} in {buffer:?}"),
                    Frame::Complete(n) => found.push(buffer.drain(..n).collect::<Vec<u8>>()),
                }
            }
        }
        assert_eq!(found, frames);
    }

    #[test]
    fn initialisation_reads_only_which_axes_have_an_encoder() {
        let mut p = protocol();
        let init = p.init(&[11, 21]);
        assert_eq!(payloads(&init), ["M1.1P34R M2.1P34R"]);
        assert_eq!(init[0].step, Step::EncoderTypes);
        assert_eq!(p.reply(&init[0], &ack(&["1", "0"])).unwrap(), []);
        let poll = p.poll(&[11, 21]);
        let events = p.reply(&poll[0], &ack(&["0", "0", "0", "0", "0", "0"])).unwrap();
        let present: Vec<bool> = events
            .iter()
            .filter_map(|e| match e {
                ReplyEvent::Status { status, .. } => Some(status.msta & msta::PRESENT != 0),
                _ => None,
            })
            .collect();
        assert_eq!(present, [true, false]);
    }

    #[test]
    fn units_per_step_scales_positions_not_frequencies() {
        let mut p = Phymotion::new(&ProtocolOptions { units_per_step: Some(0.005), ..ProtocolOptions::default() });
        let sent = payloads(&p.command(11, &go(1234.0, false)).unwrap());
        assert_eq!(sent, ["M1.1P14=2000.000000 M1.1P04=200.000000 M1.1P15=10000.000000 M1.1MA M1.1A6.17"]);
        assert_eq!(
            payloads(&p.command(11, &DriverCommand::SetPosition { position: 100.0 }).unwrap()),
            ["M1.1P20=0.500000"]
        );
        p.command(11, &DriverCommand::SetEncoderRatio { ratio: 2.0 }).unwrap();
        let poll = p.poll(&[11]);
        let events = p.reply(&poll[0], &ack(&["0", "6.17", "3.085"])).unwrap();
        let [ReplyEvent::Status { status, .. }] = &events[..] else { panic!("{events:?}") };
        assert!((status.position - 1234.0).abs() < 1e-9);
        assert!((status.encoder_position - 1234.0).abs() < 1e-9, "counts: P22 in units × ratio");
    }
}
