//! Field values and the storage types behind them.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// The value of one field as it travels on the wire: integer fields (LONG, SHORT, menus, ...) as
/// integers, DOUBLE/FLOAT as floats, strings and links as text.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum Value {
    /// An integer: LONG, ULONG, SHORT, USHORT and menu (choice index) fields.
    Int(i64),
    /// A floating-point number: DOUBLE and FLOAT fields.
    Float(f64),
    /// Text: STRING and link fields.
    Text(String),
}

impl Value {
    /// Numeric view (integers widen to f64); None for text.
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Value::Int(i) => Some(*i as f64),
            Value::Float(f) => Some(*f),
            Value::Text(_) => None,
        }
    }
}

impl std::fmt::Display for Value {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Value::Int(i) => write!(f, "{i}"),
            Value::Float(x) => write!(f, "{x}"),
            Value::Text(s) => write!(f, "{s}"),
        }
    }
}

/// A Rust storage type of a field; conversions are exact because the codec has already
/// validated the value against the field's kind and range.
pub(crate) trait FieldStorage: Sized {
    /// The stored value as it travels on the wire.
    fn to_value(&self) -> Value;
    /// The storage form of a value already validated for the field.
    fn from_value(value: &Value) -> Self;
}

macro_rules! int_storage {
    ($($t:ty),*) => {$(
        impl FieldStorage for $t {
            fn to_value(&self) -> Value {
                Value::Int(i64::from(*self))
            }
            fn from_value(value: &Value) -> Self {
                match value {
                    Value::Int(i) => *i as $t,
                    Value::Float(f) => *f as $t,
                    Value::Text(_) => 0,
                }
            }
        }
    )*};
}
int_storage!(u8, i16, u16, i32, u32);

impl FieldStorage for f64 {
    fn to_value(&self) -> Value {
        Value::Float(*self)
    }
    fn from_value(value: &Value) -> Self {
        value.as_f64().unwrap_or(0.0)
    }
}

impl FieldStorage for f32 {
    fn to_value(&self) -> Value {
        Value::Float(f64::from(*self))
    }
    fn from_value(value: &Value) -> Self {
        value.as_f64().unwrap_or(0.0) as f32
    }
}

impl FieldStorage for String {
    fn to_value(&self) -> Value {
        Value::Text(self.clone())
    }
    fn from_value(value: &Value) -> Self {
        match value {
            Value::Text(s) => s.clone(),
            other => other.to_string(),
        }
    }
}
