//! The one-way floor of the executor's own shape: a periodic raw iceoryx2 publisher and an
//! event-woken raw reader, each placed as the executor and the stress test's logger are.
//!
//! The ping-pong floors ([`crate::pingpong`]) send the next message as soon as the last is
//! acknowledged, with neither side at real-time priority and the CPUs' idle states left as
//! they are. The executor → logger path is not that shape: a SCHED_FIFO thread pinned to its CPU
//! wakes at each deadline of its rate, publishes a tick's samples and notifies one event; the
//! reader, kept off that CPU, sleeps on the event between ticks, and the CPUs are held out of
//! deep idle states (`/dev/cpu_dma_latency` at 0). This floor is that path with the Conductor
//! layer taken out: the same variant ([`RtIpc`]), payload and service settings
//! ([`qos::state_service`] with the stress test's buffer, [`qos::snapshot_service`],
//! [`qos::tick_event`]), the same number of states, and each way of reading:
//!
//! * per state: `states` services, one sample each per tick, the reader taking them one after
//!   another after one wake-up (the receive time read per sample, as the logger does);
//! * snapshot: one slice of `states` samples per tick, read at once (one receive time).
//!
//! The latency is receive time − the tick's wake-up time (the raw samples carry it as
//! `t_sample_ns`), measured over every tick after a half-second of warm-up ticks (counted by
//! tick, so a late tick moves no sample in or out of the measurement).

use std::ffi::OsString;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use conductor_bus::{monotonic_ns, qos, rt, Domain, RtIpc, StateSample};
use conductor_executor::schedule::sleep_until;
use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;

use crate::pingpong::{
    iox, node, parse_oneway, pin, print_oneway, raw_event, raw_state_service, service_name,
    spawn_child, PingPongError,
};
use crate::Percentiles;

/// The prefix of [`crate::pingpong::ROLE_ENV`] that makes a program this floor's reader:
/// `"periodic <domain> <states> <snapshot 0|1> <avoid cpu> <buffer> <warm-up ticks>"`.
pub const ROLE: &str = "periodic ";

/// The warm-up the reader leaves out (s), in ticks of the rate.
const WARM_UP_S: f64 = 0.5;

/// One floor run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Periodic {
    /// Ticks per second.
    pub rate_hz: f64,
    /// Samples per tick.
    pub states: usize,
    /// One slice per tick instead of one service per state.
    pub snapshot: bool,
    /// Measured seconds (after the warm-up).
    pub seconds: f64,
    /// The publisher's CPU (the executor's); the reader stays off it.
    pub cpu: usize,
    /// The publisher's SCHED_FIFO priority (the executor's).
    pub priority: i32,
    /// Each per-state subscriber's buffer (the stress test's history).
    pub buffer: usize,
}

type Slices =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<RtIpc, [StateSample], ()>;

fn snapshot_service(n: &Node<RtIpc>) -> Result<Slices, PingPongError> {
    qos::snapshot_service(
        n.service_builder(&service_name("bench/snapshot")?)
            .publish_subscribe::<[StateSample]>(),
    )
    .open_or_create()
    .map_err(|e| PingPongError::Iox(format!("snapshot service: {e}")))
}

fn state_name(i: usize) -> String {
    format!("bench/s{i}")
}

fn sample(seq: u64, t: u64) -> StateSample {
    StateSample {
        seq,
        tick: seq,
        t_sample_ns: t,
        t_publish_ns: t,
        value: 1.0,
        status: 0,
        reserved: 0,
    }
}

/// Runs the floor: the reader in `child_program` (run with the role set), the publisher on a
/// thread of this process at the executor's CPU and priority. Returns the reader's latencies.
/// Without root, the publisher runs at normal priority (the floor is then that of normal
/// scheduling, as the executor's would be).
pub fn measure(p: &Periodic, child_program: &[OsString]) -> Result<Percentiles, PingPongError> {
    let p = *p;
    let prog = child_program.to_vec();
    std::thread::spawn(move || publish(&p, &prog))
        .join()
        .unwrap_or_else(|_| {
            Err(PingPongError::Child(
                "the publishing thread panicked".into(),
            ))
        })
}

fn publish(p: &Periodic, child_program: &[OsString]) -> Result<Percentiles, PingPongError> {
    let d = Domain::unique("benchfloor")?;
    let n = node(&d)?;
    conductor_bus::prepare_thread();
    // Everything the reader opens exists before it starts.
    let mut per_state = Vec::new();
    let mut slices = None;
    if p.snapshot {
        let svc = snapshot_service(&n)?;
        let port = svc
            .publisher_builder()
            .initial_max_slice_len(p.states.max(1))
            .create()
            .map_err(|e| PingPongError::Iox(format!("snapshot publisher: {e}")))?;
        slices = Some((svc, port));
    } else {
        for i in 0..p.states {
            let svc = raw_state_service(&n, &state_name(i), p.buffer)?;
            let port = svc
                .publisher_builder()
                .create()
                .map_err(|e| PingPongError::Iox(format!("publisher: {e}")))?;
            per_state.push((svc, port));
        }
    }
    let ev = raw_event(&n)?;
    let notifier = ev
        .notifier_builder()
        .create()
        .map_err(|e| PingPongError::Iox(format!("notifier: {e}")))?;
    let warm_up = (WARM_UP_S * p.rate_hz).ceil() as u64;
    let measured = (p.seconds * p.rate_hz).ceil() as u64;
    let role = format!(
        "{ROLE}{} {} {} {} {} {warm_up}",
        d.name(),
        p.states,
        u8::from(p.snapshot),
        p.cpu,
        p.buffer
    );
    let (mut child, out) = spawn_child(child_program, &role)?;

    // The executor's set-up, each part optional as it is there.
    let _ = rt::hold_wakeup_latency(0);
    let _ = rt::pin_to_cpu(p.cpu);
    let _ = rt::set_fifo(p.priority);
    let period = (1e9 / p.rate_hz) as u64;
    let ticks = warm_up + measured;
    let never = AtomicBool::new(false);
    let mut deadline = monotonic_ns() + period;
    let send = |seq: u64, t: u64| -> Result<(), PingPongError> {
        if let Some((_, port)) = &slices {
            port.loan_slice_uninit(p.states)
                .map_err(|e| iox("loan")(e.to_string()))?
                .write_from_fn(|_| sample(seq, t))
                .send()
                .map_err(|e| iox("send")(e.to_string()))?;
        }
        for (_, port) in &per_state {
            port.loan_uninit()
                .map_err(|e| iox("loan")(e.to_string()))?
                .write_payload(sample(seq, t))
                .send()
                .map_err(|e| iox("send")(e.to_string()))?;
        }
        notifier
            .notify()
            .map_err(|e| iox("notify")(e.to_string()))?;
        Ok(())
    };
    let mut outcome = Ok(());
    for seq in 0..ticks {
        sleep_until(deadline, 0, &never);
        if let Err(e) = send(seq, monotonic_ns()) {
            outcome = Err(e);
            break;
        }
        deadline += period;
    }
    // The stop: a sample stamped 0. A reader that cannot be told to stop is killed.
    if let Err(e) = outcome.and_then(|()| send(u64::MAX, 0)) {
        let _ = child.kill();
        let _ = child.wait();
        return Err(e);
    }
    let line = out
        .recv_timeout(Duration::from_secs(20))
        .map_err(|_| PingPongError::Child("no summary line".into()));
    if line.is_err() {
        let _ = child.kill();
    }
    let _ = child.wait();
    parse_oneway(&line?)
}

/// The reader, in the child process: `args` is the role after [`ROLE`].
pub fn child(args: &str) -> Result<(), PingPongError> {
    let bad = || {
        PingPongError::Child(format!(
            "{ROLE}{args:?}: expected \"<domain> <states> <snapshot> <cpu> <buffer> <warm-up>\""
        ))
    };
    let f: Vec<&str> = args.split_whitespace().collect();
    let [domain, states, snapshot, cpu, buffer, warm_up] = f[..] else {
        return Err(bad());
    };
    let (Ok(states), Ok(cpu), Ok(buffer), Ok(warm_up)) = (
        states.parse::<usize>(),
        cpu.parse::<usize>(),
        buffer.parse::<usize>(),
        warm_up.parse::<u64>(),
    ) else {
        return Err(bad());
    };
    if rt::avoid_cpu(cpu).is_err() {
        pin(usize::from(cpu == 0));
    }
    let d = Domain::new(domain)?;
    let n = node(&d)?;
    let ev = raw_event(&n)?;
    let listener: Listener<RtIpc> = ev
        .listener_builder()
        .create()
        .map_err(|e| PingPongError::Iox(format!("listener: {e}")))?;
    let mut lat = Vec::with_capacity(1 << 22);
    // Records one sample read at `now` (its `seq` is the tick); false at the stop.
    let mut record = |s: &StateSample, now: u64| -> bool {
        if s.t_sample_ns == 0 {
            return false;
        }
        if s.seq >= warm_up {
            lat.push(now.saturating_sub(s.t_sample_ns));
        }
        true
    };
    let wait = |what| {
        listener
            .blocking_wait(|_| {})
            .map(drop)
            .map_err(|e| iox(what)(e.to_string()))
    };
    if snapshot == "1" {
        let sub = snapshot_service(&n)?
            .subscriber_builder()
            .buffer_size(2)
            .create()
            .map_err(|e| PingPongError::Iox(format!("snapshot subscriber: {e}")))?;
        println!("READY");
        'snap: loop {
            wait("waiting")?;
            while let Some(s) = sub.receive().map_err(|e| iox("receive")(e.to_string()))? {
                let now = monotonic_ns();
                for x in s.payload() {
                    if !record(x, now) {
                        break 'snap;
                    }
                }
            }
        }
    } else {
        let subs = (0..states)
            .map(|i| {
                raw_state_service(&n, &state_name(i), buffer)?
                    .subscriber_builder()
                    .buffer_size(buffer)
                    .create()
                    .map_err(|e| PingPongError::Iox(format!("subscriber: {e}")))
            })
            .collect::<Result<Vec<_>, _>>()?;
        println!("READY");
        // The stop reaches the first state's queue before the last tick's other states are
        // read: finish the pass over every state, then stop.
        let mut stopped = false;
        while !stopped {
            wait("waiting")?;
            for sub in &subs {
                while let Some(s) = sub.receive().map_err(|e| iox("receive")(e.to_string()))? {
                    stopped |= !record(&s, monotonic_ns());
                }
            }
        }
    }
    print_oneway(&mut lat)
}
