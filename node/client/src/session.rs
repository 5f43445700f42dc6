//! Sessions from a configuration: a launch file's `[zenoh]` section or a client's settings
//! (`zmotor_deploy::ZenohConfig`) become a Zenoh configuration and an open session.

use zmotor_deploy::{ZenohConfig, NODE_LEASE};

/// A Zenoh configuration entry that Zenoh refused (an endpoint it cannot parse, ...).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
#[error("zenoh configuration {key}: {message}")]
pub struct ConfigError {
    /// The configuration key.
    pub key: &'static str,
    /// What Zenoh said.
    pub message: String,
}

/// Why a session could not be opened.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SessionError {
    /// The configuration is not one Zenoh takes.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Nothing answered where the configuration connects (or it refused this process's
    /// certificate or login).
    #[error("nothing answers at {endpoints}{}", if *.tls { ", or it refused this client's certificate" } else { "" })]
    Unreachable {
        /// Where it tried, comma-separated.
        endpoints: String,
        /// Whether the connection was under TLS (a refused certificate looks the same).
        tls: bool,
        /// What Zenoh said.
        #[source]
        source: zenoh::Error,
    },
    /// A node's or router's session could not be opened where it listens (a port in use, an
    /// endpoint it cannot bind).
    #[error("cannot listen on {listen}: {}", zenoh_words(&source.to_string()))]
    CannotListen {
        /// Where it listens, comma-separated.
        listen: String,
        /// What Zenoh said.
        source: zenoh::Error,
    },
}

/// The Zenoh configuration of `section`.
pub fn zenoh_config(section: &ZenohConfig) -> Result<zenoh::Config, ConfigError> {
    let mut config = zenoh::Config::default();
    for (key, value) in section.entries() {
        config.insert_json5(key, &value).map_err(|e| ConfigError { key, message: zenoh_words(&e.to_string()) })?;
    }
    Ok(config)
}

/// What Zenoh said, in its words only: without the JSON5 parser's wrapping (`Json5Err(Message
/// { msg: "..", .. })`) or where in Zenoh's sources it was said (` at <file>.rs:<line>.`).
fn zenoh_words(said: &str) -> String {
    let inner = match said.split_once("msg: \"") {
        Some((_, rest)) => rest.split_once("\", location").map_or(rest, |(message, _)| message),
        None => said,
    };
    let mut words = inner.trim_end().trim_end_matches('.');
    // " at zenoh-protocol-1.10.2/src/core/endpoint.rs:615": a file, a colon, a line number.
    while let Some((before, place)) = words.rsplit_once(" at ") {
        let at_a_line = place.rsplit_once(".rs:").is_some_and(|(_, line)| line.chars().all(|c| c.is_ascii_digit()));
        if !at_a_line {
            break;
        }
        words = before.trim_end_matches('.');
    }
    words.to_string()
}

/// A session joined as `section` says.
pub async fn open(section: &ZenohConfig) -> Result<zenoh::Session, SessionError> {
    zenoh::open(zenoh_config(section)?).await.map_err(|source| SessionError::Unreachable {
        endpoints: section.connect.join(", "),
        tls: section.tls.is_some(),
        source,
    })
}

/// A node's or router's session, joined as `section` says: it keeps trying to connect (it may
/// start before the routers or peers it connects to, and serves from the first connection),
/// and has a node's lease whatever its mode (a busy node must not be taken for gone).
pub async fn open_waiting(section: &ZenohConfig) -> Result<zenoh::Session, SessionError> {
    let mut config = zenoh_config(section)?;
    let lease = NODE_LEASE.as_millis().to_string();
    for (key, value) in [("connect/timeout_ms", "-1"), ("transport/link/tx/lease", lease.as_str())] {
        config.insert_json5(key, value).map_err(|e| ConfigError { key, message: zenoh_words(&e.to_string()) })?;
    }
    // It waits for what it connects to: what fails at once is what it listens on.
    zenoh::open(config).await.map_err(|source| SessionError::CannotListen { listen: section.listen.join(", "), source })
}

/// A TCP endpoint on 127.0.0.1 with a port that is free now, for tests and benchmarks.
///
/// The port is taken below the kernel's ephemeral range: a port the kernel hands out (port 0)
/// may be given again to any outgoing connection between this probe and the listener's bind,
/// and a test suite opens many such connections.
pub fn free_local_endpoint() -> std::io::Result<String> {
    let port = free_local_port()?;
    Ok(format!("tcp/127.0.0.1:{port}"))
}

/// The first free port of 127.0.0.1 from a starting point this process has not used,
/// among the ports no outgoing connection takes; the kernel's choice where that range is unknown.
fn free_local_port() -> std::io::Result<u16> {
    use std::hash::{BuildHasher, RandomState};
    use std::sync::atomic::{AtomicU16, Ordering};
    const LOWEST: u16 = 10_000;
    static NEXT: AtomicU16 = AtomicU16::new(0);
    let Some(ephemeral) = first_ephemeral_port().filter(|first| *first > LOWEST + 1_000) else {
        return Ok(std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port());
    };
    let span = ephemeral - LOWEST;
    // Each process starts somewhere else (tests of several binaries may run at once), then walks on.
    let start = (RandomState::new().hash_one(std::process::id()) % u64::from(span)) as u16;
    let _ = NEXT.compare_exchange(0, start.max(1), Ordering::Relaxed, Ordering::Relaxed);
    for _ in 0..span {
        let port = LOWEST + NEXT.fetch_add(1, Ordering::Relaxed) % span;
        if std::net::TcpListener::bind(("127.0.0.1", port)).is_ok() {
            return Ok(port);
        }
    }
    Err(std::io::Error::new(std::io::ErrorKind::AddrInUse, "no free port on 127.0.0.1"))
}

/// The lowest port Linux gives outgoing connections, where it says.
fn first_ephemeral_port() -> Option<u16> {
    let range = std::fs::read_to_string("/proc/sys/net/ipv4/ip_local_port_range").ok()?;
    range.split_whitespace().next()?.parse().ok()
}

/// Until SIGINT (Ctrl-C) or SIGTERM: what stops a process of zmotor's (a node, a gateway, a
/// client that holds a jog, the benchmark). The signals are caught from this call on, before the
/// future is first polled: one that comes while the process starts what it will stop is not
/// lost (nor does it kill the process, leaving what it started behind).
pub fn interrupted() -> impl std::future::Future<Output = std::io::Result<()>> + Send {
    use tokio::signal::unix::{signal, SignalKind};
    let signals =
        signal(SignalKind::terminate()).and_then(|terminate| Ok((terminate, signal(SignalKind::interrupt())?)));
    async move {
        let (mut terminate, mut interrupt) = signals?;
        tokio::select! {
            _ = terminate.recv() => {}
            _ = interrupt.recv() => {}
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use zmotor_deploy::Mode;
    use zmotor_msgs::{Field, KeyLayout};

    #[test]
    fn a_free_local_endpoint_is_bindable_below_the_ports_outgoing_connections_take() {
        let ports: Vec<u16> = (0..3)
            .map(|_| free_local_endpoint().unwrap().strip_prefix("tcp/127.0.0.1:").unwrap().parse().unwrap())
            .collect();
        assert!(ports[0] != ports[1] && ports[1] != ports[2], "{ports:?}");
        for port in ports {
            if let Some(ephemeral) = first_ephemeral_port() {
                assert!(port < ephemeral, "{port} is in the ephemeral range from {ephemeral}");
            }
            std::net::TcpListener::bind(("127.0.0.1", port)).unwrap();
        }
    }

    #[test]
    fn a_quic_endpoint_on_one_stream_is_one_zenoh_takes() {
        let section = ZenohConfig { listen: vec!["quic/127.0.0.1:7447".into()], ..ZenohConfig::default() };
        let zenoh = zenoh_config(&section).unwrap();
        assert_eq!(zenoh.get_json("listen/endpoints").unwrap(), r#"["quic/127.0.0.1:7447?multistream=0"]"#);
    }

    #[test]
    fn a_malformed_endpoint_is_refused_in_zenoh_s_words_only() {
        let section = ZenohConfig { connect: vec!["nonsense".into()], ..ZenohConfig::default() };
        let error = zenoh_config(&section).unwrap_err();
        assert_eq!(error.key, "connect/endpoints");
        assert_eq!(
            error.to_string(),
            "zenoh configuration connect/endpoints: Endpoints must be of the form \
             <protocol>/<address>[?<metadata>][#<config>]: nonsense"
        );
    }

    #[test]
    fn every_mode_makes_a_configuration_zenoh_takes() {
        for mode in [Mode::Peer, Mode::Client, Mode::Router] {
            let config = ZenohConfig { mode, ..ZenohConfig::default() };
            assert!(zenoh_config(&config).is_ok(), "{mode}");
        }
    }

    #[test]
    fn tls_login_and_access_rules_of_a_launch_file_make_a_configuration_zenoh_takes() {
        let launch = zmotor_deploy::Launch::parse(
            r#"
            [zenoh]
            listen = ["tls/127.0.0.1:7447"]
            [zenoh.tls]
            ca = "ca.pem"
            certificate = "node.pem"
            key = "node.key"
            mutual = true
            [zenoh.login]
            user = "node"
            password = "pw"
            [[zenoh.access]]
            name = "viewer"
            may = ["read"]
            cert_common_names = ["viewer"]
            "#,
        )
        .unwrap();
        let zenoh = zenoh_config(&launch.deployment(None).unwrap().zenoh).unwrap();
        assert_eq!(zenoh.get_json("transport/link/tls/enable_mtls").unwrap(), "true");
        assert_eq!(zenoh.get_json("transport/link/tls/connect_certificate").unwrap(), r#""node.pem""#);
        assert_eq!(zenoh.get_json("access_control/default_permission").unwrap(), r#""deny""#);
    }

    #[test]
    fn a_reader_may_query_every_field_key_but_no_write_key() {
        // The access rules rely on this: `**` does not cover a chunk that starts with `@`.
        let all = zenoh::key_expr::KeyExpr::try_from("**").unwrap();
        let layout = KeyLayout::default();
        assert!(all.includes(&zenoh::key_expr::KeyExpr::try_from(layout.field("m1", Field::VAL)).unwrap()));
        for key in [layout.write("m1", Field::VAL), layout.hold("m1", "c"), layout.driver_cmd("m1")] {
            assert!(!all.includes(&zenoh::key_expr::KeyExpr::try_from(key.clone()).unwrap()), "{key}");
        }
    }

    #[test]
    fn a_bad_endpoint_is_named() {
        let config = ZenohConfig { listen: vec!["nonsense".into()], ..ZenohConfig::default() };
        assert_eq!(zenoh_config(&config).unwrap_err().key, "listen/endpoints");
    }
}
