//! `zmotor sim-controller`: a vendor's controller emulated on the physical simulator, on a TCP
//! socket or a pseudo-terminal (zmotor-sim-controller), until SIGINT or SIGTERM.

use crate::Error;
use std::path::PathBuf;
use std::time::Duration;
use zmotor_controllers::ProtocolKind;
use zmotor_emulators::{Faults, Model};
use zmotor_sim_controller::{pseudo_terminal, Emulated, Io};

/// Where the emulated controller listens.
pub(crate) enum Endpoint {
    /// A TCP address, `host:port`.
    Tcp(String),
    /// A pseudo-terminal, linked at this path, carrying bytes at this baud (None: the model's
    /// factory rate).
    Pty(PathBuf, Option<u32>),
}

/// The link's faults, from the command line.
#[derive(clap::Args, Clone, Debug, Default)]
pub(crate) struct FaultArgs {
    /// Never send every N-th reply.
    #[arg(long, value_name = "N")]
    pub(crate) drop_every: Option<u32>,
    /// Replace every N-th reply by noise.
    #[arg(long, value_name = "N")]
    pub(crate) garble_every: Option<u32>,
    /// Send every reply this many milliseconds late.
    #[arg(long, value_name = "MS", default_value_t = 0)]
    pub(crate) delay_ms: u64,
    /// Close the connection after N replies.
    #[arg(long, value_name = "N")]
    pub(crate) close_after: Option<u32>,
}

impl FaultArgs {
    fn faults(&self) -> Faults {
        Faults {
            drop_every: self.drop_every,
            garble_every: self.garble_every,
            delay: Duration::from_millis(self.delay_ms),
            close_after: self.close_after,
            late_connection: None,
        }
    }
}

/// Serve the emulated controller until SIGINT or SIGTERM.
pub(crate) async fn run(
    protocol: &str,
    endpoint: Endpoint,
    channels: Option<usize>,
    faults: &FaultArgs,
) -> Result<(), Error> {
    // A family a script drives is named as its emulator is (`kohzu_sc`); a protocol by any of
    // its names.
    let model = Model::speaking(protocol)
        .or_else(|| ProtocolKind::from_name(protocol).and_then(|kind| Model::speaking(kind.name())))
        .ok_or_else(|| {
            let known: Vec<&str> = Model::ALL.iter().map(|m| m.protocol()).collect();
            format!("'{protocol}' is not an emulated controller (known: {})", known.join(", "))
        })?;
    let name = model.protocol();
    let channels = channels.unwrap_or(model.typical_channels());
    let interrupted = zmotor_client::interrupted();
    tokio::pin!(interrupted);
    match endpoint {
        Endpoint::Tcp(address) => {
            let emulated = Emulated::new(model, channels, faults.faults(), None);
            let listener = tokio::net::TcpListener::bind(&address)
                .await
                .map_err(|e| format!("cannot listen on {address} (--listen): {e}"))?;
            tracing::info!("{name} emulated on tcp {}; Ctrl-C to stop", listener.local_addr()?);
            tokio::select! {
                result = emulated.serve_tcp(listener) => Ok(result?),
                result = &mut interrupted => Ok(result?),
            }
        }
        Endpoint::Pty(path, baud) => {
            let baud = baud.unwrap_or(model.factory_baud());
            let emulated = Emulated::new(model, channels, faults.faults(), Some(baud));
            let (master, slave) = pseudo_terminal(&path)?;
            let shown = path.display();
            tracing::info!("{name} emulated on the pseudo-terminal {shown} at {baud} baud; Ctrl-C to stop");
            let mut connection: Option<Box<dyn Io>> = Some(Box::new(master));
            let result = tokio::select! {
                ended = emulated.serve(&mut connection) => Err(format!("pseudo-terminal closed: {ended}").into()),
                result = &mut interrupted => Ok(result?),
            };
            drop(slave);
            let _ = std::fs::remove_file(&path);
            result
        }
    }
}
