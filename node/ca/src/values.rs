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
    /// A field of an axis, or its message, has a new value: this one.
    Value(String, Target, Entry),
    Gone(String),
}

/// The values as a change left them: the changed field shows the value the change brought, not
/// a later one (a circuit that handles DMOV 0 after DMOV 1 arrived must still post 0).
pub(crate) struct AsChanged<'a> {
    pub(crate) values: &'a Values,
    pub(crate) axis: &'a str,
    pub(crate) target: Target,
    pub(crate) entry: &'a Entry,
}

impl Directory for AsChanged<'_> {
    fn is_live(&self, axis: &str) -> bool {
        self.values.is_live(axis)
    }

    fn snapshot(&self, pv: &Pv) -> Option<Snapshot> {
        let mut snapshot = self.values.snapshot(pv)?;
        if pv.axis != self.axis {
            return Some(snapshot);
        }
        let shows = pv.target == self.target || (self.target == Target::Message && pv.target == Target::MessageChars);
        if shows {
            (snapshot.value, snapshot.stamp) = (self.entry.value.clone(), self.entry.stamp);
        }
        let alarm_word = self.entry.value.as_f64().map(|v| v as u16);
        match (self.target, alarm_word) {
            (Target::Field(Field::STAT), Some(status)) => snapshot.status = status,
            (Target::Field(Field::SEVR), Some(severity)) => snapshot.severity = severity,
            _ => {}
        }
        Some(snapshot)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(value: Value) -> Entry {
        Entry { value, stamp: Stamp::from_posix(0, 0) }
    }

    #[test]
    fn a_change_is_shown_with_its_own_value_though_a_later_one_arrived() {
        let mut values = Values::default();
        let fields = values.fields.entry("m1".into()).or_default();
        for (field, value) in [(Field::DMOV, 1), (Field::STAT, 0), (Field::SEVR, 0), (Field::MOVN, 1)] {
            fields.insert(field, entry(Value::Int(value)));
        }
        let dmov = Pv::parse("", "m1.DMOV").expect("a PV");
        let movn = Pv::parse("", "m1.MOVN").expect("a PV");
        // DMOV 0 came, then DMOV 1, before a circuit handled the first change.
        let zero = entry(Value::Int(0));
        let as_changed = AsChanged { values: &values, axis: "m1", target: Target::Field(Field::DMOV), entry: &zero };
        assert_eq!(as_changed.snapshot(&dmov).map(|s| s.value), Some(Value::Int(0)));
        assert_eq!(as_changed.snapshot(&movn).map(|s| s.value), Some(Value::Int(1)), "other fields as they are");
        assert_eq!(values.snapshot(&dmov).map(|s| s.value), Some(Value::Int(1)));
        // An alarm change shows its own severity on every field of the axis.
        let major = entry(Value::Int(2));
        let as_changed = AsChanged { values: &values, axis: "m1", target: Target::Field(Field::SEVR), entry: &major };
        assert_eq!(as_changed.snapshot(&movn).map(|s| s.severity), Some(2));
    }
}
