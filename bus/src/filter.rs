//! Filters a [`State`](crate::State) can run over its samples as they arrive.

use core::f64::consts::PI;

/// Filter specification.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Filter {
    /// First-order low-pass with cutoff `cutoff_hz`; uses the actual time between samples
    /// (exact discretisation of dy/dt = (x − y)/τ for a held input), so gaps are handled.
    LowPass {
        /// −3 dB frequency (Hz).
        cutoff_hz: f64,
    },
    /// Second-order low-pass biquad (RBJ cookbook, bilinear transform) designed for a nominal
    /// sample rate; assumes roughly uniform sampling.
    Biquad {
        /// −3 dB frequency (Hz) for Q = 1/√2.
        cutoff_hz: f64,
        /// Quality factor (1/√2 for Butterworth).
        q: f64,
        /// Nominal sample rate (Hz), usually the state's `rate_hz`.
        sample_rate_hz: f64,
    },
}

/// Running filter state.
#[derive(Debug, Clone)]
pub(crate) enum FilterState {
    LowPass {
        tau: f64,
        y: Option<f64>,
        t_ns: u64,
    },
    Biquad {
        b: [f64; 3],
        a: [f64; 2],
        x: [f64; 2],
        y: [f64; 2],
        primed: bool,
    },
}

impl FilterState {
    pub(crate) fn new(f: Filter) -> Self {
        match f {
            Filter::LowPass { cutoff_hz } => FilterState::LowPass {
                tau: 1.0 / (2.0 * PI * cutoff_hz.max(f64::MIN_POSITIVE)),
                y: None,
                t_ns: 0,
            },
            Filter::Biquad {
                cutoff_hz,
                q,
                sample_rate_hz,
            } => {
                let w0 = 2.0 * PI * cutoff_hz / sample_rate_hz;
                let (sn, cs) = w0.sin_cos();
                let alpha = sn / (2.0 * q);
                let a0 = 1.0 + alpha;
                let b1 = (1.0 - cs) / a0;
                FilterState::Biquad {
                    b: [b1 / 2.0, b1, b1 / 2.0],
                    a: [-2.0 * cs / a0, (1.0 - alpha) / a0],
                    x: [0.0; 2],
                    y: [0.0; 2],
                    primed: false,
                }
            }
        }
    }

    /// Feeds one sample; returns the new output.
    pub(crate) fn step(&mut self, t_ns: u64, x: f64) -> f64 {
        match self {
            FilterState::LowPass { tau, y, t_ns: last } => {
                let out = match *y {
                    None => x,
                    Some(prev) => {
                        let dt = t_ns.saturating_sub(*last) as f64 * 1e-9;
                        prev + (1.0 - (-dt / *tau).exp()) * (x - prev)
                    }
                };
                *y = Some(out);
                *last = t_ns;
                out
            }
            FilterState::Biquad {
                b,
                a,
                x: xs,
                y: ys,
                primed,
            } => {
                if !*primed {
                    // Start at steady state on the first input instead of ringing up from 0.
                    *xs = [x; 2];
                    *ys = [x; 2];
                    *primed = true;
                }
                let out = b[0] * x + b[1] * xs[0] + b[2] * xs[1] - a[0] * ys[0] - a[1] * ys[1];
                *xs = [x, xs[0]];
                *ys = [out, ys[0]];
                out
            }
        }
    }

    pub(crate) fn output(&self) -> Option<f64> {
        match self {
            FilterState::LowPass { y, .. } => *y,
            FilterState::Biquad { y, primed, .. } => primed.then_some(y[0]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Steady-state amplitude of the filter's response to a sine of `f` Hz sampled at `fs`.
    fn gain(filter: Filter, f: f64, fs: f64) -> f64 {
        let mut s = FilterState::new(filter);
        let dt_ns = (1e9 / fs) as u64;
        let n = (fs * 4.0) as u64;
        let mut peak: f64 = 0.0;
        for k in 0..n {
            let t = k as f64 / fs;
            let y = s.step(k * dt_ns, (2.0 * PI * f * t).sin());
            if k > n / 2 {
                peak = peak.max(y.abs());
            }
        }
        peak
    }

    #[test]
    fn low_pass_passes_dc_and_cuts_3db_at_cutoff() {
        let f = Filter::LowPass { cutoff_hz: 5.0 };
        // First-order response: |H(jω)| = 1/√(1+(f/fc)²). With fs = 1 kHz the discretisation
        // error is O(f/fs) ≈ 1 %, so allow 2 % around the analytic gain.
        assert!((gain(f, 0.5, 1000.0) - 1.0 / (1.01f64).sqrt()).abs() < 0.02);
        assert!((gain(f, 5.0, 1000.0) - 0.5f64.sqrt()).abs() < 0.02);
        assert!((gain(f, 50.0, 1000.0) - 1.0 / 101f64.sqrt()).abs() < 0.02);
    }

    #[test]
    fn biquad_butterworth_response() {
        let f = Filter::Biquad {
            cutoff_hz: 10.0,
            q: 0.5f64.sqrt(),
            sample_rate_hz: 1000.0,
        };
        // Butterworth |H| = 1/√(1+(f/fc)⁴); bilinear warping at f/fs ≤ 0.05 is < 1 %.
        assert!((gain(f, 1.0, 1000.0) - 1.0).abs() < 0.02);
        assert!((gain(f, 10.0, 1000.0) - 0.5f64.sqrt()).abs() < 0.02);
        assert!((gain(f, 50.0, 1000.0) - 1.0 / 626f64.sqrt()).abs() < 0.01);
    }

    #[test]
    fn step_settles_to_input() {
        let mut s = FilterState::new(Filter::LowPass { cutoff_hz: 10.0 });
        s.step(0, 0.0);
        let mut y = 0.0;
        for k in 1..2000u64 {
            y = s.step(k * 1_000_000, 1.0);
        }
        assert!((y - 1.0).abs() < 1e-9);
        assert_eq!(s.output(), Some(y));
    }
}
