//! `conductor bridge` end to end: a real executor (launched from a manifest) owns `leg/*` in
//! domain A; one bridge exports them, another imports them into domain B. States flow out,
//! commands flow back through the owner's checks, the link is cut for 2 s and restored.
//!
//! Two links: two network namespaces joined by a veth pair made here (root only; skipped with a
//! message elsewhere), and loopback between two domains (always), where the exporting bridge is
//! frozen (SIGSTOP) for the cut. The loopback run also injects foreign payloads on the key space.

mod support;

use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

use conductor_bridge::zenoh::{self, Wait};
use conductor_bus::{
    status, Bus, CommandFrame, CommandSender, Controller, Domain, StateSample, StateSubscriber,
};
use conductor_cli::netns::VethPair;
use support::*;

const HEARTBEAT_MS: u64 = 50;
const WATCHDOG_MS: u64 = 300;

fn manifest() -> String {
    format!(
        r#"system = "bridgebot"

[subsystems.leg]
rate_hz = 200
watchdog_ms = {WATCHDOG_MS}

[subsystems.leg.hardware.bus]
kind = "loopback"

[subsystems.leg.protocols.servo]
kind = "sim"
hardware = "bus"

[subsystems.leg.devices.dknee]
kind = "sim"
protocol = "servo"
id = 1

[subsystems.leg.devices.dhip]
kind = "sim"
protocol = "servo"
id = 2

[subsystems.leg.states.knee]
device = "dknee"
units = "rad"
writable = true
min = -1.0
max = 1.0

[subsystems.leg.states.hip]
device = "dhip"
units = "rad"
writable = true
min = -2.0
max = 2.0
"#
    )
}

/// A child whose stdout lines arrive on a channel and whose stderr is kept.
struct Proc {
    child: std::process::Child,
    lines: mpsc::Receiver<String>,
    stderr: Arc<Mutex<String>>,
}

impl Proc {
    fn spawn(cmd: &mut Command) -> Self {
        let mut child = cmd
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn");
        let (tx, lines) = mpsc::channel();
        let out = child.stdout.take().unwrap();
        std::thread::spawn(move || {
            for l in BufReader::new(out).lines().map_while(Result::ok) {
                let _ = tx.send(l);
            }
        });
        let stderr = Arc::new(Mutex::new(String::new()));
        let (err, keep) = (child.stderr.take().unwrap(), stderr.clone());
        std::thread::spawn(move || {
            for l in BufReader::new(err).lines().map_while(Result::ok) {
                let mut k = keep.lock().unwrap();
                k.push_str(&l);
                k.push('\n');
            }
        });
        Self {
            child,
            lines,
            stderr,
        }
    }

    fn wait_line(&self, what: &str, timeout: Duration) -> String {
        let end = Instant::now() + timeout;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            if let Ok(l) = self.lines.recv_timeout(left) {
                if l.contains(what) {
                    return l;
                }
            }
        }
        panic!("no {what:?} line; stderr: {}", self.stderr.lock().unwrap());
    }

    fn signal(&self, sig: i32) {
        // SAFETY: kill(2) on the pid of a child we spawned and have not reaped.
        unsafe { libc::kill(self.child.id() as i32, sig) };
    }

    /// SIGINT, wait; returns stderr.
    fn stop(mut self) -> String {
        self.signal(libc::SIGCONT);
        self.signal(libc::SIGINT);
        let end = Instant::now() + Duration::from_secs(20);
        while self.child.try_wait().unwrap().is_none() {
            assert!(Instant::now() < end, "did not stop");
            std::thread::sleep(Duration::from_millis(20));
        }
        std::thread::sleep(Duration::from_millis(100));
        let s = self.stderr.lock().unwrap().clone();
        s
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Where the two bridges run and how the link between them is cut.
enum Link {
    /// Both on 127.0.0.1; the exporting bridge is frozen for the cut.
    Loopback { port: u16 },
    /// Each in its own network namespace, joined by a veth pair; the veth goes down for the cut.
    Netns(VethPair),
}

impl Link {
    fn netns() -> Result<Self, String> {
        VethPair::make("br", 213).map(Link::Netns)
    }

    /// The endpoint bridge `i` listens on.
    fn endpoint(&self, i: usize) -> String {
        match self {
            Link::Loopback { port } => format!("tcp/127.0.0.1:{}", port + i as u16),
            Link::Netns(n) => format!("tcp/{}:7447", n.addr[i]),
        }
    }

    /// `conductor --domain d` for bridge `i`, inside its namespace when there is one.
    fn conductor(&self, i: usize, d: &Domain) -> Command {
        let mut c = match self {
            Link::Loopback { .. } => Command::new(env!("CARGO_BIN_EXE_conductor")),
            Link::Netns(n) => {
                let mut c = Command::new("ip");
                c.args(["netns", "exec", &n.ns[i], env!("CARGO_BIN_EXE_conductor")]);
                c
            }
        };
        c.arg("--domain").arg(d.name());
        c
    }

    fn cut(&self, exporter: &Proc) {
        match self {
            Link::Loopback { .. } => exporter.signal(libc::SIGSTOP),
            Link::Netns(n) => n.set_link(false).unwrap(),
        }
    }

    fn restore(&self, exporter: &Proc) {
        match self {
            Link::Loopback { .. } => exporter.signal(libc::SIGCONT),
            Link::Netns(n) => n.set_link(true).unwrap(),
        }
    }
}

fn free_tcp_ports(n: u16) -> u16 {
    let seed = std::process::id() % 997 * 31;
    for k in 0..200u32 {
        let base = (20000 + (seed + k * 101) % 40000) as u16;
        let socks: Vec<_> = (0..n)
            .map_while(|i| std::net::TcpListener::bind(("127.0.0.1", base + i)).ok())
            .collect();
        if socks.len() == n as usize {
            return base;
        }
    }
    panic!("no free TCP ports");
}

/// Waits until `name` has a sample matching `pred` on `sub`; returns it.
fn wait_sample(
    sub: &mut StateSubscriber,
    timeout: Duration,
    what: &str,
    pred: impl Fn(&StateSample) -> bool,
) -> StateSample {
    let end = Instant::now() + timeout;
    loop {
        while let Some(s) = sub.receive().unwrap() {
            if pred(&s) {
                return s;
            }
        }
        assert!(Instant::now() < end, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Failure bound of every wait for something that crosses the link: generous, so a loaded
/// machine does not fail the test; what each run measured is printed, not asserted.
const PATIENCE: Duration = Duration::from_secs(30);

/// Sends (with `send`) until `sub` shows a sample matching `pred`; resends every 2 s, fails
/// after [`PATIENCE`]. Remote command frames more than `COMMAND_MAX_AGE` late are dropped by
/// design (a returning link must not replay old setpoints), which a saturated machine can cause:
/// resending is what an operator would do, and the checks stay on what arrives.
fn resend_until<T>(
    sub: &mut StateSubscriber,
    what: &str,
    mut send: impl FnMut() -> T,
    pred: impl Fn(&StateSample) -> bool,
) -> StateSample {
    let end = Instant::now() + PATIENCE;
    loop {
        send();
        let next = Instant::now() + Duration::from_secs(2);
        while Instant::now() < next {
            while let Some(s) = sub.receive().unwrap() {
                if pred(&s) {
                    return s;
                }
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        assert!(Instant::now() < end, "timed out waiting for {what}");
    }
}

fn wait_listed(bus: &Bus, name: &str, timeout: Duration) {
    let end = Instant::now() + timeout;
    while bus.resolve(name).is_err() {
        assert!(
            Instant::now() < end,
            "{name} never appeared in {:?}",
            bus.domain().name()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A sample as the recorder saw it, with the local time it was read.
#[derive(Clone, Copy)]
struct Seen {
    at: Instant,
    s: StateSample,
}

/// Which domain's subscriber: the owner's (`a`) or the mirror's (`b`).
#[derive(Clone, Copy)]
enum Side {
    A,
    B,
}

/// Both sides' knee samples, read continuously while waiting for something.
struct Recorder {
    a: StateSubscriber,
    b: StateSubscriber,
    seen_a: Vec<Seen>,
    seen_b: Vec<Seen>,
}

impl Recorder {
    /// Reads until `side` has a sample read at or after `since` that `pred` accepts; returns
    /// when the first such sample was read.
    fn first(
        &mut self,
        side: Side,
        since: Instant,
        pred: impl Fn(&StateSample) -> bool,
        what: &str,
    ) -> Instant {
        let at = |a: &[Seen], b: &[Seen]| {
            let seen = match side {
                Side::A => a,
                Side::B => b,
            };
            seen.iter()
                .find(|x| x.at >= since && pred(&x.s))
                .map(|x| x.at)
        };
        self.until(|a, b| at(a, b).is_some(), PATIENCE, what);
        at(&self.seen_a, &self.seen_b).unwrap()
    }

    fn until(&mut self, pred: impl Fn(&[Seen], &[Seen]) -> bool, timeout: Duration, what: &str) {
        let end = Instant::now() + timeout;
        loop {
            while let Some(s) = self.a.receive().unwrap() {
                self.seen_a.push(Seen {
                    at: Instant::now(),
                    s,
                });
            }
            while let Some(s) = self.b.receive().unwrap() {
                self.seen_b.push(Seen {
                    at: Instant::now(),
                    s,
                });
            }
            if pred(&self.seen_a, &self.seen_b) {
                return;
            }
            assert!(Instant::now() < end, "timed out: {what}");
            std::thread::sleep(Duration::from_millis(1));
        }
    }
}

/// The quiet time of every "link to … quiet for N ms" line (when mirrors were marked STALE).
fn quiet_ms(log: &str) -> Vec<u64> {
    log.lines()
        .filter_map(|l| l.split(" quiet for ").nth(1))
        .filter_map(|r| r.split(" ms").next())
        .map(|n| n.parse().unwrap())
        .collect()
}

fn counter(summary: &str, name: &str) -> u64 {
    let line = summary
        .lines()
        .find(|l| l.contains("bridge stopped:"))
        .unwrap_or_else(|| panic!("no summary in {summary}"));
    let mut it = line.split_whitespace();
    while let Some(w) = it.next() {
        if w == name {
            return it.next().unwrap().parse().unwrap();
        }
    }
    panic!("no {name} in {line}");
}

/// `bridge --host HOST LINK…` exporting the leg's states and taking remote commands for the
/// knee, with heartbeat [`HEARTBEAT_MS`]; `link` are its Zenoh options.
fn exporter_args(host: &str, link: &[&str]) -> Vec<String> {
    let mut v = vec!["bridge", "--host", host];
    v.extend(link);
    v.extend([
        "--export",
        "leg/*",
        "--commands",
        "leg/knee",
        "--heartbeat-ms",
    ]);
    let mut v: Vec<String> = v.into_iter().map(str::to_string).collect();
    v.push(HEARTBEAT_MS.to_string());
    v
}

/// `bridge --host HOST LINK…` importing the states of domain `from`, with heartbeat
/// [`HEARTBEAT_MS`]; `link` are its Zenoh options.
fn importer_args(host: &str, link: &[&str], from: &Domain) -> Vec<String> {
    let mut v = vec!["bridge", "--host", host];
    v.extend(link);
    v.extend(["--import", from.name(), "--heartbeat-ms"]);
    let mut v: Vec<String> = v.into_iter().map(str::to_string).collect();
    v.push(HEARTBEAT_MS.to_string());
    v
}

/// Starts the importing bridge `host` in domain `b` (side 1 of `link`), dialling side 0 and
/// importing domain `from`; returns once it is ready.
fn start_importer(link: &Link, b: &Domain, host: &str, from: &Domain) -> Proc {
    let link_args = [
        "--connect",
        &link.endpoint(0),
        "--listen",
        &link.endpoint(1),
    ];
    let importer = Proc::spawn(
        link.conductor(1, b)
            .args(importer_args(host, &link_args, from)),
    );
    importer.wait_line(&format!("ready bridge {host}"), Duration::from_secs(30));
    importer
}

/// The scenarios run one at a time: their timing bounds assume the machine is not running two.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// `spin_us`: the exporting bridge's `--spin-us` (busy-wait before expected ticks), if any.
fn scenario(link: Link, tag: &str, inject: bool, spin_us: Option<u64>) {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let Leg {
        a,
        b,
        dir,
        bus_a,
        bus_b,
        _launcher: launcher,
    } = launch_leg(tag);

    let mut ex = link.conductor(0, &a);
    ex.args(exporter_args("hosta", &["--listen", &link.endpoint(0)]));
    if let Some(us) = spin_us {
        ex.arg("--spin-us").arg(us.to_string());
    }
    let exporter = Proc::spawn(&mut ex);
    exporter.wait_line(
        "ready bridge hosta: exporting 2 state(s)",
        Duration::from_secs(30),
    );
    let importer = start_importer(&link, &b, "hostb", &a);

    // Discovery: the mirrors exist in B, owned by host a.
    wait_listed(&bus_b, "leg/knee", Duration::from_secs(20));
    let list = ok(conductor(&b).arg("list"));
    let row = |name: &str| -> Vec<String> {
        list.lines()
            .find(|l| l.starts_with(name))
            .unwrap_or_else(|| panic!("{name} not in {list}"))
            .split_whitespace()
            .map(str::to_string)
            .collect()
    };
    let knee = row("leg/knee");
    assert_eq!(
        knee[1..8],
        [
            "rad",
            "200",
            "rw",
            "[-1,1]",
            "dknee",
            "hosta",
            "bridge@hosta"
        ],
        "{list}"
    );
    // hip is exported but not declared for remote commands: read-only on this side.
    assert_eq!(row("leg/hip")[3], "ro", "{list}");

    let mut a_knee = StateSubscriber::with_buffer(&bus_a, "leg/knee", 256).unwrap();
    let mut b_knee = StateSubscriber::with_buffer(&bus_b, "leg/knee", 256).unwrap();
    let mut a_hip = StateSubscriber::with_buffer(&bus_a, "leg/hip", 256).unwrap();

    // A command through the mirror reaches the owner and comes back.
    resend_until(
        &mut a_knee,
        "knee = 0.5 at the owner",
        || ok(conductor(&b).args(["set", "leg/knee", "0.5"])),
        |s| s.value == 0.5,
    );
    wait_sample(&mut b_knee, PATIENCE, "knee = 0.5 mirrored", |s| {
        s.value == 0.5
    });

    // Out of limits: the owner clamps, and the flag comes back to the sender's side.
    let mut ctl = Controller::new(&bus_b);
    // (The flag comes with the tick that applied the frame; the clamped value reads back a bus
    // cycle later.)
    resend_until(
        &mut b_knee,
        "CLAMPED mirrored",
        || {
            ctl.add_ctrl("leg/knee", 5.0).unwrap();
            ctl.send_ctrl().unwrap();
        },
        |s| s.status & status::CLAMPED != 0,
    );
    wait_sample(&mut b_knee, PATIENCE, "knee clamped to 1", |s| {
        s.status & status::CLAMPED != 0 && s.value == 1.0
    });
    // NaN (sent raw: the Controller refuses it before it leaves): the owner rejects it.
    let mut raw = CommandSender::open(&bus_b, "leg").unwrap();
    let mut f = CommandFrame::default();
    f.push(0, f64::NAN);
    resend_until(
        &mut b_knee,
        "REJECTED mirrored",
        || raw.send(&f).unwrap(),
        |s| s.status & status::REJECTED != 0,
    );
    // A state not declared for remote commands: refused on this side, and a raw frame for it
    // never reaches the owner.
    assert!(ctl.add_ctrl("leg/hip", 0.3).is_err());
    let mut f = CommandFrame::default();
    f.push(1, 0.3);
    raw.send(&f).unwrap();

    // A controller on B commands the knee at 50 Hz from now on.
    let running = Arc::new(AtomicBool::new(true));
    let ctl_thread = {
        let (b, running) = (b.clone(), running.clone());
        std::thread::spawn(move || {
            let bus = Bus::open(&b, "test-controller").unwrap();
            let mut c = Controller::new(&bus);
            while running.load(Ordering::Relaxed) {
                c.add_ctrl("leg/knee", 0.25).unwrap();
                c.send_ctrl().unwrap();
                std::thread::sleep(Duration::from_millis(20));
            }
        })
    };

    // Record both sides from here to the end.
    let mut rec = Recorder {
        a: a_knee,
        b: b_knee,
        seen_a: Vec::new(),
        seen_b: Vec::new(),
    };
    let since = |t: Instant| move |v: &[Seen]| v.iter().filter(|x| x.at >= t).count();
    let t0 = Instant::now();
    rec.until(
        |a, b| since(t0)(a) > 20 && b.last().is_some_and(|x| x.s.value == 0.25),
        PATIENCE,
        "knee = 0.25 on both sides",
    );

    // Foreign and malformed messages on the key space: counted, logged, never published.
    if inject {
        let mut cfg = zenoh::Config::default();
        cfg.insert_json5("mode", "\"peer\"").unwrap();
        cfg.insert_json5("scouting/multicast/enabled", "false")
            .unwrap();
        cfg.insert_json5("connect/endpoints", &format!("[\"{}\"]", link.endpoint(1)))
            .unwrap();
        let z = zenoh::open(cfg).wait().unwrap();
        std::thread::sleep(Duration::from_millis(500));
        let key = format!("conductor/{}/leg", a.name());
        for _ in 0..3 {
            z.put(&key, "hello").wait().unwrap();
            // A well-formed tick message, but with an envelope of a host nobody declared.
            let foreign = conductor_bridge::wire::Envelope {
                host: "intruder".into(),
                session: 1,
                seq: 1,
            };
            let bad = StateSample {
                value: 123.0,
                ..StateSample::default()
            };
            let mut msg = conductor_bridge::wire::encode_tick(&[(0, bad), (1, bad)]);
            z.put(&key, msg.clone())
                .attachment(foreign.encode())
                .wait()
                .unwrap();
            // A status bit the ABI does not define in its second sample: the whole message
            // is refused.
            let at = conductor_bridge::wire::TICK_HEADER_BYTES
                + conductor_bridge::wire::TICK_ENTRY_BYTES
                + 8
                + 43;
            msg[at] = 0x80;
            z.put(&key, msg)
                .attachment(foreign.encode())
                .wait()
                .unwrap();
        }
        std::thread::sleep(Duration::from_millis(300));
        z.close().wait().unwrap();
    }

    // Whether the link looked quiet before the cut is a matter of load (a bridge starved of CPU
    // for 2 heartbeats is, seen from here, a quiet link); what must hold is checked at the end:
    // every STALE mark came after 2 heartbeats of quiet on the importer's own clock.
    let stale_before_cut = rec
        .seen_b
        .iter()
        .filter(|x| x.at >= t0 && x.s.status & status::STALE != 0)
        .count();

    // Cut the link for 2 s.
    let t_cut = Instant::now();
    link.cut(&exporter);
    let t_stale = rec.first(
        Side::B,
        t_cut,
        |s| s.status & status::STALE != 0,
        "mirrors marked STALE",
    );
    let t_wd = rec.first(
        Side::A,
        t_cut,
        |s| s.status & status::WATCHDOG != 0,
        "the owner's watchdog",
    );
    let rest = Duration::from_secs(2).saturating_sub(t_cut.elapsed());
    rec.until(
        |_, _| t_cut.elapsed() >= Duration::from_secs(2),
        rest + Duration::from_secs(1),
        "the cut",
    );
    let t_restore = Instant::now();
    link.restore(&exporter);
    let t_resume = rec.first(
        Side::B,
        t_restore,
        |s| s.status & status::STALE == 0,
        "flow after the restore",
    );
    let t_end = Instant::now() + Duration::from_millis(500);
    rec.until(
        |_, _| Instant::now() >= t_end,
        Duration::from_secs(5),
        "a last half second",
    );
    running.store(false, Ordering::Relaxed);
    ctl_thread.join().unwrap();

    let stale_ms = t_stale.duration_since(t_cut).as_secs_f64() * 1e3;
    let wd_ms = t_wd.duration_since(t_cut).as_secs_f64() * 1e3;
    let resume_ms = t_resume.duration_since(t_restore).as_secs_f64() * 1e3;
    eprintln!(
        "{tag}: STALE {stale_ms:.0} ms after the cut (2 heartbeats = {} ms), owner's watchdog \
         {wd_ms:.0} ms after (watchdog_ms {WATCHDOG_MS}), flow back {resume_ms:.0} ms after the \
         restore",
        2 * HEARTBEAT_MS
    );
    if stale_before_cut > 0 {
        eprintln!("{tag}: {stale_before_cut} STALE sample(s) before the cut (a loaded machine)");
    }
    // Failure bounds only, generous for a loaded machine: the design targets are 2 heartbeats
    // and 1 s; the figures above are what this run measured (benches/README.md has figures).
    assert!(
        stale_ms < (2 * HEARTBEAT_MS) as f64 + 2000.0,
        "STALE after {stale_ms} ms"
    );
    assert!(resume_ms < 8000.0, "flow back after {resume_ms} ms");

    // No wrong or duplicated value: every mirrored sample is the owner's sample of that tick,
    // and fresh ones never repeat a tick.
    let by_tick: HashMap<u64, &StateSample> = rec.seen_a.iter().map(|x| (x.s.tick, &x.s)).collect();
    let mut last_tick = 0;
    let mut checked = 0;
    for x in &rec.seen_b {
        if let Some(o) = by_tick.get(&x.s.tick) {
            assert_eq!(x.s.value.to_bits(), o.value.to_bits(), "tick {}", x.s.tick);
            assert_eq!(x.s.t_sample_ns, o.t_sample_ns, "tick {}", x.s.tick);
            checked += 1;
        } else {
            // Only samples from before the recording started may be missing on A's side.
            assert!(
                x.s.tick <= rec.seen_a[0].s.tick,
                "tick {} unknown at the owner",
                x.s.tick
            );
        }
        if x.s.status & status::STALE == 0 {
            assert!(x.s.tick > last_tick, "tick {} after {last_tick}", x.s.tick);
            last_tick = x.s.tick;
        }
        assert_ne!(x.s.value, 123.0, "an injected value was published");
    }
    assert!(checked > 100, "only {checked} samples compared");
    // The hip never took the refused setpoint.
    while let Some(s) = a_hip.receive().unwrap() {
        assert_ne!(s.value, 0.3, "a refused remote setpoint reached the owner");
    }

    let err_b = importer.stop();
    let err_a = exporter.stop();
    assert!(err_b.contains("marked STALE"), "{err_b}");
    // STALE only after 2 heartbeats of quiet, measured by the importer on its own clock.
    for quiet in quiet_ms(&err_b) {
        assert!(
            quiet >= 2 * HEARTBEAT_MS,
            "marked STALE after {quiet} ms: {err_b}"
        );
    }
    assert!(err_b.contains("is back"), "{err_b}");
    assert!(counter(&err_b, "setpoints_refused") >= 1, "{err_b}");
    assert!(counter(&err_a, "commands_in") >= 10, "{err_a}");
    if let Some(us) = spin_us {
        // The spin ran and says what it did (how many ticks it caught depends on the machine).
        assert!(err_a.contains(&format!("spin {us} µs: ")), "{err_a}");
    }
    if inject {
        assert!(counter(&err_b, "malformed") >= 6, "{err_b}");
        assert!(counter(&err_b, "unknown") >= 3, "{err_b}");
        assert!(
            err_b.contains("dropped a malformed or foreign message"),
            "{err_b}"
        );
    }
    drop(launcher);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn across_loopback_between_two_domains() {
    let port = free_tcp_ports(2);
    // With the export spin on, so both ways of waiting for ticks cross a link in the suite.
    scenario(Link::Loopback { port }, "brlo", true, Some(300));
}

#[test]
fn across_two_network_namespaces_joined_by_a_veth_pair() {
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        eprintln!("SKIPPED: two network namespaces need root (ip netns); the loopback test ran the same scenario");
        return;
    }
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let link = match Link::netns() {
        Ok(l) => l,
        Err(e) => {
            eprintln!("SKIPPED: cannot make network namespaces here ({e}); the loopback test ran the same scenario");
            return;
        }
    };
    drop(_one);
    scenario(link, "brns", false, None);
}

#[test]
fn launch_runs_and_supervises_the_bridge_of_a_manifest() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let a = Domain::unique("brla").unwrap();
    let b = Domain::unique("brlb").unwrap();
    let port = free_tcp_ports(1);
    let dir = tempdir("brlaunch");
    let usable = conductor_bus::rt::usable_cpus();
    let exec_cpu = usable[0];
    let m = dir.join("robot.toml");
    std::fs::write(
        &m,
        format!(
            "{}\n[bridge]\nhost = \"robot\"\n\n[bridge.zenoh]\nlisten = [\"tcp/127.0.0.1:{port}\"]\n\n\
             [bridge.export]\nstates = [\"leg/*\"]\ncommands = [\"leg/knee\"]\n",
            // The executor's CPU, which the bridge keeps off.
            manifest().replace("[subsystems.leg]\n", &format!("[subsystems.leg]\ncpu = {exec_cpu}\n"))
        ),
    )
    .unwrap();
    ok(conductor(&a).arg("launch").arg(&m).arg("--check"));
    let launcher = Proc::spawn(conductor(&a).arg("launch").arg(&m).args(["--no-rt"]));
    let importer = Proc::spawn(conductor(&b).args([
        "bridge",
        "--host",
        "ws",
        "--connect",
        &format!("tcp/127.0.0.1:{port}"),
        "--import",
        a.name(),
    ]));
    importer.wait_line("ready bridge ws", Duration::from_secs(30));
    let bus_b = Bus::open(&b, "test-b").unwrap();
    wait_listed(&bus_b, "leg/knee", Duration::from_secs(30));
    // A setpoint from the workstation side reaches the launched executor.
    let bus_a = Bus::open(&a, "test-a").unwrap();
    let mut knee = StateSubscriber::with_buffer(&bus_a, "leg/knee", 64).unwrap();
    resend_until(
        &mut knee,
        "knee = -0.5",
        || ok(conductor(&b).args(["set", "leg/knee", "-0.5"])),
        |s| s.value == -0.5,
    );

    // The launcher supervises it: killed, it is restarted, and the mirror comes back to life.
    let log = || launcher.stderr.lock().unwrap().clone();
    let end = Instant::now() + PATIENCE;
    while !log().contains("bridge ready") {
        assert!(
            Instant::now() < end,
            "no 'bridge ready' from the launcher: {}",
            log()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let pid: i32 = log()
        .lines()
        .find_map(|l| l.split("bridge started (pid ").nth(1))
        .and_then(|r| r.split(')').next())
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("no bridge pid in {}", log()));
    // Every thread of the bridge, Zenoh's included, runs off the executor's CPU (where there is
    // another one to run on).
    let expected: Vec<usize> = if usable.len() > 1 {
        usable[1..].to_vec()
    } else {
        usable.clone()
    };
    let threads = allowed_cpus(pid);
    assert!(threads.len() > 3, "the bridge's threads: {threads:?}");
    for (tid, cpus) in &threads {
        assert_eq!(
            cpus, &expected,
            "thread {tid} of the bridge (executor on CPU {exec_cpu})"
        );
    }
    // SAFETY: kill(2) on the bridge the launcher (our child) started.
    unsafe { libc::kill(pid, libc::SIGKILL) };
    let mut mirror = StateSubscriber::with_buffer(&bus_b, "leg/knee", 64).unwrap();
    wait_sample(&mut mirror, PATIENCE, "STALE after the kill", |s| {
        s.status & status::STALE != 0
    });
    wait_sample(
        &mut mirror,
        Duration::from_secs(20),
        "fresh after the restart",
        |s| s.status & status::STALE == 0,
    );
    let err_b = importer.stop();
    assert!(err_b.contains("is back"), "{err_b}");
    let out = launcher.stop();
    assert!(out.contains("bridge started"), "{out}");
    let _ = std::fs::remove_dir_all(dir);
}

/// Each thread of process `pid`: its tid and the CPUs it may run on (`Cpus_allowed_list`).
fn allowed_cpus(pid: i32) -> Vec<(String, Vec<usize>)> {
    let mut out = Vec::new();
    for t in std::fs::read_dir(format!("/proc/{pid}/task"))
        .unwrap()
        .flatten()
    {
        let Ok(status) = std::fs::read_to_string(t.path().join("status")) else {
            continue;
        };
        let list = status
            .lines()
            .find_map(|l| l.strip_prefix("Cpus_allowed_list:"))
            .expect("a Cpus_allowed_list line")
            .trim();
        let mut cpus = Vec::new();
        for part in list.split(',') {
            match part.split_once('-') {
                Some((a, b)) => cpus.extend(a.parse::<usize>().unwrap()..=b.parse().unwrap()),
                None => cpus.push(part.parse().unwrap()),
            }
        }
        out.push((t.file_name().to_string_lossy().into_owned(), cpus));
    }
    out
}

/// A host's catalog changes (its bridge restarted exporting more states) while a local
/// subscriber on the importing side holds the mirror's services open: the importer rebuilds
/// its own mirror, it does not refuse it as another subsystem of the same name (which left it
/// STALE for good, the intermittent failure of the launch test above).
#[test]
fn a_changed_catalog_rebuilds_a_mirror_that_local_readers_hold_open() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let port = free_tcp_ports(1);
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let leg = launch_leg("brcat");
    let exporter = |states: &str| {
        Proc::spawn(conductor(&leg.a).args([
            "bridge",
            "--host",
            "robot",
            "--listen",
            &endpoint,
            "--export",
            states,
            "--heartbeat-ms",
            &HEARTBEAT_MS.to_string(),
        ]))
    };
    let first = exporter("leg/knee");
    first.wait_line(
        "ready bridge robot: exporting 1 state(s)",
        Duration::from_secs(30),
    );
    let importer =
        Proc::spawn(conductor(&leg.b).args(importer_args("ws", &["--connect", &endpoint], &leg.a)));
    importer.wait_line("ready bridge ws", Duration::from_secs(30));
    wait_listed(&leg.bus_b, "leg/knee", Duration::from_secs(30));
    let mut held = StateSubscriber::with_buffer(&leg.bus_b, "leg/knee", 256).unwrap();
    wait_sample(&mut held, PATIENCE, "a fresh mirror", |s| {
        s.status & status::STALE == 0
    });
    assert!(
        leg.bus_b.resolve("leg/hip").is_err(),
        "hip is not exported yet"
    );

    // The robot's bridge comes back exporting both states: a new catalog.
    first.stop();
    let second = exporter("leg/*");
    second.wait_line(
        "ready bridge robot: exporting 2 state(s)",
        Duration::from_secs(30),
    );
    wait_listed(&leg.bus_b, "leg/hip", PATIENCE);
    let restarted = conductor_bus::monotonic_ns();
    // The reader that held the old mirror open reads fresh samples of the new one.
    wait_sample(
        &mut held,
        PATIENCE,
        "fresh knee samples after the rebuild",
        |s| s.status & status::STALE == 0 && s.t_sample_ns > restarted,
    );
    let mut hip = StateSubscriber::with_buffer(&leg.bus_b, "leg/hip", 64).unwrap();
    wait_sample(&mut hip, PATIENCE, "fresh hip samples", |s| {
        s.status & status::STALE == 0
    });
    drop(second);
    let err = importer.stop();
    assert!(!err.contains("not importing"), "{err}");
    let _ = std::fs::remove_dir_all(&leg.dir);
}

/// The leg executor launched in a fresh domain `a`, and a second fresh domain `b`.
struct Leg {
    a: Domain,
    b: Domain,
    dir: std::path::PathBuf,
    bus_a: Bus,
    bus_b: Bus,
    _launcher: Proc,
}

fn launch_leg(tag: &str) -> Leg {
    let a = Domain::unique(&format!("{tag}a")).unwrap();
    let b = Domain::unique(&format!("{tag}b")).unwrap();
    let dir = tempdir(tag);
    let m = dir.join("leg.toml");
    std::fs::write(&m, manifest()).unwrap();
    let launcher = Proc::spawn(
        conductor(&a)
            .arg("launch")
            .arg(&m)
            .args(["--no-rt", "--quiet"]),
    );
    let bus_a = Bus::open(&a, "test-a").unwrap();
    let bus_b = Bus::open(&b, "test-b").unwrap();
    wait_listed(&bus_a, "leg/knee", Duration::from_secs(30));
    Leg {
        a,
        b,
        dir,
        bus_a,
        bus_b,
        _launcher: launcher,
    }
}

impl Leg {
    /// The mirror of the knee appears in `b`, a setpoint sent there reaches the owner in `a`
    /// and comes back mirrored.
    fn states_flow_and_commands_go_back(&self, value: f64) {
        wait_listed(&self.bus_b, "leg/knee", Duration::from_secs(20));
        let mut a_knee = StateSubscriber::with_buffer(&self.bus_a, "leg/knee", 256).unwrap();
        let mut b_knee = StateSubscriber::with_buffer(&self.bus_b, "leg/knee", 256).unwrap();
        wait_sample(&mut b_knee, PATIENCE, "a fresh mirror", |s| {
            s.status & status::STALE == 0
        });
        resend_until(
            &mut a_knee,
            "setpoint at the owner",
            || ok(conductor(&self.b).args(["set", "leg/knee", &value.to_string()])),
            |s| s.value == value,
        );
        wait_sample(&mut b_knee, PATIENCE, "setpoint mirrored", |s| {
            s.value == value
        });
    }
}

/// A CA written as `<name>.pem` in `dir`.
fn make_ca(dir: &std::path::Path, name: &str) -> rcgen::CertifiedIssuer<'static, rcgen::KeyPair> {
    let mut p = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
    p.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
    p.distinguished_name
        .push(rcgen::DnType::CommonName, format!("{name} CA"));
    let ca = rcgen::CertifiedIssuer::self_signed(p, rcgen::KeyPair::generate().unwrap()).unwrap();
    std::fs::write(dir.join(format!("{name}.pem")), ca.pem()).unwrap();
    ca
}

/// A certificate for `localhost` with common name `cn`, signed by `ca`, written as
/// `<file>.pem` and `<file>-key.pem` in `dir`.
fn make_cert(
    dir: &std::path::Path,
    ca: &rcgen::CertifiedIssuer<'static, rcgen::KeyPair>,
    cn: &str,
    file: &str,
) {
    let mut p =
        rcgen::CertificateParams::new(vec!["localhost".to_string(), "127.0.0.1".into()]).unwrap();
    p.distinguished_name.push(rcgen::DnType::CommonName, cn);
    let key = rcgen::KeyPair::generate().unwrap();
    let cert = p.signed_by(&key, ca).unwrap();
    std::fs::write(dir.join(format!("{file}.pem")), cert.pem()).unwrap();
    std::fs::write(dir.join(format!("{file}-key.pem")), key.serialize_pem()).unwrap();
}

/// A Zenoh client session to `endpoint` trusting `ca.pem` in `dir`, presenting `<cert>.pem`
/// when given.
fn tls_client(
    dir: &std::path::Path,
    endpoint: &str,
    cert: Option<&str>,
) -> zenoh::Result<zenoh::Session> {
    let mut c = zenoh::Config::default();
    let q = |p: std::path::PathBuf| format!("{:?}", p.display().to_string());
    c.insert_json5("mode", "\"client\"").unwrap();
    c.insert_json5("connect/endpoints", &format!("[{endpoint:?}]"))
        .unwrap();
    c.insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    c.insert_json5(
        "transport/link/tls/root_ca_certificate",
        &q(dir.join("ca.pem")),
    )
    .unwrap();
    if let Some(cert) = cert {
        // (A Zenoh client presents its certificate only with mTLS enabled.)
        c.insert_json5("transport/link/tls/enable_mtls", "true")
            .unwrap();
        c.insert_json5(
            "transport/link/tls/connect_certificate",
            &q(dir.join(format!("{cert}.pem"))),
        )
        .unwrap();
        c.insert_json5(
            "transport/link/tls/connect_private_key",
            &q(dir.join(format!("{cert}-key.pem"))),
        )
        .unwrap();
    }
    zenoh::open(c).wait()
}

/// deploy/two-host/zenoh-tls.json5 with the certificates made here: the robot's bridge runs
/// with it over mutual TLS and its access control, the workstation's with its own certificate.
/// Certificates of another CA, or none, are refused; the access control lets the leg's command
/// key in and nothing else of `@cmd`.
#[test]
fn mutual_tls_and_access_control_of_the_two_host_example() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let leg = launch_leg("brtls");
    let dir = &leg.dir;
    let ca = make_ca(dir, "ca");
    make_cert(dir, &ca, "robot", "robot");
    make_cert(dir, &ca, "workstation", "workstation");
    // Same common name, another CA.
    let rogue = make_ca(dir, "rogue-ca");
    make_cert(dir, &rogue, "workstation", "rogue");

    let example = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../deploy/two-host/zenoh-tls.json5"
    ))
    .unwrap();
    let example = example
        .replace("/etc/conductor/tls/", &format!("{}/", dir.display()))
        .replace("conductor/robot/", &format!("conductor/{}/", leg.a.name()));
    assert!(example.contains("enable_mtls: true"), "{example}");
    let robot_cfg = dir.join("robot.json5");
    std::fs::write(&robot_cfg, &example).unwrap();
    // The workstation: the same file with its own certificate and without the robot's access
    // control (see the file's header).
    let ws = example
        .replace("robot.pem", "workstation.pem")
        .replace("robot-key.pem", "workstation-key.pem")
        .replace(
            "access_control: {\n    enabled: true",
            "access_control: {\n    enabled: false",
        );
    assert!(ws.contains("enabled: false"), "{ws}");
    let ws_cfg = dir.join("workstation.json5");
    std::fs::write(&ws_cfg, &ws).unwrap();

    let port = free_tcp_ports(2);
    let robot_ep = format!("tls/localhost:{port}");
    let robot = Proc::spawn(conductor(&leg.a).args(exporter_args(
        "robot",
        &[
            "--zenoh-config",
            robot_cfg.to_str().unwrap(),
            "--listen",
            &robot_ep,
        ],
    )));
    robot.wait_line("ready bridge robot", Duration::from_secs(30));
    let workstation = Proc::spawn(conductor(&leg.b).args(importer_args(
        "workstation",
        &[
            "--zenoh-config",
            ws_cfg.to_str().unwrap(),
            "--connect",
            &robot_ep,
            "--listen",
            &format!("tls/localhost:{}", port + 1),
        ],
        &leg.a,
    )));
    workstation.wait_line("ready bridge workstation", Duration::from_secs(30));
    leg.states_flow_and_commands_go_back(0.5);

    // A certificate of another CA, or none, is refused by the robot's listener.
    assert!(tls_client(dir, &robot_ep, Some("rogue")).is_err());
    assert!(tls_client(dir, &robot_ep, None).is_err());

    // The workstation's certificate: states come in; of the command keys only the leg's reaches
    // the robot's bridge (which counts the junk sent there as malformed); `@cmd/arm` is denied.
    let s = tls_client(dir, &robot_ep, Some("workstation")).unwrap_or_else(|e| {
        panic!(
            "a valid client certificate: {e}; robot: {}",
            robot.stderr.lock().unwrap()
        )
    });
    let sub = s
        .declare_subscriber(format!("conductor/{}/leg", leg.a.name()))
        .wait()
        .unwrap();
    let got = sub.recv_timeout(PATIENCE).unwrap();
    assert!(got.is_some(), "no state over mutual TLS");
    for _ in 0..3 {
        s.put(
            format!("conductor/{}/@cmd/leg", leg.a.name()),
            b"junk".to_vec(),
        )
        .wait()
        .unwrap();
    }
    for _ in 0..5 {
        s.put(
            format!("conductor/{}/@cmd/arm", leg.a.name()),
            b"junk".to_vec(),
        )
        .wait()
        .unwrap();
    }
    std::thread::sleep(Duration::from_millis(500));
    drop(sub);
    s.close().wait().unwrap();
    let ws_summary = workstation.stop();
    let summary = robot.stop();
    assert_eq!(
        counter(&summary, "malformed"),
        3,
        "{summary}\nworkstation: {ws_summary}"
    );
}

/// A Zenoh router (what zenohd runs) between two bridges in client mode that connect only to
/// it: states flow and commands go back.
#[test]
fn through_a_zenoh_router_with_bridges_in_client_mode() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let leg = launch_leg("brrt");
    let port = free_tcp_ports(1);
    let ep = format!("tcp/127.0.0.1:{port}");
    let mut c = zenoh::Config::default();
    c.insert_json5("mode", "\"router\"").unwrap();
    c.insert_json5("listen/endpoints", &format!("[{ep:?}]"))
        .unwrap();
    c.insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    let router = zenoh::open(c).wait().expect("router");

    let client = leg.dir.join("client.json5");
    std::fs::write(
        &client,
        format!(
            "{{ mode: \"client\", connect: {{ endpoints: [{ep:?}] }}, \
             scouting: {{ multicast: {{ enabled: false }} }} }}"
        ),
    )
    .unwrap();
    let cfg = client.to_str().unwrap();
    let exporter =
        Proc::spawn(conductor(&leg.a).args(exporter_args("hosta", &["--zenoh-config", cfg])));
    exporter.wait_line("ready bridge hosta", Duration::from_secs(30));
    let importer = Proc::spawn(conductor(&leg.b).args(importer_args(
        "hostb",
        &["--zenoh-config", cfg],
        &leg.a,
    )));
    importer.wait_line("ready bridge hostb", Duration::from_secs(30));
    leg.states_flow_and_commands_go_back(-0.25);
    importer.stop();
    exporter.stop();
    router.close().wait().unwrap();
}

/// An owner written to ABI 2 before the snapshot existed publishes its states and its tick event
/// and no `snapshot` service (made here with iceoryx2 directly, from bus/ABI.md). The exporting
/// bridge reads such an owner state by state, woken by its tick: every sample crosses once, in
/// order, with the owner's timestamps.
#[test]
fn an_owner_without_a_snapshot_is_read_state_by_state() {
    use conductor_bus::metadata::{
        KEY_ABI, KEY_INDEX, KEY_KIND, KEY_LIMITS, KEY_RATE, KEY_WRITABLE,
    };
    use conductor_bus::qos;
    use iceoryx2::prelude::*;
    use iceoryx2::service::attribute::AttributeSpecifier;

    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let a = Domain::unique("brfoa").unwrap();
    let b = Domain::unique("brfob").unwrap();
    let port = free_tcp_ports(2);
    let link = Link::Loopback { port };
    let attr = |s: AttributeSpecifier, k: &str, v: &str| {
        s.define(&k.try_into().unwrap(), &v.try_into().unwrap())
            .unwrap()
    };
    let stop = Arc::new(AtomicBool::new(false));
    let (ready_tx, ready) = mpsc::channel();
    let owner = {
        let (a, stop) = (a.clone(), stop.clone());
        std::thread::spawn(move || {
            let node = NodeBuilder::new()
                .config(a.iceoryx2_config())
                .create::<ipc::Service>()
                .unwrap();
            let base = |kind| {
                attr(
                    attr(AttributeSpecifier::new(), KEY_ABI, "2"),
                    KEY_KIND,
                    kind,
                )
            };
            let mut spec = base("state");
            for (k, v) in [
                (KEY_INDEX, "0"),
                (KEY_WRITABLE, "false"),
                (KEY_RATE, "100"),
                (KEY_LIMITS, "-inf,inf"),
            ] {
                spec = attr(spec, k, v);
            }
            let state = qos::state_service(
                node.service_builder(&"conductor/fo/x".try_into().unwrap())
                    .publish_subscribe::<StateSample>(),
                16,
            )
            .create_with_attributes(&spec)
            .unwrap();
            let tick = qos::tick_event(
                node.service_builder(&"conductor/fo/tick".try_into().unwrap())
                    .event(),
            )
            .create_with_attributes(&base("tick"))
            .unwrap();
            let publisher = state.publisher_builder().create().unwrap();
            let notifier = tick.notifier_builder().create().unwrap();
            ready_tx.send(()).unwrap();
            let mut seq = 0u64;
            while !stop.load(Ordering::Relaxed) {
                seq += 1;
                let t = conductor_bus::monotonic_ns();
                publisher
                    .send_copy(StateSample {
                        seq,
                        tick: seq,
                        t_sample_ns: t,
                        t_publish_ns: t,
                        value: seq as f64,
                        status: 0,
                        reserved: 0,
                    })
                    .unwrap();
                notifier.notify().unwrap();
                std::thread::sleep(Duration::from_millis(10));
            }
        })
    };
    ready
        .recv_timeout(PATIENCE)
        .expect("the foreign owner started");
    let bus_a = Bus::open(&a, "test-a").unwrap();
    let bus_b = Bus::open(&b, "test-b").unwrap();
    wait_listed(&bus_a, "fo/x", PATIENCE);

    let mut ex = link.conductor(0, &a);
    ex.args([
        "bridge",
        "--host",
        "hostfo",
        "--listen",
        &link.endpoint(0),
        "--export",
        "fo/*",
    ]);
    let exporter = Proc::spawn(&mut ex);
    exporter.wait_line("ready bridge hostfo: exporting 1 state(s)", PATIENCE);
    let importer = start_importer(&link, &b, "hostfb", &a);
    wait_listed(&bus_b, "fo/x", PATIENCE);
    let mut mirror = StateSubscriber::with_buffer(&bus_b, "fo/x", 256).unwrap();
    let mut got = Vec::new();
    let end = Instant::now() + PATIENCE;
    while got.len() < 50 {
        assert!(Instant::now() < end, "only {} samples crossed", got.len());
        while let Some(s) = mirror.receive().unwrap() {
            if s.status & status::STALE == 0 {
                got.push(s);
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    stop.store(true, Ordering::Relaxed);
    owner.join().unwrap();
    let log = exporter.stop();
    importer.stop();
    assert!(
        log.contains("no snapshot for fo") && log.contains("reading its states one by one"),
        "{log}"
    );
    // The owner's value is its seq: each crossed once, in order, none lost in between (the
    // history sample the mirror started from aside).
    for w in got.windows(2) {
        assert_eq!(w[1].value, w[0].value + 1.0, "{:?} then {:?}", w[0], w[1]);
        assert!(w[1].t_sample_ns > w[0].t_sample_ns);
    }
}

/// A CPU the bridge may not use is refused before it starts, naming the ones it may.
#[test]
fn a_bridge_told_to_run_on_a_cpu_it_cannot_use_says_which_it_can() {
    let d = Domain::unique("brcpu").unwrap();
    let err = fails(conductor(&d).args(["bridge", "--export", "leg/*", "--cpus", "4095"]));
    let usable: Vec<String> = conductor_bus::rt::usable_cpus()
        .iter()
        .map(|c| c.to_string())
        .collect();
    assert!(
        err.contains("CPU 4095 is not available to this process")
            && err.contains(&format!("it may use {}", usable.join(", "))),
        "{err}"
    );
}
