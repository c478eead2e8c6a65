//! `cargo xtask fuzz`: every fuzz target of the project for a set number of executions, one
//! after another, and a table of what each did (executions, time, rate, corpus, crashes).
//!
//! The targets live in standalone cargo-fuzz crates (excluded from the workspace) listed in
//! [`CRATES`]; their checks also run as ordinary tests on the committed corpora, so CI needs
//! neither cargo-fuzz nor a nightly compiler. Here libFuzzer does the work: cargo-fuzz is
//! installed if missing and run with `RUSTC_BOOTSTRAP=1`, so the stable toolchain suffices.
//!
//! Each target runs on `<crate>/corpus/<target>` (a working corpus, not committed) seeded from
//! `seeds/<target>` and `regressions/<target>`. A crash stops that target: its input is left in
//! `<crate>/artifacts/<target>/` and the task fails after the table. `--update-seeds` replaces
//! `seeds/<target>` by a minimised merge of everything the target has found (what to commit).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use crate::{root, run, Result};

/// The cargo-fuzz crates, relative to the workspace root.
pub const CRATES: &[&str] = &[
    "protocols/fuzz",
    "score/core/fuzz",
    "executors/fuzz",
    "tools/cli/fuzz",
];

/// Build flags of every campaign: optimised, with debug assertions and overflow checks (so an
/// arithmetic overflow is a crash, as in the debug test builds), no sanitizer (the code under
/// test is safe Rust; ASan would halve the rate for little).
const BUILD: &[&str] = &["--release", "--debug-assertions", "--sanitizer", "none"];

/// The longest input each target is given (libFuzzer's `-max_len`), from what real input of
/// that kind looks like; a target not listed gets libFuzzer's default (the largest seed, at
/// least 4 KiB). The scanners hold a fixed window, so a few windows' worth of bytes reaches
/// every state a longer stream does (the rest repeats them) at a fraction of the cost.
pub const MAX_LEN: &[(&str, usize, &str)] = &[
    (
        "dxl2_scanner",
        1024,
        "4 windows of the 256-byte scanner: bursts of packets, resync over garbage, wrap",
    ),
    ("dxl1_scanner", 1200, "4 windows of the 300-byte scanner"),
    (
        "slcan_host_scanner",
        512,
        "17 SLCAN lines of the longest kind (30 bytes) through a 48-byte window",
    ),
    (
        "slcan_device_scanner",
        512,
        "17 SLCAN command lines through a 40-byte window",
    ),
    (
        "score_link_scanner",
        1024,
        "4 frames of the longest kind (254 bytes)",
    ),
    (
        "score_link_decode",
        300,
        "one message (at most 250 bytes) and some over",
    ),
    (
        "can_decode",
        128,
        "a CAN payload (8 bytes) or one SLCAN line (at most 30 bytes), with room for junk",
    ),
    (
        "dxl1_decode",
        300,
        "one Dynamixel 1.0 packet (at most 259 bytes) and some over",
    ),
    (
        "udp_request",
        300,
        "one datagram of the text protocol (at most 256 bytes) and some over",
    ),
    (
        "parse_line",
        2048,
        "a script of lines up to the 160-byte line editor's length",
    ),
    ("terminal", 2048, "a terminal session up to 48 lines"),
];

/// `-max_len` for `target`, if it has one.
fn max_len(target: &str) -> Option<usize> {
    MAX_LEN
        .iter()
        .find(|(t, _, _)| *t == target)
        .map(|&(_, n, _)| n)
}

struct Options {
    /// The arguments as given, for the report.
    args: Vec<String>,
    runs: u64,
    max_time: u64,
    only: Vec<String>,
    out: PathBuf,
    update_seeds: bool,
}

fn usage() -> String {
    "usage: cargo xtask fuzz [--runs N] [--max-time SECONDS] [--only T1,T2] [--out FILE] \
     [--update-seeds]\n  \
     --runs N            executions per target (default 100000)\n  \
     --max-time SECONDS  stop a target after this long even if N is not reached (default 0: no limit)\n  \
     --only T1,T2        only these targets\n  \
     --out FILE          write the table (markdown) here too (default target/fuzz-report.md)\n  \
     --update-seeds      replace seeds/<target> by a minimised merge of the corpus afterwards"
        .into()
}

fn parse(args: &[String]) -> Result<Options> {
    let mut o = Options {
        args: args.to_vec(),
        runs: 100_000,
        max_time: 0,
        only: Vec::new(),
        out: root().join("target/fuzz-report.md"),
        update_seeds: false,
    };
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = |what: &str| {
            it.next()
                .cloned()
                .ok_or_else(|| format!("{what} needs a value\n{}", usage()))
        };
        match a.as_str() {
            "--runs" => {
                o.runs = parse_count(&value("--runs")?)?;
            }
            "--max-time" => {
                o.max_time = parse_count(&value("--max-time")?)?;
            }
            "--only" => {
                o.only = value("--only")?.split(',').map(str::to_string).collect();
            }
            "--out" => o.out = PathBuf::from(value("--out")?),
            "--update-seeds" => o.update_seeds = true,
            "-h" | "--help" => return Err(usage()),
            other => return Err(format!("unknown argument {other:?}\n{}", usage())),
        }
    }
    Ok(o)
}

/// A count such as `10000000`, `1e7` or `10_000_000`.
fn parse_count(s: &str) -> Result<u64> {
    let t = s.replace('_', "");
    if let Ok(n) = t.parse::<u64>() {
        return Ok(n);
    }
    match t.parse::<f64>() {
        Ok(x) if x.is_finite() && x >= 0.0 && x.fract() == 0.0 && x < 1.8e19 => Ok(x as u64),
        _ => Err(format!("not a whole number: {s:?}")),
    }
}

/// What one target did.
struct Outcome {
    krate: String,
    target: String,
    runs: u64,
    seconds: f64,
    corpus: usize,
    crashes: Vec<PathBuf>,
    note: String,
}

/// Runs the campaign; fails if any target crashed.
pub fn fuzz(args: &[String]) -> Result {
    let o = parse(args)?;
    cargo_fuzz()?;
    let root = root();
    let mut outcomes = Vec::new();
    let started = Instant::now();
    for krate in CRATES {
        let dir = root.join(krate);
        let targets: Vec<String> = list_targets(&dir)?
            .into_iter()
            .filter(|t| o.only.is_empty() || o.only.contains(t))
            .collect();
        if targets.is_empty() {
            continue;
        }
        let mut build = fuzz_cmd(&dir);
        build.arg("build").args(BUILD);
        run(&mut build)?;
        for t in targets {
            let r = campaign(&dir, krate, &t, &o)?;
            eprintln!(
                "xtask fuzz: {krate} {t}: {} runs in {:.0} s, {} crash(es)",
                r.runs,
                r.seconds,
                r.crashes.len()
            );
            outcomes.push(r);
        }
    }
    for t in &o.only {
        if !outcomes.iter().any(|r| &r.target == t) {
            return Err(format!("no fuzz target called {t:?}"));
        }
    }
    let table = table(&outcomes, &o, started.elapsed().as_secs_f64());
    println!("{table}");
    if let Some(parent) = o.out.parent() {
        std::fs::create_dir_all(parent).map_err(|e| format!("{}: {e}", parent.display()))?;
    }
    std::fs::write(&o.out, &table).map_err(|e| format!("{}: {e}", o.out.display()))?;
    eprintln!("xtask fuzz: table written to {}", o.out.display());
    let crashed: Vec<String> = outcomes
        .iter()
        .flat_map(|r| r.crashes.iter().map(|p| p.display().to_string()))
        .collect();
    if crashed.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "crashing inputs (add each to regressions/<target>/ once fixed):\n  {}",
            crashed.join("\n  ")
        ))
    }
}

/// Installs cargo-fuzz if `cargo fuzz` is missing.
fn cargo_fuzz() -> Result {
    let present = Command::new(env!("CARGO"))
        .args(["fuzz", "--version"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if present {
        return Ok(());
    }
    run(Command::new(env!("CARGO")).args(["install", "cargo-fuzz", "--locked"]))
}

/// `cargo fuzz` in `dir`, allowed to use the unstable flags libFuzzer needs on stable Rust.
fn fuzz_cmd(dir: &Path) -> Command {
    let mut c = Command::new(env!("CARGO"));
    c.current_dir(dir).arg("fuzz").env("RUSTC_BOOTSTRAP", "1");
    c
}

fn list_targets(dir: &Path) -> Result<Vec<String>> {
    let out = fuzz_cmd(dir)
        .arg("list")
        .output()
        .map_err(|e| format!("cargo fuzz list in {}: {e}", dir.display()))?;
    if !out.status.success() {
        return Err(format!(
            "cargo fuzz list in {} failed: {}",
            dir.display(),
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    Ok(String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| l.trim().to_string())
        .filter(|l| !l.is_empty())
        .collect())
}

fn files_in(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default()
}

/// One target for `o.runs` executions (or `o.max_time` seconds).
fn campaign(dir: &Path, krate: &str, target: &str, o: &Options) -> Result<Outcome> {
    let corpus = dir.join("corpus").join(target);
    let seeds = dir.join("seeds").join(target);
    let regressions = dir.join("regressions").join(target);
    let artifacts = dir.join("artifacts").join(target);
    for d in [&corpus, &artifacts] {
        std::fs::create_dir_all(d).map_err(|e| format!("{}: {e}", d.display()))?;
    }
    let before: Vec<PathBuf> = files_in(&artifacts);
    let mut c = fuzz_cmd(dir);
    c.arg("run").args(BUILD).arg(target).arg(&corpus);
    for extra in [&seeds, &regressions] {
        if extra.is_dir() {
            c.arg(extra);
        }
    }
    c.arg("--")
        .arg(format!("-runs={}", o.runs))
        .arg(format!("-max_total_time={}", o.max_time))
        // A hang is a failure too: no single input may take more than 10 s.
        .arg("-timeout=10")
        .arg("-rss_limit_mb=2048")
        .arg("-print_final_stats=1")
        .arg(format!("-artifact_prefix={}/", artifacts.display()));
    if let Some(n) = max_len(target) {
        c.arg(format!("-max_len={n}"));
    }
    eprintln!("xtask: running {c:?}");
    let t = Instant::now();
    let out = c
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .output()
        .map_err(|e| format!("cannot start cargo fuzz run {target}: {e}"))?;
    let seconds = t.elapsed().as_secs_f64();
    let log = String::from_utf8_lossy(&out.stderr);
    let log_path = artifacts.join("last-run.log");
    let _ = std::fs::write(&log_path, log.as_bytes());
    let runs = executed(&log);
    let crashes: Vec<PathBuf> = files_in(&artifacts)
        .into_iter()
        .filter(|p| !before.contains(p) && p != &log_path)
        .collect();
    let lines: Vec<&str> = log.lines().collect();
    let note = if !out.status.success() && crashes.is_empty() {
        format!("{}; see {}", out.status, log_path.display())
    } else if crashes.is_empty() {
        // A clean run: panics in its log were caught by the code under test (the recording
        // reader refuses a file the mcap reader panics on), so they are no crash's cause.
        String::new()
    } else if let Some(i) = lines.iter().rposition(|l| l.contains("panicked at")) {
        // The last panic is the fatal one: `panicked at file:line:col:`, then the message.
        let at = lines[i];
        let at = at
            .split("panicked at ")
            .nth(1)
            .unwrap_or(at)
            .trim_end_matches(':');
        let msg = lines.get(i + 1).copied().unwrap_or_default().trim();
        format!("{at}: {msg}").chars().take(120).collect()
    } else if let Some(line) = lines.iter().find(|l| l.contains("ERROR: libFuzzer")) {
        line.trim().chars().take(120).collect()
    } else {
        String::new()
    };
    if o.update_seeds {
        update_seeds(dir, target, &corpus, &seeds, &regressions)?;
    }
    Ok(Outcome {
        krate: krate.to_string(),
        target: target.to_string(),
        runs,
        seconds,
        corpus: files_in(&corpus).len(),
        crashes,
        note,
    })
}

/// Executions reported by libFuzzer: the final statistics, else the last status line.
fn executed(log: &str) -> u64 {
    if let Some(n) = log
        .lines()
        .find_map(|l| l.strip_prefix("stat::number_of_executed_units:"))
        .and_then(|v| v.trim().parse().ok())
    {
        return n;
    }
    log.lines()
        .rev()
        .find_map(|l| {
            let rest = l.strip_prefix('#')?;
            let n: String = rest.chars().take_while(char::is_ascii_digit).collect();
            n.parse().ok()
        })
        .unwrap_or(0)
}

/// `seeds/<target>` := a minimised merge of the seeds, the working corpus and the regressions.
fn update_seeds(dir: &Path, target: &str, corpus: &Path, seeds: &Path, regs: &Path) -> Result {
    let merged = dir.join("corpus").join(format!("{target}.merged"));
    let _ = std::fs::remove_dir_all(&merged);
    std::fs::create_dir_all(&merged).map_err(|e| format!("{}: {e}", merged.display()))?;
    let mut c = fuzz_cmd(dir);
    c.arg("run")
        .args(BUILD)
        .arg(target)
        .arg(&merged)
        .arg(corpus);
    for extra in [seeds, regs] {
        if extra.is_dir() {
            c.arg(extra);
        }
    }
    c.args(["--", "-merge=1", "-timeout=10", "-rss_limit_mb=2048"]);
    if let Some(n) = max_len(target) {
        c.arg(format!("-max_len={n}"));
    }
    c.stdout(Stdio::null()).stderr(Stdio::null());
    run(&mut c)?;
    let _ = std::fs::remove_dir_all(seeds);
    if let Some(parent) = seeds.parent() {
        std::fs::create_dir_all(parent).map_err(|e| format!("{}: {e}", parent.display()))?;
    }
    std::fs::rename(&merged, seeds).map_err(|e| format!("{}: {e}", seeds.display()))?;
    eprintln!(
        "xtask fuzz: {} now holds {} inputs",
        seeds.display(),
        files_in(seeds).len()
    );
    Ok(())
}

/// The report: command, machine, one row per target, totals.
fn table(rows: &[Outcome], o: &Options, total_s: f64) -> String {
    let mut s = String::new();
    let machine = machine();
    let _ = writeln!(
        s,
        "Command: `cargo xtask fuzz {}` ({}; {:.0} min in all)\n",
        o.args.join(" "),
        machine,
        total_s / 60.0
    );
    let _ = writeln!(
        s,
        "| crate | target | executions | time (s) | exec/s | corpus | crashes |"
    );
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|");
    for r in rows {
        let rate = if r.seconds > 0.0 {
            r.runs as f64 / r.seconds
        } else {
            0.0
        };
        let crashes = if r.crashes.is_empty() && r.note.is_empty() {
            "0".to_string()
        } else if r.crashes.is_empty() {
            format!("0 ({})", r.note)
        } else {
            format!("{} ({})", r.crashes.len(), r.note)
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.0} | {:.0} | {} | {} |",
            r.krate, r.target, r.runs, r.seconds, rate, r.corpus, crashes
        );
    }
    let runs: u64 = rows.iter().map(|r| r.runs).sum();
    let crashes: usize = rows.iter().map(|r| r.crashes.len()).sum();
    let _ = writeln!(
        s,
        "\n{} targets, {runs} executions, {crashes} crashes; {} of {} targets reached {} executions.",
        rows.len(),
        rows.iter().filter(|r| r.runs >= o.runs).count(),
        rows.len(),
        o.runs
    );
    s
}

/// Date, CPU model and count, and the compiler, for the report's header.
fn machine() -> String {
    let sh = |cmd: &str| {
        Command::new("sh")
            .args(["-c", cmd])
            .output()
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
            .unwrap_or_default()
    };
    format!(
        "{}; {} × {}; {}",
        sh("date -u '+%Y-%m-%d %H:%M UTC'"),
        sh("nproc"),
        sh("sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -1"),
        sh("rustc --version")
    )
}
