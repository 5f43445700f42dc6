//! zmotor-ca, the Channel Access gateway: serves every axis live on the Zenoh network to CA
//! clients, as a client of that network (zmotor-client). `zmotor-ca-proto` holds the protocol,
//! sans-IO; this moves its bytes (a UDP socket
//! for searches, a TCP circuit per client) and holds the values: the axes' liveliness tokens
//! say which are live; when a client first asks for an axis, a subscription to its fields keeps
//! their values and a read of the whole axis fetches them. Writes are confirmed Zenoh writes to write keys
//! (so that they work under access control); a put-callback of a drive field waits for the end
//! of the motion (`?wait`). Bridge records (value holders as ao records, calc links' results as
//! calc records) are served likewise by their tokens and their value keys; an ao's write is a
//! plain put of its value, as the bridge's links write.

mod circuit;
mod values;

use circuit::serve_circuit;
use std::collections::{HashMap, VecDeque};
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};
use tokio::sync::{broadcast, mpsc};
use values::{Change, Entry, Values};
use zenoh::bytes::Encoding;
use zenoh::sample::{Sample, SampleKind};
use zmotor_ca_proto::{answer_search, Pv, Stamp, Target, WriteAnswer, WriteEnd};
use zmotor_client::{Client, NoAnswer, SentWrite, WriteOptions, WriteOutcome};
use zmotor_deploy::CaConfig;
use zmotor_msgs::{
    decode_cbor_value, decode_scalar, encode_cbor, keys, BridgeRecord, Field, PayloadEncoding, Refusal, RefusalKind,
    Value,
};

/// The gateway could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CaError {
    /// A socket could not be bound.
    #[error("cannot listen on {address}: {source}")]
    Bind {
        /// Where.
        address: SocketAddr,
        /// Why.
        source: std::io::Error,
    },
    /// A Zenoh declaration failed.
    #[error("zenoh: {0}")]
    Zenoh(#[from] zenoh::Error),
}

/// How long a put-callback of a drive field may wait for its motion to end.
const MOTION_PATIENCE: Duration = Duration::from_secs(3600);
/// How long any other request waits for the node.
const ANSWER_PATIENCE: Duration = Duration::from_secs(10);

/// Put-callbacks waiting for an axis, each with where its end goes.
type Waiting = VecDeque<(Write, mpsc::UnboundedSender<Done>)>;

/// What every task of the front-end shares.
#[derive(Clone)]
pub(crate) struct Shared {
    client: Client,
    values: Arc<Mutex<Values>>,
    changes: broadcast::Sender<Change>,
    prefix: String,
    /// The axes a put-callback moves, each with the put-callbacks of motions waiting for it.
    moved: Arc<Mutex<HashMap<String, Waiting>>>,
}

impl Shared {
    pub(crate) fn values(&self) -> std::sync::MutexGuard<'_, Values> {
        self.values.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn moved(&self) -> std::sync::MutexGuard<'_, HashMap<String, Waiting>> {
        self.moved.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Store a field's value, or the axis's message, as a sample brings it, and tell the
    /// circuits.
    fn store(&self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        if let Some(record) = BridgeRecord::of_value_key(key) {
            return self.store_record(record, sample, false);
        }
        let Some(axis) = self.client.layout().axis_chunk(key) else { return };
        let Some(name) = self.client.layout().field_name(axis, key) else { return };
        let payload = sample.payload().to_bytes();
        let (target, value) = if name == keys::ERR_KEY {
            (Target::Message, Value::Text(String::from_utf8_lossy(&payload).into_owned()))
        } else {
            let Some(field) = Field::from_name(name) else { return };
            let Ok(value) = decode_cbor_value(&payload) else { return };
            (Target::Field(field), value)
        };
        self.keep(axis.to_string(), target, Entry { value, stamp: stamp_of(sample) });
    }

    /// Store a bridge record's value, if the sample carries a number; with `fill_only`, only
    /// when it has none yet (a read's answer may come after a newer value, which anyone may put).
    fn store_record(&self, record: &str, sample: &Sample, fill_only: bool) {
        let Some(x) = sample_number(sample) else { return };
        let (kind, filled) = {
            let values = self.values();
            let Some(kind) = values.records.get(record).copied() else { return };
            (kind, values.axes.get(record).is_some_and(values::AxisValues::answered))
        };
        if fill_only && filled {
            return;
        }
        let entry = Entry { value: Value::Float(x), stamp: stamp_of(sample) };
        self.keep(record.to_string(), Target::BridgeValue(kind), entry);
    }

    /// Keep a value of an axis or a record followed now (a late sample of one that went must not
    /// revive its values), and tell the circuits.
    fn keep(&self, axis: String, target: Target, entry: Entry) {
        let mut values = self.values();
        if !values.followed.contains_key(&axis) {
            return;
        }
        // Told under the lock, so that the circuits get the changes in the order of the values.
        let change = values.store(axis, target, entry);
        let _ = self.changes.send(change);
    }

    /// Follow an axis's fields, or a bridge record's value, and read them all, once while it stays
    /// live.
    pub(crate) fn fetch(&self, axis: String) {
        let (followed, read, record) = {
            let mut values = self.values();
            let layout = self.client.layout();
            // A live axis of the name is the axis.
            let record = values.records.get(&axis).copied().filter(|_| !values.live.contains(&axis));
            let (followed, read) = match record {
                Some(_) => (BridgeRecord::value_key(&axis), BridgeRecord::value_key(&axis)),
                None => (layout.axis_fields(&axis), layout.axis_all(&axis)),
            };
            match values.followed.entry(axis.clone()) {
                std::collections::hash_map::Entry::Occupied(_) => return,
                std::collections::hash_map::Entry::Vacant(slot) => slot.insert(None),
            };
            (followed, read, record)
        };
        let shared = self.clone();
        tokio::spawn(async move {
            let storing = shared.clone();
            let follow = shared.client.session().declare_subscriber(followed);
            let Ok(subscriber) = follow.callback(move |sample| storing.store(&sample)).await else {
                shared.values().followed.remove(&axis);
                return;
            };
            if let Some(slot) = shared.values().followed.get_mut(&axis) {
                *slot = Some(subscriber);
            }
            let Ok(replies) = shared.client.session().get(read).timeout(ANSWER_PATIENCE).await else {
                return;
            };
            while let Ok(reply) = replies.recv_async().await {
                match (reply.result(), record) {
                    (Ok(sample), Some(_)) => shared.store_record(&axis, sample, true),
                    (Ok(sample), None) => shared.store(sample),
                    (Err(_), _) => {}
                }
            }
            let answered = {
                let mut values = shared.values();
                let has_values = values.axes.get(&axis).is_some_and(values::AxisValues::answered);
                if !values.followed.contains_key(&axis) {
                    // It went meanwhile: nothing to show, nothing to ask again.
                    return;
                }
                // A calc that answered nothing has no value yet (not processed): shown undefined,
                // as an IOC's. An axis or an ao always has one: asked again.
                if has_values || record == Some(BridgeRecord::Calc) {
                    let _ = shared.changes.send(values.show_whole(axis.clone()));
                    true
                } else {
                    let followed = values.followed.remove(&axis);
                    drop(values);
                    drop(followed);
                    false
                }
            };
            // Nothing came (a node too slow, or gone): asked again in a while while the axis is
            // live, so that a read or monitor waiting for its values is answered.
            if !answered {
                tokio::time::sleep(FETCH_AGAIN).await;
                let values = shared.values();
                if values.live.contains(&axis) || values.records.contains_key(&axis) {
                    drop(values);
                    shared.fetch(axis);
                }
            }
        });
    }

    /// A confirmed write to a write key; how it ended goes back to the circuit. Sent here, in
    /// the circuit's order (a client's VELO then VAL, or VAL then STOP, reach the node in that
    /// order); the answer is awaited on a task of its own.
    ///
    /// A put-callback of a motion (a target, a home search) to an axis another one moves waits
    /// for that one to complete, then is sent: an IOC's dbNotify queues a put-callback to a
    /// record another put-callback holds (its restart list), so each completes at its own
    /// target. A STOP or SPMG is never queued (an IOC's would wait for the motion it should stop).
    pub(crate) async fn write(&self, write: Write, done: mpsc::UnboundedSender<Done>) {
        let moves = write.wait && matches!(write.pv.target, Target::Field(f) if f.starts_motion());
        if moves {
            let mut moved = self.moved();
            match moved.get_mut(&write.pv.axis) {
                Some(waiting) => return waiting.push_back((write, done)),
                None => moved.insert(write.pv.axis.clone(), VecDeque::new()),
            };
        }
        let axis = write.pv.axis.clone();
        let sent = self.send(write).await;
        let shared = self.clone();
        tokio::spawn(async move {
            let (mut sent, mut done) = (sent, done);
            loop {
                let (answer, sending) = sent;
                let end = match sending {
                    Sending::Confirmed(Ok(sending)) => write_end(sending.outcome().await),
                    Sending::Confirmed(Err(e)) => WriteEnd::Unanswered { denied: false, why: e.to_string() },
                    Sending::Ended(end) => end,
                };
                let _ = done.send((answer, end));
                if !moves {
                    return;
                }
                let Some((write, next)) = shared.next_motion(&axis) else { return };
                (sent, done) = (shared.send(write).await, next);
            }
        });
    }

    async fn send(&self, write: Write) -> (WriteAnswer, Sending) {
        let Write { pv, text, wait, hold, answer } = write;
        if let Target::BridgeValue(BridgeRecord::Value) = pv.target {
            return (answer, Sending::Ended(self.put_record(&pv.axis, &text).await));
        }
        // The circuit writes only channels that write a field.
        let Some((field, text)) = pv.written(text) else {
            return (answer, Sending::Confirmed(Err(format!("{}: not a field", pv.axis).into())));
        };
        let options =
            if wait { WriteOptions::waiting(MOTION_PATIENCE) } else { WriteOptions::confirmed(ANSWER_PATIENCE) };
        (answer, Sending::Confirmed(self.client.write(&pv.axis, field, text, options.held_by(hold)).await))
    }

    /// A value holder's new value, put on its key as the bridge's links write (a value holder
    /// answers no write), then read back: access control drops a put it denies without a word,
    /// and the value read says whether it was taken (a denied one: ECA_NOWTACCESS, the holder's
    /// value shown again). Only a finite number is put.
    async fn put_record(&self, record: &str, text: &str) -> WriteEnd {
        let number = text.trim().parse::<f64>().ok().filter(|x| x.is_finite());
        let Some(x) = number else {
            let message = format!("{}{record}.VAL: '{text}' is not a finite number", self.prefix);
            return WriteEnd::Refused(Refusal { kind: RefusalKind::BadValue, message });
        };
        let key = BridgeRecord::value_key(record);
        let put = self.client.session().put(&key, encode_cbor(&Value::Float(x)));
        if let Err(e) = put.encoding(Encoding::APPLICATION_CBOR).await {
            return WriteEnd::Unanswered { denied: false, why: e.to_string() };
        }
        // Sent after the put on the same session, so answered after the holder took it.
        let replies = match self.client.session().get(&key).timeout(ANSWER_PATIENCE).await {
            Ok(replies) => replies,
            Err(e) => return WriteEnd::Unanswered { denied: false, why: e.to_string() },
        };
        let mut held = None;
        while let Ok(reply) = replies.recv_async().await {
            if let Ok(sample) = reply.result() {
                held = sample_number(sample).map(|value| (value, sample.clone()));
            }
        }
        match held {
            Some((value, _)) if value == x => WriteEnd::Done,
            Some((value, sample)) => {
                self.store_record(record, &sample, false);
                let why = format!("{}{record} kept {value}: the put was not taken (access control)", self.prefix);
                WriteEnd::Unanswered { denied: true, why }
            }
            None => WriteEnd::Unanswered { denied: false, why: format!("{}{record}: nothing answered", self.prefix) },
        }
    }

    /// The next put-callback of a motion waiting for `axis`, if any (the axis is then free): one
    /// whose circuit has closed is dropped unsent, as an IOC cancels the put-callback of a
    /// client that went.
    fn next_motion(&self, axis: &str) -> Option<(Write, mpsc::UnboundedSender<Done>)> {
        let mut moved = self.moved();
        while let Some((write, done)) = moved.get_mut(axis).and_then(VecDeque::pop_front) {
            if !done.is_closed() {
                return Some((write, done));
            }
        }
        moved.remove(axis);
        None
    }
}

/// The number a sample carries, whatever its encoding.
fn sample_number(sample: &Sample) -> Option<f64> {
    let encoding = PayloadEncoding::from_mime(&sample.encoding().to_string());
    decode_scalar(&sample.payload().to_bytes(), encoding).ok()?.as_f64()
}

/// The node's time of a value (when the axis read the status it comes from), as an IOC's record
/// time stamp; its arrival where the sample has none.
fn stamp_of(sample: &Sample) -> Stamp {
    let time = sample.timestamp().map_or_else(SystemTime::now, |t| t.get_time().to_system_time());
    let since = time.duration_since(SystemTime::UNIX_EPOCH).unwrap_or_default();
    Stamp::from_posix(since.as_secs(), since.subsec_nanos())
}

/// How a write's outcome is told to a CA client.
fn write_end(outcome: WriteOutcome) -> WriteEnd {
    match outcome {
        WriteOutcome::Accepted(_) | WriteOutcome::Completed(_) => WriteEnd::Done,
        WriteOutcome::Refused(refusal) => WriteEnd::Refused(refusal),
        silent @ WriteOutcome::NoAnswer(NoAnswer::Silent) => {
            WriteEnd::Unanswered { denied: true, why: silent.to_string() }
        }
        other => WriteEnd::Unanswered { denied: false, why: other.to_string() },
    }
}

/// How a write was sent: confirmed by the node serving the axis, or a bridge record's plain put,
/// ended once read back (`put_record`).
enum Sending {
    Confirmed(Result<SentWrite, zenoh::Error>),
    Ended(WriteEnd),
}

/// A write's end, for its circuit.
pub(crate) type Done = (WriteAnswer, WriteEnd);

/// A write to send: what the circuit asked, the hold token resolved.
pub(crate) struct Write {
    pub(crate) pv: Pv,
    pub(crate) text: String,
    pub(crate) wait: bool,
    /// The liveliness token that holds the motion, if it is held.
    pub(crate) hold: Option<String>,
    pub(crate) answer: WriteAnswer,
}

/// A running front-end; dropping it stops it.
pub struct ChannelAccess {
    tasks: Vec<tokio::task::JoinHandle<()>>,
    /// Dropped with the front-end: every circuit ends (and its holds with it).
    _running: tokio::sync::watch::Sender<()>,
    _tokens: zenoh::pubsub::Subscriber<()>,
    /// The bridge records' tokens.
    _records: zenoh::pubsub::Subscriber<()>,
    /// The TCP port circuits connect to.
    pub tcp_port: u16,
}

impl Drop for ChannelAccess {
    fn drop(&mut self) {
        self.tasks.iter().for_each(tokio::task::JoinHandle::abort);
    }
}

impl ChannelAccess {
    /// Serve the axes `client` reaches.
    pub async fn start(client: Client, config: &CaConfig) -> Result<Self, CaError> {
        let address = SocketAddr::new(config.address, config.port);
        let bind = |source| CaError::Bind { address, source };
        let listener = tokio::net::TcpListener::bind(address).await.map_err(bind)?;
        let tcp_port = listener.local_addr().map_err(bind)?.port();
        let udp = search_socket(SocketAddr::new(config.address, tcp_port)).map_err(bind)?;
        let (changes, _) = broadcast::channel(4096);
        let shared = Shared {
            client: client.clone(),
            values: Arc::default(),
            changes,
            prefix: config.pv_prefix.clone(),
            moved: Arc::default(),
        };
        let runtime = tokio::runtime::Handle::current();
        let tokens = {
            let shared = shared.clone();
            client
                .session()
                .liveliness()
                .declare_subscriber(client.layout().axis("*"))
                .history(true)
                .callback(move |sample| {
                    let Some(axis) = shared.client.layout().axis_chunk(sample.key_expr().as_str()).map(str::to_string)
                    else {
                        return;
                    };
                    let mut values = shared.values();
                    if sample.kind() == SampleKind::Put {
                        if values.records.contains_key(&axis) && !values.live.contains(&axis) {
                            // Followed as a bridge record of the name until now: the axis wins.
                            let followed = values.followed.remove(&axis);
                            runtime.spawn(async move { drop(followed) });
                            let _ = shared.changes.send(values.forget(axis.clone()));
                        }
                        values.live.insert(axis);
                    } else {
                        // Undeclared on a task of ours, not inside Zenoh's callback.
                        let followed = values.followed.remove(&axis);
                        runtime.spawn(async move { drop(followed) });
                        let _ = shared.changes.send(values.forget(axis));
                    }
                })
                .await?
        };
        let records = {
            let shared = shared.clone();
            let runtime = tokio::runtime::Handle::current();
            client
                .session()
                .liveliness()
                .declare_subscriber(BridgeRecord::every_token())
                .history(true)
                .callback(move |sample| {
                    let Some((record, kind)) = BridgeRecord::of_token(sample.key_expr().as_str()) else { return };
                    let record = record.to_string();
                    let mut values = shared.values();
                    if sample.kind() == SampleKind::Put {
                        values.records.insert(record, kind);
                    } else if values.records.remove(&record).is_some() && !values.live.contains(&record) {
                        let followed = values.followed.remove(&record);
                        runtime.spawn(async move { drop(followed) });
                        let _ = shared.changes.send(values.forget(record));
                    }
                })
                .await?
        };
        let searches = {
            let shared = shared.clone();
            tokio::spawn(async move {
                let mut buffer = vec![0; 64 * 1024];
                loop {
                    let (length, from) = match udp.recv_from(&mut buffer).await {
                        Ok(received) => received,
                        Err(e) => {
                            // As an IOC's server: said, and searches answered again after a pause.
                            tracing::warn!("Channel Access search socket: {e}");
                            tokio::time::sleep(SOCKET_PAUSE).await;
                            continue;
                        }
                    };
                    let answer = answer_search(&shared.prefix, &buffer[..length], tcp_port, &*shared.values());
                    if let Some(answer) = answer {
                        let _ = udp.send_to(&answer, from).await;
                    }
                }
            })
        };
        let (running, stopped) = tokio::sync::watch::channel(());
        let circuits = {
            let shared = shared.clone();
            tokio::spawn(async move {
                loop {
                    let (stream, peer) = match listener.accept().await {
                        Ok(accepted) => accepted,
                        Err(e) => {
                            // Out of descriptors, or a connection reset before it was taken: the
                            // clients after it are served (rsrv logs it and goes on likewise).
                            tracing::warn!("Channel Access: a connection not accepted: {e}");
                            tokio::time::sleep(SOCKET_PAUSE).await;
                            continue;
                        }
                    };
                    let shared = shared.clone();
                    let stopped = stopped.clone();
                    tokio::spawn(async move {
                        if let Err(e) = serve_circuit(stream, &shared, stopped).await {
                            tracing::debug!(%peer, "circuit closed: {e}");
                        }
                    });
                }
            })
        };
        tracing::info!(%address, tcp_port, pv_prefix = config.pv_prefix, "Channel Access serving the live axes");
        Ok(Self { tasks: vec![searches, circuits], _running: running, _tokens: tokens, _records: records, tcp_port })
    }
}

/// How long after a read of an axis that nothing answered it is read again.
const FETCH_AGAIN: std::time::Duration = std::time::Duration::from_secs(1);

/// How long the server waits after a socket error before it listens again.
const SOCKET_PAUSE: std::time::Duration = std::time::Duration::from_millis(100);

/// The UDP socket searches come to, shared as EPICS servers share it (SO_REUSEADDR): an IOC on
/// the same host and port still gets its broadcast searches.
fn search_socket(address: SocketAddr) -> std::io::Result<tokio::net::UdpSocket> {
    let socket = socket2::Socket::new(socket2::Domain::for_address(address), socket2::Type::DGRAM, None)?;
    socket.set_reuse_address(true)?;
    socket.set_nonblocking(true)?;
    socket.bind(&address.into())?;
    tokio::net::UdpSocket::from_std(socket.into())
}
