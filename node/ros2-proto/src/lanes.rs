//! The action server's and the joint commands' writes, ordered per axis. Each axis has a lane:
//! its writes leave in the order they are asked, one at a time (the next once the gateway has
//! handed the previous to the network), their answers awaited apart. A trajectory stretch's VAL
//! waits for its VELO to be taken; a stop drops every move of its axis not yet sent (and a VAL
//! waiting for its VELO), so no move asked before a stop goes after it; a joint command's target
//! is the newest one when its turn comes (a controller streams targets faster than an axis
//! takes them).

use crate::trajectory::{JointCommand, MoveEnd};
use std::collections::{HashMap, VecDeque};
use std::time::Duration;
use zmotor_msgs::Field;

/// How long an axis may take to answer a write that is not a move.
const PATIENCE: Duration = Duration::from_secs(5);

/// Names one write of `WriteLanes`, in the events that report on it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct WriteId(u64);

/// When a write is answered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Answered {
    /// When the axis takes it (or refuses it), within this patience.
    WhenTaken(Duration),
    /// When the motion it starts is over, within this patience.
    AtMotionEnd(Duration),
}

/// A write for the gateway to send now, as a confirmed write of `value` to the axis's field;
/// `handed_over` once it has left, then `answered`.
#[derive(Clone, Debug, PartialEq)]
pub struct LaneWrite {
    /// This write.
    pub id: WriteId,
    /// The axis.
    pub axis: String,
    /// The field written.
    pub field: Field,
    /// The value written.
    pub value: f64,
    /// When the answer comes.
    pub answered: Answered,
}

/// How the axis answered a write.
#[derive(Clone, Debug, PartialEq)]
pub enum WriteAnswer {
    /// Taken.
    Taken,
    /// Taken, and the motion it started is over: at the target or short of it.
    MotionEnded {
        /// Whether the target was reached (DMOV with no stop, no retries left short).
        reached: bool,
        /// Where the axis stopped (RBV).
        readback: f64,
    },
    /// Refused, unanswered or not sent: why.
    Failed(String),
}

/// What the lanes report to the action server (and the joints' state).
#[derive(Clone, Debug, PartialEq)]
pub enum LaneEvent {
    /// Where a trajectory move's axis stopped, as its end's answer says, before `MoveEnded`:
    /// the joints' state takes it (`JointStates::update` of RBV), so that the goal's arrival is
    /// judged on it, not on a readback posted before the end that may come later.
    Readback {
        /// The axis.
        axis: String,
        /// RBV, EGU.
        position: f64,
    },
    /// A trajectory move ended (`FollowJointTrajectory::move_ended`).
    MoveEnded {
        /// The axis.
        axis: String,
        /// How.
        end: MoveEnd,
    },
    /// The write restoring an axis's speed ended, taken or not (`FollowJointTrajectory::restored`).
    Restored {
        /// The axis.
        axis: String,
    },
    /// A write whose failure ends nothing (a stop, a joint command): for the log.
    Failed {
        /// The axis.
        axis: String,
        /// The field written.
        field: Field,
        /// Why.
        why: String,
    },
}

/// A write a lane has yet to send.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Job {
    /// A trajectory stretch: VELO, if a speed is given, taken before VAL goes.
    Move {
        target: f64,
        speed: Option<f64>,
        duration: Duration,
    },
    /// A stretch's VAL, its VELO taken.
    MoveTarget {
        target: f64,
        duration: Duration,
    },
    Stop,
    /// VELO back to its value before a goal.
    Restore {
        speed: f64,
    },
    /// VAL to the newest joint command's target (`Lane::joint_target`), if not written since.
    JointTarget,
}

impl Job {
    fn is_move(self) -> bool {
        matches!(self, Job::Move { .. } | Job::MoveTarget { .. } | Job::JointTarget)
    }
}

/// One axis's writes.
#[derive(Debug, Default)]
struct Lane {
    queue: VecDeque<Job>,
    /// A write given to the gateway and not handed over yet: the next waits for it.
    leaving: Option<WriteId>,
    /// A stretch's VELO written, its VAL waiting for the answer.
    speed_pending: Option<WriteId>,
    /// The newest joint command's target not written yet.
    joint_target: Option<f64>,
}

/// What an answered write means.
#[derive(Clone, Copy, Debug)]
enum Awaited {
    /// A stretch's VELO: its VAL goes when it is taken.
    Speed {
        speed: f64,
        target: f64,
        duration: Duration,
    },
    /// A stretch's VAL: the move's end.
    Motion {
        target: f64,
    },
    Restore,
    /// Only its failure is told.
    Logged {
        field: Field,
    },
}

/// The writes of the ROS face, ordered per axis (see the module's description). Feed it the
/// action server's commands (`command`) and joint targets (`joint_target`); send what
/// `poll_write` gives, reporting `handed_over` and `answered`; pass what `poll_event` gives to the
/// action server.
#[derive(Debug, Default)]
pub struct WriteLanes {
    lanes: HashMap<String, Lane>,
    awaited: HashMap<WriteId, (String, Awaited)>,
    writes: VecDeque<LaneWrite>,
    events: VecDeque<LaneEvent>,
    next_id: u64,
}

impl WriteLanes {
    /// No lanes yet: each is made at its axis's first write.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// A command of the action server.
    pub fn command(&mut self, command: JointCommand) {
        match command {
            JointCommand::Move { axis, target, speed, duration } => {
                self.lane(&axis).queue.push_back(Job::Move { target, speed, duration });
                self.advance(&axis);
            }
            JointCommand::Stop { axis } => self.stop(&axis),
            JointCommand::RestoreSpeed { axis, speed } => {
                self.lane(&axis).queue.push_back(Job::Restore { speed });
                self.advance(&axis);
            }
        }
    }

    /// A joint command's target for `axis`: written when its turn comes, unless a newer one
    /// comes first.
    pub fn joint_target(&mut self, axis: &str, target: f64) {
        let lane = self.lane(axis);
        if lane.joint_target.replace(target).is_none() {
            lane.queue.push_back(Job::JointTarget);
        }
        self.advance(axis);
    }

    /// Write `id` has left for the axis (or failed to, as `answered` then says): the next write
    /// of its axis may go.
    pub fn handed_over(&mut self, id: WriteId) {
        let Some(axis) = self.awaited.get(&id).map(|(axis, _)| axis.clone()) else { return };
        let lane = self.lane(&axis);
        if lane.leaving == Some(id) {
            lane.leaving = None;
            self.advance(&axis);
        }
    }

    /// Write `id`'s answer.
    pub fn answered(&mut self, id: WriteId, answer: WriteAnswer) {
        self.handed_over(id);
        let Some((axis, awaited)) = self.awaited.remove(&id) else { return };
        match (awaited, answer) {
            (Awaited::Speed { target, duration, .. }, WriteAnswer::Taken | WriteAnswer::MotionEnded { .. }) => {
                let lane = self.lane(&axis);
                lane.speed_pending = None;
                lane.queue.push_front(Job::MoveTarget { target, duration });
                self.advance(&axis);
            }
            (Awaited::Speed { speed, .. }, WriteAnswer::Failed(why)) => {
                self.lane(&axis).speed_pending = None;
                self.events.push_back(LaneEvent::MoveEnded {
                    axis: axis.clone(),
                    end: MoveEnd::Failed(format!("VELO {speed}: {why}")),
                });
                self.advance(&axis);
            }
            (Awaited::Motion { target }, answer) => {
                if let WriteAnswer::MotionEnded { readback, .. } = answer {
                    self.events.push_back(LaneEvent::Readback { axis: axis.clone(), position: readback });
                }
                let end = match answer {
                    WriteAnswer::MotionEnded { reached: true, .. } => MoveEnd::Reached,
                    WriteAnswer::MotionEnded { reached: false, readback } => {
                        MoveEnd::Failed(format!("stopped at {readback} short of {target}"))
                    }
                    WriteAnswer::Taken => {
                        MoveEnd::Failed(format!("VAL {target}: taken, but its motion's end not told"))
                    }
                    WriteAnswer::Failed(why) => MoveEnd::Failed(format!("VAL {target}: {why}")),
                };
                self.events.push_back(LaneEvent::MoveEnded { axis, end });
            }
            (Awaited::Restore, _) => self.events.push_back(LaneEvent::Restored { axis }),
            (Awaited::Logged { field }, WriteAnswer::Failed(why)) => {
                self.events.push_back(LaneEvent::Failed { axis, field, why });
            }
            (Awaited::Logged { .. }, _) => {}
        }
    }

    /// The next write to send.
    #[must_use]
    pub fn poll_write(&mut self) -> Option<LaneWrite> {
        self.writes.pop_front()
    }

    /// The next event for the action server.
    #[must_use]
    pub fn poll_event(&mut self) -> Option<LaneEvent> {
        self.events.pop_front()
    }

    fn lane(&mut self, axis: &str) -> &mut Lane {
        self.lanes.entry(axis.to_string()).or_default()
    }

    /// A stop of `axis`: its moves not sent are dropped (each ending as stopped), then STOP goes
    /// in its turn.
    fn stop(&mut self, axis: &str) {
        let lane = self.lane(axis);
        // A joint command not written yet is dropped too: one that comes after the stop is
        // written after it.
        lane.joint_target = None;
        let dropped = lane.queue.iter().filter(|job| job.is_move() && **job != Job::JointTarget).count();
        lane.queue.retain(|job| !job.is_move());
        let waiting_speed = lane.speed_pending.take();
        lane.queue.push_back(Job::Stop);
        if let Some(id) = waiting_speed {
            // Its answer, when it comes, sends nothing.
            self.awaited.insert(id, (axis.to_string(), Awaited::Logged { field: Field::VELO }));
        }
        let stopped = dropped + usize::from(waiting_speed.is_some());
        for _ in 0..stopped {
            let end = MoveEnd::Failed("stopped before it was sent".into());
            self.events.push_back(LaneEvent::MoveEnded { axis: axis.to_string(), end });
        }
        self.advance(axis);
    }

    /// Give the gateway `axis`'s next write, if its lane is free.
    fn advance(&mut self, axis: &str) {
        let lane = self.lane(axis);
        if lane.leaving.is_some() || lane.speed_pending.is_some() {
            return;
        }
        let Some(job) = lane.queue.pop_front() else { return };
        let (field, value, answered, awaited) = match job {
            Job::Move { target, speed: Some(speed), duration } => {
                (Field::VELO, speed, Answered::WhenTaken(PATIENCE), Awaited::Speed { speed, target, duration })
            }
            Job::Move { target, speed: None, duration } | Job::MoveTarget { target, duration } => {
                // The move may take several times its plan (acceleration, a slow axis) before it
                // is late.
                let patience = duration * 10 + Duration::from_secs(60);
                (Field::VAL, target, Answered::AtMotionEnd(patience), Awaited::Motion { target })
            }
            Job::Stop => (Field::STOP, 1.0, Answered::WhenTaken(PATIENCE), Awaited::Logged { field: Field::STOP }),
            Job::Restore { speed } => (Field::VELO, speed, Answered::WhenTaken(PATIENCE), Awaited::Restore),
            Job::JointTarget => match lane.joint_target.take() {
                Some(target) => {
                    (Field::VAL, target, Answered::WhenTaken(PATIENCE), Awaited::Logged { field: Field::VAL })
                }
                None => return self.advance(axis),
            },
        };
        let id = WriteId(self.next_id);
        self.next_id += 1;
        let lane = self.lane(axis);
        lane.leaving = Some(id);
        if let Awaited::Speed { .. } = awaited {
            lane.speed_pending = Some(id);
        }
        self.awaited.insert(id, (axis.to_string(), awaited));
        self.writes.push_back(LaneWrite { id, axis: axis.to_string(), field, value, answered });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stretch(axis: &str, target: f64, speed: Option<f64>) -> JointCommand {
        JointCommand::Move { axis: axis.into(), target, speed, duration: Duration::from_secs(4) }
    }

    fn stop(axis: &str) -> JointCommand {
        JointCommand::Stop { axis: axis.into() }
    }

    /// Every write given now.
    fn writes(lanes: &mut WriteLanes) -> Vec<LaneWrite> {
        std::iter::from_fn(|| lanes.poll_write()).collect()
    }

    fn events(lanes: &mut WriteLanes) -> Vec<LaneEvent> {
        std::iter::from_fn(|| lanes.poll_event()).collect()
    }

    fn shape(writes: &[LaneWrite]) -> Vec<(&str, Field, f64)> {
        writes.iter().map(|w| (w.axis.as_str(), w.field, w.value)).collect()
    }

    /// The one write given now.
    fn one(lanes: &mut WriteLanes) -> LaneWrite {
        let mut given = writes(lanes);
        assert_eq!(given.len(), 1, "one write: {given:?}");
        given.remove(0)
    }

    fn ended(axis: &str, end: MoveEnd) -> LaneEvent {
        LaneEvent::MoveEnded { axis: axis.into(), end }
    }

    fn stopped_unsent(axis: &str) -> LaneEvent {
        ended(axis, MoveEnd::Failed("stopped before it was sent".into()))
    }

    #[test]
    fn a_stretch_writes_velo_then_val_once_velo_is_taken_and_reports_the_end() {
        let mut lanes = WriteLanes::new();
        lanes.command(stretch("a", 2.0, Some(0.5)));
        let velo = one(&mut lanes);
        assert_eq!((velo.field, velo.value, velo.answered), (Field::VELO, 0.5, Answered::WhenTaken(PATIENCE)));
        lanes.handed_over(velo.id);
        assert!(writes(&mut lanes).is_empty(), "VAL waits for VELO's answer");
        lanes.answered(velo.id, WriteAnswer::Taken);
        let val = one(&mut lanes);
        let patience = Duration::from_secs(40 + 60);
        assert_eq!((val.field, val.value, val.answered), (Field::VAL, 2.0, Answered::AtMotionEnd(patience)));
        lanes.handed_over(val.id);
        assert!(events(&mut lanes).is_empty());
        lanes.answered(val.id, WriteAnswer::MotionEnded { reached: true, readback: 2.0 });
        let readback = LaneEvent::Readback { axis: "a".into(), position: 2.0 };
        assert_eq!(events(&mut lanes), [readback, ended("a", MoveEnd::Reached)]);
    }

    #[test]
    fn a_motion_ended_short_or_refused_fails_the_move() {
        let mut lanes = WriteLanes::new();
        lanes.command(stretch("a", 2.0, None));
        let val = one(&mut lanes);
        lanes.answered(val.id, WriteAnswer::MotionEnded { reached: false, readback: 1.25 });
        lanes.command(stretch("a", 3.0, None));
        let val = one(&mut lanes);
        lanes.answered(val.id, WriteAnswer::Failed("refused: HLM".into()));
        assert_eq!(
            events(&mut lanes),
            [
                LaneEvent::Readback { axis: "a".into(), position: 1.25 },
                ended("a", MoveEnd::Failed("stopped at 1.25 short of 2".into())),
                ended("a", MoveEnd::Failed("VAL 3: refused: HLM".into())),
            ]
        );
    }

    #[test]
    fn a_stop_while_velo_awaits_its_answer_goes_at_once_and_the_val_never_goes() {
        let mut lanes = WriteLanes::new();
        lanes.command(stretch("a", 2.0, Some(0.5)));
        let velo = one(&mut lanes);
        lanes.handed_over(velo.id);
        lanes.command(stop("a"));
        assert_eq!(shape(&writes(&mut lanes)), [("a", Field::STOP, 1.0)]);
        assert_eq!(events(&mut lanes), [stopped_unsent("a")]);
        lanes.answered(velo.id, WriteAnswer::Taken);
        assert!(writes(&mut lanes).is_empty(), "no VAL after the stop");
        assert!(events(&mut lanes).is_empty(), "the move ended once");
    }

    #[test]
    fn a_stop_leaves_after_the_write_before_it() {
        let mut lanes = WriteLanes::new();
        lanes.command(stretch("a", 2.0, None));
        let val = one(&mut lanes);
        lanes.command(stop("a"));
        assert!(writes(&mut lanes).is_empty(), "the VAL given is not handed over yet");
        lanes.handed_over(val.id);
        assert_eq!(shape(&writes(&mut lanes)), [("a", Field::STOP, 1.0)]);
        assert!(events(&mut lanes).is_empty(), "the VAL sent ends with its motion, stopped or not");
    }

    #[test]
    fn a_stop_drops_the_moves_queued_before_it_but_keeps_a_restore_in_its_place() {
        let mut lanes = WriteLanes::new();
        lanes.command(stretch("a", 2.0, Some(0.5)));
        let velo = one(&mut lanes);
        lanes.command(stretch("a", 3.0, Some(0.5)));
        lanes.command(JointCommand::RestoreSpeed { axis: "a".into(), speed: 1.0 });
        lanes.command(stretch("a", 4.0, None));
        lanes.command(stop("a"));
        assert_eq!(events(&mut lanes), [stopped_unsent("a"), stopped_unsent("a"), stopped_unsent("a")]);
        assert!(writes(&mut lanes).is_empty(), "VELO not handed over yet");
        lanes.handed_over(velo.id);
        let restore = one(&mut lanes);
        assert_eq!(shape(std::slice::from_ref(&restore)), [("a", Field::VELO, 1.0)]);
        lanes.handed_over(restore.id);
        assert_eq!(shape(&writes(&mut lanes)), [("a", Field::STOP, 1.0)]);
        lanes.answered(restore.id, WriteAnswer::Failed("no node serves the axis".into()));
        assert_eq!(events(&mut lanes), [LaneEvent::Restored { axis: "a".into() }], "taken or not");
    }

    #[test]
    fn a_refused_speed_fails_its_move_and_the_next_goes() {
        let mut lanes = WriteLanes::new();
        lanes.command(stretch("a", 2.0, Some(50.0)));
        lanes.command(stretch("a", 3.0, None));
        let velo = one(&mut lanes);
        lanes.answered(velo.id, WriteAnswer::Failed("refused: VMAX".into()));
        assert_eq!(events(&mut lanes), [ended("a", MoveEnd::Failed("VELO 50: refused: VMAX".into()))]);
        assert_eq!(shape(&writes(&mut lanes)), [("a", Field::VAL, 3.0)]);
    }

    #[test]
    fn joint_targets_coming_faster_than_they_leave_write_only_the_newest() {
        let mut lanes = WriteLanes::new();
        lanes.joint_target("a", 1.0);
        let first = one(&mut lanes);
        assert_eq!((first.field, first.value, first.answered), (Field::VAL, 1.0, Answered::WhenTaken(PATIENCE)));
        lanes.joint_target("a", 2.0);
        lanes.joint_target("a", 3.0);
        assert!(writes(&mut lanes).is_empty());
        lanes.handed_over(first.id);
        let newest = one(&mut lanes);
        assert_eq!(newest.value, 3.0);
        lanes.handed_over(newest.id);
        assert!(writes(&mut lanes).is_empty(), "2 is never written");
        lanes.answered(newest.id, WriteAnswer::Failed("refused: DISP".into()));
        assert_eq!(
            events(&mut lanes),
            [LaneEvent::Failed { axis: "a".into(), field: Field::VAL, why: "refused: DISP".into() }]
        );
    }

    #[test]
    fn a_stop_drops_a_joint_command_not_written_and_the_next_one_goes_after_it() {
        let mut lanes = WriteLanes::new();
        lanes.command(stretch("a", 2.0, None));
        let val = one(&mut lanes);
        lanes.joint_target("a", 7.0);
        lanes.command(stop("a"));
        lanes.joint_target("a", 8.0);
        lanes.handed_over(val.id);
        let stop = one(&mut lanes);
        assert_eq!((stop.field, stop.value), (Field::STOP, 1.0));
        lanes.handed_over(stop.id);
        assert_eq!(shape(&writes(&mut lanes)), [("a", Field::VAL, 8.0)], "7 never, 8 after the stop");
        assert!(events(&mut lanes).is_empty(), "a joint command is no trajectory move");
    }

    #[test]
    fn one_axis_waiting_holds_no_other_axis() {
        let mut lanes = WriteLanes::new();
        lanes.command(stretch("a", 2.0, Some(0.5)));
        lanes.joint_target("a", 9.0);
        lanes.command(stretch("b", 1.0, Some(0.25)));
        lanes.command(stop("c"));
        assert_eq!(
            shape(&writes(&mut lanes)),
            [("a", Field::VELO, 0.5), ("b", Field::VELO, 0.25), ("c", Field::STOP, 1.0)]
        );
    }

    #[test]
    fn a_write_not_handed_over_because_it_failed_to_leave_frees_its_lane() {
        let mut lanes = WriteLanes::new();
        lanes.command(stretch("a", 2.0, None));
        lanes.command(stop("a"));
        let val = one(&mut lanes);
        lanes.answered(val.id, WriteAnswer::Failed("not sent: session closed".into()));
        assert_eq!(shape(&writes(&mut lanes)), [("a", Field::STOP, 1.0)]);
        assert_eq!(events(&mut lanes), [ended("a", MoveEnd::Failed("VAL 2: not sent: session closed".into()))]);
    }
}
