//! zmotor-ros2, the ROS 2 gateway: the axes a launch or command line names, as the joints of
//! one ROS 2 node on the same Zenoh network, following rmw_zenoh's conventions
//! (zmotor-ros2-proto), as a client of that network (zmotor-client). It declares the node's
//! liveliness tokens and those of its `joint_states` publisher and `joint_commands`
//! subscription, publishes the joints' state (with the attachment every ROS sample carries)
//! and turns joint commands into confirmed writes of VAL, so refusals and access rules are the
//! node's. Not yet: transient-local state, the FollowJointTrajectory action.

use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};
use zenoh::liveliness::LivelinessToken;
use zmotor_client::{Client, Selection, WriteOptions, WriteOutcome};
use zmotor_msgs::{Field, Value};
use zmotor_ros2_proto::{
    decode, encode, topic_key, Attachment, EntityKind, GraphEntity, Joint, JointState, JointStates, Qos, JOINT_STATE,
};

/// Which axes are which joints, and the node they make.
#[derive(Clone, Debug, PartialEq)]
pub struct Ros2Config {
    /// The ROS domain id (ROS_DOMAIN_ID).
    pub domain: u32,
    /// The node's namespace, `/` for none.
    pub namespace: String,
    /// The node's name.
    pub node_name: String,
    /// Each joint: its ROS name, its axis, and SI units per EGU if not from the axis's EGU.
    pub joints: Vec<(String, String, Option<f64>)>,
    /// How often the state is published at rest.
    pub rest_period: Duration,
}

/// The gateway could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Ros2Error {
    /// A joint's axis is not served, or its units give no SI.
    #[error("{0}")]
    Joint(String),
    /// A Zenoh declaration failed.
    #[error("zenoh: {0}")]
    Zenoh(#[from] zenoh::Error),
}

/// How long a joint's axis may take to answer.
const PATIENCE: Duration = Duration::from_secs(5);

/// The QoS both topics declare: rclcpp's `QoS(10)`, reliable and volatile.
const TOPIC_QOS: u32 = 10;

/// A running ROS 2 face; dropping it takes the node out of the ROS graph.
pub struct Ros2Node {
    tasks: Vec<tokio::task::JoinHandle<()>>,
    _tokens: Vec<LivelinessToken>,
    _commands: zenoh::pubsub::Subscriber<()>,
}

impl Drop for Ros2Node {
    fn drop(&mut self) {
        self.tasks.iter().for_each(tokio::task::JoinHandle::abort);
    }
}

/// Time since the Unix epoch.
fn wall() -> Duration {
    SystemTime::now().duration_since(SystemTime::UNIX_EPOCH).unwrap_or_default()
}

/// The fully qualified name of a topic of the node.
fn qualified(namespace: &str, topic: &str) -> String {
    format!("{}/{topic}", namespace.trim_end_matches('/'))
}

impl Ros2Node {
    /// The node, its joints' axes reached through `client`.
    pub async fn start(client: Client, config: &Ros2Config) -> Result<Self, Ros2Error> {
        let mut joints = Vec::new();
        for (name, axis, factor) in &config.joints {
            let reading = client.read(axis, Selection::Field(Field::EGU)).await?;
            let egu = match reading.readings.iter().find(|r| r.field == Some(Field::EGU)).map(|r| &r.value) {
                Some(Value::Text(egu)) => egu.clone(),
                _ => return Err(Ros2Error::Joint(format!("joint '{name}': axis '{axis}' is not served"))),
            };
            joints.push(Joint::new(name, axis, &egu, *factor).map_err(|e| Ros2Error::Joint(e.to_string()))?);
        }
        let session = client.session().clone();
        let zid = session.zid().to_string();
        let entity = |id: u64, kind: EntityKind, topic: Option<&str>| GraphEntity {
            domain: config.domain,
            zid: zid.clone(),
            node_id: 0,
            id,
            kind,
            enclave: "/".into(),
            namespace: config.namespace.clone(),
            node: config.node_name.clone(),
            endpoint: topic.map(|t| (qualified(&config.namespace, t), JOINT_STATE, Qos::keep_last(TOPIC_QOS))),
        };
        let node = entity(0, EntityKind::Node, None);
        let publisher = entity(1, EntityKind::Publisher, Some("joint_states"));
        let subscription = entity(2, EntityKind::Subscription, Some("joint_commands"));
        let mut tokens = Vec::new();
        for graph in [&node, &publisher, &subscription] {
            tokens.push(session.liveliness().declare_token(graph.token_key()).await?);
        }
        let states_key = topic_key(config.domain, &qualified(&config.namespace, "joint_states"), &JOINT_STATE);
        let commands_key = topic_key(config.domain, &qualified(&config.namespace, "joint_commands"), &JOINT_STATE);
        let states = Arc::new(Mutex::new(JointStates::new(joints, config.rest_period)));

        let mut tasks = Vec::new();
        // Each joint's axis followed: RBV and DMOV, current values first.
        let (changed, mut wake) = tokio::sync::mpsc::unbounded_channel::<()>();
        let axes: Vec<String> = states.lock().expect("not poisoned").joints().iter().map(|j| j.axis.clone()).collect();
        for axis in axes {
            let mut monitor = client.monitor(&axis, &[Field::RBV, Field::DMOV]).await?;
            let (states, changed) = (states.clone(), changed.clone());
            tasks.push(tokio::spawn(async move {
                while let Some(update) = monitor.next().await {
                    let at = update.at.duration_since(SystemTime::UNIX_EPOCH).unwrap_or_default();
                    let mut states = states.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
                    match (update.field, update.value.as_f64()) {
                        (Some(Field::RBV), Some(rbv)) => states.readback(&update.axis, rbv, at),
                        (Some(Field::DMOV), Some(dmov)) => states.done_moving(&update.axis, dmov != 0.0),
                        _ => continue,
                    }
                    drop(states);
                    let _ = changed.send(());
                }
            }));
        }
        // The state published when a readback came, and at rest every period.
        let gid = publisher.gid();
        let publisher_session = session.clone();
        let publishing_states = states.clone();
        tasks.push(tokio::spawn(async move {
            let Ok(publisher) = publisher_session.declare_publisher(states_key).await else { return };
            let mut sequence = 0;
            loop {
                let now = wall();
                let (message, next) = {
                    let mut states = publishing_states.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
                    (states.poll_publish(now), states.poll_timeout())
                };
                if let Some(message) = message {
                    sequence += 1;
                    let attachment =
                        Attachment { sequence, source_time_ns: i64::try_from(now.as_nanos()).unwrap_or(i64::MAX), gid };
                    let sent = publisher.put(encode(&message)).attachment(attachment.encode()).await;
                    if let Err(e) = sent {
                        tracing::warn!("joint_states not published: {e}");
                    }
                }
                let wait = next.map_or(Duration::from_millis(100), |t| t.saturating_sub(wall()));
                tokio::select! {
                    _ = wake.recv() => {}
                    _ = tokio::time::sleep(wait) => {}
                }
            }
        }));
        // Joint commands: one confirmed write of VAL per joint, all or none.
        let commanding = states.clone();
        let writer = client.clone();
        let commands = session
            .declare_subscriber(commands_key)
            .callback(move |sample| {
                let command = match decode::<JointState>(&sample.payload().to_bytes(), "JointState") {
                    Ok(command) => command,
                    Err(e) => return tracing::warn!("joint_commands: {e}"),
                };
                let targets = commanding.lock().unwrap_or_else(std::sync::PoisonError::into_inner).command(&command);
                let targets = match targets {
                    Ok(targets) => targets,
                    Err(e) => return tracing::warn!("joint_commands: {e}; nothing moved"),
                };
                let writer = writer.clone();
                tokio::spawn(async move {
                    for (axis, target) in targets {
                        let sent =
                            writer.write(&axis, Field::VAL, target.to_string(), WriteOptions::confirmed(PATIENCE));
                        match sent.await {
                            Ok(sent) => match sent.outcome().await {
                                WriteOutcome::Accepted(_) | WriteOutcome::Completed(_) => {}
                                other => tracing::warn!(axis, "joint command: {other}"),
                            },
                            Err(e) => tracing::warn!(axis, "joint command not sent: {e}"),
                        }
                    }
                });
            })
            .await?;
        tracing::info!(
            node = config.node_name,
            namespace = config.namespace,
            domain = config.domain,
            "ROS 2 node serving its joints"
        );
        Ok(Self { tasks, _tokens: tokens, _commands: commands })
    }
}
