//! CAN motors that answer real frames: an MIT-mode motor (Katz firmware behaviour: one reply per
//! received frame, sent before the command is applied) and an ODrive axis (CAN Simple 0.6:
//! remote-frame requests, setpoints, cyclic heartbeat and encoder estimates).
//!
//! Both are as strict as their firmware, never kinder:
//!
//! * [`MitMotorSim`] ignores commands until the Enter frame (counted, [`MitMotorSim::ignored`]);
//!   Enter starts with a zero command (no torque until the next command), Exit makes it limp.
//!   A fault ([`MitMotorSim::inject_fault`]) makes it limp and refuses Enter until cleared;
//!   the fault code shows only in the 8-byte replies of newer CubeMars firmware
//!   (`long_reply = true`, `data[7]`; the 6-byte Katz reply has no room for it).
//! * [`OdriveAxisSim`] starts IDLE; an axis error ([`OdriveAxisSim::inject_error`]) puts it in
//!   IDLE, shows in the heartbeat and Get_Error, and refuses every state but IDLE until
//!   Clear_Errors. Inputs written while IDLE are kept: entering closed loop goes to the stored
//!   input position (a stale input makes it jump).

use conductor_protocols::can::CanFrame;
use conductor_protocols::mit_can::{self, Limits, MotorCommand, SpecialCommand};
use conductor_protocols::odrive_can::{self, axis_state, control_mode, split_id, CmdId, Message};
use embedded_can::{Frame, Id};

/// What a test can see of a simulated node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeSnapshot {
    /// Motor or node ID.
    pub id: u8,
    /// Position (rad).
    pub position: f64,
    /// Motor mode / closed loop on.
    pub enabled: bool,
    /// Frames received addressed to it.
    pub frames_in: u64,
    /// Active fault: the MIT fault code (1–10) or the ODrive axis error bits; 0 = none.
    pub fault: u32,
    /// Commands ignored (MIT: control frames outside motor mode; ODrive: state requests
    /// refused while an axis error is active).
    pub ignored: u64,
}

/// A node on a simulated CAN bus.
pub trait CanNode: Send {
    /// A frame from the bus at `now_ns`; answers are appended to `out`.
    fn on_frame(&mut self, f: &CanFrame, now_ns: u64, out: &mut Vec<CanFrame>);
    /// Time passes: cyclic messages due by `now_ns` are appended to `out`.
    fn poll(&mut self, _now_ns: u64, _out: &mut Vec<CanFrame>) {}
    /// Its state.
    fn snapshot(&self) -> NodeSnapshot;
    /// Injects fault `code` (MIT fault code, ODrive axis error bits); false if the node has no
    /// such faults or the code does not fit.
    fn set_fault(&mut self, _code: u32) -> bool {
        false
    }
    /// Clears an injected fault (for an ODrive the host's Clear_Errors does too); false if the
    /// node has no faults.
    fn reset_fault(&mut self) -> bool {
        false
    }
}

/// Rigid-body joint: `J·dv/dt = τ − b·v`, integrated in steps of at most 0.25 ms.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Joint {
    p: f64,
    v: f64,
    tau: f64,
    t_ns: Option<u64>,
}

impl Joint {
    const J: f64 = 0.01;
    const B: f64 = 0.05;

    fn advance(&mut self, now_ns: u64, torque: impl Fn(f64, f64) -> f64) {
        let Some(t0) = self.t_ns.replace(now_ns) else {
            return;
        };
        let mut left = now_ns.saturating_sub(t0) as f64 * 1e-9;
        // Long idle gaps need no fine integration once the joint is at rest.
        left = left.min(1.0);
        while left > 0.0 {
            let dt = left.min(0.000_25);
            self.tau = torque(self.p, self.v);
            self.v += (self.tau - Self::B * self.v) / Self::J * dt;
            self.p += self.v * dt;
            left -= dt;
        }
    }
}

/// An MIT-mode motor.
#[derive(Debug, Clone)]
pub struct MitMotorSim {
    id: u8,
    master: u16,
    limits: Limits,
    enabled: bool,
    cmd: mit_can::Command,
    joint: Joint,
    zero: f64,
    long_reply: bool,
    fault: u8,
    temperature: u8,
    ignored: u64,
    /// Frames received addressed to this motor.
    pub frames_in: u64,
}

impl MitMotorSim {
    /// Motor `id` with `limits`, replying to `master`; `long_reply` sends the 8-byte reply
    /// (temperature and fault code) of newer CubeMars firmware. Faults show only in those.
    pub fn new(id: u8, limits: Limits, master: u16, long_reply: bool) -> Self {
        Self {
            id,
            master,
            limits,
            enabled: false,
            cmd: mit_can::Command::default(),
            joint: Joint {
                p: 0.0,
                v: 0.0,
                tau: 0.0,
                t_ns: None,
            },
            zero: 0.0,
            long_reply,
            fault: 0,
            temperature: 40,
            ignored: 0,
            frames_in: 0,
        }
    }

    /// Motors `ids` of one model, each replying to master 0 with the 6-byte reply: the
    /// simulated MIT bus that tests and the `can_sim` hardware put behind an adapter.
    pub fn bus(ids: impl IntoIterator<Item = u8>, limits: Limits) -> Vec<Box<dyn CanNode>> {
        ids.into_iter()
            .map(|id| Box::new(Self::new(id, limits, 0, false)) as Box<dyn CanNode>)
            .collect()
    }

    /// Control commands ignored because motor mode was off (before Enter, after Exit, while
    /// faulted).
    pub fn ignored(&self) -> u64 {
        self.ignored
    }

    /// Latches fault `code` (CubeMars codes 1–10: over-voltage, under-voltage, DRV fault, abs
    /// over-current, FET over-temperature, motor over-temperature, gate-driver over-/under-
    /// voltage, MCU under-voltage, watchdog reset): the motor leaves motor mode (limp, command
    /// reset), refuses Enter until [`clear_fault`](Self::clear_fault), and its 8-byte replies
    /// carry `code` in `data[7]` (the 6-byte reply cannot show it). Code 0 clears.
    pub fn inject_fault(&mut self, code: u8) {
        self.fault = code;
        if code != 0 {
            self.enabled = false;
            self.cmd = mit_can::Command::default();
        }
    }

    /// Clears the fault; the motor stays limp until the next Enter.
    pub fn clear_fault(&mut self) {
        self.fault = 0;
    }

    /// The latched fault code (0 = none).
    pub fn fault(&self) -> u8 {
        self.fault
    }

    /// Sets the temperature reported in `data[6]` of the 8-byte reply (°C as sent).
    pub fn set_temperature(&mut self, c: u8) {
        self.temperature = c;
    }

    /// Whether motor mode is on.
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// Position relative to the zero (rad).
    pub fn position(&self) -> f64 {
        self.joint.p - self.zero
    }

    /// The command being executed.
    pub fn command(&self) -> mit_can::Command {
        self.cmd
    }

    fn advance(&mut self, now_ns: u64) {
        let (c, on, zero) = (self.cmd, self.enabled, self.zero);
        let tmax = self.limits.t.max as f64;
        self.joint.advance(now_ns, |p, v| {
            if !on {
                return 0.0;
            }
            let t = c.kp as f64 * (c.p as f64 - (p - zero))
                + c.kd as f64 * (c.v as f64 - v)
                + c.t as f64;
            t.clamp(-tmax, tmax)
        });
    }
}

impl CanNode for MitMotorSim {
    fn on_frame(&mut self, f: &CanFrame, now_ns: u64, out: &mut Vec<CanFrame>) {
        if f.id() != Id::Standard(embedded_can::StandardId::new(self.id as u16).unwrap())
            || f.is_remote_frame()
            || f.dlc() != 8
        {
            return;
        }
        self.frames_in += 1;
        self.advance(now_ns);
        // Katz's RX handler packs the reply before it decodes the command.
        let reply = mit_can::Reply {
            motor_id: self.id,
            p: (self.joint.p - self.zero) as f32,
            v: self.joint.v as f32,
            t: self.joint.tau as f32,
            extra: self.long_reply.then_some(mit_can::ReplyExtra {
                temperature: self.temperature,
                fault: mit_can::Fault::from_code(self.fault),
            }),
        };
        if let Ok(r) = mit_can::reply_frame(self.master, &reply, &self.limits) {
            out.push(r);
        }
        match mit_can::decode_command(f.data(), &self.limits) {
            // Motor mode starts from a zero command: no torque until the next command. A
            // faulted motor stays limp.
            Ok(MotorCommand::Special(SpecialCommand::Enter)) => {
                self.cmd = mit_can::Command::default();
                self.enabled = self.fault == 0;
            }
            Ok(MotorCommand::Special(SpecialCommand::Exit)) => {
                self.enabled = false;
                self.cmd = mit_can::Command::default();
            }
            Ok(MotorCommand::Special(SpecialCommand::Zero)) => self.zero = self.joint.p,
            Ok(MotorCommand::Control(c)) if self.enabled => self.cmd = c,
            Ok(MotorCommand::Control(_)) => self.ignored += 1,
            _ => {}
        }
    }

    fn snapshot(&self) -> NodeSnapshot {
        NodeSnapshot {
            id: self.id,
            position: self.position(),
            enabled: self.enabled,
            frames_in: self.frames_in,
            fault: self.fault as u32,
            ignored: self.ignored,
        }
    }

    fn set_fault(&mut self, code: u32) -> bool {
        match u8::try_from(code) {
            Ok(c) => {
                self.inject_fault(c);
                true
            }
            Err(_) => false,
        }
    }

    fn reset_fault(&mut self) -> bool {
        self.clear_fault();
        true
    }
}

/// An ODrive axis (node ID 0–63).
#[derive(Debug, Clone)]
pub struct OdriveAxisSim {
    node: u8,
    state: u32,
    control_mode: u32,
    input: (f32, f32, f32),
    /// Position (rev) and velocity (rev/s).
    pos: f64,
    vel: f64,
    t_ns: Option<u64>,
    heartbeat_ns: u64,
    encoder_ns: u64,
    next_heartbeat: u64,
    next_encoder: u64,
    axis_error: u32,
    ignored: u64,
    /// Frames received addressed to this axis.
    pub frames_in: u64,
}

impl OdriveAxisSim {
    /// Axis `node` sending its heartbeat every `heartbeat_ms` and encoder estimates every
    /// `encoder_ms` (0: never).
    pub fn new(node: u8, heartbeat_ms: u64, encoder_ms: u64) -> Self {
        Self {
            node,
            state: axis_state::IDLE,
            control_mode: control_mode::POSITION,
            input: (0.0, 0.0, 0.0),
            pos: 0.0,
            vel: 0.0,
            t_ns: None,
            heartbeat_ns: heartbeat_ms * 1_000_000,
            encoder_ns: encoder_ms * 1_000_000,
            next_heartbeat: 0,
            next_encoder: 0,
            axis_error: 0,
            ignored: 0,
            frames_in: 0,
        }
    }

    /// Axis state (8 = closed loop).
    pub fn state(&self) -> u32 {
        self.state
    }

    /// Sets `axis_error` bits: the axis disarms (IDLE), the heartbeat and Get_Error report
    /// them, and every requested state but IDLE is refused until Clear_Errors (or
    /// [`clear_error`](Self::clear_error)). 0 changes nothing.
    pub fn inject_error(&mut self, axis_error: u32) {
        if axis_error != 0 {
            self.axis_error |= axis_error;
            self.state = axis_state::IDLE;
        }
    }

    /// Clears the axis error, as Clear_Errors does; the axis stays IDLE.
    pub fn clear_error(&mut self) {
        self.axis_error = 0;
    }

    /// The active axis error bits (0 = none).
    pub fn axis_error(&self) -> u32 {
        self.axis_error
    }

    /// Set_Axis_State requests refused because of an active error.
    pub fn ignored(&self) -> u64 {
        self.ignored
    }

    /// The stored inputs: position (rev), velocity (rev/s), torque (Nm).
    pub fn input(&self) -> (f32, f32, f32) {
        self.input
    }

    /// Position (rev).
    pub fn position(&self) -> f64 {
        self.pos
    }

    fn advance(&mut self, now_ns: u64) {
        let Some(t0) = self.t_ns.replace(now_ns) else {
            return;
        };
        let dt = now_ns.saturating_sub(t0) as f64 * 1e-9;
        if dt <= 0.0 {
            return;
        }
        let before = self.pos;
        if self.state == axis_state::CLOSED_LOOP_CONTROL {
            match self.control_mode {
                control_mode::POSITION => {
                    let k = (-dt / 0.05).exp();
                    self.pos = self.input.0 as f64 + (self.pos - self.input.0 as f64) * k;
                }
                control_mode::VELOCITY => self.pos += self.input.1 as f64 * dt,
                _ => {}
            }
        }
        self.vel = (self.pos - before) / dt;
    }

    fn answer(&self, cmd: CmdId) -> Option<Message> {
        Some(match cmd {
            CmdId::Heartbeat => Message::Heartbeat {
                axis_error: self.axis_error,
                axis_state: self.state as u8,
                procedure_result: 0,
                trajectory_done: true,
            },
            CmdId::GetEncoderEstimates => Message::GetEncoderEstimates {
                pos: self.pos as f32,
                vel: self.vel as f32,
            },
            CmdId::GetIq => Message::GetIq {
                setpoint: self.input.2 / 0.1,
                measured: self.input.2 / 0.1,
            },
            CmdId::GetTorques => Message::GetTorques {
                target: self.input.2,
                estimate: self.input.2,
            },
            CmdId::GetBusVoltageCurrent => Message::GetBusVoltageCurrent {
                voltage: 24.0,
                current: 0.5,
            },
            CmdId::GetTemperature => Message::GetTemperature {
                fet: 35.0,
                motor: 30.0,
            },
            CmdId::GetError => Message::GetError {
                active_errors: self.axis_error,
                disarm_reason: self.axis_error,
            },
            _ => return None,
        })
    }
}

impl CanNode for OdriveAxisSim {
    fn on_frame(&mut self, f: &CanFrame, now_ns: u64, out: &mut Vec<CanFrame>) {
        let Id::Standard(sid) = f.id() else { return };
        let (node, code) = split_id(sid.as_raw());
        if node != self.node {
            return;
        }
        let Some(cmd) = CmdId::from_code(code) else {
            return;
        };
        self.frames_in += 1;
        self.advance(now_ns);
        if f.is_remote_frame() {
            if let Some(m) = self.answer(cmd) {
                if let Ok(fr) = odrive_can::frame(self.node, &m) {
                    out.push(fr);
                }
            }
            return;
        }
        match Message::decode(cmd, f.data()) {
            // An axis with an active error only goes (stays) IDLE. Entering closed loop keeps
            // the stored input position.
            Ok(Message::SetAxisState { requested_state })
                if self.axis_error != 0 && requested_state != axis_state::IDLE =>
            {
                self.ignored += 1;
            }
            Ok(Message::SetAxisState { requested_state }) => self.state = requested_state,
            Ok(Message::ClearErrors { .. }) => self.axis_error = 0,
            Ok(Message::Estop) => self.state = axis_state::IDLE,
            Ok(Message::SetControllerMode { control_mode, .. }) => self.control_mode = control_mode,
            Ok(Message::SetInputPos {
                pos,
                vel_ff,
                torque_ff,
            }) => self.input = (pos, vel_ff, torque_ff),
            Ok(Message::SetInputVel { vel, torque_ff }) => {
                self.input = (self.input.0, vel, torque_ff)
            }
            Ok(Message::SetInputTorque { torque }) => self.input.2 = torque,
            _ => {}
        }
    }

    fn poll(&mut self, now_ns: u64, out: &mut Vec<CanFrame>) {
        let due = |next: &mut u64, period: u64| {
            if period == 0 || now_ns < *next {
                return false;
            }
            *next = now_ns + period;
            true
        };
        let hb = due(&mut self.next_heartbeat, self.heartbeat_ns);
        let enc = due(&mut self.next_encoder, self.encoder_ns);
        if hb || enc {
            self.advance(now_ns);
        }
        for (yes, cmd) in [(hb, CmdId::Heartbeat), (enc, CmdId::GetEncoderEstimates)] {
            if let Some(m) = self.answer(cmd).filter(|_| yes) {
                if let Ok(fr) = odrive_can::frame(self.node, &m) {
                    out.push(fr);
                }
            }
        }
    }

    fn snapshot(&self) -> NodeSnapshot {
        NodeSnapshot {
            id: self.node,
            position: self.pos * std::f64::consts::TAU,
            enabled: self.state == axis_state::CLOSED_LOOP_CONTROL,
            frames_in: self.frames_in,
            fault: self.axis_error,
            ignored: self.ignored,
        }
    }

    fn set_fault(&mut self, code: u32) -> bool {
        self.inject_error(code);
        true
    }

    fn reset_fault(&mut self) -> bool {
        self.clear_error();
        true
    }
}
