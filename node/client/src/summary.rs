//! What a user first wants to know of the network: the axes live on it, each with its
//! description, units, readback and whether it moves (`zmotor list`, the web index).

use crate::Client;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;
use zmotor_msgs::decode_cbor_value;
use zmotor_msgs::{Field, Value};

/// One live axis at a glance.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct AxisSummary {
    /// Its name.
    pub name: String,
    /// DESC.
    pub desc: Option<String>,
    /// EGU.
    pub egu: Option<String>,
    /// RBV.
    pub rbv: Option<f64>,
    /// PREC: the decimals RBV is shown with.
    pub prec: Option<i16>,
    /// Whether it moves (DMOV 0); `None` when DMOV did not answer.
    pub moving: Option<bool>,
}

/// How long a summary waits for the axes' answers.
const PATIENCE: Duration = Duration::from_secs(3);

impl Client {
    /// The live axes (by their liveliness tokens), read with one wildcard `get` per column.
    pub async fn live_axes(&self) -> Result<Vec<AxisSummary>, zenoh::Error> {
        let (session, layout) = (self.session(), self.layout());
        let tokens = session.liveliness().get(layout.axis("*")).timeout(PATIENCE).await?;
        let mut names = BTreeSet::new();
        while let Ok(reply) = tokens.recv_async().await {
            if let Some(axis) = reply.result().ok().and_then(|s| layout.axis_chunk(s.key_expr().as_str())) {
                names.insert(axis.to_string());
            }
        }
        let mut rows: BTreeMap<String, AxisSummary> =
            names.into_iter().map(|name| (name.clone(), AxisSummary { name, ..AxisSummary::default() })).collect();
        for field in [Field::DESC, Field::EGU, Field::RBV, Field::PREC, Field::DMOV] {
            let replies = session.get(layout.field_of_every_axis(field)).timeout(PATIENCE).await?;
            while let Ok(reply) = replies.recv_async().await {
                let Ok(sample) = reply.result() else { continue };
                let Some(row) = layout.axis_chunk(sample.key_expr().as_str()).and_then(|a| rows.get_mut(a)) else {
                    continue;
                };
                let Ok(value) = decode_cbor_value(&sample.payload().to_bytes()) else { continue };
                match (field, value) {
                    (Field::DESC, Value::Text(text)) => row.desc = Some(text),
                    (Field::EGU, Value::Text(text)) => row.egu = Some(text),
                    (Field::RBV, value) => row.rbv = value.as_f64(),
                    (Field::PREC, Value::Int(prec)) => row.prec = i16::try_from(prec).ok(),
                    (Field::DMOV, value) => row.moving = value.as_f64().map(|d| d == 0.0),
                    _ => {}
                }
            }
        }
        Ok(rows.into_values().collect())
    }
}
