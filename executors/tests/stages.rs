//! The stage scheduler in-process, tick by tick, on the built-in simulated hardware: divisors,
//! caching and bundling, credential matching, stale values, setpoint checks, the watchdog.
//! Time is synthetic (tick k happens at k ms), so every expectation is exact.

use std::cell::RefCell;
use std::rc::Rc;

use conductor_bus::{status, Setpoint};
use conductor_devices::kinds::{build_device, build_link, Capacity};
use conductor_devices::{
    Bounded, Credential, HwError, Link, LinkCounters, LinkState, Op, Reply, ReplyData, Request,
    TickCtx,
};
use conductor_executor::stages::{Publish, Stages};
use conductor_manifest::{Manifest, Subsystem};

const MS: u64 = 1_000_000;

/// Every encode call a link received: (tick, requests).
type Log = Rc<RefCell<Vec<(u64, Vec<Request>)>>>;

/// A real link that also records what the protocol stage was handed, and can inject replies.
struct Recorder {
    inner: Box<dyn Link>,
    log: Log,
    inject: Rc<RefCell<Vec<Reply>>>,
}

impl Link for Recorder {
    fn receive(&mut self, ctx: TickCtx) {
        self.inner.receive(ctx);
    }
    fn encode(&mut self, requests: &[Request], ctx: TickCtx) {
        self.log.borrow_mut().push((ctx.tick, requests.to_vec()));
        self.inner.encode(requests, ctx);
    }
    fn exchange(&mut self, ctx: TickCtx) -> Result<(), HwError> {
        self.inner.exchange(ctx)
    }
    fn decode(&mut self, out: &mut Bounded<Reply>, ctx: TickCtx) {
        self.inner.decode(out, ctx);
        for r in self.inject.borrow_mut().drain(..) {
            out.push(r).unwrap();
        }
    }
    fn counters(&self) -> LinkCounters {
        self.inner.counters()
    }
    fn preempt(&mut self) {
        self.inner.preempt();
    }
    fn flushed(&self) -> bool {
        self.inner.flushed()
    }
    fn state(&self) -> LinkState {
        self.inner.state()
    }
    fn shutdown(&mut self) {
        self.inner.shutdown();
    }
}

struct Rig {
    sub: Subsystem,
    stages: Stages,
    logs: Vec<Log>,
    inject: Vec<Rc<RefCell<Vec<Reply>>>>,
    tick: u64,
}

impl Rig {
    fn new(manifest: &str) -> Rig {
        let m = Manifest::parse(manifest, "test.toml").unwrap_or_else(|e| panic!("{e}"));
        let sub = m.subsystems[0].clone();
        let mut links: Vec<Box<dyn Link>> = Vec::new();
        let mut logs = Vec::new();
        let mut inject = Vec::new();
        for p in &sub.protocols {
            let hw = &sub.hardware[p.hardware];
            let cap = Capacity {
                words: 256,
                in_flight: 64,
                devices: 16,
            };
            let inner = build_link(&p.kind, &p.params, &hw.kind, &hw.params, cap).unwrap();
            let log: Log = Rc::default();
            let inj: Rc<RefCell<Vec<Reply>>> = Rc::default();
            logs.push(log.clone());
            inject.push(inj.clone());
            links.push(Box::new(Recorder {
                inner,
                log,
                inject: inj,
            }));
        }
        let devices = sub
            .devices
            .iter()
            .map(|d| build_device(&d.kind, &d.params, d.credential).unwrap())
            .collect();
        let stages = Stages::from_parts(&sub, links, devices);
        Rig {
            sub,
            stages,
            logs,
            inject,
            tick: 0,
        }
    }

    /// Runs one tick at t = tick ms and returns what was published.
    fn step(&mut self) -> Vec<Publish> {
        let mut out = Vec::new();
        let t = self.tick * MS;
        self.stages.tick(self.tick, t, t, |p| out.push(*p));
        self.tick += 1;
        out
    }

    fn frame(&mut self, setpoints: &[(u32, f64)]) {
        let sps: Vec<Setpoint> = setpoints
            .iter()
            .map(|&(index, value)| Setpoint {
                index,
                flags: 0,
                value,
            })
            .collect();
        self.stages.apply_frame(&sps, self.tick * MS);
    }

    fn index(&self, state: &str) -> usize {
        self.sub
            .states
            .iter()
            .position(|s| s.name == state)
            .unwrap()
    }
}

const HEADER: &str = r#"
system = "t"
[subsystems.s]
rate_hz = 1000
"#;

fn joints(n: usize, extra_sub: &str, device_extra: &str, state_extra: &str) -> String {
    let mut s = format!(
        "{HEADER}{extra_sub}\n[subsystems.s.hardware.bus]\nkind = \"loopback\"\n\
         [subsystems.s.protocols.p]\nkind = \"sim\"\nhardware = \"bus\"\n"
    );
    for i in 0..n {
        s += &format!(
            "[subsystems.s.devices.d{i}]\nkind = \"sim\"\nprotocol = \"p\"\nid = {}\n{device_extra}\n",
            i + 1
        );
    }
    for i in 0..n {
        s += &format!(
            "[subsystems.s.states.q{i}]\ndevice = \"d{i}\"\nwritable = true\nmin = -1.0\nmax = 1.0\n{state_extra}\n"
        );
    }
    s
}

#[test]
fn stages_tick_at_their_divisors_and_the_protocol_gets_each_batch_in_one_call() {
    // States at 500 Hz (every 2 ticks), devices at 250 Hz (every 4), protocol at 125 Hz (every 8).
    let text = r#"
system = "t"
[subsystems.s]
rate_hz = 1000
[subsystems.s.hardware.bus]
kind = "loopback"
[subsystems.s.protocols.p]
kind = "sim"
hardware = "bus"
rate_hz = 125
[subsystems.s.devices.a]
kind = "sim"
protocol = "p"
id = 1
rate_hz = 250
[subsystems.s.devices.b]
kind = "sim"
protocol = "p"
id = 2
rate_hz = 250
[subsystems.s.states.qa]
device = "a"
rate_hz = 500
[subsystems.s.states.qb]
device = "b"
rate_hz = 500
"#;
    let mut rig = Rig::new(text);
    let mut published_at = Vec::new();
    for _ in 0..17 {
        let t = rig.tick;
        if !rig.step().is_empty() {
            published_at.push(t);
        }
    }
    // The protocol ticked at 0, 8, 16 only, each time with everything queued since its last tick:
    // tick 0: both devices' samples of tick 0; tick 8: those of ticks 4 and 8 (the device ticks
    // in between), and so on. The state requests of ticks 2 and 6 were coalesced into the
    // device ticks 4 and 8 (a device samples a channel at most once per tick).
    let log = rig.logs[0].borrow();
    let calls: Vec<(u64, usize)> = log.iter().map(|(t, r)| (*t, r.len())).collect();
    assert_eq!(calls, [(0, 2), (8, 4), (16, 4)]);
    let ticks_in_8: Vec<u64> = log[1].1.iter().map(|r| r.tick).collect();
    assert_eq!(ticks_in_8, [4, 4, 8, 8]);
    assert!(log[1].1.iter().all(|r| r.op == Op::Sample));
    // Replies come back on protocol ticks and reach the states on the next device tick; the
    // states publish every 2 ticks once they have a value.
    assert_eq!(published_at, [0, 2, 4, 6, 8, 10, 12, 14, 16]);
}

#[test]
fn a_frame_is_applied_in_one_tick_and_reads_back_on_the_next_bus_cycle() {
    let mut rig = Rig::new(&joints(6, "", "", ""));
    rig.step();
    rig.frame(&[(0, 0.1), (1, 0.2), (2, 0.3), (3, 0.4), (4, 0.5), (5, 0.6)]);
    let apply_tick = rig.tick;
    rig.step();
    // All six writes were handed to the protocol in the same encode call (one bundle).
    let log = rig.logs[0].borrow();
    let (t, reqs) = log.last().unwrap();
    assert_eq!(*t, apply_tick);
    let sets: Vec<(u32, f64)> = reqs
        .iter()
        .filter_map(|r| match r.op {
            Op::Set { value } => Some((r.cred.id, value)),
            _ => None,
        })
        .collect();
    assert_eq!(
        sets,
        [(1, 0.1), (2, 0.2), (3, 0.3), (4, 0.4), (5, 0.5), (6, 0.6)]
    );
    drop(log);
    // The samples that reflect it: all six share one tick and one sample time.
    let out = rig.step();
    assert_eq!(out.len(), 6);
    let values: Vec<f64> = out.iter().map(|p| p.value).collect();
    assert_eq!(values, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]);
    assert!(out.iter().all(|p| p.tick == apply_tick + 1));
    assert!(out.iter().all(|p| p.t_sample_ns == out[0].t_sample_ns));
    assert!(out.iter().all(|p| p.status == status::SIMULATED));
}

#[test]
fn setpoints_are_clamped_rejected_and_counted() {
    let text = format!(
        "{}\n[subsystems.s.devices.sensor]\nkind = \"sim\"\nprotocol = \"p\"\nid = 9\n\
         [subsystems.s.states.ro]\ndevice = \"sensor\"\n",
        joints(3, "", "", "")
    );
    let mut rig = Rig::new(&text);
    let ro = rig.index("ro") as u32;
    rig.step();
    rig.frame(&[
        (0, 5.0),           // clamped to 1.0
        (1, f64::NAN),      // rejected
        (2, f64::INFINITY), // rejected
        (ro, 0.5),          // read-only: rejected
        (99, 0.5),          // no such state: rejected
    ]);
    rig.step();
    let out = rig.step();
    let by = |i: usize| out.iter().find(|p| p.index == i).unwrap();
    assert_eq!(by(0).value, 1.0);
    assert_ne!(by(0).status & status::CLAMPED, 0);
    assert_eq!(
        by(1).value,
        0.0,
        "the rejected NaN never reached the device"
    );
    assert_ne!(by(1).status & status::REJECTED, 0);
    assert_ne!(by(2).status & status::REJECTED, 0);
    assert_ne!(by(ro as usize).status & status::REJECTED, 0);
    let c = rig.stages.counters();
    assert_eq!((c.frames, c.clamped, c.rejected), (1, 1, 4));
    // An accepted in-range setpoint clears both flags.
    rig.frame(&[(0, 0.5), (1, -0.5)]);
    rig.step();
    let out = rig.step();
    let flags = out[0].status | out[1].status;
    assert_eq!(flags & (status::CLAMPED | status::REJECTED), 0);
    assert_eq!((out[0].value, out[1].value), (0.5, -0.5));
}

#[test]
fn calibration_is_applied_both_ways() {
    // state = -2 · (device − 0.5)
    let mut rig = Rig::new(&joints(
        1,
        "",
        "offset = 0.5\nscale = 2.0\ndirection = -1",
        "",
    ));
    let out = rig.step();
    // The loopback starts at device 0 → state −2·(0 − 0.5) = 1.
    assert_eq!(out[0].value, 1.0);
    rig.frame(&[(0, -0.5)]);
    rig.step();
    let log = rig.logs[0].borrow();
    let set = log
        .iter()
        .flat_map(|(_, r)| r.iter())
        .find_map(|r| match r.op {
            Op::Set { value } => Some(value),
            _ => None,
        })
        .unwrap();
    // device = state / (−2) + 0.5 = 0.75
    assert_eq!(set, 0.75);
    drop(log);
    assert_eq!(rig.step()[0].value, -0.5);
}

#[test]
fn replies_reach_devices_by_credential_and_strangers_are_counted() {
    let mut rig = Rig::new(&joints(2, "", "", ""));
    rig.step();
    // A reply from id 7 (no such device) and one for device 2 (index 1) with a value.
    rig.inject[0].borrow_mut().extend([
        Reply::answer(Credential::id(7), Op::Sample, ReplyData::Value(3.0), 1, MS),
        Reply::answer(
            Credential::id(2),
            Op::Sample,
            ReplyData::Value(0.25),
            1,
            MS + 123,
        ),
    ]);
    let out = rig.step();
    assert_eq!(rig.stages.counters().unmatched_replies, 1);
    // Device 2's injected reply arrived after its real one of this tick, sampled later: it is
    // the newest.
    let q1 = out.iter().find(|p| p.index == 1).unwrap();
    assert_eq!((q1.value, q1.t_sample_ns), (0.25, MS + 123));
    let q0 = out.iter().find(|p| p.index == 0).unwrap();
    assert_eq!(q0.value, 0.0);
    assert_eq!(rig.stages.bus_errors(), 1);
}

/// A reply that comes after a newer one (an earlier round's, held up on its way) is not
/// published over it, value or staleness: a state's sample time never goes backwards.
#[test]
fn an_older_reading_never_replaces_a_newer_one() {
    let mut rig = Rig::new(&joints(1, "", "", ""));
    rig.step();
    let newer = rig.step();
    let t_new = newer[0].t_sample_ns;
    assert!(t_new > 0);
    rig.inject[0].borrow_mut().extend([
        Reply::answer(
            Credential::id(1),
            Op::Sample,
            ReplyData::Value(0.75),
            0,
            t_new - 1,
        ),
        Reply::missing(Credential::id(1), Op::Sample, 0, t_new - 1),
    ]);
    let out = rig.step();
    assert!(out[0].t_sample_ns >= t_new, "{:?}", out[0]);
    assert_ne!(out[0].value, 0.75, "the older reading is not published");
    assert_eq!(out[0].status & status::STALE, 0, "nor its missing twin");
}

#[test]
fn a_missing_reply_marks_the_state_stale_and_keeps_the_last_value() {
    // The hardware ticks only every 100 ms; requests expire after 1 ms.
    let text = r#"
system = "t"
[subsystems.s]
rate_hz = 1000
[subsystems.s.hardware.bus]
kind = "sine"
rate_hz = 10
[subsystems.s.protocols.p]
kind = "sim"
hardware = "bus"
timeout_us = 1000
[subsystems.s.devices.d]
kind = "sim"
protocol = "p"
id = 0
[subsystems.s.states.x]
device = "d"
"#;
    let mut rig = Rig::new(text);
    let first = rig.step();
    assert_eq!(first[0].status & status::STALE, 0);
    assert_eq!(first[0].value, 0.0, "sin(0)");
    let t0 = first[0].t_sample_ns;
    rig.step(); // tick 1: request goes out, the hardware does not tick
    let out = rig.step(); // tick 2: the request of tick 1 expired
    assert_ne!(out[0].status & status::STALE, 0);
    assert_eq!(
        out[0].t_sample_ns, t0,
        "the last good sample, never an invented one"
    );
    assert_eq!(rig.stages.stale_states(), 1);
    assert!(rig.stages.bus_errors() >= 1);
}

#[test]
fn watchdog_sends_the_safe_action_within_timeout_plus_one_tick() {
    // Watchdog 10 ms at 1 kHz; safe action: setpoint −0.5 (state units).
    let mut rig = Rig::new(&joints(
        2,
        "watchdog_ms = 10",
        "safe_action = \"setpoint\"\nsafe_value = -0.5",
        "",
    ));
    rig.step();
    // Never armed before the first frame: no trip however long we wait.
    for _ in 0..30 {
        rig.step();
    }
    assert!(!rig.stages.watchdog_tripped());
    let h = rig.stages.health();
    assert_eq!(
        (h.devices, h.enabled, h.tripped),
        (2, 2, 0),
        "simulated devices drive"
    );
    rig.frame(&[(0, 0.5), (1, 0.5)]);
    let applied = rig.tick;
    let mut tripped_at = None;
    for _ in 0..20 {
        let t = rig.tick;
        let out = rig.step();
        if tripped_at.is_none() && out.iter().all(|p| p.status & status::WATCHDOG != 0) {
            tripped_at = Some(t);
            // The safe setpoint was sent on the trip tick itself, before that tick's samples.
            assert!(out.iter().all(|p| p.value == -0.5), "{out:?}");
        }
    }
    let tripped_at = tripped_at.expect("watchdog fired");
    assert_eq!(tripped_at - applied, 10, "timeout 10 ms = 10 ticks");
    assert_eq!(
        rig.stages.counters().watchdog_trips,
        1,
        "fires once per silence"
    );
    // A new frame clears the flag and is obeyed.
    rig.frame(&[(0, 0.25)]);
    rig.step();
    let out = rig.step();
    assert!(out.iter().all(|p| p.status & status::WATCHDOG == 0));
    assert_eq!(out[0].value, 0.25);
}

#[test]
fn shutdown_puts_writable_devices_in_their_safe_state() {
    let mut rig = Rig::new(&joints(1, "", "safe_action = \"torque_off\"", ""));
    rig.frame(&[(0, 0.7)]);
    rig.step();
    rig.step();
    let ctx = TickCtx {
        tick: rig.tick,
        now_ns: rig.tick * MS,
    };
    rig.stages.begin_shutdown(ctx);
    rig.stages.stop_tick(ctx);
    let log = rig.logs[0].borrow();
    let (_, last) = log.last().unwrap();
    // The sim device's torque-off is a setpoint of 0.
    assert!(
        last.iter().any(|r| r.op == Op::Set { value: 0.0 }),
        "{last:?}"
    );
}
