//! Warnings about actuators: one nothing can command, and one that nothing could enable again
//! after a trip (the watchdog, or a fault of the device, trips it; a tripped device refuses
//! setpoints until its `enable` channel is written 1).
//!
//! An actuator is a device whose kind has a writable `position` channel (Dynamixel servos, MIT
//! motors, ODrive axes); what a kind offers is read from its channels, not from a list of kinds.

use std::ops::Range;

use super::super::diag::{quote_key, Diags};
use super::super::Subsystem;

/// Checks every device of `sub`; `devices[i]` is where device `i`'s table starts and its key.
pub(super) fn check(d: &mut Diags, sub: &Subsystem, devices: &[(Range<usize>, String)]) {
    let mut no_enable: Vec<(Range<usize>, String, String)> = Vec::new();
    for (i, ((span, key), dev)) in devices.iter().zip(&sub.devices).enumerate() {
        let actuator = dev
            .channels
            .iter()
            .any(|c| c.name == "position" && c.writable);
        if !actuator {
            continue;
        }
        let writable = |channel: Option<usize>| {
            sub.states
                .iter()
                .any(|s| s.device == i && s.writable && channel.is_none_or(|c| s.channel == c))
        };
        if !writable(None) {
            d.warning(
                span,
                key,
                format!(
                    "device {:?} (kind {:?}) is an actuator, but no writable state is bound to \
                     it: nothing can command it; it is enabled at start and holds where it is \
                     (startup = \"hold_off\" leaves it limp); if it should move, bind a state \
                     to one of its writable channels (e.g. position) with writable = true",
                    dev.name, dev.kind
                ),
            );
            continue;
        }
        // A trip (the watchdog's, or a fault's) latches: the device refuses setpoints until
        // its `enable` channel is written 1.
        let Some(enable) = dev
            .channels
            .iter()
            .position(|c| c.name == "enable" && c.writable)
        else {
            continue;
        };
        if !writable(Some(enable)) {
            no_enable.push((span.clone(), key.clone(), dev.name.clone()));
        }
    }
    // One warning for the subsystem, at its first such device.
    let Some((span, key, first)) = no_enable.first() else {
        return;
    };
    let by = if sub.watchdog_ns.is_some() {
        "the command watchdog (watchdog_ms) or a fault"
    } else {
        "a fault"
    };
    let names: Vec<String> = no_enable.iter().map(|(_, _, n)| format!("{n:?}")).collect();
    d.warning(
        span,
        key,
        format!(
            "{} of subsystem {:?} ({}) {} no writable state bound to the `enable` channel: \
             once tripped by {by}, a device refuses every setpoint until enabled again, and \
             nothing but restarting the executor could; bind one per device, e.g. \
             [subsystems.{}.states.{}] device = {first:?}, channel = \"enable\", writable = true",
            if names.len() == 1 {
                "device"
            } else {
                "devices"
            },
            sub.name,
            names.join(", "),
            if names.len() == 1 { "has" } else { "have" },
            quote_key(&sub.name),
            quote_key(&format!("{first}_enable")),
        ),
    );
}
