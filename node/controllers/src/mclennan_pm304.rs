//! McLennan PM304 on a serial line: ASCII commands prefixed by the axis's address (`1MA1000`),
//! one a line ended by `\r`, each answered by one line ended by `\r\n`, as the EPICS driver
//! motorMclennan (devPM304.cc, drvPM304.cc) speaks it.
//!
//! # Channels and units
//! Channel = the axis's address, 1 to 8. Positions, speeds (steps/s) and accelerations
//! (steps/s²) are whole motor steps, one a record step (the controller counts nothing else): a
//! target beyond 32 bits is refused, never clamped.
//!
//! # Record commands (axis 1), one exchange each, as devPM304.cc builds them
//! - move: `1SV<v>`, `1SA<a>`, `1SD<a>`, `1MA<n>` (relative `1MR<n>`);
//! - jog: `1SA<a>`, `1SD<a>`, `1SV<|v|>`, `1CV1` (or `1CV-1`);
//! - home: `1SV<v>`, `1SA<a>`, `1SD<a>`, `1IX` (forward) or `1IX-1` (reverse): the datum search;
//! - stop `1ST`; set position `1AP<n>` (the actual position, the one polled);
//! - raw text as one line; enable, soft limits, gains, encoder ratio, status refresh: nothing is
//!   sent (the PM304 has no amplifier switch in this driver's reach; the record keeps its limits).
//!
//! Every command is answered; a reply beginning `!` is the controller refusing it (its text on
//! the axis's ERR).
//!
//! # Polls and status
//! Initialisation reads each axis's identity `1ID` (logged); nothing is stopped or written (the
//! EPICS driver sends `1ST` at connection). A poll reads, per axis, `1OS` (eight flags) and
//! `1OA` (the actual position, `AP=1000`):
//!
//! | `OS` flag | MSTA |
//! |---|---|
//! | 1st: − limit, 2nd: + limit | MINUS_LS, PLUS_LS |
//! | 4th: idle (1) or busy (0) | DONE or MOVING |
//! | 5th to 8th: error flags | PROBLEM |
//!
//! The PM304 reports no home switch and no homed state: HOMED is the driver's, set when a datum
//! search it started ends at rest without a limit or an abort, until the connection closes.

use crate::protocol::{
    line_frame, line_text, state_of, whole_steps, CommandError, Finding, Frame, Protocol, Purpose, ReplyError,
    ReplyEvent, Request, UnitIdentities, VendorError,
};
use crate::scale::Scale;
use zmotor_core::DeviceStatus;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

/// The protocol's name in launch files.
pub(crate) const NAME: &str = "mclennan_pm304";

/// Ends a reply.
const INPUT_TERMINATOR: &[u8] = b"\r\n";

/// A request of the PM304.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Step {
    /// `1ID`.
    Identity {
        /// The axis.
        channel: usize,
    },
    /// `1OS`.
    Status {
        /// The axis.
        channel: usize,
    },
    /// `1OA`.
    Position {
        /// The axis.
        channel: usize,
    },
    /// A command.
    Command {
        /// The axis.
        channel: usize,
        /// It starts a datum search.
        search: bool,
    },
}

/// What the protocol knows of an axis: its status as its poll assembles it, and whether a datum
/// search it started has ended well.
#[derive(Clone, Copy, Debug, Default)]
struct Axis {
    status: DeviceStatus,
    searching: bool,
    homed: bool,
}

/// The PM304 protocol.
#[derive(Debug, Default)]
pub(crate) struct Pm304 {
    axes: Vec<(usize, Axis)>,
    /// Each unit's identity as the initialisation read it (`sync`).
    identities: UnitIdentities,
}

impl Pm304 {
    /// A protocol with nothing polled yet.
    pub(crate) fn new() -> Self {
        Self::default()
    }

    fn axis(&mut self, channel: usize) -> &mut Axis {
        state_of(&mut self.axes, channel)
    }
}

fn line(channel: usize, text: &str) -> Vec<u8> {
    format!("{channel}{text}\r").into_bytes()
}

/// Speed and accelerations, as every motion sets them first.
fn speeds(velocity: f64, acceleration: f64) -> Result<Vec<String>, CommandError> {
    let v = whole_steps("velocity", velocity.abs())?;
    let a = whole_steps("acceleration", acceleration.abs())?;
    Ok(vec![format!("SV{v}"), format!("SA{a}"), format!("SD{a}")])
}

impl Protocol for Pm304 {
    type Step = Step;

    fn name(&self) -> &'static str {
        NAME
    }

    fn purpose(step: Step) -> Purpose {
        match step {
            Step::Identity { .. } => Purpose::Init,
            Step::Status { channel } | Step::Position { channel } => Purpose::Poll { channel },
            Step::Command { channel, .. } => Purpose::Command { channel },
        }
    }

    fn frame(&self, buffer: &[u8]) -> Frame {
        match line_frame(buffer, INPUT_TERMINATOR) {
            Frame::Complete(2) => Frame::Junk(2),
            frame => frame,
        }
    }

    fn init(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        // A new connection may be a controller that was switched off: no datum is known.
        self.axes.clear();
        self.identities.clear();
        channels.iter().map(|&channel| Request::query(line(channel, "ID"), Step::Identity { channel })).collect()
    }

    fn sync(&mut self) -> Option<Request<Step>> {
        let channel = self.identities.next()?;
        Some(Request::query(line(channel, "ID"), Step::Identity { channel }))
    }

    /// "Mclennan Servo Supplies Ltd. PM304 V6.15", as the unit asked answered at connection.
    fn is_sync_reply(&self, frame: &[u8]) -> bool {
        self.identities.is_answer(line_text(frame, INPUT_TERMINATOR).trim())
    }

    fn poll(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        channels
            .iter()
            .flat_map(|&channel| {
                [
                    Request::query(line(channel, "OS"), Step::Status { channel }),
                    Request::query(line(channel, "OA"), Step::Position { channel }),
                ]
            })
            .collect()
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        let parts = match command {
            DriverCommand::Move { position, relative, max_velocity, acceleration, .. } => {
                let mut parts = speeds(*max_velocity, *acceleration)?;
                let verb = if *relative { "MR" } else { "MA" };
                parts.push(format!("{verb}{}", whole_steps("target", *position)?));
                parts
            }
            DriverCommand::MoveVelocity { max_velocity, acceleration, .. } => {
                // The record's jog: the accelerations, then the speed and the motion.
                let mut parts = speeds(*max_velocity, *acceleration)?;
                parts.rotate_left(1);
                parts.push(if *max_velocity < 0.0 { "CV-1" } else { "CV1" }.to_string());
                parts
            }
            DriverCommand::Home { forward, max_velocity, acceleration, .. } => {
                let mut parts = speeds(*max_velocity, *acceleration)?;
                parts.push(if *forward { "IX" } else { "IX-1" }.to_string());
                parts
            }
            DriverCommand::Stop { .. } => vec!["ST".to_string()],
            DriverCommand::SetPosition { position } => vec![format!("AP{}", whole_steps("position", *position)?)],
            DriverCommand::Raw { text } => {
                return Ok(vec![Request::query(format!("{text}\r"), Step::Command { channel, search: false })]);
            }
            DriverCommand::Enable { .. }
            | DriverCommand::SetEncoderRatio { .. }
            | DriverCommand::SetHighLimit { .. }
            | DriverCommand::SetLowLimit { .. }
            | DriverCommand::SetGain { .. }
            | DriverCommand::Poll => Vec::new(),
        };
        Ok(parts
            .iter()
            .map(|part| Request::query(line(channel, part), Step::Command { channel, search: part.starts_with("IX") }))
            .collect())
    }

    fn scale(&self, _channel: usize) -> Scale {
        Scale::motor_steps()
    }

    fn reply(&mut self, request: &Request<Step>, frame: &[u8]) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let text = line_text(frame, INPUT_TERMINATOR);
        let text = text.trim();
        let error = |why| ReplyError::new(request, frame, why);
        let channel = match request.step {
            Step::Identity { channel }
            | Step::Status { channel }
            | Step::Position { channel }
            | Step::Command { channel, .. } => channel,
        };
        if let Some(refusal) = text.strip_prefix('!') {
            let meaning = format!("{} (to {})", refusal.trim(), line_text(&request.bytes, b"\r"));
            return Ok(vec![ReplyEvent::ControllerError(VendorError {
                channel: Some(channel),
                code: "!".to_string(),
                meaning,
            })]);
        }
        match request.step {
            Step::Identity { channel } => {
                self.identities.read(channel, text);
                Ok(vec![ReplyEvent::Found(Finding::Identity(text.to_string()))])
            }
            Step::Status { channel } => {
                let flags = text.as_bytes();
                if flags.len() != 8 || !flags.iter().all(|b| matches!(b, b'0' | b'1')) {
                    return Err(error("not eight flags"));
                }
                let on = |i: usize| flags[i] == b'1';
                let axis = self.axis(channel);
                let idle = on(3);
                let trouble = on(0) || on(1) || (4..8).any(on);
                if axis.searching && idle {
                    // The search ended: at the datum, unless a limit or an abort ended it.
                    axis.searching = false;
                    axis.homed = !trouble;
                }
                let mut bits = axis.status.msta & msta::DIRECTION;
                let mut set = |on: bool, bit: u32| bits |= if on { bit } else { 0 };
                set(on(0), msta::MINUS_LS);
                set(on(1), msta::PLUS_LS);
                set(idle, msta::DONE);
                set(!idle, msta::MOVING);
                set((4..8).any(on), msta::PROBLEM);
                set(axis.homed, msta::HOMED);
                axis.status.msta = bits;
                Ok(Vec::new())
            }
            Step::Position { channel } => {
                let value = text.split_once('=').map_or(text, |(_, v)| v);
                let position: f64 = value.trim().parse().map_err(|_| error("not a position"))?;
                let status = &mut self.axis(channel).status;
                let moving = status.msta & msta::MOVING != 0;
                if moving && position != status.position {
                    let up = position > status.position;
                    status.msta = (status.msta & !msta::DIRECTION) | if up { msta::DIRECTION } else { 0 };
                }
                if !moving {
                    status.msta &= !msta::DIRECTION;
                }
                status.position = position;
                status.encoder_position = position;
                Ok(vec![ReplyEvent::Status { channel, status: *status }])
            }
            Step::Command { channel, search } => {
                if search {
                    self.axis(channel).searching = true;
                }
                Ok(Vec::new())
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

    #[test]
    fn commands_are_one_a_line_with_the_address() {
        let mut p = Pm304::new();
        let go = DriverCommand::Move {
            position: 12000.4,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 2000.0,
            acceleration: 20000.0,
        };
        assert_eq!(sent(&p.command(3, &go).unwrap()), ["3SV2000\r", "3SA20000\r", "3SD20000\r", "3MA12000\r"]);
        let jog = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -2000.0, acceleration: 20000.0 };
        assert_eq!(sent(&p.command(1, &jog).unwrap()), ["1SA20000\r", "1SD20000\r", "1SV2000\r", "1CV-1\r"]);
        assert!(p.command(1, &DriverCommand::Enable { on: true }).unwrap().is_empty());
        let far = DriverCommand::Move {
            position: 3e9,
            relative: true,
            min_velocity: 0.0,
            max_velocity: 1.0,
            acceleration: 1.0,
        };
        assert!(matches!(p.command(1, &far), Err(CommandError::OutOfRange { .. })), "refused, not clamped");
    }

    #[test]
    fn a_poll_reads_the_flags_then_the_position_and_a_search_that_ends_well_is_homed() {
        let mut p = Pm304::new();
        let poll = p.poll(&[1]);
        assert_eq!(sent(&poll), ["1OS\r", "1OA\r"]);
        assert_eq!(p.reply(&poll[0], b"01100000\r\n").unwrap(), []);
        let events = p.reply(&poll[1], b"AP=-250\r\n").unwrap();
        let [ReplyEvent::Status { channel: 1, status }] = &events[..] else { panic!("{events:?}") };
        assert_eq!((status.position, status.msta), (-250.0, msta::MOVING | msta::PLUS_LS));
        let search = p.command(
            1,
            &DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 1.0, acceleration: 1.0 },
        );
        let search = search.unwrap().pop().unwrap();
        assert_eq!(p.reply(&search, b"OK\r\n").unwrap(), []);
        p.reply(&poll[0], b"00110000\r\n").unwrap();
        let events = p.reply(&poll[1], b"AP=0\r\n").unwrap();
        let [ReplyEvent::Status { status, .. }] = &events[..] else { panic!("{events:?}") };
        assert_eq!(status.msta, msta::DONE | msta::HOMED);
        assert!(p.reply(&poll[0], b"0011\r\n").is_err());
    }

    #[test]
    fn a_refusal_names_its_command() {
        let mut p = Pm304::new();
        let stop = p.command(2, &DriverCommand::Stop { acceleration: 1.0 }).unwrap().remove(0);
        let events = p.reply(&stop, b"!NOT ALLOWED IN THIS MODE\r\n").unwrap();
        let [ReplyEvent::ControllerError(VendorError { channel: Some(2), meaning, .. })] = &events[..] else {
            panic!("{events:?}")
        };
        assert_eq!(meaning, "NOT ALLOWED IN THIS MODE (to 2ST)");
    }
}
