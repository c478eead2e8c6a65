//! Fixed-size log-linear latency histogram, allocation-free, for RT loops and the stats ABI.
//!
//! Values below 16 ns get one bucket each; above, every power-of-two octave is split into 8
//! linear sub-buckets, so a bucket's width is at most 1/8 of its lower bound: a percentile read
//! from the histogram (the bucket's upper bound) overstates the true value by at most 12.5 %.
//! Values of 2^36 ns (≈ 69 s) and above saturate into the last bucket.

/// Number of buckets.
pub const BUCKETS: usize = 280;

/// Bucket index of a value in nanoseconds.
pub const fn bucket_of(v: u64) -> usize {
    if v < 16 {
        return v as usize;
    }
    let msb = 63 - v.leading_zeros() as usize;
    let shift = msb - 3;
    let mantissa = (v >> shift) as usize; // in 8..16
    let idx = (shift + 1) * 8 + (mantissa - 8);
    if idx >= BUCKETS {
        BUCKETS - 1
    } else {
        idx
    }
}

/// Inclusive `(low, high)` range of values that fall into bucket `idx`.
pub const fn bucket_range(idx: usize) -> (u64, u64) {
    if idx < 16 {
        return (idx as u64, idx as u64);
    }
    let shift = idx / 8 - 1;
    let m = (idx % 8 + 8) as u64;
    let low = m << shift;
    if idx == BUCKETS - 1 {
        (low, u64::MAX)
    } else {
        (low, ((m + 1) << shift) - 1)
    }
}

/// A latency histogram over [`BUCKETS`] log-linear buckets plus an exact maximum.
#[derive(Debug, Clone, PartialEq)]
pub struct Histogram {
    counts: [u64; BUCKETS],
    total: u64,
    max: u64,
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

impl Histogram {
    /// An empty histogram.
    pub const fn new() -> Self {
        Self {
            counts: [0; BUCKETS],
            total: 0,
            max: 0,
        }
    }

    /// Rebuilds a histogram from published bucket counts (e.g. [`crate::ExecutorStats::histogram`]).
    pub fn from_counts(counts: &[u64; BUCKETS], max: u64) -> Self {
        Self {
            counts: *counts,
            total: counts.iter().sum(),
            max,
        }
    }

    /// Records one value (ns). Constant time, no allocation.
    #[inline]
    pub fn record(&mut self, v: u64) {
        self.counts[bucket_of(v)] += 1;
        self.total += 1;
        if v > self.max {
            self.max = v;
        }
    }

    /// Number of recorded values.
    pub fn count(&self) -> u64 {
        self.total
    }

    /// Largest recorded value (exact).
    pub fn max(&self) -> u64 {
        self.max
    }

    /// Bucket counts.
    pub fn counts(&self) -> &[u64; BUCKETS] {
        &self.counts
    }

    /// The `q`-quantile (0 ≤ q ≤ 1) as the upper bound of the bucket holding the nearest-rank
    /// value, capped at the exact maximum. Returns 0 for an empty histogram.
    pub fn quantile(&self, q: f64) -> u64 {
        if self.total == 0 {
            return 0;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.total as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (idx, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                return bucket_range(idx).1.min(self.max);
            }
        }
        self.max
    }

    /// Adds every count of `other` into `self`.
    pub fn merge(&mut self, other: &Histogram) {
        for (a, b) in self.counts.iter_mut().zip(other.counts.iter()) {
            *a += b;
        }
        self.total += other.total;
        self.max = self.max.max(other.max);
    }

    /// Forgets everything.
    pub fn reset(&mut self) {
        *self = Self::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_tile_the_line_without_gaps() {
        for idx in 1..BUCKETS {
            let (_, prev_hi) = bucket_range(idx - 1);
            let (lo, hi) = bucket_range(idx);
            assert_eq!(lo, prev_hi + 1, "bucket {idx}");
            assert!(hi >= lo);
            assert_eq!(bucket_of(lo), idx);
            if idx < BUCKETS - 1 {
                assert_eq!(bucket_of(hi), idx);
                // Width bound that the module doc promises.
                if lo >= 16 {
                    assert!((hi - lo + 1) * 8 <= lo, "bucket {idx} too wide");
                }
            }
        }
        assert_eq!(bucket_of(u64::MAX), BUCKETS - 1);
    }

    #[test]
    fn quantiles_within_a_bucket_of_exact() {
        let mut h = Histogram::new();
        // 1..=100_000 ns uniformly: exact p50 = 50_000, p99 = 99_000.
        for v in 1..=100_000u64 {
            h.record(v);
        }
        let p50 = h.quantile(0.5);
        let p99 = h.quantile(0.99);
        assert!((50_000..=56_250).contains(&p50), "{p50}");
        assert!((99_000..=100_000).contains(&p99), "{p99}");
        assert_eq!(h.quantile(1.0), 100_000);
        assert_eq!(h.max(), 100_000);
        assert_eq!(h.count(), 100_000);
    }

    #[test]
    fn merge_and_roundtrip_through_counts() {
        let mut a = Histogram::new();
        let mut b = Histogram::new();
        a.record(10);
        b.record(1_000_000);
        a.merge(&b);
        let c = Histogram::from_counts(a.counts(), a.max());
        assert_eq!(c, a);
        assert_eq!(c.quantile(0.5), 10);
        assert_eq!(c.quantile(1.0), 1_000_000);
        assert_eq!(Histogram::new().quantile(0.5), 0);
    }
}
