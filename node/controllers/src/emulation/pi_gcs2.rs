//! A PI C-884 (GCS 2): LF-ended command lines, silent setters, one error register read and
//! cleared by `ERR?`, queries answered `<axis>=<value>` (several lines joined by " \n"), and the
//! single bytes `#4` (status registers), `#5` (moving axes), `#7` (ready) and `#24` (stop all)
//! acted on at once. As a real one it powers up with every axis unreferenced, servo off, its
//! position counting from 0 wherever the stage stands, and reference mode on: a move is refused
//! (error 5) until the axis is referenced (`FRF`, `FNL`, `FPL`) or its position set
//! (`RON 0` + `POS`).
//!
//! Mechanics (`mechanics()`), in millimetres: a stage standing at 5 mm, its reference switch at
//! 0, limit switches at ±20 mm, a travel range (`TMN?`/`TMX?`) of ±19.5 mm, 10000 counts per mm.
//! Referencing defines the position as the stage's own (0 at the reference switch, ±20 at the
//! limit switches).

use super::Emulator;
use crate::pi_gcs2::{parameter, parse_id, register, MODELS, NAME};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};
use zmotor_msgs::bits::msta;

/// Counts per unit, numerator and denominator (parameters 0x0E and 0x0F).
pub(crate) const COUNTS_PER_UNIT: (f64, f64) = (10_000.0, 1.0);

/// The travel range, mm (`TMN?`, `TMX?`): targets beyond are refused with error 7.
pub(crate) const TRAVEL: (f64, f64) = (-19.5, 19.5);

/// The highest velocity, mm/s.
pub(crate) const MAX_VELOCITY: f64 = 50.0;

/// The highest acceleration and deceleration, mm/s² (parameters 0x4A and 0x4B).
pub(crate) const MAX_ACCELERATION: f64 = 1000.0;

/// The controller's error codes (`crate::pi_gcs2::error_meaning` says what they mean).
pub(crate) mod code {
    /// Parameter syntax error.
    pub(crate) const PARAMETER_SYNTAX: u32 = 1;
    /// Unknown command.
    pub(crate) const UNKNOWN_COMMAND: u32 = 2;
    /// A move of an unreferenced axis, or with servo off.
    pub(crate) const MOVE_REFUSED: u32 = 5;
    /// Position out of limits.
    pub(crate) const POSITION_OUT_OF_LIMITS: u32 = 7;
    /// Velocity out of limits.
    pub(crate) const VELOCITY_OUT_OF_LIMITS: u32 = 8;
    /// Stopped by command (HLT, STP, #24).
    pub(crate) const STOPPED: u32 = 10;
    /// Invalid axis identifier.
    pub(crate) const INVALID_AXIS: u32 = 15;
    /// Parameter out of range.
    pub(crate) const PARAMETER_OUT_OF_RANGE: u32 = 17;
    /// Incorrect number of parameters.
    pub(crate) const PARAMETER_COUNT: u32 = 24;
    /// Referencing with reference mode off.
    pub(crate) const REFERENCING_DISABLED: u32 = 50;
    /// Unknown parameter.
    pub(crate) const UNKNOWN_PARAMETER: u32 = 54;
    /// A parameter protected at the user's command level.
    pub(crate) const PROTECTED_PARAMETER: u32 = 60;
    /// POS with reference mode on ("move without referenced stage"; the code PI names
    /// REF_MODE_IS_ON).
    pub(crate) const REFERENCE_MODE_ON: u32 = 88;
    /// Motion error: the position error grew too large and the servo switched itself off.
    pub(crate) const MOTION_ERROR: u32 = 1024;
}

/// Error codes that mean the request itself was wrong: a driver's fault, counted as malformed.
const REQUEST_FAULTS: [u32; 5] =
    [code::PARAMETER_SYNTAX, code::UNKNOWN_COMMAND, code::INVALID_AXIS, code::PARAMETER_COUNT, code::UNKNOWN_PARAMETER];

/// The single bytes that are commands of their own.
const STATUS_REGISTERS: u8 = 0x04;
const MOTION_STATUS: u8 = 0x05;
const READY_STATUS: u8 = 0x07;
const STOP_ALL: u8 = 0x18;

/// The stage behind every axis, in millimetres (see the module documentation).
pub(crate) fn mechanics() -> SimConfig {
    SimConfig {
        position: 5.0,
        high_limit_switch: Some(20.0),
        low_limit_switch: Some(-20.0),
        home_switch: 0.0,
        servo: true,
        ..SimConfig::default()
    }
}

/// How an axis is being referenced.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Referencing {
    ReferenceSwitch,
    NegativeLimit,
    PositiveLimit,
}

/// One axis: the stage and the controller's settings for it.
struct EmulatedAxis {
    stage: SimAxis,
    servo: bool,
    /// RON: positions come from referencing only (POS refused).
    reference_mode: bool,
    referenced: bool,
    referencing: Option<Referencing>,
    /// The last target commanded (MOV, MVR), mm.
    target: f64,
    velocity: f64,
    acceleration: f64,
    deceleration: f64,
    reference_velocity: f64,
}

impl EmulatedAxis {
    fn new(mechanics: &SimConfig) -> Self {
        let mut stage = SimAxis::new(mechanics.clone());
        // At power-up the position counts from 0 wherever the stage stands.
        stage.set_position(0.0);
        stage.enable(false);
        Self {
            stage,
            servo: false,
            reference_mode: true,
            referenced: false,
            referencing: None,
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

    fn register(&self) -> u16 {
        let switches = self.stage.status().msta;
        let physical = self.stage.physical_position();
        let mut bits = 0;
        for (bit, on) in [
            (register::NEGATIVE_LIMIT, switches & msta::MINUS_LS != 0),
            (register::REFERENCE_SIGNAL, physical > self.stage.config().home_switch),
            (register::POSITIVE_LIMIT, switches & msta::PLUS_LS != 0),
            (register::SERVO_ON, self.servo),
            (register::IN_MOTION, self.moving()),
            (register::REFERENCING, self.referencing.is_some()),
            (register::ON_TARGET, self.servo && !self.moving() && self.referencing.is_none()),
        ] {
            if on {
                bits |= bit;
            }
        }
        bits
    }

    fn set_servo(&mut self, on: bool) {
        self.servo = on;
        // Switching the servo off stops the stage at once, referencing included.
        self.stage.enable(on);
        if !on {
            self.referencing = None;
        }
        self.target = self.position();
    }

    fn halt(&mut self) {
        self.stage.stop(self.deceleration);
        self.referencing = None;
    }

    /// A referencing that has come to rest: referenced if it ended at its switch.
    fn settle_referencing(&mut self) {
        let Some(how) = self.referencing.filter(|_| !self.moving()) else { return };
        self.referencing = None;
        let switches = self.stage.status().msta;
        self.referenced = match how {
            // The stage's own home search ends exactly on the switch and counts 0 there.
            Referencing::ReferenceSwitch => self.stage.on_home_switch(),
            Referencing::NegativeLimit => switches & msta::MINUS_LS != 0,
            Referencing::PositiveLimit => switches & msta::PLUS_LS != 0,
        };
        if self.referenced && how != Referencing::ReferenceSwitch {
            let physical = self.stage.physical_position();
            self.stage.set_position(physical);
        }
        self.target = self.position();
    }

    fn reference(&mut self, how: Referencing) {
        self.referenced = false;
        self.referencing = Some(how);
        let (v, a) = (self.reference_velocity, self.acceleration);
        match how {
            Referencing::ReferenceSwitch => self.stage.home(true, 0.0, v, a),
            Referencing::NegativeLimit => self.stage.move_velocity(0.0, -v, a),
            Referencing::PositiveLimit => self.stage.move_velocity(0.0, v, a),
        }
    }

    fn parameter(&self, id: u32) -> Option<f64> {
        Some(match id {
            parameter::ACCELERATION => self.acceleration,
            parameter::DECELERATION => self.deceleration,
            parameter::COUNTS_PER_UNIT_NUMERATOR => COUNTS_PER_UNIT.0,
            parameter::COUNTS_PER_UNIT_DENOMINATOR => COUNTS_PER_UNIT.1,
            parameter::REFERENCE_VELOCITY => self.reference_velocity,
            // Maximum velocity, maximum acceleration and deceleration.
            0x0A => MAX_VELOCITY,
            0x4A | 0x4B => MAX_ACCELERATION,
            // Has a reference switch; has no limit switches.
            0x14 => 1.0,
            0x32 => 0.0,
            _ => return None,
        })
    }
}

/// A PI C-884 of some axes (`"1"` …), behind one connection.
pub(crate) struct Gcs2Emulator {
    axes: Vec<EmulatedAxis>,
    /// The last error, until `ERR?` reads it.
    error: u32,
    input: Vec<u8>,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

/// What a command line does: a reply to send, or nothing (a setter, done).
type Outcome = Result<Option<String>, u32>;

impl Gcs2Emulator {
    /// A controller with `axes` axes on `mechanics` (mm), as at power-up.
    pub(crate) fn new(axes: usize, mechanics: &SimConfig) -> Self {
        Self {
            axes: (0..axes).map(|_| EmulatedAxis::new(mechanics)).collect(),
            error: 0,
            input: Vec::new(),
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    /// The index of the axis named `name`.
    fn index(&self, name: &str) -> Result<usize, u32> {
        name.parse::<usize>()
            .ok()
            .filter(|n| (1..=self.axes.len()).contains(n))
            .map(|n| n - 1)
            .ok_or(code::INVALID_AXIS)
    }

    /// The axes named by `names`, or every axis when none is.
    fn indexes(&self, names: &[&str]) -> Result<Vec<usize>, u32> {
        if names.is_empty() {
            return Ok((0..self.axes.len()).collect());
        }
        names.iter().map(|name| self.index(name)).collect()
    }

    /// `<axis> <value>` pairs.
    fn pairs(&self, args: &[&str]) -> Result<Vec<(usize, f64)>, u32> {
        if args.is_empty() || !args.len().is_multiple_of(2) {
            return Err(code::PARAMETER_COUNT);
        }
        args.chunks(2)
            .map(|pair| {
                let value = pair[1].parse::<f64>().ok().filter(|v| v.is_finite()).ok_or(code::PARAMETER_SYNTAX)?;
                Ok((self.index(pair[0])?, value))
            })
            .collect()
    }

    /// One command line (without its LF).
    fn execute(&mut self, line: &str) -> Outcome {
        let mut words = line.split_whitespace();
        let command = words.next().unwrap_or_default();
        let args: Vec<&str> = words.collect();
        match command {
            "*IDN?" => Ok(Some(format!(
                "(c)2019 Physik Instrumente (PI) GmbH & Co. KG, {}.4DC, 119000001, 1.3.4.2",
                MODELS[3]
            ))),
            "SAI?" => Ok(Some(lines((1..=self.axes.len()).map(|n| n.to_string())))),
            "ERR?" => Ok(Some(std::mem::take(&mut self.error).to_string())),
            "POS?" | "MOV?" | "FRF?" | "SVO?" | "RON?" | "ONT?" | "VEL?" | "ACC?" | "DEC?" | "TMN?" | "TMX?"
            | "LIM?" | "TRS?" | "HAR?" | "CST?" => {
                let indexes = self.indexes(&args)?;
                Ok(Some(lines(indexes.into_iter().map(|i| format!("{}={}", i + 1, self.axis_query(command, i))))))
            }
            "SRG?" => self.register_query(&args),
            "SPA?" => self.parameter_query(&args),
            "MOV" | "MVR" => self.move_to(command == "MVR", &args),
            "VEL" | "ACC" | "DEC" => {
                let (limit, refusal) = if command == "VEL" {
                    (MAX_VELOCITY, code::VELOCITY_OUT_OF_LIMITS)
                } else {
                    (MAX_ACCELERATION, code::PARAMETER_OUT_OF_RANGE)
                };
                let pairs = self.pairs(&args)?;
                if pairs.iter().any(|(_, v)| *v <= 0.0 || *v > limit) {
                    return Err(refusal);
                }
                for (i, value) in pairs {
                    let axis = &mut self.axes[i];
                    *match command {
                        "VEL" => &mut axis.velocity,
                        "ACC" => &mut axis.acceleration,
                        _ => &mut axis.deceleration,
                    } = value;
                }
                Ok(None)
            }
            "SVO" | "RON" => {
                let pairs = self.pairs(&args)?;
                if pairs.iter().any(|(_, v)| *v != 0.0 && *v != 1.0) {
                    return Err(code::PARAMETER_SYNTAX);
                }
                for (i, value) in pairs {
                    if command == "SVO" {
                        self.axes[i].set_servo(value == 1.0);
                    } else {
                        self.axes[i].reference_mode = value == 1.0;
                    }
                }
                Ok(None)
            }
            "POS" => {
                let pairs = self.pairs(&args)?;
                if pairs.iter().any(|(i, _)| self.axes[*i].reference_mode) {
                    return Err(code::REFERENCE_MODE_ON);
                }
                for (i, value) in pairs {
                    let axis = &mut self.axes[i];
                    axis.stage.set_position(value);
                    axis.target = value;
                    axis.referenced = true;
                }
                Ok(None)
            }
            "SPA" => self.set_parameter(&args),
            "HLT" => {
                for i in self.indexes(&args)? {
                    self.axes[i].halt();
                }
                Err(code::STOPPED)
            }
            "STP" if args.is_empty() => {
                self.stop_all();
                Err(code::STOPPED)
            }
            "FRF" | "FNL" | "FPL" => {
                let indexes = self.indexes(&args)?;
                if indexes.iter().any(|i| !self.axes[*i].servo) {
                    return Err(code::MOVE_REFUSED);
                }
                if indexes.iter().any(|i| !self.axes[*i].reference_mode) {
                    return Err(code::REFERENCING_DISABLED);
                }
                let how = match command {
                    "FRF" => Referencing::ReferenceSwitch,
                    "FNL" => Referencing::NegativeLimit,
                    _ => Referencing::PositiveLimit,
                };
                for i in indexes {
                    self.axes[i].reference(how);
                }
                Ok(None)
            }
            _ => Err(code::UNKNOWN_COMMAND),
        }
    }

    fn axis_query(&self, command: &str, i: usize) -> String {
        let axis = &self.axes[i];
        let flag = |on: bool| u8::from(on).to_string();
        match command {
            "POS?" => format!("{:.7}", axis.position()),
            "MOV?" => format!("{:.7}", axis.target),
            "FRF?" => flag(axis.referenced),
            "SVO?" => flag(axis.servo),
            "RON?" => flag(axis.reference_mode),
            "ONT?" => flag(axis.register() & register::ON_TARGET != 0),
            "VEL?" => format!("{:.7}", axis.velocity),
            "ACC?" => format!("{:.7}", axis.acceleration),
            "DEC?" => format!("{:.7}", axis.deceleration),
            "TMN?" => format!("{:.7}", TRAVEL.0),
            "TMX?" => format!("{:.7}", TRAVEL.1),
            "LIM?" | "TRS?" => flag(true),
            "HAR?" => flag(false),
            _ => "M-403.2DG".to_string(),
        }
    }

    fn register_query(&self, args: &[&str]) -> Outcome {
        let indexes: Vec<usize> = if args.is_empty() {
            (0..self.axes.len()).collect()
        } else {
            if !args.len().is_multiple_of(2) {
                return Err(code::PARAMETER_COUNT);
            }
            let pairs: Result<Vec<usize>, u32> = args
                .chunks(2)
                .map(
                    |pair| if parse_id(pair[1]) == Some(1) { self.index(pair[0]) } else { Err(code::PARAMETER_SYNTAX) },
                )
                .collect();
            pairs?
        };
        Ok(Some(lines(indexes.into_iter().map(|i| format!("{} 1=0x{:04X}", i + 1, self.axes[i].register())))))
    }

    fn parameter_query(&self, args: &[&str]) -> Outcome {
        if args.is_empty() || !args.len().is_multiple_of(2) {
            return Err(code::PARAMETER_COUNT);
        }
        let mut replies = Vec::new();
        for pair in args.chunks(2) {
            let i = self.index(pair[0])?;
            let value = parse_id(pair[1]).and_then(|id| self.axes[i].parameter(id)).ok_or(code::UNKNOWN_PARAMETER)?;
            replies.push(format!("{} {}={value}", i + 1, pair[1]));
        }
        Ok(Some(lines(replies.into_iter())))
    }

    fn set_parameter(&mut self, args: &[&str]) -> Outcome {
        if args.is_empty() || !args.len().is_multiple_of(3) {
            return Err(code::PARAMETER_COUNT);
        }
        let mut settings = Vec::new();
        for triple in args.chunks(3) {
            let i = self.index(triple[0])?;
            let id = parse_id(triple[1]).ok_or(code::PARAMETER_SYNTAX)?;
            let value = triple[2].parse::<f64>().ok().filter(|v| v.is_finite()).ok_or(code::PARAMETER_SYNTAX)?;
            let limit = match id {
                parameter::ACCELERATION | parameter::DECELERATION => MAX_ACCELERATION,
                parameter::REFERENCE_VELOCITY => MAX_VELOCITY,
                // Known, but not for writing at the user's command level.
                _ if self.axes[i].parameter(id).is_some() => return Err(code::PROTECTED_PARAMETER),
                _ => return Err(code::UNKNOWN_PARAMETER),
            };
            if value <= 0.0 || value > limit {
                return Err(code::PARAMETER_OUT_OF_RANGE);
            }
            settings.push((i, id, value));
        }
        for (i, id, value) in settings {
            let axis = &mut self.axes[i];
            *match id {
                parameter::ACCELERATION => &mut axis.acceleration,
                parameter::DECELERATION => &mut axis.deceleration,
                _ => &mut axis.reference_velocity,
            } = value;
        }
        Ok(None)
    }

    fn move_to(&mut self, relative: bool, args: &[&str]) -> Outcome {
        let mut targets = Vec::new();
        for (i, value) in self.pairs(args)? {
            let axis = &self.axes[i];
            if !axis.servo || (axis.reference_mode && !axis.referenced) {
                return Err(code::MOVE_REFUSED);
            }
            // MVR is relative to the target of a motion under way, else to where the axis is.
            let base = if axis.moving() { axis.target } else { axis.position() };
            let target = if relative { base + value } else { value };
            if !(TRAVEL.0..=TRAVEL.1).contains(&target) {
                return Err(code::POSITION_OUT_OF_LIMITS);
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

    fn stop_all(&mut self) {
        for axis in &mut self.axes {
            // STP stops abruptly, not on the deceleration ramp.
            axis.stage.stop(0.0);
            axis.referencing = None;
        }
    }

    /// A single-byte command: its reply, if it has one.
    fn single_byte(&mut self, byte: u8) -> Option<Vec<u8>> {
        match byte {
            STATUS_REGISTERS => {
                let registers: String = self.axes.iter().map(|a| format!("{:04X}", a.register())).collect();
                Some(format!("0x{registers}\n").into_bytes())
            }
            MOTION_STATUS => {
                let mask = self
                    .axes
                    .iter()
                    .enumerate()
                    .filter(|(_, a)| a.moving())
                    .fold(0u64, |mask, (i, _)| mask | 1u64.checked_shl(i as u32).unwrap_or(0));
                Some(format!("{mask:X}\n").into_bytes())
            }
            READY_STATUS => {
                let ready = self.axes.iter().all(|a| a.referencing.is_none());
                Some(vec![if ready { 0xB1 } else { 0xB0 }, b'\n'])
            }
            _ => {
                self.stop_all();
                self.error = code::STOPPED;
                None
            }
        }
    }

    fn advance(&mut self, now: Instant) {
        for axis in &mut self.axes {
            axis.stage.advance(now);
            axis.settle_referencing();
        }
    }
}

/// Reply lines as the controller joins them: a space before every LF but the last.
fn lines(items: impl Iterator<Item = String>) -> String {
    items.collect::<Vec<_>>().join(" \n")
}

impl Emulator for Gcs2Emulator {
    fn name(&self) -> &'static str {
        NAME
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        self.advance(now);
        for &byte in bytes {
            // A control byte at the start of a line is a whole command, acted on at once.
            if self.input.is_empty() && [STATUS_REGISTERS, MOTION_STATUS, READY_STATUS, STOP_ALL].contains(&byte) {
                if let Some(reply) = self.single_byte(byte) {
                    self.output.push_back(reply);
                }
                continue;
            }
            if byte != b'\n' {
                self.input.push(byte);
                continue;
            }
            let line = String::from_utf8_lossy(&std::mem::take(&mut self.input)).replace('\r', "");
            if line.trim().is_empty() {
                continue;
            }
            match self.execute(line.trim()) {
                Ok(Some(reply)) => self.output.push_back(format!("{reply}\n").into_bytes()),
                Ok(None) => {}
                // A refused query is not answered; the error waits for ERR?.
                Err(code) => {
                    if REQUEST_FAULTS.contains(&code) {
                        self.malformed += 1;
                    }
                    self.error = code;
                }
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
        let index = channel.checked_sub(1)?;
        self.axes.get_mut(index).map(|a| &mut a.stage)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        // A motion error: the position error grew too large, the servo switched itself off.
        let Some(axis) = channel.checked_sub(1).and_then(|i| self.axes.get_mut(i)) else { return false };
        axis.set_servo(false);
        self.error = code::MOTION_ERROR;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn c884() -> Gcs2Emulator {
        Gcs2Emulator::new(4, &mechanics())
    }

    /// Send `bytes` at `at` seconds; every reply, as text.
    fn send(e: &mut Gcs2Emulator, at: f64, bytes: &[u8]) -> Vec<String> {
        e.handle_input(Instant::ZERO + Duration::from_secs_f64(at), bytes);
        std::iter::from_fn(|| e.poll_transmit()).map(|r| String::from_utf8_lossy(&r).into_owned()).collect()
    }

    #[test]
    fn queries_answer_axis_equals_value_on_lines_joined_by_a_space() {
        let mut e = c884();
        assert!(send(&mut e, 0.0, b"*IDN?\n")[0].contains("C-884"));
        assert_eq!(send(&mut e, 0.0, b"SAI?\n"), ["1 \n2 \n3 \n4\n"]);
        assert_eq!(send(&mut e, 0.0, b"POS? 1 3\n"), ["1=0.0000000 \n3=0.0000000\n"], "0 wherever it stands");
        assert_eq!(send(&mut e, 0.0, b"SPA? 2 14\nSPA? 2 0xF\n"), ["2 14=10000\n", "2 0xF=1\n"]);
        assert_eq!(send(&mut e, 0.0, b"SRG? 4 1\n"), ["4 1=0x0002\n"], "servo off, on the reference's plus side");
        assert_eq!(send(&mut e, 0.0, b"TMX? 1\nFRF? 1\n"), ["1=19.5000000\n", "1=0\n"]);
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn setters_are_silent_and_errors_wait_for_err() {
        let mut e = c884();
        assert_eq!(send(&mut e, 0.0, b"SVO 1 1\n"), Vec::<String>::new());
        assert_eq!(send(&mut e, 0.0, b"MOV 1 1.5\nERR?\n"), ["5\n"], "not referenced");
        assert_eq!(send(&mut e, 0.0, b"ERR?\n"), ["0\n"], "read and cleared");
        assert_eq!(send(&mut e, 0.0, b"POS 1 2\nERR?\n"), ["88\n"], "reference mode is on");
        assert_eq!(send(&mut e, 0.0, b"RON 1 0\nPOS 1 2\nRON 1 1\nERR?\nFRF? 1\n"), ["0\n", "1=1\n"]);
        assert_eq!(send(&mut e, 0.0, b"MOV 1 25\nERR?\n"), ["7\n"]);
        assert_eq!(send(&mut e, 0.0, b"VEL 1 80\nERR?\n"), ["8\n"]);
        assert_eq!(send(&mut e, 0.0, b"VEL 1 1\nMOV 1 3\nERR?\n"), ["0\n"]);
        // 10 ms ramps at 100 mm/s²: 5 µm short of 0.5 mm travelled.
        assert_eq!(send(&mut e, 0.5, b"POS? 1\n"), ["1=2.4950000\n"]);
        assert_eq!(send(&mut e, 0.5, b"HLT 1\nERR?\n"), ["10\n"]);
        assert_eq!(send(&mut e, 1.0, b"SRG? 1 1\nHLT 1\nERR?\n"), ["1 1=0x9002\n", "10\n"], "even when idle");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_request_the_controller_cannot_parse_is_counted_and_a_query_so_is_not_answered() {
        let mut e = c884();
        assert_eq!(send(&mut e, 0.0, b"POS? 9\nMOVE 1 2\nMOV 1\nSPA? 1 999\n"), Vec::<String>::new());
        assert_eq!(e.malformed(), 4);
        assert_eq!(send(&mut e, 0.0, b"ERR?\n"), ["54\n"], "only the last error is kept");
    }

    #[test]
    fn single_bytes_answer_in_their_own_formats_at_once() {
        let mut e = c884();
        send(&mut e, 0.0, b"SVO 1 1 2 1\nRON 2 0\nPOS 2 0\nVEL 2 1\nMOV 2 1\n");
        assert_eq!(send(&mut e, 0.1, b"\x04"), ["0x9002300200020002\n"]);
        assert_eq!(send(&mut e, 0.1, b"\x05"), ["2\n"]);
        assert_eq!(send(&mut e, 0.1, b"\x07"), ["\u{fffd}\n"], "0xB1: ready");
        send(&mut e, 0.1, b"FRF 1\n");
        let mut ready = Vec::new();
        e.handle_input(Instant::ZERO + Duration::from_millis(200), b"\x07");
        ready.extend(e.poll_transmit());
        assert_eq!(ready, [vec![0xB0, b'\n']], "referencing: not ready");
        assert_eq!(send(&mut e, 0.2, b"\x18ERR?\n\x05"), ["10\n", "0\n"], "#24 stops every axis");
    }

    #[test]
    fn referencing_ends_on_the_switch_and_counts_from_it() {
        let mut e = c884();
        send(&mut e, 0.0, b"SVO 1 1 2 1\nSPA 1 0x50 5\nFRF 1\nFNL 2\n");
        assert_eq!(send(&mut e, 0.5, b"SRG? 1 1\nERR?\n"), ["1 1=0x7002\n", "0\n"]);
        assert_eq!(send(&mut e, 10.0, b"FRF? 1 2\nPOS? 1 2\n"), ["1=1 \n2=1\n", "1=0.0000000 \n2=-20.0000000\n"]);
        assert_eq!(send(&mut e, 10.0, b"SRG? 2 1\n"), ["2 1=0x9001\n"], "on the negative limit switch");
        send(&mut e, 10.0, b"MOV 1 3\n");
        send(&mut e, 12.0, b"FRF 1\n");
        assert_eq!(send(&mut e, 12.1, b"HLT 1\n"), Vec::<String>::new());
        assert_eq!(send(&mut e, 13.0, b"FRF? 1\nERR?\n"), ["1=0\n", "10\n"], "a referencing halted leaves none");
    }

    #[test]
    fn a_raised_error_is_a_motion_error_that_switches_the_servo_off() {
        let mut e = c884();
        send(&mut e, 0.0, b"SVO 3 1\n");
        assert!(e.raise_error(3));
        assert!(!e.raise_error(0) && !e.raise_error(5));
        assert_eq!(send(&mut e, 0.0, b"SVO? 3\nERR?\n"), ["3=0\n", "1024\n"]);
    }
}
