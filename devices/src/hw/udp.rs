//! UDP: a byte stream carried in datagrams, for serial-over-network bridges and simulators
//! running on another machine.

use std::io;
use std::net::{SocketAddr, UdpSocket};

use crate::component::{Hardware, HwError, TickCtx};

/// Largest datagram accepted.
const MAX_DATAGRAM: usize = 2048;

/// A connected, non-blocking UDP socket. Each `transmit` sends one datagram (split at 1472
/// bytes, a safe Ethernet payload); received datagrams are concatenated into the byte stream.
pub struct UdpHardware {
    socket: UdpSocket,
    peer: SocketAddr,
    /// A datagram only partly handed out (`out` was smaller than it).
    held: [u8; MAX_DATAGRAM],
    held_len: usize,
    held_pos: usize,
}

debug_fields!(UdpHardware { peer });

/// Payload per datagram.
const MTU_PAYLOAD: usize = 1472;

impl UdpHardware {
    /// Binds `local` and talks to `peer` only (datagrams from elsewhere are dropped by the OS).
    pub fn open(local: SocketAddr, peer: SocketAddr) -> io::Result<Self> {
        let socket = UdpSocket::bind(local)?;
        socket.connect(peer)?;
        socket.set_nonblocking(true)?;
        Ok(Self {
            socket,
            peer,
            held: [0; MAX_DATAGRAM],
            held_len: 0,
            held_pos: 0,
        })
    }

    /// The bound local address.
    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.socket.local_addr()
    }
}

/// Every failure of a connected UDP socket is an I/O error: there is no device to vanish (a
/// peer that went away is `ECONNREFUSED`, absorbed by the callers).
fn hw_error(e: io::Error) -> HwError {
    HwError::Io(HwError::errno_of(&e))
}

impl Hardware for UdpHardware {
    type Word = u8;

    fn transmit(&mut self, words: &[u8], _ctx: TickCtx) -> Result<usize, HwError> {
        let mut sent = 0;
        for chunk in words.chunks(MTU_PAYLOAD) {
            match self.socket.send(chunk) {
                Ok(n) => sent += n,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                // Nobody listening (ICMP port unreachable from an earlier send): the bytes are
                // gone, as on a serial line with nothing attached.
                Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => sent += chunk.len(),
                Err(e) => return Err(hw_error(e)),
            }
        }
        Ok(sent)
    }

    fn receive(&mut self, out: &mut [u8], _ctx: TickCtx) -> Result<usize, HwError> {
        let mut n = 0;
        loop {
            if self.held_pos < self.held_len {
                let k = (self.held_len - self.held_pos).min(out.len() - n);
                out[n..n + k].copy_from_slice(&self.held[self.held_pos..self.held_pos + k]);
                self.held_pos += k;
                n += k;
            }
            if n == out.len() {
                return Ok(n);
            }
            match self.socket.recv(&mut self.held) {
                Ok(k) => {
                    self.held_len = k;
                    self.held_pos = 0;
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Ok(n),
                Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => return Ok(n),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(hw_error(e)),
            }
        }
    }
}

use crate::kinds::{
    Build, BuildError, Capacity, HardwareBuild, KindSpec, OpenedHardware, ParamSpec, Params,
};

/// The `udp` hardware kind.
pub const KIND: KindSpec = KindSpec {
    kind: "udp",
    params: &[
        ParamSpec::text(
            "remote",
            None,
            "peer address host:port (a serial-over-UDP bridge, conductor-sim --udp)",
        ),
        ParamSpec::text("local", Some("0.0.0.0:0"), "local address to bind"),
        ParamSpec::int(
            "baud",
            Some(1_000_000),
            1200.0,
            12_000_000.0,
            "speed of the serial bus behind the bridge (bit/s), for the protocol's timing",
        ),
    ],
    doc: "A byte stream over UDP datagrams (non-blocking, connected to one peer).",
    build: Build::Hardware {
        resource: None,
        open: HardwareBuild::Bytes(open_kind),
    },
};

fn open_kind(p: &Params, _: Capacity) -> Result<OpenedHardware<u8>, BuildError> {
    let local = crate::kinds::socket_addr(p, "local")?;
    let remote = crate::kinds::socket_addr(p, "remote")?;
    let hw = UdpHardware::open(local, remote).map_err(|e| BuildError::open("udp", e))?;
    Ok(OpenedHardware::new(hw).at_baud(crate::kinds::baud(p)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn datagrams_become_a_byte_stream() {
        let any: SocketAddr = "127.0.0.1:0".parse().unwrap();
        let peer = UdpSocket::bind(any).unwrap();
        let mut hw = UdpHardware::open(any, peer.local_addr().unwrap()).unwrap();
        peer.connect(hw.local_addr().unwrap()).unwrap();
        let ctx = TickCtx { tick: 0, now_ns: 0 };
        let mut out = [0u8; 4];
        assert_eq!(hw.receive(&mut out, ctx).unwrap(), 0, "nothing pending");
        assert_eq!(hw.transmit(&[1, 2, 3], ctx).unwrap(), 3);
        let mut buf = [0u8; 16];
        assert_eq!(peer.recv(&mut buf).unwrap(), 3);
        peer.send(&[10, 11, 12]).unwrap();
        peer.send(&[13, 14]).unwrap();
        let mut got = Vec::new();
        for _ in 0..1000 {
            let k = hw.receive(&mut out, ctx).unwrap();
            got.extend_from_slice(&out[..k]);
            if got.len() == 5 {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        assert_eq!(
            got,
            [10, 11, 12, 13, 14],
            "split across a small buffer, in order"
        );
    }

    /// The socket is connected to `remote`: the kernel drops datagrams from any other address
    /// or port, so only the configured bridge can put bytes on the bus (docs/permissions.md).
    #[test]
    fn datagrams_from_anyone_but_the_peer_are_dropped() {
        let any: SocketAddr = "127.0.0.1:0".parse().unwrap();
        let peer = UdpSocket::bind(any).unwrap();
        let stranger = UdpSocket::bind(any).unwrap();
        let mut hw = UdpHardware::open(any, peer.local_addr().unwrap()).unwrap();
        let to = hw.local_addr().unwrap();
        stranger.send_to(&[66, 66], to).unwrap();
        peer.send_to(&[7], to).unwrap();
        let ctx = TickCtx { tick: 0, now_ns: 0 };
        let mut out = [0u8; 8];
        let mut got = Vec::new();
        for _ in 0..1000 {
            let k = hw.receive(&mut out, ctx).unwrap();
            got.extend_from_slice(&out[..k]);
            if !got.is_empty() {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        // The stranger's first datagram was sent before the peer's, so it would have come
        // first; a later one does not arrive either.
        stranger.send_to(&[66], to).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(50));
        let k = hw.receive(&mut out, ctx).unwrap();
        got.extend_from_slice(&out[..k]);
        assert_eq!(got, [7]);
    }

    /// A socket the OS refuses to send on (shut for writing) reports the OS's own error number
    /// as a typed value, every time; receiving still works.
    #[test]
    fn a_refused_send_is_a_typed_errno() {
        use nix::errno::Errno;
        use std::os::fd::AsRawFd;

        let any: SocketAddr = "127.0.0.1:0".parse().unwrap();
        let peer = UdpSocket::bind(any).unwrap();
        let mut hw = UdpHardware::open(any, peer.local_addr().unwrap()).unwrap();
        // SAFETY: shutdown(2) on a descriptor the socket owns; it changes no memory.
        let r = unsafe { libc::shutdown(hw.socket.as_raw_fd(), libc::SHUT_WR) };
        assert_eq!(r, 0);
        let ctx = TickCtx { tick: 0, now_ns: 0 };
        for _ in 0..3 {
            assert_eq!(hw.transmit(&[1, 2, 3], ctx), Err(HwError::Io(Errno::EPIPE)));
        }
        assert_eq!(
            HwError::Io(Errno::EPIPE).to_string(),
            "I/O error: EPIPE: Broken pipe"
        );
        peer.send_to(&[9], hw.local_addr().unwrap()).unwrap();
        let mut out = [0u8; 4];
        let mut got = 0;
        for _ in 0..1000 {
            got = hw.receive(&mut out, ctx).unwrap();
            if got > 0 {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        assert_eq!(&out[..got], &[9]);
    }
}
