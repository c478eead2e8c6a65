//! ROBOTIS Dynamixel Protocol 1.0 (AX-12, MX on P1 firmware, RX).
//!
//! Instruction `FF FF ID LEN INST params… CHK`, status `FF FF ID LEN ERR params… CHK`,
//! `LEN = params + 2`, `CHK = !(ID + LEN + INST/ERR + Σparams)` (low byte). No stuffing, no
//! reserved byte; IDs 0–253, broadcast 0xFE.
//!
//! Encoders: [`ping`], [`read`], [`write()`], [`reg_write`], [`action`], [`reset`],
//! [`sync_write`], [`bulk_read`] (MX only), and [`status`] for simulators. Decoding:
//! [`Scanner`] (byte stream → checked [`Packet`]s), [`parse`] (one packet),
//! [`Status`] and [`ErrorBits`].

use crate::scan::{Engine, Framing, ScanStats};
use crate::writer::Writer;
use crate::BufferTooSmall;

/// The two bytes every packet starts with.
pub const HEADER: [u8; 2] = [0xFF, 0xFF];
/// The broadcast ID.
pub const BROADCAST_ID: u8 = 0xFE;
/// The largest device ID.
pub const MAX_DEVICE_ID: u8 = 0xFD;
/// Largest packet: LEN is one byte.
pub const MAX_PACKET: usize = 4 + 255;

/// Instruction codes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Instruction {
    /// 0x01.
    Ping = 0x01,
    /// 0x02: read (addr, len).
    Read = 0x02,
    /// 0x03: write (addr, data…).
    Write = 0x03,
    /// 0x04: staged write.
    RegWrite = 0x04,
    /// 0x05: run staged writes.
    Action = 0x05,
    /// 0x06: factory reset.
    Reset = 0x06,
    /// 0x83: same address/length on many IDs, no reply.
    SyncWrite = 0x83,
    /// 0x92: bulk read (MX only).
    BulkRead = 0x92,
}

/// The 1.0 checksum over ID, LEN, INST/ERR and parameters (the bytes after the header).
pub fn checksum(body: &[u8]) -> u8 {
    !body.iter().fold(0u8, |a, &b| a.wrapping_add(b))
}

/// Why a packet could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// The output buffer cannot hold the packet.
    #[error("output buffer too small")]
    BufferTooSmall,
    /// The ID is not valid here.
    #[error("invalid ID {0:#04x}")]
    InvalidId(u8),
    /// An entry's data length differs from the declared one.
    #[error("data length {got} where {expected} is required")]
    DataLength {
        /// Declared length.
        expected: usize,
        /// Supplied length.
        got: usize,
    },
    /// Sync write / bulk read without entries.
    #[error("no entries")]
    NoEntries,
    /// An ID appears twice.
    #[error("ID {0} listed twice")]
    DuplicateId(u8),
    /// More than 253 parameter bytes (LEN is one byte).
    #[error("packet too long for the length field")]
    TooLong,
}

impl From<BufferTooSmall> for EncodeError {
    fn from(_: BufferTooSmall) -> Self {
        EncodeError::BufferTooSmall
    }
}

struct Builder<'a> {
    w: Writer<'a>,
}

impl<'a> Builder<'a> {
    fn new(buf: &'a mut [u8], id: u8, inst: u8) -> Result<Self, EncodeError> {
        let mut w = Writer::new(buf);
        w.put_all(&[0xFF, 0xFF, id, 0, inst])?;
        Ok(Self { w })
    }

    fn bytes(&mut self, b: &[u8]) -> Result<(), EncodeError> {
        Ok(self.w.put_all(b)?)
    }

    fn finish(mut self) -> Result<usize, EncodeError> {
        let len = u8::try_from(self.w.pos() - 4 + 1).map_err(|_| EncodeError::TooLong)?;
        self.w.set(3, len);
        let chk = checksum(&self.w.written()[2..]);
        self.w.put(chk)?;
        Ok(self.w.pos())
    }
}

fn device_id(id: u8) -> Result<u8, EncodeError> {
    if id <= MAX_DEVICE_ID {
        Ok(id)
    } else {
        Err(EncodeError::InvalidId(id))
    }
}

fn device_or_broadcast(id: u8) -> Result<u8, EncodeError> {
    if id <= BROADCAST_ID {
        Ok(id)
    } else {
        Err(EncodeError::InvalidId(id))
    }
}

fn simple(buf: &mut [u8], id: u8, inst: Instruction, params: &[u8]) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, id, inst as u8)?;
    b.bytes(params)?;
    b.finish()
}

/// PING.
pub fn ping(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    simple(buf, device_or_broadcast(id)?, Instruction::Ping, &[])
}

/// READ `len` bytes at `addr`.
pub fn read(buf: &mut [u8], id: u8, addr: u8, len: u8) -> Result<usize, EncodeError> {
    simple(buf, device_id(id)?, Instruction::Read, &[addr, len])
}

fn write_like(
    buf: &mut [u8],
    inst: Instruction,
    id: u8,
    addr: u8,
    data: &[u8],
) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, device_or_broadcast(id)?, inst as u8)?;
    b.bytes(&[addr])?;
    b.bytes(data)?;
    b.finish()
}

/// WRITE `data` at `addr`.
pub fn write(buf: &mut [u8], id: u8, addr: u8, data: &[u8]) -> Result<usize, EncodeError> {
    write_like(buf, Instruction::Write, id, addr, data)
}

/// REG_WRITE `data` at `addr` (applied by [`action`]).
pub fn reg_write(buf: &mut [u8], id: u8, addr: u8, data: &[u8]) -> Result<usize, EncodeError> {
    write_like(buf, Instruction::RegWrite, id, addr, data)
}

/// ACTION.
pub fn action(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    simple(buf, device_or_broadcast(id)?, Instruction::Action, &[])
}

/// RESET (factory settings).
pub fn reset(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    simple(buf, device_or_broadcast(id)?, Instruction::Reset, &[])
}

/// SYNC WRITE of `len` bytes at `addr`; entries are `(id, data)` with `data.len() == len`.
pub fn sync_write<'d>(
    buf: &mut [u8],
    addr: u8,
    len: u8,
    entries: impl IntoIterator<Item = (u8, &'d [u8])>,
) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, BROADCAST_ID, Instruction::SyncWrite as u8)?;
    b.bytes(&[addr, len])?;
    let mut seen = [false; 256];
    let mut any = false;
    for (id, data) in entries {
        device_id(id)?;
        if core::mem::replace(&mut seen[id as usize], true) {
            return Err(EncodeError::DuplicateId(id));
        }
        if data.len() != len as usize {
            return Err(EncodeError::DataLength {
                expected: len as usize,
                got: data.len(),
            });
        }
        b.bytes(&[id])?;
        b.bytes(data)?;
        any = true;
    }
    if !any {
        return Err(EncodeError::NoEntries);
    }
    b.finish()
}

/// One device's part of a BULK READ (MX series).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BulkReadEntry {
    /// Bytes to read.
    pub len: u8,
    /// Device ID.
    pub id: u8,
    /// Start address.
    pub addr: u8,
}

/// BULK READ (MX only): `0x00, [len id addr]…`.
pub fn bulk_read(
    buf: &mut [u8],
    entries: impl IntoIterator<Item = BulkReadEntry>,
) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, BROADCAST_ID, Instruction::BulkRead as u8)?;
    b.bytes(&[0x00])?;
    let mut any = false;
    for e in entries {
        device_id(e.id)?;
        b.bytes(&[e.len, e.id, e.addr])?;
        any = true;
    }
    if !any {
        return Err(EncodeError::NoEntries);
    }
    b.finish()
}

/// A status packet (what a servo or simulator sends).
pub fn status(
    buf: &mut [u8],
    id: u8,
    error: ErrorBits,
    params: &[u8],
) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, device_id(id)?, error.0)?;
    b.bytes(params)?;
    b.finish()
}

/// A checksum-verified packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Packet<'a> {
    /// Device ID.
    pub id: u8,
    /// Instruction (instruction packet) or error byte (status packet): the protocol does not
    /// say which; the direction does.
    pub code: u8,
    /// Parameters, without the checksum.
    pub params: &'a [u8],
}

/// Why bytes are not a valid packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    /// Fewer bytes than needed.
    #[error("incomplete packet: {needed} bytes needed, {got} present")]
    Incomplete {
        /// Bytes needed.
        needed: usize,
        /// Bytes present.
        got: usize,
    },
    /// No `FF FF` header.
    #[error("no packet header")]
    BadHeader,
    /// ID 0xFF.
    #[error("invalid ID {0:#04x}")]
    BadId(u8),
    /// LEN below 2.
    #[error("invalid length field {0}")]
    BadLength(u8),
    /// Checksum mismatch.
    #[error("checksum mismatch: packet says {received:#04x}, bytes give {computed:#04x}")]
    Checksum {
        /// Carried by the packet.
        received: u8,
        /// Computed.
        computed: u8,
    },
}

/// Parses the packet at the start of `buf`; returns it and its wire length.
pub fn parse(buf: &[u8]) -> Result<(Packet<'_>, usize), ParseError> {
    if buf.len() < 4 {
        return Err(ParseError::Incomplete {
            needed: 4,
            got: buf.len(),
        });
    }
    if buf[..2] != HEADER {
        return Err(ParseError::BadHeader);
    }
    if buf[2] == 0xFF {
        return Err(ParseError::BadId(0xFF));
    }
    if buf[3] < 2 {
        return Err(ParseError::BadLength(buf[3]));
    }
    let total = 4 + buf[3] as usize;
    if buf.len() < total {
        return Err(ParseError::Incomplete {
            needed: total,
            got: buf.len(),
        });
    }
    let computed = checksum(&buf[2..total - 1]);
    if computed != buf[total - 1] {
        return Err(ParseError::Checksum {
            received: buf[total - 1],
            computed,
        });
    }
    Ok((decode_checked(&buf[..total]), total))
}

fn decode_checked(frame: &[u8]) -> Packet<'_> {
    Packet {
        id: frame[2],
        code: frame[4],
        params: &frame[5..frame.len() - 1],
    }
}

/// The status error byte (bit flags).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ErrorBits(pub u8);

impl ErrorBits {
    /// Bit 0: input voltage out of range.
    pub const INPUT_VOLTAGE: u8 = 1 << 0;
    /// Bit 1: goal position outside the angle limits.
    pub const ANGLE_LIMIT: u8 = 1 << 1;
    /// Bit 2: overheating.
    pub const OVERHEATING: u8 = 1 << 2;
    /// Bit 3: command out of range.
    pub const RANGE: u8 = 1 << 3;
    /// Bit 4: checksum of the instruction was wrong.
    pub const CHECKSUM: u8 = 1 << 4;
    /// Bit 5: load exceeds the torque limit.
    pub const OVERLOAD: u8 = 1 << 5;
    /// Bit 6: undefined instruction or ACTION without REG_WRITE.
    pub const INSTRUCTION: u8 = 1 << 6;

    /// No error bit set.
    pub fn is_ok(self) -> bool {
        self.0 == 0
    }
    /// Whether all bits of `mask` are set.
    pub fn has(self, mask: u8) -> bool {
        self.0 & mask == mask
    }
    /// Input voltage error.
    pub fn input_voltage(self) -> bool {
        self.has(Self::INPUT_VOLTAGE)
    }
    /// Angle limit error.
    pub fn angle_limit(self) -> bool {
        self.has(Self::ANGLE_LIMIT)
    }
    /// Overheating error.
    pub fn overheating(self) -> bool {
        self.has(Self::OVERHEATING)
    }
    /// Range error.
    pub fn range(self) -> bool {
        self.has(Self::RANGE)
    }
    /// Checksum error.
    pub fn checksum(self) -> bool {
        self.has(Self::CHECKSUM)
    }
    /// Overload error.
    pub fn overload(self) -> bool {
        self.has(Self::OVERLOAD)
    }
    /// Instruction error.
    pub fn instruction(self) -> bool {
        self.has(Self::INSTRUCTION)
    }
}

/// A packet read as a status packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Status<'a> {
    /// Replying device.
    pub id: u8,
    /// Error flags.
    pub error: ErrorBits,
    /// Data (e.g. the bytes of a READ).
    pub data: &'a [u8],
}

impl<'a> Status<'a> {
    /// Reads `p` as a status packet (its code byte is the error byte).
    pub fn from_packet(p: &Packet<'a>) -> Self {
        Status {
            id: p.id,
            error: ErrorBits(p.code),
            data: p.params,
        }
    }

    /// Data as a little-endian u8 or u16.
    pub fn data_u16(&self) -> Option<u16> {
        match *self.data {
            [a] => Some(a as u16),
            [a, b] => Some(u16::from_le_bytes([a, b])),
            _ => None,
        }
    }
}

struct Dxl1;

impl Framing for Dxl1 {
    const HEADER: &'static [u8] = &HEADER;
    const FIELDS_LEN: usize = 4;

    fn total_len(f: &[u8]) -> Option<usize> {
        (f[2] != 0xFF && f[3] >= 2).then_some(4 + f[3] as usize)
    }

    fn check(p: &[u8]) -> bool {
        let n = p.len();
        checksum(&p[2..n - 1]) == p[n - 1]
    }
}

/// Fixed-capacity Protocol 1.0 stream scanner with discard counters (see [`crate::scan`]).
///
/// The header `FF FF` is weak (it appears in data), so the checksum does most of the work;
/// a run of `FF`s before a packet is counted as `bad_header` (ID 0xFF) byte by byte.
pub struct Scanner<const N: usize = 512> {
    engine: Engine<N>,
}

impl<const N: usize> Default for Scanner<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Scanner<N> {
    const MIN_CAPACITY: () = assert!(N >= 16, "scanner capacity must be at least 16 bytes");

    /// A scanner accepting packets up to `min(N - 1, 259)` bytes.
    pub fn new() -> Self {
        Self::with_max_packet(MAX_PACKET)
    }

    /// A scanner accepting packets up to `max_packet` bytes (clamped to `N - 1`).
    pub fn with_max_packet(max_packet: usize) -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::MIN_CAPACITY;
        Self {
            engine: Engine::new(max_packet.clamp(6, MAX_PACKET), HEADER.len()),
        }
    }

    /// Copies as many bytes as fit; returns how many were taken.
    pub fn push(&mut self, bytes: &[u8]) -> usize {
        self.engine.push(bytes)
    }

    /// The next checksum-verified packet (borrowed until the next call).
    pub fn next_packet(&mut self) -> Option<Packet<'_>> {
        let range = self.engine.next_frame::<Dxl1>()?;
        Some(decode_checked(&self.engine.buf_mut()[range]))
    }

    /// No more bytes are coming for what is buffered: see
    /// [`dynamixel2::Scanner::expire`](crate::dynamixel2::Scanner::expire).
    pub fn expire(&mut self) {
        self.engine.expire();
    }

    /// Pushes all of `bytes`, calling `on_packet` for every packet completed.
    pub fn feed(&mut self, mut bytes: &[u8], mut on_packet: impl FnMut(Packet<'_>)) {
        loop {
            let n = self.push(bytes);
            bytes = &bytes[n..];
            while let Some(p) = self.next_packet() {
                on_packet(p);
            }
            if bytes.is_empty() {
                return;
            }
        }
    }

    /// [`expire`](Self::expire), then drain.
    pub fn expire_with(&mut self, mut on_packet: impl FnMut(Packet<'_>)) {
        self.expire();
        while let Some(p) = self.next_packet() {
            on_packet(p);
        }
    }

    /// Discard counters since creation.
    pub fn stats(&self) -> &ScanStats {
        self.engine.stats()
    }

    /// Bytes accepted but not yet yielded or discarded.
    pub fn buffered(&self) -> usize {
        self.engine.buffered()
    }
}
