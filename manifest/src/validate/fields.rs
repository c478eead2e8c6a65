//! Checks shared by every component table: names, rates as divisors of the base rate, kinds and
//! their parameters, links by name, calibration.

use std::collections::BTreeMap;

use conductor_bus::naming;
use conductor_devices::kinds::{KindSpec, ParamType, ParamValue, Params, Role};
use toml::de::DeValue;

use super::super::diag::{hint, one_of, Diags};
use super::super::reader::{describe, integer, number, At, Table};
use super::super::{Calibration, MAX_RATE_HZ};
use super::Ctx;

const RATE: &str = "a rate in Hz above 0 and at most 100000";

pub(super) fn check_name(d: &mut Diags, what: &'static str, key: &str, name: &At<String>) -> bool {
    // Component names follow the bus's naming rules (they appear in service attributes).
    let what_bus = if what == "state" {
        "state"
    } else {
        "subsystem"
    };
    match naming::validate(what_bus, &name.value) {
        Ok(()) => true,
        Err(e) => {
            let msg = e.to_string().replacen(what_bus, what, 1);
            d.error(&name.span, key, msg);
            false
        }
    }
}

pub(super) fn fmt_num(x: f64) -> String {
    let r = (x * 1000.0).round() / 1000.0;
    format!("{r}")
}

/// `rate_hz` of a component as a divisor of the base rate (1 when absent).
pub(super) fn divisor(d: &mut Diags, t: &mut Table, base: Option<f64>) -> Option<u32> {
    if t.span_of("rate_hz").is_none() {
        return Some(1);
    }
    let rate = t.num(d, "rate_hz", (f64::MIN_POSITIVE, MAX_RATE_HZ), RATE)?;
    let base = base?;
    let key = t.key_path("rate_hz");
    if rate.value > base * (1.0 + 1e-12) {
        d.error(
            &rate.span,
            &key,
            format!(
                "{} Hz is faster than the subsystem's base rate {} Hz; expected a rate that \
                 divides the base rate (base / rate a whole number)",
                fmt_num(rate.value),
                fmt_num(base)
            ),
        );
        return None;
    }
    let q = base / rate.value;
    let n = q.round();
    if (q - n).abs() > 1e-9 * q || n < 1.0 || n > f64::from(u32::MAX) {
        let (lo, hi) = (q.floor().max(1.0), q.ceil());
        d.error(
            &rate.span,
            &key,
            format!(
                "{} Hz does not divide the base rate {} Hz (base / rate = {}); expected a rate \
                 that divides it, e.g. {} or {} Hz",
                fmt_num(rate.value),
                fmt_num(base),
                fmt_num(q),
                fmt_num(base / lo),
                fmt_num(base / hi)
            ),
        );
        return None;
    }
    Some(n as u32)
}

/// Looks up the kind named by `kind` in `role`.
pub(super) fn kind_spec<'k>(
    cx: &mut Ctx<'k, '_>,
    t: &mut Table,
    role: Role,
    what: &str,
) -> Option<&'k KindSpec> {
    let kind = t.req_str(&mut cx.d, "kind", &format!("the {what} kind, a string"))?;
    let found = cx
        .kinds
        .iter()
        .find(|k| k.role() == role && k.kind == kind.value);
    match found {
        Some(spec) => Some(spec),
        None => {
            let known: Vec<&str> = cx
                .kinds
                .iter()
                .filter(|k| k.role() == role)
                .map(|k| k.kind)
                .collect();
            let hint = hint(&kind.value, &known);
            cx.d.error(
                &kind.span,
                &t.key_path("kind"),
                format!(
                    "unknown {what} kind {:?}{hint}; expected one of: {}",
                    kind.value,
                    one_of(&known)
                ),
            );
            None
        }
    }
}

/// Validates a kind's parameters; `None` if any is wrong (errors recorded).
pub(super) fn kind_params(d: &mut Diags, t: &mut Table, spec: &KindSpec) -> Option<Params> {
    let mut given = BTreeMap::new();
    let mut ok = true;
    for p in spec.params {
        let Some(v) = t.value(p.name) else {
            if p.default.is_none() {
                d.error(
                    &t.span,
                    &t.key_path(p.name),
                    format!(
                        "missing required key `{}` ({} for kind {:?}: {})",
                        p.name,
                        p.ty.expected(),
                        spec.kind,
                        p.doc
                    ),
                );
                ok = false;
            }
            continue;
        };
        let key = t.key_path(p.name);
        let span = v.span();
        let range_text = match p.range {
            Some((lo, hi)) => format!(" from {} to {}", fmt_num(lo), fmt_num(hi)),
            None => String::new(),
        };
        let bad = |d: &mut Diags, what: String| {
            d.error(
                &span,
                &key,
                format!("expected {what}, found {}", describe(v.get_ref())),
            );
        };
        let in_range = |x: f64| p.range.is_none_or(|(lo, hi)| x >= lo && x <= hi);
        let value = match p.ty {
            ParamType::Int => match integer(v.get_ref()) {
                Some(x) if in_range(x as f64) => Some(ParamValue::Int(x)),
                _ => {
                    bad(d, format!("{}{range_text}", p.ty.expected()));
                    None
                }
            },
            ParamType::Float => match number(v.get_ref()) {
                Some(x) if x.is_finite() && in_range(x) => Some(ParamValue::Float(x)),
                _ => {
                    bad(d, format!("a finite number{range_text}"));
                    None
                }
            },
            ParamType::Bool => match v.get_ref() {
                DeValue::Boolean(b) => Some(ParamValue::Bool(*b)),
                _ => {
                    bad(d, p.ty.expected().to_string());
                    None
                }
            },
            ParamType::Str => match v.get_ref() {
                DeValue::String(s) if p.choices.is_empty() || p.choices.contains(&s.as_ref()) => {
                    Some(ParamValue::Str(s.to_string()))
                }
                DeValue::String(_) => {
                    bad(d, format!("one of: {}", one_of(p.choices)));
                    None
                }
                _ => {
                    bad(d, p.ty.expected().to_string());
                    None
                }
            },
        };
        match value {
            Some(v) => {
                given.insert(p.name.to_string(), v);
            }
            None => ok = false,
        }
    }
    ok.then(|| Params::new(spec, given))
}

pub(super) fn accepted(stage_keys: &[&'static str], spec: Option<&KindSpec>) -> Vec<&'static str> {
    let mut v = stage_keys.to_vec();
    if let Some(s) = spec {
        v.extend(s.params.iter().map(|p| p.name));
    }
    v
}

/// Resolves a link by name among `names` (in the subsystem), reporting a dangling link.
pub(super) fn link(
    d: &mut Diags,
    t: &Table,
    key: &str,
    target: &At<String>,
    names: &[String],
    what: &str,
    subsystem: &str,
) -> Option<usize> {
    if let Some(i) = names.iter().position(|n| *n == target.value) {
        return Some(i);
    }
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let hint = hint(&target.value, &refs);
    let expected = if refs.is_empty() {
        format!("the subsystem declares no {what}")
    } else {
        format!("expected one of: {}", one_of(&refs))
    };
    d.error(
        &target.span,
        &t.key_path(key),
        format!(
            "no {what} named {:?} in subsystem {subsystem:?}{hint}; {expected}",
            target.value
        ),
    );
    None
}

/// `scale`, `offset`, `direction` over `defaults`; `None` if any is invalid.
pub(super) fn calibration(
    d: &mut Diags,
    t: &mut Table,
    defaults: Calibration,
) -> Option<Calibration> {
    let mut c = defaults;
    let mut ok = true;
    if let Some(s) = t.num(d, "scale", (-1e12, 1e12), "a non-zero finite number") {
        if s.value == 0.0 {
            d.error(
                &s.span,
                &t.key_path("scale"),
                "expected a non-zero finite number, found 0",
            );
            ok = false;
        }
        c.scale = s.value;
    } else if t.span_of("scale").is_some() {
        ok = false;
    }
    match t.num(d, "offset", (-1e12, 1e12), "a finite number (device units)") {
        Some(o) => c.offset = o.value,
        None if t.span_of("offset").is_some() => ok = false,
        None => {}
    }
    if let Some(v) = t.value("direction") {
        match integer(v.get_ref()) {
            Some(1) => c.direction = 1.0,
            Some(-1) => c.direction = -1.0,
            _ => {
                d.error(
                    &v.span(),
                    &t.key_path("direction"),
                    format!("expected 1 or -1, found {}", describe(v.get_ref())),
                );
                ok = false;
            }
        }
    }
    ok.then_some(c)
}
