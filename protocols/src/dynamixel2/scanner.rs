//! Stream scanner: bytes in any chunking → CRC-checked, unstuffed packets.

use super::packet::{decode_checked, id_is_valid, Packet};
use super::{crc, HEADER};
use crate::scan::{Framing, PacketScanner};

/// The Protocol 2.0 framing: header `FF FF FD 00`, ID, two-byte length, CRC-16; the scanner
/// removes the byte stuffing of the packets it yields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dxl2Framing;

impl Framing for Dxl2Framing {
    type Packet<'a> = Packet<'a>;
    const HEADER: &'static [u8] = &HEADER;
    const FIELDS_LEN: usize = 7;
    const MIN_PACKET: usize = 10;
    const MAX_PACKET: usize = usize::MAX;

    fn total_len(f: &[u8]) -> Option<usize> {
        let len = u16::from_le_bytes([f[5], f[6]]);
        (id_is_valid(f[4]) && len >= 3).then_some(7 + len as usize)
    }

    fn check(p: &[u8]) -> bool {
        let n = p.len();
        crc::crc16(&p[..n - 2]) == u16::from_le_bytes([p[n - 2], p[n - 1]])
    }

    fn decode(frame: &mut [u8]) -> Packet<'_> {
        decode_checked(frame)
    }
}

/// Fixed-capacity Dynamixel 2.0 stream scanner with discard counters ([`PacketScanner`]).
///
/// `N` is the buffer capacity; the largest packet it yields is `N - 3` bytes (or the smaller
/// maximum given to `with_max_packet`): a longer candidate counts as `oversize`. Packets come
/// with their stuffing removed.
///
/// ```
/// use conductor_protocols::dynamixel2::{Scanner, Status};
/// let mut s = Scanner::<256>::new();
/// let wire = [0x00, 0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x04, 0x00, 0x55, 0x00, 0xA1, 0x0C];
/// let mut ids = [0u8; 1];
/// s.feed(&wire, |p| ids[0] = Status::from_packet(&p).unwrap().id);
/// assert_eq!(ids, [1]);
/// assert_eq!(s.stats().garbage.bytes, 1);
/// ```
pub type Scanner<const N: usize = 1024> = PacketScanner<Dxl2Framing, N>;
