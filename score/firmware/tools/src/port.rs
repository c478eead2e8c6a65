//! A serial port (a harness PTY or a real `/dev/ttyACM*`) for tests: raw bytes in and out with
//! wall-clock timeouts, and "read until" helpers for the terminal.

use std::io::{Read, Write};
use std::path::Path;
use std::time::{Duration, Instant};

use serialport::TTYPort;

/// An open serial port.
pub struct Port {
    tty: TTYPort,
    pending: Vec<u8>,
}

impl Port {
    /// Opens `path`, waiting up to `wait` for it to appear (a PTY link is created by the harness).
    pub fn open(path: &Path, wait: Duration) -> std::io::Result<Self> {
        let end = Instant::now() + wait;
        while !path.exists() && Instant::now() < end {
            std::thread::sleep(Duration::from_millis(20));
        }
        let tty = serialport::new(path.to_string_lossy(), 115_200)
            .timeout(Duration::from_millis(20))
            .open_native()
            .map_err(std::io::Error::from)?;
        Ok(Self {
            tty,
            pending: Vec::new(),
        })
    }

    /// Writes all of `bytes`.
    pub fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.tty.write_all(bytes)?;
        self.tty.flush()
    }

    /// Reads what arrives within `wait` (at least one read attempt).
    pub fn read_some(&mut self, wait: Duration) -> std::io::Result<Vec<u8>> {
        let end = Instant::now() + wait;
        let mut out = std::mem::take(&mut self.pending);
        let mut buf = [0u8; 4096];
        loop {
            match self.tty.read(&mut buf) {
                Ok(0) => {}
                Ok(n) => {
                    out.extend_from_slice(&buf[..n]);
                    continue;
                }
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            }
            if !out.is_empty() || Instant::now() >= end {
                return Ok(out);
            }
        }
    }

    /// Reads until the text received ends with `suffix` (after at least one byte), or fails
    /// with `TimedOut` after `wait`, carrying what arrived.
    pub fn read_until_suffix(&mut self, suffix: &str, wait: Duration) -> std::io::Result<String> {
        let end = Instant::now() + wait;
        let mut got = Vec::new();
        loop {
            let left = end.saturating_duration_since(Instant::now());
            got.extend(self.read_some(left.min(Duration::from_millis(200)))?);
            if got.ends_with(suffix.as_bytes()) {
                return Ok(String::from_utf8_lossy(&got).into_owned());
            }
            if Instant::now() >= end {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    format!(
                        "no {suffix:?} after {wait:?}; received {:?}",
                        String::from_utf8_lossy(&got)
                    ),
                ));
            }
        }
    }

    /// Bytes of the port's input not yet consumed by `read_until_suffix` are kept here.
    pub fn unread(&mut self, bytes: &[u8]) {
        let mut v = bytes.to_vec();
        v.extend(std::mem::take(&mut self.pending));
        self.pending = v;
    }
}
