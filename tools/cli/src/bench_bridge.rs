//! `conductor bench --bridge`: the bridge against raw Zenoh over the same link, in one run.
//!
//! The link is two network namespaces joined by a veth pair made for the run (as root), else
//! loopback (said in the report). Three measurements:
//!
//! 1. latency, one state at `--bridge-latency-hz`: publish in domain A → a subscriber of the
//!    mirror in domain B (through both bridges), beside the same subscriber on A's local bus,
//!    and beside raw Zenoh pub/sub of the same message between the two namespaces (helper
//!    processes `conductor __bridge-bench zpub|zsub`): a one-entry tick message with its envelope,
//!    put with the bridge's publisher settings (congestion drop, express). Each way of reading
//!    the bridge has its raw Zenoh counterpart, so that a ratio compares two paths and not two
//!    wake-up patterns: the mirror's sample on B's bus (its `t_publish_ns`, stamped in the
//!    importing bridge's Zenoh callback) against raw Zenoh read in its callback; a thread woken
//!    by the mirror's tick event (as a controller reads) against a thread woken by Zenoh's
//!    default FIFO-channel handler; a thread busy-polling the mirror against one busy-polling
//!    that channel. The woken readers of A's and B's bus run one after the other, so that A's
//!    does not take a CPU from the exporting bridge at the tick it measures;
//! 2. load, `--bridge-states` states at `--bridge-rate` Hz for `--seconds`: CPU % of each bridge
//!    process and the samples that never reached B (drops).
//!
//! Latencies compare `t_sample_ns` (stamped at publish) with the receive time: one clock, since
//! namespaces share the machine's CLOCK_MONOTONIC.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use conductor_bridge::zenoh::{self, Wait};
use conductor_bus::{
    monotonic_ns, Bus, Domain, StateMeta, StatePublisher, StateSpec, StateSubscriber, TickWaiter,
};

use crate::error::{CliError, Result};
use crate::netns::VethPair;

/// What to run.
#[derive(Debug, Clone)]
pub struct Options {
    /// States of the load run.
    pub states: usize,
    /// Rate of the load run (Hz).
    pub rate_hz: f64,
    /// Seconds of the load run.
    pub seconds: f64,
    /// Samples per latency path.
    pub latency_samples: usize,
    /// Rate of the latency run (Hz).
    pub latency_hz: f64,
    /// Use loopback even as root.
    pub loopback: bool,
    /// The exporting bridge's `--spin-us` (`None`: its default).
    pub spin_us: Option<u64>,
    /// Leave the publisher and the exporting bridge wherever the scheduler puts them.
    pub unpinned: bool,
}

fn err(m: impl Into<String>) -> CliError {
    CliError::Usage(format!("bench --bridge: {}", m.into()))
}

fn me() -> Result<std::path::PathBuf> {
    std::env::current_exe().map_err(|e| CliError::os("finding my own program", e))
}

struct Sides {
    netns: Option<VethPair>,
    port: u16,
}

impl Sides {
    fn endpoint(&self, i: usize) -> String {
        match &self.netns {
            Some(n) => format!("tcp/{}:{}", n.addr[i], self.port),
            None => format!("tcp/127.0.0.1:{}", self.port + i as u16),
        }
    }

    fn command(&self, i: usize) -> Result<Command> {
        Ok(match &self.netns {
            Some(n) => {
                let mut c = Command::new("ip");
                c.args(["netns", "exec", &n.ns[i]]).arg(me()?);
                c
            }
            None => Command::new(me()?),
        })
    }

    fn describe(&self) -> &'static str {
        if self.netns.is_some() {
            "two network namespaces joined by a veth pair"
        } else {
            "loopback (not root, or --bridge-loopback)"
        }
    }
}

struct Helper {
    child: Child,
    lines: std::sync::mpsc::Receiver<String>,
}

impl Helper {
    fn spawn(mut c: Command) -> Result<Self> {
        let mut child = c
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| CliError::os("starting a bench helper", e))?;
        let (tx, lines) = std::sync::mpsc::channel();
        let out = child.stdout.take().expect("piped");
        std::thread::spawn(move || {
            for l in BufReader::new(out)
                .lines()
                .map_while(std::result::Result::ok)
            {
                let _ = tx.send(l);
            }
        });
        Ok(Self { child, lines })
    }

    fn line(&self, starts: &str, timeout: Duration) -> Result<String> {
        let end = Instant::now() + timeout;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            match self.lines.recv_timeout(left) {
                Ok(l) if l.starts_with(starts) => return Ok(l),
                Ok(_) => {}
                Err(_) => break,
            }
        }
        Err(err(format!("no {starts:?} line from a helper")))
    }

    /// The process doing the work (through `ip netns exec`, which execs it).
    fn pid(&self) -> u32 {
        self.child.id()
    }

    /// SIGINT (a bridge's orderly stop), then at most 10 s before the kill of `drop`.
    fn stop(mut self) {
        // SAFETY: kill(2) on our own child's pid.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGINT) };
        let end = Instant::now() + Duration::from_secs(10);
        while self.child.try_wait().ok().flatten().is_none() && Instant::now() < end {
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// A run that fails half-way does not leave its helpers (bridges spinning, Zenoh sessions)
/// running after it.
impl Drop for Helper {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// CPU seconds (user + system) of a process so far.
fn cpu_seconds(pid: u32) -> f64 {
    let Ok(s) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
        return 0.0;
    };
    // Fields after the command name (which may contain spaces) start after the last ')'.
    let rest = s.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11).and_then(|u| u.parse().ok()).unwrap_or(0.0)
        + f.get(12).and_then(|u| u.parse().ok()).unwrap_or(0.0);
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    ticks / hz.max(1.0)
}

fn percentile(v: &mut [u64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_unstable();
    let i = ((v.len() - 1) as f64 * p).round() as usize;
    v[i] as f64 / 1e3
}

fn specs(n: usize, rate: f64) -> Vec<StateSpec> {
    (0..n)
        .map(|i| {
            StateSpec::new(
                format!("s{i}"),
                StateMeta {
                    index: i as u32,
                    rate_hz: rate,
                    ..StateMeta::default()
                },
            )
        })
        .collect()
}

/// Publishes `n` states of `subsystem` at `rate` in its own thread until `stop`; returns the
/// number of ticks published.
fn publisher(
    d: &Domain,
    subsystem: &str,
    n: usize,
    rate: f64,
    cpu: Option<usize>,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<Result<u64>> {
    let (d, subsystem) = (d.clone(), subsystem.to_string());
    std::thread::spawn(move || {
        if let Some(c) = cpu {
            // Where an executor runs: on its own CPU.
            conductor_bus::rt::pin_to_cpu(c).map_err(|p| err(p.what))?;
        }
        let bus = Bus::open(&d, "bench-publisher")?;
        let mut p = StatePublisher::create(&bus, &subsystem, &specs(n, rate))?;
        let period = Duration::from_secs_f64(1.0 / rate);
        let mut next = Instant::now();
        let mut tick = 0u64;
        while !stop.load(Ordering::Relaxed) {
            tick += 1;
            for i in 0..n {
                p.publish(i, tick, monotonic_ns(), tick as f64, 0)?;
            }
            p.notify_tick()?;
            next += period;
            let now = Instant::now();
            if next > now {
                std::thread::sleep(next - now);
            } else {
                next = now;
            }
        }
        Ok(tick)
    })
}

fn bridge(
    sides: &Sides,
    i: usize,
    d: &Domain,
    remote: &Domain,
    export: &str,
    o: &Options,
) -> Result<Helper> {
    let mut c = sides.command(i)?;
    c.arg("--domain").arg(d.name()).arg("bridge");
    c.args(["--host", if i == 0 { "bench-a" } else { "bench-b" }]);
    c.arg("--listen").arg(sides.endpoint(i));
    if i == 0 {
        c.args(["--export", export]);
        if let Some(us) = o.spin_us {
            c.arg("--spin-us").arg(us.to_string());
        }
        if let Some((_, cpus)) = placement(o) {
            let cpus: Vec<String> = cpus.iter().map(|c| c.to_string()).collect();
            c.arg("--cpus").arg(cpus.join(","));
        }
    } else {
        c.arg("--connect").arg(sides.endpoint(0));
        c.args(["--import", remote.name()]);
    }
    let h = Helper::spawn(c)?;
    h.line("ready bridge", Duration::from_secs(180))?;
    Ok(h)
}

/// Where A's side runs, unless `--bridge-unpinned` or one CPU: the publisher, standing for
/// an executor, on the first CPU; the exporting bridge on the others, as a launched manifest
/// places it (off its executors' CPUs).
fn placement(o: &Options) -> Option<(usize, Vec<usize>)> {
    let cpus = conductor_bus::rt::usable_cpus();
    match cpus.split_first() {
        Some((&first, rest)) if !o.unpinned && !rest.is_empty() => Some((first, rest.to_vec())),
        _ => None,
    }
}

fn wait_listed(bus: &Bus, name: &str) -> Result<()> {
    let end = Instant::now() + Duration::from_secs(180);
    while bus.resolve(name).is_err() {
        if Instant::now() > end {
            return Err(err(format!(
                "{name} never appeared in domain {}",
                bus.domain().name()
            )));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok(())
}

/// Reads `n` samples of `lat/s0` in domain `d`, woken by the subsystem's tick event, in its own
/// thread; returns, per sample, (read time, the sample's `t_publish_ns`) − `t_sample_ns`.
fn woken_reader(
    d: &Domain,
    n: usize,
    timeout: Duration,
) -> std::thread::JoinHandle<Result<Vec<(u64, u64)>>> {
    let d = d.clone();
    std::thread::spawn(move || {
        let bus = Bus::open(&d, "bench-woken")?;
        let mut w = TickWaiter::new(&bus, "lat")?;
        let mut s = StateSubscriber::with_buffer(&bus, "lat/s0", 16)?;
        while s.receive()?.is_some() {}
        let mut v = Vec::with_capacity(n);
        let end = Instant::now() + timeout;
        while v.len() < n && Instant::now() < end {
            w.wait(Duration::from_millis(100))?;
            while let Some(x) = s.receive()? {
                let now = monotonic_ns();
                if x.status & conductor_bus::status::STALE == 0 {
                    v.push((
                        now.saturating_sub(x.t_sample_ns),
                        x.t_publish_ns.saturating_sub(x.t_sample_ns),
                    ));
                }
            }
        }
        Ok(v)
    })
}

/// How the raw Zenoh subscriber takes its samples.
#[derive(Debug, Clone, Copy)]
enum RawMode {
    /// In the subscriber's callback, on Zenoh's own thread.
    Callback,
    /// An application thread blocked on Zenoh's default handler (a FIFO channel).
    Woken,
    /// An application thread busy-polling that channel (yielding when it is empty).
    Poll,
}

impl RawMode {
    fn arg(self) -> &'static str {
        match self {
            RawMode::Callback => "callback",
            RawMode::Woken => "woken",
            RawMode::Poll => "poll",
        }
    }
}

/// Raw Zenoh pub/sub of the bridge's one-state message between the two sides, read `mode`'s way:
/// latency p50/p99 (µs) from the sample's time.
fn raw_zenoh(sides: &Sides, o: &Options, mode: RawMode) -> Result<(f64, f64)> {
    let n = o.latency_samples;
    let mut sub = sides.command(1)?;
    sub.args(["__bridge-bench", "zsub", "--count"])
        .arg(n.to_string())
        .arg("--endpoint")
        .arg(sides.endpoint(1))
        .args(["--mode", mode.arg()]);
    let sub = Helper::spawn(sub)?;
    sub.line("ready", Duration::from_secs(30))?;
    let mut publ = sides.command(0)?;
    publ.args(["__bridge-bench", "zpub", "--count"])
        .arg((n + n / 10 + 50).to_string())
        .arg("--rate")
        .arg(o.latency_hz.to_string())
        .arg("--endpoint")
        .arg(sides.endpoint(1));
    let publ = Helper::spawn(publ)?;
    let line = sub.line(
        "latency",
        Duration::from_secs_f64(60.0 + 3.0 * n as f64 / o.latency_hz),
    )?;
    publ.stop();
    sub.stop();
    let nums: Vec<f64> = line
        .split_whitespace()
        .skip(1)
        .filter_map(|w| w.parse().ok())
        .collect();
    Ok((
        nums.first().copied().unwrap_or(f64::NAN),
        nums.get(1).copied().unwrap_or(f64::NAN),
    ))
}

/// The figures of one run.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Report {
    /// How the two sides were joined.
    pub link: String,
    /// The exporting bridge's spin (µs; `None`: its default).
    pub spin_us: Option<u64>,
    /// Where the publisher and the exporting bridge ran (`None`: wherever the scheduler put
    /// them).
    pub placement: Option<String>,
    /// Every CPU was held out of deep idle states for the run (`/dev/cpu_dma_latency` at 0), as
    /// on a host whose executor runs (it holds the same while it lives): both raw Zenoh and the
    /// bridges wake from the same idle states. `false` when that could not be had (not root).
    pub deep_idle_off: bool,
    /// Latency p50/p99 (µs), the bench's thread busy-polling: local bus.
    pub local_us: (f64, f64),
    /// Raw Zenoh pub/sub over the link, read in the subscriber's callback (on Zenoh's thread).
    pub zenoh_us: (f64, f64),
    /// The same, read by an application thread woken by Zenoh's default (FIFO channel)
    /// handler: the counterpart of a reader woken by the mirror's tick.
    pub zenoh_woken_us: (f64, f64),
    /// The same, read by an application thread busy-polling that channel: the counterpart of a
    /// reader busy-polling the mirror.
    pub zenoh_poll_us: (f64, f64),
    /// Through both bridges, the bench's thread busy-polling the mirror.
    pub bridge_us: (f64, f64),
    /// Local bus, read by a thread woken by the tick event.
    pub local_woken_us: (f64, f64),
    /// Through both bridges, until the mirror's sample was on B's bus (its `t_publish_ns`).
    pub bridge_on_bus_us: (f64, f64),
    /// Through both bridges, read by a thread woken by the mirror's tick event.
    pub bridge_woken_us: (f64, f64),
    /// CPU % of the exporting and the importing bridge while one state crossed at 1 kHz (the
    /// woken-reader part of the latency run).
    pub latency_cpu_percent: (f64, f64),
    /// States × rate of the load run.
    pub load: (usize, f64, f64),
    /// CPU % of the exporting and the importing bridge during the load run.
    pub cpu_percent: (f64, f64),
    /// Samples published and received on B during the load run.
    pub published: u64,
    /// Received by B's subscribers.
    pub received: u64,
    /// Ticks per second the load publisher reached.
    pub publish_hz: f64,
    /// Samples B saw marked STALE during the load run (each quiet-link episode marks every
    /// mirror once).
    pub stale_samples: u64,
}

impl Report {
    /// A Markdown section.
    pub fn markdown(&self) -> String {
        let row = |name: &str, v: (f64, f64), raw: Option<(f64, f64)>| {
            let r = |a: f64, b: f64| if b > 0.0 { a / b } else { f64::NAN };
            let same = raw.map_or("".to_string(), |raw| {
                format!("{:.2}× / {:.2}×", r(v.0, raw.0), r(v.1, raw.1))
            });
            format!(
                "| {name} | {:.1} | {:.1} | {:.2}× | {same} |\n",
                v.0,
                v.1,
                r(v.0, self.zenoh_us.0),
            )
        };
        let spin = self
            .spin_us
            .map_or("the bridge's default".to_string(), |u| format!("{u} µs"));
        let idle = if self.deep_idle_off {
            "deep idle states held off, as on a host running an executor"
        } else {
            "deep idle states allowed"
        };
        let placed = self
            .placement
            .clone()
            .unwrap_or_else(|| "publisher and bridges unpinned".into());
        format!(
            "### Bridge ({link}; export spin {spin}; {placed}; {idle})\n\n\
             | path | p50 µs | p99 µs | p50 vs raw Zenoh (callback) | p50 / p99 vs raw Zenoh read \
             the same way |\n|---|---|---|---|---|\n\
             {}{}{}{}{}{}{}{}\n\
             The goal (≤ 1.2× at p50) compares each bridge row with raw Zenoh read the same way: \
             \"on B's bus\" (the mirror sample's `t_publish_ns`, stamped in the importing bridge's \
             Zenoh callback) with the callback, a woken reader with a woken reader, a busy-polling \
             reader with a busy-polling reader; all from the sample's time. While one state \
             crossed (woken readers): exporting bridge {:.1} % CPU, importing bridge {:.1} % CPU.\n\n\
             Load: {} states at {} Hz for {} s (publisher reached {:.0} ticks/s): exporting bridge \
             {:.1} % CPU, importing bridge {:.1} % CPU; {} of {} samples reached B ({} dropped, \
             {:.3} %); {} samples marked STALE.\n",
            row("raw Zenoh pub/sub: callback", self.zenoh_us, None),
            row("raw Zenoh pub/sub: reader woken by the channel", self.zenoh_woken_us, None),
            row("raw Zenoh pub/sub: reader busy-polling the channel", self.zenoh_poll_us, None),
            row(
                "bridge: on B's bus (mirror `t_publish_ns`)",
                self.bridge_on_bus_us,
                Some(self.zenoh_us)
            ),
            row(
                "bridge: reader on B woken by the mirror's tick",
                self.bridge_woken_us,
                Some(self.zenoh_woken_us)
            ),
            row(
                "bridge: reader on B busy-polling",
                self.bridge_us,
                Some(self.zenoh_poll_us)
            ),
            row("local bus: reader woken by the tick", self.local_woken_us, None),
            row("local bus: reader busy-polling", self.local_us, None),
            self.latency_cpu_percent.0,
            self.latency_cpu_percent.1,
            self.load.0,
            self.load.1,
            self.load.2,
            self.publish_hz,
            self.cpu_percent.0,
            self.cpu_percent.1,
            self.received,
            self.published,
            self.published.saturating_sub(self.received),
            100.0 * self.published.saturating_sub(self.received) as f64
                / (self.published.max(1) as f64),
            self.stale_samples,
            link = self.link,
        )
    }
}

/// Runs the whole benchmark.
pub fn run(o: &Options) -> Result<Report> {
    // A robot host runs its executors, and an executor holds every CPU out of deep idle states
    // while it lives; so does this run, for raw Zenoh and the bridges alike.
    let deep_idle_off = conductor_bus::rt::hold_wakeup_latency(0).is_ok();
    // SAFETY: geteuid has no preconditions.
    let root = unsafe { libc::geteuid() } == 0;
    let netns = if root && !o.loopback {
        match VethPair::make("bb", 214) {
            Ok(n) => Some(n),
            Err(e) => {
                eprintln!("bench --bridge: no network namespaces ({e}); using loopback");
                None
            }
        }
    } else {
        None
    };
    let port = if netns.is_some() {
        7447
    } else {
        let l = std::net::TcpListener::bind("127.0.0.1:0").map_err(|e| CliError::os("port", e))?;
        let p = l.local_addr().map_err(|e| CliError::os("port", e))?.port();
        drop(l);
        p
    };
    let sides = Sides { netns, port };

    // 1. Raw Zenoh between the two sides, received the three ways the bridge path is read.
    let n = o.latency_samples;
    let zenoh_us = raw_zenoh(&sides, o, RawMode::Callback)?;
    let zenoh_woken_us = raw_zenoh(&sides, o, RawMode::Woken)?;
    let zenoh_poll_us = raw_zenoh(&sides, o, RawMode::Poll)?;

    // 2. Through the bridges, beside the local bus.
    let a = Domain::unique("bbench-a")?;
    let b = Domain::unique("bbench-b")?;
    let ex = bridge(&sides, 0, &a, &b, "lat/*", o)?;
    let im = bridge(&sides, 1, &b, &a, "", o)?;
    let stop = Arc::new(AtomicBool::new(false));
    let pub_cpu = placement(o).map(|p| p.0);
    let p = publisher(&a, "lat", 1, o.latency_hz, pub_cpu, stop.clone());
    let bus_a = Bus::open(&a, "bench-a")?;
    let bus_b = Bus::open(&b, "bench-b")?;
    wait_listed(&bus_b, "lat/s0")?;
    let mut sa = StateSubscriber::with_buffer(&bus_a, "lat/s0", 16)?;
    let mut sb = StateSubscriber::with_buffer(&bus_b, "lat/s0", 16)?;
    // Let the mirror settle, then measure.
    std::thread::sleep(Duration::from_millis(300));
    while sa.receive()?.is_some() || sb.receive()?.is_some() {}
    let (mut la, mut lb) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let end = Instant::now() + Duration::from_secs_f64(30.0 + 3.0 * n as f64 / o.latency_hz);
    while (la.len() < n || lb.len() < n) && Instant::now() < end {
        let mut idle = true;
        if let Some(s) = sa.receive()? {
            la.push(monotonic_ns().saturating_sub(s.t_sample_ns));
            idle = false;
        }
        if let Some(s) = sb.receive()? {
            if s.status & conductor_bus::status::STALE == 0 {
                lb.push(monotonic_ns().saturating_sub(s.t_sample_ns));
            }
            idle = false;
        }
        if idle {
            std::thread::yield_now();
        }
    }
    drop((sa, sb));
    // The same, read by threads woken by the tick events (no CPU held by the bench).
    let timeout = Duration::from_secs_f64(30.0 + 3.0 * n as f64 / o.latency_hz);
    // One reader at a time: a reader on A's bus woken by the same tick as the exporting bridge
    // would take a CPU from it at that very moment, which raw Zenoh's run does not suffer.
    let (c0, c1) = (cpu_seconds(ex.pid()), cpu_seconds(im.pid()));
    let t0 = Instant::now();
    let wb = woken_reader(&b, n, timeout)
        .join()
        .map_err(|_| err("a reader panicked"))??;
    let wall = t0.elapsed().as_secs_f64();
    let latency_cpu_percent = (
        100.0 * (cpu_seconds(ex.pid()) - c0) / wall,
        100.0 * (cpu_seconds(im.pid()) - c1) / wall,
    );
    let wa = woken_reader(&a, n, timeout)
        .join()
        .map_err(|_| err("a reader panicked"))??;
    stop.store(true, Ordering::Relaxed);
    p.join().map_err(|_| err("publisher panicked"))??;
    ex.stop();
    im.stop();
    let local_us = (percentile(&mut la, 0.5), percentile(&mut la, 0.99));
    let bridge_us = (percentile(&mut lb, 0.5), percentile(&mut lb, 0.99));
    let p50_99 = |mut v: Vec<u64>| (percentile(&mut v, 0.5), percentile(&mut v, 0.99));
    let local_woken_us = p50_99(wa.iter().map(|x| x.0).collect());
    let bridge_woken_us = p50_99(wb.iter().map(|x| x.0).collect());
    let bridge_on_bus_us = p50_99(wb.iter().map(|x| x.1).collect());

    // 3. Load.
    let a = Domain::unique("bbload-a")?;
    let b = Domain::unique("bbload-b")?;
    let stop = Arc::new(AtomicBool::new(false));
    let p = publisher(&a, "load", o.states, o.rate_hz, pub_cpu, stop.clone());
    let bus_a = Bus::open(&a, "bench-a")?;
    wait_listed(&bus_a, &format!("load/s{}", o.states - 1))?;
    let ex = bridge(&sides, 0, &a, &b, "load/*", o)?;
    let im = bridge(&sides, 1, &b, &a, "", o)?;
    let bus_b = Bus::open(&b, "bench-b")?;
    wait_listed(&bus_b, &format!("load/s{}", o.states - 1))?;
    let mut subs = bus_b
        .list_states()?
        .into_iter()
        .filter(|s| s.subsystem == "load")
        .map(|s| StateSubscriber::from_info(&bus_b, s, 256))
        .collect::<std::result::Result<Vec<_>, _>>()?;
    std::thread::sleep(Duration::from_millis(500));
    for s in &mut subs {
        while s.receive()?.is_some() {}
    }
    // Count what B receives of the ticks published from here on.
    let first_tick = {
        let mut t = 0;
        for s in &mut subs {
            if let Some(x) = s.latest()? {
                t = t.max(x.tick);
            }
        }
        t
    };
    let (c0, c1) = (cpu_seconds(ex.pid()), cpu_seconds(im.pid()));
    let t0 = Instant::now();
    let mut received = 0u64;
    let mut stale_samples = 0u64;
    let dur = Duration::from_secs_f64(o.seconds);
    while t0.elapsed() < dur {
        for s in &mut subs {
            while let Some(x) = s.receive()? {
                if x.status & conductor_bus::status::STALE != 0 {
                    stale_samples += 1;
                } else if x.tick > first_tick {
                    received += 1;
                }
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let wall = t0.elapsed().as_secs_f64();
    let cpu = (
        100.0 * (cpu_seconds(ex.pid()) - c0) / wall,
        100.0 * (cpu_seconds(im.pid()) - c1) / wall,
    );
    stop.store(true, Ordering::Relaxed);
    let total_ticks = p.join().map_err(|_| err("publisher panicked"))??;
    let publish_hz = (total_ticks - first_tick) as f64 / t0.elapsed().as_secs_f64();
    // Let the tail arrive, then count it.
    std::thread::sleep(Duration::from_millis(500));
    for s in &mut subs {
        while let Some(x) = s.receive()? {
            if x.tick > first_tick
                && x.tick <= total_ticks
                && x.status & conductor_bus::status::STALE == 0
            {
                received += 1;
            }
        }
    }
    let published = (total_ticks - first_tick) * o.states as u64;
    ex.stop();
    im.stop();
    Ok(Report {
        link: sides.describe().into(),
        spin_us: o.spin_us,
        placement: placement(o).map(|(p, b)| {
            let b: Vec<String> = b.iter().map(|c| c.to_string()).collect();
            format!(
                "publisher on CPU {p}, exporting bridge on CPU(s) {}",
                b.join(", ")
            )
        }),
        deep_idle_off,
        local_us,
        zenoh_us,
        zenoh_woken_us,
        zenoh_poll_us,
        bridge_us,
        local_woken_us,
        bridge_on_bus_us,
        bridge_woken_us,
        latency_cpu_percent,
        load: (o.states, o.rate_hz, o.seconds),
        cpu_percent: cpu,
        published,
        received,
        publish_hz,
        stale_samples,
    })
}

/// `conductor __bridge-bench zpub|zsub`: raw Zenoh pub/sub of a sample-sized payload.
pub fn helper(args: &[std::ffi::OsString]) -> Result<()> {
    let a: Vec<String> = args
        .iter()
        .map(|s| s.to_string_lossy().into_owned())
        .collect();
    let get = |k: &str| {
        a.iter()
            .position(|x| x == k)
            .and_then(|i| a.get(i + 1))
            .cloned()
            .ok_or_else(|| err(format!("missing {k}")))
    };
    let role = a.first().cloned().unwrap_or_default();
    let count: usize = get("--count")?.parse().map_err(|_| err("--count"))?;
    let endpoint = get("--endpoint")?;
    let mut cfg = zenoh::Config::default();
    let set = |c: &mut zenoh::Config, k: &str, v: &str| {
        c.insert_json5(k, v).map_err(|e| err(format!("{k}: {e}")))
    };
    set(&mut cfg, "mode", "\"peer\"")?;
    set(&mut cfg, "scouting/multicast/enabled", "false")?;
    let key = "conductor/bench/raw";
    let envelope = conductor_bridge::wire::Envelope {
        host: "bench-a".into(),
        session: 1,
        seq: 0,
    };
    match role.as_str() {
        "zsub" => {
            set(&mut cfg, "listen/endpoints", &format!("[\"{endpoint}\"]"))?;
            let mode = get("--mode").unwrap_or_else(|_| "callback".into());
            let z = zenoh::open(cfg).wait().map_err(|e| err(e.to_string()))?;
            let age = |now: u64, s: &zenoh::sample::Sample| {
                let b = s.payload().to_bytes();
                conductor_bridge::wire::decode_tick(&b)
                    .ok()
                    .and_then(|mut e| e.next())
                    .map(|(_, x)| now.saturating_sub(x.t_sample_ns))
            };
            let mut v = Vec::with_capacity(count);
            // Skip the first samples (connection set-up).
            let mut skip = 20u32;
            let keep = |v: &mut Vec<u64>, skip: &mut u32, ns: Option<u64>| match ns {
                Some(_) if *skip > 0 => *skip -= 1,
                Some(ns) => v.push(ns),
                None => {}
            };
            let wait = Duration::from_secs(60);
            match mode.as_str() {
                "callback" => {
                    let (tx, rx) = std::sync::mpsc::channel::<u64>();
                    let _s = z
                        .declare_subscriber(key)
                        .callback(move |s| {
                            if let Some(ns) = age(monotonic_ns(), &s) {
                                let _ = tx.send(ns);
                            }
                        })
                        .wait()
                        .map_err(|e| err(e.to_string()))?;
                    println!("ready");
                    while v.len() < count {
                        match rx.recv_timeout(wait) {
                            Ok(ns) => keep(&mut v, &mut skip, Some(ns)),
                            Err(_) => break,
                        }
                    }
                }
                "woken" | "poll" => {
                    // Zenoh's default handler: a FIFO channel an application thread reads.
                    let s = z
                        .declare_subscriber(key)
                        .wait()
                        .map_err(|e| err(e.to_string()))?;
                    println!("ready");
                    let end = Instant::now() + wait;
                    while v.len() < count && Instant::now() < end {
                        if mode == "woken" {
                            match s.recv_timeout(wait) {
                                Ok(Some(x)) => keep(&mut v, &mut skip, age(monotonic_ns(), &x)),
                                _ => break,
                            }
                        } else {
                            match s.try_recv() {
                                Ok(Some(x)) => keep(&mut v, &mut skip, age(monotonic_ns(), &x)),
                                Ok(None) => std::thread::yield_now(),
                                Err(_) => break,
                            }
                        }
                    }
                }
                other => return Err(err(format!("unknown --mode {other:?}"))),
            }
            println!(
                "latency {} {} {}",
                percentile(&mut v, 0.5),
                percentile(&mut v, 0.99),
                v.len()
            );
            let _ = z.close().wait();
            Ok(())
        }
        "zpub" => {
            set(&mut cfg, "connect/endpoints", &format!("[\"{endpoint}\"]"))?;
            let rate: f64 = get("--rate")?.parse().map_err(|_| err("--rate"))?;
            let z = zenoh::open(cfg).wait().map_err(|e| err(e.to_string()))?;
            // The bridge's state publisher settings.
            let p = z
                .declare_publisher(key)
                .congestion_control(zenoh::qos::CongestionControl::Drop)
                .express(true)
                .wait()
                .map_err(|e| err(e.to_string()))?;
            std::thread::sleep(Duration::from_millis(500));
            let period = Duration::from_secs_f64(1.0 / rate);
            let mut next = Instant::now();
            for i in 0..count as u64 {
                let s = conductor_bus::StateSample {
                    seq: i,
                    tick: i,
                    t_sample_ns: monotonic_ns(),
                    t_publish_ns: monotonic_ns(),
                    value: i as f64,
                    status: 0,
                    reserved: 0,
                };
                let env = conductor_bridge::wire::Envelope {
                    seq: i,
                    ..envelope.clone()
                };
                p.put(conductor_bridge::wire::encode_tick(&[(0, s)]))
                    .attachment(env.encode())
                    .wait()
                    .map_err(|e| err(e.to_string()))?;
                next += period;
                let now = Instant::now();
                if next > now {
                    std::thread::sleep(next - now);
                }
            }
            let _ = z.close().wait();
            Ok(())
        }
        other => Err(err(format!("unknown helper role {other:?}"))),
    }
}
