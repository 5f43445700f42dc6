//! The McLennan PM304 "Digiloop Mk II" intelligent motor controller: one axis a unit, several
//! units on one serial line, each answering the lines that begin with its address, one command
//! a line in ASCII (`1MA1000`).
//!
//! # Witnesses
//!
//! 1. McLennan Servo Supplies' "User's Manual for PM304 Digiloop Mk II", written for ROM
//!    version 6.15 (25 July 2005; as published on manualzilla and vdocument.in). Only its front
//!    matter could be read: the model, the ROM version and the words "PM304 V6.15". The body
//!    (the command reference, the status output, the error list) could not.
//! 2. The EPICS driver, motorMclennan (`drvPM304.cc`, `devPM304.cc`, Mark Rivers 1998, with
//!    PM600 support and ISIS's later changes). It gives the bytes: `\r` ends a command, `\r\n`
//!    a reply; "the PM304 cannot handle more than 1 command on a line" (the driver splits at
//!    `;` and sends each alone); the PM304 answers without echoing the command (the PM600
//!    echoes it first); `OS` is answered with "an eight character string of ones and zeroes"
//!    whose character 0 is the lower (−) hard limit, 1 the upper (+) hard limit, 3 the
//!    motion done (`1` when idle), 4 to 7 faults, and 2 a fault flag whose sense changed
//!    between ROM 6.15 (`1` for no problem) and 6.17 (`0`); `OA`/`OC` are answered
//!    `AP=10234` (the number from the fourth character); `QS` is answered
//!    `SV=16200,SC=1000,SA=100000,SD=100000`; errors contain `!`; `ST` of an axis at rest is
//!    answered "NOT ALLOWED IN THIS MODE"; `RS` of an axis not aborted is answered
//!    `!NOT ABORTED`, and a reset otherwise contains `RESET`; the identification contains
//!    "PM304". Its commands: `MA` `MR` `SV` `SA` `SD` `SC` `ST` `RS` `AB` `AP` `CP` `KP` `KS`
//!    `KV` `BA`, `CV1`/`CV-1` (a jog at the `SV` speed, the sign its direction) and
//!    `IX1`/`IX-1` (the datum search, at the creep speed `SC`).
//! 3. ISIS's Lewis emulator of the McLennan (for the same driver): the identification
//!    `Mclennan Servo Supplies Ltd. PM304 V6.15`, `OK` to a command, `!RESET` to a reset.
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Replies are not addressed** (only the addressed unit speaks, and the EPICS driver
//!   reads the `OS` flags from the reply's first character). `OC` is answered `CP=n` after
//!   `OA`'s `AP=n`. Commands are answered `OK`.
//! - **No unit answers** a line without an address, or with an address no unit on the line
//!   has: the driver's own fault, counted as malformed.
//! - **The error texts** other than the witnessed ones: an unknown mnemonic, a missing or bad
//!   argument, or more than one command on a line (a `;` inside it) are answered
//!   `!ILLEGAL COMMAND` and counted as malformed. One `;` ending the line is tolerated (the
//!   EPICS driver's own separator). A motion, a datum search or a position definition
//!   refused because of the axis's state is answered `!NOT ALLOWED IN THIS MODE` (as `ST` at
//!   rest is): a motion or search while aborted, `AP`/`CP` while moving.
//! - **The `OS` flags**, characters 0–7: lower limit, upper limit, control loop active
//!   (ROM 6.15's sense: `1` unless aborted), idle, tracking abort, abort (by `AB`), then two
//!   flags this emulator never sets. The datum (home) switch is not among them (the EPICS
//!   driver reads no home bit from a PM304).
//! - **Aborts.** `AB` stops the pulses at once and aborts the axis; a tracking abort
//!   (`raise_error`) does the same and shows in character 4. Either lasts until `RS`, which
//!   is then answered `!RESET`.
//! - **Motion.** `MA`/`MR` ramp at `SA`; `ST` (and `CV0`) decelerate at `SD`. A new motion
//!   may replace one in progress. A motion into a limit switch stops there; moving away is
//!   allowed. `IX`/`HD` (no argument or `1`: forward; `-1`: reverse) search the datum at up
//!   to `SV`, leaving the position 0 there.
//! - **`AP` and `CP`** both set the position: with no encoder slip the actual (encoder) and
//!   command positions are the same number, so `OA` and `OC` always agree.
//! - **Power-on**: every axis at rest at 0, not aborted, `SV` 16 200, `SC` 1 000, `SA` and
//!   `SD` 100 000 (the values of the EPICS driver's `QS` example), gains 0. `ID` answers
//!   `Mclennan Servo Supplies Ltd. PM304 V6.15`.
//! - **Numbers** are 32-bit signed decimals, a sign optional; speeds and accelerations at
//!   least 1. Mnemonics are upper case. Addresses are 1 to 99 (one or two digits); the
//!   emulator puts units at 1 to 8.
//! - **Input buffer**: 160 bytes without a `\r` overflow it.

use crate::emulator::axes;
use crate::{Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

/// Units (axes) on one line at most.
const MAX_UNITS: usize = 8;

/// The command terminator.
const CR: &[u8] = b"\r";

/// The reply terminator.
const CRLF: &str = "\r\n";

/// Bytes without a terminator a unit holds before its buffer overflows.
const INPUT_BUFFER: usize = 160;

/// The identification, ROM 6.15.
const IDENTIFICATION: &str = "Mclennan Servo Supplies Ltd. PM304 V6.15";

const OK: &str = "OK";
const ILLEGAL: &str = "!ILLEGAL COMMAND";
const NOT_ALLOWED: &str = "!NOT ALLOWED IN THIS MODE";

/// One PM304 unit: its settings and the carriage behind it.
#[derive(Debug)]
struct Unit {
    sim: SimAxis,
    /// SV, steps/s.
    speed: u32,
    /// SC, steps/s.
    creep: u32,
    /// SA, steps/s².
    acceleration: u32,
    /// SD, steps/s².
    deceleration: u32,
    /// KP, KS, KV.
    gains: [i32; 3],
    /// Aborted by AB.
    aborted: bool,
    /// Aborted by a tracking error.
    tracking_abort: bool,
}

impl Unit {
    fn new(sim: SimAxis) -> Self {
        Self {
            sim,
            speed: 16_200,
            creep: 1_000,
            acceleration: 100_000,
            deceleration: 100_000,
            gains: [0; 3],
            aborted: false,
            tracking_abort: false,
        }
    }

    fn in_abort(&self) -> bool {
        self.aborted || self.tracking_abort
    }

    fn position(&self) -> i64 {
        self.sim.status().position.round() as i64
    }

    /// The eight `OS` flags.
    fn status(&self) -> String {
        let state = self.sim.state();
        let flags = [
            state.low_limit,
            state.high_limit,
            !self.in_abort(),
            !self.sim.is_moving(),
            self.tracking_abort,
            self.aborted,
            false,
            false,
        ];
        flags.iter().map(|&on| if on { '1' } else { '0' }).collect()
    }
}

/// A serial line with PM304 units at addresses 1 … n.
pub struct Pm304Emulator {
    units: Vec<Unit>,
    lines: Lines,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl Pm304Emulator {
    /// A line with `units` PM304s (one at least, eight at most) at addresses 1 to `units`.
    pub fn new(units: usize, mechanics: &SimConfig) -> Self {
        let units = units.clamp(1, MAX_UNITS);
        Self {
            units: axes(units, mechanics).into_iter().map(Unit::new).collect(),
            lines: Lines::new(CR, INPUT_BUFFER),
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    /// The reply to one line, None when no unit answers it.
    fn answer(&mut self, line: &str) -> Option<String> {
        let line = line.strip_suffix(';').unwrap_or(line);
        let digits = line.bytes().take_while(u8::is_ascii_digit).count();
        if digits == 0 || digits > 2 {
            return None;
        }
        let address: usize = line[..digits].parse().ok()?;
        let unit = self.units.get_mut(address.checked_sub(1)?)?;
        let command = &line[digits..];
        let reply = command.get(..2).zip(command.get(2..)).and_then(|(m, a)| execute(unit, m, a));
        Some(reply.unwrap_or_else(|| {
            self.malformed += 1;
            ILLEGAL.to_string()
        }))
    }
}

/// Carry out `mnemonic` with `argument` on `unit`: the reply, None when the command is illegal.
fn execute(unit: &mut Unit, mnemonic: &str, argument: &str) -> Option<String> {
    let reply = |text: &str| Some(text.to_string());
    match (mnemonic, argument) {
        ("OS", "") => Some(unit.status()),
        ("OA", "") => Some(format!("AP={}", unit.position())),
        ("OC", "") => Some(format!("CP={}", unit.position())),
        ("ID", "") => reply(IDENTIFICATION),
        ("QS", "") => {
            Some(format!("SV={},SC={},SA={},SD={}", unit.speed, unit.creep, unit.acceleration, unit.deceleration))
        }
        ("SV", _) => {
            unit.speed = rate(argument)?;
            reply(OK)
        }
        ("SC", _) => {
            unit.creep = rate(argument)?;
            reply(OK)
        }
        ("SA", _) => {
            unit.acceleration = rate(argument)?;
            reply(OK)
        }
        ("SD", _) => {
            unit.deceleration = rate(argument)?;
            reply(OK)
        }
        ("KP" | "KS" | "KV", _) => {
            let gain = number(argument)?;
            unit.gains[["KP", "KS", "KV"].iter().position(|k| *k == mnemonic)?] = gain;
            reply(OK)
        }
        ("MA" | "MR", _) => {
            let target = number(argument)?;
            if unit.in_abort() {
                return reply(NOT_ALLOWED);
            }
            let (speed, acceleration) = (f64::from(unit.speed), f64::from(unit.acceleration));
            unit.sim.move_to(f64::from(target), mnemonic == "MR", 0.0, speed, acceleration);
            reply(OK)
        }
        ("CV", _) => {
            let direction = number(argument)?;
            if unit.in_abort() {
                return reply(NOT_ALLOWED);
            }
            if direction == 0 {
                unit.sim.stop(f64::from(unit.deceleration));
            } else {
                let velocity = f64::from(direction.signum()) * f64::from(unit.speed);
                unit.sim.move_velocity(0.0, velocity, f64::from(unit.acceleration));
            }
            reply(OK)
        }
        ("IX" | "HD", "" | "1" | "+1" | "-1") => {
            if unit.in_abort() {
                return reply(NOT_ALLOWED);
            }
            let (creep, speed) = (f64::from(unit.creep.min(unit.speed)), f64::from(unit.speed));
            unit.sim.home(argument != "-1", creep, speed, f64::from(unit.acceleration));
            reply(OK)
        }
        ("ST", "") => {
            if !unit.sim.is_moving() {
                return reply(NOT_ALLOWED);
            }
            unit.sim.stop(f64::from(unit.deceleration));
            reply(OK)
        }
        ("AB", "") => {
            unit.sim.stop(0.0);
            unit.aborted = true;
            reply(OK)
        }
        ("RS", "") => {
            if !unit.in_abort() {
                return reply("!NOT ABORTED");
            }
            unit.aborted = false;
            unit.tracking_abort = false;
            reply("!RESET")
        }
        ("AP" | "CP", _) => {
            let position = number(argument)?;
            if unit.sim.is_moving() {
                return reply(NOT_ALLOWED);
            }
            unit.sim.set_position(f64::from(position));
            reply(OK)
        }
        // Sent by the EPICS driver before a datum search; acknowledged.
        ("BA", "") => reply(OK),
        _ => None,
    }
}

/// A signed 32-bit decimal, its sign optional.
fn number(text: &str) -> Option<i32> {
    let digits = text.strip_prefix(['+', '-']).unwrap_or(text);
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    text.strip_prefix('+').unwrap_or(text).parse().ok()
}

/// A speed or acceleration: a positive 32-bit decimal.
fn rate(text: &str) -> Option<u32> {
    number(text).filter(|&n| n >= 1).map(i32::unsigned_abs)
}

impl Emulator for Pm304Emulator {
    fn name(&self) -> &'static str {
        "mclennan_pm304"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for unit in &mut self.units {
            unit.sim.advance(now);
        }
        for line in self.lines.push(bytes) {
            // A line feed after the previous carriage return, or spaces, are not part of it.
            let text = std::str::from_utf8(&line).ok().map(|t| t.trim_matches(|c: char| c.is_ascii_whitespace()));
            if text == Some("") {
                continue;
            }
            match text.filter(|t| t.is_ascii()).and_then(|t| self.answer(t)) {
                Some(reply) => self.output.push_back(format!("{reply}{CRLF}").into_bytes()),
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
        self.units.get_mut(channel.checked_sub(1)?).map(|unit| &mut unit.sim)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(unit) = channel.checked_sub(1).and_then(|i| self.units.get_mut(i)) else { return false };
        unit.sim.stop(0.0);
        unit.tracking_abort = true;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage;
    use std::time::Duration;

    fn exchange(e: &mut Pm304Emulator, now: Instant, line: &str) -> String {
        e.handle_input(now, format!("{line}\r").as_bytes());
        let reply = e.poll_transmit().expect("the line is answered");
        assert!(e.poll_transmit().is_none(), "one reply a line");
        String::from_utf8(reply).expect("ASCII")
    }

    fn at(ms: u64) -> Instant {
        Instant::ZERO + Duration::from_millis(ms)
    }

    #[test]
    fn power_on_state_and_identification() {
        let mut e = Pm304Emulator::new(2, &stage());
        assert_eq!(exchange(&mut e, at(0), "1ID"), "Mclennan Servo Supplies Ltd. PM304 V6.15\r\n");
        assert_eq!(exchange(&mut e, at(0), "2OS"), "00110000\r\n");
        assert_eq!(exchange(&mut e, at(0), "1OA"), "AP=0\r\n");
        assert_eq!(exchange(&mut e, at(0), "1OC"), "CP=0\r\n");
        assert_eq!(exchange(&mut e, at(0), "1QS"), "SV=16200,SC=1000,SA=100000,SD=100000\r\n");
        assert_eq!(exchange(&mut e, at(0), "1RS"), "!NOT ABORTED\r\n");
        assert_eq!(exchange(&mut e, at(0), "1ST"), "!NOT ALLOWED IN THIS MODE\r\n", "nothing to stop");
        for line in ["1KP10", "1KS-2", "1KV300", "1BA", "1SC500;"] {
            assert_eq!(exchange(&mut e, at(0), line), "OK\r\n", "{line}");
        }
        assert_eq!(e.units[0].gains, [10, -2, 300]);
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_move_is_busy_then_done_at_its_target() {
        let mut e = Pm304Emulator::new(1, &stage());
        assert_eq!(exchange(&mut e, at(0), "1SV1000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(0), "1SA1000000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(0), "1SD1000000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(0), "1MA2000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(1000), "1OS"), "00100000\r\n", "busy");
        let p: i64 = exchange(&mut e, at(1000), "1OA")[3..].trim().parse().unwrap();
        assert!((995..=1001).contains(&p), "{p}");
        assert_eq!(exchange(&mut e, at(1000), "1AP5"), "!NOT ALLOWED IN THIS MODE\r\n");
        assert_eq!(exchange(&mut e, at(2100), "1OS"), "00110000\r\n", "done");
        assert_eq!(exchange(&mut e, at(2100), "1OA"), "AP=2000\r\n");
        assert_eq!(exchange(&mut e, at(2100), "1OC"), "CP=2000\r\n");
        assert_eq!(exchange(&mut e, at(2100), "1MR-500"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(3000), "1OC"), "CP=1500\r\n");
    }

    #[test]
    fn a_jog_runs_until_stopped_and_into_a_limit() {
        let mut e = Pm304Emulator::new(1, &stage());
        exchange(&mut e, at(0), "1SV1000");
        exchange(&mut e, at(0), "1SD1000");
        assert_eq!(exchange(&mut e, at(0), "1CV-1"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(5000), "1OS"), "00100000\r\n");
        assert!(e.units[0].position() < -4000);
        assert_eq!(exchange(&mut e, at(5000), "1ST"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(5200), "1OS"), "00100000\r\n", "decelerating");
        assert_eq!(exchange(&mut e, at(6100), "1OS"), "00110000\r\n");
        exchange(&mut e, at(6100), "1SV100000");
        exchange(&mut e, at(6100), "1CV1");
        assert_eq!(exchange(&mut e, at(16_000), "1OS"), "01110000\r\n", "on the upper limit");
        assert_eq!(exchange(&mut e, at(16_000), "1MR-1000"), "OK\r\n", "away from it");
        assert_eq!(exchange(&mut e, at(17_000), "1OS"), "00110000\r\n");
    }

    #[test]
    fn datum_searches_and_position_definitions() {
        let mut e = Pm304Emulator::new(3, &stage());
        exchange(&mut e, at(0), "3SV10000");
        assert_eq!(exchange(&mut e, at(0), "3AP-5000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(0), "3OA"), "AP=-5000\r\n");
        assert_eq!(exchange(&mut e, at(0), "3IX1"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(5000), "3OS"), "00110000\r\n");
        assert_eq!(exchange(&mut e, at(5000), "3OA"), "AP=0\r\n");
        exchange(&mut e, at(5000), "3MA3000");
        assert_eq!(exchange(&mut e, at(10_000), "3CP100"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(10_000), "3OA"), "AP=100\r\n");
        assert_eq!(exchange(&mut e, at(10_000), "3HD-1"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(20_000), "3OC"), "CP=0\r\n");
        assert!(e.axis(3).unwrap().state().position.abs() < 1e-9, "on the switch");
        assert_eq!(exchange(&mut e, at(20_000), "3HD"), "OK\r\n");
    }

    #[test]
    fn aborts_hold_until_reset() {
        let mut e = Pm304Emulator::new(2, &stage());
        exchange(&mut e, at(0), "2CV1");
        assert_eq!(exchange(&mut e, at(100), "2AB"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(100), "2OS"), "00010100\r\n");
        assert_eq!(exchange(&mut e, at(100), "2MA0"), "!NOT ALLOWED IN THIS MODE\r\n");
        assert_eq!(exchange(&mut e, at(100), "2RS"), "!RESET\r\n");
        assert_eq!(exchange(&mut e, at(100), "2OS"), "00110000\r\n");
        exchange(&mut e, at(100), "2MR100000");
        assert!(e.raise_error(2));
        assert_eq!(exchange(&mut e, at(200), "2OS"), "00011000\r\n", "a tracking abort");
        assert_eq!(exchange(&mut e, at(200), "2IX"), "!NOT ALLOWED IN THIS MODE\r\n");
        assert_eq!(exchange(&mut e, at(200), "2RS"), "!RESET\r\n");
        assert!(!e.raise_error(0) && !e.raise_error(3));
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn illegal_commands_are_answered_and_counted() {
        let mut e = Pm304Emulator::new(1, &stage());
        for line in ["1XX", "1MA", "1MAabc", "1MA3000000000", "1SV0", "1SA-5", "1OS1", "1IX2", "1ma100", "1OS;1OA", "1"]
        {
            assert_eq!(exchange(&mut e, at(0), line), "!ILLEGAL COMMAND\r\n", "{line}");
        }
        assert_eq!(e.malformed(), 11);
        assert_eq!(e.name(), "mclennan_pm304");
    }

    #[test]
    fn no_unit_answers_a_line_without_its_address() {
        let mut e = Pm304Emulator::new(2, &stage());
        for line in ["3OS", "0OS", "OS", "100OS", "1O\u{e9}"] {
            e.handle_input(at(0), format!("{line}\r").as_bytes());
            assert!(e.poll_transmit().is_none(), "{line}");
        }
        assert_eq!(e.malformed(), 5);
        assert!(e.axis(0).is_none() && e.axis(2).is_some() && e.axis(3).is_none());
        assert_eq!(Pm304Emulator::new(20, &stage()).units.len(), 8);
        assert_eq!(Pm304Emulator::new(0, &stage()).units.len(), 1);
    }

    #[test]
    fn lines_come_whole_from_any_pieces() {
        let mut e = Pm304Emulator::new(1, &stage());
        e.handle_input(at(0), b"1O");
        assert!(e.poll_transmit().is_none());
        e.handle_input(at(0), b"A\r\n1O");
        e.handle_input(at(0), b"S\n\r\xff\r");
        let replies: Vec<Vec<u8>> = std::iter::from_fn(|| e.poll_transmit()).collect();
        assert_eq!(replies, [b"AP=0\r\n".to_vec(), b"00110000\r\n".to_vec()]);
        assert_eq!(e.malformed(), 1, "the byte that is not ASCII");
        e.handle_input(at(0), &[b'1'; 161]);
        assert_eq!(e.malformed(), 2, "an overflowing input buffer counts");
    }
}
