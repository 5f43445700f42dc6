//! A link between a driver and its controller: its faults, and the pace of a serial line.

use crate::{Connection, Emulator};
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
    /// The driver's bytes on this connection reach the controller this late (one socket of
    /// several slower than the others: a controller may then see them out of their order).
    pub late_connection: Option<(Connection, Duration)>,
}

/// Bits on the wire per character of a serial line at 8N1: start, eight data bits, stop.
const BITS_PER_CHARACTER: u32 = 10;

/// An emulator behind a faulty link (see `Faults`), paced as a serial line where it is one.
pub struct WithFaults {
    emulator: Box<dyn Emulator>,
    faults: Faults,
    replies: u32,
    late: VecDeque<(Instant, Connection, Vec<u8>)>,
    /// On a serial line: how long one character takes, and the driver's bytes still on their
    /// way (each with when its last character has arrived).
    character_time: Option<Duration>,
    arriving: VecDeque<(Instant, Connection, Vec<u8>)>,
    /// When each direction of the line is free again.
    receive_free: Instant,
    send_free: Instant,
    now: Instant,
    closed: bool,
}

impl WithFaults {
    /// `emulator` behind `faults`.
    pub fn new(emulator: Box<dyn Emulator>, faults: Faults) -> Self {
        Self {
            emulator,
            faults,
            replies: 0,
            late: VecDeque::new(),
            character_time: None,
            arriving: VecDeque::new(),
            receive_free: Instant::ZERO,
            send_free: Instant::ZERO,
            now: Instant::ZERO,
            closed: false,
        }
    }

    /// The same link as a serial line at `baud` (8N1): every byte takes its time on the wire
    /// both ways, one after the other, so that a controller at 57,600 baud answers no faster
    /// than its line carries the bytes (a pseudo-terminal carries them at once).
    #[must_use]
    pub fn at_baud(self, baud: u32) -> Self {
        let character_time = Duration::from_secs(u64::from(BITS_PER_CHARACTER)) / baud.max(1);
        Self { character_time: Some(character_time), ..self }
    }

    /// How long `bytes` take on the line, if it is a serial line.
    fn on_the_wire(&self, bytes: usize) -> Duration {
        self.character_time.map_or(Duration::ZERO, |t| t * u32::try_from(bytes).unwrap_or(u32::MAX))
    }

    /// The protocol spoken.
    pub fn name(&self) -> &'static str {
        self.emulator.name()
    }

    /// Bytes from the driver at `now` on the first connection (on a serial line, the controller
    /// has them once they have crossed it).
    pub fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        self.handle_input_on(now, 0, bytes);
    }

    /// Bytes from the driver at `now` on `connection`.
    pub fn handle_input_on(&mut self, now: Instant, connection: Connection, bytes: &[u8]) {
        self.now = self.now.max(now);
        if self.closed {
            return;
        }
        let arrived = self.receive_free.max(self.now) + self.on_the_wire(bytes.len());
        self.receive_free = arrived;
        let late =
            self.faults.late_connection.filter(|(late, _)| *late == connection).map_or(Duration::ZERO, |(_, by)| by);
        self.arriving.push_back((arrived + late, connection, bytes.to_vec()));
        self.deliver();
    }

    /// Time passed to `now` (bytes on the line arrive, late replies come due, replies the
    /// controller held until a motion ended are sent).
    pub fn handle_timeout(&mut self, now: Instant) {
        self.now = self.now.max(now);
        self.deliver();
        if self.emulator.poll_timeout().is_some_and(|due| due <= self.now) {
            // Motions end whether the link is up or not; a closed link sends nothing.
            self.emulator.handle_timeout(self.now);
            if self.closed {
                while self.emulator.poll_transmit_on().is_some() {}
            } else {
                self.take_replies(self.now);
            }
        }
    }

    /// `connection` closed by the driver: the controller drops what it held for it.
    pub fn close(&mut self, connection: Connection) {
        self.emulator.handle_closed(connection);
        self.late.retain(|(_, on, _)| *on != connection);
        self.arriving.retain(|(_, on, _)| *on != connection);
    }

    /// The driver's bytes that have arrived, to the controller; its replies onto the line.
    fn deliver(&mut self) {
        // In the order they arrive (a late connection's bytes after others sent later).
        while !self.closed {
            let due = self
                .arriving
                .iter()
                .enumerate()
                .filter(|(_, (at, _, _))| *at <= self.now)
                .min_by_key(|(_, (at, _, _))| *at);
            let Some(index) = due.map(|(index, _)| index) else { break };
            let (at, connection, bytes) = self.arriving.remove(index).expect("an index of the queue");
            self.emulator.handle_input_on(at, connection, &bytes);
            self.take_replies(at);
        }
    }

    /// The controller's replies at `at`, onto the link with its faults.
    fn take_replies(&mut self, at: Instant) {
        while let Some((connection, reply)) = self.emulator.poll_transmit_on() {
            self.replies += 1;
            let nth = |every: Option<u32>| every.is_some_and(|n| n > 0 && self.replies.is_multiple_of(n));
            if nth(self.faults.drop_every) {
                continue;
            }
            let reply = if nth(self.faults.garble_every) { vec![b'~'; reply.len().max(3)] } else { reply };
            let sent = self.send_free.max(at + self.faults.delay) + self.on_the_wire(reply.len());
            self.send_free = sent;
            self.late.push_back((sent, connection, reply));
            if self.faults.close_after.is_some_and(|n| self.replies >= n) {
                self.closed = true;
                break;
            }
        }
    }

    /// The next reply due by now (of a controller serving one connection).
    #[must_use]
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.poll_transmit_on().map(|(_, bytes)| bytes)
    }

    /// The next reply due by now, and the connection it goes on.
    #[must_use]
    pub fn poll_transmit_on(&mut self) -> Option<(Connection, Vec<u8>)> {
        if self.late.front().is_some_and(|(due, _, _)| *due <= self.now) {
            return self.late.pop_front().map(|(_, connection, bytes)| (connection, bytes));
        }
        None
    }

    /// When the next late reply is due, the next bytes on the line arrive, or the controller
    /// sends a reply it held.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        let arriving = self.arriving.iter().map(|(due, _, _)| *due);
        let link = self.late.front().map(|(due, _, _)| *due).into_iter().chain(arriving);
        link.chain(self.emulator.poll_timeout()).min()
    }

    /// How many connections the controller serves at once.
    pub fn connections(&self) -> usize {
        self.emulator.connections()
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
        for connection in 0..self.emulator.connections() {
            self.emulator.handle_closed(connection);
        }
        self.closed = false;
        self.replies = 0;
        self.late.clear();
        self.arriving.clear();
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Model;

    fn at(seconds: f64) -> Instant {
        Instant::after(Duration::from_secs_f64(seconds))
    }

    /// Run the link until `until`, stepping from due time to due time; the replies with when.
    fn replies_until(link: &mut WithFaults, until: Instant) -> Vec<(Instant, Vec<u8>)> {
        let mut seen = Vec::new();
        while let Some(due) = link.poll_timeout().filter(|due| *due <= until) {
            link.handle_timeout(due);
            while let Some(reply) = link.poll_transmit() {
                seen.push((due, reply));
            }
        }
        seen
    }

    #[test]
    fn a_serial_line_carries_each_byte_in_its_time_both_ways() {
        // 57,600 baud: 5,760 characters a second.
        let mut link = WithFaults::new(Model::NewportSmc100.emulator(2), Faults::default()).at_baud(57_600);
        link.handle_input(Instant::ZERO, b"1TS\r\n");
        assert_eq!(link.poll_transmit(), None, "nothing before the request has crossed the line");
        let replies = replies_until(&mut link, at(1.0));
        let [(when, reply)] = &replies[..] else { panic!("{replies:?}") };
        let characters = 5 + reply.len();
        let per_character = Duration::from_secs(10) / 57_600;
        assert_eq!(when.since_origin(), per_character * characters as u32, "{characters} characters at 5,760 a second");
        // Requests sent at once queue on the line: a second is answered a request and a reply later.
        link.handle_input(at(2.0), b"1TS\r\n1TS\r\n");
        let replies = replies_until(&mut link, at(3.0));
        assert_eq!(replies.len(), 2);
        assert_eq!(replies[1].0 - replies[0].0, per_character * replies[1].1.len() as u32);
    }

    #[test]
    fn without_a_line_replies_come_at_once() {
        let mut link = WithFaults::new(Model::NewportSmc100.emulator(2), Faults::default());
        link.handle_input(Instant::ZERO, b"1TS\r\n");
        assert!(link.poll_transmit().is_some());
    }
}
