//! zmotor-controllers: real motor controllers, sans-IO. `controller` is the controller layer
//! (one connection, a priority queue, polls, the link and its loss); `protocol` what a vendor's
//! protocol provides; one module per vendor; `emulator` the vendors' controllers emulated on
//! zmotor-core's physical simulator. A runner (zmotor-zenoh) moves the bytes.

pub mod acs;
pub mod controller;
pub mod emulator;
pub mod loopback;
pub mod protocol;
pub mod smaract_mcs2;

pub use controller::{Controller, ControllerConfig, ControllerEvent, Refusal};
pub use protocol::{CommandError, Protocol, ProtocolOptions};

/// The protocols zmotor speaks, by the names launch files give them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ProtocolKind {
    /// ACS MCB-4B.
    AcsMcb4b,
    /// SmarAct MCS2 (linear positioners with a sensor, over TCP).
    SmaractMcs2,
}

impl ProtocolKind {
    /// Every protocol.
    pub const ALL: [ProtocolKind; 2] = [ProtocolKind::AcsMcb4b, ProtocolKind::SmaractMcs2];

    /// Its name in launch files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ProtocolKind::AcsMcb4b => acs::NAME,
            ProtocolKind::SmaractMcs2 => smaract_mcs2::NAME,
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
            ProtocolKind::SmaractMcs2 => Box::new(smaract_mcs2::Mcs2::new(options)),
        }
    }

    /// An emulated controller of `channels` axes (an MCS2's in picometres, at the default
    /// scale of one nanometre per step).
    pub fn emulator(self, channels: usize) -> Box<dyn emulator::Emulator> {
        let mechanics = emulator::stage();
        match self {
            ProtocolKind::AcsMcb4b => Box::new(emulator::acs::Mcb4bEmulator::new(channels, &mechanics)),
            ProtocolKind::SmaractMcs2 => {
                let positioner = emulator::smaract_mcs2::positioner(&mechanics);
                Box::new(emulator::smaract_mcs2::Mcs2Emulator::new(channels, &positioner))
            }
        }
    }
}
