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
#[non_exhaustive]
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
    /// TLS for `tls/...` and `quic/...` endpoints (`[zenoh.tls]`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tls: Option<TlsConfig>,
    /// User/password authentication (`[zenoh.login]`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub login: Option<LoginConfig>,
    /// Who may do what (`[[zenoh.access]]`); with none, whoever reaches the process may do
    /// anything.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub access: Vec<AccessRule>,
    /// A client that holds no motion (a command line's get, put, list or monitor): it announces
    /// Zenoh's own lease (`COMMAND_LEASE`), not a client's half second, which only a hold needs
    /// (a starved command line then lost its link and reported its write's outcome unknown).
    #[serde(skip)]
    pub holds_nothing: bool,
}

/// TLS on `tls/...` and `quic/...` endpoints: the authority this process trusts and the certificate it shows.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TlsConfig {
    /// PEM file of the certificate authority that signed the others' certificates.
    pub ca: String,
    /// PEM file of this process's certificate (required to listen, and to connect under mutual
    /// TLS).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub certificate: Option<String>,
    /// PEM file of its private key.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub key: Option<String>,
    /// Mutual TLS: whoever connects here must show a certificate the authority signed (its
    /// common name is then a subject of the access rules).
    #[serde(default)]
    pub mutual: bool,
}

/// User/password authentication: the name this process gives when it connects, and the users
/// it accepts from those who connect to it.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LoginConfig {
    /// The user this process connects as.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub user: Option<String>,
    /// Its password.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub password: Option<String>,
    /// A file of `user:password` lines: whoever connects here must be one of them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub users_file: Option<String>,
}

/// What a group of clients may do, and how Zenoh recognises them.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AccessRule {
    /// A name for the group (it names the rule in Zenoh's access control).
    pub name: String,
    /// What its members may do.
    pub may: Vec<Permission>,
    /// Members by the common name of their TLS certificate (mutual TLS).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cert_common_names: Vec<String>,
    /// Members by user name (`[zenoh.login]`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub usernames: Vec<String>,
    /// Members by the network interface they arrive on (e.g. `lo`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub interfaces: Vec<String>,
}

/// A permission of an access rule.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Permission {
    /// Subscribe, read (`get`) and see the axes' liveliness.
    Read,
    /// Read, and write the fields that move or stop an axis (`WriteClass::Drive`), holding
    /// what they start.
    Drive,
    /// Read, and write every other writable field (limits, resolution, speeds, offsets, SET,
    /// links) and the simulator's settings.
    Configure,
    /// Everything, on every key: for other nodes and routers.
    All,
}

impl Default for ZenohConfig {
    fn default() -> Self {
        Self {
            mode: Mode::Peer,
            listen: vec!["tcp/127.0.0.1:7447".into()],
            connect: vec![],
            multicast_scouting: false,
            prefix: keys::DEFAULT_PREFIX.into(),
            tls: None,
            login: None,
            access: Vec::new(),
            holds_nothing: false,
        }
    }
}

impl ZenohConfig {
    /// A client of `endpoint`: listens nowhere, connects there.
    pub fn client(endpoint: &str) -> Self {
        Self { mode: Mode::Client, listen: vec![], connect: vec![endpoint.to_string()], ..Self::default() }
    }

    /// How long this process may be silent before its peers take it for gone: half a second
    /// for a client (a jog it holds ends within a second of its being cut off), Zenoh's ten
    /// seconds for one that holds nothing, a second for a node or router (a busy one must not be
    /// dropped).
    pub fn lease(&self) -> std::time::Duration {
        match self.mode {
            Mode::Client if self.holds_nothing => COMMAND_LEASE,
            Mode::Client => CLIENT_LEASE,
            Mode::Peer | Mode::Router => NODE_LEASE,
        }
    }

    /// The Zenoh configuration as (key, JSON5 value) entries, in the order they are applied to
    /// Zenoh's defaults (`zmotor_client::zenoh_config` applies them).
    pub fn entries(&self) -> Vec<(&'static str, String)> {
        fn json(value: impl Serialize) -> String {
            serde_json::to_string(&value).expect("plain values serialize")
        }
        let mut entries = vec![
            ("mode", json(self.mode)),
            ("listen/endpoints", json(zenoh_endpoints(&self.listen))),
            ("connect/endpoints", json(zenoh_endpoints(&self.connect))),
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
            // A batch goes out as soon as the link can take it, not up to 1 ms later (Zenoh's
            // default while samples keep coming): 16 axes read back at 1 kHz arrived in pairs,
            // p99 jitter 1.9 ms; now 1.1 ms (BENCHMARKS, part 12).
            ("transport/link/tx/queue/batching/time_limit", "0".to_string()),
        ];

        if let Some(tls) = &self.tls {
            entries.push(("transport/link/tls", json(tls.zenoh())));
        }
        if let Some(login) = &self.login {
            let usrpwd = serde_json::json!({
                "user": login.user, "password": login.password, "dictionary_file": login.users_file,
            });
            entries.push(("transport/auth/usrpwd", usrpwd.to_string()));
        }
        if !self.access.is_empty() {
            entries.push(("access_control", access_control(&KeyLayout::new(&self.prefix), &self.access).to_string()));
        }
        entries
    }

    /// Whether access rules guard this process (confirmed writes then go to write keys only).
    pub fn guarded(&self) -> bool {
        !self.access.is_empty()
    }
}

/// The endpoints as Zenoh is given them: a `quic/...` endpoint that does not choose carries
/// `multistream=0`, one QUIC stream per link. Zenoh 1.10's stream per priority lost the first
/// queries of a fresh client now and then (a `get` or confirmed write through a router that
/// nothing answered: 3 of 20 runs of the multi-host test, none of 50 on one stream).
fn zenoh_endpoints(endpoints: &[String]) -> Vec<String> {
    endpoints
        .iter()
        .map(|endpoint| {
            if !endpoint.starts_with("quic/") {
                return endpoint.clone();
            }
            let (locator, config) = endpoint.split_once('#').map_or((endpoint.as_str(), None), |(l, c)| (l, Some(c)));
            let (address, metadata) = locator.split_once('?').unwrap_or((locator, ""));
            if metadata.split(';').any(|entry| entry.split('=').next() == Some("multistream")) {
                return endpoint.clone();
            }
            let metadata =
                if metadata.is_empty() { "multistream=0".to_string() } else { format!("{metadata};multistream=0") };
            let config = config.map(|c| format!("#{c}")).unwrap_or_default();
            format!("{address}?{metadata}{config}")
        })
        .collect()
}

impl TlsConfig {
    fn zenoh(&self) -> serde_json::Value {
        serde_json::json!({
            "root_ca_certificate": self.ca,
            "listen_certificate": self.certificate,
            "listen_private_key": self.key,
            // Under mutual TLS this process shows its certificate when it connects, too.
            "connect_certificate": self.certificate.as_ref().filter(|_| self.mutual),
            "connect_private_key": self.key.as_ref().filter(|_| self.mutual),
            "enable_mtls": self.mutual,
            "verify_name_on_connect": true,
        })
    }
}

/// Zenoh's access control for a launch file's rules. Nothing is allowed but what a rule
/// allows: a member of any rule sees everything that flows to it (publications, replies,
/// declarations); what it may send depends on its permissions. Zenoh's rules tell a put from
/// a query, but not a read from a confirmed write (both are queries): so confirmed writes go
/// to write keys (`<prefix>/<axis>/@write/<FIELD>`), which `**` does not cover, and a guarded
/// node refuses a confirmed write anywhere else.
fn access_control(layout: &KeyLayout, rules: &[AccessRule]) -> serde_json::Value {
    use zmotor_msgs::{Field, WriteClass};
    const EVERY_MESSAGE: [&str; 9] = [
        "put",
        "delete",
        "declare_subscriber",
        "query",
        "declare_queryable",
        "reply",
        "liveliness_token",
        "declare_liveliness_subscriber",
        "liveliness_query",
    ];
    let every_key = serde_json::json!([
        "**",
        layout.every_write(),
        layout.every_hold(),
        layout.driver_cmd("*"),
        layout.every_controller_reload()
    ]);
    let writable = |class: WriteClass| -> Vec<String> {
        Field::all()
            .filter(|f| f.write_class() == Some(class))
            .flat_map(|f| [layout.field_of_every_axis(f), layout.writes_of(f)])
            .collect()
    };
    let mut configure = writable(WriteClass::Configure);
    configure.push(keys::sim_key("*", "*"));
    configure.push(layout.every_controller_reload());
    let rule = |id: &str, flow: &str, messages: &[&str], key_exprs: serde_json::Value| serde_json::json!({ "id": id, "permission": "allow", "flows": [flow], "messages": messages, "key_exprs": key_exprs });
    let zenoh_rules = [
        rule("see", "egress", &EVERY_MESSAGE, every_key.clone()),
        rule(
            "read",
            "ingress",
            &["declare_subscriber", "query", "declare_liveliness_subscriber", "liveliness_query"],
            serde_json::json!(["**"]),
        ),
        rule("drive", "ingress", &["put", "query"], serde_json::json!(writable(WriteClass::Drive))),
        rule("hold", "ingress", &["liveliness_token"], serde_json::json!([layout.every_hold()])),
        rule("configure", "ingress", &["put", "query"], serde_json::json!(configure)),
        rule("all", "ingress", &EVERY_MESSAGE, every_key),
    ];
    let subjects: Vec<serde_json::Value> = rules
        .iter()
        .map(|r| {
            let mut subject = serde_json::json!({ "id": r.name });
            for (key, names) in [
                ("cert_common_names", &r.cert_common_names),
                ("usernames", &r.usernames),
                ("interfaces", &r.interfaces),
            ] {
                if !names.is_empty() {
                    subject[key] = serde_json::json!(names);
                }
            }
            subject
        })
        .collect();
    let policies: Vec<serde_json::Value> = rules
        .iter()
        .map(|r| {
            let mut granted = vec!["see", "read"];
            for permission in &r.may {
                granted.extend_from_slice(match permission {
                    Permission::Read => &[],
                    Permission::Drive => &["drive", "hold"],
                    Permission::Configure => &["configure"],
                    Permission::All => &["all"],
                });
            }
            granted.sort_unstable();
            granted.dedup();
            serde_json::json!({ "id": r.name, "rules": granted, "subjects": [r.name] })
        })
        .collect();
    serde_json::json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": zenoh_rules,
        "subjects": subjects,
        "policies": policies,
    })
}

/// The lease of a client session (see `ZenohConfig::lease`).
pub const CLIENT_LEASE: std::time::Duration = std::time::Duration::from_millis(500);

/// The lease of a node's or router's session (see `ZenohConfig::lease`).
pub const NODE_LEASE: std::time::Duration = std::time::Duration::from_millis(1000);

/// The lease of a client that holds nothing, Zenoh's own (see `ZenohConfig::lease`).
pub const COMMAND_LEASE: std::time::Duration = std::time::Duration::from_secs(10);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_parse_and_print_by_name() {
        assert_eq!("router".parse::<Mode>(), Ok(Mode::Router));
        assert_eq!("Peer".parse::<Mode>(), Err(UnknownMode("Peer".into())));
        assert_eq!(Mode::Client.to_string(), "client");
        assert_eq!(ZenohConfig::client("tcp/127.0.0.1:1").lease(), CLIENT_LEASE);
        let command = ZenohConfig { holds_nothing: true, ..ZenohConfig::client("tcp/127.0.0.1:1") };
        assert_eq!(command.lease(), COMMAND_LEASE);
        assert_eq!(ZenohConfig { holds_nothing: true, ..ZenohConfig::default() }.lease(), NODE_LEASE, "a peer");
    }

    /// A process under TLS, user/password and three access rules.
    pub(crate) fn guarded() -> ZenohConfig {
        let rule = |name: &str, may: Vec<Permission>| AccessRule {
            name: name.into(),
            may,
            cert_common_names: vec![name.into()],
            ..AccessRule::default()
        };
        ZenohConfig {
            tls: Some(TlsConfig {
                ca: "ca.pem".into(),
                certificate: Some("node.pem".into()),
                key: Some("node.key".into()),
                mutual: true,
            }),
            login: Some(LoginConfig { user: Some("node".into()), password: Some("pw".into()), users_file: None }),
            access: vec![
                rule("viewer", vec![Permission::Read]),
                rule("operator", vec![Permission::Drive, Permission::Configure, Permission::Drive]),
                AccessRule { interfaces: vec!["lo".into()], ..rule("nodes", vec![Permission::All]) },
            ],
            ..ZenohConfig::default()
        }
    }

    #[test]
    fn each_permission_grants_its_rules_once() {
        let acl = access_control(&KeyLayout::default(), &guarded().access);
        let granted = |i: usize| acl["policies"][i]["rules"].clone();
        assert_eq!(granted(0), serde_json::json!(["read", "see"]));
        assert_eq!(granted(1), serde_json::json!(["configure", "drive", "hold", "read", "see"]));
        assert_eq!(granted(2), serde_json::json!(["all", "read", "see"]));
        assert_eq!(
            acl["subjects"][2],
            serde_json::json!({"id": "nodes", "cert_common_names": ["nodes"], "interfaces": ["lo"]})
        );
        assert!(guarded().guarded() && !ZenohConfig::default().guarded());
    }

    #[test]
    fn a_quic_endpoint_runs_on_one_stream_unless_it_chooses() {
        let given = [
            "quic/10.0.0.1:7447",
            "quic/[::1]:7447?rel=1#iface=eth0",
            "quic/10.0.0.1:7447?multistream=1",
            "tls/10.0.0.1:7447",
        ];
        let endpoints = zenoh_endpoints(&given.map(String::from));
        assert_eq!(
            endpoints,
            [
                "quic/10.0.0.1:7447?multistream=0",
                "quic/[::1]:7447?rel=1;multistream=0#iface=eth0",
                "quic/10.0.0.1:7447?multistream=1",
                "tls/10.0.0.1:7447",
            ]
        );
        let config =
            ZenohConfig { listen: vec![given[0].into()], connect: vec![given[1].into()], ..Default::default() };
        let entries = config.entries();
        let entry = |key: &str| entries.iter().find(|(k, _)| *k == key).map(|(_, v)| v.clone());
        assert_eq!(entry("listen/endpoints"), Some(r#"["quic/10.0.0.1:7447?multistream=0"]"#.into()));
        assert_eq!(entry("connect/endpoints"), Some(r#"["quic/[::1]:7447?rel=1;multistream=0#iface=eth0"]"#.into()));
    }
}
