//! The executor's log of the hardware edge: a bus that vanished or came back, a device brought
//! up or failing, a fault, a trip, a setpoint refused. The real-time thread only moves
//! [`Event`]s (plain `Copy` values) into a preallocated channel with `try_send` (no allocation,
//! no lock, no system call: the logger thread never blocks on the channel, it polls it); the
//! logger thread formats them with the subsystem's names and writes one line each to stderr,
//! at most [`LINES_PER_S`] per second (the rest are counted and summarised), so a flapping bus
//! cannot flood the log.

use std::sync::mpsc::{self, Receiver, SyncSender, TryRecvError, TrySendError};
use std::time::{Duration, Instant};

use conductor_devices::device::{AX_MODELS, MX_MODELS, X_MODELS};
use conductor_devices::{ControllerState, Failure, Phase};

use crate::stages::{Event, TripCause};
use conductor_manifest::Subsystem;

/// Most lines written per second.
pub const LINES_PER_S: u32 = 20;
/// Events buffered between the real-time thread and the logger.
const CAPACITY: usize = 256;

/// The names an event is told with.
#[derive(Debug, Clone)]
pub struct Names {
    tag: String,
    devices: Vec<(String, String)>,
    links: Vec<String>,
    states: Vec<String>,
}

impl Names {
    /// The names of `sub`'s devices, buses and states.
    pub fn of(sub: &Subsystem) -> Self {
        let links = sub
            .protocols
            .iter()
            .map(|p| {
                let hw = &sub.hardware[p.hardware];
                let at = ["port", "interface"]
                    .iter()
                    .find_map(|k| hw.params.str(k).ok())
                    .map(|a| format!(" {a}"))
                    .unwrap_or_default();
                format!("bus {:?} ({}{at})", hw.name, hw.kind)
            })
            .collect();
        let devices = sub
            .devices
            .iter()
            .map(|d| {
                let bus = &sub.hardware[sub.protocols[d.protocol].hardware].name;
                (
                    format!(
                        "device {:?} ({}, id {} on bus {bus:?})",
                        d.name, d.kind, d.credential.id
                    ),
                    expected_model(&d.kind, &d.params),
                )
            })
            .collect();
        Self {
            tag: format!("conductor-executor[{}]", sub.name),
            devices,
            links,
            states: sub.states.iter().map(|s| s.name.clone()).collect(),
        }
    }

    /// One line for `e`.
    pub fn describe(&self, e: &Event) -> String {
        let dev = |i: usize| self.devices.get(i).map_or("a device", |d| d.0.as_str());
        let link = |i: usize| self.links.get(i).map_or("a bus", String::as_str);
        let tag = &self.tag;
        match *e {
            Event::BusDown { link: l, cause } => {
                format!(
                "{tag}: {} vanished{}: its states are STALE; reopening it (10 ms … 1 s back-off)",
                link(l),
                // Errno's Display is "ENODEV: No such device".
                cause.map(|c| format!(" ({c})")).unwrap_or_default()
            )
            }
            Event::Controller { link: l, state } => match state {
                ControllerState::Active => format!(
                    "{tag}: {}: the CAN controller is error-active again",
                    link(l)
                ),
                ControllerState::BusOff => format!(
                    "{tag}: {}: the CAN controller reports bus-off: nothing reaches the bus \
                     until it restarts (restart-ms, see docs/hardware.md); its states go STALE",
                    link(l)
                ),
                s => format!(
                    "{tag}: {}: the CAN controller reports {} (errors on the bus: wiring, \
                     termination, bitrate?)",
                    link(l),
                    s.name()
                ),
            },
            Event::TxQueue {
                link: l,
                full: true,
            } => format!(
                "{tag}: {}: transmit queue full (ENOBUFS): frames wait for the next tick; \
                 is any other node acknowledging? (txqueuelen, see docs/hardware.md)",
                link(l)
            ),
            Event::TxQueue {
                link: l,
                full: false,
            } => {
                format!("{tag}: {}: transmit queue takes frames again", link(l))
            }
            Event::BusUp { link: l, outage_ns } => format!(
                "{tag}: {} is back after {:.2} s; bringing its devices up again",
                link(l),
                outage_ns as f64 * 1e-9
            ),
            Event::Phase {
                device,
                phase,
                failure,
            } => match (phase, failure) {
                (Phase::Failed, Some(f)) | (Phase::Disabled, Some(f)) => {
                    format!("{tag}: {}: {}", dev(device), self.failure(device, f))
                }
                (p, _) => format!("{tag}: {} is {}", dev(device), p.name()),
            },
            Event::Fault { device, bits } => {
                format!(
                    "{tag}: {} reports a fault: {}",
                    dev(device),
                    fault_text(bits)
                )
            }
            Event::FaultCleared { device } => format!("{tag}: {}: fault cleared", dev(device)),
            Event::Tripped { device, cause } => format!(
                "{tag}: {} tripped by {}: safe action sent ahead of queued traffic; setpoints \
                 refused until its enable state is set to 1",
                dev(device),
                match cause {
                    TripCause::Watchdog => "the command watchdog",
                    TripCause::Fault => "its fault",
                }
            ),
            Event::SafeConfirmed { device } => {
                format!("{tag}: {}: safe action confirmed on the wire", dev(device))
            }
            Event::Refused {
                state,
                phase,
                tripped,
            } => format!(
                "{tag}: setpoint for {:?} refused: its device is {}{} (set its enable state to 1)",
                self.states.get(state).map_or("?", String::as_str),
                phase.name(),
                if tripped { ", tripped" } else { "" }
            ),
        }
    }

    /// Why device `i` failed, with what to do.
    pub fn failure(&self, i: usize, f: Failure) -> String {
        let expected = self.devices.get(i).map_or("", |d| d.1.as_str());
        match f {
            Failure::NoAnswer => "does not answer: check its id, the bus speed, its power and \
                                  the wiring (optional = true makes a missing device a warning)"
                .into(),
            Failure::WrongModel { found } => format!(
                "answered as model {found} ({}) where the manifest expects {expected}; check the \
                 id or set the device's `model`",
                model_name(found).unwrap_or("unknown to this kind")
            ),
            Failure::ConfigRefused { addr, wrote, read } => format!(
                "refused its configuration: register {addr} reads {read} after writing {wrote} \
                 (EEPROM is writable only with torque off; check the value's range)"
            ),
            Failure::OutOfRange { raw } => format!(
                "present position (raw {raw}) is outside the range it can be commanded to: \
                 enabling would move it; move the joint into range or check operating_mode"
            ),
            Failure::EnableRefused => {
                "did not switch on (a latched fault? see its fault flags and error states)".into()
            }
        }
    }

    /// How device `i` is named in messages.
    pub fn device(&self, i: usize) -> &str {
        self.devices.get(i).map_or("a device", |d| d.0.as_str())
    }

    /// The executor's tag for log lines.
    pub fn tag(&self) -> &str {
        &self.tag
    }
}

fn model_name(n: u16) -> Option<&'static str> {
    X_MODELS
        .iter()
        .chain(AX_MODELS)
        .chain(MX_MODELS)
        .find(|(m, _)| *m == n)
        .map(|(_, name)| *name)
}

/// What model a device of `kind` with `params` must report, for messages.
fn expected_model(kind: &str, params: &conductor_devices::kinds::Params) -> String {
    let list = |l: &[(u16, &str)]| {
        l.iter()
            .map(|(n, name)| format!("{name} ({n})"))
            .collect::<Vec<_>>()
            .join(" or ")
    };
    match (kind, params.str("model")) {
        ("dynamixel_x", Ok("any")) => "any model".into(),
        ("dynamixel_x", Ok(m)) => list(
            &X_MODELS
                .iter()
                .copied()
                .filter(|(_, n)| *n == m)
                .collect::<Vec<_>>(),
        ),
        ("dynamixel1", Ok("mx")) => list(MX_MODELS),
        ("dynamixel1", _) => list(AX_MODELS),
        _ => "its kind's model".into(),
    }
}

fn fault_text(bits: u32) -> String {
    format!("{bits:#x}")
}

/// The sending half, owned by the executor (real-time thread).
#[derive(Debug)]
pub struct EventLog {
    tx: Option<SyncSender<Event>>,
    lost: u64,
}

impl EventLog {
    /// Starts the logger thread, which tells events with `names`.
    pub fn spawn(names: Names) -> Self {
        let (tx, rx) = mpsc::sync_channel(CAPACITY);
        let spawned = std::thread::Builder::new()
            .name("events".into())
            .spawn(move || log_thread(rx, names));
        Self {
            tx: spawned.ok().map(|_| tx),
            lost: 0,
        }
    }

    /// A log that drops everything (tests).
    pub fn none() -> Self {
        Self { tx: None, lost: 0 }
    }

    /// Hands `e` to the logger; never blocks or allocates (a full channel counts a loss).
    pub fn send(&mut self, e: &Event) {
        if let Some(tx) = &self.tx {
            if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) = tx.try_send(*e) {
                self.lost += 1;
            }
        }
    }

    /// Events the logger never got.
    pub fn lost(&self) -> u64 {
        self.lost
    }
}

fn log_thread(rx: Receiver<Event>, names: Names) {
    let mut window = Instant::now();
    let mut written = 0u32;
    let mut suppressed = 0u64;
    loop {
        // Polling, never blocking in recv: the sender then never has a waiter to wake.
        let e = match rx.try_recv() {
            Ok(e) => e,
            Err(TryRecvError::Empty) => {
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
            Err(TryRecvError::Disconnected) => break,
        };
        if window.elapsed() >= Duration::from_secs(1) {
            if suppressed > 0 {
                crate::note!(
                    "{}: {suppressed} more events in the last second not shown",
                    names.tag()
                );
            }
            window = Instant::now();
            written = 0;
            suppressed = 0;
        }
        if written < LINES_PER_S {
            written += 1;
            crate::note!("{}", names.describe(&e));
        } else {
            suppressed += 1;
        }
    }
    if suppressed > 0 {
        crate::note!("{}: {suppressed} more events not shown", names.tag());
    }
}
