//! Splits a command line into tokens.
//!
//! Tolerances that let the thesis' transcripts run unchanged: a leading `$>` prompt is skipped;
//! a token starting with `(` begins a comment (the thesis annotates `$> adc 0 100 (set adc 0 to
//! 100Hz)`), as does `#`; the typographic minus `−` and asterisk `∗` of the printed scripts are
//! read as `-` and `*` (see [`normalize`]). A UTF-8 byte-order mark at the start of a line (the
//! first line of a file saved by some editors) is skipped.

use crate::capacity::MAX_TOKENS;
use crate::error::{tok, Error, Result};

/// The tokens of one line.
pub(crate) struct Tokens<'a> {
    items: [&'a str; MAX_TOKENS],
    len: usize,
}

impl<'a> Tokens<'a> {
    pub(crate) fn split(line: &'a str) -> Result<Self> {
        // A byte-order mark (an editor's first character of a UTF-8 file) is not text.
        let line = line.strip_prefix('\u{feff}').unwrap_or(line);
        let mut t = Tokens {
            items: [""; MAX_TOKENS],
            len: 0,
        };
        for (i, word) in line.split_whitespace().enumerate() {
            if word.starts_with('#') || word.starts_with('(') {
                break;
            }
            if i == 0 && word == "$>" {
                continue;
            }
            if t.len == MAX_TOKENS {
                return Err(Error::Invalid {
                    command: "line",
                    token: tok(word),
                    expected: "within the limit of tokens per line (see 'capacities')",
                });
            }
            t.items[t.len] = word;
            t.len += 1;
        }
        Ok(t)
    }

    pub(crate) fn as_slice(&self) -> &[&'a str] {
        &self.items[..self.len]
    }
}

/// Maps the typographic `−` (U+2212) and `∗` (U+2217) of the printed thesis to ASCII, for
/// operator tokens; numbers handle a leading `−` in [`parse_number`].
pub(crate) fn normalize(token: &str) -> &str {
    match token {
        "\u{2212}" => "-",
        "\u{2217}" => "*",
        t => t,
    }
}

/// Parses a finite number, also with a leading typographic minus.
pub(crate) fn parse_number<N: crate::Real>(token: &str) -> Option<N> {
    match token.strip_prefix('\u{2212}') {
        Some(rest) if !rest.starts_with(['-', '+']) => N::parse_finite(rest).map(|v| -v),
        Some(_) => None,
        None => N::parse_finite(token),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn comments_prompt_and_unicode() {
        let t = Tokens::split("$> adc 0 100 (set adc 0 to 100Hz)").unwrap();
        assert_eq!(t.as_slice(), ["adc", "0", "100"]);
        let t = Tokens::split("  defexp x 1 # note").unwrap();
        assert_eq!(t.as_slice(), ["defexp", "x", "1"]);
        assert_eq!(parse_number::<f64>("\u{2212}1.5"), Some(-1.5));
        assert_eq!(parse_number::<f64>("\u{2212}.5"), Some(-0.5));
        assert_eq!(parse_number::<f64>("\u{2212}-1"), None);
        assert_eq!(normalize("\u{2217}"), "*");
    }
}
