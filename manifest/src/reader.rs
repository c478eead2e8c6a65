//! Typed, span-aware access to one TOML table, recording every error and every key it read so
//! that unknown keys can be reported afterwards.

use std::collections::BTreeSet;
use std::ops::Range;

use toml::de::{DeTable, DeValue};
use toml::Spanned;

use super::diag::{hint, one_of, quote_key, Diags};

/// A table being read: its dotted path, its entries in document order, and which keys were used.
pub(crate) struct Table<'a, 'i> {
    pub(crate) path: String,
    pub(crate) span: Range<usize>,
    entries: Vec<(
        &'a Spanned<toml::de::DeString<'i>>,
        &'a Spanned<DeValue<'i>>,
    )>,
    used: BTreeSet<String>,
}

/// A value with where it came from.
pub(crate) struct At<T> {
    pub(crate) value: T,
    pub(crate) span: Range<usize>,
}

impl<'a, 'i> Table<'a, 'i> {
    pub(crate) fn new(path: String, table: &'a DeTable<'i>, span: Range<usize>) -> Self {
        let mut entries: Vec<_> = table.iter().collect();
        // Document order (the map itself is sorted by key).
        entries.sort_by_key(|(k, _)| k.span().start);
        Self {
            path,
            span,
            entries,
            used: BTreeSet::new(),
        }
    }

    /// `path.key`.
    pub(crate) fn key_path(&self, key: &str) -> String {
        if self.path.is_empty() {
            quote_key(key)
        } else {
            format!("{}.{}", self.path, quote_key(key))
        }
    }

    fn raw(&mut self, key: &str) -> Option<&'a Spanned<DeValue<'i>>> {
        let (_, v) = self.entries.iter().find(|(k, _)| k.get_ref() == key)?;
        self.used.insert(key.to_string());
        Some(*v)
    }

    /// Span of `key`'s value, if present.
    pub(crate) fn span_of(&self, key: &str) -> Option<Range<usize>> {
        self.entries
            .iter()
            .find(|(k, _)| k.get_ref() == key)
            .map(|(_, v)| v.span())
    }

    fn mismatch(&self, d: &mut Diags, key: &str, v: &Spanned<DeValue<'i>>, expected: &str) {
        d.error(
            &v.span(),
            &self.key_path(key),
            format!("expected {expected}, found {}", describe(v.get_ref())),
        );
    }

    fn missing(&self, d: &mut Diags, key: &str, expected: &str) {
        d.error(
            &self.span,
            &self.key_path(key),
            format!("missing required key `{key}` ({expected})"),
        );
    }

    /// The value of `key` converted by `convert`; `None` if absent, or (with an error saying
    /// `expected`) if `convert` refuses it.
    fn typed<T>(
        &mut self,
        d: &mut Diags,
        key: &str,
        expected: &str,
        convert: impl FnOnce(&'a DeValue<'i>) -> Option<T>,
    ) -> Option<At<T>> {
        let v = self.raw(key)?;
        match convert(v.get_ref()) {
            Some(value) => Some(At {
                value,
                span: v.span(),
            }),
            None => {
                self.mismatch(d, key, v, expected);
                None
            }
        }
    }

    /// `get`, or (with an error saying `expected`) `None` if `key` is absent.
    fn required<T>(
        &mut self,
        d: &mut Diags,
        key: &str,
        expected: &str,
        get: impl FnOnce(&mut Self, &mut Diags) -> Option<T>,
    ) -> Option<T> {
        if self.span_of(key).is_none() {
            self.missing(d, key, expected);
            return None;
        }
        get(self, d)
    }

    /// A string; `None` (with an error) if present but not a string.
    pub(crate) fn str(&mut self, d: &mut Diags, key: &str) -> Option<At<String>> {
        self.typed(d, key, "a string", |v| match v {
            DeValue::String(s) => Some(s.to_string()),
            _ => None,
        })
    }

    /// A required string.
    pub(crate) fn req_str(&mut self, d: &mut Diags, key: &str, what: &str) -> Option<At<String>> {
        self.required(d, key, what, |t, d| t.str(d, key))
    }

    /// A finite number (integers accepted) within `range` (inclusive).
    pub(crate) fn num(
        &mut self,
        d: &mut Diags,
        key: &str,
        range: (f64, f64),
        expected: &str,
    ) -> Option<At<f64>> {
        self.typed(d, key, expected, |v| {
            number(v).filter(|x| x.is_finite() && *x >= range.0 && *x <= range.1)
        })
    }

    /// A required number.
    pub(crate) fn req_num(
        &mut self,
        d: &mut Diags,
        key: &str,
        range: (f64, f64),
        expected: &str,
    ) -> Option<At<f64>> {
        self.required(d, key, expected, |t, d| t.num(d, key, range, expected))
    }

    /// An integer within `range` (inclusive).
    pub(crate) fn int(
        &mut self,
        d: &mut Diags,
        key: &str,
        range: (i64, i64),
        expected: &str,
    ) -> Option<At<i64>> {
        self.typed(d, key, expected, |v| {
            integer(v).filter(|x| *x >= range.0 && *x <= range.1)
        })
    }

    /// A required integer.
    pub(crate) fn req_int(
        &mut self,
        d: &mut Diags,
        key: &str,
        range: (i64, i64),
        expected: &str,
    ) -> Option<At<i64>> {
        self.required(d, key, expected, |t, d| t.int(d, key, range, expected))
    }

    /// A boolean.
    pub(crate) fn bool(&mut self, d: &mut Diags, key: &str) -> Option<At<bool>> {
        self.typed(d, key, "true or false", |v| match v {
            DeValue::Boolean(b) => Some(*b),
            _ => None,
        })
    }

    /// A sub-table, or `None` (with an error if present but not a table).
    pub(crate) fn table(&mut self, d: &mut Diags, key: &str) -> Option<Table<'a, 'i>> {
        let t = self.typed(d, key, "a table", |v| match v {
            DeValue::Table(t) => Some(t),
            _ => None,
        })?;
        Some(Table::new(self.key_path(key), t.value, t.span))
    }

    /// Every entry of this table as (name, sub-table), in document order; entries that are not
    /// tables are reported as `expected` and come with `None` (their names still count).
    pub(crate) fn named_tables(
        &mut self,
        d: &mut Diags,
        expected: &str,
    ) -> Vec<(At<String>, Option<Table<'a, 'i>>)> {
        let mut out = Vec::new();
        for (k, v) in self.entries.clone() {
            self.used.insert(k.get_ref().to_string());
            let path = self.key_path(k.get_ref());
            let name = At {
                value: k.get_ref().to_string(),
                span: k.span(),
            };
            match v.get_ref() {
                DeValue::Table(t) => out.push((name, Some(Table::new(path, t, v.span())))),
                other => {
                    d.error(
                        &v.span(),
                        &path,
                        format!("expected {expected}, found {}", describe(other)),
                    );
                    out.push((name, None));
                }
            }
        }
        out
    }

    /// Reports every key not read, with the accepted keys and a "did you mean" hint.
    pub(crate) fn finish(&self, d: &mut Diags, accepted: &[&str]) {
        for (k, _) in &self.entries {
            let name = k.get_ref().as_ref();
            if self.used.contains(name) {
                continue;
            }
            let hint = hint(name, accepted);
            d.error(
                &k.span(),
                &self.key_path(name),
                format!(
                    "unknown key `{name}`{hint}; expected one of: {}",
                    one_of(accepted)
                ),
            );
        }
    }

    /// Marks `key` as read without looking at it (it is validated elsewhere).
    pub(crate) fn touch(&mut self, key: &str) {
        self.used.insert(key.to_string());
    }

    /// The raw value of `key` (marks it used).
    pub(crate) fn value(&mut self, key: &str) -> Option<&'a Spanned<DeValue<'i>>> {
        self.raw(key)
    }

    /// Keys present, in document order.
    pub(crate) fn keys(&self) -> Vec<String> {
        self.entries
            .iter()
            .map(|(k, _)| k.get_ref().to_string())
            .collect()
    }
}

/// A TOML number as f64 (integers widen).
pub(crate) fn number(v: &DeValue<'_>) -> Option<f64> {
    match v {
        DeValue::Integer(i) => integer(v)
            .map(|x| x as f64)
            .or_else(|| i.as_str().parse().ok()),
        DeValue::Float(f) => f.as_str().parse().ok(),
        _ => None,
    }
}

/// A TOML integer as i64.
pub(crate) fn integer(v: &DeValue<'_>) -> Option<i64> {
    match v {
        DeValue::Integer(i) => i64::from_str_radix(i.as_str(), i.radix()).ok(),
        _ => None,
    }
}

/// How a value reads in a message: `the string "x"`, `the integer 3`, `a table`.
pub(crate) fn describe(v: &DeValue<'_>) -> String {
    match v {
        DeValue::String(s) => format!("the string {s:?}"),
        DeValue::Integer(i) => format!("the integer {i}"),
        DeValue::Float(f) => format!("the number {}", f.as_str()),
        DeValue::Boolean(b) => format!("the boolean {b}"),
        DeValue::Datetime(t) => format!("the datetime {t}"),
        DeValue::Array(_) => "an array".into(),
        DeValue::Table(_) => "a table".into(),
    }
}
