//! A Newport ESP300 / ESP301: up to three axes of DC servo motors behind one serial line, ASCII
//! commands `xxAAnn` (`xx` the axis, `AA` the mnemonic in either case, `nn` the parameter or
//! `?`), written from Newport's "ESP300 Motion Controller/Driver User's Manual" (P/N 28187-01,
//! section 3 "Remote Mode"; the ESP301's manual EDH0235En carries the same command set).
//!
//! # Witnesses
//!
//! 1. The ESP300 user's manual, as the pages stored from easymanua.ls and manualshive.com could
//!    be read (not all of it: the pages of `MD`, `MO`/`MF`, `OR`, `DH`, `SN`, `SU`, `ZB`, `ZH`,
//!    `VE` and the error appendix were not among them):
//!    - §3.4 "Command Syntax" (3-7, 3-8): `xx`, two letters, `nn`; blanks are ignored; several
//!      commands on one line are separated by `;`, several parameters by `,`; a line ends with
//!      CR and holds 80 characters at most; replies always end with CR LF. 3-2: a command
//!      without its axis prefix, or for an axis that is not there, is an error; commands are
//!      carried out in order without waiting for a motion to end unless `WS` says so.
//!    - `TE` (3-139): `TE?`, one code of up to three digits, 1–99 for the controller, 100–199
//!      for axis 1, 200–299 for axis 2 …; `TB` (3-138): `TB?` answers `code, timestamp,
//!      MESSAGE`, the timestamp in servo ticks (400 µs) since the last reset (`0, 451322, NO
//!      ERROR DETECTED`). Both read a FIFO of ten errors, each error once.
//!    - `TS` (3-142): one character, bits 0–2 axes 1–3 in motion, bit 4 the power of at least
//!      one motor; its example (`[P`) sets bit 6 besides the bits it names.
//!    - `PH` (3-110, 3-111): two registers in hex with an `H`, `18000404H, 4H`; of the second,
//!      bits 8–10 are the axes' index signals and 16–17 the digital inputs A and B.
//!    - `ID` (3-86): `xxID?` answers `model, serial` (`TS50DC.5, SN1263`); an axis missing is
//!      error 37 AXIS NUMBER MISSING, out of range error 9 AXIS NUMBER OUT OF RANGE.
//!    - `DP` (3-52): `3TP?` answers `5.32`, a bare number; `DP` is the desired position.
//!    - `ZS` (3-169): `xxZSnn` / `xxZS?`, `nn` hexadecimal (the `H` optional), 0 to 0FFFFH;
//!      a parameter missing is error 38 COMMAND PARAMETER MISSING, a critical setting error
//!      x17 ESP CRITICAL SETTINGS ARE PROTECTED.
//!    - `MV` (3-101): `3MV+`, `3MV-` move until stopped; `3MV?` answers 0 while in motion.
//! 2. pymeasure 0.16 (`pymeasure/instruments/newport/esp300.py`), the outside client: the
//!    texts of the error codes (general 1–41, axis x00–x32), and what it sends: `1TP` (no `?`)
//!    for the position, `1PA5`, `1MO?`, `1MD?`, `1SN?` (2 is millimetres), `1SL?`, `1SR?`,
//!    `1MO`, `1MF`, `1OR1` (modes 0 to 6), `1DH` and `1DH1.5`, `1WS0` then `1MD?` until done,
//!    `TE?` until 0 (codes above 100 being axis errors).
//! 3. Newport's New Focus 8742 manual (the same conventions): `xxMD?` answers 0 while a motion
//!    is in progress, 1 when not; `xxTP?` the position.
//! 4. The ESP302-GPIB-ADPT manual (§2.5): the ESP family's line, 19,200 baud, 8N1, RTS/CTS.
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Units.** One simulator step is 0.0001 mm (`UNIT_PER_STEP`), the encoder resolution
//!   `SU?` reports; `SN?` answers 2 (millimetres). `SN`, `SU`, `FR` (0.001), `QS` (10) are the
//!   stage's data: setting the value they have is taken, any other is x17.
//! - **Lines.** LF ends a line as CR does (CR LF is one end). The answers of the queries of one
//!   line go back as one line, separated by `, ` (as the manual's own lists are), ended by
//!   CR LF; a line without a query gets nothing. Every command of a line is carried out, the
//!   errors of the others notwithstanding. A mnemonic of the controller (`TB`, `TE`, `TS`,
//!   `PH`, `VE`, `AB`, `RS`) ignores an axis prefix (`01PH` is `PH`).
//! - **Queries.** The read-only commands answer with or without `?` (`1TP`, `1MD`, `PH`,
//!   `TE`); `xxMV?` answers as `xxMD?`. Values are printed to a millionth, trailing zeros
//!   dropped (`5`, `-0.0001`); positions to the encoder count.
//! - **Errors.** Unknown mnemonic 6 (also `*IDN?`); a bad parameter of a controller command 7,
//!   of an axis command x01; a parameter missing 38; no axis 37; an axis beyond those present
//!   9. These count as malformed. A motion of a motor that is off is x13; during a home search
//!   x30; a target beyond `SR`/`SL` x06/x07; `VA` above `VU` x10, `AC`/`AG` above `AU` x11. A
//!   motion that ends on an end-of-run switch queues x04/x05 (the motor stays on; a stop by
//!   hand on the switch does not). `ST` or `MF` during a home search queue x20 (`AB`, `RS` and
//!   a following error end it silently). A full buffer drops its oldest error.
//! - **Power-up and `RS`:** motors off, positions 0 where the stages stand, the error buffer
//!   empty, the timestamps from 0; `VA` 2.5 mm/s, `VU` 5, `VB` 0, `AC` = `AG` 10 mm/s², `AU`
//!   40, `SL`/`SR` 0.5 mm inside the end-of-run switches (±19.5 mm), gains 0. `AB` stops every
//!   axis at once and turns its motor off.
//! - **Motions.** `PA`/`PR` run at `VA` with `AC` (the simulator's ramps are symmetric), `ST`
//!   decelerates with `AG`, `MF` stops at once. `PR` is relative to the target of the motion
//!   under way, else to the position. `VB` (a stepper's base velocity) is kept and not used: the
//!   motors are DC servos. A new motion replaces the one under way. Software limits bound the
//!   targets of `PA`/`PR` only; `MV` runs to the switch. Settings changed during a motion serve
//!   the next one. `DH` is taken at any time. `WS` is taken and does not hold the commands
//!   after it (the emulator only runs when bytes arrive): poll `MD?`.
//! - **Home search `OR`** (mode 0 when missing): 0 moves to position 0; 1 and 2 search the home
//!   switch, 3 and 5 the + end-of-run switch, 4 and 6 the − one; the position there is 0. All
//!   run at `VA` with `AC`.
//! - `KP`, `KI`, `KD` are kept and reach the servo at `UF`. `ZB`, `ZH`, `ZS` are kept and read
//!   back; nothing acts on them. At power-up `ZH` and `ZS` are `0H` and `ZB` is `100H`: bit 8,
//!   encoder feedback, as a DC servo stage with its encoder is configured (the `ZB` page was not
//!   to be had; the bit is the one EPICS's drvESP300.cc reads as "encoder feedback", and then
//!   takes the resolution from `SU?`). `ID?` answers `UTS50CC, SN000n`. `VE?`
//!   answers `ESP300 Version 3.08 09/09/02`.
//! - `raise_error` is a following error (x03): the axis stops at once, its motor off.
//! - `TS`'s bit 6 is always set, as in the manual's example, so that the character prints (`@`
//!   at rest with every motor off, `P` with a motor on, `Q` when axis 1 moves besides).

use crate::emulator::axes;
use crate::{stage, Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};
use zmotor_msgs::Gain;

/// Millimetres (the controller's unit) per simulator step: the encoder resolution.
const UNIT_PER_STEP: f64 = 1e-4;
/// Axes an ESP300 drives.
const MAX_AXES: usize = 3;
/// `ZB` bit 8: the position loop closes on the encoder.
const ENCODER_FEEDBACK: u32 = 0x100;
/// Longest command line (§3.4.1).
const LINE_CAPACITY: usize = 80;
/// Errors the FIFO holds.
const ERROR_BUFFER: usize = 10;
/// The servo cycle the timestamps count, s.
const SERVO_TICK: f64 = 400e-6;
/// How far inside an end-of-run switch the power-up software limit is, mm.
const SOFT_LIMIT_MARGIN: f64 = 0.5;
/// The software limit on a side without a switch, mm.
const NO_SWITCH_LIMIT: f64 = 1e6;
/// Targets this close beyond a software limit are on it (decimal millimetres in binary).
const LIMIT_TOLERANCE: f64 = 1e-9;
const VERSION: &str = "ESP300 Version 3.08 09/09/02";
const STAGE_MODEL: &str = "UTS50CC";

/// General error codes (pymeasure's table, the manual's pages).
mod code {
    pub(super) const NONE: u32 = 0;
    pub(super) const UNKNOWN_COMMAND: u32 = 6;
    pub(super) const PARAMETER_OUT_OF_RANGE: u32 = 7;
    pub(super) const AXIS_OUT_OF_RANGE: u32 = 9;
    pub(super) const AXIS_MISSING: u32 = 37;
    pub(super) const PARAMETER_MISSING: u32 = 38;
}

/// Axis error codes, to be added to 100 × the axis number.
mod axis_code {
    pub(super) const PARAMETER_OUT_OF_RANGE: u32 = 1;
    pub(super) const FOLLOWING_ERROR: u32 = 3;
    pub(super) const POSITIVE_HARDWARE_LIMIT: u32 = 4;
    pub(super) const NEGATIVE_HARDWARE_LIMIT: u32 = 5;
    pub(super) const POSITIVE_SOFTWARE_LIMIT: u32 = 6;
    pub(super) const NEGATIVE_SOFTWARE_LIMIT: u32 = 7;
    pub(super) const MAXIMUM_VELOCITY: u32 = 10;
    pub(super) const MAXIMUM_ACCELERATION: u32 = 11;
    pub(super) const MOTOR_NOT_ENABLED: u32 = 13;
    pub(super) const CRITICAL_SETTING: u32 = 17;
    pub(super) const HOMING_ABORTED: u32 = 20;
    pub(super) const DURING_HOMING: u32 = 30;
}

/// The message `TB?` gives with `error`.
fn message(error: u32) -> &'static str {
    if error >= 100 {
        return match error % 100 {
            axis_code::PARAMETER_OUT_OF_RANGE => "PARAMETER OUT OF RANGE",
            axis_code::FOLLOWING_ERROR => "FOLLOWING ERROR THRESHOLD EXCEEDED",
            axis_code::POSITIVE_HARDWARE_LIMIT => "POSITIVE HARDWARE LIMIT DETECTED",
            axis_code::NEGATIVE_HARDWARE_LIMIT => "NEGATIVE HARDWARE LIMIT DETECTED",
            axis_code::POSITIVE_SOFTWARE_LIMIT => "POSITIVE SOFTWARE LIMIT DETECTED",
            axis_code::NEGATIVE_SOFTWARE_LIMIT => "NEGATIVE SOFTWARE LIMIT DETECTED",
            axis_code::MAXIMUM_VELOCITY => "MAXIMUM VELOCITY EXCEEDED",
            axis_code::MAXIMUM_ACCELERATION => "MAXIMUM ACCELERATION EXCEEDED",
            axis_code::MOTOR_NOT_ENABLED => "MOTOR NOT ENABLED",
            axis_code::CRITICAL_SETTING => "ESP CRITICAL SETTINGS ARE PROTECTED",
            axis_code::HOMING_ABORTED => "HOMING ABORTED",
            _ => "COMMAND NOT ALLOWED DURING HOMING",
        };
    }
    match error {
        code::NONE => "NO ERROR DETECTED",
        code::UNKNOWN_COMMAND => "COMMAND DOES NOT EXIST",
        code::PARAMETER_OUT_OF_RANGE => "PARAMETER OUT OF RANGE",
        code::AXIS_OUT_OF_RANGE => "AXIS NUMBER OUT OF RANGE",
        code::AXIS_MISSING => "AXIS NUMBER MISSING",
        _ => "COMMAND PARAMETER MISSING",
    }
}

/// Errors that say the command was not well-formed (a driver's fault).
fn is_malformed(error: u32) -> bool {
    matches!(
        error,
        code::UNKNOWN_COMMAND
            | code::PARAMETER_OUT_OF_RANGE
            | code::AXIS_OUT_OF_RANGE
            | code::AXIS_MISSING
            | code::PARAMETER_MISSING
    ) || (error >= 100 && error % 100 == axis_code::PARAMETER_OUT_OF_RANGE)
}

/// Why an axis command was not carried out (or what it raised while carried out).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Fault {
    /// A controller code.
    General(u32),
    /// An axis code (x00–x99).
    Axis(u32),
}

/// What an axis command answers, if it is answered.
type Answer = Result<Option<String>, Fault>;

/// The mnemonics addressed to an axis.
const AXIS_COMMANDS: [&str; 33] = [
    "AC", "AG", "AU", "DH", "DP", "FR", "ID", "KD", "KI", "KP", "MD", "MF", "MO", "MV", "OR", "PA", "PR", "QS", "SL",
    "SN", "SR", "ST", "SU", "TP", "TV", "UF", "VA", "VB", "VU", "WS", "ZB", "ZH", "ZS",
];

/// The stage's data: read, or set to the value it has.
fn stage_datum(mnemonic: &str) -> Option<f64> {
    Some(match mnemonic {
        "SN" => 2.0,
        "SU" => UNIT_PER_STEP,
        "FR" => UNIT_PER_STEP * 10.0,
        "QS" => 10.0,
        _ => return None,
    })
}

/// A number as the controller prints it: to a millionth, no trailing zeros.
fn number(value: f64) -> String {
    let rounded = (value * 1e6).round() / 1e6 + 0.0;
    format!("{rounded}")
}

/// The numeric parameter of a setter.
fn value(parameter: &str) -> Result<f64, Fault> {
    if parameter.is_empty() {
        return Err(Fault::General(code::PARAMETER_MISSING));
    }
    parameter.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or(Fault::Axis(axis_code::PARAMETER_OUT_OF_RANGE))
}

/// Nothing, or `?`, after a read-only or action mnemonic.
fn bare(parameter: &str, allow_query: bool) -> Result<(), Fault> {
    match parameter {
        "" => Ok(()),
        "?" if allow_query => Ok(()),
        _ => Err(Fault::Axis(axis_code::PARAMETER_OUT_OF_RANGE)),
    }
}

/// An axis's settings, in millimetres and seconds.
#[derive(Clone, Debug)]
struct Settings {
    velocity: f64,
    base_velocity: f64,
    max_velocity: f64,
    acceleration: f64,
    deceleration: f64,
    max_acceleration: f64,
    low_limit: f64,
    high_limit: f64,
    gains: [f64; 3],
    /// `ZB`, `ZH`, `ZS`.
    configuration: [u32; 3],
}

impl Settings {
    fn at_power_up(mechanics: &SimConfig) -> Self {
        let soft = |switch: Option<f64>, inward: f64, none: f64| {
            switch.map_or(none, |steps| steps * UNIT_PER_STEP + inward * SOFT_LIMIT_MARGIN)
        };
        Self {
            velocity: 2.5,
            base_velocity: 0.0,
            max_velocity: 5.0,
            acceleration: 10.0,
            deceleration: 10.0,
            max_acceleration: 40.0,
            low_limit: soft(mechanics.low_limit_switch, 1.0, -NO_SWITCH_LIMIT),
            high_limit: soft(mechanics.high_limit_switch, -1.0, NO_SWITCH_LIMIT),
            gains: [0.0; 3],
            // ZB bit 8: encoder feedback, as a DC servo stage has it.
            configuration: [ENCODER_FEEDBACK, 0, 0],
        }
    }

    fn numeric(&mut self, mnemonic: &str) -> Option<&mut f64> {
        Some(match mnemonic {
            "VA" => &mut self.velocity,
            "VB" => &mut self.base_velocity,
            "VU" => &mut self.max_velocity,
            "AC" => &mut self.acceleration,
            "AG" => &mut self.deceleration,
            "AU" => &mut self.max_acceleration,
            "SL" => &mut self.low_limit,
            "SR" => &mut self.high_limit,
            "KP" => &mut self.gains[0],
            "KI" => &mut self.gains[1],
            "KD" => &mut self.gains[2],
            _ => return None,
        })
    }

    /// Whether `mnemonic` may take `value`.
    fn check(&self, mnemonic: &str, value: f64) -> Result<(), Fault> {
        let error = match mnemonic {
            "VA" if value > self.max_velocity => axis_code::MAXIMUM_VELOCITY,
            "AC" | "AG" if value > self.max_acceleration => axis_code::MAXIMUM_ACCELERATION,
            "VA" | "VU" | "AC" | "AG" | "AU" if value <= 0.0 => axis_code::PARAMETER_OUT_OF_RANGE,
            "VB" | "KP" | "KI" | "KD" if value < 0.0 => axis_code::PARAMETER_OUT_OF_RANGE,
            _ => return Ok(()),
        };
        Err(Fault::Axis(error))
    }
}

/// A home search under way, by what it looks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Homing {
    /// Position 0 (mode 0) or the home switch (modes 1, 2): the simulator ends it.
    Simulated,
    /// An end-of-run switch, + or −: its position becomes 0.
    Limit { positive: bool },
}

/// One axis: its motor, its stage, its settings.
struct Axis {
    number: usize,
    sim: SimAxis,
    on: bool,
    settings: Settings,
    homing: Option<Homing>,
    /// Where the `PA`/`PR` under way goes, mm.
    target: Option<f64>,
    /// Moving as of the last look (to see a motion end).
    moving: bool,
}

impl Axis {
    fn new(number: usize, mut sim: SimAxis) -> Self {
        sim.enable(false);
        let settings = Settings::at_power_up(sim.config());
        Self { number, sim, on: false, settings, homing: None, target: None, moving: false }
    }

    /// The position, mm, to the encoder count.
    fn position(&self) -> f64 {
        self.sim.status().position.round() * UNIT_PER_STEP
    }

    /// Time passed to `now`; the axis code of an error the motion raised as it ended.
    fn update(&mut self, now: Instant) -> Option<u32> {
        self.sim.advance(now);
        let was_moving = std::mem::replace(&mut self.moving, self.sim.is_moving());
        if !was_moving || self.moving {
            return None;
        }
        self.target = None;
        let state = self.sim.state();
        match self.homing.take() {
            Some(Homing::Limit { positive }) => {
                if (positive && state.high_limit) || (!positive && state.low_limit) {
                    self.sim.set_position(0.0);
                }
                None
            }
            Some(Homing::Simulated) => None,
            None if state.high_limit => Some(axis_code::POSITIVE_HARDWARE_LIMIT),
            None if state.low_limit => Some(axis_code::NEGATIVE_HARDWARE_LIMIT),
            None => None,
        }
    }

    /// Whether a motion may start.
    fn may_move(&self) -> Result<(), Fault> {
        if self.homing.is_some() {
            Err(Fault::Axis(axis_code::DURING_HOMING))
        } else if !self.on {
            Err(Fault::Axis(axis_code::MOTOR_NOT_ENABLED))
        } else {
            Ok(())
        }
    }

    /// Stop with `deceleration` (mm/s², 0 at once); a home search under way is aborted.
    fn stop(&mut self, deceleration: f64) -> Result<(), Fault> {
        self.sim.stop(deceleration / UNIT_PER_STEP);
        self.target = None;
        match self.homing.take() {
            Some(_) => Err(Fault::Axis(axis_code::HOMING_ABORTED)),
            None => Ok(()),
        }
    }

    /// Stop at once and turn the motor off.
    fn power_off(&mut self) -> Result<(), Fault> {
        let stopped = self.stop(0.0);
        self.sim.enable(false);
        self.on = false;
        // Nothing ran to an end: no end-of-run error for a stop on a switch.
        self.moving = false;
        stopped
    }

    fn execute(&mut self, mnemonic: &str, parameter: &str) -> Answer {
        let query = parameter == "?";
        let velocity = self.settings.velocity / UNIT_PER_STEP;
        let acceleration = self.settings.acceleration / UNIT_PER_STEP;
        match mnemonic {
            "TP" => bare(parameter, true).map(|()| Some(number(self.position()))),
            "TV" => bare(parameter, true).map(|()| Some(number(self.sim.status().velocity * UNIT_PER_STEP))),
            "DP" => bare(parameter, true).map(|()| Some(number(self.target.unwrap_or_else(|| self.position())))),
            "MD" => bare(parameter, true).map(|()| Some(u8::from(!self.sim.is_moving()).to_string())),
            "ID" => bare(parameter, true).map(|()| Some(format!("{STAGE_MODEL}, SN{:04}", self.number))),
            "MO" if query => Ok(Some(u8::from(self.on).to_string())),
            "MO" => {
                bare(parameter, false)?;
                self.on = true;
                self.sim.enable(true);
                Ok(None)
            }
            "MF" => {
                bare(parameter, false)?;
                self.power_off().map(|()| None)
            }
            "ST" => {
                bare(parameter, false)?;
                self.stop(self.settings.deceleration).map(|()| None)
            }
            "UF" => {
                bare(parameter, false)?;
                let gains = [Gain::Proportional, Gain::Integral, Gain::Derivative];
                for (gain, value) in gains.into_iter().zip(self.settings.gains) {
                    self.sim.set_gain(gain, value);
                }
                Ok(None)
            }
            "WS" if parameter.is_empty() => Ok(None),
            "WS" => value(parameter).and_then(|delay| {
                if delay < 0.0 {
                    Err(Fault::Axis(axis_code::PARAMETER_OUT_OF_RANGE))
                } else {
                    Ok(None)
                }
            }),
            "DH" => {
                let home = if parameter.is_empty() { 0.0 } else { value(parameter)? };
                self.sim.set_position(home / UNIT_PER_STEP);
                self.target = None;
                Ok(None)
            }
            "PA" | "PR" => {
                let value = value(parameter)?;
                self.may_move()?;
                let from = if mnemonic == "PR" { self.target.unwrap_or_else(|| self.position()) } else { 0.0 };
                let target = from + value;
                if target > self.settings.high_limit + LIMIT_TOLERANCE {
                    return Err(Fault::Axis(axis_code::POSITIVE_SOFTWARE_LIMIT));
                }
                if target < self.settings.low_limit - LIMIT_TOLERANCE {
                    return Err(Fault::Axis(axis_code::NEGATIVE_SOFTWARE_LIMIT));
                }
                self.target = Some(target);
                self.sim.move_to(target / UNIT_PER_STEP, false, 0.0, velocity, acceleration);
                Ok(None)
            }
            "MV" if query => Ok(Some(u8::from(!self.sim.is_moving()).to_string())),
            "MV" => {
                let sign = match parameter {
                    "+" => 1.0,
                    "-" => -1.0,
                    "" => return Err(Fault::General(code::PARAMETER_MISSING)),
                    _ => return Err(Fault::Axis(axis_code::PARAMETER_OUT_OF_RANGE)),
                };
                self.may_move()?;
                self.target = None;
                self.sim.move_velocity(0.0, sign * velocity, acceleration);
                Ok(None)
            }
            "OR" => {
                let mode = if parameter.is_empty() { 0.0 } else { value(parameter)? };
                if mode.fract() != 0.0 || !(0.0..=6.0).contains(&mode) {
                    return Err(Fault::Axis(axis_code::PARAMETER_OUT_OF_RANGE));
                }
                self.may_move()?;
                self.target = None;
                let homing = match mode as u8 {
                    0 => {
                        self.sim.move_to(0.0, false, 0.0, velocity, acceleration);
                        Homing::Simulated
                    }
                    1 | 2 => {
                        self.sim.home(false, 0.0, velocity, acceleration);
                        Homing::Simulated
                    }
                    mode => {
                        let positive = mode % 2 == 1;
                        let signed = if positive { velocity } else { -velocity };
                        self.sim.move_velocity(0.0, signed, acceleration);
                        Homing::Limit { positive }
                    }
                };
                // A search already where it ends is over (the simulator has nothing to run).
                self.homing = self.sim.is_moving().then_some(homing);
                Ok(None)
            }
            "ZB" | "ZH" | "ZS" => {
                let index = ["ZB", "ZH", "ZS"].iter().position(|m| *m == mnemonic).unwrap_or(0);
                if query {
                    return Ok(Some(format!("{:X}H", self.settings.configuration[index])));
                }
                if parameter.is_empty() {
                    return Err(Fault::General(code::PARAMETER_MISSING));
                }
                let digits = parameter.strip_suffix(['H', 'h']).unwrap_or(parameter);
                let word = u32::from_str_radix(digits, 16).ok().filter(|w| *w <= 0xFFFF);
                self.settings.configuration[index] = word.ok_or(Fault::Axis(axis_code::PARAMETER_OUT_OF_RANGE))?;
                Ok(None)
            }
            _ => {
                if let Some(datum) = stage_datum(mnemonic) {
                    if query {
                        return Ok(Some(number(datum)));
                    }
                    if (value(parameter)? - datum).abs() > 1e-12 {
                        return Err(Fault::Axis(axis_code::CRITICAL_SETTING));
                    }
                    return Ok(None);
                }
                let current = self.settings.numeric(mnemonic).map(|v| *v).unwrap_or_default();
                if query {
                    return Ok(Some(number(current)));
                }
                let value = value(parameter)?;
                self.settings.check(mnemonic, value)?;
                if let Some(setting) = self.settings.numeric(mnemonic) {
                    *setting = value;
                }
                Ok(None)
            }
        }
    }
}

/// A Newport ESP300 with one to three axes (see the module documentation).
pub struct Esp300Emulator {
    axes: Vec<Axis>,
    lines: Lines,
    replies: VecDeque<Vec<u8>>,
    /// Codes and their timestamps, oldest first.
    errors: VecDeque<(u32, u64)>,
    malformed: usize,
    /// The last reset, where the timestamps count from.
    reset_at: Instant,
    /// The latest time seen.
    now: Instant,
}

impl Esp300Emulator {
    /// An ESP300 with axes 1 to `axes_present` (one to three) on `mechanics` (in steps of
    /// 0.0001 mm), just powered up.
    pub fn new(axes_present: usize, mechanics: &SimConfig) -> Self {
        let count = axes_present.clamp(1, MAX_AXES);
        Self {
            axes: axes(count, mechanics).into_iter().enumerate().map(|(i, sim)| Axis::new(i + 1, sim)).collect(),
            lines: Lines::new(b"\r", LINE_CAPACITY),
            replies: VecDeque::new(),
            errors: VecDeque::new(),
            malformed: 0,
            reset_at: Instant::ZERO,
            now: Instant::ZERO,
        }
    }

    /// The stage each axis drives: the crate's mechanics (end-of-run switches at ±20 mm, the
    /// home switch at 0) behind a DC servo motor.
    pub fn mechanics() -> SimConfig {
        SimConfig { servo: true, ..stage() }
    }

    fn timestamp(&self, now: Instant) -> u64 {
        (now.saturating_duration_since(self.reset_at).as_secs_f64() / SERVO_TICK) as u64
    }

    fn push_error(&mut self, error: u32) {
        if self.errors.len() == ERROR_BUFFER {
            self.errors.pop_front();
        }
        self.errors.push_back((error, self.timestamp(self.now)));
    }

    fn update(&mut self, now: Instant) {
        self.now = now;
        for index in 0..self.axes.len() {
            if let Some(error) = self.axes[index].update(now) {
                self.push_error(100 * (index as u32 + 1) + error);
            }
        }
    }

    /// The answer of one command (blanks removed), or its error code.
    fn command(&mut self, now: Instant, text: &str) -> Result<Option<String>, u32> {
        let digits = text.bytes().take_while(u8::is_ascii_digit).count();
        let rest = &text[digits..];
        let mnemonic = match rest.as_bytes() {
            [a, b, ..] if a.is_ascii_alphabetic() && b.is_ascii_alphabetic() => rest[..2].to_ascii_uppercase(),
            _ => return Err(code::UNKNOWN_COMMAND),
        };
        let parameter = &rest[2..];
        let reading = if matches!(parameter, "" | "?") { Ok(()) } else { Err(code::PARAMETER_OUT_OF_RANGE) };
        match mnemonic.as_str() {
            "TE" | "TB" => {
                reading?;
                let (error, stamp) = self.errors.pop_front().unwrap_or((code::NONE, self.timestamp(now)));
                Ok(Some(match mnemonic.as_str() {
                    "TE" => error.to_string(),
                    _ => format!("{error}, {stamp}, {}", message(error)),
                }))
            }
            "TS" => {
                reading?;
                let mut status = 0x40u8;
                for (bit, axis) in self.axes.iter().enumerate() {
                    status |= u8::from(axis.sim.is_moving()) << bit;
                }
                status |= u8::from(self.axes.iter().any(|a| a.on)) << 4;
                Ok(Some(char::from(status).to_string()))
            }
            "PH" => {
                reading?;
                let (mut limits, mut home) = (0u32, 0u32);
                for (bit, axis) in self.axes.iter().enumerate() {
                    let state = axis.sim.state();
                    limits |= (u32::from(state.high_limit) << bit) | (u32::from(state.low_limit) << (bit + 8));
                    home |= u32::from(axis.sim.on_home_switch()) << bit;
                }
                Ok(Some(format!("{limits:X}H, {home:X}H")))
            }
            "VE" => reading.map(|()| Some(VERSION.to_string())),
            "AB" | "RS" => {
                if !parameter.is_empty() {
                    return Err(code::PARAMETER_OUT_OF_RANGE);
                }
                for axis in &mut self.axes {
                    // An abort or a reset ends a home search without an error of its own.
                    let _ = axis.power_off();
                    if mnemonic == "RS" {
                        axis.sim.set_position(0.0);
                        axis.settings = Settings::at_power_up(axis.sim.config());
                    }
                }
                if mnemonic == "RS" {
                    self.errors.clear();
                    self.reset_at = now;
                }
                Ok(None)
            }
            known if AXIS_COMMANDS.contains(&known) => {
                let number = match text[..digits].parse::<usize>() {
                    _ if digits == 0 => return Err(code::AXIS_MISSING),
                    Ok(n) if (1..=self.axes.len()).contains(&n) => n,
                    _ => return Err(code::AXIS_OUT_OF_RANGE),
                };
                let axis = &mut self.axes[number - 1];
                let answer = axis.execute(&mnemonic, parameter);
                axis.moving = axis.sim.is_moving();
                answer.map_err(|fault| match fault {
                    Fault::General(error) => error,
                    Fault::Axis(error) => 100 * number as u32 + error,
                })
            }
            _ => Err(code::UNKNOWN_COMMAND),
        }
    }

    fn on_line(&mut self, now: Instant, line: &[u8]) {
        let text: String = String::from_utf8_lossy(line).chars().filter(|c| !c.is_whitespace()).collect();
        let mut answers = Vec::new();
        for command in text.split(';').filter(|c| !c.is_empty()) {
            match self.command(now, command) {
                Ok(answer) => answers.extend(answer),
                Err(error) => {
                    self.malformed += usize::from(is_malformed(error));
                    self.push_error(error);
                }
            }
        }
        if !answers.is_empty() {
            self.replies.push_back(format!("{}\r\n", answers.join(", ")).into_bytes());
        }
    }
}

impl Emulator for Esp300Emulator {
    fn name(&self) -> &'static str {
        "newport_esp300"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        self.update(now);
        // LF ends a line as CR does; the empty line between CR and LF is nothing.
        let bytes: Vec<u8> = bytes.iter().map(|&b| if b == b'\n' { b'\r' } else { b }).collect();
        for line in self.lines.push(&bytes) {
            self.on_line(now, &line);
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.replies.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed + self.lines.overflowed()
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.axes.get_mut(channel.checked_sub(1)?).map(|axis| &mut axis.sim)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(axis) = channel.checked_sub(1).and_then(|i| self.axes.get_mut(i)) else { return false };
        // The home search a following error ends is not reported as aborted besides.
        let _ = axis.power_off();
        self.push_error(100 * channel as u32 + axis_code::FOLLOWING_ERROR);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use zmotor_core::SimSetting;
    use zmotor_msgs::Value;

    fn esp(axes: usize) -> Esp300Emulator {
        Esp300Emulator::new(axes, &Esp300Emulator::mechanics())
    }

    /// Send `line` (CR added) at `seconds`; every reply line, its CR LF removed.
    fn ask(e: &mut Esp300Emulator, seconds: f64, line: &str) -> Vec<String> {
        e.handle_input(Instant::from_secs_f64(seconds), format!("{line}\r").as_bytes());
        std::iter::from_fn(|| e.poll_transmit())
            .map(|reply| {
                let text = String::from_utf8(reply).expect("ASCII");
                text.strip_suffix("\r\n").expect("CR LF ends a reply").to_string()
            })
            .collect()
    }

    fn one(e: &mut Esp300Emulator, seconds: f64, line: &str) -> String {
        let replies = ask(e, seconds, line);
        assert_eq!(replies.len(), 1, "{line}: {replies:?}");
        replies[0].clone()
    }

    fn silent(e: &mut Esp300Emulator, seconds: f64, line: &str) {
        assert_eq!(ask(e, seconds, line), Vec::<String>::new(), "{line}");
    }

    /// Put axis `n`'s carriage at `mm` by hand.
    fn push_to(e: &mut Esp300Emulator, n: usize, mm: f64) {
        let axis = e.axis(n).expect("axis");
        axis.apply(SimSetting::Position, &Value::Float(mm / UNIT_PER_STEP)).unwrap();
    }

    #[test]
    fn what_a_client_asks_first_is_answered() {
        let mut e = esp(3);
        assert_eq!(one(&mut e, 0.0, "VE?"), "ESP300 Version 3.08 09/09/02");
        assert_eq!(one(&mut e, 0.0, "TS"), "@", "power-up: nothing moves, every motor off");
        assert_eq!(one(&mut e, 0.0, "1ID?"), "UTS50CC, SN0001");
        assert_eq!(one(&mut e, 0.0, "2SN?;2SU?;2FR?;2QS?"), "2, 0.0001, 0.001, 10");
        assert_eq!(one(&mut e, 0.0, "1MO?;1TP;3TP?;1SL?;1SR?"), "0, 0, 0, -19.5, 19.5");
        assert_eq!(one(&mut e, 0.0, "1ZB?;1ZH?"), "100H, 0H");
        silent(&mut e, 0.0, "1ZB0F0H;1ZH 12;1SN2");
        assert_eq!(one(&mut e, 0.0, "1zb?;1ZH?"), "F0H, 12H", "either case, blanks ignored");
        silent(&mut e, 0.0, "1SN3");
        assert_eq!(one(&mut e, 0.0, "TE?"), "117", "the units are the stage's");
        assert_eq!(one(&mut e, 0.0, "TE"), "0");
        assert_eq!(e.malformed(), 0);
        assert_eq!(e.name(), "newport_esp300");
    }

    #[test]
    fn several_commands_on_a_line_and_a_move_to_its_end() {
        let mut e = esp(3);
        silent(&mut e, 0.0, "01MO;01VA1.000000;01VB0.000000;01AC10.000000;01AG10.000000;01PA5.000000");
        assert_eq!(one(&mut e, 0.0, "01VA?;01VB?;01AC?;01AG?;01DP?"), "1, 0, 10, 10, 5");
        assert_eq!(one(&mut e, 0.0, "TS"), "Q", "axis 1 moving, a motor on");
        // 1 mm/s with 0.1 s ramps of 0.05 mm each: 5.1 s in all.
        let mut t = 0.0;
        while one(&mut e, t, "1MD?") == "0" {
            assert!(t < 6.0, "still moving at {t} s");
            let position: f64 = one(&mut e, t, "1TP?").parse().unwrap();
            assert!((0.0..=5.0).contains(&position), "{position}");
            t += 0.5;
        }
        assert!(t > 5.0, "done at {t} s");
        assert_eq!(one(&mut e, t, "1TP?;1MD;1TV"), "5, 1, 0");
        silent(&mut e, t, "1PR-1.25");
        assert_eq!(one(&mut e, t + 10.0, "1TP"), "3.75");
        assert_eq!(one(&mut e, t + 10.0, "TE?"), "0");
    }

    #[test]
    fn mv_runs_until_st_decelerates_it() {
        let mut e = esp(1);
        silent(&mut e, 0.0, "1MO;1VA2;1AG4;1MV+");
        assert_eq!(one(&mut e, 2.0, "1MV?;1MD?;1TV"), "0, 0, 2");
        let at_stop: f64 = one(&mut e, 2.0, "1TP").parse().unwrap();
        silent(&mut e, 2.0, "1ST");
        assert_eq!(one(&mut e, 2.2, "1MD?"), "0", "decelerating for 0.5 s");
        assert_eq!(one(&mut e, 3.0, "1MD?"), "1");
        let stopped: f64 = one(&mut e, 3.0, "1TP").parse().unwrap();
        assert!((stopped - at_stop - 0.5).abs() < 1e-3, "{at_stop} → {stopped}");
        silent(&mut e, 3.0, "1MV-;1MF");
        assert_eq!(one(&mut e, 4.0, "1MD?;1MO?;TE?"), "1, 0, 0", "MF stops at once");
    }

    #[test]
    fn or_searches_home_and_dh_defines_it() {
        let mut e = esp(1);
        push_to(&mut e, 1, 3.0);
        assert_eq!(one(&mut e, 0.0, "1TP"), "3", "the counter follows the carriage");
        silent(&mut e, 0.0, "1MO;1OR1");
        silent(&mut e, 0.5, "1PA1");
        assert_eq!(one(&mut e, 0.5, "TE?"), "130", "no motion during a home search");
        assert_eq!(one(&mut e, 10.0, "1MD?;1TP;PH"), "1, 0, 0H, 1H");
        silent(&mut e, 10.0, "1DH2.5");
        assert_eq!(one(&mut e, 10.0, "1TP"), "2.5");
        silent(&mut e, 10.0, "1DH");
        assert_eq!(one(&mut e, 10.0, "1TP"), "0");
        silent(&mut e, 10.0, "1OR3");
        assert_eq!(one(&mut e, 30.0, "1TP;PH;TE?"), "0, 1H, 0H, 0", "zero at the + switch, no error");
        silent(&mut e, 30.0, "1OR4");
        silent(&mut e, 31.0, "1ST");
        assert_eq!(one(&mut e, 31.0, "TE?"), "120", "a stopped search is aborted");
        silent(&mut e, 40.0, "1OR0");
        assert_eq!(one(&mut e, 60.0, "1TP;1MD"), "0, 1");
        silent(&mut e, 60.0, "1OR7");
        assert_eq!(one(&mut e, 60.0, "TE?"), "101");
    }

    #[test]
    fn the_error_buffer_is_a_fifo_read_once() {
        let mut e = esp(2);
        assert_eq!(one(&mut e, 0.0, "TB?"), "0, 0, NO ERROR DETECTED");
        silent(&mut e, 1.0, "1XY;3PA1;PA1;1VA;2PA1");
        assert_eq!(one(&mut e, 2.0, "TE?"), "6");
        assert_eq!(one(&mut e, 2.0, "TB?"), "9, 2500, AXIS NUMBER OUT OF RANGE", "stamped in 400 µs ticks");
        assert_eq!(one(&mut e, 2.0, "TB?;TE?"), "37, 2500, AXIS NUMBER MISSING, 38");
        assert_eq!(one(&mut e, 2.0, "TB"), "213, 2500, MOTOR NOT ENABLED", "axis 2 is off");
        assert_eq!(one(&mut e, 2.0, "TE?;TE?"), "0, 0");
        for _ in 0..12 {
            silent(&mut e, 3.0, "1QQ");
        }
        silent(&mut e, 3.0, "1VA-1");
        let codes: Vec<String> = (0..11).map(|_| one(&mut e, 3.0, "TE?")).collect();
        assert_eq!(codes[..9], vec!["6".to_string(); 9], "the oldest fell out of the ten");
        assert_eq!(codes[9..], ["101".to_string(), "0".to_string()]);
        assert_eq!(e.malformed(), 4 + 12 + 1, "unknown, axis out of range or missing, bad parameters");
    }

    #[test]
    fn axes_beyond_those_present_and_unknown_commands() {
        let mut e = esp(2);
        silent(&mut e, 0.0, "3TP;4MO;0TP;99999999999999999999TP");
        silent(&mut e, 0.0, "*IDN?;1T;1;1P?;;");
        let codes: Vec<String> = (0..9).map(|_| one(&mut e, 0.0, "TE")).collect();
        assert_eq!(codes, ["9", "9", "9", "9", "6", "6", "6", "6", "0"]);
        assert_eq!(one(&mut e, 0.0, "01PH;02TS"), "0H, 3H, @", "a controller command ignores the prefix");
    }

    #[test]
    fn a_motor_that_is_off_does_not_move() {
        let mut e = esp(1);
        silent(&mut e, 0.0, "1PA2;1PR1;1MV+;1OR");
        assert_eq!(one(&mut e, 1.0, "1TP;1MD?;TE?;TE?;TE?;TE?;TE?"), "0, 1, 113, 113, 113, 113, 0");
        silent(&mut e, 1.0, "1MO;1PA25;1PA-25");
        assert_eq!(one(&mut e, 1.0, "TE?;TE?;1MD?"), "106, 107, 1", "beyond the software limits");
        silent(&mut e, 1.0, "1VA6;1AC50;1AU60;1AC50;1VU10;1VA6");
        assert_eq!(one(&mut e, 1.0, "TE?;TE?;TE?;1VA?;1AC?"), "110, 111, 0, 6, 50");
    }

    #[test]
    fn end_of_run_switches_show_in_ph_and_raise_errors() {
        let mut e = esp(2);
        assert_eq!(one(&mut e, 0.0, "PH"), "0H, 3H", "both carriages on their home switch");
        silent(&mut e, 0.0, "1MO;2MO;1VA5;2VA5;1MV+;2MV-");
        assert_eq!(one(&mut e, 10.0, "PH;1TP;2TP;1MD;2MD"), "201H, 0H, 20, -20, 1, 1");
        assert_eq!(one(&mut e, 10.0, "TE?;TE?;TE?"), "104, 205, 0");
        silent(&mut e, 10.0, "1SR25;1PA25");
        assert_eq!(one(&mut e, 10.1, "1MD;TE?"), "1, 104", "no further into the switch");
        silent(&mut e, 10.1, "1PA10;1MF");
        assert_eq!(one(&mut e, 10.1, "PH;TE?"), "201H, 0H, 0", "stopped by hand on the switch: no error");
    }

    #[test]
    fn input_in_any_pieces_and_any_line_end() {
        let mut e = esp(1);
        e.handle_input(Instant::ZERO, b"1T");
        e.handle_input(Instant::ZERO, b"P?");
        assert!(e.poll_transmit().is_none());
        e.handle_input(Instant::ZERO, b"\r1MD?\r\n1 T S\n1MO?");
        let replies: Vec<Vec<u8>> = std::iter::from_fn(|| e.poll_transmit()).collect();
        assert_eq!(replies, [b"0\r\n".to_vec(), b"1\r\n".to_vec(), b"@\r\n".to_vec()]);
        e.handle_input(Instant::ZERO, &[b'1'; 81]);
        assert_eq!(e.malformed(), 1, "81 characters without an end overflow the line");
        assert_eq!(one(&mut e, 0.0, "1MO?"), "0");
    }

    #[test]
    fn a_raised_error_is_a_following_error_and_the_motor_drops_out() {
        let mut e = esp(3);
        assert!(!e.raise_error(0) && !e.raise_error(4));
        assert!(e.axis(0).is_none() && e.axis(4).is_none());
        silent(&mut e, 0.0, "2MO;2PA10");
        assert!(e.raise_error(2));
        assert_eq!(one(&mut e, 1.0, "2MD?;2MO?;TS;TE?;TE?"), "1, 0, @, 203, 0");
        silent(&mut e, 2.0, "2MO;2KP100;2KI5;2UF");
        assert_eq!(e.axis(2).unwrap().gains(), [100.0, 5.0, 0.0]);
        silent(&mut e, 2.0, "2PA1;AB");
        assert_eq!(one(&mut e, 3.0, "2MO?;2MD;TE?"), "0, 1, 0");
        silent(&mut e, 3.0, "3VA1;1QQ;RS");
        assert_eq!(one(&mut e, 3.5, "TB?;3VA?;2TP"), "0, 1250, NO ERROR DETECTED, 2.5, 0");
    }
}
