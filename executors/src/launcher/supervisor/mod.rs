//! The supervisor thread: what it keeps of each supervised process, and its loop. Its jobs are
//! modules of their own: [`spawn`] (command lines, inherited descriptors, output forwarding),
//! [`readiness`] (ready lines, the start-up wait), [`restart`] (back-off, crash limits, giving
//! up), [`summary`] (the live summary) and [`stop`] (the orderly stop and the report).

mod readiness;
mod restart;
mod spawn;
mod stop;
mod summary;

use std::collections::VecDeque;
use std::os::unix::process::ExitStatusExt;
use std::path::PathBuf;
use std::process::{Child, ExitStatus};
use std::sync::mpsc::{Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use conductor_bus::Domain;
use conductor_manifest::{GatewayDef, ViewDef};
use nix::sys::signal::Signal;

use super::{ExecutorInfo, LaunchError, LaunchOptions, LaunchReport, ProcessKind};
use crate::signals::Stop;
use readiness::Event;
use summary::LiveSummary;

/// Where a supervised process is in its life.
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

/// The supervisor thread's state: the launch's options, domain and stop request, and every
/// supervised process.
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

/// An exit status in words (`exit status 2`, `killed by signal SIGKILL`).
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

    fn supervise(&mut self) -> Result<(), LaunchError> {
        let mut summary = LiveSummary::new(self);
        while !self.stop.requested() {
            self.handle_events();
            let now = Instant::now();
            for i in 0..self.children.len() {
                self.check_child(i, now)?;
            }
            summary.draw_if_due(self, now);
            std::thread::sleep(POLL);
        }
        Ok(())
    }
}
