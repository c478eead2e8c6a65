//! The orderly stop: the stop signal forwarded to every process, a bounded wait (then SIGKILL),
//! what dead processes left removed, and the report of how each ended.

use std::time::Instant;

use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;

use super::{describe, Phase, Role, Supervisor, POLL};
use crate::cleanup::scan_and_clean;
use crate::launcher::{LaunchError, LaunchReport, SubsystemReport};

impl Supervisor {
    /// Stops every executor and gateway (forwarding the signal that asked for it), waits, kills
    /// stragglers, removes what they left behind.
    pub(super) fn stop_all(&mut self) -> Result<LaunchReport, LaunchError> {
        let sig = Signal::try_from(self.stop.signal()).unwrap_or(Signal::SIGTERM);
        for c in &self.children {
            if let Some(p) = &c.proc {
                let _ = kill(Pid::from_raw(p.id() as i32), sig);
            }
        }
        let deadline = Instant::now() + self.opts.stop_timeout;
        let mut failures = Vec::new();
        for c in &mut self.children {
            let Some(mut p) = c.proc.take() else { continue };
            let status = loop {
                match p.try_wait() {
                    Ok(Some(s)) => break Some(s),
                    Ok(None) if Instant::now() < deadline => std::thread::sleep(POLL),
                    _ => {
                        let _ = p.kill();
                        failures.push(format!(
                            "{}: did not stop within {:?}, killed",
                            c.subsystem, self.opts.stop_timeout
                        ));
                        break p.wait().ok();
                    }
                }
            };
            c.drain_output();
            if let Some(s) = status {
                if !s.success() && !failures.iter().any(|f| f.starts_with(&c.subsystem)) {
                    failures.push(format!("{}: {}", c.subsystem, describe(&s)));
                }
                c.exit = Some(s);
            }
            c.phase = Phase::Stopped;
        }
        for c in &self.children {
            if let Some(why) = &c.failed {
                failures.push(format!("{}: given up: {why}", c.role.label(&c.subsystem)));
            }
        }
        let _ = scan_and_clean(&self.domain);
        for i in 0..self.children.len() {
            self.set_info(i, None, false);
        }
        let gateways = self
            .children
            .iter()
            .filter(|c| matches!(c.role, Role::Gateway(_)))
            .count();
        let executors = self
            .children
            .iter()
            .filter(|c| matches!(c.role, Role::Executor))
            .count();
        let view = if self
            .children
            .iter()
            .any(|c| matches!(c.role, Role::View(_)))
        {
            " and the view"
        } else {
            ""
        };
        match (gateways, view.is_empty()) {
            (0, _) => note!("conductor: {executors} executor(s){view} stopped"),
            (g, true) => note!("conductor: {executors} executor(s) and {g} gateway(s) stopped"),
            (g, false) => note!("conductor: {executors} executor(s), {g} gateway(s){view} stopped"),
        }
        if !failures.is_empty() {
            return Err(LaunchError::Unclean { failures });
        }
        Ok(LaunchReport {
            domain: self.domain.name().into(),
            subsystems: self
                .children
                .iter()
                .map(|c| SubsystemReport {
                    subsystem: c.subsystem.clone(),
                    kind: c.role.kind(),
                    restarts: c.restarts,
                    exit_code: c.exit.and_then(|s| s.code()),
                })
                .collect(),
        })
    }
}
