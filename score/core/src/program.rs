//! Compiled expressions: the form in which `defexp` expressions are stored and evaluated.
//!
//! A postfix expression is compiled once, at definition, into instructions that keep the top of
//! the stack in a register (`acc`) and fuse an operand with the binary operator that consumes
//! it: `Pterm Iterm + Dterm +` becomes `load Pterm; add Iterm; add Dterm`, three dispatches
//! and no stack traffic instead of five pushes and pops. Every instruction stands for one or two
//! tokens, in order, so the tokens (for `save`, `show` and the tree echo) are recovered exactly
//! by [`tokens`], and the same floating-point operations run in the same order as on the
//! postfix stack: the results are the same bits.

use crate::capacity::MAX_EXPR_TOKENS;
use crate::expr::{BinOp, Op, UnOp};
use crate::num::Real;
use crate::VarId;

/// One compiled step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Instr<N> {
    /// `acc = x` (the expression's first token, a variable).
    LoadVar(VarId),
    /// `acc = x` (the first token, a number).
    LoadLit(N),
    /// Push `acc`; `acc = x` (an operand that a later operator consumes).
    PushVar(VarId),
    /// Push `acc`; `acc = x`.
    PushLit(N),
    /// `acc = acc op x` (an operand directly followed by its binary operator: two tokens).
    BinVar(BinOp, VarId),
    /// `acc = acc op x` (two tokens).
    BinLit(BinOp, N),
    /// `acc = pop() op acc`.
    BinPop(BinOp),
    /// `acc = op(acc)`.
    Un(UnOp),
}

impl<N> Default for Instr<N> {
    fn default() -> Self {
        Instr::BinPop(BinOp::Add)
    }
}

impl<N: Copy> Instr<N> {
    /// How many source tokens this instruction stands for.
    pub fn tokens(&self) -> usize {
        match self {
            Instr::BinVar(..) | Instr::BinLit(..) => 2,
            _ => 1,
        }
    }

    /// The variable this instruction reads, if any.
    pub fn var(&self) -> Option<VarId> {
        match *self {
            Instr::LoadVar(v) | Instr::PushVar(v) | Instr::BinVar(_, v) => Some(v),
            _ => None,
        }
    }
}

/// Source tokens of compiled code.
pub(crate) fn tokens_in<N: Copy>(code: &[Instr<N>]) -> usize {
    code.iter().map(Instr::tokens).sum()
}

/// Compiles validated postfix tokens into `out`; returns the number of instructions (at most
/// the number of tokens, so `out` as long as `tokens` always suffices).
pub(crate) fn compile<N: Copy>(tokens: &[Op<N>], out: &mut [Instr<N>]) -> usize {
    let mut n = 0;
    let mut i = 0;
    while i < tokens.len() && n < out.len() {
        let next_bin = match tokens.get(i + 1) {
            Some(Op::Bin(b)) if i > 0 => Some(*b),
            _ => None,
        };
        let (instr, used) = match (tokens[i], next_bin) {
            (Op::Var(v), _) if i == 0 => (Instr::LoadVar(v), 1),
            (Op::Lit(x), _) if i == 0 => (Instr::LoadLit(x), 1),
            (Op::Var(v), Some(b)) => (Instr::BinVar(b, v), 2),
            (Op::Lit(x), Some(b)) => (Instr::BinLit(b, x), 2),
            (Op::Var(v), None) => (Instr::PushVar(v), 1),
            (Op::Lit(x), None) => (Instr::PushLit(x), 1),
            (Op::Bin(b), _) => (Instr::BinPop(b), 1),
            (Op::Un(u), _) => (Instr::Un(u), 1),
        };
        out[n] = instr;
        n += 1;
        i += used;
    }
    n
}

/// The postfix tokens `code` was compiled from, in order.
pub(crate) fn tokens<N: Copy>(code: &[Instr<N>]) -> impl Iterator<Item = Op<N>> + '_ {
    code.iter().flat_map(|i| {
        let (a, b) = match *i {
            Instr::LoadVar(v) | Instr::PushVar(v) => (Op::Var(v), None),
            Instr::LoadLit(x) | Instr::PushLit(x) => (Op::Lit(x), None),
            Instr::BinVar(op, v) => (Op::Var(v), Some(Op::Bin(op))),
            Instr::BinLit(op, x) => (Op::Lit(x), Some(Op::Bin(op))),
            Instr::BinPop(op) => (Op::Bin(op), None),
            Instr::Un(u) => (Op::Un(u), None),
        };
        core::iter::once(a).chain(b)
    })
}

/// The evaluation stack, kept in the engine so that an evaluation does not first clear an
/// array of [`MAX_EXPR_TOKENS`] numbers (a memset of up to 256 bytes per expression on a
/// Cortex-M0+). Working memory, not state: nothing in it survives an evaluation, so it takes
/// no part in comparing engines.
#[derive(Clone, Copy)]
pub(crate) struct Stack<N>([N; MAX_EXPR_TOKENS]);

impl<N: Real> Stack<N> {
    pub const fn new() -> Self {
        Stack([N::ZERO; MAX_EXPR_TOKENS])
    }
}

impl<N> PartialEq for Stack<N> {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl<N> core::fmt::Debug for Stack<N> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("Stack")
    }
}

#[inline]
fn apply_bin<N: Real>(op: BinOp, a: N, b: N) -> N {
    match op {
        BinOp::Add => a + b,
        BinOp::Sub => a - b,
        BinOp::Mul => a * b,
        BinOp::Div => a / b,
        BinOp::Min => {
            if b < a {
                b
            } else {
                a
            }
        }
        BinOp::Max => {
            if b > a {
                b
            } else {
                a
            }
        }
    }
}

#[inline]
fn apply_un<N: Real>(op: UnOp, a: N) -> N {
    match op {
        UnOp::Neg => -a,
        UnOp::Abs => a.abs(),
        UnOp::Sqrt => a.sqrt(),
        UnOp::Sin => a.sin(),
        UnOp::Cos => a.cos(),
        UnOp::Exp => a.exp(),
    }
}

/// Evaluates compiled code reading variables from `values` (by slot; a slot out of range reads
/// 0). Code that is not the compilation of a valid expression (impossible: only [`compile`]
/// writes it) yields NaN rather than a panic.
pub(crate) fn eval<N: Real>(code: &[Instr<N>], values: &[N], stack: &mut Stack<N>) -> N {
    let stack = &mut stack.0;
    let var = |v: VarId| values.get(v.0 as usize).copied().unwrap_or(N::ZERO);
    let mut acc = N::NAN;
    let mut sp = 0usize;
    for instr in code {
        acc = match *instr {
            Instr::LoadVar(v) => var(v),
            Instr::LoadLit(x) => x,
            Instr::PushVar(_) | Instr::PushLit(_) if sp >= MAX_EXPR_TOKENS => return N::NAN,
            Instr::PushVar(v) => {
                stack[sp] = acc;
                sp += 1;
                var(v)
            }
            Instr::PushLit(x) => {
                stack[sp] = acc;
                sp += 1;
                x
            }
            Instr::BinVar(op, v) => apply_bin(op, acc, var(v)),
            Instr::BinLit(op, x) => apply_bin(op, acc, x),
            Instr::BinPop(op) => {
                if sp == 0 {
                    return N::NAN;
                }
                sp -= 1;
                apply_bin(op, stack[sp], acc)
            }
            Instr::Un(u) => apply_un(u, acc),
        };
    }
    if sp == 0 {
        acc
    } else {
        N::NAN
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    /// The reference: the postfix stack machine the compiled form replaces.
    fn postfix(tokens: &[Op<f64>], values: &[f64]) -> f64 {
        let mut st = Vec::new();
        for t in tokens {
            match *t {
                Op::Lit(x) => st.push(x),
                Op::Var(v) => st.push(values[v.0 as usize]),
                Op::Un(u) => {
                    let a = st.pop().unwrap();
                    st.push(apply_un(u, a));
                }
                Op::Bin(b) => {
                    let y = st.pop().unwrap();
                    let x = st.pop().unwrap();
                    st.push(apply_bin(b, x, y));
                }
            }
        }
        assert_eq!(st.len(), 1);
        st[0]
    }

    fn check(source: &[Op<f64>], values: &[f64]) -> usize {
        let mut code = [Instr::default(); MAX_EXPR_TOKENS];
        let n = compile(source, &mut code);
        assert!(n <= source.len());
        assert_eq!(tokens_in(&code[..n]), source.len());
        assert_eq!(tokens(&code[..n]).collect::<Vec<_>>(), source);
        let got = eval(&code[..n], values, &mut Stack::new());
        let want = postfix(source, values);
        assert!(
            got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
            "{source:?}: {got} vs {want}"
        );
        n
    }

    #[test]
    fn compiled_code_gives_the_postfix_result_and_tokens_back() {
        use BinOp::*;
        use Op::{Bin, Lit, Un, Var};
        let (a, b, c) = (Var(VarId(0)), Var(VarId(1)), Var(VarId(2)));
        let values = [0.3, -1.7, 2.5];
        // Fig. 5.20: Pterm Iterm + Dterm + is three instructions.
        assert_eq!(check(&[a, b, Bin(Add), c, Bin(Add)], &values), 3);
        assert_eq!(check(&[a], &values), 1);
        assert_eq!(check(&[Lit(2.0), a, Bin(Sub)], &values), 2);
        check(&[a, b, c, Bin(Mul), Bin(Sub)], &values);
        check(
            &[a, b, Bin(Div), c, a, Bin(Max), Bin(Min), Un(UnOp::Abs)],
            &values,
        );
        check(
            &[
                a,
                Un(UnOp::Neg),
                Lit(1.0),
                b,
                Bin(Add),
                Un(UnOp::Sqrt),
                Bin(Mul),
            ],
            &values,
        );
        // The deepest expression of 32 tokens: 16 operands pushed before the first of 15
        // operators, then a unary one.
        let mut deep: Vec<Op<f64>> = (0..16).map(|k| Var(VarId(k % 3))).collect();
        deep.extend((0..15).map(|k| Bin(if k % 2 == 0 { Sub } else { Mul })));
        deep.push(Un(UnOp::Exp));
        assert_eq!(deep.len(), MAX_EXPR_TOKENS);
        check(&deep, &values);
    }

    #[test]
    fn malformed_code_is_nan_not_a_panic() {
        let mut s = Stack::new();
        assert!(eval::<f64>(&[Instr::BinPop(BinOp::Add)], &[], &mut s).is_nan());
        assert!(eval::<f64>(&[Instr::LoadLit(1.0), Instr::PushLit(2.0)], &[], &mut s).is_nan());
        let pushes = [Instr::PushLit(1.0f64); MAX_EXPR_TOKENS + 1];
        assert!(eval(&pushes, &[], &mut s).is_nan());
        // A variable slot out of range reads 0.
        assert_eq!(eval(&[Instr::LoadVar(VarId(9))], &[1.0f64], &mut s), 0.0);
    }
}
