//! A reply that comes after its request was given up and asked again, every reply after it
//! delayed behind it in order (a TCP retransmission stall): no protocol takes one request's
//! reply for another's. Protocols whose replies name their request cannot mistake them; the
//! others find their replies again with a query nothing else answers like (`Protocol::sync`).

mod common;

use common::bring_up;
use std::time::Duration;
use zmotor_controllers::{Loopback, ProtocolKind};
use zmotor_emulators::Faults;
use zmotor_msgs::DriverCommand;

/// Each protocol with one of its channels.
const CASES: [(ProtocolKind, usize); 12] = [
    (ProtocolKind::AcsMcb4b, 0),
    (ProtocolKind::NewportSmc100, 1),
    (ProtocolKind::PiGcs2, 1),
    (ProtocolKind::SmaractMcs2, 0),
    (ProtocolKind::Phytron, 11),
    (ProtocolKind::Pmac, 1),
    (ProtocolKind::NewportEsp300, 1),
    (ProtocolKind::Galil, 0),
    (ProtocolKind::McLennanPm304, 1),
    (ProtocolKind::NewportXps, 1),
    (ProtocolKind::ImsMdrive, 1),
    (ProtocolKind::OmsMaxnet, 0),
];

#[test]
fn a_reply_later_than_its_retry_is_never_taken_for_another_requests() {
    let mut misread = Vec::new();
    for (kind, channel) in CASES {
        let mut lb = common::loopback(kind, &[channel], Faults::default());
        let axis = lb.link.emulator().axis(channel).expect("an emulated channel");
        zmotor_core::Driver::set_position(axis, 4321.0);
        bring_up(&mut lb);
        lb.run_for(Duration::from_secs(2));
        let at_rest = Loopback::statuses(&lb.take_events(), channel).last().expect("a status").position;
        // A reply in flight for 1.28 s: past the timeout (1 s) and the quiet after it (0.25 s),
        // the retry already sent; for 2.52 s and 2.6 s: past the first resynchronisation's
        // timeout too (its late answer then taken for the second's).
        // Then 50 ms each, in order.
        for (stall, offset) in [(1280, 0), (1280, 3), (1280, 7), (2520, 11), (2600, 13), (2600, 29)] {
            lb.run_for(Duration::from_millis(offset));
            lb.link.set_faults(Faults { delay: Duration::from_millis(stall), ..Faults::default() });
            lb.command(channel, &DriverCommand::Poll);
            lb.run_for(Duration::from_millis(1));
            lb.link.set_faults(Faults { delay: Duration::from_millis(50), ..Faults::default() });
            lb.run_for(Duration::from_secs(6));
        }
        let statuses = Loopback::statuses(&lb.take_events(), channel);
        let read: Vec<f64> = statuses.iter().map(|s| s.position).collect();
        if read.iter().any(|p| *p != at_rest) {
            misread.push(format!("{}: at rest at {at_rest}, read {read:?}", kind.name()));
        }
    }
    assert!(misread.is_empty(), "{misread:#?}");
}
