//! Order statistics over raw latency samples.

use core::fmt;

/// p50/p99/p99.9/max (and min, mean) of a set of nanosecond samples.
///
/// Computed by sorting the full sample set: nearest-rank percentiles, no interpolation and no
/// outlier rejection, so the reported max is the largest value actually observed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Percentiles {
    /// Number of samples summarised.
    pub count: usize,
    /// Smallest sample.
    pub min: u64,
    /// Median (nearest rank).
    pub p50: u64,
    /// 99th percentile (nearest rank).
    pub p99: u64,
    /// 99.9th percentile (nearest rank).
    pub p999: u64,
    /// Largest sample.
    pub max: u64,
    /// Arithmetic mean.
    pub mean: f64,
}

impl Percentiles {
    /// Summarises `samples` (sorted in place). Returns `None` for an empty slice.
    pub fn from_samples(samples: &mut [u64]) -> Option<Self> {
        if samples.is_empty() {
            return None;
        }
        samples.sort_unstable();
        let rank = |q: f64| {
            // Nearest-rank: the smallest value with at least q of the samples at or below it.
            let r = (q * samples.len() as f64).ceil() as usize;
            samples[r.clamp(1, samples.len()) - 1]
        };
        let sum: u128 = samples.iter().map(|&s| s as u128).sum();
        Some(Self {
            count: samples.len(),
            min: samples[0],
            p50: rank(0.50),
            p99: rank(0.99),
            p999: rank(0.999),
            max: samples[samples.len() - 1],
            mean: sum as f64 / samples.len() as f64,
        })
    }

    /// Ratio of each percentile to a floor measured in the same run (`self / floor`).
    pub fn ratio_to(&self, floor: &Percentiles) -> Ratios {
        let r = |a: u64, b: u64| {
            if b == 0 {
                f64::NAN
            } else {
                a as f64 / b as f64
            }
        };
        Ratios {
            p50: r(self.p50, floor.p50),
            p99: r(self.p99, floor.p99),
            p999: r(self.p999, floor.p999),
            max: r(self.max, floor.max),
        }
    }
}

/// Per-percentile ratios against a floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ratios {
    /// p50 / floor p50.
    pub p50: f64,
    /// p99 / floor p99.
    pub p99: f64,
    /// p99.9 / floor p99.9.
    pub p999: f64,
    /// max / floor max.
    pub max: f64,
}

/// Formats nanoseconds with a unit that keeps three significant figures readable.
pub fn fmt_ns(ns: u64) -> String {
    match ns {
        0..=9_999 => format!("{ns} ns"),
        10_000..=9_999_999 => format!("{:.1} µs", ns as f64 / 1e3),
        _ => format!("{:.2} ms", ns as f64 / 1e6),
    }
}

impl fmt::Display for Percentiles {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "n={} p50={} p99={} p99.9={} max={}",
            self.count,
            fmt_ns(self.p50),
            fmt_ns(self.p99),
            fmt_ns(self.p999),
            fmt_ns(self.max)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_on_known_set() {
        let mut v: Vec<u64> = (1..=1000).rev().collect();
        let p = Percentiles::from_samples(&mut v).unwrap();
        assert_eq!(
            (p.min, p.p50, p.p99, p.p999, p.max),
            (1, 500, 990, 999, 1000)
        );
        assert!((p.mean - 500.5).abs() < 1e-9);
    }

    #[test]
    fn single_sample_and_empty() {
        assert!(Percentiles::from_samples(&mut []).is_none());
        let p = Percentiles::from_samples(&mut [42]).unwrap();
        assert_eq!((p.p50, p.p999, p.max), (42, 42, 42));
    }

    #[test]
    fn ratios_against_floor() {
        let a = Percentiles::from_samples(&mut [10, 20, 30]).unwrap();
        let b = Percentiles::from_samples(&mut [5, 10, 15]).unwrap();
        let r = a.ratio_to(&b);
        assert_eq!((r.p50, r.max), (2.0, 2.0));
    }
}
