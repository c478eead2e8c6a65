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

/// The table row of one executor.
pub fn row(subsystem: &str, s: Option<&ExecutorStats>, now_ns: u64) -> Vec<String> {
    let Some(s) = s else {
        let mut r = vec![subsystem.to_string(), "no-stats".into()];
        r.extend(std::iter::repeat_n("-".to_string(), 13));
        return r;
    };
    vec![
        subsystem.to_string(),
        format!("{:.1}", s.achieved_rate_hz),
        format!("{:.1}", s.base_rate_hz),
        us(s.lateness_p50_ns),
        us(s.lateness_p99_ns),
        us(s.lateness_max_ns),
        s.misses.to_string(),
        s.bus_errors.to_string(),
        format!("{}/{}", s.stale_states, s.states),
        s.frames_applied.to_string(),
        s.setpoints_rejected.to_string(),
        s.setpoints_clamped.to_string(),
        s.watchdog_trips.to_string(),
        match (s.rt_active, s.cpu) {
            (0, _) => "no".into(),
            (_, c) if c < 0 => "fifo".into(),
            (_, c) => format!("fifo@{c}"),
        },
        out::age(now_ns.saturating_sub(s.t_ns) as f64 * 1e-9).replace(' ', ""),
    ]
}

/// The column headers, matching [`row`].
pub const HEADER: [&str; 15] = [
    "SUBSYSTEM",
    "RATE_HZ",
    "TARGET_HZ",
    "LATE_P50_US",
    "LATE_P99_US",
    "LATE_MAX_US",
    "MISSES",
    "BUS_ERR",
    "STALE",
    "FRAMES",
    "REJECTED",
    "CLAMPED",
    "WATCHDOG",
    "RT",
    "AGE",
];

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
        let mut rows = vec![HEADER.map(String::from).to_vec()];
        for ((name, _), s) in subs.iter().zip(&latest) {
            rows.push(row(name, s.as_ref(), now));
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
