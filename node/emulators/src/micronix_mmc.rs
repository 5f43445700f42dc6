//! The Micronix USA MMC-100 modular motion controller (the MMC-200 speaks the same command
//! set): one module an axis, up to 99 modules daisy-chained on one serial line, one ASCII
//! command line at a time (`1MVA1.5`, `2POS?`), only read operations (`?`) answered, every
//! other outcome, errors included, kept in the module's error buffer for `ERR?`.
//!
//! # Witnesses
//!
//! 1. Micronix USA, "MMC-200 Series" reference manual, Rev 3.02 (as published on
//!    manualshive.com; only its pages 5-11 and 5-72 could be read). Section 5.1/5.2 gave the
//!    command line: an axis number 0 to 99 (0 = every controller at once), a command of
//!    always three letters, then the parameter; `?` instead of a parameter is a read
//!    operation; up to three parameters separated by `,`; all white space ignored
//!    (`4 TRM 13 , 45` is `4TRM13,45`); commands on one line separated by `;` and executed in
//!    order; a line ends in a terminator ("EX: carriage return"); up to 8 commands a line;
//!    only one read operation a line; positions in mm (degrees on rotary stages). Page 5-72
//!    (`STA`) gave the status byte, an integer 0 to 255 from `nSTA?`: bit 7 ERR (one or more
//!    errors; `ERR?` or `CER` clears), 6 ACC (acceleration phase), 5 CNST (constant velocity
//!    phase), 4 DEC (deceleration phase), 3 STP (stage stopped; in closed loop: in the
//!    deadband), 2 PGM (a program is running), 1 PLS (positive switch active), 0 NLS
//!    (negative switch active); and two error numbers: `STA?` without an axis is "read
//!    operation with missing axis number [27]", `nSTA` without `?` is "missing read operation
//!    parameter [28]".
//! 2. The EPICS driver module motorMicronix (epics-motor/motorMicronix, R1-2, 2026-01-22), used
//!    only for the bytes a client sends and reads: commands end with `\r` and replies with
//!    `\n\r` (its example `st.cmd`); set commands are written without reading anything back
//!    (no reply comes); read replies begin with `#`: `nVER?` answers a string beginning
//!    `#MMC-100` (or `#MMC-200`, `#MMC-103`, `#MMC-110`, `#MMC-ETH`); `nPOS?` answers
//!    `#<theoretical>,<encoder>` in mm with six decimals (`#0.000000,0.000000`); `nSTA?`
//!    answers `#8`; `nFBK?` `#0` (0 open loop, 1 to 3 closed loop), `nREZ?` (MMC-1xx: steps
//!    per µm), `nENC?` (encoder resolution, µm a count), `nVMX?`, `nMOT?` answer `#<n>`. The
//!    client sends `VEL`/`ACC`/`DEC`/`JAC` (mm/s, mm/s²) with three decimals, `MVA`/`MVR`
//!    (mm) with six, `HCG0`/`HCG1` then `HOM` to home, `JOG<percent of VMX>` (signed, at most
//!    100 in size) to jog, `STP` to stop, `ZRO` to zero the position, `MOT0`/`MOT1`, and `CER`
//!    when status bit 7 is set.
//! 3. Two public client programs for the MMC-100 (constants only, no logic taken):
//!    Magneto.Desktop's `MicronixConstants.cs` lists the error numbers with their names (10
//!    receive buffer overrun, 11 motor disabled, 12 no encoder detected, 13 index not found,
//!    14 home requires encoder, 20 command is read only, 21 one read operation per line, 22
//!    too many commands on line, 23 line character limit exceeded, 24 missing axis number, 25
//!    malformed command, 26 invalid command, 27 global read operation request, 28 invalid
//!    parameter type, 29 invalid character in parameter, 30 command cannot be used in global
//!    context, 31 parameter out of bounds, 32 incorrect jog velocity request, 36 command
//!    cannot be executed during motion, 38 read not available for this command, 50 limit
//!    activated, 51 end of travel limit, 52 home in progress, and others) and `ERR?` as "read
//!    and clear errors"; vxl_drivers' MMC tests show an `ERR?` reply as lines
//!    `#11 - Motor Disabled [MVA]` (number, text, the command in brackets) separated by `\n`,
//!    the last followed by `\n\r`, and `EST`, `MLN`, `MLP`, `HOM?`, `SAV`, `AMX` among the
//!    commands.
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Model and identification**: an MMC-100; `nVER?` answers `#MMC-100 v1.4.53`. The
//!   MMC-200's own `UST` (microsteps) is not an MMC-100 command: error 26. Commands not
//!   listed here (programs, triggers, soft limits, `LIM`, `DBD`, `WST`...) are error 26 too.
//! - **Units.** One step of the simulated axis is 1 nm (0.000001 mm): a position of `x` mm is
//!   `x`·10⁶ steps, speeds mm/s and accelerations mm/s² likewise. `REZ?` answers `#1000`
//!   (steps per µm) and `ENC?` `#0.001` (µm a count), so a client deriving its resolution
//!   from either also counts in nm. Positions are answered with six decimals (whole steps).
//!   Settings (`VEL?`, `ACC?`, `DEC?`, `JAC?`, `VMX?`, `AMX?`) are answered with three.
//! - **Channels**: axis numbers 1 to `channels` (at least 1, at most 99), channel n = axis n.
//!   A line addressed to an axis number no module has is answered by nobody and counted as
//!   malformed.
//! - **Terminators**: `\r` or `\n` ends a command line (so `\r\n` too; the empty line between
//!   is skipped). Replies end with `\n\r`. Lower-case command letters are accepted.
//! - **Errors** are never answered on the wire: each goes into the addressed module's error
//!   buffer (at most 10, the later ones dropped) and sets status bit 7 until `ERR?` (which
//!   answers and clears them) or `CER`. With no errors `ERR?` answers `#0 - No Error`. The
//!   texts are the names of witness 3 in title case. A line-level error (more than 8
//!   commands: 22, more than one read: 21; nothing on the line is executed) goes to every
//!   module the line addresses; a command without an axis number (24, or 27 for a read) and a
//!   read addressed to axis 0 (27) go to every module; more than 128 bytes without a
//!   terminator is error 23 in every module (the bytes are lost). An unknown command is 26,
//!   a command whose name is not three letters 25, `?` on a set-only command 38, a parameter
//!   on a read-only one 20 (none: 28), a missing or non-numeric parameter 28, a character
//!   other than digits, sign and point 29, a value out of range 31, a jog beyond ±100 % 32.
//!   These are counted as malformed; refusals for the axis's state are not: a motion with
//!   the motor off (`MOT0`) is 11, a motion while a home search runs 52, `ZRO` or `FBK`
//!   while moving 36, closed loop (`FBK1`-`3`) without an encoder 12, a motion (other than
//!   `MLN`/`MLP`) ended by a limit switch 50.
//! - **Motion.** `MVA`/`MVR` ramp at `ACC` up to `VEL`; `STP` decelerates at `DEC`; `EST`
//!   stops at once; `JOG` runs at the signed percentage of `VMX` with `JAC` (`JOG0` ramps
//!   down at `JAC`); `MLN`/`MLP` run at `VEL` to the negative/positive switch and stop there
//!   without an error. A new motion replaces one in progress. `HOM` searches the home switch
//!   (in the direction `HCG` sets: 0 negative, 1 positive) at `VEL` and sets the position to
//!   0 there; no encoder is required. `HOM?` answers `#1` once a home search has completed
//!   since power-on, else `#0`. The phase bits follow the profile: constant velocity at
//!   `VEL`, deceleration once the remaining distance is what stopping takes (or after `STP`).
//! - **Power-on**: every axis at rest at 0, motor on, open loop (`FBK` 0), `VEL` 1.000,
//!   `VMX` 10.000 mm/s, `ACC`, `DEC`, `JAC` 10.000, `AMX` 500.000 mm/s², `HCG` 0. Bounds: `VEL`
//!   above 0 up to `VMX`; `ACC`/`DEC`/`JAC` above 0 up to `AMX`; `VMX` up to 1000, `AMX` up to
//!   10000; positions within ±1000 mm. `SAV` is accepted and does nothing.
//! - **`raise_error`** puts error 10 (receive buffer overrun) in the module's buffer, as if
//!   the last command had been lost.

use crate::emulator::axes;
use crate::{Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

/// The protocol's name, as launch files give it.
const NAME: &str = "micronix_mmc";

/// Modules on one line at most (axis numbers 1 to 99).
const MAX_AXES: usize = 99;

/// Commands a line at most.
const MAX_COMMANDS: usize = 8;

/// Bytes without a terminator before the input buffer overflows.
const INPUT_BUFFER: usize = 128;

/// Errors a module's buffer keeps.
const ERROR_DEPTH: usize = 10;

/// The reply terminator.
const END: &str = "\n\r";

/// The answer to `VER?`, without its `#`.
const VERSION: &str = "MMC-100 v1.4.53";

/// Steps (nm) in one mm.
const STEPS_PER_MM: f64 = 1e6;

/// What goes wrong, by the controller's error number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Fault {
    Overrun = 10,
    MotorDisabled = 11,
    NoEncoder = 12,
    ReadOnly = 20,
    OneRead = 21,
    TooManyCommands = 22,
    LineLimit = 23,
    MissingAxis = 24,
    Malformed = 25,
    InvalidCommand = 26,
    GlobalRead = 27,
    ParameterType = 28,
    ParameterCharacter = 29,
    OutOfBounds = 31,
    JogVelocity = 32,
    DuringMotion = 36,
    NoRead = 38,
    LimitActivated = 50,
    HomeInProgress = 52,
}

impl Fault {
    fn text(self) -> &'static str {
        match self {
            Fault::Overrun => "Receive Buffer Overrun",
            Fault::MotorDisabled => "Motor Disabled",
            Fault::NoEncoder => "No Encoder Detected",
            Fault::ReadOnly => "Command Is Read Only",
            Fault::OneRead => "One Read Operation Per Line",
            Fault::TooManyCommands => "Too Many Commands On Line",
            Fault::LineLimit => "Line Character Limit Exceeded",
            Fault::MissingAxis => "Missing Axis Number",
            Fault::Malformed => "Malformed Command",
            Fault::InvalidCommand => "Invalid Command",
            Fault::GlobalRead => "Global Read Operation Request",
            Fault::ParameterType => "Invalid Parameter Type",
            Fault::ParameterCharacter => "Invalid Character In Parameter",
            Fault::OutOfBounds => "Parameter Out Of Bounds",
            Fault::JogVelocity => "Incorrect Jog Velocity Request",
            Fault::DuringMotion => "Command Cannot Be Executed During Motion",
            Fault::NoRead => "Read Not Available For This Command",
            Fault::LimitActivated => "Limit Activated",
            Fault::HomeInProgress => "Home In Progress",
        }
    }

    /// The request itself was wrong (the client's fault), not refused for the axis's state.
    fn is_malformed(self) -> bool {
        matches!(self as u8, 20..=32 | 38)
    }
}

/// A command's parameter part.
#[derive(Debug, PartialEq)]
enum Arg {
    None,
    Read,
    Value(String),
}

/// A command's name (upper case) and parameter, or why it cannot be read.
type Body = Result<(String, Arg), Fault>;

/// What kind of motion runs.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    Move,
    Jog,
    Home,
    ToLimit,
}

/// The motion in progress, for the phase bits and the end-of-motion checks.
#[derive(Debug)]
struct Motion {
    kind: Kind,
    /// The command that started it.
    command: String,
    /// Where it ends, physical steps (None for a jog).
    target: Option<f64>,
    /// Cruise speed, steps/s.
    cruise: f64,
    /// Acceleration, steps/s².
    acceleration: f64,
    /// `STP` (or `JOG0`) was sent: decelerating.
    stopping: bool,
}

/// One MMC module and the stage behind it.
#[derive(Debug)]
struct Axis {
    sim: SimAxis,
    /// VEL, VMX (mm/s); ACC, DEC, JAC, AMX (mm/s²).
    velocity: f64,
    max_velocity: f64,
    acceleration: f64,
    deceleration: f64,
    jog_acceleration: f64,
    max_acceleration: f64,
    /// HCG: home towards the positive side.
    home_positive: bool,
    /// FBK, 0 to 3.
    feedback: u8,
    /// MOT.
    motor_on: bool,
    errors: VecDeque<(Fault, Option<String>)>,
    motion: Option<Motion>,
}

impl Axis {
    fn new(sim: SimAxis) -> Self {
        Self {
            sim,
            velocity: 1.0,
            max_velocity: 10.0,
            acceleration: 10.0,
            deceleration: 10.0,
            jog_acceleration: 10.0,
            max_acceleration: 500.0,
            home_positive: false,
            feedback: 0,
            motor_on: true,
            errors: VecDeque::new(),
            motion: None,
        }
    }

    fn record(&mut self, fault: Fault, command: Option<&str>) {
        if self.errors.len() < ERROR_DEPTH {
            self.errors.push_back((fault, command.map(str::to_string)));
        }
    }

    /// The step counter (theoretical position), steps.
    fn counter(&self) -> f64 {
        self.sim.status().position
    }

    /// The encoder reading, steps (0 without an encoder).
    fn encoder(&self) -> f64 {
        let ratio = self.sim.config().encoder_counts_per_step.unwrap_or(1.0);
        self.sim.state().encoder.map_or(0.0, |counts| counts / ratio)
    }

    /// The `STA` byte.
    fn status(&self) -> u8 {
        let state = self.sim.state();
        let mut byte = u8::from(state.low_limit) | (u8::from(state.high_limit) << 1);
        if !self.sim.is_moving() {
            byte |= 1 << 3;
        } else if let Some(m) = &self.motion {
            let speed = state.velocity.abs();
            let braking = m.target.is_some_and(|target| {
                (target - state.position).abs() <= speed * speed / (2.0 * m.acceleration) * (1.0 + 1e-6) + 1e-6
            });
            byte |= if m.stopping || (braking && speed > 0.0) {
                1 << 4
            } else if speed >= m.cruise * (1.0 - 1e-6) {
                1 << 5
            } else {
                1 << 6
            };
        }
        if !self.errors.is_empty() {
            byte |= 1 << 7;
        }
        byte
    }

    /// Start a motion of `kind` unless the axis's state refuses it.
    fn may_move(&self) -> Result<(), Fault> {
        if !self.motor_on {
            return Err(Fault::MotorDisabled);
        }
        if self.sim.is_moving() && self.motion.as_ref().is_some_and(|m| m.kind == Kind::Home) {
            return Err(Fault::HomeInProgress);
        }
        Ok(())
    }

    fn begin(&mut self, kind: Kind, command: &str, target: Option<f64>, cruise: f64, acceleration: f64) {
        self.motion =
            Some(Motion { kind, command: command.to_string(), target, cruise, acceleration, stopping: false });
    }

    /// The motion ended: a limit switch that ended it is an error.
    fn settle(&mut self) {
        if self.sim.is_moving() {
            return;
        }
        if let Some(motion) = self.motion.take() {
            let state = self.sim.state();
            if motion.kind != Kind::ToLimit && (state.low_limit || state.high_limit) {
                self.record(Fault::LimitActivated, Some(&motion.command));
            }
        }
    }

    fn stop(&mut self, deceleration: f64) {
        if !self.sim.is_moving() {
            return;
        }
        self.sim.stop(deceleration * STEPS_PER_MM);
        if deceleration <= 0.0 {
            self.motion = None;
        } else if let Some(m) = &mut self.motion {
            m.stopping = true;
        }
    }
}

/// A serial line with MMC-100 modules at axis numbers 1 … n.
pub struct MmcEmulator {
    axes: Vec<Axis>,
    lines: Lines,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl MmcEmulator {
    /// A line with `channels` modules (one at least, 99 at most) at axis numbers 1 to
    /// `channels`.
    pub fn new(channels: usize, mechanics: &SimConfig) -> Self {
        let channels = channels.clamp(1, MAX_AXES);
        Self {
            axes: axes(channels, mechanics).into_iter().map(Axis::new).collect(),
            lines: Lines::new(b"\r", INPUT_BUFFER),
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    fn broadcast(&mut self, fault: Fault, command: Option<&str>) {
        for axis in &mut self.axes {
            axis.record(fault, command);
        }
    }

    /// One command line: the reply to its read operation, if it has one that succeeds.
    fn line(&mut self, text: &str) -> Option<String> {
        let pieces: Vec<String> = text
            .split(';')
            .map(|piece| piece.chars().filter(|c| !c.is_ascii_whitespace()).collect::<String>())
            .filter(|piece| !piece.is_empty())
            .collect();
        let parsed: Vec<(Option<usize>, Body)> = pieces.iter().map(|piece| parse(piece)).collect();
        let reads = parsed.iter().filter(|(_, body)| matches!(body, Ok((_, Arg::Read)))).count();
        let refusal = if parsed.len() > MAX_COMMANDS {
            Some(Fault::TooManyCommands)
        } else if reads > 1 {
            Some(Fault::OneRead)
        } else {
            None
        };
        if let Some(fault) = refusal {
            self.malformed += 1;
            // Once in each module the line addresses (every module for axis 0).
            let global = parsed.iter().any(|(axis, _)| *axis == Some(0));
            for (index, axis) in self.axes.iter_mut().enumerate() {
                if global || parsed.iter().any(|(n, _)| *n == Some(index + 1)) {
                    axis.record(fault, None);
                }
            }
            return None;
        }
        let mut reply = None;
        for (axis, body) in parsed {
            if let Some(answer) = self.route(axis, body) {
                reply = Some(answer);
            }
        }
        reply
    }

    /// One command, to the module(s) its axis number names.
    fn route(&mut self, axis: Option<usize>, body: Body) -> Option<String> {
        let channels = self.axes.len();
        match (axis, body) {
            (None, body) => {
                let fault = if matches!(body, Ok((_, Arg::Read))) { Fault::GlobalRead } else { Fault::MissingAxis };
                self.malformed += 1;
                self.broadcast(fault, body.as_ref().ok().map(|(name, _)| name.as_str()));
                None
            }
            (Some(0), Ok((name, Arg::Read))) => {
                self.malformed += 1;
                self.broadcast(Fault::GlobalRead, Some(&name));
                None
            }
            (Some(0), Ok((name, arg))) => {
                let mut refused = false;
                for index in 0..channels {
                    refused |= self.run(index, &name, &arg).is_err_and(Fault::is_malformed);
                }
                self.malformed += usize::from(refused);
                None
            }
            (Some(0), Err(fault)) => {
                self.malformed += 1;
                self.broadcast(fault, None);
                None
            }
            (Some(n), body) if n <= channels => match body {
                Ok((name, arg)) => match self.run(n - 1, &name, &arg) {
                    Ok(reply) => reply,
                    Err(fault) => {
                        self.malformed += usize::from(fault.is_malformed());
                        None
                    }
                },
                Err(fault) => {
                    self.malformed += 1;
                    self.axes[n - 1].record(fault, None);
                    None
                }
            },
            // No module has that axis number: nobody answers.
            (Some(_), _) => {
                self.malformed += 1;
                None
            }
        }
    }

    /// Carry out `name` on axis `index`; a failure goes into its error buffer.
    fn run(&mut self, index: usize, name: &str, arg: &Arg) -> Result<Option<String>, Fault> {
        let axis = &mut self.axes[index];
        execute(axis, name, arg).inspect_err(|&fault| axis.record(fault, Some(name)))
    }
}

/// Split one command into its axis number (None when missing; a number no module can have
/// when too long) and its name and parameter.
fn parse(text: &str) -> (Option<usize>, Body) {
    let digits = text.bytes().take_while(u8::is_ascii_digit).count();
    let axis = (digits > 0).then(|| if digits > 2 { usize::MAX } else { text[..digits].parse().unwrap_or(usize::MAX) });
    let rest = &text[digits..];
    let name = rest.get(..3).filter(|n| n.bytes().all(|b| b.is_ascii_alphabetic()));
    let Some(name) = name else { return (axis, Err(Fault::Malformed)) };
    let arg = match &rest[3..] {
        "" => Arg::None,
        "?" => Arg::Read,
        value if value.contains('?') => return (axis, Err(Fault::Malformed)),
        value => Arg::Value(value.to_string()),
    };
    (axis, Ok((name.to_ascii_uppercase(), arg)))
}

/// A decimal number: digits, a sign, a point.
fn number(text: &str) -> Result<f64, Fault> {
    if !text.bytes().all(|b| b.is_ascii_digit() || b == b'.' || b == b'+' || b == b'-') {
        return Err(Fault::ParameterCharacter);
    }
    let value: f64 = text.parse().map_err(|_| Fault::ParameterType)?;
    if value.is_finite() {
        Ok(value)
    } else {
        Err(Fault::OutOfBounds)
    }
}

/// A number of `arg` within `low` (exclusive when `open`) and `high`.
fn bounded(arg: &Arg, low: f64, open: bool, high: f64) -> Result<f64, Fault> {
    let Arg::Value(text) = arg else {
        return Err(if *arg == Arg::Read { Fault::NoRead } else { Fault::ParameterType });
    };
    let value = number(text)?;
    let above = if open { value > low } else { value >= low };
    if above && value <= high {
        Ok(value)
    } else {
        Err(Fault::OutOfBounds)
    }
}

/// A position in mm with six decimals, from steps (nm).
fn mm(steps: f64) -> String {
    let n = steps.round() as i64;
    let sign = if n < 0 { "-" } else { "" };
    let size = n.unsigned_abs();
    format!("{sign}{}.{:06}", size / 1_000_000, size % 1_000_000)
}

/// Carry out `name` with `arg` on `axis`: the reply to a read, or the fault.
fn execute(axis: &mut Axis, name: &str, arg: &Arg) -> Result<Option<String>, Fault> {
    let setting = |value: f64| Ok(Some(format!("{value:.3}")));
    // Read-only commands, then commands both read and set, then set-only ones.
    match (name, arg) {
        ("POS", Arg::Read) => return Ok(Some(format!("{},{}", mm(axis.counter()), mm(axis.encoder())))),
        ("STA", Arg::Read) => return Ok(Some(axis.status().to_string())),
        ("VER", Arg::Read) => return Ok(Some(VERSION.to_string())),
        ("REZ", Arg::Read) => return Ok(Some("1000".to_string())),
        ("ENC", Arg::Read) => return Ok(Some("0.001".to_string())),
        ("ERR", Arg::Read) => {
            if axis.errors.is_empty() {
                return Ok(Some("0 - No Error".to_string()));
            }
            let lines: Vec<String> = axis
                .errors
                .drain(..)
                .map(|(fault, command)| match command {
                    Some(command) => format!("{} - {} [{command}]", fault as u8, fault.text()),
                    None => format!("{} - {}", fault as u8, fault.text()),
                })
                .collect();
            return Ok(Some(lines.join("\n#")));
        }
        ("POS" | "STA" | "VER" | "REZ" | "ENC" | "ERR", Arg::None) => return Err(Fault::ParameterType),
        ("POS" | "STA" | "VER" | "REZ" | "ENC" | "ERR", Arg::Value(_)) => return Err(Fault::ReadOnly),
        ("VEL", Arg::Read) => return setting(axis.velocity),
        ("VMX", Arg::Read) => return setting(axis.max_velocity),
        ("ACC", Arg::Read) => return setting(axis.acceleration),
        ("DEC", Arg::Read) => return setting(axis.deceleration),
        ("JAC", Arg::Read) => return setting(axis.jog_acceleration),
        ("AMX", Arg::Read) => return setting(axis.max_acceleration),
        ("FBK", Arg::Read) => return Ok(Some(axis.feedback.to_string())),
        ("MOT", Arg::Read) => return Ok(Some(u8::from(axis.motor_on).to_string())),
        ("HCG", Arg::Read) => return Ok(Some(u8::from(axis.home_positive).to_string())),
        ("HOM", Arg::Read) => return Ok(Some(u8::from(axis.sim.state().homed).to_string())),
        _ => {}
    }
    match name {
        "VEL" => axis.velocity = bounded(arg, 0.0, true, axis.max_velocity)?,
        "VMX" => {
            axis.max_velocity = bounded(arg, 0.0, true, 1000.0)?;
            axis.velocity = axis.velocity.min(axis.max_velocity);
        }
        "ACC" => axis.acceleration = bounded(arg, 0.0, true, axis.max_acceleration)?,
        "DEC" => axis.deceleration = bounded(arg, 0.0, true, axis.max_acceleration)?,
        "JAC" => axis.jog_acceleration = bounded(arg, 0.0, true, axis.max_acceleration)?,
        "AMX" => axis.max_acceleration = bounded(arg, 0.0, true, 10_000.0)?,
        "HCG" => axis.home_positive = bounded(arg, 0.0, false, 1.0)? >= 1.0,
        "FBK" => {
            let mode = bounded(arg, 0.0, false, 3.0)?;
            if mode.fract() != 0.0 {
                return Err(Fault::OutOfBounds);
            }
            if axis.sim.is_moving() {
                return Err(Fault::DuringMotion);
            }
            if mode >= 1.0 && axis.sim.config().encoder_counts_per_step.is_none() {
                return Err(Fault::NoEncoder);
            }
            axis.feedback = mode as u8;
        }
        "MOT" => {
            let on = bounded(arg, 0.0, false, 1.0)?;
            if on.fract() != 0.0 {
                return Err(Fault::OutOfBounds);
            }
            axis.motor_on = on >= 1.0;
            if !axis.motor_on {
                axis.sim.stop(0.0);
                axis.motion = None;
            }
            axis.sim.enable(axis.motor_on);
        }
        "MVA" | "MVR" => {
            let target = bounded(arg, -1000.0, false, 1000.0)? * STEPS_PER_MM;
            axis.may_move()?;
            let relative = name == "MVR";
            let physical = axis.sim.state().position;
            let end = if relative { physical + target } else { target - (axis.counter() - physical) };
            let (speed, acceleration) = (axis.velocity * STEPS_PER_MM, axis.acceleration * STEPS_PER_MM);
            axis.sim.move_to(target, relative, 0.0, speed, acceleration);
            axis.begin(Kind::Move, name, Some(end), speed, acceleration);
        }
        "JOG" => {
            let percent = match arg {
                Arg::Value(text) => number(text)?,
                Arg::Read => return Err(Fault::NoRead),
                Arg::None => return Err(Fault::ParameterType),
            };
            if percent.abs() > 100.0 {
                return Err(Fault::JogVelocity);
            }
            axis.may_move()?;
            if percent == 0.0 {
                axis.stop(axis.jog_acceleration);
                return Ok(None);
            }
            let velocity = percent / 100.0 * axis.max_velocity * STEPS_PER_MM;
            let acceleration = axis.jog_acceleration * STEPS_PER_MM;
            axis.sim.move_velocity(0.0, velocity, acceleration);
            axis.begin(Kind::Jog, name, None, velocity.abs(), acceleration);
        }
        "STP" | "EST" | "ZRO" | "CER" | "SAV" | "HOM" | "MLN" | "MLP" => {
            match arg {
                Arg::None => {}
                Arg::Read => return Err(Fault::NoRead),
                Arg::Value(_) => return Err(Fault::ParameterType),
            }
            match name {
                "STP" => axis.stop(axis.deceleration),
                "EST" => axis.stop(0.0),
                "ZRO" if axis.sim.is_moving() => return Err(Fault::DuringMotion),
                "ZRO" => axis.sim.set_position(0.0),
                "CER" => axis.errors.clear(),
                "HOM" => {
                    axis.may_move()?;
                    let (speed, acceleration) = (axis.velocity * STEPS_PER_MM, axis.acceleration * STEPS_PER_MM);
                    axis.sim.home(axis.home_positive, 0.0, speed, acceleration);
                    axis.begin(Kind::Home, name, Some(axis.sim.config().home_switch), speed, acceleration);
                }
                "MLN" | "MLP" => {
                    axis.may_move()?;
                    let sign = if name == "MLP" { 1.0 } else { -1.0 };
                    let (speed, acceleration) = (axis.velocity * STEPS_PER_MM, axis.acceleration * STEPS_PER_MM);
                    axis.sim.move_velocity(0.0, sign * speed, acceleration);
                    axis.begin(Kind::ToLimit, name, None, speed, acceleration);
                }
                _ => {}
            }
        }
        _ => return Err(Fault::InvalidCommand),
    }
    Ok(None)
}

impl Emulator for MmcEmulator {
    fn name(&self) -> &'static str {
        NAME
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for axis in &mut self.axes {
            axis.sim.advance(now);
            axis.settle();
        }
        // `\n` ends a line as `\r` does.
        let bytes: Vec<u8> = bytes.iter().map(|&b| if b == b'\n' { b'\r' } else { b }).collect();
        let overflowed = self.lines.overflowed();
        let lines = self.lines.push(&bytes);
        if self.lines.overflowed() > overflowed {
            self.broadcast(Fault::LineLimit, None);
        }
        for line in lines {
            match std::str::from_utf8(&line).ok().filter(|t| t.is_ascii()) {
                Some(text) if text.trim().is_empty() => {}
                Some(text) => {
                    if let Some(reply) = self.line(text) {
                        self.output.push_back(format!("#{reply}{END}").into_bytes());
                    }
                }
                None => self.malformed += 1,
            }
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.output.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed + self.lines.overflowed()
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.axes.get_mut(channel.checked_sub(1)?).map(|axis| &mut axis.sim)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(axis) = channel.checked_sub(1).and_then(|i| self.axes.get_mut(i)) else { return false };
        axis.record(Fault::Overrun, None);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage;
    use std::time::Duration;

    fn at(ms: u64) -> Instant {
        Instant::ZERO + Duration::from_millis(ms)
    }

    /// A read: its one reply.
    fn ask(e: &mut MmcEmulator, now: Instant, line: &str) -> String {
        e.handle_input(now, format!("{line}\r").as_bytes());
        let reply = e.poll_transmit().expect("a read is answered");
        assert!(e.poll_transmit().is_none(), "one reply a line");
        String::from_utf8(reply).expect("ASCII")
    }

    /// A command: no reply.
    fn tell(e: &mut MmcEmulator, now: Instant, line: &str) {
        e.handle_input(now, format!("{line}\r").as_bytes());
        assert!(e.poll_transmit().is_none(), "{line} is not answered");
    }

    #[test]
    fn power_on_state_and_identification() {
        let mut e = MmcEmulator::new(2, &stage());
        assert_eq!(ask(&mut e, at(0), "1VER?"), "#MMC-100 v1.4.53\n\r");
        assert_eq!(ask(&mut e, at(0), "2POS?"), "#0.000000,0.000000\n\r");
        assert_eq!(ask(&mut e, at(0), "1STA?"), "#8\n\r");
        assert_eq!(ask(&mut e, at(0), "1ERR?"), "#0 - No Error\n\r");
        for (query, reply) in [
            ("1VEL?", "#1.000\n\r"),
            ("1VMX?", "#10.000\n\r"),
            ("1ACC?", "#10.000\n\r"),
            ("1DEC?", "#10.000\n\r"),
            ("1JAC?", "#10.000\n\r"),
            ("1AMX?", "#500.000\n\r"),
            ("1FBK?", "#0\n\r"),
            ("1REZ?", "#1000\n\r"),
            ("1ENC?", "#0.001\n\r"),
            ("1MOT?", "#1\n\r"),
            ("1HCG?", "#0\n\r"),
            ("1HOM?", "#0\n\r"),
            (" 2 sta ? ", "#8\n\r"),
        ] {
            assert_eq!(ask(&mut e, at(0), query), reply, "{query}");
        }
        for line in ["1VEL2.5", "1ACC20", "1DEC15", "1SAV", "1HCG1", "1CER"] {
            tell(&mut e, at(0), line);
        }
        assert_eq!(ask(&mut e, at(0), "1VEL?"), "#2.500\n\r");
        assert_eq!(ask(&mut e, at(0), "1HCG?"), "#1\n\r");
        assert_eq!(ask(&mut e, at(0), "2VEL?"), "#1.000\n\r");
        assert_eq!(e.malformed(), 0);
        assert_eq!(e.name(), "micronix_mmc");
    }

    #[test]
    fn a_move_goes_through_its_phases_and_arrives() {
        let mut e = MmcEmulator::new(1, &stage());
        // 1 mm/s, 10 mm/s²: 0.1 s ramps, 0.05 s at constant velocity.
        tell(&mut e, at(0), "1MVA0.15");
        assert_eq!(ask(&mut e, at(50), "1STA?"), "#64\n\r", "accelerating");
        assert_eq!(ask(&mut e, at(120), "1STA?"), "#32\n\r", "constant velocity");
        assert_eq!(ask(&mut e, at(200), "1STA?"), "#16\n\r", "decelerating");
        assert_eq!(ask(&mut e, at(300), "1STA?"), "#8\n\r", "stopped");
        assert_eq!(ask(&mut e, at(300), "1POS?"), "#0.150000,0.000000\n\r");
        tell(&mut e, at(300), "1MVR-0.05");
        assert_eq!(ask(&mut e, at(800), "1POS?"), "#0.100000,0.000000\n\r");
        tell(&mut e, at(800), "1ZRO");
        assert_eq!(ask(&mut e, at(800), "1POS?"), "#0.000000,0.000000\n\r");
        tell(&mut e, at(800), "1MVA-0.05");
        assert_eq!(ask(&mut e, at(1500), "1POS?"), "#-0.050000,0.000000\n\r");
        assert!((e.axis(1).unwrap().physical_position() - 50_000.0).abs() < 1e-6, "1 step = 1 nm");
        assert_eq!(ask(&mut e, at(1500), "1ERR?"), "#0 - No Error\n\r");
    }

    #[test]
    fn encoder_positions_are_read_through_the_encoder() {
        let mechanics = SimConfig { encoder_counts_per_step: Some(0.5), ..stage() };
        let mut e = MmcEmulator::new(1, &mechanics);
        tell(&mut e, at(0), "1FBK3");
        assert_eq!(ask(&mut e, at(0), "1FBK?"), "#3\n\r");
        tell(&mut e, at(0), "1MVR0.012345");
        assert_eq!(ask(&mut e, at(1000), "1POS?"), "#0.012345,0.012345\n\r");
        let mut plain = MmcEmulator::new(1, &stage());
        tell(&mut plain, at(0), "1FBK2");
        assert_eq!(ask(&mut plain, at(0), "1ERR?"), "#12 - No Encoder Detected [FBK]\n\r");
        assert_eq!(plain.malformed(), 0, "a refusal, not a malformed request");
    }

    #[test]
    fn a_jog_runs_until_stopped() {
        let mut e = MmcEmulator::new(1, &stage());
        tell(&mut e, at(0), "1VMX1");
        tell(&mut e, at(0), "1JOG-50");
        assert_eq!(ask(&mut e, at(100), "1STA?"), "#32\n\r", "at 0.5 mm/s");
        assert_eq!(ask(&mut e, at(200), "1POS?"), "#-0.087500,0.000000\n\r");
        tell(&mut e, at(200), "1STP");
        assert_eq!(ask(&mut e, at(210), "1STA?"), "#16\n\r", "ramping down at DEC");
        assert_eq!(ask(&mut e, at(300), "1STA?"), "#8\n\r");
        assert_eq!(ask(&mut e, at(300), "1POS?"), "#-0.100000,0.000000\n\r");
        tell(&mut e, at(300), "1JOG100");
        assert_eq!(ask(&mut e, at(350), "1STA?"), "#64\n\r");
        tell(&mut e, at(400), "1JOG0");
        assert_eq!(ask(&mut e, at(450), "1STA?"), "#16\n\r");
        tell(&mut e, at(500), "1JOG20");
        tell(&mut e, at(600), "1EST");
        assert_eq!(ask(&mut e, at(600), "1STA?"), "#8\n\r", "stopped at once");
        assert_eq!(ask(&mut e, at(600), "1ERR?"), "#0 - No Error\n\r");
    }

    #[test]
    fn limit_switches_stop_motion_and_report() {
        let mut e = MmcEmulator::new(1, &stage());
        tell(&mut e, at(0), "1MLP");
        assert_eq!(ask(&mut e, at(1000), "1STA?"), "#10\n\r", "on the positive switch, no error");
        assert_eq!(ask(&mut e, at(1000), "1POS?"), "#0.200000,0.000000\n\r");
        tell(&mut e, at(1000), "1MVA0.3");
        assert_eq!(ask(&mut e, at(2000), "1STA?"), "#138\n\r", "a move ended by the switch");
        assert_eq!(ask(&mut e, at(2000), "1ERR?"), "#50 - Limit Activated [MVA]\n\r");
        assert_eq!(ask(&mut e, at(2000), "1STA?"), "#10\n\r");
        tell(&mut e, at(2000), "1JOG-100");
        assert_eq!(ask(&mut e, at(3000), "1STA?"), "#137\n\r", "on the negative switch, in error");
        tell(&mut e, at(3000), "1CER");
        assert_eq!(ask(&mut e, at(3000), "1STA?"), "#9\n\r");
        tell(&mut e, at(3000), "1MLN");
        assert_eq!(ask(&mut e, at(3100), "1STA?"), "#9\n\r");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_home_search_zeroes_at_the_switch() {
        let mut e = MmcEmulator::new(2, &stage());
        tell(&mut e, at(0), "2MVA0.1");
        assert_eq!(ask(&mut e, at(1000), "2POS?"), "#0.100000,0.000000\n\r");
        tell(&mut e, at(1000), "2ZRO");
        tell(&mut e, at(1000), "2HCG0;2HOM");
        assert_eq!(ask(&mut e, at(1050), "2STA?"), "#64\n\r");
        assert_eq!(ask(&mut e, at(1050), "2HOM?"), "#0\n\r");
        tell(&mut e, at(1050), "2MVA0.5");
        assert_eq!(ask(&mut e, at(1050), "2ERR?"), "#52 - Home In Progress [MVA]\n\r");
        tell(&mut e, at(1050), "2ZRO");
        assert_eq!(ask(&mut e, at(1050), "2ERR?"), "#36 - Command Cannot Be Executed During Motion [ZRO]\n\r");
        assert_eq!(ask(&mut e, at(2000), "2STA?"), "#8\n\r");
        assert_eq!(ask(&mut e, at(2000), "2HOM?"), "#1\n\r");
        assert_eq!(ask(&mut e, at(2000), "2POS?"), "#0.000000,0.000000\n\r");
        assert!(e.axis(2).unwrap().physical_position().abs() < 1e-9, "on the switch");
        assert_eq!(ask(&mut e, at(2000), "1HOM?"), "#0\n\r");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn errors_are_kept_for_err_and_set_the_status_bit() {
        let mut e = MmcEmulator::new(2, &stage());
        for line in ["1XYZ", "1MVA?", "1POS", "1POS5", "1VEL0", "1VELabc", "1VEL", "1JOG150", "1MV", "1FBK1.5"] {
            tell(&mut e, at(0), line);
        }
        assert_eq!(ask(&mut e, at(0), "1STA?"), "#136\n\r");
        assert_eq!(
            ask(&mut e, at(0), "1ERR?"),
            "#26 - Invalid Command [XYZ]\n#38 - Read Not Available For This Command [MVA]\n\
             #28 - Invalid Parameter Type [POS]\n#20 - Command Is Read Only [POS]\n\
             #31 - Parameter Out Of Bounds [VEL]\n#29 - Invalid Character In Parameter [VEL]\n\
             #28 - Invalid Parameter Type [VEL]\n#32 - Incorrect Jog Velocity Request [JOG]\n\
             #25 - Malformed Command\n#31 - Parameter Out Of Bounds [FBK]\n\r"
        );
        assert_eq!(e.malformed(), 10);
        assert_eq!(ask(&mut e, at(0), "1STA?"), "#8\n\r", "read and cleared");
        assert_eq!(ask(&mut e, at(0), "2STA?"), "#8\n\r", "the other module saw none of it");
        tell(&mut e, at(0), "1MVA1e3");
        assert_eq!(ask(&mut e, at(0), "1ERR?"), "#29 - Invalid Character In Parameter [MVA]\n\r");
        tell(&mut e, at(0), "1MOT0");
        assert_eq!(ask(&mut e, at(0), "1MOT?"), "#0\n\r");
        tell(&mut e, at(0), "1MVA0.1");
        assert_eq!(ask(&mut e, at(0), "1ERR?"), "#11 - Motor Disabled [MVA]\n\r");
        assert!(e.raise_error(2));
        assert_eq!(ask(&mut e, at(0), "2STA?"), "#136\n\r");
        assert_eq!(ask(&mut e, at(0), "2ERR?"), "#10 - Receive Buffer Overrun\n\r");
        assert!(!e.raise_error(0) && !e.raise_error(3));
        assert_eq!(e.malformed(), 11, "refusals for the axis's state are not malformed");
    }

    #[test]
    fn line_rules_axis_numbers_and_global_commands() {
        let mut e = MmcEmulator::new(2, &stage());
        tell(&mut e, at(0), "1POS?;2POS?");
        assert_eq!(ask(&mut e, at(0), "1ERR?"), "#21 - One Read Operation Per Line\n\r");
        assert_eq!(ask(&mut e, at(0), "2ERR?"), "#21 - One Read Operation Per Line\n\r");
        tell(&mut e, at(0), "1CER;1CER;1CER;1CER;1CER;1CER;1CER;1CER;1VEL2");
        assert_eq!(ask(&mut e, at(0), "1ERR?"), "#22 - Too Many Commands On Line\n\r");
        assert_eq!(ask(&mut e, at(0), "1VEL?"), "#1.000\n\r", "nothing on the line was executed");
        tell(&mut e, at(0), "STA?");
        tell(&mut e, at(0), "0POS?");
        tell(&mut e, at(0), "MVA1");
        let both = "#27 - Global Read Operation Request [STA]\n#27 - Global Read Operation Request [POS]\n\
                    #24 - Missing Axis Number [MVA]\n\r";
        assert_eq!(ask(&mut e, at(0), "1ERR?"), both);
        assert_eq!(ask(&mut e, at(0), "2ERR?"), both);
        tell(&mut e, at(0), "3POS?");
        tell(&mut e, at(0), "100POS?");
        assert_eq!(e.malformed(), 7);
        // Two axes on one line; a global stop; a read after commands on the same line.
        assert_eq!(ask(&mut e, at(0), "1MVR0.01;2MVR-0.02;1STA?"), "#64\n\r");
        assert_eq!(ask(&mut e, at(1000), "2POS?"), "#-0.020000,0.000000\n\r");
        tell(&mut e, at(1000), "0JOG10");
        assert_eq!(ask(&mut e, at(1100), "2STA?"), "#32\n\r");
        tell(&mut e, at(1100), "0STP");
        assert_eq!(ask(&mut e, at(1300), "1STA?"), "#8\n\r");
        assert_eq!(ask(&mut e, at(1300), "2STA?"), "#8\n\r");
        assert_eq!(ask(&mut e, at(1300), "1pos?;"), "#0.110000,0.000000\n\r");
        assert!(e.axis(0).is_none() && e.axis(2).is_some() && e.axis(3).is_none());
        assert_eq!(MmcEmulator::new(150, &stage()).axes.len(), 99);
        assert_eq!(MmcEmulator::new(0, &stage()).axes.len(), 1);
    }

    #[test]
    fn lines_come_whole_from_any_pieces_and_garbage_is_survived() {
        let mut e = MmcEmulator::new(2, &stage());
        e.handle_input(at(0), b"1PO");
        assert!(e.poll_transmit().is_none());
        e.handle_input(at(0), b"S?\r\n2ST");
        e.handle_input(at(0), b"A?\n\xff\x00\r");
        let replies: Vec<Vec<u8>> = std::iter::from_fn(|| e.poll_transmit()).collect();
        assert_eq!(replies, [b"#0.000000,0.000000\n\r".to_vec(), b"#8\n\r".to_vec()]);
        assert_eq!(e.malformed(), 1, "the bytes that are not ASCII");
        e.handle_input(at(0), &[b'1'; 129]);
        assert_eq!(e.malformed(), 2, "an overflowing input buffer counts");
        assert_eq!(ask(&mut e, at(0), "2ERR?"), "#23 - Line Character Limit Exceeded\n\r");
        e.handle_input(at(0), b"\r;;\r  \r1\x01POS?\r");
        assert!(e.poll_transmit().is_none());
        assert_eq!(ask(&mut e, at(0), "1ERR?"), "#23 - Line Character Limit Exceeded\n#25 - Malformed Command\n\r");
    }

    #[test]
    fn random_bytes_never_panic() {
        let mut e = MmcEmulator::new(3, &stage());
        let alphabet = b"0123456789?;,.+-e MVAROSTPJGHZCEQLmva\r\n\xff";
        let mut seed: u64 = 0x2545_f491_4f6c_dd1d;
        for step in 0..20_000u64 {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            let byte = alphabet[(seed >> 33) as usize % alphabet.len()];
            e.handle_input(at(step), &[byte]);
            while e.poll_transmit().is_some() {}
        }
        assert!(e.malformed() > 0);
    }
}
