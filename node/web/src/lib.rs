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
use axum::http::{header, StatusCode};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use tokio::sync::mpsc;
use zenoh::bytes::Encoding;
use zenoh::sample::{Sample, SampleKind};
use zenoh::Session;
use zmotor_msgs::codec::decode_cbor_value;
use zmotor_msgs::{keys, Field, Hold, KeyLayout};

/// Where the screen is served.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WebConfig {
    /// The HTTP address (127.0.0.1:8080 by default: only this host's browsers).
    pub address: SocketAddr,
}

impl Default for WebConfig {
    fn default() -> Self {
        Self { address: SocketAddr::from(([127, 0, 0, 1], 8080)) }
    }
}

/// The server could not start.
#[derive(Debug, thiserror::Error)]
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
    session: Session,
    layout: KeyLayout,
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
    /// Serve the screens of the axes under `layout` that `session` reaches.
    pub async fn start(session: Session, layout: KeyLayout, config: &WebConfig) -> Result<Self, WebError> {
        let bind = |source| WebError::Bind { address: config.address, source };
        let listener = tokio::net::TcpListener::bind(config.address).await.map_err(bind)?;
        let address = listener.local_addr().map_err(bind)?;
        let router = Router::new()
            .route("/", get(|| async { Html(INDEX) }))
            .route("/axis/{axis}", get(|| async { Html(SCREEN) }))
            .route("/assets/{file}", get(asset))
            .route("/api/axes", get(axes))
            .route("/api/fields", get(|| async { Json(zmotor_msgs::schema::catalogue_json()) }))
            .route("/ws/{axis}", get(socket))
            .with_state(AppState { session, layout });
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
    match zmotor_zenoh::summary::live_axes(&state.session, &state.layout).await {
        Ok(axes) => Json(axes).into_response(),
        Err(e) => (StatusCode::BAD_GATEWAY, e.to_string()).into_response(),
    }
}

async fn socket(ws: WebSocketUpgrade, Path(axis): Path<String>, State(state): State<AppState>) -> Response {
    if keys::validate_axis_name(&axis).is_err() {
        return (StatusCode::BAD_REQUEST, format!("'{axis}' is not an axis name")).into_response();
    }
    ws.on_upgrade(move |socket| async move {
        if let Err(e) = serve_screen(socket, state, axis).await {
            tracing::debug!("a screen's socket closed: {e}");
        }
    })
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

/// One page's socket, until it closes; its jogs end with it.
async fn serve_screen(mut socket: WebSocket, state: AppState, axis: String) -> Result<(), axum::Error> {
    let AppState { session, layout } = state;
    let (out, mut outgoing) = mpsc::unbounded_channel::<String>();
    let to_page = out.clone();
    let zenoh_error = |e: zenoh::Error| axum::Error::new(e);
    let _fields = session
        .declare_subscriber(layout.axis_fields(&axis))
        .callback(move |sample| {
            if let Some(text) = shown(&sample) {
                let _ = to_page.send(text);
            }
        })
        .await
        .map_err(zenoh_error)?;
    let to_page = out.clone();
    let _token = session
        .liveliness()
        .declare_subscriber(layout.axis(&axis))
        .history(true)
        .callback(move |sample| {
            let live = sample.kind() == SampleKind::Put;
            let _ = to_page.send(serde_json::json!({ "live": live }).to_string());
        })
        .await
        .map_err(zenoh_error)?;
    let replies = session.get(layout.axis_all(&axis)).timeout(ANSWER_PATIENCE).await.map_err(zenoh_error)?;
    let to_page = out.clone();
    tokio::spawn(async move {
        while let Ok(reply) = replies.recv_async().await {
            if let Some(text) = reply.result().ok().and_then(shown) {
                let _ = to_page.send(text);
            }
        }
    });
    // The token this page holds its jogs by, declared at its first jog.
    let client = format!("web-{}-{}", session.zid(), SOCKETS.fetch_add(1, Ordering::Relaxed));
    let mut hold: Option<(String, zenoh::liveliness::LivelinessToken)> = None;
    loop {
        tokio::select! {
            message = socket.recv() => match message {
                Some(Ok(Message::Text(text))) => {
                    let Ok(write) = serde_json::from_str::<PageWrite>(&text) else {
                        let _ = out.send(serde_json::json!({ "error": format!("not a write: {text}") }).to_string());
                        continue;
                    };
                    let held = match Field::from_name(&write.field) {
                        Some(Field::JOGF | Field::JOGR) => {
                            if hold.is_none() {
                                let key = layout.hold(&axis, &client);
                                let token = session.liveliness().declare_token(&key).await.map_err(zenoh_error)?;
                                hold = Some((key, token));
                            }
                            hold.as_ref().map(|(key, _)| key.clone())
                        }
                        _ => None,
                    };
                    tokio::spawn(confirmed_write(session.clone(), layout.clone(), axis.clone(), write, held, out.clone()));
                }
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => return Ok(()),
                Some(Ok(_)) => {}
            },
            Some(text) = outgoing.recv() => socket.send(Message::Text(text.into())).await?,
        }
    }
}

/// A page's write as a confirmed write to the axis's write key; the outcome goes to the page.
async fn confirmed_write(
    session: Session,
    layout: KeyLayout,
    axis: String,
    write: PageWrite,
    hold: Option<String>,
    out: mpsc::UnboundedSender<String>,
) {
    let PageWrite { id, field, value } = write;
    let outcome = match Field::from_name(&field) {
        None => Err(format!("{field}: unknown field")),
        Some(field) => {
            let mut request = session
                .get(layout.write_selector(&axis, field, false))
                .payload(value)
                .encoding(Encoding::TEXT_PLAIN)
                .timeout(ANSWER_PATIENCE);
            if let Some(token) = &hold {
                request = request.attachment(Hold::new(token).encode());
            }
            match request.await {
                Ok(replies) => match replies.recv_async().await {
                    Ok(reply) => reply
                        .result()
                        .map(|_| ())
                        .map_err(|e| String::from_utf8_lossy(&e.payload().to_bytes()).into_owned()),
                    Err(_) => {
                        Err(format!("{axis}: no answer (its node vanished, or access control refused the write)"))
                    }
                },
                Err(e) => Err(e.to_string()),
            }
        }
    };
    let answer = match outcome {
        Ok(()) => serde_json::json!({ "id": id, "ok": true }),
        Err(error) => serde_json::json!({ "id": id, "error": error }),
    };
    let _ = out.send(answer.to_string());
}
