//! Readiness: the ready lines of the supervised processes' stdout (an executor's `READY`, a
//! gateway's or the view's `ready <name> …`) as events, and the start-up wait for every executor.

use std::process::Child;
use std::time::Instant;

use super::{describe, Phase, Role, Supervisor, POLL};
use crate::launcher::LaunchError;
use crate::process::{EXIT_CONFIG, EXIT_NO_RT, READY};
use conductor_manifest::GatewayKind;

/// What a supervised process's stdout told.
pub(super) enum EventKind {
    /// The process reported ready; for a gateway, what its ready line said after its name.
    Ready(String),
}

/// One ready line, from one start (`generation`) of supervised process `child`.
pub(super) struct Event {
    pub(super) child: usize,
    pub(super) generation: u64,
    pub(super) kind: EventKind,
}

/// What follows the name in a gateway's `ready <subsystem> <what>` line (`3 states`).
pub(super) fn gateway_ready(line: &str) -> Option<String> {
    let rest = line.trim().strip_prefix("ready ")?;
    let (_, what) = rest.split_once(' ').unwrap_or((rest, ""));
    Some(what.to_string())
}

/// An executor's `READY` line.
pub(super) fn executor_ready(line: &str) -> Option<String> {
    (line.trim() == READY).then(String::new)
}

impl Supervisor {
    pub(super) fn handle_events(&mut self) {
        while let Ok(ev) = self.events.1.try_recv() {
            let c = &mut self.children[ev.child];
            if ev.generation != c.generation {
                continue;
            }
            match ev.kind {
                EventKind::Ready(what) => {
                    if matches!(c.phase, Phase::Starting { .. }) {
                        c.phase = Phase::Running {
                            since: Instant::now(),
                        };
                        let pid = c.proc.as_ref().map(Child::id);
                        let pid = pid.map_or("?".into(), |p| p.to_string());
                        match &c.role {
                            Role::Executor => {
                                note!("conductor: subsystem {} ready (pid {pid})", c.subsystem)
                            }
                            Role::Gateway(g) if g.kind == GatewayKind::Bridge => {
                                note!("conductor: bridge ready (pid {pid}): {what}")
                            }
                            Role::Gateway(g) => note!(
                                "conductor: gateway {} ready (pid {pid}): {what} from {}",
                                c.subsystem,
                                g.port.display()
                            ),
                            Role::View(_) => {
                                note!("conductor: view ready (pid {pid}): open {what} in Foxglove")
                            }
                        }
                        c.ready_text = what;
                        let pid = c.proc.as_ref().map(Child::id);
                        self.set_info(ev.child, pid, true);
                    }
                }
            }
        }
    }

    pub(super) fn await_initial_readiness(&mut self) -> Result<(), LaunchError> {
        loop {
            self.handle_events();
            for i in 0..self.children.len() {
                let c = &mut self.children[i];
                // Gateways are supervised from the start but not waited for.
                let (Phase::Starting { since }, Role::Executor) = (&c.phase, &c.role) else {
                    continue;
                };
                let since = *since;
                if let Some(status) = c.proc.as_mut().and_then(|p| p.try_wait().ok().flatten()) {
                    c.proc = None;
                    c.phase = Phase::Stopped;
                    c.drain_output();
                    let code = status.code().map(|c| c as u8);
                    let output = self.tail(i);
                    let subsystem = self.children[i].subsystem.clone();
                    return Err(if matches!(code, Some(EXIT_CONFIG) | Some(EXIT_NO_RT)) {
                        LaunchError::CannotRun {
                            subsystem,
                            status: describe(&status),
                            output,
                        }
                    } else {
                        LaunchError::NotReady {
                            subsystem,
                            status: describe(&status),
                            output,
                        }
                    });
                }
                if since.elapsed() > self.opts.ready_timeout {
                    return Err(LaunchError::NotReady {
                        subsystem: c.subsystem.clone(),
                        status: format!("no READY within {:?}", self.opts.ready_timeout),
                        output: self.tail(i),
                    });
                }
            }
            if self
                .children
                .iter()
                .all(|c| c.role.auxiliary() || matches!(c.phase, Phase::Running { .. }))
            {
                return Ok(());
            }
            if self.stop.requested() {
                return Err(LaunchError::NotReady {
                    subsystem: "(all)".into(),
                    status: "stop requested during start-up".into(),
                    output: Vec::new(),
                });
            }
            std::thread::sleep(POLL);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ready_lines() {
        assert_eq!(
            gateway_ready("ready board 3 states\n").as_deref(),
            Some("3 states")
        );
        assert_eq!(gateway_ready("ready board").as_deref(), Some(""));
        assert_eq!(gateway_ready("score-gateway: ready soon"), None);
        assert_eq!(gateway_ready("READY"), None);
        assert_eq!(executor_ready(" READY\n").as_deref(), Some(""));
        assert_eq!(executor_ready("ready board 3 states"), None);
    }
}
