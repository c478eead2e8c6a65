//! An MIT-mode CAN motor (Ben Katz firmware, CubeMars AK series).
//!
//! The motor answers every frame it receives with its state and sends nothing unasked, so a
//! sample needs a frame on the bus. Each device tick sends at most one command: the writes of
//! the tick (position, velocity, torque, kp, kd) combined into one MIT command; without writes,
//! a sample re-sends the last command (which also feeds the motor's CAN timeout), or, before
//! any command, a poll that does not change the motor's mode (exit frame while disabled, enter
//! frame while enabled).

use crate::message::{Credential, MitSpecial, Op, Reply, ReplyData, Request, Update};
use crate::queue::Bounded;
use crate::stage::{Channel, Device, SafeAction, TickCtx};

/// Channel indices of [`MitMotor`].
pub mod mit_channel {
    /// Position (rad): reply position, command target.
    pub const POSITION: usize = 0;
    /// Velocity (rad/s): reply velocity, command target.
    pub const VELOCITY: usize = 1;
    /// Torque (N·m): reply torque, command feed-forward.
    pub const TORQUE: usize = 2;
    /// Position gain (write-only).
    pub const KP: usize = 3;
    /// Velocity gain (write-only).
    pub const KD: usize = 4;
    /// 1 enters motor mode, 0 exits (write-only).
    pub const ENABLE: usize = 5;
}

const CHANNELS: [Channel; 6] = [
    Channel::read_write("position", "rad"),
    Channel::read_write("velocity", "rad/s"),
    Channel::read_write("torque", "N.m"),
    Channel::write_only("kp", "N.m/rad"),
    Channel::write_only("kd", "N.m.s/rad"),
    Channel::write_only("enable", ""),
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

/// An MIT-mode motor.
#[derive(Debug)]
pub struct MitMotor {
    cred: Credential,
    target: Target,
    dirty: bool,
    enable: Option<bool>,
    enabled: bool,
    commanded: bool,
    /// Bit per channel ever sampled: every reply updates them.
    sampled: u8,
    /// A sample was asked for this tick: a frame must go out.
    poll: bool,
    last_p: Option<f32>,
    fault_tick: Option<u64>,
    faults: u64,
}

impl MitMotor {
    /// The motor with CAN ID `cred.id`, gains `kp`/`kd` until written; with `enable_on_start`
    /// the first tick enters motor mode.
    pub fn new(cred: Credential, kp: f32, kd: f32, enable_on_start: bool) -> Self {
        Self {
            cred,
            target: Target {
                kp,
                kd,
                ..Target::default()
            },
            dirty: false,
            enable: enable_on_start.then_some(true),
            enabled: false,
            commanded: false,
            sampled: 0,
            poll: false,
            last_p: None,
            fault_tick: None,
            faults: 0,
        }
    }

    /// The safe action this kind declares: exit motor mode.
    pub const SAFE_ACTION: SafeAction = SafeAction::TorqueOff;

    /// Fault replies (8-byte replies with a fault code) since start.
    pub fn faults(&self) -> u64 {
        self.faults
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
}

impl Device for MitMotor {
    fn credential(&self) -> Credential {
        self.cred
    }

    fn channels(&self) -> &[Channel] {
        &CHANNELS
    }

    fn sample(&mut self, channel: usize, _ctx: TickCtx, _out: &mut Bounded<Request>) {
        // The frame that samples goes out at flush, combined with the tick's writes.
        if channel <= mit_channel::TORQUE {
            self.sampled |= 1 << channel;
            self.poll = true;
        }
    }

    fn write(&mut self, channel: usize, value: f64, _ctx: TickCtx) {
        if !value.is_finite() {
            return;
        }
        let v = value as f32;
        let t = &mut self.target;
        match channel {
            mit_channel::POSITION => t.p = v,
            mit_channel::VELOCITY => t.v = v,
            mit_channel::TORQUE => t.t = v,
            mit_channel::KP => t.kp = v,
            mit_channel::KD => t.kd = v,
            mit_channel::ENABLE => {
                self.enable = Some(value >= 0.5);
                return;
            }
            _ => return,
        }
        self.dirty = true;
    }

    fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        let mut sent = false;
        if self.dirty || self.enable.is_some() {
            // The command's reply answers this tick's samples.
            self.poll = false;
        }
        if let Some(on) = self.enable.take() {
            let s = if on {
                MitSpecial::Enter
            } else {
                MitSpecial::Exit
            };
            self.push(Op::MitSpecial(s), ctx, out);
            self.enabled = on;
            sent = true;
        }
        if self.dirty {
            self.dirty = false;
            self.push(self.command(), ctx, out);
            self.commanded = true;
            sent = true;
        }
        if !sent && std::mem::take(&mut self.poll) {
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
        let (vals, fault) = match reply.data {
            ReplyData::Mit { p, v, t } => {
                self.last_p = Some(p);
                (Some([p as f64, v as f64, t as f64]), false)
            }
            ReplyData::Missing { .. } => (None, false),
            ReplyData::DeviceError { .. } => {
                self.faults += 1;
                self.fault_tick = Some(reply.tick);
                return;
            }
            _ => return,
        };
        let fault = fault || self.fault_tick == Some(reply.tick);
        for ch in 0..3 {
            if self.sampled & (1 << ch) == 0 {
                continue;
            }
            let _ = out.push(Update::from_reply(reply, ch, vals.map(|v| v[ch]), fault));
        }
    }

    fn safe(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        match action {
            SafeAction::TorqueOff => {
                self.enabled = false;
                self.dirty = false;
                self.push(Op::MitSpecial(MitSpecial::Exit), ctx, out);
            }
            SafeAction::Hold => match self.last_p {
                Some(p) => {
                    self.target.p = p;
                    self.target.v = 0.0;
                    self.target.t = 0.0;
                    self.dirty = false;
                    self.push(self.command(), ctx, out);
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
