//! The simulators as in-process [`Hardware`]: bytes the protocol stage transmits go straight
//! into the simulator, and its replies come back when their time has come (`ctx.now_ns` past
//! the reply's ready time), optionally through fault injectors in either direction. Every
//! reply is logged with what was done to it, for tests that reconcile counters with faults.

use std::collections::VecDeque;

use conductor_protocols::can::CanFrame;

use super::can_motors::{CanNode, NodeSnapshot};
use super::dxl::{DxlBusSim, DxlSimConfig, DxlSimStats};
use super::fault::{FaultConfig, FaultInjector, FaultRecord};
use super::slcan_adapter::{SlcanAdapterSim, SlcanSimStats};
use crate::component::{Hardware, HwError, TickCtx};

/// What the host sent in one `transmit`, as the simulator saw it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HostChunk {
    /// Transmit time.
    pub t_ns: u64,
    /// Bytes the host sent.
    pub sent: usize,
    /// What the injector did to them.
    pub fault: FaultRecord,
}

/// One status packet the simulator sent, and its fate.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReplyRecord {
    /// Time the instruction it answers arrived.
    pub t_request_ns: u64,
    /// Replying servo (0xFE: a fast reply).
    pub id: u8,
    /// Address and bytes read, if it answers a read.
    pub data: Option<(u16, Vec<u8>)>,
    /// Bytes on the wire before faults.
    pub bytes: usize,
    /// What the injector did to it.
    pub fault: FaultRecord,
}

/// The Dynamixel bus simulator as byte hardware.
#[derive(Debug)]
pub struct DxlSimHardware {
    sim: DxlBusSim,
    /// Reply packets in bus order: (ready time, bytes, bytes already handed out).
    queue: VecDeque<(u64, Vec<u8>, usize)>,
    down: FaultInjector,
    up: FaultInjector,
    log: bool,
    host_log: Vec<HostChunk>,
    reply_log: Vec<ReplyRecord>,
    bytes_to_host: u64,
}

impl DxlSimHardware {
    /// A simulated bus; `down` damages host→servo bytes (each transmit is one packet for the
    /// injector), `up` each status packet.
    pub fn new(cfg: DxlSimConfig, down: FaultConfig, up: FaultConfig) -> Self {
        Self {
            sim: DxlBusSim::new(cfg),
            queue: VecDeque::with_capacity(256),
            down: FaultInjector::new(down),
            up: FaultInjector::new(up),
            log: false,
            host_log: Vec::new(),
            reply_log: Vec::new(),
            bytes_to_host: 0,
        }
    }

    /// Keeps a log of every transmit and reply (for tests; it grows without bound).
    pub fn with_log(mut self) -> Self {
        self.log = true;
        self
    }

    /// The simulator.
    pub fn sim(&self) -> &DxlBusSim {
        &self.sim
    }

    /// The simulator, to change it behind the host's back (e.g.
    /// `sim_mut().servo_mut(id)` to inject a hardware error or move a limp shaft).
    pub fn sim_mut(&mut self) -> &mut DxlBusSim {
        &mut self.sim
    }

    /// The simulator's counters.
    pub fn stats(&self) -> DxlSimStats {
        self.sim.stats()
    }

    /// Bytes delivered to the host (after faults).
    pub fn bytes_to_host(&self) -> u64 {
        self.bytes_to_host
    }

    /// Every transmit since creation (with [`with_log`](Self::with_log)).
    pub fn host_log(&self) -> &[HostChunk] {
        &self.host_log
    }

    /// Every status packet sent since creation (with [`with_log`](Self::with_log)).
    pub fn reply_log(&self) -> &[ReplyRecord] {
        &self.reply_log
    }
}

impl Hardware for DxlSimHardware {
    type Word = u8;

    fn transmit(&mut self, words: &[u8], ctx: TickCtx) -> Result<usize, HwError> {
        let mut bytes = words.to_vec();
        let (fault, _) = self.down.apply(&mut bytes);
        if self.log {
            self.host_log.push(HostChunk {
                t_ns: ctx.now_ns,
                sent: words.len(),
                fault,
            });
        }
        let Self {
            sim,
            queue,
            up,
            log,
            reply_log,
            ..
        } = self;
        sim.feed(&bytes, ctx.now_ns, |r| {
            let mut b = r.bytes;
            let n = b.len();
            let (fault, delay) = up.apply(&mut b);
            if *log {
                reply_log.push(ReplyRecord {
                    t_request_ns: ctx.now_ns,
                    id: r.id,
                    data: r.data,
                    bytes: n,
                    fault,
                });
            }
            queue.push_back((r.ready_ns + delay, b, 0));
        });
        Ok(words.len())
    }

    fn receive(&mut self, out: &mut [u8], ctx: TickCtx) -> Result<usize, HwError> {
        let mut n = 0;
        while n < out.len() {
            let Some((ready, bytes, pos)) = self.queue.front_mut() else {
                break;
            };
            if *ready > ctx.now_ns {
                break;
            }
            let k = (bytes.len() - *pos).min(out.len() - n);
            out[n..n + k].copy_from_slice(&bytes[*pos..*pos + k]);
            *pos += k;
            n += k;
            if *pos == bytes.len() {
                self.queue.pop_front();
            }
        }
        // The line is quiet: a partial instruction will never complete.
        if self.queue.is_empty() {
            self.sim.advance(ctx.now_ns);
        }
        self.bytes_to_host += n as u64;
        Ok(n)
    }
}

/// CAN motors on an in-process bus, as frame hardware: each transmitted frame reaches every
/// node; their answers arrive `latency_ns` later (one frame time at 1 Mbit/s is ~0.13 ms).
pub struct CanSimHardware {
    nodes: Vec<Box<dyn CanNode>>,
    queue: VecDeque<(u64, CanFrame)>,
    latency_ns: u64,
    scratch: Vec<CanFrame>,
    frames_from_host: u64,
}

impl std::fmt::Debug for CanSimHardware {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CanSimHardware")
            .field("nodes", &self.nodes.len())
            .finish()
    }
}

impl CanSimHardware {
    /// A bus with `nodes`.
    pub fn new(nodes: Vec<Box<dyn CanNode>>, latency_ns: u64) -> Self {
        Self {
            nodes,
            queue: VecDeque::with_capacity(256),
            latency_ns,
            scratch: Vec::with_capacity(64),
            frames_from_host: 0,
        }
    }

    /// The nodes, to inject faults behind the host's back ([`CanNode::set_fault`]).
    pub fn nodes_mut(&mut self) -> &mut [Box<dyn CanNode>] {
        &mut self.nodes
    }

    /// The nodes' states.
    pub fn snapshots(&self) -> Vec<NodeSnapshot> {
        self.nodes.iter().map(|n| n.snapshot()).collect()
    }

    /// Frames the host transmitted.
    pub fn frames_from_host(&self) -> u64 {
        self.frames_from_host
    }
}

impl Hardware for CanSimHardware {
    type Word = CanFrame;

    fn transmit(&mut self, words: &[CanFrame], ctx: TickCtx) -> Result<usize, HwError> {
        for f in words {
            self.frames_from_host += 1;
            self.scratch.clear();
            for n in &mut self.nodes {
                n.on_frame(f, ctx.now_ns, &mut self.scratch);
            }
            for r in &self.scratch {
                self.queue.push_back((ctx.now_ns + self.latency_ns, *r));
            }
        }
        Ok(words.len())
    }

    fn receive(&mut self, out: &mut [CanFrame], ctx: TickCtx) -> Result<usize, HwError> {
        self.scratch.clear();
        for n in &mut self.nodes {
            n.poll(ctx.now_ns, &mut self.scratch);
        }
        for r in &self.scratch {
            self.queue.push_back((ctx.now_ns, *r));
        }
        let mut k = 0;
        while k < out.len() {
            match self.queue.front() {
                Some(&(ready, f)) if ready <= ctx.now_ns => {
                    out[k] = f;
                    k += 1;
                    self.queue.pop_front();
                }
                _ => break,
            }
        }
        Ok(k)
    }
}

/// The SLCAN adapter simulator as byte hardware (the serial side of a USB-CAN adapter), for
/// running [`crate::hw::SlcanHardware`] in process. Answers are available at once, or after
/// the adapter's latency or stall ([`SlcanAdapterSim::set_latency`],
/// [`SlcanAdapterSim::stall_until`]).
#[derive(Debug)]
pub struct SlcanSimPort {
    adapter: SlcanAdapterSim,
    out: VecDeque<u8>,
    scratch: Vec<u8>,
    now_ns: u64,
}

impl SlcanSimPort {
    /// The adapter behind a byte port.
    pub fn new(adapter: SlcanAdapterSim) -> Self {
        Self {
            adapter,
            out: VecDeque::with_capacity(4096),
            scratch: Vec::with_capacity(4096),
            now_ns: 0,
        }
    }

    /// The adapter.
    pub fn adapter(&self) -> &SlcanAdapterSim {
        &self.adapter
    }

    /// The adapter, to make it lag, stall or drop acks, or to reach its nodes.
    pub fn adapter_mut(&mut self) -> &mut SlcanAdapterSim {
        &mut self.adapter
    }

    /// The adapter's counters.
    pub fn stats(&self) -> SlcanSimStats {
        self.adapter.stats()
    }
}

impl Hardware for SlcanSimPort {
    type Word = u8;

    fn transmit(&mut self, words: &[u8], ctx: TickCtx) -> Result<usize, HwError> {
        // The open sequence runs before the executor's clock: keep time monotonic.
        self.now_ns = self.now_ns.max(ctx.now_ns);
        self.scratch.clear();
        self.adapter.feed(words, self.now_ns, &mut self.scratch);
        self.out.extend(&self.scratch);
        Ok(words.len())
    }

    fn receive(&mut self, out: &mut [u8], ctx: TickCtx) -> Result<usize, HwError> {
        self.now_ns = self.now_ns.max(ctx.now_ns);
        self.scratch.clear();
        self.adapter.poll(self.now_ns, &mut self.scratch);
        self.out.extend(&self.scratch);
        let n = out.len().min(self.out.len());
        for (o, b) in out.iter_mut().zip(self.out.drain(..n)) {
            *o = b;
        }
        Ok(n)
    }
}

use crate::kinds::{
    id_list, Build, BuildError, Capacity, HardwareBuild, KindSpec, OpenedHardware, ParamSpec,
    Params,
};

/// The `dynamixel_sim` hardware kind.
pub const DYNAMIXEL_SIM: KindSpec = KindSpec {
    kind: "dynamixel_sim",
    params: &[
        ParamSpec::text(
            "ids",
            Some("1,2,3,4,5,6"),
            "servo IDs on the simulated bus, comma-separated",
        ),
        ParamSpec::int(
            "baud",
            Some(1_000_000),
            1200.0,
            12_000_000.0,
            crate::kinds::BAUD_DOC,
        ),
        crate::kinds::RETURN_DELAY_US,
        ParamSpec::bool(
            "baud_timing",
            true,
            "replies take their wire time at `baud`",
        ),
        ParamSpec::float(
            "tau_s",
            0.05,
            Some((0.0, 100.0)),
            "time constant of the servos' position response (s)",
        ),
        ParamSpec::float(
            "corrupt",
            0.0,
            Some((0.0, 1.0)),
            "probability that a byte is corrupted (both directions)",
        ),
        ParamSpec::float(
            "drop",
            0.0,
            Some((0.0, 1.0)),
            "probability that a byte is lost (both directions)",
        ),
        ParamSpec::int("seed", Some(1), 0.0, 9.0e15, "seed of the fault generator"),
    ],
    doc: "An in-process Dynamixel Protocol 2.0 bus of XM430 servos (the simulator of \
          `conductor-sim dxl`, without the pty), with optional fault injection.",
    build: Build::Hardware {
        resource: None,
        open: HardwareBuild::Bytes(open_dynamixel_sim),
    },
};

fn open_dynamixel_sim(p: &Params, _: Capacity) -> Result<OpenedHardware<u8>, BuildError> {
    let baud = crate::kinds::baud(p)?;
    let cfg = DxlSimConfig {
        ids: id_list(p, "ids")?,
        baud,
        return_delay_us: p.int_as("return_delay_us")?,
        baud_timing: p.bool("baud_timing")?,
        tau_s: p.float("tau_s")?,
        ..DxlSimConfig::default()
    };
    let down = FaultConfig {
        corrupt: p.float("corrupt")?,
        drop: p.float("drop")?,
        seed: p.int_as("seed")?,
        ..FaultConfig::default()
    };
    let up = FaultConfig {
        seed: down.seed ^ 0x5EED,
        ..down
    };
    Ok(OpenedHardware::new(DxlSimHardware::new(cfg, down, up)).at_baud(baud))
}

/// The `can_sim` hardware kind.
pub const CAN_SIM: KindSpec = KindSpec {
    kind: "can_sim",
    params: &[
        ParamSpec::text("mit", Some(""), "MIT-mode motor IDs, comma-separated"),
        ParamSpec::text("odrive", Some(""), "ODrive node IDs, comma-separated"),
        ParamSpec::names(
            "model",
            Some("ak80-9"),
            crate::protocol_stage::MIT_MODEL_NAMES,
            "MIT motor model (ranges)",
        ),
        ParamSpec::int(
            "latency_us",
            Some(150),
            0.0,
            1_000_000.0,
            "delay of the motors' answers (µs)",
        ),
        ParamSpec::int(
            "heartbeat_ms",
            Some(100),
            0.0,
            100_000.0,
            "ODrive heartbeat period (ms, 0 = off)",
        ),
    ],
    doc: "An in-process CAN bus with simulated MIT-mode motors and ODrive axes.",
    build: Build::Hardware {
        resource: None,
        open: HardwareBuild::Can(open_can_sim),
    },
};

fn open_can_sim(p: &Params, _: Capacity) -> Result<OpenedHardware<CanFrame>, BuildError> {
    let limits = crate::protocol_stage::mit_model(p, "model")?;
    let mut nodes = super::can_motors::MitMotorSim::bus(id_list(p, "mit")?, limits);
    let heartbeat_ms = p.int_as("heartbeat_ms")?;
    for n in id_list(p, "odrive")? {
        nodes.push(Box::new(super::can_motors::OdriveAxisSim::new(
            n,
            heartbeat_ms,
            0,
        )));
    }
    let latency_us: u64 = p.int_as("latency_us")?;
    Ok(OpenedHardware::new(CanSimHardware::new(
        nodes,
        latency_us * 1000,
    )))
}
