//! The attocube AMC100 (being written).

/// The attocube AMC100, emulated.
#[derive(Debug)]
pub struct AmcEmulator;
