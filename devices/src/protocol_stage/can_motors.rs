//! The CAN motor stage: MIT-mode motors and ODrive axes on one classic CAN bus (SocketCAN or
//! SLCAN). Every request of a tick becomes one frame and the tick's frames go out together;
//! replies are matched to requests by the motor ID in the payload (MIT) or the node ID in the
//! arbitration ID (ODrive).

use conductor_protocols::can::CanFrame;
use conductor_protocols::mit_can::{self, Command, Limits, Model, SpecialCommand};
use conductor_protocols::odrive_can::{self, CmdId, Message};
use embedded_can::{Frame, Id, StandardId};

use crate::component::{Protocol, ProtocolCounters, TickCtx};
use crate::message::{Credential, MitSpecial, Op, Reply, ReplyData, Request};
use crate::outstanding::{Outstanding, Pending};
use crate::queue::Bounded;

/// The MIT-mode model names the manifest accepts, with their ranges.
pub const MIT_MODELS: &[(&str, Model)] = &[
    ("ak10-9", Model::Ak10_9),
    ("ak60-6", Model::Ak60_6),
    ("ak70-10", Model::Ak70_10),
    ("ak80-6", Model::Ak80_6),
    ("ak80-9", Model::Ak80_9),
    ("ak80-64", Model::Ak80_64),
    ("mini-cheetah", Model::MiniCheetah),
];

/// Ranges of a model name from [`MIT_MODELS`].
pub fn mit_limits(name: &str) -> Option<Limits> {
    MIT_MODELS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, m)| m.limits())
}

/// Why a per-motor model table does not parse.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("bad MIT model table entry {0:?}: expected \"<id>=<model>\" with a model from {models}", models = MIT_MODELS.iter().map(|m| m.0).collect::<Vec<_>>().join(", "))]
pub struct ModelTableError(pub String);

/// Parses `"1=ak80-9,2=ak10-9"` (empty string: no overrides).
pub fn parse_model_table(s: &str) -> Result<Vec<(u8, Limits)>, ModelTableError> {
    s.split(',')
        .map(str::trim)
        .filter(|e| !e.is_empty())
        .map(|e| {
            let (id, model) = e.split_once('=').ok_or_else(|| ModelTableError(e.into()))?;
            let id: u8 = id.trim().parse().map_err(|_| ModelTableError(e.into()))?;
            let l = mit_limits(model.trim()).ok_or_else(|| ModelTableError(e.into()))?;
            Ok((id, l))
        })
        .collect()
}

/// ODrive messages that are requested with a remote frame and answered by the axis.
fn is_get(cmd: CmdId) -> bool {
    matches!(
        cmd,
        CmdId::GetVersion
            | CmdId::Heartbeat
            | CmdId::GetError
            | CmdId::GetEncoderEstimates
            | CmdId::GetIq
            | CmdId::GetTemperature
            | CmdId::GetBusVoltageCurrent
            | CmdId::GetTorques
            | CmdId::GetPowers
    )
}

fn special(s: MitSpecial) -> SpecialCommand {
    match s {
        MitSpecial::Enter => SpecialCommand::Enter,
        MitSpecial::Exit => SpecialCommand::Exit,
        MitSpecial::Zero => SpecialCommand::Zero,
    }
}

/// MIT-mode and ODrive protocol stage. Word = [`CanFrame`].
#[derive(Debug)]
pub struct CanMotorProtocol {
    default_limits: Limits,
    limits: Vec<(u8, Limits)>,
    master: StandardId,
    timeout_ns: u64,
    pending: Outstanding,
    counters: ProtocolCounters,
    unsolicited: u64,
}

impl CanMotorProtocol {
    /// A stage whose MIT motors use `default_limits` unless listed in `per_motor`; MIT replies
    /// arrive on `master_id`; a request unanswered after `timeout_ns` is missing.
    pub fn new(
        default_limits: Limits,
        per_motor: Vec<(u8, Limits)>,
        master_id: u16,
        timeout_ns: u64,
        in_flight: usize,
    ) -> Self {
        Self {
            default_limits,
            limits: per_motor,
            // IDs above 0x7FF are refused by the manifest's range check.
            master: StandardId::new(master_id).unwrap_or(StandardId::ZERO),
            timeout_ns,
            pending: Outstanding::with_capacity(in_flight.max(1)),
            counters: ProtocolCounters::default(),
            unsolicited: 0,
        }
    }

    fn limits_of(&self, motor: u8) -> Limits {
        self.limits
            .iter()
            .find(|(id, _)| *id == motor)
            .map_or(self.default_limits, |(_, l)| *l)
    }

    /// Valid frames nobody asked for and no device stage can use.
    pub fn unsolicited(&self) -> u64 {
        self.unsolicited
    }

    fn frame_for(&self, r: &Request) -> Option<(CanFrame, bool)> {
        let id = u16::try_from(r.cred.id).ok()?;
        match r.op {
            Op::Mit { p, v, kp, kd, t } => {
                let l = self.limits_of(u8::try_from(id).ok()?);
                let cmd = Command { p, v, kp, kd, t };
                mit_can::command_frame(id, &cmd, &l).ok().map(|f| (f, true))
            }
            Op::MitSpecial(s) => mit_can::special_frame(id, special(s))
                .ok()
                .map(|f| (f, true)),
            Op::Odrive(msg) => {
                let node = u8::try_from(id).ok()?;
                if is_get(msg.cmd_id()) {
                    odrive_can::request_frame(node, msg.cmd_id())
                        .ok()
                        .map(|f| (f, true))
                } else {
                    odrive_can::frame(node, &msg).ok().map(|f| (f, false))
                }
            }
            _ => None,
        }
    }

    /// `t_rx` is the frame's arrival (CLOCK_MONOTONIC ns, 0 = unknown): a motor samples when
    /// it answers, so the sample time is the answer's arrival where the kernel stamped it.
    fn on_frame(
        &mut self,
        f: &CanFrame,
        fence: u64,
        t_rx: u64,
        ctx: TickCtx,
        out: &mut Bounded<Reply>,
    ) {
        // MIT reply: from the master ID, motor ID in data[0].
        if f.id() == Id::Standard(self.master) && !f.is_remote_frame() && matches!(f.dlc(), 6 | 8) {
            let motor = f.data()[0];
            let cred = Credential::id(motor as u32);
            let is_mit = |op: &Op| matches!(op, Op::Mit { .. } | Op::MitSpecial(_));
            if let Some(p) = self.pending.resolve(cred, fence, is_mit) {
                let l = self.limits_of(motor);
                match mit_can::Reply::decode(f.data(), &l) {
                    Ok(rep) => {
                        self.counters.packets_in += 1;
                        if let Some(fault) = rep.extra.and_then(|e| e.fault) {
                            self.counters.device_errors += 1;
                            let _ = out.push(p.reply_at(
                                ReplyData::DeviceError {
                                    code: fault.code() as u32,
                                },
                                t_rx,
                            ));
                        }
                        let _ = out.push(p.reply_at(
                            ReplyData::Mit {
                                p: rep.p,
                                v: rep.v,
                                t: rep.t,
                                temperature: rep.extra.map(|e| e.temperature),
                            },
                            t_rx,
                        ));
                    }
                    Err(_) => {
                        self.counters.rejected_packets += 1;
                        let _ = out.push(p.reply(ReplyData::Missing { op: p.op }));
                    }
                }
                return;
            }
            if let Some(p) = self.pending.resolve_late(cred, is_mit) {
                // The answer to a request already reported missing: its time is unknown, so it
                // carries no value; it still proves the motor got the request.
                self.counters.late_replies += 1;
                let _ = out.push(p.reply(ReplyData::Late { op: p.op }));
                return;
            }
        }
        match odrive_can::decode_frame(f) {
            Ok((node, msg)) => {
                let cred = Credential::id(node as u32);
                let cmd = msg.cmd_id();
                let same = |op: &Op| matches!(op, Op::Odrive(m) if m.cmd_id() == cmd);
                let asked = self.pending.resolve(cred, fence, same);
                if asked.is_none() {
                    if let Some(p) = self.pending.resolve_late(cred, same) {
                        self.counters.late_replies += 1;
                        let _ = out.push(p.reply(ReplyData::Late { op: p.op }));
                        return;
                    }
                }
                self.counters.packets_in += 1;
                // Cyclic messages (heartbeat, encoder estimates) arrive unasked: they are
                // sampled when received.
                let reply = match asked {
                    Some(p) => p.reply_at(ReplyData::Odrive(msg), t_rx),
                    None => Reply {
                        cred,
                        data: ReplyData::Odrive(msg),
                        op: None,
                        tick: ctx.tick,
                        t_sample_ns: if t_rx == 0 { ctx.now_ns } else { t_rx },
                    },
                };
                let _ = out.push(reply);
            }
            Err(_) => self.unsolicited += 1,
        }
    }
}

impl Protocol for CanMotorProtocol {
    type Word = CanFrame;
    // A motor's command of this tick supersedes the one of an earlier tick still unsent.
    const SUPERSEDES_UNSENT: bool = true;

    fn encode(&mut self, requests: &[Request], out: &mut Bounded<CanFrame>, ctx: TickCtx) {
        for r in requests {
            let Some((frame, answered)) = self.frame_for(r) else {
                self.counters.dropped_requests += 1;
                continue;
            };
            if out.push(frame).is_err() {
                self.counters.dropped_requests += 1;
                continue;
            }
            self.counters.packets_out += 1;
            self.counters.words_out += 1;
            let end_pos = self.counters.words_out;
            if answered
                && !self
                    .pending
                    .track(Pending::new(r, ctx.now_ns + self.timeout_ns, end_pos))
            {
                // It goes out, but its answer cannot be told apart: counted, left unmatched.
                self.counters.dropped_requests += 1;
            }
        }
    }

    fn decode(
        &mut self,
        words: &[CanFrame],
        fence: &[u64],
        out: &mut Bounded<Reply>,
        ctx: TickCtx,
    ) {
        self.decode_timed(words, fence, &[], out, ctx);
    }

    fn decode_timed(
        &mut self,
        words: &[CanFrame],
        fence: &[u64],
        times: &[u64],
        out: &mut Bounded<Reply>,
        ctx: TickCtx,
    ) {
        for (i, f) in words.iter().enumerate() {
            self.counters.words_in += 1;
            let fence = fence.get(i).copied().unwrap_or(u64::MAX);
            let t_rx = times.get(i).copied().unwrap_or(0);
            self.on_frame(f, fence, t_rx, ctx, out);
        }
    }

    fn expire(&mut self, out: &mut Bounded<Reply>, ctx: TickCtx) {
        self.counters.missing_replies += self.pending.expire(ctx.now_ns, out);
    }

    fn counters(&self) -> ProtocolCounters {
        let mut c = self.counters;
        c.rejected_packets += self.unsolicited;
        c
    }

    fn reset(&mut self, out: &mut Bounded<Reply>) {
        self.counters.missing_replies += self.pending.drain_missing(out);
    }

    fn preempt(&mut self) {
        // Requests become frames at once: nothing is queued here (the link drops unsent frames).
    }

    fn discard_unsent(&mut self, from: u64) {
        self.counters.dropped_requests += self.pending.forget_from(from);
    }
}

/// An ODrive "get" message for `cmd`, with zeroed fields (the request carries no data).
pub fn odrive_get(cmd: CmdId) -> Option<Message> {
    Message::decode(cmd, &[0; 8]).ok().filter(|_| is_get(cmd))
}

/// The names of [`MIT_MODELS`], for the kinds' `model` parameters.
pub const MIT_MODEL_NAMES: &[&str] = &[
    "ak10-9",
    "ak60-6",
    "ak70-10",
    "ak80-6",
    "ak80-9",
    "ak80-64",
    "mini-cheetah",
];

/// The ranges of the MIT model named in parameter `name`.
pub fn mit_model(p: &crate::kinds::Params, name: &str) -> Result<Limits, crate::kinds::BuildError> {
    let model = p.str(name)?;
    mit_limits(model).ok_or_else(|| {
        crate::kinds::BuildError::invalid(
            name,
            crate::kinds::Invalid::Name {
                value: model.into(),
                names: MIT_MODEL_NAMES,
            },
        )
    })
}

/// The ranges a `can_motors` stage with parameters `p` encodes motor `id`'s frames with: its
/// `models` entry for that id, else its `model` (as [`CanMotorProtocol`] looks them up).
pub fn stage_limits(p: &crate::kinds::Params, id: u32) -> Result<Limits, crate::kinds::BuildError> {
    let table = parse_model_table(p.str("models")?)
        .map_err(|e| crate::kinds::BuildError::invalid("models", e))?;
    match table.iter().find(|(m, _)| u32::from(*m) == id) {
        Some((_, l)) => Ok(*l),
        None => mit_model(p, "model"),
    }
}

/// The `can_motors` protocol kind.
pub const KIND: crate::kinds::KindSpec = crate::kinds::KindSpec {
    kind: "can_motors",
    params: &[
        crate::kinds::ParamSpec::names("model", Some("ak80-9"), MIT_MODEL_NAMES, "ranges of the MIT-mode motors"),
        crate::kinds::ParamSpec::text("models", Some(""), "per-motor overrides, e.g. \"1=ak80-9,2=ak10-9\""),
        crate::kinds::ParamSpec::int("master_id", Some(0), 0.0, 2047.0, "CAN ID the MIT motors reply on (CAN_MASTER)"),
        crate::kinds::TIMEOUT_US,
    ],
    doc: "MIT-mode motors and ODrive axes (CAN Simple 0.6) on one classic CAN bus: one frame per \
          device and tick, all of a tick's frames sent together; MIT replies matched by the motor ID \
          in the payload, ODrive replies by node ID; cyclic ODrive messages are passed on.",
    build: crate::kinds::Build::Protocol(crate::kinds::ProtocolBuild::Can(|p, hw, cap| {
        let table = parse_model_table(p.str("models")?)
            .map_err(|e| crate::kinds::BuildError::invalid("models", e))?;
        let timeout_us: u64 = p.int_as("timeout_us")?;
        let stage = CanMotorProtocol::new(
            mit_model(p, "model")?,
            table,
            p.int_as("master_id")?,
            timeout_us * 1000,
            cap.in_flight,
        );
        hw.link(stage, cap)
    })),
};

#[cfg(test)]
mod kind_tests {
    #[test]
    fn model_names_match_the_table() {
        let names: Vec<&str> = super::MIT_MODELS.iter().map(|m| m.0).collect();
        assert_eq!(names, super::MIT_MODEL_NAMES);
    }
}
