//! The attachment every rmw_zenoh sample carries (`attachment_helpers.cpp`, serialized with
//! zenoh-ext's serializer): the publisher's sequence number (`i64`, from 1), the source time
//! (`i64`, ns since the Unix epoch) and the publisher's GID (16 bytes, as a sequence: its
//! length 16 in LEB128, then the bytes), little-endian, 33 bytes. A sample without one is
//! dropped by ROS subscribers.

use crate::graph::Gid;

/// What an attachment says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Attachment {
    /// The publisher's count of its samples, from 1.
    pub sequence: i64,
    /// When the sample was made, ns since the Unix epoch.
    pub source_time_ns: i64,
    /// The publisher's GID.
    pub gid: Gid,
}

/// Bytes that are not an attachment.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("not an rmw_zenoh attachment: {0}")]
pub struct AttachmentError(&'static str);

/// Its length on the wire.
const SIZE: usize = 33;
/// The GID's length, as zenoh-ext prefixes a sequence with it (LEB128: one byte).
const GID_LENGTH: u8 = 16;

impl Attachment {
    /// Its 33 bytes.
    #[must_use]
    pub fn encode(&self) -> Vec<u8> {
        let mut bytes = Vec::with_capacity(SIZE);
        bytes.extend_from_slice(&self.sequence.to_le_bytes());
        bytes.extend_from_slice(&self.source_time_ns.to_le_bytes());
        bytes.push(GID_LENGTH);
        bytes.extend_from_slice(&self.gid);
        bytes
    }

    /// The attachment in `bytes`.
    pub fn decode(bytes: &[u8]) -> Result<Self, AttachmentError> {
        if bytes.len() != SIZE {
            return Err(AttachmentError("33 bytes expected"));
        }
        if bytes[16] != GID_LENGTH {
            return Err(AttachmentError("a GID of 16 bytes expected"));
        }
        let word = |at: usize| i64::from_le_bytes(bytes[at..at + 8].try_into().expect("eight bytes"));
        let gid = bytes[17..].try_into().expect("sixteen bytes");
        Ok(Self { sequence: word(0), source_time_ns: word(8), gid })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bytes rmw_zenoh_cpp 0.2.10 sends for sequence 1 at 1700000000.123456789 s from the
    /// publisher whose GID is d3b34c37….
    #[test]
    fn an_attachment_is_rmw_zenohs_33_bytes_both_ways() {
        let gid: Gid = [0xd3, 0xb3, 0x4c, 0x37, 0xc1, 0xb7, 0xe0, 0x33, 0xa7, 0xef, 0x01, 0x29, 0x82, 0xb2, 0x0e, 0x33];
        let attachment = Attachment { sequence: 1, source_time_ns: 1_700_000_000_123_456_789, gid };
        let hex: String = attachment.encode().iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(hex, "010000000000000015cd853dfe9c971710d3b34c37c1b7e033a7ef012982b20e33");
        assert_eq!(Attachment::decode(&attachment.encode()), Ok(attachment));
        assert!(Attachment::decode(&[0; 32]).is_err());
        let mut wrong = attachment.encode();
        wrong[16] = 8;
        assert!(Attachment::decode(&wrong).is_err());
    }
}
