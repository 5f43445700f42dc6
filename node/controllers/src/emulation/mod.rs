//! Emulators of the vendors' controllers: each speaks its vendor's bytes, and moves the
//! physical simulator of zmotor-core (one physics for all) behind every channel. They let a
//! launch file for real hardware run with none attached (`zmotor sim-controller`), and the
//! drivers be tested against the bytes of their protocol. `WithFaults` adds what real links
//! do: replies lost, late or garbled, a connection that closes.

pub(crate) mod acs;
pub(crate) mod newport;
pub(crate) mod phytron;
pub(crate) mod pi_gcs2;
pub(crate) mod smaract_mcs2;

use std::collections::VecDeque;
use std::time::Duration;
use zmotor_core::{Instant, SimAxis, SimConfig};

/// A controller's side of the wire, sans-IO: bytes in at a time, bytes out.
pub trait Emulator: Send {
    /// The protocol it speaks, as launch files name it.
    fn name(&self) -> &'static str;
    /// Bytes from the driver, at `now`; the replies are queued.
    fn handle_input(&mut self, now: Instant, bytes: &[u8]);
    /// The next bytes to send to the driver.
    #[must_use]
    fn poll_transmit(&mut self) -> Option<Vec<u8>>;
    /// How many requests so far were not well-formed in the protocol (a driver's fault).
    fn malformed(&self) -> usize;
    /// The simulated axis behind channel `channel`, if the controller has that channel.
    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis>;
    /// Make the controller report an error for `channel` its own way (an error code, an error
    /// queue entry, a refusal), as if the last command had failed. False when the protocol has
    /// no way to report one.
    fn raise_error(&mut self, channel: usize) -> bool;
}

/// The mechanics behind every channel of an emulated controller, in steps.
pub fn stage() -> SimConfig {
    SimConfig {
        high_limit_switch: Some(200_000.0),
        low_limit_switch: Some(-200_000.0),
        home_switch: 0.0,
        ..SimConfig::default()
    }
}

/// One simulated axis per channel, `channels` of them.
pub(crate) fn axes(channels: usize, mechanics: &SimConfig) -> Vec<SimAxis> {
    (0..channels).map(|_| SimAxis::new(mechanics.clone())).collect()
}

/// What goes wrong on the link, every so many replies.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Faults {
    /// Every n-th reply is never sent.
    pub drop_every: Option<u32>,
    /// Every n-th reply is replaced by noise.
    pub garble_every: Option<u32>,
    /// Every reply is sent this late.
    pub delay: Duration,
    /// The connection closes after this many replies.
    pub close_after: Option<u32>,
}

/// An emulator behind a faulty link (see `Faults`).
pub struct WithFaults {
    emulator: Box<dyn Emulator>,
    faults: Faults,
    replies: u32,
    late: VecDeque<(Instant, Vec<u8>)>,
    now: Instant,
    closed: bool,
}

impl WithFaults {
    /// `emulator` behind `faults`.
    pub fn new(emulator: Box<dyn Emulator>, faults: Faults) -> Self {
        Self { emulator, faults, replies: 0, late: VecDeque::new(), now: Instant::ZERO, closed: false }
    }

    /// The protocol spoken.
    pub fn name(&self) -> &'static str {
        self.emulator.name()
    }

    /// Bytes from the driver at `now`.
    pub fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        self.now = self.now.max(now);
        if self.closed {
            return;
        }
        self.emulator.handle_input(self.now, bytes);
        while let Some(reply) = self.emulator.poll_transmit() {
            self.replies += 1;
            let nth = |every: Option<u32>| every.is_some_and(|n| n > 0 && self.replies.is_multiple_of(n));
            if nth(self.faults.drop_every) {
                continue;
            }
            let reply = if nth(self.faults.garble_every) { vec![b'~'; reply.len().max(3)] } else { reply };
            self.late.push_back((self.now + self.faults.delay, reply));
            if self.faults.close_after.is_some_and(|n| self.replies >= n) {
                self.closed = true;
                break;
            }
        }
    }

    /// Time passed to `now` (late replies come due).
    pub fn handle_timeout(&mut self, now: Instant) {
        self.now = self.now.max(now);
    }

    /// The next reply due by now.
    #[must_use]
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        if self.late.front().is_some_and(|(due, _)| *due <= self.now) {
            return self.late.pop_front().map(|(_, bytes)| bytes);
        }
        None
    }

    /// When the next late reply is due.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.late.front().map(|(due, _)| *due)
    }

    /// The connection is to be closed (after its last replies).
    pub fn is_closed(&self) -> bool {
        self.closed && self.late.is_empty()
    }

    /// Other faults from now on, replies counted from here.
    pub fn set_faults(&mut self, faults: Faults) {
        self.faults = faults;
        self.replies = 0;
    }

    /// A new connection to the same controller: what the old one had in transit is lost, the
    /// controller itself (its axes, its settings) is as it was, the faults count again.
    pub fn reconnect(&mut self) {
        self.closed = false;
        self.replies = 0;
        self.late.clear();
    }

    /// Requests that were not well-formed.
    pub fn malformed(&self) -> usize {
        self.emulator.malformed()
    }

    /// The emulator, to reach its axes.
    pub fn emulator(&mut self) -> &mut dyn Emulator {
        self.emulator.as_mut()
    }
}
