//! A PI C-884 class controller (also C-863 Mercury) speaking GCS 2.0 over TCP, written from
//! PI's documents: the C-863.12 user manual MS249E (v1.2.1, chapter 8 "GCS Commands": #4, #5,
//! #7, SRG?, POS, the error code table of 8.7), the GCS command reference PZ285EN (#4, #5, #7),
//! and what PI's own Python library pipython 2.11.0.6 sends and parses (`gcsmessages`: a reply
//! ends with an LF not preceded by a space, every line of a multi-line reply but the last ends
//! with " \n"; `getsupportedfunctions`: `HLP?` is read without its first and last line, each
//! other line starting with a command; `initparamconv`: `HPA?` lines `<id>=` then the type as the
//! fourth word; `isgcs30_by_qcsv`: `CSV?` ≤ 2.0 is GCS 2; `IsControllerReady`: #7 is 0xB1 or
//! 0xB0; `gcserror`: the error texts).
//!
//! The rules it follows:
//! - A command line ends with LF; a setter answers nothing, a query answers
//!   `{<axis>"="<value>}` lines (`SRG?`, `SPA?`: `<axis> <id>"="<value>`).
//! - A command the controller does not know, or cannot carry out, is not answered at all: its
//!   error code is kept for `ERR?`, which answers it and resets it to 0. Only the last error is
//!   kept.
//! - The single bytes #4 (status registers), #5 (moving axes), #7 (ready) and #24 (stop all) are
//!   commands of their own, acted on at once.
//! - At power-up every axis is unreferenced, its servo off, its position counting from 0
//!   wherever the stage stands, referencing mode on (`RON 1`). A move (`MOV`, `MVR`) is refused
//!   with error 5 while the servo is off or the axis unreferenced, with error 7 when its target
//!   lies beyond the travel range (`TMN?`/`TMX?`). `FRF`, `FNL`, `FPL` reference the axis; `POS`
//!   sets the position (and makes the axis referenced) only with `RON 0`, else error 88.
//! - `HLT` and `STP`/#24 stop and set error 10 ("Controller was stopped by command").
//!
//! Readings taken where the documents leave a choice:
//! - `HLT` sets error 10 whether or not the axis was moving (the manual says it sets 10, with no
//!   condition).
//! - `FRF`/`FNL`/`FPL` with the servo off are refused with error 5: its text names "move
//!   attempted with servo off", and a reference move is a move.
//! - `SPA?` echoes the parameter id as it was sent (`SPA? 1 0xE` → `1 0xE=…`).
//! - `HLP?`: the manual gives no example we could read; pipython's parser fixes its shape: a
//!   first line of header, one line per command starting with the command, a last line closing
//!   the list. Those are what this controller sends.
//! - `*IDN?`: the four comma-separated fields of IEEE 488.2, the model in the second (pipython
//!   takes its `devname` from there).
//!
//! Mechanics (`Gcs2Emulator::mechanics()`), in millimetres: a stage standing at 5 mm, its reference switch at
//! 0, limit switches at ±20 mm, a travel range of ±19.5 mm, 10000 counts per mm. Referencing at
//! the reference switch counts 0 there; at a limit switch, the switch's own distance (±20).

use crate::Emulator;
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};
use zmotor_msgs::bits::msta;

/// The travel range, mm (`TMN?`, `TMX?`).
const TRAVEL_MIN: f64 = -19.5;
const TRAVEL_MAX: f64 = 19.5;
/// Counts per mm: numerator (parameter 0xE) and denominator (0xF).
const COUNTS_NUMERATOR: f64 = 10_000.0;
const COUNTS_DENOMINATOR: f64 = 1.0;
/// The fastest closed-loop velocity, mm/s (parameter 0xA).
const VELOCITY_LIMIT: f64 = 50.0;
/// The highest acceleration and deceleration, mm/s² (parameters 0x4A, 0x4B).
const ACCELERATION_LIMIT: f64 = 1000.0;
/// The longest command line the controller takes.
const LINE_CAPACITY: usize = 256;

/// GCS error codes used here, as PI numbers them (MS249E 8.7, pipython `gcserror`).
mod code {
    pub(super) const NONE: u32 = 0;
    pub(super) const PARAM_SYNTAX: u32 = 1;
    pub(super) const UNKNOWN_COMMAND: u32 = 2;
    pub(super) const COMMAND_TOO_LONG: u32 = 3;
    pub(super) const MOVE_WITHOUT_REF_OR_NO_SERVO: u32 = 5;
    pub(super) const POS_OUT_OF_LIMITS: u32 = 7;
    pub(super) const VEL_OUT_OF_LIMITS: u32 = 8;
    pub(super) const STOP: u32 = 10;
    pub(super) const INVALID_AXIS_IDENTIFIER: u32 = 15;
    pub(super) const PARAM_OUT_OF_RANGE: u32 = 17;
    pub(super) const PARAM_NR: u32 = 24;
    pub(super) const INVALID_REAL_NR: u32 = 25;
    pub(super) const REF_WITH_REF_DISABLED: u32 = 50;
    pub(super) const UNKNOWN_PARAMETER: u32 = 54;
    pub(super) const PARAM_PROTECTION: u32 = 60;
    pub(super) const REF_MODE_IS_ON: u32 = 88;
    pub(super) const MOTION_ERROR: u32 = 1024;
}

/// The manual's text for each code this controller sets.
#[cfg(test)]
const ERROR_TEXTS: [(u32, &str); 17] = [
    (code::NONE, "No error"),
    (code::PARAM_SYNTAX, "Parameter syntax error"),
    (code::UNKNOWN_COMMAND, "Unknown command"),
    (code::COMMAND_TOO_LONG, "Command length out of limits or command buffer overrun"),
    (
        code::MOVE_WITHOUT_REF_OR_NO_SERVO,
        "Unallowable move attempted on unreferenced axis, or move attempted with servo off",
    ),
    (code::POS_OUT_OF_LIMITS, "Position out of limits"),
    (code::VEL_OUT_OF_LIMITS, "Velocity out of limits"),
    (code::STOP, "Controller was stopped by command"),
    (code::INVALID_AXIS_IDENTIFIER, "Invalid axis identifier"),
    (code::PARAM_OUT_OF_RANGE, "Parameter out of range"),
    (code::PARAM_NR, "Incorrect number of parameters"),
    (code::INVALID_REAL_NR, "Invalid floating point number"),
    (code::REF_WITH_REF_DISABLED, "Attempt to reference axis with referencing disabled"),
    (code::UNKNOWN_PARAMETER, "Unknown parameter"),
    (code::PARAM_PROTECTION, "Protected Param: current Command Level (CCL) too low"),
    (code::REF_MODE_IS_ON, "Move without referenced stage"),
    (code::MOTION_ERROR, "Motion error: position error too large, servo is switched off automatically"),
];

/// The codes that say the request itself could not be read: a driver's fault.
const UNREADABLE: [u32; 7] = [
    code::PARAM_SYNTAX,
    code::UNKNOWN_COMMAND,
    code::COMMAND_TOO_LONG,
    code::INVALID_AXIS_IDENTIFIER,
    code::PARAM_NR,
    code::INVALID_REAL_NR,
    code::UNKNOWN_PARAMETER,
];

/// The single-byte commands (#4, #5, #7, #24).
const REQUEST_STATUS: u8 = 4;
const REQUEST_MOTION: u8 = 5;
const REQUEST_READY: u8 = 7;
const STOP_ALL: u8 = 24;

/// `SRG?` register 1 and `#4`, bit by bit (MS249E, SRG?).
mod status {
    pub(super) const NEGATIVE_LIMIT: u16 = 1;
    pub(super) const REFERENCE_SWITCH: u16 = 1 << 1;
    pub(super) const POSITIVE_LIMIT: u16 = 1 << 2;
    pub(super) const ERROR: u16 = 1 << 8;
    pub(super) const SERVO: u16 = 1 << 12;
    pub(super) const MOTION: u16 = 1 << 13;
    pub(super) const REFERENCING: u16 = 1 << 14;
    pub(super) const ON_TARGET: u16 = 1 << 15;
}

/// The stage type `CST?` names for every axis.
const STAGE: &str = "ZMOTOR-EMULATED-STAGE";

/// The commands `HLP?` lists, with what they do.
const COMMANDS: [(&str, &str); 37] = [
    ("#4", "Request Status Register"),
    ("#5", "Request Motion Status"),
    ("#7", "Request Controller Ready Status"),
    ("#24", "Stop All Axes"),
    ("*IDN?", "Get Device Identification"),
    ("ACC", "Set Closed-Loop Acceleration"),
    ("ACC?", "Get Closed-Loop Acceleration"),
    ("CST?", "Get Assignment Of Stages To Axes"),
    ("CSV?", "Get Current Syntax Version"),
    ("DEC", "Set Closed-Loop Deceleration"),
    ("DEC?", "Get Closed-Loop Deceleration"),
    ("ERR?", "Get Error Number"),
    ("FNL", "Fast Reference Move To Negative Limit"),
    ("FPL", "Fast Reference Move To Positive Limit"),
    ("FRF", "Fast Reference Move To Reference Switch"),
    ("FRF?", "Get Referencing Result"),
    ("HLP?", "Get List Of Available Commands"),
    ("HLT", "Halt Motion Smoothly"),
    ("HPA?", "Get List Of Available Parameters"),
    ("LIM?", "Indicate Limit Switches"),
    ("MOV", "Set Target Position"),
    ("MOV?", "Get Target Position"),
    ("MVR", "Set Target Relative To Current Position"),
    ("ONT?", "Get On-Target State"),
    ("POS", "Set Real Position"),
    ("POS?", "Get Real Position"),
    ("RON", "Set Reference Mode"),
    ("RON?", "Get Reference Mode"),
    ("SAI?", "Get List Of Current Axis Identifiers"),
    ("SPA", "Set Volatile Memory Parameters"),
    ("SPA?", "Get Volatile Memory Parameters"),
    ("SRG?", "Query Status Register Value"),
    ("STP", "Stop All Axes"),
    ("SVO", "Set Servo Mode"),
    ("SVO?", "Get Servo Mode"),
    ("TMN?", "Get Minimum Commandable Position"),
    ("TMX?", "Get Maximum Commandable Position"),
];

/// Parameters (`SPA`, `SPA?`, `HPA?`): id, writable, type, description.
const PARAMETERS: [(u32, bool, &str, &str); 8] = [
    (0x0A, false, "FLOAT", "Maximum closed-loop velocity (phys. unit/s)"),
    (0x0B, true, "FLOAT", "Closed-loop acceleration (phys. unit/s2)"),
    (0x0C, true, "FLOAT", "Closed-loop deceleration (phys. unit/s2)"),
    (0x0E, false, "INT", "Numerator of the counts-per-physical-unit factor"),
    (0x0F, false, "INT", "Denominator of the counts-per-physical-unit factor"),
    (0x4A, false, "FLOAT", "Maximum closed-loop acceleration (phys. unit/s2)"),
    (0x4B, false, "FLOAT", "Maximum closed-loop deceleration (phys. unit/s2)"),
    (0x50, true, "FLOAT", "Velocity for reference moves (phys. unit/s)"),
];

/// Where a reference move is bound.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Reference {
    Switch,
    NegativeLimit,
    PositiveLimit,
}

/// One axis of the controller.
struct Axis {
    stage: SimAxis,
    servo: bool,
    reference_mode: bool,
    referenced: bool,
    reference_move: Option<Reference>,
    /// Halted: once at rest, the target becomes where it stopped.
    halting: bool,
    target: f64,
    velocity: f64,
    acceleration: f64,
    deceleration: f64,
    reference_velocity: f64,
}

impl Axis {
    /// An axis at power-up on `stage`: the position counts from 0 where it stands.
    fn power_up(mut stage: SimAxis) -> Self {
        stage.set_position(0.0);
        stage.enable(false);
        Axis {
            stage,
            servo: false,
            reference_mode: true,
            referenced: false,
            reference_move: None,
            halting: false,
            target: 0.0,
            velocity: 10.0,
            acceleration: 100.0,
            deceleration: 100.0,
            reference_velocity: 5.0,
        }
    }

    fn position(&self) -> f64 {
        self.stage.status().position
    }

    fn moving(&self) -> bool {
        self.stage.is_moving()
    }

    fn on_target(&self) -> bool {
        self.servo && !self.moving() && self.reference_move.is_none()
    }

    fn register(&self) -> u16 {
        let switches = self.stage.status().msta;
        [
            (status::NEGATIVE_LIMIT, switches & msta::MINUS_LS != 0),
            // High on the positive side of the reference switch (the manual's example 0x9002).
            (status::REFERENCE_SWITCH, self.stage.physical_position() > self.stage.config().home_switch),
            (status::POSITIVE_LIMIT, switches & msta::PLUS_LS != 0),
            (status::ERROR, false),
            (status::SERVO, self.servo),
            (status::MOTION, self.moving()),
            (status::REFERENCING, self.reference_move.is_some()),
            (status::ON_TARGET, self.on_target()),
        ]
        .into_iter()
        .filter(|(_, on)| *on)
        .fold(0, |bits, (bit, _)| bits | bit)
    }

    fn servo(&mut self, on: bool) {
        self.servo = on;
        self.stage.enable(on);
        if !on {
            self.reference_move = None;
        }
        self.target = self.position();
    }

    fn start_reference(&mut self, to: Reference) {
        self.referenced = false;
        self.reference_move = Some(to);
        let (v, a) = (self.reference_velocity, self.acceleration);
        match to {
            Reference::Switch => self.stage.home(true, 0.0, v, a),
            Reference::NegativeLimit => self.stage.move_velocity(0.0, -v, a),
            Reference::PositiveLimit => self.stage.move_velocity(0.0, v, a),
        }
    }

    /// A reference move at rest: the axis is referenced if it found what it looked for.
    fn finish_reference(&mut self) {
        let Some(to) = self.reference_move else { return };
        if self.moving() {
            return;
        }
        self.reference_move = None;
        let switches = self.stage.status().msta;
        self.referenced = match to {
            Reference::Switch => self.stage.on_home_switch(),
            Reference::NegativeLimit => switches & msta::MINUS_LS != 0,
            Reference::PositiveLimit => switches & msta::PLUS_LS != 0,
        };
        if self.referenced && to != Reference::Switch {
            // At a limit switch the position is the switch's distance from the reference.
            let at = self.stage.physical_position() - self.stage.config().home_switch;
            self.stage.set_position(at);
        }
        self.target = self.position();
    }

    fn parameter(&self, id: u32) -> Option<f64> {
        Some(match id {
            0x0A => VELOCITY_LIMIT,
            0x0B => self.acceleration,
            0x0C => self.deceleration,
            0x0E => COUNTS_NUMERATOR,
            0x0F => COUNTS_DENOMINATOR,
            0x4A | 0x4B => ACCELERATION_LIMIT,
            0x50 => self.reference_velocity,
            _ => return None,
        })
    }
}

/// A PI C-884 with axes `1` … `n` behind one TCP connection.
pub struct Gcs2Emulator {
    axes: Vec<Axis>,
    error: u32,
    line: Vec<u8>,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

/// A command's outcome: a reply (or none), or the error code it leaves.
type Outcome = Result<Option<String>, u32>;

/// A number as GCS sends it.
fn number(value: f64) -> String {
    format!("{value:.6}")
}

/// A parameter id, decimal or hexadecimal (`14`, `0xE`).
fn parameter_id(text: &str) -> Option<u32> {
    match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16).ok(),
        None => text.parse().ok(),
    }
}

fn real(text: &str) -> Result<f64, u32> {
    text.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or(code::INVALID_REAL_NR)
}

/// Lines of a reply: every one but the last ends with a space before its LF.
fn reply(lines: Vec<String>) -> String {
    lines.join(" \n")
}

impl Gcs2Emulator {
    /// The stage behind every axis, in millimetres (see the module documentation).
    pub fn mechanics() -> SimConfig {
        SimConfig {
            position: 5.0,
            high_limit_switch: Some(20.0),
            low_limit_switch: Some(-20.0),
            home_switch: 0.0,
            servo: true,
            ..SimConfig::default()
        }
    }

    /// A controller of `axes` axes on `mechanics` (mm), as at power-up.
    pub fn new(axes: usize, mechanics: &SimConfig) -> Self {
        Gcs2Emulator {
            axes: crate::emulator::axes(axes, mechanics).into_iter().map(Axis::power_up).collect(),
            error: code::NONE,
            line: Vec::new(),
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    fn axis_index(&self, name: &str) -> Result<usize, u32> {
        match name.parse::<usize>() {
            Ok(n) if (1..=self.axes.len()).contains(&n) => Ok(n - 1),
            _ => Err(code::INVALID_AXIS_IDENTIFIER),
        }
    }

    /// The axes named, or all of them when none is.
    fn axes_named(&self, names: &[&str]) -> Result<Vec<usize>, u32> {
        if names.is_empty() {
            Ok((0..self.axes.len()).collect())
        } else {
            names.iter().map(|name| self.axis_index(name)).collect()
        }
    }

    /// `{<axis> <value>}`.
    fn axis_values(&self, args: &[&str]) -> Result<Vec<(usize, f64)>, u32> {
        if args.is_empty() || !args.len().is_multiple_of(2) {
            return Err(code::PARAM_NR);
        }
        args.chunks(2).map(|pair| Ok((self.axis_index(pair[0])?, real(pair[1])?))).collect()
    }

    /// `{<axis> 0|1}`.
    fn axis_flags(&self, args: &[&str]) -> Result<Vec<(usize, bool)>, u32> {
        self.axis_values(args)?
            .into_iter()
            .map(|(i, v)| match v {
                0.0 => Ok((i, false)),
                1.0 => Ok((i, true)),
                _ => Err(code::PARAM_SYNTAX),
            })
            .collect()
    }

    fn per_axis(&self, args: &[&str], value: impl Fn(&Axis) -> String) -> Outcome {
        let lines = self.axes_named(args)?.into_iter().map(|i| format!("{}={}", i + 1, value(&self.axes[i])));
        Ok(Some(reply(lines.collect())))
    }

    fn command(&mut self, line: &str) -> Outcome {
        let mut words = line.split_whitespace();
        let Some(mnemonic) = words.next() else { return Ok(None) };
        let args: Vec<&str> = words.collect();
        // The mnemonic is not case-sensitive.
        let mnemonic = mnemonic.to_ascii_uppercase();
        let no_args = |outcome: Outcome| if args.is_empty() { outcome } else { Err(code::PARAM_NR) };
        match mnemonic.as_str() {
            "*IDN?" => no_args(Ok(Some(
                "(c)2026 Physik Instrumente (PI) GmbH & Co. KG, C-884.4DC, 0000000001, 1.3.4.2".into(),
            ))),
            "CSV?" => no_args(Ok(Some("2.0".into()))),
            "ERR?" => no_args(Ok(Some(std::mem::take(&mut self.error).to_string()))),
            "HLP?" => no_args(Ok(Some(help()))),
            "HPA?" => no_args(Ok(Some(parameter_help()))),
            "SAI?" => Ok(Some(reply((1..=self.axes.len()).map(|n| n.to_string()).collect()))),
            "POS?" => self.per_axis(&args, |a| number(a.position())),
            "MOV?" => self.per_axis(&args, |a| number(a.target)),
            "VEL?" => self.per_axis(&args, |a| number(a.velocity)),
            "ACC?" => self.per_axis(&args, |a| number(a.acceleration)),
            "DEC?" => self.per_axis(&args, |a| number(a.deceleration)),
            "TMN?" => self.per_axis(&args, |_| number(TRAVEL_MIN)),
            // The stage type assigned to each axis; the name is this emulator's (EPICS only
            // logs it).
            "CST?" => self.per_axis(&args, |_| STAGE.into()),
            "TMX?" => self.per_axis(&args, |_| number(TRAVEL_MAX)),
            "SVO?" => self.per_axis(&args, |a| u8::from(a.servo).to_string()),
            "RON?" => self.per_axis(&args, |a| u8::from(a.reference_mode).to_string()),
            "FRF?" => self.per_axis(&args, |a| u8::from(a.referenced).to_string()),
            "ONT?" => self.per_axis(&args, |a| u8::from(a.on_target()).to_string()),
            // The stage has a reference switch and limit switches.
            "TRS?" | "LIM?" => self.per_axis(&args, |_| "1".into()),
            "SRG?" => self.status_registers(&args),
            "SPA?" => self.parameters(&args),
            "SPA" => self.set_parameters(&args),
            "SVO" => {
                for (i, on) in self.axis_flags(&args)? {
                    self.axes[i].servo(on);
                }
                Ok(None)
            }
            "RON" => {
                for (i, on) in self.axis_flags(&args)? {
                    self.axes[i].reference_mode = on;
                }
                Ok(None)
            }
            "POS" => {
                let values = self.axis_values(&args)?;
                if values.iter().any(|(i, _)| self.axes[*i].reference_mode) {
                    return Err(code::REF_MODE_IS_ON);
                }
                for (i, position) in values {
                    let axis = &mut self.axes[i];
                    axis.stage.set_position(position);
                    axis.target = position;
                    axis.referenced = true;
                }
                Ok(None)
            }
            "MOV" | "MVR" => self.move_axes(mnemonic == "MVR", &args),
            "VEL" | "ACC" | "DEC" => self.set_motion(&mnemonic, &args),
            "FRF" | "FNL" | "FPL" => {
                let to = match mnemonic.as_str() {
                    "FRF" => Reference::Switch,
                    "FNL" => Reference::NegativeLimit,
                    _ => Reference::PositiveLimit,
                };
                let axes = self.axes_named(&args)?;
                if axes.iter().any(|i| !self.axes[*i].servo) {
                    return Err(code::MOVE_WITHOUT_REF_OR_NO_SERVO);
                }
                if axes.iter().any(|i| !self.axes[*i].reference_mode) {
                    return Err(code::REF_WITH_REF_DISABLED);
                }
                for i in axes {
                    self.axes[i].start_reference(to);
                }
                Ok(None)
            }
            "HLT" => {
                for i in self.axes_named(&args)? {
                    let axis = &mut self.axes[i];
                    axis.stage.stop(axis.deceleration);
                    axis.reference_move = None;
                    axis.halting = true;
                }
                Err(code::STOP)
            }
            "STP" => {
                if !args.is_empty() {
                    return Err(code::PARAM_NR);
                }
                self.stop_all();
                Err(code::STOP)
            }
            _ => Err(code::UNKNOWN_COMMAND),
        }
    }

    fn status_registers(&self, args: &[&str]) -> Outcome {
        let axes = if args.is_empty() {
            (0..self.axes.len()).collect()
        } else {
            if !args.len().is_multiple_of(2) {
                return Err(code::PARAM_NR);
            }
            let mut axes = Vec::new();
            for pair in args.chunks(2) {
                let axis = self.axis_index(pair[0])?;
                if pair[1] != "1" {
                    return Err(code::PARAM_OUT_OF_RANGE);
                }
                axes.push(axis);
            }
            axes
        };
        let lines = axes.into_iter().map(|i| format!("{} 1=0x{:X}", i + 1, self.axes[i].register()));
        Ok(Some(reply(lines.collect())))
    }

    fn parameters(&self, args: &[&str]) -> Outcome {
        if args.is_empty() || !args.len().is_multiple_of(2) {
            return Err(code::PARAM_NR);
        }
        let mut lines = Vec::new();
        for pair in args.chunks(2) {
            let axis = &self.axes[self.axis_index(pair[0])?];
            let value = parameter_id(pair[1]).and_then(|id| axis.parameter(id)).ok_or(code::UNKNOWN_PARAMETER)?;
            lines.push(format!("{} {}={value}", pair[0], pair[1]));
        }
        Ok(Some(reply(lines)))
    }

    fn set_parameters(&mut self, args: &[&str]) -> Outcome {
        if args.is_empty() || !args.len().is_multiple_of(3) {
            return Err(code::PARAM_NR);
        }
        let mut changes = Vec::new();
        for triple in args.chunks(3) {
            let i = self.axis_index(triple[0])?;
            let id = parameter_id(triple[1]).ok_or(code::UNKNOWN_PARAMETER)?;
            let value = real(triple[2])?;
            match PARAMETERS.iter().find(|p| p.0 == id) {
                None => return Err(code::UNKNOWN_PARAMETER),
                Some((_, false, ..)) => return Err(code::PARAM_PROTECTION),
                Some(_) => {}
            }
            let limit = if id == 0x50 { VELOCITY_LIMIT } else { ACCELERATION_LIMIT };
            if value <= 0.0 || value > limit {
                return Err(code::PARAM_OUT_OF_RANGE);
            }
            changes.push((i, id, value));
        }
        for (i, id, value) in changes {
            let axis = &mut self.axes[i];
            match id {
                0x0B => axis.acceleration = value,
                0x0C => axis.deceleration = value,
                _ => axis.reference_velocity = value,
            }
        }
        Ok(None)
    }

    fn set_motion(&mut self, mnemonic: &str, args: &[&str]) -> Outcome {
        let values = self.axis_values(args)?;
        let (limit, refusal) = if mnemonic == "VEL" {
            (VELOCITY_LIMIT, code::VEL_OUT_OF_LIMITS)
        } else {
            (ACCELERATION_LIMIT, code::PARAM_OUT_OF_RANGE)
        };
        if values.iter().any(|(_, v)| *v <= 0.0 || *v > limit) {
            return Err(refusal);
        }
        for (i, value) in values {
            let axis = &mut self.axes[i];
            match mnemonic {
                "VEL" => axis.velocity = value,
                "ACC" => axis.acceleration = value,
                _ => axis.deceleration = value,
            }
        }
        Ok(None)
    }

    /// MOV (absolute) or MVR (relative to the current target): every axis or none.
    fn move_axes(&mut self, relative: bool, args: &[&str]) -> Outcome {
        let mut targets = Vec::new();
        for (i, value) in self.axis_values(args)? {
            let axis = &self.axes[i];
            if !axis.servo || !axis.referenced || axis.reference_move.is_some() {
                return Err(code::MOVE_WITHOUT_REF_OR_NO_SERVO);
            }
            let target = if relative { axis.target + value } else { value };
            if !(TRAVEL_MIN..=TRAVEL_MAX).contains(&target) {
                return Err(code::POS_OUT_OF_LIMITS);
            }
            targets.push((i, target));
        }
        for (i, target) in targets {
            let axis = &mut self.axes[i];
            axis.target = target;
            let (v, a) = (axis.velocity, axis.acceleration);
            axis.stage.move_to(target, false, 0.0, v, a);
        }
        Ok(None)
    }

    /// STP and #24: every axis stops at once.
    fn stop_all(&mut self) {
        for axis in &mut self.axes {
            axis.stage.stop(0.0);
            axis.reference_move = None;
            axis.target = axis.position();
        }
    }

    fn single_byte(&mut self, byte: u8) {
        match byte {
            REQUEST_STATUS => {
                let registers: String = self.axes.iter().map(|a| format!("{:04X}", a.register())).collect();
                self.output.push_back(format!("0x{registers}\n").into_bytes());
            }
            REQUEST_MOTION => {
                let bits = self
                    .axes
                    .iter()
                    .enumerate()
                    .filter(|(_, a)| a.moving() || a.reference_move.is_some())
                    .fold(0u128, |bits, (i, _)| bits | 1u128.checked_shl(i as u32).unwrap_or(0));
                self.output.push_back(format!("{bits:X}\n").into_bytes());
            }
            REQUEST_READY => {
                // Not ready while a reference move runs (MS249E, #7).
                let ready = self.axes.iter().all(|a| a.reference_move.is_none());
                self.output.push_back(vec![if ready { 0xB1 } else { 0xB0 }, b'\n']);
            }
            _ => {
                self.stop_all();
                self.error = code::STOP;
            }
        }
    }

    fn execute_line(&mut self) {
        let line = std::mem::take(&mut self.line);
        if line.len() > LINE_CAPACITY {
            self.fail(code::COMMAND_TOO_LONG);
            return;
        }
        let text = String::from_utf8_lossy(&line);
        match self.command(text.trim()) {
            Ok(Some(answer)) => self.output.push_back(format!("{answer}\n").into_bytes()),
            Ok(None) => {}
            Err(code) => self.fail(code),
        }
    }

    fn fail(&mut self, code: u32) {
        if UNREADABLE.contains(&code) {
            self.malformed += 1;
        }
        self.error = code;
    }
}

/// `HLP?`: a header line, a line a command, a closing line.
fn help() -> String {
    let mut lines = vec!["The following commands are valid:".to_string()];
    lines.extend(COMMANDS.iter().map(|(command, what)| format!("{command} {what}")));
    lines.push("end of help".into());
    reply(lines)
}

/// `HPA?`: a header line, then `<id>=<command level> <items> <type> <group> <description>`
/// separated by tabs.
fn parameter_help() -> String {
    let mut lines = vec!["#Possible parameters:".to_string()];
    lines.extend(PARAMETERS.iter().map(|(id, _, kind, what)| format!("0x{id:X}=\t0\t1\t{kind}\tmotion\t{what}")));
    lines.push("end of help".into());
    reply(lines)
}

/// The manual's text for an error code this controller sets.
#[cfg(test)]
fn error_text(code: u32) -> Option<&'static str> {
    ERROR_TEXTS.iter().find(|(c, _)| *c == code).map(|(_, text)| *text)
}

impl Emulator for Gcs2Emulator {
    fn name(&self) -> &'static str {
        "pi_gcs2"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for axis in &mut self.axes {
            axis.stage.advance(now);
            axis.finish_reference();
            if axis.halting && !axis.moving() {
                axis.halting = false;
                axis.target = axis.position();
            }
        }
        for &byte in bytes {
            if self.line.is_empty() && [REQUEST_STATUS, REQUEST_MOTION, REQUEST_READY, STOP_ALL].contains(&byte) {
                self.single_byte(byte);
            } else if byte == b'\n' {
                self.execute_line();
            } else if byte != b'\r' && self.line.len() <= LINE_CAPACITY {
                self.line.push(byte);
            }
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.output.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.axes.get_mut(channel.checked_sub(1)?).map(|a| &mut a.stage)
    }

    /// A motion error (1024): the position error grew too large, the servo went off.
    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(axis) = channel.checked_sub(1).and_then(|i| self.axes.get_mut(i)) else { return false };
        axis.servo(false);
        self.error = code::MOTION_ERROR;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn c884() -> Gcs2Emulator {
        Gcs2Emulator::new(4, &Gcs2Emulator::mechanics())
    }

    /// `bytes` sent `at` seconds after power-up; the replies as text (cp1252 0xB0/0xB1 kept).
    fn send(e: &mut Gcs2Emulator, at: f64, bytes: &[u8]) -> Vec<String> {
        e.handle_input(Instant::ZERO + Duration::from_secs_f64(at), bytes);
        std::iter::from_fn(|| e.poll_transmit()).map(|r| r.iter().map(|&b| char::from(b)).collect()).collect()
    }

    #[test]
    fn identification_syntax_version_and_axes() {
        let mut e = c884();
        let idn = send(&mut e, 0.0, b"*IDN?\n").remove(0);
        assert_eq!(idn.split(',').nth(1).map(str::trim), Some("C-884.4DC"), "pipython's devname");
        assert!(idn.ends_with('\n') && !idn.ends_with(" \n"));
        assert_eq!(send(&mut e, 0.0, b"CSV?\n"), ["2.0\n"]);
        assert_eq!(send(&mut e, 0.0, b"SAI?\n"), ["1 \n2 \n3 \n4\n"]);
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn help_is_multi_line_as_pipython_reads_it() {
        let mut e = c884();
        let help = send(&mut e, 0.0, b"HLP?\n").remove(0);
        // Every LF but the last follows a space (pipython's end-of-answer rule).
        let lfs: Vec<usize> = help.match_indices('\n').map(|(i, _)| i).collect();
        assert_eq!(lfs.last(), Some(&(help.len() - 1)));
        assert!(lfs[..lfs.len() - 1].iter().all(|&i| &help[i - 1..i] == " "));
        // Without its first and last line, each line starts with a command.
        let commands: Vec<&str> = help.lines().skip(1).map(|l| l.split_whitespace().next().unwrap_or("")).collect();
        for command in ["#5", "#7", "#24", "*IDN?", "MOV", "MVR", "FRF?", "ONT?", "SVO", "HLT", "ERR?", "CSV?"] {
            assert!(commands.contains(&command), "{command} listed");
        }
        let hpa = send(&mut e, 0.0, b"HPA?\n").remove(0);
        let line = hpa.lines().find(|l| l.starts_with("0xE=")).expect("0xE");
        assert_eq!(line.split_whitespace().nth(3), Some("INT"));
    }

    #[test]
    fn an_unknown_command_is_not_answered_and_leaves_error_2() {
        let mut e = c884();
        assert!(send(&mut e, 0.0, b"XYZ 1\n").is_empty());
        assert_eq!(send(&mut e, 0.0, b"ERR?\n"), ["2\n"]);
        assert_eq!(send(&mut e, 0.0, b"ERR?\n"), ["0\n"], "read and reset");
        assert!(send(&mut e, 0.0, b"POS? 9\n").is_empty());
        assert_eq!(send(&mut e, 0.0, b"ERR?\n"), ["15\n"]);
        assert_eq!(e.malformed(), 2);
        assert_eq!(error_text(2), Some("Unknown command"));
        assert_eq!(error_text(15), Some("Invalid axis identifier"));
    }

    #[test]
    fn moves_are_refused_unreferenced_with_servo_off_and_beyond_the_travel_range() {
        let mut e = c884();
        assert_eq!(send(&mut e, 0.0, b"MOV 1 1\nERR?\n"), ["5\n"], "servo off");
        assert_eq!(send(&mut e, 0.0, b"SVO 1 1\nMOV 1 1\nERR?\n"), ["5\n"], "unreferenced");
        assert_eq!(send(&mut e, 0.0, b"POS 1 0\nERR?\n"), ["88\n"], "POS wants RON 0");
        assert_eq!(send(&mut e, 0.0, b"RON 1 0\nPOS 1 0\nRON 1 1\nFRF? 1\nERR?\n"), ["1=1\n", "0\n"]);
        assert_eq!(send(&mut e, 0.0, b"TMN? 1\nTMX? 1\n"), ["1=-19.500000\n", "1=19.500000\n"]);
        assert_eq!(send(&mut e, 0.0, b"MOV 1 19.6\nERR?\n"), ["7\n"]);
        assert_eq!(send(&mut e, 0.0, b"MVR 1 -19.6\nERR?\n"), ["7\n"]);
        assert_eq!(send(&mut e, 0.0, b"VEL 1 51\nERR?\n"), ["8\n"]);
        assert_eq!(send(&mut e, 0.0, b"SPA 1 0xE 5\nERR?\n"), ["60\n"]);
        assert_eq!(send(&mut e, 0.0, b"SPA? 1 0xE\nSPA? 1 15\n"), ["1 0xE=10000\n", "1 15=1\n"]);
        assert_eq!(send(&mut e, 0.0, b"MOV 1 2\nERR?\nONT? 1\n"), ["0\n", "1=0\n"]);
        assert_eq!(send(&mut e, 0.1, b"\x05"), ["1\n"], "axis 1 moving");
        assert_eq!(send(&mut e, 5.0, b"POS? 1\nONT? 1\n\x05"), ["1=2.000000\n", "1=1\n", "0\n"]);
        assert_eq!(send(&mut e, 5.0, b"MVR 1 -1\nMOV? 1\n"), ["1=1.000000\n"]);
        assert_eq!(error_text(5).map(|t| t.contains("unreferenced axis")), Some(true));
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn status_register_as_the_manual_example() {
        let mut e = c884();
        // Referenced, servo on, standing on the positive side of the reference switch.
        send(&mut e, 0.0, b"SVO 1 1\n");
        assert_eq!(send(&mut e, 0.0, b"SRG? 1 1\n"), ["1 1=0x9002\n"]);
        assert_eq!(send(&mut e, 0.0, b"\x04"), ["0x9002000200020002\n"]);
        assert!(send(&mut e, 0.0, b"SRG? 1 2\n").is_empty());
        assert_eq!(send(&mut e, 0.0, b"ERR?\n"), ["17\n"]);
    }

    #[test]
    fn referencing_reports_not_ready_then_referenced_at_the_switch() {
        let mut e = c884();
        assert_eq!(send(&mut e, 0.0, b"FRF 1\nERR?\n"), ["5\n"], "servo off");
        send(&mut e, 0.0, b"SVO 1 1 2 1\nFRF 1\nFNL 2\n");
        assert_eq!(send(&mut e, 0.2, b"\x07"), ["\u{b0}\n"]);
        assert_eq!(send(&mut e, 0.2, b"SRG? 1 1\nFRF? 1\n"), ["1 1=0x7002\n", "1=0\n"]);
        assert_eq!(send(&mut e, 10.0, b"\x07"), ["\u{b1}\n"]);
        assert_eq!(send(&mut e, 10.0, b"FRF? 1 2\nPOS? 1 2\n"), ["1=1 \n2=1\n", "1=0.000000 \n2=-20.000000\n"]);
        assert_eq!(send(&mut e, 10.0, b"RON 1 0\nFRF 1\nERR?\n"), ["50\n"]);
    }

    #[test]
    fn halt_and_stop_all_leave_error_10() {
        let mut e = c884();
        send(&mut e, 0.0, b"SVO 1 1 2 1\nRON 1 0 2 0\nPOS 1 0 2 0\nMOV 1 10 2 -10\n");
        assert!(send(&mut e, 0.5, b"HLT 1\n").is_empty());
        assert_eq!(send(&mut e, 0.5, b"ERR?\n"), ["10\n"]);
        assert_eq!(send(&mut e, 0.6, b"\x18"), Vec::<String>::new(), "#24 answers nothing");
        assert_eq!(send(&mut e, 0.6, b"\x05ERR?\n"), ["0\n", "10\n"]);
        let position = send(&mut e, 2.0, b"POS? 1\nMOV? 1\n");
        assert_eq!(position[0].replace("POS", ""), position[1], "the target is where it stopped");
    }

    #[test]
    fn a_raised_error_is_a_motion_error_with_the_servo_off() {
        let mut e = c884();
        send(&mut e, 0.0, b"SVO 2 1\n");
        assert!(e.raise_error(2));
        assert!(!e.raise_error(0) && !e.raise_error(9));
        assert_eq!(send(&mut e, 0.0, b"SVO? 2\nERR?\n"), ["2=0\n", "1024\n"]);
    }

    #[test]
    fn a_line_too_long_is_error_3() {
        let mut e = c884();
        let mut flood = vec![b'A'; 1000];
        flood.push(b'\n');
        assert!(send(&mut e, 0.0, &flood).is_empty());
        assert_eq!(send(&mut e, 0.0, b"ERR?\n"), ["3\n"]);
    }
}
