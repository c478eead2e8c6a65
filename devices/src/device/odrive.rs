//! An ODrive axis on CAN Simple (firmware 0.6.x).
//!
//! Positions and velocities are converted from ODrive's turns to radians. Samples are remote
//! frames requesting the message that carries the value (one per message and tick: position
//! and velocity share Get_Encoder_Estimates); with `poll = false` the device relies on the
//! axis's cyclic messages instead. A tick's setpoints become one Set_Input_Pos (position
//! mode, with velocity and torque as feed-forward), Set_Input_Vel or Set_Input_Torque.
//!
//! Lifecycle (managed by the executor):
//!
//! ```text
//! Probe    Heartbeat (remote frame): it is there; its state and axis error
//! Align    Set_Controller_Mode, Get_Encoder_Estimates: where it is
//! Enable   Clear_Errors if an error is latched, the input set to where it is (position mode;
//!          0 velocity or torque otherwise), Set_Axis_State(closed loop), then Heartbeats until
//!          it reports closed loop without error
//! ```
//!
//! CAN Simple cannot read back the controller mode, so it is written at every enable. The axis
//! disarms itself on an error (axis error in the heartbeat): that trips it.

use std::f64::consts::TAU;

use conductor_protocols::odrive_can::{axis_state, control_mode, input_mode, CmdId, Message};

use crate::component::{Channel, Device, SafeAction, TickCtx};
use crate::lifecycle::{
    life_step, DeviceStatus, Failure, Goal, Lifecycle, Phase, Startup, PROBE_TRIES,
};
use crate::message::{Credential, Op, Reply, ReplyData, Request, Update};
use crate::protocol_stage::odrive_get;
use crate::queue::Bounded;

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
    /// Axis state (8 = closed loop, 1 = idle), from the heartbeat.
    pub const STATE: usize = 4;
    /// Axis error bits from the heartbeat, read-only.
    pub const ERROR: usize = 5;
    /// Bus voltage (V), read-only.
    pub const BUS_VOLTAGE: usize = 6;
    /// Motor temperature (°C), read-only.
    pub const TEMPERATURE: usize = 7;
    /// 1 while in closed loop control; write 1 to enable from where it is, 0 to idle it.
    pub const ENABLE: usize = 8;
}

const CHANNELS: [Channel; 9] = [
    Channel::read_write("position", "rad"),
    Channel::read_write("velocity", "rad/s"),
    Channel::read_write("torque", "N.m"),
    Channel::read_only("current", "A"),
    Channel::read_only("state", ""),
    Channel::read_only("error", ""),
    Channel::read_only("bus_voltage", "V"),
    Channel::read_only("temperature", "degC"),
    Channel::read_write("enable", ""),
];

/// Polls of the heartbeat, one per tick, while waiting for the axis to enter closed loop.
const CONFIRM_POLLS: u8 = 50;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    None,
    /// Heartbeat request out.
    Probe,
    /// Controller mode written, encoder estimates requested.
    Align,
    /// Input set, closed loop requested: heartbeats until it says so.
    Enable,
    /// Idle requested (limp goal): heartbeats until it says so.
    Idle,
    /// A safe action: heartbeats until the axis shows it.
    Safe,
}

life_step!(Step);

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
    pos: f64,
    vel: f64,
    torque: f64,
    dirty: bool,
    /// Messages requested this tick (dedupe), with the tick.
    asked: (u64, u32),
    last_pos: Option<f64>,
    /// Axis state and error from the last heartbeat.
    axis: Option<(u32, u32)>,
    fault_tick: Option<u64>,
    report_enable: bool,
    /// Unmanaged: closed loop (or idle) asked for through the `enable` channel.
    raw_enable: Option<bool>,
    life: Lifecycle<Step>,
    /// The state the axis must report to complete the step.
    want_state: u32,
    /// The safe action's setpoint (re-sent while holding).
    safe_msg: Option<Message>,
}

impl OdriveAxis {
    /// The axis with node ID `cred.id`; `poll` requests values with remote frames (else the
    /// axis's cyclic messages are used).
    pub fn new(cred: Credential, mode: OdriveMode, poll: bool) -> Self {
        Self {
            cred,
            mode,
            poll,
            pos: 0.0,
            vel: 0.0,
            torque: 0.0,
            dirty: false,
            asked: (u64::MAX, 0),
            last_pos: None,
            axis: None,
            fault_tick: None,
            report_enable: false,
            raw_enable: None,
            life: Lifecycle::new(),
            want_state: 0,
            safe_msg: None,
        }
    }

    fn managed(&self) -> bool {
        self.life.managed()
    }

    fn control_mode(&self) -> u32 {
        match self.mode {
            OdriveMode::Position => control_mode::POSITION,
            OdriveMode::Velocity => control_mode::VELOCITY,
            OdriveMode::Torque => control_mode::TORQUE,
        }
    }

    /// The input that holds the axis where it is (position mode) or still (others).
    fn hold_input(&mut self, pos: f64) -> Message {
        self.pos = pos;
        self.vel = 0.0;
        self.torque = 0.0;
        self.setpoint()
    }

    fn heartbeat(&self, ctx: TickCtx, out: &mut Bounded<Request>) {
        if let Some(m) = odrive_get(CmdId::Heartbeat) {
            self.push(m, ctx, out);
        }
    }

    /// Lifecycle requests of this tick.
    fn drive(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        if !self.managed() || self.life.sent || ctx.now_ns < self.life.next_try_ns {
            return;
        }
        match self.life.step {
            Step::None => return,
            Step::Probe => self.heartbeat(ctx, out),
            Step::Align => {
                self.push(
                    Message::SetControllerMode {
                        control_mode: self.control_mode(),
                        input_mode: input_mode::PASSTHROUGH,
                    },
                    ctx,
                    out,
                );
                if let Some(m) = odrive_get(CmdId::GetEncoderEstimates) {
                    self.push(m, ctx, out);
                }
            }
            Step::Enable if self.life.tries == 0 => {
                if self.life.status.fault != 0 {
                    self.push(Message::ClearErrors { identify: 0 }, ctx, out);
                }
                let input = self.hold_input(self.last_pos.unwrap_or(0.0));
                self.push(input, ctx, out);
                self.request_state(axis_state::CLOSED_LOOP_CONTROL, ctx, out);
            }
            Step::Idle if self.life.tries == 0 => {
                self.request_state(axis_state::IDLE, ctx, out);
            }
            Step::Enable | Step::Idle | Step::Safe => self.heartbeat(ctx, out),
        }
        self.life.sent = true;
    }

    /// A heartbeat (asked or cyclic) arrived.
    fn on_heartbeat(&mut self, state: u32, error: u32) {
        self.axis = Some((state, error));
        if self.managed() {
            self.life.status.fault = error;
        }
        match self.life.step {
            Step::Probe => {
                if self.life.goal == Goal::Limp {
                    if state == axis_state::IDLE {
                        self.life.settle_limp();
                    } else {
                        self.life.go(Step::Idle);
                    }
                } else {
                    self.life.status.phase = Phase::Configuring;
                    self.life.go(Step::Align);
                }
            }
            Step::Enable | Step::Idle | Step::Safe if self.life.sent => {
                if state == self.want_state && (error == 0 || self.want_state == axis_state::IDLE) {
                    self.confirmed();
                } else {
                    self.poll_again();
                }
            }
            _ => {}
        }
    }

    fn confirmed(&mut self) {
        match self.life.step {
            Step::Enable => self.life.switched_on(),
            Step::Idle => self.life.settle_limp(),
            Step::Safe => self.life.safe_confirmed(),
            _ => {}
        }
    }

    /// The axis is not there yet: ask again next tick, up to a bound.
    fn poll_again(&mut self) {
        self.life.tries = self.life.tries.saturating_add(1);
        self.life.sent = false;
        // A safe action is watched until it shows; the executor bounds the wait.
        if self.life.tries >= CONFIRM_POLLS && self.life.step != Step::Safe {
            if self.life.step == Step::Enable {
                self.life.refuse_enable();
            } else {
                // Any other action stays unconfirmed.
                self.life.step = Step::None;
            }
        }
    }

    fn missing(&mut self, now_ns: u64) {
        match self.life.step {
            Step::Probe => {
                if self.life.retry_exhausted(now_ns) {
                    self.life.fail(Failure::NoAnswer);
                }
            }
            Step::Align => {
                // Asked again at once, as many times as a probe.
                self.life.tries += 1;
                self.life.sent = false;
                if self.life.tries >= PROBE_TRIES {
                    self.life.fail(Failure::NoAnswer);
                }
            }
            Step::Enable | Step::Idle | Step::Safe => self.poll_again(),
            Step::None => {}
        }
    }

    /// Asks the axis for `state` and for the heartbeat that will confirm it.
    fn request_state(&mut self, state: u32, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.push(
            Message::SetAxisState {
                requested_state: state,
            },
            ctx,
            out,
        );
        self.want_state = state;
        self.heartbeat(ctx, out);
    }

    fn start_enable(&mut self) {
        self.life.goal = Goal::Drive;
        self.life.user_off = false;
        self.dirty = false;
        self.safe_msg = None;
        self.life.status.phase = Phase::Enabling;
        // Where it is now, never a target from before.
        self.life.go(Step::Align);
    }

    fn start_disable(&mut self) {
        self.life.goal = Goal::Limp;
        self.life.user_off = true;
        self.dirty = false;
        self.safe_msg = None;
        self.life.status.phase = Phase::Disabled;
        self.life.go(Step::Idle);
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
        if channel == odrive_channel::ENABLE {
            self.report_enable = true;
            return;
        }
        let absent = matches!(
            self.life.status.phase,
            Phase::Offline | Phase::Probing | Phase::Failed
        );
        if !self.poll || absent {
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
        if channel == ENABLE {
            if !self.managed() {
                self.raw_enable = Some(value >= 0.5);
                return;
            }
            match self.life.enable_request(value) {
                Some(true) => self.start_enable(),
                Some(false) => self.start_disable(),
                None => {}
            }
            return;
        }
        if !self.accepts(channel) {
            return;
        }
        if self.life.setpoint_enables() {
            self.start_enable();
        }
        match channel {
            POSITION => self.pos = value,
            VELOCITY => self.vel = value,
            TORQUE => self.torque = value,
            _ => return,
        }
        self.dirty = true;
    }

    fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.drive(ctx, out);
        if let Some(on) = self.raw_enable.take() {
            if on {
                self.push(
                    Message::SetControllerMode {
                        control_mode: self.control_mode(),
                        input_mode: input_mode::PASSTHROUGH,
                    },
                    ctx,
                    out,
                );
            }
            let requested_state = if on {
                axis_state::CLOSED_LOOP_CONTROL
            } else {
                axis_state::IDLE
            };
            self.push(Message::SetAxisState { requested_state }, ctx, out);
        }
        // Holding (any other phase): the axis keeps its input by itself.
        if matches!(self.life.status.phase, Phase::Unmanaged | Phase::Enabled)
            && std::mem::take(&mut self.dirty)
        {
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
                    if self.life.step == Step::Align && self.life.sent {
                        self.life.status.phase = Phase::Enabling;
                        self.life.go(Step::Enable);
                    }
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
                    self.on_heartbeat(axis_state as u32, axis_error);
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
                if matches!(msg.cmd_id(), CmdId::Heartbeat | CmdId::GetEncoderEstimates)
                    && self.life.sent
                {
                    self.missing(reply.t_sample_ns);
                }
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
        let managed = self.managed();
        self.dirty = false;
        if managed && !self.life.begin_safe() {
            return;
        }
        let idle = Message::SetAxisState {
            requested_state: axis_state::IDLE,
        };
        let (msg, state) = match action {
            SafeAction::TorqueOff | SafeAction::Damp { .. } => (idle, axis_state::IDLE),
            SafeAction::Hold => match self.last_pos {
                Some(p) if self.life.status.phase != Phase::Disabled => {
                    (self.hold_input(p), axis_state::CLOSED_LOOP_CONTROL)
                }
                _ => (idle, axis_state::IDLE),
            },
            SafeAction::Setpoint { channel, value } => {
                match channel {
                    odrive_channel::POSITION => self.pos = value,
                    odrive_channel::VELOCITY => self.vel = value,
                    odrive_channel::TORQUE => self.torque = value,
                    _ => {}
                }
                (self.setpoint(), axis_state::CLOSED_LOOP_CONTROL)
            }
        };
        self.push(msg, ctx, out);
        if !managed {
            return;
        }
        if state == axis_state::IDLE {
            self.life.goal = Goal::Limp;
            self.life.status.phase = Phase::Disabled;
            self.safe_msg = None;
        } else {
            self.safe_msg = Some(msg);
            self.life.status.phase = Phase::Holding;
            if self.life.status.tripped {
                self.life.goal = Goal::Hold;
            }
        }
        // Confirmed by the axis's heartbeat showing the state.
        self.life.go(Step::Safe);
        self.want_state = state;
        self.heartbeat(ctx, out);
        self.life.sent = true;
    }

    fn status(&self) -> DeviceStatus {
        self.life.status
    }

    fn bring_up(&mut self, startup: Startup, _ctx: TickCtx) {
        self.life.bring_up(startup);
        self.life.go(Step::Probe);
    }

    fn bus_lost(&mut self) {
        if !self.managed() {
            return;
        }
        self.life.bus_lost();
        self.dirty = false;
    }

    fn accepts(&self, channel: usize) -> bool {
        if channel == odrive_channel::ENABLE {
            return self.managed();
        }
        if !CHANNELS.get(channel).is_some_and(|c| c.writable) {
            return false;
        }
        self.life.accepts_setpoints()
    }

    fn trip(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.life.begin_trip();
        self.safe(action, ctx, out);
    }

    fn report(&mut self, ctx: TickCtx, out: &mut Bounded<Update>) {
        if self.report_enable {
            let on = matches!(self.life.status.phase, Phase::Enabled);
            let _ = out.push(Update::local(odrive_channel::ENABLE, on as u8 as f64, ctx));
        }
    }

    fn describe(&self) -> String {
        format!(
            "ODrive axis, {} control{}",
            match self.mode {
                OdriveMode::Position => "position",
                OdriveMode::Velocity => "velocity",
                OdriveMode::Torque => "torque",
            },
            self.axis
                .map(|(s, e)| format!("; axis state {s}, error {e:#x}"))
                .unwrap_or_default()
        )
    }
}

crate::choices!(OdriveMode { Position = "position", Velocity = "velocity", Torque = "torque" });

/// The `odrive_axis` device kind.
pub const KIND: crate::kinds::KindSpec = crate::kinds::KindSpec {
    kind: "odrive_axis",
    params: &[
        crate::kinds::ParamSpec::choice::<OdriveMode>(
            "control_mode",
            "position",
            "which input the setpoints drive",
        ),
        crate::kinds::ParamSpec::bool(
            "poll",
            true,
            "request values with remote frames (false: use the axis's cyclic messages)",
        ),
    ],
    doc: "An ODrive axis (CAN Simple, firmware 0.6). Channels: position (rad), velocity (rad/s), \
          torque (N·m), current (A), state, error, bus_voltage (V), temperature (°C), enable. \
          Brought up by a heartbeat request, the controller mode written, the input set to the \
          present position, then closed-loop control, confirmed by its heartbeat. Safe action: \
          torque off (idle).",
    build: crate::kinds::Build::Device {
        protocols: &["can_motors"],
        safe_actions: &["torque_off", "hold", "setpoint"],
        build: |p, cred| {
            Ok(Box::new(OdriveAxis::new(
                cred,
                p.choice("control_mode")?,
                p.bool("poll")?,
            )))
        },
        agrees: None,
    },
};
