//! Linux SocketCAN interfaces (`can0`, `vcan0`, an `slcand`-attached adapter, ...).

use std::io;

use conductor_protocols::can::CanFrame;
use socketcan::{CanSocket, EmbeddedFrame, Socket};

use nix::errno::Errno;

use crate::stage::{Hardware, HwCounters, HwError, TickCtx};

/// Converts to socketcan's frame type (for transmission).
pub fn to_socketcan(f: &CanFrame) -> socketcan::CanFrame {
    let frame = if f.is_remote_frame() {
        <socketcan::CanFrame as EmbeddedFrame>::new_remote(f.id(), f.dlc())
    } else {
        <socketcan::CanFrame as EmbeddedFrame>::new(f.id(), f.data())
    };
    // Both types accept exactly the same IDs and lengths (classic CAN, DLC ≤ 8).
    frame.expect("a valid classic CAN frame converts")
}

/// Converts a received socketcan frame; error frames (bus errors reported by the controller)
/// give `None`.
pub fn from_socketcan(f: &socketcan::CanFrame) -> Option<CanFrame> {
    match f {
        socketcan::CanFrame::Error(_) => None,
        socketcan::CanFrame::Remote(r) => CanFrame::new_remote(r.id(), r.dlc()),
        socketcan::CanFrame::Data(d) => CanFrame::new(d.id(), d.data()),
    }
}

/// A raw CAN socket on one interface, non-blocking.
pub struct SocketCanHardware {
    socket: CanSocket,
    iface: String,
    error_frames: u64,
}

impl std::fmt::Debug for SocketCanHardware {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SocketCanHardware")
            .field("iface", &self.iface)
            .finish()
    }
}

impl SocketCanHardware {
    /// Opens `iface` (the interface must exist and be up: `ip link set can0 up type can
    /// bitrate 1000000`). Fails with `ENODEV` when the kernel has no such interface, or
    /// `EAFNOSUPPORT` when it has no CAN support at all.
    pub fn open(iface: &str) -> io::Result<Self> {
        let socket = CanSocket::open(iface)?;
        socket.set_nonblocking(true)?;
        Ok(Self {
            socket,
            iface: iface.into(),
            error_frames: 0,
        })
    }

    /// The interface name.
    pub fn iface(&self) -> &str {
        &self.iface
    }

    /// Error frames received (and not passed on) since opening.
    pub fn error_frames(&self) -> u64 {
        self.error_frames
    }
}

/// Whether interface `name` exists and is up (`IFF_UP` in `/sys/class/net/<name>/flags`).
pub fn interface_up(name: &str) -> bool {
    let path = format!("/sys/class/net/{name}/flags");
    std::fs::read_to_string(path)
        .ok()
        .and_then(|f| u32::from_str_radix(f.trim().trim_start_matches("0x"), 16).ok())
        .is_some_and(|flags| flags & libc::IFF_UP as u32 != 0)
}

/// The interface vanished (`ENODEV`, `ENXIO`: a USB-CAN adapter unplugged, the interface
/// deleted) or went down (`ENETDOWN`): a disconnection, reopened by the link; anything else is
/// an I/O error. OS errors carry their number; io::Error builds no text for them.
fn hw_error(e: io::Error) -> HwError {
    let errno = Errno::from_raw(e.raw_os_error().unwrap_or(libc::EIO));
    match errno {
        Errno::ENODEV | Errno::ENXIO | Errno::ENETDOWN => HwError::Disconnected(Some(errno)),
        _ => HwError::Io(errno),
    }
}

impl Hardware for SocketCanHardware {
    type Word = CanFrame;

    fn transmit(&mut self, words: &[CanFrame], _ctx: TickCtx) -> Result<usize, HwError> {
        for (i, f) in words.iter().enumerate() {
            match self.socket.write_frame(&to_socketcan(f)) {
                Ok(()) => {}
                // The interface's queue is full (txqueuelen): the rest waits for the next tick.
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Ok(i),
                Err(e) if e.raw_os_error() == Some(libc::ENOBUFS) => return Ok(i),
                Err(e) => return Err(hw_error(e)),
            }
        }
        Ok(words.len())
    }

    fn receive(&mut self, out: &mut [CanFrame], _ctx: TickCtx) -> Result<usize, HwError> {
        let mut n = 0;
        while n < out.len() {
            match self.socket.read_frame() {
                Ok(f) => match from_socketcan(&f) {
                    Some(frame) => {
                        out[n] = frame;
                        n += 1;
                    }
                    None => self.error_frames += 1,
                },
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(hw_error(e)),
            }
        }
        Ok(n)
    }

    fn counters(&self) -> HwCounters {
        HwCounters {
            error_frames: self.error_frames,
            ..HwCounters::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_can::{ExtendedId, StandardId};

    #[test]
    fn frames_convert_both_ways() {
        let cases = [
            CanFrame::standard(0x001, &[0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFC]).unwrap(),
            CanFrame::standard(0x7FF, &[]).unwrap(),
            CanFrame::extended(0x12AB_CDEF, &[0xAA, 0x55]).unwrap(),
            CanFrame::new_remote(StandardId::new(0x029).unwrap(), 8).unwrap(),
            CanFrame::new_remote(ExtendedId::new(0x1FFF_FFFF).unwrap(), 0).unwrap(),
        ];
        for f in cases {
            let s = to_socketcan(&f);
            assert_eq!(s.id(), f.id());
            assert_eq!(s.is_remote_frame(), f.is_remote_frame());
            assert_eq!(s.dlc(), f.dlc());
            assert_eq!(from_socketcan(&s), Some(f));
        }
    }

    #[test]
    fn error_frames_are_not_data() {
        let e = socketcan::CanFrame::Error(
            socketcan::CanErrorFrame::new_error(0x004, &[0; 8]).expect("error frame"),
        );
        assert_eq!(from_socketcan(&e), None);
    }

    /// This machine (and CI) has no kernel CAN: opening must fail with a clear OS error, not
    /// panic. Where a vcan0 exists the open succeeds, and that is fine too.
    #[test]
    fn open_without_kernel_can_reports_the_os_error() {
        match SocketCanHardware::open("vcan0") {
            Ok(hw) => assert_eq!(hw.iface(), "vcan0"),
            Err(e) => {
                let code = e.raw_os_error();
                assert!(
                    matches!(code, Some(libc::ENODEV) | Some(libc::EAFNOSUPPORT)),
                    "unexpected error {e:?}"
                );
            }
        }
        let e = SocketCanHardware::open("conductor-none0").unwrap_err();
        assert!(e.raw_os_error().is_some(), "{e:?}");
    }
}
