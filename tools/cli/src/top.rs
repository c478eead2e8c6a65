//! `conductor top`: per-executor health from `conductor/<subsystem>/stats`.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

use conductor_bus::{monotonic_ns, Bus, ExecutorStats, StatsSubscriber};

use crate::cli::TopArgs;
use crate::error::{CliError, Result};
use crate::out;

/// Lateness in microseconds with one decimal.
fn us(ns: u64) -> String {
    format!("{:.1}", ns as f64 / 1e3)
}

/// One column of the table: its header in the default (narrow) and `--wide` tables, and its
/// cell. Columns without a narrow header appear only in the wide table.
struct Column {
    narrow: Option<&'static str>,
    wide: &'static str,
    cell: fn(&ExecutorStats, u64) -> String,
}

/// A [`Column`] on one line of [`COLUMNS`].
const fn col(
    narrow: Option<&'static str>,
    wide: &'static str,
    cell: fn(&ExecutorStats, u64) -> String,
) -> Column {
    Column { narrow, wide, cell }
}

/// `done/total`, or `-` when there is no total.
fn of(n: u32, total: u32) -> String {
    if total == 0 {
        "-".into()
    } else {
        format!("{n}/{total}")
    }
}

/// Every column after SUBSYSTEM, in table order. The narrow table (the default) keeps what tells
/// whether a subsystem is healthy and fits about 100 columns; `--wide` has every figure.
const COLUMNS: [Column; 22] = [
    col(Some("HZ"), "RATE_HZ", |s, _| {
        format!("{:.1}", s.achieved_rate_hz)
    }),
    col(None, "TARGET_HZ", |s, _| format!("{:.1}", s.base_rate_hz)),
    col(None, "LATE_P50_US", |s, _| us(s.lateness_p50_ns)),
    col(Some("P99_US"), "LATE_P99_US", |s, _| us(s.lateness_p99_ns)),
    col(None, "LATE_MAX_US", |s, _| us(s.lateness_max_ns)),
    col(Some("MISS"), "MISSES", |s, _| s.misses.to_string()),
    col(Some("STALE"), "STALE", |s, _| {
        format!("{}/{}", s.stale_states, s.states)
    }),
    col(Some("DEV"), "ENABLED", |s, _| {
        of(s.devices_enabled, s.devices)
    }),
    col(Some("TRIP"), "TRIPPED", |s, _| {
        s.devices_tripped.to_string()
    }),
    col(Some("FAULT"), "FAULTED", |s, _| {
        s.devices_faulted.to_string()
    }),
    col(None, "LINKS_DOWN", |s, _| s.links_down.to_string()),
    col(Some("BUS_ERR"), "BUS_ERR", |s, _| s.bus_errors.to_string()),
    col(Some("OUTAGE"), "OUTAGES", |s, _| s.bus_outages.to_string()),
    col(Some("LATE"), "LATE_REPLIES", |s, _| {
        s.late_replies.to_string()
    }),
    col(None, "FRAMES", |s, _| s.frames_applied.to_string()),
    col(None, "REJECTED", |s, _| s.setpoints_rejected.to_string()),
    col(Some("REFUSED"), "REFUSED", |s, _| {
        s.setpoints_refused.to_string()
    }),
    col(None, "CLAMPED", |s, _| s.setpoints_clamped.to_string()),
    col(None, "WATCHDOG", |s, _| s.watchdog_trips.to_string()),
    col(None, "FAULTS", |s, _| s.device_faults.to_string()),
    col(None, "RT", |s, _| match (s.rt_active, s.cpu) {
        (0, _) => "no".into(),
        (_, c) if c < 0 => "fifo".into(),
        (_, c) => format!("fifo@{c}"),
    }),
    col(Some("AGE"), "AGE", |s, now| {
        out::age(now.saturating_sub(s.t_ns) as f64 * 1e-9).replace(' ', "")
    }),
];

fn columns(wide: bool) -> impl Iterator<Item = &'static Column> {
    COLUMNS.iter().filter(move |c| wide || c.narrow.is_some())
}

/// The column headers of the narrow (default) or `--wide` table, matching [`row`].
pub fn header(wide: bool) -> Vec<&'static str> {
    std::iter::once("SUBSYSTEM")
        .chain(columns(wide).map(|c| {
            if wide {
                c.wide
            } else {
                c.narrow.unwrap_or(c.wide)
            }
        }))
        .collect()
}

/// The table row of one executor (`no-stats` and dashes before its first stats message).
pub fn row(subsystem: &str, s: Option<&ExecutorStats>, now_ns: u64, wide: bool) -> Vec<String> {
    let mut r = vec![subsystem.to_string()];
    match s {
        Some(s) => r.extend(columns(wide).map(|c| (c.cell)(s, now_ns))),
        None => {
            r.push("no-stats".into());
            r.extend(std::iter::repeat_n(
                "-".to_string(),
                columns(wide).count() - 1,
            ));
        }
    }
    r
}

/// Prints `--count` tables (or until Ctrl-C); returns the number printed.
pub fn run(bus: &Bus, args: &TopArgs) -> Result<u64> {
    if !(args.interval > 0.0 && args.interval.is_finite()) {
        return Err(CliError::Usage("--interval must be positive".into()));
    }
    let count = if args.once { Some(1) } else { args.count };
    let clear = std::io::stdout().is_terminal() && count != Some(1);
    let mut subs: Vec<(String, Option<StatsSubscriber>)> = Vec::new();
    let mut printed = 0u64;
    let mut first = true;
    loop {
        // Executors come and go: pick up new subsystems at every refresh.
        for name in bus.list_subsystems()? {
            if !subs.iter().any(|(n, _)| *n == name) {
                let sub = StatsSubscriber::new(bus, &name).ok();
                subs.push((name, sub));
            }
        }
        for (name, sub) in &mut subs {
            if sub.is_none() {
                *sub = StatsSubscriber::new(bus, name).ok();
            }
        }
        // Stats arrive about 10 times per second; the first time, wait for everyone's first.
        let deadline =
            Instant::now() + Duration::from_secs_f64(if first { args.wait } else { 0.0 });
        let mut latest: Vec<Option<ExecutorStats>>;
        loop {
            latest = subs
                .iter_mut()
                .map(|(_, s)| s.as_mut().and_then(|s| s.latest().ok().flatten()))
                .collect();
            if latest.iter().all(Option::is_some) || Instant::now() >= deadline {
                break;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        first = false;
        let now = monotonic_ns();
        let mut rows = vec![header(args.wide).into_iter().map(String::from).collect()];
        for ((name, _), s) in subs.iter().zip(&latest) {
            rows.push(row(name, s.as_ref(), now, args.wide));
        }
        let mut text = String::new();
        if clear {
            text += "\x1b[2J\x1b[H";
        }
        text += &format!("domain {}\n", bus.domain().name());
        if subs.is_empty() {
            text += "no executors\n";
        } else {
            text += &out::table(&rows);
        }
        let mut o = std::io::stdout().lock();
        if o.write_all(text.as_bytes())
            .and_then(|()| o.flush())
            .is_err()
        {
            return Ok(printed);
        }
        printed += 1;
        if count.is_some_and(|c| printed >= c) {
            return Ok(printed);
        }
        let next = Instant::now() + Duration::from_secs_f64(args.interval);
        while Instant::now() < next {
            if conductor_bus::shutdown::requested() {
                return Ok(printed);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}
