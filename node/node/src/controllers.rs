//! Controllers on their connections: a thin tokio runner around each sans-IO `Controller`
//! (zmotor-controllers). It opens the TCP socket or serial port when the controller asks (one
//! socket for each of the controller's lanes, where it has several), moves
//! bytes both ways, turns the wall clock into timeouts, hands each channel's status to its axis
//! and the axes' driver commands to the controller. Nothing here decides anything.

use std::collections::BTreeMap;
use std::future::Future;
use std::pin::Pin;
use std::task::Poll;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt, ReadBuf, ReadHalf, WriteHalf};
use tokio::sync::{mpsc, oneshot, watch};
use zenoh::bytes::Encoding;
use zenoh::Session;
use zmotor_controllers::{AnyController, ControllerEvent, Lane, ProtocolOptions, ScriptSource};
use zmotor_controllers::{ControllerSpec, FlowControl, Parity, SerialSettings, Transport};
use zmotor_controllers::{ControllerUnit, Finding, Scale, ScaleCheck, VendorError};
use zmotor_controllers::{KeyAccess, KeyName, KeyReply, KeyValue};
use zmotor_core::DeviceStatus;
use zmotor_core::Instant;
use zmotor_deploy::ScriptFiles;
use zmotor_msgs::DriverCommand;
use zmotor_msgs::{decode_scalar, Field, KeyLayout, PayloadEncoding, Value};

/// Longest wait for a TCP connection or a serial port to open.
const OPEN_TIMEOUT: Duration = Duration::from_secs(3);

/// A byte stream to a controller.
trait Io: AsyncRead + AsyncWrite + Unpin + Send {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send> Io for T {}

type Stream = Box<dyn Io>;
type Opening = Pin<Box<dyn Future<Output = std::io::Result<Vec<Stream>>> + Send>>;

/// A controller's axes, once they exist: where its statuses and its messages go.
pub(crate) trait ControllerAxes: Send {
    /// The status of `channel`, after `motions` motion commands received.
    fn status(&mut self, channel: usize, status: DeviceStatus, motions: u64);
    /// A controller error, or a command not sent, for `channel` (None: every channel).
    fn message(&mut self, channel: Option<usize>, message: &str);
    /// Every axis in motion stops, as its record's STOP stops it (a record whose motion the
    /// controller alone stopped would retry to reach its target).
    fn stop_motion(&mut self);
}

/// What reaches a controller's runner.
pub(crate) enum ToController {
    /// A driver command of the axis on `channel`.
    Command { channel: usize, command: DriverCommand },
    /// The axes exist: statuses and messages go to them from now on.
    Attach(Box<dyn ControllerAxes>),
    /// Read the controller's script again (its reload key was written).
    Reload,
}

/// How an axis reaches its controller.
#[derive(Clone)]
pub(crate) struct ControllerPort {
    pub(crate) sender: mpsc::UnboundedSender<ToController>,
    pub(crate) channel: usize,
}

impl ControllerPort {
    pub(crate) fn send(&self, command: DriverCommand) {
        let _ = self.sender.send(ToController::Command { channel: self.channel, command });
    }
}

/// A controller being run: how to reach it, and what it reported by the time its axes boot.
pub(crate) struct RunningController {
    pub(crate) name: String,
    pub(crate) sender: mpsc::UnboundedSender<ToController>,
    /// The statuses of its channels once it is up, or none if it could not be reached.
    pub(crate) first: oneshot::Receiver<BTreeMap<usize, DeviceStatus>>,
    pub(crate) task: tokio::task::JoinHandle<()>,
    /// It runs a script, which its reload key re-reads.
    pub(crate) scripted: bool,
}

/// The node's key space, as a script reaches it (`epics.get`/`epics.put`).
#[derive(Clone)]
pub(crate) struct KeySpace {
    pub(crate) session: Session,
    pub(crate) layout: KeyLayout,
}

impl KeySpace {
    /// Carry out a script's key access (`Lane::Keys` bytes), answering within `within`.
    async fn carry_out(&self, bytes: &[u8], within: Duration) -> KeyReply {
        let Some(access) = KeyAccess::decode(bytes) else {
            return KeyReply::Failed("not a key access".into());
        };
        let (key, payload) = match &access {
            KeyAccess::Get(name) => (self.read_key(name), None),
            KeyAccess::Put(name, value) => {
                let text = match value {
                    KeyValue::Number(n) => n.to_string(),
                    KeyValue::Text(text) => text.clone(),
                };
                (self.write_key(name), Some(text))
            }
        };
        let mut get = self.session.get(&key).timeout(within);
        if let Some(text) = payload {
            get = get.payload(text).encoding(Encoding::TEXT_PLAIN);
        }
        let replies = match get.await {
            Ok(replies) => replies,
            Err(e) => return KeyReply::Failed(format!("{key}: {e}")),
        };
        let Ok(reply) = replies.recv_async().await else {
            return KeyReply::Failed(format!("nothing answers for {key}"));
        };
        match (reply.result(), access) {
            (Err(refused), _) => {
                KeyReply::Failed(format!("{key}: {}", String::from_utf8_lossy(&refused.payload().to_bytes())))
            }
            (Ok(_), KeyAccess::Put(_, value)) => KeyReply::Value(value),
            (Ok(sample), KeyAccess::Get(_)) => {
                let encoding = PayloadEncoding::from_mime(&sample.encoding().to_string());
                match decode_scalar(&sample.payload().to_bytes(), encoding) {
                    Ok(Value::Int(n)) => KeyReply::Value(KeyValue::Number(n as f64)),
                    Ok(Value::Float(x)) => KeyReply::Value(KeyValue::Number(x)),
                    Ok(Value::Text(text)) => KeyReply::Value(KeyValue::Text(text)),
                    Err(e) => KeyReply::Failed(format!("{key}: {e}")),
                }
            }
        }
    }

    /// Where a read of `name` goes: a catalogue field's key, or the key named.
    fn read_key(&self, name: &KeyName) -> String {
        match name {
            KeyName::Field { record, field } => match Field::from_name(field) {
                Some(field) => self.layout.field(record, field),
                None => name.key(self.layout.prefix()),
            },
            KeyName::Key(key) => key.clone(),
        }
    }

    /// Where a confirmed write of `name` goes: a catalogue field's write key (answered with or
    /// without access control), or the key named.
    fn write_key(&self, name: &KeyName) -> String {
        match name {
            KeyName::Field { record, field } => match Field::from_name(field) {
                Some(field) => self.layout.write(record, field),
                None => name.key(self.layout.prefix()),
            },
            KeyName::Key(key) => key.clone(),
        }
    }
}

/// Start the runner of one controller; it ends when `stopped` turns true. Its script, if it has
/// one, reads and writes `keys`.
pub(crate) fn start(spec: ControllerSpec, stopped: watch::Receiver<bool>, keys: KeySpace) -> RunningController {
    let (sender, commands) = mpsc::unbounded_channel();
    let (key_answers, answered) = mpsc::unbounded_channel();
    let (first_in, first) = oneshot::channel();
    let origin = tokio::time::Instant::now();
    let controller = spec.protocol.controller(&spec.options, spec.config.clone(), Instant::ZERO);
    let name = spec.name.clone();
    let scripted = spec.options.script.is_some();
    let mut runner = Runner {
        name: spec.name,
        transport: spec.transport,
        lanes: controller.lanes(),
        controller,
        options: spec.options,
        origin,
        readers: Vec::new(),
        writers: Vec::new(),
        opening: None,
        axes: None,
        latest: BTreeMap::new(),
        unheard: Vec::new(),
        first: Some(first_in),
        write_timeout: spec.config.timeout,
        was_up: false,
        unreachable: false,
        repeats: Repeats::default(),
        keys,
        key_answers,
    };
    let task = tokio::spawn(async move { runner.run(commands, answered, stopped).await });
    RunningController { name, sender, first, task, scripted }
}

struct Runner {
    name: String,
    transport: Transport,
    controller: Box<dyn AnyController>,
    /// What its protocol was given (a script's files are read again from its path).
    options: ProtocolOptions,
    origin: tokio::time::Instant,
    /// The controller's lanes; the connections below are theirs, in the same order.
    lanes: Vec<Lane>,
    readers: Vec<ReadHalf<Stream>>,
    writers: Vec<WriteHalf<Stream>>,
    opening: Option<Opening>,
    axes: Option<Box<dyn ControllerAxes>>,
    /// Each channel's latest status (and motions received), for axes not attached yet.
    latest: BTreeMap<usize, (DeviceStatus, u64)>,
    /// Messages for axes not attached yet (a scale found wrong at the first connection).
    unheard: Vec<(Option<usize>, String)>,
    first: Option<oneshot::Sender<BTreeMap<usize, DeviceStatus>>>,
    /// How long a write may take.
    write_timeout: std::time::Duration,
    was_up: bool,
    /// Opening the connection failed, and has not succeeded since.
    unreachable: bool,
    /// The controller's last error message and its repeats, so the log names it once.
    repeats: Repeats,
    keys: KeySpace,
    /// Where the answers of key accesses carried out meanwhile come back.
    key_answers: mpsc::UnboundedSender<KeyReply>,
}

/// A controller's error named once, its repeats counted: a move the controller refuses is
/// refused again at each of the record's retries, and the log says so in two lines, not ten.
#[derive(Debug, Default)]
struct Repeats {
    /// The last error: its channel (None: every channel) and its line.
    last: Option<(Option<usize>, String)>,
    repeated: u32,
}

/// What an error is to the log.
#[derive(Debug, PartialEq)]
enum Noted {
    /// New: log it; the one before it came `repeated` more times (0: none).
    New { before: Option<(String, u32)> },
    /// The same as the last: counted.
    Repeat,
}

impl Repeats {
    fn note(&mut self, channel: Option<usize>, line: &str) -> Noted {
        if self.last.as_ref().is_some_and(|(c, l)| *c == channel && l == line) {
            self.repeated += 1;
            return Noted::Repeat;
        }
        let before =
            self.last.replace((channel, line.to_string())).map(|(_, l)| (l, std::mem::take(&mut self.repeated)));
        Noted::New { before: before.filter(|(_, n)| *n > 0) }
    }

    /// `channel` reported without a problem: the last error, if it was that channel's, is over;
    /// its repeats not said yet.
    fn settle(&mut self, channel: usize) -> Option<(String, u32)> {
        if !self.last.as_ref().is_some_and(|(c, _)| c.is_none_or(|c| c == channel)) {
            return None;
        }
        let repeated = std::mem::take(&mut self.repeated);
        self.last.take().map(|(_, line)| (line, repeated)).filter(|(_, n)| *n > 0)
    }
}

impl Runner {
    fn now(&self) -> Instant {
        Instant::after(self.origin.elapsed())
    }

    async fn run(
        &mut self,
        mut commands: mpsc::UnboundedReceiver<ToController>,
        mut key_answers: mpsc::UnboundedReceiver<KeyReply>,
        mut stopped: watch::Receiver<bool>,
    ) {
        let mut buffer = vec![0u8; 4096];
        self.controller.handle_timeout(self.now());
        loop {
            self.drain().await;
            let deadline = self.controller.poll_timeout().map(|t| self.origin + t.since_origin());
            tokio::select! {
                Some(message) = commands.recv() => match message {
                    ToController::Command { channel, command } => self.controller.command(self.now(), channel, &command),
                    ToController::Attach(mut axes) => {
                        for (channel, (status, motions)) in std::mem::take(&mut self.latest) {
                            axes.status(channel, status, motions);
                        }
                        for (channel, message) in std::mem::take(&mut self.unheard) {
                            axes.message(channel, &message);
                        }
                        self.axes = Some(axes);
                    }
                    ToController::Reload => self.reload(),
                },
                Some(answer) = key_answers.recv() => {
                    self.controller.handle_input(self.now(), Lane::Keys, &answer.encode());
                }
                (lane, read) = read_any(&mut self.readers, &mut buffer) => match read {
                    Ok(n) if n > 0 => self.controller.handle_input(self.now(), self.lanes[lane], &buffer[..n]),
                    Ok(_) => self.closed("the controller closed the connection"),
                    Err(e) => self.closed(&e.to_string()),
                },
                opened = async { self.opening.as_mut().expect("guarded").await }, if self.opening.is_some() => {
                    self.opening = None;
                    match opened {
                        Ok(streams) => {
                            (self.readers, self.writers) = streams.into_iter().map(tokio::io::split).unzip();
                            self.controller.handle_connected(self.now());
                        }
                        Err(e) => {
                            // Said once; the attempts go on quietly, with a growing back-off.
                            if std::mem::replace(&mut self.unreachable, true) {
                                tracing::debug!(controller = %self.name, "cannot open {}: {e}", self.transport);
                            } else {
                                tracing::warn!(controller = %self.name, "cannot open {}: {e}; trying again", self.transport);
                            }
                            self.controller.handle_disconnected(self.now());
                            // A controller not reached at start-up: its axes boot without it.
                            self.ready();
                        }
                    }
                }
                _ = tokio::time::sleep_until(deadline.unwrap_or(self.origin)), if deadline.is_some() => {
                    self.controller.handle_timeout(self.now());
                }
                _ = stopped.changed() => return,
            }
        }
    }

    /// Write what the controller has to send, and act on its events.
    async fn drain(&mut self) {
        loop {
            while let Some(event) = self.controller.poll_event() {
                self.on_event(event);
            }
            let Some((lane, bytes)) = self.controller.poll_transmit() else { break };
            if lane == Lane::Keys {
                // Carried out meanwhile, answered before the layer's timeout.
                let (keys, answers, within) = (self.keys.clone(), self.key_answers.clone(), self.write_timeout / 2);
                tokio::spawn(async move {
                    let _ = answers.send(keys.carry_out(&bytes, within).await);
                });
                continue;
            }
            let connection = self.lanes.iter().position(|l| *l == lane);
            let Some(writer) = connection.and_then(|c| self.writers.get_mut(c)) else { continue };
            let written = async {
                writer.write_all(&bytes).await?;
                writer.flush().await
            };
            // A port that takes nothing (flow control held, a stalled peer) must not stop the
            // runner: its timeouts, reads and stops go on.
            match tokio::time::timeout(self.write_timeout, written).await {
                Ok(Ok(())) => {}
                Ok(Err(e)) => self.closed(&e.to_string()),
                Err(_) => self.closed("a write did not complete in time"),
            }
        }
        if !self.was_up && self.controller.is_up() {
            self.unreachable = false;
            tracing::info!(controller = %self.name, "{} on {}: up", self.controller.protocol(), self.transport);
            self.ready();
        }
        self.was_up = self.controller.is_up();
    }

    fn on_event(&mut self, event: ControllerEvent) {
        match event {
            ControllerEvent::Connect => {
                tracing::debug!(controller = %self.name, "opening {}", self.transport);
                self.opening = Some(open(self.transport.clone(), self.lanes.len()));
            }
            ControllerEvent::Disconnect => {
                tracing::warn!(controller = %self.name, "communication lost; its axes are in COMM alarm until it answers again");
                (self.readers, self.writers) = (Vec::new(), Vec::new());
                self.ready();
            }
            ControllerEvent::Status { channel, status, motions } => {
                if status.msta & zmotor_msgs::bits::msta::PROBLEM == 0 {
                    if let Some((before, times)) = self.repeats.settle(channel) {
                        tracing::warn!(controller = %self.name, "{before} (and {times} more times)");
                    }
                }
                match &mut self.axes {
                    Some(axes) => axes.status(channel, status, motions),
                    None => {
                        self.latest.insert(channel, (status, motions));
                    }
                }
            }
            ControllerEvent::ControllerError(VendorError { channel, code, meaning }) => {
                self.tell(channel, &format!("controller error {code}: {meaning}"), tracing::Level::ERROR);
            }
            ControllerEvent::Refused { channel, why } => {
                self.tell(Some(channel), &why.to_string(), tracing::Level::WARN)
            }
            ControllerEvent::Found(finding) => {
                let found = match finding {
                    Finding::Identity(identity) => format!("identifies itself as {identity}"),
                    Finding::Axes(names) => format!("has axes {}", names.join(", ")),
                    Finding::Travel { channel, min, max } => format!("channel {channel}: travel {min} to {max}"),
                    other => format!("{other:?}"),
                };
                tracing::info!(controller = %self.name, "{found}");
            }
            ControllerEvent::Scale { channel, scale, check } => self.scale_found(channel, &scale, &check),
            ControllerEvent::Failed { what } => tracing::warn!(controller = %self.name, "exchange failed: {what}"),
            other => tracing::debug!(controller = %self.name, "an event this runner does not act on: {other:?}"),
        }
    }

    /// A channel's scale, said at `info`; one its axis's MRES disagrees with, an error on the
    /// axis's ERR too (its motions are refused).
    fn scale_found(&mut self, channel: usize, scale: &Scale, check: &ScaleCheck) {
        let unit = match scale.unit {
            ControllerUnit::Physical { linear, rotary } => {
                format!("{} ({} on a rotary stage)", linear.name, rotary.name)
            }
            ControllerUnit::Known(unit) => unit.name.to_string(),
            ControllerUnit::Steps => "controller units".to_string(),
        };
        let step = format!("channel {channel}: one step is {} {unit}, {}", scale.units_per_step, scale.source);
        match check {
            ScaleCheck::Agrees => tracing::info!(controller = %self.name, "{step}; the axis's MRES and EGU agree"),
            ScaleCheck::Unchecked(why) => {
                tracing::info!(controller = %self.name, "{step}; not compared with the axis's MRES: {why}")
            }
            ScaleCheck::Disagrees(mismatch) => {
                tracing::error!(controller = %self.name, "channel {channel}: {mismatch}; its motions are refused");
                let message = format!("{}: {mismatch}", self.name);
                match &mut self.axes {
                    Some(axes) => axes.message(Some(channel), &message),
                    None => self.unheard.push((Some(channel), message)),
                }
            }
        }
    }

    /// A controller's error or a command not sent: on the axes' ERR every time, in the log
    /// once (at `level`) however often it repeats in a row.
    fn tell(&mut self, channel: Option<usize>, message: &str, level: tracing::Level) {
        let on = channel.map_or_else(|| "every channel".to_string(), |c| format!("channel {c}"));
        let line = format!("{on}: {message}");
        match self.repeats.note(channel, &line) {
            Noted::New { before } => {
                if let Some((before, times)) = before {
                    tracing::warn!(controller = %self.name, "{before} (and {times} more times)");
                }
                if level == tracing::Level::ERROR {
                    tracing::error!(controller = %self.name, "{line}");
                } else {
                    tracing::warn!(controller = %self.name, "{line}");
                }
            }
            Noted::Repeat => tracing::debug!(controller = %self.name, "{line} (again)"),
        }
        if let Some(axes) = &mut self.axes {
            axes.message(channel, &format!("{}: {message}", self.name));
        }
    }

    /// The script read again from its file (and the modules beside it), used once every axis
    /// in motion is stopped; a script that does not read or load changes nothing.
    fn reload(&mut self) {
        let Some(running) = self.options.script.clone() else { return };
        let read = ScriptFiles::read(std::path::Path::new(&running.path));
        let outcome = read.map_err(|e| format!("cannot read the script again: {e}")).and_then(|files| {
            let script = ScriptSource { text: files.text, modules: files.modules, ..running };
            let options = ProtocolOptions { script: Some(script), ..self.options.clone() };
            self.controller.reload(self.now(), &options).map_err(|e| e.to_string())?;
            if let Some(axes) = &mut self.axes {
                axes.stop_motion();
            }
            self.options = options;
            Ok(())
        });
        match outcome {
            Ok(()) => {
                let path = self.options.script.as_ref().map_or("", |s| s.path.as_str());
                tracing::info!(controller = %self.name, "{path} reloaded; axes in motion are stopped first");
            }
            Err(e) => self.tell(None, &format!("reload refused: {e}"), tracing::Level::WARN),
        }
    }

    /// The connection failed under us.
    fn closed(&mut self, why: &str) {
        tracing::warn!(controller = %self.name, "{}: {why}", self.transport);
        (self.readers, self.writers) = (Vec::new(), Vec::new());
        self.controller.handle_disconnected(self.now());
    }

    /// The axes may boot: on the statuses known so far (none if the controller was not reached).
    fn ready(&mut self) {
        if let Some(first) = self.first.take() {
            let known = if self.controller.is_up() {
                self.latest.iter().map(|(channel, (status, _))| (*channel, *status)).collect()
            } else {
                BTreeMap::new()
            };
            let _ = first.send(known);
        }
    }
}

/// Read from whichever connection has bytes first: its index and what was read. Never ready
/// without a connection.
async fn read_any(readers: &mut [ReadHalf<Stream>], buffer: &mut [u8]) -> (usize, std::io::Result<usize>) {
    if readers.is_empty() {
        return std::future::pending().await;
    }
    std::future::poll_fn(|context| {
        for (index, reader) in readers.iter_mut().enumerate() {
            let mut read = ReadBuf::new(buffer);
            if let Poll::Ready(result) = Pin::new(reader).poll_read(context, &mut read) {
                return Poll::Ready((index, result.map(|()| read.filled().len())));
            }
        }
        Poll::Pending
    })
    .await
}

/// Open `connections` connections on the transport (a serial line has one), each within
/// `OPEN_TIMEOUT`.
fn open(transport: Transport, connections: usize) -> Opening {
    Box::pin(async move {
        let mut streams = Vec::with_capacity(connections);
        for opened in 0..connections {
            let opening = async {
                match &transport {
                    Transport::Tcp { address } => {
                        let stream = tokio::net::TcpStream::connect(address.as_str()).await?;
                        // Requests are small and each waits for its reply: no Nagle delay.
                        stream.set_nodelay(true)?;
                        Ok(Some(Box::new(stream) as Stream))
                    }
                    Transport::Serial(_) if opened > 0 => Err(std::io::Error::new(
                        std::io::ErrorKind::Unsupported,
                        "the protocol needs several connections, and a serial line is one",
                    )),
                    Transport::Serial(settings) => open_serial(settings).map(Some),
                    Transport::None => Ok(None),
                }
            };
            let stream = tokio::time::timeout(OPEN_TIMEOUT, opening)
                .await
                .unwrap_or_else(|_| Err(std::io::Error::new(std::io::ErrorKind::TimedOut, "no answer in time")))?;
            streams.extend(stream);
        }
        Ok(streams)
    })
}

fn open_serial(settings: &SerialSettings) -> std::io::Result<Stream> {
    use tokio_serial::SerialPortBuilderExt;
    let port = tokio_serial::new(&settings.device, settings.baud)
        .parity(match settings.parity {
            Parity::None => tokio_serial::Parity::None,
            Parity::Odd => tokio_serial::Parity::Odd,
            Parity::Even => tokio_serial::Parity::Even,
        })
        .data_bits(match settings.data_bits {
            5 => tokio_serial::DataBits::Five,
            6 => tokio_serial::DataBits::Six,
            7 => tokio_serial::DataBits::Seven,
            _ => tokio_serial::DataBits::Eight,
        })
        .stop_bits(if settings.stop_bits == 2 { tokio_serial::StopBits::Two } else { tokio_serial::StopBits::One })
        .flow_control(match settings.flow_control {
            FlowControl::None => tokio_serial::FlowControl::None,
            FlowControl::Software => tokio_serial::FlowControl::Software,
            FlowControl::Hardware => tokio_serial::FlowControl::Hardware,
        })
        .open_native_async()
        .map_err(std::io::Error::from)?;
    Ok(Box::new(port))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_repeated_error_is_named_once_and_counted() {
        let mut repeats = Repeats::default();
        let five = "channel 1: error 5";
        assert_eq!(repeats.note(Some(1), five), Noted::New { before: None });
        assert_eq!(repeats.note(Some(1), five), Noted::Repeat);
        assert_eq!(repeats.settle(2), None, "another channel's good status ends nothing");
        assert_eq!(repeats.note(Some(1), five), Noted::Repeat);
        assert_eq!(repeats.note(Some(2), "channel 2: error 7"), Noted::New { before: Some((five.into(), 2)) });
        assert_eq!(repeats.settle(2), None, "error 7 came once");
        assert_eq!(repeats.note(Some(2), "channel 2: error 7"), Noted::New { before: None }, "new after a good answer");
        assert_eq!(repeats.note(Some(2), "channel 2: error 7"), Noted::Repeat);
        assert_eq!(repeats.settle(2), Some(("channel 2: error 7".into(), 1)));
    }
}
