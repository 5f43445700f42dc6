//! `zmotor sim-controller`: a vendor's controller emulated on the physical simulator, speaking
//! its bytes on a TCP socket or on a pseudo-terminal, with the link's faults on request. It lets
//! a launch file written for real hardware run with none attached. One connection at a time; a
//! new one replaces the old (the controller, its axes and settings, stays as it was).

use crate::Error;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use zmotor_controllers::emulator::{Faults, WithFaults};
use zmotor_controllers::ProtocolKind;
use zmotor_core::driver::Driver;
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
pub(crate) trait Io: AsyncRead + AsyncWrite + Unpin + Send {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send> Io for T {}

/// An emulated controller: its faulty link and its clock. Connections come one at a time;
/// the benchmark also watches its stages.
#[derive(Clone)]
pub struct Emulated {
    link: Arc<Mutex<WithFaults>>,
    origin: tokio::time::Instant,
}

impl Emulated {
    /// A controller of `kind` with every channel below `channels`, behind `faults`.
    pub fn new(kind: ProtocolKind, channels: usize, faults: Faults) -> Self {
        let link = WithFaults::new(kind.emulator(channels), faults);
        Self { link: Arc::new(Mutex::new(link)), origin: tokio::time::Instant::now() }
    }

    fn link(&self) -> MutexGuard<'_, WithFaults> {
        self.link.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    fn now(&self) -> Instant {
        Instant::after(self.origin.elapsed())
    }

    /// When the motion under way on `channel` ends, on the wall clock; None at rest.
    pub fn motion_end(&self, channel: usize) -> Option<tokio::time::Instant> {
        let now = self.now();
        let mut link = self.link();
        let axis = link.emulator().axis(channel)?;
        axis.advance(now);
        axis.next_event().map(|end| self.origin + end.since_origin())
    }

    /// Serve connections on `listener`, a new one replacing the old; returns only on error.
    pub async fn serve_tcp(&self, listener: tokio::net::TcpListener) -> Result<(), Error> {
        let mut connection: Option<Box<dyn Io>> = None;
        loop {
            tokio::select! {
                accepted = listener.accept() => {
                    let (stream, peer) = accepted?;
                    stream.set_nodelay(true)?;
                    tracing::debug!("connection from {peer}");
                    self.link().reconnect();
                    connection = Some(Box::new(stream));
                }
                ended = self.serve(&mut connection) => {
                    tracing::info!("connection closed: {ended}");
                    connection = None;
                }
            }
        }
    }

    /// Serve one connection until it closes; what ended it. Never returns without a connection.
    pub(crate) async fn serve(&self, connection: &mut Option<Box<dyn Io>>) -> String {
        let Some(stream) = connection.as_mut() else { return std::future::pending().await };
        let mut buffer = vec![0u8; 4096];
        loop {
            let (replies, closed, due) = {
                let mut link = self.link();
                let replies: Vec<Vec<u8>> = std::iter::from_fn(|| link.poll_transmit()).collect();
                (replies, link.is_closed(), link.poll_timeout().map(|t| self.origin + t.since_origin()))
            };
            for reply in replies {
                if let Err(e) = stream.write_all(&reply).await {
                    return e.to_string();
                }
            }
            if closed {
                return "closed on purpose (--close-after)".into();
            }
            tokio::select! {
                read = stream.read(&mut buffer) => match read {
                    Ok(0) => return "the driver closed it".into(),
                    Ok(n) => {
                        let now = self.now();
                        self.link().handle_input(now, &buffer[..n]);
                    }
                    Err(e) => return e.to_string(),
                },
                _ = tokio::time::sleep_until(due.unwrap_or(self.origin)), if due.is_some() => {
                    let now = self.now();
                    self.link().handle_timeout(now);
                }
            }
        }
    }
}

/// Serve the emulated controller until SIGINT or SIGTERM.
pub async fn run(protocol: &str, endpoint: Endpoint, channels: Option<usize>, faults: &FaultArgs) -> Result<(), Error> {
    let kind = ProtocolKind::from_name(protocol)
        .ok_or_else(|| format!("'{protocol}' is not a known protocol (known: {})", ProtocolKind::known()))?;
    let emulated = Emulated::new(kind, channels.unwrap_or(kind.emulated_size()), faults.faults());
    let interrupted = crate::interrupted();
    tokio::pin!(interrupted);
    match endpoint {
        Endpoint::Tcp(address) => {
            let listener = tokio::net::TcpListener::bind(&address).await?;
            tracing::info!("{} emulated on tcp {}; Ctrl-C to stop", kind.name(), listener.local_addr()?);
            tokio::select! {
                result = emulated.serve_tcp(listener) => result,
                result = &mut interrupted => result,
            }
        }
        Endpoint::Pty(path) => {
            let (master, slave) = pseudo_terminal(&path)?;
            tracing::info!("{} emulated on the pseudo-terminal {}; Ctrl-C to stop", kind.name(), path.display());
            let mut connection: Option<Box<dyn Io>> = Some(Box::new(master));
            let result = tokio::select! {
                ended = emulated.serve(&mut connection) => Err(format!("pseudo-terminal closed: {ended}").into()),
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
pub(crate) fn pseudo_terminal(path: &Path) -> Result<(tokio_serial::SerialStream, tokio_serial::SerialStream), Error> {
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
