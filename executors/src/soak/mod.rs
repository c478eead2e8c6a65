//! `conductor-soak`: a fault campaign on the simulated robots of deploy/.
//!
//! The mini-Hubo leg on its Dynamixel bus and the quadruped leg on MIT motors behind an SLCAN
//! adapter (the shipped manifests, pointed at in-process simulators on pseudo-terminals) run
//! under the launcher while, for a chosen time:
//!
//! * every bus corrupts and drops bytes (0.5 % each by default, 1 % of the bytes damaged;
//!   see [`rig`] for where);
//! * a controller process per robot commands it at 1 kHz, now and then with values out of
//!   limits, NaN or infinite;
//! * one at a time, at random, per robot: the adapter is unplugged and plugged back, the
//!   executor is SIGKILLed (the launcher restarts it), the controller is SIGKILLed or stopped
//!   with SIGSTOP (its clock stalls: the executor's watchdog must fire) and a new one started
//!   or the old one continued, or the controller floods command frames back to back.
//!
//! [`monitor`] checks, from outside the executors, every published value and every value
//! the devices received, the safe state after each controller death, and the counters; the
//! campaign measures each recovery and what the processes and the domain hold. The result is
//! one [`Report`]: a table and JSON.

pub mod cli;
pub mod controller;
pub mod episode;
pub mod monitor;
pub mod procs;
pub mod report;
pub mod rig;
pub mod score_campaign;
pub mod score_rig;

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::atomic::AtomicBool;
use std::sync::mpsc::{channel, Receiver};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use conductor_bus::{monotonic_ns, Domain};
use conductor_devices::sim::fault::Rng;
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;

use crate::launcher::{Launch, LaunchOptions};
use monitor::{lock, Watched};
pub use report::{Fault, Report};
use rig::Robot;

/// How to run a campaign.
#[derive(Debug, Clone)]
pub struct Options {
    /// How long.
    pub duration: Duration,
    /// Seed of the faults and of their schedule.
    pub seed: u64,
    /// Probability that a byte on a wire is corrupted.
    pub corrupt: f64,
    /// Probability that a byte on a wire is lost.
    pub drop: f64,
    /// Command frames per second of each controller.
    pub rate_hz: f64,
    /// The workspace root (deploy/ is read from there).
    pub root: PathBuf,
    /// The executor program.
    pub executor: PathBuf,
    /// Arguments before the executor's own (a program that runs itself as the executor).
    pub executor_args: Vec<std::ffi::OsString>,
    /// The program (and its arguments) that runs a controller: it gets the controller's own
    /// arguments after these.
    pub controller: Vec<String>,
    /// The kinds of faults injected one at a time (default [`EVENTS`]: all of them); byte
    /// faults and bad setpoints are always on.
    pub faults: Vec<Fault>,
    /// Run as in production: the executors with their manifests' real-time settings, the
    /// campaign's own threads (simulators, monitor) `SCHED_FIFO` just below them, so that other
    /// work on the machine does not decide the result. Off: everything at normal scheduling.
    pub rt: bool,
    /// The Score board: its programs and its link's byte faults. `None`: the legs only.
    pub board: Option<BoardOptions>,
}

/// The Score board's part (see [`score_campaign`]).
#[derive(Debug, Clone)]
pub struct BoardOptions {
    /// Its controller, before the controller's own arguments.
    pub controller: Vec<String>,
    /// The gateway (`score-gateway`, or a program running its main), before its arguments.
    pub gateway: Vec<String>,
    /// Probability that a byte on the board's USB link is corrupted.
    pub corrupt: f64,
    /// Probability that a byte on the board's USB link is lost.
    pub drop: f64,
}

/// The `SCHED_FIFO` priority of the campaign's threads (simulators, monitor): below the
/// executors' (80 in deploy/), above everything else.
pub const SOAK_PRIORITY: i32 = 70;

/// The kinds of faults injected on purpose, one at a time.
pub const EVENTS: [Fault; 5] = [
    Fault::Unplug,
    Fault::ExecutorKill,
    Fault::ControllerKill,
    Fault::ControllerStall,
    Fault::Flood,
];

/// A controller process (a robot's here, the Score board's in [`score_campaign`]).
struct Ctl {
    child: Child,
    stdin: ChildStdin,
    lines: Receiver<String>,
}

impl Ctl {
    /// The controller `program` (its path, then arguments of its own) as a command.
    fn command(program: &[String]) -> std::io::Result<Command> {
        let (prog, pre) = program
            .split_first()
            .ok_or_else(|| std::io::Error::other("no controller program"))?;
        let mut cmd = Command::new(prog);
        cmd.args(pre);
        Ok(cmd)
    }

    /// Starts `cmd` with its stdin open for requests and its stdout lines on a channel.
    fn spawn(cmd: &mut Command) -> std::io::Result<Ctl> {
        let mut child = cmd.stdin(Stdio::piped()).stdout(Stdio::piped()).spawn()?;
        let stdin = child.stdin.take().expect("piped");
        let out = child.stdout.take().expect("piped");
        let (tx, lines) = channel();
        std::thread::spawn(move || {
            for l in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send(l).is_err() {
                    break;
                }
            }
        });
        Ok(Ctl {
            child,
            stdin,
            lines,
        })
    }

    fn start(o: &Options, robot: &Robot, domain: &str, seed: u64) -> std::io::Result<Ctl> {
        let mut cmd = Self::command(&o.controller)?;
        cmd.args(["--domain", domain, "--subsystem", &robot.subsystem])
            .args([
                "--rate-hz",
                &o.rate_hz.to_string(),
                "--seed",
                &seed.to_string(),
            ]);
        for j in &robot.joints {
            cmd.args(["--joint", &j.to_arg()]);
        }
        Self::spawn(&mut cmd)
    }

    fn pid(&self) -> Pid {
        Pid::from_raw(self.child.id() as i32)
    }

    /// Waits for its next `running` line.
    fn running(&self, within: Duration) -> bool {
        let end = Instant::now() + within;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            match self.lines.recv_timeout(left) {
                Ok(l) if l == "running" => return true,
                Ok(_) => {}
                Err(_) => return false,
            }
        }
        false
    }

    fn flood(&mut self, ms: u64) {
        let _ = writeln!(self.stdin, "flood {ms}");
        let _ = self.stdin.flush();
    }

    fn kill(mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// One robot in the campaign.
struct Member {
    /// Controller deaths so far.
    deaths: u64,
    robot: Arc<Robot>,
    watched: Arc<Mutex<Watched>>,
    ctl: Option<Ctl>,
    tally: report::Tally,
}

/// What the campaign holds while it runs.
struct Campaign<'a> {
    o: &'a Options,
    launch: Launch,
    domain: Domain,
    members: Vec<Member>,
    rng: Rng,
    resources: report::Resources,
    failures: Vec<String>,
    last_sample: Instant,
    started: Instant,
}

/// Runs a campaign.
pub fn run(o: &Options) -> Result<Report, String> {
    let dir = std::env::temp_dir().join(format!("conductor-soak-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let result = run_in(o, &dir);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// Puts the calling thread, and the threads it starts from now on, at `SCHED_FIFO`
/// `priority` (`Some`) or back at normal scheduling (`None`).
pub fn realtime_threads(priority: Option<i32>) -> std::io::Result<()> {
    let (policy, p) = match priority {
        Some(p) => (libc::SCHED_FIFO, p),
        None => (libc::SCHED_OTHER, 0),
    };
    let p = libc::sched_param { sched_priority: p };
    // SAFETY: a valid sched_param for the calling thread (pid 0).
    let r = unsafe { libc::sched_setscheduler(0, policy, &p) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

fn run_in(o: &Options, dir: &std::path::Path) -> Result<Report, String> {
    if o.rt {
        // The simulators' and the monitor's threads inherit it; the launcher's and the
        // controllers' (started once this thread is back at normal scheduling) do not.
        realtime_threads(Some(SOAK_PRIORITY)).map_err(|e| {
            format!("SCHED_FIFO for the campaign's threads: {e} (run as root, give CAP_SYS_NICE, or use --no-rt)")
        })?;
    }
    let dxl_link = dir.join("dxl0");
    let can_link = dir.join("can0");
    let io = |e: std::io::Error| e.to_string();
    let dxl = Robot::dynamixel(&dxl_link, o.corrupt, o.drop, o.seed).map_err(io)?;
    let can = Robot::mit_slcan(&can_link, o.corrupt, o.drop, o.seed ^ 0xCA).map_err(io)?;
    let manifest = dir.join("soak.toml");
    let mut text = rig::manifest(&o.root, &dxl_link, &can_link).map_err(io)?;
    // The Score board: its simulator on a pty and the gateway table of deploy/score-board.toml.
    let board = match &o.board {
        Some(b) => {
            let link = score_campaign::link_path(dir);
            text.push_str(&score_rig::manifest_section(&o.root, &link).map_err(io)?);
            let sim =
                score_rig::BoardSim::start(&link, b.corrupt, b.drop, o.seed ^ 0x5C).map_err(io)?;
            Some(Arc::new(sim))
        }
        None => None,
    };
    std::fs::write(&manifest, text).map_err(io)?;
    let domain = Domain::unique("soak").map_err(|e| e.to_string())?;
    let members: Vec<Member> = [dxl, can]
        .into_iter()
        .map(|r| Member {
            deaths: 0,
            tally: report::Tally::new(&r),
            robot: Arc::new(r),
            watched: Arc::new(Mutex::new(Watched::default())),
            ctl: None,
        })
        .collect();
    // Watching starts before the launch: bring-up writes to the devices too.
    let stop = Arc::new(AtomicBool::new(false));
    let eyes = monitor::spawn(
        domain.clone(),
        members
            .iter()
            .map(|m| (m.robot.clone(), m.watched.clone()))
            .collect(),
        stop.clone(),
    );
    if o.rt {
        realtime_threads(None).map_err(|e| format!("normal scheduling again: {e}"))?;
    }
    let launch = Launch::start(
        &manifest,
        LaunchOptions {
            executor: o.executor.clone(),
            executor_args: o.executor_args.clone(),
            domain: Some(domain.name().into()),
            no_rt: !o.rt,
            quiet: true,
            handle_signals: false,
            backoff: Duration::from_millis(50),
            backoff_max: Duration::from_millis(500),
            // Only the campaign's kills (a few a minute) are expected; a crash of its own
            // shows as a restart the campaign did not cause.
            max_restarts: 50,
            gateway: o
                .board
                .as_ref()
                .map_or_else(crate::launcher::default_gateway, |b| {
                    b.gateway[0].clone().into()
                }),
            gateway_args: o.board.as_ref().map_or_else(Vec::new, |b| {
                b.gateway[1..].iter().map(Into::into).collect()
            }),
            ..LaunchOptions::default()
        },
    );
    let launch = match launch {
        Ok(l) => l,
        Err(e) => {
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
            let _ = eyes.join();
            return Err(format!("launch: {e}"));
        }
    };
    let mut c = Campaign {
        o,
        launch,
        domain,
        members,
        rng: Rng::new(o.seed ^ 0x50AC),
        resources: report::Resources::default(),
        failures: Vec::new(),
        last_sample: Instant::now(),
        started: Instant::now(),
    };
    let board_run = match (&board, &o.board) {
        (Some(sim), Some(p)) => Some(score_campaign::spawn(score_campaign::BoardCampaign {
            board: sim.clone(),
            domain: c.domain.clone(),
            controller: p.controller.clone(),
            rate_hz: o.rate_hz,
            seed: o.seed,
            watchdog_ns: score_rig::watchdog_ns(&o.root).map_err(io)?,
            end: c.started + o.duration,
            started: c.started,
            link_faults: (p.corrupt, p.drop),
        })),
        _ => None,
    };
    let outcome = c.campaign();
    let board_out = board_run.map(|t| t.join());
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let monitor = eyes
        .join()
        .map_err(|_| "the monitor panicked".to_string())?;
    if let Err(e) = monitor {
        c.failures.push(format!("monitor: {e}"));
    }
    if let Err(e) = outcome {
        c.failures.push(e);
    }
    let board_out = match board_out {
        Some(Ok(mut b)) => {
            b.report.gateway_restarts = c
                .launch
                .executors()
                .iter()
                .find(|e| e.subsystem == score_rig::SUBSYSTEM)
                .map_or(0, |e| e.restarts as u64);
            for (name, v) in std::mem::take(&mut b.resources.processes) {
                c.resources.processes.entry(name).or_default().extend(v);
            }
            c.failures.append(&mut b.failures);
            Some(b.report)
        }
        Some(Err(_)) => {
            c.failures.push("the board's campaign panicked".into());
            None
        }
        None => None,
    };
    let mut report = c.finish();
    if let Some(b) = board_out {
        report.add_board(b);
    }
    Ok(report)
}

impl Campaign<'_> {
    fn campaign(&mut self) -> Result<(), String> {
        for i in 0..self.members.len() {
            self.start_controller(i)?;
        }
        let end = self.started + self.o.duration;
        'run: loop {
            // Every kind for every robot, in a shuffled order, then again.
            let kinds = &self.o.faults;
            let mut plan: Vec<(usize, Fault)> = (0..self.members.len())
                .flat_map(|m| kinds.iter().map(move |&f| (m, f)))
                .collect();
            for i in (1..plan.len()).rev() {
                plan.swap(i, self.rng.below(i as u64 + 1) as usize);
            }
            for (m, f) in plan {
                if Instant::now() + Duration::from_secs(3) > end {
                    break 'run;
                }
                self.event(m, f)?;
                let gap = 300 + self.rng.below(700);
                self.idle(Duration::from_millis(gap));
            }
        }
        self.sample_resources(true);
        Ok(())
    }

    /// Waits, sampling what the processes hold.
    fn idle(&mut self, d: Duration) {
        let end = Instant::now() + d;
        while Instant::now() < end {
            if self.last_sample.elapsed() > Duration::from_secs(2) {
                self.sample_resources(false);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn sample_resources(&mut self, last: bool) {
        self.last_sample = Instant::now();
        let t = self.started.elapsed().as_secs_f64();
        let mut pids = vec![("soak".to_string(), std::process::id())];
        for m in &self.members {
            if let Some(p) = self.launch.pid(&m.robot.subsystem) {
                pids.push((format!("executor {}", m.robot.subsystem), p));
            }
        }
        for (name, pid) in pids {
            if let Some((rss, fds)) = procs::usage(pid) {
                self.resources.sample(&name, pid, t, rss, fds);
            }
        }
        let shm = procs::shm_entries(&self.domain.prefix(), &self.domain.root_path());

        self.resources.shm(t, shm, last);
    }

    fn start_controller(&mut self, m: usize) -> Result<(), String> {
        let seed = self.rng.next_u64();
        let ctl = Ctl::start(self.o, &self.members[m].robot, self.domain.name(), seed)
            .map_err(|e| format!("controller: {e}"))?;
        if !ctl.running(Duration::from_secs(20)) {
            ctl.kill();
            return Err(format!(
                "{}: a new controller could not enable the devices within 20 s",
                self.members[m].robot.subsystem
            ));
        }
        self.members[m].ctl = Some(ctl);
        Ok(())
    }

    /// Waits until every joint of robot `m` has a sample without `STALE` taken after `t`.
    fn fresh_after(&mut self, m: usize, t: u64, within: Duration) -> Option<u64> {
        let end = Instant::now() + within;
        while Instant::now() < end {
            let w = lock(&self.members[m].watched);
            if w.fresh_ns.iter().all(|&f| f > t) {
                return Some(monotonic_ns());
            }
            drop(w);
            std::thread::sleep(Duration::from_millis(1));
        }
        None
    }

    fn event(&mut self, m: usize, f: Fault) -> Result<(), String> {
        let name = self.members[m].robot.subsystem.clone();
        eprintln!(
            "soak: at {:.3} s: {name}: {}",
            monotonic_ns() as f64 / 1e9,
            f.name()
        );
        let recovery = match f {
            Fault::Unplug => self.unplug(m),
            Fault::ExecutorKill => self.kill_executor(m),
            Fault::ControllerKill => self.controller_dies(m, false),
            Fault::ControllerStall => self.controller_dies(m, true),
            Fault::Flood => self.flood(m),
            Fault::ByteFaults | Fault::BadSetpoints => unreachable!("not an event"),
        };
        let tally = &mut self.members[m].tally;
        tally.injected(f);
        match recovery {
            Ok(ns) => tally.recovered(f, ns),
            Err(why) => {
                let text = format!("{name}: {}: {why}", f.name());
                eprintln!("soak: {text}");
                self.failures.push(text);
            }
        }
        Ok(())
    }

    fn unplug(&mut self, m: usize) -> Result<u64, String> {
        let r = self.members[m].robot.clone();
        let t = monotonic_ns();
        r.unplug();
        // Samples taken from one tick and a reply timeout on cannot be fresh.
        let window_from = t + 2 * r.tick_ns + 2_000_000;
        lock(&self.members[m].watched)
            .unplugged
            .push((window_from, u64::MAX));
        let out = 200 + self.rng.below(1300);
        std::thread::sleep(Duration::from_millis(out));
        let back = monotonic_ns();
        {
            let mut w = lock(&self.members[m].watched);
            if let Some(last) = w.unplugged.last_mut() {
                last.1 = back;
            }
            let n = w.unplugged.len();
            if n > 16 {
                w.unplugged.drain(..n - 16);
            }
        }
        r.replug().map_err(|e| format!("replug: {e}"))?;
        let done = self
            .fresh_after(m, back, Duration::from_secs(15))
            .ok_or("no fresh sample within 15 s of the replug")?;
        Ok(done - back)
    }

    fn kill_executor(&mut self, m: usize) -> Result<u64, String> {
        let sub = self.members[m].robot.subsystem.clone();
        let pid = self.launch.pid(&sub).ok_or("no executor running")?;
        let t = monotonic_ns();
        kill(Pid::from_raw(pid as i32), Signal::SIGKILL).map_err(|e| e.to_string())?;
        let done = self
            .fresh_after(m, t, Duration::from_secs(20))
            .ok_or("no fresh sample within 20 s of the kill")?;
        if self.launch.pid(&sub) == Some(pid) {
            return Err("fresh samples from a killed executor".into());
        }
        Ok(done - t)
    }

    /// The controller dies (or stalls): the safe state within the watchdog, kept until a
    /// controller enables the robot again; the recovery is the time until it commands again.
    fn controller_dies(&mut self, m: usize, stall: bool) -> Result<u64, String> {
        let r = self.members[m].robot.clone();
        // A controller that never commanded leaves no watchdog to fire: first see its frames
        // applied.
        let frames0 = lock(&self.members[m].watched).counted().frames_applied;
        let until = Instant::now() + Duration::from_secs(5);
        while lock(&self.members[m].watched).counted().frames_applied <= frames0 {
            if Instant::now() > until {
                return Err("its controller's frames are not applied".into());
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let ctl = self.members[m].ctl.take().ok_or("no controller")?;
        let (trips0, tripped0) = {
            let w = lock(&self.members[m].watched);
            let tripped = w
                .flags
                .iter()
                .all(|f| f & conductor_bus::status::TRIPPED != 0);
            (w.counted().watchdog_trips, tripped)
        };
        let t = monotonic_ns();
        let sig = if stall {
            Signal::SIGSTOP
        } else {
            Signal::SIGKILL
        };
        kill(ctl.pid(), sig).map_err(|e| e.to_string())?;
        self.members[m].deaths += 1;
        let limit = r.watchdog_ns + r.tick_ns + episode::SEND_ALLOWANCE_NS;
        let names: Vec<String> = r.joints.iter().map(|j| j.name.clone()).collect();
        let kill_s = self.started.elapsed().as_secs_f64();
        let number = self.members[m].deaths;
        // Frames sent before the kill are in the monitor's queue by now or within its next
        // poll: the origin is fixed a few milliseconds on.
        std::thread::sleep(Duration::from_millis(5));
        {
            let mut w = lock(&self.members[m].watched);
            let mut e = episode::Episode::new(
                &r.subsystem,
                number,
                if stall {
                    episode::Death::Stop
                } else {
                    episode::Death::Kill
                },
                kill_s,
                t,
                w.last_command_ns,
                limit,
                &names,
            );
            e.hist0 = w.hist.clone();
            e.executors_rt = self.o.rt;
            w.episode = Some(e);
        }
        // Safe, and still safe when the watchdog must have fired.
        let fired = t + r.watchdog_ns + 2 * r.tick_ns;
        let wait_until =
            Instant::now() + Duration::from_nanos(r.watchdog_ns) + Duration::from_secs(3);
        let safe = loop {
            let s = lock(&self.members[m].watched)
                .episode
                .as_ref()
                .is_some_and(|e| e.all_safe());
            if (s && monotonic_ns() >= fired) || Instant::now() > wait_until {
                break s;
            }
            std::thread::sleep(Duration::from_millis(1));
        };
        let result = if safe {
            Ok(0)
        } else {
            Err("never reached its safe state".to_string())
        };
        // It must stay safe while nobody commands it.
        let dead = 300 + self.rng.below(300);
        self.idle(Duration::from_millis(dead));
        let e = {
            let mut w = lock(&self.members[m].watched);
            let e = w.close_episode();
            if w.counted().watchdog_trips == trips0 && !tripped0 {
                drop(w);
                self.members[m].tally.death_uncounted();
            }
            e
        };
        if let Some(e) = e {
            self.members[m].tally.safe(&e);
        }
        let back = Instant::now();
        if stall {
            kill(ctl.pid(), Signal::SIGCONT).map_err(|e| e.to_string())?;
            if !ctl.running(Duration::from_secs(20)) {
                ctl.kill();
                self.start_controller(m)?;
                return Err("the continued controller could not enable the devices again".into());
            }
            self.members[m].ctl = Some(ctl);
        } else {
            ctl.kill();
            self.start_controller(m)?;
        }
        result.map(|_| back.elapsed().as_nanos() as u64)
    }

    fn flood(&mut self, m: usize) -> Result<u64, String> {
        let sub = self.members[m].robot.subsystem.clone();
        let pid = self.launch.pid(&sub);
        let ms = 100 + self.rng.below(200);
        self.members[m]
            .ctl
            .as_mut()
            .ok_or("no controller")?
            .flood(ms);
        std::thread::sleep(Duration::from_millis(ms + 20));
        let t = monotonic_ns();
        let done = self
            .fresh_after(m, t, Duration::from_secs(10))
            .ok_or("no fresh sample within 10 s of a flood")?;
        if self.launch.pid(&sub) != pid {
            return Err("the executor did not survive the flood".into());
        }
        Ok(done - t)
    }

    fn finish(mut self) -> Report {
        for m in self.members.iter_mut() {
            if let Some(c) = m.ctl.take() {
                c.kill();
            }
        }
        let infos = self.launch.executors();
        self.launch.stop();
        let stopped = self.launch.wait();
        let mut robots = Vec::new();
        for m in &self.members {
            let w = lock(&m.watched);
            let restarts = infos
                .iter()
                .find(|e| e.subsystem == m.robot.subsystem)
                .map_or(0, |e| e.restarts as u64);
            robots.push(m.tally.report(&m.robot, &w, restarts));
        }
        if let Err(e) = stopped {
            self.failures
                .push(format!("the launch did not stop cleanly: {e}"));
        }
        // What the domain still holds once everything stopped: the segments of processes
        // that were killed (nobody is left to clean up after them). The campaign's domain is
        // its own: removed.
        std::thread::sleep(Duration::from_millis(200));
        let left = procs::shm_entries(&self.domain.prefix(), &self.domain.root_path());
        self.resources.left_after_stop = left.len() as u64;
        for f in &left {
            let _ = std::fs::remove_file(f);
        }
        let _ = std::fs::remove_dir_all(self.domain.root_path());
        Report::new(
            self.o,
            self.started.elapsed(),
            robots,
            std::mem::take(&mut self.resources),
            std::mem::take(&mut self.failures),
        )
    }
}
