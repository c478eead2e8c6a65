//! `conductor-sim`: the bus simulators as a standalone process, so an executor (or any other
//! program: DynamixelSDK, python-can) can open them like real hardware.
//!
//! ```text
//! conductor-sim dxl   --pty-link /tmp/dxl0 --servos 6
//! conductor-sim slcan --pty-link /tmp/can0 --mit 1,2,3 --odrive 4
//! conductor-sim socketcan --interface vcan0 --mit 1,2,3 --odrive 4
//! ```
//!
//! The first line on stdout is `ready <device> [link <path>]`. Then each line on stdin is a
//! command:
//!
//! * `stats`: one JSON line of counters and state (for `dxl`, every servo's present and goal
//!   position, torque and hardware error; for `slcan`, every node's position, fault and
//!   ignored commands);
//! * `unplug`, `replug`: the USB adapter leaves and comes back at the same path (`--pty-link`
//!   needed for `replug`), the servos or motors keeping their state;
//! * `fault <id> <code>`: `dxl`: latch hardware error bits in servo `id`; `slcan`,
//!   `socketcan`: MIT fault code or ODrive axis error bits for node `id`;
//! * `clear <id>` (`slcan`, `socketcan`): clear node `id`'s fault;
//! * `stall <ms>`, `acks on|off`, `latency <us>`, `inject <hex bytes>` (`slcan`): the adapter
//!   stalls, stops acknowledging transmitted frames, lags, or sends raw bytes to the host;
//! * `quit` (or end of input) stops the simulator.
//!
//! Every command but `stats` is answered with one line, `ok` or `error <why>`.

use std::io::{BufRead, Write};
use std::net::SocketAddr;
use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use conductor_devices::hw::SlcanDialect;
use conductor_devices::protocol_stage::mit_limits;
use conductor_devices::sim::can_motors::{CanNode, MitMotorSim, OdriveAxisSim};
use conductor_devices::sim::dxl::{DxlBusSim, DxlSimConfig};
use conductor_devices::sim::fault::FaultConfig;
use conductor_devices::sim::runner::{run_dxl, run_slcan, Endpoint, Pty, Running};
use conductor_devices::sim::slcan_adapter::SlcanAdapterSim;
use conductor_devices::sim::socketcan_bus::SocketCanSim;

#[derive(Parser)]
#[command(
    name = "conductor-sim",
    about = "Bus simulators speaking the real wire protocols"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Args)]
struct Where {
    /// Make a pseudo-terminal and put a symlink to it here (a stable path for manifests).
    #[arg(long)]
    pty_link: Option<PathBuf>,
    /// Listen on UDP instead of a pty.
    #[arg(long, conflicts_with = "pty_link")]
    udp: Option<SocketAddr>,
    /// Print the stats line every this many milliseconds (0: only on request).
    #[arg(long, default_value_t = 0)]
    stats_ms: u64,
}

/// The simulated CAN nodes of the `slcan` and `socketcan` simulators.
#[derive(Args)]
struct CanNodes {
    /// MIT-mode motor IDs.
    #[arg(long, value_delimiter = ',')]
    mit: Vec<u8>,
    /// ODrive node IDs.
    #[arg(long, value_delimiter = ',')]
    odrive: Vec<u8>,
    /// MIT model (ranges): ak10-9, ak60-6, ak70-10, ak80-6, ak80-9, ak80-64, mini-cheetah.
    #[arg(long, default_value = "ak80-9")]
    model: String,
    /// MIT motors send 8-byte replies (temperature, fault code).
    #[arg(long)]
    long_reply: bool,
    /// ODrive heartbeat period (ms, 0 = off).
    #[arg(long, default_value_t = 100)]
    heartbeat_ms: u64,
    /// ODrive encoder-estimate period (ms, 0 = off).
    #[arg(long, default_value_t = 0)]
    encoder_ms: u64,
}

impl CanNodes {
    /// The nodes; exits with status 2 on an unknown MIT model.
    fn build(&self) -> Vec<Box<dyn CanNode>> {
        let Some(limits) = mit_limits(&self.model) else {
            eprintln!("conductor-sim: unknown MIT model {:?}", self.model);
            std::process::exit(2);
        };
        let mut nodes: Vec<Box<dyn CanNode>> = Vec::new();
        for &id in &self.mit {
            nodes.push(Box::new(MitMotorSim::new(id, limits, 0, self.long_reply)));
        }
        for &n in &self.odrive {
            nodes.push(Box::new(OdriveAxisSim::new(
                n,
                self.heartbeat_ms,
                self.encoder_ms,
            )));
        }
        nodes
    }
}

#[derive(Args)]
struct Faults {
    /// Probability that a byte is corrupted (both directions).
    #[arg(long, default_value_t = 0.0)]
    corrupt: f64,
    /// Probability that a byte is lost (both directions).
    #[arg(long, default_value_t = 0.0)]
    drop: f64,
    /// Probability that a reply is delayed by --delay-us.
    #[arg(long, default_value_t = 0.0)]
    delay: f64,
    /// Delay of a delayed reply (µs).
    #[arg(long, default_value_t = 0)]
    delay_us: u64,
    /// Probability that a packet loses its tail.
    #[arg(long, default_value_t = 0.0)]
    truncate: f64,
    /// Seed of the fault generator.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

#[derive(Subcommand)]
enum Cmd {
    /// A Dynamixel Protocol 2.0 bus of X-series servos.
    Dxl {
        #[command(flatten)]
        at: Where,
        /// Servos with IDs 1..=N.
        #[arg(long, default_value_t = 6)]
        servos: u8,
        /// Explicit IDs instead (comma-separated).
        #[arg(long, value_delimiter = ',')]
        ids: Vec<u8>,
        /// Line speed for reply timing.
        #[arg(long, default_value_t = 1_000_000)]
        baud: u32,
        /// Return Delay Time (µs).
        #[arg(long, default_value_t = 0)]
        return_delay_us: u32,
        /// Answer without the wire time of the replies.
        #[arg(long)]
        no_baud_timing: bool,
        /// Time constant of the position response (s).
        #[arg(long, default_value_t = 0.05)]
        tau: f64,
        /// Power up with torque on (legacy; a real servo powers up with torque off).
        #[arg(long)]
        torque_on: bool,
        /// Model number every servo reports (1020 = XM430-W350).
        #[arg(long, default_value_t = 1020)]
        model: u16,
        #[command(flatten)]
        faults: Faults,
    },
    /// An SLCAN USB-CAN adapter with MIT-mode motors and ODrive axes behind it.
    Slcan {
        #[command(flatten)]
        at: Where,
        #[command(flatten)]
        nodes: CanNodes,
        /// SLCAN dialect: canable (CR acks, S7 = 750k) or lawicel (z acks, S7 = 800k).
        #[arg(long, default_value = "canable")]
        dialect: SlcanDialect,
    },
    /// MIT-mode motors and ODrive axes on a SocketCAN interface (e.g. a vcan: `ip link add
    /// vcan0 type vcan && ip link set vcan0 up`); they survive the interface going down or
    /// being re-created. Commands: `stats`, `fault`, `clear`, `quit`.
    Socketcan {
        /// The interface (must exist and be up).
        #[arg(long)]
        interface: String,
        #[command(flatten)]
        nodes: CanNodes,
    },
}

fn node_stats(nodes: &[Box<dyn CanNode>]) -> String {
    nodes
        .iter()
        .map(|n| {
            let s = n.snapshot();
            format!(
                "{{\"id\": {}, \"position\": {}, \"enabled\": {}, \"frames_in\": {}, \
                 \"fault\": {}, \"ignored\": {}}}",
                s.id, s.position, s.enabled, s.frames_in, s.fault, s.ignored
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// Serves `stats`, `fault`, `clear` and `quit` on stdin for the SocketCAN nodes.
fn serve_socketcan(sim: SocketCanSim) {
    for l in std::io::stdin().lock().lines() {
        let Ok(l) = l else { break };
        let words: Vec<&str> = l.split_whitespace().collect();
        let Some((&cmd, rest)) = words.split_first() else {
            continue;
        };
        let on_node = |id: &str, f: &dyn Fn(&mut dyn CanNode) -> bool| {
            fault_node(&mut sim.nodes(), number(id)?, f)
        };
        let result = match cmd {
            "stats" => {
                say(&format!(
                    "{{\"frames_in\": {}, \"frames_out\": {}, \"reopens\": {}, \"nodes\": [{}]}}",
                    sim.frames_in(),
                    sim.frames_out(),
                    sim.reopens(),
                    node_stats(&sim.nodes())
                ));
                continue;
            }
            "quit" => break,
            "fault" => args::<2>(rest, "fault <id> <code>").and_then(|[id, code]| {
                let code: u32 = number(&code)?;
                on_node(&id, &|n| n.set_fault(code))
            }),
            "clear" => {
                args::<1>(rest, "clear <id>").and_then(|[id]| on_node(&id, &|n| n.reset_fault()))
            }
            other => Err(format!("not a socketcan command: {other}")),
        };
        match result {
            Ok(()) => say("ok"),
            Err(why) => say(&format!("error {why}")),
        }
    }
}

fn endpoint(at: &Where) -> std::io::Result<(Endpoint, String)> {
    Ok(match (&at.pty_link, at.udp) {
        (_, Some(addr)) => {
            let e = Endpoint::udp(addr)?;
            let d = e.describe();
            (e, d)
        }
        (link, None) => {
            let pty = Pty::open(link.as_deref())?;
            let mut d = pty.path().to_string();
            if let Some(l) = pty.link() {
                d.push_str(&format!(" link {}", l.display()));
            }
            (Endpoint::Pty(pty), d)
        }
    })
}

fn dxl_stats(sim: &DxlBusSim) -> String {
    let s = sim.stats();
    let ids = sim.ids();
    let list = |f: &dyn Fn(u8) -> i32| {
        ids.iter()
            .map(|&id| f(id).to_string())
            .collect::<Vec<_>>()
            .join(",")
    };
    format!(
        "{{\"bytes_in\": {}, \"packets_in\": {}, \"discarded_in\": {}, \"rejected_in\": {}, \
         \"ping\": {}, \"read\": {}, \"write\": {}, \"sync_read\": {}, \"fast_sync_read\": {}, \
         \"sync_write\": {}, \"sync_write_bytes\": {}, \"bulk_read\": {}, \"bulk_write\": {}, \
         \"reboot\": {}, \"packets_out\": {}, \"bytes_out\": {}, \"ids\": [{}], \"present\": [{}], \
         \"goal\": [{}], \"torque\": [{}], \"hardware_error\": [{}]}}",
        s.bytes_in,
        s.packets_in,
        s.discarded_in,
        s.rejected_in,
        s.ping,
        s.read,
        s.write,
        s.sync_read,
        s.fast_sync_read,
        s.sync_write,
        s.sync_write_bytes,
        s.bulk_read,
        s.bulk_write,
        s.reboot,
        s.packets_out,
        s.bytes_out,
        ids.iter()
            .map(|i| i.to_string())
            .collect::<Vec<_>>()
            .join(","),
        list(&|id| sim.servo(id).map_or(0, |s| s.present_position())),
        list(&|id| sim.servo(id).map_or(0, |s| s.goal_position())),
        list(&|id| sim.servo(id).map_or(0, |s| s.torque_on() as i32)),
        list(&|id| sim.servo(id).map_or(0, |s| s.hardware_error() as i32)),
    )
}

fn slcan_stats(a: &SlcanAdapterSim) -> String {
    let s = a.stats();
    let nodes = node_stats(a.nodes());
    format!(
        "{{\"bytes_in\": {}, \"commands\": {}, \"frames_from_host\": {}, \"frames_to_host\": {}, \
         \"nacks\": {}, \"bytes_out\": {}, \"open\": {}, \"nodes\": [{}]}}",
        s.bytes_in,
        s.commands,
        s.frames_from_host,
        s.frames_to_host,
        s.nacks,
        s.bytes_out,
        a.is_open(),
        nodes
    )
}

/// A simulator-specific command: its name and arguments → `Ok` or why not.
type Control<S> = fn(&Running<S>, &str, &[&str]) -> Result<(), String>;

/// A number, decimal or `0x` hex.
fn number<T: TryFrom<u64>>(s: &str) -> Result<T, String> {
    let v = match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(h) => u64::from_str_radix(h, 16),
        None => s.parse(),
    }
    .map_err(|_| format!("not a number: {s:?}"))?;
    T::try_from(v).map_err(|_| format!("out of range: {s}"))
}

fn args<const N: usize>(a: &[&str], usage: &str) -> Result<[String; N], String> {
    if a.len() != N {
        return Err(format!("usage: {usage}"));
    }
    Ok(std::array::from_fn(|i| a[i].to_string()))
}

fn dxl_control(r: &Running<DxlBusSim>, cmd: &str, a: &[&str]) -> Result<(), String> {
    match cmd {
        "fault" => {
            let [id, bits] = args(a, "fault <id> <hardware error bits>")?;
            let (id, bits): (u8, u8) = (number(&id)?, number(&bits)?);
            let mut sim = r.sim();
            let s = sim.servo_mut(id).ok_or(format!("no servo {id}"))?;
            s.inject_hardware_error(bits);
            Ok(())
        }
        other => Err(format!("not a dxl command: {other}")),
    }
}

/// Applies `f` (a fault or its clearing) to node `id`; an error names a missing node or one
/// that does not take the fault.
fn fault_node(
    nodes: &mut [Box<dyn CanNode>],
    id: u8,
    f: &dyn Fn(&mut dyn CanNode) -> bool,
) -> Result<(), String> {
    let n = nodes
        .iter_mut()
        .find(|n| n.snapshot().id == id)
        .ok_or(format!("no node {id}"))?;
    if f(n.as_mut()) {
        Ok(())
    } else {
        Err(format!("node {id} does not take that fault"))
    }
}

fn slcan_control(r: &Running<SlcanAdapterSim>, cmd: &str, a: &[&str]) -> Result<(), String> {
    let node = |sim: &mut SlcanAdapterSim, id: u8, f: &dyn Fn(&mut dyn CanNode) -> bool| {
        fault_node(sim.nodes_mut(), id, f)
    };
    match cmd {
        "fault" => {
            let [id, code] = args(a, "fault <id> <code>")?;
            let (id, code): (u8, u32) = (number(&id)?, number(&code)?);
            node(&mut r.sim(), id, &|n| n.set_fault(code))
        }
        "clear" => {
            let [id] = args(a, "clear <id>")?;
            node(&mut r.sim(), number(&id)?, &|n| n.reset_fault())
        }
        "stall" => {
            let [ms] = args(a, "stall <ms>")?;
            let ms: u64 = number(&ms)?;
            let until = r.now_ns() + ms * 1_000_000;
            r.sim().stall_until(until);
            Ok(())
        }
        "acks" => {
            let on = match a {
                ["on"] => true,
                ["off"] => false,
                _ => return Err("usage: acks on|off".into()),
            };
            r.sim().set_acks(on);
            Ok(())
        }
        "latency" => {
            let [us] = args(a, "latency <us>")?;
            let us: u64 = number(&us)?;
            r.sim().set_latency(us * 1000);
            Ok(())
        }
        "inject" => {
            let hex: String = a.concat();
            if hex.is_empty() || !hex.is_ascii() || !hex.len().is_multiple_of(2) {
                return Err("usage: inject <hex bytes>".into());
            }
            let bytes = (0..hex.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&hex[i..i + 2], 16))
                .collect::<Result<Vec<u8>, _>>()
                .map_err(|_| format!("not hex: {hex}"))?;
            r.sim().inject_to_host(&bytes);
            Ok(())
        }
        other => Err(format!("not an slcan command: {other}")),
    }
}

fn say(text: &str) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{text}");
    let _ = out.flush();
}

/// Serves the commands on stdin until `quit` or end of input.
fn serve<S: Send + 'static>(
    running: Running<S>,
    stats_ms: u64,
    line: fn(&S) -> String,
    control: Control<S>,
) {
    let running = std::sync::Arc::new(running);
    if stats_ms > 0 {
        let r = running.clone();
        std::thread::spawn(move || loop {
            std::thread::sleep(std::time::Duration::from_millis(stats_ms));
            let text = line(&r.sim());
            say(&text);
        });
    }
    for l in std::io::stdin().lock().lines() {
        let Ok(l) = l else { break };
        let words: Vec<&str> = l.split_whitespace().collect();
        let Some((&cmd, rest)) = words.split_first() else {
            continue;
        };
        let result = match cmd {
            "stats" => {
                let text = line(&running.sim());
                say(&text);
                continue;
            }
            "quit" => break,
            "unplug" => {
                running.unplug();
                Ok(())
            }
            "replug" => running.replug().map_err(|e| e.to_string()),
            _ => control(&running, cmd, rest),
        };
        match result {
            Ok(()) => say("ok"),
            Err(why) => say(&format!("error {why}")),
        }
    }
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.cmd {
        Cmd::Dxl {
            at,
            servos,
            ids,
            baud,
            return_delay_us,
            no_baud_timing,
            tau,
            torque_on,
            model,
            faults: f,
        } => endpoint(&at).map(|(ep, desc)| {
            let cfg = DxlSimConfig {
                ids: if ids.is_empty() {
                    (1..=servos).collect()
                } else {
                    ids
                },
                baud,
                return_delay_us,
                baud_timing: !no_baud_timing,
                tau_s: tau,
                torque_on,
                model,
                ..DxlSimConfig::default()
            };
            let faults = FaultConfig {
                corrupt: f.corrupt,
                drop: f.drop,
                delay: f.delay,
                delay_ns: f.delay_us * 1000,
                truncate: f.truncate,
                seed: f.seed,
            };
            let up = FaultConfig {
                seed: f.seed ^ 0x5EED,
                ..faults
            };
            let running = run_dxl(ep, cfg, faults, up);
            println!("ready {desc}");
            let _ = std::io::stdout().flush();
            serve(running, at.stats_ms, dxl_stats, dxl_control);
        }),
        Cmd::Slcan { at, nodes, dialect } => {
            let nodes = nodes.build();
            endpoint(&at).map(|(ep, desc)| {
                let running = run_slcan(ep, SlcanAdapterSim::new(dialect.dialect(), nodes));
                println!("ready {desc}");
                let _ = std::io::stdout().flush();
                serve(running, at.stats_ms, slcan_stats, slcan_control);
            })
        }
        Cmd::Socketcan { interface, nodes } => {
            SocketCanSim::start(&interface, nodes.build()).map(|sim| {
                say(&format!("ready socketcan {interface}"));
                serve_socketcan(sim);
            })
        }
    };
    if let Err(e) = result {
        eprintln!("conductor-sim: {e}");
        std::process::exit(1);
    }
}
