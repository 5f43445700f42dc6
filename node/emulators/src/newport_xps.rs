//! A Newport XPS (XPS-C8 / XPS-Q8 / XPS-D) reached over TCP port 5001: function calls in ASCII
//! (`GroupMoveAbsolute(GROUP1.POSITIONER,10.5)`), answered `<error code>,<values>,EndOfAPI`, many
//! sockets served at once, a motion call answered on its socket only when the motion ends.
//!
//! Channel n (1 to `groups`) is the single-axis group `GROUPn` whose one positioner is
//! `GROUPn.POSITIONER`, as the vendor's example system.ini names them. Positions, speeds and
//! accelerations are in the positioner's unit, the millimetre; one simulator step is
//! [`XpsEmulator::UNIT_PER_STEP`] = 1e-4 mm.
//!
//! # Witnesses
//!
//! 1. The vendor's C library as shipped in the EPICS module motorNewport (epics-motor/
//!    motorNewport, commit e641602): `XPS_C8_drivers.cpp` ("Library version for XPS-C8 Firmware
//!    V2.6.x") gives each request's bytes — `Name (args)`, a space before the parenthesis, inputs
//!    printed `%.13g`, each output named by a C type placeholder (`double *`, `int *`,
//!    `char *`), one per positioner for the group functions (`GroupPositionCurrentGet
//!    (GROUP1,double *)`), no terminator after `)` — and the parsing of replies: the error code
//!    by `%i` from the start, each value after the next comma. `XPS_C8_errors.h` gives the error
//!    codes' numbers and names (−1 busy socket … −118). `asynOctetSocket.cpp` reads until the
//!    reply ends with `,EndOfAPI` and, on a socket written without waiting (the move socket),
//!    retries when answered −1, "previous command not complete". `XPSAxis.cpp` gives what the
//!    EPICS driver sends and reads: a move socket per axis and a poll socket; group states 0–9,
//!    50, 63 not initialised, 10–18 ready, 20–36 disabled, 11 ready from homing (its ATHM), 43
//!    homing, 44 moving, 45 trajectory, 47 jogging, 21/22/24–26/28/35 following errors, 42 and 64
//!    (not referenced, referencing); GroupKill then GroupInitialize then GroupHomeSearch (on the
//!    move socket) to home; GroupJogModeEnable then GroupJogParametersSet(positioner, v, a) to
//!    jog; GroupMoveAbort to stop a move or jog, GroupKill to stop a home search (both on the
//!    move socket, while its motion call is still unanswered); GroupKill, GroupInitialize,
//!    GroupReferencingStart, GroupReferencingActionExecute(positioner,SetPosition,None,p),
//!    GroupReferencingStop to set a position; PositionerErrorGet's 0x100 and 0x200 as the minus
//!    and plus ends of run; 0x4 of the hardware status as "ZM high level".
//! 2. The vendor's Python driver as shipped by newportxps (pyepics/newportxps, commit c09efcf):
//!    the same requests without the space (`GroupStatusGet(GROUP1,int *)`, `ErrorStringGet(-17,
//!    char *)`, `GroupStatusStringGet(12, char*)`); it splits the text before `,EndOfAPI` at its
//!    first comma into the code and the rest, so every reply has a comma there — an empty output
//!    list gives `0,,EndOfAPI` (PositionerErrorStringGet of 0 answers an empty string, shown
//!    "OK"). It logs in (`Login(Administrator,Administrator)`), reads `ErrorListGet(char *)` on
//!    connecting, then FirmwareVersionGet, and its README shows "Ready state from motion" and
//!    "First driver powered on - ZM low level". Its example system.ini names GROUP1…GROUP8 with
//!    `PositionerInUse = POSITIONER`; its stages.ini has MinimumJerkTime and MaximumJerkTime.
//! 3. The XPS Unified Programmer's Manual (EDH0373En1023, 01/18, on easymanua.ls): only its
//!    GroupReferencingStart page could be read — group name checked (−19 "GroupName doesn't
//!    exist or unknown command"), the group must be NOT REFERENCED (−22 "Not allowed action"),
//!    the group goes to REFERENCING, and GroupReferencingStop goes to READY. The XPS-D Startup
//!    Manual (manualslib, §2.8): the XPS serves a high number of sockets at once and always
//!    answers a function on the socket that sent it. The rest of the manuals (the common input
//!    tests of §7.1, the group status list, the error texts, the positioner error and hardware
//!    status lists) could not be read.
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Framing**: a request ends at its `)` (neither library sends a terminator; the XPS answers
//!   each call it has whole). Spaces and line ends around the name are ignored. 1,024 bytes
//!   without `)` (the C library's request buffer) are lost and answered −3, counted malformed.
//!   A request without `(` is −7. Values are printed with up to 10 decimals, zeros trimmed.
//! - **Busy sockets**: EPICS sends GroupMoveAbort and GroupKill on a move socket whose motion
//!   call is unanswered, so a socket holding a motion still serves other functions at once (their
//!   replies go out before the held one); a second motion call (move or home search) there is
//!   answered −1 at once and not carried out — the busy socket of the error list, and what the
//!   EPICS socket layer retries on. The held reply is 0 when the motion ends, −27 when it is
//!   aborted or killed, −25 on a following error, −5 when an end of run stops it. A socket
//!   closed drops its held reply; the group moves on. 100 sockets (the Python library's
//!   `MAX_NB_SOCKETS`; the manual says only "a high number").
//! - **Status codes and texts**: the group status texts are those recalled from the XPS manuals'
//!   group status list (only "Ready state from motion" is witnessed); an undefined code is −17.
//!   The emulator goes through 0 (power-up), 42 (GroupInitialize, GroupKill's next step), 43,
//!   11, 44, 12, 10 (GroupMoveAbort), 47, 15, 20, 13 (GroupMotionEnable), 64, 7 (GroupKill,
//!   KillAll), 8 (an end of run reached), 21, 22, 25 and 3 (a following error when ready,
//!   moving, jogging, homing). Functions of motion are refused −22 outside their states.
//! - **Errors and texts**: an unknown function is −4; a group name that is none is −19, a
//!   positioner name −18 (also a group given where a positioner is wanted, and the reverse); a
//!   wrong count of inputs or outputs −9; a number that is not one −14 (double) or −15 (int);
//!   a value out of range −17; a target outside the user travel limits −35; a jog beyond the
//!   maxima −42; a login other than Administrator/Administrator −106. All these but −1, −17,
//!   −22, −35, −42 and −106 count as malformed. ErrorStringGet's texts follow the XPS manuals as
//!   recalled (the header's names otherwise); ErrorListGet joins `code : text` with `;`.
//! - **Positioner error** (PositionerErrorGet; PositionerErrorRead also clears the latched
//!   following error): 0x1 fatal following error (`raise_error`), 0x100 minus and 0x200 plus end
//!   of run, live. **Hardware status**: 0x4 ZM high level (the carriage on the positive side of
//!   the home switch, inclusive), 0x100 and 0x200 the ends of run, 0x00400000 first driver
//!   powered on (a group initialised and not disabled; the bit is a reading). Their strings join
//!   the texts with " - " (as the README shows), the hardware one always naming the ZM level.
//!   PositionerDriverStatusGet is 0; PositionerCorrectorTypeGet is `NoEncoderPosition`.
//! - **Motion**: every motion runs at the SGamma velocity and acceleration (the jerk times are
//!   kept, not simulated); GroupMoveAbort decelerates at the acceleration in use. A jog runs at
//!   most to the user travel limits, a change of its velocity replans it, a velocity of 0 stops
//!   it in jog mode; GroupJogModeDisable is refused while it moves. A home search goes to the
//!   home switch, which reads 0 (HomePreset 0). SetPosition defines the position in REFERENCING;
//!   SetPositionToHomePreset defines 0; other referencing actions are −17. The setpoint is the
//!   current position (no following error); the target is the last move's. The current
//!   acceleration is the profile's: ± the acceleration while ramping or braking, 0 cruising.
//! - **Power-up**: every group NOTINIT (0) at the simulator's position; maximum velocity 10
//!   mm/s, maximum acceleration 40 mm/s², SGamma at those with jerk times 0.005 and 0.05 s; user
//!   travel limits 0.1 mm inside the limit switches (±1,000 mm without). FirmwareVersionGet
//!   answers `XPS-C8 Firmware V2.6.x`, the firmware the libraries are written for.

use crate::emulator::axes;
use crate::{Connection, Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

/// Sockets the controller serves at once.
const SOCKETS: usize = 100;
/// Bytes of a request before its `)`, as the vendor's library sizes its buffer.
const REQUEST_BUFFER: usize = 1024;
const FIRMWARE: &str = "XPS-C8 Firmware V2.6.x";
const MAX_VELOCITY: f64 = 10.0;
const MAX_ACCELERATION: f64 = 40.0;

// Error codes (XPS_C8_errors.h).
const BUSY_SOCKET: i32 = -1;
const STRING_TOO_LONG: i32 = -3;
const UNKNOWN_COMMAND: i32 = -4;
const POSITIONER_ERROR: i32 = -5;
const WRONG_FORMAT: i32 = -7;
const WRONG_PARAMETERS_NUMBER: i32 = -9;
const WRONG_TYPE_DOUBLE: i32 = -14;
const WRONG_TYPE_INT: i32 = -15;
const OUT_OF_RANGE: i32 = -17;
const POSITIONER_NAME: i32 = -18;
const GROUP_NAME: i32 = -19;
const NOT_ALLOWED: i32 = -22;
const FOLLOWING_ERROR: i32 = -25;
const ABORTED: i32 = -27;
const TRAVEL_LIMITS: i32 = -35;
const JOG_OUT_OF_RANGE: i32 = -42;
const WRONG_LOGIN: i32 = -106;

const ERRORS: &[(i32, &str)] = &[
    (0, "Successful command"),
    (BUSY_SOCKET, "Busy socket: previous command not yet finished"),
    (-2, "TCP timeout"),
    (STRING_TOO_LONG, "String command too long"),
    (UNKNOWN_COMMAND, "Unknown command"),
    (POSITIONER_ERROR, "Not allowed due to a positioner error or hardware status"),
    (WRONG_FORMAT, "Wrong format in the command string"),
    (-8, "Wrong object type for this command"),
    (WRONG_PARAMETERS_NUMBER, "Wrong number of parameters in the command"),
    (-10, "Wrong parameter type in the command string"),
    (WRONG_TYPE_DOUBLE, "Wrong parameter type in the command string: double or double * expected"),
    (WRONG_TYPE_INT, "Wrong parameter type in the command string: int or int * expected"),
    (OUT_OF_RANGE, "Parameter out of range or incorrect"),
    (POSITIONER_NAME, "Positioner Name doesn't exist or unknown command"),
    (GROUP_NAME, "GroupName doesn't exist or unknown command"),
    (NOT_ALLOWED, "Not allowed action"),
    (FOLLOWING_ERROR, "Following Error"),
    (ABORTED, "Move Aborted"),
    (TRAVEL_LIMITS, "Travel limits"),
    (JOG_OUT_OF_RANGE, "Jog value out of range"),
    (WRONG_LOGIN, "Wrong user name or password"),
];

const GROUP_STATES: &[(u8, &str)] = &[
    (0, "Not initialized state"),
    (1, "Not initialized state due to an emergency brake: see positioner status"),
    (2, "Not initialized state due to an emergency stop: see positioner status"),
    (3, "Not initialized state due to a following error during homing"),
    (4, "Not initialized state due to a following error"),
    (5, "Not initialized state due to an homing timeout"),
    (6, "Not initialized state due to a motion done timeout during homing"),
    (7, "Not initialized state due to a GroupKill or KillAll command"),
    (8, "Not initialized state due to an end of run after homing"),
    (9, "Not initialized state due to an encoder calibration error"),
    (10, "Ready state due to an AbortMove command"),
    (11, "Ready state from homing"),
    (12, "Ready state from motion"),
    (13, "Ready State due to a MotionEnable command"),
    (14, "Ready state from slave"),
    (15, "Ready state from jogging"),
    (16, "Ready state from analog tracking"),
    (17, "Ready state from trajectory"),
    (18, "Ready state from spinning"),
    (19, "Ready state due to a group interlock error during motion"),
    (20, "Disabled state"),
    (21, "Disabled state due to a following error on ready state"),
    (22, "Disabled state due to a following error during motion"),
    (23, "Disabled state due to a motion done timeout during moving"),
    (24, "Disabled state due to a following error on slave state"),
    (25, "Disabled state due to a following error on jogging state"),
    (26, "Disabled state due to a following error during trajectory"),
    (27, "Disabled state due to a motion done timeout during trajectory"),
    (28, "Disabled state due to a following error during analog tracking"),
    (29, "Disabled state due to a slave error during motion"),
    (30, "Disabled state due to a slave error on slave state"),
    (31, "Disabled state due to a slave error on jogging state"),
    (32, "Disabled state due to a slave error during trajectory"),
    (33, "Disabled state due to a slave error during analog tracking"),
    (34, "Disabled state due to a slave error on ready state"),
    (35, "Disabled state due to a following error on spinning state"),
    (36, "Disabled state due to a slave error on spinning state"),
    (37, "Disabled state due to a following error on auto-tuning"),
    (38, "Disabled state due to a slave error on auto-tuning"),
    (39, "Disabled state due to an emergency stop on auto-tuning state"),
    (40, "Emergency braking"),
    (41, "Motor initialization state"),
    (42, "Not referenced state"),
    (43, "Homing state"),
    (44, "Moving state"),
    (45, "Trajectory state"),
    (46, "Slave state due to a SlaveEnable command"),
    (47, "Jogging state due to a JogEnable command"),
    (48, "Analog tracking state due to a TrackingEnable command"),
    (49, "Analog interpolated encoder calibrating state"),
    (50, "Not initialized state due to a mechanical zero inconsistency during homing"),
    (51, "Spinning state due to a SpinParametersSet command"),
    (52, "Not initialized state due to a clamping timeout"),
    (55, "Clamped"),
    (56, "Ready state from clamped"),
    (58, "Disabled state due to a following error during clamped"),
    (59, "Disabled state due to a motion done timeout during clamped"),
    (60, "Not initialized state due to a group interlock error on not reference state"),
    (61, "Not initialized state due to a group interlock error during homing"),
    (63, "Not initialized state due to a motor initialization error"),
    (64, "Referencing state"),
    (65, "Clamping initialization"),
    (66, "Not initialized state due to a perpendicularity error homing"),
    (67, "Not initialized state due to a master/slave error during homing"),
    (68, "Auto-tuning state"),
    (69, "Scaling calibration state"),
    (70, "Ready state from auto-tuning"),
    (71, "Not initialized state from scaling calibration"),
    (72, "Not initialized state due to a scaling calibration error"),
    (73, "Excitation signal generation state"),
    (74, "Disable state due to a following error on excitation signal generation state"),
    (75, "Disable state due to a master/slave error on excitation signal generation state"),
    (76, "Disable state due to an emergency stop on excitation signal generation state"),
    (77, "Ready state from excitation signal generation"),
    (78, "Focus state"),
    (79, "Ready state from focus"),
];

// Positioner error and hardware status bits.
const FATAL_FOLLOWING_ERROR: i64 = 0x1;
const ZM_HIGH_LEVEL: i64 = 0x4;
const MINUS_END_OF_RUN: i64 = 0x100;
const PLUS_END_OF_RUN: i64 = 0x200;
const FIRST_DRIVER_POWERED: i64 = 0x0040_0000;

/// A function's answer: its values, or an error code.
type Answer = Result<Vec<String>, i32>;

/// What a motion call started: the group's motion, and whose reply waits for it.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    Move,
    Home,
    Jog,
}

#[derive(Clone, Copy, Debug)]
struct Motion {
    kind: Kind,
    /// The socket whose motion call is answered when the motion ends.
    holder: Option<Connection>,
    aborted: bool,
    /// Stopping: aborted, or a jog set to velocity 0.
    braking: bool,
    /// Where the carriage is headed (steps, physical), its cruise speed and acceleration (steps).
    end: f64,
    cruise: f64,
    acceleration: f64,
}

impl Motion {
    fn new(kind: Kind, holder: Option<Connection>, end: f64, cruise: f64, acceleration: f64) -> Self {
        Self { kind, holder, aborted: false, braking: false, end, cruise, acceleration }
    }
}

/// One single-axis group and its positioner.
struct Group {
    sim: SimAxis,
    status: u8,
    motion: Option<Motion>,
    velocity: f64,
    acceleration: f64,
    jerk: (f64, f64),
    jog: (f64, f64),
    travel: (f64, f64),
    target: f64,
    following_error: bool,
}

impl Group {
    fn new(sim: SimAxis) -> Self {
        let limit = |switch: Option<f64>, inward: f64, none: f64| {
            switch.map_or(none, |s| s * XpsEmulator::UNIT_PER_STEP + inward)
        };
        let config = sim.config();
        let travel = (limit(config.low_limit_switch, 0.1, -1000.0), limit(config.high_limit_switch, -0.1, 1000.0));
        let target = sim.status().position * XpsEmulator::UNIT_PER_STEP;
        Self {
            sim,
            status: 0,
            motion: None,
            velocity: MAX_VELOCITY,
            acceleration: MAX_ACCELERATION,
            jerk: (0.005, 0.05),
            jog: (0.0, 0.0),
            travel,
            target,
            following_error: false,
        }
    }

    fn position(&self) -> f64 {
        self.sim.status().position * XpsEmulator::UNIT_PER_STEP
    }

    fn velocity_now(&self) -> f64 {
        self.sim.status().velocity * XpsEmulator::UNIT_PER_STEP
    }

    fn ready(&self) -> bool {
        (10..=19).contains(&self.status)
    }

    fn not_initialized(&self) -> bool {
        self.status <= 9 || matches!(self.status, 50 | 52 | 60 | 61 | 63 | 66 | 67 | 71 | 72)
    }

    fn disabled(&self) -> bool {
        (20..=39).contains(&self.status)
    }

    /// The acceleration of the profile now (mm/s²): ramping up, cruising, or braking to its end.
    fn acceleration_now(&self) -> f64 {
        let Some(motion) = self.motion else { return 0.0 };
        let velocity = self.sim.status().velocity;
        let physical = self.sim.physical_position();
        let ahead = motion.end - physical;
        let sign = if velocity != 0.0 { velocity.signum() } else { ahead.signum() };
        let braking_distance = velocity * velocity / (2.0 * motion.acceleration);
        let steps = if motion.braking || ahead.abs() <= braking_distance + 1e-9 {
            -sign * motion.acceleration
        } else if velocity.abs() < motion.cruise - 1e-9 {
            sign * motion.acceleration
        } else {
            0.0
        };
        steps * XpsEmulator::UNIT_PER_STEP
    }

    /// Where a move to `target` (mm) ends, in physical steps.
    fn physical_end(&self, target: f64) -> f64 {
        self.sim.physical_position() + target / XpsEmulator::UNIT_PER_STEP - self.sim.status().position
    }

    /// A motion that has ended gets the group's new state; the held reply, if any, is returned.
    fn settle(&mut self) -> Option<(Connection, i32)> {
        let motion = self.motion?;
        if self.sim.is_moving() {
            return None;
        }
        self.motion = None;
        let state = self.sim.state();
        let (status, code) = if state.high_limit || state.low_limit {
            (8, POSITIONER_ERROR)
        } else if motion.aborted {
            (10, ABORTED)
        } else {
            match motion.kind {
                Kind::Move => (12, 0),
                Kind::Home => (11, 0),
                Kind::Jog => (47, 0),
            }
        };
        self.status = status;
        motion.holder.map(|holder| (holder, code))
    }

    /// The motion stops at once (a kill, a following error); its held reply gets `code`.
    fn halt(&mut self, code: i32) -> Option<(Connection, i32)> {
        let motion = self.motion.take()?;
        self.sim.stop(0.0);
        motion.holder.map(|holder| (holder, code))
    }

    fn positioner_error(&self) -> i64 {
        let state = self.sim.state();
        let flag = |on: bool, bit: i64| if on { bit } else { 0 };
        flag(self.following_error, FATAL_FOLLOWING_ERROR)
            | flag(state.low_limit, MINUS_END_OF_RUN)
            | flag(state.high_limit, PLUS_END_OF_RUN)
    }

    fn hardware_status(&self) -> i64 {
        let state = self.sim.state();
        let powered = !self.not_initialized() && !self.disabled();
        let zm_high = self.sim.physical_position() >= self.sim.config().home_switch;
        let flag = |on: bool, bit: i64| if on { bit } else { 0 };
        flag(powered, FIRST_DRIVER_POWERED)
            | flag(zm_high, ZM_HIGH_LEVEL)
            | flag(state.low_limit, MINUS_END_OF_RUN)
            | flag(state.high_limit, PLUS_END_OF_RUN)
    }

    /// A move to `target` (mm) from a ready state.
    fn start_move(&mut self, target: f64, holder: Connection) -> Result<(), i32> {
        if !self.ready() {
            return Err(NOT_ALLOWED);
        }
        if !(self.travel.0..=self.travel.1).contains(&target) {
            return Err(TRAVEL_LIMITS);
        }
        let unit = XpsEmulator::UNIT_PER_STEP;
        let (cruise, acceleration) = (self.velocity / unit, self.acceleration / unit);
        let end = self.physical_end(target);
        self.target = target;
        self.sim.move_to(target / unit, false, 0.0, cruise, acceleration);
        self.status = 44;
        self.motion = Some(Motion::new(Kind::Move, Some(holder), end, cruise, acceleration));
        Ok(())
    }

    /// A new jog velocity and acceleration, in jog mode.
    fn set_jog(&mut self, velocity: f64, acceleration: f64) -> Result<(), i32> {
        if self.status != 47 {
            return Err(NOT_ALLOWED);
        }
        if velocity.abs() > MAX_VELOCITY || acceleration <= 0.0 || acceleration > MAX_ACCELERATION {
            return Err(JOG_OUT_OF_RANGE);
        }
        let unit = XpsEmulator::UNIT_PER_STEP;
        self.jog = (velocity, acceleration);
        if velocity == 0.0 {
            if let Some(motion) = self.motion.as_mut() {
                (motion.braking, motion.acceleration) = (true, acceleration / unit);
            }
            self.sim.stop(acceleration / unit);
            return Ok(());
        }
        let limit = if velocity > 0.0 { self.travel.1 } else { self.travel.0 };
        let (end, cruise) = (self.physical_end(limit), velocity.abs() / unit);
        self.sim.move_to(limit / unit, false, 0.0, cruise, acceleration / unit);
        self.motion = self.sim.is_moving().then(|| Motion::new(Kind::Jog, None, end, cruise, acceleration / unit));
        Ok(())
    }

    fn abort(&mut self) -> Result<(), i32> {
        let unit = XpsEmulator::UNIT_PER_STEP;
        match self.motion.as_mut() {
            Some(motion) if motion.kind != Kind::Home => {
                let deceleration = if motion.kind == Kind::Jog { self.jog.1 } else { self.acceleration };
                (motion.aborted, motion.braking, motion.acceleration) = (true, true, deceleration / unit);
                self.sim.stop(deceleration / unit);
                Ok(())
            }
            None if self.status == 47 => {
                self.status = 10;
                Ok(())
            }
            _ => Err(NOT_ALLOWED),
        }
    }
}

/// One socket: its requests in pieces.
struct Socket {
    requests: Lines,
}

impl Socket {
    fn new() -> Self {
        Self { requests: Lines::new(b")", REQUEST_BUFFER) }
    }
}

/// An XPS with the single-axis groups GROUP1… (as many as asked) behind port 5001.
pub struct XpsEmulator {
    groups: Vec<Group>,
    sockets: Vec<Socket>,
    output: VecDeque<(Connection, Vec<u8>)>,
    now: Instant,
    malformed: usize,
}

fn reply(code: i32, values: &[String]) -> Vec<u8> {
    format!("{code},{},EndOfAPI", values.join(",")).into_bytes()
}

/// A double as the XPS prints it here: up to 10 decimals, trailing zeros trimmed.
fn number(value: f64) -> String {
    let text = format!("{value:.10}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    if text == "-0" {
        "0".into()
    } else {
        text.into()
    }
}

fn double(text: &str) -> Result<f64, i32> {
    text.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or(WRONG_TYPE_DOUBLE)
}

fn int(text: &str) -> Result<i64, i32> {
    text.parse().map_err(|_| WRONG_TYPE_INT)
}

fn is_output(arg: &str) -> bool {
    arg.ends_with('*')
}

/// The inputs are `inputs` values followed by `outputs` placeholders.
fn shape(args: &[&str], inputs: usize, outputs: usize) -> Result<(), i32> {
    let fits = args.len() == inputs + outputs
        && args[..inputs].iter().all(|a| !is_output(a))
        && args[inputs..].iter().all(|a| is_output(a));
    fits.then_some(()).ok_or(WRONG_PARAMETERS_NUMBER)
}

fn bits_text(code: i64, texts: &[(i64, &str)]) -> String {
    texts.iter().filter(|(bit, _)| code & bit != 0).map(|(_, text)| *text).collect::<Vec<_>>().join(" - ")
}

fn one(value: impl ToString) -> Answer {
    Ok(vec![value.to_string()])
}

impl XpsEmulator {
    /// Millimetres of the positioner's travel in one simulator step.
    pub const UNIT_PER_STEP: f64 = 1e-4;

    /// A controller with `groups` single-axis groups (1 to 8), GROUP1 to GROUPn, on `mechanics`,
    /// every group not initialised.
    pub fn new(groups: usize, mechanics: &SimConfig) -> Self {
        Self {
            groups: axes(groups.clamp(1, 8), mechanics).into_iter().map(Group::new).collect(),
            sockets: Vec::new(),
            output: VecDeque::new(),
            now: Instant::ZERO,
            malformed: 0,
        }
    }

    /// The group a name of `GROUPn` is.
    fn group(&self, name: &str) -> Result<usize, i32> {
        name.strip_prefix("GROUP")
            .and_then(|n| n.parse::<usize>().ok())
            .filter(|n| (1..=self.groups.len()).contains(n) && name == format!("GROUP{n}"))
            .map(|n| n - 1)
            .ok_or(GROUP_NAME)
    }

    /// The group whose positioner `GROUPn.POSITIONER` is.
    fn positioner(&self, name: &str) -> Result<usize, i32> {
        let group = name.strip_suffix(".POSITIONER").ok_or(POSITIONER_NAME)?;
        self.group(group).map_err(|_| POSITIONER_NAME)
    }

    /// A group, or a positioner standing for its group (one positioner: one value).
    fn group_or_positioner(&self, name: &str) -> Result<usize, i32> {
        if name.contains('.') {
            self.positioner(name)
        } else {
            self.group(name)
        }
    }

    fn busy(&self, connection: Connection) -> bool {
        self.groups.iter().any(|g| g.motion.is_some_and(|m| m.holder == Some(connection)))
    }

    fn send(&mut self, connection: Connection, code: i32, values: &[String]) {
        self.output.push_back((connection, reply(code, values)));
    }

    fn advance(&mut self, now: Instant) {
        self.now = self.now.max(now);
        for group in &mut self.groups {
            group.sim.advance(self.now);
        }
        self.settle();
    }

    fn settle(&mut self) {
        let done: Vec<_> = self.groups.iter_mut().filter_map(Group::settle).collect();
        for (connection, code) in done {
            self.send(connection, code, &[]);
        }
    }

    /// One request, as text without its `)`; None when the answer is held for a motion.
    fn request(&mut self, connection: Connection, text: &str) -> Option<Answer> {
        let Some((name, args)) = text.split_once('(') else { return Some(Err(WRONG_FORMAT)) };
        let name = name.trim();
        let args: Vec<&str> =
            if args.trim().is_empty() { Vec::new() } else { args.split(',').map(str::trim).collect() };
        if matches!(name, "GroupMoveAbsolute" | "GroupMoveRelative" | "GroupHomeSearch") {
            if self.busy(connection) {
                return Some(Err(BUSY_SOCKET));
            }
            return self.motion_call(connection, name, &args).err().map(Err);
        }
        Some(self.function(name, &args))
    }

    /// The functions that are answered when their motion ends.
    fn motion_call(&mut self, connection: Connection, name: &str, args: &[&str]) -> Result<(), i32> {
        let first = args.first().ok_or(WRONG_PARAMETERS_NUMBER)?;
        if name == "GroupHomeSearch" {
            shape(args, 1, 0)?;
            let i = self.group(first)?;
            let g = &mut self.groups[i];
            if g.status != 42 {
                return Err(NOT_ALLOWED);
            }
            let unit = Self::UNIT_PER_STEP;
            let (cruise, acceleration, end) = (g.velocity / unit, g.acceleration / unit, g.sim.config().home_switch);
            g.sim.home(g.sim.physical_position() < end, 0.0, cruise, acceleration);
            g.status = 43;
            g.target = 0.0;
            g.motion = Some(Motion::new(Kind::Home, Some(connection), end, cruise, acceleration));
            return Ok(());
        }
        let i = self.group_or_positioner(first)?;
        shape(args, 2, 0)?;
        let value = double(args[1])?;
        let g = &mut self.groups[i];
        let target = if name == "GroupMoveAbsolute" { value } else { g.position() + value };
        g.start_move(target, connection)
    }

    fn function(&mut self, name: &str, args: &[&str]) -> Answer {
        let arg = |n: usize| args.get(n).copied().unwrap_or("");
        match name {
            "Login" => {
                shape(args, 2, 0)?;
                if args == ["Administrator", "Administrator"] {
                    Ok(vec![])
                } else {
                    Err(WRONG_LOGIN)
                }
            }
            "FirmwareVersionGet" => shape(args, 0, 1).and_then(|_| one(FIRMWARE)),
            "ElapsedTimeGet" => shape(args, 0, 1).and_then(|_| one(number(self.now.as_secs_f64()))),
            "ControllerStatusGet" => shape(args, 0, 1).and_then(|_| one(0)),
            "ErrorStringGet" => {
                shape(args, 1, 1)?;
                let code = int(arg(0))?;
                let text = ERRORS.iter().find(|(c, _)| i64::from(*c) == code).ok_or(OUT_OF_RANGE)?;
                one(text.1)
            }
            "ErrorListGet" => {
                shape(args, 0, 1)?;
                one(ERRORS.iter().map(|(code, text)| format!("{code} : {text}")).collect::<Vec<_>>().join(";"))
            }
            "GroupStatusGet" => {
                shape(args, 1, 1)?;
                one(self.groups[self.group(arg(0))?].status)
            }
            "GroupStatusStringGet" => {
                shape(args, 1, 1)?;
                let code = int(arg(0))?;
                let text = GROUP_STATES.iter().find(|(c, _)| i64::from(*c) == code).ok_or(OUT_OF_RANGE)?;
                one(text.1)
            }
            "KillAll" => {
                shape(args, 0, 0)?;
                for i in 0..self.groups.len() {
                    self.kill(i);
                }
                Ok(vec![])
            }
            "GroupKill"
            | "GroupInitialize"
            | "GroupInitializeWithEncoderCalibration"
            | "GroupMoveAbort"
            | "GroupMotionEnable"
            | "GroupMotionDisable"
            | "GroupJogModeEnable"
            | "GroupJogModeDisable"
            | "GroupReferencingStart"
            | "GroupReferencingStop" => {
                shape(args, 1, 0)?;
                let i = self.group(arg(0))?;
                self.group_action(name, i).map(|_| vec![])
            }
            "GroupJogParametersSet" => {
                shape(args, 3, 0)?;
                let i = self.group_or_positioner(arg(0))?;
                let (velocity, acceleration) = (double(arg(1))?, double(arg(2))?);
                self.groups[i].set_jog(velocity, acceleration).map(|_| vec![])
            }
            "GroupJogParametersGet" | "GroupJogCurrentGet" => {
                let g = &self.groups[self.group_or_positioner(arg(0))?];
                shape(args, 1, 2)?;
                let values =
                    if name == "GroupJogParametersGet" { g.jog } else { (g.velocity_now(), g.acceleration_now()) };
                Ok(vec![number(values.0), number(values.1)])
            }
            "GroupPositionCurrentGet"
            | "GroupPositionSetpointGet"
            | "GroupPositionTargetGet"
            | "GroupVelocityCurrentGet"
            | "GroupAccelerationCurrentGet" => {
                let g = &self.groups[self.group_or_positioner(arg(0))?];
                shape(args, 1, 1)?;
                let value = match name {
                    "GroupPositionTargetGet" => g.target,
                    "GroupVelocityCurrentGet" => g.velocity_now(),
                    "GroupAccelerationCurrentGet" => g.acceleration_now(),
                    _ => g.position(),
                };
                one(number(value))
            }
            "PositionerErrorGet" | "PositionerErrorRead" => {
                shape(args, 1, 1)?;
                let i = self.positioner(arg(0))?;
                let g = &mut self.groups[i];
                let code = g.positioner_error();
                g.following_error &= name == "PositionerErrorGet";
                one(code)
            }
            "PositionerErrorStringGet" => {
                shape(args, 1, 1)?;
                let texts = [
                    (FATAL_FOLLOWING_ERROR, "Fatal following error"),
                    (MINUS_END_OF_RUN, "Minus end of run activated"),
                    (PLUS_END_OF_RUN, "Plus end of run activated"),
                ];
                one(bits_text(int(arg(0))?, &texts))
            }
            "PositionerHardwareStatusGet" => {
                shape(args, 1, 1)?;
                one(self.groups[self.positioner(arg(0))?].hardware_status())
            }
            "PositionerHardwareStatusStringGet" => {
                shape(args, 1, 1)?;
                let code = int(arg(0))?;
                let zm = if code & ZM_HIGH_LEVEL != 0 { "ZM high level" } else { "ZM low level" };
                let powered = bits_text(code, &[(FIRST_DRIVER_POWERED, "First driver powered on")]);
                let ends = bits_text(
                    code,
                    &[(MINUS_END_OF_RUN, "Minus end of run activated"), (PLUS_END_OF_RUN, "Plus end of run activated")],
                );
                let parts: Vec<&str> =
                    [powered.as_str(), zm, ends.as_str()].into_iter().filter(|t| !t.is_empty()).collect();
                one(parts.join(" - "))
            }
            "PositionerDriverStatusGet" => {
                shape(args, 1, 1)?;
                self.positioner(arg(0)).and_then(|_| one(0))
            }
            "PositionerCorrectorTypeGet" => {
                shape(args, 1, 1)?;
                self.positioner(arg(0)).and_then(|_| one("NoEncoderPosition"))
            }
            "PositionerMaximumVelocityAndAccelerationGet" => {
                shape(args, 1, 2)?;
                self.positioner(arg(0))?;
                Ok(vec![number(MAX_VELOCITY), number(MAX_ACCELERATION)])
            }
            "PositionerUserTravelLimitsGet" => {
                shape(args, 1, 2)?;
                let g = &self.groups[self.positioner(arg(0))?];
                Ok(vec![number(g.travel.0), number(g.travel.1)])
            }
            "PositionerUserTravelLimitsSet" => {
                shape(args, 3, 0)?;
                let i = self.positioner(arg(0))?;
                let (low, high) = (double(arg(1))?, double(arg(2))?);
                if low >= high {
                    return Err(OUT_OF_RANGE);
                }
                self.groups[i].travel = (low, high);
                Ok(vec![])
            }
            "PositionerSGammaParametersGet" => {
                shape(args, 1, 4)?;
                let g = &self.groups[self.positioner(arg(0))?];
                Ok([g.velocity, g.acceleration, g.jerk.0, g.jerk.1].map(number).to_vec())
            }
            "PositionerSGammaParametersSet" => {
                shape(args, 5, 0)?;
                let i = self.positioner(arg(0))?;
                let v: Vec<f64> = args[1..].iter().map(|a| double(a)).collect::<Result<_, _>>()?;
                let valid = v[0] > 0.0
                    && v[0] <= MAX_VELOCITY
                    && v[1] > 0.0
                    && v[1] <= MAX_ACCELERATION
                    && v[2] >= 0.001
                    && v[2] <= v[3];
                if !valid {
                    return Err(OUT_OF_RANGE);
                }
                let g = &mut self.groups[i];
                (g.velocity, g.acceleration, g.jerk) = (v[0], v[1], (v[2], v[3]));
                Ok(vec![])
            }
            "GroupReferencingActionExecute" => {
                shape(args, 4, 0)?;
                let i = self.positioner(arg(0))?;
                let parameter = double(arg(3))?;
                let g = &mut self.groups[i];
                if g.status != 64 {
                    return Err(NOT_ALLOWED);
                }
                let position = match (arg(1), arg(2)) {
                    ("SetPosition", "None") => parameter,
                    ("SetPositionToHomePreset", "None") => 0.0,
                    _ => return Err(OUT_OF_RANGE),
                };
                g.sim.set_position(position / Self::UNIT_PER_STEP);
                g.target = position;
                Ok(vec![])
            }
            _ => Err(UNKNOWN_COMMAND),
        }
    }

    /// A function of one group taking no other input.
    fn group_action(&mut self, name: &str, i: usize) -> Result<(), i32> {
        let g = &mut self.groups[i];
        let (allowed, next) = match name {
            "GroupKill" => {
                self.kill(i);
                return Ok(());
            }
            "GroupMoveAbort" => return g.abort(),
            "GroupInitialize" | "GroupInitializeWithEncoderCalibration" => (g.not_initialized(), 42),
            "GroupMotionEnable" => (g.disabled(), 13),
            "GroupMotionDisable" => (g.ready(), 20),
            "GroupJogModeEnable" => (g.ready(), 47),
            "GroupJogModeDisable" => (g.status == 47 && g.motion.is_none(), 15),
            "GroupReferencingStart" => (g.status == 42, 64),
            _ => (g.status == 64, 11),
        };
        if !allowed {
            return Err(NOT_ALLOWED);
        }
        if next == 47 {
            g.jog = (0.0, g.acceleration);
        }
        g.status = next;
        Ok(())
    }

    fn kill(&mut self, i: usize) {
        let g = &mut self.groups[i];
        g.status = 7;
        if let Some((connection, code)) = g.halt(ABORTED) {
            self.send(connection, code, &[]);
        }
    }
}

impl Emulator for XpsEmulator {
    fn name(&self) -> &'static str {
        "newport_xps"
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
        self.groups.get_mut(channel.checked_sub(1)?).map(|g| &mut g.sim)
    }

    /// A fatal following error: the group is disabled (or not initialised while homing), its
    /// motion call answered −25, bit 0x1 of PositionerErrorGet set until PositionerErrorRead.
    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(g) = channel.checked_sub(1).and_then(|i| self.groups.get_mut(i)) else { return false };
        let kind = g.motion.map(|m| m.kind);
        g.following_error = true;
        let held = g.halt(FOLLOWING_ERROR);
        g.status = match kind {
            Some(Kind::Move) => 22,
            Some(Kind::Jog) => 25,
            Some(Kind::Home) => 3,
            None if g.ready() || g.status == 47 => 21,
            None => g.status,
        };
        if let Some((connection, code)) = held {
            self.send(connection, code, &[]);
        }
        true
    }

    fn connections(&self) -> usize {
        SOCKETS
    }

    fn handle_input_on(&mut self, now: Instant, connection: Connection, bytes: &[u8]) {
        if connection >= SOCKETS {
            // No such socket: the XPS would have refused the connection.
            return;
        }
        self.advance(now);
        while self.sockets.len() <= connection {
            self.sockets.push(Socket::new());
        }
        let socket = &mut self.sockets[connection];
        let overflowed = socket.requests.overflowed();
        let requests = socket.requests.push(bytes);
        if socket.requests.overflowed() > overflowed {
            self.malformed += 1;
            self.send(connection, STRING_TOO_LONG, &[]);
        }
        for request in requests {
            let answer = match std::str::from_utf8(&request) {
                Ok(text) => self.request(connection, text.trim()),
                Err(_) => Some(Err(WRONG_FORMAT)),
            };
            match answer {
                Some(Ok(values)) => self.send(connection, 0, &values),
                Some(Err(code)) => {
                    let theirs = [BUSY_SOCKET, OUT_OF_RANGE, NOT_ALLOWED, TRAVEL_LIMITS, JOG_OUT_OF_RANGE, WRONG_LOGIN];
                    self.malformed += usize::from(!theirs.contains(&code) && code != FOLLOWING_ERROR);
                    self.send(connection, code, &[]);
                }
                None => {}
            }
            // A motion of no length ends at once, and its reply with it.
            self.settle();
        }
    }

    fn poll_transmit_on(&mut self) -> Option<(Connection, Vec<u8>)> {
        self.output.pop_front()
    }

    fn handle_closed(&mut self, connection: Connection) {
        for g in &mut self.groups {
            if let Some(motion) = g.motion.as_mut().filter(|m| m.holder == Some(connection)) {
                motion.holder = None;
            }
        }
        self.output.retain(|(c, _)| *c != connection);
        if let Some(socket) = self.sockets.get_mut(connection) {
            *socket = Socket::new();
        }
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.advance(now);
    }

    fn poll_timeout(&self) -> Option<Instant> {
        self.groups
            .iter()
            .filter(|g| g.motion.is_some_and(|m| m.holder.is_some()))
            .filter_map(|g| g.sim.next_event())
            .min()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage;
    use std::time::Duration;
    use zmotor_core::SimSetting;
    use zmotor_msgs::Value;

    fn at(ms: u64) -> Instant {
        Instant::ZERO + Duration::from_millis(ms)
    }

    fn xps() -> XpsEmulator {
        XpsEmulator::new(2, &stage())
    }

    /// Everything sent on `connection` so far, as text.
    fn drain(e: &mut XpsEmulator, connection: Connection) -> String {
        let mut text = String::new();
        let mut others = Vec::new();
        while let Some((c, bytes)) = e.poll_transmit_on() {
            if c == connection {
                text.push_str(&String::from_utf8(bytes).expect("ASCII"));
            } else {
                others.push((c, bytes));
            }
        }
        e.output.extend(others);
        text
    }

    fn say_on(e: &mut XpsEmulator, connection: Connection, ms: u64, request: &str) -> String {
        e.handle_input_on(at(ms), connection, request.as_bytes());
        drain(e, connection)
    }

    fn say(e: &mut XpsEmulator, ms: u64, request: &str) -> String {
        say_on(e, 0, ms, request)
    }

    fn status(e: &mut XpsEmulator, ms: u64, group: usize) -> String {
        say(e, ms, &format!("GroupStatusGet(GROUP{group},int *)"))
    }

    /// Initialised and homed, at 0.
    fn ready(e: &mut XpsEmulator, group: usize) {
        assert_eq!(say(e, 0, &format!("GroupInitialize(GROUP{group})")), "0,,EndOfAPI");
        assert_eq!(say_on(e, 9, 0, &format!("GroupHomeSearch(GROUP{group})")), "0,,EndOfAPI");
    }

    #[test]
    fn identification_login_errors_and_unknown_functions() {
        let mut e = xps();
        assert_eq!(say(&mut e, 0, "FirmwareVersionGet (char *)"), "0,XPS-C8 Firmware V2.6.x,EndOfAPI");
        assert_eq!(say(&mut e, 0, "Login(Administrator,Administrator)"), "0,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "Login(Administrator,guess)"), "-106,,EndOfAPI");
        assert_eq!(say(&mut e, 1500, "ElapsedTimeGet(double *)"), "0,1.5,EndOfAPI");
        assert_eq!(say(&mut e, 0, "ErrorStringGet(-17, char *)"), "0,Parameter out of range or incorrect,EndOfAPI");
        assert!(say(&mut e, 0, "ErrorListGet(char *)").contains(";-22 : Not allowed action;"));
        assert_eq!(e.malformed(), 0);
        assert_eq!(say(&mut e, 0, "GroupFly(GROUP1)"), "-4,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupStatusGet GROUP1)"), "-7,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupStatusGet(GROUP3,int *)"), "-19,,EndOfAPI", "two groups");
        assert_eq!(say(&mut e, 0, "PositionerErrorGet(GROUP1,int *)"), "-18,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "ErrorStringGet(x,char *)"), "-15,,EndOfAPI");
        assert_eq!(e.malformed(), 5);
        assert_eq!(e.name(), "newport_xps");
    }

    #[test]
    fn power_up_initialise_and_home_blocks_only_its_socket() {
        let mut e = xps();
        assert_eq!(status(&mut e, 0, 1), "0,0,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupStatusStringGet(0, char*)"), "0,Not initialized state,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupMoveAbsolute(GROUP1.POSITIONER,1)"), "-22,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupHomeSearch(GROUP1)"), "-22,,EndOfAPI", "not initialised");
        e.axis(1).unwrap().apply(SimSetting::Position, &Value::Float(30_000.0)).unwrap();
        assert_eq!(say(&mut e, 0, "GroupInitialize(GROUP1)"), "0,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupPositionCurrentGet(GROUP1,double *)"), "0,3,EndOfAPI");
        assert_eq!(status(&mut e, 0, 1), "0,42,EndOfAPI");
        assert_eq!(say_on(&mut e, 1, 0, "GroupHomeSearch(GROUP1)"), "", "held until homed");
        assert_eq!(status(&mut e, 10, 1), "0,43,EndOfAPI");
        let due = e.poll_timeout().expect("a reply is held");
        assert!(due > at(300) && due < at(1000), "{due:?}");
        e.handle_timeout(due);
        assert_eq!(drain(&mut e, 1), "0,,EndOfAPI");
        assert_eq!(status(&mut e, 1000, 1), "0,11,EndOfAPI");
        assert_eq!(say(&mut e, 1000, "GroupPositionCurrentGet(GROUP1.POSITIONER,double *)"), "0,0,EndOfAPI");
        assert_eq!(e.poll_timeout(), None);
    }

    #[test]
    fn a_move_holds_its_reply_and_a_second_motion_call_there_is_busy() {
        let mut e = xps();
        ready(&mut e, 1);
        assert_eq!(say_on(&mut e, 1, 0, "GroupMoveAbsolute(GROUP1.POSITIONER,5)"), "");
        assert_eq!(say_on(&mut e, 1, 100, "GroupMoveRelative(GROUP1,1)"), "-1,,EndOfAPI");
        assert_eq!(say_on(&mut e, 1, 100, "GroupStatusGet(GROUP1,int *)"), "0,44,EndOfAPI", "served");
        let velocity = say(&mut e, 100, "GroupVelocityCurrentGet(GROUP1.POSITIONER,double *)");
        assert_eq!(velocity, "0,4,EndOfAPI", "accelerating at 40 mm/s²");
        assert_eq!(say(&mut e, 100, "GroupPositionTargetGet(GROUP1,double *)"), "0,5,EndOfAPI");
        assert_eq!(say(&mut e, 100, "GroupAccelerationCurrentGet(GROUP1,double *)"), "0,40,EndOfAPI");
        e.handle_timeout(at(2000));
        assert_eq!(drain(&mut e, 1), "0,,EndOfAPI");
        assert_eq!(status(&mut e, 2000, 1), "0,12,EndOfAPI");
        assert_eq!(say(&mut e, 2000, "GroupStatusStringGet(12, char*)"), "0,Ready state from motion,EndOfAPI");
        assert_eq!(say(&mut e, 2000, "GroupPositionSetpointGet(GROUP1,double *)"), "0,5,EndOfAPI");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn abort_from_another_socket_answers_the_held_move_with_27() {
        let mut e = xps();
        ready(&mut e, 2);
        assert_eq!(say_on(&mut e, 3, 0, "GroupMoveRelative (GROUP2.POSITIONER,-15)"), "");
        assert_eq!(say(&mut e, 500, "GroupMoveAbort(GROUP2)"), "0,,EndOfAPI");
        assert_eq!(drain(&mut e, 3), "", "still decelerating");
        e.handle_timeout(e.poll_timeout().expect("held"));
        assert_eq!(drain(&mut e, 3), "-27,,EndOfAPI");
        assert_eq!(status(&mut e, 1000, 2), "0,10,EndOfAPI");
        assert_eq!(say(&mut e, 1000, "GroupMoveAbort(GROUP2)"), "-22,,EndOfAPI", "nothing to abort");
        assert_eq!(say_on(&mut e, 3, 1000, "GroupMoveAbsolute(GROUP2,0)"), "");
        assert_eq!(say(&mut e, 1100, "GroupKill(GROUP2)"), "0,,EndOfAPI");
        assert_eq!(drain(&mut e, 3), "-27,,EndOfAPI", "killed");
        assert_eq!(status(&mut e, 1100, 2), "0,7,EndOfAPI");
    }

    #[test]
    fn a_jog_runs_until_its_velocity_is_zero() {
        let mut e = xps();
        ready(&mut e, 1);
        assert_eq!(say_on(&mut e, 1, 0, "GroupJogParametersSet(GROUP1.POSITIONER,2,20)"), "-22,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupJogModeEnable(GROUP1)"), "0,,EndOfAPI");
        assert_eq!(say_on(&mut e, 1, 0, "GroupJogParametersSet(GROUP1.POSITIONER,-2,20)"), "0,,EndOfAPI");
        assert_eq!(say_on(&mut e, 1, 0, "GroupJogParametersSet(GROUP1.POSITIONER,11,20)"), "-42,,EndOfAPI");
        assert_eq!(say(&mut e, 1000, "GroupJogCurrentGet(GROUP1,double *,double *)"), "0,-2,0,EndOfAPI");
        assert_eq!(say(&mut e, 1000, "GroupJogParametersGet(GROUP1,double *,double *)"), "0,-2,20,EndOfAPI");
        assert_eq!(say(&mut e, 1000, "GroupPositionCurrentGet(GROUP1,double *)"), "0,-1.9,EndOfAPI");
        assert_eq!(say_on(&mut e, 1, 1000, "GroupJogParametersSet(GROUP1.POSITIONER,0,20)"), "0,,EndOfAPI");
        assert_eq!(say(&mut e, 1050, "GroupJogModeDisable(GROUP1)"), "-22,,EndOfAPI", "still moving");
        assert_eq!(status(&mut e, 2000, 1), "0,47,EndOfAPI");
        assert_eq!(say(&mut e, 2000, "GroupJogModeDisable(GROUP1)"), "0,,EndOfAPI");
        assert_eq!(status(&mut e, 2000, 1), "0,15,EndOfAPI");
    }

    #[test]
    fn travel_limits_and_end_of_run_switches() {
        let mut e = xps();
        ready(&mut e, 1);
        let limits = say(&mut e, 0, "PositionerUserTravelLimitsGet(GROUP1.POSITIONER,double *,double *)");
        assert_eq!(limits, "0,-19.9,19.9,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupMoveAbsolute(GROUP1,20)"), "-35,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "PositionerUserTravelLimitsSet(GROUP1.POSITIONER,-1,-2)"), "-17,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "PositionerUserTravelLimitsSet(GROUP1.POSITIONER,-1,1)"), "0,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupMoveRelative(GROUP1,1.5)"), "-35,,EndOfAPI");
        let hardware = say(&mut e, 0, "PositionerHardwareStatusGet(GROUP1.POSITIONER,int *)");
        assert_eq!(hardware, "0,4194308,EndOfAPI", "powered, ZM high on the switch");
        let text = say(&mut e, 0, "PositionerHardwareStatusStringGet(4194308,char *)");
        assert_eq!(text, "0,First driver powered on - ZM high level,EndOfAPI");
        e.axis(1).unwrap().apply(SimSetting::Position, &Value::Float(200_000.0)).unwrap();
        assert_eq!(say(&mut e, 0, "PositionerErrorGet(GROUP1.POSITIONER,int *)"), "0,512,EndOfAPI");
        assert_eq!(say(&mut e, 0, "PositionerHardwareStatusGet(GROUP1.POSITIONER,int *)"), "0,4194820,EndOfAPI");
        assert_eq!(say(&mut e, 0, "PositionerErrorStringGet(512,char *)"), "0,Plus end of run activated,EndOfAPI");
        assert_eq!(say(&mut e, 0, "PositionerErrorStringGet(0,char *)"), "0,,EndOfAPI");
        e.axis(1).unwrap().apply(SimSetting::Position, &Value::Float(-190_000.0)).unwrap();
        e.axis(1).unwrap().apply(SimSetting::LowLimit, &Value::Float(-195_000.0)).unwrap();
        assert_eq!(say(&mut e, 0, "PositionerUserTravelLimitsSet(GROUP1.POSITIONER,-19.9,19.9)"), "0,,EndOfAPI");
        assert_eq!(say_on(&mut e, 1, 0, "GroupMoveAbsolute(GROUP1,-19.8)"), "");
        e.handle_timeout(at(3000));
        assert_eq!(drain(&mut e, 1), "-5,,EndOfAPI", "stopped by the minus end of run");
        assert_eq!(status(&mut e, 3000, 1), "0,8,EndOfAPI");
        assert_eq!(say(&mut e, 3000, "PositionerErrorGet(GROUP1.POSITIONER,int *)"), "0,256,EndOfAPI");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_following_error_is_reported_until_read() {
        let mut e = xps();
        ready(&mut e, 1);
        assert!(!e.raise_error(0) && !e.raise_error(3));
        assert_eq!(say_on(&mut e, 1, 0, "GroupMoveAbsolute(GROUP1,3)"), "");
        assert!(e.raise_error(1));
        assert_eq!(drain(&mut e, 1), "-25,,EndOfAPI");
        assert_eq!(status(&mut e, 100, 1), "0,22,EndOfAPI");
        assert_eq!(say(&mut e, 100, "PositionerErrorGet(GROUP1.POSITIONER,int *)"), "0,1,EndOfAPI");
        assert_eq!(say(&mut e, 100, "PositionerErrorRead(GROUP1.POSITIONER,int *)"), "0,1,EndOfAPI");
        assert_eq!(say(&mut e, 100, "PositionerErrorGet(GROUP1.POSITIONER,int *)"), "0,0,EndOfAPI");
        assert_eq!(say(&mut e, 100, "GroupMoveAbsolute(GROUP1,0)"), "-22,,EndOfAPI", "disabled");
        assert_eq!(say(&mut e, 100, "GroupMotionEnable(GROUP1)"), "0,,EndOfAPI");
        assert_eq!(status(&mut e, 100, 1), "0,13,EndOfAPI");
        assert_eq!(say(&mut e, 100, "GroupMotionDisable(GROUP1)"), "0,,EndOfAPI");
        assert_eq!(status(&mut e, 100, 1), "0,20,EndOfAPI");
    }

    #[test]
    fn referencing_sets_a_position_as_epics_does() {
        let mut e = xps();
        assert_eq!(say(&mut e, 0, "GroupKill(GROUP2)"), "0,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupInitialize(GROUP2)"), "0,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupReferencingStop(GROUP2)"), "-22,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupReferencingStart(GROUP2)"), "0,,EndOfAPI");
        assert_eq!(status(&mut e, 0, 2), "0,64,EndOfAPI");
        let set = "GroupReferencingActionExecute(GROUP2.POSITIONER,SetPosition,None,7.25)";
        assert_eq!(say(&mut e, 0, set), "0,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupReferencingStop(GROUP2)"), "0,,EndOfAPI");
        assert_eq!(status(&mut e, 0, 2), "0,11,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupPositionCurrentGet(GROUP2,double *)"), "0,7.25,EndOfAPI");
        assert_eq!(e.axis(2).unwrap().physical_position(), 0.0, "nothing moved");
    }

    #[test]
    fn sgamma_parameters_shape_the_motion_and_are_range_checked() {
        let mut e = xps();
        let get = "PositionerSGammaParametersGet(GROUP1.POSITIONER,double *,double *,double *,double *)";
        assert_eq!(say(&mut e, 0, get), "0,10,40,0.005,0.05,EndOfAPI");
        assert_eq!(
            say(&mut e, 0, "PositionerSGammaParametersSet(GROUP1.POSITIONER,11,40,0.005,0.05)"),
            "-17,,EndOfAPI"
        );
        assert_eq!(say(&mut e, 0, "PositionerSGammaParametersSet(GROUP1.POSITIONER,2.5,10,0.01,0.1)"), "0,,EndOfAPI");
        assert_eq!(say(&mut e, 0, get), "0,2.5,10,0.01,0.1,EndOfAPI");
        let max = "PositionerMaximumVelocityAndAccelerationGet(GROUP1.POSITIONER,double *,double *)";
        assert_eq!(say(&mut e, 0, max), "0,10,40,EndOfAPI");
        assert_eq!(say(&mut e, 0, "PositionerSGammaParametersSet(GROUP1.POSITIONER,1,x,0.01,0.1)"), "-14,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupPositionCurrentGet(GROUP1,double *,double *)"), "-9,,EndOfAPI");
        assert_eq!(say(&mut e, 0, "GroupMoveAbsolute(GROUP1,1,2)"), "-9,,EndOfAPI");
        assert_eq!(e.malformed(), 3);
    }

    #[test]
    fn requests_come_in_pieces_and_floods_are_refused() {
        let mut e = xps();
        assert_eq!(say(&mut e, 0, "GroupStatus"), "");
        assert_eq!(say(&mut e, 0, "Get(GROUP1,int *"), "");
        assert_eq!(say(&mut e, 0, ")GroupStatusGet(GROUP2,int *)"), "0,0,EndOfAPI0,0,EndOfAPI");
        assert_eq!(say(&mut e, 0, &"x".repeat(1100)), "-3,,EndOfAPI");
        assert_eq!(e.malformed(), 1);
        assert_eq!(say(&mut e, 0, "\r\nControllerStatusGet(int *)"), "0,0,EndOfAPI");
    }

    #[test]
    fn a_closed_socket_drops_its_held_reply_and_the_group_moves_on() {
        let mut e = xps();
        ready(&mut e, 1);
        assert_eq!(say_on(&mut e, 4, 0, "GroupMoveAbsolute(GROUP1,2)"), "");
        e.handle_input_on(at(0), 4, b"GroupStat");
        e.handle_closed(4);
        assert_eq!(e.poll_timeout(), None, "no reply held");
        assert_eq!(say_on(&mut e, 4, 2000, "usGet(GROUP1,int *)"), "-4,,EndOfAPI", "a fresh buffer");
        assert_eq!(status(&mut e, 2000, 1), "0,12,EndOfAPI");
        assert_eq!(e.connections(), 100);
        e.handle_input(at(2000), b"GroupStatusGet(GROUP1,int *)");
        assert_eq!(e.poll_transmit(), Some(b"0,12,EndOfAPI".to_vec()));
    }
}
