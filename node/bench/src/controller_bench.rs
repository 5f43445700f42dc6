//! The controllers' figures of `zmotor bench`, per protocol against its emulator (played here,
//! as the hardware would be, by `zmotor_sim_controller::Emulated`), over the transport of the
//! vendor's ready launch file (TCP, or for the SMC100 a pseudo-terminal carrying bytes at the
//! controller's 57,600 baud), all through the production controller layer
//! (zmotor-controllers' `Controller`, as a node runs it): requests a second while status
//! refreshes of one axis follow each other, the time of the controller's own full poll of 1 and
//! 8 axes (as many as the controller has, if fewer), and the delay from the emulated stage's end
//! of motion to DMOV 1 at a client, beside the moving-poll period. That last one runs the ready
//! launch file in a node process of its own, with the client in this process.

use crate::process::{client_when_ready, Programs};
use crate::stats::Percentiles;
use crate::Error;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use zenoh::Session;
use zmotor_controllers::{AnyController, ControllerConfig, ControllerEvent, Lane, ProtocolKind, ProtocolOptions};
use zmotor_controllers::{SerialSettings, Transport};
use zmotor_emulators::{Faults, Model};
use zmotor_msgs::decode_cbor_value;
use zmotor_msgs::DriverCommand;
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
    /// For a family a script drives: its script, its emulator, whether it homes.
    script: Option<ReadyScript>,
}

/// The script of a script-driven family's ready launch file.
struct ReadyScript {
    /// The script's path as the launch file names it.
    named: &'static str,
    text: &'static str,
    model: Model,
    /// The launch file's channel (the script's `AXIS`) of the axis moved.
    channel: usize,
    /// The emulator's number for the script's channel c is c + this (AXIS 0 is axis 1).
    first_axis: usize,
    homes: bool,
}

/// A native protocol's ready launch file (no script).
const fn native(
    kind: ProtocolKind,
    launch: &'static str,
    reach: Reach,
    axis: &'static str,
    channel: usize,
    targets: [f64; 2],
) -> Ready {
    Ready { kind, launch, reach, axis, channel, targets, script: None }
}

/// A script-driven family's ready launch file, its axis on the script's channel `script.channel`.
const fn scripted(
    launch: &'static str,
    reach: Reach,
    axis: &'static str,
    targets: [f64; 2],
    script: ReadyScript,
) -> Ready {
    let channel = script.channel;
    Ready { kind: ProtocolKind::Script, launch, reach, axis, channel, targets, script: Some(script) }
}

impl Ready {
    /// The name its figures go by.
    fn name(&self) -> &'static str {
        match &self.script {
            Some(script) => script.model.protocol(),
            None => self.kind.name(),
        }
    }

    /// The emulated model of its controller.
    fn model(&self) -> Result<Model, Error> {
        match &self.script {
            Some(script) => Ok(script.model),
            None => {
                Model::speaking(self.kind.name()).ok_or_else(|| format!("{} has no emulator", self.kind.name()).into())
            }
        }
    }

    /// The emulator's number of the launch file's channel `channel`.
    fn emulated(&self, channel: usize) -> usize {
        channel + self.script.as_ref().map_or(0, |s| s.first_axis)
    }

    /// Its launch file in `dir`, the controller reached at `here` instead of where the file
    /// names it, its script (if any) beside it.
    fn write_launch(&self, dir: &std::path::Path, named: &str, here: &str) -> Result<std::path::PathBuf, Error> {
        let mut text = if named.is_empty() { self.launch.to_string() } else { self.launch.replace(named, here) };
        if let Some(script) = &self.script {
            let file = script.named.rsplit('/').next().unwrap_or(script.named);
            std::fs::create_dir_all(dir.join("scripts"))?;
            std::fs::write(dir.join("scripts").join(file), script.text)?;
            text = text.replace(script.named, &format!("scripts/{file}"));
        }
        let path = dir.join("launch.toml");
        std::fs::write(&path, text)?;
        Ok(path)
    }

    /// What its protocol is given: a script's, as its launch file configures it.
    fn options(&self, dir: &std::path::Path) -> Result<ProtocolOptions, Error> {
        if self.script.is_none() {
            return Ok(ProtocolOptions::default());
        }
        let file = self.write_launch(dir, "", "")?;
        let deployment = zmotor_deploy::Launch::load(&file)?.deployment(None)?;
        Ok(deployment.contents.controllers[0].options.clone())
    }
}

const READY: [Ready; 18] = [
    native(
        ProtocolKind::AcsMcb4b,
        include_str!("../../../launch/acs-mcb4b.toml"),
        Reach::Tcp("127.0.0.1:4001"),
        "acs1",
        0,
        [1.0, 1.5],
    ),
    native(
        ProtocolKind::NewportSmc100,
        include_str!("../../../launch/newport-smc100.toml"),
        Reach::Pty("/tmp/zmotor-smc100"),
        "smc1",
        1,
        [1.0, 1.5],
    ),
    native(
        ProtocolKind::PiGcs2,
        include_str!("../../../launch/pi-gcs2.toml"),
        Reach::Tcp("127.0.0.1:50000"),
        "pi1",
        1,
        [1.0, 1.5],
    ),
    native(
        ProtocolKind::SmaractMcs2,
        include_str!("../../../launch/smaract-mcs2.toml"),
        Reach::Tcp("127.0.0.1:55551"),
        "mcs0",
        0,
        [10.0, 30.0],
    ),
    native(
        ProtocolKind::Phytron,
        include_str!("../../../launch/phytron.toml"),
        Reach::Tcp("127.0.0.1:22222"),
        "phy11",
        11,
        [1.0, 1.5],
    ),
    native(
        ProtocolKind::Pmac,
        include_str!("../../../launch/pmac.toml"),
        Reach::Tcp("127.0.0.1:1025"),
        "pmac1",
        1,
        [1.0, 1.5],
    ),
    native(
        ProtocolKind::NewportEsp300,
        include_str!("../../../launch/newport-esp300.toml"),
        Reach::Pty("/tmp/zmotor-esp300"),
        "esp1",
        1,
        [1.0, 1.5],
    ),
    native(
        ProtocolKind::Galil,
        include_str!("../../../launch/galil.toml"),
        Reach::Tcp("127.0.0.1:2323"),
        "galA",
        0,
        [1.0, 1.5],
    ),
    native(
        ProtocolKind::McLennanPm304,
        include_str!("../../../launch/mclennan-pm304.toml"),
        Reach::Pty("/tmp/zmotor-pm304"),
        "pm1",
        1,
        [1.0, 1.5],
    ),
    native(
        ProtocolKind::NewportXps,
        include_str!("../../../launch/newport-xps.toml"),
        Reach::Tcp("127.0.0.1:5001"),
        "xps1",
        1,
        [1.0, 1.5],
    ),
    native(
        ProtocolKind::ImsMdrive,
        include_str!("../../../launch/ims-mdrive.toml"),
        Reach::Pty("/tmp/zmotor-mdrive"),
        "mdrive1",
        1,
        [1.0, 1.5],
    ),
    native(
        ProtocolKind::OmsMaxnet,
        include_str!("../../../launch/oms-maxnet.toml"),
        Reach::Tcp("127.0.0.1:2023"),
        "omsX",
        0,
        [1.0, 1.5],
    ),
    scripted(
        include_str!("../../../launch/kohzu-sc.toml"),
        Reach::Pty("/tmp/zmotor-kohzu"),
        "kohzu1",
        [1.0, 1.5],
        ReadyScript {
            named: "scripts/kohzu_sc.lua",
            text: include_str!("../../../launch/scripts/kohzu_sc.lua"),
            model: Model::KohzuSc,
            channel: 0,
            first_axis: 1,
            homes: true,
        },
    ),
    scripted(
        include_str!("../../../launch/micronix-mmc.toml"),
        Reach::Pty("/tmp/zmotor-mmc"),
        "mmc1",
        [10.0, 20.0],
        ReadyScript {
            named: "scripts/micronix_mmc.lua",
            text: include_str!("../../../launch/scripts/micronix_mmc.lua"),
            model: Model::MicronixMmc,
            channel: 0,
            first_axis: 1,
            homes: true,
        },
    ),
    scripted(
        include_str!("../../../launch/newfocus-8742.toml"),
        Reach::Tcp("127.0.0.1:2323"),
        "pico1",
        [10.0, 20.0],
        ReadyScript {
            named: "scripts/newfocus_8742.lua",
            text: include_str!("../../../launch/scripts/newfocus_8742.lua"),
            model: Model::NewFocus8742,
            channel: 0,
            first_axis: 1,
            homes: false,
        },
    ),
    scripted(
        include_str!("../../../launch/piezojena-nv40.toml"),
        Reach::Pty("/tmp/zmotor-nv40"),
        "piezo0",
        // Moves of 24 µm at least: 2.4 ms at the NV40's slew, long enough to be seen moving.
        [10.0, 90.0],
        ReadyScript {
            named: "scripts/piezojena_nv40.lua",
            text: include_str!("../../../launch/scripts/piezojena_nv40.lua"),
            model: Model::PiezojenaNv40,
            channel: 0,
            first_axis: 0,
            homes: false,
        },
    ),
    scripted(
        include_str!("../../../launch/faulhaber-mc.toml"),
        Reach::Pty("/tmp/zmotor-faulhaber"),
        "fau1",
        [1.0, 1.5],
        ReadyScript {
            named: "scripts/faulhaber_mc.lua",
            text: include_str!("../../../launch/scripts/faulhaber_mc.lua"),
            model: Model::FaulhaberMc,
            channel: 1,
            first_axis: 0,
            homes: true,
        },
    ),
    scripted(
        include_str!("../../../launch/vmc.toml"),
        Reach::Tcp("127.0.0.1:31337"),
        "vmc1",
        [1.0, 1.5],
        ReadyScript {
            named: "../node/controllers/tests/scripts/motorScriptMotor/vmc.lua",
            text: include_str!("../../controllers/tests/scripts/motorScriptMotor/vmc.lua"),
            model: Model::Vmc,
            channel: 0,
            first_axis: 1,
            homes: false,
        },
    ),
];

/// What one protocol measured.
pub(crate) struct ProtocolFigures {
    pub(crate) name: &'static str,
    /// The line measured on: tcp, or a serial line at its speed.
    pub(crate) line: String,
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
        figures.push(measured.map_err(|e| format!("{}: {e}", ready.name()))?);
    }
    Ok(figures)
}

async fn measure(programs: &Programs, ready: &Ready, window: f64, moves: usize) -> Result<ProtocolFigures, Error> {
    let kind = ready.kind;
    let many = up_to_eight_channels(ready);
    let model = ready.model()?;
    let channels = many.iter().max().map_or(1, |c| ready.emulated(*c) + 1);
    let dir = tempfile::tempdir_in(&programs.dir)?;
    let options = ready.options(dir.path())?;
    // Over the transport its ready launch file uses: TCP, or the serial line at its speed.
    let (emulated, transport) = match ready.reach {
        Reach::Tcp(_) => {
            let emulated = Emulated::new(model, channels, Faults::default(), None);
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
            let address = listener.local_addr()?.to_string();
            let serving = emulated.clone();
            tokio::spawn(async move { serving.serve_tcp(listener).await });
            (emulated, Transport::Tcp { address })
        }
        Reach::Pty(_) => {
            let baud = model.factory_baud();
            let emulated = Emulated::new(model, channels, Faults::default(), Some(baud));
            let path = dir.path().join("tty");
            let (master, slave) = pseudo_terminal(&path)?;
            let serving = emulated.clone();
            tokio::spawn(async move {
                let _slave = slave;
                let mut connection: Option<Box<dyn Io>> = Some(Box::new(master));
                serving.serve(&mut connection).await
            });
            let device = path.to_string_lossy().into_owned();
            (emulated, Transport::Serial(SerialSettings::eight_n_one(&device, baud)))
        }
    };
    let window = Duration::from_secs_f64(window);
    let mut one = Driven::connect(kind, &options, &transport, &many[..1]).await?;
    let (round_trips, elapsed) = one.refresh_for(many[0], window).await?;
    let poll_one = one.poll_time().await?;
    drop(one);
    let mut all = Driven::connect(kind, &options, &transport, &many).await?;
    let poll_many = (many.len(), all.poll_time().await?);
    drop(all);
    drop(emulated);
    let (end_to_done, moving_poll) = end_of_motion_to_done(programs, ready, moves).await?;
    Ok(ProtocolFigures {
        name: ready.name(),
        line: match transport {
            Transport::Serial(settings) => format!("serial {} baud", settings.baud),
            Transport::Tcp { .. } => "tcp".into(),
            Transport::None => "none".into(),
        },
        round_trips_per_s: round_trips as f64 / elapsed.as_secs_f64(),
        poll_one,
        poll_many,
        end_to_done,
        moving_poll,
    })
}

/// The first eight channels the ready file's protocol numbers and its emulator has (fewer if
/// it has fewer).
fn up_to_eight_channels(ready: &Ready) -> Vec<usize> {
    let Ok(model) = ready.model() else { return Vec::new() };
    let mut probe = model.emulator(100);
    let numbered = |c: &usize| ready.kind.check_channel(*c).is_ok();
    (0..100).filter(numbered).filter(|&c| probe.axis(ready.emulated(c)).is_some()).take(8).collect()
}

/// The production controller layer (zmotor-controllers' `Controller`, as a node runs it) over
/// one connection, its bytes moved here; every request it writes counted.
struct Driven {
    controller: Box<dyn AnyController>,
    stream: Box<dyn Io>,
    channels: Vec<usize>,
    origin: Instant,
    written: usize,
    /// When the first request was written since `poll_time` last cleared it.
    first_write: Option<Instant>,
}

/// A reopened serial line is quiet once nothing came for this long (over 100 characters at
/// 9,600 baud).
const QUIET_LINE: Duration = Duration::from_millis(120);

/// The controller polls its channels this often, at rest as in motion.
const POLL_PERIOD: Duration = Duration::from_millis(100);

impl Driven {
    /// Connected to the emulator at `transport` and initialised, for `channels`.
    async fn connect(
        kind: ProtocolKind,
        options: &ProtocolOptions,
        transport: &Transport,
        channels: &[usize],
    ) -> Result<Self, Error> {
        let stream: Box<dyn Io> = match transport {
            Transport::Tcp { address } => {
                let stream = tokio::net::TcpStream::connect(address).await?;
                stream.set_nodelay(true)?;
                Box::new(stream)
            }
            Transport::Serial(settings) => {
                use tokio_serial::SerialPortBuilderExt;
                let mut port: Box<dyn Io> =
                    Box::new(tokio_serial::new(&settings.device, settings.baud).open_native_async()?);
                // The line reopened: what a former connection's last exchange left on it is
                // read and dropped first, or it would pass for the first reply.
                let mut stale = [0u8; 256];
                while let Ok(Ok(n)) = tokio::time::timeout(QUIET_LINE, port.read(&mut stale)).await {
                    if n == 0 {
                        break;
                    }
                }
                port
            }
            Transport::None => return Err("a controller without a connection has no round trips to time".into()),
        };
        let config = ControllerConfig {
            idle_poll: POLL_PERIOD,
            moving_poll: POLL_PERIOD,
            ..ControllerConfig::for_channels(channels.to_vec())
        };
        let controller = kind.controller(options, config, zmotor_core::Instant::ZERO);
        let mut driven = Self {
            controller,
            stream,
            channels: channels.to_vec(),
            origin: Instant::now(),
            written: 0,
            first_write: None,
        };
        let now = driven.now();
        driven.controller.handle_timeout(now);
        driven.controller.handle_connected(now);
        driven.run_until(|controller, _| controller.is_up()).await?;
        Ok(driven)
    }

    fn now(&self) -> zmotor_core::Instant {
        zmotor_core::Instant::after(self.origin.elapsed())
    }

    /// Move bytes and time until `done` says so (after an event, or with none); a controller
    /// that does not get there within 10 s is an error.
    async fn run_until(
        &mut self,
        mut done: impl FnMut(&dyn AnyController, Option<&ControllerEvent>) -> bool,
    ) -> Result<(), Error> {
        let limit = Instant::now() + Duration::from_secs(10);
        let mut buffer = vec![0u8; 4096];
        loop {
            while let Some((lane, bytes)) = self.controller.poll_transmit() {
                // Only polls and status refreshes are timed here: all on the main connection.
                if lane != Lane::Main {
                    return Err(format!("a write on {lane:?}, which this bench does not open").into());
                }
                self.first_write.get_or_insert_with(Instant::now);
                self.stream.write_all(&bytes).await?;
                self.written += 1;
            }
            let mut finished = done(self.controller.as_ref(), None);
            while let Some(event) = self.controller.poll_event() {
                if let ControllerEvent::Failed { what } = &event {
                    return Err(format!("an exchange failed: {what}").into());
                }
                finished |= done(self.controller.as_ref(), Some(&event));
            }
            if finished {
                return Ok(());
            }
            if Instant::now() > limit {
                return Err("the controller did not get there within 10 s".into());
            }
            let due = self.controller.poll_timeout().map(|t| self.origin + t.since_origin());
            tokio::select! {
                read = self.stream.read(&mut buffer) => {
                    let n = read?;
                    if n == 0 {
                        return Err("the emulator closed the connection".into());
                    }
                    let now = self.now();
                    self.controller.handle_input(now, Lane::Main, &buffer[..n]);
                }
                _ = tokio::time::sleep_until(due.unwrap_or(limit).into()) => {
                    let now = self.now();
                    self.controller.handle_timeout(now);
                }
            }
        }
    }

    /// Status refreshes of `channel` (the record's GET_INFO), each asked once the last is
    /// answered, for `window`: the requests written and the time taken.
    async fn refresh_for(&mut self, channel: usize, window: Duration) -> Result<(usize, Duration), Error> {
        let (start, written) = (Instant::now(), self.written);
        while start.elapsed() < window {
            self.refresh(channel).await?;
        }
        Ok((self.written - written, start.elapsed()))
    }

    async fn refresh(&mut self, channel: usize) -> Result<(), Error> {
        let now = self.now();
        self.controller.command(now, channel, &DriverCommand::Poll);
        self.run_until(|_, event| matches!(event, Some(ControllerEvent::Status { channel: c, .. }) if *c == channel))
            .await
    }

    /// The median time of the controller's own full poll of its channels (batched where the
    /// protocol batches), from its first request to the last channel's status; the polls come
    /// at the controller's period, nothing else asked meanwhile.
    async fn poll_time(&mut self) -> Result<Duration, Error> {
        let mut times = Vec::new();
        for _ in 0..21 {
            // The last poll's trailing request (an error query) may still be answered: it
            // writes nothing, so the first write from here is the next poll's.
            self.first_write = None;
            let mut waiting = self.channels.clone();
            self.run_until(|_, event| {
                if let Some(ControllerEvent::Status { channel, .. }) = event {
                    waiting.retain(|c| c != channel);
                }
                waiting.is_empty()
            })
            .await?;
            let start = self.first_write.ok_or("a poll without a request")?;
            times.push(start.elapsed());
        }
        times.sort();
        Ok(times[times.len() / 2])
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
    let model = ready.model()?;
    let baud = matches!(ready.reach, Reach::Pty(_)).then(|| model.factory_baud());
    let emulated = Emulated::new(model, model.typical_channels(), Faults::default(), baud);
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
    let file = ready.write_launch(dir.path(), named, &here)?;
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
    if ready.script.as_ref().is_none_or(|s| s.homes) {
        wait_put(session, &key("HOMF"), "1").await?;
    }
    let mut delays = Vec::new();
    let [near, far] = ready.targets;
    for i in 0..moves {
        // Polls restart with every motion command (as asyn's do): moves of one length would all
        // end at the same phase of the polls. Every other move goes a length spread evenly over
        // 30–100 % of the span, the others back to the start.
        let spread = 0.3 + 0.7 * (i as f64 * 0.618_033_988_75).fract();
        let target = if i % 2 == 0 { near + (far - near) * spread } else { near };
        while dmov.try_recv().ok().flatten().is_some() {}
        let sent = Instant::now();
        session.put(key("VAL"), format!("{target:.3}")).await?;
        let end = loop {
            // A motion of a few milliseconds (a piezo's) may start and end between two looks.
            if let Some(end) = emulated.motion_end(ready.emulated(ready.channel), sent.into()) {
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
