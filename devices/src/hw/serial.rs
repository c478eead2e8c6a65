//! Serial ports (USB-serial adapters such as the ROBOTIS U2D2, RS-485 adapters, ptys).

use std::os::unix::io::{AsRawFd, RawFd};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use nix::time::{clock_gettime, ClockId};
use serialport::{DataBits, FlowControl, Parity, SerialPort, StopBits, TTYPort};

use super::fd;
use crate::component::{Hardware, HwError, TickCtx};

/// How to open a serial port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialOptions {
    /// Line speed (any integer on Linux: serialport sets it through `BOTHER`).
    pub baud: u32,
    /// Ask the driver for low latency (`ASYNC_LOW_LATENCY`); failure is ignored.
    pub low_latency: bool,
    /// Take the port exclusively (`TIOCEXCL` + `flock`).
    pub exclusive: bool,
}

impl Default for SerialOptions {
    fn default() -> Self {
        Self {
            baud: 1_000_000,
            low_latency: true,
            exclusive: true,
        }
    }
}

/// A serial port in raw 8N1 mode, read and written without blocking.
///
/// A tty hands received bytes to readers through a normal-priority kernel worker, which a
/// busy machine can keep off the CPU for hundreds of milliseconds. The real-time thread never
/// waits for it (it reads only what `FIONREAD` reports); a helper thread does, and tells
/// when the worker last caught up ([`Hardware::drained_ns`]), so the protocol can tell a
/// quiet line from bytes still held up in the OS.
pub struct SerialHardware {
    port: TTYPort,
    fd: RawFd,
    path: String,
    low_latency: bool,
    bytes_out: u64,
    bytes_in: u64,
    drain: Drain,
}

/// The helper thread behind [`SerialHardware`]'s `drained_ns`.
struct Drain {
    drained_ns: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

/// How often the helper waits for the tty's receive worker.
const DRAIN_EVERY: Duration = Duration::from_micros(500);

impl Drain {
    fn spawn(fd: RawFd, path: &str) -> std::io::Result<Self> {
        let drained_ns = Arc::new(AtomicU64::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let (d, s) = (drained_ns.clone(), stop.clone());
        let thread = std::thread::Builder::new()
            .name(format!("drain-{}", path.rsplit('/').next().unwrap_or(path)))
            .spawn(move || {
                while !s.load(Ordering::Relaxed) {
                    let t = clock_gettime(ClockId::CLOCK_MONOTONIC).map_or(0, |t| {
                        t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64
                    });
                    fd::wait_receivable(fd);
                    d.fetch_max(t, Ordering::Release);
                    std::thread::sleep(DRAIN_EVERY);
                }
            })?;
        Ok(Self {
            drained_ns,
            stop,
            thread: Some(thread),
        })
    }
}

impl Drop for SerialHardware {
    fn drop(&mut self) {
        // The helper polls this descriptor: it stops before the port closes it.
        self.drain.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.drain.thread.take() {
            let _ = t.join();
        }
    }
}

debug_fields!(SerialHardware { path, low_latency });

impl SerialHardware {
    /// Opens `path` (8N1, no flow control), makes it non-blocking and, if asked, low-latency.
    pub fn open(path: &str, opts: &SerialOptions) -> Result<Self, serialport::Error> {
        let port = serialport::new(path, opts.baud)
            .data_bits(DataBits::Eight)
            .parity(Parity::None)
            .stop_bits(StopBits::One)
            .flow_control(FlowControl::None)
            .timeout(Duration::ZERO)
            .open_native()?;
        Self::from_port(port, path, opts)
    }

    /// Wraps an already open port (e.g. one end of `TTYPort::pair()`).
    pub fn from_port(
        mut port: TTYPort,
        path: &str,
        opts: &SerialOptions,
    ) -> Result<Self, serialport::Error> {
        if !opts.exclusive {
            port.set_exclusive(false)?;
        }
        let fd = port.as_raw_fd();
        fd::set_nonblocking(fd)?;
        fd::set_cloexec(fd)?;
        let low_latency = opts.low_latency && fd::set_low_latency(fd).is_ok();
        // Whatever the adapter buffered before we opened it belongs to nobody.
        let _ = port.clear(serialport::ClearBuffer::All);
        let drain = Drain::spawn(fd, path)?;
        Ok(Self {
            port,
            fd,
            path: path.into(),
            low_latency,
            bytes_out: 0,
            bytes_in: 0,
            drain,
        })
    }

    /// The path it was opened with.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// Whether the driver accepted the low-latency flag (false on ptys and CDC-ACM devices).
    pub fn low_latency(&self) -> bool {
        self.low_latency
    }

    /// Bytes written since opening.
    pub fn bytes_out(&self) -> u64 {
        self.bytes_out
    }

    /// Bytes read since opening.
    pub fn bytes_in(&self) -> u64 {
        self.bytes_in
    }

    /// Writes, returning how many bytes the kernel accepted (never blocks).
    pub fn write_some(&mut self, data: &[u8]) -> Result<usize, HwError> {
        let n = fd::write_nb(self.fd, data)?;
        self.bytes_out += n as u64;
        Ok(n)
    }

    /// Reads what is pending (never blocks; 0 when nothing is). It asks how much is ready
    /// first: an empty `read(2)` on a tty waits for the kernel's receive worker.
    pub fn read_some(&mut self, out: &mut [u8]) -> Result<usize, HwError> {
        if fd::pending(self.fd)? == 0 {
            return Ok(0);
        }
        let n = fd::read_nb(self.fd, out)?;
        self.bytes_in += n as u64;
        Ok(n)
    }
}

impl Hardware for SerialHardware {
    type Word = u8;

    fn transmit(&mut self, words: &[u8], _ctx: TickCtx) -> Result<usize, HwError> {
        self.write_some(words)
    }

    fn receive(&mut self, out: &mut [u8], _ctx: TickCtx) -> Result<usize, HwError> {
        self.read_some(out)
    }

    fn drained_ns(&self) -> Option<u64> {
        Some(self.drain.drained_ns.load(Ordering::Acquire))
    }

    fn shutdown(&mut self) {
        // Bounded wait for the last bytes (the safe-action packets) to leave the UART.
        let _ = std::io::Write::flush(&mut self.port);
    }
}

use crate::kinds::{
    Build, BuildError, Capacity, HardwareBuild, KindSpec, OpenedHardware, ParamSpec, Params,
};

/// The `serial` hardware kind.
pub const KIND: KindSpec = KindSpec {
    kind: "serial",
    params: &[
        ParamSpec::text("port", None, "serial device, e.g. /dev/ttyUSB0 or /dev/serial/by-id/usb-FTDI_..."),
        ParamSpec::int("baud", Some(1_000_000), 1200.0, 12_000_000.0, crate::kinds::BAUD_DOC),
        ParamSpec::bool("low_latency", true, "ask the driver for ASYNC_LOW_LATENCY (FTDI: 1 ms latency timer); ignored where unsupported"),
    ],
    doc: "A serial port (USB adapter such as the ROBOTIS U2D2, RS-485 adapter, or a pty), raw 8N1, \
          read and written without blocking.",
    build: Build::Hardware {
        resource: Some("port"),
        open: HardwareBuild::Bytes(open_kind),
    },
};

fn open_kind(p: &Params, _: Capacity) -> Result<OpenedHardware<u8>, BuildError> {
    let port = p.str("port")?;
    let opts = SerialOptions {
        baud: crate::kinds::baud(p)?,
        low_latency: p.bool("low_latency")?,
        exclusive: true,
    };
    let hw = SerialHardware::open(port, &opts).map_err(|e| BuildError::open(port, e))?;
    let baud = opts.baud;
    Ok(OpenedHardware::new(hw)
        .at_baud(baud)
        .reopening_node(port, move |path| SerialHardware::open(path, &opts)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctx() -> TickCtx {
        TickCtx { tick: 0, now_ns: 0 }
    }

    #[test]
    fn pty_round_trip_without_blocking() {
        let (mut master, slave) = TTYPort::pair().expect("pty pair");
        let path = slave.name().expect("pts name");
        let mut hw = SerialHardware::open(&path, &SerialOptions::default()).unwrap();
        assert!(!hw.low_latency(), "a pty has no serial ioctls");
        // Nothing pending: returns 0 at once.
        let mut buf = [0u8; 16];
        assert_eq!(hw.receive(&mut buf, ctx()).unwrap(), 0);
        assert_eq!(hw.transmit(b"hello", ctx()).unwrap(), 5);
        let mut got = [0u8; 5];
        std::io::Read::read_exact(&mut master, &mut got).unwrap();
        assert_eq!(&got, b"hello");
        std::io::Write::write_all(&mut master, b"abc").unwrap();
        let mut n = 0;
        for _ in 0..1000 {
            n += hw.receive(&mut buf[n..], ctx()).unwrap();
            if n == 3 {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(&buf[..n], b"abc");
        assert_eq!((hw.bytes_out(), hw.bytes_in()), (5, 3));
        drop(slave);
    }

    /// Bytes that reached the port before [`Hardware::drained_ns`] are readable: the helper
    /// waited for the tty's receive worker after they came, so one read takes them all.
    #[test]
    fn what_arrived_before_drained_ns_is_read_in_one_go() {
        let (mut master, slave) = TTYPort::pair().expect("pty pair");
        let path = slave.name().unwrap();
        let mut hw = SerialHardware::open(&path, &SerialOptions::default()).unwrap();
        let now = || {
            let t = clock_gettime(ClockId::CLOCK_MONOTONIC).unwrap();
            t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64
        };
        for round in 1..=20u8 {
            let payload = [round; 7];
            std::io::Write::write_all(&mut master, &payload).unwrap();
            let written = now();
            let end = std::time::Instant::now() + Duration::from_secs(10);
            while hw.drained_ns().unwrap() < written {
                assert!(
                    std::time::Instant::now() < end,
                    "the helper never caught up"
                );
                std::thread::sleep(Duration::from_micros(100));
            }
            let mut buf = [0u8; 16];
            assert_eq!(hw.receive(&mut buf, ctx()).unwrap(), 7, "round {round}");
            assert_eq!(&buf[..7], &payload);
        }
        drop(slave);
    }

    #[test]
    fn missing_device_is_an_error() {
        let e = SerialHardware::open("/dev/does-not-exist-conductor", &SerialOptions::default())
            .unwrap_err();
        assert!(
            matches!(
                e.kind(),
                serialport::ErrorKind::NoDevice
                    | serialport::ErrorKind::Io(std::io::ErrorKind::NotFound)
            ),
            "{e:?}"
        );
    }

    #[test]
    fn closed_peer_reports_disconnected() {
        let (master, slave) = TTYPort::pair().expect("pty pair");
        let path = slave.name().unwrap();
        let mut hw = SerialHardware::open(&path, &SerialOptions::default()).unwrap();
        drop(master);
        let mut buf = [0u8; 4];
        assert!(
            matches!(hw.receive(&mut buf, ctx()), Err(HwError::Disconnected(_))),
            "a hang-up is a disconnection"
        );
        drop(slave);
    }
}
