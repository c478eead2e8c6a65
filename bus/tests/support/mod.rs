//! Helpers for cross-process tests: start `conductor-bus-peer` processes on a private domain.

#![allow(dead_code)]

use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use conductor_bus::Domain;

/// A peer process whose stdout lines arrive on a channel.
pub struct Peer {
    pub child: Child,
    lines: mpsc::Receiver<String>,
}

impl Peer {
    /// Starts `conductor-bus-peer --domain <d> <args>`.
    pub fn start(domain: &Domain, args: &[&str]) -> Peer {
        let (child, lines) = conductor_testkit::spawn_with_lines(
            Command::new(env!("CARGO_BIN_EXE_conductor-bus-peer"))
                .arg("--domain")
                .arg(domain.name())
                .args(args)
                .stderr(Stdio::inherit()),
        );
        Peer { child, lines }
    }

    /// The next stdout line, or panics after `secs`.
    pub fn line(&self, secs: u64) -> String {
        self.lines
            .recv_timeout(Duration::from_secs(secs))
            .expect("peer printed nothing in time")
    }

    /// Waits for the peer's `READY` line.
    pub fn ready(self) -> Peer {
        let l = self.line(20);
        assert_eq!(l, "READY", "peer did not start");
        self
    }

    /// Waits for exit and returns (success, remaining stdout lines).
    pub fn finish(mut self) -> (bool, Vec<String>) {
        let ok = self.child.wait().expect("wait peer").success();
        let mut rest = Vec::new();
        while let Ok(l) = self.lines.recv_timeout(Duration::from_millis(500)) {
            rest.push(l);
        }
        (ok, rest)
    }
}

impl Drop for Peer {
    /// SIGTERM, so the peer drops its ports and releases the domain's shared memory; SIGKILL only
    /// if it does not exit within 5 s.
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            // SAFETY: kill(2) on our own child's pid has no memory-safety preconditions.
            unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
            let deadline = std::time::Instant::now() + Duration::from_secs(5);
            while std::time::Instant::now() < deadline {
                if let Ok(Some(_)) = self.child.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

/// Parses `received R missed M last_seq S`.
pub fn parse_report(line: &str) -> (u64, u64, Option<u64>) {
    let f: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(f.len(), 6, "unexpected report {line:?}");
    (
        f[1].parse().unwrap(),
        f[3].parse().unwrap(),
        f[5].parse().ok(),
    )
}
