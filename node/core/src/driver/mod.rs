//! The driver trait: the shape of the motor record's driver interface, in raw units (steps,
//! steps/s, steps/s²). Time is injected: a driver is told the clock advanced, never reads it.

pub(crate) mod sim;
pub(crate) mod soft;

use crate::engine::DeviceStatus;
use crate::time::Instant;
use zmotor_msgs::{DriverCommand, Gain};

/// A motor controller axis as the record's device support drives it (spec §15.5).
pub trait Driver: Send + Sync {
    /// The clock advanced to `now`; a physical model integrates up to it.
    fn advance(&mut self, now: Instant);
    /// Absolute move to `position`, or relative move by `position` steps.
    fn move_to(&mut self, position: f64, relative: bool, min_velocity: f64, max_velocity: f64, acceleration: f64);
    /// Constant-velocity motion; `velocity` is signed.
    fn move_velocity(&mut self, min_velocity: f64, velocity: f64, acceleration: f64);
    /// Search for home, forwards or backwards.
    fn home(&mut self, forward: bool, min_velocity: f64, max_velocity: f64, acceleration: f64);
    /// Decelerate to a stop.
    fn stop(&mut self, acceleration: f64);
    /// Redefine the current position without moving.
    fn set_position(&mut self, position: f64);
    /// Closed-loop control (the amplifier) on or off.
    fn enable(&mut self, on: bool);
    /// Encoder counts per motor step (MRES/ERES).
    fn set_encoder_ratio(&mut self, ratio: f64);
    /// The controller's own high soft limit, steps.
    fn set_high_limit(&mut self, position: f64);
    /// The controller's own low soft limit, steps.
    fn set_low_limit(&mut self, position: f64);
    /// A PID gain, 0 to 1.
    fn set_gain(&mut self, gain: Gain, value: f64);
    /// A command primitive (INIT/PREM/POST text).
    fn raw(&mut self, text: &str);
    /// The status as of the last `advance`.
    fn status(&self) -> DeviceStatus;
    /// When the status will next change by itself (the end of a motion), if known, so that
    /// completion is reported when it happens rather than at the next poll.
    fn next_event(&self) -> Option<Instant>;
    /// The simulator behind this driver, if it is one (fault injection, physical state).
    fn simulation(&mut self) -> Option<&mut sim::SimAxis> {
        None
    }
}

/// Deliver one command to a driver.
pub(crate) fn execute(driver: &mut dyn Driver, command: &DriverCommand) {
    match command {
        DriverCommand::Move { position, relative, min_velocity, max_velocity, acceleration } => {
            driver.move_to(*position, *relative, *min_velocity, *max_velocity, *acceleration)
        }
        DriverCommand::MoveVelocity { min_velocity, max_velocity, acceleration } => {
            driver.move_velocity(*min_velocity, *max_velocity, *acceleration)
        }
        DriverCommand::Home { forward, min_velocity, max_velocity, acceleration } => {
            driver.home(*forward, *min_velocity, *max_velocity, *acceleration)
        }
        DriverCommand::Stop { acceleration } => driver.stop(*acceleration),
        DriverCommand::SetPosition { position } => driver.set_position(*position),
        DriverCommand::Enable { on } => driver.enable(*on),
        DriverCommand::SetEncoderRatio { ratio } => driver.set_encoder_ratio(*ratio),
        DriverCommand::SetHighLimit { position } => driver.set_high_limit(*position),
        DriverCommand::SetLowLimit { position } => driver.set_low_limit(*position),
        DriverCommand::SetGain { gain, value } => driver.set_gain(*gain, *value),
        // Status is read after every transaction that asks for it; nothing to send.
        DriverCommand::Poll => {}
        DriverCommand::Raw { text } => driver.raw(text),
    }
}
