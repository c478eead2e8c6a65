//! Postfix expressions as typed: tokens, validation, operator words. (Compiled and evaluated
//! in [`crate::program`].)

use crate::capacity::{MAX_EXPR_TOKENS, MAX_NAME_LEN};
use crate::error::{tok, Error, Result};
use crate::lexer::{normalize, parse_number};
use crate::num::Real;
use crate::VarId;

/// Binary operators (pop b, pop a, push a op b).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum BinOp {
    Add,
    Sub,
    Mul,
    Div,
    Min,
    Max,
}

/// Unary operators.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum UnOp {
    Neg,
    Abs,
    Sqrt,
    Sin,
    Cos,
    Exp,
}

/// One postfix token, resolved (names to slots, numbers parsed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Op<N> {
    Lit(N),
    Var(VarId),
    Bin(BinOp),
    Un(UnOp),
}

impl<N> Default for Op<N> {
    fn default() -> Self {
        Op::Bin(BinOp::Add)
    }
}

/// What a token of an expression is.
pub(crate) enum Class<'a, N> {
    Lit(N),
    Name(&'a str),
    Bin(BinOp),
    Un(UnOp),
}

pub(crate) fn operator(token: &str) -> Option<Class<'static, ()>> {
    Some(match normalize(token) {
        "+" => Class::Bin(BinOp::Add),
        "-" => Class::Bin(BinOp::Sub),
        "*" => Class::Bin(BinOp::Mul),
        "/" => Class::Bin(BinOp::Div),
        "min" => Class::Bin(BinOp::Min),
        "max" => Class::Bin(BinOp::Max),
        "neg" => Class::Un(UnOp::Neg),
        "abs" => Class::Un(UnOp::Abs),
        "sqrt" => Class::Un(UnOp::Sqrt),
        "sin" => Class::Un(UnOp::Sin),
        "cos" => Class::Un(UnOp::Cos),
        "exp" => Class::Un(UnOp::Exp),
        _ => return None,
    })
}

/// A valid variable name: a letter or `_`, then letters, digits or `_`; not an operator word.
pub(crate) fn is_name(s: &str) -> bool {
    let mut chars = s.chars();
    let first_ok = matches!(chars.next(), Some(c) if c.is_ascii_alphabetic() || c == '_');
    first_ok
        && s.len() <= MAX_NAME_LEN
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
        && operator(s).is_none()
}

pub(crate) fn classify<N: Real>(token: &str) -> Option<Class<'_, N>> {
    if let Some(op) = operator(token) {
        return Some(match op {
            Class::Bin(b) => Class::Bin(b),
            Class::Un(u) => Class::Un(u),
            _ => return None,
        });
    }
    if let Some(v) = parse_number::<N>(token) {
        return Some(Class::Lit(v));
    }
    is_name(token).then_some(Class::Name(token))
}

/// Checks a postfix expression without touching the table: every token known, the stack never
/// underflows, exactly one value remains, length within [`MAX_EXPR_TOKENS`].
pub(crate) fn validate<N: Real>(command: &'static str, tokens: &[&str]) -> Result<()> {
    if tokens.len() > MAX_EXPR_TOKENS {
        return Err(Error::Expression {
            command,
            token: tok(tokens[MAX_EXPR_TOKENS]),
            problem: "too many tokens (see 'capacities')",
        });
    }
    let mut depth = 0usize;
    for t in tokens {
        match classify::<N>(t) {
            None => {
                let problem = if t.len() > MAX_NAME_LEN
                    && t.starts_with(|c: char| c.is_ascii_alphabetic())
                {
                    "names are at most 15 characters"
                } else {
                    "expected a number, a variable name or an operator (+ - * / min max neg abs sqrt sin cos exp)"
                };
                return Err(Error::Expression {
                    command,
                    token: tok(t),
                    problem,
                });
            }
            Some(Class::Lit(_)) | Some(Class::Name(_)) => depth += 1,
            Some(Class::Un(_)) => {
                if depth < 1 {
                    return Err(Error::Expression {
                        command,
                        token: tok(t),
                        problem: "this operator needs one operand before it (postfix: 'x abs')",
                    });
                }
            }
            Some(Class::Bin(_)) => {
                if depth < 2 {
                    return Err(Error::Expression {
                        command,
                        token: tok(t),
                        problem: "this operator needs two operands before it (postfix: 'a b +')",
                    });
                }
                depth -= 1;
            }
        }
    }
    if depth != 1 {
        return Err(Error::Expression {
            command,
            token: tok(tokens.last().copied().unwrap_or("")),
            problem: "the expression must leave exactly one value (operators missing?)",
        });
    }
    Ok(())
}

/// Writes the token text of an op (for `save` and the tree echo).
pub(crate) fn op_word(op: BinOp) -> &'static str {
    match op {
        BinOp::Add => "+",
        BinOp::Sub => "-",
        BinOp::Mul => "*",
        BinOp::Div => "/",
        BinOp::Min => "min",
        BinOp::Max => "max",
    }
}

/// Word of a unary operator.
pub(crate) fn un_word(op: UnOp) -> &'static str {
    match op {
        UnOp::Neg => "neg",
        UnOp::Abs => "abs",
        UnOp::Sqrt => "sqrt",
        UnOp::Sin => "sin",
        UnOp::Cos => "cos",
        UnOp::Exp => "exp",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation() {
        validate::<f64>("defexp", &["a", "1", "\u{2212}"]).unwrap();
        assert!(validate::<f64>("defexp", &["a", "+"]).is_err());
        assert!(validate::<f64>("defexp", &["a", "b"]).is_err());
        assert!(validate::<f64>("defexp", &["a", "$"]).is_err());
    }

    #[test]
    fn names() {
        assert!(is_name("Kp") && is_name("_x1") && is_name("ADC0"));
        assert!(
            !is_name("1a") && !is_name("neg") && !is_name("a-b") && !is_name("abcdefghijklmnop")
        );
    }
}
