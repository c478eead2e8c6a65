//! The command probe: an external controller that measures **controller command → hardware
//! write** on the stress manifest's loopback state ([`super::PROBE_STATE`]).
//!
//! What is measured, exactly: the probe sends a frame with a fresh value v (stamp t_send, taken
//! just before `send_ctrl`) and reads the state's samples. Within one tick the executor's device
//! stage puts the tick's sample request on the wire *before* the tick's setpoint (the sim
//! device's `sample` then `flush`), and the loopback hardware answers a sample with the last value
//! written to it. So the tick that wrote v reports the old value, and the **next** executed tick
//! is the first to report v. Hence:
//!
//! * `write` = t_sample of the sample just before the first one showing v, − t_send: the wake
//!   stamp of the tick that wrote v to the hardware. That stamp is taken a few µs before the tick
//!   drains its frames and reaches the hardware stage, so `write` understates the true write time
//!   by the tick's own work up to the hardware stage; a frame that arrived inside that gap gives
//!   a stamp before t_send, counted as `early` and recorded as 0.
//! * `reflect` = t_sample of the first sample showing v − t_send: command → first sample that
//!   reflects it (one base period more than `write`).
//!
//! Both include the wait for the next tick: sent at a random phase, a command waits 0 … 1 period
//! (½ period on average) before any tick can take it. A write is resolved only when no sample was
//! lost in between (else it is `unresolved`). One command is in flight at a time.

use conductor_bus::histogram::Histogram;
use conductor_bus::{monotonic_ns, Bus, BusError, Controller, StateSample, StateSubscriber};

use super::logger::quantile_keys;

/// A command not yet seen in a sample.
#[derive(Debug, Clone, Copy)]
struct Pending {
    value: f64,
    t_send_ns: u64,
}

/// What the probe measured.
#[derive(Debug, Clone, Default)]
pub struct ProbeReport {
    /// `subsystem/state` probed.
    pub name: String,
    /// Commands sent.
    pub sent: u64,
    /// Commands whose write tick was identified.
    pub written: u64,
    /// Commands seen in a sample but with a lost sample before it (write tick unknown), or
    /// never seen within the give-up time.
    pub unresolved: u64,
    /// Writes whose tick stamp preceded the send (see the module docs); recorded as 0.
    pub early: u64,
    /// Controller send → wake stamp of the tick that wrote the value to the hardware (ns).
    pub to_write: Histogram,
    /// Controller send → sample time of the first sample reflecting the value (ns).
    pub to_reflect: Histogram,
}

impl ProbeReport {
    /// One line of `key=value` pairs, starting with `probe=<state>`.
    pub fn line(&self) -> String {
        format!(
            "probe={} sent={} reflected={} written={} unresolved={} early={} {} {}",
            self.name,
            self.sent,
            self.to_reflect.count(),
            self.written,
            self.unresolved,
            self.early,
            quantile_keys("write", &self.to_write),
            quantile_keys("reflect", &self.to_reflect)
        )
    }
}

/// Sends setpoints to a loopback state and times them (see the module docs).
pub struct CommandProbe {
    ctrl: Controller,
    sub: StateSubscriber,
    pending: Option<Pending>,
    next_value: f64,
    prev: Option<StateSample>,
    missed: u64,
    report: ProbeReport,
}

impl core::fmt::Debug for CommandProbe {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("CommandProbe")
            .field("state", &self.report.name)
            .finish()
    }
}

/// A command not seen within this time is given up (counted unresolved).
const GIVE_UP_NS: u64 = 1_000_000_000;

impl CommandProbe {
    /// Probes the writable state `name` (`subsystem/state`) on a loopback hardware.
    pub fn new(bus: &Bus, name: &str) -> Result<Self, BusError> {
        let sub = StateSubscriber::with_buffer(bus, name, 4096)?;
        let mut ctrl = Controller::new(bus);
        // Resolve the target now, so sending later only writes into the pre-allocated frame.
        ctrl.add_ctrl(name, 0.0)?;
        ctrl.clear_ctrl();
        Ok(Self {
            ctrl,
            sub,
            pending: None,
            next_value: 1.0,
            prev: None,
            missed: 0,
            report: ProbeReport {
                name: name.into(),
                ..Default::default()
            },
        })
    }

    /// Sends a new command unless one is still in flight; returns whether it sent.
    pub fn send(&mut self) -> Result<bool, BusError> {
        if let Some(p) = self.pending {
            if monotonic_ns().saturating_sub(p.t_send_ns) < GIVE_UP_NS {
                return Ok(false);
            }
            self.report.unresolved += 1;
        }
        let name = self.report.name.clone();
        let value = self.next_value;
        self.next_value += 1.0;
        self.ctrl.add_ctrl(&name, value)?;
        let t_send_ns = monotonic_ns();
        self.ctrl.send_ctrl()?;
        self.pending = Some(Pending { value, t_send_ns });
        self.report.sent += 1;
        Ok(true)
    }

    /// Reads every queued sample and resolves the command in flight; returns the samples read.
    pub fn poll(&mut self) -> Result<usize, BusError> {
        let mut n = 0;
        while let Some(s) = self.sub.receive()? {
            n += 1;
            let lost = self.sub.missed() != self.missed;
            self.missed = self.sub.missed();
            if let Some(p) = self.pending.filter(|p| s.value == p.value) {
                self.pending = None;
                resolve(
                    &mut self.report,
                    p,
                    self.prev.as_ref().filter(|_| !lost),
                    &s,
                );
            }
            self.prev = Some(s);
        }
        Ok(n)
    }

    /// The figures so far (a command still in flight is not counted).
    pub fn report(&self) -> &ProbeReport {
        &self.report
    }
}

/// Accounts for the first sample `first` showing the pending command `p`; `prev` is the sample
/// just before it, if none was lost in between.
fn resolve(rep: &mut ProbeReport, p: Pending, prev: Option<&StateSample>, first: &StateSample) {
    rep.to_reflect
        .record(first.t_sample_ns.saturating_sub(p.t_send_ns));
    match prev {
        Some(w) if w.value != p.value => {
            if w.t_sample_ns < p.t_send_ns {
                rep.early += 1;
            }
            rep.to_write
                .record(w.t_sample_ns.saturating_sub(p.t_send_ns));
            rep.written += 1;
        }
        _ => rep.unresolved += 1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stress::{manifest, StressConfig, PROBE_STATE};
    use conductor_bus::Setpoint;
    use conductor_executor::stages::Stages;
    use conductor_manifest::Manifest;

    /// The premise of the measurement: a setpoint applied before tick k's stages is written to
    /// the loopback hardware in tick k, whose own sample still shows the old value; tick k+1's
    /// sample is the first to show it.
    #[test]
    fn the_writing_tick_reports_the_old_value_and_the_next_tick_the_new() {
        let text = manifest(&StressConfig {
            states: 2,
            probe: true,
            ..Default::default()
        });
        let m = Manifest::parse(&text, "stress.toml").unwrap_or_else(|e| panic!("{e}"));
        let sub = &m.subsystems[0];
        let idx = sub
            .states
            .iter()
            .position(|s| s.name == PROBE_STATE)
            .unwrap();
        let mut st = Stages::new(sub).unwrap();
        let ms = 1_000_000;
        let probe_value = |st: &mut Stages, k: u64| {
            let mut v = None;
            st.tick(k, k * ms, k * ms, |p| {
                if p.index == idx {
                    v = Some(p.value);
                }
            });
            v.expect("the probe state is sampled every tick")
        };
        assert_eq!(probe_value(&mut st, 0), 0.0);
        st.apply_frame(
            &[Setpoint {
                index: idx as u32,
                flags: 0,
                value: 7.0,
            }],
            ms,
        );
        assert_eq!(
            probe_value(&mut st, 1),
            0.0,
            "the writing tick shows the old value"
        );
        assert_eq!(
            probe_value(&mut st, 2),
            7.0,
            "the next tick shows the new one"
        );
    }

    fn sample(t: u64, value: f64) -> StateSample {
        StateSample {
            t_sample_ns: t,
            value,
            ..Default::default()
        }
    }

    #[test]
    fn write_time_is_the_tick_before_the_first_reflecting_sample() {
        let mut r = ProbeReport::default();
        let p = Pending {
            value: 3.0,
            t_send_ns: 1_000_000,
        };
        resolve(
            &mut r,
            p,
            Some(&sample(1_400_000, 2.0)),
            &sample(2_400_000, 3.0),
        );
        assert_eq!((r.written, r.early, r.unresolved), (1, 0, 0));
        assert_eq!((r.to_write.max(), r.to_reflect.max()), (400_000, 1_400_000));

        // The write tick's wake stamp can precede the send by the tick's drain delay.
        resolve(
            &mut r,
            p,
            Some(&sample(999_000, 2.0)),
            &sample(1_999_000, 3.0),
        );
        assert_eq!((r.written, r.early), (2, 1));
        // A lost sample before the reflecting one: the write tick is unknown.
        resolve(&mut r, p, None, &sample(2_400_000, 3.0));
        assert_eq!((r.written, r.unresolved, r.to_reflect.count()), (2, 1, 3));
        let kv = crate::stress::parse_line(&r.line());
        assert_eq!(kv["write_max_us"], "400.0");
    }
}
