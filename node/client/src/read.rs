//! Reads: one field, a pattern of fields or every field of an axis (or of the axes a pattern
//! such as `m*` names), each answer with the axis and the field it names, and each axis's PREC
//! so the values can be shown as caget shows them.

use crate::show::show;
use crate::Client;
use std::collections::BTreeMap;
use std::time::Duration;
use zenoh::sample::Sample;
use zmotor_msgs::keys::chunk_pattern;
use zmotor_msgs::{decode_cbor_value, KeyLayout};
use zmotor_msgs::{Field, Refusal, Value};

/// How long a read waits for its answers.
const PATIENCE: Duration = Duration::from_secs(5);

/// Which fields of an axis a read asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Selection<'a> {
    /// One field.
    Field(Field),
    /// The fields whose names match a pattern with `*` (`D*`).
    Pattern(&'a str),
    /// Every field.
    All,
    /// The axis's last message (its ERR key): the words of its last refused write or
    /// controller error, empty while it has none.
    LastMessage,
}

/// One field's value, as read.
#[derive(Clone, Debug, PartialEq)]
pub struct Reading {
    /// The axis the answer's key names.
    pub axis: String,
    /// The field, when the answer's key names one of the catalogue.
    pub field: Option<Field>,
    /// The last chunk of the answer's key (the field's name).
    pub name: String,
    /// The value (a payload that is no CBOR value as text).
    pub value: Value,
}

/// What a read of an axis (or of the axes a pattern names) brought.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AxisReading {
    /// The fields' values, by axis, each axis's in catalogue order.
    pub readings: Vec<Reading>,
    /// Error answers.
    pub refusals: Vec<Refusal>,
    /// Each axis's PREC, when it answered.
    pub precs: BTreeMap<String, i16>,
}

impl AxisReading {
    /// A reading's value as caget shows it (menus by name, doubles at its axis's precision).
    pub fn shown(&self, reading: &Reading) -> String {
        match reading.field {
            Some(field) => show(field, &reading.value, self.precs.get(&reading.axis).copied()),
            None => reading.value.to_string(),
        }
    }
}

/// A sample's value: CBOR as published, anything else as text.
pub(crate) fn sample_value(sample: &Sample) -> Value {
    let payload = sample.payload().to_bytes();
    let text = || Value::Text(String::from_utf8_lossy(&payload).into_owned());
    // Text says it is (ERR's messages): read as CBOR, "c884: ..." would be the string "884".
    if sample.encoding().to_string().starts_with("text/plain") {
        return text();
    }
    decode_cbor_value(&payload).unwrap_or_else(|_| text())
}

/// The axis a sample's key names.
pub(crate) fn axis_of(layout: &KeyLayout, sample: &Sample) -> String {
    layout.axis_chunk(sample.key_expr().as_str()).unwrap_or_default().to_string()
}

/// The field a sample's key names, and that name.
pub(crate) fn field_of(sample: &Sample) -> (Option<Field>, String) {
    let name = sample.key_expr().as_str().rsplit('/').next().unwrap_or_default().to_string();
    (Field::from_name(&name), name)
}

impl Client {
    /// Read `selection` of `axis` (an axis name, or a pattern such as `m*` or `*`), and each
    /// axis's PREC beside.
    pub async fn read(&self, axis: &str, selection: Selection<'_>) -> Result<AxisReading, zenoh::Error> {
        let layout = self.layout();
        let axis = &chunk_pattern(axis);
        let key = match selection {
            Selection::Field(field) => layout.field(axis, field),
            Selection::Pattern(pattern) => layout.field_pattern(axis, pattern),
            Selection::All => layout.axis_all(axis),
            Selection::LastMessage => layout.err(axis),
        };
        let session = self.session();
        let answers = session.get(&key).timeout(PATIENCE).await?;
        let precision = match selection {
            Selection::All | Selection::LastMessage => None,
            _ => Some(session.get(layout.field(axis, Field::PREC)).timeout(PATIENCE).await?),
        };
        let mut read = AxisReading::default();
        while let Ok(reply) = answers.recv_async().await {
            match reply.into_result() {
                Ok(sample) => {
                    let (field, name) = field_of(&sample);
                    let axis = axis_of(layout, &sample);
                    read.readings.push(Reading { axis, field, name, value: sample_value(&sample) });
                }
                // Some did not answer in time: what came is the read.
                Err(error) if crate::timed_out(&error) => {}
                Err(error) => {
                    read.refusals.push(Refusal::from_wire(&error.encoding().to_string(), &error.payload().to_bytes()))
                }
            }
        }
        read.readings.sort_by(|a, b| (&a.axis, a.field).cmp(&(&b.axis, b.field)));
        let mut precs: Vec<(String, Value)> = read
            .readings
            .iter()
            .filter(|r| r.field == Some(Field::PREC))
            .map(|r| (r.axis.clone(), r.value.clone()))
            .collect();
        if let Some(answers) = precision {
            while let Ok(reply) = answers.recv_async().await {
                if let Ok(sample) = reply.into_result() {
                    precs.push((axis_of(layout, &sample), sample_value(&sample)));
                }
            }
        }
        for (axis, prec) in precs {
            if let Some(prec) = prec.as_f64() {
                read.precs.insert(axis, prec as i16);
            }
        }
        Ok(read)
    }
}
