//! Helpers: a scratch directory holding the thesis files, running scripts, reading logs.
#![allow(dead_code)]

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};

use score_host::{Session, TimeMode};

/// The `score` binary of this build.
pub fn score() -> Command {
    Command::new(env!("CARGO_BIN_EXE_score"))
}

/// `score args… --dir dir`: scripts named in `args` are found in `dir` and write their logs there.
/// Run it with `.output()`, or with `conductor_testkit::run_ok` where it must succeed.
pub fn score_in(dir: &Path, args: &[&str]) -> Command {
    let mut cmd = score();
    cmd.args(args).arg("--dir").arg(dir);
    cmd
}

/// `score args…` with `input` piped to it as a session; its stdout captured (stderr inherited).
pub fn piped_session(args: &[&str], input: &[u8]) -> Output {
    let mut child = score()
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(input).unwrap();
    child.wait_with_output().unwrap()
}

pub fn thesis_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/thesis")
}

/// A fresh directory with copies of every file in tests/thesis (scripts write logs beside them).
pub fn workdir(tag: &str) -> PathBuf {
    static N: AtomicUsize = AtomicUsize::new(0);
    let dir = std::env::temp_dir().join(format!(
        "score-host-{}-{}-{}",
        std::process::id(),
        tag,
        N.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    for e in std::fs::read_dir(thesis_dir()).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), dir.join(e.file_name())).unwrap();
    }
    dir
}

/// [`workdir`] with one more file, `name`, holding `text` (a script of the test's own).
pub fn workdir_with(tag: &str, name: &str, text: &str) -> PathBuf {
    let dir = workdir(tag);
    std::fs::write(dir.join(name), text).unwrap();
    dir
}

/// Runs a thesis script unchanged in simulated time, then advances `seconds`.
pub fn run_script(script: &str, extra: &[&str], seconds: f64) -> (Session, PathBuf) {
    let dir = workdir(script);
    let mut s = Session::new(TimeMode::Simulated, &dir);
    let mut out = String::new();
    s.script(script, &mut out)
        .unwrap_or_else(|e| panic!("{script}: {e}\n{out}"));
    for l in extra {
        s.line(l, &mut out).unwrap_or_else(|e| panic!("{l}: {e}"));
    }
    s.advance(seconds).unwrap();
    (s, dir)
}

pub fn numbers(path: &Path) -> Vec<f64> {
    score_host::board::Files::read_numbers(path).unwrap()
}

/// Unit roundoff of the core's number type (half its machine epsilon).
pub fn unit_roundoff() -> f64 {
    use score_core::Real;
    <score_core::Num as Real>::EPSILON.to_f64() / 2.0
}
