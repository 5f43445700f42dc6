//! Fast readback (part 12), as a robot arm reads its joints: a handful of axes read back at
//! 1 kHz in a node process, their RBV seen by a subscriber here: how regular the samples of each
//! axis arrive, and how late after the node read the status (the Zenoh timestamp on every post),
//! beside Zenoh's own one-way latency to an echo process.

use crate::axes::{bench_axis, bench_key};
use crate::bench::{bench_launch, Echo};
use crate::process::{client_when_ready, wait_for_axes, Programs};
use crate::stats::Percentiles;
use crate::{BenchOptions, Error};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};
use zenoh::bytes::Encoding;
use zmotor_msgs::{Field, KeyLayout};

/// The joints of an arm and a hand, read back every millisecond.
const AXES: usize = 16;
const READBACK_HZ: f64 = 1000.0;
/// Issue 26's targets: the p99 of |interval − 1 ms|, and the median latency against the echo's
/// one-way latency.
const JITTER_P99_LIMIT_US: f64 = 500.0;
const LATENCY_RATIO_LIMIT: f64 = 1.2;

/// One RBV sample as it arrived: its axis, when, and how long after the node stamped it.
struct Arrival {
    axis: usize,
    at: Instant,
    latency: Duration,
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
    let (_node, endpoint) = programs.launch("fast-readback", &bench_launch(AXES, READBACK_HZ))?;
    let client = client_when_ready(&endpoint).await?;
    let session = client.session().clone();
    wait_for_axes(&session, AXES, Duration::from_secs(60)).await?;
    let arrivals: Arc<Mutex<Vec<Arrival>>> = Arc::default();
    let unstamped = Arc::new(AtomicU64::new(0));
    let (into, recording) = (arrivals.clone(), Arc::new(AtomicBool::new(false)));
    let (on, unstamped_seen) = (recording.clone(), unstamped.clone());
    let layout = KeyLayout::default();
    let names: Vec<String> = (0..AXES).map(bench_axis).collect();
    let _readbacks = session
        .declare_subscriber(layout.field("*", Field::RBV))
        .callback(move |sample| {
            if !on.load(Relaxed) {
                return;
            }
            let (at, now) = (Instant::now(), SystemTime::now());
            let axis = KeyLayout::default()
                .axis_chunk(sample.key_expr().as_str())
                .and_then(|name| names.iter().position(|n| n == name));
            let stamped = sample.timestamp().map(|t| t.get_time().to_system_time());
            match (axis, stamped) {
                (Some(axis), Some(stamped)) => {
                    let latency = now.duration_since(stamped).unwrap_or_default();
                    into.lock().unwrap_or_else(|e| e.into_inner()).push(Arrival { axis, at, latency });
                }
                _ => {
                    unstamped_seen.fetch_add(1, Relaxed);
                }
            }
        })
        .await?;
    for i in 0..AXES {
        session.put(bench_key(i, Field::VAL), "1000").encoding(Encoding::TEXT_PLAIN).await?;
    }
    // Past the acceleration and the first publications' declarations.
    tokio::time::sleep(Duration::from_secs(1)).await;
    recording.store(true, Relaxed);
    tokio::time::sleep(window).await;
    recording.store(false, Relaxed);
    let arrivals = std::mem::take(&mut *arrivals.lock().unwrap_or_else(|e| e.into_inner()));
    if arrivals.len() < AXES * 2 {
        let unstamped = unstamped.load(Relaxed);
        return Err(format!(
            "{} stamped RBV samples of {AXES} axes in {window:?} ({unstamped} without a timestamp: a zmotor older than its stamps?)",
            arrivals.len()
        )
        .into());
    }
    let mut jitter = Vec::new();
    for axis in 0..AXES {
        let times: Vec<Instant> = arrivals.iter().filter(|a| a.axis == axis).map(|a| a.at).collect();
        let period = Duration::from_secs_f64(1.0 / READBACK_HZ);
        jitter.extend(times.windows(2).map(|w| (w[1] - w[0]).abs_diff(period)));
    }
    let per_axis_per_s = arrivals.len() as f64 / AXES as f64 / window.as_secs_f64();
    let latency = Percentiles::of(arrivals.into_iter().map(|a| a.latency).collect());
    let jitter = Percentiles::of(jitter);
    let one_way = Percentiles::of(round_trips);
    println!("   {:<44} {:>8} {:>8} {:>8} {:>8}", "", "p50", "p90", "p99", "max");
    for (what, p) in [
        ("jitter, |interval − 1 ms|", &jitter),
        ("latency, arrival − the node's stamp", &latency),
        ("Zenoh one-way to an echo (the floor)", &one_way),
    ] {
        println!("   {what:<44} {:>8.1} {:>8.1} {:>8.1} {:>8.1}", p.p50, p.p90, p.p99, p.max);
    }
    let ratio = latency.p50 / one_way.p50;
    let met = |ok: bool| if ok { "met" } else { "MISSED" };
    println!(
        "   {per_axis_per_s:.1} RBV per axis and second; targets: p99 jitter < {JITTER_P99_LIMIT_US} µs: {:.1} {}; \
         latency p50 <= {LATENCY_RATIO_LIMIT} × the echo's: {ratio:.2} × {}",
        jitter.p99,
        met(jitter.p99 < JITTER_P99_LIMIT_US),
        met(ratio <= LATENCY_RATIO_LIMIT)
    );
    Ok(())
}
