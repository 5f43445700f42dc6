//! `zmotor-bench` (run as `zmotor bench`): measures command latency, scale, the load of the
//! EPICS figure, start-up, controllers, storms of writes, Channel Access and the jog deadman,
//! each beside its floor in the same run, and prints the figures; it asserts nothing. Nodes are
//! started as a user starts them (`zmotor launch FILE`); the floor is Zenoh alone, in processes
//! of this program (`zmotor-bench floor ...`). The engine's own cost per event is measured by
//! criterion: `cargo bench -p zmotor-core --bench engine`.

mod axes;
mod bench;
mod ca_bench;
mod controller_bench;
mod fast_readback;
mod floor;
mod process;
mod ros2_bench;
mod soak;
mod stats;

use clap::{Parser, Subcommand};
use process::Programs;
use std::path::PathBuf;
use std::process::ExitCode;

/// Any failure, as the user will read it.
type Error = Box<dyn std::error::Error + Send + Sync>;

#[derive(Parser)]
#[command(name = "zmotor bench", about = "Measure zmotor beside Zenoh's own floor, and print the figures")]
struct Cli {
    /// The `zmotor` whose nodes are measured (`zmotor bench` passes itself).
    #[arg(long, global = true)]
    zmotor: Option<PathBuf>,
    /// A run of seconds that only proves every part works.
    #[arg(long)]
    smoke: bool,
    /// Moves for the latency figures (default 2000).
    #[arg(long, value_parser = at_least_one)]
    moves: Option<usize>,
    /// Axis counts for the scale figures, comma-separated (default 1,100,1000,10000).
    #[arg(long, value_delimiter = ',', value_parser = at_least_one)]
    scales: Option<Vec<usize>>,
    /// Most axes set moving for the scale figures (default 2000; beyond, start and idle memory
    /// only).
    #[arg(long)]
    moving_up_to: Option<usize>,
    /// Measure only these parts, comma-separated (default: all).
    #[arg(long, value_delimiter = ',', value_enum)]
    parts: Option<Vec<Part>>,
    /// Seconds each storm of writes lasts (default 60).
    #[arg(long, value_parser = a_while)]
    storm: Option<f64>,
    /// Minutes the soak lasts (default 60); the soak runs only when named in --parts.
    #[arg(long, value_parser = a_while)]
    minutes: Option<f64>,
    #[command(subcommand)]
    floor: Option<FloorCommand>,
}

/// A count a figure is made of: at least one.
fn at_least_one(text: &str) -> Result<usize, String> {
    match text.parse::<usize>() {
        Ok(0) => Err("a figure needs at least one".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(e.to_string()),
    }
}

/// A length of time in the option's unit: more than 0, up to 10,080 (a week of minutes).
fn a_while(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(t) if t > 0.0 && t <= 10_080.0 => Ok(t),
        Ok(t) => Err(format!("{t} is not a length more than 0, up to 10080")),
        Err(e) => Err(e.to_string()),
    }
}

#[derive(Subcommand)]
enum FloorCommand {
    /// The floor's own processes (the benchmark starts them).
    #[command(subcommand, hide = true)]
    Floor(floor::Floor),
}

/// The parts of the benchmark.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Part {
    /// 1. command latency.
    Latency,
    /// 3. scale.
    Scale,
    /// 4. the load of the EPICS figure.
    EpicsLoad,
    /// 5. start-up.
    Startup,
    /// 6. controllers.
    Controllers,
    /// 7. a storm of writes.
    Writes,
    /// 8. Channel Access beside Zenoh.
    ChannelAccess,
    /// 9. the jog deadman.
    Holds,
    /// 10. ROS 2 joints beside zmotor's keys.
    Ros2,
    /// 11. the soak (only when named: it lasts --minutes).
    Soak,
    /// 12. fast readback: 16 axes at 1 kHz.
    FastReadback,
}

impl Part {
    /// What a run measures unless told: every part but the soak, which lasts an hour.
    const ALL: [Part; 10] = [
        Part::Latency,
        Part::Scale,
        Part::EpicsLoad,
        Part::Startup,
        Part::Controllers,
        Part::Writes,
        Part::ChannelAccess,
        Part::Holds,
        Part::Ros2,
        Part::FastReadback,
    ];
}

/// What a run measures.
#[derive(Clone, Debug)]
struct BenchOptions {
    /// Moves (and pings) for the latency figures.
    moves: usize,
    /// Commands run as processes for the "as a user runs it" figures.
    command_runs: usize,
    /// Axis counts for the scale figures.
    scales: Vec<usize>,
    /// Axes for the start-up figure.
    startup_axes: usize,
    /// Seconds each CPU/publication measurement lasts.
    window: f64,
    /// Most axes set moving for the scale figures; beyond, start and idle memory only.
    moving_up_to: usize,
    /// Axes under the load of the EPICS figure.
    epics_load_axes: usize,
    /// Seconds of request/reply round trips per controller protocol.
    controller_window: f64,
    /// Moves per controller protocol for the end-of-motion figure.
    controller_moves: usize,
    /// The parts measured.
    parts: Vec<Part>,
    /// Seconds each storm of writes lasts.
    storm: f64,
    /// One-step moves each way for the Channel Access figures.
    ca_moves: usize,
    /// Minutes the soak lasts.
    soak_minutes: f64,
    /// Seconds the fast readback is recorded.
    fast_readback_window: f64,
    /// Jogging clients killed for the deadman figure.
    holds: usize,
}

impl BenchOptions {
    fn full() -> Self {
        Self {
            moves: 2000,
            command_runs: 20,
            scales: vec![1, 100, 1000, 10_000],
            startup_axes: 10_000,
            window: 3.0,
            moving_up_to: 2000,
            epics_load_axes: 1000,
            controller_window: 2.0,
            controller_moves: 40,
            parts: Part::ALL.to_vec(),
            storm: 60.0,
            ca_moves: 100,
            soak_minutes: 60.0,
            fast_readback_window: 10.0,
            holds: 20,
        }
    }

    /// A run of seconds that only proves every part works.
    fn smoke() -> Self {
        Self {
            moves: 50,
            command_runs: 2,
            scales: vec![1, 10],
            startup_axes: 10,
            window: 0.5,
            moving_up_to: 10,
            epics_load_axes: 10,
            controller_window: 0.2,
            controller_moves: 2,
            parts: Part::ALL.into_iter().chain([Part::Soak]).collect(),
            storm: 1.0,
            ca_moves: 3,
            soak_minutes: 0.1,
            fast_readback_window: 0.5,
            holds: 2,
        }
    }
}

#[tokio::main]
async fn main() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "off".into()))
        .with_writer(std::io::stderr)
        .init();
    let result = match cli.floor {
        Some(FloorCommand::Floor(floor)) => floor::run(floor).await,
        // Stopped by a signal, the run is dropped, and with it the processes it started (each
        // killed when dropped): a node left running would go on moving its axes unwatched.
        None => tokio::select! {
            result = run(cli) => result,
            signal = zmotor_client::interrupted() => signal.map_err(Error::from).and(Err("interrupted; the processes it started are stopped".into())),
        },
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("zmotor bench: {e}");
            ExitCode::FAILURE
        }
    }
}

async fn run(cli: Cli) -> Result<(), Error> {
    let mut options = if cli.smoke { BenchOptions::smoke() } else { BenchOptions::full() };
    options.parts = cli.parts.unwrap_or(options.parts);
    options.storm = cli.storm.unwrap_or(options.storm);
    options.soak_minutes = cli.minutes.unwrap_or(options.soak_minutes);
    options.moves = cli.moves.unwrap_or(options.moves);
    options.scales = cli.scales.unwrap_or(options.scales);
    options.moving_up_to = cli.moving_up_to.unwrap_or(options.moving_up_to);
    let bench = std::env::current_exe()?;
    let zmotor = match cli.zmotor {
        Some(zmotor) => zmotor,
        None => bench.with_file_name("zmotor"),
    };
    if !zmotor.exists() {
        return Err(format!("{}: no zmotor to measure (give --zmotor, or run `zmotor bench`)", zmotor.display()).into());
    }
    let dir = tempfile::tempdir()?;
    let programs = Programs { zmotor, bench, dir: dir.path().to_path_buf() };
    println!(
        "zmotor bench: {} moves, scales {:?}, start-up of {} axes; nodes by {}",
        options.moves,
        options.scales,
        options.startup_axes,
        programs.zmotor.display()
    );
    for part in &options.parts {
        match part {
            Part::Latency => bench::latency_part(&programs, &options).await?,
            Part::Scale => bench::scale_part(&programs, &options).await?,
            Part::EpicsLoad => bench::epics_load_part(&programs, &options).await?,
            Part::Startup => bench::startup_part(&programs, &options).await?,
            Part::Controllers => controllers_part(&programs, &options).await?,
            Part::Writes => bench::writes_part(&programs, &options).await?,
            Part::ChannelAccess => channel_access_part(&programs, &options).await?,
            Part::Holds => bench::holds_part(&programs, &options).await?,
            Part::Ros2 => ros2_bench::ros2_part(&programs, &options).await?,
            Part::Soak => soak::soak_part(&programs, &options).await?,
            Part::FastReadback => fast_readback::fast_readback_part(&programs, &options).await?,
        }
    }
    Ok(())
}

async fn controllers_part(programs: &Programs, options: &BenchOptions) -> Result<(), Error> {
    println!("\n6. controllers: each protocol against its emulator (zmotor-sim-controller's, in this process)");
    println!("   through the production controller layer, over the ready launch file's line (TCP on");
    println!("   127.0.0.1, or a pseudo-terminal at the controller's baud rate);");
    println!("   requests/s: requests written a second while status refreshes of one axis follow each other;");
    println!("   poll: the controller's own full poll of 1 axis and of 8 (all of a smaller controller), median;");
    println!("   end → DMOV 1: the vendor's ready launch file in a node process (`zmotor launch`), a client");
    println!("   here: from the emulated stage's end of motion to DMOV 1 at the client, µs, beside the");
    println!("   moving-poll period");
    println!(
        "   {:<16} {:<18} {:>12} {:>10} {:>14} {:>10} {:>10} {:>10} {:>8}",
        "", "line", "requests/s", "poll 1", "poll n", "end→DMOV1 p50", "p90", "p99", "poll"
    );
    for f in controller_bench::run(programs, options.controller_window, options.controller_moves).await? {
        println!(
            "   {:<16} {:<18} {:>12.0} {:>8.0} µs {:>2} {:>8.0} µs {:>13.0} {:>10.0} {:>10.0} {:>5.0} ms",
            f.name,
            f.line,
            f.round_trips_per_s,
            f.poll_one.as_secs_f64() * 1e6,
            f.poll_many.0,
            f.poll_many.1.as_secs_f64() * 1e6,
            f.end_to_done.p50,
            f.end_to_done.p90,
            f.end_to_done.p99,
            f.moving_poll.as_secs_f64() * 1e3
        );
    }
    Ok(())
}

async fn channel_access_part(programs: &Programs, options: &BenchOptions) -> Result<(), Error> {
    println!("\n8. Channel Access beside Zenoh: the demo's axis in a node process whose launch file runs the");
    println!("   gateway ([channel_access]); here a CA client of the gateway's own codec (as caget and `caput -c`");
    println!("   send), a Zenoh client, and pyepics (libca, a stock client) in a process of its own, in turn:");
    println!("   {} reads of RBV, {} one-step (1 µm) moves answered at their end; µs", options.moves, options.ca_moves);
    let f = ca_bench::run(programs, options.moves, options.ca_moves).await?;
    let line = |what: &str, [p50, p90, p99]: [f64; 3]| {
        println!("   {what:<34} p50 {p50:>9.0}  p90 {p90:>9.0}  p99 {p99:>9.0}");
    };
    let three = |p: &stats::Percentiles| [p.p50, p.p90, p.p99];
    line("caget RBV (CA read, own codec)", three(&f.ca_read));
    line("Zenoh get RBV", three(&f.zenoh_read));
    match &f.pyepics {
        Ok(stock) => line("pyepics PV.get RBV (no monitor)", stock.read),
        Err(why) => println!("   pyepics: not measured: {why}"),
    }
    line("caput -c VAL, one step (own codec)", three(&f.ca_move));
    line("Zenoh ?wait VAL, one step", three(&f.zenoh_move));
    if let Ok(stock) = &f.pyepics {
        line("pyepics PV.put(wait=True), one step", stock.move_);
    }
    Ok(())
}
