//! The soak (part 11): the write storm of part 7 on 20 axes and 100 axes moving with readback
//! at 100 Hz, in one node process, for `--minutes`; its resident memory sampled throughout. An
//! IOC runs for months: after the warm-up (the first quarter, when publishers and routes are
//! made) the memory must stay flat.

use crate::axes::{bench_axis, bench_key};
use crate::bench::{bench_launch_at, storm_target, until_heard};
use crate::process::{client_when_ready, wait_for_axes, Programs};
use crate::stats::{cpu_seconds, percent, rss_kb};
use crate::{BenchOptions, Error};
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};
use zenoh::bytes::Encoding;
use zenoh::qos::CongestionControl;
use zmotor_msgs::{Field, KeyLayout};

/// Axes written to by the storm (b0 …), and its writes a second in all (the rate measured from
/// outside in issue 26).
const STORM_AXES: usize = 20;
const STORM_WRITES_PER_S: f64 = 970.0;
/// Axes moving all along (after the storm's), readback 100 Hz, and how often they turn round:
/// sooner than a 1000 mm move at 10 mm/s ends, so they never stop.
const MOVING_AXES: usize = 100;
const TURN_EVERY: Duration = Duration::from_secs(60);
/// Most growth of the resident memory after the warm-up (issue 26: under 1 MB over the last
/// 45 minutes of an hour).
const GROWTH_LIMIT_MB: f64 = 1.0;

pub(crate) async fn soak_part(programs: &Programs, options: &BenchOptions) -> Result<(), Error> {
    let minutes = options.soak_minutes;
    println!(
        "\n11. the soak: {minutes} minutes of a node process (`zmotor launch`) with {STORM_AXES} axes under a storm"
    );
    println!("   of {STORM_WRITES_PER_S:.0} VAL writes/s (as part 7) and {MOVING_AXES} axes moving all along, readback 100 Hz;");
    println!("   one subscriber of every key here. Resident memory sampled; the first quarter is the warm-up.");
    let (node, endpoint) = programs
        .launch("soak", &bench_launch_at(STORM_AXES + MOVING_AXES, |i| if i < STORM_AXES { 10.0 } else { 100.0 }))?;
    let pid = node.pid();
    let client = client_when_ready(&endpoint).await?;
    let session = client.session().clone();
    let axes = STORM_AXES + MOVING_AXES;
    wait_for_axes(&session, axes, Duration::from_secs(120)).await?;
    let samples = Arc::new(AtomicU64::new(0));
    let counter = samples.clone();
    let _everything = session
        .declare_subscriber(KeyLayout::default().everything())
        .callback(move |_| {
            counter.fetch_add(1, Relaxed);
        })
        .await?;
    let probe = session.declare_subscriber(bench_key(0, Field::VAL)).await?;
    until_heard(&client, &bench_axis(0), &probe).await?;
    drop(probe);
    let mut writers = Vec::new();
    for i in 0..STORM_AXES {
        let publisher = session.declare_publisher(bench_key(i, Field::VAL)).encoding(Encoding::TEXT_PLAIN);
        writers.push(publisher.congestion_control(CongestionControl::Block).await?);
    }
    let duration = Duration::from_secs_f64(minutes * 60.0);
    // At least twenty samples of the memory, at most one each ten seconds.
    let sample_every = (duration / 20).min(Duration::from_secs(10));
    let report_every = (duration / 6).max(sample_every);
    let (start, cpu0) = (Instant::now(), cpu_seconds(&pid));
    let mut memory: Vec<(Duration, f64)> = vec![(Duration::ZERO, rss_kb(&pid))];
    let (mut next_sample, mut next_report, mut next_turn) = (sample_every, report_every, Duration::ZERO);
    let (mut sent, mut turns) = (0u64, 0u64);
    let mut ticks = tokio::time::interval(Duration::from_secs_f64(1.0 / STORM_WRITES_PER_S));
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    while start.elapsed() < duration {
        ticks.tick().await;
        writers[sent as usize % STORM_AXES].put(storm_target(sent)).await?;
        sent += 1;
        let now = start.elapsed();
        if now >= next_turn {
            let target = if turns.is_multiple_of(2) { "1000" } else { "-1000" };
            for i in STORM_AXES..axes {
                session.put(bench_key(i, Field::VAL), target).encoding(Encoding::TEXT_PLAIN).await?;
            }
            turns += 1;
            next_turn += TURN_EVERY;
        }
        if now >= next_sample {
            memory.push((now, rss_kb(&pid)));
            next_sample += sample_every;
        }
        if now >= next_report {
            println!(
                "   {:>6.1} min: resident {:.1} MB, {sent} writes sent",
                now.as_secs_f64() / 60.0,
                memory.last().map_or(0.0, |m| m.1) / 1024.0
            );
            next_report += report_every;
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    let cpu = (cpu_seconds(&pid) - cpu0) / elapsed;
    memory.push((start.elapsed(), rss_kb(&pid)));
    let soak = Soak::of(&memory, duration);
    println!(
        "   {sent} writes ({:.0}/s), {:.0} samples/s to the subscriber, node CPU {}",
        sent as f64 / elapsed,
        samples.load(Relaxed) as f64 / elapsed,
        percent(cpu)
    );
    println!(
        "   resident: {:.1} MB at the start, {:.1} MB after the warm-up, {:.1} MB at the end (max {:.1})",
        soak.start_mb, soak.warm_mb, soak.end_mb, soak.max_mb
    );
    println!(
        "   target: growth after the warm-up < {GROWTH_LIMIT_MB} MB: {:+.2} MB over the last {:.1} min {}",
        soak.growth_mb(),
        duration.as_secs_f64() * 0.75 / 60.0,
        if soak.growth_mb() < GROWTH_LIMIT_MB { "met" } else { "MISSED" }
    );
    Ok(())
}

/// The resident memory of a soak: at the start, after the warm-up, at the end.
struct Soak {
    start_mb: f64,
    /// The median of the samples of the tenth of the run after the warm-up.
    warm_mb: f64,
    /// The median of the samples of the run's last tenth.
    end_mb: f64,
    max_mb: f64,
}

impl Soak {
    /// From `(time, resident kB)` samples of a run of `duration`: medians over tenths, so a
    /// sample caught in the middle of a burst of allocations does not make the figure.
    fn of(memory: &[(Duration, f64)], duration: Duration) -> Self {
        let median_between = |from: f64, to: f64| {
            let mut inside: Vec<f64> = memory
                .iter()
                .filter(|(t, _)| (from..=to).contains(&(t.as_secs_f64() / duration.as_secs_f64())))
                .map(|(_, kb)| kb / 1024.0)
                .collect();
            inside.sort_by(f64::total_cmp);
            inside.get(inside.len() / 2).copied().unwrap_or(0.0)
        };
        Self {
            start_mb: memory.first().map_or(0.0, |m| m.1 / 1024.0),
            warm_mb: median_between(0.25, 0.35),
            end_mb: median_between(0.9, 1.1),
            max_mb: memory.iter().map(|m| m.1 / 1024.0).fold(0.0, f64::max),
        }
    }

    fn growth_mb(&self) -> f64 {
        self.end_mb - self.warm_mb
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(mb_at_minute: impl Fn(u64) -> f64) -> Soak {
        let memory: Vec<(Duration, f64)> =
            (0..=100).map(|m| (Duration::from_secs(60 * m), mb_at_minute(m) * 1024.0)).collect();
        Soak::of(&memory, Duration::from_secs(6000))
    }

    #[test]
    fn a_flat_memory_with_a_spike_has_grown_by_nothing() {
        let soak = run(|m| match m {
            0..25 => 18.0 + 0.24 * m as f64,
            95 => 60.0,
            _ => 24.0,
        });
        assert_eq!((soak.start_mb, soak.warm_mb, soak.end_mb, soak.max_mb), (18.0, 24.0, 24.0, 60.0));
        assert_eq!(soak.growth_mb(), 0.0);
    }

    #[test]
    fn a_steady_climb_after_the_warm_up_is_its_growth() {
        // 0.1 MB a minute from minute 25: the medians are at minutes 30 and 95.
        let soak = run(|m| if m < 25 { 20.0 } else { 20.0 + 0.1 * (m - 25) as f64 });
        assert!((soak.growth_mb() - 6.5).abs() < 1e-9, "{}", soak.growth_mb());
    }
}
