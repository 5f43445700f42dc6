//! Which fields some subscriber on the network wants, of any axis: one probe publisher per
//! field on `<prefix>/*/<FIELD>`. A field nobody subscribes to, for any axis, is not published
//! (the record posts monitors only to those who asked); a subscriber of any axis's field gets
//! that field from every axis, so no subscriber is ever missed. (A matching listener per axis
//! and field does not scale in Zenoh 1.10: every subscriber declaration re-evaluates every
//! listener.)
//!
//! Each probe's matching listener keeps a flag, but Zenoh calls it from a task of its own,
//! about a millisecond after a subscriber reached the node's session: a write sent right behind
//! the subscription was handled first, and its posts left out (a stock client that subscribed,
//! then wrote VAL, missed the move's DMOV 0 in a quarter of its tries). So where the flag says
//! nobody wants a post, Zenoh's tables are asked: at once for an event (a client that
//! subscribed before writing gets every post the write causes, as from any Zenoh publisher),
//! every `STREAM_ASK_EVERY` for a stream sample (the next poll's supersedes it).

use std::future::{Future, IntoFuture};
use std::pin::pin;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::task::{Context, Poll, Waker};
use std::time::Duration;
use zenoh::key_expr::KeyExpr;
use zenoh::pubsub::Publisher;
use zenoh::sample::Locality;
use zenoh::Session;
use zmotor_core::{Delivery, Instant};
use zmotor_msgs::{Field, KeyLayout};

/// How often stream samples ask Zenoh, per kind: the flags follow reports made on another
/// thread, and this bounds how long one may disagree with Zenoh's tables.
const STREAM_ASK_EVERY: Duration = Duration::from_millis(100);

pub(crate) struct FieldDemand {
    /// The fields', by `Field` number, then the readback bundle's (`<prefix>/*/@readback`),
    /// then the driver-command traces' (`<prefix>/*/@driver/cmd`).
    probes: Vec<Probe>,
    /// How many times Zenoh's tables were asked.
    asks: AtomicU64,
}

/// One kind of publication and whether anyone subscribes to it.
struct Probe {
    publisher: Publisher<'static>,
    /// As the matching listener last reported, or as Zenoh last answered.
    wanted: Arc<AtomicBool>,
    /// When a stream sample may ask Zenoh next, in microseconds since the node's origin.
    next_stream_ask: AtomicU64,
}

impl FieldDemand {
    pub(crate) async fn declare(session: &Session, layout: &KeyLayout) -> Result<Self, zenoh::Error> {
        let mut probes = Vec::new();
        let keys = Field::all().map(|field| layout.field("*", field));
        for key in keys.chain([layout.readback("*"), layout.driver_cmd("*")]) {
            probes.push(Probe::watch(session, key).await?);
        }
        Ok(Self { probes, asks: AtomicU64::new(0) })
    }

    /// How many times Zenoh's tables were asked so far: an ask may wait while another thread
    /// declares, so a reading of the clock taken before one times that wait too.
    pub(crate) fn asks(&self) -> u64 {
        self.asks.load(Ordering::Acquire)
    }

    /// Whether some subscriber wants `field`'s post, sent `delivery`'s way at `now`.
    pub(crate) fn wanted(&self, field: Field, delivery: Delivery, now: Instant) -> bool {
        self.probes[field as usize].wanted(delivery, now, &self.asks)
    }

    /// Whether some subscriber wants the readback bundle.
    pub(crate) fn readback_wanted(&self, delivery: Delivery, now: Instant) -> bool {
        self.probes[Field::COUNT].wanted(delivery, now, &self.asks)
    }

    /// Whether some subscriber wants the driver-command traces (each a change: asked at once).
    pub(crate) fn traces_wanted(&self, now: Instant) -> bool {
        self.probes[Field::COUNT + 1].wanted(Delivery::Event, now, &self.asks)
    }

    /// Whether every kind of publication whose keys `key_expr` meets is wanted, asking Zenoh
    /// where a flag says no: once it is, their stream samples too are sent at once.
    pub(crate) fn covers(&self, key_expr: &KeyExpr<'_>) -> bool {
        let meets = |probe: &&Probe| probe.publisher.key_expr().intersects(key_expr);
        self.probes.iter().filter(meets).all(|probe| probe.wanted.load(Ordering::Acquire) || probe.ask(&self.asks))
    }
}

impl Probe {
    /// A probe publisher on `key` and the flag its matching status keeps: wanted until known.
    /// Zenoh reports changes, not the status at the declaration, so the status is read once the
    /// listener is there; a change reported meanwhile wins.
    async fn watch(session: &Session, key: String) -> Result<Self, zenoh::Error> {
        let publisher = session.declare_publisher(key).allowed_destination(Locality::Remote).await?;
        let wanted = Arc::new(AtomicBool::new(true));
        let reported = Arc::new(Mutex::new(false));
        let (listener, reporter) = (wanted.clone(), reported.clone());
        publisher
            .matching_listener()
            .callback(move |status| {
                let mut reported = reporter.lock().unwrap_or_else(PoisonError::into_inner);
                *reported = true;
                listener.store(status.matching(), Ordering::Release);
            })
            .background()
            .await?;
        let matching = publisher.matching_status().await?.matching();
        let reported = reported.lock().unwrap_or_else(PoisonError::into_inner);
        if !*reported {
            wanted.store(matching, Ordering::Release);
        }
        drop(reported);
        Ok(Self { publisher, wanted, next_stream_ask: AtomicU64::new(0) })
    }

    /// For an event, the flag, or Zenoh's answer where the flag says no; for a stream sample,
    /// Zenoh's answer every `STREAM_ASK_EVERY` (kept, whichever way), the flag between.
    /// (`asks` counts the asks.)
    fn wanted(&self, delivery: Delivery, now: Instant, asks: &AtomicU64) -> bool {
        let known = self.wanted.load(Ordering::Acquire);
        match delivery {
            Delivery::Event if !known => self.ask(asks),
            Delivery::Stream if self.stream_ask_due(now) => self.ask(asks),
            _ => known,
        }
    }

    /// Whether a stream sample at `now` asks Zenoh: one of the threads posting this kind does,
    /// every `STREAM_ASK_EVERY`.
    fn stream_ask_due(&self, now: Instant) -> bool {
        let now = micros(now.since_origin());
        let next = self.next_stream_ask.load(Ordering::Relaxed);
        let later = now.saturating_add(micros(STREAM_ASK_EVERY));
        now >= next && self.next_stream_ask.compare_exchange(next, later, Ordering::Relaxed, Ordering::Relaxed).is_ok()
    }

    /// Zenoh's tables now: a subscriber whose declaration reached the node's session is there.
    /// Zenoh computes the answer at the first poll; its `wait` would go through `block_in_place`
    /// and a runtime's `block_on` for it, half the ask's cost (part 19). Were it ever pending,
    /// the post is sent (the tests' "nobody there" case would fail).
    fn ask(&self, asks: &AtomicU64) -> bool {
        asks.fetch_add(1, Ordering::AcqRel);
        let mut answer = pin!(self.publisher.matching_status().into_future());
        let matching = match answer.as_mut().poll(&mut Context::from_waker(Waker::noop())) {
            Poll::Ready(status) => status.is_ok_and(|status| status.matching()),
            Poll::Pending => true,
        };
        self.wanted.store(matching, Ordering::Release);
        matching
    }
}

fn micros(duration: Duration) -> u64 {
    u64::try_from(duration.as_micros()).unwrap_or(u64::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    async fn session(endpoints: (&str, &str)) -> Session {
        let mut config = zenoh::Config::default();
        for (key, value) in [("mode", "\"peer\""), endpoints, ("scouting/multicast/enabled", "false")] {
            config.insert_json5(key, value).unwrap();
        }
        zenoh::open(config).await.unwrap()
    }

    /// Waits (5 s at most) for `holds`, which the node learns from the network.
    async fn until(what: &str, holds: impl Fn() -> bool) {
        for _ in 0..500 {
            if holds() {
                return;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        panic!("still not {what} after 5 s");
    }

    /// What the listeners last reported (or an answer stored since) of probe `index`.
    fn known(demand: &FieldDemand, index: usize) -> bool {
        demand.probes[index].wanted.load(Ordering::Acquire)
    }

    fn set_known(demand: &FieldDemand, field: Field, wanted: bool) {
        demand.probes[field as usize].wanted.store(wanted, Ordering::Release);
    }

    async fn node_and_client() -> (Session, Session) {
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let endpoint = format!("[\"tcp/127.0.0.1:{port}\"]");
        let node = session(("listen/endpoints", &endpoint)).await;
        let client = session(("connect/endpoints", &endpoint)).await;
        (node, client)
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn the_listeners_report_a_field_wanted_while_a_subscriber_elsewhere_covers_it() {
        let (node, client) = node_and_client().await;
        let layout = KeyLayout::default();
        let demand = FieldDemand::declare(&node, &layout).await.unwrap();
        let (rbv, drbv, traces) = (Field::RBV as usize, Field::DRBV as usize, Field::COUNT + 1);
        // Nobody subscribes: nothing is wanted, from the start (no change is ever reported).
        assert!(!known(&demand, rbv) && !known(&demand, drbv));
        let subscriber = client.declare_subscriber(layout.field("m1", Field::RBV)).await.unwrap();
        until("RBV wanted", || known(&demand, rbv)).await;
        assert!(!known(&demand, drbv), "a field nobody covers");
        let covered = |key: &str| demand.covers(&KeyExpr::try_from(key).unwrap());
        assert!(covered("motor/m2/RBV") && !covered("motor/m1/*") && !covered("motor/m1/@readback"));
        drop(subscriber);
        until("RBV unwanted", || !known(&demand, rbv)).await;
        // Driver-command traces likewise: no trace publisher is declared while nobody traces.
        assert!(!known(&demand, traces));
        let tracer = client.declare_subscriber(layout.driver_cmd("m1")).await.unwrap();
        until("traces wanted for a subscriber of one axis's trace", || known(&demand, traces)).await;
        assert!(!known(&demand, rbv), "a trace subscriber wants no field");
        assert!(covered("motor/m1/@driver/cmd") && !covered("motor/**"), "`**` meets no `@` chunk, fields do");
        drop(tracer);
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn where_the_flag_is_wrong_an_event_asks_zenoh_at_once_and_a_stream_sample_now_and_then() {
        let (node, client) = node_and_client().await;
        let layout = KeyLayout::default();
        let demand = FieldDemand::declare(&node, &layout).await.unwrap();
        let subscriber = client.declare_subscriber(layout.field("m1", Field::RBV)).await.unwrap();
        until("RBV wanted", || known(&demand, Field::RBV as usize)).await;
        let at = |ms| Instant::after(Duration::from_millis(ms));
        // A report not come yet (or lost): an event asks Zenoh, and keeps the answer.
        set_known(&demand, Field::RBV, false);
        assert!(demand.wanted(Field::RBV, Delivery::Event, at(1_000)));
        assert!(known(&demand, Field::RBV as usize));
        // A stream sample asks at most every STREAM_ASK_EVERY, and goes by the flag between.
        set_known(&demand, Field::RBV, false);
        assert!(demand.wanted(Field::RBV, Delivery::Stream, at(1_000)), "the first stream sample asks");
        set_known(&demand, Field::RBV, false);
        assert!(!demand.wanted(Field::RBV, Delivery::Stream, at(1_099)));
        assert!(demand.wanted(Field::RBV, Delivery::Stream, at(1_100)));
        // The last subscriber gone, a flag left wanted: an event trusts it (a post nobody
        // takes), the next stream sample due asks and clears it.
        drop(subscriber);
        until("RBV unwanted", || !known(&demand, Field::RBV as usize)).await;
        set_known(&demand, Field::RBV, true);
        assert!(demand.wanted(Field::RBV, Delivery::Event, at(1_150)));
        assert!(!demand.wanted(Field::RBV, Delivery::Stream, at(1_200)));
        assert!(!known(&demand, Field::RBV as usize));
        // Nobody there: an event asks, and is not sent.
        assert!(!demand.wanted(Field::DRBV, Delivery::Event, at(1_200)));
    }
}
