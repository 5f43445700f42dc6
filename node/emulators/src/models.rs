//! The controllers emulated, by the protocol names launch files give them (the wire's
//! vocabulary, which the drivers share; `zmotor-sim-controller`'s tests check both lists agree).

use crate::{
    mcs2_positioner, stage, AmcEmulator, Emulator, Esp300Emulator, FaulhaberEmulator, GalilEmulator, Gcs2Emulator,
    KohzuScEmulator, MaxnetEmulator, Mcb4bEmulator, Mcs2Emulator, MdriveEmulator, MmcEmulator, Nv40Emulator,
    PhymotionEmulator, Picomotor8742Emulator, Pm304Emulator, PmacEmulator, Smc100Emulator, VmcEmulator, XpsEmulator,
};

/// A controller model this crate emulates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Model {
    /// ACS MCB-4B.
    AcsMcb4b,
    /// A chain of Newport SMC100CC controllers.
    NewportSmc100,
    /// A PI C-884 class controller (GCS 2.0).
    PiGcs2,
    /// A SmarAct MCS2.
    SmaractMcs2,
    /// A Phytron phyMOTION.
    Phytron,
    /// A Delta Tau Turbo PMAC2 / Geo Brick, over Ethernet.
    Pmac,
    /// A Newport ESP300 / ESP301, three axes on a serial line.
    NewportEsp300,
    /// A Galil DMC-4040, four axes, over Ethernet.
    Galil,
    /// A McLennan PM304, or a chain of them, on a serial line.
    McLennanPm304,
    /// A Newport XPS, over Ethernet, serving several sockets at once.
    NewportXps,
    /// IMS MDrive Plus motors sharing a serial line in party mode.
    ImsMdrive,
    /// An Oregon Micro Systems MAXnet, over Ethernet.
    OmsMaxnet,
    /// Kevin Peterson's Virtual Motor Controller (motorVMC's), over TCP; driven by a script.
    Vmc,
    /// A Kohzu SC-400 (SC-200/400/800 family); driven by a script.
    KohzuSc,
    /// Micronix MMC-100 modules on one line; driven by a script.
    MicronixMmc,
    /// A New Focus 8742 picomotor controller, over Ethernet (Telnet); driven by a script.
    NewFocus8742,
    /// An attocube AMC100, JSON-RPC over TCP, its outputs switched on; driven by a script.
    AttocubeAmc,
    /// A piezosystem jena NV40/3 CLE three-channel piezo amplifier; driven by a script.
    PiezojenaNv40,
    /// Faulhaber MCDC 300x drives (ASCII) at node numbers 1 … on one line; driven by a script.
    FaulhaberMc,
}

impl Model {
    /// Every model.
    pub const ALL: [Model; 19] = [
        Model::AcsMcb4b,
        Model::NewportSmc100,
        Model::PiGcs2,
        Model::SmaractMcs2,
        Model::Phytron,
        Model::Pmac,
        Model::NewportEsp300,
        Model::Galil,
        Model::McLennanPm304,
        Model::NewportXps,
        Model::ImsMdrive,
        Model::OmsMaxnet,
        Model::Vmc,
        Model::KohzuSc,
        Model::MicronixMmc,
        Model::NewFocus8742,
        Model::AttocubeAmc,
        Model::PiezojenaNv40,
        Model::FaulhaberMc,
    ];

    /// The protocol it speaks, as launch files name it; for a controller a script drives
    /// (`protocol = "script"`), the family's name (`zmotor sim-controller` takes either).
    pub fn protocol(self) -> &'static str {
        match self {
            Model::AcsMcb4b => "acs_mcb4b",
            Model::NewportSmc100 => "newport_smc100",
            Model::PiGcs2 => "pi_gcs2",
            Model::SmaractMcs2 => "smaract_mcs2",
            Model::Phytron => "phytron",
            Model::Pmac => "pmac",
            Model::NewportEsp300 => "newport_esp300",
            Model::Galil => "galil",
            Model::McLennanPm304 => "mclennan_pm304",
            Model::NewportXps => "newport_xps",
            Model::ImsMdrive => "ims_mdrive",
            Model::OmsMaxnet => "oms_maxnet",
            Model::Vmc => "vmc",
            Model::KohzuSc => "kohzu_sc",
            Model::MicronixMmc => "micronix_mmc",
            Model::NewFocus8742 => "newfocus_8742",
            Model::AttocubeAmc => "attocube_amc",
            Model::PiezojenaNv40 => "piezojena_nv40",
            Model::FaulhaberMc => "faulhaber_mc",
        }
    }

    /// The model speaking `protocol` (a launch file's name for it, exactly).
    pub fn speaking(protocol: &str) -> Option<Model> {
        Model::ALL.into_iter().find(|model| model.protocol() == protocol)
    }

    /// The rate of its serial line as it leaves the factory, as a pseudo-terminal emulating
    /// the line carries bytes: the SMC100's manual gives 57,600 baud and PI's C-863 manual
    /// 115,200; the ESP family's line runs at 19,200 (the ESP302-GPIB adaptor's manual, §2.5);
    /// the others' documents were not to be had, and 9,600 (the usual factory rate of serial
    /// controllers) stands for theirs (`zmotor sim-controller --baud` sets any).
    pub fn factory_baud(self) -> u32 {
        match self {
            Model::NewportSmc100 => 57_600,
            // The NV40/3 CLE's line, as piezosystem jena's own library opens it.
            Model::PiezojenaNv40 => 19_200,
            Model::NewportEsp300 => 19_200,
            Model::PiGcs2 => 115_200,
            // The DMC-40x0 is reached over TCP; 115,200 is taken for its RS-232 port's factory
            // rate (not read in its manual), and only paces a pseudo-terminal standing in.
            Model::Galil => 115_200,
            // The PMAC is reached over TCP; its rate only paces a pseudo-terminal standing in.
            // The XPS and the MAXnet are reached over TCP; the rate only paces a pseudo-terminal.
            Model::AcsMcb4b
            | Model::SmaractMcs2
            | Model::Phytron
            | Model::Pmac
            | Model::McLennanPm304
            | Model::NewportXps
            | Model::ImsMdrive
            | Model::OmsMaxnet
            | Model::Vmc
            | Model::KohzuSc
            | Model::MicronixMmc
            | Model::NewFocus8742
            | Model::AttocubeAmc
            | Model::FaulhaberMc => 9_600,
        }
    }

    /// The channels a typical controller of the model has (what `zmotor sim-controller` makes
    /// when not told): one more than its highest channel number.
    pub fn typical_channels(self) -> usize {
        match self {
            Model::AcsMcb4b => 4,
            Model::NewportSmc100 => 3,
            Model::PiGcs2 => 5,
            Model::SmaractMcs2 => 3,
            Model::Phytron => 23,
            // A Geo Brick's motors 1 to 8; there is no motor 0.
            Model::Pmac => 9,
            // Axes 1 to 3; there is no axis 0.
            Model::NewportEsp300 => 4,
            // Axes A to D, channels 0 to 3.
            Model::Galil => 4,
            // Address 1; there is no address 0.
            Model::McLennanPm304 => 2,
            // Groups 1 to 4 (GROUP1.POSITIONER …); there is no group 0.
            Model::NewportXps => 5,
            // Party-mode names 1 to 3 on channels 1 to 3.
            Model::ImsMdrive => 4,
            // Axes X, Y, Z, T on channels 0 to 3.
            Model::OmsMaxnet => 4,
            // A script's AXIS n drives the controller's axis n + 1: channels 0 to 3 are axes 1 to 4.
            Model::Vmc | Model::KohzuSc | Model::NewFocus8742 => 4,
            Model::MicronixMmc => 2,
            // Axes (channels) 0 to 2, a script's AXIS.
            Model::AttocubeAmc | Model::PiezojenaNv40 => 3,
            // Node numbers 1 and 2, a script's AXIS; node 0 reaches every drive.
            Model::FaulhaberMc => 3,
        }
    }

    /// An emulated controller with every channel below `channels` the model has: an SMC100
    /// chain the addresses 1 to `channels` − 1 (one at least), a PI controller the axes 1 to
    /// `channels` − 1 (four at least), a phyMOTION modules of two axes (two modules at least), a
    /// PMAC the motors 1 to `channels` − 1 (one at least, 32 at most), an ESP300 the axes 1 to
    /// `channels` − 1 (one at least, three at most), a Galil DMC-40x0 the axes A… on channels 0
    /// to `channels` − 1 (one at least, eight at most), a chain of McLennan PM304s the addresses 1 to
    /// `channels` − 1 (one at least, eight at most).
    pub fn emulator(self, channels: usize) -> Box<dyn Emulator> {
        let mechanics = stage();
        match self {
            Model::AcsMcb4b => Box::new(Mcb4bEmulator::new(channels, &mechanics)),
            Model::NewportSmc100 => {
                Box::new(Smc100Emulator::new(channels.saturating_sub(1).max(1), &Smc100Emulator::stage()))
            }
            Model::PiGcs2 => Box::new(Gcs2Emulator::new(channels.saturating_sub(1).max(4), &Gcs2Emulator::mechanics())),
            Model::SmaractMcs2 => Box::new(Mcs2Emulator::new(channels, &mcs2_positioner(&mechanics))),
            Model::Phytron => {
                // Each axis reads an encoder of one count a step (I1EM modules).
                let mechanics = zmotor_core::SimConfig { encoder_counts_per_step: Some(1.0), ..mechanics };
                Box::new(PhymotionEmulator::with_channels_below(channels, &mechanics))
            }
            Model::Pmac => Box::new(PmacEmulator::new(channels.saturating_sub(1).clamp(1, 32), &mechanics)),
            Model::NewportEsp300 => {
                Box::new(Esp300Emulator::new(channels.saturating_sub(1), &Esp300Emulator::mechanics()))
            }
            Model::Galil => Box::new(GalilEmulator::new(channels.clamp(1, 8), &mechanics)),
            Model::McLennanPm304 => Box::new(Pm304Emulator::new(channels.saturating_sub(1).clamp(1, 8), &mechanics)),
            Model::NewportXps => Box::new(XpsEmulator::new(channels.saturating_sub(1).clamp(1, 8), &mechanics)),
            Model::ImsMdrive => Box::new(MdriveEmulator::new(channels.saturating_sub(1).clamp(1, 9), &mechanics)),
            Model::OmsMaxnet => Box::new(MaxnetEmulator::new(channels.clamp(1, 10), &mechanics)),
            // Axes 1 to `channels`, for a script's AXIS 0 to `channels` − 1.
            Model::Vmc => Box::new(VmcEmulator::new(channels.clamp(1, 8), &mechanics)),
            Model::KohzuSc => Box::new(KohzuScEmulator::new(channels.clamp(1, 8), &mechanics)),
            Model::MicronixMmc => Box::new(MmcEmulator::new(channels.clamp(1, 99), &mechanics)),
            Model::NewFocus8742 => Box::new(Picomotor8742Emulator::new(channels.clamp(1, 4), &mechanics)),
            Model::AttocubeAmc => Box::new(AmcEmulator::new(channels.clamp(1, 3), &mechanics).with_outputs_on()),
            Model::PiezojenaNv40 => Box::new(Nv40Emulator::new(channels.clamp(1, 3), &mechanics)),
            // Node numbers 1 to `channels` − 1 (one at least).
            Model::FaulhaberMc => Box::new(FaulhaberEmulator::new(channels.saturating_sub(1).max(1), &mechanics)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_model_is_found_by_its_protocol_and_speaks_it() {
        for model in Model::ALL {
            assert_eq!(Model::speaking(model.protocol()), Some(model));
            assert_eq!(model.emulator(model.typical_channels()).name(), model.protocol());
        }
        assert_eq!(Model::speaking("pi"), None, "aliases are the driver's business");
    }
}
