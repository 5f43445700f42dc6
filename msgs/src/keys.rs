//! The key layout of the wire contract (`<prefix>/<axis>/<FIELD>` and friends).

use crate::catalogue::Field;

/// Default key prefix of axes.
pub const DEFAULT_PREFIX: &str = "motor";
/// Prefix of the simulator's physical state and fault keys.
pub const SIM_PREFIX: &str = "sim";
/// The simulator's physical state report: `sim/<axis>/state`.
pub const SIM_STATE_KEY: &str = "state";
/// Prefix of the keys of calc links and value holders imported from EPICS databases
/// (`bridge/<record>/<FIELD>`), a convention launch files may follow.
pub const BRIDGE_PREFIX: &str = "bridge";
/// `bridge/<record>/<field>`: the key of a field of a record the bridge runs (an imported calc's
/// input, a transform's field, a record's PROC).
#[must_use]
pub fn bridge_key(record: &str, field: &str) -> String {
    format!("{BRIDGE_PREFIX}/{record}/{field}")
}

/// A record the bridge serves beside the axes, as an IOC's record of that type: a value holder
/// is an `ao` (clients write it), a calc link whose result has no output but its own
/// `bridge/<record>/VAL` a `calc` (read). Each is announced by a liveliness token
/// (`BridgeRecord::token`), so that a front-end (Channel Access) knows which records are live.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BridgeRecord {
    /// A value holder: an ao record.
    Value,
    /// A calc link's result: a calc record's VAL.
    Calc,
}

impl BridgeRecord {
    /// The record type an IOC would give it (`RTYP`).
    #[must_use]
    pub fn record_type(self) -> &'static str {
        match self {
            BridgeRecord::Value => "ao",
            BridgeRecord::Calc => "calc",
        }
    }

    /// `bridge/<record>/<type>`: the liveliness token of a live record `name` of this kind.
    #[must_use]
    pub fn token(self, name: &str) -> String {
        format!("{BRIDGE_PREFIX}/{name}/{}", self.record_type())
    }

    /// `bridge/*/*`: every bridge record's token.
    #[must_use]
    pub fn every_token() -> String {
        format!("{BRIDGE_PREFIX}/*/*")
    }

    /// The record a token names, and its kind, if `key` is one.
    #[must_use]
    pub fn of_token(key: &str) -> Option<(&str, BridgeRecord)> {
        let (name, kind) = key.strip_prefix(BRIDGE_PREFIX)?.strip_prefix('/')?.split_once('/')?;
        let kind = [BridgeRecord::Value, BridgeRecord::Calc].into_iter().find(|k| k.record_type() == kind)?;
        validate_axis_name(name).ok().map(|()| (name, kind))
    }

    /// `bridge/<record>/VAL`: the key of a record's value.
    #[must_use]
    pub fn value_key(name: &str) -> String {
        bridge_key(name, "VAL")
    }

    /// The record whose value `key` is, if it is one (`BridgeRecord::value_key`).
    #[must_use]
    pub fn of_value_key(key: &str) -> Option<&str> {
        let name = key.strip_prefix(BRIDGE_PREFIX)?.strip_prefix('/')?.strip_suffix("/VAL")?;
        validate_axis_name(name).ok().map(|()| name)
    }
}

/// Field-like key on which refused writes are reported as text.
pub const ERR_KEY: &str = "ERR";
/// Key suffix of the driver-command trace.
pub const DRIVER_CMD_KEY: &str = "@driver/cmd";
/// Key suffix of an axis's readback bundle (`KeyLayout::readback`).
pub const READBACK_KEY: &str = "@readback";
/// The chunk of a write key (`KeyLayout::write`).
pub const WRITE_CHUNK: &str = "@write";
/// Selector parameter of a put-with-completion (`<prefix>/<axis>/<FIELD>?wait`).
pub const WAIT_PARAMETER: &str = "wait";

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

/// A key chunk from a name as a user types it, `*` standing for any characters (`m*`, `D*`):
/// a `*` inside a chunk is spelt `$*` in a key expression; `*` and `**` stay as they are.
#[must_use]
pub fn chunk_pattern(pattern: &str) -> String {
    if pattern == "*" || pattern == "**" {
        return pattern.to_string();
    }
    // Stars in a row are one (`$*$*` is no key expression).
    let mut chunk = String::with_capacity(pattern.len() + 2);
    for c in pattern.chars() {
        match c {
            '*' if chunk.ends_with("$*") => {}
            '*' => chunk.push_str("$*"),
            c => chunk.push(c),
        }
    }
    chunk
}

impl KeyLayout {
    /// The layout under `prefix` (surrounding slashes are dropped).
    pub fn new(prefix: &str) -> Self {
        Self { prefix: prefix.trim_matches('/').to_string() }
    }

    /// The key prefix of this deployment's axes (e.g. `motor`).
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

    /// `<prefix>/<axis>/*`: every field key of one axis (a monitor of all its fields).
    pub fn axis_fields(&self, axis: &str) -> String {
        format!("{}/{axis}/*", self.prefix)
    }

    /// `<prefix>/<axis>/**`: everything of one axis (a read of all its fields).
    pub fn axis_all(&self, axis: &str) -> String {
        format!("{}/{axis}/**", self.prefix)
    }

    /// `<prefix>/*/*`: every field key of every axis (a node subscribes to writes here).
    pub fn every_field(&self) -> String {
        format!("{}/*/*", self.prefix)
    }

    /// `<prefix>/**`: everything under the prefix (a node answers queries here).
    pub fn everything(&self) -> String {
        format!("{}/**", self.prefix)
    }

    /// `<prefix>/<axis>/ERR`: where refused fire-and-forget writes are reported as text.
    pub fn err(&self, axis: &str) -> String {
        format!("{}/{axis}/{ERR_KEY}", self.prefix)
    }

    /// `<prefix>/<axis>/@readback`: the axis's readback bundle (`Readback`), one sample per
    /// poll or write that changed any of its fields. Opt-in: `*` and `**` never match a chunk
    /// that starts with `@`, so only a subscriber that names it gets it.
    pub fn readback(&self, axis: &str) -> String {
        format!("{}/{axis}/{READBACK_KEY}", self.prefix)
    }

    /// `<prefix>/<axis>/@driver/cmd`: the axis's driver-command trace.
    pub fn driver_cmd(&self, axis: &str) -> String {
        format!("{}/{axis}/{DRIVER_CMD_KEY}", self.prefix)
    }

    /// `<prefix>/<axis>/<pattern>`: the fields a pattern such as `D*` names (see
    /// `chunk_pattern`).
    pub fn field_pattern(&self, axis: &str, pattern: &str) -> String {
        format!("{}/{axis}/{}", self.prefix, chunk_pattern(pattern))
    }

    /// `<prefix>/@controller/<name>/reload`: a put here re-reads a script controller's script
    /// (motorScriptMotor's `ScriptMotorReload`).
    pub fn controller_reload(&self, controller: &str) -> String {
        format!("{}/@controller/{controller}/reload", self.prefix)
    }

    /// `<prefix>/@controller/*/reload`: every controller's reload key.
    pub fn every_controller_reload(&self) -> String {
        self.controller_reload("*")
    }

    /// `<prefix>/<axis>/@hold/<client>`: the liveliness token a client holds a motion by.
    pub fn hold(&self, axis: &str, client: &str) -> String {
        format!("{}/{axis}/@hold/{client}", self.prefix)
    }

    /// `<prefix>/<axis>/@write/<FIELD>`: where a confirmed write goes when access control must tell
    /// it from a read (Zenoh's rules see a `get` either way; `**` does not cover an `@` chunk).
    pub fn write(&self, axis: &str, field: Field) -> String {
        format!("{}/{axis}/{WRITE_CHUNK}/{}", self.prefix, field.name())
    }

    /// `<prefix>/*/@write/<FIELD>`: the write keys of one field on every axis.
    pub fn writes_of(&self, field: Field) -> String {
        format!("{}/*/{WRITE_CHUNK}/{}", self.prefix, field.name())
    }

    /// `<prefix>/*/@write/*`: every write key (a node answers confirmed writes here).
    pub fn every_write(&self) -> String {
        format!("{}/*/{WRITE_CHUNK}/*", self.prefix)
    }

    /// `<prefix>/*/<FIELD>`: one field's key on every axis.
    pub fn field_of_every_axis(&self, field: Field) -> String {
        format!("{}/*/{}", self.prefix, field.name())
    }

    /// `<prefix>/*/@hold/*`: every hold token.
    pub fn every_hold(&self) -> String {
        self.hold("*", "*")
    }

    /// The field name of `<prefix>/<axis>/@write/<FIELD>` for this axis, if the key has that shape.
    pub fn written_field_name<'k>(&self, axis: &str, key: &'k str) -> Option<&'k str> {
        let rest = key.strip_prefix(self.prefix.as_str())?.strip_prefix('/')?;
        let rest = rest.strip_prefix(axis)?.strip_prefix('/')?.strip_prefix(WRITE_CHUNK)?.strip_prefix('/')?;
        (!rest.is_empty() && !rest.contains('/')).then_some(rest)
    }

    /// `<prefix>/<axis>/@write/<FIELD>`, with `?wait` for a put-with-completion: what a
    /// client that may meet access control writes to (an open node serves it too).
    pub fn write_selector(&self, axis: &str, field: Field, wait: bool) -> String {
        let key = self.write(axis, field);
        if wait {
            format!("{key}?{WAIT_PARAMETER}")
        } else {
            key
        }
    }

    /// The axis chunk of a key under this prefix (`m1` in `motor/m1/VAL`); it may be a wildcard.
    pub fn axis_chunk<'k>(&self, key: &'k str) -> Option<&'k str> {
        key.strip_prefix(self.prefix.as_str())?.strip_prefix('/')?.split('/').next()
    }

    /// Check a link's key before it is wired: one plain key; when it names a motor field under
    /// this prefix, a field that exists, writable when the link writes to it (`writes`), and not
    /// a field of the axis that owns the link (`owner`).
    pub fn check_link(&self, key: &str, writes: bool, owner: Option<&str>) -> Result<(), LinkKeyError> {
        validate_plain_key(key)?;
        let Some(axis) = self.axis_chunk(key) else { return Ok(()) };
        let Some(name) = key.strip_prefix(self.prefix.as_str()).and_then(|r| r[1..].split_once('/')).map(|(_, n)| n)
        else {
            return Ok(());
        };
        let field = Field::from_name(name)
            .ok_or_else(|| LinkKeyError::UnknownField { key: key.to_string(), name: name.to_string() })?;
        if writes && field.def().access == crate::Access::RO {
            return Err(LinkKeyError::ReadOnly { key: key.to_string(), field });
        }
        if owner == Some(axis) {
            return Err(LinkKeyError::ToItself { key: key.to_string(), axis: axis.to_string(), field });
        }
        Ok(())
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

/// The axis chunk of a simulator key (`m1` in `sim/m1/position`); it may be a wildcard.
pub fn sim_axis_chunk(key: &str) -> Option<&str> {
    key.strip_prefix(SIM_PREFIX)?.strip_prefix('/')?.split('/').next()
}

/// Why a link's text is not a plain key (one key, no wildcards), as every link must be.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("'{key}' is not a plain key: {reason}")]
#[non_exhaustive]
pub struct PlainKeyError {
    /// The text given.
    pub key: String,
    /// What is wrong with it.
    pub reason: &'static str,
}

/// A link must name one key: chunks separated by single `/`, none empty, with none of the
/// characters Zenoh gives a meaning in key expressions (`*`, `$`, `?`, `#`).
pub fn validate_plain_key(key: &str) -> Result<(), PlainKeyError> {
    let refuse = |reason| Err(PlainKeyError { key: key.to_string(), reason });
    if key.is_empty() {
        return refuse("it is empty");
    }
    if key.contains(['*', '$']) {
        return refuse("wildcards select many keys");
    }
    if key.contains(['?', '#']) {
        return refuse("'?' and '#' cannot stand in a key");
    }
    if key.split('/').any(str::is_empty) {
        return refuse("it has an empty chunk (a leading, trailing or doubled '/')");
    }
    if key.chars().any(char::is_whitespace) {
        return refuse("it holds white space");
    }
    if key.contains('"') {
        // A key quoted as JSON text is written bare: quoted, it would name a key nobody uses.
        return refuse("quotes are no part of a key (write it bare)");
    }
    Ok(())
}

/// Why a link cannot be wired to its key.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum LinkKeyError {
    /// The text is not one plain key.
    #[error(transparent)]
    NotPlain(#[from] PlainKeyError),
    /// The key names a motor field that does not exist.
    #[error("{key}: '{name}' is not a field of a motor")]
    UnknownField {
        /// The link's key.
        key: String,
        /// The field name it holds.
        name: String,
    },
    /// An output link would write a read-only field.
    #[error("{key}: {field} is read-only")]
    ReadOnly {
        /// The link's key.
        key: String,
        /// The field it names.
        field: Field,
    },
    /// The link names a field of the axis that owns it: a loop.
    #[error("{key}: axis '{axis}' would link to its own {field}, a loop")]
    ToItself {
        /// The link's key.
        key: String,
        /// The axis.
        axis: String,
        /// The field of its own the link names.
        field: Field,
    },
}

/// Why a name cannot be an axis's key chunk.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum AxisNameError {
    /// The name is empty.
    #[error("an axis name must not be empty")]
    Empty,
    /// The name holds a character a plain key chunk cannot.
    #[error("axis name '{name}' contains '{character}', which cannot stand in a key chunk")]
    Forbidden {
        /// The name given.
        name: String,
        /// The first character at fault.
        character: char,
    },
    /// The name is longer than [`AXIS_NAME_MAX`] bytes.
    #[error("axis name '{start}...' is {length} bytes long; at most {AXIS_NAME_MAX} (its state is kept in a file named after it)")]
    TooLong {
        /// The name's first 40 characters.
        start: String,
        /// Its length in bytes.
        length: usize,
    },
}

/// The longest axis name, in bytes: the node keeps an axis's state in a file named after it,
/// and a file's name may hold 255.
pub const AXIS_NAME_MAX: usize = 200;

/// An axis name must be a single, plain key chunk.
pub fn validate_axis_name(name: &str) -> Result<(), AxisNameError> {
    check_chunk(name, false)
}

/// An axis pattern, as a reader or a monitor takes it (`m*`, `*`): an axis name in which `*`
/// stands for any characters (see `chunk_pattern`).
pub fn validate_axis_pattern(pattern: &str) -> Result<(), AxisNameError> {
    check_chunk(pattern, true)
}

fn check_chunk(name: &str, stars: bool) -> Result<(), AxisNameError> {
    if name.is_empty() {
        return Err(AxisNameError::Empty);
    }
    if name.len() > AXIS_NAME_MAX {
        return Err(AxisNameError::TooLong { start: name.chars().take(40).collect(), length: name.len() });
    }
    let forbidden = |c: &char| matches!(c, '/' | '$' | '?' | '#' | '@') || (*c == '*' && !stars) || c.is_whitespace();
    if let Some(c) = name.chars().find(forbidden) {
        return Err(AxisNameError::Forbidden { name: name.to_string(), character: c });
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
        assert_eq!(k.field_pattern("m1", "D*"), "motor/m1/D$*");
        assert_eq!(k.field_pattern("m1", "**"), "motor/m1/**");
        assert_eq!(k.write_selector("m1", Field::VAL, true), "motor/m1/@write/VAL?wait");
        assert_eq!(
            (k.axis_chunk("motor/m1/VAL"), k.axis_chunk("motor/*/VAL"), k.axis_chunk("sim/m1/x")),
            (Some("m1"), Some("*"), None)
        );
        assert_eq!(sim_axis_chunk("sim/m1/position"), Some("m1"));
        assert_eq!(k.write("m1", Field::VAL), "motor/m1/@write/VAL");
        assert_eq!(
            (k.writes_of(Field::HLM), k.every_write()),
            ("motor/*/@write/HLM".into(), "motor/*/@write/*".into())
        );
        assert_eq!(
            (k.field_of_every_axis(Field::VAL), k.every_hold()),
            ("motor/*/VAL".into(), "motor/*/@hold/*".into())
        );
    }

    #[test]
    fn written_field_names_are_parsed_from_write_keys_only() {
        let k = KeyLayout::default();
        assert_eq!(k.written_field_name("m1", "motor/m1/@write/VAL"), Some("VAL"));
        assert_eq!(k.written_field_name("m1", "motor/m1/VAL"), None);
        assert_eq!(k.written_field_name("m1", "motor/m10/@write/VAL"), None);
        assert_eq!(k.written_field_name("m1", "motor/m1/@write/"), None);
        assert_eq!(k.written_field_name("m1", "motor/m1/@write/VAL/x"), None);
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
    fn links_are_checked_against_the_catalogue_and_their_owner() {
        let k = KeyLayout::default();
        assert!(k.check_link("motor/lin/DVAL", true, Some("rot")).is_ok());
        assert!(k.check_link("bridge/calc/A", true, None).is_ok(), "not a motor key: any plain key");
        assert_eq!(
            k.check_link("motor/lin/RBV", true, None).unwrap_err().to_string(),
            "motor/lin/RBV: RBV is read-only"
        );
        assert!(k.check_link("motor/lin/RBV", false, None).is_ok(), "reading a read-only field is fine");
        assert_eq!(
            k.check_link("motor/lin/DRBX", false, None).unwrap_err().to_string(),
            "motor/lin/DRBX: 'DRBX' is not a field of a motor"
        );
        assert!(matches!(k.check_link("motor/m1/VAL", false, Some("m1")), Err(LinkKeyError::ToItself { .. })));
        assert!(matches!(k.check_link("a//b", false, None), Err(LinkKeyError::NotPlain(_))));
    }

    #[test]
    fn plain_keys_are_checked() {
        assert!(validate_plain_key("motor/lin/DVAL").is_ok());
        for bad in ["", "a//b", "x/*y", "/a", "a/", "a/$*", "a?b", "a#", "a b", "\"motor/m2/VAL\""] {
            assert!(validate_plain_key(bad).is_err(), "{bad}");
        }
        assert_eq!(
            validate_plain_key("a//b").unwrap_err().to_string(),
            "'a//b' is not a plain key: it has an empty chunk (a leading, trailing or doubled '/')"
        );
    }

    #[test]
    fn axis_names_are_checked() {
        assert!(validate_axis_name("m1").is_ok());
        assert!(validate_axis_name("a/b").is_err());
        assert!(validate_axis_name("").is_err());
        assert!(validate_axis_name("x*").is_err());
        assert!(validate_axis_name(&"a".repeat(AXIS_NAME_MAX)).is_ok());
        assert_eq!(
            validate_axis_name(&"a".repeat(AXIS_NAME_MAX + 1)).unwrap_err().to_string(),
            format!(
                "axis name '{}...' is 201 bytes long; at most 200 (its state is kept in a file named after it)",
                "a".repeat(40)
            )
        );
        assert!(validate_axis_pattern("x*").is_ok() && validate_axis_pattern("*").is_ok());
        assert_eq!(
            validate_axis_pattern("m?").unwrap_err().to_string(),
            "axis name 'm?' contains '?', which cannot stand in a key chunk"
        );
    }

    #[test]
    fn a_pattern_as_typed_becomes_a_key_chunk() {
        for (typed, chunk) in [("*", "*"), ("**", "**"), ("m*", "m$*"), ("*1", "$*1"), ("m**2", "m$*2"), ("m1", "m1")] {
            assert_eq!(chunk_pattern(typed), chunk, "{typed}");
        }
    }

    #[test]
    fn bridge_records_are_told_by_their_tokens_and_value_keys() {
        assert_eq!(BridgeRecord::Value.token("armLength"), "bridge/armLength/ao");
        assert_eq!(BridgeRecord::Calc.token("readback"), "bridge/readback/calc");
        assert_eq!(BridgeRecord::of_token("bridge/armLength/ao"), Some(("armLength", BridgeRecord::Value)));
        assert_eq!(BridgeRecord::of_token("bridge/readback/calc"), Some(("readback", BridgeRecord::Calc)));
        assert_eq!(BridgeRecord::of_token("bridge/readback/bo"), None);
        assert_eq!(BridgeRecord::of_token("motor/m1/ao"), None);
        assert_eq!(BridgeRecord::of_token("bridge/a/b/ao"), None);
        assert_eq!(BridgeRecord::value_key("armLength"), "bridge/armLength/VAL");
        assert_eq!(BridgeRecord::of_value_key("bridge/armLength/VAL"), Some("armLength"));
        assert_eq!(BridgeRecord::of_value_key("bridge/armLength/A"), None);
        assert_eq!(BridgeRecord::of_value_key("bridge/a/b/VAL"), None);
        assert_eq!(BridgeRecord::of_value_key("lab/offset"), None);
    }
}
