//! zmotor-node: the motor record engine, device support and drivers, and the Zenoh adapter.

pub mod engine;
