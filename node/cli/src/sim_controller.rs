//! `zmotor sim-controller`: a vendor's controller emulated on the physical simulator, speaking
//! its bytes on a TCP socket or on a pseudo-terminal, with the link's faults on request. It lets
//! a launch file written for real hardware run with none attached. One connection at a time; a
//! new one replaces the old (the controller, its axes and settings, stays as it was).

use crate::Error;
use std::path::{Path, PathBuf};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use zmotor_controllers::emulator::{Faults, WithFaults};
use zmotor_controllers::ProtocolKind;
use zmotor_core::Instant;

/// Where the emulated controller listens.
pub enum Endpoint {
    /// A TCP address, `host:port`.
    Tcp(String),
    /// A pseudo-terminal, linked at this path.
    Pty(PathBuf),
}

/// The link's faults, from the command line.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct FaultArgs {
    /// Never send every N-th reply.
    #[arg(long, value_name = "N")]
    pub drop_every: Option<u32>,
    /// Replace every N-th reply by noise.
    #[arg(long, value_name = "N")]
    pub garble_every: Option<u32>,
    /// Send every reply this many milliseconds late.
    #[arg(long, value_name = "MS", default_value_t = 0)]
    pub delay_ms: u64,
    /// Close the connection after N replies.
    #[arg(long, value_name = "N")]
    pub close_after: Option<u32>,
}

impl FaultArgs {
    fn faults(&self) -> Faults {
        Faults {
            drop_every: self.drop_every,
            garble_every: self.garble_every,
            delay: Duration::from_millis(self.delay_ms),
            close_after: self.close_after,
        }
    }
}

/// A byte stream to the driver.
trait Io: AsyncRead + AsyncWrite + Unpin + Send {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send> Io for T {}

/// Serve the emulated controller until SIGINT or SIGTERM.
pub async fn run(protocol: &str, endpoint: Endpoint, channels: Option<usize>, faults: &FaultArgs) -> Result<(), Error> {
    let kind = ProtocolKind::from_name(protocol)
        .ok_or_else(|| format!("'{protocol}' is not a known protocol (known: {})", ProtocolKind::known()))?;
    let mut link = WithFaults::new(kind.emulator(channels.unwrap_or(kind.emulated_size())), faults.faults());
    let origin = tokio::time::Instant::now();
    let interrupted = crate::interrupted();
    tokio::pin!(interrupted);
    match endpoint {
        Endpoint::Tcp(address) => {
            let listener = tokio::net::TcpListener::bind(&address).await?;
            tracing::info!("{} emulated on tcp {}; Ctrl-C to stop", kind.name(), listener.local_addr()?);
            let mut connection: Option<Box<dyn Io>> = None;
            loop {
                tokio::select! {
                    accepted = listener.accept() => {
                        let (stream, peer) = accepted?;
                        stream.set_nodelay(true)?;
                        tracing::info!("connection from {peer}");
                        link.reconnect();
                        connection = Some(Box::new(stream));
                    }
                    ended = serve(&mut link, &mut connection, origin) => {
                        tracing::info!("connection closed: {ended}");
                        connection = None;
                    }
                    result = &mut interrupted => return result,
                }
            }
        }
        Endpoint::Pty(path) => {
            let (master, slave) = pseudo_terminal(&path)?;
            tracing::info!("{} emulated on the pseudo-terminal {}; Ctrl-C to stop", kind.name(), path.display());
            let mut connection: Option<Box<dyn Io>> = Some(Box::new(master));
            let result = tokio::select! {
                ended = serve(&mut link, &mut connection, origin) => Err(format!("pseudo-terminal closed: {ended}").into()),
                result = &mut interrupted => result,
            };
            drop(slave);
            let _ = std::fs::remove_file(&path);
            result
        }
    }
}

/// A pseudo-terminal pair, its slave linked at `path` (a symlink left by an earlier run is
/// replaced, anything else there is not touched). The slave is kept open so that the
/// terminal survives drivers closing and reopening it.
fn pseudo_terminal(path: &Path) -> Result<(tokio_serial::SerialStream, tokio_serial::SerialStream), Error> {
    use tokio_serial::SerialPort;
    // The slave end is neither locked nor made exclusive: the driver locks it when it opens it.
    let (master, slave) = tokio_serial::SerialStream::pair()?;
    let name = slave.name().ok_or("the pseudo-terminal has no name")?;
    if path.symlink_metadata().is_ok_and(|m| m.file_type().is_symlink()) {
        std::fs::remove_file(path)?;
    }
    std::os::unix::fs::symlink(&name, path).map_err(|e| format!("cannot link {} to {name}: {e}", path.display()))?;
    Ok((master, slave))
}

/// Serve one connection until it closes; what ended it. Never returns without a connection.
async fn serve(link: &mut WithFaults, connection: &mut Option<Box<dyn Io>>, origin: tokio::time::Instant) -> String {
    let Some(stream) = connection.as_mut() else { return std::future::pending().await };
    let now = || Instant::after(origin.elapsed());
    let mut buffer = vec![0u8; 4096];
    loop {
        while let Some(reply) = link.poll_transmit() {
            if let Err(e) = stream.write_all(&reply).await {
                return e.to_string();
            }
        }
        if link.is_closed() {
            return "closed on purpose (--close-after)".into();
        }
        let due = link.poll_timeout().map(|t| origin + t.since_origin());
        tokio::select! {
            read = stream.read(&mut buffer) => match read {
                Ok(0) => return "the driver closed it".into(),
                Ok(n) => link.handle_input(now(), &buffer[..n]),
                Err(e) => return e.to_string(),
            },
            _ = tokio::time::sleep_until(due.unwrap_or(origin)), if due.is_some() => link.handle_timeout(now()),
        }
    }
}
