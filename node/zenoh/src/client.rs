//! What the front-ends (Channel Access, web) do as clients of the network: a confirmed write,
//! sent at once (so a client's writes reach the node in its order) and answered later.

use std::time::Duration;
use zenoh::bytes::Encoding;
use zenoh::handlers::FifoChannelHandler;
use zenoh::query::Reply;
use zenoh::Session;
use zmotor_msgs::{Field, Hold, KeyLayout};

/// A confirmed write on its way: `outcome` awaits the node's answer.
pub struct SentWrite {
    replies: Result<FifoChannelHandler<Reply>, String>,
    axis: String,
}

/// Send `value` to `axis`'s `field` as a confirmed write to its write key (with `?wait`, answered
/// at the end of the motion it starts; with `hold`, held by that token), waiting `patience` at
/// most for the answer.
pub async fn confirmed_write(
    session: &Session,
    layout: &KeyLayout,
    (axis, field): (&str, Field),
    value: String,
    (wait, hold): (bool, Option<&str>),
    patience: Duration,
) -> SentWrite {
    let mut request = session
        .get(layout.write_selector(axis, field, wait))
        .payload(value)
        .encoding(Encoding::TEXT_PLAIN)
        .timeout(patience);
    if let Some(token) = hold {
        request = request.attachment(Hold::new(token).encode());
    }
    SentWrite { replies: request.await.map_err(|e| e.to_string()), axis: axis.to_string() }
}

impl SentWrite {
    /// The node's answer: `Err` with its words, or saying that nothing answered.
    pub async fn outcome(self) -> Result<(), String> {
        let reply = self.replies?.recv_async().await.map_err(|_| {
            format!("{}: no answer (its node vanished, or access control refused the write)", self.axis)
        })?;
        reply.result().map(|_| ()).map_err(|e| String::from_utf8_lossy(&e.payload().to_bytes()).into_owned())
    }
}
