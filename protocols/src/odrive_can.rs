//! ODrive "CAN Simple", firmware 0.6.x (ODrive Pro / S1 / Micro).
//!
//! Arbitration ID `node_id << 5 | cmd_id` (node 0–63, command 0–31), standard 11-bit. Payloads
//! are little-endian, floats IEEE-754 f32. "Get" messages are requested with a remote frame of
//! the same ID ([`request_frame`]); the axis answers with a data frame. Field layout from
//! ODrive's generated `can_simple_messages.hpp`.
//!
//! The i16 feed-forward fields of `Set_Input_Pos` are scaled by 0.001 and **rounded** (half
//! away from zero): truncation turns 0.5 rev/s into 499.

use crate::can::CanFrame;
use crate::code_table::code_table;
use embedded_can::{Frame, Id, StandardId};

code_table! {
    /// Command IDs (low 5 bits of the arbitration ID), firmware 0.6.x.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum CmdId {
        /// `0x00`.
        GetVersion = 0x00,
        /// `0x01`.
        Heartbeat = 0x01,
        /// `0x02`.
        Estop = 0x02,
        /// `0x03`.
        GetError = 0x03,
        /// `0x04`.
        RxSdo = 0x04,
        /// `0x05`.
        TxSdo = 0x05,
        /// `0x06`.
        Address = 0x06,
        /// `0x07`.
        SetAxisState = 0x07,
        /// `0x09`.
        GetEncoderEstimates = 0x09,
        /// `0x0B`.
        SetControllerMode = 0x0B,
        /// `0x0C`.
        SetInputPos = 0x0C,
        /// `0x0D`.
        SetInputVel = 0x0D,
        /// `0x0E`.
        SetInputTorque = 0x0E,
        /// `0x0F`.
        SetLimits = 0x0F,
        /// `0x11`.
        SetTrajVelLimit = 0x11,
        /// `0x12`.
        SetTrajAccelLimits = 0x12,
        /// `0x13`.
        SetTrajInertia = 0x13,
        /// `0x14`.
        GetIq = 0x14,
        /// `0x15`.
        GetTemperature = 0x15,
        /// `0x16`.
        Reboot = 0x16,
        /// `0x17`.
        GetBusVoltageCurrent = 0x17,
        /// `0x18`.
        ClearErrors = 0x18,
        /// `0x19`.
        SetAbsolutePosition = 0x19,
        /// `0x1A`.
        SetPosGain = 0x1A,
        /// `0x1B`.
        SetVelGains = 0x1B,
        /// `0x1C`.
        GetTorques = 0x1C,
        /// `0x1D`.
        GetPowers = 0x1D,
        /// `0x1F`.
        EnterDfuMode = 0x1F,
    }
}

/// Axis states (`Axis_Requested_State`, heartbeat `Axis_State`).
pub mod axis_state {
    /// 0.
    pub const UNDEFINED: u32 = 0;
    /// 1.
    pub const IDLE: u32 = 1;
    /// 2.
    pub const STARTUP_SEQUENCE: u32 = 2;
    /// 3.
    pub const FULL_CALIBRATION_SEQUENCE: u32 = 3;
    /// 4.
    pub const MOTOR_CALIBRATION: u32 = 4;
    /// 6.
    pub const ENCODER_INDEX_SEARCH: u32 = 6;
    /// 7.
    pub const ENCODER_OFFSET_CALIBRATION: u32 = 7;
    /// 8.
    pub const CLOSED_LOOP_CONTROL: u32 = 8;
}

/// Control modes (`Set_Controller_Mode`).
pub mod control_mode {
    /// 0.
    pub const VOLTAGE: u32 = 0;
    /// 1.
    pub const TORQUE: u32 = 1;
    /// 2.
    pub const VELOCITY: u32 = 2;
    /// 3.
    pub const POSITION: u32 = 3;
}

/// Input modes (`Set_Controller_Mode`).
pub mod input_mode {
    /// 0.
    pub const INACTIVE: u32 = 0;
    /// 1.
    pub const PASSTHROUGH: u32 = 1;
    /// 2.
    pub const VEL_RAMP: u32 = 2;
    /// 3.
    pub const POS_FILTER: u32 = 3;
    /// 5.
    pub const TRAP_TRAJ: u32 = 5;
    /// 6.
    pub const TORQUE_RAMP: u32 = 6;
}

/// Errors of the ODrive codec.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum OdriveError {
    /// Node ID above 63.
    #[error("node ID {0} out of range 0..=63")]
    NodeId(u8),
    /// Not a standard-ID frame, or a command code 0.6.x does not define.
    #[error("not an ODrive CAN Simple ID: {0:#x}")]
    UnknownId(u32),
    /// The payload is shorter than the message needs.
    #[error("payload of {got} bytes, {needed} needed")]
    Length {
        /// Bytes needed.
        needed: usize,
        /// Bytes present.
        got: usize,
    },
    /// A value does not fit its field (NaN, or a scaled i16 out of range).
    #[error("value out of range for its field")]
    OutOfRange,
    /// A remote (request) frame where a data frame was expected.
    #[error("remote frame")]
    Remote,
}

/// The arbitration ID for `node` and `cmd`.
pub fn can_id(node: u8, cmd: CmdId) -> Result<u16, OdriveError> {
    if node > 63 {
        return Err(OdriveError::NodeId(node));
    }
    Ok((node as u16) << 5 | cmd as u16)
}

/// Splits an arbitration ID into node ID and command code.
pub fn split_id(id: u16) -> (u8, u8) {
    (((id >> 5) & 0x3F) as u8, (id & 0x1F) as u8)
}

/// The 0.6.x messages with their fields (units as in ODrive's docs: rev, rev/s, N·m, A, V).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Message {
    /// 0x00 Get_Version: protocol, hardware and firmware versions.
    GetVersion {
        /// CAN protocol version.
        protocol_version: u8,
        /// Hardware major version.
        hw_major: u8,
        /// Hardware minor version.
        hw_minor: u8,
        /// Hardware variant.
        hw_variant: u8,
        /// Firmware major version.
        fw_major: u8,
        /// Firmware minor version.
        fw_minor: u8,
        /// Firmware revision.
        fw_revision: u8,
        /// Non-zero for an unreleased firmware.
        fw_unreleased: u8,
    },
    /// 0x01 Heartbeat (cyclic): axis error, state, procedure result, trajectory done.
    Heartbeat {
        /// Axis error bits.
        axis_error: u32,
        /// Current axis state.
        axis_state: u8,
        /// Result of the last procedure.
        procedure_result: u8,
        /// Trajectory finished.
        trajectory_done: bool,
    },
    /// 0x02 Estop (DLC 0).
    Estop,
    /// 0x03 Get_Error: active errors and disarm reason.
    GetError {
        /// Active error bits.
        active_errors: u32,
        /// Error bits that disarmed the axis.
        disarm_reason: u32,
    },
    /// Arbitrary parameter access request.
    RxSdo {
        /// 0 read, 1 write.
        opcode: u8,
        /// Endpoint (parameter) ID.
        endpoint_id: u16,
        /// Value bytes, little-endian.
        value: [u8; 4],
    },
    /// Arbitrary parameter access reply.
    TxSdo {
        /// 0 read, 1 write.
        opcode: u8,
        /// Endpoint (parameter) ID.
        endpoint_id: u16,
        /// Value bytes, little-endian.
        value: [u8; 4],
    },
    /// Node ID and 48-bit serial number.
    Address {
        /// Node ID.
        node_id: u8,
        /// 48-bit serial number.
        serial_number: u64,
    },
    /// 0x07 Set_Axis_State (8 = closed loop, 1 = idle; see [`axis_state`]).
    SetAxisState {
        /// Requested axis state.
        requested_state: u32,
    },
    /// 0x09 Get_Encoder_Estimates (cyclic): position (rev), velocity (rev/s).
    GetEncoderEstimates {
        /// Position (rev).
        pos: f32,
        /// Velocity (rev/s).
        vel: f32,
    },
    /// 0x0B Set_Controller_Mode (see [`control_mode`], [`input_mode`]).
    SetControllerMode {
        /// Control mode.
        control_mode: u32,
        /// Input mode.
        input_mode: u32,
    },
    /// `vel_ff` and `torque_ff` travel as i16 × 0.001 (rounded).
    SetInputPos {
        /// Position (rev).
        pos: f32,
        /// Velocity feed-forward (rev/s), 0.001 resolution.
        vel_ff: f32,
        /// Torque feed-forward (N·m).
        torque_ff: f32,
    },
    /// 0x0D Set_Input_Vel: velocity (rev/s) and torque feed-forward (N·m).
    SetInputVel {
        /// Velocity (rev/s).
        vel: f32,
        /// Torque feed-forward (N·m).
        torque_ff: f32,
    },
    /// 0x0E Set_Input_Torque (N·m).
    SetInputTorque {
        /// Torque (N·m).
        torque: f32,
    },
    /// 0x0F Set_Limits: velocity (rev/s) and current (A) limits.
    SetLimits {
        /// Velocity limit (rev/s).
        velocity_limit: f32,
        /// Current limit (A).
        current_limit: f32,
    },
    /// 0x11 Set_Traj_Vel_Limit (rev/s).
    SetTrajVelLimit {
        /// Limit.
        limit: f32,
    },
    /// 0x12 Set_Traj_Accel_Limits (rev/s²).
    SetTrajAccelLimits {
        /// Acceleration limit.
        accel: f32,
        /// Deceleration limit.
        decel: f32,
    },
    /// 0x13 Set_Traj_Inertia (N·m/(rev/s²)).
    SetTrajInertia {
        /// Inertia.
        inertia: f32,
    },
    /// 0x14 Get_Iq: setpoint and measured (A).
    GetIq {
        /// Setpoint (A).
        setpoint: f32,
        /// Measured (A).
        measured: f32,
    },
    /// 0x15 Get_Temperature: FET and motor (°C).
    GetTemperature {
        /// FET temperature (°C).
        fet: f32,
        /// Motor temperature (°C).
        motor: f32,
    },
    /// 0x16 Reboot (DLC 1).
    Reboot {
        /// Reboot action code.
        action: u8,
    },
    /// 0x17 Get_Bus_Voltage_Current: (V), (A).
    GetBusVoltageCurrent {
        /// Bus voltage (V).
        voltage: f32,
        /// Bus current (A).
        current: f32,
    },
    /// 0x18 Clear_Errors (DLC 1).
    ClearErrors {
        /// Non-zero to also blink the LED.
        identify: u8,
    },
    /// 0x19 Set_Absolute_Position (rev).
    SetAbsolutePosition {
        /// Position (rev).
        position: f32,
    },
    /// 0x1A Set_Pos_Gain ((rev/s)/rev).
    SetPosGain {
        /// Gain.
        gain: f32,
    },
    /// 0x1B Set_Vel_Gains: (N·m/(rev/s)), (N·m/rev).
    SetVelGains {
        /// Velocity gain.
        vel_gain: f32,
        /// Velocity integrator gain.
        vel_integrator_gain: f32,
    },
    /// 0x1C Get_Torques: target and estimate (N·m).
    GetTorques {
        /// Target (N·m).
        target: f32,
        /// Estimate (N·m).
        estimate: f32,
    },
    /// 0x1D Get_Powers: electrical and mechanical (W).
    GetPowers {
        /// Electrical power (W).
        electrical: f32,
        /// Mechanical power (W).
        mechanical: f32,
    },
    /// 0x1F Enter_DFU_Mode (DLC 0).
    EnterDfuMode,
}

/// Scales by 1000 and rounds half away from zero, exactly (f64, no `y + 0.5` rounding trap).
fn scaled_i16(x: f32) -> Result<i16, OdriveError> {
    if !x.is_finite() {
        return Err(OdriveError::OutOfRange);
    }
    let y = x as f64 * 1000.0;
    let t = y as i64; // toward zero; saturates, and |y| is checked below
    let frac = y - t as f64;
    let r = if frac >= 0.5 {
        t + 1
    } else if frac <= -0.5 {
        t - 1
    } else {
        t
    };
    i16::try_from(r).map_err(|_| OdriveError::OutOfRange)
}

fn finite(xs: &[f32]) -> Result<(), OdriveError> {
    xs.iter()
        .all(|x| x.is_finite())
        .then_some(())
        .ok_or(OdriveError::OutOfRange)
}

struct Payload {
    data: [u8; 8],
    len: usize,
}

impl Payload {
    fn new() -> Self {
        Self {
            data: [0; 8],
            len: 0,
        }
    }
    fn put(mut self, bytes: &[u8]) -> Self {
        self.data[self.len..self.len + bytes.len()].copy_from_slice(bytes);
        self.len += bytes.len();
        self
    }
    fn f32(self, x: f32) -> Self {
        self.put(&x.to_le_bytes())
    }
    fn u32(self, x: u32) -> Self {
        self.put(&x.to_le_bytes())
    }
}

fn f32_at(d: &[u8], i: usize) -> f32 {
    f32::from_le_bytes([d[i], d[i + 1], d[i + 2], d[i + 3]])
}

fn u32_at(d: &[u8], i: usize) -> u32 {
    u32::from_le_bytes([d[i], d[i + 1], d[i + 2], d[i + 3]])
}

impl Message {
    /// The command ID of this message.
    pub fn cmd_id(&self) -> CmdId {
        use Message::*;
        match self {
            GetVersion { .. } => CmdId::GetVersion,
            Heartbeat { .. } => CmdId::Heartbeat,
            Estop => CmdId::Estop,
            GetError { .. } => CmdId::GetError,
            RxSdo { .. } => CmdId::RxSdo,
            TxSdo { .. } => CmdId::TxSdo,
            Address { .. } => CmdId::Address,
            SetAxisState { .. } => CmdId::SetAxisState,
            GetEncoderEstimates { .. } => CmdId::GetEncoderEstimates,
            SetControllerMode { .. } => CmdId::SetControllerMode,
            SetInputPos { .. } => CmdId::SetInputPos,
            SetInputVel { .. } => CmdId::SetInputVel,
            SetInputTorque { .. } => CmdId::SetInputTorque,
            SetLimits { .. } => CmdId::SetLimits,
            SetTrajVelLimit { .. } => CmdId::SetTrajVelLimit,
            SetTrajAccelLimits { .. } => CmdId::SetTrajAccelLimits,
            SetTrajInertia { .. } => CmdId::SetTrajInertia,
            GetIq { .. } => CmdId::GetIq,
            GetTemperature { .. } => CmdId::GetTemperature,
            Reboot { .. } => CmdId::Reboot,
            GetBusVoltageCurrent { .. } => CmdId::GetBusVoltageCurrent,
            ClearErrors { .. } => CmdId::ClearErrors,
            SetAbsolutePosition { .. } => CmdId::SetAbsolutePosition,
            SetPosGain { .. } => CmdId::SetPosGain,
            SetVelGains { .. } => CmdId::SetVelGains,
            GetTorques { .. } => CmdId::GetTorques,
            GetPowers { .. } => CmdId::GetPowers,
            EnterDfuMode => CmdId::EnterDfuMode,
        }
    }

    /// Encodes the payload; returns the bytes and the DLC (the DBC's message length).
    pub fn encode(&self) -> Result<([u8; 8], usize), OdriveError> {
        use Message::*;
        let p = Payload::new();
        let p = match *self {
            GetVersion {
                protocol_version,
                hw_major,
                hw_minor,
                hw_variant,
                fw_major,
                fw_minor,
                fw_revision,
                fw_unreleased,
            } => p.put(&[
                protocol_version,
                hw_major,
                hw_minor,
                hw_variant,
                fw_major,
                fw_minor,
                fw_revision,
                fw_unreleased,
            ]),
            Heartbeat {
                axis_error,
                axis_state,
                procedure_result,
                trajectory_done,
            } => p
                .u32(axis_error)
                .put(&[axis_state, procedure_result, trajectory_done as u8, 0]),
            Estop | EnterDfuMode => p,
            GetError {
                active_errors,
                disarm_reason,
            } => p.u32(active_errors).u32(disarm_reason),
            RxSdo {
                opcode,
                endpoint_id,
                value,
            }
            | TxSdo {
                opcode,
                endpoint_id,
                value,
            } => p
                .put(&[opcode])
                .put(&endpoint_id.to_le_bytes())
                .put(&[0])
                .put(&value),
            Address {
                node_id,
                serial_number,
            } => {
                if serial_number >> 48 != 0 {
                    return Err(OdriveError::OutOfRange);
                }
                p.put(&[node_id])
                    .put(&serial_number.to_le_bytes()[..6])
                    .put(&[0])
            }
            SetAxisState { requested_state } => p.u32(requested_state),
            SetControllerMode {
                control_mode,
                input_mode,
            } => p.u32(control_mode).u32(input_mode),
            SetInputPos {
                pos,
                vel_ff,
                torque_ff,
            } => {
                finite(&[pos])?;
                p.f32(pos)
                    .put(&scaled_i16(vel_ff)?.to_le_bytes())
                    .put(&scaled_i16(torque_ff)?.to_le_bytes())
            }
            SetInputTorque { torque: a }
            | SetTrajVelLimit { limit: a }
            | SetTrajInertia { inertia: a }
            | SetAbsolutePosition { position: a }
            | SetPosGain { gain: a } => {
                finite(&[a])?;
                p.f32(a)
            }
            GetEncoderEstimates { pos: a, vel: b }
            | SetInputVel {
                vel: a,
                torque_ff: b,
            }
            | SetLimits {
                velocity_limit: a,
                current_limit: b,
            }
            | SetTrajAccelLimits { accel: a, decel: b }
            | GetIq {
                setpoint: a,
                measured: b,
            }
            | GetTemperature { fet: a, motor: b }
            | GetBusVoltageCurrent {
                voltage: a,
                current: b,
            }
            | SetVelGains {
                vel_gain: a,
                vel_integrator_gain: b,
            }
            | GetTorques {
                target: a,
                estimate: b,
            }
            | GetPowers {
                electrical: a,
                mechanical: b,
            } => {
                finite(&[a, b])?;
                p.f32(a).f32(b)
            }
            Reboot { action } => p.put(&[action]),
            ClearErrors { identify } => p.put(&[identify]),
        };
        // ODrive's DBC gives every message DLC 8 (zero padded) except Estop and
        // Enter_DFU_Mode (0) and Reboot and Clear_Errors (1).
        let dlc = match self {
            Estop | EnterDfuMode | Reboot { .. } | ClearErrors { .. } => p.len,
            _ => 8,
        };
        Ok((p.data, dlc))
    }

    /// Decodes the payload of command `cmd`. Only the bytes the fields occupy are required;
    /// padding and bytes beyond are ignored.
    pub fn decode(cmd: CmdId, d: &[u8]) -> Result<Self, OdriveError> {
        use Message::*;
        let needed = match cmd {
            CmdId::Estop | CmdId::EnterDfuMode => 0,
            CmdId::Reboot | CmdId::ClearErrors => 1,
            CmdId::SetAxisState
            | CmdId::SetInputTorque
            | CmdId::SetTrajVelLimit
            | CmdId::SetTrajInertia
            | CmdId::SetAbsolutePosition
            | CmdId::SetPosGain => 4,
            CmdId::Address => 7,
            _ => 8,
        };
        if d.len() < needed {
            return Err(OdriveError::Length {
                needed,
                got: d.len(),
            });
        }
        let f = |i| f32_at(d, i);
        Ok(match cmd {
            CmdId::GetVersion => GetVersion {
                protocol_version: d[0],
                hw_major: d[1],
                hw_minor: d[2],
                hw_variant: d[3],
                fw_major: d[4],
                fw_minor: d[5],
                fw_revision: d[6],
                fw_unreleased: d[7],
            },
            CmdId::Heartbeat => Heartbeat {
                axis_error: u32_at(d, 0),
                axis_state: d[4],
                procedure_result: d[5],
                trajectory_done: d[6] & 1 != 0,
            },
            CmdId::Estop => Estop,
            CmdId::GetError => GetError {
                active_errors: u32_at(d, 0),
                disarm_reason: u32_at(d, 4),
            },
            CmdId::RxSdo | CmdId::TxSdo => {
                let (opcode, endpoint_id, value) = (
                    d[0],
                    u16::from_le_bytes([d[1], d[2]]),
                    [d[4], d[5], d[6], d[7]],
                );
                if cmd == CmdId::RxSdo {
                    RxSdo {
                        opcode,
                        endpoint_id,
                        value,
                    }
                } else {
                    TxSdo {
                        opcode,
                        endpoint_id,
                        value,
                    }
                }
            }
            CmdId::Address => {
                let mut s = [0u8; 8];
                s[..6].copy_from_slice(&d[1..7]);
                Address {
                    node_id: d[0],
                    serial_number: u64::from_le_bytes(s),
                }
            }
            CmdId::SetAxisState => SetAxisState {
                requested_state: u32_at(d, 0),
            },
            CmdId::GetEncoderEstimates => GetEncoderEstimates {
                pos: f(0),
                vel: f(4),
            },
            CmdId::SetControllerMode => SetControllerMode {
                control_mode: u32_at(d, 0),
                input_mode: u32_at(d, 4),
            },
            CmdId::SetInputPos => SetInputPos {
                pos: f(0),
                vel_ff: i16::from_le_bytes([d[4], d[5]]) as f32 * 0.001,
                torque_ff: i16::from_le_bytes([d[6], d[7]]) as f32 * 0.001,
            },
            CmdId::SetInputVel => SetInputVel {
                vel: f(0),
                torque_ff: f(4),
            },
            CmdId::SetInputTorque => SetInputTorque { torque: f(0) },
            CmdId::SetLimits => SetLimits {
                velocity_limit: f(0),
                current_limit: f(4),
            },
            CmdId::SetTrajVelLimit => SetTrajVelLimit { limit: f(0) },
            CmdId::SetTrajAccelLimits => SetTrajAccelLimits {
                accel: f(0),
                decel: f(4),
            },
            CmdId::SetTrajInertia => SetTrajInertia { inertia: f(0) },
            CmdId::GetIq => GetIq {
                setpoint: f(0),
                measured: f(4),
            },
            CmdId::GetTemperature => GetTemperature {
                fet: f(0),
                motor: f(4),
            },
            CmdId::Reboot => Reboot { action: d[0] },
            CmdId::GetBusVoltageCurrent => GetBusVoltageCurrent {
                voltage: f(0),
                current: f(4),
            },
            CmdId::ClearErrors => ClearErrors { identify: d[0] },
            CmdId::SetAbsolutePosition => SetAbsolutePosition { position: f(0) },
            CmdId::SetPosGain => SetPosGain { gain: f(0) },
            CmdId::SetVelGains => SetVelGains {
                vel_gain: f(0),
                vel_integrator_gain: f(4),
            },
            CmdId::GetTorques => GetTorques {
                target: f(0),
                estimate: f(4),
            },
            CmdId::GetPowers => GetPowers {
                electrical: f(0),
                mechanical: f(4),
            },
            CmdId::EnterDfuMode => EnterDfuMode,
        })
    }
}

/// The data frame carrying `msg` for `node`.
pub fn frame<F: Frame>(node: u8, msg: &Message) -> Result<F, OdriveError> {
    let id = can_id(node, msg.cmd_id())?;
    let (data, len) = msg.encode()?;
    let sid = StandardId::new(id).ok_or(OdriveError::NodeId(node))?;
    F::new(sid, &data[..len]).ok_or(OdriveError::NodeId(node))
}

/// The remote frame requesting `cmd` from `node` (DLC 8, as ODrive's tools send).
pub fn request_frame<F: Frame>(node: u8, cmd: CmdId) -> Result<F, OdriveError> {
    let id = can_id(node, cmd)?;
    let sid = StandardId::new(id).ok_or(OdriveError::NodeId(node))?;
    F::new_remote(sid, 8).ok_or(OdriveError::NodeId(node))
}

/// Decodes a received data frame into `(node_id, message)`.
pub fn decode_frame<F: Frame>(f: &F) -> Result<(u8, Message), OdriveError> {
    let Id::Standard(sid) = f.id() else {
        return Err(OdriveError::UnknownId(crate::can::raw_id(f.id())));
    };
    if f.is_remote_frame() {
        return Err(OdriveError::Remote);
    }
    let (node, code) = split_id(sid.as_raw());
    let cmd = CmdId::from_code(code).ok_or(OdriveError::UnknownId(sid.as_raw() as u32))?;
    Ok((node, Message::decode(cmd, f.data())?))
}

/// Convenience: [`frame`] with this crate's [`CanFrame`].
pub fn to_can_frame(node: u8, msg: &Message) -> Result<CanFrame, OdriveError> {
    frame(node, msg)
}
