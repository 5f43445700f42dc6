//! Fast readback (part 12), as a robot arm reads its joints: a handful of axes read back at
//! 1 kHz in a node process, their RBV seen by a subscriber here: how regular the samples of each
//! axis arrive, and how late after the node read the status (the Zenoh timestamp on every post),
//! beside Zenoh's own one-way latency to an echo process and the regularity of Zenoh alone
//! publishing the same fields at the same rate.

use crate::axes::{bench_axis, bench_key};
use crate::bench::{bench_launch, Echo};
use crate::process::{client_when_ready, wait_for_axes, Programs};
use crate::stats::Percentiles;
use crate::{BenchOptions, Error};
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};
use zenoh::bytes::Encoding;
use zenoh::Session;
use zmotor_client::free_local_endpoint;
use zmotor_msgs::{Field, KeyLayout};

/// The joints of an arm and a hand, read back every millisecond.
const AXES: usize = 16;
const READBACK_HZ: f64 = 1000.0;
/// Issue 26's targets: the p99 of |interval − 1 ms|, and the median latency against the echo's
/// one-way latency.
const JITTER_P99_LIMIT_US: f64 = 500.0;
const LATENCY_RATIO_LIMIT: f64 = 1.2;

/// One RBV sample as it arrived: its axis, when, and how long after it was stamped (Zenoh
/// alone does not stamp).
struct Arrival {
    axis: usize,
    at: Instant,
    latency: Option<Duration>,
}

/// The RBV samples of the bench's axes that reach `session` during `window`, once `warm_up` has
/// passed.
async fn record_readbacks(session: &Session, warm_up: Duration, window: Duration) -> Result<Vec<Arrival>, Error> {
    let arrivals: Arc<Mutex<Vec<Arrival>>> = Arc::default();
    let (into, recording) = (arrivals.clone(), Arc::new(AtomicBool::new(false)));
    let on = recording.clone();
    let names: Vec<String> = (0..AXES).map(bench_axis).collect();
    let _readbacks = session
        .declare_subscriber(KeyLayout::default().field("*", Field::RBV))
        .callback(move |sample| {
            if !on.load(Relaxed) {
                return;
            }
            let (at, now) = (Instant::now(), SystemTime::now());
            let axis = KeyLayout::default()
                .axis_chunk(sample.key_expr().as_str())
                .and_then(|name| names.iter().position(|n| n == name));
            let latency =
                sample.timestamp().map(|t| now.duration_since(t.get_time().to_system_time()).unwrap_or_default());
            if let Some(axis) = axis {
                into.lock().unwrap_or_else(|e| e.into_inner()).push(Arrival { axis, at, latency });
            }
        })
        .await?;
    tokio::time::sleep(warm_up).await;
    recording.store(true, Relaxed);
    tokio::time::sleep(window).await;
    recording.store(false, Relaxed);
    let recorded = std::mem::take(&mut *arrivals.lock().unwrap_or_else(|e| e.into_inner()));
    Ok(recorded)
}

/// |interval − period| between the successive samples of each axis.
fn jitter(arrivals: &[Arrival]) -> Percentiles {
    let period = Duration::from_secs_f64(1.0 / READBACK_HZ);
    let mut jitter = Vec::new();
    for axis in 0..AXES {
        let times: Vec<Instant> = arrivals.iter().filter(|a| a.axis == axis).map(|a| a.at).collect();
        jitter.extend(times.windows(2).map(|w| (w[1] - w[0]).abs_diff(period)));
    }
    Percentiles::of(jitter)
}

pub(crate) async fn fast_readback_part(programs: &Programs, options: &BenchOptions) -> Result<(), Error> {
    let window = Duration::from_secs_f64(options.fast_readback_window);
    println!("\n12. fast readback, as a robot arm reads its joints: {AXES} axes moving, readback {READBACK_HZ:.0} Hz, in a node");
    println!(
        "   process (`zmotor launch`); a subscriber of their RBV here for {:.0} s: the interval between the",
        window.as_secs_f64()
    );
    println!("   samples of each axis (jitter: |interval − 1 ms|) and each sample's latency (its arrival less the");
    println!("   Zenoh timestamp the node stamps when it reads the status), beside Zenoh's one-way latency to an");
    println!("   echo process (half its round trip, same run); µs");
    let echo = Echo::start(programs).await?;
    let mut round_trips = Vec::new();
    for _ in 0..options.moves.max(20) {
        if let Some(rtt) = echo.round_trip().await {
            round_trips.push(rtt / 2);
        }
    }
    drop(echo);
    let (node, endpoint) = programs.launch("fast-readback", &bench_launch(AXES, READBACK_HZ))?;
    let client = client_when_ready(&endpoint).await?;
    let session = client.session().clone();
    wait_for_axes(&session, AXES, Duration::from_secs(60)).await?;
    for i in 0..AXES {
        session.put(bench_key(i, Field::VAL), "1000").encoding(Encoding::TEXT_PLAIN).await?;
    }
    // Past the acceleration and the first publications' declarations.
    let arrivals = record_readbacks(&session, Duration::from_secs(1), window).await?;
    let stamped: Vec<Duration> = arrivals.iter().filter_map(|a| a.latency).collect();
    if stamped.len() < AXES * 2 {
        return Err(format!(
            "{} stamped RBV samples of {AXES} axes in {window:?} ({} without a timestamp: a zmotor older than its stamps?)",
            stamped.len(),
            arrivals.len() - stamped.len()
        )
        .into());
    }
    drop((client, node));
    // Zenoh alone, publishing the fields a moving axis posts, for as many axes at the same rate.
    let floor_endpoint = free_local_endpoint()?;
    let (axes, rate) = (AXES.to_string(), READBACK_HZ.to_string());
    let _floor = programs.floor(&["publish", "--listen", &floor_endpoint, "--axes", &axes, "--rate", &rate])?;
    let floor_client = client_when_ready(&floor_endpoint).await?;
    let floor_arrivals = record_readbacks(floor_client.session(), Duration::from_secs(1), window).await?;
    if floor_arrivals.len() < AXES * 2 {
        return Err(format!("{} RBV samples of Zenoh alone's {AXES} axes in {window:?}", floor_arrivals.len()).into());
    }
    let floor_per_axis_per_s = floor_arrivals.len() as f64 / AXES as f64 / window.as_secs_f64();
    let per_axis_per_s = arrivals.len() as f64 / AXES as f64 / window.as_secs_f64();
    let (jitter, floor_jitter) = (jitter(&arrivals), jitter(&floor_arrivals));
    let latency = Percentiles::of(stamped);
    let one_way = Percentiles::of(round_trips);
    println!("   {:<44} {:>8} {:>8} {:>8} {:>8}", "", "p50", "p90", "p99", "max");
    for (what, p) in [
        ("jitter, |interval − 1 ms|", &jitter),
        ("latency, arrival − the node's stamp", &latency),
        ("Zenoh one-way to an echo (the floor)", &one_way),
        ("jitter of Zenoh alone at 1 kHz (the floor)", &floor_jitter),
    ] {
        println!("   {what:<44} {:>8.1} {:>8.1} {:>8.1} {:>8.1}", p.p50, p.p90, p.p99, p.max);
    }
    let ratio = latency.p50 / one_way.p50;
    let met = |ok: bool| if ok { "met" } else { "MISSED" };
    println!(
        "   RBV per axis and second: {per_axis_per_s:.1} from the node, {floor_per_axis_per_s:.1} from Zenoh alone"
    );
    println!(
        "   targets: p99 jitter < {JITTER_P99_LIMIT_US} µs: {:.1} {}; \
         latency p50 <= {LATENCY_RATIO_LIMIT} × the echo's: {ratio:.2} × {}",
        jitter.p99,
        met(jitter.p99 < JITTER_P99_LIMIT_US),
        met(ratio <= LATENCY_RATIO_LIMIT)
    );
    Ok(())
}
