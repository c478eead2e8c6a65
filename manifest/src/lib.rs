//! The manifest: a TOML description of a robot (system → subsystems → hardware, protocols,
//! devices, states; gateways, boards put on the bus by their own process; and the live view in
//! Foxglove), validated in full before anything runs.
//!
//! [`Manifest::load`] either returns a consistent model, in which every link is resolved to an
//! index, every rate to a divisor of its subsystem's base rate and every kind's parameters to
//! typed values, or a [`ManifestError::Invalid`] listing **every** problem with file, line,
//! column, key and what was expected. The reference for every key is `docs/manifest.md`.
//!
//! The launcher and the executors (`conductor-executor`), the Score gateway and the `conductor`
//! CLI share these typed values; nothing downstream parses the TOML again.
pub mod busload;
mod diag;
pub mod gateway;
mod reader;
pub mod reference;
mod validate;

use std::path::{Path, PathBuf};

use conductor_devices::kinds::{KindSpec, Params, KINDS};
use conductor_devices::{Channel, Credential, Startup};

pub use diag::{Diagnostic, Severity};
pub use gateway::{GatewayOptions, ScoreGatewayArgs};

/// Keys a hardware table accepts besides its kind's parameters.
pub const HARDWARE_KEYS: &[&str] = &["kind", "rate_hz"];
/// Keys a protocol table accepts besides its kind's parameters.
pub const PROTOCOL_KEYS: &[&str] = &["kind", "hardware", "rate_hz"];
/// Keys a device table accepts besides its kind's parameters.
pub const DEVICE_KEYS: &[&str] = &[
    "kind",
    "protocol",
    "rate_hz",
    "id",
    "sub",
    "scale",
    "offset",
    "direction",
    "safe_action",
    "safe_value",
    "safe_state",
    "startup",
    "optional",
];
/// Keys of a state table.
pub const STATE_KEYS: &[&str] = &[
    "device",
    "channel",
    "rate_hz",
    "units",
    "writable",
    "min",
    "max",
    "history",
    "scale",
    "offset",
    "direction",
];
/// Keys of a subsystem table.
pub const SUBSYSTEM_KEYS: &[&str] = &[
    "rate_hz",
    "cpu",
    "priority",
    "require_rt",
    "spin_us",
    "watchdog_ms",
    "hardware",
    "protocols",
    "devices",
    "states",
];
/// Keys of a gateway table.
pub const GATEWAY_KEYS: &[&str] = &[
    "kind",
    "port",
    "max_rate_hz",
    "lazy_rate_hz",
    "restore",
    "retry_ms",
    "watchdog_ms",
    "priority",
];
/// Keys of the `[view]` table.
pub const VIEW_KEYS: &[&str] = &["listen", "clamp"];
/// Keys of the `[bridge]` table (its contents are checked by `conductor bridge` itself, which
/// the launcher runs with the manifest).
pub const BRIDGE_KEYS: &[&str] = &["host", "heartbeat_ms", "cpus", "zenoh", "export", "import"];
/// Top-level keys.
pub const TOP_KEYS: &[&str] = &[
    "system",
    "domain",
    "subsystems",
    "gateways",
    "view",
    "bridge",
];

/// Highest base rate a subsystem may ask for (Hz).
pub const MAX_RATE_HZ: f64 = 100_000.0;
/// Default SCHED_FIFO priority.
pub const DEFAULT_PRIORITY: i32 = 80;
/// Default history (the per-subscriber queue a client may ask for), in samples.
pub const DEFAULT_HISTORY: usize = 256;
/// Largest history.
pub const MAX_HISTORY: usize = 65_536;

/// Why a manifest cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    /// The file could not be read.
    #[error("cannot read manifest {path}: {source}")]
    Io {
        /// The path given.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The manifest is not valid; every problem is listed.
    #[error("{}", render(.diagnostics))]
    Invalid {
        /// Every problem found, in document order: at least one error, and any warnings.
        diagnostics: Vec<Diagnostic>,
    },
}

fn render(diagnostics: &[Diagnostic]) -> String {
    let mut s = String::new();
    for d in diagnostics {
        s.push_str(&d.to_string());
        s.push('\n');
    }
    let plural = |n: usize| if n == 1 { "" } else { "s" };
    let warnings = diagnostics
        .iter()
        .filter(|d| d.severity == Severity::Warning)
        .count();
    let errors = diagnostics.len() - warnings;
    s.push_str(&format!("{errors} error{} ", plural(errors)));
    if warnings > 0 {
        s.push_str(&format!("and {warnings} warning{} ", plural(warnings)));
    }
    s.push_str("in the manifest");
    s
}

/// A validated manifest.
#[derive(Debug, Clone)]
pub struct Manifest {
    /// Where it was read from.
    pub path: PathBuf,
    /// The robot's name.
    pub system: String,
    /// The bus domain the manifest asks for, if any.
    pub domain: Option<String>,
    /// Subsystems in document order; each runs as one executor process.
    pub subsystems: Vec<Subsystem>,
    /// Gateways in document order; each runs as one gateway process.
    pub gateways: Vec<GatewayDef>,
    /// The live view (`[view]`), run as one more supervised process when present.
    pub view: Option<ViewDef>,
    /// The `[bridge]` table, if any: `conductor launch` runs `conductor bridge --manifest` on it.
    pub bridge: Option<BridgeDef>,
    /// What validation found doubtful but not wrong (a bus loaded above 80 %, an actuator
    /// nothing can command, ...), in document order; see [`Manifest::render_warnings`].
    pub warnings: Vec<Diagnostic>,
}

/// What program a gateway runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GatewayKind {
    /// `score-gateway`: a Score board (score/firmware) on its binary USB link.
    Score,
    /// `conductor bridge` for the manifest's `[bridge]` table (not a `[gateways]` kind: the
    /// launcher supervises the bridge as it does a gateway; its `port` is the manifest).
    Bridge,
}

impl GatewayKind {
    /// Every kind, as written in a manifest.
    pub const ALL: &'static [GatewayKind] = &[GatewayKind::Score];

    /// The manifest's name of the kind.
    pub fn name(self) -> &'static str {
        match self {
            GatewayKind::Score => "score",
            GatewayKind::Bridge => "bridge",
        }
    }

    /// The kind written `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|k| k.name() == name)
    }
}

/// A gateway: a process that puts a board on the bus as the states of subsystem `name`. The
/// launcher starts and supervises it like an executor, but does not wait for it to be ready
/// (its board may be unplugged).
#[derive(Debug, Clone, PartialEq)]
pub struct GatewayDef {
    /// The subsystem it publishes (unique among subsystems and gateways).
    pub name: String,
    /// Which gateway program.
    pub kind: GatewayKind,
    /// The board's link device (an exclusive resource, like a serial hardware's port).
    pub port: PathBuf,
    /// What the gateway is tuned with (`max_rate_hz`, `lazy_rate_hz`, `restore`, `retry_ms`,
    /// `watchdog_ms`), as its program takes them.
    pub options: GatewayOptions,
}

/// The live view in Foxglove (`[view]`): `conductor view` on the manifest's domain, which the
/// launcher starts and supervises like a gateway (it does not wait for it).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ViewDef {
    /// Address and port of its WebSocket server (default `127.0.0.1:8765`: loopback only).
    pub listen: std::net::SocketAddr,
    /// Send the nearest limit for a setpoint outside a state's limits instead of refusing it.
    pub clamp: bool,
}

impl Default for ViewDef {
    fn default() -> Self {
        Self {
            listen: std::net::SocketAddr::from(([127, 0, 0, 1], 8765)),
            clamp: false,
        }
    }
}
/// A manifest's `[bridge]` table: the launcher starts and supervises one `conductor bridge`
/// process for it (like a gateway: not waited for, given up when it cannot run). The bridge reads
/// and checks the table's contents itself.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BridgeDef {
    /// Line of the `[bridge]` table (1-based), for messages.
    pub line: usize,
}

/// Name under which the launcher reports the bridge process.
pub const BRIDGE_NAME: &str = "bridge";

/// One executor: a base tick and the components it schedules.
#[derive(Debug, Clone)]
pub struct Subsystem {
    /// Name (also the service prefix `conductor/<name>/`).
    pub name: String,
    /// Base tick rate (Hz).
    pub rate_hz: f64,
    /// Base tick period (ns), rounded to the nearest nanosecond.
    pub period_ns: u64,
    /// CPU to pin the real-time thread to.
    pub cpu: Option<usize>,
    /// SCHED_FIFO priority (1–99).
    pub priority: i32,
    /// Refuse to run without real-time scheduling and locked memory.
    pub require_rt: bool,
    /// Busy-wait this long before each deadline instead of sleeping (ns; 0 = sleep only).
    pub spin_ns: u64,
    /// Command watchdog: no frame for this long → every writable device's safe action (ns).
    pub watchdog_ns: Option<u64>,
    /// Transports.
    pub hardware: Vec<HardwareDef>,
    /// Packet formats, each bound to one hardware.
    pub protocols: Vec<ProtocolDef>,
    /// Bus nodes.
    pub devices: Vec<DeviceDef>,
    /// Published quantities; a state's position here is its bus index.
    pub states: Vec<StateDef>,
}

/// A hardware component.
#[derive(Debug, Clone)]
pub struct HardwareDef {
    /// Name within the subsystem.
    pub name: String,
    /// Kind (see `conductor_devices::kinds`).
    pub kind: String,
    /// Ticks every `divisor` base ticks.
    pub divisor: u32,
    /// The kind's parameters, defaults filled in.
    pub params: Params,
    /// Whether this is built-in simulated hardware (states get the SIMULATED flag).
    pub simulated: bool,
}

/// A protocol component.
#[derive(Debug, Clone)]
pub struct ProtocolDef {
    /// Name within the subsystem.
    pub name: String,
    /// Kind.
    pub kind: String,
    /// Index into [`Subsystem::hardware`].
    pub hardware: usize,
    /// Ticks every `divisor` base ticks.
    pub divisor: u32,
    /// The kind's parameters.
    pub params: Params,
}

/// Linear map between device units and state units:
/// `state = direction · scale · (device − offset)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// Gain (non-zero).
    pub scale: f64,
    /// Device-unit value that reads as 0 in state units.
    pub offset: f64,
    /// +1 or −1.
    pub direction: f64,
}

impl Default for Calibration {
    fn default() -> Self {
        Self {
            scale: 1.0,
            offset: 0.0,
            direction: 1.0,
        }
    }
}

impl Calibration {
    /// Device units → state units.
    #[inline]
    pub fn to_state(&self, device: f64) -> f64 {
        self.direction * self.scale * (device - self.offset)
    }

    /// State units → device units.
    #[inline]
    pub fn to_device(&self, state: f64) -> f64 {
        state / (self.direction * self.scale) + self.offset
    }
}

/// What a device does when the command watchdog fires or the executor stops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SafeSpec {
    /// Keep the present position.
    Hold,
    /// Disable the actuator.
    TorqueOff,
    /// Let the joint move, braked: zero stiffness, velocity gain `kd` (MIT motors; `None`: the
    /// device's own kd).
    Damp {
        /// Velocity gain (N·m·s/rad).
        kd: Option<f64>,
    },
    /// Command `value` (state units) on `state` (index into [`Subsystem::states`]).
    Setpoint {
        /// The state whose channel and calibration carry the setpoint.
        state: usize,
        /// Value in that state's units.
        value: f64,
    },
}

/// A device component.
#[derive(Debug, Clone)]
pub struct DeviceDef {
    /// Name within the subsystem.
    pub name: String,
    /// Kind.
    pub kind: String,
    /// Index into [`Subsystem::protocols`].
    pub protocol: usize,
    /// Ticks every `divisor` base ticks.
    pub divisor: u32,
    /// Bus address.
    pub credential: Credential,
    /// Default calibration of its states.
    pub calibration: Calibration,
    /// Safe action.
    pub safe: SafeSpec,
    /// The kind's parameters.
    pub params: Params,
    /// The channels the device offers (read from a device built during validation).
    pub channels: Vec<Channel>,
    /// What it does once brought up: enable from where it is, or stay limp until commanded.
    pub startup: Startup,
    /// A device that does not answer at start is a warning and STALE states, not an error.
    pub optional: bool,
}

/// A state component.
#[derive(Debug, Clone)]
pub struct StateDef {
    /// Name within the subsystem (service `conductor/<subsystem>/<name>`).
    pub name: String,
    /// Index into [`Subsystem::devices`].
    pub device: usize,
    /// Channel index within the device.
    pub channel: usize,
    /// Publishes every `divisor` base ticks.
    pub divisor: u32,
    /// Units after calibration.
    pub units: String,
    /// Accepts setpoints.
    pub writable: bool,
    /// Lower setpoint limit (state units).
    pub min: f64,
    /// Upper setpoint limit.
    pub max: f64,
    /// Samples a client may keep queued (the service's subscriber buffer).
    pub history: usize,
    /// Device ↔ state units.
    pub calibration: Calibration,
    /// Whether the channel can be sampled.
    pub readable: bool,
}

impl Subsystem {
    /// Rate (Hz) of something ticking every `divisor` base ticks.
    pub fn rate_of(&self, divisor: u32) -> f64 {
        self.rate_hz / f64::from(divisor)
    }

    /// Whether a state's values come from built-in simulated hardware.
    pub fn state_is_simulated(&self, state: usize) -> bool {
        let dev = &self.devices[self.states[state].device];
        let proto = &self.protocols[dev.protocol];
        self.hardware[proto.hardware].simulated
    }
}

impl Manifest {
    /// Reads and validates the manifest at `path`.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ManifestError> {
        let path = path.as_ref();
        let source = std::fs::read_to_string(path).map_err(|source| ManifestError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&source, path)
    }

    /// Validates manifest text; `path` is used in messages and kept in the model.
    pub fn parse(source: &str, path: impl AsRef<Path>) -> Result<Self, ManifestError> {
        Self::parse_with_kinds(source, path, KINDS)
    }

    /// Validates against a given kind table (tests use it to add kinds the build lacks).
    pub fn parse_with_kinds(
        source: &str,
        path: impl AsRef<Path>,
        kinds: &[KindSpec],
    ) -> Result<Self, ManifestError> {
        let path = path.as_ref();
        validate::validate(source, path, kinds)
    }

    /// The warnings, one per line as `file:line:column: warning: key: message`, and a count;
    /// empty when there are none.
    pub fn render_warnings(&self) -> String {
        let mut s = String::new();
        for w in &self.warnings {
            s.push_str(&w.to_string());
            s.push('\n');
        }
        let n = self.warnings.len();
        if n > 0 {
            s.push_str(&format!(
                "{n} warning{} in the manifest (it is valid)",
                if n == 1 { "" } else { "s" }
            ));
        }
        s
    }

    /// The subsystem called `name`.
    pub fn subsystem(&self, name: &str) -> Option<&Subsystem> {
        self.subsystems.iter().find(|s| s.name == name)
    }

    /// The gateway called `name`.
    pub fn gateway(&self, name: &str) -> Option<&GatewayDef> {
        self.gateways.iter().find(|g| g.name == name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use conductor_devices::kinds::Role;

    #[test]
    fn calibration_round_trips() {
        let c = Calibration {
            scale: 2.0,
            offset: 2.61,
            direction: -1.0,
        };
        assert_eq!(c.to_state(2.61), 0.0);
        assert_eq!(c.to_state(3.61), -2.0);
        for v in [-1.5, 0.0, 0.25, 3.0] {
            assert!((c.to_state(c.to_device(v)) - v).abs() < 1e-12);
        }
    }

    /// Kind parameters share a table with the stage's own keys: a kind may not shadow them.
    #[test]
    fn no_kind_parameter_shadows_a_stage_key() {
        for k in KINDS {
            let reserved = match k.role() {
                Role::Hardware => HARDWARE_KEYS,
                Role::Protocol => PROTOCOL_KEYS,
                Role::Device => DEVICE_KEYS,
            };
            for p in k.params {
                assert!(
                    !reserved.contains(&p.name),
                    "kind {:?} parameter {:?} collides with a manifest key",
                    k.kind,
                    p.name
                );
            }
        }
    }
}
