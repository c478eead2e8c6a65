//! How to launch: the programs of the executors, gateways, bridge and view, and the supervision's
//! timing (ready timeout, back-off, crash limits, stop timeout).

use std::ffi::OsString;
use std::path::PathBuf;
use std::time::Duration;

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
    /// Run the executors (and gateways) without real-time set-up.
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
    /// thread is started; see [`crate::signals::install`]).
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
