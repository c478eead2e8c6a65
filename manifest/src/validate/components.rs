//! The component tables: hardware, protocols, devices, states.

use std::ops::Range;

use conductor_devices::kinds::{self, Medium, Role};
use conductor_devices::{Credential, Startup};

use super::super::diag::one_of;
use super::super::reader::{At, Table};
use super::super::{
    Calibration, DeviceDef, HardwareDef, ProtocolDef, SafeSpec, StateDef, DEFAULT_HISTORY,
    DEVICE_KEYS, HARDWARE_KEYS, MAX_HISTORY, PROTOCOL_KEYS, STATE_KEYS,
};
use super::fields::{
    accepted, calibration, check_name, divisor, fmt_num, kind_params, kind_spec, link,
};
use super::{Ctx, Resource};

pub(super) struct HwOut {
    pub(super) def: Option<HardwareDef>,
    pub(super) medium: Option<Medium>,
}

pub(super) struct ProtoOut {
    pub(super) def: Option<ProtocolDef>,
    pub(super) kind: Option<String>,
}

pub(super) fn hardware(
    cx: &mut Ctx,
    sub: &str,
    name: &At<String>,
    t: &mut Table,
    base: Option<f64>,
) -> HwOut {
    let name_ok = check_name(&mut cx.d, "hardware", &t.path.clone(), name);
    let spec = kind_spec(cx, t, Role::Hardware, "hardware");
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
    let medium = spec.and_then(|s| s.medium());
    if let (Some(s), Some(p)) = (spec, params.as_ref()) {
        if let Some(res) = s.resource() {
            if let Ok(v) = p.str(res) {
                cx.resources.push(Resource {
                    value: v.to_string(),
                    param: res,
                    owner: format!("hardware {:?} of subsystem {sub:?}", name.value),
                    span: t.span_of(res).unwrap_or(name.span.clone()),
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
            simulated: s.medium() == Some(Medium::Sim),
        }),
        _ => None,
    };
    HwOut { def, medium }
}

#[allow(clippy::too_many_arguments)]
pub(super) fn protocol(
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
    let spec = kind_spec(cx, t, Role::Protocol, "protocol");
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
            if s.medium().is_some_and(|pm| pm != hm) {
                cx.d.error(
                    &h.span,
                    &t.key_path("hardware"),
                    format!(
                        "protocol kind {:?} speaks {} but hardware {:?} carries {}; expected a \
                         hardware of the same medium",
                        s.kind,
                        s.medium().map_or("?", Medium::name),
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

pub(super) type SafePending = Option<(Option<At<String>>, f64, Range<usize>)>;

#[allow(clippy::too_many_arguments)]
pub(super) fn device(
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
    let spec = kind_spec(cx, t, Role::Device, "device");
    let target = t.req_str(&mut cx.d, "protocol", "the name of the protocol it sits on");
    let proto = target
        .as_ref()
        .and_then(|p| link(&mut cx.d, t, "protocol", p, proto_names, "protocol", sub));
    if let (Some(i), Some(s), Some(p)) = (proto, spec, target.as_ref()) {
        if let Some(pk) = &protos[i].kind {
            if !s.protocols().contains(&pk.as_str()) {
                cx.d.error(
                    &p.span,
                    &t.key_path("protocol"),
                    format!(
                        "device kind {:?} cannot sit on protocol {:?} of kind {pk:?}; expected a \
                         protocol of kind: {}",
                        s.kind,
                        p.value,
                        one_of(s.protocols())
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
    // Safe action: one of those the kind can carry out, its declared one by default.
    let action = t.str(&mut cx.d, "safe_action");
    let value = t.num(
        &mut cx.d,
        "safe_value",
        (f64::MIN, f64::MAX),
        "a finite number (state units; for damp: the velocity gain kd)",
    );
    let mut safe_state = t.str(&mut cx.d, "safe_state");
    let supported: &[&str] = match spec {
        Some(s) if !s.safe_actions().is_empty() => s.safe_actions(),
        _ => &["hold", "torque_off", "setpoint"],
    };
    let chosen = action
        .as_ref()
        .map_or(supported[0], |a| a.value.as_str())
        .to_string();
    let mut safe = None;
    let mut pending = None;
    let action_span = action.as_ref().map_or(0..0, |a| a.span.clone());
    if !supported.contains(&chosen.as_str()) {
        let a = action.as_ref().expect("the default is supported");
        cx.d.error(
            &a.span,
            &t.key_path("safe_action"),
            format!(
                "device kind {:?} cannot carry out safe action {:?}; expected one of: {}",
                spec.map_or("?", |s| s.kind),
                a.value,
                one_of(supported)
            ),
        );
    } else {
        match chosen.as_str() {
            "hold" => safe = Some(SafeSpec::Hold),
            "torque_off" => safe = Some(SafeSpec::TorqueOff),
            "damp" => {
                safe = Some(SafeSpec::Damp {
                    kd: value.as_ref().map(|v| v.value),
                })
            }
            _ => match &value {
                Some(v) => pending = Some((safe_state.take(), v.value, action_span.clone())),
                None => {
                    if t.span_of("safe_value").is_none() {
                        cx.d.error(
                            &action_span,
                            &t.key_path("safe_value"),
                            "safe_action = \"setpoint\" needs `safe_value` (the setpoint, in state units)",
                        );
                    }
                }
            },
        }
    }
    let takes_value = matches!(chosen.as_str(), "setpoint" | "damp");
    for key in ["safe_value", "safe_state"] {
        let allowed = chosen == "setpoint" || (key == "safe_value" && takes_value);
        if let Some(span) = t.span_of(key) {
            if !allowed && (safe.is_some() || pending.is_some()) {
                cx.d.error(
                    &span,
                    &t.key_path(key),
                    format!("`{key}` applies only with safe_action = \"setpoint\" (safe_value also with \"damp\")"),
                );
            }
        }
    }
    if let (Some(SafeSpec::Damp { kd: Some(kd) }), Some(v)) = (safe, value.as_ref()) {
        if !(0.0..=5.0).contains(&kd) {
            cx.d.error(
                &v.span,
                &t.key_path("safe_value"),
                format!(
                    "expected a velocity gain kd from 0 to 5 for damp, found {}",
                    fmt_num(kd)
                ),
            );
            safe = None;
        }
    }
    // Lifecycle.
    let startup = t.str(&mut cx.d, "startup");
    let startup = match startup {
        None => Some(Startup::Enable),
        Some(s) => match Startup::from_name(&s.value) {
            Some(v) => Some(v),
            None => {
                cx.d.error(
                    &s.span,
                    &t.key_path("startup"),
                    format!(
                        "expected one of: {}; found {:?}",
                        one_of(Startup::CHOICES),
                        s.value
                    ),
                );
                None
            }
        },
    };
    let optional = t.bool(&mut cx.d, "optional").is_some_and(|b| b.value);
    let params = spec.and_then(|s| kind_params(&mut cx.d, t, s));
    // A device that describes what its protocol stage also describes (a motor model) must agree.
    if let (Some(check), Some(p), Some(i), Some(c)) =
        (spec.and_then(|s| s.protocol_check()), &params, proto, cred)
    {
        if let Some(stage) = protos[i].def.as_ref() {
            if let Err(d) = check(p, &stage.params, c.id) {
                cx.d.error(
                    &t.span_of(d.param).unwrap_or(name.span.clone()),
                    &t.key_path(d.param),
                    format!(
                        "disagrees with protocol {:?}; expected {}",
                        stage.name, d.expected
                    ),
                );
            }
        }
    }
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
    // A setpoint action is resolved (to its state) once the states are known.
    let safe = safe.or(pending.as_ref().map(|_| SafeSpec::Hold));
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
        startup,
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
            Some(startup),
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
            startup,
            optional,
        }),
        _ => None,
    };
    (def, pending)
}

#[allow(clippy::too_many_arguments)]
pub(super) fn state(
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
