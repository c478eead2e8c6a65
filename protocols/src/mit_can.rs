//! "MIT mode" CAN motors: Ben Katz's mini-cheetah motor controller and the CubeMars/T-motor AK
//! series that adopted it. Classic CAN, 11-bit IDs, 1 Mbit/s.
//!
//! * Command (host → motor, ID = motor CAN ID, 8 bytes): position 16 bit, velocity 12, kp 12,
//!   kd 12, feed-forward torque 12, big-endian bit fields ([`Command::encode`]).
//! * Reply (motor → host, DLC 6 or 8): `data[0]` = motor ID, position 16 bit, velocity 12,
//!   torque 12, then optionally temperature and fault code ([`Reply::decode`]). Identify the
//!   motor by `data[0]`, not by the arbitration ID (usually the master ID 0).
//! * Special frames `FF×7 FC/FD/FE`: enter motor mode, exit, zero position
//!   ([`SpecialCommand`]). Every received frame triggers exactly one reply.
//!
//! Floats map to integers with Katz's `float_to_uint` (in f32, **truncating**, span divided
//! into `2^bits - 1` steps), not the CubeMars manual's version, whose `(1<<bits)/span` maps the
//! maximum to `2^bits` and overflows the field. The ranges are firmware configuration: pick a
//! [`Model`] or build [`Limits`] from the firmware's values.

use crate::can::CanFrame;
use crate::code_table::code_table;
use embedded_can::{Frame, StandardId};

/// A closed interval of physical values mapped onto an integer field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range {
    /// Value encoded as 0.
    pub min: f32,
    /// Value encoded as all ones.
    pub max: f32,
}

impl Range {
    /// `[-x, x]`.
    pub const fn symmetric(x: f32) -> Self {
        Range { min: -x, max: x }
    }

    fn is_valid(&self) -> bool {
        self.min.is_finite() && self.max.is_finite() && self.min < self.max
    }
}

/// The firmware's ranges for each field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Position, rad.
    pub p: Range,
    /// Velocity, rad/s.
    pub v: Range,
    /// Position gain kp, N·m/rad.
    pub kp: Range,
    /// Velocity gain kd, N·m·s/rad.
    pub kd: Range,
    /// Torque, N·m.
    pub t: Range,
}

impl Limits {
    /// Symmetric position/velocity/torque ranges with the usual gains kp 0–500, kd 0–5.
    pub const fn symmetric(p: f32, v: f32, t: f32) -> Self {
        Limits {
            p: Range::symmetric(p),
            v: Range::symmetric(v),
            kp: Range {
                min: 0.0,
                max: 500.0,
            },
            kd: Range { min: 0.0, max: 5.0 },
            t: Range::symmetric(t),
        }
    }

    /// Every range finite with `min < max`.
    pub fn validate(&self) -> Result<(), MitError> {
        [self.p, self.v, self.kp, self.kd, self.t]
            .iter()
            .all(Range::is_valid)
            .then_some(())
            .ok_or(MitError::InvalidLimits)
    }
}

/// Motor models with the CubeMars AK manual V1.0.8 ranges (p. 50), plus Katz's mini-cheetah
/// defaults. Firmware that differs (see [`variants`]) needs its own [`Limits`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Model {
    /// AK10-9: P ±12.5 rad, V ±50 rad/s, T ±65 N·m.
    Ak10_9,
    /// AK60-6: P ±12.5, V ±45, T ±15.
    Ak60_6,
    /// AK70-10: P ±12.5, V ±50, T ±25.
    Ak70_10,
    /// AK80-6: P ±12.5, V ±76, T ±12.
    Ak80_6,
    /// AK80-9: P ±12.5, V ±50, T ±18.
    Ak80_9,
    /// AK80-64 ("80-80"): P ±12.5, V ±8, T ±144.
    Ak80_64,
    /// Mini-cheetah module defaults: P ±12.5, V ±65, T ±18.
    MiniCheetah,
}

impl Model {
    /// The model's ranges (kp 0–500, kd 0–5 for all).
    pub const fn limits(self) -> Limits {
        match self {
            Model::Ak10_9 => Limits::symmetric(12.5, 50.0, 65.0),
            Model::Ak60_6 => Limits::symmetric(12.5, 45.0, 15.0),
            Model::Ak70_10 => Limits::symmetric(12.5, 50.0, 25.0),
            Model::Ak80_6 => Limits::symmetric(12.5, 76.0, 12.0),
            Model::Ak80_9 => Limits::symmetric(12.5, 50.0, 18.0),
            Model::Ak80_64 => Limits::symmetric(12.5, 8.0, 144.0),
            Model::MiniCheetah => Limits::symmetric(12.5, 65.0, 18.0),
        }
    }
}

/// Firmware-specific ranges used by the DFKI driver (`canmotorlib.py`). Check the manual that
/// matches the drive's firmware before trusting any table.
pub mod variants {
    use super::Limits;
    /// AK80-6, firmware V1.
    pub const AK80_6_V1: Limits = Limits::symmetric(95.5, 45.0, 18.0);
    /// AK80-6, firmware V1.1.
    pub const AK80_6_V1_1: Limits = Limits::symmetric(12.5, 22.5, 12.0);
    /// AK80-6, firmware V2.
    pub const AK80_6_V2: Limits = Limits::symmetric(12.5, 76.0, 12.0);
    /// AK80-9, firmware V1.1.
    pub const AK80_9_V1_1: Limits = Limits::symmetric(12.5, 22.5, 18.0);
    /// AK80-9, firmware V2.
    pub const AK80_9_V2: Limits = Limits::symmetric(12.5, 25.64, 18.0);
    /// AK70-10, firmware V1.1.
    pub const AK70_10_V1_1: Limits = Limits::symmetric(12.5, 50.0, 24.0);
    /// AK10-9, firmware V1.1.
    pub const AK10_9_V1_1: Limits = Limits::symmetric(12.5, 50.0, 65.0);
}

/// Errors of the MIT-mode codec.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum MitError {
    /// A command value is NaN or infinite.
    #[error("command value is not finite")]
    NotFinite,
    /// A range is not finite or has `min >= max`.
    #[error("invalid limits")]
    InvalidLimits,
    /// A reply that is not 6 or 8 bytes, or a command that is not 8 bytes.
    #[error("unexpected payload length {0}")]
    Length(usize),
    /// The CAN ID does not fit 11 bits.
    #[error("CAN ID {0:#x} is not a standard ID")]
    InvalidId(u16),
}

/// Katz's `float_to_uint`: clamp to the range, scale onto `2^bits - 1` steps in f32, truncate.
/// `bits` is at most 16 (larger values are treated as 16).
pub fn float_to_uint(x: f32, r: Range, bits: u32) -> u16 {
    let bits = bits.min(16);
    let steps = ((1u32 << bits) - 1) as f32;
    // max/min rather than clamp: clamp panics on an inverted or NaN range.
    let x = x.max(r.min).min(r.max);
    let n = ((x - r.min) * steps / (r.max - r.min)) as u32;
    n.min((1 << bits) - 1) as u16
}

/// Katz's `uint_to_float` (`bits` at most 16, larger values are treated as 16).
pub fn uint_to_float(n: u16, r: Range, bits: u32) -> f32 {
    let bits = bits.min(16);
    let steps = ((1u32 << bits) - 1) as f32;
    n as f32 * (r.max - r.min) / steps + r.min
}

/// A control command: `τ = kp·(p − p_meas) + kd·(v − v_meas) + t`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Command {
    /// Target position, rad.
    pub p: f32,
    /// Target velocity, rad/s.
    pub v: f32,
    /// Position gain.
    pub kp: f32,
    /// Velocity gain.
    pub kd: f32,
    /// Feed-forward torque, N·m.
    pub t: f32,
}

/// The five integer fields of a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandInts {
    /// Position, 16 bit.
    pub p: u16,
    /// Velocity, 12 bit.
    pub v: u16,
    /// kp, 12 bit.
    pub kp: u16,
    /// kd, 12 bit.
    pub kd: u16,
    /// Torque, 12 bit.
    pub t: u16,
}

impl CommandInts {
    /// Packs into the 8-byte payload (`pack_cmd` layout).
    pub fn pack(&self) -> [u8; 8] {
        let (p, v, kp, kd, t) = (
            self.p,
            self.v & 0xFFF,
            self.kp & 0xFFF,
            self.kd & 0xFFF,
            self.t & 0xFFF,
        );
        [
            (p >> 8) as u8,
            p as u8,
            (v >> 4) as u8,
            (((v & 0xF) << 4) | (kp >> 8)) as u8,
            kp as u8,
            (kd >> 4) as u8,
            (((kd & 0xF) << 4) | (t >> 8)) as u8,
            t as u8,
        ]
    }

    /// Unpacks an 8-byte payload (`unpack_cmd`).
    pub fn unpack(d: &[u8; 8]) -> Self {
        let d = d.map(u16::from);
        CommandInts {
            p: (d[0] << 8) | d[1],
            v: (d[2] << 4) | (d[3] >> 4),
            kp: ((d[3] & 0xF) << 8) | d[4],
            kd: (d[5] << 4) | (d[6] >> 4),
            t: ((d[6] & 0xF) << 8) | d[7],
        }
    }
}

impl Command {
    /// Quantises the command (clamping each value into its range, as the firmware does).
    pub fn to_ints(&self, l: &Limits) -> Result<CommandInts, MitError> {
        l.validate()?;
        if ![self.p, self.v, self.kp, self.kd, self.t]
            .iter()
            .all(|x| x.is_finite())
        {
            return Err(MitError::NotFinite);
        }
        let mut ints = CommandInts {
            p: float_to_uint(self.p, l.p, 16),
            v: float_to_uint(self.v, l.v, 12),
            kp: float_to_uint(self.kp, l.kp, 12),
            kd: float_to_uint(self.kd, l.kd, 12),
            t: float_to_uint(self.t, l.t, 12),
        };
        // With p, v, kp, kd at maximum and t_int in FFC..=FFE the payload would be byte for
        // byte a special frame; keep the torque one step below.
        if (ints.p, ints.v, ints.kp, ints.kd) == (0xFFFF, 0xFFF, 0xFFF, 0xFFF)
            && (0xFFC..=0xFFE).contains(&ints.t)
        {
            ints.t = 0xFFB;
        }
        Ok(ints)
    }

    /// The 8-byte command payload.
    pub fn encode(&self, l: &Limits) -> Result<[u8; 8], MitError> {
        Ok(self.to_ints(l)?.pack())
    }

    /// Dequantises integer fields.
    pub fn from_ints(n: &CommandInts, l: &Limits) -> Self {
        Command {
            p: uint_to_float(n.p, l.p, 16),
            v: uint_to_float(n.v, l.v, 12),
            kp: uint_to_float(n.kp, l.kp, 12),
            kd: uint_to_float(n.kd, l.kd, 12),
            t: uint_to_float(n.t, l.t, 12),
        }
    }
}

/// The special frames (payload `FF FF FF FF FF FF FF xx`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpecialCommand {
    /// `…FC`: enter motor (MIT) mode; also a state poll that commands nothing.
    Enter,
    /// `…FD`: exit motor mode.
    Exit,
    /// `…FE`: set the current position as zero.
    Zero,
}

impl SpecialCommand {
    /// The 8-byte payload.
    pub fn payload(self) -> [u8; 8] {
        let last = match self {
            SpecialCommand::Enter => 0xFC,
            SpecialCommand::Exit => 0xFD,
            SpecialCommand::Zero => 0xFE,
        };
        [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, last]
    }
}

/// What a motor makes of a received payload (the simulator side).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MotorCommand {
    /// A special frame.
    Special(SpecialCommand),
    /// A control command.
    Control(Command),
}

/// Decodes a received 8-byte payload as the motor firmware does.
pub fn decode_command(data: &[u8], l: &Limits) -> Result<MotorCommand, MitError> {
    let d: &[u8; 8] = data.try_into().map_err(|_| MitError::Length(data.len()))?;
    if d[..7] == [0xFF; 7] {
        match d[7] {
            0xFC => return Ok(MotorCommand::Special(SpecialCommand::Enter)),
            0xFD => return Ok(MotorCommand::Special(SpecialCommand::Exit)),
            0xFE => return Ok(MotorCommand::Special(SpecialCommand::Zero)),
            _ => {}
        }
    }
    l.validate()?;
    Ok(MotorCommand::Control(Command::from_ints(
        &CommandInts::unpack(d),
        l,
    )))
}

code_table! {
    /// Fault codes in byte 7 of an 8-byte reply (CubeMars manual p. 42).
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum Fault {
        /// 1.
        OverVoltage = 1,
        /// 2.
        UnderVoltage = 2,
        /// 3.
        DrvFault = 3,
        /// 4.
        AbsOverCurrent = 4,
        /// 5.
        FetOverTemperature = 5,
        /// 6.
        MotorOverTemperature = 6,
        /// 7.
        GateDriverOverVoltage = 7,
        /// 8.
        GateDriverUnderVoltage = 8,
        /// 9.
        McuUnderVoltage = 9,
        /// 10.
        WatchdogReset = 10,
    }
    /// Any other non-zero code.
    other Unknown(u8);
}

impl Fault {
    /// The fault for a code; `None` for 0 (no fault).
    pub fn from_code(c: u8) -> Option<Self> {
        (c != 0).then(|| Self::from(c))
    }
}

/// The extra bytes of an 8-byte reply (newer CubeMars firmware).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReplyExtra {
    /// `data[6]`, the motor temperature byte as sent.
    pub temperature: u8,
    /// `data[7]`, decoded; `None` = no fault.
    pub fault: Option<Fault>,
}

/// A motor's state reply.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reply {
    /// The replying motor's CAN ID (`data[0]`).
    pub motor_id: u8,
    /// Position, rad.
    pub p: f32,
    /// Velocity, rad/s.
    pub v: f32,
    /// Torque, N·m (Katz firmware sends current scaled to torque).
    pub t: f32,
    /// Present in 8-byte replies only.
    pub extra: Option<ReplyExtra>,
}

/// The integer fields of a reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReplyInts {
    /// Motor ID.
    pub motor_id: u8,
    /// Position, 16 bit.
    pub p: u16,
    /// Velocity, 12 bit.
    pub v: u16,
    /// Torque/current, 12 bit.
    pub t: u16,
}

impl ReplyInts {
    /// Unpacks a 6- or 8-byte reply payload (the first 6 bytes).
    pub fn unpack(d: &[u8]) -> Result<Self, MitError> {
        if d.len() != 6 && d.len() != 8 {
            return Err(MitError::Length(d.len()));
        }
        let w = |i: usize| d[i] as u16;
        Ok(ReplyInts {
            motor_id: d[0],
            p: (w(1) << 8) | w(2),
            v: (w(3) << 4) | (w(4) >> 4),
            t: ((w(4) & 0xF) << 8) | w(5),
        })
    }

    /// Packs the 6-byte reply (`pack_reply`).
    pub fn pack(&self) -> [u8; 6] {
        let (v, t) = (self.v & 0xFFF, self.t & 0xFFF);
        [
            self.motor_id,
            (self.p >> 8) as u8,
            self.p as u8,
            (v >> 4) as u8,
            (((v & 0xF) << 4) | (t >> 8)) as u8,
            t as u8,
        ]
    }
}

impl Reply {
    /// Decodes a 6- or 8-byte reply payload.
    pub fn decode(data: &[u8], l: &Limits) -> Result<Self, MitError> {
        l.validate()?;
        let n = ReplyInts::unpack(data)?;
        let extra = (data.len() == 8).then(|| ReplyExtra {
            temperature: data[6],
            fault: Fault::from_code(data[7]),
        });
        Ok(Reply {
            motor_id: n.motor_id,
            p: uint_to_float(n.p, l.p, 16),
            v: uint_to_float(n.v, l.v, 12),
            t: uint_to_float(n.t, l.t, 12),
            extra,
        })
    }

    /// Encodes the reply payload (simulator side): 6 bytes, or 8 with `extra`. Returns the
    /// buffer and the length used.
    pub fn encode(&self, l: &Limits) -> Result<([u8; 8], usize), MitError> {
        l.validate()?;
        if ![self.p, self.v, self.t].iter().all(|x| x.is_finite()) {
            return Err(MitError::NotFinite);
        }
        let ints = ReplyInts {
            motor_id: self.motor_id,
            p: float_to_uint(self.p, l.p, 16),
            v: float_to_uint(self.v, l.v, 12),
            t: float_to_uint(self.t, l.t, 12),
        };
        let mut out = [0u8; 8];
        out[..6].copy_from_slice(&ints.pack());
        Ok(match self.extra {
            None => (out, 6),
            Some(e) => {
                out[6] = e.temperature;
                out[7] = e.fault.map_or(0, Fault::code);
                (out, 8)
            }
        })
    }
}

fn std_id(id: u16) -> Result<StandardId, MitError> {
    StandardId::new(id).ok_or(MitError::InvalidId(id))
}

fn frame<F: Frame>(id: u16, data: &[u8]) -> Result<F, MitError> {
    // Frame::new only fails for an invalid ID or more than 8 bytes, both excluded here.
    F::new(std_id(id)?, data).ok_or(MitError::InvalidId(id))
}

/// The command frame for motor `motor_id`.
pub fn command_frame<F: Frame>(motor_id: u16, cmd: &Command, l: &Limits) -> Result<F, MitError> {
    frame(motor_id, &cmd.encode(l)?)
}

/// A special frame for motor `motor_id`.
pub fn special_frame<F: Frame>(motor_id: u16, which: SpecialCommand) -> Result<F, MitError> {
    frame(motor_id, &which.payload())
}

/// Enter motor mode.
pub fn enter_frame<F: Frame>(motor_id: u16) -> Result<F, MitError> {
    special_frame(motor_id, SpecialCommand::Enter)
}

/// Exit motor mode.
pub fn exit_frame<F: Frame>(motor_id: u16) -> Result<F, MitError> {
    special_frame(motor_id, SpecialCommand::Exit)
}

/// Set the current position as zero.
pub fn zero_frame<F: Frame>(motor_id: u16) -> Result<F, MitError> {
    special_frame(motor_id, SpecialCommand::Zero)
}

/// A reply frame sent to `master_id` (simulator side).
pub fn reply_frame<F: Frame>(master_id: u16, reply: &Reply, l: &Limits) -> Result<F, MitError> {
    let (data, n) = reply.encode(l)?;
    frame(master_id, &data[..n])
}

/// Convenience: [`command_frame`] with this crate's [`CanFrame`].
pub fn command(motor_id: u16, cmd: &Command, l: &Limits) -> Result<CanFrame, MitError> {
    command_frame(motor_id, cmd, l)
}
