//! One motor controller behind one connection, as a sans-IO state machine (asyn's "model 3"
//! controller, without threads): it keeps one request in flight and queues the rest by priority
//! (stop, then motion, then settings, then polls), polls every channel at the idle period and at
//! the moving period while any channel moves (with a few fast polls after every motion command),
//! and watches the link: a request unanswered within the timeout is retried if it is a query,
//! and after a few failed exchanges in a row, or when the connection closes, every channel
//! reports a communication error, everything queued is dropped (a move is never replayed
//! later), and the connection is reopened with a growing back-off. A reopened connection is
//! initialised and every channel polled before its status counts again.
//!
//! A protocol whose motion calls answer only once the motion ends has, beside the main
//! connection, one per channel for its motion (`Lane::Motion`): a motion call is written there
//! without waiting, and its reply, whenever it comes, is read as the protocol's and brings a poll
//! of the channel; only that poll, or a later one, can say the motion is done (one queued before
//! the answer may have read the controller before the motion even began).
//! The connections are one link: when one is lost, all are.
//!
//! Inputs: `command`, `handle_connected`, `handle_disconnected`, `handle_input` (bytes read on
//! a lane), `handle_timeout`. Outputs: `poll_transmit` (bytes to write on a lane), `poll_event`,
//! `poll_timeout`.

use crate::protocol::{
    CommandError, Finding, Frame, Lane, Protocol, ProtocolOptions, Purpose, ReloadError, ReplyEvent, Request,
    VendorError,
};
use crate::scale::{RecordUnits, Scale, ScaleCheck, ScaleMismatch};
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;
use zmotor_core::{DeviceStatus, Instant};
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

/// How a controller is driven.
#[derive(Clone, Debug, PartialEq)]
pub struct ControllerConfig {
    /// The channels (the controller's axis numbers) that have an axis.
    pub channels: Vec<usize>,
    /// Time between polls while any channel moves.
    pub moving_poll: Duration,
    /// Time between polls while every channel is idle.
    pub idle_poll: Duration,
    /// How long a reply may take.
    pub timeout: Duration,
    /// How many times a query that timed out or was not understood is sent again.
    pub retries: u32,
    /// Failed exchanges in a row that mean the controller is lost.
    pub failures_to_lose: u32,
    /// Polls at the moving period after every motion command, as asyn forces them.
    pub fast_polls: u32,
    /// Wait before the first attempt to reconnect; doubled at every failed attempt.
    pub reconnect_first: Duration,
    /// Longest wait between attempts to reconnect.
    pub reconnect_max: Duration,
    /// Only observed (`observe = true`): connected, initialised read-only and polled; every
    /// command but a status refresh refused, so nothing moves, powers up or is reconfigured.
    pub observe: bool,
    /// Each channel's axis's EGU and MRES, compared with the controller's scale whenever the
    /// link comes up: a channel where they disagree moves nothing.
    pub record_units: BTreeMap<usize, RecordUnits>,
}

impl ControllerConfig {
    /// Defaults as the EPICS drivers' examples poll (0.1 s moving, 1 s idle, 2 forced fast
    /// polls), for these channels.
    pub fn for_channels(channels: Vec<usize>) -> Self {
        Self {
            channels,
            moving_poll: Duration::from_millis(100),
            idle_poll: Duration::from_secs(1),
            timeout: Duration::from_secs(1),
            retries: 1,
            failures_to_lose: 3,
            fast_polls: 2,
            reconnect_first: Duration::from_millis(500),
            reconnect_max: Duration::from_secs(10),
            observe: false,
            record_units: BTreeMap::new(),
        }
    }
}

/// What the runner and the axes must hear about.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq)]
pub enum ControllerEvent {
    /// Open the connection (the first time, or once the back-off after a loss has passed).
    Connect,
    /// Close the open connection: communication with the controller is lost.
    Disconnect,
    /// A channel's status, for its axis (a poll's result, or a communication error).
    Status {
        /// The channel.
        channel: usize,
        /// Its status.
        status: DeviceStatus,
        /// Motion commands the controller had received for the channel when it read this: an
        /// axis that has sent more knows the status is older than its last motion.
        motions: u64,
    },
    /// The controller reported an error; the channel's status shows a problem until its next
    /// command.
    ControllerError(VendorError),
    /// What the controller said of itself at connection.
    Found(Finding),
    /// A channel's scale, once the link is up, and how its axis's MRES and EGU compare with it.
    Scale {
        /// The channel.
        channel: usize,
        /// The controller's units per record step, and where that comes from.
        scale: Scale,
        /// The comparison: a channel whose axis disagrees moves nothing until a connection
        /// finds them agreeing.
        check: ScaleCheck,
    },
    /// A command was not sent.
    Refused {
        /// The channel.
        channel: usize,
        /// Why.
        why: Refusal,
    },
    /// An exchange failed (no reply in time, or a reply that does not parse); it was retried or
    /// dropped as its kind allows.
    Failed {
        /// What failed, in words.
        what: String,
    },
}

/// Why a command was not sent.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Refusal {
    /// The protocol cannot express it.
    #[error("not sent: {0}")]
    Command(#[from] CommandError),
    /// A move or jog of an axis the controller moves only once referenced, which it is not:
    /// the controller would refuse it.
    #[error("not referenced: home the axis first (HOMF or HOMR)")]
    NotReferenced,
    /// A motion of an axis whose MRES disagrees with the controller's step: every target
    /// would be off by their ratio.
    #[error("no motion while the scale disagrees: {0}")]
    ScaleMismatch(ScaleMismatch),
    /// The controller cannot be reached now; the command is not kept for later.
    #[error("the controller cannot be reached; the command is dropped, not kept for later")]
    NotConnected,
    /// The channel has no axis on this controller.
    #[error("channel {0} has no axis on this controller")]
    UnknownChannel(usize),
    /// The controller is only observed.
    #[error("the controller is only observed (observe = true in its [[controller]]): nothing is sent that moves, enables or reconfigures")]
    Observed,
}

/// Queue classes, most urgent first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Priority {
    Stop,
    Motion,
    Setting,
    Poll,
}

/// What a transaction is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Init,
    /// A poll of every channel, or of one (a status refresh).
    Poll,
    Command {
        channel: usize,
        motion: bool,
    },
    /// A stop: sent again if it fails (stopping twice stops), and owed after a lost link.
    Stop {
        channel: usize,
    },
}

impl Kind {
    /// Whether an exchange that failed may be sent again: queries and stops may, other commands
    /// never (a move sent twice moves twice).
    fn retryable(self) -> bool {
        !matches!(self, Kind::Command { .. })
    }
}

/// Requests that belong together, sent one after the other.
#[derive(Debug)]
struct Transaction<S> {
    priority: Priority,
    kind: Kind,
    requests: VecDeque<Request<S>>,
    /// When it was queued, in the controller's sequence: a poll queued before a motion command
    /// of its channel reports a status that motion has made stale.
    issued: u64,
}

/// The request waiting for its reply.
#[derive(Debug)]
struct InFlight<S> {
    request: Request<S>,
    deadline: Instant,
    attempts: u32,
    /// The protocol's sync query (`Protocol::sync`), not a request of a transaction.
    sync: bool,
}

/// A channel's motion connection: its motion calls waiting for their replies, in order.
#[derive(Debug)]
struct MotionLane<S> {
    waiting: VecDeque<Request<S>>,
    received: Vec<u8>,
}

impl<S> Default for MotionLane<S> {
    fn default() -> Self {
        Self { waiting: VecDeque::new(), received: Vec::new() }
    }
}

/// The connection.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Link {
    /// Closed; reconnect at `at`. `backoff` is the wait after the next attempt, if it fails.
    Down {
        at: Instant,
        backoff: Duration,
    },
    /// The runner is opening it.
    Connecting {
        backoff: Duration,
    },
    /// Open; the init sequence and the first full poll run before statuses count.
    Initialising {
        backoff: Duration,
    },
    Up,
}

/// What the controller knows of one channel.
#[derive(Clone, Debug, Default)]
struct Channel {
    /// The last status reported.
    status: DeviceStatus,
    /// `status` was read on this connection: shown once the link is up.
    read_on_this_link: bool,
    /// When the poll that read it was queued, in the controller's sequence.
    status_issued: u64,
    /// The sequence number of the last home or position set queued: either may reference it.
    reference_issued: u64,
    /// A motion was commanded and no status since says it is over.
    moving: bool,
    /// The sequence number of the last motion command queued.
    motion_issued: u64,
    /// A controller error since the last command: MSTA shows a problem.
    problem: bool,
    /// Motion commands received for the channel (see `ControllerEvent::Status`).
    motions: u64,
    /// The deceleration of its last motion or stop, for a stop the controller owes it.
    acceleration: f64,
    /// It was moving, or being stopped, when the link was lost: a stop goes first when the
    /// link is back, so that nothing keeps moving that nobody commands.
    stop_owed: bool,
    /// Its axis's MRES disagrees with the controller's step, as the link found when it came up.
    mismatch: Option<ScaleMismatch>,
    /// The sequence number at which its last motion call was answered (motion lanes): a poll
    /// queued before then may have read the controller before the motion began.
    motion_answered: u64,
}

/// One controller speaking the protocol `P` (see the module documentation). Its API is
/// `AnyController`, which a runner holds for a protocol chosen at run time.
pub struct Controller<P: Protocol> {
    protocol: P,
    config: ControllerConfig,
    link: Link,
    channels: Vec<Channel>,
    queue: Vec<Transaction<P::Step>>,
    /// The transaction being carried out, and its request waiting for a reply.
    current: Option<Transaction<P::Step>>,
    in_flight: Option<InFlight<P::Step>>,
    /// After a timeout nothing is sent until then: a reply still on its way must not be taken
    /// for the next request's.
    quiet_until: Option<Instant>,
    /// A request whose reply did not come in time, sent again once the quiet is over.
    retry: Option<InFlight<P::Step>>,
    /// After a failed exchange, nothing is sent but the sync query until its reply is found:
    /// the frames before it are stale.
    syncing: bool,
    received: Vec<u8>,
    /// Options given again (a script re-read), used once the stops sent for them are out.
    reload: Option<ProtocolOptions>,
    /// Each channel's motion connection, for a protocol with motion lanes.
    motion_lanes: BTreeMap<usize, MotionLane<P::Step>>,
    next_poll: Option<Instant>,
    fast_polls_left: u32,
    failures: u32,
    seq: u64,
    now: Instant,
    transmit: VecDeque<(Lane, Vec<u8>)>,
    events: VecDeque<ControllerEvent>,
}

/// A controller of any protocol (see the module documentation): what a runner holds when the
/// protocol is chosen at run time (`ProtocolKind::controller`). Every `Controller` is one.
pub trait AnyController: Send {
    /// The protocol's name.
    fn protocol(&self) -> &'static str;

    /// Whether the link is up and initialised.
    fn is_up(&self) -> bool;

    /// A driver command for `channel` (from its axis's record).
    fn command(&mut self, now: Instant, channel: usize, command: &DriverCommand);

    /// New options for the protocol while it runs (a script re-read, motorScriptMotor's
    /// `ScriptMotorReload`): checked at once (an error changes nothing); then every channel in
    /// motion is stopped, and the options are used once the stops are sent. Positions are the
    /// controller's and stay as they are.
    fn reload(&mut self, now: Instant, options: &ProtocolOptions) -> Result<(), ReloadError>;

    /// The connections the runner opens at `ControllerEvent::Connect`, all of them: the main
    /// one first.
    #[must_use]
    fn lanes(&self) -> Vec<Lane>;

    /// The runner opened the connections (every lane).
    fn handle_connected(&mut self, now: Instant);

    /// A connection failed to open, or closed: the runner closes the others.
    fn handle_disconnected(&mut self, now: Instant);

    /// Bytes read from the connection of `lane`.
    fn handle_input(&mut self, now: Instant, lane: Lane, bytes: &[u8]);

    /// Time passed to `now`: a reply overdue, a poll due, a reconnection due.
    fn handle_timeout(&mut self, now: Instant);

    /// When `handle_timeout` is due next.
    #[must_use]
    fn poll_timeout(&self) -> Option<Instant>;

    /// The next bytes to write, and the connection they go on.
    #[must_use]
    fn poll_transmit(&mut self) -> Option<(Lane, Vec<u8>)>;

    /// The next event.
    #[must_use]
    fn poll_event(&mut self) -> Option<ControllerEvent>;
}

impl<P: Protocol> Controller<P> {
    /// A controller not connected yet: the first `handle_timeout` asks for the connection.
    pub fn new(mut protocol: P, config: ControllerConfig, now: Instant) -> Self {
        if config.observe {
            protocol.observe_only();
        }
        let channels = vec![Channel::default(); config.channels.iter().max().map_or(0, |c| c + 1)];
        let backoff = config.reconnect_first;
        Self {
            protocol,
            config,
            link: Link::Down { at: now, backoff },
            channels,
            queue: Vec::new(),
            current: None,
            in_flight: None,
            quiet_until: None,
            retry: None,
            syncing: false,
            received: Vec::new(),
            reload: None,
            motion_lanes: BTreeMap::new(),
            next_poll: None,
            fast_polls_left: 0,
            failures: 0,
            seq: 0,
            now,
            transmit: VecDeque::new(),
            events: VecDeque::new(),
        }
    }
}

impl<P: Protocol> AnyController for Controller<P> {
    fn protocol(&self) -> &'static str {
        self.protocol.name()
    }

    fn is_up(&self) -> bool {
        self.link == Link::Up
    }

    fn command(&mut self, now: Instant, channel: usize, command: &DriverCommand) {
        self.advance(now);
        if !self.config.channels.contains(&channel) {
            self.events.push_back(ControllerEvent::Refused { channel, why: Refusal::UnknownChannel(channel) });
            return;
        }
        let motion = command.starts_motion();
        let stop = matches!(command, DriverCommand::Stop { .. });
        let state = &mut self.channels[channel];
        if motion {
            state.motions += 1;
        }
        if let DriverCommand::Move { acceleration, .. }
        | DriverCommand::MoveVelocity { acceleration, .. }
        | DriverCommand::Home { acceleration, .. }
        | DriverCommand::Stop { acceleration } = command
        {
            state.acceleration = *acceleration;
        }
        if self.config.observe && !matches!(command, DriverCommand::Poll) {
            // Not even a stop, and none owed: beside a running IOC, that IOC drives the axes.
            self.events.push_back(ControllerEvent::Refused { channel, why: Refusal::Observed });
            self.report_problem(channel);
            return;
        }
        let open = matches!(self.link, Link::Initialising { .. } | Link::Up);
        if !(self.link == Link::Up || (stop && open)) {
            // Never kept for later: a move must not run minutes after it was asked for. A stop
            // is owed instead: it goes first when the link is back.
            self.channels[channel].stop_owed |= stop;
            self.events.push_back(ControllerEvent::Refused { channel, why: Refusal::NotConnected });
            self.report_lost(channel);
            return;
        }
        let state = &self.channels[channel];
        // Known unreferenced: a home or a position set since the status was read may have
        // referenced it, and the controller itself is the judge then.
        let unreferenced = state.status.msta & msta::HOMED == 0 && state.status_issued >= state.reference_issued;
        let moves = matches!(command, DriverCommand::Move { .. } | DriverCommand::MoveVelocity { .. });
        if let Some(mismatch) = state.mismatch.clone().filter(|_| motion) {
            self.events.push_back(ControllerEvent::Refused { channel, why: Refusal::ScaleMismatch(mismatch) });
            self.report_problem(channel);
            return;
        }
        if moves && unreferenced && self.protocol.moves_need_reference(channel) {
            // Said before trying: the controller's own refusal would come as a bare error code.
            self.events.push_back(ControllerEvent::Refused { channel, why: Refusal::NotReferenced });
            self.report_problem(channel);
            return;
        }
        if let DriverCommand::Poll = command {
            self.queue_poll_of(&[channel], Priority::Setting);
            self.pump();
            return;
        }
        let requests = match self.protocol.command(channel, command) {
            Ok(requests) => requests,
            Err(e) => {
                // The axis took the command as started: its status must say it is not.
                self.events.push_back(ControllerEvent::Refused { channel, why: e.into() });
                self.report_problem(channel);
                return;
            }
        };
        let (priority, kind) = if stop {
            self.drop_motion_of(channel);
            (Priority::Stop, Kind::Stop { channel })
        } else if motion {
            (Priority::Motion, Kind::Command { channel, motion })
        } else {
            (Priority::Setting, Kind::Command { channel, motion })
        };
        self.seq += 1;
        let state = &mut self.channels[channel];
        state.problem = false;
        if matches!(command, DriverCommand::Home { .. } | DriverCommand::SetPosition { .. }) {
            state.reference_issued = self.seq;
        }
        if motion {
            state.moving = true;
            state.motion_issued = self.seq;
            // Fast polls follow the command, queued behind it.
            self.fast_polls_left = self.config.fast_polls;
            self.next_poll = Some(self.now);
        }
        self.queue.push(Transaction { priority, kind, requests: requests.into(), issued: self.seq });
        self.pump();
    }

    fn reload(&mut self, now: Instant, options: &ProtocolOptions) -> Result<(), ReloadError> {
        self.advance(now);
        self.protocol.check_reload(options)?;
        let moving: Vec<(usize, f64)> = self
            .config
            .channels
            .iter()
            .filter(|&&c| self.channels[c].moving)
            .map(|&c| (c, self.channels[c].acceleration))
            .collect();
        for (channel, acceleration) in moving {
            self.command(now, channel, &DriverCommand::Stop { acceleration });
        }
        self.reload = Some(options.clone());
        self.apply_reload_when_stopped();
        self.pump();
        Ok(())
    }

    fn lanes(&self) -> Vec<Lane> {
        let motion = self.config.channels.iter().map(|&channel| Lane::Motion(channel));
        std::iter::once(Lane::Main).chain(motion.filter(|_| self.protocol.motion_lanes())).collect()
    }

    fn handle_connected(&mut self, now: Instant) {
        self.advance(now);
        let Link::Connecting { backoff } = self.link else { return };
        self.link = Link::Initialising { backoff };
        self.received.clear();
        let mut init = self.protocol.init(&self.config.channels);
        if self.config.observe {
            init.retain(|request| P::purpose(request.step) != Purpose::Setup);
        }
        self.seq += 1;
        self.queue.push(Transaction {
            priority: Priority::Stop,
            kind: Kind::Init,
            requests: init.into(),
            issued: self.seq,
        });
        let channels = self.config.channels.clone();
        self.queue_poll_of(&channels, Priority::Stop);
        self.pump();
    }

    fn handle_disconnected(&mut self, now: Instant) {
        self.advance(now);
        match self.link {
            Link::Down { .. } => {}
            Link::Connecting { backoff } => self.go_down(backoff),
            Link::Initialising { backoff } => self.lose(backoff),
            Link::Up => self.lose(self.config.reconnect_first),
        }
    }

    fn handle_input(&mut self, now: Instant, lane: Lane, bytes: &[u8]) {
        self.advance(now);
        if !matches!(self.link, Link::Initialising { .. } | Link::Up) {
            return;
        }
        // Frame by frame: handling one may send a request, whose clearing of the buffer drops
        // what came before it (a late reply must not pass for the new request's).
        match lane {
            Lane::Main => {
                self.received.extend_from_slice(bytes);
                self.drop_if_unframed(Lane::Main);
                while let Some(framed) = next_frame(&self.protocol, &mut self.received) {
                    match framed {
                        Framed::Reply(frame) => self.on_frame(&frame),
                        Framed::Notice(frame) => self.on_notice(&frame),
                    }
                }
            }
            Lane::Motion(channel) => {
                self.motion_lanes.entry(channel).or_default().received.extend_from_slice(bytes);
                self.drop_if_unframed(lane);
                while let Some(motion) = self.motion_lanes.get_mut(&channel) {
                    match next_frame(&self.protocol, &mut motion.received) {
                        Some(Framed::Reply(frame)) => self.on_motion_frame(channel, &frame),
                        Some(Framed::Notice(frame)) => self.on_notice(&frame),
                        None => break,
                    }
                }
            }
            // The runner answers a key access with one whole frame.
            Lane::Keys => {
                if self.in_flight.as_ref().is_some_and(|f| f.request.lane == Lane::Keys) {
                    self.on_frame(bytes);
                } else {
                    let what =
                        format!("an answer of the key space nothing waits for: {}", crate::protocol::printable(bytes));
                    self.events.push_back(ControllerEvent::Failed { what });
                }
            }
        }
        self.pump();
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.advance(now);
        if let Link::Down { at, backoff } = self.link {
            if self.now >= at {
                self.link = Link::Connecting { backoff };
                self.events.push_back(ControllerEvent::Connect);
            }
            return;
        }
        if self.in_flight.as_ref().is_some_and(|f| self.now >= f.deadline) {
            let in_flight = self.in_flight.take().expect("checked above");
            self.quiet_until = Some(self.now + self.config.timeout / 4);
            if in_flight.sync {
                // Asked again after the quiet, unless the controller is given up.
                self.count_failure(&in_flight, "no reply in time");
            } else {
                self.on_failure(in_flight, "no reply in time");
            }
        }
        if self.link == Link::Up && self.next_poll.is_some_and(|t| self.now >= t) {
            let already = self.queue.iter().chain(&self.current).any(|t| t.kind == Kind::Poll);
            if !already {
                let channels = self.config.channels.clone();
                self.queue_poll_of(&channels, Priority::Poll);
            }
            let moving = self.channels.iter().any(|c| c.moving);
            let period =
                if moving || self.fast_polls_left > 0 { self.config.moving_poll } else { self.config.idle_poll };
            self.fast_polls_left = self.fast_polls_left.saturating_sub(1);
            self.next_poll = Some(self.now + period);
        }
        self.pump();
    }

    fn poll_timeout(&self) -> Option<Instant> {
        match self.link {
            Link::Down { at, .. } => Some(at),
            Link::Connecting { .. } => None,
            Link::Initialising { .. } | Link::Up => {
                let deadline = self.in_flight.as_ref().map(|f| f.deadline);
                let poll = self.next_poll.filter(|_| self.link == Link::Up);
                [deadline, poll, self.quiet_until].into_iter().flatten().min()
            }
        }
    }

    fn poll_transmit(&mut self) -> Option<(Lane, Vec<u8>)> {
        self.transmit.pop_front()
    }

    fn poll_event(&mut self) -> Option<ControllerEvent> {
        self.events.pop_front()
    }
}

impl<P: Protocol> Controller<P> {
    fn advance(&mut self, now: Instant) {
        self.now = self.now.max(now);
    }

    /// Queue a poll of `channels`: one transaction per channel (a batched request its own), so
    /// that motion waits for one channel's poll at most, and a stop for one exchange.
    fn queue_poll_of(&mut self, channels: &[usize], priority: Priority) {
        self.seq += 1;
        let mut transactions: Vec<Transaction<P::Step>> = Vec::new();
        for request in self.protocol.poll(channels) {
            let channel = P::purpose(request.step).channel();
            match transactions.last_mut() {
                Some(t) if t.requests.back().is_some_and(|r| P::purpose(r.step).channel() == channel) => {
                    t.requests.push_back(request)
                }
                _ => transactions.push(Transaction {
                    priority,
                    kind: Kind::Poll,
                    requests: [request].into(),
                    issued: self.seq,
                }),
            }
        }
        self.queue.extend(transactions);
    }

    /// A stop goes before anything else of its channel: motion queued for it is dropped, and a
    /// motion command being sent is cut short (its remaining requests would start it again).
    fn drop_motion_of(&mut self, channel: usize) {
        let motion = Kind::Command { channel, motion: true };
        self.queue.retain(|t| t.kind != motion);
        if let Some(current) = self.current.as_mut().filter(|t| t.kind == motion) {
            current.requests.clear();
        }
    }

    /// Send what can be sent: one request in flight at most.
    fn pump(&mut self) {
        if self.quiet_until.is_some_and(|t| self.now < t) {
            return;
        }
        if self.quiet_until.take().is_some() {
            self.received.clear();
        }
        if self.syncing && self.in_flight.is_none() {
            self.send_sync();
        }
        if self.syncing {
            return;
        }
        if let Some(retry) = self.retry.take() {
            let stop_waits = self.queue.iter().any(|t| t.priority == Priority::Stop);
            if stop_waits && self.link == Link::Up && self.current.as_ref().is_some_and(|t| t.kind == Kind::Poll) {
                // The poll gives up this round rather than hold a stop back by a retry.
                self.preempt_poll();
            } else {
                self.send(retry.request, retry.attempts);
            }
        }
        while self.in_flight.is_none() && matches!(self.link, Link::Initialising { .. } | Link::Up) {
            if self.current.as_ref().is_none_or(|t| t.requests.is_empty()) {
                if let Some(done) = self.current.take() {
                    self.finished(done);
                }
                self.apply_reload_when_stopped();
                let Some(next) = self.next_transaction() else { return };
                self.current = Some(next);
                continue;
            }
            let stop_waits = self.queue.iter().any(|t| t.priority == Priority::Stop);
            if stop_waits && self.link == Link::Up && self.current.as_ref().is_some_and(|t| t.kind == Kind::Poll) {
                self.preempt_poll();
                continue;
            }
            let current = self.current.as_mut().expect("checked above");
            let (request, issued) = (current.requests.pop_front().expect("checked above"), current.issued);
            let prepared = self.protocol.prepare(request);
            for event in prepared.events {
                self.on_event(event, issued);
            }
            if let Some(request) = prepared.request {
                self.send(request, 1);
            }
        }
    }

    /// Send the sync query, or, for a protocol without one, stop syncing.
    fn send_sync(&mut self) {
        let Some(request) = self.protocol.sync() else {
            self.syncing = false;
            return;
        };
        self.send(request, 1);
        if let Some(in_flight) = self.in_flight.as_mut() {
            in_flight.sync = true;
        }
    }

    /// Write `request` (its `attempts`-th time); wait for its reply if it has one.
    fn send(&mut self, request: Request<P::Step>, attempts: u32) {
        if let Lane::Motion(channel) = request.lane {
            // Not waited for: its reply comes when the motion ends, however long that takes.
            self.transmit.push_back((request.lane, request.bytes.clone()));
            if request.answered {
                self.motion_lanes.entry(channel).or_default().waiting.push_back(request);
            }
            return;
        }
        // What arrived before this request belongs to nothing: a late reply to an exchange
        // given up must not pass for this one's.
        self.received.clear();
        self.transmit.push_back((request.lane, request.bytes.clone()));
        if request.answered {
            self.in_flight =
                Some(InFlight { request, deadline: self.now + self.config.timeout, attempts, sync: false });
        }
    }

    /// A stop waits: the rest of the poll being carried out waits for the next round. Requests
    /// a reply added to it that are commands (a home continued once the controller is ready)
    /// become a motion transaction of their own, behind the stop, unless the stop is theirs.
    fn preempt_poll(&mut self) {
        let Some(poll) = self.current.as_mut() else { return };
        let commands: VecDeque<Request<P::Step>> =
            poll.requests.drain(..).filter(|r| matches!(P::purpose(r.step), Purpose::Command { .. })).collect();
        let issued = poll.issued;
        let Some(channel) = commands.front().and_then(|r| P::purpose(r.step).channel()) else { return };
        if !self.queue.iter().any(|t| t.kind == Kind::Stop { channel }) {
            let kind = Kind::Command { channel, motion: true };
            self.queue.push(Transaction { priority: Priority::Motion, kind, requests: commands, issued });
        }
    }

    /// New options are used once no stop waits or is under way (the stops a reload sent go
    /// out as the old options make them), or at once while the link is down.
    fn apply_reload_when_stopped(&mut self) {
        let stopping = self.queue.iter().chain(&self.current).any(|t| t.priority == Priority::Stop);
        let open = matches!(self.link, Link::Initialising { .. } | Link::Up);
        if stopping && open {
            return;
        }
        if let Some(options) = self.reload.take() {
            self.protocol.reload(&options);
        }
    }

    fn next_transaction(&mut self) -> Option<Transaction<P::Step>> {
        let (index, _) = self.queue.iter().enumerate().min_by_key(|(i, t)| (t.priority, *i))?;
        Some(self.queue.remove(index))
    }

    /// A transaction has sent all its requests and had all its replies.
    fn finished(&mut self, transaction: Transaction<P::Step>) {
        let initialising = matches!(self.link, Link::Initialising { .. });
        let last = self.queue.iter().all(|t| t.kind != Kind::Init && t.kind != Kind::Poll);
        if initialising && matches!(transaction.kind, Kind::Init | Kind::Poll) && last {
            self.link = Link::Up;
            self.next_poll = Some(self.now + self.config.idle_poll);
            // The statuses the initialisation read, held until now: an axis shown out of its
            // COMM alarm takes commands, which a link still initialising refuses.
            for (channel, state) in self.channels.iter().enumerate().filter(|(_, s)| s.read_on_this_link) {
                let (status, motions) = (state.status, state.motions);
                self.events.push_back(ControllerEvent::Status { channel, status, motions });
            }
            self.check_scales();
            self.queue_owed_stops();
        }
    }

    /// The stops owed since the link was lost, before anything else now that it is up. Made
    /// from what this link read, not from what the lost one last saw: the controller may have
    /// changed meanwhile (a PMAC motor killed by a fault must not be closed by a `J/`), and the
    /// initialisation has shown it is the controller it should be.
    fn queue_owed_stops(&mut self) {
        for channel in self.config.channels.clone() {
            let state = &mut self.channels[channel];
            if !std::mem::take(&mut state.stop_owed) {
                continue;
            }
            let stop = DriverCommand::Stop { acceleration: state.acceleration };
            match self.protocol.command(channel, &stop) {
                Ok(requests) => {
                    tracing::warn!(channel, "moving or being stopped when the link was lost: stopped first");
                    self.seq += 1;
                    let (kind, requests, issued) = (Kind::Stop { channel }, requests.into(), self.seq);
                    self.queue.push(Transaction { priority: Priority::Stop, kind, requests, issued });
                }
                Err(e) => tracing::error!(channel, "the stop owed since the link was lost cannot be sent: {e}"),
            }
        }
    }

    /// Each channel's scale, as the initialisation left it, against its axis's MRES and EGU.
    fn check_scales(&mut self) {
        for channel in self.config.channels.clone() {
            let scale = self.protocol.scale(channel);
            let check = match self.config.record_units.get(&channel) {
                Some(record) => scale.check(record),
                None => ScaleCheck::Unchecked("no axis units given"),
            };
            self.channels[channel].mismatch = match &check {
                ScaleCheck::Disagrees(mismatch) => Some(mismatch.clone()),
                _ => None,
            };
            self.events.push_back(ControllerEvent::Scale { channel, scale, check });
        }
    }

    fn on_frame(&mut self, frame: &[u8]) {
        if self.in_flight.as_ref().is_some_and(|f| f.sync) {
            if self.protocol.is_sync_reply(frame) {
                self.in_flight = None;
                self.syncing = false;
            } else {
                let what = format!("a stale reply dropped: {}", crate::protocol::printable(frame));
                self.events.push_back(ControllerEvent::Failed { what });
            }
            return;
        }
        let Some(in_flight) = self.in_flight.take() else {
            // Nothing asked for it: noise, or a reply too late for its request.
            self.events.push_back(ControllerEvent::Failed {
                what: format!("unexpected bytes {}", crate::protocol::printable(frame)),
            });
            return;
        };
        match self.protocol.reply(&in_flight.request, frame) {
            Ok(events) if events.iter().any(|e| matches!(e, ReplyEvent::Status { status, .. } if !finite(status))) => {
                self.on_failure(in_flight, "a position that is not a number");
            }
            Ok(events) => {
                self.failures = 0;
                let issued = self.current.as_ref().map_or(0, |t| t.issued);
                for event in events {
                    self.on_event(event, issued);
                }
            }
            Err(e) => self.on_failure(in_flight, &e.to_string()),
        }
    }

    /// A notification: what it says counts as a reply's would, no request waiting for it.
    fn on_notice(&mut self, frame: &[u8]) {
        for event in self.protocol.notice(frame) {
            match event {
                ReplyEvent::FollowUp(_) => {
                    tracing::warn!("a notification asked for requests: not sent");
                }
                // Nothing of the command under way is the notification's to cut short.
                ReplyEvent::Refused(error) => self.on_event(ReplyEvent::ControllerError(error), self.seq),
                event => self.on_event(event, self.seq),
            }
        }
    }

    /// Bytes on `lane` that never make a frame (a device streaming, the wrong protocol): dropped
    /// beyond `MAX_UNFRAMED`.
    fn drop_if_unframed(&mut self, lane: Lane) {
        let buffer = match lane {
            Lane::Main => &mut self.received,
            Lane::Motion(channel) => &mut self.motion_lanes.entry(channel).or_default().received,
            Lane::Keys => return,
        };
        if buffer.len() > MAX_UNFRAMED {
            let what = format!("{} bytes that are no frame of the protocol, dropped", buffer.len());
            buffer.clear();
            self.events.push_back(ControllerEvent::Failed { what });
        }
    }

    /// The reply to a motion call of `channel`, the oldest waiting: what it says counts as any
    /// reply's, requests it asks for follow as a command of their own, and a poll comes next
    /// (the motion is over).
    fn on_motion_frame(&mut self, channel: usize, frame: &[u8]) {
        let waiting = self.motion_lanes.get_mut(&channel).and_then(|lane| lane.waiting.pop_front());
        let Some(request) = waiting else {
            self.events.push_back(ControllerEvent::Failed {
                what: format!(
                    "unexpected bytes on the motion connection of channel {channel}: {}",
                    crate::protocol::printable(frame)
                ),
            });
            return;
        };
        match self.protocol.reply(&request, frame) {
            Ok(events) => {
                for event in events {
                    match event {
                        // Nothing of the command under way is this reply's to cut short.
                        ReplyEvent::Refused(error) => self.on_event(ReplyEvent::ControllerError(error), self.seq),
                        ReplyEvent::FollowUp(requests) => {
                            self.seq += 1;
                            let kind = Kind::Command { channel, motion: false };
                            let (requests, issued) = (requests.into(), self.seq);
                            self.queue.push(Transaction { priority: Priority::Setting, kind, requests, issued });
                        }
                        event => self.on_event(event, self.seq),
                    }
                }
            }
            Err(e) => {
                self.events.push_back(ControllerEvent::Failed { what: e.to_string() });
                self.report_problem(channel);
            }
        }
        // The motion is over: a poll of the channel, queued now, reads what it left.
        if let Some(state) = self.channels.get_mut(channel) {
            self.seq += 1;
            state.motion_answered = self.seq;
            self.queue_poll_of(&[channel], Priority::Setting);
        }
    }

    fn on_event(&mut self, event: ReplyEvent<P::Step>, issued: u64) {
        match event {
            ReplyEvent::Status { channel, mut status } => {
                let unanswered = self.motion_lanes.get(&channel).is_some_and(|lane| !lane.waiting.is_empty());
                let answered_since = self.channels.get(channel).is_some_and(|c| issued <= c.motion_answered);
                if unanswered || answered_since {
                    // Its motion call is unanswered, or was answered after this poll was queued:
                    // the poll may have read the controller before the motion began, on the other
                    // connection. Not done on its word; the poll queued at the answer says.
                    status.msta &= !msta::DONE;
                }
                let Some(state) = self.channels.get_mut(channel) else { return };
                // A poll queued before the last motion command reports the state before it.
                if issued < state.motion_issued {
                    return;
                }
                state.moving = status.msta & msta::DONE == 0;
                if state.problem {
                    status.msta |= msta::PROBLEM;
                }
                state.status = status;
                state.status_issued = issued;
                state.read_on_this_link = true;
                let motions = state.motions;
                if self.link == Link::Up {
                    self.events.push_back(ControllerEvent::Status { channel, status, motions });
                }
            }
            ReplyEvent::ControllerError(error) => {
                let affected: Vec<usize> = match error.channel {
                    Some(channel) => vec![channel],
                    None => self.config.channels.clone(),
                };
                // The error first: an axis that ends its motion on the problem's status then
                // knows why (a `?wait` answer carries it).
                self.events.push_back(ControllerEvent::ControllerError(error));
                for channel in affected {
                    self.report_problem(channel);
                }
            }
            ReplyEvent::Found(finding) => self.events.push_back(ControllerEvent::Found(finding)),
            ReplyEvent::Refused(error) => {
                self.abandon_current();
                self.on_event(ReplyEvent::ControllerError(error), issued);
            }
            ReplyEvent::FollowUp(requests) => {
                if let Some(current) = self.current.as_mut() {
                    for request in requests.into_iter().rev() {
                        current.requests.push_front(request);
                    }
                }
            }
        }
    }

    /// An exchange failed: retry a query, drop a command's remaining requests, and lose the
    /// controller after too many failures in a row.
    fn on_failure(&mut self, in_flight: InFlight<P::Step>, why: &str) {
        if !self.count_failure(&in_flight, why) {
            return;
        }
        // The replies that follow may be late ones of this exchange: found again first (by a
        // protocol whose replies do not name their request).
        self.syncing = true;
        let kind = self.current.as_ref().map(|t| t.kind);
        // A setting of the initialisation changes the controller: not sent twice, as a command.
        let changes = P::purpose(in_flight.request.step) == Purpose::Setup;
        if kind.is_some_and(Kind::retryable) && !changes && in_flight.attempts <= self.config.retries {
            let retry = InFlight { attempts: in_flight.attempts + 1, ..in_flight };
            if self.quiet_until.is_some() || self.syncing {
                self.retry = Some(retry);
            } else {
                self.send(retry.request, retry.attempts);
            }
            return;
        }
        match kind {
            // A connection not initialised in full (a scale not read, the wrong controller) is
            // not used: it is dropped and opened again.
            Some(Kind::Init) => {
                let backoff = match self.link {
                    Link::Initialising { backoff } => backoff,
                    _ => self.config.reconnect_first,
                };
                self.lose(backoff);
            }
            // A command half carried out is not carried on (its channel shows a problem until
            // the next command); a poll gives up this round.
            Some(Kind::Command { channel, .. } | Kind::Stop { channel }) => {
                self.abandon_current();
                self.report_problem(channel);
            }
            _ => self.abandon_current(),
        }
    }

    /// Say an exchange failed and count it; false when the controller is given up (too many in
    /// a row).
    fn count_failure(&mut self, in_flight: &InFlight<P::Step>, why: &str) -> bool {
        let what = format!("{} ({why})", crate::protocol::printable(&in_flight.request.bytes));
        self.events.push_back(ControllerEvent::Failed { what });
        self.failures += 1;
        if self.failures >= self.config.failures_to_lose {
            let backoff = match self.link {
                Link::Initialising { backoff } => backoff,
                _ => self.config.reconnect_first,
            };
            self.lose(backoff);
            return false;
        }
        true
    }

    /// The rest of the transaction under way is not sent.
    fn abandon_current(&mut self) {
        if let Some(current) = self.current.as_mut() {
            current.requests.clear();
        }
    }

    /// Communication is lost: every channel says so, nothing queued survives, the connection
    /// closes and is reopened after `wait`.
    fn lose(&mut self, wait: Duration) {
        let stopping: Vec<usize> = self
            .queue
            .iter()
            .chain(&self.current)
            .filter_map(|t| match t.kind {
                Kind::Stop { channel } => Some(channel),
                _ => None,
            })
            .collect();
        for channel in self.config.channels.clone() {
            self.report_lost(channel);
            let state = &mut self.channels[channel];
            // An observed controller owes none: the IOC beside it drives its axes.
            state.stop_owed |= !self.config.observe && (state.moving || stopping.contains(&channel));
            state.moving = false;
        }
        self.go_down(wait);
    }

    /// Close, and reopen after `wait`; a failed attempt then waits twice as long, up to the
    /// longest wait.
    fn go_down(&mut self, wait: Duration) {
        self.queue.clear();
        self.current = None;
        self.in_flight = None;
        self.retry = None;
        self.syncing = false;
        self.quiet_until = None;
        self.received.clear();
        self.motion_lanes.clear();
        self.transmit.clear();
        self.next_poll = None;
        self.failures = 0;
        for state in &mut self.channels {
            state.read_on_this_link = false;
        }
        if matches!(self.link, Link::Initialising { .. } | Link::Up) {
            self.events.push_back(ControllerEvent::Disconnect);
        }
        let backoff = wait.saturating_mul(2).min(self.config.reconnect_max);
        self.link = Link::Down { at: self.now + wait, backoff };
    }

    /// The channel's last status, with a communication error and no motion.
    fn report_lost(&mut self, channel: usize) {
        let Some(state) = self.channels.get(channel) else { return };
        let mut status = state.status;
        status.msta = (status.msta | msta::COMM_ERR | msta::DONE) & !msta::MOVING;
        status.velocity = 0.0;
        self.events.push_back(ControllerEvent::Status { channel, status, motions: state.motions });
    }

    /// The channel shows a problem until its next command: its last status, with PROBLEM, and
    /// still "not done" if a motion commanded has not been reported over (a status read before
    /// the motion must not end it).
    fn report_problem(&mut self, channel: usize) {
        let Some(state) = self.channels.get_mut(channel) else { return };
        state.problem = true;
        if self.link != Link::Up {
            // Not out of the COMM alarm before the link is up.
            self.report_lost(channel);
            return;
        }
        let mut status = state.status;
        status.msta |= msta::PROBLEM;
        if state.moving {
            status.msta &= !msta::DONE;
        }
        self.events.push_back(ControllerEvent::Status { channel, status, motions: state.motions });
    }
}

/// Replies are read in bytes until a frame completes; beyond this many without one, they are
/// dropped.
const MAX_UNFRAMED: usize = 64 * 1024;

/// A complete frame of the byte stream.
enum Framed {
    Reply(Vec<u8>),
    Notice(Vec<u8>),
}

/// The first complete frame in `buffer`, taken out of it (noise before it dropped).
fn next_frame<P: Protocol>(protocol: &P, buffer: &mut Vec<u8>) -> Option<Framed> {
    loop {
        match protocol.frame(buffer) {
            Frame::Incomplete => return None,
            Frame::Junk(n) => {
                buffer.drain(..n.min(buffer.len()));
            }
            Frame::Complete(n) => return Some(Framed::Reply(buffer.drain(..n.min(buffer.len())).collect())),
            Frame::Notice(n) => return Some(Framed::Notice(buffer.drain(..n.min(buffer.len())).collect())),
        }
    }
}

/// A status whose numbers are numbers.
fn finite(status: &DeviceStatus) -> bool {
    status.position.is_finite() && status.encoder_position.is_finite() && status.velocity.is_finite()
}
