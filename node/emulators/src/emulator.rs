//! What every emulated controller is to its runner, and the mechanics behind its channels.

use zmotor_core::{Instant, SimAxis, SimConfig};

/// One of a controller's simultaneous connections, numbered from 0 in the order the runner
/// opened them. Most controllers serve one; an XPS serves many, each a socket of its own.
pub type Connection = usize;

/// A controller's side of the wire, sans-IO: bytes in at a time, bytes out. `handle_input` and
/// `poll_transmit` are the first connection's; a controller serving several connections at once
/// also gives the `_on` methods, and one whose replies wait for a motion gives `poll_timeout`.
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

    /// How many connections the controller serves at once.
    fn connections(&self) -> usize {
        1
    }

    /// Bytes from the driver on `connection`, at `now`.
    fn handle_input_on(&mut self, now: Instant, connection: Connection, bytes: &[u8]) {
        debug_assert_eq!(connection, 0, "{} serves one connection", self.name());
        self.handle_input(now, bytes);
    }

    /// The next bytes to send, and the connection they go on.
    #[must_use]
    fn poll_transmit_on(&mut self) -> Option<(Connection, Vec<u8>)> {
        self.poll_transmit().map(|bytes| (0, bytes))
    }

    /// `connection` closed: what it was waiting for is dropped (the axes move on).
    fn handle_closed(&mut self, connection: Connection) {
        let _ = connection;
    }

    /// Time passed to `now`: a reply held until a motion ended comes due.
    fn handle_timeout(&mut self, now: Instant) {
        let _ = now;
    }

    /// When `handle_timeout` is next due, if a reply is held.
    #[must_use]
    fn poll_timeout(&self) -> Option<Instant> {
        None
    }
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
