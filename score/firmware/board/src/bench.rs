//! The thesis' Fig. 5.20 PID (10 lines), updated at 1 kHz in a scratch engine and timed update
//! by update against a hardware cycle counter: the figure the thesis compares at 20 kHz.
//!
//! One update is what the 1 kHz scheduler does per sample: the playback source (`infile`),
//! the derivative and the integral (`tick`), then reading the lazy `PID`, which evaluates
//! Pterm, Iterm, Dterm and their sum. The playback signal is a 256-sample table (0.015 sin
//! 0.025k, the host benchmark's signal) computed before timing starts, played by score-core's
//! [`PlaybackHal`]; the script is [`FIG_5_20_PID`], the one the host benchmark runs.

use score_core::hal::PlaybackHal;
use score_core::{Engine, Real, FIG_5_20_PID};

/// Samples in the playback signal (2 KiB of f64 on the stack while the bench runs; the engine
/// loops it).
const SIGNAL: usize = 256;

/// Cycle counts of the timed updates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BenchStats {
    /// Updates timed.
    pub updates: u32,
    /// Fewest cycles of one update.
    pub min: u32,
    /// Most cycles of one update.
    pub max: u32,
    /// Sum over all updates.
    pub total: u64,
    /// The PID output after the last update, as f64 bits (to show the work was done).
    pub last_pid_bits: u64,
}

impl BenchStats {
    /// Mean cycles per update.
    pub fn mean(&self) -> f64 {
        self.total as f64 / self.updates.max(1) as f64
    }
}

/// Runs `updates` updates of Fig. 5.20 with number type `N`, timing each with `counter`: a
/// free-running **down**-counter of `mask + 1` states (SysTick: 24 bits) that must not wrap
/// more than once per update. The cost of reading the counter twice is measured first and
/// subtracted. `Err` if the script is refused (it never is; kept honest rather than unwrapped).
pub fn pid_cycles<N: Real>(
    updates: u32,
    mask: u32,
    counter: &mut dyn FnMut() -> u32,
) -> Result<BenchStats, score_core::Error> {
    let mut hal = PlaybackHal::new([0.0; SIGNAL]);
    for (k, s) in hal.signal.iter_mut().enumerate() {
        *s = 0.015 * (N::from_f64(k as f64 * 0.025)).sin().to_f64();
    }
    let mut engine: Engine<N> = Engine::new();
    let mut sink = crate::out::TextOut::<256>::new(false);
    for line in FIG_5_20_PID.lines() {
        engine.execute(line, &mut hal, &mut sink)?;
    }
    let pid = engine.lookup("PID").ok_or(score_core::Error::Unsupported {
        command: "bench",
        what: "the PID variable",
    })?;
    let mut overhead = u32::MAX;
    for _ in 0..16 {
        let a = counter();
        let b = counter();
        overhead = overhead.min(a.wrapping_sub(b) & mask);
    }
    let mut stats = BenchStats {
        updates,
        min: u32::MAX,
        max: 0,
        total: 0,
        last_pid_bits: 0,
    };
    let mut t = 0u64;
    for _ in 0..updates {
        let a = counter();
        engine.tick(t, &mut hal);
        let v = engine.value(pid);
        let b = counter();
        let cycles = (a.wrapping_sub(b) & mask).saturating_sub(overhead);
        stats.min = stats.min.min(cycles);
        stats.max = stats.max.max(cycles);
        stats.total += cycles as u64;
        stats.last_pid_bits = v.map_or(0, |v| v.to_f64().to_bits());
        t += 1000;
    }
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On the host the "counter" counts down by a fixed 100 per read: each timed update then
    /// reads 100 after the 100 of overhead... i.e. exactly 0 cycles, which proves the overhead
    /// subtraction; and the PID output matches the same script on a plain engine.
    #[test]
    fn counts_with_a_fake_counter_and_computes_the_pid() {
        let mut c = 0u32;
        let mut counter = || {
            c = c.wrapping_sub(100);
            c & 0xFF_FFFF
        };
        let s = pid_cycles::<f64>(50, 0xFF_FFFF, &mut counter).unwrap();
        assert_eq!((s.updates, s.min, s.max, s.total), (50, 0, 0, 0));
        let pid = f64::from_bits(s.last_pid_bits);
        // After 50 updates the input is 0.015 sin(0.025 k): P dominates; |PID| stays below
        // Kp*0.015 + Ki*|integral| (< 350 * 0.05 * 0.015) + Kd*|derivative| (< 0.0788*0.4).
        assert!(pid.is_finite() && pid.abs() < 21.0 * 0.015 + 350.0 * 0.05 * 0.015 + 0.04);
        assert_ne!(pid, 0.0);
        let s32 = pid_cycles::<f32>(50, 0xFF_FFFF, &mut counter).unwrap();
        let pid32 = f64::from_bits(s32.last_pid_bits);
        assert!(
            (pid32 - pid).abs() < 1e-3 * pid.abs().max(1e-3),
            "{pid32} vs {pid}"
        );
    }
}
