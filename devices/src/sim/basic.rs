//! Built-in simulated hardware for tests and demos: the thesis' stress-test *sine* hardware and a
//! *loopback* that plays back setpoints (optionally through a first-order lag, like a servo).
//!
//! They speak [`SimWord`]s through the [`SimProtocol`], so the executor runs every stage (device
//! tagging, protocol bundling and reply matching, hardware queues) exactly as for a real bus.

use crate::component::{
    Channel, Device, Hardware, HwError, Protocol, ProtocolCounters, SafeAction, TickCtx,
};
use crate::message::{Credential, Op, Reply, ReplyData, Request, Update};
use crate::outstanding::{Outstanding, Pending};
use crate::queue::Bounded;

/// The unit the simulated bus carries.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SimWord {
    /// Addressed (or answering) device.
    pub cred: Credential,
    /// Request kind (downstream) or reply flag (upstream).
    pub kind: SimKind,
    /// Setpoint (downstream `Set`) or sampled value (upstream).
    pub value: f64,
    /// Request time (ns), echoed in the reply.
    pub t_ns: u64,
}

/// What a [`SimWord`] carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SimKind {
    /// Sample request.
    #[default]
    Sample,
    /// Setpoint.
    Set,
    /// Answer to a sample request.
    Value,
    /// Starting value: the device is there at once (hardware that plays values back).
    Place,
}

/// Protocol stage for the simulated bus: one word per request, replies matched by credential.
#[derive(Debug)]
pub struct SimProtocol {
    outstanding: Outstanding,
    timeout_ns: u64,
    counters: ProtocolCounters,
}

impl SimProtocol {
    /// Tracks up to `capacity` requests in flight; a reply later than `timeout_ns` is missing.
    pub fn new(capacity: usize, timeout_ns: u64) -> Self {
        Self {
            outstanding: Outstanding::with_capacity(capacity),
            timeout_ns,
            counters: ProtocolCounters::default(),
        }
    }
}

impl Protocol for SimProtocol {
    type Word = SimWord;

    fn encode(&mut self, requests: &[Request], out: &mut Bounded<SimWord>, ctx: TickCtx) {
        for r in requests {
            let word = match r.op {
                Op::Sample => SimWord {
                    cred: r.cred,
                    kind: SimKind::Sample,
                    value: 0.0,
                    t_ns: r.t_request_ns,
                },
                Op::Set { value } => SimWord {
                    cred: r.cred,
                    kind: SimKind::Set,
                    value,
                    t_ns: r.t_request_ns,
                },
                Op::Place { value } => SimWord {
                    cred: r.cred,
                    kind: SimKind::Place,
                    value,
                    t_ns: r.t_request_ns,
                },
                _ => {
                    // Not something a simulated bus can carry.
                    self.counters.dropped_requests += 1;
                    continue;
                }
            };
            if out.push(word).is_err() {
                self.counters.dropped_requests += 1;
                continue;
            }
            self.counters.packets_out += 1;
            self.counters.words_out += 1;
            let end_pos = self.counters.words_out;
            if word.kind == SimKind::Sample
                && !self
                    .outstanding
                    .track(Pending::new(r, ctx.now_ns + self.timeout_ns, end_pos))
            {
                self.counters.dropped_requests += 1;
            }
        }
    }

    fn decode(
        &mut self,
        words: &[SimWord],
        fence: &[u64],
        out: &mut Bounded<Reply>,
        _ctx: TickCtx,
    ) {
        for (i, w) in words.iter().enumerate() {
            self.counters.words_in += 1;
            if w.kind != SimKind::Value {
                self.counters.discarded_words += 1;
                continue;
            }
            let fence = fence.get(i).copied().unwrap_or(u64::MAX);
            match self
                .outstanding
                .resolve(w.cred, fence, |op| *op == Op::Sample)
            {
                Some(p) => {
                    self.counters.packets_in += 1;
                    let _ = out.push(p.reply(ReplyData::Value(w.value)));
                }
                None => {
                    // An answer nobody asked for (or already given up on).
                    self.counters.rejected_packets += 1;
                }
            }
        }
    }

    fn expire(&mut self, out: &mut Bounded<Reply>, ctx: TickCtx) {
        self.counters.missing_replies += self.outstanding.expire(ctx.now_ns, out);
    }

    fn counters(&self) -> ProtocolCounters {
        self.counters
    }

    fn reset(&mut self, out: &mut Bounded<Reply>) {
        self.counters.missing_replies += self.outstanding.drain_missing(out);
    }

    fn preempt(&mut self) {}

    fn discard_unsent(&mut self, from: u64) {
        self.counters.dropped_requests += self.outstanding.forget_from(from);
    }
}

/// The thesis' stress-test hardware: answers every sample request at time t with
/// `amplitude · sin(2π · frequency · t + phase · id)` (defaults: `sin(t)`), t in seconds of
/// CLOCK_MONOTONIC at the request.
#[derive(Debug)]
pub struct SineHardware {
    amplitude: f64,
    omega: f64,
    phase: f64,
    replies: Bounded<SimWord>,
}

impl SineHardware {
    /// A sine source; `capacity` bounds the replies buffered between two hardware ticks.
    pub fn new(amplitude: f64, frequency_hz: f64, phase_per_id: f64, capacity: usize) -> Self {
        Self {
            amplitude,
            omega: 2.0 * core::f64::consts::PI * frequency_hz,
            phase: phase_per_id,
            replies: Bounded::with_capacity(capacity),
        }
    }

    /// The value it answers for `id` at `t_ns`.
    pub fn value_at(&self, id: u32, t_ns: u64) -> f64 {
        let t = t_ns as f64 * 1e-9;
        self.amplitude * (self.omega * t + self.phase * f64::from(id)).sin()
    }
}

impl Hardware for SineHardware {
    type Word = SimWord;

    fn transmit(&mut self, words: &[SimWord], _ctx: TickCtx) -> Result<usize, HwError> {
        for (i, w) in words.iter().enumerate() {
            if w.kind == SimKind::Sample {
                let reply = SimWord {
                    kind: SimKind::Value,
                    value: self.value_at(w.cred.id, w.t_ns),
                    ..*w
                };
                if self.replies.push(reply).is_err() {
                    return Err(HwError::TxFull {
                        dropped: words.len() - i,
                    });
                }
            }
        }
        Ok(words.len())
    }

    fn receive(&mut self, out: &mut [SimWord], _ctx: TickCtx) -> Result<usize, HwError> {
        Ok(self.replies.pop_into(out))
    }
}

/// Plays setpoints back: a sample request returns the last value set for that device, followed
/// through a first-order lag of time constant `tau_s` (0: immediately). A stand-in for a servo.
#[derive(Debug)]
pub struct LoopbackHardware {
    tau_s: f64,
    /// Per device: (credential, target, current, last update ns).
    slots: Vec<(Credential, f64, f64, u64)>,
    replies: Bounded<SimWord>,
}

impl LoopbackHardware {
    /// Room for `devices` devices and `capacity` replies between ticks.
    pub fn new(tau_s: f64, devices: usize, capacity: usize) -> Self {
        Self {
            tau_s,
            slots: Vec::with_capacity(devices),
            replies: Bounded::with_capacity(capacity),
        }
    }

    fn slot(&mut self, cred: Credential, t_ns: u64) -> Option<&mut (Credential, f64, f64, u64)> {
        let i = match self.slots.iter().position(|s| s.0 == cred) {
            Some(i) => i,
            None if self.slots.len() < self.slots.capacity() => {
                self.slots.push((cred, 0.0, 0.0, t_ns));
                self.slots.len() - 1
            }
            None => return None,
        };
        let tau = self.tau_s;
        let s = &mut self.slots[i];
        // Advance the lag to t_ns.
        if t_ns > s.3 {
            let dt = (t_ns - s.3) as f64 * 1e-9;
            s.2 = if tau > 0.0 {
                s.1 + (s.2 - s.1) * (-dt / tau).exp()
            } else {
                s.1
            };
            s.3 = t_ns;
        }
        Some(s)
    }
}

impl Hardware for LoopbackHardware {
    type Word = SimWord;

    fn transmit(&mut self, words: &[SimWord], _ctx: TickCtx) -> Result<usize, HwError> {
        for (i, w) in words.iter().enumerate() {
            let tau = self.tau_s;
            let Some(slot) = self.slot(w.cred, w.t_ns) else {
                return Err(HwError::TxFull {
                    dropped: words.len() - i,
                });
            };
            match w.kind {
                SimKind::Set => {
                    slot.1 = w.value;
                    if tau <= 0.0 {
                        slot.2 = w.value;
                    }
                }
                SimKind::Place => {
                    slot.1 = w.value;
                    slot.2 = w.value;
                }
                SimKind::Sample => {
                    let reply = SimWord {
                        kind: SimKind::Value,
                        value: slot.2,
                        ..*w
                    };
                    if self.replies.push(reply).is_err() {
                        return Err(HwError::TxFull {
                            dropped: words.len() - i,
                        });
                    }
                }
                SimKind::Value => {}
            }
        }
        Ok(words.len())
    }

    fn receive(&mut self, out: &mut [SimWord], _ctx: TickCtx) -> Result<usize, HwError> {
        Ok(self.replies.pop_into(out))
    }
}

const SIM_CHANNELS: [Channel; 1] = [Channel::read_write("value", "")];

/// A device on the simulated bus with one read/write channel, `value`.
#[derive(Debug)]
pub struct SimDevice {
    cred: Credential,
    pending: Option<f64>,
    last: f64,
    /// Where the simulated hardware should start it, sent ahead of its first request.
    start: Option<f64>,
}

impl SimDevice {
    /// The device at `cred`.
    pub fn new(cred: Credential) -> Self {
        Self {
            cred,
            pending: None,
            last: 0.0,
            start: None,
        }
    }

    /// Sends the starting value once, ahead of anything else.
    fn place(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        if let Some(value) = self.start {
            if out
                .push(Request::new(self.cred, Op::Place { value }, ctx))
                .is_ok()
            {
                self.start = None;
                self.last = value;
            }
        }
    }
}

impl Device for SimDevice {
    fn credential(&self) -> Credential {
        self.cred
    }

    fn channels(&self) -> &[Channel] {
        &SIM_CHANNELS
    }

    fn sample(&mut self, _channel: usize, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.place(ctx, out);
        let _ = out.push(Request::new(self.cred, Op::Sample, ctx));
    }

    fn write(&mut self, _channel: usize, value: f64, _ctx: TickCtx) {
        self.pending = Some(value);
    }

    fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.place(ctx, out);
        if let Some(value) = self.pending.take() {
            let _ = out.push(Request::new(self.cred, Op::Set { value }, ctx));
        }
    }

    fn reply(&mut self, reply: &Reply, out: &mut Bounded<Update>) {
        let value = match reply.data {
            ReplyData::Value(v) => {
                self.last = v;
                Some(v)
            }
            ReplyData::Missing { .. } => None,
            _ => return,
        };
        let _ = out.push(Update::from_reply(reply, 0, value, false));
    }

    fn start_at(&mut self, _channel: usize, value: f64) {
        self.start = Some(value);
    }

    fn safe(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        let value = match action {
            SafeAction::Hold => self.last,
            SafeAction::TorqueOff | SafeAction::Damp { .. } => 0.0,
            SafeAction::Setpoint { value, .. } => value,
        };
        self.pending = Some(value);
        self.flush(ctx, out);
    }
}

use crate::kinds::{
    Build, BuildError, Capacity, HardwareBuild, KindSpec, OpenedHardware, ParamSpec, Params,
    ProtocolBuild,
};
use crate::link::Link;

/// The `sine` hardware kind.
pub const SINE: KindSpec = KindSpec {
    kind: "sine",
    params: &[
        ParamSpec::float("amplitude", 1.0, None, "amplitude of the answered sine"),
        ParamSpec::float(
            "frequency_hz",
            1.0 / (2.0 * core::f64::consts::PI),
            Some((0.0, 1e6)),
            "frequency (default 1/2π Hz, i.e. sin(t) as in the thesis)",
        ),
        ParamSpec::float(
            "phase_per_id",
            0.0,
            None,
            "phase offset added per device id (rad)",
        ),
    ],
    doc: "Simulated hardware of the thesis' stress test: answers every sample request at time t \
          with amplitude·sin(2π·frequency·t + phase·id), t in seconds of CLOCK_MONOTONIC.",
    build: Build::Hardware {
        resource: None,
        open: HardwareBuild::Sim(|p, cap| {
            Ok(OpenedHardware::new(SineHardware::new(
                p.float("amplitude")?,
                p.float("frequency_hz")?,
                p.float("phase_per_id")?,
                cap.words,
            )))
        }),
    },
};

/// The `loopback` hardware kind.
pub const LOOPBACK: KindSpec = KindSpec {
    kind: "loopback",
    params: &[ParamSpec::float(
        "tau_s",
        0.0,
        Some((0.0, 1e3)),
        "first-order lag between setpoint and sampled value (s); 0 = immediate",
    )],
    doc: "Simulated hardware that answers a sample request with the last setpoint written to \
          the same device, optionally through a first-order lag (a stand-in for a servo). \
          Each device starts where its state reads a value inside the state's limits (0 when \
          the limits allow it, else their middle or the one finite limit), not at 0 in device \
          units.",
    build: Build::Hardware {
        resource: None,
        open: HardwareBuild::Sim(|p, cap| {
            Ok(OpenedHardware::new(LoopbackHardware::new(
                p.float("tau_s")?,
                cap.devices,
                cap.words,
            )))
        }),
    },
};

/// The `sim` protocol kind.
pub const SIM_PROTOCOL: KindSpec = KindSpec {
    kind: "sim",
    params: &[ParamSpec::int(
        "timeout_us",
        Some(10_000),
        1.0,
        10_000_000.0,
        "a sample request unanswered after this long is reported missing (µs)",
    )],
    doc: "Protocol of the simulated hardware: one word per request, replies matched by device id.",
    build: Build::Protocol(ProtocolBuild::Sim(link_sim)),
};

fn link_sim(
    p: &Params,
    hw: OpenedHardware<SimWord>,
    cap: Capacity,
) -> Result<Box<dyn Link>, BuildError> {
    let timeout_us: u64 = p.int_as("timeout_us")?;
    hw.link(SimProtocol::new(cap.in_flight, timeout_us * 1000), cap)
}

/// The `sim` device kind.
pub const SIM_DEVICE: KindSpec = KindSpec {
    kind: "sim",
    params: &[],
    doc: "A device on the simulated bus with one read/write channel, `value`.",
    build: Build::Device {
        protocols: &["sim"],
        safe_actions: &["hold", "torque_off", "setpoint"],
        build: |_, cred| Ok(Box::new(SimDevice::new(cred))),
        agrees: None,
    },
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::{Link, LinkOf};

    fn ctx(tick: u64, now_ns: u64) -> TickCtx {
        TickCtx { tick, now_ns }
    }

    #[test]
    fn sine_answers_sin_of_request_time_through_every_stage() {
        let mut link = LinkOf::new(
            SimProtocol::new(16, 1_000_000),
            SineHardware::new(1.0, 1.0 / (2.0 * core::f64::consts::PI), 0.0, 16),
            16,
        );
        let mut dev = SimDevice::new(Credential::id(7));
        let mut reqs = Bounded::with_capacity(8);
        let t = 1_234_567_890u64;
        dev.sample(0, ctx(5, t), &mut reqs);
        link.encode(reqs.as_slice(), ctx(5, t));
        link.exchange(ctx(5, t)).unwrap();
        let mut replies = Bounded::with_capacity(8);
        link.decode(&mut replies, ctx(5, t + 10));
        assert_eq!(replies.len(), 1);
        let mut ups = Bounded::with_capacity(8);
        dev.reply(&replies.as_slice()[0], &mut ups);
        let u = ups.as_slice()[0];
        assert_eq!((u.tick, u.t_sample_ns), (5, t));
        assert!((u.value.unwrap() - (t as f64 * 1e-9).sin()).abs() < 1e-12);
        assert_eq!(link.counters().protocol.packets_in, 1);
    }

    #[test]
    fn loopback_plays_back_setpoints_and_missing_replies_are_reported() {
        let mut link = LinkOf::new(
            SimProtocol::new(16, 1_000),
            LoopbackHardware::new(0.0, 4, 16),
            16,
        );
        let mut dev = SimDevice::new(Credential::id(1));
        let mut reqs = Bounded::with_capacity(8);
        dev.write(0, 0.75, ctx(1, 100));
        dev.flush(ctx(1, 100), &mut reqs);
        dev.sample(0, ctx(1, 100), &mut reqs);
        link.encode(reqs.as_slice(), ctx(1, 100));
        link.exchange(ctx(1, 100)).unwrap();
        let mut replies = Bounded::with_capacity(8);
        link.decode(&mut replies, ctx(1, 200));
        assert_eq!(replies.as_slice()[0].data, ReplyData::Value(0.75));

        // A request the hardware never sees (the exchange is skipped) expires as Missing.
        reqs.clear();
        replies.clear();
        dev.sample(0, ctx(2, 300), &mut reqs);
        link.encode(reqs.as_slice(), ctx(2, 300));
        link.decode(&mut replies, ctx(2, 5_000));
        assert!(matches!(
            replies.as_slice()[0].data,
            ReplyData::Missing { .. }
        ));
        let mut ups = Bounded::with_capacity(8);
        dev.reply(&replies.as_slice()[0], &mut ups);
        assert_eq!(ups.as_slice()[0].value, None, "stale, never invented");
        assert_eq!(link.counters().protocol.missing_replies, 1);
    }

    #[test]
    fn loopback_lag_follows_first_order() {
        let mut hw = LoopbackHardware::new(0.1, 1, 4);
        let c = Credential::id(1);
        let set = SimWord {
            cred: c,
            kind: SimKind::Set,
            value: 1.0,
            t_ns: 0,
        };
        hw.transmit(&[set], ctx(0, 0)).unwrap();
        let sample = SimWord {
            kind: SimKind::Sample,
            t_ns: 100_000_000,
            ..set
        };
        hw.transmit(&[sample], ctx(1, 0)).unwrap();
        let mut out = [SimWord::default(); 1];
        assert_eq!(hw.receive(&mut out, ctx(1, 0)).unwrap(), 1);
        // After one time constant: 1 − e⁻¹.
        assert!((out[0].value - (1.0 - (-1.0f64).exp())).abs() < 1e-12);
    }
}
