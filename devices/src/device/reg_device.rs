//! [`RegDevice`]: a register-mapped servo (Dynamixel 2.0 and 1.0) over its family's
//! [`ControlTable`]: sampling, buffered writes, reply interpretation with range checks, safe
//! actions confirmed by reading them back, and the bring-up lifecycle:
//!
//! ```text
//! Probe        PING (2.0: model number in the reply; 1.0: then READ of the model number)
//! ReadConfig   READ of every configuration register and Torque Enable
//! TorqueOff    only if an EEPROM (or indirect-address) register differs while torque is on
//! WriteConfig  the registers that differ, read back: a refusal is an error naming the register
//! Align        READ of Present Position; refused if outside the goal range (it would move)
//! Enable       Goal Position = present (or goal velocity/current 0), then Torque Enable = 1,
//!              read back: enabled only when the servo says so
//! ```
//!
//! Every step waits for its replies (the protocol stage answers each request or reports it
//! missing), retries a few times and then fails loudly. Nothing here allocates after
//! construction.
//!
//! Range checks matter: a CRC-16 lets about one damaged packet in 65 536 through, a 1.0
//! checksum one in 256. A value outside its register's physical range is therefore treated as
//! damaged: the channel goes stale and the rejection is counted, never delivered. So is a
//! position further from the last good one than the servo can travel in between, unless the
//! next reading confirms it (a damaged packet does not repeat itself).

use super::control_table::{ConfigItem, ControlTable, RegChannel};
use crate::component::{Channel, Device, SafeAction, TickCtx};
use crate::lifecycle::{
    life_step, Backoff, DeviceStatus, Failure, Goal, Lifecycle, Phase, Startup, LOST_ROUNDS,
    REG_ROUND_TIMEOUT_NS,
};
use crate::message::{Credential, Op, Reply, ReplyData, Request, Update};
use crate::queue::Bounded;

/// Most registers one lifecycle step reads back.
const EXPECT: usize = 48;
/// A rebooting servo is probed again after this long (ns).
const BOOT_NS: u64 = 300_000_000;
/// A `hold` writes Goal Position := the present position read at most this long ago (ns); an
/// older reading (the executor did not get the CPU, or its reads were lost) is read again
/// first: holding where the servo was some time ago would move it back there.
pub const HOLD_FRESH_NS: u64 = 20_000_000;
/// Slack on the time between two readings in the rate check (ns): a reading is dated by its
/// request, and its reply may leave the servo this much later.
const RATE_SLACK_NS: u64 = 20_000_000;

/// One register a lifecycle step waits for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Expect {
    addr: u16,
    len: u8,
    /// The value it must read (a verification), if any.
    want: Option<i64>,
    got: Option<i64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    None,
    Probe,
    ModelRead,
    ReadConfig,
    /// Torque off before writing EEPROM; then write the configuration (or stay off).
    TorqueOff {
        then_write: bool,
    },
    WriteConfig,
    Align,
    Enable,
    Reboot,
    /// A safe action, waiting for its read-back.
    Safe,
    /// A hold whose last present position is too old: reading it before the hold is written.
    SafeAlign,
}

life_step!(Step);

/// The lifecycle state of a register device.
#[derive(Debug)]
struct Life {
    /// Status, goal, step and retries, as every managed device keeps them.
    base: Lifecycle<Step>,
    /// It has been up (configured) since it was first brought up: a later enable that cannot
    /// happen leaves it disabled instead of failing its bring-up.
    was_up: bool,
    expect: [Expect; EXPECT],
    n_expect: usize,
    /// Last Torque Enable read.
    torque: Option<bool>,
    /// Raw present position read at Align.
    present: Option<i64>,
    /// When it was read (the request's time, ns).
    present_ns: u64,
    /// Times an enable read the position again because its round was sent again after the
    /// last reading had aged (bounded: see `drive`).
    realigns: u8,
    /// Hardware Error Status must be read (an alert was seen).
    fault_check: bool,
    /// Reboot after a fault, automatically (`reboot_on_fault`), at this time.
    reboot_on_fault: bool,
    reboot_at: Option<u64>,
    backoff: Backoff,
    /// The reboot was an automatic recovery: re-enable and accept commands again after it.
    recovering: bool,
    /// The `enable` channel was sampled since the last report.
    report_enable: bool,
}

impl Life {
    fn new() -> Self {
        Self {
            base: Lifecycle::new(),
            was_up: false,
            expect: [Expect {
                addr: 0,
                len: 0,
                want: None,
                got: None,
            }; EXPECT],
            n_expect: 0,
            torque: None,
            present: None,
            present_ns: 0,
            realigns: 0,
            fault_check: false,
            reboot_on_fault: false,
            reboot_at: None,
            backoff: Backoff::new(),
            recovering: false,
            report_enable: false,
        }
    }

    fn managed(&self) -> bool {
        self.base.managed()
    }

    /// Starts `step` (its requests go out at the next flush).
    fn go(&mut self, step: Step) {
        self.base.go(step);
        self.n_expect = 0;
    }

    fn expect(&mut self, addr: u16, len: u8, want: Option<i64>) {
        if self.n_expect < EXPECT {
            self.expect[self.n_expect] = Expect {
                addr,
                len,
                want,
                got: None,
            };
            self.n_expect += 1;
        }
    }

    fn expected(&self) -> &[Expect] {
        &self.expect[..self.n_expect]
    }

    fn got(&self, addr: u16) -> Option<i64> {
        self.expected().iter().find(|e| e.addr == addr)?.got
    }
}

/// A register-mapped device: sampling, buffered writes, reply interpretation, range checks,
/// safe actions and the bring-up lifecycle over the channel table of its family `T`. Its last
/// channel is `enable` (read/write, no register): 1 while driving; writing 1 enables it from
/// where it is, 0 switches torque off.
#[derive(Debug)]
pub struct RegDevice<T: ControlTable> {
    family: T,
    cred: Credential,
    table: Vec<RegChannel>,
    channels: Vec<Channel>,
    /// Address each channel is read at (its own register, or its indirect data address).
    read_at: Vec<Option<u16>>,
    /// Configuration written at bring-up (the family's, plus indirect addresses).
    config: Vec<ConfigItem>,
    /// How the sampled channels are read, for the log.
    layout: Layout,
    pending: Vec<Option<i64>>,
    /// Last good raw value read per channel.
    last: Vec<Option<i64>>,
    /// When it was read (the request's time, ns).
    last_ns: Vec<u64>,
    /// A reading of a rate-bounded channel too far from the last good one (raw, time), held
    /// back until the next reading confirms or refutes it.
    jump: Vec<Option<(i64, u64)>>,
    /// Tick whose replies carry a device error (alert / failed instruction).
    fault_tick: Option<u64>,
    range_rejects: u64,
    device_errors: u64,
    /// Channel index of the present position (for Hold) and the goal-position register.
    hold: Option<(usize, u16)>,
    life: Life,
}

/// How a register device reads the channels its states sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Layout {
    /// Bytes per cycle read through indirect addressing (0: the registers themselves).
    pub indirect: u16,
    /// Bytes the contiguous span of the registers would take.
    pub contiguous: u16,
}

impl<T: ControlTable> RegDevice<T> {
    /// The safe action this kind declares.
    pub const SAFE_ACTION: SafeAction = T::SAFE_ACTION;

    /// A device of `family` at `cred`.
    pub fn with_table(cred: Credential, family: T) -> Self {
        let table = family.channels();
        let n = table.len();
        let hold = T::HOLD.and_then(|i| Some((i, table.get(i)?.write?)));
        let mut channels: Vec<Channel> = table.iter().map(RegChannel::channel).collect();
        channels.push(Channel::read_write("enable", ""));
        let config = family.config();
        Self {
            read_at: table.iter().map(|c| c.read).collect(),
            family,
            cred,
            channels,
            table,
            config,
            layout: Layout::default(),
            pending: vec![None; n],
            last: vec![None; n],
            last_ns: vec![0; n],
            jump: vec![None; n],
            fault_tick: None,
            range_rejects: 0,
            device_errors: 0,
            hold,
            life: Life::new(),
        }
    }

    /// Reboot after a fault automatically (with back-off): see `reboot_on_fault` in the
    /// manifest reference. Families without REBOOT ignore it.
    pub fn reboot_on_fault(mut self, on: bool) -> Self {
        self.life.reboot_on_fault = on && T::REBOOT;
        self
    }

    /// The family's control table and state.
    pub fn family(&self) -> &T {
        &self.family
    }

    /// The channel table (without the `enable` channel, which has no register).
    pub fn table(&self) -> &[RegChannel] {
        &self.table
    }

    /// Index of the `enable` channel.
    pub fn enable_channel(&self) -> usize {
        self.table.len()
    }

    /// How the sampled channels are read (after [`Device::configure_reads`]).
    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// The address channel `i` is read at: its register, or its indirect data (after
    /// [`Device::configure_reads`]).
    pub fn read_address(&self, i: usize) -> Option<u16> {
        *self.read_at.get(i)?
    }

    /// Values rejected by the range check or the rate check since start (damaged packets
    /// that passed the CRC/checksum).
    pub fn range_rejects(&self) -> u64 {
        self.range_rejects
    }

    /// Device error replies since start.
    pub fn device_errors(&self) -> u64 {
        self.device_errors
    }

    /// Last good value of channel `i`, in units.
    pub fn last(&self, i: usize) -> Option<f64> {
        let raw = (*self.last.get(i)?)?;
        Some(self.table[i].to_units(raw))
    }

    fn push(&self, op: Op, ctx: TickCtx, out: &mut Bounded<Request>) {
        let _ = out.push(Request::new(self.cred, op, ctx));
    }

    fn push_write(&self, addr: u16, len: u8, value: i64, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.push(Op::Write { addr, len, value }, ctx, out);
    }

    fn push_read(&self, addr: u16, len: u8, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.push(Op::Read { addr, len }, ctx, out);
    }

    fn enabled(&self) -> bool {
        matches!(
            self.life.base.status.phase,
            Phase::Enabled | Phase::Unmanaged
        )
    }

    /// The raw range a goal may be written in.
    fn goal_range(&self) -> Option<(i64, i64)> {
        let (i, _) = self.hold?;
        Some(self.table[i].write_range)
    }

    // ---- lifecycle steps --------------------------------------------------------------

    /// Sends the requests of the current step (once; again after a retry).
    fn drive(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        if !self.life.managed() {
            return;
        }
        if self.life.base.step == Step::None {
            if let Some(at) = self.life.reboot_at {
                if ctx.now_ns >= at && !matches!(self.life.base.status.phase, Phase::Offline) {
                    self.life.reboot_at = None;
                    self.life.recovering = true;
                    self.life.base.goal = Goal::Drive;
                    self.life.go(Step::Reboot);
                }
            }
            if self.life.fault_check {
                if let Some(addr) = T::HW_ERROR {
                    self.life.fault_check = false;
                    self.push_read(addr, 1, ctx, out);
                }
            }
        }
        if self.life.managed()
            && self
                .life
                .base
                .round_overdue(ctx.now_ns, REG_ROUND_TIMEOUT_NS)
        {
            // Neither its answers nor word of them missing came: lost (sent again below).
            for e in &mut self.life.expect[..self.life.n_expect] {
                e.got = None;
            }
            self.retry_lost(ctx.now_ns);
        }
        if self.life.base.sent || ctx.now_ns < self.life.base.next_try_ns {
            return;
        }
        self.life.base.mark_sent(ctx.tick, ctx.now_ns);
        match self.life.base.step {
            Step::None => self.life.base.sent = false,
            Step::Probe => self.push(Op::Ping, ctx, out),
            Step::Reboot => self.push(Op::Reboot, ctx, out),
            Step::ModelRead => {
                self.life.n_expect = 0;
                self.life.expect(T::MODEL_AT, 2, None);
                self.push_read(T::MODEL_AT, 2, ctx, out);
            }
            Step::ReadConfig => {
                self.life.n_expect = 0;
                self.life.expect(T::TORQUE, 1, None);
                self.push_read(T::TORQUE, 1, ctx, out);
                for k in 0..self.config.len() {
                    let c = self.config[k];
                    self.life.expect(c.addr, c.len, None);
                    self.push_read(c.addr, c.len, ctx, out);
                }
            }
            Step::TorqueOff { .. } => {
                self.life.n_expect = 0;
                self.life.expect(T::TORQUE, 1, Some(0));
                self.push_write(T::TORQUE, 1, 0, ctx, out);
                self.push_read(T::TORQUE, 1, ctx, out);
            }
            Step::WriteConfig => {
                self.life.n_expect = 0;
                for k in 0..self.config.len() {
                    let c = self.config[k];
                    self.life.expect(c.addr, c.len, Some(c.value));
                    self.push_write(c.addr, c.len, c.value, ctx, out);
                    self.push_read(c.addr, c.len, ctx, out);
                }
            }
            Step::Align => {
                self.life.n_expect = 0;
                match self
                    .hold
                    .and_then(|(i, _)| self.table[i].read.map(|a| (a, self.table[i].len)))
                {
                    Some((addr, len)) => {
                        self.life.expect(addr, len, None);
                        self.push_read(addr, len, ctx, out);
                    }
                    // Nothing to align: straight to enabling.
                    None => {
                        self.life.go(Step::Enable);
                        self.drive(ctx, out);
                    }
                }
            }
            Step::Enable => {
                let again = self.life.base.tries > 0 || self.life.base.lost > 0;
                if again && ctx.now_ns.saturating_sub(self.life.present_ns) > HOLD_FRESH_NS {
                    // Sent again after lost rounds: where it was read is not where it is now
                    // (a servo still on its way to an old goal). Read it again, then enable
                    // there, within a bound: a line that keeps losing the round gives up.
                    if self.life.realigns >= LOST_ROUNDS {
                        return self.give_up(ctx.now_ns);
                    }
                    self.life.realigns += 1;
                    self.life.go(Step::Align);
                    return self.drive(ctx, out);
                }
                self.life.n_expect = 0;
                if let (Some((i, goal)), Some(present)) = (self.hold, self.life.present) {
                    let c = self.table[i];
                    let raw = c.encode_raw(present);
                    self.push_write(goal, c.len, raw, ctx, out);
                    self.life.expect(goal, c.len, Some(raw));
                    self.push_read(goal, c.len, ctx, out);
                }
                if let Some((addr, len)) = self.family.zero_goal() {
                    self.push_write(addr, len, 0, ctx, out);
                }
                self.life.expect(T::TORQUE, 1, Some(1));
                self.push_write(T::TORQUE, 1, 1, ctx, out);
                self.push_read(T::TORQUE, 1, ctx, out);
            }
            // A safe action's requests went out when it was asked for (see `safe`); a retry
            // sends its writes and read-backs again (a hold's own read first, see
            // `HOLD_FRESH_NS`, then the hold).
            Step::Safe | Step::SafeAlign => {
                if let Some((addr, len)) = self.refresh_hold(ctx.now_ns) {
                    // Where it was read is not where it is now: read it again, then hold.
                    self.life.go(Step::SafeAlign);
                    self.life.base.mark_sent(ctx.tick, ctx.now_ns);
                    self.life.expect(addr, len, None);
                    self.push_read(addr, len, ctx, out);
                    return;
                }
                for k in 0..self.life.n_expect {
                    // A new round: what the last one read (a goal the lost write never
                    // changed) is no answer to this one.
                    self.life.expect[k].got = None;
                    let e = self.life.expect[k];
                    if let Some(v) = e.want {
                        self.push_write(e.addr, e.len, v, ctx, out);
                    }
                    self.push_read(e.addr, e.len, ctx, out);
                }
            }
        }
    }

    /// Before a hold is sent again: the servo may have moved since the reading it holds at
    /// (a resend comes after the first round failed). A reading younger than
    /// [`HOLD_FRESH_NS`] (the samples go on while it holds) becomes the goal; otherwise the
    /// position must be read again first: its register is returned.
    fn refresh_hold(&mut self, now_ns: u64) -> Option<(u16, u8)> {
        if self.life.base.step != Step::Safe {
            return None;
        }
        let (i, goal) = self.hold?;
        let c = self.table[i];
        let n = self.life.n_expect;
        let k = self.life.expect[..n]
            .iter()
            .position(|e| e.addr == goal && e.want.is_some())?;
        match self.last[i] {
            Some(raw) if now_ns.saturating_sub(self.last_ns[i]) <= HOLD_FRESH_NS => {
                self.life.expect[k].want =
                    Some(c.encode_raw(raw.clamp(c.write_range.0, c.write_range.1)));
                None
            }
            _ => c.read.map(|a| (a, c.len)),
        }
    }

    /// A lifecycle request went unanswered (or was refused): retry, or give up.
    fn retry(&mut self, now_ns: u64) {
        if !self.life.base.retry_exhausted(now_ns) {
            return;
        }
        self.give_up(now_ns);
    }

    /// A lifecycle round was lost to the line (a read missing): sent again, within its budget.
    fn retry_lost(&mut self, now_ns: u64) {
        if !self.life.base.lost_exhausted(now_ns) {
            return;
        }
        self.give_up(now_ns);
    }

    /// The step's tries are used up.
    fn give_up(&mut self, now_ns: u64) {
        let l = &mut self.life;
        match l.base.step {
            Step::Probe | Step::ModelRead | Step::ReadConfig => l.base.fail(Failure::NoAnswer),
            Step::WriteConfig => {
                let bad = l.expected().iter().find(|e| e.got != e.want).copied();
                let f = match bad {
                    Some(e) => Failure::ConfigRefused {
                        addr: e.addr,
                        wrote: e.want.unwrap_or(0),
                        read: e.got.unwrap_or(-1),
                    },
                    None => Failure::NoAnswer,
                };
                l.base.fail(f);
            }
            // Up, but it did not do what it was asked: limp, and say why.
            Step::Enable => {
                // Its Torque Enable write may have taken effect all the same (the read-backs
                // lost on the line): whether it is powered is not known.
                l.torque = None;
                l.base.refuse_enable();
            }
            Step::Align | Step::TorqueOff { .. } => l.base.refuse_enable(),
            Step::Reboot => {
                // No answer to REBOOT (status return level < 2, or it restarted at once):
                // look for it again.
                l.go(Step::Probe);
                l.base.next_try_ns = now_ns + BOOT_NS;
            }
            // The action stays unconfirmed: the executor reports it (a hold whose position
            // could not be read writes nothing: the servo keeps the goal it had).
            Step::Safe | Step::SafeAlign | Step::None => l.base.step = Step::None,
        }
    }

    /// Configuration read: what differs from the manifest.
    fn config_differs(&self) -> (bool, bool) {
        let mut differs = false;
        let mut eeprom = false;
        for c in &self.config {
            if self.life.got(c.addr) != Some(c.value) {
                differs = true;
                eeprom |= self.family.needs_torque_off(c.addr);
            }
        }
        (differs, eeprom)
    }

    /// Configuration done: enable (to drive or to hold), or stay limp.
    fn settle(&mut self) {
        let l = &mut self.life;
        l.was_up = true;
        if l.base.goal != Goal::Limp {
            l.base.status.phase = Phase::Enabling;
            l.realigns = 0;
            l.go(Step::Align);
        } else if l.torque == Some(true) {
            l.go(Step::TorqueOff { then_write: false });
        } else {
            l.base.settle_limp();
        }
    }

    /// Every reply a step waited for is in: decide.
    fn step_done(&mut self, now_ns: u64) {
        match self.life.base.step {
            Step::ModelRead => {
                let found = self.life.got(T::MODEL_AT).unwrap_or(0) as u16;
                self.life.base.status.model = Some(found);
                if self.model_ok(found) {
                    self.life.base.status.phase = Phase::Configuring;
                    self.life.go(Step::ReadConfig);
                } else {
                    self.life.base.fail(Failure::WrongModel { found });
                }
            }
            Step::ReadConfig => {
                self.life.torque = self.life.got(T::TORQUE).map(|t| t != 0);
                match self.config_differs() {
                    (false, _) => self.settle(),
                    (true, true) if self.life.torque != Some(false) => {
                        self.life.go(Step::TorqueOff { then_write: true })
                    }
                    (true, _) => self.life.go(Step::WriteConfig),
                }
            }
            Step::TorqueOff { then_write } => {
                if self.life.got(T::TORQUE) != Some(0) {
                    return self.retry(now_ns);
                }
                self.life.torque = Some(false);
                if then_write {
                    self.life.go(Step::WriteConfig);
                } else {
                    self.settle();
                }
            }
            Step::WriteConfig => {
                if self.life.expected().iter().any(|e| e.got != e.want) {
                    return self.retry(now_ns);
                }
                self.settle();
            }
            Step::Align => {
                let Some((i, _)) = self.hold else { return };
                let Some(addr) = self.table[i].read else {
                    return;
                };
                let Some(bits) = self.life.got(addr) else {
                    return;
                };
                let raw = self.table[i].decode_raw(bits);
                let (lo, hi) = self.goal_range().unwrap_or((i64::MIN, i64::MAX));
                if raw < lo || raw > hi {
                    // Enabling would make it move: refuse. At start-up that fails its bring-up;
                    // later it stays limp, and says why.
                    let f = Failure::OutOfRange { raw };
                    let l = &mut self.life;
                    l.base.goal = Goal::Limp;
                    if l.base.status.tripped || l.recovering || l.base.user_off || !l.was_up {
                        l.base.fail(f);
                    } else {
                        l.base.status.failure = Some(f);
                        l.go(Step::TorqueOff { then_write: false });
                    }
                    return;
                }
                self.life.present = Some(raw);
                self.life.present_ns = now_ns;
                self.life.go(Step::Enable);
            }
            Step::Enable => {
                if self.life.expected().iter().any(|e| e.got != e.want) {
                    // Torque still off with no fault reported: the write was lost on the line
                    // (a latched fault shows in the status packets and is retried as a try).
                    return if self.life.base.status.fault == 0 {
                        self.retry_lost(now_ns)
                    } else {
                        self.retry(now_ns)
                    };
                }
                let l = &mut self.life;
                l.torque = Some(true);
                l.recovering = false;
                // Holding too: the last failure is over.
                l.base.status.failure = None;
                l.base.switched_on();
                if let Some((i, _)) = self.hold {
                    // The reading's own time: a hold right after must not take an old
                    // reading for a fresh one.
                    self.last[i] = self.life.present;
                    self.last_ns[i] = self.life.present_ns;
                }
            }
            Step::SafeAlign => {
                let Some((i, goal)) = self.hold else { return };
                let c = self.table[i];
                let Some(bits) = c.read.and_then(|a| self.life.got(a)) else {
                    return;
                };
                let raw = c.decode_raw(bits);
                self.last[i] = Some(raw);
                self.last_ns[i] = now_ns;
                let value = c.encode_raw(raw.clamp(c.write_range.0, c.write_range.1));
                // The hold itself, sent at the next flush (`drive`), confirmed as any.
                self.life.go(Step::Safe);
                self.life.base.next_try_ns = 0;
                self.life.expect(goal, c.len, Some(value));
                self.life.expect(T::TORQUE, 1, None);
            }
            Step::Safe => {
                if self
                    .life
                    .expected()
                    .iter()
                    .any(|e| e.want.is_some() && e.got != e.want)
                {
                    return self.retry(now_ns);
                }
                let l = &mut self.life;
                l.base.safe_confirmed();
                if l.got(T::TORQUE) == Some(0) {
                    l.torque = Some(false);
                    if l.base.status.phase == Phase::Holding {
                        // Its torque is off (the servo's own shutdown): it is limp.
                        l.base.status.phase = Phase::Disabled;
                        l.base.goal = Goal::Limp;
                    }
                }
            }
            Step::None | Step::Probe | Step::Reboot => {}
        }
    }

    fn model_ok(&self, model: u16) -> bool {
        let m = self.family.models();
        m.is_empty() || m.iter().any(|(n, _)| *n == model)
    }

    /// Lifecycle side of a reply.
    fn life_reply(&mut self, reply: &Reply) {
        if !self.life.managed() {
            return;
        }
        let now = reply.t_sample_ns;
        match (self.life.base.step, reply.data) {
            (Step::Probe, ReplyData::Ping { model, .. }) => {
                self.life.base.status.model = model.or(self.life.base.status.model);
                match model {
                    Some(m) if !self.model_ok(m) => {
                        self.life.base.fail(Failure::WrongModel { found: m })
                    }
                    Some(_) => {
                        self.life.base.status.phase = Phase::Configuring;
                        self.life.go(Step::ReadConfig);
                    }
                    None => self.life.go(Step::ModelRead),
                }
            }
            (
                Step::Probe | Step::Reboot,
                ReplyData::Missing {
                    op: Op::Ping | Op::Reboot,
                },
            ) => self.retry(now),
            (Step::Reboot, ReplyData::Ack) => {
                self.life.go(Step::Probe);
                self.life.base.status.phase = Phase::Probing;
                self.life.base.next_try_ns = now + BOOT_NS;
            }
            // A read of an earlier round (a sample's, or one given up) is not this round's
            // answer: its value may be long out of date (a present position read before a
            // hold, or a reply that came late).
            (_, ReplyData::Register { .. }) if reply.tick < self.life.base.sent_tick => {}
            (_, ReplyData::Register { addr, len, value }) => {
                let l = &mut self.life;
                let n = l.n_expect;
                let mut hit = false;
                for e in &mut l.expect[..n] {
                    if e.addr == addr && e.len == len && e.got.is_none() {
                        e.got = Some(value);
                        hit = true;
                    }
                }
                if hit && l.expected().iter().all(|e| e.got.is_some()) {
                    self.step_done(now);
                }
            }
            (
                _,
                ReplyData::Missing {
                    op: Op::Read { addr, len },
                },
            ) => {
                let waiting = self
                    .life
                    .expected()
                    .iter()
                    .any(|e| e.addr == addr && e.len == len && e.got.is_none());
                // A read of an earlier round (given up, then sent again) that comes back
                // missing now is no news about this round.
                if waiting && self.life.base.sent && reply.tick >= self.life.base.sent_tick {
                    // One retry per round: the other reads of the round are resent with it.
                    for e in &mut self.life.expect[..self.life.n_expect] {
                        e.got = None;
                    }
                    if self.life.base.step == Step::Safe {
                        self.life.base.sent = false;
                    }
                    self.retry_lost(now);
                }
            }
            _ => {}
        }
    }

    /// Records a fault reported by the device.
    fn set_fault(&mut self, bits: u32, now_ns: u64) {
        let was = self.life.base.status.fault;
        self.life.base.status.fault = bits;
        if bits != 0 && was == 0 && self.life.reboot_on_fault && self.life.managed() {
            self.life.reboot_at = Some(self.life.backoff.fault_at(now_ns));
        }
    }

    /// Whether it is known to be limp: disabled, and switched off by the user or read with
    /// its torque off. A device whose enable was given up is disabled but may be powered (its
    /// confirmation lost on the line): a `hold` holds it rather than letting go of a joint
    /// that may carry a load, and its read-back of Torque Enable tells which it is.
    fn known_limp(&self) -> bool {
        let l = &self.life;
        l.base.status.phase == Phase::Disabled && (l.base.user_off || l.torque == Some(false))
    }

    /// A reading of a rate-bounded channel (the position) further from the last good one than
    /// the servo can travel in between was damaged beyond what the check sum caught: it is
    /// made a missing read (stale, counted with the range rejects, and no answer to a
    /// lifecycle step), unless it confirms the reading held back before it, or the next one
    /// confirms it (a servo turned by hand while nobody read it, a reference that was itself
    /// damaged): one reading is lost then, never a wrong one taken.
    fn screen(&mut self, reply: &Reply) -> Reply {
        let ReplyData::Register { addr, len, value } = reply.data else {
            return *reply;
        };
        let t = reply.t_sample_ns;
        for i in 0..self.table.len() {
            let c = self.table[i];
            let Some(rate) = c.max_rate else { continue };
            if c.len != len || (self.read_at[i] != Some(addr) && c.read != Some(addr)) {
                continue;
            }
            let raw = c.decode_raw(value);
            if raw < c.read_range.0 || raw > c.read_range.1 {
                // The range check rejects it.
                return *reply;
            }
            let within = |from: i64, since: u64| {
                let span_s = (t.saturating_sub(since) + RATE_SLACK_NS) as f64 * 1e-9;
                (raw - from).unsigned_abs() as f64 <= rate * span_s + 2.0
            };
            let plausible = match (self.last[i], self.jump[i]) {
                (None, _) => true,
                (Some(prev), _) if within(prev, self.last_ns[i]) => true,
                (_, Some((held, at))) => within(held, at),
                _ => false,
            };
            if plausible {
                self.jump[i] = None;
                return *reply;
            }
            self.jump[i] = Some((raw, t));
            self.range_rejects += 1;
            let op = Op::Read { addr, len };
            return Reply {
                data: ReplyData::Missing { op },
                op: Some(op),
                ..*reply
            };
        }
        *reply
    }

    /// Starts enabling from where it is (the `enable` channel, or a hold-off device's first
    /// setpoint).
    fn start_enable(&mut self) {
        self.pending.iter_mut().for_each(|p| *p = None);
        let l = &mut self.life;
        if l.base.defer_enable() {
            return;
        }
        l.base.goal = Goal::Drive;
        l.base.user_off = false;
        if l.base.status.fault != 0 && T::REBOOT {
            // Only a reboot clears a latched hardware error.
            l.go(Step::Reboot);
            l.base.status.phase = Phase::Probing;
        } else {
            l.base.status.phase = Phase::Enabling;
            l.realigns = 0;
            l.go(Step::Align);
        }
    }

    /// Switches torque off on request (the `enable` channel written 0).
    fn start_disable(&mut self) {
        self.pending.iter_mut().for_each(|p| *p = None);
        let l = &mut self.life;
        l.base.goal = Goal::Limp;
        l.base.user_off = true;
        l.base.status.phase = Phase::Disabled;
        l.go(Step::TorqueOff { then_write: false });
    }
}

impl<T: ControlTable> Device for RegDevice<T> {
    fn credential(&self) -> Credential {
        self.cred
    }

    fn channels(&self) -> &[Channel] {
        &self.channels
    }

    fn sample(&mut self, i: usize, ctx: TickCtx, out: &mut Bounded<Request>) {
        if i == self.enable_channel() {
            self.life.report_enable = true;
            return;
        }
        if self.life.managed()
            && matches!(
                self.life.base.status.phase,
                Phase::Offline | Phase::Probing | Phase::Failed
            )
        {
            return;
        }
        let Some(c) = self.table.get(i) else { return };
        let Some(addr) = self.read_at[i] else { return };
        self.push_read(addr, c.len, ctx, out);
    }

    fn write(&mut self, i: usize, value: f64, _ctx: TickCtx) {
        if !value.is_finite() {
            return;
        }
        if i == self.enable_channel() {
            if !self.life.managed() {
                return;
            }
            match self.life.base.enable_request(value) {
                Some(true) => self.start_enable(),
                Some(false) => self.start_disable(),
                None => {}
            }
            return;
        }
        let Some(c) = self.table.get(i).copied() else {
            return;
        };
        if c.write.is_none() || !self.accepts(i) {
            return;
        }
        if self.life.base.setpoint_enables() {
            self.start_enable();
        }
        let raw = c.to_raw(value);
        self.pending[i] = Some(raw);
        self.family.on_raw(&mut self.table, i, raw);
    }

    fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.drive(ctx, out);
        if !self.enabled() {
            return;
        }
        for i in 0..self.table.len() {
            let Some(raw) = self.pending[i].take() else {
                continue;
            };
            let c = self.table[i];
            let Some(addr) = c.write else { continue };
            self.push_write(addr, c.len, c.encode_raw(raw), ctx, out);
        }
    }

    fn reply(&mut self, reply: &Reply, out: &mut Bounded<Update>) {
        let screened = self.screen(reply);
        let reply = &screened;
        self.life_reply(reply);
        let fault = self.fault_tick == Some(reply.tick);
        let (addr, len, value) = match reply.data {
            ReplyData::Register { addr, len, value } => (addr, len, Some(value)),
            ReplyData::Missing {
                op: Op::Read { addr, len },
            } => (addr, len, None),
            ReplyData::DeviceError { code } => {
                self.device_errors += 1;
                self.fault_tick = Some(reply.tick);
                let code = code as u8;
                if T::HW_ERROR.is_some() && code & 0x80 != 0 && self.life.base.status.fault == 0 {
                    // An alert: the Hardware Error Status says what.
                    self.life.fault_check = true;
                }
                if T::FAULT_BITS != 0 && code & T::FAULT_BITS != 0 {
                    self.set_fault((code & T::FAULT_BITS) as u32, reply.t_sample_ns);
                }
                return;
            }
            _ => return,
        };
        if value.is_some() && !fault && self.life.base.status.fault != 0 {
            // A clean status packet (no error bits, no alert): the condition has passed, or
            // the hardware error was cleared by a reboot.
            self.set_fault(0, reply.t_sample_ns);
        }
        if let (Some(hw), Some(v)) = (T::HW_ERROR, value) {
            // The alert's own read of the register (never through the indirect layout).
            if addr == hw && len == 1 {
                self.set_fault(v as u32 & 0xFF, reply.t_sample_ns);
            }
        }
        for i in 0..self.table.len() {
            let c = self.table[i];
            if self.read_at[i] != Some(addr) || c.len != len {
                continue;
            }
            let units = match value.map(|bits| c.decode_raw(bits)) {
                None => None,
                Some(raw) if raw < c.read_range.0 || raw > c.read_range.1 => {
                    self.range_rejects += 1;
                    None
                }
                Some(raw) => {
                    if T::HW_ERROR.is_some() && c.read == T::HW_ERROR && c.read != Some(addr) {
                        // The hardware_error channel sampled through Indirect Data (read
                        // directly, it was taken above).
                        self.set_fault(raw as u32 & 0xFF, reply.t_sample_ns);
                    }
                    self.last[i] = Some(raw);
                    self.last_ns[i] = reply.t_sample_ns;
                    self.family.on_raw(&mut self.table, i, raw);
                    Some(c.to_units(raw))
                }
            };
            let _ = out.push(Update::from_reply(reply, i, units, fault));
        }
    }

    fn safe(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.pending.iter_mut().for_each(|p| *p = None);
        let managed = self.life.managed();
        if managed {
            self.life.go(Step::Safe);
            self.life.base.mark_sent(ctx.tick, ctx.now_ns);
            if !self.life.base.begin_safe() {
                return;
            }
        }
        match action {
            SafeAction::Hold => match self.hold {
                Some((i, goal)) if self.last[i].is_some() && !self.known_limp() => {
                    let read = self.table[i].read.map(|a| (a, self.table[i].len));
                    let old = ctx.now_ns.saturating_sub(self.last_ns[i]) > HOLD_FRESH_NS;
                    if let (true, true, Some((addr, len))) = (managed, old, read) {
                        // Where it was is not where it is: read it, then hold there.
                        self.life.go(Step::SafeAlign);
                        self.life.base.mark_sent(ctx.tick, ctx.now_ns);
                        self.life.expect(addr, len, None);
                        self.push_read(addr, len, ctx, out);
                        if self.life.base.status.tripped {
                            self.life.base.goal = Goal::Hold;
                        }
                        self.life.base.status.phase = Phase::Holding;
                        return;
                    }
                    let raw = self.last[i].unwrap_or(0);
                    let c = self.table[i];
                    let value = c.encode_raw(raw.clamp(c.write_range.0, c.write_range.1));
                    self.push_write(goal, c.len, value, ctx, out);
                    if managed {
                        self.push_read(goal, c.len, ctx, out);
                        self.life.expect(goal, c.len, Some(value));
                        // A servo that cut its own torque (a hardware error) holds nothing.
                        self.push_read(T::TORQUE, 1, ctx, out);
                        self.life.expect(T::TORQUE, 1, None);
                        if self.life.base.status.tripped {
                            self.life.base.goal = Goal::Hold;
                        }
                        self.life.base.status.phase = Phase::Holding;
                    }
                }
                // Nothing known to hold (or limp already): the only safe thing is to let go.
                _ => self.safe(SafeAction::TorqueOff, ctx, out),
            },
            SafeAction::TorqueOff | SafeAction::Damp { .. } => {
                self.push_write(T::TORQUE, 1, 0, ctx, out);
                if managed {
                    self.push_read(T::TORQUE, 1, ctx, out);
                    self.life.expect(T::TORQUE, 1, Some(0));
                    self.life.base.goal = Goal::Limp;
                    self.life.base.status.phase = Phase::Disabled;
                }
            }
            SafeAction::Setpoint { channel, value } => {
                let Some(c) = self.table.get(channel).copied() else {
                    return;
                };
                let Some(addr) = c.write else { return };
                let raw = c.encode_raw(c.to_raw(value));
                self.push_write(addr, c.len, raw, ctx, out);
                if managed {
                    self.push_read(addr, c.len, ctx, out);
                    self.life.expect(addr, c.len, Some(raw));
                    self.life.base.status.phase = Phase::Holding;
                }
            }
        }
    }

    fn status(&self) -> DeviceStatus {
        self.life.base.status
    }

    fn bring_up(&mut self, startup: Startup, _ctx: TickCtx) {
        let l = &mut self.life;
        l.base.bring_up(startup);
        l.torque = None;
        l.go(Step::Probe);
    }

    fn bus_lost(&mut self) {
        if !self.life.managed() {
            return;
        }
        self.pending.iter_mut().for_each(|p| *p = None);
        let l = &mut self.life;
        l.base.bus_lost();
        // An automatic recovery under way resumes too.
        l.base.resume_on |= l.recovering;
        l.n_expect = 0;
    }

    fn accepts(&self, channel: usize) -> bool {
        if channel == self.enable_channel() {
            return self.life.managed();
        }
        let writable = self.table.get(channel).is_some_and(|c| c.write.is_some());
        writable && self.life.base.accepts_setpoints()
    }

    fn trip(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.life.base.begin_trip();
        self.safe(action, ctx, out);
    }

    fn report(&mut self, ctx: TickCtx, out: &mut Bounded<Update>) {
        if std::mem::take(&mut self.life.report_enable) {
            let on = self.enabled() && self.life.managed();
            let _ = out.push(Update::local(self.enable_channel(), on as u8 as f64, ctx));
        }
    }

    fn configure_reads(&mut self, sampled: &[usize]) {
        let regs = || {
            sampled
                .iter()
                .filter_map(|&i| self.table.get(i))
                .filter_map(|c| Some((c.read?, c.len as u16)))
        };
        let lo = regs().map(|(a, _)| a).min().unwrap_or(0);
        let hi = regs().map(|(a, l)| a + l).max().unwrap_or(0);
        // Registers shared by several channels are read once.
        let mut sum = 0u16;
        let mut seen: [(u16, u16); 16] = [(0, 0); 16];
        let mut n_seen = 0;
        for (a, l) in regs() {
            if !seen[..n_seen].contains(&(a, l)) && n_seen < seen.len() {
                seen[n_seen] = (a, l);
                n_seen += 1;
                sum += l;
            }
        }
        let span = hi.saturating_sub(lo);
        self.layout = Layout {
            indirect: 0,
            contiguous: span,
        };
        let Some(ind) = T::INDIRECT else { return };
        if n_seen == 0 || sum >= span || sum > ind.slots || n_seen == seen.len() {
            return;
        }
        // Map each register's bytes into consecutive indirect slots.
        let mut slot = 0u16;
        for &(a, l) in &seen[..n_seen] {
            for i in 0..self.table.len() {
                if self.table[i].read == Some(a)
                    && self.table[i].len as u16 == l
                    && sampled.contains(&i)
                {
                    self.read_at[i] = Some(ind.data + slot);
                }
            }
            for b in 0..l {
                self.config.push(ConfigItem {
                    name: "indirect_address",
                    addr: ind.addr + 2 * (slot + b),
                    len: 2,
                    value: (a + b) as i64,
                });
            }
            slot += l;
        }
        self.layout.indirect = sum;
    }

    fn describe(&self) -> String {
        let model = self.life.base.status.model.map(|m| {
            let name = self
                .family
                .models()
                .iter()
                .find(|(n, _)| *n == m)
                .map_or("?", |(_, name)| *name);
            format!("{name} (model {m})")
        });
        let reads = if self.layout.indirect > 0 {
            format!(
                "reads {} B per cycle through indirect addressing (the registers' contiguous span: {} B)",
                self.layout.indirect, self.layout.contiguous
            )
        } else if self.layout.contiguous > 0 {
            format!(
                "reads its registers' contiguous span, {} B per cycle",
                self.layout.contiguous
            )
        } else {
            "reads nothing each cycle".into()
        };
        let config: Vec<String> = self
            .config
            .iter()
            .filter(|c| c.name != "indirect_address")
            .map(|c| format!("{} {}", c.name, c.value))
            .collect();
        format!(
            "{}; {}{}",
            model.unwrap_or_else(|| "model unknown".into()),
            reads,
            if config.is_empty() {
                String::new()
            } else {
                format!("; configured: {}", config.join(", "))
            }
        )
    }
}
