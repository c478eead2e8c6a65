//! One-way latency of the Conductor bus between two processes, against raw iceoryx2 measured in
//! the same run as the floor.
//!
//! Four paths, each a parent process sending and a child process (this binary re-executed)
//! receiving on another CPU:
//! * `raw-busy`    raw iceoryx2 `u64` pub/sub, busy-polling subscriber (the IPC floor);
//! * `state-busy`  `StatePublisher` → `StateSubscriber`, busy-polling;
//! * `raw-event`   raw `u64` pub/sub + event, the subscriber sleeping in `Listener::blocking_wait`;
//! * `state-event` `StatePublisher` + tick event → `TickWaiter`.
//!
//! The child stamps `CLOCK_MONOTONIC` on receipt and subtracts the sender's stamp (same clock in
//! both processes): a true one-way figure. It then acks on a raw channel so only one message is in
//! flight. Criterion times the round trip; the summary prints one-way p50/p99/p99.9/max and the
//! ratio of each Conductor path to its raw floor.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use conductor_benches::percentiles::fmt_ns;
use conductor_benches::Percentiles;
use conductor_bus::{
    monotonic_ns, Bus, Domain, StateMeta, StatePublisher, StateSpec, StateSubscriber, TickWaiter,
};
use criterion::Criterion;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

const ROLE: &str = "CONDUCTOR_BENCH_ROLE";
const STOP: u64 = u64::MAX;
const MODES: [&str; 4] = ["raw-busy", "state-busy", "raw-event", "state-event"];

/// Pins the calling thread to `cpu`. The id is set directly: a child inherits its parent's
/// affinity mask, so `get_core_ids()` there would only list the parent's CPU. On a
/// single-CPU machine both sides share CPU 0.
fn pin(cpu: usize) {
    if !core_affinity::set_for_current(core_affinity::CoreId { id: cpu }) {
        core_affinity::set_for_current(core_affinity::CoreId { id: 0 });
    }
}

fn node(d: &Domain) -> Node<ipc::Service> {
    NodeBuilder::new()
        .config(d.iceoryx2_config())
        .create::<ipc::Service>()
        .unwrap()
}

fn raw_pub(n: &Node<ipc::Service>, name: &str) -> Publisher<ipc::Service, u64, ()> {
    n.service_builder(&name.try_into().unwrap())
        .publish_subscribe::<u64>()
        .subscriber_max_buffer_size(4)
        .open_or_create()
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap()
}

fn raw_sub(n: &Node<ipc::Service>, name: &str) -> Subscriber<ipc::Service, u64, ()> {
    n.service_builder(&name.try_into().unwrap())
        .publish_subscribe::<u64>()
        .subscriber_max_buffer_size(4)
        .open_or_create()
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

fn raw_event(
    n: &Node<ipc::Service>,
) -> iceoryx2::service::port_factory::event::PortFactory<ipc::Service> {
    n.service_builder(&"bench/ev".try_into().unwrap())
        .event()
        .open_or_create()
        .unwrap()
}

/// The receiving side, run in the child process.
fn child(mode: &str, domain: &str) {
    pin(1);
    let d = Domain::new(domain).unwrap();
    let n = node(&d);
    let ack = raw_pub(&n, "bench/ack");
    let mut lat = Vec::with_capacity(1 << 20);
    let mut record = |stamp: u64| -> bool {
        let now = monotonic_ns();
        if stamp == STOP {
            return false;
        }
        lat.push(now - stamp);
        ack.send_copy(stamp).unwrap();
        true
    };
    match mode {
        "raw-busy" | "raw-event" => {
            let sub = raw_sub(&n, "bench/ping");
            let ev = raw_event(&n);
            let listener: Listener<ipc::Service> = ev.listener_builder().create().unwrap();
            println!("READY");
            'outer: loop {
                if mode == "raw-event" {
                    listener.blocking_wait(|_| {}).unwrap();
                }
                while let Some(s) = sub.receive().unwrap() {
                    if !record(*s) {
                        break 'outer;
                    }
                }
            }
        }
        _ => {
            let bus = Bus::open(&d, "bench-child").unwrap();
            let mut sub = StateSubscriber::with_buffer(&bus, "bench/q", 4).unwrap();
            let mut tick = TickWaiter::new(&bus, "bench").unwrap();
            println!("READY");
            'outer2: loop {
                if mode == "state-event" {
                    tick.wait(Duration::from_secs(10)).unwrap();
                }
                while let Some(s) = sub.receive().unwrap() {
                    if !record(if s.value < 0.0 { STOP } else { s.t_publish_ns }) {
                        break 'outer2;
                    }
                }
            }
        }
    }
    let p = Percentiles::from_samples(&mut lat).unwrap();
    println!(
        "ONEWAY {} {} {} {} {} {}",
        p.count, p.min, p.p50, p.p99, p.p999, p.max
    );
}

/// The sending side of one mode, in the parent process.
struct Sender {
    mode: &'static str,
    raw: Option<(Publisher<ipc::Service, u64, ()>, Notifier<ipc::Service>)>,
    state: Option<StatePublisher>,
    ack: Subscriber<ipc::Service, u64, ()>,
    child: std::process::Child,
    out: std::sync::mpsc::Receiver<String>,
    seq: u64,
}

impl Sender {
    fn start(mode: &'static str) -> Sender {
        let d = Domain::unique("benchlat").unwrap();
        let n = node(&d);
        // Everything the child opens exists before it starts.
        let raw_p = raw_pub(&n, "bench/ping");
        let ev = raw_event(&n);
        let notifier = ev.notifier_builder().create().unwrap();
        let ack = raw_sub(&n, "bench/ack");
        let bus = Bus::open(&d, "bench-parent").unwrap();
        let state = StatePublisher::create(
            &bus,
            "bench",
            &[StateSpec {
                buffer: 4,
                ..StateSpec::new("q", StateMeta::default())
            }],
        )
        .unwrap();
        let mut child = Command::new(std::env::current_exe().unwrap())
            .env(ROLE, format!("{mode} {}", d.name()))
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let (tx, out) = std::sync::mpsc::channel();
        let stdout = child.stdout.take().unwrap();
        std::thread::spawn(move || {
            for l in BufReader::new(stdout).lines().map_while(Result::ok) {
                let _ = tx.send(l);
            }
        });
        assert_eq!(out.recv_timeout(Duration::from_secs(20)).unwrap(), "READY");
        // Keep the parent's node alive inside the Bus/ports; leak the raw node for the run.
        std::mem::forget(n);
        std::mem::forget(ev);
        let mut s = Sender {
            mode,
            raw: Some((raw_p, notifier)),
            state: Some(state),
            ack,
            child,
            out,
            seq: 0,
        };
        // Warm up connections and caches.
        for _ in 0..1000 {
            s.round_trip();
        }
        s
    }

    fn send(&mut self, stop: bool) {
        self.seq += 1;
        match self.mode {
            "raw-busy" | "raw-event" => {
                let (p, n) = self.raw.as_ref().unwrap();
                p.send_copy(if stop { STOP } else { monotonic_ns() })
                    .unwrap();
                if self.mode == "raw-event" {
                    n.notify().unwrap();
                }
            }
            _ => {
                let p = self.state.as_mut().unwrap();
                let v = if stop { -1.0 } else { 1.0 };
                p.publish(0, self.seq, monotonic_ns(), v, 0).unwrap();
                if self.mode == "state-event" {
                    p.notify_tick().unwrap();
                }
            }
        }
    }

    fn round_trip(&mut self) {
        self.send(false);
        let deadline = Instant::now() + Duration::from_secs(5);
        while self.ack.receive().unwrap().is_none() {
            assert!(Instant::now() < deadline, "{}: no ack", self.mode);
            std::hint::spin_loop();
        }
    }

    fn finish(mut self) -> Percentiles {
        self.send(true);
        let line = self
            .out
            .recv_timeout(Duration::from_secs(20))
            .expect("child summary");
        self.child.wait().unwrap();
        let f: Vec<u64> = line
            .split_whitespace()
            .skip(1)
            .map(|x| x.parse().unwrap())
            .collect();
        Percentiles {
            count: f[0] as usize,
            min: f[1],
            p50: f[2],
            p99: f[3],
            p999: f[4],
            max: f[5],
            mean: f64::NAN,
        }
    }
}

fn main() {
    if let Ok(role) = std::env::var(ROLE) {
        let (mode, domain) = role.split_once(' ').unwrap();
        child(mode, domain);
        return;
    }
    pin(0);
    let mut c = Criterion::default()
        .configure_from_args()
        .measurement_time(Duration::from_secs(3))
        .warm_up_time(Duration::from_secs(1));
    let mut results = Vec::new();
    {
        let mut g = c.benchmark_group("bus_round_trip");
        for mode in MODES {
            let mut s = Sender::start(mode);
            g.bench_function(mode, |b| b.iter(|| s.round_trip()));
            // A fixed extra sample count for stable percentiles.
            for _ in 0..50_000 {
                s.round_trip();
            }
            results.push((mode, s.finish()));
        }
        g.finish();
    }
    println!();
    println!(
        "One-way latency, publisher stamp → subscriber receipt, two processes on CPUs 0 and 1:"
    );
    println!("| path | samples | p50 | p99 | p99.9 | max | p50 / floor | p99 / floor |");
    println!("|---|---|---|---|---|---|---|---|");
    for (mode, p) in &results {
        let floor = if mode.ends_with("busy") {
            &results[0].1
        } else {
            &results[2].1
        };
        let r = p.ratio_to(floor);
        println!(
            "| {mode} | {} | {} | {} | {} | {} | {:.2} | {:.2} |",
            p.count,
            fmt_ns(p.p50),
            fmt_ns(p.p99),
            fmt_ns(p.p999),
            fmt_ns(p.max),
            r.p50,
            r.p99
        );
    }
    c.final_summary();
}
