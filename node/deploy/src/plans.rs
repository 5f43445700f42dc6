//! What the sections of a launch become: an axis's plan, a controller's spec, a calc link's
//! spec; and the wiring between them, checked.

use crate::file::{
    AxisSection, CalcInput, CalcOption, CalcSection, ControllerSection, DriverKind, FlowControlChoice, InputLinkMode,
    JogHoldChoice, Origin, ParityChoice, DEFAULT_IDLE_POLL, DEFAULT_MOVING_POLL, MAX_READBACK_RATE,
};
use crate::problem::Problem;
use std::collections::BTreeMap;
use std::time::Duration;
use zmotor_bridge::{find_cycle, input_index, CalcLinkSpec, InputMode, InputSpec, OutputOption};
use zmotor_controllers::{
    ControllerConfig, MacroValue, ProtocolKind, ProtocolOptions, RecordUnits, ScriptSettings, ScriptSource,
};
use zmotor_controllers::{ControllerSpec, FlowControl, Parity, SerialSettings, SpecError, Transport};
use zmotor_core::JogHold;
use zmotor_core::{AxisPlan, DriverPlan, PollRates};
use zmotor_msgs::field_value;
use zmotor_msgs::{keys, Access, Field, Fields, KeyLayout, Kind, LinkKeyError, Value};

impl AxisSection {
    pub(crate) fn plan(&self) -> Result<AxisPlan, Problem> {
        let at = |inner: &[&str], message: String| {
            let key = inner.join(".");
            Problem::in_item("axis", self.origin, inner, format!("axis '{}': {key}: {message}", self.name))
        };
        keys::validate_axis_name(&self.name).map_err(|e| at(&["name"], e.to_string()))?;
        let driver = match (self.driver, &self.controller, self.channel) {
            (DriverKind::Controller, Some(controller), Some(channel)) => {
                DriverPlan::Controller { controller: controller.clone(), channel }
            }
            (DriverKind::Controller, None, _) => return Err(at(&["controller"], "names no [[controller]]".into())),
            (DriverKind::Controller, _, None) => {
                return Err(at(&["channel"], "the controller's number for the axis is missing".into()))
            }
            (_, Some(_), _) => return Err(at(&["controller"], "only with driver = \"controller\"".into())),
            (_, _, Some(_)) => return Err(at(&["channel"], "only with driver = \"controller\"".into())),
            (DriverKind::Sim, None, None) => {
                self.sim.check().map_err(|e| at(&["sim"], e.to_string()))?;
                DriverPlan::Sim(self.sim.clone())
            }
            (DriverKind::Soft, None, None) => DriverPlan::Soft,
        };
        if !matches!(driver, DriverPlan::Sim(_)) && self.sim != zmotor_core::SimConfig::default() {
            return Err(at(&["sim"], "the simulator's model, for driver = \"sim\" only".into()));
        }
        if !(self.readback_rate > 0.0 && self.readback_rate <= MAX_READBACK_RATE) {
            let message = format!("{} Hz is outside (0, {MAX_READBACK_RATE}]", self.readback_rate);
            return Err(at(&["readback_rate"], message));
        }
        let dtyp = match driver {
            DriverPlan::Soft => "Soft Channel",
            DriverPlan::Sim(_) => "Sim Motor",
            DriverPlan::Controller { .. } => "asynMotor",
        };
        let mut fields = Fields { name: self.name.clone(), dtyp: dtyp.into(), ..Fields::default() };
        for (name, raw) in &self.fields {
            let inner = ["fields", name.as_str()];
            let field = Field::from_name(name).ok_or_else(|| {
                let hint = Field::from_name_any_case(name).map(|f| format!(" (field names are upper case: {f})"));
                at(&inner, format!("no such field{}", hint.unwrap_or_default()))
            })?;
            // Raw soft limits may be given, as in a database file; other read-only fields not.
            if field.def().access == Access::RO && !matches!(field, Field::RHLM | Field::RLLM) {
                return Err(at(&inner, "read-only, cannot be configured".into()));
            }
            if field.is_command() {
                let message = "a command, not a setting: a launch file configures an axis and never commands it \
                               (it would act at the axis's first write)";
                return Err(at(&inner, message.into()));
            }
            if field.starts_at_readback() {
                let message = "an axis starts where its readback is (the record sets VAL and RVAL from it); DVAL sets \
                               its position";
                return Err(at(&inner, message.into()));
            }
            // The key names the field already: its messages lose their own "VELO: ".
            let unnamed = |message: String| match message.strip_prefix(&format!("{field}: ")) {
                Some(rest) => rest.to_string(),
                None => message,
            };
            let value = field_value(field, raw).map_err(|e| at(&inner, unnamed(e.to_string())))?;
            if let Some(unusable) = zmotor_core::Unusable::of(field, &value) {
                return Err(at(&inner, unnamed(unusable.to_string())));
            }
            fields.set(field, &value);
        }
        let rates = PollRates { moving: Duration::from_secs_f64(1.0 / self.readback_rate), ..PollRates::default() };
        let jog_hold = match self.jog_hold {
            JogHoldChoice::Optional => JogHold::Optional,
            JogHoldChoice::Required => JogHold::Required,
        };
        Ok(AxisPlan { name: self.name.clone(), fields, driver, rates, jog_hold })
    }
}

impl ControllerSection {
    /// The controller, driving `axes` (each channel, with its axis's EGU and MRES); every
    /// setting checked.
    pub(crate) fn spec(&self, axes: Vec<(usize, RecordUnits)>) -> Result<ControllerSpec, Problem> {
        let at = |inner: &[&str], message: String| {
            let key = inner.join(".");
            Problem::in_item("controller", self.origin, inner, format!("controller '{}': {key}: {message}", self.name))
        };
        if self.name.trim().is_empty() {
            return Err(at(&["name"], "must not be empty".into()));
        }
        let protocol = ProtocolKind::from_name(&self.protocol).ok_or_else(|| {
            at(&["protocol"], format!("'{}' is not a known protocol (known: {})", self.protocol, ProtocolKind::known()))
        })?;
        let transport = match (&self.tcp, &self.serial) {
            (Some(address), None) => {
                let (host, port) = address.rsplit_once(':').unwrap_or((address, ""));
                if host.is_empty() || port.parse::<u16>().map_or(true, |p| p == 0) {
                    return Err(at(&["tcp"], format!("'{address}' is not host:port")));
                }
                Transport::Tcp { address: address.clone() }
            }
            (None, Some(serial)) => {
                let settings = SerialSettings {
                    device: serial.device.clone(),
                    baud: serial.baud,
                    parity: match serial.parity {
                        ParityChoice::None => Parity::None,
                        ParityChoice::Odd => Parity::Odd,
                        ParityChoice::Even => Parity::Even,
                    },
                    data_bits: serial.data_bits,
                    stop_bits: serial.stop_bits,
                    flow_control: match serial.flow_control {
                        FlowControlChoice::None => FlowControl::None,
                        FlowControlChoice::Software => FlowControl::Software,
                        FlowControlChoice::Hardware => FlowControl::Hardware,
                    },
                };
                settings.check().map_err(|e| at(&["serial"], e.to_string()))?;
                if protocol.opens_several_connections() {
                    let why = format!(
                        "{} opens a connection for each axis's motion beside the main one, and a serial line is one: give tcp = \"host:port\"",
                        protocol.name()
                    );
                    return Err(at(&["serial"], why));
                }
                Transport::Serial(settings)
            }
            // A script may talk to the node's keys only (softMotor.lua).
            (None, None) if protocol == ProtocolKind::Script => Transport::None,
            (None, None) => {
                let why =
                    "give one of tcp = \"host:port\" or a [controller.serial] port (only a script may have neither)";
                return Err(at(&["name"], why.into()));
            }
            _ => {
                return Err(at(
                    &["name"],
                    "give one of tcp = \"host:port\" or a [controller.serial] port, not both".into(),
                ))
            }
        };
        let mut names = BTreeMap::new();
        for (channel, name) in &self.axis_names {
            let number = channel.parse::<usize>().map_err(|_| {
                at(&["axis_names"], format!("'{channel}' is not a channel number: write {{ 1 = \"GROUP1.POS\" }}"))
            })?;
            names.insert(number, name.clone());
        }
        let mut script = self.script_source(protocol).map_err(|(key, message)| at(&[key], message))?;
        if let Some(source) = &mut script {
            source.record_resolution = axes.iter().map(|(channel, units)| (*channel, units.mres)).collect();
        }
        let settings = match &script {
            Some(source) => ScriptSettings::of(source).map_err(|e| at(&["script"], e.to_string()))?,
            None => ScriptSettings::default(),
        };
        let options = ProtocolOptions { units_per_step: self.units_per_step, names, script };
        options.check(protocol).map_err(|e| {
            let key = if matches!(e, SpecError::NoNames(_) | SpecError::Name { .. }) {
                "axis_names"
            } else {
                "units_per_step"
            };
            at(&[key], e.to_string())
        })?;
        let period = |key: &'static str, seconds: f64, min: f64, max: f64| {
            ControllerConfig::checked_period(key, seconds, min, max).map_err(|e| at(&[key], e.to_string()))
        };
        // The launch file's periods, or the script's, or the defaults.
        let moving_poll = self.moving_poll.or(settings.moving_poll).unwrap_or(DEFAULT_MOVING_POLL);
        let idle_poll = self.idle_poll.or(settings.idle_poll).unwrap_or(DEFAULT_IDLE_POLL);
        let defaults = ControllerConfig::for_channels(axes.iter().map(|(channel, _)| *channel).collect());
        let fast_polls = match settings.forced_fast_polls {
            Some(n) if n.is_finite() && (0.0..=100.0).contains(&n) => n as u32,
            Some(n) => return Err(at(&["script"], format!("ForcedFastPolls = {n} is not a count from 0 to 100"))),
            None => defaults.fast_polls,
        };
        let config = ControllerConfig {
            moving_poll: period("moving_poll", moving_poll, 0.001, 10.0)?,
            idle_poll: period("idle_poll", idle_poll, 0.001, 60.0)?,
            fast_polls,
            timeout: period("timeout", self.timeout, 0.001, 60.0)?,
            retries: self.retries,
            observe: self.observe,
            ..defaults
        };
        let config = ControllerConfig { record_units: axes.into_iter().collect(), ..config };
        if self.retries > 10 {
            return Err(at(&["retries"], format!("{} is more than 10", self.retries)));
        }
        Ok(ControllerSpec { name: self.name.clone(), protocol, options, transport, config })
    }
}

impl ControllerSection {
    /// A script controller's script, with its macros: given for `protocol = "script"` only.
    fn script_source(&self, protocol: ProtocolKind) -> Result<Option<ScriptSource>, (&'static str, String)> {
        let is_script = protocol == ProtocolKind::Script;
        if !is_script {
            let given = [
                ("script", self.script.is_some()),
                ("macros", !self.macros.is_empty()),
                ("axis_macros", !self.axis_macros.is_empty()),
            ];
            if let Some((key, _)) = given.into_iter().find(|(_, given)| *given) {
                return Err((key, format!("only a script controller (protocol = \"script\") takes a {key}")));
            }
            return Ok(None);
        }
        let Some(files) = &self.script_files else {
            let message = match &self.script {
                Some(_) => "the script was not read (a launch built in memory reads no files)",
                None => "give the Lua script: script = \"scripts/my_controller.lua\" (relative to this file)",
            };
            return Err(("script", message.into()));
        };
        let macros = |table: &BTreeMap<String, toml::Value>, key: &'static str| {
            table
                .iter()
                .map(|(name, value)| {
                    let value = match value {
                        toml::Value::String(text) => MacroValue::Text(text.clone()),
                        toml::Value::Integer(n) => MacroValue::Integer(*n),
                        toml::Value::Float(n) => MacroValue::Number(*n),
                        toml::Value::Boolean(b) => MacroValue::Boolean(*b),
                        other => {
                            let why =
                                format!("{name} is a {}: a macro is a string, a number or a boolean", other.type_str());
                            return Err((key, why));
                        }
                    };
                    Ok((name.clone(), value))
                })
                .collect::<Result<BTreeMap<_, _>, _>>()
        };
        let mut axis_macros = BTreeMap::new();
        for (channel, table) in &self.axis_macros {
            let number = channel.parse::<usize>().map_err(|_| {
                (
                    "axis_macros",
                    format!("'{channel}' is not a channel number: write {{ 0 = {{ OPEN_LOOP = \"NO\" }} }}"),
                )
            })?;
            protocol.check_channel(number).map_err(|e| ("axis_macros", e.to_string()))?;
            axis_macros.insert(number, macros(table, "axis_macros")?);
        }
        Ok(Some(ScriptSource {
            path: files.path.clone(),
            text: files.text.clone(),
            modules: files.modules.clone(),
            driver: self.name.clone(),
            macros: macros(&self.macros, "macros")?,
            axis_macros,
            record_resolution: BTreeMap::new(),
        }))
    }
}

impl CalcSection {
    pub(crate) fn spec(&self) -> Result<CalcLinkSpec, Problem> {
        let at = |inner: &[&str], message: String| {
            let key = inner.join(".");
            Problem::in_item("calc", self.origin, inner, format!("calc '{}': {key}: {message}", self.name))
        };
        let option = match self.option {
            CalcOption::Every => OutputOption::EveryTime,
            CalcOption::OnChange => OutputOption::OnChange,
        };
        let mut inputs = Vec::new();
        for (letter, input) in &self.inputs {
            let inner = ["inputs", letter.as_str()];
            let index = input_index(letter).ok_or_else(|| at(&inner, "inputs are A to P".into()))?;
            let (key, mode) = match input {
                CalcInput::Key(key) => (key.clone(), InputMode::Process),
                CalcInput::Linked { key, mode: InputLinkMode::Cp } => (key.clone(), InputMode::Process),
                CalcInput::Linked { key, mode: InputLinkMode::Npp } => (key.clone(), InputMode::NoProcess),
            };
            keys::validate_plain_key(&key).map_err(|e| at(&inner, e.to_string()))?;
            inputs.push(InputSpec { index, key, mode });
        }
        let mut constants = Vec::new();
        for (letter, value) in &self.constants {
            let inner = ["constants", letter.as_str()];
            let index = input_index(letter).ok_or_else(|| at(&inner, "inputs are A to P".into()))?;
            if !value.is_finite() {
                return Err(at(&inner, "must be a finite number".into()));
            }
            constants.push((index, *value));
        }
        keys::validate_plain_key(&self.output).map_err(|e| at(&["output"], e.to_string()))?;
        let mut processed_by: Vec<String> = Vec::new();
        for key in &self.processed_by {
            keys::validate_plain_key(key).map_err(|e| at(&["processed_by"], e.to_string()))?;
            // Named twice, it would process twice a write.
            if !processed_by.contains(key) {
                processed_by.push(key.clone());
            }
        }
        let spec = CalcLinkSpec {
            name: self.name.clone(),
            expression: self.expression.clone(),
            inputs,
            constants,
            output: self.output.clone(),
            option,
            processed_by,
        };
        zmotor_bridge::CalcLink::new(spec.clone())
            .map_err(|e| Problem::in_item("calc", self.origin, &["expression"], e.to_string()))?;
        Ok(spec)
    }
}

/// Refuse wiring that cannot work: calc links that feed themselves (a cycle of keys without a
/// motor in between), links to unknown fields, and writes to read-only fields. `axes` and `calcs`
/// are in the order of the launch's items, so each problem points at its item.
pub(crate) fn check_wiring(
    layout: &KeyLayout,
    axes: &[AxisPlan],
    axis_origins: &[Origin],
    calcs: &[CalcLinkSpec],
    calc_origins: &[Origin],
) -> Result<(), Problem> {
    if let Some(cycle) = find_cycle(calcs) {
        let first = calcs.iter().position(|c| c.name == cycle[0]).unwrap_or(0);
        let message = format!("calc links form a loop with no motor in between: {}", cycle.join(" → "));
        return Err(Problem::in_item("calc", calc_origins[first], &[], message));
    }
    // The calc links' keys were checked to be plain where they were read.
    for (calc, origin) in calcs.iter().zip(calc_origins) {
        let problem = |who: String, e: LinkKeyError| Problem::in_item("calc", *origin, &[], format!("{who}: {e}"));
        for input in &calc.inputs {
            let letter = zmotor_bridge::input_name(input.index);
            let who = format!("calc '{}' input {letter}", calc.name);
            layout.check_link(&input.key, false, None).map_err(|e| problem(who, e))?;
        }
        let who = format!("calc '{}' output", calc.name);
        layout.check_link(&calc.output, true, None).map_err(|e| problem(who, e))?;
        for key in &calc.processed_by {
            let who = format!("calc '{}' processed_by", calc.name);
            layout.check_link(key, false, None).map_err(|e| problem(who, e))?;
        }
    }
    for (axis, origin) in axes.iter().zip(axis_origins) {
        for field in Field::all().filter(|f| f.def().kind == Kind::Link) {
            let Value::Text(key) = axis.fields.get(field) else { continue };
            if key.is_empty() {
                continue;
            }
            match layout.check_link(&key, field.is_output_link(), Some(&axis.name)) {
                Ok(()) => {}
                Err(LinkKeyError::NotPlain(e)) => {
                    let inner = ["fields", field.name()];
                    let message = format!("axis '{}': fields.{field}: {e}", axis.name);
                    return Err(Problem::in_item("axis", *origin, &inner, message));
                }
                Err(e) => {
                    return Err(Problem::in_item("axis", *origin, &[], format!("axis '{}' {field}: {e}", axis.name)))
                }
            }
        }
    }
    Ok(())
}
