//! Serial ports (USB-serial adapters such as the ROBOTIS U2D2, RS-485 adapters, ptys).

use std::os::unix::io::{AsRawFd, RawFd};
use std::time::Duration;

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
pub struct SerialHardware {
    port: TTYPort,
    fd: RawFd,
    path: String,
    low_latency: bool,
    bytes_out: u64,
    bytes_in: u64,
}

impl std::fmt::Debug for SerialHardware {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SerialHardware")
            .field("path", &self.path)
            .field("low_latency", &self.low_latency)
            .finish()
    }
}

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
        Ok(Self {
            port,
            fd,
            path: path.into(),
            low_latency,
            bytes_out: 0,
            bytes_in: 0,
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
    /// first: an empty `read(2)` on a tty waits for the kernel's receive worker (see
    /// [`fd::pending`]).
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
