//! Part 8 of the benchmark: the Channel Access front-end beside Zenoh, in the same run. The
//! demo's axis (launch/sim-axis.toml) in a node process whose launch file runs the front-end;
//! here, a CA client (the protocol of `zmotor-ca`, as caget and `caput -c` send it) and a Zenoh
//! client: a read's round trip, and a put-callback of a one-step move answered at its end.

use crate::process::{client_when_ready, Programs};
use crate::stats::Percentiles;
use crate::Error;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use zenoh::bytes::Encoding;
use zmotor_ca_proto::codec::{self, command, Header, MINOR_VERSION};

/// The figures of one run.
pub(crate) struct Figures {
    /// caget of RBV through the front-end.
    pub(crate) ca_read: Percentiles,
    /// A Zenoh `get` of RBV.
    pub(crate) zenoh_read: Percentiles,
    /// `caput -c` of a one-step move through the front-end.
    pub(crate) ca_move: Percentiles,
    /// The same move as a Zenoh `?wait` write.
    pub(crate) zenoh_move: Percentiles,
    /// pyepics's caget and put-callback, or why they were not measured.
    pub(crate) pyepics: Result<StockClient, String>,
}

/// A stock client's figures, µs.
pub(crate) struct StockClient {
    pub(crate) read: [f64; 3],
    pub(crate) move_: [f64; 3],
}

const DBR_DOUBLE: u16 = 6;
const PATIENCE: Duration = Duration::from_secs(30);

/// A CA client on one circuit.
struct CaClient {
    stream: tokio::net::TcpStream,
    received: Vec<u8>,
}

impl CaClient {
    async fn connect(port: u16) -> Result<Self, Error> {
        let since = Instant::now();
        let stream = loop {
            match tokio::net::TcpStream::connect(("127.0.0.1", port)).await {
                Ok(stream) => break stream,
                Err(_) if since.elapsed() < PATIENCE => tokio::time::sleep(Duration::from_millis(20)).await,
                Err(e) => return Err(format!("the front-end on port {port}: {e}").into()),
            }
        };
        stream.set_nodelay(true)?;
        let mut client = Self { stream, received: Vec::new() };
        client.send(Header::new(command::VERSION, 0, MINOR_VERSION.into(), 0, 0), &[]).await?;
        Ok(client)
    }

    async fn send(&mut self, header: Header, payload: &[u8]) -> Result<(), Error> {
        Ok(self.stream.write_all(&codec::encode(header, payload)).await?)
    }

    /// The next message of one of `commands` (others are passed over).
    async fn receive(&mut self, commands: &[u16]) -> Result<(Header, Vec<u8>), Error> {
        let mut buffer = [0; 4096];
        loop {
            if let Some((header, payload, used)) = codec::parse(&self.received)? {
                let payload = payload.to_vec();
                self.received.drain(..used);
                if commands.contains(&header.command) {
                    return Ok((header, payload));
                }
                continue;
            }
            let read = tokio::time::timeout(PATIENCE, self.stream.read(&mut buffer)).await??;
            if read == 0 {
                return Err("the front-end closed the circuit".into());
            }
            self.received.extend_from_slice(&buffer[..read]);
        }
    }

    /// Open a channel; its server id.
    async fn channel(&mut self, name: &str, cid: u32) -> Result<u32, Error> {
        let since = Instant::now();
        loop {
            self.send(Header::new(command::CREATE_CHAN, 0, 0, cid, MINOR_VERSION.into()), &codec::name_payload(name))
                .await?;
            let (header, _) = self.receive(&[command::CREATE_CHAN, command::CREATE_CH_FAIL]).await?;
            if header.command == command::CREATE_CHAN {
                return Ok(header.p2);
            }
            if since.elapsed() > PATIENCE {
                return Err(format!("{name} is not served").into());
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
}

/// `reads` read round trips and `moves` one-step moves each way.
pub(crate) async fn run(programs: &Programs, reads: usize, moves: usize) -> Result<Figures, Error> {
    let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
    let launch = format!("{}\n[channel_access]\nport = {port}\n", include_str!("../../../launch/sim-axis.toml"));
    let (_node, endpoint) = programs.launch("channel-access", &launch)?;
    let client = client_when_ready(&endpoint).await?;
    let session = client.session().clone();
    let mut ca = CaClient::connect(port).await?;
    let rbv = ca.channel("m1.RBV", 1).await?;
    let val = ca.channel("m1", 2).await?;

    let mut ca_read = Vec::with_capacity(reads);
    let mut zenoh_read = Vec::with_capacity(reads);
    for ioid in 0..reads as u32 {
        let start = Instant::now();
        ca.send(Header::new(command::READ_NOTIFY, DBR_DOUBLE, 1, rbv, ioid), &[]).await?;
        ca.receive(&[command::READ_NOTIFY]).await?;
        ca_read.push(start.elapsed());
        let start = Instant::now();
        let replies = session.get("motor/m1/RBV").timeout(PATIENCE).await?;
        replies.recv_async().await?.result().map_err(|e| format!("RBV: {:?}", e.payload()))?;
        zenoh_read.push(start.elapsed());
    }

    // One step (MRES 1 µm) at a time, in turn through each: answered at the end of the motion.
    let mut ca_move = Vec::with_capacity(moves);
    let mut zenoh_move = Vec::with_capacity(moves);
    let step = |n: usize| format!("{:.3}", n as f64 * 0.001);
    for i in 0..moves {
        let target: f64 = step(2 * i + 1).parse()?;
        let start = Instant::now();
        ca.send(Header::new(command::WRITE_NOTIFY, DBR_DOUBLE, 1, val, i as u32), &target.to_be_bytes()).await?;
        let (done, _) = ca.receive(&[command::WRITE_NOTIFY]).await?;
        if done.p1 != 1 {
            return Err(format!("the put-callback of VAL {target} failed (ECA {})", done.p1).into());
        }
        ca_move.push(start.elapsed());
        let start = Instant::now();
        let next = step(2 * i + 2);
        let replies = session
            .get("motor/m1/VAL?wait")
            .payload(next.as_str())
            .encoding(Encoding::TEXT_PLAIN)
            .timeout(PATIENCE)
            .await?;
        replies.recv_async().await?.result().map_err(|e| format!("VAL {next}: {:?}", e.payload()))?;
        zenoh_move.push(start.elapsed());
    }
    let pyepics = stock_client(programs, port, reads, moves).await;
    session.close().await?;
    Ok(Figures {
        pyepics,
        ca_read: Percentiles::of(ca_read),
        zenoh_read: Percentiles::of(zenoh_read),
        ca_move: Percentiles::of(ca_move),
        zenoh_move: Percentiles::of(zenoh_move),
    })
}

/// The Python that has the stock clients: `ZMOTOR_PYTHON`, or the one the test suite's setup
/// installs beside the build (`target/test-env`).
fn python(programs: &Programs) -> Option<std::path::PathBuf> {
    if let Some(python) = std::env::var_os("ZMOTOR_PYTHON") {
        return Some(python.into());
    }
    let target = programs.bench.parent()?.parent()?;
    let python = target.join("test-env/python/bin/python3");
    python.exists().then_some(python)
}

/// pyepics against the gateway on `port` (its script is `python/ca_timing.py`).
async fn stock_client(programs: &Programs, port: u16, reads: usize, moves: usize) -> Result<StockClient, String> {
    let Some(python) = python(programs) else {
        return Err("no Python with pyepics: tests/run installs one in target/test-env, or set ZMOTOR_PYTHON".into());
    };
    let script = programs.dir.join("ca_timing.py");
    std::fs::write(&script, include_str!("../python/ca_timing.py")).map_err(|e| e.to_string())?;
    let mut command = std::process::Command::new(&python);
    command.arg(&script).args([port.to_string(), reads.to_string(), moves.to_string()]);
    let output = tokio::task::spawn_blocking(move || command.output())
        .await
        .map_err(|e| e.to_string())?
        .map_err(|e| format!("{}: {e}", python.display()))?;
    if !output.status.success() {
        return Err(String::from_utf8_lossy(&output.stderr).trim().to_string());
    }
    let figures: serde_json::Value = serde_json::from_slice(&output.stdout).map_err(|e| e.to_string())?;
    let three = |what: &str| ["p50", "p90", "p99"].map(|p| figures[what][p].as_f64().unwrap_or(f64::NAN));
    Ok(StockClient { read: three("read"), move_: three("move") })
}
