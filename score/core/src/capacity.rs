//! Compile-time capacities of the engine. Nothing grows at run time: a definition that would
//! exceed one of these is refused with [`crate::Error::Full`].

use core::fmt;

/// Symbols (variables) in the table, including the raw/volt pair of each ADC channel and the
/// placeholders created by forward references.
pub const MAX_SYMBOLS: usize = 64;
/// Longest symbol name in bytes.
pub const MAX_NAME_LEN: usize = 15;
/// Postfix tokens in one `defexp` expression (also the depth of the evaluation stack).
pub const MAX_EXPR_TOKENS: usize = 32;
/// Postfix tokens of all expressions together (one shared arena).
pub const MAX_EXPR_OPS: usize = 512;
/// Whitespace-separated tokens in one command line.
pub const MAX_TOKENS: usize = 40;
/// Bytes in one command line (see [`crate::line::LineBuffer`]).
pub const MAX_LINE: usize = 160;
/// Open `infile`/`log` streams (host port).
pub const MAX_STREAMS: usize = 8;
/// Longest `infile`/`log` file path in bytes.
pub const MAX_PATH_LEN: usize = 63;
/// Highest update rate of a periodic symbol, in Hz (the thesis' ADC limit).
pub const MAX_RATE_HZ: u32 = 100_000;
/// Lowest update rate of a periodic symbol, in millihertz.
pub const MIN_RATE_MILLIHZ: u32 = 1;
/// Longest `run` (and `score --run`), in seconds: 10⁹ s, about 31.7 years. Every clock of the
/// engine counts microseconds in a `u64` (≈ 584 000 years), so a run within this bound never
/// overflows a clock, while `run 1e30` is refused instead of wrapping it.
pub const MAX_RUN_SECONDS: f64 = 1e9;

// Slots are addressed by a `u8` (`VarId`), expression positions by a `u16`.
const _: () =
    assert!(MAX_SYMBOLS <= 255 && MAX_EXPR_OPS <= u16::MAX as usize && MAX_STREAMS <= 255);
const _: () = assert!(MAX_NAME_LEN <= 255 && MAX_PATH_LEN <= 255);

/// The capacities of this build, for reports (`capacities` command, firmware banner).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Capacities {
    /// [`MAX_SYMBOLS`].
    pub symbols: usize,
    /// [`MAX_NAME_LEN`].
    pub name_len: usize,
    /// [`MAX_EXPR_TOKENS`].
    pub expr_tokens: usize,
    /// [`MAX_EXPR_OPS`].
    pub expr_ops: usize,
    /// [`MAX_TOKENS`].
    pub line_tokens: usize,
    /// [`MAX_LINE`].
    pub line_bytes: usize,
    /// [`MAX_STREAMS`].
    pub streams: usize,
    /// [`MAX_PATH_LEN`].
    pub path_len: usize,
    /// [`MAX_RATE_HZ`].
    pub max_rate_hz: u32,
    /// Name of the build's number type ([`crate::Num`]).
    pub number_type: &'static str,
}

/// The capacities of this build.
pub const CAPACITIES: Capacities = Capacities {
    symbols: MAX_SYMBOLS,
    name_len: MAX_NAME_LEN,
    expr_tokens: MAX_EXPR_TOKENS,
    expr_ops: MAX_EXPR_OPS,
    line_tokens: MAX_TOKENS,
    line_bytes: MAX_LINE,
    streams: MAX_STREAMS,
    path_len: MAX_PATH_LEN,
    max_rate_hz: MAX_RATE_HZ,
    number_type: <crate::Num as crate::Real>::NAME,
};

impl fmt::Display for Capacities {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "capacities: {} symbols, names {} bytes, {} tokens per expression, {} expression tokens in all, \
             {} tokens / {} bytes per line, {} file streams, paths {} bytes, rates up to {} Hz, numbers {}",
            self.symbols,
            self.name_len,
            self.expr_tokens,
            self.expr_ops,
            self.line_tokens,
            self.line_bytes,
            self.streams,
            self.path_len,
            self.max_rate_hz,
            self.number_type
        )
    }
}
