//! The validator: walks the TOML document once, checks every key, type, range, name and link,
//! and either builds the model or reports every problem found.
//!
//! Errors do not cascade: a component with an error is still known by name, so links to it are
//! not reported as dangling, but checks that need its content (a device's channels) are skipped.
//!
//! * this module: the document, subsystems, and checks across subsystems and gateways;
//! * [`components`]: hardware, protocol, device and state tables;
//! * [`gateways`]: gateway tables;
//! * [`view`]: the `[view]` table;
//! * [`fields`]: the checks shared by them (names, rates, kinds and their parameters, links,
//!   calibration);
//! * [`load`]: the load of every bus (an error above 100 % of the wire, a warning above 80 %);
//! * [`actuators`]: warnings about actuators nothing can command or re-enable.

mod actuators;
mod components;
mod fields;
mod gateways;
mod load;
mod view;

use std::ops::Range;
use std::path::Path;

use conductor_bus::Domain;
use conductor_devices::kinds::KindSpec;
use conductor_devices::Credential;
use toml::de::DeTable;

use super::diag::{line_column, one_of, quote_key, Diags};
use super::reader::{At, Table};
use super::{
    BridgeDef, DeviceDef, Manifest, ManifestError, SafeSpec, StateDef, Subsystem, BRIDGE_KEYS,
    DEFAULT_PRIORITY, MAX_RATE_HZ, SUBSYSTEM_KEYS, TOP_KEYS,
};
use components::{device, hardware, protocol, state, HwOut, ProtoOut, SafePending};
use fields::{check_name, fmt_num};

/// An exclusive OS resource (a serial port, a CAN interface, a gateway's board) and who holds it.
pub(super) struct Resource {
    pub(super) value: String,
    pub(super) param: &'static str,
    pub(super) owner: String,
    pub(super) span: Range<usize>,
    pub(super) key: String,
}

pub(super) struct Ctx<'k, 's> {
    pub(super) d: Diags,
    pub(super) kinds: &'k [KindSpec],
    pub(super) source: &'s str,
    pub(super) resources: Vec<Resource>,
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
    // Gateways first: whether there are any decides if subsystems are required.
    let mut gateways = Vec::new();
    let mut gateway_names: Vec<(String, Range<usize>)> = Vec::new();
    if let Some(mut gws) = top.table(&mut cx.d, "gateways") {
        for (name, table) in gws.named_tables(&mut cx.d, "a gateway table") {
            gateway_names.push((name.value.clone(), name.span.clone()));
            if let Some(mut table) = table {
                gateways.push(gateways::gateway(&mut cx, &name, &mut table));
            }
        }
    }
    let bridge = top.table(&mut cx.d, "bridge").map(|mut b| {
        // The bridge checks what is inside; here only that the table's keys are known.
        for k in b.keys() {
            if BRIDGE_KEYS.contains(&k.as_str()) {
                b.touch(&k);
            }
        }
        b.finish(&mut cx.d, BRIDGE_KEYS);
        BridgeDef {
            line: line_column(source, b.span.start).0,
        }
    });
    let mut subsystems = Vec::new();
    let mut subsystem_names: Vec<(String, Range<usize>)> = Vec::new();
    match top.table(&mut cx.d, "subsystems") {
        Some(mut subs) => {
            let entries = subs.named_tables(&mut cx.d, "a subsystem table");
            if entries.is_empty() && subs.keys().is_empty() && gateway_names.is_empty() {
                cx.d.error(
                    &subs.span,
                    "subsystems",
                    "expected at least one subsystem ([subsystems.<name>])",
                );
            }
            for (name, table) in entries {
                subsystem_names.push((name.value.clone(), name.span.clone()));
                match table {
                    Some(table) => subsystems.push(subsystem(&mut cx, name, table)),
                    None => subsystems.push(None),
                }
            }
        }
        None if top.span_of("subsystems").is_none() && gateway_names.is_empty() => cx.d.error(
            &(0..0),
            "subsystems",
            "missing required key `subsystems` (at least one [subsystems.<name>] table)",
        ),
        None => {}
    }
    let view = top
        .table(&mut cx.d, "view")
        .map(|mut t| view::view(&mut cx, &mut t));
    top.finish(&mut cx.d, TOP_KEYS);
    check_gateway_names(&mut cx, &subsystem_names, &gateway_names);
    check_resources(&mut cx);

    if cx.d.has_errors() {
        return Err(ManifestError::Invalid {
            diagnostics: cx.d.finish(&file, source),
        });
    }
    Ok(Manifest {
        path: path.to_path_buf(),
        system: system.map(|s| s.value).unwrap_or_default(),
        domain: domain.map(|d| d.value),
        subsystems: subsystems.into_iter().flatten().collect(),
        gateways: gateways.into_iter().flatten().collect(),
        view: view.flatten(),
        bridge,
        warnings: cx.d.finish(&file, source),
    })
}

/// The parser's message, made specific for duplicates (which name, where it was first defined).
fn syntax_message(source: &str, span: &Range<usize>, message: &str) -> String {
    if message != "duplicate key" {
        return format!("invalid TOML: {message}");
    }
    // The line holding the span, found from the span (a parse can report many duplicates, and
    // counting lines from the start for each made that quadratic).
    let mut pos = span.start.min(source.len());
    while !source.is_char_boundary(pos) {
        pos -= 1;
    }
    let start = source[..pos].rfind('\n').map_or(0, |i| i + 1);
    let end = source[pos..].find('\n').map_or(source.len(), |i| pos + i);
    let text = source[start..end].trim();
    if text.starts_with('[') {
        let first = source
            .lines()
            .position(|l| l.trim() == text)
            .map_or_else(|| line_column(source, pos).0, |i| i + 1);
        format!(
            "table {text} is defined twice (first on line {first}); expected each name once \
             within its section"
        )
    } else {
        let key = source.get(span.clone()).unwrap_or("").trim();
        format!("key `{key}` is given twice in the same table; expected each key once")
    }
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
    let def = Subsystem {
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
    };
    // Checks of the built subsystem, reported on the component's table header.
    let headers = |tables: &[(At<String>, Option<Table>)]| -> Vec<(Range<usize>, String)> {
        tables
            .iter()
            .map(|(n, t)| {
                t.as_ref().map_or((n.span.clone(), String::new()), |t| {
                    (t.span.clone(), t.path.clone())
                })
            })
            .collect()
    };
    load::check(&mut cx.d, &def, &headers(&proto_tables));
    actuators::check(&mut cx.d, &def, &headers(&dev_tables));
    Some(def)
}

/// A gateway publishes the subsystem of its name: no subsystem may have it too.
fn check_gateway_names(
    cx: &mut Ctx,
    subsystems: &[(String, Range<usize>)],
    gateways: &[(String, Range<usize>)],
) {
    for (name, span) in gateways {
        if let Some((_, first)) = subsystems.iter().find(|(s, _)| s == name) {
            let (line, _) = line_column(cx.source, first.start);
            cx.d.error(
                span,
                &format!("gateways.{}", quote_key(name)),
                format!(
                    "subsystem {name:?} is already defined (line {line}); expected a gateway \
                     name unique among subsystems and gateways (the gateway publishes the \
                     states of subsystem {name:?})"
                ),
            );
        }
    }
}

/// Two hardware components or gateways anywhere in the manifest may not open the same OS
/// resource.
fn check_resources(cx: &mut Ctx) {
    // Document order, so "already used by" names the first use in the file.
    cx.resources.sort_by_key(|r| r.span.start);
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
                     to be opened by one hardware or gateway only",
                    r.param, r.value, r.owner, first.owner
                ),
            );
        }
    }
}
