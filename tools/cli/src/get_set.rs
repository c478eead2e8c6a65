//! `conductor get` and `conductor set`.

use std::time::{Duration, Instant};

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
/// state's first sample that reflects the frame.
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
    ctl.send_ctrl()?;
    let note = if was_clamped {
        format!(" (clamped from {})", out::value(args.value))
    } else {
        String::new()
    };
    println!("sent {name} <- {}{note}", out::value(clamped));
    if args.wait <= 0.0 {
        // The frame lives in our shared memory: stay long enough for the executor's next tick.
        std::thread::sleep(Duration::from_millis(200));
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
    match s {
        Some(s) => {
            println!("now  {}", describe(&name, &m.units, &s));
            if s.status & status::REJECTED != 0 {
                eprintln!("warning: the executor rejected the setpoint");
            }
        }
        None => eprintln!(
            "note: no new sample of {name} within {} s (is its executor ticking?)",
            args.wait
        ),
    }
    Ok(())
}
