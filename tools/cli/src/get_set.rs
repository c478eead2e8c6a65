//! `conductor get` and `conductor set`.

use std::time::{Duration, Instant};

use conductor_bus::setpoint::{self, NotSent, VerdictWatch};
pub use conductor_bus::setpoint::{enable_state, refusal};
use conductor_bus::{
    monotonic_ns, status, Bus, BusError, Controller, StateSample, StateSubscriber,
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

/// `set`: checks the value against the state's metadata, sends one frame, and reports the
/// state's first sample that reflects the frame. A sample that says the executor refused it
/// (`REJECTED`) is an error ([`CliError::Refused`]) saying why and what to do; when no such
/// sample comes within `--wait` (or with `--wait 0`) the verdict is unknown and a note says so.
pub fn set(bus: &Bus, args: &SetArgs) -> Result<()> {
    let info = bus.resolve(&args.state)?;
    let name = info.qualified_name();
    let m = &info.meta;
    let (clamped, was_clamped) = match setpoint::check(m, args.value, args.clamp) {
        Ok(v) => v,
        Err(NotSent::NotFinite) => {
            return Err(BusError::NotFinite {
                name,
                value: args.value,
            }
            .into())
        }
        Err(NotSent::ReadOnly) => return Err(BusError::ReadOnly { name }.into()),
        Err(NotSent::OutOfLimits { min, max, nearest }) => {
            return Err(CliError::OutOfLimits {
                state: name,
                value: args.value,
                min,
                max,
                clamped: nearest,
            })
        }
    };
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
    let mut watch = VerdictWatch::new(t_send);
    let s = wait_for(&mut sub, args.wait, |s| watch.offer(s))?;
    let after = watch.seen();
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
    if setpoint::refused(&s) {
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
