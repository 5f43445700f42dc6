//! A node: the axes of one process served on a Zenoh session. Each axis is a sans-IO
//! `AxisService` (zmotor-core); this module only moves bytes: samples and queries in, the
//! wall clock as ticks, publications, replies and trace samples out, as
//! ../shared/spec/zenoh-api.md requires.
//!
//! One subscriber and one queryable per node (not per axis) take everything addressed to the
//! node's axes and hand it to the axis by name: Zenoh's cost per declaration grows with the
//! declarations already there, and thousands of axes would pay it squared.

use crate::autosave::{AutosaveError, SavedAxis, StateStore};
use crate::controllers::{ControllerPort, RunningController, ToController};
use crate::holds::Holds;
use crate::links::{is_state, CalcTask, Follows, LocalFollowers, ValueHolder, ValueSpec};
use crate::timer::Timer;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, TryLockError};
use std::time::Duration;
use zenoh::bytes::{Encoding, ZBytes};
use zenoh::key_expr::KeyExpr;
use zenoh::query::Query;
use zenoh::sample::{Locality, Sample};
use zenoh::{Session, Wait};
use zmotor_bridge::{CalcLink, CalcLinkSpec, LinkError};
use zmotor_controllers::spec::ControllerSpec;
use zmotor_core::axis::{AxisPlan, DriverPlan};
use zmotor_core::driver::soft::InputLink;
use zmotor_core::engine::DeviceStatus;
use zmotor_core::service::{AxisService, Reply, ServiceOutput, WriteRequest};
use zmotor_core::Instant;
use zmotor_msgs::{encode_cbor, keys, Field, Hold, KeyLayout, PayloadEncoding, StateMarker, Value};

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
    /// The timer thread cannot be started.
    #[error("cannot start the timer thread: {0}")]
    Timer(std::io::Error),
    /// An axis names a controller the node does not run.
    #[error("axis '{axis}': no controller '{controller}' in this node")]
    UnknownController {
        /// The axis.
        axis: String,
        /// The controller it names.
        controller: String,
    },
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

/// Where an axis's liveliness token is kept once declared.
type TokenSlot = Arc<Mutex<Option<zenoh::liveliness::LivelinessToken>>>;

/// The liveliness tokens of a node's axes (`<prefix>/<axis>`), declared in order by a task of
/// their own once the axes already answer; each axis withdraws its own at shutdown.
#[derive(Default)]
struct Tokens(Vec<(String, TokenSlot)>);

impl Tokens {
    fn slot(&mut self, axis: &str) -> TokenSlot {
        let slot = TokenSlot::default();
        self.0.push((axis.to_string(), slot.clone()));
        slot
    }

    fn declare_in_background(self, session: &Session, layout: &KeyLayout, stopped: tokio::sync::watch::Receiver<bool>) {
        let (session, layout) = (session.clone(), layout.clone());
        tokio::spawn(async move {
            for (axis, slot) in self.0 {
                if *stopped.borrow() {
                    return;
                }
                match session.liveliness().declare_token(layout.axis(&axis)).await {
                    Ok(token) => *slot.lock().unwrap_or_else(|e| e.into_inner()) = Some(token),
                    Err(e) => tracing::error!(axis, "cannot declare the liveliness token: {e}"),
                }
            }
        });
    }
}

/// How long a shutdown waits for moving axes to stop before saving anyway.
const STOP_GRACE: Duration = Duration::from_secs(5);

/// How long the axes of a controller wait at start-up for its first full poll; past it, they
/// boot in COMM alarm and follow the controller when it answers.
const CONTROLLER_BOOT_WAIT: Duration = Duration::from_secs(10);

/// What a node serves.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NodeContents {
    /// Its axes.
    pub plans: Vec<AxisPlan>,
    /// Its calc links.
    pub calcs: Vec<CalcLinkSpec>,
    /// Its value holders.
    pub values: Vec<ValueSpec>,
    /// The controllers its axes are on.
    pub controllers: Vec<ControllerSpec>,
    /// Under access control: a confirmed write is taken on a write key only
    /// (`KeyLayout::write`), which the rules can tell from a read.
    pub guarded: bool,
}

/// A running node: its axes' and calc links' tasks, stopped when dropped or on `shutdown`.
pub struct Node {
    axis_tasks: Vec<tokio::task::JoinHandle<()>>,
    calc_tasks: Vec<tokio::task::JoinHandle<()>>,
    controller_tasks: Vec<tokio::task::JoinHandle<()>>,
    stop: tokio::sync::watch::Sender<bool>,
    /// Stops the controllers, after the axes (their last stop commands go through them).
    stop_controllers: tokio::sync::watch::Sender<bool>,
    _router: Router,
    _values: Vec<ValueHolder>,
}

impl Node {
    /// Start one task per controller, then one per axis (an axis on a controller boots on the
    /// controller's first full poll), then one per calc link, on `session`. With autosave,
    /// each axis boots from its saved state (RSTM deciding about the position) and saves its
    /// changes.
    pub async fn start(
        session: Session,
        layout: KeyLayout,
        contents: NodeContents,
        autosave: Option<AutosaveConfig>,
    ) -> Result<Self, NodeError> {
        let NodeContents { plans, calcs, values, controllers, guarded } = contents;
        let (stop, stopped) = tokio::sync::watch::channel(false);
        let (stop_controllers, controllers_stopped) = tokio::sync::watch::channel(false);
        let mut running: Vec<RunningController> =
            controllers.into_iter().map(|spec| crate::controllers::start(spec, controllers_stopped.clone())).collect();
        let mut first_statuses = std::collections::HashMap::new();
        for controller in &mut running {
            let first = tokio::time::timeout(CONTROLLER_BOOT_WAIT, &mut controller.first).await;
            first_statuses.insert(controller.name.clone(), first.ok().and_then(Result::ok).unwrap_or_default());
        }
        let mut on_controllers: std::collections::HashMap<String, Vec<(usize, AxisHandle)>> = Default::default();
        let timer = Timer::start().map_err(NodeError::Timer)?;
        let writer = Writer { session: session.clone(), fields: Space::Fields(layout.clone()), local: Arc::default() };
        let followers = Arc::new(LocalFollowers::new(layout.clone()));
        let mut tokens = Tokens::default();
        let demand = Arc::new(FieldDemand::declare(&session, &layout).await?);
        let mut routes = std::collections::HashMap::new();
        let mut axis_tasks = Vec::new();
        let budget = Arc::new(AtomicUsize::new(PUBLISHER_BUDGET));
        for mut plan in plans {
            let saver = match &autosave {
                Some(config) => Some(Saver::restore(config, &mut plan)?),
                None => None,
            };
            let (mut follows, links) = Follows::new(&session, followers.clone());
            for (link, key) in plan.input_links() {
                follows.follow(link as usize, &key)?;
            }
            let (holds, released) = Holds::new(&session, tokio::runtime::Handle::current());
            let (name, jog_hold) = (plan.name.clone(), plan.jog_hold);
            let on_controller = match &plan.driver {
                DriverPlan::Controller { controller, channel } => Some((controller.clone(), *channel)),
                _ => None,
            };
            let (controller, first_status) = match &on_controller {
                Some((controller, channel)) => {
                    let running = running.iter().find(|r| r.name == *controller).ok_or_else(|| {
                        NodeError::UnknownController { axis: name.clone(), controller: controller.clone() }
                    })?;
                    let port = ControllerPort { sender: running.sender.clone(), channel: *channel };
                    let known: Option<&std::collections::BTreeMap<usize, DeviceStatus>> =
                        first_statuses.get(controller);
                    (Some(port), known.and_then(|statuses| statuses.get(channel).copied()))
                }
                None => (None, None),
            };
            let core = AxisCore {
                service: AxisService::new(&layout, &name, plan.build(Instant::ZERO, first_status))
                    .with_jog_hold(jog_hold),
                controller: controller.clone(),
                session: session.clone(),
                writer: writer.clone(),
                followers: followers.clone(),
                follows,
                holds,
                demand: demand.clone(),
                layout: layout.clone(),
                guarded,
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
            if let Some((controller, channel)) = on_controller {
                on_controllers.entry(controller).or_default().push((channel, handle.clone()));
            }
            axis_tasks.push(AxisTask {
                core: handle.core,
                queue,
                queued: handle.queued,
                rearm: handle.rearm,
                links,
                released,
                saver,
                timer: timer.clone(),
                token: tokens.slot(&name),
                name,
            });
        }
        for controller in &running {
            let axes = on_controllers.remove(&controller.name).unwrap_or_default();
            let sink = move |channel: usize, status: DeviceStatus, motions: u64| {
                for (_, handle) in axes.iter().filter(|(c, _)| *c == channel) {
                    handle.deliver(AxisInput::ControllerStatus(status, motions));
                }
            };
            let _ = controller.sender.send(ToController::Attach(Box::new(sink)));
        }
        let controller_tasks = running.into_iter().map(|r| r.task).collect();
        let router = Router::declare(&session, &layout, routes, &writer).await?;
        // The axes answer as soon as the router exists; their liveliness tokens follow, as
        // Zenoh's cost per token grows with the tokens already declared.
        tokens.declare_in_background(&session, &layout, stopped.clone());
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
            let (mut follows, inputs) = Follows::new(&session, followers.clone());
            for (index, key) in link.input_keys().enumerate() {
                follows.follow(index, key)?;
            }
            let mut task = CalcTask { writer: writer.clone(), link, _follows: follows, inputs };
            calc_tasks.push(tokio::spawn(async move { task.run().await }));
        }
        Ok(Self { axis_tasks, calc_tasks, controller_tasks, stop, stop_controllers, _router: router, _values: holders })
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
        let _ = self.stop_controllers.send(true);
        for task in std::mem::take(&mut self.controller_tasks) {
            let _ = task.await;
        }
    }
}

impl Drop for Node {
    fn drop(&mut self) {
        let _ = self.stop.send(true);
        let _ = self.stop_controllers.send(true);
        for task in &self.calc_tasks {
            task.abort();
        }
    }
}

/// What reaches one axis: from the network, or from this node itself.
enum AxisInput {
    Write(Written),
    Query(Query),
    SimWrite(Written),
    SimQuery(Query),
    /// What the axis's controller reported for its channel, after how many motion commands.
    ControllerStatus(DeviceStatus, u64),
}

/// A plain write to one key of an axis: the field (or simulator setting) named, the payload.
struct Written {
    name: String,
    payload: Vec<u8>,
    encoding: PayloadEncoding,
    /// The hold its attachment names, if any.
    hold: Option<Hold>,
}

/// Plain writes this node makes to keys: link outputs, directives, calc results. The node's own
/// subscribers do not hear its session (so publishing costs it no delivery to itself), so a
/// write to one of its own axes is handed to that axis here, and put on the network for
/// everyone else.
#[derive(Clone)]
pub(crate) struct Writer {
    session: Session,
    fields: Space,
    /// The node's axes, once its router exists; weak, as the axes hold this writer.
    local: Arc<std::sync::OnceLock<std::sync::Weak<Routes>>>,
}

impl Writer {
    /// Write `value` (text) to `key`.
    pub(crate) fn put(&self, key: &str, value: String) {
        if let Some(routes) = self.local.get().and_then(std::sync::Weak::upgrade) {
            for (space, wrap) in
                [(&self.fields, AxisInput::Write as fn(Written) -> AxisInput), (&Space::Sim, AxisInput::SimWrite)]
            {
                if let Some((handle, name)) = space.target(&routes, key) {
                    let written = Written {
                        name,
                        payload: value.as_bytes().to_vec(),
                        encoding: PayloadEncoding::Text,
                        hold: None,
                    };
                    handle.deliver(wrap(written));
                }
            }
        }
        if let Err(e) = self.session.put(key, value).encoding(Encoding::TEXT_PLAIN).wait() {
            tracing::warn!(key, "put failed: {e}");
        }
    }
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
    /// Wakes the axis's task: its deadline came, or may have moved.
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
    _confirmed_writes: zenoh::query::Queryable<()>,
    _sim_writes: zenoh::pubsub::Subscriber<()>,
    _sim_queries: zenoh::query::Queryable<()>,
}

impl Router {
    async fn declare(
        session: &Session,
        layout: &KeyLayout,
        routes: Routes,
        writer: &Writer,
    ) -> Result<Self, zenoh::Error> {
        let routes = Arc::new(routes);
        let _ = writer.local.set(Arc::downgrade(&routes));
        let fields = Space::Fields(layout.clone());
        let (r1, s1) = (routes.clone(), fields.clone());
        let (r2, s2) = (routes.clone(), fields.clone());
        let (r5, s5) = (routes.clone(), fields);
        let (r3, r4) = (routes.clone(), routes);
        // The node's own publications do not come back to it: what it writes to its own axes
        // goes through `Writer`.
        Ok(Self {
            _writes: session
                .declare_subscriber(layout.every_field())
                .allowed_origin(Locality::Remote)
                .callback(move |sample| {
                    if !is_state(&sample) {
                        route_sample(&r1, &s1, &sample, AxisInput::Write);
                    }
                })
                .await?,
            _queries: session
                .declare_queryable(layout.everything())
                .callback(move |q| route_query(&r2, &s2, q, AxisInput::Query))
                .await?,
            // `<prefix>/**` does not cover the `@write` chunk: write keys are served apart.
            _confirmed_writes: session
                .declare_queryable(layout.every_write())
                .callback(move |q| route_query(&r5, &s5, q, AxisInput::Query))
                .await?,
            _sim_writes: session
                .declare_subscriber(keys::sim_key("*", "*"))
                .allowed_origin(Locality::Remote)
                .callback(move |sample| {
                    if !is_state(&sample) {
                        route_sample(&r3, &Space::Sim, &sample, AxisInput::SimWrite);
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

    /// The axis of ours a key names, and the name of the field or setting it names.
    fn target<'r>(&self, routes: &'r Routes, key: &str) -> Option<(&'r AxisHandle, String)> {
        let axis = self.axis_chunk(key)?;
        let handle = routes.get(axis)?;
        let name = match self {
            Space::Fields(layout) => layout.field_name(axis, key)?,
            Space::Sim => key.rsplit('/').next()?,
        };
        Some((handle, name.to_string()))
    }
}

/// A sample goes to the axis its key names, if it is one of ours.
fn route_sample(routes: &Routes, space: &Space, sample: &Sample, wrap: fn(Written) -> AxisInput) {
    if sample.key_expr().as_str().contains(['*', '$']) {
        tracing::warn!(key = %sample.key_expr(), "a put to a key with wildcards is not a write; ignored");
        return;
    }
    if let Some((handle, name)) = space.target(routes, sample.key_expr().as_str()) {
        let encoding = PayloadEncoding::from_mime(&sample.encoding().to_string());
        let hold = sample.attachment().and_then(|a| Hold::decode(&a.to_bytes()));
        handle.deliver(wrap(Written { name, payload: sample.payload().to_bytes().into_owned(), encoding, hold }));
    }
}

/// A query goes to every axis of ours it can concern (one, or all for a wildcard).
fn route_query(routes: &Routes, space: &Space, query: Query, wrap: fn(Query) -> AxisInput) {
    if query.payload().is_some() && query.key_expr().as_str().contains(['*', '$']) {
        // Answering with the fields' values would look like success, and writing every match
        // is not what a write means: refused, naming the key.
        let message = format!("{}: a write names one field of one axis; this key has wildcards", query.key_expr());
        let _ = query.reply_err(message).encoding(Encoding::TEXT_PLAIN).wait();
        return;
    }
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
    /// The controller behind the axis, if it has one: its driver commands go there.
    controller: Option<ControllerPort>,
    session: Session,
    /// Its plain writes to other keys.
    writer: Writer,
    /// Links of this node that follow this axis's fields.
    followers: Arc<LocalFollowers>,
    /// The keys this axis's input links follow, by `InputLink` index.
    follows: Follows,
    /// The liveliness tokens its held motions depend on.
    holds: Holds,
    layout: KeyLayout,
    /// Whether confirmed writes are taken on write keys only (`NodeContents::guarded`).
    guarded: bool,
    clock: tokio::time::Instant,
    /// Declared at the first driver command, so idle axes cost no publisher.
    trace: Option<zenoh::pubsub::Publisher<'static>>,
    /// Publishers of the fields this axis posts again and again, declared at their second post:
    /// a declared publisher's put costs a fraction of a session put (the key is resolved once).
    hot: Vec<(Field, zenoh::pubsub::Publisher<'static>)>,
    /// Which fields anyone on the network subscribes to.
    demand: Arc<FieldDemand>,
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
            AxisInput::Write(w) => {
                self.service.put(now, WriteRequest::new(&w.name, &w.payload, w.encoding).held(w.hold))
            }
            AxisInput::Query(query) => self.on_query(now, query),
            AxisInput::SimWrite(w) => self.service.sim_write(now, &w.name, &w.payload, w.encoding),
            AxisInput::SimQuery(query) => {
                let selected = query.key_expr().clone();
                let axis = self.name().to_string();
                let selects = |name: &str| {
                    KeyExpr::try_from(keys::sim_key(&axis, name)).is_ok_and(|key| selected.intersects(&key))
                };
                self.service.sim_read(now, selects, query);
            }
            AxisInput::ControllerStatus(status, motions) => self.service.controller_status(now, status, motions),
        }
        self.flush();
    }

    fn on_query(&mut self, now: Instant, query: Query) {
        let key = query.key_expr().as_str();
        let written = self.layout.written_field_name(self.service.name(), key);
        let name = written.or_else(|| self.layout.field_name(self.service.name(), key)).map(str::to_string);
        match (name, query.payload().map(|p| p.to_bytes().into_owned())) {
            (Some(name), Some(_)) if self.guarded && written.is_none() => {
                // Here a query on a field key is a read: the access rules let readers make it.
                let message = format!(
                    "{key}: this node is under access control; a confirmed write goes to {}/@write/{name}",
                    self.layout.axis(self.service.name())
                );
                let _ = query.reply_err(message).encoding(Encoding::TEXT_PLAIN).wait();
            }
            (Some(name), Some(payload)) => {
                let encoding = PayloadEncoding::from_mime(&query.encoding().map(|e| e.to_string()).unwrap_or_default());
                let wait = query.parameters().contains_key(keys::WAIT_PARAMETER);
                let hold = query.attachment().and_then(|a| Hold::decode(&a.to_bytes()));
                let request = WriteRequest::new(&name, &payload, encoding).held(hold);
                self.service.write(now, request, wait, query);
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

    fn hold_released(&mut self, token: &str) {
        let now = self.now();
        self.service.hold_released(now, token);
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
                    if let Some(controller) = &self.controller {
                        controller.send(command.clone());
                    }
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
                // A link's or directive's put is a command: a plain write, no marker.
                ServiceOutput::Put { key, value } => self.writer.put(&key, value),
                ServiceOutput::WatchHold { token } => self.holds.watch(&token),
                ServiceOutput::ForgetHold { token } => self.holds.forget(&token),
                ServiceOutput::Follow { link, key } => {
                    if let Err(e) = self.follows.follow(link as usize, &key) {
                        tracing::error!(axis = %self.name(), key, "cannot follow the link: {e}");
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
        // A reply to a write key carries that key: Zenoh drops replies outside the query's.
        let written = self.layout.written_field_name(self.name(), query.key_expr().as_str()).is_some();
        let key_of = |field| if written { query.key_expr().clone().into_owned() } else { self.field_key(field) };
        let (key, payload) = match reply {
            Reply::Value(field, value) => (key_of(field), encode_cbor(&value)),
            Reply::Completion(field, completion) => (key_of(field), encode_cbor(&completion)),
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

    /// Publish a field's new value: to the links of this node that follow it, and to the
    /// network when a subscriber there wants that field (as the record posts a monitor only to
    /// those who asked). Publications go to other processes only: the node hears itself
    /// in-process.
    fn publish(&mut self, field: Field, value: &Value, marker: &StateMarker) {
        self.followers.deliver(self.service.name(), field, value);
        if !self.demand.wanted(field) {
            return;
        }
        let declared = match self.hot.iter().position(|(f, _)| *f == field) {
            Some(index) => Some(index),
            None if !self.posted_once.contains(&field) => {
                self.posted_once.push(field);
                None
            }
            None if self.budget.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1)).is_ok() => {
                let declared = self
                    .session
                    .declare_publisher(self.field_key(field))
                    .encoding(Encoding::APPLICATION_CBOR)
                    .allowed_destination(Locality::Remote)
                    .wait();
                match declared {
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
        let attachment = ZBytes::from(marker.encode());
        let _ = match declared {
            Some(index) => self.hot[index].1.put(encode_cbor(value)).attachment(attachment).wait(),
            None => self
                .session
                .put(self.field_key(field), encode_cbor(value))
                .encoding(Encoding::APPLICATION_CBOR)
                .allowed_destination(Locality::Remote)
                .attachment(attachment)
                .wait(),
        };
    }
}

/// Which fields some subscriber on the network wants, of any axis: one probe publisher per
/// field on `<prefix>/*/<FIELD>` whose matching status Zenoh keeps current. A field nobody
/// subscribes to, for any axis, is not published (the record posts monitors only to those who
/// asked); a subscriber of any axis's field gets that field from every axis, so no subscriber is
/// ever missed. (A matching listener per axis and field does not scale in Zenoh 1.10: every
/// subscriber declaration re-evaluates every listener.)
pub(crate) struct FieldDemand {
    wanted: Vec<Arc<AtomicBool>>,
    _probes: Vec<zenoh::pubsub::Publisher<'static>>,
}

impl FieldDemand {
    async fn declare(session: &Session, layout: &KeyLayout) -> Result<Self, zenoh::Error> {
        let (mut wanted, mut probes) = (Vec::new(), Vec::new());
        for field in Field::all() {
            let probe =
                session.declare_publisher(layout.field("*", field)).allowed_destination(Locality::Remote).await?;
            let flag = Arc::new(AtomicBool::new(true));
            let listener = flag.clone();
            probe
                .matching_listener()
                .callback(move |status| listener.store(status.matching(), Ordering::Release))
                .background()
                .await?;
            wanted.push(flag);
            probes.push(probe);
        }
        Ok(Self { wanted, _probes: probes })
    }

    fn wanted(&self, field: Field) -> bool {
        self.wanted[field as usize].load(Ordering::Acquire)
    }
}

/// The task of one axis: the wall clock, link updates, queued inputs, autosave and shutdown.
struct AxisTask {
    core: Arc<Mutex<AxisCore>>,
    queue: tokio::sync::mpsc::UnboundedReceiver<AxisInput>,
    queued: Arc<AtomicUsize>,
    rearm: Arc<tokio::sync::Notify>,
    /// Values of the record's input links (RDBL, RINP, DINP, DOL), by `InputLink` index.
    links: tokio::sync::mpsc::UnboundedReceiver<(usize, f64)>,
    /// Liveliness tokens of held motions that went.
    released: tokio::sync::mpsc::UnboundedReceiver<String>,
    saver: Option<Saver>,
    /// Wakes the task (through `rearm`) when the axis's next event comes.
    timer: Timer,
    /// The axis's liveliness token, once declared.
    token: TokenSlot,
    name: String,
}

impl AxisTask {
    /// Serve until the node stops; then stop the motion, save and withdraw the liveliness token.
    async fn run(&mut self, mut stopped: tokio::sync::watch::Receiver<bool>) {
        let mut stopping: Option<tokio::time::Instant> = None;
        let clock = lock(&self.core).clock;
        let mut scheduled = None;
        loop {
            // Polls keep tokio's millisecond timer; events (the end of a motion, DLY) also go to
            // the precise one, so they are reported when they happen. A Soft Channel axis may
            // have no deadline at all.
            let (next, event) = {
                let core = lock(&self.core);
                let at = |t: zmotor_core::Instant| clock + t.since_origin();
                (core.service.poll_timeout().map(at), core.service.event_timeout().map(at))
            };
            if event != scheduled {
                if let Some(at) = event {
                    self.timer.wake_at(at.into_std(), self.rearm.clone());
                }
                scheduled = event;
            }
            let other = [next, stopping, self.saver.as_ref().and_then(|s| s.due)].into_iter().flatten().min();
            tokio::select! {
                Some((index, value)) = self.links.recv() => {
                    lock(&self.core).link_update(InputLink::ALL[index], value);
                }
                Some(token) = self.released.recv() => lock(&self.core).hold_released(&token),
                Some(input) = self.queue.recv() => {
                    self.queued.fetch_sub(1, Ordering::AcqRel);
                    lock(&self.core).handle(input);
                }
                _ = self.rearm.notified() => {}
                _ = tokio::time::sleep_until(other.unwrap_or(clock)), if other.is_some() => {}
                _ = stopped.changed(), if stopping.is_none() => {
                    stopping = Some(tokio::time::Instant::now() + STOP_GRACE);
                    lock(&self.core).stop_motion();
                }
            }
            // Whatever woke the task, the axis's own time may have come.
            if next.is_some_and(|at| tokio::time::Instant::now() >= at) {
                lock(&self.core).tick();
                scheduled = None;
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
        let token = self.token.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(token) = token {
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
