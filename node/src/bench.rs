//! `zmotor bench`: measures command latency against Zenoh's own round trip (client and node in
//! separate processes over TCP on 127.0.0.1), the engine's cost per event, the cost of many
//! axes in one process, and start-up time. It prints its figures; it asserts nothing.

use crate::axis::{Axis, PollRates};
use crate::driver::sim::{SimAxis, SimConfig};
use crate::engine::{DeviceStatus, MotorRecord};
use crate::launch::{AxisPlan, DriverPlan, ZenohSection};
use crate::net::{zenoh_config, Error, Node};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use zenoh::bytes::Encoding;
use zenoh::Session;
use zmotor_msgs::bits::msta;
use zmotor_msgs::{codec::decode_cbor_value, Field, Fields, KeyLayout, Value};

/// What a run measures.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// Moves (and pings) for the latency figures.
    pub moves: usize,
    /// Axis counts for the scale figures.
    pub scales: Vec<usize>,
    /// Axes for the start-up figure.
    pub startup_axes: usize,
    /// Seconds each CPU/publication measurement lasts.
    pub window: f64,
}

impl BenchOptions {
    pub fn full() -> Self {
        Self { moves: 2000, scales: vec![1, 100, 1000, 10_000], startup_axes: 1000, window: 3.0 }
    }

    /// A run of a few seconds that only proves every part works.
    pub fn smoke() -> Self {
        Self { moves: 50, scales: vec![1, 10], startup_axes: 10, window: 0.5 }
    }
}

const PING: &str = "bench/ping";
const PONG: &str = "bench/pong";

/// The benchmark server: `n` instant simulated axes and a ping echo on one session.
pub async fn serve(listen: &str, axes: usize, rate: f64) -> Result<(), Error> {
    let section = ZenohSection { mode: "peer".into(), listen: vec![listen.into()], ..ZenohSection::default() };
    let session = zenoh::open(zenoh_config(&section)?).await?;
    let echo_session = session.clone();
    let _echo = session
        .declare_subscriber(PING)
        .callback(move |sample| {
            let session = echo_session.clone();
            let payload = sample.payload().clone();
            tokio::spawn(async move {
                let _ = session.put(PONG, payload).await;
            });
        })
        .await?;
    let node =
        Node::start(session.clone(), KeyLayout::default(), bench_axes(axes, true, rate), vec![], vec![], None).await?;
    tokio::signal::ctrl_c().await?;
    node.shutdown().await;
    Ok(())
}

/// `n` simulated axes named b0, b1, …; `instant` ones finish every move at once.
fn bench_axes(n: usize, instant: bool, rate: f64) -> Vec<AxisPlan> {
    (0..n)
        .map(|i| AxisPlan {
            name: format!("b{i}"),
            fields: Fields { mres: 0.001, velo: 10.0, accl: 0.1, ..Fields::default() },
            driver: DriverPlan::Sim(SimConfig { instant, ..SimConfig::default() }),
            rates: PollRates { moving: 1.0 / rate, idle: 1.0 },
        })
        .collect()
}

fn free_endpoint() -> Result<String, Error> {
    let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
    Ok(format!("tcp/127.0.0.1:{port}"))
}

/// A `zmotor bench-serve` child process; killed when dropped.
struct Server(Child);

impl Server {
    fn spawn(endpoint: &str, axes: usize) -> Result<Self, Error> {
        let exe = std::env::current_exe()?;
        let child = Command::new(exe)
            .args(["bench-serve", "--listen", endpoint, "--axes", &axes.to_string()])
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

async fn client(endpoint: &str) -> Result<Session, Error> {
    let section = ZenohSection {
        mode: "client".into(),
        listen: vec![],
        connect: vec![endpoint.into()],
        ..ZenohSection::default()
    };
    zenoh::open(zenoh_config(&section)?).await
}

/// A client of a server process that may not listen yet.
async fn client_when_ready(endpoint: &str, since: Instant) -> Result<Session, Error> {
    loop {
        if let Ok(session) = client(endpoint).await {
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
    let replies = session.get("motor/*/DMOV").timeout(Duration::from_secs(10)).await?;
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
pub struct Percentiles {
    pub p50: f64,
    pub p90: f64,
    pub p99: f64,
}

impl Percentiles {
    fn of(mut samples: Vec<Duration>) -> Self {
        samples.sort();
        let at = |q: f64| samples[((samples.len() as f64 - 1.0) * q).round() as usize].as_secs_f64() * 1e6;
        Self { p50: at(0.5), p90: at(0.9), p99: at(0.99) }
    }
}

pub struct Latency {
    pub dmov0: Percentiles,
    pub dmov1: Percentiles,
    pub rtt: Percentiles,
}

/// Put VAL and time DMOV 0 and DMOV 1 at the client; then Zenoh's own ping-pong.
async fn latency(moves: usize) -> Result<Latency, Error> {
    let endpoint = free_endpoint()?;
    let _server = Server::spawn(&endpoint, 1)?;
    let session = client_when_ready(&endpoint, Instant::now()).await?;
    wait_for_axes(&session, 1, Duration::from_secs(20)).await?;
    let dmov = session.declare_subscriber("motor/b0/DMOV").await?;
    let pong = session.declare_subscriber(PONG).await?;
    let val = session.declare_publisher("motor/b0/VAL").encoding(Encoding::TEXT_PLAIN).await?;
    let ping = session.declare_publisher(PING).await?;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (mut to_dmov0, mut to_dmov1, mut rtt) = (Vec::new(), Vec::new(), Vec::new());
    // Moves and pings alternate, so both see the same conditions on a shared machine.
    for i in 0..moves + moves / 10 {
        let target = if i % 2 == 0 { "0.01" } else { "0.02" };
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
    Ok(Latency { dmov0: Percentiles::of(to_dmov0), dmov1: Percentiles::of(to_dmov1), rtt: Percentiles::of(rtt) })
}

pub struct EngineCost {
    pub write_ns: f64,
    pub status_ns: f64,
    pub move_cycle_ns: f64,
}

/// Nanoseconds per engine event, in this process, on the record alone.
pub fn engine_cost(iterations: usize) -> EngineCost {
    let fields = Fields { mres: 0.001, velo: 10.0, ..Fields::default() };
    let status = |p: f64, done: bool| DeviceStatus {
        position: p,
        msta: if done { msta::DONE } else { 0 },
        ..DeviceStatus::default()
    };
    let mut record = MotorRecord::new(fields);
    record.init(status(0.0, true));
    let time = |f: &mut dyn FnMut(usize)| {
        let start = Instant::now();
        for i in 0..iterations {
            f(i);
        }
        start.elapsed().as_secs_f64() * 1e9 / iterations as f64
    };
    // A write that processes the record without moving (a DESC-like no-op would not process).
    let write_ns = time(&mut |_| {
        let _ = record.write(Field::STUP, &Value::Int(1));
        record.drain_outputs().count();
        record.callback(status(0.0, true));
        record.drain_outputs().count();
    }) / 2.0;
    let status_ns = time(&mut |i| {
        record.callback(status((i % 100) as f64, true));
        record.drain_outputs().count();
    });
    let move_cycle_ns = time(&mut |i| {
        let target = if i % 2 == 0 { 1.0 } else { 2.0 };
        let _ = record.write(Field::VAL, &Value::Float(target));
        record.callback(status(target * 500.0, false));
        record.callback(status(target * 1000.0, true));
        record.drain_outputs().count();
    });
    EngineCost { write_ns, status_ns, move_cycle_ns }
}

pub struct Scale {
    pub axes: usize,
    pub start: Duration,
    pub rss_per_axis_idle_kb: f64,
    /// CPU (fraction of one core) and publications per second with every axis moving; None
    /// above `MOVING_MEASURED_UP_TO` axes.
    pub moving: Option<(f64, f64)>,
}

/// Most axes set moving together for the scale figures. Beyond, the first publications on the
/// axes' keys take minutes (Zenoh's cost of a new key grows with the keys already there), so
/// only start and idle memory are measured.
const MOVING_MEASURED_UP_TO: usize = 2000;

fn rss_kb() -> f64 {
    let statm = std::fs::read_to_string("/proc/self/statm").unwrap_or_default();
    let pages: f64 = statm.split_whitespace().nth(1).and_then(|p| p.parse().ok()).unwrap_or(0.0);
    pages * 4.0
}

/// CPU seconds this process has used (user + system).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after_name = stat.rsplit(')').next().unwrap_or("");
    let fields: Vec<&str> = after_name.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

/// `n` axes in this process: memory when idle, CPU and publications while all move with
/// readback at 100 Hz.
async fn scale(n: usize, window: f64) -> Result<Scale, Error> {
    let endpoint = free_endpoint()?;
    let section = ZenohSection { mode: "peer".into(), listen: vec![endpoint.clone()], ..ZenohSection::default() };
    let session = zenoh::open(zenoh_config(&section)?).await?;
    let observer = client(&endpoint).await?;
    let rss_before = rss_kb();
    let start = Instant::now();
    let node =
        Node::start(session.clone(), KeyLayout::default(), bench_axes(n, false, 100.0), vec![], vec![], None).await?;
    let started = start.elapsed();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let rss_per_axis_idle_kb = (rss_kb() - rss_before) / n as f64;
    if n > MOVING_MEASURED_UP_TO {
        node.shutdown().await;
        session.close().await?;
        observer.close().await?;
        return Ok(Scale { axes: n, start: started, rss_per_axis_idle_kb, moving: None });
    }
    let counter = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let count = counter.clone();
    let _all = observer
        .declare_subscriber("motor/**")
        .callback(move |_| {
            count.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        })
        .await?;
    tokio::time::sleep(Duration::from_millis(200)).await;
    // Long moves (10 mm/s for 1000 mm) keep every axis moving through the window.
    for i in 0..n {
        session.put(format!("motor/b{i}/VAL"), "1000").encoding(Encoding::TEXT_PLAIN).await?;
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (cpu0, pubs0, t0) = (cpu_seconds(), counter.load(std::sync::atomic::Ordering::Relaxed), Instant::now());
    tokio::time::sleep(Duration::from_secs_f64(window)).await;
    let elapsed = t0.elapsed().as_secs_f64();
    let cpu_moving = (cpu_seconds() - cpu0) / elapsed;
    let publications_per_s = (counter.load(std::sync::atomic::Ordering::Relaxed) - pubs0) as f64 / elapsed;
    node.shutdown().await;
    session.close().await?;
    observer.close().await?;
    Ok(Scale { axes: n, start: started, rss_per_axis_idle_kb, moving: Some((cpu_moving, publications_per_s)) })
}

/// From spawning a node process with `n` axes to all of them answering a get.
async fn startup(n: usize) -> Result<Duration, Error> {
    let endpoint = free_endpoint()?;
    let start = Instant::now();
    let _server = Server::spawn(&endpoint, n)?;
    let session = client_when_ready(&endpoint, start).await?;
    wait_for_axes(&session, n, Duration::from_secs(120)).await?;
    Ok(start.elapsed())
}

/// Run every measurement and print the figures.
pub async fn run(options: &BenchOptions) -> Result<(), Error> {
    println!(
        "zmotor bench: {} moves, scales {:?}, start-up of {} axes",
        options.moves, options.scales, options.startup_axes
    );
    println!("\n1. command latency (client and node in separate processes, TCP on 127.0.0.1), µs");
    let l = latency(options.moves).await?;
    println!("   {:<34} {:>9} {:>9} {:>9}", "", "p50", "p90", "p99");
    for (name, p) in [
        ("put VAL → DMOV 0 at the client", &l.dmov0),
        ("put VAL → DMOV 1 (instant sim)", &l.dmov1),
        ("Zenoh pub/sub round trip", &l.rtt),
    ] {
        println!("   {name:<34} {:>9.1} {:>9.1} {:>9.1}", p.p50, p.p90, p.p99);
    }
    println!(
        "   ratio DMOV 0 / Zenoh RTT (p50): {:.2}; DMOV 1 / RTT: {:.2}",
        l.dmov0.p50 / l.rtt.p50,
        l.dmov1.p50 / l.rtt.p50
    );

    println!("\n2. engine cost per event (record alone), ns");
    let e = engine_cost(if options.moves < 1000 { 10_000 } else { 200_000 });
    println!(
        "   write (processing, no motion): {:.0}   status update: {:.0}   full move cycle (write + 2 callbacks): {:.0}",
        e.write_ns, e.status_ns, e.move_cycle_ns
    );

    println!("\n3. scale: axes in one process, readback at 100 Hz while moving");
    println!(
        "   {:>7} {:>12} {:>16} {:>15} {:>18}",
        "axes", "start (s)", "RSS/axis idle KB", "CPU moving (%)", "publications/s"
    );
    for &n in &options.scales {
        match scale(n, options.window).await {
            Ok(s) => {
                let (cpu, publications) = match s.moving {
                    Some((cpu, publications)) => (format!("{:.0}", cpu * 100.0), format!("{publications:.0}")),
                    None => ("not measured".into(), format!("(> {MOVING_MEASURED_UP_TO} axes)")),
                };
                println!(
                    "   {:>7} {:>12.2} {:>16.1} {:>15} {:>18}",
                    s.axes,
                    s.start.as_secs_f64(),
                    s.rss_per_axis_idle_kb,
                    cpu,
                    publications
                )
            }
            Err(e) => println!("   {n:>7} failed: {e}"),
        }
    }

    println!("\n4. start-up: process start → all {} axes answer get", options.startup_axes);
    let t = startup(options.startup_axes).await?;
    println!("   {:.2} s", t.as_secs_f64());
    Ok(())
}

/// An axis under the same clock as the engine cost figures, for the criterion benches.
pub fn instant_axis() -> Axis {
    let sim = SimAxis::new(SimConfig { instant: true, ..SimConfig::default() });
    Axis::new(Fields { mres: 0.001, velo: 10.0, ..Fields::default() }, Box::new(sim), PollRates::default(), 0.0)
}
