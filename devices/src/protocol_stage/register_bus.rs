//! The protocol stage shared by the register-mapped UART protocols (Dynamixel 2.0 and 1.0):
//! each tick it queues the requests in the [`Core`], sends the queued writes as one SYNC WRITE
//! per register and the queued reads as one read transaction, and hands every status packet the
//! scanner finds back to the core. A [`Dialect`] supplies what differs: the packet encoders,
//! the read instruction, the packet framing and how a status packet reads.

use conductor_protocols::scan::{Framing, PacketScanner, ScanStats};

use super::transactions::{Core, Entry, ReadShape, Timing};
use crate::component::{ProtocolCounters, TickCtx};
use crate::message::{Reply, Request};
use crate::queue::Bounded;

/// A read transaction as encoded: what it puts on the wire and what it expects back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct ReadTxn {
    /// Instruction bytes.
    pub bytes: usize,
    /// Answered by one combined (fast) reply.
    pub fast: bool,
    /// Reply bytes expected (before stuffing).
    pub reply_bytes: usize,
    /// Status packets expected.
    pub replies: usize,
}

/// What one register-bus protocol adds to the shared stage.
pub(crate) trait Dialect {
    /// The packets the stage scans for.
    type Framing: Framing;

    /// Reads go one device per transaction (round robin) instead of all at once.
    fn single(&self) -> bool;

    /// Data bytes of a PING status packet.
    const PING_LEN: u16;

    /// Encodes a SYNC WRITE of `len` bytes at `addr` into `buf`, one `(id, little-endian
    /// value)` per device; `None` if the protocol cannot carry it.
    fn sync_write(
        &mut self,
        buf: &mut [u8],
        addr: u16,
        len: u8,
        values: &[(u8, [u8; 4])],
    ) -> Option<usize>;

    /// Encodes the instruction for `entries` (all of one `shape`: a read, or a PING or REBOOT
    /// of one device) into `buf`; `None` if the protocol cannot carry it.
    fn read(&mut self, buf: &mut [u8], entries: &[Entry], shape: ReadShape) -> Option<ReadTxn>;

    /// Hands a packet the scanner found, which arrived at `fence`, to `core` (status packets)
    /// or counts it.
    fn on_packet(
        &mut self,
        core: &mut Core,
        packet: <Self::Framing as Framing>::Packet<'_>,
        fence: u64,
        out: &mut Bounded<Reply>,
    );
}

/// A register-bus protocol stage over dialect `D`, scanning with an `N`-byte buffer.
pub(crate) struct RegisterBus<D: Dialect, const N: usize> {
    core: Core,
    dialect: D,
    scanner: Box<PacketScanner<D::Framing, N>>,
    pkt: Vec<u8>,
    group: Vec<(u8, i64)>,
    values: Vec<(u8, [u8; 4])>,
    entries: Vec<Entry>,
}

impl<D: Dialect, const N: usize> RegisterBus<D, N> {
    /// Room for `devices` devices (IDs up to `max_id`), `in_flight` read requests and packets
    /// of `max_packet` bytes.
    pub fn new(
        dialect: D,
        timing: Timing,
        max_id: u8,
        devices: usize,
        in_flight: usize,
        max_packet: usize,
    ) -> Self {
        Self {
            core: Core::new(timing, max_id, devices, in_flight, D::PING_LEN),
            dialect,
            scanner: Box::new(PacketScanner::new()),
            pkt: vec![0; max_packet],
            group: Vec::with_capacity(devices),
            values: Vec::with_capacity(devices),
            entries: Vec::with_capacity(devices),
        }
    }

    pub fn dialect(&self) -> &D {
        &self.dialect
    }

    /// The scanner's discard counters.
    pub fn scan_stats(&self) -> &ScanStats {
        self.scanner.stats()
    }

    /// Valid status packets nobody was waiting for.
    pub fn unsolicited(&self) -> u64 {
        self.core.unsolicited
    }

    /// Appends the first `n` bytes of the packet buffer to `out` if they fit.
    fn emit(&mut self, n: usize, out: &mut Bounded<u8>) -> bool {
        if out.remaining() < n {
            return false;
        }
        out.extend_from_slice(&self.pkt[..n]);
        self.core.counters.packets_out += 1;
        self.core.counters.words_out += n as u64;
        true
    }

    pub fn encode(&mut self, requests: &[Request], out: &mut Bounded<u8>, ctx: TickCtx) {
        self.core.absorb(requests);
        if !self.core.has_work() || !self.core.bus_free(ctx.now_ns) {
            return;
        }
        self.send_writes(out, ctx.now_ns);
        self.send_reads(out, ctx.now_ns);
    }

    fn send_writes(&mut self, out: &mut Bounded<u8>, now_ns: u64) {
        while let Some((addr, len)) = self.core.take_write_group(&mut self.group) {
            self.values.clear();
            for &(id, v) in &self.group {
                self.values.push((id, (v as u32).to_le_bytes()));
            }
            match self
                .dialect
                .sync_write(&mut self.pkt, addr, len, &self.values)
            {
                Some(n) if self.emit(n, out) => self.core.occupy(now_ns, n),
                _ => self.core.drop_writes(self.group.len()),
            }
        }
    }

    fn send_reads(&mut self, out: &mut Bounded<u8>, now_ns: u64) {
        let single = self.dialect.single();
        let Some(shape) = self.core.plan_reads(single, &mut self.entries) else {
            return;
        };
        let txn = self.dialect.read(&mut self.pkt, &self.entries, shape);
        let entries = std::mem::take(&mut self.entries);
        match txn {
            Some(t) if self.emit(t.bytes, out) => {
                let end_pos = self.core.counters.words_out;
                self.core.start_txn(
                    &entries,
                    shape,
                    t.fast,
                    now_ns,
                    end_pos,
                    t.bytes,
                    t.reply_bytes,
                    t.replies,
                );
            }
            _ => self.core.abandon(&entries, shape),
        }
        self.entries = entries;
    }

    pub fn decode(&mut self, words: &[u8], fence: &[u64], out: &mut Bounded<Reply>, now_ns: u64) {
        if words.is_empty() {
            return;
        }
        self.core.counters.words_in += words.len() as u64;
        self.core.heard(now_ns);
        let Self {
            core,
            dialect,
            scanner,
            ..
        } = self;
        // Feed runs of bytes that arrived with the same fence; a packet completes at the fence
        // of its last byte.
        let mut start = 0;
        while start < words.len() {
            let f = fence.get(start).copied().unwrap_or(u64::MAX);
            let mut end = start + 1;
            while end < words.len() && fence.get(end).copied().unwrap_or(u64::MAX) == f {
                end += 1;
            }
            scanner.feed(&words[start..end], |p| dialect.on_packet(core, p, f, out));
            start = end;
        }
    }

    pub fn expire(&mut self, out: &mut Bounded<Reply>, ctx: TickCtx) {
        let due = self.core.next_deadline().is_some_and(|d| d <= ctx.now_ns);
        if due || (!self.core.any_open() && self.scanner.buffered() > 0) {
            // The line is quiet for the oldest transaction: a partial packet will never
            // complete. Packets complete behind it still count (at the newest fence).
            let Self {
                core,
                dialect,
                scanner,
                ..
            } = self;
            scanner.expire_with(|p| dialect.on_packet(core, p, u64::MAX, out));
        }
        self.core.expire(ctx.now_ns, out);
    }

    pub fn preempt(&mut self) {
        self.core.preempt();
    }

    pub fn line_drained(&mut self, t_ns: u64) {
        self.core.line_drained(t_ns);
    }

    pub fn reset(&mut self, out: &mut Bounded<Reply>) {
        let Self {
            core,
            dialect,
            scanner,
            ..
        } = self;
        // A half-received packet will never complete; whole ones are from the old bus.
        scanner.expire_with(|p| dialect.on_packet(core, p, 0, out));
        self.core.reset(out);
    }

    pub fn counters(&self) -> ProtocolCounters {
        let s = self.scanner.stats();
        let mut c = self.core.counters;
        c.discarded_words = s.discarded_bytes();
        c.rejected_packets += s.rejected_packets() + self.core.unsolicited;
        c
    }
}

/// `impl Protocol` for a wrapper whose `stage` field is a [`RegisterBus`]: both Dynamixel stages are
/// the register stage under their own public name.
macro_rules! protocol_over_register_bus {
    ($t:ty) => {
        impl $crate::component::Protocol for $t {
            type Word = u8;

            fn encode(
                &mut self,
                requests: &[$crate::message::Request],
                out: &mut $crate::queue::Bounded<u8>,
                ctx: $crate::component::TickCtx,
            ) {
                self.stage.encode(requests, out, ctx);
            }

            fn decode(
                &mut self,
                words: &[u8],
                fence: &[u64],
                out: &mut $crate::queue::Bounded<$crate::message::Reply>,
                ctx: $crate::component::TickCtx,
            ) {
                self.stage.decode(words, fence, out, ctx.now_ns);
            }

            fn expire(
                &mut self,
                out: &mut $crate::queue::Bounded<$crate::message::Reply>,
                ctx: $crate::component::TickCtx,
            ) {
                self.stage.expire(out, ctx);
            }

            fn counters(&self) -> $crate::component::ProtocolCounters {
                self.stage.counters()
            }

            fn reset(&mut self, out: &mut $crate::queue::Bounded<$crate::message::Reply>) {
                self.stage.reset(out);
            }

            fn preempt(&mut self) {
                self.stage.preempt();
            }

            fn line_drained(&mut self, t_ns: u64) {
                self.stage.line_drained(t_ns);
            }
        }
    };
}
pub(crate) use protocol_over_register_bus;

/// Builds a Dynamixel protocol kind's stage with `new` (its bus timing from the kind's
/// `return_delay_us` and `timeout_us` at the hardware's line speed, its `read` mode) and binds
/// it to the hardware.
pub(crate) fn link_kind<S, M>(
    p: &crate::kinds::Params,
    hw: crate::kinds::OpenedHardware<u8>,
    cap: crate::kinds::Capacity,
    new: fn(Timing, M, usize, usize) -> S,
) -> Result<Box<dyn crate::Link>, crate::kinds::BuildError>
where
    S: crate::component::Protocol<Word = u8> + 'static,
    M: crate::kinds::Choice,
{
    let (delay_us, timeout_us): (u64, u64) =
        (p.int_as("return_delay_us")?, p.int_as("timeout_us")?);
    let timing = Timing {
        baud: hw.baud(),
        return_delay_ns: delay_us * 1000,
        timeout_ns: timeout_us * 1000,
    };
    hw.link(
        new(timing, p.choice("read")?, cap.devices, cap.in_flight),
        cap,
    )
}
