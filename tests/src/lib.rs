//! Helpers for end-to-end tests: a node on a free 127.0.0.1 port with multicast scouting off,
//! client sessions connected to it, and a recorder of published fields; and what the tests
//! need beyond Rust (`environment`).

pub mod environment;

use std::collections::HashMap;
use std::time::Duration;
use zenoh::bytes::Encoding;
use zenoh::key_expr::KeyExpr;
use zenoh::sample::Locality;
use zenoh::Session;
use zmotor_client::free_local_endpoint;
use zmotor_core::SimConfig;
use zmotor_core::{AxisPlan, DriverPlan, PollRates};
use zmotor_deploy::{import_db_text, Launch, Macros, NodeContents, ZenohConfig};
use zmotor_msgs::decode_cbor_value;
use zmotor_msgs::{Field, Fields, KeyLayout, StateMarker, Value};
use zmotor_node::Node;

/// Longest any single expectation waits before the test fails.
pub const PATIENCE: Duration = Duration::from_secs(10);

/// A fast simulated stage: MRES 0.001 mm, VELO 100 mm/s, ACCL 0.05 s, soft limits ±100 mm,
/// limit switches at ±105 mm, readback at 50 Hz.
pub fn fast_axis(name: &str) -> AxisPlan {
    AxisPlan {
        name: name.to_string(),
        fields: Fields {
            name: name.into(),
            mres: 0.001,
            velo: 100.0,
            accl: 0.05,
            dhlm: 100.0,
            dllm: -100.0,
            egu: "mm".into(),
            ..Fields::default()
        },
        driver: DriverPlan::Sim(SimConfig {
            high_limit_switch: Some(105_000.0),
            low_limit_switch: Some(-105_000.0),
            ..SimConfig::default()
        }),
        rates: PollRates { moving: Duration::from_millis(20), idle: Duration::from_secs(1) },
        jog_hold: zmotor_core::JogHold::Optional,
    }
}

/// A running node and the endpoint clients connect to.
pub struct TestNode {
    /// The node serving the axes; an `Option` so a test can take it to shut it down.
    pub node: Option<Node>,
    /// The node's own Zenoh session, listening on `endpoint`.
    pub session: Session,
    /// The 127.0.0.1 endpoint the node listens on, for clients to connect to.
    pub endpoint: String,
    /// The node's key layout.
    pub layout: KeyLayout,
}

impl TestNode {
    /// Start a node serving `plans`, with no calc links or value holders, on a free port.
    pub async fn start(plans: Vec<AxisPlan>) -> Self {
        let endpoint = free_local_endpoint().unwrap();
        let config = ZenohConfig { listen: vec![endpoint.clone()], ..ZenohConfig::default() };
        let session = zmotor_client::open(&config).await.unwrap();
        let layout = KeyLayout::default();
        let node =
            Node::start(session.clone(), layout.clone(), NodeContents { plans, ..NodeContents::default() }, None)
                .await
                .unwrap();
        Self { node: Some(node), session, endpoint, layout }
    }

    /// Start the axes and calc links of a launch file's text, on a free port.
    pub async fn launch(text: &str) -> Self {
        Self::deploy(Launch::parse(text).unwrap()).await
    }

    /// Start what an EPICS database's text imports to (no macros), on a free port.
    pub async fn launch_database(text: &str) -> Self {
        let (file, _) = import_db_text("test.db", text, &Macros::default(), zmotor_msgs::keys::DEFAULT_PREFIX).unwrap();
        Self::deploy(Launch::from_file("test.db", file).unwrap()).await
    }

    async fn deploy(launch: Launch) -> Self {
        let endpoint = free_local_endpoint().unwrap();
        let deployment = launch.deployment(None).unwrap();
        let config = ZenohConfig { listen: vec![endpoint.clone()], ..deployment.zenoh.clone() };
        let session = zmotor_client::open(&config).await.unwrap();
        let layout = KeyLayout::new(&deployment.zenoh.prefix);
        let node = Node::start(session.clone(), layout.clone(), deployment.contents, None).await.unwrap();
        Self { node: Some(node), session, endpoint, layout }
    }

    /// A client session connected to this node.
    pub async fn client(&self) -> Session {
        zmotor_client::open(&ZenohConfig::client(&self.endpoint)).await.unwrap()
    }

    /// Wait until a subscriber of another session covers `key_expr`, as this node sees it: its
    /// session routes there, and the node sends every post there (it publishes only what
    /// someone wants).
    pub async fn until_subscribed(&self, key_expr: &str) {
        let probe = self.session.declare_publisher(key_expr.to_string()).allowed_destination(Locality::Remote);
        let probe = probe.await.unwrap();
        let wanted = KeyExpr::try_from(key_expr).unwrap();
        let known = || self.node.as_ref().is_none_or(|node| node.knows_subscribers_of(&wanted));
        let deadline = tokio::time::Instant::now() + PATIENCE;
        while !(probe.matching_status().await.unwrap().matching() && known()) {
            assert!(
                tokio::time::Instant::now() < deadline,
                "no subscriber of {key_expr} reached the node in {PATIENCE:?}"
            );
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    }

    /// The key of one field of an axis of this node.
    pub fn key(&self, axis: &str, field: Field) -> String {
        self.layout.field(axis, field)
    }
}

/// A plain (fire-and-forget) put of text, as a stock tool would send it.
pub async fn put_text(session: &Session, key: &str, text: &str) {
    session.put(key, text.to_string()).encoding(Encoding::TEXT_PLAIN).await.unwrap();
}

/// A confirmed write: Ok(reply payload) or Err(the node's error text).
pub async fn confirmed_write(
    session: &Session,
    selector: &str,
    text: &str,
    timeout: Duration,
) -> Result<Vec<u8>, String> {
    let replies =
        session.get(selector).payload(text.to_string()).encoding(Encoding::TEXT_PLAIN).timeout(timeout).await.unwrap();
    let reply = replies.recv_async().await.map_err(|_| "no reply".to_string())?;
    match reply.result() {
        Ok(sample) => Ok(sample.payload().to_bytes().into_owned()),
        Err(err) => Err(String::from_utf8_lossy(&err.payload().to_bytes()).into_owned()),
    }
}

/// Read one field with a get.
pub async fn get_value(session: &Session, key: &str) -> Value {
    let replies = session.get(key).timeout(PATIENCE).await.unwrap();
    let reply = replies.recv_async().await.expect("a reply");
    decode_cbor_value(&reply.result().expect("a value").payload().to_bytes()).unwrap()
}

/// Read one numeric field with a get, as f64.
pub async fn get_f64(session: &Session, key: &str) -> f64 {
    get_value(session, key).await.as_f64().expect("a number")
}

/// One publication seen by a `Recorder`.
#[derive(Clone, Debug)]
pub struct Seen {
    /// The key it was published on.
    pub key: String,
    /// The published value (CBOR decoded; other encodings as text).
    pub value: Value,
    /// The state marker attached to it.
    pub marker: StateMarker,
}

/// Records every state publication under a key expression, in arrival order; samples without
/// the state marker (clients' writes) are only counted.
pub struct Recorder {
    subscriber: zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    /// Every state publication recorded so far, in arrival order.
    pub seen: Vec<Seen>,
    /// Number of samples received without a state marker (writes, not state).
    pub unmarked: usize,
}

impl Recorder {
    /// Subscribe `session` to `key_expr`, and return once `node` sees the subscription (a
    /// publisher of its own on `key_expr` matches it), so nothing it publishes is missed.
    pub async fn new(node: &TestNode, session: &Session, key_expr: &str) -> Self {
        let subscriber = session.declare_subscriber(key_expr.to_string()).await.unwrap();
        node.until_subscribed(key_expr).await;
        Self { subscriber, seen: Vec::new(), unmarked: 0 }
    }

    fn record(&mut self, sample: zenoh::sample::Sample) -> Option<Seen> {
        let Some(marker) = sample.attachment().and_then(|a| StateMarker::decode(&a.to_bytes())) else {
            self.unmarked += 1;
            return None;
        };
        let payload = sample.payload().to_bytes();
        let value = if *sample.encoding() == Encoding::APPLICATION_CBOR {
            decode_cbor_value(&payload).expect("CBOR publication")
        } else {
            Value::Text(String::from_utf8_lossy(&payload).into_owned())
        };
        let seen = Seen { key: sample.key_expr().as_str().to_string(), value, marker };
        self.seen.push(seen.clone());
        Some(seen)
    }

    /// Wait until a publication on a key ending in `/<suffix>` satisfies `accept`; panics after PATIENCE.
    pub async fn wait_for(&mut self, suffix: &str, accept: impl Fn(&Value) -> bool) -> Value {
        let deadline = tokio::time::Instant::now() + PATIENCE;
        loop {
            let sample = tokio::time::timeout_at(deadline, self.subscriber.recv_async())
                .await
                .unwrap_or_else(|_| {
                    panic!("no publication of {suffix} as expected within {PATIENCE:?}; seen {:?}", self.values(suffix))
                })
                .unwrap();
            let Some(seen) = self.record(sample) else {
                continue;
            };
            if seen.key.ends_with(&format!("/{suffix}")) && accept(&seen.value) {
                return seen.value;
            }
        }
    }

    /// Record whatever arrives during `quiet`.
    pub async fn drain_for(&mut self, quiet: Duration) {
        let deadline = tokio::time::Instant::now() + quiet;
        while let Ok(Ok(sample)) = tokio::time::timeout_at(deadline, self.subscriber.recv_async()).await {
            self.record(sample);
        }
    }

    /// Values published so far on keys ending in `/<suffix>`.
    pub fn values(&self, suffix: &str) -> Vec<Value> {
        let tail = format!("/{suffix}");
        self.seen.iter().filter(|s| s.key.ends_with(&tail)).map(|s| s.value.clone()).collect()
    }
}

/// Whether `(key, seq)` samples came in the order the node posted them: each with a larger
/// seq than any before it, except a sample sent again (after congestion the node sends each
/// readback key's last sample again: the same sample, as a repeat of that key's latest).
pub fn in_post_order<'a>(samples: impl IntoIterator<Item = (&'a str, u64)>) -> bool {
    let mut latest: HashMap<&str, u64> = HashMap::new();
    let mut newest = None;
    samples.into_iter().all(|(key, seq)| {
        let again = latest.get(key) == Some(&seq);
        let next = newest.is_none_or(|newest| seq > newest);
        if next {
            newest = Some(seq);
            latest.insert(key, seq);
        }
        again || next
    })
}

/// `Value::Int(v)`, for short expectations.
pub fn int(v: i64) -> Value {
    Value::Int(v)
}

#[cfg(test)]
mod tests {
    use super::in_post_order;

    #[test]
    fn post_order_allows_only_a_key_s_latest_sample_again() {
        assert!(in_post_order([("RBV", 1), ("DRBV", 2), ("RBV", 1), ("DRBV", 2), ("DMOV", 3)]));
        assert!(!in_post_order([("RBV", 2), ("DRBV", 1)]), "an older sample, never seen");
        assert!(!in_post_order([("RBV", 1), ("RBV", 2), ("RBV", 1)]), "not the key's latest");
        assert!(!in_post_order([("RBV", 1), ("DRBV", 1)]), "another key's seq");
    }
}
