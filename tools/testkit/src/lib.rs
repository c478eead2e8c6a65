//! # conductor-testkit
//!
//! What several test suites of the workspace need, in one place:
//!
//! * [`workspace`] — the workspace root, for fixtures that live outside a crate (`deploy/`,
//!   `bus/ABI.md`, ...).
//! * [`python`] — the interpreter of the venv that `cargo xtask test` creates with the PyPI
//!   packages of the interop tests (`tools/python-requirements.txt`); tests fail, never skip,
//!   when it is missing.
//! * [`alloc`] — a counting global allocator, to prove that a real-time path allocates nothing.
//! * [`can_vm`] — Debian's kernel booted in QEMU with the host's file system shared, for tests
//!   that need a real Linux CAN stack (vcan, slcan) the build machine's kernel lacks.
//! * [`fuzz`] — the fuzz targets' seed and regression corpora replayed as an ordinary test.
//! * [`eventually`] — polling for what another process or thread will make true.
//! * [`run_ok`] — running a program that must succeed, with its output in the failure message.
//! * [`spawn_with_lines`], [`lines_of`] — a child's output lines on a channel, to wait for with
//!   a timeout.
//! * [`number_after`], [`json_strings`] — a figure, a list of names read out of a program's
//!   report.

use std::io::{BufRead, BufReader, Read};
use std::path::PathBuf;
use std::process::{Child, Command, Output, Stdio};
use std::str::FromStr;
use std::sync::mpsc;
use std::time::{Duration, Instant};

pub mod alloc;
pub mod can_vm;
pub mod fuzz;

/// The workspace root.
pub fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .expect("the workspace root exists")
}

/// `$CONDUCTOR_PYTHON`, else `<workspace>/.venv/bin/python`; panics with the fix when absent.
pub fn python() -> PathBuf {
    let py = std::env::var_os("CONDUCTOR_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace().join(".venv/bin/python"));
    assert!(
        py.exists(),
        "{} not found: run `cargo xtask setup` (it creates the venv with the packages of \
         tools/python-requirements.txt)",
        py.display()
    );
    py
}

/// Polls `f` every 10 ms until it returns `Some`, and returns that; panics naming `what` once
/// `timeout` has passed (a bound on failure, not a speed claim).
pub fn eventually<T>(timeout: Duration, what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    let end = Instant::now() + timeout;
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < end, "{what}: not within {timeout:?}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Runs `cmd` to completion and returns its output; panics with the command, its stdout and its
/// stderr when it fails (or cannot start).
pub fn run_ok(cmd: &mut Command) -> Output {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{cmd:?} did not start: {e}"));
    assert!(
        out.status.success(),
        "{cmd:?} failed ({}):\n{}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// The lines `out` (a child's stdout, say) writes, read by a thread and sent to the returned
/// receiver, so that a test can wait for each with a timeout. The thread reads to the end of
/// `out` even when nobody receives any more, so the child never blocks on a full pipe.
pub fn lines_of(out: impl Read + Send + 'static) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    rx
}

/// Starts `cmd` with its stdout piped to [`lines_of`] (stdin and stderr as `cmd` sets them);
/// panics with the command when it cannot start.
pub fn spawn_with_lines(cmd: &mut Command) -> (Child, mpsc::Receiver<String>) {
    let mut child = cmd
        .stdout(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("{cmd:?} did not start: {e}"));
    let lines = lines_of(child.stdout.take().expect("stdout is piped"));
    (child, lines)
}

/// The number that follows `marker` in `text` (a program's report, up to the next space),
/// parsed; panics with the text when the marker or the number is missing.
pub fn number_after<T: FromStr>(text: &str, marker: &str) -> T {
    text.split(marker)
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no number after {marker:?} in: {text}"))
}

/// The strings of the JSON array `v` (a report's list of names); panics when `v` is not an
/// array of strings.
pub fn json_strings(v: &serde_json::Value) -> Vec<&str> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_str().unwrap_or_else(|| panic!("not a string: {x}")))
        .collect()
}
