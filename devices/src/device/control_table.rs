//! Register-mapped devices (Dynamixel 2.0 and 1.0): one generic device,
//! [`RegDevice`](super::RegDevice), over a family's [`ControlTable`]: a table of channels, each a
//! control-table register (or a read/write register pair) with its size, signedness, scale,
//! offset and the range of raw values a healthy servo can report, and what the family needs to
//! be brought up (model numbers, configuration registers, torque, faults).
//!
//! Range checks matter: a CRC-16 lets about one damaged packet in 65 536 through, a 1.0
//! checksum one in 256. A value outside its register's physical range is therefore treated as
//! damaged: the channel goes stale and the rejection is counted, never delivered.

use crate::component::{Channel, SafeAction};

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
    /// The fastest a healthy device's reading can change (raw steps per second), where
    /// physics bounds it (a servo's position, by its top speed); `None`: unbounded.
    pub max_rate: Option<f64>,
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
            max_rate: None,
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

    /// Its reading changes by at most `steps_per_s` raw steps a second (see
    /// [`max_rate`](Self::max_rate)).
    pub const fn bounded_rate(mut self, steps_per_s: f64) -> Self {
        self.max_rate = Some(steps_per_s);
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

/// A register the manifest's configuration sets at bring-up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConfigItem {
    /// Manifest name, for messages.
    pub name: &'static str,
    /// Control-table address.
    pub addr: u16,
    /// Bytes (1, 2 or 4).
    pub len: u8,
    /// Raw value.
    pub value: i64,
}

/// Indirect addressing: Indirect Address `n` (2 bytes each from `addr`) holds the address of
/// the byte that Indirect Data `n` (1 byte each from `data`) reads and writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Indirect {
    /// Address of Indirect Address 1.
    pub addr: u16,
    /// Address of Indirect Data 1.
    pub data: u16,
    /// Slots available.
    pub slots: u16,
}

/// What sets one family of register-mapped servos apart (its control table); the
/// [`RegDevice`](super::RegDevice) it parameterises does the rest.
pub trait ControlTable: std::fmt::Debug {
    /// The safe action devices of this family declare.
    const SAFE_ACTION: SafeAction;
    /// The channel whose last value [`SafeAction::Hold`] writes back to its write register
    /// (the present position, written as the goal).
    const HOLD: Option<usize>;
    /// Torque Enable (1 byte).
    const TORQUE: u16;
    /// Whether PING returns the model number (Protocol 2.0); else it is read at
    /// [`MODEL_AT`](Self::MODEL_AT).
    const PING_MODEL: bool;
    /// Model Number (2 bytes).
    const MODEL_AT: u16 = 0;
    /// Hardware Error Status (1 byte), where the family latches faults behind an alert bit.
    const HW_ERROR: Option<u16> = None;
    /// Status error bits that report a fault condition (Protocol 1.0: input voltage,
    /// overheating, overload); 0 where faults are latched in [`HW_ERROR`](Self::HW_ERROR).
    const FAULT_BITS: u8 = 0;
    /// Whether the family has REBOOT (which clears a latched hardware error).
    const REBOOT: bool = false;
    /// Indirect addressing, where the family has it.
    const INDIRECT: Option<Indirect> = None;

    /// The channels, in channel-index order.
    fn channels(&self) -> Vec<RegChannel>;

    /// Channel `i` has just taken raw value `raw` (a setpoint written, or a good value read):
    /// a family whose registers depend on each other re-ranges `table` here.
    fn on_raw(&mut self, table: &mut [RegChannel], i: usize, raw: i64) {
        let _ = (table, i, raw);
    }

    /// The model numbers a device of this configuration may report, with their names; empty:
    /// any.
    fn models(&self) -> &'static [(u16, &'static str)];

    /// The configuration registers to write at bring-up (built once, at construction).
    fn config(&self) -> Vec<ConfigItem>;

    /// Whether writing `addr` needs torque off (EEPROM, and on X-series the indirect addresses).
    fn needs_torque_off(&self, addr: u16) -> bool;

    /// Besides the goal position (channel [`HOLD`](Self::HOLD)): the goal register written 0
    /// before enabling, in an operating mode whose goal is not a position (velocity, current,
    /// PWM), as `(addr, len)`.
    fn zero_goal(&self) -> Option<(u16, u8)> {
        None
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
