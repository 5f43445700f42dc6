//! The node's Zenoh entities for all its axes: one subscriber and one queryable per key space
//! (not per axis: Zenoh's cost per declaration grows with the declarations already there, and
//! thousands of axes would pay it squared). Their callbacks hand each sample or query to its
//! axis by name and never block (the node's own publications pass through them too): handled
//! on Zenoh's receiving thread, or on the node's inputs thread while axes do slow work.

use crate::input::{AxisInput, Deliver, Written};
use crate::refusal::refuse;
use crate::routes::{Routes, Space};
use crate::streamed::KeyWork;
use crate::writer::Writer;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use zenoh::key_expr::KeyExpr;
use zenoh::query::Query;
use zenoh::sample::{Locality, Sample, SampleKind};
use zenoh::Session;
use zmotor_core::RequestError;
use zmotor_msgs::{excerpt, keys, Attached, KeyLayout, PayloadEncoding};

/// Held for as long as the node serves.
pub(crate) struct Router {
    _writes: zenoh::pubsub::Subscriber<()>,
    _queries: zenoh::query::Queryable<()>,
    _confirmed_writes: zenoh::query::Queryable<()>,
    /// Gets of the readback bundles (`**` does not reach a chunk that starts with `@`).
    _readbacks: zenoh::query::Queryable<()>,
    _sim_writes: zenoh::pubsub::Subscriber<()>,
    _sim_queries: zenoh::query::Queryable<()>,
}

impl Router {
    /// Serve `routes`; `writer` reaches them from now on.
    pub(crate) async fn declare(
        session: &Session,
        layout: &KeyLayout,
        routes: Routes,
        writer: &Writer,
        key_work: Arc<KeyWork>,
    ) -> Result<Self, zenoh::Error> {
        let routes = Arc::new(routes);
        writer.reach(&routes);
        let inputs = Inputs::start(tokio::runtime::Handle::current(), key_work)?;
        let fields = Space::Fields(layout.clone());
        let (r1, s1, i1) = (routes.clone(), fields.clone(), inputs.clone());
        let (r2, s2, i2) = (routes.clone(), fields.clone(), inputs.clone());
        let (r5, s5, i5) = (routes.clone(), fields, inputs.clone());
        let (r6, l6, i6) = (routes.clone(), layout.clone(), inputs.clone());
        let (r3, r4, i3, i4) = (routes.clone(), routes, inputs.clone(), inputs);
        // The node's own publications do not come back to it: what it writes to its own axes
        // goes through `Writer`.
        Ok(Self {
            _writes: session
                .declare_subscriber(layout.every_field())
                .allowed_origin(Locality::Remote)
                .callback(move |sample| route_sample(&r1, &s1, &i1, &sample, AxisInput::Write))
                .await?,
            _queries: session
                .declare_queryable(layout.everything())
                .callback(move |q| route_query(&r2, &s2, &i2, q, AxisInput::Query))
                .await?,
            // `<prefix>/**` does not cover the `@write` chunk: write keys are served apart.
            _confirmed_writes: session
                .declare_queryable(layout.every_write())
                .callback(move |q| route_query(&r5, &s5, &i5, q, AxisInput::Query))
                .await?,
            _readbacks: session
                .declare_queryable(layout.readback("*"))
                .callback(move |q| route_readback(&r6, &l6, &i6, &q))
                .await?,
            _sim_writes: session
                .declare_subscriber(keys::sim_key("*", "*"))
                .allowed_origin(Locality::Remote)
                .callback(move |sample| route_sample(&r3, &Space::Sim, &i3, &sample, AxisInput::SimWrite))
                .await?,
            _sim_queries: session
                .declare_queryable(keys::sim_key("*", "**"))
                .callback(move |q| route_query(&r4, &Space::Sim, &i4, q, AxisInput::SimQuery))
                .await?,
        })
    }
}

/// A sample goes to the axis its key names, if it is one of ours and a write: a publication of
/// some node (it carries a state marker) never is.
fn route_sample(routes: &Routes, space: &Space, inputs: &Inputs, sample: &Sample, wrap: fn(Written) -> AxisInput) {
    let attached = sample.attachment().map_or(Attached::Plain, |a| Attached::read(&a.to_bytes()));
    if attached == Attached::State {
        return;
    }
    if sample.key_expr().as_str().contains(['*', '$']) {
        // Refused on the ERR of each axis of ours the key covers.
        for handle in space.covered(routes, sample.key_expr()) {
            inputs.hand(handle, AxisInput::WildcardWrite(sample.key_expr().to_string()));
        }
        return;
    }
    if let Some((handle, name)) = space.target(routes, sample.key_expr().as_str()) {
        if sample.kind() == SampleKind::Delete {
            // A delete carries no value: taken as a write, it would empty a text field or
            // unwire a link.
            inputs.hand(handle, AxisInput::Deleted(sample.key_expr().to_string()));
            return;
        }
        let encoding = PayloadEncoding::from_mime(&sample.encoding().to_string());
        let hold = attached.hold();
        inputs.hand(handle, wrap(Written { name, payload: sample.payload().to_bytes().into_owned(), encoding, hold }));
    }
}

/// A get of readback bundles goes to every axis of ours whose bundle it names.
fn route_readback(routes: &Routes, layout: &KeyLayout, inputs: &Inputs, query: &Query) {
    for (axis, handle) in routes.iter() {
        if KeyExpr::try_from(layout.readback(axis)).is_ok_and(|key| query.key_expr().intersects(&key)) {
            inputs.hand(handle, AxisInput::Query(query.clone()));
        }
    }
}

/// A query goes to every axis of ours it can concern (one, or all for a wildcard).
fn route_query(routes: &Routes, space: &Space, inputs: &Inputs, query: Query, wrap: fn(Query) -> AxisInput) {
    if query.payload().is_some() && query.key_expr().as_str().contains(['*', '$']) {
        // Answering with the fields' values would look like success, and writing every match
        // is not what a write means: refused, naming the key.
        let refusal = RequestError::Wildcard(excerpt(query.key_expr().as_str()));
        refuse(&query, refusal.kind(), refusal.to_string());
        return;
    }
    let chunk = space.axis_chunk(query.key_expr().as_str()).unwrap_or("");
    if !chunk.is_empty() && !chunk.contains(['*', '$']) {
        if let Some(handle) = routes.get(chunk) {
            inputs.hand(handle, wrap(query));
        }
        return;
    }
    for handle in space.covered(routes, query.key_expr()) {
        inputs.hand(handle, wrap(query.clone()));
    }
}

/// Hands what the network brings to its axis: on Zenoh's receiving thread (no hop: a command's
/// first post leaves sooner), unless an axis of the node did slow work for a new key lately or an
/// input handed over still waits; then to the node's inputs thread (`zmotor-inputs`), in the
/// order it came, and the receiving thread goes back to its link at once. Handled on that thread,
/// the first moves of many axes (a publisher declared for each field, each matched against every
/// key: milliseconds apiece at a thousand axes) kept the link unread, and a client's puts, which
/// Zenoh drops by default when the link does not drain, were lost.
#[derive(Clone)]
struct Inputs {
    sender: std::sync::mpsc::Sender<(Arc<dyn Deliver>, AxisInput)>,
    /// Handed over and not yet delivered to their axes: while any wait, the next waits behind.
    waiting: Arc<AtomicUsize>,
    key_work: Arc<KeyWork>,
}

impl Inputs {
    /// The thread, handling in `runtime`'s context (an axis may spawn onto it); it ends when
    /// the last callback holding an `Inputs` is dropped, after what was handed before.
    fn start(runtime: tokio::runtime::Handle, key_work: Arc<KeyWork>) -> std::io::Result<Self> {
        let (sender, handed) = std::sync::mpsc::channel::<(Arc<dyn Deliver>, AxisInput)>();
        let waiting = Arc::new(AtomicUsize::new(0));
        let delivered = waiting.clone();
        std::thread::Builder::new().name("zmotor-inputs".into()).spawn(move || {
            let _context = runtime.enter();
            for (axis, input) in handed {
                axis.deliver(input);
                delivered.fetch_sub(1, Ordering::AcqRel);
            }
        })?;
        Ok(Self { sender, waiting, key_work })
    }

    fn hand(&self, axis: &Arc<dyn Deliver>, input: AxisInput) {
        if self.waiting.load(Ordering::Acquire) == 0 && !self.key_work.lately() {
            return axis.deliver(input);
        }
        self.waiting.fetch_add(1, Ordering::AcqRel);
        if self.sender.send((axis.clone(), input)).is_err() {
            // The thread is gone only when the node no longer serves.
            self.waiting.fetch_sub(1, Ordering::AcqRel);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::streamed::NodeClock;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::mpsc;
    use std::sync::Mutex;
    use std::time::Duration;

    /// An axis whose handling waits to be released.
    struct Held {
        entered: Mutex<mpsc::Sender<()>>,
        release: Mutex<mpsc::Receiver<()>>,
        handled: AtomicUsize,
    }

    impl Deliver for Held {
        fn deliver(&self, _input: AxisInput) {
            let _ = self.entered.lock().unwrap().send(());
            let _ = self.release.lock().unwrap().recv();
            self.handled.fetch_add(1, Ordering::AcqRel);
        }
    }

    fn held() -> (Arc<Held>, mpsc::Receiver<()>, mpsc::Sender<()>) {
        let ((entered, entering), (releasing, release)) = (mpsc::channel(), mpsc::channel());
        let held = Arc::new(Held { entered: Mutex::new(entered), release: Mutex::new(release), handled: 0.into() });
        (held, entering, releasing)
    }

    fn handled_within_seconds(held: &Held, n: usize) {
        for _ in 0..1000 {
            if held.handled.load(Ordering::Acquire) == n {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        panic!("{} of {n} inputs handled", held.handled.load(Ordering::Acquire));
    }

    #[test]
    fn while_axes_do_slow_key_work_the_receiving_thread_hands_inputs_over_and_goes_on() {
        let runtime = tokio::runtime::Builder::new_current_thread().build().unwrap();
        let key_work = Arc::new(KeyWork::new(NodeClock::new(std::time::Instant::now())));
        let inputs = Inputs::start(runtime.handle().clone(), key_work.clone()).unwrap();
        let (held, entering, releasing) = held();
        let axis: Arc<dyn Deliver> = held.clone();
        key_work.note();
        let (handed, handing) = mpsc::channel();
        let receiving = inputs.clone();
        std::thread::spawn(move || {
            receiving.hand(&axis, AxisInput::Tick);
            // The slow work is past, but an input handed over waits: the next waits behind it.
            key_work.forget();
            for _ in 0..2 {
                receiving.hand(&axis, AxisInput::Tick);
            }
            let _ = handed.send(());
        });
        entering.recv_timeout(Duration::from_secs(10)).expect("the first input reaches the axis");
        handing.recv_timeout(Duration::from_secs(10)).expect("every input handed while the first is being handled");
        assert_eq!(held.handled.load(Ordering::Acquire), 0);
        for _ in 0..3 {
            releasing.send(()).unwrap();
        }
        handled_within_seconds(&held, 3);
        for _ in 0..1000 {
            if inputs.waiting.load(Ordering::Acquire) == 0 {
                break;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        // Nothing waits and no slow work was done lately: handled on the receiving thread.
        releasing.send(()).unwrap();
        inputs.hand(&(held.clone() as Arc<dyn Deliver>), AxisInput::Tick);
        assert_eq!(held.handled.load(Ordering::Acquire), 4, "handled before the hand returned");
    }
}
