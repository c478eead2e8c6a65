//! [`Controller`]: the thesis' controller API over the bus: `add_ctrl`, `send_ctrl`,
//! `check_ctrl`, `get_surface`.

use std::collections::HashMap;

use iceoryx2::port::publisher::Publisher;

use iceoryx2::service::port_factory::publish_subscribe::PortFactory;

use crate::abi::{CommandFrame, MAX_SETPOINTS};
use crate::bus::Bus;
use crate::clock::monotonic_ns;
use crate::error::{BusError, Result};
use crate::metadata::{ServiceKind, StateMeta};
use crate::naming;
use crate::state::State;
use crate::variant::RtIpc;

/// Default history kept for states read through [`Controller::get_surface`].
pub const SURFACE_HISTORY: usize = 256;

struct Target {
    outbox: usize,
    index: u32,
    meta: StateMeta,
}

struct Outbox {
    subsystem: String,
    port: Publisher<RtIpc, CommandFrame, ()>,
    frame: CommandFrame,
    seq: u64,
    _service: PortFactory<RtIpc, CommandFrame, ()>,
}

impl Outbox {
    /// Stamps the buffered frame with the next sequence number and the send time and publishes
    /// it; returns how many receivers it reached.
    fn send_frame(&mut self) -> Result<usize> {
        self.seq += 1;
        self.frame.seq = self.seq;
        self.frame.t_send_ns = monotonic_ns();
        let sample = self
            .port
            .loan_uninit()
            .map_err(|e| BusError::iceoryx("loaning a command frame", e))?;
        sample
            .write_payload(self.frame)
            .send()
            .map_err(|e| BusError::iceoryx("sending a command frame", e))
    }
}

/// Buffers setpoints and sends them as one [`CommandFrame`] per subsystem, which the owning
/// executor applies in a single tick; reads states on demand.
///
/// Resolving a state name the first time looks it up on the bus (allocates); after that,
/// `add_ctrl`/`send_ctrl` on known names only write into pre-allocated frames.
pub struct Controller {
    bus: Bus,
    targets: HashMap<String, Target>,
    outboxes: Vec<Outbox>,
    surfaces: HashMap<String, State>,
}

impl core::fmt::Debug for Controller {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Controller")
            .field("targets", &self.targets.len())
            .field("subsystems", &self.outboxes.len())
            .finish()
    }
}

impl Controller {
    /// A controller on `bus`.
    pub fn new(bus: &Bus) -> Self {
        Self {
            bus: bus.clone(),
            targets: HashMap::new(),
            outboxes: Vec::new(),
            surfaces: HashMap::new(),
        }
    }

    fn target(&mut self, name: &str) -> Result<&Target> {
        if !self.targets.contains_key(name) {
            let info = self.bus.resolve(name)?;
            let outbox = match self
                .outboxes
                .iter()
                .position(|o| o.subsystem == info.subsystem)
            {
                Some(i) => i,
                None => {
                    self.outboxes.push(open_outbox(&self.bus, &info.subsystem)?);
                    self.outboxes.len() - 1
                }
            };
            self.targets.insert(
                name.to_string(),
                Target {
                    outbox,
                    index: info.meta.index,
                    meta: info.meta,
                },
            );
        }
        Ok(&self.targets[name])
    }

    /// Buffers a setpoint of `value` for state `name` (`subsystem/state` or a unique bare
    /// name). A second setpoint for the same state before `send_ctrl` replaces the first.
    pub fn add_ctrl(&mut self, name: &str, value: f64) -> Result<()> {
        if !value.is_finite() {
            return Err(BusError::NotFinite {
                name: name.into(),
                value,
            });
        }
        let t = self.target(name)?;
        if !t.meta.writable {
            return Err(BusError::ReadOnly { name: name.into() });
        }
        let (outbox, index) = (t.outbox, t.index);
        let ob = &mut self.outboxes[outbox];
        let n = ob.frame.count as usize;
        if let Some(sp) = ob.frame.entries[..n].iter_mut().find(|s| s.index == index) {
            sp.value = value;
            return Ok(());
        }
        if !ob.frame.push(index, value) {
            return Err(BusError::FrameFull {
                subsystem: ob.subsystem.clone(),
                capacity: MAX_SETPOINTS,
            });
        }
        Ok(())
    }

    /// The setpoint buffered for `name`, if any.
    pub fn check_ctrl(&self, name: &str) -> Option<f64> {
        let t = self.targets.get(name)?;
        self.outboxes[t.outbox]
            .frame
            .setpoints()
            .iter()
            .find(|s| s.index == t.index)
            .map(|s| s.value)
    }

    /// Sends every buffered setpoint: one frame per subsystem. Returns the number of setpoints
    /// sent; the buffer is empty afterwards.
    pub fn send_ctrl(&mut self) -> Result<usize> {
        self.send_frames().map(|(sent, _)| sent)
    }

    /// As [`send_ctrl`](Self::send_ctrl), but a frame that reached no receiver (no executor
    /// listens on the subsystem's commands service) is [`BusError::NotDelivered`], after every
    /// frame was sent.
    pub fn send_ctrl_checked(&mut self) -> Result<usize> {
        let (sent, undelivered) = self.send_frames()?;
        match undelivered {
            Some(i) => Err(BusError::NotDelivered {
                subsystem: self.outboxes[i].subsystem.clone(),
                domain: self.bus.domain().name().into(),
            }),
            None => Ok(sent),
        }
    }

    /// Sends the buffered frames; returns the setpoints sent and the first outbox whose frame
    /// reached no receiver (an index, so that sending never allocates).
    fn send_frames(&mut self) -> Result<(usize, Option<usize>)> {
        let mut sent = 0;
        let mut undelivered = None;
        for (i, ob) in self.outboxes.iter_mut().enumerate() {
            if ob.frame.count == 0 {
                continue;
            }
            let receivers = ob.send_frame()?;
            if receivers == 0 && undelivered.is_none() {
                undelivered = Some(i);
            }
            sent += ob.frame.count as usize;
            ob.frame.clear();
        }
        Ok((sent, undelivered))
    }

    /// Drops every buffered setpoint without sending.
    pub fn clear_ctrl(&mut self) {
        for ob in &mut self.outboxes {
            ob.frame.clear();
        }
    }

    /// The state `name`, subscribed on first use and updated with every queued sample.
    pub fn state(&mut self, name: &str) -> Result<&mut State> {
        if !self.surfaces.contains_key(name) {
            let s = State::new(&self.bus, name, SURFACE_HISTORY)?;
            self.surfaces.insert(name.to_string(), s);
        }
        let s = self.surfaces.get_mut(name).expect("inserted above");
        s.update()?;
        Ok(s)
    }

    /// The last known value of `name` (the thesis' `getSurface`).
    pub fn get_surface(&mut self, name: &str) -> Result<f64> {
        self.state(name)?.value()
    }

    /// The bus this controller talks on.
    pub fn bus(&self) -> &Bus {
        &self.bus
    }
}

fn open_outbox(bus: &Bus, subsystem: &str) -> Result<Outbox> {
    let name = naming::commands(subsystem);
    let service =
        bus.open_conductor_pubsub::<CommandFrame>(subsystem, &name, ServiceKind::Commands)?;
    let port = service
        .publisher_builder()
        .create()
        .map_err(|e| BusError::iceoryx(format!("command publisher on {name:?}"), e))?;
    Ok(Outbox {
        subsystem: subsystem.into(),
        port,
        frame: CommandFrame::default(),
        seq: 0,
        _service: service,
    })
}

/// Sends whole [`CommandFrame`]s, as built elsewhere, to one subsystem's executor: the path a
/// bridge uses to hand a remote controller's frame to the owner, which then checks it like any
/// local frame. `seq` and `t_send_ns` are stamped here, in this process's sequence and clock.
pub struct CommandSender {
    outbox: Outbox,
}

impl core::fmt::Debug for CommandSender {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("CommandSender")
            .field("subsystem", &self.outbox.subsystem)
            .finish()
    }
}

impl CommandSender {
    /// Opens `conductor/<subsystem>/commands` (the executor must have created it).
    pub fn open(bus: &Bus, subsystem: &str) -> Result<Self> {
        Ok(Self {
            outbox: open_outbox(bus, subsystem)?,
        })
    }

    /// Sends the first `count` setpoints of `frame` as one frame.
    pub fn send(&mut self, frame: &CommandFrame) -> Result<()> {
        let ob = &mut self.outbox;
        ob.frame = *frame;
        ob.frame.count = ob.frame.count.min(MAX_SETPOINTS as u32);
        ob.send_frame()?;
        Ok(())
    }
}
