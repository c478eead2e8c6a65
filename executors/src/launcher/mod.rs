//! The launcher: validates a manifest, cleans what dead processes left in the domain, starts one
//! executor process per subsystem and one gateway process per gateway, waits until each
//! executor is ready, supervises them all (restart with bounded back-off), shows a live summary,
//! and on a stop request (SIGINT/SIGTERM or [`Launch::stop`]) stops them in order.
//!
//! A gateway (a board on the bus, e.g. `score-gateway`) is started and restarted like an
//! executor, but the launch does not wait for it: its board may be unplugged, and it reports
//! ready (its `ready …` line) whenever the board answers. A gateway that cannot run or keeps
//! crashing is given up (reported at once and in the final result) while the robot runs on.
//! The live view of a manifest's `[view]` (`conductor view`) is supervised the same way.
//!
//! ```no_run
//! use conductor_executor::launcher::{launch, LaunchOptions};
//! // Blocks until SIGINT/SIGTERM; Err says why an executor could not run.
//! let report = launch("deploy/minihubo-right-leg.toml".as_ref(), LaunchOptions::default())?;
//! # Ok::<(), conductor_executor::launcher::LaunchError>(())
//! ```

mod supervisor;

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use crate::cleanup::{executor_node_name, gateway_node_name, scan_and_clean};
use crate::process::resolve_domain;
use crate::signals::{self, Stop};
use conductor_manifest::{
    GatewayDef, GatewayKind, GatewayOptions, Manifest, ManifestError, ViewDef, BRIDGE_NAME,
};
use supervisor::Supervisor;

/// How to launch.
#[derive(Debug, Clone)]
pub struct LaunchOptions {
    /// The executor program.
    pub executor: PathBuf,
    /// Arguments put before the executor's own (e.g. a sub-command when a program runs itself
    /// as the executor).
    pub executor_args: Vec<OsString>,
    /// The program of `kind = "score"` gateways (`score-gateway` or a program running its main).
    pub gateway: PathBuf,
    /// Arguments put before the gateway's own (e.g. a sub-command).
    pub gateway_args: Vec<OsString>,
    /// The program of the manifest's `[view]` (`conductor`).
    pub view: PathBuf,
    /// Arguments put before the view's own `--domain`, `--listen`, `--clamp` (the `view`
    /// sub-command).
    pub view_args: Vec<OsString>,
    /// The program run for a manifest's `[bridge]` table (`conductor`, with `bridge_args`).
    pub bridge: PathBuf,
    /// Arguments put before the bridge's own (`bridge`: the sub-command).
    pub bridge_args: Vec<OsString>,
    /// Bus domain (default: the manifest's, else `CONDUCTOR_DOMAIN`, else "default").
    pub domain: Option<String>,
    /// Only these subsystems (empty: all).
    pub only: Vec<String>,
    /// Run the executors without real-time set-up.
    pub no_rt: bool,
    /// No live summary (events — ready, restarts, stops — are always reported on stderr).
    pub quiet: bool,
    /// Summary interval (default: 1 s on a terminal, 10 s otherwise).
    pub summary_interval: Option<Duration>,
    /// Time an executor has to print `READY`.
    pub ready_timeout: Duration,
    /// Time executors have to stop after SIGTERM before they are killed.
    pub stop_timeout: Duration,
    /// First restart delay; doubles with each consecutive crash.
    pub backoff: Duration,
    /// Longest restart delay.
    pub backoff_max: Duration,
    /// Crashes tolerated within [`restart_window`](Self::restart_window) before giving up.
    pub max_restarts: u32,
    /// See [`max_restarts`](Self::max_restarts).
    pub restart_window: Duration,
    /// Turn SIGINT/SIGTERM into a stop request (call from the main thread before any other
    /// thread is started; see [`signals::install`]).
    pub handle_signals: bool,
}

impl Default for LaunchOptions {
    fn default() -> Self {
        Self {
            executor: default_executor(),
            executor_args: Vec::new(),
            gateway: default_gateway(),
            gateway_args: Vec::new(),
            view: beside_me("conductor"),
            view_args: vec!["view".into()],
            bridge: beside_me("conductor"),
            bridge_args: vec!["bridge".into()],
            domain: None,
            only: Vec::new(),
            no_rt: false,
            quiet: false,
            summary_interval: None,
            ready_timeout: Duration::from_secs(10),
            stop_timeout: Duration::from_secs(5),
            backoff: Duration::from_millis(200),
            backoff_max: Duration::from_secs(5),
            max_restarts: 5,
            restart_window: Duration::from_secs(60),
            handle_signals: true,
        }
    }
}

/// `conductor-executor` next to the running program (where cargo and installers put it), else
/// the one on `PATH`.
pub fn default_executor() -> PathBuf {
    beside_me("conductor-executor")
}

/// `score-gateway` next to the running program, else the one on `PATH`.
pub fn default_gateway() -> PathBuf {
    beside_me("score-gateway")
}

/// The program `name` next to the running one (or one directory up), else `name` for `PATH`.
fn beside_me(name: &str) -> PathBuf {
    std::env::current_exe()
        .ok()
        .and_then(|exe| {
            let dir = exe.parent()?;
            // Test and example binaries live one level below the binaries.
            [dir.join(name), dir.parent()?.join(name)]
                .into_iter()
                .find(|p| p.is_file())
        })
        .unwrap_or_else(|| PathBuf::from(name))
}

/// Why a launch failed.
#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    /// The manifest is invalid (every problem listed).
    #[error("{0}")]
    Manifest(#[from] ManifestError),
    /// The domain name is unusable.
    #[error("{0}")]
    Domain(String),
    /// `only` names a subsystem the manifest lacks.
    #[error("the manifest has no subsystem {name:?}; expected one of: {known}")]
    UnknownSubsystem {
        /// Asked for.
        name: String,
        /// What exists.
        known: String,
    },
    /// An executor of this subsystem already runs in the domain.
    #[error("subsystem {subsystem:?} already runs in domain {domain:?} (process {pid}); stop it first or use another domain")]
    AlreadyRunning {
        /// The subsystem.
        subsystem: String,
        /// The domain.
        domain: String,
        /// Its process.
        pid: String,
    },
    /// The executor program could not be started.
    #[error("cannot start the executor program {program:?} for subsystem {subsystem:?}: {source} (build it with `cargo build -p conductor-executor`, or point LaunchOptions::executor at it)")]
    Spawn {
        /// The subsystem.
        subsystem: String,
        /// The program.
        program: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The view program could not be started.
    #[error("cannot start the view program {program:?}: {source} (build it with `cargo build -p conductor-cli`, or point LaunchOptions::view at it)")]
    SpawnView {
        /// The program.
        program: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A gateway program could not be started.
    #[error("cannot start the gateway program {program:?} for gateway {gateway:?}: {source} (build it with `cargo build -p score-gateway`, or point LaunchOptions::gateway at it)")]
    SpawnGateway {
        /// The gateway.
        gateway: String,
        /// The program.
        program: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// An executor exited or hung before it was ready.
    #[error("the executor of subsystem {subsystem:?} did not become ready: {status}{}", tail_text(.output))]
    NotReady {
        /// The subsystem.
        subsystem: String,
        /// What happened.
        status: String,
        /// Its last lines of output.
        output: Vec<String>,
    },
    /// An executor reported that it cannot run (configuration, real time required), so a restart
    /// cannot help.
    #[error("the executor of subsystem {subsystem:?} cannot run ({status}){}", tail_text(.output))]
    CannotRun {
        /// The subsystem.
        subsystem: String,
        /// Its exit status.
        status: String,
        /// Its last lines of output.
        output: Vec<String>,
    },
    /// An executor kept crashing.
    #[error("the executor of subsystem {subsystem:?} crashed {crashes} times within {window:?} (last: {status}); giving up{}", tail_text(.output))]
    TooManyRestarts {
        /// The subsystem.
        subsystem: String,
        /// Crashes counted.
        crashes: u32,
        /// The window.
        window: Duration,
        /// Last exit status.
        status: String,
        /// Its last lines of output.
        output: Vec<String>,
    },
    /// At the orderly stop, some executors or gateways did not exit cleanly (or a gateway had
    /// been given up).
    #[error("not every executor and gateway stopped cleanly: {}", .failures.join("; "))]
    Unclean {
        /// `subsystem: status` for each.
        failures: Vec<String>,
    },
    /// The domain could not be inspected or joined.
    #[error("{0}")]
    Bus(String),
}

fn tail_text(lines: &[String]) -> String {
    if lines.is_empty() {
        String::new()
    } else {
        format!("; its last output:\n  {}", lines.join("\n  "))
    }
}

/// What a supervised process is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProcessKind {
    /// The executor of a subsystem; the launch waits until it is ready.
    Executor,
    /// A gateway (`[gateways.<name>]`); the launch does not wait for it.
    Gateway,
    /// The live view (`[view]`); the launch does not wait for it.
    View,
}

/// How each executor and gateway ended, after an orderly stop.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SubsystemReport {
    /// The subsystem (for a gateway: its name, the subsystem it publishes).
    pub subsystem: String,
    /// Executor or gateway.
    pub kind: ProcessKind,
    /// Restarts after crashes.
    pub restarts: u32,
    /// Exit code of the last run (None: killed by a signal).
    pub exit_code: Option<i32>,
}

/// The result of a launch that ended with a stop request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LaunchReport {
    /// The domain used.
    pub domain: String,
    /// One per subsystem, in manifest order, then one per gateway.
    pub subsystems: Vec<SubsystemReport>,
}

/// What the handle can see of each executor and gateway while it runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExecutorInfo {
    /// The subsystem (for a gateway: its name).
    pub subsystem: String,
    /// Executor or gateway.
    pub kind: ProcessKind,
    /// Current process, if one runs.
    pub pid: Option<u32>,
    /// Restarts so far.
    pub restarts: u32,
    /// Whether it has reported ready (since its last start). A gateway that runs but is not
    /// ready is waiting for its board.
    pub ready: bool,
    /// Why the launcher gave up on it (only gateways are given up; an executor that cannot run
    /// ends the launch).
    pub failed: Option<String>,
}

/// A running launch.
pub struct Launch {
    stop: Stop,
    info: Arc<Mutex<Vec<ExecutorInfo>>>,
    domain: String,
    thread: Option<JoinHandle<Result<LaunchReport, LaunchError>>>,
}

impl core::fmt::Debug for Launch {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Launch")
            .field("domain", &self.domain)
            .finish()
    }
}

/// Reads and validates the manifest at `path` and prints its warnings, if any, on stderr (so
/// that whoever launches or checks a manifest sees them before anything starts).
pub fn load_manifest(path: &Path) -> Result<Manifest, ManifestError> {
    let manifest = Manifest::load(path)?;
    if !manifest.warnings.is_empty() {
        note!("{}", manifest.render_warnings());
    }
    Ok(manifest)
}

/// Launches and blocks until a stop request (SIGINT/SIGTERM when `handle_signals`), then stops
/// every executor and gateway. Returns an error as soon as an executor cannot run.
pub fn launch(manifest: &Path, opts: LaunchOptions) -> Result<LaunchReport, LaunchError> {
    Launch::start(manifest, opts)?.wait()
}

impl Launch {
    /// Validates, cleans, starts every executor and gateway and returns once every executor is
    /// ready (gateways become ready when their boards answer).
    pub fn start(manifest_path: &Path, opts: LaunchOptions) -> Result<Launch, LaunchError> {
        let stop = Stop::new();
        if opts.handle_signals {
            signals::install(&stop).map_err(|e| LaunchError::Bus(e.to_string()))?;
        }
        let manifest = load_manifest(manifest_path)?;
        let domain =
            resolve_domain(opts.domain.as_deref(), &manifest).map_err(LaunchError::Domain)?;
        let known: Vec<&str> = manifest
            .subsystems
            .iter()
            .map(|s| s.name.as_str())
            .chain(manifest.gateways.iter().map(|g| g.name.as_str()))
            .chain(manifest.bridge.as_ref().map(|_| BRIDGE_NAME))
            .collect();
        for o in &opts.only {
            if !known.contains(&o.as_str()) {
                return Err(LaunchError::UnknownSubsystem {
                    name: o.clone(),
                    known: known.join(", "),
                });
            }
        }
        let wanted = |n: &str| opts.only.is_empty() || opts.only.iter().any(|o| o == n);
        let subsystems: Vec<String> = manifest
            .subsystems
            .iter()
            .filter(|s| wanted(&s.name))
            .map(|s| s.name.clone())
            .collect();
        let mut gateways: Vec<GatewayDef> = manifest
            .gateways
            .iter()
            .filter(|g| wanted(&g.name))
            .cloned()
            .collect();
        // The bridge is supervised like a gateway whose "board" is the manifest it reads.
        if manifest.bridge.is_some() && wanted(BRIDGE_NAME) {
            gateways.push(GatewayDef {
                name: BRIDGE_NAME.into(),
                kind: GatewayKind::Bridge,
                port: manifest_path
                    .canonicalize()
                    .unwrap_or_else(|_| manifest_path.to_path_buf()),
                options: GatewayOptions {
                    restore: false,
                    ..GatewayOptions::default()
                },
            });
        }

        // Nothing of a previous run may be in the way.
        let scan = scan_and_clean(&domain).map_err(LaunchError::Bus)?;
        let nodes = subsystems.iter().map(|s| (s, executor_node_name(s))).chain(
            gateways
                .iter()
                .map(|g| (&g.name, gateway_node_name(&g.name))),
        );
        for (s, node) in nodes {
            if let Some(n) = scan.alive.iter().find(|n| n.name == node) {
                return Err(LaunchError::AlreadyRunning {
                    subsystem: s.clone(),
                    domain: domain.name().into(),
                    pid: n.pid.map_or("?".into(), |p| p.to_string()),
                });
            }
        }
        if scan.removed > 0 {
            note!(
                "conductor: removed the stale resources of {} dead process(es) in domain {:?}",
                scan.removed,
                domain.name()
            );
        }

        // The view watches the whole domain: it runs whatever `only` says.
        let view: Option<ViewDef> = manifest.view.clone();
        let view_name = String::from("view");
        let info = Arc::new(Mutex::new(
            subsystems
                .iter()
                .map(|s| (s, ProcessKind::Executor))
                .chain(gateways.iter().map(|g| (&g.name, ProcessKind::Gateway)))
                .chain(view.iter().map(|_| (&view_name, ProcessKind::View)))
                .map(|(s, kind)| ExecutorInfo {
                    subsystem: s.clone(),
                    kind,
                    pid: None,
                    restarts: 0,
                    ready: false,
                    failed: None,
                })
                .collect(),
        ));
        let path = manifest_path
            .canonicalize()
            .unwrap_or_else(|_| manifest_path.to_path_buf());
        let (ready_tx, ready_rx) = mpsc::channel();
        let sup = Supervisor::new(opts, path, domain.clone(), stop.clone(), info.clone());
        let thread = std::thread::Builder::new()
            .name("supervisor".into())
            .spawn(move || sup.run(subsystems, gateways, view, ready_tx))
            .map_err(|e| LaunchError::Bus(e.to_string()))?;
        match ready_rx.recv() {
            Ok(()) => Ok(Launch {
                stop,
                info,
                domain: domain.name().into(),
                thread: Some(thread),
            }),
            // The supervisor ended before everything was ready: its result says why.
            Err(_) => Err(thread
                .join()
                .unwrap_or_else(|_| Err(LaunchError::Bus("the supervisor panicked".into())))
                .err()
                .unwrap_or_else(|| LaunchError::Bus("stopped before ready".into()))),
        }
    }

    /// Current executors, then gateways, then the view.
    pub fn executors(&self) -> Vec<ExecutorInfo> {
        self.info.lock().map(|v| v.clone()).unwrap_or_default()
    }

    /// The process of `subsystem`'s executor (or of the gateway of that name), if one runs.
    pub fn pid(&self, subsystem: &str) -> Option<u32> {
        self.executors()
            .into_iter()
            .find(|e| e.subsystem == subsystem)
            .and_then(|e| e.pid)
    }

    /// The domain.
    pub fn domain(&self) -> &str {
        &self.domain
    }

    /// Requests an orderly stop (as SIGTERM would).
    pub fn stop(&self) {
        self.stop.request(0);
    }

    /// The stop request, to share with other code.
    pub fn stop_handle(&self) -> Stop {
        self.stop.clone()
    }

    /// Blocks until the launch ends (after a stop request, or when an executor cannot run).
    pub fn wait(mut self) -> Result<LaunchReport, LaunchError> {
        let t = self.thread.take().expect("waited once");
        t.join()
            .unwrap_or_else(|_| Err(LaunchError::Bus("the supervisor panicked".into())))
    }
}

impl Drop for Launch {
    fn drop(&mut self) {
        if let Some(t) = self.thread.take() {
            self.stop.request(0);
            let _ = t.join();
        }
    }
}
