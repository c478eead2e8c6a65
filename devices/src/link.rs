//! [`Link`]: a protocol bound to the hardware of one bus, with the fixed-capacity queues between
//! them, the causality fence that matches replies to the requests that caused them, urgent
//! traffic (safe actions ahead of anything queued), and reconnection when the bus vanishes.
//!
//! One base tick of a link, as the executor drives it:
//!
//! ```text
//! receive   hardware tick: take what the bus delivered BEFORE anything new is sent
//!           (those words cannot answer this tick's requests: their fence says so)
//! encode    protocol tick: decode what was received, so the protocol knows which
//!           transactions are done, then bundle the queued requests into words
//! exchange  hardware tick: send the words, take what arrived meanwhile
//! decode    protocol tick: decode the rest, expire what is overdue → replies
//! ```
//!
//! **Fence.** Words are numbered in the order the protocol appended them. Every received word
//! carries the number of appended words known to be on the bus when it arrived: the words the
//! hardware had taken, minus those it reports unconfirmed ([`Hardware::rx_unconfirmed`]: an
//! SLCAN adapter's pending acknowledgements). A reply never answers a request sent after it.
//!
//! **Reconnection.** When the hardware reports [`HwError::Disconnected`] (USB unplug, closed pty,
//! CAN interface removed or down), the link goes [`LinkState::Down`]: the protocol answers every
//! request in flight `Missing`, and the dead hardware goes to a helper thread that drops it and
//! reopens the bus with exponential back-off (10 ms doubling to 1 s). The real-time thread
//! never waits for it: each tick it only checks (without blocking or allocating) whether a fresh
//! hardware has arrived, and the link is [`LinkState::Up`] again from that tick.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TryRecvError};
use std::sync::Arc;
use std::time::Duration;

use nix::errno::Errno;

use crate::component::{
    BusCondition, Hardware, HwCounters, HwError, Protocol, ProtocolCounters, TickCtx,
};
use crate::message::{Reply, Request};
use crate::queue::Bounded;

/// Whether a link's bus is there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkState {
    /// Open and working.
    Up,
    /// Vanished at `since_ns`; being reopened.
    Down {
        /// CLOCK_MONOTONIC when it went down.
        since_ns: u64,
        /// The error that took it down, where the OS gave one.
        cause: Option<Errno>,
    },
}

/// Everything a link counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LinkCounters {
    /// The protocol's counters.
    pub protocol: ProtocolCounters,
    /// The hardware's counters (summed over every hardware the link has had).
    pub hardware: HwCounters,
    /// Transport errors that did not take the bus down.
    pub io_errors: u64,
    /// The newest of those, as the OS numbered it (`None` for a full transmit side, which has no
    /// number): kept typed, so the cause of `io_errors` is not lost.
    pub last_io_error: Option<Errno>,
    /// Times the bus vanished.
    pub outages: u64,
    /// Times it was reopened.
    pub reconnects: u64,
    /// Words dropped unsent (superseded, or cleared by an error or an urgent action).
    pub dropped_words: u64,
}

impl LinkCounters {
    /// What the executor reports as bus errors.
    pub fn bus_errors(&self) -> u64 {
        self.protocol.bus_errors() + self.hardware.errors() + self.io_errors
    }
}

/// A protocol bound to its hardware, with the queues between them: what the executor schedules.
pub trait Link {
    /// Hardware tick, first half: take what the bus delivered before anything new is sent.
    fn receive(&mut self, ctx: TickCtx);
    /// Protocol tick, downstream: decode what was received, then bundle the queued requests.
    fn encode(&mut self, requests: &[Request], ctx: TickCtx);
    /// Hardware tick, second half: send pending words, collect what arrived meanwhile. An error
    /// is returned once, when it happens (a vanished bus is then [`LinkState::Down`]).
    fn exchange(&mut self, ctx: TickCtx) -> Result<(), HwError>;
    /// Protocol tick, upstream: decode received words and expire overdue requests.
    fn decode(&mut self, out: &mut Bounded<Reply>, ctx: TickCtx);
    /// Urgent requests follow (a safe action): drop everything queued and unsent.
    fn preempt(&mut self);
    /// Whether every word has left and been confirmed where the hardware confirms.
    fn flushed(&self) -> bool;
    /// Whether the bus is there.
    fn state(&self) -> LinkState;
    /// What the hardware reports about its bus (controller state, a full transmit queue);
    /// the default condition while the bus is down.
    fn condition(&self) -> BusCondition {
        BusCondition::default()
    }
    /// Counters since start.
    fn counters(&self) -> LinkCounters;
    /// Quiets the hardware (flush, close) at the end.
    fn shutdown(&mut self);
}

/// How to reopen a vanished bus.
pub struct Opener<H> {
    /// Opens the port, interface or adapter again.
    pub open: Box<dyn FnMut() -> Result<H, String> + Send>,
    /// A cheap check that the bus is back (its device node or interface exists), polled every
    /// 10 ms between attempts: the back-off limits failing opens, not how soon a returning bus
    /// is noticed.
    pub present: Box<dyn Fn() -> bool + Send>,
}

/// The helper thread that drops a dead hardware and opens a fresh one with back-off.
struct Reopener<H> {
    /// Dead hardware in, one at a time.
    dead: SyncSender<H>,
    /// Fresh hardware out.
    fresh: Receiver<H>,
    stop: Arc<AtomicBool>,
    attempts: Arc<AtomicU64>,
}

impl<H: Send + 'static> Reopener<H> {
    const FIRST: Duration = Duration::from_millis(10);
    const MAX: Duration = Duration::from_secs(1);

    const POLL: Duration = Duration::from_millis(10);

    fn spawn(name: &str, mut opener: Opener<H>) -> std::io::Result<Self> {
        // Capacity 1 each way: the array flavour is preallocated, so the real-time side's
        // try_send/try_recv neither allocate nor lock.
        let (dead_tx, dead_rx) = mpsc::sync_channel::<H>(1);
        let (fresh_tx, fresh_rx) = mpsc::sync_channel::<H>(1);
        let stop = Arc::new(AtomicBool::new(false));
        let attempts = Arc::new(AtomicU64::new(0));
        let (st, at) = (stop.clone(), attempts.clone());
        std::thread::Builder::new()
            .name(format!("reopen-{name}"))
            .spawn(move || {
                while let Ok(old) = dead_rx.recv() {
                    drop(old);
                    let mut wait = Self::FIRST;
                    loop {
                        if st.load(Ordering::Relaxed) {
                            return;
                        }
                        at.fetch_add(1, Ordering::Relaxed);
                        if let Ok(h) = (opener.open)() {
                            if fresh_tx.send(h).is_err() {
                                return;
                            }
                            break;
                        }
                        // Back off, but try at once when the bus reappears.
                        let absent = !(opener.present)();
                        let mut slept = Duration::ZERO;
                        while slept < wait && !st.load(Ordering::Relaxed) {
                            std::thread::sleep(Self::POLL);
                            slept += Self::POLL;
                            if absent && (opener.present)() {
                                break;
                            }
                        }
                        wait = (wait * 2).min(Self::MAX);
                    }
                }
            })?;
        Ok(Self {
            dead: dead_tx,
            fresh: fresh_rx,
            stop,
            attempts,
        })
    }
}

impl<H> Drop for Reopener<H> {
    fn drop(&mut self) {
        // The thread ends at its next attempt (or at once, when it waits for a dead hardware
        // and its sender goes away with us); nobody waits for it.
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// [`Link`] over any protocol/hardware pair that share a word type.
pub struct LinkOf<P: Protocol, H: Hardware<Word = P::Word>> {
    protocol: P,
    hardware: Option<H>,
    reopen: Option<Reopener<H>>,
    tx: Bounded<P::Word>,
    rx: Bounded<P::Word>,
    rx_fence: Bounded<u64>,
    /// Arrival time of each word in `rx` (0: unknown).
    rx_time: Bounded<u64>,
    rx_buf: Vec<P::Word>,
    /// Replies decoded before `decode` (at `encode`, or from a reset).
    early: Bounded<Reply>,
    /// Stream position of `tx[0]`: words appended so far minus those still queued.
    taken: u64,
    state: LinkState,
    counters: LinkCounters,
    /// Counters of the hardware before the current one (reopened buses).
    past_hw: HwCounters,
}

impl<P: Protocol, H: Hardware<Word = P::Word>> LinkOf<P, H>
where
    P::Word: Default,
{
    /// Binds `protocol` to `hardware` with room for `words` words each way per tick.
    pub fn new(protocol: P, hardware: H, words: usize) -> Self {
        Self::with_fill(protocol, hardware, words, P::Word::default())
    }
}

impl<P: Protocol, H: Hardware<Word = P::Word>> LinkOf<P, H> {
    /// As [`new`](Self::new), for word types without a `Default` (CAN frames): `fill`
    /// initialises the receive buffer.
    pub fn with_fill(protocol: P, hardware: H, words: usize, fill: P::Word) -> Self {
        Self {
            protocol,
            hardware: Some(hardware),
            reopen: None,
            tx: Bounded::with_capacity(words),
            rx: Bounded::with_capacity(words),
            rx_fence: Bounded::with_capacity(words),
            rx_time: Bounded::with_capacity(words),
            rx_buf: vec![fill; words],
            early: Bounded::with_capacity(words.max(64)),
            taken: 0,
            state: LinkState::Up,
            counters: LinkCounters::default(),
            past_hw: HwCounters::default(),
        }
    }

    /// The protocol (for tests and diagnostics).
    pub fn protocol(&self) -> &P {
        &self.protocol
    }

    /// The hardware (for tests and diagnostics); `None` while the bus is down.
    pub fn hardware(&self) -> Option<&H> {
        self.hardware.as_ref()
    }

    /// Attempts to reopen the bus since start.
    pub fn reopen_attempts(&self) -> u64 {
        self.reopen
            .as_ref()
            .map_or(0, |r| r.attempts.load(Ordering::Relaxed))
    }

    fn hw_counters(&self) -> HwCounters {
        let now = self.hardware.as_ref().map(H::counters).unwrap_or_default();
        self.past_hw.plus(&now)
    }

    /// Drops the queued words (counted), keeping the stream numbering.
    fn drop_tx(&mut self) {
        let n = self.tx.len() as u64;
        if n > 0 {
            self.protocol.discard_unsent(self.taken);
            self.taken += n;
            self.counters.dropped_words += n;
            self.tx.clear();
        }
    }

    /// The bus vanished: everything in flight is missing; the hardware goes to be reopened.
    fn go_down(&mut self, cause: Option<Errno>, now_ns: u64) {
        if matches!(self.state, LinkState::Down { .. }) {
            return;
        }
        self.state = LinkState::Down {
            since_ns: now_ns,
            cause,
        };
        self.counters.outages += 1;
        self.drop_tx();
        self.rx.clear();
        self.rx_fence.clear();
        self.rx_time.clear();
        self.protocol.reset(&mut self.early);
        if let Some(h) = self.hardware.take() {
            self.past_hw = self.past_hw.plus(&h.counters());
            match &self.reopen {
                // The helper drops it (closing a port is a system call we keep off this thread).
                Some(r) => {
                    if let Err(mpsc::TrySendError::Full(h) | mpsc::TrySendError::Disconnected(h)) =
                        r.dead.try_send(h)
                    {
                        drop(h);
                    }
                }
                None => drop(h),
            }
        }
    }

    /// Counts an error; a disconnection takes the link down.
    fn on_error(&mut self, e: HwError, now_ns: u64) {
        match e {
            HwError::Disconnected(cause) => self.go_down(cause, now_ns),
            HwError::Io(errno) => {
                self.counters.io_errors += 1;
                self.counters.last_io_error = Some(errno);
            }
            HwError::TxFull { .. } => {
                self.counters.io_errors += 1;
                self.counters.last_io_error = None;
            }
        }
    }

    /// Takes what the hardware has, with each word's fence.
    fn pull(&mut self, ctx: TickCtx) -> Result<(), HwError> {
        let Some(hw) = self.hardware.as_mut() else {
            return Ok(());
        };
        let room = self.rx.remaining().min(self.rx_buf.len());
        if room == 0 {
            return Ok(());
        }
        // Taken before the read: what had reached the host by then is in this read, unless
        // the read filled the room.
        let drained = hw.drained_ns();
        let n = hw.receive(&mut self.rx_buf[..room], ctx)?;
        let unconfirmed = hw.rx_unconfirmed();
        let times = hw.rx_times();
        self.rx.extend_from_slice(&self.rx_buf[..n]);
        for i in 0..n {
            let behind = unconfirmed.get(i).copied().unwrap_or(0) as u64;
            let _ = self.rx_fence.push(self.taken.saturating_sub(behind));
            let _ = self.rx_time.push(times.get(i).copied().unwrap_or(0));
        }
        if let (Some(t), true) = (drained, n < room) {
            self.decode_pending(ctx);
            self.protocol.line_drained(t);
        }
        Ok(())
    }

    /// Decodes what has been received so far into `early`.
    fn decode_pending(&mut self, ctx: TickCtx) {
        if !self.rx.is_empty() {
            self.protocol.decode_timed(
                self.rx.as_slice(),
                self.rx_fence.as_slice(),
                self.rx_time.as_slice(),
                &mut self.early,
                ctx,
            );
            self.rx.clear();
            self.rx_fence.clear();
            self.rx_time.clear();
        }
    }

    /// While down: has the helper opened the bus again?
    fn poll_reopen(&mut self) {
        let Some(r) = &self.reopen else { return };
        match r.fresh.try_recv() {
            Ok(h) => {
                self.hardware = Some(h);
                self.state = LinkState::Up;
                self.counters.reconnects += 1;
            }
            Err(TryRecvError::Empty | TryRecvError::Disconnected) => {}
        }
    }
}

impl<P: Protocol, H: Hardware<Word = P::Word> + Send + 'static> LinkOf<P, H> {
    /// Makes the link reopen its bus with `open` (on a helper thread named after `name`)
    /// whenever the hardware vanishes.
    pub fn with_reopen(mut self, name: &str, open: Opener<H>) -> std::io::Result<Self> {
        self.reopen = Some(Reopener::spawn(name, open)?);
        Ok(self)
    }
}

impl<P: Protocol, H: Hardware<Word = P::Word>> Link for LinkOf<P, H> {
    fn receive(&mut self, ctx: TickCtx) {
        if let Err(e) = self.pull(ctx) {
            self.on_error(e, ctx.now_ns);
        }
    }

    fn encode(&mut self, requests: &[Request], ctx: TickCtx) {
        self.decode_pending(ctx);
        if P::SUPERSEDES_UNSENT {
            self.drop_tx();
        }
        self.protocol.encode(requests, &mut self.tx, ctx);
        if matches!(self.state, LinkState::Down { .. }) {
            // Nothing can be sent: every request is answered Missing at this tick's decode.
            self.drop_tx();
            self.protocol.reset(&mut self.early);
        }
    }

    fn exchange(&mut self, ctx: TickCtx) -> Result<(), HwError> {
        if matches!(self.state, LinkState::Down { .. }) {
            self.poll_reopen();
            return Ok(());
        }
        let mut result = Ok(());
        if !self.tx.is_empty() {
            let sent = match self.hardware.as_mut() {
                Some(hw) => hw.transmit(self.tx.as_slice(), ctx),
                None => Ok(0),
            };
            match sent {
                Ok(n) => {
                    self.tx.consume(n);
                    self.taken += n as u64;
                }
                Err(e) => {
                    // What could not go out now is stale by the next tick.
                    self.drop_tx();
                    self.on_error(e, ctx.now_ns);
                    result = Err(e);
                }
            }
        }
        if result.is_ok() {
            if let Err(e) = self.pull(ctx) {
                self.on_error(e, ctx.now_ns);
                result = Err(e);
            }
        }
        result
    }

    fn decode(&mut self, out: &mut Bounded<Reply>, ctx: TickCtx) {
        for r in self.early.as_slice() {
            let _ = out.push(*r);
        }
        self.early.clear();
        self.protocol.decode_timed(
            self.rx.as_slice(),
            self.rx_fence.as_slice(),
            self.rx_time.as_slice(),
            out,
            ctx,
        );
        self.rx.clear();
        self.rx_fence.clear();
        self.rx_time.clear();
        self.protocol.expire(out, ctx);
    }

    fn preempt(&mut self) {
        self.protocol.preempt();
        if P::SUPERSEDES_UNSENT {
            // Whole frames: safe to drop. (A byte stream's queued packet may be half sent.)
            self.drop_tx();
        }
        if let Some(hw) = self.hardware.as_mut() {
            hw.preempt();
        }
    }

    fn flushed(&self) -> bool {
        self.tx.is_empty() && self.hardware.as_ref().is_none_or(H::flushed)
    }

    fn state(&self) -> LinkState {
        self.state
    }

    fn condition(&self) -> BusCondition {
        self.hardware.as_ref().map(H::condition).unwrap_or_default()
    }

    fn counters(&self) -> LinkCounters {
        LinkCounters {
            protocol: self.protocol.counters(),
            hardware: self.hw_counters(),
            ..self.counters
        }
    }

    fn shutdown(&mut self) {
        if let Some(hw) = self.hardware.as_mut() {
            hw.shutdown();
        }
    }
}
