//! Entry points for fuzzing: every parser that a stranger (a client's payload, a controller's
//! bytes) or a file (a launch file, an EPICS database) can reach, each as a function of raw
//! bytes that must return, whatever the bytes, without panicking. `cargo-fuzz/` runs them under
//! libFuzzer (nightly); `tests/corpus.rs` replays the committed corpus and random inputs on the
//! stable toolchain, in the test suite.

use std::time::Duration;
use zmotor_bridge::Expression;
use zmotor_bridge::{INPUTS, TRANSFORM_FIELDS};
use zmotor_controllers::{ControllerConfig, ProtocolKind, ProtocolOptions};
use zmotor_core::Instant;
use zmotor_msgs::{decode_write, Attached, Field, Hold, PayloadEncoding, StateMarker, FIELDS};
use zmotor_ros2_proto::{
    decode, CancelGoalRequest, FollowJointTrajectory, GetResultRequest, GoalInfo, Joint, JointCommand, JointState,
    JointStates, JointTolerance, JointTrajectory, JointTrajectoryPoint, MoveEnd, RosDuration, SendGoalRequest, Time,
    TrajectoryGoal,
};

/// A fuzz target: takes any bytes, returns or panics.
pub type Target = fn(&[u8]);

/// The targets, by name (the corpus directories and the cargo-fuzz targets are named alike).
pub const TARGETS: &[(&str, Target)] = &[
    ("write_decoders", write_decoders),
    ("calc", calc),
    ("launch_toml", launch_toml),
    ("epics_db", epics_db),
    ("controller_replies", controller_replies),
    ("ros2_requests", ros2_requests),
];

/// A write as a client sends it: byte 0 picks the field, byte 1 the encoding, the rest is the
/// payload; the attachment decoders (state marker, hold) read the payload too.
pub fn write_decoders(data: &[u8]) {
    let [field, encoding, payload @ ..] = data else { return };
    let def = &FIELDS[usize::from(*field) % FIELDS.len()];
    let encoding = [PayloadEncoding::Cbor, PayloadEncoding::Json, PayloadEncoding::Text][usize::from(*encoding) % 3];
    if let Ok(value) = decode_write(def, payload, encoding) {
        // What was accepted is accepted again as it is: decoding settles on one value.
        assert_eq!(zmotor_msgs::validate(def, value.clone()).as_ref(), Ok(&value), "{}", def.name);
    }
    let _ = StateMarker::decode(payload);
    // Whatever the bytes, an attachment reads as one thing; a hold read is of kind "hold".
    match Attached::read(payload) {
        Attached::Hold(Ok(hold)) => assert_eq!(hold.kind, Hold::KIND),
        Attached::Hold(Err(_)) | Attached::State | Attached::Plain => {}
    }
}

/// A CALC expression as a launch file or a database gives it (a calc record's, over A–L, and a
/// transform record's, over A–P), evaluated on inputs made of the same bytes.
pub fn calc(data: &[u8]) {
    let Ok(source) = std::str::from_utf8(data) else { return };
    let mut inputs = [0.0; TRANSFORM_FIELDS];
    for (input, byte) in inputs.iter_mut().zip(data) {
        *input = f64::from(*byte) - 128.0;
    }
    if let Ok(expression) = Expression::parse(source) {
        let mut calc_inputs = [0.0; INPUTS];
        calc_inputs.copy_from_slice(&inputs[..INPUTS]);
        let _ = expression.eval(&mut calc_inputs);
    }
    if let Ok(expression) = Expression::parse_over(source, TRANSFORM_FIELDS) {
        let _ = expression.eval(&mut inputs);
    }
}

/// A launch file.
pub fn launch_toml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Ok(launch) = zmotor_deploy::Launch::parse(text) {
        let _ = launch.deployment(None);
        let _ = launch.to_toml();
    }
}

/// An EPICS database, with a macro defined.
pub fn epics_db(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let macros = zmotor_deploy::Macros::parse(&["P=fz:".to_string()]).expect("a macro definition");
    let Ok((file, _)) = zmotor_deploy::import_db_text("fuzz.db", text, &macros, zmotor_msgs::keys::DEFAULT_PREFIX)
    else {
        return;
    };
    // What it imports to is checked as a launch file is (its calc links' chained expressions
    // parsed, the wiring checked).
    if let Ok(launch) = zmotor_deploy::Launch::from_file("fuzz.db", file) {
        let _ = launch.deployment(None);
    }
}

/// Bytes from a controller: byte 0 picks the protocol, byte 1 how many bytes arrive at a time;
/// the rest arrives on the open connections, piece by piece in turn, while the controller
/// initialises and polls, 10 ms apart.
pub fn controller_replies(data: &[u8]) {
    let [kind, chunk, bytes @ ..] = data else { return };
    let kind = ProtocolKind::ALL[usize::from(*kind) % ProtocolKind::ALL.len()];
    let channels: Vec<usize> = (0..100).filter(|c| kind.check_channel(*c).is_ok()).take(2).collect();
    let config = ControllerConfig::for_channels(channels);
    let mut controller = kind.controller(&ProtocolOptions::default(), config, Instant::ZERO);
    let mut now = Instant::ZERO;
    controller.handle_timeout(now);
    controller.handle_connected(now);
    // Pieces go to each of the controller's connections in turn (an XPS has one per channel).
    let lanes = controller.lanes();
    for (index, piece) in bytes.chunks(usize::from(*chunk).max(1)).enumerate() {
        controller.handle_input(now, lanes[index % lanes.len()], piece);
        now = now + Duration::from_millis(10);
        controller.handle_timeout(now);
        while controller.poll_transmit().is_some() {}
        while controller.poll_event().is_some() {}
    }
}

/// Bytes read in turn, zeros once they run out (moves then reach their targets, uncancelled).
struct Bytes<'a>(&'a [u8]);

impl Bytes<'_> {
    fn byte(&mut self) -> u8 {
        let (first, rest) = self.0.split_first().map_or((0, &[][..]), |(b, rest)| (*b, rest));
        self.0 = rest;
        first
    }

    /// A number as a planner sends them (a byte's worth of hundredths), now and then one no
    /// planner should (NaN, infinite, huge).
    fn number(&mut self) -> f64 {
        match self.byte() {
            0xFF => [f64::NAN, f64::INFINITY, -1e300, 1e-300][usize::from(self.byte() % 4)],
            b => f64::from(b as i8) / 100.0,
        }
    }
}

/// Two joints as the action server sees them: `lift` (mm, soft limits ±1,000) and `turn` (deg,
/// none), at rest at 0, VELO 1, RDBD 0.001.
fn fuzz_joints() -> JointStates {
    let lift = Joint::new("lift", "m1", "mm", None).expect("a joint");
    let turn = Joint::new("turn", "m2", "deg", None).expect("a joint");
    let mut states = JointStates::new(vec![lift, turn], Duration::from_secs(1), Duration::ZERO);
    for (axis, limits) in [("m1", [1000.0, -1000.0, 1000.0, -1000.0]), ("m2", [0.0; 4])] {
        for (field, value) in [(Field::RBV, 0.0), (Field::DMOV, 1.0), (Field::VELO, 1.0), (Field::RDBD, 0.001)] {
            states.update(axis, field, value, Duration::ZERO);
        }
        for (field, value) in [Field::HLM, Field::LLM, Field::DHLM, Field::DLLM].into_iter().zip(limits) {
            states.update(axis, field, value, Duration::ZERO);
        }
    }
    states
}

/// A trajectory goal made of the bytes: up to three joints named from the two known and one
/// not, up to 40 points a byte's worth of milliseconds apart (0: due at once), velocities and
/// path tolerances now and then, a stamp behind or ahead.
fn fuzz_goal(bytes: &mut Bytes<'_>, now: Duration) -> SendGoalRequest {
    let names: Vec<String> = (0..1 + bytes.byte() % 3)
        .map(|_| ["lift", "turn", "wrist"][usize::from(bytes.byte() % 3)].to_string())
        .collect();
    let mut at = Duration::ZERO;
    let points = (0..bytes.byte() % 40)
        .map(|_| {
            at += Duration::from_millis(u64::from(bytes.byte()));
            let positions = names.iter().map(|_| bytes.number()).collect();
            let velocities =
                if bytes.byte().is_multiple_of(4) { names.iter().map(|_| bytes.number()).collect() } else { vec![] };
            let time_from_start =
                RosDuration { sec: i32::try_from(at.as_secs()).unwrap_or(i32::MAX), nanosec: at.subsec_nanos() };
            JointTrajectoryPoint { positions, velocities, time_from_start, ..JointTrajectoryPoint::default() }
        })
        .collect();
    let mut path_tolerance = Vec::new();
    for name in &names {
        if bytes.byte() % 2 == 1 {
            continue;
        }
        path_tolerance.push(JointTolerance {
            name: name.clone(),
            position: bytes.number(),
            ..JointTolerance::default()
        });
    }
    let mut trajectory = JointTrajectory { joint_names: names, points, ..JointTrajectory::default() };
    let shift = Duration::from_millis(u64::from(bytes.byte()) * 10);
    let stamp = match bytes.byte() % 3 {
        0 => Duration::ZERO,
        1 => now.saturating_sub(shift),
        _ => now + shift,
    };
    trajectory.header.stamp =
        Time { sec: i32::try_from(stamp.as_secs()).unwrap_or(i32::MAX), nanosec: stamp.subsec_nanos() };
    let goal = TrajectoryGoal { trajectory, path_tolerance, ..TrajectoryGoal::default() };
    SendGoalRequest { goal_id: [bytes.byte(); 16], goal }
}

/// What a ROS 2 peer sends the ROS face: byte 0 picks a joint command, a cancel, a result
/// request or a trajectory on the topic (its CDR body the rest of the bytes), or a trajectory
/// goal made of the bytes (and the axes' ramps), which runs in virtual time with its moves
/// ending as the bytes say (reached, failed, later), a cancel (of a goal sent or of all) or
/// another goal or topic trajectory replacing it when they say. Whatever comes, every move is to
/// a finite target at a finite speed, the server never asks to be woken at a time already past,
/// and a goal ends.
pub fn ros2_requests(data: &[u8]) {
    let [kind, body @ ..] = data else { return };
    let payload = [&[0, 1, 0, 0][..], body].concat();
    let mut states = fuzz_joints();
    let mut server = FollowJointTrajectory::new();
    let now = Duration::from_secs(1_700_000_000);
    match kind % 5 {
        0 => {
            if let Ok(command) = decode::<JointState>(&payload, "JointState") {
                for (axis, target) in states.command(&command).unwrap_or_default() {
                    assert!(target.is_finite(), "{axis}: {target}");
                }
            }
        }
        1 => {
            if let Ok(request) = decode::<CancelGoalRequest>(&payload, "CancelGoal") {
                let (_, commands) = server.cancel(&request);
                assert!(commands.is_empty(), "nothing to stop");
            }
        }
        2 => {
            if let Ok(request) = decode::<GetResultRequest>(&payload, "GetResult") {
                assert!(server.result(&request.goal_id).is_some(), "an unknown goal is answered at once");
            }
        }
        4 => {
            if let Ok(trajectory) = decode::<JointTrajectory>(&payload, "JointTrajectory") {
                if server.follow_trajectory(&trajectory, &states, now).is_ok() {
                    run_to_end(&mut server, &mut states, &mut Bytes(&[]), vec![], now, data.len());
                    assert!(server.poll_status().is_none(), "a trajectory from the topic is no goal: no status");
                }
            }
        }
        _ => {
            let mut bytes = Bytes(body);
            let request = fuzz_goal(&mut bytes, now);
            // The axes' ramps (ACCL, VBAS, ACCU, ACCS) as the next bytes say.
            for axis in ["m1", "m2"] {
                for field in [Field::ACCL, Field::VBAS, Field::ACCU, Field::ACCS] {
                    states.update(axis, field, bytes.number().abs() * 10.0, now);
                }
            }
            if server.send_goal(&request, &states, now).is_ok() {
                run_to_end(&mut server, &mut states, &mut bytes, vec![request.goal_id], now, data.len());
            }
        }
    }
}

/// What is executing, run to its end in virtual time: its moves ending as `bytes` say (reached,
/// failed, later), a cancel (of a goal `sent` or of all) or another goal or topic trajectory
/// replacing it when they say. Each round takes a byte at least; once they run out, moves end
/// at once and the goal in a round a stretch: it must end within `input` + 200 rounds.
fn run_to_end(
    server: &mut FollowJointTrajectory,
    states: &mut JointStates,
    bytes: &mut Bytes<'_>,
    mut sent: Vec<[u8; 16]>,
    mut now: Duration,
    input: usize,
) {
    let mut moving: Vec<(String, f64)> = Vec::new();
    for _ in 0..input + 200 {
        for command in server.poll(states, now) {
            if let JointCommand::Move { axis, target, speed, .. } = command {
                assert!(target.is_finite() && speed.is_none_or(|s| s.is_finite() && s > 0.0), "{target} {speed:?}");
                moving.push((axis, target));
            }
        }
        assert!(server.poll_timeout().is_none_or(|at| at > now), "woken in the past");
        let _ = server.feedback(states, now);
        if let Some(state) = states.poll_publish(now) {
            let controller = server.controller_state(states, &state);
            assert_eq!(controller.reference.positions.len(), state.position.len(), "a reference for every joint");
        }
        match bytes.byte() % 16 {
            // A cancel of one goal sent, or of every goal.
            15 => {
                let which = usize::from(bytes.byte());
                let goal_id = sent.get(which % (sent.len() + 1)).copied().unwrap_or_default();
                let info = GoalInfo { goal_id, stamp: Time::default() };
                let _ = server.cancel(&CancelGoalRequest { goal_info: info });
            }
            // Another goal, replacing this one (its joints' stops need no answer here: every
            // move in flight ends below, sooner or later).
            14 => {
                let next = fuzz_goal(bytes, now);
                sent.push(next.goal_id);
                let _ = server.send_goal(&next, states, now);
            }
            // A trajectory on the topic, replacing it too.
            13 => {
                let next = fuzz_goal(bytes, now);
                let _ = server.follow_trajectory(&next.goal.trajectory, states, now);
            }
            _ => {}
        }
        // Each move ends now (reached or failed) or is held for a later round.
        let mut held = Vec::new();
        for (axis, target) in std::mem::take(&mut moving) {
            let end = match bytes.byte() % 8 {
                7 => MoveEnd::Failed("fuzzed".into()),
                6 => {
                    held.push((axis, target));
                    continue;
                }
                _ => MoveEnd::Reached,
            };
            states.update(&axis, Field::RBV, target, now);
            let _ = server.move_ended(&axis, end);
        }
        moving = held;
        while server.poll_refusal().is_some() {}
        if !server.executing() {
            return;
        }
        now = server.poll_timeout().unwrap_or(now + Duration::from_millis(10));
    }
    panic!("what executed did not end in {} rounds", input + 200);
}
