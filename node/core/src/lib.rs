//! zmotor-core: the sans-IO heart of a motion node. The motor record engine, asyn-style device
//! support, the `Driver` trait with the physical simulator, Soft Channel device support, the
//! command primitives, the axis that composes them on an injected clock, and the request
//! semantics of the wire contract (`service`). Events go in (a write, a link update, the time),
//! actions come out (posts, driver commands, puts, replies); nothing here performs I/O or reads
//! a clock, and the crate's dependencies make that a compile error.

pub mod axis;
pub mod device;
pub mod driver;
pub mod engine;
pub mod primitives;
pub mod service;
pub mod time;

pub use time::Instant;
