//! What flows into and out of the engine, as plain data.

use std::time::Duration;
use zmotor_msgs::{Field, Value};

/// A record-level device command (the reference's `motor_cmnd`), in raw units.
#[derive(Clone, Debug, PartialEq)]
pub enum MotorCommand {
    MoveAbs(f64),
    MoveRel(f64),
    HomeFor,
    HomeRev,
    LoadPos(f64),
    SetVelBase(f64),
    SetVelocity(f64),
    SetAccel(f64),
    Go,
    /// `[encoder counts, motor steps]` for a common length.
    SetEncRatio(f64, f64),
    GetInfo,
    StopAxis,
    Jog(f64),
    SetPGain(f64),
    SetIGain(f64),
    SetDGain(f64),
    EnableTorque,
    DisableTorque,
    SetHighLimit(f64),
    SetLowLimit(f64),
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
    #[error("{0} is read-only")]
    ReadOnly(Field),
    #[error("{field} refused: {reason}")]
    Refused { field: Field, reason: String },
    #[error("{field} adjusted: {reason}")]
    Adjusted { field: Field, reason: String },
    /// Accepted and processed, but the record would not act on it (a soft-limit violation,
    /// a home against an active switch, ...); the drive fields went back.
    #[error("{0}")]
    NotActedUpon(String),
}
