//! The per-update path: the scheduler (`tick`), one update of a periodic variable, and the
//! on-demand evaluation of bare expressions (`value`).
//!
//! This is what runs thousands of times a second on a Cortex-M0+ without FPU or divider, so
//! everything that can be decided when the table changes is decided in `rebuild` (evaluation
//! order, which expressions each reader must refresh, the earliest deadline), values live in
//! one dense array, and updates change the table in place instead of copying symbols.

use core::fmt::Write as _;

use crate::capacity::MAX_SYMBOLS;
use crate::engine::{clamp, Engine, Stream};
use crate::hal::{AdcInput, Hal, StreamId};
use crate::num::Real;
use crate::program;
use crate::symbol::{Kind, Operand};
use crate::text::BufWriter;
use crate::VarId;

/// The stored value of `id` (0 for an empty slot, which always holds 0).
#[inline]
fn at<N: Real>(values: &[N; MAX_SYMBOLS], id: VarId) -> N {
    values.get(id.0 as usize).copied().unwrap_or(N::ZERO)
}

#[inline]
fn operand<N: Real>(values: &[N; MAX_SYMBOLS], o: Operand<N>) -> N {
    match o {
        Operand::Lit(v) => v,
        Operand::Var(id) => at(values, id),
    }
}

/// The new value of a lazy variable other than an expression from its inputs' stored values
/// (`old` for other kinds).
/// A scale or saturation limits what it passes to `[lo, hi]`: an infinite input gives the
/// limit on its side, and NaN (which has no side) the point of `[lo, hi]` nearest 0 — 0 itself
/// when the limits straddle it, so a duty or a command behind a saturation goes to rest.
fn compute_lazy<N: Real>(kind: &Kind<N>, values: &[N; MAX_SYMBOLS], old: N) -> N {
    let (y, lo, hi) = match *kind {
        Kind::Scale { src, a, b, c, d } => {
            let y = c + (at(values, src) - a) * (d - c) / (b - a);
            let (lo, hi) = if c <= d { (c, d) } else { (d, c) };
            (y, lo, hi)
        }
        Kind::Sat { src, lo, hi } => (at(values, src), lo, hi),
        _ => return old,
    };
    // NaN fails every comparison: `y == y` is the one-compare test for it.
    #[allow(clippy::eq_op)]
    let y = if y == y { y } else { N::ZERO };
    clamp(y, lo, hi)
}

fn stream_id(streams: &[Option<Stream>], slot: u8) -> Option<StreamId> {
    streams
        .get(slot as usize)
        .and_then(|s| s.as_ref())
        .map(|s| s.id)
}

impl<N: Real> Engine<N> {
    /// Recomputes, in dependency order, the bare expressions that reading slot `i` (a lazy
    /// slot: its inputs and itself, `view`) or updating it (a periodic slot: its lazy inputs,
    /// `needs`) must have fresh: the positions `span[i]` of the evaluation order precomputed by
    /// `rebuild`. Most updates read no bare expression and have an empty span.
    // The check inline at every caller, the loop out of line: an empty span then costs a
    // compare instead of a call.
    #[inline(always)]
    fn refresh(&mut self, i: usize) {
        let (from, to) = self.span[i];
        if from < to {
            self.refresh_span(i, from as usize, to as usize);
        }
    }

    #[inline(never)]
    fn refresh_span(&mut self, i: usize, from: usize, to: usize) {
        let set = match &self.syms[i] {
            Some(s) if s.kind.is_lazy() => self.view[i],
            _ => self.needs[i],
        };
        let Engine {
            syms,
            ops,
            values,
            stack,
            eval_order,
            eval_code,
            ..
        } = self;
        for k in from..to.min(MAX_SYMBOLS) {
            let j = eval_order[k] as usize;
            if !set.contains(j) {
                continue;
            }
            let (start, len) = (eval_code[k].0 as usize, eval_code[k].1 as usize);
            values[j] = if len > 0 {
                match ops.get(start..start + len) {
                    Some(code) => program::eval(code, values, stack),
                    None => N::NAN,
                }
            } else if let Some(s) = &syms[j] {
                compute_lazy(&s.kind, values, values[j])
            } else {
                values[j]
            };
        }
    }

    /// Current value of a variable, evaluating bare expressions on demand.
    pub fn value(&mut self, id: VarId) -> Option<N> {
        let i = id.0 as usize;
        let s = self.syms.get(i)?.as_ref()?;
        if s.kind.is_lazy() {
            self.refresh(i);
        }
        Some(self.values[i])
    }

    /// Current value of a variable by name.
    pub fn value_of(&mut self, name: &str) -> Option<N> {
        let id = self.lookup(name)?;
        self.value(id)
    }

    /// Tells the engine the current time without running any update (never backwards). A
    /// periodic variable defined afterwards first runs at this instant; ports call it before
    /// [`Engine::execute`] so that new variables start when they are typed.
    pub fn set_time(&mut self, now_us: u64) {
        self.now_us = self.now_us.max(now_us);
    }

    /// The earliest instant at which a periodic variable is due (`now_us` for one that has not
    /// run yet), or `None` if nothing is periodic. A simulated-time port jumps straight there.
    /// O(1): the scheduler keeps the earliest deadline as it runs.
    pub fn next_deadline(&self) -> Option<u64> {
        if self.run_len == 0 {
            return None;
        }
        Some(if self.due_now {
            self.due_min.min(self.now_us)
        } else {
            self.due_min
        })
    }

    /// Recomputes the earliest deadline from every task (after a change of the table).
    pub(crate) fn rescan_deadlines(&mut self) {
        let (mut due_min, mut due_now) = (u64::MAX, false);
        for s in self.syms.iter().flatten() {
            match s.task.map(|t| t.due) {
                Some(Some(due)) => due_min = due_min.min(due),
                Some(None) => due_now = true,
                None => {}
            }
        }
        self.due_min = due_min;
        self.due_now = due_now;
    }

    /// Runs every periodic variable that is due at `now_us`, in priority order (rate descending;
    /// at equal rates producers before consumers; then slot order). A task more than one period
    /// late runs once, at its latest due instant, and counts the skipped updates instead of
    /// catching up in a burst. Returns how many updates ran. Time never goes backwards: an older
    /// `now_us` is treated as the latest one seen.
    pub fn tick(&mut self, now_us: u64, hal: &mut impl Hal) -> usize {
        if now_us > self.now_us {
            self.now_us = now_us;
        }
        let now = self.now_us;
        if self.run_len == 0 || (!self.due_now && now < self.due_min) {
            return 0;
        }
        let mut ran = 0;
        let mut due_min = u64::MAX;
        for k in 0..self.run_len {
            let i = self.run_order[k] as usize;
            let Some(task) = self.syms[i].as_mut().and_then(|s| s.task.as_mut()) else {
                continue;
            };
            let t = match task.due {
                None => now,
                Some(due) if due > now => {
                    due_min = due_min.min(due);
                    continue;
                }
                Some(due) => match task.periods_behind(due, now) {
                    0 => due,
                    behind => {
                        task.missed = task
                            .missed
                            .saturating_add(behind.min(u32::MAX as u64) as u32);
                        task.advance(due, behind);
                        task.due.unwrap_or(now)
                    }
                },
            };
            let next = task.advance_one(t);
            task.last = Some(t);
            due_min = due_min.min(next);
            self.update(i, t, hal);
            ran += 1;
        }
        self.due_min = due_min;
        self.due_now = false;
        ran
    }

    /// One update of periodic slot `i` at instant `t`, in place.
    fn update(&mut self, i: usize, t: u64, hal: &mut impl Hal) {
        self.refresh(i);
        let Engine {
            syms,
            values,
            streams,
            ..
        } = self;
        let Some(sym) = syms[i].as_mut() else { return };
        let old = values[i];
        // An ADC's raw task also stores its volts variable.
        let mut volts_update = None;
        // `None` from a block: its input or result was not finite; it holds its value.
        let value: Option<N> = match &mut sym.kind {
            Kind::AdcRaw { input, volts } => match hal.adc_read(*input) {
                Ok(raw) => {
                    volts_update = Some((volts.0 as usize, Self::volts(*input, raw, hal)));
                    Some(N::from_u32(raw as u32))
                }
                Err(_) => Some(old),
            },
            Kind::Int { src, st } => st.step(t, at(values, *src)),
            Kind::Wind {
                src,
                gain,
                pre,
                post,
                st,
            } => {
                let x = at(values, *src) + *gain * (at(values, *post) - at(values, *pre));
                st.step(t, x)
            }
            Kind::Diff { src, st } => st.step(t, at(values, *src)),
            Kind::Lpf { src, st, .. } => st.step(t, at(values, *src), old),
            Kind::Pid {
                src,
                kp,
                ki,
                kd,
                limits,
                int,
                der,
            } => {
                let e = at(values, *src);
                let (kp, ki, kd) = (
                    operand(values, *kp),
                    operand(values, *ki),
                    operand(values, *kd),
                );
                if !(e.is_finite() && kp.is_finite() && ki.is_finite() && kd.is_finite()) {
                    // Hold the output; the integral and derivative start afresh after the gap.
                    int.last = None;
                    der.last = None;
                    None
                } else {
                    pid_step(t, e, kp, ki, kd, *limits, int, der)
                }
            }
            Kind::PwmFollow { src, out, .. } => {
                let x = at(values, *src) / N::from_u32(100);
                let duty = if x.is_finite() {
                    clamp(x, N::ZERO, N::ONE)
                } else {
                    N::ZERO
                };
                let applied = hal.pwm_set_duty(*out, duty.to_f64() as f32);
                Some(N::from_f64(applied as f64) * N::from_u32(100))
            }
            Kind::GpioIn { pin } => Some(bool_num(hal.gpio_read(*pin))),
            Kind::GpioOut { src, pin } => {
                // NaN compares false: the pin goes low.
                let high = at(values, *src) >= N::HALF;
                hal.gpio_write(*pin, high);
                Some(bool_num(high))
            }
            Kind::Infile {
                stream,
                len,
                cursor,
            } => match stream_id(streams, *stream) {
                Some(id) if *len > 0 => {
                    let v = N::from_f64(hal.input_sample(id, *cursor));
                    // The cursor stays below `len` (it starts at 0): wrap without a division.
                    *cursor = if *cursor + 1 >= *len { 0 } else { *cursor + 1 };
                    Some(v)
                }
                _ => Some(old),
            },
            Kind::Log { src, stream } => {
                let x = at(values, *src);
                if let Some(id) = stream_id(streams, *stream) {
                    let mut buf = [0u8; 48];
                    let mut w = BufWriter::new(&mut buf);
                    if write!(w, "{}", crate::num::Compact(x)).is_ok() {
                        hal.write_log(id, w.as_str());
                    }
                }
                Some(x)
            }
            _ => Some(old),
        };
        values[i] = match value {
            Some(v) => v,
            None => {
                if let Some(task) = &mut sym.task {
                    task.held = task.held.saturating_add(1);
                }
                old
            }
        };
        if let Some((v, x)) = volts_update {
            if syms.get(v).is_some_and(|s| s.is_some()) {
                values[v] = x;
            }
        }
    }

    /// Volts of a raw code (thesis: `[0, vref]` single-ended, `[-vref/2, vref/2]` differential).
    pub(crate) fn volts(input: AdcInput, raw: u16, hal: &impl Hal) -> N {
        let vref = N::from_f64(hal.adc_reference_volts() as f64);
        let fs = N::from_u32(hal.adc_full_scale().max(1) as u32);
        let v = N::from_u32(raw as u32) * vref / fs;
        match input {
            AdcInput::Differential(_) => v - vref.halve(), // = vref / 2, exactly
            _ => v,
        }
    }
}

/// One update of a PID with finite error and gains (the trapezoid and two-point methods of
/// `defint`/`defdiff`); with limits the output is clamped and the integral stops at the limit.
/// `None` if a part overflows: the caller holds the output.
#[allow(clippy::too_many_arguments)]
#[inline]
fn pid_step<N: Real>(
    t: u64,
    e: N,
    kp: N,
    ki: N,
    kd: N,
    limits: Option<(N, N)>,
    int: &mut crate::symbol::Trapezoid<N>,
    der: &mut crate::symbol::TwoPoint<N>,
) -> Option<N> {
    let before = int.acc;
    let i_term = int.step(t, e)?;
    let d_term = der.step(t, e)?;
    let u = kp * e + ki * i_term + kd * d_term;
    let out = match limits {
        None => u,
        Some((lo, hi)) => {
            // Conditional integration: a step that would push the output further into
            // saturation only goes as far as the limit (never past the value before the step,
            // so it neither winds up nor unwinds by itself).
            let limit = if u > hi && e * ki > N::ZERO {
                Some(hi)
            } else if u < lo && e * ki < N::ZERO {
                Some(lo)
            } else {
                None
            };
            if let Some(limit) = limit {
                let target = (limit - kp * e - kd * d_term) / ki;
                let (a, b) = if before <= i_term {
                    (before, i_term)
                } else {
                    (i_term, before)
                };
                int.acc = clamp(target, a, b);
            }
            clamp(kp * e + ki * int.acc + kd * d_term, lo, hi)
        }
    };
    out.is_finite().then_some(out)
}

#[inline]
fn bool_num<N: Real>(b: bool) -> N {
    if b {
        N::ONE
    } else {
        N::ZERO
    }
}
