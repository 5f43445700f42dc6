//! A simulated axis: a physical model on the injected clock. Motion follows trapezoidal
//! velocity profiles (start at the base velocity, constant acceleration to the slew velocity,
//! cruise, symmetric deceleration); hard limit switches stop motion; a home switch; an optional
//! encoder; and injectable faults (stall, communication loss, driver problem, a per-move
//! fraction of the distance actually travelled).
//!
//! Positions are in steps. The *physical* position is where the carriage is; the controller's
//! step counter is the physical position plus an offset that `set_position` redefines.

use super::Driver;
use crate::engine::DeviceStatus;
use crate::time::Instant;
use serde::{Deserialize, Serialize};
use zmotor_msgs::bits::msta;
use zmotor_msgs::{Gain, SimState, Value};

/// Times closer than this (seconds) are the same instant: the clock is counted in whole
/// nanoseconds, the profile in floating-point seconds.
const SAME_INSTANT: f64 = 2e-9;

/// A run-time setting of the simulator, read and written on `sim/<axis>/<name>`: positions in
/// steps, flags 0/1. This table is the one place that names them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimSetting {
    /// Where the carriage is; a write moves it there at once, as if pushed by hand.
    Position,
    /// The plus limit switch, in steps, or `none`.
    HighLimit,
    /// The minus limit switch, in steps, or `none`.
    LowLimit,
    /// The home switch, in steps.
    Home,
    /// Encoder counts per step; 0 removes the encoder.
    Encoder,
    /// 1: the motor stops where it is and moves no more.
    Stall,
    /// 1: commands are lost, MSTA reports a communication error.
    CommLost,
    /// 1: MSTA RA_PROBLEM; motion ends.
    Problem,
    /// Fraction of every commanded distance actually travelled, 0 to 2.
    Fraction,
    /// Fraction of every move the carriage misses while the steps are counted, 0 to 1.
    Slip,
    /// Whether the axis is a servo (read-only: set in the launch file).
    Servo,
}

impl SimSetting {
    /// Every setting, in the order a read of `sim/<axis>/**` answers them.
    pub const ALL: [SimSetting; 11] = [
        SimSetting::Position,
        SimSetting::HighLimit,
        SimSetting::LowLimit,
        SimSetting::Home,
        SimSetting::Encoder,
        SimSetting::Stall,
        SimSetting::CommLost,
        SimSetting::Problem,
        SimSetting::Fraction,
        SimSetting::Slip,
        SimSetting::Servo,
    ];

    /// The key chunk that names it.
    pub fn name(self) -> &'static str {
        match self {
            SimSetting::Position => "position",
            SimSetting::HighLimit => "high_limit",
            SimSetting::LowLimit => "low_limit",
            SimSetting::Home => "home",
            SimSetting::Encoder => "encoder",
            SimSetting::Stall => "stall",
            SimSetting::CommLost => "comm_lost",
            SimSetting::Problem => "problem",
            SimSetting::Fraction => "fraction",
            SimSetting::Slip => "slip",
            SimSetting::Servo => "servo",
        }
    }

    /// The setting a key chunk names.
    pub fn from_name(name: &str) -> Option<SimSetting> {
        SimSetting::ALL.into_iter().find(|s| s.name() == name)
    }
}

/// Why a simulator setting was not changed.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SimSettingError {
    /// No setting has that name.
    #[error("unknown simulator key '{0}'")]
    Unknown(String),
    /// The setting is fixed by the launch file.
    #[error("{} is read-only (set it in the launch file's [axis.sim])", .0.name())]
    ReadOnly(SimSetting),
    /// The value is not a finite number.
    #[error("{}: a finite number is required, got '{got}'", setting.name())]
    NotANumber {
        /// The setting written.
        setting: SimSetting,
        /// The value given.
        got: Value,
    },
    /// The number is outside the setting's range.
    #[error("{} {value} is outside [{min}, {max}]", setting.name())]
    OutOfRange {
        /// The setting written.
        setting: SimSetting,
        /// The value given.
        value: f64,
        /// Lowest value allowed.
        min: f64,
        /// Highest value allowed.
        max: f64,
    },
}

/// Static description of the simulated mechanics, in steps (physical coordinates).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Physical position at start.
    pub position: f64,
    /// Position of the plus (raw positive) limit switch; None = no switch.
    pub high_limit_switch: Option<f64>,
    /// Position of the minus limit switch; None = no switch.
    pub low_limit_switch: Option<f64>,
    /// Position of the home switch.
    pub home_switch: f64,
    /// Encoder counts per motor step; None = no encoder.
    pub encoder_counts_per_step: Option<f64>,
    /// A servo: closed-loop control that can be enabled and tuned (MSTA GAIN_SUPPORT).
    pub servo: bool,
    /// Every motion arrives at once (no travel time), for latency benchmarks.
    pub instant: bool,
}

/// Why a simulated axis cannot be built as its launch file describes it.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SimConfigError {
    /// A position that is no finite number of steps.
    #[error("{key}: {value} is not a finite number of steps")]
    NotFinite {
        /// The setting.
        key: &'static str,
        /// Its value.
        value: f64,
    },
    /// An encoder of no counts (or of a number that is none): leaving it out means no encoder.
    #[error("encoder_counts_per_step: {0} is not a number of counts more than 0 (leave it out for no encoder)")]
    Encoder(f64),
}

impl SimConfig {
    /// Whether the model can be built: every position a finite number of steps, an encoder of
    /// counts more than 0.
    pub fn check(&self) -> Result<(), SimConfigError> {
        let positions = [
            ("position", Some(self.position)),
            ("high_limit_switch", self.high_limit_switch),
            ("low_limit_switch", self.low_limit_switch),
            ("home_switch", Some(self.home_switch)),
        ];
        if let Some((key, value)) =
            positions.into_iter().find_map(|(k, v)| v.filter(|v| !v.is_finite()).map(|v| (k, v)))
        {
            return Err(SimConfigError::NotFinite { key, value });
        }
        match self.encoder_counts_per_step {
            Some(counts) if !(counts.is_finite() && counts > 0.0) => Err(SimConfigError::Encoder(counts)),
            _ => Ok(()),
        }
    }
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            position: 0.0,
            high_limit_switch: None,
            low_limit_switch: None,
            home_switch: 0.0,
            encoder_counts_per_step: None,
            servo: false,
            instant: false,
        }
    }
}

/// One piece of a motion profile with constant acceleration.
#[derive(Clone, Copy, Debug)]
struct Segment {
    start: f64,
    duration: f64,
    position: f64,
    velocity: f64,
    acceleration: f64,
}

impl Segment {
    fn end(&self) -> f64 {
        self.start + self.duration
    }

    fn at(&self, t: f64) -> (f64, f64) {
        let dt = (t - self.start).clamp(0.0, self.duration);
        (self.position + self.velocity * dt + 0.5 * self.acceleration * dt * dt, self.velocity + self.acceleration * dt)
    }
}

/// What happens when the current motion ends.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Arrival {
    Nothing,
    /// A home: the counter is set to zero at the home switch.
    Homed,
}

#[derive(Debug)]
/// A simulated controller axis with its physical carriage (see the module documentation).
pub struct SimAxis {
    config: SimConfig,
    /// Seconds since the clock's origin.
    now: f64,
    physical: f64,
    velocity: f64,
    counter_offset: f64,
    encoder_offset: f64,
    /// Steps the motor will count at the end of this motion without the carriage moving (slip).
    pending_slip: f64,
    profile: Vec<Segment>,
    arrival: Arrival,
    last_direction_positive: bool,
    homed: bool,
    /// The carriage came to rest by a home search and has not moved since.
    rests_after_home_search: bool,
    /// Where the current motion ends, exactly: a stepper arrives on a whole count, whatever the
    /// rounding of the profile's arithmetic. None for a jog or a stop.
    landing: Option<f64>,
    enabled: bool,
    /// Fraction of each commanded distance actually travelled (inch-worm): the motor stops short.
    fraction: f64,
    /// Fraction of each commanded distance the carriage misses although the motor counts it
    /// (a slipping stepper): the step count reaches the target, the encoder does not.
    slip: f64,
    stalled: bool,
    comm_lost: bool,
    problem: bool,
    /// When the last motion that ran its course ended (seconds): a motion shorter than the gap
    /// between two looks is still seen to have run.
    last_motion_end: Option<f64>,
    /// Command primitives received, for inspection.
    raw_commands: Vec<String>,
    /// PID gains last set (proportional, integral, derivative).
    gains: [f64; 3],
}

impl SimAxis {
    /// A simulator at rest at `config.position`, at time zero.
    pub fn new(config: SimConfig) -> Self {
        Self {
            physical: config.position,
            config,
            now: 0.0,
            velocity: 0.0,
            counter_offset: 0.0,
            encoder_offset: 0.0,
            pending_slip: 0.0,
            profile: Vec::new(),
            arrival: Arrival::Nothing,
            last_direction_positive: true,
            homed: false,
            rests_after_home_search: false,
            landing: None,
            enabled: true,
            fraction: 1.0,
            slip: 0.0,
            stalled: false,
            comm_lost: false,
            problem: false,
            last_motion_end: None,
            raw_commands: Vec::new(),
            gains: [0.0; 3],
        }
    }

    /// The mechanics as configured (and changed by settings since).
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// The current value of a run-time setting.
    pub fn setting(&self, setting: SimSetting) -> Value {
        let flag = |on: bool| Value::Int(on.into());
        // As a write takes it: a switch that is not there is `none`.
        let switch = |position: Option<f64>| position.map_or_else(|| Value::Text("none".into()), Value::Float);
        match setting {
            SimSetting::Position => Value::Float(self.physical),
            SimSetting::HighLimit => switch(self.config.high_limit_switch),
            SimSetting::LowLimit => switch(self.config.low_limit_switch),
            SimSetting::Home => Value::Float(self.config.home_switch),
            SimSetting::Encoder => Value::Float(self.config.encoder_counts_per_step.unwrap_or(0.0)),
            SimSetting::Stall => flag(self.stalled),
            SimSetting::CommLost => flag(self.comm_lost),
            SimSetting::Problem => flag(self.problem),
            SimSetting::Fraction => Value::Float(self.fraction),
            SimSetting::Slip => Value::Float(self.slip),
            SimSetting::Servo => flag(self.config.servo),
        }
    }

    /// Change a run-time setting; nothing changes when the value is refused.
    pub fn apply(&mut self, setting: SimSetting, value: &Value) -> Result<(), SimSettingError> {
        let number = || {
            value.as_f64().filter(|x| x.is_finite()).ok_or(SimSettingError::NotANumber { setting, got: value.clone() })
        };
        let within = |min: f64, max: f64| {
            let x = number()?;
            if (min..=max).contains(&x) {
                Ok(x)
            } else {
                Err(SimSettingError::OutOfRange { setting, value: x, min, max })
            }
        };
        let switch_position = || match value {
            Value::Text(t) if t.eq_ignore_ascii_case("none") => Ok(None),
            _ => number().map(Some),
        };
        match setting {
            SimSetting::Position => self.teleport(number()?),
            SimSetting::HighLimit => self.config.high_limit_switch = switch_position()?,
            SimSetting::LowLimit => self.config.low_limit_switch = switch_position()?,
            SimSetting::Home => self.config.home_switch = number()?,
            SimSetting::Encoder => self.config.encoder_counts_per_step = Some(number()?).filter(|r| *r != 0.0),
            SimSetting::Stall => self.stalled = number()? != 0.0,
            SimSetting::CommLost => self.comm_lost = number()? != 0.0,
            SimSetting::Problem => self.problem = number()? != 0.0,
            SimSetting::Fraction => self.fraction = within(0.0, 2.0)?,
            SimSetting::Slip => self.slip = within(0.0, 1.0)?,
            SimSetting::Servo => return Err(SimSettingError::ReadOnly(setting)),
        }
        Ok(())
    }

    /// Command primitives received (INIT/PREM/POST text), oldest first.
    pub fn raw_commands(&self) -> &[String] {
        &self.raw_commands
    }

    /// PID gains last set: proportional, integral, derivative.
    pub fn gains(&self) -> [f64; 3] {
        self.gains
    }

    /// Where the carriage is, steps.
    pub fn physical_position(&self) -> f64 {
        self.physical
    }

    /// When the last motion that ran its course ended (not one halted by a switch or a stall).
    pub fn last_motion_end(&self) -> Option<Instant> {
        self.last_motion_end.map(Instant::from_secs_f64)
    }

    /// A motion is in progress.
    pub fn is_moving(&self) -> bool {
        !self.profile.is_empty()
    }

    /// Put the carriage somewhere else by hand, at once; any motion in progress is abandoned.
    fn teleport(&mut self, physical: f64) {
        self.halt();
        self.physical = physical;
        self.rests_after_home_search = false;
    }

    /// The physical state, as `sim/<axis>/state` reports it.
    pub fn state(&self) -> SimState {
        SimState {
            position: self.physical,
            encoder: self.encoder_reading(),
            velocity: self.velocity,
            moving: self.is_moving(),
            high_limit: self.at_high_limit(),
            low_limit: self.at_low_limit(),
            at_home: self.at_home(),
            homed: self.homed,
        }
    }

    fn encoder_reading(&self) -> Option<f64> {
        // The encoder is read through the controller, so a set-position redefines it too.
        self.config.encoder_counts_per_step.map(|ratio| (self.physical + self.encoder_offset) * ratio)
    }

    fn at_high_limit(&self) -> bool {
        self.config.high_limit_switch.is_some_and(|s| self.physical >= s)
    }

    fn at_low_limit(&self) -> bool {
        self.config.low_limit_switch.is_some_and(|s| self.physical <= s)
    }

    /// The carriage stands on the home switch, as the switch's own input reads (the status's
    /// HOME bit follows motorSim, which clears it after a home search).
    pub fn on_home_switch(&self) -> bool {
        self.physical == self.config.home_switch
    }

    /// As motorSim reports it: the carriage exactly on the home position. motorSim compares
    /// positions exactly; a move to the switch lands on it, but its home search ends a rounding
    /// error away, so the record reads ATHM 0 after a home. This simulator's search lands
    /// exactly, so the bit stays clear after it until the carriage moves again.
    fn at_home(&self) -> bool {
        self.physical == self.config.home_switch && !self.rests_after_home_search
    }

    /// Commands are lost while the controller cannot be reached.
    fn accepts_commands(&self) -> bool {
        !self.comm_lost
    }

    /// A disabled servo does not move.
    fn can_move(&self) -> bool {
        self.accepts_commands() && (self.enabled || !self.config.servo)
    }

    /// Plan a trapezoidal motion from the current physical position to `target`.
    fn start_motion(&mut self, target: f64, min_velocity: f64, max_velocity: f64, acceleration: f64, arrival: Arrival) {
        self.rests_after_home_search = false;
        self.profile.clear();
        self.velocity = 0.0;
        self.arrival = arrival;
        self.landing = Some(target);
        let distance = (target - self.physical).abs();
        // Below a nanostep there is nothing to travel (and no time would pass doing it).
        if distance < 1e-9 {
            self.finish_motion();
            return;
        }
        let sign = (target - self.physical).signum();
        self.last_direction_positive = sign > 0.0;
        if self.config.instant && !self.stalled {
            self.physical = target;
            self.finish_motion();
            return;
        }
        if self.stalled {
            return;
        }
        let vb = min_velocity.abs();
        let vm = max_velocity.abs().max(vb);
        if vm <= 0.0 {
            // No speed at all: the motor cannot move; the motion is over at once.
            self.finish_motion();
            return;
        }
        let mut t = self.now;
        let mut p = self.physical;
        let push = |duration: f64, v0: f64, a: f64, t: &mut f64, p: &mut f64, profile: &mut Vec<Segment>| {
            if duration > 0.0 {
                profile.push(Segment {
                    start: *t,
                    duration,
                    position: *p,
                    velocity: sign * v0,
                    acceleration: sign * a,
                });
                *t += duration;
                *p += sign * (v0 * duration + 0.5 * a * duration * duration);
            }
        };
        if acceleration <= 0.0 || vm == vb {
            push(distance / vm, vm, 0.0, &mut t, &mut p, &mut self.profile);
        } else {
            let ramp_time = (vm - vb) / acceleration;
            let ramp_distance = (vb + vm) / 2.0 * ramp_time;
            if 2.0 * ramp_distance >= distance {
                let peak = (vb * vb + acceleration * distance).sqrt();
                let half = (peak - vb) / acceleration;
                push(half, vb, acceleration, &mut t, &mut p, &mut self.profile);
                push(half, peak, -acceleration, &mut t, &mut p, &mut self.profile);
            } else {
                push(ramp_time, vb, acceleration, &mut t, &mut p, &mut self.profile);
                push((distance - 2.0 * ramp_distance) / vm, vm, 0.0, &mut t, &mut p, &mut self.profile);
                push(ramp_time, vm, -acceleration, &mut t, &mut p, &mut self.profile);
            }
        }
        // Rounding aside, the last segment ends exactly on the target.
        if let Some(last) = self.profile.last_mut() {
            last.position += target - p;
        }
        self.velocity = sign * vb;
    }

    fn finish_motion(&mut self) {
        self.last_motion_end = self.profile.last().map(Segment::end);
        self.profile.clear();
        self.velocity = 0.0;
        self.counter_offset += std::mem::take(&mut self.pending_slip);
        if self.arrival == Arrival::Homed {
            self.counter_offset = -self.physical;
            self.encoder_offset = -self.physical;
            self.homed = true;
            self.rests_after_home_search = true;
        }
        self.arrival = Arrival::Nothing;
    }

    /// Halt at once where the carriage is (a limit switch or a stall).
    fn halt(&mut self) {
        self.pending_slip = 0.0;
        self.landing = None;
        self.profile.clear();
        self.velocity = 0.0;
        self.arrival = Arrival::Nothing;
    }
}

impl Driver for SimAxis {
    fn advance(&mut self, now: Instant) {
        // Time never runs back; a motion due at this very instant still ends.
        let now = now.as_secs_f64().max(self.now);
        self.now = now;
        if self.profile.is_empty() {
            return;
        }
        if self.stalled {
            self.halt();
            return;
        }
        let end = self.profile.last().map(Segment::end).unwrap_or(now);
        let ended = now + SAME_INSTANT >= end;
        let segment = self.profile.iter().find(|s| now < s.end()).or(self.profile.last()).copied();
        if let Some(segment) = segment {
            let (p, v) = segment.at(if ended { f64::INFINITY } else { now });
            self.physical = if ended { self.landing.unwrap_or(p) } else { p };
            self.velocity = if ended { 0.0 } else { v };
        }
        let moving_up = self.last_direction_positive;
        if let (true, Some(s)) = (moving_up, self.config.high_limit_switch) {
            if self.physical >= s {
                self.physical = s;
                self.halt();
                return;
            }
        }
        if let (false, Some(s)) = (moving_up, self.config.low_limit_switch) {
            if self.physical <= s {
                self.physical = s;
                self.halt();
                return;
            }
        }
        if ended {
            self.finish_motion();
        }
    }

    fn move_to(&mut self, position: f64, relative: bool, min_velocity: f64, max_velocity: f64, acceleration: f64) {
        if !self.can_move() {
            return;
        }
        let commanded = if relative { self.physical + position } else { position - self.counter_offset };
        let travel = self.fraction * (commanded - self.physical);
        self.start_motion(
            self.physical + (1.0 - self.slip) * travel,
            min_velocity,
            max_velocity,
            acceleration,
            Arrival::Nothing,
        );
        self.pending_slip = self.slip * travel;
    }

    fn move_velocity(&mut self, min_velocity: f64, velocity: f64, acceleration: f64) {
        if !self.can_move() {
            return;
        }
        // A jog runs until stopped or a switch is hit: plan a very long move that way.
        let far = self.physical + velocity.signum() * 1e15;
        self.start_motion(far, min_velocity, velocity.abs(), acceleration, Arrival::Nothing);
    }

    /// The simulated home search always finds the switch, whichever side it is on; a real
    /// controller would reverse at a limit switch to find it.
    fn home(&mut self, _forward: bool, min_velocity: f64, max_velocity: f64, acceleration: f64) {
        if self.can_move() {
            self.start_motion(self.config.home_switch, min_velocity, max_velocity, acceleration, Arrival::Homed);
        }
    }

    fn stop(&mut self, acceleration: f64) {
        if !self.accepts_commands() || self.profile.is_empty() {
            return;
        }
        let v = self.velocity.abs();
        if acceleration <= 0.0 || v == 0.0 {
            self.halt();
            return;
        }
        let sign = self.velocity.signum();
        self.profile = vec![Segment {
            start: self.now,
            duration: v / acceleration,
            position: self.physical,
            velocity: self.velocity,
            acceleration: -sign * acceleration,
        }];
        self.landing = None;
        self.arrival = Arrival::Nothing;
    }

    fn set_position(&mut self, position: f64) {
        if self.accepts_commands() {
            self.counter_offset = position - self.physical;
            self.encoder_offset = self.counter_offset;
        }
    }

    fn enable(&mut self, on: bool) {
        self.enabled = on;
        if !on && self.config.servo {
            self.halt();
        }
    }

    fn set_encoder_ratio(&mut self, _ratio: f64) {}

    fn set_high_limit(&mut self, _position: f64) {}

    fn set_low_limit(&mut self, _position: f64) {}

    fn set_gain(&mut self, gain: Gain, value: f64) {
        let index = match gain {
            Gain::Proportional => 0,
            Gain::Integral => 1,
            Gain::Derivative => 2,
        };
        self.gains[index] = value;
    }

    fn raw(&mut self, text: &str) {
        self.raw_commands.push(text.to_string());
    }

    fn status(&self) -> DeviceStatus {
        let mut bits = 0;
        let mut set = |cond: bool, bit: u32| {
            if cond {
                bits |= bit;
            }
        };
        // As motorSim: the direction of the current motion, 0 at rest.
        set(self.velocity > 0.0, msta::DIRECTION);
        set(!self.is_moving(), msta::DONE);
        set(self.at_high_limit(), msta::PLUS_LS);
        set(self.at_low_limit(), msta::MINUS_LS);
        set(self.at_home(), msta::HOME);
        set(self.enabled, msta::POSITION);
        set(self.config.servo, msta::GAIN_SUPPORT);
        set(self.stalled, msta::SLIP_STALL);
        set(self.config.encoder_counts_per_step.is_some(), msta::PRESENT);
        set(self.problem, msta::PROBLEM);
        set(self.velocity != 0.0, msta::MOVING);
        set(self.comm_lost, msta::COMM_ERR);
        set(self.homed, msta::HOMED);
        DeviceStatus {
            position: self.physical + self.counter_offset,
            encoder_position: self.encoder_reading().unwrap_or(0.0),
            velocity: self.velocity,
            msta: bits,
            readback: None,
        }
    }

    fn next_event(&self) -> Option<Instant> {
        self.profile.last().map(Segment::end).filter(|end| end.is_finite()).map(Instant::from_secs_f64)
    }

    fn simulation(&mut self) -> Option<&mut SimAxis> {
        Some(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(seconds: f64) -> Instant {
        Instant::from_secs_f64(seconds)
    }

    fn set(s: &mut SimAxis, setting: SimSetting, value: f64) {
        s.apply(setting, &Value::Float(value)).unwrap();
    }

    fn sim() -> SimAxis {
        SimAxis::new(SimConfig {
            high_limit_switch: Some(1000.0),
            low_limit_switch: Some(-1000.0),
            ..SimConfig::default()
        })
    }

    #[test]
    fn trapezoid_reaches_the_target_at_the_planned_time() {
        let mut s = sim();
        // 0 → 100 steps, base 0, slew 100 steps/s, 200 steps/s²: 0.5 s ramps of 25 steps, 0.5 s cruise.
        s.move_to(100.0, false, 0.0, 100.0, 200.0);
        assert_eq!(s.next_event(), Some(at(1.5)));
        s.advance(at(0.5));
        assert!((s.status().position - 25.0).abs() < 1e-9);
        assert_eq!(s.status().msta & msta::DONE, 0);
        s.advance(at(1.0));
        assert!((s.status().position - 75.0).abs() < 1e-9);
        s.advance(at(1.5));
        assert_eq!(s.status().position, 100.0);
        assert_ne!(s.status().msta & msta::DONE, 0);
        assert_eq!(s.next_event(), None);
    }

    #[test]
    fn a_motion_looked_at_only_after_its_end_says_when_it_ended() {
        let mut s = sim();
        assert_eq!(s.last_motion_end(), None);
        s.move_to(100.0, false, 0.0, 100.0, 200.0);
        // Looked at long after: the motion ended at 1.5 s, not when it was looked at.
        s.advance(at(4.0));
        assert_eq!((s.next_event(), s.last_motion_end()), (None, Some(at(1.5))));
        // One halted by a limit switch did not run its course: the last end stays.
        s.move_velocity(0.0, 500.0, 0.0);
        s.advance(at(10.0));
        assert_eq!(s.last_motion_end(), Some(at(1.5)));
    }

    #[test]
    fn triangular_profile_for_short_moves() {
        let mut s = sim();
        s.move_to(10.0, false, 0.0, 100.0, 10.0);
        // Peak sqrt(10*10) = 10 steps/s after 1 s, total 2 s.
        assert!((s.next_event().unwrap().as_secs_f64() - 2.0).abs() < 1e-9);
        s.advance(at(1.0));
        assert!((s.status().position - 5.0).abs() < 1e-9);
    }

    #[test]
    fn limit_switch_stops_motion_and_reports_in_msta() {
        let mut s = sim();
        s.move_velocity(0.0, 500.0, 0.0);
        s.advance(at(1.0));
        assert_eq!(s.status().position, 500.0);
        s.advance(at(3.0));
        let st = s.status();
        assert_eq!(st.position, 1000.0);
        assert_ne!(st.msta & msta::PLUS_LS, 0);
        assert_ne!(st.msta & msta::DONE, 0);
    }

    #[test]
    fn stop_decelerates() {
        let mut s = sim();
        s.move_velocity(0.0, 100.0, 0.0);
        s.advance(at(1.0));
        s.stop(100.0);
        s.advance(at(3.0));
        let st = s.status();
        assert!((st.position - 150.0).abs() < 1e-9, "{}", st.position);
        assert_ne!(st.msta & msta::DONE, 0);
    }

    #[test]
    fn set_position_home_and_faults() {
        let mut s = SimAxis::new(SimConfig {
            position: 300.0,
            home_switch: 120.0,
            encoder_counts_per_step: Some(2.0),
            ..SimConfig::default()
        });
        s.set_position(0.0);
        assert_eq!(s.status().position, 0.0);
        assert_eq!(s.status().encoder_position, 0.0);
        s.home(false, 0.0, 100.0, 0.0);
        s.advance(at(10.0));
        let st = s.status();
        assert_eq!((st.position, s.physical_position()), (0.0, 120.0));
        assert_ne!(st.msta & msta::HOMED, 0);
        assert_eq!(st.msta & msta::HOME, 0, "as motorSim, not at home after a home search");
        set(&mut s, SimSetting::Fraction, 0.5);
        s.move_to(100.0, false, 0.0, 100.0, 0.0);
        s.advance(at(20.0));
        assert_eq!(s.status().position, 50.0);
        set(&mut s, SimSetting::Fraction, 1.0);
        set(&mut s, SimSetting::Slip, 0.1);
        s.move_to(150.0, false, 0.0, 100.0, 0.0);
        s.advance(at(30.0));
        let st = s.status();
        assert_eq!(
            (st.position, st.encoder_position),
            (150.0, 2.0 * 140.0),
            "the steps are counted, the carriage slips"
        );
        set(&mut s, SimSetting::Slip, 0.0);
        set(&mut s, SimSetting::CommLost, 1.0);
        s.move_to(0.0, false, 0.0, 100.0, 0.0);
        assert!(!s.is_moving());
        assert_ne!(s.status().msta & msta::COMM_ERR, 0);
        set(&mut s, SimSetting::CommLost, 0.0);
        set(&mut s, SimSetting::Stall, 1.0);
        s.move_to(0.0, false, 0.0, 100.0, 0.0);
        assert!(!s.is_moving());
        assert_ne!(s.status().msta & msta::SLIP_STALL, 0);
    }
    #[test]
    fn every_setting_is_named_once_and_read_back_as_written() {
        for setting in SimSetting::ALL {
            assert_eq!(SimSetting::from_name(setting.name()), Some(setting));
        }
        let mut s = SimAxis::new(SimConfig::default());
        s.apply(SimSetting::HighLimit, &Value::Float(500.0)).unwrap();
        s.apply(SimSetting::LowLimit, &Value::Text("none".into())).unwrap();
        s.apply(SimSetting::Fraction, &Value::Float(0.5)).unwrap();
        assert_eq!(s.setting(SimSetting::HighLimit), Value::Float(500.0));
        assert_eq!(s.setting(SimSetting::LowLimit), Value::Text("none".into()), "read back as it is written");
        assert_eq!(s.setting(SimSetting::Fraction), Value::Float(0.5));
    }

    #[test]
    fn refused_settings_change_nothing_and_say_why() {
        let mut s = SimAxis::new(SimConfig::default());
        let refusal = s.apply(SimSetting::Slip, &Value::Float(1.5)).unwrap_err();
        assert_eq!(refusal.to_string(), "slip 1.5 is outside [0, 1]");
        assert_eq!(s.setting(SimSetting::Slip), Value::Float(0.0));
        let refusal = s.apply(SimSetting::Stall, &Value::Text("often".into())).unwrap_err();
        assert_eq!(refusal.to_string(), "stall: a finite number is required, got 'often'");
        let refusal = s.apply(SimSetting::Servo, &Value::Int(1)).unwrap_err();
        assert!(refusal.to_string().starts_with("servo is read-only"), "{refusal}");
        assert_eq!(s.setting(SimSetting::Servo), Value::Int(0));
    }
}
