//! `conductor bench`: the thesis' stress test and the bus benchmarks as one reproducible suite,
//! every figure measured beside its floor in the same run.
//!
//! One run, in order:
//! 1. **IPC floor**: the four ping-pong paths of [`crate::pingpong`] (raw iceoryx2 busy-poll and
//!    event-woken, the Conductor bus over each).
//! 2. For every rate: **cyclictest** at that rate, priority and CPU (the kernel's wake-up floor),
//!    then the **stress test** ([`crate::stress::run`]) for each number of sine
//!    states, with the command probe: tick lateness, misses, executor CPU, sample → subscriber,
//!    command → hardware write, the thesis' error.
//! 3. Plots (lateness histograms beside cyclictest's per rate, the error against time per rate
//!    and all rates together as in Fig. 3.1), `report.json` and `report.md` in the output
//!    directory.
//!
//! The executor sleeps to each deadline (no spin) in every run, so a suite never leaves a
//! SCHED_FIFO thread spinning.
//!
//! [`scaling`] is `conductor bench --scaling`: the same stress test swept over states,
//! subscribers per state and executors per host, with fitted per-unit costs.

pub mod cyclictest;
pub mod fit;
pub mod machine;
pub mod plots;
pub mod report;
pub mod scaling;

use std::ffi::OsString;
use std::io::IsTerminal as _;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::stress::{self, RunError, RunOptions, RunResult, StressConfig};
use conductor_executor::launcher::LaunchOptions;
use indicatif::{ProgressBar, ProgressStyle};

use crate::pingpong::{self, Mode, PingPongError};
use cyclictest::{CyclicConfig, CyclicResult};
use machine::{load_average, utc_now, Machine};
use plots::{Curve, Distribution, PlotError};
use report::{
    CommandRow, CyclicRow, IpcRow, PerStateCostRow, PublishCostRow, Quantiles, Report, StressRow,
};

/// The rates of a full run (Hz): the thesis' 50 Hz – 10 kHz.
pub const FULL_RATES: [f64; 6] = [50.0, 100.0, 500.0, 1000.0, 5000.0, 10_000.0];
/// The rates of a `--quick` run (Hz).
pub const QUICK_RATES: [f64; 2] = [100.0, 1000.0];
/// Sine-state counts: the thesis' 3, and a 41-DOF Hubo's worth.
pub const STATES: [usize; 2] = [3, 41];
/// Logged seconds per run in a full run: the 15 s span of Fig. 3.1.
pub const FULL_SECONDS: f64 = 15.0;
/// Logged seconds per run in a `--quick` run.
pub const QUICK_SECONDS: f64 = 3.0;
/// Longest run of the executor-shaped floor ([`crate::periodic`]) per stress run.
pub const SHAPE_FLOOR_SECONDS: f64 = 5.0;

/// How the stress test's readers take the states.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reader {
    /// A subscriber per state, woken by the tick event.
    States,
    /// The subsystem's snapshot, woken by the snapshot event.
    Snapshot,
}

impl Reader {
    /// Both, in report order.
    pub const ALL: [Reader; 2] = [Reader::States, Reader::Snapshot];

    /// `states` or `snapshot`.
    pub fn name(self) -> &'static str {
        match self {
            Reader::States => "states",
            Reader::Snapshot => "snapshot",
        }
    }

    /// The reader called `s`.
    pub fn parse(s: &str) -> Option<Reader> {
        Reader::ALL.into_iter().find(|r| r.name() == s)
    }
}

/// What to do about cyclictest.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CyclicChoice {
    /// Run it, installing `rt-tests` when missing.
    Install,
    /// Run it if it is installed.
    IfInstalled,
    /// Do not run it.
    Skip,
}

/// The programs the suite starts: how to run the executor, the stress logger and probe, and the
/// ping-pong child (each a program and its leading arguments).
#[derive(Debug, Clone)]
pub struct Helpers {
    /// Launch options for the executor (program, leading arguments); the domain and quiet
    /// flags are set by the suite.
    pub launch: LaunchOptions,
    /// The stress tool (`<tool...> log ...`, `<tool...> probe ...`).
    pub stress_tool: Vec<OsString>,
    /// The ping-pong child (run with [`pingpong::ROLE_ENV`] set).
    pub pingpong_child: Vec<OsString>,
}

/// One suite run's parameters.
#[derive(Debug, Clone)]
pub struct Config {
    /// A `--quick` run (recorded in the report).
    pub quick: bool,
    /// Rates (Hz).
    pub rates_hz: Vec<f64>,
    /// Numbers of sine states.
    pub states: Vec<usize>,
    /// How the readers take the states: a stress run (and a floor) for each.
    pub readers: Vec<Reader>,
    /// Measure the executor-shaped floor beside each stress run.
    pub shape_floor: bool,
    /// Logged seconds per stress run (and cyclictest's length).
    pub seconds: f64,
    /// CPU of the executor and cyclictest.
    pub cpu: usize,
    /// SCHED_FIFO priority of both.
    pub priority: i32,
    /// Round trips per ping-pong path (after 1000 of warm-up).
    pub ipc_samples: usize,
    /// Output directory.
    pub out: PathBuf,
    /// cyclictest.
    pub cyclictest: CyclicChoice,
    /// Draw a progress bar (when stderr is a terminal).
    pub progress: bool,
    /// The command line, for the report.
    pub command: String,
    /// The helper programs.
    pub helpers: Helpers,
}

impl Config {
    /// The full suite (or the `--quick` one) with `helpers`, writing into `bench-out/`.
    pub fn new(quick: bool, helpers: Helpers) -> Self {
        let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        Self {
            quick,
            rates_hz: if quick {
                QUICK_RATES.to_vec()
            } else {
                FULL_RATES.to_vec()
            },
            states: STATES.to_vec(),
            readers: Reader::ALL.to_vec(),
            shape_floor: true,
            seconds: if quick { QUICK_SECONDS } else { FULL_SECONDS },
            // The last CPU: CPU 0 takes most of the machine's housekeeping.
            cpu: cpus - 1,
            priority: 80,
            ipc_samples: if quick { 5_000 } else { 50_000 },
            out: PathBuf::from("bench-out"),
            cyclictest: CyclicChoice::Install,
            progress: true,
            command: String::new(),
            helpers,
        }
    }

    fn check(&self) -> Result<(), SuiteError> {
        let bad = |m: String| Err(SuiteError::Invalid(m));
        if self.rates_hz.is_empty() || self.rates_hz.iter().any(|r| !(*r > 0.0 && *r <= 1e5)) {
            return bad(format!(
                "rates must be in (0, 100000] Hz, got {:?}",
                self.rates_hz
            ));
        }
        if self.states.is_empty() || self.states.iter().any(|&s| s == 0 || s > 1000) {
            return bad(format!(
                "state counts must be in 1..=1000, got {:?}",
                self.states
            ));
        }
        if !(self.seconds > 0.0 && self.seconds <= 3600.0) {
            return bad(format!(
                "seconds must be in (0, 3600], got {}",
                self.seconds
            ));
        }
        if !(1..=99).contains(&self.priority) {
            return bad(format!("priority must be 1–99, got {}", self.priority));
        }
        if self.readers.is_empty() {
            return bad("at least one reader (states, snapshot)".into());
        }
        Ok(())
    }

    /// Seconds of each executor-shaped floor run.
    pub fn shape_floor_seconds(&self) -> f64 {
        if self.quick {
            1.0
        } else {
            self.seconds.min(SHAPE_FLOOR_SECONDS)
        }
    }
}

/// Why the suite stopped.
#[derive(Debug, thiserror::Error)]
pub enum SuiteError {
    /// Bad parameters.
    #[error("{0}")]
    Invalid(String),
    /// Writing the output failed.
    #[error("{context}: {source}")]
    Io {
        /// What was being written.
        context: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// A stress run failed.
    #[error("stress test at {rate_hz} Hz with {states} states: {source}")]
    Stress {
        /// Its rate.
        rate_hz: f64,
        /// Its states.
        states: usize,
        /// Why.
        source: RunError,
    },
    /// The executor-shaped floor failed.
    #[error("the executor-shaped floor at {rate_hz} Hz with {states} states: {source}")]
    ShapeFloor {
        /// Its rate.
        rate_hz: f64,
        /// Its states.
        states: usize,
        /// Why.
        source: PingPongError,
    },
    /// A ping-pong failed.
    #[error("IPC ping-pong {mode}: {source}")]
    PingPong {
        /// The path.
        mode: &'static str,
        /// Why.
        source: PingPongError,
    },
    /// A plot failed.
    #[error(transparent)]
    Plot(#[from] PlotError),
}

fn io(context: impl Into<String>) -> impl FnOnce(std::io::Error) -> SuiteError {
    let context = context.into();
    move |source| SuiteError::Io { context, source }
}

/// Shows where the suite is: a bar on a terminal, a line per step otherwise.
struct Progress {
    bar: Option<ProgressBar>,
    steps: u64,
    step: u64,
    weight_done: f64,
}

impl Progress {
    fn new(cfg: &Config, weight: f64, steps: u64) -> Self {
        let bar = (cfg.progress && std::io::stderr().is_terminal()).then(|| {
            let b = ProgressBar::new((weight * 1000.0) as u64);
            if let Ok(style) = ProgressStyle::with_template(
                "{elapsed_precise} [{bar:40}] {percent:>3}% (eta {eta}) {msg}",
            ) {
                b.set_style(style.progress_chars("=> "));
            }
            b.enable_steady_tick(Duration::from_millis(200));
            b
        });
        Self {
            bar,
            steps,
            step: 0,
            weight_done: 0.0,
        }
    }

    fn start(&mut self, what: &str) {
        self.step += 1;
        match &self.bar {
            Some(b) => b.set_message(format!("[{}/{}] {what}", self.step, self.steps)),
            None => eprintln!("bench: [{}/{}] {what}", self.step, self.steps),
        }
    }

    fn done(&mut self, weight: f64) {
        self.weight_done += weight;
        if let Some(b) = &self.bar {
            b.set_position((self.weight_done * 1000.0) as u64);
        }
    }

    fn note(&self, text: &str) {
        match &self.bar {
            Some(b) => b.suspend(|| eprintln!("bench: note: {text}")),
            None => eprintln!("bench: note: {text}"),
        }
    }

    fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

/// Time weights of the steps (≈ seconds), for the progress bar.
const IPC_WEIGHT: f64 = 1.0;
const STRESS_OVERHEAD: f64 = 1.5;
const PLOT_WEIGHT: f64 = 0.5;

/// Runs the suite and writes `report.json`, `report.md` and the plots into `cfg.out`.
pub fn run(cfg: &Config) -> Result<Report, SuiteError> {
    cfg.check()?;
    std::fs::create_dir_all(&cfg.out).map_err(io(format!("creating {}", cfg.out.display())))?;
    let date = utc_now();
    let mut machine = Machine::now();
    let runs = cfg.rates_hz.len() * cfg.states.len() * cfg.readers.len();
    let with_ct = cfg.cyclictest != CyclicChoice::Skip;
    let floor_s = if cfg.shape_floor {
        cfg.shape_floor_seconds() + 1.0
    } else {
        0.0
    };
    let weight = IPC_WEIGHT * (Mode::ALL.len() + 1) as f64
        + cfg.rates_hz.len() as f64 * (if with_ct { cfg.seconds } else { 0.0 } + PLOT_WEIGHT)
        + runs as f64 * (cfg.seconds + STRESS_OVERHEAD + floor_s);
    let steps = (Mode::ALL.len()
        + 1
        + runs * (1 + usize::from(cfg.shape_floor))
        + if with_ct { cfg.rates_hz.len() } else { 0 }) as u64;
    let mut progress = Progress::new(cfg, weight, steps);

    let mut cyclictest_note = None;
    let ct_program = match cfg.cyclictest {
        CyclicChoice::Skip => {
            cyclictest_note = Some("skipped (--no-cyclictest)".to_string());
            None
        }
        choice => match cyclictest::ensure(choice == CyclicChoice::Install) {
            Ok(p) => Some(p),
            Err(note) => {
                progress.note(&format!("{note}; the kernel floor is skipped"));
                cyclictest_note = Some(note);
                None
            }
        },
    };

    let ipc = measure_ipc(cfg, &mut progress)?;
    progress.start("publish cost (raw iceoryx2 publish, the per-state cost's denominator)");
    let publish_cost = measure_publish_cost(cfg)?;
    progress.done(IPC_WEIGHT);
    let event_floor = ipc
        .iter()
        .find(|r| r.path == Mode::RawEvent.name())
        .map(|r| r.one_way);

    let mut cyclic_rows = Vec::new();
    let mut stress_rows = Vec::new();
    let mut plots_written = Vec::new();
    let mut fig31: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    for &rate in &cfg.rates_hz {
        let mut ct: Option<CyclicResult> = None;
        if let Some(prog) = &ct_program {
            progress.start(&format!("cyclictest at {rate} Hz"));
            let c = CyclicConfig {
                rate_hz: rate,
                priority: cfg.priority,
                cpu: cfg.cpu,
                seconds: cfg.seconds,
            };
            match cyclictest::run(prog, &c) {
                Ok(r) => ct = Some(r),
                Err(e) => {
                    progress.note(&format!("{e}; no kernel floor at {rate} Hz"));
                    cyclictest_note.get_or_insert_with(|| e.to_string());
                }
            }
            progress.done(cfg.seconds);
        }
        let ct_row = ct.as_ref().map(|r| CyclicRow {
            rate_hz: rate,
            command: r.command.clone(),
            latency: Quantiles::from(&r.latency),
            mean_ns: r.latency.mean,
            overflows: r.overflows,
        });
        let mut dists = Vec::new();
        let mut traces: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
        for &states in &cfg.states {
            for &reader in &cfg.readers {
                let how = reader.name();
                let shape_floor = if cfg.shape_floor {
                    progress.start(&format!(
                        "executor-shaped floor at {rate} Hz, {states} states, {how}"
                    ));
                    let f = shape_floor(cfg, rate, states, reader)?;
                    progress.done(floor_s);
                    Some(f)
                } else {
                    None
                };
                progress.start(&format!(
                    "stress test at {rate} Hz, {states} states, read by {how}"
                ));
                let r = stress_run(cfg, rate, states, reader)?;
                let mut row = stress_row(&r, ct_row.as_ref(), event_floor.as_ref());
                row.reader = how.into();
                row.sample_to_subscriber_over_shape_floor = shape_floor
                    .as_ref()
                    .map(|f| row.sample_to_subscriber.over(f));
                row.shape_floor = shape_floor;
                stress_rows.push(row);
                dists.push(Distribution::from_histogram(
                    &format!("executor, {states} states, read by {how}"),
                    &r.lateness,
                ));
                if reader == cfg.readers[0] {
                    traces.push((format!("{rate} Hz, {states} states"), r.trace));
                }
                progress.done(cfg.seconds + STRESS_OVERHEAD);
            }
        }
        if let Some(r) = &ct {
            dists.push(Distribution::from_us_buckets(
                "cyclictest (kernel floor)",
                &r.histogram,
            ));
        }
        let name = format!("lateness-{rate}hz.png");
        plots::lateness_png(
            &cfg.out.join(&name),
            &format!("Tick lateness at {rate} Hz: executor beside cyclictest"),
            &dists,
        )?;
        plots_written.push(name);
        let name = format!("error-{rate}hz.png");
        let curves = labelled_curves(&traces);
        plots::error_png(
            &cfg.out.join(&name),
            &format!("Conductor state error at {rate} Hz (thesis Fig. 3.1)"),
            &curves,
        )?;
        plots_written.push(name);
        progress.done(PLOT_WEIGHT);
        // Fig. 3.1 proper: the thesis' configuration (the fewest states) at every rate.
        if let Some(t) = traces.into_iter().next() {
            fig31.push((format!("{rate}Hz"), t.1));
        }
        cyclic_rows.extend(ct_row);
    }
    let name = "error-all-rates.png".to_string();
    let curves = labelled_curves(&fig31);
    plots::error_png(
        &cfg.out.join(&name),
        &format!(
            "Conductor state error for various sampling frequencies, {} states",
            cfg.states[0]
        ),
        &curves,
    )?;
    plots_written.push(name);
    progress.finish();

    machine.load_end = load_average();
    let report = Report {
        schema: report::SCHEMA,
        mode: "suite".into(),
        date,
        command: cfg.command.clone(),
        machine,
        quick: cfg.quick,
        rates_hz: cfg.rates_hz.clone(),
        states: cfg.states.clone(),
        seconds: cfg.seconds,
        cpu: cfg.cpu,
        priority: cfg.priority,
        ipc,
        cyclictest: cyclic_rows,
        cyclictest_note,
        per_state_cost: per_state_cost(&stress_rows, &publish_cost),
        publish_cost,
        stress: stress_rows,
        plots: plots_written,
    };
    write(&cfg.out.join("report.json"), &json(&report))?;
    write(&cfg.out.join("report.md"), &report.markdown())?;
    Ok(report)
}

fn json(report: &Report) -> String {
    // Serializing plain structs of numbers and strings cannot fail.
    serde_json::to_string_pretty(report).unwrap_or_default() + "\n"
}

fn write(path: &Path, text: &str) -> Result<(), SuiteError> {
    std::fs::write(path, text).map_err(io(format!("writing {}", path.display())))
}

fn measure_ipc(cfg: &Config, progress: &mut Progress) -> Result<Vec<IpcRow>, SuiteError> {
    let mut measured = Vec::new();
    for mode in Mode::ALL {
        progress.start(&format!("IPC ping-pong, {}", mode.name()));
        let p = pingpong::measure(mode, cfg.ipc_samples, &cfg.helpers.pingpong_child).map_err(
            |source| SuiteError::PingPong {
                mode: mode.name(),
                source,
            },
        )?;
        measured.push((mode, Quantiles::from(&p)));
        progress.done(IPC_WEIGHT);
    }
    Ok(measured
        .iter()
        .map(|(mode, q)| {
            let floor = measured
                .iter()
                .find(|(m, _)| *m == mode.floor())
                .map_or(*q, |(_, f)| *f);
            IpcRow {
                path: mode.name().into(),
                floor: mode.floor().name().into(),
                one_way: *q,
                over_floor: q.over(&floor),
            }
        })
        .collect())
}

/// The publish paths' cost per state for the largest state count, with one subscriber per
/// state (as a per-state reader) and with none (as when the readers take the snapshot), in
/// this run.
fn measure_publish_cost(cfg: &Config) -> Result<Vec<PublishCostRow>, SuiteError> {
    let states = cfg.states.iter().copied().max().unwrap_or(1);
    let ticks = if cfg.quick { 500 } else { 2_000 };
    let mut rows = Vec::new();
    for subscribers in [1, 0] {
        let costs =
            crate::publish_cost::measure(states, subscribers, ticks, 7).map_err(|source| {
                SuiteError::PingPong {
                    mode: "publish cost",
                    source,
                }
            })?;
        rows.extend(costs.iter().map(|c| PublishCostRow {
            path: c.path.name().into(),
            states,
            subscribers,
            per_state_ns: c.per_state_ns,
            per_tick_ns: c.per_tick_ns,
        }));
    }
    Ok(rows)
}

/// The executor's CPU per state per tick (the slope between the smallest and the largest state
/// count of a rate and reader) beside a raw publish of one state, measured in the same run.
fn per_state_cost(rows: &[StressRow], publish: &[PublishCostRow]) -> Vec<PerStateCostRow> {
    // A per-state reader subscribes to every state; a snapshot reader to none of them.
    let per = |path: crate::publish_cost::Path, reader: &str| {
        let subscribers = usize::from(reader == Reader::States.name());
        publish
            .iter()
            .find(|p| p.path == path.name() && p.subscribers == subscribers)
            .map(|p| p.per_state_ns)
    };
    let cpu_ns_per_tick = |r: &StressRow| {
        r.cpu_percent
            .filter(|_| r.achieved_hz > 0.0)
            .map(|c| c / 100.0 * 1e9 / r.achieved_hz)
    };
    let mut out = Vec::new();
    for (i, lo) in rows.iter().enumerate() {
        // Each (rate, reader) once, from its smallest state count to its largest.
        let same = |r: &&StressRow| r.rate_hz == lo.rate_hz && r.reader == lo.reader;
        if rows[..i].iter().any(|r| same(&r)) {
            continue;
        }
        let group: Vec<&StressRow> = rows.iter().filter(same).collect();
        let (Some(a), Some(b)) = (
            group.iter().min_by_key(|r| r.states),
            group.iter().max_by_key(|r| r.states),
        ) else {
            continue;
        };
        let (Some(ca), Some(cb)) = (cpu_ns_per_tick(a), cpu_ns_per_tick(b)) else {
            continue;
        };
        if b.states == a.states {
            continue;
        }
        let executor_ns = (cb - ca) / (b.states - a.states) as f64;
        let (Some(raw), Some(staged)) = (
            per(crate::publish_cost::Path::Raw, &lo.reader),
            per(crate::publish_cost::Path::Staged, &lo.reader),
        ) else {
            continue;
        };
        out.push(PerStateCostRow {
            rate_hz: lo.rate_hz,
            reader: lo.reader.clone(),
            states: (a.states, b.states),
            executor_ns_per_state: executor_ns,
            raw_publish_ns: raw,
            staged_publish_ns: staged,
            over_raw: executor_ns / raw,
        });
    }
    out
}

fn stress_run(
    cfg: &Config,
    rate_hz: f64,
    states: usize,
    reader: Reader,
) -> Result<RunResult, SuiteError> {
    let sc = StressConfig {
        probe: true,
        snapshot: reader == Reader::Snapshot,
        ..stress_config(cfg, rate_hz, states)
    };
    run_stress(cfg, &sc, true, None)
}

/// The executor-shaped floor ([`crate::periodic`]) of a stress run: the same rate, number of
/// states, reading, CPU, priority and subscriber buffer, without the Conductor layer.
fn shape_floor(
    cfg: &Config,
    rate_hz: f64,
    states: usize,
    reader: Reader,
) -> Result<Quantiles, SuiteError> {
    let p = crate::periodic::Periodic {
        rate_hz,
        states,
        snapshot: reader == Reader::Snapshot,
        seconds: cfg.shape_floor_seconds(),
        cpu: cfg.cpu,
        priority: cfg.priority,
        buffer: StressConfig::default().history,
    };
    crate::periodic::measure(&p, &cfg.helpers.pingpong_child)
        .map(|p| Quantiles::from(&p))
        .map_err(|source| SuiteError::ShapeFloor {
            rate_hz,
            states,
            source,
        })
}

/// A stress run of `states` at `rate_hz` on the suite's CPU and priority, sleeping to its
/// deadlines (no spin).
pub(crate) fn stress_config(cfg: &Config, rate_hz: f64, states: usize) -> StressConfig {
    StressConfig {
        rate_hz,
        cpu: Some(cfg.cpu),
        priority: cfg.priority,
        spin_us: 0.0,
        states,
        ..StressConfig::default()
    }
}

/// Runs `sc` for the suite's time with its helpers, quietly; `trace` keeps the per-sample
/// trace, `ready` bounds the bring-up (default: the launcher's).
pub(crate) fn run_stress(
    cfg: &Config,
    sc: &StressConfig,
    trace: bool,
    ready: Option<Duration>,
) -> Result<RunResult, SuiteError> {
    let mut opts = RunOptions::new(cfg.seconds);
    opts.tool = cfg.helpers.stress_tool.clone();
    opts.launch = LaunchOptions {
        quiet: true,
        handle_signals: false,
        ..cfg.helpers.launch.clone()
    };
    if let Some(r) = ready {
        opts.launch.ready_timeout = r;
    }
    opts.trace = trace;
    stress::run(sc, &opts).map_err(|source| SuiteError::Stress {
        rate_hz: sc.rate_hz,
        states: sc.states,
        source,
    })
}

pub(crate) fn num<T: std::str::FromStr + Default>(
    kv: &std::collections::HashMap<String, String>,
    k: &str,
) -> T {
    kv.get(k).and_then(|v| v.parse().ok()).unwrap_or_default()
}

fn stress_row(r: &RunResult, ct: Option<&CyclicRow>, event_floor: Option<&Quantiles>) -> StressRow {
    let lateness = Quantiles::from(&r.lateness);
    let s2s = Quantiles::from_line(&r.summary, "e2e", "count").unwrap_or_default();
    let command = r.probe.as_ref().map(|p| CommandRow {
        sent: num(p, "sent"),
        written: num(p, "written"),
        unresolved: num(p, "unresolved"),
        early: num(p, "early"),
        to_write: Quantiles::from_line(p, "write", "written").unwrap_or_default(),
        to_reflect: Quantiles::from_line(p, "reflect", "reflected").unwrap_or_default(),
    });
    StressRow {
        rate_hz: r.config.rate_hz,
        states: r.config.states,
        reader: if r.config.snapshot {
            Reader::Snapshot
        } else {
            Reader::States
        }
        .name()
        .into(),
        rt_active: r.rt_active,
        pinned_cpu: r.pinned_cpu,
        ticks: r.ticks,
        misses: r.misses,
        misses_by_second: r.misses_by_second.clone(),
        misses_by_half: r.misses_by_half(),
        achieved_hz: r.achieved_hz(),
        cpu_percent: r.cpu_percent,
        lateness,
        lateness_over_cyclictest: ct.map(|c| lateness.over(&c.latency)),
        sample_to_subscriber: s2s,
        publish_to_subscriber: Quantiles::from_line(&r.summary, "latency", "count")
            .unwrap_or_default(),
        sample_to_subscriber_over_ipc: event_floor.map(|f| s2s.over(f)),
        shape_floor: None,
        sample_to_subscriber_over_shape_floor: None,
        command,
        samples: num(&r.summary, "count"),
        lost: num(&r.summary, "missed"),
        late_steps: num(&r.summary, "late_steps"),
        thesis_error_max: num(&r.summary, "err_thesis_max"),
        thesis_error_rms: num(&r.summary, "err_thesis_rms"),
        pipeline_error_max: num(&r.summary, "err_sample_max"),
    }
}

/// Borrowed plot curves of `(label, points)` traces.
fn labelled_curves(traces: &[(String, Vec<(f64, f64)>)]) -> Vec<Curve<'_>> {
    traces
        .iter()
        .map(|(label, points)| Curve { label, points })
        .collect()
}
