//! The external logger of the stress test: subscribes to states, accounts for every sample whose
//! sample time falls in a window, and computes the thesis' error sin(t_L) − value.

use std::collections::HashMap;

use conductor_bus::histogram::Histogram;
use conductor_bus::{monotonic_ns, Bus, SnapshotReader, StateSample, StateSubscriber, TickWaiter};

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
    /// Publish → receive latency (ns) of every sample in the window.
    pub latency: Histogram,
    /// Sample request → receive latency (ns) of every sample in the window: hardware sample →
    /// external subscriber.
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

fn us(ns: u64) -> f64 {
    ns as f64 / 1e3
}

impl StateReport {
    /// One line of `key=value` pairs.
    pub fn line(&self) -> String {
        format!(
            "state={} rate_hz={} count={} missed={} restarts={} max_step_us={:.1} late_steps={} \
             repeats={} {} {} err_sample_max={:.3e} err_thesis_max={:.3e} err_thesis_rms={:.3e}",
            self.name,
            self.rate_hz,
            self.count,
            self.missed,
            self.restarts,
            us(self.max_step_ns),
            self.late_steps,
            self.repeats,
            quantile_keys("latency", &self.latency),
            quantile_keys("e2e", &self.end_to_end),
            self.err_sample_max,
            self.err_thesis_max,
            self.err_thesis_rms
        )
    }

    fn finish(&self) -> Self {
        let mut r = self.clone();
        if r.n_err > 0 {
            r.err_thesis_rms = (r.sum_sq / r.n_err as f64).sqrt();
        }
        r
    }
}

/// `<p>_p50_us=.. <p>_p99_us=.. <p>_p999_us=.. <p>_max_us=..` of a histogram.
pub(crate) fn quantile_keys(prefix: &str, h: &Histogram) -> String {
    format!(
        "{prefix}_p50_us={:.1} {prefix}_p99_us={:.1} {prefix}_p999_us={:.1} {prefix}_max_us={:.1}",
        us(h.quantile(0.5)),
        us(h.quantile(0.99)),
        us(h.quantile(0.999)),
        us(h.max())
    )
}

/// Every state of a [`Logger`] taken together.
#[derive(Debug, Clone, Default)]
pub struct Summary {
    /// States logged.
    pub states: usize,
    /// Samples in the window, all states.
    pub count: u64,
    /// Samples the subscribers lost.
    pub missed: u64,
    /// Sample-time steps longer than 1.5 periods.
    pub late_steps: u64,
    /// Republished (stale) samples.
    pub repeats: u64,
    /// Publish → receive latency, all states merged.
    pub latency: Histogram,
    /// Hardware sample → external subscriber, all states merged.
    pub end_to_end: Histogram,
    /// Largest |sin(t_S) − value| over all states.
    pub err_sample_max: f64,
    /// Largest |sin(t_L) − value| over all states.
    pub err_thesis_max: f64,
    /// RMS of sin(t_L) − value over all samples.
    pub err_thesis_rms: f64,
}

impl Summary {
    /// One line of `key=value` pairs, starting with `summary=all`.
    pub fn line(&self) -> String {
        format!(
            "summary=all states={} count={} missed={} late_steps={} repeats={} {} {} \
             err_sample_max={:.3e} err_thesis_max={:.3e} err_thesis_rms={:.3e}",
            self.states,
            self.count,
            self.missed,
            self.late_steps,
            self.repeats,
            quantile_keys("latency", &self.latency),
            quantile_keys("e2e", &self.end_to_end),
            self.err_sample_max,
            self.err_thesis_max,
            self.err_thesis_rms
        )
    }
}

/// The external logger: subscribes to states and accounts for every sample.
pub struct Logger {
    subs: Vec<(Source, StateReport)>,
    ticks: Vec<TickWaiter>,
    snapshots: Vec<SnapshotReader>,
    sine: bool,
    window: (u64, u64),
    trace: Vec<(u64, f64)>,
}

/// Where the logger reads a state.
enum Source {
    /// Its own service.
    State(Box<StateSubscriber>),
    /// Entry `index` of the snapshot of `snapshots[reader]`, with the last `seq` taken.
    Entry {
        reader: usize,
        index: usize,
        last_seq: Option<u64>,
    },
}

impl core::fmt::Debug for Logger {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Logger")
            .field("states", &self.subs.len())
            .field("snapshots", &self.snapshots.len())
            .finish()
    }
}

impl Logger {
    /// Subscribes to `names` (`subsystem/state`) with a buffer of `buffer` samples each (at
    /// most the states' history), and to the tick event of each of their subsystems (up to 16);
    /// `sine` enables the sin(t) error columns. Samples are counted once a window is set
    /// ([`set_window`](Self::set_window)).
    pub fn new(
        bus: &Bus,
        names: &[String],
        sine: bool,
        buffer: usize,
    ) -> Result<Self, conductor_bus::BusError> {
        let mut logger = Self::empty(sine);
        let mut subsystems: Vec<String> = Vec::new();
        for n in names {
            let s = StateSubscriber::with_buffer(bus, n, buffer.max(1))?;
            if !subsystems.contains(&s.info().subsystem) {
                subsystems.push(s.info().subsystem.clone());
                logger
                    .ticks
                    .push(TickWaiter::new(bus, &s.info().subsystem)?);
            }
            let report = StateReport {
                name: n.clone(),
                rate_hz: s.info().meta.rate_hz,
                ..Default::default()
            };
            logger.subs.push((Source::State(Box::new(s)), report));
        }
        Ok(logger)
    }

    /// Reads `names` from their subsystems' snapshots instead (one reader per subsystem, up to
    /// 16, woken by the snapshot events): what a controller of whole subsystems does. Each
    /// state's samples are those of its own service; one repeated in a snapshot (a slower
    /// state) is counted once, and a `seq` gap counts as lost.
    pub fn with_snapshots(
        bus: &Bus,
        names: &[String],
        sine: bool,
    ) -> Result<Self, conductor_bus::BusError> {
        let mut logger = Self::empty(sine);
        let mut subsystems: Vec<String> = Vec::new();
        // One listing of the domain for every name (resolving each name alone lists the
        // domain each time: minutes for 1 000 states).
        let listed: HashMap<String, conductor_bus::StateInfo> = bus
            .list_states()?
            .into_iter()
            .map(|s| (s.qualified_name(), s))
            .collect();
        for n in names {
            let info = match listed.get(n) {
                Some(i) => i.clone(),
                None => bus.resolve(n)?,
            };
            let reader = match subsystems.iter().position(|s| *s == info.subsystem) {
                Some(r) => r,
                None => {
                    logger.snapshots.push(SnapshotReader::with_buffer(
                        bus,
                        &info.subsystem,
                        conductor_bus::qos::SNAPSHOT_BUFFER,
                    )?);
                    subsystems.push(info.subsystem.clone());
                    subsystems.len() - 1
                }
            };
            let report = StateReport {
                name: n.clone(),
                rate_hz: info.meta.rate_hz,
                ..Default::default()
            };
            let source = Source::Entry {
                reader,
                index: info.meta.index as usize,
                last_seq: None,
            };
            logger.subs.push((source, report));
        }
        Ok(logger)
    }

    fn empty(sine: bool) -> Self {
        Self {
            subs: Vec::new(),
            ticks: Vec::new(),
            snapshots: Vec::new(),
            sine,
            window: (u64::MAX, u64::MAX),
            trace: Vec::new(),
        }
    }

    /// Counts the samples whose sample time falls in `[start_ns, end_ns)`. Open the window only
    /// after subscribing: samples from before a subscription may already be gone (and the ones
    /// a new subscriber is handed from the service's history are old).
    pub fn set_window(&mut self, start_ns: u64, end_ns: u64) {
        self.window = (start_ns, end_ns);
    }

    /// Keeps the first state's `(t_L, sin(t_L) − value)` for up to `capacity` samples of the
    /// window (with `sine`): the curve of the thesis' Fig. 3.1. Allocates here, not while
    /// logging.
    pub fn keep_trace(&mut self, capacity: usize) {
        self.trace = Vec::with_capacity(capacity);
    }

    /// The kept trace: `(t_L ns, sin(t_L) − value)` in read order.
    pub fn trace(&self) -> &[(u64, f64)] {
        &self.trace
    }

    /// Sleeps until a subsystem's next tick (or snapshot), or `timeout`: waking on the events
    /// instead of polling keeps the measured latency that of the bus, not of a poll interval.
    pub fn wait(&mut self, timeout: std::time::Duration) -> Result<(), conductor_bus::BusError> {
        if !self.snapshots.is_empty() {
            return SnapshotReader::wait_any(&mut self.snapshots, timeout);
        }
        match self.ticks.as_mut_slice() {
            [] => {
                std::thread::sleep(timeout);
                Ok(())
            }
            [t] => t.wait(timeout).map(|_| ()),
            all => TickWaiter::wait_any(all, timeout).map(|_| ()),
        }
    }

    /// Drains every subscription (or takes each subsystem's newest snapshot) once; returns the
    /// samples taken.
    pub fn poll(&mut self) -> Result<usize, conductor_bus::BusError> {
        let (sine, window) = (self.sine, self.window);
        let trace = &mut self.trace;
        let mut keep = |i: usize, now: u64, err: Option<f64>| {
            if let Some(e) = err.filter(|_| i == 0) {
                if trace.len() < trace.capacity() {
                    trace.push((now, e));
                }
            }
        };
        let mut n = 0;
        for (i, (source, rep)) in self.subs.iter_mut().enumerate() {
            if let Source::State(sub) = source {
                while let Some(s) = sub.receive()? {
                    let now = monotonic_ns();
                    keep(i, now, account(rep, &s, now, sine, window));
                    n += 1;
                }
                rep.missed = sub.missed();
                rep.restarts = sub.restarts();
            }
        }
        // Every queued snapshot, oldest first, with one receive time each: the whole tick is
        // in hand at once.
        for (r, reader) in self.snapshots.iter_mut().enumerate() {
            while let Some(snap) = reader.receive()? {
                let now = monotonic_ns();
                for (i, (source, rep)) in self.subs.iter_mut().enumerate() {
                    let Source::Entry {
                        reader,
                        index,
                        last_seq,
                    } = source
                    else {
                        continue;
                    };
                    let Some(s) = snap
                        .get(*index)
                        .filter(|s| *reader == r && s.t_sample_ns != 0)
                    else {
                        continue;
                    };
                    match *last_seq {
                        Some(l) if s.seq == l => continue,
                        Some(l) if s.seq < l => rep.restarts += 1,
                        Some(l) => rep.missed += s.seq - l - 1,
                        None => {}
                    }
                    *last_seq = Some(s.seq);
                    keep(i, now, account(rep, s, now, sine, window));
                    n += 1;
                }
            }
        }
        Ok(n)
    }

    /// The reports so far.
    pub fn reports(&self) -> Vec<StateReport> {
        self.subs.iter().map(|(_, r)| r.finish()).collect()
    }

    /// Every state's figures taken together.
    pub fn summary(&self) -> Summary {
        summarize(self.subs.iter().map(|(_, r)| r))
    }
}

fn summarize<'a>(reports: impl Iterator<Item = &'a StateReport>) -> Summary {
    let mut s = Summary::default();
    let (mut sum_sq, mut n_err) = (0.0, 0);
    for r in reports {
        s.states += 1;
        s.count += r.count;
        s.missed += r.missed;
        s.late_steps += r.late_steps;
        s.repeats += r.repeats;
        s.latency.merge(&r.latency);
        s.end_to_end.merge(&r.end_to_end);
        s.err_sample_max = s.err_sample_max.max(r.err_sample_max);
        s.err_thesis_max = s.err_thesis_max.max(r.err_thesis_max);
        sum_sq += r.sum_sq;
        n_err += r.n_err;
    }
    if n_err > 0 {
        s.err_thesis_rms = (sum_sq / n_err as f64).sqrt();
    }
    s
}

/// Accounts for one sample read at `now`; returns the thesis' error sin(t_L) − value when the
/// sample lies in the window and `sine` is set.
fn account(
    rep: &mut StateReport,
    s: &StateSample,
    now: u64,
    sine: bool,
    window: (u64, u64),
) -> Option<f64> {
    let in_window = s.t_sample_ns >= window.0 && s.t_sample_ns < window.1;
    if in_window && rep.last_t >= window.0 {
        let step = s.t_sample_ns.saturating_sub(rep.last_t);
        rep.max_step_ns = rep.max_step_ns.max(step);
        if step == 0 {
            rep.repeats += 1;
        } else if rep.rate_hz > 0.0 && step as f64 > 1.5e9 / rep.rate_hz {
            rep.late_steps += 1;
        }
    }
    rep.last_t = s.t_sample_ns;
    if !in_window {
        return None;
    }
    rep.count += 1;
    rep.latency.record(now.saturating_sub(s.t_publish_ns));
    rep.end_to_end.record(now.saturating_sub(s.t_sample_ns));
    if !sine {
        return None;
    }
    let e_sample = ((s.t_sample_ns as f64 * 1e-9).sin() - s.value).abs();
    let e_thesis = (now as f64 * 1e-9).sin() - s.value;
    rep.err_sample_max = rep.err_sample_max.max(e_sample);
    rep.err_thesis_max = rep.err_thesis_max.max(e_thesis.abs());
    rep.sum_sq += e_thesis * e_thesis;
    rep.n_err += 1;
    Some(e_thesis)
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

    fn sample(t_s: u64, value: f64) -> StateSample {
        StateSample {
            t_sample_ns: t_s,
            t_publish_ns: t_s + 1_000,
            value,
            ..Default::default()
        }
    }

    #[test]
    fn the_thesis_error_is_sin_of_the_read_time_minus_the_value() {
        let mut r = StateReport::default();
        let t_s = 1_000_000_000u64; // 1 s
                                    // Read 1 ms later: the error is sin(1.001) − sin(1) ≈ cos(1)·0.001.
        let e = account(
            &mut r,
            &sample(t_s, 1f64.sin()),
            t_s + 1_000_000,
            true,
            (0, u64::MAX),
        );
        assert_eq!(r.count, 1);
        assert!(r.err_sample_max < 1e-15);
        let expect = 1.001f64.sin() - 1f64.sin();
        assert!((r.err_thesis_max - expect).abs() < 1e-12);
        assert!((e.unwrap() - expect).abs() < 1e-12);
        assert_eq!(r.end_to_end.max(), 1_000_000);
        let kv = parse_line(&r.line());
        assert_eq!(kv["count"], "1");
        assert_eq!(kv["e2e_max_us"], "1000.0");
    }

    #[test]
    fn samples_outside_the_window_add_no_latency_or_error() {
        let mut r = StateReport {
            rate_hz: 1000.0,
            ..Default::default()
        };
        // A sample from long before the window (a new subscriber gets the service's history)
        // read now would otherwise show seconds of "latency".
        assert_eq!(
            account(
                &mut r,
                &sample(1_000, 0.7),
                5_000_000_000,
                true,
                (4_000_000_000, u64::MAX)
            ),
            None
        );
        assert_eq!(
            (r.count, r.end_to_end.count(), r.err_thesis_max),
            (0, 0, 0.0)
        );
        // In the window: counted; the step from the old sample is not a late step.
        let t = 4_500_000_000;
        account(
            &mut r,
            &sample(t, (t as f64 * 1e-9).sin()),
            t + 10_000,
            true,
            (4_000_000_000, u64::MAX),
        );
        assert_eq!((r.count, r.late_steps, r.end_to_end.max()), (1, 0, 10_000));
    }

    #[test]
    fn the_summary_merges_states() {
        let mut a = StateReport::default();
        let mut b = StateReport::default();
        account(&mut a, &sample(0, 0.0), 2_000, true, (0, u64::MAX));
        account(&mut b, &sample(0, 0.0), 9_000, true, (0, u64::MAX));
        let s = summarize([&a, &b].into_iter());
        assert_eq!((s.states, s.count, s.end_to_end.max()), (2, 2, 9_000));
        // Both read sin(2 µs) and sin(9 µs) against a value of 0: RMS of the two errors.
        let rms = (((2e-6f64).sin().powi(2) + (9e-6f64).sin().powi(2)) / 2.0).sqrt();
        assert!((s.err_thesis_rms - rms).abs() < 1e-15);
        let kv = parse_line(&s.line());
        assert_eq!(kv["summary"], "all");
        assert_eq!(kv["e2e_max_us"], "9.0");
    }
}
