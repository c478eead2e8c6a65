//! The campaign's result: per robot, the faults injected by kind, what the executors counted,
//! the recoveries and the worst recovery time, the safe states, the wrong values; what the
//! processes and the domain held; every check with its verdict. Printed as one table, written
//! as JSON.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Duration;

use serde::Serialize;

use super::episode::Episode;
use super::monitor::{Counted, Watched};
use super::rig::{Kind, Robot};
use super::Options;

/// A kind of fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Fault {
    /// Bytes corrupted or lost on a wire (counted in damaged packets towards the host).
    ByteFaults,
    /// Setpoints out of limits, NaN or infinite, from the controllers.
    BadSetpoints,
    /// The adapter unplugged and plugged back.
    Unplug,
    /// The executor SIGKILLed (the launcher restarts it).
    ExecutorKill,
    /// The controller SIGKILLed, a new one started.
    ControllerKill,
    /// The controller stopped (SIGSTOP), then continued.
    ControllerStall,
    /// Command frames back to back.
    Flood,
}

impl Fault {
    /// Its name in the table.
    pub fn name(self) -> &'static str {
        match self {
            Fault::ByteFaults => "damaged packets",
            Fault::BadSetpoints => "bad setpoints",
            Fault::Unplug => "unplug/replug",
            Fault::ExecutorKill => "executor SIGKILL",
            Fault::ControllerKill => "controller SIGKILL",
            Fault::ControllerStall => "controller SIGSTOP",
            Fault::Flood => "command flood",
        }
    }
}

/// Per kind: injected, recovered, worst recovery.
#[derive(Debug, Clone, Default, Serialize)]
pub struct KindTally {
    /// Times injected.
    pub injected: u64,
    /// What the executor counted for it (summed over its restarts; `None` when no counter
    /// matches this kind).
    pub counted: Option<u64>,
    /// Recoveries seen.
    pub recovered: u64,
    /// Worst recovery time (ms).
    pub worst_recovery_ms: f64,
    /// Mean recovery time (ms).
    pub mean_recovery_ms: f64,
    #[serde(skip)]
    sum_ns: u64,
}

/// What the campaign did to one robot.
#[derive(Debug, Clone)]
pub struct Tally {
    kinds: BTreeMap<Fault, KindTally>,
    safe_episodes: u64,
    safe_limit_ms: f64,
    deaths_uncounted: u64,
}

impl Tally {
    /// Nothing yet.
    pub fn new(_robot: &Robot) -> Self {
        Self {
            kinds: BTreeMap::new(),
            safe_episodes: 0,
            safe_limit_ms: 0.0,
            deaths_uncounted: 0,
        }
    }

    /// A controller death after which the watchdog counter did not move (and the devices were
    /// not tripped already).
    pub fn death_uncounted(&mut self) {
        self.deaths_uncounted += 1;
    }

    /// One more fault of kind `f`.
    pub fn injected(&mut self, f: Fault) {
        self.kinds.entry(f).or_default().injected += 1;
    }

    /// A recovery from `f` after `ns`.
    pub fn recovered(&mut self, f: Fault, ns: u64) {
        let k = self.kinds.entry(f).or_default();
        k.recovered += 1;
        k.sum_ns += ns;
        k.worst_recovery_ms = k.worst_recovery_ms.max(ns as f64 / 1e6);
        k.mean_recovery_ms = k.sum_ns as f64 / 1e6 / k.recovered as f64;
    }

    /// A controller death judged (the monitor keeps the verdicts and the bad ones).
    pub fn safe(&mut self, e: &Episode) {
        self.safe_episodes += 1;
        self.safe_limit_ms = e.limit_ms;
    }

    /// The robot's report.
    pub fn report(&self, robot: &Robot, w: &Watched, restarts: u64) -> RobotReport {
        let counted = w.counted();
        let mut kinds = self.kinds.clone();
        let k = |f| kinds.get(&f).map_or(0, |k: &KindTally| k.injected);
        let deaths = k(Fault::ControllerKill) + k(Fault::ControllerStall);
        kinds.entry(Fault::ByteFaults).or_default().injected = w.injected_up;
        kinds.get_mut(&Fault::ByteFaults).expect("set").counted = Some(counted.bus_errors);
        kinds.entry(Fault::BadSetpoints).or_default().counted =
            Some(counted.setpoints_rejected + counted.setpoints_clamped);
        if let Some(t) = kinds.get_mut(&Fault::Unplug) {
            t.counted = Some(counted.bus_outages);
        }
        if let Some(t) = kinds.get_mut(&Fault::ExecutorKill) {
            t.counted = Some(restarts);
        }
        // A death and a stall both trip the watchdog once: the two rows share the counter.
        if let Some(t) = kinds.get_mut(&Fault::ControllerKill) {
            t.counted = Some(counted.watchdog_trips);
        }
        if let Some(t) = kinds.get_mut(&Fault::ControllerStall) {
            t.counted = Some(counted.watchdog_trips);
        }
        if let Some(t) = kinds.get_mut(&Fault::Flood) {
            t.counted = Some(counted.frames_applied);
        }
        RobotReport {
            subsystem: robot.subsystem.clone(),
            kind: robot.kind,
            faults: kinds,
            controller_deaths: deaths,
            deaths_uncounted: self.deaths_uncounted,
            safe_state: SafeReport {
                episodes: self.safe_episodes,
                in_time: w.verdicts[0],
                resent: w.verdicts[1],
                late_tick: w.verdicts[2],
                late: w.verdicts[3],
                unsafe_stops: w.verdicts[4],
                never: w.verdicts[5],
                worst_ms: w.safe_worst_ms,
                watchdog_plus_tick_ms: (robot.watchdog_ns + robot.tick_ns) as f64 / 1e6,
                limit_ms: self.safe_limit_ms,
                bad: w.bad_episodes.clone(),
            },
            samples_checked: w.samples_checked,
            samples_stale: w.samples_stale,
            samples_unchecked: w.samples_unchecked,
            samples_misdated: w.samples_misdated,
            worst_sim_lag_ms: w.worst_sim_lag_ms,
            writes_checked: w.writes_checked,
            wrong_published: w.wrong_published,
            wrong_written: w.wrong_written,
            unsafe_events: w.unsafe_events,
            corrupted_bytes: w.corrupted_bytes,
            dropped_bytes: w.dropped_bytes,
            can_frames_lost: w.can_frames_lost,
            damaged_towards_devices: w.injected_down,
            worst_uncounted: w.worst_uncounted,
            counted,
            restarts,
            examples: w.examples.clone(),
        }
    }
}

/// The safe state after controller deaths, each timed from its controller's last command.
#[derive(Debug, Clone, Serialize)]
pub struct SafeReport {
    /// Controller deaths and stalls judged.
    pub episodes: u64,
    /// Every joint safe within the limit, and kept.
    pub in_time: u64,
    /// Safe and kept, later than the limit only by resending safe packets the wire damaged
    /// (see `episode::Verdict::Resent`).
    pub resent: u64,
    /// Safe and kept, later than the limit only by the executor's measured tick lateness at
    /// real-time priority (see `episode::Verdict::LateTick`).
    pub late_tick: u64,
    /// Safe and kept, but later than the limit.
    pub late: u64,
    /// A joint left its safe state, or held where the device was not.
    pub unsafe_stops: u64,
    /// A joint never reached it.
    pub never: u64,
    /// Worst time from the last command to the last joint's safe state (ms).
    pub worst_ms: f64,
    /// The watchdog plus one tick (ms).
    pub watchdog_plus_tick_ms: f64,
    /// The limit checked: watchdog + 1 tick + the allowances of `soak::episode` (ms).
    pub limit_ms: f64,
    /// Every late, unsafe or never-safe death, whole (at most `episode::KEPT`).
    pub bad: Vec<Episode>,
}

/// One robot's result.
#[derive(Debug, Clone, Serialize)]
pub struct RobotReport {
    /// Its subsystem.
    pub subsystem: String,
    /// Which robot.
    pub kind: Kind,
    /// Per fault kind.
    pub faults: BTreeMap<Fault, KindTally>,
    /// Controller deaths and stalls (each trips the watchdog once).
    pub controller_deaths: u64,
    /// Deaths after which the watchdog counter did not move (the devices not tripped before).
    pub deaths_uncounted: u64,
    /// Safe states.
    pub safe_state: SafeReport,
    /// Published samples compared with the simulator.
    pub samples_checked: u64,
    /// Published samples flagged STALE.
    pub samples_stale: u64,
    /// Published samples the monitor could not check (it fell behind).
    pub samples_unchecked: u64,
    /// Right values with a sample time too late by the simulator's own lateness (its thread
    /// starved of CPU): see `Watched::samples_misdated`.
    pub samples_misdated: u64,
    /// The largest simulator lateness behind a misdated sample (ms).
    pub worst_sim_lag_ms: f64,
    /// Values received by devices that were checked.
    pub writes_checked: u64,
    /// Wrong values published.
    pub wrong_published: u64,
    /// Wrong values written to a device.
    pub wrong_written: u64,
    /// Devices not safe while nobody commanded them.
    pub unsafe_events: u64,
    /// Bytes corrupted on the wires.
    pub corrupted_bytes: u64,
    /// Bytes dropped on the wires.
    pub dropped_bytes: u64,
    /// CAN frames lost on the wire.
    pub can_frames_lost: u64,
    /// Packets damaged on their way to the devices (reported, not compared: a lost write
    /// cannot be seen by the host).
    pub damaged_towards_devices: u64,
    /// Largest excess of damaged packets towards the host over bus errors counted, within
    /// one executor incarnation (≤ 0: all counted).
    pub worst_uncounted: i64,
    /// The executor's counters summed over its restarts.
    pub counted: Counted,
    /// Restarts by the launcher.
    pub restarts: u64,
    /// Examples of what went wrong.
    pub examples: Vec<String>,
}

/// One process's memory and descriptors.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ProcUsage {
    /// Process id.
    pub pid: u32,
    /// Samples: (s since the campaign started, RSS KiB, open descriptors).
    pub samples: Vec<(f64, u64, u64)>,
}

/// Whether what a series holds grows: the least it held in the last quarter of its life against
/// the most it held in the first half after the warm-up. A leak adds with every fault and keeps
/// what it took, so even the tail's least ends above the first half's envelope; the churn of
/// processes coming and going does not. `None` when too few samples were taken to say.
fn grows(samples: &[(f64, u64, u64)], warmup: f64, slack: (u64, u64)) -> Option<(bool, String)> {
    let start = samples.first()?.0 + warmup;
    let after: Vec<_> = samples.iter().filter(|s| s.0 >= start).collect();
    if after.len() < 4 {
        return None;
    }
    let mid = (after[0].0 + after[after.len() - 1].0) / 2.0;
    let first: Vec<_> = after.iter().filter(|s| s.0 <= mid).collect();
    let env = (
        first.iter().map(|s| s.1).max()?,
        first.iter().map(|s| s.2).max()?,
    );
    // The last quarter's least, not its last sample: a leak holds on to what it took, while a
    // sample taken mid-restart (old segments not yet reclaimed, new ones made) is a moment.
    let tail = &after[after.len() - (after.len() / 4).max(1)..];
    let least = (
        tail.iter().map(|s| s.1).min()?,
        tail.iter().map(|s| s.2).min()?,
    );
    let ok = least.0 <= env.0 + slack.0 && least.1 <= env.1 + slack.1;
    Some((
        !ok,
        format!(
            "at most {} and {} in {:.0}–{:.0} s, at least {} and {} in {:.0}–{:.0} s",
            env.0,
            env.1,
            after[0].0,
            mid,
            least.0,
            least.1,
            tail[0].0,
            tail[tail.len() - 1].0
        ),
    ))
}

/// What the processes and the domain held over time.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Resources {
    /// Per process name, per pid.
    pub processes: BTreeMap<String, Vec<ProcUsage>>,
    /// The domain's entries (shm files, node and service records): (s, count, 0).
    pub shm: Vec<(f64, u64, u64)>,
    /// Entries at the end that were not there after the warm-up (at most 20).
    pub shm_new: Vec<String>,
    /// Entries left once every process had stopped (removed then).
    pub left_after_stop: u64,
    #[serde(skip)]
    shm_base_names: Vec<String>,
}

/// Seconds a process (or the campaign) runs before its samples count.
const WARMUP_S: f64 = 5.0;

impl Resources {
    /// A sample of process `name`.
    pub fn sample(&mut self, name: &str, pid: u32, t: f64, rss: u64, fds: u64) {
        let v = self.processes.entry(name.into()).or_default();
        if v.last().is_none_or(|u| u.pid != pid) {
            v.push(ProcUsage {
                pid,
                samples: Vec::new(),
            });
        }
        v.last_mut().expect("pushed").samples.push((t, rss, fds));
    }

    /// A sample of the domain's entries (`last`: the end of the run).
    pub fn shm(&mut self, t: f64, names: Vec<String>, last: bool) {
        if self.shm_base_names.is_empty() && t >= 2.0 * WARMUP_S {
            self.shm_base_names = names.clone();
        }
        self.shm.push((t, names.len() as u64, 0));
        if last {
            self.shm_new = names
                .into_iter()
                .filter(|x| self.shm_base_names.binary_search(x).is_err())
                .take(20)
                .collect();
        }
    }
}

/// One check and its verdict.
#[derive(Debug, Clone, Serialize)]
pub struct Check {
    /// What is checked.
    pub name: String,
    /// Passed.
    pub ok: bool,
    /// The figures behind the verdict.
    pub detail: String,
}

/// The campaign's result.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// Seconds run.
    pub duration_s: f64,
    /// Seed.
    pub seed: u64,
    /// Byte corruption probability on every wire.
    pub corrupt: f64,
    /// Byte loss probability on every wire.
    pub drop: f64,
    /// Controller frame rate.
    pub rate_hz: f64,
    /// Per robot.
    pub robots: Vec<RobotReport>,
    /// Memory, descriptors, shared memory.
    pub resources: Resources,
    /// Every check.
    pub checks: Vec<Check>,
    /// Failures seen while running (recoveries that did not come, a launch that did not stop).
    pub failures: Vec<String>,
    /// The Score board's part, when it ran (see `score_campaign`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub board: Option<super::score_campaign::BoardReport>,
    /// Every check passed and nothing failed.
    pub passed: bool,
}

/// RSS growth tolerated after the warm-up (KiB): allocator and page-cache noise.
const RSS_SLACK_KIB: u64 = 2048;

impl Report {
    /// The report of a finished campaign, with its checks.
    pub fn new(
        o: &Options,
        took: Duration,
        robots: Vec<RobotReport>,
        resources: Resources,
        failures: Vec<String>,
    ) -> Self {
        let mut checks = Vec::new();
        let mut check =
            |name: String, ok: bool, detail: String| checks.push(Check { name, ok, detail });
        for r in &robots {
            let s = &r.subsystem;
            let inj = |f| r.faults.get(&f).map_or(0, |k| k.injected);
            check(
                format!("{s}: no wrong value published"),
                r.wrong_published == 0 && r.samples_checked > 0,
                format!(
                    "{} wrong of {} checked ({} stale)",
                    r.wrong_published, r.samples_checked, r.samples_stale
                ),
            );
            check(
                format!("{s}: no wrong value written to a device"),
                r.wrong_written == 0 && r.writes_checked > 0,
                format!("{} wrong of {} checked", r.wrong_written, r.writes_checked),
            );
            check(
                format!("{s}: safe state in time after every controller death, kept"),
                r.unsafe_events == 0
                    && r.safe_state.in_time + r.safe_state.resent + r.safe_state.late_tick
                        == r.controller_deaths
                    && r.safe_state.episodes == r.controller_deaths,
                format!(
                    "{} deaths, {} safe in time, {} in time but for resent damaged packets, {} in time but for the kernel's late tick, {} late, {} unsafe, {} never safe; worst {:.1} ms from the last command (limit {:.1} ms: watchdog + 1 tick {:.1} ms + allowances)",
                    r.controller_deaths, r.safe_state.in_time, r.safe_state.resent, r.safe_state.late_tick, r.safe_state.late, r.safe_state.unsafe_stops,
                    r.safe_state.never, r.safe_state.worst_ms, r.safe_state.limit_ms,
                    r.safe_state.watchdog_plus_tick_ms
                ),
            );
            check(
                format!("{s}: every unplug counted as a bus outage"),
                r.counted.bus_outages == inj(Fault::Unplug),
                format!(
                    "{} unplugs, {} outages counted",
                    inj(Fault::Unplug),
                    r.counted.bus_outages
                ),
            );
            check(
                format!("{s}: every controller death counted as a watchdog trip"),
                r.deaths_uncounted == 0 && r.counted.watchdog_trips >= r.controller_deaths,
                format!(
                    "{} deaths, {} trips counted, {} deaths without a trip (trips beyond the deaths: a controller starved of CPU longer than the watchdog)",
                    r.controller_deaths, r.counted.watchdog_trips, r.deaths_uncounted
                ),
            );
            check(
                format!("{s}: every executor kill restarted, and nothing else"),
                r.restarts == inj(Fault::ExecutorKill),
                format!(
                    "{} kills, {} restarts",
                    inj(Fault::ExecutorKill),
                    r.restarts
                ),
            );
            check(
                format!("{s}: every damaged packet towards the host counted as a bus error"),
                r.worst_uncounted <= 0 && r.counted.bus_errors >= inj(Fault::ByteFaults).min(1),
                format!(
                    "{} damaged, {} bus errors; worst uncounted within an incarnation {}",
                    inj(Fault::ByteFaults),
                    r.counted.bus_errors,
                    r.worst_uncounted
                ),
            );
            check(
                format!("{s}: bad setpoints rejected or clamped"),
                r.counted.setpoints_rejected + r.counted.setpoints_clamped > 0,
                format!(
                    "{} rejected, {} clamped",
                    r.counted.setpoints_rejected, r.counted.setpoints_clamped
                ),
            );
            // The kinds this campaign injects (`--faults`).
            for &f in &o.faults {
                let k = r.faults.get(&f).cloned().unwrap_or_default();
                check(
                    format!("{s}: {} injected and recovered from", f.name()),
                    k.injected > 0 && k.recovered == k.injected,
                    format!("{} injected, {} recovered", k.injected, k.recovered),
                );
            }
        }
        for (name, v) in &resources.processes {
            for u in v {
                let Some((grew, detail)) = grows(&u.samples, WARMUP_S, (RSS_SLACK_KIB, 0)) else {
                    continue;
                };
                check(
                    format!("{name} (pid {}): memory and descriptors do not grow", u.pid),
                    !grew,
                    format!("RSS KiB and descriptors: {detail}"),
                );
            }
        }
        if let Some((grew, detail)) = grows(&resources.shm, 2.0 * WARMUP_S, (0, 0)) {
            check(
                "the domain's shared memory does not grow".into(),
                !grew,
                format!(
                    "entries: {detail} (new since the warm-up: {:?})",
                    resources.shm_new
                ),
            );
        }
        let passed = checks.iter().all(|c| c.ok) && failures.is_empty();
        Self {
            duration_s: took.as_secs_f64(),
            seed: o.seed,
            corrupt: o.corrupt,
            drop: o.drop,
            rate_hz: o.rate_hz,
            robots,
            resources,
            checks,
            failures,
            board: None,
            passed,
        }
    }

    /// The table.
    pub fn table(&self) -> String {
        let mut t = String::new();
        let _ = writeln!(
            t,
            "Fault campaign: {:.0} s, seed {}, {} % of bytes corrupted and {} % dropped on every wire, controllers at {} Hz",
            self.duration_s,
            self.seed,
            self.corrupt * 100.0,
            self.drop * 100.0,
            self.rate_hz
        );
        let _ = writeln!(
            t,
            "{:<11} {:<20} {:>10} {:>12} {:>10} {:>14} {:>12}",
            "robot", "fault", "injected", "counted", "recovered", "worst recovery", "mean"
        );
        for r in &self.robots {
            for (f, k) in &r.faults {
                let counted = k.counted.map_or("-".to_string(), |c| c.to_string());
                // The controllers do not report how many bad values they sent (they are killed
                // at random): the executor's count of rejected and clamped setpoints is the
                // figure.
                let injected = if *f == Fault::BadSetpoints {
                    "-".to_string()
                } else {
                    k.injected.to_string()
                };
                let (rec, worst, mean) = if k.recovered > 0 {
                    (
                        k.recovered.to_string(),
                        format!("{:.1} ms", k.worst_recovery_ms),
                        format!("{:.1} ms", k.mean_recovery_ms),
                    )
                } else {
                    ("-".into(), "-".into(), "-".into())
                };
                let _ = writeln!(
                    t,
                    "{:<11} {:<20} {:>10} {:>12} {:>10} {:>14} {:>12}",
                    r.subsystem,
                    f.name(),
                    injected,
                    counted,
                    rec,
                    worst,
                    mean
                );
            }
            let _ = writeln!(
                t,
                "{:<11} safe state after {} controller deaths: {} in time, {} after resending damaged packets, {} after a tick the kernel ran late, {} late, {} unsafe, {} never; worst {:.1} ms from the last command (watchdog + 1 tick = {:.1} ms, limit {:.1} ms)",
                r.subsystem,
                r.controller_deaths,
                r.safe_state.in_time,
                r.safe_state.resent,
                r.safe_state.late_tick,
                r.safe_state.late,
                r.safe_state.unsafe_stops,
                r.safe_state.never,
                r.safe_state.worst_ms,
                r.safe_state.watchdog_plus_tick_ms,
                r.safe_state.limit_ms
            );
            for e in &r.safe_state.bad {
                t += &e.describe();
            }
            let _ = writeln!(
                t,
                "{:<11} wrong values published: {} of {} checked ({} stale, {} dated late by a starved simulator, worst {:.1} ms); written to devices: {} of {} checked",
                r.subsystem,
                r.wrong_published,
                r.samples_checked,
                r.samples_stale,
                r.samples_misdated,
                r.worst_sim_lag_ms,
                r.wrong_written,
                r.writes_checked
            );
        }
        if let Some(b) = &self.board {
            t.push_str(&b.table());
        }
        for c in self.checks.iter().filter(|c| !c.ok) {
            let _ = writeln!(t, "FAILED  {}: {}", c.name, c.detail);
        }
        for f in &self.failures {
            let _ = writeln!(t, "FAILED  {f}");
        }
        let _ = writeln!(
            t,
            "{} of {} checks passed{}",
            self.checks.iter().filter(|c| c.ok).count(),
            self.checks.len(),
            if self.passed { "" } else { " — FAILED" }
        );
        t
    }
}

#[cfg(test)]
mod grows_tests {
    use super::grows;

    fn series(values: &[u64]) -> Vec<(f64, u64, u64)> {
        values
            .iter()
            .enumerate()
            .map(|(i, &v)| (i as f64, v, 0))
            .collect()
    }

    #[test]
    fn a_leak_grows_and_a_moment_does_not() {
        // Steady at 10 with one sample mid-restart at the very end: not growth.
        let blip = series(&[10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 11]);
        assert!(!grows(&blip, 0.0, (0, 0)).unwrap().0);
        // One more entry kept after every fault: growth, even at the tail's least.
        let leak = series(&[10, 10, 11, 11, 12, 12, 13, 13, 14, 14, 15, 15]);
        assert!(grows(&leak, 0.0, (0, 0)).unwrap().0);
        assert!(grows(&series(&[1, 2]), 0.0, (0, 0)).is_none());
    }
}
