//! The Zenoh adapter: one task per axis, a thin loop around the sans-IO `Axis`. It turns
//! samples and queries into writes, the wall clock into ticks, and `AxisEvent`s into
//! publications, trace samples and replies, as ../shared/spec/zenoh-api.md requires.
//! One subscriber and one queryable per node (not per axis) take everything addressed to the
//! node's axes and hand it to the axis by name: Zenoh's cost per declaration grows with the
//! declarations already there, and thousands of axes would pay it squared.

use crate::autosave::{SavedAxis, StateStore};
use crate::axis::{Axis, AxisEvent};
use crate::driver::sim::SimAxis;
use crate::driver::soft::InputLink;
use crate::engine::WriteError;
use crate::launch::{AxisPlan, DriverPlan, ValueSpec, ZenohSection};
use std::sync::atomic::Ordering;
use std::time::Duration;
use tokio::time::Instant;
use zenoh::bytes::{Encoding, ZBytes};
use zenoh::key_expr::KeyExpr;
use zenoh::query::Query;
use zenoh::sample::Sample;
use zenoh::{Session, Wait};
use zmotor_bridge::{CalcLink, CalcLinkSpec};
use zmotor_msgs::{
    decode_scalar, encode_cbor, keys, DriverTrace, Field, KeyLayout, PayloadEncoding, StateMarker, Value,
};

pub type Error = Box<dyn std::error::Error + Send + Sync>;

/// Zenoh configuration for a node or a client from the launch file's `[zenoh]` section.
pub fn zenoh_config(section: &ZenohSection) -> Result<zenoh::Config, Error> {
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", &serde_json::to_string(&section.mode)?)?;
    config.insert_json5("listen/endpoints", &serde_json::to_string(&section.listen)?)?;
    config.insert_json5("connect/endpoints", &serde_json::to_string(&section.connect)?)?;
    config.insert_json5("scouting/multicast/enabled", &section.multicast_scouting.to_string())?;
    Ok(config)
}

/// Autosave of a node's axes: where state is kept, and how long a change may wait before it
/// is written (changes within that time are written together).
#[derive(Clone, Debug)]
pub struct AutosaveConfig {
    pub store: StateStore,
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
    ) -> Result<Self, Error> {
        let (stop, stopped) = tokio::sync::watch::channel(false);
        let mut routes = std::collections::HashMap::new();
        let mut axis_tasks = Vec::new();
        let budget = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(PUBLISHER_BUDGET));
        for mut plan in plans {
            let saver = match &autosave {
                Some(config) => Some(Saver::restore(config, &mut plan)?),
                None => None,
            };
            let axis = match plan.driver {
                DriverPlan::Sim(sim) => Axis::new(plan.fields, Box::new(SimAxis::new(sim)), plan.rates, 0.0),
                DriverPlan::Soft => Axis::new_soft(plan.fields, plan.rates, 0.0),
            };
            let f = axis.fields();
            let (link_kinds, keys): (Vec<InputLink>, Vec<String>) = [
                (InputLink::Readback, &f.rdbl),
                (InputLink::RawPosition, &f.rinp),
                (InputLink::Done, &f.dinp),
                (InputLink::Desired, &f.dol),
            ]
            .into_iter()
            .filter(|(_, key)| !key.is_empty())
            .map(|(kind, key)| (kind, key.clone()))
            .unzip();
            let links = KeyFollower::start(&session, keys).await?;
            let mut core = AxisCore {
                session: session.clone(),
                layout: layout.clone(),
                name: plan.name.clone(),
                axis,
                clock: Instant::now(),
                seq: 0,
                waiting: Vec::new(),
                trace: None,
                hot: Vec::new(),
                posted_once: Vec::new(),
                budget: budget.clone(),
                // Boot may have changed the position (RSTM): the file follows what is.
                changed: true,
            };
            // Initialisation posts no monitors, as in EPICS: clients read the initial state with a
            // get once the liveliness token appears. (Publishing it would also cost Zenoh a new
            // resource per field and axis, a start-up growing with the square of the axes.)
            core.axis.drain_events().count();
            let (queue_in, queue) = tokio::sync::mpsc::unbounded_channel();
            let handle = AxisHandle {
                core: std::sync::Arc::new(std::sync::Mutex::new(core)),
                queue: queue_in,
                queued: Default::default(),
                rearm: Default::default(),
            };
            routes.insert(plan.name.clone(), handle.clone());
            axis_tasks.push(AxisTask {
                core: handle.core,
                queue,
                queued: handle.queued,
                rearm: handle.rearm,
                links,
                link_kinds,
                saver,
                token: Some(session.liveliness().declare_token(layout.axis(&plan.name)).await?),
                name: plan.name,
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
    core: std::sync::Arc<std::sync::Mutex<AxisCore>>,
    queue: tokio::sync::mpsc::UnboundedSender<AxisInput>,
    queued: std::sync::Arc<std::sync::atomic::AtomicUsize>,
    /// Tells the task that its next wake-up may have moved.
    rearm: std::sync::Arc<tokio::sync::Notify>,
}

impl AxisHandle {
    fn deliver(&self, input: AxisInput) {
        if self.queued.load(Ordering::Acquire) == 0 {
            let core = match self.core.try_lock() {
                Ok(core) => Some(core),
                Err(std::sync::TryLockError::Poisoned(poisoned)) => Some(poisoned.into_inner()),
                Err(std::sync::TryLockError::WouldBlock) => None,
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

fn lock(core: &std::sync::Mutex<AxisCore>) -> std::sync::MutexGuard<'_, AxisCore> {
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
    async fn declare(session: &Session, layout: &KeyLayout, routes: Routes) -> Result<Self, Error> {
        let routes = std::sync::Arc::new(routes);
        let prefix = format!("{}/", layout.prefix());
        let sim_prefix = format!("{}/", keys::SIM_PREFIX);
        let (r1, p1) = (routes.clone(), prefix.clone());
        let (r2, p2) = (routes.clone(), prefix.clone());
        let (r3, p3) = (routes.clone(), sim_prefix.clone());
        let (r4, p4) = (routes, sim_prefix);
        Ok(Self {
            _writes: session
                .declare_subscriber(format!("{prefix}*/*"))
                .callback(move |sample| {
                    if !is_state(&sample) {
                        route_sample(&r1, &p1, sample, AxisInput::Write);
                    }
                })
                .await?,
            _queries: session
                .declare_queryable(format!("{prefix}**"))
                .callback(move |q| route_query(&r2, &p2, q, AxisInput::Query))
                .await?,
            _sim_writes: session
                .declare_subscriber(keys::sim_key("*", "*"))
                .callback(move |sample| {
                    if !is_state(&sample) {
                        route_sample(&r3, &p3, sample, AxisInput::SimWrite);
                    }
                })
                .await?,
            _sim_queries: session
                .declare_queryable(keys::sim_key("*", "**"))
                .callback(move |q| route_query(&r4, &p4, q, AxisInput::SimQuery))
                .await?,
        })
    }
}

/// `<prefix><axis>/...` goes to that axis, if it is one of ours.
fn route_sample(routes: &Routes, prefix: &str, sample: Sample, wrap: fn(Sample) -> AxisInput) {
    let axis = sample.key_expr().as_str().strip_prefix(prefix).and_then(|rest| rest.split('/').next());
    if let Some(handle) = axis.and_then(|axis| routes.get(axis)) {
        handle.deliver(wrap(sample));
    }
}

/// A query goes to every axis of ours it can concern (one, or all for a wildcard).
fn route_query(routes: &Routes, prefix: &str, query: Query, wrap: fn(Query) -> AxisInput) {
    let chunk = query
        .key_expr()
        .as_str()
        .strip_prefix(prefix)
        .and_then(|rest| rest.split('/').next())
        .unwrap_or("")
        .to_string();
    if !chunk.is_empty() && !chunk.contains(['*', '$']) {
        if let Some(handle) = routes.get(&chunk) {
            handle.deliver(wrap(query));
        }
        return;
    }
    for (axis, handle) in routes.iter() {
        let Ok(all) = KeyExpr::try_from(format!("{prefix}{axis}/**")) else { continue };
        if query.key_expr().intersects(&all) {
            handle.deliver(wrap(query.clone()));
        }
    }
}

/// A confirmed write with `?wait`, answered when the motion has finished.
struct Waiter {
    query: Query,
    field: Field,
}

/// One axis and its Zenoh side, under one lock: whatever reaches the axis (a write, a query, a
/// link update, a tick) is applied and its events published before the lock is released.
/// Publications and replies are sent without awaiting (`wait`), so a Zenoh callback can run this.
struct AxisCore {
    session: Session,
    layout: KeyLayout,
    name: String,
    axis: Axis,
    clock: Instant,
    seq: u64,
    waiting: Vec<Waiter>,
    /// Declared at the first driver command, so idle axes cost no publisher.
    trace: Option<zenoh::pubsub::Publisher<'static>>,
    /// A saved field changed since the task last looked (autosave).
    changed: bool,
    /// Publishers of the fields this axis posts again and again, declared at their second post:
    /// a declared publisher's put costs a fraction of a session put (the key is resolved once).
    hot: Vec<(Field, zenoh::pubsub::Publisher<'static>)>,
    /// Fields posted once so far (with a session put).
    posted_once: Vec<Field>,
    /// Declarations the node may still make (`PUBLISHER_BUDGET`), shared by its axes.
    budget: std::sync::Arc<std::sync::atomic::AtomicUsize>,
}

/// Publishers one node declares at most (fields and traces). Zenoh numbers a session's
/// declarations with 16 bits and remaps them beyond (logging "Remapping unsupported"); 10,000
/// moving axes with 30,000 field publishers went past it, so the budget is kept well inside,
/// with room for every axis's liveliness token and trace. Past it, fields are published with
/// session puts: slower, always correct. (1,000 axes moving back and forth declare about 17,000.)
const PUBLISHER_BUDGET: usize = 20_000;

impl AxisCore {
    fn now(&self) -> f64 {
        self.clock.elapsed().as_secs_f64()
    }

    fn field_key(&self, field: Field) -> KeyExpr<'static> {
        KeyExpr::try_from(self.layout.field(&self.name, field)).expect("axis names are checked at launch")
    }

    fn handle(&mut self, input: AxisInput) {
        match input {
            AxisInput::Write(sample) => self.on_write_sample(sample),
            AxisInput::Query(query) => self.on_query(query),
            AxisInput::SimWrite(sample) => self.on_sim_write(sample),
            AxisInput::SimQuery(query) => self.on_sim_query(query),
        }
        self.publish_events();
    }

    fn tick(&mut self) {
        let now = self.now();
        self.axis.tick(now, false);
        self.publish_events();
    }

    fn link_update(&mut self, link: InputLink, value: f64) {
        let now = self.now();
        self.axis.link_update(now, link, value);
        self.publish_events();
    }

    /// The start of a shutdown: a moving axis is told to stop.
    fn stop_motion(&mut self) {
        if self.axis.fields().dmov == 0 {
            let now = self.now();
            if let Err(e) = self.axis.write(now, Field::STOP, &Value::Int(1)) {
                tracing::warn!(axis = %self.name, "stop at shutdown refused: {e}");
            }
            self.publish_events();
        }
    }

    /// A plain put (the router has dropped state publications).
    fn on_write_sample(&mut self, sample: Sample) {
        let key = sample.key_expr().as_str().to_string();
        let Some(name) = self.layout.field_name(&self.name, &key) else {
            return;
        };
        let encoding = PayloadEncoding::from_mime(&sample.encoding().to_string());
        if let Err(message) = self.apply_write(name, &sample.payload().to_bytes(), encoding) {
            tracing::warn!(axis = %self.name, key, "write refused: {message}");
            self.publish_error(&message);
        }
    }

    /// Decode and apply one write; Err is the plain-words reason it was refused.
    fn apply_write(&mut self, name: &str, payload: &[u8], encoding: PayloadEncoding) -> Result<Field, String> {
        let field = Field::from_name(name).ok_or_else(|| format!("{name}: unknown field"))?;
        let value = zmotor_msgs::decode_write(field.def(), payload, encoding).map_err(|e| e.to_string())?;
        let now = self.now();
        // What was due before this write goes out first, with the completions it answers, so a
        // `?wait` on this write is answered by the end of its own motion only.
        self.axis.settle(now);
        self.publish_events();
        self.axis.write(now, field, &value).map_err(|e: WriteError| e.to_string())?;
        self.changed |= field.autosave().is_some();
        Ok(field)
    }

    fn on_query(&mut self, query: Query) {
        let key = query.key_expr().as_str().to_string();
        match (self.layout.field_name(&self.name, &key), query.payload().map(|p| p.to_bytes().into_owned())) {
            (Some(name), Some(payload)) => {
                let encoding = PayloadEncoding::from_mime(&query.encoding().map(|e| e.to_string()).unwrap_or_default());
                match self.apply_write(name, &payload, encoding) {
                    Err(message) => {
                        tracing::warn!(axis = %self.name, key, "confirmed write refused: {message}");
                        self.publish_error(&message);
                        let _ = query.reply_err(message).encoding(Encoding::TEXT_PLAIN).wait();
                    }
                    Ok(field) if query.parameters().contains_key("wait") && self.axis.fields().dmov == 0 => {
                        self.waiting.push(Waiter { query, field });
                    }
                    Ok(field) if query.parameters().contains_key("wait") => self.reply_completion(&query, field),
                    Ok(field) => self.reply_field(&query, field),
                }
            }
            (Some(name), None) if !name.contains('*') && Field::from_name(name).is_none() => {
                let _ = query.reply_err(format!("{name}: unknown field")).encoding(Encoding::TEXT_PLAIN).wait();
            }
            _ => {
                // A read of one field or of a key expression covering several.
                let selected = query.key_expr().clone();
                for field in zmotor_msgs::Field::all() {
                    if selected.intersects(&self.field_key(field)) {
                        self.reply_field(&query, field);
                    }
                }
            }
        }
    }

    fn reply_field(&self, query: &Query, field: Field) {
        let value = self.axis.record().get(field);
        let _ = query.reply(self.field_key(field), encode_cbor(&value)).encoding(Encoding::APPLICATION_CBOR).wait();
    }

    /// The answer to a `?wait` write: the field, the readback and whether the target was reached.
    fn reply_completion(&self, query: &Query, field: Field) {
        let f = self.axis.fields();
        let reached = f.miss == 0 && f.lvio == 0 && f.sevr < zmotor_msgs::menus::severity::MAJOR;
        let outcome = std::collections::BTreeMap::from([
            (field.name(), self.axis.record().get(field)),
            ("RBV", Value::Float(f.rbv)),
            ("DMOV", Value::Int(f.dmov.into())),
            ("MISS", Value::Int(f.miss.into())),
            ("LVIO", Value::Int(f.lvio.into())),
            ("STAT", Value::Int(f.stat.into())),
            ("SEVR", Value::Int(f.sevr.into())),
            ("reached", Value::Int(reached.into())),
        ]);
        let _ = query.reply(self.field_key(field), encode_cbor(&outcome)).encoding(Encoding::APPLICATION_CBOR).wait();
    }

    fn on_sim_write(&mut self, sample: Sample) {
        let key = sample.key_expr().as_str().to_string();
        let name = key.rsplit('/').next().unwrap_or_default().to_string();
        let encoding = PayloadEncoding::from_mime(&sample.encoding().to_string());
        let value = decode_scalar(&sample.payload().to_bytes(), encoding)
            .map_err(|(enc, e)| format!("{key}: malformed {enc}: {e}"));
        let now = self.now();
        self.axis.tick(now, false);
        let result = value.and_then(|v| match self.axis.simulation() {
            Some(sim) => apply_sim_setting(sim, &name, &v).map_err(|e| format!("{key}: {e}")),
            None => Err(format!("{key}: this axis is not simulated")),
        });
        match result {
            Ok(()) => self.axis.tick(now, true),
            Err(message) => {
                tracing::warn!(axis = %self.name, "{message}");
                self.publish_error(&message);
            }
        }
    }

    fn on_sim_query(&mut self, query: Query) {
        let now = self.now();
        self.axis.tick(now, false);
        let Some(sim) = self.axis.simulation() else {
            return;
        };
        let state = sim.state();
        let config = sim.config().clone();
        let mut entries: Vec<(&str, Vec<u8>)> = vec![("state", encode_cbor(&state))];
        let optional = |x: Option<f64>| Value::Float(x.unwrap_or(f64::NAN));
        for (name, value) in [
            ("position", Value::Float(state.position)),
            ("high_limit", optional(config.high_limit_switch)),
            ("low_limit", optional(config.low_limit_switch)),
            ("home", Value::Float(config.home_switch)),
            ("encoder", Value::Float(config.encoder_counts_per_step.unwrap_or(0.0))),
            ("stall", Value::Int(sim.stalled.into())),
            ("comm_lost", Value::Int(sim.comm_lost.into())),
            ("problem", Value::Int(sim.problem.into())),
            ("fraction", Value::Float(sim.fraction)),
            ("slip", Value::Float(sim.slip)),
            ("servo", Value::Int(config.servo.into())),
        ] {
            entries.push((name, encode_cbor(&value)));
        }
        for (name, payload) in entries {
            let Ok(key) = KeyExpr::try_from(keys::sim_key(&self.name, name)) else {
                continue;
            };
            if query.key_expr().intersects(&key) {
                let _ = query.reply(key, payload).encoding(Encoding::APPLICATION_CBOR).wait();
            }
        }
    }

    fn publish_events(&mut self) {
        let events: Vec<AxisEvent> = self.axis.drain_events().collect();
        let mut traced = None;
        for event in events {
            match event {
                AxisEvent::Post(field, value) => {
                    self.changed |= field.autosave().is_some();
                    self.publish(field, &value)
                }
                AxisEvent::Driver { command, t } => {
                    if self.trace.is_none() {
                        let key = self.layout.driver_cmd(&self.name);
                        self.trace =
                            self.session.declare_publisher(key).encoding(Encoding::APPLICATION_CBOR).wait().ok();
                        // The trace must exist whatever the budget; it counts against it all the same.
                        let _ = self.budget.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1));
                    }
                    let Some(trace_publisher) = &self.trace else { continue };
                    let listening = *traced
                        .get_or_insert_with(|| trace_publisher.matching_status().wait().is_ok_and(|m| m.matching()));
                    if listening {
                        self.seq += 1;
                        let trace = DriverTrace { command, t, seq: self.seq };
                        let _ = trace_publisher.put(encode_cbor(&trace)).wait();
                    }
                }
                AxisEvent::Put { key, value } => {
                    // A directive's put is a command to another node: a plain write, no marker.
                    if let Err(e) = self.session.put(&key, value).encoding(Encoding::TEXT_PLAIN).wait() {
                        tracing::warn!(axis = %self.name, key, "directive put failed: {e}");
                    }
                }
                AxisEvent::Done => {
                    for waiter in std::mem::take(&mut self.waiting) {
                        self.reply_completion(&waiter.query, waiter.field);
                    }
                }
            }
        }
    }

    fn marker(&mut self) -> ZBytes {
        self.seq += 1;
        let f = self.axis.fields();
        ZBytes::from(StateMarker::new(self.seq, f.stat, f.sevr).encode())
    }

    fn publish(&mut self, field: Field, value: &Value) {
        let attachment = self.marker();
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
                        tracing::warn!(axis = %self.name, %field, "cannot declare a publisher: {e}");
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

    fn publish_error(&mut self, message: &str) {
        let attachment = self.marker();
        let key = self.layout.err(&self.name);
        let _ = self.session.put(key, message.to_string()).encoding(Encoding::TEXT_PLAIN).attachment(attachment).wait();
    }
}

/// The task of one axis: the wall clock, link updates, queued inputs, autosave and shutdown.
struct AxisTask {
    core: std::sync::Arc<std::sync::Mutex<AxisCore>>,
    queue: tokio::sync::mpsc::UnboundedReceiver<AxisInput>,
    queued: std::sync::Arc<std::sync::atomic::AtomicUsize>,
    rearm: std::sync::Arc<tokio::sync::Notify>,
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
        let mut stopping: Option<Instant> = None;
        let clock = lock(&self.core).clock;
        loop {
            let next = {
                let core = lock(&self.core);
                // A Soft Channel axis without a timer has nothing to wake for: look again in a minute.
                core.axis.next_wakeup().min(core.now() + 60.0)
            };
            let mut wake = clock + Duration::from_secs_f64(next);
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
                    stopping = Some(Instant::now() + STOP_GRACE);
                    lock(&self.core).stop_motion();
                }
            }
            self.autosave(false).await;
            if stopping.is_some_and(|limit| lock(&self.core).axis.fields().dmov == 1 || Instant::now() >= limit) {
                break;
            }
        }
        if lock(&self.core).axis.fields().dmov == 0 {
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
            if std::mem::take(&mut core.changed) {
                saver.changed(Instant::now());
            }
            (finally || saver.due.is_some_and(|due| Instant::now() >= due)).then(|| SavedAxis::of(core.axis.fields()))
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
    due: Option<Instant>,
}

impl Saver {
    /// Lay the saved state over the plan's fields, and be ready to save the axis.
    fn restore(config: &AutosaveConfig, plan: &mut AxisPlan) -> Result<Self, Error> {
        let saved = config.store.load(&plan.name)?;
        if let Some(saved) = &saved {
            let path = config.store.path(&plan.name);
            saved.restore_into(&mut plan.fields).map_err(|e| format!("{}: {e}", path.display()))?;
            tracing::info!(axis = %plan.name, file = %path.display(), "restored saved state");
        }
        Ok(Self { store: config.store.clone(), delay: config.delay, written: saved.unwrap_or_default(), due: None })
    }

    fn changed(&mut self, now: Instant) {
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

/// Follows keys as EPICS links follow PVs: every update, and the current value asked for once
/// at the start (as a link does when it connects). Any sample is a reading, state or write.
struct KeyFollower {
    values: tokio::sync::mpsc::UnboundedReceiver<(usize, f64)>,
    _subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
}

impl KeyFollower {
    async fn start(session: &Session, keys: Vec<String>) -> Result<Self, Error> {
        let (tx, values) = tokio::sync::mpsc::unbounded_channel();
        let mut subscribers = Vec::new();
        for (index, key) in keys.iter().enumerate() {
            let updates = tx.clone();
            let subscriber = session
                .declare_subscriber(key.clone())
                .callback(move |sample| {
                    if let Some(value) = sample_number(&sample) {
                        let _ = updates.send((index, value));
                    }
                })
                .await?;
            subscribers.push(subscriber);
            let replies = session.get(key.clone()).timeout(Duration::from_secs(5)).await?;
            let tx = tx.clone();
            tokio::spawn(async move {
                while let Ok(reply) = replies.recv_async().await {
                    if let Some(value) = reply.result().ok().and_then(sample_number) {
                        let _ = tx.send((index, value));
                    }
                }
            });
        }
        Ok(Self { values, _subscribers: subscribers })
    }
}

/// The number a sample carries, whatever its encoding.
fn sample_number(sample: &Sample) -> Option<f64> {
    let encoding = PayloadEncoding::from_mime(&sample.encoding().to_string());
    decode_scalar(&sample.payload().to_bytes(), encoding).ok()?.as_f64()
}

/// A calc link: recompute on its inputs, write the result to its output key.
struct CalcTask {
    session: Session,
    link: CalcLink,
    inputs: KeyFollower,
}

impl CalcTask {
    async fn run(&mut self) {
        let keys: Vec<String> = self.link.input_keys().map(str::to_string).collect();
        while let Some((index, value)) = self.inputs.values.recv().await {
            if let Some(result) = self.link.update(&keys[index], value) {
                let output = &self.link.spec().output;
                // A write to the output key, like a calcout's OUT: plain, no state marker.
                if let Err(e) = self.session.put(output, result.to_string()).encoding(Encoding::TEXT_PLAIN).await {
                    tracing::warn!(calc = %self.link.spec().name, output, "output put failed: {e}");
                }
            }
        }
    }
}

/// A value holder (an ao/ai record that only holds a value): keeps the latest number put on
/// its key and answers reads of it.
struct ValueHolder {
    _updates: zenoh::pubsub::Subscriber<()>,
    _reads: zenoh::query::Queryable<()>,
}

impl ValueHolder {
    async fn declare(session: &Session, spec: ValueSpec) -> Result<Self, Error> {
        let value = std::sync::Arc::new(std::sync::Mutex::new(spec.initial));
        let latest = value.clone();
        let updates = session
            .declare_subscriber(spec.key.clone())
            .callback(move |sample| match sample_number(&sample) {
                Some(x) => *latest.lock().unwrap_or_else(|e| e.into_inner()) = x,
                None => tracing::warn!(key = %sample.key_expr(), "value holder: not a number; ignored"),
            })
            .await?;
        let reads = session
            .declare_queryable(spec.key.clone())
            .callback(move |query| {
                let x = *value.lock().unwrap_or_else(|e| e.into_inner());
                let reply = query.reply(query.key_expr().clone(), encode_cbor(&Value::Float(x)));
                // Replies of a callback are sent without waiting: callbacks must not block.
                let _ = zenoh::Wait::wait(reply.encoding(Encoding::APPLICATION_CBOR));
            })
            .await?;
        Ok(Self { _updates: updates, _reads: reads })
    }
}

/// A publication of some node (it carries the state marker), never a write.
fn is_state(sample: &Sample) -> bool {
    sample.attachment().is_some_and(|a| StateMarker::is_marker(&a.to_bytes()))
}

/// The simulator's keys under `sim/<axis>/`: positions in steps, flags as 0/1.
fn apply_sim_setting(sim: &mut SimAxis, name: &str, value: &Value) -> Result<(), String> {
    let number = || {
        value.as_f64().filter(|x| x.is_finite()).ok_or_else(|| format!("a finite number is required, got '{value}'"))
    };
    let switch_position = || match value {
        Value::Text(t) if t.eq_ignore_ascii_case("none") => Ok(None),
        _ => number().map(Some),
    };
    match name {
        "position" => sim.teleport(number()?),
        "high_limit" => sim.set_high_limit_switch(switch_position()?),
        "low_limit" => sim.set_low_limit_switch(switch_position()?),
        "home" => sim.set_home_switch(number()?),
        "encoder" => sim.set_encoder(Some(number()?).filter(|r| *r != 0.0)),
        "stall" => sim.stalled = number()? != 0.0,
        "comm_lost" => sim.comm_lost = number()? != 0.0,
        "problem" => sim.problem = number()? != 0.0,
        "slip" => {
            let f = number()?;
            if !(0.0..=1.0).contains(&f) {
                return Err(format!("slip {f} is outside [0, 1]"));
            }
            sim.slip = f;
        }
        "fraction" => {
            let f = number()?;
            if !(0.0..=2.0).contains(&f) {
                return Err(format!("fraction {f} is outside [0, 2]"));
            }
            sim.fraction = f;
        }
        other => return Err(format!("unknown simulator key '{other}'")),
    }
    Ok(())
}
