//! zmotor-ros2, the ROS 2 gateway: the axes a launch or command line names, as the joints of
//! one ROS 2 node on the same Zenoh network, following rmw_zenoh's conventions
//! (zmotor-ros2-proto), as a client of that network (zmotor-client). It declares the node's
//! liveliness tokens and those of its endpoints: the `joint_states` publisher (transient local:
//! a late subscriber gets the last state), the `joint_commands` and `joint_trajectory`
//! subscriptions, the `follow_joint_trajectory` action (three services, two topics) and the
//! `controller_state` publisher (joint_trajectory_controller's, sent with each joint state). Joint commands and
//! trajectory moves are confirmed writes, so refusals and access rules are the node's (which
//! posts a refusal on the axis's ERR). One task drives the sans-IO state; the rest only moves
//! bytes. The joints' values come from monitors over the network (`start`), or, in the process
//! of a node, from its posts for its own axes (`start_fed` and its `Feed`), one Zenoh hop
//! sooner, and from monitors for the others.

use std::collections::HashSet;
use std::time::{Duration, SystemTime};
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver, UnboundedSender};
use zenoh::liveliness::LivelinessToken;
use zenoh::query::{Query, Queryable};
use zenoh::Session;
use zenoh_ext::{AdvancedPublisher, AdvancedPublisherBuilderExt, CacheConfig, MissDetectionConfig};
use zmotor_client::{AxisReading, Client, Selection, WriteOptions, WriteOutcome};
use zmotor_deploy::{JointConfig, Ros2Config};
use zmotor_msgs::{Field, Value};
use zmotor_ros2_proto::{
    decode, encode, topic_key, Answered, Attachment, CancelGoalRequest, CancelGoalResponse, Distribution, Durability,
    EntityKind, FollowJointTrajectory, GetResultRequest, GetResultResponse, GoalId, GraphEntity, Joint, JointCommand,
    JointState, JointStates, JointTrajectory, LaneEvent, LaneWrite, Qos, Reliability, SendGoalRequest,
    SendGoalResponse, Time, TypeInfo, WriteAnswer, WriteId, WriteLanes, CANCEL_GOAL, CONTROLLER_STATE, FEEDBACK,
    GET_RESULT, GOAL_STATUS_ARRAY, JOINT_STATE, JOINT_TRAJECTORY, SEND_GOAL,
};

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

/// rclcpp's `QoS(10)`: the commands topic, the feedback topic and the services.
const DEFAULT_QOS: Qos = Qos { reliability: Reliability::Reliable, durability: Durability::Volatile, depth: 10 };
/// rclcpp's `SystemDefaultsQoS()`, as rmw_zenoh fills it in (reliable, volatile, depth 42):
/// joint_trajectory_controller's `~/joint_trajectory` and `~/controller_state`.
const SYSTEM_DEFAULT_QOS: Qos = Qos { reliability: Reliability::Reliable, durability: Durability::Volatile, depth: 42 };
/// The state: its last sample kept for late subscribers.
const STATE_QOS: Qos = Qos { reliability: Reliability::Reliable, durability: Durability::TransientLocal, depth: 1 };
/// An action's status topic (`rcl_action_qos_profile_status_default`).
const STATUS_QOS: Qos = STATE_QOS;

/// The fields each joint's axis is followed by.
const FOLLOWED: [Field; 13] = [
    Field::RBV,
    Field::VAL,
    Field::DMOV,
    Field::HLM,
    Field::LLM,
    Field::DHLM,
    Field::DLLM,
    Field::VELO,
    Field::RDBD,
    Field::ACCL,
    Field::VBAS,
    Field::ACCU,
    Field::ACCS,
];

/// A running ROS 2 face; dropping it takes the node out of the ROS graph.
pub struct Ros2Node {
    tasks: Vec<tokio::task::JoinHandle<()>>,
    _tokens: Vec<LivelinessToken>,
    _commands: zenoh::pubsub::Subscriber<()>,
    _trajectories: zenoh::pubsub::Subscriber<()>,
    _services: Vec<Queryable<()>>,
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

fn nanos(at: Duration) -> i64 {
    i64::try_from(at.as_nanos()).unwrap_or(i64::MAX)
}

/// The fully qualified name of a topic or service of the node.
fn qualified(namespace: &str, name: &str) -> String {
    format!("{}/{name}", namespace.trim_end_matches('/'))
}

/// The action's services.
#[derive(Clone, Copy, Debug)]
enum Service {
    SendGoal,
    CancelGoal,
    GetResult,
}

/// What the driving task is told.
enum Event {
    /// A followed field of a joint's axis.
    Posted { axis: String, field: Field, value: f64, at: Duration },
    /// A value read at start: taken unless a post of that field came first.
    Read { axis: String, field: Field, value: f64, at: Duration },
    /// A joint_commands sample.
    JointCommand(Vec<u8>),
    /// A joint_trajectory sample.
    Trajectory(Vec<u8>),
    /// A request to one of the action's services.
    Request(Service, Query),
    /// A lane's write has left.
    HandedOver(WriteId),
    /// A lane's write was answered (or failed to leave).
    Answered(WriteId, WriteAnswer),
}

/// A publisher as rmw_zenoh makes one: advanced (a cache of `depth` for transient local), each
/// sample with its attachment.
struct RosPublisher {
    publisher: AdvancedPublisher<'static>,
    gid: [u8; 16],
    sequence: i64,
}

impl RosPublisher {
    /// rmw_zenoh_cpp `rmw_publisher_data.cpp`: transient local adds a cache of `depth`,
    /// publisher detection and a sporadic heartbeat of 500 ms for reliable ones.
    async fn declare(session: &Session, key: String, qos: Qos, gid: [u8; 16]) -> Result<Self, zenoh::Error> {
        let mut builder =
            session.declare_publisher(key).congestion_control(zenoh::qos::CongestionControl::Drop).advanced();
        if qos.durability == Durability::TransientLocal {
            builder = builder
                .publisher_detection()
                .cache(CacheConfig::default().max_samples(qos.depth as usize))
                .sample_miss_detection(MissDetectionConfig::default().sporadic_heartbeat(Duration::from_millis(500)));
        }
        Ok(Self { publisher: builder.await?, gid, sequence: 0 })
    }

    async fn publish(&mut self, payload: Vec<u8>, now: Duration) {
        self.sequence += 1;
        let attachment = Attachment { sequence: self.sequence, source_time_ns: nanos(now), gid: self.gid };
        if let Err(e) = self.publisher.put(payload).attachment(attachment.encode()).await {
            tracing::warn!(key = %self.publisher.key_expr(), "not published: {e}");
        }
    }
}

/// Reply to a service request as rmw_zenoh does: the response, with the request's sequence
/// number and client GID in the attachment (`rmw_service_data.cpp`, `send_response`).
async fn reply(query: &Query, request: &Attachment, payload: Vec<u8>) {
    let attachment = Attachment { sequence: request.sequence, source_time_ns: nanos(wall()), gid: request.gid };
    if let Err(e) = query.reply(query.key_expr().clone(), payload).attachment(attachment.encode()).await {
        tracing::warn!(key = %query.key_expr(), "no reply sent: {e}");
    }
}

/// The request's attachment, without which rmw_zenoh takes no request.
fn request_attachment(query: &Query) -> Option<Attachment> {
    let attachment = query.attachment().and_then(|a| Attachment::decode(&a.to_bytes()).ok());
    if attachment.is_none() {
        tracing::warn!(key = %query.key_expr(), "a request without rmw_zenoh's attachment: not answered");
    }
    attachment
}

/// A joint's axis's fields and its EGU, once a node serves it: at once (or the joint is
/// refused), or when `waits`, whenever its node comes (its liveliness token, or a second on).
async fn read_served(client: &Client, joint: &JointConfig, waits: bool) -> Result<(AxisReading, String), Ros2Error> {
    let (came, mut coming) = unbounded_channel();
    let token = client.layout().axis(&joint.axis);
    let _tokens = match waits {
        true => Some(
            client
                .session()
                .liveliness()
                .declare_subscriber(token)
                .callback(move |sample| {
                    let _ = came.send(sample.kind());
                })
                .await?,
        ),
        false => None,
    };
    let mut told = false;
    loop {
        let reading = client.read(&joint.axis, Selection::All).await?;
        if let Some(Value::Text(egu)) = reading.readings.iter().find(|r| r.field == Some(Field::EGU)).map(|r| &r.value)
        {
            let egu = egu.clone();
            return Ok((reading, egu));
        }
        if !waits {
            return Err(Ros2Error::Joint(format!("joint '{}': axis '{}' is not served", joint.name, joint.axis)));
        }
        if !told {
            tracing::info!(joint = joint.name, axis = joint.axis, "waiting for a node to serve the joint's axis");
            told = true;
        }
        let _ = tokio::time::timeout(Duration::from_secs(1), coming.recv()).await;
    }
}

/// Where the joints' values come from.
enum Source<'a> {
    /// Monitors of each joint's axis over the network.
    Monitors,
    /// A `Feed` the caller posts to, for the joints of these axes (its node's); monitors for
    /// the others, whose nodes (a launch's other hosts) may start after this one.
    Fed(&'a [String]),
}

impl Source<'_> {
    /// Whether the joint of `axis` is followed over the network.
    fn monitors(&self, axis: &str) -> bool {
        match self {
            Source::Monitors => true,
            Source::Fed(fed) => !fed.iter().any(|a| a == axis),
        }
    }
}

/// Hands the values of the joints' axes to a running ROS face from the node that posts them,
/// in the same process (`zmotor_node::Node::follow_posts` with `keys()`).
#[derive(Clone)]
pub struct Feed {
    events: UnboundedSender<Event>,
    keys: Vec<(String, Field)>,
    layout: zmotor_msgs::KeyLayout,
}

impl std::fmt::Debug for Feed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Feed").field("keys", &self.keys).finish_non_exhaustive()
    }
}

impl Feed {
    /// The keys whose values the ROS face needs, by index: each joint's axis's fields it
    /// follows (RBV, DMOV, VAL, soft limits, VELO, RDBD and the ramps').
    #[must_use]
    pub fn keys(&self) -> Vec<String> {
        self.keys.iter().map(|(axis, field)| self.layout.field(axis, *field)).collect()
    }

    /// Key `index` took `value`, now.
    pub fn post(&self, index: usize, value: f64) {
        if let Some((axis, field)) = self.keys.get(index) {
            let event = Event::Posted { axis: axis.clone(), field: *field, value, at: wall() };
            let _ = self.events.send(event);
        }
    }
}

impl Ros2Node {
    /// The node, its joints' axes reached and followed through `client`.
    pub async fn start(client: Client, config: &Ros2Config) -> Result<Self, Ros2Error> {
        Ok(Self::serve(client, config, Source::Monitors).await?.0)
    }

    /// The node, its joints' axes reached through `client`; the values of those on the `fed`
    /// axes posted to the `Feed` returned (their current values are read once), the others
    /// followed over the network, waited for until a node serves them (in a launch over
    /// several hosts, another host's, which may start later).
    pub async fn start_fed(client: Client, config: &Ros2Config, fed: &[String]) -> Result<(Self, Feed), Ros2Error> {
        Self::serve(client, config, Source::Fed(fed)).await
    }

    async fn serve(client: Client, config: &Ros2Config, source: Source<'_>) -> Result<(Self, Feed), Ros2Error> {
        let (events, inbox) = unbounded_channel();
        let mut joints = Vec::new();
        for joint in &config.joints {
            let waits = matches!(source, Source::Fed(_)) && source.monitors(&joint.axis);
            let (reading, egu) = read_served(&client, joint, waits).await?;
            let made = Joint::new(&joint.name, &joint.axis, &egu, joint.factor);
            joints.push(made.map_err(|e| Ros2Error::Joint(e.to_string()))?);
            for read in reading.readings.iter().filter(|r| r.field.is_some_and(|f| FOLLOWED.contains(&f))) {
                let (Some(field), Some(value)) = (read.field, read.value.as_f64()) else { continue };
                let _ = events.send(Event::Read { axis: joint.axis.clone(), field, value, at: wall() });
            }
        }
        let session = client.session().clone();
        let zid = session.zid().to_string();
        let mut next_id = 0;
        let mut entity = |kind: EntityKind, endpoint: Option<(&str, TypeInfo, Qos)>| {
            let id = next_id;
            next_id += 1;
            GraphEntity {
                domain: config.domain_id,
                zid: zid.clone(),
                node_id: 0,
                id,
                kind,
                enclave: "/".into(),
                namespace: config.namespace.clone(),
                node: config.node_name.clone(),
                endpoint: endpoint.map(|(name, type_info, qos)| {
                    (qualified(&config.namespace, name), type_info.in_distribution(config.distribution), qos)
                }),
            }
        };
        let action = |part: &str| format!("follow_joint_trajectory/_action/{part}");
        let (send_goal, cancel_goal, get_result) = (action("send_goal"), action("cancel_goal"), action("get_result"));
        let (feedback_topic, status_topic) = (action("feedback"), action("status"));
        let graph = [
            entity(EntityKind::Node, None),
            entity(EntityKind::Publisher, Some(("joint_states", JOINT_STATE, STATE_QOS))),
            entity(EntityKind::Subscription, Some(("joint_commands", JOINT_STATE, DEFAULT_QOS))),
            entity(EntityKind::ServiceServer, Some((&send_goal, SEND_GOAL, DEFAULT_QOS))),
            entity(EntityKind::ServiceServer, Some((&cancel_goal, CANCEL_GOAL, DEFAULT_QOS))),
            entity(EntityKind::ServiceServer, Some((&get_result, GET_RESULT, DEFAULT_QOS))),
            entity(EntityKind::Publisher, Some((&feedback_topic, FEEDBACK, DEFAULT_QOS))),
            entity(EntityKind::Publisher, Some((&status_topic, GOAL_STATUS_ARRAY, STATUS_QOS))),
            entity(EntityKind::Subscription, Some(("joint_trajectory", JOINT_TRAJECTORY, SYSTEM_DEFAULT_QOS))),
            entity(EntityKind::Publisher, Some(("controller_state", CONTROLLER_STATE, SYSTEM_DEFAULT_QOS))),
        ];
        let key = |entity: &GraphEntity| {
            let (name, type_info, _) = entity.endpoint.as_ref().expect("an endpoint");
            topic_key(config.domain_id, name, type_info)
        };
        let mut tasks = Vec::new();
        for joint in joints.iter().filter(|j| source.monitors(&j.axis)) {
            let mut monitor = client.monitor(&joint.axis, &FOLLOWED).await?;
            let events = events.clone();
            tasks.push(tokio::spawn(async move {
                while let Some(update) = monitor.next().await {
                    let (Some(field), Some(value)) = (update.field, update.value.as_f64()) else { continue };
                    let at = update.at.duration_since(SystemTime::UNIX_EPOCH).unwrap_or_default();
                    if events.send(Event::Posted { axis: update.axis, field, value, at }).is_err() {
                        return;
                    }
                }
            }));
        }
        let fed = joints.iter().filter(|j| !source.monitors(&j.axis));
        let keys = fed.flat_map(|j| FOLLOWED.iter().map(|f| (j.axis.clone(), *f))).collect();
        let feed = Feed { events: events.clone(), keys, layout: client.layout().clone() };
        let commanding = events.clone();
        let commands = session
            .declare_subscriber(key(&graph[2]))
            .callback(move |sample| {
                let _ = commanding.send(Event::JointCommand(sample.payload().to_bytes().into_owned()));
            })
            .await?;
        let following = events.clone();
        let trajectories = session
            .declare_subscriber(key(&graph[8]))
            .callback(move |sample| {
                let _ = following.send(Event::Trajectory(sample.payload().to_bytes().into_owned()));
            })
            .await?;
        let mut services = Vec::new();
        for (entity, service) in graph[3..6].iter().zip([Service::SendGoal, Service::CancelGoal, Service::GetResult]) {
            let events = events.clone();
            let queryable = session
                .declare_queryable(key(entity))
                .complete(true)
                .callback(move |query| {
                    let _ = events.send(Event::Request(service, query));
                })
                .await?;
            services.push(queryable);
        }
        let driver = Driver {
            states: JointStates::new(joints, config.rest_period, Duration::from_secs_f64(1.0 / config.max_rate)),
            follow: FollowJointTrajectory::new(),
            joint_states: RosPublisher::declare(&session, key(&graph[1]), STATE_QOS, graph[1].gid()).await?,
            feedback: RosPublisher::declare(&session, key(&graph[6]), DEFAULT_QOS, graph[6].gid()).await?,
            status: RosPublisher::declare(&session, key(&graph[7]), STATUS_QOS, graph[7].gid()).await?,
            controller_state: RosPublisher::declare(&session, key(&graph[9]), SYSTEM_DEFAULT_QOS, graph[9].gid())
                .await?,
            distribution: config.distribution,
            pending_results: Vec::new(),
            posted: HashSet::new(),
            lanes: WriteLanes::new(),
            client,
            events,
        };
        tasks.push(tokio::spawn(driver.run(inbox)));
        // The tokens last: the graph shows the node once it serves.
        let mut tokens = Vec::new();
        for entity in &graph {
            tokens.push(session.liveliness().declare_token(entity.token_key()).await?);
        }
        tracing::info!(
            node = config.node_name,
            namespace = config.namespace,
            domain = config.domain_id,
            "ROS 2 node serving its joints"
        );
        Ok((
            Self { tasks, _tokens: tokens, _commands: commands, _trajectories: trajectories, _services: services },
            feed,
        ))
    }
}

/// The task that owns the joints' state and the action server.
struct Driver {
    states: JointStates,
    follow: FollowJointTrajectory,
    joint_states: RosPublisher,
    feedback: RosPublisher,
    status: RosPublisher,
    controller_state: RosPublisher,
    /// The controller state's layout.
    distribution: Distribution,
    /// get_result requests waiting for their goal's end.
    pending_results: Vec<(GoalId, Query, Attachment)>,
    /// The fields of which a post came: a value read at start does not undo it.
    posted: HashSet<(String, Field)>,
    /// Each axis's writes, sent in the order they are asked.
    lanes: WriteLanes,
    client: Client,
    events: UnboundedSender<Event>,
}

/// Send a lane's write and report when it has left and how it was answered.
fn send(client: &Client, write: LaneWrite, events: &UnboundedSender<Event>) {
    let (client, events) = (client.clone(), events.clone());
    tokio::spawn(async move {
        let options = match write.answered {
            Answered::WhenTaken(patience) => WriteOptions::confirmed(patience),
            Answered::AtMotionEnd(patience) => WriteOptions::waiting(patience),
        };
        let answer = match client.write(&write.axis, write.field, write.value.to_string(), options).await {
            Ok(sent) => {
                let _ = events.send(Event::HandedOver(write.id));
                match sent.outcome().await {
                    WriteOutcome::Accepted(_) => WriteAnswer::Taken,
                    WriteOutcome::Completed(done) => {
                        WriteAnswer::MotionEnded { reached: done.reached == 1, readback: done.rbv }
                    }
                    other => WriteAnswer::Failed(other.to_string()),
                }
            }
            Err(e) => WriteAnswer::Failed(format!("not sent: {e}")),
        };
        let _ = events.send(Event::Answered(write.id, answer));
    });
}

impl Driver {
    async fn run(mut self, mut inbox: UnboundedReceiver<Event>) {
        loop {
            let now = wall();
            let commands = self.follow.poll(&self.states, now);
            self.execute(commands);
            while let Some(why) = self.follow.poll_refusal() {
                tracing::warn!("joint_trajectory: rejected once the trajectory it replaced had stopped: {why}");
            }
            if let Some(status) = self.follow.poll_status() {
                self.status.publish(encode(&status), now).await;
                self.answer_results().await;
            }
            if let Some(state) = self.states.poll_publish(now) {
                self.joint_states.publish(encode(&state), now).await;
                let controller = self.follow.controller_state(&self.states, &state);
                self.controller_state.publish(controller.encode(self.distribution), now).await;
                if let Some(feedback) = self.follow.feedback(&self.states, now) {
                    self.feedback.publish(encode(&feedback), now).await;
                }
            }
            let next = [self.states.poll_timeout(), self.follow.poll_timeout()].into_iter().flatten().min();
            let wait = next.map_or(Duration::from_millis(100), |at| at.saturating_sub(wall()));
            tokio::select! {
                event = inbox.recv() => match event {
                    Some(event) => self.handle(event).await,
                    None => return,
                },
                () = tokio::time::sleep(wait) => {}
            }
        }
    }

    async fn handle(&mut self, event: Event) {
        match event {
            Event::HandedOver(id) => {
                self.lanes.handed_over(id);
                self.flush();
            }
            Event::Answered(id, answer) => {
                self.lanes.answered(id, answer);
                self.flush();
            }
            Event::Posted { axis, field, value, at } => {
                self.states.update(&axis, field, value, at);
                self.posted.insert((axis, field));
            }
            Event::Read { axis, field, value, at } => {
                if !self.posted.contains(&(axis.clone(), field)) {
                    self.states.update(&axis, field, value, at);
                }
            }
            Event::JointCommand(payload) => self.joint_command(&payload),
            Event::Trajectory(payload) => self.trajectory(&payload),
            Event::Request(service, query) => self.request(service, query).await,
        }
    }

    /// A joint command: one confirmed write of VAL per joint, all or none, unless a trajectory
    /// is executing.
    fn joint_command(&mut self, payload: &[u8]) {
        let command = match decode::<JointState>(payload, "JointState") {
            Ok(command) => command,
            Err(e) => return tracing::warn!("joint_commands: {e}"),
        };
        if self.follow.executing() {
            return tracing::warn!("joint_commands: ignored while a trajectory executes");
        }
        match self.states.command(&command) {
            Ok(targets) => {
                for (axis, target) in targets {
                    self.lanes.joint_target(&axis, target);
                }
                self.flush();
            }
            Err(e) => tracing::warn!("joint_commands: {e}; nothing moved"),
        }
    }

    /// A trajectory on the topic: run as a goal no one follows, replacing the one running.
    fn trajectory(&mut self, payload: &[u8]) {
        let trajectory = match decode::<JointTrajectory>(payload, "JointTrajectory") {
            Ok(trajectory) => trajectory,
            Err(e) => return tracing::warn!("joint_trajectory: {e}"),
        };
        match self.follow.follow_trajectory(&trajectory, &self.states, wall()) {
            Ok(commands) => self.execute(commands),
            Err(why) => tracing::warn!("joint_trajectory: rejected: {why}; nothing moved"),
        }
    }

    async fn request(&mut self, service: Service, query: Query) {
        let Some(attachment) = request_attachment(&query) else { return };
        let payload = query.payload().map(|p| p.to_bytes().into_owned()).unwrap_or_default();
        let now = wall();
        match service {
            Service::SendGoal => {
                let accepted = match decode::<SendGoalRequest>(&payload, "FollowJointTrajectory goal") {
                    Ok(request) => match self.follow.send_goal(&request, &self.states, now) {
                        Ok(commands) => {
                            self.execute(commands);
                            true
                        }
                        Err(why) => {
                            tracing::warn!("follow_joint_trajectory: goal rejected: {why}");
                            false
                        }
                    },
                    Err(e) => {
                        tracing::warn!("follow_joint_trajectory: {e}");
                        false
                    }
                };
                let stamp = Time { sec: i32::try_from(now.as_secs()).unwrap_or(i32::MAX), nanosec: now.subsec_nanos() };
                reply(&query, &attachment, encode(&SendGoalResponse { accepted, stamp })).await;
            }
            Service::CancelGoal => match decode::<CancelGoalRequest>(&payload, "CancelGoal request") {
                Ok(request) => {
                    let (response, commands) = self.follow.cancel(&request);
                    self.execute(commands);
                    reply(&query, &attachment, encode(&response)).await;
                }
                Err(e) => {
                    // Answered, as a refusal: an unanswered request hangs its caller.
                    tracing::warn!("follow_joint_trajectory: {e}");
                    reply(&query, &attachment, encode(&CancelGoalResponse::rejected())).await;
                }
            },
            Service::GetResult => match decode::<GetResultRequest>(&payload, "GetResult request") {
                Ok(request) => match self.follow.result(&request.goal_id) {
                    Some(result) => reply(&query, &attachment, encode(&result)).await,
                    None => self.pending_results.push((request.goal_id, query, attachment)),
                },
                Err(e) => {
                    tracing::warn!("follow_joint_trajectory: {e}");
                    reply(&query, &attachment, encode(&GetResultResponse::unknown())).await;
                }
            },
        }
    }

    /// Answer the get_result requests whose goal has ended.
    async fn answer_results(&mut self) {
        let mut waiting = Vec::new();
        for (id, query, attachment) in std::mem::take(&mut self.pending_results) {
            match self.follow.result(&id) {
                Some(result) => reply(&query, &attachment, encode(&result)).await,
                None => waiting.push((id, query, attachment)),
            }
        }
        self.pending_results = waiting;
    }

    /// Carry out the action server's commands as writes.
    fn execute(&mut self, commands: Vec<JointCommand>) {
        for command in commands {
            self.lanes.command(command);
        }
        self.flush();
    }

    /// Tell the action server what the lanes report (which may ask for more writes), and send
    /// the writes the lanes give.
    fn flush(&mut self) {
        while let Some(event) = self.lanes.poll_event() {
            match event {
                LaneEvent::MoveEnded { axis, end } => {
                    for command in self.follow.move_ended(&axis, end) {
                        self.lanes.command(command);
                    }
                }
                LaneEvent::Readback { axis, position } => self.states.update(&axis, Field::RBV, position, wall()),
                LaneEvent::Restored { axis } => self.follow.restored(&axis),
                LaneEvent::Failed { axis, field, why } => tracing::warn!(axis, "{field}: {why}"),
            }
        }
        while let Some(write) = self.lanes.poll_write() {
            send(&self.client, write, &self.events);
        }
    }
}
