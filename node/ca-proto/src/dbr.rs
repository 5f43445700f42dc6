//! The DBR encodings of a value: plain, with alarm (STS), with time (TIME), with display
//! metadata (GR) and with control limits (CTRL), for each of the seven base types, as
//! `db_access.h` lays them out; and the decoding of a client's write into the text a zmotor
//! node takes.

use zmotor_msgs::{Kind, Value};

/// Seconds from the POSIX epoch to the EPICS epoch (1990-01-01).
pub(crate) const EPICS_EPOCH_OFFSET: u64 = 631_152_000;

/// Length of a DBR_STRING, its NUL included.
pub(crate) const STRING_SIZE: usize = 40;

/// The base types, by their DBR code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Base {
    /// DBR_STRING (0)
    String,
    /// DBR_SHORT (1)
    Short,
    /// DBR_FLOAT (2)
    Float,
    /// DBR_ENUM (3)
    Enum,
    /// DBR_CHAR (4)
    Char,
    /// DBR_LONG (5)
    Long,
    /// DBR_DOUBLE (6)
    Double,
}

impl Base {
    const ALL: [Base; 7] = [Base::String, Base::Short, Base::Float, Base::Enum, Base::Char, Base::Long, Base::Double];

    /// The DBR code.
    pub fn code(self) -> u16 {
        Self::ALL.iter().position(|b| *b == self).unwrap_or(0) as u16
    }

    /// The type a channel of a field of this kind has.
    pub fn native(kind: Kind) -> Base {
        match kind {
            Kind::Double | Kind::ULong => Base::Double,
            Kind::Float => Base::Float,
            Kind::Long | Kind::UShort => Base::Long,
            Kind::Short => Base::Short,
            Kind::UChar => Base::Char,
            Kind::Menu(_) => Base::Enum,
            Kind::Str(_) | Kind::Link => Base::String,
        }
    }
}

/// What a DBR type adds to the value (in order: each adds to the one before).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Class {
    /// The value alone.
    Plain,
    /// Alarm status and severity.
    Status,
    /// Alarm and time stamp.
    Time,
    /// Alarm, units, precision and display limits.
    Graphic,
    /// The same and control limits.
    Control,
}

/// A DBR type a client asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DbrType {
    /// Its base type.
    pub base: Base,
    /// Its class.
    pub class: Class,
}

/// DBR_PUT_ACKT: a write of whether transient alarms are held for acknowledgement.
pub(crate) const DBR_PUT_ACKT: u16 = 35;
/// DBR_PUT_ACKS: a write acknowledging alarms up to a severity.
pub(crate) const DBR_PUT_ACKS: u16 = 36;
/// DBR_STSACK_STRING: alarm, acknowledgement and the value as text.
pub(crate) const DBR_STSACK_STRING: u16 = 37;
/// DBR_CLASS_NAME: the record type's name.
pub(crate) const DBR_CLASS_NAME: u16 = 38;

impl DbrType {
    /// The type of a DBR code from 0 to 34; others are served apart (or refused).
    pub fn from_code(code: u16) -> Option<Self> {
        let class =
            [Class::Plain, Class::Status, Class::Time, Class::Graphic, Class::Control].get(usize::from(code / 7))?;
        Some(Self { base: Base::ALL[usize::from(code % 7)], class: *class })
    }
}

/// A time stamp in the EPICS epoch.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stamp {
    /// Seconds since 1990-01-01 UTC.
    pub seconds: u32,
    /// Nanoseconds within the second.
    pub nanoseconds: u32,
}

impl Stamp {
    /// The stamp of a time given as seconds and nanoseconds since the POSIX epoch.
    pub fn from_posix(seconds: u64, nanoseconds: u32) -> Self {
        Self { seconds: seconds.saturating_sub(EPICS_EPOCH_OFFSET) as u32, nanoseconds }
    }
}

/// What a channel shows: the value and everything the DBR classes add to it.
#[derive(Clone, Debug, PartialEq)]
pub struct Snapshot {
    /// The value.
    pub value: Value,
    /// The channel's native type.
    pub native: Base,
    /// Alarm status (menuAlarmStat index).
    pub status: u16,
    /// Alarm severity (menuAlarmSevr index).
    pub severity: u16,
    /// Whether transient alarms are held for acknowledgement (ACKT) and the severity to
    /// acknowledge (ACKS), as DBR_STSACK_STRING carries them.
    pub acknowledgement: (u16, u16),
    /// When the value arrived.
    pub stamp: Stamp,
    /// Engineering units.
    pub units: String,
    /// Display precision.
    pub precision: i16,
    /// Upper display and control limit.
    pub upper: f64,
    /// Lower display and control limit.
    pub lower: f64,
    /// Alarm limits: upper alarm, upper warning, lower warning, lower alarm (NaN: none).
    pub alarm: [f64; 4],
    /// The choices of a menu field.
    pub choices: &'static [&'static str],
}

impl Snapshot {
    fn number(&self) -> f64 {
        match &self.value {
            Value::Int(i) => *i as f64,
            Value::Float(x) => *x,
            Value::Text(text) => text.trim().parse().unwrap_or(0.0),
        }
    }

    /// The value as DBR_STRING text: a menu's choice, a number at the channel's precision.
    pub fn text(&self) -> String {
        match (&self.value, self.native) {
            (Value::Int(i), Base::Enum) => usize::try_from(*i)
                .ok()
                .and_then(|i| self.choices.get(i))
                .map_or_else(|| i.to_string(), |c| c.to_string()),
            // A negative precision is a large one to the IOC's unsigned conversion.
            (Value::Float(x), _) => double_text(*x, self.precision as u16),
            (value, _) => value.to_string(),
        }
    }

    /// Whether this is text in a character array (a long string), not a number of a DBF_UCHAR.
    fn is_characters(&self) -> bool {
        self.native == Base::Char && matches!(self.value, Value::Text(_))
    }

    /// How many elements a reply of this snapshot carries when `requested` were asked for (0:
    /// as many as there are, CA's dynamic arrays) as `base` of a channel of `count` elements:
    /// the text of a character array and its NUL, or the requested part of it, read as
    /// characters; one of anything else (a character array read as a string is its text).
    pub fn elements(&self, base: Base, requested: u32, count: u32) -> u32 {
        if count <= 1 || !self.is_characters() || base != Base::Char {
            return 1;
        }
        let used = u32::try_from(self.text().len() + 1).unwrap_or(u32::MAX).min(count);
        if requested == 0 {
            used
        } else {
            requested.min(count)
        }
    }

    /// The DBR encoding of this snapshot as `dbr`, `elements` of it (more than one only for a
    /// character array, its text NUL-padded).
    pub fn encode(&self, dbr: DbrType, elements: u32) -> Vec<u8> {
        let mut out = Writer::default();
        if dbr.class != Class::Plain {
            out.u16(self.status);
            out.u16(self.severity);
        }
        match (dbr.class, dbr.base) {
            (Class::Plain, _) => {}
            (Class::Status, Base::Char) => out.pad(1),
            (Class::Status, Base::Double) => out.pad(4),
            (Class::Status, _) => {}
            (Class::Time, base) => {
                out.u32(self.stamp.seconds);
                out.u32(self.stamp.nanoseconds);
                match base {
                    Base::Short | Base::Enum => out.pad(2),
                    Base::Char => out.pad(3),
                    Base::Double => out.pad(4),
                    Base::String | Base::Float | Base::Long => {}
                }
            }
            (Class::Graphic | Class::Control, Base::String) => {}
            (Class::Graphic | Class::Control, Base::Enum) => {
                let choices = &self.choices[..self.choices.len().min(16)];
                out.u16(choices.len() as u16);
                for index in 0..16 {
                    out.fixed_text(choices.get(index).copied().unwrap_or(""), 26);
                }
            }
            (class, base) => {
                if matches!(base, Base::Float | Base::Double) {
                    out.u16(self.precision as u16);
                    out.pad(2);
                }
                out.fixed_text(&self.units, 8);
                // Display limits, then the alarm limits, then the control limits.
                let mut limits = vec![self.upper, self.lower];
                limits.extend(self.alarm);
                if class == Class::Control {
                    limits.extend([self.upper, self.lower]);
                }
                for limit in limits {
                    out.number(base, limit);
                }
                if base == Base::Char {
                    out.pad(1);
                }
            }
        }
        match dbr.base {
            Base::String => out.fixed_text(&self.text(), STRING_SIZE),
            Base::Char if self.is_characters() => out.characters(&self.text(), elements as usize),
            Base::Enum => out.u16(self.number().clamp(0.0, f64::from(u16::MAX)) as u16),
            base => out.number(base, self.number()),
        }
        out.0
    }
}

/// Big-endian output.
#[derive(Default)]
struct Writer(Vec<u8>);

impl Writer {
    fn u16(&mut self, value: u16) {
        self.0.extend_from_slice(&value.to_be_bytes());
    }

    fn u32(&mut self, value: u32) {
        self.0.extend_from_slice(&value.to_be_bytes());
    }

    fn pad(&mut self, bytes: usize) {
        self.0.resize(self.0.len() + bytes, 0);
    }

    /// Text in a fixed field: truncated to leave a NUL, padded with NULs.
    fn fixed_text(&mut self, text: &str, size: usize) {
        let bytes = text.as_bytes();
        let used = bytes.len().min(size - 1);
        self.0.extend_from_slice(&bytes[..used]);
        self.pad(size - used);
    }

    /// The first `count` characters of `text`, NUL-padded to `count` (no NUL when it fills them).
    fn characters(&mut self, text: &str, count: usize) {
        let bytes = &text.as_bytes()[..text.len().min(count)];
        self.0.extend_from_slice(bytes);
        self.pad(count - bytes.len());
    }

    /// A number in a numeric base type: toward zero into an integer, as an IOC's conversion
    /// (a C cast: 2.7 reads 2), saturating where it does not fit.
    fn number(&mut self, base: Base, value: f64) {
        match base {
            Base::Short => self.0.extend_from_slice(&(value as i16).to_be_bytes()),
            Base::Float => self.0.extend_from_slice(&(value as f32).to_be_bytes()),
            Base::Char => self.0.push(value as u8),
            Base::Long => self.0.extend_from_slice(&(value as i32).to_be_bytes()),
            Base::Double => self.0.extend_from_slice(&value.to_be_bytes()),
            Base::Enum => self.u16(value as u16),
            Base::String => self.fixed_text(&value.to_string(), STRING_SIZE),
        }
    }
}

/// A write a client sent that cannot be read.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub(crate) enum WriteError {
    /// The DBR type is not one a value is written as.
    #[error("DBR type {0} is not a type a value is written as")]
    BadType(u16),
    /// The payload is shorter than one element.
    #[error("a {0:?} write needs {1} bytes, {2} came")]
    Short(Base, usize, usize),
}

/// The first element of a client's write to a channel of type `native`, as the text a zmotor
/// node takes (a number, a menu index or choice, a string). A finite floating-point value to an
/// integer or menu channel is cut toward zero, as an IOC's dbPut converts it (a C cast: 2.7 is 2).
pub(crate) fn written_text(data_type: u16, payload: &[u8], native: Base) -> Result<String, WriteError> {
    let dbr =
        DbrType::from_code(data_type).filter(|d| d.class == Class::Plain).ok_or(WriteError::BadType(data_type))?;
    let size = match dbr.base {
        Base::String => 1,
        Base::Char => 1,
        Base::Short | Base::Enum => 2,
        Base::Float | Base::Long => 4,
        Base::Double => 8,
    };
    if payload.len() < size {
        return Err(WriteError::Short(dbr.base, size, payload.len()));
    }
    let be = |n: usize| -> [u8; 8] {
        let mut bytes = [0; 8];
        bytes[..n].copy_from_slice(&payload[..n]);
        bytes
    };
    Ok(match dbr.base {
        Base::String => crate::codec::text(&payload[..payload.len().min(STRING_SIZE)]),
        Base::Char => payload[0].to_string(),
        Base::Short => i16::from_be_bytes([payload[0], payload[1]]).to_string(),
        Base::Enum => u16::from_be_bytes([payload[0], payload[1]]).to_string(),
        Base::Float => {
            let value = f32::from_be_bytes(be(4)[..4].try_into().expect("four bytes"));
            cut(value.into(), native).unwrap_or_else(|| value.to_string())
        }
        Base::Long => i32::from_be_bytes(be(4)[..4].try_into().expect("four bytes")).to_string(),
        Base::Double => {
            let value = f64::from_be_bytes(be(8));
            cut(value, native).unwrap_or_else(|| value.to_string())
        }
    })
}

/// A double as an IOC's DBR_STRING gives it (EPICS base's `cvtDoubleToString`, which
/// dbConvert calls with the record's precision): up to ±1e7 with at most 8 decimals, digits
/// rounded half up from the first digit beyond; beyond, at most 3 decimals; beyond ±1e16 or
/// with more than 8 decimals, C's `%e` (at most 17 digits, right-aligned to the precision + 7).
fn double_text(value: f64, precision: u16) -> String {
    if value.is_nan() || precision > 8 || value.abs() > 1e7 {
        if precision > 8 || value.abs() > 1e16 {
            let precision = usize::from(precision.min(17));
            return format!("{:>width$}", c_exponent(value, precision), width = precision + 7);
        }
        if value.is_nan() {
            return "nan".into();
        }
        return format!("{value:.*}", usize::from(precision.min(3)));
    }
    let sign = if value < 0.0 { "-" } else { "" };
    let magnitude = value.abs();
    // Whole part and the decimals as the C code cuts them: truncated one digit further, then
    // rounded half up (2.5 at precision 0 is 3, not 2).
    let mut whole = magnitude.trunc() as i64;
    let scale = 10_i64.pow(u32::from(precision));
    let mut fraction = (((magnitude - whole as f64) * scale as f64 * 10.0) as i64 + 5) / 10;
    if fraction >= scale {
        whole += 1;
        fraction -= scale;
    }
    match precision {
        0 => format!("{sign}{whole}"),
        digits => format!("{sign}{whole}.{fraction:0digits$}", digits = usize::from(digits)),
    }
}

/// C's `%.*e`: the exponent signed, of at least two digits (`1.500e+20`, `inf`).
fn c_exponent(value: f64, precision: usize) -> String {
    if value.is_nan() {
        return "nan".into();
    }
    if value.is_infinite() {
        return if value < 0.0 { "-inf" } else { "inf" }.into();
    }
    let text = format!("{value:.precision$e}");
    let (mantissa, exponent) = text.split_once('e').unwrap_or((&text, "0"));
    let (sign, digits) = exponent.strip_prefix('-').map_or(('+', exponent), |d| ('-', d));
    format!("{mantissa}e{sign}{digits:0>2}")
}

/// A finite floating-point value written to an integer or menu channel, cut toward zero, as text
/// (what is out of the field's range the node refuses, saying so).
fn cut(value: f64, native: Base) -> Option<String> {
    let integer = matches!(native, Base::Char | Base::Short | Base::Long | Base::Enum);
    (integer && value.is_finite()).then(|| (value.trunc() as i64).to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn snapshot(value: Value, native: Base) -> Snapshot {
        Snapshot {
            value,
            native,
            status: 0,
            severity: 0,
            acknowledgement: (1, 0),
            stamp: Stamp::from_posix(EPICS_EPOCH_OFFSET + 10, 5),
            units: "mm".into(),
            precision: 3,
            upper: 100.0,
            lower: -100.0,
            alarm: [f64::NAN; 4],
            choices: &["Stop", "Pause", "Move", "Go"],
        }
    }

    /// The sizes of db_access.h's structures (dbr_size[]), before padding to 8.
    #[test]
    fn every_class_has_the_size_of_its_c_structure() {
        let sizes: [(u16, usize); 20] = [
            (0, 40),
            (5, 4),
            (6, 8),
            (7, 44),
            (10, 6),
            (13, 16),
            (14, 52),
            (15, 16),
            (17, 16),
            (18, 16),
            (19, 16),
            (20, 24),
            (21, 44),
            (22, 26),
            (24, 424),
            (27, 72),
            (28, 44),
            (29, 30),
            (33, 48),
            (34, 88),
        ];
        for (code, size) in sizes {
            let dbr = DbrType::from_code(code).unwrap();
            let native = if dbr.base == Base::Enum { Base::Enum } else { Base::Double };
            let value = if native == Base::Enum { Value::Int(3) } else { Value::Float(1.5) };
            assert_eq!(snapshot(value, native).encode(dbr, 1).len(), size, "DBR type {code}");
        }
    }

    #[test]
    fn a_ctrl_double_carries_units_precision_limits_and_value() {
        let bytes = snapshot(Value::Float(2.5), Base::Double).encode(DbrType::from_code(34).unwrap(), 1);
        assert_eq!(i16::from_be_bytes([bytes[4], bytes[5]]), 3, "precision");
        assert_eq!(&bytes[8..10], b"mm");
        assert_eq!(f64::from_be_bytes(bytes[16..24].try_into().unwrap()), 100.0, "upper display");
        assert!(f64::from_be_bytes(bytes[32..40].try_into().unwrap()).is_nan(), "no upper alarm limit");
        assert_eq!(f64::from_be_bytes(bytes[64..72].try_into().unwrap()), 100.0, "upper control");
        assert_eq!(f64::from_be_bytes(bytes[72..80].try_into().unwrap()), -100.0, "lower control");
        assert_eq!(f64::from_be_bytes(bytes[80..88].try_into().unwrap()), 2.5);
    }

    #[test]
    fn a_time_double_carries_the_epics_stamp() {
        let bytes = snapshot(Value::Float(2.5), Base::Double).encode(DbrType::from_code(20).unwrap(), 1);
        assert_eq!(u32::from_be_bytes(bytes[4..8].try_into().unwrap()), 10);
        assert_eq!(u32::from_be_bytes(bytes[8..12].try_into().unwrap()), 5);
        assert_eq!(f64::from_be_bytes(bytes[16..24].try_into().unwrap()), 2.5);
    }

    #[test]
    fn menus_read_as_their_choices_and_numbers_at_their_precision() {
        let menu = snapshot(Value::Int(3), Base::Enum);
        assert_eq!(&menu.encode(DbrType::from_code(0).unwrap(), 1)[..3], b"Go\0");
        let ctrl = menu.encode(DbrType::from_code(31).unwrap(), 1);
        assert_eq!(i16::from_be_bytes([ctrl[4], ctrl[5]]), 4, "four choices");
        assert_eq!(&ctrl[6 + 26..6 + 26 + 5], b"Pause");
        assert_eq!(u16::from_be_bytes([ctrl[422], ctrl[423]]), 3);
        assert_eq!(snapshot(Value::Float(2.5), Base::Double).text(), "2.500");
    }

    #[test]
    fn channels_have_the_native_types_of_an_ioc() {
        use zmotor_msgs::Field;
        let native = |field: Field| Base::native(field.def().kind);
        // dbCommon's flags are DBF_UCHAR: DBR_CHAR to cainfo and to clients that ask natively.
        assert_eq!([native(Field::DISP), native(Field::PROC), native(Field::UDF)], [Base::Char; 3]);
        assert_eq!([native(Field::DMOV), native(Field::JOGF)], [Base::Short; 2]);
        assert_eq!([native(Field::VAL), native(Field::MSTA)], [Base::Double; 2]);
        assert_eq!([native(Field::SPMG), native(Field::RMP)], [Base::Enum, Base::Long]);
        let disabled = snapshot(Value::Int(1), Base::Char);
        assert_eq!(disabled.elements(Base::Char, 0, 1), 1);
        assert_eq!(disabled.encode(DbrType::from_code(4).unwrap(), 1), [1], "the number, not the character '1'");
        assert_eq!(&disabled.encode(DbrType::from_code(0).unwrap(), 1)[..2], b"1\0");
    }

    #[test]
    fn doubles_read_as_strings_as_cvt_double_to_string_writes_them() {
        let cases: [(f64, u16, &str); 17] = [
            (2.5, 3, "2.500"),
            (-1.23456, 4, "-1.2346"),
            (2.5, 0, "3"),
            (0.0005, 3, "0.001"),
            (-0.0001, 3, "-0.000"),
            (9_999_999.99, 1, "10000000.0"),
            (12_345_678.9, 5, "12345678.900"),
            (-12_345_678.9, 1, "-12345678.9"),
            (1.5, 9, " 1.500000000e+00"),
            (1.5e20, 3, " 1.500e+20"),
            (-1.5e-5, 10, "-1.5000000000e-05"),
            (1.0, 20, " 1.00000000000000000e+00"),
            (f64::INFINITY, 2, "      inf"),
            (f64::NEG_INFINITY, 2, "     -inf"),
            (f64::NAN, 2, "nan"),
            (f64::NAN, 9, "             nan"),
            (1e7, 8, "10000000.00000000"),
        ];
        for (value, precision, text) in cases {
            assert_eq!(double_text(value, precision), text, "{value} at precision {precision}");
        }
    }

    #[test]
    fn a_message_reads_in_full_as_a_character_array_and_cut_as_a_string() {
        let long = "c884: not referenced: home the axis first (HOMF or HOMR)";
        let chars = snapshot(Value::Text(long.into()), Base::Char);
        let dynamic = chars.elements(Base::Char, 0, 512);
        assert_eq!(dynamic as usize, long.len() + 1, "the text and its NUL");
        let bytes = chars.encode(DbrType::from_code(4).unwrap(), dynamic);
        assert_eq!((&bytes[..long.len()], bytes[long.len()]), (long.as_bytes(), 0));
        assert_eq!(chars.elements(Base::Char, 10, 512), 10, "as many as asked for");
        assert_eq!(&chars.encode(DbrType::from_code(4).unwrap(), 10), &long.as_bytes()[..10]);
        assert_eq!(chars.encode(DbrType::from_code(4).unwrap(), 1), b"c", "the first character");
        assert_eq!(chars.elements(Base::Char, 4096, 512), 512, "no more than the channel has");
        // Read as anything but characters, one element: its header's count is what it carries.
        for code in [0, 1, 2, 5, 6, 14, 20] {
            let dbr = DbrType::from_code(code).unwrap();
            assert_eq!(chars.elements(dbr.base, 0, 512), 1, "DBR type {code}");
            let plain = DbrType { class: Class::Plain, ..dbr };
            assert_eq!(chars.encode(plain, 1).len(), snapshot(Value::Int(0), Base::Long).encode(plain, 1).len());
        }
        let time = chars.encode(DbrType::from_code(18).unwrap(), 512);
        assert_eq!(time.len(), 12 + 3 + 512, "alarm, stamp, padding, then the characters");
        let string = snapshot(Value::Text(long.into()), Base::String).encode(DbrType::from_code(0).unwrap(), 1);
        assert_eq!((&string[..39], string.len()), (&long.as_bytes()[..39], 40));
    }

    #[test]
    fn a_double_read_as_an_integer_is_cut_toward_zero_as_an_ioc_converts_it() {
        let read =
            |x: f64, code: u16| snapshot(Value::Float(x), Base::Double).encode(DbrType::from_code(code).unwrap(), 1);
        assert_eq!(read(2.7, 5), 2i32.to_be_bytes(), "DBR_LONG");
        assert_eq!(read(-2.7, 1), (-2i16).to_be_bytes(), "DBR_SHORT");
        assert_eq!(read(2.7, 4), [2], "DBR_CHAR");
        assert_eq!(read(1e12, 5), i32::MAX.to_be_bytes(), "saturated");
    }

    #[test]
    fn writes_become_the_text_a_node_takes() {
        assert_eq!(written_text(6, &2.5f64.to_be_bytes(), Base::Double), Ok("2.5".into()));
        assert_eq!(written_text(3, &[0, 2], Base::Enum), Ok("2".into()));
        assert_eq!(written_text(0, b"Go\0\0\0\0\0\0", Base::Enum), Ok("Go".into()));
        assert_eq!(written_text(5, &(-7i32).to_be_bytes(), Base::Long), Ok("-7".into()));
        assert_eq!(written_text(20, &[0; 24], Base::Double), Err(WriteError::BadType(20)));
        assert_eq!(written_text(6, &[0; 4], Base::Double), Err(WriteError::Short(Base::Double, 8, 4)));
        // To an integer or a menu, as dbPut's C cast: toward zero; NaN is left for the node to refuse.
        assert_eq!(written_text(6, &2.7f64.to_be_bytes(), Base::Short), Ok("2".into()));
        assert_eq!(written_text(2, &(-2.7f32).to_be_bytes(), Base::Enum), Ok("-2".into()));
        assert_eq!(written_text(6, &f64::NAN.to_be_bytes(), Base::Long), Ok("NaN".into()));
        assert_eq!(written_text(2, &0.1f32.to_be_bytes(), Base::Float), Ok("0.1".into()));
    }
}
