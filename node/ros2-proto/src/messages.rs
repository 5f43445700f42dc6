//! ROS messages as rmw_zenoh sends them: CDR (XCDR1), little-endian, after the 4-byte
//! encapsulation header `00 01 00 00` (alignment counted from after it), nothing appended
//! (rmw_zenoh_cpp `type_support.cpp`, FastCDR's `DDS_CDR` with `serialize_encapsulation`). The
//! encoding itself is the `cdr-encoding` crate's.

use byteorder::LittleEndian;
use serde::{de::DeserializeOwned, Deserialize, Serialize};

/// `builtin_interfaces/msg/Time`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// When.
    pub stamp: Time,
    /// The frame the data is in.
    pub frame_id: String,
}

/// `sensor_msgs/msg/JointState`: joints by name, each with its position (m or rad), velocity
/// (m/s or rad/s) and effort; any of the three arrays may be empty.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    /// Stamp and frame.
    pub header: Header,
    /// The joints' names.
    pub name: Vec<String>,
    /// Their positions.
    pub position: Vec<f64>,
    /// Their velocities.
    pub velocity: Vec<f64>,
    /// Their efforts.
    pub effort: Vec<f64>,
}

/// A payload that is not the message expected.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CdrError {
    /// Not little-endian CDR: the encapsulation header is missing or another.
    #[error("not little-endian CDR (encapsulation header {0:02x?})")]
    Encapsulation(Vec<u8>),
    /// The CDR does not hold the message.
    #[error("not a {what}: {why}")]
    Body {
        /// The message expected.
        what: &'static str,
        /// Why not.
        why: String,
    },
}

/// The encapsulation header of little-endian plain CDR.
const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// `message` as a ROS payload.
pub fn encode<T: Serialize>(message: &T) -> Vec<u8> {
    let mut bytes = CDR_LE.to_vec();
    // Serializing a message of plain fields into memory cannot fail.
    let body = cdr_encoding::to_vec::<T, LittleEndian>(message).expect("a ROS message serializes");
    bytes.extend(body);
    bytes
}

/// The message of type `T` in a ROS payload.
pub fn decode<T: DeserializeOwned>(payload: &[u8], what: &'static str) -> Result<T, CdrError> {
    let (header, body) = payload.split_at(payload.len().min(4));
    if header != CDR_LE {
        return Err(CdrError::Encapsulation(header.to_vec()));
    }
    cdr_encoding::from_bytes::<T, LittleEndian>(body)
        .map(|(message, _)| message)
        .map_err(|e| CdrError::Body { what, why: e.to_string() })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bytes written by hand from the CDR rules: i32, u32, a string as its length with the
    /// NUL then its bytes and the NUL, sequences as their length then their elements, each
    /// primitive aligned to its size from after the header.
    #[test]
    fn a_joint_state_is_cdr_as_ros_lays_it_out() {
        let state = JointState {
            header: Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: String::new() },
            name: vec!["x".into()],
            position: vec![1.5],
            velocity: Vec::new(),
            effort: Vec::new(),
        };
        let expected: Vec<u8> = [
            &[0x00, 0x01, 0x00, 0x00][..], // encapsulation
            &[1, 0, 0, 0],                 // stamp.sec
            &[2, 0, 0, 0],                 // stamp.nanosec
            &[1, 0, 0, 0, 0],              // frame_id: "" (its NUL)
            &[0, 0, 0],                    // pad to 4
            &[1, 0, 0, 0],                 // name: one
            &[2, 0, 0, 0, b'x', 0],        // "x"
            &[0, 0],                       // pad to 4
            &[1, 0, 0, 0],                 // position: one, at 32, aligned for f64
            &1.5f64.to_le_bytes(),
            &[0, 0, 0, 0], // velocity: none
            &[0, 0, 0, 0], // effort: none
        ]
        .concat();
        assert_eq!(encode(&state), expected);
        assert_eq!(decode::<JointState>(&expected, "JointState").unwrap(), state);
        assert!(matches!(decode::<JointState>(&expected[1..], "JointState"), Err(CdrError::Encapsulation(_))));
        assert!(matches!(decode::<JointState>(&expected[..20], "JointState"), Err(CdrError::Body { .. })));
    }
}
