//! Warnings about actuators: one nothing can command, and one the watchdog switches off with no
//! way to switch it back on.
//!
//! An actuator is a device whose kind has a writable `position` channel (Dynamixel servos, MIT
//! motors, ODrive axes); what a kind offers is read from its channels, not from a list of kinds.

use std::ops::Range;

use super::super::diag::{quote_key, Diags};
use super::super::{SafeSpec, Subsystem};

/// Checks every device of `sub`; `devices[i]` is where device `i`'s table starts and its key.
pub(super) fn check(d: &mut Diags, sub: &Subsystem, devices: &[(Range<usize>, String)]) {
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
                     it: nothing can command it, it only reports (and keeps whatever it does \
                     when the executor starts); if it should move, bind a state to one of its \
                     writable channels (e.g. position) with writable = true",
                    dev.name, dev.kind
                ),
            );
            continue;
        }
        // The watchdog runs the safe action of devices with a writable state. Switched off, a
        // device is only switched on again through its `enable` channel.
        let Some(enable) = dev
            .channels
            .iter()
            .position(|c| c.name == "enable" && c.writable)
        else {
            continue;
        };
        if sub.watchdog_ns.is_some()
            && matches!(dev.safe, SafeSpec::TorqueOff)
            && !writable(Some(enable))
        {
            d.warning(
                span,
                key,
                format!(
                    "subsystem {:?} has a watchdog (watchdog_ms) whose safe action switches \
                     device {:?} off (torque_off), but no writable state is bound to its \
                     `enable` channel: after a watchdog trip nothing can switch it on again \
                     but restarting the executor; bind one, e.g. \
                     [subsystems.{}.states.{}] device = {:?}, channel = \"enable\", \
                     writable = true",
                    sub.name,
                    dev.name,
                    quote_key(&sub.name),
                    quote_key(&format!("{}_enable", dev.name)),
                    dev.name
                ),
            );
        }
    }
}
