//! A chain of Newport SMC100 controllers (or one CONEX-CC, address 1): lines
//! `<address><CMD><argument>\r\n`, blanks ignored, the command in either case. Each controller
//! answers only lines with its own address, and only queries (`TP`, `TS`, `TE`, `TB`, `TH`,
//! `VE`, `XX?`), as `<address><CMD><value>\r\n`; setters are silent, and a command it refuses
//! stores the TE error letter (read and cleared by `TE`). Lines for an address with no
//! controller on the chain get no answer.
//!
//! Each controller runs the state machine of the manual on a physical simulator in
//! millimetres (see [`stage`]): power-up in NOT REFERENCED (0A); `OR` → HOMING (1E) → READY
//! from HOMING (32) at the home switch, whose position becomes 0 (`ST` on the way: NOT
//! REFERENCED from HOMING, 0B); `PA`/`PR` in READY → MOVING (28) → READY from MOVING (33),
//! within the software limits SL…SR (else G); a motion that runs into an end-of-run switch
//! stops there in NOT REFERENCED from MOVING (0F), the switch's bit set in `TS` while the stage
//! stands on it; `MM0`/`MM1` READY ↔ DISABLE (3C, 34); `PW1`/`PW0` CONFIGURATION (14, 0C);
//! `RS` back to NOT REFERENCED (0A) with the EEPROM's speed, acceleration, limits and gains.
//! A command refused for the state stores H, I, J, K, L or M as the manual says. The reset
//! is instantaneous here: a real controller is deaf for a moment after `RS`, and the layer
//! retries the query that meets it. A request that is not well-formed (no address, an
//! address outside 1…31, an unknown command, a missing or out-of-range argument: errors A and
//! C) is counted in `malformed()`. `raise_error` is a following error: the servo drops out
//! (DISABLE from MOVING or from READY, or NOT REFERENCED from HOMING) and `TS` shows bit 0x0020
//! until `MM1`, `OR` or `RS`.

use super::{axes, Emulator};
use crate::newport::{
    error_meaning, errors, state, state_class, state_refusal, StateClass, ADDRESSES, LARGEST_VALUE, NAME, TERMINATOR,
};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};
use zmotor_msgs::bits::msta;

/// The software limits at power-up (SL = −this, SR = +this), mm.
pub(crate) const SOFT_LIMIT: f64 = 12.5;

/// Where the end-of-run switches are (− and +), mm: just beyond the software limits, as on a
/// real stage.
pub(crate) const END_OF_RUN: f64 = 13.0;

/// `VA` at power-up, mm/s.
pub(crate) const DEFAULT_VELOCITY: f64 = 2.5;

/// `AC` at power-up, mm/s².
pub(crate) const DEFAULT_ACCELERATION: f64 = 10.0;

/// The home search's speed (`OH`), mm/s.
pub(crate) const HOME_VELOCITY: f64 = 2.5;

/// Targets this close beyond a software limit are on it (decimal millimetres in binary).
const LIMIT_TOLERANCE: f64 = 1e-9;

/// The mechanics of one stage, in millimetres: a 25 mm DC servo stage with its home switch in
/// the middle, the carriage at 0 at power-up.
pub(crate) fn stage() -> SimConfig {
    SimConfig {
        high_limit_switch: Some(END_OF_RUN),
        low_limit_switch: Some(-END_OF_RUN),
        home_switch: 0.0,
        servo: true,
        ..SimConfig::default()
    }
}

/// What a controller does with one line.
enum Outcome {
    /// Answer with this value after the echo.
    Reply(String),
    /// A setter that was carried out.
    Silent,
    /// Refused: the TE letter stored.
    Refused(char),
}

/// One controller on the chain.
struct Unit {
    axis: SimAxis,
    state: u8,
    /// The TE letter of the last refused command, `@` once read.
    error: char,
    /// Fault bits latched (the end-of-run bits are read from the switches).
    faults: u16,
    velocity: f64,
    acceleration: f64,
    low_limit: f64,
    high_limit: f64,
    gains: [f64; 3],
    target: f64,
    /// A stop came during the home search: it ends not referenced.
    home_stopped: bool,
}

impl Unit {
    fn new(axis: SimAxis) -> Self {
        let mut unit = Self {
            axis,
            state: state::NOT_REFERENCED_FROM_RESET,
            error: '@',
            faults: 0,
            velocity: 0.0,
            acceleration: 0.0,
            low_limit: 0.0,
            high_limit: 0.0,
            gains: [0.0; 3],
            target: 0.0,
            home_stopped: false,
        };
        unit.restore_eeprom();
        unit
    }

    /// What the controller loads at power-up and reset.
    fn restore_eeprom(&mut self) {
        self.velocity = DEFAULT_VELOCITY;
        self.acceleration = DEFAULT_ACCELERATION;
        self.low_limit = -SOFT_LIMIT;
        self.high_limit = SOFT_LIMIT;
        self.gains = [1500.0, 300.0, 0.0];
    }

    fn class(&self) -> StateClass {
        state_class(self.state).unwrap_or(StateClass::NotReferenced)
    }

    fn position(&self) -> f64 {
        self.axis.status().position
    }

    fn end_of_run_bits(&self) -> u16 {
        let bits = self.axis.status().msta;
        let flag = |bit: u32, error: u16| if bits & bit != 0 { error } else { 0 };
        flag(msta::PLUS_LS, errors::POSITIVE_END_OF_RUN) | flag(msta::MINUS_LS, errors::NEGATIVE_END_OF_RUN)
    }

    /// The state once a motion is over.
    fn settle(&mut self) {
        if self.axis.is_moving() {
            return;
        }
        match self.state {
            state::MOVING if self.end_of_run_bits() != 0 => self.state = state::NOT_REFERENCED_FROM_MOVING,
            state::MOVING => self.state = state::READY_FROM_MOVING,
            state::HOMING if self.home_stopped => self.state = state::NOT_REFERENCED_FROM_HOMING,
            state::HOMING => self.state = state::READY_FROM_HOMING,
            _ => {}
        }
    }

    /// Carry out one command (`command` upper case, `argument` without blanks).
    fn execute(&mut self, command: &str, argument: &str) -> Outcome {
        let class = self.class();
        let refused_here = Outcome::Refused(state_refusal(class));
        let number = argument.parse::<f64>().ok().filter(|v| v.is_finite() && v.abs() < LARGEST_VALUE);
        match (command, argument) {
            ("TP", "") => Outcome::Reply(millimetres(self.position())),
            ("TS", "") => Outcome::Reply(format!("{:04X}{:02X}", self.faults | self.end_of_run_bits(), self.state)),
            ("TE", "") => Outcome::Reply(std::mem::replace(&mut self.error, '@').to_string()),
            ("TB", "") => {
                let code = std::mem::replace(&mut self.error, '@');
                Outcome::Reply(format!("{code} {}", error_meaning(code).unwrap_or("")))
            }
            ("TH", "") => Outcome::Reply(millimetres(self.target)),
            ("VE", "") => Outcome::Reply(" SMC_CC - Version 2.0.0 (zmotor emulator)".to_string()),
            ("MM", "?") => Outcome::Reply(format!("{:02X}", self.state)),
            (_, "?") => match self.setting(command) {
                Some(value) => Outcome::Reply(millimetres(value)),
                None => Outcome::Refused('A'),
            },
            ("VA" | "AC", _) => match number.filter(|v| *v > 0.0) {
                Some(rate) if command == "VA" => {
                    self.velocity = rate;
                    Outcome::Silent
                }
                Some(rate) => {
                    self.acceleration = rate;
                    Outcome::Silent
                }
                None => Outcome::Refused('C'),
            },
            ("PA" | "PR", _) => {
                let Some(value) = number else { return Outcome::Refused('C') };
                if class != StateClass::Ready {
                    return refused_here;
                }
                let target = if command == "PR" { self.position() + value } else { value };
                if target < self.low_limit - LIMIT_TOLERANCE || target > self.high_limit + LIMIT_TOLERANCE {
                    return Outcome::Refused('G');
                }
                self.target = target;
                self.state = state::MOVING;
                self.axis.move_to(target, false, 0.0, self.velocity, self.acceleration);
                Outcome::Silent
            }
            ("OR", "") => match class {
                StateClass::NotReferenced => {
                    self.state = state::HOMING;
                    self.faults = 0;
                    self.home_stopped = false;
                    self.target = 0.0;
                    self.axis.home(false, 0.0, HOME_VELOCITY, self.acceleration);
                    Outcome::Silent
                }
                StateClass::Homing => Outcome::Refused('E'),
                _ => refused_here,
            },
            ("ST", "") => {
                if matches!(class, StateClass::Moving | StateClass::Homing) {
                    self.home_stopped = class == StateClass::Homing;
                    self.axis.stop(self.acceleration);
                }
                Outcome::Silent
            }
            ("RS", "") => {
                self.axis.stop(0.0);
                self.axis.enable(true);
                self.state = state::NOT_REFERENCED_FROM_RESET;
                self.error = '@';
                self.faults = 0;
                self.home_stopped = false;
                self.restore_eeprom();
                Outcome::Silent
            }
            ("MM", "0" | "1") => {
                let on = argument == "1";
                match class {
                    StateClass::Ready if !on => {
                        self.state = state::DISABLE_FROM_READY;
                        self.axis.enable(false);
                    }
                    StateClass::Disable if on => {
                        self.state = state::READY_FROM_DISABLE;
                        self.faults = 0;
                        self.axis.enable(true);
                    }
                    StateClass::Ready | StateClass::Disable => {}
                    _ => return refused_here,
                }
                Outcome::Silent
            }
            ("SL" | "SR", _) => {
                let within = |v: &f64| if command == "SL" { *v <= 0.0 } else { *v >= 0.0 };
                let Some(limit) = number.filter(within) else { return Outcome::Refused('C') };
                if matches!(class, StateClass::Moving | StateClass::Homing | StateClass::Jogging) {
                    return refused_here;
                }
                *(if command == "SL" { &mut self.low_limit } else { &mut self.high_limit }) = limit;
                Outcome::Silent
            }
            ("KP" | "KI" | "KD", _) => {
                let Some(gain) = number.filter(|v| *v >= 0.0) else { return Outcome::Refused('C') };
                if !matches!(class, StateClass::NotReferenced | StateClass::Configuration | StateClass::Disable) {
                    return refused_here;
                }
                self.gains[["KP", "KI", "KD"].iter().position(|k| *k == command).unwrap_or(0)] = gain;
                Outcome::Silent
            }
            ("PW", "1") if class == StateClass::NotReferenced => {
                self.state = state::CONFIGURATION;
                Outcome::Silent
            }
            ("PW", "0") if class == StateClass::Configuration => {
                self.state = state::NOT_REFERENCED_FROM_CONFIGURATION;
                Outcome::Silent
            }
            ("PW", "0" | "1") => refused_here,
            _ => Outcome::Refused(if command.len() == 2 && known_command(command) { 'C' } else { 'A' }),
        }
    }

    /// A setting `XX?` reads, in its own units.
    fn setting(&self, command: &str) -> Option<f64> {
        Some(match command {
            "VA" => self.velocity,
            "AC" => self.acceleration,
            "SL" => self.low_limit,
            "SR" => self.high_limit,
            "KP" => self.gains[0],
            "KI" => self.gains[1],
            "KD" => self.gains[2],
            "OH" => HOME_VELOCITY,
            _ => return None,
        })
    }

    /// A following error: the servo drops out.
    fn following_error(&mut self) {
        self.faults |= errors::FOLLOWING_ERROR;
        match self.class() {
            StateClass::Moving => self.state = state::DISABLE_FROM_MOVING,
            StateClass::Ready => self.state = state::DISABLE_FROM_READY,
            StateClass::Homing => self.state = state::NOT_REFERENCED_FROM_HOMING,
            _ => return,
        }
        self.axis.enable(false);
    }
}

/// Commands this emulator knows, whose argument was wrong when they fall through.
fn known_command(command: &str) -> bool {
    [
        "TP", "TS", "TE", "TB", "TH", "VE", "MM", "VA", "AC", "PA", "PR", "OR", "ST", "RS", "SL", "SR", "KP", "KI",
        "KD", "PW",
    ]
    .contains(&command)
}

/// A position or setting as the controller prints it: to a millionth of a millimetre, no
/// trailing zeros.
fn millimetres(value: f64) -> String {
    let rounded = (value * 1e6).round() / 1e6 + 0.0;
    format!("{rounded}")
}

/// A chain of SMC100 controllers at addresses 1, 2, … (see the module documentation).
pub(crate) struct Smc100Emulator {
    units: Vec<Unit>,
    input: Vec<u8>,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl Smc100Emulator {
    /// A chain of `controllers` controllers (at most 31), addresses 1 to `controllers`, each
    /// on `mechanics` (in millimetres), all just powered up.
    pub(crate) fn new(controllers: usize, mechanics: &SimConfig) -> Self {
        let controllers = controllers.min(*ADDRESSES.end());
        Self {
            units: axes(controllers, mechanics).into_iter().map(Unit::new).collect(),
            input: Vec::new(),
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    /// The controller at `address`.
    fn unit(&mut self, address: usize) -> Option<&mut Unit> {
        self.units.get_mut(address.checked_sub(1)?)
    }

    /// Carry out one line (terminator removed).
    fn on_line(&mut self, line: &[u8]) {
        let Ok(text) = std::str::from_utf8(line) else {
            self.malformed += 1;
            return;
        };
        let compact: String = text.chars().filter(|c| *c != ' ' && *c != '\t').collect();
        if compact.is_empty() {
            return;
        }
        let digits = compact.bytes().take_while(u8::is_ascii_digit).count();
        let address = compact[..digits].parse::<usize>().ok().filter(|a| digits <= 2 && ADDRESSES.contains(a));
        let Some(address) = address else {
            // No controller takes it: a driver's fault.
            self.malformed += 1;
            return;
        };
        let rest = &compact[digits..];
        let well_formed = rest.len() >= 2 && rest.as_bytes()[..2].iter().all(u8::is_ascii_alphabetic);
        let Some(unit) = self.units.get_mut(address - 1) else {
            // Another controller's line, and none is there: nobody answers.
            if !well_formed {
                self.malformed += 1;
            }
            return;
        };
        let outcome = if well_formed {
            let (command, argument) = rest.split_at(2);
            let command = command.to_ascii_uppercase();
            unit.settle();
            let outcome = unit.execute(&command, argument);
            unit.settle();
            match outcome {
                Outcome::Reply(value) => Some(format!("{address}{command}{value}\r\n")),
                Outcome::Silent => None,
                Outcome::Refused(code) => {
                    unit.error = code;
                    if matches!(code, 'A' | 'C') {
                        self.malformed += 1;
                    }
                    None
                }
            }
        } else {
            unit.error = 'A';
            self.malformed += 1;
            None
        };
        self.output.extend(outcome.map(String::into_bytes));
    }
}

impl Emulator for Smc100Emulator {
    fn name(&self) -> &'static str {
        NAME
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for unit in &mut self.units {
            unit.axis.advance(now);
            unit.settle();
        }
        self.input.extend_from_slice(bytes);
        while let Some(at) = self.input.windows(TERMINATOR.len()).position(|w| w == TERMINATOR) {
            let line: Vec<u8> = self.input.drain(..at + TERMINATOR.len()).take(at).collect();
            self.on_line(&line);
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.output.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.unit(channel).map(|unit| &mut unit.axis)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        match self.unit(channel) {
            Some(unit) => {
                unit.following_error();
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
        Smc100Emulator::new(controllers, &stage())
    }

    /// Send `line` at `seconds`; the reply, if any.
    fn ask(e: &mut Smc100Emulator, seconds: f64, line: &str) -> Option<String> {
        e.handle_input(Instant::from_secs_f64(seconds), format!("{line}\r\n").as_bytes());
        e.poll_transmit().map(|b| String::from_utf8_lossy(&b).into_owned())
    }

    fn state_of(e: &mut Smc100Emulator, seconds: f64, address: usize) -> String {
        let reply = ask(e, seconds, &format!("{address}TS")).expect("TS is answered");
        reply.trim_end().to_string()
    }

    #[test]
    fn only_queries_are_answered_and_only_at_the_controller_s_own_address() {
        let mut e = chain(2);
        assert_eq!(ask(&mut e, 0.0, "1TS").as_deref(), Some("1TS00000A\r\n"));
        assert_eq!(ask(&mut e, 0.0, "2TP").as_deref(), Some("2TP0\r\n"));
        assert_eq!(ask(&mut e, 0.0, "2 s r ?").as_deref(), Some("2SR12.5\r\n"), "blanks ignored");
        assert_eq!(ask(&mut e, 0.0, "1va?").as_deref(), Some("1VA2.5\r\n"), "either case");
        assert_eq!(ask(&mut e, 0.0, "1VA1.5"), None, "a setter is silent");
        assert_eq!(ask(&mut e, 0.0, "3TS"), None, "no controller 3 on this chain");
        assert_eq!(e.malformed(), 0);
        for garbage in ["TS", "0TS", "32TS", "1T", "1XX", "1VAfast", "1VA-1", "1SR-2"] {
            assert_eq!(ask(&mut e, 0.0, garbage), None, "{garbage}");
        }
        assert_eq!(e.malformed(), 8);
        assert_eq!(ask(&mut e, 0.0, "1TE").as_deref(), Some("1TEC\r\n"), "the last refusal");
        assert_eq!(ask(&mut e, 0.0, "1TE").as_deref(), Some("1TE@\r\n"), "read once");
    }

    #[test]
    fn the_state_machine_runs_from_power_up_through_home_and_moves() {
        let mut e = chain(1);
        assert_eq!(ask(&mut e, 0.0, "1PA1"), None);
        assert_eq!(ask(&mut e, 0.0, "1TE").as_deref(), Some("1TEH\r\n"), "not referenced");
        e.axis(1).expect("controller 1").apply(SimSetting::Position, &Value::Float(2.5)).unwrap();
        ask(&mut e, 0.0, "1OR");
        assert_eq!(state_of(&mut e, 0.1, 1), "1TS00001E");
        assert_eq!(ask(&mut e, 0.2, "1OR"), None);
        assert_eq!(ask(&mut e, 0.2, "1TE").as_deref(), Some("1TEE\r\n"), "home already started");
        assert_eq!(state_of(&mut e, 5.0, 1), "1TS000032");
        assert_eq!(ask(&mut e, 5.0, "1TP").as_deref(), Some("1TP0\r\n"), "the home switch is 0");
        ask(&mut e, 5.0, "1PA14");
        assert_eq!(ask(&mut e, 5.0, "1TE").as_deref(), Some("1TEG\r\n"), "beyond SR");
        ask(&mut e, 5.0, "1PR1.25");
        assert_eq!(state_of(&mut e, 5.1, 1), "1TS000028");
        assert_eq!(state_of(&mut e, 10.0, 1), "1TS000033");
        assert_eq!(ask(&mut e, 10.0, "1TP").as_deref(), Some("1TP1.25\r\n"));
        ask(&mut e, 10.0, "1MM0");
        assert_eq!(state_of(&mut e, 10.0, 1), "1TS00003C");
        ask(&mut e, 10.0, "1PA0");
        assert_eq!(ask(&mut e, 10.0, "1TE").as_deref(), Some("1TEJ\r\n"));
        ask(&mut e, 10.0, "1MM1");
        assert_eq!(state_of(&mut e, 10.0, 1), "1TS000034");
        ask(&mut e, 10.0, "1OR");
        assert_eq!(ask(&mut e, 10.0, "1TE").as_deref(), Some("1TEK\r\n"), "a home needs a reset first");
        ask(&mut e, 10.0, "1RS");
        assert_eq!(state_of(&mut e, 10.0, 1), "1TS00000A");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_move_into_an_end_of_run_switch_stops_there_not_referenced() {
        let mut e = chain(1);
        ask(&mut e, 0.0, "1OR");
        ask(&mut e, 0.0, "1SR20");
        ask(&mut e, 0.0, "1PA20");
        assert_eq!(ask(&mut e, 0.0, "1TE").as_deref(), Some("1TE@\r\n"));
        assert_eq!(state_of(&mut e, 20.0, 1), "1TS00020F");
        assert_eq!(ask(&mut e, 20.0, "1TP").as_deref(), Some("1TP13\r\n"));
    }

    #[test]
    fn a_stop_ends_a_move_ready_and_a_home_not_referenced() {
        let mut e = chain(1);
        e.axis(1).expect("controller 1").apply(SimSetting::Position, &Value::Float(10.0)).unwrap();
        ask(&mut e, 0.0, "1OR");
        ask(&mut e, 1.0, "1ST");
        assert_eq!(state_of(&mut e, 2.0, 1), "1TS00000B");
        ask(&mut e, 2.0, "1OR");
        assert_eq!(state_of(&mut e, 20.0, 1), "1TS000032");
        ask(&mut e, 20.0, "1PA10");
        ask(&mut e, 21.0, "1ST");
        assert_eq!(state_of(&mut e, 22.0, 1), "1TS000033");
        let stopped: f64 = ask(&mut e, 22.0, "1TP").expect("TP")[3..].trim().parse().expect("a number");
        assert!(stopped > 1.0 && stopped < 5.0, "{stopped}");
    }

    #[test]
    fn a_raised_error_is_a_following_error_that_drops_the_servo_until_enabled() {
        let mut e = chain(2);
        assert!(!e.raise_error(3), "no controller 3");
        ask(&mut e, 0.0, "2OR");
        ask(&mut e, 0.0, "2PA5");
        assert!(e.raise_error(2));
        assert_eq!(state_of(&mut e, 0.5, 2), "2TS00203D");
        let now = Instant::from_secs_f64(5.0);
        e.handle_input(now, b"");
        assert!(!e.axis(2).expect("controller 2").is_moving(), "the motion ended with the servo");
        ask(&mut e, 5.0, "2MM1");
        assert_eq!(state_of(&mut e, 5.0, 2), "2TS000034");
    }
}
