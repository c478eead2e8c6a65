//! Parameters several kinds share, written once.

use super::spec::ParamSpec;

/// Meaning of a byte hardware's `baud`.
pub const BAUD_DOC: &str =
    "line speed (bit/s); the protocol stage also times its transactions with it";

/// A protocol stage's reply timeout.
pub const TIMEOUT_US: ParamSpec = ParamSpec::int(
    "timeout_us",
    Some(2_000),
    1.0,
    10_000_000.0,
    "margin after a transaction's expected end (wire time, return delays) before its replies count as missing (µs)",
);

/// The Dynamixel servos' Return Delay Time, as a bus (simulator or protocol stage) assumes it.
pub const RETURN_DELAY_US: ParamSpec = ParamSpec::int(
    "return_delay_us",
    Some(0),
    0.0,
    508.0,
    "the servos' Return Delay Time (address 9 × 2 µs); set the servos to 0 for the fastest bus",
);
