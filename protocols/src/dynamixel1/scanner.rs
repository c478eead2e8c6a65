//! Stream scanner for Protocol 1.0.

use super::packet::{decode_checked, Packet};
use super::{checksum, HEADER, MAX_DEVICE_ID, MAX_PACKET};
use crate::dynamixel_common::addressable;
use crate::scan::{Framing, PacketScanner};

/// The Protocol 1.0 framing: header `FF FF`, ID, one-byte length, checksum.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dxl1Framing;

impl Framing for Dxl1Framing {
    type Packet<'a> = Packet<'a>;
    const HEADER: &'static [u8] = &HEADER;
    const FIELDS_LEN: usize = 4;
    const MIN_PACKET: usize = 6;
    const MAX_PACKET: usize = MAX_PACKET;

    fn total_len(f: &[u8]) -> Option<usize> {
        (addressable(f[2], MAX_DEVICE_ID) && f[3] >= 2).then_some(4 + f[3] as usize)
    }

    fn check(p: &[u8]) -> bool {
        let n = p.len();
        checksum(&p[2..n - 1]) == p[n - 1]
    }

    fn decode(frame: &mut [u8]) -> Packet<'_> {
        decode_checked(frame)
    }
}

/// Fixed-capacity Protocol 1.0 stream scanner with discard counters ([`PacketScanner`]):
/// packets up to `min(N - 1, 259)` bytes.
///
/// The header `FF FF` is weak (it appears in data), so the checksum does most of the work;
/// a run of `FF`s before a packet is counted as `bad_header` (ID 0xFF) byte by byte.
pub type Scanner<const N: usize = 512> = PacketScanner<Dxl1Framing, N>;
