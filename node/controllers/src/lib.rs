//! zmotor-controllers: real motor controllers, sans-IO. `Controller` is the controller layer
//! (one connection, a priority queue, polls, the link and its loss) over a `Protocol`, what a
//! vendor's protocol provides; `ProtocolKind` names the vendors' protocols and makes their
//! controllers (`AnyController`); `ControllerSpec` is a controller as a deployment describes it.
//! A runner (zmotor-node) moves the bytes.
//!
//! Everything a caller uses is named here, at the root; the modules are the crate's own. The
//! feature `testing` adds `Loopback`, the test bench of every protocol: a controller wired to a
//! witness of zmotor-emulators, which owes nothing to the drivers here.

mod acs;
mod controller;
mod galil;
mod ims_mdrive;
mod keys;
#[cfg(feature = "testing")]
mod loopback;
mod mclennan_pm304;
mod newport;
mod newport_esp300;
mod newport_xps;
mod oms_maxnet;
mod phytron;
mod pi_gcs2;
mod pmac;
mod protocol;
mod scale;
mod script;
mod script_source;
mod smaract_mcs2;
mod spec;

pub use controller::{AnyController, Controller, ControllerConfig, ControllerEvent, Refusal};
pub use keys::{KeyAccess, KeyName, KeyNameError, KeyReply, KeyValue};
#[cfg(feature = "testing")]
pub use loopback::Loopback;
pub use protocol::{
    line_frame, CommandError, Finding, Frame, Lane, Prepared, Protocol, ProtocolOptions, Purpose, ReloadError,
    ReplyError, ReplyEvent, Request, VendorError,
};
pub use scale::{ControllerUnit, RecordUnits, Scale, ScaleCheck, ScaleMismatch, ScaleSource};
pub use script::ScriptSettings;
pub use script_source::{MacroValue, ScriptError, ScriptSource};
pub use spec::{ControllerSpec, FlowControl, Parity, SerialSettings, SpecError, Transport};
use zmotor_core::Instant;

/// The protocols zmotor speaks, by the names launch files give them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ProtocolKind {
    /// ACS MCB-4B.
    AcsMcb4b,
    /// Newport SMC100 (CC/PP) chain, or CONEX-CC.
    NewportSmc100,
    /// PI GCS 2 (C-863 Mercury, C-884 and their class).
    PiGcs2,
    /// SmarAct MCS2 (linear positioners with a sensor, over TCP).
    SmaractMcs2,
    /// Phytron phyMOTION (channel = module × 10 + axis).
    Phytron,
    /// Delta Tau Turbo PMAC2 and Geo Brick, over Ethernet (channel = motor number).
    Pmac,
    /// Newport ESP300 / ESP301 (channel = axis, 1 to 3).
    NewportEsp300,
    /// Galil DMC-40x0, DMC-41x3, DMC-30010 (channel = axis, 0 to 7 for A to H).
    Galil,
    /// McLennan PM304 (channel = the axis's address, 1 to 8).
    McLennanPm304,
    /// Newport XPS (channel = n for the group GROUPn, 1 to 8).
    NewportXps,
    /// IMS MDrive Plus in party mode (channel = the motor's name, 1 to 9).
    ImsMdrive,
    /// Oregon Micro Systems MAXnet (channel = the axis, 0 to 9 for X, Y, Z, T, U, V, R, S, W, K).
    OmsMaxnet,
    /// A motorScriptMotor Lua script (channel = the script's `AXIS`, from 0).
    Script,
}

impl ProtocolKind {
    /// Every protocol.
    pub const ALL: [ProtocolKind; 13] = [
        ProtocolKind::AcsMcb4b,
        ProtocolKind::NewportSmc100,
        ProtocolKind::PiGcs2,
        ProtocolKind::SmaractMcs2,
        ProtocolKind::Phytron,
        ProtocolKind::Pmac,
        ProtocolKind::NewportEsp300,
        ProtocolKind::Galil,
        ProtocolKind::McLennanPm304,
        ProtocolKind::NewportXps,
        ProtocolKind::ImsMdrive,
        ProtocolKind::OmsMaxnet,
        ProtocolKind::Script,
    ];

    /// Its name in launch files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ProtocolKind::AcsMcb4b => acs::NAME,
            ProtocolKind::NewportSmc100 => newport::NAME,
            ProtocolKind::PiGcs2 => pi_gcs2::NAME,
            ProtocolKind::SmaractMcs2 => smaract_mcs2::NAME,
            ProtocolKind::Phytron => phytron::NAME,
            ProtocolKind::Pmac => pmac::NAME,
            ProtocolKind::NewportEsp300 => newport_esp300::NAME,
            ProtocolKind::Galil => galil::NAME,
            ProtocolKind::McLennanPm304 => mclennan_pm304::NAME,
            ProtocolKind::NewportXps => newport_xps::NAME,
            ProtocolKind::ImsMdrive => ims_mdrive::NAME,
            ProtocolKind::OmsMaxnet => oms_maxnet::NAME,
            ProtocolKind::Script => script::NAME,
        }
    }

    /// Other names people call it by (the controller, the maker, the EPICS module).
    pub fn aliases(self) -> &'static [&'static str] {
        match self {
            ProtocolKind::AcsMcb4b => &["mcb4b", "mcb-4b", "acs", "motoracs"],
            ProtocolKind::NewportSmc100 => &["smc100", "smc100cc", "conex", "conex_cc", "conex-cc"],
            ProtocolKind::PiGcs2 => &["gcs2", "pigcs2", "pi", "motorpigcs2"],
            ProtocolKind::SmaractMcs2 => &["mcs2", "smaract", "motorsmaract"],
            ProtocolKind::Phytron => &["phymotion", "motorphytron"],
            ProtocolKind::Pmac => &["turbo_pmac", "pmac2", "geobrick", "geo_brick", "delta_tau", "motorpmac"],
            ProtocolKind::NewportEsp300 => &["esp300", "esp301", "esp", "mm4000"],
            ProtocolKind::Galil => &["dmc", "dmc4040", "dmc4143", "dmc30010", "motorgalil"],
            ProtocolKind::McLennanPm304 => &["pm304", "mclennan", "motormclennan"],
            ProtocolKind::NewportXps => &["xps", "xps_c8", "xps_q8", "xps_d", "xpsc8"],
            ProtocolKind::ImsMdrive => &["mdrive", "mdrive_plus", "ims", "motorims"],
            ProtocolKind::OmsMaxnet => &["maxnet", "oms", "motoromsasyn"],
            ProtocolKind::Script => &["lua", "script_motor", "scriptmotor", "motorscriptmotor"],
        }
    }

    /// The protocol named `name` or one of its aliases, in any case.
    pub fn from_name(name: &str) -> Option<ProtocolKind> {
        let named = |p: &ProtocolKind| {
            p.name().eq_ignore_ascii_case(name) || p.aliases().iter().any(|a| a.eq_ignore_ascii_case(name))
        };
        ProtocolKind::ALL.into_iter().find(named)
    }

    /// Every protocol's name, for messages.
    pub fn known() -> String {
        ProtocolKind::ALL.map(ProtocolKind::name).join(", ")
    }

    /// Whether `channel` numbers an axis of this protocol's controllers.
    pub fn check_channel(self, channel: usize) -> Result<(), SpecError> {
        let (valid, allowed) = match self {
            ProtocolKind::AcsMcb4b => (channel <= 3, "0 to 3"),
            ProtocolKind::NewportSmc100 => ((1..=31).contains(&channel), "by their address, 1 to 31"),
            ProtocolKind::PiGcs2 => ((1..=16).contains(&channel), "by their axis name, 1 to 16"),
            ProtocolKind::SmaractMcs2 => (channel <= 26, "0 to 26"),
            ProtocolKind::Phytron => {
                ((11..=99).contains(&channel) && !channel.is_multiple_of(10), "module × 10 + axis, each 1 to 9")
            }
            ProtocolKind::Pmac => ((1..=32).contains(&channel), "by their motor number, 1 to 32"),
            ProtocolKind::NewportEsp300 => ((1..=3).contains(&channel), "by their axis number, 1 to 3"),
            ProtocolKind::Galil => (channel <= 7, "0 to 7, for the axes A to H"),
            ProtocolKind::McLennanPm304 => ((1..=8).contains(&channel), "by their address, 1 to 8"),
            ProtocolKind::NewportXps => ((1..=8).contains(&channel), "by their group, 1 to 8 for GROUP1 to GROUP8"),
            ProtocolKind::ImsMdrive => ((1..=9).contains(&channel), "by their name, the motors named 1 to 9"),
            ProtocolKind::OmsMaxnet => (channel <= 9, "0 to 9, for the axes X, Y, Z, T, U, V, R, S, W, K"),
            ProtocolKind::Script => (channel <= 63, "0 to 63, the script's AXIS"),
        };
        if valid {
            Ok(())
        } else {
            Err(SpecError::Channel { channel, protocol: self.name(), allowed })
        }
    }

    /// Whether its controllers are reached over several connections at once (motion lanes):
    /// over TCP only.
    pub fn opens_several_connections(self) -> bool {
        /// Asks the protocol.
        struct MotionLanes;
        impl WithProtocol for MotionLanes {
            type Output = bool;
            fn with<P: Protocol + 'static>(self, protocol: P) -> bool {
                protocol.motion_lanes()
            }
        }
        self.with_protocol(&ProtocolOptions::default(), MotionLanes)
    }

    /// A controller speaking the protocol, not connected yet (see `Controller::new`).
    pub fn controller(
        self,
        options: &ProtocolOptions,
        config: ControllerConfig,
        now: Instant,
    ) -> Box<dyn AnyController> {
        /// Builds the controller around whichever protocol it is given.
        struct Build {
            config: ControllerConfig,
            now: Instant,
        }
        impl WithProtocol for Build {
            type Output = Box<dyn AnyController>;
            fn with<P: Protocol + 'static>(self, protocol: P) -> Self::Output {
                Box::new(Controller::new(protocol, self.config, self.now))
            }
        }
        self.with_protocol(options, Build { config, now })
    }

    /// `user` run on the driver side of the protocol: code generic over `Protocol` (which has
    /// a type of its own per vendor) on a protocol chosen at run time.
    pub fn with_protocol<U: WithProtocol>(self, options: &ProtocolOptions, user: U) -> U::Output {
        match self {
            ProtocolKind::AcsMcb4b => user.with(acs::Mcb4b::new()),
            ProtocolKind::NewportSmc100 => user.with(newport::Smc100::new(options.units_per_step)),
            ProtocolKind::PiGcs2 => user.with(pi_gcs2::PiGcs2::new(options)),
            ProtocolKind::SmaractMcs2 => user.with(smaract_mcs2::Mcs2::new(options)),
            ProtocolKind::Phytron => user.with(phytron::Phymotion::new(options)),
            ProtocolKind::Pmac => user.with(pmac::Pmac::new(options)),
            ProtocolKind::NewportEsp300 => user.with(newport_esp300::Esp300::new(options)),
            ProtocolKind::Galil => user.with(galil::Galil::new(options)),
            ProtocolKind::McLennanPm304 => user.with(mclennan_pm304::Pm304::new()),
            ProtocolKind::NewportXps => user.with(newport_xps::Xps::new(options)),
            ProtocolKind::ImsMdrive => user.with(ims_mdrive::Mdrive::new()),
            ProtocolKind::OmsMaxnet => user.with(oms_maxnet::Maxnet::new()),
            ProtocolKind::Script => user.with(script::Script::new(options)),
        }
    }
}

/// Code generic over the protocol, run by `ProtocolKind::with_protocol` on the protocol of a
/// kind chosen at run time.
pub trait WithProtocol {
    /// What it gives back.
    type Output;

    /// Run on `protocol`.
    fn with<P: Protocol + 'static>(self, protocol: P) -> Self::Output;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn protocols_are_found_by_name_and_alias_in_any_case_and_aliases_are_unique() {
        assert_eq!(ProtocolKind::from_name("acs_mcb4b"), Some(ProtocolKind::AcsMcb4b));
        assert_eq!(ProtocolKind::from_name("SMC100"), Some(ProtocolKind::NewportSmc100));
        assert_eq!(ProtocolKind::from_name("phyMOTION"), Some(ProtocolKind::Phytron));
        assert_eq!(ProtocolKind::from_name("acs_mcb"), None);
        let mut names: Vec<&str> = ProtocolKind::ALL
            .iter()
            .flat_map(|p| std::iter::once(p.name()).chain(p.aliases().iter().copied()))
            .collect();
        let all = names.len();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), all, "a name names one protocol");
    }
}
