//! Payload codecs of the wire contract: publications are CBOR; writes are accepted as CBOR,
//! JSON or plain UTF-8 text, and are validated against the field's kind here, so a bad write
//! is refused with a message that names the field and what was wrong.

use crate::catalogue::{FieldDef, Kind};
use crate::value::Value;

/// How a write's payload is encoded (from the Zenoh encoding of the sample or query).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PayloadEncoding {
    /// `application/cbor`
    Cbor,
    /// `application/json` (or `text/json`)
    Json,
    /// UTF-8 text: `text/plain`, no encoding, or anything else.
    Text,
}

impl PayloadEncoding {
    /// The encoding's name in messages.
    pub fn name(self) -> &'static str {
        match self {
            PayloadEncoding::Cbor => "CBOR",
            PayloadEncoding::Json => "JSON",
            PayloadEncoding::Text => "text",
        }
    }

    /// Map a Zenoh encoding string ("application/cbor", "text/plain;charset=utf-8", ...).
    /// Anything that is neither CBOR nor JSON (text/plain, no encoding, zenoh/bytes) is text.
    pub fn from_mime(mime: &str) -> Self {
        let base = mime.split(';').next().unwrap_or("").trim();
        match base {
            "application/cbor" => PayloadEncoding::Cbor,
            "application/json" | "text/json" => PayloadEncoding::Json,
            _ => PayloadEncoding::Text,
        }
    }
}

/// A payload that is not one well-formed scalar (number or text) in its encoding.
#[derive(Clone, Debug, thiserror::Error, PartialEq)]
#[error("malformed {} payload: {detail}", encoding.name())]
#[non_exhaustive]
pub struct MalformedPayload {
    /// The encoding the payload claimed.
    pub encoding: PayloadEncoding,
    /// What was wrong with it.
    pub detail: String,
}

/// Why a write's payload was refused for its field; every message names the field.
#[derive(Clone, Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum CodecError {
    /// The payload does not decode in its encoding.
    #[error("{field}: malformed {encoding} payload: {detail}")]
    Malformed {
        /// The field written.
        field: &'static str,
        /// The payload's encoding, by name (`CBOR`, `JSON`, `text`).
        encoding: &'static str,
        /// What was wrong with the payload.
        detail: String,
    },
    /// Text written to a numeric field, or a fractional number to an integer field.
    #[error("{field}: wrong type: expected {expected}, got {got}")]
    WrongType {
        /// The field written.
        field: &'static str,
        /// What the field takes (e.g. "a number", "an integer").
        expected: String,
        /// What the payload held.
        got: String,
    },
    /// NaN or an infinity written to a DOUBLE or FLOAT field.
    #[error("{field}: not a number ({value}); a finite value is required")]
    NotFinite {
        /// The field written.
        field: &'static str,
        /// The value given, as text.
        value: String,
    },
    /// A finite number beyond what a FLOAT field holds (an f32).
    #[error("{field}: {value} is beyond what the field holds (a FLOAT: at most 3.4e38 either way)")]
    BeyondFloat {
        /// The field written.
        field: &'static str,
        /// The value given, as text.
        value: String,
    },
    /// An integer outside the range of the field's kind, or a menu index with no choice.
    #[error("{field}: {value} is out of range [{min}, {max}]")]
    OutOfRange {
        /// The field written.
        field: &'static str,
        /// The value given, as text.
        value: String,
        /// Smallest allowed value.
        min: i64,
        /// Largest allowed value.
        max: i64,
    },
    /// Text written to a menu field that names none of its choices.
    #[error("{field}: '{value}' is not a choice of {menu} ({choices})")]
    NotAChoice {
        /// The field written.
        field: &'static str,
        /// The text given.
        value: String,
        /// The menu's name (e.g. `motorSPMG`).
        menu: &'static str,
        /// The menu's choices, comma-separated.
        choices: String,
    },
    /// Text longer than a STRING field holds (one byte is kept for the terminator).
    #[error("{field}: text of {len} bytes is longer than the field's {max}")]
    TooLong {
        /// The field written.
        field: &'static str,
        /// Length of the text given, in bytes.
        len: usize,
        /// Longest text the field holds, in bytes.
        max: usize,
    },
}

/// Encode a published value as CBOR.
pub fn encode_cbor<T: serde::Serialize>(value: &T) -> Vec<u8> {
    let mut out = Vec::with_capacity(16);
    ciborium::into_writer(value, &mut out).expect("writing CBOR to a Vec cannot fail");
    out
}

/// Decode a published (CBOR) value.
pub fn decode_cbor_value(bytes: &[u8]) -> Result<Value, MalformedPayload> {
    decode_scalar(bytes, PayloadEncoding::Cbor)
}

/// Decode and validate a write to the field described by `def`.
pub fn decode_write(def: &FieldDef, bytes: &[u8], encoding: PayloadEncoding) -> Result<Value, CodecError> {
    let malformed =
        |e: MalformedPayload| CodecError::Malformed { field: def.name, encoding: e.encoding.name(), detail: e.detail };
    // Text written to a text field is stored as written (a description `007`, a primitive `-0`),
    // never read as a number and re-formatted; only the line end a shell adds goes.
    if encoding == PayloadEncoding::Text && matches!(def.kind, Kind::Str(_) | Kind::Link) {
        let text =
            std::str::from_utf8(bytes).map_err(|e| malformed(MalformedPayload { encoding, detail: e.to_string() }))?;
        let line = text.strip_suffix('\n').map_or(text, |t| t.strip_suffix('\r').unwrap_or(t));
        return validate(def, Value::Text(line.to_string()));
    }
    let item = match decode_item(bytes, encoding) {
        Ok(item) => item,
        // What Python's json.dumps writes for a float that is no number: not JSON, but plain in
        // meaning to a DOUBLE or FLOAT field, so the refusal says what is wrong with the value.
        Err(e) if encoding == PayloadEncoding::Json && matches!(def.kind, Kind::Double | Kind::Float) => {
            non_finite_json(bytes).ok_or_else(|| malformed(e))?
        }
        Err(e) => return Err(malformed(e)),
    };
    match item {
        Item::Scalar(value) => validate(def, value),
        // A flag is 1 or 0 to a field that takes only whole numbers (a button: JOGF, STOP) or a
        // menu of two choices (CNEN); to a position, a speed or a longer menu it is a client's
        // mistake, not a target of 1 mm or a menu's second choice.
        Item::Boolean(flag) if def.kind.takes_a_flag() => validate(def, Value::Int(i64::from(flag))),
        Item::Boolean(flag) => Err(CodecError::WrongType {
            field: def.name,
            expected: def.kind.expected().into(),
            got: format!("a boolean ({flag})"),
        }),
    }
}

/// Decode one scalar (number or text) in any accepted encoding; a CBOR or JSON boolean reads as
/// 1 or 0 (a value a link follows may be another publisher's flag).
pub fn decode_scalar(bytes: &[u8], encoding: PayloadEncoding) -> Result<Value, MalformedPayload> {
    Ok(match decode_item(bytes, encoding)? {
        Item::Scalar(value) => value,
        Item::Boolean(flag) => Value::Int(i64::from(flag)),
    })
}

/// One decoded payload item.
enum Item {
    Scalar(Value),
    Boolean(bool),
}

fn decode_item(bytes: &[u8], encoding: PayloadEncoding) -> Result<Item, MalformedPayload> {
    let malformed = |detail: String| MalformedPayload { encoding, detail };
    match encoding {
        PayloadEncoding::Cbor => {
            let mut rest = bytes;
            let v: ciborium::Value = ciborium::from_reader(&mut rest).map_err(|e| malformed(cbor_error(&e)))?;
            if !rest.is_empty() {
                return Err(malformed(format!("{} bytes after the item", rest.len())));
            }
            from_cbor(v)
                .ok_or_else(|| malformed(format!("a single number or text is required, got {}", cbor_kind(bytes))))
        }
        PayloadEncoding::Json => {
            let v: serde_json::Value = serde_json::from_slice(bytes).map_err(|e| malformed(e.to_string()))?;
            from_json(&v).ok_or_else(|| malformed(format!("a number or a string is required, got {}", json_kind(&v))))
        }
        PayloadEncoding::Text => {
            let text = std::str::from_utf8(bytes).map_err(|e| malformed(e.to_string()))?;
            Ok(Item::Scalar(from_text(text)))
        }
    }
}

/// The scalar a CBOR item holds, if it is one that fits.
fn from_cbor(v: ciborium::Value) -> Option<Item> {
    match v {
        ciborium::Value::Integer(i) => i64::try_from(i128::from(i)).ok().map(|i| Item::Scalar(Value::Int(i))),
        ciborium::Value::Float(f) => Some(Item::Scalar(Value::Float(f))),
        ciborium::Value::Text(s) => Some(Item::Scalar(Value::Text(s))),
        ciborium::Value::Bool(b) => Some(Item::Boolean(b)),
        _ => None,
    }
}

/// Why bytes are not one CBOR item, in words.
fn cbor_error(error: &ciborium::de::Error<std::io::Error>) -> String {
    use ciborium::de::Error;
    match error {
        Error::Io(_) => "the bytes end before the item does".into(),
        Error::Syntax(at) => format!("not CBOR at byte {at}"),
        Error::Semantic(Some(at), what) => format!("not a valid item at byte {at}: {what}"),
        Error::Semantic(None, what) => format!("not a valid item: {what}"),
        Error::RecursionLimitExceeded => "items nested too deeply".into(),
    }
}

/// What a CBOR payload that is not one scalar holds, in words.
fn cbor_kind(bytes: &[u8]) -> &'static str {
    match ciborium::from_reader::<ciborium::Value, _>(bytes) {
        Ok(ciborium::Value::Integer(_)) => "an integer that does not fit in 64 bits",
        Ok(ciborium::Value::Bytes(_)) => "a byte string",
        Ok(ciborium::Value::Array(_)) => "an array",
        Ok(ciborium::Value::Map(_)) => "a map",
        Ok(ciborium::Value::Null) => "null",
        Ok(ciborium::Value::Tag(..)) => "a tagged item",
        _ => "an unsupported item",
    }
}

/// `NaN`, `Infinity` or `-Infinity`, as JSON writers that allow them spell them.
fn non_finite_json(bytes: &[u8]) -> Option<Item> {
    let x = match std::str::from_utf8(bytes).ok()?.trim() {
        "NaN" => f64::NAN,
        "Infinity" => f64::INFINITY,
        "-Infinity" => f64::NEG_INFINITY,
        _ => return None,
    };
    Some(Item::Scalar(Value::Float(x)))
}

/// The scalar a JSON value holds, if it is one.
fn from_json(v: &serde_json::Value) -> Option<Item> {
    match v {
        serde_json::Value::Number(n) => {
            n.as_i64().map(Value::Int).or_else(|| n.as_f64().map(Value::Float)).map(Item::Scalar)
        }
        serde_json::Value::String(s) => Some(Item::Scalar(Value::Text(s.clone()))),
        serde_json::Value::Bool(b) => Some(Item::Boolean(*b)),
        _ => None,
    }
}

/// What a JSON value that is not one scalar is, in words.
fn json_kind(v: &serde_json::Value) -> &'static str {
    match v {
        serde_json::Value::Null => "null",
        serde_json::Value::Array(_) => "an array",
        serde_json::Value::Object(_) => "an object",
        _ => "an unrepresentable number",
    }
}

/// Plain text: a number if it reads as one, else the text itself (surrounding quotes removed).
fn from_text(text: &str) -> Value {
    let t = text.trim();
    if let Ok(i) = t.parse::<i64>() {
        return Value::Int(i);
    }
    if let Ok(f) = t.parse::<f64>() {
        return Value::Float(f);
    }
    let unquoted = t.strip_prefix('"').and_then(|s| s.strip_suffix('"')).unwrap_or(t);
    Value::Text(unquoted.to_string())
}

/// Check a value against the field's kind and range, converting where the meaning is exact
/// (an integer to a double, a menu choice name to its index).
pub fn validate(def: &FieldDef, raw: Value) -> Result<Value, CodecError> {
    let field = def.name;
    match def.kind {
        Kind::Double | Kind::Float => {
            let x = match &raw {
                Value::Int(i) => *i as f64,
                Value::Float(f) => *f,
                Value::Text(t) => {
                    return Err(CodecError::WrongType {
                        field,
                        expected: "a number".into(),
                        got: format!("text '{}'", excerpt(t)),
                    })
                }
            };
            if !x.is_finite() {
                return Err(CodecError::NotFinite { field, value: x.to_string() });
            }
            if def.kind == Kind::Float && x.abs() > f64::from(f32::MAX) {
                return Err(CodecError::BeyondFloat { field, value: format!("{x:e}") });
            }
            Ok(Value::Float(x))
        }
        Kind::Menu(menu) => {
            let index = match &raw {
                Value::Text(t) => match menu.index_of(t) {
                    Some(i) => i64::from(i),
                    None => {
                        return Err(CodecError::NotAChoice {
                            field,
                            value: excerpt(t),
                            menu: menu.name,
                            choices: menu.choices.join(", "),
                        })
                    }
                },
                other => integral(field, other)?,
            };
            check_range(def, index)
        }
        Kind::Long | Kind::ULong | Kind::Short | Kind::UShort | Kind::UChar => {
            let i = match &raw {
                Value::Text(t) => {
                    return Err(CodecError::WrongType {
                        field,
                        expected: "an integer".into(),
                        got: format!("text '{}'", excerpt(t)),
                    })
                }
                other => integral(field, other)?,
            };
            check_range(def, i)
        }
        Kind::Str(max) => {
            let s = raw.to_string();
            // One byte is kept for the terminator, as in an EPICS DBF_STRING.
            if s.len() >= max {
                return Err(CodecError::TooLong { field, len: s.len(), max: max - 1 });
            }
            Ok(Value::Text(s))
        }
        // As an IOC's link fields, which take only strings: a number would name no key.
        Kind::Link => match raw {
            Value::Text(text) => Ok(Value::Text(text)),
            number => {
                Err(CodecError::WrongType { field, expected: Kind::Link.expected().into(), got: number.to_string() })
            }
        },
    }
}

/// Text from a writer as a message repeats it: whole when short, else its start and its length
/// (a megabyte of garbage is not sent back to the writer and every subscriber of ERR).
pub fn excerpt(text: &str) -> String {
    const SHOWN: usize = 40;
    match text.char_indices().nth(SHOWN) {
        Some((cut, _)) => format!("{}... ({} bytes)", &text[..cut], text.len()),
        None => text.to_string(),
    }
}

fn integral(field: &'static str, raw: &Value) -> Result<i64, CodecError> {
    match raw {
        Value::Int(i) => Ok(*i),
        Value::Float(f) if !f.is_finite() => Err(CodecError::NotFinite { field, value: f.to_string() }),
        Value::Float(f) if f.fract() == 0.0 && f.abs() < 9.0e18 => Ok(*f as i64),
        other => Err(CodecError::WrongType { field, expected: "an integer".into(), got: other.to_string() }),
    }
}

fn check_range(def: &FieldDef, i: i64) -> Result<Value, CodecError> {
    let (min, max) = def.kind.int_range().expect("integer kinds have a range");
    if i < min || i > max {
        return Err(CodecError::OutOfRange { field: def.name, value: i.to_string(), min, max });
    }
    Ok(Value::Int(i))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::catalogue::Field;

    fn write(field: Field, bytes: &[u8], enc: PayloadEncoding) -> Result<Value, CodecError> {
        decode_write(field.def(), bytes, enc)
    }

    fn cbor<T: serde::Serialize>(v: T) -> Vec<u8> {
        encode_cbor(&v)
    }

    #[test]
    fn text_numbers_and_menu_names() {
        use PayloadEncoding::Text;
        assert_eq!(write(Field::VAL, b"5", Text), Ok(Value::Float(5.0)));
        assert_eq!(write(Field::VAL, b" -2.5e-3\n", Text), Ok(Value::Float(-2.5e-3)));
        assert_eq!(write(Field::STOP, b"1", Text), Ok(Value::Int(1)));
        assert_eq!(write(Field::SPMG, b"Go", Text), Ok(Value::Int(3)));
        assert_eq!(write(Field::SPMG, b"\"pause\"", Text), Ok(Value::Int(1)));
        assert_eq!(write(Field::SPMG, b"2", Text), Ok(Value::Int(2)));
        assert_eq!(write(Field::RMOD, b"in-position", Text), Ok(Value::Int(3)));
        assert_eq!(write(Field::DESC, b"slit blade", Text), Ok(Value::Text("slit blade".into())));
        assert_eq!(write(Field::STOP, b"1.0", Text), Ok(Value::Int(1)));
    }

    #[test]
    fn text_fields_store_what_was_written_or_refuse_it() {
        use PayloadEncoding::Text;
        for written in ["007", "1.50", "1e3", "-0", " padded ", "\"quoted\""] {
            assert_eq!(write(Field::DESC, written.as_bytes(), Text), Ok(Value::Text(written.into())), "{written}");
        }
        assert_eq!(write(Field::PREM, b"-0\n", Text), Ok(Value::Text("-0".into())), "a shell's line end goes");
        let long = format!("1{}", "0".repeat(5000));
        assert!(matches!(write(Field::DESC, long.as_bytes(), Text), Err(CodecError::TooLong { field: "DESC", .. })));
        assert!(write(Field::EGU, b"\xff", Text).is_err(), "not UTF-8");
    }

    #[test]
    fn cbor_and_json_values() {
        assert_eq!(write(Field::VAL, &cbor(10.5), PayloadEncoding::Cbor), Ok(Value::Float(10.5)));
        assert_eq!(write(Field::VAL, &cbor(3), PayloadEncoding::Cbor), Ok(Value::Float(3.0)));
        assert_eq!(write(Field::DIR, &cbor("Neg"), PayloadEncoding::Cbor), Ok(Value::Int(1)));
        assert_eq!(write(Field::JOGF, &cbor(true), PayloadEncoding::Cbor), Ok(Value::Int(1)));
        assert_eq!(write(Field::CNEN, b"true", PayloadEncoding::Json), Ok(Value::Int(1)));
        assert_eq!(write(Field::STOP, &cbor(false), PayloadEncoding::Cbor), Ok(Value::Int(0)));
        assert_eq!(write(Field::VAL, b"7.25", PayloadEncoding::Json), Ok(Value::Float(7.25)));
        assert_eq!(write(Field::SPMG, b"\"Stop\"", PayloadEncoding::Json), Ok(Value::Int(0)));
        assert_eq!(write(Field::SPMG, b"1", PayloadEncoding::Json), Ok(Value::Int(1)));
    }

    #[test]
    fn a_boolean_is_no_position_speed_or_choice_of_several() {
        for (field, bytes, encoding) in [
            (Field::VAL, cbor(true), PayloadEncoding::Cbor),
            (Field::VELO, cbor(false), PayloadEncoding::Cbor),
            (Field::VAL, b"false".to_vec(), PayloadEncoding::Json),
            (Field::SPMG, cbor(true), PayloadEncoding::Cbor),
            (Field::DESC, b"true".to_vec(), PayloadEncoding::Json),
        ] {
            let e = write(field, &bytes, encoding).unwrap_err();
            assert!(matches!(e, CodecError::WrongType { .. }), "{field}: {e}");
            assert!(e.to_string().contains("a boolean"), "{e}");
        }
        // A link follows another publisher's flag as 1 or 0.
        assert_eq!(decode_scalar(&cbor(true), PayloadEncoding::Cbor), Ok(Value::Int(1)));
    }

    #[test]
    fn a_cbor_payload_is_one_item_and_nothing_after_it() {
        let mut two = cbor(2.0);
        two.extend(cbor("junk"));
        for bytes in [two, [cbor(4.0), vec![0xff]].concat()] {
            let e = write(Field::VAL, &bytes, PayloadEncoding::Cbor).unwrap_err();
            assert!(matches!(e, CodecError::Malformed { encoding: "CBOR", .. }), "{e}");
            assert!(e.to_string().contains("after the item"), "{e}");
        }
    }

    #[test]
    fn bytes_that_are_not_cbor_are_refused_in_plain_words() {
        let nested = [vec![0x81; 1000], cbor(1.0)].concat();
        for (bytes, words) in [
            (&b""[..], "VAL: malformed CBOR payload: the bytes end before the item does"),
            (&[0xff, 0xfe, 0x00][..], "VAL: malformed CBOR payload: not a valid item"),
            (&nested[..], "VAL: malformed CBOR payload: items nested too deeply"),
        ] {
            let e = write(Field::VAL, bytes, PayloadEncoding::Cbor).unwrap_err().to_string();
            assert!(e.starts_with(words), "{e}");
            assert!(!e.contains("Error {") && !e.contains("Semantic("), "{e}");
        }
    }

    #[test]
    fn a_long_text_is_repeated_by_its_start_and_length() {
        let e = write(Field::VAL, "x".repeat(1_000_000).as_bytes(), PayloadEncoding::Text).unwrap_err().to_string();
        assert_eq!(e, format!("VAL: wrong type: expected a number, got text '{}... (1000000 bytes)'", "x".repeat(40)));
        let e = write(Field::SPMG, "é".repeat(50).as_bytes(), PayloadEncoding::Text).unwrap_err().to_string();
        assert!(e.starts_with(&format!("SPMG: '{}... (100 bytes)' is not a choice", "é".repeat(40))), "{e}");
        assert_eq!(excerpt("Go on"), "Go on");
    }

    #[test]
    fn rejections_name_the_field_and_the_fault() {
        use PayloadEncoding::*;
        let e = write(Field::VAL, b"abc", Text).unwrap_err();
        assert!(matches!(e, CodecError::WrongType { field: "VAL", .. }), "{e}");
        let e = write(Field::VAL, b"NaN", Text).unwrap_err();
        assert!(matches!(e, CodecError::NotFinite { field: "VAL", .. }), "{e}");
        let e = write(Field::VAL, b"inf", Text).unwrap_err();
        assert!(matches!(e, CodecError::NotFinite { .. }), "{e}");
        let e = write(Field::VAL, &cbor(f64::NAN), Cbor).unwrap_err();
        assert!(matches!(e, CodecError::NotFinite { .. }), "{e}");
        for python in ["NaN", "Infinity", "-Infinity"] {
            let e = write(Field::VAL, python.as_bytes(), Json).unwrap_err();
            assert!(matches!(e, CodecError::NotFinite { field: "VAL", .. }), "{python}: {e}");
            let e = write(Field::DESC, python.as_bytes(), Json).unwrap_err();
            assert!(matches!(e, CodecError::Malformed { encoding: "JSON", .. }), "to a text field, {python}: {e}");
        }
        let e = write(Field::FRAC, b"1e39", Text).unwrap_err();
        let beyond = "FRAC: 1e39 is beyond what the field holds (a FLOAT: at most 3.4e38 either way)";
        assert_eq!(e.to_string(), beyond);
        let e = write(Field::VAL, &[0xff, 0x00, 0x13], Cbor).unwrap_err();
        assert!(matches!(e, CodecError::Malformed { encoding: "CBOR", .. }), "{e}");
        let e = write(Field::VAL, &cbor(vec![1, 2]), Cbor).unwrap_err();
        assert!(e.to_string().contains("an array"), "{e}");
        let e = write(Field::VAL, b"{\"a\":1}", Json).unwrap_err();
        assert!(e.to_string().contains("an object"), "{e}");
        let e = write(Field::VAL, b"{nope", Json).unwrap_err();
        assert!(matches!(e, CodecError::Malformed { encoding: "JSON", .. }), "{e}");
        let e = write(Field::VAL, &[0xc3, 0x28], Text).unwrap_err();
        assert!(matches!(e, CodecError::Malformed { encoding: "text", .. }), "{e}");
        let e = write(Field::SPMG, b"Run", Text).unwrap_err();
        assert_eq!(e.to_string(), "SPMG: 'Run' is not a choice of motorSPMG (Stop, Pause, Move, Go)");
        let e = write(Field::SPMG, b"4", Text).unwrap_err();
        assert!(matches!(e, CodecError::OutOfRange { max: 3, .. }), "{e}");
        let e = write(Field::STOP, b"70000", Text).unwrap_err();
        assert!(matches!(e, CodecError::OutOfRange { field: "STOP", .. }), "{e}");
        let e = write(Field::STOP, b"1.5", Text).unwrap_err();
        assert!(matches!(e, CodecError::WrongType { .. }), "{e}");
        // A link takes text only, as an IOC's: a number would be taken for a key.
        let e = write(Field::OUT, &cbor(5), PayloadEncoding::Cbor).unwrap_err();
        assert_eq!(e.to_string(), "OUT: wrong type: expected a key expression, got 5");
        assert_eq!(write(Field::OUT, b"5", Text), Ok(Value::Text("5".into())));
        let e = write(Field::NTMF, b"-1", Text).unwrap_err();
        assert!(matches!(e, CodecError::OutOfRange { .. }), "{e}");
        let e = write(Field::EGU, b"a unit name far too long", Text).unwrap_err();
        assert!(matches!(e, CodecError::TooLong { max: 15, .. }), "{e}");
    }

    #[test]
    fn encodings_from_zenoh_mime_strings() {
        assert_eq!(PayloadEncoding::from_mime("application/cbor"), PayloadEncoding::Cbor);
        assert_eq!(PayloadEncoding::from_mime("application/json;x"), PayloadEncoding::Json);
        assert_eq!(PayloadEncoding::from_mime("text/plain;charset=utf-8"), PayloadEncoding::Text);
        assert_eq!(PayloadEncoding::from_mime("zenoh/bytes"), PayloadEncoding::Text);
        assert_eq!(PayloadEncoding::from_mime(""), PayloadEncoding::Text);
    }

    #[test]
    fn published_values_round_trip_through_cbor() {
        for v in [Value::Float(1.25), Value::Int(-7), Value::Text("mm".into())] {
            assert_eq!(decode_cbor_value(&encode_cbor(&v)).unwrap(), v);
        }
        // A double is a CBOR float, an integer a CBOR integer.
        assert_eq!(encode_cbor(&Value::Int(1)), vec![0x01]);
        assert_eq!(encode_cbor(&Value::Float(1.5))[0] & 0xe0, 0xe0);
    }
}
