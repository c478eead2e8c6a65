//! `score_link`: the binary link between a Score board (RP2040 firmware) and its host gateway,
//! carried on the board's second USB CDC-ACM interface.
//!
//! # Layers
//!
//! ```text
//! message  = version u8 | kind u8 | seq u16 | body ...          (≤ MAX_MESSAGE bytes, little-endian)
//! checked  = message | crc16(message) u16                         (CRC-16/UMTS, as Dynamixel 2.0)
//! frame    = COBS(checked) | 0x00                                 (0x00 never occurs inside)
//! ```
//!
//! COBS makes every frame end at the next `0x00`, so a reader that starts in the middle of a
//! stream (a gateway that reconnects) loses at most one frame; the CRC rejects a frame spliced
//! from two. [`FrameScanner`] turns bytes in any chunking into checked messages and counts what
//! it drops; [`encode_request`] / [`encode_reply`] produce whole frames.
//!
//! # Conversation
//!
//! The host sends [`Request`]s with a sequence number; the board answers each with one or more
//! [`Reply`]s carrying the same number (a variable listing is several [`Reply::Var`] and a final
//! [`Reply::ListEnd`]; a command line is zero or more [`Reply::Output`] chunks and a final
//! [`Reply::ExecDone`]). Unsolicited messages from the board use sequence number 0:
//! [`Reply::Samples`] (subscribed variables, stamped with the board's microsecond clock) and
//! [`Reply::TableChanged`] (the variable table changed; list again).
//!
//! Version: every message starts with [`VERSION`]. A peer that receives another version
//! answers nothing useful; the gateway checks [`Reply::Hello`] first and refuses to go on.

mod frame;
mod message;
mod wire;

pub use frame::{encode_frame, FrameError, FrameScanner, LinkStats, MAX_FRAME};
pub use message::{
    decode_reply, decode_request, encode_reply, encode_request, ErrorCode, Hello, MessageError,
    Reply, Request, SampleBatch, SampleIter, VarEntry, MAX_SAMPLES,
};

/// Protocol version carried in every message.
pub const VERSION: u8 = 1;

/// Largest message (header and body, before CRC and COBS).
pub const MAX_MESSAGE: usize = 250;

/// Longest text in one [`Reply::Output`] chunk or [`Request::Exec`] line.
pub const MAX_TEXT: usize = 200;
