//! The Score board in the fault campaign: its controller process, its faults one at a time,
//! the checks from outside the gateway, and its rows of the report.
//!
//! The board ([`score_rig::BoardSim`]) runs under the launcher's `score-gateway` (the table of
//! deploy/score-board.toml). While the legs' campaign runs, a thread of its own:
//!
//! * keeps a controller process commanding `PWM4` and `PWM6` at the campaign's rate (duties on a
//!   0.5 % grid, now and then out of 0–100 % or, through a raw writer, NaN/infinite/unknown);
//! * one at a time, in shuffled rounds: unplugs the board (a power cycle: it comes back empty
//!   and the gateway must restore its configuration), SIGKILLs the gateway (the launcher
//!   restarts it), SIGKILLs or SIGSTOPs the controller (the gateway's command watchdog must
//!   set both duties to 0 within `watchdog_ms` + one gateway loop, and they must stay 0 until a
//!   controller commands again), and floods commands;
//! * a monitor checks every published sample of `ADC0`, `adc0`, `PWM4`, `PWM6`: a value the
//!   board had within the last 3 s (a damaged frame that got through would publish something
//!   else), and every PWM compare value the board was given: within 0–100 % and on the
//!   controller's grid.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use conductor_bus::{
    monotonic_ns, status, Bus, CommandFrame, Controller, Domain, StateSubscriber, MAX_SETPOINTS,
};
use conductor_devices::sim::fault::Rng;
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;
use serde::Serialize;

use super::controller::RawSender;
use super::monitor::lock;
use super::report::{Check, Report, Resources};
use super::score_rig::{self, BoardSim, OUTPUTS, SUBSYSTEM, WATCHED};
use super::Ctl;

/// The gateway's main loop waits at most this long for the board (its port read timeout): one
/// "tick" of the gateway.
pub const GATEWAY_LOOP_NS: u64 = 5_000_000;

/// The board's fault kinds, one at a time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BoardFault {
    /// USB cable out and back (power cycle).
    Unplug,
    /// The gateway SIGKILLed.
    GatewayKill,
    /// The controller SIGKILLed.
    ControllerKill,
    /// The controller SIGSTOPped, then continued.
    ControllerStall,
    /// Command frames back to back.
    Flood,
}

const EVENTS: [BoardFault; 5] = [
    BoardFault::Unplug,
    BoardFault::GatewayKill,
    BoardFault::ControllerKill,
    BoardFault::ControllerStall,
    BoardFault::Flood,
];

impl BoardFault {
    /// The table's name.
    pub fn name(self) -> &'static str {
        match self {
            BoardFault::Unplug => "unplug/replug",
            BoardFault::GatewayKill => "gateway SIGKILL",
            BoardFault::ControllerKill => "controller SIGKILL",
            BoardFault::ControllerStall => "controller SIGSTOP",
            BoardFault::Flood => "command flood",
        }
    }
}

/// One kind's figures.
#[derive(Debug, Clone, Default, Serialize)]
pub struct KindReport {
    /// Injected.
    pub injected: u64,
    /// Counted by the system (see the table's notes per kind).
    pub counted: u64,
    /// Recovered from.
    pub recovered: u64,
    /// Worst recovery (ms).
    pub worst_recovery_ms: f64,
    /// Mean recovery (ms).
    pub mean_recovery_ms: f64,
    #[serde(skip)]
    sum_ns: u64,
}

/// The board's part of the report.
#[derive(Debug, Clone, Default, Serialize)]
pub struct BoardReport {
    /// The gateway's subsystem.
    pub subsystem: String,
    /// Probability that a byte on the board's link was corrupted.
    pub link_corrupt: f64,
    /// Probability that a byte on the board's link was lost.
    pub link_drop: f64,
    /// Per fault kind.
    pub faults: BTreeMap<BoardFault, KindReport>,
    /// Frames the board sent / of them damaged on the wire.
    pub frames_to_host: u64,
    /// Damaged frames towards the host.
    pub damaged_to_host: u64,
    /// Chunks of bytes towards the board that were damaged.
    pub damaged_to_board: u64,
    /// Frames the board rejected (CRC, COBS, length) / accepted.
    pub rejected_by_board: u64,
    /// Frames the board accepted.
    pub accepted_by_board: u64,
    /// Published samples checked.
    pub samples_checked: u64,
    /// Of them, not a value the board had.
    pub wrong_published: u64,
    /// PWM compare values written to the board.
    pub writes_checked: u64,
    /// Of them, out of limits or off the grid.
    pub wrong_written: u64,
    /// Examples of wrong values.
    pub wrong_examples: Vec<String>,
    /// Controller deaths (kills and stalls).
    pub controller_deaths: u64,
    /// Deaths after which both duties reached 0 in time.
    pub safe_in_time: u64,
    /// Deaths after which the duties did not reach 0 in time, or left 0 while nobody
    /// commanded.
    pub unsafe_events: u64,
    /// Worst time from the controller's last command that reached the board to both duties
    /// at 0 (ms).
    pub worst_safe_ms: f64,
    /// Worst time from the kill (or stop) itself to both duties at 0 (ms): the above plus the
    /// commands still queued in the gateway when the controller died.
    pub worst_safe_from_kill_ms: f64,
    /// The gateway's watchdog + one loop (ms).
    pub watchdog_plus_tick_ms: f64,
    /// Deaths whose watchdog trip was seen on the bus (samples flagged WATCHDOG).
    pub trips_seen: u64,
    /// Samples flagged CLAMPED or REJECTED (bad setpoints counted by the gateway).
    pub bad_setpoints_flagged: u64,
    /// Handshakes the board served.
    pub handshakes: u64,
    /// Power-ons whose table the gateway restored.
    pub restores: u64,
    /// Gateway restarts by the launcher.
    pub gateway_restarts: u64,
    /// The longest the board's thread overslept (ms).
    pub worst_board_lag_ms: f64,
}

impl BoardReport {
    fn injected(&mut self, f: BoardFault) {
        self.faults.entry(f).or_default().injected += 1;
    }

    fn recovered(&mut self, f: BoardFault, ns: u64) {
        let k = self.faults.entry(f).or_default();
        k.recovered += 1;
        k.sum_ns += ns;
        k.worst_recovery_ms = k.worst_recovery_ms.max(ns as f64 / 1e6);
        k.mean_recovery_ms = k.sum_ns as f64 / 1e6 / k.recovered as f64;
    }

    /// The board's lines of the table (same columns as the robots').
    pub fn table(&self) -> String {
        use std::fmt::Write as _;
        let s = &self.subsystem;
        let mut t = String::new();
        let row =
            |t: &mut String, fault: &str, inj: String, counted: String, k: Option<&KindReport>| {
                let (rec, worst, mean) = match k {
                    Some(k) if k.recovered > 0 => (
                        k.recovered.to_string(),
                        format!("{:.1} ms", k.worst_recovery_ms),
                        format!("{:.1} ms", k.mean_recovery_ms),
                    ),
                    _ => ("-".into(), "-".into(), "-".into()),
                };
                let _ = writeln!(
                    t,
                    "{s:<11} {fault:<20} {inj:>10} {counted:>12} {rec:>10} {worst:>14} {mean:>12}"
                );
            };
        row(
            &mut t,
            "damaged frames",
            (self.damaged_to_host + self.damaged_to_board).to_string(),
            self.rejected_by_board.to_string(),
            None,
        );
        row(
            &mut t,
            "bad setpoints",
            "-".into(),
            self.bad_setpoints_flagged.to_string(),
            None,
        );
        for (f, k) in &self.faults {
            // Unplugs: the gateway met the board again; gateway kills: a new gateway; controller
            // deaths: samples flagged WATCHDOG. A flood has nothing to count.
            let counted = if *f == BoardFault::Flood {
                "-".to_string()
            } else {
                k.counted.to_string()
            };
            row(&mut t, f.name(), k.injected.to_string(), counted, Some(k));
        }
        let _ = writeln!(
            t,
            "{s:<11} safe state (both duties 0) after {} controller deaths: {} late, {} unsafe, worst {:.1} ms after the last command applied (watchdog + 1 gateway loop = {:.1} ms), {:.1} ms after the kill",
            self.controller_deaths,
            self.controller_deaths - self.safe_in_time,
            self.unsafe_events,
            self.worst_safe_ms,
            self.watchdog_plus_tick_ms,
            self.worst_safe_from_kill_ms
        );
        let _ = writeln!(
            t,
            "{s:<11} USB link: {} % of bytes corrupted and {} % lost; wrong values published: {} of {} checked; written to the board: {} of {} checked; frames damaged towards the host {} of {}, towards the board {} (board rejected {}, accepted {})",
            self.link_corrupt * 100.0,
            self.link_drop * 100.0,
            self.wrong_published,
            self.samples_checked,
            self.wrong_written,
            self.writes_checked,
            self.damaged_to_host,
            self.frames_to_host,
            self.damaged_to_board,
            self.rejected_by_board,
            self.accepted_by_board
        );
        t
    }

    /// The board's checks.
    pub fn checks(&self) -> Vec<Check> {
        let s = &self.subsystem;
        let k = |f: BoardFault| self.faults.get(&f).cloned().unwrap_or_default();
        let mut c = Vec::new();
        let mut check = |name: String, ok: bool, detail: String| c.push(Check { name, ok, detail });
        check(
            format!("{s}: no wrong value published"),
            self.wrong_published == 0 && self.samples_checked > 0,
            format!(
                "{} wrong of {} checked",
                self.wrong_published, self.samples_checked
            ),
        );
        check(
            format!("{s}: no wrong or out-of-limit duty written to the board"),
            self.wrong_written == 0 && self.writes_checked > 0,
            format!(
                "{} wrong of {} checked {:?}",
                self.wrong_written, self.writes_checked, self.wrong_examples
            ),
        );
        check(
            format!("{s}: both duties 0 in time after every controller death, kept"),
            self.unsafe_events == 0 && self.safe_in_time == self.controller_deaths,
            format!(
                "{} deaths, {} in time, {} unsafe; worst {:.1} ms",
                self.controller_deaths, self.safe_in_time, self.unsafe_events, self.worst_safe_ms
            ),
        );
        check(
            format!("{s}: every controller death seen as a watchdog trip"),
            self.trips_seen == self.controller_deaths,
            format!(
                "{} deaths, {} with samples flagged WATCHDOG",
                self.controller_deaths, self.trips_seen
            ),
        );
        check(
            format!("{s}: every replugged (empty) board restored by the gateway"),
            self.restores == k(BoardFault::Unplug).injected,
            format!(
                "{} unplugs, {} restores",
                k(BoardFault::Unplug).injected,
                self.restores
            ),
        );
        check(
            format!("{s}: every gateway kill restarted by the launcher, and nothing else"),
            self.gateway_restarts == k(BoardFault::GatewayKill).injected,
            format!(
                "{} kills, {} restarts",
                k(BoardFault::GatewayKill).injected,
                self.gateway_restarts
            ),
        );
        check(
            format!("{s}: damaged frames towards the board rejected by its CRC check"),
            self.damaged_to_board == 0 || self.rejected_by_board > 0,
            format!(
                "{} damaged chunks, {} frames rejected",
                self.damaged_to_board, self.rejected_by_board
            ),
        );
        for f in EVENTS {
            let k = k(f);
            check(
                format!("{s}: {} injected and recovered from", f.name()),
                k.injected > 0 && k.recovered == k.injected,
                format!("{} injected, {} recovered", k.injected, k.recovered),
            );
        }
        c
    }
}

impl Report {
    /// Adds the board's rows and checks to a finished report (its process samples went into
    /// the report's resources before).
    pub fn add_board(&mut self, board: BoardReport) {
        let mut checks = board.checks();
        self.checks.append(&mut checks);
        self.board = Some(board);
        self.passed = self.checks.iter().all(|c| c.ok) && self.failures.is_empty();
    }
}

// ---------------------------------------------------------------- the controller process

/// What the board's controller process is told.
#[derive(Debug, Clone)]
pub struct ControllerArgs {
    /// Bus domain.
    pub domain: String,
    /// Frames per second.
    pub rate_hz: f64,
    /// Seed of its bad values.
    pub seed: u64,
}

/// Runs the board's controller until killed (or its stdin closes): says `running` once its
/// first frame went out, then commands `PWM4` and `PWM6` at the rate.
pub fn run_controller(args: &ControllerArgs) -> Result<(), Box<dyn std::error::Error>> {
    let domain = Domain::new(&args.domain)?;
    let bus = Bus::open(&domain, &format!("soak-score-ctl-{}", std::process::id()))?;
    let mut ctl = Controller::new(&bus);
    let names: Vec<String> = OUTPUTS
        .iter()
        .map(|o| format!("{SUBSYSTEM}/PWM{o}"))
        .collect();
    // The states exist once the gateway has met the board.
    let end = Instant::now() + Duration::from_secs(30);
    let mut indices = Vec::new();
    for n in &names {
        loop {
            match bus.resolve(n) {
                Ok(info) => {
                    indices.push(info.meta.index);
                    break;
                }
                Err(e) if Instant::now() > end => return Err(e.into()),
                Err(_) => std::thread::sleep(Duration::from_millis(20)),
            }
        }
    }
    let raw = RawSender::open(&domain, SUBSYSTEM)?;
    let flood_until = super::controller::flood_requests();
    let mut rng = Rng::new(args.seed);
    let period = Duration::from_secs_f64(1.0 / args.rate_hz);
    let t0 = Instant::now();
    let mut next = t0;
    let mut said = false;
    loop {
        let t = t0.elapsed().as_secs_f64();
        let bad = rng.chance(0.002);
        if bad && rng.chance(0.5) {
            let mut f = CommandFrame::default();
            for &i in &indices {
                f.push(
                    i,
                    match rng.below(3) {
                        0 => f64::NAN,
                        1 => f64::INFINITY,
                        _ => f64::NEG_INFINITY,
                    },
                );
            }
            f.push(MAX_SETPOINTS as u32 - 1, 50.0);
            f.t_send_ns = monotonic_ns();
            raw.send(&f)?;
        }
        for (i, n) in names.iter().enumerate() {
            let mut v = 50.0 + 40.0 * (0.5 * t + i as f64).sin();
            if bad {
                v = if rng.chance(0.5) {
                    101.0 + rng.unit() * 100.0
                } else {
                    -1.0 - rng.unit() * 100.0
                };
            }
            // On the 0.5 % grid (what is written to the board is checked against it).
            ctl.add_ctrl(n, (v * 2.0).round() / 2.0)?;
        }
        ctl.send_ctrl()?;
        if !said {
            said = true;
            let mut out = std::io::stdout().lock();
            writeln!(out, "running")?;
            out.flush()?;
        }
        super::controller::pace(&mut next, period, &flood_until);
    }
}

/// Starts the board's controller process (`program`, then its own arguments).
fn start_ctl(program: &[String], domain: &str, rate_hz: f64, seed: u64) -> std::io::Result<Ctl> {
    let mut cmd = Ctl::command(program)?;
    cmd.args([
        "--domain",
        domain,
        "--rate-hz",
        &rate_hz.to_string(),
        "--seed",
        &seed.to_string(),
    ]);
    Ctl::spawn(&mut cmd)
}

// ---------------------------------------------------------------- the monitor

/// What the monitor saw.
#[derive(Debug, Default)]
struct Seen {
    samples: u64,
    wrong: u64,
    examples: Vec<String>,
    /// When the newest sample of every watched state was published.
    fresh_ns: [u64; 4],
    /// Samples of the PWM states flagged WATCHDOG since this was last cleared.
    watchdog_flags: u64,
    bad_flags: u64,
}

fn monitor(
    domain: Domain,
    board: Arc<BoardSim>,
    seen: Arc<Mutex<Seen>>,
    stop: Arc<AtomicBool>,
) -> Result<(), String> {
    let bus = Bus::open(&domain, "soak-score-monitor").map_err(|e| e.to_string())?;
    let end = Instant::now() + Duration::from_secs(60);
    let mut subs = Vec::new();
    for n in WATCHED {
        loop {
            match StateSubscriber::new(&bus, &format!("{SUBSYSTEM}/{n}")) {
                Ok(s) => {
                    subs.push(s);
                    break;
                }
                Err(e) if Instant::now() > end => return Err(format!("{SUBSYSTEM}/{n}: {e}")),
                Err(_) if stop.load(Ordering::Relaxed) => return Ok(()),
                Err(_) => std::thread::sleep(Duration::from_millis(20)),
            }
        }
    }
    let mut last_flags = [0u32; 4];
    while !stop.load(Ordering::Relaxed) {
        for (i, s) in subs.iter_mut().enumerate() {
            while let Some(x) = s.receive().map_err(|e| e.to_string())? {
                // A value the board had between 3 s before and the publication (the gateway
                // publishes what the board sent; a damaged frame that passed would not be one).
                let ok = x.value.is_finite()
                    && board.record().had(
                        i,
                        x.value,
                        x.t_publish_ns.saturating_sub(3_000_000_000),
                        x.t_publish_ns,
                    );
                let mut w = lock(&seen);
                w.samples += 1;
                w.fresh_ns[i] = x.t_publish_ns;
                if !ok {
                    w.wrong += 1;
                    if w.examples.len() < 10 {
                        w.examples.push(format!(
                            "{} = {} published at {} ns",
                            WATCHED[i], x.value, x.t_publish_ns
                        ));
                    }
                }
                if x.status & status::WATCHDOG != 0 {
                    w.watchdog_flags += 1;
                }
                let bad = x.status & (status::CLAMPED | status::REJECTED);
                if bad != 0 && bad != last_flags[i] & (status::CLAMPED | status::REJECTED) {
                    w.bad_flags += 1;
                }
                last_flags[i] = x.status;
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok(())
}

// ---------------------------------------------------------------- the campaign thread

/// What the board's campaign needs.
pub struct BoardCampaign {
    /// The board.
    pub board: Arc<BoardSim>,
    /// Domain.
    pub domain: Domain,
    /// The controller program and its arguments before the controller's own.
    pub controller: Vec<String>,
    /// Controller rate.
    pub rate_hz: f64,
    /// Seed.
    pub seed: u64,
    /// The gateway's command watchdog (ns).
    pub watchdog_ns: u64,
    /// When to stop injecting.
    pub end: Instant,
    /// When the campaign started (for resource samples).
    pub started: Instant,
    /// The link's byte corruption and loss probabilities (for the report).
    pub link_faults: (f64, f64),
}

/// The board's campaign result: its report, the process samples, failures.
pub struct BoardOutcome {
    /// Rows and figures.
    pub report: BoardReport,
    /// Gateway and controller samples.
    pub resources: Resources,
    /// Recoveries that did not come.
    pub failures: Vec<String>,
}

/// Runs the board's faults until `c.end` in a thread.
pub fn spawn(c: BoardCampaign) -> JoinHandle<BoardOutcome> {
    std::thread::Builder::new()
        .name("soak-score".into())
        .spawn(move || run(c))
        .expect("spawn the board's campaign")
}

/// The gateway's process (a child of this one whose command line names the board's port).
fn gateway_pid(link: &std::path::Path) -> Option<u32> {
    let me = std::process::id();
    let port = link.display().to_string();
    for e in std::fs::read_dir("/proc").ok()?.flatten() {
        let Some(pid) = e.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
            continue;
        };
        // pid (comm) state ppid ...
        let ppid = stat
            .rsplit_once(')')
            .and_then(|(_, r)| r.split_whitespace().nth(1))
            .and_then(|p| p.parse::<u32>().ok());
        if ppid != Some(me) {
            continue;
        }
        let cmd = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
        let args: Vec<&[u8]> = cmd.split(|&b| b == 0).collect();
        if args.contains(&port.as_bytes()) {
            return Some(pid);
        }
    }
    None
}

/// How long process `pid` has waited on a run queue in all (ns; `/proc/<pid>/schedstat`).
fn run_delay_ns(pid: u32) -> Option<u64> {
    schedstat(&format!("/proc/{pid}/schedstat"))
}

/// The same for thread `tid` of this process.
fn thread_run_delay_ns(tid: i32) -> Option<u64> {
    schedstat(&format!("/proc/self/task/{tid}/schedstat"))
}

fn schedstat(path: &str) -> Option<u64> {
    std::fs::read_to_string(path)
        .ok()?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

struct Run {
    c: BoardCampaign,
    rng: Rng,
    ctl: Option<Ctl>,
    seen: Arc<Mutex<Seen>>,
    report: BoardReport,
    resources: Resources,
    failures: Vec<String>,
    last_sample: Instant,
}

fn run(c: BoardCampaign) -> BoardOutcome {
    let seen = Arc::new(Mutex::new(Seen::default()));
    let stop = Arc::new(AtomicBool::new(false));
    let eyes = {
        let (d, b, s, st) = (
            c.domain.clone(),
            c.board.clone(),
            seen.clone(),
            stop.clone(),
        );
        std::thread::spawn(move || monitor(d, b, s, st))
    };
    let mut r = Run {
        rng: Rng::new(c.seed ^ 0x5C0E),
        report: BoardReport {
            subsystem: SUBSYSTEM.into(),
            link_corrupt: c.link_faults.0,
            link_drop: c.link_faults.1,
            watchdog_plus_tick_ms: (c.watchdog_ns + GATEWAY_LOOP_NS) as f64 / 1e6,
            ..BoardReport::default()
        },
        c,
        ctl: None,
        seen,
        resources: Resources::default(),
        failures: Vec::new(),
        last_sample: Instant::now(),
    };
    if let Err(e) = r.campaign() {
        r.failures.push(format!("{SUBSYSTEM}: {e}"));
    }
    if let Some(c) = r.ctl.take() {
        c.kill();
    }
    stop.store(true, Ordering::Relaxed);
    match eyes.join() {
        Ok(Ok(())) => {}
        Ok(Err(e)) => r.failures.push(format!("{SUBSYSTEM} monitor: {e}")),
        Err(_) => r.failures.push(format!("{SUBSYSTEM} monitor panicked")),
    }
    {
        let w = lock(&r.seen);
        r.report.samples_checked = w.samples;
        r.report.wrong_published = w.wrong;
        r.report.wrong_examples.extend(w.examples.iter().cloned());
        r.report.bad_setpoints_flagged = w.bad_flags;
    }
    {
        let b = r.c.board.record();
        r.report.frames_to_host = b.frames_out;
        r.report.damaged_to_host = b.damaged_out;
        r.report.damaged_to_board = b.damaged_in;
        r.report.rejected_by_board = b.rejected_in;
        r.report.accepted_by_board = b.accepted_in;
        r.report.writes_checked = b.writes;
        r.report.wrong_written = b.wrong_writes;
        r.report
            .wrong_examples
            .extend(b.wrong_examples.iter().cloned());
        r.report.handshakes = b.hellos;
        r.report.restores = b.restores;
        r.report.worst_board_lag_ms = b.worst_lag_ns as f64 / 1e6;
    }
    BoardOutcome {
        report: r.report,
        resources: r.resources,
        failures: r.failures,
    }
}

impl Run {
    fn campaign(&mut self) -> Result<(), String> {
        self.start_controller()?;
        'run: loop {
            let mut plan = EVENTS.to_vec();
            for i in (1..plan.len()).rev() {
                plan.swap(i, self.rng.below(i as u64 + 1) as usize);
            }
            for f in plan {
                if Instant::now() + Duration::from_secs(3) > self.c.end {
                    break 'run;
                }
                self.event(f);
                let gap = 300 + self.rng.below(700);
                self.idle(Duration::from_millis(gap));
            }
        }
        Ok(())
    }

    fn idle(&mut self, d: Duration) {
        let end = Instant::now() + d;
        while Instant::now() < end {
            if self.last_sample.elapsed() > Duration::from_secs(2) {
                self.last_sample = Instant::now();
                let t = self.c.started.elapsed().as_secs_f64();
                if let Some(pid) = gateway_pid(self.c.board.link()) {
                    if let Some((rss, fds)) = super::procs::usage(pid) {
                        self.resources
                            .sample(&format!("gateway {SUBSYSTEM}"), pid, t, rss, fds);
                    }
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn start_controller(&mut self) -> Result<(), String> {
        let seed = self.rng.next_u64();
        let ctl = start_ctl(
            &self.c.controller,
            self.c.domain.name(),
            self.c.rate_hz,
            seed,
        )
        .map_err(|e| format!("controller: {e}"))?;
        if !ctl.running(Duration::from_secs(30)) {
            ctl.kill();
            return Err("the board's controller did not start commanding within 30 s".into());
        }
        self.ctl = Some(ctl);
        Ok(())
    }

    /// Waits until every watched state has a sample published after `t` (ns).
    fn fresh_after(&self, t: u64, within: Duration) -> Option<u64> {
        let end = Instant::now() + within;
        while Instant::now() < end {
            if lock(&self.seen).fresh_ns.iter().all(|&f| f > t) {
                return Some(monotonic_ns());
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        None
    }

    fn event(&mut self, f: BoardFault) {
        eprintln!(
            "soak: at {:.3} s: {SUBSYSTEM}: {}",
            monotonic_ns() as f64 / 1e9,
            f.name()
        );
        let r = match f {
            BoardFault::Unplug => self.unplug(),
            BoardFault::GatewayKill => self.kill_gateway(),
            BoardFault::ControllerKill => self.controller_dies(false),
            BoardFault::ControllerStall => self.controller_dies(true),
            BoardFault::Flood => self.flood(),
        };
        self.report.injected(f);
        match r {
            Ok(ns) => self.report.recovered(f, ns),
            Err(why) => {
                let text = format!("{SUBSYSTEM}: {}: {why}", f.name());
                eprintln!("soak: {text}");
                self.failures.push(text);
            }
        }
    }

    fn unplug(&mut self) -> Result<u64, String> {
        let (hellos0, restores0) = {
            let b = self.c.board.record();
            (b.hellos, b.restores)
        };
        self.c.board.unplug();
        std::thread::sleep(Duration::from_millis(200 + self.rng.below(1300)));
        let back = monotonic_ns();
        self.c.board.replug();
        let done = self
            .fresh_after(back, Duration::from_secs(15))
            .ok_or("no fresh sample within 15 s of the replug")?;
        let b = self.c.board.record();
        let k = self.report.faults.entry(BoardFault::Unplug).or_default();
        // Counted: the gateway met the board again.
        k.counted += u64::from(b.hellos > hellos0);
        if b.restores == restores0 {
            return Err("the board came back empty and was not restored".into());
        }
        Ok(done - back)
    }

    fn kill_gateway(&mut self) -> Result<u64, String> {
        let link = self.c.board.link().to_path_buf();
        let pid = gateway_pid(&link).ok_or("no gateway running")?;
        let t = monotonic_ns();
        kill(Pid::from_raw(pid as i32), Signal::SIGKILL).map_err(|e| e.to_string())?;
        let done = self
            .fresh_after(t, Duration::from_secs(20))
            .ok_or("no fresh sample within 20 s of the kill")?;
        let now = gateway_pid(&link);
        if now == Some(pid) || now.is_none() {
            return Err("fresh samples but no new gateway".into());
        }
        self.report
            .faults
            .entry(BoardFault::GatewayKill)
            .or_default()
            .counted += 1;
        Ok(done - t)
    }

    /// The controller dies or stalls: both duties 0 within the watchdog + one gateway loop,
    /// kept at 0 until a controller commands again.
    fn controller_dies(&mut self, stall: bool) -> Result<u64, String> {
        let ctl = self.ctl.take().ok_or("no controller")?;
        // Its commands are reaching the board: some duty is not 0.
        let until = Instant::now() + Duration::from_secs(5);
        while self.c.board.record().all_off() {
            if Instant::now() > until {
                self.ctl = Some(ctl);
                return Err("the controller's duties do not reach the board".into());
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        lock(&self.seen).watchdog_flags = 0;
        let lost = |b: &score_rig::Record| b.damaged_in + b.damaged_replies;
        let lost0 = lost(&self.c.board.record());
        self.c.board.record().window_lag_ns = 0;
        let gw = gateway_pid(self.c.board.link());
        let tid = self.c.board.record().tid;
        let waited0 = gw.and_then(run_delay_ns);
        let board_waited0 = thread_run_delay_ns(tid);
        let t = monotonic_ns();
        kill(
            ctl.pid(),
            if stall {
                Signal::SIGSTOP
            } else {
                Signal::SIGKILL
            },
        )
        .map_err(|e| e.to_string())?;
        self.report.controller_deaths += 1;
        // Both duties at 0: when? A run of zeros that lasts 50 ms: a frame of the controller's
        // with both values below 0 % (clamped to 0) makes one moment of zeros, and a gateway
        // behind applies frames a few ms apart, so a moment is not the safe state.
        let wait_until =
            Instant::now() + Duration::from_nanos(self.c.watchdog_ns) + Duration::from_secs(5);
        let mut zeros: Option<(u64, u64, u64)> = None;
        let safe_at = loop {
            let b = self.c.board.record();
            if b.all_off() {
                if zeros.is_none() {
                    let at = b.duty.iter().map(|d| d.1).max().unwrap_or(0).max(t);
                    let first = b.duty.iter().map(|d| d.1).min().unwrap_or(0).max(t);
                    zeros = Some((at, b.last_nonzero_ns.max(t), first));
                }
            } else {
                zeros = None;
            }
            drop(b);
            if let Some(z) = zeros {
                if monotonic_ns().saturating_sub(z.0) >= 50_000_000 {
                    break Some(z);
                }
            }
            if Instant::now() > wait_until {
                break zeros;
            }
            std::thread::sleep(Duration::from_millis(1));
        };
        // Each request or answer lost on the link in the meantime costs the gateway one
        // resend (the safe `Set` may be among them), as a lost request costs the legs one retry:
        // `RESEND_AFTER`, seen at the end of one of its port reads (one loop).
        let lost_round_trips = lost(&self.c.board.record()) - lost0;
        // And the time the gateway waited for a CPU meanwhile (its run-queue delay, from
        // /proc) and the board's thread overslept: a starved process is late by that much.
        let delta = |a: Option<u64>, b: Option<u64>| match (a, b) {
            (Some(a), Some(b)) => b.saturating_sub(a),
            _ => 0,
        };
        let starved = delta(waited0, gw.and_then(run_delay_ns))
            + delta(board_waited0, thread_run_delay_ns(tid))
                .max(self.c.board.record().window_lag_ns);
        let limit = self.c.watchdog_ns
            + GATEWAY_LOOP_NS
            + 2_000_000
            + starved
            + lost_round_trips
                * (score_gateway::client::RESEND_AFTER.as_nanos() as u64 + GATEWAY_LOOP_NS);
        let mut result = Ok(());
        match safe_at {
            None => {
                self.report.unsafe_events += 1;
                result = Err("the duties never reached 0".to_string());
            }
            Some((s, last, first)) => {
                // The watchdog counts from the last command: the one that reached the board
                // (a gateway behind on a flood of commands applies them after the death).
                let took = s - last;
                self.report.worst_safe_ms = self.report.worst_safe_ms.max(took as f64 / 1e6);
                self.report.worst_safe_from_kill_ms = self
                    .report
                    .worst_safe_from_kill_ms
                    .max((s - t) as f64 / 1e6);
                if took <= limit {
                    self.report.safe_in_time += 1;
                } else {
                    result = Err(format!(
                        "duties at 0 {:.1} ms after the last command reached the board (the first at {:.1} ms; limit {:.1} ms: watchdog, one gateway loop, 2 ms, {} resends, {:.1} ms starved of CPU)",
                        took as f64 / 1e6,
                        first.saturating_sub(last) as f64 / 1e6,
                        limit as f64 / 1e6,
                        lost_round_trips,
                        starved as f64 / 1e6
                    ));
                }
            }
        }
        // Kept at 0 while nobody commands (and long enough for a flagged sample at the
        // gateway's lazy rate).
        let dead = Duration::from_millis(400 + self.rng.below(300));
        let end = Instant::now() + dead;
        while Instant::now() < end {
            if safe_at.is_some() && !self.c.board.record().all_off() {
                self.report.unsafe_events += 1;
                result = Err("a duty left 0 while no controller commanded".into());
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        self.idle(end.saturating_duration_since(Instant::now()));
        let tripped = lock(&self.seen).watchdog_flags > 0;
        if tripped {
            self.report.trips_seen += 1;
        } else {
            let text = format!(
                "{SUBSYSTEM}: {}: no sample flagged WATCHDOG while nobody commanded",
                if stall {
                    "controller SIGSTOP"
                } else {
                    "controller SIGKILL"
                }
            );
            eprintln!("soak: {text}");
        }
        let back = Instant::now();
        if stall {
            kill(ctl.pid(), Signal::SIGCONT).map_err(|e| e.to_string())?;
            self.ctl = Some(ctl);
        } else {
            ctl.kill();
            self.start_controller()?;
        }
        // Recovered once the duties move again.
        let until = Instant::now() + Duration::from_secs(10);
        while self.c.board.record().all_off() {
            if Instant::now() > until {
                return Err("no duty commanded within 10 s of the controller's return".into());
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        self.report
            .faults
            .entry(if stall {
                BoardFault::ControllerStall
            } else {
                BoardFault::ControllerKill
            })
            .or_default()
            .counted += u64::from(tripped);
        result.map(|_| back.elapsed().as_nanos() as u64)
    }

    fn flood(&mut self) -> Result<u64, String> {
        let link = self.c.board.link().to_path_buf();
        let pid = gateway_pid(&link);
        let ms = 100 + self.rng.below(200);
        let ctl = self.ctl.as_mut().ok_or("no controller")?;
        ctl.flood(ms);
        std::thread::sleep(Duration::from_millis(ms + 20));
        let t = monotonic_ns();
        let done = self
            .fresh_after(t, Duration::from_secs(10))
            .ok_or("no fresh sample within 10 s of a flood")?;
        if gateway_pid(&link) != pid {
            return Err("the gateway did not survive the flood".into());
        }
        Ok(done - t)
    }
}

/// Where the board's port link goes in the campaign's directory.
pub fn link_path(dir: &std::path::Path) -> PathBuf {
    dir.join("score-link")
}

/// Re-exported for the binary's sub-command.
pub use score_rig::manifest_section;
