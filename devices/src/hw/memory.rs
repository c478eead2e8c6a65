//! In-memory buses for tests and in-process simulation: a byte pipe and a CAN bus.
//!
//! Both are bounded (capacity fixed at creation) and shareable across threads. They take a
//! mutex per call, which is fine for tests and simulators; real buses never go through here.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};

use conductor_protocols::can::CanFrame;

use crate::component::{Hardware, HwError, TickCtx};

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panicking test thread must not cascade into every other user of the bus.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

#[derive(Debug)]
struct Queue<T> {
    items: VecDeque<T>,
    cap: usize,
}

impl<T: Copy> Queue<T> {
    fn new(cap: usize) -> Self {
        Self {
            items: VecDeque::with_capacity(cap),
            cap,
        }
    }

    fn push_some(&mut self, data: &[T]) -> usize {
        let n = data.len().min(self.cap - self.items.len());
        self.items.extend(&data[..n]);
        n
    }

    fn pop_some(&mut self, out: &mut [T]) -> usize {
        let n = out.len().min(self.items.len());
        for (o, v) in out.iter_mut().zip(self.items.drain(..n)) {
            *o = v;
        }
        n
    }
}

/// One end of an in-memory byte pipe.
#[derive(Debug, Clone)]
pub struct MemPort {
    tx: Arc<Mutex<Queue<u8>>>,
    rx: Arc<Mutex<Queue<u8>>>,
}

/// Two connected ends: bytes written to one are read from the other. Each direction holds at
/// most `capacity` bytes; a write to a full direction accepts fewer.
pub fn mem_pipe(capacity: usize) -> (MemPort, MemPort) {
    let a = Arc::new(Mutex::new(Queue::new(capacity)));
    let b = Arc::new(Mutex::new(Queue::new(capacity)));
    (
        MemPort {
            tx: a.clone(),
            rx: b.clone(),
        },
        MemPort { tx: b, rx: a },
    )
}

impl MemPort {
    /// Writes as many bytes as fit; returns how many.
    pub fn write(&self, data: &[u8]) -> usize {
        lock(&self.tx).push_some(data)
    }

    /// Reads what is pending.
    pub fn read(&self, out: &mut [u8]) -> usize {
        lock(&self.rx).pop_some(out)
    }

    /// Bytes waiting to be read at this end.
    pub fn pending(&self) -> usize {
        lock(&self.rx).items.len()
    }
}

impl Hardware for MemPort {
    type Word = u8;

    fn transmit(&mut self, words: &[u8], _ctx: TickCtx) -> Result<usize, HwError> {
        Ok(self.write(words))
    }

    fn receive(&mut self, out: &mut [u8], _ctx: TickCtx) -> Result<usize, HwError> {
        Ok(self.read(out))
    }
}

#[derive(Debug)]
struct BusInner {
    nodes: Vec<Queue<CanFrame>>,
    overruns: Vec<u64>,
    cap: usize,
}

/// An in-memory CAN bus: every frame a node transmits is delivered to every other node (as on
/// a real bus, a node does not receive its own frames). A node whose receive queue is full
/// loses the frame and counts an overrun.
#[derive(Debug, Clone)]
pub struct MemCanBus {
    inner: Arc<Mutex<BusInner>>,
}

/// A node on a [`MemCanBus`].
#[derive(Debug, Clone)]
pub struct MemCanPort {
    bus: Arc<Mutex<BusInner>>,
    node: usize,
}

impl MemCanBus {
    /// A bus whose nodes each buffer up to `capacity` received frames.
    pub fn new(capacity: usize) -> Self {
        Self {
            inner: Arc::new(Mutex::new(BusInner {
                nodes: Vec::new(),
                overruns: Vec::new(),
                cap: capacity,
            })),
        }
    }

    /// Attaches a new node.
    pub fn attach(&self) -> MemCanPort {
        let mut b = lock(&self.inner);
        let cap = b.cap;
        b.nodes.push(Queue::new(cap));
        b.overruns.push(0);
        MemCanPort {
            bus: self.inner.clone(),
            node: b.nodes.len() - 1,
        }
    }
}

impl MemCanPort {
    /// Puts frames on the bus (always accepted: the bus itself never refuses).
    pub fn send(&self, frames: &[CanFrame]) -> usize {
        let mut b = lock(&self.bus);
        let BusInner {
            nodes, overruns, ..
        } = &mut *b;
        for (i, q) in nodes.iter_mut().enumerate() {
            if i != self.node {
                for f in frames {
                    if q.push_some(std::slice::from_ref(f)) == 0 {
                        overruns[i] += 1;
                    }
                }
            }
        }
        frames.len()
    }

    /// Takes received frames.
    pub fn recv(&self, out: &mut [CanFrame]) -> usize {
        lock(&self.bus).nodes[self.node].pop_some(out)
    }

    /// Frames this node lost because its queue was full.
    pub fn overruns(&self) -> u64 {
        lock(&self.bus).overruns[self.node]
    }
}

impl Hardware for MemCanPort {
    type Word = CanFrame;

    fn transmit(&mut self, words: &[CanFrame], _ctx: TickCtx) -> Result<usize, HwError> {
        Ok(self.send(words))
    }

    fn receive(&mut self, out: &mut [CanFrame], _ctx: TickCtx) -> Result<usize, HwError> {
        Ok(self.recv(out))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pipe_is_bounded_and_ordered() {
        let (a, b) = mem_pipe(4);
        assert_eq!(a.write(&[1, 2, 3, 4, 5]), 4);
        let mut out = [0u8; 8];
        assert_eq!(b.read(&mut out), 4);
        assert_eq!(&out[..4], &[1, 2, 3, 4]);
        assert_eq!(b.write(&[9]), 1);
        assert_eq!(a.read(&mut out), 1);
        assert_eq!(out[0], 9);
    }

    #[test]
    fn can_bus_broadcasts_to_others_only() {
        let bus = MemCanBus::new(2);
        let (a, b, c) = (bus.attach(), bus.attach(), bus.attach());
        let f = CanFrame::standard(0x123, &[1]).unwrap();
        a.send(&[f, f, f]);
        let mut out = [CanFrame::standard(0, &[]).unwrap(); 4];
        assert_eq!(a.recv(&mut out), 0, "no echo of own frames");
        assert_eq!(b.recv(&mut out), 2);
        assert_eq!(out[0], f);
        assert_eq!(c.overruns(), 1);
        assert_eq!(c.recv(&mut out), 2);
    }
}
