//! PI GCS 2 (Physik Instrumente's General Command Set, version 2) on the motor controllers of
//! the C-863 Mercury / C-884 class (also C-663, C-867, E-861, E-871, E-873), as the EPICS driver
//! motorPIGCS2 drives them, with the departures listed below.
//!
//! **Wire.** ASCII over TCP (port 50000) or a serial line (115200 8N1), every command line
//! ended by LF. An axis is named by text; channel N is GCS axis `"N"` (axes are numbered from
//! 1, so channel 0 has no axis). Setters (`MOV`, `MVR`, `VEL`, `ACC`, `DEC`, `SVO`, `RON`,
//! `POS`, `SPA`, `HLT`, `FRF`, `FNL`, `FPL`) are silent: the controller answers nothing, keeps
//! the code of the last error, and `ERR?` reads and clears it. So every setter is followed by
//! `ERR?`; a code other than 0 is a `ReplyEvent::ControllerError` with PI's meaning of the code
//! (`error_meaning`), e.g. 7 "Position out of limits". Queries answer `<axis>=<value>`
//! (`SPA?` and `SRG?` answer `<axis> <id>=<value>`); a reply of several lines ends every line
//! but the last with a space before the LF, so `frame` returns one whole reply, whatever its
//! lines. A query the controller does not know is not answered at all (the layer's timeout).
//!
//! **Units.** Positions on the wire are the stage's physical units (mm or deg), velocities
//! units/s, accelerations units/s². A record step is `units_per_step` units:
//! `ProtocolOptions::units_per_step` when given, else read from the controller at every
//! connection as EPICS does: counts per unit = `SPA? <ax> 14` / `SPA? <ax> 15`, one step =
//! one count, so units per step = den/num (a C-884 with 10000/1 counts one step per 0.1 µm).
//! Before they are read, EPICS's 1000 counts per unit (`DEFAULT_UNITS_PER_STEP`). Targets are
//! rounded to whole steps, then sent in units with at least six decimals (EPICS's `%f`) and as
//! many more as one step needs; a target beyond 32-bit steps is refused (`OutOfRange`), never
//! clamped. Positions read back are rounded to whole steps.
//!
//! **Connection.** `*IDN?` (one of the motor-class models above, else the reply is refused and
//! the link does not come up), `SAI?` (every channel must be one of its axes), then per channel
//! `TRS?` (reference switch), `LIM?` (limit switches), `SPA? 14`/`SPA? 15` (unless the units
//! are given), `TMN?`/`TMX?` (the travel range, a jog's targets). At the first connection only,
//! `SVO <ax> 1 …` for every channel then `ERR?`: EPICS switches servo on at start-up. A
//! reconnection leaves the servo as it finds it, so a servo that dropped while the link was
//! down (a motion error, a controller restarted) shows as PROBLEM instead of being switched on
//! again behind the user's back. Nothing at connection moves an axis: referencing is only ever
//! started by a record's home.
//!
//! **Poll**, per channel: `SRG? <ax> 1` (the status register), `POS? <ax>`, `FRF? <ax>`
//! (referenced); then, once per poll, `ERR?`, so that an error no command asked about (a motion
//! error that switched the servo off) is reported when it happens; not under `observe`, where
//! reading the error would clear it before the IOC beside reads it. The EPICS driver reads the
//! same register with the single byte `#4`, cutting four hex digits per axis out of its reply;
//! that multi-axis layout is not documented by PI, while `SRG?` (documented as identical to
//! `#4`) names its axis, so a reply for another axis is caught. It reads `FRF?` only when a
//! referencing ends; reading it every poll costs what EPICS's second `POS?` costs.
//!
//! **Commands.**
//! - Move: `VEL <ax> <v>`, `ACC <ax> <a>`, `DEC <ax> <a>` (each skipped when the record's value
//!   is 0, as EPICS does), then `MOV <ax> <target>`, or `MVR <ax> <distance>` for a relative
//!   move (EPICS ignores the relative flag), each followed by `ERR?`. EPICS writes the
//!   acceleration as parameters 0xB/0xC; `ACC`/`DEC` are the same settings.
//! - Jog: GCS 2 has no constant-velocity motion on these controllers, so, as EPICS does, a move
//!   at the jog velocity to the end of the travel range read at connection (`TMX?` forwards,
//!   `TMN?` backwards), ended by a stop.
//! - Home: `SPA <ax> 0x50 <v>` (the reference move velocity, when the record's is not 0), then
//!   `SVO <ax> 1`, then `FRF <ax>` on an axis with a reference switch (forward and reverse
//!   alike: the controller finds its side of the switch), else `FPL` forward / `FNL` reverse on
//!   an axis with limit switches (referencing at the switch), each followed by `ERR?`. An axis
//!   with neither is refused (`Unsupported`).
//! - Stop: `HLT <ax>` then `ERR?`, which answers 10 ("controller was stopped by command"):
//!   expected, not a problem.
//! - Set position: `RON <ax> 0`, `POS <ax> <p>`, `RON <ax> 1` (the controller takes `POS` only
//!   with reference mode off), each followed by `ERR?`. The controller then counts the axis as
//!   referenced (HOMED).
//! - Enable: `SVO <ax> 1|0` then `ERR?`.
//! - Raw text: a query (with `?`) is sent and its reply, whatever it is, taken; anything else is
//!   sent as a setter and followed by `ERR?`. Text of several lines is refused.
//! - Soft limits, encoder ratio, gains: nothing is sent (EPICS sends none: the controller keeps
//!   its own travel range, its encoder is its own, and its PID terms are not the record's
//!   fractions).
//!
//! **Status** from the status register: DONE when neither "in motion" (bit 13) nor "is
//! referencing" (bit 14), else MOVING; PLUS_LS bit 2, MINUS_LS bit 0; POSITION (closed loop)
//! bit 12 (servo on); HOMED from `FRF?`; GAIN_SUPPORT always (the record's CNEN switches the
//! servo); DIRECTION the way of the last motion commanded (as EPICS); PROBLEM latched, as EPICS
//! does, when the servo went off without a request (a motion error), until the servo is
//! switched on again by enable or home. HOME is never set: the reference switch signal
//! (bit 1) tells which side of the switch the stage is on, not that it is on it. No encoder
//! (PRESENT) is reported: `POS?` is the closed-loop position the record reads as both.
//!
//! **Left out.** `#4`/`#5`/`#7`/`#24` (the emulator answers them), `STP` (it stops every
//! axis), deferred multi-axis moves, daisy-chain addressing, `HAR?` hard stops (a controller
//! without `HAR?` would not answer it), macros, joystick, data recording, wave generator.

use crate::protocol::{
    line_text, whole_steps, CommandError, Finding, Frame, Protocol, ProtocolOptions, Purpose, ReplyError, ReplyEvent,
    Request, VendorError,
};
use crate::scale::{ControllerUnit, Scale, ScaleSource};
use std::collections::BTreeMap;
use zmotor_core::DeviceStatus;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;
use zmotor_msgs::Unit;

/// The protocol's name in launch files.
pub(crate) const NAME: &str = "pi_gcs2";

/// The line terminator, both ways.
pub(crate) const TERMINATOR: &[u8] = b"\n";

/// Units per step before the controller's counts per unit are read (EPICS: 1000 counts per
/// unit).
pub(crate) const DEFAULT_UNITS_PER_STEP: f64 = 0.001;

/// The error code `HLT` leaves: the controller was stopped by command.
pub(crate) const STOPPED_BY_COMMAND: i64 = 10;

/// The models, as `*IDN?` names them, that speak GCS 2 the way this module drives it.
pub(crate) const MODELS: [&str; 7] = ["C-663", "C-863", "C-867", "C-884", "E-861", "E-871", "E-873"];

/// Bits of an axis's status register (`SRG? <ax> 1`, `#4`).
// The whole register, as the manual defines it: a reference of what a reply may carry, the bits
// the driver does not read included.
#[allow(dead_code)]
pub(crate) mod register {
    /// The negative limit switch is active.
    pub(crate) const NEGATIVE_LIMIT: u16 = 1 << 0;
    /// The reference switch signal is high (the stage is on its positive side).
    pub(crate) const REFERENCE_SIGNAL: u16 = 1 << 1;
    /// The positive limit switch is active.
    pub(crate) const POSITIVE_LIMIT: u16 = 1 << 2;
    /// An error occurred.
    pub(crate) const ERROR: u16 = 1 << 8;
    /// Servo (closed loop) on.
    pub(crate) const SERVO_ON: u16 = 1 << 12;
    /// In motion.
    pub(crate) const IN_MOTION: u16 = 1 << 13;
    /// A referencing (FRF, FNL, FPL) is running.
    pub(crate) const REFERENCING: u16 = 1 << 14;
    /// On target.
    pub(crate) const ON_TARGET: u16 = 1 << 15;
}

/// Parameter IDs (`SPA`, `SPA?`).
pub(crate) mod parameter {
    /// Counts per unit, numerator.
    pub(crate) const COUNTS_PER_UNIT_NUMERATOR: u32 = 0x0E;
    /// Counts per unit, denominator.
    pub(crate) const COUNTS_PER_UNIT_DENOMINATOR: u32 = 0x0F;
    /// Velocity of the reference move, units/s.
    pub(crate) const REFERENCE_VELOCITY: u32 = 0x50;
}

/// PI's meaning of a controller error code (the codes of the C-863/C-884 class and the GCS
/// codes a driver meets).
pub(crate) fn error_meaning(code: i64) -> &'static str {
    match code {
        0 => "No error",
        1 => "Parameter syntax error",
        2 => "Unknown command",
        3 => "Command length out of limits or command buffer overrun",
        4 => "Error while scanning",
        5 => "Unallowable move attempted on unreferenced axis, or move attempted with servo off",
        7 => "Position out of limits",
        8 => "Velocity out of limits",
        10 => "Controller was stopped by command",
        15 => "Invalid axis identifier",
        17 => "Parameter out of range",
        22 => "Axis identifier specified more than once",
        23 => "Illegal axis",
        24 => "Incorrect number of parameters",
        25 => "Invalid floating point number",
        26 => "Parameter missing",
        27 => "Soft limit out of range",
        31 => "Axis has no reference sensor",
        32 => "Axis has no limit switch",
        34 => "Command not allowed for selected stage(s)",
        45 => "Referencing failed",
        49 => "Move to limit switch failed",
        50 => "Attempt to reference axis with referencing disabled",
        53 => "Command not allowed while the affected axis is in motion",
        54 => "Unknown parameter",
        60 => "Protected parameter: current command level (CCL) too low",
        64 => "Parameter is read-only",
        76 => "Interface buffer did overrun and command couldn't be received correctly",
        84 => "Motor is off",
        88 => "Move without referenced stage",
        89 => "Command not allowed in current motion mode",
        93 => "Command not allowed while the affected axis or its master is in motion",
        95 => "Parameter cannot be changed in current servo mode",
        200 => "No stage connected to axis",
        214 => "Position calculations failed",
        215 => "The connection between controller and stage may be broken",
        216 => "The connected stage has driven into a limit switch",
        301 => "Send buffer overflow",
        304 => "Received command is too long",
        500 => "Emergency stop button was activated",
        504 => "Following error (motion error)",
        555 => "Unknown error",
        1024 => "Motion error: position error too large, servo is switched off automatically",
        _ => "An error code this driver does not know (see the controller's manual)",
    }
}

/// A request of GCS 2.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Step {
    /// `*IDN?` at initialisation: is it a controller of the class?
    Identity,
    /// `SAI?` at initialisation: the controller's axes.
    Axes,
    /// A setting of one axis, read at initialisation.
    Setting {
        /// The axis.
        channel: usize,
        /// Which setting.
        setting: Setting,
    },
    /// `SVO` of every axis at the first connection: silent.
    ServoStart,
    /// `ERR?` after `SVO` at the first connection.
    ServoStarted,
    /// One reading of a channel's poll.
    Read {
        /// The channel polled.
        channel: usize,
        /// Which reading.
        reading: Reading,
    },
    /// `ERR?` at the end of a poll: the controller's error register, of no axis.
    PollErrors,
    /// A setter of a command: silent.
    Setter {
        /// The axis commanded.
        channel: usize,
    },
    /// `ERR?` after a setter.
    ErrorCheck {
        /// The axis commanded.
        channel: usize,
    },
    /// `ERR?` after `HLT`: the stop asked for is no error.
    StopCheck {
        /// The axis stopped.
        channel: usize,
    },
    /// Raw text with a `?`: its reply is the user's to read.
    RawQuery {
        /// The axis it goes with.
        channel: usize,
    },
}

/// A setting of an axis read at initialisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Setting {
    /// `TRS?`: whether it has a reference switch.
    HasReference,
    /// `LIM?`: whether it has limit switches.
    HasLimitSwitches,
    /// `SPA? <axis> 14`: the numerator of its counts per unit.
    CountsNumerator,
    /// `SPA? <axis> 15`: the denominator of its counts per unit.
    CountsDenominator,
    /// `TMN?`: the low end of its travel.
    TravelMin,
    /// `TMX?`: the high end of its travel.
    TravelMax,
}

/// The readings of a channel's poll, in the order they are asked for: the last completes it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Reading {
    /// `SRG? <axis> 1`: the status register.
    StatusRegister,
    /// `POS?`: the position.
    Position,
    /// `FRF?`: whether it is referenced.
    Referenced,
}

/// What the protocol knows of one axis.
#[derive(Clone, Debug)]
struct Axis {
    counts_numerator: Option<f64>,
    counts_denominator: Option<f64>,
    has_reference: bool,
    has_limit_switches: bool,
    travel_min: Option<f64>,
    travel_max: Option<f64>,
    /// The last poll's status register and position (steps).
    register: u16,
    position: f64,
    /// The way of the last motion commanded.
    direction_up: bool,
    /// The servo was on at the last poll.
    servo_was_on: bool,
    /// The servo was switched off on request (enable off) and not switched on since.
    servo_off_requested: bool,
    /// The servo went off without a request: PROBLEM until it is switched on again.
    servo_dropped: bool,
}

impl Default for Axis {
    fn default() -> Self {
        Self {
            counts_numerator: None,
            counts_denominator: None,
            // Unknown until read: FRF is what a controller with a reference switch takes.
            has_reference: true,
            has_limit_switches: false,
            travel_min: None,
            travel_max: None,
            register: 0,
            position: 0.0,
            direction_up: true,
            servo_was_on: false,
            servo_off_requested: false,
            servo_dropped: false,
        }
    }
}

/// The GCS 2 protocol (see the module documentation).
#[derive(Debug, Default)]
pub(crate) struct PiGcs2 {
    /// Units per step given by the installation, for every channel.
    units_per_step: Option<f64>,
    /// The channels of the connection being initialised.
    channels: Vec<usize>,
    axes: BTreeMap<usize, Axis>,
    /// Servo was switched on at a first connection: reconnections leave it alone.
    servo_started: bool,
    /// Observed beside an IOC: polls leave `ERR?`, which clears the error, to the IOC.
    observed: bool,
}

impl PiGcs2 {
    /// A protocol with nothing read yet; `options.units_per_step`, when given (finite and
    /// positive), replaces the counts per unit read from the controller.
    pub(crate) fn new(options: &ProtocolOptions) -> Self {
        let units_per_step = options.units_per_step.filter(|u| u.is_finite() && *u > 0.0);
        if units_per_step.is_none() && options.units_per_step.is_some() {
            tracing::warn!(
                given = ?options.units_per_step,
                "pi_gcs2: units per step must be finite and positive; reading the controller's instead"
            );
        }
        Self { units_per_step, ..Self::default() }
    }

    fn axis(&mut self, channel: usize) -> &mut Axis {
        self.axes.entry(channel).or_default()
    }

    /// Controller units per record step on `channel`.
    fn units_per_step(&self, channel: usize) -> f64 {
        if let Some(given) = self.units_per_step {
            return given;
        }
        let axis = self.axes.get(&channel);
        match axis.and_then(|a| a.counts_numerator.zip(a.counts_denominator)) {
            Some((numerator, denominator)) => denominator / numerator,
            None => DEFAULT_UNITS_PER_STEP,
        }
    }

    /// `value` (controller units) as the controller reads it: six decimals at least, as
    /// many as one step of `channel` needs.
    fn units_text(&self, channel: usize, value: f64) -> String {
        let needed = (-self.units_per_step(channel).log10()).ceil();
        let decimals = if needed.is_finite() { (needed as usize + 1).clamp(6, 15) } else { 6 };
        // No "-0.000000".
        let value = if value == 0.0 { 0.0 } else { value };
        format!("{value:.decimals$}")
    }

    /// A velocity or acceleration of the record (steps/s, steps/s²) in controller units, as
    /// text; None when it is 0 (the controller's own setting is kept, as EPICS does).
    fn rate_text(&self, channel: usize, what: &'static str, steps: f64) -> Result<Option<String>, CommandError> {
        let units = steps.abs() * self.units_per_step(channel);
        if !units.is_finite() {
            return Err(CommandError::OutOfRange { what, value: steps });
        }
        Ok((units != 0.0).then(|| self.units_text(channel, units)))
    }

    /// A position of the record (steps) in controller units, as text.
    fn position_text(&self, channel: usize, what: &'static str, steps: f64) -> Result<String, CommandError> {
        let whole = whole_steps(what, steps)?;
        Ok(self.units_text(channel, f64::from(whole) * self.units_per_step(channel)))
    }

    /// Velocity and acceleration, as every motion sets them first.
    fn dynamics(&self, channel: usize, velocity: f64, acceleration: f64) -> Result<Vec<Request<Step>>, CommandError> {
        let mut requests = Vec::new();
        if let Some(v) = self.rate_text(channel, "velocity", velocity)? {
            requests.extend(checked(channel, format!("VEL {channel} {v}")));
        }
        if let Some(a) = self.rate_text(channel, "acceleration", acceleration)? {
            requests.extend(checked(channel, format!("ACC {channel} {a}")));
            requests.extend(checked(channel, format!("DEC {channel} {a}")));
        }
        Ok(requests)
    }

    fn status_of(&mut self, channel: usize, referenced: bool) -> DeviceStatus {
        let axis = self.axis(channel);
        let register = axis.register;
        let mut bits = msta::GAIN_SUPPORT;
        let busy = register & (register::IN_MOTION | register::REFERENCING) != 0;
        bits |= if busy { msta::MOVING } else { msta::DONE };
        for (bit, on) in [
            (msta::PLUS_LS, register & register::POSITIVE_LIMIT != 0),
            (msta::MINUS_LS, register & register::NEGATIVE_LIMIT != 0),
            (msta::POSITION, register & register::SERVO_ON != 0),
            (msta::HOMED, referenced),
            (msta::DIRECTION, axis.direction_up),
            (msta::PROBLEM, axis.servo_dropped),
        ] {
            if on {
                bits |= bit;
            }
        }
        DeviceStatus {
            position: axis.position,
            encoder_position: axis.position,
            velocity: 0.0,
            msta: bits,
            readback: None,
        }
    }

    /// An axis's setting read at initialisation.
    fn on_setting(
        &mut self,
        request: &Request<Step>,
        frame: &[u8],
        channel: usize,
        setting: Setting,
    ) -> Result<(), ReplyError> {
        let text = reply_text(frame);
        match setting {
            Setting::HasReference => self.axis(channel).has_reference = flag(request, frame, &text, channel)?,
            Setting::HasLimitSwitches => self.axis(channel).has_limit_switches = flag(request, frame, &text, channel)?,
            Setting::CountsNumerator | Setting::CountsDenominator => {
                let numerator = setting == Setting::CountsNumerator;
                let id = if numerator {
                    parameter::COUNTS_PER_UNIT_NUMERATOR
                } else {
                    parameter::COUNTS_PER_UNIT_DENOMINATOR
                };
                let value = parameter_value(request, frame, &text, channel, id)?;
                let counts: f64 = value.trim().parse().map_err(|_| ReplyError::new(request, frame, "not a number"))?;
                if !(counts.is_finite() && counts > 0.0) {
                    return Err(ReplyError::new(request, frame, "counts per unit must be positive"));
                }
                let axis = self.axis(channel);
                if numerator {
                    axis.counts_numerator = Some(counts);
                } else {
                    axis.counts_denominator = Some(counts);
                }
            }
            Setting::TravelMin | Setting::TravelMax => {
                let limit = number(request, frame, axis_value(request, frame, &text, channel)?)?;
                let axis = self.axis(channel);
                if setting == Setting::TravelMin {
                    axis.travel_min = Some(limit);
                } else {
                    axis.travel_max = Some(limit);
                }
            }
        }
        Ok(())
    }

    fn on_reading(
        &mut self,
        request: &Request<Step>,
        frame: &[u8],
        channel: usize,
        reading: Reading,
    ) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let text = reply_text(frame);
        match reading {
            Reading::StatusRegister => {
                let value = register_value(request, frame, &text, channel)?;
                let register = parse_hex(value).ok_or_else(|| ReplyError::new(request, frame, "not a hex register"))?;
                let axis = self.axis(channel);
                let servo_on = register & register::SERVO_ON != 0;
                if axis.servo_was_on && !servo_on && !axis.servo_off_requested {
                    // Off without a request: a motion error (EPICS raises PROBLEM the same way).
                    axis.servo_dropped = true;
                }
                axis.servo_was_on = servo_on;
                axis.register = register;
            }
            Reading::Position => {
                let units = number(request, frame, axis_value(request, frame, &text, channel)?)?;
                let steps = (units / self.units_per_step(channel)).round();
                if !steps.is_finite() {
                    return Err(ReplyError::new(request, frame, "a position beyond any step count"));
                }
                self.axis(channel).position = steps;
            }
            Reading::Referenced => {
                let referenced = flag(request, frame, &text, channel)?;
                return Ok(vec![ReplyEvent::Status { channel, status: self.status_of(channel, referenced) }]);
            }
        }
        Ok(Vec::new())
    }
}

/// A setter of `channel`, then the error query that tells whether it was taken.
fn checked(channel: usize, line: String) -> [Request<Step>; 2] {
    [
        Request::silent(format!("{line}\n"), Step::Setter { channel }),
        Request::query("ERR?\n", Step::ErrorCheck { channel }),
    ]
}

/// A reply's text: its lines without the continuation spaces and the last LF.
fn reply_text(frame: &[u8]) -> String {
    line_text(frame, TERMINATOR).split('\n').map(str::trim_end).collect::<Vec<_>>().join("\n")
}

/// The value of a one-line reply `<key>=<value>` whose key, split at spaces, is `key`.
fn keyed_value<'a>(
    request: &Request<Step>,
    frame: &[u8],
    text: &'a str,
    key_matches: impl Fn(&[&str]) -> bool,
) -> Result<&'a str, ReplyError> {
    if text.contains('\n') {
        return Err(ReplyError::new(request, frame, "several lines where one was asked for"));
    }
    let (key, value) = text.split_once('=').ok_or_else(|| ReplyError::new(request, frame, "no '='"))?;
    let key: Vec<&str> = key.split_whitespace().collect();
    if !key_matches(&key) {
        return Err(ReplyError::new(request, frame, "the reply of another axis or item"));
    }
    Ok(value.trim())
}

/// The value of `<axis>=<value>` for `channel`.
fn axis_value<'a>(request: &Request<Step>, frame: &[u8], text: &'a str, channel: usize) -> Result<&'a str, ReplyError> {
    let name = channel.to_string();
    keyed_value(request, frame, text, |key| key == [name.as_str()])
}

/// The value of `<axis> 1=<register>` for `channel`.
fn register_value<'a>(
    request: &Request<Step>,
    frame: &[u8],
    text: &'a str,
    channel: usize,
) -> Result<&'a str, ReplyError> {
    let name = channel.to_string();
    keyed_value(request, frame, text, |key| key.len() == 2 && key[0] == name && parse_id(key[1]) == Some(1))
}

/// The value of `<axis> <parameter>=<value>` for `channel` (the ID echoed in decimal or hex).
fn parameter_value<'a>(
    request: &Request<Step>,
    frame: &[u8],
    text: &'a str,
    channel: usize,
    id: u32,
) -> Result<&'a str, ReplyError> {
    let name = channel.to_string();
    keyed_value(request, frame, text, |key| key.len() == 2 && key[0] == name && parse_id(key[1]) == Some(id))
}

/// A 0/1 answer for `channel`.
fn flag(request: &Request<Step>, frame: &[u8], text: &str, channel: usize) -> Result<bool, ReplyError> {
    match axis_value(request, frame, text, channel)? {
        "1" => Ok(true),
        "0" => Ok(false),
        _ => Err(ReplyError::new(request, frame, "neither 0 nor 1")),
    }
}

fn number(request: &Request<Step>, frame: &[u8], value: &str) -> Result<f64, ReplyError> {
    value.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| ReplyError::new(request, frame, "not a number"))
}

/// A parameter or register ID, decimal or `0x` hex.
pub(crate) fn parse_id(text: &str) -> Option<u32> {
    match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16).ok(),
        None => text.parse().ok(),
    }
}

/// A 16-bit register in hex, with or without `0x`.
fn parse_hex(text: &str) -> Option<u16> {
    let digits = text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")).unwrap_or(text);
    u16::from_str_radix(digits, 16).ok()
}

/// The events of an `ERR?` reply: nothing for 0 and the `expected` codes, else the error.
fn error_events(
    request: &Request<Step>,
    frame: &[u8],
    channel: Option<usize>,
    expected: &[i64],
) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
    let text = reply_text(frame);
    let code: i64 = text.trim().parse().map_err(|_| ReplyError::new(request, frame, "not an error code"))?;
    if code == 0 || expected.contains(&code) {
        return Ok(Vec::new());
    }
    Ok(vec![ReplyEvent::ControllerError(VendorError {
        channel,
        code: code.to_string(),
        meaning: error_meaning(code).to_string(),
    })])
}

impl Protocol for PiGcs2 {
    type Step = Step;

    fn name(&self) -> &'static str {
        NAME
    }

    /// An unreferenced axis takes no move (error 5); `FRF?` (HOMED) says whether it is
    /// referenced, by a reference move or by a position set with `RON 0`.
    fn moves_need_reference(&self, _channel: usize) -> bool {
        true
    }

    fn scale(&self, channel: usize) -> Scale {
        // PI's stages count in mm (linear) or degrees (rotary), their physical units.
        let unit = ControllerUnit::Physical { linear: Unit::MM, rotary: Unit::DEG };
        let read =
            self.axes.get(&channel).is_some_and(|a| a.counts_numerator.is_some() && a.counts_denominator.is_some());
        let source = match (self.units_per_step, read) {
            (Some(_), _) => ScaleSource::Installation,
            (None, true) => ScaleSource::Controller("SPA? <axis> 14 and 15, counts per unit"),
            (None, false) => ScaleSource::ProtocolDefault,
        };
        Scale { units_per_step: self.units_per_step(channel), unit, source }
    }

    fn purpose(step: Step) -> Purpose {
        match step {
            Step::Identity | Step::Axes | Step::Setting { .. } => Purpose::Init,
            Step::ServoStart | Step::ServoStarted => Purpose::Setup,
            Step::Read { channel, .. } => Purpose::Poll { channel },
            Step::PollErrors => Purpose::PollMany,
            Step::Setter { channel }
            | Step::ErrorCheck { channel }
            | Step::StopCheck { channel }
            | Step::RawQuery { channel } => Purpose::Command { channel },
        }
    }

    fn frame(&self, buffer: &[u8]) -> Frame {
        // A reply never starts with a line end: a stray one is noise.
        if matches!(buffer.first(), Some(b'\n' | b'\r')) {
            return Frame::Junk(1);
        }
        let mut from = 0;
        while let Some(at) = buffer[from..].iter().position(|b| *b == b'\n') {
            let end = from + at;
            // A space before the LF: another line of the same reply follows.
            if end > 0 && buffer[end - 1] == b' ' {
                from = end + 1;
                continue;
            }
            return Frame::Complete(end + 1);
        }
        Frame::Incomplete
    }

    fn init(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        self.channels = channels.to_vec();
        let mut requests = vec![Request::query("*IDN?\n", Step::Identity), Request::query("SAI?\n", Step::Axes)];
        for &channel in channels {
            let read = |query: String, setting: Setting| Request::query(query, Step::Setting { channel, setting });
            requests.push(read(format!("TRS? {channel}\n"), Setting::HasReference));
            requests.push(read(format!("LIM? {channel}\n"), Setting::HasLimitSwitches));
            if self.units_per_step.is_none() {
                requests.push(read(format!("SPA? {channel} 14\n"), Setting::CountsNumerator));
                requests.push(read(format!("SPA? {channel} 15\n"), Setting::CountsDenominator));
            }
            requests.push(read(format!("TMN? {channel}\n"), Setting::TravelMin));
            requests.push(read(format!("TMX? {channel}\n"), Setting::TravelMax));
        }
        if !self.servo_started && !channels.is_empty() {
            let pairs: Vec<String> = channels.iter().map(|c| format!("{c} 1")).collect();
            requests.push(Request::silent(format!("SVO {}\n", pairs.join(" ")), Step::ServoStart));
            requests.push(Request::query("ERR?\n", Step::ServoStarted));
        }
        requests
    }

    fn observe_only(&mut self) {
        self.observed = true;
    }

    fn poll(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        let mut requests = Vec::new();
        for &channel in channels {
            for (reading, query) in [
                (Reading::StatusRegister, format!("SRG? {channel} 1\n")),
                (Reading::Position, format!("POS? {channel}\n")),
                (Reading::Referenced, format!("FRF? {channel}\n")),
            ] {
                requests.push(Request::query(query, Step::Read { channel, reading }));
            }
        }
        if !self.observed {
            requests.push(Request::query("ERR?\n", Step::PollErrors));
        }
        requests
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        if channel == 0 {
            return Err(CommandError::Unsupported { protocol: NAME, what: "address channel 0 (axes count from 1)" });
        }
        let requests = match command {
            DriverCommand::Move { position, relative, max_velocity, acceleration, .. } => {
                let target = self.position_text(channel, if *relative { "distance" } else { "target" }, *position)?;
                let mut requests = self.dynamics(channel, *max_velocity, *acceleration)?;
                let verb = if *relative { "MVR" } else { "MOV" };
                requests.extend(checked(channel, format!("{verb} {channel} {target}")));
                let from = if *relative { 0.0 } else { self.axis(channel).position };
                self.axis(channel).direction_up = position.round() > from;
                requests
            }
            DriverCommand::MoveVelocity { max_velocity, acceleration, .. } => {
                let up = *max_velocity >= 0.0;
                let axis = self.axis(channel);
                let end = if up { axis.travel_max } else { axis.travel_min };
                let end = end
                    .ok_or(CommandError::Unsupported { protocol: NAME, what: "jog before its travel range is read" })?;
                let mut requests = self.dynamics(channel, *max_velocity, *acceleration)?;
                requests.extend(checked(channel, format!("MOV {channel} {}", self.units_text(channel, end))));
                self.axis(channel).direction_up = up;
                requests
            }
            DriverCommand::Home { forward, max_velocity, .. } => {
                let axis = self.axis(channel);
                let verb = match (axis.has_reference, axis.has_limit_switches, forward) {
                    (true, _, _) => "FRF",
                    (false, true, true) => "FPL",
                    (false, true, false) => "FNL",
                    (false, false, _) => {
                        return Err(CommandError::Unsupported {
                            protocol: NAME,
                            what: "home an axis with neither a reference switch nor limit switches",
                        })
                    }
                };
                let mut requests = Vec::new();
                if let Some(v) = self.rate_text(channel, "home velocity", *max_velocity)? {
                    requests
                        .extend(checked(channel, format!("SPA {channel} 0x{:X} {v}", parameter::REFERENCE_VELOCITY)));
                }
                requests.extend(checked(channel, format!("SVO {channel} 1")));
                requests.extend(checked(channel, format!("{verb} {channel}")));
                let axis = self.axis(channel);
                axis.direction_up = *forward;
                axis.servo_off_requested = false;
                axis.servo_dropped = false;
                requests
            }
            DriverCommand::Stop { .. } => vec![
                Request::silent(format!("HLT {channel}\n"), Step::Setter { channel }),
                Request::query("ERR?\n", Step::StopCheck { channel }),
            ],
            DriverCommand::SetPosition { position } => {
                let value = self.position_text(channel, "position", *position)?;
                let mut requests = Vec::new();
                for line in [format!("RON {channel} 0"), format!("POS {channel} {value}"), format!("RON {channel} 1")] {
                    requests.extend(checked(channel, line));
                }
                requests
            }
            DriverCommand::Enable { on } => {
                let axis = self.axis(channel);
                axis.servo_off_requested = !on;
                if *on {
                    axis.servo_dropped = false;
                }
                checked(channel, format!("SVO {channel} {}", u8::from(*on))).into()
            }
            DriverCommand::Raw { text } => {
                if text.contains(['\n', '\r']) {
                    return Err(CommandError::Unsupported { protocol: NAME, what: "send raw text of several lines" });
                }
                if text.trim().is_empty() {
                    Vec::new()
                } else if text.contains('?') {
                    vec![Request::query(format!("{text}\n"), Step::RawQuery { channel })]
                } else {
                    checked(channel, text.clone()).into()
                }
            }
            // The controller keeps its own travel range, encoder and PID terms; a status
            // refresh is a poll.
            DriverCommand::SetEncoderRatio { .. }
            | DriverCommand::SetHighLimit { .. }
            | DriverCommand::SetLowLimit { .. }
            | DriverCommand::SetGain { .. }
            | DriverCommand::Poll => Vec::new(),
        };
        Ok(requests)
    }

    fn reply(&mut self, request: &Request<Step>, frame: &[u8]) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        match request.step {
            Step::Identity => {
                let upper = reply_text(frame).to_ascii_uppercase();
                if !MODELS.iter().any(|model| upper.contains(model)) {
                    return Err(ReplyError::new(request, frame, "not a PI controller of the C-863/C-884 class"));
                }
                Ok(vec![ReplyEvent::Found(Finding::Identity(reply_text(frame).trim().to_string()))])
            }
            Step::Axes => {
                let text = reply_text(frame);
                let names: Vec<&str> = text.lines().map(str::trim).collect();
                if !self.channels.iter().all(|channel| names.contains(&channel.to_string().as_str())) {
                    return Err(ReplyError::new(request, frame, "a channel is not one of the controller's axes"));
                }
                Ok(vec![ReplyEvent::Found(Finding::Axes(names.iter().map(|n| n.to_string()).collect()))])
            }
            Step::Setting { channel, setting } => {
                self.on_setting(request, frame, channel, setting)?;
                let axis = self.axes.get(&channel);
                let travel =
                    axis.and_then(|a| a.travel_min.zip(a.travel_max)).filter(|_| setting == Setting::TravelMax);
                Ok(travel
                    .map(|(min, max)| ReplyEvent::Found(Finding::Travel { channel, min, max }))
                    .into_iter()
                    .collect())
            }
            Step::ServoStarted => {
                self.servo_started = true;
                error_events(request, frame, None, &[])
            }
            Step::Read { channel, reading } => self.on_reading(request, frame, channel, reading),
            // The controller's error register names no axis.
            Step::PollErrors => error_events(request, frame, None, &[]),
            Step::StopCheck { channel } => error_events(request, frame, Some(channel), &[STOPPED_BY_COMMAND]),
            Step::ErrorCheck { channel } => error_events(request, frame, Some(channel), &[]),
            // A raw query's reply is the user's to read; setters are not answered.
            Step::RawQuery { .. } | Step::Setter { .. } | Step::ServoStart => Ok(Vec::new()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sent(requests: &[Request<Step>]) -> Vec<String> {
        requests.iter().map(|r| String::from_utf8_lossy(&r.bytes).into_owned()).collect()
    }

    /// A protocol whose channels 1 and 3 have been initialised from a C-884 with 10000 counts
    /// per mm, a travel range of ±19.5 mm, reference and limit switches.
    fn initialised() -> PiGcs2 {
        let mut p = PiGcs2::new(&ProtocolOptions::default());
        let init = p.init(&[1, 3]);
        for request in init.iter().filter(|r| r.answered) {
            let text = String::from_utf8_lossy(&request.bytes).trim().to_string();
            let channel = if let Step::Setting { channel, .. } = request.step { channel } else { 0 };
            let reply = match text.split_whitespace().next().unwrap_or("") {
                "*IDN?" => "(c)2019 Physik Instrumente (PI) GmbH & Co. KG, C-884.4DC, 119012345, 1.3.4.2\n".into(),
                "SAI?" => "1 \n2 \n3 \n4\n".into(),
                "TRS?" | "LIM?" => format!("{channel}=1\n"),
                "SPA?" if text.ends_with("14") => format!("{channel} 0xE=10000\n"),
                "SPA?" => format!("{channel} 15=1\n"),
                "TMN?" => format!("{channel}=-19.5000000\n"),
                "TMX?" => format!("{channel}=19.5000000\n"),
                _ => "0\n".into(),
            };
            let events = p.reply(request, reply.as_bytes()).expect(&text);
            assert!(events.iter().all(|e| matches!(e, ReplyEvent::Found(_))), "{text}: {events:?}");
        }
        p
    }

    fn go(position: f64, relative: bool) -> DriverCommand {
        DriverCommand::Move { position, relative, min_velocity: 0.0, max_velocity: 50_000.0, acceleration: 1e6 }
    }

    #[test]
    fn a_connection_identifies_checks_axes_reads_scaling_and_range_and_switches_servo_on_once() {
        let mut p = PiGcs2::new(&ProtocolOptions::default());
        assert_eq!(
            sent(&p.init(&[1, 3])),
            [
                "*IDN?\n",
                "SAI?\n",
                "TRS? 1\n",
                "LIM? 1\n",
                "SPA? 1 14\n",
                "SPA? 1 15\n",
                "TMN? 1\n",
                "TMX? 1\n",
                "TRS? 3\n",
                "LIM? 3\n",
                "SPA? 3 14\n",
                "SPA? 3 15\n",
                "TMN? 3\n",
                "TMX? 3\n",
                "SVO 1 1 3 1\n",
                "ERR?\n",
            ]
        );
        let mut p = initialised();
        assert_eq!(p.units_per_step(1), 1e-4);
        let again = sent(&p.init(&[1, 3]));
        assert!(!again.iter().any(|r| r.starts_with("SVO")), "a reconnection leaves the servo alone: {again:?}");
        let given =
            PiGcs2::new(&ProtocolOptions { units_per_step: Some(0.0005), ..ProtocolOptions::default() }).init(&[2]);
        assert!(!sent(&given).iter().any(|r| r.starts_with("SPA?")), "the units are given");
    }

    #[test]
    fn a_connection_to_the_wrong_controller_or_without_the_axes_is_refused() {
        let mut p = PiGcs2::new(&ProtocolOptions::default());
        let init = p.init(&[1, 5]);
        assert!(p.reply(&init[0], b"(c)2019 Physik Instrumente (PI) GmbH & Co. KG, E-727, 1, 1\n").is_err());
        assert!(p.reply(&init[0], b"(c)2013 Physik Instrumente (PI) GmbH & Co. KG, c-863.11, 1, 1\n").is_ok());
        assert!(p.reply(&init[1], b"1 \n2 \n3 \n4\n").is_err(), "no axis 5");
        assert!(p.reply(&init[1], b"1 \n5\n").is_ok());
        assert!(p.reply(&init[4], b"1 14=0\n").is_err(), "counts per unit of 0 scale nothing");
        assert!(p.reply(&init[4], b"2 14=10000\n").is_err(), "another axis's parameter");
        assert!(p.reply(&init[4], b"1 15=10000\n").is_err(), "another parameter");
    }

    #[test]
    fn moves_set_velocity_and_acceleration_then_go_each_setter_checked() {
        let mut p = initialised();
        assert_eq!(
            sent(&p.command(1, &go(123_456.0, false)).unwrap()),
            [
                "VEL 1 5.000000\n",
                "ERR?\n",
                "ACC 1 100.000000\n",
                "ERR?\n",
                "DEC 1 100.000000\n",
                "ERR?\n",
                "MOV 1 12.345600\n",
                "ERR?\n",
            ]
        );
        let by = sent(&p.command(3, &go(-500.4, true)).unwrap());
        assert_eq!(by[6..], ["MVR 3 -0.050000\n", "ERR?\n"]);
        let at_rest = DriverCommand::Move {
            position: 10.0,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 0.0,
            acceleration: 0.0,
        };
        assert_eq!(sent(&p.command(1, &at_rest).unwrap()), ["MOV 1 0.001000\n", "ERR?\n"], "0: the controller's own");
        let requests = p.command(1, &go(0.0, false)).unwrap();
        assert!(requests.iter().all(|r| r.answered == r.bytes.starts_with(b"ERR?")), "setters are silent");
        assert!(matches!(p.command(1, &go(3e9, false)), Err(CommandError::OutOfRange { .. })), "refused, not clamped");
        assert!(matches!(p.command(0, &go(1.0, false)), Err(CommandError::Unsupported { .. })));
    }

    #[test]
    fn positions_carry_as_many_decimals_as_one_step_needs() {
        let mut p = PiGcs2::new(&ProtocolOptions { units_per_step: Some(1e-9), ..ProtocolOptions::default() });
        assert_eq!(sent(&p.command(1, &go(1_234_567.0, false)).unwrap())[6], "MOV 1 0.0012345670\n");
    }

    #[test]
    fn a_jog_moves_to_the_end_of_the_travel_range_at_the_jog_velocity() {
        let mut p = initialised();
        let jog = |v: f64| DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: v, acceleration: 2e5 };
        assert_eq!(
            sent(&p.command(1, &jog(-20_000.0)).unwrap()),
            [
                "VEL 1 2.000000\n",
                "ERR?\n",
                "ACC 1 20.000000\n",
                "ERR?\n",
                "DEC 1 20.000000\n",
                "ERR?\n",
                "MOV 1 -19.500000\n",
                "ERR?\n",
            ]
        );
        assert_eq!(sent(&p.command(3, &jog(1000.0)).unwrap())[6], "MOV 3 19.500000\n");
        let mut fresh = PiGcs2::new(&ProtocolOptions::default());
        assert!(fresh.command(1, &jog(1000.0)).is_err(), "no travel range read: no target");
    }

    #[test]
    fn home_references_at_the_reference_switch_or_else_at_a_limit_switch() {
        let mut p = initialised();
        let home = |forward: bool| DriverCommand::Home {
            forward,
            min_velocity: 0.0,
            max_velocity: 20_000.0,
            acceleration: 1.0,
        };
        assert_eq!(
            sent(&p.command(1, &home(false)).unwrap()),
            ["SPA 1 0x50 2.000000\n", "ERR?\n", "SVO 1 1\n", "ERR?\n", "FRF 1\n", "ERR?\n"]
        );
        assert_eq!(sent(&p.command(1, &home(true)).unwrap())[4], "FRF 1\n", "the controller finds its side");
        p.axis(3).has_reference = false;
        assert_eq!(sent(&p.command(3, &home(true)).unwrap())[4], "FPL 3\n");
        assert_eq!(sent(&p.command(3, &home(false)).unwrap())[4], "FNL 3\n");
        p.axis(3).has_limit_switches = false;
        assert!(matches!(p.command(3, &home(true)), Err(CommandError::Unsupported { .. })));
    }

    #[test]
    fn stop_set_position_enable_and_raw_text() {
        let mut p = initialised();
        assert_eq!(sent(&p.command(1, &DriverCommand::Stop { acceleration: 1.0 }).unwrap()), ["HLT 1\n", "ERR?\n"]);
        assert_eq!(
            sent(&p.command(3, &DriverCommand::SetPosition { position: -30_000.0 }).unwrap()),
            ["RON 3 0\n", "ERR?\n", "POS 3 -3.000000\n", "ERR?\n", "RON 3 1\n", "ERR?\n"]
        );
        assert_eq!(sent(&p.command(1, &DriverCommand::Enable { on: false }).unwrap()), ["SVO 1 0\n", "ERR?\n"]);
        let raw = |text: &str| DriverCommand::Raw { text: text.into() };
        let query = p.command(1, &raw("VEL? 1")).unwrap();
        assert_eq!((sent(&query), query[0].answered), (vec!["VEL? 1\n".to_string()], true));
        assert_eq!(sent(&p.command(1, &raw("SPA 1 0x3F 0.1")).unwrap()), ["SPA 1 0x3F 0.1\n", "ERR?\n"]);
        assert!(p.command(1, &raw("MOV 1 1\nMOV 2 2")).is_err(), "one line, or the replies fall out of step");
        assert_eq!(p.command(1, &DriverCommand::SetHighLimit { position: 1.0 }), Ok(vec![]));
        assert_eq!(p.command(1, &DriverCommand::SetGain { gain: zmotor_msgs::Gain::Integral, value: 0.5 }), Ok(vec![]));
    }

    #[test]
    fn a_poll_reads_the_status_register_position_and_referencing_then_the_error() {
        let mut p = initialised();
        let poll = p.poll(&[1]);
        assert_eq!(sent(&poll), ["SRG? 1 1\n", "POS? 1\n", "FRF? 1\n", "ERR?\n"]);
        assert_eq!(p.reply(&poll[0], b"1 1=0x3005\n").unwrap(), []);
        assert_eq!(p.reply(&poll[1], b"1=12.3456000\n").unwrap(), []);
        let events = p.reply(&poll[2], b"1=1\n").unwrap();
        let [ReplyEvent::Status { channel: 1, status }] = &events[..] else { panic!("{events:?}") };
        assert_eq!(status.position, 123_456.0);
        let expected =
            msta::MOVING | msta::PLUS_LS | msta::MINUS_LS | msta::POSITION | msta::HOMED | msta::GAIN_SUPPORT;
        assert_eq!(status.msta & !msta::DIRECTION, expected);
        // Referencing is motion too; at rest on target, done.
        p.reply(&poll[0], b"1 1=0x4000\n").unwrap();
        let events = p.reply(&poll[2], b"1=0\n").unwrap();
        let [ReplyEvent::Status { status, .. }] = &events[..] else { panic!("{events:?}") };
        assert_eq!(status.msta & (msta::DONE | msta::MOVING | msta::HOMED | msta::POSITION), msta::MOVING);
        p.reply(&poll[0], b"1 0x1=0x9000\n").unwrap();
        let events = p.reply(&poll[2], b"1=1\n").unwrap();
        let [ReplyEvent::Status { status, .. }] = &events[..] else { panic!("{events:?}") };
        assert_eq!(status.msta & (msta::DONE | msta::MOVING | msta::POSITION), msta::DONE | msta::POSITION);
    }

    #[test]
    fn the_direction_is_the_way_of_the_last_motion_commanded() {
        let mut p = initialised();
        let poll = p.poll(&[1]);
        let direction = |p: &mut PiGcs2| match &p.reply(&poll[2], b"1=1\n").unwrap()[..] {
            [ReplyEvent::Status { status, .. }] => status.msta & msta::DIRECTION != 0,
            other => panic!("{other:?}"),
        };
        p.reply(&poll[1], b"1=1.0\n").unwrap();
        p.command(1, &go(5000.0, false)).unwrap();
        assert!(!direction(&mut p), "5000 steps is below 1 mm");
        p.command(1, &go(5000.0, true)).unwrap();
        assert!(direction(&mut p));
    }

    #[test]
    fn errors_are_reported_with_their_meaning_except_the_stop_that_was_asked_for() {
        let mut p = initialised();
        let moved = p.command(3, &go(300_000.0, false)).unwrap();
        assert_eq!(p.reply(&moved[7], b"0\n").unwrap(), []);
        assert_eq!(
            p.reply(&moved[7], b"7\n").unwrap(),
            [ReplyEvent::ControllerError(VendorError {
                channel: Some(3),
                code: "7".into(),
                meaning: "Position out of limits".into()
            })]
        );
        let stop = p.command(3, &DriverCommand::Stop { acceleration: 1.0 }).unwrap();
        assert_eq!(p.reply(&stop[1], b"10\n").unwrap(), [], "a stop leaves 10");
        assert!(matches!(&p.reply(&stop[1], b"5\n").unwrap()[..], [ReplyEvent::ControllerError(VendorError { .. })]));
        let poll = p.poll(&[1]);
        let events = p.reply(&poll[3], b"1024\n").unwrap();
        let [ReplyEvent::ControllerError(VendorError { channel: None, code, meaning })] = &events[..] else {
            panic!("{events:?}")
        };
        assert_eq!((code.as_str(), meaning.starts_with("Motion error")), ("1024", true));
        assert!(p.reply(&poll[3], b"1=0\n").is_err());
    }

    #[test]
    fn a_servo_that_goes_off_unasked_is_a_problem_until_switched_on_again() {
        let mut p = initialised();
        let poll = p.poll(&[1]);
        let problem = |p: &mut PiGcs2, register: &[u8]| {
            p.reply(&poll[0], register).unwrap();
            match &p.reply(&poll[2], b"1=1\n").unwrap()[..] {
                [ReplyEvent::Status { status, .. }] => status.msta & msta::PROBLEM != 0,
                other => panic!("{other:?}"),
            }
        };
        assert!(!problem(&mut p, b"1 1=0x9000\n"));
        assert!(problem(&mut p, b"1 1=0x0000\n"), "servo dropped");
        assert!(problem(&mut p, b"1 1=0x0000\n"), "latched");
        p.command(1, &DriverCommand::Enable { on: true }).unwrap();
        assert!(!problem(&mut p, b"1 1=0x9000\n"));
        p.command(1, &DriverCommand::Enable { on: false }).unwrap();
        assert!(!problem(&mut p, b"1 1=0x8000\n"), "switched off on request");
    }

    #[test]
    fn a_reply_of_another_axis_or_garbage_is_refused() {
        let mut p = initialised();
        let poll = p.poll(&[1]);
        assert!(p.reply(&poll[0], b"2 1=0x9000\n").is_err(), "another axis's register");
        assert!(p.reply(&poll[0], b"1 2=0x9000\n").is_err(), "another register");
        assert!(p.reply(&poll[0], b"1 1=0xZZ\n").is_err());
        assert!(p.reply(&poll[1], b"3=1.5\n").is_err(), "another axis's position");
        assert!(p.reply(&poll[1], b"1=lots\n").is_err());
        assert!(p.reply(&poll[1], b"1=1.5 \n3=2.5\n").is_err(), "two axes where one was asked for");
        assert!(p.reply(&poll[2], b"1=2\n").is_err());
        assert!(p.reply(&poll[3], b"~~~\n").is_err());
    }

    #[test]
    fn a_reply_ends_at_the_first_line_end_without_a_space_before_it() {
        let p = PiGcs2::new(&ProtocolOptions::default());
        assert_eq!(p.frame(b"1=0.5\n2="), Frame::Complete(6));
        assert_eq!(p.frame(b"1 \n2 \n3 \n4\nx"), Frame::Complete(11));
        assert_eq!(p.frame(b"1 \n2 \n"), Frame::Incomplete);
        assert_eq!(p.frame(b"\xb1\n"), Frame::Complete(2));
        assert_eq!(p.frame(b"\n1=1\n"), Frame::Junk(1));
        let reply = b"1 \n2 \n3 \n4\n";
        for split in 0..reply.len() {
            assert_eq!(p.frame(&reply[..split]), Frame::Incomplete, "cut after {split} bytes");
        }
        assert_eq!(p.frame(reply), Frame::Complete(reply.len()));
    }
}
