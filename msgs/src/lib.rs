//! zmotor-msgs: what travels on the wire and what every other crate agrees on: the field
//! catalogue (the single source of truth, like motorRecord.dbd), values and menus, status bits,
//! CBOR/JSON/text codecs, the key layout, refusals and JSON schemas.
//!
//! Types and functions are named at the root. Three modules stay public because they are
//! namespaces of the wire's vocabulary rather than code: `bits` (MSTA and MIP bits, as
//! `msta::DONE`), `menus` (menu choices, as `choice::SPMG_GO`) and `keys` (the key layout's
//! rules and constants).

pub mod bits;
mod catalogue;
mod codec;
pub mod keys;
pub mod menus;
mod refusal;
mod schema;
mod toml_value;
mod units;
mod value;
mod wire;

pub use catalogue::{
    past_deadband, unmodelled_common_field, Access, Autosave, CommonField, Field, FieldDef, Fields, Kind, WriteClass,
    FIELDS, UNMODELLED_COMMON_FIELDS,
};
pub use codec::{
    decode_cbor_value, decode_scalar, decode_write, encode_cbor, excerpt, validate, CodecError, MalformedPayload,
    PayloadEncoding,
};
pub use keys::{BridgeRecord, KeyLayout, LinkKeyError};
pub use refusal::{Refusal, RefusalKind};
pub use schema::{catalogue_json, message_schemas};
pub use toml_value::{field_value, to_toml};
pub use units::{Dimension, Unit};
pub use value::Value;
pub use wire::{
    Attached, Completion, DriverCommand, DriverTrace, Gain, Hold, MalformedHold, Readback, SimState, StateMarker,
};
