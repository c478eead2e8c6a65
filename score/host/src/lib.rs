//! # score-host
//!
//! The x86 port of Score (thesis §4.2.2, "x86 port"): algorithms are proven here before they
//! touch hardware. It wraps [`score_core::Engine`] with a simulated board ([`board::SimBoard`]:
//! ADC inputs you set, PWM and GPIO you can inspect, real files for `infile` and `log`) and a
//! clock ([`session::TimeMode`]: simulated, deterministic and as fast as the CPU allows, or real
//! time). The `score` binary adds the REPL and `--script` batch runs.

#![deny(missing_docs)]

pub mod board;
pub mod session;

pub use session::{Session, SessionError, TimeMode};
