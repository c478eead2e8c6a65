//! A bounds-checked cursor over a caller-provided output buffer.

/// The output buffer handed to an encoder cannot hold the encoded bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("output buffer too small")]
pub struct BufferTooSmall;

/// Appends bytes to a borrowed slice, failing (without writing past the end) when it is full.
pub(crate) struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl<'a> Writer<'a> {
    pub(crate) fn new(buf: &'a mut [u8]) -> Self {
        Self { buf, pos: 0 }
    }

    pub(crate) fn pos(&self) -> usize {
        self.pos
    }

    pub(crate) fn put(&mut self, byte: u8) -> Result<(), BufferTooSmall> {
        let slot = self.buf.get_mut(self.pos).ok_or(BufferTooSmall)?;
        *slot = byte;
        self.pos += 1;
        Ok(())
    }

    pub(crate) fn put_all(&mut self, bytes: &[u8]) -> Result<(), BufferTooSmall> {
        let end = self.pos.checked_add(bytes.len()).ok_or(BufferTooSmall)?;
        self.buf
            .get_mut(self.pos..end)
            .ok_or(BufferTooSmall)?
            .copy_from_slice(bytes);
        self.pos = end;
        Ok(())
    }

    /// Overwrites an already written byte (used to patch length fields).
    pub(crate) fn set(&mut self, at: usize, byte: u8) {
        debug_assert!(at < self.pos);
        if let Some(slot) = self.buf.get_mut(at) {
            *slot = byte;
        }
    }

    pub(crate) fn written(&self) -> &[u8] {
        &self.buf[..self.pos]
    }
}
