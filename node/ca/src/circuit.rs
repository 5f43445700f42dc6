//! One CA client's TCP circuit, until it closes: its bytes to and from the sans-IO `Circuit`,
//! the network's changes to it, its requests to the network. A circuit holds the jogs it
//! starts by a liveliness token of its own, so a client that dies or is cut off has its jogs
//! ended.

use crate::values::{Change, Seen};
use crate::{Done, Shared, Write};
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{broadcast, mpsc};
use zmotor_ca_proto::{Circuit, Request};
use zmotor_client::HoldToken;

/// Circuits served so far by this process: each holds its jogs by a token of its own.
static CIRCUITS: AtomicU64 = AtomicU64::new(0);

/// How long the alarm changes of one processing are gathered into one event: the node
/// publishes them back to back, microseconds apart.
const ALARM_GATHERING: Duration = Duration::from_millis(3);

/// One client's circuit until it closes.
pub(crate) async fn serve_circuit(
    stream: tokio::net::TcpStream,
    shared: &Shared,
    mut stopped: tokio::sync::watch::Receiver<()>,
) -> std::io::Result<()> {
    stream.set_nodelay(true)?;
    let (mut reader, mut writer) = stream.into_split();
    let mut changes = shared.changes.subscribe();
    let (done, mut finished) = mpsc::unbounded_channel::<Done>();
    let mut circuit = Circuit::new(&shared.prefix);
    let mut seen = Seen::default();
    // The tokens this circuit holds its jogs by, per axis: they go when the circuit closes (the
    // client quit, died or was cut off), and the node then ends the jogs.
    let mut holds: HashMap<String, HoldToken> = HashMap::new();
    let client = format!("ca-{}-{}", shared.client.session().zid(), CIRCUITS.fetch_add(1, Ordering::Relaxed));
    let mut buffer = vec![0; 16 * 1024];
    // When the alarm events owed go: one processing's alarm changes (SEVR, STAT, ACKS, separate
    // samples) are given this long to arrive and make one event.
    let mut alarms_at: Option<tokio::time::Instant> = None;
    loop {
        let flush_alarms = async {
            match alarms_at {
                Some(at) => tokio::time::sleep_until(at).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            _ = stopped.changed() => return Ok(()),
            () = flush_alarms => {
                circuit.flush_alarms(&seen.directory(&shared.values()));
            }
            read = reader.read(&mut buffer) => {
                let length = read?;
                if length == 0 {
                    return Ok(());
                }
                // A request is answered with all the network has told: the changes before it are
                // handled (and posted) first.
                catch_up(&mut changes, &mut circuit, &mut seen, shared);
                let handled = circuit.handle_input(&buffer[..length], &seen.directory(&shared.values()));
                handled.map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))?;
            }
            change = changes.recv() => {
                if !take(change, &mut circuit, &mut seen, shared) {
                    return Ok(());
                }
                // The changes that came with it (one processing's posts) make one alarm event.
                catch_up(&mut changes, &mut circuit, &mut seen, shared);
            }
            Some((answer, outcome)) = finished.recv() => {
                // A put-callback's motion ends after its last posts.
                catch_up(&mut changes, &mut circuit, &mut seen, shared);
                circuit.write_done(answer, outcome, &seen.directory(&shared.values()));
            }
        }
        while let Some(request) = circuit.poll_request() {
            match request {
                Request::Fetch { axis } => shared.fetch(axis),
                Request::Write { pv, text, wait, hold, answer } => {
                    let hold = match hold {
                        true => {
                            // A circuit that holds a jog must notice a client cut off within a
                            // second, not TCP's quarter of an hour.
                            watch_closely(writer.as_ref())?;
                            Some(hold_token(shared, &mut holds, &pv.axis, &client).await?)
                        }
                        false => None,
                    };
                    shared.write(Write { pv, text, wait, hold, answer }, done.clone()).await;
                }
            }
        }
        alarms_at = match (circuit.alarms_due(), alarms_at) {
            (false, _) => None,
            (true, Some(at)) => Some(at),
            (true, None) => Some(tokio::time::Instant::now() + ALARM_GATHERING),
        };
        while let Some(bytes) = circuit.poll_transmit() {
            writer.write_all(&bytes).await?;
        }
    }
}

/// Handle a change told by the gateway, in the order told; false when the gateway is gone.
fn take(
    told: Result<Change, broadcast::error::RecvError>,
    circuit: &mut Circuit,
    seen: &mut Seen,
    shared: &Shared,
) -> bool {
    match told {
        Ok(change) if seen.take(&change) => match change {
            Change::Value { axis, target, .. } => {
                circuit.handle_change(&axis, target, &seen.directory(&shared.values()))
            }
            Change::Whole { axis, .. } => circuit.values_arrived(&axis, &seen.directory(&shared.values())),
            Change::Gone { axis, .. } => circuit.axis_gone(&axis),
        },
        Ok(_) => {}
        Err(broadcast::error::RecvError::Lagged(missed)) => {
            tracing::warn!(missed, "a circuit fell behind the network's changes: posting every monitor again");
            seen.forget_all();
            circuit.repost(&seen.directory(&shared.values()));
        }
        Err(broadcast::error::RecvError::Closed) => return false,
    }
    true
}

/// Handle every change told so far (not those told meanwhile: a stream of changes does not hold
/// the client's requests back).
fn catch_up(changes: &mut broadcast::Receiver<Change>, circuit: &mut Circuit, seen: &mut Seen, shared: &Shared) {
    for _ in 0..changes.len() {
        let told = match changes.try_recv() {
            Ok(change) => Ok(change),
            Err(broadcast::error::TryRecvError::Lagged(missed)) => Err(broadcast::error::RecvError::Lagged(missed)),
            Err(broadcast::error::TryRecvError::Empty | broadcast::error::TryRecvError::Closed) => return,
        };
        take(told, circuit, seen, shared);
    }
}

/// The key of the token a circuit holds an axis's jogs by, declared at its first jog.
async fn hold_token(
    shared: &Shared,
    holds: &mut HashMap<String, HoldToken>,
    axis: &str,
    client: &str,
) -> std::io::Result<String> {
    if let Some(token) = holds.get(axis) {
        return Ok(token.key().to_string());
    }
    let token = shared.client.hold(axis, client).await.map_err(std::io::Error::other)?;
    let key = token.key().to_string();
    holds.insert(axis.to_string(), token);
    Ok(key)
}

/// Keep-alive probes after a second of silence, and at most half a second for sent data to be
/// acknowledged: a client cut off (no FIN, no RST) is then dropped, and its holds with it.
fn watch_closely(stream: &tokio::net::TcpStream) -> std::io::Result<()> {
    let socket = socket2::SockRef::from(stream);
    let probes = socket2::TcpKeepalive::new()
        .with_time(Duration::from_secs(1))
        .with_interval(Duration::from_secs(1))
        .with_retries(1);
    socket.set_tcp_keepalive(&probes)?;
    socket.set_tcp_user_timeout(Some(Duration::from_millis(500)))
}
