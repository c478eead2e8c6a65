#![doc = include_str!("../README.md")]

pub mod config;
pub mod counters;
pub mod cpus;
pub mod error;
mod export;
mod import;
pub mod profile;
pub mod wire;

use std::sync::mpsc;
use std::sync::Arc;
use std::time::{Duration, Instant};

use conductor_bus::{Bus, Domain};
use tracing::{info, warn};
use zenoh::Wait;

pub use config::BridgeConfig;
pub use counters::Counters;
pub use error::{BridgeError, Result};
pub use export::COMMAND_MAX_AGE;

/// Mirrors of host `h`'s states are published by a bus node called `bridge@h`.
pub const MIRROR_NODE_PREFIX: &str = "bridge@";

/// The host that publishes a state, from the names of its writer nodes: `Some(h)` for a mirror
/// of host `h`'s state, `None` for a state of this machine.
pub fn owning_host<'a>(writers: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    writers
        .into_iter()
        .find_map(|w| w.strip_prefix(MIRROR_NODE_PREFIX))
}

/// What the bridge reports once it runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ready {
    /// This bridge's host name.
    pub host: String,
    /// States exported at start (more are picked up as their executors start).
    pub exported: usize,
    /// Remote domains imported.
    pub imports: usize,
}

/// How long a bridge thread waits for work before looking at its timers (work itself wakes it:
/// ticks, command frames and inbound messages are events).
pub(crate) const POLL: Duration = Duration::from_millis(1);

fn session_id() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u64(conductor_bus::monotonic_ns());
    h.write_u32(std::process::id());
    h.finish()
}

/// Runs the bridge on `domain` until `stop()` returns true; calls `ready` once everything is
/// declared. Returns the counters.
///
/// Threads: one exports (with its own bus node), one imports (one bus node per remote host),
/// one puts command frames on the link; Zenoh runs its own.
pub fn run(
    cfg: &BridgeConfig,
    domain: &Domain,
    stop: impl Fn() -> bool + Send + Sync + Clone + 'static,
    ready: impl FnOnce(&Ready),
) -> Result<Arc<Counters>> {
    cfg.check()?;
    // Before Zenoh starts its threads, so they inherit the CPUs.
    let placed = cpus::place(cfg)?;
    let host = cfg.host();
    let session = session_id();
    let heartbeat = Duration::from_millis(cfg.heartbeat_ms());
    let counters = Arc::new(Counters::default());
    let zs = zenoh::open(cfg.zenoh_config()?)
        .wait()
        .map_err(error::zenoh("opening the session"))?;
    info!(
        "bridge {host} on domain {:?}: zenoh id {}",
        domain.name(),
        zs.zid()
    );
    if let Some(p) = placed {
        info!("bridge {host}: {p}");
    }

    let (up_tx, up_rx) = mpsc::channel::<Result<(usize, usize)>>();
    let mut threads = Vec::new();

    if let Some(ecfg) = cfg.export.clone() {
        let (zs, d, host, c, stop, up) = (
            zs.clone(),
            domain.clone(),
            host.clone(),
            counters.clone(),
            stop.clone(),
            up_tx.clone(),
        );
        threads.push(spawn("bridge-export", move || {
            let bus = Bus::open(&d, &format!("bridge-export@{host}"))?;
            let mut ex = match export::Exporter::new(bus, zs, &ecfg, host, session, heartbeat, c) {
                Ok(ex) => ex,
                Err(e) => {
                    let msg = e.to_string();
                    let _ = up.send(Err(e));
                    return Err(BridgeError::Thread(msg));
                }
            };
            // The catalog queryable: importers ask when they start or see a new version.
            let catalog = Arc::new(std::sync::Mutex::new(Vec::new()));
            let (cat2, key) = (catalog.clone(), wire::catalog_key(ex.domain(), ex.host()));
            let _queryable = ex
                .zenoh()
                .declare_queryable(key.clone())
                .callback(move |q| {
                    let json = cat2.lock().map(|j| j.clone()).unwrap_or_default();
                    if !json.is_empty() {
                        let _ = q.reply(key.clone(), json).wait();
                    }
                })
                .wait()
                .map_err(error::zenoh("declaring the catalog queryable"))?;
            let publish_catalog = |ex: &export::Exporter| -> Result<()> {
                let json = serde_json::to_vec(&ex.catalog()).expect("a catalog serialises");
                if let Ok(mut j) = catalog.lock() {
                    *j = json;
                }
                ex.put_catalog()
            };
            publish_catalog(&ex)?;
            let _ = up.send(Ok((ex.len(), 0)));
            // Later listings of the domain come from a thread of their own (they are slow).
            let (scan_tx, scans) = mpsc::sync_channel(1);
            let (d2, h2, stop2) = (d.clone(), ex.host().to_string(), stop.clone());
            let _scanner = spawn("bridge-scan", move || {
                let bus = Bus::open(&d2, &format!("bridge-scan@{h2}"))?;
                export::scanner(bus, scan_tx, stop2);
                Ok(())
            })?;
            let mut next_hb = Instant::now();
            let mut next_scan = Instant::now() + export::RESCAN;
            while !stop() {
                // Ticks and command frames wake the thread; otherwise it sleeps until the next
                // heartbeat or rescan (or polls, for what has no event: rate-limited export,
                // a subsystem without a tick event).
                let now = Instant::now();
                let timeout = if ex.needs_polling() {
                    POLL
                } else {
                    next_hb.min(next_scan).saturating_duration_since(now)
                };
                ex.wait(timeout)?;
                ex.pump_states()?;
                ex.pump_commands()?;
                let now = Instant::now();
                if now >= next_hb {
                    ex.put_heartbeat()?;
                    next_hb = (next_hb + heartbeat).max(now);
                }
                if let Ok(all) = scans.try_recv() {
                    ex.add(all)?;
                }
                if now >= next_scan {
                    publish_catalog(&ex)?;
                    next_scan = now + export::RESCAN;
                }
            }
            if let Some(s) = ex.spin_summary() {
                info!("{s}");
            }
            Ok(())
        })?);
    } else {
        let _ = up_tx.send(Ok((0, 0)));
    }

    let (out_tx, out_rx) = mpsc::sync_channel(import::OUTBOUND_COMMANDS);
    if !cfg.import.is_empty() {
        let (zs2, c2) = (zs.clone(), counters.clone());
        threads.push(spawn("bridge-commands", move || {
            import::command_sender(zs2, out_rx, c2);
            Ok(())
        })?);
        let (zs, d, rules, host, c, stop, up) = (
            zs.clone(),
            domain.clone(),
            cfg.import.clone(),
            host.clone(),
            counters.clone(),
            stop.clone(),
            up_tx.clone(),
        );
        threads.push(spawn("bridge-import", move || {
            let n = rules.len();
            let mut im = match import::Importer::new(d, zs, &rules, host, session, out_tx, c) {
                Ok(im) => im,
                Err(e) => {
                    let msg = e.to_string();
                    let _ = up.send(Err(e));
                    return Err(BridgeError::Thread(msg));
                }
            };
            im.query_catalogs();
            let _ = up.send(Ok((0, n)));
            while !stop() {
                im.step(POLL)?;
            }
            Ok(())
        })?);
    } else {
        drop(out_rx);
        let _ = up_tx.send(Ok((0, 0)));
    }
    drop(up_tx);

    let mut r = Ready {
        host: host.clone(),
        exported: 0,
        imports: 0,
    };
    for _ in 0..2 {
        match up_rx.recv() {
            Ok(Ok((e, i))) => {
                r.exported += e;
                r.imports += i;
            }
            Ok(Err(e)) => {
                let _ = zs.close().wait();
                return Err(e);
            }
            Err(_) => break,
        }
    }
    ready(&r);

    let mut first_err = None;
    for t in threads {
        match t.join() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                warn!("{e}");
                first_err.get_or_insert(e);
            }
            Err(_) => {
                first_err.get_or_insert(BridgeError::Thread("a bridge thread panicked".into()));
            }
        }
        // Once one thread ended, the others must too.
        if first_err.is_some() {
            break;
        }
    }
    let _ = zs.close().wait();
    match first_err {
        Some(e) => Err(e),
        None => Ok(counters),
    }
}

fn spawn(
    name: &'static str,
    f: impl FnOnce() -> Result<()> + Send + 'static,
) -> Result<std::thread::JoinHandle<Result<()>>> {
    std::thread::Builder::new()
        .name(name.into())
        .spawn(f)
        .map_err(|source| BridgeError::Spawn { name, source })
}

/// The Zenoh crate the bridge is built on (for tools and tests that talk to the key space).
pub use zenoh;
