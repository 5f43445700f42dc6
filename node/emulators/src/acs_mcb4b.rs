//! The ACS (Advanced Control Systems) MCB-4B: four stepping motors on one board, driven over a
//! serial line in ASCII, one instruction a line.
//!
//! # Witnesses
//!
//! 1. ACS's "MCB-4B User's Manual", revision 1.1. Only its table of contents could be read
//!    (as published on vdocuments.site); the body of chapter 3 (the instruction set) could not.
//!    The contents still name the instructions and what they are: J jog rate index, C constant
//!    rate index, V velocity rate index, R ramp index, M move a number of steps at constant
//!    rate, G go to an absolute position, I index to a relative position, F finish
//!    (decelerating) and stop, and a "QUI…" stop (the line is cut there), after sections on
//!    error responses and on stepping rate indexes.
//! 2. The EPICS driver, epics-motor/motorAcs: `MCB4BDriver.cpp` (asyn motor, 2012) and the
//!    older `drvMCB4B.cc`/`devMCB4B.cc`, with the IOC's serial settings. They give the bytes:
//!    `#` and the motor's number in two digits, the instruction letter, its argument, `\r` both
//!    ways (19200 8N1); queries `P` `X` `E` `W` answered as `#01P=+1000`, `#01X=1`, `#01E=…`
//!    (+limit, −limit, home at characters 5, 6, 7), `#01W=1`; the settings `V=` `R=` `C=`
//!    `P=` `W=`; the motions `G±n` `I±n` `M±n` `H+` `H-`; the stop `Q`; and that "the MCB4B
//!    always sends back a response", which the driver reads and throws away after a command.
//!    They also carry the rate formulas, written as ACS's: speed = 115 200 / V steps/s, and
//!    acceleration = 720 000 / (256 − R) steps/s², with V (and C) from 2 and R from 1 to 255;
//!    C reaches 65 535 (`devMCB4B.cc` clamps it there).
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Rates.** The tables below are the index → rate direction of the EPICS formulas (the
//!   controller is given an index, it never sees a rate). J is taken to be a stepping rate
//!   index like V (its section follows "stepping rate indexes" in the manual), 2–255; it
//!   paces the jog box (connector H19), which the emulator has none of, so it is only
//!   acknowledged.
//! - **Acknowledgement of a setting or a motion.** Neither witness shows its text, only that it
//!   comes. Queries answer with their own line followed by `=value`, so a command is taken to
//!   be answered with its own line, echoed.
//! - **Error response.** The manual has a section on it, unread; the EPICS drivers never look.
//!   A line this emulator does not take (unknown letter, motor not on the board, argument out of
//!   range or not a number, not ASCII) is answered `?` and counted as malformed. No
//!   identification or version query is known for the MCB-4B: the EPICS drivers ask none
//!   (`drvMCB4B.cc` probes with `#00X` and names the board "MCB-4B" itself), so such a query
//!   gets the same `?`. For the same reason `raise_error` is false: the protocol has no error
//!   state to read back, and the driver would not read one.
//! - **Stops.** F decelerates on the ramp (R); Q, the "quick" stop the manual's cut line begins,
//!   stops the pulses at once.
//! - **M** moves at the constant rate C without a ramp.
//! - **Drive power (W).** With the drive off, a motion instruction is acknowledged and nothing
//!   moves (the step counter included). Drives are on at power-up: the asyn driver moves axes
//!   without ever powering them.
//! - **Power-up indexes**: V 255, R 1, C 255 (the slowest and gentlest); every EPICS
//!   motion sends V and R first anyway.
//! - **Numbers** are 32-bit signed (the EPICS drivers format an `int`), with or without a sign.
//! - **Input buffer**: 64 bytes without a `\r` overflow it (the size is not documented).

use crate::emulator::axes;
use crate::{Emulator, Lines};
use std::collections::VecDeque;
use std::ops::RangeInclusive;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

/// Motors on one board.
const MOTORS: usize = 4;

/// The line terminator, both ways.
const CR: &[u8] = b"\r";

/// Bytes without a terminator the board holds before its buffer overflows.
const INPUT_BUFFER: usize = 64;

/// The step clock the rate indexes divide: a rate index n is 115 200 / n steps/s.
const STEP_CLOCK: f64 = 115_200.0;

/// The ramp constant: a ramp index R is 720 000 / (256 − R) steps/s².
const RAMP_CONSTANT: f64 = 720_000.0;

/// Velocity (V) and jog (J) rate indexes.
const RATE_INDEXES: RangeInclusive<u32> = 2..=255;

/// Constant rate (C) indexes.
const CONSTANT_RATE_INDEXES: RangeInclusive<u32> = 2..=65_535;

/// Ramp (R) indexes.
const RAMP_INDEXES: RangeInclusive<u32> = 1..=255;

/// The speed, steps/s, of a rate index (V, J or C).
fn rate_of_index(index: u32) -> f64 {
    STEP_CLOCK / f64::from(index)
}

/// The acceleration, steps/s², of a ramp index (R).
fn ramp_of_index(index: u32) -> f64 {
    RAMP_CONSTANT / (256.0 - f64::from(index))
}

/// One motor's settings as the board keeps them.
#[derive(Clone, Copy, Debug)]
struct Settings {
    velocity_index: u32,
    ramp_index: u32,
    constant_index: u32,
    powered: bool,
}

impl Default for Settings {
    fn default() -> Self {
        Self { velocity_index: 255, ramp_index: 1, constant_index: 255, powered: true }
    }
}

/// An MCB-4B with motors `#00` … `#03` (as many as asked, four at most).
pub struct Mcb4bEmulator {
    axes: Vec<SimAxis>,
    settings: Vec<Settings>,
    lines: Lines,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl Mcb4bEmulator {
    /// A board with `channels` motors (four at most) on `mechanics`, drives powered.
    pub fn new(channels: usize, mechanics: &SimConfig) -> Self {
        let motors = channels.min(MOTORS);
        Self {
            axes: axes(motors, mechanics),
            settings: vec![Settings::default(); motors],
            lines: Lines::new(CR, INPUT_BUFFER),
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    /// The answer to one line (terminator removed), None when the board does not take it.
    fn answer(&mut self, line: &str) -> Option<String> {
        let rest = line.strip_prefix('#')?;
        let (address, rest) = (rest.get(..2)?, rest.get(2..)?);
        if !address.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        let motor: usize = address.parse().ok()?;
        let mut chars = rest.chars();
        let letter = chars.next()?;
        let argument = chars.as_str();
        let axis = self.axes.get_mut(motor)?;
        let settings = &mut self.settings[motor];
        let query = |value: String| Some(format!("#{address}{letter}={value}"));
        let flag = |on: bool| if on { '1' } else { '0' };
        let speed = rate_of_index(settings.velocity_index);
        let ramp = ramp_of_index(settings.ramp_index);
        match (letter, argument) {
            // Queries.
            ('P', "") => return query(format!("{:+}", axis.status().position.round() as i64)),
            ('X', "") => return query(flag(axis.is_moving()).to_string()),
            ('E', "") => {
                let state = axis.state();
                let flags = [state.high_limit, state.low_limit, axis.on_home_switch()];
                return query(flags.into_iter().map(flag).collect());
            }
            ('W', "") => return query(flag(settings.powered).to_string()),
            // Settings.
            ('V', _) => settings.velocity_index = index(argument, RATE_INDEXES)?,
            ('R', _) => settings.ramp_index = index(argument, RAMP_INDEXES)?,
            ('C', _) => settings.constant_index = index(argument, CONSTANT_RATE_INDEXES)?,
            // The jog box's rate: taken, and nothing here jogs by it.
            ('J', _) => {
                index(argument, RATE_INDEXES)?;
            }
            ('P', _) => axis.set_position(f64::from(number(argument.strip_prefix('=')?)?)),
            ('W', "=0" | "=1") => settings.powered = argument == "=1",
            // Motions.
            ('G' | 'I' | 'M', _) => {
                let steps = f64::from(number(argument)?);
                if settings.powered {
                    match letter {
                        'G' => axis.move_to(steps, false, 0.0, speed, ramp),
                        'I' => axis.move_to(steps, true, 0.0, speed, ramp),
                        _ => {
                            let constant = rate_of_index(settings.constant_index);
                            axis.move_to(steps, true, constant, constant, ramp);
                        }
                    }
                }
            }
            ('H', "+" | "-") => {
                if settings.powered {
                    axis.home(argument == "+", 0.0, speed, ramp);
                }
            }
            ('F', "") => axis.stop(ramp),
            // No deceleration: the pulses stop.
            ('Q', "") => axis.stop(0.0),
            _ => return None,
        }
        Some(format!("#{address}{letter}{argument}"))
    }
}

/// The index of `=n`, if within `range`.
fn index(argument: &str, range: RangeInclusive<u32>) -> Option<u32> {
    let digits = argument.strip_prefix('=')?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok().filter(|n| range.contains(n))
}

/// A signed 32-bit step count, its sign optional.
fn number(text: &str) -> Option<i32> {
    let digits = text.strip_prefix(['+', '-']).unwrap_or(text);
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    text.strip_prefix('+').unwrap_or(text).parse().ok()
}

impl Emulator for Mcb4bEmulator {
    fn name(&self) -> &'static str {
        "acs_mcb4b"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for axis in &mut self.axes {
            axis.advance(now);
        }
        for line in self.lines.push(bytes) {
            // A line feed after the previous carriage return, or spaces, are not part of it.
            let text = std::str::from_utf8(&line).ok().map(|t| t.trim_matches(|c: char| c.is_ascii_whitespace()));
            if text == Some("") {
                continue;
            }
            let answer = text.filter(|t| t.is_ascii()).and_then(|t| self.answer(t)).unwrap_or_else(|| {
                self.malformed += 1;
                "?".to_string()
            });
            self.output.push_back(format!("{answer}\r").into_bytes());
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.output.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed + self.lines.overflowed()
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.axes.get_mut(channel)
    }

    fn raise_error(&mut self, _channel: usize) -> bool {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage;
    use std::time::Duration;

    fn exchange(e: &mut Mcb4bEmulator, now: Instant, line: &str) -> String {
        e.handle_input(now, format!("{line}\r").as_bytes());
        let reply = e.poll_transmit().expect("every line is answered");
        assert!(e.poll_transmit().is_none(), "one line each");
        String::from_utf8(reply).expect("ASCII")
    }

    fn at(ms: u64) -> Instant {
        Instant::ZERO + Duration::from_millis(ms)
    }

    #[test]
    fn the_rate_tables_follow_acs_formulas() {
        assert_eq!(rate_of_index(2), 57_600.0);
        assert!((rate_of_index(255) - 451.76).abs() < 0.01);
        assert_eq!(rate_of_index(100), 1152.0);
        assert!((rate_of_index(65_535) - 1.758).abs() < 0.001);
        assert!((ramp_of_index(1) - 2823.53).abs() < 0.01);
        assert_eq!(ramp_of_index(255), 720_000.0);
        assert_eq!(ramp_of_index(176), 9000.0);
    }

    #[test]
    fn queries_echo_their_line_and_give_the_value() {
        let mut e = Mcb4bEmulator::new(4, &stage());
        assert_eq!(exchange(&mut e, at(0), "#01P"), "#01P=+0\r");
        assert_eq!(exchange(&mut e, at(0), "#01X"), "#01X=0\r");
        assert_eq!(exchange(&mut e, at(0), "#01E"), "#01E=001\r", "on the home switch at 0");
        assert_eq!(exchange(&mut e, at(0), "#03W"), "#03W=1\r");
        assert_eq!(exchange(&mut e, at(0), "#02P=-1500"), "#02P=-1500\r");
        assert_eq!(exchange(&mut e, at(0), "#02P"), "#02P=-1500\r");
        assert_eq!(exchange(&mut e, at(0), "#02E"), "#02E=001\r", "the counter changed, not the carriage");
    }

    #[test]
    fn a_move_runs_at_the_indexed_speed() {
        let mut e = Mcb4bEmulator::new(4, &stage());
        // V=100: 1152 steps/s; R=255: 720 000 steps/s², the ramp is negligible.
        assert_eq!(exchange(&mut e, at(0), "#00V=100"), "#00V=100\r");
        assert_eq!(exchange(&mut e, at(0), "#00R=255"), "#00R=255\r");
        assert_eq!(exchange(&mut e, at(0), "#00G+2304"), "#00G+2304\r");
        assert_eq!(exchange(&mut e, at(1000), "#00X"), "#00X=1\r");
        let p: i64 = exchange(&mut e, at(1000), "#00P")["#00P=".len()..].trim().parse().unwrap();
        assert!((1150..=1153).contains(&p), "{p}");
        assert_eq!(exchange(&mut e, at(2100), "#00X"), "#00X=0\r");
        assert_eq!(exchange(&mut e, at(2100), "#00P"), "#00P=+2304\r");
        assert_eq!(exchange(&mut e, at(2100), "#00I-304"), "#00I-304\r");
        assert_eq!(exchange(&mut e, at(3000), "#00P"), "#00P=+2000\r");
    }

    #[test]
    fn m_moves_at_the_constant_rate() {
        let mut e = Mcb4bEmulator::new(1, &stage());
        exchange(&mut e, at(0), "#00C=1152");
        exchange(&mut e, at(0), "#00M+500");
        // 100 steps/s, no ramp.
        assert_eq!(exchange(&mut e, at(2000), "#00P"), "#00P=+200\r");
    }

    #[test]
    fn f_decelerates_and_q_stops_at_once() {
        let mut e = Mcb4bEmulator::new(1, &stage());
        exchange(&mut e, at(0), "#00V=2");
        exchange(&mut e, at(0), "#00R=1");
        exchange(&mut e, at(0), "#00I+1000000");
        exchange(&mut e, at(1000), "#00F");
        assert_eq!(exchange(&mut e, at(1000), "#00X"), "#00X=1\r", "still ramping down");
        assert_eq!(exchange(&mut e, at(2100), "#00X"), "#00X=0\r");
        exchange(&mut e, at(2100), "#00I-1000000");
        exchange(&mut e, at(3000), "#00Q");
        assert_eq!(exchange(&mut e, at(3000), "#00X"), "#00X=0\r");
    }

    #[test]
    fn limit_switches_and_home_search() {
        let mut e = Mcb4bEmulator::new(2, &stage());
        exchange(&mut e, at(0), "#01V=2");
        exchange(&mut e, at(0), "#01R=255");
        exchange(&mut e, at(0), "#01I+1000000");
        assert_eq!(exchange(&mut e, at(10_000), "#01E"), "#01E=100\r");
        assert_eq!(exchange(&mut e, at(10_000), "#01X"), "#01X=0\r");
        assert_eq!(exchange(&mut e, at(10_000), "#01H-"), "#01H-\r");
        assert_eq!(exchange(&mut e, at(20_000), "#01E"), "#01E=001\r");
        assert_eq!(exchange(&mut e, at(20_000), "#01P"), "#01P=+0\r");
    }

    #[test]
    fn a_drive_without_power_does_not_move() {
        let mut e = Mcb4bEmulator::new(1, &stage());
        assert_eq!(exchange(&mut e, at(0), "#00W=0"), "#00W=0\r");
        assert_eq!(exchange(&mut e, at(0), "#00W"), "#00W=0\r");
        assert_eq!(exchange(&mut e, at(0), "#00G+100"), "#00G+100\r");
        assert_eq!(exchange(&mut e, at(0), "#00H+"), "#00H+\r");
        assert_eq!(exchange(&mut e, at(0), "#00X"), "#00X=0\r");
        assert_eq!(exchange(&mut e, at(1000), "#00P"), "#00P=+0\r");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn what_the_board_does_not_take_is_answered_with_a_question_mark() {
        let mut e = Mcb4bEmulator::new(4, &stage());
        for line in [
            "#04P",            // no fifth motor
            "#0P",             // one digit
            "01P",             // no '#'
            "#00V=1",          // below the rate indexes
            "#00V=256",        // above
            "#00R=0",          // below the ramp indexes
            "#00C=65536",      // above the constant rate indexes
            "#00G",            // no target
            "#00G+3000000000", // beyond 32 bits
            "#00Gabc",
            "#00H",
            "#00W=2",
            "#00Z",
            "*IDN?", // no identification query is known
            "#00\u{e9}",
        ] {
            assert_eq!(exchange(&mut e, at(0), line), "?\r", "{line}");
        }
        assert_eq!(e.malformed(), 15);
        assert!(!e.raise_error(0));
        assert_eq!(e.name(), "acs_mcb4b");
    }

    #[test]
    fn lines_come_whole_from_any_pieces_and_garbage_never_panics() {
        let mut e = Mcb4bEmulator::new(2, &stage());
        e.handle_input(at(0), b"#0");
        e.handle_input(at(0), b"1X\r#01W\r\n\r#01\xc3\xa9\r\xff\r");
        let replies: Vec<Vec<u8>> = std::iter::from_fn(|| e.poll_transmit()).collect();
        assert_eq!(replies, [b"#01X=0\r".to_vec(), b"#01W=1\r".to_vec(), b"?\r".to_vec(), b"?\r".to_vec()]);
        assert_eq!(e.malformed(), 2);
        e.handle_input(at(0), &[b'#'; 65]);
        assert_eq!(e.malformed(), 3, "an overflowing input buffer counts");
        assert!(e.axis(1).is_some() && e.axis(2).is_none());
        assert_eq!(Mcb4bEmulator::new(8, &stage()).axes.len(), 4, "four motors on a board");
    }
}
