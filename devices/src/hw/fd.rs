//! Non-blocking I/O on a raw file descriptor, without allocation.
//!
//! `serialport`'s own `Read`/`Write` poll first and build a boxed `io::Error` for "timed out"
//! on every empty read; on the real-time path we call `read(2)`/`write(2)` on an `O_NONBLOCK`
//! descriptor instead, where "nothing there" is `EAGAIN` and costs one system call.

use std::io;
use std::os::unix::io::RawFd;

use nix::errno::Errno;

use crate::component::HwError;

/// Sets `O_NONBLOCK` on `fd`.
pub(crate) fn set_nonblocking(fd: RawFd) -> io::Result<()> {
    // SAFETY: fcntl with F_GETFL/F_SETFL only reads and writes the descriptor's flags; an
    // invalid fd yields EBADF, which we report.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
    if flags < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: as above.
    if unsafe { libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK) } < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

/// Sets `FD_CLOEXEC` on `fd`: a process the executor (or a test) starts must not inherit a bus,
/// or the bus stays open in it after we close it (a pty would never hang up).
pub(crate) fn set_cloexec(fd: RawFd) -> io::Result<()> {
    // SAFETY: fcntl with F_GETFD/F_SETFD only reads and writes the descriptor's flags; an
    // invalid fd yields EBADF, which we report.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFD) };
    if flags < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: as above.
    if unsafe { libc::fcntl(fd, libc::F_SETFD, flags | libc::FD_CLOEXEC) } < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

/// `struct serial_struct` from `<linux/serial.h>` (libc has the ioctl numbers, not the struct).
#[cfg(target_os = "linux")]
#[repr(C)]
struct SerialStruct {
    type_: libc::c_int,
    line: libc::c_int,
    port: libc::c_uint,
    irq: libc::c_int,
    flags: libc::c_int,
    xmit_fifo_size: libc::c_int,
    custom_divisor: libc::c_int,
    baud_base: libc::c_int,
    close_delay: libc::c_ushort,
    io_type: libc::c_char,
    reserved_char: [libc::c_char; 1],
    hub6: libc::c_int,
    closing_wait: libc::c_ushort,
    closing_wait2: libc::c_ushort,
    iomem_base: *mut libc::c_uchar,
    iomem_reg_shift: libc::c_ushort,
    port_high: libc::c_uint,
    iomap_base: libc::c_ulong,
}

/// `ASYNC_LOW_LATENCY` from `<linux/tty_flags.h>`.
#[cfg(target_os = "linux")]
const ASYNC_LOW_LATENCY: libc::c_int = 1 << 13;

/// Asks the serial driver for low latency (`ASYNC_LOW_LATENCY`, which FTDI adapters such as
/// the U2D2 turn into a 1 ms latency timer), as DynamixelSDK does. Fails on devices without
/// the serial ioctls (ptys, CDC-ACM): the caller ignores that.
#[cfg(target_os = "linux")]
pub(crate) fn set_low_latency(fd: RawFd) -> io::Result<()> {
    // SAFETY: SerialStruct is plain old data; all-zero is a valid value (null pointer included).
    let mut ss: SerialStruct = unsafe { std::mem::zeroed() };
    // SAFETY: TIOCGSERIAL writes one serial_struct to the pointer, which points to one.
    if unsafe { libc::ioctl(fd, libc::TIOCGSERIAL, &mut ss as *mut SerialStruct) } < 0 {
        return Err(io::Error::last_os_error());
    }
    ss.flags |= ASYNC_LOW_LATENCY;
    // SAFETY: TIOCSSERIAL reads one serial_struct from the pointer.
    if unsafe { libc::ioctl(fd, libc::TIOCSSERIAL, &ss as *const SerialStruct) } < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

/// Not available off Linux.
#[cfg(not(target_os = "linux"))]
pub(crate) fn set_low_latency(_fd: RawFd) -> io::Result<()> {
    Err(io::Error::from(io::ErrorKind::Unsupported))
}

/// The error of the last failed system call, as the link sees it: a vanished device (a pty
/// whose other side closed, an unplugged USB adapter) is a disconnection, anything else an I/O
/// error. Reads `errno` only: nothing is formatted or allocated on the real-time path.
pub(crate) fn hw_error(e: Errno) -> HwError {
    match e {
        Errno::EIO | Errno::ENXIO | Errno::ENODEV | Errno::EBADF => HwError::Disconnected(Some(e)),
        _ => HwError::Io(e),
    }
}

/// One non-blocking `read(2)`: `Ok(0)` when nothing is pending (`EAGAIN`). A tty in raw mode
/// (`VMIN = 1`) returns end-of-file only on hang-up, so a 0 from `read(2)` is a disconnection.
pub(crate) fn read_nb(fd: RawFd, out: &mut [u8]) -> Result<usize, HwError> {
    if out.is_empty() {
        return Ok(0);
    }
    loop {
        // SAFETY: `out` is a valid writable buffer of `out.len()` bytes.
        let n = unsafe { libc::read(fd, out.as_mut_ptr().cast(), out.len()) };
        if n > 0 {
            return Ok(n as usize);
        }
        if n == 0 {
            return Err(HwError::Disconnected(None));
        }
        match Errno::last() {
            Errno::EAGAIN => return Ok(0),
            Errno::EINTR => continue,
            e => return Err(hw_error(e)),
        }
    }
}

/// Bytes the line discipline holds ready to read (`FIONREAD`), without waiting.
///
/// A `read(2)` or `poll(2)` on a tty that finds nothing ready first waits for the kernel's
/// pending receive work (`flush_to_ldisc`, run by a normal-priority kworker) to finish,
/// `O_NONBLOCK` or not: a real-time thread calling it would block for as long as that
/// kworker is kept off the CPU (hundreds of milliseconds on a busy machine). `FIONREAD`
/// only counts what has arrived, so reading only what it reports never waits.
pub(crate) fn pending(fd: RawFd) -> Result<usize, HwError> {
    let mut n: libc::c_int = 0;
    // SAFETY: FIONREAD writes one c_int to the pointer, which points to one.
    if unsafe { libc::ioctl(fd, libc::FIONREAD, &mut n) } < 0 {
        return Err(hw_error(Errno::last()));
    }
    Ok(n.max(0) as usize)
}

/// Waits until the tty's pending receive work has run, so that everything that reached the
/// host before the call can be read: a `poll(2)` with no timeout does exactly that first
/// (`n_tty_poll`). Blocks for as long as that worker waits for a CPU: never on the real-time
/// thread.
pub(crate) fn wait_receivable(fd: RawFd) {
    let mut p = libc::pollfd {
        fd,
        events: libc::POLLIN,
        revents: 0,
    };
    // SAFETY: one valid pollfd; a timeout of 0 returns at once once the tty has been looked at.
    unsafe { libc::poll(&mut p, 1, 0) };
}

/// One non-blocking `write(2)`: returns how many bytes the kernel took (0 when its buffer is
/// full).
pub(crate) fn write_nb(fd: RawFd, data: &[u8]) -> Result<usize, HwError> {
    if data.is_empty() {
        return Ok(0);
    }
    loop {
        // SAFETY: `data` is a valid readable buffer of `data.len()` bytes.
        let n = unsafe { libc::write(fd, data.as_ptr().cast(), data.len()) };
        if n >= 0 {
            return Ok(n as usize);
        }
        match Errno::last() {
            Errno::EAGAIN => return Ok(0),
            Errno::EINTR => continue,
            e => return Err(hw_error(e)),
        }
    }
}
