//! Field values in TOML, as launch files and state files hold them: one conversion each way.

use zmotor_msgs::{Field, Value};

pub fn to_toml(value: Value) -> toml::Value {
    match value {
        Value::Int(i) => toml::Value::Integer(i),
        Value::Float(x) => toml::Value::Float(x),
        Value::Text(t) => toml::Value::String(t),
    }
}

/// A TOML value as the value of `field`, validated like a write (a boolean is 0 or 1).
pub fn field_value(field: Field, raw: &toml::Value) -> Result<Value, String> {
    let value = match raw {
        toml::Value::Integer(i) => Value::Int(*i),
        toml::Value::Float(x) => Value::Float(*x),
        toml::Value::String(s) => Value::Text(s.clone()),
        toml::Value::Boolean(b) => Value::Int(i64::from(*b)),
        other => return Err(format!("{field}: a number or a string is required, got {}", other.type_str())),
    };
    zmotor_msgs::validate(field.def(), value).map_err(|e| e.to_string())
}
