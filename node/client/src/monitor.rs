//! Monitors, as camonitor makes them: the current value of each field first, then every
//! change. The subscription is declared before the current values are asked for, and both
//! arrive through one queue in the order the network delivered them, so no change between the
//! two is lost and none is shown out of order.

use crate::read::{axis_of, field_of, sample_value};
use crate::show::show;
use crate::Client;
use std::collections::HashMap;
use std::time::{Duration, SystemTime};
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver};
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;
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
    /// When it arrived.
    pub at: SystemTime,
    /// The value as camonitor shows it (menus by name, doubles at the axis's precision).
    pub shown: String,
}

/// A monitor of some fields of one axis (or of the axes a pattern names); it ends when dropped.
pub struct Monitor {
    layout: KeyLayout,
    /// The fields followed; empty for every field.
    wanted: Vec<Field>,
    /// Whether the axis's messages (ERR: refused writes, its controller's errors) are followed.
    messages: bool,
    arrivals: UnboundedReceiver<Arrival>,
    /// Each axis's PREC.
    precs: HashMap<String, i16>,
    _subscribers: Vec<Subscriber<()>>,
}

/// What reaches a monitor's queue.
enum Arrival {
    /// A value of a followed field, current or changed.
    Value(Sample),
    /// An axis's PREC, asked for first so the first values are shown at it.
    Precision(Sample),
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
        let mut followed: Vec<String> = match fields {
            [] => vec![layout.axis_fields(axis)],
            named => named.iter().map(|f| layout.field(axis, *f)).collect(),
        };
        let mut subscribed = followed.clone();
        if messages && !fields.is_empty() {
            subscribed.push(layout.err(axis));
        }
        if !fields.is_empty() && !fields.contains(&Field::PREC) {
            // PREC says how the values are shown: followed, not shown.
            subscribed.push(layout.field(axis, Field::PREC));
        }
        let mut subscribers = Vec::new();
        for key in &subscribed {
            let queue = queue.clone();
            let subscriber = self.session().declare_subscriber(key).callback(move |sample| {
                let _ = queue.send(Arrival::Value(sample));
            });
            subscribers.push(subscriber.await?);
        }
        if fields.is_empty() {
            followed = vec![layout.axis_all(axis)];
        }
        let precision = self.session().get(layout.field(axis, Field::PREC)).timeout(PATIENCE);
        let to_queue = queue.clone();
        precision
            .callback(move |reply| {
                if let Ok(sample) = reply.into_result() {
                    let _ = to_queue.send(Arrival::Precision(sample));
                }
            })
            .await?;
        for key in followed {
            let queue = queue.clone();
            self.session()
                .get(key)
                .timeout(PATIENCE)
                .callback(move |reply| {
                    if let Ok(sample) = reply.into_result() {
                        let _ = queue.send(Arrival::Value(sample));
                    }
                })
                .await?;
        }
        let wanted = fields.to_vec();
        let layout = layout.clone();
        Ok(Monitor { layout, wanted, messages, arrivals, precs: HashMap::new(), _subscribers: subscribers })
    }
}

impl Monitor {
    /// The next value, current or changed; None once the session is closed.
    pub async fn next(&mut self) -> Option<Update> {
        loop {
            let (sample, shown) = match self.arrivals.recv().await? {
                Arrival::Value(sample) => (sample, true),
                Arrival::Precision(sample) => (sample, false),
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
                let at = SystemTime::now();
                return Some(Update { axis, field, name, value, at, shown });
            }
        }
    }
}
