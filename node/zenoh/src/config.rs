//! How a process joins the Zenoh network: the `[zenoh]` section of a launch file and the client
//! settings of the command line, turned into a Zenoh configuration.

use serde::{Deserialize, Serialize};
use zmotor_msgs::{keys, KeyLayout};

/// The Zenoh role of a process.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Mode {
    /// Talks to its peers directly (the default of a node).
    #[default]
    Peer,
    /// Reaches the network through one router or peer.
    Client,
    /// Routes for others (a `zmotor router`).
    Router,
}

impl Mode {
    /// The name Zenoh and launch files use.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Peer => "peer",
            Mode::Client => "client",
            Mode::Router => "router",
        }
    }
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl Serialize for Mode {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

impl<'de> Deserialize<'de> for Mode {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let name = String::deserialize(deserializer)?;
        name.parse().map_err(|e| serde::de::Error::custom(format!("zenoh.mode: {e}")))
    }
}

/// A mode name that is not one of peer, client, router.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("'{0}' is not one of peer, client, router")]
pub struct UnknownMode(pub String);

impl std::str::FromStr for Mode {
    type Err = UnknownMode;

    fn from_str(name: &str) -> Result<Self, UnknownMode> {
        [Mode::Peer, Mode::Client, Mode::Router]
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| UnknownMode(name.to_string()))
    }
}

/// The `[zenoh]` section of a launch file.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ZenohConfig {
    /// peer, client or router.
    pub mode: Mode,
    /// Endpoints to listen on, e.g. `tcp/127.0.0.1:7447`.
    pub listen: Vec<String>,
    /// Endpoints to connect to.
    pub connect: Vec<String>,
    /// Multicast scouting (off: deployments name their endpoints).
    pub multicast_scouting: bool,
    /// Key prefix of the axes.
    pub prefix: String,
}

impl Default for ZenohConfig {
    fn default() -> Self {
        Self {
            mode: Mode::Peer,
            listen: vec!["tcp/127.0.0.1:7447".into()],
            connect: vec![],
            multicast_scouting: false,
            prefix: keys::DEFAULT_PREFIX.into(),
        }
    }
}

impl ZenohConfig {
    /// A client of `endpoint`: listens nowhere, connects there.
    pub fn client(endpoint: &str) -> Self {
        Self { mode: Mode::Client, listen: vec![], connect: vec![endpoint.to_string()], ..Self::default() }
    }

    /// How long this process may be silent before its peers take it for gone: half a second
    /// for a client (a jog it holds ends within a second of its being cut off), a second for a
    /// node or router (a busy one must not be dropped). Zenoh's default is ten seconds.
    pub fn lease(&self) -> std::time::Duration {
        match self.mode {
            Mode::Client => CLIENT_LEASE,
            Mode::Peer | Mode::Router => NODE_LEASE,
        }
    }

    /// The Zenoh configuration.
    pub fn zenoh(&self) -> Result<zenoh::Config, ConfigError> {
        fn json(value: impl Serialize) -> String {
            serde_json::to_string(&value).expect("plain values serialize")
        }
        let mut config = zenoh::Config::default();
        for (key, value) in [
            ("mode", json(self.mode)),
            ("listen/endpoints", json(&self.listen)),
            ("connect/endpoints", json(&self.connect)),
            ("scouting/multicast/enabled", json(self.multicast_scouting)),
            // A node declares a publisher per field it posts again and again; aggregated under
            // the prefix, Zenoh declares its interest once instead of once per publisher (which
            // cost the first moves of 1,000 axes about 20 s).
            ("aggregation/publishers", json([KeyLayout::new(&self.prefix).everything()])),
            // How long this process may be silent before the others take it for gone: what a
            // hold (the jog deadman) relies on to stop a jog whose client is cut off.
            ("transport/link/tx/lease", json(self.lease().as_millis() as u64)),
            // A lost router or node is tried again every second at most (Zenoh: up to 4 s), so
            // monitors and links resume soon after it is back.
            ("connect/retry", r#"{ period_max_ms: 1000 }"#.to_string()),
        ] {
            config.insert_json5(key, &value).map_err(|e| ConfigError { key, message: e.to_string() })?;
        }
        Ok(config)
    }
}

/// The lease of a client session (see `ZenohConfig::lease`).
pub const CLIENT_LEASE: std::time::Duration = std::time::Duration::from_millis(500);

/// The lease of a node's or router's session (see `ZenohConfig::lease`).
pub const NODE_LEASE: std::time::Duration = std::time::Duration::from_millis(1000);

/// A Zenoh configuration entry that Zenoh refused (an endpoint it cannot parse, ...).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("zenoh configuration {key}: {message}")]
pub struct ConfigError {
    /// The configuration key.
    pub key: &'static str,
    /// What Zenoh said.
    pub message: String,
}

/// A TCP endpoint on 127.0.0.1 with a port that is free now, for tests and benchmarks.
pub fn free_local_endpoint() -> std::io::Result<String> {
    let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
    Ok(format!("tcp/127.0.0.1:{port}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_mode_makes_a_configuration_zenoh_takes() {
        for mode in [Mode::Peer, Mode::Client, Mode::Router] {
            let config = ZenohConfig { mode, ..ZenohConfig::default() };
            assert!(config.zenoh().is_ok(), "{mode}");
        }
        assert_eq!(ZenohConfig::client("tcp/127.0.0.1:1").lease(), CLIENT_LEASE);
    }

    #[test]
    fn modes_parse_and_print_by_name() {
        assert_eq!("router".parse::<Mode>(), Ok(Mode::Router));
        assert_eq!("Peer".parse::<Mode>(), Err(UnknownMode("Peer".into())));
        assert_eq!(Mode::Client.to_string(), "client");
    }

    #[test]
    fn a_bad_endpoint_is_named() {
        let config = ZenohConfig { listen: vec!["nonsense".into()], ..ZenohConfig::default() };
        let error = config.zenoh().unwrap_err();
        assert_eq!(error.key, "listen/endpoints");
    }
}
