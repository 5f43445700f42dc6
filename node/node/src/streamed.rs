//! What an axis sent the droppable way (`Delivery::Stream`) since its last event post, so that
//! when the network may have dropped some of it, the axis's next event post sends those keys'
//! last values again first: a motion's last readback may come a poll before its end (DMOV 1).
//! Zenoh does not say which sample it dropped, but it drops only after a put found a link's
//! queue full for `wait_before_drop` (1 ms): a put that took that long marks the node congested.

use std::sync::atomic::{AtomicU64, Ordering};
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

/// When something last happened, on the node's clock: read as "since" a moment or "within" a
/// window. Shared by threads, so an atomic.
struct LastSeen {
    origin: std::time::Instant,
    /// Microseconds since `origin`, plus one; 0 while never.
    last: AtomicU64,
}

impl LastSeen {
    fn new(origin: std::time::Instant) -> Self {
        Self { origin, last: AtomicU64::new(0) }
    }

    fn now(&self) -> u64 {
        u64::try_from(self.origin.elapsed().as_micros()).unwrap_or(u64::MAX).saturating_add(1)
    }

    fn mark(&self) {
        self.last.store(self.now(), Ordering::Release);
    }

    fn since(&self, at: u64) -> bool {
        self.last.load(Ordering::Acquire) >= at
    }

    fn within(&self, window: Duration) -> bool {
        let last = self.last.load(Ordering::Acquire);
        let window = u64::try_from(window.as_micros()).unwrap_or(u64::MAX);
        last != 0 && self.now().saturating_sub(last) < window
    }
}

/// When a put of the node last found a link congested.
pub(crate) struct Congestion(LastSeen);

impl Congestion {
    pub(crate) fn new(origin: std::time::Instant) -> Self {
        Self(LastSeen::new(origin))
    }

    /// Now on the node's clock, as `StreamLog` counts it.
    pub(crate) fn now(&self) -> u64 {
        self.0.now()
    }

    /// Run a put, noting congestion if it was slow.
    pub(crate) fn timed(&self, put: impl FnOnce()) {
        let start = std::time::Instant::now();
        put();
        self.took(start.elapsed());
    }

    /// A put took `elapsed`.
    fn took(&self, elapsed: Duration) {
        if elapsed >= SLOW_PUT {
            self.0.mark();
        }
    }

    fn since(&self, at: u64) -> bool {
        self.0.since(at)
    }

    /// Whether a put was slow lately (`CONGESTED_FOR`).
    pub(crate) fn recent(&self) -> bool {
        self.0.within(CONGESTED_FOR)
    }
}

/// How long after an axis's last slow work for a new key the network's inputs are handed to the
/// inputs thread (a storm of first moves does that work without pause; a lone one is past).
const KEY_WORK_FOR: Duration = Duration::from_secs(1);

/// When an axis of the node last did Zenoh's slow work for a new key: declared a publisher (each
/// declaration is matched against every key already there: a millisecond at a thousand axes) or
/// put to a key that has none.
pub(crate) struct KeyWork(LastSeen);

impl KeyWork {
    pub(crate) fn new(origin: std::time::Instant) -> Self {
        Self(LastSeen::new(origin))
    }

    /// Some is being done now.
    pub(crate) fn note(&self) {
        self.0.mark();
    }

    /// Whether some was done within `KEY_WORK_FOR`.
    pub(crate) fn lately(&self) -> bool {
        self.0.within(KEY_WORK_FOR)
    }

    /// As if none had ever been done.
    #[cfg(test)]
    pub(crate) fn forget(&self) {
        self.0.last.store(0, Ordering::Release);
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

    fn same_key(&self, other: &Streamed) -> bool {
        match (self, other) {
            (Streamed::Field(a, _), Streamed::Field(b, _)) => a == b,
            (Streamed::Bundle(_), Streamed::Bundle(_)) => true,
            _ => false,
        }
    }
}

/// The last stream sample of each key of one axis since its last event post.
#[derive(Default)]
pub(crate) struct StreamLog {
    /// When the first of them was sent.
    since: Option<u64>,
    sent: Vec<(Streamed, StateMarker, Timestamp)>,
}

impl StreamLog {
    pub(crate) fn record(&mut self, now: u64, sample: Streamed, marker: &StateMarker, stamp: Timestamp) {
        self.since.get_or_insert(now);
        let entry = (sample, marker.clone(), stamp);
        match self.sent.iter().position(|(s, _, _)| s.same_key(&entry.0)) {
            Some(index) => {
                self.sent.remove(index);
                self.sent.push(entry);
            }
            None => self.sent.push(entry),
        }
    }

    /// At an event post: what to send again (all of it, in order, if the node was congested
    /// since the first was sent), and a fresh log.
    pub(crate) fn take_unsure(&mut self, congestion: &Congestion) -> Vec<(Streamed, StateMarker, Timestamp)> {
        let unsure = self.since.take().is_some_and(|since| congestion.since(since));
        let sent = std::mem::take(&mut self.sent);
        if unsure {
            sent
        } else {
            Vec::new()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use zenoh::time::{TimestampId, NTP64};

    fn marker(seq: u64) -> StateMarker {
        StateMarker { kind: "state".into(), seq, stat: 0, sevr: 0 }
    }

    fn keys(sent: &[(Streamed, StateMarker, Timestamp)]) -> Vec<(String, u64)> {
        let key = |s: &Streamed| match s {
            Streamed::Field(field, _) => field.to_string(),
            Streamed::Bundle(_) => "@readback".to_string(),
        };
        sent.iter().map(|(s, m, _)| (key(s), m.seq)).collect()
    }

    #[test]
    fn after_a_slow_put_an_event_sends_each_stream_keys_last_sample_again_and_otherwise_nothing() {
        let congestion = Congestion::new(std::time::Instant::now());
        let stamp = Timestamp::new(NTP64(0), TimestampId::rand());
        let mut log = StreamLog::default();
        for (seq, field) in [(1, Field::RBV), (2, Field::DRBV), (3, Field::RBV)] {
            log.record(congestion.now(), Streamed::Field(field, Value::Float(seq as f64)), &marker(seq), stamp);
        }
        congestion.took(SLOW_PUT / 2);
        assert!(log.take_unsure(&congestion).is_empty(), "quick puts: nothing dropped");
        for (seq, field) in [(4, Field::RBV), (5, Field::DRBV)] {
            log.record(congestion.now(), Streamed::Field(field, Value::Float(seq as f64)), &marker(seq), stamp);
        }
        log.record(congestion.now(), Streamed::Bundle(vec![1]), &marker(5), stamp);
        log.record(congestion.now(), Streamed::Field(Field::RBV, Value::Float(6.0)), &marker(6), stamp);
        congestion.took(SLOW_PUT);
        let again = log.take_unsure(&congestion);
        let expected = [("DRBV", 5), ("@readback", 5), ("RBV", 6)].map(|(k, s)| (k.to_string(), s));
        assert_eq!(keys(&again), expected);
        assert!(log.take_unsure(&congestion).is_empty(), "each is sent again once");
    }
}
