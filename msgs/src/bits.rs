//! Bit layouts: MSTA (motor status word, from the driver) and MIP (motion in progress).

use serde::Serialize;

/// One documented bit of a status word.
#[derive(Debug, Serialize)]
pub struct BitDef {
    /// The bit's mask within the word.
    pub mask: u32,
    /// The bit's name as the motor record's sources spell it (e.g. `RA_DONE`).
    pub name: &'static str,
    /// What the bit means when set.
    pub meaning: &'static str,
}

/// MSTA bits (bit 0 = least significant), as the asyn motor drivers build the word.
pub mod msta {
    /// `RA_DIRECTION`: last raw direction of travel (1 = positive).
    pub const DIRECTION: u32 = 1 << 0;
    /// `RA_DONE`: motion is complete.
    pub const DONE: u32 = 1 << 1;
    /// `RA_PLUS_LS`: plus (raw positive) limit switch active.
    pub const PLUS_LS: u32 = 1 << 2;
    /// `RA_HOME`: home switch active.
    pub const HOME: u32 = 1 << 3;
    /// `EA_SLIP`: encoder slip detection enabled.
    pub const SLIP: u32 = 1 << 4;
    /// `EA_POSITION`: position maintenance (closed loop) enabled.
    pub const POSITION: u32 = 1 << 5;
    /// `EA_SLIP_STALL`: slip or stall detected (following error).
    pub const SLIP_STALL: u32 = 1 << 6;
    /// `EA_HOME`: encoder home signal active.
    pub const ENCODER_HOME: u32 = 1 << 7;
    /// `EA_PRESENT`: an encoder is present.
    pub const PRESENT: u32 = 1 << 8;
    /// `RA_PROBLEM`: driver or hardware problem.
    pub const PROBLEM: u32 = 1 << 9;
    /// `RA_MOVING`: non-zero velocity present.
    pub const MOVING: u32 = 1 << 10;
    /// `GAIN_SUPPORT`: closed-loop position control supported.
    pub const GAIN_SUPPORT: u32 = 1 << 11;
    /// `CNTRL_COMM_ERR`: controller communication error.
    pub const COMM_ERR: u32 = 1 << 12;
    /// `RA_MINUS_LS`: minus (raw negative) limit switch active.
    pub const MINUS_LS: u32 = 1 << 13;
    /// `RA_HOMED`: the axis has been homed.
    pub const HOMED: u32 = 1 << 14;
}

/// Every MSTA bit with its name and meaning (documentation and the catalogue JSON).
pub const MSTA_BITS: &[BitDef] = &[
    BitDef { mask: msta::DIRECTION, name: "RA_DIRECTION", meaning: "last raw direction of travel (1 = positive)" },
    BitDef { mask: msta::DONE, name: "RA_DONE", meaning: "motion is complete" },
    BitDef { mask: msta::PLUS_LS, name: "RA_PLUS_LS", meaning: "plus (raw positive) limit switch active" },
    BitDef { mask: msta::HOME, name: "RA_HOME", meaning: "home switch active" },
    BitDef { mask: msta::SLIP, name: "EA_SLIP", meaning: "encoder slip detection enabled" },
    BitDef { mask: msta::POSITION, name: "EA_POSITION", meaning: "position maintenance (closed loop) enabled" },
    BitDef { mask: msta::SLIP_STALL, name: "EA_SLIP_STALL", meaning: "slip or stall detected (following error)" },
    BitDef { mask: msta::ENCODER_HOME, name: "EA_HOME", meaning: "encoder home signal active" },
    BitDef { mask: msta::PRESENT, name: "EA_PRESENT", meaning: "an encoder is present" },
    BitDef { mask: msta::PROBLEM, name: "RA_PROBLEM", meaning: "driver or hardware problem" },
    BitDef { mask: msta::MOVING, name: "RA_MOVING", meaning: "non-zero velocity present" },
    BitDef { mask: msta::GAIN_SUPPORT, name: "GAIN_SUPPORT", meaning: "closed-loop position control supported" },
    BitDef { mask: msta::COMM_ERR, name: "CNTRL_COMM_ERR", meaning: "controller communication error" },
    BitDef { mask: msta::MINUS_LS, name: "RA_MINUS_LS", meaning: "minus (raw negative) limit switch active" },
    BitDef { mask: msta::HOMED, name: "RA_HOMED", meaning: "the axis has been homed" },
];

/// MIP bits: which phase of a motion sequence is in progress.
pub mod mip {
    /// No bit set: no motion in progress.
    pub const DONE: u16 = 0x0000;
    /// Jogging forward.
    pub const JOGF: u16 = 0x0001;
    /// Jogging reverse.
    pub const JOGR: u16 = 0x0002;
    /// After a jog: first backlash leg.
    pub const JOG_BL1: u16 = 0x0004;
    /// Homing forward.
    pub const HOMF: u16 = 0x0008;
    /// Homing reverse.
    pub const HOMR: u16 = 0x0010;
    /// A move (also set on retries).
    pub const MOVE: u16 = 0x0020;
    /// A retry is pending or in progress.
    pub const RETRY: u16 = 0x0040;
    /// Set-position in progress.
    pub const LOAD_P: u16 = 0x0080;
    /// Final backlash leg of a move.
    pub const MOVE_BL: u16 = 0x0100;
    /// Stop sent, waiting for the motor to stop.
    pub const STOP: u16 = 0x0200;
    /// Settling delay (DLY) running.
    pub const DELAY_REQ: u16 = 0x0400;
    /// Settling delay expired.
    pub const DELAY_ACK: u16 = 0x0800;
    /// Jog requested, not started.
    pub const JOG_REQ: u16 = 0x1000;
    /// Jog released, waiting for the stop.
    pub const JOG_STOP: u16 = 0x2000;
    /// After a jog: final backlash leg.
    pub const JOG_BL2: u16 = 0x4000;
    /// Motion the record did not command.
    pub const EXTERNAL: u16 = 0x8000;

    /// Every jog phase: jogging forward or reverse, or either backlash leg after a jog.
    pub const JOG_GROUP: u16 = JOGF | JOGR | JOG_BL1 | JOG_BL2;
    /// Homing in either direction.
    pub const HOME_GROUP: u16 = HOMF | HOMR;
    /// The settling delay (DLY), running or expired.
    pub const DELAY_GROUP: u16 = DELAY_REQ | DELAY_ACK;
}

/// Every MIP bit with its name and meaning (documentation and the catalogue JSON).
pub const MIP_BITS: &[BitDef] = &[
    BitDef { mask: mip::JOGF as u32, name: "JOGF", meaning: "jogging forward" },
    BitDef { mask: mip::JOGR as u32, name: "JOGR", meaning: "jogging reverse" },
    BitDef { mask: mip::JOG_BL1 as u32, name: "JOG_BL1", meaning: "after a jog: first backlash leg" },
    BitDef { mask: mip::HOMF as u32, name: "HOMF", meaning: "homing forward" },
    BitDef { mask: mip::HOMR as u32, name: "HOMR", meaning: "homing reverse" },
    BitDef { mask: mip::MOVE as u32, name: "MOVE", meaning: "a move (also set on retries)" },
    BitDef { mask: mip::RETRY as u32, name: "RETRY", meaning: "a retry is pending or in progress" },
    BitDef { mask: mip::LOAD_P as u32, name: "LOAD_P", meaning: "set-position in progress" },
    BitDef { mask: mip::MOVE_BL as u32, name: "MOVE_BL", meaning: "final backlash leg of a move" },
    BitDef { mask: mip::STOP as u32, name: "STOP", meaning: "stop sent, waiting for the motor to stop" },
    BitDef { mask: mip::DELAY_REQ as u32, name: "DELAY_REQ", meaning: "settling delay (DLY) running" },
    BitDef { mask: mip::DELAY_ACK as u32, name: "DELAY_ACK", meaning: "settling delay expired" },
    BitDef { mask: mip::JOG_REQ as u32, name: "JOG_REQ", meaning: "jog requested, not started" },
    BitDef { mask: mip::JOG_STOP as u32, name: "JOG_STOP", meaning: "jog released, waiting for the stop" },
    BitDef { mask: mip::JOG_BL2 as u32, name: "JOG_BL2", meaning: "after a jog: final backlash leg" },
    BitDef { mask: mip::EXTERNAL as u32, name: "EXTERNAL", meaning: "motion the record did not command" },
];
