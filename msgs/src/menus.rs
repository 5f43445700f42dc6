//! Menu (enumerated) field types, with the exact choice strings of motorRecord.dbd and EPICS base.

use serde::Serialize;

/// A menu: a named, ordered list of choices; a menu field holds the index of one of them.
#[derive(Debug, PartialEq, Eq, Serialize)]
pub struct Menu {
    pub name: &'static str,
    pub choices: &'static [&'static str],
}

impl Menu {
    /// Index of a choice by name, case-insensitive.
    pub fn index_of(&self, choice: &str) -> Option<u16> {
        let choice = choice.trim();
        self.choices.iter().position(|c| c.eq_ignore_ascii_case(choice)).map(|i| i as u16)
    }

    pub fn choice(&self, index: u16) -> Option<&'static str> {
        self.choices.get(usize::from(index)).copied()
    }
}

pub const MOTOR_DIR: Menu = Menu { name: "motorDIR", choices: &["Pos", "Neg"] };
pub const MOTOR_SET: Menu = Menu { name: "motorSET", choices: &["Use", "Set"] };
pub const MOTOR_UEIP: Menu = Menu { name: "motorUEIP", choices: &["No", "Yes"] };
pub const MOTOR_SPMG: Menu = Menu { name: "motorSPMG", choices: &["Stop", "Pause", "Move", "Go"] };
pub const MOTOR_FOFF: Menu = Menu { name: "motorFOFF", choices: &["Variable", "Frozen"] };
pub const MOTOR_TORQ: Menu = Menu { name: "motorTORQ", choices: &["Disable", "Enable"] };
pub const MOTOR_STUP: Menu = Menu { name: "motorSTUP", choices: &["OFF", "ON", "BUSY"] };
pub const MOTOR_RMOD: Menu =
    Menu { name: "motorRMOD", choices: &["Default", "Arithmetic", "Geometric", "In-Position"] };
pub const MOTOR_RSTM: Menu = Menu { name: "motorRSTM", choices: &["Never", "Always", "NearZero", "Conditional"] };
pub const MOTOR_ACCU: Menu = Menu { name: "motorACCU", choices: &["Use ACCL", "Use ACCS"] };
pub const MENU_OMSL: Menu = Menu { name: "menuOmsl", choices: &["supervisory", "closed_loop"] };
pub const MENU_YES_NO: Menu = Menu { name: "menuYesNo", choices: &["NO", "YES"] };
pub const MENU_ALARM_SEVR: Menu = Menu { name: "menuAlarmSevr", choices: &["NO_ALARM", "MINOR", "MAJOR", "INVALID"] };
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
];

/// Menu indices the engine reasons about, named so the record logic reads like the manual.
pub mod choice {
    pub const DIR_POS: u16 = 0;
    pub const DIR_NEG: u16 = 1;
    pub const SPMG_STOP: u16 = 0;
    pub const SPMG_PAUSE: u16 = 1;
    pub const SPMG_MOVE: u16 = 2;
    pub const SPMG_GO: u16 = 3;
    pub const FOFF_VARIABLE: u16 = 0;
    pub const FOFF_FROZEN: u16 = 1;
    pub const STUP_OFF: u16 = 0;
    pub const STUP_ON: u16 = 1;
    pub const STUP_BUSY: u16 = 2;
    pub const RMOD_DEFAULT: u16 = 0;
    pub const RMOD_ARITHMETIC: u16 = 1;
    pub const RMOD_GEOMETRIC: u16 = 2;
    pub const RMOD_IN_POSITION: u16 = 3;
    pub const ACCU_USE_ACCS: u16 = 1;
    pub const OMSL_CLOSED_LOOP: u16 = 1;
    pub const NO: u16 = 0;
    pub const YES: u16 = 1;
}

/// Alarm severities (menuAlarmSevr).
pub mod severity {
    pub const NO_ALARM: u16 = 0;
    pub const MINOR: u16 = 1;
    pub const MAJOR: u16 = 2;
    pub const INVALID: u16 = 3;
}

/// Alarm conditions (menuAlarmStat) the motor record raises.
pub mod status {
    pub const NO_ALARM: u16 = 0;
    pub const HIGH: u16 = 4;
    pub const LOW: u16 = 6;
    pub const STATE: u16 = 7;
    pub const COMM: u16 = 9;
    pub const UDF: u16 = 17;
}
