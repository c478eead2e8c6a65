//! The client-side rules of a setpoint, shared by every tool that commands a state (`conductor
//! set`, `conductor view`, ...), so that they refuse, clamp and judge alike:
//!
//! * [`check`]: what is refused before anything is sent: a value that is not finite, a
//!   read-only state, a value outside the state's limits unless the caller asked to clamp it
//!   (then the nearest limit is sent);
//! * [`VerdictWatch`]: which sample carries the executor's verdict on a frame (the second one
//!   published after the send: the first may come from a tick that drained its commands just
//!   before);
//! * [`refusal`] and [`enable_state`]: why the executor refused one (`REJECTED` and the other
//!   flags of that sample) and which state switches its device on again.

use crate::abi::{status, StateSample};
use crate::discovery::StateInfo;
use crate::metadata::StateMeta;

/// Why a setpoint is not sent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NotSent {
    /// NaN or infinite.
    NotFinite,
    /// The state takes no setpoints.
    ReadOnly,
    /// Outside `[min, max]` and clamping was not asked for; `nearest` is what clamping sends.
    OutOfLimits {
        /// Lower limit.
        min: f64,
        /// Upper limit.
        max: f64,
        /// The nearest limit.
        nearest: f64,
    },
}

/// Checks `value` for a state with metadata `meta`: refused when not finite, when the state is
/// read-only, or when it is outside the limits and `clamp` is false. Returns the value to send
/// and whether it was clamped to a limit.
pub fn check(meta: &StateMeta, value: f64, clamp: bool) -> Result<(f64, bool), NotSent> {
    if !value.is_finite() {
        return Err(NotSent::NotFinite);
    }
    if !meta.writable {
        return Err(NotSent::ReadOnly);
    }
    let (nearest, clamped) = meta.clamp(value);
    if clamped && !clamp {
        return Err(NotSent::OutOfLimits {
            min: meta.min,
            max: meta.max,
            nearest,
        });
    }
    Ok((nearest, clamped))
}

/// Finds the sample that carries the executor's verdict on a frame sent at `t_send` (CLOCK_MONOTONIC
/// ns): the second sample of the state published after the send, i.e. one from a tick that
/// started after it. Feed it the state's samples in order.
#[derive(Debug, Clone, Copy)]
pub struct VerdictWatch {
    t_send: u64,
    after: u32,
}

impl VerdictWatch {
    /// Watches for the verdict on a frame sent at `t_send`.
    pub fn new(t_send: u64) -> Self {
        Self { t_send, after: 0 }
    }

    /// Whether `s` is the verdict sample.
    pub fn offer(&mut self, s: &StateSample) -> bool {
        if s.t_publish_ns > self.t_send {
            self.after += 1;
        }
        self.after >= 2
    }

    /// Samples published after the send seen so far.
    pub fn seen(&self) -> u32 {
        self.after
    }
}

/// Whether the verdict sample says the setpoint was refused (`REJECTED`).
pub fn refused(s: &StateSample) -> bool {
    s.status & status::REJECTED != 0
}

/// Whether `name` reads like the state bound to a device's `enable` channel (`enable`,
/// `knee_enable`, `RHY_enable`, `enable_knee`, ...).
fn looks_like_enable(name: &str) -> bool {
    let n = name.to_ascii_lowercase();
    n == "enable"
        || n.starts_with("enable_")
        || ["_enable", "-enable", ".enable"]
            .iter()
            .any(|s| n.ends_with(s))
}

/// The state that switches `target`'s device on again: a writable state of the same subsystem
/// whose metadata names the same device and whose name reads like an enable state
/// (`<device>_enable` first). The bus metadata carries the device, not the channel, so the name
/// decides.
pub fn enable_state(states: &[StateInfo], target: &StateInfo) -> Option<StateInfo> {
    let device = &target.meta.device;
    if device.is_empty() || looks_like_enable(&target.name) {
        return None;
    }
    let exact = format!("{device}_enable");
    states
        .iter()
        .filter(|s| {
            s.subsystem == target.subsystem
                && s.name != target.name
                && s.meta.device == *device
                && s.meta.writable
                && looks_like_enable(&s.name)
        })
        .min_by_key(|s| !s.name.eq_ignore_ascii_case(&exact))
        .cloned()
}

/// Why the executor refused a setpoint for `target`, from the flags of the sample that carries
/// `REJECTED`, and what to do about it. `enable` is the state that enables its device, if any.
pub fn refusal(flags: u32, target: &StateInfo, enable: Option<&StateInfo>) -> String {
    let device = &target.meta.device;
    let dev = if device.is_empty() {
        "its device".to_string()
    } else {
        format!("device {device}")
    };
    let switch_on = || match enable {
        Some(e) => format!("conductor set {} 1", e.qualified_name()),
        None if device.is_empty() => "the state names no device, so no enable state could be \
             found (restarting its executor brings its devices up again)"
            .to_string(),
        None => format!(
            "no state of {sub} is bound to its enable channel: bind one in the manifest \
             ([subsystems.{sub}.states.{device}_enable] device = \"{device}\", channel = \
             \"enable\", writable = true), or restart its executor",
            sub = target.subsystem
        ),
    };
    if flags & status::TRIPPED != 0 {
        let cause = if flags & status::DEVICE_FAULT != 0 {
            "it reported a fault"
        } else if flags & status::WATCHDOG != 0 {
            "the command watchdog fired: no command frame came within the subsystem's watchdog_ms"
        } else {
            "a watchdog trip or a fault took it to its safe state"
        };
        let how = match enable {
            Some(_) => format!("{} enables it from where it is", switch_on()),
            None => switch_on(),
        };
        format!("{dev} is tripped ({cause}) and refuses setpoints until it is enabled again: {how}")
    } else if flags & status::DISABLED != 0 {
        let stale = if flags & status::STALE != 0 {
            "; its samples are stale: it or its bus does not answer"
        } else {
            ""
        };
        let how = match enable {
            Some(_) => format!("if it stays so, enable it: {}", switch_on()),
            None => switch_on(),
        };
        format!(
            "{dev} is disabled (not driving: torque off, out of motor mode, idle, or still being \
             brought up{stale}) and refuses setpoints; {how}"
        )
    } else {
        format!(
            "it refuses values that are not finite, indices it does not know, read-only states, \
             and channels {dev} does not take now (its log may say which)"
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metadata::StateMeta;

    fn info(subsystem: &str, name: &str, device: &str, writable: bool) -> StateInfo {
        StateInfo {
            subsystem: subsystem.into(),
            name: name.into(),
            meta: StateMeta {
                writable,
                device: device.into(),
                ..StateMeta::default()
            },
            nodes: Vec::new(),
        }
    }

    #[test]
    fn the_enable_state_is_found_by_device_and_name() {
        let knee = info("leg", "knee", "knee", true);
        let states = vec![
            knee.clone(),
            info("leg", "knee_kp", "knee", true),
            // Read-only, another device, another subsystem: not it.
            info("leg", "knee_torque_enable", "knee", false),
            info("leg", "hip_enable", "hip", true),
            info("arm", "knee_enable", "knee", true),
            info("leg", "enable_all", "knee", true),
            info("leg", "knee_enable", "knee", true),
        ];
        let e = enable_state(&states, &knee).unwrap();
        assert_eq!(e.qualified_name(), "leg/knee_enable");
        // Any enable-like name of the same device when there is no `<device>_enable`.
        let e = enable_state(&states[..6], &knee).unwrap();
        assert_eq!(e.qualified_name(), "leg/enable_all");
        assert!(enable_state(&states[..5], &knee).is_none());
        // The shipped manifests' style: `RHY_enable` for device `RHY`.
        let rhy = info("right_leg", "RHY", "RHY", true);
        let states = vec![rhy.clone(), info("right_leg", "RHY_enable", "RHY", true)];
        assert_eq!(
            enable_state(&states, &rhy).unwrap().qualified_name(),
            "right_leg/RHY_enable"
        );
        // No device, or the enable state itself: no hint.
        assert!(enable_state(&states, &info("right_leg", "x", "", true)).is_none());
        assert!(enable_state(&states, &states[1]).is_none());
    }

    #[test]
    fn refusals_say_why_and_what_to_do() {
        let knee = info("leg", "knee", "knee", true);
        let en = info("leg", "knee_enable", "knee", true);
        let r = refusal(
            status::REJECTED | status::WATCHDOG | status::TRIPPED | status::DISABLED,
            &knee,
            Some(&en),
        );
        assert!(
            r.starts_with("device knee is tripped (the command watchdog fired"),
            "{r}"
        );
        assert!(
            r.contains("conductor set leg/knee_enable 1 enables it"),
            "{r}"
        );
        let r = refusal(status::REJECTED | status::TRIPPED, &knee, None);
        assert!(r.contains("bind one in the manifest"), "{r}");
        assert!(r.contains("[subsystems.leg.states.knee_enable]"), "{r}");
        let r = refusal(
            status::REJECTED | status::TRIPPED | status::DEVICE_FAULT,
            &knee,
            Some(&en),
        );
        assert!(r.contains("(it reported a fault)"), "{r}");
        let r = refusal(status::REJECTED | status::DISABLED, &knee, Some(&en));
        assert!(r.starts_with("device knee is disabled"), "{r}");
        assert!(
            r.ends_with("enable it: conductor set leg/knee_enable 1"),
            "{r}"
        );
        let r = refusal(status::REJECTED, &knee, Some(&en));
        assert!(r.contains("not finite") && r.contains("read-only"), "{r}");
    }

    #[test]
    fn check_refuses_what_set_refuses() {
        let m = StateMeta {
            writable: true,
            min: -1.0,
            max: 2.0,
            ..StateMeta::default()
        };
        assert_eq!(check(&m, 0.5, false), Ok((0.5, false)));
        assert_eq!(
            check(&m, 3.0, false),
            Err(NotSent::OutOfLimits {
                min: -1.0,
                max: 2.0,
                nearest: 2.0
            })
        );
        assert_eq!(check(&m, -3.0, true), Ok((-1.0, true)));
        assert_eq!(check(&m, f64::NAN, true), Err(NotSent::NotFinite));
        assert_eq!(check(&m, f64::INFINITY, true), Err(NotSent::NotFinite));
        let ro = StateMeta {
            writable: false,
            ..m
        };
        assert_eq!(check(&ro, 0.0, false), Err(NotSent::ReadOnly));
    }

    #[test]
    fn the_verdict_is_the_second_sample_after_the_send() {
        let at = |t: u64| StateSample {
            t_publish_ns: t,
            ..StateSample::default()
        };
        let mut w = VerdictWatch::new(100);
        assert!(!w.offer(&at(90)));
        assert!(!w.offer(&at(110)));
        assert_eq!(w.seen(), 1);
        assert!(w.offer(&at(120)));
    }
}
