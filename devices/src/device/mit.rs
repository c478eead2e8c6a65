//! An MIT-mode CAN motor (Ben Katz firmware, CubeMars AK series).
//!
//! The motor answers every frame it receives with its state and sends nothing unasked, so a
//! sample needs a frame on the bus. Each device tick sends at most one command: the writes of
//! the tick (position, velocity, torque, kp, kd) combined into one MIT command; without writes,
//! a sample re-sends the last command (which also feeds the motor's CAN timeout), or, while the
//! motor is out of motor mode, an exit frame (a poll that does not change its mode).
//!
//! Lifecycle (managed by the executor):
//!
//! ```text
//! Probe    exit-motor-mode frame: the reply says it is there, and where
//! Enable   enter-motor-mode frame, then a command holding the present position with the
//!          configured gains (entering motor mode never resumes an old target); enabled
//!          when the motor answers the command. Sent again after lost rounds, it polls
//!          first once the position reading is older than `HOLD_FRESH_NS`
//! ```
//!
//! MIT motors have no model number and no configuration on the bus (their IDs, CAN master ID and
//! ranges are set in the motor's own menu): bring-up checks that the motor answers. A fault code
//! (8-byte replies of newer firmware) trips it.

use crate::component::{Channel, Device, SafeAction, TickCtx};
use crate::lifecycle::{
    life_step, DeviceStatus, Failure, Goal, Lifecycle, Phase, Startup, LOST_ROUNDS,
    ROUND_TIMEOUT_NS,
};
use crate::message::{Credential, MitSpecial, Op, Reply, ReplyData, Request, Update};
use crate::queue::Bounded;

use super::reg_device::HOLD_FRESH_NS;

/// Channel indices of [`MitMotor`].
pub mod mit_channel {
    /// Position (rad): reply position, command target.
    pub const POSITION: usize = 0;
    /// Velocity (rad/s): reply velocity, command target.
    pub const VELOCITY: usize = 1;
    /// Torque (N·m): reply torque, command feed-forward.
    pub const TORQUE: usize = 2;
    /// Position gain: the one in use (reported by the device), settable.
    pub const KP: usize = 3;
    /// Velocity gain: the one in use, settable.
    pub const KD: usize = 4;
    /// 1 while in motor mode and driving; write 1 to enable from where it is, 0 to exit motor
    /// mode.
    pub const ENABLE: usize = 5;
    /// Motor temperature (°C), from 8-byte replies.
    pub const TEMPERATURE: usize = 6;
    /// Fault code of the last reply (0 = none; 8-byte replies).
    pub const FAULT: usize = 7;
}

const CHANNELS: [Channel; 8] = [
    Channel::read_write("position", "rad"),
    Channel::read_write("velocity", "rad/s"),
    Channel::read_write("torque", "N.m"),
    Channel::read_write("kp", "N.m/rad"),
    Channel::read_write("kd", "N.m.s/rad"),
    Channel::read_write("enable", ""),
    Channel::read_only("temperature", "degC"),
    Channel::read_only("fault", ""),
];

/// Command targets.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Target {
    p: f32,
    v: f32,
    kp: f32,
    kd: f32,
    t: f32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    None,
    Probe,
    Enable,
    /// A safe action, waiting for the motor's answer to it.
    Safe,
}

life_step!(Step);

/// An MIT-mode motor.
#[derive(Debug)]
pub struct MitMotor {
    cred: Credential,
    target: Target,
    /// Gains in use (the manifest's until the kp/kd channels are written).
    gains: (f32, f32),
    /// The manifest's gains: enabling (again) holds with these, whatever was written before.
    configured: (f32, f32),
    dirty: bool,
    /// Bit per channel ever sampled: every reply (and report) updates them.
    sampled: u8,
    /// Unmanaged: an enter/exit frame asked for through the `enable` channel.
    special: Option<MitSpecial>,
    /// A sample was asked for this tick: a frame must go out.
    poll: bool,
    /// In motor mode, as far as we commanded it.
    enabled: bool,
    commanded: bool,
    last_p: Option<f32>,
    /// When `last_p` was sampled.
    last_p_ns: u64,
    /// Re-probes of the present enable (a resent enable whose position reading had grown old);
    /// bounded by [`LOST_ROUNDS`].
    realigns: u8,
    temperature: Option<u8>,
    fault_tick: Option<u64>,
    faults: u64,
    /// Lifecycle (a hold goal holds the position, or damps, with `safe_cmd`, refusing
    /// setpoints).
    life: Lifecycle<Step>,
    /// The request whose answer completes the step.
    awaiting: Option<Op>,
    /// The command a safe action sends (re-sent every tick while tripped in motor mode).
    safe_cmd: Option<Op>,
}

impl MitMotor {
    /// The motor with CAN ID `cred.id`, gains `kp`/`kd` until written.
    pub fn new(cred: Credential, kp: f32, kd: f32) -> Self {
        Self {
            cred,
            target: Target {
                kp,
                kd,
                ..Target::default()
            },
            gains: (kp, kd),
            configured: (kp, kd),
            dirty: false,
            sampled: 0,
            special: None,
            poll: false,
            enabled: false,
            commanded: false,
            last_p: None,
            last_p_ns: 0,
            realigns: 0,
            temperature: None,
            fault_tick: None,
            faults: 0,
            life: Lifecycle::new(),
            awaiting: None,
            safe_cmd: None,
        }
    }

    /// The safe action this kind declares: exit motor mode.
    pub const SAFE_ACTION: SafeAction = SafeAction::TorqueOff;

    /// Fault replies (8-byte replies with a fault code) since start.
    pub fn faults(&self) -> u64 {
        self.faults
    }

    fn managed(&self) -> bool {
        self.life.managed()
    }

    fn push(&self, op: Op, ctx: TickCtx, out: &mut Bounded<Request>) {
        let _ = out.push(Request::new(self.cred, op, ctx));
    }

    fn command(&self) -> Op {
        let t = self.target;
        Op::Mit {
            p: t.p,
            v: t.v,
            kp: t.kp,
            kd: t.kd,
            t: t.t,
        }
    }

    /// Holding `p` with the manifest's gains: what enabling (and a hold) sends; gains a
    /// controller wrote before are not kept (they may be none at all).
    fn hold_at(&mut self, p: f32) -> Op {
        self.gains = self.configured;
        self.target = Target {
            p,
            v: 0.0,
            kp: self.gains.0,
            kd: self.gains.1,
            t: 0.0,
        };
        self.command()
    }

    fn go(&mut self, step: Step) {
        self.life.go(step);
        self.awaiting = None;
    }

    fn driving(&self) -> bool {
        matches!(self.life.status.phase, Phase::Enabled | Phase::Unmanaged)
    }

    /// Lifecycle requests of this tick; true if a frame went out.
    fn drive(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) -> bool {
        if self.managed() && self.life.round_overdue(ctx.now_ns, ROUND_TIMEOUT_NS) {
            // Neither its answer nor word of it missing came: lost (sent again below).
            self.retry(ctx.now_ns);
        }
        if !self.managed() || self.life.sent || ctx.now_ns < self.life.next_try_ns {
            return false;
        }
        match self.life.step {
            Step::None => return false,
            Step::Probe => {
                let op = Op::MitSpecial(MitSpecial::Exit);
                self.push(op, ctx, out);
                self.enabled = false;
                self.awaiting = Some(op);
            }
            Step::Enable => {
                let Some(p) = self.last_p else {
                    // Where it is must be known first: poll.
                    self.go(Step::Probe);
                    return self.drive(ctx, out);
                };
                let again = self.life.tries > 0 || self.life.lost > 0;
                if again && ctx.now_ns.saturating_sub(self.last_p_ns) > HOLD_FRESH_NS {
                    // Sent again after lost rounds: where it was read is not where it is now
                    // (a limp joint still coasting). Poll again and enable there, within a
                    // bound: a line that keeps losing the round gives up.
                    if self.realigns >= LOST_ROUNDS {
                        self.life.refuse_enable();
                        self.enabled = false;
                        return false;
                    }
                    self.realigns += 1;
                    self.go(Step::Probe);
                    return self.drive(ctx, out);
                }
                self.push(Op::MitSpecial(MitSpecial::Enter), ctx, out);
                let cmd = self.hold_at(p);
                self.push(cmd, ctx, out);
                self.enabled = true;
                self.commanded = true;
                self.awaiting = Some(cmd);
            }
            Step::Safe => {
                // A retry of the action.
                let Some(op) = self.awaiting else {
                    return false;
                };
                self.push(op, ctx, out);
            }
        }
        self.life.mark_sent(ctx.tick, ctx.now_ns);
        self.dirty = false;
        true
    }

    /// The step's reply is missing (the frame or its answer lost on the bus): sent again,
    /// within the step's budget for losses.
    fn retry(&mut self, now_ns: u64) {
        if !self.life.lost_exhausted(now_ns) {
            return;
        }
        match self.life.step {
            Step::Probe => self.life.fail(Failure::NoAnswer),
            Step::Enable => {
                self.life.refuse_enable();
                self.enabled = false;
            }
            // The action stays unconfirmed: the executor reports it.
            Step::Safe | Step::None => self.life.step = Step::None,
        }
    }

    /// The answer to the step's request arrived.
    fn step_done(&mut self) {
        match self.life.step {
            Step::Probe => {
                if self.life.goal == Goal::Limp {
                    self.life.settle_limp();
                } else {
                    self.life.status.phase = Phase::Enabling;
                    self.go(Step::Enable);
                }
            }
            Step::Enable => {
                if self.life.status.fault != 0 {
                    // A faulted motor does not enter motor mode.
                    self.life.refuse_enable();
                    self.enabled = false;
                } else {
                    self.life.switched_on();
                }
            }
            Step::Safe => self.life.safe_confirmed(),
            Step::None => {}
        }
    }

    fn life_reply(&mut self, reply: &Reply) {
        if !self.managed() || self.life.step == Step::None {
            return;
        }
        let Some(want) = self.awaiting else { return };
        if reply.op != Some(want) {
            return;
        }
        match reply.data {
            ReplyData::Mit { .. } => self.step_done(),
            // Late: it did get the frame (a lagging adapter); enough to confirm a safe action.
            ReplyData::Late { .. } if self.life.step == Step::Safe => self.step_done(),
            ReplyData::Missing { .. } => self.retry(reply.t_sample_ns),
            _ => {}
        }
    }

    fn start_enable(&mut self) {
        self.realigns = 0;
        self.life.goal = Goal::Drive;
        self.life.user_off = false;
        self.dirty = false;
        self.safe_cmd = None;
        self.life.status.phase = Phase::Enabling;
        // Where it is now, never a target from before: poll first, then enter and hold there.
        self.go(Step::Probe);
        self.life.status.phase = Phase::Enabling;
    }

    fn start_disable(&mut self) {
        self.life.goal = Goal::Limp;
        self.life.user_off = true;
        self.dirty = false;
        self.safe_cmd = None;
        self.life.status.phase = Phase::Disabled;
        self.go(Step::Probe);
    }
}

impl Device for MitMotor {
    fn credential(&self) -> Credential {
        self.cred
    }

    fn channels(&self) -> &[Channel] {
        &CHANNELS
    }

    fn sample(&mut self, channel: usize, _ctx: TickCtx, _out: &mut Bounded<Request>) {
        self.sampled |= 1 << channel;
        // The frame that samples goes out at flush, combined with the tick's writes.
        if channel <= mit_channel::TORQUE || channel == mit_channel::TEMPERATURE {
            self.poll = true;
        }
    }

    fn write(&mut self, channel: usize, value: f64, _ctx: TickCtx) {
        if !value.is_finite() {
            return;
        }
        if channel == mit_channel::ENABLE {
            if !self.managed() {
                self.special = Some(if value >= 0.5 {
                    MitSpecial::Enter
                } else {
                    MitSpecial::Exit
                });
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
        let v = value as f32;
        let t = &mut self.target;
        match channel {
            mit_channel::POSITION => t.p = v,
            mit_channel::VELOCITY => t.v = v,
            mit_channel::TORQUE => t.t = v,
            mit_channel::KP => {
                t.kp = v;
                self.gains.0 = v;
            }
            mit_channel::KD => {
                t.kd = v;
                self.gains.1 = v;
            }
            _ => return,
        }
        self.dirty = true;
    }

    fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        let poll = std::mem::take(&mut self.poll);
        if self.managed() {
            if self.drive(ctx, out) {
                return;
            }
            match self.life.status.phase {
                Phase::Enabled => {}
                Phase::Holding => {
                    // Keep holding (and feeding the motor's CAN timeout).
                    if let Some(op) = self.safe_cmd {
                        self.push(op, ctx, out);
                    }
                    return;
                }
                Phase::Disabled if poll => {
                    self.push(Op::MitSpecial(MitSpecial::Exit), ctx, out);
                    return;
                }
                _ => return,
            }
        }
        let mut sent = false;
        if let Some(s) = self.special.take() {
            self.push(Op::MitSpecial(s), ctx, out);
            self.enabled = s == MitSpecial::Enter;
            sent = true;
        }
        if self.dirty {
            self.dirty = false;
            self.push(self.command(), ctx, out);
            self.commanded = true;
            return;
        }
        if sent {
            return;
        }
        if poll {
            let op = if self.enabled && self.commanded {
                self.command()
            } else if self.enabled {
                Op::MitSpecial(MitSpecial::Enter)
            } else {
                Op::MitSpecial(MitSpecial::Exit)
            };
            self.push(op, ctx, out);
        }
    }

    fn reply(&mut self, reply: &Reply, out: &mut Bounded<Update>) {
        let vals = match reply.data {
            ReplyData::Mit {
                p,
                v,
                t,
                temperature,
            } => {
                self.last_p = Some(p);
                self.last_p_ns = reply.t_sample_ns;
                if temperature.is_some() {
                    self.temperature = temperature;
                    if self.fault_tick != Some(reply.tick) {
                        // A long reply without a fault code: the fault has cleared.
                        self.life.status.fault = 0;
                    }
                }
                Some([p as f64, v as f64, t as f64])
            }
            ReplyData::Missing { .. } => None,
            ReplyData::Late { .. } => {
                // No value (its time is unknown); it may still confirm a safe action.
                self.life_reply(reply);
                return;
            }
            ReplyData::DeviceError { code } => {
                self.faults += 1;
                self.fault_tick = Some(reply.tick);
                self.life.status.fault = code;
                return;
            }
            _ => return,
        };
        self.life_reply(reply);
        let fault = self.fault_tick == Some(reply.tick);
        for ch in 0..3 {
            if self.sampled & (1 << ch) != 0 {
                let _ = out.push(Update::from_reply(reply, ch, vals.map(|v| v[ch]), fault));
            }
        }
        if self.sampled & (1 << mit_channel::TEMPERATURE) != 0 && vals.is_some() {
            let t = self.temperature.map(f64::from);
            let _ = out.push(Update::from_reply(
                reply,
                mit_channel::TEMPERATURE,
                t,
                fault,
            ));
        }
    }

    fn safe(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        let managed = self.managed();
        self.dirty = false;
        if managed {
            self.go(Step::Safe);
            if !self.life.begin_safe() {
                return;
            }
        }
        let op = match action {
            SafeAction::Hold | SafeAction::Damp { .. }
                if self.last_p.is_none() || !self.enabled =>
            {
                return self.safe(SafeAction::TorqueOff, ctx, out)
            }
            SafeAction::TorqueOff => {
                self.enabled = false;
                self.life.goal = Goal::Limp;
                if managed {
                    self.life.status.phase = Phase::Disabled;
                }
                Op::MitSpecial(MitSpecial::Exit)
            }
            SafeAction::Hold => {
                let p = self.last_p.unwrap_or(0.0);
                self.hold_at(p)
            }
            SafeAction::Damp { kd } => {
                let p = self.last_p.unwrap_or(0.0);
                self.target = Target {
                    p,
                    v: 0.0,
                    kp: 0.0,
                    kd: kd as f32,
                    t: 0.0,
                };
                self.command()
            }
            SafeAction::Setpoint { channel, value } => {
                let v = value as f32;
                match channel {
                    mit_channel::POSITION => self.target.p = v,
                    mit_channel::VELOCITY => self.target.v = v,
                    mit_channel::TORQUE => self.target.t = v,
                    _ => {}
                }
                self.command()
            }
        };
        self.push(op, ctx, out);
        if managed {
            self.awaiting = Some(op);
            self.life.mark_sent(ctx.tick, ctx.now_ns);
            if matches!(op, Op::Mit { .. }) {
                self.safe_cmd = Some(op);
                self.life.status.phase = Phase::Holding;
                if self.life.status.tripped {
                    self.life.goal = Goal::Hold;
                }
            }
        }
    }

    fn status(&self) -> DeviceStatus {
        self.life.status
    }

    fn bring_up(&mut self, startup: Startup, _ctx: TickCtx) {
        self.realigns = 0;
        self.life.bring_up(startup);
        self.enabled = false;
        self.commanded = false;
        self.go(Step::Probe);
    }

    fn bus_lost(&mut self) {
        if !self.managed() {
            return;
        }
        self.life.bus_lost();
        self.dirty = false;
    }

    fn accepts(&self, channel: usize) -> bool {
        if channel == mit_channel::ENABLE {
            return true;
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
        let local = [
            (mit_channel::KP, self.target.kp as f64),
            (mit_channel::KD, self.target.kd as f64),
            (
                mit_channel::ENABLE,
                (self.enabled && self.driving()) as u8 as f64,
            ),
            (mit_channel::FAULT, self.life.status.fault as f64),
        ];
        for (ch, v) in local {
            if self.sampled & (1 << ch) != 0 {
                let _ = out.push(Update::local(ch, v, ctx));
            }
        }
    }

    fn describe(&self) -> String {
        format!(
            "MIT-mode motor (no model number on the bus); gains kp {} kd {}",
            self.gains.0, self.gains.1
        )
    }
}

/// The `mit_motor` device kind.
pub const KIND: crate::kinds::KindSpec = crate::kinds::KindSpec {
    kind: "mit_motor",
    params: &[
        crate::kinds::ParamSpec::float("kp", 0.0, Some((0.0, 500.0)), "position gain until the kp channel is written"),
        crate::kinds::ParamSpec::float("kd", 0.0, Some((0.0, 5.0)), "velocity gain until the kd channel is written"),
    ],
    doc: "An MIT-mode motor (Katz firmware, CubeMars AK). Channels: position (rad), velocity (rad/s), \
          torque (N·m), kp, kd (the gains in use), enable, temperature (°C) and fault (code), the \
          last two from 8-byte replies. A tick's writes form one command; the motor only answers \
          frames, so a sample re-sends the last command. Brought up by an exit-motor-mode frame \
          (it must answer), then enter motor mode and a command holding the present position. \
          Safe action: torque off (exit motor mode); `damp` commands kp = 0 and kd = `safe_value` \
          (default: the kd parameter).",
    build: crate::kinds::Build::Device {
        protocols: &["can_motors"],
        safe_actions: &["torque_off", "damp", "hold", "setpoint"],
        build: |p, cred| {
            Ok(Box::new(MitMotor::new(
                cred,
                p.float("kp")? as f32,
                p.float("kd")? as f32,
            )))
        },
        agrees: None,
    },
};
