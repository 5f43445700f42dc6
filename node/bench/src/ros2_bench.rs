//! Part 10, ROS 2: axes as joints as a user deploys them (`[ros2]` in the launch file: the ROS
//! face in the node's process, on its session, fed by its posts), seen by a ROS subscriber on
//! rmw_zenoh's keys in this process beside the same readbacks on zmotor's own keys; and the
//! node's CPU with 100 joints moving, with the ROS face and without.

use crate::axes::{bench_axis, bench_key};
use crate::bench::{bench_launch, Echo};
use crate::process::{client_when_ready, wait_for_axes, Programs};
use crate::stats::{cpu_seconds, percent, Percentiles};
use crate::{BenchOptions, Error};
use std::fmt::Write as _;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use zenoh::bytes::Encoding;
use zenoh::Session;
use zmotor_msgs::{decode_cbor_value, Field};
use zmotor_ros2_proto::{decode, topic_key, JointState, JOINT_STATE};

/// Readbacks per second while moving, in both figures.
const READBACK_HZ: f64 = 50.0;

/// `n` bench axes, and with `ros2` the joints j0 … of a ROS 2 node on them (mm: 0.001 m).
fn joints_launch(n: usize, ros2: bool) -> String {
    let mut text = bench_launch(n, READBACK_HZ);
    if ros2 {
        text.push_str("[ros2]\n");
        for i in 0..n {
            let _ = write!(text, "[[ros2.joint]]\nname = \"j{i}\"\naxis = \"{}\"\nfactor = 0.001\n", bench_axis(i));
        }
    }
    text
}

/// The key of the ROS node's joint states (domain 0, no namespace, Jazzy).
fn joint_states_key() -> String {
    topic_key(0, "/joint_states", &JOINT_STATE)
}

/// Until the ROS face publishes (its state comes at least every second at rest).
async fn until_ros_speaks(session: &Session) -> Result<(), Error> {
    let states = session.declare_subscriber(joint_states_key()).await?;
    tokio::time::timeout(Duration::from_secs(30), states.recv_async())
        .await
        .map_err(|_| "no joint_states within 30 s")??;
    Ok(())
}

/// Long moves on every axis of `n`, then the node's CPU over `window` s; then stop.
async fn cpu_while_moving(programs: &Programs, n: usize, ros2: bool, window: f64) -> Result<(f64, f64), Error> {
    let (node, endpoint) = programs.launch("ros2-cpu", &joints_launch(n, ros2))?;
    let client = client_when_ready(&endpoint).await?;
    let session = client.session().clone();
    wait_for_axes(&session, n, Duration::from_secs(60)).await?;
    if ros2 {
        until_ros_speaks(&session).await?;
    }
    let received = Arc::new(Mutex::new(0u64));
    let counter = received.clone();
    let _states = session
        .declare_subscriber(joint_states_key())
        .callback(move |_| *counter.lock().unwrap_or_else(std::sync::PoisonError::into_inner) += 1)
        .await?;
    for i in 0..n {
        session.put(bench_key(i, Field::VAL), "1000").encoding(Encoding::TEXT_PLAIN).await?;
    }
    tokio::time::sleep(Duration::from_secs(1)).await;
    let pid = node.pid();
    let (cpu0, states0, t0) = (cpu_seconds(&pid), *received.lock().unwrap_or_else(|e| e.into_inner()), Instant::now());
    tokio::time::sleep(Duration::from_secs_f64(window)).await;
    let elapsed = t0.elapsed().as_secs_f64();
    let cpu = (cpu_seconds(&pid) - cpu0) / elapsed;
    let states = (*received.lock().unwrap_or_else(|e| e.into_inner()) - states0) as f64 / elapsed;
    for i in 0..n {
        session.put(bench_key(i, Field::STOP), "1").encoding(Encoding::TEXT_PLAIN).await?;
    }
    session.close().await?;
    Ok((cpu, states))
}

pub(crate) async fn ros2_part(programs: &Programs, options: &BenchOptions) -> Result<(), Error> {
    println!("\n10. ROS 2: axes as joints ([ros2] in the launch file: the ROS face in the node's process, fed by");
    println!("   its posts), a ROS subscriber here on rmw_zenoh's keys beside zmotor's; TCP on 127.0.0.1");
    let (_node, endpoint) = programs.launch("ros2-latency", &joints_launch(1, true))?;
    let echo = Echo::start(programs).await?;
    let client = client_when_ready(&endpoint).await?;
    let session = client.session().clone();
    wait_for_axes(&session, 1, Duration::from_secs(20)).await?;
    until_ros_speaks(&session).await?;
    // Each readback's arrival on zmotor's key and in a JointState (which carries it in metres).
    type Arrivals = Arc<Mutex<Vec<(f64, Instant)>>>;
    let (on_key, on_ros): (Arrivals, Arrivals) = Default::default();
    let keyed = on_key.clone();
    let _rbv = session
        .declare_subscriber(bench_key(0, Field::RBV))
        .callback(move |sample| {
            let at = Instant::now();
            if let Some(mm) = decode_cbor_value(&sample.payload().to_bytes()).ok().and_then(|v| v.as_f64()) {
                keyed.lock().unwrap_or_else(|e| e.into_inner()).push((mm, at));
            }
        })
        .await?;
    let rosy = on_ros.clone();
    let _states = session
        .declare_subscriber(joint_states_key())
        .callback(move |sample| {
            let at = Instant::now();
            if let Ok(state) = decode::<JointState>(&sample.payload().to_bytes(), "JointState") {
                rosy.lock().unwrap_or_else(|e| e.into_inner()).push((state.position[0] * 1e3, at));
            }
        })
        .await?;
    let moving = Duration::from_secs_f64(options.window.max(1.0) * 2.0);
    session.put(bench_key(0, Field::VAL), "1000").encoding(Encoding::TEXT_PLAIN).await?;
    let mut rtt = Vec::new();
    let start = Instant::now();
    while start.elapsed() < moving {
        rtt.extend(echo.round_trip().await);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    session.put(bench_key(0, Field::STOP), "1").encoding(Encoding::TEXT_PLAIN).await?;
    tokio::time::sleep(Duration::from_millis(500)).await;
    let on_key = on_key.lock().unwrap_or_else(|e| e.into_inner()).clone();
    let on_ros = on_ros.lock().unwrap_or_else(|e| e.into_inner()).clone();
    // A reading's two arrivals: the same position (readbacks of a move differ one from the next).
    let gaps: Vec<Duration> = on_ros
        .iter()
        .filter_map(|(mm, ros_at)| {
            let (_, key_at) = on_key.iter().find(|(key_mm, _)| (key_mm - mm).abs() < 1e-9)?;
            Some(ros_at.saturating_duration_since(*key_at))
        })
        .collect();
    if gaps.len() < 10 {
        return Err(format!("only {} readbacks seen both ways", gaps.len()).into());
    }
    let (gaps, rtt) = (Percentiles::of(gaps), Percentiles::of(rtt));
    println!("   one axis moving, readback {READBACK_HZ} Hz; µs                          p50       p90       p99");
    println!(
        "   {:<58} {:>9.1} {:>9.1} {:>9.1}",
        "a readback: JointState arrival − RBV arrival", gaps.p50, gaps.p90, gaps.p99
    );
    println!("   {:<58} {:>9.1} {:>9.1} {:>9.1}", "Zenoh round trip to an echo process", rtt.p50, rtt.p90, rtt.p99);
    println!(
        "   the ROS face adds {:.1} % to a sample's latency (p50, beside half the floor's round trip)",
        gaps.p50 / (rtt.p50 / 2.0) * 100.0
    );
    let joints = if options.scales.iter().any(|&n| n >= 100) { 100 } else { 10 };
    let (without, _) = cpu_while_moving(programs, joints, false, options.window).await?;
    let (with, states_per_s) = cpu_while_moving(programs, joints, true, options.window).await?;
    println!("   {joints} axes moving, readback {READBACK_HZ} Hz each: the node process's CPU (one core = 100 %)");
    println!("   {:<58} {:>9}", "without [ros2]", percent(without));
    println!(
        "   {:<58} {:>9}  ({states_per_s:.0} JointState/s)",
        format!("with [ros2], {joints} joints"),
        percent(with)
    );
    Ok(())
}
