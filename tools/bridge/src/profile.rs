//! Where a sample's time goes inside the bridge, when `CONDUCTOR_BRIDGE_PROFILE` is set.
//!
//! Each stage records, per message, the time since the sample was stamped by its owner
//! (`t_sample_ns`) into a lock-free histogram of 1 µs buckets; the bridge prints p50/p99 per
//! stage at exit. Only meaningful when both bridges share one clock (one machine, or network
//! namespaces of one machine, as in `conductor bench --bridge`). Off, a stage costs one load.

use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::OnceLock;

/// A point on a sample's way through a bridge.
#[derive(Debug, Clone, Copy)]
pub enum Stage {
    /// Exporter: the tick's samples taken from the local bus (after the wake) and the message built.
    ExportReceived = 0,
    /// Exporter: the Zenoh put returned.
    ExportPut = 1,
    /// Importer: Zenoh's callback got the message.
    ImportArrived = 2,
    /// Importer: the callback checked it and holds the importer's lock.
    ImportLocked = 3,
    /// Importer: the mirror's samples are on the local bus and its tick notified.
    ImportPublished = 4,
}

const STAGES: [&str; 5] = [
    "export received",
    "export put",
    "import arrived",
    "import checked and locked",
    "import published",
];
/// Buckets of 1 µs; the last one holds everything slower.
const BUCKETS: usize = 10_000;

struct Profile {
    hist: Vec<Vec<AtomicU64>>,
}

fn profile() -> Option<&'static Profile> {
    static P: OnceLock<Option<Profile>> = OnceLock::new();
    P.get_or_init(|| {
        std::env::var_os("CONDUCTOR_BRIDGE_PROFILE").map(|_| Profile {
            hist: (0..STAGES.len())
                .map(|_| (0..BUCKETS).map(|_| AtomicU64::new(0)).collect())
                .collect(),
        })
    })
    .as_ref()
}

/// Whether profiling is on (`CONDUCTOR_BRIDGE_PROFILE` set).
pub fn enabled() -> bool {
    profile().is_some()
}

/// Records that a message whose (first) sample was stamped at `t_sample_ns` reached `stage`.
#[inline]
pub fn record(stage: Stage, t_sample_ns: u64) {
    if let Some(p) = profile() {
        let us = conductor_bus::monotonic_ns().saturating_sub(t_sample_ns) / 1_000;
        p.hist[stage as usize][(us as usize).min(BUCKETS - 1)].fetch_add(1, Relaxed);
    }
}

/// One line per stage that saw messages (`None` when profiling is off).
pub fn report() -> Option<String> {
    let p = profile()?;
    let mut out = String::new();
    for (name, h) in STAGES.iter().zip(&p.hist) {
        let counts: Vec<u64> = h.iter().map(|c| c.load(Relaxed)).collect();
        let n: u64 = counts.iter().sum();
        if n == 0 {
            continue;
        }
        let at = |q: f64| {
            let want = ((n as f64) * q).ceil().max(1.0) as u64;
            let mut seen = 0;
            counts
                .iter()
                .position(|c| {
                    seen += c;
                    seen >= want
                })
                .unwrap_or(BUCKETS - 1)
        };
        out.push_str(&format!(
            "profile {name}: n {n} p50 {} µs p99 {} µs\n",
            at(0.5),
            at(0.99)
        ));
    }
    Some(out)
}
