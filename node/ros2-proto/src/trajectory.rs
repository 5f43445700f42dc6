//! The `FollowJointTrajectory` action server, sans-IO: goals checked against the joints
//! (unknown joints, positions beyond the soft limits, time going backwards), then executed as
//! timed moves, one per stretch of the path. A stretch runs through the points that lie on one
//! straight line in joint space (every joint's position the same share of its way at each,
//! within the joint's path tolerance, or else its RDBD, where the record takes a move as done)
//! and ends where the path turns, rests (stays at a point, or every joint is given a velocity of
//! 0 there), ends, or after 500 points: the motor record stops at the end of every move, and a
//! planner's many close waypoints (MoveIt's, on lines between its via-states) must not each
//! become a stop, nor may a merge cut the corners the planner checked. A stretch starts when its
//! time has come and every joint has ended the one before, each joint moving at the speed that
//! ends it in its time, its record's ramps included (`Ramp`), never faster for the ramps' sake
//! than its VELO from before the goal (VELO, restored when the goal ends; a point due at once
//! goes at the speed from before the goal). A joint with no way to go in a stretch is not sent
//! one. The result comes when every joint has arrived (the motion's end, as a waiting write reports it),
//! not before the last point's time; a cancel stops the joints. A trajectory from the topic
//! (`follow_trajectory`) runs as a goal no one follows. The controller's state
//! (`controller_state`) is the trajectory's sample beside the joints' readbacks. Time is given (since the Unix epoch: it
//! stamps goals and feedback).
//!
//! The goal's life follows `action_msgs/msg/GoalStatus`: accepted goals execute at once (one at
//! a time: a goal accepted while another executes replaces it, as joint_trajectory_controller
//! does, once that one's joints have stopped), then end SUCCEEDED, ABORTED or, after
//! CANCELING, CANCELED. Path tolerances bound the merging of points into stretches but
//! are not checked while moving, nor is `goal_time_tolerance` (the record's own deadband and
//! retries decide arrival); goal position tolerances are.

use crate::follow::{
    CancelGoalRequest, CancelGoalResponse, ControllerState, FeedbackMessage, GetResultResponse, GoalId, GoalInfo,
    GoalStatusArray, GoalStatusEntry, JointTolerance, JointTrajectory, JointTrajectoryPoint, RosDuration,
    SendGoalRequest, TrajectoryFeedback, TrajectoryGoal, TrajectoryResult,
};
use crate::joints::{JointStates, Ramp};
use crate::messages::{Header, JointState, Time};
use std::collections::VecDeque;
use std::time::Duration;

/// `action_msgs/msg/GoalStatus` codes.
pub mod status {
    /// Not known.
    pub const UNKNOWN: i8 = 0;
    /// Executing.
    pub const EXECUTING: i8 = 2;
    /// Stopping after a cancel.
    pub const CANCELING: i8 = 3;
    /// Every joint arrived.
    pub const SUCCEEDED: i8 = 4;
    /// Stopped by a cancel.
    pub const CANCELED: i8 = 5;
    /// Ended by a failure.
    pub const ABORTED: i8 = 6;
}

/// `FollowJointTrajectory` result codes.
mod error_code {
    pub(super) const SUCCESSFUL: i32 = 0;
    pub(super) const INVALID_GOAL: i32 = -1;
    pub(super) const PATH_TOLERANCE_VIOLATED: i32 = -4;
    pub(super) const GOAL_TOLERANCE_VIOLATED: i32 = -5;
}

/// `CancelGoal` return codes.
mod cancel_code {
    pub(super) const NONE: i8 = 0;
    pub(super) const REJECTED: i8 = 1;
    pub(super) const UNKNOWN_GOAL_ID: i8 = 2;
    pub(super) const GOAL_TERMINATED: i8 = 3;
}

/// Why a goal was not accepted.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum GoalRejection {
    /// A joint this node does not have.
    #[error("no joint named '{0}'")]
    UnknownJoint(String),
    /// A joint named twice.
    #[error("joint '{0}' is named twice")]
    DuplicateJoint(String),
    /// A multi-DOF trajectory.
    #[error("multi-DOF trajectories are not served: each joint here is one axis")]
    MultiDof,
    /// No points.
    #[error("the trajectory has no points")]
    NoPoints,
    /// A point whose positions do not match the joints.
    #[error("point {point}: {got} positions for {expected} joints")]
    Positions {
        /// The point's index.
        point: usize,
        /// Joints named.
        expected: usize,
        /// Positions given.
        got: usize,
    },
    /// A position that is not a number, or none in its axis's units (1e308 rad in degrees).
    #[error("point {point}: joint '{joint}': the position is not a finite number in its axis's units")]
    NotFinite {
        /// The point's index.
        point: usize,
        /// The joint.
        joint: String,
    },
    /// A point due before the one before it.
    #[error("point {point}: time_from_start is negative or before the previous point's")]
    TimeBackwards {
        /// The point's index.
        point: usize,
    },
    /// A target beyond a joint's soft limits.
    #[error("point {point}: joint '{joint}': {target} (its axis's units) is beyond the soft limits [{low}, {high}]")]
    BeyondLimits {
        /// The point's index.
        point: usize,
        /// The joint.
        joint: String,
        /// The target, in the axis's EGU.
        target: f64,
        /// LLM.
        low: f64,
        /// HLM.
        high: f64,
    },
    /// A joint whose axis has not yet said where it is and what its limits are.
    #[error("joint '{0}': its axis's position, limits and speed are not known yet")]
    NotReady(String),
    /// A goal id already used by a goal kept here (rcl_action refuses it too).
    #[error("the goal id is a known goal's")]
    KnownId,
    /// No joint named.
    #[error("the trajectory names no joint")]
    NoJoints,
    /// Velocities or accelerations given, but not one per joint.
    #[error("point {point}: {got} {what} for {expected} joints")]
    Derivatives {
        /// The point's index.
        point: usize,
        /// "velocities" or "accelerations".
        what: &'static str,
        /// Joints named.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// A start stamp so far back that the last point is already past (joint_trajectory_controller
    /// refuses it too: its points would be replayed from now, late).
    #[error("the trajectory, stamped to start in the past, ends in the past")]
    EndsInThePast,
}

impl CancelGoalResponse {
    /// The answer to a cancel request that cannot be read.
    #[must_use]
    pub fn rejected() -> Self {
        Self { return_code: cancel_code::REJECTED, goals_canceling: Vec::new() }
    }
}

impl GetResultResponse {
    /// The answer to a result request that cannot be read (status UNKNOWN).
    #[must_use]
    pub fn unknown() -> Self {
        Self { status: status::UNKNOWN, result: TrajectoryResult::default() }
    }
}

/// What the gateway is to do for a goal.
#[derive(Clone, Debug, PartialEq)]
pub enum JointCommand {
    /// Write VELO (when a speed is given) then VAL, and report the motion's end with
    /// `move_ended`; `duration` is the stretch's planned time.
    Move {
        /// The axis.
        axis: String,
        /// VAL, EGU.
        target: f64,
        /// VELO, EGU/s; none for a point due at once (the axis's own speed).
        speed: Option<f64>,
        /// The stretch's planned time.
        duration: Duration,
    },
    /// Write STOP.
    Stop {
        /// The axis.
        axis: String,
    },
    /// Write VELO back to what it was before the goal.
    RestoreSpeed {
        /// The axis.
        axis: String,
        /// VELO, EGU/s.
        speed: f64,
    },
}

/// How a joint's move ended.
#[derive(Clone, Debug, PartialEq)]
pub enum MoveEnd {
    /// At its target.
    Reached,
    /// Refused, stopped short or unanswered: why.
    Failed(String),
}

/// One joint of an executing goal.
#[derive(Clone, Debug)]
struct PlannedJoint {
    /// Its index in `JointStates`.
    index: usize,
    axis: String,
    si_per_egu: f64,
    /// Where it was when the goal was accepted, EGU.
    from: f64,
    /// VELO then, to restore; whether the goal changed it.
    speed: f64,
    speed_changed: bool,
    /// The goal position tolerance, EGU.
    tolerance: Option<f64>,
    /// How far off the planned path it may pass, EGU: the goal's path tolerance, or else its
    /// axis's RDBD (where the record takes a move as done).
    off_path: f64,
    /// Where it was last sent (or stood), EGU.
    sent_to: f64,
    /// How its axis speeds up and slows down, when known.
    ramp: Option<Ramp>,
    /// A move commanded whose end has not come.
    in_flight: bool,
}

/// A point of a goal's trajectory.
#[derive(Clone, Debug)]
struct Waypoint {
    /// Its time from the start.
    at: Duration,
    /// Each joint's target, EGU, in `Plan::joints`' order.
    targets: Vec<f64>,
    /// Every joint is to be at rest there (velocities of 0 given).
    resting: bool,
}

/// An executing goal.
#[derive(Clone, Debug)]
struct Plan {
    /// Its goal's id; none for a trajectory from the topic, which no one follows.
    id: Option<GoalId>,
    joints: Vec<PlannedJoint>,
    points: Vec<Waypoint>,
    /// The points where the stretches end, in order (the last point last).
    stretch_ends: Vec<usize>,
    /// The next stretch to command.
    next: usize,
    start: Duration,
    /// The end decided (a failure, a cancel) while moves are still in flight.
    ending: Option<(i8, TrajectoryResult)>,
}

impl Plan {
    fn busy(&self) -> bool {
        self.joints.iter().any(|j| j.in_flight)
    }

    /// The point the stretch `i` starts from; none for the first (from where the joints stood).
    fn stretch_start(&self, i: usize) -> Option<usize> {
        i.checked_sub(1).map(|before| self.stretch_ends[before])
    }

    /// The time from the start of point `i`, or of the goal's start for none.
    fn time_of(&self, point: Option<usize>) -> Duration {
        point.map_or(Duration::ZERO, |i| self.points[i].at)
    }

    /// When the next stretch may start, if only time holds it back.
    fn next_due(&self) -> Option<Duration> {
        let ready = !self.busy() && self.ending.is_none() && self.next < self.stretch_ends.len();
        ready.then(|| self.start + self.time_of(self.stretch_start(self.next)))
    }

    /// When the goal may end, once its joints have ended every stretch: at its last point's time
    /// (a goal to where the joints are lasts its time).
    fn end_due(&self) -> Option<Duration> {
        let ready = !self.busy() && self.ending.is_none() && self.next == self.stretch_ends.len();
        ready.then(|| self.start + self.points[self.points.len() - 1].at)
    }

    /// Start the next stretch: a move for each joint that has a way to go in it.
    fn start_stretch(&mut self) -> Vec<JointCommand> {
        let (start, end) = (self.stretch_start(self.next), self.stretch_ends[self.next]);
        self.next += 1;
        let time = self.points[end].at.saturating_sub(self.time_of(start));
        let mut commands = Vec::new();
        for (k, joint) in self.joints.iter_mut().enumerate() {
            let (from, target) = (joint.sent_to, self.points[end].targets[k]);
            if within(target, from, 0.0) {
                continue;
            }
            joint.sent_to = target;
            // A point due at once goes at the speed from before the goal, not the last stretch's.
            let speed = if time.is_zero() {
                joint.speed_changed.then_some(joint.speed)
            } else {
                let (way, seconds) = (target - from, time.as_secs_f64());
                let plain = way.abs() / seconds;
                let ramped = joint.ramp.map_or(plain, |ramp| ramp.speed_for(way, seconds));
                // For the ramps' sake never faster than the axis's own VELO (with ACCL, faster is
                // also a harder acceleration than the one set up): only as fast as the plan asks.
                Some(ramped.min(plain.max(joint.speed)))
            };
            joint.speed_changed |= speed.is_some();
            joint.in_flight = true;
            commands.push(JointCommand::Move { axis: joint.axis.clone(), target, speed, duration: time });
        }
        commands
    }

    /// Where joint `k` should be at `now` on the trajectory as planned, and how fast it should
    /// go there (EGU, EGU/s): on the line between the points about it, as
    /// joint_trajectory_controller interpolates positions alone; at rest before the start and
    /// past the last point.
    fn desired(&self, k: usize, now: Duration) -> (f64, f64) {
        let mut before = (Duration::ZERO, self.joints[k].from);
        if now < self.start {
            // A goal stamped ahead: where the joint stands until then.
            return (before.1, 0.0);
        }
        let t = now - self.start;
        for point in &self.points {
            let to = point.targets[k];
            if t < point.at {
                let span = (point.at - before.0).as_secs_f64();
                let share = (t - before.0).as_secs_f64() / span;
                return (before.1 + (to - before.1) * share, (to - before.1) / span);
            }
            before = (point.at, to);
        }
        (before.1, 0.0)
    }

    /// Stop every joint still moving, ending the goal with `status` and `result` once stopped
    /// (the first end decided stands).
    fn end_with(&mut self, status: i8, result: TrajectoryResult) -> Vec<JointCommand> {
        if self.ending.is_some() {
            return Vec::new();
        }
        self.ending = Some((status, result));
        self.joints.iter().filter(|j| j.in_flight).map(|j| JointCommand::Stop { axis: j.axis.clone() }).collect()
    }
}

/// A goal the server knows: its id, stamp, status and, once ended, its result.
#[derive(Clone, Debug)]
struct Goal {
    info: GoalInfo,
    status: i8,
    result: Option<TrajectoryResult>,
}

/// A goal accepted while another ran: it starts once that one's joints have stopped.
#[derive(Clone, Debug)]
struct Waiting {
    id: Option<GoalId>,
    goal: TrajectoryGoal,
    accepted: Duration,
}

/// The end of a goal a new goal replaced, as joint_trajectory_controller (Jazzy) ends it, or a
/// trajectory from the topic (which that controller follows beside the goal, no longer
/// judging it by its own points).
fn preempted(by_topic: bool) -> TrajectoryResult {
    let error_string = if by_topic {
        "Current goal preempted by a trajectory on joint_trajectory."
    } else {
        "Current goal preempted by new incoming action."
    };
    TrajectoryResult { error_code: error_code::INVALID_GOAL, error_string: error_string.to_string() }
}

/// How many ended goals keep their results.
const KEPT_GOALS: usize = 16;

/// The action server's state (see the module documentation).
#[derive(Clone, Debug, Default)]
pub struct FollowJointTrajectory {
    goals: VecDeque<Goal>,
    plan: Option<Plan>,
    waiting: Option<Waiting>,
    /// Trajectories from the topic that could not start once the one they replaced had
    /// stopped (a goal says so in its result), for the gateway to log.
    refusals: Vec<GoalRejection>,
    status_changed: bool,
    /// Speeds ended goals restore, by axis (VELO before them), until the restore's write has
    /// ended (`restored`): a goal accepted meanwhile restores that speed, not the last stretch's.
    restoring: Vec<(String, f64)>,
}

fn stamp(now: Duration) -> Time {
    Time { sec: i32::try_from(now.as_secs()).unwrap_or(i32::MAX), nanosec: now.subsec_nanos() }
}

/// A goal stamped before this (2001-09-09) is of another clock than this host's: simulated
/// time, counted from the simulation's start; it starts now.
const WALL_CLOCK_SINCE: Duration = Duration::from_secs(1_000_000_000);

fn since_epoch(time: Time) -> Option<Duration> {
    let sec = u64::try_from(time.sec).ok()?;
    Some(Duration::new(sec, 0) + Duration::from_nanos(u64::from(time.nanosec)))
}

impl FollowJointTrajectory {
    /// A server with no goals.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// A goal sent at `now`: accepted (it executes at once) or rejected, saying why. As
    /// joint_trajectory_controller does, a goal accepted while another executes replaces it: that
    /// one ends ABORTED (its joints stopped: the commands returned), and this one starts from
    /// where they stopped, its times counted from now.
    pub fn send_goal(
        &mut self,
        request: &SendGoalRequest,
        joints: &JointStates,
        now: Duration,
    ) -> Result<Vec<JointCommand>, GoalRejection> {
        if self.goals.iter().any(|g| g.info.goal_id == request.goal_id) {
            return Err(GoalRejection::KnownId);
        }
        let commands = self.accept(Some(request.goal_id), &request.goal, joints, now)?;
        self.goals.push_back(Goal {
            info: GoalInfo { goal_id: request.goal_id, stamp: stamp(now) },
            status: status::EXECUTING,
            result: None,
        });
        // Ended goals beyond the newest KEPT_GOALS are forgotten; one running or stopping is not.
        let mut ended = self.goals.iter().filter(|g| g.result.is_some()).count();
        self.goals.retain(|g| {
            let forget = ended > KEPT_GOALS && g.result.is_some();
            ended -= usize::from(forget);
            !forget
        });
        self.status_changed = true;
        Ok(commands)
    }

    /// A trajectory published on `<namespace>/joint_trajectory` at `now` (as on
    /// joint_trajectory_controller's `~/joint_trajectory`): run as a goal no one follows (no
    /// status, feedback or result; a cancel does not reach it), replacing the goal running as a
    /// goal does, and replaced by the next trajectory or goal; or rejected, saying why.
    pub fn follow_trajectory(
        &mut self,
        trajectory: &JointTrajectory,
        joints: &JointStates,
        now: Duration,
    ) -> Result<Vec<JointCommand>, GoalRejection> {
        let goal = TrajectoryGoal { trajectory: trajectory.clone(), ..TrajectoryGoal::default() };
        self.accept(None, &goal, joints, now)
    }

    /// Plan `goal` (the goal `id`, or a trajectory from the topic) and run it, or keep it until
    /// the one running, which it replaces, has stopped (the commands returned stop it).
    fn accept(
        &mut self,
        id: Option<GoalId>,
        goal: &TrajectoryGoal,
        joints: &JointStates,
        now: Duration,
    ) -> Result<Vec<JointCommand>, GoalRejection> {
        let plan = plan(id, goal, joints, now)?;
        let Some(running) = &mut self.plan else {
            self.start(plan);
            return Ok(Vec::new());
        };
        let commands = running.end_with(status::ABORTED, preempted(id.is_none()));
        if let Some(earlier) = self.waiting.take() {
            self.finish(earlier.id, status::ABORTED, preempted(id.is_none()));
        }
        // Planned again when it starts, from where the joints stopped.
        self.waiting = Some(Waiting { id, goal: goal.clone(), accepted: now });
        Ok(commands)
    }

    /// Execute `plan`.
    fn start(&mut self, mut plan: Plan) {
        for joint in &mut plan.joints {
            // A restore not seen yet: what this goal restores is the speed from before the last.
            if let Some((_, before)) = self.restoring.iter().find(|(axis, _)| *axis == joint.axis) {
                joint.speed = *before;
            }
        }
        self.plan = Some(plan);
    }

    /// The write restoring `axis`'s speed has ended (taken or not): from now on its VELO, as
    /// posted, is the speed a goal restores.
    pub fn restored(&mut self, axis: &str) {
        self.restoring.retain(|(restoring, _)| restoring != axis);
    }

    /// Whether a goal is executing (or stopping, or waiting for the one it replaced to stop).
    #[must_use]
    pub fn executing(&self) -> bool {
        self.plan.is_some() || self.waiting.is_some()
    }

    /// What to do at `now`: the moves of the stretch due, or the goal's end.
    #[must_use]
    pub fn poll(&mut self, joints: &JointStates, now: Duration) -> Vec<JointCommand> {
        let mut commands = Vec::new();
        while let Some(running) = &mut self.plan {
            // A stretch no joint has a way to go in ends at once: until one moves or none is due.
            while running.next_due().is_some_and(|due| now >= due) {
                commands.extend(running.start_stretch());
            }
            if running.busy() {
                break;
            }
            let end = match running.ending.take() {
                Some(end) => end,
                None if running.end_due().is_some_and(|due| now >= due) => arrival(running, joints),
                None => break,
            };
            for joint in running.joints.iter().filter(|j| j.speed_changed) {
                commands.push(JointCommand::RestoreSpeed { axis: joint.axis.clone(), speed: joint.speed });
                self.restoring.retain(|(axis, _)| *axis != joint.axis);
                self.restoring.push((joint.axis.clone(), joint.speed));
            }
            let id = running.id;
            self.plan = None;
            self.finish(id, end.0, end.1);
            // The goal that replaced it starts, from where the joints stopped.
            let Some(next) = self.waiting.take() else { break };
            match plan(next.id, &next.goal, joints, next.accepted) {
                Ok(plan) => self.start(plan),
                Err(why) if next.id.is_none() => self.refusals.push(why),
                Err(why) => {
                    let result =
                        TrajectoryResult { error_code: error_code::INVALID_GOAL, error_string: why.to_string() };
                    self.finish(next.id, status::ABORTED, result);
                }
            }
        }
        commands
    }

    /// A trajectory from the topic accepted while another ran that could not start once it had
    /// stopped (the joints' limits changed meanwhile), and why.
    #[must_use]
    pub fn poll_refusal(&mut self) -> Option<GoalRejection> {
        (!self.refusals.is_empty()).then(|| self.refusals.remove(0))
    }

    /// When `poll` is next due without another event (it is due after every event and call too:
    /// an end decided by one, a cancel or a failure, is carried out there).
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Duration> {
        let plan = self.plan.as_ref()?;
        plan.next_due().or_else(|| plan.end_due())
    }

    /// The end of the move `axis` was sent; a failure aborts the goal, stopping the others.
    #[must_use]
    pub fn move_ended(&mut self, axis: &str, end: MoveEnd) -> Vec<JointCommand> {
        let Some(plan) = &mut self.plan else { return Vec::new() };
        let Some(joint) = plan.joints.iter_mut().find(|j| j.axis == axis && j.in_flight) else { return Vec::new() };
        joint.in_flight = false;
        match end {
            MoveEnd::Reached => Vec::new(),
            MoveEnd::Failed(why) => {
                let error_string = format!("axis '{axis}': {why}");
                let result = TrajectoryResult { error_code: error_code::PATH_TOLERANCE_VIOLATED, error_string };
                plan.end_with(status::ABORTED, result)
            }
        }
    }

    /// A cancel request: the executing goal, if it is one the request names, stops.
    #[must_use]
    pub fn cancel(&mut self, request: &CancelGoalRequest) -> (CancelGoalResponse, Vec<JointCommand>) {
        let GoalInfo { goal_id, stamp: before } = request.goal_info;
        let every = goal_id == GoalId::default();
        let named = self.goals.iter().find(|g| g.info.goal_id == goal_id);
        if !every && named.is_none() {
            return (
                CancelGoalResponse { return_code: cancel_code::UNKNOWN_GOAL_ID, goals_canceling: Vec::new() },
                Vec::new(),
            );
        }
        let cutoff = since_epoch(before).filter(|t| !t.is_zero());
        let matches = |goal: &Goal| {
            (every && cutoff.is_none())
                || goal.info.goal_id == goal_id
                || cutoff.is_some_and(|cut| since_epoch(goal.info.stamp).is_some_and(|at| at <= cut))
        };
        let mut canceling = Vec::new();
        let mut commands = Vec::new();
        let canceled = || TrajectoryResult { error_code: error_code::SUCCESSFUL, error_string: "canceled".into() };
        let waiting = self.waiting.as_ref().and_then(|w| self.goals.iter().find(|g| Some(g.info.goal_id) == w.id));
        let mut replacement_canceled = false;
        if let Some(goal) = waiting.filter(|goal| matches(goal)) {
            // Not started: it ends at once.
            let (info, id) = (goal.info, goal.info.goal_id);
            canceling.push(info);
            self.waiting = None;
            replacement_canceled = true;
            self.finish(Some(id), status::CANCELED, canceled());
        }
        // A trajectory from the topic is no goal: no cancel reaches it.
        let running = self.plan.as_mut().and_then(|plan| {
            let goal = self.goals.iter_mut().find(|g| Some(g.info.goal_id) == plan.id)?;
            Some((plan, goal))
        });
        if let Some((plan, goal)) = running {
            if matches(goal) && goal.status == status::EXECUTING {
                goal.status = status::CANCELING;
                self.status_changed = true;
                canceling.push(goal.info);
                commands = plan.end_with(status::CANCELED, canceled());
                let preempted = [preempted(false), preempted(true)];
                if replacement_canceled && plan.ending.as_ref().is_some_and(|(_, why)| preempted.contains(why)) {
                    // Stopping for a goal no longer coming: it ends as cancelled, not replaced.
                    plan.ending = Some((status::CANCELED, canceled()));
                }
            } else if matches(goal) && goal.status == status::CANCELING {
                canceling.push(goal.info);
            }
        }
        let return_code = if canceling.is_empty() && !every { cancel_code::GOAL_TERMINATED } else { cancel_code::NONE };
        (CancelGoalResponse { return_code, goals_canceling: canceling }, commands)
    }

    /// The result of goal `id` once it has ended (a goal not known answers at once with status
    /// UNKNOWN); none while it runs: answer when it ends.
    #[must_use]
    pub fn result(&self, id: &GoalId) -> Option<GetResultResponse> {
        match self.goals.iter().find(|g| &g.info.goal_id == id) {
            None => Some(GetResultResponse { status: status::UNKNOWN, result: TrajectoryResult::default() }),
            Some(goal) => goal.result.clone().map(|result| GetResultResponse { status: goal.status, result }),
        }
    }

    /// Every goal's status, when it changed since the last call.
    #[must_use]
    pub fn poll_status(&mut self) -> Option<GoalStatusArray> {
        if !std::mem::take(&mut self.status_changed) {
            return None;
        }
        let status_list = self.goals.iter().map(|g| GoalStatusEntry { goal_info: g.info, status: g.status }).collect();
        Some(GoalStatusArray { status_list })
    }

    /// The executing goal's feedback at `now`: where its joints should be (on the trajectory as
    /// planned), where they are, and the difference, in SI units.
    #[must_use]
    pub fn feedback(&self, joints: &JointStates, now: Duration) -> Option<FeedbackMessage> {
        // A goal replaced is stopping: it has no feedback, nor has the new one before it starts.
        let plan = self.plan.as_ref().filter(|_| self.waiting.is_none())?;
        let goal_id = plan.id?;
        let names: Vec<String> = plan.joints.iter().map(|j| joints.joints()[j.index].name.clone()).collect();
        let (mut desired, mut actual) = (Vec::new(), Vec::new());
        for (k, joint) in plan.joints.iter().enumerate() {
            let position = joints.joint_state(joint.index)?.position;
            desired.push(plan.desired(k, now).0 * joint.si_per_egu);
            actual.push(position * joint.si_per_egu);
        }
        // As joint_trajectory_controller computes it (and control_msgs defines it): reference −
        // feedback, the way the joint still has to go.
        let error = desired.iter().zip(&actual).map(|(d, a)| d - a).collect();
        let point = |positions| JointTrajectoryPoint { positions, ..JointTrajectoryPoint::default() };
        Some(FeedbackMessage {
            goal_id,
            feedback: TrajectoryFeedback {
                header: Header { stamp: stamp(now), frame_id: String::new() },
                joint_names: names,
                desired: point(desired),
                actual: point(actual),
                error: point(error),
                ..TrajectoryFeedback::default()
            },
        })
    }

    /// The controller's state as `state` (a `joint_states` message of every joint) shows it,
    /// as joint_trajectory_controller publishes it on `~/controller_state`, in SI units. The
    /// reference of a joint of the running trajectory is that trajectory's sample at the state's
    /// stamp (position, velocity, time from its start); of a joint being stopped (a goal
    /// cancelled, failed or replaced), where it is, at rest, as that controller holds a joint it
    /// stops; of any other, where its axis is sent (VAL), at rest. Feedback is the state; error is
    /// reference − feedback (velocities too); output is where each axis is sent (VAL: what
    /// the hardware was commanded).
    #[must_use]
    pub fn controller_state(&self, joints: &JointStates, state: &JointState) -> ControllerState {
        let stamp = &state.header.stamp;
        let at = Duration::new(u64::try_from(stamp.sec).unwrap_or(0), stamp.nanosec);
        let running = self.plan.as_ref().filter(|plan| plan.ending.is_none() && self.waiting.is_none());
        let stopping = self.plan.as_ref().filter(|_| running.is_none());
        let mut reference = JointTrajectoryPoint::default();
        let mut error = JointTrajectoryPoint::default();
        let mut output = JointTrajectoryPoint::default();
        let readings = state.position.iter().zip(&state.velocity);
        for (i, (joint, (&position, &velocity))) in joints.joints().iter().zip(readings).enumerate() {
            let sent = joints.target(i).map_or(position, |target| target * joint.si_per_egu);
            let of = |plan: &Plan| plan.joints.iter().position(|j| j.index == i);
            let (want, speed) = match (running.and_then(|p| of(p).map(|k| p.desired(k, at))), stopping.and_then(of)) {
                (Some((want, speed)), _) => (want * joint.si_per_egu, speed * joint.si_per_egu),
                (None, Some(_)) => (position, 0.0),
                (None, None) => (sent, 0.0),
            };
            reference.positions.push(want);
            reference.velocities.push(speed);
            reference.accelerations.push(0.0);
            error.positions.push(want - position);
            error.velocities.push(speed - velocity);
            output.positions.push(sent);
        }
        if let Some(plan) = running {
            let since = at.saturating_sub(plan.start);
            reference.time_from_start =
                RosDuration { sec: i32::try_from(since.as_secs()).unwrap_or(i32::MAX), nanosec: since.subsec_nanos() };
        }
        let feedback = JointTrajectoryPoint {
            positions: state.position.clone(),
            velocities: state.velocity.clone(),
            ..JointTrajectoryPoint::default()
        };
        ControllerState {
            header: state.header.clone(),
            joint_names: state.name.clone(),
            reference,
            feedback,
            error,
            output,
            speed_scaling_factor: 1.0,
            ..ControllerState::default()
        }
    }

    /// Goal `id` has ended so (nothing for a trajectory from the topic).
    fn finish(&mut self, id: Option<GoalId>, status: i8, result: TrajectoryResult) {
        if let Some(goal) = self.goals.iter_mut().find(|g| Some(g.info.goal_id) == id) {
            goal.status = status;
            goal.result = Some(result);
            self.status_changed = true;
        }
    }
}

/// The end of a goal whose every stretch is done: success when each joint is within its goal
/// tolerance.
fn arrival(plan: &Plan, joints: &JointStates) -> (i8, TrajectoryResult) {
    let last = &plan.points[plan.points.len() - 1].targets;
    for (k, joint) in plan.joints.iter().enumerate() {
        let (Some(tolerance), Some(reading)) = (joint.tolerance, joints.joint_state(joint.index)) else { continue };
        let rbv = reading.position;
        if (rbv - last[k]).abs() > tolerance {
            let error_string = format!(
                "axis '{}' ended at {rbv}, {} from its goal {} (tolerance {tolerance}, its axis's units)",
                joint.axis,
                (rbv - last[k]).abs(),
                last[k]
            );
            return (
                status::ABORTED,
                TrajectoryResult { error_code: error_code::GOAL_TOLERANCE_VIOLATED, error_string },
            );
        }
    }
    (status::SUCCEEDED, TrajectoryResult { error_code: error_code::SUCCESSFUL, error_string: String::new() })
}

/// The goal checked and planned, or why not.
fn plan(id: Option<GoalId>, goal: &TrajectoryGoal, joints: &JointStates, now: Duration) -> Result<Plan, GoalRejection> {
    if !goal.multi_dof_trajectory.joint_names.is_empty() || !goal.multi_dof_trajectory.points.is_empty() {
        return Err(GoalRejection::MultiDof);
    }
    let trajectory = &goal.trajectory;
    if trajectory.points.is_empty() {
        return Err(GoalRejection::NoPoints);
    }
    if trajectory.joint_names.is_empty() {
        return Err(GoalRejection::NoJoints);
    }
    let mut planned = Vec::new();
    let mut travels = Vec::new();
    for (k, name) in trajectory.joint_names.iter().enumerate() {
        if trajectory.joint_names[..k].contains(name) {
            return Err(GoalRejection::DuplicateJoint(name.clone()));
        }
        let index = joints.joint_index(name).ok_or_else(|| GoalRejection::UnknownJoint(name.clone()))?;
        let reading = joints.joint_state(index).ok_or_else(|| GoalRejection::NotReady(name.clone()))?;
        let joint = &joints.joints()[index];
        let tolerance = |tolerances: &[JointTolerance]| {
            tolerances.iter().find(|t| &t.name == name && t.position > 0.0).map(|t| t.position / joint.si_per_egu)
        };
        travels.push(reading.travel);
        planned.push(PlannedJoint {
            index,
            axis: joint.axis.clone(),
            si_per_egu: joint.si_per_egu,
            from: reading.position,
            speed: reading.speed,
            speed_changed: false,
            tolerance: tolerance(&goal.goal_tolerance),
            off_path: tolerance(&goal.path_tolerance).unwrap_or(reading.deadband),
            sent_to: reading.position,
            ramp: reading.ramp,
            in_flight: false,
        });
    }
    let mut points = Vec::new();
    let mut previous = Duration::ZERO;
    for (i, point) in trajectory.points.iter().enumerate() {
        let (expected, got) = (planned.len(), point.positions.len());
        if got != expected {
            return Err(GoalRejection::Positions { point: i, expected, got });
        }
        for (what, values) in [("velocities", &point.velocities), ("accelerations", &point.accelerations)] {
            if !values.is_empty() && values.len() != expected {
                return Err(GoalRejection::Derivatives { point: i, what, expected, got: values.len() });
            }
        }
        let at = point.time_from_start.to_duration().filter(|at| *at >= previous);
        let at = at.ok_or(GoalRejection::TimeBackwards { point: i })?;
        previous = at;
        let mut targets = Vec::new();
        for (k, position) in point.positions.iter().enumerate() {
            let joint = trajectory.joint_names[k].clone();
            let target = position / planned[k].si_per_egu;
            if !target.is_finite() {
                return Err(GoalRejection::NotFinite { point: i, joint });
            }
            if let crate::joints::Travel::Within { low, high } = travels[k] {
                if !travels[k].allows(target) {
                    return Err(GoalRejection::BeyondLimits { point: i, joint, target, low, high });
                }
            }
            targets.push(target);
        }
        let resting = !point.velocities.is_empty() && point.velocities.iter().all(|v| *v == 0.0);
        points.push(Waypoint { at, targets, resting });
    }
    // A zero stamp is "start now"; so is one of simulated time.
    let stamp = since_epoch(trajectory.header.stamp).filter(|at| *at >= WALL_CLOCK_SINCE);
    if stamp.is_some_and(|start| start + previous < now) {
        return Err(GoalRejection::EndsInThePast);
    }
    // Started in the past (joint_trajectory_controller joins it where it is now): the points
    // already due are passed over, and the joints go from where they stand to the first point
    // to come, in the time left to it.
    let late = stamp.map_or(Duration::ZERO, |start| now.saturating_sub(start));
    if !late.is_zero() {
        let last = points.len() - 1;
        points = points.into_iter().enumerate().filter(|(i, p)| p.at > late || *i == last).map(|(_, p)| p).collect();
        points.iter_mut().for_each(|p| p.at = p.at.saturating_sub(late));
    }
    let stretch_ends = stretch_ends(&planned, &points);
    let start = stamp.filter(|at| *at > now).unwrap_or(now);
    Ok(Plan { id, joints: planned, points, stretch_ends, next: 0, start, ending: None })
}

/// How far apart `a` and `b` may be and count as one within `tolerance`: at least their last
/// bits (a planner's start point is the joint state it was given, in SI units, which converted
/// back may differ from the readback there).
fn allowance(a: f64, b: f64, tolerance: f64) -> f64 {
    tolerance.max(1e-12 * a.abs().max(b.abs()).max(1.0))
}

/// Whether two positions are one within `tolerance` (see `allowance`).
fn within(a: f64, b: f64, tolerance: f64) -> bool {
    (a - b).abs() <= allowance(a, b, tolerance)
}

/// The most points a stretch runs through: each point added checks those before it again, and a
/// goal is planned on the task that serves the joints.
const STRETCH_POINTS: usize = 500;

/// The points where the stretches of the path from where the `joints` stand through `points`
/// end (see the module documentation): a stretch goes on while the next point keeps its
/// positions on one straight line in joint space, each joint within its `off_path`.
fn stretch_ends(joints: &[PlannedJoint], points: &[Waypoint]) -> Vec<usize> {
    // Position 0 is where the joints stand, position i the point i − 1.
    let at = |i: usize, k: usize| if i == 0 { joints[k].from } else { points[i - 1].targets[k] };
    let straight = |first: usize, last: usize| {
        let way: Vec<f64> = (0..joints.len()).map(|k| at(last, k) - at(first, k)).collect();
        // The joint going furthest, counted in its tolerance, tells each point's share of the way;
        // a way of none (in the last bits) is a stay, no line.
        let scale = |k: usize| allowance(at(last, k), at(first, k), joints[k].off_path);
        let lead = (0..joints.len()).max_by(|&a, &b| (way[a].abs() / scale(a)).total_cmp(&(way[b].abs() / scale(b))));
        let Some(lead) = lead.filter(|&k| !within(at(last, k), at(first, k), 0.0)) else { return false };
        let mut share_before = 0.0;
        (first + 1..last).all(|i| {
            let share = (at(i, lead) - at(first, lead)) / way[lead];
            let on_line =
                (0..joints.len()).all(|k| within(at(i, k), at(first, k) + way[k] * share, joints[k].off_path));
            let onward = share > share_before && share < 1.0;
            share_before = share;
            onward && on_line
        })
    };
    let mut ends = Vec::new();
    let mut first = 0;
    while first < points.len() {
        let mut last = first + 1;
        while last < points.len()
            && last - first < STRETCH_POINTS
            && !points[last - 1].resting
            && straight(first, last + 1)
        {
            last += 1;
        }
        ends.push(last - 1);
        first = last;
    }
    ends
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::follow::RosDuration;
    use crate::joints::Joint;
    use zmotor_msgs::Field;

    const T0: Duration = Duration::from_secs(1_700_000_000);

    fn at(ms: u64) -> Duration {
        T0 + Duration::from_millis(ms)
    }

    /// Two joints: `lift` on m1 (mm, soft limits ±50) and `turn` on m2 (deg, no soft limits),
    /// both at 0, VELO 1.
    fn joints() -> JointStates {
        let lift = Joint::new("lift", "m1", "mm", None).unwrap();
        let turn = Joint::new("turn", "m2", "deg", None).unwrap();
        let mut states = JointStates::new(vec![lift, turn], Duration::from_secs(1), Duration::ZERO);
        for (axis, limits) in [("m1", [50.0, -50.0, 50.0, -50.0]), ("m2", [0.0; 4])] {
            states.update(axis, Field::RBV, 0.0, T0);
            states.update(axis, Field::DMOV, 1.0, T0);
            states.update(axis, Field::VELO, 1.0, T0);
            for (field, value) in [Field::HLM, Field::LLM, Field::DHLM, Field::DLLM].into_iter().zip(limits) {
                states.update(axis, field, value, T0);
            }
        }
        states
    }

    fn goal(names: &[&str], points: &[(u64, &[f64])]) -> SendGoalRequest {
        let points = points
            .iter()
            .map(|(ms, positions)| JointTrajectoryPoint {
                positions: positions.to_vec(),
                time_from_start: RosDuration { sec: (ms / 1000) as i32, nanosec: (ms % 1000) as u32 * 1_000_000 },
                ..JointTrajectoryPoint::default()
            })
            .collect();
        let trajectory = JointTrajectory {
            joint_names: names.iter().map(|n| n.to_string()).collect(),
            points,
            ..JointTrajectory::default()
        };
        SendGoalRequest { goal_id: [1; 16], goal: TrajectoryGoal { trajectory, ..TrajectoryGoal::default() } }
    }

    fn moves(commands: &[JointCommand]) -> Vec<(&str, f64, Option<f64>)> {
        commands
            .iter()
            .filter_map(|c| match c {
                JointCommand::Move { axis, target, speed, .. } => {
                    Some((axis.as_str(), *target, speed.map(|s| (s * 1e9).round() / 1e9)))
                }
                _ => None,
            })
            .collect()
    }

    #[test]
    fn three_points_with_turns_run_as_timed_moves_one_stretch_after_the_other_then_succeed() {
        let mut states = joints();
        let mut server = FollowJointTrajectory::new();
        // 10 mm and 90° in 2 s, then back to 5 mm in 1 s, then 180° in 3 s.
        let quarter = std::f64::consts::FRAC_PI_2;
        let request = goal(
            &["lift", "turn"],
            &[(2000, &[0.010, quarter]), (3000, &[0.005, quarter]), (6000, &[0.005, 2.0 * quarter])],
        );
        server.send_goal(&request, &states, at(0)).unwrap();
        let status = server.poll_status().expect("a new goal changes the status");
        assert_eq!((status.status_list.len(), status.status_list[0].status), (1, status::EXECUTING));
        assert_eq!(server.result(&[1; 16]), None, "no result while it runs");

        let first = server.poll(&states, at(0));
        assert_eq!(moves(&first), [("m1", 10.0, Some(5.0)), ("m2", 90.0, Some(45.0))]);
        assert_eq!(server.poll(&states, at(2500)), [], "not before both joints ended the stretch to the first point");
        assert_eq!(server.poll_timeout(), None, "waiting on the moves, not on time");
        assert_eq!(server.move_ended("m1", MoveEnd::Reached), []);
        assert_eq!(server.poll(&states, at(2500)), [], "m2 still moving");
        assert_eq!(server.move_ended("m2", MoveEnd::Reached), []);
        // Second stretch: only lift moves, 5 mm in 1 s; it is late (2.5 s), so it starts now.
        let second = server.poll(&states, at(2500));
        assert_eq!(moves(&second), [("m1", 5.0, Some(5.0))]);
        assert_eq!(server.move_ended("m1", MoveEnd::Reached), []);
        // Third: due at 3 s.
        assert_eq!(server.poll_timeout(), Some(at(3000)));
        assert_eq!(server.poll(&states, at(2900)), []);
        let third = server.poll(&states, at(3000));
        assert_eq!(moves(&third), [("m2", 180.0, Some(30.0))]);
        let feedback = server.feedback(&states, at(4500)).expect("feedback while executing");
        assert_eq!(feedback.feedback.joint_names, ["lift", "turn"]);
        assert!((feedback.feedback.desired.positions[1] - 1.5 * quarter).abs() < 1e-9, "half way between the points");
        let (desired, actual) = (&feedback.feedback.desired.positions, &feedback.feedback.actual.positions);
        assert_eq!(feedback.feedback.error.positions[1], desired[1] - actual[1], "reference − feedback, as JTC");
        assert!(feedback.feedback.error.positions[1] > 0.0, "the way still to go, forward");
        assert_eq!(server.move_ended("m2", MoveEnd::Reached), []);
        states.update("m1", Field::RBV, 5.0, at(6000));
        states.update("m2", Field::RBV, 180.0, at(6000));
        let end = server.poll(&states, at(6000));
        assert_eq!(
            end,
            [
                JointCommand::RestoreSpeed { axis: "m1".into(), speed: 1.0 },
                JointCommand::RestoreSpeed { axis: "m2".into(), speed: 1.0 }
            ]
        );
        let result = server.result(&[1; 16]).expect("ended");
        assert_eq!((result.status, result.result.error_code), (status::SUCCEEDED, 0));
        assert_eq!(server.poll_status().unwrap().status_list[0].status, status::SUCCEEDED);
        assert_eq!(server.feedback(&states, at(6000)), None);
    }

    #[test]
    fn a_goal_accepted_before_the_last_ones_speed_is_restored_restores_the_speed_from_before() {
        let mut states = joints();
        let mut server = FollowJointTrajectory::new();
        let mut request = goal(&["lift"], &[(2000, &[0.010])]);
        server.send_goal(&request, &states, at(0)).unwrap();
        assert_eq!(moves(&server.poll(&states, at(0))), [("m1", 10.0, Some(5.0))]);
        states.update("m1", Field::VELO, 5.0, at(10));
        assert_eq!(server.move_ended("m1", MoveEnd::Reached), []);
        states.update("m1", Field::RBV, 10.0, at(2000));
        let end = server.poll(&states, at(2000));
        assert_eq!(end, [JointCommand::RestoreSpeed { axis: "m1".into(), speed: 1.0 }]);
        // The next goal comes before VELO 1 is posted back: it restores 1, not 5 (nor VBAS, had
        // the record made the stretch's speed that).
        request.goal_id = [2; 16];
        request.goal.trajectory.points[0].positions = vec![0.0];
        server.send_goal(&request, &states, at(2001)).unwrap();
        assert_eq!(moves(&server.poll(&states, at(2001))), [("m1", 0.0, Some(5.0))]);
        assert_eq!(server.move_ended("m1", MoveEnd::Reached), []);
        states.update("m1", Field::RBV, 0.0, at(4001));
        let end = server.poll(&states, at(4001));
        assert_eq!(end, [JointCommand::RestoreSpeed { axis: "m1".into(), speed: 1.0 }]);
        // Once the restore's write has ended, the axis's own VELO is what the next goal restores.
        server.restored("m1");
        states.update("m1", Field::VELO, 2.0, at(5000));
        request.goal_id = [3; 16];
        request.goal.trajectory.points[0].positions = vec![0.010];
        server.send_goal(&request, &states, at(5000)).unwrap();
        let _ = server.poll(&states, at(5000));
        assert_eq!(server.move_ended("m1", MoveEnd::Reached), []);
        states.update("m1", Field::RBV, 10.0, at(7000));
        assert_eq!(server.poll(&states, at(7000)), [JointCommand::RestoreSpeed { axis: "m1".into(), speed: 2.0 }]);
    }

    #[test]
    fn goals_that_cannot_run_are_rejected_saying_why_and_move_nothing() {
        let states = joints();
        let mut server = FollowJointTrajectory::new();
        let reject = |server: &mut FollowJointTrajectory, request: SendGoalRequest| {
            server.send_goal(&request, &states, at(0)).unwrap_err()
        };
        assert_eq!(
            reject(&mut server, goal(&["wrist"], &[(1000, &[0.0])])),
            GoalRejection::UnknownJoint("wrist".into())
        );
        assert_eq!(
            reject(&mut server, goal(&["lift", "lift"], &[(1000, &[0.0, 0.0])])),
            GoalRejection::DuplicateJoint("lift".into())
        );
        assert_eq!(reject(&mut server, goal(&["lift"], &[])), GoalRejection::NoPoints);
        assert_eq!(
            reject(&mut server, goal(&["lift", "turn"], &[(1000, &[0.0])])),
            GoalRejection::Positions { point: 0, expected: 2, got: 1 }
        );
        assert_eq!(
            reject(&mut server, goal(&["lift"], &[(1000, &[f64::NAN])])),
            GoalRejection::NotFinite { point: 0, joint: "lift".into() }
        );
        // 1e308 rad is a number, but no number of degrees (the turn has no soft limits).
        assert_eq!(
            reject(&mut server, goal(&["turn"], &[(1000, &[1e308])])),
            GoalRejection::NotFinite { point: 0, joint: "turn".into() }
        );
        assert_eq!(
            reject(&mut server, goal(&["lift"], &[(2000, &[0.0]), (1000, &[0.001])])),
            GoalRejection::TimeBackwards { point: 1 }
        );
        assert_eq!(
            reject(&mut server, goal(&["lift"], &[(1000, &[0.010]), (2000, &[0.060])])),
            GoalRejection::BeyondLimits { point: 1, joint: "lift".into(), target: 60.0, low: -50.0, high: 50.0 }
        );
        let mut unknown = JointStates::new(
            vec![Joint::new("lift", "m1", "mm", None).unwrap()],
            Duration::from_secs(1),
            Duration::ZERO,
        );
        unknown.update("m1", Field::RBV, 0.0, T0);
        assert_eq!(
            server.send_goal(&goal(&["lift"], &[(1000, &[0.0])]), &unknown, at(0)),
            Err(GoalRejection::NotReady("lift".into()))
        );
        assert_eq!(server.poll_status(), None, "no goal known");
        assert_eq!(server.poll(&states, at(0)), []);
        assert_eq!(reject(&mut server, goal(&[], &[(1000, &[])])), GoalRejection::NoJoints);
        let mut speeds = goal(&["lift", "turn"], &[(1000, &[0.0, 0.0])]);
        speeds.goal.trajectory.points[0].velocities = vec![0.1];
        assert_eq!(
            reject(&mut server, speeds),
            GoalRejection::Derivatives { point: 0, what: "velocities", expected: 2, got: 1 }
        );
        // Stamped to start 5 s ago, its last point 2 s in: over (a second later, it runs).
        let mut stale = goal(&["lift"], &[(2000, &[0.001])]);
        stale.goal.trajectory.header.stamp = stamp(at(0));
        assert_eq!(server.send_goal(&stale, &states, at(5000)), Err(GoalRejection::EndsInThePast));
        // Stamped in simulated time (seconds since the simulation began): another clock, it starts now.
        let mut simulated = goal(&["turn"], &[(2000, &[0.0])]);
        simulated.goal_id = [7; 16];
        simulated.goal.trajectory.header.stamp = Time { sec: 120, nanosec: 0 };
        let mut fresh = FollowJointTrajectory::new();
        assert_eq!(fresh.send_goal(&simulated, &states, at(5000)), Ok(vec![]));
        // No soft limits on turn: any angle goes. A goal that cannot run, sent while it runs,
        // is rejected and the running one goes on.
        server.send_goal(&goal(&["turn"], &[(1000, &[100.0])]), &states, at(0)).unwrap();
        let _ = server.poll(&states, at(0));
        let mut beyond = goal(&["lift"], &[(1000, &[0.060])]);
        beyond.goal_id = [8; 16];
        assert!(matches!(reject(&mut server, beyond), GoalRejection::BeyondLimits { .. }));
        assert!(server.executing() && server.poll_status().unwrap().status_list[0].status == status::EXECUTING);
        // Once a goal ended, another with its id is refused (its result would be the old one's).
        let mut ended = FollowJointTrajectory::new();
        ended.send_goal(&goal(&["turn"], &[(1000, &[0.0])]), &states, at(0)).unwrap();
        let _ = ended.poll(&states, at(1000));
        assert!(!ended.executing(), "a goal to where the joint is ends at its time");
        assert_eq!(reject(&mut ended, goal(&["turn"], &[(1000, &[1.0])])), GoalRejection::KnownId);
    }

    #[test]
    fn a_cancel_stops_the_moving_joints_and_ends_the_goal_once_they_stopped() {
        let states = joints();
        let mut server = FollowJointTrajectory::new();
        server
            .send_goal(&goal(&["lift", "turn"], &[(2000, &[0.010, 1.0]), (4000, &[0.0, 0.0])]), &states, at(0))
            .unwrap();
        let _ = server.poll_status();
        assert_eq!(moves(&server.poll(&states, at(0))).len(), 2);
        let unknown = CancelGoalRequest { goal_info: GoalInfo { goal_id: [9; 16], stamp: Time::default() } };
        assert_eq!(server.cancel(&unknown).0.return_code, cancel_code::UNKNOWN_GOAL_ID);
        let (answer, commands) = server.cancel(&CancelGoalRequest::default());
        assert_eq!((answer.return_code, answer.goals_canceling.len()), (cancel_code::NONE, 1));
        assert_eq!(commands, [JointCommand::Stop { axis: "m1".into() }, JointCommand::Stop { axis: "m2".into() }]);
        assert_eq!(server.poll_status().unwrap().status_list[0].status, status::CANCELING);
        assert_eq!(server.move_ended("m1", MoveEnd::Failed("stopped".into())), [], "already ending");
        assert_eq!(server.poll(&states, at(3000)), [], "m2 not yet stopped; no second stretch");
        assert_eq!(server.result(&[1; 16]), None);
        assert_eq!(server.move_ended("m2", MoveEnd::Reached), []);
        let end = server.poll(&states, at(3000));
        assert_eq!(end.len(), 2, "both speeds restored: {end:?}");
        assert_eq!(server.result(&[1; 16]).unwrap().status, status::CANCELED);
        let again =
            server.cancel(&CancelGoalRequest { goal_info: GoalInfo { goal_id: [1; 16], stamp: Time::default() } });
        assert_eq!(again.0.return_code, cancel_code::GOAL_TERMINATED);
    }

    #[test]
    fn a_joint_that_fails_aborts_the_goal_stopping_the_others() {
        let mut states = joints();
        let mut server = FollowJointTrajectory::new();
        server.send_goal(&goal(&["lift", "turn"], &[(1000, &[0.010, 1.0])]), &states, at(0)).unwrap();
        let _ = server.poll(&states, at(0));
        assert_eq!(
            server.move_ended("m1", MoveEnd::Failed("not referenced".into())),
            [JointCommand::Stop { axis: "m2".into() }]
        );
        assert_eq!(server.move_ended("m2", MoveEnd::Reached), []);
        let _ = server.poll(&states, at(500));
        let result = server.result(&[1; 16]).unwrap();
        assert_eq!((result.status, result.result.error_code), (status::ABORTED, error_code::PATH_TOLERANCE_VIOLATED));
        assert!(result.result.error_string.contains("m1") && result.result.error_string.contains("not referenced"));

        // A goal tolerance the joint missed.
        let mut request = goal(&["lift"], &[(1000, &[0.010])]);
        request.goal_id = [2; 16];
        request.goal.goal_tolerance =
            vec![JointTolerance { name: "lift".into(), position: 0.0001, ..JointTolerance::default() }];
        server.send_goal(&request, &states, at(1000)).unwrap();
        let _ = server.poll(&states, at(1000));
        let _ = server.move_ended("m1", MoveEnd::Reached);
        states.update("m1", Field::RBV, 9.8, at(2000));
        let _ = server.poll(&states, at(2000));
        let result = server.result(&[2; 16]).unwrap();
        assert_eq!((result.status, result.result.error_code), (status::ABORTED, error_code::GOAL_TOLERANCE_VIOLATED));
    }

    #[test]
    fn a_goal_stamped_in_the_past_joins_its_trajectory_where_it_is_now() {
        let states = joints();
        let mut server = FollowJointTrajectory::new();
        // Stamped 1.5 s ago: the point at 1 s is past; 20 mm is due in 0.5 s, 15 mm in 1.5 s.
        let mut request = goal(&["lift"], &[(1000, &[0.010]), (2000, &[0.020]), (3000, &[0.015])]);
        request.goal.trajectory.header.stamp = stamp(at(0));
        server.send_goal(&request, &states, at(1500)).unwrap();
        let first = server.poll(&states, at(1500));
        assert_eq!(moves(&first), [("m1", 20.0, Some(40.0))], "from where it stands, in the 0.5 s left");
        let _ = server.move_ended("m1", MoveEnd::Reached);
        assert_eq!(server.poll(&states, at(1999)), []);
        assert_eq!(moves(&server.poll(&states, at(2000))), [("m1", 15.0, Some(5.0))], "the next, at its time");
    }

    #[test]
    fn a_goal_stamped_in_the_future_waits_for_its_time_and_a_point_at_the_current_position_moves_nothing() {
        let states = joints();
        let mut server = FollowJointTrajectory::new();
        let mut request = goal(&["lift"], &[(0, &[0.0]), (1000, &[0.002])]);
        request.goal.trajectory.header.stamp = stamp(at(500));
        server.send_goal(&request, &states, at(0)).unwrap();
        assert_eq!(server.poll(&states, at(100)), []);
        assert_eq!(server.poll_timeout(), Some(at(500)));
        assert_eq!(moves(&server.poll(&states, at(500))), [("m1", 2.0, Some(2.0))]);
        assert_eq!(server.result(&[3; 16]).unwrap().status, status::UNKNOWN, "an unknown goal answers at once");
    }

    /// `points` waypoints of `names`, one every `step` ms, each joint's positions from `way`.
    fn waypoints(names: &[&str], points: u64, step: u64, way: impl Fn(u64) -> Vec<f64>) -> SendGoalRequest {
        let positions: Vec<(u64, Vec<f64>)> = (1..=points).map(|i| (i * step, way(i))).collect();
        let borrowed: Vec<(u64, &[f64])> = positions.iter().map(|(t, p)| (*t, p.as_slice())).collect();
        goal(names, &borrowed)
    }

    #[test]
    fn close_waypoints_on_one_line_are_one_move_a_joint_and_the_path_turns_where_the_plan_does() {
        let mut states = joints();
        let mut server = FollowJointTrajectory::new();
        // 40 waypoints 0.1 s apart: lift out to 10 mm in 2 s and back in 2 s while turn goes
        // on to 90°: two straight lines in joint space, a corner at 2 s. The motor record stops
        // at the end of each move: one a line, not one a point, and the corner kept.
        let quarter = std::f64::consts::FRAC_PI_2;
        let request = waypoints(&["lift", "turn"], 40, 100, |i| {
            let lift = if i <= 20 { 0.0005 * i as f64 } else { 0.0005 * (40 - i) as f64 };
            vec![lift, quarter * i as f64 / 40.0]
        });
        server.send_goal(&request, &states, at(0)).unwrap();
        let first = server.poll(&states, at(0));
        assert_eq!(moves(&first), [("m1", 10.0, Some(5.0)), ("m2", 45.0, Some(22.5))]);
        let feedback = server.feedback(&states, at(1050)).expect("feedback");
        let desired = &feedback.feedback.desired.positions;
        assert!((desired[0] - 0.00525).abs() < 1e-12, "between its points at 1.0 and 1.1 s: {desired:?}");
        assert!((desired[1] - quarter * 10.5 / 40.0).abs() < 1e-12, "{desired:?}");
        assert_eq!(server.poll_timeout(), None, "both moving: their ends come as events");
        assert_eq!(server.move_ended("m1", MoveEnd::Reached), []);
        assert_eq!(server.poll(&states, at(2050)), [], "the turn has not ended its move");
        assert_eq!(server.move_ended("m2", MoveEnd::Reached), []);
        // Late by 0.1 s, the second line starts at once; the plan's clock runs on.
        assert_eq!(moves(&server.poll(&states, at(2100))), [("m1", 0.0, Some(5.0)), ("m2", 90.0, Some(22.5))]);
        let desired = server.feedback(&states, at(2100)).unwrap().feedback.desired.positions;
        assert!((desired[0] - 0.0095).abs() < 1e-12, "the plan at 2.1 s, not the move's start: {desired:?}");
        assert_eq!(server.move_ended("m2", MoveEnd::Reached), []);
        assert_eq!(server.poll(&states, at(4000)), [], "the lift still moving");
        assert_eq!(server.move_ended("m1", MoveEnd::Reached), []);
        states.update("m2", Field::RBV, 90.0, at(4100));
        let end = server.poll(&states, at(4100));
        assert_eq!(end.len(), 2, "the goal ends, both speeds restored: {end:?}");
        assert_eq!(server.result(&[1; 16]).unwrap().status, status::SUCCEEDED);
        let desired = server.feedback(&states, at(4100));
        assert_eq!(desired, None, "no feedback once ended");
    }

    #[test]
    fn a_stretch_ends_where_the_path_turns_rests_or_stays_and_a_point_due_at_once_goes_at_the_speed_before() {
        let states = joints();
        let mut server = FollowJointTrajectory::new();
        let degrees = |rad: f64| rad.to_degrees();
        // Both joints go one way throughout, but the path turns at 1 s and 2 s; the line after
        // it is broken at 3 s by a rest (velocities of 0); it stays put from 4 to 5 s; then the
        // lift is sent on at once.
        let mut request = goal(
            &["lift", "turn"],
            &[
                (1000, &[0.010, 0.001]),
                (2000, &[0.011, 0.5]),
                (3000, &[0.012, 0.6]),
                (4000, &[0.013, 0.7]),
                (5000, &[0.013, 0.7]),
                (5000, &[0.020, 0.7]),
            ],
        );
        request.goal.trajectory.points[2].velocities = vec![0.0, 0.0];
        server.send_goal(&request, &states, at(0)).unwrap();
        let expect = |commands: Vec<JointCommand>, lift: (f64, f64), turn: (f64, f64)| {
            let got = moves(&commands);
            assert_eq!(got.len(), 2, "{got:?}");
            assert_eq!((got[0].0, got[1].0), ("m1", "m2"));
            let close = |a: f64, b: f64| (a - b).abs() < 1e-6;
            assert!(close(got[0].1, lift.0) && close(got[0].2.unwrap(), lift.1), "{got:?}");
            assert!(close(got[1].1, degrees(turn.0)) && close(got[1].2.unwrap(), degrees(turn.1)), "{got:?}");
        };
        let both_end = |server: &mut FollowJointTrajectory| {
            assert_eq!(server.move_ended("m1", MoveEnd::Reached), []);
            assert_eq!(server.move_ended("m2", MoveEnd::Reached), []);
        };
        expect(server.poll(&states, at(0)), (10.0, 10.0), (0.001, 0.001));
        both_end(&mut server);
        expect(server.poll(&states, at(1000)), (11.0, 1.0), (0.5, 0.499));
        both_end(&mut server);
        expect(server.poll(&states, at(2000)), (12.0, 1.0), (0.6, 0.1));
        both_end(&mut server);
        assert_eq!(server.poll(&states, at(2900)), [], "at rest until 3 s");
        expect(server.poll(&states, at(3000)), (13.0, 1.0), (0.7, 0.1));
        both_end(&mut server);
        assert_eq!(server.poll(&states, at(4000)), [], "staying put moves nothing");
        assert_eq!(server.poll_timeout(), Some(at(5000)));
        let last = server.poll(&states, at(5000));
        assert_eq!(moves(&last), [("m1", 20.0, Some(1.0))], "VELO from before the goal, not the last move's");
    }

    #[test]
    fn a_path_tolerance_lets_a_bend_be_one_move_and_a_start_point_at_the_readback_moves_nothing() {
        let mut states = joints();
        let start_deg = 51.566;
        states.update("m2", Field::RBV, start_deg, T0);
        let mut server = FollowJointTrajectory::new();
        // MoveIt's start point (the joint states it read, in SI), then ten points of a line bent
        // by up to 5 mrad on the turn.
        let start = start_deg.to_radians();
        let bent = |i: u64| {
            let share = i as f64 / 10.0;
            vec![0.010 * share, start + 0.5 * share + 0.005 * (std::f64::consts::PI * share).sin()]
        };
        let mut request = waypoints(&["lift", "turn"], 10, 100, bent);
        let first_point = JointTrajectoryPoint { positions: vec![0.0, start], ..JointTrajectoryPoint::default() };
        request.goal.trajectory.points.insert(0, first_point);
        let mut tolerant = request.clone();
        // Tolerances wider than the points' spacing (5 mm against 1 mm, 0.2 rad against 0.05).
        tolerant.goal.path_tolerance = vec![
            JointTolerance { name: "lift".into(), position: 0.005, ..JointTolerance::default() },
            JointTolerance { name: "turn".into(), position: 0.2, ..JointTolerance::default() },
        ];
        server.send_goal(&tolerant, &states, at(0)).unwrap();
        let commands = server.poll(&states, at(0));
        let first = moves(&commands);
        assert_eq!(first.len(), 2, "within its tolerance the bend is one line, to the last point: {first:?}");
        assert_eq!((first[0].0, first[0].1, first[0].2), ("m1", 10.0, Some(10.0)));
        assert!((first[1].1 - (start + 0.5).to_degrees()).abs() < 1e-9, "{first:?}");

        // Without it, the bend is followed point by point.
        let mut strict = FollowJointTrajectory::new();
        strict.send_goal(&request, &states, at(0)).unwrap();
        let commands = strict.poll(&states, at(0));
        let first = moves(&commands);
        assert_eq!(first.len(), 2, "{first:?}");
        assert_eq!((first[0].0, first[0].1, first[0].2), ("m1", 1.0, Some(10.0)), "to the first point, not the start");
    }

    #[test]
    fn a_way_shorter_than_the_retry_deadband_is_still_sent_and_a_long_line_stops_every_500_points() {
        let mut states = joints();
        states.update("m1", Field::RDBD, 0.002, T0);
        let mut server = FollowJointTrajectory::new();
        // 1.5 µm, less than RDBD: the record moves it (RDBD only bounds its retries).
        let mut request = goal(&["lift"], &[(1000, &[0.0000015])]);
        request.goal.goal_tolerance =
            vec![JointTolerance { name: "lift".into(), position: 1e-6, ..JointTolerance::default() }];
        server.send_goal(&request, &states, at(0)).unwrap();
        assert_eq!(moves(&server.poll(&states, at(0))), [("m1", 0.0015, Some(0.0015))]);
        assert_eq!(server.move_ended("m1", MoveEnd::Reached), []);
        states.update("m1", Field::RBV, 0.0015, at(1000));
        let _ = server.poll(&states, at(1000));
        assert_eq!(server.result(&[1; 16]).unwrap().status, status::SUCCEEDED);

        // 1,200 points on one line, 10 ms apart: a stop every 500 (the planning's bound).
        let mut line = waypoints(&["lift"], 1200, 10, |i| vec![0.00001 * i as f64]);
        line.goal_id = [2; 16];
        states.update("m1", Field::RBV, 0.0, at(2000));
        server.send_goal(&line, &states, at(2000)).unwrap();
        let mut targets = Vec::new();
        let mut now = at(2000);
        for _ in 0..10 {
            for (axis, target, speed) in moves(&server.poll(&states, now)) {
                targets.push((target * 1e9).round() / 1e9);
                assert_eq!((axis, speed), ("m1", Some(1.0)));
                assert_eq!(server.move_ended(axis, MoveEnd::Reached), []);
            }
            now = server.poll_timeout().unwrap_or(now);
        }
        assert!(!server.executing());
        assert_eq!(targets, [5.0, 10.0, 12.0]);
    }

    #[test]
    fn a_goal_sent_while_another_runs_replaces_it_once_its_joints_have_stopped() {
        let mut states = joints();
        let mut server = FollowJointTrajectory::new();
        server.send_goal(&goal(&["lift", "turn"], &[(2000, &[0.010, 1.0])]), &states, at(0)).unwrap();
        assert_eq!(moves(&server.poll(&states, at(0))).len(), 2);
        // The first goal's speeds, posted: the goals after it restore those from before it.
        states.update("m1", Field::VELO, 5.0, at(100));
        states.update("m2", Field::VELO, 28.6, at(100));
        // 0.5 s in, a new goal for the lift: the running goal's joints stop (both: it ends).
        let mut second = goal(&["lift"], &[(1000, &[-0.005])]);
        second.goal_id = [2; 16];
        let stops = server.send_goal(&second, &states, at(500)).unwrap();
        assert_eq!(stops, [JointCommand::Stop { axis: "m1".into() }, JointCommand::Stop { axis: "m2".into() }]);
        assert!(server.feedback(&states, at(500)).is_none(), "no feedback for a goal replaced");
        // And another before they stopped: the second never runs.
        let mut third = goal(&["lift"], &[(1000, &[-0.010])]);
        third.goal_id = [3; 16];
        assert_eq!(server.send_goal(&third, &states, at(600)).unwrap(), [], "already stopping");
        assert_eq!(server.result(&[2; 16]).map(|r| (r.status, r.result.error_code)), Some((status::ABORTED, -1)));
        assert_eq!(server.poll(&states, at(700)), [], "the first goal's joints are still stopping");
        assert_eq!(server.result(&[1; 16]), None);
        assert_eq!(server.move_ended("m1", MoveEnd::Failed("stopped".into())), []);
        assert_eq!(server.move_ended("m2", MoveEnd::Failed("stopped".into())), []);
        // Stopped at 2.5 mm: the first goal ends ABORTED as joint_trajectory_controller ends a
        // goal replaced, its speeds are restored, and the third starts from where the lift is.
        states.update("m1", Field::RBV, 2.5, at(800));
        let commands = server.poll(&states, at(800));
        let first = server.result(&[1; 16]).expect("ended");
        assert_eq!((first.status, first.result.error_code), (status::ABORTED, -1));
        assert_eq!(first.result.error_string, "Current goal preempted by new incoming action.");
        assert_eq!(
            commands[..2],
            [
                JointCommand::RestoreSpeed { axis: "m1".into(), speed: 1.0 },
                JointCommand::RestoreSpeed { axis: "m2".into(), speed: 1.0 }
            ]
        );
        assert_eq!(moves(&commands[2..]), [("m1", -10.0, Some(12.5))], "12.5 mm in its 1 s, late");
        assert!(server.executing());
        assert!(server.feedback(&states, at(900)).is_some());
        let _ = server.move_ended("m1", MoveEnd::Reached);
        states.update("m1", Field::RBV, -10.0, at(1900));
        let end = server.poll(&states, at(1900));
        assert_eq!(end, [JointCommand::RestoreSpeed { axis: "m1".into(), speed: 1.0 }], "the speed from before");
        assert_eq!(server.result(&[3; 16]).unwrap().status, status::SUCCEEDED);

        // A goal waiting for the one it replaced to stop is cancelled at once.
        let mut fourth = goal(&["lift"], &[(1000, &[0.0])]);
        fourth.goal_id = [4; 16];
        server.send_goal(&fourth, &states, at(2000)).unwrap();
        let _ = server.poll(&states, at(2000));
        let mut fifth = goal(&["lift"], &[(1000, &[0.005])]);
        fifth.goal_id = [5; 16];
        assert_eq!(server.send_goal(&fifth, &states, at(2100)).unwrap(), [JointCommand::Stop { axis: "m1".into() }]);
        let info = GoalInfo { goal_id: [5; 16], stamp: Time::default() };
        let (answer, commands) = server.cancel(&CancelGoalRequest { goal_info: info });
        assert_eq!((answer.goals_canceling.len(), commands), (1, vec![]));
        assert_eq!(server.result(&[5; 16]).unwrap().status, status::CANCELED);
        let _ = server.move_ended("m1", MoveEnd::Failed("stopped".into()));
        let _ = server.poll(&states, at(2200));
        assert!(!server.executing(), "nothing waits");
    }

    #[test]
    fn a_stream_of_goals_while_one_stops_keeps_the_stopping_one_and_a_cancel_of_all_ends_both() {
        let states = joints();
        let mut server = FollowJointTrajectory::new();
        server.send_goal(&goal(&["lift"], &[(2000, &[0.010])]), &states, at(0)).unwrap();
        let _ = server.poll(&states, at(0));
        // Twenty goals while its joint stops (more than the ended goals kept): each replaces the
        // one waiting.
        for i in 2..=21u8 {
            let mut next = goal(&["lift"], &[(1000, &[0.001 * f64::from(i)])]);
            next.goal_id = [i; 16];
            let stops = server.send_goal(&next, &states, at(500 + u64::from(i))).unwrap();
            assert_eq!(stops.len(), usize::from(i == 2), "one stop, for the running goal");
        }
        assert_eq!(server.result(&[20; 16]).map(|r| r.status), Some(status::ABORTED));
        assert_eq!(server.result(&[1; 16]), None, "the stopping goal is kept, not forgotten");
        let (answer, commands) = server.cancel(&CancelGoalRequest::default());
        let canceling: Vec<u8> = answer.goals_canceling.iter().map(|g| g.goal_id[0]).collect();
        assert_eq!((canceling, commands), (vec![21, 1], vec![]), "the waiting goal and the stopping one");
        assert_eq!(server.result(&[21; 16]).unwrap().status, status::CANCELED);
        assert_eq!(server.move_ended("m1", MoveEnd::Failed("stopped".into())), []);
        let _ = server.poll(&states, at(700));
        let first = server.result(&[1; 16]).expect("ended");
        assert_eq!(first.status, status::CANCELED, "nothing replaced it: cancelled, not preempted");
        assert!(!server.executing());
        // Sixteen ended goals kept at the last acceptance, beside the two still going then.
        assert_eq!(server.poll_status().unwrap().status_list.len(), KEPT_GOALS + 2);
    }

    #[test]
    fn a_trajectory_from_the_topic_runs_as_a_goal_no_one_follows_replacing_and_replaced() {
        let mut states = joints();
        let mut server = FollowJointTrajectory::new();
        let topic = |ms: u64, lift: f64| goal(&["lift"], &[(ms, &[lift])]).goal.trajectory;
        assert_eq!(server.follow_trajectory(&topic(1000, 0.010), &states, at(0)).unwrap(), []);
        assert_eq!(moves(&server.poll(&states, at(0))), [("m1", 10.0, Some(10.0))]);
        assert!(server.executing());
        assert_eq!(server.poll_status(), None, "no goal: no status");
        assert_eq!(server.feedback(&states, at(500)), None, "nor feedback");
        let (answer, commands) = server.cancel(&CancelGoalRequest::default());
        assert!(answer.goals_canceling.is_empty() && commands.is_empty(), "no cancel reaches it");
        // A goal replaces it once its joint has stopped.
        let stops = server.send_goal(&goal(&["lift"], &[(1000, &[0.0])]), &states, at(600)).unwrap();
        assert_eq!(stops, [JointCommand::Stop { axis: "m1".into() }]);
        assert_eq!(server.move_ended("m1", MoveEnd::Failed("stopped".into())), []);
        states.update("m1", Field::RBV, 6.0, at(650));
        let commands = server.poll(&states, at(700));
        assert_eq!(commands[0], JointCommand::RestoreSpeed { axis: "m1".into(), speed: 1.0 });
        assert_eq!(moves(&commands[1..]), [("m1", 0.0, Some(6.0))]);
        // One that cannot run is rejected, and the goal goes on; one that can replaces it.
        assert!(matches!(
            server.follow_trajectory(&topic(1000, 0.5), &states, at(800)),
            Err(GoalRejection::BeyondLimits { .. })
        ));
        assert!(server.feedback(&states, at(800)).is_some(), "the goal runs on");
        let stops = server.follow_trajectory(&topic(1000, 0.005), &states, at(900)).unwrap();
        assert_eq!(stops, [JointCommand::Stop { axis: "m1".into() }]);
        assert_eq!(server.move_ended("m1", MoveEnd::Failed("stopped".into())), []);
        states.update("m1", Field::RBV, 5.0, at(950));
        let _ = server.poll(&states, at(1000));
        let replaced = server.result(&[1; 16]).expect("ended");
        assert_eq!((replaced.status, replaced.result.error_code), (status::ABORTED, -1));
        assert_eq!(replaced.result.error_string, "Current goal preempted by a trajectory on joint_trajectory.");
        assert!(server.executing(), "the topic's trajectory runs (its joint already there: it ends at its time)");
        let _ = server.poll(&states, at(2000));
        assert!(!server.executing());

        // A goal waiting for the joint to stop is replaced by a trajectory at once; one from the
        // topic that cannot run once the joint has stopped (its limits changed) is said.
        let mut third = goal(&["lift"], &[(1000, &[0.020])]);
        third.goal_id = [3; 16];
        let _ = server.send_goal(&third, &states, at(3000)).unwrap();
        let _ = server.poll(&states, at(3000));
        let mut fourth = goal(&["lift"], &[(1000, &[0.0])]);
        fourth.goal_id = [4; 16];
        assert_eq!(server.send_goal(&fourth, &states, at(3100)).unwrap(), [JointCommand::Stop { axis: "m1".into() }]);
        let _ = server.follow_trajectory(&topic(1000, 0.030), &states, at(3200)).unwrap();
        assert_eq!(server.result(&[4; 16]).map(|r| r.status), Some(status::ABORTED), "replaced while waiting");
        states.update("m1", Field::HLM, 25.0, at(3300));
        assert_eq!(server.move_ended("m1", MoveEnd::Failed("stopped".into())), []);
        let _ = server.poll(&states, at(3400));
        assert!(matches!(server.poll_refusal(), Some(GoalRejection::BeyondLimits { .. })));
        assert_eq!(server.poll_refusal(), None);
        assert!(!server.executing());
    }

    #[test]
    fn a_stretch_is_sent_at_the_speed_that_ends_it_on_time_ramps_included() {
        let mut states = joints();
        // The lift's record takes 0.5 s from VBAS 0 to VELO (10 mm/s); the turn's ramps are not
        // known.
        for (field, value) in [(Field::ACCL, 0.5), (Field::VBAS, 0.0), (Field::ACCU, 0.0), (Field::VELO, 10.0)] {
            states.update("m1", field, value, T0);
        }
        let mut server = FollowJointTrajectory::new();
        server.send_goal(&goal(&["lift", "turn"], &[(2000, &[0.010, 0.1])]), &states, at(0)).unwrap();
        let commands = server.poll(&states, at(0));
        let sent = moves(&commands);
        // 10 mm in 2 s lasting 10 / VELO + 0.5 s: VELO 10 / 1.5, not 5.
        assert_eq!((sent[0].0, sent[0].2), ("m1", Some((10.0_f64 / 1.5 * 1e9).round() / 1e9)));
        assert!((sent[1].2.unwrap() - 0.1_f64.to_degrees() / 2.0).abs() < 1e-6, "the plain quotient: {sent:?}");

        // 1 mm in 0.2 s with 0.5 s ramps would need VELO 50, an acceleration of 100 mm/s² where
        // the axis's own VELO, 6, makes 12: for the ramps' sake no faster than that VELO.
        states.update("m1", Field::VELO, 6.0, at(5000));
        let mut short = goal(&["lift"], &[(200, &[0.011])]);
        short.goal_id = [2; 16];
        states.update("m1", Field::RBV, 10.0, at(5000));
        let _ = server.move_ended("m1", MoveEnd::Reached);
        let _ = server.move_ended("m2", MoveEnd::Reached);
        let _ = server.poll(&states, at(5000));
        server.restored("m1");
        server.restored("m2");
        server.send_goal(&short, &states, at(5000)).unwrap();
        assert_eq!(moves(&server.poll(&states, at(5000))), [("m1", 11.0, Some(6.0))]);
    }

    #[test]
    fn the_controller_state_holds_each_joint_at_its_target_at_rest_and_samples_the_trajectory_while_one_runs() {
        let mut states = joints();
        let mut server = FollowJointTrajectory::new();
        // At rest: lift sent to 2 mm and still at 0 (a joint command under way), turn at rest.
        states.update("m1", Field::VAL, 2.0, T0);
        states.update("m2", Field::VAL, 0.0, T0);
        let state = states.poll_publish(at(0)).expect("every joint has a readback");
        let rest = server.controller_state(&states, &state);
        assert_eq!(rest.joint_names, ["lift", "turn"]);
        assert_eq!(rest.header, state.header);
        assert_eq!(rest.feedback.positions, [0.0, 0.0]);
        assert_eq!(rest.reference.positions, [0.002, 0.0], "where each axis is sent (VAL), in SI");
        assert_eq!(rest.reference.velocities, [0.0, 0.0]);
        assert_eq!(rest.reference.accelerations, [0.0, 0.0]);
        assert_eq!(rest.error.positions, [0.002, 0.0], "reference − feedback");
        assert_eq!(rest.output.positions, [0.002, 0.0], "what the axes were sent");
        assert_eq!(rest.speed_scaling_factor, 1.0);

        // A goal for lift alone: 10 mm in 2 s; turn sent to 1° meanwhile (not by the goal). Half-way
        // in time, lift read back at 4 mm.
        server.send_goal(&goal(&["lift"], &[(2000, &[0.010])]), &states, at(0)).unwrap();
        let _ = server.poll(&states, at(0));
        states.update("m1", Field::VAL, 10.0, at(0));
        states.update("m1", Field::DMOV, 0.0, at(0));
        states.update("m2", Field::VAL, 1.0, at(0));
        states.update("m1", Field::RBV, 4.0, at(1000));
        let state = states.poll_publish(at(1000)).expect("a fresh readback");
        let running = server.controller_state(&states, &state);
        let one_degree = 1f64.to_radians();
        let near = |a: &[f64], b: &[f64]| a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12);
        assert!(
            near(&running.reference.positions, &[0.005, one_degree]),
            "the trajectory at the state's stamp: {running:?}"
        );
        assert!(near(&running.reference.velocities, &[0.005, 0.0]), "its slope, m/s: {running:?}");
        assert_eq!(running.reference.time_from_start, RosDuration { sec: 1, nanosec: 0 });
        assert!(near(&running.feedback.positions, &[0.004, 0.0]), "{running:?}");
        assert!(near(&running.error.positions, &[0.001, one_degree]), "{running:?}");
        assert!(near(&running.error.velocities, &[0.005 - state.velocity[0], 0.0]), "{running:?}");
        assert!(near(&running.output.positions, &[0.010, one_degree]), "{running:?}");

        // Cancelled: while the lift stops, it is held where it is, at rest, as the controller holds
        // a joint it stops (not on the trajectory given up, nor at the target it was sent to).
        let info = GoalInfo { goal_id: [1; 16], stamp: Time::default() };
        let (_, stops) = server.cancel(&CancelGoalRequest { goal_info: info });
        assert_eq!(stops, [JointCommand::Stop { axis: "m1".into() }]);
        states.update("m1", Field::RBV, 5.0, at(1200));
        let state = states.poll_publish(at(1200)).expect("a fresh readback");
        let stopping = server.controller_state(&states, &state);
        assert!(near(&stopping.reference.positions, &[0.005, one_degree]), "{stopping:?}");
        assert_eq!(stopping.reference.velocities, [0.0, 0.0]);
        assert_eq!(stopping.reference.time_from_start, RosDuration::default());
        assert!(near(&stopping.error.positions, &[0.0, one_degree]), "{stopping:?}");
    }

    #[test]
    fn the_controller_state_is_laid_out_as_each_distribution_declares_it() {
        use crate::messages::{decode, encode};
        use crate::names::Distribution;
        let state = ControllerState {
            joint_names: vec!["lift".into()],
            reference: JointTrajectoryPoint { positions: vec![0.5], velocities: vec![0.1], ..Default::default() },
            feedback: JointTrajectoryPoint { positions: vec![0.4], velocities: vec![0.2], ..Default::default() },
            error: JointTrajectoryPoint { positions: vec![0.1], velocities: vec![-0.1], ..Default::default() },
            speed_scaling_factor: 1.0,
            ..ControllerState::default()
        };
        let jazzy = state.encode(Distribution::Jazzy);
        assert_eq!(decode::<ControllerState>(&jazzy, "jazzy").unwrap(), state);
        assert_eq!(jazzy[jazzy.len() - 8..], 1f64.to_le_bytes(), "the speed scaling last");
        // Humble's (control_msgs 4): desired and actual after output, the multi-DOF desired and
        // actual after the multi-DOF output, no speed scaling; its controller fills desired as
        // reference and actual as feedback.
        #[derive(serde::Serialize, serde::Deserialize)]
        struct Humble {
            header: Header,
            joint_names: Vec<String>,
            reference: JointTrajectoryPoint,
            feedback: JointTrajectoryPoint,
            error: JointTrajectoryPoint,
            output: JointTrajectoryPoint,
            desired: JointTrajectoryPoint,
            actual: JointTrajectoryPoint,
            multi_dof_joint_names: Vec<String>,
            multi_dof_points: [crate::follow::MultiDofJointTrajectoryPoint; 6],
        }
        let humble = state.encode(Distribution::Humble);
        let read = decode::<Humble>(&humble, "humble").unwrap();
        assert_eq!((&read.header, &read.joint_names), (&state.header, &state.joint_names));
        assert_eq!((&read.reference, &read.feedback, &read.error), (&state.reference, &state.feedback, &state.error));
        assert_eq!((&read.desired, &read.actual, &read.output), (&state.reference, &state.feedback, &state.output));
        assert!(read.multi_dof_joint_names.is_empty() && read.multi_dof_points.iter().all(|p| p.transforms.is_empty()));
        assert_eq!(encode(&read), humble, "every byte read, none left over");
    }
}
