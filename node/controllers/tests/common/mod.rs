//! What every protocol's tests share: a loopback in virtual time, and arbitrary record commands.
#![allow(dead_code)] // each test file uses its own part

pub(crate) mod golden;

use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{ControllerConfig, ControllerEvent, Loopback, ProtocolKind, ProtocolOptions, VendorError};
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
    let mut lb = loopback(kind, channels, Faults::default());
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
}
