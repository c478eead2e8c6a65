//! The Dynamixel Protocol 2.0 stage: bundles a tick's writes into SYNC WRITEs (one per
//! register) and its reads into one SYNC READ or FAST SYNC READ (BULK / FAST BULK READ when the
//! devices read different spans), and matches status packets back to the requests.

use conductor_protocols::dynamixel2::{
    self as dxl, BulkReadEntry, FastReply, Packet, Scanner, Status,
};

use super::register::{Core, Entry, ReadShape, StatusErr, Timing};
use crate::message::{Reply, Request};
use crate::queue::Bounded;
use crate::stage::{Protocol, ProtocolCounters, TickCtx};

/// How the stage reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dxl2ReadMode {
    /// SYNC READ (or BULK READ): one status packet per device.
    Sync,
    /// FAST SYNC READ (or FAST BULK READ): one combined status packet (X430/540 FW ≥ 45).
    Fast,
}

/// Largest packet the stage builds or accepts.
const MAX_PACKET: usize = 1024;

/// Dynamixel 2.0 protocol stage. Word = byte.
pub struct Dxl2Protocol {
    core: Core,
    mode: Dxl2ReadMode,
    scanner: Box<Scanner<MAX_PACKET>>,
    pkt: Vec<u8>,
    group: Vec<(u8, i64)>,
    data: Vec<(u8, [u8; 4])>,
    entries: Vec<Entry>,
    bulk: Vec<BulkReadEntry>,
    ids: Vec<u8>,
    lens: Vec<usize>,
    unsolicited: u64,
}

impl std::fmt::Debug for Dxl2Protocol {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Dxl2Protocol")
            .field("mode", &self.mode)
            .field("counters", &self.counters())
            .finish()
    }
}

impl Dxl2Protocol {
    /// A stage for up to `devices` servos and `in_flight` read requests per transaction.
    pub fn new(timing: Timing, mode: Dxl2ReadMode, devices: usize, in_flight: usize) -> Self {
        let devices = devices.clamp(1, 253);
        Self {
            core: Core::new(timing, dxl::MAX_DEVICE_ID, devices, in_flight),
            mode,
            scanner: Box::new(Scanner::new()),
            pkt: vec![0; MAX_PACKET],
            group: Vec::with_capacity(devices),
            data: Vec::with_capacity(devices),
            entries: Vec::with_capacity(devices),
            bulk: Vec::with_capacity(devices),
            ids: Vec::with_capacity(devices),
            lens: Vec::with_capacity(devices),
            unsolicited: 0,
        }
    }

    /// The configured read mode.
    pub fn mode(&self) -> Dxl2ReadMode {
        self.mode
    }

    /// The scanner's discard statistics.
    pub fn scan_stats(&self) -> conductor_protocols::scan::ScanStats {
        *self.scanner.stats()
    }

    /// Valid status packets nobody was waiting for (late, duplicated or foreign).
    pub fn unsolicited(&self) -> u64 {
        self.unsolicited
    }

    fn emit(&mut self, n: usize, out: &mut Bounded<u8>) -> bool {
        if out.remaining() < n {
            return false;
        }
        out.extend_from_slice(&self.pkt[..n]);
        self.core.counters.packets_out += 1;
        self.core.counters.words_out += n as u64;
        true
    }

    fn send_writes(&mut self, out: &mut Bounded<u8>, now_ns: u64) {
        while let Some((addr, len)) = self.core.take_write_group(&mut self.group) {
            self.data.clear();
            for &(id, v) in &self.group {
                self.data.push((id, (v as u32).to_le_bytes()));
            }
            let l = len as usize;
            let res = dxl::sync_write(
                &mut self.pkt,
                addr,
                len as u16,
                self.data.iter().map(|(id, b)| (*id, &b[..l])),
            );
            match res {
                Ok(n) if self.emit(n, out) => self.core.occupy(now_ns, n),
                _ => self.core.drop_writes(self.group.len()),
            }
        }
    }

    fn send_reads(&mut self, out: &mut Bounded<u8>, now_ns: u64) {
        let Some(shape) = self.core.plan_reads(false, &mut self.entries) else {
            return;
        };
        let fast = self.mode == Dxl2ReadMode::Fast;
        let n = self.entries.len();
        let res = match shape {
            ReadShape::Uniform => {
                let (addr, len) = (self.entries[0].addr, self.entries[0].len);
                self.ids.clear();
                self.ids.extend(self.entries.iter().map(|e| e.id));
                if fast {
                    dxl::fast_sync_read(&mut self.pkt, addr, len, &self.ids)
                } else {
                    dxl::sync_read(&mut self.pkt, addr, len, &self.ids)
                }
            }
            ReadShape::Mixed => {
                self.bulk.clear();
                self.bulk.extend(self.entries.iter().map(|e| BulkReadEntry {
                    id: e.id,
                    addr: e.addr,
                    len: e.len,
                }));
                if fast {
                    dxl::fast_bulk_read(&mut self.pkt, self.bulk.iter().copied())
                } else {
                    dxl::bulk_read(&mut self.pkt, self.bulk.iter().copied())
                }
            }
        };
        let reply_bytes = if fast {
            // Each slice: ERR ID DATA CRC; plus header, ID, LEN, INST.
            8 + self
                .entries
                .iter()
                .map(|e| 4 + e.len as usize)
                .sum::<usize>()
        } else {
            self.entries
                .iter()
                .map(|e| dxl::status_len(e.len as usize))
                .sum()
        };
        let replies = if fast { 1 } else { n };
        match res {
            Ok(k) if self.emit(k, out) => {
                let entries = std::mem::take(&mut self.entries);
                self.core
                    .start_txn(&entries, fast, now_ns, k, reply_bytes, replies);
                self.entries = entries;
            }
            _ => {
                let entries = std::mem::take(&mut self.entries);
                self.core.abandon_reads(&entries);
                self.entries = entries;
            }
        }
    }
}

/// Interprets a 2.0 error byte.
fn status_err(e: dxl::ErrorByte) -> StatusErr {
    StatusErr {
        failed: e.error().is_some(),
        alert: e.alert(),
        code: e.0,
    }
}

fn handle_packet(
    core: &mut Core,
    lens: &mut Vec<usize>,
    unsolicited: &mut u64,
    p: Packet<'_>,
    ctx: TickCtx,
    out: &mut Bounded<Reply>,
) {
    if !p.is_status() {
        // An instruction packet: the echo of an adapter that hears itself. Not ours to answer.
        return;
    }
    if p.id == dxl::BROADCAST_ID {
        let Ok(fr) = FastReply::from_packet(&p) else {
            core.counters.rejected_packets += 1;
            return;
        };
        if !core.fast_lens(lens) {
            *unsolicited += 1;
            return;
        }
        for s in fr.slices(lens.iter().copied()) {
            match s {
                Ok(s) => {
                    if !core.on_status(s.id, status_err(s.error), s.data, ctx, out) {
                        *unsolicited += 1;
                    }
                }
                Err(_) => {
                    // The slices after a bad embedded CRC cannot be trusted; their requests
                    // expire as missing.
                    core.counters.rejected_packets += 1;
                    break;
                }
            }
        }
        return;
    }
    match Status::from_packet(&p) {
        Ok(s) => {
            if !core.on_status(s.id, status_err(s.error), s.data, ctx, out) {
                *unsolicited += 1;
            }
        }
        Err(_) => core.counters.rejected_packets += 1,
    }
}

impl Protocol for Dxl2Protocol {
    type Word = u8;

    fn encode(&mut self, requests: &[Request], out: &mut Bounded<u8>, ctx: TickCtx) {
        self.core.absorb(requests);
        if !self.core.has_work() || !self.core.bus_free(ctx.now_ns) {
            return;
        }
        self.send_writes(out, ctx.now_ns);
        self.send_reads(out, ctx.now_ns);
    }

    fn decode(&mut self, words: &[u8], out: &mut Bounded<Reply>, ctx: TickCtx) {
        self.core.counters.words_in += words.len() as u64;
        let Self {
            core,
            scanner,
            lens,
            unsolicited,
            ..
        } = self;
        scanner.feed(words, |p| {
            handle_packet(core, lens, unsolicited, p, ctx, out);
        });
    }

    fn expire(&mut self, out: &mut Bounded<Reply>, ctx: TickCtx) {
        let due = self.core.next_deadline().is_some_and(|d| d <= ctx.now_ns);
        if due || (!self.core.any_open() && self.scanner.buffered() > 0) {
            // The line is quiet for the oldest transaction: a partial packet will never
            // complete. Packets complete behind it still count.
            let Self {
                core,
                scanner,
                lens,
                unsolicited,
                ..
            } = self;
            scanner.expire_with(|p| handle_packet(core, lens, unsolicited, p, ctx, out));
        }
        self.core.expire(ctx.now_ns, out);
    }

    fn counters(&self) -> ProtocolCounters {
        let s = self.scanner.stats();
        let mut c = self.core.counters;
        c.discarded_words = s.discarded_bytes();
        c.rejected_packets += s.rejected_packets() + self.unsolicited;
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::message::{Credential, Op, ReplyData};

    fn req(id: u32, op: Op, tick: u64) -> Request {
        Request {
            cred: Credential::id(id),
            op,
            tick,
            t_request_ns: tick * 100_000,
        }
    }

    fn ctx(tick: u64) -> TickCtx {
        TickCtx {
            tick,
            now_ns: tick * 100_000,
        }
    }

    fn timing() -> Timing {
        Timing {
            baud: 1_000_000,
            return_delay_ns: 0,
            timeout_ns: 1_000_000,
        }
    }

    /// Ticks faster than the bus: while the previous transaction is on the wire nothing is
    /// sent, and the requests that pile up are coalesced (latest goal wins, one read).
    #[test]
    fn busy_bus_defers_and_coalesces() {
        let mut p = Dxl2Protocol::new(timing(), Dxl2ReadMode::Sync, 2, 16);
        let mut out = Bounded::with_capacity(512);
        let goal = |v, t| {
            req(
                1,
                Op::Write {
                    addr: 116,
                    len: 4,
                    value: v,
                },
                t,
            )
        };
        let read = |t| req(1, Op::Read { addr: 132, len: 4 }, t);
        p.encode(&[goal(100, 0), read(0)], &mut out, ctx(0));
        let first = out.len();
        assert!(first > 0);
        // 0.1 ms later: the read's reply (15 bytes, 0.15 ms at 1 Mbit/s) is still due.
        p.encode(&[goal(200, 1), read(1)], &mut out, ctx(1));
        p.encode(&[goal(300, 2), read(2)], &mut out, ctx(2));
        assert_eq!(out.len(), first, "nothing sent while the bus is busy");
        // Later: one SYNC WRITE carrying the newest goal, one SYNC READ.
        out.clear();
        p.encode(&[], &mut out, ctx(10));
        let mut buf = out.as_slice().to_vec();
        let pk = conductor_protocols::dynamixel2::parse_in_place(&mut buf).unwrap();
        assert_eq!(pk.instruction, 0x83);
        assert_eq!(&pk.params[4..], &[1, 0x2C, 0x01, 0, 0], "goal 300");
        assert_eq!(p.counters().packets_out, 4);
        assert_eq!(p.counters().dropped_requests, 0);
    }

    #[test]
    fn unsendable_reads_are_missing_not_silent() {
        let mut p = Dxl2Protocol::new(timing(), Dxl2ReadMode::Sync, 2, 16);
        let mut out = Bounded::with_capacity(8); // too small for any packet
        p.encode(
            &[req(3, Op::Read { addr: 132, len: 4 }, 0)],
            &mut out,
            ctx(0),
        );
        assert!(out.is_empty());
        let mut replies = Bounded::with_capacity(4);
        p.expire(&mut replies, ctx(0));
        assert!(matches!(
            replies.as_slice()[0].data,
            ReplyData::Missing { .. }
        ));
        assert_eq!(p.counters().dropped_requests, 1);
        // An ID the protocol cannot address is refused the same way.
        p.encode(
            &[req(300, Op::Read { addr: 132, len: 4 }, 1)],
            &mut out,
            ctx(1),
        );
        replies.clear();
        p.expire(&mut replies, ctx(1));
        assert_eq!(replies.len(), 1);
        assert_eq!(p.counters().dropped_requests, 2);
    }
}
