//! Part 8 of the benchmark: the Channel Access front-end beside Zenoh, in the same run. The
//! demo's axis (launch/sim-axis.toml) in a node process whose launch file runs the front-end;
//! here, a CA client (the protocol of `zmotor-ca`, as caget and `caput -c` send it) and a Zenoh
//! client: a read's round trip, and a put-callback of a one-step move answered at its end.

use crate::bench::{client_when_ready, Percentiles};
use crate::controller_bench::NodeProcess;
use crate::Error;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use zenoh::bytes::Encoding;
use zmotor_ca::codec::{self, command, Header, MINOR_VERSION};

/// The figures of one run.
pub(crate) struct Figures {
    /// caget of RBV through the front-end.
    pub ca_read: Percentiles,
    /// A Zenoh `get` of RBV.
    pub zenoh_read: Percentiles,
    /// `caput -c` of a one-step move through the front-end.
    pub ca_move: Percentiles,
    /// The same move as a Zenoh `?wait` write.
    pub zenoh_move: Percentiles,
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
pub(crate) async fn run(reads: usize, moves: usize) -> Result<Figures, Error> {
    let dir = tempfile::tempdir()?;
    let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
    let launch = format!("{}\n[channel_access]\nport = {port}\n", include_str!("../../../launch/sim-axis.toml"));
    let file = dir.path().join("axis.toml");
    std::fs::write(&file, launch)?;
    let (_node, endpoint) = NodeProcess::launch(&file, dir.path())?;
    let session = client_when_ready(&endpoint, Instant::now()).await?;
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
    session.close().await?;
    Ok(Figures {
        ca_read: Percentiles::of(ca_read),
        zenoh_read: Percentiles::of(zenoh_read),
        ca_move: Percentiles::of(ca_move),
        zenoh_move: Percentiles::of(zenoh_move),
    })
}
