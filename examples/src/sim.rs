//! A simulated executor: owns the states of one subsystem, applies command frames the way the
//! real executor does (limits clamp and flag, NaN/inf and read-only refused), steps a [`Plant`]
//! at a fixed rate and publishes samples, tick events and
//! [`ExecutorStats`](conductor_bus::ExecutorStats).
//!
//! The examples run against it (`sim-motor`), and the CLI's integration tests use it as the
//! publisher they inspect, command, record and replay. It is a test stand-in, not the executor:
//! it runs on an ordinary thread with `std::thread::sleep` and makes no real-time promises, and
//! after a missed deadline it catches up (the executor re-anchors instead) so that it publishes
//! exactly `rate_hz` samples per second on average.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use conductor_bus::{
    monotonic_ns, status, Bus, BusError, CommandFrame, CommandReceiver, Domain, Histogram,
    StatePublisher, StateSpec, StatsPublisher,
};
use thiserror::Error;

/// Errors of the simulator.
#[derive(Debug, Error)]
pub enum SimError {
    /// The bus refused something (names, services).
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The spec is inconsistent.
    #[error("invalid simulator spec: {0}")]
    Spec(String),
    /// The simulator thread died.
    #[error("simulator thread: {0}")]
    Thread(String),
}

/// What to simulate.
#[derive(Debug, Clone)]
pub struct SimSpec {
    /// Subsystem name (`conductor/<subsystem>/...`).
    pub subsystem: String,
    /// Tick rate (Hz): every tick drains commands, steps the plant and publishes every state.
    pub rate_hz: f64,
    /// The states, `states[i].meta.index == i`.
    pub states: Vec<StateSpec>,
    /// Initial values, one per state.
    pub initial: Vec<f64>,
    /// Rate of the stats messages (Hz).
    pub stats_hz: f64,
}

/// The dynamics between ticks. `values` holds every state by index; commands have already been
/// written into the writable ones (clamped to their limits) when `step` is called.
pub trait Plant {
    /// Advances the plant by `dt` seconds.
    fn step(&mut self, dt: f64, values: &mut [f64]);
}

impl<F: FnMut(f64, &mut [f64])> Plant for F {
    fn step(&mut self, dt: f64, values: &mut [f64]) {
        self(dt, values)
    }
}

/// A plant that only holds what was commanded.
pub fn hold(_dt: f64, _values: &mut [f64]) {}

/// Totals of one run.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SimReport {
    /// Ticks executed.
    pub ticks: u64,
    /// Command frames applied.
    pub frames: u64,
    /// Setpoints refused (unknown index, read-only, not finite).
    pub rejected: u64,
    /// Setpoints clamped to the limits.
    pub clamped: u64,
}

/// Per-state command bookkeeping, mirrored into `StateSample::status`.
struct Commands {
    flags: Vec<u32>,
    report: SimReport,
}

impl Commands {
    fn apply(&mut self, spec: &SimSpec, values: &mut [f64], frame: &CommandFrame) {
        self.report.frames += 1;
        for sp in frame.setpoints() {
            let Some(st) = spec.states.get(sp.index as usize) else {
                self.report.rejected += 1;
                continue;
            };
            let i = sp.index as usize;
            if !st.meta.writable || !sp.value.is_finite() {
                self.report.rejected += 1;
                self.flags[i] = status::REJECTED;
                continue;
            }
            let (v, clamped) = st.meta.clamp(sp.value);
            values[i] = v;
            if clamped {
                self.report.clamped += 1;
                self.flags[i] = status::CLAMPED;
            } else {
                self.flags[i] = 0;
            }
        }
    }
}

/// Runs the simulator on this thread until `stop` is set. `ready` is called once every service
/// exists.
pub fn run(
    domain: &Domain,
    spec: &SimSpec,
    plant: &mut dyn Plant,
    stop: &AtomicBool,
    ready: impl FnOnce(),
) -> Result<SimReport, SimError> {
    if spec.initial.len() != spec.states.len() {
        return Err(SimError::Spec(format!(
            "{} states but {} initial values",
            spec.states.len(),
            spec.initial.len()
        )));
    }
    if !(spec.rate_hz > 0.0 && spec.rate_hz.is_finite()) {
        return Err(SimError::Spec(format!("rate {} Hz", spec.rate_hz)));
    }
    let bus = Bus::open(domain, &format!("executor/{}", spec.subsystem))?;
    let mut publisher = StatePublisher::create(&bus, &spec.subsystem, &spec.states)?;
    // The plant has no command watchdog, and says so on the bus.
    let mut commands = CommandReceiver::with_watchdog(&bus, &spec.subsystem, None)?;
    let mut stats = StatsPublisher::create(&bus, &spec.subsystem)?;
    ready();

    let mut values = spec.initial.clone();
    let mut cmd = Commands {
        flags: vec![0; values.len()],
        report: SimReport::default(),
    };
    let period = Duration::from_secs_f64(1.0 / spec.rate_hz);
    let dt = period.as_secs_f64();
    let stats_every = ((spec.rate_hz / spec.stats_hz.max(0.1)).round() as u64).max(1);
    let mut lateness = Histogram::new();
    let mut misses = 0u64;
    let mut interval = (Instant::now(), 0u64);
    let mut achieved = 0.0;
    let start = Instant::now();
    let mut tick = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let deadline = start + period.mul_f64(tick as f64);
        let now = Instant::now();
        if let Some(d) = deadline.checked_duration_since(now) {
            std::thread::sleep(d);
        }
        let late = Instant::now().saturating_duration_since(deadline);
        lateness.record(late.as_nanos() as u64);
        if late > period {
            // Counted, but unlike the executor not re-anchored: the late ticks run back to back,
            // so the average rate (and the sample count of a recording) stays exact.
            misses += 1;
        }
        commands.drain(|f| cmd.apply(spec, &mut values, f))?;
        plant.step(dt, &mut values);
        let t = monotonic_ns();
        for (i, v) in values.iter().enumerate() {
            publisher.publish(i, tick, t, *v, status::SIMULATED | cmd.flags[i])?;
        }
        publisher.notify_tick()?;
        tick += 1;
        if tick.is_multiple_of(stats_every) {
            let (t0, n0) = interval;
            let secs = t0.elapsed().as_secs_f64();
            if secs > 0.0 {
                achieved = (tick - n0) as f64 / secs;
            }
            interval = (Instant::now(), tick);
            let report = cmd.report;
            stats.publish(|s| {
                s.seq = tick / stats_every;
                s.t_ns = monotonic_ns();
                s.ticks = tick;
                s.misses = misses;
                s.base_rate_hz = spec.rate_hz;
                s.achieved_rate_hz = achieved;
                s.lateness_p50_ns = lateness.quantile(0.5);
                s.lateness_p99_ns = lateness.quantile(0.99);
                s.lateness_p999_ns = lateness.quantile(0.999);
                s.lateness_max_ns = lateness.max();
                s.frames_applied = report.frames;
                s.setpoints_rejected = report.rejected;
                s.setpoints_clamped = report.clamped;
                s.states = values.len() as u32;
                s.histogram = *lateness.counts();
            })?;
        }
    }
    cmd.report.ticks = tick;
    Ok(cmd.report)
}

/// A simulator running on its own thread; stopped (and joined) on drop.
#[derive(Debug)]
pub struct SimHandle {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<SimReport, SimError>>>,
}

impl SimHandle {
    /// Stops the simulator and returns its totals.
    pub fn stop(mut self) -> Result<SimReport, SimError> {
        self.join()
    }

    fn join(&mut self) -> Result<SimReport, SimError> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take() {
            Some(t) => t.join().map_err(|_| SimError::Thread("panicked".into()))?,
            None => Ok(SimReport::default()),
        }
    }
}

impl Drop for SimHandle {
    fn drop(&mut self) {
        let _ = self.join();
    }
}

/// Starts the simulator on a new thread and returns once its services exist.
pub fn spawn<P: Plant + Send + 'static>(
    domain: &Domain,
    spec: SimSpec,
    mut plant: P,
) -> Result<SimHandle, SimError> {
    let stop = Arc::new(AtomicBool::new(false));
    let (tx, rx) = mpsc::channel();
    let domain = domain.clone();
    let flag = stop.clone();
    let thread = std::thread::Builder::new()
        .name(format!("sim/{}", spec.subsystem))
        .spawn(move || {
            let ready = tx.clone();
            let r = run(&domain, &spec, &mut plant, &flag, move || {
                let _ = ready.send(Ok(()));
            });
            if let Err(e) = &r {
                let _ = tx.send(Err(e.to_string()));
            }
            r
        })
        .map_err(|e| SimError::Thread(e.to_string()))?;
    let mut handle = SimHandle {
        stop,
        thread: Some(thread),
    };
    match rx.recv() {
        Ok(Ok(())) => Ok(handle),
        Ok(Err(_)) | Err(_) => Err(match handle.join() {
            Err(e) => e,
            Ok(_) => SimError::Thread("stopped before it was ready".into()),
        }),
    }
}
