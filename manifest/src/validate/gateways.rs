//! The `[gateways.<name>]` tables: processes that put a board on the bus as the states of
//! subsystem `<name>` (a Score board through `score-gateway`).

use std::path::PathBuf;

use super::super::diag::{hint, one_of};
use super::super::reader::{At, Table};
use super::super::{GatewayDef, GatewayKind, GatewayOptions, GATEWAY_KEYS, MAX_RATE_HZ};
use super::fields::check_name;
use super::{Ctx, Resource};

const RATE: &str = "a rate in Hz above 0 and at most 100000";

/// Validates one gateway table; `None` if anything in it is wrong (errors recorded).
pub(super) fn gateway(cx: &mut Ctx, name: &At<String>, t: &mut Table) -> Option<GatewayDef> {
    let name_ok = check_name(&mut cx.d, "gateway", &t.path.clone(), name);
    let kind = t
        .req_str(&mut cx.d, "kind", "the gateway kind, a string")
        .and_then(|k| {
            let found = GatewayKind::from_name(&k.value);
            if found.is_none() {
                let known: Vec<&str> = GatewayKind::ALL.iter().map(|k| k.name()).collect();
                cx.d.error(
                    &k.span,
                    &t.key_path("kind"),
                    format!(
                        "unknown gateway kind {:?}{}; expected one of: {}",
                        k.value,
                        hint(&k.value, &known),
                        one_of(&known)
                    ),
                );
            }
            found
        });
    let port = t
        .req_str(
            &mut cx.d,
            "port",
            "the board's link device, a path such as \"/dev/score-link\"",
        )
        .and_then(|p| {
            if p.value.is_empty() {
                cx.d.error(
                    &p.span,
                    &t.key_path("port"),
                    "expected a device path such as \"/dev/score-link\", found the string \"\"",
                );
                return None;
            }
            cx.resources.push(Resource {
                value: p.value.clone(),
                param: "port",
                owner: format!("gateway {:?}", name.value),
                span: p.span.clone(),
                key: t.key_path("port"),
            });
            Some(p.value)
        });
    let max_rate = t.num(
        &mut cx.d,
        "max_rate_hz",
        (f64::MIN_POSITIVE, MAX_RATE_HZ),
        RATE,
    );
    let lazy_rate = t.num(
        &mut cx.d,
        "lazy_rate_hz",
        (f64::MIN_POSITIVE, MAX_RATE_HZ),
        RATE,
    );
    let restore = t.bool(&mut cx.d, "restore");
    let retry = t.int(
        &mut cx.d,
        "retry_ms",
        (10, 60_000),
        "a retry interval in ms from 10 to 60000",
    );
    let watchdog = t.int(
        &mut cx.d,
        "watchdog_ms",
        (1, 60_000),
        "a command watchdog timeout in ms from 1 to 60000",
    );
    let priority = t.int(
        &mut cx.d,
        "priority",
        (1, 99),
        "a SCHED_FIFO priority from 1 to 99",
    );
    t.finish(&mut cx.d, GATEWAY_KEYS);
    // A wrong optional key has its error recorded, which rejects the whole manifest.
    if !name_ok {
        return None;
    }
    Some(GatewayDef {
        name: name.value.clone(),
        kind: kind?,
        port: PathBuf::from(port?),
        options: GatewayOptions {
            max_rate_hz: max_rate.map(|r| r.value),
            lazy_rate_hz: lazy_rate.map(|r| r.value),
            restore: restore.is_none_or(|r| r.value),
            retry_ms: retry.map(|r| r.value as u64),
            watchdog_ms: watchdog.map(|w| w.value as u64),
            priority: priority.map(|p| p.value as i32),
        },
    })
}
