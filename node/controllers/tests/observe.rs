//! `observe = true`: a controller connected, initialised read-only and polled, and nothing
//! else, whatever the record commands: no motion, no power, no setting. A lab connects zmotor
//! beside its running IOC, or to new hardware before its first move, and compares readbacks.

mod common;

use common::{bring_up, command};
use proptest::prelude::*;
use std::collections::BTreeSet;
use std::time::Duration;
use zmotor_controllers::{ControllerConfig, ControllerEvent, Loopback, ProtocolKind, ProtocolOptions, Refusal};
use zmotor_core::Instant;
use zmotor_emulators::Faults;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

/// Each protocol with two of its channels.
const CASES: [(ProtocolKind, [usize; 2]); 12] = [
    (ProtocolKind::AcsMcb4b, [0, 2]),
    (ProtocolKind::NewportSmc100, [1, 2]),
    (ProtocolKind::PiGcs2, [1, 4]),
    (ProtocolKind::SmaractMcs2, [0, 2]),
    (ProtocolKind::Phytron, [11, 22]),
    (ProtocolKind::Pmac, [1, 2]),
    (ProtocolKind::NewportEsp300, [1, 2]),
    (ProtocolKind::Galil, [0, 1]),
    (ProtocolKind::McLennanPm304, [1, 2]),
    (ProtocolKind::NewportXps, [1, 2]),
    (ProtocolKind::ImsMdrive, [1, 2]),
    (ProtocolKind::OmsMaxnet, [0, 2]),
];

fn observed(kind: ProtocolKind, channels: &[usize]) -> Loopback {
    let emulator = common::emulator(kind, channels.iter().max().map_or(1, |c| c + 1));
    let config = ControllerConfig { observe: true, ..ControllerConfig::for_channels(channels.to_vec()) };
    Loopback::new(kind.controller(&ProtocolOptions::default(), config, Instant::ZERO), emulator, Faults::default())
}

/// Every request an observed controller sends when left alone and asked for status refreshes:
/// its readings.
fn readings(kind: ProtocolKind, channels: &[usize]) -> BTreeSet<Vec<u8>> {
    let mut lb = observed(kind, channels);
    bring_up(&mut lb);
    for &channel in channels {
        lb.command(channel, &DriverCommand::Poll);
        lb.run_for(Duration::from_millis(200));
    }
    lb.run_for(Duration::from_secs(3));
    lb.written().iter().cloned().collect()
}

#[test]
fn an_observed_controller_is_initialised_without_a_setting() {
    // PI's servo is not switched on, SmarAct's holding time not set, ESP300 motors and Galil
    // servos stay off, XPS groups uninitialised: only readings go out.
    for (kind, channels) in CASES {
        let mut plain = common::loopback(kind, &channels, Faults::default());
        bring_up(&mut plain);
        let observed_requests = readings(kind, &channels);
        let setup: Vec<String> = plain
            .written()
            .iter()
            .filter(|r| !observed_requests.contains(*r))
            .map(|r| String::from_utf8_lossy(r).into_owned())
            .collect();
        match kind {
            ProtocolKind::PiGcs2 => assert!(setup.iter().any(|r| r.starts_with("SVO")), "{setup:?}"),
            ProtocolKind::SmaractMcs2 => assert!(setup.iter().any(|r| r.contains(":HOLD")), "{setup:?}"),
            ProtocolKind::NewportEsp300 => assert!(setup.iter().any(|r| r.contains("MO")), "{setup:?}"),
            ProtocolKind::Galil => assert!(setup.iter().any(|r| r.starts_with("SH")), "{setup:?}"),
            ProtocolKind::NewportXps => assert!(setup.iter().any(|r| r.starts_with("GroupInitialize")), "{setup:?}"),
            // Its done flags read by `QI`, which leaves them to the IOC beside.
            ProtocolKind::OmsMaxnet => assert_eq!(setup, ["AM;RI;\n"]),
            _ => assert!(setup.is_empty(), "{}: an observed init leaves out {setup:?}", kind.name()),
        }
    }
}

#[test]
fn an_observed_controller_reads_nothing_that_clears_what_the_ioc_beside_reads() {
    // PI's error register, SmarAct's error queue and the ESP300's error buffer are emptied by
    // their reads, a MAXnet's done flags by `RI`: under `observe` they are the IOC's.
    let clearing = ["ERR?", ":SYST:ERR?", "TB?", "AM;RI;"];
    for (kind, channels) in CASES {
        let cleared: Vec<String> = readings(kind, &channels)
            .iter()
            .map(|r| String::from_utf8_lossy(r).into_owned())
            .filter(|r| clearing.iter().any(|c| r.starts_with(c)))
            .collect();
        assert!(cleared.is_empty(), "{}: an observed controller read {cleared:?}", kind.name());
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn an_observed_controller_moves_nothing_under_any_command(
        case in 0..CASES.len(),
        commands in proptest::collection::vec((0..2usize, command(), 0..300u64), 1..16),
    ) {
        let (kind, channels) = CASES[case];
        let allowed = readings(kind, &channels);
        let mut lb = observed(kind, &channels);
        bring_up(&mut lb);
        let before: Vec<f64> =
            channels.iter().map(|&c| lb.link.emulator().axis(c).expect("an emulated channel").physical_position()).collect();
        for (pick, command, gap_ms) in &commands {
            lb.command(channels[*pick], command);
            lb.run_for(Duration::from_millis(*gap_ms));
        }
        lb.run_for(Duration::from_secs(2));
        for event in lb.take_events() {
            if let ControllerEvent::Refused { why, .. } = event {
                prop_assert!(matches!(why, Refusal::Observed), "{}: refused for another reason: {why}", kind.name());
            }
        }
        let unexpected: Vec<String> = lb
            .written()
            .iter()
            .filter(|r| !allowed.contains(*r))
            .map(|r| String::from_utf8_lossy(r).into_owned())
            .collect();
        prop_assert!(unexpected.is_empty(), "{}: an observed controller was sent {unexpected:?}", kind.name());
        for (&channel, position) in channels.iter().zip(before) {
            let axis = lb.link.emulator().axis(channel).expect("an emulated channel");
            prop_assert!(!axis.is_moving() && axis.physical_position() == position, "{} channel {channel} moved", kind.name());
        }
    }
}

#[test]
fn an_observed_controller_owes_no_stop_when_its_link_comes_back() {
    // The IOC beside zmotor jogs a channel; zmotor's link drops while its polls see it move,
    // and comes back: the jog is the IOC's to stop, not zmotor's. (The protocols whose emulator
    // reports a jog started on its simulated stage, not through its own commands: the others
    // keep a motion state of their own, and the rule is the controller layer's, one for all.)
    let reporting = [
        ProtocolKind::AcsMcb4b,
        ProtocolKind::SmaractMcs2,
        ProtocolKind::Phytron,
        ProtocolKind::NewportEsp300,
        ProtocolKind::McLennanPm304,
        ProtocolKind::ImsMdrive,
        ProtocolKind::OmsMaxnet,
    ];
    for (kind, channels) in CASES.into_iter().filter(|(kind, _)| reporting.contains(kind)) {
        let mut lb = observed(kind, &channels);
        bring_up(&mut lb);
        let axis = lb.link.emulator().axis(channels[0]).expect("an emulated channel");
        zmotor_core::Driver::enable(axis, true);
        zmotor_core::Driver::move_velocity(axis, 0.0, 500.0, 100_000.0);
        lb.run_for(Duration::from_secs(3));
        let seen_moving = Loopback::statuses(&lb.take_events(), channels[0]).iter().any(|s| s.msta & msta::DONE == 0);
        assert!(seen_moving, "{}: the polls saw the jog", kind.name());
        lb.set_reachable(false);
        lb.run_for(Duration::from_secs(3));
        lb.set_reachable(true);
        lb.run_for(Duration::from_secs(3));
        assert!(lb.controller.is_up(), "{}: the link is back", kind.name());
        let now = lb.now();
        let axis = lb.link.emulator().axis(channels[0]).expect("an emulated channel");
        zmotor_core::Driver::advance(axis, now);
        assert!(axis.is_moving(), "{}: an observed controller stopped the IOC's jog", kind.name());
    }
}
