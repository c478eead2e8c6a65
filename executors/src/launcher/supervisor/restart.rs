//! Restarts: a supervised process that exited is restarted after a back-off that doubles with
//! each consecutive crash (reset after a stable run), within a bounded number of crashes per
//! window; one that cannot run at its first start, or an auxiliary one that keeps crashing,
//! is given up. An executor that ran before and cannot bring its devices up after a restart
//! is retried as a crash.

use std::time::{Duration, Instant};

use super::{describe, Phase, Role, Supervisor, STABLE};
use crate::cleanup::scan_and_clean;
use crate::launcher::LaunchError;
use crate::process::{EXIT_CONFIG, EXIT_NO_RT};

/// The wait before restart number `consecutive` (1 for the first crash in a row): `first`,
/// doubling each time, at most `max`.
pub(super) fn backoff(first: Duration, max: Duration, consecutive: u32) -> Duration {
    first
        .saturating_mul(1 << consecutive.saturating_sub(1).min(16))
        .min(max)
}

impl Supervisor {
    pub(super) fn check_child(&mut self, i: usize, now: Instant) -> Result<(), LaunchError> {
        match self.children[i].phase {
            Phase::Waiting { until, last } => {
                if now >= until {
                    // Whatever the dead process left behind must go before its successor starts.
                    let _ = scan_and_clean(&self.domain);
                    let c = &mut self.children[i];
                    c.restarts += 1;
                    note!(
                        "conductor: restarting {} (restart {}, after {})",
                        c.role.label(&c.subsystem),
                        c.restarts,
                        describe(&last)
                    );
                    match self.spawn(i) {
                        Ok(()) => {}
                        Err(e) if self.children[i].role.auxiliary() => {
                            self.give_up(i, e.to_string())
                        }
                        Err(e) => return Err(e),
                    }
                }
                return Ok(());
            }
            Phase::Stopped => return Ok(()),
            Phase::Starting { since } => {
                let waited = now.duration_since(since);
                match self.children[i].role {
                    Role::Executor if waited > self.opts.ready_timeout => {
                        // Hung before READY: treat it as a crash.
                        if let Some(p) = self.children[i].proc.as_mut() {
                            let _ = p.kill();
                        }
                    }
                    // A gateway waiting this long for its board is not crashing.
                    Role::Gateway(_) | Role::View(_) if waited > STABLE => {
                        self.children[i].consecutive = 0
                    }
                    _ => {}
                }
            }
            Phase::Running { since } if now.duration_since(since) > STABLE => {
                self.children[i].consecutive = 0;
            }
            _ => {}
        }
        let c = &mut self.children[i];
        let Some(status) = c.proc.as_mut().and_then(|p| p.try_wait().ok().flatten()) else {
            return Ok(());
        };
        c.proc = None;
        let code = status.code().map(|c| c as u8);
        let gateway = c.role.auxiliary();
        if gateway && code == Some(EXIT_CONFIG) {
            self.give_up(i, format!("it cannot run ({})", describe(&status)));
            return Ok(());
        }
        // An executor that ran before and now cannot bring its devices up (a bus not back
        // yet, devices rebooting) is retried like a crash, within the same bounds: what ran
        // once may run again. At its first start, "cannot run" ends the launch.
        let ran_before = c.restarts > 0 && code == Some(EXIT_CONFIG);
        if matches!(code, Some(EXIT_CONFIG) | Some(EXIT_NO_RT)) && !ran_before {
            c.phase = Phase::Stopped;
            c.drain_output();
            self.set_info(i, None, false);
            return Err(LaunchError::CannotRun {
                subsystem: self.children[i].subsystem.clone(),
                status: describe(&status),
                output: self.tail(i),
            });
        }
        // A crash (or an exit nobody asked for): restart with back-off, within bounds.
        let window = self.opts.restart_window;
        c.crashes.push_back(now);
        while c
            .crashes
            .front()
            .is_some_and(|t| now.duration_since(*t) > window)
        {
            c.crashes.pop_front();
        }
        if c.crashes.len() as u32 > self.opts.max_restarts {
            let crashes = c.crashes.len() as u32;
            if gateway {
                self.give_up(
                    i,
                    format!(
                        "it crashed {crashes} times within {window:?} (last: {})",
                        describe(&status)
                    ),
                );
                return Ok(());
            }
            c.phase = Phase::Stopped;
            c.drain_output();
            return Err(LaunchError::TooManyRestarts {
                subsystem: self.children[i].subsystem.clone(),
                crashes,
                window,
                status: describe(&status),
                output: self.tail(i),
            });
        }
        c.consecutive += 1;
        let delay = backoff(self.opts.backoff, self.opts.backoff_max, c.consecutive);
        note!(
            "conductor: {} stopped unexpectedly ({}); restarting in {:?}",
            c.role.label(&c.subsystem),
            describe(&status),
            delay
        );
        c.phase = Phase::Waiting {
            until: now + delay,
            last: status,
        };
        self.set_info(i, None, false);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_backoff_doubles_up_to_its_limit() {
        let ms = Duration::from_millis;
        let waits: Vec<Duration> = (1..=7).map(|n| backoff(ms(200), ms(5000), n)).collect();
        assert_eq!(
            waits,
            [
                ms(200),
                ms(400),
                ms(800),
                ms(1600),
                ms(3200),
                ms(5000),
                ms(5000)
            ]
        );
        assert_eq!(backoff(ms(200), ms(5000), 1000), ms(5000));
    }
}
