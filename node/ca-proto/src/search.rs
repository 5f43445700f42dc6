//! Name searches (UDP datagrams of SEARCH messages, usually after a VERSION): a live channel's
//! name is answered with this server's TCP port; others are left unanswered, as EPICS servers
//! do.

use crate::codec::{self, command, Header, MINOR_VERSION};
use crate::directory::Directory;

/// The reply to one SEARCH message, if the name is ours and live.
pub(crate) fn reply(
    prefix: &str,
    request: Header,
    payload: &[u8],
    tcp_port: u16,
    directory: &dyn Directory,
) -> Option<Vec<u8>> {
    crate::directory::resolve(prefix, &codec::text(payload), directory)?;
    // The server's address: ~0 tells the client to use the address the reply came from.
    let header = Header::new(command::SEARCH, tcp_port, 0, u32::MAX, request.p2);
    Some(codec::encode(header, &MINOR_VERSION.to_be_bytes()))
}

/// The answer to a search datagram: a VERSION and a reply per name found, or `None`.
pub fn answer(prefix: &str, datagram: &[u8], tcp_port: u16, directory: &dyn Directory) -> Option<Vec<u8>> {
    let mut replies = Vec::new();
    let mut rest = datagram;
    while let Ok(Some((header, payload, used))) = codec::parse(rest) {
        if header.command == command::SEARCH {
            replies.extend(reply(prefix, header, payload, tcp_port, directory).unwrap_or_default());
        }
        rest = &rest[used..];
    }
    if replies.is_empty() {
        return None;
    }
    let mut answer = codec::encode(Header::new(command::VERSION, 0, MINOR_VERSION.into(), 0, 0), &[]);
    answer.extend(replies);
    Some(answer)
}
