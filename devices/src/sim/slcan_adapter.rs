//! An SLCAN USB-CAN adapter with CAN nodes behind it: parses host commands (open, close,
//! bitrate, transmit, queries), acknowledges them as the chosen dialect does, hands
//! transmitted frames to the nodes and reports their answers as `t…` lines.
//!
//! It can also behave like a lagging or odd real adapter (all sans-IO, driven by
//! [`feed`](SlcanAdapterSim::feed) and [`poll`](SlcanAdapterSim::poll)):
//!
//! * [`set_latency`](SlcanAdapterSim::set_latency): everything it sends reaches the host that
//!   much later (USB and firmware buffering), in order;
//! * [`stall_until`](SlcanAdapterSim::stall_until): it processes nothing for a while (host
//!   bytes are buffered; no acks, no bus traffic, no cyclic node messages), then works through
//!   the backlog in order;
//! * [`set_acks`](SlcanAdapterSim::set_acks): firmware that does not acknowledge transmitted
//!   frames;
//! * [`inject_to_host`](SlcanAdapterSim::inject_to_host): raw bytes to the host (garbage, odd
//!   lines);
//! * [`unplug`](SlcanAdapterSim::unplug): the USB side lost power (channel closed, state lost;
//!   the nodes keep theirs);
//! * [`set_wire_faults`](SlcanAdapterSim::set_wire_faults): frames damaged on the CAN wire,
//!   lost whole as the CAN CRC makes them.

use std::collections::VecDeque;

use conductor_protocols::can::CanFrame;
use conductor_protocols::slcan::{Command, DeviceScanner, Dialect, Response, TxAck};
use embedded_can::{Frame, Id};

use super::fault::{FaultConfig, FaultInjector};

use super::can_motors::CanNode;

/// Counters of the adapter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SlcanSimStats {
    /// Bytes from the host.
    pub bytes_in: u64,
    /// Commands parsed.
    pub commands: u64,
    /// Frames the host transmitted onto the bus.
    pub frames_from_host: u64,
    /// Frames reported to the host.
    pub frames_to_host: u64,
    /// Commands refused with BEL (with acks off, transmits refused silently count too).
    pub nacks: u64,
    /// Bytes sent to the host (handed out by `feed`/`poll`, after the latency).
    pub bytes_out: u64,
    /// Host frames damaged on the CAN wire (see [`SlcanAdapterSim::set_wire_faults`]): the
    /// nodes' CAN controllers discard them on the CRC, so they never arrive.
    pub wire_lost_to_nodes: u64,
    /// Node frames damaged on the CAN wire, discarded by the adapter's CAN controller.
    pub wire_lost_to_host: u64,
}

/// The adapter.
pub struct SlcanAdapterSim {
    dialect: Dialect,
    scanner: DeviceScanner<64>,
    open: bool,
    listen_only: bool,
    timestamps: bool,
    nodes: Vec<Box<dyn CanNode>>,
    stats: SlcanSimStats,
    scratch: Vec<CanFrame>,
    /// Frames seen on the bus (host's and nodes'), for tests.
    log: Option<Vec<(bool, CanFrame)>>,
    latency_ns: u64,
    acks: bool,
    stall_until: Option<u64>,
    backlog: Vec<u8>,
    /// Bytes on their way to the host, and their segments: (ready time, length).
    out_bytes: VecDeque<u8>,
    out_segments: VecDeque<(u64, usize)>,
    /// The latest time seen by `feed` or `poll`.
    now_ns: u64,
    /// Damage on the CAN wire: (host → nodes, nodes → host).
    wire: Option<(FaultInjector, FaultInjector)>,
}

debug_fields!(SlcanAdapterSim { open, stats });

impl SlcanAdapterSim {
    /// An adapter speaking `dialect`, with `nodes` on its bus.
    pub fn new(dialect: Dialect, nodes: Vec<Box<dyn CanNode>>) -> Self {
        Self {
            dialect,
            scanner: DeviceScanner::new(dialect),
            open: false,
            listen_only: false,
            timestamps: false,
            nodes,
            stats: SlcanSimStats::default(),
            scratch: Vec::new(),
            log: None,
            latency_ns: 0,
            acks: true,
            stall_until: None,
            backlog: Vec::new(),
            out_bytes: VecDeque::with_capacity(4096),
            out_segments: VecDeque::with_capacity(256),
            now_ns: 0,
            wire: None,
        }
    }

    /// Records every frame on the bus: `(from_host, frame)`.
    pub fn with_log(mut self) -> Self {
        self.log = Some(Vec::new());
        self
    }

    /// The bus log.
    pub fn log(&self) -> &[(bool, CanFrame)] {
        self.log.as_deref().unwrap_or(&[])
    }

    /// Takes the frames logged so far, leaving the log running and empty.
    pub fn take_log(&mut self) -> Vec<(bool, CanFrame)> {
        self.log.as_mut().map(std::mem::take).unwrap_or_default()
    }

    /// Damages frames on the CAN wire: the bytes of each frame (identifier and data) go through
    /// an injector, one per direction, and a frame with any byte corrupted or lost is lost
    /// whole, as a real CAN controller drops a frame whose CRC fails (counted in
    /// [`SlcanSimStats::wire_lost_to_nodes`] and [`SlcanSimStats::wire_lost_to_host`]). The
    /// adapter still acknowledges a transmit it put on the wire.
    pub fn set_wire_faults(&mut self, to_nodes: FaultConfig, to_host: FaultConfig) {
        self.wire = Some((FaultInjector::new(to_nodes), FaultInjector::new(to_host)));
    }

    /// Whether the frame survives the wire (`to_nodes`: the host's direction).
    fn survives(&mut self, f: &CanFrame, to_nodes: bool) -> bool {
        let Some((down, up)) = &mut self.wire else {
            return true;
        };
        let mut bytes = match f.id() {
            Id::Standard(s) => (s.as_raw() as u32).to_be_bytes().to_vec(),
            Id::Extended(e) => e.as_raw().to_be_bytes().to_vec(),
        };
        bytes.extend_from_slice(f.data());
        let (rec, _) = if to_nodes { down } else { up }.apply(&mut bytes);
        if !rec.damaged() {
            return true;
        }
        if to_nodes {
            self.stats.wire_lost_to_nodes += 1;
        } else {
            self.stats.wire_lost_to_host += 1;
        }
        false
    }

    /// Counters since creation.
    pub fn stats(&self) -> SlcanSimStats {
        self.stats
    }

    /// Whether the channel is open.
    pub fn is_open(&self) -> bool {
        self.open
    }

    /// The nodes.
    pub fn nodes(&self) -> &[Box<dyn CanNode>] {
        &self.nodes
    }

    /// The nodes, to inject faults behind the host's back ([`CanNode::set_fault`]).
    pub fn nodes_mut(&mut self) -> &mut [Box<dyn CanNode>] {
        &mut self.nodes
    }

    /// Every byte the adapter sends from now on (acks, replies, frames from the bus) reaches
    /// the host `ns` after the adapter produced it. Order is kept.
    pub fn set_latency(&mut self, ns: u64) {
        self.latency_ns = ns;
    }

    /// The latency set by [`set_latency`](Self::set_latency).
    pub fn latency(&self) -> u64 {
        self.latency_ns
    }

    /// Until `t_ns` the adapter processes nothing: host bytes are buffered, no acks, no bus
    /// traffic, no cyclic node messages (bytes already on their way still arrive). At `t_ns`
    /// it works through the backlog in order (ack of command k, the nodes' answers to frame
    /// k, ack of k + 1, …), all produced at `t_ns`.
    pub fn stall_until(&mut self, t_ns: u64) {
        self.stall_until = Some(t_ns);
    }

    /// Whether the adapter is stalled at `now_ns`.
    pub fn is_stalled(&self, now_ns: u64) -> bool {
        self.stall_until.is_some_and(|t| now_ns < t)
    }

    /// With `false`, transmitted frames (`t`/`T`/`r`/`R`) go on the bus (the nodes answer)
    /// but are not acknowledged, neither CR/`z` nor BEL (a transmit on a closed channel is
    /// dropped silently and counted as a nack); other commands are still answered. Like
    /// firmware without TX acks.
    pub fn set_acks(&mut self, on: bool) {
        self.acks = on;
    }

    /// Raw bytes to the host (garbage, a malformed line, a frame line with a timestamp the
    /// host did not ask for), after everything already on its way, with no added latency.
    pub fn inject_to_host(&mut self, bytes: &[u8]) {
        let t = self.now_ns;
        self.queue(bytes, t, 0);
    }

    /// The USB side lost power (unplugged): the channel closes, timestamps go off, buffered
    /// and in-flight bytes and a stall are lost. Latency and ack settings (how this adapter
    /// behaves) and the nodes behind it (powered separately) are kept.
    pub fn unplug(&mut self) {
        self.scanner = DeviceScanner::new(self.dialect);
        self.open = false;
        self.listen_only = false;
        self.timestamps = false;
        self.stall_until = None;
        self.backlog.clear();
        self.out_bytes.clear();
        self.out_segments.clear();
    }

    /// When the adapter next has something to do without new host bytes: the ready time of
    /// the next byte on its way, or the end of a stall with a backlog. `None` if nothing.
    pub fn next_due(&self) -> Option<u64> {
        let out = self.out_segments.front().map(|&(t, _)| t);
        let stall = self.stall_until.filter(|_| !self.backlog.is_empty());
        match (out, stall) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Bytes produced and not yet handed to the host.
    pub fn in_flight(&self) -> usize {
        self.out_bytes.len()
    }

    /// Queues `bytes` for the host, produced at `t_ns`, ready `extra_ns` later (never before
    /// what is already queued).
    fn queue(&mut self, bytes: &[u8], t_ns: u64, extra_ns: u64) {
        if bytes.is_empty() {
            return;
        }
        let tail = self.out_segments.back().map_or(0, |&(t, _)| t);
        self.out_bytes.extend(bytes);
        self.out_segments
            .push_back(((t_ns + extra_ns).max(tail), bytes.len()));
    }

    /// Hands the host everything due by `now_ns`.
    fn release(&mut self, now_ns: u64, out: &mut Vec<u8>) {
        while let Some(&(ready, n)) = self.out_segments.front() {
            if ready > now_ns {
                break;
            }
            self.out_segments.pop_front();
            out.extend(self.out_bytes.drain(..n));
            self.stats.bytes_out += n as u64;
        }
    }

    fn respond(&mut self, r: Response<'_>, now_ns: u64) {
        let mut buf = [0u8; 40];
        let r = match r {
            Response::Frame { frame, .. } if self.timestamps => Response::Frame {
                frame,
                timestamp: Some(((now_ns / 1_000_000) % 60_000) as u16),
            },
            other => other,
        };
        if let Ok(n) = r.encode(&mut buf) {
            self.queue(&buf[..n], now_ns, self.latency_ns);
        }
    }

    fn deliver(&mut self, frames: &[CanFrame], now_ns: u64) {
        for f in frames {
            if let Some(l) = &mut self.log {
                l.push((false, *f));
            }
            if self.open && self.survives(f, false) {
                self.stats.frames_to_host += 1;
                self.respond(
                    Response::Frame {
                        frame: *f,
                        timestamp: None,
                    },
                    now_ns,
                );
            }
        }
    }

    /// Ends a stall that is over by `now_ns`: the backlog is processed at the stall's end.
    fn resume(&mut self, now_ns: u64) {
        let Some(t) = self.stall_until.filter(|&t| now_ns >= t) else {
            return;
        };
        self.stall_until = None;
        let backlog = std::mem::take(&mut self.backlog);
        self.process(&backlog, t);
        self.backlog = backlog;
        self.backlog.clear();
    }

    /// Bytes from the host at `now_ns`; what the adapter has for the host by then is appended
    /// to `out`.
    pub fn feed(&mut self, bytes: &[u8], now_ns: u64, out: &mut Vec<u8>) {
        self.now_ns = self.now_ns.max(now_ns);
        self.stats.bytes_in += bytes.len() as u64;
        if self.is_stalled(now_ns) {
            self.backlog.extend_from_slice(bytes);
        } else {
            self.resume(now_ns);
            self.process(bytes, now_ns);
        }
        self.release(now_ns, out);
    }

    fn process(&mut self, bytes: &[u8], now_ns: u64) {
        let mut cmds = Vec::new();
        self.scanner.feed(bytes, |c| cmds.push(c));
        for c in cmds {
            self.stats.commands += 1;
            let ok = match c {
                Err(_) => false,
                Ok(Command::Open) | Ok(Command::ListenOnly) if self.open => false,
                Ok(Command::Open) => {
                    self.open = true;
                    true
                }
                Ok(Command::ListenOnly) => {
                    self.open = true;
                    self.listen_only = true;
                    true
                }
                Ok(Command::Close) => {
                    let was = self.open;
                    self.open = false;
                    self.listen_only = false;
                    was
                }
                Ok(Command::Bitrate(_)) | Ok(Command::Btr { .. }) => !self.open,
                Ok(Command::Timestamps(on)) => {
                    self.timestamps = on;
                    true
                }
                Ok(Command::AcceptanceCode(_)) | Ok(Command::AcceptanceMask(_)) => true,
                Ok(Command::Version) => {
                    self.respond(Response::Version(b"1013"), now_ns);
                    continue;
                }
                Ok(Command::SerialNumber) => {
                    self.respond(Response::Serial(b"SIM1"), now_ns);
                    continue;
                }
                Ok(Command::ReadStatus) => {
                    self.respond(Response::Status(0), now_ns);
                    continue;
                }
                Ok(Command::Transmit(f)) => {
                    if !self.open || self.listen_only {
                        if !self.acks {
                            self.stats.nacks += 1;
                            continue;
                        }
                        false
                    } else {
                        if self.acks {
                            let ack = match self.dialect.tx_ack {
                                TxAck::Cr => Response::Ok,
                                TxAck::Z => Response::TxAck {
                                    extended: f.is_extended(),
                                },
                            };
                            self.respond(ack, now_ns);
                        }
                        self.stats.frames_from_host += 1;
                        if !self.survives(&f, true) {
                            continue;
                        }
                        if let Some(l) = &mut self.log {
                            l.push((true, f));
                        }
                        let mut answers = std::mem::take(&mut self.scratch);
                        answers.clear();
                        for n in &mut self.nodes {
                            n.on_frame(&f, now_ns, &mut answers);
                        }
                        self.deliver(&answers, now_ns);
                        self.scratch = answers;
                        continue;
                    }
                }
            };
            if ok {
                self.respond(Response::Ok, now_ns);
            } else {
                self.stats.nacks += 1;
                self.respond(Response::Error, now_ns);
            }
        }
    }

    /// Time passes: cyclic frames of the nodes are reported (not while stalled), and what the
    /// adapter has for the host by `now_ns` is appended to `out`.
    pub fn poll(&mut self, now_ns: u64, out: &mut Vec<u8>) {
        self.now_ns = self.now_ns.max(now_ns);
        if !self.is_stalled(now_ns) {
            self.resume(now_ns);
            let mut frames = std::mem::take(&mut self.scratch);
            frames.clear();
            for n in &mut self.nodes {
                n.poll(now_ns, &mut frames);
            }
            self.deliver(&frames, now_ns);
            self.scratch = frames;
        }
        self.release(now_ns, out);
    }
}
