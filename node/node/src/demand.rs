//! Which fields some subscriber on the network wants, of any axis: one probe publisher per
//! field on `<prefix>/*/<FIELD>` whose matching status Zenoh keeps current. A field nobody
//! subscribes to, for any axis, is not published (the record posts monitors only to those who
//! asked); a subscriber of any axis's field gets that field from every axis, so no subscriber is
//! ever missed. (A matching listener per axis and field does not scale in Zenoh 1.10: every
//! subscriber declaration re-evaluates every listener.)

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use zenoh::key_expr::KeyExpr;
use zenoh::pubsub::Publisher;
use zenoh::sample::Locality;
use zenoh::Session;
use zmotor_msgs::{Field, KeyLayout};

pub(crate) struct FieldDemand {
    wanted: Vec<Arc<AtomicBool>>,
    /// Whether anyone subscribes to some axis's readback bundle (`<prefix>/*/@readback`).
    readback: Arc<AtomicBool>,
    /// Whether anyone subscribes to some axis's driver-command trace (`<prefix>/*/@driver/cmd`).
    traces: Arc<AtomicBool>,
    /// In the order of the flags: the fields', the readback bundle's, the traces'.
    probes: Vec<zenoh::pubsub::Publisher<'static>>,
}

impl FieldDemand {
    pub(crate) async fn declare(session: &Session, layout: &KeyLayout) -> Result<Self, zenoh::Error> {
        let (mut wanted, mut probes) = (Vec::new(), Vec::new());
        for field in Field::all() {
            let (flag, probe) = watch(session, layout.field("*", field)).await?;
            wanted.push(flag);
            probes.push(probe);
        }
        let (readback, probe) = watch(session, layout.readback("*")).await?;
        probes.push(probe);
        let (traces, probe) = watch(session, layout.driver_cmd("*")).await?;
        probes.push(probe);
        Ok(Self { wanted, readback, traces, probes })
    }

    /// Whether anyone subscribes to some axis's readback bundle.
    pub(crate) fn readback_wanted(&self) -> bool {
        self.readback.load(Ordering::Acquire)
    }

    /// Whether anyone subscribes to some axis's driver-command trace.
    pub(crate) fn traces_wanted(&self) -> bool {
        self.traces.load(Ordering::Acquire)
    }

    pub(crate) fn wanted(&self, field: Field) -> bool {
        self.wanted[field as usize].load(Ordering::Acquire)
    }

    /// Whether every kind of publication whose keys `key_expr` meets is wanted. Zenoh reports a
    /// new subscriber to the probes' listeners from a task of its own, a moment after the
    /// subscriber reached the session: until then its publications are not sent.
    pub(crate) fn covers(&self, key_expr: &KeyExpr<'_>) -> bool {
        let flags = self.wanted.iter().chain([&self.readback, &self.traces]);
        self.probes
            .iter()
            .zip(flags)
            .filter(|(probe, _)| probe.key_expr().intersects(key_expr))
            .all(|(_, flag)| flag.load(Ordering::Acquire))
    }
}

/// A probe publisher on `key` and the flag its matching status keeps: wanted until known.
/// Zenoh reports changes, not the status at the declaration, so the status is read once the
/// listener is there; a change reported meanwhile wins.
async fn watch(session: &Session, key: String) -> Result<(Arc<AtomicBool>, Publisher<'static>), zenoh::Error> {
    let probe = session.declare_publisher(key).allowed_destination(Locality::Remote).await?;
    let flag = Arc::new(AtomicBool::new(true));
    let reported = Arc::new(Mutex::new(false));
    let (listener, reporter) = (flag.clone(), reported.clone());
    probe
        .matching_listener()
        .callback(move |status| {
            let mut reported = reporter.lock().unwrap_or_else(PoisonError::into_inner);
            *reported = true;
            listener.store(status.matching(), Ordering::Release);
        })
        .background()
        .await?;
    let matching = probe.matching_status().await?.matching();
    let reported = reported.lock().unwrap_or_else(PoisonError::into_inner);
    if !*reported {
        flag.store(matching, Ordering::Release);
    }
    drop(reported);
    Ok((flag, probe))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

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

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_field_is_wanted_while_a_subscriber_elsewhere_covers_it_and_not_before() {
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let endpoint = format!("[\"tcp/127.0.0.1:{port}\"]");
        let node = session(("listen/endpoints", &endpoint)).await;
        let client = session(("connect/endpoints", &endpoint)).await;
        let layout = KeyLayout::default();
        let demand = FieldDemand::declare(&node, &layout).await.unwrap();
        // Nobody subscribes: nothing is wanted, from the start (no change is ever reported).
        assert!(!demand.wanted(Field::RBV) && !demand.wanted(Field::DRBV));
        let subscriber = client.declare_subscriber(layout.field("m1", Field::RBV)).await.unwrap();
        until("RBV wanted", || demand.wanted(Field::RBV)).await;
        assert!(!demand.wanted(Field::DRBV), "a field nobody covers");
        let covered = |key: &str| demand.covers(&KeyExpr::try_from(key).unwrap());
        assert!(covered("motor/m2/RBV") && !covered("motor/m1/*") && !covered("motor/m1/@readback"));
        drop(subscriber);
        until("RBV unwanted", || !demand.wanted(Field::RBV)).await;
        // Driver-command traces likewise: no trace publisher is declared while nobody traces.
        assert!(!demand.traces_wanted());
        let tracer = client.declare_subscriber(layout.driver_cmd("m1")).await.unwrap();
        until("traces wanted for a subscriber of one axis's trace", || demand.traces_wanted()).await;
        assert!(!demand.wanted(Field::RBV), "a trace subscriber wants no field");
        assert!(covered("motor/m1/@driver/cmd") && !covered("motor/**"), "`**` meets no `@` chunk, fields do");
        drop(tracer);
    }
}
