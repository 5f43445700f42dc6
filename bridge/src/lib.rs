//! zmotor-bridge: soft-channel wiring between keys, beside the engine on top of `msgs`.
//! `calc` is the EPICS calc expression language; `link` the calcout-like links between keys.
//! Both are sans-IO: the node's Zenoh adapter runs them.

pub mod calc;
pub mod link;

pub use calc::{CalcError, Expression};
pub use link::{CalcLink, CalcLinkSpec, InputMode, InputSpec, LinkError, OutputOption};
