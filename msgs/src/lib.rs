//! zmotor-msgs: what travels on the wire and what every other crate agrees on: the field
//! catalogue (the single source of truth, like motorRecord.dbd), values and menus, status bits,
//! CBOR/JSON/text codecs, the key layout and JSON schemas.

pub mod bits;
pub mod catalogue;
pub mod codec;
pub mod keys;
pub mod menus;
pub mod refusal;
pub mod schema;
pub mod toml_value;
pub mod value;
pub mod wire;

pub use catalogue::{Access, Autosave, Field, FieldDef, Fields, Kind, WriteClass, FIELDS, UNMODELLED_COMMON_FIELDS};
pub use codec::{decode_scalar, decode_write, encode_cbor, validate, CodecError, MalformedPayload, PayloadEncoding};
pub use keys::{KeyLayout, LinkKeyError};
pub use refusal::{Refusal, RefusalKind};
pub use value::Value;
pub use wire::{Completion, DriverCommand, DriverTrace, Gain, Hold, SimState, StateMarker};
