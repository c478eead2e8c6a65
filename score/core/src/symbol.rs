//! Symbol kinds, block states and periodic tasks.

use crate::capacity::MAX_SYMBOLS;
use crate::error::Name;
use crate::hal::{AdcInput, PwmOutput};
use crate::num::Real;
use crate::VarId;

/// A gain or limit: a literal or another variable (so `set` can tune it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Operand<N> {
    Lit(N),
    Var(VarId),
}

/// The length in seconds of a block's latest time step, kept with the step in microseconds:
/// at a steady rate the step repeats, and converting it again (a 64-bit conversion and a
/// division, hundreds of cycles in soft float) would give the same bits.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Step<N> {
    us: u64,
    s: N,
}

impl<N: Real> Step<N> {
    /// `N::seconds_from_us(us)`, converted only when `us` differs from the previous step.
    /// (The default, 0 µs = 0 s, is the conversion of 0.)
    #[inline]
    pub fn seconds(&mut self, us: u64) -> N {
        if us != self.us {
            self.us = us;
            self.s = N::seconds_from_us(us);
        }
        self.s
    }
}

/// Trapezoid integrator state: `I += (t2 - t1) (x1 + x2) / 2`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Trapezoid<N> {
    pub last: Option<(u64, N)>,
    pub acc: N,
    dt: Step<N>,
}

impl<N: Real> Trapezoid<N> {
    /// Adds the sample `x` taken at `t_us`; the first sample only sets the starting point.
    /// `None` (the sum unchanged) for a sample that is not finite, after which the next finite
    /// sample starts afresh (the gap adds nothing), or a sum that would overflow.
    #[inline]
    pub fn step(&mut self, t_us: u64, x: N) -> Option<N> {
        if !x.is_finite() {
            self.last = None;
            return None;
        }
        let last = self.last.replace((t_us, x));
        if let Some((t0, x0)) = last {
            let dt = self.dt.seconds(t_us.saturating_sub(t0));
            let acc = self.acc + ((x0 + x) * dt).halve();
            if !acc.is_finite() {
                return None;
            }
            self.acc = acc;
        }
        Some(self.acc)
    }
}

/// Two-point derivative state: `dx/dt = (x2 - x1) / (t2 - t1)`; 0 until two samples exist.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct TwoPoint<N> {
    pub last: Option<(u64, N)>,
    pub out: N,
    dt: Step<N>,
}

impl<N: Real> TwoPoint<N> {
    /// The derivative after sample `x` at `t_us`. `None` (the output unchanged) for a sample
    /// that is not finite, after which the next finite sample starts afresh, or a quotient
    /// that overflows.
    #[inline]
    pub fn step(&mut self, t_us: u64, x: N) -> Option<N> {
        if !x.is_finite() {
            self.last = None;
            return None;
        }
        if let Some((t0, x0)) = self.last.replace((t_us, x)) {
            if t_us > t0 {
                let out = (x - x0) / self.dt.seconds(t_us - t0);
                if !out.is_finite() {
                    return None;
                }
                self.out = out;
            }
        }
        Some(self.out)
    }
}

/// First-order low-pass state: `y += dt/(tau+dt) (x - y)`, `tau = 1/(2 pi fc)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LowPass<N> {
    /// `1 / (2 pi fc)`, computed once at definition.
    tau: N,
    /// Instant of the previous sample (`None` before the first).
    last_t: Option<u64>,
    /// `dt/(tau+dt)` of the latest step (`dt_us` in microseconds; 0 before the first step),
    /// kept like [`Step`].
    dt_us: u64,
    gain: N,
}

impl<N: Real> LowPass<N> {
    pub fn new(cutoff_hz: N) -> Self {
        LowPass {
            tau: N::ONE / (N::from_f64(core::f64::consts::TAU) * cutoff_hz),
            last_t: None,
            dt_us: 0,
            gain: N::ZERO,
        }
    }

    /// The output after sample `x` at `t_us`, from the previous output `y`: the first sample
    /// passes through; a repeated instant leaves `y`. `None` (the output and the state
    /// unchanged) for a sample that is not finite: the filter holds through it.
    #[inline]
    pub fn step(&mut self, t_us: u64, x: N, y: N) -> Option<N> {
        if !x.is_finite() {
            return None;
        }
        let out = match self.last_t {
            Some(t0) if t_us > t0 => {
                let us = t_us - t0;
                if us != self.dt_us {
                    let dt = N::seconds_from_us(us);
                    self.dt_us = us;
                    self.gain = dt / (self.tau + dt);
                }
                y + self.gain * (x - y)
            }
            Some(_) => y,
            None => x,
        };
        self.last_t = Some(t_us);
        Some(out)
    }
}

/// What a variable is. `Copy` so a command can take it out, change it, and put it back.
/// `repr(u8)`: an explicit one-byte tag (same size here) instead of a discriminant hidden in
/// a 64-bit field's spare values, which made every `match` on a Cortex-M0+ a chain of 64-bit
/// compares.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(u8)]
pub(crate) enum Kind<N> {
    /// Referenced before being defined; reads as 0.
    Placeholder,
    /// `defexp name <number>`: a settable constant.
    Const,
    /// `defexp`: compiled instructions `ops[start..start+len]`, evaluated lazily.
    Expr { start: u16, len: u16 },
    /// `defscale`: `[a,b] -> [c,d]`, hard-limited to `[c,d]`, lazy.
    Scale { src: VarId, a: N, b: N, c: N, d: N },
    /// `defsat`: clamp to `[lo,hi]`, lazy.
    Sat { src: VarId, lo: N, hi: N },
    /// `defint`: trapezoid integral, periodic.
    Int { src: VarId, st: Trapezoid<N> },
    /// `defwind`: integral of `src + gain (post - pre)`, periodic (thesis Fig. 5.11).
    Wind {
        src: VarId,
        gain: N,
        pre: VarId,
        post: VarId,
        st: Trapezoid<N>,
    },
    /// `defdiff`: two-point derivative, periodic.
    Diff { src: VarId, st: TwoPoint<N> },
    /// `deflpf`: first-order low-pass, periodic.
    Lpf {
        src: VarId,
        cutoff_hz: N,
        st: LowPass<N>,
    },
    /// `defpid`: `kp e + ki I(e) + kd D(e)`, optionally clamped with conditional integration.
    Pid {
        src: VarId,
        kp: Operand<N>,
        ki: Operand<N>,
        kd: Operand<N>,
        limits: Option<(N, N)>,
        int: Trapezoid<N>,
        der: TwoPoint<N>,
    },
    /// `adc`: raw code, periodic; its task also refreshes the paired volts variable.
    AdcRaw { input: AdcInput, volts: VarId },
    /// `adc`: the volts of `raw`, stored by the raw variable's task.
    AdcVolts { raw: VarId },
    /// `pwm`: a fixed duty cycle in %, settable.
    PwmFixed { out: PwmOutput, freq: f32 },
    /// `defpwm`: the duty (%) follows `src`, periodic.
    PwmFollow {
        src: VarId,
        out: PwmOutput,
        freq: f32,
    },
    /// `gpio`: a sampled input pin (0/1), periodic.
    GpioIn { pin: u8 },
    /// `defgpio`: drives `pin` high while `src >= 0.5`, periodic.
    GpioOut { src: VarId, pin: u8 },
    /// `infile`: plays back a file, one sample per update, looping (host port).
    Infile { stream: u8, len: u32, cursor: u32 },
    /// `log`: writes `src` to a file, one value per line per update (host port).
    Log { src: VarId, stream: u8 },
}

/// Which command family may (re)define a variable of this kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Family {
    Placeholder,
    /// defexp, defscale, defsat, defint, defwind, defdiff, deflpf, defpid, defpwm, defgpio.
    Def,
    Adc,
    Pwm,
    Gpio,
    Infile,
    Log,
}

impl<N> Kind<N> {
    pub fn family(&self) -> Family {
        match self {
            Kind::Placeholder => Family::Placeholder,
            Kind::AdcRaw { .. } | Kind::AdcVolts { .. } => Family::Adc,
            Kind::PwmFixed { .. } => Family::Pwm,
            Kind::GpioIn { .. } => Family::Gpio,
            Kind::Infile { .. } => Family::Infile,
            Kind::Log { .. } => Family::Log,
            _ => Family::Def,
        }
    }

    /// Evaluated on demand from its inputs (no state of its own).
    pub fn is_lazy(&self) -> bool {
        matches!(
            self,
            Kind::Expr { .. } | Kind::Scale { .. } | Kind::Sat { .. }
        )
    }

    /// Description for messages ("an ADC channel", ...).
    pub fn what(&self) -> &'static str {
        match self {
            Kind::Placeholder => "not defined yet",
            Kind::Const => "a constant",
            Kind::Expr { .. } => "an expression",
            Kind::Scale { .. } => "a scale",
            Kind::Sat { .. } => "a saturation",
            Kind::Int { .. } => "an integral",
            Kind::Wind { .. } => "an anti-windup integral",
            Kind::Diff { .. } => "a derivative",
            Kind::Lpf { .. } => "a low-pass filter",
            Kind::Pid { .. } => "a PID controller",
            Kind::AdcRaw { .. } => "an ADC channel (raw)",
            Kind::AdcVolts { .. } => "an ADC channel (volts)",
            Kind::PwmFixed { .. } => "a PWM output",
            Kind::PwmFollow { .. } => "a PWM output following a variable",
            Kind::GpioIn { .. } => "a GPIO input",
            Kind::GpioOut { .. } => "a GPIO output",
            Kind::Infile { .. } => "a file playback",
            Kind::Log { .. } => "a log",
        }
    }

    /// Calls `f` for every variable this one reads (expression variables via `ops`).
    pub fn for_each_ref(&self, ops: &[crate::program::Instr<N>], mut f: impl FnMut(VarId))
    where
        N: Copy,
    {
        let operand = |o: &Operand<N>, f: &mut dyn FnMut(VarId)| {
            if let Operand::Var(v) = o {
                f(*v)
            }
        };
        match self {
            Kind::Expr { start, len } => {
                let (s, l) = (*start as usize, *len as usize);
                for v in ops
                    .get(s..s + l)
                    .unwrap_or(&[])
                    .iter()
                    .filter_map(|i| i.var())
                {
                    f(v)
                }
            }
            Kind::Scale { src, .. }
            | Kind::Sat { src, .. }
            | Kind::Int { src, .. }
            | Kind::Diff { src, .. }
            | Kind::Lpf { src, .. }
            | Kind::PwmFollow { src, .. }
            | Kind::GpioOut { src, .. }
            | Kind::Log { src, .. } => f(*src),
            Kind::Wind { src, pre, post, .. } => {
                f(*src);
                f(*pre);
                f(*post);
            }
            Kind::Pid {
                src, kp, ki, kd, ..
            } => {
                f(*src);
                operand(kp, &mut f);
                operand(ki, &mut f);
                operand(kd, &mut f);
            }
            _ => {}
        }
    }
}

/// The schedule of a periodic variable. The k-th update falls at `t0 + k * 1e9 / rate_mhz` µs,
/// kept exact with an integer remainder, so rates like 3 Hz never drift. The period's whole and
/// fractional microseconds are precomputed: an on-time update costs no division.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Task {
    /// Rate in millihertz.
    pub mhz: u32,
    /// Whole microseconds of the period (`1e9 / mhz`).
    q: u32,
    /// Fractional part of the period, in units of 1/mhz µs (`1e9 % mhz`).
    r: u32,
    /// Next update instant; `None` = at the next tick.
    pub due: Option<u64>,
    /// Accumulated fractional microseconds, in units of 1/mhz µs.
    frac: u32,
    /// Updates skipped because the port called `tick` more than a period late.
    pub missed: u32,
    /// Updates of a block whose input (or result) was not finite, so it held its value.
    pub held: u32,
    /// Instant of the latest update (`None` before the first).
    pub last: Option<u64>,
}

impl Task {
    pub fn new(mhz: u32) -> Self {
        let mut t = Task {
            mhz: 1,
            q: 0,
            r: 0,
            due: None,
            frac: 0,
            missed: 0,
            held: 0,
            last: None,
        };
        t.set_rate(mhz);
        t
    }

    /// Changes the rate; the next update stays where it was.
    pub fn set_rate(&mut self, mhz: u32) {
        self.mhz = mhz.max(1);
        self.q = 1_000_000_000 / self.mhz;
        self.r = 1_000_000_000 % self.mhz;
        self.frac = 0;
    }

    /// Sets `due` one period after `from`, and returns it.
    #[inline]
    pub fn advance_one(&mut self, from: u64) -> u64 {
        // frac < mhz and r < mhz, so the sum carries at most one microsecond. In 32 bits (a
        // sum past u32::MAX is a carry too): 64-bit arithmetic costs several instructions per
        // operation on a Cortex-M0+.
        let (f, wrapped) = self.frac.overflowing_add(self.r);
        let carry = wrapped || f >= self.mhz;
        self.frac = if carry { f.wrapping_sub(self.mhz) } else { f };
        let due = from.saturating_add(self.q as u64 + carry as u64);
        self.due = Some(due);
        due
    }

    /// Sets `due` `n` periods after `from` (the late path: 128-bit arithmetic).
    pub fn advance(&mut self, from: u64, n: u64) {
        let mhz = self.mhz as u128;
        let total_frac = self.frac as u128 + self.r as u128 * n as u128;
        let due = from as u128 + self.q as u128 * n as u128 + total_frac / mhz;
        self.due = Some(due.min(u64::MAX as u128) as u64);
        self.frac = (total_frac % mhz) as u32;
    }

    /// Whole periods between `due` and `now` (how far behind the task is).
    #[inline]
    pub fn periods_behind(&self, due: u64, now: u64) -> u64 {
        let late = now - due;
        if late < self.q as u64 {
            0
        } else {
            (late as u128 * self.mhz as u128 / 1_000_000_000u128) as u64
        }
    }
}

/// One table slot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Symbol<N> {
    pub name: Name,
    pub kind: Kind<N>,
    pub task: Option<Task>,
}

/// A set of symbol slots.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct SymSet([u32; MAX_SYMBOLS.div_ceil(32)]);

impl SymSet {
    pub const EMPTY: SymSet = SymSet([0; MAX_SYMBOLS.div_ceil(32)]);

    pub fn insert(&mut self, id: usize) {
        self.0[id / 32] |= 1 << (id % 32);
    }
    pub fn contains(&self, id: usize) -> bool {
        self.0[id / 32] & (1 << (id % 32)) != 0
    }
    pub fn union(&mut self, other: &SymSet) {
        for (a, b) in self.0.iter_mut().zip(other.0.iter()) {
            *a |= *b;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The on-time step (32-bit) agrees with the general one (128-bit) for every rate, up to
    /// rates whose fractional sums pass u32::MAX.
    #[test]
    fn advance_one_is_advance_by_one_period() {
        for mhz in [1, 3, 7_000, 999_999, 100_000_000, (1 << 31) + 5, u32::MAX] {
            let (mut a, mut b) = (Task::new(mhz), Task::new(mhz));
            let mut t = 0u64;
            for _ in 0..2_000 {
                a.advance_one(t);
                b.advance(t, 1);
                assert_eq!(a, b, "{mhz} mHz at {t} us");
                t = a.due.unwrap_or(0);
            }
        }
    }
}
