//! The machinery shared by the register-mapped UART protocols (Dynamixel 2.0 and 1.0): what
//! devices want read and written, the read transactions in flight on the half-duplex bus, and
//! matching status packets back to the requests that caused them.
//!
//! * Requests that arrive while the bus is still busy with the previous transaction stay
//!   queued (the thesis' tick cache) and are **coalesced**: a newer write to the same register
//!   replaces the older one; repeated reads of the same register share one bus read, and every
//!   one of them is answered (by its value, or `Missing`). When more reads pile up than the
//!   stage has room for, the excess is answered `Missing` at once and counted as dropped.
//! * A transaction is one read instruction (SYNC/FAST SYNC/BULK/FAST BULK READ, or a single
//!   READ) and the status packets it expects. Status packets arrive in wire order, so a reply
//!   for a newer transaction closes the older ones: what they still lacked is missing.
//! * Each transaction has a deadline from the wire time at the configured baud, the servos'
//!   return delay and a timeout margin; what has not arrived then is reported
//!   [`ReplyData::Missing`] and counted, never invented.

use crate::message::{Credential, Op, Reply, ReplyData, Request};
use crate::queue::Bounded;
use crate::stage::ProtocolCounters;

/// Nanoseconds to send `bytes` 8N1 bytes (10 bits each) at `baud`.
pub fn wire_ns(bytes: usize, baud: u32) -> u64 {
    (bytes as u64 * 10 * 1_000_000_000).div_ceil(baud.max(1) as u64)
}

/// Bus timing assumptions of a protocol stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    /// Line speed.
    pub baud: u32,
    /// The servos' Return Delay Time (ns) before each status packet.
    pub return_delay_ns: u64,
    /// Extra time after the expected end of a transaction before its replies are missing.
    pub timeout_ns: u64,
}

/// One read request waiting for its value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Waiter {
    pub cred: Credential,
    pub addr: u16,
    pub len: u8,
    pub tick: u64,
    pub t_request_ns: u64,
}

impl Waiter {
    fn op(&self) -> Op {
        Op::Read {
            addr: self.addr,
            len: self.len,
        }
    }

    fn end(&self) -> u16 {
        self.addr + self.len as u16
    }

    /// The answer that this read went unanswered.
    fn missing(&self) -> Reply {
        Reply {
            cred: self.cred,
            data: ReplyData::Missing { op: self.op() },
            tick: self.tick,
            t_sample_ns: self.t_request_ns,
        }
    }
}

/// One register write waiting for the bus.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct WriteReq {
    pub cred: Credential,
    pub addr: u16,
    pub len: u8,
    pub value: i64,
}

/// One device's part of a read transaction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Entry {
    pub id: u8,
    pub addr: u16,
    pub len: u16,
    done: bool,
}

/// How a status packet's error byte reads, protocol-independently.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct StatusErr {
    /// The instruction failed: the data is not to be trusted.
    pub failed: bool,
    /// A hardware alarm is latched; the data is still valid.
    pub alert: bool,
    /// The raw error byte.
    pub code: u8,
}

/// The read instruction a transaction sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ReadShape {
    /// Every entry has the same address and length.
    Uniform,
    /// Entries differ (bulk read).
    Mixed,
}

#[derive(Debug)]
struct Txn {
    active: bool,
    seq: u64,
    fast: bool,
    deadline_ns: u64,
    t_sent_ns: u64,
    entries: Vec<Entry>,
    /// (entry index, waiter).
    waiters: Vec<(usize, Waiter)>,
}

/// Most transactions open at once (sent, replies not all decoded). On a half-duplex bus a new
/// one starts only after the previous one's expected end, so two are typical.
const TXNS: usize = 4;

/// The shared state of a register-bus protocol stage.
#[derive(Debug)]
pub(crate) struct Core {
    timing: Timing,
    max_id: u8,
    want_reads: Bounded<Waiter>,
    want_writes: Bounded<WriteReq>,
    /// Replies decided at encode time (requests that cannot be sent), handed out at expire.
    early: Bounded<Reply>,
    txns: Vec<Txn>,
    next_seq: u64,
    bus_free_at: u64,
    rr: u8,
    pub counters: ProtocolCounters,
    /// Valid status packets nobody was waiting for (late, duplicated or foreign).
    pub unsolicited: u64,
}

impl Core {
    /// Room for `devices` devices and `in_flight` read requests.
    pub fn new(timing: Timing, max_id: u8, devices: usize, in_flight: usize) -> Self {
        let devices = devices.max(1);
        let in_flight = in_flight.max(devices);
        Self {
            timing,
            max_id,
            want_reads: Bounded::with_capacity(in_flight),
            want_writes: Bounded::with_capacity(in_flight),
            early: Bounded::with_capacity(in_flight),
            txns: (0..TXNS)
                .map(|_| Txn {
                    active: false,
                    seq: 0,
                    fast: false,
                    deadline_ns: 0,
                    t_sent_ns: 0,
                    entries: Vec::with_capacity(devices),
                    waiters: Vec::with_capacity(in_flight),
                })
                .collect(),
            next_seq: 0,
            bus_free_at: 0,
            rr: 0,
            counters: ProtocolCounters::default(),
            unsolicited: 0,
        }
    }

    /// Queues (and coalesces) this tick's requests.
    pub fn absorb(&mut self, requests: &[Request]) {
        for r in requests {
            let Ok(id) = u8::try_from(r.cred.id) else {
                self.refuse(r);
                continue;
            };
            if id > self.max_id {
                self.refuse(r);
                continue;
            }
            match r.op {
                Op::Read { addr, len } if len > 0 && addr.checked_add(len as u16).is_some() => {
                    // A read of a register already queued shares its bus read: both requests
                    // are answered by the one value (it is kept as its own waiter).
                    let w = Waiter {
                        cred: r.cred,
                        addr,
                        len,
                        tick: r.tick,
                        t_request_ns: r.t_request_ns,
                    };
                    if self.want_reads.push(w).is_err() {
                        self.refuse(r);
                    }
                }
                Op::Write { addr, len, value } if matches!(len, 1 | 2 | 4) => {
                    let w = WriteReq {
                        cred: r.cred,
                        addr,
                        len,
                        value,
                    };
                    let slot = self
                        .want_writes
                        .as_mut_slice()
                        .iter_mut()
                        .find(|q| q.cred == r.cred && q.addr == addr);
                    match slot {
                        Some(q) => *q = w,
                        None => {
                            if self.want_writes.push(w).is_err() {
                                self.counters.dropped_requests += 1;
                            }
                        }
                    }
                }
                _ => self.refuse(r),
            }
        }
    }

    /// A request this bus cannot carry: counted; a read is answered `Missing` at expire.
    fn refuse(&mut self, r: &Request) {
        self.counters.dropped_requests += 1;
        if matches!(r.op, Op::Read { .. }) {
            let _ = self.early.push(Reply {
                cred: r.cred,
                data: ReplyData::Missing { op: r.op },
                tick: r.tick,
                t_sample_ns: r.t_request_ns,
            });
        }
    }

    /// Whether the previous transaction's replies should be off the wire by `now`.
    pub fn bus_free(&self, now_ns: u64) -> bool {
        now_ns >= self.bus_free_at
    }

    pub fn has_work(&self) -> bool {
        !self.want_reads.is_empty() || !self.want_writes.is_empty()
    }

    /// Takes the queued writes with the same address and length as the first one, into
    /// `group` as `(id, value)`. Returns `(addr, len)`, or `None` when no write is queued.
    pub fn take_write_group(&mut self, group: &mut Vec<(u8, i64)>) -> Option<(u16, u8)> {
        group.clear();
        let first = *self.want_writes.as_slice().first()?;
        let (addr, len) = (first.addr, first.len);
        let cap = group.capacity();
        self.want_writes.retain(|w| {
            if w.addr == addr && w.len == len && group.len() < cap {
                group.push((w.cred.id as u8, w.value));
                false
            } else {
                true
            }
        });
        Some((addr, len))
    }

    /// Counts writes that could not be encoded or sent.
    pub fn drop_writes(&mut self, n: usize) {
        self.counters.dropped_requests += n as u64;
    }

    /// Plans the next read transaction: the devices with queued reads (only one, round robin,
    /// when `single`), each reading the smallest span covering its requests. Fills `entries`
    /// and returns the shape, or `None` when nothing is to be read.
    pub fn plan_reads(&mut self, single: bool, entries: &mut Vec<Entry>) -> Option<ReadShape> {
        entries.clear();
        let cap = entries.capacity();
        if single {
            // The queued device with the smallest ID at or after the cursor, wrapping.
            let ids = self.want_reads.as_slice().iter().map(|w| w.cred.id as u8);
            let pick = ids
                .clone()
                .filter(|&i| i >= self.rr)
                .min()
                .or_else(|| ids.min())?;
            self.rr = pick.wrapping_add(1);
            entries.push(self.span_of(pick));
        } else {
            for w in self.want_reads.as_slice() {
                let id = w.cred.id as u8;
                if entries.len() < cap && !entries.iter().any(|e| e.id == id) {
                    entries.push(Entry {
                        id,
                        addr: 0,
                        len: 0,
                        done: false,
                    });
                }
            }
            for e in entries.iter_mut() {
                *e = self.span_of(e.id);
            }
        }
        let first = *entries.first()?;
        Some(
            if entries
                .iter()
                .all(|e| e.addr == first.addr && e.len == first.len)
            {
                ReadShape::Uniform
            } else {
                ReadShape::Mixed
            },
        )
    }

    fn span_of(&self, id: u8) -> Entry {
        let mine = || {
            self.want_reads
                .as_slice()
                .iter()
                .filter(move |w| w.cred.id as u8 == id)
        };
        let addr = mine().map(|w| w.addr).min().unwrap_or(0);
        let end = mine().map(Waiter::end).max().unwrap_or(0);
        Entry {
            id,
            addr,
            len: end - addr,
            done: false,
        }
    }

    /// Reads planned in `entries` that cannot be sent (encoding failed, no room): their
    /// requests are answered `Missing` and counted as dropped.
    pub fn abandon_reads(&mut self, entries: &[Entry]) {
        let Self {
            want_reads,
            early,
            counters,
            ..
        } = self;
        want_reads.retain(|w| {
            if !entries.iter().any(|e| e.id == w.cred.id as u8) {
                return true;
            }
            counters.dropped_requests += 1;
            let _ = early.push(w.missing());
            false
        });
    }

    /// Records that the transaction for `entries` went out at `now_ns` with `tx_bytes`
    /// instruction bytes, expecting `reply_bytes` in `replies` status packets. Moves the
    /// requests into it.
    pub fn start_txn(
        &mut self,
        entries: &[Entry],
        fast: bool,
        now_ns: u64,
        tx_bytes: usize,
        reply_bytes: usize,
        replies: usize,
    ) {
        let t = self.timing;
        let end =
            now_ns + wire_ns(tx_bytes + reply_bytes, t.baud) + replies as u64 * t.return_delay_ns;
        self.bus_free_at = self.bus_free_at.max(end);
        // A full table (the decoder has not run for a while): the oldest is given up.
        let slot = match self.txns.iter().position(|x| !x.active) {
            Some(i) => i,
            None => {
                let oldest = (0..TXNS).min_by_key(|&i| self.txns[i].seq).unwrap_or(0);
                self.counters.missing_replies += self.txns[oldest].close_missing(&mut self.early);
                oldest
            }
        };
        self.next_seq += 1;
        let seq = self.next_seq;
        let Self {
            txns, want_reads, ..
        } = self;
        let x = &mut txns[slot];
        x.active = true;
        x.seq = seq;
        x.fast = fast;
        x.t_sent_ns = now_ns;
        x.deadline_ns = end + t.timeout_ns;
        x.entries.clear();
        x.entries.extend_from_slice(entries);
        x.waiters.clear();
        let cap = x.waiters.capacity();
        want_reads.retain(|w| {
            let Some(i) = entries.iter().position(|e| e.id == w.cred.id as u8) else {
                return true;
            };
            if x.waiters.len() < cap {
                x.waiters.push((i, *w));
            }
            false
        });
    }

    /// Records writes/other packets that occupy the wire for `bytes` bytes without replies.
    pub fn occupy(&mut self, now_ns: u64, bytes: usize) {
        let start = self.bus_free_at.max(now_ns);
        self.bus_free_at = start + wire_ns(bytes, self.timing.baud);
    }

    /// The open fast-read transaction expecting a combined reply, oldest first: its entry
    /// lengths, to split the reply.
    pub fn fast_lens(&self, out: &mut Vec<usize>) -> bool {
        out.clear();
        let Some(x) = self.oldest_active(|x| x.fast) else {
            return false;
        };
        out.extend(x.entries.iter().map(|e| e.len as usize));
        true
    }

    fn oldest_active(&self, pred: impl Fn(&Txn) -> bool) -> Option<&Txn> {
        self.txns
            .iter()
            .filter(|x| x.active && pred(x))
            .min_by_key(|x| x.seq)
    }

    /// A status packet from `id`, in wire order; counted as unsolicited if nobody was waiting
    /// for it.
    pub fn on_status(&mut self, id: u8, err: StatusErr, data: &[u8], out: &mut Bounded<Reply>) {
        if !self.match_status(id, err, data, out) {
            self.unsolicited += 1;
        }
    }

    /// [`on_status`](Self::on_status); false if nobody was waiting for the packet.
    fn match_status(
        &mut self,
        id: u8,
        err: StatusErr,
        data: &[u8],
        out: &mut Bounded<Reply>,
    ) -> bool {
        // The oldest open transaction still expecting `id`.
        let found = self
            .txns
            .iter()
            .enumerate()
            .filter(|(_, x)| x.active && x.entries.iter().any(|e| e.id == id && !e.done))
            .min_by_key(|(_, x)| x.seq)
            .map(|(i, x)| (i, x.seq));
        let Some((slot, seq)) = found else {
            return false;
        };
        // Replies come in wire order: older transactions will get nothing more.
        for i in 0..TXNS {
            if self.txns[i].active && self.txns[i].seq < seq {
                self.counters.missing_replies += self.txns[i].close_missing(out);
            }
        }
        let x = &mut self.txns[slot];
        let Some(ei) = x.entries.iter().position(|e| e.id == id && !e.done) else {
            return false;
        };
        let e = x.entries[ei];
        if !err.failed && data.len() != e.len as usize {
            // A well-formed packet of the wrong size: not the answer to this request.
            return false;
        }
        x.entries[ei].done = true;
        self.counters.packets_in += 1;
        let t_sample = x.t_sent_ns;
        if err.failed || err.alert {
            self.counters.device_errors += 1;
        }
        let mut first = true;
        for &(wi, w) in &x.waiters {
            if wi != ei {
                continue;
            }
            if (err.failed || err.alert) && first {
                let _ = out.push(Reply {
                    cred: w.cred,
                    data: ReplyData::DeviceError {
                        code: err.code as u32,
                    },
                    tick: w.tick,
                    t_sample_ns: t_sample,
                });
                first = false;
            }
            let data = if err.failed {
                ReplyData::Missing { op: w.op() }
            } else {
                let off = (w.addr - e.addr) as usize;
                let mut v = 0u64;
                for (k, b) in data[off..off + w.len as usize].iter().enumerate() {
                    v |= (*b as u64) << (8 * k);
                }
                ReplyData::Register {
                    addr: w.addr,
                    len: w.len,
                    value: v as i64,
                }
            };
            let _ = out.push(Reply {
                cred: w.cred,
                data,
                tick: w.tick,
                t_sample_ns: t_sample,
            });
        }
        if x.entries.iter().all(|e| e.done) {
            x.active = false;
        }
        true
    }

    /// Reports what could not be sent and the transactions past their deadline. Returns
    /// whether a transaction expired (the line is quiet for it).
    pub fn expire(&mut self, now_ns: u64, out: &mut Bounded<Reply>) -> bool {
        for r in self.early.as_slice() {
            let _ = out.push(*r);
        }
        self.early.clear();
        let mut any = false;
        for x in &mut self.txns {
            if x.active && x.deadline_ns <= now_ns {
                self.counters.missing_replies += x.close_missing(out);
                any = true;
            }
        }
        any
    }

    /// The earliest deadline of an open transaction.
    pub fn next_deadline(&self) -> Option<u64> {
        self.txns
            .iter()
            .filter(|x| x.active)
            .map(|x| x.deadline_ns)
            .min()
    }

    /// Whether any transaction is open.
    pub fn any_open(&self) -> bool {
        self.txns.iter().any(|x| x.active)
    }
}

impl Txn {
    /// Closes the transaction, answering every request still waiting with `Missing`; returns
    /// how many.
    fn close_missing(&mut self, out: &mut Bounded<Reply>) -> u64 {
        let mut n = 0;
        for &(wi, w) in &self.waiters {
            if self.entries[wi].done {
                continue;
            }
            n += 1;
            let _ = out.push(w.missing());
        }
        self.active = false;
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_time_is_ten_bits_per_byte() {
        assert_eq!(wire_ns(100, 1_000_000), 1_000_000);
        assert_eq!(wire_ns(1, 4_000_000), 2_500);
        assert_eq!(wire_ns(3, 3), 10_000_000_000);
    }
}
