//! `conductor get` and `conductor set`.

use std::time::{Duration, Instant};

use conductor_bus::{
    monotonic_ns, status, Bus, BusError, Controller, StateInfo, StateSample, StateSubscriber,
};

use crate::cli::{GetArgs, SetArgs};
use crate::error::{CliError, Result};
use crate::out;

/// Waits up to `timeout` s for a sample of `sub` accepted by `pred`.
fn wait_for(
    sub: &mut StateSubscriber,
    timeout: f64,
    mut pred: impl FnMut(&StateSample) -> bool,
) -> Result<Option<StateSample>> {
    let deadline = Instant::now() + Duration::from_secs_f64(timeout.max(0.0));
    loop {
        while let Some(s) = sub.receive()? {
            if pred(&s) {
                return Ok(Some(s));
            }
        }
        if Instant::now() >= deadline || conductor_bus::shutdown::requested() {
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn describe(name: &str, units: &str, s: &StateSample) -> String {
    let age = monotonic_ns().saturating_sub(s.t_sample_ns) as f64 * 1e-9;
    format!(
        "{name} = {}{}{}  (seq {}, tick {}, age {}, flags {})",
        out::value(s.value),
        if units.is_empty() { "" } else { " " },
        units,
        s.seq,
        s.tick,
        out::age(age),
        out::flags(s.status)
    )
}

/// `get`: prints the newest sample.
pub fn get(bus: &Bus, args: &GetArgs) -> Result<StateSample> {
    let mut sub = StateSubscriber::with_buffer(bus, &args.state, 1)?;
    let name = sub.info().qualified_name();
    let units = sub.info().meta.units.clone();
    // The newest sample arrives with the owner's next publish (iceoryx2 history of 1).
    let s = wait_for(&mut sub, args.timeout, |_| true)?.ok_or_else(|| {
        CliError::Timeout(format!("no sample of {name} within {} s", args.timeout))
    })?;
    if args.raw {
        println!("{}", out::value(s.value));
    } else {
        println!("{}", describe(&name, &units, &s));
    }
    Ok(s)
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

/// `set`: checks the value against the state's metadata, sends one frame, and reports the
/// state's first sample that reflects the frame. A sample that says the executor refused it
/// (`REJECTED`) is an error ([`CliError::Refused`]) saying why and what to do; when no such
/// sample comes within `--wait` (or with `--wait 0`) the verdict is unknown and a note says so.
pub fn set(bus: &Bus, args: &SetArgs) -> Result<()> {
    let info = bus.resolve(&args.state)?;
    let name = info.qualified_name();
    let m = &info.meta;
    if !args.value.is_finite() {
        return Err(BusError::NotFinite {
            name,
            value: args.value,
        }
        .into());
    }
    if !m.writable {
        return Err(BusError::ReadOnly { name }.into());
    }
    let (clamped, was_clamped) = m.clamp(args.value);
    if was_clamped && !args.clamp {
        return Err(CliError::OutOfLimits {
            state: name,
            value: args.value,
            min: m.min,
            max: m.max,
            clamped,
        });
    }
    // Subscribe before sending, so the samples after the frame are ours to see.
    let mut sub = StateSubscriber::with_buffer(bus, &name, 64)?;
    let mut ctl = Controller::new(bus);
    ctl.add_ctrl(&name, clamped)?;
    let t_send = monotonic_ns();
    // A frame nobody receives was not delivered: say so and fail rather than print "sent".
    ctl.send_ctrl_checked()?;
    let note = if was_clamped {
        format!(" (clamped from {})", out::value(args.value))
    } else {
        String::new()
    };
    println!("sent {name} <- {}{note}", out::value(clamped));
    if args.wait <= 0.0 {
        // The frame lives in our shared memory: stay long enough for the executor's next tick.
        std::thread::sleep(Duration::from_millis(200));
        eprintln!(
            "note: not checked whether the executor took it (--wait 0 does not wait for {name}'s \
             samples)"
        );
        return Ok(());
    }
    // The first sample published after the send may come from a tick that drained its commands
    // just before; the second one is from a tick that started after the send.
    let mut after = 0;
    let s = wait_for(&mut sub, args.wait, |s| {
        if s.t_publish_ns > t_send {
            after += 1;
        }
        after >= 2
    })?;
    let Some(s) = s else {
        eprintln!(
            "note: {} of {name} within {} s (is its executor ticking?): not checked whether the \
             executor took it",
            if after == 0 {
                "no new sample"
            } else {
                "only one new sample, maybe from a tick before the frame,"
            },
            args.wait
        );
        return Ok(());
    };
    println!("now  {}", describe(&name, &m.units, &s));
    if s.status & status::REJECTED != 0 {
        // The flags are those of the tick that applied the frame: REJECTED means ours was refused.
        let states = bus.list_states()?;
        let enable = enable_state(&states, &info);
        return Err(CliError::Refused {
            state: name,
            value: out::value(clamped),
            reason: refusal(s.status, &info, enable.as_ref()),
        });
    }
    let off = s.status & (status::DISABLED | status::TRIPPED);
    if off != 0 {
        // Taken (an enable state, or the first setpoint of a device that starts held off), but
        // the device is not driving at this sample: say so rather than let it look like it is.
        eprintln!(
            "note: {} is not driving at this sample ({}): setpoints to its other states are \
             refused until those flags clear",
            if m.device.is_empty() {
                "its device".to_string()
            } else {
                format!("device {}", m.device)
            },
            out::flags(off)
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use conductor_bus::StateMeta;

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
}
