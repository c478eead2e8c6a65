//! Little-endian field reader for message bodies.

use super::message::MessageError;

/// A cursor over a received message body.
pub(crate) struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(buf: &'a [u8]) -> Self {
        Self { buf, pos: 0 }
    }

    pub(crate) fn bytes(&mut self, n: usize) -> Result<&'a [u8], MessageError> {
        let end = self.pos.checked_add(n).ok_or(MessageError::Truncated)?;
        let s = self.buf.get(self.pos..end).ok_or(MessageError::Truncated)?;
        self.pos = end;
        Ok(s)
    }

    pub(crate) fn u8(&mut self) -> Result<u8, MessageError> {
        Ok(self.bytes(1)?[0])
    }

    pub(crate) fn u16(&mut self) -> Result<u16, MessageError> {
        let b = self.bytes(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }

    pub(crate) fn u32(&mut self) -> Result<u32, MessageError> {
        let b = self.bytes(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    pub(crate) fn u64(&mut self) -> Result<u64, MessageError> {
        let mut a = [0u8; 8];
        a.copy_from_slice(self.bytes(8)?);
        Ok(u64::from_le_bytes(a))
    }

    pub(crate) fn f64(&mut self) -> Result<f64, MessageError> {
        Ok(f64::from_bits(self.u64()?))
    }

    pub(crate) fn bool(&mut self) -> Result<bool, MessageError> {
        match self.u8()? {
            0 => Ok(false),
            1 => Ok(true),
            v => Err(MessageError::BadField {
                field: "flag",
                value: v as u32,
            }),
        }
    }

    /// A string: length u8, then UTF-8 bytes; longer than `max` is refused, as the encoder
    /// refuses to write it (a peer gets nothing a conforming sender could not have sent).
    pub(crate) fn str(&mut self, max: usize) -> Result<&'a str, MessageError> {
        let n = self.u8()? as usize;
        if n > max {
            return Err(MessageError::TooLong);
        }
        core::str::from_utf8(self.bytes(n)?).map_err(|_| MessageError::BadUtf8)
    }

    pub(crate) fn end(&self) -> Result<(), MessageError> {
        if self.pos == self.buf.len() {
            Ok(())
        } else {
            Err(MessageError::TrailingBytes {
                extra: self.buf.len() - self.pos,
            })
        }
    }
}
