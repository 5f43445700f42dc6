//! Framing shared by the line-based protocols: bytes arrive in any pieces, commands end with a
//! terminator. Real controllers have a bounded input buffer; so has this.

/// Complete lines out of bytes that arrive in pieces.
#[derive(Debug)]
pub struct Lines {
    terminator: &'static [u8],
    capacity: usize,
    pending: Vec<u8>,
    overflowed: usize,
}

impl Lines {
    /// Lines ending with `terminator` (not empty), each at most `capacity` bytes long before it.
    pub fn new(terminator: &'static [u8], capacity: usize) -> Self {
        assert!(!terminator.is_empty(), "a line needs a terminator");
        Self { terminator, capacity, pending: Vec::new(), overflowed: 0 }
    }

    /// `bytes` received; then the complete lines, without their terminator, in order.
    pub fn push(&mut self, bytes: &[u8]) -> Vec<Vec<u8>> {
        self.pending.extend_from_slice(bytes);
        let mut lines = Vec::new();
        while let Some(end) = find(&self.pending, self.terminator) {
            let line = self.pending[..end].to_vec();
            self.pending.drain(..end + self.terminator.len());
            lines.push(line);
        }
        if self.pending.len() > self.capacity {
            // A controller's input buffer overflows: what it held is lost, as on the device.
            self.pending.clear();
            self.overflowed += 1;
        }
        lines
    }

    /// How many times more than `capacity` bytes came without a terminator.
    pub fn overflowed(&self) -> usize {
        self.overflowed
    }
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|window| window == needle)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_come_whole_whatever_the_pieces() {
        let mut lines = Lines::new(b"\r\n", 64);
        assert!(lines.push(b"1T").is_empty());
        assert_eq!(lines.push(b"S\r"), Vec::<Vec<u8>>::new());
        assert_eq!(lines.push(b"\n1PA2\r\n1TP"), vec![b"1TS".to_vec(), b"1PA2".to_vec()]);
        assert_eq!(lines.push(b"\r\n"), vec![b"1TP".to_vec()]);
    }

    #[test]
    fn a_flood_without_terminator_is_dropped_and_counted() {
        let mut lines = Lines::new(b"\n", 8);
        assert!(lines.push(&[b'x'; 9]).is_empty());
        assert_eq!(lines.overflowed(), 1);
        assert_eq!(lines.push(b"ERR?\n"), vec![b"ERR?".to_vec()]);
    }
}
