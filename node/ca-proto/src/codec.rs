//! Channel Access messages: a 16-byte header (extended to 24 bytes for large payloads) and a
//! payload padded to 8 bytes, all big-endian.

/// Commands of the subset served.
pub mod command {
    /// Protocol version (both ways).
    pub const VERSION: u16 = 0;
    /// Subscribe (client) / a monitor update (server).
    pub const EVENT_ADD: u16 = 1;
    /// Unsubscribe.
    pub const EVENT_CANCEL: u16 = 2;
    /// Write without notification.
    pub const WRITE: u16 = 4;
    /// Search for a channel by name (UDP, or TCP).
    pub const SEARCH: u16 = 6;
    /// Flow control: stop sending monitors.
    pub const EVENTS_OFF: u16 = 8;
    /// Flow control: send monitors again.
    pub const EVENTS_ON: u16 = 9;
    /// An error about a request.
    pub const ERROR: u16 = 11;
    /// Close a channel.
    pub const CLEAR_CHANNEL: u16 = 12;
    /// A server's beacon.
    pub const BEACON: u16 = 13;
    /// Read with a reply.
    pub const READ_NOTIFY: u16 = 15;
    /// Open a channel.
    pub const CREATE_CHAN: u16 = 18;
    /// Write, answered when done.
    pub const WRITE_NOTIFY: u16 = 19;
    /// The client's user name.
    pub const CLIENT_NAME: u16 = 20;
    /// The client's host name.
    pub const HOST_NAME: u16 = 21;
    /// A channel's access rights.
    pub const ACCESS_RIGHTS: u16 = 22;
    /// Are you there?
    pub const ECHO: u16 = 23;
    /// A channel could not be created.
    pub const CREATE_CH_FAIL: u16 = 26;
    /// A channel's server side went away.
    pub const SERVER_DISCONN: u16 = 27;
}

/// The minor protocol version this server speaks (EPICS 3.14 onwards).
pub const MINOR_VERSION: u16 = 13;

/// A message header; `p1` and `p2` are the command's two parameters (cid, sid, ioid, status...).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Header {
    /// The command.
    pub command: u16,
    /// Bytes of payload that follow (padded).
    pub payload_size: u32,
    /// DBR type, or another use per command.
    pub data_type: u16,
    /// Element count, or another use per command.
    pub count: u32,
    /// First parameter.
    pub p1: u32,
    /// Second parameter.
    pub p2: u32,
}

impl Header {
    /// A header for `command` with its parameters and no payload.
    pub fn new(command: u16, data_type: u16, count: u32, p1: u32, p2: u32) -> Self {
        Self { command, payload_size: 0, data_type, count, p1, p2 }
    }
}

/// Bytes that cannot be a message.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum FrameError {
    /// The payload is larger than a circuit accepts.
    #[error("a message of {0} bytes is larger than the {MAX_PAYLOAD} a circuit accepts")]
    TooLarge(u32),
}

/// Largest payload accepted from a client (motor fields are scalars; a name is at most a few
/// dozen bytes).
pub const MAX_PAYLOAD: u32 = 16 * 1024;

/// A message parsed off the front of a buffer: its header, its payload, the bytes it took.
pub type Parsed<'b> = (Header, &'b [u8], usize);

/// One message parsed off the front of `buffer`; `Ok(None)` when the buffer holds only part of
/// one.
pub fn parse(buffer: &[u8]) -> Result<Option<Parsed<'_>>, FrameError> {
    if buffer.len() < 16 {
        return Ok(None);
    }
    let u16_at = |i: usize| u16::from_be_bytes([buffer[i], buffer[i + 1]]);
    let u32_at = |i: usize| u32::from_be_bytes([buffer[i], buffer[i + 1], buffer[i + 2], buffer[i + 3]]);
    let mut header = Header {
        command: u16_at(0),
        payload_size: u32::from(u16_at(2)),
        data_type: u16_at(4),
        count: u32::from(u16_at(6)),
        p1: u32_at(8),
        p2: u32_at(12),
    };
    let mut start = 16;
    if header.payload_size == 0xFFFF && header.count == 0 {
        if buffer.len() < 24 {
            return Ok(None);
        }
        header.payload_size = u32_at(16);
        header.count = u32_at(20);
        start = 24;
    }
    if header.payload_size > MAX_PAYLOAD {
        return Err(FrameError::TooLarge(header.payload_size));
    }
    let end = start + header.payload_size as usize;
    if buffer.len() < end {
        return Ok(None);
    }
    Ok(Some((header, &buffer[start..end], end)))
}

/// A message: the header (its payload size and count set here) and the payload padded to 8.
pub fn encode(header: Header, payload: &[u8]) -> Vec<u8> {
    let padded = payload.len().div_ceil(8) * 8;
    let mut out = Vec::with_capacity(24 + padded);
    let extended = padded >= 0xFFFF || header.count >= 0xFFFF;
    out.extend_from_slice(&header.command.to_be_bytes());
    out.extend_from_slice(&(if extended { 0xFFFF } else { padded as u16 }).to_be_bytes());
    out.extend_from_slice(&header.data_type.to_be_bytes());
    out.extend_from_slice(&(if extended { 0 } else { header.count as u16 }).to_be_bytes());
    out.extend_from_slice(&header.p1.to_be_bytes());
    out.extend_from_slice(&header.p2.to_be_bytes());
    if extended {
        out.extend_from_slice(&(padded as u32).to_be_bytes());
        out.extend_from_slice(&header.count.to_be_bytes());
    }
    out.extend_from_slice(payload);
    out.resize(out.len() + padded - payload.len(), 0);
    out
}

/// A name or string payload: the bytes up to the first NUL.
pub fn text(payload: &[u8]) -> String {
    let end = payload.iter().position(|b| *b == 0).unwrap_or(payload.len());
    String::from_utf8_lossy(&payload[..end]).into_owned()
}

/// A name as a payload: its bytes and a NUL.
pub fn name_payload(name: &str) -> Vec<u8> {
    let mut bytes = name.as_bytes().to_vec();
    bytes.push(0);
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn a_message_is_padded_and_parsed_back() {
        let header = Header::new(command::CREATE_CHAN, 0, 0, 7, MINOR_VERSION.into());
        let bytes = encode(header, &name_payload("m1.RBV"));
        assert_eq!(bytes.len(), 16 + 8);
        assert_eq!(&bytes[..4], &[0, 18, 0, 8]);
        let (parsed, payload, used) = parse(&bytes).unwrap().unwrap();
        assert_eq!((parsed.command, parsed.p1, parsed.p2, used), (18, 7, 13, 24));
        assert_eq!(text(payload), "m1.RBV");
        assert_eq!(parse(&bytes[..20]), Ok(None), "half a message waits for the rest");
    }

    #[test]
    fn extended_headers_carry_large_sizes() {
        let header = Header::new(command::EVENT_ADD, 6, 70_000, 1, 2);
        let bytes = encode(header, &[1; 8]);
        assert_eq!(&bytes[2..4], &[0xFF, 0xFF]);
        let (parsed, payload, _) = parse(&bytes).unwrap().unwrap();
        assert_eq!((parsed.count, payload.len()), (70_000, 8));
        let mut huge = bytes.clone();
        huge[16..20].copy_from_slice(&(MAX_PAYLOAD + 8).to_be_bytes());
        assert_eq!(parse(&huge), Err(FrameError::TooLarge(MAX_PAYLOAD + 8)));
    }

    proptest! {
        #[test]
        fn any_bytes_parse_or_wait_without_panicking(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            let _ = parse(&bytes);
        }
    }
}
