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
use serde::{Deserialize, Serialize};
use zmotor_msgs::bits::msta;
use zmotor_msgs::{Gain, SimState};

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
pub struct SimAxis {
    config: SimConfig,
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
    enabled: bool,
    /// Fraction of each commanded distance actually travelled (inch-worm): the motor stops short.
    pub fraction: f64,
    /// Fraction of each commanded distance the carriage misses although the motor counts it
    /// (a slipping stepper): the step count reaches the target, the encoder does not.
    pub slip: f64,
    pub stalled: bool,
    pub comm_lost: bool,
    pub problem: bool,
    /// Command primitives received, for inspection.
    pub raw_commands: Vec<String>,
    /// PID gains last set (proportional, integral, derivative).
    pub gains: [f64; 3],
}

impl SimAxis {
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
            enabled: true,
            fraction: 1.0,
            slip: 0.0,
            stalled: false,
            comm_lost: false,
            problem: false,
            raw_commands: Vec::new(),
            gains: [0.0; 3],
        }
    }

    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    pub fn physical_position(&self) -> f64 {
        self.physical
    }

    pub fn is_moving(&self) -> bool {
        !self.profile.is_empty()
    }

    /// Put the carriage somewhere else by hand, at once; any motion in progress is abandoned.
    pub fn teleport(&mut self, physical: f64) {
        self.halt();
        self.physical = physical;
    }

    pub fn set_high_limit_switch(&mut self, position: Option<f64>) {
        self.config.high_limit_switch = position;
    }

    pub fn set_low_limit_switch(&mut self, position: Option<f64>) {
        self.config.low_limit_switch = position;
    }

    pub fn set_home_switch(&mut self, position: f64) {
        self.config.home_switch = position;
    }

    pub fn set_encoder(&mut self, counts_per_step: Option<f64>) {
        self.config.encoder_counts_per_step = counts_per_step;
    }

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

    fn at_home(&self) -> bool {
        (self.physical - self.config.home_switch).abs() <= 0.5
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
        self.profile.clear();
        self.velocity = 0.0;
        self.arrival = arrival;
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
        self.profile.clear();
        self.velocity = 0.0;
        self.counter_offset += std::mem::take(&mut self.pending_slip);
        if self.arrival == Arrival::Homed {
            self.counter_offset = -self.physical;
            self.encoder_offset = -self.physical;
            self.homed = true;
        }
        self.arrival = Arrival::Nothing;
    }

    /// Halt at once where the carriage is (a limit switch or a stall).
    fn halt(&mut self) {
        self.pending_slip = 0.0;
        self.profile.clear();
        self.velocity = 0.0;
        self.arrival = Arrival::Nothing;
    }
}

impl Driver for SimAxis {
    fn advance(&mut self, now: f64) {
        // Time never runs back; a motion due at this very instant still ends.
        let now = now.max(self.now);
        self.now = now;
        if self.profile.is_empty() {
            return;
        }
        if self.stalled {
            self.halt();
            return;
        }
        let end = self.profile.last().map(Segment::end).unwrap_or(now);
        let segment = self.profile.iter().find(|s| now < s.end()).or(self.profile.last()).copied();
        if let Some(segment) = segment {
            let (p, v) = segment.at(now);
            self.physical = p;
            self.velocity = if now >= end { 0.0 } else { v };
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
        if now >= end {
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
        set(self.last_direction_positive, msta::DIRECTION);
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

    fn next_event(&self) -> Option<f64> {
        self.profile.last().map(Segment::end).filter(|end| end.is_finite())
    }

    fn simulation(&mut self) -> Option<&mut SimAxis> {
        Some(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert_eq!(s.next_event(), Some(1.5));
        s.advance(0.5);
        assert!((s.status().position - 25.0).abs() < 1e-9);
        assert_eq!(s.status().msta & msta::DONE, 0);
        s.advance(1.0);
        assert!((s.status().position - 75.0).abs() < 1e-9);
        s.advance(1.5);
        assert_eq!(s.status().position, 100.0);
        assert_ne!(s.status().msta & msta::DONE, 0);
        assert_eq!(s.next_event(), None);
    }

    #[test]
    fn triangular_profile_for_short_moves() {
        let mut s = sim();
        s.move_to(10.0, false, 0.0, 100.0, 10.0);
        // Peak sqrt(10*10) = 10 steps/s after 1 s, total 2 s.
        assert!((s.next_event().unwrap() - 2.0).abs() < 1e-12);
        s.advance(1.0);
        assert!((s.status().position - 5.0).abs() < 1e-9);
    }

    #[test]
    fn limit_switch_stops_motion_and_reports_in_msta() {
        let mut s = sim();
        s.move_velocity(0.0, 500.0, 0.0);
        s.advance(1.0);
        assert_eq!(s.status().position, 500.0);
        s.advance(3.0);
        let st = s.status();
        assert_eq!(st.position, 1000.0);
        assert_ne!(st.msta & msta::PLUS_LS, 0);
        assert_ne!(st.msta & msta::DONE, 0);
    }

    #[test]
    fn stop_decelerates() {
        let mut s = sim();
        s.move_velocity(0.0, 100.0, 0.0);
        s.advance(1.0);
        s.stop(100.0);
        s.advance(3.0);
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
        s.advance(10.0);
        let st = s.status();
        assert_eq!((st.position, s.physical_position()), (0.0, 120.0));
        assert_ne!(st.msta & msta::HOMED, 0);
        assert_ne!(st.msta & msta::HOME, 0);
        s.fraction = 0.5;
        s.move_to(100.0, false, 0.0, 100.0, 0.0);
        s.advance(20.0);
        assert_eq!(s.status().position, 50.0);
        s.fraction = 1.0;
        s.slip = 0.1;
        s.move_to(150.0, false, 0.0, 100.0, 0.0);
        s.advance(30.0);
        let st = s.status();
        assert_eq!(
            (st.position, st.encoder_position),
            (150.0, 2.0 * 140.0),
            "the steps are counted, the carriage slips"
        );
        s.slip = 0.0;
        s.comm_lost = true;
        s.move_to(0.0, false, 0.0, 100.0, 0.0);
        assert!(!s.is_moving());
        assert_ne!(s.status().msta & msta::COMM_ERR, 0);
        s.comm_lost = false;
        s.stalled = true;
        s.move_to(0.0, false, 0.0, 100.0, 0.0);
        assert!(!s.is_moving());
        assert_ne!(s.status().msta & msta::SLIP_STALL, 0);
    }
}
