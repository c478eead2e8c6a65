//! Text the engine prints: `printvars`, the expression tree echo of `defexp`, `show`, and
//! `save` (the configuration as the minimal command script that recreates the table).

use core::fmt::{self, Write};

use crate::capacity::{MAX_EXPR_TOKENS, MAX_SYMBOLS};
use crate::engine::Engine;
use crate::expr::{op_word, un_word, Op};
use crate::hal::{AdcInput, PwmOutput};
use crate::num::{Compact, Real};
use crate::program::tokens;
use crate::symbol::{Kind, Operand};
use crate::VarId;

/// A rate in millihertz as Hz text (`100`, `0.5`).
pub(crate) struct Hz(pub u32);

impl fmt::Display for Hz {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (whole, frac) = (self.0 / 1000, self.0 % 1000);
        if frac == 0 {
            write!(f, "{whole}")
        } else {
            let mut digits = frac;
            let mut width = 3;
            while digits % 10 == 0 {
                digits /= 10;
                width -= 1;
            }
            write!(f, "{whole}.{digits:0width$}")
        }
    }
}

struct Chan(AdcInput);

impl fmt::Display for Chan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            AdcInput::Single(n) => write!(f, "{n}"),
            AdcInput::Differential(k) => write!(f, "{}", (b'A' + k) as char),
            AdcInput::Temperature => f.write_str("T"),
        }
    }
}

struct Out(PwmOutput);

impl fmt::Display for Out {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            PwmOutput::Single(n) => write!(f, "{n}"),
            PwmOutput::Complementary(k) => write!(f, "{}", (b'A' + k) as char),
        }
    }
}

impl<N: Real> Engine<N> {
    fn write_operand(&self, out: &mut dyn Write, o: Operand<N>) -> fmt::Result {
        match o {
            Operand::Lit(v) => write!(out, "{}", Compact(v)),
            Operand::Var(id) => out.write_str(self.name_of(id)),
        }
    }

    /// Prints `name - value` (thesis format, six decimals).
    pub(crate) fn print_var(&mut self, id: VarId, out: &mut impl Write) {
        let Some(v) = self.value(id) else { return };
        let Some(sym) = self.sym(id) else { return };
        let _ = match sym.kind {
            Kind::Placeholder => writeln!(out, "{} - undefined", sym.name),
            _ => writeln!(out, "{} - {:.6}", sym.name, v),
        };
    }

    /// `printvars`: every variable in ASCII order of names.
    pub(crate) fn print_vars(&mut self, out: &mut impl Write) {
        let (ids, n) = self.sorted_ids();
        let _ = writeln!(out);
        for &i in &ids[..n] {
            self.print_var(VarId(i), out);
        }
    }

    /// The `defexp` echo: the expression tree in pre-order, one node per line, children
    /// indented (thesis Fig. 5.25 prints `-`, `adca`, `1.000000` for `adca 1 -`).
    pub(crate) fn write_tree(&self, id: VarId, out: &mut impl Write) {
        let Some(sym) = self.sym(id) else { return };
        let (start, len) = match sym.kind {
            Kind::Expr { start, len } => (start as usize, len as usize),
            Kind::Const => {
                let _ = writeln!(out, "{:.6}", self.values[id.0 as usize]);
                return;
            }
            _ => return,
        };
        let mut ops = [Op::Lit(N::ZERO); MAX_EXPR_TOKENS];
        let mut n = 0;
        for (slot, op) in ops.iter_mut().zip(tokens(&self.ops[start..start + len])) {
            *slot = op;
            n += 1;
        }
        let ops = &ops[..n];
        let mut kids = [[usize::MAX; 2]; MAX_EXPR_TOKENS];
        let mut stack = [0usize; MAX_EXPR_TOKENS];
        let mut sp = 0;
        for (i, op) in ops.iter().enumerate() {
            let arity = match op {
                Op::Lit(_) | Op::Var(_) => 0,
                Op::Un(_) => 1,
                Op::Bin(_) => 2,
            };
            if sp < arity {
                return;
            }
            for k in (0..arity).rev() {
                sp -= 1;
                kids[i][k] = stack[sp];
            }
            stack[sp] = i;
            sp += 1;
        }
        if sp != 1 {
            return;
        }
        // Pre-order walk with an explicit stack of (node, depth).
        let mut todo = [(0usize, 0usize); MAX_EXPR_TOKENS];
        let mut top = 1;
        todo[0] = (stack[0], 0);
        while top > 0 {
            top -= 1;
            let (node, depth) = todo[top];
            let _ = write!(out, "{:width$}", "", width = 2 * depth);
            let _ = match ops[node] {
                Op::Lit(v) => writeln!(out, "{v:.6}"),
                Op::Var(v) => writeln!(out, "{}", self.name_of(v)),
                Op::Bin(b) => writeln!(out, "{}", op_word(b)),
                Op::Un(u) => writeln!(out, "{}", un_word(u)),
            };
            for k in (0..2).rev() {
                let c = kids[node][k];
                if c != usize::MAX && top < MAX_EXPR_TOKENS {
                    todo[top] = (c, depth + 1);
                    top += 1;
                }
            }
        }
    }

    /// Writes the command line that recreates variable `id` (none for placeholders and the
    /// volts half of an ADC pair). Returns whether a line was written.
    pub(crate) fn write_definition(
        &self,
        id: VarId,
        out: &mut dyn Write,
    ) -> Result<bool, fmt::Error> {
        let Some(sym) = self.sym(id) else {
            return Ok(false);
        };
        let name = sym.name.as_str();
        let rate = Hz(sym.task.map_or(0, |t| t.mhz));
        match sym.kind {
            Kind::Placeholder | Kind::AdcVolts { .. } => return Ok(false),
            Kind::Const => write!(out, "defexp {name} {}", Compact(self.values[id.0 as usize]))?,
            Kind::Expr { start, len } => {
                write!(out, "defexp {name}")?;
                for op in tokens(&self.ops[start as usize..(start + len) as usize]) {
                    match op {
                        Op::Lit(v) => write!(out, " {}", Compact(v))?,
                        Op::Var(v) => write!(out, " {}", self.name_of(v))?,
                        Op::Bin(b) => write!(out, " {}", op_word(b))?,
                        Op::Un(u) => write!(out, " {}", un_word(u))?,
                    }
                }
            }
            Kind::Scale { src, a, b, c, d } => {
                let (a, b, c, d) = (Compact(a), Compact(b), Compact(c), Compact(d));
                write!(out, "defscale {name} {} {a} {b} {c} {d}", self.name_of(src))?
            }
            Kind::Sat { src, lo, hi } => {
                write!(out, "defsat {name} {} {lo} {hi}", self.name_of(src))?
            }
            Kind::Int { src, .. } => write!(out, "defint {name} {} {rate}", self.name_of(src))?,
            Kind::Diff { src, .. } => write!(out, "defdiff {name} {} {rate}", self.name_of(src))?,
            Kind::Wind {
                src,
                gain,
                pre,
                post,
                ..
            } => write!(
                out,
                "defwind {name} {} {rate} {} {} {}",
                self.name_of(src),
                Compact(gain),
                self.name_of(pre),
                self.name_of(post)
            )?,
            Kind::Lpf { src, cutoff_hz, .. } => write!(
                out,
                "deflpf {name} {} {rate} {cutoff_hz}",
                self.name_of(src)
            )?,
            Kind::Pid {
                src,
                kp,
                ki,
                kd,
                limits,
                ..
            } => {
                write!(out, "defpid {name} {} {rate}", self.name_of(src))?;
                for o in [kp, ki, kd] {
                    out.write_char(' ')?;
                    self.write_operand(out, o)?;
                }
                if let Some((lo, hi)) = limits {
                    write!(out, " {} {}", Compact(lo), Compact(hi))?;
                }
            }
            Kind::AdcRaw { input, .. } => write!(out, "adc {} {rate}", Chan(input))?,
            Kind::PwmFixed { out: o, freq } => write!(
                out,
                "pwm {} {freq} {}",
                Out(o),
                Compact(self.values[id.0 as usize])
            )?,
            Kind::PwmFollow { src, out: o, freq } => write!(
                out,
                "defpwm {name} {} {rate} {} {freq}",
                self.name_of(src),
                Out(o)
            )?,
            Kind::GpioIn { pin } => write!(out, "gpio {pin} {rate}")?,
            Kind::GpioOut { src, pin } => {
                write!(out, "defgpio {name} {} {rate} {pin}", self.name_of(src))?
            }
            Kind::Infile { stream, .. } => {
                let path = self.streams[stream as usize]
                    .map(|s| s.path)
                    .unwrap_or_default();
                write!(out, "infile {name} {rate} {path}")?
            }
            Kind::Log { src, stream } => {
                let path = self.streams[stream as usize]
                    .map(|s| s.path)
                    .unwrap_or_default();
                write!(out, "log {name} {} {rate} {path}", self.name_of(src))?
            }
        }
        Ok(true)
    }

    /// Writes the configuration as a command script: running it on an empty table recreates
    /// this table (constants and pwm duties with their current values; block states start
    /// afresh). Hardware first, then the variables menu, then definitions, then files.
    pub fn save(&self, out: &mut dyn Write) -> fmt::Result {
        let group = |k: &Kind<N>| match k {
            Kind::AdcRaw { .. } | Kind::PwmFixed { .. } | Kind::GpioIn { .. } => 0,
            Kind::Const => 1,
            Kind::Infile { .. } | Kind::Log { .. } => 3,
            _ => 2,
        };
        writeln!(out, "# Score configuration ({} variables)", self.len())?;
        for g in 0..4 {
            if g == 1 {
                writeln!(out, "var")?;
            }
            for i in 0..MAX_SYMBOLS {
                let Some(s) = &self.syms[i] else { continue };
                if group(&s.kind) == g && self.write_definition(VarId(i as u8), out)? {
                    writeln!(out)?;
                }
            }
        }
        Ok(())
    }

    /// `show`: definition, kind, rate, missed updates and users.
    pub(crate) fn show(&mut self, id: VarId, out: &mut impl Write) {
        let mut line = [0u8; 160];
        let mut w = crate::text::BufWriter::new(&mut line);
        let _ = self.write_definition(id, &mut w);
        let _ = writeln!(out, "{}", w.as_str());
        let Some(sym) = self.sym(id).copied() else {
            return;
        };
        let _ = write!(out, "{}: {}", sym.name, sym.kind.what());
        if let Some(t) = sym.task {
            let _ = write!(
                out,
                ", updated at {} Hz, {} updates missed",
                Hz(t.mhz),
                t.missed
            );
            if t.held > 0 {
                let _ = write!(out, ", {} held (input not finite)", t.held);
            }
        } else if sym.kind.is_lazy() {
            let _ = write!(out, ", evaluated on demand");
        }
        let mut first = true;
        self.users(id, |u| {
            let _ = write!(
                out,
                "{}{}",
                if first { "; used by " } else { ", " },
                self.name_of(u)
            );
            first = false;
        });
        let _ = writeln!(out);
        self.print_var(id, out);
    }
}
