//! A Galil DMC-4040 (a DMC-40x0 of one to eight axes, A to H), reached over Ethernet (TCP port
//! 23): Galil's two-letter ASCII commands, `:` for done, `?` for refused, the binary data record
//! of `QR`; one simulator step a count, every axis a servo (MT 1).
//!
//! # Witnesses
//!
//! 1. Galil's "DMC-40x0 User Manual", chapter 5 (as published on easymanua.ls): the controller
//!    answers `:` to a valid command and `?` to an invalid one (lower case included), the reason
//!    then being read with `TC1`; interrogations answer decimal text on a line of its own ended
//!    by CR LF, formatted by PF, VF and LZ. The command reference's QZ page: four integers
//!    separated by commas, the axes and the bytes of the general, coordinated and axis blocks.
//! 2. Galil's DMC-2x00, DMC-1700/1800 and DMC-3425 user manuals ("Data Record", same family):
//!    the header (byte 0 bit 7 set and the S, T, I blocks present in bits 0–2; byte 1 the axis
//!    blocks A–H present; bytes 2–3 the record's length, header included, little-endian); the
//!    axis status word (bit 15 move in progress, 14 PA or PR, 13 PA only, 12 FE in progress,
//!    11 HM in progress, 10 HM phase 1 complete, 9 HM phase 2 complete or FI issued, 7 negative
//!    direction, 4 stopping by ST or a limit, 1 off-on-error armed, 0 motor off); the switch byte
//!    (bit 3 forward limit, 2 reverse limit, 1 home input, 0 stepper mode); the velocity in the
//!    record being 64 times TV; `TC1` answering `1 Unrecognized command`.
//! 3. The DMC-1400 command reference, TS: bit 7 axis in motion, 6 error limit exceeded, 5 motor
//!    off, 3 and 2 the forward and reverse limits, 1 the home switch, 0 latch not armed; with the
//!    default CN the limit bits are 1 when the switch is inactive.
//! 4. The Optima (DMC-1xxx) command reference, HM: three stages for a servo; at SP to the home
//!    input's transition (the direction from the input's state), back slowly to it, then slowly
//!    forward to the encoder's index, which becomes position 0.
//! 5. The DMC-3425 and DMC-1700 manuals, command syntax: `PRA=1000`, `PR 1000,,-500`,
//!    `PR ?,?`, `BG AB`, `BG` alone for every axis, `;` or CR ending a command.
//! 6. A research brief on the DMC-40x0 (Galil's gclib record struct and several clients): the
//!    general block's offsets (4 sample, 6–15 inputs, 16–25 outputs, 42–49 handles, 50 error
//!    code, 51 threads, 52–55 amplifiers, 56–81 contour and the S and T planes) and the axis
//!    block's (36 bytes at 82 + 36·i: +0 status, +2 switches, +3 stop code, +4 RP, +8 TP, +12
//!    TE, +16 TD, +20 velocity, +24 torque, +28 analog in, +30 halls, +32 ZA); QZ `n, 52, 26,
//!    36`; `QR` answered by the record then a bare `:`; the stop codes (1 at the commanded
//!    position, 2/3 forward/reverse limit, 4 ST, 7 AB, 8 off-on-error, 9 FE, 10 HM or FI) and
//!    TC codes (1, 6, 7, 20, 21, 22); AC and DC resolution 1024 up to 1 073 740 800, SP
//!    resolution 2; `WH` answering `IHA`; `^R^V` answering `DMC4040 Rev 1.2f`.
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Variables**: `name=value`, a name of a letter then up to 7 letters and digits that is no
//!   command, creates the variable or sets it (510 at most: TC 6 beyond), as the user manual's
//!   chapter on programming has variables created by assignment; `MG name` reports it. No program
//!   runs here, so they change nothing else.
//! - **Power-on**: every motor off (MO); `BG` is refused (TC 20) until `SH`. SP 25 000, AC and
//!   DC 256 000, JG 25 000, KP 6, KI 0, KD 64, ER 16 384, OE 0, FL 2 147 483 647 and BL
//!   −2 147 483 648 (no software limits), stop code 0, TC 0.
//! - **Formats**: interrogations (TP, TD, TE, TS, SC, TV, RP, `XX ?`, `XXA=?`) answer integers
//!   with a space where a sign would go (` 1000`, `-5`), several comma-separated; MT answers one
//!   decimal (` 1.0`), KP/KI/KD four. `MG` answers VF 10.4 (` 1000.0000`); `MG "text"` the text;
//!   several operands space-separated. QZ answers `n, 52, 26, 36`. `TC1` with no error answers
//!   `0`; reading the code does not clear it.
//! - **Refusals**: an unknown command, bad syntax, an axis not installed and too many fields
//!   are TC 1 and malformed; a number out of range TC 6 and malformed; a refusal for a reason
//!   of state (BG motor off 20, moving 21, toward an active limit or beyond FL/BL 22; DP, DE,
//!   MT on a moving axis 7) is not malformed. Known commands not carried out (TH, UL, DL, XQ,
//!   HX, LZ, PF, VF, `QR` with arguments…) answer TC 1, not malformed. Each command of a line is
//!   answered, an error not stopping the ones after it. Lines hold 1024 bytes at most.
//! - **Motion**: one acceleration for a move's ramps, AC (DC brakes ST); a PA/PR target beyond
//!   FL or BL is cut there (stop code 2 or 3); a jog toward a software limit ends there, else
//!   runs until ST, AB or a switch (2 or 3, the simulator halting on the switch). `JG` on a
//!   jogging axis changes its speed at once. `MO` on a moving axis stops it at once (stop code
//!   7, as AB). AB stops every axis at once, motors left on.
//! - **Home**: the home input reads 1 on the positive side of the simulator's home switch
//!   (inclusive). `HM` + `BG` goes to the switch at SP and reads 0 there (the index is taken to
//!   be at the switch): status bit 11 during it, bits 10 and 9 after it until the next BG, stop
//!   code 10. `FI` the same (bit 9 during it); `FE` goes to the switch without zeroing, stop
//!   code 9 (bit 12 during it).
//! - **Encoders**: no following error (TE 0, RP = TP, torque 0); TD the auxiliary encoder, TP
//!   plus an offset that DE defines. DP defines TP. MT is taken (±1, ±1.5, ±2, ±2.5); ±2 and ±2.5
//!   set the record's stepper bit and change nothing else. CN, DR, EO, CF, CW are taken and
//!   change nothing.
//! - **Record**: inputs read all ones (nothing wired), outputs 0, handle bytes, threads,
//!   amplifier status, contour and planes 0; the sample counter counts milliseconds. `raise_error`
//!   is an off-on-error: the motor off, stop code 8, TS bit 6, until `SH`.

use crate::emulator::axes;
use crate::{Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

const LETTERS: &[u8; 8] = b"ABCDEFGH";
const CR: &[u8] = b"\r";
const INPUT_BUFFER: usize = 1024;
/// The record's header, general (I) block, coordinated block (contour, S and T planes), axis block.
const HEADER: usize = 4;
const GENERAL: usize = 52;
const COORDINATED: usize = 26;
const AXIS_BLOCK: usize = 36;
const SERIAL_NUMBER: u32 = 12_345;
const SPEED_MAX: f64 = 22_000_000.0;
const ACCEL_MAX: f64 = 1_073_740_800.0;
const POSITION_MAX: f64 = 2_147_483_647.0;
const POSITION_MIN: f64 = -2_147_483_648.0;

/// Why a command is answered `?`; its TC code.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Refusal {
    Unrecognized,
    /// A command this emulator knows of and does not carry out: TC 1, not the host's fault.
    NotCarriedOut,
    OutOfRange,
    WhileRunning,
    MotorOff,
    Running,
    Limit,
}

impl Refusal {
    fn code(self) -> u8 {
        match self {
            Refusal::Unrecognized | Refusal::NotCarriedOut => 1,
            Refusal::OutOfRange => 6,
            Refusal::WhileRunning => 7,
            Refusal::MotorOff => 20,
            Refusal::Running => 21,
            Refusal::Limit => 22,
        }
    }

    fn malformed(self) -> bool {
        matches!(self, Refusal::Unrecognized | Refusal::OutOfRange)
    }
}

fn tc_text(code: u8) -> &'static str {
    match code {
        1 => "Unrecognized command",
        6 => "Number out of range",
        7 => "Command not valid while running",
        20 => "Begin not valid with motor off",
        21 => "Begin not valid while running",
        22 => "Begin not possible due to Limit Switch",
        _ => "",
    }
}

/// What a command answers.
enum Reply {
    Done,
    Text(String),
    Binary(Vec<u8>),
}

/// What `BG` begins: the last of PA, PR, JG, HM, FE, FI given.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Mode {
    Absolute,
    Relative,
    Jog,
    Home,
    FindEdge,
    FindIndex,
}

/// A motion begun and not yet ended.
#[derive(Clone, Copy, Debug)]
struct Run {
    mode: Mode,
    negative: bool,
    stopping: bool,
    /// The stop code of the software limit the motion was cut at.
    cut: Option<u8>,
}

/// The settings read and written as `XXA=v`, `XX v,v`, `XXA=?`, `XX ?,?`.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Setting {
    Speed,
    Accel,
    Decel,
    Jog,
    Absolute,
    Relative,
    ForwardLimit,
    ReverseLimit,
    Gain(usize),
    MotorType,
    ErrorLimit,
    OffOnError,
    DefinePosition,
    DefineAux,
}

impl Setting {
    fn named(name: &str) -> Option<Setting> {
        Some(match name {
            "SP" => Setting::Speed,
            "AC" => Setting::Accel,
            "DC" => Setting::Decel,
            "JG" => Setting::Jog,
            "PA" => Setting::Absolute,
            "PR" => Setting::Relative,
            "FL" => Setting::ForwardLimit,
            "BL" => Setting::ReverseLimit,
            "KP" => Setting::Gain(0),
            "KI" => Setting::Gain(1),
            "KD" => Setting::Gain(2),
            "MT" => Setting::MotorType,
            "ER" => Setting::ErrorLimit,
            "OE" => Setting::OffOnError,
            "DP" => Setting::DefinePosition,
            "DE" => Setting::DefineAux,
            _ => return None,
        })
    }

    /// The value stored for `value`, at the setting's resolution, if within its range.
    fn accept(self, value: f64) -> Result<f64, Refusal> {
        let within =
            |min: f64, max: f64, v: f64| if (min..=max).contains(&v) { Ok(v) } else { Err(Refusal::OutOfRange) };
        match self {
            Setting::Speed => within(0.0, SPEED_MAX, 2.0 * (value / 2.0).round()),
            Setting::Jog => within(-SPEED_MAX, SPEED_MAX, 2.0 * (value / 2.0).round()),
            Setting::Accel | Setting::Decel => {
                within(1024.0, ACCEL_MAX, (1024.0 * (value / 1024.0).round()).max(1024.0))
            }
            Setting::Absolute
            | Setting::Relative
            | Setting::ForwardLimit
            | Setting::ReverseLimit
            | Setting::DefinePosition
            | Setting::DefineAux => within(POSITION_MIN, POSITION_MAX, value.round()),
            Setting::Gain(0) => within(0.0, 1023.875, value),
            Setting::Gain(1) => within(0.0, 255.999, value),
            Setting::Gain(_) => within(0.0, 4095.875, value),
            Setting::MotorType => [1.0, -1.0, 1.5, -1.5, 2.0, -2.0, 2.5, -2.5]
                .contains(&value)
                .then_some(value)
                .ok_or(Refusal::OutOfRange),
            Setting::ErrorLimit => within(1.0, POSITION_MAX, value.round()),
            Setting::OffOnError => within(0.0, 3.0, value.round()),
        }
    }

    fn format(self, value: f64) -> String {
        match self {
            Setting::MotorType => fixed(value, 1),
            Setting::Gain(_) => fixed(value, 4),
            _ => integer(value),
        }
    }
}

/// An integer with a space where a sign would go.
fn integer(value: f64) -> String {
    let n = value.round() as i64;
    if n < 0 {
        n.to_string()
    } else {
        format!(" {n}")
    }
}

/// A decimal with `places` decimals and a space where a sign would go.
fn fixed(value: f64, places: usize) -> String {
    if value < 0.0 {
        format!("{value:.places$}")
    } else {
        format!(" {:.places$}", value.abs())
    }
}

/// One axis: its simulator and what the controller keeps of it.
struct Axis {
    sim: SimAxis,
    speed: f64,
    accel: f64,
    decel: f64,
    jog: f64,
    absolute: f64,
    relative: f64,
    forward_limit: f64,
    reverse_limit: f64,
    gains: [f64; 3],
    motor_type: f64,
    error_limit: f64,
    off_on_error: f64,
    aux_offset: f64,
    mode: Mode,
    motor_off: bool,
    error_exceeded: bool,
    run: Option<Run>,
    stop_code: u8,
    /// HM's phases 1 and 2 done, until the next BG.
    homed: bool,
}

impl Axis {
    fn new(mut sim: SimAxis) -> Self {
        sim.enable(false);
        Self {
            sim,
            speed: 25_000.0,
            accel: 256_000.0,
            decel: 256_000.0,
            jog: 25_000.0,
            absolute: 0.0,
            relative: 0.0,
            forward_limit: POSITION_MAX,
            reverse_limit: POSITION_MIN,
            gains: [6.0, 0.0, 64.0],
            motor_type: 1.0,
            error_limit: 16_384.0,
            off_on_error: 0.0,
            aux_offset: 0.0,
            mode: Mode::Absolute,
            motor_off: true,
            error_exceeded: false,
            run: None,
            stop_code: 0,
            homed: false,
        }
    }

    fn position(&self) -> f64 {
        self.sim.status().position.round()
    }

    fn get(&self, setting: Setting) -> f64 {
        match setting {
            Setting::Speed => self.speed,
            Setting::Accel => self.accel,
            Setting::Decel => self.decel,
            Setting::Jog => self.jog,
            Setting::Absolute => self.absolute,
            Setting::Relative => self.relative,
            Setting::ForwardLimit => self.forward_limit,
            Setting::ReverseLimit => self.reverse_limit,
            Setting::Gain(i) => self.gains[i],
            Setting::MotorType => self.motor_type,
            Setting::ErrorLimit => self.error_limit,
            Setting::OffOnError => self.off_on_error,
            Setting::DefinePosition => self.position(),
            Setting::DefineAux => self.position() + self.aux_offset,
        }
    }

    fn set(&mut self, setting: Setting, value: f64) -> Result<(), Refusal> {
        let moving = self.run.is_some();
        match setting {
            Setting::Speed => self.speed = value,
            Setting::Accel => self.accel = value,
            Setting::Decel => self.decel = value,
            Setting::Jog => {
                self.jog = value;
                self.mode = Mode::Jog;
                if self.run.is_some_and(|run| run.mode == Mode::Jog && !run.stopping) {
                    self.sim.move_velocity(0.0, value, self.accel);
                }
            }
            Setting::Absolute => (self.absolute, self.mode) = (value, Mode::Absolute),
            Setting::Relative => (self.relative, self.mode) = (value, Mode::Relative),
            Setting::ForwardLimit => self.forward_limit = value,
            Setting::ReverseLimit => self.reverse_limit = value,
            Setting::Gain(i) => self.gains[i] = value,
            Setting::ErrorLimit => self.error_limit = value,
            Setting::OffOnError => self.off_on_error = value,
            Setting::MotorType | Setting::DefinePosition | Setting::DefineAux if moving => {
                return Err(Refusal::WhileRunning)
            }
            Setting::MotorType => self.motor_type = value,
            Setting::DefinePosition => {
                let aux = self.get(Setting::DefineAux);
                self.sim.set_position(value);
                self.aux_offset = aux - value;
            }
            Setting::DefineAux => self.aux_offset = value - self.position(),
        }
        Ok(())
    }

    /// Why `BG` cannot begin this axis's motion, if it cannot.
    fn refuse_begin(&self) -> Option<Refusal> {
        if self.motor_off {
            return Some(Refusal::MotorOff);
        }
        if self.run.is_some() {
            return Some(Refusal::Running);
        }
        let position = self.position();
        let state = self.sim.state();
        let blocked = match self.direction() {
            Some(false) => state.high_limit || position >= self.forward_limit,
            Some(true) => state.low_limit || position <= self.reverse_limit,
            None => false,
        };
        blocked.then_some(Refusal::Limit)
    }

    /// Whether the motion `BG` would begin goes negative; None for the searches.
    fn direction(&self) -> Option<bool> {
        match self.mode {
            Mode::Absolute => Some(self.absolute < self.position()),
            Mode::Relative => Some(self.relative < 0.0),
            Mode::Jog => Some(self.jog < 0.0),
            Mode::Home | Mode::FindEdge | Mode::FindIndex => None,
        }
    }

    fn begin(&mut self) {
        let position = self.position();
        let negative = self.direction().unwrap_or(self.sim.physical_position() > self.sim.config().home_switch);
        let soft = if negative { (self.reverse_limit, 3) } else { (self.forward_limit, 2) };
        let beyond = |target: f64| if negative { target < soft.0 } else { target > soft.0 };
        let mut cut = None;
        let (speed, accel) = (self.speed, self.accel);
        match self.mode {
            Mode::Absolute | Mode::Relative => {
                let mut target = if self.mode == Mode::Absolute { self.absolute } else { position + self.relative };
                if beyond(target) {
                    (target, cut) = (soft.0, Some(soft.1));
                }
                self.sim.move_to(target, false, 0.0, speed, accel);
            }
            Mode::Jog if soft.0 > POSITION_MIN && soft.0 < POSITION_MAX => {
                cut = Some(soft.1);
                self.sim.move_to(soft.0, false, 0.0, self.jog.abs(), accel);
            }
            Mode::Jog => self.sim.move_velocity(0.0, self.jog, accel),
            Mode::Home | Mode::FindIndex => self.sim.home(!negative, 0.0, speed, accel),
            Mode::FindEdge => {
                let distance = self.sim.config().home_switch - self.sim.physical_position();
                self.sim.move_to(distance, true, 0.0, speed, accel);
            }
        }
        self.homed = false;
        self.stop_code = 0;
        self.run = Some(Run { mode: self.mode, negative, stopping: false, cut });
    }

    /// A motion that has ended gets its stop code.
    fn settle(&mut self) {
        let Some(run) = self.run else { return };
        if self.sim.is_moving() {
            return;
        }
        let state = self.sim.state();
        self.stop_code = if run.stopping {
            4
        } else if !run.negative && state.high_limit {
            2
        } else if run.negative && state.low_limit {
            3
        } else if let Some(code) = run.cut {
            code
        } else {
            match run.mode {
                Mode::Absolute | Mode::Relative | Mode::Jog => 1,
                Mode::FindEdge => 9,
                Mode::Home | Mode::FindIndex => 10,
            }
        };
        self.homed = run.mode == Mode::Home && self.stop_code == 10;
        self.run = None;
    }

    /// Stopped at once, without deceleration (AB, MO, off-on-error).
    fn halt(&mut self, stop_code: u8) {
        if self.run.take().is_some() {
            self.sim.stop(0.0);
            self.stop_code = stop_code;
        }
    }

    fn motor(&mut self, on: bool) {
        if !on {
            self.halt(7);
        }
        self.sim.enable(on);
        self.motor_off = !on;
        self.error_exceeded &= !on;
    }

    fn home_input(&self) -> bool {
        self.sim.physical_position() >= self.sim.config().home_switch
    }

    /// The record's status word.
    fn status_word(&self) -> u16 {
        let mut word = 0;
        if let Some(run) = self.run {
            word |= 1 << 15;
            word |= match run.mode {
                Mode::Absolute => (1 << 14) | (1 << 13),
                Mode::Relative => 1 << 14,
                Mode::Jog => 0,
                Mode::Home => 1 << 11,
                Mode::FindEdge => 1 << 12,
                Mode::FindIndex => 1 << 9,
            };
            word |= u16::from(run.negative) << 7 | u16::from(run.stopping) << 4;
        }
        word |= u16::from(self.homed) * ((1 << 10) | (1 << 9));
        word | u16::from(self.off_on_error > 0.0) << 1 | u16::from(self.motor_off)
    }

    /// The record's switch byte, TS's bits 3 to 1.
    fn switches(&self) -> u8 {
        let state = self.sim.state();
        u8::from(!state.high_limit) << 3
            | u8::from(!state.low_limit) << 2
            | u8::from(self.home_input()) << 1
            | u8::from(self.motor_type.abs() >= 2.0)
    }

    /// TS: moving, error limit exceeded, motor off, the switches, latch not armed.
    fn tell_switches(&self) -> u8 {
        u8::from(self.run.is_some()) << 7
            | u8::from(self.error_exceeded) << 6
            | u8::from(self.motor_off) << 5
            | (self.switches() & 0b1110)
            | 1
    }

    /// An interrogation (`TP`…) or operand (`_TP`…) of this axis.
    fn operand(&self, name: &str) -> Option<f64> {
        let flag = |on: bool| f64::from(u8::from(on));
        let state = self.sim.state();
        Some(match name {
            "TP" | "RP" => self.position(),
            "TD" => self.get(Setting::DefineAux),
            "TE" => 0.0,
            "TS" => f64::from(self.tell_switches()),
            "SC" => f64::from(self.stop_code),
            "TV" => self.sim.status().velocity.round(),
            "BG" => flag(self.run.is_some()),
            "MO" => flag(self.motor_off),
            "LF" => flag(!state.high_limit),
            "LR" => flag(!state.low_limit),
            "HM" => flag(self.home_input()),
            _ => return Setting::named(name).map(|setting| self.get(setting)),
        })
    }

    fn block(&self) -> [u8; AXIS_BLOCK] {
        let mut block = [0; AXIS_BLOCK];
        let long = |v: f64| (v.round() as i32).to_le_bytes();
        block[0..2].copy_from_slice(&self.status_word().to_le_bytes());
        block[2] = self.switches();
        block[3] = self.stop_code;
        block[4..8].copy_from_slice(&long(self.position()));
        block[8..12].copy_from_slice(&long(self.position()));
        block[16..20].copy_from_slice(&long(self.get(Setting::DefineAux)));
        block[20..24].copy_from_slice(&long(64.0 * self.sim.status().velocity));
        block
    }
}

/// A DMC-40x0 with axes A to H (as many as asked) behind its Ethernet port.
pub struct GalilEmulator {
    axes: Vec<Axis>,
    lines: Lines,
    output: VecDeque<Vec<u8>>,
    error_code: u8,
    now: Instant,
    malformed: usize,
    /// Variables, created by assignment (a program's; none runs here).
    variables: Vec<(String, f64)>,
}

/// The most variables a DMC-40x0 holds.
const VARIABLES: usize = 510;

/// A variable's name: a letter, then letters and digits, 8 at most, and no command's form
/// (two capitals, then at most an axis letter).
fn variable_name(name: &str) -> bool {
    let bytes = name.as_bytes();
    let command_form = bytes.len() <= 3 && bytes.iter().all(u8::is_ascii_uppercase);
    (1..=8).contains(&bytes.len())
        && bytes[0].is_ascii_alphabetic()
        && bytes.iter().all(u8::is_ascii_alphanumeric)
        && !command_form
}

impl GalilEmulator {
    /// A controller with `axes` axes (1 to 8) on `mechanics`, each a servo, its motor off.
    pub fn new(axes_count: usize, mechanics: &SimConfig) -> Self {
        let mechanics = SimConfig { servo: true, ..mechanics.clone() };
        Self {
            axes: axes(axes_count.clamp(1, LETTERS.len()), &mechanics).into_iter().map(Axis::new).collect(),
            lines: Lines::new(CR, INPUT_BUFFER),
            output: VecDeque::new(),
            error_code: 0,
            now: Instant::ZERO,
            malformed: 0,
            variables: Vec::new(),
        }
    }

    /// The axes a list of letters names (all of them when empty), in order.
    fn axis_list(&self, text: &str) -> Result<Vec<usize>, Refusal> {
        let text = text.trim();
        if text.is_empty() {
            return Ok((0..self.axes.len()).collect());
        }
        let mut list = Vec::new();
        for letter in text.bytes().filter(|b| *b != b' ') {
            let i = LETTERS.iter().position(|l| *l == letter).filter(|i| *i < self.axes.len());
            let i = i.ok_or(Refusal::Unrecognized)?;
            if !list.contains(&i) {
                list.push(i);
            }
        }
        Ok(list)
    }

    fn command(&mut self, text: &str) -> Result<Reply, Refusal> {
        if text == "\x12\x16" {
            return Ok(Reply::Text(format!("DMC40{}0 Rev 1.2f", self.axes.len())));
        }
        if let Some((name, value)) = text.split_once('=').filter(|(name, _)| variable_name(name.trim())) {
            let value = number(value.trim()).ok_or(Refusal::Unrecognized)?;
            return self.assign(name.trim(), value);
        }
        let name = text.get(..2).filter(|n| n.bytes().all(|b| b.is_ascii_uppercase())).ok_or(Refusal::Unrecognized)?;
        let rest = &text[2..];
        let done = Ok(Reply::Done);
        match name {
            "BG" => {
                let list = self.axis_list(rest)?;
                if let Some(refusal) = list.iter().find_map(|i| self.axes[*i].refuse_begin()) {
                    return Err(refusal);
                }
                list.into_iter().for_each(|i| self.axes[i].begin());
                done
            }
            "ST" => {
                for i in self.axis_list(rest)? {
                    let axis = &mut self.axes[i];
                    if let Some(run) = axis.run.as_mut() {
                        run.stopping = true;
                        axis.sim.stop(axis.decel);
                    }
                }
                done
            }
            "AB" => {
                if !matches!(rest.trim(), "" | "0" | "1") {
                    return Err(Refusal::Unrecognized);
                }
                self.axes.iter_mut().for_each(|axis| axis.halt(7));
                done
            }
            "SH" | "MO" => {
                for i in self.axis_list(rest)? {
                    self.axes[i].motor(name == "SH");
                }
                done
            }
            "HM" | "FE" | "FI" => {
                let mode = match name {
                    "HM" => Mode::Home,
                    "FE" => Mode::FindEdge,
                    _ => Mode::FindIndex,
                };
                self.axis_list(rest)?.into_iter().for_each(|i| self.axes[i].mode = mode);
                done
            }
            "TP" | "TD" | "TE" | "TS" | "SC" | "TV" | "RP" => {
                let values: Vec<String> =
                    self.axis_list(rest)?.into_iter().filter_map(|i| self.axes[i].operand(name)).map(integer).collect();
                Ok(Reply::Text(values.join(",")))
            }
            "TC" => match rest.trim() {
                "" | "0" => Ok(Reply::Text(self.error_code.to_string())),
                "1" if self.error_code == 0 => Ok(Reply::Text("0".into())),
                "1" => Ok(Reply::Text(format!("{} {}", self.error_code, tc_text(self.error_code)))),
                _ => Err(Refusal::Unrecognized),
            },
            "QZ" if rest.is_empty() => {
                Ok(Reply::Text(format!("{}, {GENERAL}, {COORDINATED}, {AXIS_BLOCK}", self.axes.len())))
            }
            "QR" if rest.trim().is_empty() => Ok(Reply::Binary(self.record())),
            "QR" => Err(Refusal::NotCarriedOut),
            "WH" if rest.is_empty() => Ok(Reply::Text("IHA".into())),
            "MG" => self.message(rest.trim()).map(Reply::Text),
            "CN" | "DR" | "EO" | "CF" | "CW" => done,
            "TH" | "UL" | "DL" | "XQ" | "HX" | "LZ" | "PF" | "VF" | "IH" | "BN" | "TM" => Err(Refusal::NotCarriedOut),
            _ => {
                let setting = Setting::named(name).ok_or(Refusal::Unrecognized)?;
                self.setting(setting, rest)
            }
        }
    }

    /// `XXA=v`, `XXA=?`, `XX v,,v`, `XX ?,?`: values set, or queried.
    fn setting(&mut self, setting: Setting, rest: &str) -> Result<Reply, Refusal> {
        let rest = rest.trim();
        let fields: Vec<(usize, &str)> = match rest.as_bytes() {
            [letter, b'=', ..] if letter.is_ascii_uppercase() => {
                vec![(self.axis_list(&rest[..1])?[0], rest[2..].trim())]
            }
            _ => rest.split(',').map(str::trim).enumerate().filter(|(_, field)| !field.is_empty()).collect(),
        };
        if fields.iter().any(|(i, _)| *i >= self.axes.len()) {
            return Err(Refusal::Unrecognized);
        }
        if fields.iter().any(|(_, field)| *field == "?") {
            if fields.iter().any(|(_, field)| *field != "?") {
                return Err(Refusal::Unrecognized);
            }
            let values: Vec<String> = fields.iter().map(|(i, _)| setting.format(self.axes[*i].get(setting))).collect();
            return Ok(Reply::Text(values.join(",")));
        }
        let mut values = Vec::new();
        for (i, field) in fields {
            values.push((i, setting.accept(number(field).ok_or(Refusal::Unrecognized)?)?));
        }
        for (i, value) in values {
            self.axes[i].set(setting, value)?;
        }
        Ok(Reply::Done)
    }

    /// `name=value`: the variable created, or set.
    fn assign(&mut self, name: &str, value: f64) -> Result<Reply, Refusal> {
        let room = self.variables.len() < VARIABLES;
        match self.variables.iter_mut().find(|(n, _)| n == name) {
            Some((_, held)) => *held = value,
            None if room => self.variables.push((name.to_string(), value)),
            None => return Err(Refusal::OutOfRange),
        }
        Ok(Reply::Done)
    }

    /// MG's operands (`_TPA`, `_BN`, `_TC`, `_TM`), variables and quoted strings.
    fn message(&self, text: &str) -> Result<String, Refusal> {
        let mut parts = Vec::new();
        for item in text.split(',').map(str::trim) {
            if let Some(quoted) = item.strip_prefix('"').and_then(|t| t.strip_suffix('"')) {
                parts.push(quoted.to_string());
                continue;
            }
            if let Some((_, value)) = self.variables.iter().find(|(name, _)| name == item) {
                parts.push(format!("{value:10.4}"));
                continue;
            }
            let operand = item.strip_prefix('_').ok_or(Refusal::Unrecognized)?;
            let value = match operand {
                "BN" => f64::from(SERIAL_NUMBER),
                "TC" => f64::from(self.error_code),
                "TM" => 1000.0,
                _ => {
                    let (name, letter) = (operand.get(..2), operand.get(2..));
                    let (Some(name), Some(letter)) = (name, letter) else { return Err(Refusal::Unrecognized) };
                    if letter.len() != 1 {
                        return Err(Refusal::Unrecognized);
                    }
                    let i = self.axis_list(letter)?[0];
                    self.axes[i].operand(name).ok_or(Refusal::Unrecognized)?
                }
            };
            parts.push(fixed(value, 4));
        }
        Ok(parts.join(" "))
    }

    /// The data record: header, general block, coordinated block, one block an axis.
    fn record(&self) -> Vec<u8> {
        let length = HEADER + GENERAL + COORDINATED + AXIS_BLOCK * self.axes.len();
        let mut record = vec![0; HEADER + GENERAL + COORDINATED];
        record[0] = 0x87;
        record[1] = ((1u16 << self.axes.len()) - 1) as u8;
        record[2..4].copy_from_slice(&(length as u16).to_le_bytes());
        let sample = (self.now.as_secs_f64() * 1000.0) as u64 as u16;
        record[4..6].copy_from_slice(&sample.to_le_bytes());
        record[6..16].fill(0xFF);
        record[50] = self.error_code;
        for axis in &self.axes {
            record.extend(axis.block());
        }
        record
    }
}

/// A decimal number, its sign and fraction optional.
fn number(text: &str) -> Option<f64> {
    let digits = text.strip_prefix(['+', '-']).unwrap_or(text);
    let valid = !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit() || b == b'.') && digits != ".";
    valid.then(|| text.parse().ok()).flatten()
}

impl Emulator for GalilEmulator {
    fn name(&self) -> &'static str {
        "galil"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        self.now = now;
        for axis in &mut self.axes {
            axis.sim.advance(now);
            axis.settle();
        }
        for line in self.lines.push(bytes) {
            let mut answer = Vec::new();
            for command in line.split(|b| *b == b';') {
                let text = std::str::from_utf8(command).ok().map(|t| t.trim_matches(|c: char| c == ' ' || c == '\n'));
                if text == Some("") {
                    continue;
                }
                match text.ok_or(Refusal::Unrecognized).and_then(|t| self.command(t)) {
                    Ok(Reply::Done) => answer.push(b':'),
                    Ok(Reply::Text(text)) => answer.extend(format!("{text}\r\n:").bytes()),
                    Ok(Reply::Binary(bytes)) => {
                        answer.extend(bytes);
                        answer.push(b':');
                    }
                    Err(refusal) => {
                        self.error_code = refusal.code();
                        self.malformed += usize::from(refusal.malformed());
                        answer.push(b'?');
                    }
                }
                self.axes.iter_mut().for_each(Axis::settle);
            }
            if !answer.is_empty() {
                self.output.push_back(answer);
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
        self.axes.get_mut(channel).map(|axis| &mut axis.sim)
    }

    /// An off-on-error: the motor is turned off, stop code 8, TS bit 6 until `SH`.
    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(axis) = self.axes.get_mut(channel) else { return false };
        axis.motor(false);
        axis.stop_code = 8;
        axis.error_exceeded = true;
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

    fn dmc() -> GalilEmulator {
        GalilEmulator::new(4, &stage())
    }

    fn say_bytes(e: &mut GalilEmulator, ms: u64, line: &str) -> Vec<u8> {
        e.handle_input(at(ms), format!("{line}\r").as_bytes());
        let reply = e.poll_transmit().expect("answered");
        assert!(e.poll_transmit().is_none(), "one piece a line");
        reply
    }

    fn say(e: &mut GalilEmulator, ms: u64, line: &str) -> String {
        String::from_utf8(say_bytes(e, ms, line)).expect("ASCII")
    }

    fn record(e: &mut GalilEmulator, ms: u64) -> Vec<u8> {
        let mut reply = say_bytes(e, ms, "QR");
        assert_eq!(reply.pop(), Some(b':'));
        reply
    }

    fn axis_block(record: &[u8], i: usize) -> &[u8] {
        &record[82 + 36 * i..82 + 36 * (i + 1)]
    }

    fn long(block: &[u8], at: usize) -> i32 {
        i32::from_le_bytes(block[at..at + 4].try_into().unwrap())
    }

    #[test]
    fn variables_are_created_by_assignment_and_reported() {
        let mut e = GalilEmulator::new(2, &crate::stage());
        e.handle_input(Instant::ZERO, b"limdcA=1999872;nrmdcA=9216;SPA=2000\r");
        let mut reply = Vec::new();
        while let Some(bytes) = e.poll_transmit() {
            reply.extend(bytes);
        }
        assert_eq!(reply, b":::");
        e.handle_input(Instant::ZERO, b"MG limdcA\r");
        let reply = e.poll_transmit().expect("a reply");
        assert_eq!(String::from_utf8_lossy(&reply), "1999872.0000\r\n:");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn identification_and_each_command_of_a_line_answered() {
        let mut e = dmc();
        assert_eq!(say(&mut e, 0, "\x12\x16"), "DMC4040 Rev 1.2f\r\n:");
        assert_eq!(say(&mut e, 0, "WH"), "IHA\r\n:");
        assert_eq!(say(&mut e, 0, "QZ"), "4, 52, 26, 36\r\n:");
        assert_eq!(say(&mut e, 0, "MG _BN"), " 12345.0000\r\n:");
        assert_eq!(say(&mut e, 0, "SPA=1000;SPB=2000;SP ?,?;MTA=?"), ":: 1000, 2000\r\n: 1.0\r\n:");
        assert_eq!(
            say(&mut e, 0, "ACA=1000;ACA=?;DC 3000,,5000000;DC ?,?,?"),
            ": 1024\r\n:: 3072, 256000, 5000192\r\n:"
        );
        assert_eq!(
            say(&mut e, 0, "TPA;MG _TPA, _MOA;TS;SC"),
            " 0\r\n: 0.0000  1.0000\r\n: 47, 47, 47, 47\r\n: 0, 0, 0, 0\r\n:"
        );
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_move_runs_then_stops_at_the_target_with_stop_code_1() {
        let mut e = dmc();
        assert_eq!(say(&mut e, 0, "SHA;SPA=10000;ACA=102400;DCA=102400;PAA=10000;BGA"), "::::::");
        let moving = record(&mut e, 500);
        let block = axis_block(&moving, 0);
        let status = u16::from_le_bytes([block[0], block[1]]);
        assert_eq!(status & 0xE001, 0xE000, "move in progress, PA, motor on: {status:#06x}");
        assert_eq!(block[3], 0, "running");
        assert!((0..10_000).contains(&long(block, 8)));
        assert_eq!(long(block, 4), long(block, 8), "RP = TP");
        assert!(long(block, 20) > 0, "velocity");
        assert_eq!(say(&mut e, 500, "MG _BGA"), " 1.0000\r\n:");
        assert_eq!(say(&mut e, 500, "BGA"), "?");
        assert_eq!(say(&mut e, 500, "TC1"), "21 Begin not valid while running\r\n:");
        assert_eq!(say(&mut e, 2000, "TPA;SCA;MG _BGA"), " 10000\r\n: 1\r\n: 0.0000\r\n:");
        let done = record(&mut e, 2000);
        assert_eq!(u16::from_le_bytes([done[82], done[83]]) & 0x8000, 0);
        assert_eq!(done[82 + 3], 1);
        assert_eq!(say(&mut e, 2000, "PRA=-500;BGA"), "::");
        assert_eq!(say(&mut e, 3000, "TPA;TDA"), " 9500\r\n: 9500\r\n:");
    }

    #[test]
    fn a_jog_runs_until_st_decelerates_it() {
        let mut e = dmc();
        say(&mut e, 0, "SH AB;JGB=-5000;ACB=1024000;DCB=10240;BG B");
        assert_eq!(say(&mut e, 1000, "TPB;TVB"), "-4988\r\n:-5000\r\n:");
        assert_eq!(say(&mut e, 1000, "STB;MG _BGB"), ": 1.0000\r\n:", "still decelerating");
        let status = u16::from_le_bytes(axis_block(&record(&mut e, 1000), 1)[0..2].try_into().unwrap());
        assert_eq!(status & 0x8090, 0x8090, "moving, negative, stopping: {status:#06x}");
        assert_eq!(say(&mut e, 2000, "MG _BGB;SCB"), " 0.0000\r\n: 4\r\n:");
    }

    #[test]
    fn hm_and_bg_end_at_zero_with_stop_code_10() {
        let mut e = dmc();
        say(&mut e, 0, "SHC;PAC=3000;BGC");
        assert_eq!(say(&mut e, 1000, "TPC;DPC=777;TPC;MG _HMC"), " 3000\r\n:: 777\r\n: 1.0000\r\n:");
        assert_eq!(say(&mut e, 1000, "HMC;BGC"), "::");
        let homing = u16::from_le_bytes(axis_block(&record(&mut e, 1010), 2)[0..2].try_into().unwrap());
        assert_eq!(homing & 0x8800, 0x8800, "{homing:#06x}");
        assert_eq!(say(&mut e, 2000, "TPC;SCC;MG _BGC"), " 0\r\n: 10\r\n: 0.0000\r\n:");
        let homed = u16::from_le_bytes(axis_block(&record(&mut e, 2000), 2)[0..2].try_into().unwrap());
        assert_eq!(homed, 0x0600, "phases 1 and 2 complete");
        assert_eq!(e.axis(2).unwrap().physical_position(), 0.0, "on the switch");
        say(&mut e, 2000, "PRC=100;BGC;");
        assert_eq!(say(&mut e, 3000, "FEC;BGC"), "::");
        assert_eq!(say(&mut e, 4000, "TPC;SCC"), " 0\r\n: 9\r\n:");
    }

    #[test]
    fn a_motor_off_refuses_bg_and_stops_at_once() {
        let mut e = dmc();
        assert_eq!(say(&mut e, 0, "PRA=1000;BGA"), ":?");
        assert_eq!(say(&mut e, 0, "TC1;TC;MG _TC"), "20 Begin not valid with motor off\r\n:20\r\n: 20.0000\r\n:");
        assert_eq!(e.malformed(), 0, "a refusal of state is not malformed");
        assert_eq!(say(&mut e, 0, "SHA;BGA;TSA"), ":: 143\r\n:");
        assert_eq!(say(&mut e, 100, "MOA;MG _MOA;SCA;TSA"), ": 1.0000\r\n: 7\r\n: 47\r\n:");
        let position = say(&mut e, 100, "TPA");
        assert_eq!(say(&mut e, 1000, "TPA"), position);
        assert!(e.raise_error(1) && !e.raise_error(4));
        assert_eq!(say(&mut e, 1000, "SCB;TSB"), " 8\r\n: 111\r\n:", "off-on-error");
        assert_eq!(say(&mut e, 1000, "SHB;TSB"), ": 15\r\n:");
    }

    #[test]
    fn limits_read_one_when_inactive_and_stop_motion() {
        let mut e = dmc();
        assert_eq!(axis_block(&record(&mut e, 0), 3)[2] & 0b1100, 0b1100, "both inactive");
        say(&mut e, 0, "SHD;SPD=400000;JGD=400000;ACD=1048576;BGD");
        assert_eq!(say(&mut e, 2000, "SCD;MG _LFD, _LRD;TPD"), " 2\r\n: 0.0000  1.0000\r\n: 200000\r\n:");
        assert_eq!(axis_block(&record(&mut e, 2000), 3)[2] & 0b1100, 0b0100);
        assert_eq!(say(&mut e, 2000, "BGD;TC1"), "?22 Begin not possible due to Limit Switch\r\n:");
        say(&mut e, 2000, "FLA=1000;SHA;PAA=5000;SPA=100000;BGA");
        assert_eq!(say(&mut e, 3000, "TPA;SCA;BGA"), " 1000\r\n: 2\r\n:?", "cut at FL");
        assert_eq!(say(&mut e, 3000, "FLA=?;BL ?"), " 1000\r\n:-2147483648\r\n:");
    }

    #[test]
    fn the_record_is_laid_out_as_qz_says() {
        let mut e = GalilEmulator::new(8, &stage());
        assert_eq!(say(&mut e, 0, "QZ"), "8, 52, 26, 36\r\n:");
        let r = record(&mut e, 1234);
        assert_eq!(r.len(), 370);
        assert_eq!((r[0], r[1], u16::from_le_bytes([r[2], r[3]])), (0x87, 0xFF, 370));
        assert_eq!(u16::from_le_bytes([r[4], r[5]]), 1234, "sample counter, ms");
        say(&mut e, 0, "SHH;DPH=-42;XX");
        let r = record(&mut e, 1234);
        assert_eq!(r[50], 1, "the last TC code");
        let h = axis_block(&r, 7);
        assert_eq!((long(h, 4), long(h, 8), long(h, 12), long(h, 16)), (-42, -42, 0, 0), "DP leaves TD");
        assert_eq!((h[2], h[3]), (0b1110, 0), "limits inactive, on the home switch");
        let mut small = GalilEmulator::new(1, &stage());
        let r = record(&mut small, 0);
        assert_eq!((r[1], u16::from_le_bytes([r[2], r[3]]), r.len()), (0x01, 118, 118));
        assert_eq!(say(&mut small, 0, "\x12\x16"), "DMC4010 Rev 1.2f\r\n:");
    }

    #[test]
    fn pieces_unknown_commands_and_ranges() {
        let mut e = dmc();
        e.handle_input(at(0), b"SP");
        e.handle_input(at(0), b"A=2");
        assert!(e.poll_transmit().is_none());
        e.handle_input(at(0), b"4\rSPA=?\r");
        assert_eq!(e.poll_transmit().unwrap(), b":");
        assert_eq!(e.poll_transmit().unwrap(), b" 24\r\n:");
        assert_eq!(say(&mut e, 0, "XY;TC1"), "?1 Unrecognized command\r\n:");
        assert_eq!(say(&mut e, 0, "bg"), "?");
        assert_eq!(say(&mut e, 0, "SPA=30000000;TC"), "?6\r\n:");
        assert_eq!(say(&mut e, 0, "TPE"), "?", "four axes");
        assert_eq!(say(&mut e, 0, "SPA=12x"), "?");
        assert_eq!(e.malformed(), 5);
        assert_eq!(say(&mut e, 0, "TH;SPA=?"), "? 24\r\n:", "known, not carried out");
        assert_eq!(e.malformed(), 5);
        assert_eq!(e.name(), "galil");
    }
}
