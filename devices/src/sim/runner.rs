//! The simulators on a real byte transport, in a thread of their own: a pseudo-terminal (the
//! host opens `/dev/pts/N`, or a symlink to it, exactly like a USB adapter's `/dev/ttyUSB0`)
//! or a UDP socket. `conductor-sim` runs these as a standalone process.
//!
//! Replies are written when their time comes (the simulator's return delay and baud-accurate
//! wire time, the SLCAN adapter's latency and stalls), measured on `CLOCK_MONOTONIC` from the
//! moment the instruction was read.
//!
//! A running simulator can be unplugged and plugged back ([`Running::unplug`],
//! [`Running::replug`]): the USB adapter leaves and comes back at the same path while the
//! servos or motors behind it stay powered and keep their state.

use super::worker::Worker;
use std::io;
use std::net::{SocketAddr, UdpSocket};
use std::os::unix::io::{AsRawFd, RawFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
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

debug_fields!(Pty { path, link });

impl Pty {
    /// A new pty; with `link`, a symlink at that path points to the slave (an existing file
    /// or link there is replaced).
    pub fn open(link: Option<&Path>) -> io::Result<Self> {
        let (master, slave) = TTYPort::pair().map_err(io::Error::from)?;
        let path = slave
            .name()
            .ok_or_else(|| io::Error::other("pty without a name"))?;
        fd::set_nonblocking(master.as_raw_fd())?;
        // A process the test starts (an executor) must not hold our end open: it would never
        // see the hang-up of an unplug.
        fd::set_cloexec(master.as_raw_fd())?;
        fd::set_cloexec(slave.as_raw_fd())?;
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

/// What the handle asks the serving thread to do with its endpoint.
enum PlugRequest {
    Unplug,
    Replug(Endpoint),
}

/// The endpoint's plug state, shared by the handle and the serving thread.
#[derive(Default)]
struct PlugState {
    plugged: bool,
    request: Option<PlugRequest>,
    /// A request was taken and is being carried out (the requester waits for it too).
    busy: bool,
}

#[derive(Default)]
struct Plug {
    state: Mutex<PlugState>,
    changed: Condvar,
    /// The simulator reads nothing from the host (its writes go on).
    paused: AtomicBool,
}

/// What happened to the endpoint during [`Io::service`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PlugEvent {
    Unplugged,
    Replugged,
}

struct Io {
    ep: Option<Endpoint>,
    peer: Option<SocketAddr>,
    plug: Arc<Plug>,
    t0: Instant,
    /// The longest this thread overslept a wait since the handle last asked (ns).
    lag: Arc<AtomicU64>,
}

impl Io {
    /// Nanoseconds since the simulator started (the clock of its `now_ns`).
    fn now(&self) -> u64 {
        self.t0.elapsed().as_nanos() as u64
    }

    /// Carries out a pending unplug or replug request, with what the simulator does about it
    /// (`apply`), before the requester is told it is done.
    fn service(&mut self, apply: impl FnOnce(PlugEvent)) {
        let mut st = lock(&self.plug.state);
        let Some(req) = st.request.take() else {
            return;
        };
        st.busy = true;
        let ev = match req {
            PlugRequest::Unplug => {
                // Dropping a Pty closes the master and our slave handle (the host's open
                // slave sees the hang-up) and removes the symlink.
                self.ep = None;
                self.peer = None;
                st.plugged = false;
                PlugEvent::Unplugged
            }
            PlugRequest::Replug(ep) => {
                self.ep = Some(ep);
                st.plugged = true;
                PlugEvent::Replugged
            }
        };
        drop(st);
        apply(ev);
        lock(&self.plug.state).busy = false;
        self.plug.changed.notify_all();
    }

    /// Waits up to `timeout` (at most 50 ms) for input; returns what arrived.
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> usize {
        let timeout = timeout.min(Duration::from_millis(50));
        let start = Instant::now();
        let n = self.read_inner(buf, timeout);
        // Woken later than asked: the thread did not get the CPU (replies went out late).
        let over = start.elapsed().saturating_sub(timeout).as_nanos() as u64;
        self.lag.fetch_max(over, Ordering::Relaxed);
        n
    }

    fn read_inner(&mut self, buf: &mut [u8], timeout: Duration) -> usize {
        if self.plug.paused.load(Ordering::Relaxed) {
            std::thread::sleep(timeout.min(Duration::from_millis(1)));
            return 0;
        }
        let Some(ep) = &self.ep else {
            // Unplugged: nothing arrives; wake up often enough to see a replug.
            std::thread::sleep(timeout.min(Duration::from_millis(1)));
            return 0;
        };
        let mut pfd = libc::pollfd {
            fd: ep.raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        let ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: timeout.as_nanos() as libc::c_long,
        };
        // SAFETY: one valid pollfd, a valid timespec, no signal mask.
        let r = unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
        if r <= 0 {
            return 0;
        }
        match ep {
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
            None => {}
            Some(Endpoint::Pty(p)) => {
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
            Some(Endpoint::Udp(s)) => {
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

/// How a simulator's endpoint is made again after an unplug.
#[derive(Debug, Clone)]
enum Replug {
    /// A new pty with its symlink at this path.
    Pty(PathBuf),
    /// The UDP socket bound again to this address.
    Udp(SocketAddr),
    /// A pty without a link: the host could not find a new one.
    Never,
}

/// A simulator running in its own thread.
pub struct Running<S> {
    sim: Arc<Mutex<S>>,
    faults: Arc<Faults>,
    lag: Arc<AtomicU64>,
    worker: Worker,
    endpoint: String,
    plug: Arc<Plug>,
    replug: Replug,
    t0: Instant,
}

/// Fault totals of a simulator thread: (host → simulator, simulator → host).
type Faults = Mutex<(FaultTotals, FaultTotals)>;

/// How long the handle waits for the serving thread to carry out an unplug or replug (it looks
/// at least every 50 ms).
const PLUG_WAIT: Duration = Duration::from_secs(5);

impl<S: Send + 'static> Running<S> {
    /// Runs `serve` in a thread named `name`, on `ep`, with the simulator and the fault totals
    /// it shares with the handle, and the flag that tells it to stop.
    fn spawn(
        name: &str,
        ep: Endpoint,
        sim: S,
        serve: impl FnOnce(Io, &Mutex<S>, &Faults, &AtomicBool) + Send + 'static,
    ) -> Self {
        let lag = Arc::new(AtomicU64::new(0));
        let endpoint = ep.describe();
        let replug = match &ep {
            Endpoint::Pty(p) => p.link().map_or(Replug::Never, |l| Replug::Pty(l.into())),
            Endpoint::Udp(s) => s.local_addr().map_or(Replug::Never, Replug::Udp),
        };
        let sim = Arc::new(Mutex::new(sim));
        let faults = Arc::new(Faults::default());
        let plug = Arc::new(Plug::default());
        lock(&plug.state).plugged = true;
        let t0 = Instant::now();
        let io = Io {
            ep: Some(ep),
            peer: None,
            plug: plug.clone(),
            t0,
            lag: lag.clone(),
        };
        let (s2, f2) = (sim.clone(), faults.clone());
        let worker = Worker::spawn(name.into(), move |stop| serve(io, &s2, &f2, &stop))
            .expect("spawn simulator thread");
        Running {
            sim,
            faults,
            lag,
            worker,
            endpoint,
            plug,
            replug,
            t0,
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

    /// Where the host connects: the pty device it was started on, or the UDP address. After
    /// a [`replug`](Self::replug) the pty device differs; the [`link`](Self::link) does not.
    pub fn endpoint(&self) -> &str {
        &self.endpoint
    }

    /// The pty's symlink, if it was made with one.
    pub fn link(&self) -> Option<&Path> {
        match &self.replug {
            Replug::Pty(l) => Some(l),
            _ => None,
        }
    }

    /// The simulator's clock: nanoseconds since it started, the `now_ns` it is driven with
    /// (for [`SlcanAdapterSim::stall_until`] and the like).
    pub fn now_ns(&self) -> u64 {
        self.t0.elapsed().as_nanos() as u64
    }

    /// The longest the serving thread woke up later than it asked to, since the last call
    /// (ns): on a loaded machine it may not get the CPU when a reply is due, and then the
    /// reply leaves late (what a real device never does).
    pub fn take_lag_ns(&self) -> u64 {
        self.lag.swap(0, Ordering::Relaxed)
    }

    /// Whether the endpoint is plugged in.
    pub fn is_plugged(&self) -> bool {
        lock(&self.plug.state).plugged
    }

    /// Stops (`true`) or resumes reading what the host sends, as an adapter whose receive
    /// side hangs: the host's writes pile up in the pty (and, through the kernel's slcan
    /// driver, in the interface's transmit queue) while answers already due still go out.
    pub fn pause_reading(&self, paused: bool) {
        self.plug.paused.store(paused, Ordering::Relaxed);
    }

    /// Unplugs the endpoint, as a USB adapter pulled out while the servos or motors behind it
    /// stay powered: the pty (master and the slave handle kept open) is closed, so the host's
    /// open descriptor sees the hang-up, and the symlink is removed (a UDP socket is closed).
    /// Bytes in flight are lost; the simulator keeps its state and its motors keep moving.
    /// An SLCAN adapter loses its own state ([`SlcanAdapterSim::unplug`]). Does nothing if
    /// already unplugged.
    pub fn unplug(&self) {
        self.request(|plugged| plugged.then_some(PlugRequest::Unplug));
    }

    /// Plugs the simulator back in: a new pty with the symlink at the same path (or the UDP
    /// socket bound to the same address), served with the same simulator state. An error if
    /// it is plugged in, or was started on a pty without a link (the host could not find the
    /// new one), or the pty cannot be made.
    pub fn replug(&self) -> io::Result<()> {
        if self.is_plugged() {
            return Err(io::Error::new(
                io::ErrorKind::AlreadyExists,
                "the simulator is plugged in",
            ));
        }
        let ep = match &self.replug {
            Replug::Pty(l) => Endpoint::Pty(Pty::open(Some(l))?),
            Replug::Udp(a) => Endpoint::udp(*a)?,
            Replug::Never => {
                return Err(io::Error::new(
                    io::ErrorKind::Unsupported,
                    "replug needs a pty made with a link path (or a UDP endpoint)",
                ))
            }
        };
        if self.request(|_| Some(PlugRequest::Replug(ep))) {
            Ok(())
        } else {
            Err(io::Error::new(
                io::ErrorKind::TimedOut,
                "the simulator thread did not take the new endpoint",
            ))
        }
    }

    /// Hands the serving thread the request `make` builds from the plug state (`None`: nothing
    /// to do) and waits until it is carried out; false if the thread did not do it in time.
    fn request(&self, make: impl FnOnce(bool) -> Option<PlugRequest>) -> bool {
        let mut st = lock(&self.plug.state);
        let Some(req) = make(st.plugged) else {
            return true;
        };
        st.request = Some(req);
        let deadline = Instant::now() + PLUG_WAIT;
        while st.request.is_some() || st.busy {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() || self.worker.is_finished() {
                st.request = None;
                return false;
            }
            st = self
                .plug
                .changed
                .wait_timeout(st, left)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
        true
    }

    /// Stops the thread.
    pub fn stop(mut self) {
        self.worker.halt();
    }
}

/// Runs a Dynamixel bus on `ep`. `down` damages what the host sends (per read chunk), `up`
/// each status packet. Replies leave at the time the simulator gives them (each servo's
/// Return Delay Time register, and the wire time at the baud rate).
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
        let mut queue: std::collections::VecDeque<(u64, Vec<u8>)> = Default::default();
        let mut buf = vec![0u8; 4096];
        while !stop.load(Ordering::Relaxed) {
            io.service(|ev| {
                if ev == PlugEvent::Unplugged {
                    // Replies on their way and a partial instruction die with the adapter.
                    queue.clear();
                    lock(sim).expire();
                }
            });
            // Write what is due; sleep precisely for a reply due within 2 ms.
            while let Some((ready, _)) = queue.front() {
                let t = io.now();
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
                    Duration::from_nanos(ready.saturating_sub(io.now()).saturating_sub(2_000_000))
                }
                None => Duration::from_millis(5),
            };
            let n = io.read(&mut buf, timeout);
            let t = io.now();
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

/// [`run_dxl`] with no faults injected either way: a clean bus of `cfg`'s servos.
pub fn run_dxl_faultless(ep: Endpoint, cfg: DxlSimConfig) -> Running<DxlBusSim> {
    run_dxl(ep, cfg, FaultConfig::default(), FaultConfig::default())
}

/// Runs an SLCAN adapter on `ep`: answers as soon as the adapter has them (at once, or after
/// its latency or stall, to within about 0.1 ms), cyclic node messages at least every
/// millisecond.
pub fn run_slcan(ep: Endpoint, adapter: SlcanAdapterSim) -> Running<SlcanAdapterSim> {
    run_slcan_with_faults(ep, adapter, FaultConfig::default(), FaultConfig::default())
}

/// [`run_slcan`] with the serial link damaged: `down` on each chunk the host sends, `up` on
/// each chunk sent to the host (damage on the CAN wire itself is the adapter's:
/// [`SlcanAdapterSim::set_wire_faults`]).
pub fn run_slcan_with_faults(
    ep: Endpoint,
    adapter: SlcanAdapterSim,
    down: FaultConfig,
    up: FaultConfig,
) -> Running<SlcanAdapterSim> {
    Running::spawn(
        "slcan-sim",
        ep,
        adapter,
        move |mut io, sim, faults, stop| {
            let mut down = FaultInjector::new(down);
            let mut up = FaultInjector::new(up);
            let mut chunk = Vec::with_capacity(4096);
            let mut buf = vec![0u8; 4096];
            let mut out = Vec::with_capacity(4096);
            while !stop.load(Ordering::Relaxed) {
                io.service(|ev| {
                    if ev == PlugEvent::Unplugged {
                        lock(sim).unplug();
                    }
                });
                let due = lock(sim).next_due();
                let now = io.now();
                let wait = due.map_or(1_000_000, |d| d.saturating_sub(now).min(1_000_000));
                let n = io.read(&mut buf, Duration::from_nanos(wait));
                let t = io.now();
                out.clear();
                {
                    let mut a = lock(sim);
                    if n > 0 {
                        chunk.clear();
                        chunk.extend_from_slice(&buf[..n]);
                        down.apply(&mut chunk);
                        a.feed(&chunk, t, &mut out);
                    }
                    a.poll(t, &mut out);
                }
                if !out.is_empty() {
                    up.apply(&mut out);
                    io.write(&out);
                }
                if n > 0 || !out.is_empty() {
                    *lock(faults) = (down.totals(), up.totals());
                }
            }
        },
    )
}
