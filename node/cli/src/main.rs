//! `zmotor`: start deployments and talk to axes from the command line. This is the edge where
//! errors become the plain words a user reads.

mod sim_controller;

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, SystemTime};
use zmotor_client::{interrupted, show, Client, Event, NoAnswer, Selection, SessionError, WriteOptions, WriteOutcome};
use zmotor_deploy::{
    import_db, simulated_without_controllers, CaConfig, Distribution, JointConfig, Launch, LoginConfig, Macros, Mode,
    Ros2Config, TlsConfig, WebConfig, ZenohConfig,
};
use zmotor_msgs::{keys, Field, KeyLayout, Value, FIELDS};
use zmotor_node::{state_dir, AutosaveConfig, Node, StateStore};

/// Any failure, as the user will read it.
type Error = Box<dyn std::error::Error + Send + Sync>;

#[derive(Parser)]
#[command(name = "zmotor", version, about = "EPICS motor record axes on a Zenoh network")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// A `--joint NAME=AXIS[*FACTOR]` argument.
fn joint_arg(text: &str) -> Result<JointConfig, Error> {
    let (name, rest) = text.split_once('=').ok_or_else(|| format!("--joint {text}: give NAME=AXIS[*FACTOR]"))?;
    let (axis, factor) = match rest.split_once('*') {
        Some((axis, factor)) => {
            let factor: f64 = factor.parse().map_err(|_| format!("--joint {text}: '{factor}' is not a number"))?;
            (axis, Some(factor))
        }
        None => (rest, None),
    };
    if name.is_empty() || axis.is_empty() {
        return Err(format!("--joint {text}: give NAME=AXIS[*FACTOR]").into());
    }
    Ok(JointConfig { name: name.to_string(), axis: axis.to_string(), factor })
}

/// How a client reaches the network.
#[derive(clap::Args, Clone)]
struct ClientArgs {
    /// Zenoh endpoint of a node or router to connect to.
    #[arg(long, default_value = "tcp/127.0.0.1:7447")]
    connect: String,
    /// Key prefix of the axes.
    #[arg(long, default_value = zmotor_msgs::keys::DEFAULT_PREFIX, value_parser = plain_prefix)]
    prefix: String,
    /// PEM file of the certificate authority to trust (tls/... and quic/... endpoints).
    #[arg(long)]
    ca: Option<PathBuf>,
    /// PEM file of this client's certificate, for mutual TLS (with --key).
    #[arg(long, requires_all = ["ca", "key"])]
    cert: Option<PathBuf>,
    /// PEM file of its private key.
    #[arg(long, requires = "cert")]
    key: Option<PathBuf>,
    /// Connect as this user; the password is read from ZMOTOR_PASSWORD.
    #[arg(long)]
    user: Option<String>,
}

impl ClientArgs {
    /// How this client joins the network.
    fn zenoh(&self) -> Result<ZenohConfig, Error> {
        let path = |p: &PathBuf| p.display().to_string();
        let mut section = ZenohConfig { prefix: self.prefix.clone(), ..ZenohConfig::client(&self.connect) };
        section.tls = self.ca.as_ref().map(|ca| TlsConfig {
            ca: path(ca),
            certificate: self.cert.as_ref().map(path),
            key: self.key.as_ref().map(path),
            mutual: self.cert.is_some(),
        });
        if let Some(user) = &self.user {
            let password =
                std::env::var("ZMOTOR_PASSWORD").map_err(|_| "--user needs the password in ZMOTOR_PASSWORD")?;
            section.login = Some(LoginConfig { user: Some(user.clone()), password: Some(password), users_file: None });
        }
        Ok(section)
    }
}

/// How a deployment's process joins the network, over what its launch file says.
#[derive(clap::Args, Clone, Default)]
struct NetworkOverrides {
    /// Zenoh mode: peer, client or router.
    #[arg(long)]
    mode: Option<Mode>,
    /// Endpoint to listen on (repeatable), instead of the launch file's.
    #[arg(long)]
    listen: Vec<String>,
    /// Endpoint to connect to (repeatable), instead of the launch file's.
    #[arg(long)]
    connect: Vec<String>,
}

impl NetworkOverrides {
    fn apply(&self, section: &mut ZenohConfig) {
        if let Some(mode) = self.mode {
            section.mode = mode;
        }
        if !self.listen.is_empty() {
            section.listen.clone_from(&self.listen);
        }
        if !self.connect.is_empty() {
            section.connect.clone_from(&self.connect);
        }
    }
}

#[derive(Subcommand)]
enum Command {
    /// Start the axes of a launch file (TOML) or an EPICS database (.db) and serve them until
    /// SIGINT/SIGTERM, which stops moving axes, saves their state and exits.
    Launch {
        file: PathBuf,
        /// Start only this host's part of a multi-host launch file.
        #[arg(long)]
        host: Option<String>,
        /// Macros of a .db file, name=value[,name=value] (repeatable), as for dbLoadRecords.
        #[arg(short = 'm', long = "macros")]
        macros: Vec<String>,
        #[command(flatten)]
        network: NetworkOverrides,
    },
    /// Convert an EPICS database (.db) into a launch file (TOML) on stdout.
    Convert {
        file: PathBuf,
        #[arg(short = 'm', long = "macros")]
        macros: Vec<String>,
    },
    /// A Zenoh router, so that peers and clients on other hosts reach each other's axes.
    Router {
        /// Endpoint to listen on (repeatable).
        #[arg(long, default_values_t = ["tcp/0.0.0.0:7447".to_string()])]
        listen: Vec<String>,
        /// Another router to connect to (repeatable).
        #[arg(long)]
        connect: Vec<String>,
        /// Answer multicast scouting (off by default: deployments name their endpoints).
        #[arg(long)]
        multicast_scouting: bool,
        /// Take TLS, logins and access rules from this launch file's [zenoh] section.
        #[arg(long)]
        launch: Option<PathBuf>,
    },
    /// List the axes live on the network: name, DESC, EGU, RBV and whether each moves.
    List {
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Read a field (or every field when FIELD is omitted) of an axis, or of several axes
    /// separated by commas or named by a pattern (m1,m2 or 'm*': lines `m1.RBV 1.5`); FIELD may
    /// be a pattern too ('D*').
    Get {
        #[arg(value_parser = axis_patterns)]
        axis: String,
        field: Option<String>,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Write a field; the node confirms or says why it refused.
    Put {
        #[arg(value_parser = axis_name)]
        axis: String,
        field: String,
        /// The value (a negative number is a value, not an option).
        #[arg(allow_hyphen_values = true)]
        value: String,
        /// Answer only when the motion this write started has finished (DMOV back to 1).
        #[arg(long, conflicts_with = "plain")]
        wait: bool,
        /// A plain put, as a robot's publisher sends it: no answer, a refusal goes to ERR.
        #[arg(long)]
        plain: bool,
        /// Seconds to wait for the answer.
        #[arg(long, default_value_t = 600.0, value_parser = seconds)]
        timeout: f64,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Jog an axis while this runs: it stops at Ctrl-C, and also if this process dies or is cut
    /// off (the jog is held by this process's liveliness token: the jog deadman).
    Jog {
        #[arg(value_parser = axis_name)]
        axis: String,
        /// `+` (JOGF) or `-` (JOGR).
        #[arg(allow_hyphen_values = true, value_parser = ["+", "-"])]
        direction: String,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Print field changes as they arrive, as camonitor does (`m1.RBV 2026-12-01
    /// 12:00:00.123456 10`, the node's time of the value in UTC), all fields when none is named; AXIS
    /// may be a pattern ('m*', '*'). An axis whose node goes is told (`m1 ... *** disconnected`);
    /// when a node serves it again, `*** connected` and its current values.
    Monitor {
        #[arg(value_parser = monitored_axes)]
        axis: String,
        fields: Vec<String>,
        /// One JSON object a line: {"axis", "field", "time" (RFC 3339), "value"}, or {"axis",
        /// "time", "connected"} when an axis's node goes (false) or serves it again (true).
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Serve every live axis to Channel Access clients (caget, pyepics, ophyd, CS-Studio) as a
    /// motor record: `<P><axis>` its VAL, `<P><axis>.<FIELD>` each field.
    Ca {
        /// `<P>`, prepended to every channel name.
        #[arg(long, default_value = "")]
        pv_prefix: String,
        /// Address to serve on (searches by UDP, circuits by TCP).
        #[arg(long, default_value = "127.0.0.1")]
        address: std::net::IpAddr,
        /// Port of searches and circuits (EPICS_CA_SERVER_PORT).
        #[arg(long, default_value_t = 5064)]
        port: u16,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Serve motor screens to browsers: an index of the live axes and a screen per axis.
    Web {
        /// HTTP address to serve on.
        #[arg(long, default_value = "127.0.0.1:8080")]
        address: std::net::SocketAddr,
        /// A host name browsers reach the screens by (besides IP addresses, localhost and this
        /// machine's name, which always work); pages under other names are refused. Repeat.
        #[arg(long = "name", value_name = "HOSTNAME")]
        names: Vec<String>,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Be a ROS 2 node (rmw_zenoh's conventions) whose joints are axes: sensor_msgs/JointState
    /// on <namespace>/joint_states (SI units), joint commands on <namespace>/joint_commands, and
    /// the FollowJointTrajectory action on <namespace>/follow_joint_trajectory.
    Ros2 {
        /// A joint: NAME=AXIS, or NAME=AXIS*FACTOR (SI units per EGU when the EGU is no unit of
        /// length or angle). Repeat for each joint.
        #[arg(long = "joint", value_name = "NAME=AXIS[*FACTOR]", required = true)]
        joints: Vec<String>,
        /// The ROS domain (ROS_DOMAIN_ID).
        #[arg(long, default_value_t = 0)]
        domain: u32,
        /// The node's namespace.
        #[arg(long, default_value = "/")]
        namespace: String,
        /// The node's name.
        #[arg(long, default_value = "zmotor")]
        node_name: String,
        /// The ROS 2 distribution whose keys to use: jazzy (type hashes) or humble (none).
        #[arg(long, default_value = "jazzy")]
        distribution: String,
        /// Seconds between the joints' state messages at rest.
        #[arg(long, default_value_t = 1.0)]
        rest_period: f64,
        /// The most joint state messages a second while joints move.
        #[arg(long, default_value_t = 100.0)]
        max_rate: f64,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Write the JSON Schemas of every message type and the field catalogue into DIR.
    Schema { dir: PathBuf },
    /// List every field: name, type, access, default, prompt.
    Fields,
    /// Measure latency, scale, start-up, controllers, storms of writes, Channel Access, the jog
    /// deadman and ROS 2, each beside Zenoh's own floor, and print the figures (runs `zmotor-bench`, built beside
    /// `zmotor`; `zmotor bench --help` lists its options).
    #[command(disable_help_flag = true)]
    Bench {
        /// The benchmark's own arguments.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// Emulate a motor controller on the physical simulator, speaking its protocol on a TCP
    /// socket or a pseudo-terminal, so that a launch file for real hardware runs with none.
    SimController {
        /// The protocol (acs_mcb4b, ...), or the family a script drives (kohzu_sc, vmc, ...).
        protocol: String,
        /// Serve on this TCP address, host:port.
        #[arg(long, conflicts_with = "pty", required_unless_present = "pty")]
        listen: Option<String>,
        /// Serve on a pseudo-terminal linked at this path.
        #[arg(long)]
        pty: Option<PathBuf>,
        /// The pseudo-terminal's bytes take the time they take on a serial line at this rate
        /// (default: the controller's factory rate, e.g. 57600 for an SMC100).
        #[arg(long, requires = "pty", value_parser = clap::value_parser!(u32).range(50..=4_000_000))]
        baud: Option<u32>,
        /// Axes of the emulated controller (default: a typical controller of the kind).
        #[arg(long)]
        channels: Option<usize>,
        #[command(flatten)]
        faults: sim_controller::FaultArgs,
    },
}

/// jemalloc, not glibc's malloc: with an arena per thread, glibc's resident memory kept growing
/// under a storm of writes (about 0.25 MB a minute while the live heap stayed at 2.4 MB);
/// jemalloc's stays flat (BENCHMARKS.md, memory under writes).
#[cfg(not(target_env = "msvc"))]
#[global_allocator]
static ALLOCATOR: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

#[tokio::main]
async fn main() -> ExitCode {
    let command = Cli::parse().command;
    // A client command says what went wrong in one line of its own; Zenoh's logs (with its
    // source paths) only when RUST_LOG asks for them. A node logs Zenoh's warnings.
    let quiet_zenoh = matches!(
        command,
        Command::Get { .. }
            | Command::Put { .. }
            | Command::Monitor { .. }
            | Command::Jog { .. }
            | Command::List { .. }
    );
    let default_filter = if quiet_zenoh { "info,zenoh=off" } else { "info,zenoh=warn" };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| default_filter.into()),
        )
        .with_writer(std::io::stderr)
        // Colours on a terminal only: a log file keeps plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    match run(command).await {
        Ok(code) => code,
        Err(e) => {
            eprintln!("zmotor: {e}");
            ExitCode::FAILURE
        }
    }
}

async fn run(command: Command) -> Result<ExitCode, Error> {
    match command {
        Command::Launch { file, host, macros, network } => launch(&file, host.as_deref(), &macros, &network).await,
        Command::Convert { file, macros } => {
            let (launch, warnings) = load(&file, &macros)?;
            let notes: String = warnings.iter().map(|w| format!("# warning: {w}\n")).collect();
            print!("# converted by zmotor convert from {}\n{notes}\n{}\n", file.display(), launch.to_toml().trim_end());
            Ok(ExitCode::SUCCESS)
        }
        Command::Router { listen, connect, multicast_scouting, launch } => {
            let security = match launch {
                Some(file) => Launch::load(&file)?.deployment(None)?.zenoh,
                None => ZenohConfig::default(),
            };
            warn_if_open(&security);
            let section = ZenohConfig {
                mode: Mode::Router,
                listen,
                connect,
                multicast_scouting,
                prefix: security.prefix,
                tls: security.tls,
                login: security.login,
                access: security.access,
                holds_nothing: false,
            };
            let session = zmotor_client::open_waiting(&section).await?;
            tracing::info!(listen = ?section.listen, connect = ?section.connect, "zmotor router serving; Ctrl-C to stop");
            interrupted().await?;
            session.close().await?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Get { axis, field, client } => get(&client, &axis, field.as_deref()).await,
        Command::Put { axis, field, value, plain: true, client, .. } => {
            let zmotor = connect_command(&client).await?;
            zmotor.put(&axis, field_named(&field)?, value).await?;
            zmotor.session().close().await?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Put { axis, field, value, wait, timeout, client, .. } => {
            put(&client, &axis, &field, &value, wait, timeout).await
        }
        Command::Monitor { axis, fields, json, client } => monitor(&client, &axis, &fields, json).await,
        Command::List { client } => list(&client).await,
        Command::Web { address, names, client } => {
            let zmotor = connect(&client).await?;
            let served = zmotor_web::Web::start(zmotor.clone(), &WebConfig { address, names }).await?;
            eprintln!("motor screens at http://{}/ ; Ctrl-C to stop", served.address);
            interrupted().await?;
            drop(served);
            zmotor.session().close().await?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Ca { pv_prefix, address, port, client } => {
            let zmotor = connect(&client).await?;
            let served =
                zmotor_ca::ChannelAccess::start(zmotor.clone(), &CaConfig { pv_prefix, address, port }).await?;
            interrupted().await?;
            drop(served);
            zmotor.session().close().await?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Ros2 { joints, domain, namespace, node_name, distribution, rest_period, max_rate, client } => {
            let joints = joints.iter().map(|j| joint_arg(j)).collect::<Result<Vec<_>, _>>()?;
            let distribution = Distribution::from_name(&distribution)
                .ok_or_else(|| format!("--distribution {distribution}: give jazzy or humble"))?;
            if !(rest_period.is_finite() && rest_period > 0.0) {
                return Err("--rest-period: give a positive number of seconds".into());
            }
            let rest_period = Duration::from_secs_f64(rest_period);
            let config =
                Ros2Config { domain_id: domain, namespace, node_name, distribution, joints, rest_period, max_rate };
            config.check()?;
            tracing::warn!(
                "the ROS face moves the joints with this session's rights for whoever reaches its ROS 2 keys \
                 (zmotor's access rules do not cover them)"
            );
            let zmotor = connect(&client).await?;
            let served = zmotor_ros2::Ros2Node::start(zmotor.clone(), &config).await?;
            interrupted().await?;
            drop(served);
            zmotor.session().close().await?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Jog { axis, direction, client } => jog(&client, &axis, direction == "+").await,
        Command::Schema { dir } => schema(&dir),
        Command::Bench { args } => bench(&args),
        Command::SimController { protocol, listen, pty, baud, channels, faults } => {
            let endpoint = match (listen, pty) {
                (Some(address), _) => sim_controller::Endpoint::Tcp(address),
                (None, Some(path)) => sim_controller::Endpoint::Pty(path, baud),
                (None, None) => return Err("give --listen host:port or --pty PATH".into()),
            };
            sim_controller::run(&protocol, endpoint, channels, &faults).await?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Fields => {
            print_lines(FIELDS.iter().map(|d| {
                format!(
                    "{:<6} {:<7} {:<5} {:<10} {}",
                    d.name,
                    d.kind.type_name(),
                    d.access.label(),
                    d.default_value().to_string(),
                    d.prompt
                )
            }));
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// `zmotor bench ARGS`: the benchmark is a program of its own, `zmotor-bench`, found beside this
/// one (as cargo finds its subcommands); it starts nodes as a user does, with this `zmotor`.
fn bench(args: &[String]) -> Result<ExitCode, Error> {
    let here = std::env::current_exe()?;
    let bench = here.with_file_name("zmotor-bench");
    if !bench.exists() {
        return Err(format!(
            "{} is not built: `cargo build --release -p zmotor-bench` builds it beside zmotor",
            bench.display()
        )
        .into());
    }
    // Replaced by the benchmark (exec), so that a signal sent to this process reaches the
    // benchmark, which stops the nodes it started.
    use std::os::unix::process::CommandExt;
    Err(std::process::Command::new(&bench).args(args).arg("--zmotor").arg(&here).exec().into())
}

/// A launch file, or an EPICS database converted into one (with what the conversion warns of).
fn load(file: &std::path::Path, macros: &[String]) -> Result<(Launch, Vec<String>), Error> {
    if file.extension().is_some_and(|e| e == "db") {
        let (mut converted, mut warnings) = import_db(file, &Macros::parse(macros)?, keys::DEFAULT_PREFIX)?;
        warnings.extend(simulated_without_controllers(&mut converted));
        let name = format!("{} (as converted by zmotor convert)", file.display());
        Ok((Launch::from_file(&name, converted)?, warnings))
    } else if !macros.is_empty() {
        Err("-m applies to .db files only".into())
    } else {
        let launch = Launch::load(file)?;
        let warnings = launch.warnings().to_vec();
        Ok((launch, warnings))
    }
}

async fn launch(
    file: &std::path::Path,
    host: Option<&str>,
    macros: &[String],
    network: &NetworkOverrides,
) -> Result<ExitCode, Error> {
    let (launch, warnings) = load(file, macros)?;
    for warning in &warnings {
        tracing::warn!("{}: {warning}", file.display());
    }
    let mut deployment = launch.deployment(host)?;
    network.apply(&mut deployment.zenoh);
    warn_if_open(&deployment.zenoh);
    let layout = KeyLayout::new(&deployment.zenoh.prefix);
    let autosave = if deployment.autosave.enabled && !deployment.contents.plans.is_empty() {
        let dir = state_dir(deployment.state_dir.as_deref())?;
        let store = StateStore::open(&dir, layout.prefix())?;
        tracing::info!(dir = %store.dir().display(), "autosave on");
        Some(AutosaveConfig { store, delay: Duration::from_secs_f64(deployment.autosave.delay) })
    } else {
        None
    };
    if !deployment.zenoh.connect.is_empty() {
        tracing::info!(connect = ?deployment.zenoh.connect, "connecting");
    }
    let session = zmotor_client::open_waiting(&deployment.zenoh).await?;
    let names: Vec<String> = deployment.contents.plans.iter().map(|p| p.name.clone()).collect();
    let calc_names: Vec<String> = deployment.contents.calcs.iter().map(|c| c.name.clone()).collect();
    let node = Node::start(session.clone(), layout.clone(), deployment.contents, autosave).await?;
    // Channel Access and the web screens are clients of the node's own network, on a session of
    // their own: a node's publications leave its session only for others.
    let front_client = match deployment.channel_access.is_some() || deployment.web.is_some() {
        true => Some(front_end_client(&deployment.zenoh).await?),
        false => None,
    };
    let mut front_ends = (None, None, None, None);
    if let Some(client) = &front_client {
        if let Some(config) = &deployment.channel_access {
            front_ends.0 = Some(zmotor_ca::ChannelAccess::start(client.clone(), config).await?);
        }
        if let Some(config) = &deployment.web {
            front_ends.1 = Some(zmotor_web::Web::start(client.clone(), config).await?);
        }
    }
    let stopped = interrupted();
    tokio::pin!(stopped);
    let mut stopping = false;
    if let Some(config) = &deployment.ros2 {
        // The ROS face is on the node's own session, the joints' values of this node's axes
        // handed over as it posts them: a readback reaches ROS as soon as zmotor's key
        // (BENCHMARKS.md §10); other hosts' axes are followed over the network, and waited for.
        // Its writes are the node's queries, under the node's own identity, as a client session
        // of the node's credentials would be.
        let client = Client::new(session.clone(), layout.clone());
        tokio::select! {
            started = zmotor_ros2::Ros2Node::start_fed(client, config, &names) => {
                let (ros2, feed) = started?;
                front_ends.3 = Some(node.follow_posts(&feed.keys(), move |index, value| feed.post(index, value)));
                front_ends.2 = Some(ros2);
            }
            signal = &mut stopped => {
                signal?;
                stopping = true;
            }
        }
    }
    if !stopping {
        tracing::info!(axes = ?names, calcs = ?calc_names, mode = %deployment.zenoh.mode,
            listen = ?deployment.zenoh.listen, connect = ?deployment.zenoh.connect, prefix = layout.prefix(),
            "zmotor serving; Ctrl-C to stop");
        stopped.await?;
    }
    drop(front_ends);
    if let Some(client) = front_client {
        client.session().close().await?;
    }
    tracing::info!("stopping: moving axes stop, state is saved");
    node.shutdown().await;
    session.close().await?;
    tracing::info!("stopped");
    Ok(ExitCode::SUCCESS)
}

/// Say at start that a process is open to whoever reaches it.
fn warn_if_open(section: &ZenohConfig) {
    if !section.guarded() {
        tracing::warn!(
            "no [[zenoh.access]] rules: whoever reaches this process may move its axes and change their settings \
             (README: Running it safely)"
        );
    }
}

/// A client of the network a node's `section` joins: to where it listens (or else connects),
/// with its TLS and login.
async fn front_end_client(section: &ZenohConfig) -> Result<Client, Error> {
    let reach = section.listen.first().map(|l| l.replace("0.0.0.0", "127.0.0.1"));
    let Some(endpoint) = reach.or_else(|| section.connect.first().cloned()) else {
        return Err("[channel_access] and [web] need the node to listen or connect somewhere".into());
    };
    let client = ZenohConfig {
        tls: section.tls.clone(),
        login: section.login.clone(),
        prefix: section.prefix.clone(),
        ..ZenohConfig::client(&endpoint)
    };
    Ok(Client::connect(&client).await?)
}

/// A client connected where `client` says, which may hold a motion (a jog, a gateway's): it
/// announces a client's short lease, so that its holds end soon after it is cut off.
async fn connect(client: &ClientArgs) -> Result<Client, Error> {
    open_client(&client.zenoh()?).await
}

/// A client connected where `client` says, for a command that holds no motion (get, put, list,
/// monitor): with Zenoh's lease, a command starved on a busy host keeps its link.
async fn connect_command(client: &ClientArgs) -> Result<Client, Error> {
    open_client(&ZenohConfig { holds_nothing: true, ..client.zenoh()? }).await
}

async fn open_client(section: &ZenohConfig) -> Result<Client, Error> {
    Client::connect(section).await.map_err(|e| match e {
        SessionError::Unreachable { .. } => {
            format!("{e}: start a node there (zmotor launch launch/sim-axis.toml) or point --connect at one").into()
        }
        other => other.into(),
    })
}

/// The field a user typed, in any case.
fn field_named(name: &str) -> Result<Field, Error> {
    Field::from_name_any_case(name).ok_or_else(|| format!("{name}: unknown field (zmotor fields lists them)").into())
}

/// Print `lines` until the reader goes away; false when it has (`monitor ... | head -1`).
fn print_lines(lines: impl IntoIterator<Item = String>) -> bool {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    lines.into_iter().all(|line| writeln!(out, "{line}").and_then(|()| out.flush()).is_ok())
}

/// An axis's name, as a write or a jog takes it.
fn axis_name(text: &str) -> Result<String, String> {
    keys::validate_axis_name(text).map(|()| text.to_string()).map_err(|e| e.to_string())
}

/// An axis's name or a pattern such as `m*`, as a monitor takes it.
fn axis_pattern(text: &str) -> Result<String, String> {
    keys::validate_axis_pattern(text).map(|()| text.to_string()).map_err(|e| e.to_string())
}

/// A key prefix: one plain key, as every key of the axes starts with it.
fn plain_prefix(text: &str) -> Result<String, String> {
    keys::validate_plain_key(text).map(|()| text.to_string()).map_err(|e| e.to_string())
}

/// An axis's name or a pattern, as a monitor takes it: one, not a list (a read takes a list).
fn monitored_axes(text: &str) -> Result<String, String> {
    match text.contains(',') {
        true => Err(format!("{text}: a monitor takes one axis or a pattern such as 'm*', not a list")),
        false => axis_pattern(text),
    }
}

/// Axes' names or patterns separated by commas, as a read takes them.
fn axis_patterns(text: &str) -> Result<String, String> {
    text.split(',').filter(|a| !a.is_empty()).try_for_each(|a| axis_pattern(a).map(drop))?;
    Ok(text.to_string())
}

/// A number of seconds a command waits: finite, not negative, at most a year.
fn seconds(text: &str) -> Result<f64, String> {
    const YEAR: f64 = 365.0 * 24.0 * 3600.0;
    match text.parse::<f64>() {
        // No answer could come within 0 s: the write would go out and be reported unanswered.
        Ok(s) if s > 0.0 && s <= YEAR => Ok(s),
        Ok(s) => Err(format!("{s} is not a number of seconds more than 0, up to a year")),
        Err(e) => Err(e.to_string()),
    }
}

/// What an unanswered client may also be told: Zenoh answers a query its access rules deny
/// with nothing at all.
const UNANSWERED_UNDER_ACCESS_CONTROL: &str = " Under access control, a request the rules deny gets no answer either.";

async fn get(client: &ClientArgs, axes: &str, field: Option<&str>) -> Result<ExitCode, Error> {
    let zmotor = connect_command(client).await?;
    let axes: Vec<&str> = axes.split(',').filter(|a| !a.is_empty()).collect();
    // Lines name their axis when there may be several.
    let several = axes.len() > 1 || axes.iter().any(|a| a.contains('*'));
    // Field names are upper case, as EPICS spells them; a name is found in any case.
    let pattern = field.filter(|f| f.contains('*')).map(str::to_ascii_uppercase);
    let mut code = ExitCode::SUCCESS;
    for axis in axes {
        // One field by name, or a pattern such as D* or the whole axis.
        let selection = match (&pattern, field) {
            (Some(pattern), _) => Selection::Pattern(pattern),
            // ERR is no field but the axis's messages: its last one.
            (None, Some(name)) if name.eq_ignore_ascii_case(zmotor_msgs::keys::ERR_KEY) => Selection::LastMessage,
            (None, Some(name)) => Selection::Field(field_named(name)?),
            (None, None) => Selection::All,
        };
        let read = zmotor.read(axis, selection).await?;
        for refusal in &read.refusals {
            eprintln!("zmotor: {refusal}");
        }
        let single = matches!(selection, Selection::Field(_) | Selection::LastMessage);
        print_lines(read.readings.iter().map(|reading| {
            let (name, value) = (&reading.name, read.shown(reading));
            match (several, single) {
                (true, _) => format!("{}.{name} {value}", reading.axis),
                (false, true) => value,
                (false, false) => format!("{name:<6} {value}"),
            }
        }));
        if read.readings.is_empty() {
            code = ExitCode::FAILURE;
            eprintln!(
                "zmotor: no answer for {axis} (is the axis running, and is {} reachable?{})",
                client.connect, UNANSWERED_UNDER_ACCESS_CONTROL
            );
        }
    }
    zmotor.session().close().await?;
    Ok(code)
}

/// The live axes (their liveliness tokens), with DESC, EGU, RBV and whether they move.
async fn list(client: &ClientArgs) -> Result<ExitCode, Error> {
    let zmotor = connect_command(client).await?;
    let axes = zmotor.live_axes().await?;
    let text = |t: &Option<String>| t.clone().unwrap_or_else(|| "?".into());
    let rows: Vec<[String; 5]> = axes
        .iter()
        .map(|a| {
            let state = match a.moving {
                Some(true) => "moving",
                Some(false) => "idle",
                None => "?",
            };
            // As caget shows it: at the axis's precision.
            let rbv = a.rbv.map_or_else(|| "?".into(), |r| show(Field::RBV, &zmotor_msgs::Value::Float(r), a.prec));
            [a.name.clone(), text(&a.desc), text(&a.egu), rbv, state.into()]
        })
        .collect();
    let header = ["AXIS", "DESC", "EGU", "RBV", "STATE"].map(String::from);
    let widths: Vec<usize> =
        (0..5).map(|i| rows.iter().chain([&header]).map(|r| r[i].chars().count()).max().unwrap_or(0)).collect();
    let line = |row: &[String; 5]| {
        row.iter().zip(&widths).map(|(text, width)| format!("{text:<width$}")).collect::<Vec<_>>().join("  ")
    };
    if rows.is_empty() {
        eprintln!("zmotor: no axis is live at {}", client.connect);
    } else {
        print_lines(std::iter::once(line(&header)).chain(rows.iter().map(line)).map(|l| l.trim_end().to_string()));
    }
    zmotor.session().close().await?;
    Ok(ExitCode::SUCCESS)
}

async fn put(
    client: &ClientArgs,
    axis: &str,
    field: &str,
    value: &str,
    wait: bool,
    timeout: f64,
) -> Result<ExitCode, Error> {
    let zmotor = connect_command(client).await?;
    let field = field_named(field)?;
    let patience = Duration::from_secs_f64(timeout);
    let options = if wait { WriteOptions::waiting(patience) } else { WriteOptions::confirmed(patience) };
    let sent = zmotor.write(axis, field, value, options).await?;
    let outcome = if wait { saying_why_held(&zmotor, axis, sent.outcome()).await } else { sent.outcome().await };
    let code = match outcome {
        WriteOutcome::Accepted(value) => {
            println!("{}", show(field, &value, None));
            ExitCode::SUCCESS
        }
        // A motion that ended away from its target (stopped, on a limit, MISS, an alarm) is a
        // failure to a script (`put ... --wait && take_image`), as its line says.
        WriteOutcome::Completed(completion) => {
            let reached = completion.reached == 1;
            println!("{}", WriteOutcome::Completed(completion));
            if reached {
                ExitCode::SUCCESS
            } else {
                eprintln!("zmotor: {axis} did not reach the target (reached=0: see MISS, LVIO, SEVR and RBV)");
                ExitCode::FAILURE
            }
        }
        WriteOutcome::Refused(refusal) => {
            eprintln!("zmotor: {refusal}");
            ExitCode::FAILURE
        }
        WriteOutcome::Vanished => {
            let token = zmotor.layout().axis(axis);
            eprintln!(
                "zmotor: the node serving {axis} vanished before answering (its liveliness token {token} went away): \
                 the write's outcome is unknown"
            );
            ExitCode::FAILURE
        }
        WriteOutcome::NoAnswer(NoAnswer::TimedOut) => {
            let motion = if wait { ", and a motion it started may still be under way" } else { "" };
            eprintln!(
                "zmotor: {axis} is served but did not answer within {timeout} s: the write of {} may have been \
                 taken{motion}",
                field.name()
            );
            ExitCode::FAILURE
        }
        WriteOutcome::NoAnswer(NoAnswer::Silent) => {
            eprintln!("zmotor: {axis} is served but its node gave no answer.{UNANSWERED_UNDER_ACCESS_CONTROL}");
            ExitCode::FAILURE
        }
        other => {
            eprintln!(
                "zmotor: no axis {axis} answers at {} ({other}: is its node running and reachable?{})",
                client.connect, UNANSWERED_UNDER_ACCESS_CONTROL
            );
            ExitCode::FAILURE
        }
    };
    zmotor.session().close().await?;
    Ok(code)
}

/// A --wait's outcome; if it has not come within a second and the axis is held by SPMG (Stop or
/// Pause: the motion waits for Go or Move, as on an IOC), say so once, then wait on.
async fn saying_why_held(
    zmotor: &Client,
    axis: &str,
    outcome: impl std::future::Future<Output = WriteOutcome>,
) -> WriteOutcome {
    tokio::pin!(outcome);
    tokio::select! {
        done = &mut outcome => return done,
        () = tokio::time::sleep(Duration::from_secs(1)) => {}
    }
    if let Ok(read) = zmotor.read(axis, Selection::Field(Field::SPMG)).await {
        let held = read.readings.first().filter(|r| matches!(r.value, Value::Int(0 | 1)));
        if let Some(spmg) = held {
            eprintln!("zmotor: {axis} is held by SPMG {}: the motion waits until SPMG is Go or Move", read.shown(spmg));
        }
    }
    outcome.await
}

/// Jog `axis` under a hold until Ctrl-C (or SIGTERM), or until the jog ends by itself (a limit).
async fn jog(client: &ClientArgs, axis: &str, forward: bool) -> Result<ExitCode, Error> {
    let zmotor = connect(client).await?;
    let button = if forward { Field::JOGF } else { Field::JOGR };
    let token = zmotor.hold(axis, &zmotor.session().zid().to_string()).await?;
    let options = WriteOptions::confirmed(Duration::from_secs(5)).held_by(Some(token.key().to_string()));
    match zmotor.write(axis, button, "1", options.clone()).await?.outcome().await {
        WriteOutcome::Accepted(_) => {
            eprintln!("jogging {axis} {}; Ctrl-C to stop", if forward { "forward" } else { "in reverse" })
        }
        WriteOutcome::Refused(refusal) => return Err(refusal.into()),
        other => return Err(format!("{axis}: {other}").into()),
    }
    // DMOV, from now: 0 while the jog runs; 1 once it ended, also before this monitor began.
    let mut dmov = zmotor.monitor(axis, &[Field::DMOV]).await?;
    let ended = |update: &zmotor_client::Update| update.value == Value::Int(1);
    let interrupted = interrupted();
    tokio::pin!(interrupted);
    let mut jog_over = false;
    loop {
        tokio::select! {
            result = &mut interrupted => {
                result?;
                break;
            }
            update = dmov.next() => match update {
                Some(update) if ended(&update) => {
                    eprintln!("the jog ended by itself (a limit, a STOP, or SPMG not Go)");
                    jog_over = true;
                    break;
                }
                Some(_) => {}
                None => break,
            },
        }
    }
    let _ = zmotor.write(axis, button, "0", options).await?.outcome().await;
    // The jog decelerates (and takes out its backlash) before it is over.
    let settled = async {
        while let Some(update) = dmov.next().await {
            if ended(&update) {
                return;
            }
        }
    };
    if !jog_over {
        let _ = tokio::time::timeout(Duration::from_secs(30), settled).await;
    }
    let read = zmotor.read(axis, Selection::Field(Field::RBV)).await?;
    if let Some(rbv) = read.readings.first() {
        println!("{}", read.shown(rbv));
    }
    zmotor.session().close().await?;
    Ok(ExitCode::SUCCESS)
}

/// A monitor that starts with the current values, then every change, as camonitor does.
async fn monitor(client: &ClientArgs, axis: &str, fields: &[String], json: bool) -> Result<ExitCode, Error> {
    let zmotor = connect_command(client).await?;
    // ERR is no field but the axis's messages: refused writes, its controller's errors.
    let is_err = |name: &String| name.eq_ignore_ascii_case(zmotor_msgs::keys::ERR_KEY);
    let wanted: Vec<Field> = fields.iter().filter(|f| !is_err(f)).map(|f| field_named(f)).collect::<Result<_, _>>()?;
    let messages = fields.iter().any(is_err);
    // As camonitor says "not connected": a monitor of an axis nobody serves waits silently.
    let token = zmotor.layout().axis(&keys::chunk_pattern(axis));
    let tokens = zmotor.session().liveliness().get(token).timeout(Duration::from_secs(2)).await?;
    if tokens.recv_async().await.is_err() {
        eprintln!("zmotor: no node serves {axis} now; its values will show when one does (Ctrl-C to stop)");
    }
    // Only messages: follow nothing else (PREC still comes, for the shape of the values, and is
    // not shown).
    let only_messages = messages && wanted.is_empty();
    let followed = if only_messages { vec![Field::PREC] } else { wanted };
    let mut updates = zmotor.monitor_with_messages(axis, &followed, messages).await?;
    loop {
        tokio::select! {
            event = updates.next_event() => {
                let line = match event {
                    None => break,
                    Some(Event::Value(update)) if only_messages && update.field.is_some() => continue,
                    Some(Event::Value(update)) => monitor_line(&update, json),
                    Some(Event::Gone(axis)) => connection_line(&axis, false, json),
                    Some(Event::Back(axis)) => connection_line(&axis, true, json),
                };
                if !print_lines([line]) {
                    break;
                }
            }
            _ = tokio::signal::ctrl_c() => break,
        }
    }
    drop(updates);
    zmotor.session().close().await?;
    Ok(ExitCode::SUCCESS)
}

/// A monitor's line: camonitor's `m1.RBV 2026-12-01 12:00:00.123456 10`, or a JSON object with
/// the value as published.
fn monitor_line(update: &zmotor_client::Update, json: bool) -> String {
    let time = humantime::format_rfc3339_micros(update.at).to_string();
    let (axis, field) = (&update.axis, &update.name);
    if json {
        serde_json::json!({ "axis": axis, "field": field, "time": time, "value": update.value }).to_string()
    } else {
        format!("{axis}.{field} {} {}", time.trim_end_matches('Z').replacen('T', " ", 1), update.shown)
    }
}

/// A monitor's line when an axis's node goes (as camonitor's `*** disconnected`) or a node serves
/// it again (its current values follow).
fn connection_line(axis: &str, connected: bool, json: bool) -> String {
    let time = humantime::format_rfc3339_micros(SystemTime::now()).to_string();
    if json {
        serde_json::json!({ "axis": axis, "time": time, "connected": connected }).to_string()
    } else {
        let said = if connected { "connected" } else { "disconnected" };
        format!("{axis} {} *** {said}", time.trim_end_matches('Z').replacen('T', " ", 1))
    }
}

fn schema(dir: &std::path::Path) -> Result<ExitCode, Error> {
    let at = |path: &std::path::Path| {
        let path = path.display().to_string();
        move |e: std::io::Error| format!("{path}: {e}")
    };
    std::fs::create_dir_all(dir).map_err(at(dir))?;
    let schemas = zmotor_msgs::message_schemas().into_iter().map(|(name, schema)| (name.to_string(), schema));
    for (name, schema) in schemas.chain([("fields.json".to_string(), zmotor_msgs::catalogue_json())]) {
        let path = dir.join(name);
        std::fs::write(&path, serde_json::to_string_pretty(&schema)? + "\n").map_err(at(&path))?;
    }
    println!("wrote the schemas and fields.json to {}", dir.display());
    Ok(ExitCode::SUCCESS)
}
