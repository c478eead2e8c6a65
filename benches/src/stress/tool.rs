//! The stress test's command line, shared by `conductor-stress` and `conductor bench`'s helper
//! processes (`conductor __stress ...`):
//!
//! * `run` launches the stress manifest, logs it from a separate process and prints the report;
//! * `log` is that logger: it counts each state's samples whose sample time falls in a window
//!   and prints one `key=value` line per state (also used by the executor's tests as the
//!   external subscriber process), optionally a summary line and the Fig. 3.1 trace;
//! * `probe` is the external controller of the command probe ([`super::CommandProbe`]).

use std::ffi::OsString;
use std::io::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::{Parser, Subcommand};
use conductor_bus::{monotonic_ns, Bus, Domain};

use super::{run, CommandProbe, Logger, RunOptions, StressConfig};
use crate::suite::{scaling, Helpers};
use conductor_executor::launcher::LaunchOptions;

/// `conductor-stress`.
#[derive(Debug, Parser)]
#[command(
    name = "conductor-stress",
    version,
    about = "The thesis' stress test: sine states at a rate, an external logger and a command probe"
)]
pub struct StressCli {
    /// What to do.
    #[command(subcommand)]
    pub cmd: Cmd,
}

/// The sub-commands.
#[derive(Debug, Subcommand)]
pub enum Cmd {
    /// Launch the stress manifest and log it from another process.
    Run {
        /// Sample rate (Hz).
        #[arg(long, default_value_t = 1000.0)]
        rate: f64,
        /// Logged duration (s).
        #[arg(long, default_value_t = 5.0)]
        seconds: f64,
        /// Number of sine states.
        #[arg(long, default_value_t = 3)]
        states: usize,
        /// CPU for the executor.
        #[arg(long)]
        cpu: Option<usize>,
        /// SCHED_FIFO priority.
        #[arg(long, default_value_t = 80)]
        priority: i32,
        /// Spin this long before each deadline (µs).
        #[arg(long, default_value_t = 0.0)]
        spin_us: f64,
        /// Run the executor without real-time set-up.
        #[arg(long)]
        no_rt: bool,
        /// Also measure controller command → hardware write with a probe process.
        #[arg(long)]
        probe: bool,
        /// Keep the generated manifest here instead of a temporary file.
        #[arg(long)]
        manifest_out: Option<PathBuf>,
    },
    /// The scaling curves of `conductor bench --scaling` (the same library function, this
    /// program as every helper): CPU per tick and sample → controller latency against states,
    /// subscribers per state and executors per host, with the fitted per-unit costs.
    Scaling {
        /// Fewer points, 1 s each.
        #[arg(long)]
        quick: bool,
        /// Output directory (report.md, report.json, *.png).
        #[arg(short, long, default_value = "bench-out")]
        out: PathBuf,
        /// States of the states sweep [default: 1,10,41,200,1000; --quick: 1,10,41].
        #[arg(long, value_delimiter = ',')]
        states: Vec<usize>,
        /// Logged seconds per point [default: 5; --quick: 1].
        #[arg(long)]
        seconds: Option<f64>,
        /// CPU of the executors [default: the last one].
        #[arg(long)]
        cpu: Option<usize>,
    },
    /// Subscribe to states and report what arrived (one `key=value` line per state).
    Log {
        /// Bus domain.
        #[arg(long)]
        domain: String,
        /// States to log, `subsystem/state`, comma-separated.
        #[arg(long, value_delimiter = ',', required = true)]
        states: Vec<String>,
        /// Window length (s) over which samples are counted by their sample time.
        #[arg(long, default_value_t = 2.0)]
        seconds: f64,
        /// Wait this long (ms) after subscribing before the window opens.
        #[arg(long, default_value_t = 200)]
        settle_ms: u64,
        /// The states carry sin(t_S): report the thesis' errors.
        #[arg(long)]
        sine: bool,
        /// Also print a `summary=all` line over every state.
        #[arg(long)]
        summary: bool,
        /// Each subscriber's buffer (samples; at most the states' history).
        #[arg(long, default_value_t = 4096)]
        buffer: usize,
        /// Create this file once subscribed, then read every sample while waiting for `--go`.
        #[arg(long, requires = "go")]
        ready: Option<PathBuf>,
        /// Open the window at the CLOCK_MONOTONIC time (ns) this file holds, once it exists
        /// (instead of `--settle-ms` after subscribing): every reader of a run shares one window.
        #[arg(long, requires = "ready")]
        go: Option<PathBuf>,
        /// Write the first state's `<t_L ns> <sin(t_L) − value>` per sample here (with --sine).
        #[arg(long)]
        trace: Option<PathBuf>,
        /// Stay off this CPU (the executor's), as processes do on a robot computer whose
        /// real-time CPU is isolated.
        #[arg(long)]
        avoid_cpu: Option<usize>,
        /// Read each subsystem's snapshot (one sample per tick, all states) instead of
        /// subscribing to every state.
        #[arg(long)]
        snapshot: bool,
    },
    /// Send setpoints to a loopback state and time them (one `probe=...` line).
    Probe {
        /// Bus domain.
        #[arg(long)]
        domain: String,
        /// The writable loopback state, `subsystem/state`.
        #[arg(long)]
        state: String,
        /// Probing time (s).
        #[arg(long, default_value_t = 2.0)]
        seconds: f64,
        /// Wait this long (ms) after subscribing before the first command.
        #[arg(long, default_value_t = 200)]
        settle_ms: u64,
        /// Mean interval between commands (µs); each is drawn from 0.5–1.5× this, so commands
        /// land at random phases of the executor's tick.
        #[arg(long, default_value_t = 10_000)]
        interval_us: u64,
        /// Stay off this CPU (the executor's), as processes do on a robot computer whose
        /// real-time CPU is isolated.
        #[arg(long)]
        avoid_cpu: Option<usize>,
    },
}

/// Where `run` finds its helpers and executor.
#[derive(Debug, Clone)]
pub struct ToolContext {
    /// This tool's program and leading arguments (for the logger and probe processes).
    pub tool: Vec<OsString>,
    /// How to launch the executor.
    pub launch: LaunchOptions,
}

/// Runs the tool with `args` (program name first).
pub fn main_with_args(args: impl IntoIterator<Item = OsString>, ctx: ToolContext) -> ExitCode {
    let cli = match StressCli::try_parse_from(args) {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return ExitCode::from(if e.use_stderr() { 2 } else { 0 });
        }
    };
    let (what, result) = match cli.cmd {
        Cmd::Log {
            domain,
            states,
            seconds,
            settle_ms,
            sine,
            summary,
            buffer,
            ready,
            go,
            trace,
            avoid_cpu,
            snapshot,
        } => (
            "log",
            keep_off(avoid_cpu).and_then(|()| {
                log(
                    &domain,
                    &states,
                    Window {
                        seconds,
                        settle_ms,
                        handshake: ready.zip(go),
                    },
                    Reading {
                        sine,
                        summary,
                        buffer,
                        snapshot,
                    },
                    trace,
                )
            }),
        ),
        Cmd::Probe {
            domain,
            state,
            seconds,
            settle_ms,
            interval_us,
            avoid_cpu,
        } => (
            "probe",
            keep_off(avoid_cpu)
                .and_then(|()| probe(&domain, &state, seconds, settle_ms, interval_us)),
        ),
        Cmd::Scaling {
            quick,
            out,
            states,
            seconds,
            cpu,
        } => {
            let helpers = Helpers {
                launch: LaunchOptions {
                    quiet: true,
                    handle_signals: false,
                    ..ctx.launch
                },
                stress_tool: ctx.tool,
                pingpong_child: Vec::new(),
            };
            let mut cfg = crate::suite::Config::new(quick, helpers);
            let mut plan = scaling::Plan::new(quick);
            if !states.is_empty() {
                plan.states = states;
            }
            cfg.seconds = seconds.unwrap_or(if quick {
                scaling::QUICK_SECONDS
            } else {
                scaling::FULL_SECONDS
            });
            if let Some(c) = cpu {
                cfg.cpu = c;
            }
            cfg.out = out;
            cfg.command = std::env::args().collect::<Vec<_>>().join(" ");
            let r = scaling::run(&cfg, &plan).map(|r| println!("{}", r.markdown()));
            ("scaling", r.map_err(|e| e.to_string()))
        }
        Cmd::Run {
            rate,
            seconds,
            states,
            cpu,
            priority,
            spin_us,
            no_rt,
            probe,
            manifest_out,
        } => {
            let cfg = StressConfig {
                rate_hz: rate,
                cpu,
                priority,
                spin_us,
                states,
                probe,
                ..StressConfig::default()
            };
            let mut opts = RunOptions::new(seconds);
            opts.tool = ctx.tool;
            opts.launch = LaunchOptions {
                no_rt,
                ..ctx.launch
            };
            opts.manifest_out = manifest_out;
            ("run", run_and_print(&cfg, &opts))
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            conductor_executor::note!("conductor-stress {what}: {e}");
            ExitCode::FAILURE
        }
    }
}

/// `--avoid-cpu`: keeps this helper process off the executor's CPU.
fn keep_off(cpu: Option<usize>) -> Result<(), String> {
    match cpu {
        Some(c) => {
            conductor_executor::rt::avoid_cpu(c).map_err(|p| format!("{}; {}", p.what, p.fix))
        }
        None => Ok(()),
    }
}

/// A logger's window: it opens `settle_ms` after subscribing, or with `handshake` (ready file,
/// go file) at the time the go file gives, and lasts `seconds`.
struct Window {
    seconds: f64,
    settle_ms: u64,
    handshake: Option<(PathBuf, PathBuf)>,
}

/// How long a reader waits for its go file before giving up.
const GO_TIMEOUT: Duration = Duration::from_secs(120);

/// Says the logger is subscribed (`ready`), reads every sample while the other readers come up,
/// and returns the window start the run wrote into `go`.
fn handshake(
    logger: &mut Logger,
    ready: &std::path::Path,
    go: &std::path::Path,
) -> Result<u64, String> {
    std::fs::write(ready, b"").map_err(|e| format!("writing {}: {e}", ready.display()))?;
    let give_up = Instant::now() + GO_TIMEOUT;
    loop {
        if let Some(t0) = std::fs::read_to_string(go)
            .ok()
            .and_then(|t| t.trim().parse::<u64>().ok())
        {
            return Ok(t0);
        }
        if Instant::now() > give_up {
            return Err(format!(
                "no window start in {} after {GO_TIMEOUT:?}",
                go.display()
            ));
        }
        logger.poll().map_err(|e| e.to_string())?;
        logger
            .wait(Duration::from_millis(5))
            .map_err(|e| e.to_string())?;
    }
}

/// How `log` reads and what it prints.
struct Reading {
    /// The sin(t) checks.
    sine: bool,
    /// A summary line.
    summary: bool,
    /// Each subscriber's buffer.
    buffer: usize,
    /// Snapshots instead of per-state subscribers.
    snapshot: bool,
}

fn log(
    domain: &str,
    states: &[String],
    Window {
        seconds,
        settle_ms,
        handshake: files,
    }: Window,
    Reading {
        sine,
        summary,
        buffer,
        snapshot,
    }: Reading,
    trace: Option<PathBuf>,
) -> Result<(), String> {
    let domain = Domain::new(domain).map_err(|e| e.to_string())?;
    let bus = Bus::open(&domain, "stress-logger").map_err(|e| e.to_string())?;
    // The states may still be coming up: retry for a while.
    let give_up = Instant::now() + Duration::from_secs(10);
    let mut logger = loop {
        let opened = if snapshot {
            Logger::with_snapshots(&bus, states, sine)
        } else {
            Logger::new(&bus, states, sine, buffer)
        };
        match opened {
            Ok(l) => break l,
            Err(e) if Instant::now() > give_up => return Err(e.to_string()),
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    };
    if trace.is_some() {
        let rate = logger.reports().first().map_or(0.0, |r| r.rate_hz);
        // One point per sample of the window, plus room for a late tail.
        logger.keep_trace(((rate * (seconds + 1.0)) as usize).min(20_000_000));
    }
    let t0 = match &files {
        Some((ready, go)) => handshake(&mut logger, ready, go)?,
        None => monotonic_ns() + settle_ms * 1_000_000,
    };
    let t1 = t0 + (seconds * 1e9) as u64;
    logger.set_window(t0, t1);
    // Samples of the window's last instants arrive a little after it closes.
    while monotonic_ns() < t1 + 100_000_000 {
        logger.poll().map_err(|e| e.to_string())?;
        logger
            .wait(Duration::from_millis(5))
            .map_err(|e| e.to_string())?;
    }
    logger.poll().map_err(|e| e.to_string())?;
    if let Some(path) = trace {
        let mut text = String::with_capacity(logger.trace().len() * 24);
        for (t, e) in logger.trace() {
            text += &format!("{t} {e:e}\n");
        }
        std::fs::write(&path, text).map_err(|e| format!("writing {}: {e}", path.display()))?;
    }
    let mut out = std::io::stdout().lock();
    for r in logger.reports() {
        writeln!(out, "{}", r.line()).map_err(|e| e.to_string())?;
    }
    if summary {
        writeln!(out, "{}", logger.summary().line()).map_err(|e| e.to_string())?;
    }
    Ok(())
}

fn probe(
    domain: &str,
    state: &str,
    seconds: f64,
    settle_ms: u64,
    interval_us: u64,
) -> Result<(), String> {
    let domain = Domain::new(domain).map_err(|e| e.to_string())?;
    let bus = Bus::open(&domain, "stress-probe").map_err(|e| e.to_string())?;
    let give_up = Instant::now() + Duration::from_secs(10);
    let mut probe = loop {
        match CommandProbe::new(&bus, state) {
            Ok(p) => break p,
            Err(e) if Instant::now() > give_up => return Err(e.to_string()),
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    };
    let start = Instant::now() + Duration::from_millis(settle_ms);
    let end = start + Duration::from_secs_f64(seconds);
    // xorshift64: a phase generator needs no crate; seeded from the clock so runs differ.
    let mut rng = monotonic_ns() | 1;
    let mut uniform = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let mean = Duration::from_micros(interval_us.max(1));
    let mut next = start + mean.mul_f64(uniform());
    while next < end {
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
        probe.poll().map_err(|e| e.to_string())?;
        probe.send().map_err(|e| e.to_string())?;
        next += mean.mul_f64(0.5 + uniform());
    }
    // The last command is written within a few ticks.
    std::thread::sleep(Duration::from_millis(100).max(mean));
    probe.poll().map_err(|e| e.to_string())?;
    println!("{}", probe.report().line());
    Ok(())
}

fn run_and_print(cfg: &StressConfig, opts: &RunOptions) -> Result<(), String> {
    let r = run(cfg, opts).map_err(|e| e.to_string())?;
    println!(
        "stress test: {} sine states at {} Hz, logged for {} s by a separate process",
        cfg.states, cfg.rate_hz, opts.seconds
    );
    println!("{}", r.executor_line());
    let line = |kv: &std::collections::HashMap<String, String>, first: &str| {
        let mut keys: Vec<&String> = kv.keys().filter(|k| *k != first).collect();
        keys.sort();
        let mut s = format!("{first}={}", kv[first]);
        for k in keys {
            s += &format!(" {k}={}", kv[k]);
        }
        s
    };
    for s in &r.states {
        println!("{}", line(s, "state"));
    }
    if !r.summary.is_empty() {
        println!("{}", line(&r.summary, "summary"));
    }
    if let Some(p) = &r.probe {
        println!("{}", line(p, "probe"));
    }
    Ok(())
}
