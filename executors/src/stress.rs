//! The thesis' stress test (§3.1): three states whose simulated hardware answers every sample
//! request with sin(t_S), t_S the request time, sampled at a given rate, and an external logger
//! that compares what it reads with sin(t_L) at the time it reads it.
//!
//! [`manifest`] writes the executor side; [`Logger`] is the external side (run it in another
//! process: `conductor-stress log`); `conductor-stress run` does both and prints the report.

use std::collections::HashMap;

use conductor_bus::histogram::Histogram;
use conductor_bus::{monotonic_ns, Bus, StateSample, StateSubscriber, TickWaiter};

/// Parameters of a stress manifest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StressConfig {
    /// Base and sample rate (Hz).
    pub rate_hz: f64,
    /// CPU to pin the executor to.
    pub cpu: Option<usize>,
    /// SCHED_FIFO priority.
    pub priority: i32,
    /// Spin before each deadline (µs; 0 = sleep only).
    pub spin_us: f64,
    /// Number of sine states (the thesis used 3).
    pub states: usize,
}

impl Default for StressConfig {
    fn default() -> Self {
        Self {
            rate_hz: 1000.0,
            cpu: None,
            priority: 80,
            spin_us: 0.0,
            states: 3,
        }
    }
}

/// The subsystem name of the stress manifest.
pub const SUBSYSTEM: &str = "stress";

/// A one-subsystem manifest: `states` states `s0..` at `rate_hz`, each on its own device of a
/// `sine` hardware answering sin(t_S) (amplitude 1, 1/2π Hz).
pub fn manifest(cfg: &StressConfig) -> String {
    let mut m = format!(
        "# The thesis' stress test: {n} sine states at {r} Hz.\nsystem = \"stress\"\n\n\
         [subsystems.{SUBSYSTEM}]\nrate_hz = {r}\npriority = {p}\nspin_us = {s}\n",
        n = cfg.states,
        r = cfg.rate_hz,
        p = cfg.priority,
        s = cfg.spin_us
    );
    if let Some(cpu) = cfg.cpu {
        m += &format!("cpu = {cpu}\n");
    }
    m += &format!(
        "\n[subsystems.{SUBSYSTEM}.hardware.sine]\nkind = \"sine\"\n\n\
         [subsystems.{SUBSYSTEM}.protocols.sim]\nkind = \"sim\"\nhardware = \"sine\"\n"
    );
    for i in 0..cfg.states {
        m += &format!(
            "\n[subsystems.{SUBSYSTEM}.devices.d{i}]\nkind = \"sim\"\nprotocol = \"sim\"\nid = {i}\n\n\
             [subsystems.{SUBSYSTEM}.states.s{i}]\ndevice = \"d{i}\"\nhistory = 4096\n"
        );
    }
    m
}

/// What the logger measured for one state.
#[derive(Debug, Clone, Default)]
pub struct StateReport {
    /// `subsystem/state`.
    pub name: String,
    /// Configured rate (Hz).
    pub rate_hz: f64,
    /// Samples whose sample time fell in the window.
    pub count: u64,
    /// Samples the subscriber lost (sequence gaps).
    pub missed: u64,
    /// Owner restarts seen (sequence went backwards).
    pub restarts: u64,
    /// Largest step in sample time between consecutive samples (ns).
    pub max_step_ns: u64,
    /// Consecutive samples more than 1.5 periods apart in sample time.
    pub late_steps: u64,
    /// Consecutive samples with the same sample time (a republished, stale value).
    pub repeats: u64,
    last_t: u64,
    /// Publish → receive latency (ns) of every received sample.
    pub latency: Histogram,
    /// Sample request → receive latency (ns).
    pub end_to_end: Histogram,
    /// Largest |sin(t_S) − value|: what the pipeline did to the value (0 when intact).
    pub err_sample_max: f64,
    /// Largest |sin(t_L) − value|, t_L the logger's read time: the thesis' error.
    pub err_thesis_max: f64,
    /// RMS of the thesis' error.
    pub err_thesis_rms: f64,
    n_err: u64,
    sum_sq: f64,
}

impl StateReport {
    /// One line of `key=value` pairs.
    pub fn line(&self) -> String {
        format!(
            "state={} rate_hz={} count={} missed={} restarts={} max_step_us={:.1} late_steps={} \
             repeats={} latency_p50_us={:.1} \
             latency_p99_us={:.1} latency_max_us={:.1} e2e_p50_us={:.1} e2e_p99_us={:.1} \
             e2e_max_us={:.1} err_sample_max={:.3e} err_thesis_max={:.3e} err_thesis_rms={:.3e}",
            self.name,
            self.rate_hz,
            self.count,
            self.missed,
            self.restarts,
            self.max_step_ns as f64 / 1e3,
            self.late_steps,
            self.repeats,
            self.latency.quantile(0.5) as f64 / 1e3,
            self.latency.quantile(0.99) as f64 / 1e3,
            self.latency.max() as f64 / 1e3,
            self.end_to_end.quantile(0.5) as f64 / 1e3,
            self.end_to_end.quantile(0.99) as f64 / 1e3,
            self.end_to_end.max() as f64 / 1e3,
            self.err_sample_max,
            self.err_thesis_max,
            self.err_thesis_rms
        )
    }
}

/// The external logger: subscribes to states and accounts for every sample.
pub struct Logger {
    subs: Vec<(StateSubscriber, StateReport)>,
    ticks: Option<TickWaiter>,
    sine: bool,
    window: (u64, u64),
}

impl core::fmt::Debug for Logger {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Logger")
            .field("states", &self.subs.len())
            .finish()
    }
}

impl Logger {
    /// Subscribes to `names` (`subsystem/state`); `sine` enables the sin(t) error columns.
    /// Samples are counted once a window is set ([`set_window`](Self::set_window)).
    pub fn new(bus: &Bus, names: &[String], sine: bool) -> Result<Self, conductor_bus::BusError> {
        let mut subs = Vec::with_capacity(names.len());
        let mut ticks = None;
        for n in names {
            let s = StateSubscriber::with_buffer(bus, n, 4096)?;
            if ticks.is_none() {
                ticks = Some(TickWaiter::new(bus, &s.info().subsystem)?);
            }
            let report = StateReport {
                name: n.clone(),
                rate_hz: s.info().meta.rate_hz,
                ..Default::default()
            };
            subs.push((s, report));
        }
        Ok(Self {
            subs,
            ticks,
            sine,
            window: (u64::MAX, u64::MAX),
        })
    }

    /// Counts the samples whose sample time falls in `[start_ns, end_ns)`. Open the window only
    /// after subscribing: samples from before a subscription may already be gone.
    pub fn set_window(&mut self, start_ns: u64, end_ns: u64) {
        self.window = (start_ns, end_ns);
    }

    /// Sleeps until the (first) subsystem's next tick, or `timeout`: waking on the tick event
    /// instead of polling keeps the measured latency that of the bus, not of a poll interval.
    pub fn wait(&mut self, timeout: std::time::Duration) -> Result<(), conductor_bus::BusError> {
        match &mut self.ticks {
            Some(t) => t.wait(timeout).map(|_| ()),
            None => {
                std::thread::sleep(timeout);
                Ok(())
            }
        }
    }

    /// Drains every subscription once; returns the samples taken.
    pub fn poll(&mut self) -> Result<usize, conductor_bus::BusError> {
        let mut n = 0;
        for (sub, rep) in &mut self.subs {
            while let Some(s) = sub.receive()? {
                let now = monotonic_ns();
                account(rep, &s, now, self.sine, self.window);
                n += 1;
            }
            rep.missed = sub.missed();
            rep.restarts = sub.restarts();
        }
        Ok(n)
    }

    /// The reports so far.
    pub fn reports(&self) -> Vec<StateReport> {
        self.subs
            .iter()
            .map(|(_, r)| {
                let mut r = r.clone();
                if r.n_err > 0 {
                    r.err_thesis_rms = (r.sum_sq / r.n_err as f64).sqrt();
                }
                r
            })
            .collect()
    }
}

fn account(rep: &mut StateReport, s: &StateSample, now: u64, sine: bool, window: (u64, u64)) {
    if s.t_sample_ns >= window.0 && s.t_sample_ns < window.1 {
        rep.count += 1;
        if rep.last_t >= window.0 {
            let step = s.t_sample_ns.saturating_sub(rep.last_t);
            rep.max_step_ns = rep.max_step_ns.max(step);
            if step == 0 {
                rep.repeats += 1;
            } else if rep.rate_hz > 0.0 && step as f64 > 1.5e9 / rep.rate_hz {
                rep.late_steps += 1;
            }
        }
    }
    rep.last_t = s.t_sample_ns;
    rep.latency.record(now.saturating_sub(s.t_publish_ns));
    rep.end_to_end.record(now.saturating_sub(s.t_sample_ns));
    if sine {
        let e_sample = ((s.t_sample_ns as f64 * 1e-9).sin() - s.value).abs();
        let e_thesis = (now as f64 * 1e-9).sin() - s.value;
        rep.err_sample_max = rep.err_sample_max.max(e_sample);
        rep.err_thesis_max = rep.err_thesis_max.max(e_thesis.abs());
        rep.sum_sq += e_thesis * e_thesis;
        rep.n_err += 1;
    }
}

/// Parses a report line back into `key → value` (for tests and scripts).
pub fn parse_line(line: &str) -> HashMap<String, String> {
    line.split_whitespace()
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::manifest::Manifest;

    #[test]
    fn stress_manifests_validate() {
        for rate in [50.0, 1000.0, 10_000.0] {
            let text = manifest(&StressConfig {
                rate_hz: rate,
                cpu: Some(1),
                ..Default::default()
            });
            let m = Manifest::parse(&text, "stress.toml").unwrap_or_else(|e| panic!("{e}"));
            let s = &m.subsystems[0];
            assert_eq!((s.rate_hz, s.states.len(), s.cpu), (rate, 3, Some(1)));
        }
    }

    #[test]
    fn the_thesis_error_is_sin_of_the_read_time_minus_the_value() {
        let mut r = StateReport::default();
        let t_s = 1_000_000_000u64; // 1 s
        let s = StateSample {
            t_sample_ns: t_s,
            t_publish_ns: t_s + 1_000,
            value: 1f64.sin(),
            ..Default::default()
        };
        // Read 1 ms later: the error is sin(1.001) − sin(1) ≈ cos(1)·0.001.
        account(&mut r, &s, t_s + 1_000_000, true, (0, u64::MAX));
        assert_eq!(r.count, 1);
        assert!(r.err_sample_max < 1e-15);
        let expect = 1.001f64.sin() - 1f64.sin();
        assert!((r.err_thesis_max - expect).abs() < 1e-12);
        assert_eq!(r.end_to_end.max(), 1_000_000);
        let kv = parse_line(&r.line());
        assert_eq!(kv["count"], "1");
    }
}
