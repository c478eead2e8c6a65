//! Diagnostics: one validation error or warning with its file, line, column, key and what was
//! expected.

use std::fmt;
use std::ops::Range;

/// How bad a [`Diagnostic`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Severity {
    /// The manifest cannot be used.
    Error,
    /// The manifest is valid, but probably not what was meant (or close to a limit).
    Warning,
}

/// One problem found in a manifest.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Diagnostic {
    /// Error (the manifest is refused) or warning (it is accepted).
    pub severity: Severity,
    /// The manifest file as given by the caller.
    pub file: String,
    /// 1-based line.
    pub line: usize,
    /// 1-based column, in characters.
    pub column: usize,
    /// Dotted path of the offending key (`subsystems.leg.states.RAR.rate_hz`); empty for syntax
    /// errors that belong to no key.
    pub key: String,
    /// What is wrong and what was expected.
    pub message: String,
}

impl fmt::Display for Diagnostic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}:{}: ", self.file, self.line, self.column)?;
        if self.severity == Severity::Warning {
            f.write_str("warning: ")?;
        }
        if !self.key.is_empty() {
            write!(f, "{}: ", self.key)?;
        }
        f.write_str(&self.message)
    }
}

/// Collects errors and warnings (with byte spans) while a document is validated.
#[derive(Debug, Default)]
pub(crate) struct Diags {
    items: Vec<(usize, Severity, String, String)>,
}

impl Diags {
    /// Records an error at byte offset `span.start` for `key`.
    pub(crate) fn error(&mut self, span: &Range<usize>, key: &str, message: impl Into<String>) {
        self.items
            .push((span.start, Severity::Error, key.to_string(), message.into()));
    }

    /// Records a warning at byte offset `span.start` for `key`.
    pub(crate) fn warning(&mut self, span: &Range<usize>, key: &str, message: impl Into<String>) {
        self.items.push((
            span.start,
            Severity::Warning,
            key.to_string(),
            message.into(),
        ));
    }

    /// Whether any error (not counting warnings) was recorded.
    pub(crate) fn has_errors(&self) -> bool {
        self.items.iter().any(|i| i.1 == Severity::Error)
    }

    /// Resolves offsets to lines and columns, sorted by position (stable for equal positions),
    /// without duplicates.
    pub(crate) fn finish(self, file: &str, source: &str) -> Vec<Diagnostic> {
        let mut items = self.items;
        items.sort_by_key(|(pos, _, _, _)| *pos);
        items.dedup();
        // The positions ascend, so one pass over the source places them all (a scan from the
        // start per diagnostic was quadratic in a file with many errors).
        let mut place = Places::new(source);
        items
            .into_iter()
            .map(|(pos, severity, key, message)| {
                let (line, column) = place.at(pos);
                Diagnostic {
                    severity,
                    file: file.to_string(),
                    line,
                    column,
                    key,
                    message,
                }
            })
            .collect()
    }
}

/// 1-based line and character column of byte offset `pos` (clamped to the source).
pub(crate) fn line_column(source: &str, pos: usize) -> (usize, usize) {
    let mut pos = pos.min(source.len());
    while !source.is_char_boundary(pos) {
        pos -= 1;
    }
    let before = &source[..pos];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    (line, source[line_start..pos].chars().count() + 1)
}

/// [`line_column`] of ascending positions, in one pass over the source.
struct Places<'s> {
    source: &'s str,
    /// Byte offset reached (a character boundary), and its 1-based line and column.
    pos: usize,
    line: usize,
    column: usize,
}

impl<'s> Places<'s> {
    fn new(source: &'s str) -> Self {
        Self {
            source,
            pos: 0,
            line: 1,
            column: 1,
        }
    }

    /// [`line_column`]`(source, pos)`; from where the previous call got to when `pos` is not
    /// before it.
    fn at(&mut self, pos: usize) -> (usize, usize) {
        let mut pos = pos.min(self.source.len());
        while !self.source.is_char_boundary(pos) {
            pos -= 1;
        }
        if pos < self.pos {
            return line_column(self.source, pos);
        }
        for c in self.source[self.pos..pos].chars() {
            if c == '\n' {
                self.line += 1;
                self.column = 1;
            } else {
                self.column += 1;
            }
        }
        self.pos = pos;
        (self.line, self.column)
    }
}

/// Edit distance, for "did you mean" hints on misspelt keys and names.
fn distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut cur = vec![i + 1; b.len() + 1];
        for (j, cb) in b.iter().enumerate() {
            let sub = prev[j] + usize::from(ca != *cb);
            cur[j + 1] = sub.min(prev[j + 1] + 1).min(cur[j] + 1);
        }
        prev = cur;
    }
    prev[b.len()]
}

/// Candidates `word` is plausibly a typo or abbreviation of: every candidate it is a prefix of,
/// else the closest one by edit distance (if close enough).
pub(crate) fn suggest<'a>(word: &str, candidates: &[&'a str]) -> Vec<&'a str> {
    let w = word.to_lowercase();
    if w.len() >= 3 {
        let prefixed: Vec<&str> = candidates
            .iter()
            .filter(|c| c.to_lowercase().starts_with(&w))
            .copied()
            .collect();
        if !prefixed.is_empty() {
            return prefixed;
        }
    }
    candidates
        .iter()
        .map(|c| (distance(&w, &c.to_lowercase()), *c))
        .filter(|(d, c)| *d <= 2.max(c.len() / 3))
        .min_by_key(|(d, _)| *d)
        .map(|(_, c)| c)
        .into_iter()
        .collect()
}

/// ` (did you mean `a`?)`, ` (did you mean one of `a`, `b`?)`, or nothing.
pub(crate) fn hint(word: &str, candidates: &[&str]) -> String {
    match suggest(word, candidates).as_slice() {
        [] => String::new(),
        [one] => format!(" (did you mean `{one}`?)"),
        many => format!(
            " (did you mean one of {}?)",
            many.iter()
                .map(|c| format!("`{c}`"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// A key as it must be written in a dotted TOML path (quoted unless bare).
pub(crate) fn quote_key(key: &str) -> String {
    let bare = !key.is_empty()
        && key
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
    if bare {
        key.to_string()
    } else {
        format!("{key:?}")
    }
}

/// `a, b, c` (or `none` when empty).
pub(crate) fn one_of(items: &[&str]) -> String {
    if items.is_empty() {
        "none".into()
    } else {
        items.join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_and_columns_count_characters() {
        let s = "a = 1\nµ = \"x\"\n";
        assert_eq!(line_column(s, 0), (1, 1));
        assert_eq!(line_column(s, 4), (1, 5));
        assert_eq!(line_column(s, 6), (2, 1));
        // 'µ' is two bytes: the '=' after it is character 3 of line 2.
        assert_eq!(line_column(s, 9), (2, 3));
        assert_eq!(line_column(s, 1000), (3, 1));
    }

    #[test]
    fn one_pass_places_agree_with_line_column_everywhere() {
        let s = "a = 1\r\nµ = \"€x\"\n\n  [t]\nend";
        let mut place = Places::new(s);
        // Every offset in order (inside characters too, and past the end), then one going back.
        for pos in 0..s.len() + 3 {
            assert_eq!(place.at(pos), line_column(s, pos), "offset {pos}");
        }
        assert_eq!(place.at(7), line_column(s, 7));
    }

    #[test]
    fn warnings_render_as_warning_and_are_not_errors() {
        let src = "a = 1\nb = 2\n";
        let mut d = Diags::default();
        d.warning(&(6..7), "b", "doubtful");
        assert!(!d.has_errors());
        d.error(&(0..1), "a", "wrong");
        assert!(d.has_errors());
        let all = d.finish("f.toml", src);
        assert_eq!(all[0].to_string(), "f.toml:1:1: a: wrong");
        assert_eq!(all[1].severity, Severity::Warning);
        assert_eq!(all[1].to_string(), "f.toml:2:1: warning: b: doubtful");
    }

    #[test]
    fn suggestions_only_for_near_misses() {
        let keys = ["rate_hz", "priority", "cpu"];
        assert_eq!(suggest("rate", &keys), ["rate_hz"]);
        assert_eq!(suggest("prority", &keys), ["priority"]);
        assert!(suggest("colour", &keys).is_empty());
        let safe = ["scale", "safe_action", "safe_value"];
        assert_eq!(suggest("safe", &safe), ["safe_action", "safe_value"]);
        assert_eq!(hint("scal", &safe), " (did you mean `scale`?)");
        assert_eq!(quote_key("left leg"), "\"left leg\"");
        assert_eq!(quote_key("RAR_2"), "RAR_2");
        assert_eq!(distance("kitten", "sitting"), 3);
    }
}
