//! A chain of Newport SMC100CC controllers (a CONEX-CC speaks the same command set alone at
//! address 1; its TRACKING mode is not emulated), written from Newport's "SMC100CC & SMC100PP Single-Axis DC or Stepper Motion
//! Controller/Driver User's Manual" (EDH0206En, chapter 6 "Controller Commands"; its pages
//! are at <https://www.manualslib.com/manual/1238858/Newport-Smc100cc.html>).
//!
//! **Lines.** `nnAAxx` ended by CR LF: `nn` the controller's address (1 to 31), `AA` the
//! two-letter command in either case, `xx` a value or `?`. Blanks are ignored anywhere, also
//! inside a number (§6.3). Each controller takes only the lines with its own address; what
//! follows a command that takes no parameter is ignored (§6.3: "all remaining characters ...
//! will be ignored"). Only queries are answered, as `nnAA<value>` CR LF; a setter is silent,
//! and a command that cannot be carried out is silent too: the controller memorises an error
//! letter that `TE` reads (§6.3). An unknown command is memorised as `A`; there is no reply.
//!
//! **Commands emulated** (§6.5): `AC` `VA` (acceleration, velocity), `HT` `OH` `OT` (home
//! search type, speed, time-out), `ID` (stage identifier), `KP` `KI` `KD` (PID gains), `MM`
//! (leave / enter DISABLE), `OR` (home search), `PA` `PR` (absolute / relative move), `PW`
//! (enter / leave CONFIGURATION), `RS` (reset), `SL` `SR` (software limits), `ST` (stop),
//! `TB` (error string), `TE` (last command error), `TH` (set-point position), `TP`
//! (position), `TS` (positioner errors and state), `VE` (version), `ZT` (all parameters).
//! `BA` `BH` `DV` `FD` `FE` `FF` `JR` `KV` `SU` (the stage's other parameters) are kept, read
//! in any state and set in CONFIGURATION only, without acting on the motion. `VB` and `FR`,
//! the manual's "Not for CC" commands, are memorised as `X` ("Command not allowed for CC
//! version"). The manual's remaining commands (`JD` `JM` `PT` `QI` `RA` `RB` `SA` `SB` `SC`
//! `SE` `ZX`) are not emulated: a line with one of them is memorised as `A`, as an unknown
//! command would be, and counted in `malformed()`; `RS##` (reset the RS-485 address) is taken
//! as `RS`, the address of an emulated controller being its place on the chain.
//!
//! **States** (`TS`, last two hex digits): power-up and `RS` give NOT REFERENCED from reset
//! (0A). `OR` → HOMING (1E) → READY from HOMING (32) at the stage's home switch, whose
//! position becomes 0; `ST` during the search, or a search longer than `OT`, ends in NOT
//! REFERENCED from HOMING (0B), the latter with the homing time-out bit. `PA`/`PR` in READY
//! → MOVING (28) → READY from MOVING (33); a motion that ends on an end-of-run switch ends in
//! NOT REFERENCED from MOVING (0F). `MM0` READY → DISABLE from READY (3C), `MM1` DISABLE →
//! READY from DISABLE (34). `PW1` NOT REFERENCED → CONFIGURATION (14), `PW0` back to NOT
//! REFERENCED from CONFIGURATION (0C), the settings made in CONFIGURATION kept (the "EEPROM").
//! A command not allowed in the present state is memorised with that state's letter: H NOT
//! REFERENCED, I CONFIGURATION, J DISABLE, K READY, L HOMING, M MOVING.
//!
//! **Positioner errors** (`TS`, first four hex digits): 0001 negative end of run, 0002
//! positive end of run (while the stage stands on the switch), 0004 peak current limit, 0008
//! RMS current limit, 0010 short circuit, 0020 following error, 0040 homing time-out, 0080
//! wrong ESP stage, 0100 DC voltage too low, 0200 80 W output power exceeded. The emulator
//! raises 0001, 0002, 0020 (`raise_error`: the servo drops out, MOVING → DISABLE from MOVING
//! 3D, READY → 3C, HOMING → 0B) and 0040.
//!
//! **Readings taken where the manual leaves room:**
//! - A line without an address, or with one outside 1–31, is error B ("Controller address
//!   not correct", the manual's "Missing: Error B / Out of range: Error B"); a floating-point
//!   address is error A. Some controller must memorise it: here the first of the chain, the
//!   one the RS-232 link reaches. A line for a valid address with no controller there gets
//!   nothing from anyone.
//! - `TE` returns the letter and clears it (`@` after). `TB` without a parameter does the
//!   same with the letter's text after it (`1TBH Command not allowed in NOT REFERENCED
//!   state`); `TBx` gives the text of letter `x` and clears nothing.
//! - `PR` is relative to the set-point (`TH`), which is where the stage stands once a motion
//!   was stopped short.
//! - `OR` during a home search is `E` ("Home sequence already started") rather than `L`.
//! - `ST` is taken in every state but CONFIGURATION (I) and does nothing when nothing moves.
//! - `VA`, `AC`, `SL`, `SR` are taken in NOT REFERENCED, CONFIGURATION, READY and DISABLE
//!   (refused in HOMING and MOVING). Set in CONFIGURATION they are stored (kept by `RS`);
//!   elsewhere they change the working values only, which `RS` restores.
//! - `KP`, `KI`, `KD` are taken in CONFIGURATION and DISABLE only (refused H, K, L, M).
//! - `HT`, `OH`, `OT`, `ID` are set in CONFIGURATION only; every `XX?` is read in any state.
//! - The positioner error bits stay set until `MM1`, `OR` or `RS` (the end-of-run bits follow
//!   the switches).
//! - `MM?` answers the state code (as `TS`'s last two digits); `PW?` answers 1 in
//!   CONFIGURATION, else 0.
//! - `ZT` answers one line per emulated parameter, `nnXXvalue`, in alphabetical order (the
//!   form of the dump is not given in the pages at hand).
//! - `PA?` and `PR?` answer the set-point, as `TH` does.
//! - `VE` answers `SMC_CC - Version 2.0.0 (emulated)`: the wording of the version text is the
//!   firmware's, so no driver should read more than its start.
//! - The stage (see [`Smc100Emulator::stage`]) is a 25 mm DC stage, home switch mid-travel;
//!   every home search type but HT1 (the present position is home) ends on that switch, the
//!   switches' wiring (MZ, end of run, index) not being simulated. `N` ("Current position out
//!   of software limit") is never raised. A reset is instantaneous here.

use crate::emulator::axes;
use crate::{Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};
use zmotor_msgs::bits::msta;

const NAME: &str = "newport_smc100";
/// RS-485 addresses a controller can have.
const LAST_ADDRESS: usize = 31;
/// Longest line the emulated input buffer holds.
const LINE_CAPACITY: usize = 256;
/// Parameters must be smaller than this in magnitude (the manual's ranges end at 1E12).
const LARGEST: f64 = 1e12;
/// Targets this close beyond a software limit are on it (decimal millimetres in binary).
const LIMIT_TOLERANCE: f64 = 1e-9;

/// Where the end-of-run switches are, mm (the software limits are just inside).
const END_OF_RUN: f64 = 13.0;

/// Controller states (`TS`, last two hex digits).
mod state {
    pub(super) const NOT_REFERENCED_FROM_RESET: u8 = 0x0A;
    pub(super) const NOT_REFERENCED_FROM_HOMING: u8 = 0x0B;
    pub(super) const NOT_REFERENCED_FROM_CONFIGURATION: u8 = 0x0C;
    pub(super) const NOT_REFERENCED_FROM_MOVING: u8 = 0x0F;
    pub(super) const CONFIGURATION: u8 = 0x14;
    pub(super) const HOMING: u8 = 0x1E;
    pub(super) const MOVING: u8 = 0x28;
    pub(super) const READY_FROM_HOMING: u8 = 0x32;
    pub(super) const READY_FROM_MOVING: u8 = 0x33;
    pub(super) const READY_FROM_DISABLE: u8 = 0x34;
    pub(super) const DISABLE_FROM_READY: u8 = 0x3C;
    pub(super) const DISABLE_FROM_MOVING: u8 = 0x3D;
}

/// Positioner error bits (`TS`, first four hex digits).
mod fault {
    pub(super) const NEGATIVE_END_OF_RUN: u16 = 0x0001;
    pub(super) const POSITIVE_END_OF_RUN: u16 = 0x0002;
    pub(super) const FOLLOWING_ERROR: u16 = 0x0020;
    pub(super) const HOMING_TIME_OUT: u16 = 0x0040;
}

/// The manual's text for each `TE` letter.
fn error_text(letter: char) -> Option<&'static str> {
    Some(match letter {
        '@' => "No error",
        'A' => "Unknown message code or floating point controller address",
        'B' => "Controller address not correct",
        'C' => "Parameter missing or out of range",
        'D' => "Command not allowed",
        'E' => "Home sequence already started",
        'F' => "ESP stage name unknown",
        'G' => "Displacement out of limits",
        'H' => "Command not allowed in NOT REFERENCED state",
        'I' => "Command not allowed in CONFIGURATION state",
        'J' => "Command not allowed in DISABLE state",
        'K' => "Command not allowed in READY state",
        'L' => "Command not allowed in HOMING state",
        'M' => "Command not allowed in MOVING state",
        'N' => "Current position out of software limit",
        'S' => "Communication Time Out",
        'U' => "Error during EEPROM access",
        'V' => "Error during command execution",
        'W' => "Command not allowed for PP version",
        'X' => "Command not allowed for CC version",
        _ => return None,
    })
}

/// The family of states a command's usage is given for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Family {
    NotReferenced,
    Configuration,
    Homing,
    Moving,
    Ready,
    Disable,
}

impl Family {
    fn of(code: u8) -> Family {
        match code {
            0x14 => Family::Configuration,
            0x1E | 0x1F => Family::Homing,
            0x28 => Family::Moving,
            0x32..=0x35 => Family::Ready,
            0x3C..=0x3E => Family::Disable,
            _ => Family::NotReferenced,
        }
    }

    /// The letter a command not allowed in this state is memorised with.
    fn refusal(self) -> char {
        match self {
            Family::NotReferenced => 'H',
            Family::Configuration => 'I',
            Family::Disable => 'J',
            Family::Ready => 'K',
            Family::Homing => 'L',
            Family::Moving => 'M',
        }
    }
}

/// What the controller keeps over a reset, and works with.
#[derive(Clone, Debug)]
struct Parameters {
    acceleration: f64,
    velocity: f64,
    low_limit: f64,
    high_limit: f64,
    home_type: u8,
    home_velocity: f64,
    home_time_out: f64,
    gains: [f64; 3],
    stage: String,
    /// The stage's other parameters, set in CONFIGURATION only, in `STAGE_PARAMETERS` order.
    other: [f64; STAGE_PARAMETERS.len()],
}

/// The manual's other settable parameters of an SMC100CC that this emulator keeps without
/// acting on them (`ZT` lists them): command, the emulated stage's value, the least value.
const STAGE_PARAMETERS: [(&str, f64, f64); 9] = [
    ("BA", 0.0, 0.0),     // backlash compensation
    ("BH", 0.0, 0.0),     // hysteresis compensation
    ("DV", 12.0, 12.0),   // driver voltage
    ("FD", 1000.0, 1e-6), // low pass filter for Kd
    ("FE", 0.05, 1e-6),   // following error limit
    ("FF", 0.0, 0.0),     // friction compensation
    ("JR", 0.05, 1e-3),   // jerk time
    ("KV", 0.0, 0.0),     // velocity feed forward
    ("SU", 0.0001, 1e-6), // encoder increment value
];

impl Default for Parameters {
    fn default() -> Self {
        Self {
            acceleration: 10.0,
            velocity: 2.5,
            low_limit: -12.5,
            high_limit: 12.5,
            home_type: 0,
            home_velocity: 2.5,
            home_time_out: 100.0,
            gains: [1500.0, 300.0, 0.0],
            stage: "TRA25CC".to_string(),
            other: STAGE_PARAMETERS.map(|(_, value, _)| value),
        }
    }
}

/// What one line asked of a controller.
enum Outcome {
    /// Answer these values (each after the address and the command).
    Reply(Vec<String>),
    /// Answer these lines, each after the address only (`ZT`).
    Lines(Vec<String>),
    /// Carried out, nothing to say.
    Done,
    /// Not carried out: the letter memorised.
    Error(char),
}

/// One controller of the chain.
struct Controller {
    axis: SimAxis,
    state: u8,
    /// The last command error, `@` for none.
    error: char,
    /// Latched positioner error bits (the end-of-run bits come from the switches).
    faults: u16,
    /// Stored (saved by leaving CONFIGURATION).
    stored: Parameters,
    /// In use.
    working: Parameters,
    target: f64,
    home_started: Instant,
    /// `ST` came during the home search.
    home_stopped: bool,
}

impl Controller {
    fn new(axis: SimAxis) -> Self {
        Self {
            axis,
            state: state::NOT_REFERENCED_FROM_RESET,
            error: '@',
            faults: 0,
            stored: Parameters::default(),
            working: Parameters::default(),
            target: 0.0,
            home_started: Instant::ZERO,
            home_stopped: false,
        }
    }

    fn family(&self) -> Family {
        Family::of(self.state)
    }

    fn position(&self) -> f64 {
        self.axis.status().position
    }

    fn end_of_run(&self) -> u16 {
        let bits = self.axis.status().msta;
        let mut faults = 0;
        if bits & msta::MINUS_LS != 0 {
            faults |= fault::NEGATIVE_END_OF_RUN;
        }
        if bits & msta::PLUS_LS != 0 {
            faults |= fault::POSITIVE_END_OF_RUN;
        }
        faults
    }

    /// Time passed to `now`: motions end, home searches time out.
    fn update(&mut self, now: Instant) {
        self.axis.advance(now);
        if self.state == state::HOMING
            && self.axis.is_moving()
            && now.saturating_duration_since(self.home_started).as_secs_f64() > self.working.home_time_out
        {
            self.axis.stop(0.0);
            self.faults |= fault::HOMING_TIME_OUT;
            self.home_stopped = true;
        }
        if self.axis.is_moving() {
            return;
        }
        if matches!(self.state, state::MOVING | state::HOMING) && (self.position() - self.target).abs() > 1e-9 {
            // Stopped short (ST, a switch, a time-out): the set-point is where it stands.
            self.target = self.position();
        }
        match self.state {
            state::MOVING if self.end_of_run() != 0 => self.state = state::NOT_REFERENCED_FROM_MOVING,
            state::MOVING => self.state = state::READY_FROM_MOVING,
            state::HOMING if self.home_stopped => self.state = state::NOT_REFERENCED_FROM_HOMING,
            state::HOMING => self.state = state::READY_FROM_HOMING,
            _ => {}
        }
    }

    /// Carry out `command` (upper case) with `parameter` (blanks removed) at `now`.
    fn execute(&mut self, now: Instant, command: &str, parameter: &str) -> Outcome {
        let family = self.family();
        let query = parameter == "?";
        let value = parameter.parse::<f64>().ok().filter(|v| v.is_finite() && v.abs() < LARGEST);
        match command {
            "TE" => Outcome::Reply(vec![std::mem::replace(&mut self.error, '@').to_string()]),
            "TB" => {
                let letter = match parameter.chars().next() {
                    None => std::mem::replace(&mut self.error, '@'),
                    Some(c) => c.to_ascii_uppercase(),
                };
                match error_text(letter) {
                    Some(text) => Outcome::Reply(vec![format!("{letter} {text}")]),
                    None => Outcome::Error('C'),
                }
            }
            "TS" => Outcome::Reply(vec![format!("{:04X}{:02X}", self.faults | self.end_of_run(), self.state)]),
            "TP" => Outcome::Reply(vec![number(self.position())]),
            "TH" => Outcome::Reply(vec![number(self.target)]),
            "VE" => Outcome::Reply(vec!["SMC_CC - Version 2.0.0 (emulated)".to_string()]),
            "ZT" => Outcome::Lines(self.all_parameters()),
            "RS" => {
                self.axis.stop(0.0);
                self.axis.enable(true);
                self.state = state::NOT_REFERENCED_FROM_RESET;
                self.faults = 0;
                self.home_stopped = false;
                self.working = self.stored.clone();
                self.target = self.position();
                Outcome::Done
            }
            "ST" => {
                if family == Family::Configuration {
                    return Outcome::Error('I');
                }
                if matches!(family, Family::Moving | Family::Homing) {
                    self.home_stopped = family == Family::Homing;
                    self.axis.stop(self.working.acceleration);
                }
                Outcome::Done
            }
            "OR" => match family {
                Family::NotReferenced => {
                    self.state = state::HOMING;
                    self.faults = 0;
                    self.home_stopped = false;
                    self.home_started = now;
                    self.target = 0.0;
                    if self.working.home_type == 1 {
                        // HT1: the present position is home, nothing moves.
                        self.axis.set_position(0.0);
                    } else {
                        let speed = self.working.home_velocity;
                        self.axis.home(false, 0.0, speed, self.working.acceleration);
                    }
                    Outcome::Done
                }
                Family::Homing => Outcome::Error('E'),
                _ => Outcome::Error(family.refusal()),
            },
            "PA" | "PR" => {
                if query {
                    return Outcome::Reply(vec![number(self.target)]);
                }
                let Some(value) = value else { return Outcome::Error('C') };
                if family != Family::Ready {
                    return Outcome::Error(family.refusal());
                }
                let target = if command == "PR" { self.target + value } else { value };
                let within = target >= self.working.low_limit - LIMIT_TOLERANCE
                    && target <= self.working.high_limit + LIMIT_TOLERANCE;
                if !within {
                    return Outcome::Error('G');
                }
                self.target = target;
                self.state = state::MOVING;
                let p = &self.working;
                self.axis.move_to(target, false, 0.0, p.velocity, p.acceleration);
                Outcome::Done
            }
            "MM" => {
                if query {
                    return Outcome::Reply(vec![format!("{:02X}", self.state)]);
                }
                match (parameter, family) {
                    ("0", Family::Ready) => {
                        self.state = state::DISABLE_FROM_READY;
                        self.axis.enable(false);
                    }
                    ("1", Family::Disable) => {
                        self.state = state::READY_FROM_DISABLE;
                        self.faults = 0;
                        self.axis.enable(true);
                        self.target = self.position();
                    }
                    ("0" | "1", Family::Ready | Family::Disable) => {}
                    ("0" | "1", _) => return Outcome::Error(family.refusal()),
                    _ => return Outcome::Error('C'),
                }
                Outcome::Done
            }
            "PW" => {
                if query {
                    return Outcome::Reply(vec![u8::from(family == Family::Configuration).to_string()]);
                }
                match (parameter, family) {
                    ("1", Family::NotReferenced) => self.state = state::CONFIGURATION,
                    ("0", Family::Configuration) => {
                        self.stored = self.working.clone();
                        self.state = state::NOT_REFERENCED_FROM_CONFIGURATION;
                    }
                    ("1", Family::Configuration) | ("0", Family::NotReferenced) => {}
                    ("0" | "1", _) => return Outcome::Error(family.refusal()),
                    _ => return Outcome::Error('C'),
                }
                Outcome::Done
            }
            "ID" => {
                if query {
                    return Outcome::Reply(vec![self.working.stage.clone()]);
                }
                if family != Family::Configuration {
                    return Outcome::Error(family.refusal());
                }
                if parameter.is_empty() || parameter.len() > 31 {
                    return Outcome::Error('C');
                }
                self.working.stage = parameter.to_string();
                Outcome::Done
            }
            "AC" | "VA" | "SL" | "SR" | "HT" | "OH" | "OT" | "KP" | "KI" | "KD" => {
                if query {
                    return Outcome::Reply(vec![number(self.parameter(command))]);
                }
                let Some(value) = value.filter(|v| in_range(command, *v)) else { return Outcome::Error('C') };
                let allowed = match command {
                    "AC" | "VA" | "SL" | "SR" => !matches!(family, Family::Homing | Family::Moving),
                    "KP" | "KI" | "KD" => matches!(family, Family::Configuration | Family::Disable),
                    _ => family == Family::Configuration,
                };
                if !allowed {
                    return Outcome::Error(family.refusal());
                }
                self.set_parameter(command, value);
                Outcome::Done
            }
            "VB" | "FR" => Outcome::Error('X'),
            _ => match STAGE_PARAMETERS.iter().position(|(name, _, _)| *name == command) {
                Some(index) => self.stage_parameter(index, family, query, value),
                None => Outcome::Error('A'),
            },
        }
    }

    /// One of `STAGE_PARAMETERS`: read in any state, set in CONFIGURATION only.
    fn stage_parameter(&mut self, index: usize, family: Family, query: bool, value: Option<f64>) -> Outcome {
        if query {
            return Outcome::Reply(vec![number(self.working.other[index])]);
        }
        let least = STAGE_PARAMETERS[index].2;
        let Some(value) = value.filter(|v| *v >= least) else { return Outcome::Error('C') };
        if family != Family::Configuration {
            return Outcome::Error(family.refusal());
        }
        self.working.other[index] = value;
        Outcome::Done
    }

    fn parameter(&self, command: &str) -> f64 {
        let p = &self.working;
        match command {
            "AC" => p.acceleration,
            "VA" => p.velocity,
            "SL" => p.low_limit,
            "SR" => p.high_limit,
            "HT" => f64::from(p.home_type),
            "OH" => p.home_velocity,
            "OT" => p.home_time_out,
            "KP" => p.gains[0],
            "KI" => p.gains[1],
            _ => p.gains[2],
        }
    }

    fn set_parameter(&mut self, command: &str, value: f64) {
        let p = &mut self.working;
        match command {
            "AC" => p.acceleration = value,
            "VA" => p.velocity = value,
            "SL" => p.low_limit = value,
            "SR" => p.high_limit = value,
            "HT" => p.home_type = value as u8,
            "OH" => p.home_velocity = value,
            "OT" => p.home_time_out = value,
            "KP" => p.gains[0] = value,
            "KI" => p.gains[1] = value,
            _ => p.gains[2] = value,
        }
        if matches!(command, "KP" | "KI" | "KD") {
            let gain = [zmotor_msgs::Gain::Proportional, zmotor_msgs::Gain::Integral, zmotor_msgs::Gain::Derivative]
                [["KP", "KI", "KD"].iter().position(|k| *k == command).unwrap_or(0)];
            self.axis.set_gain(gain, value);
        }
    }

    /// `ZT`: every emulated parameter, alphabetically.
    fn all_parameters(&self) -> Vec<String> {
        let mut lines: Vec<(String, String)> = ["AC", "HT", "KD", "KI", "KP", "OH", "OT", "SL", "SR", "VA"]
            .iter()
            .map(|command| (command.to_string(), number(self.parameter(command))))
            .collect();
        lines.push(("ID".to_string(), self.working.stage.clone()));
        for ((command, _, _), value) in STAGE_PARAMETERS.iter().zip(self.working.other) {
            lines.push((command.to_string(), number(value)));
        }
        lines.sort();
        lines.into_iter().map(|(command, value)| format!("{command}{value}")).collect()
    }

    /// A following error: the servo drops out.
    fn following_error(&mut self) {
        self.faults |= fault::FOLLOWING_ERROR;
        self.state = match self.family() {
            Family::Moving => state::DISABLE_FROM_MOVING,
            Family::Ready => state::DISABLE_FROM_READY,
            Family::Homing => state::NOT_REFERENCED_FROM_HOMING,
            _ => return,
        };
        self.axis.enable(false);
    }
}

/// Whether `value` is in the manual's range for `command`'s parameter.
fn in_range(command: &str, value: f64) -> bool {
    match command {
        "AC" | "VA" | "OH" => value > 1e-6,
        "SL" => value <= 0.0,
        "SR" => value >= 0.0,
        "HT" => value.fract() == 0.0 && (0.0..=4.0).contains(&value),
        "OT" => value >= 1.0,
        _ => value >= 0.0,
    }
}

/// A number as the controller prints it: to a millionth, no trailing zeros.
fn number(value: f64) -> String {
    let rounded = (value * 1e6).round() / 1e6 + 0.0;
    format!("{rounded}")
}

/// A chain of SMC100CC controllers at addresses 1, 2, … (see the module documentation).
pub struct Smc100Emulator {
    controllers: Vec<Controller>,
    lines: Lines,
    replies: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl Smc100Emulator {
    /// A chain of `controllers` controllers (31 at most), at addresses 1 to `controllers`, each
    /// driving a stage of `mechanics` (in millimetres), all just powered up.
    pub fn new(controllers: usize, mechanics: &SimConfig) -> Self {
        let count = controllers.min(LAST_ADDRESS);
        Self {
            controllers: axes(count, mechanics).into_iter().map(Controller::new).collect(),
            lines: Lines::new(b"\r\n", LINE_CAPACITY),
            replies: VecDeque::new(),
            malformed: 0,
        }
    }

    /// The stage each controller drives, in millimetres: 25 mm of travel between end-of-run
    /// switches at ±13 mm (the software limits at ±12.5 mm are inside them), the home switch
    /// in the middle, the carriage there at power-up, a DC servo motor.
    pub fn stage() -> SimConfig {
        SimConfig {
            high_limit_switch: Some(END_OF_RUN),
            low_limit_switch: Some(-END_OF_RUN),
            home_switch: 0.0,
            servo: true,
            ..SimConfig::default()
        }
    }

    fn controller(&mut self, address: usize) -> Option<&mut Controller> {
        self.controllers.get_mut(address.checked_sub(1)?)
    }

    /// Memorise `letter` at the first controller (a line no controller could take).
    fn chain_error(&mut self, letter: char) {
        self.malformed += 1;
        if let Some(first) = self.controllers.first_mut() {
            first.error = letter;
        }
    }

    fn on_line(&mut self, now: Instant, line: &[u8]) {
        let text: String = String::from_utf8_lossy(line).chars().filter(|c| !c.is_whitespace()).collect();
        if text.is_empty() {
            return;
        }
        let digits = text.bytes().take_while(u8::is_ascii_digit).count();
        if text[digits..].starts_with('.') {
            return self.chain_error('A');
        }
        let Some(address) = text[..digits].parse::<usize>().ok().filter(|a| (1..=LAST_ADDRESS).contains(a)) else {
            return self.chain_error('B');
        };
        let rest = &text[digits..];
        let Some(controller) = self.controller(address) else { return };
        let well_formed = rest.len() >= 2 && rest.bytes().take(2).all(|b| b.is_ascii_alphabetic());
        let (replies, error) = if well_formed {
            let (command, parameter) = rest.split_at(2);
            let command = command.to_ascii_uppercase();
            controller.update(now);
            let outcome = controller.execute(now, &command, parameter);
            controller.update(now);
            match outcome {
                Outcome::Reply(values) => {
                    (values.into_iter().map(|v| format!("{address}{command}{v}\r\n")).collect(), None)
                }
                Outcome::Lines(values) => (values.into_iter().map(|v| format!("{address}{v}\r\n")).collect(), None),
                Outcome::Done => (Vec::new(), None),
                Outcome::Error(letter) => (Vec::new(), Some(letter)),
            }
        } else {
            (Vec::new(), Some('A'))
        };
        if let Some(letter) = error {
            controller.error = letter;
            if matches!(letter, 'A' | 'B' | 'C') {
                // Not well-formed for the protocol: a driver's fault.
                self.malformed += 1;
            }
        }
        self.replies.extend(replies.into_iter().map(String::into_bytes));
    }
}

impl Emulator for Smc100Emulator {
    fn name(&self) -> &'static str {
        NAME
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for controller in &mut self.controllers {
            controller.update(now);
        }
        for line in self.lines.push(bytes) {
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
        self.controller(channel).map(|c| &mut c.axis)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        match self.controller(channel) {
            Some(controller) => {
                controller.following_error();
                true
            }
            None => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use zmotor_core::SimSetting;
    use zmotor_msgs::Value;

    fn chain(controllers: usize) -> Smc100Emulator {
        Smc100Emulator::new(controllers, &Smc100Emulator::stage())
    }

    /// Send `line` at `seconds`; every reply line.
    fn ask(e: &mut Smc100Emulator, seconds: f64, line: &str) -> Vec<String> {
        e.handle_input(Instant::from_secs_f64(seconds), format!("{line}\r\n").as_bytes());
        std::iter::from_fn(|| e.poll_transmit()).map(|b| String::from_utf8_lossy(&b).into_owned()).collect()
    }

    fn one(e: &mut Smc100Emulator, seconds: f64, line: &str) -> String {
        let replies = ask(e, seconds, line);
        assert_eq!(replies.len(), 1, "{line}: {replies:?}");
        replies[0].trim_end().to_string()
    }

    #[test]
    fn what_newport_s_own_software_asks_is_answered() {
        let mut e = chain(1);
        assert_eq!(one(&mut e, 0.0, "1ID?"), "1IDTRA25CC");
        assert!(one(&mut e, 0.0, "1VE").starts_with("1VE"));
        assert_eq!(one(&mut e, 0.0, "1TS"), "1TS00000A", "power-up: NOT REFERENCED from reset");
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TE@");
        assert_eq!(one(&mut e, 0.0, "1TB"), "1TB@ No error");
        let zt = ask(&mut e, 0.0, "1ZT");
        assert!(zt.contains(&"1SL-12.5\r\n".to_string()) && zt.contains(&"1VA2.5\r\n".to_string()), "{zt:?}");
        assert!(zt.iter().all(|l| l.starts_with('1') && l.ends_with("\r\n")));
        assert!(zt.contains(&"1FE0.05\r\n".to_string()), "{zt:?}");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn an_unknown_command_gets_no_reply_and_te_says_a() {
        let mut e = chain(1);
        assert!(ask(&mut e, 0.0, "1XY").is_empty());
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TEA");
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TE@", "read once");
        assert!(ask(&mut e, 0.0, "1QQ5").is_empty());
        assert_eq!(one(&mut e, 0.0, "1TB"), "1TBA Unknown message code or floating point controller address");
        assert_eq!(one(&mut e, 0.0, "1TBG"), "1TBG Displacement out of limits");
        assert_eq!(e.malformed(), 2);
        assert!(ask(&mut e, 0.0, "1VB1").is_empty());
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TEX", "VB is not for a CC controller");
        ask(&mut e, 0.0, "1FE0.1");
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TEH", "stage parameters in CONFIGURATION only");
        ask(&mut e, 0.0, "1PW1");
        ask(&mut e, 0.0, "1FE0.1");
        assert_eq!(one(&mut e, 0.0, "1FE?"), "1FE0.1");
    }

    #[test]
    fn addresses_blanks_and_case_as_the_manual_says() {
        let mut e = chain(2);
        assert_eq!(one(&mut e, 0.0, "2 s r ?"), "2SR12.5", "blanks anywhere");
        assert_eq!(one(&mut e, 0.0, "1va?"), "1VA2.5", "either case");
        assert!(ask(&mut e, 0.0, "1VA1. 5").is_empty(), "a setter is silent, blanks inside a number too");
        assert_eq!(one(&mut e, 0.0, "1VA?"), "1VA1.5");
        assert!(ask(&mut e, 0.0, "3TS").is_empty(), "no controller 3 on the chain");
        assert!(ask(&mut e, 0.0, "TS").is_empty());
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TEB", "a missing address");
        assert!(ask(&mut e, 0.0, "32TS").is_empty());
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TEB", "an address out of range");
        assert!(ask(&mut e, 0.0, "1.5TS").is_empty());
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TEA", "a floating point address");
        assert!(ask(&mut e, 0.0, "2VA-1").is_empty());
        assert_eq!(one(&mut e, 0.0, "2TE"), "2TEC");
        assert_eq!(one(&mut e, 0.0, "1TP?"), "1TP0", "what follows TP is ignored");
        assert_eq!(e.malformed(), 4);
    }

    #[test]
    fn each_state_refuses_what_it_must_with_its_letter() {
        let mut e = chain(1);
        ask(&mut e, 0.0, "1PA1");
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TEH", "NOT REFERENCED");
        ask(&mut e, 0.0, "1MM0");
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TEH");
        ask(&mut e, 0.0, "1PW1");
        assert_eq!(one(&mut e, 0.0, "1TS"), "1TS000014");
        ask(&mut e, 0.0, "1OR");
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TEI", "CONFIGURATION");
        ask(&mut e, 0.0, "1HT1");
        ask(&mut e, 0.0, "1SR10");
        ask(&mut e, 0.0, "1PW0");
        assert_eq!(one(&mut e, 0.0, "1TS"), "1TS00000C");
        ask(&mut e, 0.0, "1RS");
        assert_eq!(one(&mut e, 0.0, "1SR?"), "1SR10", "kept over a reset");
        assert_eq!(one(&mut e, 0.0, "1HT?"), "1HT1");
        ask(&mut e, 0.0, "1OR");
        assert_eq!(one(&mut e, 0.0, "1TS"), "1TS000032", "HT1: home where it stands");
        ask(&mut e, 0.0, "1OR");
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TEK", "READY");
        ask(&mut e, 0.0, "1KP100");
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TEK");
        ask(&mut e, 0.0, "1PA11");
        assert_eq!(one(&mut e, 0.0, "1TE"), "1TEG", "beyond SR");
        ask(&mut e, 0.0, "1PA5");
        assert_eq!(one(&mut e, 0.1, "1TS"), "1TS000028");
        ask(&mut e, 0.1, "1PA6");
        assert_eq!(one(&mut e, 0.1, "1TE"), "1TEM", "MOVING");
        assert_eq!(one(&mut e, 0.1, "1TH"), "1TH5");
        assert_eq!(one(&mut e, 10.0, "1TS"), "1TS000033");
        assert_eq!(one(&mut e, 10.0, "1TP"), "1TP5");
        ask(&mut e, 10.0, "1MM0");
        assert_eq!(one(&mut e, 10.0, "1MM?"), "1MM3C");
        ask(&mut e, 10.0, "1PR1");
        assert_eq!(one(&mut e, 10.0, "1TE"), "1TEJ", "DISABLE");
        ask(&mut e, 10.0, "1KD3");
        assert_eq!(one(&mut e, 10.0, "1TE"), "1TE@", "gains in DISABLE");
        ask(&mut e, 10.0, "1MM1");
        assert_eq!(one(&mut e, 10.0, "1TS"), "1TS000034");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_home_search_ends_at_the_home_switch_or_not_referenced_when_stopped() {
        let mut e = chain(1);
        e.axis(1).expect("controller 1").apply(SimSetting::Position, &Value::Float(10.0)).unwrap();
        ask(&mut e, 0.0, "1OR");
        assert_eq!(one(&mut e, 0.1, "1TS"), "1TS00001E");
        ask(&mut e, 0.2, "1OR");
        assert_eq!(one(&mut e, 0.2, "1TE"), "1TEE");
        ask(&mut e, 1.0, "1ST");
        assert_eq!(one(&mut e, 3.0, "1TS"), "1TS00000B");
        ask(&mut e, 3.0, "1OR");
        assert_eq!(one(&mut e, 20.0, "1TS"), "1TS000032");
        assert_eq!(one(&mut e, 20.0, "1TP"), "1TP0");
    }

    #[test]
    fn a_home_search_longer_than_ot_times_out() {
        let mut e = chain(1);
        e.axis(1).expect("controller 1").apply(SimSetting::Position, &Value::Float(12.0)).unwrap();
        ask(&mut e, 0.0, "1PW1");
        ask(&mut e, 0.0, "1OT1");
        ask(&mut e, 0.0, "1PW0");
        ask(&mut e, 0.0, "1OR");
        assert_eq!(one(&mut e, 1.5, "1TS"), "1TS00400B");
    }

    #[test]
    fn a_move_onto_an_end_of_run_switch_ends_not_referenced() {
        let mut e = chain(1);
        ask(&mut e, 0.0, "1OR");
        ask(&mut e, 0.0, "1SR20");
        ask(&mut e, 0.0, "1PA20");
        assert_eq!(one(&mut e, 20.0, "1TS"), "1TS00020F");
        assert_eq!(one(&mut e, 20.0, "1TP"), "1TP13");
        ask(&mut e, 20.0, "1RS");
        assert_eq!(one(&mut e, 20.0, "1SR?"), "1SR12.5", "the working limit is lost by a reset");
    }

    #[test]
    fn a_raised_error_is_a_following_error_and_the_servo_drops_out() {
        let mut e = chain(2);
        assert!(!e.raise_error(3));
        ask(&mut e, 0.0, "2OR");
        ask(&mut e, 0.0, "2PA5");
        assert!(e.raise_error(2));
        assert_eq!(one(&mut e, 0.5, "2TS"), "2TS00203D");
        e.handle_input(Instant::from_secs_f64(5.0), b"");
        assert!(!e.axis(2).expect("controller 2").is_moving());
        ask(&mut e, 5.0, "2MM1");
        assert_eq!(one(&mut e, 5.0, "2TS"), "2TS000034");
        assert_eq!(e.name(), "newport_smc100");
    }
}
