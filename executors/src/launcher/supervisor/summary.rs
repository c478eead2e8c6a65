//! The live summary: one line per executor (rate, lateness, misses, bus errors, restarts, from
//! its stats), per gateway and for the view; redrawn in place on a terminal, printed every
//! interval otherwise.

use std::io::{IsTerminal, Write as _};
use std::time::{Duration, Instant};

use conductor_bus::{Bus, StatsSubscriber};
use conductor_manifest::{GatewayDef, ViewDef};

use super::{Phase, Role, Supervised, Supervisor};

/// What the summary keeps between two drawings: the launcher's bus node and a stats subscriber
/// per executor (opened only when a summary is shown).
pub(super) struct LiveSummary {
    bus: Option<Bus>,
    stats: Vec<Option<StatsSubscriber>>,
    tty: bool,
    interval: Duration,
    next: Instant,
    /// Lines drawn last time (to redraw them in place on a terminal).
    drawn: usize,
}

impl LiveSummary {
    /// Joins the domain for the executors' stats, unless the launch is quiet.
    pub(super) fn new(sup: &Supervisor) -> Self {
        let bus = if sup.opts.quiet {
            None
        } else {
            Bus::open(&sup.domain, "launcher").ok()
        };
        let stats = sup
            .children
            .iter()
            .map(|c| match c.role {
                Role::Executor => bus
                    .as_ref()
                    .and_then(|b| StatsSubscriber::new(b, &c.subsystem).ok()),
                // A gateway or the view publishes no executor stats.
                Role::Gateway(_) | Role::View(_) => None,
            })
            .collect();
        let tty = std::io::stderr().is_terminal();
        let interval = sup.opts.summary_interval.unwrap_or(if tty {
            Duration::from_secs(1)
        } else {
            Duration::from_secs(10)
        });
        Self {
            bus,
            stats,
            tty,
            interval,
            next: Instant::now() + interval,
            drawn: 0,
        }
    }

    /// Draws the summary on stderr when its interval has passed.
    pub(super) fn draw_if_due(&mut self, sup: &Supervisor, now: Instant) {
        if now < self.next {
            return;
        }
        self.next = now + self.interval;
        let Some(bus) = &self.bus else { return };
        let lines = sup.summary(bus, &mut self.stats);
        let mut err = std::io::stderr().lock();
        if self.tty && self.drawn > 0 {
            // Redraw the previous block in place.
            let _ = write!(err, "\x1b[{}A", self.drawn);
        }
        for l in &lines {
            let _ = writeln!(err, "{l}{}", if self.tty { "\x1b[K" } else { "" });
        }
        self.drawn = lines.len();
    }
}

impl Supervisor {
    pub(super) fn summary(&self, bus: &Bus, stats: &mut [Option<StatsSubscriber>]) -> Vec<String> {
        let mut lines = Vec::new();
        for (i, c) in self.children.iter().enumerate() {
            match &c.role {
                Role::Gateway(g) => {
                    lines.push(gateway_summary(c, g));
                    continue;
                }
                Role::View(v) => {
                    lines.push(view_summary(c, v));
                    continue;
                }
                Role::Executor => {}
            }
            if stats[i].is_none() {
                stats[i] = StatsSubscriber::new(bus, &c.subsystem).ok();
            }
            let s = stats[i].as_mut().and_then(|s| s.latest().ok().flatten());
            let state = match c.phase {
                Phase::Running { .. } => "",
                Phase::Starting { .. } => " (starting)",
                Phase::Waiting { .. } => " (restarting)",
                Phase::Stopped => " (stopped)",
            };
            lines.push(match s {
                Some(s) => format!(
                    "conductor: {:<16} {:>9.1} Hz of {}  lateness p99 {:>7.1} µs  max {:>8.1} µs  \
                     misses {}  bus errors {}  restarts {}{state}",
                    c.subsystem,
                    s.achieved_rate_hz,
                    s.base_rate_hz,
                    s.lateness_p99_ns as f64 / 1e3,
                    s.lateness_max_ns as f64 / 1e3,
                    s.misses,
                    s.bus_errors,
                    c.restarts
                ),
                None => format!("conductor: {:<16} (no stats yet){state}", c.subsystem),
            });
        }
        lines
    }
}

/// What an auxiliary process (a gateway, the view) is doing, for its summary line; `starting`
/// says what a started one that is not ready yet is doing.
fn auxiliary_state(c: &Supervised, starting: &str) -> String {
    match (&c.phase, &c.failed) {
        (_, Some(why)) => format!(" (given up: {why})"),
        (Phase::Running { .. }, _) => String::new(),
        (Phase::Starting { .. }, _) => format!(" ({starting})"),
        (Phase::Waiting { .. }, _) => " (restarting)".into(),
        (Phase::Stopped, _) => " (stopped)".into(),
    }
}

/// A gateway's summary line: its board, what it publishes, restarts, and what it is doing.
fn gateway_summary(c: &Supervised, g: &GatewayDef) -> String {
    let state = auxiliary_state(c, "waiting for its board");
    let what = if c.ready_text.is_empty() {
        String::new()
    } else {
        format!("{}  ", c.ready_text)
    };
    format!(
        "conductor: {:<16} {} gateway on {}  {what}restarts {}{state}",
        c.subsystem,
        g.kind.name(),
        g.port.display(),
        c.restarts
    )
}

/// The view's summary line: where it listens, restarts, and what it is doing.
fn view_summary(c: &Supervised, v: &ViewDef) -> String {
    let state = auxiliary_state(c, "starting");
    let url = if c.ready_text.is_empty() {
        format!("ws://{}", v.listen)
    } else {
        c.ready_text.clone()
    };
    format!(
        "conductor: {:<16} Foxglove view on {url}  restarts {}{state}",
        c.subsystem, c.restarts
    )
}
