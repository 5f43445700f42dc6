//! Where the front-ends serve: Channel Access (`[channel_access]`, `zmotor ca`) and the motor
//! screens (`[web]`, `zmotor web`).

use std::net::{IpAddr, SocketAddr};

/// Where and how the Channel Access front-end serves.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CaConfig {
    /// Prepended to every channel name (`<P><axis>.<FIELD>`).
    pub pv_prefix: String,
    /// The address to listen on.
    pub address: IpAddr,
    /// The UDP port searches come to, and the TCP port of circuits (5064 in EPICS).
    pub port: u16,
}

impl Default for CaConfig {
    /// No prefix, on 127.0.0.1 (a lab serves on 0.0.0.0 or an interface's address), port 5064.
    fn default() -> Self {
        Self { pv_prefix: String::new(), address: IpAddr::from([127, 0, 0, 1]), port: 5064 }
    }
}

/// Where the motor screens are served.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WebConfig {
    /// The HTTP address (127.0.0.1:8080 by default: only this host's browsers).
    pub address: SocketAddr,
}

impl Default for WebConfig {
    fn default() -> Self {
        Self { address: SocketAddr::from(([127, 0, 0, 1], 8080)) }
    }
}
