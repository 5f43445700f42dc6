//! What every emulated controller is to its runner, and the mechanics behind its channels.

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
