//! The thesis' Score terminal transcripts as tests for any Score terminal.
//!
//! [`Transcript::load`] reads one from the thesis corpus ([`thesis_dir`]); [`Transcript::check`]
//! types its commands through a closure (the host port in-process, the firmware's USB terminal
//! in the emulator) and holds the output to the printed one: the same lines in order, and for a
//! `printvars` exactly the same variables, whose values it returns for the caller's checks.
//! Printing changed the text (`−`, `’`, spacing), so lines are compared after [`normalize`].

mod check;
mod parse;

use std::path::{Path, PathBuf};

pub use check::{Listing, Mismatch};
pub use parse::{normalize, var_line, Step, Transcript};

/// The thesis corpus, `score/host/tests/thesis`: every script and transcript as printed.
pub fn thesis_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/thesis")
}
