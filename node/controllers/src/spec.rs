//! A controller as a deployment describes it: its protocol, how to reach it, how to poll it.
//! Plain data, checked here so that launch files and the runner agree on what is valid.

use crate::controller::ControllerConfig;
use crate::protocol::ProtocolOptions;
use crate::ProtocolKind;
use std::time::Duration;

/// One controller of a deployment.
#[derive(Clone, Debug, PartialEq)]
pub struct ControllerSpec {
    /// Its name in the deployment (axes name it).
    pub name: String,
    /// The protocol it speaks.
    pub protocol: ProtocolKind,
    /// What the protocol needs to know of the installation.
    pub options: ProtocolOptions,
    /// How it is reached.
    pub transport: Transport,
    /// How it is driven; `config.channels` are its axes' channels.
    pub config: ControllerConfig,
}

/// How a controller is reached.
#[derive(Clone, Debug, PartialEq)]
pub enum Transport {
    /// A TCP socket (an Ethernet controller, or a terminal server in front of a serial one).
    Tcp {
        /// `host:port`.
        address: String,
    },
    /// A serial port.
    Serial(SerialSettings),
    /// No connection: a script that reads and writes only the node's keys (motorScriptMotor's
    /// `softMotor.lua`). What it writes to a controller reaches none, and goes unanswered.
    None,
}

impl std::fmt::Display for Transport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Transport::Tcp { address } => write!(f, "tcp {address}"),
            Transport::Serial(s) => write!(f, "serial {} {}", s.device, s.baud),
            Transport::None => write!(f, "no connection"),
        }
    }
}

/// A serial line's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct SerialSettings {
    /// The device, e.g. `/dev/ttyUSB0`.
    pub device: String,
    /// Bits per second.
    pub baud: u32,
    /// Parity.
    pub parity: Parity,
    /// Data bits, 5 to 8.
    pub data_bits: u8,
    /// Stop bits, 1 or 2.
    pub stop_bits: u8,
    /// Flow control.
    pub flow_control: FlowControl,
}

impl SerialSettings {
    /// 8 data bits, no parity, 1 stop bit, no flow control, at `baud`.
    pub fn eight_n_one(device: &str, baud: u32) -> Self {
        Self {
            device: device.to_string(),
            baud,
            parity: Parity::None,
            data_bits: 8,
            stop_bits: 1,
            flow_control: FlowControl::None,
        }
    }
}

/// A serial line's parity.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Parity {
    /// No parity bit.
    None,
    /// Odd parity.
    Odd,
    /// Even parity.
    Even,
}

/// A serial line's flow control.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlowControl {
    /// None.
    None,
    /// XON/XOFF.
    Software,
    /// RTS/CTS.
    Hardware,
}

/// A controller setting that cannot be used.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SpecError {
    /// A period or timeout outside what makes sense.
    #[error("{seconds} s is outside [{min}, {max}] s")]
    Period {
        /// Which setting.
        what: &'static str,
        /// The value given.
        seconds: f64,
        /// Smallest allowed.
        min: f64,
        /// Largest allowed.
        max: f64,
    },
    /// A serial setting the line cannot have.
    #[error("{what}: {value} is not one of {allowed}")]
    Serial {
        /// Which setting.
        what: &'static str,
        /// The value given.
        value: u32,
        /// What is allowed.
        allowed: &'static str,
    },
    /// units_per_step that is not a positive number.
    #[error("units_per_step: {0} is not a positive number")]
    UnitsPerStep(f64),
    /// units_per_step given to a protocol that counts motor steps only.
    #[error("units_per_step: {0} counts motor steps, one per record step; it has no units to scale")]
    NoUnits(&'static str),
    /// Axis names given to a protocol whose controllers do not name their axes.
    #[error("axis_names: {0} numbers its axes; it has no names for them")]
    NoNames(&'static str),
    /// An axis name the controller could not have.
    #[error("axis_names: channel {channel}: {name:?} is not a name of the form GROUP.POSITIONER (letters, digits, _)")]
    Name {
        /// The channel named.
        channel: usize,
        /// The name given.
        name: String,
    },
    /// A channel the protocol has no such number for.
    #[error("channel {channel}: {protocol} numbers its axes {allowed}")]
    Channel {
        /// The channel given.
        channel: usize,
        /// The protocol.
        protocol: &'static str,
        /// How the protocol numbers them.
        allowed: &'static str,
    },
}

impl ControllerConfig {
    /// A period or timeout of `what` in seconds, checked against its bounds.
    pub fn checked_period(what: &'static str, seconds: f64, min: f64, max: f64) -> Result<Duration, SpecError> {
        if seconds.is_finite() && (min..=max).contains(&seconds) {
            Ok(Duration::from_secs_f64(seconds))
        } else {
            Err(SpecError::Period { what, seconds, min, max })
        }
    }
}

impl SerialSettings {
    /// Whether a serial port can be opened with these settings.
    pub fn check(&self) -> Result<(), SpecError> {
        if self.baud == 0 {
            return Err(SpecError::Serial { what: "baud", value: 0, allowed: "positive rates" });
        }
        if !(5..=8).contains(&self.data_bits) {
            return Err(SpecError::Serial { what: "data_bits", value: self.data_bits.into(), allowed: "5, 6, 7, 8" });
        }
        if !(1..=2).contains(&self.stop_bits) {
            return Err(SpecError::Serial { what: "stop_bits", value: self.stop_bits.into(), allowed: "1, 2" });
        }
        Ok(())
    }
}

impl ProtocolOptions {
    /// Whether the options can be used with `protocol`.
    pub fn check(&self, protocol: ProtocolKind) -> Result<(), SpecError> {
        if !self.names.is_empty() && protocol != ProtocolKind::NewportXps {
            return Err(SpecError::NoNames(protocol.name()));
        }
        for (&channel, name) in &self.names {
            protocol.check_channel(channel)?;
            let word = |part: &str| !part.is_empty() && part.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
            if !name.split_once('.').is_some_and(|(group, positioner)| word(group) && word(positioner)) {
                return Err(SpecError::Name { channel, name: name.clone() });
            }
        }
        match self.units_per_step {
            Some(units) if !(units.is_finite() && units > 0.0) => Err(SpecError::UnitsPerStep(units)),
            Some(_)
                if matches!(
                    protocol,
                    ProtocolKind::AcsMcb4b
                        | ProtocolKind::McLennanPm304
                        | ProtocolKind::ImsMdrive
                        | ProtocolKind::OmsMaxnet
                ) =>
            {
                Err(SpecError::NoUnits(protocol.name()))
            }
            _ => Ok(()),
        }
    }
}
