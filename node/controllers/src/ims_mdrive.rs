//! IMS (Schneider Electric Motion) MDrive Plus motors in party mode: several motors on one line
//! (RS-485, or a terminal server's TCP port), each addressed by its one-character device name,
//! MCode in ASCII, as the EPICS driver motorIms (ImsMDrivePlusMotorAxis.cpp and
//! ImsMDrivePlusMotorController.cpp) speaks it.
//!
//! # Wire format
//! A command is the motor's name, the MCode and `\r\n`: `1MA 1000`. The motors are set up as
//! motorIms requires (party mode `PY=1`, echo mode `EM=2`): a motor answers only its `PR`
//! (print) queries, with the value and `\r\n`; every other command is silent. An error shows
//! nowhere but in the motor's error number `ER`: zmotor reads `PR ER` after each command (a
//! refusal reaches the axis's ERR with its code and meaning) and at the end of each motion the
//! motor took (a stall; a search ended on a limit; a motion ending on a limit switch is said by
//! the limit bits, not as an error), and clears it, `ER=0`.
//!
//! # Channels
//! Channel n (1 to 9) is the motor named `n`. Positions are the motor's counts (microsteps, or
//! encoder counts with `EE=1`), speeds counts/s: the record's steps, nothing to scale.
//!
//! # Record commands (motor 1), as motorIms builds them
//! - move: `1VI=<v0>` (with a base speed), `1VM=<v>`, `1A=<a>` and `1D=<a>` (with an
//!   acceleration), `1ST=0` (the stall flag cleared), `1MA <p>` or `1MR <d>`;
//! - jog: the same settings at |v|, then `1SL <v>` (slew, signed);
//! - home: the settings, `1HM 3` forward (slew +, creep − off the switch) or `1HM 1` reverse,
//!   then `1R1=0`: user register R1 is motorIms's "homed" flag, set `1R1=1` by the first poll
//!   that finds the search over. Unlike motorIms, only a search the motor took (`PR ER` 0), that
//!   nobody stopped and that ended without an error sets it; motorIms's `PR VI` before a home
//!   without base speed (read, never used) is not sent;
//! - stop: `1D=<a>` (with a deceleration), `1SL 0`;
//! - set position: `1P=<p>`; enable: `1DE=1` / `1DE=0` (drive enable; motorIms has none);
//! - raw text: sent after the name as it is; a `PR` query's answer is read (and dropped);
//! - soft limits, gains, encoder ratio: nothing is sent.
//!
//! Numbers are whole counts (rounded; one beyond 32 bits is refused, never clamped).
//!
//! # Connection and polls
//! Initialisation reads per motor `PR VR` (the firmware, logged), `PR EE` (an encoder) and
//! `PR S1` … `PR S4`, the inputs' functions (1 home, 2 limit +, 3 limit −), as motorIms does;
//! nothing is written. A poll reads per motor `PR MV`, then `PR P` (motorIms reads them the other
//! way round; this way the poll that finds a motion over has its final position), the home and
//! limit inputs set up (`PR I<n>`), `PR R1`, `PR ST`, `PR C2`:
//!
//! | reading | MSTA |
//! |---|---|
//! | `MV` 0 / 1 | DONE / MOVING |
//! | home input 1, limit + 1, limit − 1 | HOME, PLUS_LS, MINUS_LS |
//! | `R1` > 0 | HOMED |
//! | `ST` > 0 | SLIP_STALL (a stall) |
//! | `EE` 1 | PRESENT; the encoder position is `C2` (else `P`) |

use crate::protocol::{
    line_frame, line_text, set_bit, state_of, whole_steps, CommandError, Finding, Frame, Protocol, Purpose, ReplyError,
    ReplyEvent, Request, UnitIdentities, VendorError,
};
use crate::scale::Scale;
use zmotor_core::DeviceStatus;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

/// The protocol's name in launch files.
pub(crate) const NAME: &str = "ims_mdrive";

/// What ends a command (motorIms's output terminator for the MDrive Plus).
const OUTPUT_TERMINATOR: &str = "\r\n";

/// What ends a reply.
const INPUT_TERMINATOR: &[u8] = b"\r\n";

/// A request's place in the protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Step {
    Version {
        channel: usize,
    },
    Encoder {
        channel: usize,
    },
    /// `PR S<input>`: what the input is set up as.
    InputFunction {
        channel: usize,
        input: u8,
    },
    Read {
        channel: usize,
        reading: Reading,
    },
    /// A home search found over: its flag set, `R1=1`.
    Homed {
        channel: usize,
    },
    Command {
        channel: usize,
    },
    /// `PR ER` after a command: what it started, armed when the motor took it.
    Errors {
        channel: usize,
        started: Started,
    },
    /// `PR ER` once a motion is over: a stall, a search that failed.
    MotionEnded {
        channel: usize,
    },
    /// A raw `PR` query: its answer is read and dropped.
    RawQuery {
        channel: usize,
    },
    ClearError {
        channel: usize,
    },
}

/// What a command started, once the motor took it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Started {
    Nothing,
    Motion,
    HomeSearch,
}

/// One reading of a motor's poll, in the order sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Reading {
    Position,
    Moving,
    Switch(Switch),
    Homed,
    Stall,
    Encoder,
}

/// The switches an input can be set up as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Switch {
    Home,
    Plus,
    Minus,
}

/// What the protocol knows of a motor.
#[derive(Clone, Copy, Debug, Default)]
struct Motor {
    encoder: bool,
    /// The input each switch is wired to, as `S1`…`S4` say.
    inputs: [Option<u8>; 3],
    /// A motion the motor took: its end reads the error number.
    moving_since_command: bool,
    /// A home search the motor took and nobody stopped: its end, without an error, sets the
    /// homed flag.
    homing: bool,
    /// A stop was asked since the last home: a home's `PR ER` answered after it does not make
    /// a search that was stopped count as one that ended (its end would set HOMED).
    stopped: bool,
    status: DeviceStatus,
}

/// The MDrive protocol.
#[derive(Debug, Default)]
pub(crate) struct Mdrive {
    motors: Vec<(usize, Motor)>,
    /// Each motor's firmware (`PR VR`) as the initialisation read it (`sync`).
    identities: UnitIdentities,
}

impl Mdrive {
    pub(crate) fn new() -> Self {
        Self::default()
    }

    fn motor(&mut self, channel: usize) -> &mut Motor {
        state_of(&mut self.motors, channel)
    }

    /// The commands of a record command, without the name.
    fn mcode(&mut self, n: usize, command: &DriverCommand) -> Result<Vec<String>, CommandError> {
        let settings = |base: f64, velocity: f64, acceleration: f64| -> Result<Vec<String>, CommandError> {
            let mut lines = Vec::new();
            if base > 0.0 {
                lines.push(format!("VI={}", whole_steps("base velocity", base)?));
            }
            lines.push(format!("VM={}", whole_steps("velocity", velocity)?));
            if acceleration != 0.0 {
                let acceleration = whole_steps("acceleration", acceleration.abs())?;
                lines.extend([format!("A={acceleration}"), format!("D={acceleration}")]);
            }
            lines.push("ST=0".into());
            Ok(lines)
        };
        Ok(match command {
            DriverCommand::Move { position, relative, min_velocity, max_velocity, acceleration } => {
                let mut lines = settings(*min_velocity, max_velocity.abs(), *acceleration)?;
                let verb = if *relative { "MR" } else { "MA" };
                lines.push(format!("{verb} {}", whole_steps("target", *position)?));
                lines
            }
            DriverCommand::MoveVelocity { min_velocity, max_velocity, acceleration } => {
                let mut lines = settings(*min_velocity, max_velocity.abs(), *acceleration)?;
                lines.push(format!("SL {}", whole_steps("jog velocity", *max_velocity)?));
                lines
            }
            DriverCommand::Home { forward, min_velocity, max_velocity, acceleration } => {
                let mut lines = settings(*min_velocity, max_velocity.abs(), *acceleration)?;
                lines.extend([format!("HM {}", if *forward { 3 } else { 1 }), "R1=0".into()]);
                lines
            }
            DriverCommand::Stop { acceleration } => {
                self.motor(n).homing = false;
                let mut lines = Vec::new();
                if *acceleration != 0.0 {
                    lines.push(format!("D={}", whole_steps("deceleration", acceleration.abs())?));
                }
                lines.push("SL 0".into());
                lines
            }
            DriverCommand::SetPosition { position } => vec![format!("P={}", whole_steps("position", *position)?)],
            DriverCommand::Enable { on } => vec![format!("DE={}", u8::from(*on))],
            DriverCommand::Raw { text } if text.contains(['\n', '\r']) => {
                return Err(CommandError::Unsupported { protocol: NAME, what: "send raw text of several lines" })
            }
            DriverCommand::Raw { text } => vec![text.clone()],
            DriverCommand::SetEncoderRatio { .. }
            | DriverCommand::SetHighLimit { .. }
            | DriverCommand::SetLowLimit { .. }
            | DriverCommand::SetGain { .. }
            | DriverCommand::Poll => Vec::new(),
        })
    }

    /// A poll's reading of `channel`: its status once the last is in.
    fn read(&mut self, channel: usize, reading: Reading, value: f64) -> Vec<ReplyEvent<Step>> {
        let motor = self.motor(channel);
        let status = &mut motor.status;
        let on = value > 0.0;
        match reading {
            Reading::Moving => {
                set_bit(&mut status.msta, msta::DONE, !on);
                set_bit(&mut status.msta, msta::MOVING, on);
                // A motion over: its error, if any (a stall, a search ended on a limit).
                if !on && std::mem::take(&mut motor.moving_since_command) {
                    let query = Request::query(line(channel, "PR ER"), Step::MotionEnded { channel });
                    return vec![ReplyEvent::FollowUp(vec![query])];
                }
            }
            Reading::Position => {
                let moving = status.msta & msta::MOVING != 0;
                set_bit(&mut status.msta, msta::DIRECTION, moving && value > status.position);
                status.position = value;
                if !motor.encoder {
                    status.encoder_position = value;
                }
                // The switches as set up: known by now (the poll was made before the
                // initialisation's answers, at a new connection).
                let mut switches = Vec::new();
                for (switch, input) in [Switch::Home, Switch::Plus, Switch::Minus].into_iter().zip(motor.inputs) {
                    if let Some(input) = input {
                        let query = line(channel, &format!("PR I{input}"));
                        switches.push(Request::query(query, Step::Read { channel, reading: Reading::Switch(switch) }));
                    }
                }
                return vec![ReplyEvent::FollowUp(switches)];
            }
            Reading::Switch(Switch::Home) => set_bit(&mut status.msta, msta::HOME, on),
            Reading::Switch(Switch::Plus) => set_bit(&mut status.msta, msta::PLUS_LS, on),
            Reading::Switch(Switch::Minus) => set_bit(&mut status.msta, msta::MINUS_LS, on),
            Reading::Homed => set_bit(&mut status.msta, msta::HOMED, on),
            Reading::Stall => set_bit(&mut status.msta, msta::SLIP_STALL, on),
            Reading::Encoder => {
                if motor.encoder {
                    status.encoder_position = value;
                }
                set_bit(&mut status.msta, msta::PRESENT, motor.encoder);
                return vec![ReplyEvent::Status { channel, status: *status }];
            }
        }
        Vec::new()
    }
}

/// The error numbers of a motion stopped by the plus and the minus limit switch.
const LIMIT_PLUS: u32 = 83;
const LIMIT_MINUS: u32 = 84;

/// Motor `channel`'s error `code`, on ERR, then cleared (`ER=0`).
fn motor_error(channel: usize, code: u32) -> Vec<ReplyEvent<Step>> {
    let meaning = format!("{} (error {code})", meaning(code));
    let clear = Request::silent(line(channel, "ER=0"), Step::ClearError { channel });
    vec![
        ReplyEvent::ControllerError(VendorError { channel: Some(channel), code: code.to_string(), meaning }),
        ReplyEvent::FollowUp(vec![clear]),
    ]
}

/// `code` to motor `channel`, terminated.
fn line(channel: usize, code: &str) -> Vec<u8> {
    format!("{channel}{code}{OUTPUT_TERMINATOR}").into_bytes()
}

/// What an MCode error number means (the MCode reference's table, as motorIms lists it).
fn meaning(code: u32) -> &'static str {
    match code {
        6 => "an I/O is already set to this type",
        8 => "tried to set an I/O to an incorrect I/O type",
        9 => "tried to write to an I/O set as input or typed",
        10 => "illegal I/O number",
        20 => "tried to set an unknown variable or flag",
        21 => "tried to set an incorrect value",
        22 => "VI is set greater than or equal to VM",
        23 => "VM is set less than or equal to VI",
        24 => "illegal data entered",
        25 => "variable or flag is read only",
        30 => "unknown label or user variable",
        34 => "a variable sent as a command",
        35 => "unknown name in a print",
        38 => "a number glued to the command's name",
        40 => "a program command in immediate mode",
        73 => "a save while moving",
        74 => "a reset of the parameters while moving",
        80 => "no input set up as the home switch",
        81 => "home type out of range",
        83 => "stopped on the plus limit switch",
        84 => "stopped on the minus limit switch",
        85 => "a motion during a home search, or a home during a motion",
        86 => "stall detected",
        94 => "a motion while the drive is disabled",
        _ => "an MCode error (see the MCode reference's error table)",
    }
}

impl Protocol for Mdrive {
    type Step = Step;

    fn name(&self) -> &'static str {
        NAME
    }

    fn purpose(step: Step) -> Purpose {
        match step {
            Step::Version { .. } | Step::Encoder { .. } | Step::InputFunction { .. } => Purpose::Init,
            Step::Read { channel, .. } | Step::MotionEnded { channel } => Purpose::Poll { channel },
            Step::Homed { channel }
            | Step::Command { channel }
            | Step::Errors { channel, .. }
            | Step::RawQuery { channel }
            | Step::ClearError { channel } => Purpose::Command { channel },
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
        self.identities.clear();
        let mut requests = Vec::new();
        for &channel in channels {
            requests.push(Request::query(line(channel, "PR VR"), Step::Version { channel }));
            requests.push(Request::query(line(channel, "PR EE"), Step::Encoder { channel }));
            for input in 1..=4 {
                let query = line(channel, &format!("PR S{input}"));
                requests.push(Request::query(query, Step::InputFunction { channel, input }));
            }
            self.motor(channel).inputs = [None; 3];
        }
        requests
    }

    fn sync(&mut self) -> Option<Request<Step>> {
        let channel = self.identities.next()?;
        Some(Request::query(line(channel, "PR VR"), Step::Version { channel }))
    }

    /// The firmware, "3.010", as the motor asked answered at connection: no other reply has a
    /// decimal point (positions, speeds and flags are whole numbers).
    fn is_sync_reply(&self, frame: &[u8]) -> bool {
        self.identities.is_answer(line_text(frame, INPUT_TERMINATOR).trim())
    }

    fn poll(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        let mut requests = Vec::new();
        for &channel in channels {
            // `MV` before `P`: a poll that finds the motion over then carries a position read
            // after it ended, so DMOV 1 comes with the final readback (motorIms reads `P` first,
            // and its last steps may show a poll after the end). The switches' readings follow
            // `P`'s answer.
            let readings = [
                ("PR MV", Reading::Moving),
                ("PR P", Reading::Position),
                ("PR R1", Reading::Homed),
                ("PR ST", Reading::Stall),
                ("PR C2", Reading::Encoder),
            ];
            for (query, reading) in readings {
                requests.push(Request::query(line(channel, query), Step::Read { channel, reading }));
            }
        }
        requests
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        if let DriverCommand::Raw { text } = command {
            if text.trim_start().to_ascii_uppercase().starts_with("PR") {
                return Ok(vec![Request::query(line(channel, text), Step::RawQuery { channel })]);
            }
        }
        let lines = self.mcode(channel, command)?;
        if lines.is_empty() {
            return Ok(Vec::new());
        }
        let started = match command {
            DriverCommand::Home { .. } => Started::HomeSearch,
            DriverCommand::Move { .. } | DriverCommand::MoveVelocity { .. } => Started::Motion,
            _ => Started::Nothing,
        };
        match command {
            // A search stopped referenced nothing.
            DriverCommand::Stop { .. } => (self.motor(channel).homing, self.motor(channel).stopped) = (false, true),
            DriverCommand::Home { .. } => self.motor(channel).stopped = false,
            _ => {}
        }
        let mut requests: Vec<Request<Step>> =
            lines.iter().map(|code| Request::silent(line(channel, code), Step::Command { channel })).collect();
        requests.push(Request::query(line(channel, "PR ER"), Step::Errors { channel, started }));
        Ok(requests)
    }

    fn scale(&self, _channel: usize) -> Scale {
        // Counts: what one is in EGU is the lab's mechanics.
        Scale::motor_steps()
    }

    fn reply(&mut self, request: &Request<Step>, frame: &[u8]) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let text = line_text(frame, INPUT_TERMINATOR);
        let text = text.trim();
        let error = |why| ReplyError::new(request, frame, why);
        let number = || text.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| error("not a number"));
        match request.step {
            Step::Version { channel } if !text.is_empty() => {
                self.identities.read(channel, text);
                Ok(vec![ReplyEvent::Found(Finding::Identity(format!("MDrive {channel}: firmware {text}")))])
            }
            Step::Version { .. } => Err(error("no firmware version")),
            Step::Encoder { channel } => {
                self.motor(channel).encoder = number()? > 0.0;
                Ok(Vec::new())
            }
            Step::InputFunction { channel, input } => {
                // `function,active,sink`: 1 home, 2 limit +, 3 limit −.
                let function = text.split(',').next().and_then(|f| f.trim().parse::<u8>().ok());
                let slot = match function.ok_or_else(|| error("not an input set-up"))? {
                    1 => Some(0),
                    2 => Some(1),
                    3 => Some(2),
                    _ => None,
                };
                if let Some(slot) = slot {
                    self.motor(channel).inputs[slot] = Some(input);
                }
                Ok(Vec::new())
            }
            // Counts, flags and inputs are whole numbers: anything else (the firmware's "3.010",
            // a reply taken for another's) is not a reading.
            Step::Read { channel, reading } => {
                let whole = text.parse::<i64>().map_err(|_| error("not a whole number"))?;
                Ok(self.read(channel, reading, whole as f64))
            }
            Step::Errors { channel, started } => {
                let code = text.parse::<u32>().map_err(|_| error("not an error number"))?;
                if code != 0 {
                    return Ok(motor_error(channel, code));
                }
                let motor = self.motor(channel);
                match started {
                    Started::Nothing => {}
                    Started::Motion => motor.moving_since_command = true,
                    Started::HomeSearch => (motor.moving_since_command, motor.homing) = (true, !motor.stopped),
                }
                Ok(Vec::new())
            }
            Step::MotionEnded { channel } => {
                let code = text.parse::<u32>().map_err(|_| error("not an error number"))?;
                let homing = std::mem::take(&mut self.motor(channel).homing);
                match code {
                    0 if homing => Ok(vec![ReplyEvent::FollowUp(vec![Request::silent(
                        line(channel, "R1=1"),
                        Step::Homed { channel },
                    )])]),
                    0 => Ok(Vec::new()),
                    // A motion ended on a limit switch: the limit bits say so; only a search
                    // that ended there failed.
                    LIMIT_PLUS | LIMIT_MINUS if !homing => Ok(vec![ReplyEvent::FollowUp(vec![Request::silent(
                        line(channel, "ER=0"),
                        Step::ClearError { channel },
                    )])]),
                    code => Ok(motor_error(channel, code)),
                }
            }
            Step::RawQuery { .. } => Ok(Vec::new()),
            Step::Homed { .. } | Step::Command { .. } | Step::ClearError { .. } => {
                Err(error("a silent command answered"))
            }
        }
    }
}
