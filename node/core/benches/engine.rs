//! Engine cost per event (criterion): `cargo bench -p zmotor-core --bench engine`. This is the
//! one measurement of the engine's cost; `zmotor bench` measures the node as users run it.

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use std::time::Duration;
use zmotor_core::{Axis, AxisService, DeviceStatus, Instant, MotorRecord, PollRates, SimAxis, SimConfig, WriteRequest};
use zmotor_msgs::bits::msta;
use zmotor_msgs::{Field, Fields, KeyLayout, PayloadEncoding, Value};

fn status(position: f64, done: bool) -> DeviceStatus {
    DeviceStatus { position, msta: if done { msta::DONE } else { 0 }, ..DeviceStatus::default() }
}

fn fields() -> Fields {
    Fields { mres: 0.001, velo: 10.0, ..Fields::default() }
}

fn booted() -> MotorRecord {
    let mut record = MotorRecord::new(fields());
    record.init(status(0.0, true));
    record.drain_outputs().count();
    record
}

/// An axis whose simulator arrives at once, so the figure is the engine, device support and
/// axis bookkeeping of one move, with no time passing.
fn instant_axis() -> Axis {
    let sim = SimAxis::new(SimConfig { instant: true, ..SimConfig::default() });
    Axis::new(fields(), Box::new(sim), PollRates::default(), Instant::ZERO)
}

fn engine(c: &mut Criterion) {
    let mut record = booted();
    c.bench_function("write that processes the record (STUP ON, then its status callback)", |b| {
        b.iter(|| {
            let _ = record.write(Field::STUP, &Value::Int(black_box(1)));
            record.callback(status(0.0, true));
            record.drain_outputs().count()
        })
    });
    let mut record = booted();
    let mut i = 0u64;
    c.bench_function("status update (callback while idle)", |b| {
        b.iter(|| {
            i += 1;
            record.callback(black_box(status((i % 100) as f64, true)));
            record.drain_outputs().count()
        })
    });
    let mut record = booted();
    c.bench_function("move cycle (write VAL, moving callback, done callback)", |b| {
        b.iter(|| {
            i += 1;
            let target = if i.is_multiple_of(2) { 1.0 } else { 2.0 };
            let _ = record.write(Field::VAL, &Value::Float(black_box(target)));
            record.callback(status(target * 500.0, false));
            record.callback(status(target * 1000.0, true));
            record.drain_outputs().count()
        })
    });
    let mut axis = instant_axis();
    c.bench_function("axis move on the instant simulator (write VAL to DMOV 1)", |b| {
        b.iter(|| {
            i += 1;
            let target = if i.is_multiple_of(2) { 1.0 } else { 2.0 };
            let _ = axis.write(Instant::ZERO, Field::VAL, &Value::Float(black_box(target)));
            axis.drain_events().count()
        })
    });
}

/// A request's reply handle as large as a Zenoh query (120 bytes), which the node's service holds.
type QuerySized = [u64; 15];

/// A moving axis's readback poll as the node runs it: the service advances the simulator to the
/// poll and the node takes its outputs (the six readback posts of a poll, with their markers).
fn poll(c: &mut Criterion) {
    let rates = PollRates { moving: Duration::from_millis(10), idle: Duration::from_secs(1) };
    let sim = SimAxis::new(SimConfig::default());
    let axis = Axis::new(Fields { mres: 0.001, velo: 1.0, ..Fields::default() }, Box::new(sim), rates, Instant::ZERO);
    let mut service: AxisService<QuerySized> = AxisService::new(&KeyLayout::default(), "m1", axis);
    // A move long enough for every poll criterion makes (a micrometre a poll).
    service.put(Instant::ZERO, WriteRequest::new("VAL", b"1000000", PayloadEncoding::Text));
    while service.poll_output().is_some() {}
    let mut now = Instant::ZERO;
    let mut next_poll = || {
        now = service.poll_timeout().unwrap_or(now);
        service.handle_timeout(now);
        std::iter::from_fn(|| service.poll_output()).count()
    };
    assert!(next_poll() >= 6, "a moving axis posts its readbacks at each poll");
    c.bench_function("a moving axis's readback poll through the service, its posts taken", |b| b.iter(&mut next_poll));
}

criterion_group!(benches, engine, poll);
criterion_main!(benches);
