//! The Channel Access front-end: serves every axis live on the Zenoh network to CA clients, as
//! a client of that network. `zmotor-ca` holds the protocol; this moves its bytes (a UDP socket
//! for searches, a TCP circuit per client) and holds the values: the axes' liveliness tokens
//! say which are live; when a client first asks for an axis, a subscription to its fields keeps
//! their values and a read of the whole axis fetches them. Writes are confirmed Zenoh writes to write keys
//! (so that they work under access control); a put-callback of a drive field waits for the end
//! of the motion (`?wait`).

use std::collections::{HashMap, HashSet};
use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{broadcast, mpsc};
use zenoh::sample::{Sample, SampleKind};
use zenoh::Session;
use zmotor_ca::{search, Circuit, Directory, Pv, Request, Snapshot, Stamp, Target, WriteAnswer};
use zmotor_msgs::codec::decode_cbor_value;
use zmotor_msgs::{Field, KeyLayout, Kind, Value};

/// Circuits served so far by this process: each holds its jogs by a token of its own.
static CIRCUITS: AtomicU64 = AtomicU64::new(0);

/// Where and how the front-end serves.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CaConfig {
    /// Prepended to every channel name (`<P><axis>.<FIELD>`).
    pub pv_prefix: String,
    /// The address to listen on.
    pub address: IpAddr,
    /// The UDP port searches come to, and the TCP port of circuits (5064 in EPICS).
    pub port: u16,
}

impl Default for CaConfig {
    /// No prefix, on 127.0.0.1 (a lab serves on 0.0.0.0 or an interface's address), port 5064.
    fn default() -> Self {
        Self { pv_prefix: String::new(), address: IpAddr::from([127, 0, 0, 1]), port: 5064 }
    }
}

/// The front-end could not start.
#[derive(Debug, thiserror::Error)]
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

/// A field's last value, and when it arrived.
#[derive(Clone, Debug)]
struct Entry {
    value: Value,
    stamp: Stamp,
}

/// The values the front-end holds.
#[derive(Default)]
struct Values {
    live: HashSet<String>,
    /// The axes a client asked for since they became live, each with the subscriber to its
    /// fields (`None` while it is declared): the nodes publish only what someone follows.
    followed: HashMap<String, Option<zenoh::pubsub::Subscriber<()>>>,
    fields: HashMap<String, HashMap<Field, Entry>>,
}

impl Values {
    fn number(&self, axis: &str, field: Field) -> f64 {
        self.entry(axis, field).and_then(|e| e.value.as_f64()).unwrap_or(0.0)
    }

    fn entry(&self, axis: &str, field: Field) -> Option<&Entry> {
        self.fields.get(axis)?.get(&field)
    }
}

impl Directory for Values {
    fn is_live(&self, axis: &str) -> bool {
        self.live.contains(axis)
    }

    fn snapshot(&self, pv: &Pv) -> Option<Snapshot> {
        let alarm = self.entry(&pv.axis, Field::STAT)?;
        let (value, stamp, choices) = match pv.target {
            Target::Field(field) => {
                let entry = self.entry(&pv.axis, field)?;
                let choices = match field.def().kind {
                    Kind::Menu(menu) => menu.choices,
                    _ => &[],
                };
                (entry.value.clone(), entry.stamp, choices)
            }
            Target::RecordType => (Value::Text("motor".into()), alarm.stamp, &[][..]),
        };
        let egu = match self.entry(&pv.axis, Field::EGU).map(|e| &e.value) {
            Some(Value::Text(egu)) => egu.clone(),
            _ => String::new(),
        };
        let (upper, lower) =
            pv.limits().map_or((0.0, 0.0), |(high, low)| (self.number(&pv.axis, high), self.number(&pv.axis, low)));
        Some(Snapshot {
            value,
            native: pv.native(),
            status: self.number(&pv.axis, Field::STAT) as u16,
            severity: self.number(&pv.axis, Field::SEVR) as u16,
            stamp,
            units: pv.units(&egu),
            precision: self.number(&pv.axis, Field::PREC) as i16,
            upper,
            lower,
            alarm: pv.alarm_limits().map_or([f64::NAN; 4], |fields| fields.map(|f| self.number(&pv.axis, f))),
            choices,
        })
    }
}

/// What circuits are told of the network.
#[derive(Clone, Debug)]
enum Change {
    Field(String, Field),
    Gone(String),
}

/// What every task of the front-end shares.
#[derive(Clone)]
struct Shared {
    session: Session,
    layout: KeyLayout,
    values: Arc<Mutex<Values>>,
    changes: broadcast::Sender<Change>,
    prefix: String,
}

impl Shared {
    fn values(&self) -> std::sync::MutexGuard<'_, Values> {
        self.values.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Store a field's value as a sample brings it, and tell the circuits.
    fn store(&self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        let Some(axis) = self.layout.axis_chunk(key) else { return };
        let Some(field) = self.layout.field_name(axis, key).and_then(Field::from_name) else { return };
        let Ok(value) = decode_cbor_value(&sample.payload().to_bytes()) else { return };
        let since = SystemTime::now().duration_since(SystemTime::UNIX_EPOCH).unwrap_or_default();
        let stamp = Stamp::from_posix(since.as_secs(), since.subsec_nanos());
        let axis = axis.to_string();
        let mut values = self.values();
        // Only axes followed now: a late sample of an axis that went must not revive its values.
        if !values.followed.contains_key(&axis) {
            return;
        }
        values.fields.entry(axis.clone()).or_default().insert(field, Entry { value, stamp });
        drop(values);
        let _ = self.changes.send(Change::Field(axis, field));
    }

    /// Follow an axis's fields and read them all, once while it stays live.
    fn fetch(&self, axis: String) {
        match self.values().followed.entry(axis.clone()) {
            std::collections::hash_map::Entry::Occupied(_) => return,
            std::collections::hash_map::Entry::Vacant(slot) => slot.insert(None),
        };
        let shared = self.clone();
        tokio::spawn(async move {
            let storing = shared.clone();
            let follow = shared.session.declare_subscriber(shared.layout.axis_fields(&axis));
            let Ok(subscriber) = follow.callback(move |sample| storing.store(&sample)).await else {
                shared.values().followed.remove(&axis);
                return;
            };
            if let Some(slot) = shared.values().followed.get_mut(&axis) {
                *slot = Some(subscriber);
            }
            let Ok(replies) = shared.session.get(shared.layout.axis_all(&axis)).timeout(ANSWER_PATIENCE).await else {
                return;
            };
            while let Ok(reply) = replies.recv_async().await {
                if let Ok(sample) = reply.result() {
                    shared.store(sample);
                }
            }
            // Nothing came (a node too slow, or gone): the next client request tries again.
            let mut values = shared.values();
            if values.entry(&axis, Field::STAT).is_none() {
                let followed = values.followed.remove(&axis);
                drop(values);
                drop(followed);
            }
        });
    }

    /// A confirmed write to a write key; the outcome goes back to the circuit.
    /// Sent here, in the circuit's order (a client's VELO then VAL, or VAL then STOP, reach the
    /// node in that order); the answer is awaited on a task of its own.
    async fn write(&self, write: Write, done: mpsc::UnboundedSender<Done>) {
        let Write { pv, text, wait, hold, answer } = write;
        let Target::Field(field) = pv.target else { return };
        let patience = if wait { MOTION_PATIENCE } else { ANSWER_PATIENCE };
        let how = (wait, hold.as_deref());
        let sent = crate::client::confirmed_write(&self.session, &self.layout, (&pv.axis, field), text, how, patience);
        let sent = sent.await;
        tokio::spawn(async move {
            let _ = done.send((answer, sent.outcome().await));
        });
    }
}

/// A write's outcome, for its circuit.
type Done = (WriteAnswer, Result<(), String>);

/// A write to send: what the circuit asked, the hold token resolved.
struct Write {
    pv: Pv,
    text: String,
    wait: bool,
    /// The liveliness token that holds the motion, if it is held.
    hold: Option<String>,
    answer: WriteAnswer,
}

/// A running front-end; dropping it stops it.
pub struct ChannelAccess {
    tasks: Vec<tokio::task::JoinHandle<()>>,
    /// Dropped with the front-end: every circuit ends (and its holds with it).
    _running: tokio::sync::watch::Sender<()>,
    _tokens: zenoh::pubsub::Subscriber<()>,
    /// The TCP port circuits connect to.
    pub tcp_port: u16,
}

impl Drop for ChannelAccess {
    fn drop(&mut self) {
        self.tasks.iter().for_each(tokio::task::JoinHandle::abort);
    }
}

impl ChannelAccess {
    /// Serve the axes under `layout` that `session` reaches.
    pub async fn start(session: Session, layout: KeyLayout, config: &CaConfig) -> Result<Self, CaError> {
        let address = SocketAddr::new(config.address, config.port);
        let bind = |source| CaError::Bind { address, source };
        let listener = tokio::net::TcpListener::bind(address).await.map_err(bind)?;
        let tcp_port = listener.local_addr().map_err(bind)?.port();
        let udp = search_socket(SocketAddr::new(config.address, tcp_port)).map_err(bind)?;
        let (changes, _) = broadcast::channel(4096);
        let shared = Shared {
            session: session.clone(),
            layout: layout.clone(),
            values: Arc::default(),
            changes,
            prefix: config.pv_prefix.clone(),
        };
        let runtime = tokio::runtime::Handle::current();
        let tokens = {
            let shared = shared.clone();
            session
                .liveliness()
                .declare_subscriber(layout.axis("*"))
                .history(true)
                .callback(move |sample| {
                    let Some(axis) = shared.layout.axis_chunk(sample.key_expr().as_str()).map(str::to_string) else {
                        return;
                    };
                    let mut values = shared.values();
                    if sample.kind() == SampleKind::Put {
                        values.live.insert(axis);
                    } else {
                        values.live.remove(&axis);
                        values.fields.remove(&axis);
                        // Undeclared on a task of ours, not inside Zenoh's callback.
                        let followed = values.followed.remove(&axis);
                        drop(values);
                        runtime.spawn(async move { drop(followed) });
                        let _ = shared.changes.send(Change::Gone(axis));
                    }
                })
                .await?
        };
        let searches = {
            let shared = shared.clone();
            tokio::spawn(async move {
                let mut buffer = vec![0; 64 * 1024];
                while let Ok((length, from)) = udp.recv_from(&mut buffer).await {
                    let answer = search::answer(&shared.prefix, &buffer[..length], tcp_port, &*shared.values());
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
                while let Ok((stream, peer)) = listener.accept().await {
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
        Ok(Self { tasks: vec![searches, circuits], _running: running, _tokens: tokens, tcp_port })
    }
}

/// One client's circuit until it closes.
async fn serve_circuit(
    stream: tokio::net::TcpStream,
    shared: &Shared,
    mut stopped: tokio::sync::watch::Receiver<()>,
) -> std::io::Result<()> {
    stream.set_nodelay(true)?;
    let (mut reader, mut writer) = stream.into_split();
    let mut changes = shared.changes.subscribe();
    let (done, mut finished) = mpsc::unbounded_channel::<Done>();
    let mut circuit = Circuit::new(&shared.prefix);
    // The tokens this circuit holds its jogs by, per axis: they go when the circuit closes (the
    // client quit, died or was cut off), and the node then ends the jogs.
    let mut holds: HashMap<String, (String, zenoh::liveliness::LivelinessToken)> = HashMap::new();
    let client = format!("ca-{}-{}", shared.session.zid(), CIRCUITS.fetch_add(1, Ordering::Relaxed));
    let mut buffer = vec![0; 16 * 1024];
    loop {
        tokio::select! {
            _ = stopped.changed() => return Ok(()),
            read = reader.read(&mut buffer) => {
                let length = read?;
                if length == 0 {
                    return Ok(());
                }
                let handled = circuit.handle_input(&buffer[..length], &*shared.values());
                handled.map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))?;
            }
            change = changes.recv() => match change {
                Ok(Change::Field(axis, field)) => circuit.handle_change(&axis, field, &*shared.values()),
                Ok(Change::Gone(axis)) => circuit.axis_gone(&axis),
                Err(broadcast::error::RecvError::Lagged(missed)) => {
                    tracing::warn!(missed, "a circuit fell behind the network's changes: posting every monitor again");
                    circuit.repost(&*shared.values());
                }
                Err(broadcast::error::RecvError::Closed) => return Ok(()),
            },
            Some((answer, outcome)) = finished.recv() => circuit.write_done(answer, outcome),
        }
        while let Some(request) = circuit.poll_request() {
            match request {
                Request::Fetch { axis } => shared.fetch(axis),
                Request::Write { pv, text, wait, hold, answer } => {
                    let hold = match hold {
                        true => {
                            // A circuit that holds a jog must notice a client cut off within a
                            // second, not TCP's quarter of an hour.
                            watch_closely(writer.as_ref())?;
                            Some(hold_token(shared, &mut holds, &pv.axis, &client).await?)
                        }
                        false => None,
                    };
                    shared.write(Write { pv, text, wait, hold, answer }, done.clone()).await;
                }
            }
        }
        while let Some(bytes) = circuit.poll_transmit() {
            writer.write_all(&bytes).await?;
        }
    }
}

/// The key of the token a circuit holds an axis's jogs by, declared at its first jog.
async fn hold_token(
    shared: &Shared,
    holds: &mut HashMap<String, (String, zenoh::liveliness::LivelinessToken)>,
    axis: &str,
    client: &str,
) -> std::io::Result<String> {
    if let Some((key, _)) = holds.get(axis) {
        return Ok(key.clone());
    }
    let key = shared.layout.hold(axis, client);
    let token = shared.session.liveliness().declare_token(&key).await.map_err(std::io::Error::other)?;
    holds.insert(axis.to_string(), (key.clone(), token));
    Ok(key)
}

/// Keep-alive probes after a second of silence, and at most half a second for sent data to be
/// acknowledged: a client cut off (no FIN, no RST) is then dropped, and its holds with it.
fn watch_closely(stream: &tokio::net::TcpStream) -> std::io::Result<()> {
    let socket = socket2::SockRef::from(stream);
    let probes = socket2::TcpKeepalive::new()
        .with_time(Duration::from_secs(1))
        .with_interval(Duration::from_secs(1))
        .with_retries(1);
    socket.set_tcp_keepalive(&probes)?;
    socket.set_tcp_user_timeout(Some(Duration::from_millis(500)))
}

/// The UDP socket searches come to, shared as EPICS servers share it (SO_REUSEADDR): an IOC on
/// the same host and port still gets its broadcast searches.
fn search_socket(address: SocketAddr) -> std::io::Result<tokio::net::UdpSocket> {
    let socket = socket2::Socket::new(socket2::Domain::for_address(address), socket2::Type::DGRAM, None)?;
    socket.set_reuse_address(true)?;
    socket.set_nonblocking(true)?;
    socket.bind(&address.into())?;
    tokio::net::UdpSocket::from_std(socket.into())
}
