//! What every protocol's tests share: a loopback in virtual time, and arbitrary record commands.
#![allow(dead_code)] // each test file uses its own part

pub(crate) mod golden;

use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{
    ControllerConfig, ControllerEvent, Loopback, MacroValue, ProtocolKind, ProtocolOptions, ScriptSettings,
    ScriptSource, VendorError,
};
use zmotor_core::{DeviceStatus, Instant};
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::{DriverCommand, Gain};

/// `kind` driving its emulator with `channels` (the emulator has every channel up to the
/// highest), through `faults`.
pub(crate) fn loopback(kind: ProtocolKind, channels: &[usize], faults: Faults) -> Loopback {
    let emulator = emulator(kind, channels.iter().max().map_or(1, |c| c + 1));
    let config = ControllerConfig::for_channels(channels.to_vec());
    Loopback::new(kind.controller(&ProtocolOptions::default(), config, Instant::ZERO), emulator, faults)
}

/// The script at `path` (relative to the workspace's root) and the `.lua` files beside it, for
/// the controller `driver`, with `macros`.
pub(crate) fn script_source(path: &str, driver: &str, macros: &[(&str, MacroValue)]) -> ScriptSource {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let file = root.join(path);
    let text = std::fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    let mut modules = std::collections::BTreeMap::new();
    for entry in std::fs::read_dir(file.parent().expect("a directory")).expect("readable").flatten() {
        let other = entry.path();
        if other.extension().is_some_and(|e| e == "lua") && other != file {
            let stem = other.file_stem().and_then(|s| s.to_str()).expect("a name").to_string();
            modules.insert(stem, std::fs::read_to_string(&other).expect("readable"));
        }
    }
    let macros = macros.iter().map(|(name, value)| (name.to_string(), value.clone())).collect();
    ScriptSource { path: path.into(), text, modules, driver: driver.into(), macros, ..ScriptSource::default() }
}

/// A script controller running `source` on `channels` against `model`'s emulator (every channel
/// up to the highest), polled as the script asks, through `faults`.
pub(crate) fn script_loopback(
    source: &ScriptSource,
    model: zmotor_emulators::Model,
    channels: &[usize],
    faults: Faults,
) -> Loopback {
    let settings = ScriptSettings::of(source).expect("the script loads");
    let mut config = ControllerConfig::for_channels(channels.to_vec());
    config.moving_poll = settings.moving_poll.map_or(config.moving_poll, Duration::from_secs_f64);
    config.idle_poll = settings.idle_poll.map_or(config.idle_poll, Duration::from_secs_f64);
    config.fast_polls = settings.forced_fast_polls.map_or(config.fast_polls, |n| n as u32);
    let options = ProtocolOptions { script: Some(source.clone()), ..ProtocolOptions::default() };
    let emulator = model.emulator(channels.iter().max().map_or(1, |c| c + 1));
    Loopback::new(ProtocolKind::Script.controller(&options, config, Instant::ZERO), emulator, faults)
}

/// The emulator of `kind`'s controllers, with every channel below `channels`.
pub(crate) fn emulator(kind: ProtocolKind, channels: usize) -> Box<dyn zmotor_emulators::Emulator> {
    let model = zmotor_emulators::Model::speaking(kind.name()).expect("every protocol has its emulator");
    model.emulator(channels)
}

/// Run until the controller is up and has reported every channel; the events on the way.
pub(crate) fn bring_up(lb: &mut Loopback) -> Vec<ControllerEvent> {
    lb.run_for(Duration::from_millis(100));
    assert!(lb.controller.is_up(), "the controller came up: {:?}", lb.take_events());
    lb.take_events()
}

/// The controller errors among `events`: (channel, code, meaning).
pub(crate) fn controller_errors(events: &[ControllerEvent]) -> Vec<(Option<usize>, String, String)> {
    events
        .iter()
        .filter_map(|e| match e {
            ControllerEvent::ControllerError(VendorError { channel, code, meaning }) => {
                Some((*channel, code.clone(), meaning.clone()))
            }
            _ => None,
        })
        .collect()
}

/// Bytes as text, for assertions on ASCII protocols.
pub(crate) fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// What the driver wrote from request number `from` on, as text.
pub(crate) fn written_since(lb: &Loopback, from: usize) -> Vec<String> {
    lb.written()[from..].iter().map(|b| text(b)).collect()
}

/// The last status of `channel` among `events`.
pub(crate) fn last_status(events: &[ControllerEvent], channel: usize) -> DeviceStatus {
    *Loopback::statuses(events, channel).last().unwrap_or_else(|| panic!("a status of channel {channel}: {events:?}"))
}

/// Run in steps of `step` until `channel` reports done, at most `limit`; the statuses seen.
pub(crate) fn run_until_done(lb: &mut Loopback, channel: usize, step: Duration, limit: Duration) -> Vec<DeviceStatus> {
    let end = lb.now() + limit;
    let mut seen = Vec::new();
    while lb.now() < end {
        lb.run_for(step);
        let statuses = Loopback::statuses(&lb.take_events(), channel);
        let done = statuses.last().is_some_and(|s| s.msta & msta::DONE != 0);
        seen.extend(statuses);
        if done {
            return seen;
        }
    }
    panic!("channel {channel} did not report done within {limit:?}: {seen:?}");
}

/// A motion command in the ranges a record sends (steps, steps/s, steps/s²).
pub(crate) fn motion() -> impl Strategy<Value = DriverCommand> {
    let speed = 10.0..50_000.0f64;
    let accel = 100.0..500_000.0f64;
    prop_oneof![
        (-150_000.0..150_000.0f64, any::<bool>(), speed.clone(), accel.clone()).prop_map(
            |(position, relative, max_velocity, acceleration)| DriverCommand::Move {
                position,
                relative,
                min_velocity: 0.0,
                max_velocity,
                acceleration
            }
        ),
        (speed.clone(), any::<bool>(), accel.clone()).prop_map(|(v, up, acceleration)| DriverCommand::MoveVelocity {
            min_velocity: 0.0,
            max_velocity: if up { v } else { -v },
            acceleration
        }),
        (any::<bool>(), speed, accel.clone()).prop_map(|(forward, max_velocity, acceleration)| DriverCommand::Home {
            forward,
            min_velocity: 0.0,
            max_velocity,
            acceleration
        }),
        accel.prop_map(|acceleration| DriverCommand::Stop { acceleration }),
    ]
}

/// Any command a record's device support sends, raw text excepted (it is the user's own).
pub(crate) fn command() -> impl Strategy<Value = DriverCommand> {
    prop_oneof![
        4 => motion(),
        1 => (-150_000.0..150_000.0f64).prop_map(|position| DriverCommand::SetPosition { position }),
        1 => any::<bool>().prop_map(|on| DriverCommand::Enable { on }),
        1 => (0.01..100.0f64).prop_map(|ratio| DriverCommand::SetEncoderRatio { ratio }),
        1 => (0.0..190_000.0f64).prop_map(|position| DriverCommand::SetHighLimit { position }),
        1 => (-190_000.0..0.0f64).prop_map(|position| DriverCommand::SetLowLimit { position }),
        1 => (prop_oneof![Just(Gain::Proportional), Just(Gain::Integral), Just(Gain::Derivative)], 0.0..1.0f64)
            .prop_map(|(gain, value)| DriverCommand::SetGain { gain, value }),
        1 => Just(DriverCommand::Poll),
    ]
}

/// Home `channel` forward and run until it is done and referenced (HOMED).
pub(crate) fn home_and_wait(lb: &mut Loopback, channel: usize) {
    let home =
        DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 };
    lb.command(channel, &home);
    let statuses = run_until_done(lb, channel, Duration::from_millis(50), Duration::from_secs(120));
    assert!(statuses.last().is_some_and(|s| s.msta & msta::HOMED != 0), "homed: {statuses:?}");
}

/// Whether `no_malformed_frames` homes every channel first: a controller that moves only
/// referenced axes would otherwise see none of the moves (the layer refuses them unsent).
#[derive(Clone, Copy, PartialEq)]
pub(crate) enum Start {
    AsPoweredUp,
    Homed,
}

/// Feed `commands` to `channels` in turn, a little apart, and check that every frame the driver
/// wrote was well-formed for the emulator.
pub(crate) fn no_malformed_frames(
    kind: ProtocolKind,
    channels: &[usize],
    start: Start,
    commands: &[(usize, DriverCommand, u64)],
) {
    no_malformed_frames_on(loopback(kind, channels, Faults::default()), channels, start, commands);
}

/// `no_malformed_frames` on the loopback `lb`, not brought up yet.
pub(crate) fn no_malformed_frames_on(
    mut lb: Loopback,
    channels: &[usize],
    start: Start,
    commands: &[(usize, DriverCommand, u64)],
) {
    bring_up(&mut lb);
    if start == Start::Homed {
        for &channel in channels {
            home_and_wait(&mut lb, channel);
        }
    }
    for (pick, command, gap_ms) in commands {
        lb.command(channels[pick % channels.len()], command);
        lb.run_for(Duration::from_millis(*gap_ms));
    }
    lb.run_for(Duration::from_secs(2));
    let refused: Vec<_> = lb
        .take_events()
        .into_iter()
        .filter(|e| matches!(e, ControllerEvent::Refused { .. } | ControllerEvent::Failed { .. }))
        .collect();
    assert_eq!(lb.link.malformed(), 0, "frames the controller could not take, among {:?}", lb.written());
    assert!(
        refused.iter().all(|e| matches!(e, ControllerEvent::Refused { .. })),
        "exchanges failed on a clean link: {refused:?}"
    );
    // Whatever came before, a stop of every channel ends with every channel done, within the
    // time the commands allow it (10 s more).
    for &channel in channels {
        lb.command(channel, &DriverCommand::Stop { acceleration: 200_000.0 });
    }
    let limit = slowest_stop(commands) + Duration::from_secs(10);
    for &channel in channels {
        run_until_done(&mut lb, channel, Duration::from_millis(100), limit);
    }
}

/// The longest a stop may take after `commands`: a controller whose stop decelerates at the
/// acceleration last set (the VMC's `AB` at its `ACC`) may be left at the fastest speed they
/// commanded, slowing at the lowest acceleration they set (50,000 steps/s at 100 steps/s²:
/// 500 s).
fn slowest_stop(commands: &[(usize, DriverCommand, u64)]) -> Duration {
    let (mut fastest, mut slowest_acceleration) = (0.0f64, f64::INFINITY);
    for (_, command, _) in commands {
        let (speed, acceleration) = match *command {
            DriverCommand::Move { max_velocity, acceleration, .. }
            | DriverCommand::MoveVelocity { max_velocity, acceleration, .. }
            | DriverCommand::Home { max_velocity, acceleration, .. } => (max_velocity.abs(), acceleration),
            DriverCommand::Stop { acceleration } => (0.0, acceleration),
            _ => continue,
        };
        fastest = fastest.max(speed);
        slowest_acceleration = slowest_acceleration.min(acceleration);
    }
    match fastest > 0.0 && slowest_acceleration > 0.0 {
        true => Duration::from_secs_f64(fastest / slowest_acceleration),
        false => Duration::ZERO,
    }
}

/// A move to `position` (a distance when `relative`) at 20,000 steps/s and 200,000 steps/s².
pub(crate) fn go(position: f64, relative: bool) -> DriverCommand {
    DriverCommand::Move { position, relative, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 200_000.0 }
}

/// A move of `channel` (up, switched on) by `go` (target, relative) arrives at 12,345 steps,
/// seen moving up on the way; one of −2,345 from there arrives at 10,000.
pub(crate) fn a_move_arrives_where_asked_and_a_relative_one_from_there(
    lb: &mut Loopback,
    channel: usize,
    go: impl Fn(f64, bool) -> DriverCommand,
) {
    let tick = Duration::from_millis(10);
    lb.command(channel, &go(12_345.0, false));
    let statuses = run_until_done(lb, channel, tick, Duration::from_secs(5));
    let arrived = statuses.last().expect("done");
    assert!((arrived.position - 12_345.0).abs() < 1e-6, "{arrived:?}");
    let up = msta::MOVING | msta::DIRECTION;
    assert!(statuses.iter().any(|s| s.msta & up == up), "seen moving up: {statuses:?}");
    lb.command(channel, &go(-2_345.0, true));
    let arrived = *run_until_done(lb, channel, tick, Duration::from_secs(5)).last().expect("done");
    assert!((arrived.position - 10_000.0).abs() < 1e-6, "{arrived:?}");
}

/// A jog of `channel` (up, switched on) runs until stopped and stops soon after; left running it
/// ends on the minus limit switch of the emulators' stage (-200000 steps).
pub(crate) fn a_jog_runs_until_stopped_or_the_limit_switch(lb: &mut Loopback, channel: usize) {
    let tick = Duration::from_millis(10);
    lb.command(
        channel,
        &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -5000.0, acceleration: 50_000.0 },
    );
    lb.run_for(Duration::from_secs(1));
    let status = last_status(&lb.take_events(), channel);
    assert_eq!(status.msta & (msta::DONE | msta::MOVING), msta::MOVING, "{status:?}");
    assert!(status.position < -3000.0, "{status:?}");
    lb.command(channel, &DriverCommand::Stop { acceleration: 50_000.0 });
    let stopped = *run_until_done(lb, channel, tick, Duration::from_secs(3)).last().expect("done");
    assert!(stopped.position > -7000.0, "stopped soon after the stop: {stopped:?}");
    // 40,000 steps/s: under every emulated controller's top speed (an ESP300's VU is 50,000).
    let fast = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -40_000.0, acceleration: 400_000.0 };
    lb.command(channel, &fast);
    let at_limit = *run_until_done(lb, channel, tick, Duration::from_secs(10)).last().expect("done");
    assert_ne!(at_limit.msta & msta::MINUS_LS, 0, "{at_limit:?}");
    assert!(at_limit.position <= -199_999.0, "{at_limit:?}");
}

/// Moves of `channel` (up, switched on) by `go` (target, relative), there and back, and jogs
/// stopped, each lasting a little longer than the last so that their ends fall at every moment
/// of a poll: the status that first says done has the position the motor rests at (DMOV 1 comes
/// with the final readback). On a slow line (`WithFaults::at_baud`) a poll's readings are
/// milliseconds apart, and a motion may end between two of them.
pub(crate) fn done_comes_with_the_final_position(
    lb: &mut Loopback,
    channel: usize,
    go: impl Fn(f64, bool) -> DriverCommand,
) {
    let tick = Duration::from_millis(5);
    lb.take_events();
    let came_to_rest = |lb: &mut Loopback, what: &str| {
        let done = *run_until_done(lb, channel, tick, Duration::from_secs(10)).last().expect("done");
        lb.run_for(Duration::from_secs(1));
        let at_rest = last_status(&lb.take_events(), channel);
        assert_eq!(done.position, at_rest.position, "{what}: done at {done:?}, then at rest at {at_rest:?}");
    };
    for k in 0..40_u32 {
        // 97 steps more each time: 4.85 ms longer at 20,000 steps/s.
        let distance = 2000.0 + 97.0 * f64::from(k);
        lb.command(channel, &go(distance, true));
        came_to_rest(lb, &format!("a move of {distance} steps"));
        lb.command(channel, &go(-distance, true));
        came_to_rest(lb, &format!("a move of {distance} steps back"));
        let jog = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: 5000.0, acceleration: 50_000.0 };
        lb.command(channel, &jog);
        lb.run_for(Duration::from_millis(300 + 3 * u64::from(k)));
        lb.command(channel, &DriverCommand::Stop { acceleration: 50_000.0 });
        came_to_rest(lb, "a jog stopped");
    }
}

/// Every kind of record command on the first two of `channels` (switched on first), replies
/// delivered whole or in pieces of `chunk` bytes: the statuses each of the two reported.
pub(crate) fn statuses_of_a_script(kind: ProtocolKind, channels: &[usize], chunk: usize) -> [Vec<DeviceStatus>; 2] {
    statuses_of_a_script_on(loopback(kind, channels, Faults::default()).with_chunks(chunk), channels)
}

/// `statuses_of_a_script` on the loopback `lb`, not brought up yet.
pub(crate) fn statuses_of_a_script_on(mut lb: Loopback, channels: &[usize]) -> [Vec<DeviceStatus>; 2] {
    bring_up(&mut lb);
    let [first, second] = [channels[0], channels[1]];
    for channel in [first, second] {
        lb.command(channel, &DriverCommand::Enable { on: true });
    }
    let go = DriverCommand::Move {
        position: 3000.0,
        relative: false,
        min_velocity: 0.0,
        max_velocity: 20_000.0,
        acceleration: 200_000.0,
    };
    lb.command(first, &go);
    lb.command(
        second,
        &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: 8000.0, acceleration: 80_000.0 },
    );
    lb.run_for(Duration::from_millis(400));
    lb.command(second, &DriverCommand::Stop { acceleration: 80_000.0 });
    lb.command(first, &DriverCommand::SetPosition { position: -77.0 });
    lb.run_for(Duration::from_secs(2));
    let events = lb.take_events();
    [Loopback::statuses(&events, first), Loopback::statuses(&events, second)]
}

/// Replies split at every byte give the statuses whole replies give: the script's first
/// channel ends at -77 (set), the second stopped beyond 0.
pub(crate) fn replies_in_pieces_give_the_same_statuses(kind: ProtocolKind, channels: &[usize]) {
    replies_in_pieces_give_the_same_statuses_on(
        |chunk| loopback(kind, channels, Faults::default()).with_chunks(chunk),
        channels,
    );
}

/// `replies_in_pieces_give_the_same_statuses` on the loopbacks `make` makes, with replies in
/// pieces of the given size.
pub(crate) fn replies_in_pieces_give_the_same_statuses_on(make: impl Fn(usize) -> Loopback, channels: &[usize]) {
    let whole = statuses_of_a_script_on(make(usize::MAX), channels);
    assert_eq!(statuses_of_a_script_on(make(1), channels), whole);
    assert!(whole[0].last().is_some_and(|s| (s.position + 77.0).abs() < 1e-6), "{:?}", whole[0].last());
    assert!(whole[1].last().is_some_and(|s| s.msta & msta::DONE != 0 && s.position > 0.0), "{:?}", whole[1].last());
}

/// Through lost and garbled replies, a move of `channel` (up, switched on) is sent once (one
/// request for which `is_move` holds); then a connection that closes and comes back starts
/// again with `first` and writes only what `is_read` accepts. `line` reads a request.
pub(crate) fn a_move_goes_once_and_a_new_connection_only_reads(
    lb: &mut Loopback,
    channel: usize,
    line: impl Fn(&[u8]) -> String,
    is_move: impl Fn(&str) -> bool,
    is_read: impl Fn(&str) -> bool,
) {
    let lines_since =
        |lb: &Loopback, from: usize| -> Vec<String> { lb.written()[from..].iter().map(|r| line(r)).collect() };
    let first = lines_since(lb, 0);
    // Every third reply lost, every fifth replaced by noise.
    lb.link.set_faults(Faults { drop_every: Some(3), garble_every: Some(5), ..Faults::default() });
    let start = lb.written().len();
    let go = DriverCommand::Move {
        position: 5000.0,
        relative: false,
        min_velocity: 0.0,
        max_velocity: 20_000.0,
        acceleration: 200_000.0,
    };
    lb.command(channel, &go);
    lb.run_for(Duration::from_secs(5));
    let sent = lines_since(lb, start);
    // Sent once, or cut short when a reply to one of its requests was lost (a command half
    // carried out is not carried on): never twice.
    assert!(sent.iter().filter(|l| is_move(l)).count() <= 1, "a move is never sent twice: {sent:?}");
    for status in Loopback::statuses(&lb.take_events(), channel) {
        assert!((0.0..=5000.0 + 1e-6).contains(&status.position), "no noise became a position: {status:?}");
    }
    // Clean again, up; then the connection drops and comes back.
    lb.link.set_faults(Faults::default());
    lb.run_for(Duration::from_secs(3));
    assert!(lb.controller.is_up());
    lb.take_events();
    lb.link.set_faults(Faults { close_after: Some(1), ..Faults::default() });
    lb.run_for(Duration::from_millis(1200));
    assert!(lb.take_events().contains(&ControllerEvent::Disconnect));
    lb.link.set_faults(Faults::default());
    let start = lb.written().len();
    lb.run_for(Duration::from_secs(3));
    assert!(lb.controller.is_up());
    let again = lines_since(lb, start);
    assert_eq!(again.first(), first.first(), "initialised again: {again:?}");
    assert!(again.iter().all(|l| is_read(l)), "reads only: {again:?}");
    let axis = lb.link.emulator().axis(channel).expect("the channel");
    assert!(!axis.is_moving(), "nothing moves after the reconnection");
}

/// `kind` driving its emulator with `channels`, up, every channel switched on.
pub(crate) fn switched_on(kind: ProtocolKind, channels: &[usize]) -> Loopback {
    let mut lb = loopback(kind, channels, Faults::default());
    bring_up(&mut lb);
    for &channel in channels {
        lb.command(channel, &DriverCommand::Enable { on: true });
    }
    lb.run_for(Duration::from_millis(100));
    lb
}

/// A line the controller does not know, sent raw to `channel`, is its error, reported once as
/// `(channel, code)` say (the channel the vendor's error names, None for a controller's error);
/// the link stays up and the channel polled.
pub(crate) fn an_unknown_command_is_an_error_and_the_link_stays_up(
    lb: &mut Loopback,
    channel: usize,
    text: &str,
    (named, code): (Option<usize>, &str),
) {
    lb.command(channel, &DriverCommand::Raw { text: text.into() });
    lb.run_for(Duration::from_millis(1100));
    let events = lb.take_events();
    let errors = controller_errors(&events);
    assert_eq!(errors.len(), 1, "{events:?}");
    assert_eq!((errors[0].0, errors[0].1.as_str()), (named, code), "{errors:?}");
    assert!(lb.controller.is_up());
    assert!(!Loopback::statuses(&events, channel).is_empty(), "still polled");
}
