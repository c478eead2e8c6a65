//! Byte stuffing: inside the instruction/parameter region a `FF FF FD` gets an extra `FD`
//! (`FF FF FD` → `FF FF FD FD`) so that a header can never appear inside a packet.

use crate::writer::Writer;
use crate::BufferTooSmall;

/// Stuffs bytes as they are written, remembering the last two unstuffed bytes.
#[derive(Default, Clone, Copy)]
pub(crate) struct Stuffer {
    prev: [u8; 2],
}

impl Stuffer {
    pub(crate) fn put(&mut self, w: &mut Writer<'_>, b: u8) -> Result<(), BufferTooSmall> {
        w.put(b)?;
        if b == 0xFD && self.prev == [0xFF, 0xFF] {
            w.put(0xFD)?;
        }
        self.prev = [self.prev[1], b];
        Ok(())
    }
}

/// Writes `src` into `dst` with stuffing applied; returns the stuffed length.
pub fn stuff(src: &[u8], dst: &mut [u8]) -> Result<usize, BufferTooSmall> {
    let mut w = Writer::new(dst);
    let mut s = Stuffer::default();
    for &b in src {
        s.put(&mut w, b)?;
    }
    Ok(w.pos())
}

/// Number of bytes `src` occupies once stuffed.
pub fn stuffed_len(src: &[u8]) -> usize {
    src.len() + src.windows(3).filter(|w| *w == [0xFF, 0xFF, 0xFD]).count()
}

/// Removes stuffing in place (`FF FF FD FD` → `FF FF FD`); returns the unstuffed length.
///
/// A `FF FF FD` not followed by `FD` is kept as is: that cannot happen in a packet whose CRC
/// checked, and it is not this function's job to reject it.
pub fn unstuff_in_place(buf: &mut [u8]) -> usize {
    let mut out = 0;
    let mut i = 0;
    while i < buf.len() {
        let b = buf[i];
        buf[out] = b;
        out += 1;
        i += 1;
        if b == 0xFD
            && out >= 3
            && buf[out - 3] == 0xFF
            && buf[out - 2] == 0xFF
            && buf.get(i) == Some(&0xFD)
        {
            i += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stuffs_the_pattern() {
        let mut out = [0u8; 16];
        let n = stuff(&[0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00], &mut out).unwrap();
        assert_eq!(&out[..n], &[0x74, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x00]);
        assert_eq!(stuffed_len(&[0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00]), 7);
    }

    #[test]
    fn already_stuffed_looking_input_gains_one_fd() {
        let src = [0xFF, 0xFF, 0xFD, 0xFD];
        let mut out = [0u8; 8];
        let n = stuff(&src, &mut out).unwrap();
        assert_eq!(&out[..n], &[0xFF, 0xFF, 0xFD, 0xFD, 0xFD]);
        let m = unstuff_in_place(&mut out[..n]);
        assert_eq!(&out[..m], &src);
    }

    #[test]
    fn too_small_output_is_an_error() {
        let mut out = [0u8; 3];
        assert_eq!(stuff(&[0xFF, 0xFF, 0xFD], &mut out), Err(BufferTooSmall));
    }
}
