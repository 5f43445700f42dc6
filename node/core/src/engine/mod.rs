//! The sans-IO motor record engine: events in (field writes, device status, the DLY timer),
//! outputs out (monitor posts, device transactions, timer requests, completion). No clock, no I/O.

mod commands;
mod marks;
mod maths;
mod record;

pub use commands::{Adjustment, Busy, DeviceStatus, Inaction, LimitSwitch, MotorCommand, Output, Unusable, WriteError};
pub use maths::nint;
pub use record::MotorRecord;

#[cfg(test)]
mod tests;
