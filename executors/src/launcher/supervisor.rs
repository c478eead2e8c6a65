//! The supervisor thread: spawns the executors and gateways, waits for the executors'
//! readiness, restarts crashed processes with back-off, draws the summary, and stops them in
//! order.

use std::collections::VecDeque;
use std::ffi::OsString;
use std::io::{BufRead, BufReader, IsTerminal, Write as _};
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc::{Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use conductor_bus::{Bus, Domain, StatsSubscriber};
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;

use super::{ExecutorInfo, LaunchError, LaunchOptions, LaunchReport, ProcessKind, SubsystemReport};
use crate::cleanup::scan_and_clean;
use crate::process::{EXIT_CONFIG, EXIT_NO_RT, READY};
use crate::signals::Stop;
use conductor_manifest::{GatewayDef, GatewayKind, ScoreGatewayArgs, ViewDef};

enum EventKind {
    /// The process reported ready; for a gateway, what its ready line said after its name.
    Ready(String),
}

struct Event {
    child: usize,
    generation: u64,
    kind: EventKind,
}

enum Phase {
    Starting { since: Instant },
    Running { since: Instant },
    Waiting { until: Instant, last: ExitStatus },
    Stopped,
}

/// What a supervised process runs.
enum Role {
    Executor,
    Gateway(GatewayDef),
    View(ViewDef),
}

impl Role {
    fn kind(&self) -> ProcessKind {
        match self {
            Role::Executor => ProcessKind::Executor,
            Role::Gateway(_) => ProcessKind::Gateway,
            Role::View(_) => ProcessKind::View,
        }
    }

    /// Gateways and the view: not waited for at start, given up (the robot runs on) when they
    /// cannot run or keep crashing.
    fn auxiliary(&self) -> bool {
        !matches!(self, Role::Executor)
    }

    /// How events name the process called `name`.
    fn label(&self, name: &str) -> String {
        match self {
            Role::Executor => format!("subsystem {name}"),
            Role::Gateway(_) => format!("gateway {name}"),
            Role::View(_) => "the view".into(),
        }
    }
}

/// The arguments of the view process (after [`LaunchOptions::view_args`]).
pub(super) fn view_args(v: &ViewDef, domain: &str) -> Vec<OsString> {
    let mut a: Vec<OsString> = vec![
        "--domain".into(),
        domain.into(),
        "--listen".into(),
        v.listen.to_string().into(),
    ];
    if v.clamp {
        a.push("--clamp".into());
    }
    a
}

/// One supervised process (an executor, a gateway or the view) across its restarts: what it runs,
/// its current process and phase, its crash history and its output's last lines.
struct Supervised {
    subsystem: String,
    role: Role,
    proc: Option<Child>,
    phase: Phase,
    generation: u64,
    crashes: VecDeque<Instant>,
    consecutive: u32,
    restarts: u32,
    tail: Arc<Mutex<VecDeque<String>>>,
    /// Forwards the executor's stderr; ends at EOF, i.e. once the process is gone.
    output: Option<JoinHandle<()>>,
    exit: Option<ExitStatus>,
    /// What the last ready line said (gateways: `<n> states`).
    ready_text: String,
    /// Why the launcher gave up on this gateway.
    failed: Option<String>,
}

impl Supervised {
    /// Waits (briefly) until everything the exited process wrote has been forwarded.
    fn drain_output(&mut self) {
        if let Some(t) = self.output.take() {
            let until = Instant::now() + Duration::from_secs(1);
            while !t.is_finished() && Instant::now() < until {
                std::thread::sleep(Duration::from_millis(5));
            }
            if t.is_finished() {
                let _ = t.join();
            }
        }
    }
}

pub(super) struct Supervisor {
    opts: LaunchOptions,
    manifest: PathBuf,
    domain: Domain,
    stop: Stop,
    info: Arc<Mutex<Vec<ExecutorInfo>>>,
    children: Vec<Supervised>,
    events: (Sender<Event>, Receiver<Event>),
}

const TAIL_LINES: usize = 12;
const POLL: Duration = Duration::from_millis(20);
/// A run this long resets the back-off.
const STABLE: Duration = Duration::from_secs(30);

/// The arguments of a gateway process (after [`LaunchOptions::gateway_args`]).
pub(super) fn gateway_args(g: &GatewayDef, domain: &str) -> Vec<OsString> {
    match g.kind {
        GatewayKind::Score => ScoreGatewayArgs::for_gateway(g, domain).to_args(),
        GatewayKind::Bridge => vec![
            "--manifest".into(),
            g.port.clone().into(),
            "--domain".into(),
            domain.into(),
        ],
    }
}

/// The program (and its leading arguments) that runs gateway `g`.
fn gateway_program<'a>(opts: &'a LaunchOptions, g: &GatewayDef) -> (&'a PathBuf, &'a [OsString]) {
    match g.kind {
        GatewayKind::Score => (&opts.gateway, &opts.gateway_args),
        GatewayKind::Bridge => (&opts.bridge, &opts.bridge_args),
    }
}

/// What follows the name in a gateway's `ready <subsystem> <what>` line (`3 states`).
pub(super) fn gateway_ready(line: &str) -> Option<String> {
    let rest = line.trim().strip_prefix("ready ")?;
    let (_, what) = rest.split_once(' ').unwrap_or((rest, ""));
    Some(what.to_string())
}

/// An executor's `READY` line.
fn executor_ready(line: &str) -> Option<String> {
    (line.trim() == READY).then(String::new)
}

/// In a forked child before `exec`: marks every descriptor above stderr close-on-exec, so the
/// program inherits only stdin, stdout and stderr. The launcher's process holds descriptors that
/// were opened without `O_CLOEXEC` (iceoryx2's node and port files of the launcher's own bus, and
/// in a program that launches in-process, whatever that program has open); without this, each
/// executor started after them would carry them for its whole life. Marked rather than closed:
/// std reports a failed `exec` through a close-on-exec pipe of its own.
///
/// Only async-signal-safe system calls (close_range(2), else fcntl(2) on each descriptor).
fn inherit_only_stdio() {
    // SAFETY: close_range(2) takes three integers and touches no memory of this process.
    let marked = unsafe {
        libc::syscall(
            libc::SYS_close_range,
            3 as libc::c_uint,
            libc::c_uint::MAX,
            libc::CLOSE_RANGE_CLOEXEC,
        )
    } == 0;
    if marked {
        return;
    }
    // Kernels before 5.11 lack CLOSE_RANGE_CLOEXEC: every possible descriptor, one by one.
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit(2) writes the struct it is given, which lives on this stack.
    let max = if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) } == 0 {
        limit.rlim_cur.min(1 << 20) as libc::c_int
    } else {
        1024
    };
    for fd in 3..max {
        // SAFETY: fcntl(2) on a descriptor number; one that is not open fails with EBADF.
        let flags = unsafe { libc::fcntl(fd, libc::F_GETFD) };
        if flags >= 0 && flags & libc::FD_CLOEXEC == 0 {
            // SAFETY: as above, on a descriptor that is open.
            unsafe { libc::fcntl(fd, libc::F_SETFD, flags | libc::FD_CLOEXEC) };
        }
    }
}

fn describe(status: &ExitStatus) -> String {
    match (status.code(), status.signal()) {
        (Some(c), _) => format!("exit status {c}"),
        (None, Some(s)) => format!(
            "killed by signal {}",
            Signal::try_from(s).map_or(s.to_string(), |s| s.as_str().to_string())
        ),
        _ => status.to_string(),
    }
}

impl Supervisor {
    pub(super) fn new(
        opts: LaunchOptions,
        manifest: PathBuf,
        domain: Domain,
        stop: Stop,
        info: Arc<Mutex<Vec<ExecutorInfo>>>,
    ) -> Self {
        Self {
            opts,
            manifest,
            domain,
            stop,
            info,
            children: Vec::new(),
            events: std::sync::mpsc::channel(),
        }
    }

    pub(super) fn run(
        mut self,
        subsystems: Vec<String>,
        gateways: Vec<GatewayDef>,
        view: Option<ViewDef>,
        ready: Sender<()>,
    ) -> Result<LaunchReport, LaunchError> {
        let roles = subsystems
            .into_iter()
            .map(|s| (s, Role::Executor))
            .chain(
                gateways
                    .into_iter()
                    .map(|g| (g.name.clone(), Role::Gateway(g))),
            )
            .chain(view.map(|v| ("view".to_string(), Role::View(v))));
        for (s, role) in roles {
            self.children.push(Supervised {
                subsystem: s,
                role,
                proc: None,
                phase: Phase::Stopped,
                generation: 0,
                crashes: VecDeque::new(),
                consecutive: 0,
                restarts: 0,
                tail: Arc::new(Mutex::new(VecDeque::new())),
                output: None,
                exit: None,
                ready_text: String::new(),
                failed: None,
            });
        }
        // Start everything and wait for every executor's READY (not for the gateways).
        for i in 0..self.children.len() {
            if let Err(e) = self.spawn(i) {
                let _ = self.stop_all();
                return Err(e);
            }
        }
        if let Err(e) = self.await_initial_readiness() {
            let _ = self.stop_all();
            return Err(e);
        }
        let _ = ready.send(());
        drop(ready);
        let result = self.supervise();
        let stopped = self.stop_all();
        result.and(stopped)
    }

    fn spawn(&mut self, i: usize) -> Result<(), LaunchError> {
        let c = &mut self.children[i];
        c.generation += 1;
        let mut cmd = match &c.role {
            Role::Executor => {
                let mut cmd = Command::new(&self.opts.executor);
                cmd.args(&self.opts.executor_args)
                    .arg("--manifest")
                    .arg(&self.manifest)
                    .arg("--subsystem")
                    .arg(&c.subsystem)
                    .arg("--domain")
                    .arg(self.domain.name());
                if self.opts.no_rt {
                    cmd.arg("--no-rt");
                }
                cmd
            }
            Role::Gateway(g) => {
                let (program, args) = gateway_program(&self.opts, g);
                let mut cmd = Command::new(program);
                cmd.args(args).args(gateway_args(g, self.domain.name()));
                cmd
            }
            Role::View(v) => {
                let mut cmd = Command::new(&self.opts.view);
                cmd.args(&self.opts.view_args)
                    .args(view_args(v, self.domain.name()));
                cmd
            }
        };
        cmd.stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            // Its own process group: a terminal's Ctrl-C reaches only the launcher, which
            // forwards it once.
            .process_group(0);
        let gateway = c.role.auxiliary();
        // SAFETY: the closure runs in the forked child before exec and only makes the
        // async-signal-safe sigprocmask(2), close_range(2)/fcntl(2) and prctl(2) system calls.
        unsafe {
            cmd.pre_exec(move || {
                if gateway {
                    // A launcher that takes SIGINT/SIGTERM with sigwait has them blocked, and the
                    // mask survives exec. An executor takes them the same way (so one arriving
                    // while it starts waits for it); a gateway has ordinary handlers, which a
                    // blocked signal would never reach.
                    nix::sys::signal::pthread_sigmask(
                        nix::sys::signal::SigmaskHow::SIG_SETMASK,
                        Some(&nix::sys::signal::SigSet::empty()),
                        None,
                    )
                    .map_err(std::io::Error::from)?;
                }
                inherit_only_stdio();
                // The child stops (orderly) if the launcher dies.
                nix::sys::prctl::set_pdeathsig(Signal::SIGTERM).map_err(std::io::Error::from)
            });
        }
        let mut child = cmd.spawn().map_err(|source| match &c.role {
            Role::Executor => LaunchError::Spawn {
                subsystem: c.subsystem.clone(),
                program: self.opts.executor.clone(),
                source,
            },
            Role::Gateway(g) => LaunchError::SpawnGateway {
                gateway: c.subsystem.clone(),
                program: gateway_program(&self.opts, g).0.clone(),
                source,
            },
            Role::View(_) => LaunchError::SpawnView {
                program: self.opts.view.clone(),
                source,
            },
        })?;
        let stdout = child.stdout.take().expect("piped");
        let stderr = child.stderr.take().expect("piped");
        let (tx, generation) = (self.events.0.clone(), c.generation);
        let ready_line = match c.role {
            Role::Executor => executor_ready,
            // `ready view ws://…`, like a gateway's `ready <name> …`.
            Role::Gateway(_) | Role::View(_) => gateway_ready,
        };
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if let Some(what) = ready_line(&line) {
                    let _ = tx.send(Event {
                        child: i,
                        generation,
                        kind: EventKind::Ready(what),
                    });
                }
            }
        });
        let tail = c.tail.clone();
        if let Ok(mut t) = c.tail.lock() {
            t.clear();
        }
        c.output = Some(std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                note!("{line}");
                if let Ok(mut t) = tail.lock() {
                    if t.len() == TAIL_LINES {
                        t.pop_front();
                    }
                    t.push_back(line);
                }
            }
        }));
        let pid = child.id();
        c.proc = Some(child);
        c.phase = Phase::Starting {
            since: Instant::now(),
        };
        match &c.role {
            Role::Gateway(g) if g.kind == GatewayKind::Bridge => {
                note!(
                    "conductor: bridge started (pid {pid}) for {}",
                    g.port.display()
                )
            }
            Role::Gateway(g) => note!(
                "conductor: gateway {} started (pid {pid}), waiting for its board on {}",
                c.subsystem,
                g.port.display()
            ),
            Role::Executor | Role::View(_) => {}
        }
        self.set_info(i, Some(pid), false);
        Ok(())
    }

    fn set_info(&self, i: usize, pid: Option<u32>, ready: bool) {
        if let Ok(mut v) = self.info.lock() {
            v[i].pid = pid;
            v[i].ready = ready;
            v[i].restarts = self.children[i].restarts;
            v[i].failed = self.children[i].failed.clone();
        }
    }

    /// Stops restarting gateway `i` (it cannot run or keeps crashing); the robot runs on.
    fn give_up(&mut self, i: usize, reason: String) {
        let c = &mut self.children[i];
        c.phase = Phase::Stopped;
        c.drain_output();
        note!(
            "conductor: giving up on {}: {reason}; the rest of the robot runs on{}",
            self.children[i].role.label(&self.children[i].subsystem),
            super::tail_text(&self.tail(i))
        );
        self.children[i].failed = Some(reason);
        self.set_info(i, None, false);
    }

    fn tail(&self, i: usize) -> Vec<String> {
        self.children[i]
            .tail
            .lock()
            .map(|t| t.iter().cloned().collect())
            .unwrap_or_default()
    }

    fn handle_events(&mut self) {
        while let Ok(ev) = self.events.1.try_recv() {
            let c = &mut self.children[ev.child];
            if ev.generation != c.generation {
                continue;
            }
            match ev.kind {
                EventKind::Ready(what) => {
                    if matches!(c.phase, Phase::Starting { .. }) {
                        c.phase = Phase::Running {
                            since: Instant::now(),
                        };
                        let pid = c.proc.as_ref().map(Child::id);
                        let pid = pid.map_or("?".into(), |p| p.to_string());
                        match &c.role {
                            Role::Executor => {
                                note!("conductor: subsystem {} ready (pid {pid})", c.subsystem)
                            }
                            Role::Gateway(g) if g.kind == GatewayKind::Bridge => {
                                note!("conductor: bridge ready (pid {pid}): {what}")
                            }
                            Role::Gateway(g) => note!(
                                "conductor: gateway {} ready (pid {pid}): {what} from {}",
                                c.subsystem,
                                g.port.display()
                            ),
                            Role::View(_) => {
                                note!("conductor: view ready (pid {pid}): open {what} in Foxglove")
                            }
                        }
                        c.ready_text = what;
                        let pid = c.proc.as_ref().map(Child::id);
                        self.set_info(ev.child, pid, true);
                    }
                }
            }
        }
    }

    fn await_initial_readiness(&mut self) -> Result<(), LaunchError> {
        loop {
            self.handle_events();
            for i in 0..self.children.len() {
                let c = &mut self.children[i];
                // Gateways are supervised from the start but not waited for.
                let (Phase::Starting { since }, Role::Executor) = (&c.phase, &c.role) else {
                    continue;
                };
                let since = *since;
                if let Some(status) = c.proc.as_mut().and_then(|p| p.try_wait().ok().flatten()) {
                    c.proc = None;
                    c.phase = Phase::Stopped;
                    c.drain_output();
                    let code = status.code().map(|c| c as u8);
                    let output = self.tail(i);
                    let subsystem = self.children[i].subsystem.clone();
                    return Err(if matches!(code, Some(EXIT_CONFIG) | Some(EXIT_NO_RT)) {
                        LaunchError::CannotRun {
                            subsystem,
                            status: describe(&status),
                            output,
                        }
                    } else {
                        LaunchError::NotReady {
                            subsystem,
                            status: describe(&status),
                            output,
                        }
                    });
                }
                if since.elapsed() > self.opts.ready_timeout {
                    return Err(LaunchError::NotReady {
                        subsystem: c.subsystem.clone(),
                        status: format!("no READY within {:?}", self.opts.ready_timeout),
                        output: self.tail(i),
                    });
                }
            }
            if self
                .children
                .iter()
                .all(|c| c.role.auxiliary() || matches!(c.phase, Phase::Running { .. }))
            {
                return Ok(());
            }
            if self.stop.requested() {
                return Err(LaunchError::NotReady {
                    subsystem: "(all)".into(),
                    status: "stop requested during start-up".into(),
                    output: Vec::new(),
                });
            }
            std::thread::sleep(POLL);
        }
    }

    fn supervise(&mut self) -> Result<(), LaunchError> {
        let bus = Bus::open(&self.domain, "launcher").ok();
        let mut stats: Vec<Option<StatsSubscriber>> = self
            .children
            .iter()
            .map(|c| match c.role {
                Role::Executor => bus
                    .as_ref()
                    .and_then(|b| StatsSubscriber::new(b, &c.subsystem).ok()),
                // A gateway or the view publishes no executor stats.
                Role::Gateway(_) | Role::View(_) => None,
            })
            .collect();
        let tty = std::io::stderr().is_terminal();
        let interval = self.opts.summary_interval.unwrap_or(if tty {
            Duration::from_secs(1)
        } else {
            Duration::from_secs(10)
        });
        let mut next_summary = Instant::now() + interval;
        let mut drawn = 0usize;
        while !self.stop.requested() {
            self.handle_events();
            let now = Instant::now();
            for i in 0..self.children.len() {
                self.check_child(i, now)?;
            }
            if !self.opts.quiet && now >= next_summary {
                if let Some(bus) = &bus {
                    let lines = self.summary(bus, &mut stats);
                    let mut err = std::io::stderr().lock();
                    if tty && drawn > 0 {
                        // Redraw the previous block in place.
                        let _ = write!(err, "\x1b[{drawn}A");
                    }
                    for l in &lines {
                        let _ = writeln!(err, "{l}{}", if tty { "\x1b[K" } else { "" });
                    }
                    drawn = lines.len();
                }
                next_summary = now + interval;
            }
            std::thread::sleep(POLL);
        }
        Ok(())
    }

    fn check_child(&mut self, i: usize, now: Instant) -> Result<(), LaunchError> {
        match self.children[i].phase {
            Phase::Waiting { until, last } => {
                if now >= until {
                    // Whatever the dead process left behind must go before its successor starts.
                    let _ = scan_and_clean(&self.domain);
                    let c = &mut self.children[i];
                    c.restarts += 1;
                    note!(
                        "conductor: restarting {} (restart {}, after {})",
                        c.role.label(&c.subsystem),
                        c.restarts,
                        describe(&last)
                    );
                    match self.spawn(i) {
                        Ok(()) => {}
                        Err(e) if self.children[i].role.auxiliary() => {
                            self.give_up(i, e.to_string())
                        }
                        Err(e) => return Err(e),
                    }
                }
                return Ok(());
            }
            Phase::Stopped => return Ok(()),
            Phase::Starting { since } => {
                let waited = now.duration_since(since);
                match self.children[i].role {
                    Role::Executor if waited > self.opts.ready_timeout => {
                        // Hung before READY: treat it as a crash.
                        if let Some(p) = self.children[i].proc.as_mut() {
                            let _ = p.kill();
                        }
                    }
                    // A gateway waiting this long for its board is not crashing.
                    Role::Gateway(_) | Role::View(_) if waited > STABLE => {
                        self.children[i].consecutive = 0
                    }
                    _ => {}
                }
            }
            Phase::Running { since } if now.duration_since(since) > STABLE => {
                self.children[i].consecutive = 0;
            }
            _ => {}
        }
        let c = &mut self.children[i];
        let Some(status) = c.proc.as_mut().and_then(|p| p.try_wait().ok().flatten()) else {
            return Ok(());
        };
        c.proc = None;
        let code = status.code().map(|c| c as u8);
        let gateway = c.role.auxiliary();
        if gateway && code == Some(EXIT_CONFIG) {
            self.give_up(i, format!("it cannot run ({})", describe(&status)));
            return Ok(());
        }
        if matches!(code, Some(EXIT_CONFIG) | Some(EXIT_NO_RT)) {
            c.phase = Phase::Stopped;
            c.drain_output();
            self.set_info(i, None, false);
            return Err(LaunchError::CannotRun {
                subsystem: self.children[i].subsystem.clone(),
                status: describe(&status),
                output: self.tail(i),
            });
        }
        // A crash (or an exit nobody asked for): restart with back-off, within bounds.
        let window = self.opts.restart_window;
        c.crashes.push_back(now);
        while c
            .crashes
            .front()
            .is_some_and(|t| now.duration_since(*t) > window)
        {
            c.crashes.pop_front();
        }
        if c.crashes.len() as u32 > self.opts.max_restarts {
            let crashes = c.crashes.len() as u32;
            if gateway {
                self.give_up(
                    i,
                    format!(
                        "it crashed {crashes} times within {window:?} (last: {})",
                        describe(&status)
                    ),
                );
                return Ok(());
            }
            c.phase = Phase::Stopped;
            c.drain_output();
            return Err(LaunchError::TooManyRestarts {
                subsystem: self.children[i].subsystem.clone(),
                crashes,
                window,
                status: describe(&status),
                output: self.tail(i),
            });
        }
        c.consecutive += 1;
        let delay = self
            .opts
            .backoff
            .saturating_mul(1 << (c.consecutive - 1).min(16))
            .min(self.opts.backoff_max);
        note!(
            "conductor: {} stopped unexpectedly ({}); restarting in {:?}",
            c.role.label(&c.subsystem),
            describe(&status),
            delay
        );
        c.phase = Phase::Waiting {
            until: now + delay,
            last: status,
        };
        self.set_info(i, None, false);
        Ok(())
    }

    fn summary(&self, bus: &Bus, stats: &mut [Option<StatsSubscriber>]) -> Vec<String> {
        let mut lines = Vec::new();
        for (i, c) in self.children.iter().enumerate() {
            match &c.role {
                Role::Gateway(g) => {
                    lines.push(gateway_summary(c, g));
                    continue;
                }
                Role::View(v) => {
                    lines.push(view_summary(c, v));
                    continue;
                }
                Role::Executor => {}
            }
            if stats[i].is_none() {
                stats[i] = StatsSubscriber::new(bus, &c.subsystem).ok();
            }
            let s = stats[i].as_mut().and_then(|s| s.latest().ok().flatten());
            let state = match c.phase {
                Phase::Running { .. } => "",
                Phase::Starting { .. } => " (starting)",
                Phase::Waiting { .. } => " (restarting)",
                Phase::Stopped => " (stopped)",
            };
            lines.push(match s {
                Some(s) => format!(
                    "conductor: {:<16} {:>9.1} Hz of {}  lateness p99 {:>7.1} µs  max {:>8.1} µs  \
                     misses {}  bus errors {}  restarts {}{state}",
                    c.subsystem,
                    s.achieved_rate_hz,
                    s.base_rate_hz,
                    s.lateness_p99_ns as f64 / 1e3,
                    s.lateness_max_ns as f64 / 1e3,
                    s.misses,
                    s.bus_errors,
                    c.restarts
                ),
                None => format!("conductor: {:<16} (no stats yet){state}", c.subsystem),
            });
        }
        lines
    }

    /// Stops every executor and gateway (forwarding the signal that asked for it), waits, kills
    /// stragglers, removes what they left behind.
    fn stop_all(&mut self) -> Result<LaunchReport, LaunchError> {
        let sig = Signal::try_from(self.stop.signal()).unwrap_or(Signal::SIGTERM);
        for c in &self.children {
            if let Some(p) = &c.proc {
                let _ = kill(Pid::from_raw(p.id() as i32), sig);
            }
        }
        let deadline = Instant::now() + self.opts.stop_timeout;
        let mut failures = Vec::new();
        for c in &mut self.children {
            let Some(mut p) = c.proc.take() else { continue };
            let status = loop {
                match p.try_wait() {
                    Ok(Some(s)) => break Some(s),
                    Ok(None) if Instant::now() < deadline => std::thread::sleep(POLL),
                    _ => {
                        let _ = p.kill();
                        failures.push(format!(
                            "{}: did not stop within {:?}, killed",
                            c.subsystem, self.opts.stop_timeout
                        ));
                        break p.wait().ok();
                    }
                }
            };
            c.drain_output();
            if let Some(s) = status {
                if !s.success() && !failures.iter().any(|f| f.starts_with(&c.subsystem)) {
                    failures.push(format!("{}: {}", c.subsystem, describe(&s)));
                }
                c.exit = Some(s);
            }
            c.phase = Phase::Stopped;
        }
        for c in &self.children {
            if let Some(why) = &c.failed {
                failures.push(format!("{}: given up: {why}", c.role.label(&c.subsystem)));
            }
        }
        let _ = scan_and_clean(&self.domain);
        for i in 0..self.children.len() {
            self.set_info(i, None, false);
        }
        let gateways = self
            .children
            .iter()
            .filter(|c| matches!(c.role, Role::Gateway(_)))
            .count();
        let executors = self
            .children
            .iter()
            .filter(|c| matches!(c.role, Role::Executor))
            .count();
        let view = if self
            .children
            .iter()
            .any(|c| matches!(c.role, Role::View(_)))
        {
            " and the view"
        } else {
            ""
        };
        match (gateways, view.is_empty()) {
            (0, _) => note!("conductor: {executors} executor(s){view} stopped"),
            (g, true) => note!("conductor: {executors} executor(s) and {g} gateway(s) stopped"),
            (g, false) => note!("conductor: {executors} executor(s), {g} gateway(s){view} stopped"),
        }
        if !failures.is_empty() {
            return Err(LaunchError::Unclean { failures });
        }
        Ok(LaunchReport {
            domain: self.domain.name().into(),
            subsystems: self
                .children
                .iter()
                .map(|c| SubsystemReport {
                    subsystem: c.subsystem.clone(),
                    kind: c.role.kind(),
                    restarts: c.restarts,
                    exit_code: c.exit.and_then(|s| s.code()),
                })
                .collect(),
        })
    }
}

/// A gateway's summary line: its board, what it publishes, restarts, and what it is doing.
fn gateway_summary(c: &Supervised, g: &GatewayDef) -> String {
    let state = match (&c.phase, &c.failed) {
        (_, Some(why)) => format!(" (given up: {why})"),
        (Phase::Running { .. }, _) => String::new(),
        (Phase::Starting { .. }, _) => " (waiting for its board)".into(),
        (Phase::Waiting { .. }, _) => " (restarting)".into(),
        (Phase::Stopped, _) => " (stopped)".into(),
    };
    let what = if c.ready_text.is_empty() {
        String::new()
    } else {
        format!("{}  ", c.ready_text)
    };
    format!(
        "conductor: {:<16} {} gateway on {}  {what}restarts {}{state}",
        c.subsystem,
        g.kind.name(),
        g.port.display(),
        c.restarts
    )
}

/// The view's summary line: where it listens, restarts, and what it is doing.
fn view_summary(c: &Supervised, v: &ViewDef) -> String {
    let state = match (&c.phase, &c.failed) {
        (_, Some(why)) => format!(" (given up: {why})"),
        (Phase::Running { .. }, _) => String::new(),
        (Phase::Starting { .. }, _) => " (starting)".into(),
        (Phase::Waiting { .. }, _) => " (restarting)".into(),
        (Phase::Stopped, _) => " (stopped)".into(),
    };
    let url = if c.ready_text.is_empty() {
        format!("ws://{}", v.listen)
    } else {
        c.ready_text.clone()
    };
    format!(
        "conductor: {:<16} Foxglove view on {url}  restarts {}{state}",
        c.subsystem, c.restarts
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use conductor_manifest::GatewayOptions;

    fn def() -> GatewayDef {
        GatewayDef {
            name: "board".into(),
            kind: GatewayKind::Score,
            port: "/dev/score-link".into(),
            options: GatewayOptions::default(),
        }
    }

    fn strings(a: Vec<OsString>) -> Vec<String> {
        a.into_iter().map(|s| s.into_string().unwrap()).collect()
    }

    #[test]
    fn gateway_arguments_carry_only_what_the_manifest_sets() {
        assert_eq!(
            strings(gateway_args(&def(), "d1")),
            [
                "--port",
                "/dev/score-link",
                "--subsystem",
                "board",
                "--domain",
                "d1"
            ]
        );
        let g = GatewayDef {
            options: GatewayOptions {
                max_rate_hz: Some(500.0),
                lazy_rate_hz: Some(2.5),
                restore: false,
                retry_ms: Some(50),
                watchdog_ms: Some(250),
            },
            ..def()
        };
        assert_eq!(
            strings(gateway_args(&g, "d1"))[6..],
            [
                "--max-rate",
                "500",
                "--lazy-rate",
                "2.5",
                "--no-restore",
                "--retry-ms",
                "50",
                "--watchdog-ms",
                "250"
            ]
        );
    }

    #[test]
    fn view_arguments() {
        let v = ViewDef::default();
        assert_eq!(
            strings(view_args(&v, "d1")),
            ["--domain", "d1", "--listen", "127.0.0.1:8765"]
        );
        let v = ViewDef {
            listen: "0.0.0.0:9000".parse().unwrap(),
            clamp: true,
        };
        assert_eq!(
            strings(view_args(&v, "d1"))[3..],
            ["0.0.0.0:9000", "--clamp"]
        );
        assert_eq!(
            gateway_ready("ready view ws://127.0.0.1:8765").as_deref(),
            Some("ws://127.0.0.1:8765")
        );
    }

    #[test]
    fn ready_lines() {
        assert_eq!(
            gateway_ready("ready board 3 states\n").as_deref(),
            Some("3 states")
        );
        assert_eq!(gateway_ready("ready board").as_deref(), Some(""));
        assert_eq!(gateway_ready("score-gateway: ready soon"), None);
        assert_eq!(gateway_ready("READY"), None);
        assert_eq!(executor_ready(" READY\n").as_deref(), Some(""));
        assert_eq!(executor_ready("ready board 3 states"), None);
    }
}
