//! The values the gateway holds: which axes are live, and the last value of each field of the
//! axes a client follows, with when it arrived; a circuit reads them as its `Directory`.

use std::collections::{HashMap, HashSet};
use zmotor_ca_proto::{Directory, Limits, Pv, Snapshot, Stamp, Target};
use zmotor_msgs::{Field, Kind, Value};

/// A field's last value, and when it arrived.
#[derive(Clone, Debug)]
pub(crate) struct Entry {
    pub(crate) value: Value,
    pub(crate) stamp: Stamp,
}

/// The values the front-end holds.
#[derive(Default)]
pub(crate) struct Values {
    pub(crate) live: HashSet<String>,
    /// The axes a client asked for since they became live, each with the subscriber to its
    /// fields (`None` while it is declared): the nodes publish only what someone follows.
    pub(crate) followed: HashMap<String, Option<zenoh::pubsub::Subscriber<()>>>,
    pub(crate) fields: HashMap<String, HashMap<Field, Entry>>,
    /// Each followed axis's last message (its ERR key).
    pub(crate) messages: HashMap<String, Entry>,
}

impl Values {
    fn number(&self, axis: &str, field: Field) -> f64 {
        self.entry(axis, field).and_then(|e| e.value.as_f64()).unwrap_or(0.0)
    }

    pub(crate) fn entry(&self, axis: &str, field: Field) -> Option<&Entry> {
        self.fields.get(axis)?.get(&field)
    }
}

impl Directory for Values {
    fn is_live(&self, axis: &str) -> bool {
        self.live.contains(axis)
    }

    fn snapshot(&self, pv: &Pv) -> Option<Snapshot> {
        let alarm = self.entry(&pv.axis, Field::STAT)?;
        let (value, stamp, choices) = match pv.target {
            Target::Field(field) => {
                let entry = self.entry(&pv.axis, field)?;
                let choices = match field.def().kind {
                    Kind::Menu(menu) => menu.choices,
                    _ => &[],
                };
                (entry.value.clone(), entry.stamp, choices)
            }
            Target::RecordType => (Value::Text("motor".into()), alarm.stamp, &[][..]),
            Target::Message | Target::MessageChars => match self.messages.get(&pv.axis) {
                Some(message) => (message.value.clone(), message.stamp, &[][..]),
                None => (Value::Text(String::new()), alarm.stamp, &[][..]),
            },
        };
        let egu = match self.entry(&pv.axis, Field::EGU).map(|e| &e.value) {
            Some(Value::Text(egu)) => egu.clone(),
            _ => String::new(),
        };
        let (upper, lower) = match pv.limits() {
            Limits::Fields(high, low) => (self.number(&pv.axis, high), self.number(&pv.axis, low)),
            Limits::RawDial => {
                let mres = self.number(&pv.axis, Field::MRES);
                let (high, low) =
                    (self.number(&pv.axis, Field::DHLM) / mres, self.number(&pv.axis, Field::DLLM) / mres);
                if mres == 0.0 {
                    (0.0, 0.0)
                } else if mres > 0.0 {
                    (high, low)
                } else {
                    (low, high)
                }
            }
            Limits::Range(range) => range,
        };
        let prec = self.number(&pv.axis, Field::PREC) as i16;
        Some(Snapshot {
            value,
            native: pv.native(),
            status: self.number(&pv.axis, Field::STAT) as u16,
            severity: self.number(&pv.axis, Field::SEVR) as u16,
            stamp,
            units: pv.units(&egu),
            precision: match pv.target {
                Target::Field(field) => field.precision(prec),
                Target::RecordType | Target::Message | Target::MessageChars => prec,
            },
            upper,
            lower,
            alarm: pv.alarm_limits().map_or([f64::NAN; 4], |fields| fields.map(|f| self.number(&pv.axis, f))),
            choices,
        })
    }
}

/// What circuits are told of the network.
#[derive(Clone, Debug)]
pub(crate) enum Change {
    /// A field of an axis, or its message, has a new value.
    Value(String, Target),
    Gone(String),
}
