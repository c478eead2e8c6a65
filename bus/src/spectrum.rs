//! Frequency content of a state's recent history (rustfft).

use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

/// Magnitude spectrum of the newest `window` samples of a state.
#[derive(Debug, Clone, PartialEq)]
pub struct Spectrum {
    /// Bin spacing in Hz (sample rate / window).
    pub resolution_hz: f64,
    /// Single-sided amplitude per bin, 0 ..= window/2, Hann-windowed and scaled so a pure tone of
    /// amplitude A on a bin centre reads A.
    pub magnitudes: Vec<f64>,
}

impl Spectrum {
    /// Frequency (Hz) of bin `k`.
    pub fn frequency(&self, k: usize) -> f64 {
        k as f64 * self.resolution_hz
    }

    /// Index of the largest bin above DC.
    pub fn peak_bin(&self) -> Option<usize> {
        self.magnitudes
            .iter()
            .enumerate()
            .skip(1)
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map(|(k, _)| k)
    }
}

/// Computes the spectrum of uniformly sampled `values` (oldest first) taken at `sample_rate_hz`.
pub fn spectrum(values: &[f64], sample_rate_hz: f64) -> Spectrum {
    let n = values.len();
    let mut buf: Vec<Complex<f64>> = values
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            let w = 0.5 - 0.5 * (2.0 * core::f64::consts::PI * i as f64 / n as f64).cos();
            Complex::new(v * w, 0.0)
        })
        .collect();
    FftPlanner::new().plan_fft_forward(n).process(&mut buf);
    // Hann coherent gain is 1/2; single-sided doubles all bins but DC and Nyquist.
    let scale = 2.0 / (n as f64 * 0.5);
    let magnitudes = buf[..=n / 2]
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let s = if k == 0 || 2 * k == n {
                scale / 2.0
            } else {
                scale
            };
            c.norm() * s
        })
        .collect();
    Spectrum {
        resolution_hz: sample_rate_hz / n as f64,
        magnitudes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pure_tone_peaks_at_its_bin_with_its_amplitude() {
        let fs = 100.0;
        let n = 256;
        let k = 20; // tone on bin 20 → 20 · 100/256 Hz
        let f = k as f64 * fs / n as f64;
        let v: Vec<f64> = (0..n)
            .map(|i| 0.7 * (2.0 * core::f64::consts::PI * f * i as f64 / fs).sin())
            .collect();
        let s = spectrum(&v, fs);
        assert_eq!(s.magnitudes.len(), n / 2 + 1);
        assert_eq!(s.peak_bin(), Some(k));
        assert!((s.frequency(k) - f).abs() < 1e-12);
        assert!((s.magnitudes[k] - 0.7).abs() < 1e-9);
        // Hann leakage stays in the neighbouring bins.
        assert!(s.magnitudes[k + 3] < 1e-9);
    }
}
