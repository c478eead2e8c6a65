//! The engine: symbol table, dependency graph, lazy evaluation and the rate-monotonic scheduler.

use core::fmt::Write as _;

use crate::capacity::{MAX_EXPR_OPS, MAX_PATH_LEN, MAX_STREAMS, MAX_SYMBOLS};
use crate::expr::{self, Op};
use crate::hal::{AdcInput, Hal, StreamId};
use crate::num::{Num, Real};
use crate::symbol::{Kind, Operand, SymSet, Symbol};
use crate::text::{BufWriter, ShortStr};
use crate::VarId;

/// Which command list `help` shows (the thesis' main and variables menus). Every command is
/// accepted in either menu.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Menu {
    /// Hardware configuration (`adc`, `pwm`, ...).
    #[default]
    Main,
    /// Variables (`printvars`, `defexp`, ...).
    Var,
}

/// An open `infile`/`log` file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Stream {
    pub id: StreamId,
    pub path: ShortStr<MAX_PATH_LEN>,
}

/// The Score engine: a fixed-capacity table of signal variables and their scheduler.
///
/// Data flow: the port feeds command lines to [`Engine::execute`] (which parses, checks, and only
/// then changes the table) and calls [`Engine::tick`] with the current time; `tick` runs every
/// periodic variable that is due, highest rate first, producers before consumers at equal rates.
/// Bare expressions are evaluated when something reads them. The engine owns no hardware: calls
/// that touch it take the port's [`Hal`].
///
/// `Engine` is `Clone + PartialEq` so that a table can be snapshotted and compared.
#[derive(Debug, Clone, PartialEq)]
pub struct Engine<N: Real = Num> {
    pub(crate) syms: [Option<Symbol<N>>; MAX_SYMBOLS],
    pub(crate) ops: [Op<N>; MAX_EXPR_OPS],
    pub(crate) ops_used: usize,
    pub(crate) streams: [Option<Stream>; MAX_STREAMS],
    /// What a reader of slot i must have fresh: i itself, plus for a lazy i its inputs' views.
    pub(crate) view: [SymSet; MAX_SYMBOLS],
    /// What computing slot i's new value reads.
    pub(crate) needs: [SymSet; MAX_SYMBOLS],
    /// Lazy slots in dependency order (inputs first).
    pub(crate) eval_order: [u8; MAX_SYMBOLS],
    pub(crate) eval_len: usize,
    /// Periodic slots in priority order: rate descending, then producers before consumers.
    pub(crate) run_order: [u8; MAX_SYMBOLS],
    pub(crate) run_len: usize,
    pub(crate) now_us: u64,
    pub(crate) menu: Menu,
    pub(crate) generation: u32,
}

impl<N: Real> Default for Engine<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<N: Real> Engine<N> {
    /// An empty table at time 0. `const`, so a firmware can place the engine (16-23 KB, see
    /// the `capacities` command) in a `static` instead of building it on the stack.
    pub const fn new() -> Self {
        Engine {
            syms: [None; MAX_SYMBOLS],
            ops: [Op::Bin(crate::expr::BinOp::Add); MAX_EXPR_OPS],
            ops_used: 0,
            streams: [None; MAX_STREAMS],
            view: [SymSet::EMPTY; MAX_SYMBOLS],
            needs: [SymSet::EMPTY; MAX_SYMBOLS],
            eval_order: [0; MAX_SYMBOLS],
            eval_len: 0,
            run_order: [0; MAX_SYMBOLS],
            run_len: 0,
            now_us: 0,
            menu: Menu::Main,
            generation: 0,
        }
    }

    /// The current menu.
    pub fn menu(&self) -> Menu {
        self.menu
    }

    /// Incremented by every change of the table (definitions, deletions, rate changes; not by
    /// value updates). A gateway re-lists the variables when it changes.
    pub fn generation(&self) -> u32 {
        self.generation
    }

    /// The latest time given to [`Engine::tick`], in microseconds.
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// Number of variables in the table.
    pub fn len(&self) -> usize {
        self.syms.iter().flatten().count()
    }

    /// True if the table is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The slot of a variable by name.
    pub fn lookup(&self, name: &str) -> Option<VarId> {
        self.syms
            .iter()
            .position(|s| s.as_ref().is_some_and(|s| s.name.as_str() == name))
            .map(|i| VarId(i as u8))
    }

    pub(crate) fn sym(&self, id: VarId) -> Option<&Symbol<N>> {
        self.syms.get(id.0 as usize).and_then(|s| s.as_ref())
    }

    pub(crate) fn name_of(&self, id: VarId) -> &str {
        self.sym(id).map(|s| s.name.as_str()).unwrap_or("?")
    }

    pub(crate) fn refs(&self, id: usize, f: impl FnMut(VarId)) {
        if let Some(s) = &self.syms[id] {
            s.kind.for_each_ref(&self.ops[..self.ops_used], f);
        }
    }

    /// True if any other variable reads `id`.
    pub(crate) fn users(&self, id: VarId, mut f: impl FnMut(VarId)) {
        for i in 0..MAX_SYMBOLS {
            let mut uses = false;
            self.refs(i, |r| uses |= r == id);
            if uses && i != id.0 as usize {
                f(VarId(i as u8));
            }
        }
    }

    pub(crate) fn has_users(&self, id: VarId) -> bool {
        let mut any = false;
        self.users(id, |_| any = true);
        any
    }

    /// Slot indices sorted by name (ASCII, as `printvars` lists them).
    pub(crate) fn sorted_ids(&self) -> ([u8; MAX_SYMBOLS], usize) {
        let mut ids = [0u8; MAX_SYMBOLS];
        let mut n = 0;
        for (i, s) in self.syms.iter().enumerate() {
            if s.is_some() {
                ids[n] = i as u8;
                n += 1;
            }
        }
        // Insertion sort: at most MAX_SYMBOLS entries, no allocation.
        for a in 1..n {
            let mut b = a;
            while b > 0 && self.name_of(VarId(ids[b - 1])) > self.name_of(VarId(ids[b])) {
                ids.swap(b - 1, b);
                b -= 1;
            }
        }
        (ids, n)
    }

    /// Recomputes the evaluation order, the read sets and the task priorities after a change of
    /// the table. O(MAX_SYMBOLS^2); runs only on configuration changes.
    pub(crate) fn rebuild(&mut self) {
        let ops_used = self.ops_used;
        let lazy = |s: &Option<Symbol<N>>| s.as_ref().is_some_and(|s| s.kind.is_lazy());
        for i in 0..MAX_SYMBOLS {
            self.view[i] = SymSet::default();
            self.needs[i] = SymSet::default();
            if self.syms[i].is_some() && !lazy(&self.syms[i]) {
                self.view[i].insert(i);
            }
        }
        // Lazy slots in dependency order: repeatedly place the lowest slot whose lazy inputs are
        // placed. Definitions are checked for cycles before they enter the table, so every lazy
        // slot gets placed; a slot that could not be would simply never be re-evaluated.
        let mut placed = SymSet::default();
        self.eval_len = 0;
        loop {
            let mut progress = false;
            for i in 0..MAX_SYMBOLS {
                if placed.contains(i) || !lazy(&self.syms[i]) {
                    continue;
                }
                let mut ready = true;
                self.refs(i, |r| {
                    let r = r.0 as usize;
                    if r == i || (lazy(&self.syms[r]) && !placed.contains(r)) {
                        ready = false;
                    }
                });
                if ready {
                    placed.insert(i);
                    self.eval_order[self.eval_len] = i as u8;
                    self.eval_len += 1;
                    let mut needs = SymSet::default();
                    let view = &self.view;
                    if let Some(s) = &self.syms[i] {
                        s.kind.for_each_ref(&self.ops[..ops_used], |r| {
                            needs.union(&view[r.0 as usize])
                        });
                    }
                    self.needs[i] = needs;
                    self.view[i] = needs;
                    self.view[i].insert(i);
                    progress = true;
                }
            }
            if !progress {
                break;
            }
        }
        for i in 0..MAX_SYMBOLS {
            if self.syms[i].is_some() && !lazy(&self.syms[i]) {
                let mut needs = SymSet::default();
                let view = &self.view;
                if let Some(s) = &self.syms[i] {
                    s.kind
                        .for_each_ref(&self.ops[..ops_used], |r| needs.union(&view[r.0 as usize]));
                }
                self.needs[i] = needs;
            }
        }
        self.rebuild_run_order();
        self.generation = self.generation.wrapping_add(1);
    }

    /// The task that produces slot `j`'s value (an ADC's volts are written by its raw task).
    fn producer(&self, j: usize) -> usize {
        match self.syms[j].as_ref().map(|s| s.kind) {
            Some(Kind::AdcVolts { raw }) => raw.0 as usize,
            _ => j,
        }
    }

    fn rebuild_run_order(&mut self) {
        let is_task = |s: &Option<Symbol<N>>| s.as_ref().is_some_and(|s| s.task.is_some());
        // Producers first: place the lowest task whose producer tasks are placed; when only
        // cycles (through stateful blocks) remain, place the lowest remaining task.
        let mut rank = [0u8; MAX_SYMBOLS];
        let mut placed = SymSet::default();
        let total = self.syms.iter().filter(|s| is_task(s)).count();
        for r in 0..total {
            let mut pick = None;
            for i in 0..MAX_SYMBOLS {
                if placed.contains(i) || !is_task(&self.syms[i]) {
                    continue;
                }
                let ready = (0..MAX_SYMBOLS).all(|j| {
                    let p = self.producer(j);
                    !self.needs[i].contains(j)
                        || p == i
                        || !is_task(&self.syms[p])
                        || placed.contains(p)
                });
                if ready {
                    pick = Some(i);
                    break;
                }
            }
            let i = pick.or_else(|| {
                (0..MAX_SYMBOLS).find(|&i| is_task(&self.syms[i]) && !placed.contains(i))
            });
            let Some(i) = i else { break };
            placed.insert(i);
            rank[i] = r as u8;
        }
        self.run_len = 0;
        for i in 0..MAX_SYMBOLS {
            if is_task(&self.syms[i]) {
                self.run_order[self.run_len] = i as u8;
                self.run_len += 1;
            }
        }
        let key = |e: &Self, i: u8| {
            let mhz = e.syms[i as usize]
                .as_ref()
                .and_then(|s| s.task)
                .map_or(0, |t| t.mhz);
            (u32::MAX - mhz, rank[i as usize])
        };
        for a in 1..self.run_len {
            let mut b = a;
            while b > 0 && key(self, self.run_order[b - 1]) > key(self, self.run_order[b]) {
                self.run_order.swap(b - 1, b);
                b -= 1;
            }
        }
    }

    /// Recomputes the lazy members of `set` in dependency order.
    fn refresh(&mut self, set: SymSet) {
        for k in 0..self.eval_len {
            let j = self.eval_order[k] as usize;
            if set.contains(j) {
                let v = self.compute_lazy(j);
                if let Some(s) = &mut self.syms[j] {
                    s.value = v;
                }
            }
        }
    }

    #[inline]
    fn stored(&self, id: VarId) -> N {
        self.syms
            .get(id.0 as usize)
            .and_then(|s| s.as_ref())
            .map_or(N::ZERO, |s| s.value)
    }

    fn operand(&self, o: Operand<N>) -> N {
        match o {
            Operand::Lit(v) => v,
            Operand::Var(id) => self.stored(id),
        }
    }

    fn compute_lazy(&self, j: usize) -> N {
        let Some(s) = &self.syms[j] else {
            return N::ZERO;
        };
        match s.kind {
            Kind::Expr { start, len } => {
                let (s, l) = (start as usize, len as usize);
                expr::eval(&self.ops[s..s + l], |id| self.stored(id))
            }
            Kind::Scale { src, a, b, c, d } => {
                let y = c + (self.stored(src) - a) * (d - c) / (b - a);
                let (lo, hi) = if c <= d { (c, d) } else { (d, c) };
                clamp(y, lo, hi)
            }
            Kind::Sat { src, lo, hi } => clamp(self.stored(src), lo, hi),
            _ => s.value,
        }
    }

    /// Current value of a variable, evaluating bare expressions on demand.
    pub fn value(&mut self, id: VarId) -> Option<N> {
        let s = self.sym(id)?;
        if s.kind.is_lazy() {
            let set = self.view[id.0 as usize];
            self.refresh(set);
        }
        self.sym(id).map(|s| s.value)
    }

    /// Current value of a variable by name.
    pub fn value_of(&mut self, name: &str) -> Option<N> {
        let id = self.lookup(name)?;
        self.value(id)
    }

    /// Tells the engine the current time without running any update (never backwards). A
    /// periodic variable defined afterwards first runs at this instant; ports call it before
    /// [`Engine::execute`] so that new variables start when they are typed.
    pub fn set_time(&mut self, now_us: u64) {
        self.now_us = self.now_us.max(now_us);
    }

    /// The earliest instant at which a periodic variable is due (`now_us` for one that has not
    /// run yet), or `None` if nothing is periodic. A simulated-time port jumps straight there.
    pub fn next_deadline(&self) -> Option<u64> {
        self.syms
            .iter()
            .flatten()
            .filter_map(|s| s.task)
            .map(|t| t.due.unwrap_or(self.now_us))
            .min()
    }

    /// Runs every periodic variable that is due at `now_us`, in priority order (rate descending;
    /// at equal rates producers before consumers; then slot order). A task more than one period
    /// late runs once, at its latest due instant, and counts the skipped updates instead of
    /// catching up in a burst. Returns how many updates ran. Time never goes backwards: an older
    /// `now_us` is treated as the latest one seen.
    pub fn tick(&mut self, now_us: u64, hal: &mut impl Hal) -> usize {
        if now_us > self.now_us {
            self.now_us = now_us;
        }
        let now = self.now_us;
        let mut ran = 0;
        for k in 0..self.run_len {
            let i = self.run_order[k] as usize;
            let Some(mut task) = self.syms[i].as_ref().and_then(|s| s.task) else {
                continue;
            };
            let t = match task.due {
                None => now,
                Some(due) if due > now => continue,
                Some(due) => {
                    let behind = task.periods_behind(due, now);
                    if behind > 0 {
                        task.missed = task
                            .missed
                            .saturating_add(behind.min(u32::MAX as u64) as u32);
                        task.advance(due, behind);
                    }
                    task.due.unwrap_or(now)
                }
            };
            task.advance_one(t);
            task.last = Some(t);
            if let Some(s) = &mut self.syms[i] {
                s.task = Some(task);
            }
            self.update(i, t, hal);
            ran += 1;
        }
        ran
    }

    /// One update of periodic slot `i` at instant `t`.
    fn update(&mut self, i: usize, t: u64, hal: &mut impl Hal) {
        self.refresh(self.needs[i]);
        let Some(sym) = self.syms[i] else { return };
        let mut kind = sym.kind;
        let value = match &mut kind {
            Kind::AdcRaw { input, volts } => match hal.adc_read(*input) {
                Ok(raw) => {
                    let v = self.volts(*input, raw, hal);
                    if let Some(s) = &mut self.syms[volts.0 as usize] {
                        s.value = v;
                    }
                    N::from_u32(raw as u32)
                }
                Err(_) => sym.value,
            },
            Kind::Int { src, st } => st.step(t, self.stored(*src)),
            Kind::Wind {
                src,
                gain,
                pre,
                post,
                st,
            } => {
                let x = self.stored(*src) + *gain * (self.stored(*post) - self.stored(*pre));
                st.step(t, x)
            }
            Kind::Diff { src, st } => st.step(t, self.stored(*src)),
            Kind::Lpf {
                src,
                cutoff_hz,
                last_t,
            } => {
                let x = self.stored(*src);
                let y = match *last_t {
                    Some(t0) if t > t0 => {
                        let dt = N::seconds_from_us(t - t0);
                        let tau = N::ONE / (N::from_f64(core::f64::consts::TAU) * *cutoff_hz);
                        sym.value + dt / (tau + dt) * (x - sym.value)
                    }
                    Some(_) => sym.value,
                    None => x,
                };
                *last_t = Some(t);
                y
            }
            Kind::Pid {
                src,
                kp,
                ki,
                kd,
                limits,
                int,
                der,
            } => {
                let e = self.stored(*src);
                let (kp, ki, kd) = (self.operand(*kp), self.operand(*ki), self.operand(*kd));
                let before = int.acc;
                let i_term = int.step(t, e);
                let d_term = der.step(t, e);
                let u = kp * e + ki * i_term + kd * d_term;
                match *limits {
                    None => u,
                    Some((lo, hi)) => {
                        // Conditional integration: a step that would push the output further
                        // into saturation only goes as far as the limit (never past the value
                        // before the step, so it neither winds up nor unwinds by itself).
                        let limit = if u > hi && e * ki > N::ZERO {
                            Some(hi)
                        } else if u < lo && e * ki < N::ZERO {
                            Some(lo)
                        } else {
                            None
                        };
                        if let Some(limit) = limit {
                            let target = (limit - kp * e - kd * d_term) / ki;
                            let (a, b) = if before <= i_term {
                                (before, i_term)
                            } else {
                                (i_term, before)
                            };
                            int.acc = clamp(target, a, b);
                        }
                        clamp(kp * e + ki * int.acc + kd * d_term, lo, hi)
                    }
                }
            }
            Kind::PwmFollow { src, out, .. } => {
                let x = self.stored(*src) / N::from_u32(100);
                let duty = if x.is_finite() {
                    clamp(x, N::ZERO, N::ONE)
                } else {
                    N::ZERO
                };
                let applied = hal.pwm_set_duty(*out, duty.to_f64() as f32);
                N::from_f64(applied as f64) * N::from_u32(100)
            }
            Kind::GpioIn { pin } => bool_num(hal.gpio_read(*pin)),
            Kind::GpioOut { src, pin } => {
                let high = self.stored(*src) >= N::from_f64(0.5);
                hal.gpio_write(*pin, high);
                bool_num(high)
            }
            Kind::Infile {
                stream,
                len,
                cursor,
            } => match self.stream_id(*stream) {
                Some(id) if *len > 0 => {
                    let v = N::from_f64(hal.input_sample(id, *cursor));
                    *cursor = (*cursor + 1) % *len;
                    v
                }
                _ => sym.value,
            },
            Kind::Log { src, stream } => {
                let x = self.stored(*src);
                if let Some(id) = self.stream_id(*stream) {
                    let mut buf = [0u8; 48];
                    let mut w = BufWriter::new(&mut buf);
                    if write!(w, "{}", crate::num::Compact(x)).is_ok() {
                        hal.write_log(id, w.as_str());
                    }
                }
                x
            }
            _ => sym.value,
        };
        if let Some(s) = &mut self.syms[i] {
            s.kind = kind;
            s.value = value;
        }
    }

    pub(crate) fn stream_id(&self, slot: u8) -> Option<StreamId> {
        self.streams
            .get(slot as usize)
            .and_then(|s| s.as_ref())
            .map(|s| s.id)
    }

    /// Volts of a raw code (thesis: `[0, vref]` single-ended, `[-vref/2, vref/2]` differential).
    pub(crate) fn volts(&self, input: AdcInput, raw: u16, hal: &impl Hal) -> N {
        let vref = N::from_f64(hal.adc_reference_volts() as f64);
        let fs = N::from_u32(hal.adc_full_scale().max(1) as u32);
        let v = N::from_u32(raw as u32) * vref / fs;
        match input {
            AdcInput::Differential(_) => v - vref / N::from_u32(2),
            _ => v,
        }
    }
}

#[inline]
pub(crate) fn clamp<N: Real>(y: N, lo: N, hi: N) -> N {
    if y < lo {
        lo
    } else if y > hi {
        hi
    } else {
        y
    }
}

#[inline]
fn bool_num<N: Real>(b: bool) -> N {
    if b {
        N::ONE
    } else {
        N::ZERO
    }
}
