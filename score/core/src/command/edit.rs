//! Changing and removing variables: set, del, clear, and releasing what they held.

use core::fmt::Write;

use crate::capacity::MAX_SYMBOLS;
use crate::engine::Engine;
use crate::error::{tok, Error, NameList, Result};
use crate::hal::Hal;
use crate::num::Real;
use crate::symbol::Kind;
use crate::VarId;

use super::hardware::{hardware, Hw};

impl<N: Real> Engine<N> {
    /// Sets a writable variable: a constant, the duty (%) of a `pwm` output, or the accumulated
    /// value of an integral (`defint`/`defwind`). Others are refused with
    /// [`Error::NotWritable`]; the table is unchanged on error.
    pub fn set(&mut self, id: VarId, value: N, hal: &mut impl Hal) -> Result<()> {
        let sym = *self.sym(id).ok_or(Error::UnknownVariable {
            command: "set",
            token: tok("?"),
        })?;
        if !value.is_finite() {
            return Err(Error::Invalid {
                command: "set",
                token: tok("value"),
                expected: "a finite number",
            });
        }
        let mut kind = sym.kind;
        let stored = match &mut kind {
            Kind::Const => value,
            Kind::PwmFixed { out, .. } => {
                if value < N::ZERO || value > N::from_u32(100) {
                    let mut b = [0u8; 24];
                    let mut w = crate::text::BufWriter::new(&mut b);
                    let _ = write!(w, "{value}");
                    return Err(Error::Invalid {
                        command: "set",
                        token: tok(w.as_str()),
                        expected: "a duty cycle in percent (0-100)",
                    });
                }
                let applied = hal.pwm_set_duty(*out, (value.to_f64() / 100.0) as f32);
                N::from_f64(applied as f64 * 100.0)
            }
            Kind::Int { st, .. } | Kind::Wind { st, .. } => {
                st.acc = value;
                value
            }
            k => {
                return Err(Error::NotWritable {
                    name: sym.name,
                    what: k.what(),
                })
            }
        };
        if let Some(s) = &mut self.syms[id.0 as usize] {
            s.kind = kind;
            self.values[id.0 as usize] = stored;
        }
        Ok(())
    }

    /// Deletes a variable (both of an ADC pair), releasing its hardware or file. Refused with
    /// [`Error::InUse`] while other variables read it.
    pub fn delete(&mut self, id: VarId, hal: &mut impl Hal) -> Result<()> {
        let sym = *self.sym(id).ok_or(Error::UnknownVariable {
            command: "del",
            token: tok("?"),
        })?;
        let partner = match sym.kind {
            Kind::AdcRaw { volts, .. } => Some(volts),
            Kind::AdcVolts { raw } => Some(raw),
            _ => None,
        };
        let mut users = NameList::default();
        for who in [Some(id), partner].into_iter().flatten() {
            self.users(who, |u| {
                if Some(u) != partner && u != id {
                    users.push(self.name_of(u));
                }
            });
        }
        if users.total() > 0 {
            return Err(Error::InUse {
                name: sym.name,
                users,
            });
        }
        for who in [Some(id), partner].into_iter().flatten() {
            self.remove(who, hal);
        }
        self.collect_placeholders();
        self.rebuild();
        Ok(())
    }

    /// Deletes every variable, releasing all hardware and files.
    pub fn clear(&mut self, hal: &mut impl Hal) {
        for i in 0..MAX_SYMBOLS {
            self.remove(VarId(i as u8), hal);
        }
        self.rebuild();
    }

    pub(super) fn remove(&mut self, id: VarId, hal: &mut impl Hal) {
        let Some(sym) = self.syms[id.0 as usize] else {
            return;
        };
        if let Kind::Expr { start, len } = sym.kind {
            self.remove_ops(start as usize, len as usize);
        }
        if let Some(hw) = hardware(&sym.kind) {
            self.release(hw, hal);
        }
        self.syms[id.0 as usize] = None;
        self.values[id.0 as usize] = N::ZERO;
    }

    pub(super) fn release(&mut self, hw: Hw, hal: &mut impl Hal) {
        match hw {
            Hw::Adc(input) => hal.adc_release(input),
            Hw::Pwm(out) => hal.pwm_release(out),
            Hw::Pin(pin) => hal.gpio_release(pin),
            Hw::Stream(slot) => {
                if let Some(s) = self.streams.get_mut(slot as usize).and_then(|s| s.take()) {
                    hal.close(s.id);
                }
            }
        }
    }

    pub(super) fn remove_ops(&mut self, start: usize, len: usize) {
        let end = (start + len).min(self.ops_used);
        self.ops.copy_within(end..self.ops_used, start);
        self.ops_used -= end - start;
        for s in self.syms.iter_mut().flatten() {
            if let Kind::Expr { start: st, .. } = &mut s.kind {
                if *st as usize > start {
                    *st -= (end - start) as u16;
                }
            }
        }
    }

    /// Removes placeholders nothing refers to any more.
    pub(super) fn collect_placeholders(&mut self) {
        for i in 0..MAX_SYMBOLS {
            if matches!(self.syms[i].map(|s| s.kind), Some(Kind::Placeholder))
                && !self.has_users(VarId(i as u8))
            {
                self.syms[i] = None;
                self.values[i] = N::ZERO;
            }
        }
    }
}
