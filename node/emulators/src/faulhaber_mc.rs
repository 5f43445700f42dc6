//! The Faulhaber motion controllers of the MCDC 300x / MCBL 300x family (MCDC 3006 S and its
//! kin) on RS-232, speaking Faulhaber's ASCII command set: one drive a node, several nodes on one
//! line, each command a mnemonic with an optional node number before it and an optional number
//! after it, ended by a carriage return (`1LA1000\r`, `POS\r`).
//!
//! # Witnesses
//!
//! 1. Faulhaber's "Communication and Function Manual, Motion Control Series MCBL 300x RS, MCDC
//!    300x RS, 3564…B CS, 32xx…BX4 CS, 22xx…BX4 CSD" (RS232), as published page by page on
//!    manualshive (document 546592; the imprints of its 3rd issue, 07.11.2013, 4th issue,
//!    30.04.2015 and 5th edition, 16-05-2017, were seen elsewhere; the page texts read here are
//!    the same in substance). It gave: the command structure `[Node No.] Command [Argument] CR`,
//!    the node number optional; "space characters are ignored, and no distinction is made
//!    between upper and lower case"; replies and asynchronous events end `CR LF`; `POS` answered
//!    with the bare number (`98956`); with `ANSW2` a command is answered `OK`, or on an execution
//!    error one of `Unknown command`, `Invalid parameter`, `Command not available`,
//!    `Overtemperature – drive disabled`; `SAVE`/`EEPSAV` always answered `EEPROM writing done`;
//!    node numbers 1 to 255, drives delivered with 0, `NODEADR` (p. 21); the general queries
//!    `GTYP` `GSER` `VER` `POS` `TPOS` `GV` `GN` `GCL` `GRC` `TEM`, and `OST` with its bits
//!    (0 homing running, 1–3 sequence program, 4 current limitation, 5 deviation error,
//!    6 overvoltage, 7 overtemperature, 8–12 status inputs 1–5, 16 position attained) (p. 68);
//!    the predecessors' queries kept for compatibility: `GST` (7 characters: position control,
//!    analog/PWM source, PWM, enabled, target reached, positive edge, high level), `GFS`
//!    (4 characters: overtemperature, current limiting, reserved, overvoltage) and `GAST`
//!    (4 characters: limit switch 2 level, limit switch 3 level, clockwise with positive values,
//!    homing active) (p. 63).
//! 2. Faulhaber's older "Series MCBL 05002" and "Series 3564 K024 BC" instruction manuals
//!    (manualshive 546590 p. 15, 546611 p. 52): a command without a node number "is sent to all
//!    the drives on the network"; with a single drive the number can be omitted; `NP 1000`
//!    (notify position) sends back a `p` when position 1000 is reached; asynchronous replies on
//!    a line with several drives collide, so only one drive should be allowed them; `GNODEADR`.
//! 3. Kickdrive's Docklight project "Faulhaber_RS232" (Marco Flachmann, 2019-10-08): the bytes
//!    of `ENCRES`, `ANSW`, `LL`, `SP`, `AC`, `DEC`, `DI`, `EN`, `M`, `LA`, `LR`, `NP`, `NPOFF`,
//!    `V`, `GOHOSEQ`, `HO`, `POS`, `TPOS`, `OST`, `SAVE`, `EEPSAV`, and the replies `OK\r\n` and
//!    `p\r\n` ("position notified").
//! 4. The EPICS module epics-motor/motorFaulhaber (drvMCDC2805/devMCDC2805, Mark Rivers 2005)
//!    and MichaS-git/motorFaulhaber (MCBL2805Driver, 2020), read only for the bytes a client
//!    sends: node numbers `0`…`7` before the mnemonic; `LA 1000` with a space, `LA1000.000000`
//!    with a fraction; `V 0` to stop; `HO n`; `ENCRES`, `HOSP`, `SP`, `AC`, `POR`, `I`, `EN`,
//!    `DI`, `SOR 0`, `REFIN`, `HP7`, `HB6`, `HD2`, `HL1`, `HA1`, `CAHOSEQ`, `DEV100`, `LL±n`;
//!    the queries `VER`, `GST`, `GAST`, `POS`, `GV`, `GNL`, `GPL`; commands sent without
//!    reading a reply (so a drive in its default answer mode does not confirm them).
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Answer mode.** `ANSW0`: no asynchronous replies; `ANSW1` (the power-on default, a
//!   guess): asynchronous `p` allowed; `ANSW2`: also `OK` after every command and the error
//!   texts after a failed one. The manual ties the error texts to `ANSW2`, so under `ANSW0`/`1`
//!   a failed command is silent (still counted when malformed). Queries are always answered.
//!   A change of `ANSW` is answered under the new mode. Other values are invalid.
//! - **The overtemperature text** is sent with an ASCII hyphen, `Overtemperature - drive
//!   disabled` (the manual prints a dash, which the firmware's 7-bit text is taken not to have).
//! - **Addressing.** The drives answer to 1 … `channels` (at most 255); `NODEADR n` renumbers one
//!   (the channel numbering of `axis` and `raise_error` stays the original one). A line without
//!   a node number, or with 0, goes to every drive: with one drive on the line it answers; with
//!   several they all carry out a command but their replies would collide, so none is sent, and
//!   a query sent so is counted as malformed. A number no drive has is not answered, counted.
//!   Replies carry no node number.
//! - **Units.** One encoder increment is one simulator step. Speeds are rpm and accelerations
//!   1/s² (revolutions), turned into steps with `ENCRES` increments a revolution (power-on 4096,
//!   a guess): 1 rpm = ENCRES/60 steps/s, 1/s² = ENCRES steps/s².
//! - **Motion.** `LA n` loads an absolute, `LR n` a relative target (relative to the last loaded
//!   target); `M` starts it at `SP`, ramping at `AC` (the simulator ramps both ends at one
//!   rate). `V n` runs at n rpm (clamped to `SP`) until `V0`, which decelerates at `DEC`; a new
//!   command replaces a motion under way. `DI` stops at once. `HO [n]` sets the actual position
//!   (and the target) to n, 0 without argument. `GOHOSEQ` seeks the home switch (status input 1)
//!   at `HOSP` rpm, its sign the direction, and sets the position 0 there; `HA` `HL` `HN` `HP`
//!   `HB` `HD` `CAHOSEQ` `REFIN` are accepted and change nothing here. Power-on: enabled, at 0,
//!   `SP` 3000, `AC`/`DEC` 100, `HOSP` 100.
//! - **Refusals.** Disabled (`DI`), `M`, `GOHOSEQ` and `V` other than `V0` are answered
//!   `Command not available`; during an overtemperature, `Overtemperature - drive disabled`.
//! - **Limits.** `LL n` loads the upper range limit when n ≥ 0, the lower when negative
//!   (power-on ±1 800 000 000); `APL1` applies them: a target outside is clamped to the limit and
//!   a `V` run ends at it. The limit switches are the simulator's: the upper one status input 2
//!   (the fault pin), the lower one input 3; a motion into a switch stops there.
//! - **Notifications.** `NP` without argument sends `p` once a motion started by `M` (before or
//!   after the `NP`) ends on its target; `NP n` once the position reaches or passes n; `NPOFF`
//!   cancels. While one is pending on a moving drive the emulator looks every 10 ms.
//! - **Status.** `OST` bit 8 is the home switch, 9 the upper and 10 the lower limit switch;
//!   bit 16 (position attained) is set at rest on the loaded target in position mode (so at
//!   power-on). `GST` position 4 is the same; positions 5 and 6 follow the `HP` setting (1 when
//!   it is not 0). `GAST` position 2 is 1. `GN`/`GV` answer the actual velocity in rpm.
//! - **`raise_error`** is an overtemperature: the drive disabled, `OST` bit 7, `GFS` position 0,
//!   `TEM` 90 (25 otherwise). `EN` clears it.
//! - **Identification**: `VER` answers `Version 3006.02A`, `GTYP` `MCDC 3006 S`, `GSER` the
//!   node's serial `000000nn`. `GCL` 2000, `GRC` 0.
//! - **Numbers** are 32-bit signed decimals, a sign optional; a fraction after a point is
//!   accepted and dropped. Settings `SP`, `AC`, `DEC`, `ENCRES` are at least 1. The mnemonic is
//!   every letter before the argument, so letters in an argument make an unknown command
//!   (`LAabc`), anything else in it an invalid parameter (`LA12x`).
//! - **Input buffer**: 128 bytes without a `\r` overflow it. XON/XOFF bytes are dropped.

use crate::emulator::axes;
use crate::{Emulator, Lines};
use std::collections::VecDeque;
use std::time::Duration;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

/// Drives on one line at most (node numbers are 1 to 255).
const MAX_NODES: usize = 255;
/// The command terminator.
const CR: &[u8] = b"\r";
/// The reply terminator.
const CRLF: &str = "\r\n";
/// Bytes without a terminator a drive holds before its buffer overflows.
const INPUT_BUFFER: usize = 128;
/// How often a pending position notification is checked during a motion.
const NOTIFY_POLL: Duration = Duration::from_millis(10);

const UNKNOWN: &str = "Unknown command";
const INVALID: &str = "Invalid parameter";
const NOT_AVAILABLE: &str = "Command not available";
const OVERTEMPERATURE: &str = "Overtemperature - drive disabled";
/// The default range limits.
const RANGE: i64 = 1_800_000_000;

/// What the drive does.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Mode {
    Position,
    Velocity,
    Homing,
}

/// A pending `NP`.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Notify {
    Off,
    /// On the target, once a motion started by M has ended (`started`).
    Target {
        started: bool,
    },
    /// When the position reaches `at`, coming from above or below.
    Position {
        at: i64,
        above: bool,
    },
}

/// The outcome of one command on one drive.
#[derive(Debug, PartialEq)]
enum Outcome {
    /// A query's answer, always sent.
    Value(String),
    /// A command carried out: `OK` under ANSW2.
    Done,
    /// A command refused: the text under ANSW2; malformed when the request was.
    Refused(&'static str),
}

/// One drive: its settings and the carriage behind it.
#[derive(Debug)]
struct Node {
    address: u32,
    serial: usize,
    sim: SimAxis,
    answer: u8,
    encres: i64,
    /// SP, rpm.
    speed: i64,
    /// AC, 1/s².
    acceleration: i64,
    /// DEC, 1/s².
    deceleration: i64,
    /// HOSP, rpm, its sign the direction.
    homing_speed: i64,
    upper: i64,
    lower: i64,
    limits_on: bool,
    hp: i64,
    enabled: bool,
    overtemperature: bool,
    target: i64,
    mode: Mode,
    notify: Notify,
}

impl Node {
    fn new(address: u32, sim: SimAxis) -> Self {
        Self {
            address,
            serial: address as usize,
            sim,
            answer: 1,
            encres: 4096,
            speed: 3000,
            acceleration: 100,
            deceleration: 100,
            homing_speed: 100,
            upper: RANGE,
            lower: -RANGE,
            limits_on: false,
            hp: 0,
            enabled: true,
            overtemperature: false,
            target: 0,
            mode: Mode::Position,
            notify: Notify::Off,
        }
    }

    fn position(&self) -> i64 {
        self.sim.status().position.round() as i64
    }

    /// Revolutions (per minute, per second squared) into steps.
    fn steps_per_second(&self, rpm: i64) -> f64 {
        rpm as f64 * self.encres as f64 / 60.0
    }

    fn steps_per_second2(&self, per_s2: i64) -> f64 {
        per_s2 as f64 * self.encres as f64
    }

    fn rpm(&self) -> i64 {
        (self.sim.state().velocity * 60.0 / self.encres as f64).round() as i64
    }

    fn attained(&self) -> bool {
        self.mode == Mode::Position && !self.sim.is_moving() && self.position() == self.target
    }

    fn operation_status(&self) -> u32 {
        let state = self.sim.state();
        let bits = [
            (self.mode == Mode::Homing, 0),
            (self.overtemperature, 7),
            (self.sim.on_home_switch(), 8),
            (state.high_limit, 9),
            (state.low_limit, 10),
            (self.attained(), 16),
        ];
        bits.iter().filter(|(on, _)| *on).map(|(_, bit)| 1u32 << bit).sum()
    }

    fn flags(flags: &[bool]) -> String {
        flags.iter().map(|&on| if on { '1' } else { '0' }).collect()
    }

    /// Homing ended, notifications due: true when a `p` is due.
    fn refresh(&mut self) -> bool {
        if self.mode == Mode::Homing && !self.sim.is_moving() {
            self.mode = Mode::Position;
            self.target = self.position();
        }
        let position = self.position();
        let due = match self.notify {
            Notify::Off => false,
            Notify::Target { started } => started && self.attained(),
            Notify::Position { at, above } => (above && position <= at) || (!above && position >= at),
        };
        if due {
            self.notify = Notify::Off;
        }
        due
    }

    /// A target within the range limits when they apply.
    fn clamp(&self, target: i64) -> i64 {
        if self.limits_on {
            target.clamp(self.lower.min(self.upper), self.upper.max(self.lower))
        } else {
            target
        }
    }

    /// Why the drive cannot move now, if it cannot.
    fn refusal(&self) -> Option<&'static str> {
        if self.overtemperature {
            Some(OVERTEMPERATURE)
        } else if !self.enabled {
            Some(NOT_AVAILABLE)
        } else {
            None
        }
    }

    fn start_positioning(&mut self) {
        self.mode = Mode::Position;
        let (speed, acceleration) = (self.steps_per_second(self.speed), self.steps_per_second2(self.acceleration));
        self.sim.move_to(self.target as f64, false, 0.0, speed, acceleration);
        if let Notify::Target { .. } = self.notify {
            self.notify = Notify::Target { started: true };
        }
    }

    fn run(&mut self, rpm: i64) {
        let rpm = rpm.clamp(-self.speed, self.speed);
        let (velocity, acceleration) = (self.steps_per_second(rpm), self.steps_per_second2(self.acceleration));
        self.mode = Mode::Velocity;
        if self.limits_on {
            let end = if rpm > 0 { self.upper } else { self.lower };
            self.sim.move_to(end as f64, false, 0.0, velocity.abs(), acceleration);
        } else {
            self.sim.move_velocity(0.0, velocity, acceleration);
        }
    }

    fn stop(&mut self) {
        let deceleration = self.steps_per_second2(self.deceleration);
        self.sim.stop(deceleration);
    }
}

/// A serial line with Faulhaber drives at node numbers 1 … n.
#[derive(Debug)]
pub struct FaulhaberEmulator {
    nodes: Vec<Node>,
    lines: Lines,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
    now: Instant,
}

impl FaulhaberEmulator {
    /// A line with `channels` drives (one at least, 255 at most) at node numbers 1 to `channels`.
    pub fn new(channels: usize, mechanics: &SimConfig) -> Self {
        let channels = channels.clamp(1, MAX_NODES);
        let nodes = axes(channels, mechanics).into_iter().zip(1u32..).map(|(sim, a)| Node::new(a, sim)).collect();
        Self { nodes, lines: Lines::new(CR, INPUT_BUFFER), output: VecDeque::new(), malformed: 0, now: Instant::ZERO }
    }

    fn send(&mut self, text: &str) {
        self.output.push_back(format!("{text}{CRLF}").into_bytes());
    }

    /// Advance every drive to `now` and send the notifications that came due.
    fn advance(&mut self, now: Instant) {
        self.now = self.now.max(now);
        for node in &mut self.nodes {
            node.sim.advance(now);
        }
        self.notify_all();
    }

    fn notify_all(&mut self) {
        let mut due = 0;
        for node in &mut self.nodes {
            if node.refresh() && node.answer >= 1 {
                due += 1;
            }
        }
        for _ in 0..due {
            self.send("p");
        }
    }

    /// One line, its node number not yet taken off.
    fn line(&mut self, text: &str) {
        let digits = text.bytes().take_while(u8::is_ascii_digit).count();
        let address = if digits == 0 { Some(0) } else { text[..digits].parse::<u32>().ok().filter(|a| *a <= 255) };
        let Some(address) = address else {
            self.malformed += 1;
            return;
        };
        let (mnemonic, argument) = split(&text[digits..]);
        if address != 0 {
            let Some(node) = self.nodes.iter_mut().find(|n| n.address == address) else {
                self.malformed += 1;
                return;
            };
            let outcome = execute(node, mnemonic, argument);
            let reply = reply(node.answer, &outcome);
            self.count(&outcome);
            if let Some(reply) = reply {
                self.send(&reply);
            }
        } else if self.nodes.len() == 1 {
            let outcome = execute(&mut self.nodes[0], mnemonic, argument);
            let reply = reply(self.nodes[0].answer, &outcome);
            self.count(&outcome);
            if let Some(reply) = reply {
                self.send(&reply);
            }
        } else {
            // Every drive carries it out; their replies would collide, so none is sent.
            let outcomes: Vec<Outcome> = self.nodes.iter_mut().map(|n| execute(n, mnemonic, argument)).collect();
            if outcomes.iter().any(|o| matches!(o, Outcome::Value(_) | Outcome::Refused(UNKNOWN | INVALID))) {
                self.malformed += 1;
            }
        }
        self.notify_all();
    }

    fn count(&mut self, outcome: &Outcome) {
        if matches!(outcome, Outcome::Refused(UNKNOWN | INVALID)) {
            self.malformed += 1;
        }
    }
}

/// The reply the drive sends in answer mode `answer`, if any.
fn reply(answer: u8, outcome: &Outcome) -> Option<String> {
    match outcome {
        Outcome::Value(text) => Some(text.clone()),
        Outcome::Done if answer >= 2 => Some("OK".to_string()),
        Outcome::Refused(text) if answer >= 2 => Some((*text).to_string()),
        _ => None,
    }
}

/// The mnemonic (its letters) and the argument after it.
fn split(command: &str) -> (&str, &str) {
    let letters = command.bytes().take_while(u8::is_ascii_alphabetic).count();
    command.split_at(letters)
}

/// A 32-bit signed decimal, a sign optional, a fraction dropped.
fn number(text: &str) -> Option<i64> {
    let (whole, fraction) = text.split_once('.').unwrap_or((text, ""));
    let digits = whole.strip_prefix(['+', '-']).unwrap_or(whole);
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) || !fraction.bytes().all(|b| b.is_ascii_digit())
    {
        return None;
    }
    whole.strip_prefix('+').unwrap_or(whole).parse::<i32>().ok().map(i64::from)
}

/// Carry out `mnemonic` with `argument` on `node`.
fn execute(node: &mut Node, mnemonic: &str, argument: &str) -> Outcome {
    use Outcome::{Done, Refused, Value};
    let value = |v: i64| Value(v.to_string());
    let arg = number(argument);
    let none = argument.is_empty();
    // A query takes no argument; a setting takes one, at least `min`.
    let setting = |min: i64| arg.filter(|n| *n >= min);
    let query = |v: i64| if none { value(v) } else { Refused(INVALID) };
    match mnemonic {
        "POS" => query(node.position()),
        "TPOS" => query(node.target),
        "GV" | "GN" => query(node.rpm()),
        "OST" => query(i64::from(node.operation_status())),
        "TEM" => query(if node.overtemperature { 90 } else { 25 }),
        "GCL" => query(2000),
        "GRC" => query(0),
        "GNODEADR" => query(i64::from(node.address)),
        "GENCRES" => query(node.encres),
        "GSP" => query(node.speed),
        "GAC" => query(node.acceleration),
        "GDEC" => query(node.deceleration),
        "GHOSP" => query(node.homing_speed),
        "GPL" => query(node.upper),
        "GNL" => query(node.lower),
        "VER" | "GTYP" | "GSER" | "GST" | "GFS" | "GAST" if !none => Refused(INVALID),
        "VER" => Value("Version 3006.02A".to_string()),
        "GTYP" => Value("MCDC 3006 S".to_string()),
        "GSER" => Value(format!("{:08}", node.serial)),
        "GST" => {
            let edge = node.hp != 0;
            let reached = node.attained();
            Value(Node::flags(&[node.mode != Mode::Velocity, false, false, node.enabled, reached, edge, edge]))
        }
        "GFS" => Value(Node::flags(&[node.overtemperature, false, false, false])),
        "GAST" => {
            let state = node.sim.state();
            Value(Node::flags(&[state.high_limit, state.low_limit, true, node.mode == Mode::Homing]))
        }
        "SAVE" | "EEPSAV" if none => Value("EEPROM writing done".to_string()),
        "ANSW" => match arg.filter(|n| (0..=2).contains(n)) {
            Some(mode) => {
                node.answer = mode as u8;
                Done
            }
            None => Refused(INVALID),
        },
        "ENCRES" | "SP" | "AC" | "DEC" => match setting(1) {
            Some(n) => {
                *match mnemonic {
                    "ENCRES" => &mut node.encres,
                    "SP" => &mut node.speed,
                    "AC" => &mut node.acceleration,
                    _ => &mut node.deceleration,
                } = n;
                Done
            }
            None => Refused(INVALID),
        },
        "HOSP" => arg.filter(|n| *n != 0).map_or(Refused(INVALID), |n| {
            node.homing_speed = n;
            Done
        }),
        "LL" => arg.map_or(Refused(INVALID), |n| {
            if n >= 0 {
                node.upper = n;
            } else {
                node.lower = n;
            }
            Done
        }),
        "APL" => arg.filter(|n| (0..=1).contains(n)).map_or(Refused(INVALID), |n| {
            node.limits_on = n == 1;
            Done
        }),
        "NODEADR" => arg.filter(|n| (0..=255).contains(n)).map_or(Refused(INVALID), |n| {
            node.address = n as u32;
            Done
        }),
        "HP" => arg.map_or(Refused(INVALID), |n| {
            node.hp = n;
            Done
        }),
        "POR" | "I" | "PD" => arg.map_or(Refused(INVALID), |n| {
            let gain = match mnemonic {
                "POR" => zmotor_msgs::Gain::Proportional,
                "I" => zmotor_msgs::Gain::Integral,
                _ => zmotor_msgs::Gain::Derivative,
            };
            node.sim.set_gain(gain, n as f64);
            Done
        }),
        // Configuration this emulator accepts and does not model.
        "SOR" | "HB" | "HD" | "HL" | "HA" | "HN" | "DEV" | "CORRIDOR" | "LPC" | "LCC" | "NE" | "PP" => {
            arg.map_or(Refused(INVALID), |_| Done)
        }
        "REFIN" | "CAHOSEQ" | "ADL" | "ADR" | "CONTMOD" | "ENCMOD" | "HALLSPEED" if none => Done,
        "EN" if none => {
            node.enabled = true;
            node.overtemperature = false;
            node.sim.enable(true);
            Done
        }
        "DI" if none => {
            node.enabled = false;
            node.sim.stop(0.0);
            node.sim.enable(false);
            Done
        }
        "LA" | "LR" => arg.map_or(Refused(INVALID), |n| {
            let target = if mnemonic == "LA" { n } else { node.target.saturating_add(n) };
            node.target = node.clamp(target);
            Done
        }),
        "M" if none => match node.refusal() {
            Some(why) => Refused(why),
            None => {
                node.start_positioning();
                Done
            }
        },
        "V" => match arg {
            None => Refused(INVALID),
            Some(0) => {
                node.stop();
                Done
            }
            Some(rpm) => match node.refusal() {
                Some(why) => Refused(why),
                None => {
                    node.run(rpm);
                    Done
                }
            },
        },
        "HO" => match if none { Some(0) } else { arg } {
            Some(n) => {
                node.sim.set_position(n as f64);
                node.target = n;
                Done
            }
            None => Refused(INVALID),
        },
        "GOHOSEQ" if none => match node.refusal() {
            Some(why) => Refused(why),
            None => {
                let speed = node.steps_per_second(node.homing_speed.abs());
                let acceleration = node.steps_per_second2(node.acceleration);
                node.mode = Mode::Homing;
                node.sim.home(node.homing_speed > 0, speed, speed, acceleration);
                Done
            }
        },
        "NP" => {
            if none {
                node.notify = Notify::Target { started: node.sim.is_moving() && node.mode == Mode::Position };
                return Done;
            }
            arg.map_or(Refused(INVALID), |at| {
                node.notify = Notify::Position { at, above: node.position() > at };
                Done
            })
        }
        "NPOFF" if none => {
            node.notify = Notify::Off;
            Done
        }
        // The argument-less commands given an argument.
        "SAVE" | "EEPSAV" | "REFIN" | "CAHOSEQ" | "EN" | "DI" | "M" | "GOHOSEQ" | "NPOFF" | "ADL" | "ADR"
        | "CONTMOD" | "ENCMOD" | "HALLSPEED" => Refused(INVALID),
        _ => Refused(UNKNOWN),
    }
}

impl Emulator for FaulhaberEmulator {
    fn name(&self) -> &'static str {
        "faulhaber_mc"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        self.advance(now);
        for line in self.lines.push(bytes) {
            // Spaces (and a line feed after the last CR) are ignored, case does not matter.
            let Ok(text) = std::str::from_utf8(&line) else {
                self.malformed += 1;
                continue;
            };
            if !text.is_ascii() {
                self.malformed += 1;
                continue;
            }
            let text: String =
                text.chars().filter(|c| !c.is_ascii_whitespace() && !matches!(c, '\u{11}' | '\u{13}')).collect();
            if !text.is_empty() {
                self.line(&text.to_ascii_uppercase());
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
        self.nodes.get_mut(channel.checked_sub(1)?).map(|node| &mut node.sim)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(node) = channel.checked_sub(1).and_then(|i| self.nodes.get_mut(i)) else { return false };
        node.sim.stop(0.0);
        node.sim.enable(false);
        node.overtemperature = true;
        node.enabled = false;
        true
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.advance(now);
    }

    fn poll_timeout(&self) -> Option<Instant> {
        self.nodes
            .iter()
            .filter(|n| n.notify != Notify::Off && n.sim.is_moving())
            .filter_map(|n| match n.notify {
                Notify::Position { .. } => Some(self.now + NOTIFY_POLL),
                _ => n.sim.next_event(),
            })
            .min()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage;

    fn at(ms: u64) -> Instant {
        Instant::ZERO + Duration::from_millis(ms)
    }

    fn send(e: &mut FaulhaberEmulator, now: Instant, line: &str) -> Vec<String> {
        e.handle_input(now, format!("{line}\r").as_bytes());
        std::iter::from_fn(|| e.poll_transmit()).map(|r| String::from_utf8(r).expect("ASCII")).collect()
    }

    fn exchange(e: &mut FaulhaberEmulator, now: Instant, line: &str) -> String {
        let replies = send(e, now, line);
        assert_eq!(replies.len(), 1, "{line}: {replies:?}");
        replies[0].clone()
    }

    /// A line with ANSW2 on every drive.
    fn confirming(channels: usize) -> FaulhaberEmulator {
        let mut e = FaulhaberEmulator::new(channels, &stage());
        assert!(send(&mut e, at(0), "ANSW2").is_empty() || channels == 1);
        e.output.clear();
        e
    }

    #[test]
    fn power_on_identification_and_status() {
        let mut e = FaulhaberEmulator::new(1, &stage());
        assert_eq!(exchange(&mut e, at(0), "VER"), "Version 3006.02A\r\n");
        assert_eq!(exchange(&mut e, at(0), "GTYP"), "MCDC 3006 S\r\n");
        assert_eq!(exchange(&mut e, at(0), "GSER"), "00000001\r\n");
        assert_eq!(exchange(&mut e, at(0), "POS"), "0\r\n");
        assert_eq!(exchange(&mut e, at(0), "TPOS"), "0\r\n");
        // Position attained (bit 16) and the home switch on input 1 (bit 8).
        assert_eq!(exchange(&mut e, at(0), "OST"), "65792\r\n");
        assert_eq!(exchange(&mut e, at(0), "GST"), "1001100\r\n");
        assert_eq!(exchange(&mut e, at(0), "GFS"), "0000\r\n");
        assert_eq!(exchange(&mut e, at(0), "GAST"), "0010\r\n");
        assert_eq!(exchange(&mut e, at(0), "TEM"), "25\r\n");
        assert_eq!(exchange(&mut e, at(0), "GENCRES"), "4096\r\n");
        // ANSW1: commands are not confirmed; the change to ANSW2 is.
        assert!(send(&mut e, at(0), "EN").is_empty());
        assert!(send(&mut e, at(0), "SP 600").is_empty());
        assert_eq!(exchange(&mut e, at(0), "ANSW2"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(0), "EEPSAV"), "EEPROM writing done\r\n");
        assert_eq!(exchange(&mut e, at(0), "gsp"), "600\r\n");
        assert!(send(&mut e, at(0), "ANSW0").is_empty());
        assert_eq!(e.malformed(), 0);
        assert_eq!(e.name(), "faulhaber_mc");
    }

    #[test]
    fn a_loaded_move_runs_and_notifies_its_arrival() {
        let mut e = confirming(1);
        // 600 rpm at 4096/rev = 40 960 steps/s; 100/s² = 409 600 steps/s²: 1.1 s for 40 960.
        for line in ["SP600", "AC100", "LA 40960", "NP", "M"] {
            assert_eq!(exchange(&mut e, at(0), line), "OK\r\n", "{line}");
        }
        assert_eq!(exchange(&mut e, at(500), "OST"), "0\r\n", "under way");
        assert_eq!(exchange(&mut e, at(500), "GN"), "600\r\n");
        assert_eq!(exchange(&mut e, at(500), "TPOS"), "40960\r\n");
        assert_eq!(e.poll_timeout(), Some(Instant::from_secs_f64(1.1)));
        e.handle_timeout(at(1100));
        assert_eq!(e.poll_transmit(), Some(b"p\r\n".to_vec()));
        assert_eq!(e.poll_timeout(), None);
        assert_eq!(exchange(&mut e, at(1200), "POS"), "40960\r\n");
        assert_eq!(exchange(&mut e, at(1200), "OST"), "65536\r\n");
        assert_eq!(exchange(&mut e, at(1200), "GV"), "0\r\n");
        // Relative to the last target; a fraction is dropped.
        assert_eq!(exchange(&mut e, at(1200), "LR-960.5"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(1200), "TPOS"), "40000\r\n");
        assert_eq!(exchange(&mut e, at(1200), "NP 40500"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(1200), "M"), "OK\r\n");
        assert_eq!(e.poll_timeout(), Some(at(1210)));
        assert_eq!(send(&mut e, at(1300), "POS"), ["p\r\n", "40000\r\n"]);
    }

    #[test]
    fn a_velocity_run_stops_on_v0_and_at_a_limit_switch() {
        let mut e = confirming(1);
        exchange(&mut e, at(0), "SP6000");
        exchange(&mut e, at(0), "DEC10");
        assert_eq!(exchange(&mut e, at(0), "V-600"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(1000), "GV"), "-600\r\n");
        assert_eq!(exchange(&mut e, at(1000), "GST"), "0001000\r\n", "velocity control");
        assert_eq!(exchange(&mut e, at(1000), "V 0"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(1500), "GN"), "-300\r\n", "decelerating at 10/s²");
        assert_eq!(exchange(&mut e, at(2000), "GN"), "0\r\n");
        assert_eq!(exchange(&mut e, at(2000), "OST"), "0\r\n", "no target in velocity mode");
        // 6000 rpm clamps to SP; the upper switch at 200 000 stops it.
        assert_eq!(exchange(&mut e, at(2000), "V9000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(5000), "POS"), "200000\r\n");
        assert_eq!(exchange(&mut e, at(5000), "GAST"), "1010\r\n");
        assert_eq!(exchange(&mut e, at(5000), "OST"), "512\r\n");
        assert_eq!(exchange(&mut e, at(5000), "LR-1000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(5000), "TPOS"), "-1000\r\n", "from the last target, 0");
    }

    #[test]
    fn homing_and_position_definition() {
        let mut e = confirming(1);
        assert_eq!(exchange(&mut e, at(0), "HO-5000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(0), "POS"), "-5000\r\n");
        assert_eq!(exchange(&mut e, at(0), "LA 35000"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(0), "M"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(2000), "POS"), "35000\r\n");
        assert_eq!(exchange(&mut e, at(2000), "HOSP-600"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(2000), "GOHOSEQ"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(2100), "OST"), "1\r\n", "homing running");
        assert_eq!(exchange(&mut e, at(2100), "GAST"), "0011\r\n");
        assert_eq!(exchange(&mut e, at(4000), "POS"), "0\r\n");
        assert_eq!(exchange(&mut e, at(4000), "OST"), "65792\r\n");
        assert_eq!(exchange(&mut e, at(4000), "HO"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(4000), "POS"), "0\r\n");
    }

    #[test]
    fn range_limits_apply_when_activated() {
        let mut e = confirming(1);
        exchange(&mut e, at(0), "SP6000");
        for line in ["LL10000", "LL-10000", "APL1", "LA50000", "M"] {
            assert_eq!(exchange(&mut e, at(0), line), "OK\r\n", "{line}");
        }
        assert_eq!(exchange(&mut e, at(0), "GPL"), "10000\r\n");
        assert_eq!(exchange(&mut e, at(0), "GNL"), "-10000\r\n");
        assert_eq!(exchange(&mut e, at(0), "TPOS"), "10000\r\n");
        assert_eq!(exchange(&mut e, at(2000), "POS"), "10000\r\n");
        assert_eq!(exchange(&mut e, at(2000), "V-600"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(4000), "POS"), "-10000\r\n", "the run ends at the limit");
        assert_eq!(exchange(&mut e, at(4000), "APL0"), "OK\r\n");
        exchange(&mut e, at(4000), "LA50000");
        exchange(&mut e, at(4000), "M");
        assert_eq!(exchange(&mut e, at(8000), "POS"), "50000\r\n");
        assert_eq!(exchange(&mut e, at(8000), "APL2"), "Invalid parameter\r\n");
    }

    #[test]
    fn errors_refusals_and_unknown_commands() {
        let mut e = confirming(2);
        assert!(e.raise_error(2));
        assert_eq!(exchange(&mut e, at(0), "2OST"), "65920\r\n", "overtemperature, bit 7");
        assert_eq!(exchange(&mut e, at(0), "2GFS"), "1000\r\n");
        assert_eq!(exchange(&mut e, at(0), "2TEM"), "90\r\n");
        assert_eq!(exchange(&mut e, at(0), "2M"), "Overtemperature - drive disabled\r\n");
        assert_eq!(exchange(&mut e, at(0), "2EN"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(0), "2GFS"), "0000\r\n");
        assert_eq!(exchange(&mut e, at(0), "1DI"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(0), "1GST"), "1000100\r\n");
        assert_eq!(exchange(&mut e, at(0), "1M"), "Command not available\r\n");
        assert_eq!(exchange(&mut e, at(0), "1GOHOSEQ"), "Command not available\r\n");
        assert_eq!(exchange(&mut e, at(0), "1V0"), "OK\r\n");
        assert_eq!(e.malformed(), 0, "refusals are not the client's fault");
        for (line, reply) in [
            ("1XYZ", "Unknown command"),
            ("1LAabc", "Unknown command"),
            ("1LA12x", "Invalid parameter"),
            ("1LA", "Invalid parameter"),
            ("1LA3000000000", "Invalid parameter"),
            ("1ANSW7", "Invalid parameter"),
            ("1SP0", "Invalid parameter"),
            ("1POS5", "Invalid parameter"),
            ("1M1", "Invalid parameter"),
            ("1-5", "Unknown command"),
        ] {
            assert_eq!(exchange(&mut e, at(0), line), format!("{reply}\r\n"), "{line}");
        }
        assert_eq!(e.malformed(), 10);
        // Under ANSW1 a failed command is silent, still counted.
        assert!(send(&mut e, at(0), "1ANSW1").is_empty());
        assert!(send(&mut e, at(0), "1XYZ").is_empty());
        assert_eq!(e.malformed(), 11);
        assert!(!e.raise_error(0) && !e.raise_error(3));
    }

    #[test]
    fn node_numbers_and_broadcasts() {
        let mut e = FaulhaberEmulator::new(3, &stage());
        assert_eq!(exchange(&mut e, at(0), "2GNODEADR"), "2\r\n");
        assert!(send(&mut e, at(0), "2 la 100").is_empty(), "ANSW1: not confirmed");
        assert_eq!(exchange(&mut e, at(0), "2tpos"), "100\r\n");
        assert_eq!(exchange(&mut e, at(0), "1TPOS"), "0\r\n");
        for line in ["4POS", "256POS", "POS"] {
            assert!(send(&mut e, at(0), line).is_empty(), "{line}");
        }
        assert_eq!(e.malformed(), 3, "no such drive, and a query to all");
        // A command to all is carried out by all, unanswered.
        assert!(send(&mut e, at(0), "ANSW2").is_empty());
        assert!(send(&mut e, at(0), "V600").is_empty());
        assert_eq!(exchange(&mut e, at(1000), "1GN"), "600\r\n");
        assert_eq!(exchange(&mut e, at(1000), "3GN"), "600\r\n");
        assert!(send(&mut e, at(1000), "V0").is_empty());
        assert_eq!(e.malformed(), 3);
        assert_eq!(exchange(&mut e, at(1000), "3NODEADR7"), "OK\r\n");
        assert_eq!(exchange(&mut e, at(1000), "7GNODEADR"), "7\r\n");
        assert!(send(&mut e, at(1000), "3POS").is_empty());
        assert_eq!(e.malformed(), 4);
        assert!(e.axis(3).is_some(), "channels keep their first numbers");
        // Each drive notifies for itself.
        exchange(&mut e, at(2000), "1LA100");
        exchange(&mut e, at(2000), "1NP");
        assert_eq!(send(&mut e, at(2000), "1M"), ["OK\r\n"]);
        assert_eq!(send(&mut e, at(3000), "1POS"), ["p\r\n", "100\r\n"]);
    }

    #[test]
    fn lines_come_whole_from_any_pieces_and_garbage_is_counted() {
        let mut e = FaulhaberEmulator::new(1, &stage());
        e.handle_input(at(0), b"1PO");
        assert!(e.poll_transmit().is_none());
        e.handle_input(at(0), b"S\r\n\x11T");
        e.handle_input(at(0), b"POS\r\xff\r\r");
        let replies: Vec<Vec<u8>> = std::iter::from_fn(|| e.poll_transmit()).collect();
        assert_eq!(replies, [b"0\r\n".to_vec(), b"0\r\n".to_vec()]);
        assert_eq!(e.malformed(), 1, "the byte that is not ASCII");
        e.handle_input(at(0), &[b'7'; 129]);
        assert_eq!(e.malformed(), 2, "an overflowing input buffer counts");
        assert_eq!(exchange(&mut e, at(0), "0POS"), "0\r\n", "node 0 reaches the single drive");
        assert!(e.axis(0).is_none() && e.axis(1).is_some() && e.axis(2).is_none());
        assert_eq!(FaulhaberEmulator::new(0, &stage()).nodes.len(), 1);
        assert_eq!(FaulhaberEmulator::new(300, &stage()).nodes.len(), 255);
    }
}
