//! Launch files: a TOML description of the Zenoh side and of the axes to start. Every value is
//! checked before anything starts, and an error names the file, the axis and the key.

use crate::axis::PollRates;
use crate::driver::sim::SimConfig;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;
use zmotor_bridge::link::{find_cycle, input_index, CalcLinkSpec, InputMode, InputSpec, OutputOption};
use zmotor_msgs::{keys, Access, Field, Fields, KeyLayout, Value};

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
    #[serde(default, rename = "calc")]
    pub calcs: Vec<CalcSection>,
}

/// A calc link, shaped like a calcout record.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CalcSection {
    pub name: String,
    /// The CALC expression.
    pub expression: String,
    /// Inputs A–L: a key (CP: recompute on each update) or `{ key = "...", mode = "npp" }`.
    #[serde(default)]
    pub inputs: BTreeMap<String, CalcInput>,
    /// Key the result is written to.
    pub output: String,
    /// "every" (write every time, the default) or "on_change".
    #[serde(default = "default_option")]
    pub option: String,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(untagged)]
pub enum CalcInput {
    Key(String),
    Linked { key: String, mode: String },
}

fn default_option() -> String {
    "every".into()
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
    /// "sim" (the simulator) or "soft" (Soft Channel: the axis drives other keys).
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

/// An axis ready to start: validated fields, what drives it and poll rates.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisPlan {
    pub name: String,
    pub fields: Fields,
    pub driver: DriverPlan,
    pub rates: PollRates,
}

#[derive(Clone, Debug, PartialEq)]
pub enum DriverPlan {
    Sim(SimConfig),
    Soft,
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
        let mut seen = std::collections::BTreeSet::new();
        for calc in &launch.calcs {
            if !seen.insert(calc.name.as_str()) {
                return Err(format!("calc '{}' is defined twice", calc.name));
            }
        }
        let plans = launch.plans()?;
        let calcs = launch.calc_links()?;
        check_wiring(&KeyLayout::new(&launch.zenoh.prefix), &plans, &calcs)?;
        Ok(launch)
    }

    /// Validate and build every calc link.
    pub fn calc_links(&self) -> Result<Vec<CalcLinkSpec>, String> {
        self.calcs.iter().map(CalcSection::spec).collect()
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
        let driver = match self.driver.as_str() {
            "sim" => DriverPlan::Sim(self.sim.clone()),
            "soft" => DriverPlan::Soft,
            other => return Err(at("driver", format!("'{other}' is not a known driver (known: sim, soft)"))),
        };
        if !(self.readback_rate > 0.0 && self.readback_rate <= MAX_READBACK_RATE) {
            return Err(at("readback_rate", format!("{} Hz is outside (0, {MAX_READBACK_RATE}]", self.readback_rate)));
        }
        let dtyp = if driver == DriverPlan::Soft { "Soft Channel" } else { "Sim Motor" };
        let mut fields = Fields { name: self.name.clone(), dtyp: dtyp.into(), ..Fields::default() };
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
        Ok(AxisPlan { name: self.name.clone(), fields, driver, rates })
    }
}

impl CalcSection {
    fn spec(&self) -> Result<CalcLinkSpec, String> {
        let at = |key: &str, message: String| format!("calc '{}': {key}: {message}", self.name);
        let option = match self.option.as_str() {
            "every" => OutputOption::EveryTime,
            "on_change" => OutputOption::OnChange,
            other => return Err(at("option", format!("'{other}' is not one of every, on_change"))),
        };
        let mut inputs = Vec::new();
        for (letter, input) in &self.inputs {
            let index =
                input_index(letter).ok_or_else(|| at(&format!("inputs.{letter}"), "inputs are A to L".into()))?;
            let (key, mode) = match input {
                CalcInput::Key(key) => (key.clone(), InputMode::Process),
                CalcInput::Linked { key, mode } => match mode.to_ascii_lowercase().as_str() {
                    "cp" => (key.clone(), InputMode::Process),
                    "npp" => (key.clone(), InputMode::NoProcess),
                    other => {
                        return Err(at(&format!("inputs.{letter}.mode"), format!("'{other}' is not one of cp, npp")))
                    }
                },
            };
            zenoh_key(&key).map_err(|e| at(&format!("inputs.{letter}"), e))?;
            inputs.push(InputSpec { index, key, mode });
        }
        zenoh_key(&self.output).map_err(|e| at("output", e))?;
        let spec = CalcLinkSpec {
            name: self.name.clone(),
            expression: self.expression.clone(),
            inputs,
            output: self.output.clone(),
            option,
        };
        zmotor_bridge::CalcLink::new(spec.clone()).map_err(|e| e.to_string())?;
        Ok(spec)
    }
}

/// A key written to or read by a link must be a plain key (no wildcards).
fn zenoh_key(key: &str) -> Result<(), String> {
    if key.is_empty() || key.contains(['*', '$', '?', '#']) || key.starts_with('/') || key.ends_with('/') {
        return Err(format!("'{key}' is not a plain key"));
    }
    Ok(())
}

/// Refuse wiring that cannot work: calc links that feed themselves (a cycle of keys without a
/// motor in between), links to unknown fields, and writes to read-only fields.
fn check_wiring(layout: &KeyLayout, axes: &[AxisPlan], calcs: &[CalcLinkSpec]) -> Result<(), String> {
    if let Some(cycle) = find_cycle(calcs) {
        return Err(format!("calc links form a loop with no motor in between: {}", cycle.join(" → ")));
    }
    // (who, key, writes)
    let mut links: Vec<(String, &str, bool)> = Vec::new();
    for calc in calcs {
        for input in &calc.inputs {
            links.push((
                format!("calc '{}' input {}", calc.name, zmotor_bridge::link::input_name(input.index)),
                &input.key,
                false,
            ));
        }
        links.push((format!("calc '{}' output", calc.name), &calc.output, true));
    }
    for axis in axes {
        let f = &axis.fields;
        for (field, key, writes) in [
            (Field::OUT, &f.out, true),
            (Field::STOO, &f.stoo, true),
            (Field::RLNK, &f.rlnk, true),
            (Field::FLNK, &f.flnk, true),
            (Field::RDBL, &f.rdbl, false),
            (Field::RINP, &f.rinp, false),
            (Field::DINP, &f.dinp, false),
            (Field::DOL, &f.dol, false),
        ] {
            if !key.is_empty() {
                zenoh_key(key).map_err(|e| format!("axis '{}': fields.{field}: {e}", axis.name))?;
                links.push((format!("axis '{}' {field}", axis.name), key, writes));
            }
        }
    }
    for (who, key, writes) in links {
        let Some(rest) = key.strip_prefix(layout.prefix()).and_then(|r| r.strip_prefix('/')) else { continue };
        let Some((_, name)) = rest.split_once('/') else { continue };
        let field =
            Field::from_name(name).ok_or_else(|| format!("{who}: {key}: '{name}' is not a field of a motor"))?;
        if writes && field.def().access == Access::RO {
            return Err(format!("{who}: {key}: {field} is read-only"));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const WIRING: &str = r#"
        [[axis]]
        name = "lin"
        [[axis]]
        name = "rot"
        driver = "soft"
        [axis.fields]
        OUT = "bridge/drive/A"
        RDBL = "bridge/readback"
        DINP = "motor/lin/DMOV"
        STOO = "motor/lin/STOP"
        URIP = "Yes"
        [[calc]]
        name = "drive"
        expression = "TAN(A/57.296)*1000"
        inputs = { A = "bridge/drive/A" }
        output = "motor/lin/DVAL"
        [[calc]]
        name = "readback"
        expression = "ATAN(A/1000)*57.296"
        inputs = { A = "motor/lin/DRBV" }
        output = "bridge/readback"
    "#;

    #[test]
    fn the_tangent_arm_wiring_is_accepted() {
        let launch = Launch::parse(WIRING).unwrap();
        let calcs = launch.calc_links().unwrap();
        assert_eq!(calcs[0].inputs[0].mode, InputMode::Process);
        assert_eq!(launch.plans().unwrap()[1].driver, DriverPlan::Soft);
        assert_eq!(launch.plans().unwrap()[1].fields.dtyp, "Soft Channel");
    }

    #[test]
    fn broken_wiring_is_refused_at_start() {
        let cycle = WIRING
            .replace(r#"inputs = { A = "motor/lin/DRBV" }"#, r#"inputs = { A = "motor/lin/DVAL" }"#)
            .replace(r#"output = "bridge/readback""#, r#"output = "bridge/drive/A""#);
        assert_eq!(
            Launch::parse(&cycle).unwrap_err(),
            "calc links form a loop with no motor in between: drive → readback → drive"
        );
        let read_only = WIRING.replace(r#"output = "motor/lin/DVAL""#, r#"output = "motor/lin/RBV""#);
        assert_eq!(Launch::parse(&read_only).unwrap_err(), "calc 'drive' output: motor/lin/RBV: RBV is read-only");
        let unknown = WIRING.replace("motor/lin/DRBV", "motor/lin/DRBX");
        assert_eq!(
            Launch::parse(&unknown).unwrap_err(),
            "calc 'readback' input A: motor/lin/DRBX: 'DRBX' is not a field of a motor"
        );
        let unknown_axis_link = WIRING.replace(r#"DINP = "motor/lin/DMOV""#, r#"DINP = "motor/lin/DONE""#);
        assert!(Launch::parse(&unknown_axis_link).unwrap_err().starts_with("axis 'rot' DINP: motor/lin/DONE"));
        let npp = WIRING.replace(
            r#"inputs = { A = "motor/lin/DRBV" }"#,
            r#"inputs = { A = { key = "motor/lin/DRBV", mode = "sometimes" } }"#,
        );
        assert!(Launch::parse(&npp).unwrap_err().contains("'sometimes' is not one of cp, npp"));
    }

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
        assert!(matches!(&plans[0].driver, DriverPlan::Sim(sim) if sim.high_limit_switch == Some(105000.0)));
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
        assert!(bad("[[calc]]\nname = \"c\"\nexpression = \"A+\"\noutput = \"x\"")
            .contains("calc 'c': expression 'A+': column 3"));
        assert!(bad("[[calc]]\nname = \"c\"\nexpression = \"A\"\noutput = \"x\"\ninputs = { M = \"y\" }")
            .contains("inputs are A to L"));
        assert!(bad("[[calc]]\nname = \"c\"\nexpression = \"A\"\noutput = \"x/*\"").contains("not a plain key"));
        assert!(bad("[[axis]]\nname = \"m1\"\nreadback_rate = 5000").contains("readback_rate"));
        assert!(bad("[[axis]]\nname = \"m1\"\n[[axis]]\nname = \"m1\"").contains("defined twice"));
        assert!(bad("[zenoh]\nmode = \"server\"").contains("zenoh.mode"));
        assert!(bad("[[axis]]\nname = \"m1\"\nspeed = 3").contains("unknown field"));
        assert!(bad("[[axis]\nname = ").contains("line 1"));
    }
}
