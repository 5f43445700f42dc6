//! The Kohzu Precision SC-200/SC-400/SC-800 stepping-motor controllers (2, 4 or 8 axes), on
//! RS-232C or Ethernet (TCP): every command an STX (0x02), a three-letter mnemonic, its
//! parameters separated by `/` (the first, the axis number, glued to the mnemonic) and CR LF
//! (`\x02APS1/2/0/0/5000/0/0/1\r\n`); every reply a letter (`C` done, `W` warning, `E` error),
//! TAB-separated fields and CR LF (`C\tRDP1\t5000\r\n`).
//!
//! # Witnesses
//!
//! Kohzu's "SC-400/SC-800 Operation Manual" itself could not be found in any searchable
//! corpus (searched in English and Japanese); what it says reaches this file through three
//! clients and one emulator that were written from it, used only for the bytes on the wire:
//!
//! 1. The EPICS driver, epics-motor/motorKohzu (`drvSC800.cc`, `devSC800.cc`, R. Sluiter
//!    2007, SC-200/400 added 2009; its README quotes the manual). It gives the bytes: STX
//!    before, CR LF after every command and reply; `IDN` answered `C\tIDN0\t<model>\t<ver>`
//!    (model `800`, `400` or `200`, a number); `STR1/<axis>` answered
//!    `C\tSTR<axis>\t1\t<move>\t<norg>\t<orgg>\t<cwlm>\t<ccwl>\t<swng>\t<errr>`, `move` 0 when
//!    done, `cwlm`/`ccwl` 1 on the plus (CW) / minus (CCW) limit switch; `RDP<axis>/0`
//!    answered `C\tRDP<axis>\t<position>` (a signed decimal count); `RSY<axis>/21` answered
//!    `C\tRSY<axis>\t21\t<n>`, 0 when the motor is energised; the commands
//!    `ASI<axis>/<start speed>/<max speed>/<accel time>/<decel time>/0/…` (14 parameters,
//!    speeds 1 to 4 095 500 pulse/s, times in 10 ms), `APS<axis>/2/0/0/<position>/0/0/1`,
//!    `RPS` alike, `ORG<axis>/2/0/0/3/1`, `FRP<axis>/2/0/0/<1 = CW, 0 = CCW>/1` (a jog),
//!    `STP<axis>/0`, `WRP<axis>/<position>`, `COF<axis>/<0 energise, 1 release>`. From the
//!    manual, quoted: STP's "Response is transmitted at the time when the axis completely
//!    stops"; and "the home search can only be started in the positive direction".
//! 2. The MX driver (`i_kohzu_sc.c`, `d_kohzu_sc.c`, W. Lavender 2004–2006). Replies begin
//!    `C`, `W` or `E`, the code of a `W`/`E` in the third TAB field. Error numbers: 1 first
//!    byte not STX, 2 "total number of commands is short", 3 no CR, 4 illegal characters,
//!    5 illegal command, 10 manual mode, 100 wrong number of parameters, 101–107 "the
//!    numerical value of parameter N is out of range" (N = code − 100). Warnings: 1 target and
//!    present position the same, 2 (OSC waiting time), 100 (TPS). `STP<axis>/1` is the
//!    immediate stop, `/0` the decelerating one. `RMS<axis>` is answered with the start speed
//!    in field 2, the maximum speed in 3, acceleration and deceleration times (10 ms) in 15
//!    and 16. Serial at 9600/19200/38400 baud. 4 095 500 pulse/s maximum "as documented in
//!    the manual".
//! 3. A user's script for an SC-410 (github Eric-nih/Kohzu3Axes, `commandList.txt`,
//!    `stageCommands.py`): `APS1/2/0/0/4000/3/0/0`, `ORG1/2/0/0/3/0`, `STR1/1` ("the stage
//!    number is the second parameter"), the driving flag read at byte 9 of `C\tSTR1\t1\t…`,
//!    and the script waiting for the reply of a move sent with a last parameter 0.
//! 4. Diamond's Kohzu simulator (`dls_simulationlib`, J. Thompson, October 2010): motion
//!    commands answered `C\t<CMD><axis>`, the same `STR`, `RDP`, `RSY` and `IDN` forms.
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Channels and units.** `new(channels, …)` makes axes 1 to `channels` (one at least,
//!   eight at most), numbered on the wire as on the front panel; `axis(n)` and
//!   `raise_error(n)` take the same numbers. `IDN` names the model the count fits: `200` up
//!   to 2 axes, `400` up to 4, else `800`; the version is `1000`. One pulse is one simulator
//!   step; positions are 32-bit signed.
//! - **Move parameters** (`APS`/`RPS`, 8 parameters): 1 axis, 2 speed table (0–9), 3 and 4
//!   accepted and ignored (any integer; an acceleration pattern is a guess), 5 target, 6 and
//!   7 ignored, 8 reply method: 1 answers at once, 0 only when the motion ends (the script of
//!   witness 3 waits for it; the pollers of witnesses 1 and 2 send 1). `ORG` (6 parameters):
//!   axis, table, two ignored, origin method (0–15, all search the home switch alike), reply
//!   method. `FRP` (6): axis, table, two ignored, direction, reply method. Every speed table
//!   holds the axis's `ASI` speeds (the EPICS driver writes `ASI` before every move and names
//!   table 2): the number is checked, not used.
//! - **Speeds.** Power-on: start 100 pulse/s, maximum 10 000 pulse/s, 0.2 s ramps (times
//!   20). Ramps are linear from the start to the maximum speed over the acceleration time;
//!   a motion decelerates as it accelerated; `STP…/0` decelerates over the deceleration time,
//!   `/1` and a time 0 stop at once. ASI's parameters 6–14 are accepted (any integer) and
//!   ignored; `RMS` answers 0 in its fields 4–14.
//! - **Replies held.** A held reply (`STP` of a moving axis, a motion with reply method 0)
//!   goes out when the axis comes to rest, whatever else was answered meanwhile; other
//!   commands are served while it waits. A motion to where the axis already is answers
//!   `W\t<CMD><axis>\t1` at once.
//! - **Error form** `E\t<head>\t<code>`, head being the mnemonic and first parameter as
//!   received (`E\tAPS9\t101`); before a mnemonic could be read, whatever printable text
//!   came before the first `/`. The axis is parameter 1 (an axis the controller lacks is
//!   101), except in `STR`, whose mode (only 1) is parameter 1 and axis parameter 2. Numbers
//!   are decimal with an optional `-`; an empty or unparseable parameter is out of range.
//!   Allowed characters after STX: `A`–`Z`, `0`–`9`, `/`, `-`, else 4; fewer than three
//!   characters 2; a mnemonic not known 5. Every `E` is counted as malformed; warnings are
//!   not. Error 10 (manual mode) is never given. Lines are split at LF; blank lines are
//!   ignored; 256 bytes without LF overflow the input buffer.
//! - **`STR` fields.** NORG lights within 1 000 pulses of the home switch, ORG on it; the
//!   soft-limit field is always 0 (no soft limits are emulated); the error field is 1 after
//!   `raise_error` (the axis stops at once) until the next accepted drive command or `STP`.
//! - **Motion and state.** A new drive command replaces one in progress. A motion into a
//!   limit switch stops there; moving away is allowed. `WRP` redefines the position even
//!   while moving. System parameters (`RSY`/`WSY`) are 1–99, any integer, power-on 0;
//!   number 21 (0 or 1) is `COF`'s excitation state. A released (`COF…/1`) motor still moves
//!   in the emulator.

use crate::emulator::axes;
use crate::{Emulator, Lines};
use std::collections::{BTreeMap, VecDeque};
use std::ops::RangeInclusive;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

/// Axes on an SC-800.
const MAX_AXES: usize = 8;
/// Commands end at the line feed of their CR LF.
const LF: &[u8] = b"\n";
const STX: u8 = 0x02;
const INPUT_BUFFER: usize = 256;
const FIRMWARE: u32 = 1000;
/// Pulse/s, "as documented in the manual" (witness 2).
const MAX_SPEED: i64 = 4_095_500;
/// Acceleration and deceleration times, 10 ms.
const MAX_TIME: i64 = 1_000_000;
const TABLES: RangeInclusive<i64> = 0..=9;
const SYSTEM: RangeInclusive<i64> = 1..=99;
/// The system parameter holding the excitation state (0 energised).
const EXCITATION: i64 = 21;
const ANY: RangeInclusive<i64> = i32::MIN as i64..=i32::MAX as i64;
const FLAG: RangeInclusive<i64> = 0..=1;
/// Pulses either side of the home switch where NORG lights.
const NEAR_ORIGIN: f64 = 1000.0;

const NO_STX: u32 = 1;
const SHORT: u32 = 2;
const NO_CR: u32 = 3;
const ILLEGAL_CHARACTER: u32 = 4;
const ILLEGAL_COMMAND: u32 = 5;
const PARAMETER_COUNT: u32 = 100;
/// Warning: the target is where the axis is.
const SAME_POSITION: u32 = 1;

/// One axis: its settings and the carriage behind it.
#[derive(Debug)]
struct Axis {
    sim: SimAxis,
    /// Pulse/s.
    start_speed: i64,
    /// Pulse/s.
    max_speed: i64,
    /// 10 ms.
    accel_time: i64,
    /// 10 ms.
    decel_time: i64,
    system: BTreeMap<i64, i64>,
    /// Raised by `raise_error`, shown in STR's last field.
    error: bool,
}

impl Axis {
    fn new(sim: SimAxis) -> Self {
        Self {
            sim,
            start_speed: 100,
            max_speed: 10_000,
            accel_time: 20,
            decel_time: 20,
            system: BTreeMap::new(),
            error: false,
        }
    }

    fn position(&self) -> i64 {
        self.sim.status().position.round() as i64
    }

    /// (start, maximum) speed, pulse/s.
    fn speeds(&self) -> (f64, f64) {
        (self.start_speed as f64, self.max_speed as f64)
    }

    /// Pulse/s² of a ramp from the start to the maximum speed over `time` (10 ms); 0 none.
    fn rate(&self, time: i64) -> f64 {
        let (start, max) = self.speeds();
        if time <= 0 {
            0.0
        } else {
            (max - start).max(0.0) / (time as f64 * 0.01)
        }
    }

    fn status_fields(&self) -> [u8; 7] {
        let state = self.sim.state();
        let home = self.sim.config().home_switch;
        [
            u8::from(self.sim.is_moving()),
            u8::from((state.position - home).abs() <= NEAR_ORIGIN),
            u8::from(self.sim.on_home_switch()),
            u8::from(state.high_limit),
            u8::from(state.low_limit),
            0,
            u8::from(self.error),
        ]
    }
}

/// What a command comes to: a reply now, or one held until an axis is at rest.
enum Reply {
    Now(String),
    Held(usize, String),
}

/// An `E` reply's code.
type Code = u32;

/// The parameters of one command, numbered from 1 as the error codes count them.
struct Params<'a>(Vec<&'a str>);

impl Params<'_> {
    fn count(&self, n: usize) -> Result<(), Code> {
        if self.0.len() == n {
            Ok(())
        } else {
            Err(PARAMETER_COUNT)
        }
    }

    fn int(&self, n: usize, range: RangeInclusive<i64>) -> Result<i64, Code> {
        let out_of_range = PARAMETER_COUNT + n as Code;
        let text = self.0.get(n.wrapping_sub(1)).copied().unwrap_or("");
        let digits = text.strip_prefix('-').unwrap_or(text);
        if digits.is_empty() || digits.len() > 12 || !digits.bytes().all(|b| b.is_ascii_digit()) {
            return Err(out_of_range);
        }
        text.parse().ok().filter(|v| range.contains(v)).ok_or(out_of_range)
    }
}

/// An SC-200/400/800 with axes 1 … n.
pub struct KohzuScEmulator {
    axes: Vec<Axis>,
    lines: Lines,
    output: VecDeque<Vec<u8>>,
    held: Vec<(usize, String)>,
    malformed: usize,
}

impl KohzuScEmulator {
    /// A controller with `channels` axes (one at least, eight at most), numbered 1 to
    /// `channels` on the wire; an SC-400 has 4.
    pub fn new(channels: usize, mechanics: &SimConfig) -> Self {
        let channels = channels.clamp(1, MAX_AXES);
        Self {
            axes: axes(channels, mechanics).into_iter().map(Axis::new).collect(),
            lines: Lines::new(LF, INPUT_BUFFER),
            output: VecDeque::new(),
            held: Vec::new(),
            malformed: 0,
        }
    }

    fn model(&self) -> u32 {
        match self.axes.len() {
            0..=2 => 200,
            3..=4 => 400,
            _ => 800,
        }
    }

    fn advance(&mut self, now: Instant) {
        for axis in &mut self.axes {
            axis.sim.advance(now);
        }
        self.release();
    }

    /// Held replies whose axis has come to rest go out, in the order they were held.
    fn release(&mut self) {
        let axes = &self.axes;
        let output = &mut self.output;
        self.held.retain(|(index, reply)| {
            let done = axes.get(*index).is_none_or(|axis| !axis.sim.is_moving());
            if done {
                output.push_back(format!("{reply}\r\n").into_bytes());
            }
            !done
        });
    }

    /// The reply to one line (its LF removed).
    fn answer(&mut self, line: &[u8]) -> Reply {
        let head = line.strip_prefix(&[STX]).unwrap_or(line);
        let head: String = head
            .iter()
            .take_while(|&&b| b != b'/')
            .filter(|b| b.is_ascii_graphic())
            .take(8)
            .map(|&b| char::from(b))
            .collect();
        let refuse = |code: Code| Reply::Now(format!("E\t{head}\t{code}"));
        let Some(body) = line.strip_suffix(b"\r") else { return refuse(NO_CR) };
        let Some(body) = body.strip_prefix(&[STX]) else { return refuse(NO_STX) };
        if body.len() < 3 {
            return refuse(SHORT);
        }
        if !body.iter().all(|b| b.is_ascii_uppercase() || b.is_ascii_digit() || matches!(b, b'/' | b'-')) {
            return refuse(ILLEGAL_CHARACTER);
        }
        let Ok(text) = std::str::from_utf8(body) else { return refuse(ILLEGAL_CHARACTER) };
        let (mnemonic, rest) = text.split_at(3);
        let params = Params(if rest.is_empty() { Vec::new() } else { rest.split('/').collect() });
        self.execute(mnemonic, &params).unwrap_or_else(refuse)
    }

    fn axis_index(&self, params: &Params<'_>, n: usize) -> Result<usize, Code> {
        let number = params.int(n, 1..=self.axes.len() as i64)?;
        Ok(number as usize - 1)
    }

    /// Carry out one well-formed command.
    fn execute(&mut self, mnemonic: &str, p: &Params<'_>) -> Result<Reply, Code> {
        let now = |text: String| Ok(Reply::Now(text));
        let done = |index: usize| Reply::Now(format!("C\t{mnemonic}{}", index + 1));
        match mnemonic {
            "IDN" => {
                p.count(0)?;
                now(format!("C\tIDN0\t{}\t{FIRMWARE}", self.model()))
            }
            "APS" | "RPS" => {
                p.count(8)?;
                let i = self.axis_index(p, 1)?;
                p.int(2, TABLES)?;
                p.int(3, ANY)?;
                p.int(4, ANY)?;
                let target = p.int(5, ANY)?;
                p.int(6, ANY)?;
                p.int(7, ANY)?;
                let wait = p.int(8, FLAG)? == 0;
                let relative = mnemonic == "RPS";
                let axis = &mut self.axes[i];
                let here = axis.position();
                if (relative && target == 0) || (!relative && target == here) {
                    return now(format!("W\t{mnemonic}{}\t{SAME_POSITION}", i + 1));
                }
                let ((start, max), rate) = (axis.speeds(), axis.rate(axis.accel_time));
                axis.error = false;
                axis.sim.move_to(target as f64, relative, start, max, rate);
                Ok(self.hold_if(wait, i, done(i)))
            }
            "ORG" | "FRP" => {
                p.count(6)?;
                let i = self.axis_index(p, 1)?;
                p.int(2, TABLES)?;
                p.int(3, ANY)?;
                p.int(4, ANY)?;
                let fifth = p.int(5, if mnemonic == "ORG" { 0..=15 } else { FLAG })?;
                let wait = p.int(6, FLAG)? == 0;
                let axis = &mut self.axes[i];
                let ((start, max), rate) = (axis.speeds(), axis.rate(axis.accel_time));
                axis.error = false;
                if mnemonic == "ORG" {
                    axis.sim.home(true, start, max, rate);
                } else {
                    let velocity = if fifth == 1 { max } else { -max };
                    axis.sim.move_velocity(start, velocity, rate);
                }
                Ok(self.hold_if(wait, i, done(i)))
            }
            "STP" => {
                p.count(2)?;
                let i = self.axis_index(p, 1)?;
                let immediate = p.int(2, FLAG)? == 1;
                let axis = &mut self.axes[i];
                let rate = if immediate { 0.0 } else { axis.rate(axis.decel_time) };
                axis.error = false;
                axis.sim.stop(rate);
                Ok(self.hold_if(true, i, done(i)))
            }
            "RDP" => {
                p.count(2)?;
                let i = self.axis_index(p, 1)?;
                p.int(2, FLAG)?;
                now(format!("C\tRDP{}\t{}", i + 1, self.axes[i].position()))
            }
            "STR" => {
                p.count(2)?;
                p.int(1, 1..=1)?;
                let i = self.axis_index(p, 2)?;
                let fields: Vec<String> = self.axes[i].status_fields().iter().map(u8::to_string).collect();
                now(format!("C\tSTR{}\t1\t{}", i + 1, fields.join("\t")))
            }
            "WRP" => {
                p.count(2)?;
                let i = self.axis_index(p, 1)?;
                let position = p.int(2, ANY)?;
                self.axes[i].sim.set_position(position as f64);
                Ok(done(i))
            }
            "RSY" => {
                p.count(2)?;
                let i = self.axis_index(p, 1)?;
                let number = p.int(2, SYSTEM)?;
                let value = self.axes[i].system.get(&number).copied().unwrap_or(0);
                now(format!("C\tRSY{}\t{number}\t{value}", i + 1))
            }
            "WSY" => {
                p.count(3)?;
                let i = self.axis_index(p, 1)?;
                let number = p.int(2, SYSTEM)?;
                let value = p.int(3, if number == EXCITATION { FLAG } else { ANY })?;
                self.axes[i].system.insert(number, value);
                Ok(done(i))
            }
            "COF" => {
                p.count(2)?;
                let i = self.axis_index(p, 1)?;
                let released = p.int(2, FLAG)?;
                self.axes[i].system.insert(EXCITATION, released);
                Ok(done(i))
            }
            "ASI" => {
                p.count(14)?;
                let i = self.axis_index(p, 1)?;
                let start = p.int(2, 1..=MAX_SPEED)?;
                let max = p.int(3, 1..=MAX_SPEED)?;
                let accel = p.int(4, 0..=MAX_TIME)?;
                let decel = p.int(5, 0..=MAX_TIME)?;
                for n in 6..=14 {
                    p.int(n, ANY)?;
                }
                let axis = &mut self.axes[i];
                (axis.start_speed, axis.max_speed, axis.accel_time, axis.decel_time) = (start, max, accel, decel);
                Ok(done(i))
            }
            "RMS" => {
                p.count(1)?;
                let i = self.axis_index(p, 1)?;
                let axis = &self.axes[i];
                let unused = ["0"; 11].join("\t");
                now(format!(
                    "C\tRMS{}\t{}\t{}\t{unused}\t{}\t{}",
                    i + 1,
                    axis.start_speed,
                    axis.max_speed,
                    axis.accel_time,
                    axis.decel_time
                ))
            }
            _ => Err(ILLEGAL_COMMAND),
        }
    }

    /// `reply`, held until axis `index` is at rest when `wait` (and it moves).
    fn hold_if(&self, wait: bool, index: usize, reply: Reply) -> Reply {
        match reply {
            Reply::Now(text) if wait && self.axes[index].sim.is_moving() => Reply::Held(index, text),
            other => other,
        }
    }
}

impl Emulator for KohzuScEmulator {
    fn name(&self) -> &'static str {
        "kohzu_sc"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        self.advance(now);
        for line in self.lines.push(bytes) {
            if line.iter().all(u8::is_ascii_whitespace) {
                continue;
            }
            match self.answer(&line) {
                Reply::Now(text) => {
                    if text.starts_with('E') {
                        self.malformed += 1;
                    }
                    self.output.push_back(format!("{text}\r\n").into_bytes());
                }
                Reply::Held(index, text) => self.held.push((index, text)),
            }
        }
        self.release();
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
        axis.sim.stop(0.0);
        axis.error = true;
        true
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.advance(now);
    }

    fn poll_timeout(&self) -> Option<Instant> {
        self.held.iter().filter_map(|(index, _)| self.axes.get(*index)?.sim.next_event()).min()
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

    fn send(e: &mut KohzuScEmulator, now: Instant, command: &str) {
        e.handle_input(now, format!("\x02{command}\r\n").as_bytes());
    }

    fn replies(e: &mut KohzuScEmulator) -> Vec<String> {
        std::iter::from_fn(|| e.poll_transmit()).map(|r| String::from_utf8(r).expect("ASCII")).collect()
    }

    fn exchange(e: &mut KohzuScEmulator, now: Instant, command: &str) -> String {
        send(e, now, command);
        let mut all = replies(e);
        assert_eq!(all.len(), 1, "one reply to {command:?}: {all:?}");
        all.remove(0)
    }

    fn position(e: &mut KohzuScEmulator, now: Instant, axis: usize) -> i64 {
        let reply = exchange(e, now, &format!("RDP{axis}/0"));
        reply.trim_end().rsplit('\t').next().and_then(|p| p.parse().ok()).expect("a position")
    }

    #[test]
    fn identification_and_power_on_state() {
        let mut e = KohzuScEmulator::new(4, &stage());
        assert_eq!(exchange(&mut e, at(0), "IDN"), "C\tIDN0\t400\t1000\r\n");
        assert_eq!(exchange(&mut e, at(0), "STR1/3"), "C\tSTR3\t1\t0\t1\t1\t0\t0\t0\t0\r\n", "on the home switch");
        assert_eq!(exchange(&mut e, at(0), "RDP4/0"), "C\tRDP4\t0\r\n");
        assert_eq!(exchange(&mut e, at(0), "RSY1/21"), "C\tRSY1\t21\t0\r\n");
        assert_eq!(exchange(&mut e, at(0), "COF1/1"), "C\tCOF1\r\n");
        assert_eq!(exchange(&mut e, at(0), "RSY1/21"), "C\tRSY1\t21\t1\r\n");
        assert_eq!(exchange(&mut e, at(0), "WSY2/5/-7"), "C\tWSY2\r\n");
        assert_eq!(exchange(&mut e, at(0), "RSY2/5"), "C\tRSY2\t5\t-7\r\n");
        assert_eq!(exchange(&mut e, at(0), "ASI2/150/1500/20/30/0/0/0/1/1/0/0/2/0"), "C\tASI2\r\n");
        assert_eq!(exchange(&mut e, at(0), "RMS2"), "C\tRMS2\t150\t1500\t0\t0\t0\t0\t0\t0\t0\t0\t0\t0\t0\t20\t30\r\n");
        assert_eq!(exchange(&mut e, at(0), "WRP3/-250"), "C\tWRP3\r\n");
        assert_eq!(exchange(&mut e, at(0), "RDP3/1"), "C\tRDP3\t-250\r\n");
        assert_eq!(e.malformed(), 0);
        assert_eq!(e.name(), "kohzu_sc");
        let mut sc800 = KohzuScEmulator::new(12, &stage());
        assert_eq!(exchange(&mut sc800, at(0), "IDN"), "C\tIDN0\t800\t1000\r\n");
        assert!(sc800.axis(8).is_some() && sc800.axis(9).is_none() && sc800.axis(0).is_none());
        let mut sc200 = KohzuScEmulator::new(0, &stage());
        assert_eq!(exchange(&mut sc200, at(0), "IDN"), "C\tIDN0\t200\t1000\r\n");
        assert_eq!(sc200.axes.len(), 1);
    }

    #[test]
    fn a_move_answered_at_once_arrives() {
        let mut e = KohzuScEmulator::new(4, &stage());
        // Ramps 100 → 1000 pulse/s in 0.1 s: 5000 pulses take about 5.09 s.
        assert_eq!(exchange(&mut e, at(0), "ASI1/100/1000/10/10/0/0/0/0/0/0/0/0/0"), "C\tASI1\r\n");
        assert_eq!(exchange(&mut e, at(0), "APS1/2/0/0/5000/0/0/1"), "C\tAPS1\r\n");
        assert_eq!(exchange(&mut e, at(2000), "STR1/1"), "C\tSTR1\t1\t1\t0\t0\t0\t0\t0\t0\r\n", "driving");
        let p = position(&mut e, at(2000), 1);
        assert!((1900..=2000).contains(&p), "{p}");
        assert_eq!(exchange(&mut e, at(5200), "STR1/1"), "C\tSTR1\t1\t0\t0\t0\t0\t0\t0\t0\r\n", "done");
        assert_eq!(position(&mut e, at(5200), 1), 5000);
        assert_eq!(exchange(&mut e, at(5200), "RPS1/2/0/0/-500/3/0/1"), "C\tRPS1\r\n");
        assert_eq!(position(&mut e, at(7000), 1), 4500);
        assert_eq!(exchange(&mut e, at(7000), "APS1/2/0/0/4500/0/0/1"), "W\tAPS1\t1\r\n", "already there");
        assert_eq!(exchange(&mut e, at(7000), "RPS1/0/0/0/0/0/0/0"), "W\tRPS1\t1\r\n");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_move_with_reply_method_0_is_answered_when_it_ends() {
        let mut e = KohzuScEmulator::new(4, &stage());
        send(&mut e, at(0), "APS2/2/0/0/3000/3/0/0");
        assert!(replies(&mut e).is_empty());
        let due = e.poll_timeout().expect("a reply is held");
        assert_eq!(exchange(&mut e, at(100), "STR1/2"), "C\tSTR2\t1\t1\t1\t0\t0\t0\t0\t0\r\n", "served meanwhile");
        e.handle_timeout(due);
        assert_eq!(replies(&mut e), ["C\tAPS2\r\n"]);
        assert_eq!(e.poll_timeout(), None);
        assert_eq!(position(&mut e, due, 2), 3000);
    }

    #[test]
    fn a_jog_is_stopped_and_the_stop_answered_at_rest() {
        let mut e = KohzuScEmulator::new(4, &stage());
        assert_eq!(exchange(&mut e, at(0), "FRP1/2/0/0/0/1"), "C\tFRP1\r\n");
        assert!(position(&mut e, at(1000), 1) < -9000, "CCW at 10 000 pulse/s");
        send(&mut e, at(1000), "STP1/0");
        assert!(replies(&mut e).is_empty(), "decelerating for 0.2 s");
        assert_eq!(exchange(&mut e, at(1100), "STR1/1"), "C\tSTR1\t1\t1\t0\t0\t0\t0\t0\t0\r\n");
        send(&mut e, at(1300), "STR1/1");
        assert_eq!(replies(&mut e), ["C\tSTP1\r\n", "C\tSTR1\t1\t0\t0\t0\t0\t0\t0\t0\r\n"]);
        assert_eq!(exchange(&mut e, at(1300), "STP1/0"), "C\tSTP1\r\n", "at rest: at once");
        assert_eq!(exchange(&mut e, at(1300), "FRP1/2/0/0/1/1"), "C\tFRP1\r\n");
        assert_eq!(exchange(&mut e, at(2000), "STP1/1"), "C\tSTP1\r\n", "an immediate stop");
        let p = position(&mut e, at(2000), 1);
        assert_eq!(position(&mut e, at(3000), 1), p);
    }

    #[test]
    fn a_jog_ends_on_a_limit_switch() {
        let mut e = KohzuScEmulator::new(4, &stage());
        send(&mut e, at(0), "FRP3/2/0/0/1/0");
        assert!(replies(&mut e).is_empty());
        send(&mut e, at(25_000), "STR1/3");
        let on_cw = "C\tSTR3\t1\t0\t0\t0\t1\t0\t0\t0\r\n";
        assert_eq!(replies(&mut e), ["C\tFRP3\r\n", on_cw], "the held reply goes first");
        assert!(e.held.is_empty());
        assert_eq!(position(&mut e, at(25_000), 3), 200_000);
        assert_eq!(exchange(&mut e, at(25_000), "RPS3/2/0/0/-1000/0/0/1"), "C\tRPS3\r\n", "away from it");
        assert_eq!(exchange(&mut e, at(27_000), "STR1/3"), "C\tSTR3\t1\t0\t0\t0\t0\t0\t0\t0\r\n");
        send(&mut e, at(27_000), "FRP3/2/0/0/0/0");
        e.handle_timeout(at(70_000));
        assert_eq!(replies(&mut e), ["C\tFRP3\r\n"]);
        assert_eq!(exchange(&mut e, at(70_000), "STR1/3"), "C\tSTR3\t1\t0\t0\t0\t0\t1\t0\t0\r\n", "on CCW");
    }

    #[test]
    fn an_origin_search_ends_at_zero_on_the_switch() {
        let mut e = KohzuScEmulator::new(4, &stage());
        exchange(&mut e, at(0), "APS4/2/0/0/5000/0/0/1");
        assert_eq!(exchange(&mut e, at(2000), "WRP4/12345"), "C\tWRP4\r\n");
        assert_eq!(exchange(&mut e, at(2000), "STR1/4"), "C\tSTR4\t1\t0\t0\t0\t0\t0\t0\t0\r\n");
        assert_eq!(exchange(&mut e, at(2000), "ORG4/2/0/0/3/1"), "C\tORG4\r\n");
        assert_eq!(exchange(&mut e, at(2100), "STR1/4"), "C\tSTR4\t1\t1\t0\t0\t0\t0\t0\t0\r\n");
        assert_eq!(exchange(&mut e, at(4000), "STR1/4"), "C\tSTR4\t1\t0\t1\t1\t0\t0\t0\t0\r\n");
        assert_eq!(position(&mut e, at(4000), 4), 0);
        assert_eq!(e.axis(4).map(|a| a.state().homed), Some(true));
    }

    #[test]
    fn a_raised_error_stops_the_axis_and_shows_until_the_next_drive() {
        let mut e = KohzuScEmulator::new(4, &stage());
        exchange(&mut e, at(0), "FRP2/2/0/0/1/1");
        assert!(e.raise_error(2));
        assert_eq!(exchange(&mut e, at(100), "STR1/2"), "C\tSTR2\t1\t0\t1\t1\t0\t0\t0\t1\r\n");
        assert_eq!(position(&mut e, at(100), 2), 0, "stopped at once");
        assert_eq!(exchange(&mut e, at(100), "APS2/2/0/0/100/0/0/1"), "C\tAPS2\r\n");
        assert_eq!(exchange(&mut e, at(100), "STR1/2"), "C\tSTR2\t1\t1\t1\t1\t0\t0\t0\t0\r\n");
        assert!(!e.raise_error(0) && !e.raise_error(5));
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn errors_are_answered_with_their_numbers_and_counted() {
        let mut e = KohzuScEmulator::new(4, &stage());
        let cases = [
            ("XYZ1/0", "E\tXYZ1\t5"),
            ("APS1/2/0/0/100", "E\tAPS1\t100"),
            ("APS5/2/0/0/100/0/0/1", "E\tAPS5\t101"),
            ("APS1/10/0/0/100/0/0/1", "E\tAPS1\t102"),
            ("APS1/2/0/0/99999999999/0/0/1", "E\tAPS1\t105"),
            ("APS1/2/0/0/1--2/0/0/1", "E\tAPS1\t105"),
            ("APS1/2/0/0/100/0/0/2", "E\tAPS1\t108"),
            ("STR2/1", "E\tSTR2\t101"),
            ("STR1/0", "E\tSTR1\t102"),
            ("RDP1/", "E\tRDP1\t102"),
            ("ASI1/0/1000/10/10/0/0/0/0/0/0/0/0/0", "E\tASI1\t102"),
            ("WSY1/21/2", "E\tWSY1\t103"),
            ("IDN1", "E\tIDN1\t100"),
            ("rdp1/0", "E\trdp1\t4"),
            ("RDP1/+0", "E\tRDP1\t4"),
            ("ID", "E\tID\t2"),
        ];
        for (command, reply) in cases {
            assert_eq!(exchange(&mut e, at(0), command), format!("{reply}\r\n"), "{command}");
        }
        e.handle_input(at(0), b"RDP1/0\r\n");
        e.handle_input(at(0), b"\x02RDP1/0\n");
        assert_eq!(replies(&mut e), ["E\tRDP1\t1\r\n", "E\tRDP1\t3\r\n"]);
        assert_eq!(e.malformed(), cases.len() + 2);
        assert_eq!(position(&mut e, at(0), 1), 0, "nothing moved");
    }

    #[test]
    fn commands_come_whole_from_any_pieces_and_garbage_is_refused() {
        let mut e = KohzuScEmulator::new(4, &stage());
        e.handle_input(at(0), b"\x02RD");
        assert!(e.poll_transmit().is_none());
        e.handle_input(at(0), b"P1/0\r");
        assert!(e.poll_transmit().is_none());
        e.handle_input(at(0), b"\n\r\n\x02IDN\r\n\x02ST");
        e.handle_input(at(0), b"R1/1\r\n\xff\xfe\x02\r\n");
        assert_eq!(
            replies(&mut e),
            ["C\tRDP1\t0\r\n", "C\tIDN0\t400\t1000\r\n", "C\tSTR1\t1\t0\t1\t1\t0\t0\t0\t0\r\n", "E\t\t1\r\n"]
        );
        assert_eq!(e.malformed(), 1, "the garbage line");
        e.handle_input(at(0), &[b'A'; 300]);
        assert_eq!(e.malformed(), 2, "an overflowing input buffer counts");
        e.handle_input(at(0), b"\r\n\x02IDN\r\n");
        assert_eq!(replies(&mut e), ["C\tIDN0\t400\t1000\r\n"], "what the buffer held is lost");
    }
}
