//! A Phytron phyMOTION: modules of two axes (channels 11, 12, 21, 22, …), framed requests
//! `STX '0' <commands> ':' <XOR> ETX` answered by one frame of one ACK or NAK (and data) per
//! command, with its checksum. What it takes:
//! - `M<m.a>A<n>`, `M<m.a>+<n>`, `M<m.a>-<n>`: moves at the run frequency P14 from the start
//!   frequency P04 with the ramp P15; `M<m.a>L+` / `L-`: runs until stopped or a limit switch;
//!   `M<m.a>R+C` / `R-C`: the reference run to the center switch at P08 from P10 with the ramp
//!   P09, which sets the counters to 0 there and the axis initialised (offsets P11/P12 are 0);
//!   `M<m.a>S`: stops with the ramp P15;
//! - `M<m.a>MA` / `MD`: the power stage on / off (off while running stops with the emergency
//!   ramp P07); a motion with the power stage off or in error is refused (NAK);
//! - `M<m.a>P<n>R`, `M<m.a>P<n>=<value>` for parameters 1–58 (`P1` ≡ `P01`): P20 is the position
//!   counter (a write sets it), P21 the absolute counter, P22 the encoder counter (encoder
//!   counts × the conversion factor P39), P34 the encoder type (1 when the mechanics have an
//!   encoder); P21, P22, P49 and P54 are read-only (NAK); frequencies outside 1–500000 Hz and
//!   ramps outside 4000–500000 Hz/s are refused, as the EPICS driver's limits;
//! - `M<m.a>==H`: `E` at rest, `N` running; `SE<m.a>`: the extended status word (busy, initialised,
//!   limit switches, center switch, power stage ready, limit-switch, power-stage, SFI and internal
//!   errors, running, in position); `SEC<m.a>`: clears the limit-switch and power-stage errors.
//!
//! A run that ends on a limit switch leaves the limit-switch error (SE bit 12) until `SEC`.
//! `raise_error` is a power-stage error (SE bit 13): the axis stops, and motions are refused
//! until `SEC`. A command for an axis the controller does not have is refused (NAK). A frame
//! without STX … ETX, without a good checksum or the address `0`, and a command the emulator
//! does not know are counted as malformed (the driver's fault) and refused.

use super::Emulator;
use crate::phytron::{
    reply_frame, split_axis, status_bit, without_checksum, ACK, ADDRESS, ETX, FREQUENCIES, MAX_PAYLOAD, NAK, NAME,
    RAMPS, STX,
};
use std::collections::{BTreeMap, VecDeque};
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};
use zmotor_msgs::bits::msta;

/// Axes on each emulated module.
pub(crate) const AXES_PER_MODULE: usize = 2;

/// Parameters that are read, never written.
const READ_ONLY: [u32; 4] = [21, 22, 49, 54];

/// The highest parameter number.
const LAST_PARAMETER: u32 = 58;

/// What the controller answers to one command.
enum Answer {
    /// ACK and its data.
    Done(String),
    /// NAK: a command the controller knows but will not carry out now.
    Refused,
    /// NAK: not a command of the protocol (counted as malformed).
    Malformed,
}

/// One axis: its mechanics and what the controller keeps for it.
struct Axis {
    channel: usize,
    sim: SimAxis,
    parameters: BTreeMap<u32, f64>,
    power: bool,
    power_stage_error: bool,
    limit_switch_error: bool,
    /// Running when last looked at: a run that ends on a limit switch is a limit-switch error.
    was_moving: bool,
}

impl Axis {
    fn new(channel: usize, mechanics: &SimConfig) -> Self {
        let mut parameters: BTreeMap<u32, f64> = (1..=LAST_PARAMETER).map(|n| (n, 0.0)).collect();
        let encoder_type = if mechanics.encoder_counts_per_step.is_some() { 1.0 } else { 0.0 };
        // The factory settings that matter here: steps, limit switches monitored, the
        // frequencies and ramps, power stage on after power-up, 30 °C.
        for (number, value) in [
            (1, 1.0),
            (2, 1.0),
            (3, 1.0),
            (4, 400.0),
            (7, 100_000.0),
            (8, 2000.0),
            (9, 4000.0),
            (10, 400.0),
            (13, 20.0),
            (14, 4000.0),
            (15, 4000.0),
            (16, 20.0),
            (28, 1.0),
            (34, encoder_type),
            (39, 1.0),
            (49, 300.0),
            (54, 300.0),
        ] {
            parameters.insert(number, value);
        }
        Self {
            channel,
            sim: SimAxis::new(mechanics.clone()),
            parameters,
            power: true,
            power_stage_error: false,
            limit_switch_error: false,
            was_moving: false,
        }
    }

    fn parameter(&self, number: u32) -> f64 {
        self.parameters.get(&number).copied().unwrap_or_default()
    }

    /// Note the end of a run on a limit switch.
    fn observe(&mut self) {
        let moving = self.sim.is_moving();
        let on_limit = self.sim.status().msta & (msta::PLUS_LS | msta::MINUS_LS) != 0;
        if self.was_moving && !moving && on_limit {
            self.limit_switch_error = true;
        }
        self.was_moving = moving;
    }

    fn status_word(&self) -> u32 {
        let status = self.sim.status();
        let moving = self.sim.is_moving();
        let mut word = 0;
        for (on, bit) in [
            (moving, status_bit::BUSY | status_bit::RUNNING),
            (!moving, status_bit::IN_POSITION),
            (status.msta & msta::HOMED != 0, status_bit::INITIALISED),
            (status.msta & msta::PLUS_LS != 0, status_bit::PLUS_LIMIT),
            (status.msta & msta::MINUS_LS != 0, status_bit::MINUS_LIMIT),
            (self.sim.on_home_switch(), status_bit::CENTER_SWITCH),
            (self.power && !self.power_stage_error, status_bit::POWER_STAGE_READY),
            (status.msta & msta::PROBLEM != 0, status_bit::INTERNAL_ERROR),
            (self.limit_switch_error, status_bit::LIMIT_SWITCH_ERROR),
            (self.power_stage_error, status_bit::POWER_STAGE_ERROR),
            (status.msta & msta::SLIP_STALL != 0, status_bit::SFI_ERROR),
        ] {
            if on {
                word |= bit;
            }
        }
        word
    }

    /// A parameter as `P<n>R` reads it.
    fn read(&self, number: u32) -> f64 {
        let status = self.sim.status();
        match number {
            20 | 21 => status.position.round(),
            22 => status.encoder_position.round() * self.parameter(39),
            _ => self.parameter(number),
        }
    }

    fn write(&mut self, number: u32, value: f64) -> Answer {
        let fits = match number {
            4 | 8 | 10 | 14 => FREQUENCIES.contains(&value),
            9 | 15 => RAMPS.contains(&value),
            39 => value > 0.0,
            _ => true,
        };
        if !fits {
            return Answer::Malformed;
        }
        if READ_ONLY.contains(&number) {
            return Answer::Refused;
        }
        if number == 20 {
            self.sim.set_position(value);
        } else {
            self.parameters.insert(number, value);
        }
        Answer::Done(String::new())
    }

    /// One command for this axis (after `M<m.a>`).
    fn command(&mut self, order: &str) -> Answer {
        let answer = self.carry_out(order);
        self.observe();
        answer
    }

    fn carry_out(&mut self, order: &str) -> Answer {
        let run = |axis: &Self| (axis.parameter(4), axis.parameter(14), axis.parameter(15));
        let can_run = self.power && !self.power_stage_error;
        match order {
            "==H" => return Answer::Done(if self.sim.is_moving() { "N" } else { "E" }.to_string()),
            "MA" => self.power = true,
            "MD" => {
                self.power = false;
                self.sim.stop(self.parameter(7));
            }
            "S" => self.sim.stop(self.parameter(15)),
            "L+" | "L-" | "R+C" | "R-C" if !can_run => return Answer::Refused,
            "L+" | "L-" => {
                let (start, speed, ramp) = run(self);
                let velocity = if order == "L+" { speed } else { -speed };
                self.sim.move_velocity(start, velocity, ramp);
            }
            "R+C" | "R-C" => {
                let (start, speed, ramp) = (self.parameter(10), self.parameter(8), self.parameter(9));
                self.sim.home(order == "R+C", start, speed, ramp);
            }
            _ => {
                if let Some(rest) = order.strip_prefix('P') {
                    return self.parameter_command(rest);
                }
                let (relative, target) = match order.split_at_checked(1) {
                    Some(("A", value)) => (false, number(value, true)),
                    Some(("+", value)) => (true, number(value, false)),
                    Some(("-", value)) => (true, number(value, false).map(|v| -v)),
                    _ => (false, None),
                };
                let Some(target) = target else { return Answer::Malformed };
                if !can_run {
                    return Answer::Refused;
                }
                let (start, speed, ramp) = run(self);
                self.sim.move_to(target, relative, start, speed, ramp);
            }
        }
        Answer::Done(String::new())
    }

    /// `P<n>R` or `P<n>=<value>` (after the `P`).
    fn parameter_command(&mut self, text: &str) -> Answer {
        let digits = text.bytes().take_while(u8::is_ascii_digit).count();
        let Some(parameter) = text[..digits].parse::<u32>().ok().filter(|n| (1..=LAST_PARAMETER).contains(n)) else {
            return Answer::Malformed;
        };
        match &text[digits..] {
            "R" => Answer::Done(number_text(self.read(parameter))),
            rest => match rest.strip_prefix('=').and_then(|value| number(value, true)) {
                Some(value) => self.write(parameter, value),
                None => Answer::Malformed,
            },
        }
    }
}

/// A decimal number as commands write it (digits, one point, a sign if `signed`); no
/// exponents, no infinities.
fn number(text: &str, signed: bool) -> Option<f64> {
    let unsigned = if signed { text.strip_prefix('-').unwrap_or(text) } else { text };
    let well_formed = !unsigned.is_empty()
        && unsigned.bytes().all(|b| b.is_ascii_digit() || b == b'.')
        && unsigned.bytes().filter(|b| *b == b'.').count() <= 1
        && unsigned.bytes().any(|b| b.is_ascii_digit());
    well_formed.then(|| text.parse().ok()).flatten()
}

/// A value as the controller prints it: an integer when it is one.
fn number_text(value: f64) -> String {
    if value == 0.0 {
        "0".to_string()
    } else {
        format!("{value}")
    }
}

/// A phyMOTION with modules of [`AXES_PER_MODULE`] axes.
pub(crate) struct PhymotionEmulator {
    axes: Vec<Axis>,
    input: Vec<u8>,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl PhymotionEmulator {
    /// A controller of `modules` modules on `mechanics` (an encoder if the mechanics have one),
    /// power stages on.
    pub(crate) fn new(modules: usize, mechanics: &SimConfig) -> Self {
        let axes = (1..=modules)
            .flat_map(|module| (1..=AXES_PER_MODULE).map(move |axis| module * 10 + axis))
            .map(|channel| Axis::new(channel, mechanics))
            .collect();
        Self { axes, input: Vec::new(), output: VecDeque::new(), malformed: 0 }
    }

    /// A controller with every channel below `channels` that its modules have, two modules at
    /// least (channels 11, 12, 21, 22).
    pub(crate) fn with_channels_below(channels: usize, mechanics: &SimConfig) -> Self {
        Self::new((channels.saturating_sub(1) / 10).max(2), mechanics)
    }

    fn axis_mut(&mut self, channel: usize) -> Option<&mut Axis> {
        self.axes.iter_mut().find(|a| a.channel == channel)
    }

    /// The commands of a frame's content (between STX and ETX), if it is well-formed.
    fn payload(content: &[u8]) -> Option<String> {
        let sum = content.len().checked_sub(2).map(|at| &content[at..])?;
        // The driver always sends a checksum, never `XX`.
        if content.len() < 4 || content[content.len() - 3] != b':' || sum.eq_ignore_ascii_case(b"XX") {
            return None;
        }
        let (address, payload) = without_checksum(content).ok()?.split_first()?;
        let printable = payload.iter().all(|b| b.is_ascii_graphic() || *b == b' ');
        (*address == ADDRESS && !payload.is_empty() && payload.len() <= MAX_PAYLOAD && printable)
            .then(|| String::from_utf8_lossy(payload).into_owned())
    }

    fn answer(&mut self, command: &str) -> Answer {
        let (channel, order) = if let Some(rest) = command.strip_prefix("SEC") {
            match split_axis(rest) {
                Some((channel, "")) => (channel, "SEC"),
                _ => return Answer::Malformed,
            }
        } else if let Some(rest) = command.strip_prefix("SE") {
            match split_axis(rest) {
                Some((channel, "")) => (channel, "SE"),
                _ => return Answer::Malformed,
            }
        } else {
            match command.strip_prefix('M').and_then(split_axis) {
                Some((channel, order)) => (channel, order),
                None => return Answer::Malformed,
            }
        };
        let Some(axis) = self.axis_mut(channel) else { return Answer::Refused };
        match order {
            "SE" => Answer::Done(axis.status_word().to_string()),
            "SEC" => {
                axis.limit_switch_error = false;
                axis.power_stage_error = false;
                Answer::Done(String::new())
            }
            order => axis.command(order),
        }
    }

    fn answer_frame(&mut self, content: &[u8]) -> Vec<u8> {
        let Some(payload) = Self::payload(content) else {
            self.malformed += 1;
            return reply_frame(&[NAK]);
        };
        let mut body = Vec::new();
        for command in payload.split(' ') {
            match self.answer(command) {
                Answer::Done(data) => {
                    body.push(ACK);
                    body.extend_from_slice(data.as_bytes());
                }
                Answer::Refused => body.push(NAK),
                Answer::Malformed => {
                    self.malformed += 1;
                    body.push(NAK);
                }
            }
        }
        reply_frame(&body)
    }
}

impl Emulator for PhymotionEmulator {
    fn name(&self) -> &'static str {
        NAME
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for axis in &mut self.axes {
            axis.sim.advance(now);
            axis.observe();
        }
        self.input.extend_from_slice(bytes);
        loop {
            match self.input.iter().position(|b| *b == STX) {
                Some(0) => {}
                Some(noise) => {
                    self.input.drain(..noise);
                    self.malformed += 1;
                }
                None => {
                    if !self.input.is_empty() {
                        self.input.clear();
                        self.malformed += 1;
                    }
                    return;
                }
            }
            let Some(end) = self.input.iter().position(|b| *b == ETX) else {
                if self.input.len() > MAX_PAYLOAD + 6 {
                    // Longer than any frame the controller takes: drop it.
                    self.input.clear();
                    self.malformed += 1;
                }
                return;
            };
            let frame: Vec<u8> = self.input.drain(..=end).collect();
            let reply = self.answer_frame(&frame[1..end]);
            self.output.push_back(reply);
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.output.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.axis_mut(channel).map(|a| &mut a.sim)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(axis) = self.axis_mut(channel) else { return false };
        axis.power_stage_error = true;
        axis.sim.stop(axis.parameter(7));
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::phytron::{request_frame, sub_replies};

    fn emulator() -> PhymotionEmulator {
        PhymotionEmulator::new(2, &SimConfig { encoder_counts_per_step: Some(1.0), ..super::super::stage() })
    }

    /// Send `payload` at `seconds`; the sub-replies as (ACK?, data).
    fn ask(e: &mut PhymotionEmulator, seconds: f64, payload: &str) -> Vec<(bool, String)> {
        e.handle_input(Instant::from_secs_f64(seconds), &request_frame(payload));
        let reply = e.poll_transmit().expect("a reply");
        sub_replies(&reply).expect("a well-formed reply").into_iter().map(|(ack, d)| (ack, d.to_string())).collect()
    }

    fn data(replies: &[(bool, String)]) -> Vec<&str> {
        replies.iter().map(|(ack, d)| if *ack { d.as_str() } else { "NAK" }).collect()
    }

    #[test]
    fn every_command_of_a_frame_is_answered_in_one_reply() {
        let mut e = emulator();
        let replies = ask(&mut e, 0.0, "SE1.1 M1.1P20R M1.1P22R M1.2P34R M2.2==H SE3.1");
        assert_eq!(data(&replies), ["524864", "0", "0", "1", "E", "NAK"], "524864: ready, in position, on center");
        assert_eq!(e.malformed(), 0, "an axis it lacks is refused, not malformed");
        e.handle_input(Instant::ZERO, b"\x020SE1.1\x03");
        e.handle_input(Instant::ZERO, b"\x020SE1.1:33\x03");
        e.handle_input(Instant::ZERO, b"\x021SE1.1:33\x03");
        e.handle_input(Instant::ZERO, &request_frame("M1.1P14=0.5 M1.1P99R M1.1X"));
        assert_eq!(e.malformed(), 6);
    }

    #[test]
    fn moves_run_at_the_parameters_and_end_in_position() {
        let mut e = emulator();
        ask(&mut e, 0.0, "M1.1P14=1000.000000 M1.1P04=1000.000000 M1.1P15=4000.000000 M1.1MA M1.1A500");
        assert_eq!(data(&ask(&mut e, 0.25, "M1.1==H M1.1P20R")), ["N", "250"]);
        assert_eq!(data(&ask(&mut e, 1.0, "SE1.1 M1.1P20R")), ["524800", "500"], "ready and in position");
        ask(&mut e, 1.0, "M1.1-100");
        assert_eq!(data(&ask(&mut e, 2.0, "M1.1P20R M1.1P21R M1.1P22R")), ["400", "400", "400"]);
        ask(&mut e, 2.0, "M1.1P39=0.5 M1.1P20=0.000000");
        assert_eq!(data(&ask(&mut e, 2.0, "M1.1P20R M1.1P22R")), ["0", "0"]);
    }

    #[test]
    fn a_run_into_a_limit_switch_leaves_an_error_until_cleared() {
        let mut e = emulator();
        ask(&mut e, 0.0, "M2.1P14=500000 M2.1P15=500000 M2.1L-");
        let word: u32 = data(&ask(&mut e, 5.0, "SE2.1"))[0].parse().unwrap();
        assert_eq!(word & (status_bit::MINUS_LIMIT | status_bit::LIMIT_SWITCH_ERROR | status_bit::BUSY), 0x1020);
        ask(&mut e, 5.0, "SEC2.1");
        let word: u32 = data(&ask(&mut e, 5.0, "SE2.1"))[0].parse().unwrap();
        assert_eq!(word & status_bit::LIMIT_SWITCH_ERROR, 0);
    }

    #[test]
    fn no_motion_without_the_power_stage_and_a_power_stage_error_until_cleared() {
        let mut e = emulator();
        assert_eq!(data(&ask(&mut e, 0.0, "M1.2MD M1.2A100 M1.2L+ M1.2R+C")), ["", "NAK", "NAK", "NAK"]);
        assert_eq!(e.malformed(), 0);
        let word: u32 = data(&ask(&mut e, 0.0, "SE1.2"))[0].parse().unwrap();
        assert_eq!(word & status_bit::POWER_STAGE_READY, 0);
        assert!(e.raise_error(12) && !e.raise_error(13));
        assert_eq!(data(&ask(&mut e, 0.0, "M1.2MA M1.2A100")), ["", "NAK"]);
        let word: u32 = data(&ask(&mut e, 0.0, "SE1.2"))[0].parse().unwrap();
        assert_eq!(
            word & (status_bit::POWER_STAGE_ERROR | status_bit::POWER_STAGE_READY),
            status_bit::POWER_STAGE_ERROR
        );
        assert_eq!(data(&ask(&mut e, 0.0, "SEC1.2 M1.2A100")), ["", ""]);
    }

    #[test]
    fn a_reference_run_ends_initialised_on_the_center_switch() {
        let mut e = emulator();
        ask(&mut e, 0.0, "M2.2P14=10000 M2.2P15=100000 M2.2A5000");
        ask(&mut e, 2.0, "M2.2P20=7000 M2.2P08=10000 M2.2P09=100000 M2.2R-C");
        let word: u32 = data(&ask(&mut e, 2.0, "SE2.2"))[0].parse().unwrap();
        assert_eq!(word & (status_bit::BUSY | status_bit::INITIALISED), status_bit::BUSY);
        let replies = ask(&mut e, 5.0, "SE2.2 M2.2P20R");
        let word: u32 = data(&replies)[0].parse().unwrap();
        let expected = status_bit::INITIALISED | status_bit::CENTER_SWITCH;
        assert_eq!(word & (status_bit::BUSY | expected), expected);
        assert_eq!(data(&replies)[1], "0");
    }
}
