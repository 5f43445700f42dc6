//! zmotor-bridge: soft-channel wiring between keys. `calc` is the EPICS calc expression
//! language; calc links (calcout-like records over Zenoh keys) build on it.

pub mod calc;

pub use calc::{CalcError, Expression};
