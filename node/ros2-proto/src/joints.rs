//! Axes as ROS joints, sans-IO: each axis's readbacks become a `sensor_msgs/JointState` in SI
//! units (metres or radians, from its EGU or a factor given), published at the readback rate
//! while any joint moves (no more often than a given interval: many axes at their readback rate
//! make one message per interval, not one per readback) and every `rest_period` at rest, each
//! stamped with its newest readback's time; a `JointState` received as a command
//! (ros2_control's topic-based hardware interface sends one) becomes a target per axis, in the
//! axis's own units. Time is given (since the Unix epoch: it stamps the messages).

use crate::messages::{Header, JointState, Time};
use std::time::Duration;
use zmotor_msgs::menus::choice::ACCU_USE_ACCS;
use zmotor_msgs::{Field, Unit};

/// One axis seen as a joint.
#[derive(Clone, Debug, PartialEq)]
pub struct Joint {
    /// The joint's name in ROS.
    pub name: String,
    /// The axis.
    pub axis: String,
    /// SI units (m or rad) per the axis's EGU.
    pub si_per_egu: f64,
}

/// A joint that cannot be made.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum JointError {
    /// The EGU names no length or angle, and no factor was given.
    #[error("joint '{joint}': axis '{axis}' has EGU '{egu}', no unit of length or angle: give its factor to SI")]
    NoSiUnit {
        /// The joint.
        joint: String,
        /// Its axis.
        axis: String,
        /// The axis's EGU.
        egu: String,
    },
    /// A factor that is not a positive number.
    #[error("joint '{joint}': factor {factor} is not a positive number")]
    Factor {
        /// The joint.
        joint: String,
        /// The factor.
        factor: f64,
    },
}

impl Joint {
    /// The joint `name` on `axis`, whose EGU is `egu`; `factor` (SI units per EGU) when the
    /// EGU is no unit of length or angle zmotor knows, or to override it.
    pub fn new(name: &str, axis: &str, egu: &str, factor: Option<f64>) -> Result<Self, JointError> {
        let si_per_egu = match factor {
            Some(f) if f.is_finite() && f > 0.0 => f,
            Some(factor) => return Err(JointError::Factor { joint: name.into(), factor }),
            None => Unit::parse(egu).map(Unit::si).ok_or_else(|| JointError::NoSiUnit {
                joint: name.into(),
                axis: axis.into(),
                egu: egu.into(),
            })?,
        };
        Ok(Self { name: name.into(), axis: axis.into(), si_per_egu })
    }
}

/// A joint command that moves nothing.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum JointCommandError {
    /// A name that is no joint of this node.
    #[error("no joint named '{0}'")]
    UnknownJoint(String),
    /// Fewer positions than names.
    #[error("{names} joint names but {positions} positions")]
    Positions {
        /// Names given.
        names: usize,
        /// Positions given.
        positions: usize,
    },
    /// A position that is not a number, or none in its axis's units (1e308 rad in degrees).
    #[error("joint '{0}': the position is not a finite number in its axis's units")]
    NotFinite(String),
}

/// What is known of one joint.
#[derive(Clone, Copy, Debug, Default)]
struct Seen {
    /// The last readback (EGU) and when it came.
    last: Option<(f64, Duration)>,
    /// Its velocity, SI per second, from the last two readbacks while it moves.
    velocity: f64,
    moving: bool,
    /// User soft limits (HLM, LLM) and dial ones (DHLM, DLLM: both 0 means none).
    limits: [Option<f64>; 4],
    /// VELO, EGU/s.
    speed: Option<f64>,
    /// RDBD, EGU.
    deadband: Option<f64>,
    /// ACCL, VBAS, ACCU and ACCS.
    ramp: [Option<f64>; 4],
    /// VAL, EGU: where the record is sent (or holds, after a stop).
    target: Option<f64>,
}

/// What a trajectory needs of a joint's axis (`JointStates::joint_state`), in its EGU.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointReading {
    /// The last readback.
    pub position: f64,
    /// Where it may be sent.
    pub travel: Travel,
    /// VELO.
    pub speed: f64,
    /// RDBD: positions closer than this are one to the record (0 until it is posted).
    pub deadband: f64,
    /// How its moves speed up and slow down (none until posted).
    pub ramp: Option<Ramp>,
}

/// How a joint's axis speeds up and slows down, as its record drives it (behaviour spec §4): from
/// VBAS to VELO in ACCL seconds, or at ACCS when ACCU says so.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ramp {
    /// ACCL, seconds.
    pub seconds: f64,
    /// VBAS, EGU/s.
    pub base_speed: f64,
    /// ACCS, EGU/s², when ACCU is "Use ACCS".
    pub acceleration: Option<f64>,
}

impl Ramp {
    /// The VELO that makes a move of `way` (EGU) last `time` (s), its ramps included: a move
    /// at the plain quotient way / time arrives late by its ramps. The quotient where no speed
    /// meets the time (the way too short for the base speed's ramps, or too long for ACCS).
    #[must_use]
    pub fn speed_for(&self, way: f64, time: f64) -> f64 {
        let (d, t, b) = (way.abs(), time, self.base_speed.max(0.0));
        let plain = d / t;
        let speed = match self.acceleration {
            // Trapezoid at acceleration A: (V − b)² − A·t·V + A·d = 0, the slower root.
            Some(a) if a > 0.0 => {
                let (sum, product) = (2.0 * b + a * t, b * b + a * d);
                let discriminant = sum * sum - 4.0 * product;
                (discriminant >= 0.0).then(|| (sum - discriminant.sqrt()) / 2.0)
            }
            Some(_) => None,
            // ACCL seconds from b to V: t = ACCL + (d − b·ACCL) / V on a trapezoid (t ≥ 2 ACCL),
            // else a triangle whose acceleration (V − b) / ACCL peaks at its middle.
            None => {
                let r = self.seconds;
                if r <= 0.0 {
                    None
                } else if t >= 2.0 * r {
                    (d > b * r).then(|| (d - b * r) / (t - r))
                } else {
                    (d > b * t).then(|| b + 4.0 * r * (d - b * t) / (t * t))
                }
            }
        };
        speed.filter(|v| v.is_finite() && *v >= plain).unwrap_or(plain)
    }
}

/// The positions a joint's axis may be sent to, in its EGU.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Travel {
    /// Between LLM and HLM.
    Within {
        /// LLM.
        low: f64,
        /// HLM.
        high: f64,
    },
    /// Anywhere: the soft limits are off (DHLM = DLLM = 0).
    Unlimited,
}

impl Travel {
    /// Whether `position` (EGU) may be asked for.
    #[must_use]
    pub fn allows(self, position: f64) -> bool {
        match self {
            Travel::Within { low, high } => (low..=high).contains(&position),
            Travel::Unlimited => true,
        }
    }
}

/// The joints' state as ROS sees it (see the module documentation).
#[derive(Clone, Debug)]
pub struct JointStates {
    joints: Vec<Joint>,
    seen: Vec<Seen>,
    rest_period: Duration,
    /// The shortest interval between two messages.
    min_interval: Duration,
    /// A readback came since the last message.
    fresh: bool,
    last_sent: Option<Duration>,
}

impl JointStates {
    /// The state of `joints`, sent every `rest_period` at rest and at most once per
    /// `min_interval`.
    pub fn new(joints: Vec<Joint>, rest_period: Duration, min_interval: Duration) -> Self {
        let seen = vec![Seen::default(); joints.len()];
        Self { joints, seen, rest_period, min_interval, fresh: false, last_sent: None }
    }

    /// The joints.
    pub fn joints(&self) -> &[Joint] {
        &self.joints
    }

    fn index(&self, axis: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.axis == axis)
    }

    /// A posted value of `axis`'s `field` at `at`: RBV and DMOV make the state; HLM, LLM,
    /// DHLM, DLLM, VELO, RDBD and the ramps' ACCL, VBAS, ACCU, ACCS are kept for trajectories,
    /// VAL for the controller state's reference. Other fields are ignored.
    pub fn update(&mut self, axis: &str, field: Field, value: f64, at: Duration) {
        let Some(i) = self.index(axis).filter(|_| value.is_finite()) else { return };
        let seen = &mut self.seen[i];
        match field {
            Field::RBV => self.readback(i, value, at),
            Field::DMOV => self.done_moving(i, value != 0.0),
            Field::HLM => seen.limits[0] = Some(value),
            Field::LLM => seen.limits[1] = Some(value),
            Field::DHLM => seen.limits[2] = Some(value),
            Field::DLLM => seen.limits[3] = Some(value),
            Field::VELO => seen.speed = Some(value),
            Field::RDBD => seen.deadband = Some(value.abs()),
            Field::ACCL => seen.ramp[0] = Some(value),
            Field::VBAS => seen.ramp[1] = Some(value),
            Field::ACCU => seen.ramp[2] = Some(value),
            Field::ACCS => seen.ramp[3] = Some(value),
            Field::VAL => seen.target = Some(value),
            _ => {}
        }
    }

    /// The joint at `index`, once its readback, limits and speed are known.
    #[must_use]
    pub fn joint_state(&self, index: usize) -> Option<JointReading> {
        let seen = self.seen.get(index)?;
        let (rbv, _) = seen.last?;
        let travel = match seen.limits {
            [_, _, Some(dhlm), Some(dllm)] if dhlm == 0.0 && dllm == 0.0 => Travel::Unlimited,
            [Some(high), Some(low), Some(_), Some(_)] => Travel::Within { low, high },
            _ => return None,
        };
        Some(JointReading {
            position: rbv,
            travel,
            speed: seen.speed?,
            deadband: seen.deadband.unwrap_or(0.0),
            ramp: match seen.ramp {
                [Some(seconds), Some(base_speed), Some(accu), accs] => Some(Ramp {
                    seconds,
                    base_speed,
                    acceleration: (accu == f64::from(ACCU_USE_ACCS)).then(|| accs.unwrap_or(0.0)),
                }),
                _ => None,
            },
        })
    }

    /// Where joint `index`'s axis is sent (VAL, EGU), once posted.
    #[must_use]
    pub fn target(&self, index: usize) -> Option<f64> {
        self.seen.get(index)?.target
    }

    /// The index of the joint named `name`.
    #[must_use]
    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }

    fn readback(&mut self, i: usize, rbv: f64, at: Duration) {
        let si = self.joints[i].si_per_egu;
        let seen = &mut self.seen[i];
        if let Some((before, then)) = seen.last.filter(|_| seen.moving) {
            let dt = at.saturating_sub(then).as_secs_f64();
            if dt > 0.0 {
                seen.velocity = (rbv - before) * si / dt;
            }
        }
        seen.last = Some((rbv, at));
        self.fresh = true;
    }

    /// A joint at rest has no velocity.
    fn done_moving(&mut self, i: usize, done: bool) {
        let seen = &mut self.seen[i];
        seen.moving = !done;
        if done && seen.velocity != 0.0 {
            seen.velocity = 0.0;
            self.fresh = true;
        }
    }

    /// The message to publish at `now`, if one is due: once every joint has a readback, on
    /// every new readback, and every `rest_period` without one.
    #[must_use]
    pub fn poll_publish(&mut self, now: Duration) -> Option<JointState> {
        if self.seen.iter().any(|s| s.last.is_none()) {
            return None;
        }
        let due = match self.last_sent {
            None => true,
            Some(sent) if self.fresh => now >= sent + self.min_interval,
            Some(sent) => now >= sent + self.rest_period,
        };
        if !due {
            return None;
        }
        // A new readback is stamped with its own time, a state at rest with the time it is sent.
        let newest = self.seen.iter().filter_map(|s| s.last.map(|(_, at)| at)).max();
        let at = if self.fresh { newest.unwrap_or(now) } else { now };
        self.fresh = false;
        self.last_sent = Some(now);
        let stamp = Time { sec: i32::try_from(at.as_secs()).unwrap_or(i32::MAX), nanosec: at.subsec_nanos() };
        let positions = self.joints.iter().zip(&self.seen);
        Some(JointState {
            header: Header { stamp, frame_id: String::new() },
            name: self.joints.iter().map(|j| j.name.clone()).collect(),
            position: positions.map(|(j, s)| s.last.map_or(0.0, |(rbv, _)| rbv * j.si_per_egu)).collect(),
            velocity: self.seen.iter().map(|s| s.velocity).collect(),
            effort: Vec::new(),
        })
    }

    /// When `poll_publish` is next due without a new readback.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Duration> {
        let wait = if self.fresh { self.min_interval } else { self.rest_period };
        self.last_sent.map(|t| t + wait)
    }

    /// The targets a joint command asks for: each named joint's axis and its position in the
    /// axis's EGU. All or nothing: a command with one bad joint moves none.
    pub fn command(&self, command: &JointState) -> Result<Vec<(String, f64)>, JointCommandError> {
        if command.position.len() < command.name.len() {
            let (names, positions) = (command.name.len(), command.position.len());
            return Err(JointCommandError::Positions { names, positions });
        }
        command
            .name
            .iter()
            .zip(&command.position)
            .map(|(name, position)| {
                let joint = self
                    .joints
                    .iter()
                    .find(|j| &j.name == name)
                    .ok_or_else(|| JointCommandError::UnknownJoint(name.clone()))?;
                let target = position / joint.si_per_egu;
                if !target.is_finite() {
                    return Err(JointCommandError::NotFinite(name.clone()));
                }
                Ok((joint.axis.clone(), target))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(ms: u64) -> Duration {
        Duration::from_millis(1_700_000_000_000 + ms)
    }

    fn two_joints() -> JointStates {
        let lift = Joint::new("lift", "m1", "mm", None).unwrap();
        let turn = Joint::new("turn", "m2", "deg", None).unwrap();
        JointStates::new(vec![lift, turn], Duration::from_secs(1), Duration::from_millis(10))
    }

    #[test]
    fn joints_take_si_from_their_egu_or_a_factor() {
        assert_eq!(Joint::new("j", "m1", "um", None).unwrap().si_per_egu, 1e-6);
        assert_eq!(Joint::new("j", "m1", "counts", Some(2e-9)).unwrap().si_per_egu, 2e-9);
        assert!(matches!(Joint::new("j", "m1", "counts", None), Err(JointError::NoSiUnit { .. })));
        assert!(matches!(Joint::new("j", "m1", "mm", Some(-1.0)), Err(JointError::Factor { .. })));
    }

    #[test]
    fn state_is_published_in_si_on_every_readback_while_moving_and_slowly_at_rest() {
        let mut states = two_joints();
        states.update("m1", Field::RBV, 5.0, at(0));
        assert_eq!(states.poll_publish(at(0)), None, "not before every joint is known");
        states.update("m2", Field::RBV, 90.0, at(0));
        let first = states.poll_publish(at(0)).expect("every joint known");
        assert_eq!(first.name, ["lift", "turn"]);
        assert!(
            (first.position[0] - 0.005).abs() < 1e-15
                && (first.position[1] - std::f64::consts::FRAC_PI_2).abs() < 1e-12
        );
        assert_eq!((first.header.stamp.sec, first.header.stamp.nanosec), (1_700_000_000, 0));
        assert_eq!(states.poll_publish(at(500)), None, "at rest: not before the rest period");
        assert_eq!(states.poll_timeout(), Some(at(1000)));
        let at_rest = states.poll_publish(at(1000)).expect("at rest: every period");
        assert_eq!(at_rest.header.stamp.sec, 1_700_000_001, "at rest: stamped when sent");
        // Moving at 10 mm/s, readbacks every 100 ms: one message each, with the velocity.
        states.update("m1", Field::DMOV, 0.0, at(1050));
        states.update("m1", Field::RBV, 6.0, at(1100));
        states.update("m1", Field::RBV, 7.0, at(1200));
        let moving = states.poll_publish(at(1230)).expect("a new readback");
        assert!((moving.velocity[0] - 0.01).abs() < 1e-12, "{:?}", moving.velocity);
        assert_eq!(moving.header.stamp.nanosec, 200_000_000, "stamped with the readback's time");
        assert_eq!(states.poll_publish(at(1229)), None, "nothing new");
        // Readbacks closer than the interval make one message.
        states.update("m1", Field::RBV, 7.1, at(1231));
        states.update("m2", Field::RBV, 90.5, at(1232));
        assert_eq!(states.poll_publish(at(1235)), None, "within 10 ms of the last");
        assert_eq!(states.poll_timeout(), Some(at(1240)));
        let both = states.poll_publish(at(1240)).expect("both readbacks in one message");
        assert!((both.position[0] - 0.0071).abs() < 1e-15 && both.header.stamp.nanosec == 232_000_000, "{both:?}");
        states.update("m1", Field::DMOV, 1.0, at(1255));
        assert_eq!(states.poll_publish(at(1260)).map(|s| s.velocity[0]), Some(0.0), "at rest: no velocity");
    }

    #[test]
    fn a_command_becomes_targets_in_axis_units_all_or_nothing() {
        let states = two_joints();
        let command = |names: &[&str], positions: &[f64]| JointState {
            name: names.iter().map(|n| n.to_string()).collect(),
            position: positions.to_vec(),
            ..JointState::default()
        };
        let targets = states.command(&command(&["turn", "lift"], &[std::f64::consts::PI, 0.0125])).unwrap();
        assert_eq!(targets[0].0, "m2");
        assert!((targets[0].1 - 180.0).abs() < 1e-9 && targets[1] == ("m1".to_string(), 12.5));
        assert_eq!(
            states.command(&command(&["lift", "wrist"], &[0.0, 0.0])),
            Err(JointCommandError::UnknownJoint("wrist".into()))
        );
        assert_eq!(
            states.command(&command(&["lift", "turn"], &[0.0])),
            Err(JointCommandError::Positions { names: 2, positions: 1 })
        );
        assert_eq!(states.command(&command(&["lift"], &[f64::NAN])), Err(JointCommandError::NotFinite("lift".into())));
        // 1e308 rad is a number but no number of degrees: nothing moves, not even the lift.
        assert_eq!(
            states.command(&command(&["lift", "turn"], &[0.001, 1e308])),
            Err(JointCommandError::NotFinite("turn".into()))
        );
    }

    /// How long the record's move of `way` at VELO `speed` lasts with `ramp` (its acceleration
    /// from VBAS to VELO and back, behaviour spec §4), worked out as the motion goes.
    fn move_time(ramp: &Ramp, way: f64, speed: f64) -> f64 {
        let base = ramp.base_speed;
        let acceleration = ramp.acceleration.unwrap_or((speed - base) / ramp.seconds);
        let ramp_time = (speed - base) / acceleration;
        let ramp_way = (speed + base) / 2.0 * ramp_time;
        if 2.0 * ramp_way <= way {
            2.0 * ramp_time + (way - 2.0 * ramp_way) / speed
        } else {
            let peak = (base * base + acceleration * way).sqrt();
            2.0 * (peak - base) / acceleration
        }
    }

    #[test]
    fn a_ramps_speed_makes_the_move_last_the_time_asked_ramps_included() {
        let ramps = [
            Ramp { seconds: 0.5, base_speed: 0.0, acceleration: None },
            Ramp { seconds: 0.2, base_speed: 1.0, acceleration: None },
            Ramp { seconds: 0.2, base_speed: 0.0, acceleration: Some(10.0) },
            Ramp { seconds: 0.2, base_speed: 0.5, acceleration: Some(40.0) },
        ];
        for ramp in &ramps {
            for (way, time) in [(10.0, 2.0), (10.0, 3.0), (1.0, 0.8), (0.3, 0.25), (-4.0, 1.5)] {
                let speed = ramp.speed_for(way, time);
                let (plain, base) = (f64::abs(way) / time, ramp.base_speed);
                // At ACCS, a move can only go so far in the time: a triangle at that acceleration.
                let reachable = ramp.acceleration.is_none_or(|a| f64::abs(way) <= base * time + a * time * time / 4.0);
                if reachable {
                    let lasts = move_time(ramp, f64::abs(way), speed);
                    assert!((lasts - time).abs() < 1e-9, "{ramp:?}: {way} in {time} s at {speed}: lasts {lasts} s");
                } else {
                    assert_eq!(speed, plain, "{ramp:?}: {way} in {time} s cannot be met");
                }
                assert!(speed >= plain, "never slower than the plain quotient");
            }
        }
        // Where no speed meets the time, the plain quotient: ACCS too low for 10 in 2 s, and a
        // way shorter than the base speed's ramps.
        let slow = Ramp { seconds: 0.2, base_speed: 0.0, acceleration: Some(1.0) };
        assert_eq!(slow.speed_for(10.0, 2.0), 5.0);
        let based = Ramp { seconds: 1.0, base_speed: 5.0, acceleration: None };
        assert_eq!(based.speed_for(1.0, 4.0), 0.25);
        // Known values: 10 mm in 2 s with 0.5 s ramps is VELO 10 / 1.5.
        assert!((ramps[0].speed_for(10.0, 2.0) - 10.0 / 1.5).abs() < 1e-12);
    }
}
