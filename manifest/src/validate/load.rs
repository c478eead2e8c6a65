//! Bus load: a bus whose traffic needs more than its wire can carry is refused, one close to it
//! is warned about; both with the figures and what to change. The model is
//! [`busload`](super::super::busload).

use std::ops::Range;

use super::super::busload::{BusLoad, Part, Wire, MAX_LOAD, WARN_LOAD};
use super::super::diag::Diags;
use super::super::Subsystem;
use super::fields::fmt_num;
use conductor_devices::protocol_stage::Dxl2ReadMode;

/// Checks every bus of `sub`; `protocols[i]` is where protocol `i`'s table starts and its key.
pub(super) fn check(d: &mut Diags, sub: &Subsystem, protocols: &[(Range<usize>, String)]) {
    for (i, (span, key)) in protocols.iter().enumerate() {
        let Some(load) = sub.bus_load(i) else {
            continue;
        };
        let f = load.fraction();
        // A hair of tolerance: a bus computed at exactly 100 % is not refused for rounding.
        if f > MAX_LOAD * (1.0 + 1e-9) {
            let lead = format!(
                "more than the wire can carry: {}; expected at most {} %",
                figures(&load),
                pct(MAX_LOAD)
            );
            d.error(span, key, message(sub, &load, &lead));
        } else if f > WARN_LOAD * (1.0 + 1e-9) {
            let lead = format!(
                "above {} %: {}; little time is left for retries, late replies and the host's \
                 jitter",
                pct(WARN_LOAD),
                figures(&load)
            );
            d.warning(span, key, message(sub, &load, &lead));
        }
    }
}

/// `38.5`, `300`: a percentage to 0.1.
fn pct(fraction: f64) -> String {
    format!("{}", (fraction * 1000.0).round() / 10.0)
}

/// `packets`, `replies`, `delays`.
fn plural(what: &str) -> String {
    match what.strip_suffix('y') {
        Some(stem) if !stem.ends_with(['a', 'e', 'o', 'u']) => format!("{stem}ies"),
        _ => format!("{what}s"),
    }
}

fn part(p: &Part, wire: Wire) -> String {
    let what = if p.count == 1 {
        p.what.to_string()
    } else {
        format!("{} {}", p.count, plural(p.what))
    };
    match (p.size, wire) {
        (0, _) => format!("{what} {} µs", fmt_num(p.ns / 1e3)),
        (n, Wire::Uart { .. }) => format!("{what} {n} B"),
        (n, Wire::Can { .. }) => format!("{what} {n} bits"),
    }
}

/// What a cycle puts on the wire, how long it takes, how many cycles a second.
fn figures(load: &BusLoad) -> String {
    let cy = &load.busiest;
    let parts: Vec<String> = cy.parts.iter().map(|p| part(p, load.wire)).collect();
    let (size, speed) = match load.wire {
        Wire::Uart { baud } => (format!("{} bytes", cy.size()), format!("{baud} baud (8N1)")),
        Wire::Can { bitrate } => (
            format!("{} bits", cy.size()),
            format!("{bitrate} bit/s (classic CAN frames, worst-case bit stuffing)"),
        ),
    };
    let which = if load.uniform {
        "each cycle"
    } else {
        "the busiest cycle"
    };
    format!(
        "{which} puts {size} on the wire ({}) in {} ms at {speed}, and {} cycles a second carry \
         traffic: {} ms of wire time per second",
        parts.join(", "),
        fmt_num(cy.ns() / 1e6),
        fmt_num(load.cycles_per_s),
        fmt_num(load.busy_ns_per_s / 1e6),
    )
}

/// `bus load …`, `lead` (the verdict and the figures), and what to change.
fn message(sub: &Subsystem, load: &BusLoad, lead: &str) -> String {
    let estimate = if load.exact { "" } else { " (estimated)" };
    format!(
        "bus load {} % of the wire{estimate}, {lead}; to lower it: {}",
        pct(load.fraction()),
        advice(sub, load)
    )
}

/// `two buses`, `at least 3 buses`: what splitting the load takes.
fn buses(load: &BusLoad) -> String {
    // (less a hair, so that a bus at exactly 300 % asks for 3)
    let n = (load.fraction() / MAX_LOAD - 1e-9).ceil().max(2.0);
    if n <= 2.0 {
        "two buses".into()
    } else {
        format!("at least {n} buses")
    }
}

fn advice(sub: &Subsystem, load: &BusLoad) -> String {
    let p = &sub.protocols[load.protocol];
    let mut a = vec![
        "lower the rates (rate_hz) of the states on this bus, or of its protocol or devices"
            .to_string(),
    ];
    match load.wire {
        Wire::Uart { .. } => {
            a.push(
                "read fewer registers (each servo's read spans from its lowest to its highest \
                 register)"
                    .into(),
            );
            a.push("raise the baud rate (the hardware's `baud` and the servos' Baud Rate)".into());
            if p.params.int("return_delay_us").unwrap_or(0) > 0 {
                a.push("set the servos' Return Delay Time to 0 (and return_delay_us = 0)".into());
            }
            if p.kind == "dynamixel2" && p.params.choice("read").ok() != Some(Dxl2ReadMode::Fast) {
                a.push(
                    "read with read = \"fast_sync\" (one combined reply; X430/540 firmware ≥ 45)"
                        .into(),
                );
            }
            a.push(format!(
                "split the servos over {} (a hardware and protocol each)",
                buses(load)
            ));
        }
        Wire::Can { bitrate } => {
            if bitrate < 1_000_000 {
                a.push("raise the bitrate (the hardware's `bitrate`, up to 1000000)".into());
            }
            a.push(format!(
                "split the motors over {} (a hardware and protocol each)",
                buses(load)
            ));
        }
    }
    let last = a.pop().unwrap_or_default();
    if a.is_empty() {
        last
    } else {
        format!("{}, or {last}", a.join(", "))
    }
}
