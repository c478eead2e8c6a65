//! The simulators as in-process [`Hardware`]: bytes the protocol stage transmits go straight
//! into the simulator, and its replies come back when their time has come (`ctx.now_ns` past
//! the reply's ready time), optionally through fault injectors in either direction. Every
//! reply is logged with what was done to it, for tests that reconcile counters with faults.

use std::collections::VecDeque;

use super::dxl::{DxlBusSim, DxlSimConfig, DxlSimStats};
use super::fault::{FaultConfig, FaultInjector, FaultRecord};
use crate::stage::{Hardware, HwError, TickCtx};

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
