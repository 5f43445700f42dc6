//! The clock of a node's axes: a fixed set of worker threads, each keeping the deadlines of its
//! share of the axes and delivering their ticks in batches. An axis reports its next deadline
//! after each input it handles (`AxisClock::schedule`); a worker sleeps until the earliest one
//! (the kernel's high-resolution timer, tens of microseconds) and ticks every axis then due, on
//! its own thread, one after the other.
//!
//! One task and one timer per axis cost the node more than its axes' records did (1,000 axes
//! polled at 100 Hz: a task wake-up, a timer-wheel entry and a notification per poll). Polls are
//! rounded up to the millisecond, as tokio's timer did, so the axes of a node polled at the same
//! rate share a wake-up; events (the end of a motion, DLY) keep their exact time, so they are
//! reported when they happen.

use crate::input::{AxisInput, Deliver};
use crate::lock;
use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, OnceLock, PoisonError, Weak};
use std::time::{Duration, Instant};

/// No deadline.
const NONE: u64 = u64::MAX;
/// Polls are due on whole milliseconds of the clock.
const POLL_GRAIN_NS: u64 = 1_000_000;

/// One deadline: when (nanoseconds since the origin), and whose.
struct Entry {
    at: u64,
    /// Breaks ties in arrival order.
    seq: u64,
    clock: Arc<AxisClock>,
}

impl PartialEq for Entry {
    fn eq(&self, other: &Self) -> bool {
        (self.at, self.seq) == (other.at, other.seq)
    }
}

impl Eq for Entry {}

impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Entry {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        (self.at, self.seq).cmp(&(other.at, other.seq))
    }
}

#[derive(Default)]
struct Queue {
    due: BinaryHeap<Reverse<Entry>>,
    seq: u64,
    stopped: bool,
}

/// The deadlines one worker keeps.
struct Shard {
    queue: Mutex<Queue>,
    wakeup: Condvar,
    origin: Instant,
}

impl Shard {
    fn push(&self, at: u64, clock: Arc<AxisClock>) {
        let mut queue = lock(&self.queue);
        queue.seq += 1;
        let seq = queue.seq;
        let earliest = queue.due.peek().is_none_or(|Reverse(first)| at < first.at);
        queue.due.push(Reverse(Entry { at, seq, clock }));
        if earliest {
            self.wakeup.notify_one();
        }
    }

    fn now(&self) -> u64 {
        nanos(self.origin.elapsed())
    }
}

/// The workers of a node; they end when the last handle is dropped.
pub(crate) struct Ticker {
    shards: Vec<Arc<Shard>>,
    next: std::sync::atomic::AtomicUsize,
}

impl Ticker {
    /// Start `workers` threads (at least one), on the clock whose origin is `origin`. Ticks are
    /// handled in `runtime`'s context (an axis may spawn onto it).
    pub(crate) fn start(workers: usize, origin: Instant, runtime: tokio::runtime::Handle) -> std::io::Result<Self> {
        let mut shards = Vec::new();
        for worker in 0..workers.max(1) {
            let shard = Arc::new(Shard { queue: Mutex::default(), wakeup: Condvar::new(), origin });
            let (kept, runtime) = (shard.clone(), runtime.clone());
            std::thread::Builder::new().name(format!("zmotor-tick-{worker}")).spawn(move || {
                let _context = runtime.enter();
                keep(&kept);
            })?;
            shards.push(shard);
        }
        Ok(Self { shards, next: Default::default() })
    }

    /// The clock of a new axis, on the workers in turn.
    pub(crate) fn clock(&self) -> Arc<AxisClock> {
        let index = self.next.fetch_add(1, Ordering::Relaxed) % self.shards.len();
        Arc::new(AxisClock {
            shard: self.shards[index].clone(),
            scheduled: AtomicU64::new(NONE),
            axis: OnceLock::new(),
        })
    }
}

impl Drop for Ticker {
    fn drop(&mut self) {
        for shard in &self.shards {
            lock(&shard.queue).stopped = true;
            shard.wakeup.notify_one();
        }
    }
}

/// One axis's place on a worker: its deadline, and the axis to tick.
pub(crate) struct AxisClock {
    shard: Arc<Shard>,
    /// The deadline in the worker's queue (nanoseconds since the origin), `NONE` if none:
    /// entries of other deadlines are stale and skipped.
    scheduled: AtomicU64,
    /// Weak: the axis holds its clock.
    axis: OnceLock<Weak<dyn Deliver>>,
}

impl AxisClock {
    /// The axis this clock ticks, from now on.
    pub(crate) fn attach(&self, axis: Weak<dyn Deliver>) {
        let _ = self.axis.set(axis);
    }

    /// The axis's next poll (`AxisService::poll_timeout`) and next event (`event_timeout`), as
    /// they are after an input: a tick is delivered then (a poll on the next whole millisecond).
    pub(crate) fn schedule(self: &Arc<Self>, poll: Option<zmotor_core::Instant>, event: Option<zmotor_core::Instant>) {
        let at = match poll {
            None => NONE,
            Some(poll) if Some(poll) == event => nanos(poll.since_origin()),
            Some(poll) => nanos(poll.since_origin()).div_ceil(POLL_GRAIN_NS).saturating_mul(POLL_GRAIN_NS),
        };
        if self.scheduled.swap(at, Ordering::AcqRel) != at && at != NONE {
            self.shard.push(at, self.clone());
        }
    }
}

fn nanos(since_origin: Duration) -> u64 {
    u64::try_from(since_origin.as_nanos()).unwrap_or(NONE - 1)
}

/// A worker: tick the axes due, sleep until the next deadline.
fn keep(shard: &Shard) {
    let mut due = Vec::new();
    let mut queue = lock(&shard.queue);
    loop {
        if queue.stopped {
            return;
        }
        let now = shard.now();
        while queue.due.peek().is_some_and(|Reverse(first)| first.at <= now) {
            if let Some(Reverse(entry)) = queue.due.pop() {
                due.push(entry);
            }
        }
        if !due.is_empty() {
            drop(queue);
            for Entry { at, clock, .. } in due.drain(..) {
                // A deadline the axis no longer has is skipped; a taken one is cleared, so the
                // axis reports its next one after the tick, even if it is the same.
                if clock.scheduled.compare_exchange(at, NONE, Ordering::AcqRel, Ordering::Acquire).is_ok() {
                    if let Some(axis) = clock.axis.get().and_then(Weak::upgrade) {
                        axis.deliver(AxisInput::Tick);
                    }
                }
            }
            queue = lock(&shard.queue);
            continue;
        }
        queue = match queue.due.peek().map(|Reverse(first)| first.at - now) {
            Some(wait) => {
                shard.wakeup.wait_timeout(queue, Duration::from_nanos(wait)).unwrap_or_else(PoisonError::into_inner).0
            }
            None => shard.wakeup.wait(queue).unwrap_or_else(PoisonError::into_inner),
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;

    /// Records when each tick came.
    struct Recorder(Mutex<mpsc::Sender<Instant>>);

    impl Deliver for Recorder {
        fn deliver(&self, input: AxisInput) {
            if matches!(input, AxisInput::Tick) {
                let _ = lock(&self.0).send(Instant::now());
            }
        }
    }

    fn axis(ticker: &Ticker) -> (Arc<AxisClock>, Arc<Recorder>, mpsc::Receiver<Instant>) {
        let (sender, ticks) = mpsc::channel();
        let recorder = Arc::new(Recorder(Mutex::new(sender)));
        let clock = ticker.clock();
        clock.attach(Arc::downgrade(&recorder) as Weak<dyn Deliver>);
        (clock, recorder, ticks)
    }

    fn at(origin: Instant, t: Instant) -> Option<zmotor_core::Instant> {
        Some(zmotor_core::Instant::after(t - origin))
    }

    #[tokio::test]
    async fn an_event_is_ticked_at_its_time_and_a_poll_on_the_next_millisecond() {
        let origin = Instant::now();
        let ticker = Ticker::start(1, origin, tokio::runtime::Handle::current()).unwrap();
        let (event_clock, _event_axis, event_ticks) = axis(&ticker);
        let (poll_clock, _poll_axis, poll_ticks) = axis(&ticker);
        let event = Instant::now() + Duration::from_micros(20_300);
        let poll = Instant::now() + Duration::from_micros(10_300);
        event_clock.schedule(at(origin, event), at(origin, event));
        poll_clock.schedule(at(origin, poll), None);
        let event_tick = event_ticks.recv_timeout(Duration::from_secs(5)).unwrap();
        let poll_tick = poll_ticks.recv_timeout(Duration::from_secs(5)).unwrap();
        assert!(event_tick >= event, "an event ticked {:?} early", event - event_tick);
        let grain = origin + Duration::from_nanos(nanos(poll - origin).div_ceil(POLL_GRAIN_NS) * POLL_GRAIN_NS);
        assert!(poll_tick >= grain, "a poll ticked before its millisecond");
        assert!(event_ticks.try_recv().is_err() && poll_ticks.try_recv().is_err(), "each deadline ticks once");
    }

    #[tokio::test]
    async fn a_deadline_moved_or_withdrawn_before_it_came_does_not_tick() {
        let origin = Instant::now();
        let ticker = Ticker::start(2, origin, tokio::runtime::Handle::current()).unwrap();
        let (moved, _moved_axis, moved_ticks) = axis(&ticker);
        let (withdrawn, _withdrawn_axis, withdrawn_ticks) = axis(&ticker);
        let soon = Instant::now() + Duration::from_millis(20);
        let later = soon + Duration::from_millis(40);
        moved.schedule(at(origin, soon), at(origin, soon));
        moved.schedule(at(origin, later), at(origin, later));
        withdrawn.schedule(at(origin, soon), at(origin, soon));
        withdrawn.schedule(None, None);
        let tick = moved_ticks.recv_timeout(Duration::from_secs(5)).unwrap();
        assert!(tick >= later, "ticked at the deadline it no longer had");
        assert!(withdrawn_ticks.recv_timeout(Duration::from_millis(100)).is_err(), "a withdrawn deadline ticked");
        assert!(moved_ticks.try_recv().is_err(), "the moved deadline ticked twice");
    }

    #[tokio::test]
    async fn the_same_deadline_reported_again_after_its_tick_ticks_again() {
        let origin = Instant::now();
        let ticker = Ticker::start(1, origin, tokio::runtime::Handle::current()).unwrap();
        let (clock, _axis, ticks) = axis(&ticker);
        let past = at(origin, origin);
        clock.schedule(past, past);
        ticks.recv_timeout(Duration::from_secs(5)).unwrap();
        // An axis whose deadline stayed where it was (still due) must be ticked again.
        clock.schedule(past, past);
        ticks.recv_timeout(Duration::from_secs(5)).unwrap();
    }
}
