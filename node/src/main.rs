//! `zmotor`: start deployments and talk to axes from the command line.

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;
use zenoh::bytes::Encoding;
use zmotor_msgs::{codec::decode_cbor_value, Field, KeyLayout, FIELDS};
use zmotor_node::bench;
use zmotor_node::launch::{Launch, ZenohSection};
use zmotor_node::net::{zenoh_config, Error, Node};

#[derive(Parser)]
#[command(name = "zmotor", version, about = "EPICS motor record axes on a Zenoh network")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// How a client reaches the network.
#[derive(clap::Args, Clone)]
struct ClientArgs {
    /// Zenoh endpoint of a node or router to connect to.
    #[arg(long, default_value = "tcp/127.0.0.1:7447")]
    connect: String,
    /// Key prefix of the axes.
    #[arg(long, default_value = zmotor_msgs::keys::DEFAULT_PREFIX)]
    prefix: String,
}

#[derive(Subcommand)]
enum Command {
    /// Start the axes of a launch file and serve them until interrupted.
    Launch { file: PathBuf },
    /// Read a field (or every field when FIELD is omitted).
    Get {
        axis: String,
        field: Option<String>,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Write a field; the node confirms or says why it refused.
    Put {
        axis: String,
        field: String,
        value: String,
        /// Answer only when the motion this write started has finished (DMOV back to 1).
        #[arg(long)]
        wait: bool,
        /// Seconds to wait for the answer.
        #[arg(long, default_value_t = 600.0)]
        timeout: f64,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Print field changes as they are published (all fields when none is named).
    Monitor {
        axis: String,
        fields: Vec<String>,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Write the JSON Schemas of every message type and the field catalogue into DIR.
    Schema { dir: PathBuf },
    /// List every field: name, type, access, default, prompt.
    Fields,
    /// Measure latency, engine cost, scale and start-up, and print the figures.
    Bench {
        /// A run of seconds that only proves every part works.
        #[arg(long)]
        smoke: bool,
        /// Moves for the latency figures (default 2000).
        #[arg(long)]
        moves: Option<usize>,
        /// Axis counts for the scale figures, comma-separated (default 1,100,1000,10000).
        #[arg(long, value_delimiter = ',')]
        scales: Option<Vec<usize>>,
    },
    /// The benchmark's node process (started by `zmotor bench`).
    #[command(hide = true)]
    BenchServe {
        #[arg(long)]
        listen: String,
        #[arg(long, default_value_t = 1)]
        axes: usize,
    },
}

#[tokio::main]
async fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info,zenoh=warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match run(Cli::parse().command).await {
        Ok(code) => code,
        Err(e) => {
            eprintln!("zmotor: {e}");
            ExitCode::FAILURE
        }
    }
}

async fn run(command: Command) -> Result<ExitCode, Error> {
    match command {
        Command::Launch { file } => launch(&file).await,
        Command::Get { axis, field, client } => get(&client, &axis, field.as_deref()).await,
        Command::Put { axis, field, value, wait, timeout, client } => {
            put(&client, &axis, &field, &value, wait, timeout).await
        }
        Command::Monitor { axis, fields, client } => monitor(&client, &axis, &fields).await,
        Command::Schema { dir } => schema(&dir),
        Command::Bench { smoke, moves, scales } => {
            let mut options = if smoke { bench::BenchOptions::smoke() } else { bench::BenchOptions::full() };
            options.moves = moves.unwrap_or(options.moves);
            options.scales = scales.unwrap_or(options.scales);
            bench::run(&options).await?;
            Ok(ExitCode::SUCCESS)
        }
        Command::BenchServe { listen, axes } => {
            bench::serve(&listen, axes, 100.0).await?;
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

async fn launch(file: &std::path::Path) -> Result<ExitCode, Error> {
    let launch = Launch::load(file)?;
    let session = zenoh::open(zenoh_config(&launch.zenoh)?).await?;
    let layout = KeyLayout::new(&launch.zenoh.prefix);
    let plans = launch.plans()?;
    let calcs = launch.calc_links()?;
    let names: Vec<String> = plans.iter().map(|p| p.name.clone()).collect();
    let calc_names: Vec<String> = calcs.iter().map(|c| c.name.clone()).collect();
    let node = Node::start(session.clone(), layout.clone(), plans, calcs).await?;
    tracing::info!(axes = ?names, calcs = ?calc_names, listen = ?launch.zenoh.listen, prefix = layout.prefix(), "zmotor serving; Ctrl-C to stop");
    tokio::signal::ctrl_c().await?;
    node.shutdown().await;
    session.close().await?;
    Ok(ExitCode::SUCCESS)
}

async fn client_session(client: &ClientArgs) -> Result<zenoh::Session, Error> {
    let section = ZenohSection {
        mode: "client".into(),
        listen: vec![],
        connect: vec![client.connect.clone()],
        ..ZenohSection::default()
    };
    zenoh::open(zenoh_config(&section)?).await
}

fn field_name(name: &str) -> Result<&'static str, Error> {
    Field::from_name(name)
        .map(Field::name)
        .ok_or_else(|| format!("{name}: unknown field (zmotor fields lists them)").into())
}

/// Print lines until the reader goes away (e.g. `| head`).
fn print_lines(lines: impl IntoIterator<Item = String>) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    for line in lines {
        if writeln!(out, "{line}").is_err() {
            return;
        }
    }
}

/// A published value, or the outcome map of a `?wait` write as `NAME=value` pairs.
fn show(payload: &[u8]) -> String {
    if let Ok(value) = decode_cbor_value(payload) {
        return value.to_string();
    }
    match ciborium::from_reader::<std::collections::BTreeMap<String, zmotor_msgs::Value>, _>(payload) {
        Ok(map) => map.iter().map(|(k, v)| format!("{k}={v}")).collect::<Vec<_>>().join(" "),
        Err(_) => String::from_utf8_lossy(payload).into_owned(),
    }
}

async fn get(client: &ClientArgs, axis: &str, field: Option<&str>) -> Result<ExitCode, Error> {
    let session = client_session(client).await?;
    let layout = KeyLayout::new(&client.prefix);
    // One field by name, or a pattern such as D* or the whole axis.
    let (key, single) = match field {
        // Zenoh spells a wildcard inside a chunk `$*`.
        Some(f) if f.contains('*') => {
            let pattern = if f == "*" || f == "**" { f.to_string() } else { f.replace('*', "$*") };
            (format!("{}/{axis}/{pattern}", layout.prefix()), false)
        }
        Some(f) => (format!("{}/{axis}/{}", layout.prefix(), field_name(f)?), true),
        None => (layout.axis_all(axis), false),
    };
    let replies = session.get(&key).timeout(Duration::from_secs(5)).await?;
    let mut values = Vec::new();
    while let Ok(reply) = replies.recv_async().await {
        match reply.result() {
            Ok(sample) => {
                let name = sample.key_expr().as_str().rsplit('/').next().unwrap_or_default().to_string();
                values.push((Field::from_name(&name), name, show(&sample.payload().to_bytes())));
            }
            Err(err) => eprintln!("zmotor: {}", String::from_utf8_lossy(&err.payload().to_bytes())),
        }
    }
    values.sort_by_key(|(field, ..)| *field);
    let lines = values.iter().map(|(_, name, value)| if single { value.clone() } else { format!("{name:<6} {value}") });
    print_lines(lines);
    let code = if values.is_empty() { ExitCode::FAILURE } else { ExitCode::SUCCESS };
    if values.is_empty() {
        eprintln!("zmotor: no answer for {key} (is the axis running, and is {} reachable?)", client.connect);
    }
    session.close().await?;
    Ok(code)
}

async fn put(
    client: &ClientArgs,
    axis: &str,
    field: &str,
    value: &str,
    wait: bool,
    timeout: f64,
) -> Result<ExitCode, Error> {
    let session = client_session(client).await?;
    let layout = KeyLayout::new(&client.prefix);
    let key = format!("{}/{axis}/{}", layout.prefix(), field_name(field)?);
    let selector = if wait { format!("{key}?wait") } else { key.clone() };
    let replies = session
        .get(&selector)
        .payload(value.to_string())
        .encoding(Encoding::TEXT_PLAIN)
        .timeout(Duration::from_secs_f64(timeout))
        .await?;
    let mut code = ExitCode::FAILURE;
    match replies.recv_async().await {
        Ok(reply) => match reply.result() {
            Ok(sample) => {
                println!("{}", show(&sample.payload().to_bytes()));
                code = ExitCode::SUCCESS;
            }
            Err(err) => eprintln!("zmotor: {}", String::from_utf8_lossy(&err.payload().to_bytes())),
        },
        Err(_) => eprintln!("zmotor: no answer for {key} (is the axis running, and is {} reachable?)", client.connect),
    }
    session.close().await?;
    Ok(code)
}

async fn monitor(client: &ClientArgs, axis: &str, fields: &[String]) -> Result<ExitCode, Error> {
    let session = client_session(client).await?;
    let layout = KeyLayout::new(&client.prefix);
    let wanted: Vec<&str> = fields.iter().map(|f| field_name(f)).collect::<Result<_, _>>()?;
    let subscriber = session.declare_subscriber(format!("{}/{axis}/*", layout.prefix())).await?;
    loop {
        tokio::select! {
            sample = subscriber.recv_async() => {
                let Ok(sample) = sample else { break };
                let name = sample.key_expr().as_str().rsplit('/').next().unwrap_or_default().to_string();
                if wanted.is_empty() || wanted.contains(&name.as_str()) {
                    let payload = sample.payload().to_bytes();
                    let value = if name == zmotor_msgs::keys::ERR_KEY { String::from_utf8_lossy(&payload).into_owned() } else { show(&payload) };
                    print_lines([format!("{name:<6} {value}")]);
                }
            }
            _ = tokio::signal::ctrl_c() => break,
        }
    }
    session.close().await?;
    Ok(ExitCode::SUCCESS)
}

fn schema(dir: &std::path::Path) -> Result<ExitCode, Error> {
    std::fs::create_dir_all(dir)?;
    for (name, schema) in zmotor_msgs::schema::message_schemas() {
        std::fs::write(dir.join(name), serde_json::to_string_pretty(&schema)? + "\n")?;
    }
    std::fs::write(
        dir.join("fields.json"),
        serde_json::to_string_pretty(&zmotor_msgs::schema::catalogue_json())? + "\n",
    )?;
    println!("wrote the schemas and fields.json to {}", dir.display());
    Ok(ExitCode::SUCCESS)
}
