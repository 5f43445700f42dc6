//! Field values in TOML, as launch files and state files hold them: one conversion each way.

use crate::codec::{validate, CodecError};
use crate::{Field, Value};

/// A field value as TOML.
pub fn to_toml(value: Value) -> toml::Value {
    match value {
        Value::Int(i) => toml::Value::Integer(i),
        Value::Float(x) => toml::Value::Float(x),
        Value::Text(t) => toml::Value::String(t),
    }
}

/// A TOML value as the value of `field`, validated like a write (a boolean is 0 or 1 to a field
/// that takes a flag, and the wrong type to a position, a speed or a longer menu).
pub fn field_value(field: Field, raw: &toml::Value) -> Result<Value, CodecError> {
    let def = field.def();
    let value = match raw {
        toml::Value::Integer(i) => Value::Int(*i),
        toml::Value::Float(x) => Value::Float(*x),
        toml::Value::String(s) => Value::Text(s.clone()),
        toml::Value::Boolean(b) if def.kind.takes_a_flag() => Value::Int(i64::from(*b)),
        toml::Value::Boolean(b) => {
            return Err(CodecError::WrongType {
                field: field.name(),
                expected: def.kind.expected().into(),
                got: format!("a boolean ({b})"),
            })
        }
        other => {
            return Err(CodecError::WrongType {
                field: field.name(),
                expected: "a number or a string".into(),
                got: other.type_str().into(),
            })
        }
    };
    validate(field.def(), value)
}
