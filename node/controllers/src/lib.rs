//! zmotor-controllers: real motor controllers, sans-IO. `controller` is the controller layer
//! (one connection, a priority queue, polls, the link and its loss); `protocol` what a vendor's
//! protocol provides; one module per vendor; `emulator` the vendors' controllers emulated on
//! zmotor-core's physical simulator. A runner (zmotor-zenoh) moves the bytes.

pub mod acs;
pub mod controller;
pub mod emulator;
pub mod loopback;
pub mod pi_gcs2;
pub mod protocol;

pub use controller::{Controller, ControllerConfig, ControllerEvent, Refusal};
pub use protocol::{CommandError, Protocol, ProtocolOptions};

/// The protocols zmotor speaks, by the names launch files give them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ProtocolKind {
    /// ACS MCB-4B.
    AcsMcb4b,
    /// PI GCS 2 (C-863 Mercury, C-884 and their class).
    PiGcs2,
}

impl ProtocolKind {
    /// Every protocol.
    pub const ALL: [ProtocolKind; 2] = [ProtocolKind::AcsMcb4b, ProtocolKind::PiGcs2];

    /// Its name in launch files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ProtocolKind::AcsMcb4b => acs::NAME,
            ProtocolKind::PiGcs2 => pi_gcs2::NAME,
        }
    }

    /// The protocol named `name`.
    pub fn from_name(name: &str) -> Option<ProtocolKind> {
        ProtocolKind::ALL.into_iter().find(|p| p.name() == name)
    }

    /// A driver side of the protocol.
    pub fn protocol(self, options: &ProtocolOptions) -> Box<dyn Protocol> {
        match self {
            ProtocolKind::AcsMcb4b => Box::new(acs::Mcb4b::new()),
            ProtocolKind::PiGcs2 => Box::new(pi_gcs2::PiGcs2::new(options)),
        }
    }

    /// An emulated controller of `channels` axes (channels 0 to `channels` − 1; a PI
    /// controller's axes count from 1: a C-884 of four, or as many as the channels need).
    pub fn emulator(self, channels: usize) -> Box<dyn emulator::Emulator> {
        let mechanics = emulator::stage();
        match self {
            ProtocolKind::AcsMcb4b => Box::new(emulator::acs::Mcb4bEmulator::new(channels, &mechanics)),
            ProtocolKind::PiGcs2 => {
                let axes = channels.saturating_sub(1).max(4);
                Box::new(emulator::pi_gcs2::Gcs2Emulator::new(axes, &emulator::pi_gcs2::mechanics()))
            }
        }
    }
}
