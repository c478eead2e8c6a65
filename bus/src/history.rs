//! A fixed-capacity ring of timestamped samples and the calculus the thesis asks of a State:
//! values between samples, derivative and integral.
//!
//! Times are absolute `CLOCK_MONOTONIC` nanoseconds on input; queries use seconds relative to
//! the newest sample, as the thesis writes ω[t] for t in [−hist, 0]. Sampling need not be
//! uniform: every formula here works on the actual sample times.

use crate::error::{BusError, Result};

/// How [`History::at`] reconstructs a value between samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Interpolation {
    /// Straight line between the two neighbours. Error ≤ h²/8 · max|f''|.
    #[default]
    Linear,
    /// Cubic through the four nearest samples (two each side where they exist).
    /// Error ≤ (3/128) h⁴ · max|f''''| between interior samples of spacing h, and ≤ h⁴/24 ·
    /// max|f''''| in the newest and oldest intervals, where the stencil is one-sided.
    Cubic,
}

/// Fixed-capacity history: pushing never allocates once created.
#[derive(Debug, Clone)]
pub struct History {
    t_ns: Vec<u64>,
    v: Vec<f64>,
    head: usize,
    len: usize,
    max_extrapolation: f64,
}

impl History {
    /// A history holding the newest `capacity` samples (at least 4, so cubic interpolation and
    /// the three-point derivative always have the points they need once filled).
    pub fn new(capacity: usize) -> Self {
        let cap = capacity.max(4);
        Self {
            t_ns: vec![0; cap],
            v: vec![0.0; cap],
            head: 0,
            len: 0,
            max_extrapolation: 2.0,
        }
    }

    /// Allows [`at`](Self::at) to extrapolate up to `periods` mean sample periods past the newest
    /// sample (default 2). Linear extrapolation error grows as t(t+h)/2 · max|f''|, so keep it small.
    pub fn set_max_extrapolation(&mut self, periods: f64) {
        self.max_extrapolation = periods.max(0.0);
    }

    /// Capacity in samples.
    pub fn capacity(&self) -> usize {
        self.v.len()
    }

    /// Samples held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no sample is held.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Forgets every sample.
    pub fn clear(&mut self) {
        self.len = 0;
        self.head = 0;
    }

    /// Appends a sample. A sample not newer than the newest one is ignored (returns `false`):
    /// time must move forward for the calculus to mean anything.
    #[inline]
    pub fn push(&mut self, t_ns: u64, v: f64) -> bool {
        if let Some((t_last, _)) = self.newest() {
            if t_ns <= t_last {
                return false;
            }
        }
        let cap = self.v.len();
        self.head = (self.head + 1) % cap;
        self.t_ns[self.head] = t_ns;
        self.v[self.head] = v;
        self.len = (self.len + 1).min(cap);
        true
    }

    /// The `i`-th newest sample (0 = newest) as (t_ns, value).
    #[inline]
    pub fn get(&self, i: usize) -> Option<(u64, f64)> {
        if i >= self.len {
            return None;
        }
        let cap = self.v.len();
        let k = (self.head + cap - i) % cap;
        Some((self.t_ns[k], self.v[k]))
    }

    /// The newest sample.
    pub fn newest(&self) -> Option<(u64, f64)> {
        self.get(0)
    }

    /// Time of sample `i` relative to the newest, in seconds (≤ 0).
    fn rel(&self, i: usize, t0: u64) -> f64 {
        let (t, _) = self.get(i).expect("index checked by caller");
        -((t0 - t) as f64) * 1e-9
    }

    /// Span of the history in seconds (newest − oldest).
    pub fn span(&self) -> f64 {
        match (self.newest(), self.get(self.len.saturating_sub(1))) {
            (Some((t0, _)), Some((t1, _))) => (t0 - t1) as f64 * 1e-9,
            _ => 0.0,
        }
    }

    /// Mean sample period in seconds.
    pub fn mean_period(&self) -> Option<f64> {
        (self.len >= 2).then(|| self.span() / (self.len - 1) as f64)
    }

    /// The value at `t` seconds relative to the newest sample: t = 0 is the newest value,
    /// t in [−span, 0] is interpolated, small t > 0 is extrapolated linearly (up to the
    /// configured number of sample periods).
    pub fn at(&self, t: f64, interp: Interpolation) -> Result<f64> {
        let (t0, v0) = self
            .newest()
            .ok_or(BusError::NotEnoughSamples { needed: 1, have: 0 })?;
        if t == 0.0 {
            return Ok(v0);
        }
        let oldest = -self.span();
        let limit = self.mean_period().unwrap_or(0.0) * self.max_extrapolation;
        if !t.is_finite() || t < oldest || t > limit {
            return Err(BusError::OutOfHistory {
                t,
                oldest,
                newest: limit,
            });
        }
        if self.len < 2 {
            return Err(BusError::NotEnoughSamples {
                needed: 2,
                have: self.len,
            });
        }
        if t > 0.0 {
            let (t1, v1) = (self.rel(1, t0), self.get(1).unwrap().1);
            return Ok(v0 + (v0 - v1) / (0.0 - t1) * t);
        }
        // Find i with rel(i+1) <= t <= rel(i): samples are newest-first, so walk back.
        // Binary search over the ring by relative time.
        let (mut lo, mut hi) = (0usize, self.len - 1); // rel(lo) >= t >= rel(hi)
        while hi - lo > 1 {
            let mid = (lo + hi) / 2;
            if self.rel(mid, t0) >= t {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        match interp {
            Interpolation::Linear => {
                let (ta, va) = (self.rel(lo, t0), self.get(lo).unwrap().1);
                let (tb, vb) = (self.rel(hi, t0), self.get(hi).unwrap().1);
                Ok(va + (vb - va) * (t - ta) / (tb - ta))
            }
            Interpolation::Cubic => {
                if self.len < 4 {
                    return Err(BusError::NotEnoughSamples {
                        needed: 4,
                        have: self.len,
                    });
                }
                // Four points centred on the bracket [hi, lo], shifted inwards at the ends.
                let first = lo.saturating_sub(1).min(self.len - 4);
                let mut ts = [0.0; 4];
                let mut vs = [0.0; 4];
                for k in 0..4 {
                    ts[k] = self.rel(first + k, t0);
                    vs[k] = self.get(first + k).unwrap().1;
                }
                Ok(lagrange4(&ts, &vs, t))
            }
        }
    }

    /// Derivative at the newest sample: the slope of the parabola through the three newest
    /// samples (second-order one-sided difference). Error ≤ h²/3 · max|f'''| for spacing h.
    pub fn derivative(&self) -> Result<f64> {
        if self.len < 3 {
            return Err(BusError::NotEnoughSamples {
                needed: 3,
                have: self.len,
            });
        }
        let (t0n, f0) = self.get(0).unwrap();
        let f1 = self.get(1).unwrap().1;
        let f2 = self.get(2).unwrap().1;
        let (t1, t2) = (self.rel(1, t0n), self.rel(2, t0n)); // t0 = 0
                                                             // d/dt of the Lagrange parabola at t = 0.
        let d0 = (-t1 - t2) / (t1 * t2); // f0 weight: (2·0 − t1 − t2)/((0−t1)(0−t2))
        let d1 = (0.0 - t2) / ((t1 - 0.0) * (t1 - t2));
        let d2 = (0.0 - t1) / ((t2 - 0.0) * (t2 - t1));
        Ok(f0 * d0 + f1 * d1 + f2 * d2)
    }

    /// Trapezoid integral over the last `window` seconds of history (the whole history if it is
    /// shorter). Error ≤ (T h²/12) · max|f''| over a span T with spacing h.
    pub fn integral_over(&self, window: f64) -> Result<f64> {
        if self.len < 2 {
            return Err(BusError::NotEnoughSamples {
                needed: 2,
                have: self.len,
            });
        }
        let t0 = self.newest().unwrap().0;
        let mut acc = 0.0;
        for i in 0..self.len - 1 {
            let (ta, tb) = (self.rel(i, t0), self.rel(i + 1, t0));
            if -tb > window {
                // Partial last trapezoid up to the window edge.
                if -ta < window {
                    let edge = self.at(-window, Interpolation::Linear)?;
                    let va = self.get(i).unwrap().1;
                    acc += (ta + window) * (va + edge) / 2.0;
                }
                break;
            }
            let (va, vb) = (self.get(i).unwrap().1, self.get(i + 1).unwrap().1);
            acc += (ta - tb) * (va + vb) / 2.0;
        }
        Ok(acc)
    }

    /// Copies the newest `n` values, oldest first, into `out` (which must hold `n`). For FFTs
    /// and vector gathers.
    pub fn newest_values(&self, n: usize, out: &mut [f64]) -> Result<()> {
        if self.len < n {
            return Err(BusError::NotEnoughSamples {
                needed: n,
                have: self.len,
            });
        }
        for (k, slot) in out[..n].iter_mut().enumerate() {
            *slot = self.get(n - 1 - k).unwrap().1;
        }
        Ok(())
    }
}

/// Cubic Lagrange interpolation through four points.
fn lagrange4(ts: &[f64; 4], vs: &[f64; 4], t: f64) -> f64 {
    let mut acc = 0.0;
    for j in 0..4 {
        let mut w = 1.0;
        for m in 0..4 {
            if m != j {
                w *= (t - ts[m]) / (ts[j] - ts[m]);
            }
        }
        acc += w * vs[j];
    }
    acc
}

#[cfg(test)]
mod tests {
    use super::*;

    const H: f64 = 0.01; // 100 Hz, the thesis' test rate
    const NS: u64 = 10_000_000;

    /// sin(t) sampled at 100 Hz for `secs` seconds, t starting at 0.
    fn sampled_sin(secs: f64, cap: usize) -> History {
        let mut h = History::new(cap);
        let n = (secs / H).round() as u64;
        for k in 0..=n {
            assert!(h.push(k * NS, (k as f64 * H).sin()));
        }
        h
    }

    #[test]
    fn interpolation_between_samples_meets_method_bounds() {
        let h = sampled_sin(2.0, 256); // newest sample at t = 2.0 s
        let t_end = 2.0;
        // Linear: |f''| ≤ 1 → error ≤ h²/8 = 1.25e-5.
        // Cubic: |f''''| ≤ 1 → error ≤ 3/128 h⁴ ≈ 2.3e-10 (plus rounding, ~1e-15).
        let linear_bound = H * H / 8.0;
        let cubic_bound = 3.0 / 128.0 * H.powi(4) + 1e-13;
        let mut worst_lin: f64 = 0.0;
        for k in 1..190 {
            let t = -(k as f64) * H - 0.37 * H; // between samples, not at a node
            if t < -h.span() {
                break;
            }
            let exact = (t_end + t).sin();
            let lin = h.at(t, Interpolation::Linear).unwrap();
            let cub = h.at(t, Interpolation::Cubic).unwrap();
            assert!((lin - exact).abs() <= linear_bound, "linear at {t}");
            assert!(
                (cub - exact).abs() <= cubic_bound,
                "cubic at {t}: {}",
                cub - exact
            );
            worst_lin = worst_lin.max((lin - exact).abs());
        }
        // The bound is attained to within a factor of a few, i.e. it is the right order.
        assert!(worst_lin > linear_bound / 4.0);
        // The thesis' example: halfway between two samples is their average.
        let mid = h.at(-1.5 * H, Interpolation::Linear).unwrap();
        let avg = (h.get(1).unwrap().1 + h.get(2).unwrap().1) / 2.0;
        assert!((mid - avg).abs() < 1e-15);
    }

    #[test]
    fn at_nodes_is_exact_and_range_is_enforced() {
        let h = sampled_sin(1.0, 16);
        assert_eq!(h.at(0.0, Interpolation::Cubic).unwrap(), 1.0f64.sin());
        let v = h.at(-3.0 * H, Interpolation::Linear).unwrap();
        assert!((v - (1.0 - 3.0 * H).sin()).abs() < 1e-12);
        assert!(matches!(
            h.at(-0.5, Interpolation::Linear),
            Err(BusError::OutOfHistory { .. })
        ));
        assert!(h.at(3.0 * H, Interpolation::Linear).is_err());
        assert!(h.at(f64::NAN, Interpolation::Linear).is_err());
    }

    #[test]
    fn bounded_extrapolation() {
        let h = sampled_sin(1.0, 16);
        // Linear extrapolation error for t ≤ 2h: |f''|/2 · t (t + h) ≤ 3 h² = 3e-4.
        let t = 1.5 * H;
        let v = h.at(t, Interpolation::Linear).unwrap();
        assert!((v - (1.0 + t).sin()).abs() <= 0.5 * t * (t + H));
    }

    #[test]
    fn derivative_of_sin_is_cos() {
        let h = sampled_sin(3.0, 64);
        // Three-point one-sided difference: error ≤ h²/3 · max|f'''| = 3.3e-5.
        let d = h.derivative().unwrap();
        assert!(
            (d - 3.0f64.cos()).abs() <= H * H / 3.0,
            "{}",
            d - 3.0f64.cos()
        );
        assert!(History::new(4).derivative().is_err());
    }

    #[test]
    fn integral_of_sin_is_one_minus_cos() {
        let secs = 5.0;
        let h = sampled_sin(secs, 1024);
        let i = h.integral_over(10.0).unwrap(); // whole history: 0 .. 5 s
        let exact = 1.0 - secs.cos();
        // Trapezoid: error ≤ T h²/12 · max|f''| = 5 · 1e-4 / 12 ≈ 4.2e-5.
        assert!((i - exact).abs() <= secs * H * H / 12.0, "{}", i - exact);
        // A window inside the history: ∫_{4}^{5} sin = cos 4 − cos 5.
        let w = h.integral_over(1.0).unwrap();
        assert!((w - (4.0f64.cos() - 5.0f64.cos())).abs() <= 1.0 * H * H / 12.0 + 1e-12);
    }

    #[test]
    fn ring_keeps_newest_and_rejects_time_travel() {
        let mut h = History::new(4);
        for k in 0..10u64 {
            h.push(k * 10, k as f64);
        }
        assert_eq!(h.len(), 4);
        assert_eq!(h.get(0), Some((90, 9.0)));
        assert_eq!(h.get(3), Some((60, 6.0)));
        assert_eq!(h.get(4), None);
        assert!(!h.push(90, 1.0));
        assert!(!h.push(50, 1.0));
        let mut out = [0.0; 3];
        h.newest_values(3, &mut out).unwrap();
        assert_eq!(out, [7.0, 8.0, 9.0]);
    }
}
