//! zmotor-emulators: the vendors' motor controllers, emulated. Each speaks its vendor's bytes
//! as the vendor's manual gives them (including what the vendor's own software sends:
//! identification, version and help queries, status bytes, error codes, the answer to an
//! unknown command) and moves zmotor-core's physical simulator behind every channel.
//!
//! An emulator is a witness, not a mirror: this crate depends on no driver, so a misreading of
//! a manual in a driver shows up as a disagreement with its emulator instead of being shared.
//! Emulators let a launch file for real hardware run with none attached (`zmotor
//! sim-controller`) and the drivers be tested byte for byte; `WithFaults` adds what real links
//! do: replies lost, late or garbled, a connection that closes.

mod acs_mcb4b;
mod attocube_amc;
mod emulator;
mod faulhaber_mc;
mod faults;
mod framing;
mod galil;
mod ims_mdrive;
mod kohzu_sc;
mod mclennan_pm304;
mod micronix_mmc;
mod models;
mod newfocus_8742;
mod newport_esp300;
mod newport_smc100;
mod newport_xps;
mod oms_maxnet;
mod phytron;
mod pi_gcs2;
mod piezojena_nv40;
mod pmac;
mod smaract_mcs2;
mod vmc;

pub use acs_mcb4b::Mcb4bEmulator;
pub use attocube_amc::AmcEmulator;
pub use emulator::{stage, Connection, Emulator};
pub use faulhaber_mc::FaulhaberEmulator;
pub use faults::{Faults, WithFaults};
pub use framing::Lines;
pub use galil::GalilEmulator;
pub use ims_mdrive::MdriveEmulator;
pub use kohzu_sc::KohzuScEmulator;
pub use mclennan_pm304::Pm304Emulator;
pub use micronix_mmc::MmcEmulator;
pub use models::Model;
pub use newfocus_8742::Picomotor8742Emulator;
pub use newport_esp300::Esp300Emulator;
pub use newport_smc100::Smc100Emulator;
pub use newport_xps::XpsEmulator;
pub use oms_maxnet::MaxnetEmulator;
pub use phytron::PhymotionEmulator;
pub use pi_gcs2::Gcs2Emulator;
pub use piezojena_nv40::Nv40Emulator;
pub use pmac::PmacEmulator;
pub use smaract_mcs2::{mcs2_positioner, Mcs2Emulator};
pub use vmc::VmcEmulator;
