//! A SmarAct MCS2 with linear positioners that have a sensor, on its TCP ASCII interface: one
//! command per line (`\n` or `\r\n`), queries answered with one line ended by `\r\n`, setters and
//! actions silent. A command it cannot take leaves an entry in the error queue (20 entries, the
//! last replaced by -350 when full) and nothing else: a refused query is not answered.
//!
//! Each channel is a physical simulator in picometres. The positioner has no limit switches:
//! the stage's switches are its mechanical end stops (END_STOP_REACHED while it stands on one),
//! its home switch the reference mark. Moves run in closed loop only: `:CHAN<n>:MMOD` takes 0
//! (absolute) and 1 (relative); the scan and step modes are refused with 19. `VEL 0` moves at
//! full speed ([`FULL_SPEED`]), `ACC 0` without ramps. A timed hold is taken as holding forever.
//! Short command forms only (`:CHAN0:STAT?`, not `:CHANnel0:STATe?`), any case.

use super::{axes, Emulator};
use crate::smaract_mcs2::{error_text, move_mode, reference_option, state, DEFAULT_PICOMETRES_PER_STEP, NAME};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};
use zmotor_msgs::bits::msta;

/// What `:DEV:SNUM?` answers.
pub(crate) const SERIAL_NUMBER: &str = "MCS2-00001234";

/// The speed of a move with velocity control off (`VEL 0`), pm/s: 10 mm/s.
pub(crate) const FULL_SPEED: f64 = 10_000_000_000.0;

/// The highest `:CHAN<n>:VEL`, pm/s (100 mm/s).
pub(crate) const MAX_VELOCITY: i64 = 100_000_000_000;

/// The highest `:CHAN<n>:ACC`, pm/s² (10 m/s²).
pub(crate) const MAX_ACCELERATION: i64 = 10_000_000_000_000;

/// What `raise_error` queues: a move of the channel was overridden.
pub(crate) const RAISED_ERROR: i64 = 272;

/// Entries the error queue holds.
const QUEUE_CAPACITY: usize = 20;

/// The queue's last entry once it is full.
const QUEUE_OVERFLOW: i64 = -350;

/// A linear positioner with a sensor counting picometres, on `stage`'s mechanics (given in record
/// steps of [`DEFAULT_PICOMETRES_PER_STEP`] pm).
pub(crate) fn positioner(stage: &SimConfig) -> SimConfig {
    let pm = |steps: f64| steps * DEFAULT_PICOMETRES_PER_STEP;
    SimConfig {
        position: pm(stage.position),
        high_limit_switch: stage.high_limit_switch.map(pm),
        low_limit_switch: stage.low_limit_switch.map(pm),
        home_switch: pm(stage.home_switch),
        encoder_counts_per_step: Some(1.0),
        // The amplifier is the drive power: switched off, the positioner does not move.
        servo: true,
        instant: stage.instant,
    }
}

/// Why a line was not carried out, as the controller numbers it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Refusal {
    UndefinedHeader,
    MissingParameter,
    ParameterNotAllowed,
    DataType,
    InvalidParameter,
    InvalidChannel,
    AmplifierDisabled,
}

impl Refusal {
    fn code(self) -> i64 {
        match self {
            Refusal::UndefinedHeader => -113,
            Refusal::MissingParameter => -109,
            Refusal::ParameterNotAllowed => -108,
            Refusal::DataType => -104,
            Refusal::InvalidParameter => 19,
            Refusal::InvalidChannel => 34,
            Refusal::AmplifierDisabled => 262,
        }
    }

    /// A line no driver should write; the others depend on the controller's state or on the
    /// channels installed.
    fn is_malformed(self) -> bool {
        !matches!(self, Refusal::InvalidChannel | Refusal::AmplifierDisabled)
    }
}

/// One channel: its positioner and its settings.
struct Channel {
    axis: SimAxis,
    move_mode: i64,
    velocity: i64,
    acceleration: i64,
    hold: i64,
    reference_options: i64,
    amplifier: bool,
    /// The control loop holds the target of the last move.
    holding: bool,
    /// A reference search is under way.
    referencing: bool,
}

impl Channel {
    fn new(axis: SimAxis) -> Self {
        Self {
            axis,
            move_mode: move_mode::CLOSED_LOOP_ABSOLUTE,
            velocity: 0,
            acceleration: 0,
            hold: 0,
            reference_options: 0,
            amplifier: true,
            holding: false,
            referencing: false,
        }
    }

    fn speed(&self) -> f64 {
        if self.velocity == 0 {
            FULL_SPEED
        } else {
            self.velocity as f64
        }
    }

    fn state_word(&self) -> u32 {
        let status = self.axis.status();
        let moving = self.axis.is_moving();
        let mut word = state::SENSOR_PRESENT | state::IS_CALIBRATED;
        let mut set = |bit: u32, condition: bool| {
            if condition {
                word |= bit;
            }
        };
        set(state::ACTIVELY_MOVING, moving);
        set(state::CLOSED_LOOP_ACTIVE, self.amplifier && (moving || self.holding));
        set(state::REFERENCING, moving && self.referencing);
        set(state::IS_REFERENCED, status.msta & msta::HOMED != 0);
        set(state::END_STOP_REACHED, status.msta & (msta::PLUS_LS | msta::MINUS_LS) != 0);
        set(state::REFERENCE_MARK, self.axis.on_home_switch());
        set(state::AMPLIFIER_ENABLED, self.amplifier);
        word
    }

    /// A reference search that has ended: without AUTO_ZERO the position at the mark is the
    /// sensor's own scale (here the carriage's physical position), not 0.
    fn settle_reference(&mut self) {
        if self.referencing && !self.axis.is_moving() {
            self.referencing = false;
            if self.reference_options & reference_option::AUTO_ZERO == 0 && self.axis.on_home_switch() {
                let scale = self.axis.physical_position();
                self.axis.set_position(scale);
            }
        }
    }

    /// A query's answer.
    fn read(&self, property: &str) -> Result<String, Refusal> {
        Ok(match property {
            ":STAT" => self.state_word().to_string(),
            ":POS" | ":POS:CURR" => (self.axis.status().position.round() as i64).to_string(),
            ":AMPL" => u8::from(self.amplifier).to_string(),
            ":MMOD" => self.move_mode.to_string(),
            ":VEL" => self.velocity.to_string(),
            ":ACC" => self.acceleration.to_string(),
            ":HOLD" => self.hold.to_string(),
            ":REF:OPT" => self.reference_options.to_string(),
            _ => return Err(Refusal::UndefinedHeader),
        })
    }

    /// A setter.
    fn write(&mut self, property: &str, argument: Option<&str>) -> Result<(), Refusal> {
        const SETTERS: [&str; 7] = [":AMPL", ":MMOD", ":VEL", ":ACC", ":HOLD", ":REF:OPT", ":POS"];
        if !SETTERS.contains(&property) {
            return Err(Refusal::UndefinedHeader);
        }
        let value = parse_value(argument.ok_or(Refusal::MissingParameter)?)?;
        let within = |low: i64, high: i64| {
            if (low..=high).contains(&value) {
                Ok(value)
            } else {
                Err(Refusal::InvalidParameter)
            }
        };
        match property {
            ":AMPL" => {
                self.amplifier = within(0, 1)? == 1;
                self.axis.enable(self.amplifier);
                if !self.amplifier {
                    self.holding = false;
                    self.referencing = false;
                }
            }
            ":MMOD" => {
                self.move_mode = within(move_mode::CLOSED_LOOP_ABSOLUTE, move_mode::CLOSED_LOOP_RELATIVE)?;
            }
            ":VEL" => self.velocity = within(0, MAX_VELOCITY)?,
            ":ACC" => self.acceleration = within(0, MAX_ACCELERATION)?,
            ":HOLD" => self.hold = within(-1, i64::from(i32::MAX))?,
            ":REF:OPT" => self.reference_options = within(0, 0x3f)?,
            _ => self.axis.set_position(value as f64),
        }
        Ok(())
    }

    /// `:MOVE<n> <value>` in the channel's move mode.
    fn start_move(&mut self, value: i64) -> Result<(), Refusal> {
        if !self.amplifier {
            return Err(Refusal::AmplifierDisabled);
        }
        let relative = self.move_mode == move_mode::CLOSED_LOOP_RELATIVE;
        let (speed, acceleration) = (self.speed(), self.acceleration as f64);
        self.axis.move_to(value as f64, relative, 0.0, speed, acceleration);
        self.referencing = false;
        self.holding = self.hold != 0;
        Ok(())
    }

    /// `:REF<n>`: the reference mark search.
    fn start_reference(&mut self) -> Result<(), Refusal> {
        if !self.amplifier {
            return Err(Refusal::AmplifierDisabled);
        }
        let forward = self.reference_options & reference_option::START_DIRECTION == 0;
        let (speed, acceleration) = (self.speed(), self.acceleration as f64);
        self.axis.home(forward, 0.0, speed, acceleration);
        self.referencing = true;
        self.holding = self.hold != 0;
        Ok(())
    }

    fn stop(&mut self) {
        self.axis.stop(self.acceleration as f64);
        self.referencing = false;
    }
}

/// A value as the controller takes it: an integer, or a decimal (the EPICS driver prints `%f`)
/// rounded to the nearest integer.
fn parse_value(text: &str) -> Result<i64, Refusal> {
    let digits = text.strip_prefix(['+', '-']).unwrap_or(text);
    let (whole, fraction) = digits.split_once('.').unwrap_or((digits, ""));
    let all_digits = |part: &str| part.bytes().all(|b| b.is_ascii_digit());
    if whole.is_empty() || !all_digits(whole) || !all_digits(fraction) {
        return Err(Refusal::DataType);
    }
    let value: f64 = text.parse().map_err(|_| Refusal::DataType)?;
    let rounded = value.round();
    if rounded >= i64::MIN as f64 && rounded < i64::MAX as f64 {
        Ok(rounded as i64)
    } else {
        Err(Refusal::InvalidParameter)
    }
}

/// The channel number at the start of `text` and what follows it.
fn channel_number(text: &str) -> Option<(usize, &str)> {
    let end = text.find(|c: char| !c.is_ascii_digit()).unwrap_or(text.len());
    Some((text[..end].parse().ok()?, &text[end..]))
}

/// An MCS2 with `channels` positioners (channels 0 …).
pub(crate) struct Mcs2Emulator {
    channels: Vec<Channel>,
    errors: VecDeque<i64>,
    input: Vec<u8>,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl Mcs2Emulator {
    /// A controller of `channels` positioners on `mechanics` (in picometres, see
    /// [`positioner`]), amplifiers on, not referenced.
    pub(crate) fn new(channels: usize, mechanics: &SimConfig) -> Self {
        Self {
            channels: axes(channels, mechanics).into_iter().map(Channel::new).collect(),
            errors: VecDeque::new(),
            input: Vec::new(),
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    fn push_error(&mut self, code: i64) {
        if self.errors.len() < QUEUE_CAPACITY {
            self.errors.push_back(code);
        } else if let Some(last) = self.errors.back_mut() {
            *last = QUEUE_OVERFLOW;
        }
    }

    fn channel_mut(&mut self, index: usize) -> Result<&mut Channel, Refusal> {
        self.channels.get_mut(index).ok_or(Refusal::InvalidChannel)
    }

    /// Carry out one line: its answer, if it is a query.
    fn execute(&mut self, line: &str) -> Result<Option<String>, Refusal> {
        let (header, argument) = match line.split_once(char::is_whitespace) {
            Some((header, argument)) => (header.to_ascii_uppercase(), Some(argument.trim())),
            None => (line.to_ascii_uppercase(), None),
        };
        if let Some(rest) = header.strip_prefix(":CHAN") {
            let (index, property) = channel_number(rest).ok_or(Refusal::UndefinedHeader)?;
            if let Some(property) = property.strip_suffix('?') {
                let answer = self.channel_mut(index)?.read(property)?;
                return if argument.is_some() { Err(Refusal::ParameterNotAllowed) } else { Ok(Some(answer)) };
            }
            self.channel_mut(index)?.write(property, argument)?;
            return Ok(None);
        }
        for verb in [":MOVE", ":STOP", ":REF"] {
            let Some((index, "")) = header.strip_prefix(verb).and_then(channel_number) else { continue };
            let channel = self.channel_mut(index)?;
            match (verb, argument) {
                (":MOVE", Some(value)) => channel.start_move(parse_value(value)?)?,
                (":MOVE", None) => return Err(Refusal::MissingParameter),
                (_, Some(_)) => return Err(Refusal::ParameterNotAllowed),
                (":STOP", None) => channel.stop(),
                _ => channel.start_reference()?,
            }
            return Ok(None);
        }
        let answer = match header.as_str() {
            ":DEV:SNUM?" => format!("\"{SERIAL_NUMBER}\""),
            ":DEV:NOCH?" => self.channels.len().to_string(),
            ":SYST:ERR:COUN?" => self.errors.len().to_string(),
            ":SYST:ERR?" | ":SYST:ERR:NEXT?" => {
                let code = self.errors.pop_front().unwrap_or(0);
                format!("{code},\"{}\"", error_text(code).unwrap_or("Unknown error"))
            }
            _ => return Err(Refusal::UndefinedHeader),
        };
        if argument.is_some() {
            return Err(Refusal::ParameterNotAllowed);
        }
        Ok(Some(answer))
    }
}

impl Emulator for Mcs2Emulator {
    fn name(&self) -> &'static str {
        NAME
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for channel in &mut self.channels {
            channel.axis.advance(now);
            channel.settle_reference();
        }
        self.input.extend_from_slice(bytes);
        while let Some(end) = self.input.iter().position(|b| *b == b'\n') {
            let line: Vec<u8> = self.input.drain(..=end).collect();
            let text = String::from_utf8_lossy(&line).trim().to_string();
            if text.is_empty() {
                continue;
            }
            match self.execute(&text) {
                Ok(Some(answer)) => self.output.push_back(format!("{answer}\r\n").into_bytes()),
                Ok(None) => {}
                Err(refusal) => {
                    if refusal.is_malformed() {
                        self.malformed += 1;
                    }
                    self.push_error(refusal.code());
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
        self.channels.get_mut(channel).map(|c| &mut c.axis)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        if channel >= self.channels.len() {
            return false;
        }
        self.push_error(RAISED_ERROR);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::emulation::stage;
    use zmotor_core::SimSetting;
    use zmotor_msgs::Value;

    fn mcs2() -> Mcs2Emulator {
        Mcs2Emulator::new(2, &positioner(&stage()))
    }

    /// Send `text` at `seconds`; every reply line since.
    fn say(e: &mut Mcs2Emulator, seconds: f64, text: &str) -> Vec<String> {
        e.handle_input(Instant::from_secs_f64(seconds), text.as_bytes());
        std::iter::from_fn(|| e.poll_transmit()).map(|b| String::from_utf8_lossy(&b).into_owned()).collect()
    }

    #[test]
    fn queries_are_answered_with_crlf_and_setters_are_silent() {
        let mut e = mcs2();
        // Power-up: sensor, calibrated, at the reference mark, amplifier on, not referenced.
        let word = state::SENSOR_PRESENT | state::IS_CALIBRATED | state::REFERENCE_MARK | state::AMPLIFIER_ENABLED;
        assert_eq!(say(&mut e, 0.0, ":CHAN0:STAT?\r\n"), [format!("{word}\r\n")]);
        assert_eq!(say(&mut e, 0.0, ":chan1:vel 2000000.000000\n:CHAN1:VEL?\n"), ["2000000\r\n"], "%f taken, any case");
        assert_eq!(say(&mut e, 0.0, ":DEV:SNUM?\r\n:DEV:NOCH?\r\n"), ["\"MCS2-00001234\"\r\n", "2\r\n"]);
        assert_eq!(
            say(&mut e, 0.0, ":CHAN0:POS 1500\r\n:CHAN0:POS?\r\n:CHAN0:POS:CURR?\r\n"),
            ["1500\r\n", "1500\r\n"]
        );
        assert_eq!(say(&mut e, 0.0, "\r\n\n"), Vec::<String>::new());
        assert_eq!(say(&mut e, 0.0, ":SYST:ERR?\r\n"), ["0,\"No error\"\r\n"]);
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_closed_loop_move_runs_at_the_set_velocity_and_holds() {
        let mut e = mcs2();
        say(&mut e, 0.0, ":CHAN0:HOLD -1\r\n:CHAN0:MMOD 0\r\n:CHAN0:ACC 0\r\n:CHAN0:VEL 1000000\r\n:MOVE0 500000\r\n");
        let moving = say(&mut e, 0.25, ":CHAN0:STAT?\r\n:CHAN0:POS?\r\n");
        let word = state::ACTIVELY_MOVING | state::CLOSED_LOOP_ACTIVE | state::SENSOR_PRESENT | state::IS_CALIBRATED;
        assert_eq!(moving, [format!("{}\r\n", word | state::AMPLIFIER_ENABLED), "250000\r\n".to_string()]);
        let done = say(&mut e, 1.0, ":CHAN0:STAT?\r\n:CHAN0:POS?\r\n:MOVE0 -1000\r\n:CHAN0:MMOD 1\r\n:MOVE0 -1000\r\n");
        let word = state::CLOSED_LOOP_ACTIVE | state::SENSOR_PRESENT | state::IS_CALIBRATED | state::AMPLIFIER_ENABLED;
        assert_eq!(done, [format!("{word}\r\n"), "500000\r\n".to_string()]);
        assert_eq!(
            say(&mut e, 2.0, ":CHAN0:POS?\r\n"),
            ["499000\r\n"],
            "the absolute move was overridden by the relative one"
        );
    }

    #[test]
    fn a_stage_driven_into_its_end_stop_stops_there_and_says_so() {
        let mut e = mcs2();
        say(&mut e, 0.0, ":CHAN1:MMOD 1\r\n:CHAN1:VEL 0\r\n:MOVE1 -100000000000\r\n");
        let word: u32 = say(&mut e, 1.0, ":CHAN1:STAT?\r\n")[0].trim().parse().unwrap();
        assert_eq!(word & (state::ACTIVELY_MOVING | state::END_STOP_REACHED), state::END_STOP_REACHED);
        assert_eq!(say(&mut e, 1.0, ":CHAN1:POS?\r\n"), ["-200000000\r\n"]);
    }

    #[test]
    fn a_reference_search_ends_on_the_mark_at_zero_or_at_the_sensor_scale() {
        let mut e = mcs2();
        say(&mut e, 0.0, ":CHAN0:VEL 0\r\n:MOVE0 3000000\r\n");
        say(&mut e, 1.0, ":CHAN0:REF:OPT 5\r\n:CHAN0:REF0\r\n:REF0\r\n");
        assert_eq!(e.malformed(), 1, ":CHAN0:REF0 is no command");
        let word: u32 = say(&mut e, 1.0, ":CHAN0:STAT?\r\n")[0].trim().parse().unwrap();
        assert_ne!(word & state::REFERENCING, 0);
        let word: u32 = say(&mut e, 2.0, ":CHAN0:STAT?\r\n")[0].trim().parse().unwrap();
        let found = state::IS_REFERENCED | state::REFERENCE_MARK;
        assert_eq!(word & (found | state::REFERENCING | state::ACTIVELY_MOVING), found);
        assert_eq!(say(&mut e, 2.0, ":CHAN0:POS?\r\n"), ["0\r\n"], "AUTO_ZERO");
        // Without AUTO_ZERO the mark keeps the sensor's scale: the stage's home at 0 pm here,
        // so move the mark to see it.
        e.axis(1).expect("channel 1").apply(SimSetting::Home, &Value::Float(2_000_000.0)).unwrap();
        say(&mut e, 2.0, ":CHAN1:POS 7\r\n:CHAN1:VEL 0\r\n:CHAN1:REF:OPT 0\r\n:REF1\r\n");
        assert_eq!(say(&mut e, 3.0, ":CHAN1:POS?\r\n"), ["2000000\r\n"]);
    }

    #[test]
    fn refusals_go_to_the_error_queue_and_what_no_driver_should_send_is_malformed() {
        let mut e = mcs2();
        assert_eq!(
            say(
                &mut e,
                0.0,
                ":CHAN0:FOO?\r\n:CHAN0:VEL fast\r\n:CHAN0:MMOD 4\r\n:CHAN0:STAT? 1\r\n:STOP0 1\r\n:CHAN0:VEL\r\n"
            ),
            Vec::<String>::new()
        );
        assert_eq!(e.malformed(), 6);
        // A channel the controller does not have, and a move with the amplifier off: refused,
        // the driver's fault neither.
        assert_eq!(say(&mut e, 0.0, ":CHAN7:STAT?\r\n:CHAN0:AMPL 0\r\n:MOVE0 1000\r\n:REF0\r\n"), Vec::<String>::new());
        assert_eq!(e.malformed(), 6);
        assert_eq!(say(&mut e, 0.0, ":SYST:ERR:COUN?\r\n"), ["9\r\n"]);
        let entries: Vec<String> = (0..11).flat_map(|_| say(&mut e, 0.0, ":SYST:ERR?\r\n")).collect();
        let codes: Vec<&str> = entries.iter().map(|entry| entry.split(',').next().unwrap_or("")).collect();
        assert_eq!(codes, ["-113", "-104", "19", "-108", "-108", "-109", "34", "262", "262", "0", "0"]);
        assert_eq!(entries[7], "262,\"Amplifier disabled\"\r\n");
        let axis = e.axis(0).expect("channel 0");
        assert!(!axis.is_moving());
        assert!(e.raise_error(1));
        assert!(!e.raise_error(2));
        for _ in 0..QUEUE_CAPACITY {
            e.raise_error(0);
        }
        let entries: Vec<String> = (0..QUEUE_CAPACITY).flat_map(|_| say(&mut e, 0.0, ":SYST:ERR?\r\n")).collect();
        assert_eq!(entries[0], "272,\"Movement overridden\"\r\n");
        assert_eq!(entries.last().map(String::as_str), Some("-350,\"Queue overflow\"\r\n"));
    }
}
