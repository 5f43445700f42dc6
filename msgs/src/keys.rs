//! The key layout of the wire contract (`<prefix>/<axis>/<FIELD>` and friends).

use crate::catalogue::Field;

/// Default key prefix of axes.
pub const DEFAULT_PREFIX: &str = "motor";
/// Prefix of the simulator's physical state and fault keys.
pub const SIM_PREFIX: &str = "sim";
/// Prefix of the keys of calc links and value holders imported from EPICS databases
/// (`bridge/<record>/<FIELD>`), a convention launch files may follow.
pub const BRIDGE_PREFIX: &str = "bridge";
/// Field-like key on which refused writes are reported as text.
pub const ERR_KEY: &str = "ERR";
/// Key suffix of the driver-command trace.
pub const DRIVER_CMD_KEY: &str = "@driver/cmd";

/// Builds and parses the keys of one deployment (one prefix).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct KeyLayout {
    prefix: String,
}

impl Default for KeyLayout {
    fn default() -> Self {
        Self::new(DEFAULT_PREFIX)
    }
}

impl KeyLayout {
    pub fn new(prefix: &str) -> Self {
        Self { prefix: prefix.trim_matches('/').to_string() }
    }

    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// `<prefix>/<axis>/<FIELD>`
    pub fn field(&self, axis: &str, field: Field) -> String {
        format!("{}/{axis}/{}", self.prefix, field.name())
    }

    /// `<prefix>/<axis>`: the axis's liveliness token.
    pub fn axis(&self, axis: &str) -> String {
        format!("{}/{axis}", self.prefix)
    }

    /// `<prefix>/<axis>/*`: every field key (writes are subscribed here).
    pub fn axis_fields(&self, axis: &str) -> String {
        format!("{}/{axis}/*", self.prefix)
    }

    /// `<prefix>/<axis>/**`: everything of one axis (gets are answered here).
    pub fn axis_all(&self, axis: &str) -> String {
        format!("{}/{axis}/**", self.prefix)
    }

    /// `<prefix>/*`: liveliness of every axis.
    pub fn all_axes(&self) -> String {
        format!("{}/*", self.prefix)
    }

    pub fn err(&self, axis: &str) -> String {
        format!("{}/{axis}/{ERR_KEY}", self.prefix)
    }

    pub fn driver_cmd(&self, axis: &str) -> String {
        format!("{}/{axis}/{DRIVER_CMD_KEY}", self.prefix)
    }

    /// The field name part of `<prefix>/<axis>/<FIELD>` for this axis, if the key has that shape.
    pub fn field_name<'k>(&self, axis: &str, key: &'k str) -> Option<&'k str> {
        let rest = key.strip_prefix(self.prefix.as_str())?.strip_prefix('/')?;
        let rest = rest.strip_prefix(axis)?.strip_prefix('/')?;
        (!rest.is_empty() && !rest.contains('/')).then_some(rest)
    }
}

/// `sim/<axis>/<name>`
pub fn sim_key(axis: &str, name: &str) -> String {
    format!("{SIM_PREFIX}/{axis}/{name}")
}

/// An axis name must be a single, plain key chunk.
pub fn validate_axis_name(name: &str) -> Result<(), String> {
    if name.is_empty() {
        return Err("an axis name must not be empty".into());
    }
    if let Some(c) = name.chars().find(|c| matches!(c, '/' | '*' | '$' | '?' | '#' | '@') || c.is_whitespace()) {
        return Err(format!("axis name '{name}' contains '{c}', which cannot stand in a key chunk"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_follow_the_contract() {
        let k = KeyLayout::default();
        assert_eq!(k.field("m1", Field::VAL), "motor/m1/VAL");
        assert_eq!(k.axis("m1"), "motor/m1");
        assert_eq!(k.axis_all("m1"), "motor/m1/**");
        assert_eq!(k.driver_cmd("m1"), "motor/m1/@driver/cmd");
        assert_eq!(KeyLayout::new("lab/motor/").field("x", Field::DMOV), "lab/motor/x/DMOV");
        assert_eq!(sim_key("m1", "position"), "sim/m1/position");
    }

    #[test]
    fn field_names_are_parsed_only_for_this_axis() {
        let k = KeyLayout::default();
        assert_eq!(k.field_name("m1", "motor/m1/VAL"), Some("VAL"));
        assert_eq!(k.field_name("m1", "motor/m10/VAL"), None);
        assert_eq!(k.field_name("m1", "motor/m1/@driver/cmd"), None);
        assert_eq!(k.field_name("m1", "motorx/m1/VAL"), None);
    }

    #[test]
    fn axis_names_are_checked() {
        assert!(validate_axis_name("m1").is_ok());
        assert!(validate_axis_name("a/b").is_err());
        assert!(validate_axis_name("").is_err());
        assert!(validate_axis_name("x*").is_err());
    }
}
