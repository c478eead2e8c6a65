//! What flows between the stages: [`Request`]s downstream, [`Reply`]s upstream, and the
//! [`Update`]s a device hands back to the state stage.

use crate::component::TickCtx;

/// The identity of a device on its bus, which the Device stage tags on every request and the
/// Protocol stage reconstructs from every reply (the thesis' "credential").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct Credential {
    /// Bus address: Dynamixel ID, CAN node ID, simulated channel.
    pub id: u32,
    /// Sub-address where a node has several (an ODrive axis, ...); 0 otherwise.
    pub sub: u32,
}

impl Credential {
    /// Credential with sub-address 0.
    pub const fn id(id: u32) -> Self {
        Self { id, sub: 0 }
    }
}

/// MIT-mode special frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MitSpecial {
    /// Enter motor mode (enable).
    Enter,
    /// Exit motor mode (torque off).
    Exit,
    /// Set the current position as zero.
    Zero,
}

/// The operation a device asks its protocol to perform.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Op {
    /// Read `len` bytes at control-table address `addr` (register-mapped buses: Dynamixel).
    Read {
        /// Control-table address.
        addr: u16,
        /// Bytes (1, 2 or 4).
        len: u8,
    },
    /// Write `value` (little-endian, `len` bytes) at `addr`.
    Write {
        /// Control-table address.
        addr: u16,
        /// Bytes (1, 2 or 4).
        len: u8,
        /// Raw register value.
        value: i64,
    },
    /// An MIT-mode command; the motor answers every command with its state.
    Mit {
        /// Position setpoint (rad).
        p: f32,
        /// Velocity setpoint (rad/s).
        v: f32,
        /// Position gain.
        kp: f32,
        /// Velocity gain.
        kd: f32,
        /// Feed-forward torque (N·m).
        t: f32,
    },
    /// An MIT-mode special frame.
    MitSpecial(MitSpecial),
    /// An ODrive CAN Simple message (encoded by the protocol stage).
    Odrive(conductor_protocols::odrive_can::Message),
    /// Register buses: is the device there, and which model is it (answered by
    /// [`ReplyData::Ping`]).
    Ping,
    /// Register buses: restart the device (clears a latched hardware error; answered by
    /// [`ReplyData::Ack`] where the device's status return level allows).
    Reboot,
    /// Simulated hardware: report the channel's value.
    Sample,
    /// Simulated hardware: set the channel's value.
    Set {
        /// New value.
        value: f64,
    },
    /// Simulated hardware: the channel starts at this value (where a simulated servo is when
    /// the executor starts: no lag towards it, unlike [`Op::Set`]).
    Place {
        /// Starting value.
        value: f64,
    },
}

/// A downstream request, tagged by its device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Request {
    /// Target device.
    pub cred: Credential,
    /// What to do.
    pub op: Op,
    /// Executor tick that issued the request.
    pub tick: u64,
    /// When it was issued (CLOCK_MONOTONIC ns): the sample time of the value it brings back.
    pub t_request_ns: u64,
}

impl Request {
    /// `op` for the device at `cred`, issued now (the tick and time of `ctx`).
    pub fn new(cred: Credential, op: Op, ctx: TickCtx) -> Self {
        Self {
            cred,
            op,
            tick: ctx.tick,
            t_request_ns: ctx.now_ns,
        }
    }
}

/// What came back.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ReplyData {
    /// Register contents (`len` bytes little-endian, zero-extended; the device sign-extends).
    Register {
        /// Control-table address.
        addr: u16,
        /// Bytes.
        len: u8,
        /// Raw value.
        value: i64,
    },
    /// MIT-mode motor state.
    Mit {
        /// Position (rad).
        p: f32,
        /// Velocity (rad/s).
        v: f32,
        /// Torque (N·m).
        t: f32,
        /// Motor temperature (°C), in the 8-byte replies of newer firmware.
        temperature: Option<u8>,
    },
    /// An ODrive message from the node.
    Odrive(conductor_protocols::odrive_can::Message),
    /// The answer to [`Op::Ping`]: the model number and firmware version where the protocol's
    /// ping carries them (Dynamixel 2.0), else `None` (Dynamixel 1.0).
    Ping {
        /// Model number.
        model: Option<u16>,
        /// Firmware version.
        firmware: Option<u8>,
    },
    /// The device acknowledged an instruction that returns no data ([`Op::Reboot`]).
    Ack,
    /// A simulated channel's value.
    Value(f64),
    /// The device answered with an error (Dynamixel error byte / alert, ODrive error).
    DeviceError {
        /// Protocol-specific error code.
        code: u32,
    },
    /// The answer to `op` came after its deadline (it was already reported `Missing`): its
    /// value's time is unknown, so it carries none, but it proves the device got the request
    /// (a safe action's confirmation).
    Late {
        /// The request it answers.
        op: Op,
    },
    /// No (valid) answer arrived for this request before its deadline.
    Missing {
        /// The request that went unanswered.
        op: Op,
    },
}

/// An upstream reply, tagged with the credential the protocol reconstructed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reply {
    /// Which device answered (or should have).
    pub cred: Credential,
    /// The answer.
    pub data: ReplyData,
    /// The request this answers; `None` for messages nobody asked for (cyclic ODrive messages).
    pub op: Option<Op>,
    /// Tick of the request this answers.
    pub tick: u64,
    /// Sample time: the request time for request/reply buses.
    pub t_sample_ns: u64,
}

/// A new value for one of a device's channels, in the device's physical units (before the
/// manifest's calibration).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Update {
    /// Channel index within the device ([`crate::Device::channels`]).
    pub channel: usize,
    /// Value in device units, or `None` when the channel is stale (no valid reply).
    pub value: Option<f64>,
    /// The device reported a fault with this reply.
    pub fault: bool,
    /// Tick of the request.
    pub tick: u64,
    /// Sample time.
    pub t_sample_ns: u64,
}

impl Update {
    /// The update of `channel` that `reply` brings (its tick and sample time).
    pub fn from_reply(reply: &Reply, channel: usize, value: Option<f64>, fault: bool) -> Self {
        Self {
            channel,
            value,
            fault,
            tick: reply.tick,
            t_sample_ns: reply.t_sample_ns,
        }
    }
}

impl Reply {
    /// The answer `data` to request `op` of the device at `cred`, sampled at `t_sample_ns`
    /// on tick `tick`.
    pub fn answer(cred: Credential, op: Op, data: ReplyData, tick: u64, t_sample_ns: u64) -> Self {
        Self {
            cred,
            data,
            op: Some(op),
            tick,
            t_sample_ns,
        }
    }

    /// `op` of the device at `cred` went unanswered.
    pub fn missing(cred: Credential, op: Op, tick: u64, t_sample_ns: u64) -> Self {
        Self::answer(cred, op, ReplyData::Missing { op }, tick, t_sample_ns)
    }
}

impl Update {
    /// A value of `channel` known by the device itself (a commanded gain, its enable state),
    /// reported at `ctx`.
    pub fn local(channel: usize, value: f64, ctx: TickCtx) -> Self {
        Self {
            channel,
            value: Some(value),
            fault: false,
            tick: ctx.tick,
            t_sample_ns: ctx.now_ns,
        }
    }
}
