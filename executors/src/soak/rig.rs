//! The simulated robots of deploy/ on pseudo-terminals, with faults on every bus, and the
//! manifest that points the shipped files at them.
//!
//! * The mini-Hubo right leg (deploy/minihubo-right-leg-dxl.toml): six XM430 servos on a
//!   Dynamixel bus; bytes are corrupted and dropped in both directions on the RS-485 wire
//!   (Protocol 2.0's CRC-16 is what must catch them).
//! * The quadruped leg (deploy/quadruped-leg-mit-slcan.toml): three MIT motors behind an
//!   SLCAN adapter. Bytes are corrupted and dropped on the CAN wire, where the CAN CRC makes a
//!   damaged frame a lost frame. The adapter's own link to the host is USB, whose packets carry
//!   a CRC and are sent again when damaged: its bytes are not corrupted or lost one by one
//!   (SLCAN text has no check of its own, so such a line would let a wrong frame through when
//!   two characters of one line were lost: the campaign would report that, but it is not a
//!   fault a USB adapter has).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use conductor_devices::protocol_stage::mit_limits;
use conductor_devices::sim::can_motors::{CanNode, MitMotorSim};
use conductor_devices::sim::dxl::{DxlBusSim, DxlSimConfig};
use conductor_devices::sim::fault::{FaultConfig, FaultTotals};
use conductor_devices::sim::runner::{run_dxl, run_slcan_with_faults, Endpoint, Pty, Running};
use conductor_devices::sim::slcan_adapter::SlcanAdapterSim;
use conductor_protocols::slcan::Dialect;

/// A joint: its position state and the limits the manifest gives it.
#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    /// State name (its enable state is `<name>_enable`).
    pub name: String,
    /// Lowest setpoint.
    pub min: f64,
    /// Highest setpoint.
    pub max: f64,
}

impl Joint {
    fn new(name: &str, min: f64, max: f64) -> Self {
        Self {
            name: name.into(),
            min,
            max,
        }
    }

    /// `name:min:max`, as the controller process is told.
    pub fn to_arg(&self) -> String {
        format!("{}:{}:{}", self.name, self.min, self.max)
    }

    /// Parses [`to_arg`](Self::to_arg).
    pub fn from_arg(s: &str) -> Result<Self, String> {
        let p: Vec<&str> = s.split(':').collect();
        let num = |x: &str| x.parse::<f64>().map_err(|_| format!("bad joint {s:?}"));
        match p.as_slice() {
            [n, lo, hi] => Ok(Self::new(n, num(lo)?, num(hi)?)),
            _ => Err(format!("bad joint {s:?}: expected name:min:max")),
        }
    }
}

/// Which robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Kind {
    /// The Dynamixel leg.
    Dynamixel,
    /// The MIT-motor leg over SLCAN.
    MitSlcan,
}

/// The simulator behind a robot.
pub enum Sim {
    /// Dynamixel bus.
    Dxl(Arc<Running<DxlBusSim>>),
    /// SLCAN adapter with MIT motors.
    Slcan(Arc<Running<SlcanAdapterSim>>),
}

/// What the simulator says about its devices at one instant.
#[derive(Debug, Clone, Copy, Default)]
pub struct DeviceTruth {
    /// Position in the state's units (rad).
    pub position: f64,
    /// Dynamixel: Goal Position (rad); MIT: the last commanded position (rad).
    pub goal: f64,
    /// Torque on / in motor mode.
    pub driving: bool,
}

/// One robot of the campaign.
pub struct Robot {
    /// Which.
    pub kind: Kind,
    /// Its subsystem in the manifest.
    pub subsystem: String,
    /// Its joints.
    pub joints: Vec<Joint>,
    /// Command watchdog (ns).
    pub watchdog_ns: u64,
    /// Base tick (ns).
    pub tick_ns: u64,
    /// The simulator.
    pub sim: Sim,
    /// Smallest step of a reported position (rad): one encoder pulse or one 16-bit step.
    pub resolution: f64,
}

/// One Dynamixel pulse in radians (4096 per turn, 2048 = 0 rad).
pub const PULSE: f64 = 2.0 * std::f64::consts::PI / 4096.0;

impl Robot {
    /// The Dynamixel leg on a pty linked at `link`.
    pub fn dynamixel(link: &Path, corrupt: f64, drop: f64, seed: u64) -> std::io::Result<Self> {
        let wire = |s| FaultConfig {
            corrupt,
            drop,
            seed: s,
            ..FaultConfig::default()
        };
        let sim = run_dxl(
            Endpoint::Pty(Pty::open(Some(link))?),
            DxlSimConfig::default(),
            wire(seed),
            wire(seed ^ 0x5EED),
        );
        // Every instruction the servos take, with its time: the monitor times the holds by it.
        sim.sim().start_log();
        Ok(Self {
            kind: Kind::Dynamixel,
            subsystem: "right_leg".into(),
            joints: vec![
                Joint::new("RHY", -1.0, 1.0),
                Joint::new("RHR", -0.8, 0.8),
                Joint::new("RHP", -1.6, 1.6),
                Joint::new("RKP", 0.0, 2.4),
                Joint::new("RAP", -1.2, 1.2),
                Joint::new("RAR", -0.8, 0.8),
            ],
            watchdog_ns: 500_000_000,
            tick_ns: 4_000_000,
            sim: Sim::Dxl(Arc::new(sim)),
            resolution: PULSE,
        })
    }

    /// The MIT leg behind an SLCAN adapter on a pty linked at `link`.
    pub fn mit_slcan(link: &Path, corrupt: f64, drop: f64, seed: u64) -> std::io::Result<Self> {
        let limits = mit_limits("ak80-9").expect("a known model");
        let nodes: Vec<Box<dyn CanNode>> = (1..=3)
            .map(|id| Box::new(MitMotorSim::new(id, limits, 0, false)) as Box<dyn CanNode>)
            .collect();
        let mut adapter = SlcanAdapterSim::new(Dialect::CANABLE, nodes).with_log();
        let can = |s| FaultConfig {
            corrupt,
            drop,
            seed: s,
            ..FaultConfig::default()
        };
        adapter.set_wire_faults(can(seed ^ 0xC0), can(seed ^ 0xC1));
        let sim = run_slcan_with_faults(
            Endpoint::Pty(Pty::open(Some(link))?),
            adapter,
            FaultConfig::default(),
            FaultConfig::default(),
        );
        let p = limits.p;
        Ok(Self {
            kind: Kind::MitSlcan,
            subsystem: "front_left".into(),
            joints: vec![
                Joint::new("hip_ab", -0.6, 0.6),
                Joint::new("hip_fl", -1.5, 1.5),
                Joint::new("knee", -2.6, -0.3),
            ],
            watchdog_ns: 100_000_000,
            tick_ns: 2_000_000,
            sim: Sim::Slcan(Arc::new(sim)),
            resolution: (p.max - p.min) as f64 / 65535.0,
        })
    }

    /// What the simulator says about each joint's device now, in joint order.
    pub fn truth(&self, out: &mut Vec<DeviceTruth>) {
        out.clear();
        match &self.sim {
            Sim::Dxl(r) => {
                let s = r.sim();
                for id in 1..=self.joints.len() as u8 {
                    let v = s.servo(id).expect("servo on the bus");
                    out.push(DeviceTruth {
                        position: (v.present_position() - 2048) as f64 * PULSE,
                        goal: (v.goal_position() - 2048) as f64 * PULSE,
                        driving: v.torque_on(),
                    });
                }
            }
            Sim::Slcan(r) => {
                let s = r.sim();
                for n in s.nodes() {
                    let snap = n.snapshot();
                    out.push(DeviceTruth {
                        position: snap.position,
                        goal: f64::NAN,
                        driving: snap.enabled,
                    });
                }
            }
        }
    }

    /// Fault totals of the serial link: (host → simulator, simulator → host).
    pub fn link_faults(&self) -> (FaultTotals, FaultTotals) {
        match &self.sim {
            Sim::Dxl(r) => r.faults(),
            Sim::Slcan(r) => r.faults(),
        }
    }

    /// The longest the simulator's thread woke up late since the last call (ns): its replies
    /// left that much late.
    pub fn take_lag_ns(&self) -> u64 {
        match &self.sim {
            Sim::Dxl(r) => r.take_lag_ns(),
            Sim::Slcan(r) => r.take_lag_ns(),
        }
    }

    /// Pulls the adapter out.
    pub fn unplug(&self) {
        match &self.sim {
            Sim::Dxl(r) => r.unplug(),
            Sim::Slcan(r) => r.unplug(),
        }
    }

    /// Plugs it back in.
    pub fn replug(&self) -> std::io::Result<()> {
        match &self.sim {
            Sim::Dxl(r) => r.replug(),
            Sim::Slcan(r) => r.replug(),
        }
    }

    /// The simulator's clock (ns since it started).
    pub fn sim_now_ns(&self) -> u64 {
        match &self.sim {
            Sim::Dxl(r) => r.now_ns(),
            Sim::Slcan(r) => r.now_ns(),
        }
    }
}

/// The two shipped manifests in one, each pointed at its simulator's link: the shipped text
/// with only the ports changed (and the second file's `system`/`domain` lines left out, since
/// a manifest has one of each; the domain is the launch's).
pub fn manifest(root: &Path, dxl_link: &Path, can_link: &Path) -> std::io::Result<String> {
    let read = |name: &str| std::fs::read_to_string(root.join("deploy").join(name));
    let dxl = read("minihubo-right-leg-dxl.toml")?;
    let can = read("quadruped-leg-mit-slcan.toml")?;
    let swap = |text: &str, from: &str, to: &Path| -> std::io::Result<String> {
        if !text.contains(from) {
            return Err(std::io::Error::other(format!(
                "the shipped manifest no longer has {from:?}"
            )));
        }
        Ok(text.replace(from, &format!("port = \"{}\"", to.display())))
    };
    let dxl = swap(&dxl, "port = \"/tmp/conductor-dxl0\"", dxl_link)?;
    let can = swap(&can, "port = \"/tmp/conductor-can0\"", can_link)?;
    let keep = |l: &&str| !(l.starts_with("system =") || l.starts_with("domain ="));
    let dxl: Vec<&str> = dxl.lines().filter(keep).collect();
    let can: Vec<&str> = can.lines().filter(keep).collect();
    Ok(format!(
        "system = \"soak\"\n{}\n{}\n",
        dxl.join("\n"),
        can.join("\n")
    ))
}

/// The workspace root (deploy/ lives there): `--root`, else found from the current directory
/// or the program's location.
pub fn find_root(explicit: Option<PathBuf>) -> Option<PathBuf> {
    if let Some(r) = explicit {
        return Some(r);
    }
    let has = |d: &Path| d.join("deploy/minihubo-right-leg-dxl.toml").is_file();
    let starts = [
        std::env::current_dir().ok(),
        std::env::current_exe().ok(),
        Some(PathBuf::from(env!("CARGO_MANIFEST_DIR"))),
    ];
    starts
        .into_iter()
        .flatten()
        .find_map(|s| s.ancestors().find(|d| has(d)).map(Path::to_path_buf))
}
