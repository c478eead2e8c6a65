//! One controller death, followed from outside: when its last command left, when each joint
//! reached its documented safe state at the simulator (and whether it left it, when and for
//! what), what each device held, and how late the executor's ticks were around it. Every death
//! is judged against watchdog + 1 tick from the last command; the late and unsafe ones are kept
//! whole for the report.

use conductor_bus::histogram;
use serde::Serialize;

/// Small allowances of the safe-state deadline, beyond watchdog + 1 tick (see RELIABILITY.md,
/// "Fault campaign (soak)"): the trip tick's own work before the safe action's packet leaves,
/// and that packet's time on the wire (a Dynamixel WRITE/SYNC WRITE at 1 Mbit/s: 0.2–0.5 ms;
/// three CAN frames through the SLCAN adapter: 0.1 ms and a pty).
pub const SEND_ALLOWANCE_NS: u64 = 1_000_000;
/// A safe action not confirmed is sent again this often (the devices' lifecycle,
/// `SAFE_RETRY_NS`): a safe packet damaged on the wire reaches the device that much later.
pub const SAFE_RETRY_NS: u64 = 20_000_000;
/// Late and unsafe episodes kept whole in the report (the counts go on).
pub const KEPT: usize = 50;

/// How the controller died.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Death {
    /// Killed.
    #[serde(rename = "SIGKILL")]
    Kill,
    /// Stopped: its clock stalls.
    #[serde(rename = "SIGSTOP")]
    Stop,
}

impl Death {
    /// The signal's name.
    pub fn name(self) -> &'static str {
        match self {
            Death::Kill => "SIGKILL",
            Death::Stop => "SIGSTOP",
        }
    }
}

/// The verdict on one death.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Every joint safe in time, and kept there.
    InTime,
    /// Safe and kept, later than the limit only by the resending of safe packets the wire
    /// damaged on their way to the devices (at most one retry interval and one tick per
    /// packet damaged from the watchdog's firing to the safe state), the executor's
    /// `WATCHDOG` published in time.
    Resent,
    /// Safe and kept, later than the limit (and the resending) only by the executor's own
    /// measured tick lateness in the episode, at real-time priority: the kernel ran the trip
    /// tick late, the executor's count of ticks was kept. Counted apart so that a machine's
    /// latency shows as such and never hides in "in time".
    LateTick,
    /// Every joint safe and kept, but at least one after the deadline.
    Late,
    /// A joint left its safe state (or held a position the device was not at).
    Unsafe,
    /// A joint never reached its safe state.
    Never,
}

/// One joint through one death.
#[derive(Debug, Clone, Default, Serialize)]
pub struct JointEpisode {
    /// Its state.
    pub name: String,
    /// When its samples first carried `WATCHDOG` (their publication, ms after the last command).
    pub flagged_ms: Option<f64>,
    /// When the device reached its safe state, seen at the simulator (ms after the last
    /// command).
    pub safe_ms: Option<f64>,
    /// When it left it (ms after the last command).
    pub left_ms: Option<f64>,
    /// What it went to.
    pub left_to: Option<String>,
    /// Torque on / in motor mode, when it was reached (or at the end when never).
    pub torque: bool,
    /// Dynamixel: Goal Position then (rad); MIT: not known (NaN, written null).
    pub goal: f64,
    /// Present position then (rad).
    pub present: f64,
    /// A hold written where the device was not (Dynamixel): (goal, present) at the write, rad.
    pub bad_hold: Option<(f64, f64)>,
}

/// One controller death.
#[derive(Debug, Clone, Serialize)]
pub struct Episode {
    /// The robot.
    pub robot: String,
    /// Its controller deaths so far, this one included.
    pub number: u64,
    /// How it died.
    pub death: Death,
    /// When (s since the campaign started).
    pub kill_s: f64,
    /// The last command frame the executor got from it, before the kill (ms); `None`: none
    /// seen (then the kill is the origin).
    pub last_command_before_kill_ms: Option<f64>,
    /// The deadline (ms after the last command): watchdog + 1 tick + the allowances.
    pub limit_ms: f64,
    /// When the last joint reached its safe state (ms after the last command).
    pub worst_ms: Option<f64>,
    /// Per joint.
    pub joints: Vec<JointEpisode>,
    /// The executor's worst tick lateness from the kill to the end of the episode (the upper
    /// bound of its lateness histogram's bucket, ms); `None`: no statistics in between.
    pub tick_lateness_ms: Option<f64>,
    /// Its executor restarted during the episode.
    pub executor_restarted: bool,
    /// Packets towards the devices the wire damaged from one tick before the watchdog could
    /// fire until every joint was safe (a damaged safe packet is sent again).
    pub damaged_towards_devices: u64,
    /// The tick (ms).
    pub tick_ms: f64,
    /// The executors ran with real-time priority: the limit is strict. Without it (`--no-rt`)
    /// the executor's worst tick lateness in the episode is added to the limit: then the
    /// machine's load, not the executor, decides how late a tick runs.
    pub executors_rt: bool,
    /// The verdict.
    pub verdict: Verdict,
    #[serde(skip)]
    pub(crate) origin_ns: u64,
    #[serde(skip)]
    pub(crate) hist0: Option<(u64, Box<[u64; histogram::BUCKETS]>)>,
}

impl Episode {
    /// A death at `kill_ns` whose source last spoke at `last_ns`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        robot: &str,
        number: u64,
        death: Death,
        kill_s: f64,
        kill_ns: u64,
        last_ns: Option<u64>,
        limit_ns: u64,
        joints: &[String],
    ) -> Self {
        // A frame stamped after the campaign read its clock still left before the signal
        // landed: the newest frame seen is the origin whatever its stamp.
        let origin_ns = last_ns.unwrap_or(kill_ns);
        Self {
            robot: robot.into(),
            number,
            death,
            kill_s,
            last_command_before_kill_ms: last_ns.map(|l| (kill_ns as f64 - l as f64) / 1e6),
            limit_ms: limit_ns as f64 / 1e6,
            worst_ms: None,
            joints: joints
                .iter()
                .map(|n| JointEpisode {
                    name: n.clone(),
                    goal: f64::NAN,
                    ..JointEpisode::default()
                })
                .collect(),
            tick_lateness_ms: None,
            executor_restarted: false,
            damaged_towards_devices: 0,
            tick_ms: 0.0,
            executors_rt: true,
            verdict: Verdict::Never,
            origin_ns,
            hist0: None,
        }
    }

    /// Milliseconds from the origin (the last command) to `t_ns`.
    pub fn ms(&self, t_ns: u64) -> f64 {
        (t_ns as f64 - self.origin_ns as f64) / 1e6
    }

    /// Whether every joint has reached its safe state.
    pub fn all_safe(&self) -> bool {
        self.joints.iter().all(|j| j.safe_ms.is_some())
    }

    /// Judges it (at its end): `hist1` is the executor's latest lateness histogram.
    pub fn close(&mut self, hist1: Option<(u64, &[u64; histogram::BUCKETS])>) {
        if let (Some((t0, h0)), Some((t1, h1))) = (&self.hist0, hist1) {
            // The same incarnation (its ticks went on): the buckets that grew.
            let worst = (0..histogram::BUCKETS)
                .rev()
                .find(|&b| t1 >= *t0 && h1[b] > h0[b]);
            self.tick_lateness_ms = worst.map(|b| histogram::bucket_range(b).1 as f64 / 1e6);
            self.executor_restarted |= t1 < *t0;
        }
        self.worst_ms = self
            .joints
            .iter()
            .map(|j| j.safe_ms)
            .try_fold(f64::NEG_INFINITY, |m, s| s.map(|s| m.max(s)));
        self.verdict = if self
            .joints
            .iter()
            .any(|j| j.left_ms.is_some() || j.bad_hold.is_some())
        {
            Verdict::Unsafe
        } else if !self.all_safe() {
            Verdict::Never
        } else if self.worst_ms.is_some_and(|w| {
            let lateness = if self.executors_rt {
                0.0
            } else {
                self.tick_lateness_ms.unwrap_or(0.0)
            };
            w > self.limit_ms + lateness
        }) {
            let resend =
                self.damaged_towards_devices as f64 * (SAFE_RETRY_NS as f64 / 1e6 + self.tick_ms);
            let flagged_in_time = self
                .joints
                .iter()
                .all(|j| j.flagged_ms.is_some_and(|f| f <= self.limit_ms));
            let within = |allowance: f64| {
                self.worst_ms
                    .is_some_and(|w| w <= self.limit_ms + allowance)
            };
            if flagged_in_time && within(resend) {
                Verdict::Resent
            } else if self.executors_rt && within(resend + self.tick_lateness_ms.unwrap_or(0.0)) {
                Verdict::LateTick
            } else {
                Verdict::Late
            }
        } else {
            Verdict::InTime
        };
    }

    /// One line per joint, for the table.
    pub fn describe(&self) -> String {
        let ms = |x: Option<f64>| x.map_or("never".into(), |v| format!("{v:.1} ms"));
        let mut s = format!(
            "  {} death {} ({}) at {:.3} s: {:?}; last command {} before the kill; deadline {:.1} ms; {} packets towards the devices damaged meanwhile; executor tick lateness up to {}{}\n",
            self.robot,
            self.number,
            self.death.name(),
            self.kill_s,
            self.verdict,
            self.last_command_before_kill_ms
                .map_or("not seen".into(), |v| format!("{v:.1} ms")),
            self.limit_ms,
            self.damaged_towards_devices,
            self.tick_lateness_ms
                .map_or("? (no statistics)".into(), |v| format!("{v:.2} ms")),
            if self.executor_restarted {
                "; its executor restarted meanwhile"
            } else {
                ""
            }
        );
        for j in &self.joints {
            s += &format!(
                "    {:<8} WATCHDOG flag {}, safe {}, torque {}, goal {:.4}, present {:.4}",
                j.name,
                ms(j.flagged_ms),
                ms(j.safe_ms),
                if j.torque { "on" } else { "off" },
                j.goal,
                j.present
            );
            if let Some((g, p)) = j.bad_hold {
                s += &format!("; held at {g:.4} where the device was at {p:.4}");
            }
            if let (Some(t), Some(to)) = (j.left_ms, &j.left_to) {
                s += &format!("; left it at {t:.1} ms: {to}");
            }
            s += "\n";
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ep() -> Episode {
        Episode::new(
            "leg",
            1,
            Death::Kill,
            1.0,
            1_000_000_000,
            Some(990_000_000),
            505_000_000,
            &["a".into(), "b".into()],
        )
    }

    #[test]
    fn verdicts() {
        let mut e = ep();
        assert_eq!(e.ms(1_000_000_000), 10.0);
        e.close(None);
        assert_eq!(e.verdict, Verdict::Never);
        e.joints[0].safe_ms = Some(500.0);
        e.joints[1].safe_ms = Some(504.0);
        e.close(None);
        assert_eq!((e.verdict, e.worst_ms), (Verdict::InTime, Some(504.0)));
        e.joints[1].safe_ms = Some(506.0);
        e.close(None);
        assert_eq!(e.verdict, Verdict::Late);
        // One safe packet damaged on the way, sent again 20 ms on: resent, not late.
        e.damaged_towards_devices = 1;
        e.tick_ms = 4.0;
        e.joints[0].flagged_ms = Some(501.0);
        e.joints[1].flagged_ms = Some(501.0);
        e.joints[1].safe_ms = Some(526.0);
        e.close(None);
        assert_eq!(e.verdict, Verdict::Resent);
        e.joints[1].safe_ms = Some(531.0);
        e.close(None);
        assert_eq!(e.verdict, Verdict::Late);
        // The trip tick ran 1.6 ms late at real-time priority: late only by the machine.
        e.damaged_towards_devices = 0;
        e.joints[1].safe_ms = Some(506.1);
        e.tick_lateness_ms = Some(1.6);
        e.close(None);
        assert_eq!(e.verdict, Verdict::LateTick);
        e.joints[1].safe_ms = Some(506.7);
        e.close(None);
        assert_eq!(e.verdict, Verdict::Late);
        // Without real-time priority that lateness is part of the limit itself.
        e.executors_rt = false;
        e.joints[1].safe_ms = Some(506.1);
        e.close(None);
        assert_eq!(e.verdict, Verdict::InTime);
        e.executors_rt = true;
        e.joints[0].left_ms = Some(600.0);
        e.joints[0].left_to = Some("torque off".into());
        e.close(None);
        assert_eq!(e.verdict, Verdict::Unsafe);
        assert!(e.describe().contains("left it at 600.0 ms: torque off"));
    }
}
