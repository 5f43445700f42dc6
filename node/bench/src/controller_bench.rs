//! The controllers' figures of `zmotor bench`, per protocol against its emulator (played here,
//! as the hardware would be, by `zmotor_sim_controller::Emulated`): request/reply round trips per
//! second over one TCP connection, the time of a full poll of 1 and 8 axes (as many as the
//! controller has, if fewer), and the delay from the emulated stage's end of motion to DMOV 1
//! at a client, beside the moving-poll period. That last one runs the vendor's ready launch
//! file in a node process of its own, reaching the emulator over the launch file's transport
//! (a pseudo-terminal for the serial SMC100), with the client in this process.

use crate::process::{client_when_ready, Programs};
use crate::stats::Percentiles;
use crate::Error;
use std::future::Future;
use std::pin::Pin;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use zenoh::Session;
use zmotor_controllers::{Frame, Protocol, ProtocolKind, ProtocolOptions, ReplyEvent, Request, WithProtocol};
use zmotor_emulators::{Faults, Model};
use zmotor_msgs::decode_cbor_value;
use zmotor_msgs::Value;
use zmotor_sim_controller::{pseudo_terminal, Emulated, Io};

/// How a ready launch file reaches its controller.
enum Reach {
    Tcp(&'static str),
    Pty(&'static str),
}

/// A vendor's ready launch file and the axis the benchmark moves.
struct Ready {
    kind: ProtocolKind,
    launch: &'static str,
    reach: Reach,
    axis: &'static str,
    channel: usize,
    /// Where moves start, and the farthest they go, in the axis's units.
    targets: [f64; 2],
}

const READY: [Ready; 5] = [
    Ready {
        kind: ProtocolKind::AcsMcb4b,
        launch: include_str!("../../../launch/acs-mcb4b.toml"),
        reach: Reach::Tcp("127.0.0.1:4001"),
        axis: "acs1",
        channel: 0,
        targets: [1.0, 1.5],
    },
    Ready {
        kind: ProtocolKind::NewportSmc100,
        launch: include_str!("../../../launch/newport-smc100.toml"),
        reach: Reach::Pty("/tmp/zmotor-smc100"),
        axis: "smc1",
        channel: 1,
        targets: [1.0, 1.5],
    },
    Ready {
        kind: ProtocolKind::PiGcs2,
        launch: include_str!("../../../launch/pi-gcs2.toml"),
        reach: Reach::Tcp("127.0.0.1:50000"),
        axis: "pi1",
        channel: 1,
        targets: [1.0, 1.5],
    },
    Ready {
        kind: ProtocolKind::SmaractMcs2,
        launch: include_str!("../../../launch/smaract-mcs2.toml"),
        reach: Reach::Tcp("127.0.0.1:55551"),
        axis: "mcs0",
        channel: 0,
        targets: [10.0, 30.0],
    },
    Ready {
        kind: ProtocolKind::Phytron,
        launch: include_str!("../../../launch/phytron.toml"),
        reach: Reach::Tcp("127.0.0.1:22222"),
        axis: "phy11",
        channel: 11,
        targets: [1.0, 1.5],
    },
];

/// What one protocol measured.
pub(crate) struct ProtocolFigures {
    pub(crate) name: &'static str,
    pub(crate) round_trips_per_s: f64,
    pub(crate) poll_one: Duration,
    pub(crate) poll_many: (usize, Duration),
    /// End of motion → DMOV 1 at the client, µs.
    pub(crate) end_to_done: Percentiles,
    pub(crate) moving_poll: Duration,
}

/// Every protocol's figures: `window` seconds of round trips, `moves` moves for the delay.
pub(crate) async fn run(programs: &Programs, window: f64, moves: usize) -> Result<Vec<ProtocolFigures>, Error> {
    let mut figures = Vec::new();
    for ready in &READY {
        let measured = measure(programs, ready, window, moves).await;
        figures.push(measured.map_err(|e| format!("{}: {e}", ready.kind.name()))?);
    }
    Ok(figures)
}

/// Round trips and poll times of one protocol, over a connection to `address`.
struct Exchanges {
    address: String,
    channels: Vec<usize>,
    window: Duration,
}

/// Round trips in `window` (with the time they took), and the median poll of one and of all
/// the channels.
type ExchangeFigures = (usize, Duration, Duration, Duration);

impl WithProtocol for Exchanges {
    type Output = Pin<Box<dyn Future<Output = Result<ExchangeFigures, Error>> + Send>>;

    fn with<P: Protocol + 'static>(self, protocol: P) -> Self::Output {
        Box::pin(async move {
            let Exchanges { address, channels, window } = self;
            let mut exchange = Exchange::open(protocol, &address).await?;
            exchange.init(&channels).await?;
            let (round_trips, elapsed) = exchange.poll_for(&channels[..1], window).await?;
            let poll_one = exchange.poll_time(&channels[..1]).await?;
            let poll_many = exchange.poll_time(&channels).await?;
            Ok((round_trips, elapsed, poll_one, poll_many))
        })
    }
}

async fn measure(programs: &Programs, ready: &Ready, window: f64, moves: usize) -> Result<ProtocolFigures, Error> {
    let kind = ready.kind;
    let many = up_to_eight_channels(kind);
    let emulated = Emulated::new(model(kind)?, many.iter().max().map_or(1, |c| c + 1), Faults::default());
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let address = listener.local_addr()?.to_string();
    let serving = emulated.clone();
    let server = tokio::spawn(async move { serving.serve_tcp(listener).await });
    let exchanges = Exchanges { address, channels: many.clone(), window: Duration::from_secs_f64(window) };
    let (round_trips, elapsed, poll_one, poll_many) =
        kind.with_protocol(&ProtocolOptions::default(), exchanges).await?;
    let poll_many = (many.len(), poll_many);
    server.abort();
    let (end_to_done, moving_poll) = end_of_motion_to_done(programs, ready, moves).await?;
    Ok(ProtocolFigures {
        name: kind.name(),
        round_trips_per_s: round_trips as f64 / elapsed.as_secs_f64(),
        poll_one,
        poll_many,
        end_to_done,
        moving_poll,
    })
}

/// The emulated model of a protocol's controllers.
fn model(kind: ProtocolKind) -> Result<Model, Error> {
    Model::speaking(kind.name()).ok_or_else(|| format!("{} has no emulator", kind.name()).into())
}

/// The first eight channels the kind numbers and its emulator has (fewer if it has fewer).
fn up_to_eight_channels(kind: ProtocolKind) -> Vec<usize> {
    let Ok(model) = model(kind) else { return Vec::new() };
    let mut probe = model.emulator(100);
    (0..100).filter(|&c| kind.check_channel(c).is_ok() && probe.axis(c).is_some()).take(8).collect()
}

/// A protocol driven by hand over one connection: each request sent once its predecessor is
/// answered, replies parsed, follow-ups sent as the controller layer sends them.
struct Exchange<P> {
    protocol: P,
    stream: tokio::net::TcpStream,
    received: Vec<u8>,
}

impl<P: Protocol> Exchange<P> {
    async fn open(protocol: P, address: &str) -> Result<Self, Error> {
        let stream = tokio::net::TcpStream::connect(address).await?;
        stream.set_nodelay(true)?;
        Ok(Self { protocol, stream, received: Vec::new() })
    }

    async fn init(&mut self, channels: &[usize]) -> Result<usize, Error> {
        let requests = self.protocol.init(channels);
        self.carry_out(requests).await
    }

    /// Full polls of `channels` for `window`: the exchanges made and the time taken.
    async fn poll_for(&mut self, channels: &[usize], window: Duration) -> Result<(usize, Duration), Error> {
        let start = Instant::now();
        let mut exchanges = 0;
        while start.elapsed() < window {
            let requests = self.protocol.poll(channels);
            exchanges += self.carry_out(requests).await?;
        }
        Ok((exchanges, start.elapsed()))
    }

    /// The median time of a full poll of `channels`.
    async fn poll_time(&mut self, channels: &[usize]) -> Result<Duration, Error> {
        let mut times = Vec::new();
        for _ in 0..21 {
            let start = Instant::now();
            let requests = self.protocol.poll(channels);
            self.carry_out(requests).await?;
            times.push(start.elapsed());
        }
        times.sort();
        Ok(times[times.len() / 2])
    }

    /// Send `requests` one after the other, each answered one waiting for its reply; the number
    /// of exchanges (follow-ups included).
    async fn carry_out(&mut self, requests: Vec<Request<P::Step>>) -> Result<usize, Error> {
        let mut queue: std::collections::VecDeque<Request<P::Step>> = requests.into();
        let mut exchanges = 0;
        while let Some(request) = queue.pop_front() {
            self.stream.write_all(&request.bytes).await?;
            exchanges += 1;
            if !request.answered {
                continue;
            }
            let frame = self.next_frame().await?;
            let events = self.protocol.reply(&request, &frame)?;
            for event in events {
                if let ReplyEvent::FollowUp(more) = event {
                    for follow in more.into_iter().rev() {
                        queue.push_front(follow);
                    }
                }
            }
        }
        Ok(exchanges)
    }

    async fn next_frame(&mut self) -> Result<Vec<u8>, Error> {
        let mut buffer = [0u8; 4096];
        loop {
            match self.protocol.frame(&self.received) {
                Frame::Complete(n) => return Ok(self.received.drain(..n).collect()),
                Frame::Junk(n) => {
                    self.received.drain(..n);
                }
                Frame::Incomplete => {
                    let n = tokio::time::timeout(Duration::from_secs(2), self.stream.read(&mut buffer)).await??;
                    if n == 0 {
                        return Err("the emulator closed the connection".into());
                    }
                    self.received.extend_from_slice(&buffer[..n]);
                }
            }
        }
    }
}

/// Run the ready launch file in a node process against the emulator; move its axis `moves`
/// times and time, at this client, DMOV 1 after the emulated stage's end of motion.
async fn end_of_motion_to_done(
    programs: &Programs,
    ready: &Ready,
    moves: usize,
) -> Result<(Percentiles, Duration), Error> {
    let dir = tempfile::tempdir_in(&programs.dir)?;
    let model = model(ready.kind)?;
    let emulated = Emulated::new(model, model.typical_channels(), Faults::default());
    let serving = emulated.clone();
    let (named, here, server) = match ready.reach {
        Reach::Tcp(address) => {
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
            let here = listener.local_addr()?.to_string();
            (address, here, tokio::spawn(async move { serving.serve_tcp(listener).await }))
        }
        Reach::Pty(device) => {
            let path = dir.path().join("tty");
            let (master, slave) = pseudo_terminal(&path)?;
            let here = path.to_string_lossy().into_owned();
            let server = tokio::spawn(async move {
                let _slave = slave;
                let mut connection: Option<Box<dyn Io>> = Some(Box::new(master));
                Err(std::io::Error::other(serving.serve(&mut connection).await))
            });
            (device, here, server)
        }
    };
    let file = dir.path().join("launch.toml");
    std::fs::write(&file, ready.launch.replace(named, &here))?;
    let launch = zmotor_deploy::Launch::load(&file)?;
    let moving_poll = launch.deployment(None)?.contents.controllers[0].config.moving_poll;
    let (_node, endpoint) = programs.launch_file(&file)?;
    let session = client_when_ready(&endpoint).await?.session().clone();
    let result = time_moves(&session, ready, &emulated, moves).await;
    server.abort();
    session.close().await?;
    Ok((result?, moving_poll))
}

async fn time_moves(session: &Session, ready: &Ready, emulated: &Emulated, moves: usize) -> Result<Percentiles, Error> {
    let key = |field: &str| format!("motor/{}/{field}", ready.axis);
    let dmov = session.declare_subscriber(key("DMOV")).await?;
    // Up (the controller reached), then homed: some controllers move only once referenced.
    let up = Instant::now();
    while read(session, &key("SEVR")).await? != Some(0.0) {
        if up.elapsed() > Duration::from_secs(20) {
            return Err("the axis never left its alarm".into());
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    wait_put(session, &key("HOMF"), "1").await?;
    let mut delays = Vec::new();
    let [near, far] = ready.targets;
    for i in 0..moves {
        // Polls restart with every motion command (as asyn's do): moves of one length would all
        // end at the same phase of the polls. Every other move goes a length spread evenly over
        // 30–100 % of the span, the others back to the start.
        let spread = 0.3 + 0.7 * (i as f64 * 0.618_033_988_75).fract();
        let target = if i % 2 == 0 { near + (far - near) * spread } else { near };
        while dmov.try_recv().ok().flatten().is_some() {}
        session.put(key("VAL"), format!("{target:.3}")).await?;
        let sent = Instant::now();
        let end = loop {
            if let Some(end) = emulated.motion_end(ready.channel) {
                break end;
            }
            if sent.elapsed() > Duration::from_secs(5) {
                return Err(format!("move {i} to {target:.3} never reached the emulated stage").into());
            }
            tokio::time::sleep(Duration::from_micros(200)).await;
        };
        loop {
            let sample = tokio::time::timeout(Duration::from_secs(10), dmov.recv_async()).await??;
            if decode_cbor_value(&sample.payload().to_bytes()) == Ok(Value::Int(1)) {
                break;
            }
        }
        delays.push(Instant::now().saturating_duration_since(end.into_std()));
    }
    Ok(Percentiles::of(delays))
}

async fn read(session: &Session, key: &str) -> Result<Option<f64>, Error> {
    let replies = session.get(key).timeout(Duration::from_secs(2)).await?;
    let Ok(reply) = replies.recv_async().await else { return Ok(None) };
    let Ok(sample) = reply.result() else { return Ok(None) };
    Ok(decode_cbor_value(&sample.payload().to_bytes()).ok().and_then(|v| v.as_f64()))
}

async fn wait_put(session: &Session, key: &str, value: &str) -> Result<(), Error> {
    let replies = session.get(format!("{key}?wait")).payload(value).timeout(Duration::from_secs(120)).await?;
    match replies.recv_async().await?.result() {
        Ok(_) => Ok(()),
        Err(e) => Err(format!("{key} = {value}: {}", e.payload().try_to_string().unwrap_or_default()).into()),
    }
}
