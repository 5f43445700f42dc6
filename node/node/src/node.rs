//! A node's life: its controllers, axes, calc links and value holders started on a Zenoh
//! session, and stopped in the order that moves nothing and loses nothing.

use crate::autosave::{AutosaveConfig, AutosaveError, Saver};
use crate::axis_core::{AxisCore, AxisInbox, LinkInbox, NodeSide, PUBLISHER_BUDGET};
use crate::axis_task::AxisTask;
use crate::controllers::{ControllerAxes, ControllerPort, RunningController, ToController};
use crate::demand::FieldDemand;
use crate::event_posts::EventPosts;
use crate::holds::Holds;
use crate::input::{AxisInput, Deliver};
use crate::links::{CalcTask, Follows, LocalFollowers, PostsFollowed, ValueHolder};
use crate::router::Router;
use crate::routes::Routes;
use crate::streamed::{Congestion, KeyWork, NodeClock};
use crate::ticker::Ticker;
use crate::tokens::Tokens;
use crate::writer::Writer;
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;
use std::time::Duration;
use zenoh::key_expr::KeyExpr;
use zenoh::sample::SampleKind;
use zenoh::Session;
use zmotor_bridge::{CalcLink, LinkError};
use zmotor_core::{AxisService, DeviceStatus, DriverPlan, Instant};
use zmotor_deploy::NodeContents;
use zmotor_inbox::Inbox;
use zmotor_msgs::{Attached, KeyLayout};

/// Why a node could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NodeError {
    /// Zenoh refused a declaration or a query.
    #[error("zenoh: {0}")]
    Zenoh(zenoh::Error),
    /// An axis's saved state cannot be restored.
    #[error(transparent)]
    Autosave(#[from] AutosaveError),
    /// A calc link cannot be built.
    #[error(transparent)]
    Calc(#[from] LinkError),
    /// The clock's worker threads cannot be started.
    #[error("cannot start the axes' clock: {0}")]
    Clock(std::io::Error),
    /// The thread that sends the posts that must arrive cannot be started.
    #[error("cannot start the event sender: {0}")]
    EventSender(std::io::Error),
    /// An axis names a controller the node does not run.
    #[error("axis '{axis}': no controller '{controller}' in this node")]
    UnknownController {
        /// The axis.
        axis: String,
        /// The controller it names.
        controller: String,
    },
}

impl From<zenoh::Error> for NodeError {
    fn from(error: zenoh::Error) -> Self {
        NodeError::Zenoh(error)
    }
}

/// How long the axes of a controller wait at start-up for its first full poll; past it, they
/// boot in COMM alarm and follow the controller when it answers.
const CONTROLLER_BOOT_WAIT: Duration = Duration::from_secs(10);

/// How many threads tick the axes of a node: one. Two threads posting at once contend for
/// Zenoh's routing tables and each link's queue, whose sender then waits for tokio's next
/// millisecond: 16 axes read back at 1 kHz saw p99 latencies of 1.2 ms with two workers, 0.2 ms
/// with one; at 1,000 axes at 100 Hz one worker carries as much at less CPU (BENCHMARKS.md 3b, 12).
const TICK_WORKERS: usize = 1;

/// A running node: its axes' and calc links' tasks, stopped when dropped or on `shutdown`.
pub struct Node {
    axis_tasks: Vec<tokio::task::JoinHandle<()>>,
    calc_tasks: Vec<tokio::task::JoinHandle<()>>,
    controller_tasks: Vec<tokio::task::JoinHandle<()>>,
    stop: tokio::sync::watch::Sender<bool>,
    /// Stops the controllers, after the axes (their last stop commands go through them).
    stop_controllers: tokio::sync::watch::Sender<bool>,
    _router: Router,
    /// Ticks the axes; its workers end with the node.
    _ticker: Ticker,
    /// Sends the posts that must arrive; what waits is sent at `shutdown`.
    events: Option<EventPosts>,
    _values: Vec<ValueHolder>,
    /// The reload keys of the script controllers.
    _reloads: Vec<zenoh::pubsub::Subscriber<()>>,
    followers: Arc<LocalFollowers>,
    demand: Arc<FieldDemand>,
}

impl Node {
    /// Start one task per controller, the value holders, then one task per axis (an axis on a
    /// controller boots on the controller's first full poll), then one per calc link, on
    /// `session`. With autosave,
    /// each axis boots from its saved state (RSTM deciding about the position) and saves its
    /// changes.
    pub async fn start(
        session: Session,
        layout: KeyLayout,
        contents: NodeContents,
        autosave: Option<AutosaveConfig>,
    ) -> Result<Self, NodeError> {
        let NodeContents { plans, calcs, values, controllers, guarded } = contents;
        let (stop, stopped) = tokio::sync::watch::channel(false);
        let (stop_controllers, controllers_stopped) = tokio::sync::watch::channel(false);
        let mut running: Vec<RunningController> = controllers
            .into_iter()
            .map(|spec| {
                let keys = crate::controllers::KeySpace { session: session.clone(), layout: layout.clone() };
                crate::controllers::start(spec, controllers_stopped.clone(), keys)
            })
            .collect();
        let mut first_statuses = HashMap::new();
        for controller in &mut running {
            let first = tokio::time::timeout(CONTROLLER_BOOT_WAIT, &mut controller.first).await;
            first_statuses.insert(controller.name.clone(), first.ok().and_then(Result::ok).unwrap_or_default());
        }
        let mut on_controllers: HashMap<String, Vec<(usize, Arc<AxisInbox>)>> = HashMap::new();
        let clock = tokio::time::Instant::now();
        let ticker = Ticker::start(TICK_WORKERS, clock.into_std(), tokio::runtime::Handle::current())
            .map_err(NodeError::Clock)?;
        let node_clock = NodeClock::new(clock.into_std());
        let key_work = Arc::new(KeyWork::new(node_clock));
        let congestion = Arc::new(Congestion::new(node_clock, key_work.clone()));
        let events = EventPosts::start(session.clone(), congestion.clone()).map_err(NodeError::EventSender)?;
        let side = NodeSide {
            session: session.clone(),
            layout: layout.clone(),
            writer: Writer::new(events.outbox(), &layout),
            events: events.outbox(),
            congestion,
            key_work: key_work.clone(),
            followers: Arc::new(LocalFollowers::new(layout.clone())),
            demand: Arc::new(FieldDemand::declare(&session, &layout).await?),
            budget: Arc::new(AtomicUsize::new(PUBLISHER_BUDGET)),
            guarded,
            clock,
        };
        // Value holders answer reads before the axes' links ask for their values at connect (a
        // soft motor's RDBL or DINP on an ao of the same database: found unreadable otherwise).
        let held: std::collections::HashSet<String> = values.iter().map(|spec| spec.key.clone()).collect();
        let mut holders = Vec::new();
        for spec in values {
            holders.push(ValueHolder::declare(&session, spec).await?);
        }
        let mut tokens = Tokens::default();
        let mut routes = Routes::new();
        let mut axis_tasks = Vec::new();
        let ahead = crate::axis_core::declares_ahead(plans.len());
        for mut plan in plans {
            let saver = match &autosave {
                Some(config) => Some(Saver::restore(config, &mut plan)?),
                None => None,
            };
            let links = Arc::new(LinkInbox::default());
            let (sink, reads, loss) = (links.clone(), links.clone(), links.clone());
            let mut follows = Follows::new(
                &session,
                side.followers.clone(),
                Arc::new(move |i, v| sink.deliver(i, v)),
                Arc::new(move |i, v| reads.read(i, v)),
            )
            .on_loss(Arc::new(move |i| loss.lost(i)));
            for (link, key) in plan.input_links() {
                follows.follow(link as usize, &key)?;
            }
            let (holds, released) = Holds::new(&session, tokio::runtime::Handle::current());
            let name = plan.name.clone();
            let on_controller = match &plan.driver {
                DriverPlan::Controller { controller, channel } => Some((controller.clone(), *channel)),
                _ => None,
            };
            let (controller, first_status) = match &on_controller {
                Some((controller, channel)) => {
                    let running = running.iter().find(|r| r.name == *controller).ok_or_else(|| {
                        NodeError::UnknownController { axis: name.clone(), controller: controller.clone() }
                    })?;
                    let port = ControllerPort { sender: running.sender.clone(), channel: *channel };
                    let known: Option<&BTreeMap<usize, DeviceStatus>> = first_statuses.get(controller);
                    (Some(port), known.and_then(|statuses| statuses.get(channel).copied()))
                }
                None => (None, None),
            };
            let jog_hold = plan.jog_hold;
            let service =
                AxisService::new(&layout, &name, plan.build(Instant::ZERO, first_status)).with_jog_hold(jog_hold);
            let axis_clock = ticker.clock();
            let mut core = AxisCore::new(service, side.clone(), controller, follows, holds, axis_clock.clone());
            if ahead {
                // Before the axes answer, so that no motion comes first (measured: declared while
                // the first motions ran, they slowed them more than keys first met at them).
                core.declare_ahead();
            }
            let (unsaved, save_due) = (core.unsaved.clone(), core.save_due.clone());
            let axis = Arc::new(Inbox::new(core));
            axis_clock.attach(Arc::downgrade(&axis) as std::sync::Weak<dyn Deliver>);
            axis.inspect(AxisCore::schedule_ticks);
            links.attach(&axis);
            routes.insert(name.clone(), axis.clone() as Arc<dyn Deliver>);
            if let Some((controller, channel)) = on_controller {
                on_controllers.entry(controller).or_default().push((channel, axis.clone()));
            }
            axis_tasks.push(AxisTask { axis, unsaved, save_due, released, saver, token: tokens.slot(&name), name });
        }
        for controller in &running {
            let axes = on_controllers.remove(&controller.name).unwrap_or_default();
            let _ = controller.sender.send(ToController::Attach(Box::new(AxesOfController(axes))));
        }
        let mut reloads = Vec::new();
        for controller in running.iter().filter(|r| r.scripted) {
            let sender = controller.sender.clone();
            let key = layout.controller_reload(&controller.name);
            let subscriber = session
                .declare_subscriber(key)
                .callback(move |sample| {
                    // A command is a plain put: a delete, or some node's publication (it carries
                    // a state marker), reloads nothing.
                    let attached = sample.attachment().map_or(Attached::Plain, |a| Attached::read(&a.to_bytes()));
                    if sample.kind() == SampleKind::Put && attached != Attached::State {
                        let _ = sender.send(ToController::Reload);
                    }
                })
                .await?;
            reloads.push(subscriber);
        }
        let controller_tasks = running.into_iter().map(|r| r.task).collect();
        let router = Router::declare(&session, &layout, routes, &side.writer, key_work).await?;
        // The axes answer as soon as the router exists; their liveliness tokens follow.
        tokens.declare_in_background(&session, &layout, stopped.clone());
        let axis_tasks = axis_tasks.into_iter().map(|task| tokio::spawn(task.run(stopped.clone()))).collect();
        let mut calc_tasks = Vec::new();
        for spec in calcs {
            let link = CalcLink::new(spec)?;
            // A calc whose result a value holder holds is no record of its own: the holder answers.
            let serves_record = !held.contains(&link.spec().output);
            let mut task = CalcTask::start(&session, side.followers.clone(), side.writer.clone(), link, serves_record)?;
            calc_tasks.push(tokio::spawn(async move { task.run().await }));
        }
        Ok(Self {
            axis_tasks,
            calc_tasks,
            controller_tasks,
            stop,
            stop_controllers,
            _router: router,
            _ticker: ticker,
            events: Some(events),
            _values: holders,
            _reloads: reloads,
            followers: side.followers.clone(),
            demand: side.demand.clone(),
        })
    }

    /// Follow `keys` (fields of this node's axes, `<prefix>/<axis>/<FIELD>`) in-process: each
    /// numeric value an axis posts there goes to `sink` with the key's index, as it is posted,
    /// before the network gets it, and whether or not anyone there subscribes. `sink` runs on
    /// the axis's task: it must only hand the value on. Changes only: read the current values
    /// apart.
    #[must_use = "following ends when the returned value is dropped"]
    pub fn follow_posts(&self, keys: &[String], sink: impl Fn(usize, f64) + Send + Sync + 'static) -> PostsFollowed {
        PostsFollowed::new(self.followers.clone(), keys, Arc::new(sink))
    }

    /// Whether subscribers elsewhere, known to the node's session, cover every kind of
    /// publication (field, readback bundle, driver-command trace) whose keys `key_expr` meets:
    /// the node publishes only those someone subscribes to. Once true, every post of them is
    /// sent, its stream samples too (which otherwise wait for Zenoh's listeners to report the
    /// subscriber, about a millisecond, or for the next ask, 0.1 s at most). A subscriber whose writes come from another session
    /// (not ordered after its declaration) waits for this before commanding.
    #[must_use]
    pub fn knows_subscribers_of(&self, key_expr: &KeyExpr<'_>) -> bool {
        self.demand.covers(key_expr)
    }

    /// Stop every moving axis, wait (at most five seconds) until they are done, save their
    /// state, withdraw their liveliness tokens; then end the calc links, which may carry the
    /// soft axes' stops and readbacks until then; then the controllers.
    pub async fn shutdown(mut self) {
        let _ = self.stop.send(true);
        for task in std::mem::take(&mut self.axis_tasks) {
            let _ = task.await;
        }
        for task in std::mem::take(&mut self.calc_tasks) {
            task.abort();
        }
        let _ = self.stop_controllers.send(true);
        for task in std::mem::take(&mut self.controller_tasks) {
            let _ = task.await;
        }
        // The axes' last posts (their stops' ends) reach the network before the session closes.
        if let Some(events) = self.events.take() {
            let _ = tokio::task::spawn_blocking(move || events.finish()).await;
        }
    }
}

impl Drop for Node {
    fn drop(&mut self) {
        let _ = self.stop.send(true);
        let _ = self.stop_controllers.send(true);
        for task in &self.calc_tasks {
            task.abort();
        }
    }
}

/// A controller's axes, by channel.
struct AxesOfController(Vec<(usize, Arc<AxisInbox>)>);

impl ControllerAxes for AxesOfController {
    fn status(&mut self, channel: usize, status: DeviceStatus, motions: u64) {
        for (_, axis) in self.0.iter().filter(|(c, _)| *c == channel) {
            axis.deliver(AxisInput::ControllerStatus(status, motions));
        }
    }

    fn message(&mut self, channel: Option<usize>, message: &str) {
        for (_, axis) in self.0.iter().filter(|(c, _)| channel.is_none_or(|channel| *c == channel)) {
            axis.deliver(AxisInput::ControllerMessage(message.to_string()));
        }
    }

    fn stop_motion(&mut self) {
        for (_, axis) in &self.0 {
            axis.deliver(AxisInput::StopMotion);
        }
    }
}
