//! Fixed-capacity output buffers: terminal text and link frames. Nothing here allocates; a
//! buffer that fills up keeps what fits and says so.

use core::fmt;

use conductor_protocols::score_link::{encode_reply, Reply, MAX_FRAME};

/// Text for the terminal. With `crlf`, every `\n` is written as `\r\n` (what serial terminals
/// expect). Past the capacity, text is dropped and [`TextOut::truncated`] is set.
pub struct TextOut<const N: usize> {
    buf: [u8; N],
    len: usize,
    truncated: bool,
    crlf: bool,
}

impl<const N: usize> TextOut<N> {
    /// An empty buffer; `crlf` turns `\n` into `\r\n`.
    pub const fn new(crlf: bool) -> Self {
        Self {
            buf: [0; N],
            len: 0,
            truncated: false,
            crlf,
        }
    }

    /// Appends raw bytes (as much as fits).
    pub fn push_bytes(&mut self, bytes: &[u8]) {
        for &b in bytes {
            if b == b'\n' && self.crlf {
                self.push(b'\r');
            }
            self.push(b);
        }
    }

    fn push(&mut self, b: u8) {
        if self.len < N {
            self.buf[self.len] = b;
            self.len += 1;
        } else {
            self.truncated = true;
        }
    }

    /// What was written.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }

    /// What was written, as text (cut before an incomplete character at the end).
    pub fn as_str(&self) -> &str {
        match core::str::from_utf8(self.as_bytes()) {
            Ok(s) => s,
            Err(e) => core::str::from_utf8(&self.buf[..e.valid_up_to()]).unwrap_or(""),
        }
    }

    /// True if something was dropped because the buffer was full.
    pub fn truncated(&self) -> bool {
        self.truncated
    }

    /// Empties the buffer.
    pub fn clear(&mut self) {
        self.len = 0;
        self.truncated = false;
    }
}

impl<const N: usize> fmt::Write for TextOut<N> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        self.push_bytes(s.as_bytes());
        Ok(())
    }
}

/// Whole link frames, concatenated (each ends with its `0x00`). A frame that does not fit is
/// dropped whole and counted, never cut.
pub struct FrameOut<const N: usize> {
    buf: [u8; N],
    len: usize,
    dropped: u32,
}

impl<const N: usize> Default for FrameOut<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameOut<N> {
    /// Empty.
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            len: 0,
            dropped: 0,
        }
    }

    /// Encodes and appends one reply; false if it was dropped (no room, or not encodable).
    pub fn push(&mut self, seq: u16, reply: &Reply<'_>) -> bool {
        let mut frame = [0u8; MAX_FRAME];
        match encode_reply(seq, reply, &mut frame) {
            Ok(n) if self.len + n <= N => {
                self.buf[self.len..self.len + n].copy_from_slice(&frame[..n]);
                self.len += n;
                true
            }
            _ => {
                self.dropped += 1;
                false
            }
        }
    }

    /// The frames written.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }

    /// Each frame, terminator included.
    pub fn frames(&self) -> impl Iterator<Item = &[u8]> {
        self.as_bytes().split_inclusive(|&b| b == 0)
    }

    /// Frames dropped since [`FrameOut::clear`].
    pub fn dropped(&self) -> u32 {
        self.dropped
    }

    /// Bytes free.
    pub fn free(&self) -> usize {
        N - self.len
    }

    /// Empties the buffer and the drop count.
    pub fn clear(&mut self) {
        self.len = 0;
        self.dropped = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::fmt::Write;

    #[test]
    fn text_converts_newlines_and_flags_truncation() {
        let mut t = TextOut::<8>::new(true);
        write!(t, "ab\ncd").unwrap();
        assert_eq!(t.as_bytes(), b"ab\r\ncd");
        write!(t, "efgh").unwrap();
        assert_eq!(t.as_bytes(), b"ab\r\ncdef");
        assert!(t.truncated());
    }

    #[test]
    fn frames_are_whole_or_dropped() {
        // Ack is 8 bytes framed, Time 16: exactly 24.
        let mut f = FrameOut::<24>::new();
        assert!(f.push(1, &Reply::Ack));
        assert!(!f.push(
            2,
            &Reply::Output {
                text: "far too long for the rest"
            }
        ));
        assert!(f.push(3, &Reply::Time { t_us: 5 }));
        assert_eq!(f.frames().count(), 2);
        assert_eq!(f.dropped(), 1);
    }
}
