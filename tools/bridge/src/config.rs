//! The bridge's configuration: a `bridge.toml`, or the `[bridge]` table of a robot manifest.
//!
//! ```toml
//! host = "robot"                # this bridge's name on Zenoh (default: the machine's host name)
//! heartbeat_ms = 50             # liveness period; importers mark states STALE after 2 missed
//! cpus = [2, 3]                 # CPUs it runs on (default: all but the manifest's executors')
//!
//! [zenoh]
//! mode = "peer"                 # "peer" (default) or "client" (through a zenohd router)
//! listen = ["tcp/0.0.0.0:7447"]
//! connect = ["tcp/192.168.1.20:7447"]
//! multicast_scouting = false    # default: explicit endpoints only
//! lease_ms = 1000               # a silent link is dropped after this and redialled
//! config_file = "zenoh.json5"   # a full Zenoh config (TLS, access control), applied first
//!
//! [export]                      # what leaves this host
//! states = ["leg/*"]            # globs over subsystem/state
//! rate_hz = 100                 # optional: at most this rate per state (default: every sample)
//! commands = ["leg/knee"]       # states that accept remote commands (default: none)
//! spin_us = 0                   # busy-wait up to this long before an expected tick (default 0)
//!
//! [[import]]                    # what comes in: states of another host's domain
//! domain = "robot"
//! states = ["*"]
//! prefix = ""                   # mirror subsystem = prefix + subsystem
//! ```

use std::path::PathBuf;

use glob::{MatchOptions, Pattern};
use serde::Deserialize;

use crate::error::{BridgeError, Result};
use crate::wire::valid_host;

/// Default heartbeat period (ms).
pub const DEFAULT_HEARTBEAT_MS: u64 = 50;
/// Default Zenoh lease (ms): how long a silent link is kept before it is closed and redialled.
pub const DEFAULT_LEASE_MS: u64 = 1000;
/// Default export spin (µs): none, the export thread sleeps until a tick wakes it.
pub const DEFAULT_SPIN_US: u64 = 0;
/// Longest export spin (µs).
pub const MAX_SPIN_US: u64 = 1000;

/// The whole configuration.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BridgeConfig {
    /// This bridge's host name on Zenoh (default: the machine's host name).
    pub host: Option<String>,
    /// Heartbeat period (ms); default [`DEFAULT_HEARTBEAT_MS`].
    pub heartbeat_ms: Option<u64>,
    /// How to reach the other hosts.
    #[serde(default)]
    pub zenoh: ZenohConfig,
    /// What this host exports.
    pub export: Option<ExportConfig>,
    /// What this host imports.
    #[serde(default)]
    pub import: Vec<ImportConfig>,
    /// CPUs the whole bridge process runs on (every thread, Zenoh's included). Default: any CPU
    /// it may use except those the manifest pins executors to (`[subsystems.*] cpu`), unless
    /// that leaves none. See [`crate::cpus`].
    pub cpus: Option<Vec<usize>>,
    /// CPUs the manifest's executors are pinned to (read by [`Self::from_manifest`]): kept free
    /// when `cpus` is not given.
    #[serde(skip)]
    pub executor_cpus: Vec<usize>,
}

/// The Zenoh side.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZenohConfig {
    /// `peer` (default) or `client`.
    pub mode: Option<String>,
    /// Endpoints to listen on (`tcp/<addr>:<port>`, `tls/<addr>:<port>`).
    #[serde(default)]
    pub listen: Vec<String>,
    /// Endpoints to connect to.
    #[serde(default)]
    pub connect: Vec<String>,
    /// Multicast scouting (default off: only explicit endpoints).
    pub multicast_scouting: Option<bool>,
    /// Zenoh lease (ms), default [`DEFAULT_LEASE_MS`].
    pub lease_ms: Option<u64>,
    /// A Zenoh JSON5 configuration file applied first (TLS certificates, access control).
    pub config_file: Option<PathBuf>,
}

/// What leaves this host.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExportConfig {
    /// Globs over `subsystem/state` (or bare state names).
    pub states: Vec<String>,
    /// Highest export rate per state (Hz); default: every sample, at the tick rate.
    pub rate_hz: Option<f64>,
    /// Exported states that accept remote commands (globs); default none.
    #[serde(default)]
    pub commands: Vec<String>,
    /// Domain name used in the key expressions (default: the local domain's).
    pub domain: Option<String>,
    /// Busy-wait of the export thread before each expected tick (µs, at most [`MAX_SPIN_US`];
    /// 0, the default, turns it off): a tick that arrives while it spins leaves without a
    /// thread wake-up, and the thread yields after each put so Zenoh's TX thread sends at once
    /// (≈ 4–25 µs less latency at p50 on a VM), for up to `spin_us` × tick rate of a CPU. See
    /// the crate README.
    #[serde(default = "default_spin_us")]
    pub spin_us: u64,
}

fn default_spin_us() -> u64 {
    DEFAULT_SPIN_US
}

/// What comes in.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImportConfig {
    /// The remote domain (as exported).
    pub domain: String,
    /// Globs over `subsystem/state` (default all).
    #[serde(default = "all")]
    pub states: Vec<String>,
    /// Mirror subsystem = prefix + subsystem.
    #[serde(default)]
    pub prefix: String,
}

fn all() -> Vec<String> {
    vec!["*".into()]
}

/// A glob over `subsystem/state`, or over the state name when it has no `/`.
#[derive(Debug, Clone)]
pub struct Selector {
    pattern: Pattern,
    qualified: bool,
}

const OPTIONS: MatchOptions = MatchOptions {
    case_sensitive: true,
    require_literal_separator: true,
    require_literal_leading_dot: false,
};

impl Selector {
    /// Parses a glob.
    pub fn new(text: &str) -> Result<Self> {
        let pattern = Pattern::new(text)
            .map_err(|e| BridgeError::Config(format!("bad state pattern {text:?}: {}", e.msg)))?;
        Ok(Self {
            pattern,
            qualified: text.contains('/'),
        })
    }

    /// Parses several globs.
    pub fn many(texts: &[String]) -> Result<Vec<Self>> {
        texts.iter().map(|t| Self::new(t)).collect()
    }

    /// Whether `subsystem/state` is selected.
    pub fn matches(&self, subsystem: &str, state: &str) -> bool {
        if self.qualified {
            self.pattern
                .matches_with(&format!("{subsystem}/{state}"), OPTIONS)
        } else {
            self.pattern.matches_with(state, OPTIONS)
        }
    }
}

/// Whether any selector selects `subsystem/state`.
pub fn any_matches(sels: &[Selector], subsystem: &str, state: &str) -> bool {
    sels.iter().any(|s| s.matches(subsystem, state))
}

impl BridgeConfig {
    /// Parses a `bridge.toml`.
    pub fn from_toml(text: &str) -> Result<Self> {
        let c: Self = toml::from_str(text).map_err(|e| BridgeError::Config(e.to_string()))?;
        c.check()?;
        Ok(c)
    }

    /// Reads the `[bridge]` table of a robot manifest (`None` when it has none).
    pub fn from_manifest(text: &str) -> Result<Option<Self>> {
        #[derive(Deserialize)]
        struct Doc {
            bridge: Option<BridgeConfig>,
        }
        // Everything else in the manifest is the executors' business (and validated there).
        let doc: toml::Table =
            toml::from_str(text).map_err(|e| BridgeError::Config(e.to_string()))?;
        let Some(b) = doc.get("bridge") else {
            return Ok(None);
        };
        let c: Doc = toml::Table::from_iter([("bridge".to_string(), b.clone())])
            .try_into()
            .map_err(|e: toml::de::Error| BridgeError::Config(format!("[bridge]: {e}")))?;
        let mut c = c.bridge.expect("present");
        // Only the executors' `cpu`s: the rest of each subsystem is validated by its executor.
        if let Some(subs) = doc.get("subsystems").and_then(toml::Value::as_table) {
            for s in subs.values() {
                if let Some(cpu) = s.get("cpu").and_then(toml::Value::as_integer) {
                    if let Ok(cpu) = usize::try_from(cpu) {
                        if !c.executor_cpus.contains(&cpu) {
                            c.executor_cpus.push(cpu);
                        }
                    }
                }
            }
            c.executor_cpus.sort_unstable();
        }
        c.check()?;
        Ok(Some(c))
    }

    /// Checks what serde cannot.
    pub fn check(&self) -> Result<()> {
        let bad = |m: String| Err(BridgeError::Config(m));
        if let Some(h) = &self.host {
            if !valid_host(h) {
                return bad(format!(
                    "host {h:?}: expected 1-64 of [A-Za-z0-9_.-], not starting with '.' or '-'"
                ));
            }
        }
        if self.heartbeat_ms == Some(0) {
            return bad("heartbeat_ms must be at least 1".into());
        }
        if self.cpus.as_ref().is_some_and(Vec::is_empty) {
            return bad("cpus = []: give at least one CPU, or leave cpus out".into());
        }
        if let Some(m) = &self.zenoh.mode {
            if m != "peer" && m != "client" {
                return bad(format!(
                    "zenoh.mode {m:?}: expected \"peer\" or \"client\" (run zenohd for a router)"
                ));
            }
        }
        if let Some(e) = &self.export {
            Selector::many(&e.states)?;
            Selector::many(&e.commands)?;
            if let Some(r) = e.rate_hz {
                if !(r.is_finite() && r > 0.0) {
                    return bad(format!("export.rate_hz {r}: expected a positive rate"));
                }
            }
            if e.spin_us > MAX_SPIN_US {
                return bad(format!(
                    "export.spin_us {}: at most {MAX_SPIN_US} µs",
                    e.spin_us
                ));
            }
            if let Some(d) = &e.domain {
                conductor_bus::Domain::new(d).map_err(|e| BridgeError::Config(e.to_string()))?;
            }
        }
        for i in &self.import {
            conductor_bus::Domain::new(&i.domain)
                .map_err(|e| BridgeError::Config(e.to_string()))?;
            Selector::many(&i.states)?;
            if !i.prefix.is_empty() {
                conductor_bus::naming::validate("subsystem", &format!("{}x", i.prefix))
                    .map_err(|e| BridgeError::Config(format!("import prefix: {e}")))?;
            }
        }
        if self.export.is_none() && self.import.is_empty() {
            return Err(BridgeError::NothingToDo);
        }
        Ok(())
    }

    /// The heartbeat period (ms).
    pub fn heartbeat_ms(&self) -> u64 {
        self.heartbeat_ms.unwrap_or(DEFAULT_HEARTBEAT_MS)
    }

    /// The host name: configured, else the machine's (cleaned up to a valid name).
    pub fn host(&self) -> String {
        if let Some(h) = &self.host {
            return h.clone();
        }
        let raw = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
        let mut h: String = raw
            .trim()
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '-') {
                    c
                } else {
                    '_'
                }
            })
            .take(crate::wire::MAX_HOST)
            .collect();
        if !valid_host(&h) {
            h = "host".into();
        }
        h
    }

    /// The Zenoh configuration.
    pub fn zenoh_config(&self) -> Result<zenoh::Config> {
        let z = &self.zenoh;
        let mut c = match &z.config_file {
            Some(p) => zenoh::Config::from_file(p).map_err(|e| {
                BridgeError::Config(format!("zenoh config file {}: {e}", p.display()))
            })?,
            None => zenoh::Config::default(),
        };
        let set = |c: &mut zenoh::Config, k: &str, v: String| {
            c.insert_json5(k, &v)
                .map_err(|e| BridgeError::Config(format!("zenoh {k} = {v}: {e}")))
        };
        let defaults = z.config_file.is_none();
        if z.mode.is_some() || defaults {
            let mode = z.mode.as_deref().unwrap_or("peer");
            set(&mut c, "mode", format!("{mode:?}"))?;
        }
        let list = |v: &[String]| serde_json::to_string(v).expect("strings serialise");
        if !z.listen.is_empty() {
            set(&mut c, "listen/endpoints", list(&z.listen))?;
        }
        if !z.connect.is_empty() {
            set(&mut c, "connect/endpoints", list(&z.connect))?;
        }
        if z.multicast_scouting.is_some() || defaults {
            let on = z.multicast_scouting.unwrap_or(false);
            set(&mut c, "scouting/multicast/enabled", on.to_string())?;
        }
        if z.lease_ms.is_some() || defaults {
            let lease = z.lease_ms.unwrap_or(DEFAULT_LEASE_MS);
            set(&mut c, "transport/link/tx/lease", lease.to_string())?;
        }
        if defaults {
            // Redial a lost peer quickly: a link back after a cut carries states again within
            // a second.
            set(
                &mut c,
                "connect/retry",
                "{period_init_ms: 100, period_max_ms: 500, period_increase_factor: 2}".into(),
            )?;
        }
        Ok(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_file_parses() {
        let c = BridgeConfig::from_toml(
            r#"
host = "robot"
[zenoh]
listen = ["tcp/127.0.0.1:7447"]
[export]
states = ["leg/*"]
commands = ["leg/knee"]
[[import]]
domain = "ws"
"#,
        )
        .unwrap();
        assert_eq!(c.host(), "robot");
        assert_eq!(c.heartbeat_ms(), DEFAULT_HEARTBEAT_MS);
        assert_eq!(c.import[0].states, vec!["*".to_string()]);
        let z = c.zenoh_config().unwrap();
        assert_eq!(z.get_json("scouting/multicast/enabled").unwrap(), "false");
    }

    #[test]
    fn mistakes_are_named() {
        for (text, says) in [
            ("host = \"a/b\"\n[export]\nstates=[\"*\"]", "host"),
            ("[export]\nstates=[\"*\"]\nrate_hz = -1", "rate_hz"),
            (
                "[zenoh]\nmode = \"router\"\n[export]\nstates=[\"*\"]",
                "zenohd",
            ),
            ("heartbeat_ms = 50", "nothing to do"),
            ("[export]\nstate=[\"*\"]", "unknown field"),
            ("[export]\nstates=[\"*\"]\nspin_us = 5000", "spin_us"),
        ] {
            let e = BridgeConfig::from_toml(text).unwrap_err().to_string();
            assert!(e.contains(says), "{text:?} -> {e}");
        }
    }

    #[test]
    fn the_two_host_example_parses() {
        let ws = BridgeConfig::from_toml(include_str!("../../../deploy/two-host/workstation.toml"))
            .unwrap();
        assert_eq!(ws.import[0].domain, "robot");
        let robot =
            BridgeConfig::from_manifest(include_str!("../../../deploy/two-host/robot.toml"))
                .unwrap()
                .unwrap();
        assert_eq!(
            robot.export.as_ref().unwrap().commands,
            vec!["leg/knee".to_string()]
        );
        robot.zenoh_config().unwrap();
    }

    #[test]
    fn the_manifest_table_is_read_alone() {
        let m = r#"
system = "x"
[subsystems.leg]
rate_hz = 100
[bridge.export]
states = ["leg/*"]
"#;
        let c = BridgeConfig::from_manifest(m).unwrap().unwrap();
        assert_eq!(c.export.unwrap().states, vec!["leg/*".to_string()]);
        assert_eq!(BridgeConfig::from_manifest("system = \"x\"").unwrap(), None);
    }

    #[test]
    fn a_manifests_bridge_keeps_off_its_executors_cpus_unless_told_where_to_run() {
        let m = r#"
system = "x"
[subsystems.leg]
rate_hz = 100
cpu = 1
[subsystems.arm]
rate_hz = 100
cpu = 0
[subsystems.head]
rate_hz = 10
[bridge.export]
states = ["leg/*"]
"#;
        let c = BridgeConfig::from_manifest(m).unwrap().unwrap();
        assert_eq!(c.executor_cpus, vec![0, 1]);
        assert_eq!(c.cpus, None);
        let told = m.replace("[bridge.export]", "[bridge]\ncpus = [3]\n[bridge.export]");
        let c = BridgeConfig::from_manifest(&told).unwrap().unwrap();
        assert_eq!(c.cpus, Some(vec![3]));
        // A bridge.toml has no executors.
        let c = BridgeConfig::from_toml("cpus = [2]\n[export]\nstates = [\"*\"]").unwrap();
        assert_eq!((c.cpus, c.executor_cpus), (Some(vec![2]), vec![]));
        let e = BridgeConfig::from_toml("cpus = []\n[export]\nstates = [\"*\"]").unwrap_err();
        assert!(e.to_string().contains("cpus = []"), "{e}");
    }
}
