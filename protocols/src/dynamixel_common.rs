//! What Dynamixel Protocol 1.0 and 2.0 share above their wire formats: which IDs address
//! what, the encoders' error type, and the checked entry lists of the sync/bulk instructions.
//! Header, length field, checksum/CRC and stuffing stay with each protocol.

use crate::BufferTooSmall;

/// The broadcast ID of both protocols.
pub(crate) const BROADCAST_ID: u8 = 0xFE;

/// Why a packet could not be encoded (Protocol 1.0 and 2.0 alike).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// The output buffer cannot hold the packet.
    #[error("output buffer too small")]
    BufferTooSmall,
    /// The ID is not a device ID (0–253 on 1.0, 0–252 on 2.0), or is broadcast where broadcast
    /// is not allowed.
    #[error("invalid ID {0:#04x}")]
    InvalidId(u8),
    /// An entry's data length differs from the length the instruction declares.
    #[error("data length {got} where {expected} is required")]
    DataLength {
        /// Length the packet declares.
        expected: usize,
        /// Length supplied.
        got: usize,
    },
    /// An ID appears twice in one sync/bulk instruction.
    #[error("ID {0} listed twice")]
    DuplicateId(u8),
    /// A sync/bulk instruction without any entry.
    #[error("no entries")]
    NoEntries,
    /// The packet would exceed its length field (one byte on 1.0, two on 2.0).
    #[error("packet too long for the length field")]
    TooLong,
}

impl From<BufferTooSmall> for EncodeError {
    fn from(_: BufferTooSmall) -> Self {
        EncodeError::BufferTooSmall
    }
}

/// Whether `id` may stand in a packet's ID field: a device ID up to `max_device_id`, or
/// broadcast.
pub(crate) const fn addressable(id: u8, max_device_id: u8) -> bool {
    id <= max_device_id || id == BROADCAST_ID
}

/// `id`, if it addresses one device.
pub(crate) fn device_id(id: u8, max_device_id: u8) -> Result<u8, EncodeError> {
    if id <= max_device_id {
        Ok(id)
    } else {
        Err(EncodeError::InvalidId(id))
    }
}

/// `id`, if it addresses one device or all of them.
pub(crate) fn device_or_broadcast(id: u8, max_device_id: u8) -> Result<u8, EncodeError> {
    if addressable(id, max_device_id) {
        Ok(id)
    } else {
        Err(EncodeError::InvalidId(id))
    }
}

/// 256-bit set for duplicate-ID checks.
#[derive(Default)]
pub(crate) struct IdSet([u64; 4]);

impl IdSet {
    pub(crate) fn insert(&mut self, id: u8) -> Result<(), EncodeError> {
        let (word, bit) = ((id >> 6) as usize, 1u64 << (id & 63));
        if self.0[word] & bit != 0 {
            return Err(EncodeError::DuplicateId(id));
        }
        self.0[word] |= bit;
        Ok(())
    }
}

/// The entry list of a sync/bulk instruction: checks that each entry's ID (`id_of`) is a
/// device ID listed once, then writes the entry with `put`; fails on an empty list.
pub(crate) fn entries<T>(
    items: impl IntoIterator<Item = T>,
    max_device_id: u8,
    id_of: impl Fn(&T) -> u8,
    mut put: impl FnMut(T) -> Result<(), EncodeError>,
) -> Result<(), EncodeError> {
    let mut seen = IdSet::default();
    let mut any = false;
    for item in items {
        seen.insert(device_id(id_of(&item), max_device_id)?)?;
        put(item)?;
        any = true;
    }
    if any {
        Ok(())
    } else {
        Err(EncodeError::NoEntries)
    }
}

/// The entries of a SYNC WRITE of `len` bytes: `(id, data)` with `data.len() == len`, each
/// written with `put` (the protocol's own byte layout).
pub(crate) fn sync_write_entries<'d>(
    items: impl IntoIterator<Item = (u8, &'d [u8])>,
    max_device_id: u8,
    len: usize,
    mut put: impl FnMut(u8, &'d [u8]) -> Result<(), EncodeError>,
) -> Result<(), EncodeError> {
    entries(
        items,
        max_device_id,
        |e| e.0,
        |(id, data)| {
            if data.len() != len {
                return Err(EncodeError::DataLength {
                    expected: len,
                    got: data.len(),
                });
            }
            put(id, data)
        },
    )
}
