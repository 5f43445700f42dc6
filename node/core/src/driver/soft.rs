//! Soft Channel device support (spec §16): a soft motor drives another key and reads its
//! position back from keys. A move writes DVAL to OUT; STOP writes 1 to STOO; RDBL (with URIP),
//! RINP and DINP bring the readback, the raw position and "done" back; LOCK stops the
//! re-synchronisation when the driven motor moves on its own.

use crate::engine::{DeviceStatus, MotorCommand};
use zmotor_msgs::bits::msta;
use zmotor_msgs::Field;

/// Where the driven motor stands, as DINP tells.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum DriveState {
    /// We started a motion of the driven motor.
    SoftMove,
    /// The driven motor moves, started by someone else.
    HardMove,
    /// Nobody moves it.
    Done,
}

/// Which input link an update arrived on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum InputLink {
    /// RDBL: the readback, in RRES units.
    Readback,
    /// RINP: the raw motor position, steps.
    RawPosition,
    /// DINP: the driven motor's done flag.
    Done,
    /// DOL: the desired value in closed-loop mode.
    Desired,
    /// SDIS: the value DISA takes (the record is disabled while it equals DISV).
    Disable,
}

impl InputLink {
    /// Every input link.
    pub const ALL: [InputLink; 5] =
        [InputLink::Readback, InputLink::RawPosition, InputLink::Done, InputLink::Desired, InputLink::Disable];

    /// The link field that names its key.
    pub fn field(self) -> Field {
        match self {
            InputLink::Readback => Field::RDBL,
            InputLink::RawPosition => Field::RINP,
            InputLink::Done => Field::DINP,
            InputLink::Desired => Field::DOL,
            InputLink::Disable => Field::SDIS,
        }
    }

    /// The input link a field names the key of, if it is one.
    pub fn of(field: Field) -> Option<InputLink> {
        InputLink::ALL.into_iter().find(|link| link.field() == field)
    }
}

#[derive(Clone, Debug)]
/// Soft Channel device support of one axis (see the module documentation).
pub(crate) struct SoftChannel {
    out: String,
    stop_out: String,
    has_done_input: bool,
    state: DriveState,
    /// The first RDBL update has been seen (the target is reset to it once).
    initialized: bool,
    raw_position: f64,
}

/// What the axis must do after a link update.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Reaction {
    /// Process the record with the new status.
    Callback,
    /// The driven motor started moving on its own: mark an external motion, then nothing.
    ExternalMotion,
    /// Mark an external motion (first readback), then process.
    ExternalMotionThenCallback,
    /// Nothing to do.
    Nothing,
}

impl SoftChannel {
    /// `out`, `stop_out` and `done_input` are the OUT, STOO and DINP keys ("" when unset);
    /// `dmov` is DMOV at boot.
    pub(crate) fn new(out: &str, stop_out: &str, done_input: &str, dmov: i16) -> Self {
        Self {
            out: out.to_string(),
            stop_out: stop_out.to_string(),
            has_done_input: !done_input.is_empty(),
            state: if dmov == 0 { DriveState::SoftMove } else { DriveState::Done },
            initialized: false,
            raw_position: 0.0,
        }
    }

    /// The OUT, STOO and DINP keys changed at run time ("" when unset).
    pub(crate) fn relink(&mut self, out: &str, stop_out: &str, done_input: &str) {
        self.out = out.to_string();
        self.stop_out = stop_out.to_string();
        self.has_done_input = !done_input.is_empty();
    }

    /// The status the record reads: the raw position and, from DINP, whether it is done.
    pub(crate) fn status(&self) -> DeviceStatus {
        let done = !self.has_done_input || self.state == DriveState::Done;
        DeviceStatus { position: self.raw_position, msta: if done { msta::DONE } else { 0 }, ..DeviceStatus::default() }
    }

    /// The puts one transaction makes (key, value) and whether a callback follows (LOAD_POS).
    /// Every move leg writes the final dial target: intermediate positions are never sent.
    pub(crate) fn translate(&mut self, transaction: &[MotorCommand], dval: f64) -> (Vec<(String, f64)>, bool) {
        let mut puts = Vec::new();
        let mut callback = false;
        for command in transaction {
            match command {
                MotorCommand::MoveAbs(_) | MotorCommand::MoveRel(_) if !self.out.is_empty() => {
                    puts.push((self.out.clone(), dval))
                }
                MotorCommand::StopAxis if !self.stop_out.is_empty() => puts.push((self.stop_out.clone(), 1.0)),
                MotorCommand::LoadPos(_) => callback = true,
                _ => {}
            }
        }
        (puts, callback)
    }

    /// A link update (§16.2). `dmov` and `locked` are the record's DMOV and LOCK, `mres` its MRES.
    pub(crate) fn update(&mut self, link: InputLink, value: f64, dmov: i16, locked: bool, mres: f64) -> Reaction {
        match link {
            InputLink::Readback => {
                self.raw_position = (value / mres).round();
                if std::mem::replace(&mut self.initialized, true) {
                    Reaction::Callback
                } else {
                    self.state = DriveState::Done;
                    Reaction::ExternalMotionThenCallback
                }
            }
            InputLink::RawPosition => {
                self.raw_position = value;
                Reaction::Callback
            }
            InputLink::Done if value == 0.0 => {
                if dmov == 0 {
                    self.state = DriveState::SoftMove;
                    Reaction::Nothing
                } else if !locked {
                    self.state = DriveState::HardMove;
                    Reaction::ExternalMotion
                } else {
                    Reaction::Nothing
                }
            }
            InputLink::Done => {
                self.state = DriveState::Done;
                Reaction::Callback
            }
            InputLink::Desired | InputLink::Disable => Reaction::Nothing,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moves_write_the_dial_target_and_stop_writes_stoo() {
        let mut soft = SoftChannel::new("calc/A", "motor/lin/STOP", "motor/lin/DMOV", 1);
        let (puts, cb) =
            soft.translate(&[MotorCommand::SetVelocity(1.0), MotorCommand::MoveAbs(72.0), MotorCommand::Go], 96.0);
        assert_eq!((puts, cb), (vec![("calc/A".to_string(), 96.0)], false));
        let (puts, _) = soft.translate(&[MotorCommand::StopAxis], 96.0);
        assert_eq!(puts, vec![("motor/lin/STOP".to_string(), 1.0)]);
        assert_eq!(soft.translate(&[MotorCommand::LoadPos(5.0)], 0.0), (vec![], true));
        assert_eq!(soft.translate(&[MotorCommand::GetInfo, MotorCommand::Jog(3.0)], 0.0), (vec![], false));
    }

    #[test]
    fn done_input_tracks_who_moves_the_driven_motor() {
        let mut soft = SoftChannel::new("o", "s", "d", 1);
        assert_eq!(soft.update(InputLink::Readback, 0.5, 1, false, 0.001), Reaction::ExternalMotionThenCallback);
        assert_eq!(soft.status().position, 500.0);
        assert_eq!(soft.update(InputLink::Readback, 0.6, 1, false, 0.001), Reaction::Callback);
        // Our own move: DMOV is 0.
        assert_eq!(soft.update(InputLink::Done, 0.0, 0, false, 0.001), Reaction::Nothing);
        assert_eq!(soft.status().msta & msta::DONE, 0);
        assert_eq!(soft.update(InputLink::Done, 1.0, 0, false, 0.001), Reaction::Callback);
        assert_ne!(soft.status().msta & msta::DONE, 0);
        // Someone else's move, unlocked and locked.
        assert_eq!(soft.update(InputLink::Done, 0.0, 1, false, 0.001), Reaction::ExternalMotion);
        assert_eq!(soft.update(InputLink::Done, 1.0, 1, false, 0.001), Reaction::Callback);
        assert_eq!(soft.update(InputLink::Done, 0.0, 1, true, 0.001), Reaction::Nothing);
        // Without DINP the driven motor always looks done.
        let soft = SoftChannel::new("o", "", "", 1);
        assert_ne!(soft.status().msta & msta::DONE, 0);
    }
}
