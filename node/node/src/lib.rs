//! zmotor-zenoh: serves zmotor's sans-IO axes on a Zenoh session. It only moves bytes: samples
//! and queries become calls of each axis's `AxisService` (zmotor-core), the wall clock becomes
//! ticks, and what the services hand back becomes publications, replies and puts. Calc links
//! (zmotor-bridge) and value holders run beside the axes; autosave keeps each axis's state in a
//! file.

pub mod autosave;
pub mod channel_access;
pub mod client;
pub mod config;
mod controllers;
mod holds;
mod links;
mod node;
pub mod summary;
mod timer;

pub use config::{free_local_endpoint, AccessRule, ConfigError, LoginConfig, Mode, Permission, TlsConfig, ZenohConfig};
pub use links::ValueSpec;
pub use node::{AutosaveConfig, Node, NodeContents, NodeError};
