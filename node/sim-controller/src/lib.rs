//! zmotor-sim-controller: a vendor's controller emulated on the physical simulator
//! (`zmotor_emulators`), served on the wall clock: its bytes on a TCP socket or on a
//! pseudo-terminal, with the link's faults on request. It lets a launch file written for real
//! hardware run with none attached (`zmotor sim-controller`), and the benchmark watch the
//! emulated stages. A controller serving one connection at a time has a new one replace the old
//! (the controller, its axes and settings, stays as it was); one serving several (an XPS) serves
//! them at once.

use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::Poll;
use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt, ReadBuf};
use zmotor_core::{Driver, Instant};
use zmotor_emulators::{Connection, Faults, Model, WithFaults};

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

/// An emulated controller: its faulty link and its clock; the benchmark also watches its
/// stages.
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

    /// When the motion under way on `channel` ends, or the last one ended if that was at or
    /// after `since` (a motion shorter than the gap between two looks), on the wall clock; None
    /// at rest since then.
    pub fn motion_end(&self, channel: usize, since: tokio::time::Instant) -> Option<tokio::time::Instant> {
        let now = self.now();
        let mut link = self.link();
        let axis = link.emulator().axis(channel)?;
        axis.advance(now);
        let ended = axis.last_motion_end().map(|end| self.origin + end.since_origin()).filter(|end| *end >= since);
        axis.next_event().map(|end| self.origin + end.since_origin()).or(ended)
    }

    /// Serve connections on `listener`: as many at once as the controller serves, each with its
    /// number (a controller serving one: a new one replaces the old); returns only on error.
    pub async fn serve_tcp(&self, listener: tokio::net::TcpListener) -> std::io::Result<()> {
        let mut connections: Vec<Option<Box<dyn Io>>> = Vec::new();
        loop {
            tokio::select! {
                accepted = listener.accept() => {
                    let (stream, peer) = accepted?;
                    stream.set_nodelay(true)?;
                    let served = self.link().connections();
                    if served == 1 || connections.iter().all(Option::is_none) {
                        connections.clear();
                        self.link().reconnect();
                    }
                    let Some(number) = free_slot(&mut connections, served) else {
                        tracing::warn!("connection from {peer} refused: the controller serves {served} at once");
                        continue;
                    };
                    tracing::debug!("connection {number} from {peer}");
                    connections[number] = Some(Box::new(stream));
                }
                ended = self.serve_connections(&mut connections) => match ended {
                    Ended::One(number, why) => {
                        tracing::info!("connection {number} closed: {why}");
                        connections[number] = None;
                        self.link().close(number);
                    }
                    Ended::All(why) => {
                        tracing::info!("connections closed: {why}");
                        connections.clear();
                    }
                },
            }
        }
    }

    /// Serve one connection (a pseudo-terminal) until it closes; what ended it. Never returns
    /// without a connection.
    pub async fn serve(&self, connection: &mut Option<Box<dyn Io>>) -> String {
        let mut connections = vec![connection.take()];
        match self.serve_connections(&mut connections).await {
            Ended::One(_, why) | Ended::All(why) => why,
        }
    }

    /// Serve `connections` (by their number; None a free number) until one closes, or all.
    /// Never returns without a connection.
    async fn serve_connections(&self, connections: &mut [Option<Box<dyn Io>>]) -> Ended {
        if connections.iter().all(Option::is_none) {
            return std::future::pending().await;
        }
        let mut buffer = vec![0u8; 4096];
        loop {
            let (replies, closed, due) = {
                let mut link = self.link();
                let replies: Vec<(Connection, Vec<u8>)> = std::iter::from_fn(|| link.poll_transmit_on()).collect();
                (replies, link.is_closed(), link.poll_timeout().map(|t| self.origin + t.since_origin()))
            };
            for (number, reply) in replies {
                // A reply for a connection closed meanwhile is lost with it.
                let Some(Some(stream)) = connections.get_mut(number) else { continue };
                if let Err(e) = stream.write_all(&reply).await {
                    return Ended::One(number, e.to_string());
                }
            }
            if closed {
                return Ended::All("closed on purpose (--close-after)".into());
            }
            tokio::select! {
                (number, read) = read_any(connections, &mut buffer) => match read {
                    Ok(0) => return Ended::One(number, "the driver closed it".into()),
                    Ok(n) => {
                        let now = self.now();
                        self.link().handle_input_on(now, number, &buffer[..n]);
                    }
                    Err(e) => return Ended::One(number, e.to_string()),
                },
                _ = tokio::time::sleep_until(due.unwrap_or(self.origin)), if due.is_some() => {
                    let now = self.now();
                    self.link().handle_timeout(now);
                }
            }
        }
    }
}

/// What ended the service of connections.
enum Ended {
    /// This connection closed.
    One(Connection, String),
    /// The controller closed them all.
    All(String),
}

/// The lowest free connection number of at most `served`, made room for.
fn free_slot(connections: &mut Vec<Option<Box<dyn Io>>>, served: usize) -> Option<Connection> {
    if let Some(free) = connections.iter().position(Option::is_none) {
        return Some(free);
    }
    (connections.len() < served).then(|| {
        connections.push(None);
        connections.len() - 1
    })
}

/// Read from whichever connection has bytes first: its number and what was read. Never ready
/// without a connection.
async fn read_any(connections: &mut [Option<Box<dyn Io>>], buffer: &mut [u8]) -> (Connection, std::io::Result<usize>) {
    std::future::poll_fn(|context| {
        for (number, connection) in connections.iter_mut().enumerate() {
            let Some(stream) = connection else { continue };
            let mut read = ReadBuf::new(buffer);
            if let Poll::Ready(result) = Pin::new(stream).poll_read(context, &mut read) {
                return Poll::Ready((number, result.map(|()| read.filled().len())));
            }
        }
        Poll::Pending
    })
    .await
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
