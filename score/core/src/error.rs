//! Typed errors of the command language. Each names the offending token and what was expected;
//! a command that returns an error has changed nothing.

use core::fmt::{self, Write as _};

use crate::capacity::MAX_NAME_LEN;
use crate::hal::HalError;
use crate::text::ShortStr;

/// A token quoted in an error message: its text (cut to 24 bytes, ending in `~` if cut;
/// invisible characters such as a byte-order mark or a zero-width space written as `\u{feff}`),
/// and where it was in the command line, so that [`Error::column`] can point at it.
#[derive(Debug, Clone, Copy, Default)]
pub struct Token {
    text: ShortStr<24>,
    /// Address of the token's first byte (compared with the line's bytes by `column`; the
    /// token may come from elsewhere, then it matches no line).
    at: usize,
}

impl Token {
    /// The token `s` (usually a slice of the command line), escaped and cut as needed.
    pub fn truncated(s: &str) -> Self {
        let text = if s.chars().any(invisible) {
            let mut buf = [0u8; 48];
            let mut w = crate::text::BufWriter::new(&mut buf);
            for c in s.chars() {
                let r = if invisible(c) {
                    write!(w, "\\u{{{:x}}}", c as u32)
                } else {
                    w.write_char(c)
                };
                if r.is_err() {
                    break;
                }
            }
            ShortStr::truncated(w.as_str())
        } else {
            ShortStr::truncated(s)
        };
        Token {
            text,
            at: s.as_ptr() as usize,
        }
    }

    /// The text as quoted in messages.
    pub fn as_str(&self) -> &str {
        self.text.as_str()
    }

    /// Byte offset of this token in `line`, if it was taken from it.
    pub fn offset_in(&self, line: &str) -> Option<usize> {
        let start = line.as_ptr() as usize;
        (self.at >= start && self.at < start + line.len()).then(|| self.at - start)
    }
}

/// Characters that print as nothing or move the cursor: control characters and the Unicode
/// format characters a text editor may leave in a file (soft hyphen, zero-width spaces and
/// joiners, direction marks, word joiner, byte-order mark).
fn invisible(c: char) -> bool {
    c.is_control()
        || matches!(c, '\u{ad}' | '\u{200b}'..='\u{200f}' | '\u{2028}'..='\u{202e}'
            | '\u{2060}'..='\u{2064}' | '\u{feff}')
}

impl PartialEq for Token {
    /// Two tokens are equal if their texts are (wherever they came from).
    fn eq(&self, other: &Self) -> bool {
        self.text == other.text
    }
}

impl Eq for Token {}

impl fmt::Display for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}
/// A symbol name.
pub type Name = ShortStr<MAX_NAME_LEN>;

/// Up to four names, plus how many more there were (for "used by ..." messages).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct NameList {
    names: [Name; 4],
    shown: u8,
    total: u16,
}

impl NameList {
    /// Adds a name (only the first four are kept; all are counted).
    pub fn push(&mut self, name: &str) {
        if (self.shown as usize) < self.names.len() {
            self.names[self.shown as usize] = Name::truncated(name);
            self.shown += 1;
        }
        self.total = self.total.saturating_add(1);
    }

    /// The names kept.
    pub fn iter(&self) -> impl Iterator<Item = &str> {
        self.names[..self.shown as usize].iter().map(|n| n.as_str())
    }

    /// How many names were pushed.
    pub fn total(&self) -> usize {
        self.total as usize
    }
}

impl fmt::Display for NameList {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, n) in self.iter().enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            f.write_str(n)?;
        }
        let more = self.total as usize - self.shown as usize;
        if more > 0 {
            write!(f, " and {more} more")?;
        }
        Ok(())
    }
}

/// Why a command line was refused.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum Error {
    /// The first word is not a command.
    #[error("unknown command '{token}' (type 'help' for the list of commands)")]
    UnknownCommand {
        /// The word.
        token: Token,
    },
    /// An argument is missing.
    #[error("{command}: missing {expected} (usage: {usage})")]
    Missing {
        /// Command name.
        command: &'static str,
        /// What should have come.
        expected: &'static str,
        /// The command's synopsis.
        usage: &'static str,
    },
    /// More arguments than the command takes.
    #[error("{command}: unexpected '{token}' after the last argument (usage: {usage})")]
    Extra {
        /// Command name.
        command: &'static str,
        /// First surplus token.
        token: Token,
        /// The command's synopsis.
        usage: &'static str,
    },
    /// An argument has the wrong form or is out of range.
    #[error("{command}: '{token}' is not {expected}")]
    Invalid {
        /// Command name.
        command: &'static str,
        /// The argument.
        token: Token,
        /// What was expected.
        expected: &'static str,
    },
    /// A postfix expression is malformed.
    #[error("{command}: in the expression at '{token}': {problem}")]
    Expression {
        /// Command name.
        command: &'static str,
        /// Token where the problem shows.
        token: Token,
        /// What is wrong.
        problem: &'static str,
    },
    /// No such variable.
    #[error("{command}: no variable named '{token}' (type 'printvars' to list them)")]
    UnknownVariable {
        /// Command name.
        command: &'static str,
        /// The name.
        token: Token,
    },
    /// The definition would make a variable depend on itself through bare expressions.
    #[error(
        "{command}: '{name}' would depend on itself through '{via}' (a loop must pass through a \
         periodic block such as defint, defwind, defdiff or deflpf)"
    )]
    Cycle {
        /// Command name.
        command: &'static str,
        /// The variable being defined.
        name: Name,
        /// Its input that leads back to it.
        via: Name,
    },
    /// `del` of a variable that others use.
    #[error("del: cannot delete '{name}': it is used by {users} (delete or redefine those first)")]
    InUse {
        /// The variable.
        name: Name,
        /// Its users.
        users: NameList,
    },
    /// The name belongs to a variable of another kind that this command may not replace.
    #[error("{command}: '{name}' is {what}; choose another name or 'del {name}' first")]
    NameTaken {
        /// Command name.
        command: &'static str,
        /// The name.
        name: Name,
        /// What the existing variable is.
        what: &'static str,
    },
    /// The hardware output or pin is driven by another variable.
    #[error("{command}: '{token}' is already driven by '{owner}' ('del {owner}' first)")]
    Busy {
        /// Command name.
        command: &'static str,
        /// The output/pin argument.
        token: Token,
        /// The variable that drives it.
        owner: Name,
    },
    /// `set` on a variable that is computed, not stored.
    #[error(
        "set: '{name}' is {what} and cannot be set (constants, pwm duties and integrators can)"
    )]
    NotWritable {
        /// The variable.
        name: Name,
        /// Its kind.
        what: &'static str,
    },
    /// A compile-time capacity would be exceeded.
    #[error("{command}: no room: {what} (capacity {capacity}; see 'capacities')")]
    Full {
        /// Command name.
        command: &'static str,
        /// Which table is full.
        what: &'static str,
        /// Its capacity.
        capacity: usize,
    },
    /// The port cannot do this.
    #[error("{command}: not available on this port ({what})")]
    Unsupported {
        /// Command name.
        command: &'static str,
        /// What is missing.
        what: &'static str,
    },
    /// No such channel or output on this board.
    #[error("{command}: '{token}' is not {what} of this board (expected {range})")]
    Channel {
        /// Command name.
        command: &'static str,
        /// The argument.
        token: Token,
        /// "an ADC channel" / "a PWM output".
        what: &'static str,
        /// What the board has.
        range: ChannelRange,
    },
    /// The hardware refused the configuration.
    #[error("{command}: '{token}' refused by the hardware: {error}")]
    Hardware {
        /// Command name.
        command: &'static str,
        /// The argument concerned.
        token: Token,
        /// The HAL's reason.
        error: HalError,
    },
}

impl Error {
    /// The token the message quotes, if it names one from the command line.
    pub fn token(&self) -> Option<&Token> {
        match self {
            Error::UnknownCommand { token }
            | Error::Extra { token, .. }
            | Error::Invalid { token, .. }
            | Error::Expression { token, .. }
            | Error::UnknownVariable { token, .. }
            | Error::Busy { token, .. }
            | Error::Channel { token, .. }
            | Error::Hardware { token, .. } => Some(token),
            _ => None,
        }
    }

    /// The 1-based column (in characters) of `line` that this error, returned by
    /// [`crate::Engine::execute`] for that same `line`, is about: the token it quotes; for a
    /// missing argument, just past the last token; otherwise the command word. `None` for a
    /// blank line or a line this error did not come from.
    pub fn column(&self, line: &str) -> Option<usize> {
        let offset = match self.token().and_then(|t| t.offset_in(line)) {
            Some(o) => o,
            None => {
                let tokens = crate::lexer::Tokens::split(line).ok()?;
                let toks = tokens.as_slice();
                let word = match self {
                    Error::Missing { .. } => toks.last()?,
                    _ => toks.first()?,
                };
                let o = word.as_ptr() as usize - line.as_ptr() as usize;
                match self {
                    Error::Missing { .. } => o + word.len() + 1,
                    _ => o,
                }
            }
        };
        let offset = offset.min(line.len() + 1);
        let before = line.get(..offset.min(line.len())).unwrap_or(line);
        Some(before.chars().count() + 1 + offset.saturating_sub(line.len()))
    }
}

/// Shorthand for the engine's results.
pub type Result<T, E = Error> = core::result::Result<T, E>;

pub(crate) fn tok(s: &str) -> Token {
    Token::truncated(s)
}

pub(crate) fn name(s: &str) -> Name {
    Name::truncated(s)
}

/// The channels a board has, for error messages ("0-3, A-B or T").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelRange {
    singles: u8,
    pairs: u8,
    temperature: bool,
}

impl ChannelRange {
    /// `singles` numbered channels, `pairs` lettered pairs, and maybe a temperature sensor.
    pub fn new(singles: u8, pairs: u8, temperature: bool) -> Self {
        Self {
            singles,
            pairs: pairs.min(26),
            temperature,
        }
    }
    /// Numbered channels.
    pub fn singles(&self) -> u8 {
        self.singles
    }
    /// Lettered pairs.
    pub fn pairs(&self) -> u8 {
        self.pairs
    }
    /// Temperature sensor present.
    pub fn temperature(&self) -> bool {
        self.temperature
    }
}

impl fmt::Display for ChannelRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // "0-3, A-B or T", or any part of it; "none" for a board without any.
        let mut any = false;
        if self.singles > 0 {
            write!(f, "0-{}", self.singles - 1)?;
            any = true;
        }
        if self.pairs > 0 {
            let sep = if any { ", " } else { "" };
            write!(f, "{sep}A-{}", (b'A' + self.pairs - 1) as char)?;
            any = true;
        }
        if self.temperature {
            f.write_str(if any { " or T" } else { "T" })?;
            any = true;
        }
        if !any {
            f.write_str("none")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::fmt::Write;

    #[test]
    fn channel_ranges_list_what_exists() {
        for (r, text) in [
            (ChannelRange::new(4, 2, true), "0-3, A-B or T"),
            (ChannelRange::new(8, 4, false), "0-7, A-D"),
            (ChannelRange::new(0, 2, true), "A-B or T"),
            (ChannelRange::new(0, 0, true), "T"),
            (ChannelRange::new(0, 0, false), "none"),
        ] {
            let mut buf = [0u8; 32];
            let mut w = crate::text::BufWriter::new(&mut buf);
            write!(w, "{r}").unwrap();
            assert_eq!(w.as_str(), text);
        }
    }
}
