//! The Faulhaber MCDC 3006 / MC 5004 motion controller (ASCII) (being written).

/// The Faulhaber MCDC 3006 / MC 5004 motion controller (ASCII), emulated.
#[derive(Debug)]
pub struct FaulhaberEmulator;
