//! JSON Schemas of every message type, generated from the Rust types, and the field catalogue
//! as a JSON document (both written by `zmotor schema DIR`).

use crate::catalogue::{Kind, FIELDS};
use crate::value::Value;
use crate::wire::{Completion, DriverTrace, Hold, Readback, SimState, StateMarker};

/// (file name, schema) for every message type on the wire.
pub fn message_schemas() -> Vec<(&'static str, serde_json::Value)> {
    fn json<T: schemars::JsonSchema>() -> serde_json::Value {
        serde_json::to_value(schemars::schema_for!(T)).expect("schemas serialize")
    }
    vec![
        ("field-value.schema.json", json::<Value>()),
        ("state-marker.schema.json", json::<StateMarker>()),
        ("hold.schema.json", json::<Hold>()),
        ("driver-command.schema.json", json::<DriverTrace>()),
        ("sim-state.schema.json", json::<SimState>()),
        ("completion.schema.json", json::<Completion>()),
        ("readback.schema.json", json::<Readback>()),
    ]
}

/// The catalogue as JSON: name, type, default, menu choices, access, prompt, unit of each field.
pub fn catalogue_json() -> serde_json::Value {
    let fields: Vec<serde_json::Value> = FIELDS
        .iter()
        .map(|d| {
            let mut entry = serde_json::json!({
                "name": d.name,
                "type": d.kind.type_name(),
                "default": d.default_value(),
                "access": d.access.label(),
                "prompt": d.prompt,
                "unit": d.unit,
            });
            match d.kind {
                Kind::Menu(menu) => {
                    entry["menu"] = menu.name.into();
                    entry["choices"] = menu.choices.into();
                }
                Kind::Str(max) => entry["max_length"] = (max - 1).into(),
                _ => {}
            }
            entry
        })
        .collect();
    let refusals: Vec<&str> = crate::refusal::RefusalKind::ALL.iter().map(|k| k.name()).collect();
    serde_json::json!({
        "fields": fields,
        "msta_bits": crate::bits::MSTA_BITS,
        "mip_bits": crate::bits::MIP_BITS,
        "refusal_kinds": refusals,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schemas_describe_the_wire_types() {
        let schemas = message_schemas();
        let trace = &schemas.iter().find(|(n, _)| *n == "driver-command.schema.json").unwrap().1;
        let text = trace.to_string();
        assert!(text.contains("move_velocity") && text.contains("set_position"), "{text}");
        let catalogue = catalogue_json();
        let spmg = catalogue["fields"].as_array().unwrap().iter().find(|f| f["name"] == "SPMG").unwrap();
        assert_eq!(spmg["choices"][3], "Go");
        assert_eq!(spmg["access"], "R/W*");
        assert_eq!(spmg["default"], 3);
    }
}

#[cfg(test)]
mod shipped {
    /// The schemas shipped in `schemas/` are exactly what the types generate
    /// (regenerate with `zmotor schema schemas`).
    #[test]
    fn shipped_schemas_are_up_to_date() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../schemas");
        let mut expected = super::message_schemas();
        expected.push(("fields.json", super::catalogue_json()));
        for (name, schema) in expected {
            let shipped = std::fs::read_to_string(dir.join(name)).unwrap_or_else(|e| panic!("schemas/{name}: {e}"));
            let shipped: serde_json::Value = serde_json::from_str(&shipped).unwrap();
            assert_eq!(shipped, schema, "schemas/{name} is stale: run `zmotor schema schemas`");
        }
    }
}
