//! A controller wired to an emulated one, in virtual time: how every protocol is tested byte
//! for byte, with the link's faults, without a socket or a clock.

use crate::controller::{AnyController, ControllerEvent};
use crate::keys::{KeyAccess, KeyReply, KeyValue};
use crate::protocol::Lane;
use std::collections::BTreeMap;
use std::time::Duration;
use zmotor_core::{DeviceStatus, Instant};
use zmotor_emulators::{Emulator, Faults, WithFaults};
use zmotor_msgs::DriverCommand;

/// Exchanges at one instant before the loop is declared runaway.
const MAX_EXCHANGES: usize = 100_000;

/// A controller and its emulated counterpart on one virtual clock.
pub struct Loopback {
    /// The driver side.
    pub controller: Box<dyn AnyController>,
    /// The controller side, behind its faults.
    pub link: WithFaults,
    now: Instant,
    /// Replies reach the driver this many bytes at a time (1: split at every byte boundary).
    chunk: usize,
    /// Whether a connection can be opened (a controller switched off, a cable pulled: no).
    reachable: bool,
    connected: bool,
    events: Vec<ControllerEvent>,
    written: Vec<Vec<u8>>,
    /// The key space a script reads and writes (`epics.get`/`put`), by key (prefix `motor`).
    pub keys: BTreeMap<String, KeyValue>,
}

/// The key prefix of the loopback's key space.
const KEY_PREFIX: &str = "motor";

impl Loopback {
    /// `controller`, made at time zero, driving `emulator` through `faults`.
    pub fn new(controller: Box<dyn AnyController>, emulator: Box<dyn Emulator>, faults: Faults) -> Self {
        Self {
            controller,
            link: WithFaults::new(emulator, faults),
            now: Instant::ZERO,
            chunk: usize::MAX,
            reachable: true,
            connected: false,
            events: Vec::new(),
            written: Vec::new(),
            keys: BTreeMap::new(),
        }
    }

    /// Replies are delivered `bytes` at a time.
    #[must_use]
    pub fn with_chunks(mut self, bytes: usize) -> Self {
        self.chunk = bytes.max(1);
        self
    }

    /// The virtual time.
    pub fn now(&self) -> Instant {
        self.now
    }

    /// Whether the emulated controller can be reached; making it unreachable closes the
    /// connection (the peer is gone), and attempts to reopen it fail until it is back.
    pub fn set_reachable(&mut self, reachable: bool) {
        self.reachable = reachable;
        if !reachable && self.connected {
            self.connected = false;
            self.controller.handle_disconnected(self.now);
        }
        self.settle();
    }

    /// A driver command now.
    pub fn command(&mut self, channel: usize, command: &DriverCommand) {
        self.controller.command(self.now, channel, command);
        self.settle();
    }

    /// Run the virtual clock for `duration`.
    pub fn run_for(&mut self, duration: Duration) {
        self.run_until(self.now + duration);
    }

    /// Run the virtual clock to `end`, everything due on the way happening at its time.
    pub fn run_until(&mut self, end: Instant) {
        self.settle();
        loop {
            let next = [self.controller.poll_timeout(), self.link.poll_timeout()].into_iter().flatten().min();
            match next {
                Some(t) if t <= end => self.step_to(t),
                _ => break,
            }
        }
        self.step_to(end);
    }

    /// Everything the controller reported since the last call.
    pub fn take_events(&mut self) -> Vec<ControllerEvent> {
        std::mem::take(&mut self.events)
    }

    /// The statuses of `channel` among `events`, in order.
    pub fn statuses(events: &[ControllerEvent], channel: usize) -> Vec<DeviceStatus> {
        events
            .iter()
            .filter_map(|e| match e {
                ControllerEvent::Status { channel: c, status, .. } if *c == channel => Some(*status),
                _ => None,
            })
            .collect()
    }

    /// Every request the driver wrote, on any lane, in order.
    pub fn written(&self) -> &[Vec<u8>] {
        &self.written
    }

    /// A script's access to the key space, carried out on `keys` as a node would.
    fn key_space(&mut self, bytes: &[u8]) -> KeyReply {
        match KeyAccess::decode(bytes) {
            Some(KeyAccess::Get(name)) => {
                let key = name.key(KEY_PREFIX);
                self.keys
                    .get(&key)
                    .cloned()
                    .map_or(KeyReply::Failed(format!("nothing answers for {key}")), KeyReply::Value)
            }
            Some(KeyAccess::Put(name, value)) => {
                self.keys.insert(name.key(KEY_PREFIX), value.clone());
                KeyReply::Value(value)
            }
            None => KeyReply::Failed("not a key access".into()),
        }
    }

    fn step_to(&mut self, t: Instant) {
        self.now = self.now.max(t);
        self.link.handle_timeout(self.now);
        self.controller.handle_timeout(self.now);
        self.settle();
    }

    /// Move bytes and events at the current instant until nothing is left to move.
    fn settle(&mut self) {
        for _ in 0..MAX_EXCHANGES {
            let mut moved = false;
            while let Some(event) = self.controller.poll_event() {
                moved = true;
                match event {
                    ControllerEvent::Connect if self.reachable => {
                        let lanes = self.controller.lanes().len();
                        assert!(
                            lanes <= self.link.connections(),
                            "the emulator serves fewer connections than the driver opens"
                        );
                        self.link.reconnect();
                        self.connected = true;
                        self.controller.handle_connected(self.now);
                    }
                    ControllerEvent::Connect => self.controller.handle_disconnected(self.now),
                    ControllerEvent::Disconnect => self.connected = false,
                    _ => {}
                }
                self.events.push(event);
            }
            // The controller's lanes are the emulator's connections, in the same order.
            let lanes = self.controller.lanes();
            let mut answers = Vec::new();
            while let Some((lane, bytes)) = self.controller.poll_transmit() {
                moved = true;
                if lane == Lane::Keys {
                    answers.push(self.key_space(&bytes));
                } else if self.connected {
                    let connection = lanes.iter().position(|l| *l == lane).expect("a lane of the controller");
                    self.link.handle_input_on(self.now, connection, &bytes);
                }
                self.written.push(bytes);
            }
            for answer in answers {
                self.controller.handle_input(self.now, Lane::Keys, &answer.encode());
            }
            while let Some((connection, reply)) = self.link.poll_transmit_on() {
                moved = true;
                let lane = lanes[connection];
                for piece in reply.chunks(self.chunk) {
                    self.controller.handle_input(self.now, lane, piece);
                }
            }
            if self.connected && self.link.is_closed() {
                moved = true;
                self.connected = false;
                self.controller.handle_disconnected(self.now);
            }
            if !moved {
                return;
            }
        }
        panic!("the controller and its emulator kept exchanging at {:?} without end", self.now);
    }
}
