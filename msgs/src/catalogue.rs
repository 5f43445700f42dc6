//! The field catalogue: the single source of truth for every field of a zmotor axis, like
//! motorRecord.dbd. The `catalogue!` table below generates the `Field` enum, the `FIELDS`
//! metadata table and the `Fields` storage struct; codecs, schemas, the key layout, the engine
//! and the CLI all derive from it.

use crate::menus::{self, Menu};
use crate::value::{FieldStorage, Value};
use serde::Serialize;

/// Storage kind of a field (the DBF type of the reference record).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Kind {
    /// DBF_DOUBLE (f64).
    Double,
    /// DBF_FLOAT (f32).
    Float,
    /// DBF_LONG (i32).
    Long,
    /// DBF_ULONG (u32).
    ULong,
    /// DBF_SHORT (i16).
    Short,
    /// DBF_USHORT (u16).
    UShort,
    /// DBF_UCHAR (u8): dbCommon's flags (UDF, DISP, PROC).
    UChar,
    /// DBF_MENU: an index into the menu's choices.
    Menu(&'static Menu),
    /// DBF_STRING with its maximum length in bytes.
    Str(usize),
    /// A link: on zmotor, a Zenoh key expression (text).
    Link,
}

impl Kind {
    /// What a write to a field of this kind must hold, in words.
    pub(crate) fn expected(self) -> &'static str {
        match self {
            Kind::Double | Kind::Float => "a number",
            Kind::Long | Kind::ULong | Kind::Short | Kind::UShort | Kind::UChar => "an integer",
            Kind::Menu(_) => "a menu choice (its name or index)",
            Kind::Str(_) => "text",
            Kind::Link => "a key expression",
        }
    }

    /// Whether a write may hold a boolean (as 1 or 0): whole-number fields and two-choice menus.
    pub(crate) fn takes_a_flag(self) -> bool {
        match self {
            Kind::Long | Kind::ULong | Kind::Short | Kind::UShort | Kind::UChar => true,
            Kind::Menu(menu) => menu.choices.len() == 2,
            Kind::Double | Kind::Float | Kind::Str(_) | Kind::Link => false,
        }
    }

    /// The range of the kind's values as EPICS record support gives it by default for display
    /// and control limits (recGbl's getMaxRangeValues): (high, low); none for text.
    pub fn default_range(self) -> (f64, f64) {
        match self {
            Kind::Double => (1e300, -1e300),
            Kind::Float => (1e30, -1e30),
            Kind::Long => (f64::from(i32::MAX), f64::from(i32::MIN)),
            Kind::ULong => (f64::from(u32::MAX), 0.0),
            Kind::Short => (f64::from(i16::MAX), f64::from(i16::MIN)),
            Kind::UShort | Kind::Menu(_) => (f64::from(u16::MAX), 0.0),
            Kind::UChar => (f64::from(u8::MAX), 0.0),
            Kind::Str(_) | Kind::Link => (0.0, 0.0),
        }
    }

    /// Allowed integer range for integer-valued kinds.
    pub fn int_range(self) -> Option<(i64, i64)> {
        match self {
            Kind::Long => Some((i32::MIN.into(), i32::MAX.into())),
            Kind::ULong => Some((0, u32::MAX.into())),
            Kind::Short => Some((i16::MIN.into(), i16::MAX.into())),
            Kind::UShort => Some((0, u16::MAX.into())),
            Kind::UChar => Some((0, u8::MAX.into())),
            Kind::Menu(menu) => Some((0, menu.choices.len() as i64 - 1)),
            _ => None,
        }
    }

    /// The DBF type's name as the catalogue JSON shows it (`DOUBLE`, `MENU`, `LINK`, ...).
    pub fn type_name(self) -> &'static str {
        match self {
            Kind::Double => "DOUBLE",
            Kind::Float => "FLOAT",
            Kind::Long => "LONG",
            Kind::ULong => "ULONG",
            Kind::Short => "SHORT",
            Kind::UShort => "USHORT",
            Kind::UChar => "UCHAR",
            Kind::Menu(_) => "MENU",
            Kind::Str(_) => "STRING",
            Kind::Link => "LINK",
        }
    }
}

/// Who may write a field, as in the manual's Access column.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Access {
    /// "R": read-only; writes are refused.
    RO,
    /// "R/W": writable; the write is stored (plus its special handling) without processing.
    RW,
    /// "R/W*": writable, and a write processes the record.
    PP,
}

impl Access {
    /// The manual's Access column: `R`, `R/W` or `R/W*`.
    pub fn label(self) -> &'static str {
        match self {
            Access::RO => "R",
            Access::RW => "R/W",
            Access::PP => "R/W*",
        }
    }
}

/// Metadata of one field.
#[derive(Debug, Serialize)]
pub struct FieldDef {
    /// The field this entry describes.
    #[serde(skip)]
    pub field: Field,
    /// The EPICS field name (e.g. `VAL`).
    pub name: &'static str,
    /// Storage kind (DBF type).
    pub kind: Kind,
    /// Who may write the field.
    pub access: Access,
    /// The DBD prompt: a short human-readable description.
    pub prompt: &'static str,
    /// Unit template; "EGU" stands for the axis's engineering units.
    pub unit: &'static str,
}

impl FieldDef {
    /// The field's value in a new axis (the DBD default).
    pub fn default_value(&self) -> Value {
        Fields::default().get(self.field)
    }
}

macro_rules! storage {
    (Double) => {
        f64
    };
    (Float) => {
        f32
    };
    (Long) => {
        i32
    };
    (ULong) => {
        u32
    };
    (Short) => {
        i16
    };
    (UShort) => {
        u16
    };
    (UChar) => {
        u8
    };
    (Menu($m:ident)) => {
        u16
    };
    (Str($n:literal)) => {
        String
    };
    (Link) => {
        String
    };
}

/// A default written in the table, as the storage type (text defaults become Strings).
macro_rules! default_value {
    (Str($n:literal), $d:expr) => {
        String::from($d)
    };
    (Link, $d:expr) => {
        String::from($d)
    };
    ($k:ident $(($a:tt))?, $d:expr) => {
        $d
    };
}

macro_rules! kind {
    (Menu($m:ident)) => {
        Kind::Menu(&menus::$m)
    };
    (Str($n:literal)) => {
        Kind::Str($n)
    };
    ($k:ident) => {
        Kind::$k
    };
}

macro_rules! catalogue {
    ($( $name:ident $member:ident : $kind:ident $(($arg:tt))? = $default:expr,
        $access:ident, $prompt:literal, $unit:literal; )*) => {
        /// Every field of an axis, by its EPICS name.
        #[allow(clippy::upper_case_acronyms)]
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
        #[repr(u16)]
        pub enum Field { $(#[doc = concat!($prompt, ".")] $name),* }

        /// Metadata of every field, in `Field` order.
        pub const FIELDS: &[FieldDef] = &[$(
            FieldDef {
                field: Field::$name,
                name: stringify!($name),
                kind: kind!($kind $(($arg))?),
                access: Access::$access,
                prompt: $prompt,
                unit: $unit,
            }
        ),*];

        /// The values of every field of one axis, as typed Rust members.
        #[derive(Clone, Debug, PartialEq)]
        pub struct Fields { $(#[doc = concat!(stringify!($name), ": ", $prompt, ".")] pub $member: storage!($kind $(($arg))?)),* }

        impl Default for Fields {
            fn default() -> Self {
                Self { $($member: { let v: storage!($kind $(($arg))?) = default_value!($kind $(($arg))?, $default); v }),* }
            }
        }

        impl Fields {
            /// The current value of a field.
            pub fn get(&self, field: Field) -> Value {
                match field { $(Field::$name => self.$member.to_value()),* }
            }

            /// Store a value already validated for the field's kind (see `codec::decode_write`).
            pub fn set(&mut self, field: Field, value: &Value) {
                match field { $(Field::$name => self.$member = FieldStorage::from_value(value)),* }
            }
        }
    };
}

catalogue! {
    // ---- position / drive ----
    VAL   val:   Double = 0.0,  PP, "User Desired Value", "EGU";
    DVAL  dval:  Double = 0.0,  PP, "Dial Desired Value", "EGU";
    RVAL  rval:  Long = 0,      PP, "Raw Desired Value", "steps";
    RLV   rlv:   Double = 0.0,  PP, "Relative Value", "EGU";
    TWF   twf:   Short = 0,     PP, "Tweak motor Forward", "";
    TWR   twr:   Short = 0,     PP, "Tweak motor Reverse", "";
    TWV   twv:   Double = 0.0,  RW, "Tweak Step Size (EGU)", "EGU";
    LVAL  lval:  Double = 0.0,  RO, "Last User Des Val", "EGU";
    LDVL  ldvl:  Double = 0.0,  RO, "Last Dial Des Val", "EGU";
    LRVL  lrvl:  Long = 0,      RO, "Last Raw Des Val", "steps";
    LRLV  lrlv:  Double = 0.0,  RO, "Last Rel Value", "EGU";
    SYNC  sync:  Short = 0,     PP, "Sync positions", "";
    // ---- readback / status ----
    RBV   rbv:   Double = 0.0,  RO, "User Readback Value", "EGU";
    DRBV  drbv:  Double = 0.0,  RO, "Dial Readback Value", "EGU";
    RRBV  rrbv:  Long = 0,      RO, "Raw Readback Value", "steps";
    RMP   rmp:   Long = 0,      RO, "Raw Motor Position", "steps";
    REP   rep:   Long = 0,      RO, "Raw Encoder Position", "counts";
    RVEL  rvel:  Long = 0,      RO, "Raw Velocity", "steps/s";
    DIFF  diff:  Double = 0.0,  RO, "Difference dval-drbv", "EGU";
    RDIF  rdif:  Long = 0,      RO, "Difference rval-rrbv", "steps";
    MSTA  msta:  ULong = 0,     RO, "Motor Status", "";
    DMOV  dmov:  Short = 1,     RO, "Done moving to value", "";
    MOVN  movn:  Short = 0,     RO, "Motor is moving", "";
    TDIR  tdir:  Short = 0,     RO, "Direction of Travel", "";
    CDIR  cdir:  Short = 0,     RO, "Raw commanded direction", "";
    HLS   hls:   Short = 0,     RO, "At High Limit Switch", "";
    LLS   lls:   Short = 0,     RO, "At Low Limit Switch", "";
    RHLS  rhls:  Short = 0,     RO, "Raw High Limit Switch", "";
    RLLS  rlls:  Short = 0,     RO, "Raw Low Limit Switch", "";
    ATHM  athm:  Short = 0,     RO, "At HOME", "";
    LVIO  lvio:  Short = 1,     RO, "Limit violation", "";
    RCNT  rcnt:  Short = 0,     RO, "Retry count", "";
    MISS  miss:  Short = 0,     RO, "Ran out of retries", "";
    MIP   mip:   UShort = 0,    RO, "Motion In Progress", "";
    PP    pp:    Short = 0,     RO, "Post process command", "";
    LSPG  lspg:  Menu(MOTOR_SPMG) = 3, RO, "Last SPMG", "";
    MMAP  mmap:  ULong = 0,     RO, "Monitor Mask", "";
    NMAP  nmap:  ULong = 0,     RO, "Monitor Mask", "";
    RHLM  rhlm:  Double = 0.0,  RO, "Raw High Limit", "steps";
    RLLM  rllm:  Double = 0.0,  RO, "Raw Low Limit", "steps";
    ALST  alst:  Double = 0.0,  RO, "Last Value Archived", "EGU";
    MLST  mlst:  Double = 0.0,  RO, "Last Value Monitored", "EGU";
    CARD  card:  Short = 0,     RO, "Card Number", "";
    VERS  vers:  Float = 1.0,   RO, "Code Version", "";
    // ---- calibration / resolution ----
    DIR   dir:   Menu(MOTOR_DIR) = 0,  PP, "User Direction", "";
    OFF   off:   Double = 0.0,  PP, "User Offset (EGU)", "EGU";
    FOFF  foff:  Menu(MOTOR_FOFF) = 0, RW, "Offset-Freeze Switch", "";
    FOF   fof:   Short = 0,     RW, "Freeze Offset", "";
    VOF   vof:   Short = 0,     RW, "Variable Offset", "";
    SET   set:   Menu(MOTOR_SET) = 0,  RW, "Set/Use Switch", "";
    SSET  sset:  Short = 0,     RW, "Set SET Mode", "";
    SUSE  suse:  Short = 0,     RW, "Set USE Mode", "";
    IGSET igset: Short = 0,     RW, "Ignore SET Field", "";
    MRES  mres:  Double = 0.0,  PP, "Motor Step Size (EGU)", "EGU";
    SREV  srev:  Long = 200,    PP, "Steps per Revolution", "steps/rev";
    UREV  urev:  Double = 0.0,  PP, "EGU's per Revolution", "EGU/rev";
    ERES  eres:  Double = 0.0,  PP, "Encoder Step Size (EGU)", "EGU";
    RRES  rres:  Double = 0.0,  RW, "Readback Step Size (EGU)", "EGU";
    UEIP  ueip:  Menu(MOTOR_UEIP) = 0, PP, "Use Encoder If Present", "";
    URIP  urip:  Menu(MOTOR_UEIP) = 0, PP, "Use RDBL Link If Present", "";
    // ---- motion parameters ----
    VELO  velo:  Double = 0.0,  RW, "Velocity (EGU/s)", "EGU/s";
    S     s:     Double = 0.0,  RW, "Speed (revolutions/sec)", "rev/s";
    VBAS  vbas:  Double = 0.0,  RW, "Base Velocity (EGU/s)", "EGU/s";
    SBAS  sbas:  Double = 0.0,  RW, "Base Speed (RPS)", "rev/s";
    VMAX  vmax:  Double = 0.0,  RW, "Max. Velocity (EGU/s)", "EGU/s";
    SMAX  smax:  Double = 0.0,  RW, "Max. Speed (RPS)", "rev/s";
    ACCL  accl:  Double = 0.2,  RW, "Seconds to Velocity", "s";
    ACCS  accs:  Double = 0.0,  RW, "Acceleration (EGU/s^2)", "EGU/s^2";
    ACCU  accu:  Menu(MOTOR_ACCU) = 0, RW, "Acceleration used", "";
    BDST  bdst:  Double = 0.0,  RW, "BL Distance (EGU)", "EGU";
    BVEL  bvel:  Double = 0.0,  RW, "BL Velocity (EGU/s)", "EGU/s";
    SBAK  sbak:  Double = 0.0,  RW, "BL Speed (RPS)", "rev/s";
    BACC  bacc:  Double = 0.5,  RW, "BL Seconds to Velocity", "s";
    FRAC  frac:  Float = 1.0,   RW, "Move Fraction", "";
    JVEL  jvel:  Double = 0.0,  RW, "Jog Velocity (EGU/s)", "EGU/s";
    JAR   jar:   Double = 0.0,  RW, "Jog Accel. (EGU/s^2)", "EGU/s^2";
    HVEL  hvel:  Double = 0.0,  RW, "Home Velocity (EGU/s)", "EGU/s";
    RDBD  rdbd:  Double = 0.0,  RW, "Retry Deadband (EGU)", "EGU";
    SPDB  spdb:  Double = 0.0,  RW, "Setpoint Deadband (EGU)", "EGU";
    RTRY  rtry:  Short = 10,    RW, "Max retry count", "";
    RMOD  rmod:  Menu(MOTOR_RMOD) = 0, RW, "Retry Mode", "";
    DLY   dly:   Double = 0.0,  RW, "Readback settle time (s)", "s";
    NTM   ntm:   Menu(MENU_YES_NO) = 1, RW, "New Target Monitor", "";
    NTMF  ntmf:  UShort = 2,    RW, "NTM Deadband Factor", "";
    // ---- commands ----
    SPMG  spmg:  Menu(MOTOR_SPMG) = 3, PP, "Stop/Pause/Move/Go", "";
    STOP  stop:  Short = 0,     PP, "Stop", "";
    HOMF  homf:  Short = 0,     PP, "Home Forward", "";
    HOMR  homr:  Short = 0,     PP, "Home Reverse", "";
    JOGF  jogf:  Short = 0,     PP, "Jog motor Forward", "";
    JOGR  jogr:  Short = 0,     PP, "Jog motor Reverse", "";
    STUP  stup:  Menu(MOTOR_STUP) = 0, PP, "Status Update", "";
    CNEN  cnen:  Menu(MOTOR_TORQ) = 0, PP, "Enable control", "";
    PCOF  pcof:  Double = 0.0,  RW, "Proportional Gain", "";
    ICOF  icof:  Double = 0.0,  RW, "Integral Gain", "";
    DCOF  dcof:  Double = 0.0,  RW, "Derivative Gain", "";
    PROC  proc:  UChar = 0,     PP, "Force Processing", "";
    // ---- limits and alarms ----
    HLM   hlm:   Double = 0.0,  PP, "User High Limit", "EGU";
    LLM   llm:   Double = 0.0,  PP, "User Low Limit", "EGU";
    DHLM  dhlm:  Double = 0.0,  PP, "Dial High Limit", "EGU";
    DLLM  dllm:  Double = 0.0,  PP, "Dial Low Limit", "EGU";
    HLSV  hlsv:  Menu(MENU_ALARM_SEVR) = 0, PP, "HW Lim. Violation Svr", "";
    HIHI  hihi:  Double = 0.0,  PP, "Hihi Alarm Limit (EGU)", "EGU";
    HIGH  high:  Double = 0.0,  PP, "High Alarm Limit (EGU)", "EGU";
    LOW   low:   Double = 0.0,  PP, "Low Alarm Limit (EGU)", "EGU";
    LOLO  lolo:  Double = 0.0,  PP, "Lolo Alarm Limit (EGU)", "EGU";
    HHSV  hhsv:  Menu(MENU_ALARM_SEVR) = 0, PP, "Hihi Severity", "";
    HSV   hsv:   Menu(MENU_ALARM_SEVR) = 0, PP, "High Severity", "";
    LSV   lsv:   Menu(MENU_ALARM_SEVR) = 0, PP, "Low Severity", "";
    LLSV  llsv:  Menu(MENU_ALARM_SEVR) = 0, PP, "Lolo Severity", "";
    HOPR  hopr:  Double = 0.0,  RW, "High Operating Range", "EGU";
    LOPR  lopr:  Double = 0.0,  RW, "Low Operating Range", "EGU";
    MDEL  mdel:  Double = 0.0,  RW, "Monitor Deadband", "EGU";
    ADEL  adel:  Double = 0.0,  RW, "Archive Deadband", "EGU";
    // ---- links, device, miscellaneous ----
    OUT   out:   Link = "",     RW, "Output Specification", "";
    RDBL  rdbl:  Link = "",     RW, "Readback Location", "";
    DOL   dol:   Link = "",     RW, "Desired Output Loc", "";
    OMSL  omsl:  Menu(MENU_OMSL) = 0, RW, "Output Mode Select", "";
    RLNK  rlnk:  Link = "",     RW, "Readback OutLink", "";
    STOO  stoo:  Link = "",     RW, "STOP OutLink", "";
    DINP  dinp:  Link = "",     RW, "DMOV Input Link", "";
    RINP  rinp:  Link = "",     RW, "RMP Input Link", "";
    LOCK  lock:  Menu(MENU_YES_NO) = 0, RW, "Soft Channel Position Lock", "";
    RSTM  rstm:  Menu(MOTOR_RSTM) = 2, RW, "Restore Mode", "";
    PERL  perl:  Menu(MENU_YES_NO) = 0, RW, "Periodic Limits (documented, unused)", "";
    PREC  prec:  Short = 0,     RW, "Display Precision", "";
    EGU   egu:   Str(16) = "",  RW, "Engineering Units", "";
    INIT  init:  Str(40) = "",  RW, "Startup commands", "";
    PREM  prem:  Str(40) = "",  RW, "Pre-move commands", "";
    POST  post:  Str(40) = "",  RW, "Post-move commands", "";
    // ---- common record fields ----
    NAME  name:  Str(61) = "",  RO, "Record Name", "";
    DESC  desc:  Str(41) = "",  RW, "Descriptor", "";
    DTYP  dtyp:  Str(40) = "",  RO, "Device Type", "";
    STAT  stat:  Menu(MENU_ALARM_STAT) = 17, RO, "Alarm Status", "";
    SEVR  sevr:  Menu(MENU_ALARM_SEVR) = 3,  RO, "Alarm Severity", "";
    UDF   udf:   UChar = 1,     RO, "Undefined", "";
    FLNK  flnk:  Link = "",     RW, "Forward Process Link", "";
    DISP  disp:  UChar = 0,     RW, "Disable putField", "";
    DISA  disa:  Short = 0,     RW, "Disable", "";
    DISV  disv:  Short = 1,     RW, "Disable Value", "";
    DISS  diss:  Menu(MENU_ALARM_SEVR) = 0, RW, "Disable Alarm Sevrty", "";
    SDIS  sdis:  Link = "",     RW, "Scanning Disable", "";
    ACKT  ackt:  Menu(MENU_YES_NO) = 1, RW, "Alarm Ack Transient", "";
    ACKS  acks:  Menu(MENU_ALARM_SEVR) = 0, RW, "Alarm Ack Severity", "";
}

impl Field {
    /// The field's catalogue entry.
    pub fn def(self) -> &'static FieldDef {
        &FIELDS[self as usize]
    }

    /// The field's EPICS name (e.g. `VAL`).
    pub fn name(self) -> &'static str {
        self.def().name
    }

    /// Look a field up by its EPICS name, exactly as the catalogue spells it (keys are
    /// case-sensitive: `motor/m1/val` is not `motor/m1/VAL`).
    pub fn from_name(name: &str) -> Option<Field> {
        FIELDS.iter().find(|d| d.name == name).map(|d| d.field)
    }

    /// Look a field up ignoring case: for a command line, and to name the field a mistyped
    /// key meant.
    pub fn from_name_any_case(name: &str) -> Option<Field> {
        FIELDS.iter().find(|d| d.name.eq_ignore_ascii_case(name)).map(|d| d.field)
    }

    /// Every field, in catalogue order.
    pub fn all() -> impl Iterator<Item = Field> {
        FIELDS.iter().map(|d| d.field)
    }

    /// Number of fields in the catalogue.
    pub const COUNT: usize = FIELDS.len();

    /// The display precision of this field on an axis whose PREC is `prec`, as the record's
    /// `get_precision` gives it to clients: VERS two decimals, every other floating-point field
    /// PREC (within 0 to 15), and a field of any other type (the raw readbacks, DMOV, MSTA...)
    /// none, as `recGblGetPrec` bounds it.
    pub fn precision(self, prec: i16) -> i16 {
        match self {
            Field::VERS => 2,
            _ if !matches!(self.def().kind, Kind::Double | Kind::Float) => 0,
            _ if !(0..=15).contains(&prec) => 15,
            _ => prec,
        }
    }

    /// This field's units on an axis whose EGU is `egu`, as the record's `get_units` gives them
    /// to clients: speeds `EGU/sec`, JAR `EGU/s/s`, ACCL and BACC `sec`, the rev/s speeds
    /// `rev/sec`, SREV `steps/rev`, UREV `EGU/rev`, every other field EGU; at most 15 characters.
    pub fn record_units(self, egu: &str) -> String {
        use Field::*;
        let units = match self {
            VELO | VMAX | BVEL | VBAS | JVEL | HVEL => format!("{egu}/sec"),
            JAR => format!("{egu}/s/s"),
            ACCL | BACC => "sec".into(),
            S | SBAS | SBAK => "rev/sec".into(),
            SREV => "steps/rev".into(),
            UREV => format!("{egu}/rev"),
            _ => egu.into(),
        };
        units.chars().take(15).collect()
    }

    /// A write that sets a target the axis moves to (VAL once written says where).
    pub fn sets_target(self) -> bool {
        matches!(self, Field::VAL | Field::DVAL | Field::RVAL | Field::RLV | Field::TWF | Field::TWR)
    }

    /// A write that starts a motion ending by itself: a target, or a home search (a put-callback
    /// of one completes when it has ended; a jog runs until told to end).
    pub fn starts_motion(self) -> bool {
        self.sets_target() || matches!(self, Field::HOMF | Field::HOMR)
    }

    /// The record's alarm and its acknowledgement: what an alarm's event (DBE_ALARM) carries.
    pub fn is_alarm_state(self) -> bool {
        matches!(self, Field::STAT | Field::SEVR | Field::ACKT | Field::ACKS)
    }

    /// dbCommon's ACKT and ACKS (SPC_NOMOD on an IOC): written only as an alarm's
    /// acknowledgement (Channel Access's DBR_PUT_ACKT / DBR_PUT_ACKS), and ending no motion.
    pub fn acknowledges_alarms(self) -> bool {
        matches!(self, Field::ACKT | Field::ACKS)
    }

    /// A write taken while DISP disables puts: DISP itself (as on an IOC), and STOP (departure
    /// Z23: an IOC refuses it too, leaving a motion under way that nobody may stop).
    pub fn taken_while_puts_disabled(self) -> bool {
        matches!(self, Field::DISP | Field::STOP)
    }
}

/// What autosave keeps of a field, as EPICS autosave's motor_positions.req and
/// motor_settings.req do: the position (DVAL and OFF), and every setting a user configures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Autosave {
    /// Part of the axis position (motor_positions.req): DVAL and OFF.
    Position,
    /// A user-configured setting (motor_settings.req).
    Setting,
}

impl Field {
    /// Whether autosave keeps this field, and as what. Read-only fields, commands (a restart
    /// must move nothing on its own) and values derived from others (VAL, RVAL, HLM, LLM) are not
    /// kept: the record recomputes them at boot from what is.
    pub fn autosave(self) -> Option<Autosave> {
        use Field::*;
        match self {
            DVAL | OFF => Some(Autosave::Position),
            VAL | RVAL | RLV | TWF | TWR | SYNC | SPMG | STOP | HOMF | HOMR | JOGF | JOGR | STUP | CNEN | PROC
            | SET | SSET | SUSE | FOF | VOF | HLM | LLM | ACKS => None,
            // As motor_settings.req: whether the record is disabled is the launch's (its SDIS
            // interlock) or the moment's, not a setting that outlives a restart.
            DISA | DISV | DISS | SDIS => None,
            _ if self.def().access == Access::RO => None,
            _ => Some(Autosave::Setting),
        }
    }
}

/// Who may write a field under access control: an operator drives, an expert configures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WriteClass {
    /// A command that moves or stops the axis, or the tweak step an operator sets beside it:
    /// targets (VAL, DVAL, RVAL, RLV), tweak, jog, home, STOP, SPMG, SYNC, STUP, CNEN, PROC;
    /// and an alarm's acknowledgement (ACKS).
    Drive,
    /// Everything else one may write: limits, resolution, speeds, offsets, SET, links, ...
    Configure,
}

impl Field {
    /// The class of a writable field; `None` for a read-only one.
    pub fn write_class(self) -> Option<WriteClass> {
        use Field::*;
        match self {
            _ if self.def().access == Access::RO => None,
            VAL | DVAL | RVAL | RLV | TWF | TWR | TWV | JOGF | JOGR | HOMF | HOMR | STOP | SPMG | SYNC | STUP
            | CNEN | PROC | ACKS => Some(WriteClass::Drive),
            _ => Some(WriteClass::Configure),
        }
    }
}

impl Field {
    /// A write that commands the record rather than configures it: it starts, stops, holds or
    /// ends a motion, or makes the record sync or process. A launch file or a database, which
    /// configure an axis, may not hold one: it would act at the axis's first write.
    pub fn is_command(self) -> bool {
        use Field::*;
        matches!(self, RLV | TWF | TWR | JOGF | JOGR | HOMF | HOMR | STOP | SPMG | SYNC | STUP | PROC | ACKS)
    }

    /// A target the record takes from its readback when it starts (VAL, RVAL): a configuration
    /// that set it would be a move at the axis's first write, so none may (DVAL sets a position).
    pub fn starts_at_readback(self) -> bool {
        matches!(self, Field::VAL | Field::RVAL)
    }
}

/// Whether a monitored value moved past its deadband (RBV's MDEL for monitors, ADEL for
/// archivers) from the value last posted, as the record's monitor() judges it: a deadband of 0
/// lets every change through.
pub fn past_deadband(deadband: f64, last: f64, value: f64) -> bool {
    deadband == 0.0 || (last - value).abs() > deadband
}

impl Field {
    /// A jog button (JOGF, JOGR): what a client holds (the jog deadman), since a jog runs until
    /// told to end.
    pub fn is_jog(self) -> bool {
        matches!(self, Field::JOGF | Field::JOGR)
    }
}

impl Field {
    /// A readback a poll posts again and again while the axis moves (spec §13's readback posts):
    /// each is superseded by the next poll's, so a congested link may drop it
    /// (`zmotor_core::Delivery::Stream`).
    pub fn is_readback_stream(self) -> bool {
        use Field::*;
        matches!(self, RBV | DRBV | RRBV | RMP | REP | RVEL | DIFF | RDIF)
    }
}

impl Field {
    /// A field every motion posts: its readbacks (`is_readback_stream`), and at its start and
    /// end the target, DMOV, MOVN, MIP, MSTA, TDIR and ATHM. A node declares these keys ahead
    /// of a first motion, for a key Zenoh first meets costs a walk of its neighbours.
    pub fn posted_by_every_motion(self) -> bool {
        use Field::*;
        self.is_readback_stream() || matches!(self, VAL | DVAL | RVAL | DMOV | MOVN | MIP | MSTA | TDIR | ATHM)
    }
}

impl Field {
    /// A link the record writes through (OUT, STOO, RLNK, FLNK); its other links are read.
    pub fn is_output_link(self) -> bool {
        matches!(self, Field::OUT | Field::STOO | Field::RLNK | Field::FLNK)
    }
}

/// A field every EPICS record has (dbCommon) that zmotor does not model (scanning, priorities,
/// tracing, access security): what an IOC's motor record holds in it by default. A database may
/// set it (an import ignores it); Channel Access serves it, read-only, with this value, so that
/// a screen or a tool that reads it finds it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CommonField {
    /// Its name.
    pub name: &'static str,
    /// Its type.
    pub kind: Kind,
    /// Its value: a menu's index or a number (`text` none), or text.
    pub number: f64,
    /// Its value as text, for a string or link.
    pub text: Option<&'static str>,
}

impl CommonField {
    /// Its value.
    pub fn value(&self) -> Value {
        match (self.text, self.kind) {
            (Some(text), _) => Value::Text(text.to_string()),
            (None, Kind::Double | Kind::Float) => Value::Float(self.number),
            (None, _) => Value::Int(self.number as i64),
        }
    }
}

/// The unmodelled dbCommon fields (`CommonField`); disabling (DISP, DISA, DISV, DISS, SDIS) and
/// the alarm acknowledgement (ACKT, ACKS) are modelled, as fields of the catalogue.
pub const UNMODELLED_COMMON_FIELDS: &[CommonField] = {
    const fn menu(name: &'static str, menu: &'static Menu, index: u16) -> CommonField {
        CommonField { name, kind: Kind::Menu(menu), number: index as f64, text: None }
    }
    const fn number(name: &'static str, kind: Kind) -> CommonField {
        CommonField { name, kind, number: 0.0, text: None }
    }
    const fn text(name: &'static str, kind: Kind) -> CommonField {
        CommonField { name, kind, number: 0.0, text: Some("") }
    }
    &[
        menu("SCAN", &menus::MENU_SCAN, 0),
        menu("PINI", &menus::MENU_PINI, 0),
        number("PHAS", Kind::Short),
        text("EVNT", Kind::Str(40)),
        menu("PRIO", &menus::MENU_PRIORITY, 0),
        number("TPRO", Kind::UChar),
        number("TSE", Kind::Short),
        text("TSEL", Kind::Link),
        text("ASG", Kind::Str(29)),
        menu("UDFS", &menus::MENU_ALARM_SEVR, 3),
        number("LCNT", Kind::UChar),
        number("PUTF", Kind::UChar),
        number("RPRO", Kind::UChar),
        menu("NSEV", &menus::MENU_ALARM_SEVR, 0),
        menu("NSTA", &menus::MENU_ALARM_STAT, 0),
        // The motor record sets no alarm message (it raises alarms by recGblSetSevr).
        text("AMSG", Kind::Str(40)),
        text("NAMSG", Kind::Str(40)),
        number("PACT", Kind::UChar),
        // DBF_UINT64, served as a DBR_DOUBLE as an IOC serves it.
        number("UTAG", Kind::ULong),
    ]
};

/// The unmodelled dbCommon field named `name`, if it is one.
pub fn unmodelled_common_field(name: &str) -> Option<&'static CommonField> {
    UNMODELLED_COMMON_FIELDS.iter().find(|field| field.name == name)
}

impl std::fmt::Display for Field {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floating_point_fields_show_at_prec_and_the_others_without_decimals() {
        assert_eq!((Field::RBV.precision(4), Field::VELO.precision(4), Field::VERS.precision(4)), (4, 4, 2));
        for field in [Field::RRBV, Field::RMP, Field::DMOV, Field::MSTA, Field::RCNT, Field::DIR] {
            assert_eq!(field.precision(4), 0, "{field}: recGblGetPrec gives integers and menus none");
        }
        assert_eq!(Field::RBV.precision(-1), 15, "out of 0..=15: 15");
    }

    #[test]
    fn targets_and_home_searches_start_motions_that_end_by_themselves() {
        use std::collections::BTreeSet;
        let starting: BTreeSet<Field> = Field::all().filter(|f| f.starts_motion()).collect();
        let expected =
            [Field::VAL, Field::DVAL, Field::RVAL, Field::RLV, Field::TWF, Field::TWR, Field::HOMF, Field::HOMR];
        assert_eq!(starting, expected.into_iter().collect());
    }

    #[test]
    fn table_order_matches_the_enum() {
        for (i, def) in FIELDS.iter().enumerate() {
            assert_eq!(def.field as usize, i, "{}", def.name);
        }
    }

    #[test]
    fn commands_drive_settings_configure_and_read_only_fields_take_no_write() {
        use Field::*;
        for field in [VAL, TWF, JOGR, HOMF, STOP, SPMG] {
            assert_eq!(field.write_class(), Some(WriteClass::Drive), "{field}");
        }
        for field in [HLM, DLLM, MRES, VELO, OFF, SET, FOFF, DIR, OUT] {
            assert_eq!(field.write_class(), Some(WriteClass::Configure), "{field}");
        }
        for field in [RBV, DMOV, MSTA] {
            assert_eq!(field.write_class(), None, "{field}");
        }
    }

    #[test]
    fn names_are_unique_and_exact_with_a_case_insensitive_lookup_on_request() {
        for def in FIELDS {
            assert_eq!(Field::from_name(def.name), Some(def.field));
            assert_eq!(Field::from_name_any_case(&def.name.to_lowercase()), Some(def.field));
        }
        assert_eq!(Field::from_name("val"), None);
        assert_eq!(Field::from_name("NOPE"), None);
    }

    #[test]
    fn every_manual_field_is_present() {
        // The alphabetical table of the seed manual (CBAK, an internal pointer with no access, aside).
        let manual = "ACCL ACCS ACCU ADEL ALST ATHM BACC BDST BVEL CARD CDIR CNEN DCOF DHLM DIFF DINP \
            DIR DLLM DLY DMOV DOL DRBV DVAL EGU ERES FOF FOFF FRAC HHSV HIGH HIHI HLM HLS HLSV HOMF \
            HOMR HOPR HSV HVEL ICOF IGSET INIT JAR JOGF JOGR JVEL LDVL LLM LLS LLSV LOCK LOLO LOPR LOW \
            LRLV LRVL LSPG LSV LVAL LVIO MDEL MLST MIP MISS MMAP MOVN MRES MSTA NMAP NTM NTMF OFF OMSL \
            OUT PCOF PERL POST PP PREC PREM RBV RCNT RDBD RDBL RDIF REP RHLM RHLS RINP RLLM RLLS RLNK \
            RLV RMOD RMP RRBV RRES RSTM RTRY RVAL RVEL S SBAK SBAS SET SMAX SPDB SPMG SREV SSET STOO \
            STOP STUP SUSE SYNC TDIR TWF TWR TWV UEIP UREV URIP VAL VBAS VELO VERS VMAX VOF";
        for name in manual.split_whitespace() {
            assert!(Field::from_name(name).is_some(), "{name} missing from the catalogue");
        }
    }

    #[test]
    fn autosave_keeps_positions_and_settings_but_no_command() {
        assert_eq!(Field::DVAL.autosave(), Some(Autosave::Position));
        assert_eq!(Field::VELO.autosave(), Some(Autosave::Setting));
        assert_eq!(Field::RSTM.autosave(), Some(Autosave::Setting));
        // motor_settings.req keeps the motor's `_able` record, whose value an IOC writes to DISP.
        assert_eq!(Field::DISP.autosave(), Some(Autosave::Setting));
        for field in [Field::VAL, Field::HOMF, Field::SPMG, Field::RBV, Field::DMOV, Field::SET] {
            assert_eq!(field.autosave(), None, "{field}");
        }
    }

    #[test]
    fn defaults_follow_the_dbd() {
        let f = Fields::default();
        assert_eq!((f.dmov, f.lvio, f.srev, f.rtry, f.ntmf), (1, 1, 200, 10, 2));
        assert_eq!((f.accl, f.bacc, f.frac), (0.2, 0.5, 1.0));
        assert_eq!((f.spmg, f.lspg, f.ntm, f.rstm), (3, 3, 1, 2));
        assert_eq!(Field::SPMG.def().default_value(), Value::Int(3));
    }
}
