//! Oregon Micro Systems MAXnet (and the MAXv / MAXp language it shares): two-letter commands in
//! ASCII over TCP (port 23) or a serial line, as the EPICS driver motorOmsAsyn (omsBaseAxis.cpp,
//! omsBaseController.cpp, omsMAXnet.cpp) speaks them.
//!
//! # Wire format
//! Commands end with `\n`; an axis is selected first (`AX` … `AK`), or all of them (`AM`), and
//! several commands share a line separated by `;`. Commands answer nothing; a query answers one
//! line ended by `\n\r`, all axes comma separated in `AM` mode. The controller also sends, unasked,
//! notification lines `%000 SSSSSSSS` (done, limit, slip, command error flags), never taken for
//! a reply: a command error reaches ERR of the channel last commanded (the flag names no
//! command; motorOmsAsyn prints it on the IOC console), the other flags are the polls' to read.
//!
//! # Channels
//! Channel n (0 to 9) is the n-th axis of X, Y, Z, T, U, V, R, S, W, K. Positions are motor steps,
//! speeds steps/s: the record's, nothing to scale. Open-loop (stepper) axes: encoders are not
//! read.
//!
//! # Record commands (axis X), as motorOmsAsyn builds them
//! - move: `AX;AC<a>;VL<v>;VB<v0>;MA<p>;GO;ID;` (`MR` relative; `VB` before `VL` when the new top
//!   speed is below the last base speed, so that the base stays below the top at each step);
//! - home: the same settings, then `HM` forward or `HR` reverse, `MA0;GO;ID;` (to the switch,
//!   whose position becomes 0, and there);
//! - jog: `AX AC<a>; JG<v>;`; stop: `AX AC<a>; ST ID;` (200,000 without a deceleration, as
//!   motorOmsAsyn); set position: `AX LP<p>;`;
//! - enable: `AX CL1;` / `AX CL0;` (the closed loop, on an axis with an encoder);
//! - raw text: sent after the axis selection; a query (a report such as `RP`, or a `?`) is
//!   refused, as its answer would be taken for the next poll's;
//! - soft limits, gains, encoder ratio: nothing is sent.
//!
//! Speeds and accelerations are held to the controller's ranges as motorOmsAsyn holds them
//! (top speed 1 to 4,000,000 steps/s, a home's to 1,000,000, base speed below the top,
//! acceleration 1 to 8,000,000); a target beyond ±67,000,000 steps is refused, never clamped.
//!
//! # Connection and polls
//! Initialisation reads `WY` (the identity, logged) and each axis's type and limit level
//! (`AX PS?`, `AX LT?`); nothing is written. motorOmsAsyn also sends `IC` and `AM SA` (stop
//! every axis) at connection: zmotor stops nothing that it did not start. A poll is four
//! exchanges for every axis at once, as motorOmsAsyn's: `AM;RI;` (the status of each axis, its
//! done flag cleared by the reading), `AM PP;` (positions), `AM;RV;` (speeds), `AM;QL;` (the
//! limit inputs; an empty field reads 0, as motorOmsAsyn reads it). Under `observe` the statuses
//! are read with `AM;QI;`, which leaves the done flags to the IOC beside (its own `RI` clears
//! them):
//!
//! | reading | MSTA |
//! |---|---|
//! | `RI` done `D`, or at rest (speed 0) with no motion commanded | DONE |
//! | speed not 0 | MOVING |
//! | at rest, a motion commanded, no `D`: on a limit switch once it moved, else after five polls (PROBLEM) | DONE |
//! | `RI` direction `P` | DIRECTION |
//! | `RI` home `H` | HOME |
//! | `QL` bit n / n+8 (n+16 / n+24 for W, K), against the level `LT?` gives | MINUS_LS / PLUS_LS |

use crate::protocol::{
    line_frame, line_text, set_bit, whole_steps, CommandError, Finding, Frame, Protocol, Purpose, ReplyError,
    ReplyEvent, Request, UnitIdentities, VendorError,
};
use crate::scale::Scale;
use zmotor_core::DeviceStatus;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

/// The protocol's name in launch files.
pub(crate) const NAME: &str = "oms_maxnet";

/// The axes' letters, channel 0 first.
const AXES: [char; 10] = ['X', 'Y', 'Z', 'T', 'U', 'V', 'R', 'S', 'W', 'K'];

/// What ends a reply.
const INPUT_TERMINATOR: &[u8] = b"\n\r";

/// The notification flag of a command the controller refused.
const COMMAND_ERROR: u32 = 0x0100_0000;

/// Polls at rest with a motion commanded and no done flag before the motion counts as lost.
const POLLS_TO_GIVE_UP: u32 = 5;

/// The furthest target the controller takes, in steps.
const MAX_TARGET: f64 = 67_000_000.0;

/// A request's place in the protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Step {
    Identity,
    AxisType { channel: usize },
    LimitLevel { channel: usize },
    Read(Reading),
    Command { channel: usize },
}

/// One reading of a poll of every axis, in the order sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Reading {
    Statuses,
    Positions,
    Velocities,
    Limits,
}

/// What the protocol knows of an axis.
#[derive(Clone, Copy, Debug, Default)]
struct Axis {
    /// Its limit inputs are active high (`LH`): `QL`'s bits read inverted.
    limits_active_high: bool,
    /// A motion was commanded and its end not seen yet.
    commanded: bool,
    /// Polls at rest since, with no done flag.
    at_rest_polls: u32,
    /// It was seen moving since the motion was commanded.
    moved: bool,
    /// The base speed last sent, for the order of `VL` and `VB`.
    last_base: i64,
    /// The done flag of the poll under way.
    done_flag: bool,
    status: DeviceStatus,
}

/// The MAXnet protocol.
#[derive(Debug)]
pub(crate) struct Maxnet {
    axes: [Axis; 10],
    /// The channels the poll under way reads.
    polled: Vec<usize>,
    /// The channel of the last command sent.
    last_commanded: Option<usize>,
    /// Observed beside an IOC: the done flags are read without clearing them (`QI`).
    observed: bool,
    /// `WY`'s answer as the initialisation read it (`sync`).
    identity: UnitIdentities,
}

impl Maxnet {
    pub(crate) fn new() -> Self {
        Self {
            axes: [Axis::default(); 10],
            polled: Vec::new(),
            last_commanded: None,
            observed: false,
            identity: UnitIdentities::default(),
        }
    }

    /// The speed settings of a motion: `AC`, then `VL` and `VB` in the order that keeps the
    /// base below the top.
    fn speeds(&mut self, channel: usize, base: f64, top: f64, acceleration: f64, max_top: i64) -> String {
        let top = nint(top).clamp(1, max_top);
        let base = nint(base).clamp(0, top - 1);
        let acceleration = nint(acceleration.abs()).clamp(1, 8_000_000);
        let axis = &mut self.axes[channel];
        let text = if top < axis.last_base {
            format!("AC{acceleration};VB{base};VL{top};")
        } else {
            format!("AC{acceleration};VL{top};VB{base};")
        };
        axis.last_base = base;
        text
    }

    fn text(&mut self, channel: usize, command: &DriverCommand) -> Result<Option<String>, CommandError> {
        let axis = AXES[channel];
        let text = match command {
            DriverCommand::Move { position, relative, min_velocity, max_velocity, acceleration } => {
                if position.is_nan() || position.abs() > MAX_TARGET {
                    return Err(CommandError::OutOfRange { what: "target", value: *position });
                }
                let target = whole_steps("target", *position)?;
                let speeds = self.speeds(channel, *min_velocity, max_velocity.abs(), *acceleration, 4_000_000);
                let verb = if *relative { "MR" } else { "MA" };
                format!("A{axis};{speeds}{verb}{target};GO;ID;")
            }
            DriverCommand::Home { forward, min_velocity, max_velocity, acceleration } => {
                let speeds = self.speeds(channel, *min_velocity, max_velocity.abs(), *acceleration, 1_000_000);
                format!("A{axis};{speeds}{};MA0;GO;ID;", if *forward { "HM" } else { "HR" })
            }
            DriverCommand::MoveVelocity { max_velocity, acceleration, .. } => {
                let acceleration = nint(acceleration.abs()).clamp(1, 8_000_000);
                let velocity = nint(*max_velocity).clamp(-4_000_000, 4_000_000);
                format!("A{axis} AC{acceleration}; JG{velocity};")
            }
            DriverCommand::Stop { acceleration } => {
                // No deceleration given (a stop before any motion's settings): motorOmsAsyn's
                // 200,000 steps/s², not the 1 step/s² that would hardly brake.
                let acceleration = match nint(acceleration.abs()) {
                    0 => 200_000,
                    given => given.min(8_000_000),
                };
                format!("A{axis} AC{acceleration}; ST ID;")
            }
            DriverCommand::SetPosition { position } => format!("A{axis} LP{};", whole_steps("position", *position)?),
            DriverCommand::Enable { on } => format!("A{axis} CL{};", u8::from(*on)),
            DriverCommand::Raw { text } if is_query(text) => {
                return Err(CommandError::Unsupported {
                    protocol: NAME,
                    what: "send a query as raw text (its answer would be taken for the next poll's)",
                })
            }
            DriverCommand::Raw { text } if text.contains(['\n', '\r']) => {
                return Err(CommandError::Unsupported { protocol: NAME, what: "send raw text of several lines" })
            }
            DriverCommand::Raw { text } => format!("A{axis};{text}"),
            DriverCommand::SetEncoderRatio { .. }
            | DriverCommand::SetHighLimit { .. }
            | DriverCommand::SetLowLimit { .. }
            | DriverCommand::SetGain { .. }
            | DriverCommand::Poll => return Ok(None),
        };
        self.last_commanded = Some(channel);
        if command.starts_motion() {
            let axis = &mut self.axes[channel];
            axis.commanded = true;
            axis.moved = false;
            axis.at_rest_polls = 0;
        }
        Ok(Some(text))
    }

    /// Every polled axis's field of an `AM` answer.
    fn fields<'a>(&self, text: &'a str) -> Vec<(usize, &'a str)> {
        let fields: Vec<&str> = text.split(',').map(str::trim).collect();
        self.polled.iter().filter_map(|&c| fields.get(c).map(|f| (c, *f))).collect()
    }

    /// The statuses of the poll, its last reading in.
    fn statuses(&mut self, limits: u32) -> Vec<ReplyEvent<Step>> {
        let mut events = Vec::new();
        // Read by `QI`, a done flag stays until the IOC's `RI`, through its next motion.
        let flag_is_news = !self.observed;
        for &channel in &self.polled {
            let axis = &mut self.axes[channel];
            let status = &mut axis.status;
            let (low, high) = if channel < 8 { (channel, channel + 8) } else { (channel + 8, channel + 16) };
            let level = |bit: usize| (limits >> bit) & 1 == 1;
            // A switch is active at its level: high under `LH`, low under `LL`.
            set_bit(&mut status.msta, msta::MINUS_LS, level(low) == axis.limits_active_high);
            set_bit(&mut status.msta, msta::PLUS_LS, level(high) == axis.limits_active_high);
            let moving = status.velocity != 0.0;
            let at_a_limit = status.msta & (msta::MINUS_LS | msta::PLUS_LS) != 0;
            let done = if axis.done_flag && flag_is_news {
                true
            } else if moving {
                axis.at_rest_polls = 0;
                axis.moved = true;
                false
            } else if !axis.commanded || (at_a_limit && axis.moved) {
                // At rest on a switch after moving: stopped there (its done flag never comes).
                true
            } else {
                axis.at_rest_polls += 1;
                let lost = axis.at_rest_polls >= POLLS_TO_GIVE_UP;
                set_bit(&mut status.msta, msta::PROBLEM, lost);
                lost
            };
            if done {
                axis.commanded = false;
                axis.at_rest_polls = 0;
            } else {
                status.msta &= !msta::PROBLEM;
            }
            set_bit(&mut status.msta, msta::DONE, done);
            set_bit(&mut status.msta, msta::MOVING, moving);
            status.encoder_position = status.position;
            events.push(ReplyEvent::Status { channel, status: *status });
        }
        events
    }
}

/// Whether raw text asks something the controller answers: a report (`RP`, `RI`, `WY`, …) or a
/// `?` query.
fn is_query(text: &str) -> bool {
    const REPORTS: [&str; 14] = ["RP", "RE", "RI", "RA", "RV", "RQ", "QA", "QI", "QL", "PP", "PE", "EA", "WY", "WS"];
    let text = text.to_ascii_uppercase();
    text.contains('?') || REPORTS.iter().any(|report| text.contains(report))
}

/// C's rounding of a value to an integer (`(int)(v + 0.5)` away from zero), saturated.
fn nint(value: f64) -> i64 {
    value.round() as i64
}

fn line(text: &str) -> Vec<u8> {
    format!("{text}\n").into_bytes()
}

impl Protocol for Maxnet {
    type Step = Step;

    fn name(&self) -> &'static str {
        NAME
    }

    fn purpose(step: Step) -> Purpose {
        match step {
            Step::Identity | Step::AxisType { .. } | Step::LimitLevel { .. } => Purpose::Init,
            Step::Read(_) => Purpose::PollMany,
            Step::Command { channel } => Purpose::Command { channel },
        }
    }

    fn frame(&self, buffer: &[u8]) -> Frame {
        // An acknowledgement or line ends before a line are no reply (motorOmsAsyn skips them).
        let noise = buffer.iter().take_while(|b| matches!(b, 0x06 | b'\r' | b'\n')).count();
        if noise > 0 {
            return Frame::Junk(noise);
        }
        match line_frame(buffer, INPUT_TERMINATOR) {
            // A notification (`%000 SSSSSSSS`) is no reply.
            Frame::Complete(n) if buffer.first() == Some(&b'%') => Frame::Notice(n),
            frame => frame,
        }
    }

    fn notice(&mut self, frame: &[u8]) -> Vec<ReplyEvent<Step>> {
        let text = line_text(frame, INPUT_TERMINATOR);
        let flags = text.trim().strip_prefix('%').and_then(|rest| rest.split_whitespace().nth(1));
        match flags.and_then(|flags| u32::from_str_radix(flags, 16).ok()) {
            // Said right after the command it refused: the last one sent is its channel's.
            Some(flags) if flags & COMMAND_ERROR != 0 => vec![ReplyEvent::ControllerError(VendorError {
                channel: self.last_commanded,
                code: "command error".into(),
                meaning: "the MAXnet refused a command (its command error flag, which names no command)".into(),
            })],
            _ => Vec::new(),
        }
    }

    fn init(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        // Read afresh: the controller may have been changed or upgraded.
        self.identity.clear();
        let mut requests = vec![Request::query(line("WY"), Step::Identity)];
        for &channel in channels {
            let axis = AXES[channel];
            requests.push(Request::query(line(&format!("A{axis} PS?")), Step::AxisType { channel }));
            requests.push(Request::query(line(&format!("A{axis} LT?")), Step::LimitLevel { channel }));
            self.axes[channel].commanded = false;
        }
        requests
    }

    fn observe_only(&mut self) {
        self.observed = true;
    }

    fn sync(&mut self) -> Option<Request<Step>> {
        self.identity.next()?;
        Some(Request::query(line("WY"), Step::Identity))
    }

    /// "MAXnet ver:1.33.4, s/n:000001", as read at connection.
    fn is_sync_reply(&self, frame: &[u8]) -> bool {
        self.identity.is_answer(line_text(frame, INPUT_TERMINATOR).trim())
    }

    fn poll(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        self.polled = channels.to_vec();
        [
            (if self.observed { "AM;QI;" } else { "AM;RI;" }, Reading::Statuses),
            ("AM PP;", Reading::Positions),
            ("AM;RV;", Reading::Velocities),
            ("AM;QL;", Reading::Limits),
        ]
        .into_iter()
        .map(|(text, reading)| Request::query(line(text), Step::Read(reading)))
        .collect()
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        Ok(self
            .text(channel, command)?
            .map(|text| Request::silent(line(&text), Step::Command { channel }))
            .into_iter()
            .collect())
    }

    fn scale(&self, _channel: usize) -> Scale {
        // Steps: what one is in EGU is the lab's mechanics.
        Scale::motor_steps()
    }

    fn reply(&mut self, request: &Request<Step>, frame: &[u8]) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let text = line_text(frame, INPUT_TERMINATOR);
        let text = text.trim();
        let error = |why| ReplyError::new(request, frame, why);
        match request.step {
            Step::Identity => {
                self.identity.read(0, text);
                Ok(vec![ReplyEvent::Found(Finding::Identity(text.to_string()))])
            }
            // `=O` open loop, `=E`, `=M`: logged by the identity; encoders are not read.
            Step::AxisType { .. } if text.starts_with('=') => Ok(Vec::new()),
            Step::LimitLevel { channel } => match text {
                "=l" | "=L" => Ok(Vec::new()),
                "=h" | "=H" => {
                    self.axes[channel].limits_active_high = true;
                    Ok(Vec::new())
                }
                _ => Err(error("not a limit level")),
            },
            Step::AxisType { .. } => Err(error("not an axis type")),
            Step::Read(Reading::Statuses) => {
                for (channel, field) in self.fields(text) {
                    let flags: Vec<char> = field.chars().collect();
                    let [direction, done, _limit, home] = flags[..] else {
                        return Err(error("not four status letters"));
                    };
                    let axis = &mut self.axes[channel];
                    axis.done_flag = done == 'D';
                    set_bit(&mut axis.status.msta, msta::DIRECTION, direction == 'P');
                    set_bit(&mut axis.status.msta, msta::HOME, home == 'H');
                }
                Ok(Vec::new())
            }
            Step::Read(reading @ (Reading::Positions | Reading::Velocities)) => {
                for (channel, field) in self.fields(text) {
                    // An empty field is 0, as motorOmsAsyn reads it (`,,,,`).
                    let value = if field.is_empty() {
                        0
                    } else {
                        field.parse::<i64>().map_err(|_| error("not a whole number"))?
                    };
                    let value = value as f64;
                    let status = &mut self.axes[channel].status;
                    match reading {
                        Reading::Positions => status.position = value,
                        _ => status.velocity = value,
                    }
                }
                Ok(Vec::new())
            }
            Step::Read(Reading::Limits) => {
                let limits = u32::from_str_radix(text, 16).map_err(|_| error("not a hex word"))?;
                Ok(self.statuses(limits))
            }
            Step::Command { .. } => Err(error("a command answered")),
        }
    }
}
