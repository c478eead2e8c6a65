//! The simulators on a real byte transport, in a thread of their own: a pseudo-terminal (the
//! host opens `/dev/pts/N`, or a symlink to it, exactly like a USB adapter's `/dev/ttyUSB0`)
//! or a UDP socket. `conductor-sim` runs these as a standalone process.
//!
//! Replies are written when their time comes (the simulator's return delay and baud-accurate
//! wire time), measured on `CLOCK_MONOTONIC` from the moment the instruction was read.

use std::io;
use std::net::{SocketAddr, UdpSocket};
use std::os::unix::io::{AsRawFd, RawFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serialport::{SerialPort, TTYPort};

use super::dxl::{DxlBusSim, DxlSimConfig};
use super::fault::{FaultConfig, FaultInjector, FaultTotals};
use super::slcan_adapter::SlcanAdapterSim;
use crate::hw::fd;

/// A pseudo-terminal whose slave side the host opens.
pub struct Pty {
    master: TTYPort,
    /// Kept open: closing the last slave handle hangs the line up.
    _slave: TTYPort,
    path: String,
    link: Option<PathBuf>,
}

impl std::fmt::Debug for Pty {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pty")
            .field("path", &self.path)
            .field("link", &self.link)
            .finish()
    }
}

impl Pty {
    /// A new pty; with `link`, a symlink at that path points to the slave (an existing file
    /// or link there is replaced).
    pub fn open(link: Option<&Path>) -> io::Result<Self> {
        let (master, slave) = TTYPort::pair().map_err(io::Error::from)?;
        let path = slave
            .name()
            .ok_or_else(|| io::Error::other("pty without a name"))?;
        fd::set_nonblocking(master.as_raw_fd())?;
        if let Some(l) = link {
            match std::fs::remove_file(l) {
                Ok(()) => {}
                Err(e) if e.kind() == io::ErrorKind::NotFound => {}
                Err(e) => return Err(e),
            }
            std::os::unix::fs::symlink(&path, l)?;
        }
        Ok(Self {
            master,
            _slave: slave,
            path,
            link: link.map(Path::to_path_buf),
        })
    }

    /// The slave device (`/dev/pts/N`).
    pub fn path(&self) -> &str {
        &self.path
    }

    /// The symlink, if one was made.
    pub fn link(&self) -> Option<&Path> {
        self.link.as_deref()
    }
}

impl Drop for Pty {
    fn drop(&mut self) {
        if let Some(l) = &self.link {
            let _ = std::fs::remove_file(l);
        }
    }
}

/// Where a simulator talks to the host.
#[derive(Debug)]
pub enum Endpoint {
    /// A pseudo-terminal.
    Pty(Pty),
    /// A UDP socket: replies go to whoever sent the last datagram.
    Udp(UdpSocket),
}

impl Endpoint {
    /// A UDP endpoint bound to `addr`.
    pub fn udp(addr: SocketAddr) -> io::Result<Self> {
        let s = UdpSocket::bind(addr)?;
        s.set_nonblocking(true)?;
        Ok(Endpoint::Udp(s))
    }

    /// Where the host connects: the pty path (or its link) or the UDP address.
    pub fn describe(&self) -> String {
        match self {
            Endpoint::Pty(p) => p.path().to_string(),
            Endpoint::Udp(s) => s.local_addr().map(|a| a.to_string()).unwrap_or_default(),
        }
    }

    fn raw_fd(&self) -> RawFd {
        match self {
            Endpoint::Pty(p) => p.master.as_raw_fd(),
            Endpoint::Udp(s) => s.as_raw_fd(),
        }
    }
}

struct Io {
    ep: Endpoint,
    peer: Option<SocketAddr>,
}

impl Io {
    /// Waits up to `timeout` for input; returns what arrived.
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> usize {
        let mut pfd = libc::pollfd {
            fd: self.ep.raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        let ms = timeout.as_millis().min(50) as libc::c_int;
        // SAFETY: one valid pollfd.
        let r = unsafe { libc::poll(&mut pfd, 1, ms) };
        if r <= 0 {
            return 0;
        }
        match &self.ep {
            Endpoint::Pty(p) => fd::read_nb(p.master.as_raw_fd(), buf).unwrap_or(0),
            Endpoint::Udp(s) => match s.recv_from(buf) {
                Ok((n, from)) => {
                    self.peer = Some(from);
                    n
                }
                Err(_) => 0,
            },
        }
    }

    fn write(&mut self, data: &[u8]) {
        match &self.ep {
            Endpoint::Pty(p) => {
                let mut rest = data;
                let deadline = Instant::now() + Duration::from_secs(1);
                while !rest.is_empty() && Instant::now() < deadline {
                    match fd::write_nb(p.master.as_raw_fd(), rest) {
                        Ok(0) => std::thread::sleep(Duration::from_micros(100)),
                        Ok(n) => rest = &rest[n..],
                        Err(_) => return,
                    }
                }
            }
            Endpoint::Udp(s) => {
                if let Some(peer) = self.peer {
                    let _ = s.send_to(data, peer);
                }
            }
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// A simulator running in its own thread.
pub struct Running<S> {
    sim: Arc<Mutex<S>>,
    faults: Arc<Faults>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    endpoint: String,
}

/// Fault totals of a simulator thread: (host → simulator, simulator → host).
type Faults = Mutex<(FaultTotals, FaultTotals)>;

impl<S: Send + 'static> Running<S> {
    /// Runs `serve` in a thread named `name`, on `ep`, with the simulator and the fault totals
    /// it shares with the handle, and the flag that tells it to stop.
    fn spawn(
        name: &str,
        ep: Endpoint,
        sim: S,
        serve: impl FnOnce(Io, &Mutex<S>, &Faults, &AtomicBool) + Send + 'static,
    ) -> Self {
        let endpoint = ep.describe();
        let sim = Arc::new(Mutex::new(sim));
        let faults = Arc::new(Faults::default());
        let stop = Arc::new(AtomicBool::new(false));
        let (s2, f2, st2) = (sim.clone(), faults.clone(), stop.clone());
        let thread = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || serve(Io { ep, peer: None }, &s2, &f2, &st2))
            .expect("spawn simulator thread");
        Running {
            sim,
            faults,
            stop,
            thread: Some(thread),
            endpoint,
        }
    }
}

impl<S> Running<S> {
    /// The simulator (locked while the thread is not using it).
    pub fn sim(&self) -> MutexGuard<'_, S> {
        lock(&self.sim)
    }

    /// Fault totals: (host → simulator, simulator → host).
    pub fn faults(&self) -> (FaultTotals, FaultTotals) {
        *lock(&self.faults)
    }

    /// Where the host connects.
    pub fn endpoint(&self) -> &str {
        &self.endpoint
    }

    /// Stops the thread.
    pub fn stop(mut self) {
        self.halt();
    }

    fn halt(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl<S> Drop for Running<S> {
    fn drop(&mut self) {
        self.halt();
    }
}

/// Runs a Dynamixel bus on `ep`. `down` damages what the host sends (per read chunk), `up`
/// each status packet.
pub fn run_dxl(
    ep: Endpoint,
    cfg: DxlSimConfig,
    down: FaultConfig,
    up: FaultConfig,
) -> Running<DxlBusSim> {
    let sim = DxlBusSim::new(cfg);
    Running::spawn("dxl-sim", ep, sim, move |mut io, sim, faults, stop| {
        let mut down = FaultInjector::new(down);
        let mut up = FaultInjector::new(up);
        let t0 = Instant::now();
        let now = || t0.elapsed().as_nanos() as u64;
        let mut queue: std::collections::VecDeque<(u64, Vec<u8>)> = Default::default();
        let mut buf = vec![0u8; 4096];
        while !stop.load(Ordering::Relaxed) {
            // Write what is due; sleep precisely for a reply due within 2 ms.
            while let Some((ready, _)) = queue.front() {
                let t = now();
                if *ready > t {
                    let wait = *ready - t;
                    if wait > 2_000_000 {
                        break;
                    }
                    std::thread::sleep(Duration::from_nanos(wait));
                }
                let (_, bytes) = queue.pop_front().unwrap_or_default();
                io.write(&bytes);
            }
            let timeout = match queue.front() {
                Some((ready, _)) => {
                    Duration::from_nanos(ready.saturating_sub(now()).saturating_sub(2_000_000))
                }
                None => Duration::from_millis(5),
            };
            let n = io.read(&mut buf, timeout);
            let t = now();
            let mut sim = lock(sim);
            if n == 0 {
                sim.advance(t);
                continue;
            }
            let mut chunk = buf[..n].to_vec();
            down.apply(&mut chunk);
            sim.feed(&chunk, t, |r| {
                let mut b = r.bytes;
                let (_, delay) = up.apply(&mut b);
                queue.push_back((r.ready_ns + delay, b));
            });
            *lock(faults) = (down.totals(), up.totals());
        }
    })
}

/// Runs an SLCAN adapter on `ep` (answers at once; cyclic node messages every millisecond).
pub fn run_slcan(ep: Endpoint, adapter: SlcanAdapterSim) -> Running<SlcanAdapterSim> {
    Running::spawn("slcan-sim", ep, adapter, |mut io, sim, _faults, stop| {
        let t0 = Instant::now();
        let mut buf = vec![0u8; 4096];
        let mut out = Vec::with_capacity(4096);
        while !stop.load(Ordering::Relaxed) {
            let n = io.read(&mut buf, Duration::from_millis(1));
            let t = t0.elapsed().as_nanos() as u64;
            out.clear();
            {
                let mut a = lock(sim);
                if n > 0 {
                    a.feed(&buf[..n], t, &mut out);
                }
                a.poll(t, &mut out);
            }
            if !out.is_empty() {
                io.write(&out);
            }
        }
    })
}
