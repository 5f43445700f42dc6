//! What flows into and out of the engine, as plain data.

use std::time::Duration;
use zmotor_msgs::{Field, Value};

/// A record-level device command (the reference's `motor_cmnd`), in raw units.
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

/// Something the engine asks of the world, in the order it happened.
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
    /// RBV to be written to the RLNK link.
    ReadbackLink(f64),
}

/// Why a write was refused or changed.
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
        reason: String,
    },
    /// The record stored a corrected value instead, and did not process.
    #[error("{field} adjusted: {reason}")]
    Adjusted {
        /// The field written.
        field: Field,
        /// What was corrected.
        reason: String,
    },
    /// Accepted and processed, but the record would not act on it (a soft-limit violation,
    /// a home against an active switch, ...); the drive fields went back.
    #[error("{field}: {reason}")]
    NotActedUpon {
        /// The field written.
        field: Field,
        /// Why the record did not act.
        reason: String,
    },
}
