//! [`State`]: the thesis' State as a client sees it, a subscription plus history and calculus.

use crate::abi::StateSample;
use crate::bus::Bus;
use crate::clock::monotonic_ns;
use crate::discovery::StateInfo;
use crate::error::{BusError, Result};
use crate::filter::{Filter, FilterState};
use crate::history::{History, Interpolation};
use crate::spectrum::{spectrum, Spectrum};
use crate::subscriber::StateSubscriber;

/// A subscribed state with a fixed-capacity history.
///
/// Call [`update`](Self::update) once per control cycle (or after a [`crate::TickWaiter`] wake) to
/// pull in new samples; every query then reads the history without touching the bus.
#[derive(Debug)]
pub struct State {
    sub: StateSubscriber,
    history: History,
    latest: Option<StateSample>,
    integral: f64,
    filter: Option<FilterState>,
}

impl State {
    /// Subscribes to `name` keeping the newest `history` samples.
    pub fn new(bus: &Bus, name: &str, history: usize) -> Result<Self> {
        let history = History::new(history);
        // Queue at least a tick's worth of samples between updates, at most the history.
        let sub = StateSubscriber::with_buffer(bus, name, history.capacity())?;
        Ok(Self {
            sub,
            history,
            latest: None,
            integral: 0.0,
            filter: None,
        })
    }

    /// Runs `filter` over every sample from now on; read it with [`filtered`](Self::filtered).
    pub fn with_filter(mut self, filter: Filter) -> Self {
        self.filter = Some(FilterState::new(filter));
        self
    }

    /// Drains the subscription into the history; returns the number of new samples.
    pub fn update(&mut self) -> Result<usize> {
        let mut n = 0;
        while let Some(s) = self.sub.receive()? {
            self.ingest(&s);
            n += 1;
        }
        Ok(n)
    }

    fn ingest(&mut self, s: &StateSample) {
        if let Some((t_prev, v_prev)) = self.history.newest() {
            if s.t_sample_ns > t_prev {
                self.integral += (s.t_sample_ns - t_prev) as f64 * 1e-9 * (s.value + v_prev) / 2.0;
            }
        }
        if self.history.push(s.t_sample_ns, s.value) {
            if let Some(f) = &mut self.filter {
                f.step(s.t_sample_ns, s.value);
            }
        }
        self.latest = Some(*s);
    }

    /// What discovery knows about the state (units, limits, rate, ...).
    pub fn info(&self) -> &StateInfo {
        self.sub.info()
    }

    /// The newest value, ω\[0\].
    pub fn value(&self) -> Result<f64> {
        self.latest
            .map(|s| s.value)
            .ok_or(BusError::NotEnoughSamples { needed: 1, have: 0 })
    }

    /// The newest raw sample (with status flags and times).
    pub fn sample(&self) -> Option<StateSample> {
        self.latest
    }

    /// ω\[t\] for t seconds relative to the newest sample (see [`History::at`]).
    pub fn at(&self, t: f64, interp: Interpolation) -> Result<f64> {
        self.history.at(t, interp)
    }

    /// dω/dt at the newest sample.
    pub fn derivative(&self) -> Result<f64> {
        self.history.derivative()
    }

    /// ∫ω dt since this subscriber's first sample (trapezoid, over every sample received).
    pub fn integral(&self) -> f64 {
        self.integral
    }

    /// Resets the running integral (e.g. on a controller mode switch).
    pub fn reset_integral(&mut self) {
        self.integral = 0.0;
    }

    /// The filter output, if a filter was set and a sample has arrived.
    pub fn filtered(&self) -> Option<f64> {
        self.filter.as_ref().and_then(FilterState::output)
    }

    /// Magnitude spectrum of the newest `window` samples, assuming the mean sample rate.
    pub fn spectrum(&self, window: usize) -> Result<Spectrum> {
        if window < 2 {
            return Err(BusError::NotEnoughSamples {
                needed: 2,
                have: window,
            });
        }
        let mut v = vec![0.0; window];
        self.history.newest_values(window, &mut v)?;
        let period = self.history.mean_period().unwrap_or(0.0);
        Ok(spectrum(&v, if period > 0.0 { 1.0 / period } else { 0.0 }))
    }

    /// Seconds since the newest sample was taken (`None` before the first sample).
    pub fn age(&self) -> Option<f64> {
        self.latest
            .map(|s| monotonic_ns().saturating_sub(s.t_sample_ns) as f64 * 1e-9)
    }

    /// Whether the newest sample is older than `periods` publish periods of the state (or the
    /// executor flagged it stale).
    pub fn is_stale(&self, periods: f64) -> bool {
        let Some(s) = self.latest else { return true };
        if s.status & crate::abi::status::STALE != 0 {
            return true;
        }
        let rate = self.info().meta.rate_hz;
        rate > 0.0 && self.age().unwrap_or(f64::INFINITY) > periods / rate
    }

    /// The history itself.
    pub fn history(&self) -> &History {
        &self.history
    }

    /// The underlying subscription (loss counters).
    pub fn subscriber(&self) -> &StateSubscriber {
        &self.sub
    }
}
