//! Newport XPS (XPS-C8, XPS-Q8, XPS-D): function calls in ASCII over TCP (port 5001), as the
//! EPICS driver motorNewport (XPSAxis.cpp, with Newport's own XPS_C8_drivers.cpp underneath)
//! speaks them.
//!
//! # Wire format
//! A request is a call, `GroupMoveAbsolute (GROUP1.POSITIONER,10.5)`, with no terminator; its
//! outputs are named by their C types (`GroupStatusGet (GROUP1,int *)`). Numbers go out as C's
//! `%.13g`. A reply is the error code, the outputs, and `EndOfAPI`, comma separated:
//! `0,12,EndOfAPI`; a call without outputs is answered `0,EndOfAPI` (or `0,,EndOfAPI`: both are
//! read). A code other than 0 is the controller's error, named on the axis's ERR; a call of a
//! command refused ends the command there (a move whose speed the XPS refuses is not sent at
//! the previous speed), as motorNewport returns at the first error.
//!
//! # Motion calls block their socket
//! `GroupMoveAbsolute`, `GroupMoveRelative` and `GroupHomeSearch` are answered only when the
//! motion ends. As motorNewport does (a "move socket" per axis beside the "poll socket"), each
//! channel's motion calls go on a connection of their own (`Lane::Motion`), written without
//! waiting; polls, stops and settings go on the main one. A channel whose motion call is still
//! unanswered is not done, whatever the group's state says (the poll may reach the XPS before the
//! move on the other socket has started), and its answer brings a poll at once. The answer
//! `-27` (motion aborted) is expected after a stop and not an error, as in motorNewport.
//!
//! # Channels and units
//! Channel n (1 to 8) is the positioner the launch file's `axis_names` gives it
//! (`axis_names = { 1 = "FINE.X" }`: group `FINE`, positioner `FINE.X`, as the XPS's system.ini
//! names them), or else the single-positioner group `GROUPn` and its `GROUPn.POSITIONER`. Axes
//! sharing a group share its state: a home, a set position or a stop of one acts on the group.
//! Positions, speeds and accelerations are in the stage's unit (mm, or deg on a rotary stage), one record step being
//! `units_per_step` of them (the launch file's; 0.1 µm otherwise), as motorNewport's `stepSize`.
//!
//! # Record commands (channel 1), with what differs from motorNewport and why
//! - move: `GroupMotionEnable (GROUP1)` first if the last poll found the group disabled
//!   (motorNewport's auto-enable), `GroupJogModeDisable (GROUP1)` if in jog mode (a jog that
//!   ended at the travel limit stays in it; motorNewport's move is refused there), `PositionerSGammaParametersSet (GROUP1.POSITIONER,v,a,jmin,jmax)`
//!   (the jerk times read at connection), then on the motion lane `GroupMoveAbsolute
//!   (GROUP1.POSITIONER,p)` or `GroupMoveRelative`;
//! - jog: `GroupJogModeEnable (GROUP1)`, `GroupJogParametersSet (GROUP1.POSITIONER,v,a)`. The
//!   latter on the main connection (motorNewport writes it on the move socket): it answers at
//!   once, so its error is seen;
//! - home: `GroupStatusGet`, then for a group in jog mode `GroupJogModeDisable`, for a group
//!   ready (10–18) or in jog mode `GroupKill` and `GroupInitialize`, for
//!   one not initialised (0–9, 50, 63) `GroupInitialize`, then on the motion lane
//!   `GroupHomeSearch (GROUP1)`: the XPS homes only a group not referenced;
//! - stop: `GroupStatusGet`, then `GroupKill (GROUP1)` if it homes (43: a home search cannot be
//!   aborted), `GroupMoveAbort (GROUP1)` otherwise: a move whose call is on its way on the motion
//!   connection may not have started when the state was read, and the abort's refusal when
//!   nothing moves (-22) is no error (motorNewport aborts only in 44, 45, 47). On the main connection: motorNewport writes them on the move socket, unanswered;
//!   here the abort's own answer is read;
//! - set position: `GroupKill`, `GroupInitialize`, `GroupReferencingStart`,
//!   `GroupReferencingActionExecute (GROUP1.POSITIONER,SetPosition,None,p)`,
//!   `GroupReferencingStop` (motorNewport's sequence, without its settling pause); refused for
//!   an axis whose group has others (motorNewport reads their positions and sets them again);
//! - enable: `GroupStatusGet`, then `GroupInitialize` for a group not initialised (its motors
//!   unpowered: 0–9, 50, 63) or `GroupMotionEnable` for a disabled one (20–36); disable:
//!   `GroupMotionDisable`. motorNewport's enable is `GroupMotionEnable` alone, which the XPS
//!   refuses until the group is initialised, so that CNEN could not power a group up;
//! - raw text: sent as it is, its code read;
//! - soft limits, gains, encoder ratio: nothing is sent. The XPS keeps its own travel limits
//!   (motorNewport writes the record's DHLM/DLLM into them, and the record's "no limits", both 0,
//!   would then refuse every move).
//!
//! # Connection and polls
//! Initialisation reads `FirmwareVersionGet (char *)` (logged) and, per channel, the jerk times
//! `PositionerSGammaParametersGet` and the travel `PositionerUserTravelLimitsGet` (logged);
//! nothing is changed or homed. At a node run's first connection only (not under `observe`,
//! not after a reconnection), each group as the XPS powers up (state 0; not one left
//! uninitialised by a fault, an emergency or a kill, 1–9) is initialised, `GroupInitialize
//! (GROUP1)`, as PI's servos are switched on: its motors powered, nothing moved. A poll reads per channel `GroupStatusGet`,
//! `GroupVelocityCurrentGet`, `GroupPositionCurrentGet` (the encoder), `GroupPositionSetpointGet`
//! (the position, as motorNewport reads them), `PositionerErrorGet`; motorNewport reads the speed
//! last, but a poll whose speed finds a jog over must read the positions after it (its final
//! position with DMOV 1):
//!
//! | reading | MSTA |
//! |---|---|
//! | group state 43–48, or a motion call unanswered | not DONE (but DONE in jog mode, 47, at rest after the jog moved) |
//! | speed beyond 1e-7 | MOVING, DIRECTION its sign |
//! | state 10–36, 44, 45, 47 | HOMED (a disabled group keeps its reference; motorNewport: 10–21) |
//! | state 11 | HOME |
//! | state 10–19, 42–49, 56, 64, 68, 70, 77, 79 | POSITION (powered) |
//! | state 1–6, 8, 9, 21–36, 50, 63 | PROBLEM (not initialised or disabled by a fault) |
//! | state 21, 22, 24–26, 28, 35 | SLIP_STALL (following error) |
//! | positioner error 0x200 / 0x100 | PLUS_LS / MINUS_LS (end of run) |
//!
//! motorNewport also sets PROBLEM in the states a group is in without a fault: as powered up (0),
//! killed on request (7), disabled on request (20), not referenced (42), referencing (64). Here
//! those are not problems (the record's alarm would stand from power-up until the first home):
//! HOMED says the group awaits its home, and a move before it is refused saying so. An
//! initialised group not referenced (42) has its motors powered: POSITION, which motorNewport
//! leaves off there.

use crate::protocol::{
    set_bit, state_of, CommandError, Finding, Frame, Protocol, ProtocolOptions, Purpose, ReplyError, ReplyEvent,
    Request, UnitIdentities, VendorError,
};
use crate::scale::{ControllerUnit, Scale, ScaleSource};
use zmotor_core::DeviceStatus;
use zmotor_msgs::bits::msta;
use zmotor_msgs::{DriverCommand, Unit};

/// The protocol's name in launch files.
pub(crate) const NAME: &str = "newport_xps";

/// What ends every reply.
const END_OF_API: &[u8] = b"EndOfAPI";

/// A record step when nothing says otherwise: 0.1 µm.
const DEFAULT_UNITS_PER_STEP: f64 = 0.0001;

/// Slower than this is at rest (motorNewport's `XPS_VELOCITY_DEADBAND`).
const VELOCITY_DEADBAND: f64 = 1e-7;

/// `PositionerErrorGet`'s end-of-run bits.
const END_OF_RUN_MINUS: i64 = 0x100;
const END_OF_RUN_PLUS: i64 = 0x200;

/// The group state of jog mode.
const JOGGING: i32 = 47;

/// The group state of a home search.
const HOMING: i32 = 43;

/// The group state as powered up: not initialised, and by no fault or request.
const POWERED_UP: i32 = 0;

/// The code of a call the group's state does not allow.
const NOT_ALLOWED: i32 = -22;

/// The code of a motion call answered because the motion was aborted.
const MOTION_ABORTED: i32 = -27;

/// A request's place in the protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Step {
    Firmware,
    Jerk {
        channel: usize,
    },
    Travel {
        channel: usize,
    },
    /// The group's state at a node run's first connection, to initialise it if it never was.
    PowerUp {
        channel: usize,
    },
    PowerUpCall {
        channel: usize,
    },
    Read {
        channel: usize,
        reading: Reading,
    },
    /// The group's state, read to choose how to stop or home it.
    StateFor {
        channel: usize,
        then: Then,
    },
    Command {
        channel: usize,
    },
    /// `GroupMoveAbort` of a stop: refused (-22) when nothing moves, which is no error.
    Abort {
        channel: usize,
    },
    /// A motion call, answered when the motion ends.
    Motion {
        channel: usize,
    },
}

/// One reading of a channel's poll, in the order sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Reading {
    GroupState,
    Current,
    Setpoint,
    PositionerError,
    Velocity,
}

/// What follows a group state read for a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Then {
    Stop,
    Home,
    Enable,
}

/// What the protocol knows of a channel.
#[derive(Clone, Copy, Debug, Default)]
struct Axis {
    /// `PositionerSGammaParametersGet`'s jerk times, read at connection.
    jerk: Option<(f64, f64)>,
    /// The group state the last poll read.
    state: Option<i32>,
    /// The last jog was seen moving: standing still in jog mode since means it has ended (not
    /// that it has yet to start).
    jog_seen_moving: bool,
    /// A stop was asked since the last home: a home whose group state comes after it goes no
    /// further (its kill, initialisation and search would start it again).
    stopped: bool,
    status: DeviceStatus,
}

/// The XPS protocol.
#[derive(Debug)]
pub(crate) struct Xps {
    units_per_step: f64,
    source: ScaleSource,
    axes: Vec<(usize, Axis)>,
    /// The launch file's positioner names, by channel.
    names: std::collections::BTreeMap<usize, String>,
    /// The groups not initialised were initialised at a connection of this run (once only: a
    /// group killed since stays as it is).
    initialised_at_start: bool,
    /// The firmware as the initialisation read it (`sync`).
    identity: UnitIdentities,
}

impl Xps {
    /// A protocol scaled by `options.units_per_step`.
    pub(crate) fn new(options: &ProtocolOptions) -> Self {
        let (units_per_step, source) = match options.units_per_step {
            Some(units) => (units, ScaleSource::Installation),
            None => (DEFAULT_UNITS_PER_STEP, ScaleSource::ProtocolDefault),
        };
        Self {
            units_per_step,
            source,
            axes: Vec::new(),
            names: options.names.clone(),
            initialised_at_start: false,
            identity: UnitIdentities::default(),
        }
    }

    /// Channel `n`'s positioner, `GROUP.POSITIONER`: the launch file's name, or `GROUPn.POSITIONER`.
    fn positioner(&self, n: usize) -> String {
        self.names.get(&n).cloned().unwrap_or_else(|| format!("GROUP{n}.POSITIONER"))
    }

    /// Channel `n`'s group: its positioner's name before the dot.
    fn group(&self, n: usize) -> String {
        let positioner = self.positioner(n);
        positioner.split_once('.').map_or(positioner.clone(), |(group, _)| group.to_string())
    }

    /// `GroupStatusGet` of channel `n`'s group.
    fn state_query(&self, n: usize) -> String {
        format!("GroupStatusGet ({},int *)", self.group(n))
    }

    fn axis(&mut self, channel: usize) -> &mut Axis {
        state_of(&mut self.axes, channel)
    }

    /// `steps` in the stage's unit, as the XPS takes numbers.
    fn units(&self, what: &'static str, steps: f64) -> Result<String, CommandError> {
        let units = steps * self.units_per_step;
        if units.is_finite() {
            Ok(c_g13(units))
        } else {
            Err(CommandError::OutOfRange { what, value: steps })
        }
    }

    fn command_requests(&mut self, n: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        let (group, positioner) = (self.group(n), self.positioner(n));
        let call = |text: String| Request::query(text, Step::Command { channel: n });
        Ok(match command {
            DriverCommand::Move { position, relative, max_velocity, acceleration, .. } => {
                let axis = *self.axis(n);
                let (min_jerk, max_jerk) = axis
                    .jerk
                    .ok_or(CommandError::Unsupported { protocol: NAME, what: "move before the jerk times are read" })?;
                let velocity = self.units("velocity", max_velocity.abs())?;
                let acceleration = self.units("acceleration", acceleration.abs())?;
                let target = self.units("target", *position)?;
                let mut requests = Vec::new();
                match axis.state {
                    Some(20..=36) => requests.push(call(format!("GroupMotionEnable ({group})"))),
                    // A jog that ended at the travel limit leaves the group in jog mode.
                    Some(JOGGING) => requests.push(call(format!("GroupJogModeDisable ({group})"))),
                    _ => {}
                }
                requests.push(call(format!(
                    "PositionerSGammaParametersSet ({positioner},{velocity},{acceleration},{},{})",
                    c_g13(min_jerk),
                    c_g13(max_jerk)
                )));
                let verb = if *relative { "GroupMoveRelative" } else { "GroupMoveAbsolute" };
                requests.push(Request::motion(
                    format!("{verb} ({positioner},{target})"),
                    Step::Motion { channel: n },
                    n,
                ));
                requests
            }
            DriverCommand::MoveVelocity { max_velocity, acceleration, .. } => {
                let velocity = self.units("velocity", *max_velocity)?;
                let acceleration = self.units("acceleration", acceleration.abs())?;
                let axis = self.axis(n);
                axis.jog_seen_moving = false;
                let mut requests = Vec::new();
                // A new speed while jogging: jog mode is on already (enabling it again is refused).
                if axis.state != Some(JOGGING) {
                    requests.push(call(format!("GroupJogModeEnable ({group})")));
                }
                requests.push(call(format!("GroupJogParametersSet ({positioner},{velocity},{acceleration})")));
                requests
            }
            DriverCommand::Home { .. } => {
                self.axis(n).stopped = false;
                vec![Request::query(self.state_query(n), Step::StateFor { channel: n, then: Then::Home })]
            }
            DriverCommand::Stop { .. } => {
                self.axis(n).stopped = true;
                vec![Request::query(self.state_query(n), Step::StateFor { channel: n, then: Then::Stop })]
            }
            DriverCommand::SetPosition { position } => {
                // The XPS sets a position by re-initialising the whole group: another axis of it
                // would lose its reference and position (motorNewport reads and sets them again).
                let known = self.names.keys().copied().chain(self.axes.iter().map(|(c, _)| *c));
                if known.filter(|&c| c != n).any(|c| self.group(c) == group) {
                    return Err(CommandError::Unsupported {
                        protocol: NAME,
                        what: "set the position of an axis whose group has other axes (it re-initialises the group)",
                    });
                }
                let position = self.units("position", *position)?;
                vec![
                    call(format!("GroupKill ({group})")),
                    call(format!("GroupInitialize ({group})")),
                    call(format!("GroupReferencingStart ({group})")),
                    call(format!("GroupReferencingActionExecute ({positioner},SetPosition,None,{position})")),
                    call(format!("GroupReferencingStop ({group})")),
                ]
            }
            DriverCommand::Enable { on: true } => {
                vec![Request::query(self.state_query(n), Step::StateFor { channel: n, then: Then::Enable })]
            }
            DriverCommand::Enable { on: false } => vec![call(format!("GroupMotionDisable ({group})"))],
            DriverCommand::Raw { text } => vec![call(text.clone())],
            DriverCommand::SetEncoderRatio { .. }
            | DriverCommand::SetHighLimit { .. }
            | DriverCommand::SetLowLimit { .. }
            | DriverCommand::SetGain { .. }
            | DriverCommand::Poll => Vec::new(),
        })
    }

    /// What follows the group state `state` for `then`.
    fn after_state(&mut self, channel: usize, state: i32, then: Then) -> Vec<Request<Step>> {
        let group = self.group(channel);
        let call = |text: String| Request::query(text, Step::Command { channel });
        match then {
            Then::Stop if state == HOMING => vec![call(format!("GroupKill ({group})"))],
            // Whatever else the state: a move whose call is on its way on the motion connection
            // may not have started yet when the state was read. Nothing to abort is no error.
            Then::Stop => vec![Request::query(format!("GroupMoveAbort ({group})"), Step::Abort { channel })],
            Then::Enable if not_initialised(state) => vec![call(format!("GroupInitialize ({group})"))],
            Then::Enable if (20..=36).contains(&state) => vec![call(format!("GroupMotionEnable ({group})"))],
            Then::Enable => Vec::new(),
            Then::Home if self.axis(channel).stopped => Vec::new(),
            Then::Home => {
                let mut requests = Vec::new();
                if state == JOGGING {
                    requests.push(call(format!("GroupJogModeDisable ({group})")));
                }
                if (10..=18).contains(&state) || state == JOGGING {
                    requests.push(call(format!("GroupKill ({group})")));
                }
                // Killed, the group is not initialised: initialised next, as one that never was.
                if (10..=18).contains(&state) || state == JOGGING || not_initialised(state) {
                    requests.push(call(format!("GroupInitialize ({group})")));
                }
                requests.push(Request::motion(format!("GroupHomeSearch ({group})"), Step::Motion { channel }, channel));
                requests
            }
        }
    }

    /// The status of `channel` from a poll's readings so far.
    fn read(&mut self, channel: usize, reading: Reading, value: f64) -> Option<ReplyEvent<Step>> {
        let units_per_step = self.units_per_step;
        let axis = self.axis(channel);
        let status = &mut axis.status;
        match reading {
            Reading::GroupState => {
                // Codes are small integers; the float came from the same parse as the others.
                let state = value as i32;
                axis.state = Some(state);
                let bits = [
                    // Disabled (20–36), a group keeps its reference: enabled, it is ready again.
                    (msta::HOMED, (10..=36).contains(&state) || matches!(state, 44 | 45 | 47)),
                    (msta::HOME, state == 11),
                    (
                        msta::POSITION,
                        (10..=19).contains(&state)
                            || (42..=49).contains(&state)
                            || matches!(state, 56 | 64 | 68 | 70 | 77 | 79),
                    ),
                    (msta::PROBLEM, faulted(state)),
                    (msta::SLIP_STALL, matches!(state, 21 | 22 | 24 | 25 | 26 | 28 | 35)),
                ];
                for (bit, on) in bits {
                    set_bit(&mut status.msta, bit, on);
                }
                // (While a motion call is unanswered, the controller layer holds DONE off.)
                set_bit(&mut status.msta, msta::DONE, !(43..=48).contains(&state));
                // In jog mode the group stays "jogging" at rest (at the travel limit, or at
                // speed 0): done once the speed says it stands, read below.
            }
            Reading::Current => status.encoder_position = value / units_per_step,
            Reading::Setpoint => status.position = value / units_per_step,
            Reading::PositionerError => {
                let bits = value as i64;
                set_bit(&mut status.msta, msta::PLUS_LS, bits & END_OF_RUN_PLUS != 0);
                set_bit(&mut status.msta, msta::MINUS_LS, bits & END_OF_RUN_MINUS != 0);
                status.msta |= msta::PRESENT | msta::GAIN_SUPPORT;
                return Some(ReplyEvent::Status { channel, status: *status });
            }
            Reading::Velocity => {
                let moving = value.abs() > VELOCITY_DEADBAND;
                set_bit(&mut status.msta, msta::MOVING, moving);
                if axis.state == Some(JOGGING) {
                    axis.jog_seen_moving |= moving;
                    if axis.jog_seen_moving && !moving {
                        status.msta |= msta::DONE;
                    }
                }
                if moving {
                    set_bit(&mut status.msta, msta::DIRECTION, value > 0.0);
                }
                status.velocity = value / units_per_step;
            }
        }
        None
    }
}

/// A group state the XPS reaches through a fault: not initialised after an emergency, a
/// following error, a timeout, an end of run or a failed initialisation; disabled by a fault.
fn faulted(state: i32) -> bool {
    matches!(state, 1..=6 | 8 | 9 | 21..=36 | 50 | 63)
}

/// A group state from which only `GroupInitialize` leads on (its motors unpowered).
fn not_initialised(state: i32) -> bool {
    matches!(state, 0..=9 | 50 | 63)
}

/// A number as C's `%.13g` writes it (Newport's driver formats every argument so).
fn c_g13(value: f64) -> String {
    if value == 0.0 {
        return "0".into();
    }
    let scientific = format!("{value:.12e}");
    let (mantissa, exponent) = scientific.split_once('e').expect("{:e} has an exponent");
    let exponent: i32 = exponent.parse().expect("{:e}'s exponent is a number");
    let trim = |digits: &str| -> String {
        if digits.contains('.') {
            digits.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            digits.to_string()
        }
    };
    if !(-4..13).contains(&exponent) {
        let sign = if exponent < 0 { '-' } else { '+' };
        format!("{}e{sign}{:02}", trim(mantissa), exponent.abs())
    } else {
        let decimals = usize::try_from(12 - exponent).unwrap_or(0);
        trim(&format!("{value:.decimals$}"))
    }
}

/// A reply's code and outputs: `0,12.5,EndOfAPI`.
fn split_reply(frame: &[u8]) -> Option<(i32, Vec<&str>)> {
    let text = std::str::from_utf8(frame).ok()?.trim();
    let body = text.strip_suffix("EndOfAPI")?.trim_end_matches(',');
    let mut fields = body.split(',').map(str::trim);
    let code = fields.next()?.parse().ok()?;
    Some((code, fields.collect()))
}

/// What an XPS error code means (XPS_C8_errors.h's names, in words).
fn meaning(code: i32) -> &'static str {
    match code {
        1 => "TCL interpreter error",
        -1 => "busy socket: the previous call on it is not complete",
        -2 => "TCP timeout",
        -3 => "string too long",
        -4 => "unknown command",
        -5 => "positioner error",
        -7 => "wrong format in the command string",
        -8 => "wrong object type for this command",
        -9 => "wrong number of parameters",
        -16..=-10 => "a parameter of the wrong type",
        -17 => "parameter out of range or incorrect",
        -18 => "positioner name does not exist or is unknown",
        -19 => "group name does not exist or is unknown",
        -20 => "fatal error during initialisation",
        -21 => "controller in initialisation",
        -22 => "not allowed action (the group's state does not allow it)",
        -24 => "not available in this configuration",
        -25 => "following error",
        -26 => "emergency signal",
        -27 => "motion aborted",
        -28 => "home search timeout",
        -31 => "home position out of the user travel",
        -33 => "motion done timeout",
        -35 => "not allowed: target out of the user travel limits",
        -42 => "jog value out of range",
        -45 => "end of run",
        -48 => "base velocity",
        -49 => "home search ZM error",
        -50 => "motor initialisation error",
        -100 => "internal error",
        _ => "an XPS error (see the XPS programmer's manual)",
    }
}

impl Protocol for Xps {
    type Step = Step;

    fn name(&self) -> &'static str {
        NAME
    }

    fn purpose(step: Step) -> Purpose {
        match step {
            Step::Firmware | Step::Jerk { .. } | Step::Travel { .. } => Purpose::Init,
            Step::PowerUp { .. } | Step::PowerUpCall { .. } => Purpose::Setup,
            Step::Read { channel, .. } => Purpose::Poll { channel },
            Step::StateFor { channel, .. }
            | Step::Command { channel }
            | Step::Abort { channel }
            | Step::Motion { channel } => Purpose::Command { channel },
        }
    }

    fn frame(&self, buffer: &[u8]) -> Frame {
        match buffer.windows(END_OF_API.len()).position(|w| w == END_OF_API) {
            Some(at) => Frame::Complete(at + END_OF_API.len()),
            None => Frame::Incomplete,
        }
    }

    fn motion_lanes(&self) -> bool {
        true
    }

    fn moves_need_reference(&self, _channel: usize) -> bool {
        // The XPS moves and jogs a group only once homed (ready, states 10-18).
        true
    }

    fn init(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        // Read afresh: the controller may have been changed or upgraded.
        self.identity.clear();
        let mut requests = vec![Request::query("FirmwareVersionGet (char *)", Step::Firmware)];
        for &channel in channels {
            let positioner = self.positioner(channel);
            requests.push(Request::query(
                format!("PositionerSGammaParametersGet ({positioner},double *,double *,double *,double *)"),
                Step::Jerk { channel },
            ));
            requests.push(Request::query(
                format!("PositionerUserTravelLimitsGet ({positioner},double *,double *)"),
                Step::Travel { channel },
            ));
        }
        if !std::mem::replace(&mut self.initialised_at_start, true) {
            for &channel in channels {
                requests.push(Request::query(self.state_query(channel), Step::PowerUp { channel }));
            }
        }
        requests
    }

    fn sync(&mut self) -> Option<Request<Step>> {
        self.identity.next()?;
        Some(Request::query("FirmwareVersionGet (char *)", Step::Firmware))
    }

    /// The firmware, "XPS-C8 Firmware V2.6.x", as read at connection.
    fn is_sync_reply(&self, frame: &[u8]) -> bool {
        split_reply(frame).is_some_and(|(code, outputs)| code == 0 && self.identity.is_answer(&outputs.join(",")))
    }

    fn poll(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        let mut requests = Vec::new();
        for &channel in channels {
            let (group, positioner) = (self.group(channel), self.positioner(channel));
            let readings = [
                (format!("GroupStatusGet ({group},int *)"), Reading::GroupState),
                (format!("GroupVelocityCurrentGet ({positioner},double *)"), Reading::Velocity),
                (format!("GroupPositionCurrentGet ({positioner},double *)"), Reading::Current),
                (format!("GroupPositionSetpointGet ({positioner},double *)"), Reading::Setpoint),
                (format!("PositionerErrorGet ({positioner},int *)"), Reading::PositionerError),
            ];
            for (text, reading) in readings {
                requests.push(Request::query(text, Step::Read { channel, reading }));
            }
        }
        requests
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        self.command_requests(channel, command)
    }

    fn scale(&self, _channel: usize) -> Scale {
        let unit = match (Unit::parse("mm"), Unit::parse("deg")) {
            (Some(linear), Some(rotary)) => ControllerUnit::Physical { linear, rotary },
            _ => ControllerUnit::Steps,
        };
        Scale { units_per_step: self.units_per_step, unit, source: self.source }
    }

    fn reply(&mut self, request: &Request<Step>, frame: &[u8]) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let error = |why| ReplyError::new(request, frame, why);
        let (code, outputs) = split_reply(frame).ok_or_else(|| error("not an XPS reply"))?;
        let call = String::from_utf8_lossy(&request.bytes).into_owned();
        match request.step {
            // Aborted by a stop (or a new motion of the record's): the stop said all there is.
            Step::Motion { .. } if code == MOTION_ABORTED => return Ok(Vec::new()),
            Step::Abort { .. } if code == NOT_ALLOWED => return Ok(Vec::new()),
            _ => {}
        }
        if code != 0 {
            let channel = match request.step {
                Step::Firmware => None,
                Step::Jerk { channel }
                | Step::Travel { channel }
                | Step::PowerUp { channel }
                | Step::PowerUpCall { channel }
                | Step::Read { channel, .. }
                | Step::StateFor { channel, .. }
                | Step::Command { channel }
                | Step::Abort { channel }
                | Step::Motion { channel } => Some(channel),
            };
            if matches!(Self::purpose(request.step), Purpose::Init) || matches!(request.step, Step::Read { .. }) {
                // A reading the controller refuses (a group system.ini lacks): the link is of no use.
                return Err(error("the controller refused the reading"));
            }
            let meaning = format!("{} (to {call})", meaning(code));
            let error = VendorError { channel, code: code.to_string(), meaning };
            // A step of a command refused: the rest of it is not sent. A motion call's answer
            // comes when the motion ended: nothing is left to cut short.
            return Ok(vec![if matches!(request.step, Step::Motion { .. }) {
                ReplyEvent::ControllerError(error)
            } else {
                ReplyEvent::Refused(error)
            }]);
        }
        let number = |i: usize| -> Result<f64, ReplyError> {
            outputs
                .get(i)
                .and_then(|v| v.parse::<f64>().ok())
                .filter(|v| v.is_finite())
                .ok_or_else(|| error("not a number"))
        };
        match request.step {
            Step::Firmware => {
                self.identity.read(0, &outputs.join(","));
                Ok(vec![ReplyEvent::Found(Finding::Identity(outputs.join(",")))])
            }
            Step::Jerk { channel } => {
                let (min, max) = (number(2)?, number(3)?);
                self.axis(channel).jerk = Some((min, max));
                Ok(Vec::new())
            }
            Step::Travel { channel } => {
                Ok(vec![ReplyEvent::Found(Finding::Travel { channel, min: number(0)?, max: number(1)? })])
            }
            Step::Read { channel, reading } => Ok(self.read(channel, reading, number(0)?).into_iter().collect()),
            Step::PowerUp { channel } if number(0)? as i32 == POWERED_UP => {
                let call = format!("GroupInitialize ({})", self.group(channel));
                Ok(vec![ReplyEvent::FollowUp(vec![Request::query(call, Step::PowerUpCall { channel })])])
            }
            Step::PowerUp { .. } | Step::PowerUpCall { .. } => Ok(Vec::new()),
            Step::StateFor { channel, then } => {
                let state = number(0)? as i32;
                Ok(vec![ReplyEvent::FollowUp(self.after_state(channel, state, then))])
            }
            Step::Command { .. } | Step::Abort { .. } | Step::Motion { .. } => Ok(Vec::new()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_go_out_as_c_writes_them_with_13_significant_digits() {
        assert_eq!(c_g13(10.5), "10.5");
        assert_eq!(c_g13(-0.0001), "-0.0001");
        assert_eq!(c_g13(0.00001), "1e-05");
        assert_eq!(c_g13(1.0 / 3.0), "0.3333333333333");
        assert_eq!(c_g13(25.0), "25");
        assert_eq!(c_g13(1e13), "1e+13");
        assert_eq!(c_g13(123456.0001), "123456.0001");
    }

    #[test]
    fn the_launch_files_positioner_names_are_the_calls_names() {
        let names = [(1, "FINE.X".to_string())].into();
        let mut xps = Xps::new(&ProtocolOptions { names, ..ProtocolOptions::default() });
        let text = |requests: Vec<Request<Step>>| -> Vec<String> {
            requests.iter().map(|r| String::from_utf8_lossy(&r.bytes).into_owned()).collect()
        };
        let polled = text(xps.poll(&[1, 2]));
        assert_eq!(polled[..2], ["GroupStatusGet (FINE,int *)", "GroupVelocityCurrentGet (FINE.X,double *)"]);
        assert_eq!(polled[5], "GroupStatusGet (GROUP2,int *)", "a channel not named keeps its default");
        let stop = xps.command(1, &DriverCommand::Stop { acceleration: 1.0 }).expect("a stop");
        assert_eq!(text(stop), ["GroupStatusGet (FINE,int *)"]);
        let set = xps.command(1, &DriverCommand::SetPosition { position: 10.0 }).expect("a set position");
        assert_eq!(text(set)[3], "GroupReferencingActionExecute (FINE.X,SetPosition,None,0.001)");
        // Two positioners of one group: a set position would re-initialise the other one too.
        let names = [(1, "FINE.X".to_string()), (2, "FINE.Y".to_string())].into();
        let mut shared = Xps::new(&ProtocolOptions { names, ..ProtocolOptions::default() });
        let refused = shared.command(2, &DriverCommand::SetPosition { position: 10.0 });
        assert!(matches!(refused, Err(CommandError::Unsupported { .. })), "{refused:?}");
    }

    #[test]
    fn replies_are_read_with_or_without_an_empty_output() {
        assert_eq!(split_reply(b"0,EndOfAPI"), Some((0, vec![])));
        assert_eq!(split_reply(b"0,,EndOfAPI"), Some((0, vec![])));
        assert_eq!(split_reply(b"0,12,EndOfAPI"), Some((0, vec!["12"])));
        assert_eq!(split_reply(b"-17,EndOfAPI"), Some((-17, vec![])));
        assert_eq!(split_reply(b"garbage"), None);
    }
}
