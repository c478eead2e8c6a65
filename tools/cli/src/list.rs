//! `conductor list`: every state with its metadata, owning host, writer and the age of its latest
//! sample.

use std::time::{Duration, Instant};

use conductor_bus::{monotonic_ns, Bus};

use crate::cli::ListArgs;
use crate::error::{CliError, Result};
use crate::out;
use crate::probe::Probe;
use crate::select;

/// Prints the table; returns the number of states listed.
pub fn run(bus: &Bus, args: &ListArgs) -> Result<usize> {
    let states = select::states(bus, args.pattern.as_deref().unwrap_or("*"))?;
    if states.is_empty() {
        // A pattern that matches nothing is an error (like `ls missing`); an empty domain
        // listed without a pattern is an empty answer, said on stderr.
        let Some(pattern) = &args.pattern else {
            eprintln!(
                "no states in domain {:?} (is the executor running, in this domain?)",
                bus.domain().name()
            );
            return Ok(0);
        };
        let known = bus
            .list_states()?
            .iter()
            .take(12)
            .map(conductor_bus::StateInfo::qualified_name)
            .collect();
        return Err(CliError::NoMatch {
            pattern: pattern.clone(),
            domain: bus.domain().name().into(),
            known,
        });
    }
    let probe = Probe::new(bus.domain())?;
    // A service that vanished between listing and opening is shown without writer and age.
    let mut probed: Vec<_> = states.iter().map(|s| probe.open(s).ok()).collect();
    // New subscribers get the newest sample with the publisher's next send: wait at most
    // `--wait` for all of them.
    let deadline = Instant::now() + Duration::from_secs_f64(args.wait.max(0.0));
    loop {
        let mut all = true;
        for p in probed.iter_mut().flatten() {
            all &= p.poll()?;
        }
        if all || Instant::now() >= deadline {
            break;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let names = probe.node_names()?;
    let now = monotonic_ns();
    let this_host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_else(|_| "local".into());
    let mut rows = vec![[
        "STATE", "UNITS", "RATE_HZ", "RW", "LIMITS", "DEVICE", "HOST", "WRITER", "VALUE", "AGE",
    ]
    .map(String::from)
    .to_vec()];
    for (s, p) in states.iter().zip(&probed) {
        let m = &s.meta;
        let writer_names = p.as_ref().map(|p| p.writers(&names)).unwrap_or_default();
        // A mirror imported by `conductor bridge` is written by node `bridge@<owning host>`.
        let owner = conductor_bridge::owning_host(writer_names.iter().map(String::as_str));
        let mirrored = owner.is_some();
        let host = owner.map_or_else(|| this_host.clone(), str::to_string);
        let writers = Some(writer_names.join(","))
            .filter(|w| !w.is_empty())
            .unwrap_or_else(|| "-".into());
        let latest = p.as_ref().and_then(|p| p.latest());
        rows.push(vec![
            s.qualified_name(),
            if m.units.is_empty() {
                "-".into()
            } else {
                m.units.clone()
            },
            out::value(m.rate_hz),
            if m.writable { "rw" } else { "ro" }.into(),
            out::limits(m.min, m.max),
            if m.device.is_empty() {
                "-".into()
            } else {
                m.device.clone()
            },
            host,
            writers,
            latest.map_or("-".into(), |l| out::value(l.value)),
            latest.map_or("-".into(), |l| {
                // A mirror's t_sample_ns is on its owner's clock; its t_publish_ns is when it
                // was received here: age on this machine's clock, never two clocks mixed.
                let t = if mirrored {
                    l.t_publish_ns
                } else {
                    l.t_sample_ns
                };
                out::age(now.saturating_sub(t) as f64 * 1e-9)
            }),
        ]);
    }
    print!("{}", out::table(&rows));
    Ok(states.len())
}
