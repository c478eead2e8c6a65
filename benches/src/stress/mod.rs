//! The thesis' stress test (§3.1): states whose simulated hardware answers every sample request
//! with sin(t_S), t_S the request time, sampled at a given rate, and an external logger that
//! compares what it reads with sin(t_L) at the time it reads it.
//!
//! * [`manifest`] writes the executor side (optionally with a command probe state, below).
//! * [`Logger`] is the external side (run it in another process: `conductor-stress log`).
//! * [`CommandProbe`] is an external controller: it sends setpoints to a loopback state and
//!   measures command → hardware write from the samples that first reflect them.
//! * [`run`] launches the manifest, runs the logger and the probe as separate processes and
//!   gathers the executor's tick lateness, misses and CPU use over the logged window.
//! * [`tool`] is the command line of all three (`conductor-stress`, and `conductor bench`'s
//!   helper processes).

mod logger;
mod probe;
mod run;
#[cfg(feature = "cli")]
pub mod tool;

pub use logger::{parse_line, Logger, StateReport, Summary};
pub use probe::{CommandProbe, ProbeReport};
pub use run::{process_cpu_ns, run, RunError, RunOptions, RunResult};

/// Parameters of a stress manifest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StressConfig {
    /// Base and sample rate (Hz).
    pub rate_hz: f64,
    /// CPU to pin the executor to.
    pub cpu: Option<usize>,
    /// SCHED_FIFO priority.
    pub priority: i32,
    /// Spin before each deadline (µs; 0 = sleep only).
    pub spin_us: f64,
    /// Number of sine states (the thesis used 3).
    pub states: usize,
    /// Add the writable [`PROBE_STATE`] on a loopback hardware, for [`CommandProbe`] (on the
    /// first executor).
    pub probe: bool,
    /// Executors on the host: subsystems of `states` sine states each, every one its own
    /// process, all pinned to `cpu` (the scaling curves' executors per host).
    pub executors: usize,
    /// Subscribers per sine state, each in a process of its own woken by the tick events: 0 runs
    /// no logger (no latency then), 1 the logger, n the logger and n − 1 more readers.
    pub subscribers: usize,
    /// Each state's history and the subscribers' buffer (samples): a reader that falls this
    /// far behind loses samples, and the service's shared memory grows with it (× up to
    /// [`conductor_bus::qos::STATE_SUBSCRIBERS`] subscribers × states).
    pub history: usize,
    /// The readers take each subsystem's snapshot (one sample per tick, all states, woken by
    /// the snapshot event) instead of subscribing to every state.
    pub snapshot: bool,
}

impl Default for StressConfig {
    fn default() -> Self {
        Self {
            rate_hz: 1000.0,
            cpu: None,
            priority: 80,
            spin_us: 0.0,
            states: 3,
            probe: false,
            executors: 1,
            subscribers: 1,
            history: 4096,
            snapshot: false,
        }
    }
}

/// The subsystem name of the stress manifest (its first executor).
pub const SUBSYSTEM: &str = "stress";

/// The subsystem of executor `i` (0-based): [`SUBSYSTEM`], then `stress1`, `stress2`, ...
pub fn subsystem(i: usize) -> String {
    if i == 0 {
        SUBSYSTEM.to_string()
    } else {
        format!("{SUBSYSTEM}{i}")
    }
}

/// The subsystems of `cfg`, one per executor.
pub fn subsystems(cfg: &StressConfig) -> Vec<String> {
    (0..cfg.executors.max(1)).map(subsystem).collect()
}

/// The command probe's state (with [`StressConfig::probe`]): writable, on a `loopback` hardware
/// that answers each sample with the last setpoint written to it.
pub const PROBE_STATE: &str = "cmd";

/// The names (`subsystem/state`) of the sine states of `cfg`, executor by executor.
pub fn sine_states(cfg: &StressConfig) -> Vec<String> {
    subsystems(cfg)
        .iter()
        .flat_map(|sub| (0..cfg.states).map(move |i| format!("{sub}/s{i}")))
        .collect()
}

/// The manifest of `cfg`: per executor a subsystem of `states` states `s0..` at `rate_hz`, each
/// on its own device of a `sine` hardware answering sin(t_S) (amplitude 1, 1/2π Hz); with
/// `probe`, also the writable state [`PROBE_STATE`] on a `loopback` hardware of its own in the
/// first subsystem.
pub fn manifest(cfg: &StressConfig) -> String {
    let mut m = format!(
        "# The thesis' stress test: {e} executor(s) of {n} sine states at {r} Hz.\n\
         system = \"stress\"\n",
        e = cfg.executors.max(1),
        n = cfg.states,
        r = cfg.rate_hz,
    );
    for sub in subsystems(cfg) {
        m += &format!(
            "\n[subsystems.{sub}]\nrate_hz = {r}\npriority = {p}\nspin_us = {s}\n",
            r = cfg.rate_hz,
            p = cfg.priority,
            s = cfg.spin_us
        );
        if let Some(cpu) = cfg.cpu {
            m += &format!("cpu = {cpu}\n");
        }
        m += &format!(
            "\n[subsystems.{sub}.hardware.sine]\nkind = \"sine\"\n\n\
             [subsystems.{sub}.protocols.sim]\nkind = \"sim\"\nhardware = \"sine\"\n"
        );
        for i in 0..cfg.states {
            m += &format!(
                "\n[subsystems.{sub}.devices.d{i}]\nkind = \"sim\"\nprotocol = \"sim\"\nid = {i}\n\n\
                 [subsystems.{sub}.states.s{i}]\ndevice = \"d{i}\"\nhistory = {h}\n",
                h = cfg.history.max(1)
            );
        }
    }
    if cfg.probe {
        m += &format!(
            "\n# The command probe: setpoints come back in the next sample.\n\
             [subsystems.{SUBSYSTEM}.hardware.probe_hw]\nkind = \"loopback\"\n\n\
             [subsystems.{SUBSYSTEM}.protocols.probe_link]\nkind = \"sim\"\nhardware = \"probe_hw\"\n\n\
             [subsystems.{SUBSYSTEM}.devices.probe_dev]\nkind = \"sim\"\nprotocol = \"probe_link\"\nid = 0\n\n\
             [subsystems.{SUBSYSTEM}.states.{PROBE_STATE}]\ndevice = \"probe_dev\"\nwritable = true\n\
             history = {h}\n",
            h = cfg.history.max(1)
        );
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use conductor_manifest::Manifest;

    #[test]
    fn stress_manifests_validate() {
        for rate in [50.0, 1000.0, 10_000.0] {
            let text = manifest(&StressConfig {
                rate_hz: rate,
                cpu: Some(1),
                ..Default::default()
            });
            let m = Manifest::parse(&text, "stress.toml").unwrap_or_else(|e| panic!("{e}"));
            let s = &m.subsystems[0];
            assert_eq!((s.rate_hz, s.states.len(), s.cpu), (rate, 3, Some(1)));
        }
    }

    #[test]
    fn the_probe_adds_one_writable_state_on_its_own_link() {
        let text = manifest(&StressConfig {
            states: 41,
            probe: true,
            ..Default::default()
        });
        let m = Manifest::parse(&text, "stress.toml").unwrap_or_else(|e| panic!("{e}"));
        let s = &m.subsystems[0];
        assert_eq!(s.states.len(), 42);
        let probe = s.states.iter().find(|st| st.name == PROBE_STATE).unwrap();
        assert!(probe.writable);
        assert_eq!(s.states.iter().filter(|st| st.writable).count(), 1);
        assert_eq!(
            sine_states(&StressConfig::default()),
            ["stress/s0", "stress/s1", "stress/s2"]
        );
    }

    #[test]
    fn each_executor_is_a_subsystem_of_its_own_on_the_same_cpu() {
        let cfg = StressConfig {
            states: 2,
            executors: 3,
            cpu: Some(1),
            history: 64,
            ..Default::default()
        };
        let m = Manifest::parse(&manifest(&cfg), "stress.toml").unwrap_or_else(|e| panic!("{e}"));
        let names: Vec<&str> = m.subsystems.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["stress", "stress1", "stress2"]);
        for s in &m.subsystems {
            assert_eq!((s.states.len(), s.cpu), (2, Some(1)));
            assert!(s.states.iter().all(|st| st.history == 64));
        }
        assert_eq!(
            sine_states(&cfg),
            [
                "stress/s0",
                "stress/s1",
                "stress1/s0",
                "stress1/s1",
                "stress2/s0",
                "stress2/s1"
            ]
        );
    }
}
