//! What follows keys besides the axes: input links (as EPICS links follow PVs), calc links and
//! value holders.

use std::time::Duration;
use zenoh::bytes::Encoding;
use zenoh::sample::Sample;
use zenoh::{Session, Wait};
use zmotor_bridge::CalcLink;
use zmotor_msgs::{decode_scalar, encode_cbor, PayloadEncoding, StateMarker, Value};

/// Follows keys as EPICS links follow PVs: every update, and the current value asked for once
/// at the start (as a link does when it connects). Any sample is a reading, state or write.
pub(crate) struct KeyFollower {
    /// (index of the key, value), in arrival order.
    pub(crate) values: tokio::sync::mpsc::UnboundedReceiver<(usize, f64)>,
    _subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
}

impl KeyFollower {
    pub(crate) async fn start(session: &Session, keys: Vec<String>) -> Result<Self, zenoh::Error> {
        let (tx, values) = tokio::sync::mpsc::unbounded_channel();
        let mut subscribers = Vec::new();
        for (index, key) in keys.iter().enumerate() {
            let updates = tx.clone();
            let subscriber = session
                .declare_subscriber(key.clone())
                .callback(move |sample| {
                    if let Some(value) = sample_number(&sample) {
                        let _ = updates.send((index, value));
                    }
                })
                .await?;
            subscribers.push(subscriber);
            let replies = session.get(key.clone()).timeout(Duration::from_secs(5)).await?;
            let tx = tx.clone();
            tokio::spawn(async move {
                while let Ok(reply) = replies.recv_async().await {
                    if let Some(value) = reply.result().ok().and_then(sample_number) {
                        let _ = tx.send((index, value));
                    }
                }
            });
        }
        Ok(Self { values, _subscribers: subscribers })
    }
}

/// The number a sample carries, whatever its encoding.
fn sample_number(sample: &Sample) -> Option<f64> {
    let encoding = PayloadEncoding::from_mime(&sample.encoding().to_string());
    decode_scalar(&sample.payload().to_bytes(), encoding).ok()?.as_f64()
}

/// A publication of some node (it carries the state marker), never a write.
pub(crate) fn is_state(sample: &Sample) -> bool {
    sample.attachment().is_some_and(|a| StateMarker::is_marker(&a.to_bytes()))
}

/// A calc link: recompute on its inputs, write the result to its output key.
pub(crate) struct CalcTask {
    pub(crate) session: Session,
    pub(crate) link: CalcLink,
    pub(crate) inputs: KeyFollower,
}

impl CalcTask {
    pub(crate) async fn run(&mut self) {
        let keys: Vec<String> = self.link.input_keys().map(str::to_string).collect();
        while let Some((index, value)) = self.inputs.values.recv().await {
            if let Some(result) = self.link.update(&keys[index], value) {
                let output = &self.link.spec().output;
                // A write to the output key, like a calcout's OUT: plain, no state marker.
                if let Err(e) = self.session.put(output, result.to_string()).encoding(Encoding::TEXT_PLAIN).await {
                    tracing::warn!(calc = %self.link.spec().name, output, "output put failed: {e}");
                }
            }
        }
    }
}

/// A value holder ready to start: its key and the value it holds before any write.
#[derive(Clone, Debug, PartialEq)]
pub struct ValueSpec {
    /// The key it holds the value of.
    pub key: String,
    /// The value before anything is written.
    pub initial: f64,
}

/// A value holder (an ao/ai record that only holds a value): keeps the latest number put on
/// its key and answers reads of it.
pub(crate) struct ValueHolder {
    _updates: zenoh::pubsub::Subscriber<()>,
    _reads: zenoh::query::Queryable<()>,
}

impl ValueHolder {
    pub(crate) async fn declare(session: &Session, spec: ValueSpec) -> Result<Self, zenoh::Error> {
        let value = std::sync::Arc::new(std::sync::Mutex::new(spec.initial));
        let latest = value.clone();
        let updates = session
            .declare_subscriber(spec.key.clone())
            .callback(move |sample| match sample_number(&sample) {
                Some(x) => *latest.lock().unwrap_or_else(|e| e.into_inner()) = x,
                None => tracing::warn!(key = %sample.key_expr(), "value holder: not a number; ignored"),
            })
            .await?;
        let reads = session
            .declare_queryable(spec.key.clone())
            .callback(move |query| {
                let x = *value.lock().unwrap_or_else(|e| e.into_inner());
                let reply = query.reply(query.key_expr().clone(), encode_cbor(&Value::Float(x)));
                // Replies of a callback are sent without waiting: callbacks must not block.
                let _ = reply.encoding(Encoding::APPLICATION_CBOR).wait();
            })
            .await?;
        Ok(Self { _updates: updates, _reads: reads })
    }
}
