//! The CLI's error type: every failure becomes one line on stderr and a non-zero exit.

use std::path::PathBuf;

use conductor_bus::BusError;
use thiserror::Error;

/// What can stop a `conductor` command.
#[derive(Debug, Error)]
pub enum CliError {
    /// The bus refused (unknown state, bad name, iceoryx2 failure, ...).
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The live view cannot run (its address, the bus).
    #[error(transparent)]
    View(#[from] conductor_view::ViewError),
    /// No state of the domain matches a pattern.
    #[error(
        "no state matches {pattern:?} in domain {domain:?}{}",
        known_hint(known)
    )]
    NoMatch {
        /// The pattern.
        pattern: String,
        /// The domain searched.
        domain: String,
        /// Some states that do exist.
        known: Vec<String>,
    },
    /// A pattern is not a valid glob.
    #[error("bad pattern {pattern:?}: {reason}")]
    BadPattern {
        /// The pattern.
        pattern: String,
        /// Why.
        reason: String,
    },
    /// A setpoint outside the state's limits, without `--clamp`.
    #[error("{value} is outside the limits [{min}, {max}] of {state}; pass --clamp to send {clamped} instead")]
    OutOfLimits {
        /// The state.
        state: String,
        /// The requested value.
        value: f64,
        /// Lower limit.
        min: f64,
        /// Upper limit.
        max: f64,
        /// What `--clamp` would send.
        clamped: f64,
    },
    /// The executor refused a setpoint: a sample published after the frame carries `REJECTED`.
    #[error("the executor refused {state} <- {value}: {reason}")]
    Refused {
        /// The state.
        state: String,
        /// The value sent (as printed).
        value: String,
        /// Why, from the sample's flags, with what to do about it.
        reason: String,
    },
    /// Nothing arrived in time.
    #[error("timed out: {0}")]
    Timeout(String),
    /// A bad option value.
    #[error("{0}")]
    Usage(String),
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A socket or terminal error.
    #[error("{context}: {source}")]
    Os {
        /// What we were doing.
        context: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// The MCAP library refused to write a file or a record (reading: [`CliError::Recording`]).
    #[error("{}: MCAP: {detail}", path.display())]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The library's message.
        detail: String,
    },
    /// A recording that cannot be read, that `conductor` did not write, or that is damaged.
    #[error(transparent)]
    Recording(#[from] conductor_cli_formats::recording::RecordingError),
    /// Drawing the plot failed.
    #[error("plot: {0}")]
    Plot(String),
}

fn known_hint(known: &[String]) -> String {
    if known.is_empty() {
        " (no states are published there: is the executor running, in this domain?)".into()
    } else {
        format!("; states: {}", known.join(", "))
    }
}

impl CliError {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        CliError::Io {
            path: path.into(),
            source,
        }
    }

    /// An OS error while doing `context`.
    pub fn os(context: impl Into<String>, source: std::io::Error) -> Self {
        CliError::Os {
            context: context.into(),
            source,
        }
    }

    /// An MCAP library error on `path`.
    pub fn mcap(path: impl Into<PathBuf>, e: impl std::fmt::Display) -> Self {
        CliError::Mcap {
            path: path.into(),
            detail: e.to_string(),
        }
    }
}

/// Result alias of the CLI.
pub type Result<T, E = CliError> = std::result::Result<T, E>;
