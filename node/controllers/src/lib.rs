//! zmotor-controllers: real motor controllers, sans-IO. `controller` is the controller layer
//! (one connection, a priority queue, polls, the link and its loss); `protocol` what a vendor's
//! protocol provides; one module per vendor; `emulator` the vendors' controllers emulated on
//! zmotor-core's physical simulator. A runner (zmotor-zenoh) moves the bytes.

pub mod acs;
pub mod controller;
pub mod emulator;
pub mod loopback;
pub mod phytron;
pub mod protocol;

pub use controller::{Controller, ControllerConfig, ControllerEvent, Refusal};
pub use protocol::{CommandError, Protocol, ProtocolOptions};

/// The protocols zmotor speaks, by the names launch files give them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ProtocolKind {
    /// ACS MCB-4B.
    AcsMcb4b,
    /// Phytron phyMOTION (channel = module × 10 + axis).
    Phytron,
}

impl ProtocolKind {
    /// Every protocol.
    pub const ALL: [ProtocolKind; 2] = [ProtocolKind::AcsMcb4b, ProtocolKind::Phytron];

    /// Its name in launch files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ProtocolKind::AcsMcb4b => acs::NAME,
            ProtocolKind::Phytron => phytron::NAME,
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
            ProtocolKind::Phytron => Box::new(phytron::Phymotion::new(options)),
        }
    }

    /// An emulated controller of `channels` axes (a phyMOTION: modules of two axes holding
    /// every channel below `channels`, two modules at least).
    pub fn emulator(self, channels: usize) -> Box<dyn emulator::Emulator> {
        let mechanics = emulator::stage();
        match self {
            ProtocolKind::AcsMcb4b => Box::new(emulator::acs::Mcb4bEmulator::new(channels, &mechanics)),
            ProtocolKind::Phytron => {
                // Each axis reads an encoder of one count a step (I1EM modules).
                let mechanics = zmotor_core::driver::sim::SimConfig { encoder_counts_per_step: Some(1.0), ..mechanics };
                Box::new(emulator::phytron::PhymotionEmulator::with_channels_below(channels, &mechanics))
            }
        }
    }
}
