//! Matching acknowledgements to the commands that caused them.
//!
//! The adapter answers commands in order, interleaved with received frames. The host records
//! each command it sends; each acknowledgement ([`Response::Ok`], [`Response::Error`],
//! [`Response::TxAck`]) resolves the oldest. Timeouts are the caller's: it tags entries (e.g.
//! with the tick they were sent in) and drops stale ones with [`PendingAcks::pop`].

use super::{Command, Response};

/// What kind of command awaits its acknowledgement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandKind {
    /// A frame transmission (`t`/`T`/`r`/`R`).
    Transmit,
    /// A query answered with data (`F`, `V`, `N`): the data line is the acknowledgement.
    Query,
    /// Anything else (open, close, bitrate, settings).
    Control,
}

impl CommandKind {
    /// The kind of `cmd`.
    pub fn of(cmd: &Command) -> Self {
        match cmd {
            Command::Transmit(_) => CommandKind::Transmit,
            Command::ReadStatus | Command::Version | Command::SerialNumber => CommandKind::Query,
            _ => CommandKind::Control,
        }
    }
}

/// A resolved command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Acked {
    /// The command's kind.
    pub kind: CommandKind,
    /// The caller's tag given to [`PendingAcks::push`].
    pub tag: u32,
    /// False for a BEL.
    pub ok: bool,
}

/// The FIFO is full: too many unacknowledged commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("too many commands awaiting acknowledgement")]
pub struct QueueFull;

/// Fixed-capacity FIFO of commands awaiting acknowledgement.
pub struct PendingAcks<const N: usize = 32> {
    ring: [(CommandKind, u32); N],
    head: usize,
    len: usize,
}

impl<const N: usize> Default for PendingAcks<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> PendingAcks<N> {
    /// An empty queue.
    pub fn new() -> Self {
        Self {
            ring: [(CommandKind::Control, 0); N],
            head: 0,
            len: 0,
        }
    }

    /// Records a sent command.
    pub fn push(&mut self, kind: CommandKind, tag: u32) -> Result<(), QueueFull> {
        if self.len == N {
            return Err(QueueFull);
        }
        self.ring[(self.head + self.len) % N] = (kind, tag);
        self.len += 1;
        Ok(())
    }

    /// The oldest pending command.
    pub fn front(&self) -> Option<(CommandKind, u32)> {
        (self.len > 0).then(|| self.ring[self.head])
    }

    /// Removes the oldest pending command (e.g. on timeout).
    pub fn pop(&mut self) -> Option<(CommandKind, u32)> {
        let f = self.front()?;
        self.head = (self.head + 1) % N;
        self.len -= 1;
        Some(f)
    }

    /// Removes the newest pending command (a command taken back before it was sent).
    pub fn pop_back(&mut self) -> Option<(CommandKind, u32)> {
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        Some(self.ring[(self.head + self.len) % N])
    }

    /// Forgets every pending command.
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// Number of pending commands.
    pub fn len(&self) -> usize {
        self.len
    }

    /// No pending command.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Resolves the oldest command if `r` acknowledges it. Received frames and unsolicited
    /// lines return `None` and leave the queue alone; a query reply resolves a pending query.
    pub fn resolve(&mut self, r: &Response<'_>) -> Option<Acked> {
        let ok = match r {
            Response::Ok | Response::TxAck { .. } => true,
            Response::Error => false,
            Response::Status(_) | Response::Version(_) | Response::Serial(_) => {
                if self.front()?.0 != CommandKind::Query {
                    return None;
                }
                true
            }
            Response::Frame { .. } | Response::ErrorFrame(_) | Response::BusState(_) => {
                return None
            }
        };
        let (kind, tag) = self.pop()?;
        Some(Acked { kind, tag, ok })
    }
}
