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

mod error;
mod options;
mod supervisor;

use std::path::Path;
use std::process::ExitCode;
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use crate::cleanup::{executor_node_name, gateway_node_name, scan_and_clean};
use crate::process::resolve_domain;
use crate::signals::{self, Stop};
use conductor_manifest::{
    GatewayDef, GatewayKind, GatewayOptions, Manifest, ManifestError, ViewDef, BRIDGE_NAME,
};
use error::tail_text;
pub use error::LaunchError;
pub use options::{default_executor, default_gateway, LaunchOptions};
use supervisor::Supervisor;

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

/// Exit status of the launchers (`conductor-launch`, `conductor launch`) for a manifest that
/// does not load or validate: the executor's.
pub const EXIT_MANIFEST: u8 = 2;

/// A launcher's `--check`: loads and validates the manifest at `path` and says on stdout what it
/// holds; an invalid one gets its error on stderr and [`EXIT_MANIFEST`].
pub fn check_manifest(path: &Path) -> ExitCode {
    match load_manifest(path) {
        Ok(m) => {
            println!(
                "{}: valid ({} subsystems, {} gateways{})",
                path.display(),
                m.subsystems.len(),
                m.gateways.len(),
                if m.view.is_some() { ", a view" } else { "" }
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("{e}");
            ExitCode::from(EXIT_MANIFEST)
        }
    }
}

/// A launcher's exit status once [`launch`] returned: an invalid manifest's error is printed as
/// it is, with [`EXIT_MANIFEST`]; any other error as `conductor: …`, with failure.
pub fn launch_exit(result: Result<LaunchReport, LaunchError>) -> ExitCode {
    match result {
        Ok(_) => ExitCode::SUCCESS,
        Err(e @ LaunchError::Manifest(_)) => {
            eprintln!("{e}");
            ExitCode::from(EXIT_MANIFEST)
        }
        Err(e) => {
            eprintln!("conductor: {e}");
            ExitCode::FAILURE
        }
    }
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
