//! Why a launch failed: every way a manifest, a domain or a supervised process can stop it.

use std::path::PathBuf;
use std::time::Duration;

use conductor_manifest::ManifestError;

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

/// `; its last output:` and the lines, or nothing when there are none.
pub(super) fn tail_text(lines: &[String]) -> String {
    if lines.is_empty() {
        String::new()
    } else {
        format!("; its last output:\n  {}", lines.join("\n  "))
    }
}
