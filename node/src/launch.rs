//! Launch files: a TOML description of the Zenoh side and of the axes to start. Every value is
//! checked before anything starts, and an error names the file, the axis and the key.

use crate::axis::PollRates;
use crate::driver::sim::SimConfig;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;
use zmotor_msgs::{keys, Access, Field, Fields, Value};

/// Highest readback rate while moving, Hz.
pub const MAX_READBACK_RATE: f64 = 1000.0;

#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    #[error("{file}: cannot read: {source}")]
    Io { file: String, source: std::io::Error },
    #[error("{file}: {message}")]
    Invalid { file: String, message: String },
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Launch {
    #[serde(default)]
    pub zenoh: ZenohSection,
    #[serde(default, rename = "axis")]
    pub axes: Vec<AxisSection>,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ZenohSection {
    /// "peer", "client" or "router".
    pub mode: String,
    pub listen: Vec<String>,
    pub connect: Vec<String>,
    pub multicast_scouting: bool,
    /// Key prefix of the axes.
    pub prefix: String,
}

impl Default for ZenohSection {
    fn default() -> Self {
        Self {
            mode: "peer".into(),
            listen: vec!["tcp/127.0.0.1:7447".into()],
            connect: vec![],
            multicast_scouting: false,
            prefix: keys::DEFAULT_PREFIX.into(),
        }
    }
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AxisSection {
    pub name: String,
    /// Only "sim" in this release.
    #[serde(default = "default_driver")]
    pub driver: String,
    /// Readback publications per second while moving.
    #[serde(default = "default_readback_rate")]
    pub readback_rate: f64,
    /// Initial field values, by EPICS field name.
    #[serde(default)]
    pub fields: BTreeMap<String, toml::Value>,
    #[serde(default)]
    pub sim: SimConfig,
}

fn default_driver() -> String {
    "sim".into()
}

fn default_readback_rate() -> f64 {
    10.0
}

/// An axis ready to start: validated fields, simulator and poll rates.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisPlan {
    pub name: String,
    pub fields: Fields,
    pub sim: SimConfig,
    pub rates: PollRates,
}

impl Launch {
    pub fn load(path: &Path) -> Result<Self, LaunchError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| LaunchError::Io { file: file.clone(), source })?;
        Self::parse(&text).map_err(|message| LaunchError::Invalid { file, message })
    }

    pub fn parse(text: &str) -> Result<Self, String> {
        let launch: Launch = toml::from_str(text).map_err(|e| e.to_string())?;
        if !matches!(launch.zenoh.mode.as_str(), "peer" | "client" | "router") {
            return Err(format!("zenoh.mode: '{}' is not one of peer, client, router", launch.zenoh.mode));
        }
        let mut seen = std::collections::BTreeSet::new();
        for axis in &launch.axes {
            if !seen.insert(axis.name.as_str()) {
                return Err(format!("axis '{}' is defined twice", axis.name));
            }
        }
        launch.plans()?;
        Ok(launch)
    }

    /// Validate and build every axis.
    pub fn plans(&self) -> Result<Vec<AxisPlan>, String> {
        self.axes.iter().map(AxisSection::plan).collect()
    }
}

impl AxisSection {
    fn plan(&self) -> Result<AxisPlan, String> {
        let at = |key: &str, message: String| format!("axis '{}': {key}: {message}", self.name);
        keys::validate_axis_name(&self.name).map_err(|e| at("name", e))?;
        if self.driver != "sim" {
            return Err(at("driver", format!("'{}' is not a known driver (known: sim)", self.driver)));
        }
        if !(self.readback_rate > 0.0 && self.readback_rate <= MAX_READBACK_RATE) {
            return Err(at("readback_rate", format!("{} Hz is outside (0, {MAX_READBACK_RATE}]", self.readback_rate)));
        }
        let mut fields = Fields { name: self.name.clone(), dtyp: "Sim Motor".into(), ..Fields::default() };
        for (name, raw) in &self.fields {
            let key = format!("fields.{name}");
            let field = Field::from_name(name).ok_or_else(|| at(&key, "no such field".into()))?;
            // Raw soft limits may be given, as in a database file; other read-only fields not.
            if field.def().access == Access::RO && !matches!(field, Field::RHLM | Field::RLLM) {
                return Err(at(&key, "read-only, cannot be configured".into()));
            }
            let value = match raw {
                toml::Value::Integer(i) => Value::Int(*i),
                toml::Value::Float(x) => Value::Float(*x),
                toml::Value::String(s) => Value::Text(s.clone()),
                toml::Value::Boolean(b) => Value::Int(i64::from(*b)),
                other => return Err(at(&key, format!("a number or a string is required, got {}", other.type_str()))),
            };
            let value = zmotor_msgs::validate(field.def(), value).map_err(|e| at(&key, e.to_string()))?;
            fields.set(field, &value);
        }
        let rates = PollRates { moving: 1.0 / self.readback_rate, ..PollRates::default() };
        Ok(AxisPlan { name: self.name.clone(), fields, sim: self.sim.clone(), rates })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
        [zenoh]
        listen = ["tcp/127.0.0.1:7447"]
        [[axis]]
        name = "m1"
        readback_rate = 50
        [axis.fields]
        MRES = 0.001
        VELO = 10
        DIR = "Neg"
        EGU = "mm"
        [axis.sim]
        high_limit_switch = 105000
    "#;

    #[test]
    fn a_good_file_builds_its_axes() {
        let launch = Launch::parse(GOOD).unwrap();
        assert_eq!(launch.zenoh.mode, "peer");
        assert!(!launch.zenoh.multicast_scouting);
        let plans = launch.plans().unwrap();
        let f = &plans[0].fields;
        assert_eq!((f.mres, f.velo, f.dir, f.egu.as_str(), f.name.as_str()), (0.001, 10.0, 1, "mm", "m1"));
        assert_eq!(plans[0].sim.high_limit_switch, Some(105000.0));
        assert_eq!(plans[0].rates.moving, 0.02);
    }

    #[test]
    fn errors_name_the_axis_and_key() {
        let bad = |text: &str| Launch::parse(text).unwrap_err();
        assert!(
            bad("[[axis]]\nname = \"m1\"\n[axis.fields]\nNOPE = 1").contains("axis 'm1': fields.NOPE: no such field")
        );
        assert!(bad("[[axis]]\nname = \"m1\"\n[axis.fields]\nRBV = 1").contains("fields.RBV: read-only"));
        assert!(bad("[[axis]]\nname = \"m1\"\n[axis.fields]\nDIR = \"Up\"").contains("'Up' is not a choice"));
        assert!(bad("[[axis]]\nname = \"m1\"\n[axis.fields]\nVELO = \"fast\"").contains("VELO: wrong type"));
        assert!(bad("[[axis]]\nname = \"m/1\"").contains("axis 'm/1': name"));
        assert!(bad("[[axis]]\nname = \"m1\"\ndriver = \"xps\"").contains("not a known driver"));
        assert!(bad("[[axis]]\nname = \"m1\"\nreadback_rate = 5000").contains("readback_rate"));
        assert!(bad("[[axis]]\nname = \"m1\"\n[[axis]]\nname = \"m1\"").contains("defined twice"));
        assert!(bad("[zenoh]\nmode = \"server\"").contains("zenoh.mode"));
        assert!(bad("[[axis]]\nname = \"m1\"\nspeed = 3").contains("unknown field"));
        assert!(bad("[[axis]\nname = ").contains("line 1"));
    }
}
