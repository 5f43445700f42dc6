//! zmotor-sim-controller: a vendor's controller emulated on the physical simulator
//! (`zmotor_emulators`), served on the wall clock: its bytes on a TCP socket or on a
//! pseudo-terminal, with the link's faults on request. It lets a launch file written for real
//! hardware run with none attached (`zmotor sim-controller`), and the benchmark watch the
//! emulated stages. One connection at a time; a new one replaces the old (the controller, its
//! axes and settings, stays as it was).

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use zmotor_core::{Driver, Instant};
use zmotor_emulators::{Faults, Model, WithFaults};

/// A pseudo-terminal that cannot be made.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PtyError {
    /// The pair cannot be opened.
    #[error("cannot open a pseudo-terminal: {0}")]
    Open(std::io::Error),
    /// The slave end has no name to link to.
    #[error("the pseudo-terminal has no name")]
    Nameless,
    /// The link at the path given cannot be made.
    #[error("cannot link {path}: {source}")]
    Link {
        /// Where.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

/// A byte stream to the driver.
pub trait Io: AsyncRead + AsyncWrite + Unpin + Send {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send> Io for T {}

/// An emulated controller: its faulty link and its clock. Connections come one at a time;
/// the benchmark also watches its stages.
#[derive(Clone)]
pub struct Emulated {
    link: Arc<Mutex<WithFaults>>,
    origin: tokio::time::Instant,
}

impl Emulated {
    /// A controller of `model` with every channel below `channels`, behind `faults`; on a
    /// serial line at `baud`, if given (its bytes take their time, as on a real line).
    pub fn new(model: Model, channels: usize, faults: Faults, baud: Option<u32>) -> Self {
        let link = WithFaults::new(model.emulator(channels), faults);
        let link = match baud {
            Some(baud) => link.at_baud(baud),
            None => link,
        };
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
    pub async fn serve_tcp(&self, listener: tokio::net::TcpListener) -> std::io::Result<()> {
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
    pub async fn serve(&self, connection: &mut Option<Box<dyn Io>>) -> String {
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

/// A pseudo-terminal pair, its slave linked at `path` (a symlink left by an earlier run is
/// replaced, anything else there is not touched). The slave is kept open so that the
/// terminal survives drivers closing and reopening it.
pub fn pseudo_terminal(path: &Path) -> Result<(tokio_serial::SerialStream, tokio_serial::SerialStream), PtyError> {
    use tokio_serial::SerialPort;
    // The slave end is neither locked nor made exclusive: the driver locks it when it opens it.
    let (master, slave) = tokio_serial::SerialStream::pair().map_err(|e| PtyError::Open(e.into()))?;
    let name = slave.name().ok_or(PtyError::Nameless)?;
    if path.symlink_metadata().is_ok_and(|m| m.file_type().is_symlink()) {
        std::fs::remove_file(path).map_err(|source| PtyError::Link { path: path.to_path_buf(), source })?;
    }
    std::os::unix::fs::symlink(&name, path).map_err(|source| PtyError::Link { path: path.to_path_buf(), source })?;
    Ok((master, slave))
}
