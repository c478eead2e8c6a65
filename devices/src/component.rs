//! The three components of a link (thesis §2.4) as traits: [`Hardware`], [`Protocol`] (a
//! protocol stage) and [`Device`], with the types they exchange (see docs/vocabulary.md).
//!
//! The executor calls every method here on its real-time thread: implementations must not
//! block, allocate or lock. Buffers are sized when a component is built.

use nix::errno::Errno;

use crate::lifecycle::{DeviceStatus, Startup};
use crate::message::{Credential, Reply, Request, Update};
use crate::queue::Bounded;

/// Timing of the current call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TickCtx {
    /// Executor base tick.
    pub tick: u64,
    /// CLOCK_MONOTONIC now, ns.
    pub now_ns: u64,
}

/// Errors a hardware transport reports. They carry the OS's error number, never formatted
/// text: they are built on the executor's real-time thread, which must not allocate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum HwError {
    /// The OS refused the I/O.
    #[error("I/O error: {0}")]
    Io(#[source] Errno),
    /// The transmit side is full: words were not sent this tick.
    #[error("transmit buffer full ({dropped} words not sent)")]
    TxFull {
        /// Words that did not go out.
        dropped: usize,
    },
    /// The device vanished (unplugged adapter, closed pty, interface removed or down): the
    /// link closes it and reopens it with back-off.
    #[error("device disconnected{}", Cause(*.0))]
    Disconnected(Option<Errno>),
}

impl HwError {
    /// The OS's error number of an I/O error from `std` or a crate over it. The transports'
    /// errors all come from a failed system call (`io::Error::last_os_error`), which carries
    /// its number and was built without allocating; EIO stands in for the impossible rest.
    pub fn errno_of(e: &std::io::Error) -> Errno {
        Errno::from_raw(e.raw_os_error().unwrap_or(libc::EIO))
    }
}

/// " (reason)" after "device disconnected" when the OS gave one; written straight into the
/// formatter, so showing the error allocates nothing either.
struct Cause(Option<Errno>);

impl std::fmt::Display for Cause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0 {
            Some(e) => write!(f, " ({})", e.desc()),
            None => Ok(()),
        }
    }
}

/// Counters a hardware keeps about what it absorbed without failing a call.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct HwCounters {
    /// Frames the adapter refused (SLCAN BEL).
    pub nacks: u64,
    /// Frames the adapter never acknowledged within its timeout.
    pub ack_timeouts: u64,
    /// Error frames reported by the CAN controller.
    pub error_frames: u64,
    /// Bytes from the adapter that were not a valid line or frame.
    pub discarded: u64,
    /// Transmit attempts the OS refused because its queue was full (`ENOBUFS`: a SocketCAN
    /// interface's `txqueuelen` frames waiting); the frames left go with the next tick's.
    pub tx_full: u64,
}

impl HwCounters {
    /// What counts as bus errors.
    pub fn errors(&self) -> u64 {
        self.nacks + self.ack_timeouts + self.error_frames + self.tx_full
    }

    /// The sum of two counters (a link's hardware before and after a reopen).
    pub fn plus(&self, o: &HwCounters) -> HwCounters {
        HwCounters {
            nacks: self.nacks + o.nacks,
            ack_timeouts: self.ack_timeouts + o.ack_timeouts,
            error_frames: self.error_frames + o.error_frames,
            discarded: self.discarded + o.discarded,
            tx_full: self.tx_full + o.tx_full,
        }
    }
}

/// A CAN controller's fault confinement state, as its driver reports it in error frames
/// (`CAN_ERR_CRTL`, `CAN_ERR_BUSOFF`, `CAN_ERR_RESTARTED`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, PartialOrd, Ord)]
pub enum ControllerState {
    /// Error-active: taking part normally (also: no report yet).
    #[default]
    Active,
    /// An error counter passed the warning level (96).
    Warning,
    /// Error-passive (a counter passed 127): it may no longer signal errors actively.
    Passive,
    /// Bus-off (transmit errors passed 255): it takes no part until it is restarted
    /// (`restart-ms`, or `ip link set ... type can restart`).
    BusOff,
}

impl ControllerState {
    /// How the state is named in logs.
    pub fn name(self) -> &'static str {
        match self {
            Self::Active => "error-active",
            Self::Warning => "error-warning",
            Self::Passive => "error-passive",
            Self::BusOff => "bus-off",
        }
    }
}

/// What a working transport reports about its bus besides the words it moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BusCondition {
    /// The CAN controller's state (always `Active` where there is none to report).
    pub controller: ControllerState,
    /// The OS's transmit queue refused the last frames (`ENOBUFS`).
    pub tx_full: bool,
}

/// Gatekeeper to a physical (or simulated) bus: moves words, never interprets them.
///
/// `Word` is the bus's unit: `u8` for UARTs, a CAN frame for CAN, a simulation record for the
/// built-in simulated hardware.
pub trait Hardware {
    /// Unit of transfer.
    type Word: Copy;
    /// Queues `words` for the bus without blocking; returns how many were accepted ("taken").
    fn transmit(&mut self, words: &[Self::Word], ctx: TickCtx) -> Result<usize, HwError>;
    /// Copies whatever the bus has delivered (up to `out.len()`) without blocking.
    fn receive(&mut self, out: &mut [Self::Word], ctx: TickCtx) -> Result<usize, HwError>;
    /// For each word the last [`receive`](Self::receive) returned, how many of the words taken
    /// so far were not yet known to be on the bus when it arrived (an SLCAN adapter confirms
    /// each frame with an acknowledgement, interleaved with the frames it receives). A reply
    /// cannot answer a request that was not on the bus before it: this is the causality fence
    /// the protocol stage matches replies with. Empty: every word taken counts as sent.
    fn rx_unconfirmed(&self) -> &[u32] {
        &[]
    }
    /// For each word the last [`receive`](Self::receive) returned, when it reached this host
    /// (CLOCK_MONOTONIC ns: the kernel's receive timestamp, where the transport has one; 0 or
    /// an empty slice: unknown, the protocol uses its tick's time).
    fn rx_times(&self) -> &[u64] {
        &[]
    }
    /// The bus's condition as the controller and the OS report it.
    fn condition(&self) -> BusCondition {
        BusCondition::default()
    }
    /// A time (CLOCK_MONOTONIC ns) before which every word that reached this host can be
    /// received now, where the OS delivers received words late and the hardware watches for
    /// it (a tty: its bytes pass through a kernel worker before a read can see them). `None`:
    /// whatever arrived is receivable at once.
    fn drained_ns(&self) -> Option<u64> {
        None
    }
    /// Urgent words follow (a safe action): drop the words taken but not yet handed to the OS,
    /// whole words only, and do not hold the next ones back for flow control.
    fn preempt(&mut self) {}
    /// Whether every word taken has left (and, where the adapter confirms, been confirmed).
    fn flushed(&self) -> bool {
        true
    }
    /// Counters of what the hardware absorbed.
    fn counters(&self) -> HwCounters {
        HwCounters::default()
    }
    /// Puts the bus in a quiet state on shutdown (flush, close).
    fn shutdown(&mut self) {}
}

/// A boxed hardware is hardware: what a link built by kind holds, whatever the transport.
impl<H: Hardware + ?Sized> Hardware for Box<H> {
    type Word = H::Word;
    fn transmit(&mut self, words: &[Self::Word], ctx: TickCtx) -> Result<usize, HwError> {
        (**self).transmit(words, ctx)
    }
    fn receive(&mut self, out: &mut [Self::Word], ctx: TickCtx) -> Result<usize, HwError> {
        (**self).receive(out, ctx)
    }
    fn rx_unconfirmed(&self) -> &[u32] {
        (**self).rx_unconfirmed()
    }
    fn rx_times(&self) -> &[u64] {
        (**self).rx_times()
    }
    fn condition(&self) -> BusCondition {
        (**self).condition()
    }
    fn drained_ns(&self) -> Option<u64> {
        (**self).drained_ns()
    }
    fn preempt(&mut self) {
        (**self).preempt()
    }
    fn flushed(&self) -> bool {
        (**self).flushed()
    }
    fn counters(&self) -> HwCounters {
        (**self).counters()
    }
    fn shutdown(&mut self) {
        (**self).shutdown()
    }
}

/// Counters a protocol keeps about its bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ProtocolCounters {
    /// Packets (or frames) sent.
    pub packets_out: u64,
    /// Words sent.
    pub words_out: u64,
    /// Valid packets received.
    pub packets_in: u64,
    /// Words received.
    pub words_in: u64,
    /// Words discarded by the scanner (garbage, bad CRC, truncated, ...).
    pub discarded_words: u64,
    /// Packets rejected (bad CRC, bad header, truncated, ...).
    pub rejected_packets: u64,
    /// Requests that got no valid reply before their deadline.
    pub missing_replies: u64,
    /// Replies from devices reporting an error.
    pub device_errors: u64,
    /// Requests that could not be encoded (e.g. more than fit in a packet this tick).
    pub dropped_requests: u64,
    /// Valid replies that came after their request had been given up (counted, never
    /// delivered: their sample time would be wrong).
    pub late_replies: u64,
}

impl ProtocolCounters {
    /// What the executor reports as bus errors: rejected packets, missing replies and requests
    /// that could not be sent. (Discarded words are reported separately: one corrupted packet
    /// discards many.)
    pub fn bus_errors(&self) -> u64 {
        self.rejected_packets + self.missing_replies + self.dropped_requests
    }
}

/// A vendor's packet format: bundles requests into the fewest packets, and scans received words
/// back into typed replies.
///
/// Words are numbered in the order the protocol appends them (its `words_out` counter); a
/// received word carries a *fence*: the number of appended words known to be on the bus when it
/// arrived. A reply may only answer a request whose words all lie below its fence.
pub trait Protocol {
    /// Unit of transfer; must match the hardware's.
    type Word: Copy;
    /// Words of earlier ticks that the hardware has not taken yet are superseded by this
    /// tick's (CAN motors re-send their whole command every tick): the link drops them before
    /// [`encode`](Self::encode) and tells [`discard_unsent`](Self::discard_unsent).
    const SUPERSEDES_UNSENT: bool = false;
    /// Every request queued since the last protocol tick, in order. Encode them into as few
    /// packets as the protocol allows (one SYNC WRITE for all goal writes, ...), appending the
    /// words to `out`.
    fn encode(&mut self, requests: &[Request], out: &mut Bounded<Self::Word>, ctx: TickCtx);
    /// Words the hardware received, each with its fence; decode into replies.
    fn decode(
        &mut self,
        words: &[Self::Word],
        fence: &[u64],
        out: &mut Bounded<Reply>,
        ctx: TickCtx,
    );
    /// As [`decode`](Self::decode), with each word's arrival time where the hardware knows it
    /// ([`Hardware::rx_times`]; 0 = unknown). Protocols that can use it for sample times
    /// override this; the default ignores the times.
    fn decode_timed(
        &mut self,
        words: &[Self::Word],
        fence: &[u64],
        times: &[u64],
        out: &mut Bounded<Reply>,
        ctx: TickCtx,
    ) {
        let _ = times;
        self.decode(words, fence, out, ctx);
    }
    /// Called after `decode` each protocol tick: report requests whose replies are overdue as
    /// [`crate::ReplyData::Missing`] (never invent a value).
    fn expire(&mut self, out: &mut Bounded<Reply>, ctx: TickCtx);
    /// Counters since start.
    fn counters(&self) -> ProtocolCounters;
    /// The bus was lost: answer every request in flight or queued with `Missing`, forget
    /// partial packets; the protocol starts afresh when the bus returns.
    fn reset(&mut self, out: &mut Bounded<Reply>);
    /// Urgent requests follow (a safe action): drop the queued requests that have not been
    /// encoded yet (reads are answered `Missing`), so the urgent ones go out first.
    fn preempt(&mut self);
    /// The words from stream position `from` on were dropped unsent.
    fn discard_unsent(&mut self, from: u64) {
        let _ = from;
    }
    /// Every word that reached the host before `t_ns` has been received and handed to
    /// [`decode`](Self::decode) (see [`Hardware::drained_ns`]). A protocol whose replies carry
    /// no transaction tag waits for this before asking again after replies went missing, so
    /// that a late reply is not taken for the next one's.
    fn line_drained(&mut self, t_ns: u64) {
        let _ = t_ns;
    }
}

/// One physical quantity a device offers (a state attaches to one channel).
#[derive(Debug, Clone, PartialEq)]
pub struct Channel {
    /// Name used in the manifest (`position`, `current`, ...).
    pub name: &'static str,
    /// Physical units of the device-side value (before calibration).
    pub units: &'static str,
    /// Whether the channel can be sampled.
    pub readable: bool,
    /// Whether the channel accepts setpoints.
    pub writable: bool,
}

impl Channel {
    /// A channel that is sampled and accepts setpoints.
    pub const fn read_write(name: &'static str, units: &'static str) -> Self {
        Self::new(name, units, true, true)
    }

    /// A channel that is only sampled.
    pub const fn read_only(name: &'static str, units: &'static str) -> Self {
        Self::new(name, units, true, false)
    }

    /// A channel that only accepts setpoints.
    pub const fn write_only(name: &'static str, units: &'static str) -> Self {
        Self::new(name, units, false, true)
    }

    const fn new(name: &'static str, units: &'static str, readable: bool, writable: bool) -> Self {
        Self {
            name,
            units,
            readable,
            writable,
        }
    }
}

/// What a device does when commands stop (watchdog) or the executor shuts down.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SafeAction {
    /// Keep the current position (write present position as the goal).
    Hold,
    /// Disable torque / exit motor mode.
    TorqueOff,
    /// Let the joint move but brake it: zero stiffness, velocity gain `kd` (MIT-mode motors).
    Damp {
        /// Velocity gain (N·m·s/rad).
        kd: f64,
    },
    /// Command `value` (device units) on `channel`.
    Setpoint {
        /// Channel index.
        channel: usize,
        /// Value in device units.
        value: f64,
    },
}

/// A node on a bus: tags requests with its credential, and interprets replies that carry it.
///
/// A device built outside an executor is *unmanaged*: a bare driver whose writes go straight to
/// the bus (tests, tools). The executor calls [`bring_up`](Self::bring_up) once its bus is open;
/// from then on the device runs its own lifecycle (probe, configuration, enable from where it
/// is, trips, faults) and reports it through [`status`](Self::status). Every method runs on the
/// executor's real-time thread: no allocation, no blocking.
pub trait Device {
    /// The device's address on its bus.
    fn credential(&self) -> Credential;
    /// The quantities it offers.
    fn channels(&self) -> &[Channel];
    /// Queues the request(s) that sample `channel`.
    fn sample(&mut self, channel: usize, ctx: TickCtx, out: &mut Bounded<Request>);
    /// Records a setpoint (device units) for `channel`; the request goes out at [`flush`](Self::flush).
    fn write(&mut self, channel: usize, value: f64, ctx: TickCtx);
    /// Called once per device tick after `sample`/`write`: emits the write requests (a device
    /// may combine several channels into one request, as MIT-mode motors do) and the requests of
    /// its lifecycle.
    fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>);
    /// Interprets a reply addressed to this device, pushing channel updates.
    fn reply(&mut self, reply: &Reply, out: &mut Bounded<Update>);
    /// Queues the requests that carry out `action`; a managed device then confirms it on the
    /// bus (see [`DeviceStatus::safe`]).
    fn safe(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>);

    /// Where the device is in its lifecycle.
    fn status(&self) -> DeviceStatus {
        DeviceStatus::UNMANAGED
    }
    /// Starts (or, after its bus came back, restarts) the lifecycle: probe, configure, then
    /// enable from the present position or stay limp, as `startup` says (a device that was
    /// driving before its bus was lost resumes driving).
    fn bring_up(&mut self, startup: Startup, ctx: TickCtx) {
        let _ = (startup, ctx);
    }
    /// Its bus is gone: it sends nothing until [`bring_up`](Self::bring_up) is called again.
    fn bus_lost(&mut self) {}
    /// Whether a setpoint for `channel` can take effect now (a disabled or tripped device
    /// refuses everything but its `enable` channel).
    fn accepts(&self, channel: usize) -> bool {
        let _ = channel;
        true
    }
    /// A watchdog trip or a fault: `action`, and every later setpoint refused until the device
    /// is enabled again (through its `enable` channel).
    fn trip(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.safe(action, ctx, out);
    }
    /// Values the device knows without asking the bus (its enable state, commanded gains),
    /// for the channels sampled since the last call.
    fn report(&mut self, ctx: TickCtx, out: &mut Bounded<Update>) {
        let _ = (ctx, out);
    }
    /// The channels states will sample, once at start-up (a device may pick its read layout
    /// from them, as Dynamixel X-series servos do with indirect addressing).
    fn configure_reads(&mut self, sampled: &[usize]) {
        let _ = sampled;
    }
    /// One line for logs: model, read layout, configuration (called off the real-time path).
    fn describe(&self) -> String {
        String::new()
    }
    /// Simulated devices: start `channel` at `value` (device units) rather than at the
    /// simulator's 0, so that a simulated joint starts inside its state's limits. Real devices
    /// are where they are and ignore it. Called once, at set-up.
    fn start_at(&mut self, channel: usize, value: f64) {
        let _ = (channel, value);
    }
}
