//! Register-mapped devices (Dynamixel 2.0 and 1.0): one generic device, [`RegDevice`], over a
//! family's [`ControlTable`]: a table of channels, each a control-table register (or a
//! read/write register pair) with its size, signedness, scale, offset and the range of raw
//! values a healthy servo can report.
//!
//! Range checks matter: a CRC-16 lets about one damaged packet in 65 536 through, a 1.0
//! checksum one in 256. A value outside its register's physical range is therefore treated as
//! damaged: the channel goes stale and the rejection is counted, never delivered.

use crate::message::{Credential, Op, Reply, ReplyData, Request, Update};
use crate::queue::Bounded;
use crate::stage::{Channel, Device, SafeAction, TickCtx};

/// How raw register values are encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// Unsigned.
    Unsigned,
    /// Two's complement.
    Signed,
    /// Protocol 1.0 speed/load: bits 0–9 magnitude, bit 10 direction (set = negative).
    SignMagnitude10,
}

/// One channel of a register-mapped device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegChannel {
    /// Manifest name.
    pub name: &'static str,
    /// Physical units.
    pub units: &'static str,
    /// Register sampled (`None`: write-only).
    pub read: Option<u16>,
    /// Register written (`None`: read-only).
    pub write: Option<u16>,
    /// Register size in bytes.
    pub len: u8,
    /// Raw value encoding.
    pub encoding: Encoding,
    /// Units per raw step.
    pub scale: f64,
    /// Raw value that means 0 units.
    pub offset: i64,
    /// Raw values a read may legitimately return (inclusive).
    pub read_range: (i64, i64),
    /// Raw values a write may carry (inclusive); setpoints are clamped into it.
    pub write_range: (i64, i64),
}

impl RegChannel {
    /// A channel of `len`-byte registers with `encoding`, 1 unit per raw step from raw 0; add its
    /// registers with [`reads`](Self::reads) and [`writes`](Self::writes) and its scale with
    /// [`scaled`](Self::scaled).
    pub const fn new(name: &'static str, units: &'static str, len: u8, encoding: Encoding) -> Self {
        Self {
            name,
            units,
            read: None,
            write: None,
            len,
            encoding,
            scale: 1.0,
            offset: 0,
            read_range: (0, 0),
            write_range: (0, 0),
        }
    }

    /// Sampled from register `addr`, whose healthy raw values are `range`.
    pub const fn reads(mut self, addr: u16, range: (i64, i64)) -> Self {
        self.read = Some(addr);
        self.read_range = range;
        self
    }

    /// Written to register `addr`, setpoints clamped to the raw `range`.
    pub const fn writes(mut self, addr: u16, range: (i64, i64)) -> Self {
        self.write = Some(addr);
        self.write_range = range;
        self
    }

    /// `scale` units per raw step, raw `offset` meaning 0 units.
    pub const fn scaled(mut self, scale: f64, offset: i64) -> Self {
        self.scale = scale;
        self.offset = offset;
        self
    }

    /// The manifest-facing description.
    pub fn channel(&self) -> Channel {
        Channel {
            name: self.name,
            units: self.units,
            readable: self.read.is_some(),
            writable: self.write.is_some(),
        }
    }

    /// Raw register bits (zero-extended) → signed raw value.
    pub fn decode_raw(&self, bits: i64) -> i64 {
        let bits = bits as u64 & ((1u64 << (8 * self.len as u32)) - 1);
        match self.encoding {
            Encoding::Unsigned => bits as i64,
            Encoding::Signed => {
                let shift = 64 - 8 * self.len as u32;
                ((bits << shift) as i64) >> shift
            }
            Encoding::SignMagnitude10 => {
                let mag = (bits & 0x3FF) as i64;
                if bits & 0x400 != 0 {
                    -mag
                } else {
                    mag
                }
            }
        }
    }

    /// Signed raw value → register bits.
    pub fn encode_raw(&self, raw: i64) -> i64 {
        match self.encoding {
            Encoding::SignMagnitude10 if raw < 0 => (-raw).min(0x3FF) | 0x400,
            Encoding::SignMagnitude10 => raw.min(0x3FF),
            _ => raw & ((1i64 << (8 * self.len as u32)) - 1),
        }
    }

    /// Units → raw, rounded and clamped to the write range.
    pub fn to_raw(&self, value: f64) -> i64 {
        let r = (value / self.scale).round() + self.offset as f64;
        // `as` saturates and maps NaN to 0; the clamp keeps the register's range.
        (r as i64).clamp(self.write_range.0, self.write_range.1)
    }

    /// Raw → units.
    pub fn to_units(&self, raw: i64) -> f64 {
        (raw - self.offset) as f64 * self.scale
    }
}

/// What sets one family of register-mapped servos apart (its control table); the
/// [`RegDevice`] it parameterises does the rest.
pub trait ControlTable: std::fmt::Debug {
    /// The safe action devices of this family declare.
    const SAFE_ACTION: SafeAction;
    /// The channel whose last value [`SafeAction::Hold`] writes back to its write register
    /// (the present position, written as the goal).
    const HOLD: Option<usize>;
    /// The register write `(addr, len, value)` that switches torque off.
    const TORQUE_OFF: Option<(u16, u8, i64)>;

    /// The channels, in channel-index order.
    fn channels(&self) -> Vec<RegChannel>;

    /// Channel `i` has just taken raw value `raw` (a setpoint written, or a good value read):
    /// a family whose registers depend on each other re-ranges `table` here.
    fn on_raw(&mut self, table: &mut [RegChannel], i: usize, raw: i64) {
        let _ = (table, i, raw);
    }
}

/// A register-mapped device: sampling, buffered writes, reply interpretation, range checks
/// and safe actions over the channel table of its family `T`.
#[derive(Debug)]
pub struct RegDevice<T: ControlTable> {
    family: T,
    cred: Credential,
    table: Vec<RegChannel>,
    channels: Vec<Channel>,
    pending: Vec<Option<i64>>,
    /// Last good raw value read per channel.
    last: Vec<Option<i64>>,
    /// Tick whose replies carry a device error (alert / failed instruction).
    fault_tick: Option<u64>,
    range_rejects: u64,
    device_errors: u64,
    /// Channel index of the present position (for Hold) and the goal-position register.
    hold: Option<(usize, u16)>,
}

impl<T: ControlTable> RegDevice<T> {
    /// The safe action this kind declares.
    pub const SAFE_ACTION: SafeAction = T::SAFE_ACTION;

    /// A device of `family` at `cred`.
    pub fn with_table(cred: Credential, family: T) -> Self {
        let table = family.channels();
        let n = table.len();
        let hold = T::HOLD.and_then(|i| Some((i, table.get(i)?.write?)));
        Self {
            family,
            cred,
            channels: table.iter().map(RegChannel::channel).collect(),
            table,
            pending: vec![None; n],
            last: vec![None; n],
            fault_tick: None,
            range_rejects: 0,
            device_errors: 0,
            hold,
        }
    }

    /// The family's control table and state.
    pub fn family(&self) -> &T {
        &self.family
    }

    /// The channel table.
    pub fn table(&self) -> &[RegChannel] {
        &self.table
    }

    /// Values rejected by the range check since start (damaged packets that passed the
    /// CRC/checksum).
    pub fn range_rejects(&self) -> u64 {
        self.range_rejects
    }

    /// Device error replies since start.
    pub fn device_errors(&self) -> u64 {
        self.device_errors
    }

    /// Last good value of channel `i`, in units.
    pub fn last(&self, i: usize) -> Option<f64> {
        let raw = (*self.last.get(i)?)?;
        Some(self.table[i].to_units(raw))
    }

    fn push_write(&self, addr: u16, len: u8, value: i64, ctx: TickCtx, out: &mut Bounded<Request>) {
        let op = Op::Write { addr, len, value };
        let _ = out.push(Request::new(self.cred, op, ctx));
    }
}

impl<T: ControlTable> Device for RegDevice<T> {
    fn credential(&self) -> Credential {
        self.cred
    }

    fn channels(&self) -> &[Channel] {
        &self.channels
    }

    fn sample(&mut self, i: usize, ctx: TickCtx, out: &mut Bounded<Request>) {
        let Some(c) = self.table.get(i) else { return };
        let Some(addr) = c.read else { return };
        let _ = out.push(Request::new(self.cred, Op::Read { addr, len: c.len }, ctx));
    }

    fn write(&mut self, i: usize, value: f64, _ctx: TickCtx) {
        let Some(c) = self.table.get(i) else { return };
        if c.write.is_none() || !value.is_finite() {
            return;
        }
        let raw = c.to_raw(value);
        self.pending[i] = Some(raw);
        self.family.on_raw(&mut self.table, i, raw);
    }

    fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        for i in 0..self.table.len() {
            let Some(raw) = self.pending[i].take() else {
                continue;
            };
            let c = self.table[i];
            let Some(addr) = c.write else { continue };
            self.push_write(addr, c.len, c.encode_raw(raw), ctx, out);
        }
    }

    fn reply(&mut self, reply: &Reply, out: &mut Bounded<Update>) {
        let fault = self.fault_tick == Some(reply.tick);
        let (addr, len, value) = match reply.data {
            ReplyData::Register { addr, len, value } => (addr, len, Some(value)),
            ReplyData::Missing {
                op: Op::Read { addr, len },
            } => (addr, len, None),
            ReplyData::DeviceError { .. } => {
                self.device_errors += 1;
                self.fault_tick = Some(reply.tick);
                return;
            }
            _ => return,
        };
        for i in 0..self.table.len() {
            let c = self.table[i];
            if c.read != Some(addr) || c.len != len {
                continue;
            }
            let units = match value.map(|bits| c.decode_raw(bits)) {
                None => None,
                Some(raw) if raw < c.read_range.0 || raw > c.read_range.1 => {
                    self.range_rejects += 1;
                    None
                }
                Some(raw) => {
                    self.last[i] = Some(raw);
                    self.family.on_raw(&mut self.table, i, raw);
                    Some(c.to_units(raw))
                }
            };
            let _ = out.push(Update::from_reply(reply, i, units, fault));
        }
    }

    fn safe(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        match action {
            SafeAction::Hold => match self.hold {
                Some((i, goal)) if self.last[i].is_some() => {
                    let raw = self.last[i].unwrap_or(0);
                    let c = self.table[i];
                    let value = c.encode_raw(raw.clamp(c.write_range.0, c.write_range.1));
                    self.push_write(goal, c.len, value, ctx, out);
                }
                // Nothing known to hold: the only safe thing left is to let go.
                _ => self.safe(SafeAction::TorqueOff, ctx, out),
            },
            SafeAction::TorqueOff => {
                if let Some((addr, len, value)) = T::TORQUE_OFF {
                    self.push_write(addr, len, value, ctx, out);
                }
            }
            SafeAction::Setpoint { channel, value } => {
                self.pending.iter_mut().for_each(|p| *p = None);
                self.write(channel, value, ctx);
                self.flush(ctx, out);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ch(encoding: Encoding, len: u8) -> RegChannel {
        RegChannel::new("x", "", len, encoding)
            .reads(0, (i64::MIN, i64::MAX))
            .writes(0, (-5000, 5000))
    }

    #[test]
    fn raw_encodings() {
        let s4 = ch(Encoding::Signed, 4);
        assert_eq!(s4.decode_raw(0xFFFF_FFFF), -1);
        assert_eq!(s4.decode_raw(0x7FFF_FFFF), i32::MAX as i64);
        assert_eq!(s4.encode_raw(-1), 0xFFFF_FFFF);
        let s2 = ch(Encoding::Signed, 2);
        assert_eq!(s2.decode_raw(0x8000), -32768);
        let u1 = ch(Encoding::Unsigned, 1);
        assert_eq!(u1.decode_raw(0x1FF), 0xFF);
        let sm = ch(Encoding::SignMagnitude10, 2);
        assert_eq!(sm.decode_raw(0x400 | 100), -100);
        assert_eq!(sm.decode_raw(100), 100);
        assert_eq!(sm.encode_raw(-100), 0x400 | 100);
        assert_eq!(s4.to_raw(1e12), 5000, "clamped to the write range");
        assert_eq!(s4.to_raw(-2.6), -3);
    }
}
