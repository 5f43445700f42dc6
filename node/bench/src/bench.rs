//! The parts of `zmotor bench` that measure nodes over Zenoh: command latency, scale, the load
//! of the EPICS figure, start-up, storms of writes and the jog deadman. Every node is started
//! as a user starts it (`zmotor launch FILE`), and every figure is printed beside its floor,
//! measured in the same run: Zenoh alone, with no zmotor code on its path.

use crate::axes::{bench_axis, bench_axis_index, bench_key};
use crate::floor::{PING, PONG};
use crate::process::{client_when_ready, wait_for_axes, Process, Programs};
use crate::stats::{cpu_seconds, percent, rss_kb, Percentiles};
use crate::{BenchOptions, Error};
use std::collections::HashSet;
use std::fmt::Write as _;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering::Relaxed};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};
use zenoh::bytes::Encoding;
use zenoh::qos::CongestionControl;
use zenoh::sample::Sample;
use zenoh::Session;
use zmotor_client::{free_local_endpoint, Client, WriteOptions, WriteOutcome};
use zmotor_core::{Axis, Instant as Virtual};
use zmotor_deploy::{AutosaveSection, Launch, LaunchFile};
use zmotor_msgs::decode_cbor_value;
use zmotor_msgs::{keys, Field, KeyLayout, Value};

/// A launch file of `n` simulated axes b0, b1, … whose moves take real time (10 mm/s),
/// read back `readback_hz` times a second while moving; no autosave.
pub(crate) fn bench_launch(n: usize, readback_hz: f64) -> String {
    bench_launch_at(n, |_| readback_hz)
}

/// As `bench_launch`, axis `i` read back `readback_hz(i)` times a second.
pub(crate) fn bench_launch_at(n: usize, readback_hz: impl Fn(usize) -> f64) -> String {
    let mut text = String::from("[autosave]\nenabled = false\n");
    for i in 0..n {
        let (name, hz) = (bench_axis(i), readback_hz(i));
        let _ = write!(
            text,
            "[[axis]]\nname = \"{name}\"\nreadback_rate = {hz}\n[axis.fields]\nMRES = 0.001\nVELO = 10\nACCL = 0.1\n"
        );
    }
    text
}

/// The demo's launch file, as a user starts it.
const DEMO: &str = include_str!("../../../launch/sim-axis.toml");

/// A launch file of `n` copies of the demo's axis (launch/sim-axis.toml, as shipped), named
/// b0, b1, …; no autosave.
fn demo_launch(n: usize) -> Result<String, Error> {
    let demo = Launch::parse(DEMO)?;
    let axis = demo.file.axes.first().ok_or("the demo has an axis")?;
    let axes = (0..n).map(|i| zmotor_deploy::AxisSection { name: bench_axis(i), ..axis.clone() }).collect();
    let autosave = Some(AutosaveSection { enabled: false, ..AutosaveSection::default() });
    let file = LaunchFile { axes, autosave, ..LaunchFile::default() };
    Ok(Launch::from_file("the benchmark's demo axes", file)?.to_toml())
}

/// The targets the latency figures alternate between, mm.
const LATENCY_TARGETS: [f64; 2] = [0.01, 0.02];

/// How long the demo axis's latency move lasts on its simulator, in virtual time: write VAL
/// from one target to the other, run until DMOV 1.
fn demo_motion() -> Result<Duration, Error> {
    let launch = Launch::parse(DEMO)?;
    let plan = launch.deployment(None)?.contents.plans.remove(0);
    let mut axis = plan.build(Virtual::ZERO, None);
    let at_rest = |axis: &mut Axis| {
        for _ in 0..100_000 {
            if !axis.is_busy() {
                break;
            }
            let t = axis.poll_timeout().expect("a simulated axis is polled");
            axis.handle_timeout(t);
        }
        axis.now()
    };
    axis.write(Virtual::ZERO, Field::VAL, &Value::Float(LATENCY_TARGETS[0]))?;
    let from = at_rest(&mut axis);
    axis.write(from, Field::VAL, &Value::Float(LATENCY_TARGETS[1]))?;
    Ok(at_rest(&mut axis) - from)
}

/// Until `subscriber` hears from the node (its subscription reached the node): confirmed moves
/// of axis `i` between the latency targets.
pub(crate) async fn until_heard(
    client: &Client,
    axis: &str,
    subscriber: &zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<Sample>>,
) -> Result<(), Error> {
    for attempt in 0..100 {
        let target = LATENCY_TARGETS[attempt % 2].to_string();
        let options = WriteOptions::waiting(Duration::from_secs(10));
        match client.write(axis, Field::VAL, target, options).await?.outcome().await {
            WriteOutcome::Completed(_) => {}
            other => return Err(format!("{axis}: {other}").into()),
        }
        if subscriber.try_recv().ok().flatten().is_some() {
            while subscriber.try_recv().ok().flatten().is_some() {}
            return Ok(());
        }
    }
    Err(format!("a subscriber of {axis} heard nothing after 100 moves").into())
}

/// A publisher on `key` once a subscriber of it is known (bounded: 10 s).
async fn until_matched(session: &Session, key: &'static str) -> Result<zenoh::pubsub::Publisher<'static>, Error> {
    let publisher = session.declare_publisher(key).congestion_control(CongestionControl::Block).await?;
    for _ in 0..1000 {
        if publisher.matching_status().await?.matching() {
            return Ok(publisher);
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    Err(format!("no subscriber of {key} after 10 s").into())
}

pub(crate) async fn latency_part(programs: &Programs, options: &BenchOptions) -> Result<(), Error> {
    println!("\n1. command latency: the demo's axis (launch/sim-axis.toml: physical simulator, readback 10 Hz) in");
    println!("   a node process started by `zmotor launch`, a client in this one, TCP on 127.0.0.1; moves of 0.01 mm;");
    println!("   beside Zenoh's round trip to an echo in a process of its own (z_ping/z_pong style); µs");
    let (_node, endpoint) = programs.launch("latency", &demo_launch(1)?)?;
    let echo = Echo::start(programs).await?;
    let client = client_when_ready(&endpoint).await?;
    wait_for_axes(client.session(), 1, Duration::from_secs(20)).await?;
    let session = client.session();
    let dmov = session.declare_subscriber(bench_key(0, Field::DMOV)).await?;
    until_heard(&client, &bench_axis(0), &dmov).await?;
    let val = session.declare_publisher(bench_key(0, Field::VAL)).encoding(Encoding::TEXT_PLAIN).await?;
    let moves = options.moves;
    let (mut to_dmov0, mut to_dmov1, mut rtt) = (Vec::new(), Vec::new(), Vec::new());
    // Moves and pings alternate, so both see the same conditions on a shared machine; the
    // first tenth warms up connections and caches.
    for i in 0..moves + moves / 10 {
        let target = LATENCY_TARGETS[i % 2].to_string();
        let start = Instant::now();
        val.put(target).await?;
        let mut zero = None;
        loop {
            let sample = tokio::time::timeout(Duration::from_secs(5), dmov.recv_async()).await??;
            match decode_cbor_value(&sample.payload().to_bytes()) {
                Ok(Value::Int(0)) => zero = Some(start.elapsed()),
                Ok(Value::Int(1)) if zero.is_some() => break,
                _ => {}
            }
        }
        let moved = start.elapsed();
        let answered = echo.round_trip().await;
        if i >= moves / 10 {
            to_dmov0.push(zero.expect("DMOV 0 came first"));
            to_dmov1.push(moved);
            rtt.extend(answered);
        }
    }
    let (dmov0, dmov1, rtt) = (Percentiles::of(to_dmov0), Percentiles::of(to_dmov1), Percentiles::of(rtt));
    let motion_us = demo_motion()?.as_secs_f64() * 1e6;
    println!("   {:<48} {:>9} {:>9} {:>9}", "", "p50", "p90", "p99");
    for (name, p) in [
        ("put VAL → DMOV 0 at the client", &dmov0),
        ("put VAL → DMOV 1 at the client", &dmov1),
        ("Zenoh round trip to an echo process", &rtt),
    ] {
        println!("   {name:<48} {:>9.1} {:>9.1} {:>9.1}", p.p50, p.p90, p.p99);
    }
    println!("   {:<48} {:>9.1}", "the motion itself (simulator, virtual time)", motion_us);
    println!(
        "   DMOV 0 / Zenoh RTT (p50): {:.2};  DMOV 1 − motion − RTT (p50): {:.0} µs",
        dmov0.p50 / rtt.p50,
        dmov1.p50 - motion_us - rtt.p50
    );
    // As a user runs the demo: one command a move, each a process of its own.
    let runs = options.command_runs;
    let (mut puts, mut gets) = (Vec::new(), Vec::new());
    for i in 0..runs {
        let target = LATENCY_TARGETS[i % 2].to_string();
        let start = Instant::now();
        let put = programs.zmotor(&["put", "b0", "VAL", &target, "--wait", "--connect", &endpoint]).status()?;
        if !put.success() {
            return Err(format!("zmotor put b0 VAL {target} --wait failed").into());
        }
        puts.push(start.elapsed());
        let start = Instant::now();
        let mut get = std::process::Command::new(&programs.bench);
        let get = get.args(["floor", "get", "--connect", &echo.endpoint]).env("RUST_LOG", "off").status()?;
        if !get.success() {
            return Err("the floor's one-shot get failed".into());
        }
        gets.push(start.elapsed());
    }
    let (puts, gets) = (Percentiles::of(puts), Percentiles::of(gets));
    println!("   as a user runs it, {runs} commands each, a process per command, ms:");
    println!(
        "   {:<48} {:>9.1} {:>9.1} {:>9.1}",
        "zmotor put b0 VAL x --wait (start to exit)",
        puts.p50 / 1e3,
        puts.p90 / 1e3,
        puts.max / 1e3
    );
    println!(
        "   {:<48} {:>9.1} {:>9.1} {:>9.1}",
        "a Zenoh client process: open, one get, close",
        gets.p50 / 1e3,
        gets.p90 / 1e3,
        gets.max / 1e3
    );
    println!("   (p50, p90, max; the move itself lasts {:.1} ms)", motion_us / 1e3);
    println!("\n2. engine cost per event: measured by criterion, `cargo bench -p zmotor-core --bench engine`");
    Ok(())
}

/// Zenoh's round trip to an echo in a process of its own (z_ping/z_pong style): the floor of
/// the latency figures.
pub(crate) struct Echo {
    _process: Process,
    pub(crate) endpoint: String,
    _client: Client,
    ping: zenoh::pubsub::Publisher<'static>,
    pong: zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<Sample>>,
}

impl Echo {
    pub(crate) async fn start(programs: &Programs) -> Result<Self, Error> {
        let endpoint = free_local_endpoint()?;
        let process = programs.floor(&["echo", "--listen", &endpoint])?;
        let client = client_when_ready(&endpoint).await?;
        let pong = client.session().declare_subscriber(PONG).await?;
        let ping = client.session().declare_publisher(PING).congestion_control(CongestionControl::Block).await?;
        Ok(Self { _process: process, endpoint, _client: client, ping, pong })
    }

    /// One ping's round trip; none when the pong did not come (the first pings may come
    /// before the echo's subscription reached it).
    pub(crate) async fn round_trip(&self) -> Option<Duration> {
        let start = Instant::now();
        self.ping.put(vec![0u8; 8]).await.ok()?;
        tokio::time::timeout(Duration::from_millis(500), self.pong.recv_async()).await.ok()?.ok()?;
        Some(start.elapsed())
    }
}

/// Samples a subscriber received: all of them, RBV alone, DMOV 1 alone; and which axes sent a
/// readback.
struct Received {
    all: AtomicU64,
    rbv: AtomicU64,
    done: AtomicU64,
    /// Bench axis `i` sent a readback (it moves: an axis whose write was lost sends none).
    heard: Vec<AtomicBool>,
    /// How many have.
    heard_count: AtomicUsize,
    /// When the last of them was first heard.
    all_heard_at: OnceLock<Instant>,
}

impl Received {
    fn new(axes: usize) -> Self {
        let heard = (0..axes).map(|_| AtomicBool::new(false)).collect();
        let (heard_count, all_heard_at) = (AtomicUsize::new(0), OnceLock::new());
        Self {
            all: AtomicU64::new(0),
            rbv: AtomicU64::new(0),
            done: AtomicU64::new(0),
            heard,
            heard_count,
            all_heard_at,
        }
    }

    /// How many axes sent a readback.
    fn axes_heard(&self) -> usize {
        self.heard.iter().filter(|h| h.load(Relaxed)).count()
    }

    fn heard_from(&self, key: &str) {
        let axis = KeyLayout::default().axis_chunk(key).and_then(bench_axis_index);
        if let Some(heard) = axis.and_then(|i| self.heard.get(i)) {
            if !heard.swap(true, Relaxed) && self.heard_count.fetch_add(1, Relaxed) + 1 == self.heard.len() {
                let _ = self.all_heard_at.set(Instant::now());
            }
        }
    }

    fn read(&self) -> [u64; 3] {
        [self.all.load(Relaxed), self.rbv.load(Relaxed), self.done.load(Relaxed)]
    }

    fn count(&self, sample: &Sample) {
        self.all.fetch_add(1, Relaxed);
        let last_chunk = sample.key_expr().as_str().rsplit('/').next();
        if last_chunk == Some(keys::READBACK_KEY) {
            // A bundle carries one RBV sample.
            self.rbv.fetch_add(1, Relaxed);
            self.heard_from(sample.key_expr().as_str());
            return;
        }
        match last_chunk.and_then(Field::from_name) {
            Some(Field::RBV) => {
                self.rbv.fetch_add(1, Relaxed);
                self.heard_from(sample.key_expr().as_str());
            }
            Some(Field::DMOV) if decode_cbor_value(&sample.payload().to_bytes()) == Ok(Value::Int(1)) => {
                self.done.fetch_add(1, Relaxed);
            }
            _ => {}
        }
    }
}

/// What the subscriber of a publishing measurement watches.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Watch {
    /// Every key of every axis (`motor/**`): every field change the node publishes.
    Everything,
    /// RBV and DMOV of every axis, as a display or a robot stack following positions would.
    ReadbackAndDone,
    /// The readback bundle of every axis (`motor/*/@readback`): an axis's state in one sample.
    Bundles,
}

impl Watch {
    fn keys(self) -> Vec<String> {
        let layout = KeyLayout::default();
        match self {
            Watch::Everything => vec![layout.everything()],
            Watch::ReadbackAndDone => vec![layout.field("*", Field::RBV), layout.field("*", Field::DMOV)],
            Watch::Bundles => vec![layout.readback("*")],
        }
    }
}

/// How the axes of a publishing measurement move.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Load {
    /// One long move each (10 mm/s for 1000 mm), readback at 100 Hz: the scale figures.
    LongMoves,
    /// The load of the EPICS figure: 4 mm moves (0.5 s, so ~5 readbacks each) commanded to the
    /// axes in turn, `moves_per_s` in all, readback at 10 Hz.
    ShortMoves { moves_per_s: f64 },
}

impl Load {
    fn readback_hz(self) -> f64 {
        match self {
            Load::LongMoves => 100.0,
            Load::ShortMoves { .. } => 10.0,
        }
    }
}

/// Who publishes in a publishing measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Publisher {
    /// A node started by `zmotor launch`.
    Node,
    /// Zenoh alone publishing what the node publishes (`zmotor-bench floor publish`).
    ZenohAlone,
    /// Zenoh alone, its keys new at the command as a node's are at its axes' first moves
    /// (`floor publish --keys-new-at-go`): the floor of the first moves' cost.
    ZenohAloneKeysNew,
}

/// Moves per second and axis in the EPICS figure (1,600 moves/s on 1,000 axes).
const EPICS_MOVES_PER_AXIS_PER_S: f64 = 1.6;
/// Longest wait for the load to settle before the CPU window opens.
const SETTLE_LIMIT: Duration = Duration::from_secs(45);

/// A process publishing readbacks for every axis, seen by one subscriber in this one.
struct Publishing {
    /// The publishing process's CPU, as a fraction of one core.
    cpu: f64,
    /// Samples per second the subscriber received.
    publications_per_s: f64,
    /// RBV samples per axis per second the subscriber received.
    rbv_per_axis_per_s: f64,
    /// Moves per second the subscriber saw end (DMOV 1).
    moves_per_s: f64,
    /// Axes whose readback the subscriber got at all (each was commanded a move).
    axes_heard: usize,
    /// From the first command until every axis had been heard: the cost of the first moves
    /// (a key's first publication), apart from the rate the subscriber takes afterwards.
    all_heard_after: Option<Duration>,
    /// From the first command to the measurement window: until the readbacks (long moves) or
    /// the ends of moves (short moves) arrived at 90 % of their rate. None when `SETTLE_LIMIT`
    /// passed first.
    settled_after: Option<Duration>,
}

/// Command 4 mm moves to axes b0 … b(n-1) in turn, back and forth, `moves_per_s` in all.
async fn command_short_moves(session: Session, n: usize, moves_per_s: f64) -> Result<(), Error> {
    const PERIOD: Duration = Duration::from_millis(10);
    let mut ticks = tokio::time::interval(PERIOD);
    let (mut due, mut next) = (0.0, 0usize);
    loop {
        ticks.tick().await;
        due += moves_per_s * PERIOD.as_secs_f64();
        while due >= 1.0 {
            due -= 1.0;
            let (axis, outward) = (next % n, (next / n).is_multiple_of(2));
            next += 1;
            let target = if outward { "4" } else { "0" };
            session.put(bench_key(axis, Field::VAL), target).encoding(Encoding::TEXT_PLAIN).await?;
        }
    }
}

/// `n` axes moving under `load` in a node process (or Zenoh alone publishing as much): its
/// CPU and what one subscriber receives, over `window` seconds once the load has settled (or
/// `SETTLE_LIMIT` has passed).
async fn publishing(
    programs: &Programs,
    n: usize,
    window: f64,
    publisher: Publisher,
    load: Load,
    watch: Watch,
) -> Result<Publishing, Error> {
    let (process, endpoint): (Process, String) = match publisher {
        Publisher::Node => programs.launch("publishing", &bench_launch(n, load.readback_hz()))?,
        Publisher::ZenohAlone | Publisher::ZenohAloneKeysNew => {
            let endpoint = free_local_endpoint()?;
            let (axes, rate) = (n.to_string(), load.readback_hz().to_string());
            let mut args = vec!["publish", "--listen", &endpoint, "--axes", &axes, "--rate", &rate];
            if publisher == Publisher::ZenohAloneKeysNew {
                args.push("--keys-new-at-go");
            }
            (programs.floor(&args)?, endpoint)
        }
    };
    let pid = process.pid();
    let client = client_when_ready(&endpoint).await?;
    let session = client.session().clone();
    if publisher == Publisher::Node {
        wait_for_axes(&session, n, Duration::from_secs(120)).await?;
    }
    let received = Arc::new(Received::new(n));
    let mut subscribers = Vec::new();
    for key in watch.keys() {
        let counter = received.clone();
        subscribers.push(session.declare_subscriber(key).callback(move |sample| counter.count(&sample)).await?);
    }
    if publisher == Publisher::Node {
        // The subscription has reached the node once a confirmed write's post comes back.
        let probe = session.declare_subscriber(bench_key(0, Field::VAL)).await?;
        until_heard(&client, &bench_axis(0), &probe).await?;
    }
    let go = match publisher {
        Publisher::ZenohAloneKeysNew => Some(until_matched(&session, crate::floor::GO).await?),
        _ => None,
    };
    let settling = Instant::now();
    let commander = match (publisher, load) {
        (Publisher::ZenohAlone, _) => None,
        (Publisher::ZenohAloneKeysNew, _) => {
            go.ok_or("no go publisher")?.put(Vec::<u8>::new()).await?;
            None
        }
        (Publisher::Node, Load::LongMoves) => {
            for i in 0..n {
                session.put(bench_key(i, Field::VAL), "1000").encoding(Encoding::TEXT_PLAIN).await?;
            }
            None
        }
        (Publisher::Node, Load::ShortMoves { moves_per_s }) => {
            Some(tokio::spawn(command_short_moves(session.clone(), n, moves_per_s)))
        }
    };
    // Readbacks (long moves) or ends of moves (short moves) arrive at 90 % of their rate.
    let settled = |before: [u64; 3], after: [u64; 3]| match load {
        Load::LongMoves => (after[1] - before[1]) as f64 / 0.5 >= 0.9 * n as f64 * load.readback_hz(),
        Load::ShortMoves { moves_per_s } => (after[2] - before[2]) as f64 / 0.5 >= 0.9 * moves_per_s,
    };
    // Two half-seconds in a row, so a burst in the middle of the ramp does not pass for it.
    let (mut settled_after, mut in_a_row) = (None, 0);
    while settled_after.is_none() && settling.elapsed() < SETTLE_LIMIT {
        let before = received.read();
        tokio::time::sleep(Duration::from_millis(500)).await;
        in_a_row = if settled(before, received.read()) { in_a_row + 1 } else { 0 };
        if in_a_row == 2 {
            settled_after = Some(settling.elapsed());
        }
    }
    let (cpu0, [all0, rbv0, done0], t0) = (cpu_seconds(&pid), received.read(), Instant::now());
    tokio::time::sleep(Duration::from_secs_f64(window)).await;
    let elapsed = t0.elapsed().as_secs_f64();
    let cpu = (cpu_seconds(&pid) - cpu0) / elapsed;
    let [all1, rbv1, done1] = received.read();
    if let Some(commander) = commander {
        commander.abort();
        // Finished before the abort: it met an error.
        if let Ok(Err(e)) = commander.await {
            return Err(e);
        }
    }
    drop(subscribers);
    session.close().await?;
    Ok(Publishing {
        cpu,
        publications_per_s: (all1 - all0) as f64 / elapsed,
        rbv_per_axis_per_s: (rbv1 - rbv0) as f64 / elapsed / n as f64,
        moves_per_s: (done1 - done0) as f64 / elapsed,
        axes_heard: received.axes_heard(),
        all_heard_after: received.all_heard_at.get().map(|at| at.saturating_duration_since(settling)),
        settled_after,
    })
}

fn seconds(settled: Option<Duration>) -> String {
    settled.map_or_else(|| format!("> {}", SETTLE_LIMIT.as_secs()), |d| format!("{:.1}", d.as_secs_f64()))
}

/// When the last axis was first heard, if it was.
fn all_heard(after: Option<Duration>) -> String {
    after.map_or_else(|| "not all".to_string(), |d| format!("all in {:.1} s", d.as_secs_f64()))
}

/// A node process of `n` idle axes: from its start to every axis answering, and its memory then.
async fn fresh_node(programs: &Programs, n: usize) -> Result<(Duration, f64), Error> {
    let start = Instant::now();
    let (node, endpoint) = programs.launch("fresh", &bench_launch(n, 100.0))?;
    let client = client_when_ready(&endpoint).await?;
    wait_for_axes(client.session(), n, Duration::from_secs(120)).await?;
    let answering = start.elapsed();
    // Let what the start allocated settle.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let rss = rss_kb(&node.pid());
    client.session().close().await?;
    Ok((answering, rss))
}

pub(crate) async fn scale_part(programs: &Programs, options: &BenchOptions) -> Result<(), Error> {
    println!("\n3. scale: N idle axes in a fresh node process (`zmotor launch`): its start, to every axis answering;");
    println!(
        "   its memory per axis beside a node of one axis. Then, up to {} axes, every axis moving with",
        options.moving_up_to
    );
    println!(
        "   readback at {} Hz, one subscriber here: of every key (motor/**), then of RBV and DMOV only; then",
        Load::LongMoves.readback_hz()
    );
    println!("   Zenoh alone publishing what the node publishes, no record (its keys made before the subscriber");
    println!(
        "   comes, then new at the command as a node's first moves make them); then the node with a subscriber of the"
    );
    println!("   readback bundles (motor/*/@readback, one sample per poll). Settled: from the commands to all");
    println!("   readbacks flowing (the CPU window opens then).");
    let (_, one_axis_kb) = fresh_node(programs, 1).await?;
    println!("   a node of 1 axis: {:.1} MB resident", one_axis_kb / 1024.0);
    for &n in &options.scales {
        let (start, rss) = fresh_node(programs, n).await?;
        let per_axis =
            if n > 1 { format!("{:.1} KB per idle axis", (rss - one_axis_kb) / (n - 1) as f64) } else { String::new() };
        println!("   {n:>6} axes: start {:.2} s, {:.1} MB resident, {per_axis}", start.as_secs_f64(), rss / 1024.0);
        if n > options.moving_up_to {
            println!("      moving: not measured (beyond --moving-up-to)");
            continue;
        }
        let mut rows = Vec::new();
        for (who, publisher, watch) in [
            ("node, subscriber of every key", Publisher::Node, Watch::Everything),
            ("node, subscriber of RBV and DMOV", Publisher::Node, Watch::ReadbackAndDone),
            ("Zenoh alone, every key", Publisher::ZenohAlone, Watch::Everything),
            ("Zenoh alone, keys new at the command", Publisher::ZenohAloneKeysNew, Watch::Everything),
            ("node, subscriber of the bundles", Publisher::Node, Watch::Bundles),
        ] {
            let p = publishing(programs, n, options.window, publisher, Load::LongMoves, watch).await?;
            println!(
                "      {who:<36} CPU {:>6}  {:>8.0} samples/s  {:>5.1} RBV/axis/s  settled {} s  {} of {n} axes heard, {}",
                percent(p.cpu),
                p.publications_per_s,
                p.rbv_per_axis_per_s,
                seconds(p.settled_after),
                p.axes_heard,
                all_heard(p.all_heard_after)
            );
            rows.push(p);
        }
        if let [everything, readback, alone, alone_keys_new, _] = &rows[..] {
            print_scale_targets(n, everything, readback, [alone, alone_keys_new]);
        }
    }
    Ok(())
}

/// The targets of the scale figures (issue 26), beside what was measured.
fn print_scale_targets(n: usize, everything: &Publishing, readback: &Publishing, [alone, keys_new]: [&Publishing; 2]) {
    let met = |ok: bool| if ok { "met" } else { "MISSED" };
    let delivered = everything.rbv_per_axis_per_s.min(readback.rbv_per_axis_per_s);
    // Beside each, the floor's own figure of the same run: where Zenoh alone misses it too, the
    // machine does.
    println!(
        "      targets: every RBV delivered, >= 99 per axis/s: {:.1} {} (Zenoh alone {:.1}); node under one core: {} {};",
        delivered,
        met(delivered >= 99.0),
        alone.rbv_per_axis_per_s,
        percent(everything.cpu),
        met(everything.cpu < 1.0)
    );
    println!(
        "               node <= 1.1 x Zenoh alone ({}): {:.2} x {}; RBV and DMOV cheaper than every key: {} < {} {}",
        percent(alone.cpu),
        everything.cpu / alone.cpu,
        met(everything.cpu <= 1.1 * alone.cpu),
        percent(readback.cpu),
        percent(everything.cpu),
        met(readback.cpu < everything.cpu)
    );
    let settled = everything.settled_after.zip(readback.settled_after).map(|(a, b)| a.max(b));
    println!(
        "               first moves settled in < 2 s: {} s {} (axes heard with every key: {}; Zenoh alone, keys new at the command: settled {} s, {})",
        seconds(settled),
        met(settled.is_some_and(|s| s < Duration::from_secs(2))),
        all_heard(everything.all_heard_after),
        seconds(keys_new.settled_after),
        all_heard(keys_new.all_heard_after)
    );
    // Each axis was commanded by a plain put, droppable as a stock client's: one never heard
    // from never got its write.
    let heard = everything.axes_heard.min(readback.axes_heard);
    println!("               every axis's write handled (its readback heard): {heard} of {n} {}", met(heard == n));
}

pub(crate) async fn epics_load_part(programs: &Programs, options: &BenchOptions) -> Result<(), Error> {
    let n = options.epics_load_axes;
    let load = Load::ShortMoves { moves_per_s: n as f64 * EPICS_MOVES_PER_AXIS_PER_S };
    println!(
        "\n4. the load of the EPICS figure: {n} axes, readback {} Hz, 4 mm moves commanded at {:.0}/s in all",
        load.readback_hz(),
        n as f64 * EPICS_MOVES_PER_AXIS_PER_S
    );
    println!("   (the given IOC: 45 % CPU for 1,600 moves/s and 8,300 RBV events/s on 1,000 axes)");
    let p = publishing(programs, n, options.window, Publisher::Node, load, Watch::Everything).await?;
    println!(
        "   node CPU {}   moves/s ended {:.0}   RBV/s {:.0}   publications/s {:.0}   settled after {} s",
        percent(p.cpu),
        p.moves_per_s,
        p.rbv_per_axis_per_s * n as f64,
        p.publications_per_s,
        seconds(p.settled_after)
    );
    Ok(())
}

pub(crate) async fn startup_part(programs: &Programs, options: &BenchOptions) -> Result<(), Error> {
    let n = options.startup_axes;
    println!("\n5. start-up of {n} demo axes in a node process (`zmotor launch`), as a client sees it: a client");
    println!("   getting every axis; then, a node started afresh, a client watching the axes' liveliness tokens");
    println!("   (`motor/*`, with history), each connected at once");
    let start = Instant::now();
    let (node, endpoint) = programs.launch("startup", &demo_launch(n)?)?;
    let client = client_when_ready(&endpoint).await?;
    wait_for_axes(client.session(), n, Duration::from_secs(120)).await?;
    let answering = start.elapsed();
    drop((client, node));
    let start = Instant::now();
    let (_node, endpoint) = programs.launch("startup", &demo_launch(n)?)?;
    let client = client_when_ready(&endpoint).await?;
    let node_tokens = TokenWatch::declare(client.session(), n).await?.all_seen(start).await?;
    println!("   process start → every axis answers get: {:.2} s", answering.as_secs_f64());
    println!("   process start → every axis's liveliness token seen: {:.2} s", node_tokens.as_secs_f64());
    // The floor: a process of Zenoh alone declaring as many tokens, watched the same way.
    let start = Instant::now();
    let endpoint = free_local_endpoint()?;
    let _floor = programs.floor(&["tokens", "--listen", &endpoint, "--axes", &n.to_string()])?;
    let client = client_when_ready(&endpoint).await?;
    let floor_tokens = TokenWatch::declare(client.session(), n).await?.all_seen(start).await?;
    println!(
        "   Zenoh alone, a process declaring {n} tokens: process start → every token seen: {:.2} s",
        floor_tokens.as_secs_f64()
    );
    let (declared, publishers) = zenoh_declarations(n).await?;
    println!(
        "   Zenoh alone, one session in this process: {n} liveliness tokens declared in {:.2} s; {n} publishers in {:.2} s",
        declared.as_secs_f64(),
        publishers.as_secs_f64()
    );
    let met = if node_tokens < Duration::from_secs(2) { "met" } else { "MISSED" };
    println!(
        "   target: every token seen in < 2 s: {:.2} s {met} (Zenoh alone {:.2} s)",
        node_tokens.as_secs_f64(),
        floor_tokens.as_secs_f64()
    );
    Ok(())
}

/// A client's liveliness subscriber of every axis, with the tokens already there: how a client
/// watching axes appear sees them. Its callback notes the tokens as they come (a channel left
/// unread while the client gets the axes would fill and hold the client's receiving thread).
struct TokenWatch {
    _subscriber: zenoh::pubsub::Subscriber<()>,
    all_seen: Arc<std::sync::OnceLock<Instant>>,
}

impl TokenWatch {
    /// Watch until `n` distinct tokens were seen.
    async fn declare(session: &Session, n: usize) -> Result<Self, Error> {
        let all_seen = Arc::new(std::sync::OnceLock::new());
        let (seen, done) = (std::sync::Mutex::new(HashSet::new()), all_seen.clone());
        let subscriber = session
            .liveliness()
            .declare_subscriber(KeyLayout::default().axis("*"))
            .history(true)
            .callback(move |token| {
                if token.kind() == zenoh::sample::SampleKind::Put {
                    let mut seen = seen.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
                    seen.insert(token.key_expr().as_str().to_string());
                    if seen.len() >= n {
                        let _ = done.set(Instant::now());
                    }
                }
            })
            .await?;
        Ok(Self { _subscriber: subscriber, all_seen })
    }

    /// How long after `start` the last token was seen (within two minutes).
    async fn all_seen(self, start: Instant) -> Result<Duration, Error> {
        while start.elapsed() < Duration::from_secs(120) {
            if let Some(at) = self.all_seen.get() {
                return Ok(at.duration_since(start));
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        Err("not every liveliness token was seen within 120 s".into())
    }
}

/// Zenoh alone, in this process: how long one session takes to declare `n` liveliness tokens,
/// and `n` publishers, on keys shaped like the axes'. The floor under the node's start-up and
/// under the first moves of many axes (a publisher per field posted again and again).
async fn zenoh_declarations(n: usize) -> Result<(Duration, Duration), Error> {
    let config = zmotor_deploy::ZenohConfig { listen: vec![free_local_endpoint()?], ..Default::default() };
    let session = zmotor_client::open(&config).await?;
    let layout = KeyLayout::default();
    let start = Instant::now();
    let mut tokens = Vec::with_capacity(n);
    for i in 0..n {
        tokens.push(session.liveliness().declare_token(layout.axis(&bench_axis(i))).await?);
    }
    let tokens_took = start.elapsed();
    let start = Instant::now();
    let mut publishers = Vec::with_capacity(n);
    for i in 0..n {
        publishers.push(session.declare_publisher(bench_key(i, Field::RBV)).await?);
    }
    let publishers_took = start.elapsed();
    drop((tokens, publishers));
    session.close().await?;
    Ok((tokens_took, publishers_took))
}

pub(crate) async fn writes_part(programs: &Programs, options: &BenchOptions) -> Result<(), Error> {
    println!("\n7. a storm of writes: VAL written to axes in turn (plain puts, each a new target within ±50 mm,");
    println!("   publishers with congestion control Block) for {} s, readback 10 Hz, a node process", options.storm);
    println!("   (`zmotor launch`), the client here. Counted: the writes sent, and those whose target a subscriber");
    println!("   here saw the node post on VAL (each write the node takes posts its new VAL); then one `?wait`");
    println!("   write per axis.");
    for (axes, per_axis_hz) in [(1, 1000.0), (100, 100.0)] {
        let s = write_storm(programs, axes, per_axis_hz, options.storm).await?;
        println!(
            "   {axes:>3} axes × {per_axis_hz:>4.0} writes/s: {} writes sent ({:.0}/s), {} taken by the node ({}), \
             node CPU {}, RSS {:.1} → {:.1} (a quarter in) → {:.1} MB (max {:.1}), last target reached on {}/{axes} axes",
            s.sent,
            s.sent as f64 / s.seconds,
            s.taken,
            if s.taken == s.sent { "none lost".to_string() } else { format!("{} lost", s.sent.abs_diff(s.taken)) },
            percent(s.cpu),
            s.rss_start_kb / 1024.0,
            s.rss_quarter_kb / 1024.0,
            s.rss_end_kb / 1024.0,
            s.rss_max_kb / 1024.0,
            s.reached
        );
    }
    Ok(())
}

/// What a storm of writes did to a node.
struct WriteStorm {
    sent: u64,
    /// Sent targets seen in the node's VAL posts: the writes it took.
    taken: u64,
    seconds: f64,
    cpu: f64,
    rss_start_kb: f64,
    /// A quarter into the storm: what the start (publishers, routes) costs is paid by then.
    rss_quarter_kb: f64,
    rss_end_kb: f64,
    rss_max_kb: f64,
    /// Axes whose final `?wait` write reached its target.
    reached: usize,
}

/// The `k`-th target of the storm: distinct from the one before on the same axis.
pub(crate) fn storm_target(k: u64) -> String {
    format!("{:.3}", ((k * 7919) % 100_000) as f64 / 1000.0 - 50.0)
}

/// `per_axis_hz` writes a second to each of `axes` axes for `seconds`, then a final target each.
async fn write_storm(programs: &Programs, axes: usize, per_axis_hz: f64, seconds: f64) -> Result<WriteStorm, Error> {
    let (node, endpoint) = programs.launch("storm", &bench_launch(axes, 10.0))?;
    let pid = node.pid();
    let client = client_when_ready(&endpoint).await?;
    let session = client.session().clone();
    wait_for_axes(&session, axes, Duration::from_secs(60)).await?;
    // Each write of the storm is a target its axis has not had: the writes the node took are the
    // sent targets its VAL posts carry (in ten-thousandths of a millimetre), whatever else it
    // posts.
    let posted: Arc<std::sync::Mutex<HashSet<(String, i64)>>> = Arc::default();
    let seen = Arc::new(AtomicU64::new(0));
    let (into, counter) = (posted.clone(), seen.clone());
    let _posts = session
        .declare_subscriber(KeyLayout::default().field("*", Field::VAL))
        .callback(move |sample| {
            counter.fetch_add(1, Relaxed);
            let axis = KeyLayout::default().axis_chunk(sample.key_expr().as_str()).map(str::to_string);
            let value = decode_cbor_value(&sample.payload().to_bytes()).ok().and_then(|v| v.as_f64());
            if let (Some(axis), Some(value)) = (axis, value) {
                into.lock().unwrap_or_else(|e| e.into_inner()).insert((axis, (value * 1e4).round() as i64));
            }
        })
        .await?;
    // The subscription has reached the node once each axis's first confirmed write posts
    // (targets of half a thousandth, which no write of the storm has, and a step's move).
    for i in 0..axes {
        let before = seen.load(Relaxed);
        let mut attempts = 0;
        while seen.load(Relaxed) == before {
            attempts += 1;
            if attempts > 100 {
                return Err("the VAL subscription never reached the node".into());
            }
            let target = format!("{:.4}", 0.0005 + 0.001 * (attempts % 10) as f64);
            let options = WriteOptions::waiting(Duration::from_secs(30));
            let outcome = client.write(&bench_axis(i), Field::VAL, target, options).await?.outcome().await;
            if !matches!(outcome, WriteOutcome::Completed(_)) {
                return Err(format!("b{i}: {outcome}").into());
            }
        }
    }
    let mut publishers = Vec::new();
    for i in 0..axes {
        let publisher = session.declare_publisher(bench_key(i, Field::VAL)).encoding(Encoding::TEXT_PLAIN);
        publishers.push(publisher.congestion_control(CongestionControl::Block).await?);
    }
    let mut targets = Vec::new();
    let (rss_start_kb, cpu0, start) = (rss_kb(&pid), cpu_seconds(&pid), Instant::now());
    let (mut rss_max_kb, mut rss_quarter_kb) = (rss_start_kb, None);
    let mut ticks = tokio::time::interval(Duration::from_secs_f64(1.0 / (axes as f64 * per_axis_hz)));
    let mut sent = 0u64;
    while start.elapsed().as_secs_f64() < seconds {
        ticks.tick().await;
        let (axis, target) = (sent as usize % axes, storm_target(sent));
        publishers[axis].put(target.clone()).await?;
        targets.push((bench_axis(axis), target));
        sent += 1;
        if sent.is_multiple_of(1000) {
            let rss = rss_kb(&pid);
            rss_max_kb = rss_max_kb.max(rss);
            if rss_quarter_kb.is_none() && start.elapsed().as_secs_f64() >= seconds / 4.0 {
                rss_quarter_kb = Some(rss);
            }
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    let cpu = (cpu_seconds(&pid) - cpu0) / elapsed;
    // The last posts arrive: wait until a second passes with none.
    let mut last = seen.load(Relaxed);
    loop {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let now = seen.load(Relaxed);
        if now == last {
            break;
        }
        last = now;
    }
    let storm_taken = {
        let posted = posted.lock().unwrap_or_else(|e| e.into_inner());
        let taken = |(axis, target): &(String, String)| {
            let units = (target.parse::<f64>().unwrap_or(f64::NAN) * 1e4).round() as i64;
            posted.contains(&(axis.clone(), units))
        };
        targets.iter().filter(|t| taken(t)).count() as u64
    };
    // Every axis's final target at once, then their answers.
    let mut pending = Vec::new();
    for i in 0..axes {
        pending.push(
            client.write(&bench_axis(i), Field::VAL, "7.5", WriteOptions::waiting(Duration::from_secs(60))).await?,
        );
    }
    let mut reached = 0;
    for write in pending {
        if let WriteOutcome::Completed(c) = write.outcome().await {
            reached += usize::from(c.reached == 1 && (c.rbv - 7.5).abs() < 1e-9);
        }
    }
    let rss_end_kb = rss_kb(&pid);
    session.close().await?;
    Ok(WriteStorm {
        sent,
        taken: storm_taken,
        seconds: elapsed,
        cpu,
        rss_start_kb,
        rss_quarter_kb: rss_quarter_kb.unwrap_or(rss_end_kb),
        rss_end_kb,
        rss_max_kb: rss_max_kb.max(rss_end_kb),
        reached,
    })
}

/// Until a monitored field takes `value` (its current value counts).
async fn until(monitor: &mut zmotor_client::Monitor, value: Value) -> Result<(), Error> {
    loop {
        let update = tokio::time::timeout(Duration::from_secs(20), monitor.next()).await?.ok_or("the monitor ended")?;
        if update.value == value {
            return Ok(());
        }
    }
}

pub(crate) async fn holds_part(programs: &Programs, options: &BenchOptions) -> Result<(), Error> {
    println!("\n9. the jog deadman: `zmotor jog b0 +` holds a jog of the demo's axis in a node process; the jogging");
    println!("   process is killed (SIGKILL); from the kill to JOGF 0 at a subscriber here (the README promises a");
    println!("   second at most; a client cut off without a close is bounded by its 0.5 s lease instead); ms");
    let (_node, endpoint) = programs.launch("holds", &demo_launch(1)?)?;
    let client = client_when_ready(&endpoint).await?;
    wait_for_axes(client.session(), 1, Duration::from_secs(20)).await?;
    let mut released = Vec::new();
    for _ in 0..options.holds {
        let mut jogf = client.monitor("b0", &[Field::JOGF]).await?;
        let mut jog = Process::from(programs.zmotor(&["jog", "b0", "+", "--connect", &endpoint]).spawn()?);
        // Jogging (the monitor starts with the current value).
        until(&mut jogf, Value::Int(1)).await?;
        let killed = Instant::now();
        jog.kill();
        until(&mut jogf, Value::Int(0)).await?;
        released.push(killed.elapsed());
        // Back at rest before the next, once the jog's deceleration and backlash are over (a
        // target is refused until then).
        let mut back = false;
        for _ in 0..100 {
            let options = WriteOptions::waiting(Duration::from_secs(60));
            if let WriteOutcome::Completed(_) = client.write("b0", Field::VAL, "0", options).await?.outcome().await {
                back = true;
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        if !back {
            return Err("b0 did not come back to 0 after a jog".into());
        }
    }
    let n = released.len();
    let p = Percentiles::of(released);
    println!("   {n} kills: p50 {:.1}  p90 {:.1}  max {:.1}", p.p50 / 1e3, p.p90 / 1e3, p.max / 1e3);
    Ok(())
}
