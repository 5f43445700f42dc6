//! A node: the axes of one process served on a Zenoh session. Each axis is a sans-IO
//! `AxisService` (zmotor-core); this module only moves bytes: samples and queries in, the
//! wall clock as ticks, publications, replies and trace samples out, as
//! ../shared/spec/zenoh-api.md requires.
//!
//! One subscriber and one queryable per node (not per axis) take everything addressed to the
//! node's axes and hand it to the axis by name: Zenoh's cost per declaration grows with the
//! declarations already there, and thousands of axes would pay it squared.

use crate::autosave::{AutosaveError, SavedAxis, StateStore};
use crate::links::{is_state, CalcTask, KeyFollower, ValueHolder, ValueSpec};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, TryLockError};
use std::time::Duration;
use zenoh::bytes::{Encoding, ZBytes};
use zenoh::key_expr::KeyExpr;
use zenoh::query::Query;
use zenoh::sample::Sample;
use zenoh::{Session, Wait};
use zmotor_bridge::{CalcLink, CalcLinkSpec, LinkError};
use zmotor_core::axis::AxisPlan;
use zmotor_core::driver::soft::InputLink;
use zmotor_core::service::{AxisService, Reply, ServiceOutput};
use zmotor_core::Instant;
use zmotor_msgs::{encode_cbor, keys, Field, KeyLayout, PayloadEncoding, StateMarker, Value};

/// Why a node could not start.
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    /// Zenoh refused a declaration or a query.
    #[error("zenoh: {0}")]
    Zenoh(zenoh::Error),
    /// An axis's saved state cannot be restored.
    #[error(transparent)]
    Autosave(#[from] AutosaveError),
    /// A calc link cannot be built.
    #[error(transparent)]
    Calc(#[from] LinkError),
}

impl From<zenoh::Error> for NodeError {
    fn from(error: zenoh::Error) -> Self {
        NodeError::Zenoh(error)
    }
}

/// Autosave of a node's axes: where state is kept, and how long a change may wait before it
/// is written (changes within that time are written together).
#[derive(Clone, Debug)]
pub struct AutosaveConfig {
    /// The state files.
    pub store: StateStore,
    /// How long a change waits before it is written.
    pub delay: Duration,
}

/// How long a shutdown waits for moving axes to stop before saving anyway.
const STOP_GRACE: Duration = Duration::from_secs(5);

/// A running node: its axes' and calc links' tasks, stopped when dropped or on `shutdown`.
pub struct Node {
    axis_tasks: Vec<tokio::task::JoinHandle<()>>,
    calc_tasks: Vec<tokio::task::JoinHandle<()>>,
    stop: tokio::sync::watch::Sender<bool>,
    _router: Router,
    _values: Vec<ValueHolder>,
}

impl Node {
    /// Start one task per axis, then one per calc link, on `session`. With autosave, each axis
    /// boots from its saved state (RSTM deciding about the position) and saves its changes.
    pub async fn start(
        session: Session,
        layout: KeyLayout,
        plans: Vec<AxisPlan>,
        calcs: Vec<CalcLinkSpec>,
        values: Vec<ValueSpec>,
        autosave: Option<AutosaveConfig>,
    ) -> Result<Self, NodeError> {
        let (stop, stopped) = tokio::sync::watch::channel(false);
        let mut routes = std::collections::HashMap::new();
        let mut axis_tasks = Vec::new();
        let budget = Arc::new(AtomicUsize::new(PUBLISHER_BUDGET));
        for mut plan in plans {
            let saver = match &autosave {
                Some(config) => Some(Saver::restore(config, &mut plan)?),
                None => None,
            };
            let (link_kinds, link_keys): (Vec<InputLink>, Vec<String>) = plan.input_links().into_iter().unzip();
            let links = KeyFollower::start(&session, link_keys).await?;
            let name = plan.name.clone();
            let core = AxisCore {
                service: AxisService::new(&name, plan.build(Instant::ZERO)),
                session: session.clone(),
                layout: layout.clone(),
                clock: tokio::time::Instant::now(),
                trace: None,
                hot: Vec::new(),
                posted_once: Vec::new(),
                budget: budget.clone(),
            };
            let (queue_in, queue) = tokio::sync::mpsc::unbounded_channel();
            let handle = AxisHandle {
                core: Arc::new(Mutex::new(core)),
                queue: queue_in,
                queued: Default::default(),
                rearm: Default::default(),
            };
            routes.insert(name.clone(), handle.clone());
            axis_tasks.push(AxisTask {
                core: handle.core,
                queue,
                queued: handle.queued,
                rearm: handle.rearm,
                links,
                link_kinds,
                saver,
                token: Some(session.liveliness().declare_token(layout.axis(&name)).await?),
                name,
            });
        }
        let router = Router::declare(&session, &layout, routes).await?;
        let mut holders = Vec::new();
        for spec in values {
            holders.push(ValueHolder::declare(&session, spec).await?);
        }
        let axis_tasks = axis_tasks
            .into_iter()
            .map(|mut task| {
                let stopped = stopped.clone();
                tokio::spawn(async move { task.run(stopped).await })
            })
            .collect();
        let mut calc_tasks = Vec::new();
        for spec in calcs {
            let link = CalcLink::new(spec)?;
            let inputs = KeyFollower::start(&session, link.input_keys().map(str::to_string).collect()).await?;
            let mut task = CalcTask { session: session.clone(), link, inputs };
            calc_tasks.push(tokio::spawn(async move { task.run().await }));
        }
        Ok(Self { axis_tasks, calc_tasks, stop, _router: router, _values: holders })
    }

    /// Stop every moving axis, wait (at most `STOP_GRACE`) until they are done, save their
    /// state, withdraw their liveliness tokens; then end the calc links, which may carry the
    /// soft axes' stops and readbacks until then.
    pub async fn shutdown(mut self) {
        let _ = self.stop.send(true);
        for task in std::mem::take(&mut self.axis_tasks) {
            let _ = task.await;
        }
        for task in std::mem::take(&mut self.calc_tasks) {
            task.abort();
        }
    }
}

impl Drop for Node {
    fn drop(&mut self) {
        let _ = self.stop.send(true);
        for task in &self.calc_tasks {
            task.abort();
        }
    }
}

/// What reaches one axis from the network.
enum AxisInput {
    Write(Sample),
    Query(Query),
    SimWrite(Sample),
    SimQuery(Query),
}

/// How the router reaches one axis. A write is handled at once on the Zenoh thread that
/// received it (no hop to another thread before DMOV 0 goes out) when the axis is free and
/// nothing is queued before it; otherwise it is queued for the axis's task, in order. Callbacks
/// never wait for a lock, so an axis writing to itself or two axes writing to each other cannot
/// deadlock.
#[derive(Clone)]
struct AxisHandle {
    core: Arc<Mutex<AxisCore>>,
    queue: tokio::sync::mpsc::UnboundedSender<AxisInput>,
    queued: Arc<AtomicUsize>,
    /// Tells the task that its next wake-up may have moved.
    rearm: Arc<tokio::sync::Notify>,
}

impl AxisHandle {
    fn deliver(&self, input: AxisInput) {
        if self.queued.load(Ordering::Acquire) == 0 {
            let core = match self.core.try_lock() {
                Ok(core) => Some(core),
                Err(TryLockError::Poisoned(poisoned)) => Some(poisoned.into_inner()),
                Err(TryLockError::WouldBlock) => None,
            };
            if let Some(mut core) = core {
                core.handle(input);
                drop(core);
                self.rearm.notify_one();
                return;
            }
        }
        self.queued.fetch_add(1, Ordering::AcqRel);
        let _ = self.queue.send(input);
    }
}

fn lock(core: &Mutex<AxisCore>) -> MutexGuard<'_, AxisCore> {
    core.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

type Routes = std::collections::HashMap<String, AxisHandle>;

/// The node's Zenoh entities for all its axes. Their callbacks hand each sample or query to
/// its axis at once and never block: the node's own publications pass through them too.
struct Router {
    _writes: zenoh::pubsub::Subscriber<()>,
    _queries: zenoh::query::Queryable<()>,
    _sim_writes: zenoh::pubsub::Subscriber<()>,
    _sim_queries: zenoh::query::Queryable<()>,
}

impl Router {
    async fn declare(session: &Session, layout: &KeyLayout, routes: Routes) -> Result<Self, zenoh::Error> {
        let routes = Arc::new(routes);
        let fields = Space::Fields(layout.clone());
        let (r1, s1) = (routes.clone(), fields.clone());
        let (r2, s2) = (routes.clone(), fields);
        let (r3, r4) = (routes.clone(), routes);
        Ok(Self {
            _writes: session
                .declare_subscriber(layout.every_field())
                .callback(move |sample| {
                    if !is_state(&sample) {
                        route_sample(&r1, &s1, sample, AxisInput::Write);
                    }
                })
                .await?,
            _queries: session
                .declare_queryable(layout.everything())
                .callback(move |q| route_query(&r2, &s2, q, AxisInput::Query))
                .await?,
            _sim_writes: session
                .declare_subscriber(keys::sim_key("*", "*"))
                .callback(move |sample| {
                    if !is_state(&sample) {
                        route_sample(&r3, &Space::Sim, sample, AxisInput::SimWrite);
                    }
                })
                .await?,
            _sim_queries: session
                .declare_queryable(keys::sim_key("*", "**"))
                .callback(move |q| route_query(&r4, &Space::Sim, q, AxisInput::SimQuery))
                .await?,
        })
    }
}

/// The keys a router serves: the axes' fields under a prefix, or the simulator's.
#[derive(Clone)]
enum Space {
    Fields(KeyLayout),
    Sim,
}

impl Space {
    /// The axis chunk of a key in this space.
    fn axis_chunk<'k>(&self, key: &'k str) -> Option<&'k str> {
        match self {
            Space::Fields(layout) => layout.axis_chunk(key),
            Space::Sim => keys::sim_axis_chunk(key),
        }
    }

    /// Every key of one axis in this space.
    fn everything_of(&self, axis: &str) -> String {
        match self {
            Space::Fields(layout) => layout.axis_all(axis),
            Space::Sim => keys::sim_key(axis, "**"),
        }
    }
}

/// A sample goes to the axis its key names, if it is one of ours.
fn route_sample(routes: &Routes, space: &Space, sample: Sample, wrap: fn(Sample) -> AxisInput) {
    let handle = space.axis_chunk(sample.key_expr().as_str()).and_then(|axis| routes.get(axis));
    if let Some(handle) = handle {
        handle.deliver(wrap(sample));
    }
}

/// A query goes to every axis of ours it can concern (one, or all for a wildcard).
fn route_query(routes: &Routes, space: &Space, query: Query, wrap: fn(Query) -> AxisInput) {
    let chunk = space.axis_chunk(query.key_expr().as_str()).unwrap_or("");
    if !chunk.is_empty() && !chunk.contains(['*', '$']) {
        if let Some(handle) = routes.get(chunk) {
            handle.deliver(wrap(query));
        }
        return;
    }
    for (axis, handle) in routes.iter() {
        let Ok(all) = KeyExpr::try_from(space.everything_of(axis)) else { continue };
        if query.key_expr().intersects(&all) {
            handle.deliver(wrap(query.clone()));
        }
    }
}

/// One axis and its Zenoh side, under one lock: whatever reaches the axis (a write, a query, a
/// link update, a tick) is applied and its outputs sent before the lock is released.
/// Publications and replies are sent without awaiting (`wait`), so a Zenoh callback can run this.
struct AxisCore {
    service: AxisService<Query>,
    session: Session,
    layout: KeyLayout,
    clock: tokio::time::Instant,
    /// Declared at the first driver command, so idle axes cost no publisher.
    trace: Option<zenoh::pubsub::Publisher<'static>>,
    /// Publishers of the fields this axis posts again and again, declared at their second post:
    /// a declared publisher's put costs a fraction of a session put (the key is resolved once).
    hot: Vec<(Field, zenoh::pubsub::Publisher<'static>)>,
    /// Fields posted once so far (with a session put).
    posted_once: Vec<Field>,
    /// Declarations the node may still make (`PUBLISHER_BUDGET`), shared by its axes.
    budget: Arc<AtomicUsize>,
}

/// Publishers one node declares at most (fields and traces). Zenoh numbers a session's
/// declarations with 16 bits and remaps them beyond (logging "Remapping unsupported"); 10,000
/// moving axes with 30,000 field publishers went past it, so the budget is kept well inside,
/// with room for every axis's liveliness token and trace. Past it, fields are published with
/// session puts: slower, always correct. (1,000 axes moving back and forth declare about 17,000.)
const PUBLISHER_BUDGET: usize = 20_000;

impl AxisCore {
    fn now(&self) -> Instant {
        Instant::after(self.clock.elapsed())
    }

    fn name(&self) -> &str {
        self.service.name()
    }

    fn field_key(&self, field: Field) -> KeyExpr<'static> {
        KeyExpr::try_from(self.layout.field(self.name(), field)).expect("axis names are checked at launch")
    }

    fn handle(&mut self, input: AxisInput) {
        let now = self.now();
        match input {
            AxisInput::Write(sample) => {
                let key = sample.key_expr().as_str();
                if let Some(name) = self.layout.field_name(self.service.name(), key).map(str::to_string) {
                    let encoding = PayloadEncoding::from_mime(&sample.encoding().to_string());
                    self.service.put(now, &name, &sample.payload().to_bytes(), encoding);
                }
            }
            AxisInput::Query(query) => self.on_query(now, query),
            AxisInput::SimWrite(sample) => {
                let name = sample.key_expr().as_str().rsplit('/').next().unwrap_or_default().to_string();
                let encoding = PayloadEncoding::from_mime(&sample.encoding().to_string());
                self.service.sim_write(now, &name, &sample.payload().to_bytes(), encoding);
            }
            AxisInput::SimQuery(query) => {
                let selected = query.key_expr().clone();
                let axis = self.name().to_string();
                let selects = |name: &str| {
                    KeyExpr::try_from(keys::sim_key(&axis, name)).is_ok_and(|key| selected.intersects(&key))
                };
                self.service.sim_read(now, selects, query);
            }
        }
        self.flush();
    }

    fn on_query(&mut self, now: Instant, query: Query) {
        let name = self.layout.field_name(self.service.name(), query.key_expr().as_str()).map(str::to_string);
        match (name, query.payload().map(|p| p.to_bytes().into_owned())) {
            (Some(name), Some(payload)) => {
                let encoding = PayloadEncoding::from_mime(&query.encoding().map(|e| e.to_string()).unwrap_or_default());
                let wait = query.parameters().contains_key(keys::WAIT_PARAMETER);
                self.service.write(now, &name, &payload, encoding, wait, query);
            }
            (Some(name), None) if !name.contains('*') => self.service.read(&name, query),
            _ => {
                // A read of a key expression that may cover several fields.
                let selected = query.key_expr().clone();
                let keys: Vec<KeyExpr<'static>> = Field::all().map(|f| self.field_key(f)).collect();
                self.service.read_selected(|f| selected.intersects(&keys[f as usize]), query);
            }
        }
    }

    fn tick(&mut self) {
        let now = self.now();
        self.service.handle_timeout(now);
        self.flush();
    }

    fn link_update(&mut self, link: InputLink, value: f64) {
        let now = self.now();
        self.service.link_update(now, link, value);
        self.flush();
    }

    /// The start of a shutdown: a moving axis is told to stop.
    fn stop_motion(&mut self) {
        let now = self.now();
        self.service.stop_motion(now);
        self.flush();
    }

    /// Send everything the service has for the network.
    fn flush(&mut self) {
        let mut traced = None;
        while let Some(output) = self.service.poll_output() {
            match output {
                ServiceOutput::Publish { field, value, marker } => self.publish(field, &value, &marker),
                ServiceOutput::Refusal { message, marker } => {
                    let key = self.layout.err(self.name());
                    let attachment = ZBytes::from(marker.encode());
                    let _ = self.session.put(key, message).encoding(Encoding::TEXT_PLAIN).attachment(attachment).wait();
                }
                ServiceOutput::Reply { to, reply } => self.reply(&to, reply),
                ServiceOutput::DriverCommand { command, at } => {
                    let trace_publisher = self.trace_publisher();
                    let listening = *traced.get_or_insert_with(|| {
                        trace_publisher.is_some_and(|p| p.matching_status().wait().is_ok_and(|m| m.matching()))
                    });
                    if listening {
                        let trace = self.service.stamp_trace(command, at);
                        if let Some(publisher) = &self.trace {
                            let _ = publisher.put(encode_cbor(&trace)).wait();
                        }
                    }
                }
                ServiceOutput::Put { key, value } => {
                    // A link's or directive's put is a command to another node: a plain write, no marker.
                    if let Err(e) = self.session.put(&key, value).encoding(Encoding::TEXT_PLAIN).wait() {
                        tracing::warn!(axis = %self.name(), key, "put failed: {e}");
                    }
                }
            }
        }
    }

    /// The trace publisher, declared at the first driver command; it must exist whatever the
    /// budget, and counts against it all the same.
    fn trace_publisher(&mut self) -> Option<&zenoh::pubsub::Publisher<'static>> {
        if self.trace.is_none() {
            let key = self.layout.driver_cmd(self.name());
            self.trace = self.session.declare_publisher(key).encoding(Encoding::APPLICATION_CBOR).wait().ok();
            let _ = self.budget.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1));
        }
        self.trace.as_ref()
    }

    fn reply(&self, query: &Query, reply: Reply) {
        let (key, payload) = match reply {
            Reply::Value(field, value) => (self.field_key(field), encode_cbor(&value)),
            Reply::Completion(field, completion) => (self.field_key(field), encode_cbor(&completion)),
            Reply::SimState(state) => match KeyExpr::try_from(keys::sim_key(self.name(), keys::SIM_STATE_KEY)) {
                Ok(key) => (key, encode_cbor(&state)),
                Err(_) => return,
            },
            Reply::SimSetting(setting, value) => match KeyExpr::try_from(keys::sim_key(self.name(), setting.name())) {
                Ok(key) => (key, encode_cbor(&value)),
                Err(_) => return,
            },
            Reply::Refused(refusal) => {
                let _ = query.reply_err(refusal.to_string()).encoding(Encoding::TEXT_PLAIN).wait();
                return;
            }
        };
        let _ = query.reply(key, payload).encoding(Encoding::APPLICATION_CBOR).wait();
    }

    fn publish(&mut self, field: Field, value: &Value, marker: &StateMarker) {
        let attachment = ZBytes::from(marker.encode());
        let payload = encode_cbor(value);
        let declared = match self.hot.iter().position(|(f, _)| *f == field) {
            Some(index) => Some(index),
            None if !self.posted_once.contains(&field) => {
                self.posted_once.push(field);
                None
            }
            None if self.budget.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1)).is_ok() => {
                match self.session.declare_publisher(self.field_key(field)).encoding(Encoding::APPLICATION_CBOR).wait()
                {
                    Ok(publisher) => {
                        self.hot.push((field, publisher));
                        Some(self.hot.len() - 1)
                    }
                    Err(e) => {
                        tracing::warn!(axis = %self.name(), %field, "cannot declare a publisher: {e}");
                        None
                    }
                }
            }
            None => None,
        };
        let _ = match declared {
            Some(index) => self.hot[index].1.put(payload).attachment(attachment).wait(),
            None => self
                .session
                .put(self.field_key(field), payload)
                .encoding(Encoding::APPLICATION_CBOR)
                .attachment(attachment)
                .wait(),
        };
    }
}

/// The task of one axis: the wall clock, link updates, queued inputs, autosave and shutdown.
struct AxisTask {
    core: Arc<Mutex<AxisCore>>,
    queue: tokio::sync::mpsc::UnboundedReceiver<AxisInput>,
    queued: Arc<AtomicUsize>,
    rearm: Arc<tokio::sync::Notify>,
    /// Values of the record's input links (RDBL, RINP, DINP, DOL), by `link_kinds` index.
    links: KeyFollower,
    link_kinds: Vec<InputLink>,
    saver: Option<Saver>,
    token: Option<zenoh::liveliness::LivelinessToken>,
    name: String,
}

impl AxisTask {
    /// Serve until the node stops; then stop the motion, save and withdraw the liveliness token.
    async fn run(&mut self, mut stopped: tokio::sync::watch::Receiver<bool>) {
        let mut stopping: Option<tokio::time::Instant> = None;
        let clock = lock(&self.core).clock;
        loop {
            // Nothing due (a Soft Channel axis waiting for its links): look again in a minute.
            let idle = clock.elapsed() + Duration::from_secs(60);
            let next = lock(&self.core).service.poll_timeout().map_or(idle, Instant::since_origin);
            let mut wake = clock + next;
            for deadline in [stopping, self.saver.as_ref().and_then(|s| s.due)].into_iter().flatten() {
                wake = wake.min(deadline);
            }
            tokio::select! {
                Some((index, value)) = self.links.values.recv() => {
                    lock(&self.core).link_update(self.link_kinds[index], value);
                }
                Some(input) = self.queue.recv() => {
                    self.queued.fetch_sub(1, Ordering::AcqRel);
                    lock(&self.core).handle(input);
                }
                _ = tokio::time::sleep_until(wake) => lock(&self.core).tick(),
                _ = self.rearm.notified() => {}
                _ = stopped.changed(), if stopping.is_none() => {
                    stopping = Some(tokio::time::Instant::now() + STOP_GRACE);
                    lock(&self.core).stop_motion();
                }
            }
            self.autosave(false).await;
            let done = lock(&self.core).service.fields().dmov == 1;
            if stopping.is_some_and(|limit| done || tokio::time::Instant::now() >= limit) {
                break;
            }
        }
        if lock(&self.core).service.fields().dmov == 0 {
            tracing::warn!(axis = %self.name, "still moving {STOP_GRACE:?} after the stop; saving anyway");
        }
        self.autosave(true).await;
        if let Some(token) = self.token.take() {
            let _ = token.undeclare().await;
        }
    }

    /// Note changes of saved fields, and write the file when due (or now, with `finally`).
    async fn autosave(&mut self, finally: bool) {
        let Some(saver) = &mut self.saver else { return };
        let snapshot = {
            let mut core = lock(&self.core);
            if core.service.take_unsaved_change() {
                saver.changed(tokio::time::Instant::now());
            }
            let due = saver.due.is_some_and(|due| tokio::time::Instant::now() >= due);
            (finally || due).then(|| SavedAxis::of(core.service.fields()))
        };
        if let Some(saved) = snapshot {
            saver.flush(&self.name, saved).await;
        }
    }
}

/// The autosave of one axis: a change arms a deadline `delay` ahead; at the deadline the
/// saved fields are written if they differ from what the file holds. Writes run off the
/// runtime's threads; the axis waits for each (a few milliseconds, at most once per `delay`).
struct Saver {
    store: StateStore,
    delay: Duration,
    /// What the file holds.
    written: SavedAxis,
    due: Option<tokio::time::Instant>,
}

impl Saver {
    /// Lay the saved state over the plan's fields, and be ready to save the axis.
    fn restore(config: &AutosaveConfig, plan: &mut AxisPlan) -> Result<Self, AutosaveError> {
        let saved = config.store.restore(&plan.name, &mut plan.fields)?;
        if saved.is_some() {
            tracing::info!(axis = %plan.name, file = %config.store.path(&plan.name).display(), "restored saved state");
        }
        Ok(Self { store: config.store.clone(), delay: config.delay, written: saved.unwrap_or_default(), due: None })
    }

    fn changed(&mut self, now: tokio::time::Instant) {
        self.due.get_or_insert(now + self.delay);
    }

    /// Write `saved` now if it differs from the file, and wait until it is written.
    async fn flush(&mut self, axis: &str, saved: SavedAxis) {
        self.due = None;
        if saved == self.written {
            return;
        }
        self.written = saved.clone();
        let (store, axis) = (self.store.clone(), axis.to_string());
        let write = tokio::task::spawn_blocking(move || {
            if let Err(e) = store.save(&axis, &saved) {
                tracing::error!(axis, file = %store.path(&axis).display(), "autosave failed: {e}");
            }
        });
        let _ = write.await;
    }
}
