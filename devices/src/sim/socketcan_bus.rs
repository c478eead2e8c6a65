//! The CAN motor simulators ([`super::can_motors`]) on a real SocketCAN interface, in a thread
//! of their own: every frame another socket sends on the interface (an executor, `cansend`)
//! reaches every node; their answers and cyclic messages go back on it. On `vcan0` this is a
//! bus of motors behind the kernel's CAN stack; `conductor-sim socketcan` runs it as a process.
//!
//! The interface may go down or be deleted and re-created under the same name (what unplugging
//! a USB-CAN adapter does): the motors stay powered and keep their state, and the simulator
//! opens the interface again as soon as it is back up.

use super::worker::Worker;
use std::io;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use conductor_protocols::can::CanFrame;
use socketcan::{CanSocket, Socket};

use super::can_motors::{CanNode, NodeSnapshot};
use crate::hw::{from_socketcan, interface_up, to_socketcan};

/// How often the thread looks at the nodes' cyclic messages and its stop flag when the bus is
/// quiet (a frame wakes it at once).
const POLL: Duration = Duration::from_millis(5);

/// Simulated CAN nodes on a SocketCAN interface.
pub struct SocketCanSim {
    nodes: Arc<Mutex<Vec<Box<dyn CanNode>>>>,
    reopens: Arc<AtomicU64>,
    frames_in: Arc<AtomicU64>,
    frames_out: Arc<AtomicU64>,
    worker: Worker,
    iface: String,
}

debug_fields!(SocketCanSim { iface });

impl SocketCanSim {
    /// Starts `nodes` on interface `iface` (which must exist and be up).
    pub fn start(iface: &str, nodes: Vec<Box<dyn CanNode>>) -> io::Result<Self> {
        let socket = open(iface)?;
        let nodes = Arc::new(Mutex::new(nodes));
        let reopens = Arc::new(AtomicU64::new(0));
        let frames_in = Arc::new(AtomicU64::new(0));
        let frames_out = Arc::new(AtomicU64::new(0));
        let (name, nodes2) = (iface.to_string(), nodes.clone());
        let (r2, i2, o2) = (reopens.clone(), frames_in.clone(), frames_out.clone());
        let worker = Worker::spawn(format!("cansim-{iface}"), move |stop| {
            Serve {
                iface: name,
                socket: Some(socket),
                nodes: nodes2,
                stop,
                reopens: r2,
                frames_in: i2,
                frames_out: o2,
                t0: Instant::now(),
            }
            .run()
        })?;
        Ok(Self {
            nodes,
            reopens,
            frames_in,
            frames_out,
            worker,
            iface: iface.to_string(),
        })
    }

    /// The nodes (locked while the thread is not using them).
    pub fn nodes(&self) -> MutexGuard<'_, Vec<Box<dyn CanNode>>> {
        self.nodes.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Node `i`'s state.
    pub fn snapshot(&self, i: usize) -> NodeSnapshot {
        self.nodes()[i].snapshot()
    }

    /// Times the interface was opened again after it vanished.
    pub fn reopens(&self) -> u64 {
        self.reopens.load(Ordering::Relaxed)
    }

    /// Frames read from the bus (addressed to any node or not).
    pub fn frames_in(&self) -> u64 {
        self.frames_in.load(Ordering::Relaxed)
    }

    /// Frames the nodes sent.
    pub fn frames_out(&self) -> u64 {
        self.frames_out.load(Ordering::Relaxed)
    }

    /// Stops the thread.
    pub fn stop(mut self) {
        self.worker.halt();
    }
}

fn open(iface: &str) -> io::Result<CanSocket> {
    let s = CanSocket::open(iface)?;
    s.set_read_timeout(POLL)?;
    Ok(s)
}

struct Serve {
    iface: String,
    socket: Option<CanSocket>,
    nodes: Arc<Mutex<Vec<Box<dyn CanNode>>>>,
    stop: Arc<AtomicBool>,
    reopens: Arc<AtomicU64>,
    frames_in: Arc<AtomicU64>,
    frames_out: Arc<AtomicU64>,
    t0: Instant,
}

impl Serve {
    fn run(mut self) {
        let mut out: Vec<CanFrame> = Vec::with_capacity(64);
        while !self.stop.load(Ordering::Relaxed) {
            let Some(socket) = &self.socket else {
                // Gone: back as soon as the interface is up again.
                std::thread::sleep(Duration::from_millis(10));
                if interface_up(&self.iface) {
                    if let Ok(s) = open(&self.iface) {
                        self.socket = Some(s);
                        self.reopens.fetch_add(1, Ordering::Relaxed);
                    }
                }
                continue;
            };
            out.clear();
            match socket.read_frame() {
                Ok(f) => {
                    let now = self.t0.elapsed().as_nanos() as u64;
                    if let Some(frame) = from_socketcan(&f) {
                        self.frames_in.fetch_add(1, Ordering::Relaxed);
                        let mut nodes = self.nodes.lock().unwrap_or_else(|e| e.into_inner());
                        for n in nodes.iter_mut() {
                            n.on_frame(&frame, now, &mut out);
                        }
                    }
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::WouldBlock
                            | io::ErrorKind::TimedOut
                            | io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => {
                    // ENETDOWN once when it goes down, ENODEV when it is deleted: reopen.
                    let gone = matches!(
                        e.raw_os_error(),
                        Some(libc::ENETDOWN) | Some(libc::ENODEV) | Some(libc::ENXIO)
                    );
                    if gone {
                        self.socket = None;
                        continue;
                    }
                    std::thread::sleep(POLL);
                }
            }
            let now = self.t0.elapsed().as_nanos() as u64;
            {
                let mut nodes = self.nodes.lock().unwrap_or_else(|e| e.into_inner());
                for n in nodes.iter_mut() {
                    n.poll(now, &mut out);
                }
            }
            if let Some(socket) = &self.socket {
                for f in &out {
                    if socket.write_frame(&to_socketcan(f)).is_ok() {
                        self.frames_out.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        }
    }
}
