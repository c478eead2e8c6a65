//! The export side: local states out to Zenoh, remote command frames in to the owning executor.
//!
//! One thread with its own bus node (`bridge-export@<host>`). It sleeps on the exported
//! subsystems' tick events (so a sample leaves right after its tick), then drains every exported
//! state's subscription and puts each sample (or, with `rate_hz`, the newest one when due) on
//! `conductor/<domain>/<subsystem>/<state>`. It never writes into an executor's memory except
//! through the ordinary command service, and an executor never waits for it: it reads the same
//! shared-memory samples any local subscriber reads.

use std::collections::HashMap;
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use conductor_bus::{
    monotonic_ns, Bus, CommandFrame, CommandSender, StateSample, StateSubscriber, TickWaiter,
};
use tracing::{info, warn};
use zenoh::qos::CongestionControl;
use zenoh::Wait;

use crate::config::{any_matches, ExportConfig, Selector};
use crate::counters::{Counters, RateLimit};
use crate::error::{zenoh, Result};
use crate::wire::{self, Catalog, CatalogEntry, Envelope, Heartbeat, Malformed};
use crate::MIRROR_NODE_PREFIX;

/// Queue of remote command frames between Zenoh's thread and this one (frames beyond are
/// dropped and counted: commands are reliable on the link, bounded here).
const COMMAND_QUEUE: usize = 32;
/// How often the domain is rescanned for newly started states, and the catalog re-sent.
pub(crate) const RESCAN: Duration = Duration::from_secs(1);

struct Exported {
    subsystem: String,
    name: String,
    sub: StateSubscriber,
    publisher: zenoh::pubsub::Publisher<'static>,
    seq: u64,
    /// Newest sample not yet sent (rate-limited export).
    pending: Option<StateSample>,
    next_due: Instant,
    entry: CatalogEntry,
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
    exported: Vec<Exported>,
    waiters: Vec<TickWaiter>,
    waited_subsystems: Vec<String>,
    senders: HashMap<String, CommandSender>,
    frames: Receiver<RemoteFrame>,
    _commands: zenoh::pubsub::Subscriber<()>,
    last_frame: HashMap<(String, u64), u64>,
    offset_min: HashMap<String, i128>,
    counters: Arc<Counters>,
    warn_malformed: RateLimit,
    warn_refused: RateLimit,
    catalog_version: u64,
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
        let commands = zs
            .declare_subscriber(wire::command_key(&domain, "*"))
            .callback(move |s| queue_frame(&tx, &c2, s))
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
            exported: Vec::new(),
            waiters: Vec::new(),
            waited_subsystems: Vec::new(),
            senders: HashMap::new(),
            frames,
            _commands: commands,
            last_frame: HashMap::new(),
            offset_min: HashMap::new(),
            counters,
            warn_malformed: RateLimit::new(),
            warn_refused: RateLimit::new(),
            catalog_version: 0,
        };
        me.rescan()?;
        Ok(me)
    }

    /// Number of states exported now.
    pub(crate) fn len(&self) -> usize {
        self.exported.len()
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
        let mut added = 0;
        for s in all {
            if !any_matches(&self.states_sel, &s.subsystem, &s.name)
                || s.nodes.iter().any(|n| n.starts_with(MIRROR_NODE_PREFIX))
                || self
                    .exported
                    .iter()
                    .any(|e| e.subsystem == s.subsystem && e.name == s.name)
            {
                continue;
            }
            let sub = match StateSubscriber::from_info(&self.bus, s.clone(), 64) {
                Ok(sub) => sub,
                // It vanished between listing and opening: the next rescan tries again.
                Err(_) => continue,
            };
            let key = wire::state_key(&self.domain, &s.subsystem, &s.name);
            let publisher = self
                .zs
                .declare_publisher(key)
                // Latest-value: a congested link drops samples, never queues them.
                .congestion_control(CongestionControl::Drop)
                .wait()
                .map_err(zenoh("declaring a state publisher"))?;
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
            if !self.waited_subsystems.contains(&s.subsystem) && self.waiters.len() < 16 {
                if let Ok(w) = TickWaiter::new(&self.bus, &s.subsystem) {
                    self.waiters.push(w);
                    self.waited_subsystems.push(s.subsystem.clone());
                }
            }
            self.exported.push(Exported {
                subsystem: s.subsystem.clone(),
                name: s.name.clone(),
                sub,
                publisher,
                seq: 0,
                pending: None,
                next_due: Instant::now(),
                entry,
            });
            added += 1;
        }
        if added > 0 {
            self.exported.sort_by(|a, b| {
                (a.subsystem.as_str(), a.entry.index).cmp(&(b.subsystem.as_str(), b.entry.index))
            });
            self.catalog_version = self.catalog_version.wrapping_add(1);
            info!(
                "exporting {} state(s) as conductor/{}/<subsystem>/<state> ({} accept remote commands)",
                self.exported.len(),
                self.domain,
                self.exported.iter().filter(|e| e.entry.writable).count()
            );
        }
        Ok(())
    }

    /// The catalog of what is exported now.
    pub(crate) fn catalog(&self) -> Catalog {
        Catalog {
            host: self.host.clone(),
            session: self.session,
            version: self.catalog_version,
            heartbeat_ms: self.heartbeat.as_millis() as u64,
            states: self.exported.iter().map(|e| e.entry.clone()).collect(),
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

    /// Waits for the next tick of an exported subsystem (at most `timeout`).
    pub(crate) fn wait(&mut self, timeout: Duration) -> Result<()> {
        if self.waiters.is_empty() {
            std::thread::sleep(timeout);
        } else {
            TickWaiter::wait_any(&mut self.waiters, timeout)?;
        }
        Ok(())
    }

    /// Sends what the local states published since the last call.
    pub(crate) fn pump_states(&mut self) -> Result<()> {
        let now = Instant::now();
        let period = self.rate_hz.map(|r| Duration::from_secs_f64(1.0 / r));
        for e in &mut self.exported {
            while let Some(s) = e.sub.receive()? {
                e.pending = Some(s);
                if period.is_none() {
                    send(&self.host, self.session, e, &s, &self.counters)?;
                    e.pending = None;
                }
            }
            if let (Some(p), Some(s)) = (period, e.pending) {
                if now >= e.next_due {
                    send(&self.host, self.session, e, &s, &self.counters)?;
                    e.pending = None;
                    // Keep the cadence, but never bunch up after a pause.
                    e.next_due = (e.next_due + p).max(now);
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
            let ok = self
                .exported
                .iter()
                .any(|e| e.subsystem == sub && e.entry.index == sp.index && e.entry.writable);
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

/// Frames older than this (one-way, measured against the smallest delay seen from their host)
/// are dropped: a link that comes back must not replay stale setpoints.
pub const COMMAND_MAX_AGE: Duration = Duration::from_millis(250);

fn send(
    host: &str,
    session: u64,
    e: &mut Exported,
    s: &StateSample,
    counters: &Counters,
) -> Result<()> {
    e.seq += 1;
    let env = Envelope {
        host: host.into(),
        session,
        seq: e.seq,
    };
    e.publisher
        .put(wire::encode_sample(s).to_vec())
        .attachment(env.encode())
        .wait()
        .map_err(zenoh("putting a state sample"))?;
    Counters::bump(&counters.exported);
    Ok(())
}

fn queue_frame(tx: &SyncSender<RemoteFrame>, counters: &Counters, s: zenoh::sample::Sample) {
    let f = RemoteFrame {
        key: s.key_expr().as_str().to_string(),
        payload: s.payload().to_bytes().into_owned(),
        attachment: s.attachment().map(|a| a.to_bytes().into_owned()),
    };
    match tx.try_send(f) {
        Ok(()) => {}
        Err(TrySendError::Full(_)) => {
            Counters::bump(&counters.commands_dropped);
        }
        Err(TrySendError::Disconnected(_)) => {}
    }
}
