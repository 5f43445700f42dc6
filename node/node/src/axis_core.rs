//! One axis and its Zenoh side: whatever reaches the axis (a write, a query, a link update, a
//! tick) is applied to its `AxisService` and what the service hands back is sent before the
//! next input is taken. It only moves bytes: it decodes the key and encoding, calls the
//! service, and sends publications, replies, puts and traces. Everything is sent without
//! awaiting (`wait`), so a Zenoh callback can run it.

use crate::controllers::ControllerPort;
use crate::demand::FieldDemand;
use crate::event_posts::{Destination, EventOutbox, EventPost};
use crate::holds::Holds;
use crate::input::{AxisInput, Deliver};
use crate::links::{Follows, LocalFollowers};
use crate::lock;
use crate::refusal::{self, refuse};
use crate::streamed::{Congestion, KeyWork, Micros, StreamLog, Streamed};
use crate::ticker::AxisClock;
use crate::writer::Writer;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use tokio::sync::Notify;
use zenoh::bytes::{Encoding, ZBytes};
use zenoh::key_expr::KeyExpr;
use zenoh::query::Query;
use zenoh::sample::Locality;
use zenoh::time::Timestamp;
use zenoh::{Session, Wait};
use zmotor_core::{AxisService, Delivery, Instant, Reply, RequestError, ServiceOutput, WriteRequest};
use zmotor_inbox::{Handler, Inbox};
use zmotor_msgs::{
    encode_cbor, excerpt, keys, Attached, Field, KeyLayout, PayloadEncoding, Readback, RefusalKind, StateMarker, Value,
};

/// How soon an axis holding samples back looks again whether it may send them (an axis polled
/// at 100 Hz or faster sends them first at its next poll; a slower one takes a few ticks that
/// change nothing).
const HELD_RETRY: std::time::Duration = std::time::Duration::from_millis(10);

/// Which way a state sample goes (`AxisCore::way`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Way {
    /// Straight to the network, droppable.
    Stream,
    /// Held back in the stream log until the axis's posts waiting in the event sender are sent.
    HoldBack,
    /// Through the event sender, which never drops.
    Event,
}

impl Way {
    /// The way of a post of `delivery`, as `AxisCore::way` explains, while a link `congested`
    /// lately or not, and its axis has posts `waiting` in the event sender or not.
    fn of(delivery: Delivery, congested: bool, waiting: bool) -> Way {
        match delivery {
            Delivery::Stream if !congested && !waiting => Way::Stream,
            Delivery::Stream if !congested => Way::HoldBack,
            _ => Way::Event,
        }
    }
}

/// The state marker and timestamp a reply of an axis's values carries.
struct AnswerState {
    attachment: Vec<u8>,
    stamp: Timestamp,
}

/// Whether a node of `axes` axes has them declare ahead of their first motions the publishers of
/// the fields every motion posts (`Field::posted_by_every_motion`, `AxisCore::declare_ahead`): when
/// they all fit the budget, with room for a trace and a bundle each. (Else the axes declare as
/// they post: a first motion then pays Zenoh's first match of each key.)
pub(crate) fn declares_ahead(axes: usize) -> bool {
    let per_axis = Field::all().filter(|f| f.posted_by_every_motion()).count();
    axes * (per_axis + 2) <= PUBLISHER_BUDGET
}

/// Publishers one node declares at most (fields and traces). Zenoh numbers a session's
/// declarations with 16 bits and remaps them beyond (logging "Remapping unsupported"); 10,000
/// moving axes with 30,000 field publishers went past it, so the budget is kept well inside,
/// with room for every axis's liveliness token and trace. Past it, fields are published with
/// session puts: slower, always correct. (1,000 axes moving back and forth declare about 17,000.)
pub(crate) const PUBLISHER_BUDGET: usize = 20_000;

/// An axis behind its inbox: inputs from any thread, handled one at a time, in order.
pub(crate) type AxisInbox = Inbox<AxisCore, AxisInput>;

impl Deliver for AxisInbox {
    fn deliver(&self, input: AxisInput) {
        Inbox::deliver(self, input);
    }
}

/// Where an axis's input links (RDBL, RINP, DINP, DOL) deliver their values: straight into its
/// inbox, from the thread that received the value, so that a value is handled before a write
/// that came after it (a soft motor's DINP "done" before the next move's write). The first
/// values, asked for when the links connect, may come before the inbox exists: they wait for
/// it, in order.
#[derive(Default)]
pub(crate) struct LinkInbox {
    state: std::sync::Mutex<LinkState>,
}

enum LinkState {
    Waiting(Vec<AxisInput>),
    Attached(std::sync::Weak<AxisInbox>),
}

impl Default for LinkState {
    fn default() -> Self {
        LinkState::Waiting(Vec::new())
    }
}

impl LinkInbox {
    /// The value of link number `index` (`InputLink` order).
    pub(crate) fn deliver(&self, index: usize, value: f64) {
        self.pass(AxisInput::LinkUpdate(zmotor_core::InputLink::ALL[index], value));
    }

    /// The value of link number `index` found (read when it connected or its source came back,
    /// or what the `Gate` in links.rs takes as found).
    pub(crate) fn read(&self, index: usize, value: f64) {
        self.pass(AxisInput::LinkRead(zmotor_core::InputLink::ALL[index], value));
    }

    /// The source of link number `index` is gone.
    pub(crate) fn lost(&self, index: usize) {
        self.pass(AxisInput::LinkLost(zmotor_core::InputLink::ALL[index]));
    }

    fn pass(&self, input: AxisInput) {
        let inbox = match &mut *lock(&self.state) {
            LinkState::Waiting(waiting) => return waiting.push(input),
            LinkState::Attached(inbox) => inbox.clone(),
        };
        if let Some(inbox) = inbox.upgrade() {
            inbox.deliver(input);
        }
    }

    /// The inbox exists: what waited goes in first (values arriving meanwhile wait behind it).
    pub(crate) fn attach(&self, inbox: &Arc<AxisInbox>) {
        loop {
            let waiting = {
                let mut state = lock(&self.state);
                match &mut *state {
                    LinkState::Waiting(waiting) if !waiting.is_empty() => std::mem::take(waiting),
                    _ => {
                        *state = LinkState::Attached(Arc::downgrade(inbox));
                        return;
                    }
                }
            };
            for input in waiting {
                inbox.deliver(input);
            }
        }
    }
}

/// What every axis of a node shares.
#[derive(Clone)]
pub(crate) struct NodeSide {
    pub(crate) session: Session,
    pub(crate) layout: KeyLayout,
    /// The node's plain writes to keys.
    pub(crate) writer: Writer,
    /// Where posts that must arrive go (`Delivery::Event`).
    pub(crate) events: EventOutbox,
    /// When a droppable put last found a link congested.
    pub(crate) congestion: Arc<Congestion>,
    /// When an axis last did slow work for a new key.
    pub(crate) key_work: Arc<KeyWork>,
    /// Links of this node that follow its axes' fields.
    pub(crate) followers: Arc<LocalFollowers>,
    /// Which fields anyone on the network subscribes to.
    pub(crate) demand: Arc<FieldDemand>,
    /// Declarations the node may still make (`PUBLISHER_BUDGET`).
    pub(crate) budget: Arc<AtomicUsize>,
    /// Whether confirmed writes are taken on write keys only (`NodeContents::guarded`).
    pub(crate) guarded: bool,
    /// The origin of the axes' clocks.
    pub(crate) clock: tokio::time::Instant,
}

/// One axis's service and its Zenoh side.
pub(crate) struct AxisCore {
    pub(crate) service: AxisService<Query>,
    node: NodeSide,
    /// The controller behind the axis, if it has one: its driver commands go there.
    controller: Option<ControllerPort>,
    /// The keys this axis's input links follow, by `InputLink` index.
    follows: Follows,
    /// The liveliness tokens its held motions depend on.
    holds: Holds,
    /// Declared at the first driver command, so idle axes cost no publisher.
    trace: Option<zenoh::pubsub::Publisher<'static>>,
    /// The readback bundle's publisher, declared at its first sample.
    readback: Option<zenoh::pubsub::Publisher<'static>>,
    /// Publishers of the fields this axis posts again and again, declared at their second post:
    /// a declared publisher's put costs a fraction of a session put (the key is resolved once).
    hot: Vec<(Field, zenoh::pubsub::Publisher<'static>)>,
    /// Fields posted at least once (the first post of each has Zenoh match a new key).
    posted_once: Vec<Field>,
    /// This axis's posts handed to `NodeSide::events` and not sent yet: while there are any, its
    /// stream posts queue behind them, or are held back once the link is no longer congested
    /// (an axis's posts arrive in order).
    events_waiting: Arc<AtomicUsize>,
    /// What it sent the droppable way since its last event post, and what it holds back.
    stream_log: StreamLog,
    /// Where the axis's deadlines go: its ticks come from there.
    clock: Arc<AxisClock>,
    /// The clock as read when this input's last post was handed on, while nothing else ran
    /// since: the next post's start. (A reading per post instead of two or three: at 600,000
    /// posts a second the readings were 6 % of the node.)
    reading: Option<(std::time::Instant, u64)>,
    /// When the axis last posted (its start before): the time of the values a read answers.
    last_stamp: Timestamp,
    /// A field autosave keeps changed since the task last looked.
    pub(crate) unsaved: Arc<AtomicBool>,
    /// Wakes the axis's task when `unsaved` is set.
    pub(crate) save_due: Arc<Notify>,
}

impl AxisCore {
    pub(crate) fn new(
        service: AxisService<Query>,
        node: NodeSide,
        controller: Option<ControllerPort>,
        follows: Follows,
        holds: Holds,
        clock: Arc<AxisClock>,
    ) -> Self {
        let last_stamp = node.session.new_timestamp();
        Self {
            service,
            node,
            controller,
            follows,
            holds,
            trace: None,
            readback: None,
            hot: Vec::new(),
            posted_once: Vec::new(),
            events_waiting: Arc::default(),
            stream_log: StreamLog::default(),
            clock,
            reading: None,
            last_stamp,
            unsaved: Arc::default(),
            save_due: Arc::default(),
        }
    }

    /// Declare the publishers of the fields every motion posts (`declares_ahead`), so that no
    /// key is new to Zenoh at the axis's first motion.
    pub(crate) fn declare_ahead(&mut self) {
        for field in Field::all().filter(|f| f.posted_by_every_motion()) {
            self.declare_publisher(field);
        }
    }

    /// Hand the axis's next deadlines to its clock.
    pub(crate) fn schedule_ticks(&self) {
        let mut poll = self.service.poll_timeout();
        if self.stream_log.holds() {
            // Looks again soon for its held samples' turn (a tick with nothing due changes nothing).
            let retry = self.now() + HELD_RETRY;
            poll = Some(poll.map_or(retry, |poll| poll.min(retry)));
        }
        self.clock.schedule(poll, self.service.event_timeout());
    }

    /// The axis's clock.
    pub(crate) fn now(&self) -> Instant {
        Instant::after(self.node.clock.elapsed())
    }

    fn name(&self) -> &str {
        self.service.name()
    }

    fn field_key(&self, field: Field) -> KeyExpr<'static> {
        KeyExpr::try_from(self.node.layout.field(self.name(), field)).expect("axis names are checked at launch")
    }

    fn on_query(&mut self, now: Instant, query: Query) {
        let layout = &self.node.layout;
        let key = query.key_expr().as_str();
        let readback =
            KeyExpr::try_from(layout.readback(self.service.name())).expect("axis names are checked at launch");
        if query.key_expr().intersects(&readback) {
            return self.reply_readback(&query, readback);
        }
        let written = layout.written_field_name(self.service.name(), key);
        let name = written.or_else(|| layout.field_name(self.service.name(), key)).map(str::to_string);
        match (name, query.payload().map(|p| p.to_bytes().into_owned())) {
            (Some(name), Some(_)) if self.node.guarded && written.is_none() => {
                // Here a query on a field key is a read: the access rules let readers make it.
                let message = format!(
                    "{key}: this node is under access control; a confirmed write goes to {}/@write/{name}",
                    layout.axis(self.service.name())
                );
                refuse(&query, RefusalKind::WriteKeyRequired, message);
            }
            (Some(name), Some(payload)) => {
                let encoding = PayloadEncoding::from_mime(&query.encoding().map(|e| e.to_string()).unwrap_or_default());
                let wait = query.parameters().contains_key(keys::WAIT_PARAMETER);
                let hold = query.attachment().and_then(|a| Attached::read(&a.to_bytes()).hold());
                let request = WriteRequest::new(&name, &payload, encoding).held(hold);
                self.service.write(now, request, wait, query);
            }
            (Some(name), None) if !name.contains('*') => self.service.read(&name, query),
            (None, Some(_)) => {
                // A write names one field (`<prefix>/<axis>/<FIELD>`); the axis's key, or one
                // below a field, names none: refused, not read as a selection of no field.
                let refusal = RequestError::UnknownField(excerpt(key));
                refuse(&query, refusal.kind(), refusal.to_string());
            }
            _ => {
                // A read of a key expression that may cover several fields.
                let selected = query.key_expr().clone();
                let keys: Vec<KeyExpr<'static>> = Field::all().map(|f| self.field_key(f)).collect();
                self.service.read_selected(|f| selected.intersects(&keys[f as usize]), query);
            }
        }
    }

    /// The readback bundle as it is now; a write to it is refused (it is read-only).
    fn reply_readback(&self, query: &Query, key: KeyExpr<'static>) {
        if query.payload().is_some() {
            let message = format!("{}: the readback bundle is read-only", query.key_expr());
            return refuse(query, RefusalKind::ReadOnly, message);
        }
        let bundle = Readback::encode(self.service.fields(), self.service.last_seq());
        let state = self.state_now(self.last_stamp);
        let reply = query.reply(key, bundle).encoding(Encoding::APPLICATION_CBOR);
        let _ = reply.attachment(state.attachment).timestamp(state.stamp).wait();
    }

    fn on_sim_query(&mut self, now: Instant, query: Query) {
        // With a payload, a confirmed write of one setting (the router refused wildcards); under
        // access control readers may query, so there a setting is written by a put only.
        if query.payload().is_some() && self.node.guarded {
            let message = format!(
                "{}: this node is under access control; a simulator setting is written by a put",
                query.key_expr()
            );
            return refuse(&query, RefusalKind::WriteKeyRequired, message);
        }
        if let Some(payload) = query.payload().map(|p| p.to_bytes().into_owned()) {
            let prefix = keys::sim_key(self.name(), "");
            let name = query.key_expr().as_str().strip_prefix(&prefix).unwrap_or_default().to_string();
            let encoding = PayloadEncoding::from_mime(&query.encoding().map(|e| e.to_string()).unwrap_or_default());
            return self.service.sim_write_confirmed(now, &name, &payload, encoding, query);
        }
        let selected = query.key_expr().clone();
        let axis = self.name().to_string();
        let selects =
            |name: &str| KeyExpr::try_from(keys::sim_key(&axis, name)).is_ok_and(|key| selected.intersects(&key));
        self.service.sim_read(now, selects, query);
    }

    /// Send everything the service has for the network, at `now`.
    fn flush(&mut self, now: Instant) {
        let mut traced = None;
        // The posts of one input share the time it was handled: when the status they come
        // from was read (a subscriber's latency is its arrival less this).
        let mut stamp = None;
        self.reading = None;
        while let Some(output) = self.service.poll_output() {
            if !matches!(
                output,
                ServiceOutput::Publish { .. } | ServiceOutput::Readback { .. } | ServiceOutput::Refusal { .. }
            ) {
                // It may take time (a controller's command, a trace, a write): the next post
                // reads the clock afresh.
                self.reading = None;
            }
            match output {
                ServiceOutput::Publish { field, value, marker, delivery } => {
                    let stamp = *stamp.get_or_insert_with(|| self.node.session.new_timestamp());
                    self.publish(field, &value, &marker, stamp, delivery, now);
                }
                ServiceOutput::Readback { marker, delivery } if self.node.demand.readback_wanted(delivery, now) => {
                    let stamp = *stamp.get_or_insert_with(|| self.node.session.new_timestamp());
                    self.publish_readback(&marker, stamp, delivery);
                }
                ServiceOutput::Readback { .. } => {}
                ServiceOutput::Refusal { kind, message, marker } => {
                    let stamp = *stamp.get_or_insert_with(|| self.node.session.new_timestamp());
                    if let Ok(key) = KeyExpr::try_from(self.node.layout.err(self.name())) {
                        let payload = message.into_bytes();
                        self.post_event(key, payload, refusal::encoding(kind), &marker, stamp, false);
                    }
                }
                ServiceOutput::Reply(answer) => {
                    self.reply(&answer.to, answer.reply, stamp.unwrap_or(self.last_stamp));
                }
                ServiceOutput::DriverCommand { command, at } => {
                    if let Some(controller) = &self.controller {
                        controller.send(command.clone());
                    }
                    // Nobody traces any axis: no publisher (a declaration is matched against
                    // every key, and a thousand axes' first moves would pay it for nothing).
                    if !self.node.demand.traces_wanted(now) {
                        continue;
                    }
                    let trace_publisher = self.trace_publisher();
                    let listening = *traced.get_or_insert_with(|| {
                        trace_publisher.is_some_and(|p| p.matching_status().wait().is_ok_and(|m| m.matching()))
                    });
                    if listening {
                        let trace = self.service.stamp_trace(command, at);
                        // Marked and stamped as every post of the node: no follower takes it
                        // for a write.
                        let state = self.state_now(*stamp.get_or_insert_with(|| self.node.session.new_timestamp()));
                        if let Some(publisher) = &self.trace {
                            let put = publisher.put(encode_cbor(&trace)).attachment(state.attachment);
                            let _ = put.timestamp(state.stamp).wait();
                        }
                    }
                }
                // A link's or directive's put is a command: a plain write, no marker.
                ServiceOutput::Put { key, value } => self.node.writer.put(&key, value),
                ServiceOutput::WatchHold { token } => self.holds.watch(&token),
                ServiceOutput::ForgetHold { token } => self.holds.forget(&token),
                ServiceOutput::Follow { link, key } => {
                    if let Err(e) = self.follows.follow(link as usize, &key) {
                        tracing::error!(axis = %self.name(), key, "cannot follow the link: {e}");
                    }
                }
            }
        }
        if let Some(stamp) = stamp {
            self.last_stamp = stamp;
        }
        self.reading = None;
    }

    /// Which way a post goes. A stream post goes straight to the network, droppable, while no
    /// link was seen congested lately and its axis has no post waiting in the event sender. On a
    /// congested link, droppable puts would take each batch that frees before a blocking one
    /// (which Zenoh, past five seconds, takes for a dead link and closes); so then every post
    /// goes the events' way, a waiting stream sample giving way to its key's next. Once the
    /// congestion has passed, a stream post of an axis whose earlier posts still wait is held
    /// back until they are sent: the sender's queue then empties.
    fn way(&self, delivery: Delivery, now: Micros) -> Way {
        let congested = self.node.congestion.recent_at(now);
        Way::of(delivery, congested, self.events_waiting.load(Ordering::Acquire) > 0)
    }

    /// Hand a post that must arrive to the node's event sender: an event or a message, or a
    /// stream sample that queues behind them (`replaceable` by its key's next). First, if the
    /// network may have dropped some of the axis's stream samples since its last event post, or
    /// some are held back, the last value of each of their keys, as it was made.
    fn post_event(
        &mut self,
        key: KeyExpr<'static>,
        payload: Vec<u8>,
        encoding: Encoding,
        marker: &StateMarker,
        stamp: Timestamp,
        replaceable: bool,
    ) {
        let mut reading = Some(self.clock_reading());
        let unsure = self.stream_log.take_unsure(&self.node.congestion);
        let resent = unsure.into_iter().filter_map(|(sample, marker, stamp)| {
            let key = self.sample_key(&sample)?;
            Some((key, sample.into_payload(), Encoding::APPLICATION_CBOR, marker, stamp, true))
        });
        let this = (key, payload, encoding, marker.clone(), stamp, replaceable);
        for (key, payload, encoding, marker, stamp, replaceable) in resent.collect::<Vec<_>>().into_iter().chain([this])
        {
            let (attachment, stamp) = (Some(marker.encode()), Some(stamp));
            let destination = Destination::Network(Locality::Remote);
            let waiting = self.events_waiting.clone();
            let post = EventPost { key, payload, encoding, attachment, stamp, destination, replaceable, waiting };
            reading = self.node.events.post_at(post, reading.unwrap_or_else(std::time::Instant::now));
        }
        if let Some(at) = reading {
            self.keep_reading(at);
        }
    }

    /// Keep `at`, the clock as just read, for the next post.
    fn keep_reading(&mut self, at: std::time::Instant) {
        self.reading = Some((at, self.node.demand.asks()));
    }

    /// The clock as read after this input's last post, while nothing since may have taken time
    /// (Zenoh's tables asked whether a post is wanted); else read now.
    fn clock_reading(&mut self) -> std::time::Instant {
        match self.reading.take() {
            Some((at, asks)) if asks == self.node.demand.asks() => at,
            _ => std::time::Instant::now(),
        }
    }

    /// Publish the readback bundle: the state after the posts of this input, in one sample.
    fn publish_readback(&mut self, marker: &StateMarker, stamp: Timestamp, delivery: Delivery) {
        let bundle = Readback::encode(self.service.fields(), marker.seq);
        if self.readback.is_none()
            && self.node.budget.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1)).is_ok()
        {
            self.node.key_work.note_new_key();
            let key = self.node.layout.readback(self.name());
            let declared = self.node.session.declare_publisher(key).encoding(Encoding::APPLICATION_CBOR);
            self.readback = declared.allowed_destination(Locality::Remote).wait().ok();
            self.reading = None;
        }
        self.send_state(Streamed::Bundle(bundle.clone()), bundle, marker, stamp, delivery);
    }

    /// Send one state sample of this axis, `payload` its bytes, the way `way` says: the events'
    /// way (it must arrive, or the network is congested), straight out (after any held back), or
    /// held back.
    fn send_state(
        &mut self,
        sample: Streamed,
        payload: Vec<u8>,
        marker: &StateMarker,
        stamp: Timestamp,
        delivery: Delivery,
    ) {
        // One reading of the clock for the decision, the log and the put's start.
        let start = self.clock_reading();
        let now = self.node.congestion.at(start);
        self.keep_reading(start);
        match self.way(delivery, now) {
            Way::Stream => {
                if self.stream_log.holds() {
                    self.stream_held(now, Some(&sample));
                }
                self.stream(now, sample, payload, marker, stamp);
            }
            Way::HoldBack => self.stream_log.hold(sample, marker, stamp),
            Way::Event => {
                if let Some(key) = self.sample_key(&sample) {
                    let replaceable = delivery == Delivery::Stream;
                    self.post_event(key, payload, Encoding::APPLICATION_CBOR, marker, stamp, replaceable);
                }
            }
        }
    }

    /// Send the samples held back, oldest first, the droppable way, at `now`; but a held sample
    /// of the key of `next`, which is sent right after them, is only replaced.
    fn stream_held(&mut self, now: Micros, next: Option<&Streamed>) {
        let held = self.stream_log.release();
        for (sample, marker, stamp) in held.into_iter().filter(|(held, ..)| !next.is_some_and(|n| n.same_key(held))) {
            let payload = sample.payload();
            self.stream(now, sample, payload, &marker, stamp);
        }
    }

    /// Send held samples once the axis may stream again (no post of it waits any longer), or
    /// the events' way should the link be congested again.
    fn release_held(&mut self) {
        if !self.stream_log.holds() {
            return;
        }
        let start = std::time::Instant::now();
        let now = self.node.congestion.at(start);
        self.keep_reading(start);
        match self.way(Delivery::Stream, now) {
            Way::Stream => self.stream_held(now, None),
            Way::HoldBack => {}
            Way::Event => {
                for (sample, marker, stamp) in self.stream_log.release() {
                    if let Some(key) = self.sample_key(&sample) {
                        self.post_event(key, sample.into_payload(), Encoding::APPLICATION_CBOR, &marker, stamp, true);
                    }
                }
            }
        }
        self.reading = None;
    }

    /// Put one stream sample straight to the network, droppable, logged to be sent again should
    /// congestion follow, at `now`.
    fn stream(&mut self, now: Micros, sample: Streamed, payload: Vec<u8>, marker: &StateMarker, stamp: Timestamp) {
        let start = self.clock_reading();
        let (publisher, field) = match &sample {
            Streamed::Field(field, _) => (self.hot.iter().find(|(f, _)| f == field).map(|(_, p)| p), Some(*field)),
            Streamed::Bundle(_) => (self.readback.as_ref(), None),
        };
        // Asked for only when there is no publisher: a put to a key Zenoh matches afresh.
        let key = || {
            self.node.key_work.note();
            match field {
                Some(field) => Ok(self.field_key(field)),
                None => KeyExpr::try_from(self.node.layout.readback(self.name())),
            }
        };
        let end =
            self.node.congestion.timed(start, || put_state(&self.node.session, publisher, key, payload, marker, stamp));
        self.keep_reading(end);
        self.stream_log.record(now, sample, marker, stamp);
    }

    /// A sample's key, declared where it has a publisher.
    fn sample_key(&self, sample: &Streamed) -> Option<KeyExpr<'static>> {
        match sample {
            Streamed::Field(field, _) => Some(self.key_of(*field)),
            Streamed::Bundle(_) => self.readback_key(),
        }
    }

    /// The bundle's key, declared where it has a publisher.
    fn readback_key(&self) -> Option<KeyExpr<'static>> {
        match &self.readback {
            Some(publisher) => Some(publisher.key_expr().clone()),
            None => KeyExpr::try_from(self.node.layout.readback(self.name())).ok(),
        }
    }

    /// The trace publisher, declared at the first driver command traced; it must exist whatever the
    /// budget, and counts against it all the same.
    fn trace_publisher(&mut self) -> Option<&zenoh::pubsub::Publisher<'static>> {
        if self.trace.is_none() {
            let key = self.node.layout.driver_cmd(self.name());
            self.node.key_work.note_new_key();
            self.trace = self.node.session.declare_publisher(key).encoding(Encoding::APPLICATION_CBOR).wait().ok();
            let _ = self.node.budget.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1));
        }
        self.trace.as_ref()
    }

    /// Answer `query`; a field's value or a motion's end carries the axis's state as its posts
    /// do (`state_now`), `stamp` the time of the values.
    fn reply(&self, query: &Query, reply: Reply, stamp: Timestamp) {
        // A reply to a write key carries that key: Zenoh drops replies outside the query's.
        let written = self.node.layout.written_field_name(self.name(), query.key_expr().as_str()).is_some();
        let key_of = |field| if written { query.key_expr().clone().into_owned() } else { self.field_key(field) };
        let state = || Some(self.state_now(stamp));
        let (key, payload, state) = match reply {
            Reply::Value(field, value) => (key_of(field), encode_cbor(&value), state()),
            Reply::Completion(field, completion) => (key_of(field), encode_cbor(&completion), state()),
            Reply::SimState(state) => match KeyExpr::try_from(keys::sim_key(self.name(), keys::SIM_STATE_KEY)) {
                Ok(key) => (key, encode_cbor(&state), None),
                Err(_) => return,
            },
            Reply::SimSetting(setting, value) => match KeyExpr::try_from(keys::sim_key(self.name(), setting.name())) {
                Ok(key) => (key, encode_cbor(&value), None),
                Err(_) => return,
            },
            Reply::Refused(refusal) => {
                let (kind, message) = (refusal.kind(), refusal.to_string());
                let key = query.key_expr().clone().into_owned();
                let refused = Destination::Refusal(query.clone());
                return self.answer(key, message.into_bytes(), refusal::encoding(kind), refused, None);
            }
            // As ERR carries it: the words, the kind in the encoding's schema; nothing yet, no words.
            Reply::Message(message) => {
                let Ok(key) = KeyExpr::try_from(self.node.layout.err(self.name())) else { return };
                let (encoding, words) = match message {
                    Some((kind, words)) => (refusal::encoding(kind), words),
                    None => (Encoding::TEXT_PLAIN, String::new()),
                };
                return self.answer(key, words.into_bytes(), encoding, Destination::Answer(query.clone()), state());
            }
        };
        self.answer(key, payload, Encoding::APPLICATION_CBOR, Destination::Answer(query.clone()), state);
    }

    /// What a reply of the axis's values carries, as a post does: the marker of its last post
    /// (the values are as of it) with the alarm now, and `stamp`.
    fn state_now(&self, stamp: Timestamp) -> AnswerState {
        let fields = self.service.fields();
        let marker = StateMarker::new(self.service.last_seq(), fields.stat, fields.sevr);
        AnswerState { attachment: marker.encode(), stamp }
    }

    /// Answer a query behind the axis's posts that wait to be sent (sent at once when none
    /// waits): the writer has what its write did before it has the answer.
    fn answer(
        &self,
        key: KeyExpr<'static>,
        payload: Vec<u8>,
        encoding: Encoding,
        destination: Destination,
        state: Option<AnswerState>,
    ) {
        let waiting = self.events_waiting.clone();
        let (attachment, stamp) = state.map(|s| (s.attachment, s.stamp)).unzip();
        let replaceable = false;
        self.node.events.post(EventPost {
            key,
            payload,
            encoding,
            attachment,
            stamp,
            destination,
            replaceable,
            waiting,
        });
    }

    /// Publish a field's new value: to the links of this node that follow it, and to the
    /// network when a subscriber there wants that field (as the record posts a monitor only to
    /// those who asked). Publications go to other processes only: the node hears itself
    /// in-process.
    fn publish(
        &mut self,
        field: Field,
        value: &Value,
        marker: &StateMarker,
        stamp: Timestamp,
        delivery: Delivery,
        now: Instant,
    ) {
        if self.node.followers.deliver(self.service.name(), field, value) {
            // A follower may have handled the value at once, on this thread: the next post
            // reads the clock afresh.
            self.reading = None;
        }
        if !self.node.demand.wanted(field, delivery, now) {
            return;
        }
        self.declare_hot_publisher(field);
        self.send_state(Streamed::Field(field, value.clone()), encode_cbor(value), marker, stamp, delivery);
    }

    /// Declare the field's publisher at its second post (within the budget), whichever way its
    /// posts go; a readback's at its first, for a moving axis posts it at every poll (a first
    /// post without publisher would cost Zenoh a walk of every key for nothing, here and at
    /// each subscriber). A field's first post, declared or not, has Zenoh match a new key
    /// (unless the axis declared it ahead: `declare_ahead`).
    fn declare_hot_publisher(&mut self, field: Field) {
        if self.hot.iter().any(|(f, _)| *f == field) {
            return;
        }
        let first_post = !self.posted_once.contains(&field);
        if first_post {
            self.posted_once.push(field);
            self.node.key_work.note_new_key();
        }
        if first_post && !field.is_readback_stream() {
            return;
        }
        self.declare_publisher(field);
    }

    /// Declare the field's publisher, within the budget.
    fn declare_publisher(&mut self, field: Field) {
        if self.node.budget.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1)).is_err() {
            return;
        }
        self.node.key_work.note_new_key();
        let declared = self
            .node
            .session
            .declare_publisher(self.field_key(field))
            .encoding(Encoding::APPLICATION_CBOR)
            .allowed_destination(Locality::Remote)
            .wait();
        // A declaration is matched against every key: the next post reads the clock afresh.
        self.reading = None;
        match declared {
            Ok(publisher) => self.hot.push((field, publisher)),
            Err(e) => tracing::warn!(axis = %self.name(), %field, "cannot declare a publisher: {e}"),
        }
    }

    /// A field's key, declared (Zenoh resolves a declared key once, a string key at each put)
    /// where the field has a publisher.
    fn key_of(&self, field: Field) -> KeyExpr<'static> {
        match self.hot.iter().find(|(f, _)| *f == field) {
            Some((_, publisher)) => publisher.key_expr().clone(),
            None => {
                self.node.key_work.note();
                self.field_key(field)
            }
        }
    }
}

/// Send a state sample to other processes: through its declared publisher, or with a session
/// put on `key` when it has none (past the budget).
fn put_state(
    session: &Session,
    publisher: Option<&zenoh::pubsub::Publisher<'static>>,
    key: impl FnOnce() -> Result<KeyExpr<'static>, zenoh::Error>,
    payload: Vec<u8>,
    marker: &StateMarker,
    stamp: Timestamp,
) {
    let attachment = ZBytes::from(marker.encode());
    let _ = match publisher {
        Some(publisher) => publisher.put(payload).attachment(attachment).timestamp(stamp).wait(),
        None => key().and_then(|key| {
            let put = session.put(key, payload).encoding(Encoding::APPLICATION_CBOR);
            put.allowed_destination(Locality::Remote).attachment(attachment).timestamp(stamp).wait()
        }),
    };
}

impl Handler<AxisInput> for AxisCore {
    fn handle(&mut self, input: AxisInput) {
        let now = self.now();
        match input {
            AxisInput::Write(w) => {
                self.service.put(now, WriteRequest::new(&w.name, &w.payload, w.encoding).held(w.hold))
            }
            AxisInput::Query(query) => self.on_query(now, query),
            AxisInput::SimWrite(w) => self.service.sim_write(now, &w.name, &w.payload, w.encoding),
            AxisInput::SimQuery(query) => self.on_sim_query(now, query),
            AxisInput::WildcardWrite(key) => self.service.wildcard_put(&key),
            AxisInput::Deleted(key) => self.service.delete(&key),
            AxisInput::ControllerStatus(status, motions) => self.service.controller_status(now, status, motions),
            AxisInput::ControllerMessage(message) => self.service.controller_message(message),
            AxisInput::Tick => self.service.handle_timeout(now),
            AxisInput::LinkUpdate(link, value) => self.service.link_update(now, link, value),
            AxisInput::LinkRead(link, value) => self.service.link_read(now, link, value),
            AxisInput::LinkLost(link) => self.service.link_lost(now, link),
            AxisInput::HoldReleased(token) => self.service.hold_released(now, &token),
            AxisInput::StopMotion => self.service.stop_motion(now),
        }
        self.flush(now);
        self.release_held();
        if self.service.take_unsaved_change() && !self.unsaved.swap(true, Ordering::AcqRel) {
            self.save_due.notify_one();
        }
        self.schedule_ticks();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stream_samples_wait_in_the_queue_only_while_the_link_is_congested_and_are_held_back_after() {
        use Delivery::{Event, Stream};
        for (congested, waiting) in [(false, false), (false, true), (true, false), (true, true)] {
            assert_eq!(Way::of(Event, congested, waiting), Way::Event, "an event must arrive: {congested} {waiting}");
        }
        assert_eq!(Way::of(Stream, false, false), Way::Stream);
        assert_eq!(Way::of(Stream, true, false), Way::Event, "a congested link: the events' way, replaceable");
        assert_eq!(Way::of(Stream, true, true), Way::Event);
        // Queued behind its axis's waiting posts once the congestion had passed, a thousand axes
        // polled together kept the sender's queue from ever emptying.
        assert_eq!(Way::of(Stream, false, true), Way::HoldBack);
    }

    #[test]
    fn axes_declare_ahead_while_all_fit_the_budget_with_room_for_a_trace_and_a_bundle_each() {
        let per_axis = Field::all().filter(|f| f.posted_by_every_motion()).count() + 2;
        let most = PUBLISHER_BUDGET / per_axis;
        assert!(declares_ahead(1) && declares_ahead(1000) && declares_ahead(most), "{most}");
        assert!(!declares_ahead(most + 1) && !declares_ahead(10_000));
    }
}
