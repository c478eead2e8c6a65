//! An ODrive axis on CAN Simple (firmware 0.6.x).
//!
//! Positions and velocities are converted from ODrive's turns to radians. Samples are remote
//! frames requesting the message that carries the value (one per message and tick: position
//! and velocity share Get_Encoder_Estimates); with `poll = false` the device relies on the
//! axis's cyclic messages instead. A tick's setpoints become one Set_Input_Pos (position
//! mode, with velocity and torque as feed-forward), Set_Input_Vel or Set_Input_Torque.

use std::f64::consts::TAU;

use conductor_protocols::odrive_can::{axis_state, control_mode, input_mode, CmdId, Message};

use crate::message::{Credential, Op, Reply, ReplyData, Request, Update};
use crate::protocol::odrive_get;
use crate::queue::Bounded;
use crate::stage::{Channel, Device, SafeAction, TickCtx};

/// Channel indices of [`OdriveAxis`].
pub mod odrive_channel {
    /// Position (rad): encoder estimate; input position.
    pub const POSITION: usize = 0;
    /// Velocity (rad/s): encoder estimate; input velocity or feed-forward.
    pub const VELOCITY: usize = 1;
    /// Torque (N·m): torque estimate; input torque or feed-forward.
    pub const TORQUE: usize = 2;
    /// Iq measured (A), read-only.
    pub const CURRENT: usize = 3;
    /// Axis state (8 = closed loop, 1 = idle): heartbeat; requested state.
    pub const STATE: usize = 4;
    /// Axis error bits from the heartbeat, read-only.
    pub const ERROR: usize = 5;
    /// Bus voltage (V), read-only.
    pub const BUS_VOLTAGE: usize = 6;
    /// Motor temperature (°C), read-only.
    pub const TEMPERATURE: usize = 7;
}

const CHANNELS: [Channel; 8] = [
    Channel::read_write("position", "rad"),
    Channel::read_write("velocity", "rad/s"),
    Channel::read_write("torque", "N.m"),
    Channel::read_only("current", "A"),
    Channel::read_write("state", ""),
    Channel::read_only("error", ""),
    Channel::read_only("bus_voltage", "V"),
    Channel::read_only("temperature", "degC"),
];

/// Which input the axis's controller takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OdriveMode {
    /// Position control: Set_Input_Pos (velocity, torque as feed-forward).
    Position,
    /// Velocity control: Set_Input_Vel (torque as feed-forward).
    Velocity,
    /// Torque control: Set_Input_Torque.
    Torque,
}

/// The message that carries channel `ch`.
fn source(ch: usize) -> Option<CmdId> {
    use odrive_channel::*;
    Some(match ch {
        POSITION | VELOCITY => CmdId::GetEncoderEstimates,
        TORQUE => CmdId::GetTorques,
        CURRENT => CmdId::GetIq,
        STATE | ERROR => CmdId::Heartbeat,
        BUS_VOLTAGE => CmdId::GetBusVoltageCurrent,
        TEMPERATURE => CmdId::GetTemperature,
        _ => return None,
    })
}

/// An ODrive axis.
#[derive(Debug)]
pub struct OdriveAxis {
    cred: Credential,
    mode: OdriveMode,
    poll: bool,
    start: bool,
    pos: f64,
    vel: f64,
    torque: f64,
    dirty: bool,
    state: Option<u32>,
    /// Messages requested this tick (dedupe), with the tick.
    asked: (u64, u32),
    last_pos: Option<f64>,
    fault_tick: Option<u64>,
}

impl OdriveAxis {
    /// The axis with node ID `cred.id`; `poll` requests values with remote frames (else the
    /// axis's cyclic messages are used); `enable_on_start` sets the controller mode and closed
    /// loop control on the first tick.
    pub fn new(cred: Credential, mode: OdriveMode, poll: bool, enable_on_start: bool) -> Self {
        Self {
            cred,
            mode,
            poll,
            start: enable_on_start,
            pos: 0.0,
            vel: 0.0,
            torque: 0.0,
            dirty: false,
            state: None,
            asked: (u64::MAX, 0),
            last_pos: None,
            fault_tick: None,
        }
    }

    /// The safe action this kind declares: idle the axis.
    pub const SAFE_ACTION: SafeAction = SafeAction::TorqueOff;

    fn push(&self, msg: Message, ctx: TickCtx, out: &mut Bounded<Request>) {
        let _ = out.push(Request::new(self.cred, Op::Odrive(msg), ctx));
    }

    fn setpoint(&self) -> Message {
        let rev = |x: f64| (x / TAU) as f32;
        match self.mode {
            OdriveMode::Position => Message::SetInputPos {
                pos: rev(self.pos),
                vel_ff: rev(self.vel),
                torque_ff: self.torque as f32,
            },
            OdriveMode::Velocity => Message::SetInputVel {
                vel: rev(self.vel),
                torque_ff: self.torque as f32,
            },
            OdriveMode::Torque => Message::SetInputTorque {
                torque: self.torque as f32,
            },
        }
    }

    fn update(
        &self,
        ch: usize,
        value: Option<f64>,
        fault: bool,
        r: &Reply,
        out: &mut Bounded<Update>,
    ) {
        let _ = out.push(Update::from_reply(r, ch, value, fault));
    }
}

impl Device for OdriveAxis {
    fn credential(&self) -> Credential {
        self.cred
    }

    fn channels(&self) -> &[Channel] {
        &CHANNELS
    }

    fn sample(&mut self, channel: usize, ctx: TickCtx, out: &mut Bounded<Request>) {
        if !self.poll {
            return;
        }
        let Some(cmd) = source(channel) else { return };
        if self.asked.0 != ctx.tick {
            self.asked = (ctx.tick, 0);
        }
        let bit = 1u32 << (cmd as u8);
        if self.asked.1 & bit != 0 {
            return;
        }
        self.asked.1 |= bit;
        if let Some(msg) = odrive_get(cmd) {
            self.push(msg, ctx, out);
        }
    }

    fn write(&mut self, channel: usize, value: f64, _ctx: TickCtx) {
        if !value.is_finite() {
            return;
        }
        use odrive_channel::*;
        match channel {
            POSITION => self.pos = value,
            VELOCITY => self.vel = value,
            TORQUE => self.torque = value,
            STATE if (0.0..=15.0).contains(&value) => {
                self.state = Some(value.round() as u32);
                return;
            }
            _ => return,
        }
        self.dirty = true;
    }

    fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        if std::mem::take(&mut self.start) {
            let control_mode = match self.mode {
                OdriveMode::Position => control_mode::POSITION,
                OdriveMode::Velocity => control_mode::VELOCITY,
                OdriveMode::Torque => control_mode::TORQUE,
            };
            self.push(
                Message::SetControllerMode {
                    control_mode,
                    input_mode: input_mode::PASSTHROUGH,
                },
                ctx,
                out,
            );
            self.state.get_or_insert(axis_state::CLOSED_LOOP_CONTROL);
        }
        if let Some(s) = self.state.take() {
            self.push(Message::SetAxisState { requested_state: s }, ctx, out);
        }
        if std::mem::take(&mut self.dirty) {
            self.push(self.setpoint(), ctx, out);
        }
    }

    fn reply(&mut self, reply: &Reply, out: &mut Bounded<Update>) {
        use odrive_channel::*;
        let fault = self.fault_tick == Some(reply.tick);
        match reply.data {
            ReplyData::Odrive(msg) => match msg {
                Message::GetEncoderEstimates { pos, vel } => {
                    let p = pos as f64 * TAU;
                    self.last_pos = Some(p);
                    self.update(POSITION, Some(p), fault, reply, out);
                    self.update(VELOCITY, Some(vel as f64 * TAU), fault, reply, out);
                }
                Message::GetTorques { estimate, .. } => {
                    self.update(TORQUE, Some(estimate as f64), fault, reply, out)
                }
                Message::GetIq { measured, .. } => {
                    self.update(CURRENT, Some(measured as f64), fault, reply, out)
                }
                Message::Heartbeat {
                    axis_error,
                    axis_state,
                    ..
                } => {
                    let fault = fault || axis_error != 0;
                    if axis_error != 0 {
                        self.fault_tick = Some(reply.tick);
                    }
                    self.update(STATE, Some(axis_state as f64), fault, reply, out);
                    self.update(ERROR, Some(axis_error as f64), fault, reply, out);
                }
                Message::GetBusVoltageCurrent { voltage, .. } => {
                    self.update(BUS_VOLTAGE, Some(voltage as f64), fault, reply, out)
                }
                Message::GetTemperature { motor, .. } => {
                    self.update(TEMPERATURE, Some(motor as f64), fault, reply, out)
                }
                _ => {}
            },
            ReplyData::Missing {
                op: Op::Odrive(msg),
            } => {
                for ch in 0..CHANNELS.len() {
                    if source(ch) == Some(msg.cmd_id()) {
                        self.update(ch, None, fault, reply, out);
                    }
                }
            }
            _ => {}
        }
    }

    fn safe(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        match action {
            SafeAction::TorqueOff => {
                self.dirty = false;
                self.push(
                    Message::SetAxisState {
                        requested_state: axis_state::IDLE,
                    },
                    ctx,
                    out,
                );
            }
            SafeAction::Hold => match self.last_pos {
                Some(p) => {
                    self.pos = p;
                    self.vel = 0.0;
                    self.torque = 0.0;
                    self.dirty = false;
                    self.push(
                        Message::SetInputPos {
                            pos: (p / TAU) as f32,
                            vel_ff: 0.0,
                            torque_ff: 0.0,
                        },
                        ctx,
                        out,
                    );
                }
                None => self.safe(SafeAction::TorqueOff, ctx, out),
            },
            SafeAction::Setpoint { channel, value } => {
                self.write(channel, value, ctx);
                self.flush(ctx, out);
            }
        }
    }
}
