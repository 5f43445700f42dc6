//! IMS (Schneider Electric Motion, now Novanta IMS) MDrive Plus integrated motors speaking MCode
//! in party mode: up to nine motors share one RS-422/485 line, each named by one character (DN)
//! and answering the lines that begin with its name (`1PR P`), a line ended by LF; `*` addresses
//! every motor at once. Channel n is the motor named `n` (`1` to `9`), one simulator step a
//! microstep.
//!
//! # Witnesses
//!
//! 1. The EPICS driver module motorIms (github.com/epics-motor/motorIms, commit 2aeddf72 of
//!    2025-07-03). `drvMDrive.cc`/`devMDrive.cc` (R. Sluiter, 2003–2011, "verified with firmware
//!    1.071 E, 3.003 (MDI1FRD17B4-EQ), 3.010"): the name is prepended to each command, LF ends
//!    it, CR LF ends a reply; `PR VR` at connection (its answer is the identification, an `E` at
//!    its end meaning an encoder), then `PR PN` (a part number ending `E`, `EQ`, `EE`, `EJM` or
//!    `EJM-N` meaning an encoder), whose answer carries an extra CR LF the driver flushes;
//!    `PR S1`…`PR S4` parsed `%d,%d` (type 1 home switch, 2 plus limit, 3 minus limit, 0
//!    general purpose); polling `PR MV` (0 at rest), `PR P`, `PR I<n>` of the switch inputs (not
//!    0 when active), `PR C2` (encoder counts), `PR V` (the speed, its sign taken from the
//!    direction of travel); commands `MA n`, `MR n`, `P=n`, `C2=n`, `VI=n`, `VM=n`, `A=n` then
//!    `D=A`, `SL=n`, `SL 0` to stop, `DE=1`/`DE=0`, and homing written ` F1000 0`/` F1000 1`.
//!    `ImsMDrivePlusMotorAxis.cpp`/`…Controller.cpp` (N. Fong, SLAC 2011; PSI changes to 2021):
//!    output terminator CR LF, input LF; "the motor is set up for Party Mode (PY=1) and Echo
//!    Mode 2 (EM=2)", so setting commands are written without reading anything back; `PR VR`
//!    (an answer shorter than two characters is a failure; `lmm`/`lmd` in it mean a Lexium);
//!    `PR EE`; `PR S1`…`PR S4`; before a move `VI=n` (if n > 0), `VM=n`, `A=n`, `D=n`, `ST=0`;
//!    `MA n`/`MR n`; `SL n` to jog; `D=n` then `SL 0` to stop; `PR VI` (0 read as "the factory
//!    default of 1000") then `HM 1` (slew at VM in the minus direction until the switch
//!    activates, creep at VI in the plus direction until it deactivates) or `HM 3` (the same
//!    mirrored), then `R1=0`, and `R1=1` when `PR MV` reads 0 again; `P=n`; polling `PR P`,
//!    `PR MV`, `PR I<n>`, `PR R1`, `PR ST` (the stall flag), `PR C2`; `S` to save; after any
//!    failure `PR ER` and the MCode error table (0, 6, 8–12, 20–48, 61–64, 70–75, 80–93 with
//!    their texts). The README's party-mode set-up: name each motor 1–9 with DN, define the
//!    switches with S1–S4, EM=2, PY=1, Ctrl-J, then `<DN>S` saves name, echo mode, I/O set-up
//!    and party mode; "Default step resolution 51,200 steps/rev (MS=256)".
//! 2. IMS "MDrive17Plus Hardware Reference Manual" (MDI hardware manual revision R050406,
//!    page 2-8, as published on manualslib; the MForce MicroDrive manual R112706 has the same
//!    tables 2.3.1–2.3.3): in party mode a command is sent `(DN)(command)(0A)`; with EM=0 it is
//!    echoed character by character and the final response ends `(0D)(0A)>`, the prompt; EM=1
//!    no echo, the response ends CR LF; EM=2 "no response except to PR and L commands"; EM=3 a
//!    queued response ending CR LF.
//! 3. IMS application note "Multiple MDrive Motion Control System — Party Mode" (imshome.com):
//!    PY=1 on every node, a unique DN each, factory name `!`, `*` issues a global command to
//!    every device, and "when using the asterisk in Party Mode, typed entries and commands will
//!    not be echoed"; Ctrl-J activates party mode.
//! 4. Novanta IMS application note "Configuring MDrive I/O: MCode Basics" (MDrive Plus): `S<n>`
//!    takes three parameters, function, active state (0 active low, 1 high) and sink/source;
//!    input functions 0 general purpose, 1 homing, 2 positive limit, 3 negative limit, 4 G0,
//!    5 soft stop, 6 pause, 7 jog plus, 8 jog minus, 11 reset; outputs 16 general purpose,
//!    17 moving, 18 fault, 19 stall, 20 velocity changing.
//! 5. Transcriptions of the MCode manual's error table in other software (pychron's MDrive
//!    driver, 2015; kamzik3's Lexium driver): 20 "Tried to set unknown variable or flag … could
//!    be a typo", 21 "Tried to set an incorrect value … you cannot set the RC to 110%", 22/23
//!    VI not below VM, 24 illegal data, 25 read only, 30 unknown label, 34 "Trying to Execute a
//!    Variable or Flag", 35 "Trying to Print Illegal Variable or Flag", 37 not available in
//!    drive, 38 missing parameter separator, 40 "Program not running. If HOLD (H) is entered in
//!    Immediate Mode", 73 save while moving, 74 IP while moving, 80 home switch not defined, 81
//!    home type not defined "(Types = 1, 2, 3, or 4)", 83/84 plus/minus limit reached, 85 "MA or
//!    MR isn't allowed during a HOME and a HOME isn't allowed while the device is in motion", 86
//!    stall; the Lexium's 94 "Motion commanded while drive disabled (DE=0)".
//! 6. D. van Gils' party-mode MDrive library (python-dvg-devices, 2024) and a CodeProject
//!    series on the MDrive (2012): lower case accepted (`1pr p`); with EM=1 `PR` is answered
//!    `value` CR LF and a bare name CR LF; with EM=0 a bare name is answered `<DN>` CR LF `>`,
//!    `?` in place of `>` while an error is pending; ESC stops every motor, answered `#` CR LF
//!    `>` in EM=0; `PR P,"_"V,"_"MV` concatenates its items; `EF` the error flag, `ER` the
//!    error number, `ER=0` clears errors, `ST=0` the stall; `PR AL` lists every parameter; the
//!    variables A, D, HC, HT, LM (1–6), MS, MT, RC (0–100 %), VI, VM, VC, PN, SN, VR.
//!
//! The "MCode Programming and Software Reference Manual" itself and the MDrive Plus Motion
//! Control product manual's command pages could not be read.
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Power-up**: every motor as the EPICS README has it saved: PY=1, EM=2, CK=0, its name,
//!   S1 = `1,0,0` (home), S2 = `2,0,0` (plus limit), S3 = `3,0,0` (minus limit), S4 = `0,0,0`;
//!   at rest at P = 0, VI 1 000, VM 768 000, A = D = 1 000 000, MS 256, RC 25, HC 5, HT 500,
//!   MT 0, LM 1, EE 0, DE 1, ES 0, R1–R4 0, no error. `PR VR` answers `3.010`, `PR PN`
//!   `MDI1FRD17B4` (`MDI1FRD17B4-EQ` when the mechanics have an encoder), `PR SN` `07350000n`.
//! - **Echo modes**: EM=0 answers the line as received (name included, terminator not), CR LF,
//!   the `PR` text and CR LF if any, then `>` (or `?` while EF is set), all when the line is
//!   complete rather than character by character; EM=1 and EM=3 answer the `PR` text (empty
//!   otherwise) and CR LF; EM=2 only `PR` text and CR LF. Errors are not otherwise shown: EF
//!   is set and ER holds the code; reading ER (`PR ER`) clears EF, `ER=0` clears both.
//! - **Addressing**: a line for `*` is carried out by every motor, none answering; a line
//!   without a name on the line (or with none at all) is answered by nobody and is malformed.
//!   A name alone is an empty command (answered by the echo mode's framing). Leading and
//!   trailing spaces and a CR before the LF are not part of the command.
//! - **Syntax**: a name, then a space or `=` before its value (`VM=5000`, `VM 5000`, `SL=5`,
//!   `MA 100`); a value is a decimal integer or a variable's name (`D=A`). Mnemonics and names
//!   are case-insensitive. A name glued to its number (`MA100`) is 38; an unknown name 20; a
//!   bare variable 34; `PR` of an unknown name 35; a value that is no number 24; out of range
//!   21; a read-only variable 25; `EX` of any label 30 (no program is stored); `H` 40. Of
//!   these, 20, 21, 24, 25, 34, 35 and 38 count as malformed, and so do 8 and 81; 30, 40 and
//!   the refusals for the motor's state (6, 22, 23, 37, 73, 74, 80, 85, 94) do not.
//! - **Ranges**: positions and registers 32-bit signed; VI 1 to 5 000 000 below VM; VM up to
//!   5 000 000 above VI; SL ±5 000 000; A and D 91 to 1 525 878 997; MS one of 1, 2, 4, 5, 8,
//!   10, 16, 25, 32, 50, 64, 100, 108, 125, 127, 128, 180, 200, 250, 256 (changing it rescales
//!   nothing); RC, HC 0–100; HT, MT 0–65 535; LM 1–6; EM, ES 0–3; EE, DE, ST 0 or 1; ER 0.
//! - **Not emulated, refused with 37**: leaving party mode (PY=0), checksum mode (CK=1),
//!   renaming (DN=…), EE=1 without an encoder.
//! - **Motion**: MA/MR ramp from VI to VM at A; SL jogs at its speed at A and `SL 0` or `SSTP`
//!   (with no value, 0 or 1) decelerate at D; a new MA/MR/SL replaces a motion in progress. ESC
//!   (0x1B) stops every motor at once, dropping the line being received; each motor answers it
//!   as witness 6 (EM=0 `#` CR LF prompt, EM=1/3 CR LF, EM=2 nothing). A motion ending on a
//!   limit switch in its direction sets 83 or 84. DE=0 stops the motor at once and refuses
//!   MA, MR, HM and SL n with 94 until DE=1.
//! - **Home**: `HM 1`–`HM 4` (3 and 4 toward plus, 2 and 4 creeping on in the slew's direction,
//!   taken by symmetry with the witnessed 1 and 3) go to the home switch at VM and set P (and
//!   C1, C2) to 0 there; 80 if no input is set up as home, 81 for another type, 85 while
//!   moving; MA/MR during a home are 85; `SL 0` ends it.
//! - **Inputs**: I1–I4 read 1 while the switch of their function is active (home: within half
//!   a step of the simulator's home switch; limits: the simulator's switches), whatever the
//!   active level, else 0. `PR S<n>` answers `function,active,sink`. A dedicated function on
//!   two points is 6; functions outside the witnessed lists are 8.
//! - **Counters**: P and C1 are the step counter (P reads C2 while EE=1); C2 the encoder's
//!   count, settable, 0 without an encoder unless set; V the speed's magnitude; VC 1 while the
//!   speed ramps.
//! - **Memory**: S stores the variables, S1–S4 and R1–R4 as the power-up set (73 while
//!   moving); IP restores them and FD the factory ones (S1–S4 `0,0,0`; 74 while moving),
//!   keeping the party-line settings (DN, PY, EM, CK) so that the motor stays on its channel.
//! - **`PR AL`**: one `NAME = value` line per variable, in a fixed order.
//! - **Faults**: `raise_error` is a stall: the motor stops at once, ST = 1, ER = 86.
//! - **Input buffer**: 128 bytes without an LF overflow it.

use crate::emulator::axes;
use crate::{Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

/// Motors on one party line at most (names `1` to `9`).
const MAX_MOTORS: usize = 9;
/// The party-mode terminator, Ctrl-J.
const LF: &[u8] = b"\n";
/// Stops every motor at once, wherever it comes.
const ESC: u8 = 0x1b;
const CRLF: &str = "\r\n";
/// Bytes without a terminator a motor holds before its buffer overflows.
const INPUT_BUFFER: usize = 128;
/// The global name.
const EVERY_MOTOR: u8 = b'*';

const VERSION: &str = "3.010";
const PART_NUMBER: &str = "MDI1FRD17B4";
/// The part number's suffix of a motor with an encoder.
const ENCODER_SUFFIX: &str = "-EQ";
/// The serial number less its last digit, the motor's name.
const SERIAL_NUMBER: &str = "07350000";

const SPEED_MAX: i64 = 5_000_000;
const ACCELERATION_MIN: i64 = 91;
const ACCELERATION_MAX: i64 = 1_525_878_997;
const DELAY_MAX: i64 = 65_535;
const MICROSTEPS: [i64; 20] = [1, 2, 4, 5, 8, 10, 16, 25, 32, 50, 64, 100, 108, 125, 127, 128, 180, 200, 250, 256];

/// The I/O functions: inputs, then outputs.
const HOME_INPUT: u8 = 1;
const PLUS_LIMIT_INPUT: u8 = 2;
const MINUS_LIMIT_INPUT: u8 = 3;
const INPUT_FUNCTIONS: [u8; 10] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 11];
const OUTPUT_FUNCTIONS: [u8; 5] = [16, 17, 18, 19, 20];
const GENERAL_PURPOSE: [u8; 2] = [0, 16];

/// MCode error numbers (ER).
const IO_TYPE_TAKEN: u8 = 6;
const IO_TYPE_ILLEGAL: u8 = 8;
const UNKNOWN_NAME: u8 = 20;
const BAD_VALUE: u8 = 21;
const VI_NOT_BELOW_VM: u8 = 22;
const VM_NOT_ABOVE_VI: u8 = 23;
const ILLEGAL_DATA: u8 = 24;
const READ_ONLY: u8 = 25;
const UNKNOWN_LABEL: u8 = 30;
const EXECUTE_VARIABLE: u8 = 34;
const PRINT_ILLEGAL: u8 = 35;
const NOT_AVAILABLE: u8 = 37;
const MISSING_SEPARATOR: u8 = 38;
const PROGRAM_NOT_RUNNING: u8 = 40;
const SAVE_WHILE_MOVING: u8 = 73;
const INIT_WHILE_MOVING: u8 = 74;
const NO_HOME_SWITCH: u8 = 80;
const NO_HOME_TYPE: u8 = 81;
const PLUS_LIMIT_REACHED: u8 = 83;
const MINUS_LIMIT_REACHED: u8 = 84;
const HOME_CONFLICT: u8 = 85;
const STALL: u8 = 86;
const DRIVE_DISABLED: u8 = 94;

/// The errors that are the host's fault rather than the motor's state.
const MALFORMED: [u8; 9] = [
    IO_TYPE_ILLEGAL,
    UNKNOWN_NAME,
    BAD_VALUE,
    ILLEGAL_DATA,
    READ_ONLY,
    EXECUTE_VARIABLE,
    PRINT_ILLEGAL,
    MISSING_SEPARATOR,
    NO_HOME_TYPE,
];

const COMMANDS: [&str; 10] = ["PR", "MA", "MR", "SL", "HM", "SSTP", "H", "S", "IP", "FD"];
const VARIABLES: [&str; 41] = [
    "P", "C1", "C2", "V", "MV", "VC", "ST", "EF", "ER", "VI", "VM", "A", "D", "MS", "RC", "HC", "HT", "MT", "LM", "EE",
    "DE", "EM", "ES", "PY", "CK", "DN", "I1", "I2", "I3", "I4", "S1", "S2", "S3", "S4", "R1", "R2", "R3", "R4", "VR",
    "PN", "SN",
];
/// What `PR AL` lists.
const ALL: [&str; 34] = [
    "A", "C1", "C2", "CK", "D", "DE", "DN", "EE", "EF", "EM", "ER", "ES", "HC", "HT", "LM", "MS", "MT", "MV", "P",
    "PY", "R1", "R2", "R3", "R4", "RC", "S1", "S2", "S3", "S4", "ST", "V", "VI", "VM", "VR",
];

/// What `PR` printed (None for other commands), or the error number.
type Outcome = Result<Option<String>, u8>;

/// How one I/O point is set up (`S<n>=function,active,sink`).
#[derive(Clone, Copy, Debug, PartialEq)]
struct IoSetup {
    function: u8,
    active_high: bool,
    sourcing: bool,
}

impl IoSetup {
    const fn input(function: u8) -> Self {
        Self { function, active_high: false, sourcing: false }
    }
}

/// The variables S saves and IP restores.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Settings {
    initial_velocity: i64,
    max_velocity: i64,
    acceleration: i64,
    deceleration: i64,
    microsteps: i64,
    run_current: i64,
    hold_current: i64,
    hold_delay: i64,
    settle_delay: i64,
    limit_mode: i64,
    encoder_enabled: bool,
    echo_mode: i64,
    escape_mode: i64,
    io: [IoSetup; 4],
    registers: [i64; 4],
}

impl Settings {
    fn factory() -> Self {
        Self {
            initial_velocity: 1_000,
            max_velocity: 768_000,
            acceleration: 1_000_000,
            deceleration: 1_000_000,
            microsteps: 256,
            run_current: 25,
            hold_current: 5,
            hold_delay: 500,
            settle_delay: 0,
            limit_mode: 1,
            encoder_enabled: false,
            echo_mode: 0,
            escape_mode: 0,
            io: [IoSetup::input(0); 4],
            registers: [0; 4],
        }
    }

    /// As the EPICS README has every motor of a party line saved.
    fn party_line() -> Self {
        Self {
            echo_mode: 2,
            io: [
                IoSetup::input(HOME_INPUT),
                IoSetup::input(PLUS_LIMIT_INPUT),
                IoSetup::input(MINUS_LIMIT_INPUT),
                IoSetup::input(0),
            ],
            ..Self::factory()
        }
    }
}

/// One MDrive Plus: its variables and the carriage behind it.
#[derive(Debug)]
struct Motor {
    /// DN.
    name: u8,
    sim: SimAxis,
    settings: Settings,
    /// What S saved; IP restores it.
    saved: Settings,
    /// DE.
    drive_enabled: bool,
    /// ST.
    stalled: bool,
    /// ER.
    error: u8,
    /// EF.
    error_flag: bool,
    /// C2 less the encoder's reading.
    encoder_offset: i64,
    homing: bool,
    /// The direction of the current (or last) motion.
    toward_plus: bool,
    /// The speed the current motion runs at once ramped.
    cruise: f64,
}

impl Motor {
    fn new(name: u8, sim: SimAxis) -> Self {
        let settings = Settings::party_line();
        Self {
            name,
            sim,
            settings,
            saved: settings,
            drive_enabled: true,
            stalled: false,
            error: 0,
            error_flag: false,
            encoder_offset: 0,
            homing: false,
            toward_plus: true,
            cruise: 0.0,
        }
    }

    fn has_encoder(&self) -> bool {
        self.sim.config().encoder_counts_per_step.is_some()
    }

    fn fail(&mut self, code: u8) {
        self.error = code;
        self.error_flag = true;
    }

    /// Time passes to `now`: a motion ending on a switch in its way is an error.
    fn advance(&mut self, now: Instant) {
        let was_moving = self.sim.is_moving();
        self.sim.advance(now);
        if was_moving && !self.sim.is_moving() {
            let state = self.sim.state();
            if self.toward_plus && state.high_limit {
                self.fail(PLUS_LIMIT_REACHED);
            } else if !self.toward_plus && state.low_limit {
                self.fail(MINUS_LIMIT_REACHED);
            }
            self.homing = false;
        }
    }

    fn counter(&self) -> i64 {
        self.sim.status().position.round() as i64
    }

    fn encoder(&self) -> i64 {
        self.sim.state().encoder.unwrap_or(0.0).round() as i64 + self.encoder_offset
    }

    fn input(&self, point: usize) -> bool {
        let state = self.sim.state();
        match self.settings.io[point].function {
            HOME_INPUT => (state.position - self.sim.config().home_switch).abs() < 0.5,
            PLUS_LIMIT_INPUT => state.high_limit,
            MINUS_LIMIT_INPUT => state.low_limit,
            _ => false,
        }
    }

    /// A line addressed to this motor, its name taken off: what `PR` prints, or the error.
    fn run(&mut self, command: &str) -> Outcome {
        if command.is_empty() {
            return Ok(None);
        }
        let name_length = command.bytes().take_while(u8::is_ascii_alphanumeric).count();
        let (name, rest) = command.split_at(name_length);
        let name = name.to_ascii_uppercase();
        if !rest.is_empty() && !rest.starts_with([' ', '=']) {
            return Err(ILLEGAL_DATA);
        }
        let argument = rest.trim();
        let argument = argument.strip_prefix('=').unwrap_or(argument).trim();
        match name.as_str() {
            "PR" => self.print(argument).map(Some),
            "MA" | "MR" => self.start_move(argument, name == "MR").map(|()| None),
            "SL" => self.slew(argument).map(|()| None),
            "HM" => self.home(argument).map(|()| None),
            "SSTP" if matches!(argument, "" | "0" | "1") => {
                self.stop();
                Ok(None)
            }
            "H" => Err(PROGRAM_NOT_RUNNING),
            "EX" => Err(if argument.is_empty() { ILLEGAL_DATA } else { UNKNOWN_LABEL }),
            "S" | "IP" | "FD" if argument.is_empty() => self.memory(&name).map(|()| None),
            _ if VARIABLES.contains(&name.as_str()) => {
                if argument.is_empty() {
                    Err(EXECUTE_VARIABLE)
                } else {
                    self.set(&name, argument).map(|()| None)
                }
            }
            _ if COMMANDS.contains(&name.as_str()) => Err(ILLEGAL_DATA),
            _ if glued_to_a_number(&name) => Err(MISSING_SEPARATOR),
            _ => Err(UNKNOWN_NAME),
        }
    }

    /// `PR item,item…`: variables' values and quoted text, concatenated (a quoted text may
    /// also be followed by a name without a comma: `PR P,"_"V`).
    fn print(&mut self, items: &str) -> Result<String, u8> {
        let mut text = String::new();
        let mut rest = items.trim_start();
        if rest.is_empty() {
            return Err(ILLEGAL_DATA);
        }
        let mut read_error = false;
        while !rest.is_empty() {
            if let Some(quoted) = rest.strip_prefix('"') {
                let end = quoted.find('"').ok_or(ILLEGAL_DATA)?;
                text.push_str(&quoted[..end]);
                rest = &quoted[end + 1..];
            } else {
                let length = rest.bytes().take_while(u8::is_ascii_alphanumeric).count();
                let name = rest[..length].to_ascii_uppercase();
                rest = &rest[length..];
                match name.as_str() {
                    "" => return Err(ILLEGAL_DATA),
                    "AL" => {
                        let lines: Vec<String> =
                            ALL.iter().filter_map(|n| self.read(n).map(|value| format!("{n} = {value}"))).collect();
                        text.push_str(&lines.join(CRLF));
                    }
                    _ => text.push_str(&self.read(&name).ok_or(PRINT_ILLEGAL)?),
                }
                read_error |= name == "ER";
                if name == "PN" {
                    // The EPICS driver flushes an extra CR LF after the part number.
                    text.push_str(CRLF);
                }
            }
            rest = rest.trim_start();
            rest = rest.strip_prefix(',').map_or(rest, str::trim_start);
        }
        if read_error {
            self.error_flag = false;
        }
        Ok(text)
    }

    /// A variable's value as `PR` prints it.
    fn read(&self, name: &str) -> Option<String> {
        let s = &self.settings;
        let flag = |on: bool| i64::from(on);
        let point = |text: &str| text.parse::<usize>().ok().filter(|n| (1..=4).contains(n)).map(|n| n - 1);
        let number = match name {
            "P" if s.encoder_enabled => self.encoder(),
            "P" | "C1" => self.counter(),
            "C2" => self.encoder(),
            "V" => self.sim.state().velocity.abs().round() as i64,
            "MV" => flag(self.sim.is_moving()),
            "VC" => flag(self.sim.is_moving() && (self.sim.state().velocity.abs() - self.cruise).abs() > 0.5),
            "ST" => flag(self.stalled),
            "EF" => flag(self.error_flag),
            "ER" => i64::from(self.error),
            "VI" => s.initial_velocity,
            "VM" => s.max_velocity,
            "A" => s.acceleration,
            "D" => s.deceleration,
            "MS" => s.microsteps,
            "RC" => s.run_current,
            "HC" => s.hold_current,
            "HT" => s.hold_delay,
            "MT" => s.settle_delay,
            "LM" => s.limit_mode,
            "EE" => flag(s.encoder_enabled),
            "DE" => flag(self.drive_enabled),
            "EM" => s.echo_mode,
            "ES" => s.escape_mode,
            "PY" => 1,
            "CK" => 0,
            "DN" => return Some(char::from(self.name).to_string()),
            "VR" => return Some(VERSION.to_string()),
            "SN" => return Some(format!("{SERIAL_NUMBER}{}", char::from(self.name))),
            "PN" => {
                let suffix = if self.has_encoder() { ENCODER_SUFFIX } else { "" };
                return Some(format!("{PART_NUMBER}{suffix}"));
            }
            _ => {
                let (prefix, digit) = name.split_at(name.len().min(1));
                let index = point(digit)?;
                return match prefix {
                    "I" => Some(flag(self.input(index)).to_string()),
                    "R" => Some(s.registers[index].to_string()),
                    "S" => {
                        let io = s.io[index];
                        Some(format!("{},{},{}", io.function, flag(io.active_high), flag(io.sourcing)))
                    }
                    _ => None,
                };
            }
        };
        Some(number.to_string())
    }

    /// A value: a decimal integer or another variable's.
    fn value(&self, text: &str) -> Result<i64, u8> {
        let digits = text.strip_prefix(['+', '-']).unwrap_or(text);
        if !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit()) {
            return text.strip_prefix('+').unwrap_or(text).parse().map_err(|_| BAD_VALUE);
        }
        let name = text.to_ascii_uppercase();
        if VARIABLES.contains(&name.as_str()) {
            if let Some(value) = self.read(&name).and_then(|v| v.parse().ok()) {
                return Ok(value);
            }
        }
        Err(ILLEGAL_DATA)
    }

    fn set(&mut self, name: &str, argument: &str) -> Result<(), u8> {
        if let Some(point) = name.strip_prefix('S').and_then(|d| d.parse::<usize>().ok()) {
            return self.set_io(point - 1, argument);
        }
        let value = self.value(argument)?;
        let within = |min: i64, max: i64| if (min..=max).contains(&value) { Ok(value) } else { Err(BAD_VALUE) };
        let position = || within(i32::MIN.into(), i32::MAX.into());
        let has_encoder = self.has_encoder();
        let s = &mut self.settings;
        match name {
            "P" | "C1" => {
                let position = position()?;
                self.sim.set_position(position as f64);
            }
            "C2" => {
                let count = position()?;
                self.encoder_offset = 0;
                self.encoder_offset = count - self.encoder();
            }
            "VI" => {
                let value = within(1, SPEED_MAX)?;
                if value >= s.max_velocity {
                    return Err(VI_NOT_BELOW_VM);
                }
                s.initial_velocity = value;
            }
            "VM" => {
                let value = within(1, SPEED_MAX)?;
                if value <= s.initial_velocity {
                    return Err(VM_NOT_ABOVE_VI);
                }
                s.max_velocity = value;
            }
            "A" => s.acceleration = within(ACCELERATION_MIN, ACCELERATION_MAX)?,
            "D" => s.deceleration = within(ACCELERATION_MIN, ACCELERATION_MAX)?,
            "MS" if MICROSTEPS.contains(&value) => s.microsteps = value,
            "MS" => return Err(BAD_VALUE),
            "RC" => s.run_current = within(0, 100)?,
            "HC" => s.hold_current = within(0, 100)?,
            "HT" => s.hold_delay = within(0, DELAY_MAX)?,
            "MT" => s.settle_delay = within(0, DELAY_MAX)?,
            "LM" => s.limit_mode = within(1, 6)?,
            "EM" => s.echo_mode = within(0, 3)?,
            "ES" => s.escape_mode = within(0, 3)?,
            "EE" => {
                let on = within(0, 1)? == 1;
                if on && !has_encoder {
                    return Err(NOT_AVAILABLE);
                }
                s.encoder_enabled = on;
            }
            "DE" => {
                self.drive_enabled = within(0, 1)? == 1;
                if !self.drive_enabled {
                    self.sim.stop(0.0);
                    self.homing = false;
                }
            }
            "ST" => self.stalled = within(0, 1)? == 1,
            "ER" => {
                within(0, 0)?;
                self.error = 0;
                self.error_flag = false;
            }
            "R1" | "R2" | "R3" | "R4" => {
                let index = usize::from(name.as_bytes()[1] - b'1');
                s.registers[index] = position()?;
            }
            "PY" if value == 1 => {}
            "CK" if value == 0 => {}
            "PY" | "CK" | "DN" => return Err(NOT_AVAILABLE),
            _ => return Err(READ_ONLY),
        }
        Ok(())
    }

    /// `S<n>=function,active[,sink]`.
    fn set_io(&mut self, point: usize, argument: &str) -> Result<(), u8> {
        let fields: Vec<&str> = argument.split(',').map(str::trim).collect();
        if !(1..=3).contains(&fields.len()) {
            return Err(ILLEGAL_DATA);
        }
        let mut numbers = [0_i64; 3];
        for (number, field) in numbers.iter_mut().zip(&fields) {
            *number = self.value(field)?;
        }
        let [function, active, sink] = numbers;
        let function = u8::try_from(function).map_err(|_| IO_TYPE_ILLEGAL)?;
        if !INPUT_FUNCTIONS.contains(&function) && !OUTPUT_FUNCTIONS.contains(&function) {
            return Err(IO_TYPE_ILLEGAL);
        }
        if !(0..=1).contains(&active) || !(0..=1).contains(&sink) {
            return Err(BAD_VALUE);
        }
        let taken = self.settings.io.iter().enumerate().any(|(i, io)| i != point && io.function == function);
        if taken && !GENERAL_PURPOSE.contains(&function) {
            return Err(IO_TYPE_TAKEN);
        }
        self.settings.io[point] = IoSetup { function, active_high: active == 1, sourcing: sink == 1 };
        Ok(())
    }

    fn may_move(&self) -> Result<(), u8> {
        if !self.drive_enabled {
            Err(DRIVE_DISABLED)
        } else if self.homing && self.sim.is_moving() {
            Err(HOME_CONFLICT)
        } else {
            Ok(())
        }
    }

    fn start_move(&mut self, argument: &str, relative: bool) -> Result<(), u8> {
        let target = self.value(argument)?;
        if !(i64::from(i32::MIN)..=i64::from(i32::MAX)).contains(&target) {
            return Err(BAD_VALUE);
        }
        self.may_move()?;
        let s = self.settings;
        self.toward_plus = if relative { target > 0 } else { target > self.counter() };
        self.cruise = s.max_velocity as f64;
        self.sim.move_to(target as f64, relative, s.initial_velocity as f64, self.cruise, s.acceleration as f64);
        Ok(())
    }

    fn slew(&mut self, argument: &str) -> Result<(), u8> {
        let speed = self.value(argument)?;
        if !(-SPEED_MAX..=SPEED_MAX).contains(&speed) {
            return Err(BAD_VALUE);
        }
        if speed == 0 {
            self.stop();
            return Ok(());
        }
        self.may_move()?;
        let s = self.settings;
        self.toward_plus = speed > 0;
        self.cruise = speed.abs() as f64;
        let start = (s.initial_velocity as f64).min(self.cruise);
        self.sim.move_velocity(start, speed as f64, s.acceleration as f64);
        Ok(())
    }

    /// Decelerate at D to rest, a home search included.
    fn stop(&mut self) {
        self.sim.stop(self.settings.deceleration as f64);
        self.homing = false;
    }

    fn home(&mut self, argument: &str) -> Result<(), u8> {
        let kind = match argument {
            "1" | "2" | "3" | "4" => argument,
            _ => return Err(NO_HOME_TYPE),
        };
        if !self.settings.io.iter().any(|io| io.function == HOME_INPUT) {
            return Err(NO_HOME_SWITCH);
        }
        if self.sim.is_moving() {
            return Err(HOME_CONFLICT);
        }
        self.may_move()?;
        let s = self.settings;
        self.toward_plus = self.sim.config().home_switch > self.sim.physical_position();
        self.cruise = s.max_velocity as f64;
        self.homing = true;
        self.sim.home(matches!(kind, "3" | "4"), s.initial_velocity as f64, self.cruise, s.acceleration as f64);
        Ok(())
    }

    /// S, IP and FD.
    fn memory(&mut self, command: &str) -> Result<(), u8> {
        if self.sim.is_moving() {
            return Err(if command == "S" { SAVE_WHILE_MOVING } else { INIT_WHILE_MOVING });
        }
        let echo_mode = self.settings.echo_mode;
        match command {
            "S" => self.saved = self.settings,
            "IP" => self.settings = self.saved,
            _ => {
                self.settings = Settings::factory();
                self.saved = self.settings;
            }
        }
        // The party-line settings stay: the motor keeps answering on its channel.
        self.settings.echo_mode = echo_mode;
        Ok(())
    }

    /// ESC: every motion stopped at once; the answer its echo mode gives.
    fn escape(&mut self) -> Option<String> {
        self.sim.stop(0.0);
        self.homing = false;
        match self.settings.echo_mode {
            0 => Some(format!("#{CRLF}{}", self.prompt())),
            2 => None,
            _ => Some(CRLF.to_string()),
        }
    }

    fn prompt(&self) -> char {
        if self.error_flag {
            '?'
        } else {
            '>'
        }
    }

    /// The bytes answering `line` (as received) whose command gave `printed`.
    fn answer(&self, line: &str, printed: Option<String>) -> Option<String> {
        match self.settings.echo_mode {
            0 => {
                let printed = printed.map(|p| format!("{p}{CRLF}")).unwrap_or_default();
                Some(format!("{line}{CRLF}{printed}{}", self.prompt()))
            }
            2 => printed.map(|p| format!("{p}{CRLF}")),
            _ => Some(format!("{}{CRLF}", printed.unwrap_or_default())),
        }
    }
}

/// A mnemonic with its number glued on (`MA100`): the separator is missing.
fn glued_to_a_number(name: &str) -> bool {
    (1..name.len()).any(|split| {
        let (head, tail) = name.split_at(split);
        (COMMANDS.contains(&head) || VARIABLES.contains(&head)) && tail.bytes().all(|b| b.is_ascii_digit())
    })
}

/// A party line of MDrive Plus motors named `1` … `n`.
pub struct MdriveEmulator {
    motors: Vec<Motor>,
    lines: Lines,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl MdriveEmulator {
    /// A party line of `motors` MDrive Plus motors (one at least, nine at most) named `1` to
    /// `motors`.
    pub fn new(motors: usize, mechanics: &SimConfig) -> Self {
        let motors = motors.clamp(1, MAX_MOTORS);
        Self {
            motors: axes(motors, mechanics).into_iter().zip(b'1'..).map(|(sim, name)| Motor::new(name, sim)).collect(),
            lines: Lines::new(LF, INPUT_BUFFER),
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    fn handle_line(&mut self, line: &[u8]) {
        let text = std::str::from_utf8(line).ok().filter(|t| t.is_ascii()).map(str::trim);
        let Some(text) = text else {
            self.malformed += 1;
            return;
        };
        let Some(&address) = text.as_bytes().first() else { return };
        let command = text[1..].trim();
        if address == EVERY_MOTOR {
            let mut refused = false;
            for motor in &mut self.motors {
                if let Err(code) = motor.run(command) {
                    motor.fail(code);
                    refused |= MALFORMED.contains(&code);
                }
            }
            self.malformed += usize::from(refused);
            return;
        }
        let Some(index) = self.motors.iter().position(|m| m.name == address) else {
            self.malformed += 1;
            return;
        };
        let motor = &mut self.motors[index];
        let printed = motor.run(command).unwrap_or_else(|code| {
            motor.fail(code);
            self.malformed += usize::from(MALFORMED.contains(&code));
            None
        });
        if let Some(reply) = motor.answer(text, printed) {
            self.output.push_back(reply.into_bytes());
        }
    }
}

impl Emulator for MdriveEmulator {
    fn name(&self) -> &'static str {
        "ims_mdrive"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for motor in &mut self.motors {
            motor.advance(now);
        }
        let mut pieces = bytes.split(|&b| b == ESC).peekable();
        while let Some(piece) = pieces.next() {
            if pieces.peek().is_none() {
                for line in self.lines.push(piece) {
                    self.handle_line(&line);
                }
                break;
            }
            // ESC drops the line being received: end it here and leave it out.
            let mut lines = self.lines.push(&[piece, LF].concat());
            lines.pop();
            for line in lines {
                self.handle_line(&line);
            }
            for motor in &mut self.motors {
                if let Some(reply) = motor.escape() {
                    self.output.push_back(reply.into_bytes());
                }
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
        self.motors.get_mut(channel.checked_sub(1)?).map(|motor| &mut motor.sim)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(motor) = channel.checked_sub(1).and_then(|i| self.motors.get_mut(i)) else { return false };
        motor.sim.stop(0.0);
        motor.homing = false;
        motor.stalled = true;
        motor.fail(STALL);
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

    /// Send one line as the EPICS asyn driver does (CR LF) and collect every byte answered.
    fn send(e: &mut MdriveEmulator, now: Instant, line: &str) -> Option<String> {
        e.handle_input(now, format!("{line}\r\n").as_bytes());
        let replies: Vec<u8> = std::iter::from_fn(|| e.poll_transmit()).flatten().collect();
        (!replies.is_empty()).then(|| String::from_utf8(replies).expect("ASCII"))
    }

    /// A `PR` in echo mode 2: its text without the CR LF.
    fn print(e: &mut MdriveEmulator, now: Instant, line: &str) -> String {
        let reply = send(e, now, line).expect("PR is answered");
        reply.strip_suffix("\r\n").expect("ended by CR LF").to_string()
    }

    fn number(e: &mut MdriveEmulator, now: Instant, line: &str) -> i64 {
        print(e, now, line).parse().expect("a number")
    }

    #[test]
    fn identification_and_power_up_state() {
        let mut e = MdriveEmulator::new(2, &stage());
        assert_eq!(e.name(), "ims_mdrive");
        assert_eq!(send(&mut e, at(0), "1PR VR").as_deref(), Some("3.010\r\n"));
        assert_eq!(send(&mut e, at(0), "2pr pn").as_deref(), Some("MDI1FRD17B4\r\n\r\n"), "the extra CR LF");
        assert_eq!(print(&mut e, at(0), "2PR DN,\" \",SN"), "2 073500002");
        for (point, setup) in [(1, "1,0,0"), (2, "2,0,0"), (3, "3,0,0"), (4, "0,0,0")] {
            assert_eq!(print(&mut e, at(0), &format!("1PR S{point}")), setup);
        }
        assert_eq!(print(&mut e, at(0), r#"1PR VI,"_",VM,"_",A,"_",D,"_",MS"#), "1000_768000_1000000_1000000_256");
        assert_eq!(print(&mut e, at(0), r#"1PR P,"_"V,"_"MV,"_"EE,"_"EF,"_"ER,"_"ST"#), "0_0_0_0_0_0_0");
        assert_eq!(print(&mut e, at(0), "1PR EM"), "2");
        for setting in ["1VI=500", "1VM=2000", "1A=20000", "1D=A", "1ST=0", "1R1=0", "1 VM 3000 "] {
            assert_eq!(send(&mut e, at(0), setting), None, "EM=2: {setting} answers nothing");
        }
        assert_eq!(print(&mut e, at(0), r#"1PR VI,",",VM,",",D"#), "500,3000,20000");
        assert!(print(&mut e, at(0), "1PR AL").contains("VM = 3000\r\nVR = 3.010"));
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_move_is_busy_then_done_at_its_target() {
        let mut e = MdriveEmulator::new(1, &stage());
        for line in ["1VI=100", "1VM=1000", "1A=1000000", "1D=1000000", "1MA 2000"] {
            assert_eq!(send(&mut e, at(0), line), None);
        }
        assert_eq!(print(&mut e, at(1000), "1PR MV"), "1");
        assert_eq!(print(&mut e, at(1000), "1PR V"), "1000");
        let p = number(&mut e, at(1000), "1PR P");
        assert!((995..=1001).contains(&p), "{p}");
        assert_eq!(print(&mut e, at(2100), "1PR MV"), "0");
        assert_eq!(print(&mut e, at(2100), "1PR P"), "2000");
        assert_eq!(print(&mut e, at(2100), "1PR C1"), "2000");
        send(&mut e, at(2100), "1MR -500");
        assert_eq!(print(&mut e, at(3000), "1PR P"), "1500");
        send(&mut e, at(3000), "1P=100");
        assert_eq!(print(&mut e, at(3000), "1PR P"), "100");
        assert_eq!(print(&mut e, at(3000), "1PR EF"), "0");
    }

    #[test]
    fn a_jog_runs_until_slewed_to_zero() {
        let mut e = MdriveEmulator::new(2, &stage());
        send(&mut e, at(0), "2D=1000");
        send(&mut e, at(0), "2SL=-1000");
        assert_eq!(print(&mut e, at(5000), "2PR MV"), "1");
        assert_eq!(print(&mut e, at(5000), "2PR V"), "1000", "the speed's magnitude");
        assert!(number(&mut e, at(5000), "2PR P") < -4000);
        assert_eq!(print(&mut e, at(5000), "1PR MV"), "0", "motor 1 stays");
        send(&mut e, at(5000), "2SL 0");
        assert_eq!(print(&mut e, at(5200), "2PR MV"), "1", "decelerating at D");
        assert_eq!(print(&mut e, at(5200), "2PR VC"), "1");
        assert_eq!(print(&mut e, at(6100), "2PR MV"), "0");
        send(&mut e, at(6100), "2SL 2000");
        send(&mut e, at(7000), "2SSTP");
        assert_eq!(print(&mut e, at(9100), "2PR MV"), "0");
        assert_eq!(send(&mut e, at(9100), "2SL 5000001"), None);
        assert_eq!(print(&mut e, at(9100), "2PR ER"), "21");
        assert_eq!(e.malformed(), 1);
    }

    #[test]
    fn a_home_search_ends_on_the_switch_at_zero() {
        let mut e = MdriveEmulator::new(3, &stage());
        send(&mut e, at(0), "3VM=10000");
        send(&mut e, at(0), "3P=-5000");
        assert_eq!(print(&mut e, at(0), "3PR I1"), "1", "the carriage is at the switch");
        send(&mut e, at(0), "3MR 30000");
        send(&mut e, at(1000), "3HM 1");
        assert_eq!(print(&mut e, at(1000), "3PR ER"), "85", "not while moving");
        send(&mut e, at(5000), "3HM 3");
        send(&mut e, at(5000), "3R1=0");
        send(&mut e, at(5100), "3MA 0");
        assert_eq!(print(&mut e, at(5100), "3PR ER"), "85", "no move during a home");
        assert_eq!(print(&mut e, at(9000), "3PR MV"), "0");
        assert_eq!(print(&mut e, at(9000), "3PR P"), "0");
        assert_eq!(print(&mut e, at(9000), "3PR I1"), "1");
        assert!(e.axis(3).expect("motor 3").state().homed);
        send(&mut e, at(9000), "3HM 5");
        assert_eq!(print(&mut e, at(9000), "3PR ER"), "81");
        send(&mut e, at(9000), "3S1=0,0");
        send(&mut e, at(9000), "3HM 2");
        assert_eq!(print(&mut e, at(9000), "3PR ER"), "80", "no input set up as home");
        assert_eq!(e.malformed(), 1, "only the illegal type");
    }

    #[test]
    fn a_limit_switch_stops_the_motor_and_sets_its_error() {
        let mut e = MdriveEmulator::new(1, &stage());
        send(&mut e, at(0), "1SL 100000");
        assert_eq!(print(&mut e, at(3000), "1PR I2"), "1", "the plus limit");
        assert_eq!(print(&mut e, at(3000), "1PR I3"), "0");
        assert_eq!(print(&mut e, at(3000), "1PR MV"), "0");
        assert_eq!(print(&mut e, at(3000), "1PR EF"), "1");
        assert_eq!(print(&mut e, at(3000), "1PR ER"), "83");
        send(&mut e, at(3000), "1MR -1000");
        assert_eq!(print(&mut e, at(4000), "1PR I2"), "0", "away from it");
        send(&mut e, at(4000), "1SL -200000");
        assert_eq!(print(&mut e, at(8000), "1PR I3"), "1");
        assert_eq!(print(&mut e, at(8000), "1PR ER"), "84");
    }

    #[test]
    fn refusals_set_the_error_number_and_flag() {
        let mut e = MdriveEmulator::new(1, &stage());
        assert_eq!(send(&mut e, at(0), "1VM=500"), None, "VM not above VI");
        assert_eq!(print(&mut e, at(0), "1PR EF"), "1");
        assert_eq!(print(&mut e, at(0), "1PR ER"), "23");
        assert_eq!(print(&mut e, at(0), "1PR EF"), "0", "reading ER clears EF");
        assert_eq!(print(&mut e, at(0), "1PR ER,\" \",VM"), "23 768000", "VM unchanged");
        send(&mut e, at(0), "1VI=768000");
        assert_eq!(print(&mut e, at(0), "1PR ER"), "22");
        send(&mut e, at(0), "1ER=0");
        assert_eq!(print(&mut e, at(0), r#"1PR ER,EF"#), "00");
        for (line, code) in [
            ("1A=50", "21"),
            ("1RC=110", "21"),
            ("1MS=3", "21"),
            ("1VM=fast", "24"),
            ("1MV=1", "25"),
            ("1EX F1", "30"),
            ("1H", "40"),
            ("1EE=1", "37"),
            ("1PY=0", "37"),
            ("1S4=9,0", "8"),
            ("1S4=2,1", "6"),
        ] {
            assert_eq!(send(&mut e, at(0), line), None, "{line}");
            assert_eq!(print(&mut e, at(0), "1PR ER"), code, "{line}");
        }
        send(&mut e, at(0), "1S4=17,1,1");
        assert_eq!(print(&mut e, at(0), "1PR S4,ER"), "17,1,16");
        send(&mut e, at(0), "1DE=0");
        send(&mut e, at(0), "1MA 100");
        assert_eq!(print(&mut e, at(0), "1PR ER"), "94");
        assert_eq!(e.malformed(), 6, "21 ×3, 24, 25 and 8");
    }

    #[test]
    fn echo_mode_0_prompts_and_shows_errors() {
        let mut e = MdriveEmulator::new(1, &stage());
        assert_eq!(send(&mut e, at(0), "1EM=0").as_deref(), Some("1EM=0\r\n>"));
        assert_eq!(send(&mut e, at(0), "1PR P").as_deref(), Some("1PR P\r\n0\r\n>"));
        assert_eq!(send(&mut e, at(0), "1").as_deref(), Some("1\r\n>"));
        assert_eq!(send(&mut e, at(0), "1XY 5").as_deref(), Some("1XY 5\r\n?"), "unknown: error 20");
        assert_eq!(send(&mut e, at(0), "1").as_deref(), Some("1\r\n?"), "still pending");
        assert_eq!(send(&mut e, at(0), "1PR ER").as_deref(), Some("1PR ER\r\n20\r\n>"));
        for (line, code) in [("1MA100", "38"), ("1P", "34"), ("1PR ZZ", "35"), ("1PR", "24")] {
            assert_eq!(send(&mut e, at(0), line), Some(format!("{line}\r\n?")));
            assert_eq!(send(&mut e, at(0), "1PR ER"), Some(format!("1PR ER\r\n{code}\r\n>")), "{line}");
        }
        assert_eq!(send(&mut e, at(0), "1EM=1").as_deref(), Some("\r\n"), "half duplex");
        assert_eq!(send(&mut e, at(0), "1PR MV").as_deref(), Some("0\r\n"));
        assert_eq!(send(&mut e, at(0), "1").as_deref(), Some("\r\n"));
        assert_eq!(e.malformed(), 5);
    }

    #[test]
    fn only_the_named_motor_answers_and_star_reaches_all() {
        let mut e = MdriveEmulator::new(2, &stage());
        for line in ["3PR P", "PR P", "0PR P", "!PR P"] {
            assert_eq!(send(&mut e, at(0), line), None, "{line}");
        }
        assert_eq!(e.malformed(), 4);
        assert_eq!(send(&mut e, at(0), "*SL 1000"), None);
        assert_eq!(send(&mut e, at(0), "*PR P"), None, "nobody answers a global PR");
        assert_eq!(print(&mut e, at(1000), "1PR MV"), "1");
        assert_eq!(print(&mut e, at(1000), "2PR MV"), "1");
        send(&mut e, at(1000), "*XY");
        assert_eq!(e.malformed(), 5, "one line, one count");
        assert_eq!(print(&mut e, at(1000), "2PR ER"), "20");
        assert!(e.axis(0).is_none() && e.axis(2).is_some() && e.axis(3).is_none());
        assert_eq!(MdriveEmulator::new(20, &stage()).motors.len(), 9);
        assert_eq!(MdriveEmulator::new(0, &stage()).motors.len(), 1);
    }

    #[test]
    fn escape_stops_every_motor_and_drops_the_line() {
        let mut e = MdriveEmulator::new(2, &stage());
        send(&mut e, at(0), "1EM=0");
        send(&mut e, at(0), "*SL 1000");
        e.handle_input(at(1000), b"2MA 5\x1b");
        let replies: Vec<Vec<u8>> = std::iter::from_fn(|| e.poll_transmit()).collect();
        assert_eq!(replies, [b"#\r\n>".to_vec()], "motor 1 in EM=0, motor 2 in EM=2");
        assert_eq!(print(&mut e, at(1000), "2PR MV"), "0", "stopped at once");
        assert_eq!(send(&mut e, at(1000), "1PR MV").as_deref(), Some("1PR MV\r\n0\r\n>"));
        assert!((995..=1001).contains(&number(&mut e, at(1000), "2PR P")), "the MA was dropped");
    }

    #[test]
    fn saved_settings_survive_ip_and_fd_restores_the_factory() {
        let mut e = MdriveEmulator::new(1, &stage());
        send(&mut e, at(0), "1VM=5000");
        send(&mut e, at(0), "1S");
        send(&mut e, at(0), "1VM=6000");
        send(&mut e, at(0), "1IP");
        assert_eq!(print(&mut e, at(0), "1PR VM"), "5000");
        send(&mut e, at(0), "1SL 100");
        send(&mut e, at(0), "1S");
        assert_eq!(print(&mut e, at(0), "1PR ER"), "73");
        send(&mut e, at(0), "1FD");
        assert_eq!(print(&mut e, at(0), "1PR ER"), "74");
        send(&mut e, at(0), "1SL 0");
        send(&mut e, at(1000), "1FD");
        assert_eq!(print(&mut e, at(1000), r#"1PR VM,"_",S1,"_",EM"#), "768000_0,0,0_2");
    }

    #[test]
    fn a_stall_is_the_raised_error() {
        let mut e = MdriveEmulator::new(2, &stage());
        send(&mut e, at(0), "2SL 1000");
        assert!(e.raise_error(2));
        assert_eq!(print(&mut e, at(100), "2PR MV,ST,EF,ER"), "01186");
        send(&mut e, at(100), "2ST=0");
        assert_eq!(print(&mut e, at(100), "2PR ST"), "0");
        assert_eq!(print(&mut e, at(100), "1PR EF"), "0");
        assert!(!e.raise_error(0) && !e.raise_error(3));
    }

    #[test]
    fn lines_come_whole_from_any_pieces() {
        let mut e = MdriveEmulator::new(1, &stage());
        e.handle_input(at(0), b"1P");
        assert!(e.poll_transmit().is_none());
        e.handle_input(at(0), b"R V");
        e.handle_input(at(0), b"R\r\n1pr m");
        e.handle_input(at(0), b"v\n1PR \xff\n");
        let replies: Vec<Vec<u8>> = std::iter::from_fn(|| e.poll_transmit()).collect();
        assert_eq!(replies, [b"3.010\r\n".to_vec(), b"0\r\n".to_vec()]);
        assert_eq!(e.malformed(), 1, "the byte that is not ASCII");
        e.handle_input(at(0), &[b'1'; INPUT_BUFFER + 1]);
        assert_eq!(e.malformed(), 2, "an overflowing input buffer counts");
        assert_eq!(send(&mut e, at(0), "1PR MV").as_deref(), Some("0\r\n"));
    }
}
