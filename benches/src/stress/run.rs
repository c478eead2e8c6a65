//! [`run`]: one stress test — launch the manifest, log it from a separate process (and probe
//! commands from another), and take the executor's own figures over the same window.

use std::collections::HashMap;
use std::ffi::OsString;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use conductor_bus::histogram::{bucket_range, Histogram, BUCKETS};
use conductor_bus::{monotonic_ns, qos, Bus, BusError, Domain, ExecutorStats, StatsSubscriber};

use super::{manifest, parse_line, sine_states, subsystems, StressConfig, PROBE_STATE, SUBSYSTEM};
use conductor_executor::launcher::{Launch, LaunchError, LaunchOptions};

/// Why a stress run failed.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// A file or process operation failed.
    #[error("{context}: {source}")]
    Io {
        /// What was being done.
        context: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// The executor could not be launched.
    #[error("launching the stress manifest: {0}")]
    Launch(#[from] LaunchError),
    /// The bus refused a service.
    #[error("bus: {0}")]
    Bus(#[from] BusError),
    /// A helper process (logger or probe) failed.
    #[error("the {what} process failed ({status}): {stderr}")]
    Helper {
        /// `logger` or `probe`.
        what: &'static str,
        /// Its exit status.
        status: std::process::ExitStatus,
        /// Its standard error.
        stderr: String,
    },
    /// A helper process had not exited `grace` after the window closed (it was killed).
    #[error("the {what} process had not exited {grace:?} after the window closed (killed)")]
    Hung {
        /// `logger`, `subscriber` or `probe`.
        what: &'static str,
        /// How long it was given.
        grace: Duration,
    },
    /// The executor published no statistics.
    #[error("the executor published no statistics within {0:?}")]
    NoStats(Duration),
    /// Bad parameters.
    #[error("{0}")]
    Invalid(String),
}

fn io(context: impl Into<String>) -> impl FnOnce(std::io::Error) -> RunError {
    let context = context.into();
    move |source| RunError::Io { context, source }
}

/// How to run a stress test.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Logged window (s).
    pub seconds: f64,
    /// Time between subscribing and opening the window.
    pub settle: Duration,
    /// The stress tool's program and leading arguments: the logger and the probe run as
    /// `<tool...> log ...` and `<tool...> probe ...` (e.g. `conductor-stress`, or
    /// `conductor __stress`).
    pub tool: Vec<OsString>,
    /// How to launch the executor (its domain is always a fresh unique one).
    pub launch: LaunchOptions,
    /// Keep the generated manifest here instead of a temporary file.
    pub manifest_out: Option<PathBuf>,
    /// Return the first state's thesis error against time ([`RunResult::trace`]).
    pub trace: bool,
    /// Mean interval between probe commands (with [`StressConfig::probe`]); `None`: 10 ms or
    /// 4 base periods, whichever is longer.
    pub probe_interval: Option<Duration>,
}

impl RunOptions {
    /// A `seconds` window, the logger being this program (`<current exe> log ...`).
    pub fn new(seconds: f64) -> Self {
        Self {
            seconds,
            settle: Duration::from_millis(300),
            tool: std::env::current_exe()
                .map(|p| vec![p.into_os_string()])
                .unwrap_or_else(|_| vec!["conductor-stress".into()]),
            launch: LaunchOptions {
                quiet: true,
                handle_signals: false,
                ..LaunchOptions::default()
            },
            manifest_out: None,
            trace: false,
            probe_interval: None,
        }
    }
}

/// The outcome of one stress run.
#[derive(Debug, Clone)]
pub struct RunResult {
    /// What ran.
    pub config: StressConfig,
    /// The executor's thread ran SCHED_FIFO.
    pub rt_active: bool,
    /// The CPU it was pinned to, if any.
    pub pinned_cpu: Option<usize>,
    /// Executor figures over the window (between two stats messages `window_ns` apart): base
    /// ticks executed, summed over the executors.
    pub ticks: u64,
    /// Deadlines missed (slots skipped) in the window, summed over the executors.
    pub misses: u64,
    /// The same, in successive one-second slices of the window (the last may be shorter); they
    /// sum to `misses`.
    pub misses_by_second: Vec<u64>,
    /// Tick lateness (wake-up time − deadline) of the window's ticks, every executor's. Its max
    /// is exact when the window set the run's record, else the upper bound of its bucket
    /// (≤ 12.5 % over).
    pub lateness: Histogram,
    /// Time between the first executor's two stats messages (ns).
    pub window_ns: u64,
    /// CPU time of the executor processes over the window, summed, in % of one CPU (from /proc).
    pub cpu_percent: Option<f64>,
    /// The same CPU time in ns.
    pub cpu_ns: Option<u64>,
    /// The logger's line per sine state (`key → value`, see [`super::StateReport::line`]).
    pub states: Vec<HashMap<String, String>>,
    /// The logger's summary over all sine states ([`super::Summary::line`]); empty without
    /// subscribers.
    pub summary: HashMap<String, String>,
    /// The summary line of each other subscriber process (`subscribers` − 1 of them).
    pub other_subscribers: Vec<HashMap<String, String>>,
    /// The probe's line ([`super::ProbeReport::line`]), with [`StressConfig::probe`].
    pub probe: Option<HashMap<String, String>>,
    /// With [`RunOptions::trace`]: `(seconds since the window opened, sin(t_L) − value)` of the
    /// first state.
    pub trace: Vec<(f64, f64)>,
}

impl RunResult {
    /// Misses in the first and in the second half of the window's one-second slices (an odd
    /// middle slice counts in neither): equal within noise when misses do not grow over time.
    pub fn misses_by_half(&self) -> (u64, u64) {
        halves(&self.misses_by_second)
    }

    /// Ticks per second of one executor over the window (the executors' mean).
    pub fn achieved_hz(&self) -> f64 {
        if self.window_ns == 0 {
            0.0
        } else {
            self.ticks as f64 * 1e9 / self.window_ns as f64 / self.config.executors.max(1) as f64
        }
    }

    /// Executor CPU per tick of the host (µs): the executors' CPU time over the window ÷ the
    /// ticks each executed (their mean), i.e. what one tick of every executor costs together.
    pub fn cpu_us_per_tick(&self) -> Option<f64> {
        let per_executor = self.ticks as f64 / self.config.executors.max(1) as f64;
        let cpu = self.cpu_percent?;
        let hz = self.achieved_hz();
        (per_executor > 0.0 && hz > 0.0).then(|| cpu / 100.0 * 1e6 / hz)
    }

    /// The executor's line: `executor: ticks=.. misses=.. lateness_p50_us=..`.
    pub fn executor_line(&self) -> String {
        let h = &self.lateness;
        format!(
            "executor: ticks={} misses={} misses_by_half={}/{} rt={} cpu={} cpu_percent={} lateness_p50_us={:.1} \
             lateness_p99_us={:.1} lateness_p999_us={:.1} lateness_max_us={:.1} achieved_hz={:.1}",
            self.ticks,
            self.misses,
            self.misses_by_half().0,
            self.misses_by_half().1,
            u8::from(self.rt_active),
            self.pinned_cpu.map_or(-1, |c| c as i64),
            self.cpu_percent
                .map_or_else(|| "n/a".to_string(), |c| format!("{c:.1}")),
            h.quantile(0.5) as f64 / 1e3,
            h.quantile(0.99) as f64 / 1e3,
            h.quantile(0.999) as f64 / 1e3,
            h.max() as f64 / 1e3,
            self.achieved_hz()
        )
    }
}

/// Sums of the first and the second half of `v`, its middle element (odd length) left out.
fn halves(v: &[u64]) -> (u64, u64) {
    let h = v.len() / 2;
    (v[..h].iter().sum(), v[v.len() - h..].iter().sum())
}

/// CPU time (ns) used so far by every thread of process `pid`: the sum of the first field of
/// `/proc/<pid>/task/*/schedstat` (nanosecond resolution), else `utime + stime` of
/// `/proc/<pid>/stat` (clock-tick resolution).
pub fn process_cpu_ns(pid: u32) -> std::io::Result<u64> {
    let tasks = Path::new("/proc").join(pid.to_string()).join("task");
    let mut total = 0u64;
    let mut any = false;
    if let Ok(dir) = std::fs::read_dir(&tasks) {
        for t in dir.flatten() {
            if let Ok(s) = std::fs::read_to_string(t.path().join("schedstat")) {
                if let Some(ns) = s
                    .split_whitespace()
                    .next()
                    .and_then(|f| f.parse::<u64>().ok())
                {
                    total += ns;
                    any = true;
                }
            }
        }
    }
    if any {
        return Ok(total);
    }
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))?;
    let bad = || std::io::Error::new(std::io::ErrorKind::InvalidData, "unexpected /proc stat");
    // Fields after the command name (which may hold spaces) start at field 3; utime and stime
    // are fields 14 and 15.
    let rest = stat.rsplit_once(')').ok_or_else(bad)?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: u64 = f.get(11).and_then(|v| v.parse().ok()).ok_or_else(bad)?;
    let sticks: u64 = f.get(12).and_then(|v| v.parse().ok()).ok_or_else(bad)?;
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as u64;
    Ok((ticks + sticks) * 1_000_000_000 / hz)
}

/// The ticks between two stats messages of one executor.
fn window_lateness(a: &ExecutorStats, b: &ExecutorStats) -> Histogram {
    let mut counts = [0u64; BUCKETS];
    let mut top = None;
    for (i, c) in counts.iter_mut().enumerate() {
        *c = b.histogram[i].saturating_sub(a.histogram[i]);
        if *c > 0 {
            top = Some(i);
        }
    }
    let max = if b.lateness_max_ns > a.lateness_max_ns {
        b.lateness_max_ns
    } else {
        top.map_or(0, |i| bucket_range(i).1.min(b.lateness_max_ns))
    };
    Histogram::from_counts(&counts, max)
}

/// The newest stats, waiting up to `timeout` for the first (or for one newer than `after`).
fn stats(
    sub: &mut StatsSubscriber,
    after: u64,
    timeout: Duration,
) -> Result<ExecutorStats, RunError> {
    let end = Instant::now() + timeout;
    loop {
        if let Some(s) = sub.latest()?.filter(|s| s.seq > after) {
            return Ok(s);
        }
        if Instant::now() > end {
            return Err(RunError::NoStats(timeout));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn spawn(tool: &[OsString], args: &[OsString], what: &str) -> Result<Child, RunError> {
    let (prog, lead) = tool
        .split_first()
        .ok_or_else(|| RunError::Invalid("RunOptions::tool is empty".into()))?;
    Command::new(prog)
        .args(lead)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(io(format!(
            "starting the {what} ({})",
            prog.to_string_lossy()
        )))
}

/// How long a helper may take to exit after the window closed: it exits on its own then, and
/// one that does not (a reader left behind by an overloaded executor) is killed, so that a run
/// ends with an error instead of hanging.
const HELPER_GRACE: Duration = Duration::from_secs(60);

/// Reads a pipe to its end on a thread of its own (a helper that writes more than a pipe holds
/// must not block on it while we wait for it to exit).
fn drain<R: Read + Send + 'static>(pipe: Option<R>) -> Option<std::thread::JoinHandle<Vec<u8>>> {
    pipe.map(|mut r| {
        std::thread::spawn(move || {
            let mut v = Vec::new();
            let _ = r.read_to_end(&mut v);
            v
        })
    })
}

/// Waits for a helper until `deadline` (killing it then) and returns its output lines.
fn finish(
    mut child: Child,
    what: &'static str,
    deadline: Instant,
) -> Result<Vec<String>, RunError> {
    let (stdout, stderr) = (drain(child.stdout.take()), drain(child.stderr.take()));
    let status = loop {
        if let Some(status) = child
            .try_wait()
            .map_err(io(format!("waiting for the {what}")))?
        {
            break status;
        }
        if Instant::now() >= deadline {
            let _ = child.kill();
            let _ = child.wait();
            return Err(RunError::Hung {
                what,
                grace: HELPER_GRACE,
            });
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let join = |h: Option<std::thread::JoinHandle<Vec<u8>>>| {
        h.and_then(|h| h.join().ok()).unwrap_or_default()
    };
    let (stdout, stderr) = (join(stdout), join(stderr));
    if !status.success() {
        return Err(RunError::Helper {
            what,
            status,
            stderr: String::from_utf8_lossy(&stderr).trim().to_string(),
        });
    }
    Ok(BufReader::new(&stdout[..])
        .lines()
        .map_while(Result::ok)
        .collect())
}

/// Runs the stress test of `cfg`: launches its manifest in a fresh domain, starts the logger
/// (and, with `cfg.probe`, the command probe) as separate processes, takes the executor's stats
/// and CPU time at the window's start and end, and stops everything.
pub fn run(cfg: &StressConfig, opts: &RunOptions) -> Result<RunResult, RunError> {
    if !(opts.seconds > 0.0 && cfg.rate_hz > 0.0 && cfg.states > 0) {
        return Err(RunError::Invalid(format!(
            "a stress run needs seconds > 0, rate > 0 and states > 0 (got {} s, {} Hz, {} states)",
            opts.seconds, cfg.rate_hz, cfg.states
        )));
    }
    if !(1..=16).contains(&cfg.executors) || cfg.subscribers > qos::STATE_SUBSCRIBERS {
        return Err(RunError::Invalid(format!(
            "a stress run takes 1–16 executors and at most {} subscribers per state (got {} and {})",
            qos::STATE_SUBSCRIBERS,
            cfg.executors,
            cfg.subscribers
        )));
    }
    let temporary = opts.manifest_out.is_none();
    let path = opts.manifest_out.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!(
            "conductor-stress-{}-{}.toml",
            std::process::id(),
            monotonic_ns()
        ))
    });
    std::fs::write(&path, manifest(cfg)).map_err(io(format!("writing {}", path.display())))?;
    let result = run_manifest(cfg, opts, &path);
    if temporary {
        let _ = std::fs::remove_file(&path);
    }
    result
}

fn run_manifest(cfg: &StressConfig, opts: &RunOptions, path: &Path) -> Result<RunResult, RunError> {
    let domain = Domain::unique("stress")?;
    let launch = Launch::start(
        path,
        LaunchOptions {
            domain: Some(domain.name().into()),
            ..opts.launch.clone()
        },
    )?;
    let subs = subsystems(cfg);
    let pids: Vec<Option<u32>> = subs.iter().map(|s| launch.pid(s)).collect();
    let bus = Bus::open(&domain, "stress-report")?;
    let mut stats_subs = subs
        .iter()
        .map(|s| StatsSubscriber::new(&bus, s))
        .collect::<Result<Vec<_>, _>>()?;

    let secs = opts.seconds.to_string();
    let settle_ms = opts.settle.as_millis().to_string();
    let buffer = cfg.history.max(1).to_string();
    let trace_path = std::env::temp_dir().join(format!(
        "conductor-stress-trace-{}-{}.txt",
        std::process::id(),
        monotonic_ns()
    ));
    let states = sine_states(cfg).join(",");
    // Each reader creates its ready file once subscribed; the window opens for all of them at
    // the time written to the go file once every one is ready.
    let files = |what: &str| {
        std::env::temp_dir().join(format!(
            "conductor-stress-{}-{}-{what}",
            std::process::id(),
            monotonic_ns()
        ))
    };
    let go = files("go");
    let ready: Vec<PathBuf> = (0..cfg.subscribers)
        .map(|i| files(&format!("ready{i}")))
        .collect();
    // Every reader of the states: the logger (the sine checks, the trace) and the other
    // subscribers, which read every sample the same way and report what they lost.
    let reader_args = |logger: bool, ready: &Path| -> Vec<OsString> {
        let mut a: Vec<OsString> = ["log", "--domain", domain.name(), "--summary"]
            .iter()
            .map(Into::into)
            .collect();
        a.extend([
            "--ready".into(),
            ready.into(),
            "--go".into(),
            go.clone().into(),
        ]);
        if logger {
            a.push("--sine".into());
        }
        if cfg.snapshot {
            a.push("--snapshot".into());
        }
        a.extend(
            [
                "--states",
                &states,
                "--seconds",
                &secs,
                "--settle-ms",
                &settle_ms,
                "--buffer",
                &buffer,
            ]
            .iter()
            .map(Into::into),
        );
        a
    };
    let mut log_args = reader_args(true, ready.first().map_or(Path::new(""), |p| p));
    if opts.trace {
        log_args.push("--trace".into());
        log_args.push(trace_path.clone().into());
    }
    // The helpers stay off the executors' CPU, as the rest of a robot computer would with that
    // CPU isolated: what is measured is the executors, not their neighbours on the same core.
    let avoid: Vec<OsString> = cfg
        .cpu
        .map(|c| vec!["--avoid-cpu".into(), c.to_string().into()])
        .unwrap_or_default();
    log_args.extend(avoid.iter().cloned());
    let mut logger = if cfg.subscribers > 0 {
        Some(spawn(&opts.tool, &log_args, "logger")?)
    } else {
        None
    };
    let mut readers = Vec::with_capacity(cfg.subscribers.saturating_sub(1));
    for r in ready.iter().skip(1) {
        let mut args = reader_args(false, r);
        args.extend(avoid.iter().cloned());
        readers.push(spawn(&opts.tool, &args, "subscriber")?);
    }
    let probe = if cfg.probe {
        let interval = opts.probe_interval.unwrap_or_else(|| {
            Duration::from_millis(10).max(Duration::from_secs_f64(4.0 / cfg.rate_hz))
        });
        let mut args: Vec<OsString> = [
            "probe",
            "--domain",
            domain.name(),
            "--state",
            &format!("{SUBSYSTEM}/{PROBE_STATE}"),
            "--seconds",
            &secs,
            "--settle-ms",
            &settle_ms,
            "--interval-us",
            &interval.as_micros().to_string(),
        ]
        .iter()
        .map(Into::into)
        .collect();
        args.extend(avoid);
        Some(spawn(&opts.tool, &args, "probe")?)
    } else {
        None
    };

    // Every reader subscribed (a reader that exits early fails the run when it is collected
    // below), then one window start for all of them, `settle` ahead.
    let give_up = Instant::now() + Duration::from_secs(120);
    let exited = |c: &mut Child| matches!(c.try_wait(), Ok(Some(_)));
    while !ready.iter().all(|p| p.exists()) && Instant::now() < give_up {
        if logger.as_mut().is_some_and(exited) || readers.iter_mut().any(exited) {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let t0 = monotonic_ns() + opts.settle.as_nanos() as u64;
    let go_tmp = files("go-tmp");
    std::fs::write(&go_tmp, t0.to_string())
        .and_then(|()| std::fs::rename(&go_tmp, &go))
        .map_err(io(format!("writing {}", go.display())))?;
    // The executors' window: from the stats message after the readers' window opened to the
    // one `seconds` later (stats come every 100 ms), for each executor.
    std::thread::sleep(opts.settle);
    let a = stats_subs
        .iter_mut()
        .map(|s| stats(s, 0, Duration::from_secs(2)))
        .collect::<Result<Vec<_>, _>>()?;
    let cpu = |pids: &[Option<u32>]| -> Option<u64> {
        pids.iter()
            .map(|p| p.and_then(|p| process_cpu_ns(p).ok()))
            .sum()
    };
    let cpu_a = cpu(&pids);
    let wall_a = monotonic_ns();
    // Stats once a second through the window, so misses can be seen over time: a schedule that
    // drifts or a queue that fills shows as misses growing from slice to slice.
    let window = Duration::from_secs_f64(opts.seconds);
    let opened = Instant::now();
    let mut b = a.clone();
    let mut misses_by_second = Vec::with_capacity(opts.seconds.ceil() as usize + 1);
    loop {
        let left = window.saturating_sub(opened.elapsed());
        if left.is_zero() {
            break;
        }
        std::thread::sleep(left.min(Duration::from_secs(1)));
        let mut slice = 0;
        for (sub, last) in stats_subs.iter_mut().zip(b.iter_mut()) {
            let s = stats(sub, last.seq, Duration::from_secs(2))?;
            slice += s.misses - last.misses;
            *last = s;
        }
        misses_by_second.push(slice);
    }
    let cpu_b = cpu(&pids);
    let wall_b = monotonic_ns();

    let deadline = Instant::now() + HELPER_GRACE;
    let log_lines = logger.map(|l| finish(l, "logger", deadline)).transpose();
    let reader_lines: Vec<_> = readers
        .into_iter()
        .map(|r| finish(r, "subscriber", deadline))
        .collect();
    let probe_lines = probe.map(|p| finish(p, "probe", deadline)).transpose();
    for p in ready.iter().chain([&go]) {
        let _ = std::fs::remove_file(p);
    }
    drop(stats_subs);
    drop(bus);
    launch.stop();
    let ended = launch.wait();
    let trace = if opts.trace && cfg.subscribers > 0 {
        let t = read_trace(&trace_path);
        let _ = std::fs::remove_file(&trace_path);
        t?
    } else {
        Vec::new()
    };
    let log_lines = log_lines?.unwrap_or_default();
    let probe_lines = probe_lines?;
    let mut other_subscribers = Vec::with_capacity(reader_lines.len());
    for lines in reader_lines {
        other_subscribers.push(summary_of(&lines?));
    }
    ended?;

    let parsed: Vec<HashMap<String, String>> = log_lines.iter().map(|l| parse_line(l)).collect();
    let states: Vec<_> = parsed
        .iter()
        .filter(|kv| kv.contains_key("state"))
        .cloned()
        .collect();
    let summary = summary_of(&log_lines);
    let probe = probe_lines.and_then(|lines| {
        lines
            .iter()
            .map(|l| parse_line(l))
            .find(|kv| kv.contains_key("probe"))
    });
    let (cpu_ns, cpu_percent) = match (cpu_a, cpu_b) {
        (Some(x), Some(y)) if wall_b > wall_a => {
            let ns = y.saturating_sub(x);
            (Some(ns), Some(ns as f64 * 100.0 / (wall_b - wall_a) as f64))
        }
        _ => (None, None),
    };
    let mut lateness = Histogram::new();
    for (a, b) in a.iter().zip(&b) {
        lateness.merge(&window_lateness(a, b));
    }
    let (first_a, first_b) = (&a[0], &b[0]);
    Ok(RunResult {
        config: *cfg,
        rt_active: b.iter().all(|s| s.rt_active != 0),
        pinned_cpu: usize::try_from(first_b.cpu).ok(),
        ticks: a.iter().zip(&b).map(|(a, b)| b.ticks - a.ticks).sum(),
        misses: a.iter().zip(&b).map(|(a, b)| b.misses - a.misses).sum(),
        misses_by_second,
        lateness,
        window_ns: first_b.t_ns.saturating_sub(first_a.t_ns),
        cpu_percent,
        cpu_ns,
        states,
        summary,
        other_subscribers,
        probe,
        trace,
    })
}

/// The `summary=all` line among a reader's output lines, parsed (empty when it has none).
fn summary_of(lines: &[String]) -> HashMap<String, String> {
    lines
        .iter()
        .map(|l| parse_line(l))
        .find(|kv| kv.contains_key("summary"))
        .unwrap_or_default()
}

/// Reads a trace written by `log --trace`: lines of `<t_L ns> <error>`; times are returned in
/// seconds since the first line.
fn read_trace(path: &Path) -> Result<Vec<(f64, f64)>, RunError> {
    let text = std::fs::read_to_string(path).map_err(io(format!("reading {}", path.display())))?;
    let mut out = Vec::new();
    let mut t0 = None;
    for line in text.lines() {
        let mut f = line.split_whitespace();
        let (Some(Ok(t)), Some(Ok(e))) = (
            f.next().map(str::parse::<u64>),
            f.next().map(str::parse::<f64>),
        ) else {
            return Err(RunError::Invalid(format!(
                "{}: a trace line is not `<ns> <error>`: {line:?}",
                path.display()
            )));
        };
        let t0 = *t0.get_or_insert(t);
        out.push((t.saturating_sub(t0) as f64 * 1e-9, e));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use conductor_bus::histogram::bucket_of;

    #[test]
    fn cpu_time_of_this_process_grows_with_work() {
        let me = std::process::id();
        let a = process_cpu_ns(me).unwrap();
        // Burn about 20 ms of CPU; the reading must grow by at least part of it (schedstat is in
        // ns; the /proc/stat fallback in clock ticks of 10 ms at most).
        let t = Instant::now();
        let mut x = 0u64;
        while t.elapsed() < Duration::from_millis(20) {
            x = std::hint::black_box(x.wrapping_add(1));
        }
        let b = process_cpu_ns(me).unwrap();
        assert!(b > a, "{a} → {b}");
    }

    #[test]
    fn halves_leave_out_an_odd_middle() {
        assert_eq!(halves(&[]), (0, 0));
        assert_eq!(halves(&[5]), (0, 0));
        assert_eq!(halves(&[1, 2]), (1, 2));
        assert_eq!(halves(&[1, 2, 100, 3, 4]), (3, 7));
    }

    #[test]
    fn the_window_is_the_difference_of_two_stats_messages() {
        let mut a = ExecutorStats::default();
        let mut b = ExecutorStats::default();
        a.histogram[bucket_of(1_000)] = 5;
        a.lateness_max_ns = 90_000;
        b.histogram[bucket_of(1_000)] = 8;
        b.histogram[bucket_of(20_000)] = 2;
        b.lateness_max_ns = 90_000;
        let w = window_lateness(&a, &b);
        assert_eq!(w.count(), 5);
        // No new record in the window: the max is its top bucket's bound.
        assert_eq!(w.max(), bucket_range(bucket_of(20_000)).1);
        b.histogram[bucket_of(200_000)] = 1;
        b.lateness_max_ns = 200_000;
        assert_eq!(window_lateness(&a, &b).max(), 200_000);
    }

    #[test]
    fn traces_are_read_back_relative_to_their_start() {
        let p = std::env::temp_dir().join(format!("trace-test-{}.txt", std::process::id()));
        std::fs::write(&p, "1000000000 0.5\n1500000000 -0.25\n").unwrap();
        assert_eq!(read_trace(&p).unwrap(), vec![(0.0, 0.5), (0.5, -0.25)]);
        std::fs::write(&p, "1 x\n").unwrap();
        assert!(matches!(read_trace(&p), Err(RunError::Invalid(_))));
        let _ = std::fs::remove_file(&p);
    }
}
