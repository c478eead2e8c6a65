//! Register-mapped devices (Dynamixel 2.0 and 1.0): a table of channels, each a control-table
//! register (or a read/write register pair) with its size, signedness, scale, offset and the
//! range of raw values a healthy servo can report.
//!
//! Range checks matter: a CRC-16 lets about one damaged packet in 65 536 through, a 1.0
//! checksum one in 256. A value outside its register's physical range is therefore treated as
//! damaged: the channel goes stale and the rejection is counted, never delivered.

use crate::message::{Credential, Op, Reply, ReplyData, Request, Update};
use crate::queue::Bounded;
use crate::stage::{Channel, SafeAction, TickCtx};

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

/// The generic register device: sampling, buffered writes, reply interpretation, range
/// checks and safe actions over a channel table.
#[derive(Debug)]
pub struct RegDevice {
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
    /// Register and value that switch torque off.
    torque_off: Option<(u16, u8, i64)>,
}

impl RegDevice {
    /// A device at `cred` with channel `table`; `hold` names the present-position channel
    /// whose last value is written back as the goal for [`SafeAction::Hold`], `torque_off` the
    /// register write that disables torque.
    pub fn new(
        cred: Credential,
        table: Vec<RegChannel>,
        hold: Option<usize>,
        torque_off: Option<(u16, u8, i64)>,
    ) -> Self {
        let n = table.len();
        let hold = hold.and_then(|i| Some((i, table.get(i)?.write?)));
        Self {
            cred,
            channels: table.iter().map(RegChannel::channel).collect(),
            table,
            pending: vec![None; n],
            last: vec![None; n],
            fault_tick: None,
            range_rejects: 0,
            device_errors: 0,
            hold,
            torque_off,
        }
    }

    /// The device's address.
    pub fn credential(&self) -> Credential {
        self.cred
    }

    /// The channel descriptions.
    pub fn channels(&self) -> &[Channel] {
        &self.channels
    }

    /// The channel table.
    pub fn table(&self) -> &[RegChannel] {
        &self.table
    }

    /// Replaces channel `i`'s write range (e.g. after an operating-mode change).
    pub fn set_write_range(&mut self, i: usize, range: (i64, i64)) {
        if let Some(c) = self.table.get_mut(i) {
            c.write_range = range;
        }
    }

    /// Values rejected by the range check since start.
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

    /// Queues the read of channel `i`.
    pub fn sample(&mut self, i: usize, ctx: TickCtx, out: &mut Bounded<Request>) {
        let Some(c) = self.table.get(i) else { return };
        let Some(addr) = c.read else { return };
        let _ = out.push(Request::new(self.cred, Op::Read { addr, len: c.len }, ctx));
    }

    /// Records a setpoint (units) for channel `i`; returns the raw value stored.
    pub fn write(&mut self, i: usize, value: f64) -> Option<i64> {
        let c = self.table.get(i)?;
        c.write?;
        if !value.is_finite() {
            return None;
        }
        let raw = c.to_raw(value);
        self.pending[i] = Some(raw);
        Some(raw)
    }

    /// Emits the buffered writes.
    pub fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        for i in 0..self.table.len() {
            let Some(raw) = self.pending[i].take() else {
                continue;
            };
            let c = self.table[i];
            let Some(addr) = c.write else { continue };
            let op = Op::Write {
                addr,
                len: c.len,
                value: c.encode_raw(raw),
            };
            let _ = out.push(Request::new(self.cred, op, ctx));
        }
    }

    /// Interprets a reply: returns, per updated channel, its raw value (for device-specific
    /// bookkeeping such as the operating mode).
    pub fn reply(
        &mut self,
        reply: &Reply,
        out: &mut Bounded<Update>,
        mut seen: impl FnMut(usize, i64),
    ) {
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
            let units = value.and_then(|bits| {
                let raw = c.decode_raw(bits);
                if raw < c.read_range.0 || raw > c.read_range.1 {
                    self.range_rejects += 1;
                    return None;
                }
                self.last[i] = Some(raw);
                seen(i, raw);
                Some(c.to_units(raw))
            });
            let _ = out.push(Update::from_reply(reply, i, units, fault));
        }
    }

    /// Queues the requests of a safe action.
    pub fn safe(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        match action {
            SafeAction::Hold => match self.hold {
                Some((i, goal)) if self.last[i].is_some() => {
                    let raw = self.last[i].unwrap_or(0);
                    let c = self.table[i];
                    let op = Op::Write {
                        addr: goal,
                        len: c.len,
                        value: c.encode_raw(raw.clamp(c.write_range.0, c.write_range.1)),
                    };
                    let _ = out.push(Request::new(self.cred, op, ctx));
                }
                // Nothing known to hold: the only safe thing left is to let go.
                _ => self.safe(SafeAction::TorqueOff, ctx, out),
            },
            SafeAction::TorqueOff => {
                if let Some((addr, len, value)) = self.torque_off {
                    let op = Op::Write { addr, len, value };
                    let _ = out.push(Request::new(self.cred, op, ctx));
                }
            }
            SafeAction::Setpoint { channel, value } => {
                self.pending.iter_mut().for_each(|p| *p = None);
                self.write(channel, value);
                self.flush(ctx, out);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ch(encoding: Encoding, len: u8) -> RegChannel {
        RegChannel {
            name: "x",
            units: "",
            read: Some(0),
            write: Some(0),
            len,
            encoding,
            scale: 1.0,
            offset: 0,
            read_range: (i64::MIN, i64::MAX),
            write_range: (-5000, 5000),
        }
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
