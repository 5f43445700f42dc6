//! zmotor-node: the motor record engine (sans-IO), device support, drivers, the sans-IO axis
//! that composes them on an injected clock, and the Zenoh adapter around it.

pub mod autosave;
pub mod axis;
pub mod bench;
pub mod device;
pub mod driver;
pub mod engine;
pub mod launch;
pub mod net;
pub mod primitives;
pub mod toml_value;
