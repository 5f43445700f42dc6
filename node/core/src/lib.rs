//! zmotor-core: the sans-IO heart of a motion node. The motor record engine, asyn-style device
//! support, the `Driver` trait with the physical simulator, Soft Channel device support, the
//! command primitives, the axis that composes them on an injected clock, and the request
//! semantics of the wire contract (`AxisService`). Events go in (a write, a link update, the
//! time), actions come out (posts, driver commands, puts, replies); nothing here performs I/O
//! or reads a clock, and the crate's dependencies make that a compile error.
//!
//! Everything a caller uses is named here, at the root; the modules are the crate's own.

mod axis;
mod device;
mod driver;
mod engine;
mod primitives;
mod service;
mod time;

pub use axis::{
    Axis, AxisEvent, AxisPlan, Completion, DriverPlan, JogHold, PollRates, WriteAccepted, SOFT_DONE_SETTLE,
};
pub use driver::sim::{SimAxis, SimConfig, SimConfigError, SimSetting, SimSettingError};
pub use driver::soft::InputLink;
pub use driver::Driver;
pub use engine::{
    nint, Adjustment, Busy, DeviceStatus, Inaction, LimitSwitch, MotorCommand, MotorRecord, Output, Unusable,
    WriteError,
};
pub use service::{Answer, AxisService, Delivery, Reply, RequestError, ServiceOutput, WriteRequest};
pub use time::Instant;
