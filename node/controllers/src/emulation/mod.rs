//! Emulators of the vendors' controllers: each speaks its vendor's bytes, and moves the
//! physical simulator of zmotor-core (one physics for all) behind every channel. They let a
//! launch file for real hardware run with none attached (`zmotor sim-controller`), and the
//! drivers be tested against the bytes of their protocol. `WithFaults` adds what real links
//! do: replies lost, late or garbled, a connection that closes.

pub(crate) mod acs;
pub(crate) mod newport;
pub(crate) mod phytron;
pub(crate) mod smaract_mcs2;

use zmotor_core::{SimAxis, SimConfig};
pub(crate) use zmotor_emulators::{stage, Emulator};

/// One simulated axis per channel, `channels` of them.
pub(crate) fn axes(channels: usize, mechanics: &SimConfig) -> Vec<SimAxis> {
    (0..channels).map(|_| SimAxis::new(mechanics.clone())).collect()
}
