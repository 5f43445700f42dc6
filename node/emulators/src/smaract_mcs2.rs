//! SmarAct MCS2 on its TCP ASCII interface (port 55551): a SCPI-style command set, one command
//! per line, a query answered with one line, everything else silent, and every refusal left in
//! the device's error queue. Each channel drives a linear positioner with a position sensor,
//! counted in picometres; behind it is zmotor-core's physical simulator.
//!
//! # Sources
//!
//! SmarAct's MCS2 Programmer's Guide is not public, and no copy of it could be found to read.
//! What SmarAct itself publishes and was read is the MCS2 SDK's header (`SmarActControl.h`, as
//! transcribed in pylablib's `SmarActControl_defs.py`): the numbers and names of the error
//! codes (`SA_CTL_ERROR_*`), of the channel state bits (`SA_CTL_CH_STATE_BIT_*`), of the move
//! modes and of the reference options. The ASCII interface is a SCPI parser in front of the
//! same firmware; its syntax and its parser errors follow the SCPI standard (1999, volume 1:
//! mnemonics, numeric data, the error/event queue). Witnesses of what the device answers and
//! what software sends it: the EPICS driver (epics-motor/motorSmarAct, `smarActMCS2MotorDriver`:
//! its commands, its `\r\n` terminators, the codes it decodes: 34, 259, -101 … -363), the ESRF
//! BLISS MCS2 controller (which quotes the guide on hold time, velocity 0, the reference
//! options, the end stop and the state bits above 15), and two Python socket clients (kamzik3,
//! a PSI-derived one: `:SYST:ERR:NEXT?`, `:DEV:NOBM?`, `:DEV:NOCH?`, the quoted serial number,
//! `*IDN?`, `:CHAN<n>:PTYP:NAME?`, `:CHAN<n>:POS:TARG?`, `:CHAN<n>:SENS:MODE?`, `:CHAN<n>:SDIR?`,
//! `:CHAN<n>:TUN:BASE:UNIT?`, `:CHAN<n>:STEP:FREQ?`), and the CNR Tango SmarActController (which
//! documents the ranges of the step frequency and amplitude, the hold time's 4294967295 for
//! "infinite", the sensor modes, and polls `:MOD<m>:TEMP?`).
//!
//! # Syntax
//!
//! A line ends with `\n`; a `\r` before it is dropped (the EPICS driver sends `\r\n`, BLISS
//! `\n`). Every answer ends with `\r\n`. Headers are SCPI headers: nodes separated by `:` (the
//! leading colon optional), any case, each node in its short or its long form exactly (SCPI's
//! mnemonic rule), a channel or module number appended to its node (`:CHAN0`, `:MOVE2`); a
//! number left out is 0 (`:MOD:STAT?`, as BLISS polls it, is `:MOD0:STAT?`). One
//! parameter follows after white space, as SCPI decimal numeric data (`1500`, `-2.5e3`,
//! `2000000.000000`): integer settings take it rounded to the nearest integer, SCPI's rule, which
//! is also why the EPICS driver's `%f` values work on the device.
//!
//! | command | answer / effect |
//! |---|---|
//! | `*IDN?` | `SmarAct GmbH,MCS2,<serial>,<firmware>` ([`IDENTIFICATION`]) |
//! | `*CLS` | the error queue emptied |
//! | `*OPC?` | `1` |
//! | `:DEVice:SNUMber?` | `"MCS2-00004711"` (a quoted string: the clients strip the quotes) |
//! | `:DEVice:NAME?` | `"MCS2"` |
//! | `:DEVice:NOCHannels?` | the channels installed |
//! | `:DEVice:NOBModules?` | the modules installed, three channels to a module |
//! | `:DEVice:STATe?` | the device state word: 0 (no hand control module, nothing locked) |
//! | `:MODule<m>:STATe?` | the module state word: SM_PRESENT (a sensor module) |
//! | `:MODule<m>:TEMPerature?` | °C, [`TEMPERATURE`] (fixed) |
//! | `:SYSTem:ERRor[:NEXT]?` | the oldest queue entry, removed: `<code>,"<text>"`; `0,"No error"` |
//! | `:SYSTem:ERRor:COUNt?` | the entries in the queue |
//! | `:CHANnel<n>:STATe?` | the channel state word (see [`state`]) |
//! | `:CHANnel<n>:POSition[:CURRent]?`, `… <pm>` | the sensor's position; set: redefined, no motion, the target with it |
//! | `:CHANnel<n>:POSition:TARGet?` | the target the channel holds, pm: the last move's; where a stop or an end stop left it; where a reference search ended |
//! | `:CHANnel<n>:FERRor?` | the following error, pm: target − position while the loop follows a target (a closed-loop move, holding), else 0 |
//! | `:CHANnel<n>:MMODe[?]` | move mode: 0 closed-loop absolute, 1 closed-loop relative, 2/3 scan, 4 step |
//! | `:CHANnel<n>:VELocity[?]` | pm/s; 0: velocity control off, moves at [`FULL_SPEED`] |
//! | `:CHANnel<n>:ACCeleration[?]` | pm/s²; 0: acceleration control off, no ramps |
//! | `:CHANnel<n>:HOLDtime[?]` | ms the control loop holds a reached target; 0 none, -1 (or 4294967295, read back as -1) forever |
//! | `:CHANnel<n>:AMPLifier[?]` | the power amplifier, 1 on (power-up) or 0 off |
//! | `:CHANnel<n>:MCLFrequency[:CURRent][?]` | the maximum closed-loop frequency, Hz (`SA_CTL_PKEY_MAX_CL_FREQUENCY`); kept, it does not change the simulated speed; the power-up value [`POWER_UP_MCLF`] is this emulator's choice, 50 to 20,000 Hz taken |
//! | `:CHANnel<n>:REFerence:OPTions[?]` | the reference search options (see [`reference_option`]) |
//! | `:CHANnel<n>:SENSor:MODE[?]` | the sensor mode: 0 disabled, 1 enabled (power-up), 2 power save; kept, it changes nothing else |
//! | `:CHANnel<n>:SDIRection[?]` | the safe direction, 0 forward (power-up) or 1 backward; kept |
//! | `:CHANnel<n>:STEP:FREQuency[?]` | the open-loop step frequency, 1 … 20,000 Hz, power-up 1000; kept |
//! | `:CHANnel<n>:STEP:AMPLitude[?]` | the open-loop step amplitude, 1 … 65535 (100 V), power-up 65535; kept |
//! | `:CHANnel<n>:TEMPerature?` | °C, [`TEMPERATURE`] (fixed) |
//! | `:CHANnel<n>:TUNing:BASE:UNIT?`, `…:RESolution?` | the position's unit: 2 (the SDK's `SA_CTL_UNIT_METER`) and -12 (10⁻¹² of it: pm) |
//! | `:CHANnel<n>:PTYPe[?]`, `:CHANnel<n>:PTYPe:NAME?` | the positioner type, 300 `"SL...S1SS"` |
//! | `:CHANnel<n>:ERRor?` | why the last movement failed (0: it did not) |
//! | `:MOVE<n> <value>` | a move in the channel's move mode |
//! | `:STOP<n>` | the channel stops (decelerating at its acceleration, if set) |
//! | `:REFerence<n>` | the reference mark search |
//! | `:CALibrate<n>` | the sensor calibration (done at once here) |
//!
//! # Errors
//!
//! Negative codes are SCPI's (the parser's), positive ones the SDK's `SA_CTL_ERROR_*` numbers,
//! with texts made from the SDK's names (see [`error_text`]). An unknown command (an undefined
//! header, a query of a command that has no query form, a setting of a read-only property) is
//! refused with -113 "Undefined header" and nothing else: no answer, not even to a query. The
//! queue holds [`QUEUE_CAPACITY`] entries; once full, the last is replaced by -350 "Queue
//! overflow" and newer errors are lost (SCPI 21.8).
//!
//! # Readings taken where the sources are silent or ambiguous
//!
//! - **Unknown command.** The SDK numbers an unknown command 1 (`UNKNOWN_COMMAND`), SCPI -113.
//!   Taken: -113, because the ASCII parser is a SCPI parser and the EPICS driver decodes -113
//!   (as "Command not exist") and never 1. 1 belongs to the SDK's binary protocol.
//! - **Channel out of range.** SCPI would say -114 "Header suffix out of range"; taken: 34
//!   "Invalid channel index", the SDK's code, which the EPICS driver decodes. A module out of
//!   range likewise: 33 "Invalid module index".
//! - **Value out of range.** SCPI would say -222; taken: the SDK's 19 "Invalid parameter", as
//!   for the channel index (device errors are the firmware's). The ranges themselves are not
//!   documented anywhere read: velocity 0 … 100 mm/s, acceleration 0 … 100 m/s², hold time
//!   -1 … 2³¹-1 ms and 4294967295 (the CNR client's "infinite", -1 as an unsigned 32-bit
//!   number; stored as -1), reference options 0 … 0x3f (the six documented bits), sensor mode
//!   0 … 2. The step frequency and amplitude take the ranges the CNR client checks.
//! - **`*IDN?`.** The answer's form is IEEE 488.2's four fields; the words in them are this
//!   emulator's choice ([`IDENTIFICATION`]). Long forms of the nodes no witness spells out
//!   (`HOLDtime`, `AMPLifier`, `PTYPe`, `NOBModules`, `CALibrate`, `FERRor`, `SDIRection`,
//!   `TUNing`, `SENSor`, `TEMPerature`) follow SCPI's rule from the
//!   SDK's property names; the short forms are the ones the witnesses send.
//! - **Power-up.** Position 0 whatever the carriage's place (BLISS: "after power up it reports
//!   position 0"), not referenced, calibrated, amplifier on, control loop off.
//! - **End stop.** The positioner has no limit switches: the stage's switches are its
//!   mechanical end stops. A closed-loop motion that ends on one has failed: the channel stops,
//!   END_STOP_REACHED and MOVEMENT_FAILED are set and `:CHAN<n>:ERR?` says 512 "End stop
//!   reached" until the next motion command (read: the bits tell of the last movement).
//! - **Holding.** After a closed-loop move the control loop holds the target for the hold time
//!   (CLOSED_LOOP_ACTIVE and IN_POSITION set), then switches off; the time runs from when the
//!   emulator first sees the move ended (it learns the time only with input). `:STOP` ends the
//!   motion without holding.
//! - **Reference search.** It always finds the mark (the stage's home switch), whichever way it
//!   starts; with AUTO_ZERO the position there becomes 0, without it the sensor's own scale (the
//!   carriage's physical coordinate). The other options are taken but change nothing.
//! - **Scan and step modes.** Valid move modes, but no motion in them is emulated: a `:MOVE`
//!   in mode 2, 3 or 4 is refused with 32765 "Feature not supported".
//! - **Number left out.** SCPI reads an omitted numeric suffix as 1; taken: 0, the first
//!   channel or module (the MCS2 counts from 0), which BLISS relies on when it polls
//!   `:MOD:STAT?`.
//! - **Target.** `POS:TARG?` reads the target the channel holds (the EPICS driver reads it back
//!   after a home): set with the position, where the carriage came to rest after a stop or on
//!   an end stop, and where a reference search ended (0 with AUTO_ZERO).
//! - **Following error.** The simulated carriage has no trajectory setpoint apart from the
//!   target, so while a closed-loop move runs the error is what is left of it; a reference
//!   search follows no target (0).
//! - **Not emulated:** range limits (`RLIM`), what the sensor modes do (the mode is only
//!   kept), trajectory streaming, temperatures that change, several
//!   commands on one line (`;`), which is refused with -113.

use crate::emulator::axes;
use crate::{Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};
use zmotor_msgs::bits::msta;

/// Picometres per step of the stage's mechanics (`stage()` counts steps): one step is one
/// nanometre, as the EPICS driver scales the MCS2's picometres.
const PICOMETRES_PER_STAGE_STEP: f64 = 1000.0;

/// What `*IDN?` answers: manufacturer, model, serial number, firmware version.
pub(crate) const IDENTIFICATION: &str = "SmarAct GmbH,MCS2,MCS2-00004711,1.4.2";

/// What `:DEV:SNUM?` answers (a SCPI string, quoted).
const SERIAL_NUMBER: &str = "MCS2-00004711";

/// What `:DEV:NAME?` answers.
const DEVICE_NAME: &str = "MCS2";

/// Channels on one module.
const CHANNELS_PER_MODULE: usize = 3;

/// The positioner type of every channel, and its name (SL...S1SS: linear, S sensor).
const POSITIONER_TYPE: i64 = 300;
const POSITIONER_NAME: &str = "SL...S1SS";

/// The speed of a closed-loop move with velocity control off (`VEL 0`), pm/s (10 mm/s).
pub(crate) const FULL_SPEED: f64 = 1.0e10;

/// The highest velocity taken, pm/s (100 mm/s).
const MAX_VELOCITY: i64 = 100_000_000_000;

/// The highest acceleration taken, pm/s² (100 m/s²).
const MAX_ACCELERATION: i64 = 100_000_000_000_000;

/// The hold time `:CHAN<n>:HOLD` takes for "forever" besides -1: -1 as an unsigned 32-bit
/// number, as the CNR Tango client sends it.
const HOLD_FOREVER_UNSIGNED: i64 = u32::MAX as i64;

/// What `:CHAN<n>:TEMP?` and `:MOD<m>:TEMP?` answer, °C: a controller at work in a warm rack
/// (a choice; nothing here heats).
pub(crate) const TEMPERATURE: i64 = 35;

/// What `:CHAN<n>:TUN:BASE:UNIT?` answers: the SDK's `SA_CTL_UNIT_METER`.
const BASE_UNIT_METRE: i64 = 2;

/// What `:CHAN<n>:TUN:BASE:RES?` answers: positions count 10⁻¹² of the base unit, picometres.
const BASE_RESOLUTION: i64 = -12;

/// The open-loop step frequency at power-up, Hz, and the range taken (the CNR client's).
const POWER_UP_STEP_FREQUENCY: i64 = 1000;
const STEP_FREQUENCIES: (i64, i64) = (1, 20_000);

/// The highest open-loop step amplitude (100 V), also the power-up one; the lowest is 1.
const MAX_STEP_AMPLITUDE: i64 = 65535;

/// Entries the error queue holds.
pub(crate) const QUEUE_CAPACITY: usize = 16;

/// Bytes a line may have before its terminator.
const LINE_CAPACITY: usize = 512;

/// The channel state word (`:CHAN<n>:STAT?`), bit by bit as the SDK numbers
/// `SA_CTL_CH_STATE_BIT_*`.
// The whole set as documented, the bits this emulator never sets included.
#[allow(dead_code)]
pub(crate) mod state {
    /// A motion (move, calibration, reference search) is under way.
    pub(crate) const ACTIVELY_MOVING: u32 = 1 << 0;
    /// The control loop is on: moving closed loop, or holding a target.
    pub(crate) const CLOSED_LOOP_ACTIVE: u32 = 1 << 1;
    /// A sensor calibration is under way.
    pub(crate) const CALIBRATING: u32 = 1 << 2;
    /// A reference mark search is under way.
    pub(crate) const REFERENCING: u32 = 1 << 3;
    /// The start of a move waits (for the sensor, a trigger).
    pub(crate) const MOVE_DELAYED: u32 = 1 << 4;
    /// A positioner with a sensor is connected.
    pub(crate) const SENSOR_PRESENT: u32 = 1 << 5;
    /// The sensor's calibration is valid.
    pub(crate) const IS_CALIBRATED: u32 = 1 << 6;
    /// The position is known physically: a reference mark was found.
    pub(crate) const IS_REFERENCED: u32 = 1 << 7;
    /// A mechanical end stop stopped the last movement.
    pub(crate) const END_STOP_REACHED: u32 = 1 << 8;
    /// The range limit stopped the last movement.
    pub(crate) const RANGE_LIMIT_REACHED: u32 = 1 << 9;
    /// The following error went beyond its limit.
    pub(crate) const FOLLOWING_LIMIT_REACHED: u32 = 1 << 10;
    /// The last movement failed; `:CHAN<n>:ERR?` says why.
    pub(crate) const MOVEMENT_FAILED: u32 = 1 << 11;
    /// The channel takes part in trajectory streaming.
    pub(crate) const IS_STREAMING: u32 = 1 << 12;
    /// An overloaded positioner: the control loop is off.
    pub(crate) const POSITIONER_OVERLOAD: u32 = 1 << 13;
    /// Over temperature: the amplifier is off until it cools.
    pub(crate) const OVER_TEMPERATURE: u32 = 1 << 14;
    /// The positioner stands on a reference mark.
    pub(crate) const REFERENCE_MARK: u32 = 1 << 15;
    /// An electromagnetic positioner is phased.
    pub(crate) const IS_PHASED: u32 = 1 << 16;
    /// A positioner fault.
    pub(crate) const POSITIONER_FAULT: u32 = 1 << 17;
    /// The power amplifier is on.
    pub(crate) const AMPLIFIER_ENABLED: u32 = 1 << 18;
    /// Holding within the target window.
    pub(crate) const IN_POSITION: u32 = 1 << 19;
}

/// The reference search options (`:CHAN<n>:REF:OPT`), as the SDK numbers
/// `SA_CTL_REF_OPT_BIT_*`.
// The whole set as documented, the bits this emulator never sets included.
#[allow(dead_code)]
pub(crate) mod reference_option {
    /// Start the search backwards.
    pub(crate) const START_DIR: i64 = 0x01;
    /// Turn at the first mark (positioners with several marks).
    pub(crate) const REVERSE_DIR: i64 = 0x02;
    /// The position becomes 0 at the mark.
    pub(crate) const AUTO_ZERO: i64 = 0x04;
    /// Give up at the first end stop.
    pub(crate) const ABORT_ON_ENDSTOP: i64 = 0x08;
    /// Keep moving once the mark is found.
    pub(crate) const CONTINUE_ON_REF_FOUND: i64 = 0x10;
    /// Stop at once on the mark.
    pub(crate) const STOP_ON_REF_FOUND: i64 = 0x20;
}

/// The sensor modes (`:CHAN<n>:SENS:MODE`), as the SDK numbers `SA_CTL_SENSOR_MODE_*`.
mod sensor_mode {
    pub(super) const DISABLED: i64 = 0;
    pub(super) const ENABLED: i64 = 1;
    pub(super) const POWER_SAVE: i64 = 2;
}

/// The safe directions (`:CHAN<n>:SDIR`): 0 forward, 1 backward.
mod safe_direction {
    pub(super) const FORWARD: i64 = 0;
    pub(super) const BACKWARD: i64 = 1;
}

/// The move modes (`:CHAN<n>:MMOD`), as the SDK numbers `SA_CTL_MOVE_MODE_*`.
mod move_mode {
    pub(super) const CL_ABSOLUTE: i64 = 0;
    pub(super) const CL_RELATIVE: i64 = 1;
    pub(super) const STEP: i64 = 4;
}

/// Error codes: SCPI's (negative) and the SDK's `SA_CTL_ERROR_*` (positive).
mod code {
    pub(super) const NONE: i64 = 0;
    pub(super) const INVALID_CHARACTER: i64 = -101;
    pub(super) const DATA_TYPE: i64 = -104;
    pub(super) const PARAMETER_NOT_ALLOWED: i64 = -108;
    pub(super) const MISSING_PARAMETER: i64 = -109;
    pub(super) const UNDEFINED_HEADER: i64 = -113;
    pub(super) const QUEUE_OVERFLOW: i64 = -350;
    pub(super) const INPUT_BUFFER_OVERRUN: i64 = -363;
    pub(super) const INVALID_PARAMETER: i64 = 0x0013;
    pub(super) const INVALID_MODULE_INDEX: i64 = 0x0021;
    pub(super) const INVALID_CHANNEL_INDEX: i64 = 0x0022;
    pub(super) const AMPLIFIER_DISABLED: i64 = 0x0106;
    pub(super) const MOVEMENT_OVERRIDDEN: i64 = 0x0110;
    pub(super) const END_STOP_REACHED: i64 = 0x0200;
    pub(super) const FEATURE_NOT_SUPPORTED: i64 = 0x7ffd;
}

/// The text `:SYST:ERR?` gives with `code`: SCPI's words for SCPI's codes, the SDK's names
/// (`SA_CTL_ERROR_AMPLIFIER_DISABLED` → "Amplifier disabled") for the device's.
pub(crate) fn error_text(code: i64) -> &'static str {
    match code {
        0 => "No error",
        -100 => "Command error",
        -101 => "Invalid character",
        -102 => "Syntax error",
        -103 => "Invalid separator",
        -104 => "Data type error",
        -108 => "Parameter not allowed",
        -109 => "Missing parameter",
        -113 => "Undefined header",
        -350 => "Queue overflow",
        -363 => "Input buffer overrun",
        0x0001 => "Unknown command",
        0x0013 => "Invalid parameter",
        0x0016 => "Invalid data type",
        0x0021 => "Invalid module index",
        0x0022 => "Invalid channel index",
        0x0025 => "Movement locked",
        0x0103 => "No sensor present",
        0x0106 => "Amplifier disabled",
        0x0110 => "Movement overridden",
        0x0111 => "Not calibrated",
        0x0112 => "Not referenced",
        0x0150 => "Busy moving",
        0x0200 => "End stop reached",
        0x0201 => "Following error limit",
        0x0202 => "Range limit reached",
        0x7ffd => "Feature not supported",
        _ => "Unknown error",
    }
}

/// A linear positioner with a sensor counting picometres, on `stage`'s mechanics (in steps of
/// a nanometre): its end stops where the stage's limit switches are, its reference mark at the
/// stage's home switch.
pub fn mcs2_positioner(stage: &SimConfig) -> SimConfig {
    let pm = |steps: f64| steps * PICOMETRES_PER_STAGE_STEP;
    SimConfig {
        position: pm(stage.position),
        high_limit_switch: stage.high_limit_switch.map(pm),
        low_limit_switch: stage.low_limit_switch.map(pm),
        home_switch: pm(stage.home_switch),
        encoder_counts_per_step: Some(1.0),
        // Closed loop, driven by an amplifier that can be switched off.
        servo: true,
        instant: stage.instant,
    }
}

/// What a channel is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Motion {
    Idle,
    Move,
    Reference,
    Stopping,
}

/// The control loop after a motion.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Loop {
    Off,
    /// Holding the target, until the time given (seconds), or forever.
    Holding(Option<f64>),
}

/// One channel: its positioner and its properties.
struct Channel {
    axis: SimAxis,
    move_mode: i64,
    velocity: i64,
    acceleration: i64,
    hold_ms: i64,
    /// `:CHAN<n>:MCLF`, Hz.
    max_closed_loop_hz: i64,
    reference_options: i64,
    /// `:CHAN<n>:SENS:MODE` (see [`sensor_mode`]); kept, it changes nothing else.
    sensor_mode: i64,
    /// `:CHAN<n>:SDIR` (see [`safe_direction`]); kept.
    safe_direction: i64,
    /// `:CHAN<n>:STEP:FREQ`, Hz; kept (no open-loop motion is emulated).
    step_frequency: i64,
    /// `:CHAN<n>:STEP:AMPL`; kept.
    step_amplitude: i64,
    amplifier: bool,
    calibrated: bool,
    referenced: bool,
    motion: Motion,
    control: Loop,
    /// The target the channel holds (`:CHAN<n>:POS:TARG?`), pm.
    target: i64,
    end_stop: bool,
    /// Why the last movement failed; 0 when it did not.
    failure: i64,
}

impl Channel {
    fn new(mut axis: SimAxis) -> Self {
        // The sensor counts from where it was switched on.
        axis.set_position(0.0);
        Self {
            axis,
            move_mode: move_mode::CL_ABSOLUTE,
            velocity: 0,
            acceleration: 0,
            hold_ms: 0,
            max_closed_loop_hz: POWER_UP_MCLF,
            reference_options: 0,
            sensor_mode: sensor_mode::ENABLED,
            safe_direction: safe_direction::FORWARD,
            step_frequency: POWER_UP_STEP_FREQUENCY,
            step_amplitude: MAX_STEP_AMPLITUDE,
            amplifier: true,
            calibrated: true,
            referenced: false,
            motion: Motion::Idle,
            control: Loop::Off,
            target: 0,
            end_stop: false,
            failure: 0,
        }
    }

    fn position(&self) -> i64 {
        self.axis.status().position.round() as i64
    }

    /// Time passes to `now`: a motion that ended has its consequences, a timed hold expires.
    fn advance(&mut self, now: Instant) {
        self.axis.advance(now);
        let seconds = now.as_secs_f64();
        if self.motion != Motion::Idle && !self.axis.is_moving() {
            let on_end_stop = self.axis.status().msta & (msta::PLUS_LS | msta::MINUS_LS) != 0;
            let motion = std::mem::replace(&mut self.motion, Motion::Idle);
            self.control = Loop::Off;
            if motion == Motion::Stopping {
                // The target is where the carriage came to rest.
                self.target = self.position();
                return;
            }
            if on_end_stop && motion == Motion::Move {
                self.end_stop = true;
                self.failure = code::END_STOP_REACHED;
                self.target = self.position();
                return;
            }
            if motion == Motion::Reference {
                self.referenced = true;
                if self.reference_options & reference_option::AUTO_ZERO == 0 {
                    let scale = self.axis.physical_position();
                    self.axis.set_position(scale);
                }
                // The loop holds where the search ended, on the scale it left (0 with AUTO_ZERO).
                self.target = self.position();
            }
            self.control = match self.hold_ms {
                0 => Loop::Off,
                ms if ms < 0 => Loop::Holding(None),
                ms => Loop::Holding(Some(seconds + ms as f64 / 1000.0)),
            };
        }
        if let Loop::Holding(Some(until)) = self.control {
            if seconds >= until {
                self.control = Loop::Off;
            }
        }
    }

    fn state_word(&self) -> u32 {
        let moving = self.axis.is_moving();
        let holding = matches!(self.control, Loop::Holding(_));
        let mut word = 0;
        for (bit, on) in [
            (state::ACTIVELY_MOVING, moving),
            (state::CLOSED_LOOP_ACTIVE, self.amplifier && (moving || holding)),
            (state::REFERENCING, moving && self.motion == Motion::Reference),
            (state::SENSOR_PRESENT, true),
            (state::IS_CALIBRATED, self.calibrated),
            (state::IS_REFERENCED, self.referenced),
            (state::END_STOP_REACHED, self.end_stop),
            (state::MOVEMENT_FAILED, self.failure != 0),
            (state::REFERENCE_MARK, self.axis.on_home_switch()),
            (state::AMPLIFIER_ENABLED, self.amplifier),
            (state::IN_POSITION, holding && !moving),
        ] {
            if on {
                word |= bit;
            }
        }
        word
    }

    /// `:CHAN<n>:FERR?`, pm: target − position while the control loop follows the target (a
    /// closed-loop move under way, or holding), else 0.
    fn following_error(&self) -> i64 {
        let follows = match self.motion {
            Motion::Move => true,
            Motion::Idle => matches!(self.control, Loop::Holding(_)),
            Motion::Reference | Motion::Stopping => false,
        };
        if self.amplifier && follows {
            self.target.saturating_sub(self.position())
        } else {
            0
        }
    }

    fn speed(&self) -> f64 {
        if self.velocity == 0 {
            FULL_SPEED
        } else {
            self.velocity as f64
        }
    }

    /// A motion command starts: the last movement's outcome is forgotten.
    fn start(&mut self, motion: Motion) -> Result<(), i64> {
        if !self.amplifier {
            return Err(code::AMPLIFIER_DISABLED);
        }
        self.end_stop = false;
        self.failure = 0;
        self.control = Loop::Off;
        self.motion = motion;
        Ok(())
    }

    fn start_move(&mut self, value: i64) -> Result<(), i64> {
        if !(move_mode::CL_ABSOLUTE..=move_mode::CL_RELATIVE).contains(&self.move_mode) {
            return Err(code::FEATURE_NOT_SUPPORTED);
        }
        self.start(Motion::Move)?;
        let relative = self.move_mode == move_mode::CL_RELATIVE;
        self.target = if relative { self.position().saturating_add(value) } else { value };
        let (speed, acceleration) = (self.speed(), self.acceleration as f64);
        self.axis.move_to(value as f64, relative, 0.0, speed, acceleration);
        Ok(())
    }

    fn start_reference(&mut self) -> Result<(), i64> {
        self.start(Motion::Reference)?;
        let forward = self.reference_options & reference_option::START_DIR == 0;
        let (speed, acceleration) = (self.speed(), self.acceleration as f64);
        self.axis.home(forward, 0.0, speed, acceleration);
        Ok(())
    }

    fn stop(&mut self) {
        if self.motion != Motion::Idle {
            self.motion = Motion::Stopping;
            // Where it is now; where it comes to rest once it has.
            self.target = self.position();
        }
        self.control = Loop::Off;
        self.axis.stop(self.acceleration as f64);
    }

    fn set_amplifier(&mut self, on: bool) {
        self.amplifier = on;
        self.axis.enable(on);
        if !on {
            self.control = Loop::Off;
            if self.motion != Motion::Idle {
                self.motion = Motion::Stopping;
            }
        }
    }
}

/// A request's first word, understood.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Target {
    Identify,
    ClearStatus,
    OperationComplete,
    ErrorNext,
    ErrorCount,
    SerialNumber,
    DeviceName,
    ChannelCount,
    ModuleCount,
    DeviceState,
    ModuleState(usize),
    ModuleTemperature(usize),
    Channel(usize, Property),
    Move(usize),
    Stop(usize),
    Reference(usize),
    Calibrate(usize),
}

/// A channel's property.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Property {
    State,
    Position,
    TargetPosition,
    MoveMode,
    Velocity,
    Acceleration,
    HoldTime,
    Amplifier,
    MaxClosedLoopFrequency,
    ReferenceOptions,
    PositionerType,
    PositionerName,
    Error,
    SensorMode,
    SafeDirection,
    StepFrequency,
    StepAmplitude,
    Temperature,
    FollowingError,
    BaseUnit,
    BaseResolution,
}

/// One node of a header: its mnemonic, upper case, and its number if it has one.
struct Node {
    word: String,
    number: Option<usize>,
}

/// A node of a pattern: a mnemonic in SCPI's notation (short form in capitals), whether it
/// carries a number, whether it may be left out.
#[derive(Clone, Copy)]
struct Pattern {
    long: &'static str,
    numbered: bool,
    optional: bool,
}

const fn n(long: &'static str) -> Pattern {
    Pattern { long, numbered: false, optional: false }
}

const fn numbered(long: &'static str) -> Pattern {
    Pattern { long, numbered: true, optional: false }
}

const fn optional(long: &'static str) -> Pattern {
    Pattern { long, numbered: false, optional: true }
}

/// `word` (upper case) is `long`'s short or long form.
fn is_mnemonic(word: &str, long: &str) -> bool {
    let short: String = long.chars().take_while(|c| !c.is_ascii_lowercase()).collect();
    word == short || word == long.to_ascii_uppercase()
}

/// The nodes match the pattern: the numbers of its numbered nodes, in order, 0 for a number
/// left out (the MCS2 counts from 0; BLISS polls `:MOD:STAT?`).
fn matches(nodes: &[Node], pattern: &[Pattern]) -> Option<Vec<usize>> {
    let mut numbers = Vec::new();
    let mut rest = nodes;
    for p in pattern {
        let hit = rest.first().filter(|node| is_mnemonic(&node.word, p.long) && (p.numbered || node.number.is_none()));
        match hit {
            Some(node) => {
                if p.numbered {
                    numbers.push(node.number.unwrap_or(0));
                }
                rest = &rest[1..];
            }
            None if p.optional => {}
            None => return None,
        }
    }
    rest.is_empty().then_some(numbers)
}

/// The header's nodes; None when it is no SCPI header at all.
fn nodes(header: &str) -> Option<Vec<Node>> {
    let header = header.strip_prefix(':').unwrap_or(header);
    header
        .split(':')
        .map(|token| {
            let digits = token.len() - token.bytes().rev().take_while(u8::is_ascii_digit).count();
            let (word, number) = token.split_at(digits);
            if word.is_empty() || !word.bytes().all(|b| b.is_ascii_alphabetic()) {
                return None;
            }
            let number = if number.is_empty() { None } else { Some(number.parse().ok()?) };
            Some(Node { word: word.to_ascii_uppercase(), number })
        })
        .collect()
}

/// Headers without a number.
const FIXED: [(&[Pattern], Target); 7] = [
    (&[n("SYSTem"), n("ERRor"), optional("NEXT")], Target::ErrorNext),
    (&[n("SYSTem"), n("ERRor"), n("COUNt")], Target::ErrorCount),
    (&[n("DEVice"), n("SNUMber")], Target::SerialNumber),
    (&[n("DEVice"), n("NAME")], Target::DeviceName),
    (&[n("DEVice"), n("NOCHannels")], Target::ChannelCount),
    (&[n("DEVice"), n("NOBModules")], Target::ModuleCount),
    (&[n("DEVice"), n("STATe")], Target::DeviceState),
];

/// What a header with a numbered first node names, from the number.
type Numbered = fn(usize) -> Target;

/// Headers whose first node is numbered.
const NUMBERED: [(&[Pattern], Numbered); 6] = [
    (&[numbered("MOVE")], Target::Move),
    (&[numbered("STOP")], Target::Stop),
    (&[numbered("REFerence")], Target::Reference),
    (&[numbered("CALibrate")], Target::Calibrate),
    (&[numbered("MODule"), n("STATe")], Target::ModuleState),
    (&[numbered("MODule"), n("TEMPerature")], Target::ModuleTemperature),
];

/// The maximum closed-loop frequency at power-up, Hz (not documented where this emulator's
/// sources could be read: a choice).
const POWER_UP_MCLF: i64 = 15_000;

/// A channel's node.
const CHANNEL: Pattern = numbered("CHANnel");

/// A channel's properties.
const PROPERTIES: [(&[Pattern], Property); 21] = [
    (&[CHANNEL, n("STATe")], Property::State),
    (&[CHANNEL, n("POSition"), optional("CURRent")], Property::Position),
    (&[CHANNEL, n("POSition"), n("TARGet")], Property::TargetPosition),
    (&[CHANNEL, n("MMODe")], Property::MoveMode),
    (&[CHANNEL, n("VELocity")], Property::Velocity),
    (&[CHANNEL, n("ACCeleration")], Property::Acceleration),
    (&[CHANNEL, n("HOLDtime")], Property::HoldTime),
    (&[CHANNEL, n("AMPLifier")], Property::Amplifier),
    (&[CHANNEL, n("MCLFrequency"), optional("CURRent")], Property::MaxClosedLoopFrequency),
    (&[CHANNEL, n("REFerence"), n("OPTions")], Property::ReferenceOptions),
    (&[CHANNEL, n("PTYPe")], Property::PositionerType),
    (&[CHANNEL, n("PTYPe"), n("NAME")], Property::PositionerName),
    (&[CHANNEL, n("ERRor")], Property::Error),
    (&[CHANNEL, n("SENSor"), n("MODE")], Property::SensorMode),
    (&[CHANNEL, n("SDIRection")], Property::SafeDirection),
    (&[CHANNEL, n("STEP"), n("FREQuency")], Property::StepFrequency),
    (&[CHANNEL, n("STEP"), n("AMPLitude")], Property::StepAmplitude),
    (&[CHANNEL, n("TEMPerature")], Property::Temperature),
    (&[CHANNEL, n("FERRor")], Property::FollowingError),
    (&[CHANNEL, n("TUNing"), n("BASE"), n("UNIT")], Property::BaseUnit),
    (&[CHANNEL, n("TUNing"), n("BASE"), n("RESolution")], Property::BaseResolution),
];

/// What a header names.
fn target(header: &str) -> Option<Target> {
    if let Some(common) = header.strip_prefix('*') {
        return match common.to_ascii_uppercase().as_str() {
            "IDN" => Some(Target::Identify),
            "CLS" => Some(Target::ClearStatus),
            "OPC" => Some(Target::OperationComplete),
            _ => None,
        };
    }
    let nodes = nodes(header)?;
    for (pattern, target) in FIXED {
        if matches(&nodes, pattern).is_some() {
            return Some(target);
        }
    }
    for (pattern, make) in NUMBERED {
        if let Some(&[number]) = matches(&nodes, pattern).as_deref() {
            return Some(make(number));
        }
    }
    PROPERTIES.into_iter().find_map(|(pattern, property)| match matches(&nodes, pattern).as_deref() {
        Some(&[number]) => Some(Target::Channel(number, property)),
        _ => None,
    })
}

/// SCPI decimal numeric program data, rounded to an integer setting.
fn integer(text: &str) -> Result<i64, i64> {
    let body = text.strip_prefix(['+', '-']).unwrap_or(text);
    let (mantissa, exponent) = match body.find(['e', 'E']) {
        Some(at) => (&body[..at], Some(&body[at + 1..])),
        None => (body, None),
    };
    let (whole, fraction) = mantissa.split_once('.').unwrap_or((mantissa, ""));
    let digits = |part: &str| part.bytes().all(|b| b.is_ascii_digit());
    let exponent_ok = exponent.is_none_or(|e| {
        let e = e.strip_prefix(['+', '-']).unwrap_or(e);
        !e.is_empty() && digits(e)
    });
    if (whole.is_empty() && fraction.is_empty()) || !digits(whole) || !digits(fraction) || !exponent_ok {
        return Err(code::DATA_TYPE);
    }
    let value: f64 = text.parse().map_err(|_| code::DATA_TYPE)?;
    let rounded = value.round();
    if rounded >= i64::MIN as f64 && rounded < i64::MAX as f64 {
        Ok(rounded as i64)
    } else {
        Err(code::INVALID_PARAMETER)
    }
}

/// `value` if within `low..=high`, else the SDK's invalid parameter.
fn within(value: i64, low: i64, high: i64) -> Result<i64, i64> {
    if (low..=high).contains(&value) {
        Ok(value)
    } else {
        Err(code::INVALID_PARAMETER)
    }
}

/// An MCS2 with `channels` positioners, numbered from 0.
pub struct Mcs2Emulator {
    channels: Vec<Channel>,
    errors: VecDeque<i64>,
    lines: Lines,
    overruns: usize,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl Mcs2Emulator {
    /// A controller with `channels` positioners on `positioner` mechanics (in picometres, see
    /// [`mcs2_positioner`]), as at power-up.
    pub fn new(channels: usize, positioner: &SimConfig) -> Self {
        Self {
            channels: axes(channels, positioner).into_iter().map(Channel::new).collect(),
            errors: VecDeque::new(),
            lines: Lines::new(b"\n", LINE_CAPACITY),
            overruns: 0,
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    /// An entry at the end of the error queue (SCPI: when full, the last becomes -350).
    fn queue(&mut self, code: i64) {
        if self.errors.len() < QUEUE_CAPACITY {
            self.errors.push_back(code);
        } else if let Some(last) = self.errors.back_mut() {
            *last = code::QUEUE_OVERFLOW;
        }
    }

    fn channel(&mut self, index: usize) -> Result<&mut Channel, i64> {
        self.channels.get_mut(index).ok_or(code::INVALID_CHANNEL_INDEX)
    }

    fn modules(&self) -> usize {
        self.channels.len().div_ceil(CHANNELS_PER_MODULE)
    }

    /// Carry out one line: the answer, if a query.
    fn execute(&mut self, line: &str) -> Result<Option<String>, i64> {
        if !line.is_ascii() || line.bytes().any(|b| b.is_ascii_control() && b != b'\t') {
            return Err(code::INVALID_CHARACTER);
        }
        let (header, parameter) = match line.split_once([' ', '\t']) {
            Some((header, rest)) => (header, Some(rest.trim()).filter(|p| !p.is_empty())),
            None => (line, None),
        };
        let (header, query) = match header.strip_suffix('?') {
            Some(header) => (header, true),
            None => (header, false),
        };
        let target = target(header).ok_or(code::UNDEFINED_HEADER)?;
        if query {
            let answer = self.query(target)?;
            return if parameter.is_some() { Err(code::PARAMETER_NOT_ALLOWED) } else { Ok(Some(answer)) };
        }
        self.command(target, parameter)?;
        Ok(None)
    }

    fn query(&mut self, target: Target) -> Result<String, i64> {
        Ok(match target {
            Target::Identify => IDENTIFICATION.to_string(),
            Target::OperationComplete => "1".to_string(),
            Target::ErrorNext => {
                let code = self.errors.pop_front().unwrap_or(code::NONE);
                format!("{code},\"{}\"", error_text(code))
            }
            Target::ErrorCount => self.errors.len().to_string(),
            Target::SerialNumber => format!("\"{SERIAL_NUMBER}\""),
            Target::DeviceName => format!("\"{DEVICE_NAME}\""),
            Target::ChannelCount => self.channels.len().to_string(),
            Target::ModuleCount => self.modules().to_string(),
            Target::DeviceState => "0".to_string(),
            Target::ModuleState(module) => {
                if module >= self.modules() {
                    return Err(code::INVALID_MODULE_INDEX);
                }
                // SM_PRESENT: the module has its sensor module.
                "1".to_string()
            }
            Target::ModuleTemperature(module) => {
                if module >= self.modules() {
                    return Err(code::INVALID_MODULE_INDEX);
                }
                TEMPERATURE.to_string()
            }
            Target::Channel(index, property) => {
                let channel = self.channel(index)?;
                match property {
                    Property::State => channel.state_word().to_string(),
                    Property::Position => channel.position().to_string(),
                    Property::TargetPosition => channel.target.to_string(),
                    Property::MoveMode => channel.move_mode.to_string(),
                    Property::Velocity => channel.velocity.to_string(),
                    Property::Acceleration => channel.acceleration.to_string(),
                    Property::HoldTime => channel.hold_ms.to_string(),
                    Property::Amplifier => u8::from(channel.amplifier).to_string(),
                    Property::MaxClosedLoopFrequency => channel.max_closed_loop_hz.to_string(),
                    Property::ReferenceOptions => channel.reference_options.to_string(),
                    Property::PositionerType => POSITIONER_TYPE.to_string(),
                    Property::PositionerName => format!("\"{POSITIONER_NAME}\""),
                    Property::Error => channel.failure.to_string(),
                    Property::SensorMode => channel.sensor_mode.to_string(),
                    Property::SafeDirection => channel.safe_direction.to_string(),
                    Property::StepFrequency => channel.step_frequency.to_string(),
                    Property::StepAmplitude => channel.step_amplitude.to_string(),
                    Property::Temperature => TEMPERATURE.to_string(),
                    Property::FollowingError => channel.following_error().to_string(),
                    Property::BaseUnit => BASE_UNIT_METRE.to_string(),
                    Property::BaseResolution => BASE_RESOLUTION.to_string(),
                }
            }
            Target::ClearStatus | Target::Move(_) | Target::Stop(_) | Target::Reference(_) | Target::Calibrate(_) => {
                return Err(code::UNDEFINED_HEADER)
            }
        })
    }

    fn command(&mut self, target: Target, parameter: Option<&str>) -> Result<(), i64> {
        let value = || -> Result<i64, i64> {
            let text = parameter.ok_or(code::MISSING_PARAMETER)?;
            if text.contains(',') {
                return Err(code::PARAMETER_NOT_ALLOWED);
            }
            integer(text)
        };
        let none = || if parameter.is_some() { Err(code::PARAMETER_NOT_ALLOWED) } else { Ok(()) };
        match target {
            Target::ClearStatus => {
                none()?;
                self.errors.clear();
            }
            Target::Move(index) => {
                let channel = self.channel(index)?;
                let value = value()?;
                channel.start_move(value)?;
            }
            Target::Stop(index) => {
                self.channel(index)?;
                none()?;
                self.channel(index)?.stop();
            }
            Target::Reference(index) => {
                self.channel(index)?;
                none()?;
                self.channel(index)?.start_reference()?;
            }
            Target::Calibrate(index) => {
                self.channel(index)?;
                none()?;
                let channel = self.channel(index)?;
                if !channel.amplifier {
                    return Err(code::AMPLIFIER_DISABLED);
                }
                channel.calibrated = true;
            }
            Target::Channel(index, property) => {
                self.channel(index)?;
                let value = value();
                let channel = self.channel(index)?;
                match property {
                    Property::Position => {
                        let value = value?;
                        channel.axis.set_position(value as f64);
                        // The target moves with the scale: the loop holds where it is.
                        channel.target = value;
                    }
                    Property::MoveMode => channel.move_mode = within(value?, move_mode::CL_ABSOLUTE, move_mode::STEP)?,
                    Property::Velocity => channel.velocity = within(value?, 0, MAX_VELOCITY)?,
                    Property::Acceleration => channel.acceleration = within(value?, 0, MAX_ACCELERATION)?,
                    Property::HoldTime => {
                        channel.hold_ms = match value? {
                            HOLD_FOREVER_UNSIGNED => -1,
                            ms => within(ms, -1, i64::from(i32::MAX))?,
                        }
                    }
                    Property::Amplifier => channel.set_amplifier(within(value?, 0, 1)? == 1),
                    Property::MaxClosedLoopFrequency => channel.max_closed_loop_hz = within(value?, 50, 20_000)?,
                    Property::ReferenceOptions => channel.reference_options = within(value?, 0, 0x3f)?,
                    Property::PositionerType => {
                        within(value?, POSITIONER_TYPE, POSITIONER_TYPE)?;
                    }
                    Property::SensorMode => {
                        channel.sensor_mode = within(value?, sensor_mode::DISABLED, sensor_mode::POWER_SAVE)?
                    }
                    Property::SafeDirection => {
                        channel.safe_direction = within(value?, safe_direction::FORWARD, safe_direction::BACKWARD)?
                    }
                    Property::StepFrequency => {
                        let (low, high) = STEP_FREQUENCIES;
                        channel.step_frequency = within(value?, low, high)?
                    }
                    Property::StepAmplitude => channel.step_amplitude = within(value?, 1, MAX_STEP_AMPLITUDE)?,
                    Property::State
                    | Property::TargetPosition
                    | Property::PositionerName
                    | Property::Error
                    | Property::Temperature
                    | Property::FollowingError
                    | Property::BaseUnit
                    | Property::BaseResolution => return Err(code::UNDEFINED_HEADER),
                }
            }
            Target::Identify
            | Target::OperationComplete
            | Target::ErrorNext
            | Target::ErrorCount
            | Target::SerialNumber
            | Target::DeviceName
            | Target::ChannelCount
            | Target::ModuleCount
            | Target::DeviceState
            | Target::ModuleState(_)
            | Target::ModuleTemperature(_) => return Err(code::UNDEFINED_HEADER),
        }
        Ok(())
    }

    /// A refusal: queued, and counted as malformed when no well-behaved driver causes it (the
    /// others depend on the controller's state or on the channels installed).
    fn refuse(&mut self, code: i64) {
        let circumstantial = matches!(
            code,
            code::INVALID_CHANNEL_INDEX
                | code::INVALID_MODULE_INDEX
                | code::AMPLIFIER_DISABLED
                | code::FEATURE_NOT_SUPPORTED
        );
        if !circumstantial {
            self.malformed += 1;
        }
        self.queue(code);
    }
}

impl Emulator for Mcs2Emulator {
    fn name(&self) -> &'static str {
        "smaract_mcs2"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for channel in &mut self.channels {
            channel.advance(now);
        }
        let lines = self.lines.push(bytes);
        for line in lines {
            let line = line.strip_suffix(b"\r").unwrap_or(&line);
            let text = String::from_utf8_lossy(line);
            let text = text.trim();
            if text.is_empty() {
                continue;
            }
            match self.execute(text) {
                Ok(Some(answer)) => self.output.push_back(format!("{answer}\r\n").into_bytes()),
                Ok(None) => {}
                Err(code) => self.refuse(code),
            }
        }
        while self.overruns < self.lines.overflowed() {
            self.overruns += 1;
            self.refuse(code::INPUT_BUFFER_OVERRUN);
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

    /// Queues 272 "Movement overridden", as if the channel's last move had been overridden.
    fn raise_error(&mut self, channel: usize) -> bool {
        if channel >= self.channels.len() {
            return false;
        }
        self.queue(code::MOVEMENT_OVERRIDDEN);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage;

    fn mcs2(channels: usize) -> Mcs2Emulator {
        Mcs2Emulator::new(channels, &mcs2_positioner(&stage()))
    }

    /// `text` sent at `seconds`; every answer since, without its terminator.
    fn say(e: &mut Mcs2Emulator, seconds: f64, text: &str) -> Vec<String> {
        e.handle_input(Instant::from_secs_f64(seconds), text.as_bytes());
        std::iter::from_fn(|| e.poll_transmit())
            .map(|b| {
                let s = String::from_utf8(b).expect("ASCII");
                assert!(s.ends_with("\r\n"), "{s:?}");
                s.trim_end_matches("\r\n").to_string()
            })
            .collect()
    }

    fn word(e: &mut Mcs2Emulator, seconds: f64, channel: usize) -> u32 {
        say(e, seconds, &format!(":CHAN{channel}:STAT?\n"))[0].parse().expect("a number")
    }

    fn errors(e: &mut Mcs2Emulator) -> Vec<String> {
        let count: usize = say(e, 0.0, ":SYST:ERR:COUN?\n")[0].parse().expect("a count");
        (0..count).flat_map(|_| say(e, 0.0, ":SYST:ERR?\n")).collect()
    }

    #[test]
    fn what_smaracts_software_asks_first() {
        let mut e = mcs2(5);
        assert_eq!(say(&mut e, 0.0, "*IDN?\r\n"), [IDENTIFICATION]);
        assert_eq!(IDENTIFICATION.split(',').count(), 4, "IEEE 488.2: four fields");
        assert_eq!(say(&mut e, 0.0, ":DEV:SNUM?\r\n:DEVice:SNUMber?\n"), ["\"MCS2-00004711\""; 2]);
        assert_eq!(say(&mut e, 0.0, ":DEV:NOCH?\n:dev:nobm?\n:DEV:NAME?\n"), ["5", "2", "\"MCS2\""]);
        assert_eq!(say(&mut e, 0.0, ":DEV:STAT?\n:MOD1:STAT?\n"), ["0", "1"]);
        assert_eq!(say(&mut e, 0.0, ":CHAN4:PTYP?\n:CHAN4:PTYP:NAME?\n"), ["300", "\"SL...S1SS\""]);
        assert_eq!(
            say(&mut e, 0.0, ":SYST:ERR:COUN?\n:SYST:ERR?\n:SYST:ERR:NEXT?\n"),
            ["0", "0,\"No error\"", "0,\"No error\""]
        );
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn the_power_up_state_word() {
        let mut e = mcs2(1);
        let expected = state::SENSOR_PRESENT | state::IS_CALIBRATED | state::REFERENCE_MARK | state::AMPLIFIER_ENABLED;
        assert_eq!(word(&mut e, 0.0, 0), expected);
        assert_eq!(expected, 0x48060, "bits 5, 6, 15, 18");
        assert_eq!(say(&mut e, 0.0, ":CHAN0:POS?\n:CHAN0:AMPL?\n:CHAN0:HOLD?\n"), ["0", "1", "0"]);
    }

    #[test]
    fn long_and_short_forms_in_any_case_and_nothing_between() {
        let mut e = mcs2(1);
        say(&mut e, 0.0, ":CHANnel0:VELocity 2000000.000000\n:chan0:acc 1e6\n");
        assert_eq!(say(&mut e, 0.0, ":CHANNEL0:VEL?\n:CHAN0:ACCELERATION?\n"), ["2000000", "1000000"]);
        assert_eq!(say(&mut e, 0.0, "CHAN0:POSition:CURRent?\n:CHAN0:POS?\n"), ["0", "0"]);
        assert_eq!(e.malformed(), 0);
        // Neither short nor long: undefined.
        assert!(say(&mut e, 0.0, ":CHANN0:VEL?\n:CHAN0:VELO?\n").is_empty());
        assert_eq!(errors(&mut e), ["-113,\"Undefined header\""; 2]);
        // A channel number left out is channel 0 (BLISS relies on it: `:MOD:STAT?`), no longer
        // an undefined header.
        assert_eq!(say(&mut e, 0.0, ":CHAN:VEL?\n"), ["2000000"]);
    }

    #[test]
    fn an_unknown_command_is_undefined_header_and_gets_no_answer() {
        let mut e = mcs2(1);
        assert!(say(&mut e, 0.0, ":FOO?\n:CHAN0:STAT 5\n:MOVE0?\n*RST\n:CHAN0:STAT?;:CHAN0:POS?\n").is_empty());
        assert_eq!(errors(&mut e), ["-113,\"Undefined header\""; 5]);
        assert_eq!(e.malformed(), 5);
    }

    #[test]
    fn parameters_wrong_missing_or_too_many() {
        let mut e = mcs2(2);
        say(&mut e, 0.0, ":CHAN0:VEL fast\n:CHAN0:VEL\n:CHAN0:STAT? 1\n:STOP0 1\n:CHAN0:MMOD 5\n:CHAN0:VEL 1,2\n");
        let codes: Vec<String> = errors(&mut e).iter().map(|e| e.split(',').next().unwrap_or("").to_string()).collect();
        assert_eq!(codes, ["-104", "-109", "-108", "-108", "19", "-108"]);
        // A channel that is not there, a module that is not there: the device's codes.
        assert!(say(&mut e, 0.0, ":CHAN2:STAT?\n:MOVE7 5\n:MOD1:STAT?\n").is_empty());
        assert_eq!(
            errors(&mut e),
            ["34,\"Invalid channel index\"", "34,\"Invalid channel index\"", "33,\"Invalid module index\""]
        );
        assert_eq!(e.malformed(), 6);
    }

    #[test]
    fn the_queue_overflows_as_scpi_says_and_clears() {
        let mut e = mcs2(1);
        for _ in 0..QUEUE_CAPACITY + 3 {
            say(&mut e, 0.0, ":NOPE\n");
        }
        let entries = errors(&mut e);
        assert_eq!(entries.len(), QUEUE_CAPACITY);
        assert_eq!(entries[0], "-113,\"Undefined header\"");
        assert_eq!(entries.last().map(String::as_str), Some("-350,\"Queue overflow\""));
        say(&mut e, 0.0, ":NOPE\n*CLS\n");
        assert!(errors(&mut e).is_empty());
    }

    #[test]
    fn a_closed_loop_move_runs_holds_and_lets_go() {
        let mut e = mcs2(1);
        say(&mut e, 0.0, ":CHAN0:MMOD 0\n:CHAN0:ACC 0\n:CHAN0:VEL 1000000\n:CHAN0:HOLD 500\n:MOVE0 400000\n");
        assert_eq!(say(&mut e, 0.2, ":CHAN0:POS?\n:CHAN0:POS:TARG?\n"), ["200000", "400000"]);
        let moving = state::ACTIVELY_MOVING | state::CLOSED_LOOP_ACTIVE;
        assert_eq!(word(&mut e, 0.2, 0) & moving, moving);
        let holding = state::CLOSED_LOOP_ACTIVE | state::IN_POSITION;
        assert_eq!(word(&mut e, 0.5, 0) & (moving | holding), holding);
        assert_eq!(say(&mut e, 0.5, ":CHAN0:POS?\n"), ["400000"]);
        assert_eq!(word(&mut e, 1.1, 0) & (moving | holding), 0, "the hold time is over");
        // Relative, from where it is.
        say(&mut e, 2.0, ":CHAN0:MMOD 1\n:MOVE0 -100000\n");
        assert_eq!(say(&mut e, 3.0, ":CHAN0:POS?\n:CHAN0:POS:TARG?\n"), ["300000", "300000"]);
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_stop_ends_the_motion_without_holding() {
        let mut e = mcs2(1);
        say(&mut e, 0.0, ":CHAN0:VEL 1000000\n:CHAN0:HOLD -1\n:MOVE0 1000000\n");
        say(&mut e, 0.25, ":STOP0\n");
        assert_eq!(say(&mut e, 0.5, ":CHAN0:POS?\n"), ["250000"]);
        assert_eq!(word(&mut e, 0.5, 0) & (state::ACTIVELY_MOVING | state::CLOSED_LOOP_ACTIVE), 0);
    }

    #[test]
    fn an_end_stop_fails_the_movement_until_the_next() {
        let mut e = mcs2(1);
        say(&mut e, 0.0, ":CHAN0:MMOD 1\n:MOVE0 -1000000000000\n");
        let w = word(&mut e, 100.0, 0);
        let failed = state::END_STOP_REACHED | state::MOVEMENT_FAILED;
        assert_eq!(w & (failed | state::ACTIVELY_MOVING | state::CLOSED_LOOP_ACTIVE), failed);
        assert_eq!(say(&mut e, 100.0, ":CHAN0:POS?\n:CHAN0:ERR?\n"), ["-200000000", "512"]);
        say(&mut e, 100.0, ":MOVE0 1000\n");
        assert_eq!(word(&mut e, 101.0, 0) & failed, 0);
        assert_eq!(say(&mut e, 101.0, ":CHAN0:ERR?\n"), ["0"]);
    }

    #[test]
    fn a_reference_search_finds_the_mark_with_or_without_auto_zero() {
        let mut e = mcs2(1);
        say(&mut e, 0.0, ":MOVE0 3000000\n");
        say(&mut e, 1.0, ":CHAN0:POS 77\n:CHAN0:REF:OPT 5\n:REF0\n");
        let w = word(&mut e, 1.0, 0);
        assert_eq!(w & (state::REFERENCING | state::ACTIVELY_MOVING), state::REFERENCING | state::ACTIVELY_MOVING);
        let w = word(&mut e, 2.0, 0);
        let found = state::IS_REFERENCED | state::REFERENCE_MARK;
        assert_eq!(w & (found | state::REFERENCING | state::ACTIVELY_MOVING), found);
        assert_eq!(say(&mut e, 2.0, ":CHAN0:POS?\n"), ["0"]);
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn without_auto_zero_the_mark_keeps_the_sensors_scale() {
        // The mark 0.1 mm from where the carriage was switched on (where the sensor counts 0).
        let mechanics = SimConfig { home_switch: 100_000_000.0, ..mcs2_positioner(&stage()) };
        let mut e = Mcs2Emulator::new(1, &mechanics);
        say(&mut e, 0.0, ":CHAN0:POS 5000\n:CHAN0:REF:OPT 1\n:REF0\n");
        assert_eq!(say(&mut e, 1.0, ":CHAN0:POS?\n"), ["100000000"]);
        assert_ne!(word(&mut e, 1.0, 0) & state::IS_REFERENCED, 0);
    }

    #[test]
    fn with_the_amplifier_off_nothing_moves_and_the_queue_says_why() {
        let mut e = mcs2(1);
        say(&mut e, 0.0, ":CHAN0:AMPL 0\n:MOVE0 1000\n:REF0\n:CAL0\n");
        assert_eq!(errors(&mut e), ["262,\"Amplifier disabled\""; 3]);
        assert_eq!(word(&mut e, 1.0, 0) & state::AMPLIFIER_ENABLED, 0);
        assert_eq!(say(&mut e, 1.0, ":CHAN0:POS?\n"), ["0"]);
        assert_eq!(e.malformed(), 0, "the controller's state, not the driver's fault");
    }

    #[test]
    fn scan_and_step_modes_are_taken_but_not_moved_in() {
        let mut e = mcs2(1);
        say(&mut e, 0.0, ":CHAN0:MMOD 4\n:MOVE0 100\n");
        assert_eq!(say(&mut e, 0.0, ":CHAN0:MMOD?\n"), ["4"]);
        assert_eq!(errors(&mut e), ["32765,\"Feature not supported\""]);
    }

    #[test]
    fn a_flood_without_terminator_overruns_the_input_buffer() {
        let mut e = mcs2(1);
        say(&mut e, 0.0, &"x".repeat(LINE_CAPACITY + 1));
        assert_eq!(errors(&mut e), ["-363,\"Input buffer overrun\""]);
        assert_eq!(say(&mut e, 0.0, ":DEV:NOCH?\n"), ["1"]);
    }

    #[test]
    fn raise_error_queues_a_movement_overridden() {
        let mut e = mcs2(2);
        assert!(e.raise_error(1));
        assert!(!e.raise_error(2));
        assert_eq!(errors(&mut e), ["272,\"Movement overridden\""]);
        assert_eq!(e.name(), "smaract_mcs2");
    }

    #[test]
    fn the_sensor_mode_is_kept_and_checked() {
        let mut e = mcs2(2);
        assert_eq!(say(&mut e, 0.0, ":CHAN1:SENS:MODE?\n"), ["1"], "enabled at power-up");
        say(&mut e, 0.0, ":CHAN1:SENS:MODE 2\n:CHANnel0:SENSor:MODE 0\n");
        assert_eq!(say(&mut e, 0.0, ":CHAN0:SENS:MODE?\n:CHAN1:SENS:MODE?\n"), ["0", "2"]);
        assert_eq!(e.malformed(), 0);
        say(&mut e, 0.0, ":CHAN1:SENS:MODE 3\n:CHAN1:SENS:MODE -1\n");
        assert_eq!(errors(&mut e), ["19,\"Invalid parameter\""; 2]);
        assert_eq!(say(&mut e, 0.0, ":CHAN1:SENS:MODE?\n"), ["2"], "refused, unchanged");
    }

    #[test]
    fn a_number_left_out_is_zero() {
        let mut e = mcs2(4);
        assert_eq!(say(&mut e, 0.0, ":MOD:STAT?\n:MODule:TEMPerature?\n"), ["1", "35"]);
        say(&mut e, 0.0, ":CHAN:POS 1234\n:CHAN3:POS 99\n");
        assert_eq!(say(&mut e, 0.0, ":CHAN:POS?\n:CHAN0:POS?\n:CHAN3:POS?\n"), ["1234", "1234", "99"]);
        say(&mut e, 0.0, ":CHAN:VEL 1000000\n:MOVE 2000\n");
        assert_eq!(say(&mut e, 1.0, ":CHAN:POS?\n"), ["2000"]);
        assert_eq!(e.malformed(), 0);
        // Only a numbered node may go without: a number on any other is still undefined.
        assert!(say(&mut e, 1.0, ":CHAN0:POS0?\n:DEV1:NOCH?\n").is_empty());
        assert_eq!(errors(&mut e), ["-113,\"Undefined header\""; 2]);
    }

    #[test]
    fn the_target_follows_a_set_position_a_stop_an_end_stop_and_a_home() {
        let mut e = mcs2(1);
        say(&mut e, 0.0, ":CHAN0:VEL 1000000\n:MOVE0 400000\n");
        say(&mut e, 1.0, ":CHAN0:POS 50\n");
        assert_eq!(say(&mut e, 1.0, ":CHAN0:POS?\n:CHAN0:POS:TARG?\n"), ["50", "50"]);
        // Stopped halfway: the target is where it stopped.
        say(&mut e, 1.0, ":MOVE0 1000050\n");
        assert_eq!(say(&mut e, 1.25, ":STOP0\n:CHAN0:POS:TARG?\n"), ["250050"]);
        assert_eq!(say(&mut e, 2.0, ":CHAN0:POS?\n:CHAN0:POS:TARG?\n"), ["250050", "250050"]);
        // On an end stop (−0.2 mm on the carriage's own scale, shifted by the set position): where
        // the carriage stands.
        say(&mut e, 2.0, ":CHAN0:VEL 0\n:MOVE0 -1000000000000\n");
        assert_eq!(say(&mut e, 100.0, ":CHAN0:POS?\n:CHAN0:POS:TARG?\n"), ["-200399950", "-200399950"]);
        // A home that zeroes: 0, as the EPICS driver reads it back.
        say(&mut e, 100.0, ":CHAN0:REF:OPT 4\n:REF0\n");
        assert_eq!(say(&mut e, 200.0, ":CHAN0:POS?\n:CHAN0:POS:TARG?\n"), ["0", "0"]);
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn what_clients_poll_besides() {
        let mut e = mcs2(4);
        assert_eq!(
            say(&mut e, 0.0, ":CHAN3:TEMP?\n:MOD1:TEMP?\n:CHAN3:SDIR?\n:CHAN3:TUN:BASE:UNIT?\n:CHAN3:TUN:BASE:RES?\n"),
            ["35", "35", "0", "2", "-12"]
        );
        assert_eq!(say(&mut e, 0.0, ":CHAN3:STEP:FREQ?\n:CHAN3:STEP:AMPL?\n"), ["1000", "65535"]);
        say(&mut e, 0.0, ":CHAN3:STEP:FREQ 20000\n:CHAN3:STEP:AMPLitude 1\n:CHAN3:SDIRection 1\n");
        assert_eq!(say(&mut e, 0.0, ":CHAN3:STEP:FREQuency?\n:CHAN3:STEP:AMPL?\n:CHAN3:SDIR?\n"), ["20000", "1", "1"]);
        assert_eq!(say(&mut e, 0.0, ":CHAN2:STEP:FREQ?\n:CHAN2:SDIR?\n"), ["1000", "0"], "per channel");
        assert_eq!(e.malformed(), 0);
        say(&mut e, 0.0, ":CHAN3:STEP:FREQ 0\n:CHAN3:STEP:AMPL 65536\n:CHAN3:SDIR 2\n");
        assert_eq!(errors(&mut e), ["19,\"Invalid parameter\""; 3]);
        // Read-only, and a module that is not there.
        assert!(say(&mut e, 0.0, ":CHAN0:TEMP 20\n:CHAN0:FERR 0\n:CHAN0:TUN:BASE:UNIT 3\n:MOD2:TEMP?\n").is_empty());
        assert_eq!(errors(&mut e)[..3], ["-113,\"Undefined header\""; 3]);
    }

    #[test]
    fn the_following_error_while_the_loop_follows_a_target() {
        let mut e = mcs2(1);
        assert_eq!(say(&mut e, 0.0, ":CHAN0:FERR?\n"), ["0"], "control loop off");
        say(&mut e, 0.0, ":CHAN0:ACC 0\n:CHAN0:VEL 1000000\n:CHAN0:HOLD -1\n:MOVE0 400000\n");
        assert_eq!(say(&mut e, 0.1, ":CHAN0:FERR?\n"), ["300000"]);
        assert_eq!(say(&mut e, 1.0, ":CHAN0:FERR?\n"), ["0"], "holding on target");
        say(&mut e, 1.0, ":CHAN0:REF:OPT 4\n:REF0\n");
        assert_eq!(say(&mut e, 1.1, ":CHAN0:FERR?\n"), ["0"], "a reference search follows no target");
    }

    #[test]
    fn a_hold_time_of_4294967295_holds_forever() {
        let mut e = mcs2(1);
        say(&mut e, 0.0, ":CHAN0:HOLD 4294967295\n");
        assert_eq!(say(&mut e, 0.0, ":CHAN0:HOLD?\n"), ["-1"]);
        say(&mut e, 0.0, ":CHAN0:VEL 1000000\n:MOVE0 1000\n");
        let holding = state::CLOSED_LOOP_ACTIVE | state::IN_POSITION;
        assert_eq!(word(&mut e, 1000.0, 0) & holding, holding);
        // Between 2³¹-1 and 2³²-1, still refused.
        say(&mut e, 1000.0, ":CHAN0:HOLD 4294967294\n");
        assert_eq!(errors(&mut e), ["19,\"Invalid parameter\""]);
        assert_eq!(e.malformed(), 1);
    }

    #[test]
    fn lines_split_anywhere_are_one_command() {
        let mut e = mcs2(1);
        assert!(say(&mut e, 0.0, ":DEV:NO").is_empty());
        assert!(say(&mut e, 0.0, "CH?\r").is_empty());
        assert_eq!(say(&mut e, 0.0, "\n"), ["1"]);
    }
}
