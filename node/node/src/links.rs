//! What follows keys besides the axes: input links (as EPICS links follow PVs), calc links and
//! value holders.

use crate::lock;
use crate::writer::Writer;
use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;
use zenoh::bytes::Encoding;
use zenoh::sample::{Sample, SampleKind};
use zenoh::time::TimestampId;
use zenoh::{Session, Wait};
use zmotor_bridge::CalcLink;
use zmotor_deploy::ValueSpec;
use zmotor_msgs::{decode_scalar, encode_cbor, BridgeRecord, Field, KeyLayout, PayloadEncoding, StateMarker, Value};

/// Where a follower's values go, as (the key's index, its value): a calc link's channel, or an
/// axis's inbox (so that a link's value and a write reach the axis in the order they came).
pub(crate) type LinkSink = Arc<dyn Fn(usize, f64) + Send + Sync>;

/// Where one follower wants a key's values: its sink and the key's index there.
type Follower = (LinkSink, usize);

/// Whether two sinks are the same one.
fn same_sink(a: &LinkSink, b: &LinkSink) -> bool {
    std::ptr::addr_eq(Arc::as_ptr(a), Arc::as_ptr(b))
}

/// The node's followers of its own axes' fields. An axis publishes to the network only (other
/// processes, and only when someone there subscribes); a link in this very node that follows
/// one of its fields gets the value from here, in-process.
#[derive(Default)]
pub(crate) struct LocalFollowers {
    layout: KeyLayout,
    by_axis: std::sync::RwLock<HashMap<String, Vec<(Field, Follower)>>>,
    /// How many follow, in all: each post of each axis asks, and mostly none does.
    followers: AtomicUsize,
}

impl LocalFollowers {
    pub(crate) fn new(layout: KeyLayout) -> Self {
        Self { layout, by_axis: Default::default(), followers: AtomicUsize::new(0) }
    }

    /// Follow `key` if it is a field of an axis (of this node or not: cheap to keep).
    fn register(&self, key: &str, follower: Follower) {
        let Some(axis) = self.layout.axis_chunk(key) else { return };
        let Some(field) = self.layout.field_name(axis, key).and_then(Field::from_name) else { return };
        let mut by_axis = self.by_axis.write().unwrap_or_else(|e| e.into_inner());
        by_axis.entry(axis.to_string()).or_default().push((field, follower));
        self.followers.fetch_add(1, Ordering::Release);
    }

    /// Stop following whatever `follower` followed.
    fn unregister(&self, follower: &Follower) {
        let mut by_axis = self.by_axis.write().unwrap_or_else(|e| e.into_inner());
        for followers in by_axis.values_mut() {
            let before = followers.len();
            followers.retain(|(_, (sink, index))| !(same_sink(sink, &follower.0) && *index == follower.1));
            self.followers.fetch_sub(before - followers.len(), Ordering::Release);
        }
    }

    /// A field of `axis` took `value`. Called while `axis` handles an input: a following axis
    /// gets the value before anything `axis` sends after it (a `?wait` reply, say) can lead to a
    /// write of the follower. Returns whether any follower got it.
    pub(crate) fn deliver(&self, axis: &str, field: Field, value: &Value) -> bool {
        if self.followers.load(Ordering::Acquire) == 0 {
            return false;
        }
        let Some(number) = value.as_f64() else { return false };
        // Taken out of the lock: a follower may handle the value at once, and post in turn.
        let sinks: Vec<(LinkSink, usize)> = {
            let by_axis = self.by_axis.read().unwrap_or_else(|e| e.into_inner());
            let Some(followers) = by_axis.get(axis) else { return false };
            followers.iter().filter(|(f, _)| *f == field).map(|(_, follower)| follower.clone()).collect()
        };
        for (sink, index) in &sinks {
            sink(*index, number);
        }
        !sinks.is_empty()
    }
}

/// Fields of this node's own axes followed in-process, as the node posts them (before the
/// network hears them): what a front-end in the node's process follows without a hop through
/// Zenoh. The values go to the callback given, with the index of their key; following ends when
/// this is dropped.
pub struct PostsFollowed {
    local: Arc<LocalFollowers>,
    sink: LinkSink,
    keys: usize,
}

impl PostsFollowed {
    pub(crate) fn new(local: Arc<LocalFollowers>, keys: &[String], sink: LinkSink) -> Self {
        for (index, key) in keys.iter().enumerate() {
            local.register(key, (sink.clone(), index));
        }
        Self { local, sink, keys: keys.len() }
    }
}

impl Drop for PostsFollowed {
    fn drop(&mut self) {
        for index in 0..self.keys {
            self.local.unregister(&(self.sink.clone(), index));
        }
    }
}

/// The keys one task follows, by index, as EPICS links follow PVs: every update, and the
/// current value asked for once when a key is followed (as a link does when it connects). Any
/// sample is a reading, state or write. What a key follows can change at run time.
///
/// A value is either an update (an event: a move, a write) or found (the state a link finds
/// when it connects or its source comes back, as its `Gate` tells): found values go to the
/// `reads` sink, and nothing a lab runs moves on them.
pub(crate) struct Follows {
    session: Session,
    runtime: tokio::runtime::Handle,
    local: Arc<LocalFollowers>,
    updates: LinkSink,
    reads: LinkSink,
    /// Told when the source of a followed key goes (`on_loss`).
    lost: Option<LossSink>,
    followed: Vec<Option<Followed>>,
}

/// Told the index of a followed key whose source is gone.
pub(crate) type LossSink = Arc<dyn Fn(usize) + Send + Sync>;

/// One followed key: its subscriber, the watch on its source, and its gate, also registered
/// with the node's in-process followers (as `follower`) until it is dropped.
struct Followed {
    gate: Arc<Gate>,
    _subscriber: zenoh::pubsub::Subscriber<()>,
    _source: Option<zenoh::pubsub::Subscriber<()>>,
    local: Arc<LocalFollowers>,
    follower: Follower,
}

impl Drop for Followed {
    fn drop(&mut self) {
        self.local.unregister(&self.follower);
        // A read of it still under way delivers nothing: the link follows another key now.
        self.gate.retire();
    }
}

impl Follows {
    /// Nothing followed yet; updates will go to `updates`, values found to `reads`.
    pub(crate) fn new(session: &Session, local: Arc<LocalFollowers>, updates: LinkSink, reads: LinkSink) -> Self {
        Self {
            session: session.clone(),
            runtime: tokio::runtime::Handle::current(),
            local,
            updates,
            reads,
            lost: None,
            followed: Vec::new(),
        }
    }

    /// Also say when the source of a followed key goes (the liveliness token of the axis or
    /// bridge record serving it), as a link's PV disconnects.
    pub(crate) fn on_loss(mut self, lost: LossSink) -> Self {
        self.lost = Some(lost);
        self
    }

    /// Nothing followed yet; the values will arrive on the receiver, as (index, value, how).
    pub(crate) fn to_channel(
        session: &Session,
        local: Arc<LocalFollowers>,
    ) -> (Self, tokio::sync::mpsc::UnboundedReceiver<(usize, f64, Arrival)>) {
        let (tx, values) = tokio::sync::mpsc::unbounded_channel();
        let sink = |how: Arrival| -> LinkSink {
            let tx = tx.clone();
            Arc::new(move |index, value| {
                let _ = tx.send((index, value, how));
            })
        };
        (Self::new(session, local, sink(Arrival::Update), sink(Arrival::Found)), values)
    }

    /// Follow `key` at `index` instead of what was followed there; "" follows nothing.
    pub(crate) fn follow(&mut self, index: usize, key: &str) -> Result<(), zenoh::Error> {
        self.follow_with(index, key, true)
    }

    /// Follow the updates of `key` at `index`, from now on: its value now is not read (a
    /// forward link processes a record at each write, not when it connects).
    pub(crate) fn follow_updates(&mut self, index: usize, key: &str) -> Result<(), zenoh::Error> {
        self.follow_with(index, key, false)
    }

    fn follow_with(&mut self, index: usize, key: &str, read_now: bool) -> Result<(), zenoh::Error> {
        if self.followed.len() <= index {
            self.followed.resize_with(index + 1, || None);
        }
        self.followed[index] = None;
        if key.is_empty() {
            return Ok(());
        }
        // A key followed for its updates only (a forward link's writes) has no state to find.
        let source = read_now.then(|| Source::of(&self.local.layout, key)).flatten();
        let axis = matches!(source, Some(Source::Axis { .. }));
        let gate = Arc::new(Gate::new(index, self.updates.clone(), self.reads.clone(), axis));
        let through = gate.clone();
        let subscriber = self
            .session
            .declare_subscriber(key.to_string())
            .callback(move |sample| {
                if let Some(value) = sample_number(&sample) {
                    through.sample(value, Posted::of(&sample));
                }
            })
            .wait()?;
        let watch = match &source {
            Some(source) => Some(self.watch(index, key, source, gate.clone())?),
            None => None,
        };
        let through = gate.clone();
        let follower: Follower = (Arc::new(move |_, value| through.own_post(value)), index);
        self.local.register(key, follower.clone());
        if read_now {
            let (session, key, gate) = (self.session.clone(), key.to_string(), gate.clone());
            self.runtime.spawn(async move { gate.read(&session, &key).await });
        }
        let local = self.local.clone();
        self.followed[index] = Some(Followed { gate, _subscriber: subscriber, _source: watch, local, follower });
        Ok(())
    }

    /// Watch the source of `key`: when it goes, say so (the gate takes an axis's next value as
    /// found); when it comes back, read the value, as when the link connected. Zenoh tells a
    /// token's key gone only when no token of it remains, and come only when the first comes: a
    /// node restarted before its old token was dropped is told by neither, and is known by its
    /// posts (`Posted`).
    fn watch(
        &self,
        index: usize,
        key: &str,
        source: &Source,
        gate: Arc<Gate>,
    ) -> Result<zenoh::pubsub::Subscriber<()>, zenoh::Error> {
        let (session, runtime, key, lost) =
            (self.session.clone(), self.runtime.clone(), key.to_string(), self.lost.clone());
        self.session
            .liveliness()
            .declare_subscriber(source.tokens())
            .callback(move |token| match token.kind() {
                SampleKind::Delete => {
                    gate.source_gone();
                    if let Some(lost) = &lost {
                        lost(index);
                    }
                }
                SampleKind::Put => {
                    let (session, key, gate) = (session.clone(), key.clone(), gate.clone());
                    runtime.spawn(async move { gate.read(&session, &key).await });
                }
            })
            .wait()
    }
}

/// How a followed value came.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Arrival {
    /// An update: an event at its source.
    Update,
    /// Found: the state a link finds when it connects or its source comes back (see `Gate`).
    Found,
}

/// What serves a followed key, known by its liveliness token.
enum Source {
    /// The axis of an axis's field (`<prefix>/<axis>/<FIELD>`).
    Axis { token: String },
    /// The bridge record of a record's value (`bridge/<record>/VAL`): an ao or a calc.
    Record { name: String },
}

impl Source {
    fn of(layout: &KeyLayout, key: &str) -> Option<Self> {
        if let Some(axis) = layout.axis_chunk(key) {
            return Some(Source::Axis { token: layout.axis(axis) });
        }
        BridgeRecord::of_value_key(key).map(|name| Source::Record { name: name.to_string() })
    }

    /// The liveliness key expression of its tokens.
    fn tokens(&self) -> String {
        match self {
            Source::Axis { token } => token.clone(),
            Source::Record { name } => zmotor_msgs::keys::bridge_key(name, "*"),
        }
    }
}

/// What a sample's state marker says of it: which session posted it as a node's state (its
/// timestamp's id; another one than before is a node that came back), and whether it is a
/// record's value computed from values found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Posted {
    poster: Option<TimestampId>,
    found: bool,
}

impl Posted {
    fn of(sample: &Sample) -> Self {
        let Some(marker) = sample.attachment().and_then(|a| StateMarker::decode(&a.to_bytes())) else {
            return Self::default();
        };
        Self { poster: sample.timestamp().map(|t| *t.get_id()), found: marker.found }
    }
}

/// Where one followed key's values go: updates, or found (`Arrival`). A value a record marks
/// found is found. For an axis's key, also the first value (when the link connects or after the
/// axis's token went) and a post from another session than the axis's before (a node restarted
/// before its old token went, of which Zenoh tells nothing). A read's answer is found, and
/// dropped when a sample came or the source went while it was asked, or the key is followed no
/// more: it would be older than what the link has.
struct Gate {
    index: usize,
    updates: LinkSink,
    reads: LinkSink,
    /// The key is an axis's: its node posts its state, the session it posts from its own.
    axis: bool,
    state: std::sync::Mutex<GateState>,
}

struct GateState {
    /// The next value is found, not an update.
    awaiting: bool,
    /// Samples so far.
    samples: u64,
    /// Times the source went.
    losses: u64,
    /// The session the axis's state came from last (a post's or a read's).
    poster: Option<TimestampId>,
    /// Followed no more.
    retired: bool,
}

/// When a read was asked: its answer is news only if nothing came or went since.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Asked {
    samples: u64,
    losses: u64,
}

impl Gate {
    fn new(index: usize, updates: LinkSink, reads: LinkSink, axis: bool) -> Self {
        let state = GateState { awaiting: axis, samples: 0, losses: 0, poster: None, retired: false };
        Self { index, updates, reads, axis, state: std::sync::Mutex::new(state) }
    }

    /// A sample of the key from the network, and what its marker says (`Posted`).
    fn sample(&self, value: f64, posted: Posted) {
        let found = {
            let mut state = lock(&self.state);
            if state.retired {
                return;
            }
            state.samples += 1;
            let returned =
                self.axis && state.poster.is_some() && posted.poster.is_some_and(|p| Some(p) != state.poster);
            self.note_poster(&mut state, posted);
            std::mem::take(&mut state.awaiting) || returned || posted.found
        };
        let sink = if found { &self.reads } else { &self.updates };
        sink(self.index, value);
    }

    fn note_poster(&self, state: &mut GateState, posted: Posted) {
        if self.axis && posted.poster.is_some() {
            state.poster = posted.poster;
        }
    }

    /// A post of an axis of this very node, handed over in-process: an update always (the
    /// node's own axes do not come and go; their values reach it no other way).
    fn own_post(&self, value: f64) {
        {
            let mut state = lock(&self.state);
            if state.retired {
                return;
            }
            state.samples += 1;
            state.awaiting = false;
        }
        (self.updates)(self.index, value);
    }

    /// The source's token went: a read under way is stale, and an axis's next value is found
    /// (what its node posts when it comes back is the state it found).
    fn source_gone(&self) {
        let mut state = lock(&self.state);
        state.losses += 1;
        state.awaiting |= self.axis;
    }

    /// The link follows another key now: a read of this one still under way delivers nothing.
    fn retire(&self) {
        lock(&self.state).retired = true;
    }

    fn ask(&self) -> Asked {
        let state = lock(&self.state);
        Asked { samples: state.samples, losses: state.losses }
    }

    /// A read's answer, asked at `asked`.
    fn answer(&self, asked: Asked, value: f64, posted: Posted) {
        {
            let mut state = lock(&self.state);
            if state.retired || asked != (Asked { samples: state.samples, losses: state.losses }) {
                return;
            }
            state.awaiting = false;
            self.note_poster(&mut state, posted);
        }
        (self.reads)(self.index, value);
    }

    /// Read `key`'s value now, as a link does when it connects.
    async fn read(&self, session: &Session, key: &str) {
        let asked = self.ask();
        let Ok(replies) = session.get(key).timeout(Duration::from_secs(5)).await else { return };
        while let Ok(reply) = replies.recv_async().await {
            let Ok(sample) = reply.result() else { continue };
            if let Some(value) = sample_number(sample) {
                self.answer(asked, value, Posted::of(sample));
            }
        }
    }
}

/// The number a sample carries, whatever its encoding.
fn sample_number(sample: &Sample) -> Option<f64> {
    let encoding = PayloadEncoding::from_mime(&sample.encoding().to_string());
    decode_scalar(&sample.payload().to_bytes(), encoding).ok()?.as_f64()
}

/// A calc link: recompute on its inputs and the keys it is processed by, write the result to
/// its output key.
pub(crate) struct CalcTask {
    session: Session,
    writer: Writer,
    link: CalcLink,
    /// Its input keys, then the keys it is processed by, followed for as long as the task lives.
    _follows: Follows,
    updates: tokio::sync::mpsc::UnboundedReceiver<(usize, f64, Arrival)>,
    /// The calc record it serves, when its result goes to its own `bridge/<record>/VAL`.
    record: Option<AnsweredValue>,
    /// The record's publications so far (its state markers' `seq`).
    posts: u64,
}

impl CalcTask {
    /// Follow `link`'s inputs (their values now, then their updates) and the keys it is
    /// processed by (their updates). With `serves_record` (no value holder of the node holds its
    /// output), a link whose result is its own record's value (`bridge/<its name>/VAL`: a calc
    /// without OUT) answers reads of it and announces the calc record (`BridgeRecord::Calc`); a
    /// transform's field written to its own key (`bridge/R/X` of `R.X`) answers reads of it.
    pub(crate) fn start(
        session: &Session,
        local: Arc<LocalFollowers>,
        writer: Writer,
        link: CalcLink,
        serves_record: bool,
    ) -> Result<Self, zenoh::Error> {
        let (output, name) = (&link.spec().output, link.spec().name.as_str());
        // A transform's field `R.X` written to its own key `bridge/R/X` answers reads there too
        // (a soft motor's RDBL on it), as a calc's own VAL does; only the calc is announced.
        let own_field =
            name.split_once('.').is_some_and(|(record, field)| *output == zmotor_msgs::keys::bridge_key(record, field));
        let record = match serves_record && BridgeRecord::of_value_key(output) == Some(name) {
            true => Some(AnsweredValue::declare(session, output, Arc::default(), Some(BridgeRecord::Calc))?),
            false if serves_record && own_field => Some(AnsweredValue::declare(session, output, Arc::default(), None)?),
            false => None,
        };
        let (mut follows, updates) = Follows::to_channel(session, local);
        let inputs = link.input_keys().count();
        for (index, key) in link.input_keys().enumerate() {
            follows.follow(index, key)?;
        }
        for (index, key) in link.processing_keys().enumerate() {
            follows.follow_updates(inputs + index, key)?;
        }
        let link = if record.is_some() { link.serving_its_record() } else { link };
        let mut task = Self { session: session.clone(), writer, link, _follows: follows, updates, record, posts: 0 };
        // A calc record of constants only is processed by nothing here, where EPICS's readers
        // process it through their PP links: its value is served from the start. (Only as a
        // record's value: a write elsewhere, to a motor, is never made unasked.)
        if task.record.is_some() {
            if let Some(result) = task.link.constant_result() {
                task.write(result, Arrival::Found);
            }
        }
        Ok(task)
    }

    /// Write a result to the output key: a plain write, like a calcout's OUT; or, as the
    /// record's own value, kept for reads and published as its state, marked found when it was
    /// computed from a value found (its followers then move nothing on it either).
    fn write(&mut self, result: f64, from: Arrival) {
        let output = &self.link.spec().output;
        let Some(record) = &self.record else { return self.writer.put(output, result.to_string()) };
        // Kept before it is published: a read answered meanwhile has it, not the one before.
        record.set(result);
        self.posts += 1;
        let marker = StateMarker::new(self.posts, 0, 0).with_found(from == Arrival::Found);
        self.writer.put_state(output, result.to_string(), &marker);
    }

    /// Process on each CP input's update and each update of a key it is processed by, its NPP
    /// inputs read then; the updates that come meanwhile wait, in order.
    pub(crate) async fn run(&mut self) {
        let inputs: Vec<String> = self.link.input_keys().map(str::to_string).collect();
        let processing: Vec<String> = self.link.processing_keys().map(str::to_string).collect();
        while let Some((index, value, arrival)) = self.updates.recv().await {
            // The key whose value processes the link: its inputs there have that value, newer
            // than any read of it could be.
            let fresh = match index.checked_sub(inputs.len()) {
                None => inputs[index].as_str(),
                Some(index) => processing[index].as_str(),
            };
            let process = match (arrival, index < inputs.len()) {
                (Arrival::Found, _) => self.link.found(fresh, value),
                (Arrival::Update, true) => self.link.update(fresh, value),
                (Arrival::Update, false) => {
                    self.link.processed_by(fresh, value);
                    true
                }
            };
            let fresh = Some(fresh);
            if !process {
                continue;
            }
            let read = self.read_npp_inputs(fresh).await;
            if let Some(result) = self.link.process_with(&read) {
                self.write(result, arrival);
            }
        }
    }

    /// The NPP inputs' values now, read together, but those on the key `fresh` whose update
    /// processes the link (an unanswered one left out: the link keeps the value it last
    /// followed).
    async fn read_npp_inputs(&self, fresh: Option<&str>) -> Vec<(usize, f64)> {
        let mut reads = tokio::task::JoinSet::new();
        for (index, key) in self.link.read_at_processing().filter(|(_, key)| Some(*key) != fresh) {
            let (session, key) = (self.session.clone(), key.to_string());
            reads.spawn(async move { (index, read_number(&session, &key).await) });
        }
        let mut read = Vec::new();
        while let Some(done) = reads.join_next().await {
            if let Ok((index, Some(value))) = done {
                read.push((index, value));
            }
        }
        read
    }
}

/// How long a calc link waits for an input read at processing.
const READ_PATIENCE: Duration = Duration::from_secs(2);

/// A key's value now, if anything answers.
async fn read_number(session: &Session, key: &str) -> Option<f64> {
    let replies = session.get(key).timeout(READ_PATIENCE).await.ok()?;
    let mut value = None;
    while let Ok(reply) = replies.recv_async().await {
        value = value.or_else(|| reply.result().ok().and_then(sample_number));
    }
    value
}

/// A value holder (an ao/ai record that only holds a value): keeps the latest number put on
/// its key and answers reads of it; on a bridge record's key (`bridge/<record>/VAL`) it is that
/// ao record, announced by its token.
pub(crate) struct ValueHolder {
    _updates: zenoh::pubsub::Subscriber<()>,
    _value: AnsweredValue,
}

impl ValueHolder {
    pub(crate) async fn declare(session: &Session, spec: ValueSpec) -> Result<Self, zenoh::Error> {
        let latest = Arc::new(std::sync::Mutex::new(Some(spec.initial)));
        let held = latest.clone();
        // Following writes before the record is announced: none is missed once it is seen.
        let updates = session
            .declare_subscriber(spec.key.clone())
            .callback(move |sample| match sample_number(&sample) {
                Some(x) => *lock(&held) = Some(x),
                None => tracing::warn!(key = %sample.key_expr(), "value holder: not a number; ignored"),
            })
            .await?;
        let value = AnsweredValue::declare(session, &spec.key, latest, Some(BridgeRecord::Value))?;
        Ok(Self { _updates: updates, _value: value })
    }
}

/// A value answered to reads of its key (none before it has one: a calc not yet processed),
/// and the token of the bridge record it is, when its key is one's (`BridgeRecord`).
struct AnsweredValue {
    latest: Arc<std::sync::Mutex<Option<f64>>>,
    _reads: zenoh::query::Queryable<()>,
    _token: Option<zenoh::liveliness::LivelinessToken>,
}

impl AnsweredValue {
    fn declare(
        session: &Session,
        key: &str,
        latest: Arc<std::sync::Mutex<Option<f64>>>,
        record: Option<BridgeRecord>,
    ) -> Result<Self, zenoh::Error> {
        let value = latest.clone();
        let reads = session
            .declare_queryable(key.to_string())
            .callback(move |query| {
                let Some(x) = *lock(&value) else { return };
                let reply = query.reply(query.key_expr().clone(), encode_cbor(&Value::Float(x)));
                // Replies of a callback are sent without waiting: callbacks must not block.
                let _ = reply.encoding(Encoding::APPLICATION_CBOR).wait();
            })
            .wait()?;
        // Declared once reads are answered: a front-end that sees the token reads the value.
        let token = match record.zip(BridgeRecord::of_value_key(key)) {
            Some((kind, name)) => Some(session.liveliness().declare_token(kind.token(name)).wait()?),
            None => None,
        };
        Ok(Self { latest, _reads: reads, _token: token })
    }

    fn set(&self, x: f64) {
        *lock(&self.latest) = Some(x);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use Arrival::{Found, Update};

    /// What a gate delivered, as (how, value).
    type Seen = Arc<std::sync::Mutex<Vec<(Arrival, f64)>>>;

    /// A gate (of an axis's key or not) whose deliveries are recorded.
    fn recorded(axis: bool) -> (Gate, Seen) {
        let seen = Seen::default();
        let sink = |how: Arrival| -> LinkSink {
            let seen = seen.clone();
            Arc::new(move |_, value| seen.lock().unwrap().push((how, value)))
        };
        (Gate::new(0, sink(Update), sink(Found), axis), seen)
    }

    fn taken(seen: &Seen) -> Vec<(Arrival, f64)> {
        std::mem::take(&mut *seen.lock().unwrap())
    }

    fn by(poster: TimestampId) -> Posted {
        Posted { poster: Some(poster), found: false }
    }

    #[test]
    fn an_axis_keys_first_sample_is_found_then_each_is_an_update() {
        let (gate, seen) = recorded(true);
        gate.sample(1.0, Posted::default());
        gate.sample(2.0, Posted::default());
        assert_eq!(taken(&seen), [(Found, 1.0), (Update, 2.0)]);
        let (gate, seen) = recorded(false);
        gate.sample(1.0, Posted::default());
        assert_eq!(taken(&seen), [(Update, 1.0)], "a record's first result may be an event");
    }

    #[test]
    fn a_read_answers_found_unless_a_sample_or_a_loss_came_while_it_was_asked() {
        let (gate, seen) = recorded(true);
        let asked = gate.ask();
        gate.answer(asked, 1.0, Posted::default());
        gate.sample(2.0, Posted::default());
        assert_eq!(taken(&seen), [(Found, 1.0), (Update, 2.0)], "the answer ends the wait");
        let asked = gate.ask();
        gate.sample(3.0, Posted::default());
        gate.answer(asked, 2.0, Posted::default());
        assert_eq!(taken(&seen), [(Update, 3.0)], "an answer older than a sample is dropped");
        let asked = gate.ask();
        gate.source_gone();
        gate.answer(asked, 3.0, Posted::default());
        gate.sample(4.0, Posted::default());
        assert_eq!(taken(&seen), [(Found, 4.0)], "an answer from before the loss neither counts nor ends the wait");
    }

    #[test]
    fn after_an_axis_goes_its_first_value_is_found_and_a_records_is_as_it_is_marked() {
        let (gate, seen) = recorded(true);
        gate.source_gone();
        gate.sample(1.0, Posted::default());
        gate.sample(2.0, Posted::default());
        assert_eq!(taken(&seen), [(Found, 1.0), (Update, 2.0)]);
        let (gate, seen) = recorded(false);
        gate.source_gone();
        gate.sample(1.0, Posted::default());
        gate.sample(2.0, Posted { poster: None, found: true });
        assert_eq!(taken(&seen), [(Update, 1.0), (Found, 2.0)], "an ao's writes, a calc's marked values");
    }

    #[test]
    fn an_axis_post_from_another_session_than_its_state_before_is_found() {
        let (gate, seen) = recorded(true);
        let (first, second, third) = (TimestampId::rand(), TimestampId::rand(), TimestampId::rand());
        gate.answer(gate.ask(), 0.0, by(first));
        gate.sample(1.0, by(first));
        gate.sample(2.0, Posted::default());
        gate.sample(3.0, by(second));
        gate.sample(4.0, by(second));
        assert_eq!(taken(&seen), [(Found, 0.0), (Update, 1.0), (Update, 2.0), (Found, 3.0), (Update, 4.0)]);
        gate.answer(gate.ask(), 5.0, by(third));
        gate.sample(6.0, by(third));
        assert_eq!(taken(&seen), [(Found, 5.0), (Update, 6.0)], "a read tells the session too");
        let (gate, seen) = recorded(false);
        gate.sample(1.0, by(first));
        gate.sample(2.0, by(second));
        assert_eq!(taken(&seen), [(Update, 1.0), (Update, 2.0)], "a record marks what it found itself");
    }

    #[test]
    fn the_nodes_own_posts_are_updates_and_a_retired_gate_delivers_nothing() {
        let (gate, seen) = recorded(true);
        gate.own_post(1.0);
        gate.sample(2.0, Posted::default());
        assert_eq!(taken(&seen), [(Update, 1.0), (Update, 2.0)]);
        let asked = gate.ask();
        gate.retire();
        gate.answer(asked, 3.0, Posted::default());
        gate.sample(4.0, Posted::default());
        gate.own_post(5.0);
        assert!(taken(&seen).is_empty());
    }
}
