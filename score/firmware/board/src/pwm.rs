//! The RP2040 PWM block as numbers.
//!
//! Eight slices, each a 16-bit counter with a fractional clock divider, counting `0..=TOP` and
//! wrapping; channel A and B of a slice are high while the counter is below their compare value
//! (inverted if `A_INV`/`B_INV`). So, with the divider `DIV = INT + FRAC/16` (1 ≤ DIV < 256):
//!
//! ```text
//! f_pwm = f_sys / (DIV · (TOP + 1))        duty = CC / (TOP + 1)
//! ```
//!
//! Score's outputs: output `n` (0–15) is slice `n / 2`, channel A for even `n` and B for odd,
//! on GPIO `n`; complementary pair `k` (`A`–`H`) is slice `k` with A = duty and B = the same
//! compare inverted (GPIO `2k` and `2k+1`; the RP2040 has no dead-time generator). The two
//! outputs of a slice share its frequency.

use score_core::hal::{HalError, PwmOutput};

/// Single outputs (two per slice).
pub const OUTPUTS: u8 = 16;
/// Slices.
pub const SLICES: usize = 8;
/// Largest TOP used: `TOP + 1` must itself fit a compare register for a 100 % duty.
pub const MAX_TOP: u16 = 65534;
/// Divider range in sixteenths: 1 to 255 + 15/16.
const DIV16_MIN: u32 = 16;
const DIV16_MAX: u32 = 255 * 16 + 15;

/// Divider and wrap value of a slice, and the frequency they produce.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timing {
    /// Divider in sixteenths (`INT << 4 | FRAC`), 16..=4095.
    pub div16: u16,
    /// Wrap value: the period is `top + 1` counts.
    pub top: u16,
    /// The frequency produced, Hz.
    pub freq_hz: f64,
}

impl Timing {
    /// Integer part of the divider (`DIV_INT`).
    pub fn div_int(&self) -> u8 {
        (self.div16 >> 4) as u8
    }

    /// Fractional part of the divider in sixteenths (`DIV_FRAC`).
    pub fn div_frac(&self) -> u8 {
        (self.div16 & 15) as u8
    }

    /// Counts per period (`top + 1`): the duty resolution.
    pub fn counts(&self) -> u32 {
        self.top as u32 + 1
    }

    /// Compare value nearest to `duty` (a fraction, clamped to 0..=1; NaN counts as 0).
    pub fn compare(&self, duty: f32) -> u16 {
        let d = if duty.is_nan() {
            0.0
        } else {
            duty.clamp(0.0, 1.0)
        };
        let c = (d as f64 * self.counts() as f64 + 0.5) as u32;
        c.min(self.counts()) as u16
    }

    /// The duty a compare value produces.
    pub fn duty_of(&self, compare: u16) -> f32 {
        (compare as f64 / self.counts() as f64) as f32
    }
}

/// Divider and TOP for `freq_hz` from a system clock of `f_sys` Hz.
///
/// Among the dividers from the smallest that lets `TOP` fit (finest duty resolution) up to
/// twice that (at least half the resolution), takes the one whose nearest `TOP` gives the
/// smallest frequency error; ties go to the finer resolution. So 1 kHz at 125 MHz is exact
/// (DIV 2, TOP 62 499) rather than 2 ppm off at DIV 1.9375. Frequencies outside
/// `f_sys / (255.9375 · 65 535) ..= f_sys / 2` are [`HalError::OutOfRange`].
pub fn timing(f_sys: u32, freq_hz: f32) -> Result<Timing, HalError> {
    let f = freq_hz as f64;
    if !(f.is_finite() && f > 0.0) {
        return Err(HalError::OutOfRange);
    }
    // Clock sixteenths per PWM period.
    let total16 = 16.0 * f_sys as f64 / f;
    let max_counts = MAX_TOP as f64 + 1.0;
    let first = libm_ceil(total16 / max_counts).max(DIV16_MIN as f64);
    if first > DIV16_MAX as f64 || total16 / (DIV16_MIN as f64) < 1.5 {
        return Err(HalError::OutOfRange);
    }
    let first = first as u32;
    let last = (2 * first).min(DIV16_MAX);
    let mut best: Option<(f64, Timing)> = None;
    for div16 in first..=last {
        let counts = (total16 / div16 as f64 + 0.5) as u32;
        if !(2..=MAX_TOP as u32 + 1).contains(&counts) {
            continue;
        }
        let actual = 16.0 * f_sys as f64 / (div16 as f64 * counts as f64);
        let err = (actual - f).abs();
        if best.is_none_or(|(e, _)| err < e) {
            best = Some((
                err,
                Timing {
                    div16: div16 as u16,
                    top: (counts - 1) as u16,
                    freq_hz: actual,
                },
            ));
            if err == 0.0 {
                break;
            }
        }
    }
    best.map(|(_, t)| t).ok_or(HalError::OutOfRange)
}

fn libm_ceil(x: f64) -> f64 {
    let t = x as u64 as f64;
    if t < x {
        t + 1.0
    } else {
        t
    }
}

/// Register values of one slice, ready to write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SliceRegs {
    /// Slice number 0-7.
    pub slice: u8,
    /// `DIV.INT`.
    pub div_int: u8,
    /// `DIV.FRAC`.
    pub div_frac: u8,
    /// `TOP`.
    pub top: u16,
    /// `CC.A`.
    pub cc_a: u16,
    /// `CC.B`.
    pub cc_b: u16,
    /// `CSR.A_INV`.
    pub a_inv: bool,
    /// `CSR.B_INV`.
    pub b_inv: bool,
    /// `CSR.EN`.
    pub enable: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Channel {
    used: bool,
    inverted: bool,
    compare: u16,
}

#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Slice {
    timing: Option<Timing>,
    ch: [Channel; 2],
}

/// The slice and channels (0 = A, 1 = B) an output drives.
pub fn channels(out: PwmOutput) -> Result<(usize, &'static [usize]), HalError> {
    match out {
        PwmOutput::Single(n) if n < OUTPUTS => {
            Ok(((n / 2) as usize, if n % 2 == 0 { &[0] } else { &[1] }))
        }
        PwmOutput::Complementary(k) if (k as usize) < SLICES => Ok((k as usize, &[0, 1])),
        _ => Err(HalError::NoSuchChannel),
    }
}

/// The GPIO pins an output drives (output `n` is GPIO `n`).
pub fn pins(out: PwmOutput) -> Result<&'static [u8], HalError> {
    const P: [u8; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15];
    let (slice, ch) = channels(out)?;
    let first = 2 * slice + ch[0];
    Ok(&P[first..first + ch.len()])
}

/// The state of all eight slices: what each channel is doing, so that reconfiguring one
/// output keeps its sibling's duty.
#[derive(Debug, Clone, Default)]
pub struct PwmBank {
    slices: [Slice; SLICES],
}

impl PwmBank {
    /// All slices stopped.
    pub const fn new() -> Self {
        const S: Slice = Slice {
            timing: None,
            ch: [Channel {
                used: false,
                inverted: false,
                compare: 0,
            }; 2],
        };
        Self {
            slices: [S; SLICES],
        }
    }

    /// Starts `out` at (nearly) `freq_hz`, duty 0. The sibling output of the slice, if running,
    /// moves to the new frequency and keeps its duty. Returns the frequency produced and the
    /// slice's new registers.
    pub fn configure(
        &mut self,
        out: PwmOutput,
        f_sys: u32,
        freq_hz: f32,
    ) -> Result<(f64, SliceRegs), HalError> {
        let (s, chans) = channels(out)?;
        let t = timing(f_sys, freq_hz)?;
        let slice = &mut self.slices[s];
        let old = slice.timing;
        for c in 0..2 {
            let ch = &mut slice.ch[c];
            if chans.contains(&c) {
                *ch = Channel {
                    used: true,
                    inverted: matches!(out, PwmOutput::Complementary(_)) && c == 1,
                    compare: 0,
                };
            } else if ch.used {
                let duty = old.map_or(0.0, |o| o.duty_of(ch.compare));
                ch.compare = t.compare(duty);
            }
        }
        slice.timing = Some(t);
        Ok((t.freq_hz, self.regs(s)))
    }

    /// Sets the duty of a running output; returns the duty produced and the registers.
    /// An output that is not running produces 0.
    pub fn set_duty(&mut self, out: PwmOutput, duty: f32) -> (f32, Option<SliceRegs>) {
        let Ok((s, chans)) = channels(out) else {
            return (0.0, None);
        };
        let slice = &mut self.slices[s];
        let Some(t) = slice.timing else {
            return (0.0, None);
        };
        if !chans.iter().all(|&c| slice.ch[c].used) {
            return (0.0, None);
        }
        let c = t.compare(duty);
        for &ch in chans {
            slice.ch[ch].compare = c;
        }
        (t.duty_of(c), Some(self.regs(s)))
    }

    /// Stops `out`; the slice stops when neither channel is used. Returns the registers.
    pub fn release(&mut self, out: PwmOutput) -> Option<SliceRegs> {
        let (s, chans) = channels(out).ok()?;
        let slice = &mut self.slices[s];
        for &c in chans {
            slice.ch[c] = Channel::default();
        }
        if !slice.ch.iter().any(|c| c.used) {
            slice.timing = None;
        }
        Some(self.regs(s))
    }

    /// The timing of slice `s`, if running.
    pub fn timing_of(&self, s: usize) -> Option<Timing> {
        self.slices.get(s).and_then(|s| s.timing)
    }

    /// Register values of slice `s`.
    pub fn regs(&self, s: usize) -> SliceRegs {
        let slice = &self.slices[s];
        let t = slice.timing;
        SliceRegs {
            slice: s as u8,
            div_int: t.map_or(1, |t| t.div_int()),
            div_frac: t.map_or(0, |t| t.div_frac()),
            top: t.map_or(MAX_TOP, |t| t.top),
            cc_a: slice.ch[0].compare,
            cc_b: slice.ch[1].compare,
            a_inv: slice.ch[0].inverted,
            b_inv: slice.ch[1].inverted,
            enable: t.is_some(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const F_SYS: u32 = 125_000_000;

    #[test]
    fn exact_frequencies_use_an_exact_divider() {
        let t = timing(F_SYS, 1000.0).unwrap();
        assert_eq!((t.div16, t.top, t.freq_hz), (32, 62_499, 1000.0));
        let t = timing(F_SYS, 20_000.0).unwrap();
        assert_eq!((t.div16, t.top, t.freq_hz), (16, 6_249, 20_000.0));
        // 125 MHz / 2: the fastest (TOP 1, two counts).
        let t = timing(F_SYS, 62.5e6).unwrap();
        assert_eq!((t.div16, t.top), (16, 1));
    }

    #[test]
    fn inexact_frequencies_are_the_nearest_reachable() {
        // The search must find the smallest error among all dividers from the finest-resolution
        // one to twice it; a brute force over the same range (both neighbouring TOPs) agrees.
        for f in [7e6f32, 3.3e3, 44_100.0, 12.345, 1e5, 333.0] {
            let t = timing(F_SYS, f).unwrap();
            let total16 = 16.0 * F_SYS as f64 / f as f64;
            let first = (total16 / 65535.0).ceil().max(16.0) as u32;
            let mut best = f64::INFINITY;
            for d in first..=(2 * first).min(4095) {
                for counts in [(total16 / d as f64).floor(), (total16 / d as f64).ceil()] {
                    if (2.0..=65535.0).contains(&counts) {
                        let a = 16.0 * F_SYS as f64 / (d as f64 * counts);
                        best = best.min((a - f as f64).abs());
                    }
                }
            }
            assert_eq!((t.freq_hz - f as f64).abs(), best, "{f} Hz");
            // At least half the finest resolution the frequency allows.
            assert!(
                t.counts() as f64 >= total16 / (2.0 * first as f64) - 0.5,
                "{f}: resolution {t:?}"
            );
        }
    }

    #[test]
    fn out_of_range_frequencies_are_refused() {
        for f in [0.0, -1.0, f32::NAN, f32::INFINITY, 7.0, 90e6] {
            assert_eq!(timing(F_SYS, f), Err(HalError::OutOfRange), "{f}");
        }
        // The slowest reachable: 125 MHz / (255.9375 * 65535) = 7.45 Hz.
        assert!(timing(F_SYS, 7.46).is_ok());
    }

    #[test]
    fn compare_is_within_half_a_count_and_reaches_both_ends() {
        let t = timing(F_SYS, 1000.0).unwrap();
        assert_eq!(t.compare(0.0), 0);
        assert_eq!(t.compare(1.0), 62_500);
        assert_eq!(t.compare(f32::NAN), 0);
        assert_eq!(t.compare(2.0), 62_500);
        for d in [0.1f32, 0.25, 0.333, 0.5, 0.9999] {
            let c = t.compare(d);
            // The f32 duty carries at most 2^-24 relative error: far below half a count.
            assert!(
                (t.duty_of(c) as f64 - d as f64).abs() <= 0.5 / 62_500.0 + 1e-7,
                "{d}"
            );
        }
    }

    #[test]
    fn outputs_map_to_slices_channels_and_pins() {
        assert_eq!(channels(PwmOutput::Single(5)).unwrap(), (2, &[1usize][..]));
        assert_eq!(pins(PwmOutput::Single(5)).unwrap(), &[5]);
        assert_eq!(pins(PwmOutput::Complementary(3)).unwrap(), &[6, 7]);
        assert_eq!(
            channels(PwmOutput::Single(16)),
            Err(HalError::NoSuchChannel)
        );
        assert_eq!(
            channels(PwmOutput::Complementary(8)),
            Err(HalError::NoSuchChannel)
        );
    }

    #[test]
    fn reconfiguring_a_slice_keeps_the_sibling_duty() {
        let mut b = PwmBank::new();
        b.configure(PwmOutput::Single(2), F_SYS, 1000.0).unwrap();
        let (d, _) = b.set_duty(PwmOutput::Single(2), 0.25);
        assert_eq!(d, 0.25);
        let (f, regs) = b.configure(PwmOutput::Single(3), F_SYS, 20_000.0).unwrap();
        assert_eq!(f, 20_000.0);
        // Output 2 still at 25 %: 6250 counts * 0.25 = 1562.5 -> 1563 (round half up).
        assert_eq!((regs.cc_a, regs.cc_b, regs.top), (1563, 0, 6249));
        assert!(regs.enable);
        b.release(PwmOutput::Single(2));
        assert!(b.regs(1).enable, "output 3 still runs");
        let regs = b.release(PwmOutput::Single(3)).unwrap();
        assert!(!regs.enable);
    }

    #[test]
    fn complementary_pairs_invert_channel_b() {
        let mut b = PwmBank::new();
        b.configure(PwmOutput::Complementary(1), F_SYS, 20_000.0)
            .unwrap();
        let (d, regs) = b.set_duty(PwmOutput::Complementary(1), 0.3);
        let regs = regs.unwrap();
        assert_eq!(d, 0.3);
        assert_eq!(
            (regs.cc_a, regs.cc_b, regs.a_inv, regs.b_inv),
            (1875, 1875, false, true)
        );
        // Not running: nothing produced.
        assert_eq!(b.set_duty(PwmOutput::Single(0), 0.5), (0.0, None));
    }
}
