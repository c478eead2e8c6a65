//! `conductor replay`: a recording back on the bus, as live states flagged `REPLAYED`.
//!
//! Each recorded subsystem becomes a [`StatePublisher`] (with its tick event) whose states carry
//! the recorded metadata, except that they are read-only (no executor applies commands to a
//! replay) and indexed in recording order. Samples are published on the recording's timeline,
//! scaled by `--rate-scale`; `t_sample_ns` is that timeline on this machine's clock, so ages and
//! derivatives computed by subscribers are those of the replay.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use conductor_bus::{monotonic_ns, status, Bus, StateInfo, StateMeta, StatePublisher, StateSpec};
use indicatif::{ProgressBar, ProgressStyle};

use crate::cli::ReplayArgs;
use crate::error::{CliError, Result};
use crate::probe::Probe;
use crate::recording::{pass_ns, Recording, RecordingError};
use crate::select::Selector;

/// What a replay did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReplayReport {
    /// Samples published.
    pub published: u64,
    /// Complete passes over the recording.
    pub passes: u64,
}

/// Where each recorded channel goes: publisher number and state index within it.
struct Route {
    publisher: usize,
    index: usize,
}

/// Fails, naming them and their writers, when states of the recording are live in the domain:
/// their services exist with another owner's metadata, and iceoryx2 would refuse to open them
/// with ours (an `IncompatibleAttributes` error that names neither the state nor the fix).
fn refuse_live_states(
    bus: &Bus,
    subsystems: &[(String, Vec<StateSpec>)],
    args: &ReplayArgs,
) -> Result<()> {
    let live: Vec<StateInfo> = bus
        .list_states()?
        .into_iter()
        .filter(|s| {
            subsystems
                .iter()
                .any(|(sub, specs)| *sub == s.subsystem && specs.iter().any(|p| p.name == s.name))
        })
        .collect();
    let Some(first) = live.first() else {
        return Ok(());
    };
    // Who writes them, when that can be told (a state may vanish meanwhile).
    let writers = Probe::new(bus.domain())
        .and_then(|probe| {
            let names = probe.node_names()?;
            Ok(probe
                .open(first)
                .map(|p| p.writers(&names))
                .unwrap_or_default())
        })
        .unwrap_or_default();
    let shown: Vec<String> = live.iter().take(6).map(StateInfo::qualified_name).collect();
    let more = live.len().saturating_sub(shown.len());
    Err(CliError::Usage(format!(
        "cannot replay {} into domain {domain:?}: {} recorded state(s) are live there ({}{}){}; \
         replay into another domain, e.g. `conductor --domain replay replay {}` (subscribers \
         then use --domain replay or CONDUCTOR_DOMAIN=replay), or leave those states out with \
         --states",
        args.file.display(),
        live.len(),
        shown.join(", "),
        if more > 0 {
            format!(" and {more} more")
        } else {
            String::new()
        },
        if writers.is_empty() {
            String::new()
        } else {
            format!(
                ", {} written by {}",
                first.qualified_name(),
                writers.join(", ")
            )
        },
        args.file.display(),
        domain = bus.domain().name(),
    )))
}

/// Replays until the end (or, with `--loop`, until Ctrl-C).
pub fn run(bus: &Bus, args: &ReplayArgs) -> Result<ReplayReport> {
    if !(args.rate_scale > 0.0 && args.rate_scale.is_finite()) {
        return Err(CliError::Usage(format!(
            "--rate-scale must be positive, got {}",
            args.rate_scale
        )));
    }
    let mut rec = Recording::load(&args.file)?;
    if rec.truncated {
        eprintln!(
            "warning: {} ends early (was the recorder killed?); replaying what is readable",
            args.file.display()
        );
    }
    if let Some(p) = &args.states {
        let sel = Selector::new(p)?;
        let keep: Vec<bool> = rec
            .channels
            .iter()
            .map(|c| sel.matches(&c.subsystem, &c.state))
            .collect();
        rec.samples.retain(|s| keep[s.channel as usize]);
    }
    if rec.samples.is_empty() {
        return Err(RecordingError::Bad {
            path: args.file.clone(),
            detail: "no samples to replay".into(),
        }
        .into());
    }
    let mut used = vec![false; rec.channels.len()];
    for s in &rec.samples {
        used[s.channel as usize] = true;
    }

    // One publisher per subsystem, states in recording order.
    let mut subsystems: Vec<(String, Vec<StateSpec>)> = Vec::new();
    let mut routes: Vec<Option<Route>> = Vec::with_capacity(rec.channels.len());
    for (c, used) in rec.channels.iter().zip(&used) {
        if !*used {
            routes.push(None);
            continue;
        }
        let p = match subsystems.iter().position(|(s, _)| *s == c.subsystem) {
            Some(p) => p,
            None => {
                subsystems.push((c.subsystem.clone(), Vec::new()));
                subsystems.len() - 1
            }
        };
        let specs = &mut subsystems[p].1;
        // Re-indexed in its subsystem and read-only: no executor applies commands to a replay.
        let meta = StateMeta {
            index: specs.len() as u32,
            writable: false,
            ..c.meta.clone()
        };
        routes.push(Some(Route {
            publisher: p,
            index: specs.len(),
        }));
        specs.push(StateSpec::new(c.state.clone(), meta));
    }
    refuse_live_states(bus, &subsystems, args)?;
    let mut publishers = subsystems
        .iter()
        .map(|(sub, specs)| StatePublisher::create(bus, sub, specs))
        .collect::<std::result::Result<Vec<_>, _>>()?;
    let states: usize = publishers.iter().map(StatePublisher::len).sum();
    eprintln!(
        "replaying {} sample(s) of {states} state(s) from {} into domain {:?} at x{}",
        rec.samples.len(),
        args.file.display(),
        bus.domain().name(),
        args.rate_scale
    );
    if args.wait_subscribers > 0 {
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline && !conductor_bus::shutdown::requested() {
            let ready = publishers
                .iter()
                .all(|p| (0..p.len()).all(|i| p.subscribers(i) >= args.wait_subscribers));
            if ready {
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    let t_first = rec.samples[0].t_ns;
    let pass_ns = pass_ns(&rec, states);
    let bar = (!args.no_progress && std::io::stderr().is_terminal()).then(|| {
        let b = ProgressBar::new(rec.samples.len() as u64);
        if let Ok(style) =
            ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} samples")
        {
            b.set_style(style.progress_chars("=> "));
        }
        b
    });

    let start = Instant::now();
    let start_mono = monotonic_ns();
    let mut published = 0u64;
    let mut passes = 0u64;
    let mut notify = vec![false; publishers.len()];
    'outer: loop {
        let pass_offset = passes as f64 * pass_ns as f64;
        let mut i = 0;
        while i < rec.samples.len() {
            if conductor_bus::shutdown::requested() {
                break 'outer;
            }
            // Replay time of sample i, in ns since the start.
            let due_ns = |s: &crate::recording::Sample| {
                ((s.t_ns - t_first) as f64 + pass_offset) / args.rate_scale
            };
            let due = Duration::from_nanos(due_ns(&rec.samples[i]) as u64);
            if let Some(wait) = due.checked_sub(start.elapsed()) {
                // Sleep in short steps so Ctrl-C is honoured during long gaps.
                std::thread::sleep(wait.min(Duration::from_millis(50)));
                continue;
            }
            // Everything due by now goes out in one batch, then one tick event per subsystem.
            let now = start.elapsed().as_nanos() as f64;
            while i < rec.samples.len() && due_ns(&rec.samples[i]) <= now {
                let s = &rec.samples[i];
                if let Some(r) = &routes[s.channel as usize] {
                    let t_sample = start_mono + due_ns(s) as u64;
                    publishers[r.publisher].publish(
                        r.index,
                        s.tick,
                        t_sample,
                        s.value,
                        s.status | status::REPLAYED,
                    )?;
                    notify[r.publisher] = true;
                    published += 1;
                }
                i += 1;
            }
            for (p, n) in publishers.iter_mut().zip(&mut notify) {
                if std::mem::take(n) {
                    p.notify_tick()?;
                }
            }
            if let Some(b) = &bar {
                b.set_position(i as u64);
            }
        }
        passes += 1;
        if !args.repeat {
            break;
        }
    }
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    // Samples live in our shared memory: give subscribers a moment to read the last ones.
    std::thread::sleep(Duration::from_millis(500));
    eprintln!("replayed {published} sample(s) in {passes} pass(es)");
    Ok(ReplayReport { published, passes })
}
