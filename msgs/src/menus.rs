//! Menu (enumerated) field types, with the exact choice strings of motorRecord.dbd and EPICS base.

use serde::Serialize;

/// A menu: a named, ordered list of choices; a menu field holds the index of one of them.
#[derive(Debug, PartialEq, Eq, Serialize)]
pub struct Menu {
    /// The menu's name in the DBD (e.g. `motorSPMG`).
    pub name: &'static str,
    /// The choice strings, in index order.
    pub choices: &'static [&'static str],
}

impl Menu {
    /// Index of a choice by name, case-insensitive.
    pub fn index_of(&self, choice: &str) -> Option<u16> {
        let choice = choice.trim();
        self.choices.iter().position(|c| c.eq_ignore_ascii_case(choice)).map(|i| i as u16)
    }

    /// Name of the choice at an index, if the index is in range.
    pub fn choice(&self, index: u16) -> Option<&'static str> {
        self.choices.get(usize::from(index)).copied()
    }
}

/// `motorDIR` (DIR): user coordinates run with the dial (Pos) or against it (Neg).
pub const MOTOR_DIR: Menu = Menu { name: "motorDIR", choices: &["Pos", "Neg"] };
/// `motorSET` (SET): Use, so that a new target moves the motor, or Set, to calibrate (redefine the
/// position without moving).
pub const MOTOR_SET: Menu = Menu { name: "motorSET", choices: &["Use", "Set"] };
/// `motorUEIP` (UEIP, URIP): No or Yes: whether to read back from the encoder (UEIP) or from the
/// RDBL link (URIP) when present.
pub const MOTOR_UEIP: Menu = Menu { name: "motorUEIP", choices: &["No", "Yes"] };
/// `motorSPMG` (SPMG, LSPG): Stop, Pause, Move (one move, then Pause) or Go (normal operation).
pub const MOTOR_SPMG: Menu = Menu { name: "motorSPMG", choices: &["Stop", "Pause", "Move", "Go"] };
/// `motorFOFF` (FOFF): on calibration, the user offset OFF changes (Variable) or the dial value does
/// (Frozen).
pub const MOTOR_FOFF: Menu = Menu { name: "motorFOFF", choices: &["Variable", "Frozen"] };
/// `motorTORQ` (CNEN): Disable or Enable the amplifier / closed-loop control.
pub const MOTOR_TORQ: Menu = Menu { name: "motorTORQ", choices: &["Disable", "Enable"] };
/// `motorSTUP` (STUP): OFF (idle), ON (a status update is requested) or BUSY (one is under way).
pub const MOTOR_STUP: Menu = Menu { name: "motorSTUP", choices: &["OFF", "ON", "BUSY"] };
/// `motorRMOD` (RMOD): how retries scale their correction (Default, Arithmetic, Geometric), or
/// In-Position (retries command no move).
pub const MOTOR_RMOD: Menu =
    Menu { name: "motorRMOD", choices: &["Default", "Arithmetic", "Geometric", "In-Position"] };
/// `motorRSTM` (RSTM): when the saved dial position is loaded into the controller at boot: Never,
/// Always, NearZero (when the controller reads near zero), or Conditional (NearZero, or whenever
/// retries use relative moves).
pub const MOTOR_RSTM: Menu = Menu { name: "motorRSTM", choices: &["Never", "Always", "NearZero", "Conditional"] };
/// `motorACCU` (ACCU): acceleration from ACCL (seconds to velocity) or from ACCS (EGU/s²).
pub const MOTOR_ACCU: Menu = Menu { name: "motorACCU", choices: &["Use ACCL", "Use ACCS"] };
/// `menuOmsl` (OMSL): supervisory (VAL is written) or closed_loop (VAL is read from the DOL link).
pub const MENU_OMSL: Menu = Menu { name: "menuOmsl", choices: &["supervisory", "closed_loop"] };
/// `menuYesNo` (NTM, LOCK, PERL): NO or YES.
pub const MENU_YES_NO: Menu = Menu { name: "menuYesNo", choices: &["NO", "YES"] };
/// `menuAlarmSevr` (SEVR, HLSV, HHSV, HSV, LSV, LLSV): NO_ALARM, MINOR, MAJOR, INVALID.
pub const MENU_ALARM_SEVR: Menu = Menu { name: "menuAlarmSevr", choices: &["NO_ALARM", "MINOR", "MAJOR", "INVALID"] };
/// `menuAlarmStat` (STAT): the alarm conditions of EPICS base.
pub const MENU_ALARM_STAT: Menu = Menu {
    name: "menuAlarmStat",
    choices: &[
        "NO_ALARM",
        "READ",
        "WRITE",
        "HIHI",
        "HIGH",
        "LOLO",
        "LOW",
        "STATE",
        "COS",
        "COMM",
        "TIMEOUT",
        "HWLIMIT",
        "CALC",
        "SCAN",
        "LINK",
        "SOFT",
        "BAD_SUB",
        "UDF",
        "DISABLE",
        "SIMM",
        "READ_ACCESS",
        "WRITE_ACCESS",
    ],
};

/// `menuScan` (SCAN): how a record is scanned; a motor record is Passive.
pub const MENU_SCAN: Menu = Menu {
    name: "menuScan",
    choices: &[
        "Passive",
        "Event",
        "I/O Intr",
        "10 second",
        "5 second",
        "2 second",
        "1 second",
        ".5 second",
        ".2 second",
        ".1 second",
    ],
};
/// `menuPini` (PINI): whether a record is processed at initialisation.
pub const MENU_PINI: Menu = Menu { name: "menuPini", choices: &["NO", "YES", "RUN", "RUNNING", "PAUSE", "PAUSED"] };
/// `menuPriority` (PRIO): the scan thread's priority.
pub const MENU_PRIORITY: Menu = Menu { name: "menuPriority", choices: &["LOW", "MEDIUM", "HIGH"] };

/// Every menu, for documentation and schema generation.
pub const ALL_MENUS: &[&Menu] = &[
    &MOTOR_DIR,
    &MOTOR_SET,
    &MOTOR_UEIP,
    &MOTOR_SPMG,
    &MOTOR_FOFF,
    &MOTOR_TORQ,
    &MOTOR_STUP,
    &MOTOR_RMOD,
    &MOTOR_RSTM,
    &MOTOR_ACCU,
    &MENU_OMSL,
    &MENU_YES_NO,
    &MENU_ALARM_SEVR,
    &MENU_ALARM_STAT,
    &MENU_SCAN,
    &MENU_PINI,
    &MENU_PRIORITY,
];

/// Menu indices the engine reasons about, named so the record logic reads like the manual.
pub mod choice {
    /// motorDIR Pos: user coordinates run with the dial.
    pub const DIR_POS: u16 = 0;
    /// motorDIR Neg: user coordinates run against the dial.
    pub const DIR_NEG: u16 = 1;
    /// motorSPMG Stop: stop, set the target to where the motor stopped, and accept no motion.
    pub const SPMG_STOP: u16 = 0;
    /// motorSPMG Pause: stop, keeping the target (Go resumes), and accept no motion.
    pub const SPMG_PAUSE: u16 = 1;
    /// motorSPMG Move: make one move, then fall back to Pause.
    pub const SPMG_MOVE: u16 = 2;
    /// motorSPMG Go: normal operation; every new target moves the motor.
    pub const SPMG_GO: u16 = 3;
    /// motorFOFF Variable: calibration changes the user offset OFF.
    pub const FOFF_VARIABLE: u16 = 0;
    /// motorFOFF Frozen: the offset stays; calibration changes the dial value.
    pub const FOFF_FROZEN: u16 = 1;
    /// motorSTUP OFF: no status update pending.
    pub const STUP_OFF: u16 = 0;
    /// motorSTUP ON: a status update is requested.
    pub const STUP_ON: u16 = 1;
    /// motorSTUP BUSY: a status update is under way.
    pub const STUP_BUSY: u16 = 2;
    /// motorRMOD Default: each retry corrects the full remaining error.
    pub const RMOD_DEFAULT: u16 = 0;
    /// motorRMOD Arithmetic: retry corrections shrink linearly with the retry count.
    pub const RMOD_ARITHMETIC: u16 = 1;
    /// motorRMOD Geometric: each retry correction is half the previous one.
    pub const RMOD_GEOMETRIC: u16 = 2;
    /// motorRMOD In-Position: retries command no move; the record waits DLY and checks again.
    pub const RMOD_IN_POSITION: u16 = 3;
    /// motorACCU Use ACCS: acceleration comes from ACCS (EGU/s²) instead of ACCL.
    pub const ACCU_USE_ACCS: u16 = 1;
    /// menuOmsl closed_loop: VAL is read from the DOL link.
    pub const OMSL_CLOSED_LOOP: u16 = 1;
    /// menuYesNo NO (also motorUEIP No).
    pub const NO: u16 = 0;
    /// menuYesNo YES (also motorUEIP Yes).
    pub const YES: u16 = 1;
}

/// Alarm severities (menuAlarmSevr).
pub mod severity {
    /// No alarm.
    pub const NO_ALARM: u16 = 0;
    /// Minor alarm.
    pub const MINOR: u16 = 1;
    /// Major alarm.
    pub const MAJOR: u16 = 2;
    /// The value is invalid (undefined record, lost communication).
    pub const INVALID: u16 = 3;
}

/// Alarm conditions (menuAlarmStat) the motor record raises.
pub mod status {
    /// No alarm condition.
    pub const NO_ALARM: u16 = 0;
    /// At the high limit switch, or the target is above the dial high limit (severity HLSV).
    pub const HIGH: u16 = 4;
    /// At the low limit switch, or the target is below the dial low limit (severity HLSV).
    pub const LOW: u16 = 6;
    /// The driver reports a problem or a slip/stall (MAJOR).
    pub const STATE: u16 = 7;
    /// Controller communication error (INVALID).
    pub const COMM: u16 = 9;
    /// The record is undefined (INVALID).
    pub const UDF: u16 = 17;
    /// The record is disabled (DISA = DISV; severity DISS).
    pub const DISABLE: u16 = 18;
}
