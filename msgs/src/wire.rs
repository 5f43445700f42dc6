//! Structured messages of the wire contract besides field values: the state marker attached to
//! every publication, the driver-command trace, and the simulator's state report.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use std::borrow::Cow;

/// Attachment of every publication a node makes. Its presence marks a sample as state, never a
/// command, so nodes, bridges and UIs can share one key space without echo loops.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[non_exhaustive]
pub struct StateMarker {
    /// Always "state".
    // Borrowed when made here: a node makes one for every post.
    pub kind: Cow<'static, str>,
    /// Per-axis publication sequence number (per record, from its node's start, for a bridge
    /// record's value).
    pub seq: u64,
    /// Alarm status (menuAlarmStat index) when the value was published.
    pub stat: u16,
    /// Alarm severity (menuAlarmSevr index) when the value was published.
    pub sevr: u16,
    /// True on a bridge record's value (a calc's, a transform field's on its own key) computed
    /// from values found (read when its links connected, or when a source came back) rather
    /// than from an event: a link following it takes it as found, and moves no motor on it.
    /// Absent (false) on every axis's post.
    #[serde(default, skip_serializing_if = "is_false")]
    pub found: bool,
}

fn is_false(value: &bool) -> bool {
    !*value
}

impl StateMarker {
    /// The `kind` every marker carries.
    pub const KIND: &'static str = "state";

    /// The marker of publication `seq`, with the axis's alarm status and severity at that moment.
    pub fn new(seq: u64, stat: u16, sevr: u16) -> Self {
        Self { kind: Cow::Borrowed(Self::KIND), seq, stat, sevr, found: false }
    }

    /// The same marker, for a value computed from values found or not (`found`).
    #[must_use]
    pub fn with_found(self, found: bool) -> Self {
        Self { found, ..self }
    }

    /// The marker as CBOR, the bytes of the attachment.
    pub fn encode(&self) -> Vec<u8> {
        // Room for the longest marker (a 64-bit seq), so writing it never grows the buffer.
        let mut out = Vec::with_capacity(48);
        ciborium::into_writer(self, &mut out).expect("writing CBOR to a Vec cannot fail");
        out
    }

    /// The marker carried by an attachment, if it is one.
    pub fn decode(attachment: &[u8]) -> Option<Self> {
        ciborium::from_reader::<Self, _>(attachment).ok().filter(|m| m.kind == Self::KIND)
    }
}

/// What the attachment of a write says, read as a CBOR map or the same map as JSON (its
/// entries in any order, others beside them): by its `kind`, a state marker or a hold.
/// Anything else (another system's attachment, such as the one rmw_zenoh puts on every sample)
/// says nothing to zmotor: the write is a plain one.
#[derive(Clone, Debug, PartialEq)]
pub enum Attached {
    /// Nothing zmotor reads: a plain write.
    Plain,
    /// A state marker (kind "state"): a node's publication, never a write, whatever else the
    /// map holds (a marker a bridge decoded and encoded again, a field added).
    State,
    /// A hold (kind "hold"), or one that names no token (`MalformedHold`).
    Hold(Result<Hold, MalformedHold>),
}

/// A map of kind "hold" without a token as text: a hold that holds nothing, so its write is
/// refused rather than start a motion nobody holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("the write's hold (kind \"hold\") names no token as text")]
pub struct MalformedHold;

impl Attached {
    /// Read an attachment.
    pub fn read(attachment: &[u8]) -> Self {
        #[derive(Deserialize)]
        struct Tagged {
            kind: String,
        }
        fn decode<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> Option<T> {
            ciborium::from_reader(bytes).ok().or_else(|| serde_json::from_slice(bytes).ok())
        }
        match decode::<Tagged>(attachment).map(|t| t.kind) {
            Some(kind) if kind == StateMarker::KIND => Attached::State,
            Some(kind) if kind == Hold::KIND => Attached::Hold(decode::<Hold>(attachment).ok_or(MalformedHold)),
            _ => Attached::Plain,
        }
    }

    /// The hold it says the write is held by, if it is one.
    pub fn hold(self) -> Option<Result<Hold, MalformedHold>> {
        match self {
            Attached::Hold(hold) => Some(hold),
            Attached::Plain | Attached::State => None,
        }
    }
}

/// Attachment of a write that holds what it starts (the jog deadman, "hold to move"): the
/// motion lasts only while the liveliness token `token` lives. The client declares the token
/// (by convention `<prefix>/<axis>/@hold/<client>`, see `KeyLayout::hold`) before it writes;
/// when the token goes (the client stopped, crashed, or was cut off), a jog ends as JOGF/JOGR =
/// 0 would end it, any other motion as STOP.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Hold {
    /// Always "hold".
    pub kind: String,
    /// The key of the client's liveliness token.
    pub token: String,
}

impl Hold {
    /// The `kind` every hold carries.
    pub const KIND: &'static str = "hold";

    /// A hold on the liveliness token `token`.
    pub fn new(token: &str) -> Self {
        Self { kind: Self::KIND.to_string(), token: token.to_string() }
    }

    /// The hold as CBOR, the bytes of the attachment.
    pub fn encode(&self) -> Vec<u8> {
        crate::codec::encode_cbor(self)
    }
}

/// Which PID gain a `set_gain` command sets.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Gain {
    /// Proportional gain (PCOF).
    Proportional,
    /// Integral gain (ICOF).
    Integral,
    /// Derivative gain (DCOF).
    Derivative,
}

/// One command to a driver, in raw units (steps, steps/s, steps/s²), as published on
/// `<prefix>/<axis>/@driver/cmd`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "cmd", rename_all = "snake_case")]
pub enum DriverCommand {
    /// Absolute target, or distance when `relative`.
    Move {
        /// Target position, or distance when `relative`, in steps.
        position: f64,
        /// Whether `position` is a distance from the current position.
        relative: bool,
        /// Base velocity (VBAS), steps/s.
        min_velocity: f64,
        /// Slew velocity, steps/s.
        max_velocity: f64,
        /// Acceleration, steps/s².
        acceleration: f64,
    },
    /// Constant-velocity motion (jog); `max_velocity` is signed.
    MoveVelocity {
        /// Base velocity (VBAS), steps/s.
        min_velocity: f64,
        /// Jog velocity, steps/s; its sign is the direction.
        max_velocity: f64,
        /// Acceleration, steps/s².
        acceleration: f64,
    },
    /// Home search (HOMF/HOMR).
    Home {
        /// Search in the raw positive direction; else the raw negative one.
        forward: bool,
        /// Base velocity (VBAS), steps/s.
        min_velocity: f64,
        /// Home velocity, steps/s.
        max_velocity: f64,
        /// Acceleration, steps/s².
        acceleration: f64,
    },
    /// Stop the motion.
    Stop {
        /// Deceleration, steps/s².
        acceleration: f64,
    },
    /// Redefine the current position without moving.
    SetPosition {
        /// The new position, steps.
        position: f64,
    },
    /// Amplifier / closed loop on or off.
    Enable {
        /// True to enable, false to disable (CNEN).
        on: bool,
    },
    /// Encoder counts per motor step ratio (MRES/ERES).
    SetEncoderRatio {
        /// Encoder counts per motor step.
        ratio: f64,
    },
    /// Set the controller's high travel limit (from DHLM; RHLM).
    SetHighLimit {
        /// The limit, steps.
        position: f64,
    },
    /// Set the controller's low travel limit (from DLLM; RLLM).
    SetLowLimit {
        /// The limit, steps.
        position: f64,
    },
    /// Set one PID gain of closed-loop control.
    SetGain {
        /// Which gain.
        gain: Gain,
        /// The gain's value (PCOF, ICOF or DCOF).
        value: f64,
    },
    /// Request a fresh status report (the record's GET_INFO).
    Poll,
    /// A command primitive (INIT/PREM/POST text).
    Raw {
        /// The command text, passed to the driver as is.
        text: String,
    },
}

impl DriverCommand {
    /// Whether it sets the motor going (a move, a jog, a home search).
    pub fn starts_motion(&self) -> bool {
        matches!(self, DriverCommand::Move { .. } | DriverCommand::MoveVelocity { .. } | DriverCommand::Home { .. })
    }
}

/// A traced driver command with the engine's clock and a sequence number.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct DriverTrace {
    /// The command sent.
    #[serde(flatten)]
    pub command: DriverCommand,
    /// Seconds on the engine's clock.
    pub t: f64,
    /// Per-axis sequence number, shared with the state markers' `seq`.
    pub seq: u64,
}

/// An axis's readback state in one sample, on `<prefix>/<axis>/@readback` (opt-in: a subscriber
/// must name the key; the per-field keys are published as ever). Sent after each poll or write
/// that changed any of `Readback::FIELDS`, with every one of them as it is then: a CBOR map of
/// the fields by name, as their own keys carry them (e.g. `{"RBV": 1.5, "DMOV": 0, ...}`), and
/// the state marker's `seq` of the last post it follows. The sample carries the state marker and
/// the timestamp of those posts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Readback {
    /// RBV, DRBV, RRBV, RMP, DIFF, RDIF, DMOV, MOVN and MSTA by name.
    #[serde(flatten)]
    pub fields: std::collections::BTreeMap<String, crate::Value>,
    /// The per-axis sequence number of the last post this state follows.
    pub seq: u64,
}

impl Readback {
    /// The fields a readback bundle carries: what a poll of a moving axis changes, and whether
    /// it moves.
    pub const FIELDS: [crate::Field; 9] = [
        crate::Field::RBV,
        crate::Field::DRBV,
        crate::Field::RRBV,
        crate::Field::RMP,
        crate::Field::DIFF,
        crate::Field::RDIF,
        crate::Field::DMOV,
        crate::Field::MOVN,
        crate::Field::MSTA,
    ];

    /// The bundle of `fields` as they are now, after the post numbered `seq`, encoded: the
    /// CBOR of a `Readback`, written straight from the fields (a node sends one per poll).
    #[must_use]
    pub fn encode(fields: &crate::Fields, seq: u64) -> Vec<u8> {
        crate::codec::encode_cbor(&ReadbackOf { fields, seq })
    }
}

/// A `Readback` as it serializes, borrowing the fields instead of collecting them in a map.
struct ReadbackOf<'a> {
    fields: &'a crate::Fields,
    seq: u64,
}

impl Serialize for ReadbackOf<'_> {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = serializer.serialize_map(Some(Readback::FIELDS.len() + 1))?;
        for field in Readback::FIELDS {
            map.serialize_entry(field.name(), &self.fields.get(field))?;
        }
        map.serialize_entry("seq", &self.seq)?;
        map.end()
    }
}

/// The answer to a put-with-completion (`<prefix>/<axis>/<FIELD>?wait`), sent when the motion
/// the write started has finished (DMOV back to 1). A CBOR map: the written field by its name
/// with its value now, the readback, the end-of-motion flags and whether the target was reached.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Completion {
    /// The field written, by its name, with its value now (e.g. `{"VAL": 10.0}`).
    #[serde(flatten)]
    pub written: std::collections::BTreeMap<String, crate::Value>,
    /// The user readback (RBV) when the motion ended.
    #[serde(rename = "RBV")]
    pub rbv: f64,
    /// DMOV: 1 (the motion has finished).
    #[serde(rename = "DMOV")]
    pub dmov: i64,
    /// MISS: 1 when retries ran out before the target was within the deadband.
    #[serde(rename = "MISS")]
    pub miss: i64,
    /// LVIO: 1 when the target violated the soft limits.
    #[serde(rename = "LVIO")]
    pub lvio: i64,
    /// Alarm status (menuAlarmStat index).
    #[serde(rename = "STAT")]
    pub stat: i64,
    /// Alarm severity (menuAlarmSevr index).
    #[serde(rename = "SEVR")]
    pub sevr: i64,
    /// 1 when the target was reached: no MAJOR or INVALID alarm and, after a write of a target
    /// (VAL, DVAL, RVAL, RLV, TWF, TWR), MISS 0 and RBV within the retry deadband (RDBD) of the
    /// target it set.
    pub reached: i64,
    /// What the axis's controller reported while the motion ran (its errors with the vendor's
    /// code and meaning, commands it did not send), each once; absent when nothing.
    #[serde(rename = "ERR", default, skip_serializing_if = "Vec::is_empty")]
    pub err: Vec<String>,
}

/// The simulator's physical state, the answer to a get of `sim/<axis>/state` (not published:
/// it changes at every instant of a motion).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct SimState {
    /// True position in steps.
    pub position: f64,
    /// Encoder reading in counts (None without an encoder).
    pub encoder: Option<f64>,
    /// Signed velocity, steps/s.
    pub velocity: f64,
    /// Whether the stage is moving.
    pub moving: bool,
    /// The high (raw positive) limit switch is active.
    pub high_limit: bool,
    /// The low (raw negative) limit switch is active.
    pub low_limit: bool,
    /// The home switch is active.
    pub at_home: bool,
    /// A home search has completed (reported as MSTA `RA_HOMED`).
    pub homed: bool,
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_readback_bundle_decodes_to_each_field_as_its_own_key_carries_it() {
        let mut fields = crate::Fields::default();
        for (field, value) in [(crate::Field::RBV, 1.5), (crate::Field::DIFF, -0.25), (crate::Field::RRBV, 1500.0)] {
            fields.set(field, &crate::Value::Float(value));
        }
        let bundle: Readback = ciborium::from_reader(&Readback::encode(&fields, 42)[..]).unwrap();
        assert_eq!(bundle.seq, 42);
        let names: Vec<_> = bundle.fields.keys().map(String::as_str).collect();
        assert_eq!(names, ["DIFF", "DMOV", "DRBV", "MOVN", "MSTA", "RBV", "RDIF", "RMP", "RRBV"]);
        for field in Readback::FIELDS {
            assert_eq!(bundle.fields[field.name()], fields.get(field), "{field}");
        }
        assert_eq!(bundle.fields["RRBV"], crate::Value::Int(1500));
    }

    use super::*;
    use std::collections::BTreeMap;

    #[test]
    fn a_hold_round_trips_in_cbor_and_reads_from_json() {
        let hold = Hold::new("motor/m1/@hold/abc");
        assert_eq!(Attached::read(&hold.encode()), Attached::Hold(Ok(hold.clone())));
        assert_eq!(Attached::read(br#"{"token":"motor/m1/@hold/abc","kind":"hold","by":1}"#), Attached::Hold(Ok(hold)));
        assert_eq!(Attached::read(&StateMarker::new(1, 0, 0).encode()), Attached::State, "a marker is no hold");
        assert_eq!(Attached::read(b"1"), Attached::Plain);
        // A hold that holds nothing: refused, never a plain write.
        for malformed in [
            crate::codec::encode_cbor(&BTreeMap::from([("kind", "hold")])),
            br#"{"kind":"hold","token":7}"#.to_vec(),
            br#"{"kind":"hold","tokn":"motor/m1/@hold/x"}"#.to_vec(),
        ] {
            assert_eq!(Attached::read(&malformed), Attached::Hold(Err(MalformedHold)), "{malformed:?}");
        }
    }

    #[test]
    fn a_state_marker_is_known_by_its_kind_however_its_map_is_written() {
        let m = StateMarker::new(7, 4, 2);
        assert_eq!(Attached::read(&m.encode()), Attached::State);
        let entries = [("seq", 7u64), ("stat", 4), ("sevr", 2)];
        let mut with_more = BTreeMap::from([("kind", ciborium::Value::from("state"))]);
        with_more.extend(entries.map(|(k, v)| (k, ciborium::Value::from(v))));
        with_more.insert("src", ciborium::Value::from("bridge"));
        // Entries sorted (kind no longer first), one more, JSON, and an indefinite-length map.
        let mut indefinite = vec![0xbf];
        for (k, v) in [("kind", ciborium::Value::from("state")), ("seq", ciborium::Value::from(7))] {
            indefinite.extend(crate::codec::encode_cbor(&k));
            indefinite.extend(crate::codec::encode_cbor(&v));
        }
        indefinite.push(0xff);
        for marker in [
            crate::codec::encode_cbor(&with_more),
            br#"{"kind":"state","seq":7,"stat":4,"sevr":2}"#.to_vec(),
            indefinite,
        ] {
            assert_eq!(Attached::read(&marker), Attached::State, "{marker:?}");
        }
        for plain in [&b"state"[..], b"", &[0xa4, 0x64, b'k'], &crate::codec::encode_cbor(&"state")] {
            assert_eq!(Attached::read(plain), Attached::Plain, "{plain:?}");
        }
    }

    #[test]
    fn state_marker_round_trips_and_plain_payloads_are_not_markers() {
        let m = StateMarker::new(7, 4, 2);
        assert_eq!(StateMarker::decode(&m.encode()), Some(m));
        assert_eq!(StateMarker::decode(b"hello"), None);
        assert_eq!(StateMarker::decode(&crate::codec::encode_cbor(&1.0)), None);
        let longest = StateMarker::new(u64::MAX, u16::MAX, u16::MAX).with_found(true);
        let bytes = longest.encode();
        assert!(bytes.len() <= bytes.capacity() && bytes.capacity() == 48, "written in the room made for it");
        assert_eq!(StateMarker::decode(&bytes), Some(longest));
    }

    #[test]
    fn a_completion_is_one_flat_map_with_the_written_field_by_name() {
        let completion = Completion {
            written: [("VAL".to_string(), crate::Value::Float(10.0))].into(),
            rbv: 10.0,
            dmov: 1,
            miss: 0,
            lvio: 0,
            stat: 0,
            sevr: 0,
            reached: 1,
            err: Vec::new(),
        };
        let bytes = crate::codec::encode_cbor(&completion);
        let map: std::collections::BTreeMap<String, crate::Value> = ciborium::from_reader(&bytes[..]).unwrap();
        let keys: Vec<&str> = map.keys().map(String::as_str).collect();
        assert_eq!(keys, ["DMOV", "LVIO", "MISS", "RBV", "SEVR", "STAT", "VAL", "reached"]);
        assert_eq!((map["VAL"].clone(), map["DMOV"].clone()), (crate::Value::Float(10.0), crate::Value::Int(1)));
        let back: Completion = ciborium::from_reader(&bytes[..]).unwrap();
        assert_eq!(back, completion);
    }

    #[test]
    fn driver_trace_is_a_flat_map_with_cmd() {
        let t = DriverTrace {
            command: DriverCommand::Move {
                position: 100.0,
                relative: false,
                min_velocity: 0.0,
                max_velocity: 100.0,
                acceleration: 200.0,
            },
            t: 1.5,
            seq: 3,
        };
        let json = serde_json::to_value(&t).unwrap();
        assert_eq!(json["cmd"], "move");
        assert_eq!(json["position"], 100.0);
        assert_eq!(json["seq"], 3);
        let back: DriverTrace = ciborium::from_reader(&crate::codec::encode_cbor(&t)[..]).unwrap();
        assert_eq!(back, t);
    }
}
