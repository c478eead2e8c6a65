//! Variable metadata and access for programs (the USB gateway, tests): enumerate, read, write.

use crate::capacity::MAX_SYMBOLS;
use crate::engine::Engine;
use crate::num::Real;
use crate::symbol::Kind;
use crate::VarId;

/// What a variable is, for a program that lists them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VarKind {
    /// Referenced but not defined yet (reads 0).
    Undefined,
    /// `defexp name <number>`.
    Constant,
    /// `defexp` postfix expression.
    Expression,
    /// `defscale`.
    Scale,
    /// `defsat`.
    Saturation,
    /// `defint`.
    Integral,
    /// `defwind`.
    AntiWindupIntegral,
    /// `defdiff`.
    Derivative,
    /// `deflpf`.
    LowPass,
    /// `defpid`.
    Pid,
    /// `adc`: raw code.
    AdcRaw,
    /// `adc`: volts.
    AdcVolts,
    /// `pwm`: fixed duty.
    Pwm,
    /// `defpwm`: duty following a variable.
    PwmFollow,
    /// `gpio`: input pin.
    GpioIn,
    /// `defgpio`: output pin.
    GpioOut,
    /// `infile`.
    Playback,
    /// `log`.
    Log,
}

/// Metadata of one variable.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VarInfo<'a> {
    /// Stable index: valid until the variable is deleted (slots are then reused; watch
    /// [`Engine::generation`]).
    pub id: VarId,
    /// Name.
    pub name: &'a str,
    /// Kind.
    pub kind: VarKind,
    /// Update rate if periodic (an ADC's volts report the channel's rate).
    pub rate_hz: Option<f64>,
    /// Accepted by [`Engine::set`].
    pub writable: bool,
    /// Unit where the kind implies one: `V` for ADC volts, `count` for raw codes, `%` for PWM
    /// duties, `1` for pin states.
    pub unit: Option<&'static str>,
}

impl<N: Real> Engine<N> {
    /// Metadata of the variable in slot `id`.
    pub fn info(&self, id: VarId) -> Option<VarInfo<'_>> {
        let s = self.sym(id)?;
        let (kind, writable, unit) = match s.kind {
            Kind::Placeholder => (VarKind::Undefined, false, None),
            Kind::Const => (VarKind::Constant, true, None),
            Kind::Expr { .. } => (VarKind::Expression, false, None),
            Kind::Scale { .. } => (VarKind::Scale, false, None),
            Kind::Sat { .. } => (VarKind::Saturation, false, None),
            Kind::Int { .. } => (VarKind::Integral, true, None),
            Kind::Wind { .. } => (VarKind::AntiWindupIntegral, true, None),
            Kind::Diff { .. } => (VarKind::Derivative, false, None),
            Kind::Lpf { .. } => (VarKind::LowPass, false, None),
            Kind::Pid { .. } => (VarKind::Pid, false, None),
            Kind::AdcRaw { .. } => (VarKind::AdcRaw, false, Some("count")),
            Kind::AdcVolts { .. } => (VarKind::AdcVolts, false, Some("V")),
            Kind::PwmFixed { .. } => (VarKind::Pwm, true, Some("%")),
            Kind::PwmFollow { .. } => (VarKind::PwmFollow, false, Some("%")),
            Kind::GpioIn { .. } => (VarKind::GpioIn, false, Some("1")),
            Kind::GpioOut { .. } => (VarKind::GpioOut, false, Some("1")),
            Kind::Infile { .. } => (VarKind::Playback, false, None),
            Kind::Log { .. } => (VarKind::Log, false, None),
        };
        let task = match s.kind {
            Kind::AdcVolts { raw } => self.sym(raw).and_then(|r| r.task),
            _ => s.task,
        };
        Some(VarInfo {
            id,
            name: s.name.as_str(),
            kind,
            rate_hz: task.map(|t| t.mhz as f64 / 1000.0),
            writable,
            unit,
        })
    }

    /// Every variable, in slot order.
    pub fn vars(&self) -> impl Iterator<Item = VarInfo<'_>> + '_ {
        (0..MAX_SYMBOLS).filter_map(move |i| self.info(VarId(i as u8)))
    }

    /// The instant (µs, the time given to [`Engine::tick`]) of the latest update of a periodic
    /// variable; an ADC's volts report the channel's update. `None` for bare expressions and
    /// before the first update. A gateway stamps samples with it, so a value read later still
    /// carries the time it was produced.
    pub fn last_update_us(&self, id: VarId) -> Option<u64> {
        let s = self.sym(id)?;
        let task = match s.kind {
            Kind::AdcVolts { raw } => self.sym(raw).and_then(|r| r.task),
            _ => s.task,
        };
        task.and_then(|t| t.last)
    }

    /// Updates in which the block `id` (`defint`, `defwind`, `defdiff`, `deflpf`, `defpid`)
    /// held its value because its input, a gain, or its result was not finite (NaN or ±inf,
    /// e.g. from a division by zero upstream). The block resumes with the next finite input.
    pub fn held_updates(&self, id: VarId) -> Option<u32> {
        self.sym(id).and_then(|s| s.task).map(|t| t.held)
    }

    /// Updates skipped by the scheduler for `id` because ticks came more than a period late.
    pub fn missed_updates(&self, id: VarId) -> Option<u32> {
        self.sym(id).and_then(|s| s.task).map(|t| t.missed)
    }
}
