//! The values the gateway holds: which axes are live, and the last value of each field of the
//! axes a client follows, with when it arrived; and each circuit's own copy of them, which the
//! circuit reads as its `Directory`.

use std::cell::RefCell;
use std::collections::{HashMap, HashSet};
use zmotor_ca_proto::{Directory, Limits, Pv, Snapshot, Stamp, Target, ABLE};
use zmotor_msgs::menus::{severity, status};
use zmotor_msgs::{BridgeRecord, Field, Kind, Value};

/// A field's last value, and when it arrived.
#[derive(Clone, Debug)]
pub(crate) struct Entry {
    pub(crate) value: Value,
    pub(crate) stamp: Stamp,
}

/// One axis's values: its fields, and its last message (its ERR key); or a bridge record's
/// value.
#[derive(Clone, Default)]
pub(crate) struct AxisValues {
    fields: HashMap<Field, Entry>,
    message: Option<Entry>,
    /// A bridge record's value, once it has one.
    record: Option<Entry>,
    /// Whether the read of the whole axis has ended: until then nothing is shown (a client
    /// connecting would read VAL's limits as 0 or EGU as empty, their values not there yet).
    whole: bool,
}

impl AxisValues {
    /// Whether the node answered with the axis's values (its alarm state is among them), or a
    /// bridge record has its value.
    pub(crate) fn answered(&self) -> bool {
        self.fields.contains_key(&Field::STAT) || self.record.is_some()
    }

    fn take(&mut self, target: Target, entry: Entry) {
        match target {
            Target::Field(field) => {
                self.fields.insert(field, entry);
            }
            Target::Able => {
                self.fields.insert(Field::DISP, entry);
            }
            Target::Message | Target::MessageChars | Target::RecordType => self.message = Some(entry),
            // Constant: nothing on the network changes it.
            Target::Common(_) => {}
            Target::FieldChars(field) => {
                self.fields.insert(field, entry);
            }
            Target::BridgeValue(_) => self.record = Some(entry),
            Target::BridgeType(_) => {}
        }
    }

    fn number(&self, field: Field) -> f64 {
        self.fields.get(&field).and_then(|e| e.value.as_f64()).unwrap_or(0.0)
    }

    fn snapshot(&self, pv: &Pv) -> Option<Snapshot> {
        if !self.whole {
            return None;
        }
        match pv.target {
            Target::BridgeValue(_) | Target::BridgeType(_) => Some(self.record_snapshot(pv)),
            _ => self.motor_snapshot(pv),
        }
    }

    /// A motor's channel.
    fn motor_snapshot(&self, pv: &Pv) -> Option<Snapshot> {
        let alarm = self.fields.get(&Field::STAT)?;
        let (value, stamp, choices) = match pv.target {
            Target::FieldChars(field) => {
                let entry = self.fields.get(&field)?;
                (entry.value.clone(), entry.stamp, &[][..])
            }
            Target::Field(field) => {
                let entry = self.fields.get(&field)?;
                let choices = match field.def().kind {
                    Kind::Menu(menu) => menu.choices,
                    _ => &[],
                };
                (entry.value.clone(), entry.stamp, choices)
            }
            Target::Able => {
                let entry = self.fields.get(&Field::DISP)?;
                (entry.value.clone(), entry.stamp, ABLE.choices)
            }
            Target::RecordType => (Value::Text("motor".into()), alarm.stamp, &[][..]),
            Target::Common(_) => {
                let common = pv.target.common()?;
                let choices = match common.kind {
                    Kind::Menu(menu) => menu.choices,
                    _ => &[],
                };
                (common.value(), alarm.stamp, choices)
            }
            Target::Message | Target::MessageChars => match &self.message {
                Some(message) => (message.value.clone(), message.stamp, &[][..]),
                None => (Value::Text(String::new()), alarm.stamp, &[][..]),
            },
            Target::BridgeValue(_) | Target::BridgeType(_) => return None,
        };
        let egu = match self.fields.get(&Field::EGU).map(|e| &e.value) {
            Some(Value::Text(egu)) => egu.clone(),
            _ => String::new(),
        };
        let (upper, lower) = match pv.limits() {
            Limits::Fields(high, low) => (self.number(high), self.number(low)),
            Limits::RawDial => {
                let mres = self.number(Field::MRES);
                let (high, low) = (self.number(Field::DHLM) / mres, self.number(Field::DLLM) / mres);
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
        let prec = self.number(Field::PREC) as i16;
        // `_able` is a record of its own, a bo with no alarm of the motor's.
        let (status, severity, acknowledgement) = match pv.target {
            Target::Able => (0, 0, (1, 0)),
            _ => (
                self.number(Field::STAT) as u16,
                self.number(Field::SEVR) as u16,
                (self.number(Field::ACKT) as u16, self.number(Field::ACKS) as u16),
            ),
        };
        Some(Snapshot {
            value,
            native: pv.native(),
            status,
            severity,
            acknowledgement,
            stamp,
            units: pv.units(&egu),
            precision: match pv.target {
                Target::Field(field) => field.precision(prec),
                Target::RecordType | Target::Message | Target::MessageChars => prec,
                Target::Able | Target::Common(_) | Target::FieldChars(_) => 0,
                Target::BridgeValue(_) | Target::BridgeType(_) => 0,
            },
            upper,
            lower,
            alarm: pv.alarm_limits().map_or([f64::NAN; 4], |fields| fields.map(|f| self.number(f))),
            choices,
        })
    }
}

impl AxisValues {
    /// A bridge record's channel: its value, or, before it has one (a calc not yet processed),
    /// 0 undefined (UDF, INVALID), as an IOC's record reads before its first processing.
    fn record_snapshot(&self, pv: &Pv) -> Snapshot {
        let (value, stamp, alarm) = match &self.record {
            Some(entry) => (entry.value.clone(), entry.stamp, (status::NO_ALARM, severity::NO_ALARM)),
            None => (Value::Float(0.0), Stamp::default(), (status::UDF, severity::INVALID)),
        };
        let (upper, lower) = match pv.limits() {
            Limits::Range(range) => range,
            Limits::Fields(..) | Limits::RawDial => (0.0, 0.0),
        };
        Snapshot {
            value,
            native: pv.native(),
            status: alarm.0,
            severity: alarm.1,
            acknowledgement: (1, 0),
            stamp,
            units: String::new(),
            precision: 0,
            upper,
            lower,
            alarm: [f64::NAN; 4],
            choices: &[],
        }
    }
}

/// The values the front-end holds.
#[derive(Default)]
pub(crate) struct Values {
    pub(crate) live: HashSet<String>,
    /// The bridge records live now, by name (their tokens).
    pub(crate) records: HashMap<String, BridgeRecord>,
    /// The axes a client asked for since they became live, each with the subscriber to its
    /// fields (`None` while it is declared): the nodes publish only what someone follows.
    pub(crate) followed: HashMap<String, Option<zenoh::pubsub::Subscriber<()>>>,
    pub(crate) axes: HashMap<String, AxisValues>,
    /// How many changes have been told to the circuits: each is numbered, so that a circuit
    /// that copies an axis's values after change N takes only the changes after it.
    told: u64,
}

impl Values {
    /// Store a value and number the change that tells it.
    pub(crate) fn store(&mut self, axis: String, target: Target, entry: Entry) -> Change {
        self.axes.entry(axis.clone()).or_default().take(target, entry.clone());
        self.told += 1;
        Change::Value { axis, target, entry, number: self.told }
    }

    /// Show an axis whose read has ended, and number the change that tells it.
    pub(crate) fn show_whole(&mut self, axis: String) -> Change {
        self.axes.entry(axis.clone()).or_default().whole = true;
        self.told += 1;
        Change::Whole { axis, number: self.told }
    }

    /// Forget an axis or a bridge record that went, and number the change that tells it.
    pub(crate) fn forget(&mut self, axis: String) -> Change {
        self.live.remove(&axis);
        self.axes.remove(&axis);
        self.told += 1;
        Change::Gone { axis, number: self.told }
    }
}

impl Directory for Values {
    fn is_live(&self, axis: &str) -> bool {
        self.live.contains(axis)
    }

    fn bridge_record(&self, name: &str) -> Option<BridgeRecord> {
        self.records.get(name).copied()
    }

    fn snapshot(&self, pv: &Pv) -> Option<Snapshot> {
        self.axes.get(&pv.axis)?.snapshot(pv)
    }
}

/// What circuits are told of the network, in the order the gateway stored it.
#[derive(Clone, Debug)]
pub(crate) enum Change {
    /// A field of an axis, or its message, has this new value.
    Value { axis: String, target: Target, entry: Entry, number: u64 },
    /// The read of the whole axis ended: its values are shown from now on.
    Whole { axis: String, number: u64 },
    /// The axis went.
    Gone { axis: String, number: u64 },
}

/// A circuit's own copy of the values of the axes it serves: copied from the gateway's when it
/// first asks for an axis, then changed by each change in the order it handles them. What it
/// posts therefore never goes back, however far behind the network the circuit is: a null
/// move's DMOV 0 then 1 are posted as 0 then 1 (not the gateway's 1 twice), and a repost after
/// flow control is not followed by an older value.
#[derive(Default)]
pub(crate) struct Seen {
    /// Each axis's values, and the number of the last change they hold.
    axes: RefCell<HashMap<String, (u64, AxisValues)>>,
}

impl Seen {
    /// Take a change; whether the circuit must handle it (a change of an axis it does not serve,
    /// or one its copy already holds, is not).
    #[must_use]
    pub(crate) fn take(&mut self, change: &Change) -> bool {
        let axes = self.axes.get_mut();
        match change {
            Change::Value { axis, target, entry, number } => match axes.get_mut(axis) {
                Some((held, values)) if number > held => {
                    *held = *number;
                    values.take(*target, entry.clone());
                    true
                }
                _ => false,
            },
            Change::Whole { axis, number } => match axes.get_mut(axis) {
                Some((held, values)) if number > held => {
                    *held = *number;
                    values.whole = true;
                    true
                }
                _ => false,
            },
            Change::Gone { axis, number } => match axes.get(axis) {
                Some((held, _)) if number <= held => false,
                _ => {
                    axes.remove(axis);
                    true
                }
            },
        }
    }

    /// Drop every copy (the circuit lost changes): the next reads copy the gateway's again.
    pub(crate) fn forget_all(&mut self) {
        self.axes.get_mut().clear();
    }

    /// The values as this circuit shows them, copying an axis from `values` on first use.
    pub(crate) fn directory<'a>(&'a self, values: &'a Values) -> SeenDirectory<'a> {
        SeenDirectory { seen: self, values }
    }
}

/// A circuit's copy read as a `Directory`, with the gateway's values to copy from.
pub(crate) struct SeenDirectory<'a> {
    seen: &'a Seen,
    values: &'a Values,
}

impl Directory for SeenDirectory<'_> {
    fn is_live(&self, axis: &str) -> bool {
        self.values.is_live(axis)
    }

    fn bridge_record(&self, name: &str) -> Option<BridgeRecord> {
        self.values.bridge_record(name)
    }

    fn snapshot(&self, pv: &Pv) -> Option<Snapshot> {
        let mut axes = self.seen.axes.borrow_mut();
        let (_, values) = axes
            .entry(pv.axis.clone())
            .or_insert_with(|| (self.values.told, self.values.axes.get(&pv.axis).cloned().unwrap_or_default()));
        values.snapshot(pv)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(value: i64) -> Entry {
        Entry { value: Value::Int(value), stamp: Stamp::from_posix(0, 0) }
    }

    fn gateway_with_m1() -> Values {
        let mut values = Values::default();
        values.live.insert("m1".into());
        for field in [Field::STAT, Field::SEVR, Field::DMOV] {
            let _ = values.store("m1".into(), Target::Field(field), entry(i64::from(field == Field::DMOV)));
        }
        let _ = values.show_whole("m1".into());
        values
    }

    fn shown(seen: &Seen, values: &Values, pv: &Pv) -> Option<Value> {
        seen.directory(values).snapshot(pv).map(|s| s.value)
    }

    #[test]
    fn a_circuit_behind_the_network_shows_each_change_as_it_was_not_the_latest_value() {
        let mut values = gateway_with_m1();
        let dmov = Pv::parse("", "m1.DMOV").expect("a PV");
        let mut seen = Seen::default();
        assert_eq!(shown(&seen, &values, &dmov), Some(Value::Int(1)), "copied on first use");
        // A null move pulses DMOV 0 then 1 before the circuit handles the first change.
        let zero = values.store("m1".into(), Target::Field(Field::DMOV), entry(0));
        let one = values.store("m1".into(), Target::Field(Field::DMOV), entry(1));
        assert_eq!(values.snapshot(&dmov).map(|s| s.value), Some(Value::Int(1)));
        assert!(seen.take(&zero));
        assert_eq!(shown(&seen, &values, &dmov), Some(Value::Int(0)));
        assert!(seen.take(&one));
        assert_eq!(shown(&seen, &values, &dmov), Some(Value::Int(1)));
    }

    #[test]
    fn a_copy_takes_only_the_changes_after_it_and_none_of_axes_it_does_not_serve() {
        let mut values = gateway_with_m1();
        let _ = values.store("m2".into(), Target::Field(Field::STAT), entry(0));
        let dmov = Pv::parse("", "m1.DMOV").expect("a PV");
        let zero = values.store("m1".into(), Target::Field(Field::DMOV), entry(0));
        let mut seen = Seen::default();
        // Copied after the change: it holds 0 already, and a repost of it is not followed by an
        // older value when the change is handled.
        assert_eq!(shown(&seen, &values, &dmov), Some(Value::Int(0)));
        assert!(!seen.take(&zero));
        let m2 = values.store("m2".into(), Target::Field(Field::DMOV), entry(0));
        assert!(!seen.take(&m2), "m2 is not served by this circuit");
        let one = values.store("m1".into(), Target::Field(Field::DMOV), entry(1));
        assert!(seen.take(&one));
        assert_eq!(shown(&seen, &values, &dmov), Some(Value::Int(1)));
        // After lost changes the copy is made again, at the gateway's latest.
        let zero = values.store("m1".into(), Target::Field(Field::DMOV), entry(0));
        seen.forget_all();
        assert_eq!(shown(&seen, &values, &dmov), Some(Value::Int(0)));
        assert!(!seen.take(&zero));
    }

    #[test]
    fn an_axis_gone_is_forgotten_unless_the_copy_was_made_after_it_came_back() {
        let mut values = gateway_with_m1();
        let dmov = Pv::parse("", "m1.DMOV").expect("a PV");
        let mut seen = Seen::default();
        assert!(shown(&seen, &values, &dmov).is_some());
        let gone = values.forget("m1".into());
        assert!(seen.take(&gone));
        assert_eq!(shown(&seen, &values, &dmov), None, "copied again, with nothing in it");
        // Back, and copied again by a new channel before the circuit handles the old departure.
        let mut values = gateway_with_m1();
        let gone = values.forget("m1".into());
        let mut seen = Seen::default();
        for field in [Field::STAT, Field::SEVR, Field::DMOV] {
            let _ = values.store("m1".into(), Target::Field(field), entry(1));
        }
        let _ = values.show_whole("m1".into());
        values.live.insert("m1".into());
        assert!(shown(&seen, &values, &dmov).is_some());
        assert!(!seen.take(&gone), "an old departure does not cut a channel made after the return");
    }

    #[test]
    fn nothing_of_an_axis_is_shown_until_its_whole_read_has_ended() {
        let mut values = Values::default();
        let mut seen = Seen::default();
        let egu = Pv::parse("", "m1.EGU").expect("a PV");
        assert_eq!(shown(&seen, &values, &egu), None, "copied before anything arrived");
        let mut changes = vec![];
        for (field, value) in [(Field::STAT, Value::Int(0)), (Field::SEVR, Value::Int(0))] {
            changes.push(values.store(
                "m1".into(),
                Target::Field(field),
                Entry { value, stamp: Stamp::from_posix(0, 0) },
            ));
        }
        let text = Entry { value: Value::Text("mm".into()), stamp: Stamp::from_posix(0, 0) };
        changes.push(values.store("m1".into(), Target::Field(Field::EGU), text));
        changes.push(values.show_whole("m1".into()));
        let (whole, fields) = changes.split_last().expect("changes");
        for change in fields {
            assert!(seen.take(change));
            assert_eq!(shown(&seen, &values, &egu), None);
        }
        assert!(seen.take(whole));
        assert_eq!(shown(&seen, &values, &egu), Some(Value::Text("mm".into())));
    }
}
