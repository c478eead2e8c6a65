//! The export side: local states out to Zenoh, remote command frames in to the owning executor.
//!
//! One thread with its own bus node (`bridge-export@<host>`). It sleeps in one `poll(2)` over the
//! tick events of every exported subsystem (any number of them) and a wake-up descriptor that
//! Zenoh's callback signals when a remote command frame arrives, so a tick's samples leave right
//! after the tick and a command reaches its executor right after it arrives, with no polling
//! interval in between. Per subsystem it reads the owner's snapshot (`conductor/<subsystem>/
//! snapshot`: the whole tick in one sample, sent before the per-state samples) and puts **one**
//! Zenoh message per tick on `conductor/<domain>/<subsystem>` carrying every exported state that
//! has a new sample in it (or, with `rate_hz`, the newest samples when due), built in a buffer
//! reused from tick to tick. An owner without a snapshot (a foreign one of ABI 2 before the
//! snapshot) is read state by state and woken by its tick event instead. It never writes into an executor's memory except
//! through the ordinary command service, and an executor never waits for it: it reads the same
//! shared-memory samples any local subscriber reads.

use std::collections::HashMap;
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use conductor_bus::{
    monotonic_ns, Bus, CommandFrame, CommandSender, SnapshotReader, StateSample, StateSubscriber,
    TickWaiter,
};
use tracing::{info, warn};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::Wait;

use crate::config::{any_matches, ExportConfig, Selector};
use crate::counters::{Counters, RateLimit};
use crate::error::{zenoh, Result};
use crate::profile::{self, Stage};
use crate::wire::{self, Catalog, CatalogEntry, Envelope, Heartbeat, Malformed};
use crate::{MIRROR_NODE_PREFIX, POLL};

/// Queue of remote command frames between Zenoh's thread and this one (frames beyond are
/// dropped and counted: commands are reliable on the link, bounded here).
const COMMAND_QUEUE: usize = 32;
/// How often the domain is rescanned for newly started states, and the catalog re-sent.
pub(crate) const RESCAN: Duration = Duration::from_secs(1);

struct Exported {
    name: String,
    /// Its own subscription, when its owner has no snapshot.
    sub: Option<StateSubscriber>,
    /// The next sample not yet sent: of a later tick than the message being built, or (with
    /// `rate_hz`) the newest one until the next message is due.
    pending: Option<StateSample>,
    /// `seq` of the last sample taken from a snapshot (a slower state's entry repeats it).
    last_seq: u64,
    entry: CatalogEntry,
}

/// Where a subsystem's samples are read.
enum Source {
    /// The owner's snapshot, woken by its event: one receive per tick, whatever the number of
    /// states.
    Snapshot(SnapshotReader),
    /// One subscription per state, woken by the tick event (`None`: no tick event either, so
    /// polled every [`POLL`]).
    States(Option<TickWaiter>),
}

impl Source {
    /// The descriptor that wakes the thread for this subsystem.
    fn raw_fd(&self) -> Option<i32> {
        match self {
            Source::Snapshot(r) => Some(r.raw_fd()),
            Source::States(w) => w.as_ref().map(TickWaiter::raw_fd),
        }
    }

    /// The next snapshot (`None` for per-state reading).
    fn snapshot(&mut self) -> Result<Option<conductor_bus::Snapshot>> {
        match self {
            Source::Snapshot(r) => Ok(r.receive()?),
            Source::States(_) => Ok(None),
        }
    }

    /// Consumes the notifications received so far.
    fn consume(&mut self) -> Result<()> {
        match self {
            Source::Snapshot(r) => r.try_consume()?,
            Source::States(w) => {
                if let Some(w) = w {
                    w.try_consume()?;
                }
            }
        }
        Ok(())
    }
}

/// The exported states of one subsystem: one Zenoh publisher, one message per tick.
struct Group {
    subsystem: String,
    states: Vec<Exported>,
    publisher: zenoh::pubsub::Publisher<'static>,
    seq: u64,
    next_due: Instant,
    /// The tick message being built (allocated at the size of the last one).
    buf: Vec<u8>,
    /// Envelope bytes: the sequence number is rewritten in place per message.
    envelope: Vec<u8>,
    source: Source,
    /// When its tick last woke the thread, and the tick period seen (for the spin).
    cadence: Cadence,
    /// The spin saw this tick's snapshot before its notification, which is still to come and
    /// is not another tick.
    ahead: bool,
}

/// What one `poll(2)` of the export thread saw.
#[derive(Debug, Clone, Copy, Default)]
struct Fired {
    /// Anything (a tick or a remote command frame).
    any: bool,
    /// A tick event.
    tick: bool,
}

/// When a subsystem's next tick is due, learnt from the ticks seen (for the spin).
#[derive(Debug, Clone, Copy, Default)]
struct Cadence {
    last: Option<Instant>,
    /// Mean tick interval (moving average), ns; 0 until two ticks were seen.
    period_ns: f64,
    /// Whether the last interval was within a quarter of the mean: the owner ticks steadily.
    steady: bool,
}

impl Cadence {
    fn ticked(&mut self, at: Instant) {
        if let Some(last) = self.last {
            let d = at.duration_since(last).as_nanos() as f64;
            if self.period_ns == 0.0 {
                self.period_ns = d;
            }
            self.steady = (d - self.period_ns).abs() < self.period_ns / 4.0;
            // A long pause (an owner restarting) does not teach the period.
            if d < 4.0 * self.period_ns {
                self.period_ns += (d - self.period_ns) / 8.0;
            }
        }
        self.last = Some(at);
    }

    /// When the next tick is due, if the owner ticks steadily.
    fn next(&self) -> Option<Instant> {
        let last = self.last?;
        (self.steady && self.period_ns > 0.0)
            .then(|| last + Duration::from_nanos(self.period_ns as u64))
    }
}

/// The export thread's busy-wait before an expected tick (`[export] spin_us`), and how it
/// adapts: the window opens `lead` before the tick is due and lasts at most `max`; `lead` grows
/// when a tick came before the thread was spinning and shrinks when it spun long for one.
#[derive(Debug, Clone, Copy)]
struct Spin {
    max: Duration,
    lead: Duration,
    /// Ticks caught while spinning / arriving before the window / after it.
    caught: u64,
    early: u64,
    late: u64,
    /// Time spent spinning.
    spun: Duration,
}

impl Spin {
    fn new(max: Duration) -> Self {
        Self {
            max,
            lead: max / 2,
            caught: 0,
            early: 0,
            late: 0,
            spun: Duration::ZERO,
        }
    }
}

/// A remote command frame as Zenoh delivered it.
pub(crate) struct RemoteFrame {
    key: String,
    payload: Vec<u8>,
    attachment: Option<Vec<u8>>,
}

/// Everything the export thread owns.
pub(crate) struct Exporter {
    bus: Bus,
    zs: zenoh::Session,
    domain: String,
    host: String,
    session: u64,
    heartbeat: Duration,
    command_max_age_ns: u64,
    states_sel: Vec<Selector>,
    commands_sel: Vec<Selector>,
    rate_hz: Option<f64>,
    groups: Vec<Group>,
    /// `poll(2)` set: the command wake-up first, then the groups' tick listeners.
    fds: Vec<libc::pollfd>,
    /// Group of each `fds` entry after the first.
    fd_group: Vec<usize>,
    wake: Arc<Wake>,
    senders: HashMap<String, CommandSender>,
    frames: Receiver<RemoteFrame>,
    _commands: zenoh::pubsub::Subscriber<()>,
    last_frame: HashMap<(String, u64), u64>,
    offset_min: HashMap<String, i128>,
    counters: Arc<Counters>,
    warn_malformed: RateLimit,
    warn_refused: RateLimit,
    catalog_version: u64,
    /// `None`: the thread sleeps until a tick wakes it (`spin_us = 0`).
    spin: Option<Spin>,
}

impl Exporter {
    /// Joins the local domain and declares the command subscriber; states are found by
    /// [`rescan`](Self::rescan).
    pub(crate) fn new(
        bus: Bus,
        zs: zenoh::Session,
        cfg: &ExportConfig,
        host: String,
        session: u64,
        heartbeat: Duration,
        counters: Arc<Counters>,
    ) -> Result<Self> {
        let domain = cfg
            .domain
            .clone()
            .unwrap_or_else(|| bus.domain().name().to_string());
        let (tx, frames) = std::sync::mpsc::sync_channel::<RemoteFrame>(COMMAND_QUEUE);
        let c2 = counters.clone();
        let wake = Arc::new(Wake::new()?);
        let w2 = wake.clone();
        let commands = zs
            .declare_subscriber(wire::command_key(&domain, "*"))
            .callback(move |s| queue_frame(&tx, &c2, &w2, s))
            .wait()
            .map_err(zenoh("declaring the command subscriber"))?;
        let mut me = Self {
            bus,
            zs,
            domain,
            host,
            session,
            heartbeat,
            command_max_age_ns: COMMAND_MAX_AGE.as_nanos() as u64,
            states_sel: Selector::many(&cfg.states)?,
            commands_sel: Selector::many(&cfg.commands)?,
            rate_hz: cfg.rate_hz,
            groups: Vec::new(),
            fds: Vec::new(),
            fd_group: Vec::new(),
            wake,
            senders: HashMap::new(),
            frames,
            _commands: commands,
            last_frame: HashMap::new(),
            offset_min: HashMap::new(),
            counters,
            warn_malformed: RateLimit::new(),
            warn_refused: RateLimit::new(),
            catalog_version: 0,
            spin: (cfg.spin_us > 0).then(|| Spin::new(Duration::from_micros(cfg.spin_us))),
        };
        if me.spin.is_some() {
            // Sleep until the spin window opens to the microsecond, not the default 50 µs
            // timer slack later.
            // SAFETY: prctl(PR_SET_TIMERSLACK) takes an integer and affects this thread only.
            unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong) };
        }
        me.rebuild_poll_set();
        me.rescan()?;
        Ok(me)
    }

    /// Number of states exported now.
    pub(crate) fn len(&self) -> usize {
        self.groups.iter().map(|g| g.states.len()).sum()
    }

    /// Whether something exported has no event to wake the thread (a rate-limited export, or
    /// a subsystem without a tick event), so the thread must wake every [`POLL`].
    pub(crate) fn needs_polling(&self) -> bool {
        self.rate_hz.is_some() || self.groups.iter().any(|g| g.source.raw_fd().is_none())
    }

    /// The key-expression domain.
    pub(crate) fn domain(&self) -> &str {
        &self.domain
    }

    /// This bridge's host name.
    pub(crate) fn host(&self) -> &str {
        &self.host
    }

    /// The Zenoh session.
    pub(crate) fn zenoh(&self) -> &zenoh::Session {
        &self.zs
    }

    /// Subscribes to local states that match and are not yet exported (mirrors of other
    /// hosts' states are never re-exported).
    pub(crate) fn rescan(&mut self) -> Result<()> {
        let all = self.bus.list_states()?;
        self.add(all)
    }

    /// Subscribes to the states of `all` (a listing of the domain) that match and are not yet
    /// exported. The listing itself is slow (every service's records are read: tens to hundreds
    /// of ms for 1 000 states on a loaded machine), so after the first one it is made by
    /// [`scanner`] in a thread of its own: the export thread never stops sending ticks and
    /// heartbeats for it.
    pub(crate) fn add(&mut self, all: Vec<conductor_bus::StateInfo>) -> Result<()> {
        let mut added = 0;
        for s in all {
            if !any_matches(&self.states_sel, &s.subsystem, &s.name)
                || s.nodes.iter().any(|n| n.starts_with(MIRROR_NODE_PREFIX))
                || self.groups.iter().any(|g| {
                    g.subsystem == s.subsystem && g.states.iter().any(|e| e.name == s.name)
                })
            {
                continue;
            }
            let m = &s.meta;
            let remote_cmd = m.writable && any_matches(&self.commands_sel, &s.subsystem, &s.name);
            let entry = CatalogEntry {
                subsystem: s.subsystem.clone(),
                state: s.name.clone(),
                index: m.index,
                units: m.units.clone(),
                writable: remote_cmd,
                rate_hz: self.rate_hz.map_or(m.rate_hz, |r| r.min(m.rate_hz)),
                min: m.min.is_finite().then_some(m.min),
                max: m.max.is_finite().then_some(m.max),
                device: m.device.clone(),
            };
            let gi = match self.groups.iter().position(|g| g.subsystem == s.subsystem) {
                Some(gi) => gi,
                None => {
                    self.groups.push(self.group(&s.subsystem)?);
                    self.groups.len() - 1
                }
            };
            let sub = match &self.groups[gi].source {
                Source::Snapshot(_) => None,
                Source::States(_) => match StateSubscriber::from_info(&self.bus, s.clone(), 64) {
                    Ok(sub) => Some(sub),
                    // It vanished between listing and opening: the next rescan tries again.
                    Err(_) => continue,
                },
            };
            self.groups[gi].states.push(Exported {
                name: s.name.clone(),
                sub,
                pending: None,
                last_seq: 0,
                entry,
            });
            added += 1;
        }
        if added > 0 {
            self.groups.sort_by(|a, b| a.subsystem.cmp(&b.subsystem));
            for g in &mut self.groups {
                g.states.sort_by_key(|e| e.entry.index);
            }
            self.rebuild_poll_set();
            self.catalog_version = self.catalog_version.wrapping_add(1);
            info!(
                "exporting {} state(s) of {} subsystem(s) as conductor/{}/<subsystem> ({} accept \
                 remote commands, {} woken by their tick)",
                self.len(),
                self.groups.len(),
                self.domain,
                self.groups
                    .iter()
                    .flat_map(|g| &g.states)
                    .filter(|e| e.entry.writable)
                    .count(),
                self.groups
                    .iter()
                    .filter(|g| g.source.raw_fd().is_some())
                    .count()
            );
        }
        Ok(())
    }

    fn group(&self, subsystem: &str) -> Result<Group> {
        let publisher = self
            .zs
            .declare_publisher(wire::tick_key(&self.domain, subsystem))
            // Latest-value: a congested link drops tick messages, never queues them.
            .congestion_control(CongestionControl::Drop)
            // One message per tick: nothing to batch it with, send it now.
            .express(true)
            .wait()
            .map_err(zenoh("declaring a subsystem's publisher"))?;
        // The whole tick in one sample, sent before the per-state ones; a queue as deep as a
        // state's, so a late thread still sends every tick.
        let source = match SnapshotReader::with_buffer(&self.bus, subsystem, 64) {
            Ok(r) => Source::Snapshot(r),
            Err(e) => {
                info!("no snapshot for {subsystem} ({e}): reading its states one by one");
                Source::States(match TickWaiter::new(&self.bus, subsystem) {
                    Ok(w) => Some(w),
                    Err(e) => {
                        warn!(
                            "no tick event for {subsystem} ({e}): its states are polled every \
                             {POLL:?}"
                        );
                        None
                    }
                })
            }
        };
        Ok(Group {
            subsystem: subsystem.into(),
            states: Vec::new(),
            publisher,
            seq: 0,
            next_due: Instant::now(),
            buf: Vec::new(),
            envelope: Envelope {
                host: self.host.clone(),
                session: self.session,
                seq: 0,
            }
            .encode(),
            source,
            cadence: Cadence::default(),
            ahead: false,
        })
    }

    fn rebuild_poll_set(&mut self) {
        let fd = |fd| libc::pollfd {
            fd,
            events: libc::POLLIN,
            revents: 0,
        };
        self.fds.clear();
        self.fd_group.clear();
        self.fds.push(fd(self.wake.fd()));
        for (gi, g) in self.groups.iter().enumerate() {
            if let Some(f) = g.source.raw_fd() {
                self.fds.push(fd(f));
                self.fd_group.push(gi);
            }
        }
    }

    /// The catalog of what is exported now.
    pub(crate) fn catalog(&self) -> Catalog {
        Catalog {
            host: self.host.clone(),
            session: self.session,
            version: self.catalog_version,
            heartbeat_ms: self.heartbeat.as_millis() as u64,
            states: self
                .groups
                .iter()
                .flat_map(|g| &g.states)
                .map(|e| e.entry.clone())
                .collect(),
        }
    }

    /// Puts the heartbeat.
    pub(crate) fn put_heartbeat(&self) -> Result<()> {
        let hb = Heartbeat {
            session: self.session,
            catalog_version: self.catalog_version,
        };
        self.zs
            .put(wire::heartbeat_key(&self.domain, &self.host), hb.encode())
            .congestion_control(CongestionControl::Drop)
            // Ahead of tick messages in Zenoh's queues: a busy link is not a quiet one.
            .priority(Priority::DataHigh)
            .express(true)
            .wait()
            .map_err(zenoh("putting the heartbeat"))
    }

    /// Puts the catalog.
    pub(crate) fn put_catalog(&self) -> Result<()> {
        let json = serde_json::to_vec(&self.catalog()).expect("a catalog serialises");
        self.zs
            .put(wire::catalog_key(&self.domain, &self.host), json)
            .wait()
            .map_err(zenoh("putting the catalog"))
    }

    /// Sleeps until an exported subsystem ticks or a remote command frame arrives (at most
    /// `timeout`): one `poll(2)` over every tick listener, whatever their number. With a spin
    /// (`[export] spin_us`), the thread wakes shortly before a steady subsystem's next tick is
    /// due and busy-polls the same descriptors for at most `spin_us`, so that tick finds it
    /// running instead of waking it. Allocation-free.
    pub(crate) fn wait(&mut self, timeout: Duration) -> Result<()> {
        let start = Instant::now();
        let deadline = start + timeout;
        if let Some(window) = self.spin_window(start) {
            let (from, until) = (window.0.min(deadline), window.1.min(deadline));
            if from > start {
                let fired = self.poll_fds(Some(from - start))?;
                if fired.tick {
                    // The tick came before the window opened: open it earlier.
                    if let Some(sp) = &mut self.spin {
                        sp.early += 1;
                        sp.lead = (sp.lead + sp.max / 8).min(sp.max);
                    }
                }
                if fired.any {
                    return Ok(());
                }
            }
            let spin_start = Instant::now();
            while Instant::now() < until {
                if self.snapshot_sent()? || self.poll_fds(Some(Duration::ZERO))?.any {
                    let now = Instant::now();
                    if let Some(sp) = &mut self.spin {
                        sp.caught += 1;
                        let spun = now - spin_start;
                        sp.spun += spun;
                        // Aim at spinning a quarter of the window before the tick.
                        if spun > sp.max / 4 {
                            sp.lead = sp.lead.saturating_sub(sp.max / 32);
                        }
                    }
                    return Ok(());
                }
                std::hint::spin_loop();
            }
            if let Some(sp) = &mut self.spin {
                sp.late += 1;
                sp.spun += Instant::now() - spin_start;
            }
        }
        let left = deadline.saturating_duration_since(Instant::now());
        self.poll_fds(Some(left))?;
        Ok(())
    }

    /// The next spin window `(open, close)`: before the earliest tick due of a steady subsystem
    /// whose window has not closed yet.
    fn spin_window(&self, now: Instant) -> Option<(Instant, Instant)> {
        let sp = self.spin?;
        self.groups
            .iter()
            .filter(|g| g.source.raw_fd().is_some())
            .filter_map(|g| g.cadence.next())
            .map(|due| {
                let from = due.checked_sub(sp.lead).unwrap_or(due);
                (from, from + sp.max)
            })
            .filter(|w| w.1 > now)
            .min()
    }

    /// One `poll(2)` over the wake-up and the tick listeners (µs resolution); consumes what
    /// fired and notes the ticks' times.
    fn poll_fds(&mut self, timeout: Option<Duration>) -> Result<Fired> {
        for p in &mut self.fds {
            p.revents = 0;
        }
        let ts = timeout.map(|t| libc::timespec {
            tv_sec: t.as_secs().min(i32::MAX as u64) as libc::time_t,
            tv_nsec: t.subsec_nanos() as libc::c_long,
        });
        let tsp = ts
            .as_ref()
            .map_or(std::ptr::null(), |t| t as *const libc::timespec);
        // SAFETY: `fds` is a valid, initialised array of `fds.len()` entries; its descriptors
        // belong to the wake-up and to listeners owned by `self`, alive during the call; `tsp` is
        // null or points to a live timespec; a null signal mask leaves the mask unchanged.
        let r = unsafe {
            libc::ppoll(
                self.fds.as_mut_ptr(),
                self.fds.len() as libc::nfds_t,
                tsp,
                std::ptr::null(),
            )
        };
        if r < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() != std::io::ErrorKind::Interrupted {
                return Err(crate::BridgeError::Thread(format!(
                    "waiting for ticks: {e}"
                )));
            }
            return Ok(Fired::default());
        }
        let mut fired = Fired {
            any: r > 0,
            tick: false,
        };
        if r == 0 {
            return Ok(fired);
        }
        let now = Instant::now();
        if self.fds[0].revents != 0 {
            self.wake.drain();
        }
        for (p, &gi) in self.fds[1..].iter().zip(&self.fd_group) {
            if p.revents != 0 {
                let g = &mut self.groups[gi];
                g.source.consume()?;
                if !std::mem::take(&mut g.ahead) {
                    fired.tick = true;
                    g.cadence.ticked(now);
                }
            }
        }
        Ok(fired)
    }

    /// Whether an owner has sent a snapshot not yet read, seen in shared memory before its
    /// notification (the spin's check: no system call, and it does not wait for the owner's
    /// `notify`). Notes the tick of each.
    fn snapshot_sent(&mut self) -> Result<bool> {
        let mut any = false;
        let now = Instant::now();
        for g in &mut self.groups {
            if let Source::Snapshot(r) = &g.source {
                if !g.ahead && r.has_snapshots()? {
                    g.ahead = true;
                    g.cadence.ticked(now);
                    any = true;
                }
            }
        }
        Ok(any)
    }

    /// What the spin did: ticks caught while spinning, ticks before / after the window, time
    /// spent spinning (`None` without a spin).
    pub(crate) fn spin_summary(&self) -> Option<String> {
        let sp = self.spin?;
        Some(format!(
            "spin {} µs: {} tick(s) caught spinning, {} before the window, {} after it; {:.3} s \
             spent spinning",
            sp.max.as_micros(),
            sp.caught,
            sp.early,
            sp.late,
            sp.spun.as_secs_f64()
        ))
    }

    /// Sends what the local states published since the last call: one message per subsystem
    /// and tick.
    pub(crate) fn pump_states(&mut self) -> Result<()> {
        let now = Instant::now();
        let period = self.rate_hz.map(|r| Duration::from_secs_f64(1.0 / r));
        // The spin trades CPU for latency; so does yielding after each put (see `send`).
        let yield_after_put = self.spin.is_some();
        for g in &mut self.groups {
            if matches!(g.source, Source::Snapshot(_)) {
                while let Some(snap) = g.source.snapshot()? {
                    let mut any = false;
                    for e in &mut g.states {
                        // A slower state's entry repeats its last sample; a state never
                        // published yet has no time.
                        if let Some(&x) = snap.get(e.entry.index as usize) {
                            if x.seq != e.last_seq && x.t_sample_ns != 0 {
                                e.last_seq = x.seq;
                                e.pending = Some(x);
                                any = true;
                            }
                        }
                    }
                    drop(snap);
                    if any && period.is_none() {
                        g.send(|e| e.pending.is_some(), &self.counters, yield_after_put)?;
                    }
                }
                if let Some(p) = period {
                    if now >= g.next_due && g.states.iter().any(|e| e.pending.is_some()) {
                        g.send(|e| e.pending.is_some(), &self.counters, yield_after_put)?;
                        g.next_due = (g.next_due + p).max(now);
                    }
                }
                continue;
            }
            match period {
                None => loop {
                    // The oldest tick any state has a sample of goes first, alone.
                    let mut tick = None::<u64>;
                    for e in &mut g.states {
                        if e.pending.is_none() {
                            if let Some(sub) = &mut e.sub {
                                e.pending = sub.receive()?;
                            }
                        }
                        if let Some(p) = &e.pending {
                            tick = Some(tick.map_or(p.tick, |t| t.min(p.tick)));
                        }
                    }
                    let Some(tick) = tick else { break };
                    g.send(
                        |e| e.pending.is_some_and(|p| p.tick == tick),
                        &self.counters,
                        yield_after_put,
                    )?;
                },
                Some(p) => {
                    for e in g.states.iter_mut().filter_map(|e| {
                        let sub = e.sub.as_mut()?;
                        Some((sub, &mut e.pending))
                    }) {
                        while let Some(s) = e.0.receive()? {
                            *e.1 = Some(s);
                        }
                    }
                    if now >= g.next_due && g.states.iter().any(|e| e.pending.is_some()) {
                        g.send(|e| e.pending.is_some(), &self.counters, yield_after_put)?;
                        // Keep the cadence, but never bunch up after a pause.
                        g.next_due = (g.next_due + p).max(now);
                    }
                }
            }
        }
        Ok(())
    }

    /// Hands queued remote command frames to their executors.
    pub(crate) fn pump_commands(&mut self) -> Result<()> {
        while let Ok(f) = self.frames.try_recv() {
            if let Err(why) = self.command(&f) {
                let n = Counters::bump(&self.counters.malformed);
                if let Some(held) = self.warn_malformed.allow() {
                    warn!(
                        "dropped a malformed command message on {}: {why} ({n} malformed so far, \
                         {held} not logged)",
                        f.key
                    );
                }
            }
        }
        Ok(())
    }

    fn command(&mut self, f: &RemoteFrame) -> std::result::Result<(), Malformed> {
        let sub = f
            .key
            .rsplit('/')
            .next()
            .filter(|s| conductor_bus::naming::validate("subsystem", s).is_ok())
            .ok_or_else(|| Malformed::Key(f.key.clone()))?
            .to_string();
        let env = Envelope::decode(f.attachment.as_deref().ok_or(Malformed::Envelope)?)?;
        let frame = wire::decode_frame(&f.payload)?;
        // Reliable link, but a redialled one may deliver a frame twice: never apply it twice.
        let last = self
            .last_frame
            .entry((env.host.clone(), env.session))
            .or_insert(0);
        if env.seq <= *last {
            Counters::bump(&self.counters.out_of_order);
            return Ok(());
        }
        *last = env.seq;
        // One-way age against the smallest delay seen from that host: clocks of two machines
        // differ, their difference does not drift much over a run.
        let d = monotonic_ns() as i128 - frame.t_send_ns as i128;
        let min = self.offset_min.entry(env.host.clone()).or_insert(d);
        *min = (*min).min(d);
        if (d - *min) as u64 > self.command_max_age_ns {
            let n = Counters::bump(&self.counters.commands_dropped);
            if let Some(held) = self.warn_refused.allow() {
                warn!(
                    "dropped a command frame from {} for {sub}: {} ms late ({n} dropped so far, \
                     {held} warnings not logged)",
                    env.host,
                    (d - *min) / 1_000_000
                );
            }
            return Ok(());
        }
        let mut out = CommandFrame {
            t_send_ns: frame.t_send_ns,
            ..CommandFrame::default()
        };
        let mut refused = Vec::new();
        for sp in frame.setpoints() {
            let ok = self.groups.iter().any(|g| {
                g.subsystem == sub
                    && g.states
                        .iter()
                        .any(|e| e.entry.index == sp.index && e.entry.writable)
            });
            if ok {
                out.push(sp.index, sp.value);
            } else {
                refused.push(sp.index);
            }
        }
        if !refused.is_empty() {
            let n = refused.len() as u64;
            let total = self
                .counters
                .setpoints_refused
                .fetch_add(n, std::sync::atomic::Ordering::Relaxed)
                + n;
            if let Some(held) = self.warn_refused.allow() {
                warn!(
                    "refused {n} setpoint(s) from {} for {sub} (indices {refused:?}): not exported \
                     for remote commands ({total} refused so far, {held} warnings not logged)",
                    env.host
                );
            }
        }
        if out.count == 0 {
            return Ok(());
        }
        if !self.senders.contains_key(&sub) {
            match CommandSender::open(&self.bus, &sub) {
                Ok(s) => {
                    self.senders.insert(sub.clone(), s);
                }
                Err(e) => {
                    Counters::bump(&self.counters.commands_dropped);
                    warn!("cannot hand remote commands to {sub}: {e}");
                    return Ok(());
                }
            }
        }
        let sender = self.senders.get_mut(&sub).expect("inserted above");
        match sender.send(&out) {
            Ok(()) => {
                Counters::bump(&self.counters.commands_in);
            }
            Err(e) => {
                Counters::bump(&self.counters.commands_dropped);
                warn!("cannot hand remote commands to {sub}: {e}");
                // Reopen next time (the executor may have restarted).
                self.senders.remove(&sub);
            }
        }
        Ok(())
    }
}

/// Lists the domain's states every [`RESCAN`] for the export thread, on a bus node of its own,
/// until `stop()` or the export thread is gone. A listing the export thread has not taken yet
/// is not queued behind another.
pub(crate) fn scanner(
    bus: Bus,
    tx: SyncSender<Vec<conductor_bus::StateInfo>>,
    stop: impl Fn() -> bool,
) {
    let mut warn_failed = RateLimit::new();
    while !stop() {
        std::thread::sleep(RESCAN);
        let t = Instant::now();
        match bus.list_states() {
            Ok(all) => match tx.try_send(all) {
                Ok(()) | Err(TrySendError::Full(_)) => {}
                Err(TrySendError::Disconnected(_)) => return,
            },
            Err(e) => {
                if warn_failed.allow().is_some() {
                    warn!("cannot list the domain's states: {e}");
                }
            }
        }
        tracing::debug!("listed the domain's states in {:?}", t.elapsed());
    }
}

/// Frames older than this (one-way, measured against the smallest delay seen from their host)
/// are dropped: a link that comes back must not replay stale setpoints.
pub const COMMAND_MAX_AGE: Duration = Duration::from_millis(250);

impl Group {
    /// Puts one tick message with the pending samples of the states `pick` selects (and clears
    /// them); then yields the CPU if `yield_after_put`.
    fn send(
        &mut self,
        pick: impl Fn(&Exported) -> bool,
        counters: &Counters,
        yield_after_put: bool,
    ) -> Result<()> {
        wire::begin_tick(&mut self.buf);
        let mut first_t = None;
        let mut n = 0;
        for e in &mut self.states {
            if pick(e) {
                let s = e.pending.take().expect("picked states have a sample");
                wire::push_tick_entry(&mut self.buf, e.entry.index, &s);
                first_t.get_or_insert(s.t_sample_ns);
                n += 1;
            }
        }
        let Some(t) = first_t else { return Ok(()) };
        profile::record(Stage::ExportReceived, t);
        self.seq += 1;
        Envelope::set_seq(&mut self.envelope, self.seq);
        // Zenoh takes the bytes without copying them: one allocation per message (sized by the
        // last one), none per sample.
        let cap = self.buf.capacity();
        let payload = std::mem::replace(&mut self.buf, Vec::with_capacity(cap));
        self.publisher
            .put(payload)
            .attachment(self.envelope.as_slice())
            .wait()
            .map_err(zenoh("putting a tick message"))?;
        profile::record(Stage::ExportPut, t);
        if yield_after_put {
            // Zenoh's TX thread, which the put wakes, writes the message to the link; it is
            // often queued on this CPU. Yielding here lets it go first, and (measured) makes it
            // preempt the next puts as soon as they wake it: the message leaves during the put
            // rather than after it. On the project's 2-vCPU VM, with the spin, the mirror's
            // sample reached B's bus ≈ 12 µs sooner at p50; a reader busy-polling B's bus on a
            // CPU of its own saw it ≈ 5 µs later (everything else then shares one CPU).
            // benches/README.md, "Yield after the put".
            std::thread::yield_now();
        }
        counters
            .exported
            .fetch_add(n, std::sync::atomic::Ordering::Relaxed);
        Ok(())
    }
}

/// Wakes the export thread from Zenoh's callback (an `eventfd`, part of its `poll(2)` set).
struct Wake {
    fd: std::os::fd::OwnedFd,
}

impl Wake {
    fn new() -> Result<Self> {
        // SAFETY: eventfd has no memory preconditions; the result is checked before use.
        let fd = unsafe { libc::eventfd(0, libc::EFD_NONBLOCK | libc::EFD_CLOEXEC) };
        if fd < 0 {
            let e = std::io::Error::last_os_error();
            return Err(crate::BridgeError::Thread(format!("eventfd: {e}")));
        }
        // SAFETY: `fd` was just opened by eventfd and is owned by nobody else.
        let fd = unsafe { <std::os::fd::OwnedFd as std::os::fd::FromRawFd>::from_raw_fd(fd) };
        Ok(Self { fd })
    }

    fn fd(&self) -> i32 {
        std::os::fd::AsRawFd::as_raw_fd(&self.fd)
    }

    fn notify(&self) {
        let one = 1u64.to_ne_bytes();
        // SAFETY: writes 8 bytes from a live buffer to our eventfd; failure (counter full)
        // only means a wake-up is already pending.
        let _ = unsafe { libc::write(self.fd(), one.as_ptr().cast(), one.len()) };
    }

    fn drain(&self) {
        let mut v = [0u8; 8];
        // SAFETY: reads at most 8 bytes into a live buffer from our non-blocking eventfd.
        let _ = unsafe { libc::read(self.fd(), v.as_mut_ptr().cast(), v.len()) };
    }
}

fn queue_frame(
    tx: &SyncSender<RemoteFrame>,
    counters: &Counters,
    wake: &Wake,
    s: zenoh::sample::Sample,
) {
    let f = RemoteFrame {
        key: s.key_expr().as_str().to_string(),
        payload: s.payload().to_bytes().into_owned(),
        attachment: s.attachment().map(|a| a.to_bytes().into_owned()),
    };
    match tx.try_send(f) {
        Ok(()) => wake.notify(),
        Err(TrySendError::Full(_)) => {
            Counters::bump(&counters.commands_dropped);
        }
        Err(TrySendError::Disconnected(_)) => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_next_tick_is_expected_only_from_a_steady_owner() {
        let t0 = Instant::now();
        let ms = Duration::from_millis(1);
        let mut c = Cadence::default();
        assert_eq!(c.next(), None, "nothing seen yet");
        c.ticked(t0);
        assert_eq!(c.next(), None, "one tick says no period");
        for i in 1..=20 {
            c.ticked(t0 + i * ms);
        }
        let due = c.next().expect("steady ticks give a due time");
        assert_eq!(due.duration_since(t0), 21 * ms);
        // A tick far off the period: no spin until the owner is steady again.
        c.ticked(t0 + 30 * ms);
        assert_eq!(c.next(), None);
        c.ticked(t0 + 31 * ms);
        assert!(c.next().is_some());
        // A long pause does not teach the period.
        c.ticked(t0 + 1031 * ms);
        c.ticked(t0 + 1032 * ms);
        let due = c.next().expect("steady again");
        assert!(due.duration_since(t0 + 1032 * ms) < 2 * ms);
    }
}
