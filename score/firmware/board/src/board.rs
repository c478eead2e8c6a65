//! [`Board`]: the engine, the port's HAL and the link's subscriptions, owned together so that
//! the terminal, the link and the update loop see one table.

use core::fmt::Write;

use score_core::hal::Hal;
use score_core::{Engine, Outcome, Real};

use crate::sampler::Sampler;

/// Who the board is (sent in the link's hello and printed by the terminal).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BoardInfo {
    /// Firmware name and version.
    pub firmware: &'static str,
    /// Board name: the gateway publishes under `conductor/score-<board>/`.
    pub board: &'static str,
}

/// A port's own commands (the firmware's `bench`, `board`): given a command line, write its
/// output and return `Some(ok)`, or `None` if the line is not one of them.
pub type Extra<'a> = &'a mut dyn FnMut(&str, &mut dyn Write) -> Option<bool>;

/// The engine with its hardware and subscriptions.
pub struct Board<N: Real, H: Hal> {
    /// The Score table.
    pub engine: Engine<N>,
    /// The hardware.
    pub hal: H,
    /// Link subscriptions.
    pub sampler: Sampler,
    /// Identity.
    pub info: BoardInfo,
    announced: u32,
}

impl<N: Real, H: Hal> Board<N, H> {
    /// An empty table on `hal`.
    pub const fn new(hal: H, info: BoardInfo) -> Self {
        Self {
            engine: Engine::new(),
            hal,
            sampler: Sampler::new(),
            info,
            announced: 0,
        }
    }

    /// Runs the updates due at `now_us`; returns how many ran.
    pub fn tick(&mut self, now_us: u64) -> usize {
        self.engine.tick(now_us, &mut self.hal)
    }

    /// The earliest instant something is due: an update or a bare-expression sample.
    pub fn next_wake(&self) -> Option<u64> {
        match (
            self.engine.next_deadline(),
            self.sampler.next_due(&self.engine),
        ) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The table's generation if it changed since the last call (the link announces it).
    pub fn take_table_change(&mut self) -> Option<u32> {
        let g = self.engine.generation();
        (g != self.announced).then(|| {
            self.announced = g;
            g
        })
    }

    /// Collects the subscribed samples due at `now_us` (see [`Sampler::collect`]).
    pub fn collect_samples(&mut self, now_us: u64, emit: impl FnMut(u64, &[(u8, f64)])) {
        self.sampler
            .collect(&mut self.engine, &mut self.hal, now_us, emit)
    }

    /// Runs one command line as typed on the terminal: the port's own commands first, then
    /// the engine (its errors printed as `error: ...`). File and time commands have nothing
    /// to act on here and say so. Returns false if the line failed.
    pub fn run_line(
        &mut self,
        line: &str,
        now_us: u64,
        out: &mut impl Write,
        extra: Extra<'_>,
    ) -> bool {
        if let Some(ok) = extra(line, out) {
            return ok;
        }
        self.engine.set_time(now_us);
        match self.engine.execute(line, &mut self.hal, out) {
            Ok(Outcome::Done) => true,
            Ok(other) => {
                let what = match other {
                    Outcome::Script(_) => "script",
                    Outcome::Load(_) => "load",
                    Outcome::Save(_) => "save",
                    _ => "run",
                };
                let _ = writeln!(
                    out,
                    "error: {what}: not available on the board (no files; time runs by itself)"
                );
                false
            }
            Err(e) => {
                let _ = writeln!(out, "error: {e}");
                false
            }
        }
    }
}
