//! The suite's results: one [`Report`], written as JSON (for machines) and Markdown (for people,
//! every figure beside its floor with the ratio).

use std::collections::HashMap;
use std::fmt::Write as _;

use conductor_bus::Histogram;
use serde::Serialize;

use super::machine::Machine;
use crate::percentiles::fmt_ns;
use crate::Percentiles;

/// The layout version of `report.json`: 2 added `mode` (`suite` or `scaling`, whose report is
/// [`super::scaling::ScalingReport`]).
pub const SCHEMA: u32 = 3;

/// Nearest-rank percentiles of a latency (ns).
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct Quantiles {
    /// Samples.
    pub count: u64,
    /// Median.
    pub p50_ns: u64,
    /// 99th percentile.
    pub p99_ns: u64,
    /// 99.9th percentile.
    pub p999_ns: u64,
    /// Largest.
    pub max_ns: u64,
}

impl From<&Percentiles> for Quantiles {
    fn from(p: &Percentiles) -> Self {
        Self {
            count: p.count as u64,
            p50_ns: p.p50,
            p99_ns: p.p99,
            p999_ns: p.p999,
            max_ns: p.max,
        }
    }
}

impl From<&Histogram> for Quantiles {
    fn from(h: &Histogram) -> Self {
        Self {
            count: h.count(),
            p50_ns: h.quantile(0.5),
            p99_ns: h.quantile(0.99),
            p999_ns: h.quantile(0.999),
            max_ns: h.max(),
        }
    }
}

impl Quantiles {
    /// Reads `<prefix>_p50_us`, `_p99_us`, `_p999_us`, `_max_us` of a stress report line
    /// (`count` from `count_key`); `None` when a key is missing or not a number.
    pub fn from_line(kv: &HashMap<String, String>, prefix: &str, count_key: &str) -> Option<Self> {
        let us = |k: &str| -> Option<u64> {
            let v: f64 = kv.get(&format!("{prefix}_{k}_us"))?.parse().ok()?;
            Some((v * 1e3).round() as u64)
        };
        Some(Self {
            count: kv.get(count_key)?.parse().ok()?,
            p50_ns: us("p50")?,
            p99_ns: us("p99")?,
            p999_ns: us("p999")?,
            max_ns: us("max")?,
        })
    }

    /// Each percentile over the floor's (`None` fields in JSON when the floor is 0).
    pub fn over(&self, floor: &Quantiles) -> Ratios {
        let r = |a: u64, b: u64| (b > 0).then(|| a as f64 / b as f64);
        Ratios {
            p50: r(self.p50_ns, floor.p50_ns),
            p99: r(self.p99_ns, floor.p99_ns),
            p999: r(self.p999_ns, floor.p999_ns),
            max: r(self.max_ns, floor.max_ns),
        }
    }
}

/// Ratios of percentiles to a floor's.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct Ratios {
    /// p50 / floor p50.
    pub p50: Option<f64>,
    /// p99 / floor p99.
    pub p99: Option<f64>,
    /// p99.9 / floor p99.9.
    pub p999: Option<f64>,
    /// max / floor max.
    pub max: Option<f64>,
}

/// One path of the IPC ping-pong.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct IpcRow {
    /// `raw-busy`, `state-busy`, `raw-event`, `state-event`.
    pub path: String,
    /// The raw path it is compared with.
    pub floor: String,
    /// One-way latency, publisher stamp → subscriber receipt, two processes.
    pub one_way: Quantiles,
    /// This path over its floor.
    pub over_floor: Ratios,
}

/// cyclictest at one rate.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CyclicRow {
    /// Rate (Hz).
    pub rate_hz: f64,
    /// The command line.
    pub command: String,
    /// Wake-up latency (µs resolution).
    pub latency: Quantiles,
    /// Mean wake-up latency (ns).
    pub mean_ns: f64,
    /// Wake-ups beyond the histogram range.
    pub overflows: u64,
}

/// The command probe's figures of one stress run.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CommandRow {
    /// Commands sent.
    pub sent: u64,
    /// Commands whose write tick was identified.
    pub written: u64,
    /// Commands whose write tick could not be identified (lost sample, or never seen).
    pub unresolved: u64,
    /// Writes whose tick stamp preceded the send (recorded as 0).
    pub early: u64,
    /// Controller send → wake stamp of the tick that wrote it to the hardware.
    pub to_write: Quantiles,
    /// Controller send → sample time of the first sample that reflects it.
    pub to_reflect: Quantiles,
}

/// One stress run: a rate and a number of sine states.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct StressRow {
    /// Base and sample rate (Hz).
    pub rate_hz: f64,
    /// Sine states (one more, the command probe's, ran beside them).
    pub states: usize,
    /// How the readers took the states: `states` (a subscriber per state) or `snapshot`.
    pub reader: String,
    /// The executor ran SCHED_FIFO.
    pub rt_active: bool,
    /// CPU it was pinned to.
    pub pinned_cpu: Option<usize>,
    /// Ticks in the window.
    pub ticks: u64,
    /// Deadlines missed (slots skipped) in the window.
    pub misses: u64,
    /// The same per one-second slice of the window: misses over time.
    pub misses_by_second: Vec<u64>,
    /// Misses in the first and the second half of those slices: about equal when misses do
    /// not grow over time.
    pub misses_by_half: (u64, u64),
    /// Ticks per second.
    pub achieved_hz: f64,
    /// CPU time of the executor process, % of one CPU.
    pub cpu_percent: Option<f64>,
    /// Tick lateness (wake-up − deadline).
    pub lateness: Quantiles,
    /// Lateness over cyclictest's at the same rate.
    pub lateness_over_cyclictest: Option<Ratios>,
    /// Hardware sample (request time) → external subscriber, all sine states.
    pub sample_to_subscriber: Quantiles,
    /// Publish → external subscriber, all sine states.
    pub publish_to_subscriber: Quantiles,
    /// `sample_to_subscriber` over the raw-event IPC floor.
    pub sample_to_subscriber_over_ipc: Option<Ratios>,
    /// The floor of the same shape: a raw periodic publisher at the executor's rate, CPU and
    /// priority → a raw event-woken reader of the same states, read the same way.
    pub shape_floor: Option<Quantiles>,
    /// `sample_to_subscriber` over `shape_floor`.
    pub sample_to_subscriber_over_shape_floor: Option<Ratios>,
    /// Controller command → hardware write.
    pub command: Option<CommandRow>,
    /// Samples logged in the window.
    pub samples: u64,
    /// Samples the logger lost.
    pub lost: u64,
    /// Consecutive samples more than 1.5 periods apart, summed over the sine states (one late
    /// tick counts once per state).
    pub late_steps: u64,
    /// Largest |sin(t_L) − value| (the thesis' error).
    pub thesis_error_max: f64,
    /// RMS of sin(t_L) − value.
    pub thesis_error_rms: f64,
    /// Largest |sin(t_S) − value| (0: the pipeline kept every value intact).
    pub pipeline_error_max: f64,
}

/// The cost of one publish path ([`crate::publish_cost`]), one process, one subscriber per state.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct PublishCostRow {
    /// `raw`, `state`, `state-clock-per-state`, `staged`.
    pub path: String,
    /// States published per tick.
    pub states: usize,
    /// Subscribers per state.
    pub subscribers: usize,
    /// Median ns per state (no tick event).
    pub per_state_ns: f64,
    /// Median ns per tick of every state and the tick event.
    pub per_tick_ns: f64,
}

/// The executor's CPU cost per state per tick, beside a raw publish of one state.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct PerStateCostRow {
    /// Rate (Hz).
    pub rate_hz: f64,
    /// The stress runs' reader.
    pub reader: String,
    /// The two state counts whose CPU per tick the slope joins.
    pub states: (usize, usize),
    /// Executor CPU ns per tick per state (the slope).
    pub executor_ns_per_state: f64,
    /// A raw iceoryx2 publish of one state (loan, write, send) with as many subscribers per
    /// state as the reader brings (1 for `states`, 0 for `snapshot`), ns.
    pub raw_publish_ns: f64,
    /// The executor's own publish path per state (stage, snapshot, send), ns.
    pub staged_publish_ns: f64,
    /// `executor_ns_per_state / raw_publish_ns`.
    pub over_raw: f64,
}

/// Everything one suite run measured.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Report {
    /// Layout version of this JSON ([`SCHEMA`]).
    pub schema: u32,
    /// `suite` (this report) or `scaling` ([`super::scaling::ScalingReport`]).
    pub mode: String,
    /// When the run started.
    pub date: String,
    /// The command line.
    pub command: String,
    /// The machine.
    pub machine: Machine,
    /// A `--quick` run.
    pub quick: bool,
    /// Rates (Hz).
    pub rates_hz: Vec<f64>,
    /// Sine-state counts.
    pub states: Vec<usize>,
    /// Logged seconds per run.
    pub seconds: f64,
    /// Executor and cyclictest CPU.
    pub cpu: usize,
    /// Executor and cyclictest SCHED_FIFO priority.
    pub priority: i32,
    /// The IPC floor and the bus over it.
    pub ipc: Vec<IpcRow>,
    /// The kernel wake-up floor per rate.
    pub cyclictest: Vec<CyclicRow>,
    /// Why cyclictest did not run, if it did not.
    pub cyclictest_note: Option<String>,
    /// What a publish costs per state, every path, in this run.
    pub publish_cost: Vec<PublishCostRow>,
    /// The executor's CPU per state beside a raw publish, per rate and reader.
    pub per_state_cost: Vec<PerStateCostRow>,
    /// The stress runs.
    pub stress: Vec<StressRow>,
    /// Image files written (names relative to the output directory).
    pub plots: Vec<String>,
}

/// The thesis' reading of its Fig. 3.1 (3 states, 2011 hardware), by rate.
pub fn thesis_reading(rate_hz: f64) -> &'static str {
    match rate_hz {
        r if r <= 100.0 => "smooth sinusoidal error",
        r if r <= 1000.0 => "slight breakdown",
        r if r < 5000.0 => "breakdown lies between 1 and 5 kHz",
        _ => "severe breakdown, high noise",
    }
}

fn q4(q: &Quantiles) -> String {
    format!(
        "{} | {} | {} | {}",
        fmt_ns(q.p50_ns),
        fmt_ns(q.p99_ns),
        fmt_ns(q.p999_ns),
        fmt_ns(q.max_ns)
    )
}

fn ratio(r: Option<f64>) -> String {
    r.map_or_else(|| "–".into(), |r| format!("{r:.2}"))
}

fn rate(r: f64) -> String {
    format!("{r}")
}

impl Report {
    /// The Markdown report.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let m = &self.machine;
        let _ = writeln!(s, "# conductor bench — {}\n", self.date);
        let _ = writeln!(s, "Command: `{}`\n", self.command);
        let _ = writeln!(
            s,
            "Machine: {}. Kernel command line: `{}`.\n",
            m.summary(),
            m.cmdline
        );
        let _ = writeln!(
            s,
            "Each stress run: {} s logged, the executor on CPU {} at SCHED_FIFO {} (sleep-based, \
             no spin), sine states plus one command-probe state; cyclictest at the same rate, \
             priority and CPU, for the same time, just before the runs of its rate. Percentiles \
             from the executor's histogram are bucket upper bounds (≤ 12.5 % over); cyclictest's \
             have 1 µs resolution.\n",
            self.seconds, self.cpu, self.priority
        );

        let _ = writeln!(s, "## IPC floor: one-way latency between two processes\n");
        let _ = writeln!(
            s,
            "| path | samples | p50 | p99 | p99.9 | max | p50 / floor | p99 / floor |\n|---|---|---|---|---|---|---|---|"
        );
        for r in &self.ipc {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} |",
                r.path,
                r.one_way.count,
                q4(&r.one_way),
                ratio(r.over_floor.p50),
                ratio(r.over_floor.p99)
            );
        }

        per_state_section(&mut s, &self.publish_cost, &self.per_state_cost);
        let _ = writeln!(
            s,
            "\n## Tick lateness beside the kernel's wake-up floor (cyclictest)\n"
        );
        if let Some(n) = &self.cyclictest_note {
            let _ = writeln!(s, "cyclictest did not run: {n}\n");
        }
        let _ = writeln!(
            s,
            "| rate Hz | states | reader | RT | ticks | misses | 1st / 2nd half | p50 | p99 | p99.9 | max | cyclictest p50 | p99 | p99.9 | max | ×p50 | ×p99 | ×p99.9 | ×max |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
        );
        for r in &self.stress {
            let ct = self
                .cyclictest
                .iter()
                .find(|c| c.rate_hz == r.rate_hz)
                .map_or_else(|| "– | – | – | –".to_string(), |c| q4(&c.latency));
            let x = r.lateness_over_cyclictest.unwrap_or_default();
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {} / {} | {} | {} | {} | {} | {} | {} |",
                rate(r.rate_hz),
                r.states,
                r.reader,
                if r.rt_active { "FIFO" } else { "no" },
                r.ticks,
                r.misses,
                r.misses_by_half.0,
                r.misses_by_half.1,
                q4(&r.lateness),
                ct,
                ratio(x.p50),
                ratio(x.p99),
                ratio(x.p999),
                ratio(x.max)
            );
        }

        let _ = writeln!(s, "\n## End to end\n");
        let _ = writeln!(
            s,
            "Sample → subscriber: the sample request's time t_S (when the simulated hardware \
             produced sin(t_S)) → the external logger process reading it, woken by the tick \
             event and subscribed to every state (reader `states`), or woken by the snapshot \
             event and reading the subsystem's snapshot (reader `snapshot`). Its floors: the \
             raw-event ping-pong, and the floor of the same shape (a raw periodic publisher at \
             the executor's rate, CPU and priority, woken reader off that CPU, the same states \
             read the same way; `conductor_benches::periodic`). Command → write: the probe process's \
             send stamp → the wake stamp of the tick that wrote the value to the (loopback) \
             hardware; it includes the wait for the next tick (0–1 period, commands are sent at \
             random phases). Command → reflected: → the first sample showing the value (one \
             period later).\n"
        );
        let _ = writeln!(
            s,
            "| rate Hz | states | reader | sample→sub p50 | p99 | p99.9 | max | p50 / IPC floor | shape floor p50 | p99 | p50 / shape floor | cmd→write p50 | p99 | p99.9 | max | cmd→reflected p50 | max | commands |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
        );
        for r in &self.stress {
            let (cw, cr, n) = match &r.command {
                Some(c) => (
                    q4(&c.to_write),
                    format!(
                        "{} | {}",
                        fmt_ns(c.to_reflect.p50_ns),
                        fmt_ns(c.to_reflect.max_ns)
                    ),
                    format!("{}/{}", c.written, c.sent),
                ),
                None => ("– | – | – | –".into(), "– | –".into(), "–".into()),
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                rate(r.rate_hz),
                r.states,
                r.reader,
                q4(&r.sample_to_subscriber),
                ratio(r.sample_to_subscriber_over_ipc.and_then(|x| x.p50)),
                r.shape_floor.map_or_else(
                    || "– | –".to_string(),
                    |f| format!("{} | {}", fmt_ns(f.p50_ns), fmt_ns(f.p99_ns))
                ),
                ratio(r.sample_to_subscriber_over_shape_floor.and_then(|x| x.p50)),
                cw,
                cr,
                n
            );
        }

        let _ = writeln!(s, "\n## The thesis' stress test (§3.1, Fig. 3.1)\n");
        let _ = writeln!(
            s,
            "Error = sin(t_L) − value, t_L the logger's read time: without delay it would be 0; \
             it is bounded by the sample → subscriber latency (|sin a − sin b| ≤ |a − b|). \
             Pipeline = |sin(t_S) − value| (0: no value was corrupted). A late step is two \
             consecutive samples more than 1.5 periods apart (a tick late by half a period or \
             more). The thesis ran 3 states \
             on 2011 hardware and reported its real-time behaviour breaking down between 1 kHz \
             and 5 kHz.\n"
        );
        let _ = writeln!(
            s,
            "| rate Hz | states | reader | samples | lost | late steps per state | executor CPU % | error max | error RMS | pipeline max | thesis (Fig. 3.1, 3 states) |\n|---|---|---|---|---|---|---|---|---|---|---|"
        );
        for r in &self.stress {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {:.1} | {} | {:.2e} | {:.2e} | {:.1e} | {} |",
                rate(r.rate_hz),
                r.states,
                r.reader,
                r.samples,
                r.lost,
                r.late_steps as f64 / r.states.max(1) as f64,
                r.cpu_percent
                    .map_or_else(|| "–".into(), |c| format!("{c:.1}")),
                r.thesis_error_max,
                r.thesis_error_rms,
                r.pipeline_error_max,
                thesis_reading(r.rate_hz)
            );
        }
        plots_section(&mut s, &self.plots);
        s
    }
}

/// The publish paths' cost and the executor's per-state cost beside it.
fn per_state_section(s: &mut String, publish: &[PublishCostRow], per_state: &[PerStateCostRow]) {
    if publish.is_empty() {
        return;
    }
    let _ = writeln!(s, "\n## Per-state cost beside a raw publish\n");
    let _ = writeln!(
        s,
        "One process publishing {} states with one subscriber each, and with none (median of \
         7 rounds; `conductor_benches::publish_cost`): `raw` is iceoryx2 loan + write + send \
         with the states' settings, `staged` the executor's path (stage every state, the \
         snapshot, then each state). The executor's cost per state is the slope of its CPU \
         per tick between the stress runs' smallest and largest state counts (all of its \
         per-state work: stages, publish, stats), beside the raw publish with the \
         subscribers its readers bring (one per state for `states`, none for `snapshot`).\n",
        publish[0].states
    );
    let _ = writeln!(
        s,
        "| path | subscribers per state | ns per state | ns per tick (with the tick event) |\n|---|---|---|---|"
    );
    for p in publish {
        let _ = writeln!(
            s,
            "| {} | {} | {:.0} | {:.0} |",
            p.path, p.subscribers, p.per_state_ns, p.per_tick_ns
        );
    }
    if per_state.is_empty() {
        return;
    }
    let _ = writeln!(
        s,
        "\n| rate Hz | reader | states | executor ns per state per tick | raw publish ns | × raw | staged publish ns |\n|---|---|---|---|---|---|---|"
    );
    for r in per_state {
        let _ = writeln!(
            s,
            "| {} | {} | {} → {} | {:.0} | {:.0} | {:.2} | {:.0} |",
            rate(r.rate_hz),
            r.reader,
            r.states.0,
            r.states.1,
            r.executor_ns_per_state,
            r.raw_publish_ns,
            r.over_raw,
            r.staged_publish_ns
        );
    }
}

/// The report's list of its images (nothing when there are none).
pub(crate) fn plots_section(s: &mut String, plots: &[String]) {
    if !plots.is_empty() {
        let _ = writeln!(s, "\n## Plots\n");
        for p in plots {
            let _ = writeln!(s, "- [{p}]({p})");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stress::parse_line as kv;

    #[test]
    fn quantiles_read_a_stress_line_in_ns() {
        let line = kv(
            "summary=all count=12 e2e_p50_us=65.5 e2e_p99_us=786.4 e2e_p999_us=1310.7 \
                        e2e_max_us=1717.4",
        );
        let q = Quantiles::from_line(&line, "e2e", "count").unwrap();
        assert_eq!(
            q,
            Quantiles {
                count: 12,
                p50_ns: 65_500,
                p99_ns: 786_400,
                p999_ns: 1_310_700,
                max_ns: 1_717_400
            }
        );
        assert!(Quantiles::from_line(&line, "latency", "count").is_none());
    }

    #[test]
    fn ratios_skip_a_zero_floor() {
        let a = Quantiles {
            count: 1,
            p50_ns: 30,
            p99_ns: 60,
            p999_ns: 90,
            max_ns: 120,
        };
        let floor = Quantiles {
            p999_ns: 0,
            ..Quantiles {
                count: 1,
                p50_ns: 10,
                p99_ns: 20,
                p999_ns: 30,
                max_ns: 40,
            }
        };
        let r = a.over(&floor);
        assert_eq!(
            (r.p50, r.p99, r.p999, r.max),
            (Some(3.0), Some(3.0), None, Some(3.0))
        );
    }

    #[test]
    fn the_thesis_breakdown_by_rate() {
        assert_eq!(thesis_reading(50.0), "smooth sinusoidal error");
        assert_eq!(thesis_reading(1000.0), "slight breakdown");
        assert_eq!(thesis_reading(10_000.0), "severe breakdown, high noise");
    }
}
