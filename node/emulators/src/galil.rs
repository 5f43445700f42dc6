//! A Galil DMC-4040 (a DMC-40x0 of one to eight axes, A to H, the first four also X, Y, Z, W),
//! reached over Ethernet (TCP port 23): Galil's two-letter ASCII commands, `:` for done, `?` for
//! refused, the binary data record of `QR`; one simulator step a count, every axis a servo (MT 1).
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
//! 7. What clients send and read: gclibo.h's axis letters "XYZWABCDEFGHST" (X to W naming A to
//!    D); motorapp/Galil's GalilController.cpp: `TH` read for the MAC after "ETHERNET ADDRESS",
//!    `HXn` for each thread, `DL` CR then the program then `\` answered `::`, `UL` read up to
//!    Ctrl-Z then `:` (CR LF line ends), `MG _TM` for the time base.
//! 8. The DMC-40x0 command reference's `( )` page: expressions are read left to right, with no
//!    precedence but parentheses (`MG 1 + 2 * 3` answers 9); math `+ - * /`, logic `& |`.
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Variables**: `name=value`, a name of a letter then up to 7 letters and digits that is no
//!   command, creates the variable or sets it (510 at most: TC 6 beyond), as the user manual's
//!   chapter on programming has variables created by assignment; `MG name` reports it. No program
//!   runs here, so they change nothing else.
//! - **Expressions**: a value assigned, a setting's argument (`DCA=nrmdcA`, `SPA=_SPB`) and MG's
//!   items are expressions: numbers, variables, operands (`_XXa`, `_BN`, `_TC`, `_TM`) and TIME
//!   (the sample counter, in ms), joined left to right by `+ - * /`, `= < > <= >= <>` (1 or 0) and
//!   `& |` (bit by bit on the 32.16 fixed point), with parentheses and signs. An unknown name or
//!   anything else unread is TC 1; a division by 0 TC 6.
//! - **Programs**: `DL` answers `:` and takes the bytes after it (the rest of its line included)
//!   up to `\` or Ctrl-Z as the program, answering `:` at its end (`?`, TC 6, beyond 4000 lines
//!   of 80 characters); a connection closed drops a download under way. `UL` answers the program
//!   with CR LF line ends, then Ctrl-Z and `:`. No program runs: `XQ` and `HX`/`HXn` answer `:`.
//! - **Identity**: `TH` answers the address 127,0,0,1, the MAC 00-50-4C-00 then the serial
//!   number's two low bytes, handle A the host's TCP connection, B to H available; `ID` one line,
//!   the model, its axes and no internal amplifier (motorapp reads no `AMP1,` then).
//! - **Power-on**: every motor off (MO); `BG` is refused (TC 20) until `SH`. SP 25 000, AC and
//!   DC 256 000, JG 25 000, KP 6, KI 0, KD 64, ER 16 384, OE 0, FL 2 147 483 647 and BL
//!   −2 147 483 648 (no software limits), stop code 0, TC 0.
//! - **Formats**: interrogations (TP, TD, TE, TS, SC, TV, RP, `XX ?`, `XXA=?`) answer integers
//!   with a space where a sign would go (` 1000`, `-5`), several comma-separated; MT answers one
//!   decimal (` 1.0`), KP/KI/KD four. `MG` answers VF 10.4 (` 1000.0000`); `MG "text"` the text;
//!   several operands space-separated; an expression as ` 1.0000`. QZ answers `n, 52, 26, 36`,
//!   `TM ?` ` 1000`. `TC1` with no error answers `0`; reading the code does not clear it.
//! - **Refusals**: an unknown command, bad syntax, an axis not installed and too many fields
//!   are TC 1 and malformed; a number out of range TC 6 and malformed; a refusal for a reason
//!   of state (BG motor off 20, moving 21, toward an active limit or beyond FL/BL 22; DP, DE,
//!   MT on a moving axis 7) is not malformed. Known commands not carried out (LZ, PF, VF, IH,
//!   BN, `TM n`, `DR n` for a rate not 0 as no record is streamed, `QR` or `DL #` with
//!   arguments…) answer TC 1, not malformed. Each command of a line is answered, an error not
//!   stopping the ones after it. Lines hold 1024 bytes at most.
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
//!   set the record's stepper bit and change nothing else. CN, EO, CF, CW and `DR 0` are taken
//!   and change nothing.
//! - **Record**: inputs read all ones (nothing wired), outputs 0, handle bytes, threads,
//!   amplifier status, contour and planes 0; the sample counter counts milliseconds. `raise_error`
//!   is an off-on-error: the motor off, stop code 8, TS bit 6, until `SH`.

use crate::emulator::axes;
use crate::{Connection, Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

const LETTERS: &[u8; 8] = b"ABCDEFGH";
/// The other names of axes A to D (gclibo.h's axis letters, "XYZWABCDEFGHST").
const ALIASES: &[u8; 4] = b"XYZW";
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
/// TM: the sample period, microseconds.
const SAMPLE_PERIOD: f64 = 1000.0;
/// How deep an expression's parentheses and signs may nest.
const EXPRESSION_DEPTH: usize = 32;

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
    /// The bytes of a program being downloaded, from `DL` until its `\` or Ctrl-Z.
    download: Option<Vec<u8>>,
    /// The program last downloaded, a line an entry; kept and uploaded, never run.
    program: Vec<String>,
}

/// The program memory of a DMC-40x0: lines, and characters a line.
const PROGRAM_LINES: usize = 4000;
const PROGRAM_COLUMNS: usize = 80;
/// More bytes than the longest program holds (CR LF line ends): a download is cut there.
const PROGRAM_BYTES: usize = PROGRAM_LINES * (PROGRAM_COLUMNS + 2) + 1;
/// What ends a download: `\`, or Ctrl-Z.
const END_OF_PROGRAM: [u8; 2] = [b'\\', 0x1A];

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
            download: None,
            program: Vec::new(),
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
            let i = LETTERS.iter().position(|l| *l == letter).or_else(|| ALIASES.iter().position(|l| *l == letter));
            let i = i.filter(|i| *i < self.axes.len());
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
            let value = self.evaluate(value)?;
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
            "TH" if rest.trim().is_empty() => Ok(Reply::Text(self.handles())),
            "ID" if rest.trim().is_empty() => {
                let axes = self.axes.len();
                let last = char::from(LETTERS[axes - 1]);
                Ok(Reply::Text(format!("DMC40{axes}0, AXES A-{last}, NO INTERNAL AMPLIFIER")))
            }
            "TM" if rest.trim() == "?" => Ok(Reply::Text(integer(SAMPLE_PERIOD))),
            "MG" => self.message(rest.trim()).map(Reply::Text),
            // No record is streamed here: a rate is refused, as a command not carried out.
            "DR" => match rest.split(',').next().map(str::trim).unwrap_or("") {
                "" => done,
                rate => match number(rate) {
                    Some(0.0) => done,
                    Some(_) => Err(Refusal::NotCarriedOut),
                    None => Err(Refusal::Unrecognized),
                },
            },
            "DL" if rest.trim().is_empty() => {
                self.download = Some(Vec::new());
                done
            }
            "UL" if rest.trim().is_empty() => {
                let mut text: Vec<u8> =
                    self.program.iter().flat_map(|line| format!("{line}\r\n").into_bytes()).collect();
                text.push(0x1A);
                Ok(Reply::Binary(text))
            }
            // No program runs here: XQ starts nothing and HX has no thread to halt.
            "XQ" => done,
            "HX" if rest.trim().is_empty() || rest.trim().parse::<u8>().is_ok_and(|thread| thread < 8) => done,
            "CN" | "EO" | "CF" | "CW" => done,
            "TH" | "ID" | "UL" | "DL" | "HX" | "LZ" | "PF" | "VF" | "IH" | "BN" | "TM" => Err(Refusal::NotCarriedOut),
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
            values.push((i, setting.accept(self.evaluate(field)?)?));
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

    /// MG's items, comma-separated: quoted strings, variables (VF 10.4) and expressions over
    /// operands (`_TPA`, `_BN`, `_TC`, `_TM`), variables, numbers and TIME (` 1.0000`).
    fn message(&self, text: &str) -> Result<String, Refusal> {
        let mut parts = Vec::new();
        for item in text.split(',').map(str::trim) {
            if let Some(quoted) = item.strip_prefix('"').and_then(|t| t.strip_suffix('"')) {
                parts.push(quoted.to_string());
            } else if let Some(value) = self.variable(item) {
                parts.push(format!("{value:10.4}"));
            } else {
                parts.push(fixed(self.evaluate(item)?, 4));
            }
        }
        Ok(parts.join(" "))
    }

    /// The value of the variable `name`, if there is one.
    fn variable(&self, name: &str) -> Option<f64> {
        self.variables.iter().find(|(held, _)| held == name).map(|(_, value)| *value)
    }

    /// An expression, read left to right as the controller does (no precedence but that of
    /// parentheses): `MG 1+2*3` is 9. What it cannot read is refused, TC 1.
    fn evaluate(&self, text: &str) -> Result<f64, Refusal> {
        let mut reader = Reader { text: text.as_bytes(), at: 0 };
        let value = self.expression(&mut reader, 0)?;
        reader.skip_spaces();
        if reader.at == reader.text.len() {
            Ok(value)
        } else {
            Err(Refusal::Unrecognized)
        }
    }

    /// Terms joined by operators, up to the end or a `)`.
    fn expression(&self, reader: &mut Reader, depth: usize) -> Result<f64, Refusal> {
        let mut value = self.term(reader, depth)?;
        while let Some(operator) = reader.operator() {
            value = apply(operator, value, self.term(reader, depth)?)?;
        }
        Ok(value)
    }

    /// A parenthesised expression, a signed term, or an atom.
    fn term(&self, reader: &mut Reader, depth: usize) -> Result<f64, Refusal> {
        // Nesting bounded so that a line of parentheses cannot exhaust the stack.
        if depth > EXPRESSION_DEPTH {
            return Err(Refusal::Unrecognized);
        }
        reader.skip_spaces();
        match reader.text.get(reader.at) {
            Some(b'(') => {
                reader.at += 1;
                let value = self.expression(reader, depth + 1)?;
                reader.skip_spaces();
                if reader.text.get(reader.at) != Some(&b')') {
                    return Err(Refusal::Unrecognized);
                }
                reader.at += 1;
                Ok(value)
            }
            Some(b'-') => {
                reader.at += 1;
                Ok(-self.term(reader, depth + 1)?)
            }
            Some(b'+') => {
                reader.at += 1;
                self.term(reader, depth + 1)
            }
            _ => self.atom(reader.word()),
        }
    }

    /// A number, TIME (the sample counter), a variable or an operand.
    fn atom(&self, word: &str) -> Result<f64, Refusal> {
        if let Some(value) = number(word) {
            return Ok(value);
        }
        if word == "TIME" {
            return Ok(self.samples() as f64);
        }
        if let Some(value) = self.variable(word) {
            return Ok(value);
        }
        let operand = word.strip_prefix('_').ok_or(Refusal::Unrecognized)?;
        Ok(match operand {
            "BN" => f64::from(SERIAL_NUMBER),
            "TC" => f64::from(self.error_code),
            "TM" => SAMPLE_PERIOD,
            _ => {
                let (Some(name), Some(letter)) = (operand.get(..2), operand.get(2..)) else {
                    return Err(Refusal::Unrecognized);
                };
                if letter.len() != 1 {
                    return Err(Refusal::Unrecognized);
                }
                let i = self.axis_list(letter)?[0];
                self.axes[i].operand(name).ok_or(Refusal::Unrecognized)?
            }
        })
    }

    /// The sample counter: samples of TM (1000 µs) since power-on.
    fn samples(&self) -> u64 {
        (self.now.as_secs_f64() * 1000.0) as u64
    }

    /// TH: this controller's address, then its eight handles, the first the host's.
    fn handles(&self) -> String {
        let [.., high, low] = SERIAL_NUMBER.to_be_bytes();
        let mut lines = vec![
            format!("CONTROLLER IP ADDRESS 127,0,0,1 ETHERNET ADDRESS 00-50-4C-00-{high:02X}-{low:02X}"),
            "IHA TCP PORT 23 TO IP ADDRESS 127,0,0,1 PORT 50000".to_string(),
        ];
        lines.extend(LETTERS[1..].iter().map(|handle| format!("IH{} AVAILABLE", char::from(*handle))));
        lines.join("\r\n")
    }

    /// Bytes of a download; how many it took (up to and with its end, if there). Its end
    /// answers `:` once the program is stored, `?` (TC 6) if it does not fit.
    fn take_program(&mut self, bytes: &[u8]) -> usize {
        let Some(download) = self.download.as_mut() else { return 0 };
        let end = bytes.iter().position(|b| END_OF_PROGRAM.contains(b));
        let body = &bytes[..end.unwrap_or(bytes.len())];
        download.extend_from_slice(&body[..body.len().min(PROGRAM_BYTES - download.len())]);
        let Some(end) = end else { return bytes.len() };
        let text = String::from_utf8_lossy(&self.download.take().unwrap_or_default()).replace("\r\n", "\r");
        // The LF of a CR LF ending `DL` comes first; a last line's end leaves an empty piece.
        let text = text.strip_prefix('\n').unwrap_or(&text).replace('\n', "\r");
        let mut lines: Vec<String> = text.split('\r').map(str::to_string).collect();
        if lines.last().is_some_and(String::is_empty) {
            lines.pop();
        }
        let fits = lines.len() <= PROGRAM_LINES && lines.iter().all(|line| line.len() <= PROGRAM_COLUMNS);
        let answer = if fits {
            self.program = lines;
            b':'
        } else {
            self.refuse(Refusal::OutOfRange)
        };
        self.output.push_back(vec![answer]);
        end + 1
    }

    /// The refusal recorded (TC, and counted if malformed); the byte that answers it.
    fn refuse(&mut self, refusal: Refusal) -> u8 {
        self.error_code = refusal.code();
        self.malformed += usize::from(refusal.malformed());
        b'?'
    }

    /// One line's commands answered, as one piece. After a `DL`, what follows it on the line
    /// is the start of the program: returned, to be taken as a download.
    fn answer_line(&mut self, line: &[u8]) -> Option<Vec<u8>> {
        let mut answer = Vec::new();
        let mut rest = None;
        let mut start = 0;
        for command in line.split(|b| *b == b';') {
            start += command.len() + 1;
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
                Err(refusal) => answer.push(self.refuse(refusal)),
            }
            self.axes.iter_mut().for_each(Axis::settle);
            if self.download.is_some() {
                rest = line.get(start..).filter(|rest| !rest.is_empty()).map(|rest| [rest, CR].concat());
                break;
            }
        }
        if !answer.is_empty() {
            self.output.push_back(answer);
        }
        rest
    }

    /// The data record: header, general block, coordinated block, one block an axis.
    fn record(&self) -> Vec<u8> {
        let length = HEADER + GENERAL + COORDINATED + AXIS_BLOCK * self.axes.len();
        let mut record = vec![0; HEADER + GENERAL + COORDINATED];
        record[0] = 0x87;
        record[1] = ((1u16 << self.axes.len()) - 1) as u8;
        record[2..4].copy_from_slice(&(length as u16).to_le_bytes());
        let sample = self.samples() as u16;
        record[4..6].copy_from_slice(&sample.to_le_bytes());
        record[6..16].fill(0xFF);
        record[50] = self.error_code;
        for axis in &self.axes {
            record.extend(axis.block());
        }
        record
    }
}

/// Where an expression is being read.
struct Reader<'a> {
    text: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn skip_spaces(&mut self) {
        while self.text.get(self.at) == Some(&b' ') {
            self.at += 1;
        }
    }

    /// A number, a name or an operand: letters, digits, `_` and `.`.
    fn word(&mut self) -> &str {
        let start = self.at;
        while self.text.get(self.at).is_some_and(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'.')) {
            self.at += 1;
        }
        std::str::from_utf8(&self.text[start..self.at]).unwrap_or_default()
    }

    /// The operator next, if one is.
    fn operator(&mut self) -> Option<&'static str> {
        self.skip_spaces();
        let rest = &self.text[self.at..];
        let operator = ["<=", ">=", "<>", "+", "-", "*", "/", "=", "<", ">", "&", "|"]
            .into_iter()
            .find(|operator| rest.starts_with(operator.as_bytes()))?;
        self.at += operator.len();
        Some(operator)
    }
}

/// `left operator right`; comparisons give 1 or 0, `&` and `|` work bit by bit on the
/// controller's fixed point (32 bits of integer, 16 of fraction).
fn apply(operator: &str, left: f64, right: f64) -> Result<f64, Refusal> {
    let flag = |holds: bool| f64::from(u8::from(holds));
    let bits = |value: f64| (value * 65_536.0).round() as i64;
    Ok(match operator {
        "+" => left + right,
        "-" => left - right,
        "*" => left * right,
        "/" if right == 0.0 => return Err(Refusal::OutOfRange),
        "/" => left / right,
        "=" => flag(left == right),
        "<" => flag(left < right),
        ">" => flag(left > right),
        "<=" => flag(left <= right),
        ">=" => flag(left >= right),
        "<>" => flag(left != right),
        "&" => (bits(left) & bits(right)) as f64 / 65_536.0,
        "|" => (bits(left) | bits(right)) as f64 / 65_536.0,
        _ => return Err(Refusal::Unrecognized),
    })
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
        // Line by line, since a `DL` turns what follows it into a program's raw bytes.
        let mut bytes = bytes.to_vec();
        let mut at = 0;
        while at < bytes.len() {
            if self.download.is_some() {
                at += self.take_program(&bytes[at..]);
                continue;
            }
            let end = bytes[at..].iter().position(|b| *b == CR[0]).map_or(bytes.len(), |i| at + i + 1);
            for line in self.lines.push(&bytes[at..end]) {
                if let Some(program) = self.answer_line(&line) {
                    bytes.splice(end..end, program);
                }
            }
            at = end;
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

    /// A download the connection was in the middle of is dropped, the program kept.
    fn handle_closed(&mut self, connection: Connection) {
        let _ = connection;
        self.download = None;
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

    /// Every piece answered to `bytes`, joined.
    fn send(e: &mut GalilEmulator, ms: u64, bytes: &[u8]) -> String {
        e.handle_input(at(ms), bytes);
        let mut reply = Vec::new();
        while let Some(piece) = e.poll_transmit() {
            reply.extend(piece);
        }
        String::from_utf8(reply).expect("ASCII")
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
        assert_eq!(say(&mut e, 0, "VF 10.4;SPA=?"), "? 24\r\n:", "known, not carried out");
        assert_eq!(e.malformed(), 5);
        assert_eq!(e.name(), "galil");
    }

    #[test]
    fn x_y_z_w_name_axes_a_to_d() {
        let mut e = dmc();
        assert_eq!(
            say(&mut e, 0, "SPX=1000;SPY=2000;SP ?,?;SPZ=?;MG _SPW"),
            ":: 1000, 2000\r\n: 25000\r\n: 25000.0000\r\n:"
        );
        assert_eq!(say(&mut e, 0, "SH XW;PRW=-300;BG W"), ":::");
        assert_eq!(say(&mut e, 1000, "TPW;TPD;TP XY;SCW"), "-300\r\n:-300\r\n: 0, 0\r\n: 1\r\n:");
        assert_eq!(e.malformed(), 0);
        let mut two = GalilEmulator::new(2, &stage());
        assert_eq!(say(&mut two, 0, "TPZ;MG _TPW;SPZ=100;TPY"), "??? 0\r\n:", "Z and W name C and D, not installed");
    }

    #[test]
    fn th_lists_the_handles_and_id_the_hardware() {
        let mut e = dmc();
        let th = say(&mut e, 0, "TH");
        let mut expected = String::from(
            "CONTROLLER IP ADDRESS 127,0,0,1 ETHERNET ADDRESS 00-50-4C-00-30-39\r\n\
             IHA TCP PORT 23 TO IP ADDRESS 127,0,0,1 PORT 50000\r\n",
        );
        for handle in "BCDEFGH".chars() {
            expected += &format!("IH{handle} AVAILABLE\r\n");
        }
        assert_eq!(th, expected + ":");
        // motorapp's extractEthAddr: the 17 characters after "ETHERNET ADDRESS ".
        let start = th.find("ETHERNET ADDRESS").unwrap() + "ETHERNET ADDRESS ".len();
        assert_eq!(&th[start..start + 17], "00-50-4C-00-30-39");
        assert_eq!(say(&mut e, 0, "ID"), "DMC4040, AXES A-D, NO INTERNAL AMPLIFIER\r\n:");
        assert_eq!(say(&mut e, 0, "TH 1;TC1"), "?1 Unrecognized command\r\n:");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn tm_is_read_and_dr_streams_nothing() {
        let mut e = dmc();
        assert_eq!(say(&mut e, 0, "TM ?;TM?;MG _TM"), " 1000\r\n: 1000\r\n: 1000.0000\r\n:");
        assert_eq!(say(&mut e, 0, "DR 0;DR 0,0;DR"), ":::");
        assert_eq!(say(&mut e, 0, "DR 8,0;TC1"), "?1 Unrecognized command\r\n:", "no record is streamed");
        assert_eq!(say(&mut e, 0, "TM 500;DR 2"), "??");
        assert_eq!(e.malformed(), 0, "not carried out, not malformed");
        assert_eq!(say(&mut e, 0, "DR x"), "?");
        assert_eq!(e.malformed(), 1);
        assert_eq!(e.poll_transmit(), None, "nothing streamed");
    }

    #[test]
    fn a_setting_takes_a_variable_or_an_operand() {
        let mut e = dmc();
        assert_eq!(say(&mut e, 0, "nrmdcA=9216;DCA=nrmdcA;DCA=?"), ":: 9216\r\n:");
        assert_eq!(say(&mut e, 0, "SPB=3000;SPA=_SPB;SPA=?"), ":: 3000\r\n:");
        assert_eq!(say(&mut e, 0, "SP _SPA*2,,nrmdcA;SP ?,?,?"), ": 6000, 3000, 9216\r\n:");
        assert_eq!(say(&mut e, 0, "half=_SPA/2;MG half"), ": 3000.0000\r\n:");
        assert_eq!(e.malformed(), 0);
        assert_eq!(say(&mut e, 0, "SPA=nosuch;TC1;SPA=_XXA;SPA=?"), "?1 Unrecognized command\r\n:? 6000\r\n:");
        assert_eq!(say(&mut e, 0, "SPA=_SPB*100000;TC"), "?6\r\n:", "still within range");
    }

    #[test]
    fn mg_reads_expressions_left_to_right() {
        let mut e = dmc();
        assert_eq!(say(&mut e, 0, "MG (_BGA=0), _BGA=1"), " 1.0000  0.0000\r\n:");
        assert_eq!(say(&mut e, 0, "DPA=-42;MG _TPA+10, -_TPA*2"), ":-32.0000  84.0000\r\n:");
        assert_eq!(say(&mut e, 0, "MG 1 + 2 * 3;MG 1 + (2 * 3)"), " 9.0000\r\n: 7.0000\r\n:");
        assert_eq!(
            say(&mut e, 0, "MG 7/2, (5&3)|8, 2<=1, 1<>2, 3>=3, 1<2, 2>1"),
            " 3.5000  9.0000  0.0000  1.0000  1.0000  1.0000  1.0000\r\n:"
        );
        assert_eq!(say(&mut e, 1234, "MG TIME;MG (TIME-34)/100"), " 1234.0000\r\n: 12.0000\r\n:");
        assert_eq!(say(&mut e, 0, "v1=4;MG (v1+_TM/1000)*-1;MG (v1+(_TM/1000))*-1"), ":-1.0040\r\n:-5.0000\r\n:");
        assert_eq!(e.malformed(), 0);
        for unreadable in ["MG (1+2", "MG 1+", "MG 1 2", "MG nosuch+1", "MG _TPQ", "MG 1%2", "MG ()"] {
            assert_eq!(say(&mut e, 0, &format!("{unreadable};TC")), "?1\r\n:", "{unreadable}");
        }
        assert_eq!(say(&mut e, 0, "MG 1/0;TC"), "?6\r\n:");
        let nested = format!("MG {}1{}", "(".repeat(100), ")".repeat(100));
        assert_eq!(say(&mut e, 0, &nested), "?", "nesting bounded");
    }

    #[test]
    fn dl_stores_a_program_that_ul_gives_back() {
        let mut e = dmc();
        assert_eq!(say(&mut e, 0, "UL"), "\x1a:", "no program yet");
        // As motorapp downloads: `DL` CR, then the program with CR line ends and `\`, read `::`.
        assert_eq!(send(&mut e, 0, b"DL\r"), ":");
        assert_eq!(send(&mut e, 0, b"#AUTO\rMG \"HI; THERE\"\r"), "", "taken, not answered");
        assert_eq!(send(&mut e, 0, b"EN\r\\"), ":");
        assert_eq!(say(&mut e, 0, "UL"), "#AUTO\r\nMG \"HI; THERE\"\r\nEN\r\n\x1a:");
        assert_eq!(say(&mut e, 0, "XQ;XQ #AUTO,1;HX;HX0;HX7;TPA"), "::::: 0\r\n:", "no program runs");
        // In one piece, ended by Ctrl-Z, the commands after it answered; the rest of DL's line.
        assert_eq!(send(&mut e, 0, b"SPA=?;DL;#B\r\nEN\x1aTPA\r"), " 25000\r\n::: 0\r\n:");
        assert_eq!(say(&mut e, 0, "UL"), "#B\r\nEN\r\n\x1a:");
        assert_eq!(e.malformed(), 0);
        let too_long = format!("DL\r{}\\", "X".repeat(81));
        assert_eq!(send(&mut e, 0, too_long.as_bytes()), ":?");
        assert_eq!(say(&mut e, 0, "TC;UL"), "6\r\n:#B\r\nEN\r\n\x1a:", "kept");
        assert_eq!(send(&mut e, 0, b"DL\r#C\r"), ":");
        e.handle_closed(0);
        assert_eq!(say(&mut e, 0, "TPA"), " 0\r\n:", "a closed connection ends the download");
        let flood = vec![b'Y'; PROGRAM_BYTES + 10];
        assert_eq!(send(&mut e, 0, b"DL\r") + &send(&mut e, 0, &flood) + &send(&mut e, 0, b"\\"), ":?");
        assert_eq!(say(&mut e, 0, "UL"), "#B\r\nEN\r\n\x1a:");
    }
}
