//! The node's own key space as a script reaches it (`epics.get`/`epics.put`): what the script
//! driver asks on `Lane::Keys`, and what the runner answers. The layer keeps the exchange as any
//! other (one in flight, its timeout); the runner does the Zenoh get or confirmed write.

/// A name a script gives `epics.get`/`epics.put`, as a key.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum KeyName {
    /// `axis.FIELD` (or `axis`, its VAL), as EPICS names a record's field: the field's key
    /// under the node's prefix.
    Field {
        /// The axis (or value holder).
        record: String,
        /// The field, as the catalogue names it.
        field: String,
    },
    /// A name with a `/`: the key itself.
    Key(String),
}

/// A name that is no key.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("'{name}' is not a key: give axis.FIELD (as a PV's record.FIELD), axis (its VAL) or a key with '/' (motor/m1/RBV), without spaces or wildcards")]
pub struct KeyNameError {
    /// The name given.
    pub name: String,
}

impl KeyName {
    /// `name` as a key name.
    pub fn parse(name: &str) -> Result<Self, KeyNameError> {
        let refused = || KeyNameError { name: name.to_string() };
        let forbidden = |c: char| c.is_whitespace() || c.is_control() || matches!(c, '*' | '$' | '?' | '#');
        if name.is_empty() || name.contains(forbidden) {
            return Err(refused());
        }
        if name.contains('/') {
            let parts_empty = name.split('/').any(str::is_empty);
            return if parts_empty { Err(refused()) } else { Ok(KeyName::Key(name.to_string())) };
        }
        let (record, field) = name.split_once('.').unwrap_or((name, "VAL"));
        if record.is_empty() || field.is_empty() || field.contains('.') {
            return Err(refused());
        }
        Ok(KeyName::Field { record: record.to_string(), field: field.to_string() })
    }

    /// The key under `prefix` (the node's, `motor`).
    pub fn key(&self, prefix: &str) -> String {
        match self {
            KeyName::Field { record, field } => format!("{prefix}/{record}/{field}"),
            KeyName::Key(key) => key.clone(),
        }
    }

    fn text(&self) -> String {
        match self {
            KeyName::Field { record, field } => format!("{record}.{field}"),
            KeyName::Key(key) => key.clone(),
        }
    }
}

/// A script's access to a key: the bytes of a `Lane::Keys` request.
#[derive(Clone, Debug, PartialEq)]
pub enum KeyAccess {
    /// Read the key's current value.
    Get(KeyName),
    /// Write `value` to the key, confirmed by whoever serves it.
    Put(KeyName, KeyValue),
}

impl KeyAccess {
    /// As a request's bytes.
    pub fn encode(&self) -> Vec<u8> {
        match self {
            KeyAccess::Get(name) => format!("get {}", name.text()).into_bytes(),
            KeyAccess::Put(name, value) => {
                let mut bytes = format!("put {} ", name.text()).into_bytes();
                bytes.extend(value.encode());
                bytes
            }
        }
    }

    /// A request's bytes as an access (None: not one).
    pub fn decode(bytes: &[u8]) -> Option<Self> {
        let text = std::str::from_utf8(bytes).ok()?;
        let (verb, rest) = text.split_once(' ')?;
        match verb {
            "get" => Some(KeyAccess::Get(KeyName::parse(rest).ok()?)),
            "put" => {
                let (name, value) = rest.split_once(' ')?;
                Some(KeyAccess::Put(KeyName::parse(name).ok()?, KeyValue::decode(value.as_bytes())?))
            }
            _ => None,
        }
    }
}

/// A key's value, as a script sees it: a number or a string.
#[derive(Clone, Debug, PartialEq)]
pub enum KeyValue {
    /// A number (a Lua number).
    Number(f64),
    /// Text (a Lua string).
    Text(String),
}

impl KeyValue {
    fn encode(&self) -> Vec<u8> {
        match self {
            KeyValue::Number(n) => format!("n{n}").into_bytes(),
            KeyValue::Text(text) => format!("s{text}").into_bytes(),
        }
    }

    fn decode(bytes: &[u8]) -> Option<Self> {
        let text = std::str::from_utf8(bytes).ok()?;
        match text.split_at_checked(1)? {
            ("n", n) => n.parse().ok().map(KeyValue::Number),
            ("s", s) => Some(KeyValue::Text(s.to_string())),
            _ => None,
        }
    }
}

/// The runner's answer to a `KeyAccess`: the frame on `Lane::Keys`.
#[derive(Clone, Debug, PartialEq)]
pub enum KeyReply {
    /// The value read, or the write confirmed (its value then the one written).
    Value(KeyValue),
    /// Why not, in words (nobody serves the key, the write was refused, ...).
    Failed(String),
}

impl KeyReply {
    /// As a reply frame.
    pub fn encode(&self) -> Vec<u8> {
        match self {
            KeyReply::Value(value) => value.encode(),
            KeyReply::Failed(why) => format!("!{why}").into_bytes(),
        }
    }

    /// A reply frame as an answer (None: not one).
    pub fn decode(bytes: &[u8]) -> Option<Self> {
        match bytes.split_first()? {
            (b'!', why) => Some(KeyReply::Failed(String::from_utf8_lossy(why).into_owned())),
            _ => KeyValue::decode(bytes).map(KeyReply::Value),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_fields_under_the_prefix_or_keys() {
        let field = |r: &str, f: &str| KeyName::Field { record: r.into(), field: f.into() };
        assert_eq!(KeyName::parse("m1.RBV"), Ok(field("m1", "RBV")));
        assert_eq!(KeyName::parse("m1"), Ok(field("m1", "VAL")));
        assert_eq!(KeyName::parse("m1.RBV").unwrap().key("motor"), "motor/m1/RBV");
        assert_eq!(KeyName::parse("lab/gap/value").unwrap().key("motor"), "lab/gap/value");
        for bad in ["", "m1.", ".RBV", "m1.RBV.X", "a b", "motor/*/RBV", "a//b", "/a", "m1.VAL\n"] {
            assert!(KeyName::parse(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn accesses_and_replies_survive_their_bytes() {
        let name = KeyName::parse("m1.VAL").unwrap();
        for access in [
            KeyAccess::Get(name.clone()),
            KeyAccess::Put(name.clone(), KeyValue::Number(0.1 + 0.2)),
            KeyAccess::Put(name, KeyValue::Text("a text, with spaces".into())),
        ] {
            assert_eq!(KeyAccess::decode(&access.encode()), Some(access));
        }
        for reply in [
            KeyReply::Value(KeyValue::Number(-2.5e-300)),
            KeyReply::Value(KeyValue::Text(String::new())),
            KeyReply::Failed("nobody serves motor/m9/VAL".into()),
        ] {
            assert_eq!(KeyReply::decode(&reply.encode()), Some(reply));
        }
        assert_eq!(KeyReply::decode(b""), None);
        assert_eq!(KeyAccess::decode(b"del m1"), None);
    }
}
