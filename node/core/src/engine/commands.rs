//! What flows into and out of the engine, as plain data.

use std::time::Duration;
use zmotor_msgs::{Field, RefusalKind, Value};

/// A record-level device command (the reference's `motor_cmnd`), in raw units. Not
/// `#[non_exhaustive]`: each is an action device support must carry out, and a new one must stop
/// the build of one that would drop it.
#[derive(Clone, Debug, PartialEq)]
pub enum MotorCommand {
    /// Stage an absolute move to this raw position (sent at GO).
    MoveAbs(f64),
    /// Stage a relative move by this many steps (sent at GO).
    MoveRel(f64),
    /// Stage a home search forwards (sent at GO).
    HomeFor,
    /// Stage a home search backwards (sent at GO).
    HomeRev,
    /// Redefine the controller's position, steps.
    LoadPos(f64),
    /// Base velocity of the next motion, steps/s.
    SetVelBase(f64),
    /// Slew velocity of the next motion, steps/s.
    SetVelocity(f64),
    /// Acceleration of the next motion, steps/s².
    SetAccel(f64),
    /// Start the staged move or home.
    Go,
    /// `[encoder counts, motor steps]` for a common length.
    SetEncRatio(f64, f64),
    /// Refresh the status (a status callback follows).
    GetInfo,
    /// Stop the motion.
    StopAxis,
    /// Move at this signed velocity until stopped, steps/s.
    Jog(f64),
    /// Proportional gain, 0 to 1.
    SetPGain(f64),
    /// Integral gain, 0 to 1.
    SetIGain(f64),
    /// Derivative gain, 0 to 1.
    SetDGain(f64),
    /// Closed-loop control on.
    EnableTorque,
    /// Closed-loop control off.
    DisableTorque,
    /// The controller's high limit, steps.
    SetHighLimit(f64),
    /// The controller's low limit, steps.
    SetLowLimit(f64),
    /// Change the velocity of a running jog, steps/s.
    JogVelocity(f64),
}

/// Status reported by a driver, in raw units, as device support receives it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DeviceStatus {
    /// Motor (step) position, steps.
    pub position: f64,
    /// Encoder position, counts.
    pub encoder_position: f64,
    /// Actual velocity, steps/s.
    pub velocity: f64,
    /// MSTA bits (see `zmotor_msgs::bits::msta`).
    pub msta: u32,
    /// The value of the RDBL readback link, if the record has one and it can be read.
    pub readback: Option<f64>,
}

/// Something the engine asks of the world, in the order it happened. Not `#[non_exhaustive]`:
/// each is an action the caller must carry out, and a new one must stop the build of a caller
/// that would drop it.
#[derive(Clone, Debug, PartialEq)]
pub enum Output {
    /// A monitor post: the field changed (or must be re-posted).
    Post(Field, Value),
    /// One transaction to the device, delivered together and in order.
    Transaction(Vec<MotorCommand>),
    /// Start (or restart) the DLY settling timer; call `delay_expired` when it has run.
    StartDelay(Duration),
    /// The processing ended with DMOV = 1: fire the forward link and complete waiting writes.
    Done,
    /// A processing of a disabled record: waiting writes complete (as dbProcess notifies a
    /// put-callback's completion); no forward link, and a motion under way goes on.
    WritesCompleted,
    /// RBV to be written to the RLNK link.
    ReadbackLink(f64),
}

/// Why a write was refused or changed.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum WriteError {
    /// The field cannot be written.
    #[error("{0} is read-only")]
    ReadOnly(Field),
    /// The record refused the value (special() before the store): nothing changed.
    #[error("{field} refused: {reason}")]
    Refused {
        /// The field written.
        field: Field,
        /// Why.
        reason: Busy,
    },
    /// The record refused a value it cannot work with (special() before the store): nothing
    /// changed.
    #[error("{field} refused: {reason}")]
    Unusable {
        /// The field written.
        field: Field,
        /// What is wrong with the value.
        reason: Unusable,
    },
    /// The record stored a corrected value instead, and did not process.
    #[error("{field} adjusted: {reason}")]
    Adjusted {
        /// The field written.
        field: Field,
        /// What was corrected.
        reason: Adjustment,
    },
    /// Departure Z25: the record is disabled (DISA = DISV) and the write would start a motion
    /// once it is enabled (a target, a jog or home button, SPMG Move or Go): nothing changed.
    #[error("{field} refused: the record is disabled (DISA = DISV); nothing changed")]
    RecordDisabled {
        /// The field written.
        field: Field,
    },
    /// Accepted and processed, but the record would not act on it (a soft-limit violation,
    /// a home against an active switch, ...); the drive fields went back.
    #[error("{field}: {reason}")]
    NotActedUpon {
        /// The field written.
        field: Field,
        /// Why the record did not act.
        reason: Inaction,
    },
}

impl WriteError {
    /// What kind of refusal this is, as clients are told.
    pub fn kind(&self) -> RefusalKind {
        match self {
            WriteError::ReadOnly(_) => RefusalKind::ReadOnly,
            WriteError::Refused { .. } => RefusalKind::Busy,
            WriteError::Unusable { .. } => RefusalKind::BadValue,
            WriteError::Adjusted { .. } => RefusalKind::Adjusted,
            WriteError::NotActedUpon { reason, .. } => reason.kind(),
            WriteError::RecordDisabled { .. } => RefusalKind::RecordDisabled,
        }
    }
}

/// Why the record cannot take a value now (special() before the store).
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Busy {
    /// Departure Z12: a target written while a jog takes out its backlash would be forgotten.
    #[error("a jog is finishing its backlash takeout; write the target once DMOV is 1")]
    JogBacklashTakeout,
    /// A home button written while a home runs.
    #[error("a home is in progress")]
    HomeInProgress,
    /// Departure Z15: 0 written to a home button; a home is aborted with STOP.
    #[error("writing 0 does not abort a home; write STOP 1")]
    ZeroDoesNotAbortHome,
    /// STUP written while a status update runs.
    #[error("a status update is in progress")]
    StatusUpdateInProgress,
}

/// A value the record refuses whatever its state (special() before the store).
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Unusable {
    /// Departure Z21: MRES 0, or UREV 0 (MRES = UREV / SREV). The reference stores it, zeroes the
    /// speeds and the soft limits, and every position becomes infinitely many steps.
    #[error("a resolution of 0 makes every position infinitely many steps")]
    ZeroResolution,
}

impl Unusable {
    /// Why the record refuses `value` for `field` whatever its state, if it does: written, or
    /// given in a launch file or a saved state.
    pub fn of(field: Field, value: &Value) -> Option<Self> {
        match field {
            Field::MRES | Field::UREV if value.as_f64() == Some(0.0) => Some(Unusable::ZeroResolution),
            _ => None,
        }
    }
}

/// What the record corrected instead of storing the value written.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Adjustment {
    /// STUP takes ON only; anything else leaves it OFF.
    #[error("only ON may be written; STUP stays OFF")]
    StupStaysOff,
    /// NTMF below 2 became 2.
    #[error("NTMF must be at least 2; set to 2")]
    NtmfRaisedTo2,
}

/// Why the record processed a write but did not act on it.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Inaction {
    /// The dial target is beyond the soft limits (or DLLM > DHLM).
    #[error("limit violation: dial target {dial_target} is outside the soft limits [{dllm}, {dhlm}] (DLLM, DHLM)")]
    SoftLimits {
        /// The dial target written.
        dial_target: f64,
        /// The dial low limit.
        dllm: f64,
        /// The dial high limit.
        dhlm: f64,
    },
    /// A jog would reach a soft limit within one second of travel.
    #[error("limit violation: jog refused within one second of travel of a soft limit")]
    JogNearSoftLimit,
    /// Departure Z11: a servo whose closed-loop control is off (CNEN = Disable).
    #[error("motor disabled: closed-loop control is off (CNEN = Disable); write CNEN Enable first")]
    Disabled,
    /// Departure Z6: a home toward a limit switch that is active.
    #[error("home ({button}) refused: the {switch} limit switch is active")]
    SwitchActive {
        /// The home button written (HOMF or HOMR).
        button: Field,
        /// The switch in its way.
        switch: LimitSwitch,
    },
    /// Departure Z20: a target whose raw position the driver cannot hold (32 bits, as RVAL).
    #[error(
        "target out of range: dial target {dial_target} at MRES {mres} is {steps} steps, beyond the 32-bit raw \
         position"
    )]
    TargetBeyondRawRange {
        /// The dial target written.
        dial_target: f64,
        /// The motor resolution.
        mres: f64,
        /// The target in whole steps.
        steps: f64,
    },
    /// Departure Z20: a position to set that the driver cannot hold.
    #[error("the position is not set: dial {dial} at MRES {mres} is {steps} steps, beyond the 32-bit raw position")]
    PositionBeyondRawRange {
        /// The dial position to set.
        dial: f64,
        /// The motor resolution.
        mres: f64,
        /// The position in whole steps.
        steps: f64,
    },
    /// The move depends on the readback link, which has no value.
    #[error("the readback link RDBL ({link}) cannot be read")]
    ReadbackUnreadable {
        /// The key RDBL names.
        link: String,
    },
}

impl Inaction {
    /// What kind of refusal this is, as clients are told.
    pub fn kind(&self) -> RefusalKind {
        match self {
            Inaction::SoftLimits { .. } | Inaction::JogNearSoftLimit => RefusalKind::LimitViolation,
            Inaction::Disabled => RefusalKind::Disabled,
            Inaction::SwitchActive { .. } => RefusalKind::SwitchActive,
            Inaction::TargetBeyondRawRange { .. } | Inaction::PositionBeyondRawRange { .. } => {
                RefusalKind::BeyondRawRange
            }
            Inaction::ReadbackUnreadable { .. } => RefusalKind::ReadbackUnreadable,
        }
    }
}

/// One of the two limit switches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LimitSwitch {
    /// The high limit switch (HLS).
    High,
    /// The low limit switch (LLS).
    Low,
}

impl std::fmt::Display for LimitSwitch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            LimitSwitch::High => "high",
            LimitSwitch::Low => "low",
        })
    }
}
