//! `conductor echo`: prints samples as they arrive, optionally decimated by sample time.

use std::io::Write;
use std::time::{Duration, Instant};

use conductor_bus::{status, Bus, StateSample, StateSubscriber};

use crate::cli::EchoArgs;
use crate::error::{CliError, Result};
use crate::{live_plot, out, select};

struct Echoed {
    sub: StateSubscriber,
    name: String,
    units: String,
    /// Sample time (ns) of the last printed line.
    last: Option<u64>,
}

/// One output line.
fn line(e: &Echoed, s: &StateSample, json: bool) -> String {
    let t = s.t_sample_ns as f64 * 1e-9;
    if json {
        serde_json::json!({
            "state": e.name,
            "t_sample": t,
            "value": s.value,
            "status": s.status,
            "flags": status::names(s.status).collect::<Vec<_>>(),
            "seq": s.seq,
            "tick": s.tick,
        })
        .to_string()
    } else {
        format!(
            "{t:.6}  {}  {}  {}  {}",
            e.name,
            out::value(s.value),
            if e.units.is_empty() { "-" } else { &e.units },
            out::flags(s.status)
        )
    }
}

/// Runs until `--count` lines, `--duration`, or Ctrl-C; returns the number of lines printed
/// (with `--plot`: the live chart of [`live_plot`], and the number of frames drawn).
pub fn run(bus: &Bus, args: &EchoArgs) -> Result<u64> {
    if let Some(r) = args.rate {
        if !(r > 0.0 && r.is_finite()) {
            return Err(CliError::Usage(format!("--rate must be positive, got {r}")));
        }
    }
    let min_gap_ns = args.rate.map_or(0, |r| (1e9 / r) as u64);
    if args.plot {
        let mut states = Vec::new();
        for info in select::states_wait(bus, &args.pattern, args.wait)? {
            let name = info.qualified_name();
            // A queue deep enough for 1 kHz states between two 10 Hz redraws.
            let sub = StateSubscriber::with_buffer(bus, &name, 256)?;
            states.push(live_plot::Plotted::new(name, info.meta.units.clone(), sub));
        }
        return live_plot::run(states, args);
    }
    let mut subs = Vec::new();
    for info in select::states_wait(bus, &args.pattern, args.wait)? {
        let name = info.qualified_name();
        subs.push(Echoed {
            sub: StateSubscriber::new(bus, &name)?,
            units: info.meta.units.clone(),
            name,
            last: None,
        });
    }
    let end = args
        .duration
        .map(|d| Instant::now() + Duration::from_secs_f64(d.max(0.0)));
    let stdout = std::io::stdout();
    let mut lines = 0u64;
    loop {
        let mut text = String::new();
        for e in &mut subs {
            while let Some(s) = e.sub.receive()? {
                // Decimate by sample time: a line when at least 1/rate passed since the last one.
                if e.last
                    .is_some_and(|t| s.t_sample_ns < t.saturating_add(min_gap_ns))
                {
                    continue;
                }
                e.last = Some(s.t_sample_ns);
                text += &line(e, &s, args.json);
                text.push('\n');
                lines += 1;
                if args.count.is_some_and(|c| lines >= c) {
                    break;
                }
            }
            if args.count.is_some_and(|c| lines >= c) {
                break;
            }
        }
        if !text.is_empty() {
            let mut lock = stdout.lock();
            if lock
                .write_all(text.as_bytes())
                .and_then(|()| lock.flush())
                .is_err()
            {
                return Ok(lines); // the reader went away (e.g. `| head`)
            }
        }
        if args.count.is_some_and(|c| lines >= c)
            || end.is_some_and(|t| Instant::now() >= t)
            || conductor_bus::shutdown::requested()
        {
            return Ok(lines);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}
