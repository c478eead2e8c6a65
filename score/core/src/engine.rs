//! The engine: symbol table, dependency graph, lazy evaluation and the rate-monotonic scheduler.

use crate::capacity::{MAX_EXPR_OPS, MAX_PATH_LEN, MAX_STREAMS, MAX_SYMBOLS};
use crate::hal::StreamId;
use crate::num::{Num, Real};
use crate::program::{Instr, Stack};
use crate::symbol::{Kind, SymSet, Symbol};
use crate::text::ShortStr;
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
/// that touch it take the port's [`Hal`](crate::hal::Hal).
///
/// `Engine` is `Clone + PartialEq` so that a table can be snapshotted and compared.
#[derive(Debug, Clone, PartialEq)]
pub struct Engine<N: Real = Num> {
    pub(crate) syms: [Option<Symbol<N>>; MAX_SYMBOLS],
    /// The value of each slot (0 for an empty one), apart from the symbols so that reading an
    /// input is one load and an update can change its own symbol while reading the others.
    pub(crate) values: [N; MAX_SYMBOLS],
    /// The compiled `defexp` expressions, one after the other (see [`crate::program`]).
    pub(crate) ops: [Instr<N>; MAX_EXPR_OPS],
    /// Instructions in use (at most the tokens they stand for, see `tokens_used`).
    pub(crate) ops_used: usize,
    pub(crate) streams: [Option<Stream>; MAX_STREAMS],
    /// What a reader of slot i must have fresh: i itself, plus for a lazy i its inputs' views.
    pub(crate) view: [SymSet; MAX_SYMBOLS],
    /// What computing slot i's new value reads.
    pub(crate) needs: [SymSet; MAX_SYMBOLS],
    /// Lazy slots in dependency order (inputs first).
    pub(crate) eval_order: [u8; MAX_SYMBOLS],
    /// For each position of `eval_order`, where its code is in `ops` if it is an expression
    /// (length 0 for a scale or saturation).
    pub(crate) eval_code: [(u16, u16); MAX_SYMBOLS],
    pub(crate) eval_len: usize,
    /// Periodic slots in priority order: rate descending, then producers before consumers.
    pub(crate) run_order: [u8; MAX_SYMBOLS],
    pub(crate) run_len: usize,
    /// The positions in `eval_order` of the first and past the last lazy slot that reading
    /// slot i (`view[i]`, lazy i) or updating it (`needs[i]`, periodic i) must refresh.
    pub(crate) span: [(u8, u8); MAX_SYMBOLS],
    /// Earliest `due` of the tasks that have one (`u64::MAX` if none) ...
    pub(crate) due_min: u64,
    /// ... and whether some task has not run yet (it is due at the next tick).
    pub(crate) due_now: bool,
    /// The evaluation stack of bare expressions (working memory, not state).
    pub(crate) stack: Stack<N>,
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
            values: [N::ZERO; MAX_SYMBOLS],
            ops: [Instr::BinPop(crate::expr::BinOp::Add); MAX_EXPR_OPS],
            ops_used: 0,
            streams: [None; MAX_STREAMS],
            view: [SymSet::EMPTY; MAX_SYMBOLS],
            needs: [SymSet::EMPTY; MAX_SYMBOLS],
            eval_order: [0; MAX_SYMBOLS],
            eval_code: [(0, 0); MAX_SYMBOLS],
            eval_len: 0,
            run_order: [0; MAX_SYMBOLS],
            run_len: 0,
            span: [(0, 0); MAX_SYMBOLS],
            due_min: u64::MAX,
            due_now: false,
            stack: Stack::new(),
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

    /// Tokens of all expressions together (the capacity [`MAX_EXPR_OPS`] counts tokens).
    pub(crate) fn tokens_used(&self) -> usize {
        crate::program::tokens_in(&self.ops[..self.ops_used])
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
        self.eval_code = [(0, 0); MAX_SYMBOLS];
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
                    self.eval_code[self.eval_len] = match self.syms[i].as_ref().map(|s| s.kind) {
                        Some(Kind::Expr { start, len }) => (start, len),
                        _ => (0, 0),
                    };
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
        self.rebuild_spans();
        self.rescan_deadlines();
        self.generation = self.generation.wrapping_add(1);
    }

    /// The task that produces slot `j`'s value (an ADC's volts are written by its raw task).
    fn producer(&self, j: usize) -> usize {
        match self.syms[j].as_ref().map(|s| s.kind) {
            Some(Kind::AdcVolts { raw }) => raw.0 as usize,
            _ => j,
        }
    }

    /// For each slot, where in `eval_order` the lazy slots it must refresh start and end.
    fn rebuild_spans(&mut self) {
        for i in 0..MAX_SYMBOLS {
            let set = match &self.syms[i] {
                Some(s) if s.kind.is_lazy() => self.view[i],
                Some(s) if s.task.is_some() => self.needs[i],
                _ => SymSet::EMPTY,
            };
            let order = &self.eval_order[..self.eval_len];
            let first = order.iter().position(|&j| set.contains(j as usize));
            let last = order.iter().rposition(|&j| set.contains(j as usize));
            self.span[i] = match (first, last) {
                (Some(a), Some(b)) => (a as u8, b as u8 + 1),
                _ => (0, 0),
            };
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
