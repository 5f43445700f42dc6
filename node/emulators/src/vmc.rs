//! Kevin Peterson's Virtual Motor Controller (VMC): the Python TCP server written for the motor
//! sessions of the APS EPICS Training 2015, driven by EPICS's motorVMC. Eight axes, one command a
//! line in ASCII (`1 MV 400`), every command answered.
//!
//! # Witnesses
//!
//! 1. The VMC itself, as epics-motor/motorVMC packages it (`python/server.py`, `controller.py`,
//!    `axis.py`, `status.py` and `README.md`, commit 9dcae57 of 18 March 2026: the asyncio server,
//!    `FBK?`, limits enforced, the HOMING bit fixed). The server is the vendor, so its code is
//!    the manual. It gave: TCP port 31337; a request ends at `\r` (the server reads up to `\r`
//!    and strips whitespace from both ends, so the `\n` of a `\r\n` is dropped with the next
//!    request; the README's "Input terminator: `\r\n`, Output terminator: `\r`" is the client's
//!    view and contradicts the code, which was followed); every reply ends `\r\n`; an empty
//!    request is not answered. A request is split at single spaces into `<axis> <command>`
//!    (queries and `AB`) or `<axis> <command> <argument>`; any other count is answered
//!    `Argument error`, an axis not among `1`–`8` or `X Y Z T U V R S` `Axis name error`, a
//!    command not among those of that count `Command error` (so `1 MV` and `1 BAS?` too), in
//!    that order, case sensitive. Commands: `MV n`, `MR n`, `POS n`, `LL n`, `HL n` (Python
//!    `int()`), `JOG v`, `VEL v`, `ACC a`, `BAS v` (Python `float()`); `POS?`, `FBK?`, `ST?`,
//!    `VEL?`, `ACC?`, `LL?`, `HL?`, `AB`. There is no `BAS?` (its handler exists but is not in the
//!    table), no home search, no identification, no help. Every setting and `AB` is answered
//!    `OK`; `MV`/`MR`/`JOG` are answered `Busy` while a motion is in progress, and the motion in
//!    progress only ends for them once `POS?` or `FBK?` has read its end. `POS?` is
//!    `int(round(position))` (half to even); `FBK?` is the position ×1.25 (0.8 step per encoder
//!    count) plus a jitter uniform in ±3, rounded likewise; `VEL?`/`ACC?` print Python's repr of
//!    the value (`400` at power-on, an integer; `400.0` once set, a float); `LL?`/`HL?` integers
//!    (±40 000 at power-on). VEL 400, ACC 400 (also the deceleration), BAS 0 at power-on. `VEL`
//!    keeps the magnitude. `JOG v` is a relative move of `v`×3600 counts at `VEL` (an hour-long
//!    move). A move is a trapezoid from `BAS` to `VEL` at `ACC`; `AB` decelerates at `ACC`. `POS`
//!    redefines the position, and is ignored (still `OK`) during a motion. `ST?` bits: 0x1
//!    direction of the last move commanded (+), 0x2 done, 0x4 moving, 0x8 high limit, 0x10 low
//!    limit, 0x20 homing, 0x40 home switch, 0x80 homed, 0x100 error; power-on: 3. The limit
//!    bits are computed at each `ST?` from the position last read by `POS?`/`FBK?` (`> HL`,
//!    `< LL`), and an axis moving towards an active limit is then stopped as by `AB`. A move
//!    commanded towards a limit active at the last `ST?` is answered `OK` but not made, and sets
//!    the error bit, which nothing clears. The homing, home and homed bits are never set. A
//!    Python exception ends the connection without a reply: an argument `int()`/`float()`
//!    refuses (`MV 1000.5`, `MV abc`), a move with `VEL 0` or `ACC 0` (a division by zero),
//!    bytes that are not UTF-8, a line longer than asyncio's 64 KiB limit.
//! 2. The VMC as first published (kmpeters/VirtualMotorController, commit f651e4a, 12 July 2018,
//!    code of February 2015): the same protocol on asynchat, without `FBK?`, with the limits not
//!    enforced and the HOMING bit computed as `1 >> 5` (0). The 2026 behaviour is emulated.
//! 3. The EPICS driver, motorVMC's `vmcDriver.cpp` (same commit as 1), read only for the bytes a
//!    client sends: `%d BAS %f`, `%d VEL %f`, `%d ACC %f` before `%d MV %d` / `%d MR %d` /
//!    `%d JOG %f`; `%d AB`; `%d POS %d`; then `%d POS?`, `%d FBK?`, `%d ST?` each poll; axes
//!    numbered from 1; output terminator `\r`, input `\r\n`; port 31337; home not implemented.
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Units**: one VMC count is one simulator step (the controller position is the sim's
//!   counter). `FBK?` counts are the VMC's own 1.25 per step, whatever the sim's encoder; the
//!   jitter comes from a fixed-seed generator (the VMC uses Python's `random`), so runs repeat.
//! - **Channels**: `channels` axes (1 to 8), numbered 1 to n and named by the first n of
//!   `X Y Z T U V R S`; an axis above n is answered `Axis name error` (the VMC always has 8).
//! - **A dropped connection**: the emulator cannot close a socket, so after an exception the
//!   connection goes deaf (no reply, input discarded, counted malformed once) until it is closed
//!   (`handle_closed`); `dropped(connection)` tells a runner to close it. The axis stays at rest
//!   after a division by zero (the VMC leaves it marked as moving with its last profile).
//! - **Several clients** share the controller, as on the VMC (asyncio serves any number); 16 at
//!   once here.
//! - **Motion**: the sim's trapezoid (from `BAS`, ramping at `ACC`) stands for the VMC's, whose
//!   short-move peak ignores the base speed; `ACC < 0` moves at `VEL` without a ramp (the VMC
//!   computes a meaningless profile). Settings apply from the next motion. The sim's own limit
//!   switches (the mechanics') also stop an axis and show in the limit bits, besides `LL`/`HL`.
//! - **Numbers**: arguments in ASCII (Python also takes other Unicode digits), underscores
//!   between digits allowed as in Python; integers beyond 38 digits are refused as Python's
//!   `int()` refuses a bad one (Python takes any size). A non-finite float (`inf`, `nan`) is
//!   answered `OK` and ignored, counted malformed (the VMC takes it and misbehaves later).
//! - **Errors**: `raise_error` sets the error bit (0x100), as a move refused at a limit does.

use crate::emulator::axes;
use crate::{Connection, Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

/// Axes of the VMC.
const MAX_AXES: usize = 8;
/// Axis names, in axis order (numbers `1`–`8` name them too).
const AXIS_NAMES: [&str; MAX_AXES] = ["X", "Y", "Z", "T", "U", "V", "R", "S"];
/// Clients served at once.
const CONNECTIONS: usize = 16;
/// asyncio's `StreamReader` limit: a longer line raises and ends the connection.
const LINE_LIMIT: usize = 65_536;
/// The request terminator.
const CR: &[u8] = b"\r";
/// The reply terminator.
const CRLF: &str = "\r\n";
/// Encoder counts per step (the VMC's 0.8 EGU per count, 1 EGU per step).
const ENCODER_PER_STEP: f64 = 1.25;
/// `FBK?` jitter, counts peak to peak.
const ENCODER_JITTER: f64 = 6.0;
/// `JOG v` is a move of `v` × this many seconds.
const JOG_SECONDS: f64 = 3600.0;

const OK: &str = "OK";
const BUSY: &str = "Busy";
const ARGUMENT_ERROR: &str = "Argument error";
const AXIS_NAME_ERROR: &str = "Axis name error";
const COMMAND_ERROR: &str = "Command error";

/// `ST?` bits.
const DIRECTION: u32 = 1 << 0;
const DONE_MOVING: u32 = 1 << 1;
const MOVING: u32 = 1 << 2;
const HIGH_LIMIT: u32 = 1 << 3;
const LOW_LIMIT: u32 = 1 << 4;
const ERROR: u32 = 1 << 8;

/// A speed or acceleration as Python holds it: the power-on integer, or the float set since.
#[derive(Clone, Copy, Debug)]
struct Number {
    value: f64,
    float: bool,
}

impl Number {
    fn int(value: i32) -> Self {
        Self { value: f64::from(value), float: false }
    }

    fn float(value: f64) -> Self {
        Self { value, float: true }
    }

    /// As Python's `str()` prints it.
    fn text(self) -> String {
        if self.float {
            py_repr(self.value)
        } else {
            format!("{}", self.value)
        }
    }
}

/// What one request comes to.
enum Outcome {
    Reply(String),
    /// An empty request: no reply.
    Silent,
    /// A Python exception: the connection ends.
    Drop,
}

fn reply(text: &str) -> Outcome {
    Outcome::Reply(text.to_string())
}

/// One axis: its settings, its state as the VMC keeps it, and the carriage behind it.
#[derive(Debug)]
struct Axis {
    sim: SimAxis,
    velocity: Number,
    acceleration: Number,
    base: f64,
    low_limit: i128,
    high_limit: i128,
    /// A motion was started and its end not yet read by `POS?`/`FBK?` (the VMC's moveStartTime).
    pending: bool,
    /// The position last read or set (the VMC's currentPosition), counts.
    reported: f64,
    direction_positive: bool,
    /// The limit bits as of the last `ST?`.
    high_active: bool,
    low_active: bool,
    error: bool,
}

impl Axis {
    fn new(sim: SimAxis) -> Self {
        let reported = sim.status().position;
        Self {
            sim,
            velocity: Number::int(400),
            acceleration: Number::int(400),
            base: 0.0,
            low_limit: -40_000,
            high_limit: 40_000,
            pending: false,
            reported,
            direction_positive: true,
            high_active: false,
            low_active: false,
            error: false,
        }
    }

    /// The controller position, counts.
    fn position(&self) -> f64 {
        self.sim.status().position
    }

    fn busy(&self) -> bool {
        self.pending || self.sim.is_moving()
    }

    /// A move to `target` counts (`MV`, `MR`, `JOG`).
    fn start(&mut self, target: f64) -> Outcome {
        if self.busy() {
            return reply(BUSY);
        }
        self.direction_positive = target >= self.position();
        if (self.direction_positive && self.high_active) || (!self.direction_positive && self.low_active) {
            self.error = true;
            return reply(OK);
        }
        if self.acceleration.value == 0.0 || self.velocity.value == 0.0 {
            // ZeroDivisionError in the VMC's profile.
            return Outcome::Drop;
        }
        self.pending = true;
        self.sim.move_to(target, false, self.base, self.velocity.value, self.acceleration.value);
        reply(OK)
    }

    /// `POS?`/`FBK?` read the position: a finished motion ends for good.
    fn read_position(&mut self) -> f64 {
        if !self.sim.is_moving() {
            self.pending = false;
        }
        self.reported = self.position();
        self.reported
    }

    /// `ST?`: the status word; an axis running into an active limit is stopped.
    fn read_status(&mut self) -> u32 {
        let moving = self.sim.is_moving();
        let switches = self.sim.state();
        self.high_active = self.reported > self.high_limit as f64 || switches.high_limit;
        self.low_active = self.reported < self.low_limit as f64 || switches.low_limit;
        let towards_limit = if self.direction_positive { self.high_active } else { self.low_active };
        if moving && towards_limit {
            self.sim.stop(self.acceleration.value);
        }
        [
            (self.direction_positive, DIRECTION),
            (!moving, DONE_MOVING),
            (moving, MOVING),
            (self.high_active, HIGH_LIMIT),
            (self.low_active, LOW_LIMIT),
            (self.error, ERROR),
        ]
        .iter()
        .filter(|(on, _)| *on)
        .fold(0, |bits, (_, bit)| bits | bit)
    }
}

/// One client's connection.
#[derive(Debug)]
struct Link {
    lines: Lines,
    /// The VMC raised an exception and closed it.
    dropped: bool,
}

impl Link {
    fn new() -> Self {
        Self { lines: Lines::new(CR, LINE_LIMIT), dropped: false }
    }
}

/// The Virtual Motor Controller, emulated: axes 1 to n, any of 16 clients at once.
#[derive(Debug)]
pub struct VmcEmulator {
    axes: Vec<Axis>,
    links: Vec<Link>,
    output: VecDeque<(Connection, Vec<u8>)>,
    malformed: usize,
    /// xorshift64 state for the `FBK?` jitter.
    noise: u64,
}

impl VmcEmulator {
    /// A VMC with `channels` axes (one at least, eight at most), numbered 1 to `channels` and
    /// named `X`, `Y`, `Z`, `T`, `U`, `V`, `R`, `S` in that order.
    pub fn new(channels: usize, mechanics: &SimConfig) -> Self {
        let channels = channels.clamp(1, MAX_AXES);
        Self {
            axes: axes(channels, mechanics).into_iter().map(Axis::new).collect(),
            links: Vec::new(),
            output: VecDeque::new(),
            malformed: 0,
            noise: 0x2545_f491_4f6c_dd1d,
        }
    }

    /// The VMC closed `connection` (an exception in the server): the runner should close it.
    pub fn dropped(&self, connection: Connection) -> bool {
        self.links.get(connection).is_some_and(|link| link.dropped)
    }

    fn axis_index(&self, name: &str) -> Option<usize> {
        let by_name = AXIS_NAMES.iter().position(|n| *n == name);
        let by_number = (1..=MAX_AXES).position(|n| n.to_string() == name);
        by_name.or(by_number).filter(|&i| i < self.axes.len())
    }

    /// A uniform number in [0, 1), as Python's `random.random()`.
    fn random(&mut self) -> f64 {
        self.noise ^= self.noise << 13;
        self.noise ^= self.noise >> 7;
        self.noise ^= self.noise << 17;
        (self.noise >> 11) as f64 / (1u64 << 53) as f64
    }

    /// One request, stripped and not empty.
    fn execute(&mut self, request: &str) -> Outcome {
        let args: Vec<&str> = request.split(' ').collect();
        if !(2..=3).contains(&args.len()) {
            self.malformed += 1;
            return reply(ARGUMENT_ERROR);
        }
        let Some(index) = self.axis_index(args[0]) else {
            self.malformed += 1;
            return reply(AXIS_NAME_ERROR);
        };
        let outcome = match (args[1], args.get(2)) {
            (command, None) => self.query(index, command),
            (command, Some(argument)) => self.command(index, command, argument),
        };
        match outcome {
            Some(Outcome::Drop) => {
                self.malformed += 1;
                Outcome::Drop
            }
            Some(outcome) => outcome,
            None => {
                self.malformed += 1;
                reply(COMMAND_ERROR)
            }
        }
    }

    /// A command without argument; None when there is no such command.
    fn query(&mut self, index: usize, command: &str) -> Option<Outcome> {
        let text = match command {
            "POS?" => counts(self.axes[index].read_position()),
            "FBK?" => {
                let position = self.axes[index].read_position();
                let jitter = (self.random() - 0.5) * ENCODER_JITTER;
                counts(position * ENCODER_PER_STEP + jitter)
            }
            "ST?" => self.axes[index].read_status().to_string(),
            "VEL?" => self.axes[index].velocity.text(),
            "ACC?" => self.axes[index].acceleration.text(),
            "LL?" => self.axes[index].low_limit.to_string(),
            "HL?" => self.axes[index].high_limit.to_string(),
            "AB" => {
                let axis = &mut self.axes[index];
                if axis.pending {
                    axis.sim.stop(axis.acceleration.value);
                }
                OK.to_string()
            }
            _ => return None,
        };
        Some(Outcome::Reply(text))
    }

    /// A command with its argument; None when there is no such command.
    fn command(&mut self, index: usize, command: &str, argument: &str) -> Option<Outcome> {
        let axis = &mut self.axes[index];
        let outcome = match command {
            "MV" | "MR" | "POS" | "LL" | "HL" => {
                let Some(n) = py_int(argument) else { return Some(Outcome::Drop) };
                let n_counts = n as f64;
                match command {
                    "MV" => axis.start(n_counts),
                    "MR" => {
                        let here = axis.position();
                        axis.start(here + n_counts)
                    }
                    "POS" => {
                        if !axis.busy() {
                            axis.sim.set_position(n_counts);
                            axis.reported = n_counts;
                        }
                        reply(OK)
                    }
                    "LL" => {
                        axis.low_limit = n;
                        reply(OK)
                    }
                    _ => {
                        axis.high_limit = n;
                        reply(OK)
                    }
                }
            }
            "JOG" | "VEL" | "ACC" | "BAS" => {
                let Some(x) = py_float(argument) else { return Some(Outcome::Drop) };
                if !x.is_finite() {
                    self.malformed += 1;
                    return Some(reply(OK));
                }
                match command {
                    "JOG" => {
                        let here = axis.position();
                        axis.start(here + x * JOG_SECONDS)
                    }
                    "VEL" => {
                        axis.velocity = Number::float(x.abs());
                        reply(OK)
                    }
                    "ACC" => {
                        axis.acceleration = Number::float(x);
                        reply(OK)
                    }
                    _ => {
                        axis.base = x;
                        reply(OK)
                    }
                }
            }
            _ => return None,
        };
        Some(outcome)
    }
}

/// Python's `int(round(x))`: half to even.
fn counts(x: f64) -> String {
    format!("{}", x.round_ties_even() as i128)
}

/// Python's whitespace, as `str.strip()` and `int()` see it (ASCII and Unicode).
fn py_space(c: char) -> bool {
    c.is_whitespace() || ('\u{1c}'..='\u{1f}').contains(&c)
}

/// The text without the underscores Python allows between digits; None if one is misplaced.
fn without_underscores(text: &str) -> Option<String> {
    let bytes = text.as_bytes();
    for (i, &b) in bytes.iter().enumerate() {
        if b == b'_' {
            let before = i.checked_sub(1).and_then(|j| bytes.get(j)).is_some_and(u8::is_ascii_digit);
            let after = bytes.get(i + 1).is_some_and(u8::is_ascii_digit);
            if !(before && after) {
                return None;
            }
        }
    }
    Some(text.replace('_', ""))
}

/// Python's `int(text)` for ASCII decimals: None where it raises ValueError.
fn py_int(text: &str) -> Option<i128> {
    let text = without_underscores(text.trim_matches(py_space))?;
    let digits = text.strip_prefix(['+', '-']).unwrap_or(&text);
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    text.strip_prefix('+').unwrap_or(&text).parse().ok()
}

/// Python's `float(text)` for ASCII: None where it raises ValueError.
fn py_float(text: &str) -> Option<f64> {
    let text = without_underscores(text.trim_matches(py_space))?;
    let allowed = |c: char| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.');
    if !text.chars().all(allowed) {
        return None;
    }
    text.parse().ok()
}

/// Python's `repr()` of a float: the shortest digits, exponent form below 1e-4 and from 1e16.
fn py_repr(x: f64) -> String {
    if x.is_nan() {
        return "nan".into();
    }
    let sign = if x.is_sign_negative() { "-" } else { "" };
    if x.is_infinite() {
        return format!("{sign}inf");
    }
    if x == 0.0 {
        return format!("{sign}0.0");
    }
    let scientific = format!("{:e}", x.abs());
    let (mantissa, exponent) = scientific.split_once('e').unwrap_or((&scientific, "0"));
    let exponent: i32 = exponent.parse().unwrap_or(0);
    let digits: String = mantissa.chars().filter(char::is_ascii_digit).collect();
    if (-4..16).contains(&exponent) {
        if exponent >= 0 {
            let whole = exponent as usize + 1;
            if digits.len() <= whole {
                format!("{sign}{digits}{}.0", "0".repeat(whole - digits.len()))
            } else {
                format!("{sign}{}.{}", &digits[..whole], &digits[whole..])
            }
        } else {
            format!("{sign}0.{}{digits}", "0".repeat((-exponent - 1) as usize))
        }
    } else {
        let (first, rest) = digits.split_at(1);
        let point = if rest.is_empty() { String::new() } else { format!(".{rest}") };
        let exponent_sign = if exponent < 0 { '-' } else { '+' };
        format!("{sign}{first}{point}e{exponent_sign}{:02}", exponent.abs())
    }
}

impl Emulator for VmcEmulator {
    fn name(&self) -> &'static str {
        "vmc"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        self.handle_input_on(now, 0, bytes);
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        let i = self.output.iter().position(|(connection, _)| *connection == 0)?;
        self.output.remove(i).map(|(_, bytes)| bytes)
    }

    fn malformed(&self) -> usize {
        self.malformed
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.axes.get_mut(channel.checked_sub(1)?).map(|axis| &mut axis.sim)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(axis) = channel.checked_sub(1).and_then(|i| self.axes.get_mut(i)) else { return false };
        axis.error = true;
        true
    }

    fn connections(&self) -> usize {
        CONNECTIONS
    }

    fn handle_input_on(&mut self, now: Instant, connection: Connection, bytes: &[u8]) {
        if connection >= CONNECTIONS {
            return;
        }
        for axis in &mut self.axes {
            axis.sim.advance(now);
        }
        while self.links.len() <= connection {
            self.links.push(Link::new());
        }
        if self.links[connection].dropped {
            return;
        }
        let link = &mut self.links[connection];
        let overflowed = link.lines.overflowed();
        let lines = link.lines.push(bytes);
        let overflow = link.lines.overflowed() > overflowed;
        for line in lines {
            let text = std::str::from_utf8(&line).ok().filter(|_| line.len() <= LINE_LIMIT);
            let outcome = match text.map(|t| t.trim_matches(py_space)) {
                None => {
                    self.malformed += 1;
                    Outcome::Drop
                }
                Some("") => Outcome::Silent,
                Some(request) => self.execute(request),
            };
            match outcome {
                Outcome::Reply(text) => self.output.push_back((connection, format!("{text}{CRLF}").into_bytes())),
                Outcome::Silent => {}
                Outcome::Drop => {
                    self.links[connection].dropped = true;
                    return;
                }
            }
        }
        if overflow {
            self.malformed += 1;
            self.links[connection].dropped = true;
        }
    }

    fn poll_transmit_on(&mut self) -> Option<(Connection, Vec<u8>)> {
        self.output.pop_front()
    }

    fn handle_closed(&mut self, connection: Connection) {
        self.output.retain(|(c, _)| *c != connection);
        if let Some(link) = self.links.get_mut(connection) {
            *link = Link::new();
        }
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

    /// Every reply on connection 0 to `line` sent with `\r`.
    fn replies(e: &mut VmcEmulator, now: Instant, line: &str) -> Vec<String> {
        e.handle_input(now, format!("{line}\r").as_bytes());
        std::iter::from_fn(|| e.poll_transmit()).map(|r| String::from_utf8(r).expect("ASCII")).collect()
    }

    fn exchange(e: &mut VmcEmulator, now: Instant, line: &str) -> String {
        let mut all = replies(e, now, line);
        assert_eq!(all.len(), 1, "one reply to {line:?}: {all:?}");
        all.remove(0)
    }

    #[test]
    fn power_on_replies_and_number_formats() {
        let mut e = VmcEmulator::new(8, &stage());
        for (line, expected) in [
            ("1 ST?", "3"),
            ("1 POS?", "0"),
            ("X POS?", "0"),
            ("S ST?", "3"),
            ("1 VEL?", "400"),
            ("1 ACC?", "400"),
            ("1 LL?", "-40000"),
            ("1 HL?", "40000"),
            ("1 AB", "OK"),
            ("1 BAS 10", "OK"),
            ("1 VEL 400.000000", "OK"),
            ("1 VEL?", "400.0"),
            ("2 VEL -250.5", "OK"),
            ("2 VEL?", "250.5"),
            ("1 ACC 1e3", "OK"),
            ("1 ACC?", "1000.0"),
            ("2 ACC 1e20", "OK"),
            ("2 ACC?", "1e+20"),
            ("3 ACC 0.00001", "OK"),
            ("3 ACC?", "1e-05"),
            ("3 VEL 1_000", "OK"),
            ("3 VEL?", "1000.0"),
            ("1 LL -5", "OK"),
            ("1 LL?", "-5"),
            ("1 HL 0012", "OK"),
            ("1 HL?", "12"),
        ] {
            assert_eq!(exchange(&mut e, at(0), line), format!("{expected}\r\n"), "{line}");
        }
        assert_eq!(e.malformed(), 0);
        assert_eq!(exchange(&mut e, at(0), "4 VEL inf"), "OK\r\n", "taken but ignored");
        assert_eq!(exchange(&mut e, at(0), "4 VEL?"), "400\r\n");
        assert_eq!(e.malformed(), 1);
        assert_eq!(e.name(), "vmc");
    }

    #[test]
    fn a_move_is_busy_until_its_end_is_read() {
        let mut e = VmcEmulator::new(2, &stage());
        assert_eq!(exchange(&mut e, at(0), "1 MV 1000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(1000), "1 POS?"), "200\r\n", "one second of ramp at 400/s²");
        assert_eq!(exchange(&mut e, at(1000), "1 ST?"), "5\r\n", "moving, positive");
        assert_eq!(exchange(&mut e, at(1000), "1 MR 5"), "Busy\r\n");
        assert_eq!(exchange(&mut e, at(4000), "1 ST?"), "3\r\n", "done");
        assert_eq!(exchange(&mut e, at(4000), "1 MV 0"), "Busy\r\n", "its end not read yet");
        assert_eq!(exchange(&mut e, at(4000), "1 POS?"), "1000\r\n");
        assert_eq!(exchange(&mut e, at(4000), "1 MV 0"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(4000), "1 ST?"), "4\r\n", "moving, negative");
        assert_eq!(exchange(&mut e, at(8000), "1 POS?"), "0\r\n");
        assert_eq!(exchange(&mut e, at(8000), "1 MR 250"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(12_000), "1 POS?"), "250\r\n");
        assert_eq!(exchange(&mut e, at(12_000), "1 ST?"), "3\r\n");
        assert_eq!(exchange(&mut e, at(12_000), "2 POS?"), "0\r\n", "the other axis stayed");
    }

    #[test]
    fn positions_are_redefined_only_at_rest() {
        let mut e = VmcEmulator::new(1, &stage());
        assert_eq!(exchange(&mut e, at(0), "1 POS 5000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(0), "1 POS?"), "5000\r\n");
        assert_eq!(e.axis(1).expect("axis 1").physical_position(), 0.0, "the carriage did not move");
        assert_eq!(exchange(&mut e, at(0), "1 MV 6000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(500), "1 POS 7"), "OK\r\n", "ignored while moving");
        assert_eq!(exchange(&mut e, at(10_000), "1 POS?"), "6000\r\n");
        assert_eq!(e.axis(1).expect("axis 1").physical_position(), 1000.0);
    }

    #[test]
    fn a_jog_runs_until_aborted() {
        let mut e = VmcEmulator::new(1, &stage());
        assert_eq!(exchange(&mut e, at(0), "1 JOG 400.000000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(2000), "1 ST?"), "5\r\n");
        assert_eq!(exchange(&mut e, at(2000), "1 AB"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(2500), "1 ST?"), "5\r\n", "decelerating at ACC");
        assert_eq!(exchange(&mut e, at(3500), "1 ST?"), "3\r\n");
        assert_eq!(exchange(&mut e, at(3500), "1 POS?"), "800\r\n", "200 ramping, 400 at speed, 200 braking");
        assert_eq!(exchange(&mut e, at(3500), "1 JOG -10"), "OK\r\n", "at VEL, not at the jog's speed");
        assert_eq!(exchange(&mut e, at(4500), "1 POS?"), "600\r\n");
        assert_eq!(exchange(&mut e, at(4500), "1 ST?"), "4\r\n");
    }

    #[test]
    fn limits_stop_an_axis_at_the_status_poll_and_refuse_moves_into_them() {
        let mut e = VmcEmulator::new(1, &stage());
        assert_eq!(exchange(&mut e, at(0), "1 HL 500"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(0), "1 MV 2000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(2000), "1 ST?"), "5\r\n", "the position is not read yet");
        assert_eq!(exchange(&mut e, at(2000), "1 POS?"), "600\r\n");
        assert_eq!(exchange(&mut e, at(2000), "1 ST?"), "13\r\n", "high limit: stopping");
        assert_eq!(exchange(&mut e, at(3500), "1 POS?"), "800\r\n");
        assert_eq!(exchange(&mut e, at(3500), "1 ST?"), "11\r\n");
        assert_eq!(exchange(&mut e, at(3500), "1 MV 3000"), "OK\r\n", "answered, not made");
        assert_eq!(exchange(&mut e, at(3500), "1 ST?"), "267\r\n", "the error bit");
        assert_eq!(exchange(&mut e, at(3500), "1 MV 0"), "OK\r\n", "away from the limit");
        assert_eq!(exchange(&mut e, at(3500), "1 ST?"), "268\r\n");
        assert_eq!(exchange(&mut e, at(10_000), "1 POS?"), "0\r\n");
        assert_eq!(exchange(&mut e, at(10_000), "1 ST?"), "258\r\n", "the error stays");

        let mut e = VmcEmulator::new(1, &stage());
        exchange(&mut e, at(0), "1 LL -100");
        exchange(&mut e, at(0), "1 JOG -400");
        assert_eq!(exchange(&mut e, at(1000), "1 POS?"), "-200\r\n");
        assert_eq!(exchange(&mut e, at(1000), "1 ST?"), "20\r\n", "low limit: stopping");
        assert_eq!(exchange(&mut e, at(2500), "1 POS?"), "-400\r\n");
        assert_eq!(exchange(&mut e, at(2500), "1 ST?"), "18\r\n");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn the_mechanics_limit_switches_stop_it_too() {
        let mut e = VmcEmulator::new(1, &stage());
        for line in ["1 HL 1000000", "1 VEL 100000", "1 ACC 100000", "1 MV 300000"] {
            assert_eq!(exchange(&mut e, at(0), line), "OK\r\n");
        }
        assert_eq!(exchange(&mut e, at(5000), "1 POS?"), "200000\r\n");
        assert_eq!(exchange(&mut e, at(5000), "1 ST?"), "11\r\n");
        assert_eq!(exchange(&mut e, at(5000), "1 MV 400000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(5000), "1 ST?"), "267\r\n", "refused");
    }

    #[test]
    fn errors_are_answered_in_the_vmcs_order() {
        let mut e = VmcEmulator::new(3, &stage());
        let cases = [
            ("1", ARGUMENT_ERROR),
            ("1 POS? 1 2", ARGUMENT_ERROR),
            ("1\tPOS?", ARGUMENT_ERROR),
            ("9 POS?", AXIS_NAME_ERROR),
            ("x POS?", AXIS_NAME_ERROR),
            ("4 POS?", AXIS_NAME_ERROR),
            ("T POS?", AXIS_NAME_ERROR),
            ("9 FOO", AXIS_NAME_ERROR),
            ("1 MV", COMMAND_ERROR),
            ("1 BAS?", COMMAND_ERROR),
            ("1 HOMF", COMMAND_ERROR),
            ("1 EN", COMMAND_ERROR),
            ("1 mv 5", COMMAND_ERROR),
            ("1  POS?", COMMAND_ERROR),
            ("1 POS? 5", COMMAND_ERROR),
        ];
        for (line, error) in cases {
            assert_eq!(exchange(&mut e, at(0), line), format!("{error}\r\n"), "{line}");
        }
        assert_eq!(e.malformed(), cases.len());
        assert_eq!(exchange(&mut e, at(0), "Z ST?"), "3\r\n");
        assert!(e.raise_error(2));
        assert_eq!(exchange(&mut e, at(0), "2 ST?"), "259\r\n");
        assert_eq!(exchange(&mut e, at(0), "Y ST?"), "259\r\n");
        assert!(!e.raise_error(0) && !e.raise_error(4));
        assert!(e.axis(0).is_none() && e.axis(3).is_some() && e.axis(4).is_none());
        assert_eq!(VmcEmulator::new(20, &stage()).axes.len(), 8);
        assert_eq!(VmcEmulator::new(0, &stage()).axes.len(), 1);
    }

    #[test]
    fn an_exception_ends_the_connection_until_it_is_closed() {
        for line in ["1 MV 1000.5", "1 MV abc", "1 POS 1e3", "1 VEL fast", "1 LL 1__0", "1 MR 1_"] {
            let mut e = VmcEmulator::new(2, &stage());
            assert!(replies(&mut e, at(0), line).is_empty(), "{line}");
            assert!(e.dropped(0), "{line}");
            assert!(replies(&mut e, at(0), "1 POS?").is_empty(), "deaf");
            assert_eq!(e.malformed(), 1);
            assert!(!e.axis(1).expect("axis 1").is_moving());
            e.handle_input_on(at(0), 1, b"2 ST?\r");
            assert_eq!(e.poll_transmit_on(), Some((1, b"3\r\n".to_vec())), "other clients go on");
            e.handle_closed(0);
            assert!(!e.dropped(0));
            assert_eq!(exchange(&mut e, at(0), "1 POS?"), "0\r\n");
        }
        let mut e = VmcEmulator::new(1, &stage());
        assert_eq!(exchange(&mut e, at(0), "1 VEL 0"), "OK\r\n");
        assert!(replies(&mut e, at(0), "1 MV 10").is_empty(), "a division by zero");
        assert!(e.dropped(0));
        let mut e = VmcEmulator::new(1, &stage());
        e.handle_input(at(0), b"1 ST?\r\xff\r1 ST?\r");
        let got: Vec<Vec<u8>> = std::iter::from_fn(|| e.poll_transmit()).collect();
        assert_eq!(got, [b"3\r\n".to_vec()], "not UTF-8: the rest is lost");
        assert!(e.dropped(0));
        let mut e = VmcEmulator::new(1, &stage());
        e.handle_input(at(0), &vec![b'1'; LINE_LIMIT + 1]);
        assert!(e.dropped(0) && e.malformed() == 1, "asyncio's limit");
    }

    #[test]
    fn requests_come_whole_from_any_pieces_and_either_terminator() {
        let mut e = VmcEmulator::new(1, &stage());
        e.handle_input(at(0), b"1 PO");
        assert!(e.poll_transmit().is_none());
        e.handle_input(at(0), b"S?\r\n1 S");
        e.handle_input(at(0), b"T?\r\n\r\r \t\r  1 VEL?  \r");
        let got: Vec<Vec<u8>> = std::iter::from_fn(|| e.poll_transmit()).collect();
        assert_eq!(got, [b"0\r\n".to_vec(), b"3\r\n".to_vec(), b"400\r\n".to_vec()]);
        assert_eq!(e.malformed(), 0, "empty requests are not answered");
        e.handle_input(at(0), b"1 POS?\n1 ST?\r");
        assert_eq!(e.poll_transmit(), Some(b"Command error\r\n".to_vec()), "a line feed does not end one");
    }

    #[test]
    fn clients_are_answered_on_their_own_connection() {
        let mut e = VmcEmulator::new(2, &stage());
        e.handle_input_on(at(0), 2, b"2 MV 100\r");
        e.handle_input_on(at(0), 0, b"2 ST?\r");
        assert_eq!(e.poll_transmit(), Some(b"5\r\n".to_vec()), "one controller shared");
        assert_eq!(e.poll_transmit(), None);
        assert_eq!(e.poll_transmit_on(), Some((2, b"OK\r\n".to_vec())));
        e.handle_input_on(at(0), CONNECTIONS, b"1 ST?\r");
        assert_eq!(e.poll_transmit_on(), None);
        assert_eq!(e.connections(), CONNECTIONS);
    }

    #[test]
    fn the_encoder_reads_five_counts_for_four_steps_with_jitter() {
        let mut e = VmcEmulator::new(1, &stage());
        let read = |e: &mut VmcEmulator| -> i64 { exchange(e, at(0), "1 FBK?").trim().parse().expect("integer") };
        let at_zero: Vec<i64> = (0..20).map(|_| read(&mut e)).collect();
        assert!(at_zero.iter().all(|n| (-3..=3).contains(n)), "{at_zero:?}");
        assert!(at_zero.iter().any(|n| *n != at_zero[0]), "jitter");
        exchange(&mut e, at(0), "1 POS 8000");
        let far = read(&mut e);
        assert!((9997..=10_003).contains(&far), "{far}");
        let mut again = VmcEmulator::new(1, &stage());
        assert_eq!((0..20).map(|_| read(&mut again)).collect::<Vec<_>>(), at_zero, "repeatable");
    }

    #[test]
    fn numbers_as_python_reads_and_prints_them() {
        assert_eq!(py_int(" +1_000 "), Some(1000));
        assert_eq!(py_int("-007"), Some(-7));
        for bad in ["", "-", "1.0", "1e3", "_1", "1_", "0x10", "１"] {
            assert_eq!(py_int(bad), None, "{bad}");
        }
        assert_eq!(py_float("1."), Some(1.0));
        assert_eq!(py_float(".5"), Some(0.5));
        assert_eq!(py_float("-1E-3"), Some(-0.001));
        assert_eq!(py_float("Infinity"), Some(f64::INFINITY));
        assert_eq!(py_float("1,5"), None);
        for (x, text) in [
            (0.1, "0.1"),
            (-2.5, "-2.5"),
            (0.0, "0.0"),
            (1e15, "1000000000000000.0"),
            (1e16, "1e+16"),
            (1.2345678901234568e17, "1.2345678901234568e+17"),
            (0.0001, "0.0001"),
            (1.5e-7, "1.5e-07"),
            (1e300, "1e+300"),
            (f64::INFINITY, "inf"),
        ] {
            assert_eq!(py_repr(x), text);
        }
        assert_eq!([counts(2.5), counts(3.5), counts(-2.5), counts(-0.4)], ["2", "4", "-2", "0"]);
    }
}
