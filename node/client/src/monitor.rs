//! Monitors, as camonitor makes them: the current value of each field first, then every
//! change. The subscription is declared before the current values are asked for, and both
//! arrive through one queue in the order the network delivered them, so no change between the
//! two is lost and none is shown out of order. An axis whose node goes is told (camonitor's
//! "disconnected"); when a node serves it again, its current values come again.

use crate::read::{axis_of, field_of, sample_value};
use crate::show::show;
use crate::Client;
use std::collections::{HashMap, HashSet};
use std::time::{Duration, SystemTime};
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver};
use zenoh::pubsub::Subscriber;
use zenoh::sample::{Sample, SampleKind};
use zenoh::Session;
use zmotor_msgs::keys::chunk_pattern;
use zmotor_msgs::{Field, KeyLayout, Value};

/// How long the current values may take to come.
const PATIENCE: Duration = Duration::from_secs(5);

/// One field's value, current or changed.
#[derive(Clone, Debug, PartialEq)]
pub struct Update {
    /// The axis.
    pub axis: String,
    /// The field, when the key names one of the catalogue.
    pub field: Option<Field>,
    /// The field's name, as the key spells it.
    pub name: String,
    /// Its value.
    pub value: Value,
    /// The node's time of the value, when the axis read the status it comes from (as camonitor
    /// shows an IOC's record time stamp); its arrival where the sample has none.
    pub at: SystemTime,
    /// The value as camonitor shows it (menus by name, doubles at the axis's precision).
    pub shown: String,
}

/// What a monitor tells: a value, or an axis's node gone or back.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// A field's value, current or changed.
    Value(Update),
    /// No node serves the axis any more (its liveliness token went).
    Gone(String),
    /// A node serves the axis again; its current values follow.
    Back(String),
}

/// A monitor of some fields of one axis (or of the axes a pattern names); it ends when dropped.
pub struct Monitor {
    session: Session,
    layout: KeyLayout,
    queue: tokio::sync::mpsc::UnboundedSender<Arrival>,
    /// The fields followed; empty for every field.
    wanted: Vec<Field>,
    /// Whether the axis's messages (ERR: refused writes, its controller's errors) are followed.
    messages: bool,
    arrivals: UnboundedReceiver<Arrival>,
    /// Each axis's PREC.
    precs: HashMap<String, i16>,
    /// The axes served now, by their liveliness tokens.
    served: HashSet<String>,
    _subscribers: Vec<Subscriber<()>>,
}

/// What reaches a monitor's queue.
enum Arrival {
    /// A value of a followed field, current or changed.
    Value(Sample),
    /// An axis's PREC, asked for first so the first values are shown at it.
    Precision(Sample),
    /// An axis's liveliness token, come or gone.
    Token(Sample),
}

impl Client {
    /// Follow `fields` of `axis` (every field when empty), starting with their current values;
    /// `axis` may be a pattern such as `m*` or `*`.
    pub async fn monitor(&self, axis: &str, fields: &[Field]) -> Result<Monitor, zenoh::Error> {
        self.monitor_with_messages(axis, fields, false).await
    }

    /// `monitor`, and with `messages` the axis's messages too (its ERR key: refused writes and
    /// its controller's errors, as they come; a message has no current value).
    pub async fn monitor_with_messages(
        &self,
        axis: &str,
        fields: &[Field],
        messages: bool,
    ) -> Result<Monitor, zenoh::Error> {
        let layout = self.layout();
        let axis = &chunk_pattern(axis);
        let (queue, arrivals) = unbounded_channel();
        let mut subscribed: Vec<String> = match fields {
            [] => vec![layout.axis_fields(axis)],
            named => named.iter().map(|f| layout.field(axis, *f)).collect(),
        };
        if messages && !fields.is_empty() {
            subscribed.push(layout.err(axis));
        }
        if !fields.is_empty() && !fields.contains(&Field::PREC) {
            // PREC says how the values are shown: followed, not shown.
            subscribed.push(layout.field(axis, Field::PREC));
        }
        let mut subscribers = Vec::new();
        // The tokens there now, then each change: the history is what lets Zenoh tell a token's
        // end when its node dies (not only when the node withdraws it).
        let mut served = HashSet::new();
        let there = self.session().liveliness().get(layout.axis(axis)).timeout(PATIENCE).await?;
        while let Ok(reply) = there.recv_async().await {
            if let Ok(token) = reply.into_result() {
                served.insert(axis_of(layout, &token));
            }
        }
        let tokens = queue.clone();
        let token =
            self.session().liveliness().declare_subscriber(layout.axis(axis)).history(true).callback(move |sample| {
                let _ = tokens.send(Arrival::Token(sample));
            });
        subscribers.push(token.await?);
        for key in &subscribed {
            let queue = queue.clone();
            let subscriber = self.session().declare_subscriber(key).callback(move |sample| {
                let _ = queue.send(Arrival::Value(sample));
            });
            subscribers.push(subscriber.await?);
        }
        let monitor = Monitor {
            session: self.session().clone(),
            layout: layout.clone(),
            queue,
            wanted: fields.to_vec(),
            messages,
            arrivals,
            precs: HashMap::new(),
            served,
            _subscribers: subscribers,
        };
        monitor.read_current(axis).await?;
        Ok(monitor)
    }
}

impl Monitor {
    /// Ask for the current values of `axis` (a name or a pattern, as the keys spell it): its
    /// PREC first, then the fields followed, into the queue.
    async fn read_current(&self, axis: &str) -> Result<(), zenoh::Error> {
        let layout = &self.layout;
        let queue = self.queue.clone();
        let precision = self.session.get(layout.field(axis, Field::PREC)).timeout(PATIENCE);
        precision
            .callback(move |reply| {
                if let Ok(sample) = reply.into_result() {
                    let _ = queue.send(Arrival::Precision(sample));
                }
            })
            .await?;
        let keys: Vec<String> = match &self.wanted[..] {
            [] => vec![layout.axis_all(axis)],
            fields => fields.iter().map(|f| layout.field(axis, *f)).collect(),
        };
        for key in keys {
            let queue = self.queue.clone();
            self.session
                .get(key)
                .timeout(PATIENCE)
                .callback(move |reply| {
                    if let Ok(sample) = reply.into_result() {
                        let _ = queue.send(Arrival::Value(sample));
                    }
                })
                .await?;
        }
        Ok(())
    }

    /// The next value, current or changed; None once the session is closed.
    pub async fn next(&mut self) -> Option<Update> {
        loop {
            if let Event::Value(update) = self.next_event().await? {
                return Some(update);
            }
        }
    }

    /// The next value, or an axis's node gone or back; None once the session is closed.
    pub async fn next_event(&mut self) -> Option<Event> {
        loop {
            let (sample, shown) = match self.arrivals.recv().await? {
                Arrival::Value(sample) => (sample, true),
                Arrival::Precision(sample) => (sample, false),
                Arrival::Token(token) => {
                    let axis = axis_of(&self.layout, &token);
                    if token.kind() == SampleKind::Delete {
                        self.served.remove(&axis);
                        return Some(Event::Gone(axis));
                    }
                    // A token already known (the history's) is no news.
                    if !self.served.insert(axis.clone()) {
                        continue;
                    }
                    // Served again: its current values, as at the start.
                    let _ = self.read_current(&axis).await;
                    return Some(Event::Back(axis));
                }
            };
            let (field, name) = field_of(&sample);
            let axis = axis_of(&self.layout, &sample);
            let value = sample_value(&sample);
            if let (Some(Field::PREC), Some(prec)) = (field, value.as_f64()) {
                self.precs.insert(axis.clone(), prec as i16);
            }
            if !shown {
                continue;
            }
            let message = self.messages && name == zmotor_msgs::keys::ERR_KEY;
            let wanted = self.wanted.is_empty() || message || field.is_some_and(|f| self.wanted.contains(&f));
            if wanted {
                let shown =
                    field.map_or_else(|| value.to_string(), |f| show(f, &value, self.precs.get(&axis).copied()));
                let at = sample.timestamp().map_or_else(SystemTime::now, |t| t.get_time().to_system_time());
                return Some(Event::Value(Update { axis, field, name, value, at, shown }));
            }
        }
    }
}
