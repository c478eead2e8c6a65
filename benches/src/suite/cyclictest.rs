//! The kernel wake-up floor: rt-tests' `cyclictest` at the executor's rate, priority and CPU.
//!
//! cyclictest measures what our tick lateness measures — timer expiry (an absolute
//! `clock_nanosleep` deadline) → the thread running — with nothing else in the loop, so
//! `lateness / cyclictest` is what the executor adds to the machine's own floor. It is run with
//! `-m` (mlockall, as the executor) and a µs histogram (`-h`, `--json`), for its percentiles.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

use crate::Percentiles;

/// Histogram range (µs): wake-ups later than this count as overflows (their max is still exact).
const HIST_MAX_US: u64 = 100_000;

/// One cyclictest run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CyclicConfig {
    /// Wake-ups per second (interval = 1/rate, rounded to a µs).
    pub rate_hz: f64,
    /// SCHED_FIFO priority.
    pub priority: i32,
    /// CPU to pin the measuring thread to.
    pub cpu: usize,
    /// Length (s): `rate × seconds` loops.
    pub seconds: f64,
}

impl CyclicConfig {
    /// The interval in µs.
    pub fn interval_us(&self) -> u64 {
        (1e6 / self.rate_hz).round().max(1.0) as u64
    }

    fn loops(&self) -> u64 {
        (self.rate_hz * self.seconds).round().max(1.0) as u64
    }
}

/// What one run measured.
#[derive(Debug, Clone, PartialEq)]
pub struct CyclicResult {
    /// The command line that ran.
    pub command: String,
    /// Wake-up latency (ns; cyclictest's µs resolution): nearest-rank percentiles over the
    /// histogram, exact min, max and mean.
    pub latency: Percentiles,
    /// `(µs, count)` of every non-empty histogram bucket.
    pub histogram: Vec<(u64, u64)>,
    /// Wake-ups beyond the histogram's range.
    pub overflows: u64,
}

/// Why cyclictest gave no figures.
#[derive(Debug, thiserror::Error)]
pub enum CyclicError {
    /// It could not be started.
    #[error("cannot run {0}: {1}")]
    Start(String, std::io::Error),
    /// It failed (typically: no permission for SCHED_FIFO or mlockall).
    #[error("`{command}` failed ({status}): {stderr}")]
    Failed {
        /// The command line.
        command: String,
        /// Exit status.
        status: std::process::ExitStatus,
        /// What it said.
        stderr: String,
    },
    /// Its JSON output was not what rt-tests 2.x writes.
    #[error("unexpected cyclictest output: {0}")]
    Output(String),
}

/// `cyclictest` on `PATH`, if any.
pub fn locate() -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join("cyclictest"))
        .find(|p| p.is_file())
}

/// Finds cyclictest, installing the Debian package `rt-tests` when it is missing and
/// `allow_install` (as root, or with password-less sudo). `Err` is the note to print.
pub fn ensure(allow_install: bool) -> Result<PathBuf, String> {
    if let Some(p) = locate() {
        return Ok(p);
    }
    if !allow_install {
        return Err(
            "cyclictest is not installed (Debian/Ubuntu: `apt-get install rt-tests`)".into(),
        );
    }
    if locate_program("apt-get").is_none() {
        return Err(
            "cyclictest is not installed and there is no apt-get to install it; install rt-tests \
             with your package manager"
                .into(),
        );
    }
    let root = nix_is_root();
    let apt = |args: &[&str]| {
        let mut c = if root {
            Command::new("apt-get")
        } else {
            let mut c = Command::new("sudo");
            c.args(["-n", "apt-get"]);
            c
        };
        c.args(args).env("DEBIAN_FRONTEND", "noninteractive");
        c.output()
    };
    let ok = |r: std::io::Result<std::process::Output>| r.is_ok_and(|o| o.status.success());
    if !ok(apt(&["install", "-y", "-q", "rt-tests"])) {
        // A fresh machine may have no package lists yet.
        let _ = apt(&["update", "-q"]);
        let out = apt(&["install", "-y", "-q", "rt-tests"]);
        if !ok(out) {
            return Err(format!(
                "cyclictest is not installed and `apt-get install rt-tests` failed{}",
                if root {
                    ""
                } else {
                    " (not root, and sudo -n was refused)"
                }
            ));
        }
    }
    locate().ok_or_else(|| "rt-tests installed but cyclictest is not on PATH".into())
}

fn locate_program(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

fn nix_is_root() -> bool {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() == 0 }
}

/// Runs cyclictest once: `-m -p <prio> -i <interval> -a <cpu> -l <loops> -q -h <max> --json`.
pub fn run(program: &Path, cfg: &CyclicConfig) -> Result<CyclicResult, CyclicError> {
    let json = std::env::temp_dir().join(format!(
        "conductor-cyclictest-{}-{}.json",
        std::process::id(),
        cfg.interval_us()
    ));
    let args = [
        "-m".to_string(),
        "-p".into(),
        cfg.priority.to_string(),
        "-i".into(),
        cfg.interval_us().to_string(),
        "-a".into(),
        cfg.cpu.to_string(),
        "-l".into(),
        cfg.loops().to_string(),
        "-q".into(),
        "-h".into(),
        HIST_MAX_US.to_string(),
        format!("--json={}", json.display()),
    ];
    let command = format!("cyclictest {}", args[..args.len() - 1].join(" "));
    let out = Command::new(program)
        .args(&args)
        .output()
        .map_err(|e| CyclicError::Start(program.display().to_string(), e))?;
    let text = std::fs::read_to_string(&json);
    let _ = std::fs::remove_file(&json);
    if !out.status.success() {
        return Err(CyclicError::Failed {
            command,
            status: out.status,
            stderr: String::from_utf8_lossy(&out.stderr).trim().to_string(),
        });
    }
    let text = text.map_err(|e| CyclicError::Output(format!("{}: {e}", json.display())))?;
    parse(&text, command)
}

/// Reads rt-tests' `--json` output (thread 0: `histogram` {µs: count}, `cycles`, `min`, `max`,
/// `avg`).
pub fn parse(text: &str, command: String) -> Result<CyclicResult, CyclicError> {
    let bad = |what: &str| CyclicError::Output(what.to_string());
    let v: Value = serde_json::from_str(text).map_err(|e| bad(&e.to_string()))?;
    let t = v
        .get("thread")
        .and_then(|t| t.get("0"))
        .ok_or_else(|| bad("no thread 0"))?;
    let num = |k: &str| t.get(k).and_then(Value::as_f64).ok_or_else(|| bad(k));
    let cycles = num("cycles")? as u64;
    let (min_us, max_us, avg_us) = (num("min")? as u64, num("max")? as u64, num("avg")?);
    let mut histogram: Vec<(u64, u64)> = t
        .get("histogram")
        .and_then(Value::as_object)
        .ok_or_else(|| bad("no histogram (was -h given?)"))?
        .iter()
        .map(|(k, c)| Some((k.parse::<u64>().ok()?, c.as_u64()?)))
        .collect::<Option<_>>()
        .ok_or_else(|| bad("a histogram entry is not <µs>: <count>"))?;
    histogram.sort_unstable();
    if cycles == 0 {
        return Err(bad("0 cycles"));
    }
    let in_hist: u64 = histogram.iter().map(|(_, c)| c).sum();
    let overflows = cycles.saturating_sub(in_hist);
    let rank = |q: f64| {
        let r = ((q * cycles as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for &(us, c) in &histogram {
            seen += c;
            if seen >= r {
                return us * 1000;
            }
        }
        // In the overflow region: the exact max is the best bound known.
        max_us * 1000
    };
    Ok(CyclicResult {
        command,
        latency: Percentiles {
            count: cycles as usize,
            min: min_us * 1000,
            p50: rank(0.5),
            p99: rank(0.99),
            p999: rank(0.999),
            max: max_us * 1000,
            mean: avg_us * 1000.0,
        },
        histogram,
        overflows,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_come_from_the_histogram_and_overflows_count() {
        // 1000 cycles: 990 at 10 µs, 8 at 50 µs, and 2 beyond the histogram (max 250 ms).
        let text = r#"{"thread": {"0": {"histogram": {"10": 990, "50": 8},
            "cycles": 1000, "min": 10, "max": 250000, "avg": 12.5, "cpu": 1}}}"#;
        let r = parse(text, "c".into()).unwrap();
        let p = r.latency;
        assert_eq!(
            (p.count, p.min, p.p50, p.p99),
            (1000, 10_000, 10_000, 10_000)
        );
        // Rank 999 lies in the overflow region: bounded by the exact max.
        assert_eq!((p.p999, p.max), (250_000_000, 250_000_000));
        assert_eq!(r.overflows, 2);
        assert_eq!(r.histogram, vec![(10, 990), (50, 8)]);
    }

    #[test]
    fn bad_output_is_an_error_not_a_panic() {
        for t in ["", "{}", r#"{"thread": {"0": {"cycles": 5}}}"#] {
            assert!(
                matches!(parse(t, "c".into()), Err(CyclicError::Output(_))),
                "{t}"
            );
        }
    }

    #[test]
    fn intervals_and_loops() {
        let c = CyclicConfig {
            rate_hz: 10_000.0,
            priority: 80,
            cpu: 1,
            seconds: 1.5,
        };
        assert_eq!((c.interval_us(), c.loops()), (100, 15_000));
    }
}
