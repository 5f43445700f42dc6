//! The controller layer's rules, shown on the smallest protocol (ACS MCB-4B) in virtual time:
//! one request in flight, stop before everything, fast polls after motion, completion within a
//! moving-poll period, stale polls ignored, retries, comm loss, reconnection, nothing replayed.

mod common;

use common::{bring_up, last_status, loopback, run_until_done, written_since};
use std::time::Duration;
use zmotor_controllers::{
    line_frame, CommandError, Controller, ControllerConfig, ControllerEvent, ControllerUnit, Frame, Loopback,
    ProtocolKind, Purpose, Refusal, ReplyError, ReplyEvent, Request, Scale, ScaleSource,
};
use zmotor_core::{DeviceStatus, Driver};
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const ACS: ProtocolKind = ProtocolKind::AcsMcb4b;
const MS: Duration = Duration::from_millis(1);

fn go(position: f64) -> DriverCommand {
    DriverCommand::Move {
        position,
        relative: false,
        min_velocity: 0.0,
        max_velocity: 10_000.0,
        acceleration: 100_000.0,
    }
}

/// Run a millisecond at a time until the next idle poll has been written (its reply not in yet).
fn until_idle_poll_in_flight(lb: &mut Loopback) {
    let start = lb.written().len();
    for _ in 0..2000 {
        lb.run_for(MS);
        if lb.written().len() > start {
            assert_eq!(written_since(lb, start), ["#00X\r"]);
            return;
        }
    }
    panic!("no poll within 2 s");
}

#[test]
fn a_new_connection_polls_every_channel_before_it_is_up() {
    let mut lb = loopback(ACS, &[0, 2], Faults::default());
    let events = bring_up(&mut lb);
    assert_eq!(events.first(), Some(&ControllerEvent::Connect));
    let polled: Vec<String> = written_since(&lb, 0);
    assert_eq!(polled, ["#00X\r", "#00P\r", "#00E\r", "#00W\r", "#02X\r", "#02P\r", "#02E\r", "#02W\r"]);
    for channel in [0, 2] {
        let status = last_status(&events, channel);
        assert_eq!(status.msta & (msta::DONE | msta::COMM_ERR | msta::POSITION), msta::DONE | msta::POSITION);
    }
}

#[test]
fn one_request_is_in_flight_at_a_time() {
    let mut lb = loopback(ACS, &[0], Faults { delay: Duration::from_millis(5), ..Faults::default() });
    lb.run_for(Duration::from_millis(2));
    assert_eq!(written_since(&lb, 0), ["#00X\r"], "the next request waits for the reply");
    lb.run_for(Duration::from_millis(4));
    assert_eq!(written_since(&lb, 0), ["#00X\r", "#00P\r"]);
}

#[test]
fn a_move_reports_not_done_at_once_then_done_within_one_moving_poll_of_its_end() {
    let mut lb = loopback(ACS, &[0], Faults::default());
    bring_up(&mut lb);
    let start = lb.written().len();
    lb.command(0, &go(5000.0));
    assert_eq!(written_since(&lb, start)[..3], ["#00V=12\r", "#00R=249\r", "#00G+5000\r"]);
    let now = lb.now();
    let end = {
        let axis = lb.link.emulator().axis(0).expect("channel 0");
        axis.advance(now);
        axis.next_event().expect("the stage moves")
    };
    let statuses = run_until_done(&mut lb, 0, MS, Duration::from_secs(5));
    assert!(statuses.iter().any(|s| s.msta & msta::MOVING != 0), "moving was seen: {statuses:?}");
    assert_eq!(statuses.last().map(|s| s.position), Some(5000.0));
    let late = lb.now().as_secs_f64() - end.as_secs_f64();
    assert!((0.0..=0.1 + 1e-9).contains(&late), "done {late} s after the end of motion, at most one moving poll");
}

#[test]
fn polls_follow_the_moving_period_while_moving_and_the_idle_period_at_rest() {
    let mut lb = loopback(ACS, &[0], Faults::default());
    bring_up(&mut lb);
    let polls = |lb: &Loopback, from: usize| lb.written()[from..].iter().filter(|b| b.as_slice() == b"#00X\r").count();
    let start = lb.written().len();
    lb.run_for(Duration::from_secs(3));
    assert_eq!(polls(&lb, start), 3, "idle: one poll a second");
    lb.command(0, &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: 1000.0, acceleration: 100_000.0 });
    let start = lb.written().len();
    lb.run_for(Duration::from_secs(1));
    assert!((10..=11).contains(&polls(&lb, start)), "moving: ten polls a second, {}", polls(&lb, start));
}

#[test]
fn replies_split_at_every_byte_give_the_same_statuses() {
    let run = |chunk: usize| {
        let mut lb = loopback(ACS, &[0, 1], Faults::default()).with_chunks(chunk);
        bring_up(&mut lb);
        lb.command(1, &go(-3000.0));
        lb.run_for(Duration::from_secs(2));
        let events = lb.take_events();
        (Loopback::statuses(&events, 0), Loopback::statuses(&events, 1), lb.written().to_vec())
    };
    let whole = run(usize::MAX);
    assert!(whole.1.iter().any(|s| s.position == -3000.0 && s.msta & msta::DONE != 0));
    assert_eq!(run(1), whole);
    assert_eq!(run(2), whole);
}

#[test]
fn a_stop_goes_before_queued_motion_and_drops_it() {
    let mut lb = loopback(ACS, &[0], Faults { delay: Duration::from_millis(10), ..Faults::default() });
    bring_up(&mut lb);
    until_idle_poll_in_flight(&mut lb);
    // A poll is in flight: the move queues behind it, and the stop goes before the move.
    let start = lb.written().len();
    lb.command(0, &go(5000.0));
    lb.command(0, &DriverCommand::Stop { acceleration: 100_000.0 });
    lb.run_for(Duration::from_millis(500));
    let sent = written_since(&lb, start);
    assert_eq!(sent.first().map(String::as_str), Some("#00Q\r"), "{sent:?}");
    assert!(!sent.iter().any(|s| s.starts_with("#00G")), "the move was dropped: {sent:?}");
}

#[test]
fn a_poll_issued_before_a_move_does_not_end_it() {
    let mut lb = loopback(ACS, &[0], Faults { delay: Duration::from_millis(10), ..Faults::default() });
    bring_up(&mut lb);
    until_idle_poll_in_flight(&mut lb);
    lb.command(0, &go(20_000.0));
    // The poll's replies (read before the move) arrive; their "done" must not be reported, and
    // the polls after the move report it under way.
    lb.run_for(Duration::from_millis(500));
    let statuses = Loopback::statuses(&lb.take_events(), 0);
    assert!(statuses.iter().any(|s| s.msta & msta::MOVING != 0), "{statuses:?}");
    assert!(statuses.iter().all(|s| s.msta & msta::DONE == 0), "{statuses:?}");
}

#[test]
fn a_lost_reply_to_a_query_is_asked_again_and_a_lost_reply_to_a_command_is_not() {
    let mut lb = loopback(ACS, &[0], Faults { drop_every: Some(6), ..Faults::default() });
    lb.run_for(Duration::from_secs(3));
    assert!(lb.controller.is_up());
    let sent = written_since(&lb, 0);
    // The sixth reply (to the second poll's "#00P") was lost: the query went again.
    assert_eq!(sent[4..7], ["#00X\r", "#00P\r", "#00P\r"]);
    let mut lb = loopback(ACS, &[0], Faults::default());
    bring_up(&mut lb);
    // The third reply from here, the one to "#00G", is lost.
    lb.link.set_faults(Faults { drop_every: Some(3), ..Faults::default() });
    let start = lb.written().len();
    lb.command(0, &go(5000.0));
    lb.run_for(Duration::from_secs(2));
    let sent = written_since(&lb, start);
    assert_eq!(sent.iter().filter(|s| s.starts_with("#00G")).count(), 1, "a move is never sent twice: {sent:?}");
    let events = lb.take_events();
    assert!(events.iter().any(|e| matches!(e, ControllerEvent::Failed { .. })));
    assert_ne!(Loopback::statuses(&events, 0)[0].msta & msta::PROBLEM, 0, "the failed command shows");
}

#[test]
fn garbage_is_not_taken_for_a_reply() {
    let mut lb = loopback(ACS, &[0], Faults { garble_every: Some(2), ..Faults::default() });
    lb.run_for(Duration::from_secs(3));
    let events = lb.take_events();
    let failures = events.iter().filter(|e| matches!(e, ControllerEvent::Failed { .. })).count();
    assert!(failures > 0);
    for status in Loopback::statuses(&events, 0) {
        assert_eq!(status.position, 0.0, "no garbage became a position");
    }
}

#[test]
fn a_silent_controller_is_lost_then_found_again_with_nothing_replayed() {
    let mut lb = loopback(ACS, &[0, 1], Faults::default());
    bring_up(&mut lb);
    lb.link.set_faults(Faults { drop_every: Some(1), ..Faults::default() });
    lb.run_for(Duration::from_secs(5));
    let events = lb.take_events();
    assert!(events.contains(&ControllerEvent::Disconnect), "{events:?}");
    for channel in [0, 1] {
        let status = last_status(&events, channel);
        assert_eq!(status.msta & (msta::COMM_ERR | msta::DONE | msta::MOVING), msta::COMM_ERR | msta::DONE);
    }
    // While it is lost, a move is refused and not kept.
    lb.set_reachable(false);
    lb.command(0, &go(5000.0));
    let refused = lb.take_events();
    assert!(refused.iter().any(|e| matches!(e, ControllerEvent::Refused { channel: 0, why: Refusal::NotConnected })));
    assert_ne!(last_status(&refused, 0).msta & msta::COMM_ERR, 0);
    lb.run_for(Duration::from_secs(30));
    assert!(!lb.controller.is_up());
    // Back: initialised, polled in full, no comm error; the refused move never runs.
    lb.link.set_faults(Faults::default());
    lb.set_reachable(true);
    let start = lb.written().len();
    lb.run_for(Duration::from_secs(11));
    assert!(lb.controller.is_up());
    let events = lb.take_events();
    assert_eq!(last_status(&events, 0).msta & msta::COMM_ERR, 0);
    let sent = written_since(&lb, start);
    assert!(
        sent.iter().all(|s| s.ends_with("P\r") || s.ends_with("X\r") || s.ends_with("E\r") || s.ends_with("W\r")),
        "{sent:?}"
    );
    let axis = lb.link.emulator().axis(0).expect("channel 0");
    assert!(!axis.is_moving());
    assert_eq!(axis.physical_position(), 0.0);
}

#[test]
fn reconnection_backs_off_up_to_its_longest_wait() {
    let mut lb = loopback(ACS, &[0], Faults::default());
    lb.set_reachable(false);
    lb.run_for(Duration::from_secs(60));
    let attempts = lb.take_events().iter().filter(|e| **e == ControllerEvent::Connect).count();
    // At 0, 0.5, 1.5, 3.5, 7.5, 15.5, then every 10 s: 25.5, 35.5, 45.5, 55.5.
    assert_eq!(attempts, 10);
}

#[test]
fn a_closed_connection_is_a_comm_loss_at_once() {
    let mut lb = loopback(ACS, &[0], Faults::default());
    bring_up(&mut lb);
    lb.link.set_faults(Faults { close_after: Some(1), ..Faults::default() });
    lb.run_for(Duration::from_secs(1));
    let events = lb.take_events();
    assert!(events.contains(&ControllerEvent::Disconnect));
    assert_ne!(last_status(&events, 0).msta & msta::COMM_ERR, 0);
    lb.link.set_faults(Faults::default());
    lb.run_for(Duration::from_secs(1));
    assert!(lb.controller.is_up(), "reopened after the first back-off");
}

#[test]
fn a_command_the_protocol_cannot_express_is_refused_with_a_problem_and_sends_nothing() {
    let mut lb = loopback(ACS, &[0], Faults::default());
    bring_up(&mut lb);
    let start = lb.written().len();
    lb.command(0, &go(1e12));
    let events = lb.take_events();
    assert!(events.iter().any(|e| matches!(e, ControllerEvent::Refused { why: Refusal::Command(_), .. })));
    let status = last_status(&events, 0);
    assert_eq!(status.msta & (msta::PROBLEM | msta::DONE), msta::PROBLEM | msta::DONE);
    assert!(written_since(&lb, start).is_empty());
    lb.command(7, &go(1.0));
    assert!(lb
        .take_events()
        .iter()
        .any(|e| matches!(e, ControllerEvent::Refused { why: Refusal::UnknownChannel(7), .. })));
}

#[test]
fn a_stop_is_not_held_back_by_the_retry_of_a_poll() {
    let mut lb = loopback(ACS, &[0], Faults::default());
    bring_up(&mut lb);
    // The reply to the next poll is lost; a stop comes while it is awaited.
    lb.link.set_faults(Faults { drop_every: Some(1), ..Faults::default() });
    until_idle_poll_in_flight(&mut lb);
    lb.run_for(MS);
    lb.link.set_faults(Faults::default());
    let start = lb.written().len();
    lb.command(0, &DriverCommand::Stop { acceleration: 1000.0 });
    lb.run_for(Duration::from_millis(1500));
    let sent = written_since(&lb, start);
    assert_eq!(sent.first().map(String::as_str), Some("#00Q\r"), "the stop, not the poll's retry: {sent:?}");
}

#[test]
fn a_stop_whose_reply_is_lost_is_sent_again() {
    let mut lb = loopback(ACS, &[0], Faults::default());
    bring_up(&mut lb);
    lb.command(0, &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: 1000.0, acceleration: 100_000.0 });
    lb.run_for(Duration::from_millis(50));
    // The first reply from here, the stop's, is lost.
    lb.link.set_faults(Faults { drop_every: Some(1), ..Faults::default() });
    let start = lb.written().len();
    lb.command(0, &DriverCommand::Stop { acceleration: 100_000.0 });
    lb.run_for(Duration::from_millis(1100));
    lb.link.set_faults(Faults::default());
    lb.run_for(Duration::from_secs(2));
    let stops = written_since(&lb, start).iter().filter(|w| *w == "#00Q\r").count();
    assert_eq!(stops, 2, "{:?}", written_since(&lb, start));
    assert!(!lb.link.emulator().axis(0).expect("channel 0").is_moving());
}

/// What the ACS protocol sends to read `channels` afresh (a new link's reading before it is up).
fn reads_of(channels: &[usize]) -> Vec<String> {
    channels.iter().flat_map(|c| ["X", "P", "E", "W"].map(|letter| format!("#{c:02}{letter}\r"))).collect()
}

#[test]
fn a_jog_running_when_the_link_is_lost_is_stopped_first_once_the_new_link_has_read_the_controller() {
    let mut lb = loopback(ACS, &[0, 1], Faults::default());
    bring_up(&mut lb);
    lb.command(1, &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: 1000.0, acceleration: 100_000.0 });
    lb.run_for(Duration::from_millis(300));
    lb.set_reachable(false);
    lb.run_for(Duration::from_secs(2));
    let start = lb.written().len();
    lb.set_reachable(true);
    lb.run_for(Duration::from_secs(2));
    assert!(lb.controller.is_up());
    let sent = written_since(&lb, start);
    let stopped_first = [reads_of(&[0, 1]), vec!["#01Q\r".to_string()]].concat();
    assert_eq!(sent[..stopped_first.len()], stopped_first, "the stop goes first once the link is up: {sent:?}");
    assert_eq!(sent.iter().filter(|w| w.starts_with("#00Q")).count(), 0, "only the channel that moved");
    let now = lb.now();
    let axis = lb.link.emulator().axis(1).expect("channel 1");
    zmotor_core::Driver::advance(axis, now);
    assert!(!axis.is_moving());
}

#[test]
fn late_replies_are_never_taken_for_the_next_requests() {
    // Every reply 1.1 s late, the timeout 1 s: each arrives after its request was given up.
    let mut lb = loopback(ACS, &[0], Faults { delay: Duration::from_millis(1100), ..Faults::default() });
    lb.run_for(Duration::from_secs(20));
    let events = lb.take_events();
    assert!(!lb.controller.is_up());
    assert!(Loopback::statuses(&events, 0).iter().all(|s| s.msta & msta::COMM_ERR != 0), "{events:?}");
}

#[test]
fn no_channel_leaves_its_comm_alarm_before_the_link_takes_commands() {
    // Each reply 10 ms late: channel 0 is read long before channel 2, and the link is up only
    // once both are.
    let mut lb = loopback(ACS, &[0, 2], Faults { delay: Duration::from_millis(10), ..Faults::default() });
    let mut shown = Vec::new();
    for _ in 0..2000 {
        lb.run_for(MS);
        for event in lb.take_events() {
            if let ControllerEvent::Status { channel, status, .. } = event {
                if status.msta & msta::COMM_ERR == 0 {
                    assert!(lb.controller.is_up(), "channel {channel} shown reachable while the link initialises");
                    shown.push(channel);
                }
            }
        }
        if lb.controller.is_up() {
            break;
        }
    }
    assert!(lb.controller.is_up());
    assert_eq!(shown, [0, 2], "both statuses the initialisation read, once it is over");
    lb.command(0, &go(100.0));
    let refused = lb.take_events().into_iter().any(|e| matches!(e, ControllerEvent::Refused { .. }));
    assert!(!refused, "a move once shown reachable is taken");
}

#[test]
fn a_stop_is_taken_while_the_link_initialises_and_owed_while_it_is_down() {
    let mut lb = loopback(ACS, &[0], Faults { delay: Duration::from_millis(10), ..Faults::default() });
    lb.run_for(Duration::from_millis(5));
    assert!(!lb.controller.is_up());
    let start = lb.written().len();
    lb.command(0, &DriverCommand::Stop { acceleration: 1000.0 });
    lb.run_for(Duration::from_millis(200));
    assert!(written_since(&lb, start).contains(&"#00Q\r".to_string()), "sent on the open link");
    lb.set_reachable(false);
    lb.command(0, &DriverCommand::Stop { acceleration: 1000.0 });
    let start = lb.written().len();
    lb.set_reachable(true);
    lb.run_for(Duration::from_secs(2));
    let sent = written_since(&lb, start);
    let stopped_first = [reads_of(&[0]), vec!["#00Q\r".to_string()]].concat();
    assert_eq!(sent[..stopped_first.len()], stopped_first, "the owed stop, first once the link is up: {sent:?}");
}

/// A protocol whose controller never initialises (its `ID?` answer is never right), though it
/// answers polls: the link must not come up on a controller that is not what it should be.
struct Picky;

/// Picky's requests.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PickyStep {
    Identify,
    Poll { channel: usize },
}

impl zmotor_controllers::Protocol for Picky {
    type Step = PickyStep;
    fn name(&self) -> &'static str {
        "picky"
    }
    fn purpose(step: PickyStep) -> Purpose {
        match step {
            PickyStep::Identify => Purpose::Init,
            PickyStep::Poll { channel } => Purpose::Poll { channel },
        }
    }
    fn frame(&self, buffer: &[u8]) -> Frame {
        line_frame(buffer, b"\r")
    }
    fn init(&mut self, _channels: &[usize]) -> Vec<Request<PickyStep>> {
        vec![Request::query(&b"ID?\r"[..], PickyStep::Identify)]
    }
    fn poll(&mut self, channels: &[usize]) -> Vec<Request<PickyStep>> {
        channels.iter().map(|&channel| Request::query(&b"P?\r"[..], PickyStep::Poll { channel })).collect()
    }
    fn command(&mut self, _channel: usize, _command: &DriverCommand) -> Result<Vec<Request<PickyStep>>, CommandError> {
        Ok(Vec::new())
    }
    fn scale(&self, _channel: usize) -> Scale {
        Scale { units_per_step: 1.0, unit: ControllerUnit::Steps, source: ScaleSource::ProtocolDefault }
    }
    fn reply(&mut self, request: &Request<PickyStep>, frame: &[u8]) -> Result<Vec<ReplyEvent<PickyStep>>, ReplyError> {
        match request.step {
            PickyStep::Identify => Err(ReplyError::new(request, frame, "not the controller expected")),
            PickyStep::Poll { channel } => Ok(vec![ReplyEvent::Status {
                channel,
                status: DeviceStatus { msta: msta::DONE, ..DeviceStatus::default() },
            }]),
        }
    }
}

/// Answers every line with "NO" to `ID?` and "0" to anything else.
#[derive(Default)]
struct Answering(Vec<Vec<u8>>);

impl zmotor_emulators::Emulator for Answering {
    fn name(&self) -> &'static str {
        "picky"
    }
    fn handle_input(&mut self, _now: zmotor_core::Instant, bytes: &[u8]) {
        for line in bytes.split(|b| *b == b'\r').filter(|l| !l.is_empty()) {
            self.0.push(if line == b"ID?" { b"NO\r".to_vec() } else { b"0\r".to_vec() });
        }
    }
    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        (!self.0.is_empty()).then(|| self.0.remove(0))
    }
    fn malformed(&self) -> usize {
        0
    }
    fn axis(&mut self, _channel: usize) -> Option<&mut zmotor_core::SimAxis> {
        None
    }
    fn raise_error(&mut self, _channel: usize) -> bool {
        false
    }
}

#[test]
fn a_controller_that_does_not_initialise_is_not_used() {
    let config = ControllerConfig::for_channels(vec![0]);
    let controller = Box::new(Controller::new(Picky, config, zmotor_core::Instant::ZERO));
    let mut lb = Loopback::new(controller, Box::new(Answering::default()), Faults::default());
    lb.run_for(Duration::from_secs(5));
    assert!(!lb.controller.is_up());
    let events = lb.take_events();
    assert!(events.contains(&ControllerEvent::Disconnect), "dropped and opened again: {events:?}");
    assert!(Loopback::statuses(&events, 0).iter().all(|s| s.msta & msta::COMM_ERR != 0), "{events:?}");
}

#[test]
fn every_protocol_has_its_witness_and_every_witness_a_protocol_or_a_script() {
    for kind in ProtocolKind::ALL.into_iter().filter(|k| *k != ProtocolKind::Script) {
        let model = zmotor_emulators::Model::speaking(kind.name());
        assert!(model.is_some_and(|m| m.protocol() == kind.name()), "{} has an emulator", kind.name());
    }
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    for model in zmotor_emulators::Model::ALL {
        let name = model.protocol();
        // A family a script drives: zmotor ships the script, or runs motorScriptMotor's own.
        let shipped = root.join(format!("launch/scripts/{name}.lua")).exists();
        let theirs = std::fs::read_dir(root.join("node/controllers/tests/scripts/motorScriptMotor"))
            .expect("motorScriptMotor's scripts")
            .flatten()
            .any(|f| f.file_name().to_string_lossy().to_lowercase() == format!("{name}.lua"));
        assert!(ProtocolKind::from_name(name).is_some() || shipped || theirs, "{name} has a driver or a script");
    }
}
