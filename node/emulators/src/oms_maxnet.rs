//! An Oregon Micro Systems (Pro-Dex) MAXnet, reached over Ethernet (TCP port 23): the MAX
//! family's two- and three-letter ASCII commands, several to a line, axes X Y Z T U V R S W K
//! addressed by `AX` … `AK` (single-axis mode) or all at once by `AA`/`AM` (values comma
//! separated); queries answered with a line ended `\n\r`, no echo, no prompt; status flags
//! notified as `%000 SSSSSSSS`. One simulator step a motor step.
//!
//! # Witnesses
//!
//! 1. Pro-Dex OMS "MAX Command Reference Manual", MAX family, Rev. F (2012, 3301-0000001; as
//!    published on pdf.directindustry.com and fdocuments.in). Only pages 1-1 and 1-11 could be
//!    read: commands are two or three ASCII characters, upper or lower case; a numeric operand
//!    follows the command at once and is ended by a space, CR or `;`; other commands need no
//!    terminator; multi-axis modes take one comma-separated parameter an axis, omitted ones
//!    unaffected, the list ended early by `;` (`MR,#,#;`); commands are queued or immediate, the
//!    X axis queue holding 2559 units; FL flushes a queue and RQC reports it; the axis status
//!    commands are EA (encoder status), QA (query axis status), QI (query interrupt status), RA
//!    (report axis status) and RI (report axes status). The command pages themselves (formats,
//!    ranges, defaults, WY's text) could not be read.
//! 2. OMS "MAXnet User's Manual", §3.1–3.2 (as published on manualshive.com): the host talks to
//!    the MAXnet over Ethernet or RS-232; its status flags are the axis done, over-travel limit
//!    and encoder slip flags of X … K and a command error flag; when a flag is set the MAXnet
//!    sends, unasked, `%000 SSSSSSSS`, the flag word in eight hexadecimal digits: done X–S
//!    0x01–0x80, W 0x02000000, K 0x04000000; limit X–S 0x100–0x8000, W 0x08000000, K
//!    0x10000000; slip X–S 0x10000–0x800000, W 0x20000000, K 0x40000000; command error
//!    0x01000000. Query commands (RP, RE …) answer ASCII text. The rest could not be read.
//! 3. The EPICS driver motorOmsAsyn (commit c0ae4c7, 2026-01-30: `omsMAXnet.cpp`,
//!    `omsBaseController.cpp`, `omsBaseAxis.cpp`, `README_MAXnet`): TCP port 23; replies end
//!    `\n\r` (input EOS), commands `\n`; a reply's leading CR, LF or 0x06 is skipped; a line
//!    holding `000 0` is a notification, `000 01` the command error flag. At connection it sends
//!    `WY` and reads the firmware from `ver:[B|S]major.minor.revision,` (1.30 at least; 1.33.4
//!    for Ethernet), then `IC;`, `AM SA;`, the user's init string, `AA RP;` (the commas give the
//!    number of axes), and for each axis `AX PS?` (`=O` open-loop stepper, `=E` stepper with
//!    encoder, `=M` servo) and `AX LT?` (`=l` or `=h`, the limits' active level). It polls
//!    `AM;RI;` (`MDNN,MDNN,PNLN,…`: the first character P or M, 5·n − 1 characters at least, a
//!    `D` meaning done), `AM PP;` and `AM PE;` (positions and encoders, comma separated),
//!    `AM;CL?;` (fields `on`), `AM;RV;`, `AM;EA;` (character 2 `S` is a slip), `AM;QL;`
//!    (hexadecimal: bit i the low limit of axis i, bit i + 8 its high limit, W and K at 16/17
//!    and 24/25, read against the LT? level) and, from firmware 1.33, `#WS` (`=0` when the
//!    watchdog is fine). It moves with `AX;AC#;VL#;VB#;MA#;GO;ID;` (VB before VL when VL falls
//!    below the last VB, VB kept below VL), homes with `AX;AC#;VL#;VB#;HR;MA0;GO;ID;` (HM
//!    forward), jogs with `AX AC#; JG#;`, stops with `AX AC#; ST ID;`, sets positions with
//!    `AX LP#;`, `AX LO#;` and `AX LPE#;`, gains with `AX KP%f;`, closed loop with `CL1`/`CL0`
//!    (`HN`/`HF` before 1.30), and may read `AM;RQC` and send `AX;FL;`. It refuses positions
//!    beyond ±67 000 000, speeds beyond 4 000 000, accelerations beyond 8 000 000.
//! 4. The older EPICS driver motorOms (commit a8b3c4b, 2026-02-09: `drvMAXv.cc`, `devOmsCom.cc`,
//!    `drvOmsPC68.cc`, `MAX_trajectoryScan.st`, `README`), same language on the MAXv: QA's four
//!    characters are the direction (P/M), done (D/N), over-travel (L/N, the switch on the side
//!    of the direction) and home (H/N); EA's are slip enable, position maintenance enable, slip
//!    detected (S), dead band, home (H); `EA` of an axis without encoder is a command error;
//!    `CA` clears an axis's done flag; `QI` answers `MDNN,…,PNNN,`; the MAXv identifies as
//!    `MAXv-8000 ver:1.31, s/n:000274, FPGA:B1:A6`; `LL` (the default) and `LH` set the limits'
//!    active level; `PSO`, `PSE`, `PSM` the axis type. The PC68's serial framing (`\n\r` around
//!    a reply, `#` `$` `@` `!` before it for a command error, slip, over-travel, done) is that
//!    board's, not the MAXnet's.
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Framing**: a reply is its text then `\n\r`, one line a query, in the order asked;
//!   nothing is echoed, no prompt. Input lines end with LF or CR; within them commands are
//!   separated by `;`, spaces or nothing at all (`AXRP`). A notification is a line of its own
//!   (`%000 01000000\n\r`) carrying the flags just set, queued before the replies that follow.
//!   Lines hold 512 bytes at most.
//! - **Identification**: `WY` answers `MAXnet-<axes>000 ver:1.33.4, s/n:000001` (the MAXv's
//!   pattern); `#WS` answers `=0`.
//! - **Modes**: at power-up single-axis mode on X. `AA` and `AM` behave alike here (every axis,
//!   values comma separated, as many as the axes at most); queries then answer every axis,
//!   comma separated, no trailing comma (witness 3's RI). `RI`, `QI`, `QL`, `PP`, `PE` always
//!   answer every axis. Selecting an axis the board lacks is a command error.
//! - **Queue**: MA/MR set a target; GO (or GD) queues the move to it and clears the done flag;
//!   HM/HR (operand optional: the position the switch is given, 0 if none) and LP/LO queue; ID
//!   queues setting the done flag (and its notification). Each axis runs its queue in order as
//!   its motions end, each queued motion at the VL, VB, AC in force when it was queued. ST, SA,
//!   KL, JG, FL flush the queue. A motion stopped by a limit switch flushes it too (the ID queued
//!   behind it never runs): the limit flag is notified instead, at the move's planned end or the
//!   next bytes received, whichever comes first (a jog's, at the next bytes).
//! - **Status flags**: QA and QI read the done flags; RA and RI read and clear them; CA and IC
//!   clear them (IC the slip flags too). The over-travel character is L
//!   while the switch on the side of the last motion's direction is active; the home character
//!   H while the carriage is on the home switch.
//! - **Motion**: a move ramps from VB to VL at AC and back; ST (and SA, in AA/AM mode ST) brakes
//!   at AC; KL halts every axis at once. JG runs at once at its signed speed (JG0 brakes) until
//!   ST or a switch. A home goes to the switch at VL from whichever side (HM and HR alike: the
//!   simulator's search finds it), and the counter reads the HM/HR operand there. LP/LO load the
//!   position counter, LPE the encoder's.
//! - **Numbers**: integers, a sign optional. Positions within ±67 108 863 (2^26 − 1, past
//!   witness 3's bound); VL 1 to 4 000 000 and above VB; VB 0 to 4 000 000 and below VL; AC 1
//!   to 8 000 000; JG within ±4 000 000; KP, KI, KD decimals from 0 below 32 768; ER two
//!   positive integers; CL 0 or 1. Anything else is refused, never clamped.
//! - **Command errors**: an unknown command, a bad or missing operand, a number out of range,
//!   too many values or an axis not installed set the command error flag and are notified
//!   (`%000 01000000`), nothing else answered, and counted as malformed; the rest of the line
//!   still runs. `EA` of an open-loop axis in single-axis mode is a command error but not
//!   malformed (witness 4 probes with it).
//! - **Power-up**: every axis at 0, at rest, PSO (open-loop stepper, no encoder: RE and PE read
//!   the loaded encoder value, 0), LL, closed loop off, VL 200 000, VB 0, AC 2 000 000, flags
//!   clear, direction P. `CL?` answers `=on`/`=off` for one axis, `on`/`off` fields for
//!   all; `PS?` `=O`/`=E`/`=M`; `LT?` `=l`/`=h` (also `?PS`, `?LS`, `?PM`, the old forms).
//!   `QL` answers eight hexadecimal digits of the inputs' levels (an inactive switch reads high
//!   under LL, low under LH). `EA` answers five characters an axis: slip detection and
//!   position maintenance both disabled (`DD`), `S` or `N`, `N`, `H` or `N`. `RQC` answers 2559
//!   less one unit a queued step. `RV` the signed speed in steps/s.
//! - **`raise_error`**: an encoder slip on that axis: it halts at once, its queue is flushed,
//!   the slip flag is notified and EA shows `S` until IC.
//! - **Not carried out**: coordinated motion, user units, I/O, programs; ER, KP, KI, KD are
//!   checked, taken and change nothing.

use crate::emulator::axes;
use crate::{Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

/// The axes' letters, channel 0 first.
const LETTERS: &[u8; 10] = b"XYZTUVRSWK";
const LF: &[u8] = b"\n";
const REPLY_END: &str = "\n\r";
const INPUT_BUFFER: usize = 512;
const FIRMWARE: &str = "ver:1.33.4, s/n:000001";
const POSITION_MAX: i64 = 67_108_863;
const SPEED_MAX: i64 = 4_000_000;
const ACCEL_MAX: i64 = 8_000_000;
const GAIN_LIMIT: f64 = 32_768.0;
const QUEUE_UNITS: usize = 2559;
const COMMAND_ERROR_FLAG: u32 = 0x0100_0000;

/// The done, limit and slip flag of axis `i` in the notification word.
fn done_flag(i: usize) -> u32 {
    if i < 8 {
        1 << i
    } else {
        1 << (25 + i - 8)
    }
}

fn limit_flag(i: usize) -> u32 {
    if i < 8 {
        1 << (8 + i)
    } else {
        1 << (27 + i - 8)
    }
}

fn slip_flag(i: usize) -> u32 {
    if i < 8 {
        1 << (16 + i)
    } else {
        1 << (29 + i - 8)
    }
}

/// A command error; `malformed` when the host should have known better.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Refusal {
    malformed: bool,
}

const BAD: Refusal = Refusal { malformed: true };
const NOT_NOW: Refusal = Refusal { malformed: false };

/// PSO, PSE, PSM.
#[derive(Clone, Copy, Debug, PartialEq)]
enum AxisType {
    OpenLoop,
    Encoder,
    Servo,
}

/// The speeds a queued motion runs at, as set when it was queued.
#[derive(Clone, Copy, Debug)]
struct Profile {
    speed: f64,
    base: f64,
    accel: f64,
}

/// A queued command.
#[derive(Clone, Copy, Debug)]
enum Step {
    Move { value: f64, relative: bool, profile: Profile },
    Home { value: f64, profile: Profile },
    Load(f64),
    Done,
}

/// The motion under way.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Running {
    Move,
    Home(f64),
    Jog,
}

/// One axis: its simulator and what the board keeps of it.
struct Axis {
    sim: SimAxis,
    speed: i64,
    base: i64,
    accel: i64,
    /// MA/MR's target awaiting GO: the value and whether it is relative.
    target: Option<(f64, bool)>,
    queue: VecDeque<Step>,
    running: Option<Running>,
    positive: bool,
    done: bool,
    slip: bool,
    axis_type: AxisType,
    active_high: bool,
    closed_loop: bool,
    /// The encoder's reading less the position (with an encoder), or its loaded value (without).
    encoder_offset: f64,
}

impl Axis {
    fn new(sim: SimAxis) -> Self {
        Self {
            sim,
            speed: 200_000,
            base: 0,
            accel: 2_000_000,
            target: None,
            queue: VecDeque::new(),
            running: None,
            positive: true,
            done: false,
            slip: false,
            axis_type: AxisType::OpenLoop,
            active_high: false,
            closed_loop: false,
            encoder_offset: 0.0,
        }
    }

    fn position(&self) -> i64 {
        self.sim.status().position.round() as i64
    }

    fn encoder(&self) -> i64 {
        let offset = self.encoder_offset.round() as i64;
        match self.axis_type {
            AxisType::OpenLoop => offset,
            AxisType::Encoder | AxisType::Servo => self.position() + offset,
        }
    }

    fn profile(&self) -> Profile {
        Profile { speed: self.speed as f64, base: self.base as f64, accel: self.accel as f64 }
    }

    /// QA's four characters: direction, done, over-travel, home.
    fn status(&self) -> String {
        let state = self.sim.state();
        let limit = if self.positive { state.high_limit } else { state.low_limit };
        let pick = |on: bool, yes: char, no: char| if on { yes } else { no };
        [
            pick(self.positive, 'P', 'M'),
            pick(self.done, 'D', 'N'),
            pick(limit, 'L', 'N'),
            pick(self.sim.on_home_switch(), 'H', 'N'),
        ]
        .iter()
        .collect()
    }

    /// EA's five characters.
    fn encoder_status(&self) -> String {
        let slip = if self.slip { 'S' } else { 'N' };
        let home = if self.sim.on_home_switch() { 'H' } else { 'N' };
        format!("DD{slip}N{home}")
    }

    /// The levels of the low and high limit inputs.
    fn limit_levels(&self) -> (bool, bool) {
        let state = self.sim.state();
        (state.low_limit == self.active_high, state.high_limit == self.active_high)
    }

    /// Flushed queue, motion braked at `accel` (at once when 0).
    fn stop(&mut self, accel: f64) {
        self.queue.clear();
        if self.sim.is_moving() {
            self.sim.stop(accel);
        }
        self.running = None;
    }

    fn jog(&mut self, speed: i64) {
        self.queue.clear();
        if speed == 0 {
            self.stop(self.accel as f64);
            return;
        }
        self.positive = speed > 0;
        self.sim.move_velocity(self.base as f64, speed as f64, self.accel as f64);
        self.running = Some(Running::Jog);
    }

    /// Start `step`; the flags it sets.
    fn start(&mut self, step: Step, index: usize) -> u32 {
        match step {
            Step::Move { value, relative, profile } => {
                let from = self.sim.status().position;
                let distance = if relative { value } else { value - from };
                if distance != 0.0 {
                    self.positive = distance > 0.0;
                }
                self.sim.move_to(value, relative, profile.base, profile.speed, profile.accel);
                self.running = Some(Running::Move);
            }
            Step::Home { value, profile } => {
                let physical = self.sim.physical_position();
                let switch = self.sim.config().home_switch;
                if physical != switch {
                    self.positive = switch > physical;
                }
                self.sim.home(self.positive, profile.base, profile.speed, profile.accel);
                self.running = Some(Running::Home(value));
            }
            Step::Load(value) => self.sim.set_position(value),
            Step::Done => {
                self.done = true;
                return done_flag(index);
            }
        }
        0
    }

    /// The motion under way has ended: a home's counter value set, a limit's flag raised.
    fn finish(&mut self, index: usize) -> u32 {
        let Some(running) = self.running.take() else { return 0 };
        let state = self.sim.state();
        if (self.positive && state.high_limit) || (!self.positive && state.low_limit) {
            self.queue.clear();
            return limit_flag(index);
        }
        if let Running::Home(value) = running {
            self.sim.set_position(value);
        }
        0
    }

    /// Time runs to `now`: each motion ends at its own instant and the queue moves on from it.
    fn catch_up(&mut self, index: usize, now: Instant) -> u32 {
        let mut flags = 0;
        loop {
            match self.sim.next_event().filter(|end| *end <= now && self.sim.is_moving()) {
                Some(end) => self.sim.advance(end),
                None => self.sim.advance(now),
            }
            if self.sim.is_moving() {
                return flags;
            }
            flags |= self.finish(index);
            match self.queue.pop_front() {
                Some(step) => flags |= self.start(step, index),
                None => return flags,
            }
        }
    }
}

/// A MAXnet with axes X … K (as many as asked) behind its Ethernet port.
pub struct MaxnetEmulator {
    axes: Vec<Axis>,
    lines: Lines,
    output: VecDeque<Vec<u8>>,
    /// The axis single-axis mode addresses; None in AA/AM mode.
    selected: Option<usize>,
    now: Instant,
    malformed: usize,
}

impl MaxnetEmulator {
    /// A board with `axes_count` axes (1 to 10) on `mechanics`, at power-up.
    pub fn new(axes_count: usize, mechanics: &SimConfig) -> Self {
        let axes_count = axes_count.clamp(1, LETTERS.len());
        Self {
            axes: axes(axes_count, mechanics).into_iter().map(Axis::new).collect(),
            lines: Lines::new(LF, INPUT_BUFFER),
            output: VecDeque::new(),
            selected: Some(0),
            now: Instant::ZERO,
            malformed: 0,
        }
    }

    fn reply(&mut self, text: &str) {
        self.output.push_back(format!("{text}{REPLY_END}").into_bytes());
    }

    fn notify(&mut self, flags: u32) {
        if flags != 0 {
            self.reply(&format!("%000 {flags:08X}"));
        }
    }

    /// Every axis brought to `now`, the flags set on the way notified.
    fn catch_up(&mut self) {
        let now = self.now;
        let flags = self.axes.iter_mut().enumerate().fold(0, |flags, (i, axis)| flags | axis.catch_up(i, now));
        self.notify(flags);
    }

    /// The axes a command addresses.
    fn addressed(&self) -> Vec<usize> {
        match self.selected {
            Some(i) => vec![i],
            None => (0..self.axes.len()).collect(),
        }
    }

    /// One value an addressed axis, omitted ones left out (multi-axis), one required (single).
    fn values<T>(&self, operand: &str, parse: impl Fn(&str) -> Option<T>) -> Result<Vec<(usize, T)>, Refusal> {
        match self.selected {
            Some(i) => Ok(vec![(i, parse(operand).ok_or(BAD)?)]),
            None => {
                let fields: Vec<&str> = if operand.is_empty() { Vec::new() } else { operand.split(',').collect() };
                if fields.len() > self.axes.len() {
                    return Err(BAD);
                }
                let present = fields.into_iter().enumerate().filter(|(_, field)| !field.is_empty());
                present.map(|(i, field)| parse(field).map(|v| (i, v)).ok_or(BAD)).collect()
            }
        }
    }

    /// Values if given, else `default` for every addressed axis.
    fn optional_values(&self, operand: &str, default: f64) -> Result<Vec<(usize, f64)>, Refusal> {
        if operand.is_empty() {
            return Ok(self.addressed().into_iter().map(|i| (i, default)).collect());
        }
        self.values(operand, position)
    }

    /// One answer an addressed axis, comma separated.
    fn answer(&mut self, each: impl Fn(&Axis) -> String) {
        let text: Vec<String> = self.addressed().into_iter().map(|i| each(&self.axes[i])).collect();
        self.reply(&text.join(","));
    }

    /// One answer every axis, comma separated.
    fn answer_all(&mut self, each: impl Fn(&Axis) -> String) {
        let text: Vec<String> = self.axes.iter().map(each).collect();
        self.reply(&text.join(","));
    }

    /// Carry out one command (its mnemonic, `?` form and operand).
    fn command(&mut self, name: &str, query: bool, operand: &str) -> Result<(), Refusal> {
        let no_operand = if operand.is_empty() && !query { Ok(()) } else { Err(BAD) };
        let plain = if query { Err(BAD) } else { Ok(()) };
        if let Some(letter) = name.strip_prefix('A').filter(|l| l.len() == 1 && LETTERS.contains(&l.as_bytes()[0])) {
            no_operand?;
            let i = LETTERS.iter().position(|l| *l == letter.as_bytes()[0]).filter(|i| *i < self.axes.len());
            self.selected = Some(i.ok_or(BAD)?);
            return Ok(());
        }
        match name {
            "AA" | "AM" => {
                no_operand?;
                self.selected = None;
            }
            "WY" => {
                no_operand?;
                self.reply(&format!("MAXnet-{}000 {FIRMWARE}", self.axes.len()));
            }
            "#WS" => {
                no_operand?;
                self.reply("=0");
            }
            "IC" => {
                no_operand?;
                for axis in &mut self.axes {
                    (axis.done, axis.slip) = (false, false);
                }
            }
            "KL" | "SA" => {
                no_operand?;
                for axis in &mut self.axes {
                    let accel = if name == "KL" { 0.0 } else { axis.accel as f64 };
                    axis.stop(accel);
                }
            }
            "ST" => {
                no_operand?;
                for i in self.addressed() {
                    let accel = self.axes[i].accel as f64;
                    self.axes[i].stop(accel);
                }
            }
            "FL" => {
                no_operand?;
                self.addressed().into_iter().for_each(|i| self.axes[i].queue.clear());
            }
            "MA" | "MR" => {
                plain?;
                for (i, value) in self.values(operand, position)? {
                    self.axes[i].target = Some((value, name == "MR"));
                }
            }
            "GO" | "GD" => {
                no_operand?;
                for i in self.addressed() {
                    let axis = &mut self.axes[i];
                    if let Some((value, relative)) = axis.target.take() {
                        let profile = axis.profile();
                        axis.queue.push_back(Step::Move { value, relative, profile });
                        axis.done = false;
                    }
                }
            }
            "ID" => {
                no_operand?;
                self.addressed().into_iter().for_each(|i| self.axes[i].queue.push_back(Step::Done));
            }
            "CA" => {
                no_operand?;
                self.addressed().into_iter().for_each(|i| self.axes[i].done = false);
            }
            "JG" => {
                plain?;
                for (i, speed) in self.values(operand, |t| within(t, -SPEED_MAX, SPEED_MAX))? {
                    self.axes[i].jog(speed);
                }
            }
            "HM" | "HR" => {
                plain?;
                for (i, value) in self.optional_values(operand, 0.0)? {
                    let axis = &mut self.axes[i];
                    let profile = axis.profile();
                    axis.queue.push_back(Step::Home { value, profile });
                }
            }
            "LP" | "LO" => {
                plain?;
                for (i, value) in self.values(operand, position)? {
                    self.axes[i].queue.push_back(Step::Load(value));
                }
            }
            "LPE" => {
                plain?;
                for (i, value) in self.values(operand, position)? {
                    let axis = &mut self.axes[i];
                    axis.encoder_offset = match axis.axis_type {
                        AxisType::OpenLoop => value,
                        AxisType::Encoder | AxisType::Servo => value - axis.position() as f64,
                    };
                }
            }
            "VL" | "VB" | "AC" => {
                plain?;
                let (min, max) = match name {
                    "VL" => (1, SPEED_MAX),
                    "VB" => (0, SPEED_MAX),
                    _ => (1, ACCEL_MAX),
                };
                let values = self.values(operand, |t| within(t, min, max))?;
                let fits = |axis: &Axis, v: i64| match name {
                    "VL" => v > axis.base,
                    "VB" => v < axis.speed,
                    _ => true,
                };
                if values.iter().any(|(i, v)| !fits(&self.axes[*i], *v)) {
                    return Err(BAD);
                }
                for (i, v) in values {
                    let axis = &mut self.axes[i];
                    *match name {
                        "VL" => &mut axis.speed,
                        "VB" => &mut axis.base,
                        _ => &mut axis.accel,
                    } = v;
                }
            }
            // Taken, and nothing here for them to change.
            "KP" | "KI" | "KD" => {
                plain?;
                self.values(operand, decimal_gain)?;
            }
            "ER" => {
                let (Some(_), false) = (self.selected, query) else { return Err(BAD) };
                let (a, b) = operand.split_once(',').ok_or(BAD)?;
                within(a, 1, i64::from(i32::MAX)).zip(within(b, 1, i64::from(i32::MAX))).ok_or(BAD)?;
            }
            "CL" if query => {
                no_operand_query(operand)?;
                match self.selected {
                    Some(i) => {
                        let on = self.axes[i].closed_loop;
                        self.reply(if on { "=on" } else { "=off" });
                    }
                    None => self.answer(|axis| (if axis.closed_loop { "on" } else { "off" }).to_string()),
                }
            }
            "CL" => {
                for (i, on) in self.values(operand, |t| within(t, 0, 1))? {
                    self.axes[i].closed_loop = on == 1;
                }
            }
            "HN" | "HF" => {
                no_operand?;
                self.addressed().into_iter().for_each(|i| self.axes[i].closed_loop = name == "HN");
            }
            "PSO" | "PSE" | "PSM" => {
                no_operand?;
                let axis_type = match name {
                    "PSO" => AxisType::OpenLoop,
                    "PSE" => AxisType::Encoder,
                    _ => AxisType::Servo,
                };
                self.addressed().into_iter().for_each(|i| self.axes[i].axis_type = axis_type);
            }
            "LL" | "LH" => {
                no_operand?;
                self.addressed().into_iter().for_each(|i| self.axes[i].active_high = name == "LH");
            }
            "PS" | "?PS" if query || name == "?PS" => {
                no_operand_query(operand)?;
                self.answer(|axis| {
                    let letter = match axis.axis_type {
                        AxisType::OpenLoop => 'O',
                        AxisType::Encoder => 'E',
                        AxisType::Servo => 'M',
                    };
                    format!("={letter}")
                });
            }
            "LT" | "?LS" if query || name == "?LS" => {
                no_operand_query(operand)?;
                self.answer(|axis| (if axis.active_high { "=h" } else { "=l" }).to_string());
            }
            "?PM" => {
                no_operand_query(operand)?;
                self.answer(|axis| (if axis.closed_loop { "=on" } else { "=off" }).to_string());
            }
            "RP" => {
                no_operand?;
                self.answer(|axis| axis.position().to_string());
            }
            "RE" => {
                no_operand?;
                self.answer(|axis| axis.encoder().to_string());
            }
            "RV" => {
                no_operand?;
                self.answer(|axis| (axis.sim.status().velocity.round() as i64).to_string());
            }
            "PP" => {
                no_operand?;
                self.answer_all(|axis| axis.position().to_string());
            }
            "PE" => {
                no_operand?;
                self.answer_all(|axis| axis.encoder().to_string());
            }
            "QA" | "RA" => {
                no_operand?;
                self.answer(Axis::status);
                if name == "RA" {
                    self.addressed().into_iter().for_each(|i| self.axes[i].done = false);
                }
            }
            "QI" | "RI" => {
                no_operand?;
                self.answer_all(Axis::status);
                if name == "RI" {
                    self.axes.iter_mut().for_each(|axis| axis.done = false);
                }
            }
            "EA" => {
                no_operand?;
                if self.selected.is_some_and(|i| self.axes[i].axis_type == AxisType::OpenLoop) {
                    return Err(NOT_NOW);
                }
                self.answer(Axis::encoder_status);
            }
            "QL" => {
                no_operand?;
                let mut word = 0u32;
                for (i, axis) in self.axes.iter().enumerate() {
                    let (low, high) = axis.limit_levels();
                    let offset = if i < 8 { 0 } else { 8 };
                    word |= u32::from(low) << (i + offset) | u32::from(high) << (i + offset + 8);
                }
                self.reply(&format!("{word:08X}"));
            }
            "RQC" => {
                no_operand?;
                self.answer(|axis| QUEUE_UNITS.saturating_sub(axis.queue.len()).to_string());
            }
            _ => return Err(BAD),
        }
        Ok(())
    }

    /// One line's commands, in order; an error does not stop the ones after it.
    fn line(&mut self, line: &[u8]) {
        let Some(text) = std::str::from_utf8(line).ok().filter(|t| t.is_ascii()) else {
            return self.refuse(BAD);
        };
        let text = text.to_ascii_uppercase();
        for token in text.split([';', ' ', '\t', '\n', '\r']).filter(|t| !t.is_empty()) {
            let mut rest = token;
            while !rest.is_empty() {
                let Some((name, query, operand, after)) = split_command(rest) else {
                    self.refuse(BAD);
                    break;
                };
                rest = after;
                if let Err(refusal) = self.command(name, query, operand) {
                    self.refuse(refusal);
                }
                self.catch_up();
            }
        }
    }

    fn refuse(&mut self, refusal: Refusal) {
        self.malformed += usize::from(refusal.malformed);
        self.notify(COMMAND_ERROR_FLAG);
    }
}

/// Mnemonics of three characters.
const LONG_NAMES: [&str; 5] = ["RQC", "LPE", "PSO", "PSE", "PSM"];

/// The first command of `text`: its mnemonic, whether `?` follows it, its operand, the rest.
fn split_command(text: &str) -> Option<(&str, bool, &str, &str)> {
    let prefixed = text.starts_with(['#', '?']);
    let long = LONG_NAMES.iter().any(|n| text.starts_with(n));
    let length = if prefixed || long { 3 } else { 2 };
    let name = text.get(..length)?;
    if !name.bytes().skip(usize::from(prefixed)).all(|b| b.is_ascii_uppercase()) {
        return None;
    }
    let rest = &text[length..];
    let query = rest.starts_with('?');
    let rest = if query { &rest[1..] } else { rest };
    let end = rest.find(|c: char| !(c.is_ascii_digit() || matches!(c, '+' | '-' | '.' | ','))).unwrap_or(rest.len());
    Some((name, query, &rest[..end], &rest[end..]))
}

/// A query form takes no operand.
fn no_operand_query(operand: &str) -> Result<(), Refusal> {
    if operand.is_empty() {
        Ok(())
    } else {
        Err(BAD)
    }
}

/// A decimal integer, its sign optional, within `min..=max`.
fn within(text: &str, min: i64, max: i64) -> Option<i64> {
    let digits = text.strip_prefix(['+', '-']).unwrap_or(text);
    if digits.is_empty() || digits.len() > 12 || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    text.strip_prefix('+').unwrap_or(text).parse().ok().filter(|v| (min..=max).contains(v))
}

fn position(text: &str) -> Option<f64> {
    within(text, -POSITION_MAX, POSITION_MAX).map(|v| v as f64)
}

/// KP, KI, KD: a decimal from 0 below 32 768.
fn decimal_gain(text: &str) -> Option<f64> {
    let valid = !text.is_empty() && text.bytes().all(|b| b.is_ascii_digit() || b == b'.') && text != ".";
    valid.then(|| text.parse().ok()).flatten().filter(|v| (0.0..GAIN_LIMIT).contains(v))
}

impl Emulator for MaxnetEmulator {
    fn name(&self) -> &'static str {
        "oms_maxnet"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        self.now = self.now.max(now);
        self.catch_up();
        // CR ends a line as LF does.
        let bytes: Vec<u8> = bytes.iter().map(|b| if *b == b'\r' { b'\n' } else { *b }).collect();
        for line in self.lines.push(&bytes) {
            self.line(&line);
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.output.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed + self.lines.overflowed()
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.axes.get_mut(channel).map(|axis| &mut axis.sim)
    }

    /// An encoder slip: the axis halts, its flag is notified, EA shows it until IC.
    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(axis) = self.axes.get_mut(channel) else { return false };
        axis.stop(0.0);
        axis.slip = true;
        self.notify(slip_flag(channel));
        true
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.now = self.now.max(now);
        self.catch_up();
    }

    /// The end of the next move or home (its queue moves on, its done or limit flag is notified).
    fn poll_timeout(&self) -> Option<Instant> {
        let ends = self.axes.iter().filter(|axis| matches!(axis.running, Some(Running::Move | Running::Home(_))));
        ends.filter_map(|axis| axis.sim.next_event()).min()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage;
    use std::time::Duration;

    fn at(ms: u64) -> Instant {
        Instant::after(Duration::from_millis(ms))
    }

    fn board() -> MaxnetEmulator {
        MaxnetEmulator::new(4, &stage())
    }

    fn drain(e: &mut MaxnetEmulator) -> Vec<String> {
        std::iter::from_fn(|| e.poll_transmit()).map(|bytes| String::from_utf8(bytes).expect("ASCII")).collect()
    }

    /// The lines sent back for `line`, without their `\n\r`.
    fn say(e: &mut MaxnetEmulator, ms: u64, line: &str) -> Vec<String> {
        e.handle_input(at(ms), format!("{line}\n").as_bytes());
        drain(e).into_iter().map(|reply| reply.strip_suffix("\n\r").expect("ended LF CR").to_string()).collect()
    }

    #[test]
    fn identification_and_power_up_state() {
        let mut e = board();
        assert_eq!(say(&mut e, 0, "WY"), ["MAXnet-4000 ver:1.33.4, s/n:000001"]);
        assert_eq!(say(&mut e, 0, "#WS"), ["=0"]);
        assert!(say(&mut e, 0, "IC;").is_empty() && say(&mut e, 0, "AM SA;").is_empty());
        assert_eq!(say(&mut e, 0, "AA RP;"), ["0,0,0,0"]);
        assert_eq!(say(&mut e, 0, "AX PS?;AY LT?"), ["=O", "=l"]);
        assert_eq!(say(&mut e, 0, "AZ ?PS ?LS ?PM CL?"), ["=O", "=l", "=off", "=off"]);
        assert_eq!(say(&mut e, 0, "AM;RI;"), ["PNNH,PNNH,PNNH,PNNH"]);
        assert_eq!(say(&mut e, 0, "AM;CL?;"), ["off,off,off,off"]);
        assert_eq!(say(&mut e, 0, "AM;QL;"), ["00000F0F"], "inactive switches read high under LL");
        assert_eq!(say(&mut e, 0, "AM;RQC"), ["2559,2559,2559,2559"]);
        assert_eq!(say(&mut e, 0, "AM PP;AM PE;AM;RV;"), ["0,0,0,0", "0,0,0,0", "0,0,0,0"]);
        assert_eq!(say(&mut e, 0, "AM;EA;"), ["DDNNH,DDNNH,DDNNH,DDNNH"]);
        assert_eq!(say(&mut e, 0, "AT;CL1;CL?;HF;CL?;AX;KP0.000000;KI12.5;KD0;ER1,100000"), ["=on", "=off"]);
        assert_eq!(
            say(&mut e, 0, "AK;AW;WY"),
            ["%000 01000000", "%000 01000000", "MAXnet-4000 ver:1.33.4, s/n:000001"]
        );
        assert_eq!(e.malformed(), 2, "axes W and K are not installed");
        assert_eq!(MaxnetEmulator::new(10, &stage()).axes.len(), 10);
        assert_eq!(MaxnetEmulator::new(0, &stage()).axes.len(), 1);
        assert_eq!(e.name(), "oms_maxnet");
    }

    #[test]
    fn a_move_runs_its_queue_then_sets_and_notifies_done() {
        let mut e = board();
        assert!(say(&mut e, 0, "AY;AC100000;VL10000;VB0;MA5000;GO;ID;").is_empty());
        let due = e.poll_timeout().expect("the move's end");
        assert!((due.as_secs_f64() - 0.6).abs() < 1e-6, "{due:?}");
        assert_eq!(say(&mut e, 300, "AY QA"), ["PNNN"]);
        let halfway: i64 = say(&mut e, 300, "AY RP")[0].parse().unwrap();
        assert!((2000..3000).contains(&halfway), "{halfway}");
        assert_eq!(say(&mut e, 300, "AY RQC"), ["2558"], "the ID waits");
        e.handle_timeout(due);
        assert_eq!(drain(&mut e), ["%000 00000002\n\r"]);
        assert!(e.poll_timeout().is_none());
        assert_eq!(say(&mut e, 700, "AY;RA;QA;RP"), ["PDNN", "PNNN", "5000"], "RA clears the done flag");
        assert_eq!(say(&mut e, 700, "AY MR-500 GO"), Vec::<String>::new());
        assert_eq!(say(&mut e, 2000, "AY RP QA"), ["4500", "MNNN"], "no ID, no done");
        assert_eq!(say(&mut e, 2000, "AY ID; QI"), ["%000 00000002", "PNNH,MDNN,PNNH,PNNH"]);
        assert_eq!(say(&mut e, 2000, "AY MA5000 GO QA"), ["PNNN"], "GO clears the done flag");
    }

    #[test]
    fn moves_queue_one_after_another() {
        let mut e = board();
        say(&mut e, 0, "AX;AC1000000;VL10000;MR1000;GO;MR1000;GO;ID");
        assert_eq!(say(&mut e, 150, "AX RP"), ["1350"], "the second move began as the first ended, at 110 ms");
        assert_eq!(say(&mut e, 250, "AX RP RQC"), ["%000 00000001", "2000", "2559"], "done at 220 ms");
        assert_eq!(say(&mut e, 250, "AX QA"), ["PDNN"]);
    }

    #[test]
    fn a_jog_runs_until_st_brakes_it() {
        let mut e = board();
        assert!(say(&mut e, 0, "AX AC100000; JG-5000;").is_empty());
        assert_eq!(say(&mut e, 1000, "AX RV QA"), ["-5000", "MNNN"]);
        assert!(e.poll_timeout().is_none(), "a jog has no end to wait for");
        assert!(say(&mut e, 1000, "AX AC100000; ST ID;").is_empty());
        assert_eq!(say(&mut e, 1020, "AX QA"), ["MNNN"], "braking");
        assert_eq!(say(&mut e, 1100, "AX QA RP RV"), ["%000 00000001", "MDNN", "-5000", "0"]);
        say(&mut e, 1100, "AX JG2000");
        assert_eq!(say(&mut e, 1200, "AX JG0 RV"), ["2000"]);
        assert_eq!(say(&mut e, 1300, "AX RV QA CA QA"), ["0", "PDNN", "PNNN"], "JG leaves the done flag; CA clears it");
        say(&mut e, 1300, "AX JG3000");
        assert_eq!(say(&mut e, 1400, "KL AM RV"), ["0,0,0,0"], "a kill halts at once");
    }

    #[test]
    fn a_home_search_then_move_to_zero() {
        let mut e = board();
        say(&mut e, 0, "AZ;VL10000;AC1000000;MR3000;GO;LP1000");
        assert_eq!(say(&mut e, 1000, "AZ RP"), ["1000"], "LP waited for the move");
        assert!(say(&mut e, 1000, "AZ;AC1000000;VL10000;VB0;HR;MA0;GO;ID;").is_empty());
        assert_eq!(say(&mut e, 1100, "AZ QA"), ["MNNN"]);
        let due = e.poll_timeout().expect("the home's end");
        e.handle_timeout(due);
        assert_eq!(drain(&mut e), ["%000 00000004\n\r"]);
        assert_eq!(say(&mut e, 2000, "AZ RP QA"), ["0", "MDNH"]);
        assert_eq!(e.axis(2).unwrap().physical_position(), 0.0, "on the switch");
        say(&mut e, 2000, "AZ MR2000 GO");
        assert_eq!(say(&mut e, 3000, "AZ HM-100 ID RP"), ["2000"]);
        assert_eq!(say(&mut e, 4000, "AZ RP QA"), ["%000 00000004", "-100", "MDNH"]);
    }

    #[test]
    fn a_limit_switch_stops_and_is_notified() {
        let mut e = board();
        say(&mut e, 0, "AT;AC4000000;VL400000;JG400000;");
        assert_eq!(say(&mut e, 1000, "AT QA RP"), ["%000 00000800", "PNLN", "200000"]);
        assert_eq!(say(&mut e, 1000, "QL"), ["0000070F"], "T's high limit input pulled low");
        assert_eq!(
            say(&mut e, 1000, "AT;MR1000;GO;ID"),
            ["%000 00000800", "%000 00000008"],
            "the switch stops it at once; the ID comes after"
        );
        assert_eq!(say(&mut e, 1000, "AT;RQC;MR-1000;GO;ID"), ["2559"], "the ID was flushed");
        assert_eq!(say(&mut e, 2000, "AT RP QA"), ["%000 00000008", "199000", "MDNN"]);
        assert_eq!(say(&mut e, 2000, "AM;LH;QL;AT;LT?"), ["00000000", "=h"]);
        say(&mut e, 2000, "AY;AC4000000;VL400000;MR-300000;GO;ID");
        assert_eq!(say(&mut e, 3000, "AY QA RP"), ["%000 00000200", "MNLN", "-200000"], "no done: the ID was flushed");
        assert_eq!(say(&mut e, 3000, "QL"), ["00000002"], "Y's low limit input high, active under LH");
    }

    #[test]
    fn command_errors_are_notified_and_the_line_goes_on() {
        let mut e = board();
        const ERROR: &str = "%000 01000000";
        assert_eq!(say(&mut e, 0, "XX"), [ERROR]);
        assert_eq!(say(&mut e, 0, "ZZ RP"), [ERROR, "0"]);
        for line in ["AX;VL0", "AX MA99999999", "AX VB300000", "AM;VL1,2,3,4,5", "AX JG", "AX RP5", "AX KP-1", "AX ER5"]
        {
            assert_eq!(say(&mut e, 0, line), [ERROR], "{line}");
        }
        assert_eq!(e.malformed(), 10);
        assert_eq!(say(&mut e, 0, "AX;VB5000;VL4000;VL?"), [ERROR, ERROR], "VL must stay above VB");
        assert_eq!(e.malformed(), 12);
        assert_eq!(say(&mut e, 0, "AX EA"), [ERROR], "no encoder on an open-loop axis");
        assert_eq!(e.malformed(), 12, "a refusal of state is not malformed");
        assert_eq!(say(&mut e, 0, "AX PSE EA LPE-20 RE"), ["DDNNH", "-20"]);
        e.handle_input(at(0), "AY;MR100000;GO\n".as_bytes());
        assert!(e.raise_error(1) && !e.raise_error(4));
        assert_eq!(say(&mut e, 100, "AM;EA;AY;RP"), ["%000 00020000", "DDNNH,DDSNH,DDNNH,DDNNH", "0"]);
        assert_eq!(say(&mut e, 100, "IC;AM;EA"), ["DDNNH,DDNNH,DDNNH,DDNNH"]);
        assert_eq!(e.malformed(), 12);
    }

    #[test]
    fn multi_axis_values_are_comma_separated_and_may_be_omitted() {
        let mut e = board();
        let line = "AM;VL10000,20000,,;AC1000000,1000000;MR1000,,-3000;GO;ID;";
        assert_eq!(say(&mut e, 0, line), ["%000 0000000A"], "Y and T had nothing to wait for");
        assert_eq!(say(&mut e, 1000, "AM;RP;"), ["%000 00000005", "1000,0,-3000,0"]);
        assert_eq!(
            say(&mut e, 1000, "AA;MA;GO;RP;RI;QI"),
            ["1000,0,-3000,0", "PDNN,PDNH,MDNN,PDNH", "PNNN,PNNH,MNNN,PNNH"]
        );
        assert_eq!(say(&mut e, 1000, "AA LP5,6,7,8 ST PP"), ["5,6,7,8"]);
    }

    #[test]
    fn bytes_come_in_any_pieces_and_case() {
        let mut e = board();
        e.handle_input(at(0), b"A");
        e.handle_input(at(0), b"X R");
        assert!(e.poll_transmit().is_none());
        e.handle_input(at(0), b"P\r");
        assert_eq!(drain(&mut e), ["0\n\r"]);
        assert_eq!(say(&mut e, 0, "ay;lp42;rp;AXRP"), ["42", "0"]);
        assert_eq!(say(&mut e, 0, "AX;RP\u{e9}"), ["%000 01000000"]);
        assert_eq!(e.malformed(), 1, "a byte that is not ASCII");
        e.handle_input(at(0), &[b'A'; 513]);
        assert_eq!(e.malformed(), 2, "an overflowing input buffer counts");
        assert_eq!(say(&mut e, 0, "WY"), ["MAXnet-4000 ver:1.33.4, s/n:000001"]);
    }
}
