//! The validator: walks the TOML document once, checks every key, type, range, name and link,
//! and either builds the model or reports every problem found.
//!
//! Errors do not cascade: a component with an error is still known by name, so links to it are
//! not reported as dangling, but checks that need its content (a device's channels) are skipped.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::Path;

use conductor_bus::naming;
use conductor_bus::Domain;
use conductor_devices::kinds::{self, KindSpec, Medium, ParamType, ParamValue, Params, Stage};
use conductor_devices::Credential;
use toml::de::{DeTable, DeValue};

use super::diag::{hint, line_column, one_of, quote_key, Diags};
use super::reader::{describe, integer, number, At, Table};
use super::{
    Calibration, DeviceDef, HardwareDef, Manifest, ManifestError, ProtocolDef, SafeSpec, StateDef,
    Subsystem, DEFAULT_HISTORY, DEFAULT_PRIORITY, DEVICE_KEYS, HARDWARE_KEYS, MAX_HISTORY,
    MAX_RATE_HZ, PROTOCOL_KEYS, STATE_KEYS, SUBSYSTEM_KEYS, TOP_KEYS,
};

const RATE: &str = "a rate in Hz above 0 and at most 100000";

/// An exclusive OS resource (a serial port, a CAN interface) and who holds it.
struct Resource {
    value: String,
    param: &'static str,
    owner: String,
    span: Range<usize>,
    key: String,
}

struct Ctx<'k, 's> {
    d: Diags,
    kinds: &'k [KindSpec],
    source: &'s str,
    resources: Vec<Resource>,
}

pub(super) fn validate(
    source: &str,
    path: &Path,
    kinds: &[KindSpec],
) -> Result<Manifest, ManifestError> {
    let file = path.display().to_string();
    let (doc, errors) = DeTable::parse_recoverable(source);
    if !errors.is_empty() {
        // Syntax errors: the document's shape is unreliable, so report only these.
        let mut d = Diags::default();
        for e in errors {
            let span = e.span().unwrap_or(0..0);
            d.error(&span, "", syntax_message(source, &span, e.message().trim()));
        }
        return Err(ManifestError::Invalid {
            diagnostics: d.finish(&file, source),
        });
    }
    let mut cx = Ctx {
        d: Diags::default(),
        kinds,
        source,
        resources: Vec::new(),
    };
    let mut top = Table::new(String::new(), doc.get_ref(), 0..0);
    let system = top.req_str(&mut cx.d, "system", "the robot's name, a string");
    if let Some(s) = &system {
        check_name(&mut cx.d, "system", "system", s);
    }
    let domain = top.str(&mut cx.d, "domain");
    if let Some(dom) = &domain {
        if let Err(e) = Domain::new(&dom.value) {
            cx.d.error(&dom.span, "domain", e.to_string());
        }
    }
    let mut subsystems = Vec::new();
    match top.table(&mut cx.d, "subsystems") {
        Some(mut subs) => {
            let entries = subs.named_tables(&mut cx.d, "a subsystem table");
            if entries.is_empty() && subs.keys().is_empty() {
                cx.d.error(
                    &subs.span,
                    "subsystems",
                    "expected at least one subsystem ([subsystems.<name>])",
                );
            }
            for (name, table) in entries {
                match table {
                    Some(table) => subsystems.push(subsystem(&mut cx, name, table)),
                    None => subsystems.push(None),
                }
            }
        }
        None if top.span_of("subsystems").is_none() => cx.d.error(
            &(0..0),
            "subsystems",
            "missing required key `subsystems` (at least one [subsystems.<name>] table)",
        ),
        None => {}
    }
    top.finish(&mut cx.d, TOP_KEYS);
    check_resources(&mut cx);

    if !cx.d.is_empty() {
        return Err(ManifestError::Invalid {
            diagnostics: cx.d.finish(&file, source),
        });
    }
    Ok(Manifest {
        path: path.to_path_buf(),
        system: system.map(|s| s.value).unwrap_or_default(),
        domain: domain.map(|d| d.value),
        subsystems: subsystems.into_iter().flatten().collect(),
    })
}

/// The parser's message, made specific for duplicates (which name, where it was first defined).
fn syntax_message(source: &str, span: &Range<usize>, message: &str) -> String {
    if message != "duplicate key" {
        return format!("invalid TOML: {message}");
    }
    let (line, _) = line_column(source, span.start);
    let text = source.lines().nth(line - 1).unwrap_or("").trim();
    if text.starts_with('[') {
        let first = source
            .lines()
            .position(|l| l.trim() == text)
            .map_or(line, |i| i + 1);
        format!(
            "table {text} is defined twice (first on line {first}); expected each name once \
             within its section"
        )
    } else {
        let key = source.get(span.clone()).unwrap_or("").trim();
        format!("key `{key}` is given twice in the same table; expected each key once")
    }
}

fn check_name(d: &mut Diags, what: &'static str, key: &str, name: &At<String>) -> bool {
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

fn fmt_num(x: f64) -> String {
    let r = (x * 1000.0).round() / 1000.0;
    format!("{r}")
}

/// `rate_hz` of a component as a divisor of the base rate (1 when absent).
fn divisor(d: &mut Diags, t: &mut Table, base: Option<f64>) -> Option<u32> {
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

/// Looks up the kind named by `kind` for `stage`.
fn kind_spec<'k>(
    cx: &mut Ctx<'k, '_>,
    t: &mut Table,
    stage: Stage,
    what: &str,
) -> Option<&'k KindSpec> {
    let kind = t.req_str(&mut cx.d, "kind", &format!("the {what} kind, a string"))?;
    let found = cx
        .kinds
        .iter()
        .find(|k| k.stage == stage && k.kind == kind.value);
    match found {
        Some(spec) => Some(spec),
        None => {
            let known: Vec<&str> = cx
                .kinds
                .iter()
                .filter(|k| k.stage == stage)
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
fn kind_params(d: &mut Diags, t: &mut Table, spec: &KindSpec) -> Option<Params> {
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

fn accepted(stage_keys: &[&'static str], spec: Option<&KindSpec>) -> Vec<&'static str> {
    let mut v = stage_keys.to_vec();
    if let Some(s) = spec {
        v.extend(s.params.iter().map(|p| p.name));
    }
    v
}

/// Resolves a link by name among `names` (in the subsystem), reporting a dangling link.
fn link(
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

struct HwOut {
    def: Option<HardwareDef>,
    medium: Option<Medium>,
}

struct ProtoOut {
    def: Option<ProtocolDef>,
    kind: Option<String>,
}

fn subsystem(cx: &mut Ctx, name: At<String>, mut t: Table) -> Option<Subsystem> {
    let key = t.path.clone();
    let name_ok = check_name(&mut cx.d, "subsystem", &key, &name);
    let rate = t.req_num(
        &mut cx.d,
        "rate_hz",
        (f64::MIN_POSITIVE, MAX_RATE_HZ),
        "the base tick rate, a rate in Hz above 0 and at most 100000",
    );
    let base = rate.as_ref().map(|r| r.value);
    let period_ns = base.map(|b| (1e9 / b).round() as u64);
    let cpu = t.int(&mut cx.d, "cpu", (0, 1023), "a CPU number from 0 to 1023");
    let priority = t.int(
        &mut cx.d,
        "priority",
        (1, 99),
        "a SCHED_FIFO priority from 1 to 99",
    );
    let require_rt = t.bool(&mut cx.d, "require_rt");
    let spin = t.num(
        &mut cx.d,
        "spin_us",
        (0.0, 10_000.0),
        "a spin time in µs from 0 to 10000",
    );
    let mut spin_ns = spin.as_ref().map_or(0, |s| (s.value * 1e3).round() as u64);
    if let (Some(s), Some(p)) = (&spin, period_ns) {
        if spin_ns >= p {
            cx.d.error(
                &s.span,
                &t.key_path("spin_us"),
                format!(
                    "expected a spin time shorter than the base period ({} µs)",
                    fmt_num(p as f64 / 1e3)
                ),
            );
            spin_ns = 0;
        }
    }
    let watchdog = t.num(
        &mut cx.d,
        "watchdog_ms",
        (f64::MIN_POSITIVE, 3_600_000.0),
        "a timeout in ms above 0 and at most 3600000",
    );
    let mut watchdog_ns = watchdog.as_ref().map(|w| (w.value * 1e6).round() as u64);
    if let (Some(w), Some(p), Some(ns)) = (&watchdog, period_ns, watchdog_ns) {
        if ns < p {
            cx.d.error(
                &w.span,
                &t.key_path("watchdog_ms"),
                format!(
                    "expected a timeout of at least one base period ({} ms)",
                    fmt_num(p as f64 / 1e6)
                ),
            );
            watchdog_ns = None;
        }
    }

    let mut hw_tables = t
        .table(&mut cx.d, "hardware")
        .map(|mut x| x.named_tables(&mut cx.d, "a hardware table"))
        .unwrap_or_default();
    let mut proto_tables = t
        .table(&mut cx.d, "protocols")
        .map(|mut x| x.named_tables(&mut cx.d, "a protocol table"))
        .unwrap_or_default();
    let mut dev_tables = t
        .table(&mut cx.d, "devices")
        .map(|mut x| x.named_tables(&mut cx.d, "a device table"))
        .unwrap_or_default();
    let state_tables = match t.table(&mut cx.d, "states") {
        Some(mut x) => {
            let v = x.named_tables(&mut cx.d, "a state table");
            if v.is_empty() && x.keys().is_empty() {
                cx.d.error(&x.span, &x.path, "expected at least one state");
            }
            v
        }
        None => {
            if t.span_of("states").is_none() {
                cx.d.error(
                    &t.span,
                    &t.key_path("states"),
                    "missing required key `states` (a subsystem publishes at least one state)",
                );
            }
            Vec::new()
        }
    };
    t.finish(&mut cx.d, SUBSYSTEM_KEYS);

    let sub = name.value.clone();
    // Hardware.
    let hw_names: Vec<String> = hw_tables.iter().map(|(n, _)| n.value.clone()).collect();
    let mut hw: Vec<HwOut> = Vec::new();
    for (hname, ht) in hw_tables.iter_mut() {
        hw.push(match ht {
            Some(ht) => hardware(cx, &sub, hname, ht, base),
            None => HwOut {
                def: None,
                medium: None,
            },
        });
    }
    // Protocols.
    let proto_names: Vec<String> = proto_tables.iter().map(|(n, _)| n.value.clone()).collect();
    let mut protos: Vec<ProtoOut> = Vec::new();
    let mut hw_users: Vec<Option<String>> = vec![None; hw.len()];
    for (pname, pt) in proto_tables.iter_mut() {
        protos.push(match pt {
            Some(pt) => protocol(cx, &sub, pname, pt, base, &hw_names, &hw, &mut hw_users),
            None => ProtoOut {
                def: None,
                kind: None,
            },
        });
    }
    // Devices.
    let dev_names: Vec<String> = dev_tables.iter().map(|(n, _)| n.value.clone()).collect();
    let mut devs: Vec<Option<DeviceDef>> = Vec::new();
    let mut creds: Vec<(usize, Credential, String)> = Vec::new();
    let mut safe_pending: Vec<SafePending> = Vec::new();
    for (dname, dt) in dev_tables.iter_mut() {
        let (def, safe) = match dt {
            Some(dt) => device(cx, &sub, dname, dt, base, &proto_names, &protos, &mut creds),
            None => (None, None),
        };
        devs.push(def);
        safe_pending.push(safe);
    }
    // States.
    let mut states: Vec<Option<StateDef>> = Vec::new();
    let mut state_names: Vec<String> = Vec::new();
    let mut bound: Vec<(usize, usize, String)> = Vec::new();
    for (sname, st) in state_tables {
        state_names.push(sname.value.clone());
        let Some(mut st) = st else {
            states.push(None);
            continue;
        };
        let name_ok = check_name(&mut cx.d, "state", &st.path.clone(), &sname);
        let def = state(
            cx, &sub, &mut st, base, &dev_names, &devs, &mut bound, &sname,
        );
        states.push(if name_ok { def } else { None });
    }
    // Safe setpoints name a state: resolve now that states are known.
    for (di, pending) in safe_pending.into_iter().enumerate() {
        let Some((named, value, action_span)) = pending else {
            continue;
        };
        let dkey = format!(
            "subsystems.{}.devices.{}",
            quote_key(&sub),
            quote_key(&dev_names[di])
        );
        let writable: Vec<usize> = states
            .iter()
            .enumerate()
            .filter_map(|(i, s)| {
                s.as_ref()
                    .filter(|s| s.device == di && s.writable)
                    .map(|_| i)
            })
            .collect();
        let target = match named {
            Some(n) => match state_names.iter().position(|s| *s == n.value) {
                Some(i) if writable.contains(&i) => Some(i),
                Some(i) if states[i].is_none() => None,
                _ => {
                    let names: Vec<&str> =
                        writable.iter().map(|&i| state_names[i].as_str()).collect();
                    cx.d.error(
                        &n.span,
                        &format!("{dkey}.safe_state"),
                        format!(
                            "{:?} is not a writable state of device {:?}; expected one of: {}",
                            n.value,
                            dev_names[di],
                            one_of(&names)
                        ),
                    );
                    None
                }
            },
            None => match writable.as_slice() {
                [one] => Some(*one),
                [] => {
                    cx.d.error(
                        &action_span,
                        &format!("{dkey}.safe_action"),
                        "safe_action = \"setpoint\" needs a writable state on this device to \
                         carry the setpoint; expected \"hold\" or \"torque_off\", or a writable state",
                    );
                    None
                }
                many => {
                    let names: Vec<&str> = many.iter().map(|&i| state_names[i].as_str()).collect();
                    cx.d.error(
                        &action_span,
                        &format!("{dkey}.safe_action"),
                        format!(
                            "the device has several writable states; name the one that carries \
                             the safe setpoint with safe_state = one of: {}",
                            one_of(&names)
                        ),
                    );
                    None
                }
            },
        };
        if let (Some(i), Some(dev)) = (target, devs[di].as_mut()) {
            dev.safe = SafeSpec::Setpoint { state: i, value };
        }
    }

    let ok = name_ok
        && hw.iter().all(|h| h.def.is_some())
        && protos.iter().all(|p| p.def.is_some())
        && devs.iter().all(Option::is_some)
        && states.iter().all(Option::is_some);
    if !ok {
        return None;
    }
    Some(Subsystem {
        name: name.value,
        rate_hz: base?,
        period_ns: period_ns?,
        cpu: cpu.map(|c| c.value as usize),
        priority: priority.map_or(DEFAULT_PRIORITY, |p| p.value as i32),
        require_rt: require_rt.is_some_and(|r| r.value),
        spin_ns,
        watchdog_ns,
        hardware: hw.into_iter().filter_map(|h| h.def).collect(),
        protocols: protos.into_iter().filter_map(|p| p.def).collect(),
        devices: devs.into_iter().flatten().collect(),
        states: states.into_iter().flatten().collect(),
    })
}

fn hardware(cx: &mut Ctx, sub: &str, name: &At<String>, t: &mut Table, base: Option<f64>) -> HwOut {
    let name_ok = check_name(&mut cx.d, "hardware", &t.path.clone(), name);
    let spec = kind_spec(cx, t, Stage::Hardware, "hardware");
    let div = divisor(&mut cx.d, t, base);
    let params = spec.and_then(|s| kind_params(&mut cx.d, t, s));
    let accepted = accepted(HARDWARE_KEYS, spec);
    if spec.is_none() {
        // Unknown kind: its parameters cannot be checked, so don't call them unknown.
        for k in t.keys() {
            t.touch(&k);
        }
    }
    t.finish(&mut cx.d, &accepted);
    let medium = spec.and_then(|s| s.medium);
    if let (Some(s), Some(p)) = (spec, params.as_ref()) {
        if let Some(res) = s.resource {
            if let Ok(v) = p.str(res) {
                cx.resources.push(Resource {
                    value: v.to_string(),
                    param: res,
                    owner: format!("hardware {:?} of subsystem {sub:?}", name.value),
                    span: p_span(t, res).unwrap_or(name.span.clone()),
                    key: t.key_path(res),
                });
            }
        }
    }
    let def = match (name_ok, spec, div, params) {
        (true, Some(s), Some(divisor), Some(params)) => Some(HardwareDef {
            name: name.value.clone(),
            kind: s.kind.to_string(),
            divisor,
            params,
            simulated: s.medium == Some(Medium::Sim),
        }),
        _ => None,
    };
    HwOut { def, medium }
}

#[allow(clippy::too_many_arguments)]
fn protocol(
    cx: &mut Ctx,
    sub: &str,
    name: &At<String>,
    t: &mut Table,
    base: Option<f64>,
    hw_names: &[String],
    hw: &[HwOut],
    hw_users: &mut [Option<String>],
) -> ProtoOut {
    let name_ok = check_name(&mut cx.d, "protocol", &t.path.clone(), name);
    let spec = kind_spec(cx, t, Stage::Protocol, "protocol");
    let target = t.req_str(&mut cx.d, "hardware", "the name of the hardware it runs on");
    let hw_index = target
        .as_ref()
        .and_then(|h| link(&mut cx.d, t, "hardware", h, hw_names, "hardware", sub));
    if let (Some(i), Some(h)) = (hw_index, target.as_ref()) {
        match &hw_users[i] {
            Some(other) => cx.d.error(
                &h.span,
                &t.key_path("hardware"),
                format!(
                    "hardware {:?} already carries protocol {other:?}; a hardware serves one \
                     protocol (declare a second hardware for a second bus)",
                    h.value
                ),
            ),
            None => hw_users[i] = Some(name.value.clone()),
        }
        if let (Some(s), Some(hm)) = (spec, hw[i].medium) {
            if s.medium.is_some_and(|pm| pm != hm) {
                cx.d.error(
                    &h.span,
                    &t.key_path("hardware"),
                    format!(
                        "protocol kind {:?} speaks {} but hardware {:?} carries {}; expected a \
                         hardware of the same medium",
                        s.kind,
                        s.medium.map_or("?", Medium::name),
                        h.value,
                        hm.name()
                    ),
                );
            }
        }
    }
    let div = divisor(&mut cx.d, t, base);
    let params = spec.and_then(|s| kind_params(&mut cx.d, t, s));
    if spec.is_none() {
        for k in t.keys() {
            t.touch(&k);
        }
    }
    let accepted = accepted(PROTOCOL_KEYS, spec);
    t.finish(&mut cx.d, &accepted);
    let kind = spec.map(|s| s.kind.to_string());
    let def = match (name_ok, spec, hw_index, div, params) {
        (true, Some(s), Some(hardware), Some(divisor), Some(params)) => Some(ProtocolDef {
            name: name.value.clone(),
            kind: s.kind.to_string(),
            hardware,
            divisor,
            params,
        }),
        _ => None,
    };
    ProtoOut { def, kind }
}

type SafePending = Option<(Option<At<String>>, f64, Range<usize>)>;

#[allow(clippy::too_many_arguments)]
fn device(
    cx: &mut Ctx,
    sub: &str,
    name: &At<String>,
    t: &mut Table,
    base: Option<f64>,
    proto_names: &[String],
    protos: &[ProtoOut],
    creds: &mut Vec<(usize, Credential, String)>,
) -> (Option<DeviceDef>, SafePending) {
    let name_ok = check_name(&mut cx.d, "device", &t.path.clone(), name);
    let spec = kind_spec(cx, t, Stage::Device, "device");
    let target = t.req_str(&mut cx.d, "protocol", "the name of the protocol it sits on");
    let proto = target
        .as_ref()
        .and_then(|p| link(&mut cx.d, t, "protocol", p, proto_names, "protocol", sub));
    if let (Some(i), Some(s), Some(p)) = (proto, spec, target.as_ref()) {
        if let Some(pk) = &protos[i].kind {
            if !s.protocols.contains(&pk.as_str()) {
                cx.d.error(
                    &p.span,
                    &t.key_path("protocol"),
                    format!(
                        "device kind {:?} cannot sit on protocol {:?} of kind {pk:?}; expected a \
                         protocol of kind: {}",
                        s.kind,
                        p.value,
                        one_of(s.protocols)
                    ),
                );
            }
        }
    }
    let id = t.req_int(
        &mut cx.d,
        "id",
        (0, i64::from(u32::MAX)),
        "the device's bus id, an integer from 0 to 4294967295",
    );
    let subaddr = t.int(
        &mut cx.d,
        "sub",
        (0, i64::from(u32::MAX)),
        "a sub-address, an integer from 0 to 4294967295",
    );
    let cred = id.as_ref().map(|id| Credential {
        id: id.value as u32,
        sub: subaddr.as_ref().map_or(0, |s| s.value as u32),
    });
    if let (Some(c), Some(p), Some(idv)) = (cred, proto, id.as_ref()) {
        if let Some((_, _, other)) = creds.iter().find(|(pp, cc, _)| *pp == p && *cc == c) {
            cx.d.error(
                &idv.span,
                &t.key_path("id"),
                format!(
                    "bus id {} (sub {}) is already used by device {other:?} on protocol {:?}; \
                     expected ids unique on a bus",
                    c.id, c.sub, proto_names[p]
                ),
            );
        } else {
            creds.push((p, c, name.value.clone()));
        }
    }
    let calibration = calibration(&mut cx.d, t, Calibration::default());
    let div = divisor(&mut cx.d, t, base);
    // Safe action.
    let action = t.str(&mut cx.d, "safe_action");
    let value = t.num(
        &mut cx.d,
        "safe_value",
        (f64::MIN, f64::MAX),
        "a finite number (state units)",
    );
    let safe_state = t.str(&mut cx.d, "safe_state");
    let mut safe = Some(SafeSpec::Hold);
    let mut pending = None;
    match action.as_ref().map(|a| a.value.as_str()) {
        None | Some("hold") => {}
        Some("torque_off") => safe = Some(SafeSpec::TorqueOff),
        Some("setpoint") => match &value {
            Some(v) => {
                pending = Some((
                    safe_state,
                    v.value,
                    action.as_ref().map_or(0..0, |a| a.span.clone()),
                ))
            }
            None => {
                if t.span_of("safe_value").is_none() {
                    cx.d.error(
                        &action.as_ref().map_or(0..0, |a| a.span.clone()),
                        &t.key_path("safe_value"),
                        "safe_action = \"setpoint\" needs `safe_value` (the setpoint, in state units)",
                    );
                }
                safe = None;
            }
        },
        Some(_) => {
            let a = action.as_ref().expect("matched Some");
            cx.d.error(
                &a.span,
                &t.key_path("safe_action"),
                format!(
                    "expected one of: hold, torque_off, setpoint; found {:?}",
                    a.value
                ),
            );
            safe = None;
        }
    }
    if pending.is_none() {
        for key in ["safe_value", "safe_state"] {
            if let Some(span) = t.span_of(key) {
                if safe.is_some() {
                    cx.d.error(
                        &span,
                        &t.key_path(key),
                        format!("`{key}` applies only with safe_action = \"setpoint\""),
                    );
                }
            }
        }
    }
    let params = spec.and_then(|s| kind_params(&mut cx.d, t, s));
    if spec.is_none() {
        for k in t.keys() {
            t.touch(&k);
        }
    }
    let accepted = accepted(DEVICE_KEYS, spec);
    let table_path = t.path.clone();
    t.finish(&mut cx.d, &accepted);

    // Build the device once to learn its channels (devices are plain state machines: no I/O).
    let channels = match (spec, &params, cred) {
        (Some(s), Some(p), Some(c)) => match kinds::build_device(s.kind, p, c) {
            Ok(dev) => Some(dev.channels().to_vec()),
            Err(e) => {
                cx.d.error(
                    &t.span_of("kind").unwrap_or(t.span.clone()),
                    &format!("{table_path}.kind"),
                    format!("cannot build device: {e}"),
                );
                None
            }
        },
        _ => None,
    };
    let def = match (
        name_ok,
        spec,
        proto,
        div,
        params,
        cred,
        calibration,
        safe,
        channels,
    ) {
        (
            true,
            Some(s),
            Some(protocol),
            Some(divisor),
            Some(params),
            Some(credential),
            Some(calibration),
            Some(safe),
            Some(channels),
        ) => Some(DeviceDef {
            name: name.value.clone(),
            kind: s.kind.to_string(),
            protocol,
            divisor,
            credential,
            calibration,
            safe,
            params,
            channels,
        }),
        _ => None,
    };
    (def, pending)
}

/// `scale`, `offset`, `direction` over `defaults`; `None` if any is invalid.
fn calibration(d: &mut Diags, t: &mut Table, defaults: Calibration) -> Option<Calibration> {
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

#[allow(clippy::too_many_arguments)]
fn state(
    cx: &mut Ctx,
    sub: &str,
    t: &mut Table,
    base: Option<f64>,
    dev_names: &[String],
    devs: &[Option<DeviceDef>],
    bound: &mut Vec<(usize, usize, String)>,
    name: &At<String>,
) -> Option<StateDef> {
    let target = t.req_str(&mut cx.d, "device", "the name of the device it belongs to");
    let dev_index = target
        .as_ref()
        .and_then(|dn| link(&mut cx.d, t, "device", dn, dev_names, "device", sub));
    let dev = dev_index.and_then(|i| devs[i].as_ref());
    let channel_key = t.str(&mut cx.d, "channel");
    let mut channel = None;
    if let Some(dev) = dev {
        let names: Vec<&str> = dev.channels.iter().map(|c| c.name).collect();
        match &channel_key {
            Some(c) => match names.iter().position(|n| *n == c.value) {
                Some(i) => channel = Some(i),
                None => cx.d.error(
                    &c.span,
                    &t.key_path("channel"),
                    format!(
                        "device {:?} (kind {:?}) has no channel {:?}; expected one of: {}",
                        dev.name,
                        dev.kind,
                        c.value,
                        one_of(&names)
                    ),
                ),
            },
            None if names.len() == 1 => channel = Some(0),
            None => cx.d.error(
                &t.span,
                &t.key_path("channel"),
                format!(
                    "missing required key `channel`: device {:?} has several channels; expected \
                     one of: {}",
                    dev.name,
                    one_of(&names)
                ),
            ),
        }
    }
    if let (Some(di), Some(ci)) = (dev_index, channel) {
        if let Some((_, _, other)) = bound.iter().find(|(d, c, _)| *d == di && *c == ci) {
            let span = channel_key
                .as_ref()
                .map(|c| c.span.clone())
                .or_else(|| target.as_ref().map(|t| t.span.clone()))
                .unwrap_or(t.span.clone());
            cx.d.error(
                &span,
                &t.key_path(if channel_key.is_some() {
                    "channel"
                } else {
                    "device"
                }),
                format!(
                    "channel {:?} of device {:?} is already published by state {other:?}; \
                     expected one state per channel",
                    dev.map_or("", |d| d.channels[ci].name),
                    dev_names[di]
                ),
            );
        } else {
            bound.push((di, ci, name.value.clone()));
        }
    }
    let div = divisor(&mut cx.d, t, base);
    let units = t.str(&mut cx.d, "units");
    let writable = t.bool(&mut cx.d, "writable");
    let ch = dev.zip(channel).map(|(d, c)| &d.channels[c]);
    let mut ok = true;
    if let (Some(w), Some(ch)) = (&writable, ch) {
        if w.value && !ch.writable {
            cx.d.error(
                &w.span,
                &t.key_path("writable"),
                format!(
                    "channel {:?} of device {:?} is read-only; expected writable = false",
                    ch.name,
                    dev.map_or("", |d| d.name.as_str())
                ),
            );
            ok = false;
        }
    }
    if let Some(ch) = ch {
        let w = writable.as_ref().is_some_and(|w| w.value);
        if !ch.readable && !w {
            cx.d.error(
                &t.span,
                &t.key_path("writable"),
                format!(
                    "channel {:?} cannot be read, so the state must be writable (it then \
                     publishes its last setpoint); expected writable = true",
                    ch.name
                ),
            );
            ok = false;
        }
    }
    let min = t.num(
        &mut cx.d,
        "min",
        (f64::MIN, f64::MAX),
        "a finite number (state units)",
    );
    let max = t.num(
        &mut cx.d,
        "max",
        (f64::MIN, f64::MAX),
        "a finite number (state units)",
    );
    if (t.span_of("min").is_some() && min.is_none())
        || (t.span_of("max").is_some() && max.is_none())
    {
        ok = false;
    }
    if let (Some(lo), Some(hi)) = (&min, &max) {
        if lo.value > hi.value {
            cx.d.error(
                &hi.span,
                &t.key_path("max"),
                format!(
                    "expected max ≥ min ({}), found {}",
                    fmt_num(lo.value),
                    fmt_num(hi.value)
                ),
            );
            ok = false;
        }
    }
    let history = t.int(
        &mut cx.d,
        "history",
        (1, MAX_HISTORY as i64),
        "a history length in samples from 1 to 65536",
    );
    if t.span_of("history").is_some() && history.is_none() {
        ok = false;
    }
    let calibration = calibration(
        &mut cx.d,
        t,
        dev.map_or(Calibration::default(), |d| d.calibration),
    );
    t.finish(&mut cx.d, STATE_KEYS);
    if !ok {
        return None;
    }
    let (di, ci, ch) = (dev_index?, channel?, ch?);
    Some(StateDef {
        name: name.value.clone(),
        device: di,
        channel: ci,
        divisor: div?,
        units: units.map_or_else(|| ch.units.to_string(), |u| u.value),
        writable: writable.is_some_and(|w| w.value),
        min: min.map_or(f64::NEG_INFINITY, |m| m.value),
        max: max.map_or(f64::INFINITY, |m| m.value),
        history: history.map_or(DEFAULT_HISTORY, |h| h.value as usize),
        calibration: calibration?,
        readable: ch.readable,
    })
}

/// Two hardware components anywhere in the manifest may not open the same OS resource.
fn check_resources(cx: &mut Ctx) {
    for (i, r) in cx.resources.iter().enumerate() {
        if let Some(first) = cx.resources[..i]
            .iter()
            .find(|f| f.param == r.param && f.value == r.value)
        {
            let (line, _) = line_column(cx.source, first.span.start);
            cx.d.error(
                &r.span,
                &r.key,
                format!(
                    "{} {:?} of {} is already used by {} (line {line}); expected each bus device \
                     to be opened by one hardware of one executor only",
                    r.param, r.value, r.owner, first.owner
                ),
            );
        }
    }
}

fn p_span(t: &Table, key: &str) -> Option<Range<usize>> {
    t.span_of(key)
}
