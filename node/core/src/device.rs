//! Device support: turns the record's transactions (SET_VELOCITY, MOVE_ABS, GO, ...) into calls
//! of the driver trait, the way the asyn ("model 3") device support does: velocities and
//! acceleration are stored parameters, moves and homes are staged until GO, and a transaction
//! that starts something (GO, JOG, LOAD_POS, GET_INFO) is followed by a status callback.

use crate::engine::MotorCommand;
use zmotor_msgs::{DriverCommand, Gain};

#[derive(Clone, Copy, Debug)]
enum Staged {
    Move { position: f64, relative: bool },
    Home { forward: bool },
}

/// Per-axis device-support state: the last base velocity, velocity and acceleration written
/// (a transaction without SET_VEL_BASE reuses the last one) and a staged move or home.
#[derive(Clone, Debug, Default)]
pub(crate) struct DeviceSupport {
    vel_base: f64,
    velocity: f64,
    accel: f64,
    staged: Option<Staged>,
}

/// The driver commands of one transaction, and whether the record must then be processed with
/// fresh status.
#[derive(Debug, Default, PartialEq)]
pub(crate) struct Translation {
    /// The driver commands, in order.
    pub commands: Vec<DriverCommand>,
    /// The record must be processed with fresh status after them.
    pub wants_callback: bool,
}

impl DeviceSupport {
    /// Translate one transaction of the record into driver commands.
    pub(crate) fn translate(&mut self, transaction: &[MotorCommand]) -> Translation {
        let mut out = Translation::default();
        for command in transaction {
            let driver_command = match *command {
                MotorCommand::SetVelBase(v) => {
                    self.vel_base = v;
                    None
                }
                MotorCommand::SetVelocity(v) => {
                    self.velocity = v;
                    None
                }
                MotorCommand::SetAccel(a) => {
                    self.accel = a;
                    None
                }
                MotorCommand::MoveAbs(position) => {
                    self.staged = Some(Staged::Move { position, relative: false });
                    None
                }
                MotorCommand::MoveRel(position) => {
                    self.staged = Some(Staged::Move { position, relative: true });
                    None
                }
                MotorCommand::HomeFor | MotorCommand::HomeRev => {
                    self.staged = Some(Staged::Home { forward: *command == MotorCommand::HomeFor });
                    None
                }
                MotorCommand::Go => {
                    out.wants_callback = true;
                    self.staged.take().map(|staged| match staged {
                        Staged::Move { position, relative } => DriverCommand::Move {
                            position,
                            relative,
                            min_velocity: self.vel_base,
                            max_velocity: self.velocity,
                            acceleration: self.accel,
                        },
                        Staged::Home { forward } => DriverCommand::Home {
                            forward,
                            min_velocity: self.vel_base,
                            max_velocity: self.velocity,
                            acceleration: self.accel,
                        },
                    })
                }
                MotorCommand::Jog(v) | MotorCommand::JogVelocity(v) => {
                    out.wants_callback = true;
                    Some(DriverCommand::MoveVelocity {
                        min_velocity: self.vel_base,
                        max_velocity: v,
                        acceleration: self.accel,
                    })
                }
                MotorCommand::StopAxis => Some(DriverCommand::Stop { acceleration: self.accel }),
                MotorCommand::LoadPos(position) => {
                    out.wants_callback = true;
                    Some(DriverCommand::SetPosition { position })
                }
                MotorCommand::GetInfo => {
                    out.wants_callback = true;
                    Some(DriverCommand::Poll)
                }
                MotorCommand::SetEncRatio(encoder, motor) => {
                    Some(DriverCommand::SetEncoderRatio { ratio: encoder / motor })
                }
                MotorCommand::SetPGain(value) => Some(DriverCommand::SetGain { gain: Gain::Proportional, value }),
                MotorCommand::SetIGain(value) => Some(DriverCommand::SetGain { gain: Gain::Integral, value }),
                MotorCommand::SetDGain(value) => Some(DriverCommand::SetGain { gain: Gain::Derivative, value }),
                MotorCommand::EnableTorque => Some(DriverCommand::Enable { on: true }),
                MotorCommand::DisableTorque => Some(DriverCommand::Enable { on: false }),
                MotorCommand::SetHighLimit(position) => Some(DriverCommand::SetHighLimit { position }),
                MotorCommand::SetLowLimit(position) => Some(DriverCommand::SetLowLimit { position }),
            };
            out.commands.extend(driver_command);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use MotorCommand::*;

    #[test]
    fn a_move_is_staged_until_go_with_the_stored_speeds() {
        let mut dev = DeviceSupport::default();
        let t = dev.translate(&[SetVelocity(100.0), SetVelBase(10.0), SetAccel(200.0), MoveAbs(150.0), Go]);
        assert!(t.wants_callback);
        assert_eq!(
            t.commands,
            vec![DriverCommand::Move {
                position: 150.0,
                relative: false,
                min_velocity: 10.0,
                max_velocity: 100.0,
                acceleration: 200.0
            }]
        );
        // The final backlash leg sends no SET_VEL_BASE: the last one is reused.
        let t = dev.translate(&[SetVelocity(50.0), MoveRel(-5.0), Go]);
        assert_eq!(
            t.commands,
            vec![DriverCommand::Move {
                position: -5.0,
                relative: true,
                min_velocity: 10.0,
                max_velocity: 50.0,
                acceleration: 200.0
            }]
        );
    }

    #[test]
    fn jog_home_stop_and_set_position() {
        let mut dev = DeviceSupport::default();
        let t = dev.translate(&[SetVelBase(0.0), SetAccel(400.0), Jog(-200.0)]);
        assert_eq!(
            t.commands,
            vec![DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -200.0, acceleration: 400.0 }]
        );
        let t = dev.translate(&[StopAxis]);
        assert_eq!((t.commands, t.wants_callback), (vec![DriverCommand::Stop { acceleration: 400.0 }], false));
        let t = dev.translate(&[SetVelocity(50.0), SetVelBase(10.0), SetAccel(80.0), HomeRev, Go]);
        assert_eq!(
            t.commands,
            vec![DriverCommand::Home { forward: false, min_velocity: 10.0, max_velocity: 50.0, acceleration: 80.0 }]
        );
        let t = dev.translate(&[LoadPos(1250.0)]);
        assert_eq!((t.commands, t.wants_callback), (vec![DriverCommand::SetPosition { position: 1250.0 }], true));
        let t = dev.translate(&[SetEncRatio(1.0, 1.0), SetHighLimit(1000.0)]);
        assert_eq!(
            t.commands,
            vec![DriverCommand::SetEncoderRatio { ratio: 1.0 }, DriverCommand::SetHighLimit { position: 1000.0 }]
        );
    }
}
