//! The command sequences of §15.2 that start motion: move legs (T1–T4), home (T5), jog (T6).

use super::MotorRecord;
use crate::engine::commands::MotorCommand;
use crate::engine::maths::MoveMaths;
use zmotor_msgs::Field;

impl MotorRecord {
    /// Send one move leg (T1–T4). Departure Z7: CDIR is the direction this leg actually
    /// travels (the reference uses the direction to the final target, Q15). Departure Z10:
    /// a leg that starts within the soft limits never ends beyond them (FRAC > 1).
    pub(super) fn send_leg(&mut self, leg: Leg) {
        let position = self.keep_within_soft_limits(leg.position, leg.relative);
        let here = self.f.drbv / self.f.mres;
        let upwards = if leg.relative { position >= 0.0 } else { position >= here };
        self.f.cdir = i16::from(upwards);
        let mut txn = vec![MotorCommand::SetVelocity(leg.velocity)];
        txn.extend(leg.base.map(MotorCommand::SetVelBase));
        if leg.accel > 0.0 {
            txn.push(MotorCommand::SetAccel(leg.accel));
        }
        txn.push(if leg.relative { MotorCommand::MoveRel(position) } else { MotorCommand::MoveAbs(position) });
        txn.push(MotorCommand::Go);
        self.send(txn);
    }

    pub(super) fn keep_within_soft_limits(&self, position: f64, relative: bool) -> f64 {
        let f = &self.f;
        if f.dhlm == 0.0 && f.dllm == 0.0 {
            return position;
        }
        let here = f.drbv / f.mres;
        let (a, b) = (f.dllm / f.mres, f.dhlm / f.mres);
        // Moving back towards the valid range from outside stays allowed.
        let (lo, hi) = (a.min(b).min(here), a.max(b).max(here));
        let target = if relative { here + position } else { position };
        if (lo..=hi).contains(&target) {
            return position;
        }
        let kept = target.clamp(lo, hi);
        if relative {
            kept - here
        } else {
            kept
        }
    }

    /// T6: start jogging in the direction of the pressed button.
    pub(super) fn start_jog(&mut self) {
        self.f.dmov = 0;
        self.mark(Field::DMOV);
        self.f.pp = 1;
        let maths = MoveMaths::new(&self.f);
        let mut jogv = self.f.jvel * self.dirsign() / self.f.mres;
        if self.f.jogf == 0 {
            jogv = -jogv;
        }
        self.f.cdir = i16::from(jogv >= 0.0);
        self.send(vec![
            MotorCommand::SetVelBase(maths.vbase),
            MotorCommand::SetAccel(maths.jacc),
            MotorCommand::Jog(jogv),
        ]);
    }

    /// T5 plus the bookkeeping shared by §9.3 and §10.
    pub(super) fn start_home(&mut self) {
        let m = MoveMaths::new(&self.f);
        let forward = (self.f.homf != 0 && self.f.mres > 0.0) || (self.f.homr != 0 && self.f.mres < 0.0);
        let mut txn = vec![MotorCommand::SetVelocity(m.hvel), MotorCommand::SetVelBase(m.vbase)];
        if m.hacc > 0.0 {
            txn.push(MotorCommand::SetAccel(m.hacc));
        }
        txn.push(if forward { MotorCommand::HomeFor } else { MotorCommand::HomeRev });
        txn.push(MotorCommand::Go);
        self.send(txn);
        self.f.dmov = 0;
        self.mark(Field::DMOV);
        self.f.rcnt = 0;
        self.mark(Field::RCNT);
        let cdir = i16::from(self.f.homf != 0);
        self.f.cdir = if self.f.mres < 0.0 { 1 - cdir } else { cdir };
    }
}

/// Scaled retry distances keep a magnitude of at least one step (sign(0) counts as negative).
pub(super) fn at_least_one_step(steps: f64) -> f64 {
    if steps.abs() < 1.0 {
        if steps > 0.0 {
            1.0
        } else {
            -1.0
        }
    } else {
        steps
    }
}

/// One move leg for the device: speeds in steps/s, acceleration in steps/s², position in steps.
pub(super) struct Leg {
    pub(super) velocity: f64,
    /// SET_VEL_BASE, or None to keep the driver's last base velocity (T2/T4).
    pub(super) base: Option<f64>,
    pub(super) accel: f64,
    pub(super) position: f64,
    pub(super) relative: bool,
}

impl Leg {
    /// T2/T4: the final backlash approach at BVEL/BACC (VBAS + 1 step/s if BVEL ≤ VBAS, Q29).
    pub(super) fn backlash(m: &MoveMaths, position: f64, relative: bool) -> Self {
        let velocity = if m.bvel <= m.vbase { m.vbase + 1.0 } else { m.bvel };
        Self { velocity, base: None, accel: m.bacc, position, relative }
    }
}
