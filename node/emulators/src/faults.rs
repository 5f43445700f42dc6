//! A link's faults between a driver and its controller.

use crate::Emulator;
use std::collections::VecDeque;
use std::time::Duration;
use zmotor_core::Instant;

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
