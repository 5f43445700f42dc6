//! The attocube AMC100 (and AMC300) piezo positioner controller: three axes, reached over TCP
//! port 9090 by JSON-RPC 2.0, one request object at a time (`{"jsonrpc": "2.0", "method":
//! "com.attocube.amc.move.getPosition", "params": [0], "id": 1, "api": 2}`), each answered by
//! one object whose `result` array begins with the error number (`[0, 1234.5]`).
//!
//! # Witnesses
//!
//! 1. attocube systems AG, "Interface Manual AMC100 & AMC300", modified 06/2024, written for
//!    firmware/API 1.4.0 (`AMC300.b_Interface_Manual_v1.4.0.pdf` in attocube-systems/AMC-APIs).
//!    It gives port 9090; the request and response forms (§2.2.1); and, for every function, its
//!    JSON method name, `params` and `Result`: positions and targets in nm as doubles, the
//!    target range in nm, the frequency in mHz, the amplitude in mV, `setNSteps(axis,
//!    backward, step)`, `setControlContinuousFwd/Bkwd(axis, enable)` (false "stops all
//!    movement of the axis regardless its direction"), `moveReference` ("a running motion
//!    command is aborted; closed loop moving is switched on. Requires a valid reference
//!    position"), `setReset` (position to zero, reference invalid), `getStatusMoving` (0 idle,
//!    1 moving, 2 pending: driving with the output off), `getOlStatus` (0: NUM positioner),
//!    the device type ("AMC100/NUM/PRO"), the maximum target 2^47/1000 nm, positive error
//!    numbers for device errors translated by `com.attocube.system.errorNumberToString`
//!    (language 0: the error's name, 1: a message).
//! 2. attocube's Python API in the same repository (`ACS.py`, `status.py`, `control.py`; 2021
//!    to 2024, and `amc_api_python` for firmware 1.5.x): the client writes `json.dumps(req)`
//!    with no terminator and reads the answer with `readline()` on a socket file opened with
//!    `newline='\r\n'`, so every answer ends with `\r\n`; `params` is left out when empty; an
//!    answer may carry a JSON-RPC `error` member instead of `result`. Its `getFullCombinedStatus`
//!    lists the strings "positioner not connected", "output not enabled", "ready", "moving",
//!    "in target range", "backward limit reached", "forward limit reached", "grounded",
//!    "overtemperature", "output error" (the last from firmware 1.5.0 on). Its example
//!    (`python.example.py`) switches the output on before moving, then sets targets with closed
//!    loop on and waits for `getStatusTargetRange`.
//! 3. attocube's C library (`attocubeJSONCall.c`, 2020) sends `cJSON_Print` output: the request
//!    pretty-printed over several lines, booleans as `true`/`false`; it accepts a `result` or
//!    an `error` member. attocube's MATLAB API (firmware 1.5.1) sends booleans as `0`/`1`
//!    (`%i`), doubles with `%d` (an exponent form), a `"pid": "amc"` member, and ends each
//!    request with a line feed (`writeline`); its `control_getOutputHealthStatus` gives the
//!    short-circuit code 73 `HW_SHORT_DETECTED` ("Unspecific short circuit detected on the
//!    drive pins. Axis disabled").
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Framing.** A request is one balanced JSON value (braces and brackets counted outside
//!   strings), arriving in any pieces, several in one read, with whitespace (the MATLAB line
//!   feed, PuTTY's `\r\n`) between them ignored. Bytes outside a value, up to the next `{` or
//!   `[`, are one malformed piece. More than 8 KiB without a complete value overflow the input
//!   buffer. Answers are compact (`{"jsonrpc":"2.0","result":[0,1.5],"id":7}`) then `\r\n`,
//!   members in the manual's order; the id is echoed as sent.
//! - **Errors.** JSON-RPC 2.0's own: `-32700 Parse error` (id null) for bytes that are not
//!   JSON, `-32600 Invalid Request` for a value that is not an object with `"jsonrpc": "2.0"`,
//!   a string `method` and, if present, an array `params` (a batch too), `-32601 Method not
//!   found`, `-32602 Invalid params` for a wrong count or type, an axis the controller does not
//!   have, or a value out of range; an `id` that is not a string, number or null makes an
//!   invalid request. All count as malformed. A request without an `id` is a notification:
//!   carried out, never answered. Device refusals are `result: [errNo]`: `moveReference`
//!   without a valid reference gives 2 (`ERROR_NO_REFERENCE`, a number of this emulator's
//!   choosing); enabling an axis with a short detected gives 73. `api` is ignored.
//! - **Axes** are 0, 1 and 2 (channel n is axis n); `new` keeps 1 to 3 of them. Every axis has
//!   a linear NUM positioner "ANPx101" connected. Firmware "1.5.1", device type
//!   "AMC100/NUM/PRO", device name "AMC100", serial number "AMC100-EMU-0001".
//! - **Units.** One nanometre is one simulator step; one open-loop step (`setNSteps`,
//!   `setSingleStep`) moves one nanometre. Every motion runs at a constant speed of one step
//!   per actuator period: the frequency in Hz, in nm/s (power-on 1 000 Hz, allowed 1 mHz to
//!   5 kHz), starting and stopping at once. Positions are read to the picometre.
//! - **Power-on**: outputs off, closed loop off, target 0, target range 100 nm, amplitude
//!   45 000 mV, reference invalid, auto reset off, reference auto update on.
//! - **Closed loop.** With `setControlMove(true)` and the output on the axis drives to the target
//!   and keeps driving (status "moving") until within the target range; a new target is
//!   followed at once. `setControlMove(false)` stops the approach and a reference search.
//!   Continuous, stepping and search commands switch closed loop off. With the output off a
//!   requested approach, jog or search is pending and starts when the output is switched on;
//!   switching the output off stops the carriage.
//! - **Status string**, first that applies: "output error" (a short latched), "output not
//!   enabled", "moving", "forward/backward limit reached" (the carriage on that end stop),
//!   "in target range" (closed loop on and within range), "ready".
//! - **End stops** are the simulator's limit switches: a motion stops on them; the EOT flags
//!   read true while the carriage stands on one.
//! - **Reference mark** is the simulator's home switch: it becomes valid (reference position =
//!   the mark's position then) whenever the carriage reaches or crosses it, and with auto
//!   reset the position is then zeroed there. `searchReferencePosition` drives onto the mark.
//! - **`raise_error`** latches a short on the axis (health 73): the output goes off, the status
//!   reads "output error", and the next enabling is refused with 73, which clears the latch.

use crate::emulator::axes;
use crate::Emulator;
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

/// Axes of an AMC.
const MAX_AXES: usize = 3;
/// Bytes of an incomplete request the controller holds before its buffer overflows.
const INPUT_BUFFER: usize = 8192;
/// Nesting a request may have.
const MAX_DEPTH: usize = 16;
/// The answer terminator.
const CRLF: &str = "\r\n";
/// Simulator steps (nm) in one open-loop step.
const STEP_NM: f64 = 1.0;
/// The largest target the manual allows, nm.
const MAX_TARGET: f64 = 140_737_488_355.328;

const ERR_NO_REFERENCE: i64 = 2;
const HW_SHORT_DETECTED: i64 = 73;
/// Error numbers with their names (language 0) and messages (language 1).
const ERRORS: [(i64, &str, &str); 3] = [
    (0, "ERROR_OK", "No error"),
    (ERR_NO_REFERENCE, "ERROR_NO_REFERENCE", "No valid reference position"),
    (HW_SHORT_DETECTED, "HW_SHORT_DETECTED", "Unspecific short circuit detected on the drive pins. Axis disabled"),
];

/// What the identification methods answer.
const IDENTITY: [(&str, &str); 5] = [
    ("com.attocube.system.getFirmwareVersion", "1.5.1"),
    ("com.attocube.system.getSerialNumber", "AMC100-EMU-0001"),
    ("com.attocube.system.getDeviceName", "AMC100"),
    ("com.attocube.amc.description.getDeviceType", "AMC100/NUM/PRO"),
    ("com.attocube.amc.description.getFeaturesActivated", "Closed loop Operation, Pro"),
];

/// A JSON value.
#[derive(Clone, Debug, PartialEq)]
enum Json {
    Null,
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    Array(Vec<Json>),
    Object(Vec<(String, Json)>),
}

impl Json {
    fn get(&self, key: &str) -> Option<&Json> {
        match self {
            Json::Object(members) => members.iter().find(|(k, _)| k == key).map(|(_, v)| v),
            _ => None,
        }
    }

    /// The value as compact JSON text (objects, never answered, as null).
    fn text(&self) -> String {
        match self {
            Json::Bool(b) => b.to_string(),
            Json::Int(i) => i.to_string(),
            Json::Float(f) if f.is_finite() => format!("{f:?}"),
            Json::Str(s) => {
                let mut out = String::from('"');
                for c in s.chars() {
                    match c {
                        '"' | '\\' => out.extend(['\\', c]),
                        c if u32::from(c) < 0x20 => out.push_str(&format!("\\u{:04x}", u32::from(c))),
                        c => out.push(c),
                    }
                }
                out + "\""
            }
            Json::Array(items) => format!("[{}]", items.iter().map(Json::text).collect::<Vec<_>>().join(",")),
            _ => "null".into(),
        }
    }
}

/// A strict JSON text, whole: the value, None if it is not one.
fn parse(text: &str) -> Option<Json> {
    let mut parser = Parser { s: text.as_bytes(), i: 0 };
    let value = parser.value(0)?;
    parser.ws();
    (parser.i == parser.s.len()).then_some(value)
}

struct Parser<'a> {
    s: &'a [u8],
    i: usize,
}

impl Parser<'_> {
    fn ws(&mut self) {
        while matches!(self.s.get(self.i), Some(b' ' | b'\t' | b'\r' | b'\n')) {
            self.i += 1;
        }
    }

    fn eat(&mut self, byte: u8) -> bool {
        let found = self.s.get(self.i) == Some(&byte);
        self.i += usize::from(found);
        found
    }

    fn word(&mut self, word: &str, value: Json) -> Option<Json> {
        let found = self.s.get(self.i..self.i + word.len()) == Some(word.as_bytes());
        self.i += word.len();
        found.then_some(value)
    }

    fn value(&mut self, depth: usize) -> Option<Json> {
        if depth > MAX_DEPTH {
            return None;
        }
        self.ws();
        match *self.s.get(self.i)? {
            open @ (b'{' | b'[') => {
                let (object, close) = (open == b'{', if open == b'{' { b'}' } else { b']' });
                self.i += 1;
                let mut items = Vec::new();
                self.ws();
                while !self.eat(close) {
                    if !items.is_empty() {
                        self.eat(b',').then_some(())?;
                    }
                    self.ws();
                    let key = if object { self.string()? } else { String::new() };
                    self.ws();
                    if object && !self.eat(b':') {
                        return None;
                    }
                    items.push((key, self.value(depth + 1)?));
                    self.ws();
                }
                Some(if object {
                    Json::Object(items)
                } else {
                    Json::Array(items.into_iter().map(|(_, v)| v).collect())
                })
            }
            b'"' => self.string().map(Json::Str),
            b't' => self.word("true", Json::Bool(true)),
            b'f' => self.word("false", Json::Bool(false)),
            b'n' => self.word("null", Json::Null),
            _ => self.number(),
        }
    }

    fn digits(&mut self) -> usize {
        let start = self.i;
        while self.s.get(self.i).is_some_and(u8::is_ascii_digit) {
            self.i += 1;
        }
        self.i - start
    }

    fn number(&mut self) -> Option<Json> {
        let start = self.i;
        self.eat(b'-');
        let leading_zero = self.s.get(self.i) == Some(&b'0');
        let whole = self.digits();
        if whole == 0 || (leading_zero && whole > 1) {
            return None;
        }
        let mut integral = true;
        if self.eat(b'.') {
            integral = false;
            (self.digits() > 0).then_some(())?;
        }
        if self.eat(b'e') || self.eat(b'E') {
            integral = false;
            let _ = self.eat(b'+') || self.eat(b'-');
            (self.digits() > 0).then_some(())?;
        }
        let text = std::str::from_utf8(&self.s[start..self.i]).ok()?;
        match text.parse::<i64>() {
            Ok(i) if integral => Some(Json::Int(i)),
            _ => text.parse::<f64>().ok().filter(|f| f.is_finite()).map(Json::Float),
        }
    }

    fn hex4(&mut self) -> Option<u32> {
        let text = std::str::from_utf8(self.s.get(self.i..self.i + 4)?).ok()?;
        self.i += 4;
        u32::from_str_radix(text, 16).ok().filter(|_| text.bytes().all(|b| b.is_ascii_hexdigit()))
    }

    fn string(&mut self) -> Option<String> {
        if !self.eat(b'"') {
            return None;
        }
        let mut out = String::new();
        loop {
            let start = self.i;
            while self.s.get(self.i).is_some_and(|&b| b != b'"' && b != b'\\' && b >= 0x20) {
                self.i += 1;
            }
            out.push_str(std::str::from_utf8(&self.s[start..self.i]).ok()?);
            match *self.s.get(self.i)? {
                b'"' => {
                    self.i += 1;
                    return Some(out);
                }
                b'\\' => {
                    let escape = *self.s.get(self.i + 1)?;
                    self.i += 2;
                    out.push(match escape {
                        b'"' => '"',
                        b'\\' => '\\',
                        b'/' => '/',
                        b'b' => '\u{8}',
                        b'f' => '\u{c}',
                        b'n' => '\n',
                        b'r' => '\r',
                        b't' => '\t',
                        b'u' => {
                            let high = self.hex4()?;
                            let code = if (0xD800..0xDC00).contains(&high) {
                                (self.eat(b'\\') && self.eat(b'u')).then_some(())?;
                                let low = self.hex4().filter(|l| (0xDC00..0xE000).contains(l))?;
                                0x10000 + ((high - 0xD800) << 10) + (low - 0xDC00)
                            } else {
                                high
                            };
                            char::from_u32(code)?
                        }
                        _ => return None,
                    });
                }
                _ => return None,
            }
        }
    }
}

/// What the input splits into: whole JSON values, or runs of bytes outside any.
#[derive(Debug, PartialEq)]
enum Piece {
    Value(Vec<u8>),
    Garbage,
}

/// Balanced JSON values out of bytes that arrive in any pieces.
#[derive(Debug, Default)]
struct Framer {
    pending: Vec<u8>,
    overflowed: usize,
}

impl Framer {
    fn push(&mut self, bytes: &[u8]) -> Vec<Piece> {
        self.pending.extend_from_slice(bytes);
        let mut pieces = Vec::new();
        loop {
            let start = self.pending.iter().position(|b| !b.is_ascii_whitespace()).unwrap_or(self.pending.len());
            self.pending.drain(..start);
            let Some(&first) = self.pending.first() else { break };
            if first == b'{' || first == b'[' {
                let Some(end) = balanced_end(&self.pending) else {
                    if self.pending.len() > INPUT_BUFFER {
                        self.pending.clear();
                        self.overflowed += 1;
                    }
                    break;
                };
                pieces.push(Piece::Value(self.pending.drain(..=end).collect()));
            } else {
                let end = self.pending.iter().position(|&b| b == b'{' || b == b'[').unwrap_or(self.pending.len());
                self.pending.drain(..end);
                pieces.push(Piece::Garbage);
            }
        }
        pieces
    }
}

/// Where the value opening `bytes` closes.
fn balanced_end(bytes: &[u8]) -> Option<usize> {
    let (mut depth, mut in_string, mut escaped) = (0usize, false, false);
    for (i, &b) in bytes.iter().enumerate() {
        if in_string {
            if escaped {
                escaped = false;
            } else if b == b'\\' {
                escaped = true;
            } else if b == b'"' {
                in_string = false;
            }
            continue;
        }
        match b {
            b'"' => in_string = true,
            b'{' | b'[' => depth += 1,
            b'}' | b']' => {
                depth = depth.saturating_sub(1);
                if depth == 0 {
                    return Some(i);
                }
            }
            _ => {}
        }
    }
    None
}

/// A request refused by the JSON-RPC layer.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Rpc {
    MethodNotFound,
    InvalidParams,
}

type Reply = Result<Vec<Json>, Rpc>;

fn done() -> Reply {
    Ok(vec![Json::Int(0)])
}

fn value(v: Json) -> Reply {
    Ok(vec![Json::Int(0), v])
}

fn none(rest: &[Json]) -> Result<(), Rpc> {
    rest.is_empty().then_some(()).ok_or(Rpc::InvalidParams)
}

fn one(rest: &[Json]) -> Result<&Json, Rpc> {
    match rest {
        [x] => Ok(x),
        _ => Err(Rpc::InvalidParams),
    }
}

/// A boolean: `true`/`false`, or `0`/`1` as MATLAB sends them.
fn flag(v: &Json) -> Result<bool, Rpc> {
    match v {
        Json::Bool(b) => Ok(*b),
        Json::Int(0) => Ok(false),
        Json::Int(1) => Ok(true),
        _ => Err(Rpc::InvalidParams),
    }
}

fn number(v: &Json) -> Result<f64, Rpc> {
    match v {
        Json::Int(i) => Ok(*i as f64),
        Json::Float(f) => Ok(*f),
        _ => Err(Rpc::InvalidParams),
    }
}

/// A whole number in `range`.
fn whole(v: &Json, range: std::ops::RangeInclusive<i64>) -> Result<i64, Rpc> {
    let n = match v {
        Json::Int(i) => *i,
        Json::Float(f) if f.fract() == 0.0 && f.abs() < 9e15 => *f as i64,
        _ => return Err(Rpc::InvalidParams),
    };
    range.contains(&n).then_some(n).ok_or(Rpc::InvalidParams)
}

/// One axis: its settings and the positioner behind it.
#[derive(Debug)]
struct Axis {
    sim: SimAxis,
    output: bool,
    control_move: bool,
    /// A continuous drive requested: Some(true) forward.
    continuous: Option<bool>,
    searching: bool,
    target: f64,
    target_range: f64,
    frequency: i64,
    amplitude: i64,
    n_steps: i64,
    auto_reset: bool,
    reference_auto_update: bool,
    reference: Option<f64>,
    health: i64,
    last_physical: f64,
}

impl Axis {
    fn new(sim: SimAxis) -> Self {
        Self {
            last_physical: sim.physical_position(),
            sim,
            output: false,
            control_move: false,
            continuous: None,
            searching: false,
            target: 0.0,
            target_range: 100.0,
            frequency: 1_000_000,
            amplitude: 45_000,
            n_steps: 1,
            auto_reset: false,
            reference_auto_update: true,
            reference: None,
            health: 0,
        }
    }

    fn position(&self) -> f64 {
        self.sim.status().position
    }

    /// The position as read, to the picometre.
    fn reading(&self) -> f64 {
        (self.position() * 1000.0).round() / 1000.0
    }

    /// nm/s: one step a period.
    fn velocity(&self) -> f64 {
        self.frequency as f64 / 1000.0 * STEP_NM
    }

    fn in_range(&self) -> bool {
        (self.position() - self.target).abs() <= self.target_range
    }

    /// On the end stop the target lies beyond.
    fn blocked(&self) -> bool {
        let state = self.sim.state();
        let position = self.position();
        (self.target > position && state.high_limit) || (self.target < position && state.low_limit)
    }

    fn driving(&self) -> bool {
        self.output && (self.sim.is_moving() || (self.control_move && !self.in_range() && !self.blocked()))
    }

    fn status_moving(&self) -> i64 {
        if self.driving() {
            1
        } else if !self.output && (self.control_move || self.continuous.is_some() || self.searching) {
            2
        } else {
            0
        }
    }

    fn combined_status(&self) -> &'static str {
        let state = self.sim.state();
        if self.health != 0 {
            "output error"
        } else if !self.output {
            "output not enabled"
        } else if self.driving() {
            "moving"
        } else if state.high_limit {
            "forward limit reached"
        } else if state.low_limit {
            "backward limit reached"
        } else if self.control_move && self.in_range() {
            "in target range"
        } else {
            "ready"
        }
    }

    /// Time passes to `now`: the mark is watched and the closed loop regulates.
    fn update(&mut self, now: Instant) {
        self.sim.advance(now);
        let physical = self.sim.physical_position();
        let mark = self.sim.config().home_switch;
        if physical != self.last_physical && (self.last_physical - mark) * (physical - mark) <= 0.0 {
            self.mark_seen(physical, mark);
        }
        self.last_physical = physical;
        if self.output && !self.sim.is_moving() {
            self.searching = false;
            if self.control_move && !self.in_range() && !self.blocked() {
                self.approach();
            }
        }
    }

    fn mark_seen(&mut self, physical: f64, mark: f64) {
        if self.reference.is_some() && !self.reference_auto_update {
            return;
        }
        if self.auto_reset {
            self.sim.set_position(physical - mark);
            if self.control_move && self.sim.is_moving() {
                self.approach();
            }
        }
        self.reference = Some(mark + self.position() - physical);
    }

    fn approach(&mut self) {
        let v = self.velocity();
        self.sim.move_to(self.target, false, 0.0, v, 0.0);
    }

    /// Start what was asked for, if the output is on.
    fn resume(&mut self) {
        let v = self.velocity();
        if !self.output {
            return;
        }
        if let Some(forward) = self.continuous {
            self.sim.move_velocity(0.0, if forward { v } else { -v }, 0.0);
        } else if self.searching {
            if self.auto_reset {
                self.sim.home(true, v, v, 0.0);
            } else {
                let mark = self.sim.config().home_switch + self.position() - self.sim.physical_position();
                self.sim.move_to(mark, false, 0.0, v, 0.0);
            }
        } else if self.control_move {
            self.approach();
        }
    }

    /// End every motion mode (open-loop commands replace the closed loop).
    fn clear_modes(&mut self) {
        self.control_move = false;
        self.continuous = None;
        self.searching = false;
        self.sim.stop(0.0);
    }

    fn steps(&mut self, backward: bool, n: i64) {
        self.clear_modes();
        if self.output {
            let distance = n as f64 * STEP_NM * if backward { -1.0 } else { 1.0 };
            let v = self.velocity();
            self.sim.move_to(distance, true, 0.0, v, 0.0);
        }
    }
}

/// What a getter of one axis reads, None if `method` is not one.
fn reading(a: &Axis, method: &str) -> Option<Json> {
    let state = a.sim.state();
    Some(match method {
        "move.getPosition" => Json::Float(a.reading()),
        "move.getControlTargetPosition" => Json::Float(a.target),
        "move.getNSteps" => Json::Int(a.n_steps),
        "move.getControlContinuousFwd" => Json::Bool(a.continuous == Some(true)),
        "move.getControlContinuousBkwd" => Json::Bool(a.continuous == Some(false)),
        "control.getControlMove" => Json::Bool(a.control_move),
        "control.getControlOutput" => Json::Bool(a.output),
        "control.getOutputHealthStatus" => Json::Int(a.health),
        "control.getControlTargetRange" => Json::Float(a.target_range),
        "control.getControlFrequency" => Json::Int(a.frequency),
        "control.getControlAmplitude" => Json::Int(a.amplitude),
        "control.getControlAutoReset" => Json::Bool(a.auto_reset),
        "control.getControlReferenceAutoUpdate" => Json::Bool(a.reference_auto_update),
        "control.getReferencePosition" => Json::Float(a.reference.unwrap_or(0.0)),
        "control.getActorName" => Json::Str("ANPx101".into()),
        "control.getActorType" | "status.getOlStatus" => Json::Int(0),
        "status.getFullCombinedStatus" => Json::Str(a.combined_status().into()),
        "status.getStatusMoving" => Json::Int(a.status_moving()),
        "status.getStatusTargetRange" => Json::Bool(a.in_range()),
        "status.getStatusEot" => Json::Bool(state.high_limit || state.low_limit),
        "status.getStatusEotFwd" => Json::Bool(state.high_limit),
        "status.getStatusEotBkwd" => Json::Bool(state.low_limit),
        "status.getStatusReference" => Json::Bool(a.reference.is_some()),
        "status.getStatusConnected" => Json::Bool(true),
        _ => return None,
    })
}

/// `method` on axis `a`, `rest` the parameters after the axis.
fn axis_method(a: &mut Axis, method: &str, rest: &[Json]) -> Reply {
    let steps = 0..=i64::from(u32::MAX);
    match method {
        "move.setControlTargetPosition" => {
            let target = number(one(rest)?)?;
            if target.abs() > MAX_TARGET {
                return Err(Rpc::InvalidParams);
            }
            a.target = target;
            if a.control_move && a.output {
                a.approach();
            }
        }
        "move.moveReference" => {
            none(rest)?;
            let Some(reference) = a.reference else { return Ok(vec![Json::Int(ERR_NO_REFERENCE)]) };
            a.clear_modes();
            a.target = reference;
            a.control_move = true;
            a.resume();
        }
        "move.setNSteps" => match rest {
            [backward, n] => {
                let (backward, n) = (flag(backward)?, whole(n, steps)?);
                a.n_steps = n;
                a.steps(backward, n);
            }
            _ => return Err(Rpc::InvalidParams),
        },
        "move.setSingleStep" => a.steps(flag(one(rest)?)?, 1),
        "move.performNSteps" => a.steps(flag(one(rest)?)?, a.n_steps),
        "move.writeNSteps" => a.n_steps = whole(one(rest)?, steps)?,
        "move.setControlContinuousFwd" | "move.setControlContinuousBkwd" => {
            let enable = flag(one(rest)?)?;
            a.clear_modes();
            if enable {
                a.continuous = Some(method.ends_with("Fwd"));
                a.resume();
            }
        }
        "control.setControlMove" => {
            let enable = flag(one(rest)?)?;
            if enable || a.control_move || a.searching {
                a.clear_modes();
            }
            if enable {
                a.control_move = true;
                a.resume();
            }
        }
        "control.setControlOutput" => {
            let enable = flag(one(rest)?)?;
            if !enable {
                a.output = false;
                a.sim.stop(0.0);
            } else if a.health != 0 {
                return Ok(vec![Json::Int(std::mem::take(&mut a.health))]);
            } else if !a.output {
                a.output = true;
                a.resume();
            }
        }
        "control.setControlTargetRange" => {
            let range = number(one(rest)?)?;
            if !(0.0..=MAX_TARGET).contains(&range) {
                return Err(Rpc::InvalidParams);
            }
            a.target_range = range;
        }
        "control.setControlFrequency" => a.frequency = whole(one(rest)?, 1..=5_000_000)?,
        "control.setControlAmplitude" => a.amplitude = whole(one(rest)?, 0..=60_000)?,
        "control.setControlAutoReset" => a.auto_reset = flag(one(rest)?)?,
        "control.setControlReferenceAutoUpdate" => a.reference_auto_update = flag(one(rest)?)?,
        "control.searchReferencePosition" => {
            none(rest)?;
            a.clear_modes();
            a.searching = true;
            a.resume();
        }
        "control.setReset" => {
            none(rest)?;
            a.sim.set_position(0.0);
            a.reference = None;
            if a.control_move && a.sim.is_moving() {
                a.approach();
            }
        }
        _ => {
            let read = reading(a, method).ok_or(Rpc::MethodNotFound)?;
            none(rest)?;
            return value(read);
        }
    }
    done()
}

/// An AMC100 on TCP port 9090, axes 0 … n−1.
pub struct AmcEmulator {
    axes: Vec<Axis>,
    framer: Framer,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl AmcEmulator {
    /// An AMC with `channels` axes (one at least, three at most), numbered from 0.
    pub fn new(channels: usize, mechanics: &SimConfig) -> Self {
        Self {
            axes: axes(channels.clamp(1, MAX_AXES), mechanics).into_iter().map(Axis::new).collect(),
            framer: Framer::default(),
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    /// The controller as a lab leaves it once attocube's own software has switched the
    /// outputs on (the setting outlives the connection; a script that never enables them,
    /// as motorScriptMotor's `Attocube_AMC.lua`, relies on it).
    #[must_use]
    pub fn with_outputs_on(mut self) -> Self {
        for axis in &mut self.axes {
            axis.output = true;
        }
        self
    }

    /// Carry out `method` with `params`.
    fn call(&mut self, method: &str, params: &[Json]) -> Reply {
        let text = |s: &str| value(Json::Str(s.into()));
        if let Some((_, answer)) = IDENTITY.iter().find(|(name, _)| *name == method) {
            return none(params).and_then(|()| text(answer));
        }
        match method {
            "com.attocube.system.errorNumberToString" => match params {
                [language, number] => {
                    let (language, number) = (whole(language, 0..=1)?, whole(number, i64::MIN..=i64::MAX)?);
                    let known = ERRORS.iter().find(|(n, _, _)| *n == number);
                    let (name, message) = known.map_or(("ERROR_UNKNOWN", "Unknown error"), |(_, n, m)| (*n, *m));
                    text(if language == 0 { name } else { message })
                }
                _ => Err(Rpc::InvalidParams),
            },
            "com.attocube.amc.control.getStatusMovingAllAxes" | "com.attocube.amc.control.getPositionsAndVoltages" => {
                none(params)?;
                let mut result = vec![Json::Int(0)];
                if method.ends_with("AllAxes") {
                    result.extend((0..MAX_AXES).map(|i| Json::Int(self.axes.get(i).map_or(0, Axis::status_moving))));
                } else {
                    result.extend((0..MAX_AXES).map(|i| Json::Float(self.axes.get(i).map_or(0.0, Axis::reading))));
                    result.extend((0..MAX_AXES).map(|_| Json::Float(0.0)));
                }
                Ok(result)
            }
            _ => {
                let method = method.strip_prefix("com.attocube.amc.").ok_or(Rpc::MethodNotFound)?;
                let (first, rest) = params.split_first().map_or((None, params), |(f, r)| (Some(f), r));
                let count = self.axes.len() as i64;
                let axis = first.ok_or(Rpc::InvalidParams).and_then(|a| whole(a, 0..=count - 1));
                match axis.ok().and_then(|i| self.axes.get_mut(usize::try_from(i).ok()?)) {
                    Some(axis) => axis_method(axis, method, rest),
                    // No such axis: whether the method exists is asked of a scratch one.
                    None => match axis_method(&mut Axis::new(SimAxis::new(SimConfig::default())), method, rest) {
                        Err(Rpc::MethodNotFound) => Err(Rpc::MethodNotFound),
                        _ => Err(Rpc::InvalidParams),
                    },
                }
            }
        }
    }

    /// The answer to one piece of input, None for a notification.
    fn answer(&mut self, piece: &Piece) -> Option<String> {
        let request = match piece {
            Piece::Value(bytes) => std::str::from_utf8(bytes).ok().and_then(parse),
            Piece::Garbage => None,
        };
        let Some(request) = request else {
            self.malformed += 1;
            return Some(error(&Json::Null, -32700, "Parse error"));
        };
        let id = request.get("id");
        let scalar_id = matches!(id, None | Some(Json::Null | Json::Int(_) | Json::Float(_) | Json::Str(_)));
        let method = match (request.get("jsonrpc"), request.get("method"), request.get("params")) {
            (Some(Json::Str(version)), Some(Json::Str(method)), None | Some(Json::Array(_)))
                if version == "2.0" && scalar_id =>
            {
                method.clone()
            }
            _ => {
                self.malformed += 1;
                return Some(error(id.filter(|_| scalar_id).unwrap_or(&Json::Null), -32600, "Invalid Request"));
            }
        };
        let params = match request.get("params") {
            Some(Json::Array(params)) => params.as_slice(),
            _ => &[],
        };
        let outcome = self.call(&method, params);
        if outcome.is_err() {
            self.malformed += 1;
        }
        let id = id?;
        Some(match outcome {
            Ok(result) => response(id, &format!(r#""result":{}"#, Json::Array(result).text())),
            Err(Rpc::MethodNotFound) => error(id, -32601, "Method not found"),
            Err(Rpc::InvalidParams) => error(id, -32602, "Invalid params"),
        })
    }
}

/// A response to request `id` with `member` (its result or error).
fn response(id: &Json, member: &str) -> String {
    format!(r#"{{"jsonrpc":"2.0",{member},"id":{}}}"#, id.text())
}

/// A JSON-RPC error response.
fn error(id: &Json, code: i64, message: &str) -> String {
    response(id, &format!(r#""error":{{"code":{code},"message":"{message}"}}"#))
}

impl Emulator for AmcEmulator {
    fn name(&self) -> &'static str {
        "attocube_amc"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for axis in &mut self.axes {
            axis.update(now);
        }
        for piece in self.framer.push(bytes) {
            if let Some(reply) = self.answer(&piece) {
                self.output.push_back(format!("{reply}{CRLF}").into_bytes());
            }
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.output.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed + self.framer.overflowed
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.axes.get_mut(channel).map(|axis| &mut axis.sim)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(axis) = self.axes.get_mut(channel) else { return false };
        axis.health = HW_SHORT_DETECTED;
        axis.output = false;
        axis.sim.stop(0.0);
        true
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

    /// The one answer to `method(params)` with id 1, without its terminator.
    fn call(e: &mut AmcEmulator, ms: u64, method: &str, params: &str) -> String {
        let request = format!(r#"{{"jsonrpc": "2.0", "method": "{method}", "params": [{params}], "id": 1, "api": 2}}"#);
        e.handle_input(at(ms), request.as_bytes());
        let reply = String::from_utf8(e.poll_transmit().expect("answered")).expect("UTF-8");
        assert!(e.poll_transmit().is_none(), "one answer a request");
        reply.strip_suffix("\r\n").expect("ends with CR LF").to_string()
    }

    fn result(e: &mut AmcEmulator, ms: u64, method: &str, params: &str) -> String {
        let reply = call(e, ms, method, params);
        let inner = reply.strip_prefix(r#"{"jsonrpc":"2.0","result":["#).expect("a result");
        inner.strip_suffix(r#"],"id":1}"#).expect("id 1").to_string()
    }

    fn status(e: &mut AmcEmulator, ms: u64, axis: usize) -> String {
        result(e, ms, "com.attocube.amc.status.getFullCombinedStatus", &axis.to_string())
    }

    fn position(e: &mut AmcEmulator, ms: u64, axis: usize) -> f64 {
        let r = result(e, ms, "com.attocube.amc.move.getPosition", &axis.to_string());
        r.strip_prefix("0,").expect("no error").parse().expect("a number")
    }

    const OK: &str = "0";

    #[test]
    fn identification_and_power_on_state() {
        let mut e = AmcEmulator::new(3, &stage());
        assert_eq!(
            call(&mut e, 0, "com.attocube.amc.move.getPosition", "0"),
            r#"{"jsonrpc":"2.0","result":[0,0.0],"id":1}"#
        );
        assert_eq!(result(&mut e, 0, "com.attocube.system.getFirmwareVersion", ""), r#"0,"1.5.1""#);
        assert_eq!(result(&mut e, 0, "com.attocube.amc.description.getDeviceType", ""), r#"0,"AMC100/NUM/PRO""#);
        assert_eq!(result(&mut e, 0, "com.attocube.system.getDeviceName", ""), r#"0,"AMC100""#);
        assert_eq!(result(&mut e, 0, "com.attocube.system.errorNumberToString", "0, 73"), r#"0,"HW_SHORT_DETECTED""#);
        assert_eq!(
            result(&mut e, 0, "com.attocube.system.errorNumberToString", "1, 2"),
            r#"0,"No valid reference position""#
        );
        assert_eq!(status(&mut e, 0, 2), r#"0,"output not enabled""#);
        assert_eq!(result(&mut e, 0, "com.attocube.amc.control.getControlOutput", "1"), "0,false");
        assert_eq!(result(&mut e, 0, "com.attocube.amc.control.getControlTargetRange", "1"), "0,100.0");
        assert_eq!(result(&mut e, 0, "com.attocube.amc.control.getControlFrequency", "1"), "0,1000000");
        assert_eq!(result(&mut e, 0, "com.attocube.amc.status.getStatusReference", "0"), "0,false");
        assert_eq!(result(&mut e, 0, "com.attocube.amc.status.getOlStatus", "0"), "0,0");
        assert_eq!(result(&mut e, 0, "com.attocube.amc.control.getStatusMovingAllAxes", ""), "0,0,0,0");
        assert_eq!(result(&mut e, 0, "com.attocube.amc.move.moveReference", "0"), "2", "no reference yet");
        assert_eq!(e.malformed(), 0);
        assert_eq!(e.name(), "attocube_amc");
    }

    #[test]
    fn a_closed_loop_approach_arrives_in_target_range() {
        let mut e = AmcEmulator::new(3, &stage());
        assert_eq!(result(&mut e, 0, "com.attocube.amc.move.setControlTargetPosition", "1, 5000"), OK);
        assert_eq!(result(&mut e, 0, "com.attocube.amc.control.setControlMove", "1, true"), OK);
        assert_eq!(result(&mut e, 0, "com.attocube.amc.status.getStatusMoving", "1"), "0,2", "pending");
        assert_eq!(result(&mut e, 0, "com.attocube.amc.control.setControlOutput", "1, true"), OK);
        assert_eq!(status(&mut e, 2000, 1), r#"0,"moving""#);
        assert_eq!(position(&mut e, 2000, 1), 2000.0, "1000 nm/s");
        assert_eq!(result(&mut e, 2000, "com.attocube.amc.status.getStatusTargetRange", "1"), "0,false");
        assert_eq!(status(&mut e, 5000, 1), r#"0,"in target range""#);
        assert_eq!(position(&mut e, 5000, 1), 5000.0);
        assert_eq!(result(&mut e, 5000, "com.attocube.amc.control.getControlMove", "1"), "0,true");
        assert_eq!(result(&mut e, 5000, "com.attocube.amc.move.getControlTargetPosition", "1"), "0,5000.0");
        // A new target is followed at once, at the frequency set.
        assert_eq!(result(&mut e, 5000, "com.attocube.amc.control.setControlFrequency", "1, 2000000"), OK);
        assert_eq!(result(&mut e, 5000, "com.attocube.amc.move.setControlTargetPosition", "1, -1000.5"), OK);
        assert_eq!(position(&mut e, 6000, 1), 3000.0);
        assert_eq!(status(&mut e, 8100, 1), r#"0,"in target range""#);
        assert_eq!(position(&mut e, 8100, 1), -1000.5);
        assert_eq!(e.axis(1).map(|a| a.physical_position()), Some(-1000.5));
    }

    #[test]
    fn stops_open_loop_steps_and_jogs() {
        let mut e = AmcEmulator::new(1, &stage());
        result(&mut e, 0, "com.attocube.amc.control.setControlOutput", "0, true");
        result(&mut e, 0, "com.attocube.amc.move.setControlTargetPosition", "0, 100000");
        result(&mut e, 0, "com.attocube.amc.control.setControlMove", "0, true");
        assert_eq!(result(&mut e, 1500, "com.attocube.amc.control.setControlMove", "0, false"), OK);
        assert_eq!(status(&mut e, 3000, 0), r#"0,"ready""#);
        assert_eq!(position(&mut e, 3000, 0), 1500.0);
        // Open-loop steps, MATLAB's way: a boolean as 1.
        assert_eq!(result(&mut e, 3000, "com.attocube.amc.move.setNSteps", "0, 1, 300"), OK);
        assert_eq!(result(&mut e, 3000, "com.attocube.amc.status.getStatusMoving", "0"), "0,1");
        assert_eq!(position(&mut e, 4000, 0), 1200.0);
        assert_eq!(result(&mut e, 4000, "com.attocube.amc.move.getNSteps", "0"), "0,300");
        result(&mut e, 4000, "com.attocube.amc.move.setSingleStep", "0, false");
        assert_eq!(position(&mut e, 5000, 0), 1201.0);
        // A jog, stopped by its own `false`.
        assert_eq!(result(&mut e, 5000, "com.attocube.amc.move.setControlContinuousBkwd", "0, true"), OK);
        assert_eq!(result(&mut e, 6000, "com.attocube.amc.move.getControlContinuousBkwd", "0"), "0,true");
        assert_eq!(result(&mut e, 6000, "com.attocube.amc.move.setControlContinuousFwd", "0, false"), OK);
        assert_eq!(position(&mut e, 7000, 0), 201.0);
        assert_eq!(result(&mut e, 7000, "com.attocube.amc.move.getControlContinuousBkwd", "0"), "0,false");
        // Switching the output off stops the carriage too.
        result(&mut e, 7000, "com.attocube.amc.move.setControlContinuousFwd", "0, true");
        result(&mut e, 7100, "com.attocube.amc.control.setControlOutput", "0, false");
        assert_eq!(position(&mut e, 9000, 0), 301.0);
        assert_eq!(result(&mut e, 9000, "com.attocube.amc.status.getStatusMoving", "0"), "0,2", "pending");
    }

    #[test]
    fn end_stops_are_reported_and_left() {
        let mut e = AmcEmulator::new(2, &stage());
        result(&mut e, 0, "com.attocube.amc.control.setControlFrequency", "1, 5000000");
        result(&mut e, 0, "com.attocube.amc.control.setControlOutput", "1, true");
        result(&mut e, 0, "com.attocube.amc.move.setControlContinuousFwd", "1, 1");
        assert_eq!(status(&mut e, 41_000, 1), r#"0,"forward limit reached""#);
        assert_eq!(position(&mut e, 41_000, 1), 200_000.0);
        assert_eq!(result(&mut e, 41_000, "com.attocube.amc.status.getStatusEotFwd", "1"), "0,true");
        assert_eq!(result(&mut e, 41_000, "com.attocube.amc.status.getStatusEotBkwd", "1"), "0,false");
        // A closed-loop target beyond the stop ends on it.
        result(&mut e, 41_000, "com.attocube.amc.move.setControlTargetPosition", "1, -3e5");
        result(&mut e, 41_000, "com.attocube.amc.control.setControlMove", "1, true");
        assert_eq!(status(&mut e, 41_100, 1), r#"0,"moving""#);
        assert_eq!(status(&mut e, 122_000, 1), r#"0,"backward limit reached""#);
        assert_eq!(result(&mut e, 122_000, "com.attocube.amc.status.getStatusEot", "1"), "0,true");
        assert_eq!(result(&mut e, 122_000, "com.attocube.amc.move.setControlTargetPosition", "1, 0"), OK);
        assert_eq!(status(&mut e, 123_000, 1), r#"0,"moving""#);
        assert_eq!(status(&mut e, 170_000, 1), r#"0,"in target range""#);
    }

    #[test]
    fn the_reference_mark_is_searched_and_approached() {
        let mut e = AmcEmulator::new(1, &SimConfig { home_switch: -2000.0, ..stage() });
        result(&mut e, 0, "com.attocube.amc.control.setControlOutput", "0, true");
        assert_eq!(result(&mut e, 0, "com.attocube.amc.control.searchReferencePosition", "0"), OK);
        assert_eq!(status(&mut e, 1000, 0), r#"0,"moving""#);
        assert_eq!(status(&mut e, 2500, 0), r#"0,"ready""#);
        assert_eq!(result(&mut e, 2500, "com.attocube.amc.status.getStatusReference", "0"), "0,true");
        assert_eq!(result(&mut e, 2500, "com.attocube.amc.control.getReferencePosition", "0"), "0,-2000.0");
        // Elsewhere, then back to the mark by closed loop.
        result(&mut e, 2500, "com.attocube.amc.move.setNSteps", "0, false, 700");
        assert_eq!(result(&mut e, 4000, "com.attocube.amc.move.moveReference", "0"), OK);
        assert_eq!(result(&mut e, 4000, "com.attocube.amc.control.getControlMove", "0"), "0,true");
        assert_eq!(status(&mut e, 5000, 0), r#"0,"in target range""#);
        assert_eq!(position(&mut e, 5000, 0), -2000.0);
        // Auto reset zeroes the position at the mark; setReset zeroes it anywhere.
        result(&mut e, 5000, "com.attocube.amc.control.setControlAutoReset", "0, true");
        result(&mut e, 5000, "com.attocube.amc.move.setNSteps", "0, true, 500");
        result(&mut e, 6000, "com.attocube.amc.control.searchReferencePosition", "0");
        assert_eq!(position(&mut e, 7000, 0), 0.0);
        assert_eq!(result(&mut e, 7000, "com.attocube.amc.control.getReferencePosition", "0"), "0,0.0");
        assert!(e.axis(0).is_some_and(|a| a.state().homed));
        result(&mut e, 7000, "com.attocube.amc.move.setNSteps", "0, false, 250");
        assert_eq!(result(&mut e, 8000, "com.attocube.amc.control.setReset", "0"), OK);
        assert_eq!(position(&mut e, 8000, 0), 0.0);
        assert_eq!(result(&mut e, 8000, "com.attocube.amc.status.getStatusReference", "0"), "0,false");
    }

    #[test]
    fn a_short_is_reported_then_cleared() {
        let mut e = AmcEmulator::new(3, &stage());
        result(&mut e, 0, "com.attocube.amc.control.setControlOutput", "2, true");
        result(&mut e, 0, "com.attocube.amc.move.setControlContinuousFwd", "2, true");
        assert!(e.raise_error(2));
        assert!(!e.raise_error(3));
        assert_eq!(status(&mut e, 1000, 2), r#"0,"output error""#);
        assert_eq!(position(&mut e, 1000, 2), 0.0, "stopped at once");
        assert_eq!(result(&mut e, 1000, "com.attocube.amc.control.getOutputHealthStatus", "2"), "0,73");
        assert_eq!(result(&mut e, 1000, "com.attocube.amc.control.setControlOutput", "2, true"), "73");
        assert_eq!(status(&mut e, 1000, 2), r#"0,"output not enabled""#);
        assert_eq!(result(&mut e, 1000, "com.attocube.amc.control.setControlOutput", "2, true"), OK);
        assert_eq!(status(&mut e, 1500, 2), r#"0,"moving""#, "the pending jog resumes");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn errors_are_answered_and_counted() {
        let mut e = AmcEmulator::new(2, &stage());
        assert_eq!(
            call(&mut e, 0, "com.attocube.amc.move.getSpeed", "0"),
            r#"{"jsonrpc":"2.0","error":{"code":-32601,"message":"Method not found"},"id":1}"#
        );
        let invalid = r#"{"jsonrpc":"2.0","error":{"code":-32602,"message":"Invalid params"},"id":1}"#;
        for (method, params) in [
            ("com.attocube.amc.move.getPosition", "2"),
            ("com.attocube.amc.move.getPosition", "-1"),
            ("com.attocube.amc.move.getPosition", "0, 1"),
            ("com.attocube.amc.move.getPosition", r#""0""#),
            ("com.attocube.amc.control.setControlMove", "0, 2"),
            ("com.attocube.amc.move.setControlTargetPosition", "0, 1e12"),
            ("com.attocube.amc.control.setControlFrequency", "0, 0"),
            ("com.attocube.system.getFirmwareVersion", "1"),
        ] {
            assert_eq!(call(&mut e, 0, method, params), invalid, "{method}({params})");
        }
        e.handle_input(at(0), br#"{"jsonrpc": "1.0", "method": "x", "id": "a"}"#);
        e.handle_input(at(0), br#"[{"jsonrpc": "2.0", "method": "x", "id": 2}]"#);
        e.handle_input(at(0), b"hello\r\n{\"a\":}");
        let replies: Vec<String> =
            std::iter::from_fn(|| e.poll_transmit()).map(|r| String::from_utf8(r).unwrap()).collect();
        assert_eq!(
            replies,
            [
                "{\"jsonrpc\":\"2.0\",\"error\":{\"code\":-32600,\"message\":\"Invalid Request\"},\"id\":\"a\"}\r\n",
                "{\"jsonrpc\":\"2.0\",\"error\":{\"code\":-32600,\"message\":\"Invalid Request\"},\"id\":null}\r\n",
                "{\"jsonrpc\":\"2.0\",\"error\":{\"code\":-32700,\"message\":\"Parse error\"},\"id\":null}\r\n",
                "{\"jsonrpc\":\"2.0\",\"error\":{\"code\":-32700,\"message\":\"Parse error\"},\"id\":null}\r\n",
            ]
        );
        assert_eq!(e.malformed(), 13);
        e.handle_input(at(0), &[b'{'; INPUT_BUFFER + 1]);
        assert_eq!(e.malformed(), 14, "an overflowing input buffer counts");
        let unknown = call(&mut e, 0, "com.attocube.amc.move.getSpeed", "5");
        assert!(unknown.contains("-32601"), "an unknown method on an absent axis: {unknown}");
        e.handle_input(at(0), b"{\"\xff\"}[1,]{\"id\":[1]}");
        assert_eq!(std::iter::from_fn(|| e.poll_transmit()).count(), 3);
        assert_eq!(e.malformed(), 18);
        // Any bytes at all: answered or held, never a panic.
        let mut seed = 12_345u32;
        let alphabet = b"{}[]\"\\:,0123456789.eE-+tfnul \r\n\xff\x00abc";
        let noise: Vec<u8> = (0..20_000)
            .map(|_| {
                seed = seed.wrapping_mul(1_103_515_245).wrapping_add(12_345);
                alphabet[(seed >> 16) as usize % alphabet.len()]
            })
            .collect();
        for chunk in noise.chunks(37) {
            e.handle_input(at(0), chunk);
        }
        assert!(std::iter::from_fn(|| e.poll_transmit()).count() > 0);
    }

    #[test]
    fn requests_come_whole_from_any_pieces() {
        let mut e = AmcEmulator::new(3, &stage());
        // cJSON_Print's multi-line form, in pieces, with a brace and escapes inside a string.
        let request = "{\n\t\"jsonrpc\":\t\"2.0\",\n\t\"method\":\t\"com.attocube.amc.control.setControlTargetRange\",\n\t\"params\":\t[1, 2.5e2],\n\t\"pid\":\t\"x{\\\"\\u00e9\\ud83d\\ude00\",\n\t\"id\":\t7\n}";
        for piece in request.as_bytes().chunks(5) {
            assert!(e.poll_transmit().is_none());
            e.handle_input(at(0), piece);
        }
        assert_eq!(e.poll_transmit(), Some(b"{\"jsonrpc\":\"2.0\",\"result\":[0],\"id\":7}\r\n".to_vec()));
        assert_eq!(result(&mut e, 0, "com.attocube.amc.control.getControlTargetRange", "1"), "0,250.0");
        // Two at once, MATLAB's line feeds, no params, a notification, a string id.
        e.handle_input(
            at(0),
            concat!(
                r#"{"jsonrpc": "2.0", "pid": "amc", "method": "com.attocube.amc.control.setControlOutput", "params": [0, 1]}"#,
                "\n",
                r#"{"jsonrpc":"2.0","method":"com.attocube.amc.description.getFeaturesActivated","id":"f"}"#,
                "\n",
            )
            .as_bytes(),
        );
        assert_eq!(
            e.poll_transmit(),
            Some(b"{\"jsonrpc\":\"2.0\",\"result\":[0,\"Closed loop Operation, Pro\"],\"id\":\"f\"}\r\n".to_vec())
        );
        assert!(e.poll_transmit().is_none(), "the notification is not answered");
        assert_eq!(status(&mut e, 0, 0), r#"0,"ready""#, "but carried out");
        assert_eq!(e.malformed(), 0);
        assert!(e.axis(2).is_some() && e.axis(3).is_none());
        assert_eq!(AmcEmulator::new(9, &stage()).axes.len(), 3);
        assert_eq!(AmcEmulator::new(0, &stage()).axes.len(), 1);
    }
}
