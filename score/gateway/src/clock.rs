//! Board time to host time: the board stamps samples with its microsecond clock (from boot);
//! the bus wants `CLOCK_MONOTONIC` nanoseconds. The gateway pings the board (`Time`) and fits
//!
//! ```text
//! host_ns ≈ offset + slope · board_us
//! ```
//!
//! Each ping gives one point: the board's reading `b`, taken somewhere between the host's send
//! time `h0` and receive time `h1`, so the host time of `b` is `(h0 + h1) / 2 ± (h1 − h0) / 2`.
//! Points with a short round trip are the precise ones. The fit takes two of them far apart:
//! the shortest-round-trip ping of the first few after connecting (the early anchor), and the
//! shortest-round-trip ping of a window of recent ones (the recent anchor). The line through
//! them gives the slope (the drift of the board's crystal against the host: a few ppm for a
//! real board), the recent anchor the offset. If the board clock is linear in host time, the
//! error of a mapped time is at most half the recent anchor's round trip, plus the slope error
//! (the two anchors' half round trips over the distance between them) times the distance from
//! the recent anchor ([`ClockMap::error_bound_ns`]); the slope error shrinks as the connection
//! ages. USB full-speed round trips are 1–2 ms (1 ms frames), so samples are placed within about
//! a millisecond. In the emulator, board time is emulated time, which runs at a varying multiple
//! of host time: the fit follows it on average only.

use std::collections::VecDeque;

/// Recent pings kept.
const WINDOW: usize = 16;
/// Pings after a reset among which the early anchor is chosen.
const EARLY: usize = 8;
/// Shortest host span between the anchors for estimating the slope (before: nominal).
const MIN_SPAN_NS: f64 = 1e9;
/// Slope error assumed while the slope is nominal: crystals are within ±100 ppm; 10⁻³ is safe.
const NOMINAL_SLOPE_ERROR: f64 = 1e-3;

#[derive(Debug, Clone, Copy, PartialEq)]
struct Ping {
    board_us: u64,
    host_mid_ns: f64,
    rtt_ns: f64,
}

/// Offset and drift between the board's clock and the host's.
#[derive(Debug, Clone, Default)]
pub struct ClockMap {
    pings: VecDeque<Ping>,
    seen: usize,
    early: Option<Ping>,
    /// host ns per board µs.
    slope: f64,
    /// Relative error of `slope`.
    slope_error: f64,
    offset: f64,
    anchor: Option<Ping>,
}

impl ClockMap {
    /// No pings yet: the slope is nominal (1000 ns per µs).
    pub fn new() -> Self {
        Self {
            slope: 1000.0,
            slope_error: NOMINAL_SLOPE_ERROR,
            ..Default::default()
        }
    }

    /// Forgets everything (a board was replugged: its clock restarted).
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Records a ping: sent at host `h0_ns`, answered with `board_us`, received at `h1_ns`.
    pub fn add(&mut self, h0_ns: u64, board_us: u64, h1_ns: u64) {
        let p = Ping {
            board_us,
            host_mid_ns: (h0_ns as f64 + h1_ns as f64) / 2.0,
            rtt_ns: h1_ns.saturating_sub(h0_ns) as f64,
        };
        self.seen += 1;
        if self.seen <= EARLY && self.early.is_none_or(|e| p.rtt_ns < e.rtt_ns) {
            self.early = Some(p);
        }
        if self.pings.len() == WINDOW {
            self.pings.pop_front();
        }
        self.pings.push_back(p);
        self.refit();
    }

    fn refit(&mut self) {
        let Some(recent) = self
            .pings
            .iter()
            .copied()
            .min_by(|a, b| a.rtt_ns.total_cmp(&b.rtt_ns))
        else {
            return;
        };
        if let Some(e) = self.early {
            let dh = recent.host_mid_ns - e.host_mid_ns;
            let db = recent.board_us as f64 - e.board_us as f64;
            if dh >= MIN_SPAN_NS && db > 0.0 {
                self.slope = dh / db;
                self.slope_error = (e.rtt_ns + recent.rtt_ns) / 2.0 / dh;
            }
        }
        self.offset = recent.host_mid_ns - self.slope * recent.board_us as f64;
        self.anchor = Some(recent);
    }

    /// True once at least one ping was recorded.
    pub fn is_synced(&self) -> bool {
        self.anchor.is_some()
    }

    /// Host `CLOCK_MONOTONIC` ns of board time `board_us`.
    pub fn to_host_ns(&self, board_us: u64) -> u64 {
        (self.offset + self.slope * board_us as f64).max(0.0) as u64
    }

    /// Host ns per board µs (1000 when the clocks agree).
    pub fn slope(&self) -> f64 {
        self.slope
    }

    /// Relative error bound of [`ClockMap::slope`] (10⁻³ while it is still nominal).
    pub fn slope_error(&self) -> f64 {
        self.slope_error
    }

    /// Bound on the error of [`ClockMap::to_host_ns`] at `board_us` for a board clock linear
    /// in host time: half the recent anchor's round trip plus the slope error times the
    /// distance from it (not counting the board's 1 µs resolution).
    pub fn error_bound_ns(&self, board_us: u64) -> Option<f64> {
        let a = self.anchor?;
        let dist = (board_us as f64 - a.board_us as f64).abs() * self.slope;
        Some(a.rtt_ns / 2.0 + self.slope_error * dist)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A board clock running 50 ppm fast with an unknown offset; pings with round trips of
    /// 1-3 ms where the board reads at a random point inside the round trip. The mapped time of
    /// a later board instant must fall within the stated bound of the truth.
    #[test]
    fn recovers_offset_and_drift_within_the_bound() {
        let true_slope = 1000.0 / 1.000_050; // host ns per board us
        let true_offset = 7.0e12;
        let board_at = |host_ns: f64| ((host_ns - true_offset) / true_slope) as u64;
        let mut m = ClockMap::new();
        let mut rng = 12345u64;
        let mut next = || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        for k in 0..40 {
            let h0 = true_offset + 1e12 + k as f64 * 250e6;
            let rtt = 1e6 + 2e6 * next();
            let at = h0 + rtt * next();
            m.add(h0 as u64, board_at(at), (h0 + rtt) as u64);
        }
        let later_host = true_offset + 1e12 + 40.0 * 250e6 + 3e9;
        let b = board_at(later_host);
        let err = (m.to_host_ns(b) as f64 - later_host).abs();
        // + the board's 1 us tick (its readings are truncated to whole microseconds).
        let bound = m.error_bound_ns(b).unwrap() + 2.0 * true_slope;
        assert!(err <= bound, "error {err} ns > bound {bound} ns");
        // The slope is within its own stated error, and with the shortest of 1-3 ms round trips
        // over a 10 s baseline the bound 3 s past the last ping stays within 3 ms.
        let rel = (m.slope() - true_slope).abs() / true_slope;
        assert!(rel <= m.slope_error(), "slope {} ({rel:e})", m.slope());
        assert!(bound < 3e6, "bound {bound}");
    }

    #[test]
    fn nominal_before_enough_pings() {
        let mut m = ClockMap::new();
        assert!(!m.is_synced());
        m.add(1_000_000, 500, 1_002_000);
        assert_eq!(m.to_host_ns(500), 1_001_000);
        assert_eq!(m.to_host_ns(1500), 1_001_000 + 1_000_000);
    }
}
