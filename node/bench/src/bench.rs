//! `zmotor bench`: measures command latency against Zenoh's own round trip (client and node in
//! separate processes over TCP on 127.0.0.1), the cost of many axes in one process, the load of
//! the EPICS figure, and start-up time. It prints its figures; it asserts nothing. The engine's
//! own cost per event is measured by criterion: `cargo bench -p zmotor-core --bench engine`.

use crate::Error;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use zenoh::bytes::Encoding;
use zenoh::qos::CongestionControl;
use zenoh::{Session, Wait};
use zmotor_core::{AxisEvent, AxisPlan, DriverPlan, PollRates};
use zmotor_core::SimConfig;
use zmotor_core::JogHold;
use zmotor_msgs::codec::{decode_cbor_value, encode_cbor};
use zmotor_msgs::wire::StateMarker;
use zmotor_msgs::{Field, Fields, KeyLayout, Value};
use zmotor_zenoh::{free_local_endpoint, Node, NodeContents, ZenohConfig};

/// What a run measures.
#[derive(Clone, Debug)]
pub(crate) struct BenchOptions {
    /// Moves (and pings) for the latency figures.
    pub(crate) moves: usize,
    /// Axis counts for the scale figures.
    pub(crate) scales: Vec<usize>,
    /// Axes for the start-up figure.
    pub(crate) startup_axes: usize,
    /// Seconds each CPU/publication measurement lasts.
    pub(crate) window: f64,
    /// Most axes set moving for the scale figures; beyond, start and idle memory only.
    pub(crate) moving_up_to: usize,
    /// Axes under the load of the EPICS figure (`Load::ShortMoves`).
    pub(crate) epics_load_axes: usize,
    /// Seconds of request/reply round trips per controller protocol.
    pub(crate) controller_window: f64,
    /// Moves per controller protocol for the end-of-motion figure.
    pub(crate) controller_moves: usize,
    /// The parts measured.
    pub(crate) parts: Vec<Part>,
    /// Seconds each storm of writes lasts.
    pub(crate) storm: f64,
    /// One-step moves each way for the Channel Access figures.
    pub(crate) ca_moves: usize,
}

/// The parts of the benchmark.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Part {
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
}

impl Part {
    pub(crate) const ALL: [Part; 7] = [
        Part::Latency,
        Part::Scale,
        Part::EpicsLoad,
        Part::Startup,
        Part::Controllers,
        Part::Writes,
        Part::ChannelAccess,
    ];
}

impl BenchOptions {
    pub(crate) fn full() -> Self {
        Self {
            moves: 2000,
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
        }
    }

    /// A run of a few seconds that only proves every part works.
    pub(crate) fn smoke() -> Self {
        Self {
            moves: 50,
            scales: vec![1, 10],
            startup_axes: 10,
            window: 0.5,
            moving_up_to: 10,
            epics_load_axes: 10,
            controller_window: 0.2,
            controller_moves: 2,
            parts: Part::ALL.to_vec(),
            storm: 1.0,
            ca_moves: 3,
        }
    }
}

const PING: &str = "bench/ping";
const PONG: &str = "bench/pong";

/// What a `zmotor bench-serve` process runs besides its ping echo.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Serve {
    /// Axes as the demo configures them (launch/sim-axis.toml: the physical simulator, 10 mm/s,
    /// 0.2 s ramps, readback 10 Hz): the latency and start-up figures.
    Demo,
    /// Simulated axes whose moves take real time, readback at 100 Hz (the scale figures).
    Moving,
    /// No axes: Zenoh alone publishing what as many moving axes publish, at the same rate.
    Zenoh,
}

/// The benchmark server: `n` axes as `serve` says, polled `readback_hz` times a second while
/// moving, and a ping echo, on one session.
pub(crate) async fn serve(listen: &str, axes: usize, serve: Serve, readback_hz: f64) -> Result<(), Error> {
    let config = ZenohConfig { listen: vec![listen.into()], ..ZenohConfig::default() };
    let session = zenoh::open(config.zenoh()?).await?;
    // Zenoh's floor, measured as its own z_pong does: the echo is published from inside the
    // subscriber callback through a declared publisher, no task spawned per sample.
    let pong = session.declare_publisher(PONG).congestion_control(CongestionControl::Block).await?;
    let _echo = session
        .declare_subscriber(PING)
        .callback(move |sample| {
            let _ = pong.put(sample.payload().clone()).wait();
        })
        .await?;
    let node = match serve {
        Serve::Zenoh => None,
        Serve::Demo | Serve::Moving => {
            let plans = if serve == Serve::Demo { demo_axes(axes) } else { bench_axes(axes, readback_hz) };
            Some(
                Node::start(
                    session.clone(),
                    KeyLayout::default(),
                    NodeContents { plans, ..NodeContents::default() },
                    None,
                )
                .await?,
            )
        }
    };
    tokio::select! {
        stopped = tokio::signal::ctrl_c() => stopped?,
        published = publish_like_moving_axes(&session, axes, readback_hz), if node.is_none() => published?,
    }
    if let Some(node) = node {
        node.shutdown().await;
    }
    Ok(())
}

/// The fields a moving axis posts at one readback poll (RBV, DRBV, RRBV, RMP, DIFF, RDIF), as
/// the engine says: a bench axis half a second into a long move, at its next poll.
fn fields_posted_per_poll() -> Vec<Field> {
    let start = zmotor_core::Instant::ZERO;
    let mut axis = bench_axes(1, Load::LongMoves.readback_hz()).remove(0).build(start, None);
    axis.write(start, Field::VAL, &Value::Float(1000.0)).expect("a bench move is accepted");
    while axis.now() < start + Duration::from_millis(500) {
        axis.drain_events().count();
        let t = axis.poll_timeout().expect("a simulated axis is polled");
        axis.handle_timeout(t);
    }
    axis.drain_events().filter_map(|e| if let AxisEvent::Post(field, _) = e { Some(field) } else { None }).collect()
}

/// Zenoh alone doing the publishing of `n` moving axes, `rate` times a second from one task:
/// each field of `fields_posted_per_poll` through a declared publisher, a CBOR number with a state
/// marker, as the node sends it. The floor under the node's own figure.
async fn publish_like_moving_axes(session: &Session, n: usize, rate: f64) -> Result<(), Error> {
    let fields = fields_posted_per_poll();
    let mut publishers = Vec::with_capacity(n * fields.len());
    for i in 0..n {
        for &field in &fields {
            publishers.push(session.declare_publisher(bench_key(i, field)).encoding(Encoding::APPLICATION_CBOR).await?);
        }
    }
    let mut polls = tokio::time::interval(Duration::from_secs_f64(1.0 / rate));
    let mut seq = 0;
    loop {
        polls.tick().await;
        for publisher in &publishers {
            seq += 1;
            let value = Value::Float(seq as f64 * 1e-3);
            publisher.put(encode_cbor(&value)).attachment(StateMarker::new(seq, 0, 0).encode()).wait()?;
        }
    }
}

/// The name of bench axis `i`.
fn bench_axis(i: usize) -> String {
    format!("b{i}")
}

/// The key of `field` on bench axis `i`.
fn bench_key(i: usize, field: Field) -> String {
    KeyLayout::default().field(&bench_axis(i), field)
}

/// `n` simulated axes named b0, b1, …, polled `rate` times a second while moving.
fn bench_axes(n: usize, rate: f64) -> Vec<AxisPlan> {
    (0..n)
        .map(|i| AxisPlan {
            name: bench_axis(i),
            fields: Fields { mres: 0.001, velo: 10.0, accl: 0.1, ..Fields::default() },
            driver: DriverPlan::Sim(SimConfig::default()),
            rates: PollRates { moving: Duration::from_secs_f64(1.0 / rate), idle: Duration::from_secs(1) },
            jog_hold: JogHold::Optional,
        })
        .collect()
}

/// The demo's launch file, as a user starts it.
const DEMO: &str = include_str!("../../../launch/sim-axis.toml");

/// `n` copies of the demo's axis (launch/sim-axis.toml, as shipped), named b0, b1, ….
fn demo_axes(n: usize) -> Vec<AxisPlan> {
    let demo = zmotor_launch::Launch::parse(DEMO).and_then(|launch| launch.deployment(None));
    let axis = demo.expect("the shipped demo loads (a launch test checks it)").contents.plans.remove(0);
    (0..n).map(|i| AxisPlan { name: bench_axis(i), ..axis.clone() }).collect()
}

/// The targets the latency figures alternate between, mm.
const LATENCY_TARGETS: [f64; 2] = [0.01, 0.02];

/// How long the demo axis's latency move lasts on its simulator, in virtual time: write VAL
/// from one target to the other, run until DMOV 1.
fn demo_motion() -> Duration {
    let start = zmotor_core::Instant::ZERO;
    let mut axis = demo_axes(1).remove(0).build(start, None);
    let at_first = |axis: &mut zmotor_core::Axis| {
        for _ in 0..100_000 {
            if !axis.is_busy() {
                return axis.now();
            }
            let t = axis.poll_timeout().expect("a simulated axis is polled");
            axis.handle_timeout(t);
        }
        axis.now()
    };
    axis.write(start, Field::VAL, &Value::Float(LATENCY_TARGETS[0])).expect("the demo moves");
    let from = at_first(&mut axis);
    axis.write(from, Field::VAL, &Value::Float(LATENCY_TARGETS[1])).expect("the demo moves");
    at_first(&mut axis) - from
}

/// A `zmotor bench-serve` child process; killed when dropped.
struct Server(Child);

impl Server {
    fn spawn(endpoint: &str, axes: usize, serve: Serve, readback_hz: f64) -> Result<Self, Error> {
        let exe = std::env::current_exe()?;
        let serve = clap::ValueEnum::to_possible_value(&serve).expect("every kind has a name");
        let child = Command::new(exe)
            .args(["bench-serve", "--listen", endpoint, "--axes", &axes.to_string(), "--serve", serve.get_name()])
            .args(["--readback-hz", &readback_hz.to_string()])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()?;
        Ok(Self(child))
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A client of a server process that may not listen yet.
pub(crate) async fn client_when_ready(endpoint: &str, since: Instant) -> Result<Session, Error> {
    loop {
        if let Ok(session) = zenoh::open(ZenohConfig::client(endpoint).zenoh()?).await {
            return Ok(session);
        }
        if since.elapsed() > Duration::from_secs(60) {
            return Err("the benchmark server did not start".into());
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// How many axes answer a get of their DMOV.
async fn answering(session: &Session) -> Result<usize, Error> {
    let replies = session.get(KeyLayout::default().field("*", Field::DMOV)).timeout(Duration::from_secs(10)).await?;
    let mut n = 0;
    while let Ok(reply) = replies.recv_async().await {
        n += usize::from(reply.result().is_ok());
    }
    Ok(n)
}

async fn wait_for_axes(session: &Session, n: usize, limit: Duration) -> Result<Duration, Error> {
    let start = Instant::now();
    while start.elapsed() < limit {
        if answering(session).await? >= n {
            return Ok(start.elapsed());
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    Err(format!("{n} axes did not all answer within {limit:?}").into())
}

/// Percentiles of a set of durations, in microseconds.
pub(crate) struct Percentiles {
    pub p50: f64,
    pub p90: f64,
    pub p99: f64,
}

impl Percentiles {
    pub(crate) fn of(mut samples: Vec<Duration>) -> Self {
        samples.sort();
        let at = |q: f64| samples[((samples.len() as f64 - 1.0) * q).round() as usize].as_secs_f64() * 1e6;
        Self { p50: at(0.5), p90: at(0.9), p99: at(0.99) }
    }
}

pub(crate) struct Latency {
    pub dmov0: Percentiles,
    pub dmov1: Percentiles,
    pub rtt: Percentiles,
    /// The move's own duration on the simulator.
    pub motion: Duration,
}

/// Put VAL to the demo's axis and time DMOV 0 and DMOV 1 at the client; between two moves,
/// Zenoh's own round trip between the same two processes.
async fn latency(moves: usize) -> Result<Latency, Error> {
    let endpoint = free_local_endpoint()?;
    let _server = Server::spawn(&endpoint, 1, Serve::Demo, Load::LongMoves.readback_hz())?;
    let session = client_when_ready(&endpoint, Instant::now()).await?;
    wait_for_axes(&session, 1, Duration::from_secs(20)).await?;
    let dmov = session.declare_subscriber(bench_key(0, Field::DMOV)).await?;
    let pong = session.declare_subscriber(PONG).await?;
    let val = session.declare_publisher(bench_key(0, Field::VAL)).encoding(Encoding::TEXT_PLAIN).await?;
    let ping = session.declare_publisher(PING).congestion_control(CongestionControl::Block).await?;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (mut to_dmov0, mut to_dmov1, mut rtt) = (Vec::new(), Vec::new(), Vec::new());
    // Moves and pings alternate, so both see the same conditions on a shared machine.
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
        let start = Instant::now();
        ping.put(vec![0u8; 8]).await?;
        tokio::time::timeout(Duration::from_secs(5), pong.recv_async()).await??;
        // The first tenth warms up connections and caches.
        if i >= moves / 10 {
            to_dmov0.push(zero.expect("DMOV 0 came first"));
            to_dmov1.push(moved);
            rtt.push(start.elapsed());
        }
    }
    Ok(Latency {
        dmov0: Percentiles::of(to_dmov0),
        dmov1: Percentiles::of(to_dmov1),
        rtt: Percentiles::of(rtt),
        motion: demo_motion(),
    })
}

pub(crate) struct Scale {
    pub axes: usize,
    pub start: Duration,
    pub rss_per_axis_idle_kb: f64,
    /// The node with every axis moving, watched by a subscriber of everything; None above
    /// `BenchOptions::moving_up_to` axes.
    pub moving: Option<Publishing>,
    /// The same, watched by a subscriber of RBV and DMOV only.
    pub watching_readback: Option<Publishing>,
    /// Zenoh alone publishing the same samples at the same rate (`Serve::Zenoh`).
    pub zenoh_alone: Option<Publishing>,
}

/// A server process publishing readbacks for every axis, seen by one subscriber of `motor/**`
/// in another process.
pub(crate) struct Publishing {
    /// The server process's CPU, as a fraction of one core.
    pub cpu: f64,
    /// Samples per second the subscriber received.
    pub publications_per_s: f64,
    /// RBV samples per axis per second the subscriber received (the readback rate when every
    /// poll arrives).
    pub rbv_per_axis_per_s: f64,
    /// Moves per second the subscriber saw end (DMOV 1).
    pub(crate) moves_per_s: f64,
    /// From the first command to the measurement window: until the readbacks (long moves) or
    /// the ends of moves (short moves) arrived at 90 % of their rate. None when `SETTLE_LIMIT`
    /// passed first.
    pub settled_after: Option<Duration>,
}

/// What the subscriber of a publishing measurement watches.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Watch {
    /// Every key of every axis (`motor/**`): every field change the node publishes.
    Everything,
    /// RBV and DMOV of every axis, as a display or a robot stack following positions would.
    ReadbackAndDone,
}

impl Watch {
    fn keys(self) -> Vec<String> {
        let layout = KeyLayout::default();
        match self {
            Watch::Everything => vec![layout.everything()],
            Watch::ReadbackAndDone => vec![layout.field("*", Field::RBV), layout.field("*", Field::DMOV)],
        }
    }
}

/// How the axes of a publishing measurement move.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Load {
    /// One long move each (10 mm/s for 1000 mm), readback at 100 Hz: the scale figures.
    LongMoves,
    /// The load of the EPICS figure: 4 mm moves (0.5 s, so ~5 readbacks each) commanded to the axes in turn,
    /// `moves_per_s` in all, readback at 10 Hz.
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

/// Moves per second and axis in the EPICS figure (1,600 moves/s on 1,000 axes).
const EPICS_MOVES_PER_AXIS_PER_S: f64 = 1.6;
/// Longest wait for the load to settle before the CPU window opens.
const SETTLE_LIMIT: Duration = Duration::from_secs(45);

/// Resident memory of a process (`self` or a pid), KB.
fn rss_kb(process: &str) -> f64 {
    let statm = std::fs::read_to_string(format!("/proc/{process}/statm")).unwrap_or_default();
    let pages: f64 = statm.split_whitespace().nth(1).and_then(|p| p.parse().ok()).unwrap_or(0.0);
    pages * 4.0
}

/// CPU seconds a process (`self` or a pid) has used (user + system).
fn cpu_seconds(process: &str) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{process}/stat")).unwrap_or_default();
    let after_name = stat.rsplit(')').next().unwrap_or("");
    let fields: Vec<&str> = after_name.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

/// `n` axes in this process: the time they take to start and their memory when idle; then,
/// up to `moving_up_to` axes, the same axes moving in a node process of their own.
async fn scale(n: usize, window: f64, moving_up_to: usize) -> Result<Scale, Error> {
    let config = ZenohConfig { listen: vec![free_local_endpoint()?], ..ZenohConfig::default() };
    let session = zenoh::open(config.zenoh()?).await?;
    let rss_before = rss_kb("self");
    let start = Instant::now();
    let contents = NodeContents { plans: bench_axes(n, Load::LongMoves.readback_hz()), ..NodeContents::default() };
    let node = Node::start(session.clone(), KeyLayout::default(), contents, None).await?;
    let started = start.elapsed();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let rss_per_axis_idle_kb = (rss_kb("self") - rss_before) / n as f64;
    node.shutdown().await;
    session.close().await?;
    if n > moving_up_to {
        let (moving, watching_readback, zenoh_alone) = (None, None, None);
        return Ok(Scale { axes: n, start: started, rss_per_axis_idle_kb, moving, watching_readback, zenoh_alone });
    }
    let moving = Some(publishing(n, window, Serve::Moving, Load::LongMoves, Watch::Everything).await?);
    let watching_readback = Some(publishing(n, window, Serve::Moving, Load::LongMoves, Watch::ReadbackAndDone).await?);
    let zenoh_alone = Some(publishing(n, window, Serve::Zenoh, Load::LongMoves, Watch::Everything).await?);
    Ok(Scale { axes: n, start: started, rss_per_axis_idle_kb, moving, watching_readback, zenoh_alone })
}

/// Samples a subscriber of `motor/**` received: all of them, RBV alone, DMOV 1 alone.
#[derive(Default)]
struct Received {
    all: std::sync::atomic::AtomicU64,
    rbv: std::sync::atomic::AtomicU64,
    done: std::sync::atomic::AtomicU64,
}

impl Received {
    fn read(&self) -> [u64; 3] {
        use std::sync::atomic::Ordering::Relaxed;
        [self.all.load(Relaxed), self.rbv.load(Relaxed), self.done.load(Relaxed)]
    }

    fn count(&self, sample: &zenoh::sample::Sample) {
        use std::sync::atomic::Ordering::Relaxed;
        self.all.fetch_add(1, Relaxed);
        match sample.key_expr().as_str().rsplit('/').next().and_then(Field::from_name) {
            Some(Field::RBV) => {
                self.rbv.fetch_add(1, Relaxed);
            }
            Some(Field::DMOV) if decode_cbor_value(&sample.payload().to_bytes()) == Ok(Value::Int(1)) => {
                self.done.fetch_add(1, Relaxed);
            }
            _ => {}
        }
    }
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

/// A server process of `n` axes moving under `load` (or Zenoh alone publishing as much): its
/// CPU and what one subscriber receives, over `window` seconds once the load has settled (or
/// `SETTLE_LIMIT` has passed).
async fn publishing(n: usize, window: f64, serve: Serve, load: Load, watch: Watch) -> Result<Publishing, Error> {
    let endpoint = free_local_endpoint()?;
    let server = Server::spawn(&endpoint, n, serve, load.readback_hz())?;
    let pid = server.0.id().to_string();
    let session = client_when_ready(&endpoint, Instant::now()).await?;
    if serve != Serve::Zenoh {
        wait_for_axes(&session, n, Duration::from_secs(120)).await?;
    }
    let received = std::sync::Arc::new(Received::default());
    let mut subscribers = Vec::new();
    for key in watch.keys() {
        let counter = received.clone();
        subscribers.push(session.declare_subscriber(key).callback(move |sample| counter.count(&sample)).await?);
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let settling = Instant::now();
    let commander = match load {
        Load::LongMoves => {
            for i in 0..n {
                session.put(bench_key(i, Field::VAL), "1000").encoding(Encoding::TEXT_PLAIN).await?;
            }
            None
        }
        Load::ShortMoves { moves_per_s } => Some(tokio::spawn(command_short_moves(session.clone(), n, moves_per_s))),
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
    session.close().await?;
    Ok(Publishing {
        cpu,
        publications_per_s: (all1 - all0) as f64 / elapsed,
        rbv_per_axis_per_s: (rbv1 - rbv0) as f64 / elapsed / n as f64,
        moves_per_s: (done1 - done0) as f64 / elapsed,
        settled_after,
    })
}

/// The start-up of a node process with `n` axes, as a client sees it.
pub(crate) struct Startup {
    /// From spawning the process to every axis answering a get.
    answering: Duration,
    /// From spawning the process to a client seeing every axis's liveliness token.
    visible: Duration,
}

async fn startup(n: usize) -> Result<Startup, Error> {
    let endpoint = free_local_endpoint()?;
    let start = Instant::now();
    let _server = Server::spawn(&endpoint, n, Serve::Demo, Load::LongMoves.readback_hz())?;
    let session = client_when_ready(&endpoint, start).await?;
    wait_for_axes(&session, n, Duration::from_secs(120)).await?;
    let answering = start.elapsed();
    // As a client watching axes appear does: a liveliness subscriber, with the tokens already there.
    let tokens = session.liveliness().declare_subscriber(KeyLayout::default().axis("*")).history(true).await?;
    let mut seen = std::collections::HashSet::new();
    while seen.len() < n {
        let token = tokio::time::timeout_at((start + Duration::from_secs(120)).into(), tokens.recv_async()).await;
        let Ok(Ok(token)) = token else {
            return Err(format!("{} of {n} liveliness tokens after 120 s", seen.len()).into());
        };
        if token.kind() == zenoh::sample::SampleKind::Put {
            seen.insert(token.key_expr().as_str().to_string());
        }
    }
    Ok(Startup { answering, visible: start.elapsed() })
}

/// Zenoh alone, in this process: how long one session takes to declare `n` liveliness tokens,
/// and `n` publishers, on keys shaped like the axes'. The floor under the node's start-up and
/// under the first moves of many axes (a publisher per field posted again and again).
async fn zenoh_declarations(n: usize) -> Result<(Duration, Duration), Error> {
    let config = ZenohConfig { listen: vec![free_local_endpoint()?], ..ZenohConfig::default() };
    let session = zenoh::open(config.zenoh()?).await?;
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

/// Run every measurement and print the figures.
pub(crate) async fn run(options: &BenchOptions) -> Result<(), Error> {
    println!(
        "zmotor bench: {} moves, scales {:?}, start-up of {} axes",
        options.moves, options.scales, options.startup_axes
    );
    for part in &options.parts {
        match part {
            Part::Latency => latency_part(options).await?,
            Part::Scale => scale_part(options).await,
            Part::EpicsLoad => epics_load_part(options).await?,
            Part::Startup => startup_part(options).await?,
            Part::Controllers => controllers_part(options).await?,
            Part::Writes => writes_part(options).await?,
            Part::ChannelAccess => channel_access_part(options).await?,
        }
    }
    Ok(())
}

async fn latency_part(options: &BenchOptions) -> Result<(), Error> {
    println!("\n1. command latency: the demo's axis (launch/sim-axis.toml: physical simulator, readback 10 Hz) in");
    println!("   a node process, a client in this one, TCP on 127.0.0.1; moves of 0.01 mm; µs");
    let l = latency(options.moves).await?;
    let motion_us = l.motion.as_secs_f64() * 1e6;
    println!("   {:<44} {:>9} {:>9} {:>9}", "", "p50", "p90", "p99");
    for (name, p) in [
        ("put VAL → DMOV 0 at the client", &l.dmov0),
        ("put VAL → DMOV 1 at the client", &l.dmov1),
        ("Zenoh round trip (z_ping/z_pong style)", &l.rtt),
    ] {
        println!("   {name:<44} {:>9.1} {:>9.1} {:>9.1}", p.p50, p.p90, p.p99);
    }
    println!("   {:<44} {:>9.1}", "the motion itself (simulator, virtual time)", motion_us);
    println!(
        "   DMOV 0 / Zenoh RTT (p50): {:.2};  DMOV 1 − motion − RTT (p50): {:.0} µs",
        l.dmov0.p50 / l.rtt.p50,
        l.dmov1.p50 - motion_us - l.rtt.p50
    );

    println!("\n2. engine cost per event: measured by criterion, `cargo bench -p zmotor-core --bench engine`");

    Ok(())
}

async fn scale_part(options: &BenchOptions) {
    println!(
        "\n3. scale: N axes in one process (start, memory); then, up to {} axes, every axis moving with",
        options.moving_up_to
    );
    println!(
        "   readback at {} Hz in a node process of its own, one subscriber in another: of every key (motor/**),",
        Load::LongMoves.readback_hz()
    );
    println!("   then of RBV and DMOV only; then Zenoh alone publishing what the node publishes, no record.");
    println!("   Settled: from the commands to all readbacks flowing (the CPU window opens then).");
    for &n in &options.scales {
        match scale(n, options.window, options.moving_up_to).await {
            Ok(s) => {
                println!(
                    "   {:>6} axes: start {:.2} s, {:.1} KB per idle axis",
                    s.axes,
                    s.start.as_secs_f64(),
                    s.rss_per_axis_idle_kb
                );
                for (who, p) in [
                    ("node, subscriber of every key", &s.moving),
                    ("node, subscriber of RBV and DMOV", &s.watching_readback),
                    ("Zenoh alone, every key", &s.zenoh_alone),
                ] {
                    match p {
                        Some(p) => println!(
                            "      {who:<34} CPU {:>6}  {:>8.0} samples/s  {:>5.1} RBV/axis/s  settled {} s",
                            percent(p.cpu),
                            p.publications_per_s,
                            p.rbv_per_axis_per_s,
                            seconds(p.settled_after)
                        ),
                        None => println!("      {who:<34} not measured (beyond --moving-up-to)"),
                    }
                }
            }
            Err(e) => println!("   {n:>6} axes: failed: {e}"),
        }
    }
}

async fn epics_load_part(options: &BenchOptions) -> Result<(), Error> {
    let n = options.epics_load_axes;
    let load = Load::ShortMoves { moves_per_s: n as f64 * EPICS_MOVES_PER_AXIS_PER_S };
    println!(
        "\n4. the load of the EPICS figure: {n} axes, readback {} Hz, 4 mm moves commanded at {:.0}/s in all",
        load.readback_hz(),
        n as f64 * EPICS_MOVES_PER_AXIS_PER_S
    );
    println!("   (the given IOC: 45 % CPU for 1,600 moves/s and 8,300 RBV events/s on 1,000 axes)");
    let p = publishing(n, options.window, Serve::Moving, load, Watch::Everything).await?;
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

async fn startup_part(options: &BenchOptions) -> Result<(), Error> {
    let n = options.startup_axes;
    println!("\n5. start-up of {n} axes in a node process, as a client sees it");
    let t = startup(n).await?;
    println!("   process start → every axis answers get: {:.2} s", t.answering.as_secs_f64());
    println!("   process start → every axis's liveliness token seen: {:.2} s", t.visible.as_secs_f64());
    let (tokens, publishers) = zenoh_declarations(n).await?;
    println!(
        "   Zenoh alone, one session: {n} liveliness tokens declared in {:.2} s; {n} publishers in {:.2} s",
        tokens.as_secs_f64(),
        publishers.as_secs_f64()
    );

    Ok(())
}

async fn writes_part(options: &BenchOptions) -> Result<(), Error> {
    println!("\n7. a storm of writes: VAL written to axes in turn (plain puts, targets spread over ±50 mm) for");
    println!(
        "   {} s, readback 10 Hz, a node process, the client here; then one `?wait` write per axis",
        options.storm
    );
    for (axes, per_axis_hz) in [(1, 1000.0), (100, 100.0)] {
        let s = write_storm(axes, per_axis_hz, options.storm).await?;
        println!(
            "   {axes:>3} axes × {per_axis_hz:>4.0} writes/s: {:>6.0} writes/s sent, node CPU {}, RSS {:.1} → {:.1} \
             (a quarter in) → {:.1} MB (max {:.1}), last target reached on {}/{axes} axes",
            s.writes_per_s,
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
    writes_per_s: f64,
    cpu: f64,
    rss_start_kb: f64,
    /// A quarter into the storm: what the start (publishers, routes) costs is paid by then.
    rss_quarter_kb: f64,
    rss_end_kb: f64,
    rss_max_kb: f64,
    /// Axes whose final `?wait` write reached its target.
    reached: usize,
}

/// `per_axis_hz` writes a second to each of `axes` axes for `seconds`, then a final target each.
async fn write_storm(axes: usize, per_axis_hz: f64, seconds: f64) -> Result<WriteStorm, Error> {
    let endpoint = free_local_endpoint()?;
    let server = Server::spawn(&endpoint, axes, Serve::Moving, 10.0)?;
    let pid = server.0.id().to_string();
    let session = client_when_ready(&endpoint, Instant::now()).await?;
    wait_for_axes(&session, axes, Duration::from_secs(60)).await?;
    let mut publishers = Vec::new();
    for i in 0..axes {
        publishers.push(session.declare_publisher(bench_key(i, Field::VAL)).encoding(Encoding::TEXT_PLAIN).await?);
    }
    let (rss_start_kb, cpu0, start) = (rss_kb(&pid), cpu_seconds(&pid), Instant::now());
    let (mut rss_max_kb, mut rss_quarter_kb) = (rss_start_kb, None);
    let mut ticks = tokio::time::interval(Duration::from_secs_f64(1.0 / (axes as f64 * per_axis_hz)));
    let mut sent = 0usize;
    while start.elapsed().as_secs_f64() < seconds {
        ticks.tick().await;
        let target = ((sent as f64 * 0.618_033_988_75).fract() - 0.5) * 100.0;
        publishers[sent % axes].put(format!("{target:.3}")).await?;
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
    // Every axis's final target at once, then their answers.
    let mut pending = Vec::new();
    for i in 0..axes {
        let selector = format!("{}?{}", bench_key(i, Field::VAL), zmotor_msgs::keys::WAIT_PARAMETER);
        pending.push(session.get(selector).payload("7.5").timeout(Duration::from_secs(60)).await?);
    }
    let mut reached = 0;
    for replies in pending {
        let Ok(reply) = replies.recv_async().await else { continue };
        let Ok(sample) = reply.result() else { continue };
        let completion: Option<zmotor_msgs::Completion> = ciborium::from_reader(&sample.payload().to_bytes()[..]).ok();
        reached += usize::from(completion.is_some_and(|c| c.reached == 1 && (c.rbv - 7.5).abs() < 1e-9));
    }
    let rss_end_kb = rss_kb(&pid);
    session.close().await?;
    Ok(WriteStorm {
        writes_per_s: sent as f64 / elapsed,
        cpu,
        rss_start_kb,
        rss_quarter_kb: rss_quarter_kb.unwrap_or(rss_end_kb),
        rss_end_kb,
        rss_max_kb: rss_max_kb.max(rss_end_kb),
        reached,
    })
}

async fn controllers_part(options: &BenchOptions) -> Result<(), Error> {
    println!("\n6. controllers: each protocol against its emulator (zmotor sim-controller's, in this process)");
    println!("   round trips: request/reply exchanges per second over one TCP connection on 127.0.0.1;");
    println!("   poll: one full poll of 1 axis and of 8 (all of them on a smaller controller), median;");
    println!("   end → DMOV 1: the vendor's ready launch file in a node process, a client here: from the");
    println!("   emulated stage's end of motion to DMOV 1 at the client, µs, beside the moving-poll period");
    println!(
        "   {:<16} {:>12} {:>10} {:>14} {:>10} {:>10} {:>10} {:>8}",
        "", "round trips/s", "poll 1", "poll n", "end→DMOV1 p50", "p90", "p99", "poll"
    );
    for f in crate::controller_bench::run(options.controller_window, options.controller_moves).await? {
        println!(
            "   {:<16} {:>12.0} {:>8.0} µs {:>2} {:>8.0} µs {:>13.0} {:>10.0} {:>10.0} {:>5.0} ms",
            f.name,
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

async fn channel_access_part(options: &BenchOptions) -> Result<(), Error> {
    println!("\n8. Channel Access beside Zenoh: the demo's axis in a node process whose launch file runs the");
    println!("   front-end ([channel_access]); here a CA client (as caget and `caput -c` send) and a Zenoh client,");
    println!(
        "   in turn: {} reads of RBV, {} one-step (1 µm) moves answered at their end; µs",
        options.moves, options.ca_moves
    );
    let f = crate::ca_bench::run(options.moves, options.ca_moves).await?;
    for (what, p) in [
        ("caget RBV (CA read)", &f.ca_read),
        ("Zenoh get RBV", &f.zenoh_read),
        ("caput -c VAL, one step", &f.ca_move),
        ("Zenoh ?wait VAL, one step", &f.zenoh_move),
    ] {
        println!("   {what:<28} p50 {:>9.0}  p90 {:>9.0}  p99 {:>9.0}", p.p50, p.p90, p.p99);
    }
    Ok(())
}

fn percent(fraction: f64) -> String {
    format!("{:.0} %", fraction * 100.0)
}

fn seconds(settled: Option<Duration>) -> String {
    settled.map_or_else(|| format!("> {}", SETTLE_LIMIT.as_secs()), |d| format!("{:.1}", d.as_secs_f64()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_moving_axis_posts_its_six_readback_fields_per_poll() {
        let mut fields = fields_posted_per_poll();
        fields.sort_by_key(|f| f.name());
        assert_eq!(fields, [Field::DIFF, Field::DRBV, Field::RBV, Field::RDIF, Field::RMP, Field::RRBV]);
    }
}
