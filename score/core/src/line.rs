//! Assembles terminal bytes into command lines (for serial ports; the host uses a line editor).

use crate::capacity::MAX_LINE;

/// What one received byte did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineEvent {
    /// Nothing to do.
    None,
    /// A printable byte was stored: echo it.
    Echo(u8),
    /// The last byte was erased: echo "\x08 \x08".
    Erase,
    /// The line was too long; the byte was dropped (ring the bell).
    Full,
    /// Enter: the line is ready in [`LineBuffer::line`].
    Line,
}

/// A fixed buffer of [`MAX_LINE`] bytes with backspace handling; CR, LF and CR LF all end a line.
#[derive(Debug, Clone)]
pub struct LineBuffer {
    buf: [u8; MAX_LINE],
    len: usize,
    ready: bool,
    last_cr: bool,
}

impl Default for LineBuffer {
    fn default() -> Self {
        Self::new()
    }
}

impl LineBuffer {
    /// An empty buffer.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_LINE],
            len: 0,
            ready: false,
            last_cr: false,
        }
    }

    /// Feeds one received byte.
    pub fn push(&mut self, b: u8) -> LineEvent {
        let was_cr = core::mem::replace(&mut self.last_cr, b == b'\r');
        if b == b'\n' && was_cr {
            return LineEvent::None;
        }
        if self.ready {
            self.ready = false;
            self.len = 0;
        }
        match b {
            b'\r' | b'\n' => {
                self.ready = true;
                LineEvent::Line
            }
            0x08 | 0x7f => {
                if self.len > 0 {
                    self.len -= 1;
                    LineEvent::Erase
                } else {
                    LineEvent::None
                }
            }
            0x20..=0x7e | 0x80..=0xff => {
                if self.len < MAX_LINE {
                    self.buf[self.len] = b;
                    self.len += 1;
                    LineEvent::Echo(b)
                } else {
                    LineEvent::Full
                }
            }
            _ => LineEvent::None,
        }
    }

    /// The completed line (invalid UTF-8 is cut at the first bad byte).
    pub fn line(&self) -> &str {
        let bytes = &self.buf[..self.len];
        match core::str::from_utf8(bytes) {
            Ok(s) => s,
            Err(e) => core::str::from_utf8(&bytes[..e.valid_up_to()]).unwrap_or(""),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backspace_and_crlf() {
        let mut l = LineBuffer::new();
        for b in b"adx\x08c 0 1\r\n" {
            l.push(*b);
        }
        assert_eq!(l.line(), "adc 0 1");
        assert_eq!(l.push(b'v'), LineEvent::Echo(b'v'));
        assert_eq!(l.line(), "v");
    }
}
