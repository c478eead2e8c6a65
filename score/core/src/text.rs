//! Fixed-capacity strings (no heap): symbol names, tokens quoted in errors, file paths.

use core::fmt;

/// A UTF-8 string of at most `N` bytes stored inline.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct ShortStr<const N: usize> {
    buf: [u8; N],
    len: u8,
}

impl<const N: usize> ShortStr<N> {
    /// The empty string.
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            len: 0,
        }
    }

    /// Copies `s` if it fits, else `None`.
    pub fn try_from_str(s: &str) -> Option<Self> {
        if s.len() > N || s.len() > u8::MAX as usize {
            return None;
        }
        let mut out = Self::new();
        out.buf[..s.len()].copy_from_slice(s.as_bytes());
        out.len = s.len() as u8;
        Some(out)
    }

    /// Copies as much of `s` as fits, cutting at a character boundary; a cut string ends in `~`.
    pub fn truncated(s: &str) -> Self {
        if let Some(v) = Self::try_from_str(s) {
            return v;
        }
        let mut end = N.saturating_sub(1).min(s.len());
        while end > 0 && !s.is_char_boundary(end) {
            end -= 1;
        }
        let mut out = Self::try_from_str(&s[..end]).unwrap_or_default();
        if (out.len as usize) < N {
            out.buf[out.len as usize] = b'~';
            out.len += 1;
        }
        out
    }

    /// The text.
    pub fn as_str(&self) -> &str {
        // Only whole `&str`s cut at char boundaries are ever copied in.
        core::str::from_utf8(&self.buf[..self.len as usize]).unwrap_or("")
    }

    /// Length in bytes.
    pub fn len(&self) -> usize {
        self.len as usize
    }

    /// True for the empty string.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

impl<const N: usize> Default for ShortStr<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> fmt::Display for ShortStr<N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl<const N: usize> fmt::Debug for ShortStr<N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self.as_str(), f)
    }
}

/// A `fmt::Write` into a fixed byte buffer; writes past the end fail (and are dropped).
pub struct BufWriter<'a> {
    buf: &'a mut [u8],
    len: usize,
}

impl<'a> BufWriter<'a> {
    /// Writes into `buf` from its start.
    pub fn new(buf: &'a mut [u8]) -> Self {
        Self { buf, len: 0 }
    }

    /// What was written.
    pub fn as_str(&self) -> &str {
        core::str::from_utf8(&self.buf[..self.len]).unwrap_or("")
    }
}

impl fmt::Write for BufWriter<'_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        let end = self.len + s.len();
        if end > self.buf.len() {
            return Err(fmt::Error);
        }
        self.buf[self.len..end].copy_from_slice(s.as_bytes());
        self.len = end;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn truncation_keeps_char_boundaries() {
        let s: ShortStr<4> = ShortStr::truncated("aé€x");
        assert_eq!(s.as_str(), "aé~");
        let t: ShortStr<8> = ShortStr::truncated("abc");
        assert_eq!(t.as_str(), "abc");
        assert!(ShortStr::<2>::try_from_str("abc").is_none());
    }
}
