//! The machinery shared by the register-mapped UART protocols (Dynamixel 2.0 and 1.0): what
//! devices want read and written, the transactions on the half-duplex bus, and matching status
//! packets back to the requests that caused them.
//!
//! * Requests that arrive while the bus is busy stay queued (the thesis' tick cache) and are
//!   **coalesced**: a newer write to the same register replaces the older one; repeated reads of
//!   the same register share one bus read, and every one of them is answered (by its value, or
//!   `Missing`). When more reads pile up than the stage has room for, the excess is answered
//!   `Missing` at once and counted as dropped.
//! * A transaction is one instruction that expects status packets: a read (SYNC/FAST SYNC/BULK/
//!   FAST BULK READ, or a single READ), a PING or a REBOOT. Status packets arrive in wire order,
//!   so a reply for a newer transaction closes the older ones.
//! * **One transaction on the bus at a time.** Nothing is sent (no write either, it would
//!   collide with a reply) while a transaction's replies may still come: until they have all
//!   been decoded (the link decodes what arrived before it encodes) or its deadline (expected
//!   end from the wire time at the configured baud and the return delays, plus the timeout) has
//!   passed. When replies were missing at the deadline, the line must also have been quiet for
//!   one more timeout before the next transaction, so a late reply cannot be taken for the
//!   answer to the next one.
//! * **Late replies are counted and dropped.** At its deadline a transaction's unanswered
//!   requests are reported [`ReplyData::Missing`] (never invented), but the transaction stays
//!   matchable until the next one starts: a status packet that comes meanwhile is a late reply,
//!   counted in `late_replies` and never delivered with a wrong sample time, and it keeps the
//!   line from counting as quiet. A reply also never answers a transaction whose instruction was
//!   not on the wire before it arrived (the link's fence). What remains: a reply later than the
//!   timeout plus the quiet guard that arrives after the next instruction was sent cannot be
//!   told from that instruction's answer (a status packet carries no sequence number); the
//!   timeout must cover the adapter's latency (see `timeout_us`).

use crate::component::ProtocolCounters;
use crate::message::{Credential, Op, Reply, ReplyData, Request};
use crate::queue::Bounded;

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

/// What a transaction asks a device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Ask {
    /// Read `len` bytes at `addr`.
    Read,
    /// PING (model number and firmware where the protocol returns them).
    Ping,
    /// REBOOT.
    Reboot,
}

/// One request waiting for its answer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Waiter {
    pub cred: Credential,
    pub ask: Ask,
    pub addr: u16,
    pub len: u8,
    pub tick: u64,
    pub t_request_ns: u64,
}

impl Waiter {
    fn op(&self) -> Op {
        match self.ask {
            Ask::Read => Op::Read {
                addr: self.addr,
                len: self.len,
            },
            Ask::Ping => Op::Ping,
            Ask::Reboot => Op::Reboot,
        }
    }

    fn end(&self) -> u16 {
        self.addr + self.len as u16
    }

    /// The answer that this request went unanswered.
    fn missing(&self) -> Reply {
        Reply::missing(self.cred, self.op(), self.tick, self.t_request_ns)
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

/// One device's part of a transaction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Entry {
    pub id: u8,
    pub addr: u16,
    /// Data bytes its status packet carries.
    pub len: u16,
    done: bool,
}

impl Entry {
    /// Whether this entry answers `w` (a PING or REBOOT answers every special of its device).
    fn covers(&self, w: &Waiter, special: bool) -> bool {
        self.id == w.cred.id as u8
            && (special || (w.addr >= self.addr && w.end() <= self.addr + self.len))
    }
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

/// The instruction a transaction sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ReadShape {
    /// A read; every entry has the same address and length.
    Uniform,
    /// A read whose entries differ (bulk read).
    Mixed,
    /// A PING to one device.
    Ping,
    /// A REBOOT of one device.
    Reboot,
}

#[derive(Debug)]
struct Txn {
    active: bool,
    /// Past its deadline: its missing requests were reported; what still comes is late.
    expired: bool,
    seq: u64,
    fast: bool,
    deadline_ns: u64,
    t_sent_ns: u64,
    /// Stream position just after its instruction: replies with a lower fence predate it.
    end_pos: u64,
    entries: Vec<Entry>,
    /// (entry index, waiter).
    waiters: Vec<(usize, Waiter)>,
}

/// Largest gap between two reads of one device that one transaction reads across (bytes): the
/// price of a separate transaction (an instruction and a status packet's framing) is about
/// this much.
const MAX_SPAN_GAP: u16 = 64;

/// Most transactions tracked at once: the one on the bus and the expired ones whose late replies
/// may still come.
const TXNS: usize = 8;
/// An expired transaction is forgotten once the line has been silent this long (ns).
const FORGET_QUIET_NS: u64 = 100_000_000;

/// The shared state of a register-bus protocol stage.
#[derive(Debug)]
pub(crate) struct Core {
    timing: Timing,
    max_id: u8,
    /// Data bytes of a PING status packet (3 in 2.0: model and firmware; 0 in 1.0).
    ping_len: u16,
    want_reads: Bounded<Waiter>,
    /// Pings and reboots, one per transaction.
    want_specials: Bounded<Waiter>,
    want_writes: Bounded<WriteReq>,
    /// Replies decided at encode time (requests that cannot be sent), handed out at expire.
    early: Bounded<Reply>,
    txns: Vec<Txn>,
    next_seq: u64,
    bus_free_at: u64,
    /// After missing replies: nothing is sent before the line has been quiet until then.
    quiet_until: u64,
    /// Everything that reached the host before this time has been decoded (`None`: the
    /// hardware delivers at once). A quiet line means little while bytes may still be on
    /// their way through the OS: see [`line_drained`](Self::line_drained).
    drained_ns: Option<u64>,
    last_rx_ns: u64,
    rr: u8,
    pub counters: ProtocolCounters,
    /// Valid status packets nobody was waiting for (duplicated or foreign).
    pub unsolicited: u64,
}

impl Core {
    /// Room for `devices` devices and `in_flight` read requests; a PING's status carries
    /// `ping_len` data bytes.
    pub fn new(
        timing: Timing,
        max_id: u8,
        devices: usize,
        in_flight: usize,
        ping_len: u16,
    ) -> Self {
        let devices = devices.max(1);
        let in_flight = in_flight.max(devices);
        Self {
            timing,
            max_id,
            ping_len,
            want_reads: Bounded::with_capacity(in_flight),
            want_specials: Bounded::with_capacity(2 * devices),
            want_writes: Bounded::with_capacity(in_flight),
            early: Bounded::with_capacity(in_flight + 2 * devices),
            txns: (0..TXNS)
                .map(|_| Txn {
                    active: false,
                    expired: false,
                    seq: 0,
                    fast: false,
                    deadline_ns: 0,
                    t_sent_ns: 0,
                    end_pos: 0,
                    entries: Vec::with_capacity(devices),
                    waiters: Vec::with_capacity(in_flight),
                })
                .collect(),
            next_seq: 0,
            bus_free_at: 0,
            quiet_until: 0,
            drained_ns: None,
            last_rx_ns: 0,
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
            let waiter = |ask, addr, len| Waiter {
                cred: r.cred,
                ask,
                addr,
                len,
                tick: r.tick,
                t_request_ns: r.t_request_ns,
            };
            match r.op {
                Op::Read { addr, len } if len > 0 && addr.checked_add(len as u16).is_some() => {
                    // A read of a register already queued shares its bus read: both requests
                    // are answered by the one value (it is kept as its own waiter).
                    if self.want_reads.push(waiter(Ask::Read, addr, len)).is_err() {
                        self.refuse(r);
                    }
                }
                Op::Ping | Op::Reboot => {
                    let ask = if r.op == Op::Ping {
                        Ask::Ping
                    } else {
                        Ask::Reboot
                    };
                    if self.want_specials.push(waiter(ask, 0, 0)).is_err() {
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
        if matches!(r.op, Op::Read { .. } | Op::Ping | Op::Reboot) {
            let _ = self
                .early
                .push(Reply::missing(r.cred, r.op, r.tick, r.t_request_ns));
        }
    }

    /// Whether the bus is free at `now`: the previous transaction's replies are all in (or it
    /// expired and the line has been quiet since), and a table slot is free.
    pub fn bus_free(&self, now_ns: u64) -> bool {
        now_ns >= self.bus_free_at
            && now_ns >= self.quiet_until
            && self.drained_ns.is_none_or(|d| d >= self.quiet_until)
            && !self.txns.iter().any(|x| x.active && !x.expired)
            && self.txns.iter().any(|x| !x.active)
    }

    pub fn has_work(&self) -> bool {
        !self.want_reads.is_empty()
            || !self.want_writes.is_empty()
            || !self.want_specials.is_empty()
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

    /// Plans the next transaction: a queued PING or REBOOT first (one device), else a read of
    /// the devices with queued reads (only one, round robin, when `single`), each reading the
    /// smallest span covering its requests. Fills `entries` and returns the shape, or `None`
    /// when nothing is to be asked.
    pub fn plan_reads(&mut self, single: bool, entries: &mut Vec<Entry>) -> Option<ReadShape> {
        entries.clear();
        let cap = entries.capacity();
        if let Some(w) = self.want_specials.as_slice().first() {
            let (len, shape) = match w.ask {
                Ask::Ping => (self.ping_len, ReadShape::Ping),
                _ => (0, ReadShape::Reboot),
            };
            entries.push(Entry {
                id: w.cred.id as u8,
                addr: 0,
                len,
                done: false,
            });
            return Some(shape);
        }
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

    /// The span read from `id` this transaction: from its lowest queued address, growing over
    /// the queued reads that start within [`MAX_SPAN_GAP`] bytes of it. Reads further away
    /// (a configuration register and the present position, queued together during
    /// bring-up) wait for the next transaction rather than being read with everything in
    /// between: a long status packet is long on the wire and, on a noisy line, rarely
    /// arrives whole.
    fn span_of(&self, id: u8) -> Entry {
        let mine = || {
            self.want_reads
                .as_slice()
                .iter()
                .filter(move |w| w.cred.id as u8 == id)
        };
        let addr = mine().map(|w| w.addr).min().unwrap_or(0);
        let mut end = addr;
        loop {
            let grown = mine()
                .filter(|w| w.addr <= end + MAX_SPAN_GAP)
                .map(Waiter::end)
                .max()
                .unwrap_or(end)
                .max(end);
            if grown == end {
                break;
            }
            end = grown;
        }
        Entry {
            id,
            addr,
            len: end - addr,
            done: false,
        }
    }

    /// A planned transaction that cannot be sent (encoding failed, no room): its requests are
    /// answered `Missing` and counted as dropped.
    pub fn abandon(&mut self, entries: &[Entry], shape: ReadShape) {
        let Self {
            want_reads,
            want_specials,
            early,
            counters,
            ..
        } = self;
        let special = matches!(shape, ReadShape::Ping | ReadShape::Reboot);
        let queue = if special { want_specials } else { want_reads };
        let mut taken = false;
        queue.retain(|w| {
            if (special && taken) || !entries.iter().any(|e| e.covers(w, special)) {
                return true;
            }
            taken = true;
            counters.dropped_requests += 1;
            let _ = early.push(w.missing());
            false
        });
    }

    /// Records that the transaction for `entries` went out at `now_ns` with `tx_bytes`
    /// instruction bytes ending at stream position `end_pos`, expecting `reply_bytes` in
    /// `replies` status packets. Moves its requests into it.
    #[allow(clippy::too_many_arguments)]
    pub fn start_txn(
        &mut self,
        entries: &[Entry],
        shape: ReadShape,
        fast: bool,
        now_ns: u64,
        end_pos: u64,
        tx_bytes: usize,
        reply_bytes: usize,
        replies: usize,
    ) {
        let t = self.timing;
        let end =
            now_ns + wire_ns(tx_bytes + reply_bytes, t.baud) + replies as u64 * t.return_delay_ns;
        self.bus_free_at = self.bus_free_at.max(end);
        // The line was quiet since the expired ones: what comes now answers this one.
        for x in &mut self.txns {
            if x.expired {
                x.active = false;
            }
        }
        let slot = self.txns.iter().position(|x| !x.active).unwrap_or(0);
        self.next_seq += 1;
        let seq = self.next_seq;
        let special = matches!(shape, ReadShape::Ping | ReadShape::Reboot);
        let queue = match shape {
            ReadShape::Ping | ReadShape::Reboot => &mut self.want_specials,
            _ => &mut self.want_reads,
        };
        let x = &mut self.txns[slot];
        x.active = true;
        x.expired = false;
        x.seq = seq;
        x.fast = fast;
        x.t_sent_ns = now_ns;
        x.end_pos = end_pos;
        x.deadline_ns = end + t.timeout_ns;
        x.entries.clear();
        x.entries.extend_from_slice(entries);
        x.waiters.clear();
        let cap = x.waiters.capacity();
        let mut taken = false;
        queue.retain(|w| {
            if special && taken {
                return true;
            }
            let Some(i) = entries.iter().position(|e| e.covers(w, special)) else {
                return true;
            };
            taken = true;
            if x.waiters.len() < cap {
                x.waiters.push((i, *w));
            }
            false
        });
    }

    /// Records writes or other packets that occupy the wire for `bytes` bytes without replies.
    pub fn occupy(&mut self, now_ns: u64, bytes: usize) {
        let start = self.bus_free_at.max(now_ns);
        self.bus_free_at = start + wire_ns(bytes, self.timing.baud);
    }

    /// The open fast-read transaction expecting a combined reply that arrived at `fence`,
    /// oldest first: its entry lengths, to split the reply.
    pub fn fast_lens(&self, fence: u64, out: &mut Vec<usize>) -> bool {
        out.clear();
        let Some(x) = self
            .txns
            .iter()
            .filter(|x| {
                x.active && x.fast && x.end_pos <= fence && x.entries.iter().any(|e| !e.done)
            })
            .min_by_key(|x| x.seq)
        else {
            return false;
        };
        out.extend(x.entries.iter().map(|e| e.len as usize));
        true
    }

    /// Every byte that reached the host before `t_ns` has been decoded. After missing replies
    /// the next transaction waits for this to pass the quiet time too: a reply held up in the
    /// OS (a tty's receive worker kept off the CPU) would otherwise surface after the line
    /// looked quiet and be taken for the next transaction's answer, with the same IDs and
    /// lengths: an old value published as new.
    pub fn line_drained(&mut self, t_ns: u64) {
        self.drained_ns = Some(self.drained_ns.map_or(t_ns, |d| d.max(t_ns)));
    }

    /// Bytes arrived at `now_ns`.
    pub fn heard(&mut self, now_ns: u64) {
        self.last_rx_ns = now_ns;
        // While a reply may still be late, a talking line is not quiet.
        if self.txns.iter().any(|x| x.active && x.expired) {
            self.quiet_until = self.quiet_until.max(now_ns + self.timing.timeout_ns);
        }
    }

    /// A status packet from `id` that arrived at `fence`, in wire order; counted as
    /// unsolicited if nobody was waiting for it.
    pub fn on_status(
        &mut self,
        id: u8,
        err: StatusErr,
        data: &[u8],
        fence: u64,
        out: &mut Bounded<Reply>,
    ) {
        if !self.match_status(id, err, data, fence, out) {
            self.unsolicited += 1;
        }
    }

    /// [`on_status`](Self::on_status); false if nobody was waiting for the packet.
    fn match_status(
        &mut self,
        id: u8,
        err: StatusErr,
        data: &[u8],
        fence: u64,
        out: &mut Bounded<Reply>,
    ) -> bool {
        // The oldest transaction, sent before this packet arrived, still expecting `id`.
        let found = self
            .txns
            .iter()
            .enumerate()
            .filter(|(_, x)| {
                x.active && x.end_pos <= fence && x.entries.iter().any(|e| e.id == id && !e.done)
            })
            .min_by_key(|(_, x)| x.seq)
            .map(|(i, x)| (i, x.seq));
        let Some((slot, seq)) = found else {
            return false;
        };
        let x = &self.txns[slot];
        let Some(ei) = x.entries.iter().position(|e| e.id == id && !e.done) else {
            return false;
        };
        let e = x.entries[ei];
        if !err.failed && data.len() != e.len as usize {
            // A well-formed packet of the wrong size: not the answer to this request.
            return false;
        }
        // Replies come in wire order: older transactions will get nothing more.
        for i in 0..TXNS {
            let old = &mut self.txns[i];
            if old.active && old.seq < seq {
                if old.expired {
                    old.active = false;
                } else {
                    self.counters.missing_replies += old.close_missing(out);
                }
            }
        }
        let x = &mut self.txns[slot];
        x.entries[ei].done = true;
        if x.entries.iter().all(|e| e.done) {
            x.active = false;
        }
        if x.expired {
            // Its requests were already reported missing: this value's time is unknown.
            self.counters.late_replies += 1;
            return true;
        }
        self.counters.packets_in += 1;
        let t_sample = x.t_sent_ns;
        if err.failed || err.alert {
            self.counters.device_errors += 1;
        }
        for &(wi, w) in &x.waiters {
            if wi != ei {
                continue;
            }
            if err.failed || err.alert {
                // Before each answer the packet carries (requests of several ticks may share
                // it): the device flags exactly the values that came with the error.
                let _ = out.push(Reply::answer(
                    w.cred,
                    w.op(),
                    ReplyData::DeviceError {
                        code: err.code as u32,
                    },
                    w.tick,
                    t_sample,
                ));
            }
            let data = if err.failed {
                ReplyData::Missing { op: w.op() }
            } else {
                match w.ask {
                    Ask::Read => {
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
                    }
                    Ask::Ping => match data {
                        [m0, m1, fw, ..] => ReplyData::Ping {
                            model: Some(u16::from_le_bytes([*m0, *m1])),
                            firmware: Some(*fw),
                        },
                        _ => ReplyData::Ping {
                            model: None,
                            firmware: None,
                        },
                    },
                    Ask::Reboot => ReplyData::Ack,
                }
            };
            let _ = out.push(Reply::answer(w.cred, w.op(), data, w.tick, t_sample));
        }
        true
    }

    /// Reports what could not be sent and the transactions past their deadline; forgets expired
    /// ones once the line has been silent long enough.
    pub fn expire(&mut self, now_ns: u64, out: &mut Bounded<Reply>) {
        for r in self.early.as_slice() {
            let _ = out.push(*r);
        }
        self.early.clear();
        for i in 0..TXNS {
            let x = &mut self.txns[i];
            if !x.active {
                continue;
            }
            if !x.expired && x.deadline_ns <= now_ns {
                let n = x.close_missing(out);
                self.counters.missing_replies += n;
                // Keep it matchable: what still comes for it is late.
                x.active = true;
                x.expired = true;
                self.quiet_until = self.quiet_until.max(now_ns + self.timing.timeout_ns);
            } else if x.expired
                && now_ns.saturating_sub(x.deadline_ns) >= FORGET_QUIET_NS
                && now_ns.saturating_sub(self.last_rx_ns) >= FORGET_QUIET_NS
            {
                x.active = false;
            }
        }
    }

    /// The earliest deadline of a transaction still waiting for replies.
    pub fn next_deadline(&self) -> Option<u64> {
        self.txns
            .iter()
            .filter(|x| x.active && !x.expired)
            .map(|x| x.deadline_ns)
            .min()
    }

    /// Whether any transaction is waiting for replies.
    pub fn any_open(&self) -> bool {
        self.txns.iter().any(|x| x.active && !x.expired)
    }

    /// Drops every queued request not yet sent (reads answered `Missing`, counted dropped).
    pub fn preempt(&mut self) {
        let n = self.want_writes.len() as u64;
        self.want_writes.clear();
        self.counters.dropped_requests += n;
        for q in [&mut self.want_reads, &mut self.want_specials] {
            for w in q.as_slice() {
                let _ = self.early.push(w.missing());
            }
            self.counters.dropped_requests += q.len() as u64;
            q.clear();
        }
    }

    /// The bus is gone: everything queued or in flight is answered `Missing`; the stage starts
    /// afresh.
    pub fn reset(&mut self, out: &mut Bounded<Reply>) {
        self.preempt();
        for r in self.early.as_slice() {
            let _ = out.push(*r);
        }
        self.early.clear();
        for x in &mut self.txns {
            if x.active && !x.expired {
                self.counters.missing_replies += x.close_missing(out);
            }
            x.active = false;
        }
        self.bus_free_at = 0;
        self.quiet_until = 0;
    }
}

impl Txn {
    /// Answers every request still waiting with `Missing` and closes the transaction;
    /// returns how many.
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
