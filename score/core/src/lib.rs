//! # score-core
//!
//! Score turns a microcontroller into a machine of *signal variables*: an ADC channel, an
//! integral of it, a scaled copy, a PWM output that follows an expression, each refreshed at its
//! own rate, configured by typing a few lines (the command language of Sherbert's 2011 thesis,
//! chapters 4 and 5). This crate is the whole language and runtime, `no_std` and without heap:
//!
//! * [`Engine::execute`] parses one command line, checks it completely (names, numbers,
//!   channels, capacities, cycles), and only then changes the table;
//! * [`Engine::tick`] runs the periodic variables that are due, rate-monotonic and
//!   deterministic; bare expressions are evaluated when read;
//! * [`hal`] holds the traits a port implements (ADC, PWM, GPIO, files, clock, serial);
//! * [`Engine::vars`], [`Engine::value`], [`Engine::set`] serve programs such as the USB gateway.
//!
//! ```
//! use score_core::{hal::DummyHal, Engine};
//! let mut hal = DummyHal::default();
//! let mut score: Engine<f64> = Engine::new();
//! let mut out = String::new();
//! for line in ["adc 0 100", "defint I adc0 100", "defexp twice I 2 *"] {
//!     score.execute(line, &mut hal, &mut out).unwrap();
//! }
//! for t in 0..=100u64 {
//!     score.tick(t * 10_000, &mut hal); // 1 s at 100 Hz
//! }
//! // adc0 reads 512 * 3.0 / 1023 V; its integral over 1 s is that much, twice.
//! let v = score.value_of("twice").unwrap();
//! assert!((v - 2.0 * 512.0 * 3.0 / 1023.0).abs() < 1e-9);
//! ```
#![no_std]
#![deny(missing_docs)]

pub mod capacity;
mod command;
mod engine;
pub mod error;
mod expr;
pub mod hal;
pub mod help;
mod lexer;
pub mod line;
pub mod num;
mod program;
mod report;
mod run;
mod symbol;
pub mod text;
mod vars;

pub use capacity::{Capacities, CAPACITIES};
pub use command::{run_seconds, Outcome, RUN_EXPECTED};
pub use engine::{Engine, Menu};
pub use error::{Error, Result};
pub use num::{Num, Real};
pub use vars::{VarInfo, VarKind};

/// Index of a variable's slot in the table; stable while the variable exists.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct VarId(pub u8);

/// Bytes of an [`Engine`] with this build's [`Num`] and capacities (for firmware reports).
pub const ENGINE_BYTES: usize = core::mem::size_of::<Engine<Num>>();

/// The terminal prompt of the thesis.
pub const PROMPT: &str = "$> ";

/// The thesis' Fig. 5.20 PID script (`∗` typed as `*`) without its closing `log` line: the
/// workload of the host and firmware benchmarks, which read `PID` themselves. `sgnl` plays
/// `mpidin.log` at 1 kHz (any signal on [`hal::PlaybackHal`]); `PID` is `Kp sgnl + Ki ∫sgnl +
/// Kd d(sgnl)/dt` with the gains defined after their use. The thesis file itself is
/// `score/host/tests/thesis/fig5_20.score`, and a test there checks that this is it.
pub const FIG_5_20_PID: &str = "var
defdiff Dsgnl sgnl 1000
defint Isgnl sgnl 1000
defexp Iterm Isgnl Ki *
defexp Dterm Dsgnl Kd *
defexp Pterm sgnl Kp *
defexp PID Pterm Iterm + Dterm +
defexp Kp 21
defexp Ki 350
defexp Kd 0.0788
infile sgnl 1000 mpidin.log";

/// Prints the start-up banner (thesis Fig. 5.1, with this program's name and version).
pub fn write_banner(out: &mut dyn core::fmt::Write) -> core::fmt::Result {
    writeln!(out, "Welcome to Score (v{})", env!("CARGO_PKG_VERSION"))?;
    writeln!(out, "(Systems Engineering Embedded Prototyping System)")?;
    writeln!(out, "Type 'help' for a command listing")
}
