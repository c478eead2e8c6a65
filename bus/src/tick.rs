//! Waiting for a subsystem's next tick without polling.

use core::time::Duration;

use iceoryx2::prelude::FileDescriptorBased;

use crate::bus::{listener, Bus, EventService};
use crate::error::{BusError, Result};
use crate::naming;
use crate::owner::TickListener;

/// Sleeps until the owner of a subsystem has published a tick's batch of samples.
///
/// Backed by an iceoryx2 event listener (a socket the kernel wakes), so a controller uses no CPU
/// while it waits. The listener can also be attached to one's own iceoryx2 `WaitSet` to wait on
/// several subsystems at once.
pub struct TickWaiter {
    listener: TickListener,
    _service: EventService,
}

impl core::fmt::Debug for TickWaiter {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("TickWaiter")
    }
}

impl TickWaiter {
    /// Listens to `conductor/<subsystem>/tick`.
    pub fn new(bus: &Bus, subsystem: &str) -> Result<Self> {
        naming::validate("subsystem", subsystem)?;
        let service = bus.tick_event(subsystem)?;
        let listener = listener(&service, "tick listener")?;
        Ok(Self {
            listener,
            _service: service,
        })
    }

    /// Blocks until at least one tick arrives or `timeout` passes. Returns the number of ticks
    /// signalled since the last call (0 on timeout). Pending notifications are consumed.
    pub fn wait(&mut self, timeout: Duration) -> Result<u64> {
        let mut ticks = 0;
        self.listener
            .timed_wait(|activation| ticks += activation.count.max(1), timeout)
            .map_err(|e| BusError::iceoryx("waiting for a tick", e))?;
        Ok(ticks)
    }

    /// Consumes pending notifications without blocking; returns how many there were.
    pub fn try_consume(&mut self) -> Result<u64> {
        let mut ticks = 0;
        self.listener
            .try_wait(|activation| ticks += activation.count.max(1))
            .map_err(|e| BusError::iceoryx("polling ticks", e))?;
        Ok(ticks)
    }

    /// Sleeps until at least one of `waiters` ticks or `timeout` passes (one `poll(2)` over their
    /// event sockets: the way a controller of several subsystems waits). Returns, per waiter, the
    /// ticks it consumed (all zero on timeout). Allocation-free for up to 16 waiters.
    pub fn wait_any(waiters: &mut [TickWaiter], timeout: Duration) -> Result<[u64; 16]> {
        poll_readable(
            waiters.iter().map(TickWaiter::raw_fd),
            timeout,
            "tick waiters",
        )?;
        let mut ticks = [0u64; 16];
        for (t, w) in ticks.iter_mut().zip(waiters.iter_mut()) {
            *t = w.try_consume()?;
        }
        Ok(ticks)
    }

    /// The underlying listener, to attach to an iceoryx2 `WaitSet`.
    pub fn listener(&self) -> &TickListener {
        &self.listener
    }

    /// The listener's file descriptor number, for foreign event loops (epoll, tokio).
    pub fn raw_fd(&self) -> i32 {
        // SAFETY: the returned descriptor is owned by `self.listener` and stays valid while
        // `self` lives; we only report its number.
        unsafe { self.listener.file_descriptor().native_handle() }
    }
}

/// Sleeps until one of up to 16 event listeners' descriptors is readable or `timeout` passes:
/// one `poll(2)`, allocation-free. `what` names them in the capacity error.
pub(crate) fn poll_readable(
    fds: impl ExactSizeIterator<Item = i32>,
    timeout: Duration,
    what: &'static str,
) -> Result<()> {
    let mut polled = [libc::pollfd {
        fd: -1,
        events: 0,
        revents: 0,
    }; 16];
    let n = fds.len();
    if n > polled.len() {
        return Err(BusError::Capacity {
            what,
            max: polled.len(),
        });
    }
    for (p, fd) in polled.iter_mut().zip(fds) {
        p.fd = fd;
        p.events = libc::POLLIN;
    }
    let ms = timeout.as_millis().min(i32::MAX as u128) as i32;
    // SAFETY: `polled` is a valid array and the count passed does not exceed its length; the
    // descriptors belong to listeners that outlive the call.
    let r = unsafe { libc::poll(polled.as_mut_ptr(), n as libc::nfds_t, ms) };
    if r < 0 {
        let e = nix::errno::Errno::last();
        if e != nix::errno::Errno::EINTR {
            return Err(BusError::Os {
                context: "waiting for events",
                source: e,
            });
        }
    }
    Ok(())
}
