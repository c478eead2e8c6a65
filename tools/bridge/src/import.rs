//! The import side: remote states in from Zenoh as local mirror states, local command frames for
//! those mirrors out to the owning host.
//!
//! No thread wake-up between the link and the local bus: Zenoh's subscriber callback checks a
//! tick message (envelope, size and every sample's ABI fields, a catalog that declares the
//! subsystem, a sequence newer than the last) and publishes its samples on the mirror right
//! there, through an ordinary [`StatePublisher`], then notifies the mirror's tick event once, so
//! every local tool reads them as states and a controller can wait on a mirror's tick as on a
//! local one. Heartbeats are handled in their callback too. Mirrors of one remote host live on a
//! bus node called `bridge@<host>`, which is how `conductor list` tells whose a state is.
//!
//! The import thread does the rest: it builds mirrors from catalogs (service creation is slow and
//! rare), forwards local command frames, and marks quiet hosts STALE. What the callbacks and the
//! thread share (the mirrors, each host's liveness) sits behind one mutex, so a STALE mark and a
//! sample are never interleaved: the mark re-publishes the newest sample, and a sample that
//! arrives after it clears it. The lock is uncontended in practice (the thread takes it once per
//! [`POLL`](crate::POLL) for microseconds), and none of this is an executor's real-time path.
//!
//! A host whose heartbeats and samples stop for two heartbeat periods has every mirror
//! re-published once with `STALE` set (same value, tick and sample time); the next valid sample
//! clears it. Frames sent to a mirror's command service go to the owner only while its host is
//! live (a frame for a quiet link is dropped and counted, never queued for later).

use std::collections::HashMap;
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
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
use crate::wire::{self, Catalog, CatalogEntry, Envelope, Heartbeat, Malformed, TickEntries};
use crate::MIRROR_NODE_PREFIX;

/// Catalogs waiting for the import thread (they arrive once per second per host at most; beyond
/// this they are dropped and counted, and the next one is used).
const CATALOG_QUEUE: usize = 64;
/// Frames queued for the link (commands are reliable on the link, bounded here).
pub(crate) const OUTBOUND_COMMANDS: usize = 32;

/// A catalog from Zenoh (published or a query's reply), tagged with its import rule.
struct CatalogMessage {
    rule: usize,
    sample: zenoh::sample::Sample,
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

/// What Zenoh's callbacks and the import thread share, behind [`Shared::state`].
struct State {
    remotes: Vec<Remote>,
    /// Catalog queries the callbacks want made (made by the import thread, outside the lock).
    queries: Vec<(usize, String)>,
    host: String,
    session: u64,
    out: SyncSender<Outbound>,
    cmd_seq: u64,
    warn_malformed: RateLimit,
    warn_unknown: RateLimit,
    warn_commands: RateLimit,
}

/// [`State`], movable to Zenoh's threads.
struct Guarded(State);

// SAFETY: `State` is `!Send` only because of the iceoryx2 ports in its mirrors (`StatePublisher`,
// `CommandReceiver`): their process-local bookkeeping is reference-counted without atomics
// (`conductor_bus::PooledRc`, iceoryx2's `SingleThreaded` policy in its `ipc` variant); iceoryx2's
// `ipc_threadsafe` variant, identical but for a mutex around that bookkeeping, is `Send + Sync`.
// Here every access goes through the one `Mutex` in `Shared`, which orders them as that variant's
// mutex would. `PooledRc` also takes per-sample slots from the calling thread's pool and gives
// them back to the pool of the thread that drops them: a sample is loaned and sent within one
// `publish` call, on one thread, and the ports themselves are created and dropped only by the
// import thread (in `Importer::on_catalog` and `Importer::drop`), never by a callback. `Bus`
// handles (an `Rc`) are not in `State`: the import thread keeps them.
unsafe impl Send for Guarded {}

/// Shared by the import thread and Zenoh's callbacks.
struct Shared {
    rules: Vec<Rule>,
    counters: Arc<Counters>,
    /// `None` once the importer is shutting down (late callbacks then do nothing).
    state: Mutex<Option<Guarded>>,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Option<Guarded>> {
        // A callback that panicked left nothing half-published that matters more than the link.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Zenoh's callback for tick messages: checks it and publishes its samples on the mirror.
    fn on_tick(&self, rule: usize, sample: &zenoh::sample::Sample) {
        let payload = sample.payload().to_bytes();
        let first_t = profile::enabled()
            .then(|| wire::tick_first_t_sample(&payload))
            .flatten();
        if let Some(t) = first_t {
            profile::record(Stage::ImportArrived, t);
        }
        let key = sample.key_expr().as_str();
        // Everything that needs no state is checked before taking the lock.
        let checked = (|| {
            let sub = wire::split_tick_key(&self.rules[rule].domain, key)?;
            let att = sample.attachment().map(|a| a.to_bytes());
            let env = Envelope::decode(att.as_deref().ok_or(Malformed::Envelope)?)?;
            let entries = wire::decode_tick(&payload)?;
            Ok::<_, Malformed>((sub, env, entries))
        })();
        let mut g = self.lock();
        let Some(Guarded(st)) = g.as_mut() else {
            return;
        };
        if let Some(t) = first_t {
            profile::record(Stage::ImportLocked, t);
        }
        match checked {
            Ok((sub, env, entries)) => st.publish_tick(&self.counters, rule, sub, &env, entries),
            Err(why) => st.malformed(&self.counters, key, &why),
        }
    }

    /// Zenoh's callback for heartbeats.
    fn on_heartbeat(&self, rule: usize, sample: &zenoh::sample::Sample) {
        let key = sample.key_expr().as_str();
        let checked = (|| {
            let hb = Heartbeat::decode(&sample.payload().to_bytes())?;
            // conductor/<domain>/@bridge/<host>/hb
            let host = key
                .rsplit('/')
                .nth(1)
                .filter(|h| wire::valid_host(h))
                .ok_or_else(|| Malformed::Key(key.to_string()))?;
            Ok::<_, Malformed>((hb, host))
        })();
        let mut g = self.lock();
        let Some(Guarded(st)) = g.as_mut() else {
            return;
        };
        match checked {
            Ok((hb, host)) => st.on_heartbeat(&self.rules, rule, host, &hb),
            Err(why) => st.malformed(&self.counters, key, &why),
        }
    }
}

/// The import side, owned by the import thread.
pub(crate) struct Importer {
    domain: Domain,
    zs: zenoh::Session,
    shared: Arc<Shared>,
    /// One bus node per remote host (`bridge@<host>`), by rule and host; kept on this thread.
    buses: Vec<(usize, String, Bus)>,
    catalogs: Receiver<CatalogMessage>,
    catalog_tx: SyncSender<CatalogMessage>,
    subs: Vec<zenoh::pubsub::Subscriber<()>>,
}

fn queue_catalog(
    tx: &SyncSender<CatalogMessage>,
    counters: &Counters,
    rule: usize,
    sample: zenoh::sample::Sample,
) {
    if let Err(TrySendError::Full(_)) = tx.try_send(CatalogMessage { rule, sample }) {
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
        let mut parsed = Vec::new();
        for r in rules {
            parsed.push(Rule {
                domain: r.domain.clone(),
                states: Selector::many(&r.states)?,
                prefix: r.prefix.clone(),
            });
        }
        let shared = Arc::new(Shared {
            rules: parsed,
            counters: counters.clone(),
            state: Mutex::new(Some(Guarded(State {
                remotes: Vec::new(),
                queries: Vec::new(),
                host,
                session,
                out,
                cmd_seq: 0,
                warn_malformed: RateLimit::new(),
                warn_unknown: RateLimit::new(),
                warn_commands: RateLimit::new(),
            }))),
        });
        let (catalog_tx, catalogs) = std::sync::mpsc::sync_channel(CATALOG_QUEUE);
        let mut subs = Vec::new();
        for (i, r) in rules.iter().enumerate() {
            let sh = shared.clone();
            subs.push(
                zs.declare_subscriber(wire::tick_key(&r.domain, "*"))
                    .callback(move |s| sh.on_tick(i, &s))
                    .wait()
                    .map_err(zenoh("declaring an import subscriber"))?,
            );
            let sh = shared.clone();
            subs.push(
                zs.declare_subscriber(wire::heartbeat_key(&r.domain, "*"))
                    .callback(move |s| sh.on_heartbeat(i, &s))
                    .wait()
                    .map_err(zenoh("declaring an import subscriber"))?,
            );
            let (tx, c) = (catalog_tx.clone(), counters.clone());
            subs.push(
                zs.declare_subscriber(wire::catalog_key(&r.domain, "*"))
                    .callback(move |s| queue_catalog(&tx, &c, i, s))
                    .wait()
                    .map_err(zenoh("declaring an import subscriber"))?,
            );
        }
        Ok(Self {
            domain,
            zs,
            shared,
            buses: Vec::new(),
            catalogs,
            catalog_tx,
            subs,
        })
    }

    /// Asks every exporter of every rule for its catalog now (replies arrive as catalogs).
    pub(crate) fn query_catalogs(&self) {
        for (i, r) in self.shared.rules.iter().enumerate() {
            self.query(i, &wire::catalog_key(&r.domain, "*"));
        }
    }

    fn query(&self, rule: usize, key: &str) {
        let (tx, c) = (self.catalog_tx.clone(), self.shared.counters.clone());
        let res = self
            .zs
            .get(key)
            .callback(move |reply| {
                if let Ok(s) = reply.result() {
                    queue_catalog(&tx, &c, rule, s.clone());
                }
            })
            .wait();
        if let Err(e) = res {
            warn!("cannot ask for catalogs on {key}: {e}");
        }
    }

    /// Builds mirrors from the catalogs that arrived (waiting up to `timeout` for one), forwards
    /// local command frames, marks quiet hosts STALE and asks for the catalogs heartbeats said
    /// are new. (Tick messages and heartbeats are handled by Zenoh's callbacks.)
    pub(crate) fn step(&mut self, timeout: Duration) -> Result<()> {
        match self.catalogs.recv_timeout(timeout) {
            Ok(m) => {
                self.catalog(&m);
                while let Ok(m) = self.catalogs.try_recv() {
                    self.catalog(&m);
                }
            }
            Err(RecvTimeoutError::Timeout) | Err(RecvTimeoutError::Disconnected) => {}
        }
        let queries = {
            let mut g = self.shared.lock();
            let Some(Guarded(st)) = g.as_mut() else {
                return Ok(());
            };
            st.pump_commands(&self.shared.rules, &self.shared.counters);
            st.check_links(&self.shared.counters);
            std::mem::take(&mut st.queries)
        };
        // Outside the lock: a reply may be delivered on this very thread.
        for (rule, key) in queries {
            self.query(rule, &key);
        }
        Ok(())
    }

    fn catalog(&mut self, m: &CatalogMessage) {
        if let Err(why) = self.on_catalog(m) {
            let mut g = self.shared.lock();
            if let Some(Guarded(st)) = g.as_mut() {
                st.malformed(&self.shared.counters, m.sample.key_expr().as_str(), &why);
            }
        }
    }

    fn on_catalog(&mut self, m: &CatalogMessage) -> std::result::Result<(), Malformed> {
        let c = Catalog::decode(&m.sample.payload().to_bytes())?;
        let rule_i = m.rule;
        let rule = &self.shared.rules[rule_i];
        let bus = match self
            .buses
            .iter()
            .find(|(r, h, _)| *r == rule_i && *h == c.host)
        {
            Some((_, _, b)) => b.clone(),
            None => match Bus::open(&self.domain, &format!("{MIRROR_NODE_PREFIX}{}", c.host)) {
                Ok(b) => {
                    self.buses.push((rule_i, c.host.clone(), b.clone()));
                    b
                }
                Err(e) => {
                    warn!("cannot join the local domain for host {}: {e}", c.host);
                    return Ok(());
                }
            },
        };
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

        // Under the lock: take out the mirrors that change; they are dropped, and new ones
        // built, here on this thread without it (creating services is slow).
        let (i, dropped, build) = {
            let mut g = self.shared.lock();
            let Some(Guarded(st)) = g.as_mut() else {
                return Ok(());
            };
            let i = match st.remote(rule_i, &c.host) {
                Some(i) => i,
                None => {
                    st.remotes.push(Remote {
                        rule: rule_i,
                        host: c.host.clone(),
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
                    st.remotes.len() - 1
                }
            };
            let r = &mut st.remotes[i];
            if r.has_catalog && r.session == c.session && r.catalog_version == c.version {
                return Ok(());
            }
            if r.session != c.session {
                for m in &mut r.mirrors {
                    m.last_seq = 0;
                }
            }
            r.session = c.session;
            r.catalog_version = c.version;
            r.has_catalog = true;
            r.heartbeat = Duration::from_millis(c.heartbeat_ms.max(1));
            // Keep mirrors whose states did not change; take out the others.
            let (keep, dropped): (Vec<Mirror>, Vec<Mirror>) =
                std::mem::take(&mut r.mirrors).into_iter().partition(|m| {
                    by_sub
                        .iter()
                        .any(|(s, e)| *s == m.owner_sub && *e == m.entries)
                });
            r.mirrors = keep;
            let build: Vec<(String, Vec<CatalogEntry>)> = by_sub
                .into_iter()
                .filter(|(s, _)| !r.mirrors.iter().any(|m| m.owner_sub == *s))
                .collect();
            r.index = r
                .mirrors
                .iter()
                .enumerate()
                .map(|(mi, m)| (m.owner_sub.clone(), mi))
                .collect();
            (i, dropped, build)
        };
        // Our previous mirror of a subsystem goes first, so its services can be re-created;
        // what is left of them (held open by local subscribers) is ours, not a conflict.
        let rebuilt: Vec<String> = dropped.iter().map(|m| m.owner_sub.clone()).collect();
        drop(dropped);
        let local: Vec<(String, Vec<String>)> = bus
            .list_states()
            .map(|v| v.into_iter().map(|s| (s.subsystem, s.nodes)).collect())
            .unwrap_or_default();
        let me = format!("{MIRROR_NODE_PREFIX}{}", c.host);
        let mut built = Vec::new();
        for (sub, entries) in build {
            let name = format!("{}{sub}", rule.prefix);
            if !rebuilt.contains(&sub)
                && local
                    .iter()
                    .any(|(s, writers)| *s == name && !writers.contains(&me))
            {
                warn!(
                    "not importing {sub} from {}: subsystem {name:?} already exists in domain {:?} \
                     (set an import prefix)",
                    c.host,
                    self.domain.name()
                );
                continue;
            }
            match make_mirror(&bus, &sub, &name, entries) {
                Ok(m) => {
                    info!(
                        "mirroring {} state(s) of {}'s {sub} as {name}/* ({} accept commands)",
                        m.states.len(),
                        c.host,
                        m.states.iter().filter(|s| s.writable).count()
                    );
                    built.push(m);
                }
                Err(e) => warn!("cannot mirror {sub} of {}: {e}", c.host),
            }
        }
        let mut g = self.shared.lock();
        let Some(Guarded(st)) = g.as_mut() else {
            return Ok(());
        };
        let r = &mut st.remotes[i];
        for m in built {
            r.index.insert(m.owner_sub.clone(), r.mirrors.len());
            r.mirrors.push(m);
        }
        st.mark_live(i);
        Ok(())
    }
}

impl Drop for Importer {
    fn drop(&mut self) {
        // No more callbacks, then the mirrors' ports are dropped here, on the thread that made
        // them (a callback still running finishes first: it holds the lock).
        self.subs.clear();
        let state = self.shared.lock().take();
        drop(state);
    }
}

impl State {
    fn remote(&self, rule: usize, host: &str) -> Option<usize> {
        self.remotes
            .iter()
            .position(|r| r.rule == rule && r.host == host)
    }

    fn malformed(&mut self, counters: &Counters, key: &str, why: &Malformed) {
        let n = Counters::bump(&counters.malformed);
        if let Some(held) = self.warn_malformed.allow() {
            warn!(
                "dropped a malformed or foreign message on {key}: {why} ({n} malformed so far, \
                 {held} not logged)"
            );
        }
    }

    fn on_heartbeat(&mut self, rules: &[Rule], rule: usize, host: &str, hb: &Heartbeat) {
        let now = Instant::now();
        let want_catalog = match self.remote(rule, host) {
            Some(i) => {
                if self.remotes[i].session == hb.session {
                    self.mark_live(i);
                }
                let r = &mut self.remotes[i];
                let want = (r.session != hb.session
                    || r.catalog_version != hb.catalog_version
                    || !r.has_catalog)
                    && r.last_query
                        .is_none_or(|t| now.duration_since(t) > Duration::from_millis(200));
                if want {
                    r.last_query = Some(now);
                }
                want
            }
            None => true,
        };
        if want_catalog {
            let key = wire::catalog_key(&rules[rule].domain, host);
            if !self.queries.iter().any(|(r, k)| *r == rule && *k == key) {
                self.queries.push((rule, key));
            }
        }
    }

    fn mark_live(&mut self, i: usize) {
        let r = &mut self.remotes[i];
        r.last_seen = Instant::now();
        if r.stale {
            r.stale = false;
            info!("link to {} is back: its states are live again", r.host);
        }
    }

    fn publish_tick(
        &mut self,
        counters: &Counters,
        rule: usize,
        sub: &str,
        env: &Envelope,
        entries: TickEntries<'_>,
    ) {
        let Some(i) = self.remote(rule, &env.host) else {
            return self.unknown(counters, &env.host, sub, "no catalog from that host yet");
        };
        let r = &mut self.remotes[i];
        if r.session != env.session {
            return self.unknown(
                counters,
                &env.host,
                sub,
                "from another session than its catalog",
            );
        }
        let Some(&mi) = r.index.get(sub) else {
            // Exported but not imported by this rule, or not in the host's catalog.
            Counters::bump(&counters.unknown);
            return;
        };
        let mirror = &mut r.mirrors[mi];
        if env.seq <= mirror.last_seq {
            Counters::bump(&counters.out_of_order);
            return;
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
            counters
                .imported
                .fetch_add(n, std::sync::atomic::Ordering::Relaxed);
        }
        if let Some(t) = first_t {
            profile::record(Stage::ImportPublished, t);
        }
        self.mark_live(i);
    }

    fn unknown(&mut self, counters: &Counters, host: &str, sub: &str, why: &str) {
        let n = Counters::bump(&counters.unknown);
        if let Some(held) = self.warn_unknown.allow() {
            info!(
                "ignored a tick message of {sub} from {host}: {why} ({n} ignored so far, \
                 {held} not logged)"
            );
        }
    }

    fn pump_commands(&mut self, rules: &[Rule], counters: &Counters) {
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
                    self.forward(rules, counters, ri, mi, f);
                }
            }
        }
    }

    fn forward(
        &mut self,
        rules: &[Rule],
        counters: &Counters,
        ri: usize,
        mi: usize,
        f: &CommandFrame,
    ) {
        let r = &self.remotes[ri];
        let m = &r.mirrors[mi];
        if r.stale {
            let n = Counters::bump(&counters.commands_dropped);
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
                    Counters::bump(&counters.setpoints_refused);
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
        let key = wire::command_key(&rules[r.rule].domain, &m.owner_sub);
        match self
            .out
            .try_send((key, wire::encode_frame(&out), env.encode()))
        {
            Ok(()) => {}
            Err(_) => {
                let n = Counters::bump(&counters.commands_dropped);
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

    fn check_links(&mut self, counters: &Counters) {
        // Taken under the lock: a sample handled just before moved `last_seen` past any
        // earlier reading of the clock.
        let now = Instant::now();
        for r in &mut self.remotes {
            if r.stale || !r.has_catalog || now.duration_since(r.last_seen) <= 2 * r.heartbeat {
                continue;
            }
            r.stale = true;
            Counters::bump(&counters.stale_events);
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
