//! The soak's eyes, outside the executors: a thread that every millisecond reads what the
//! simulators hold (positions, goals, torque or motor mode, every frame a motor received) and
//! what the bus carries (every state sample, every executor's stats), and checks them:
//!
//! * a sample published without `STALE` must be finite and a position the device really had
//!   (within one encoder step) between its sample time (the request) and its publication;
//! * no sample without `STALE` while the bus is unplugged;
//! * every value a device received is inside its joint's limits (Dynamixel Goal Position; MIT
//!   commands, whose gains must be the manifest's);
//! * after its controller died, a robot reaches its safe state (MIT: every motor out of motor
//!   mode; Dynamixel: every joint published `WATCHDOG` with the servo's torque on, holding) and
//!   stays there until a controller enables it again;
//! * the executors' counters, summed over their restarts, and whether the byte faults the
//!   simulators injected towards the host are all counted as bus errors.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use conductor_bus::{
    histogram, monotonic_ns, status, Bus, CommandFrame, Domain, ExecutorStats, RtIpc, StateSample,
    StateSubscriber, StatsSubscriber,
};
use conductor_devices::protocol_stage::mit_limits;
use conductor_protocols::mit_can::{decode_command, MotorCommand};
use embedded_can::Frame;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

use super::episode::{Episode, Verdict, KEPT};
use super::rig::{DeviceTruth, Robot, Sim, PULSE};

/// How long the truth history reaches back.
const HISTORY_NS: u64 = 3_000_000_000;
/// How far from where a joint is a command may be and still count as holding it there (rad).
const HOLD_TOLERANCE: f64 = 0.02;
/// How far from a position the servo had a hold's Goal Position may be (pulses).
const HOLD_PULSES: f64 = 3.0;
/// How far back a hold's Goal Position may have been read (ns): the executor holds where it
/// last read the servo, a few ticks ago when reads were lost.
const HOLD_SPAN_NS: u64 = 200_000_000;
/// The longest gap between two polls of the simulator a published value is judged across.
const GAP_NS: u64 = 5_000_000;
/// The Dynamixel X Goal Position register.
const GOAL_POSITION: u16 = 116;
/// Examples of each kind of failure kept for the report.
const EXAMPLES: usize = 5;

/// Executor counters summed over an executor's restarts.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct Counted {
    /// Bus errors.
    pub bus_errors: u64,
    /// Bus outages.
    pub bus_outages: u64,
    /// Watchdog trips.
    pub watchdog_trips: u64,
    /// Command frames applied.
    pub frames_applied: u64,
    /// Setpoints rejected (NaN, infinite, refused).
    pub setpoints_rejected: u64,
    /// Setpoints clamped to limits.
    pub setpoints_clamped: u64,
    /// Setpoints refused by a disabled or tripped device.
    pub setpoints_refused: u64,
    /// Late replies.
    pub late_replies: u64,
    /// Device fault transitions.
    pub device_faults: u64,
    /// Deadline misses.
    pub misses: u64,
    /// Ticks.
    pub ticks: u64,
    /// Largest tick lateness seen (ns).
    pub lateness_max_ns: u64,
    /// Executor incarnations seen (1 + restarts).
    pub incarnations: u64,
}

impl Counted {
    fn of(s: &ExecutorStats) -> Self {
        Self {
            bus_errors: s.bus_errors,
            bus_outages: s.bus_outages,
            watchdog_trips: s.watchdog_trips,
            frames_applied: s.frames_applied,
            setpoints_rejected: s.setpoints_rejected,
            setpoints_clamped: s.setpoints_clamped,
            setpoints_refused: s.setpoints_refused,
            late_replies: s.late_replies,
            device_faults: s.device_faults,
            misses: s.misses,
            ticks: s.ticks,
            lateness_max_ns: s.lateness_max_ns,
            incarnations: 1,
        }
    }

    fn add(&self, o: &Self) -> Self {
        Self {
            bus_errors: self.bus_errors + o.bus_errors,
            bus_outages: self.bus_outages + o.bus_outages,
            watchdog_trips: self.watchdog_trips + o.watchdog_trips,
            frames_applied: self.frames_applied + o.frames_applied,
            setpoints_rejected: self.setpoints_rejected + o.setpoints_rejected,
            setpoints_clamped: self.setpoints_clamped + o.setpoints_clamped,
            setpoints_refused: self.setpoints_refused + o.setpoints_refused,
            late_replies: self.late_replies + o.late_replies,
            device_faults: self.device_faults + o.device_faults,
            misses: self.misses + o.misses,
            ticks: self.ticks + o.ticks,
            lateness_max_ns: self.lateness_max_ns.max(o.lateness_max_ns),
            incarnations: self.incarnations + o.incarnations,
        }
    }
}

/// What the monitor knows about one robot; shared with the campaign.
#[derive(Debug, Default)]
pub struct Watched {
    /// Samples checked against the simulator.
    pub samples_checked: u64,
    /// Samples flagged `STALE` (not checked: the executor says it has no fresh value).
    pub samples_stale: u64,
    /// Samples the monitor could not judge: too old for its history, or (when not matching)
    /// from a time it did not poll the simulator for more than 5 ms (it did not get the CPU).
    pub samples_unchecked: u64,
    /// Samples whose value the device had, but earlier than their sample time, when the
    /// simulator's thread had been starved of CPU and sent its reply that much late (the
    /// executor cannot tell such a reply from a timely one; a real device is not late).
    pub samples_misdated: u64,
    /// The largest lateness of the simulator accepted for a misdated sample (ms).
    pub worst_sim_lag_ms: f64,
    /// Published values that were wrong (not a position the device had, not finite, fresh
    /// while the bus was unplugged).
    pub wrong_published: u64,
    /// Values written to a device outside its limits or with the wrong gains.
    pub wrong_written: u64,
    /// Values received by the devices that were checked.
    pub writes_checked: u64,
    /// A device left its safe state (or never reached it) while no controller commanded it.
    pub unsafe_events: u64,
    /// Examples of the above.
    pub examples: Vec<String>,
    /// Per joint: the newest sample time of a sample without `STALE`.
    pub fresh_ns: Vec<u64>,
    /// Per joint: the newest status flags.
    pub flags: Vec<u32>,
    /// The newest command frame's send time seen on the robot's command service.
    pub last_command_ns: Option<u64>,
    /// The controller death under way: followed joint by joint until the campaign closes it.
    pub episode: Option<Episode>,
    /// Deaths judged, by verdict: in time, resent, late tick, late, unsafe, never safe.
    pub verdicts: [u64; 6],
    /// The latest safe state of a death, from its last command (ms).
    pub safe_worst_ms: f64,
    /// Late, unsafe and never-safe deaths, whole (at most [`KEPT`]).
    pub bad_episodes: Vec<Episode>,
    /// The running executor's latest lateness histogram: (its ticks, counts).
    pub hist: Option<(u64, Box<[u64; histogram::BUCKETS]>)>,
    /// Unplugs: samples with a sample time inside a window must be `STALE` (from one tick
    /// and a timeout after the unplug to the replug; `u64::MAX` while unplugged).
    pub unplugged: Vec<(u64, u64)>,
    /// Counters of finished executor incarnations.
    pub counted_done: Counted,
    /// Counters of the running one.
    pub counted_now: Option<Counted>,
    /// Damaged packets the simulator sent towards the host (serial and CAN wire).
    pub injected_up: u64,
    /// Damaged chunks the host sent (corrupted or cut instructions; a lost write cannot be
    /// seen by the host, so these are reported, not compared).
    pub injected_down: u64,
    /// Bytes corrupted and dropped on the wires (both directions).
    pub corrupted_bytes: u64,
    /// See `corrupted_bytes`.
    pub dropped_bytes: u64,
    /// CAN frames lost on the wire (both directions).
    pub can_frames_lost: u64,
    /// Largest excess of damaged packets towards the host over bus errors counted, within one
    /// executor incarnation (0 or less: every one counted).
    pub worst_uncounted: i64,
}

impl Watched {
    fn example(&mut self, text: String) {
        if self.examples.len() < EXAMPLES * 4 {
            let t = monotonic_ns() as f64 / 1e9;
            eprintln!("soak: at {t:.3} s: {text}");
            self.examples.push(format!("at {t:.3} s: {text}"));
        }
    }

    /// Ends the episode under way: judged, counted, kept when it went wrong.
    pub fn close_episode(&mut self) -> Option<Episode> {
        let mut e = self.episode.take()?;
        e.close(self.hist.as_ref().map(|(t, h)| (*t, &**h)));
        let k = match e.verdict {
            Verdict::InTime => 0,
            Verdict::Resent => 1,
            Verdict::LateTick => 2,
            Verdict::Late => 3,
            Verdict::Unsafe => 4,
            Verdict::Never => 5,
        };
        self.verdicts[k] += 1;
        if let Some(w) = e.worst_ms {
            self.safe_worst_ms = self.safe_worst_ms.max(w);
        }
        if k >= 2 {
            self.unsafe_events += (k >= 4) as u64;
            eprint!("soak: {}", e.describe());
            if self.bad_episodes.len() < KEPT {
                self.bad_episodes.push(e.clone());
            }
        }
        Some(e)
    }

    /// Counters summed over every incarnation so far.
    pub fn counted(&self) -> Counted {
        match &self.counted_now {
            Some(c) => self.counted_done.add(c),
            None => self.counted_done,
        }
    }
}

/// Locks ignoring poison (a panicking check must not hide the report).
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// A subscriber of a robot's command service: the frames its controller sends, as the
/// executor gets them (every frame restarts the executor's watchdog).
struct Commands {
    _service:
        iceoryx2::service::port_factory::publish_subscribe::PortFactory<RtIpc, CommandFrame, ()>,
    port: Subscriber<RtIpc, CommandFrame, ()>,
}

impl Commands {
    /// Opens it, if its executor has made it.
    fn open(node: &Node<RtIpc>, subsystem: &str) -> Option<Self> {
        let name: ServiceName = conductor_bus::naming::commands(subsystem)
            .as_str()
            .try_into()
            .ok()?;
        let service = node
            .service_builder(&name)
            .publish_subscribe::<CommandFrame>()
            .open()
            .ok()?;
        let port = service.subscriber_builder().create().ok()?;
        Some(Self {
            _service: service,
            port,
        })
    }

    /// The newest send time among the frames received since the last call.
    fn newest(&mut self) -> Option<u64> {
        let mut t = None;
        while let Ok(Some(f)) = self.port.receive() {
            t = t.max(Some(f.t_send_ns));
        }
        t
    }
}

/// One robot as the monitor thread sees it.
struct Eye {
    robot: Arc<Robot>,
    shared: Arc<Mutex<Watched>>,
    subs: Vec<StateSubscriber>,
    /// Set once the executor's services exist (with the states).
    stats: Option<StatsSubscriber>,
    /// (time, truth per joint).
    history: VecDeque<(u64, Vec<DeviceTruth>)>,
    /// (time, damaged packets towards the host so far).
    injected: VecDeque<(u64, u64)>,
    /// (time, the longest the simulator overslept since the previous poll).
    lags: VecDeque<(u64, u64)>,
    pending: VecDeque<(usize, StateSample)>,
    pending_stats: VecDeque<ExecutorStats>,
    /// Of the running incarnation: (ticks of its last stats, bus errors and injected at its
    /// first stats).
    incarnation: Option<(u64, u64, u64)>,
    last_seq: u64,
    /// The robot's command service, watched for its source's last frame.
    cmds: Option<Commands>,
    /// Goal Position writes the servos received since the last poll: (joint, time, rad).
    goal_writes: Vec<(usize, u64, f64)>,
    /// Per joint: a hold's write was received (time, value) in the episode under way.
    hold_write: Vec<Option<(u64, f64)>>,
    /// Damaged packets towards the devices at the last poll.
    down_before: u64,
    /// The previous poll's time.
    prev_poll_ns: u64,
    /// Per joint, in its safe condition since then: Dynamixel torque on with Goal Position where
    /// the servo stands (since the write that put it there, or the poll that first saw it);
    /// MIT out of motor mode (since the poll that first saw it).
    hold_since: Vec<Option<u64>>,
    truth: Vec<DeviceTruth>,
    /// How long after a sample's publication the history must reach before it is checked.
    after_ns: u64,
    /// Damage towards the host is counted by this long after it happened.
    count_slack_ns: u64,
}

/// Starts the monitor thread; it runs until `stop` is set.
pub fn spawn(
    domain: Domain,
    robots: Vec<(Arc<Robot>, Arc<Mutex<Watched>>)>,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<Result<(), String>> {
    std::thread::Builder::new()
        .name("soak-monitor".into())
        .spawn(move || run(domain, robots, stop).map_err(|e| e.to_string()))
        .expect("spawn the monitor")
}

fn run(
    domain: Domain,
    robots: Vec<(Arc<Robot>, Arc<Mutex<Watched>>)>,
    stop: Arc<AtomicBool>,
) -> Result<(), conductor_bus::BusError> {
    let bus = Bus::open(&domain, "soak-monitor")?;
    let node = NodeBuilder::new()
        .config(domain.iceoryx2_config())
        .create::<RtIpc>()
        .map_err(|e| conductor_bus::BusError::Iceoryx {
            context: "soak monitor node".into(),
            source: e.into(),
        })?;
    let mut eyes = Vec::new();
    for (robot, shared) in robots {
        {
            let mut w = lock(&shared);
            w.fresh_ns = vec![0; robot.joints.len()];
            w.flags = vec![0; robot.joints.len()];
        }
        let (after_ns, timeout_ns) = match robot.sim {
            Sim::Dxl(_) => (2_000_000, 2_000_000),
            Sim::Slcan(_) => (2_000_000, 1_500_000),
        };
        eyes.push(Eye {
            count_slack_ns: 3 * robot.tick_ns + timeout_ns + 2_000_000,
            robot,
            shared,
            subs: Vec::new(),
            stats: None,
            history: VecDeque::new(),
            injected: VecDeque::new(),
            lags: VecDeque::new(),
            pending: VecDeque::new(),
            pending_stats: VecDeque::new(),
            incarnation: None,
            last_seq: 0,
            cmds: None,
            goal_writes: Vec::new(),
            hold_write: Vec::new(),
            down_before: 0,
            prev_poll_ns: 0,
            hold_since: Vec::new(),
            truth: Vec::new(),
            after_ns,
        });
    }
    // The simulators are watched from before the launch (bring-up writes to the devices
    // too); the states and stats are subscribed to as soon as their executor offers them.
    let mut next_connect = 0;
    while !stop.load(Ordering::Relaxed) {
        let now = monotonic_ns();
        for e in eyes.iter_mut() {
            if e.stats.is_none() && now >= next_connect {
                e.connect(&bus);
            }
            if e.cmds.is_none() && now >= next_connect {
                e.cmds = Commands::open(&node, &e.robot.subsystem);
            }
            e.poll()?;
        }
        if now >= next_connect {
            next_connect = now + 50_000_000;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok(())
}

impl Eye {
    /// Subscribes to the robot's states and stats, if its executor offers them yet.
    fn connect(&mut self, bus: &Bus) {
        let sub = &self.robot.subsystem;
        let Ok(stats) = StatsSubscriber::new(bus, sub) else {
            return;
        };
        let mut subs = Vec::new();
        for j in &self.robot.joints {
            match StateSubscriber::with_buffer(bus, &format!("{sub}/{}", j.name), 1024) {
                Ok(s) => subs.push(s),
                Err(_) => return,
            }
        }
        self.subs = subs;
        self.stats = Some(stats);
    }

    fn poll(&mut self) -> Result<(), conductor_bus::BusError> {
        let now = monotonic_ns();
        self.robot.truth(&mut self.truth);
        self.check_writes();
        let (down, up) = self.robot.link_faults();
        let (lost_down, lost_up) = match &self.robot.sim {
            Sim::Slcan(r) => {
                let s = r.sim().stats();
                (s.wire_lost_to_nodes, s.wire_lost_to_host)
            }
            Sim::Dxl(_) => (0, 0),
        };
        let injected_up = up.damaged_packets + lost_up;
        {
            let mut w = lock(&self.shared);
            w.injected_up = injected_up;
            w.injected_down = down.damaged_packets + lost_down;
            w.corrupted_bytes = down.corrupted_bytes + up.corrupted_bytes;
            w.dropped_bytes = down.dropped_bytes + up.dropped_bytes;
            w.can_frames_lost = lost_down + lost_up;
        }
        self.history.push_back((now, self.truth.clone()));
        let lag = self.robot.take_lag_ns();
        if lag > 0 {
            self.lags.push_back((now, lag));
        }
        while self.lags.front().is_some_and(|(t, _)| now - t > HISTORY_NS) {
            self.lags.pop_front();
        }
        self.injected.push_back((now, injected_up));
        while self
            .history
            .front()
            .is_some_and(|(t, _)| now - t > HISTORY_NS)
        {
            self.history.pop_front();
        }
        while self
            .injected
            .front()
            .is_some_and(|(t, _)| now - t > HISTORY_NS)
        {
            self.injected.pop_front();
        }
        self.check_safe(now);
        for (i, s) in self.subs.iter_mut().enumerate() {
            while let Some(x) = s.receive()? {
                self.pending.push_back((i, x));
            }
        }
        while let Some(&(i, s)) = self.pending.front() {
            if s.t_publish_ns.max(s.t_sample_ns) + self.after_ns > now {
                break;
            }
            self.pending.pop_front();
            self.check_sample(i, &s);
        }
        if let Some(s) = self
            .stats
            .as_mut()
            .map(|s| s.latest())
            .transpose()?
            .flatten()
        {
            lock(&self.shared).hist = Some((s.ticks, Box::new(s.histogram)));
            self.pending_stats.push_back(s);
        }
        if let Some(c) = self.cmds.as_mut() {
            if let Some(t) = c.newest() {
                let mut w = lock(&self.shared);
                w.last_command_ns = w.last_command_ns.max(Some(t));
            }
        }
        while let Some(s) = self.pending_stats.front() {
            if s.t_ns + self.count_slack_ns > now {
                break;
            }
            let s = *s;
            self.pending_stats.pop_front();
            self.count(&s);
        }
        self.prev_poll_ns = now;
        Ok(())
    }

    /// The truth entries around `[from, to]`: those inside and two on each side (a poll sees
    /// the simulator as it last advanced, up to a millisecond before).
    fn around(&self, from: u64, to: u64) -> impl Iterator<Item = &(u64, Vec<DeviceTruth>)> {
        let start = self.history.partition_point(|(t, _)| *t < from);
        let end = self.history.partition_point(|(t, _)| *t <= to);
        self.history
            .range(start.saturating_sub(2)..(end + 2).min(self.history.len()))
    }

    fn check_sample(&mut self, i: usize, s: &StateSample) {
        let mut w = lock(&self.shared);
        w.flags[i] = s.status;
        if s.status & status::WATCHDOG != 0 {
            if let Some(e) = w.episode.as_mut() {
                let t = e.ms(s.t_publish_ns);
                let j = &mut e.joints[i];
                // A trip of before (the controller died while the enable it asked for was
                // still under way, or the device is still tripped from an earlier death
                // until that enable completes) is not this death's: its watchdog fires a
                // whole timeout after the last command, at the first tick past it.
                let own = t >= (self.robot.watchdog_ns - self.robot.tick_ns) as f64 / 1e6;
                if j.flagged_ms.is_none() && own {
                    j.flagged_ms = Some(t);
                }
            }
        }
        if s.status & status::STALE != 0 {
            w.samples_stale += 1;
            return;
        }
        let name = &self.robot.joints[i].name;
        if !s.value.is_finite() {
            w.wrong_published += 1;
            w.example(format!(
                "{name}: published {} at {}",
                s.value, s.t_sample_ns
            ));
            return;
        }
        if let Some(&(from, _)) = w
            .unplugged
            .iter()
            .find(|(from, to)| s.t_sample_ns > *from && s.t_sample_ns < *to)
        {
            w.wrong_published += 1;
            w.example(format!(
                "{name}: {} published without STALE {} ms into an unplug",
                s.value,
                (s.t_sample_ns - from) / 1_000_000
            ));
            return;
        }
        w.fresh_ns[i] = w.fresh_ns[i].max(s.t_sample_ns);
        if self.history.front().is_none_or(|(t, _)| *t > s.t_sample_ns) {
            w.samples_unchecked += 1;
            return;
        }
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        // The reply was made after the request left (its sample time) and read before the
        // value was published: the device had the value somewhere in between.
        let to = s.t_publish_ns.max(s.t_sample_ns) + 1_000_000;
        // Between two polls the joint moves (and may turn round): as far as the largest
        // step seen between neighbouring polls; a gap longer than GAP_NS (the monitor did not
        // get the CPU) leaves the value unchecked rather than judged.
        let (mut step, mut gap, mut prev) = (0.0f64, 0u64, None::<(u64, f64)>);
        for (t, truth) in self.around(s.t_sample_ns.saturating_sub(1_000_000), to) {
            let p = truth[i].position;
            lo = lo.min(p);
            hi = hi.max(p);
            if let Some((t0, p0)) = prev {
                step = step.max((p - p0).abs());
                gap = gap.max(t - t0);
            }
            prev = Some((*t, p));
        }
        let tol = 1.5 * self.robot.resolution + step;
        w.samples_checked += 1;
        let inside = |lo: f64, hi: f64| s.value >= lo - tol && s.value <= hi + tol;
        if inside(lo, hi) {
            return;
        }
        // The simulator's thread overslept around then: its reply may have left that much
        // late, carrying the position of its instruction's arrival.
        let lag = self
            .lags
            .iter()
            .filter(|(t, _)| *t + 200_000_000 >= s.t_sample_ns && *t <= to + self.after_ns)
            .map(|x| x.1)
            .max()
            .unwrap_or(0);
        if lag > 0 {
            let (mut lo2, mut hi2) = (lo, hi);
            for (_, truth) in self.around(s.t_sample_ns.saturating_sub(1_000_000 + lag), to) {
                lo2 = lo2.min(truth[i].position);
                hi2 = hi2.max(truth[i].position);
            }
            if inside(lo2, hi2) {
                w.samples_misdated += 1;
                w.worst_sim_lag_ms = w.worst_sim_lag_ms.max(lag as f64 / 1e6);
                return;
            }
        }
        if gap > GAP_NS {
            w.samples_unchecked += 1;
            return;
        }
        {
            w.wrong_published += 1;
            w.example(format!(
                "{name}: published {:.5} (tick {}, flags {:#x}, sampled {:.1} ms before its publication) but the device was in [{lo:.5}, {hi:.5}] from its sample time to its publication",
                s.value,
                s.tick,
                s.status,
                s.t_publish_ns.saturating_sub(s.t_sample_ns) as f64 / 1e6
            ));
        }
    }

    /// Every value the devices received: inside the limits, with the manifest's gains.
    fn check_writes(&mut self) {
        let joints = &self.robot.joints;
        match &self.robot.sim {
            Sim::Dxl(r) => {
                // Goal Position as the servos hold it, every millisecond (the bus writes it at
                // most every 4 ms); the instruction log is drained so it does not grow.
                let log = r.sim().take_log();
                // The simulator's clock is its own: ns since it started.
                let offset = monotonic_ns().saturating_sub(self.robot.sim_now_ns());
                self.goal_writes.clear();
                for (t, id, _inst, addr, data) in log {
                    let Some(i) = (id as usize).checked_sub(1).filter(|&i| i < joints.len()) else {
                        continue;
                    };
                    if addr == GOAL_POSITION && data.len() == 4 {
                        let raw = i32::from_le_bytes([data[0], data[1], data[2], data[3]]);
                        self.goal_writes
                            .push((i, t + offset, (raw - 2048) as f64 * PULSE));
                    }
                }
                let mut w = lock(&self.shared);
                for (j, t) in joints.iter().zip(&self.truth) {
                    w.writes_checked += 1;
                    // Before the first enable the goal is the power-on one (2048, 0 rad), which
                    // may lie outside a joint's range (the knee's 0..2.4 includes it).
                    let ok = t.goal >= j.min - PULSE && t.goal <= j.max + PULSE;
                    // A hold where the servo stands is safe wherever that is.
                    let hold = (t.goal - t.position).abs() <= HOLD_TOLERANCE;
                    if !ok && !hold && t.driving {
                        w.wrong_written += 1;
                        w.example(format!(
                            "{}: Goal Position {:.4} rad outside [{}, {}]",
                            j.name, t.goal, j.min, j.max
                        ));
                    }
                }
            }
            Sim::Slcan(r) => {
                let log = r.sim().take_log();
                let limits = mit_limits("ak80-9").expect("known");
                let q = |r: conductor_protocols::mit_can::Range, bits: u32| {
                    (r.max - r.min) as f64 / ((1u32 << bits) - 1) as f64
                };
                let mut w = lock(&self.shared);
                for (from_host, f) in log {
                    if !from_host {
                        continue;
                    }
                    let id = f.raw_id() as usize;
                    let Some(j) = id.checked_sub(1).and_then(|i| joints.get(i)) else {
                        w.wrong_written += 1;
                        w.example(format!("a frame to CAN id {id}, which has no motor"));
                        continue;
                    };
                    w.writes_checked += 1;
                    match decode_command(f.data(), &limits) {
                        Ok(MotorCommand::Special(_)) => {}
                        Ok(MotorCommand::Control(c)) => {
                            let p = c.p as f64;
                            let qp = q(limits.p, 16);
                            // Inside the limits, or a hold where the joint is (bring-up
                            // enables a motor where it stands, which may be outside them).
                            let here = self.truth[id - 1].position;
                            let hold = (p - here).abs() <= HOLD_TOLERANCE;
                            let bad = ((p < j.min - qp || p > j.max + qp) && !hold)
                                || (c.kp as f64 - 20.0).abs() > q(limits.kp, 12)
                                || (c.kd as f64 - 1.0).abs() > q(limits.kd, 12)
                                || (c.v as f64).abs() > q(limits.v, 12)
                                || (c.t as f64).abs() > q(limits.t, 12);
                            if bad {
                                w.wrong_written += 1;
                                w.example(format!(
                                    "{}: commanded {c:?}, limits [{}, {}]",
                                    j.name, j.min, j.max
                                ));
                            }
                        }
                        Err(e) => {
                            w.wrong_written += 1;
                            w.example(format!("{}: an undecodable command: {e}", j.name));
                        }
                    }
                }
            }
        }
    }

    /// The safe state after a controller's death, joint by joint: reached (at the simulator),
    /// then kept until the campaign closes the episode.
    ///
    /// * Dynamixel `hold`: the joint's samples say `WATCHDOG`, its torque is on, and the
    ///   servo received the hold's Goal Position write, at a position it had around then
    ///   (within [`HOLD_PULSES`]); timed by the simulator's stamp of that write. Kept: torque
    ///   stays on, every later goal written is where the servo is, `WATCHDOG` stays.
    /// * MIT `torque_off`: `WATCHDOG`, and the motor out of motor mode (seen by polling).
    ///   Kept: it stays out.
    fn check_safe(&mut self, now: u64) {
        let n = self.robot.joints.len();
        let mut w = lock(&self.shared);
        self.hold_since.resize(n, None);
        for i in 0..n {
            let t = self.truth[i];
            let holding = match self.robot.sim {
                Sim::Dxl(_) => t.driving && (t.goal - t.position).abs() <= HOLD_PULSES * PULSE,
                Sim::Slcan(_) => !t.driving,
            };
            if !holding {
                self.hold_since[i] = None;
            } else if self.hold_since[i].is_none() {
                // Since the write that made it so, else since the poll before this one (the
                // last that saw it otherwise): the earliest it can have changed.
                let write = self.goal_writes.iter().rev().find(|x| x.0 == i);
                let since = write.map_or(self.prev_poll_ns, |x| x.1).min(now);
                self.hold_since[i] = Some(since);
            }
        }
        if w.episode.is_none() {
            self.hold_write = vec![None; n];
            return;
        }
        let dxl = matches!(self.robot.sim, Sim::Dxl(_));
        let down = w.injected_down;
        let e = w.episode.as_mut().expect("checked above");
        e.tick_ms = self.robot.tick_ns as f64 / 1e6;
        if !e.all_safe() && now + self.robot.tick_ns >= e.origin_ns + self.robot.watchdog_ns {
            e.damaged_towards_devices += down.saturating_sub(self.down_before);
        }
        self.down_before = down;
        // Writes from the controller's last frames reach the servos within a few ticks of
        // it; from half the watchdog on, a goal written is the executor's own: the hold.
        let hold_from = e.origin_ns + self.robot.watchdog_ns / 2;
        for &(i, t, goal) in &self.goal_writes {
            if t < hold_from {
                continue;
            }
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for (_, truth) in self.around(t.saturating_sub(HOLD_SPAN_NS), t) {
                lo = lo.min(truth[i].position);
                hi = hi.max(truth[i].position);
            }
            let tol = HOLD_PULSES * PULSE;
            let there = goal >= lo - tol && goal <= hi + tol;
            let present = self.truth[i].position;
            let j = &mut e.joints[i];
            if self.hold_write[i].is_none() {
                self.hold_write[i] = Some((t, goal));
                if !there {
                    j.bad_hold = Some((goal, present));
                }
            } else if j.safe_ms.is_some() && !there && j.left_ms.is_none() {
                j.left_ms = Some((t as f64 - e.origin_ns as f64) / 1e6);
                j.left_to = Some(format!(
                    "Goal Position {goal:.4} written while the servo was in [{lo:.4}, {hi:.4}]"
                ));
            }
        }
        let flags = w.flags.clone();
        let Some(e) = w.episode.as_mut() else {
            return;
        };
        for (i, &f) in flags.iter().enumerate().take(n) {
            let t = self.truth[i];
            let flagged = f & status::WATCHDOG != 0;
            let j = &mut e.joints[i];
            if j.safe_ms.is_none() {
                // In its safe condition since `hold_since` (a hold write that was lost changes
                // nothing when the goal is there already: its read-back confirms it), and
                // tripped since the flag's publication.
                let reached = match (self.hold_since[i], j.flagged_ms) {
                    (Some(h), Some(f)) if flagged => {
                        Some(h.max(e.origin_ns + (f * 1e6).max(0.0) as u64))
                    }
                    _ => None,
                };
                j.torque = t.driving;
                j.goal = t.goal;
                j.present = t.position;
                if let Some(at) = reached {
                    j.safe_ms = Some((at as f64 - e.origin_ns as f64) / 1e6);
                }
                continue;
            }
            if j.left_ms.is_some() {
                continue;
            }
            let left = if dxl && !t.driving {
                Some("torque off".to_string())
            } else if !dxl && t.driving {
                Some("back in motor mode".to_string())
            } else if !flagged {
                Some(format!("its samples lost WATCHDOG (flags {:#x})", f))
            } else {
                None
            };
            if let Some(why) = left {
                j.left_ms = Some((now as f64 - e.origin_ns as f64) / 1e6);
                j.left_to = Some(why);
            }
        }
    }

    /// Executor stats: summed over restarts, and byte faults towards the host against bus
    /// errors counted.
    fn count(&mut self, s: &ExecutorStats) {
        let mut w = lock(&self.shared);
        let c = Counted::of(s);
        let restarted = match self.incarnation {
            Some((ticks, _, _)) => s.ticks < ticks || s.seq < self.last_seq,
            None => true,
        };
        self.last_seq = s.seq;
        if restarted {
            if let Some(prev) = w.counted_now.take() {
                w.counted_done = w.counted_done.add(&prev);
            }
            // The damage counted from here on: the first poll at or after this stats' time.
            let i = self.injected.partition_point(|(t, _)| *t < s.t_ns);
            let base = self.injected.get(i).map_or(w.injected_up, |x| x.1);
            self.incarnation = Some((s.ticks, s.bus_errors, base));
        }
        let (_, errors0, injected0) = self.incarnation.expect("set above");
        self.incarnation = Some((s.ticks, errors0, injected0));
        w.counted_now = Some(c);
        // Damage done by `t_ns - slack` must be counted by `t_ns`.
        let cutoff = s.t_ns.saturating_sub(self.count_slack_ns);
        let i = self.injected.partition_point(|(t, _)| *t <= cutoff);
        if let Some(&(_, inj)) = i.checked_sub(1).and_then(|i| self.injected.get(i)) {
            let uncounted = inj as i64 - injected0 as i64 - (s.bus_errors - errors0) as i64;
            w.worst_uncounted = w.worst_uncounted.max(uncounted);
        }
    }
}
