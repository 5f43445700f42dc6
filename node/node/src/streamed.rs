//! What an axis sent the droppable way (`Delivery::Stream`) since its last event post, so that
//! when the network may have dropped some of it, the axis's next event post sends those keys'
//! last values again first: a motion's last readback may come a poll before its end (DMOV 1).
//! Zenoh does not say which sample it dropped, but it drops only after a put found a link's
//! queue full for `wait_before_drop` (1 ms): a put that took that long may have dropped its
//! sample, and marks the node congested unless something else explains it (`Congestion`).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use zenoh::time::Timestamp;
use zmotor_msgs::{Field, StateMarker, Value};

/// A put this slow found a link's queue full (Zenoh's `wait_before_drop`): samples may be
/// dropped from then on. (Half of it was too little: on two busy cores a thread is often
/// preempted that long, and the node took every such put for congestion.)
const SLOW_PUT: Duration = Duration::from_millis(1);

/// How long after a slow put the node takes its links for congested (while a link stays
/// congested, Zenoh drops at once and its next wait comes within milliseconds).
const CONGESTED_FOR: Duration = Duration::from_secs(1);

/// How long after an axis began matching a new key a slow put is put down to that work rather
/// than to the network: one match takes milliseconds at a thousand axes (2.5-5.9 ms measured),
/// and the put itself or a thread it preempts is that much slower.
const NEW_KEY_SLOWS_FOR: Duration = Duration::from_millis(50);

/// Microseconds on the node's clock since its origin, plus one (0 stands for never).
pub(crate) type Micros = u64;

fn micros(duration: Duration) -> Micros {
    u64::try_from(duration.as_micros()).unwrap_or(u64::MAX)
}

/// A clock shared by threads: the node's origin.
#[derive(Clone, Copy)]
pub(crate) struct NodeClock(std::time::Instant);

impl NodeClock {
    pub(crate) fn new(origin: std::time::Instant) -> Self {
        Self(origin)
    }

    fn now(self) -> Micros {
        self.at(std::time::Instant::now())
    }

    fn at(self, instant: std::time::Instant) -> Micros {
        micros(instant.saturating_duration_since(self.0)).saturating_add(1)
    }
}

/// When something last happened, on the node's clock: read as "since" a moment or "within" a
/// window. Shared by threads, so an atomic.
#[derive(Default)]
struct LastSeen(AtomicU64);

impl LastSeen {
    /// It happened at `now`: a thread that read its clock before another's and marks after it
    /// does not move the mark back.
    fn mark(&self, now: Micros) {
        self.0.fetch_max(now, Ordering::AcqRel);
    }

    /// As if it had never happened.
    fn clear(&self) {
        self.0.store(0, Ordering::Release);
    }

    fn since(&self, at: Micros) -> bool {
        self.0.load(Ordering::Acquire) >= at
    }

    fn within(&self, now: Micros, window: Duration) -> bool {
        let last = self.0.load(Ordering::Acquire);
        last != 0 && now.saturating_sub(last) < micros(window)
    }

    /// Whether it happened, `window` ago or longer.
    fn before(&self, now: Micros, window: Duration) -> bool {
        let last = self.0.load(Ordering::Acquire);
        last != 0 && now.saturating_sub(last) >= micros(window)
    }
}

/// Whether the node's links are congested, judged by how long its puts take.
///
/// Two kinds of slowness are not the network's and must not switch the node into its congested
/// mode (every post through the event sender, for `CONGESTED_FOR`), which at a thousand moving
/// axes on two busy cores renewed itself for as long as they moved: Zenoh matching a new key
/// (the first moves), and the event sender preempted inside a put (it makes most of its puts
/// while the node is congested). A slow put while a new key is matched still makes the axes
/// send their stream keys' last samples again at their next event; the event sender counts as
/// congested while it has waited in one put longer than a slow one.
pub(crate) struct Congestion {
    clock: NodeClock,
    key_work: Arc<KeyWork>,
    /// When a put on the axes' way (a tick worker, the inputs thread) was last slow with no new
    /// key matched: the links are taken for congested.
    congested: LastSeen,
    /// When a put on the axes' way was last slow, whatever the cause: it may have dropped.
    slow: LastSeen,
    /// When the event sender's put in progress began; never while it makes none. On a cache
    /// line of its own: the sender writes it at every put, the axes read the others at every post.
    sending: Aligned<LastSeen>,
}

#[repr(align(64))]
struct Aligned<T>(T);

impl Congestion {
    pub(crate) fn new(clock: NodeClock, key_work: Arc<KeyWork>) -> Self {
        let (congested, slow, sending) = Default::default();
        Self { clock, key_work, congested, slow, sending: Aligned(sending) }
    }

    /// Now on the node's clock, as `StreamLog` counts it.
    fn now(&self) -> Micros {
        self.clock.now()
    }

    /// `instant` on the node's clock.
    pub(crate) fn at(&self, instant: std::time::Instant) -> Micros {
        self.clock.at(instant)
    }

    /// Run a put on the axes' way that begins at `start` (read just before, and used for the
    /// decisions before it: at hundreds of thousands of puts a second, five readings of the
    /// clock per put were a few per cent of the node), noting congestion if it was slow.
    /// Returns the clock read at its end (the next put's start, when one follows at once).
    pub(crate) fn timed(&self, start: std::time::Instant, put: impl FnOnce()) -> std::time::Instant {
        put();
        let end = std::time::Instant::now();
        self.took(self.at(end), end.saturating_duration_since(start));
        end
    }

    /// Run a put of the event sender (congestion control Block: it waits for room, drops
    /// nothing), counting the node congested while it waits longer than a slow put.
    pub(crate) fn sending(&self, put: impl FnOnce()) {
        self.sending.0.mark(self.now());
        put();
        self.sending.0.clear();
    }

    /// A put on the axes' way ended at `now`, after `elapsed`.
    fn took(&self, now: Micros, elapsed: Duration) {
        if elapsed < SLOW_PUT {
            return;
        }
        self.slow.mark(now);
        // A new key began matching during this put, or up to NEW_KEY_SLOWS_FOR before it.
        if !self.key_work.new_key_within(now, NEW_KEY_SLOWS_FOR + elapsed) {
            self.congested.mark(now);
        }
    }

    /// Whether a stream sample sent at `at` or later may have been dropped.
    fn since(&self, at: Micros) -> bool {
        self.slow.since(at)
    }

    /// Whether the links are taken for congested at `now`: a put on the axes' way was slow
    /// lately (`CONGESTED_FOR`) with no new key matched, or the event sender has waited in one
    /// put longer than a slow one.
    pub(crate) fn recent_at(&self, now: Micros) -> bool {
        self.congested.within(now, CONGESTED_FOR) || self.sending.0.before(now, SLOW_PUT)
    }
}

/// How long after an axis's last slow work for a new key the network's inputs are handed to the
/// inputs thread (a storm of first moves does that work without pause; a lone one is past).
const KEY_WORK_FOR: Duration = Duration::from_secs(1);

/// When an axis of the node last did Zenoh's slow work for a key: matched a new one (declared
/// a publisher, each matched against every key already there: a millisecond at a thousand axes;
/// or posted a field for the first time without one) or put to a key that has no publisher.
pub(crate) struct KeyWork {
    clock: NodeClock,
    any: LastSeen,
    new_key: LastSeen,
}

impl KeyWork {
    pub(crate) fn new(clock: NodeClock) -> Self {
        Self { clock, any: LastSeen::default(), new_key: LastSeen::default() }
    }

    /// Some is being done now: a put to a key without publisher.
    pub(crate) fn note(&self) {
        self.any.mark(self.clock.now());
    }

    /// A new key is being matched now.
    pub(crate) fn note_new_key(&self) {
        let now = self.clock.now();
        self.any.mark(now);
        self.new_key.mark(now);
    }

    /// Whether some was done within `KEY_WORK_FOR`.
    pub(crate) fn lately(&self) -> bool {
        self.any.within(self.clock.now(), KEY_WORK_FOR)
    }

    fn new_key_within(&self, now: Micros, window: Duration) -> bool {
        self.new_key.within(now, window)
    }

    /// As if none had ever been done.
    #[cfg(test)]
    pub(crate) fn forget(&self) {
        self.any.clear();
        self.new_key.clear();
    }
}

/// One sample sent the droppable way.
pub(crate) enum Streamed {
    Field(Field, Value),
    /// The readback bundle, encoded.
    Bundle(Vec<u8>),
}

impl Streamed {
    /// The sample's bytes on the wire.
    pub(crate) fn into_payload(self) -> Vec<u8> {
        match self {
            Streamed::Field(_, value) => zmotor_msgs::encode_cbor(&value),
            Streamed::Bundle(bundle) => bundle,
        }
    }

    /// The sample's bytes on the wire, the sample kept.
    pub(crate) fn payload(&self) -> Vec<u8> {
        match self {
            Streamed::Field(_, value) => zmotor_msgs::encode_cbor(value),
            Streamed::Bundle(bundle) => bundle.clone(),
        }
    }

    /// Whether both are samples of one key.
    pub(crate) fn same_key(&self, other: &Streamed) -> bool {
        match (self, other) {
            (Streamed::Field(a, _), Streamed::Field(b, _)) => a == b,
            (Streamed::Bundle(_), Streamed::Bundle(_)) => true,
            _ => false,
        }
    }
}

/// One logged stream sample.
struct Logged {
    /// When it was made, in the log's count: the order it is sent again in.
    made: u64,
    sample: Streamed,
    marker: StateMarker,
    stamp: Timestamp,
    /// Not sent yet (`StreamLog::hold`).
    held: bool,
}

/// The last stream sample of each key of one axis since its last event post: sent the droppable
/// way, or held back while the axis's earlier posts still wait in the event sender after a
/// congestion has passed. (Queued behind them instead, a thousand axes polled at 100 Hz kept
/// the sender's queue from ever emptying on two busy cores: every post stayed on the slow way,
/// for as long as the axes moved, with half the readbacks coalesced away.)
#[derive(Default)]
pub(crate) struct StreamLog {
    /// When the first of them was sent.
    since: Option<Micros>,
    entries: Vec<Logged>,
    /// How many are held back.
    held: usize,
    /// Samples logged so far.
    made: u64,
}

impl StreamLog {
    /// `sample` was sent at `now`, the droppable way.
    pub(crate) fn record(&mut self, now: Micros, sample: Streamed, marker: &StateMarker, stamp: Timestamp) {
        self.since.get_or_insert(now);
        self.log(sample, marker, stamp, false);
    }

    /// `sample` is held back: sent once `release`d (the droppable way once its axis may stream,
    /// the events' way if the link is congested again), or first at its next event post,
    /// whichever comes first.
    pub(crate) fn hold(&mut self, sample: Streamed, marker: &StateMarker, stamp: Timestamp) {
        self.held += 1;
        self.log(sample, marker, stamp, true);
    }

    /// A key's sample replaces the one logged before it, in its place (moving the others up
    /// was most of the log's cost at every poll); `made` keeps the order they were made.
    fn log(&mut self, sample: Streamed, marker: &StateMarker, stamp: Timestamp, held: bool) {
        self.made += 1;
        let entry = Logged { made: self.made, sample, marker: marker.clone(), stamp, held };
        match self.entries.iter_mut().find(|e| e.sample.same_key(&entry.sample)) {
            Some(logged) => {
                self.held -= usize::from(logged.held);
                *logged = entry;
            }
            None => self.entries.push(entry),
        }
    }

    /// The log's entries, out of it, in the order they were made.
    fn take_in_order(&mut self) -> Vec<Logged> {
        let mut entries = std::mem::take(&mut self.entries);
        entries.sort_unstable_by_key(|e| e.made);
        entries
    }

    /// Whether a sample is held back.
    pub(crate) fn holds(&self) -> bool {
        self.held > 0
    }

    /// The held samples, oldest first, out of the log: the caller sends (and records) them.
    pub(crate) fn release(&mut self) -> Vec<(Streamed, StateMarker, Timestamp)> {
        if self.held == 0 {
            return Vec::new();
        }
        self.held = 0;
        let (held, sent) = self.take_in_order().into_iter().partition(|e| e.held);
        self.entries = sent;
        held.into_iter().map(|e: Logged| (e.sample, e.marker, e.stamp)).collect()
    }

    /// At an event post: what to send first (all of it, in order, if a sample is held back or
    /// the node was congested since the first was sent), and a fresh log.
    pub(crate) fn take_unsure(&mut self, congestion: &Congestion) -> Vec<(Streamed, StateMarker, Timestamp)> {
        let since = self.since.take();
        let unsure = self.held > 0 || since.is_some_and(|since| congestion.since(since));
        self.held = 0;
        match unsure {
            true => self.take_in_order().into_iter().map(|e| (e.sample, e.marker, e.stamp)).collect(),
            false => {
                // The log's room stays for the next samples.
                self.entries.clear();
                Vec::new()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use zenoh::time::{TimestampId, NTP64};

    fn marker(seq: u64) -> StateMarker {
        StateMarker::new(seq, 0, 0)
    }

    fn keys(sent: &[(Streamed, StateMarker, Timestamp)]) -> Vec<(String, u64)> {
        let key = |s: &Streamed| match s {
            Streamed::Field(field, _) => field.to_string(),
            Streamed::Bundle(_) => "@readback".to_string(),
        };
        sent.iter().map(|(s, m, _)| (key(s), m.seq)).collect()
    }

    fn congestion() -> Congestion {
        let clock = NodeClock::new(std::time::Instant::now());
        Congestion::new(clock, Arc::new(KeyWork::new(clock)))
    }

    const MS: Micros = 1000;

    #[test]
    fn after_a_slow_put_an_event_sends_each_stream_keys_last_sample_again_and_otherwise_nothing() {
        let congestion = congestion();
        let stamp = Timestamp::new(NTP64(0), TimestampId::rand());
        let mut log = StreamLog::default();
        for (seq, field) in [(1, Field::RBV), (2, Field::DRBV), (3, Field::RBV)] {
            log.record(seq * MS, Streamed::Field(field, Value::Float(seq as f64)), &marker(seq), stamp);
        }
        congestion.took(4 * MS, SLOW_PUT / 2);
        assert!(log.take_unsure(&congestion).is_empty(), "quick puts: nothing dropped");
        for (seq, field) in [(4, Field::RBV), (5, Field::DRBV)] {
            log.record(seq * MS, Streamed::Field(field, Value::Float(seq as f64)), &marker(seq), stamp);
        }
        log.record(5 * MS, Streamed::Bundle(vec![1]), &marker(5), stamp);
        log.record(6 * MS, Streamed::Field(Field::RBV, Value::Float(6.0)), &marker(6), stamp);
        congestion.took(7 * MS, SLOW_PUT);
        let again = log.take_unsure(&congestion);
        let expected = [("DRBV", 5), ("@readback", 5), ("RBV", 6)].map(|(k, s)| (k.to_string(), s));
        assert_eq!(keys(&again), expected);
        assert!(log.take_unsure(&congestion).is_empty(), "each is sent again once");
    }

    #[test]
    fn a_held_sample_is_released_once_in_order_or_sent_first_at_the_next_event_with_the_rest() {
        let congestion = congestion();
        let stamp = Timestamp::new(NTP64(0), TimestampId::rand());
        let rbv = |seq: u64| Streamed::Field(Field::RBV, Value::Float(seq as f64));
        let mut log = StreamLog::default();
        log.record(MS, rbv(1), &marker(1), stamp);
        log.hold(Streamed::Field(Field::DRBV, Value::Float(2.0)), &marker(2), stamp);
        log.hold(rbv(3), &marker(3), stamp);
        assert!(log.holds());
        let released = log.release();
        assert_eq!(keys(&released), [("DRBV".to_string(), 2), ("RBV".to_string(), 3)]);
        assert!(!log.holds() && log.release().is_empty(), "released once");
        log.record(4 * MS, rbv(3), &marker(3), stamp);
        assert!(log.take_unsure(&congestion).is_empty(), "sent, none held, no slow put: nothing again");

        log.record(5 * MS, rbv(5), &marker(5), stamp);
        log.hold(Streamed::Bundle(vec![1]), &marker(6), stamp);
        log.hold(rbv(7), &marker(7), stamp);
        let first = log.take_unsure(&congestion);
        assert_eq!(keys(&first), [("@readback".to_string(), 6), ("RBV".to_string(), 7)]);
        assert!(!log.holds() && log.take_unsure(&congestion).is_empty(), "a fresh log");
    }

    #[test]
    fn a_mark_made_late_by_a_thread_that_read_its_clock_early_does_not_move_it_back() {
        let seen = LastSeen::default();
        seen.mark(20 * MS);
        seen.mark(10 * MS);
        assert!(seen.since(20 * MS));
        seen.clear();
        seen.mark(10 * MS);
        assert!(seen.since(10 * MS) && !seen.since(10 * MS + 1));
    }

    #[test]
    fn a_slow_put_takes_the_links_for_congested_for_a_while() {
        let congestion = congestion();
        let at = 10 * MS;
        congestion.took(at, SLOW_PUT / 2);
        assert!(!congestion.recent_at(at), "a quick put");
        congestion.took(at, SLOW_PUT);
        assert!(congestion.recent_at(at));
        assert!(congestion.recent_at(at + micros(CONGESTED_FOR) - 1));
        assert!(!congestion.recent_at(at + micros(CONGESTED_FOR)), "no slow put since");
    }

    #[test]
    fn a_slow_put_while_a_new_key_is_matched_does_not_congest_but_its_samples_are_sent_again() {
        let congestion = congestion();
        let stamp = Timestamp::new(NTP64(0), TimestampId::rand());
        let mut log = StreamLog::default();
        let matched = 100 * MS;
        congestion.key_work.new_key.mark(matched);
        log.record(matched + MS, Streamed::Field(Field::RBV, Value::Float(1.0)), &marker(1), stamp);
        // Slow because the key is matched (2.5-5.9 ms at a thousand axes), or a put beside it.
        let ended = matched + 6 * MS;
        congestion.took(ended, Duration::from_millis(6));
        assert!(!congestion.recent_at(ended), "the matching, not the network");
        assert_eq!(keys(&log.take_unsure(&congestion)), [("RBV".to_string(), 1)], "it may have dropped all the same");
        // A put beginning well after the key began matching is the network's again.
        let later = matched + micros(NEW_KEY_SLOWS_FOR) + 2 * MS;
        congestion.took(later, SLOW_PUT);
        assert!(congestion.recent_at(later));
    }

    #[test]
    fn the_event_sender_counts_as_congested_while_one_put_waits_longer_than_a_slow_one() {
        let congestion = congestion();
        let began = 10 * MS;
        congestion.sending.0.mark(began);
        assert!(!congestion.recent_at(began + micros(SLOW_PUT) - 1), "a put in progress");
        assert!(congestion.recent_at(began + micros(SLOW_PUT)), "stuck in it");
        congestion.sending.0.clear();
        assert!(!congestion.recent_at(began + 10 * micros(SLOW_PUT)), "it is over, and leaves no mark");
        let mut log = StreamLog::default();
        log.record(
            began,
            Streamed::Field(Field::RBV, Value::Float(1.0)),
            &marker(1),
            Timestamp::new(NTP64(0), TimestampId::rand()),
        );
        assert!(log.take_unsure(&congestion).is_empty(), "the sender drops nothing");
    }
}
