//! Linux SocketCAN interfaces (`can0`, `vcan0`, an `slcand`-attached adapter, ...).
//!
//! A raw CAN socket, non-blocking, with
//!
//! * the kernel's receive timestamp of every frame (`SO_TIMESTAMPNS`, taken when the frame
//!   entered the network stack), moved to CLOCK_MONOTONIC: the sample time of the replies;
//! * the driver's error frames (`CAN_RAW_ERR_FILTER`): counted, and the controller's state
//!   (warning, error-passive, bus-off, restarted) kept as the bus's [`BusCondition`];
//! * a full transmit queue (`ENOBUFS`: `txqueuelen` frames already wait) counted and kept as
//!   a condition until frames go out again; what did not fit goes with the next tick's.

use std::io;
use std::time::{SystemTime, UNIX_EPOCH};

use conductor_protocols::can::CanFrame;
use socketcan::{CanSocket, EmbeddedFrame, Socket, SocketOptions};

use nix::errno::Errno;
use nix::time::{clock_gettime, ClockId};

use crate::component::{BusCondition, ControllerState, Hardware, HwCounters, HwError, TickCtx};

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

/// The error classes the socket asks the driver for (`can_err_mask`): everything a
/// controller reports (`CAN_ERR_MASK`).
pub const ERR_MASK: u32 = libc::CAN_ERR_MASK;

/// How long the transmit queue must take every frame before it counts as no longer full.
pub const TX_FULL_CLEAR_NS: u64 = 1_000_000_000;

/// Most frames taken in one [`Hardware::receive`] call (the rest wait for the next).
const RX_BATCH: usize = 512;

/// A raw CAN socket on one interface, non-blocking.
pub struct SocketCanHardware {
    socket: CanSocket,
    iface: String,
    error_frames: u64,
    tx_full: u64,
    /// When the transmit queue last refused a frame (CLOCK_MONOTONIC ns).
    last_full_ns: u64,
    /// CLOCK_REALTIME − CLOCK_MONOTONIC (ns), measured at `offset_at` (monotonic ns).
    offset: (i128, u64),
    timestamps: bool,
    /// Arrival times of the frames of the last receive (CLOCK_MONOTONIC ns, 0 = unknown).
    rx_times: Vec<u64>,
    condition: BusCondition,
    /// The last error frame's class bits and data, for diagnostics.
    last_error: (u32, [u8; 8]),
}

debug_fields!(SocketCanHardware { iface });

impl SocketCanHardware {
    /// Opens `iface` (the interface must exist and be up: `ip link set can0 up type can
    /// bitrate 1000000`). Fails with `ENODEV` when the kernel has no such interface, or
    /// `EAFNOSUPPORT` when it has no CAN support at all.
    pub fn open(iface: &str) -> io::Result<Self> {
        let socket = CanSocket::open(iface)?;
        socket.set_nonblocking(true)?;
        socket.set_error_filter(ERR_MASK)?;
        // Where the kernel cannot stamp, the protocol stamps with its tick's time.
        let timestamps = socket.set_recv_timestamp(true).is_ok();
        Ok(Self {
            socket,
            iface: iface.into(),
            error_frames: 0,
            tx_full: 0,
            last_full_ns: 0,
            offset: (realtime_offset_ns(), 0),
            timestamps,
            rx_times: Vec::with_capacity(RX_BATCH),
            condition: BusCondition::default(),
            last_error: (0, [0; 8]),
        })
    }

    /// Whether frames carry the kernel's receive timestamp.
    pub fn timestamps(&self) -> bool {
        self.timestamps
    }

    /// The last error frame: its class bits (`CAN_ERR_*` of the id) and data.
    pub fn last_error(&self) -> (u32, [u8; 8]) {
        self.last_error
    }

    /// An error frame from the driver: counted; a controller state change taken.
    fn on_error_frame(&mut self, class: u32, data: &[u8]) {
        self.error_frames += 1;
        let mut d = [0u8; 8];
        d[..data.len().min(8)].copy_from_slice(&data[..data.len().min(8)]);
        self.last_error = (class, d);
        if let Some(state) = controller_state(class, &d) {
            self.condition.controller = state;
        }
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

/// The controller state an error frame reports, if it reports one: bus-off, restarted (back
/// to error-active), or the `CAN_ERR_CRTL` status byte (`data[1]`).
pub fn controller_state(class: u32, data: &[u8; 8]) -> Option<ControllerState> {
    if class & libc::CAN_ERR_BUSOFF != 0 {
        return Some(ControllerState::BusOff);
    }
    if class & libc::CAN_ERR_RESTARTED != 0 {
        return Some(ControllerState::Active);
    }
    if class & libc::CAN_ERR_CRTL != 0 {
        let s = data[1] as u32;
        let passive = libc::CAN_ERR_CRTL_RX_PASSIVE | libc::CAN_ERR_CRTL_TX_PASSIVE;
        let warning = libc::CAN_ERR_CRTL_RX_WARNING | libc::CAN_ERR_CRTL_TX_WARNING;
        if s & passive as u32 != 0 {
            return Some(ControllerState::Passive);
        }
        if s & warning as u32 != 0 {
            return Some(ControllerState::Warning);
        }
        if s & libc::CAN_ERR_CRTL_ACTIVE as u32 != 0 {
            return Some(ControllerState::Active);
        }
    }
    None
}

/// CLOCK_REALTIME minus CLOCK_MONOTONIC now (ns): what turns a kernel receive timestamp
/// (wall clock) into the monotonic time samples carry. The wall clock is read between two
/// monotonic reads, three times, and the tightest bracket kept (a preemption between two reads
/// would otherwise shift every timestamp). vDSO calls only; no allocation.
pub fn realtime_offset_ns() -> i128 {
    let ns = |c: ClockId| {
        clock_gettime(c).map_or(0, |t| {
            t.tv_sec() as i128 * 1_000_000_000 + t.tv_nsec() as i128
        })
    };
    let mut best = (i128::MAX, 0);
    for _ in 0..3 {
        let m0 = ns(ClockId::CLOCK_MONOTONIC);
        let real = ns(ClockId::CLOCK_REALTIME);
        let m1 = ns(ClockId::CLOCK_MONOTONIC);
        if m1 - m0 < best.0 {
            best = (m1 - m0, real - (m0 + m1) / 2);
        }
    }
    best.1
}

/// How often the wall-clock offset is measured again (the wall clock may be stepped or slewed).
const OFFSET_EVERY_NS: u64 = 1_000_000_000;

/// A kernel timestamp (wall clock) on CLOCK_MONOTONIC, given the offset between the two;
/// 0 if it cannot be told.
fn to_monotonic(t: SystemTime, offset: i128) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .ok()
        .map(|d| d.as_nanos() as i128 - offset)
        .filter(|&m| m > 0)
        .map_or(0, |m| m as u64)
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
    let errno = HwError::errno_of(&e);
    match errno {
        Errno::ENODEV | Errno::ENXIO | Errno::ENETDOWN => HwError::Disconnected(Some(errno)),
        _ => HwError::Io(errno),
    }
}

impl Hardware for SocketCanHardware {
    type Word = CanFrame;

    fn transmit(&mut self, words: &[CanFrame], ctx: TickCtx) -> Result<usize, HwError> {
        for (i, f) in words.iter().enumerate() {
            match self.socket.write_frame(&to_socketcan(f)) {
                Ok(()) => {}
                // The interface's queue is full (txqueuelen frames wait; ENOBUFS) or the
                // socket's send buffer is: counted; the rest goes with the next tick's frames.
                Err(e)
                    if e.kind() == io::ErrorKind::WouldBlock
                        || e.raw_os_error() == Some(libc::ENOBUFS) =>
                {
                    self.tx_full += 1;
                    self.condition.tx_full = true;
                    self.last_full_ns = ctx.now_ns;
                    return Ok(i);
                }
                Err(e) => return Err(hw_error(e)),
            }
        }
        // Full until the queue has taken everything for a while: a queue that flaps (a slow
        // adapter) is one condition, not a line per tick.
        if !words.is_empty() && ctx.now_ns.saturating_sub(self.last_full_ns) >= TX_FULL_CLEAR_NS {
            self.condition.tx_full = false;
        }
        Ok(words.len())
    }

    fn receive(&mut self, out: &mut [CanFrame], ctx: TickCtx) -> Result<usize, HwError> {
        self.rx_times.clear();
        if self.timestamps && ctx.now_ns.saturating_sub(self.offset.1) >= OFFSET_EVERY_NS {
            self.offset = (realtime_offset_ns(), ctx.now_ns);
        }
        let offset = self.offset.0;
        let mut n = 0;
        while n < out.len().min(RX_BATCH) {
            let read = if self.timestamps {
                self.socket
                    .read_frame_with_timestamps()
                    .map(|(f, ts)| (f, ts.socket))
            } else {
                self.socket.read_frame().map(|f| (f, None))
            };
            match read {
                Ok((socketcan::CanFrame::Error(e), _)) => {
                    let class = e.error_bits();
                    self.on_error_frame(class, e.data());
                }
                Ok((f, ts)) => {
                    if let Some(frame) = from_socketcan(&f) {
                        out[n] = frame;
                        self.rx_times
                            .push(ts.map_or(0, |t| to_monotonic(t, offset)));
                        n += 1;
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(hw_error(e)),
            }
        }
        Ok(n)
    }

    fn rx_times(&self) -> &[u64] {
        &self.rx_times
    }

    fn condition(&self) -> BusCondition {
        self.condition
    }

    fn counters(&self) -> HwCounters {
        HwCounters {
            error_frames: self.error_frames,
            tx_full: self.tx_full,
            ..HwCounters::default()
        }
    }
}

use crate::kinds::{
    Build, BuildError, Capacity, HardwareBuild, KindSpec, OpenedHardware, ParamSpec, Params,
};

/// The `socketcan` hardware kind.
pub const KIND: KindSpec = KindSpec {
    kind: "socketcan",
    params: &[
        ParamSpec::text("interface", None, "CAN interface, e.g. can0 (bring it up first: ip link set can0 up type can bitrate 1000000)"),
        ParamSpec::int("bitrate", Some(1_000_000), 10_000.0, 1_000_000.0, "the bitrate the interface was brought up with (bit/s), for the bus-load check"),
    ],
    doc: "A Linux SocketCAN interface, raw socket, non-blocking.",
    build: Build::Hardware {
        resource: Some("interface"),
        open: HardwareBuild::Can(open_kind),
    },
};

fn open_kind(p: &Params, _: Capacity) -> Result<OpenedHardware<CanFrame>, BuildError> {
    let iface = p.str("interface")?;
    let hw = SocketCanHardware::open(iface).map_err(|e| BuildError::open(iface, e))?;
    let (again, name) = (iface.to_string(), iface.to_string());
    Ok(OpenedHardware::new(hw).reopening(
        iface,
        // A down interface opens but cannot send: wait until it is up.
        move || {
            if !interface_up(&again) {
                return Err(format!("{again} is not up"));
            }
            SocketCanHardware::open(&again).map_err(|e| e.to_string())
        },
        move || interface_up(&name),
    ))
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
    fn error_frames_tell_the_controller_state() {
        let crtl = |b1: u8| [0, b1, 0, 0, 0, 0, 0, 0];
        assert_eq!(
            controller_state(libc::CAN_ERR_BUSOFF, &[0; 8]),
            Some(ControllerState::BusOff)
        );
        assert_eq!(
            controller_state(libc::CAN_ERR_RESTARTED, &[0; 8]),
            Some(ControllerState::Active)
        );
        let c = libc::CAN_ERR_CRTL;
        let tx_passive = libc::CAN_ERR_CRTL_TX_PASSIVE as u8;
        let rx_warning = libc::CAN_ERR_CRTL_RX_WARNING as u8;
        let active = libc::CAN_ERR_CRTL_ACTIVE as u8;
        assert_eq!(
            controller_state(c, &crtl(tx_passive)),
            Some(ControllerState::Passive)
        );
        assert_eq!(
            controller_state(c, &crtl(rx_warning)),
            Some(ControllerState::Warning)
        );
        assert_eq!(
            controller_state(c, &crtl(active)),
            Some(ControllerState::Active)
        );
        // A protocol error or a missing acknowledgement is counted, not a state.
        assert_eq!(controller_state(libc::CAN_ERR_PROT, &[0; 8]), None);
        assert_eq!(controller_state(libc::CAN_ERR_ACK, &[0; 8]), None);
    }

    #[test]
    fn kernel_timestamps_move_to_the_monotonic_clock() {
        let offset = realtime_offset_ns();
        let mono_now = clock_gettime(ClockId::CLOCK_MONOTONIC).unwrap();
        let mono_now = mono_now.tv_sec() as u64 * 1_000_000_000 + mono_now.tv_nsec() as u64;
        let m = to_monotonic(SystemTime::now(), offset);
        assert!(m.abs_diff(mono_now) < 50_000_000, "{m} vs {mono_now}");
        assert_eq!(to_monotonic(UNIX_EPOCH, offset), 0);
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
