//! Channel names: `<P><axis>` is the axis's VAL, `<P><axis>.<FIELD>` any field of the
//! catalogue, `<P><axis>.RTYP` the record type (`motor`), and `<P><axis>.ERR` the axis's last
//! message (its ERR key: a refused write, a controller's error), as a DBR_STRING of 39
//! characters or, as EPICS serves long strings, in full as a character array with a `$`
//! appended to the name (`.ERR$`; `caget -S`). `<P><axis>_able` is the Enable/Disable record
//! motor's databases put beside each motor (a bo whose OUT writes the motor's DISP, which
//! motor screens and pyepics's `Motor.disabled` use): the axis's DISP as a menu of two choices.
//! The dbCommon fields zmotor does not model (SCAN, PINI, PRIO, ...) read as an IOC's motor
//! record holds them by default, and take no write. A name that is no live axis's may be a
//! bridge record's (`BridgeRecord`: a value holder as an ao, a calc link's result as a calc):
//! `<P><record>` and `.VAL` its value, `.RTYP` its type (`directory::resolve`).

use crate::dbr::Base;
use zmotor_msgs::menus::Menu;
use zmotor_msgs::{keys, unmodelled_common_field, Access, BridgeRecord, CommonField, Field, Kind};

/// The choices of `<P><axis>_able` (its bo's ZNAM and ONAM in motor's asyn_motor.db).
pub const ABLE: Menu = Menu { name: "able", choices: &["Enable", "Disable"] };

/// What a motor's Enable/Disable record's name adds to the motor's.
pub(crate) const ABLE_SUFFIX: &str = "_able";

/// What a channel shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Target {
    /// A field of the catalogue.
    Field(Field),
    /// `.RTYP`: the record type, `motor`.
    RecordType,
    /// `.ERR`: the last message, as a DBR_STRING (cut at 39 characters).
    Message,
    /// `.ERR$`: the last message in full, as a character array.
    MessageChars,
    /// `<axis>_able` (its VAL): DISP, as the menu `ABLE`.
    Able,
    /// A dbCommon field zmotor does not model, by name: its default, read-only.
    Common(&'static str),
    /// `.<FIELD>$` of a string or link field: its text in full, as a character array (an IOC's
    /// long-string channel; a link's key may be longer than a DBR_STRING's 39 characters).
    FieldChars(Field),
    /// A bridge record's value (its VAL), the record being of this kind.
    BridgeValue(BridgeRecord),
    /// A bridge record's `.RTYP`.
    BridgeType(BridgeRecord),
}

impl Target {
    /// The unmodelled dbCommon field it is, if it is one.
    pub fn common(self) -> Option<&'static CommonField> {
        match self {
            Target::Common(name) => unmodelled_common_field(name),
            _ => None,
        }
    }
}

/// The length of `.ERR$`, in characters, its NUL included: a message beyond is cut.
pub const MESSAGE_CHARS: u32 = 512;

/// The length of a link's `$` channel, as an IOC's (PVLINK_STRINGSZ).
const LINK_CHARS: u32 = 1024;

/// A channel of an axis.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct Pv {
    /// The axis.
    pub axis: String,
    /// What of it.
    pub target: Target,
}

impl Pv {
    /// The channel a name asks for under `prefix`, if it is one (field names are exact, as
    /// EPICS spells them).
    pub fn parse(prefix: &str, name: &str) -> Option<Pv> {
        let rest = name.strip_prefix(prefix)?;
        let (record, field) = rest.split_once('.').unwrap_or((rest, "VAL"));
        if let Some(axis) = record.strip_suffix(ABLE_SUFFIX).filter(|_| field == "VAL") {
            keys::validate_axis_name(axis).ok()?;
            return Some(Pv { axis: axis.to_string(), target: Target::Able });
        }
        let axis = record;
        keys::validate_axis_name(axis).ok()?;
        let target = match field {
            "RTYP" => Target::RecordType,
            keys::ERR_KEY => Target::Message,
            "ERR$" => Target::MessageChars,
            name => match (Field::from_name(name), name.strip_suffix('$').and_then(Field::from_name)) {
                (Some(field), _) => Target::Field(field),
                (None, Some(field)) if matches!(field.def().kind, Kind::Str(_) | Kind::Link) => {
                    Target::FieldChars(field)
                }
                _ => Target::Common(unmodelled_common_field(name)?.name),
            },
        };
        Some(Pv { axis: axis.to_string(), target })
    }

    /// Whether it has the motor record's alarm (an `_able` or a bridge record has none to
    /// acknowledge here).
    pub fn has_motor_alarm(&self) -> bool {
        !matches!(self.target, Target::Able | Target::BridgeValue(_) | Target::BridgeType(_))
    }

    /// Its full name under `prefix`.
    pub fn name(&self, prefix: &str) -> String {
        match self.target {
            Target::Field(field) => format!("{prefix}{}.{}", self.axis, field.name()),
            Target::RecordType => format!("{prefix}{}.RTYP", self.axis),
            Target::Message => format!("{prefix}{}.{}", self.axis, keys::ERR_KEY),
            Target::MessageChars => format!("{prefix}{}.{}$", self.axis, keys::ERR_KEY),
            Target::Able => format!("{prefix}{}{ABLE_SUFFIX}", self.axis),
            Target::Common(name) => format!("{prefix}{}.{name}", self.axis),
            Target::FieldChars(field) => format!("{prefix}{}.{}$", self.axis, field.name()),
            Target::BridgeValue(_) => format!("{prefix}{}.VAL", self.axis),
            Target::BridgeType(_) => format!("{prefix}{}.RTYP", self.axis),
        }
    }

    /// The type of the record it belongs to (DBR_CLASS_NAME): `_able` is a bo record of the
    /// motor's databases, a bridge record is of its own type; every other channel is of the
    /// motor record.
    pub fn record_type(&self) -> &'static str {
        match self.target {
            Target::Able => "bo",
            Target::BridgeValue(kind) | Target::BridgeType(kind) => kind.record_type(),
            _ => "motor",
        }
    }

    /// Its element count: a message in full has `MESSAGE_CHARS`, a string field's `$` channel
    /// the field's size, a link's `LINK_CHARS`; everything else one.
    pub fn count(&self) -> u32 {
        match self.target {
            Target::MessageChars => MESSAGE_CHARS,
            Target::FieldChars(field) => match field.def().kind {
                Kind::Str(size) => u32::try_from(size).unwrap_or(LINK_CHARS),
                _ => LINK_CHARS,
            },
            _ => 1,
        }
    }

    /// Whether a client may write it.
    pub fn writable(&self) -> bool {
        match self.target {
            Target::Field(field) if field.acknowledges_alarms() => false,
            Target::Field(field) | Target::FieldChars(field) => field.def().access != Access::RO,
            Target::Able | Target::BridgeValue(BridgeRecord::Value) => true,
            Target::RecordType
            | Target::Message
            | Target::MessageChars
            | Target::Common(_)
            | Target::BridgeValue(BridgeRecord::Calc)
            | Target::BridgeType(_) => false,
        }
    }

    /// The field a write to it writes, and what it writes there: DISP for `_able`, its choice
    /// names taken as their indexes (a bo's), as a value the node reads; text longer than a
    /// string field holds cut to fit, as an IOC's dbPut copies it (the node refuses it whole).
    pub fn written(&self, text: String) -> Option<(Field, String)> {
        match self.target {
            Target::Field(field) | Target::FieldChars(field) => match field.def().kind {
                Kind::Str(size) => Some((field, cut_to(text, size - 1))),
                _ => Some((field, text)),
            },
            Target::Able => Some((Field::DISP, ABLE.index_of(&text).map_or(text, |index| index.to_string()))),
            Target::RecordType
            | Target::Message
            | Target::MessageChars
            | Target::Common(_)
            | Target::BridgeValue(_)
            | Target::BridgeType(_) => None,
        }
    }

    /// Whether a change of `changed` changes its value: its own, the message for `.ERR$`, DISP
    /// for `_able`.
    pub fn shows(&self, changed: Target) -> bool {
        changed == self.target
            || matches!(
                (changed, self.target),
                (Target::Message, Target::MessageChars) | (Target::Field(Field::DISP), Target::Able)
            )
            || matches!((changed, self.target), (Target::Field(a), Target::FieldChars(b)) if a == b)
            || matches!((changed, self.target), (Target::BridgeValue(_), Target::BridgeValue(_)))
    }

    /// Its native DBR type.
    pub fn native(&self) -> Base {
        match self.target {
            Target::Field(field) => Base::native(field.def().kind),
            Target::RecordType | Target::Message | Target::BridgeType(_) => Base::String,
            Target::BridgeValue(_) => Base::Double,
            Target::MessageChars | Target::FieldChars(_) => Base::Char,
            Target::Able => Base::Enum,
            Target::Common(_) => self.target.common().map_or(Base::String, |common| Base::native(common.kind)),
        }
    }

    /// Where its display and control limits come from, as the motor record's get_graphic_double
    /// and get_control_double give them (spec §17).
    pub fn limits(&self) -> Limits {
        use Field::*;
        match self.target {
            Target::Field(VAL | RBV) => Limits::Fields(HLM, LLM),
            Target::Field(DVAL | DRBV) => Limits::Fields(DHLM, DLLM),
            Target::Field(RVAL | RRBV) => Limits::RawDial,
            Target::Field(VELO) => Limits::Fields(VMAX, VBAS),
            Target::Field(field) => Limits::Range(field.def().kind.default_range()),
            Target::Able => Limits::Range((1.0, 0.0)),
            Target::Common(_) => Limits::Range(self.target.common().map_or((0.0, 0.0), |c| c.kind.default_range())),
            // An ao's HOPR and LOPR, a calc's, by default.
            Target::RecordType
            | Target::Message
            | Target::MessageChars
            | Target::FieldChars(_)
            | Target::BridgeValue(_)
            | Target::BridgeType(_) => Limits::Range((0.0, 0.0)),
        }
    }

    /// The fields its alarm limits come from (upper alarm, upper warning, lower warning, lower
    /// alarm), as the motor record's get_alarm_double gives them: HIHI, HIGH, LOW, LOLO for VAL
    /// and DVAL; none for the others.
    pub fn alarm_limits(&self) -> Option<[Field; 4]> {
        use Field::*;
        matches!(self.target, Target::Field(VAL | DVAL)).then_some([HIHI, HIGH, LOW, LOLO])
    }

    /// The fields its metadata comes from: alarm, units, precision, limits.
    pub fn metadata_from(&self) -> Vec<Field> {
        let mut fields = vec![Field::STAT, Field::SEVR, Field::EGU, Field::PREC];
        match self.limits() {
            Limits::Fields(high, low) => fields.extend([high, low]),
            Limits::RawDial => fields.extend([Field::DHLM, Field::DLLM, Field::MRES]),
            Limits::Range(_) => {}
        }
        fields.extend(self.alarm_limits().into_iter().flatten());
        fields
    }

    /// Its units, given the axis's engineering units, as the motor record's get_units gives
    /// them (spec §17).
    pub fn units(&self, egu: &str) -> String {
        match self.target {
            Target::Field(field) => field.record_units(egu),
            Target::RecordType
            | Target::Message
            | Target::MessageChars
            | Target::Able
            | Target::Common(_)
            | Target::FieldChars(_)
            | Target::BridgeValue(_)
            | Target::BridgeType(_) => String::new(),
        }
    }
}

/// `text` cut to at most `bytes` bytes, at a character's boundary.
fn cut_to(mut text: String, bytes: usize) -> String {
    let end = (0..=bytes.min(text.len())).rev().find(|&i| text.is_char_boundary(i)).unwrap_or(0);
    text.truncate(end);
    text
}

/// Where a channel's display and control limits come from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Limits {
    /// Two fields of the axis: (high, low).
    Fields(Field, Field),
    /// The dial limits in steps, DHLM / MRES and DLLM / MRES, the lower one low.
    RawDial,
    /// EPICS's defaults, the range of the field's type (recGblGetGraphicDouble): (high, low).
    Range((f64, f64)),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_map_onto_axes_and_fields() {
        let pv = |name| Pv::parse("bl1:", name);
        assert_eq!(pv("bl1:m1"), Some(Pv { axis: "m1".into(), target: Target::Field(Field::VAL) }));
        assert_eq!(pv("bl1:m1.RBV").map(|p| p.target), Some(Target::Field(Field::RBV)));
        assert_eq!(pv("bl1:m1.RTYP").map(|p| p.target), Some(Target::RecordType));
        assert_eq!(pv("bl1:m1.rbv"), None, "field names are exact");
        assert_eq!(pv("bl1:m1.NOPE"), None);
        assert_eq!(pv("bl2:m1"), None);
        assert_eq!(pv("bl1:m/1"), None);
        assert_eq!(pv("bl1:m1.DVAL").unwrap().name("bl1:"), "bl1:m1.DVAL");
        let (message, whole) = (pv("bl1:m1.ERR").unwrap(), pv("bl1:m1.ERR$").unwrap());
        assert_eq!((message.target, message.native(), message.count()), (Target::Message, Base::String, 1));
        assert_eq!((whole.target, whole.native(), whole.count()), (Target::MessageChars, Base::Char, MESSAGE_CHARS));
        assert_eq!((whole.name("bl1:"), message.writable(), whole.writable()), ("bl1:m1.ERR$".into(), false, false));
        // dbCommon's unmodelled fields: their defaults, read-only.
        let scan = pv("bl1:m1.SCAN").unwrap();
        assert_eq!((scan.target, scan.native(), scan.writable()), (Target::Common("SCAN"), Base::Enum, false));
        assert_eq!((scan.name("bl1:"), scan.written("1".into())), ("bl1:m1.SCAN".into(), None));
        assert_eq!(pv("bl1:m1.TPRO").map(|p| p.native()), Some(Base::Char));
        assert_eq!(pv("bl1:m1.BKPT"), None, "DBF_NOACCESS");
        // Long strings: a string field's or a link's `$` channel, its text as characters.
        let (desc, out) = (pv("bl1:m1.DESC$").unwrap(), pv("bl1:m1.OUT$").unwrap());
        assert_eq!(
            (desc.target, desc.native(), desc.count(), desc.writable()),
            (Target::FieldChars(Field::DESC), Base::Char, 41, true)
        );
        assert_eq!((out.name("bl1:"), out.count()), ("bl1:m1.OUT$".into(), LINK_CHARS));
        assert!(out.shows(Target::Field(Field::OUT)) && !out.shows(Target::Field(Field::DESC)));
        assert_eq!(pv("bl1:m1.VAL$"), None, "a number has no long string");
        // ACKT and ACKS are written by DBR_PUT_ACKT / ACKS only.
        assert!(!pv("bl1:m1.ACKS").unwrap().writable());
    }

    #[test]
    fn text_longer_than_a_string_field_holds_is_cut_to_fit_as_an_ioc_does() {
        let egu = Pv::parse("", "m1.EGU").unwrap();
        // EGU is a DBF_STRING of 16: 15 bytes and the terminator.
        assert_eq!(egu.written("millimetres, roughly".into()), Some((Field::EGU, "millimetres, ro".into())));
        assert_eq!(egu.written("mm".into()), Some((Field::EGU, "mm".into())));
        assert_eq!(egu.written("µµµµµµµµ".into()).map(|(_, t)| t), Some("µµµµµµµ".into()), "at a character");
        let val = Pv::parse("", "m1").unwrap();
        assert_eq!(val.written("12345678901234567890".into()), Some((Field::VAL, "12345678901234567890".into())));
    }

    #[test]
    fn a_motors_able_record_is_its_disp_as_enable_or_disable() {
        let pv = |name| Pv::parse("bl1:", name);
        let able = pv("bl1:m1_able").unwrap();
        assert_eq!(pv("bl1:m1_able.VAL"), Some(able.clone()));
        assert_eq!((able.axis.as_str(), able.target, able.native()), ("m1", Target::Able, Base::Enum));
        assert_eq!((able.name("bl1:"), able.writable()), ("bl1:m1_able".into(), true));
        assert_eq!((able.record_type(), pv("bl1:m1").unwrap().record_type()), ("bo", "motor"), "DBR_CLASS_NAME");
        assert!(able.shows(Target::Field(Field::DISP)) && !able.shows(Target::Field(Field::VAL)));
        assert_eq!(able.written("Disable".into()), Some((Field::DISP, "1".into())));
        assert_eq!(able.written("enable".into()), Some((Field::DISP, "0".into())));
        assert_eq!(able.written("1".into()), Some((Field::DISP, "1".into())));
        // Another field of the name is an axis's whose name ends so.
        assert_eq!(
            pv("bl1:m1_able.RBV").map(|p| (p.axis, p.target)),
            Some(("m1_able".into(), Target::Field(Field::RBV)))
        );
        assert_eq!(pv("bl1:_able"), None, "no axis");
    }

    #[test]
    fn access_type_limits_and_units_follow_the_catalogue() {
        let pv = |name| Pv::parse("", name).unwrap();
        assert!(pv("m1").writable() && !pv("m1.RBV").writable() && !pv("m1.RTYP").writable());
        assert_eq!(
            (pv("m1").native(), pv("m1.SPMG").native(), pv("m1.DESC").native()),
            (Base::Double, Base::Enum, Base::String)
        );
        assert_eq!(
            (pv("m1.RBV").limits(), pv("m1.DRBV").limits(), pv("m1.RRBV").limits(), pv("m1.VELO").limits()),
            (
                Limits::Fields(Field::HLM, Field::LLM),
                Limits::Fields(Field::DHLM, Field::DLLM),
                Limits::RawDial,
                Limits::Fields(Field::VMAX, Field::VBAS)
            )
        );
        assert_eq!(
            (pv("m1.HLM").limits(), pv("m1.RCNT").limits(), pv("m1.DMOV").limits()),
            (Limits::Range((1e300, -1e300)), Limits::Range((32767.0, -32768.0)), Limits::Range((32767.0, -32768.0)))
        );
        let units = |name| pv(name).units("mm");
        assert_eq!(
            [units("m1.VELO"), units("m1.JAR"), units("m1.ACCL"), units("m1.S")],
            ["mm/sec", "mm/s/s", "sec", "rev/sec"]
        );
        assert_eq!(
            [units("m1.SREV"), units("m1.UREV"), units("m1.RVAL"), units("m1.SMAX")],
            ["steps/rev", "mm/rev", "mm", "mm"]
        );
        assert_eq!(pv("m1.VELO").units("a long unit name"), "a long unit nam", "15 characters");
        assert_eq!(
            (pv("m1").alarm_limits(), pv("m1.RBV").alarm_limits()),
            (Some([Field::HIHI, Field::HIGH, Field::LOW, Field::LOLO]), None)
        );
    }
}
