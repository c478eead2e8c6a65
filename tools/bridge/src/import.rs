//! The import side: remote states in from Zenoh as local mirror states, local command frames for
//! those mirrors out to the owning host.
//!
//! One thread. Zenoh's callbacks only move a message into a bounded queue (waking this thread);
//! this thread checks it (envelope, tick message size and every sample's ABI fields, a catalog
//! that declares the subsystem, a sequence newer than the last) and publishes its samples on the
//! mirror through an ordinary [`StatePublisher`], then notifies the mirror's tick event once, so
//! every local tool reads them as states and a controller can wait on a mirror's tick as on a
//! local one. Mirrors of one remote host live on a bus node called
//! `bridge@<host>`, which is how `conductor list` tells whose a state is.
//!
//! A host whose heartbeats and samples stop for two heartbeat periods has every mirror
//! re-published once with `STALE` set (same value, tick and sample time); the next valid sample
//! clears it. Frames sent to a mirror's command service go to the owner only while its host is
//! live (a frame for a quiet link is dropped and counted, never queued for later).

use std::collections::HashMap;
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use conductor_bus::{
    monotonic_ns, status, Bus, CommandFrame, CommandReceiver, Domain, StatePublisher, StateSample,
    StateSpec,
};
use tracing::{info, warn};
use zenoh::Wait;

use crate::config::{any_matches, ImportConfig, Selector};
use crate::counters::{Counters, RateLimit};
use crate::error::{zenoh, Result};
use crate::profile::{self, Stage};
use crate::wire::{self, Catalog, CatalogEntry, Envelope, Heartbeat, Malformed};
use crate::MIRROR_NODE_PREFIX;

/// Inbound queue between Zenoh's threads and this one: at 1000 states × 1 kHz that is 16 ms of
/// samples; beyond it the newest are dropped and counted (latest-value: an older sample of the
/// same state is already queued).
const INBOUND_QUEUE: usize = 16_384;
/// Frames queued for the link (commands are reliable on the link, bounded here).
pub(crate) const OUTBOUND_COMMANDS: usize = 32;

/// A message from Zenoh, tagged with the import rule whose subscriber got it. The sample itself
/// is moved through the queue (its key and buffers are reference-counted): no copy and no
/// allocation per message between Zenoh's thread and this one.
pub(crate) struct Inbound {
    rule: usize,
    what: What,
    sample: zenoh::sample::Sample,
}

impl Inbound {
    fn key(&self) -> &str {
        self.sample.key_expr().as_str()
    }

    /// The payload; borrowed when it arrived in one piece (a 48-byte sample always does).
    fn payload(&self) -> std::borrow::Cow<'_, [u8]> {
        self.sample.payload().to_bytes()
    }

    fn attachment(&self) -> Option<std::borrow::Cow<'_, [u8]>> {
        self.sample.attachment().map(|a| a.to_bytes())
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum What {
    Sample,
    Heartbeat,
    Catalog,
}

/// A frame for the link: key, payload, attachment.
pub(crate) type Outbound = (String, Vec<u8>, Vec<u8>);

struct Rule {
    domain: String,
    states: Vec<Selector>,
    prefix: String,
}

struct MirrorState {
    owner_index: u32,
    writable: bool,
    last: Option<StateSample>,
}

struct Mirror {
    owner_sub: String,
    name: String,
    /// In the owner's index order (the catalog's), so an owner index is found by binary search.
    entries: Vec<CatalogEntry>,
    /// Sequence number of the last tick message published (per owner session).
    last_seq: u64,
    publisher: StatePublisher,
    commands: CommandReceiver,
    states: Vec<MirrorState>,
}

struct Remote {
    rule: usize,
    host: String,
    bus: Bus,
    session: u64,
    catalog_version: u64,
    has_catalog: bool,
    heartbeat: Duration,
    last_seen: Instant,
    last_query: Option<Instant>,
    stale: bool,
    mirrors: Vec<Mirror>,
    /// owner's subsystem → mirror; looked up by `&str`, no allocation per message.
    index: HashMap<String, usize>,
}

/// Everything the import thread owns.
pub(crate) struct Importer {
    domain: Domain,
    zs: zenoh::Session,
    host: String,
    session: u64,
    rules: Vec<Rule>,
    remotes: Vec<Remote>,
    rx: Receiver<Inbound>,
    _subs: Vec<zenoh::pubsub::Subscriber<()>>,
    tx: SyncSender<Inbound>,
    out: SyncSender<Outbound>,
    cmd_seq: u64,
    counters: Arc<Counters>,
    warn_malformed: RateLimit,
    warn_unknown: RateLimit,
    warn_commands: RateLimit,
}

fn enqueue(
    tx: &SyncSender<Inbound>,
    counters: &Counters,
    rule: usize,
    what: What,
    sample: zenoh::sample::Sample,
) {
    if what == What::Sample && profile::enabled() {
        if let Some(t) = wire::tick_first_t_sample(&sample.payload().to_bytes()) {
            profile::record(Stage::ImportArrived, t);
        }
    }
    let m = Inbound { rule, what, sample };
    if let Err(TrySendError::Full(_)) = tx.try_send(m) {
        Counters::bump(&counters.overflow);
    }
}

impl Importer {
    /// Declares the subscribers of every import rule.
    pub(crate) fn new(
        domain: Domain,
        zs: zenoh::Session,
        rules: &[ImportConfig],
        host: String,
        session: u64,
        out: SyncSender<Outbound>,
        counters: Arc<Counters>,
    ) -> Result<Self> {
        let (tx, rx) = std::sync::mpsc::sync_channel(INBOUND_QUEUE);
        let mut subs = Vec::new();
        let mut parsed = Vec::new();
        for (i, r) in rules.iter().enumerate() {
            for (what, key) in [
                (What::Sample, wire::tick_key(&r.domain, "*")),
                (What::Heartbeat, wire::heartbeat_key(&r.domain, "*")),
                (What::Catalog, wire::catalog_key(&r.domain, "*")),
            ] {
                let (tx, c) = (tx.clone(), counters.clone());
                subs.push(
                    zs.declare_subscriber(key)
                        .callback(move |s| enqueue(&tx, &c, i, what, s))
                        .wait()
                        .map_err(zenoh("declaring an import subscriber"))?,
                );
            }
            parsed.push(Rule {
                domain: r.domain.clone(),
                states: Selector::many(&r.states)?,
                prefix: r.prefix.clone(),
            });
        }
        Ok(Self {
            domain,
            zs,
            host,
            session,
            rules: parsed,
            remotes: Vec::new(),
            rx,
            _subs: subs,
            tx,
            out,
            cmd_seq: 0,
            counters,
            warn_malformed: RateLimit::new(),
            warn_unknown: RateLimit::new(),
            warn_commands: RateLimit::new(),
        })
    }

    /// Asks every exporter of every rule for its catalog now (replies arrive as catalogs).
    pub(crate) fn query_catalogs(&self) {
        for (i, r) in self.rules.iter().enumerate() {
            self.query(i, &wire::catalog_key(&r.domain, "*"));
        }
    }

    fn query(&self, rule: usize, key: &str) {
        let (tx, c) = (self.tx.clone(), self.counters.clone());
        let res = self
            .zs
            .get(key)
            .callback(move |reply| {
                if let Ok(s) = reply.result() {
                    enqueue(&tx, &c, rule, What::Catalog, s.clone());
                }
            })
            .wait();
        if let Err(e) = res {
            warn!("cannot ask for catalogs on {key}: {e}");
        }
    }

    /// Handles what arrived (waiting up to `timeout` for the first message), forwards local
    /// command frames, and marks quiet hosts STALE.
    pub(crate) fn step(&mut self, timeout: Duration) -> Result<()> {
        match self.rx.recv_timeout(timeout) {
            Ok(m) => {
                self.handle(m);
                // Bounded, so commands and link checks are served even under a flood.
                for _ in 0..INBOUND_QUEUE {
                    match self.rx.try_recv() {
                        Ok(m) => self.handle(m),
                        Err(_) => break,
                    }
                }
            }
            Err(RecvTimeoutError::Timeout) | Err(RecvTimeoutError::Disconnected) => {}
        }
        self.pump_commands();
        self.check_links();
        Ok(())
    }

    fn handle(&mut self, m: Inbound) {
        let res = match m.what {
            What::Sample => self.on_sample(&m),
            What::Heartbeat => self.on_heartbeat(&m),
            What::Catalog => self.on_catalog(&m),
        };
        if let Err(why) = res {
            let n = Counters::bump(&self.counters.malformed);
            if let Some(held) = self.warn_malformed.allow() {
                warn!(
                    "dropped a malformed or foreign message on {}: {why} ({n} malformed so far, \
                     {held} not logged)",
                    m.key()
                );
            }
        }
    }

    fn remote(&self, rule: usize, host: &str) -> Option<usize> {
        self.remotes
            .iter()
            .position(|r| r.rule == rule && r.host == host)
    }

    fn on_heartbeat(&mut self, m: &Inbound) -> std::result::Result<(), Malformed> {
        let hb = Heartbeat::decode(&m.payload())?;
        // conductor/<domain>/@bridge/<host>/hb
        let host = m
            .key()
            .rsplit('/')
            .nth(1)
            .filter(|h| wire::valid_host(h))
            .ok_or_else(|| Malformed::Key(m.key().to_string()))?
            .to_string();
        let now = Instant::now();
        let (rule, domain) = (m.rule, self.rules[m.rule].domain.clone());
        let want_catalog = match self.remote(rule, &host) {
            Some(i) => {
                let r = &mut self.remotes[i];
                if r.session == hb.session {
                    self.mark_live(i);
                }
                let r = &self.remotes[i];
                (r.session != hb.session
                    || r.catalog_version != hb.catalog_version
                    || !r.has_catalog)
                    && r.last_query
                        .is_none_or(|t| now.duration_since(t) > Duration::from_millis(200))
            }
            None => true,
        };
        if want_catalog {
            if let Some(i) = self.remote(rule, &host) {
                self.remotes[i].last_query = Some(now);
            }
            self.query(rule, &wire::catalog_key(&domain, &host));
        }
        Ok(())
    }

    fn mark_live(&mut self, i: usize) {
        let r = &mut self.remotes[i];
        r.last_seen = Instant::now();
        if r.stale {
            r.stale = false;
            info!("link to {} is back: its states are live again", r.host);
        }
    }

    fn on_catalog(&mut self, m: &Inbound) -> std::result::Result<(), Malformed> {
        let c = Catalog::decode(&m.payload())?;
        let rule = m.rule;
        let i = match self.remote(rule, &c.host) {
            Some(i) => i,
            None => {
                let bus = match Bus::open(&self.domain, &format!("{MIRROR_NODE_PREFIX}{}", c.host))
                {
                    Ok(b) => b,
                    Err(e) => {
                        warn!("cannot join the local domain for host {}: {e}", c.host);
                        return Ok(());
                    }
                };
                self.remotes.push(Remote {
                    rule,
                    host: c.host.clone(),
                    bus,
                    session: c.session,
                    catalog_version: u64::MAX,
                    has_catalog: false,
                    heartbeat: Duration::from_millis(c.heartbeat_ms.max(1)),
                    last_seen: Instant::now(),
                    last_query: None,
                    stale: false,
                    mirrors: Vec::new(),
                    index: HashMap::new(),
                });
                self.remotes.len() - 1
            }
        };
        let r = &mut self.remotes[i];
        if r.has_catalog && r.session == c.session && r.catalog_version == c.version {
            return Ok(());
        }
        let new_session = r.session != c.session;
        r.session = c.session;
        r.catalog_version = c.version;
        r.has_catalog = true;
        r.heartbeat = Duration::from_millis(c.heartbeat_ms.max(1));
        let rule = &self.rules[rule];
        // Group what this rule imports by subsystem, in the owner's index order.
        let mut by_sub: Vec<(String, Vec<CatalogEntry>)> = Vec::new();
        for e in c
            .states
            .iter()
            .filter(|e| any_matches(&rule.states, &e.subsystem, &e.state))
        {
            match by_sub.iter_mut().find(|(s, _)| *s == e.subsystem) {
                Some((_, v)) => v.push(e.clone()),
                None => by_sub.push((e.subsystem.clone(), vec![e.clone()])),
            }
        }
        for (_, v) in &mut by_sub {
            v.sort_by_key(|e| e.index);
        }
        let local = self.domain_states();
        let r = &mut self.remotes[i];
        if new_session {
            for m in &mut r.mirrors {
                m.last_seq = 0;
            }
        }
        // Keep mirrors whose states did not change; rebuild the others.
        let mut kept: Vec<Mirror> = Vec::new();
        let old = std::mem::take(&mut r.mirrors);
        let mut old: Vec<Option<Mirror>> = old.into_iter().map(Some).collect();
        for (sub, entries) in by_sub {
            let name = format!("{}{sub}", rule.prefix);
            if let Some(m) = old
                .iter_mut()
                .find(|m| {
                    m.as_ref()
                        .is_some_and(|m| m.owner_sub == sub && m.entries == entries)
                })
                .and_then(Option::take)
            {
                kept.push(m);
                continue;
            }
            // Drop our previous mirror of it first, so its services can be re-created.
            if let Some(slot) = old
                .iter_mut()
                .find(|m| m.as_ref().is_some_and(|m| m.owner_sub == sub))
            {
                *slot = None;
            }
            if local.iter().any(|(s, writers)| {
                *s == name
                    && !writers
                        .iter()
                        .any(|w| w == &format!("{MIRROR_NODE_PREFIX}{}", r.host))
            }) {
                warn!(
                    "not importing {sub} from {}: subsystem {name:?} already exists in domain {:?} \
                     (set an import prefix)",
                    r.host,
                    self.domain.name()
                );
                continue;
            }
            match make_mirror(&r.bus, &sub, &name, entries) {
                Ok(m) => {
                    info!(
                        "mirroring {} state(s) of {}'s {sub} as {name}/* ({} accept commands)",
                        m.states.len(),
                        r.host,
                        m.states.iter().filter(|s| s.writable).count()
                    );
                    kept.push(m);
                }
                Err(e) => warn!("cannot mirror {sub} of {}: {e}", r.host),
            }
        }
        drop(old);
        r.mirrors = kept;
        r.index.clear();
        for (mi, m) in r.mirrors.iter().enumerate() {
            r.index.insert(m.owner_sub.clone(), mi);
        }
        self.mark_live(i);
        Ok(())
    }

    /// Local subsystems with their state writers (node names), to avoid claiming a name.
    fn domain_states(&self) -> Vec<(String, Vec<String>)> {
        let Some(bus) = self.remotes.first().map(|r| r.bus.clone()) else {
            return Vec::new();
        };
        bus.list_states()
            .map(|v| v.into_iter().map(|s| (s.subsystem, s.nodes)).collect())
            .unwrap_or_default()
    }

    fn on_sample(&mut self, m: &Inbound) -> std::result::Result<(), Malformed> {
        let rule = m.rule;
        let sub = wire::split_tick_key(&self.rules[rule].domain, m.key())?;
        let env = Envelope::decode(&m.attachment().ok_or(Malformed::Envelope)?)?;
        let payload = m.payload();
        if let Some(t) = wire::tick_first_t_sample(&payload).filter(|_| profile::enabled()) {
            profile::record(Stage::ImportTaken, t);
        }
        let entries = wire::decode_tick(&payload)?;
        let Some(i) = self.remote(rule, &env.host) else {
            return self.unknown(&env.host, sub, "no catalog from that host yet");
        };
        let r = &mut self.remotes[i];
        if r.session != env.session {
            return self.unknown(&env.host, sub, "from another session than its catalog");
        }
        let Some(&mi) = r.index.get(sub) else {
            // Exported but not imported by this rule, or not in the host's catalog.
            Counters::bump(&self.counters.unknown);
            return Ok(());
        };
        let mirror = &mut r.mirrors[mi];
        if env.seq <= mirror.last_seq {
            Counters::bump(&self.counters.out_of_order);
            return Ok(());
        }
        mirror.last_seq = env.seq;
        let mut first_t = None;
        let mut n = 0;
        for (owner_index, s) in entries {
            first_t.get_or_insert(s.t_sample_ns);
            // States of the subsystem this rule does not import are not mirrored.
            let Ok(si) = mirror
                .entries
                .binary_search_by_key(&owner_index, |e| e.index)
            else {
                continue;
            };
            mirror.states[si].last = Some(s);
            match mirror
                .publisher
                .publish(si, s.tick, s.t_sample_ns, s.value, s.status)
            {
                Ok(_) => n += 1,
                Err(e) => warn!(
                    "cannot publish the mirror {}/{}: {e}",
                    mirror.name, mirror.entries[si].state
                ),
            }
        }
        if n > 0 {
            // Wakes whoever waits on the mirror's tick, as the owner's tick wakes local waiters.
            if let Err(e) = mirror.publisher.notify_tick() {
                warn!("cannot notify the tick of mirror {}: {e}", mirror.name);
            }
            self.counters
                .imported
                .fetch_add(n, std::sync::atomic::Ordering::Relaxed);
        }
        if let Some(t) = first_t {
            profile::record(Stage::ImportPublished, t);
        }
        self.mark_live(i);
        Ok(())
    }

    fn unknown(&mut self, host: &str, sub: &str, why: &str) -> std::result::Result<(), Malformed> {
        let n = Counters::bump(&self.counters.unknown);
        if let Some(held) = self.warn_unknown.allow() {
            info!(
                "ignored a tick message of {sub} from {host}: {why} ({n} ignored so far, \
                 {held} not logged)"
            );
        }
        Ok(())
    }

    fn pump_commands(&mut self) {
        let mut frames: Vec<CommandFrame> = Vec::new();
        for ri in 0..self.remotes.len() {
            for mi in 0..self.remotes[ri].mirrors.len() {
                frames.clear();
                let m = &mut self.remotes[ri].mirrors[mi];
                if let Err(e) = m.commands.drain(|f| frames.push(*f)) {
                    warn!("cannot read the commands of mirror {}: {e}", m.name);
                    continue;
                }
                for f in &frames {
                    self.forward(ri, mi, f);
                }
            }
        }
    }

    fn forward(&mut self, ri: usize, mi: usize, f: &CommandFrame) {
        let r = &self.remotes[ri];
        let m = &r.mirrors[mi];
        if r.stale {
            let n = Counters::bump(&self.counters.commands_dropped);
            if let Some(held) = self.warn_commands.allow() {
                warn!(
                    "dropped a command frame for {}: the link to {} is down ({n} dropped so far, \
                     {held} not logged)",
                    m.name, r.host
                );
            }
            return;
        }
        let mut out = CommandFrame::default();
        for sp in f.setpoints() {
            // The mirror's index → the owner's; read-only mirrors were refused by the sender's
            // own checks already, anything else is dropped here.
            match m.states.get(sp.index as usize) {
                Some(s) if s.writable => {
                    out.push(s.owner_index, sp.value);
                }
                _ => {
                    Counters::bump(&self.counters.setpoints_refused);
                }
            }
        }
        if out.count == 0 {
            return;
        }
        self.cmd_seq += 1;
        out.seq = self.cmd_seq;
        out.t_send_ns = monotonic_ns();
        let env = Envelope {
            host: self.host.clone(),
            session: self.session,
            seq: self.cmd_seq,
        };
        let key = wire::command_key(&self.rules[r.rule].domain, &m.owner_sub);
        match self
            .out
            .try_send((key, wire::encode_frame(&out), env.encode()))
        {
            Ok(()) => {}
            Err(_) => {
                let n = Counters::bump(&self.counters.commands_dropped);
                if let Some(held) = self.warn_commands.allow() {
                    warn!(
                        "dropped a command frame for {}: {OUTBOUND_COMMANDS} frames already wait \
                         for the link ({n} dropped so far, {held} not logged)",
                        m.name
                    );
                }
            }
        }
    }

    fn check_links(&mut self) {
        let now = Instant::now();
        for r in &mut self.remotes {
            if r.stale || !r.has_catalog || now.duration_since(r.last_seen) <= 2 * r.heartbeat {
                continue;
            }
            r.stale = true;
            Counters::bump(&self.counters.stale_events);
            let mut n = 0;
            for m in &mut r.mirrors {
                for (si, s) in m.states.iter().enumerate() {
                    if let Some(last) = s.last {
                        let _ = m.publisher.publish(
                            si,
                            last.tick,
                            last.t_sample_ns,
                            last.value,
                            last.status | status::STALE,
                        );
                        n += 1;
                    }
                }
            }
            warn!(
                "link to {} quiet for {} ms: {n} mirrored state(s) marked STALE",
                r.host,
                now.duration_since(r.last_seen).as_millis()
            );
        }
    }
}

fn make_mirror(
    bus: &Bus,
    owner_sub: &str,
    name: &str,
    entries: Vec<CatalogEntry>,
) -> Result<Mirror> {
    let mut entries = entries;
    // The catalog lists them in index order already; the lookup by owner index relies on it.
    entries.sort_by_key(|e| e.index);
    let specs: Vec<StateSpec> = entries
        .iter()
        .enumerate()
        .map(|(i, e)| StateSpec::new(e.state.clone(), e.meta(i as u32)))
        .collect();
    // Commands first: once a mirror state is visible, a controller can command it.
    let commands = CommandReceiver::create(bus, name)?;
    let publisher = StatePublisher::create(bus, name, &specs)?;
    let states = entries
        .iter()
        .map(|e| MirrorState {
            owner_index: e.index,
            writable: e.writable,
            last: None,
        })
        .collect();
    Ok(Mirror {
        owner_sub: owner_sub.into(),
        name: name.into(),
        entries,
        last_seq: 0,
        publisher,
        commands,
        states,
    })
}

/// Sends queued command frames on the link, in order; a congested link blocks this thread
/// only (reliable, bounded by [`OUTBOUND_COMMANDS`] frames before the import thread drops).
pub(crate) fn command_sender(zs: zenoh::Session, rx: Receiver<Outbound>, counters: Arc<Counters>) {
    while let Ok((key, payload, attachment)) = rx.recv() {
        let res = zs
            .put(&key, payload)
            .attachment(attachment)
            .congestion_control(zenoh::qos::CongestionControl::Block)
            .priority(zenoh::qos::Priority::InteractiveHigh)
            .wait();
        match res {
            Ok(()) => {
                Counters::bump(&counters.commands_out);
            }
            Err(e) => {
                Counters::bump(&counters.commands_dropped);
                warn!("cannot send a command frame on {key}: {e}");
            }
        }
    }
}
