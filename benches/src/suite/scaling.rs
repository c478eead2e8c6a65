//! `conductor bench --scaling`: the scaling curves of issue 17 — executor CPU per tick and
//! sample → controller latency against the number of states, subscribers per state and
//! executors per host, each from the stress test ([`crate::stress::run`]) at one rate, with the
//! per-unit costs fitted by least squares ([`super::fit`]), so a robot can be sized from them.
//!
//! Three sweeps share one base point (41 states, one subscriber, one executor), run once:
//! * **states** ∈ {1, 10, 41, 200, 1 000}, one subscriber, one executor;
//! * **subscribers per state** ∈ {0, 1, 4, 16} at 41 states (0: no reader at all, 1: the logger,
//!   n: the logger and n − 1 reader processes, each woken by the tick event, reading every
//!   sample);
//! * **executors per host** ∈ {1, 2, 4} of 41 states each, every one a subsystem and a process
//!   of its own, all SCHED_FIFO on the same CPU (the host's real-time CPU), every reader kept
//!   off it.
//!
//! Executors sleep to their deadlines (no spin), as in the suite.

use std::path::Path;
use std::time::Duration;

use serde::Serialize;

use super::fit::{fit_line, LineFit};
use super::machine::{load_average, utc_now, Machine};
use super::plots::{self, Series};
use super::report::{plots_section, Quantiles};
use super::{io, num, run_stress, stress_config, write, Config, Progress, SuiteError};
use crate::percentiles::fmt_ns;
use crate::stress::{RunResult, StressConfig};

/// States per subsystem of the subscriber and executor sweeps: a 41-DOF Hubo's worth.
pub const BASE_STATES: usize = 41;
/// The rate of every point (Hz): what this 2-vCPU class of machine holds with 200 states.
pub const RATE_HZ: f64 = 1000.0;
/// The state counts of a full run.
pub const FULL_STATES: [usize; 5] = [1, 10, 41, 200, 1000];
/// Subscribers per state of a full run.
pub const FULL_SUBSCRIBERS: [usize; 4] = [0, 1, 4, 16];
/// Executors per host of a full run.
pub const FULL_EXECUTORS: [usize; 3] = [1, 2, 4];
/// The state counts of a `--quick` run.
pub const QUICK_STATES: [usize; 3] = [1, 10, 41];
/// Subscribers per state of a `--quick` run.
pub const QUICK_SUBSCRIBERS: [usize; 3] = [0, 1, 4];
/// Executors per host of a `--quick` run.
pub const QUICK_EXECUTORS: [usize; 2] = [1, 2];
/// Logged seconds per point, full run.
pub const FULL_SECONDS: f64 = 5.0;
/// Logged seconds per point, `--quick`.
pub const QUICK_SECONDS: f64 = 1.0;
/// Each state's history and its readers' buffer (samples): 256 ms of slack at 1 kHz, and a
/// shared-memory footprint that stays reasonable at 1 000 states × 16 subscriber slots.
pub const HISTORY: usize = 256;

/// What the sweeps vary.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// Rate of every point (Hz).
    pub rate_hz: f64,
    /// States of the states sweep (one subscriber, one executor).
    pub states: Vec<usize>,
    /// Subscribers per state of the subscribers sweep ([`BASE_STATES`], one executor).
    pub subscribers: Vec<usize>,
    /// Executors of the executors sweep ([`BASE_STATES`] each, one subscriber).
    pub executors: Vec<usize>,
}

impl Plan {
    /// The full sweeps or the `--quick` ones.
    pub fn new(quick: bool) -> Self {
        if quick {
            Self {
                rate_hz: RATE_HZ,
                states: QUICK_STATES.to_vec(),
                subscribers: QUICK_SUBSCRIBERS.to_vec(),
                executors: QUICK_EXECUTORS.to_vec(),
            }
        } else {
            Self {
                rate_hz: RATE_HZ,
                states: FULL_STATES.to_vec(),
                subscribers: FULL_SUBSCRIBERS.to_vec(),
                executors: FULL_EXECUTORS.to_vec(),
            }
        }
    }

    /// Every distinct `(states, subscribers, executors)` point of the three sweeps, in run
    /// order (the base point once).
    pub fn points(&self) -> Vec<(usize, usize, usize)> {
        let mut v: Vec<(usize, usize, usize)> = Vec::new();
        let sweeps = self
            .states
            .iter()
            .map(|&n| (n, 1, 1))
            .chain(self.subscribers.iter().map(|&s| (BASE_STATES, s, 1)))
            .chain(self.executors.iter().map(|&e| (BASE_STATES, 1, e)));
        for p in sweeps {
            if !v.contains(&p) {
                v.push(p);
            }
        }
        v
    }

    fn check(&self) -> Result<(), SuiteError> {
        let bad = |m: String| Err(SuiteError::Invalid(m));
        if self.states.iter().any(|&n| n == 0 || n > 1000) {
            return bad(format!(
                "scaling: states in 1..=1000, got {:?}",
                self.states
            ));
        }
        if self
            .subscribers
            .iter()
            .any(|&s| s > conductor_bus::qos::STATE_SUBSCRIBERS)
        {
            return bad(format!(
                "scaling: at most {} subscribers per state, got {:?}",
                conductor_bus::qos::STATE_SUBSCRIBERS,
                self.subscribers
            ));
        }
        if self.executors.iter().any(|&e| !(1..=16).contains(&e)) {
            return bad(format!(
                "scaling: executors in 1..=16, got {:?}",
                self.executors
            ));
        }
        Ok(())
    }
}

/// One measured point.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ScalingPoint {
    /// Sine states per executor.
    pub states: usize,
    /// Subscribers per state (0: none; 1: the logger; n: the logger and n − 1 readers).
    pub subscribers: usize,
    /// Executors (subsystems, processes) on the host.
    pub executors: usize,
    /// Ticks in the window, all executors.
    pub ticks: u64,
    /// Deadlines missed (slots skipped) in the window, all executors.
    pub misses: u64,
    /// Ticks per second of one executor (the executors' mean).
    pub achieved_hz: f64,
    /// CPU of every executor process over the window, % of one CPU.
    pub cpu_percent: Option<f64>,
    /// Executor CPU per tick (µs): the executors' CPU time ÷ the ticks each executed.
    pub cpu_us_per_tick: Option<f64>,
    /// Tick lateness, every executor's ticks.
    pub lateness: Quantiles,
    /// Hardware sample (request time) → the logger process reading it, woken by the tick event
    /// (`None` without subscribers).
    pub sample_to_controller: Option<Quantiles>,
    /// Samples the logger read in the window.
    pub samples: u64,
    /// Samples lost by the logger and by the other readers together.
    pub lost: u64,
    /// Samples the other readers read in the window, all of them.
    pub other_samples: u64,
    /// Why the point has no figures: its run failed (the sweep goes on without it).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl ScalingPoint {
    /// A point whose run failed: no figures, the reason kept.
    fn failed((states, subscribers, executors): (usize, usize, usize), error: String) -> Self {
        Self {
            states,
            subscribers,
            executors,
            ticks: 0,
            misses: 0,
            achieved_hz: 0.0,
            cpu_percent: None,
            cpu_us_per_tick: None,
            lateness: Quantiles::default(),
            sample_to_controller: None,
            samples: 0,
            lost: 0,
            other_samples: 0,
            error: Some(error),
        }
    }
}

/// One sweep: its points (indices into [`ScalingReport::points`]) and the fits over them.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Sweep {
    /// `states`, `subscribers` or `executors`.
    pub name: String,
    /// What the others are held at.
    pub fixed: String,
    /// The points, in the sweep's order.
    pub points: Vec<usize>,
    /// Executor CPU per tick (µs) against the swept number.
    pub cpu_fit: Option<LineFit>,
    /// Sample → controller p50 (µs) against the swept number, over the points with a reader.
    pub latency_p50_fit: Option<LineFit>,
    /// The per-unit cost (µs per tick) the sweep is for (the CPU slope, per state for the
    /// subscribers sweep).
    pub unit_cost_us: Option<f64>,
    /// What one unit is.
    pub unit: String,
}

/// Everything a scaling run measured (`report.json` with `mode` = `scaling`).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ScalingReport {
    /// Layout version (2: the reports carry `mode`).
    pub schema: u32,
    /// `scaling`.
    pub mode: String,
    /// When the run started.
    pub date: String,
    /// The command line.
    pub command: String,
    /// The machine.
    pub machine: Machine,
    /// A `--quick` run.
    pub quick: bool,
    /// Rate of every point (Hz).
    pub rate_hz: f64,
    /// Logged seconds per point.
    pub seconds: f64,
    /// The executors' CPU.
    pub cpu: usize,
    /// Their SCHED_FIFO priority.
    pub priority: i32,
    /// Each state's history and its readers' buffer.
    pub history: usize,
    /// How the processes were placed.
    pub pinning: String,
    /// How every reader took the states: `states` (a subscriber per state, woken by the tick
    /// event) or `snapshot` (the subsystem's snapshot, woken by its event; a "subscriber per
    /// state" is then a snapshot reader).
    pub reader: String,
    /// Every measured point.
    pub points: Vec<ScalingPoint>,
    /// The three sweeps.
    pub sweeps: Vec<Sweep>,
    /// Image files written (names relative to the output directory).
    pub plots: Vec<String>,
}

const STRESS_OVERHEAD: f64 = 2.0;

/// Runs the sweeps of `plan` with `cfg`'s CPU, priority, helpers, output directory and seconds;
/// writes `report.json`, `report.md` and the curves into `cfg.out`.
pub fn run(cfg: &Config, plan: &Plan) -> Result<ScalingReport, SuiteError> {
    plan.check()?;
    if !(cfg.seconds > 0.0 && cfg.seconds <= 3600.0) {
        return Err(SuiteError::Invalid(format!(
            "seconds must be in (0, 3600], got {}",
            cfg.seconds
        )));
    }
    std::fs::create_dir_all(&cfg.out).map_err(io(format!("creating {}", cfg.out.display())))?;
    let date = utc_now();
    let mut machine = Machine::now();
    let todo = plan.points();
    let mut progress = Progress::new(
        cfg,
        todo.len() as f64 * (cfg.seconds + STRESS_OVERHEAD),
        todo.len() as u64,
    );
    let mut points = Vec::with_capacity(todo.len());
    for &(states, subscribers, executors) in &todo {
        progress.start(&format!(
            "{} Hz: {states} states × {subscribers} subscribers × {executors} executors",
            plan.rate_hz
        ));
        let at = (states, subscribers, executors);
        let what = format!("{states} states × {subscribers} subscribers × {executors} executors");
        match point_run(cfg, plan.rate_hz, at) {
            Ok(r) => {
                if r.misses > 0 {
                    progress.note(&format!(
                        "{what}: {} missed deadlines of {} ticks",
                        r.misses, r.ticks
                    ));
                }
                points.push(point(&r));
            }
            // One point beyond what the machine can run (1 000 states on a loaded VM) must not
            // cost the whole sweep: it is reported as failed and left out of the fits.
            Err(e) => {
                progress.note(&format!("{what}: FAILED: {e}"));
                points.push(ScalingPoint::failed(at, e.to_string()));
            }
        }
        progress.done(cfg.seconds + STRESS_OVERHEAD);
    }
    progress.finish();

    let index = |p: (usize, usize, usize)| {
        points
            .iter()
            .position(|q| (q.states, q.subscribers, q.executors) == p)
            .unwrap_or(0)
    };
    let sweeps = vec![
        sweep(
            "states",
            "1 subscriber per state, 1 executor".into(),
            plan.states.iter().map(|&n| index((n, 1, 1))).collect(),
            &points,
            |p| p.states,
            1.0,
            "µs per state per tick",
        ),
        sweep(
            "subscribers",
            format!("{BASE_STATES} states, 1 executor"),
            plan.subscribers
                .iter()
                .map(|&s| index((BASE_STATES, s, 1)))
                .collect(),
            &points,
            |p| p.subscribers,
            BASE_STATES as f64,
            "µs per subscriber per state per tick",
        ),
        sweep(
            "executors",
            format!("{BASE_STATES} states each, 1 subscriber per state"),
            plan.executors
                .iter()
                .map(|&e| index((BASE_STATES, 1, e)))
                .collect(),
            &points,
            |p| p.executors,
            1.0,
            "µs per extra executor per tick (41 states each)",
        ),
    ];
    let mut plots_written = Vec::new();
    for s in &sweeps {
        plots_written.extend(curves(&cfg.out, s, &points)?);
    }
    machine.load_end = load_average();
    let report = ScalingReport {
        schema: super::report::SCHEMA,
        mode: "scaling".into(),
        date,
        command: cfg.command.clone(),
        machine,
        quick: cfg.quick,
        rate_hz: plan.rate_hz,
        seconds: cfg.seconds,
        cpu: cfg.cpu,
        priority: cfg.priority,
        history: HISTORY,
        pinning: format!(
            "every executor SCHED_FIFO {} pinned to CPU {}, memory locked, sleeping to its \
             deadlines; the logger and the other readers kept off CPU {} (the rest of the host)",
            cfg.priority, cfg.cpu, cfg.cpu
        ),
        reader: cfg
            .readers
            .first()
            .copied()
            .unwrap_or(super::Reader::States)
            .name()
            .into(),
        points,
        sweeps,
        plots: plots_written,
    };
    write(
        &cfg.out.join("report.json"),
        &(serde_json::to_string_pretty(&report).unwrap_or_default() + "\n"),
    )?;
    write(&cfg.out.join("report.md"), &report.markdown())?;
    Ok(report)
}

fn point_run(
    cfg: &Config,
    rate_hz: f64,
    (states, subscribers, executors): (usize, usize, usize),
) -> Result<RunResult, SuiteError> {
    let sc = StressConfig {
        probe: false,
        executors,
        subscribers,
        history: HISTORY,
        snapshot: cfg.readers.first() == Some(&super::Reader::Snapshot),
        ..stress_config(cfg, rate_hz, states)
    };
    // Bring-up opens a service per state: 1 000 states take longer than the default 10 s.
    let ready = Duration::from_secs(10) + Duration::from_millis(100) * states as u32;
    run_stress(cfg, &sc, false, Some(ready))
}

/// A point's figures from its stress run.
pub fn point(r: &RunResult) -> ScalingPoint {
    ScalingPoint {
        states: r.config.states,
        subscribers: r.config.subscribers,
        executors: r.config.executors,
        ticks: r.ticks,
        misses: r.misses,
        achieved_hz: r.achieved_hz(),
        cpu_percent: r.cpu_percent,
        cpu_us_per_tick: r.cpu_us_per_tick(),
        lateness: Quantiles::from(&r.lateness),
        sample_to_controller: Quantiles::from_line(&r.summary, "e2e", "count"),
        samples: num(&r.summary, "count"),
        lost: num::<u64>(&r.summary, "missed")
            + r.other_subscribers
                .iter()
                .map(|s| num::<u64>(s, "missed"))
                .sum::<u64>(),
        other_samples: r
            .other_subscribers
            .iter()
            .map(|s| num::<u64>(s, "count"))
            .sum(),
        error: None,
    }
}

/// The sweep's fits: CPU per tick and latency p50 (µs) against `x` of its points; the unit
/// cost is the CPU slope ÷ `per`.
fn sweep(
    name: &str,
    fixed: String,
    idx: Vec<usize>,
    points: &[ScalingPoint],
    x: impl Fn(&ScalingPoint) -> usize,
    per: f64,
    unit: &str,
) -> Sweep {
    let (cpu, lat) = sweep_points(&idx, points, &x);
    let cpu_fit = fit_line(&cpu);
    Sweep {
        name: name.into(),
        fixed,
        points: idx,
        cpu_fit,
        latency_p50_fit: fit_line(&lat.iter().map(|p| (p.0, p.1)).collect::<Vec<_>>()),
        unit_cost_us: cpu_fit.map(|f| f.slope / per),
        unit: unit.into(),
    }
}

/// `(x, latency p50 µs, p99 µs)` of a sweep's points.
pub type LatencyPoints = Vec<(f64, f64, f64)>;

/// `(x, CPU µs per tick)` and `(x, latency p50 µs, p99 µs)` of a sweep's points (points
/// without the figure left out).
pub fn sweep_points(
    idx: &[usize],
    points: &[ScalingPoint],
    x: &impl Fn(&ScalingPoint) -> usize,
) -> (Vec<(f64, f64)>, LatencyPoints) {
    let mut cpu = Vec::new();
    let mut lat = Vec::new();
    for p in idx.iter().filter_map(|&i| points.get(i)) {
        let xv = x(p) as f64;
        if let Some(c) = p.cpu_us_per_tick {
            cpu.push((xv, c));
        }
        if let Some(q) = p.sample_to_controller.filter(|q| q.count > 0) {
            lat.push((xv, q.p50_ns as f64 / 1e3, q.p99_ns as f64 / 1e3));
        }
    }
    (cpu, lat)
}

/// A fitted line's legend: `<what>: a µs + b µs × <unit>`.
fn fit_label(what: &str, fit: Option<LineFit>, digits: usize, unit: &str) -> Option<String> {
    fit.map(|f| {
        format!(
            "{what}: {:.digits$} µs + {:.3} µs × {unit}",
            f.intercept, f.slope
        )
    })
}

/// `cpu-vs-<sweep>.png` and `latency-vs-<sweep>.png`.
fn curves(out: &Path, s: &Sweep, points: &[ScalingPoint]) -> Result<Vec<String>, SuiteError> {
    let x = |p: &ScalingPoint| match s.name.as_str() {
        "states" => p.states,
        "subscribers" => p.subscribers,
        _ => p.executors,
    };
    let x_desc = match s.name.as_str() {
        "states" => "States (one executor, one subscriber per state)",
        "subscribers" => "Subscribers per state (41 states, one executor)",
        _ => "Executors on the host (41 states each, pinned to one CPU)",
    };
    let (cpu, lat) = sweep_points(&s.points, points, &x);
    let cpu_name = format!("cpu-vs-{}.png", s.name);
    let unit = s.name.trim_end_matches('s');
    let cpu_label = fit_label("least squares", s.cpu_fit, 2, unit);
    plots::curve_png(
        &out.join(&cpu_name),
        &format!("Executor CPU per tick against {}", s.name),
        (x_desc, "Executor CPU per tick (µs)"),
        &[Series {
            label: "measured (schedstat over the window ÷ ticks)",
            points: &cpu,
        }],
        cpu_label.as_deref().zip(s.cpu_fit),
    )?;
    let lat_name = format!("latency-vs-{}.png", s.name);
    let p50: Vec<(f64, f64)> = lat.iter().map(|p| (p.0, p.1)).collect();
    let p99: Vec<(f64, f64)> = lat.iter().map(|p| (p.0, p.2)).collect();
    let lat_label = fit_label("p50 least squares", s.latency_p50_fit, 1, unit);
    plots::curve_png(
        &out.join(&lat_name),
        &format!("Sample → controller latency against {}", s.name),
        (x_desc, "Hardware sample → controller process (µs)"),
        &[
            Series {
                label: "p50",
                points: &p50,
            },
            Series {
                label: "p99",
                points: &p99,
            },
        ],
        lat_label.as_deref().zip(s.latency_p50_fit),
    )?;
    Ok(vec![cpu_name, lat_name])
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "–".into(), |v| format!("{v:.digits$}"))
}

impl ScalingReport {
    /// The Markdown report.
    pub fn markdown(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let m = &self.machine;
        let _ = writeln!(s, "# conductor bench --scaling — {}\n", self.date);
        let _ = writeln!(s, "Command: `{}`\n", self.command);
        let _ = writeln!(s, "Machine: {}.\n", m.summary());
        let _ = writeln!(
            s,
            "Every point: the stress test at {} Hz, {} s logged; {}; state history and reader \
             buffers {} samples. Executor CPU per tick = the executors' on-CPU time over the \
             window (`/proc/<pid>/task/*/schedstat`) ÷ the ticks each executed. Sample → \
             controller = the sample request's time → the logger process reading the sample. \
             Reader: `{}` ({}).\n",
            self.rate_hz,
            self.seconds,
            self.pinning,
            self.history,
            self.reader,
            if self.reader == super::Reader::Snapshot.name() {
                "every reader takes the subsystem's snapshot, woken by the snapshot event; the \
                 \"subscribers per state\" are that many snapshot readers"
            } else {
                "every reader subscribes to each state, woken by the tick event"
            }
        );
        for sw in &self.sweeps {
            let _ = writeln!(s, "## Against {} ({})\n", sw.name, sw.fixed);
            let _ = writeln!(
                s,
                "| states | subscribers | executors | ticks | misses | achieved Hz | executor \
                 CPU % | CPU µs/tick | lateness p99 | sample→controller p50 | p99 | samples | \
                 lost |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|"
            );
            for p in sw.points.iter().filter_map(|&i| self.points.get(i)) {
                if let Some(e) = &p.error {
                    let _ = writeln!(
                        s,
                        "| {} | {} | {} | failed: {} ||||||||||",
                        p.states,
                        p.subscribers,
                        p.executors,
                        e.replace('|', "/").replace('\n', " ")
                    );
                    continue;
                }
                let (p50, p99) = p.sample_to_controller.filter(|q| q.count > 0).map_or_else(
                    || ("–".to_string(), "–".to_string()),
                    |q| (fmt_ns(q.p50_ns), fmt_ns(q.p99_ns)),
                );
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {} | {} | {:.1} | {} | {} | {} | {} | {} | {} | {} |",
                    p.states,
                    p.subscribers,
                    p.executors,
                    p.ticks,
                    p.misses,
                    p.achieved_hz,
                    opt(p.cpu_percent, 1),
                    opt(p.cpu_us_per_tick, 2),
                    fmt_ns(p.lateness.p99_ns),
                    p50,
                    p99,
                    p.samples + p.other_samples,
                    p.lost
                );
            }
            let _ = writeln!(s);
        }
        let _ = writeln!(s, "## Fitted per-unit costs (least squares)\n");
        let _ = writeln!(
            s,
            "| sweep | per-unit cost | CPU fit: µs per tick | R² | latency p50 fit | R² | points \
             |\n|---|---|---|---|---|---|---|"
        );
        for sw in &self.sweeps {
            let line = |f: Option<LineFit>| {
                f.map_or_else(
                    || ("–".to_string(), "–".to_string()),
                    |f| {
                        (
                            format!("{:.2} + {:.4} × n", f.intercept, f.slope),
                            opt(f.r2, 3),
                        )
                    },
                )
            };
            let (cpu, cpu_r2) = line(sw.cpu_fit);
            let (lat, lat_r2) = line(sw.latency_p50_fit);
            let _ = writeln!(
                s,
                "| {} | {} {} | {} | {} | {} | {} | {} |",
                sw.name,
                opt(sw.unit_cost_us, 3),
                sw.unit,
                cpu,
                cpu_r2,
                lat,
                lat_r2,
                sw.points
                    .iter()
                    .filter(|&&i| self.points.get(i).is_some_and(|p| p.error.is_none()))
                    .count()
            );
        }
        plots_section(&mut s, &self.plots);
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_base_point_runs_once() {
        let p = Plan::new(false).points();
        assert_eq!(p.len(), 5 + 3 + 2);
        assert_eq!(p.iter().filter(|q| **q == (41, 1, 1)).count(), 1);
        assert!(p.contains(&(1000, 1, 1)) && p.contains(&(41, 16, 1)) && p.contains(&(41, 1, 4)));
        assert_eq!(Plan::new(true).points().len(), 3 + 2 + 1);
    }

    #[test]
    fn a_failed_point_is_left_out_of_the_fits() {
        let ok = |states: usize, us: f64| ScalingPoint {
            cpu_us_per_tick: Some(us),
            error: None,
            ..ScalingPoint::failed((states, 1, 1), String::new())
        };
        let points = vec![
            ok(1, 10.0),
            ok(41, 50.0),
            ScalingPoint::failed((1000, 1, 1), "the logger process had not exited".into()),
        ];
        let s = sweep(
            "states",
            String::new(),
            vec![0, 1, 2],
            &points,
            |p| p.states,
            1.0,
            "",
        );
        let f = s.cpu_fit.unwrap();
        assert!(
            (f.slope - 1.0).abs() < 1e-9 && (f.intercept - 9.0).abs() < 1e-9,
            "{f:?}"
        );
    }

    #[test]
    fn the_plan_is_checked() {
        let mut p = Plan::new(true);
        p.subscribers.push(17);
        assert!(p.check().is_err());
        let mut p = Plan::new(true);
        p.executors.push(0);
        assert!(p.check().is_err());
        assert!(Plan::new(false).check().is_ok());
    }
}
