//! A classic CAN 2.0 frame (standard or extended ID, up to 8 data bytes, or remote) that
//! implements [`embedded_can::Frame`], so the CAN codecs work with it, with socketcan's frames
//! and with embedded HAL frames alike.

use embedded_can::{ExtendedId, Frame, Id, StandardId};

/// A classic CAN frame stored inline (no allocation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CanFrame {
    id: Id,
    remote: bool,
    dlc: u8,
    data: [u8; 8],
}

impl CanFrame {
    /// A data frame with a standard (11-bit) ID; `None` if `id > 0x7FF` or `data.len() > 8`.
    pub fn standard(id: u16, data: &[u8]) -> Option<Self> {
        Self::new(StandardId::new(id)?, data)
    }

    /// A data frame with an extended (29-bit) ID; `None` if out of range or `data.len() > 8`.
    pub fn extended(id: u32, data: &[u8]) -> Option<Self> {
        Self::new(ExtendedId::new(id)?, data)
    }

    /// The ID as a number (11 or 29 significant bits).
    pub fn raw_id(&self) -> u32 {
        raw_id(self.id)
    }
}

/// The numeric value of an [`Id`].
pub fn raw_id(id: Id) -> u32 {
    match id {
        Id::Standard(s) => s.as_raw() as u32,
        Id::Extended(e) => e.as_raw(),
    }
}

impl Frame for CanFrame {
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        if data.len() > 8 {
            return None;
        }
        let mut buf = [0u8; 8];
        buf[..data.len()].copy_from_slice(data);
        Some(Self {
            id: id.into(),
            remote: false,
            dlc: data.len() as u8,
            data: buf,
        })
    }

    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        if dlc > 8 {
            return None;
        }
        Some(Self {
            id: id.into(),
            remote: true,
            dlc: dlc as u8,
            data: [0; 8],
        })
    }

    fn is_extended(&self) -> bool {
        matches!(self.id, Id::Extended(_))
    }

    fn is_remote_frame(&self) -> bool {
        self.remote
    }

    fn id(&self) -> Id {
        self.id
    }

    fn dlc(&self) -> usize {
        self.dlc as usize
    }

    /// The data bytes; empty for a remote frame.
    fn data(&self) -> &[u8] {
        if self.remote {
            &[]
        } else {
            &self.data[..self.dlc as usize]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standard_extended_remote() {
        let f = CanFrame::standard(0x123, &[1, 2, 3]).unwrap();
        assert!(f.is_standard() && f.is_data_frame());
        assert_eq!((f.raw_id(), f.dlc(), f.data()), (0x123, 3, &[1, 2, 3][..]));
        assert!(CanFrame::standard(0x800, &[]).is_none());
        assert!(CanFrame::standard(0x7FF, &[0; 9]).is_none());
        let e = CanFrame::extended(0x12AB_CDEF, &[0xAA, 0x55]).unwrap();
        assert!(e.is_extended());
        assert_eq!(e.raw_id(), 0x12AB_CDEF);
        assert!(CanFrame::extended(0x2000_0000, &[]).is_none());
        let r = CanFrame::new_remote(StandardId::new(0x29).unwrap(), 8).unwrap();
        assert!(r.is_remote_frame());
        assert_eq!((r.dlc(), r.data().len()), (8, 0));
        assert!(CanFrame::new_remote(StandardId::new(0x29).unwrap(), 9).is_none());
    }
}
