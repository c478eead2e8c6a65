//! Definitions: check everything, then commit in one infallible step.

use core::fmt::Write;

use crate::capacity::MAX_SYMBOLS;
use crate::engine::Engine;
use crate::error::{name as mk_name, tok, Error, Result};
use crate::expr::{self, Class, Op};
use crate::hal::Hal;
use crate::lexer::parse_number;
use crate::num::Real;
use crate::program::{self, tokens_in};
use crate::symbol::{Family, Kind, LowPass, Operand, Symbol, Task, Trapezoid, TwoPoint};
use crate::VarId;

use super::args::Args;
use super::hardware::{hardware, Hw};

impl<N: Real> Engine<N> {
    /// Checks that `name` may be (re)defined by a command of `family`; returns its slot if it
    /// exists (a placeholder or a variable of the same family).
    pub(super) fn check_target(
        &self,
        command: &'static str,
        name: &str,
        family: Family,
    ) -> Result<Option<VarId>> {
        let Some(id) = self.lookup(name) else {
            return Ok(None);
        };
        let kind = self.sym(id).map(|s| s.kind).unwrap_or(Kind::Placeholder);
        match kind.family() {
            Family::Placeholder => Ok(Some(id)),
            f if f == family => Ok(Some(id)),
            _ => Err(Error::NameTaken {
                command,
                name: mk_name(name),
                what: kind.what(),
            }),
        }
    }

    /// Capacity and cycle checks for a definition of `name` reading `refs`.
    pub(super) fn check_refs(
        &self,
        command: &'static str,
        name: &str,
        target: Option<VarId>,
        refs: &[&str],
        lazy: bool,
    ) -> Result<()> {
        let mut needed = target.is_none() as usize;
        for (i, r) in refs.iter().enumerate() {
            if *r != name && self.lookup(r).is_none() && !refs[..i].contains(r) {
                needed += 1;
            }
        }
        if self.len() + needed > MAX_SYMBOLS {
            return Err(Error::Full {
                command,
                what: "variables",
                capacity: MAX_SYMBOLS,
            });
        }
        if lazy {
            for r in refs {
                let cyc = *r == name
                    || match (self.lookup(r), target) {
                        (Some(d), Some(x)) => self.view[d.0 as usize].contains(x.0 as usize),
                        _ => false,
                    };
                if cyc {
                    return Err(Error::Cycle {
                        command,
                        name: mk_name(name),
                        via: mk_name(r),
                    });
                }
            }
        }
        Ok(())
    }

    pub(super) fn free_slot(&self) -> Option<usize> {
        self.syms.iter().position(|s| s.is_none())
    }

    /// Creates placeholders for unknown `refs`, puts `kind` (built once all names resolve) in
    /// `name`'s slot, releases what the old definition held, and rebuilds the graph. Infallible:
    /// every check has been done.
    pub(super) fn commit(
        &mut self,
        name: &str,
        refs: &[&str],
        task: Option<u32>,
        value: N,
        hal: &mut impl Hal,
        build: impl FnOnce(&mut Self, VarId) -> Kind<N>,
    ) -> VarId {
        let id = match self.lookup(name) {
            Some(id) => id,
            None => {
                let i = self.free_slot().unwrap_or(MAX_SYMBOLS - 1);
                self.syms[i] = Some(placeholder(name));
                VarId(i as u8)
            }
        };
        for r in refs {
            if self.lookup(r).is_none() {
                if let Some(i) = self.free_slot() {
                    self.syms[i] = Some(placeholder(r));
                }
            }
        }
        let old = self.syms[id.0 as usize]
            .map(|s| s.kind)
            .unwrap_or(Kind::Placeholder);
        if let Kind::Expr { start, len } = old {
            self.remove_ops(start as usize, len as usize);
        }
        let kind = build(self, id);
        if let Some(hw) = hardware(&old) {
            // A new definition on the same (or an overlapping) output has already reconfigured it.
            let superseded = match (hw, hardware(&kind)) {
                (Hw::Pwm(a), Some(Hw::Pwm(b))) => a.overlaps(b),
                (a, b) => Some(a) == b,
            };
            if !superseded {
                self.release(hw, hal);
            }
        }
        self.syms[id.0 as usize] = Some(Symbol {
            name: mk_name(name),
            kind,
            task: task.map(Task::new),
        });
        self.values[id.0 as usize] = value;
        self.collect_placeholders();
        self.rebuild();
        id
    }

    pub(super) fn resolve(&self, name: &str) -> VarId {
        self.lookup(name).unwrap_or(VarId(0))
    }

    pub(super) fn cmd_defexp(
        &mut self,
        a: &mut Args<'_, '_>,
        hal: &mut impl Hal,
        out: &mut impl Write,
    ) -> Result<()> {
        let name = a.name("varname")?;
        let toks = &a.toks[a.pos..];
        if toks.is_empty() {
            return Err(Error::Missing {
                command: "defexp",
                expected: "a postfix expression",
                usage: a.usage,
            });
        }
        expr::validate::<N>("defexp", toks)?;
        let target = self.check_target("defexp", name, Family::Def)?;
        let mut refs = [""; crate::capacity::MAX_EXPR_TOKENS];
        let mut nrefs = 0;
        for t in toks {
            if let Some(Class::Name(n)) = expr::classify::<N>(t) {
                refs[nrefs] = n;
                nrefs += 1;
            }
        }
        let refs = &refs[..nrefs];
        let constant = match toks {
            [t] => parse_number::<N>(t),
            _ => None,
        };
        if let Some(v) = constant {
            self.check_refs("defexp", name, target, &[], false)?;
            self.commit(name, &[], None, v, hal, |_, _| Kind::Const);
        } else {
            self.check_refs("defexp", name, target, refs, true)?;
            let old_tokens = match target.and_then(|t| self.sym(t)).map(|s| s.kind) {
                Some(Kind::Expr { start, len }) => {
                    tokens_in(&self.ops[start as usize..(start + len) as usize])
                }
                _ => 0,
            };
            if self.tokens_used() - old_tokens + toks.len() > crate::capacity::MAX_EXPR_OPS {
                return Err(Error::Full {
                    command: "defexp",
                    what: "expression tokens",
                    capacity: crate::capacity::MAX_EXPR_OPS,
                });
            }
            self.commit(name, refs, None, N::ZERO, hal, |e, _| {
                let mut ops = [Op::Lit(N::ZERO); crate::capacity::MAX_EXPR_TOKENS];
                for (op, t) in ops.iter_mut().zip(toks) {
                    *op = match expr::classify::<N>(t) {
                        Some(Class::Lit(v)) => Op::Lit(v),
                        Some(Class::Name(n)) => Op::Var(e.resolve(n)),
                        Some(Class::Bin(b)) => Op::Bin(b),
                        Some(Class::Un(u)) => Op::Un(u),
                        None => Op::Lit(N::ZERO),
                    };
                }
                // At most one instruction per token: the token check above keeps it in room.
                let start = e.ops_used;
                let len = program::compile(&ops[..toks.len()], &mut e.ops[start..]);
                e.ops_used += len;
                Kind::Expr {
                    start: start as u16,
                    len: len as u16,
                }
            });
        }
        if let Some(id) = self.lookup(name) {
            self.write_tree(id, out);
            if let Some(v) = self.value(id).filter(|v| !v.is_finite()) {
                let _ = writeln!(
                    out,
                    "note: '{name}' is {v} now (a division by zero, an overflow, or a function \
                     outside its domain)"
                );
            }
        }
        Ok(())
    }

    pub(super) fn cmd_block(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
        let cmd = a.cmd;
        let name = a.name("varname")?;
        let src = a.name("basename")?;
        let target = self.check_target(cmd, name, Family::Def)?;
        match cmd {
            "defscale" => {
                let lo_in: N = a.number("the lower input bound a")?;
                let t_b = a.toks.get(a.pos).copied().unwrap_or("");
                let hi_in: N = a.number("the upper input bound b")?;
                let lo: N = a.number("the lower output bound c")?;
                let hi: N = a.number("the upper output bound d")?;
                a.end()?;
                if hi_in == lo_in {
                    return Err(Error::Invalid {
                        command: cmd,
                        token: tok(t_b),
                        expected: "an input bound different from a (the interval [a,b] is empty)",
                    });
                }
                self.check_refs(cmd, name, target, &[src], true)?;
                self.commit(name, &[src], None, N::ZERO, hal, |e, _| Kind::Scale {
                    src: e.resolve(src),
                    a: lo_in,
                    b: hi_in,
                    c: lo,
                    d: hi,
                });
            }
            "defsat" => {
                let lo: N = a.number("the lower limit")?;
                let t_hi = a.toks.get(a.pos).copied().unwrap_or("");
                let hi: N = a.number("the upper limit")?;
                a.end()?;
                if hi < lo {
                    return Err(Error::Invalid {
                        command: cmd,
                        token: tok(t_hi),
                        expected: "an upper limit at least the lower limit",
                    });
                }
                self.check_refs(cmd, name, target, &[src], true)?;
                self.commit(name, &[src], None, N::ZERO, hal, |e, _| Kind::Sat {
                    src: e.resolve(src),
                    lo,
                    hi,
                });
            }
            "defint" | "defdiff" => {
                let rate = a.rate("refreshFreq")?;
                a.end()?;
                self.check_refs(cmd, name, target, &[src], false)?;
                let int = cmd == "defint";
                self.commit(name, &[src], Some(rate), N::ZERO, hal, |e, _| {
                    let src = e.resolve(src);
                    if int {
                        Kind::Int {
                            src,
                            st: Trapezoid::default(),
                        }
                    } else {
                        Kind::Diff {
                            src,
                            st: TwoPoint::default(),
                        }
                    }
                });
            }
            "defwind" => {
                let rate = a.rate("refreshFreq")?;
                let gain: N = a.number("the anti-windup gain (a number)")?;
                let pre = a.name("presat (the control before saturation)")?;
                let post = a.name("postsat (the control after saturation)")?;
                a.end()?;
                let refs = [src, pre, post];
                self.check_refs(cmd, name, target, &refs, false)?;
                self.commit(name, &refs, Some(rate), N::ZERO, hal, |e, _| Kind::Wind {
                    src: e.resolve(src),
                    gain,
                    pre: e.resolve(pre),
                    post: e.resolve(post),
                    st: Trapezoid::default(),
                });
            }
            "deflpf" => {
                let rate = a.rate("refreshFreq")?;
                let t = a.toks.get(a.pos).copied().unwrap_or("");
                let fc: N = a.number("the cutoff frequency in Hz")?;
                a.end()?;
                if fc <= N::ZERO {
                    return Err(Error::Invalid {
                        command: cmd,
                        token: tok(t),
                        expected: "a cutoff frequency above 0 Hz",
                    });
                }
                self.check_refs(cmd, name, target, &[src], false)?;
                self.commit(name, &[src], Some(rate), N::ZERO, hal, |e, _| Kind::Lpf {
                    src: e.resolve(src),
                    cutoff_hz: fc,
                    st: LowPass::new(fc),
                });
            }
            _ => {
                // defpid
                let rate = a.rate("refreshFreq")?;
                let kp = a.operand::<N>("kp (a number or variable)")?;
                let ki = a.operand::<N>("ki (a number or variable)")?;
                let kd = a.operand::<N>("kd (a number or variable)")?;
                let limits = match a.remaining() {
                    0 => None,
                    1 => {
                        a.pos += 1;
                        return Err(Error::Missing {
                            command: cmd,
                            expected: "the upper output limit",
                            usage: a.usage,
                        });
                    }
                    _ => {
                        let lo: N = a.number("the lower output limit")?;
                        let t_hi = a.toks.get(a.pos).copied().unwrap_or("");
                        let hi: N = a.number("the upper output limit")?;
                        if hi < lo {
                            return Err(Error::Invalid {
                                command: cmd,
                                token: tok(t_hi),
                                expected: "an upper limit at least the lower limit",
                            });
                        }
                        Some((lo, hi))
                    }
                };
                a.end()?;
                let mut refs = [src, "", "", ""];
                let mut n = 1;
                for (v, t) in [kp, ki, kd] {
                    if v.is_none() {
                        refs[n] = t;
                        n += 1;
                    }
                }
                let refs = &refs[..n];
                self.check_refs(cmd, name, target, refs, false)?;
                self.commit(name, refs, Some(rate), N::ZERO, hal, |e, _| {
                    let op = |(v, t): (Option<N>, &str)| match v {
                        Some(v) => Operand::Lit(v),
                        None => Operand::Var(e.resolve(t)),
                    };
                    Kind::Pid {
                        src: e.resolve(src),
                        kp: op(kp),
                        ki: op(ki),
                        kd: op(kd),
                        limits,
                        int: Trapezoid::default(),
                        der: TwoPoint::default(),
                    }
                });
            }
        }
        Ok(())
    }
}

pub(super) fn placeholder<N: Real>(name: &str) -> Symbol<N> {
    Symbol {
        name: mk_name(name),
        kind: Kind::Placeholder,
        task: None,
    }
}
