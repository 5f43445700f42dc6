//! The motor screen in the browser: `zmotor web` serves an index of the axes live on the Zenoh
//! network (they appear and vanish with their liveliness tokens) and, per axis, a
//! motorx_all-style screen (drive and readback in user, dial and raw units; limits; tweak; jog;
//! home; stop/pause/go; calibration; dynamics; resolution; status bits) with a plot of RBV, VAL
//! and velocity over the last minute. The page talks to the axis over a WebSocket bridged to its
//! keys: every publication of the axis goes to the page as `{"field", "value"}`; the page's
//! writes (`{"id", "field", "value"}`) are confirmed writes to the axis's write keys, answered
//! `{"id", "ok": true}` or `{"id", "error"}` with the node's words. A jog is held by the
//! socket's liveliness token: a page that closes or loses its connection ends its jog.
//! Assets (HTML, CSS, JavaScript, no library) are embedded in the binary.

use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use zenoh::sample::{Sample, SampleKind};
use zmotor_client::{Client, HoldToken, WriteOptions, WriteOutcome};
use zmotor_deploy::WebConfig;
use zmotor_msgs::decode_cbor_value;
use zmotor_msgs::{keys, Field};

/// The server could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WebError {
    /// Its address could not be bound.
    #[error("cannot listen on {address}: {source}")]
    Bind {
        /// Where.
        address: SocketAddr,
        /// Why.
        source: std::io::Error,
    },
}

/// Sockets served so far by this process: each holds its jogs by a token of its own.
static SOCKETS: AtomicU64 = AtomicU64::new(0);

/// How long a write waits for the node's answer.
const ANSWER_PATIENCE: Duration = Duration::from_secs(10);

#[derive(Clone)]
struct AppState {
    client: Client,
}

/// The host names the screens answer to, beside IP addresses and `localhost`.
#[derive(Clone, Debug)]
struct KnownNames(Arc<Vec<String>>);

impl KnownNames {
    /// The configured names and this machine's own.
    fn new(config: &WebConfig) -> Self {
        let own = std::fs::read_to_string("/proc/sys/kernel/hostname").ok();
        let names = config.names.iter().map(String::as_str).chain(own.as_deref().map(str::trim));
        Self(Arc::new(names.filter(|n| !n.is_empty()).map(normal_name).collect()))
    }

    /// Whether a request's Host header names this server. A page a DNS-rebinding site serves
    /// runs under that site's name (its Origin and Host agree, so the Origin check alone lets it
    /// through): only an IP address, `localhost` or a name the server is known by is taken. A
    /// request with no Host (no browser sends none) is taken.
    fn allow(&self, headers: &HeaderMap) -> bool {
        let Some(host) = headers.get(header::HOST) else { return true };
        let Ok(host) = host.to_str() else { return false };
        let name = match host.strip_prefix('[') {
            // An IPv6 literal, with or without a port.
            Some(rest) => return rest.split_once(']').is_some_and(|(ip, _)| ip.parse::<std::net::Ipv6Addr>().is_ok()),
            None => host.rsplit_once(':').map_or(host, |(name, _)| name),
        };
        let name = normal_name(name);
        name.parse::<std::net::Ipv4Addr>().is_ok()
            || name == "localhost"
            || name.ends_with(".localhost")
            || self.0.contains(&name)
    }
}

/// A host name as compared: lower case, without the root's trailing dot.
fn normal_name(name: &str) -> String {
    name.trim_end_matches('.').to_ascii_lowercase()
}

/// Refuse requests whose Host names another server (`KnownNames::allow`).
async fn known_host(
    State(names): State<KnownNames>,
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    if names.allow(request.headers()) {
        return next.run(request).await;
    }
    let host = request.headers().get(header::HOST).and_then(|h| h.to_str().ok()).unwrap_or("?");
    tracing::warn!(host, "a request for a host name this screen is not known by: refused");
    let words = format!(
        "this motor screen is not served as '{host}': open it by its IP address, localhost, or a name given with \
         `zmotor web --name` ([web] names in a launch file)"
    );
    (StatusCode::MISDIRECTED_REQUEST, words).into_response()
}

/// A running web server; dropping it stops it.
pub struct Web {
    task: tokio::task::JoinHandle<()>,
    /// The address it serves on.
    pub address: SocketAddr,
}

impl Drop for Web {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl Web {
    /// Serve the screens of the axes `client` reaches.
    pub async fn start(client: Client, config: &WebConfig) -> Result<Self, WebError> {
        let bind = |source| WebError::Bind { address: config.address, source };
        let listener = tokio::net::TcpListener::bind(config.address).await.map_err(bind)?;
        let address = listener.local_addr().map_err(bind)?;
        let router = Router::new()
            .route("/", get(|| async { Html(INDEX) }))
            .route("/axis/{axis}", get(|| async { Html(SCREEN) }))
            .route("/assets/{file}", get(asset))
            .route("/api/axes", get(axes))
            .route("/api/fields", get(|| async { Json(zmotor_msgs::catalogue_json()) }))
            .route("/ws/{axis}", get(socket))
            .with_state(AppState { client })
            .layer(axum::middleware::from_fn_with_state(KnownNames::new(config), known_host));
        let task = tokio::spawn(async move {
            if let Err(e) = axum::serve(listener, router).await {
                tracing::error!("the web server stopped: {e}");
            }
        });
        tracing::info!(%address, "motor screens at http://{address}/");
        Ok(Self { task, address })
    }
}

const INDEX: &str = include_str!("../assets/index.html");
const SCREEN: &str = include_str!("../assets/screen.html");

async fn asset(Path(file): Path<String>) -> Response {
    let (content_type, body) = match file.as_str() {
        "zmotor.css" => ("text/css", include_str!("../assets/zmotor.css")),
        "index.js" => ("text/javascript", include_str!("../assets/index.js")),
        "screen.js" => ("text/javascript", include_str!("../assets/screen.js")),
        _ => return StatusCode::NOT_FOUND.into_response(),
    };
    ([(header::CONTENT_TYPE, content_type)], body).into_response()
}

async fn axes(State(state): State<AppState>) -> Response {
    match state.client.live_axes().await {
        Ok(axes) => Json(axes).into_response(),
        Err(e) => (StatusCode::BAD_GATEWAY, e.to_string()).into_response(),
    }
}

async fn socket(
    ws: WebSocketUpgrade,
    Path(axis): Path<String>,
    State(state): State<AppState>,
    headers: HeaderMap,
) -> Response {
    if !same_origin(&headers) {
        // Another site's page in the operator's browser must not reach the axes.
        return (StatusCode::FORBIDDEN, "a page of another origin may not open this socket").into_response();
    }
    if keys::validate_axis_name(&axis).is_err() {
        return (StatusCode::BAD_REQUEST, format!("'{axis}' is not an axis name")).into_response();
    }
    ws.max_message_size(MAX_PAGE_MESSAGE).on_upgrade(move |socket| async move {
        if let Err(e) = serve_screen(socket, state, axis).await {
            tracing::debug!("a screen's socket closed: {e}");
        }
    })
}

/// Whether a socket's request comes from a page of this server (or from no page at all: a
/// script or a tool sends no Origin).
fn same_origin(headers: &HeaderMap) -> bool {
    let Some(origin) = headers.get(header::ORIGIN) else { return true };
    let host = headers.get(header::HOST).and_then(|h| h.to_str().ok());
    let origin_host =
        origin.to_str().ok().and_then(|o| o.split_once("://")).map(|(_, rest)| rest.trim_end_matches('/'));
    host.is_some() && origin_host == host
}

/// A write the page asks for.
#[derive(serde::Deserialize)]
struct PageWrite {
    id: u64,
    field: String,
    value: String,
}

/// What a sample of the axis shows on the page.
fn shown(sample: &Sample) -> Option<String> {
    let field = sample.key_expr().as_str().rsplit('/').next()?;
    let payload = sample.payload().to_bytes();
    let value = match decode_cbor_value(&payload) {
        Ok(value) => serde_json::to_value(value).ok()?,
        // ERR's refusals are text.
        Err(_) => serde_json::Value::String(String::from_utf8_lossy(&payload).into_owned()),
    };
    Some(serde_json::json!({ "field": field, "value": value }).to_string())
}

/// Messages waiting for a page; a page that falls this far behind is closed.
const PAGE_QUEUE: usize = 4096;

/// The longest message a page sends (a write is tens of bytes).
const MAX_PAGE_MESSAGE: usize = 16 * 1024;

/// How long a message to a page may take to go out: a page that does not take it in that
/// time is closed (a send that waits holds up the jog deadman's pings and checks).
const SEND_PATIENCE: Duration = Duration::from_secs(10);

/// How much of a message that is no write is quoted back.
const QUOTED: usize = 80;

/// While a page holds a jog, it is pinged this often, and dropped (its jog ended) when it has
/// not been heard from for `HELD_SILENCE`: a browser cut off sends no close.
const HELD_PING: Duration = Duration::from_millis(250);
const HELD_SILENCE: Duration = Duration::from_millis(750);

/// The page's queue: messages for it, and whether one had to be dropped.
#[derive(Clone)]
struct ToPage {
    sender: mpsc::Sender<String>,
    overflowed: Arc<AtomicBool>,
}

impl ToPage {
    fn send(&self, text: String) {
        if self.sender.try_send(text).is_err() {
            self.overflowed.store(true, Ordering::Relaxed);
        }
    }
}

/// One page's socket, until it closes; its jogs end with it.
async fn serve_screen(mut socket: WebSocket, state: AppState, axis: String) -> Result<(), axum::Error> {
    let AppState { client } = state;
    let (session, layout) = (client.session(), client.layout());
    let (sender, mut outgoing) = mpsc::channel::<String>(PAGE_QUEUE);
    let out = ToPage { sender, overflowed: Arc::default() };
    let zenoh_error = |e: zenoh::Error| axum::Error::new(e);
    let to_page = out.clone();
    let _fields = session
        .declare_subscriber(layout.axis_fields(&axis))
        .callback(move |sample| {
            if let Some(text) = shown(&sample) {
                to_page.send(text);
            }
        })
        .await
        .map_err(zenoh_error)?;
    // An axis nobody serves would show "connecting" forever over empty cells: the page is told.
    let served = session.liveliness().get(layout.axis(&axis)).timeout(ANSWER_PATIENCE).await.map_err(zenoh_error)?;
    if served.recv_async().await.is_err() {
        out.send(serde_json::json!({ "served": false }).to_string());
    }
    let to_page = out.clone();
    let _token = session
        .liveliness()
        .declare_subscriber(layout.axis(&axis))
        .history(true)
        .callback(move |sample| {
            to_page.send(serde_json::json!({ "live": sample.kind() == SampleKind::Put }).to_string())
        })
        .await
        .map_err(zenoh_error)?;
    let replies = session.get(layout.axis_all(&axis)).timeout(ANSWER_PATIENCE).await.map_err(zenoh_error)?;
    let to_page = out.clone();
    tokio::spawn(async move {
        while let Ok(reply) = replies.recv_async().await {
            if let Some(text) = reply.result().ok().and_then(shown) {
                to_page.send(text);
            }
        }
    });
    // The token this page holds its jogs by, declared at its first jog.
    let holder = format!("web-{}-{}", session.zid(), SOCKETS.fetch_add(1, Ordering::Relaxed));
    let mut hold: Option<HoldToken> = None;
    let mut heard = Instant::now();
    let mut pings = tokio::time::interval(HELD_PING);
    loop {
        if out.overflowed.load(Ordering::Relaxed) {
            return Err(axum::Error::new("the page fell too far behind the axis"));
        }
        tokio::select! {
            message = socket.recv() => {
                heard = Instant::now();
                match message {
                    Some(Ok(Message::Text(text))) => {
                        let Ok(write) = serde_json::from_str::<PageWrite>(&text) else {
                            let quoted: String = text.chars().take(QUOTED).collect();
                            out.send(serde_json::json!({ "error": format!("not a write: {quoted}") }).to_string());
                            continue;
                        };
                        let held = match Field::from_name(&write.field).filter(|f| f.is_jog()) {
                            Some(_) => {
                                if hold.is_none() {
                                    hold = Some(client.hold(&axis, &holder).await.map_err(zenoh_error)?);
                                }
                                hold.as_ref().map(|token| token.key().to_string())
                            }
                            _ => None,
                        };
                        confirmed_write(&client, &axis, write, held, out.clone()).await;
                    }
                    Some(Ok(Message::Binary(_))) => {
                        out.send(serde_json::json!({ "error": "not a write: a binary message" }).to_string());
                    }
                    Some(Ok(Message::Close(_))) | None | Some(Err(_)) => return Ok(()),
                    Some(Ok(_)) => {}
                }
            }
            Some(text) = outgoing.recv() => {
                // While a jog is held, no longer than the deadman allows silence.
                let patience = if hold.is_some() { HELD_SILENCE } else { SEND_PATIENCE };
                send_within(&mut socket, Message::Text(text.into()), patience).await?;
            }
            _ = pings.tick(), if hold.is_some() => {
                if heard.elapsed() > HELD_SILENCE {
                    return Err(axum::Error::new("a page holding a jog went silent"));
                }
                send_within(&mut socket, Message::Ping(Vec::new().into()), HELD_SILENCE).await?;
            }
        }
    }
}

/// Send `message` to a page, which must take it within `patience`: a page whose link is cut
/// (its TCP buffer full) is closed, and its jogs end with it.
async fn send_within(socket: &mut WebSocket, message: Message, patience: Duration) -> Result<(), axum::Error> {
    match tokio::time::timeout(patience, socket.send(message)).await {
        Ok(sent) => sent,
        Err(_) => Err(axum::Error::new("a page did not take its messages in time")),
    }
}

/// A page's write as a confirmed write to the axis's write key, sent now (in the page's
/// order: VELO then VAL, or JOGF 1 then 0, reach the node so); the answer goes to the page, a
/// refusal with its words and kind.
async fn confirmed_write(client: &Client, axis: &str, write: PageWrite, hold: Option<String>, out: ToPage) {
    let PageWrite { id, field, value } = write;
    let sent = match Field::from_name(&field) {
        None => Err(format!("{field}: unknown field")),
        Some(field) => {
            let options = WriteOptions::confirmed(ANSWER_PATIENCE).held_by(hold);
            client.write(axis, field, value, options).await.map_err(|e| e.to_string())
        }
    };
    let axis = axis.to_string();
    tokio::spawn(async move {
        let answer = match sent {
            Ok(sent) => match sent.outcome().await {
                WriteOutcome::Accepted(_) | WriteOutcome::Completed(_) => serde_json::json!({ "id": id, "ok": true }),
                WriteOutcome::Refused(refusal) => {
                    serde_json::json!({ "id": id, "error": refusal.message, "kind": refusal.kind.name() })
                }
                other => serde_json::json!({ "id": id, "error": format!("{axis}: {other}") }),
            },
            Err(error) => serde_json::json!({ "id": id, "error": error }),
        };
        out.send(answer.to_string());
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sockets_are_opened_by_this_servers_pages_or_by_no_page() {
        let headers = |origin: Option<&str>| {
            let mut map = HeaderMap::new();
            map.insert(header::HOST, "127.0.0.1:8080".parse().unwrap());
            if let Some(origin) = origin {
                map.insert(header::ORIGIN, origin.parse().unwrap());
            }
            map
        };
        assert!(same_origin(&headers(Some("http://127.0.0.1:8080"))));
        assert!(same_origin(&headers(None)), "a tool sends no Origin");
        assert!(!same_origin(&headers(Some("https://evil.example"))));
        assert!(!same_origin(&headers(Some("http://127.0.0.1:9999"))));
    }

    #[test]
    fn requests_are_taken_for_ip_addresses_localhost_and_known_names_only() {
        let config = WebConfig { names: vec!["Beamline-PC.lab".into()], ..WebConfig::default() };
        let names = KnownNames::new(&config);
        let host = |host: &str| {
            let mut map = HeaderMap::new();
            map.insert(header::HOST, host.parse().unwrap());
            names.allow(&map)
        };
        for taken in ["127.0.0.1:8080", "10.2.3.4", "[::1]:8080", "[fe80::1]", "localhost:8080", "app.localhost"] {
            assert!(host(taken), "{taken}");
        }
        assert!(host("beamline-pc.lab:8080") && host("BEAMLINE-PC.LAB.:8080"), "a configured name, any case");
        for refused in
            ["evil.example:8080", "evil.example", "127.0.0.1.evil.example", "localhost.evil.example", "[zz]:80"]
        {
            assert!(!host(refused), "{refused}");
        }
        assert!(names.allow(&HeaderMap::new()), "a tool may send no Host");
    }
}
