//! One-way latency between two processes over the Conductor bus and over raw iceoryx2 (the IPC
//! floor), shared by the `bus_latency` criterion bench and `conductor bench`.
//!
//! The parent ([`PingPong`]) sends; a child process receives on another CPU, stamps
//! `CLOCK_MONOTONIC` on receipt and subtracts the sender's stamp (same clock in both processes):
//! a true one-way figure. It then acks on a raw channel so only one message is in flight. The
//! child is whatever program the caller names, run with [`ROLE_ENV`] set; that program calls
//! [`child_from_env`] first thing in `main`.
//!
//! Four paths ([`Mode`]):
//! * `raw-busy`    raw iceoryx2 pub/sub, busy-polling subscriber (the IPC floor);
//! * `state-busy`  `StatePublisher` → `StateSubscriber`, busy-polling;
//! * `raw-event`   raw pub/sub + event, the subscriber sleeping in `Listener::blocking_wait`
//!   (the floor of every event-woken path);
//! * `state-event` `StatePublisher` + tick event → `TickWaiter`.
//!
//! The raw floors are the states' own configuration without the Conductor layer: the same
//! service variant ([`RtIpc`]), the same payload ([`StateSample`], 48 bytes, loaned, written in
//! place and sent), the same service settings ([`qos::state_service`] with the same subscriber
//! buffer, [`qos::tick_event`]) and the same polling or event wake-up. So a Conductor path can
//! only add to its floor; a ratio below 1 beyond noise is a bug in the floor.
//!
//! Both sides poll in normal scheduling: the busy modes spin one CPU each for the run's length.

use std::ffi::OsString;
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

use conductor_bus::{
    monotonic_ns, qos, Bus, BusError, Domain, RtIpc, StateMeta, StatePublisher, StateSample,
    StateSpec, StateSubscriber, TickWaiter,
};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

use crate::Percentiles;

/// The environment variable that makes a program the receiving child: `"<mode> <domain>"`.
pub const ROLE_ENV: &str = "CONDUCTOR_BENCH_ROLE";

const STOP: u64 = u64::MAX;

/// The per-subscriber queue of the measured state (raw and Conductor alike).
const BUFFER: usize = 4;

type RawService =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<RtIpc, StateSample, ()>;

/// A measured path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Raw iceoryx2 pub/sub, busy-polling: the IPC floor.
    RawBusy,
    /// Conductor state pub/sub, busy-polling.
    StateBusy,
    /// Raw iceoryx2 pub/sub woken by an event: the event-woken floor.
    RawEvent,
    /// Conductor state pub/sub woken by the tick event.
    StateEvent,
}

impl Mode {
    /// Every mode, floors first within each pair.
    pub const ALL: [Mode; 4] = [
        Mode::RawBusy,
        Mode::StateBusy,
        Mode::RawEvent,
        Mode::StateEvent,
    ];

    /// The mode's name (`raw-busy`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Mode::RawBusy => "raw-busy",
            Mode::StateBusy => "state-busy",
            Mode::RawEvent => "raw-event",
            Mode::StateEvent => "state-event",
        }
    }

    /// Parses a name of [`Mode::name`].
    pub fn parse(s: &str) -> Option<Mode> {
        Mode::ALL.into_iter().find(|m| m.name() == s)
    }

    /// The raw path this mode is compared with.
    pub fn floor(self) -> Mode {
        match self {
            Mode::RawBusy | Mode::StateBusy => Mode::RawBusy,
            Mode::RawEvent | Mode::StateEvent => Mode::RawEvent,
        }
    }

    fn raw(self) -> bool {
        matches!(self, Mode::RawBusy | Mode::RawEvent)
    }

    fn event(self) -> bool {
        matches!(self, Mode::RawEvent | Mode::StateEvent)
    }
}

/// Why a ping-pong failed.
#[derive(Debug, thiserror::Error)]
pub enum PingPongError {
    /// The Conductor bus refused.
    #[error("bus: {0}")]
    Bus(#[from] BusError),
    /// iceoryx2 refused.
    #[error("iceoryx2: {0}")]
    Iox(String),
    /// The child process misbehaved.
    #[error("the receiving process: {0}")]
    Child(String),
}

pub(crate) fn iox(what: &str) -> impl FnOnce(String) -> PingPongError + '_ {
    move |e| PingPongError::Iox(format!("{what}: {e}"))
}

/// Pins the calling thread to `cpu` (falling back to CPU 0). The id is set directly: a child
/// inherits its parent's affinity mask, so `get_core_ids()` there would only list the parent's
/// CPU. On a single-CPU machine both sides share CPU 0.
pub fn pin(cpu: usize) {
    if !core_affinity::set_for_current(core_affinity::CoreId { id: cpu }) {
        core_affinity::set_for_current(core_affinity::CoreId { id: 0 });
    }
}

pub(crate) fn node(d: &Domain) -> Result<Node<RtIpc>, PingPongError> {
    NodeBuilder::new()
        .config(d.iceoryx2_config())
        .create::<RtIpc>()
        .map_err(|e| PingPongError::Iox(format!("node: {e}")))
}

pub(crate) fn service_name(name: &str) -> Result<ServiceName, PingPongError> {
    name.try_into()
        .map_err(|e| PingPongError::Iox(format!("service name {name:?}: {e:?}")))
}

/// The ack channel back to the sender (the same for every mode, not measured).
fn ack_service(
    n: &Node<RtIpc>,
) -> Result<
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<RtIpc, u64, ()>,
    PingPongError,
> {
    n.service_builder(&service_name("bench/ack")?)
        .publish_subscribe::<u64>()
        .subscriber_max_buffer_size(BUFFER)
        .open_or_create()
        .map_err(|e| PingPongError::Iox(format!("ack service: {e}")))
}

/// The raw state service: a state's payload and settings (subscriber queues of up to
/// `buffer`), no Conductor attributes.
pub fn raw_state_service(
    n: &Node<RtIpc>,
    name: &str,
    buffer: usize,
) -> Result<RawService, PingPongError> {
    qos::state_service(
        n.service_builder(&service_name(name)?)
            .publish_subscribe::<StateSample>(),
        buffer,
    )
    .open_or_create()
    .map_err(|e| PingPongError::Iox(format!("service {name:?}: {e}")))
}

/// The raw tick event: a tick event's settings, no Conductor attributes.
pub(crate) fn raw_event(
    n: &Node<RtIpc>,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<RtIpc>, PingPongError> {
    qos::tick_event(n.service_builder(&service_name("bench/ev")?).event())
        .open_or_create()
        .map_err(|e| PingPongError::Iox(format!("event service: {e}")))
}

/// A raw publish of one state sample, as the floor does it: loan, write in place (stamped
/// `t_publish_ns`), send.
#[inline]
pub fn raw_publish(
    port: &Publisher<RtIpc, StateSample, ()>,
    seq: u64,
    value: f64,
    t_publish_ns: u64,
) -> Result<usize, PingPongError> {
    let sample = port.loan_uninit().map_err(|e| iox("loan")(e.to_string()))?;
    let sample = sample.write_payload(StateSample {
        seq,
        tick: seq,
        t_sample_ns: t_publish_ns,
        t_publish_ns,
        value,
        status: 0,
        reserved: 0,
    });
    sample.send().map_err(|e| iox("send")(e.to_string()))
}

/// Runs the child side if [`ROLE_ENV`] is set: returns `None` when it is not (carry on as the
/// parent), else the child's outcome (the caller then exits).
pub fn child_from_env() -> Option<Result<(), PingPongError>> {
    let role = std::env::var(ROLE_ENV).ok()?;
    if let Some(args) = role.strip_prefix(crate::periodic::ROLE) {
        return Some(crate::periodic::child(args));
    }
    let Some((mode, domain)) = role.split_once(' ') else {
        return Some(Err(PingPongError::Child(format!(
            "{ROLE_ENV}={role:?}: expected \"<mode> <domain>\""
        ))));
    };
    let Some(mode) = Mode::parse(mode) else {
        return Some(Err(PingPongError::Child(format!("unknown mode {mode:?}"))));
    };
    Some(child(mode, domain))
}

/// The receiving side, run in the child process: prints `READY`, records one-way latencies
/// until the stop message, then prints `ONEWAY <count> <min> <p50> <p99> <p99.9> <max>` (ns).
pub fn child(mode: Mode, domain: &str) -> Result<(), PingPongError> {
    pin(1);
    let d = Domain::new(domain)?;
    let n = node(&d)?;
    let ack = ack_service(&n)?
        .publisher_builder()
        .create()
        .map_err(|e| PingPongError::Iox(format!("ack publisher: {e}")))?;
    let mut lat = Vec::with_capacity(1 << 20);
    let mut record = |stamp: u64| -> Result<bool, PingPongError> {
        let now = monotonic_ns();
        if stamp == STOP {
            return Ok(false);
        }
        lat.push(now.saturating_sub(stamp));
        ack.send_copy(stamp)
            .map_err(|e| PingPongError::Iox(format!("ack: {e}")))?;
        Ok(true)
    };
    if mode.raw() {
        let sub = raw_state_service(&n, "bench/ping", BUFFER)?
            .subscriber_builder()
            .buffer_size(BUFFER)
            .create()
            .map_err(|e| PingPongError::Iox(format!("subscriber: {e}")))?;
        let ev = raw_event(&n)?;
        let listener: Listener<RtIpc> = ev
            .listener_builder()
            .create()
            .map_err(|e| PingPongError::Iox(format!("listener: {e}")))?;
        println!("READY");
        'outer: loop {
            if mode.event() {
                listener
                    .blocking_wait(|_| {})
                    .map_err(|e| iox("waiting")(e.to_string()))?;
            }
            while let Some(s) = sub.receive().map_err(|e| iox("receive")(e.to_string()))? {
                if !record(if s.value < 0.0 { STOP } else { s.t_publish_ns })? {
                    break 'outer;
                }
            }
        }
    } else {
        let bus = Bus::open(&d, "bench-child")?;
        let mut sub = StateSubscriber::with_buffer(&bus, "bench/q", BUFFER)?;
        let mut tick = TickWaiter::new(&bus, "bench")?;
        println!("READY");
        'outer2: loop {
            if mode.event() {
                tick.wait(Duration::from_secs(10))?;
            }
            while let Some(s) = sub.receive()? {
                if !record(if s.value < 0.0 { STOP } else { s.t_publish_ns })? {
                    break 'outer2;
                }
            }
        }
    }
    print_oneway(&mut lat)
}

/// The sending side of one mode, in the parent process.
pub struct PingPong {
    mode: Mode,
    raw: Publisher<RtIpc, StateSample, ()>,
    notifier: Notifier<RtIpc>,
    state: StatePublisher,
    ack: Subscriber<RtIpc, u64, ()>,
    child: Child,
    out: Receiver<String>,
    seq: u64,
    // Dropped last: the ports above live in this node's services.
    _raw: RawService,
    _event: iceoryx2::service::port_factory::event::PortFactory<RtIpc>,
    _node: Node<RtIpc>,
}

impl core::fmt::Debug for PingPong {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("PingPong")
            .field("mode", &self.mode.name())
            .finish()
    }
}

impl PingPong {
    /// Starts the child (`child_program[0]` with the remaining arguments and [`ROLE_ENV`] set)
    /// in a fresh domain, waits for it and warms the path up with 1000 round trips.
    pub fn start(mode: Mode, child_program: &[OsString]) -> Result<PingPong, PingPongError> {
        let d = Domain::unique("benchlat")?;
        let n = node(&d)?;
        // Everything the child opens exists before it starts.
        conductor_bus::prepare_thread();
        let raw_svc = raw_state_service(&n, "bench/ping", BUFFER)?;
        let raw = raw_svc
            .publisher_builder()
            .create()
            .map_err(|e| PingPongError::Iox(format!("publisher: {e}")))?;
        let ev = raw_event(&n)?;
        let notifier = ev
            .notifier_builder()
            .create()
            .map_err(|e| PingPongError::Iox(format!("notifier: {e}")))?;
        let ack = ack_service(&n)?
            .subscriber_builder()
            .create()
            .map_err(|e| PingPongError::Iox(format!("ack subscriber: {e}")))?;
        let bus = Bus::open(&d, "bench-parent")?;
        let state = StatePublisher::create(
            &bus,
            "bench",
            &[StateSpec {
                buffer: BUFFER,
                ..StateSpec::new("q", StateMeta::default())
            }],
        )?;
        let (child, out) = spawn_child(child_program, &format!("{} {}", mode.name(), d.name()))?;
        let mut s = PingPong {
            mode,
            raw,
            notifier,
            state,
            ack,
            child,
            out,
            seq: 0,
            _raw: raw_svc,
            _event: ev,
            _node: n,
        };
        for _ in 0..1000 {
            s.round_trip()?;
        }
        Ok(s)
    }

    /// The mode measured.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    fn send(&mut self, stop: bool) -> Result<(), PingPongError> {
        self.seq += 1;
        if self.mode.raw() {
            let v = if stop { -1.0 } else { 1.0 };
            raw_publish(&self.raw, self.seq, v, monotonic_ns())?;
            if self.mode.event() {
                self.notifier
                    .notify()
                    .map_err(|e| iox("notify")(e.to_string()))?;
            }
        } else {
            let v = if stop { -1.0 } else { 1.0 };
            self.state.publish(0, self.seq, monotonic_ns(), v, 0)?;
            if self.mode.event() {
                self.state.notify_tick()?;
            }
        }
        Ok(())
    }

    /// One message there and its ack back (busy-waiting for the ack).
    pub fn round_trip(&mut self) -> Result<(), PingPongError> {
        self.send(false)?;
        let deadline = Instant::now() + Duration::from_secs(5);
        while self
            .ack
            .receive()
            .map_err(|e| iox("ack")(e.to_string()))?
            .is_none()
        {
            if Instant::now() > deadline {
                return Err(PingPongError::Child(format!(
                    "{}: no ack within 5 s",
                    self.mode.name()
                )));
            }
            std::hint::spin_loop();
        }
        Ok(())
    }

    /// Stops the child and returns its one-way latencies (`mean` is not reported: NaN).
    pub fn finish(mut self) -> Result<Percentiles, PingPongError> {
        self.send(true)?;
        let line = self
            .out
            .recv_timeout(Duration::from_secs(20))
            .map_err(|_| PingPongError::Child("no summary line".into()))?;
        let _ = self.child.wait();
        parse_oneway(&line)
    }
}

/// Starts `child_program` (program, then arguments) with [`ROLE_ENV`] = `role`, and waits for
/// its `READY` line; returns it with the rest of its standard output, line by line.
pub(crate) fn spawn_child(
    child_program: &[OsString],
    role: &str,
) -> Result<(Child, Receiver<String>), PingPongError> {
    let (prog, args) = child_program
        .split_first()
        .ok_or_else(|| PingPongError::Child("no child program given".into()))?;
    let mut child = Command::new(prog)
        .args(args)
        .env(ROLE_ENV, role)
        .stdout(Stdio::piped())
        .spawn()
        .map_err(|e| PingPongError::Child(format!("starting {prog:?}: {e}")))?;
    let (tx, out) = std::sync::mpsc::channel();
    let stdout = child
        .stdout
        .take()
        .ok_or_else(|| PingPongError::Child("no stdout".into()))?;
    std::thread::spawn(move || {
        for l in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(l);
        }
    });
    match out.recv_timeout(Duration::from_secs(20)) {
        Ok(l) if l == "READY" => Ok((child, out)),
        other => {
            let _ = child.kill();
            let _ = child.wait();
            Err(PingPongError::Child(format!(
                "expected READY, got {other:?}"
            )))
        }
    }
}

/// Prints the child's summary line, `ONEWAY <count> <min> <p50> <p99> <p99.9> <max>` (ns).
pub(crate) fn print_oneway(lat: &mut [u64]) -> Result<(), PingPongError> {
    let p = Percentiles::from_samples(lat)
        .ok_or_else(|| PingPongError::Child("no samples before the stop message".into()))?;
    println!(
        "ONEWAY {} {} {} {} {} {}",
        p.count, p.min, p.p50, p.p99, p.p999, p.max
    );
    Ok(())
}

/// Reads a child's summary line back (`mean` is not reported: NaN).
pub(crate) fn parse_oneway(line: &str) -> Result<Percentiles, PingPongError> {
    let f: Vec<u64> = line
        .strip_prefix("ONEWAY ")
        .map(|r| {
            r.split_whitespace()
                .filter_map(|x| x.parse().ok())
                .collect()
        })
        .unwrap_or_default();
    if f.len() != 6 {
        return Err(PingPongError::Child(format!("bad summary line {line:?}")));
    }
    Ok(Percentiles {
        count: f[0] as usize,
        min: f[1],
        p50: f[2],
        p99: f[3],
        p999: f[4],
        max: f[5],
        mean: f64::NAN,
    })
}

/// Measures `samples` round trips of `mode` (after the warm-up) from a thread pinned to CPU 0,
/// the child on CPU 1; the caller's own thread keeps its CPU set.
pub fn measure(
    mode: Mode,
    samples: usize,
    child_program: &[OsString],
) -> Result<Percentiles, PingPongError> {
    let prog = child_program.to_vec();
    std::thread::spawn(move || {
        pin(0);
        let mut p = PingPong::start(mode, &prog)?;
        for _ in 0..samples {
            p.round_trip()?;
        }
        p.finish()
    })
    .join()
    .unwrap_or_else(|_| Err(PingPongError::Child("the sending thread panicked".into())))
}
