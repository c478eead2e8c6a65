//! Hardware transports: the stage that moves words on and off a bus without blocking.
//!
//! | Type | Word | Bus |
//! |---|---|---|
//! | [`SerialHardware`] | `u8` | a serial device (USB adapter such as the U2D2, or a pty) |
//! | [`UdpHardware`] | `u8` | a UDP peer (serial-over-network bridges, simulators) |
//! | [`SocketCanHardware`] | [`CanFrame`] | a Linux SocketCAN interface |
//! | [`SlcanHardware`] | [`CanFrame`] | an SLCAN (LAWICEL) USB-CAN adapter on any byte transport |
//! | [`MemPort`] | `u8` | one end of an in-memory byte pipe ([`mem_pipe`]) |
//! | [`MemCanPort`] | [`CanFrame`] | a node on an in-memory CAN bus ([`MemCanBus`]) |
//!
//! Every `transmit`/`receive` returns at once: file descriptors are non-blocking, a full
//! transmit side accepts fewer words (the link keeps the rest for the next tick), and an empty
//! receive side returns 0.
//!
//! [`CanFrame`]: conductor_protocols::can::CanFrame

pub(crate) mod fd;
mod memory;
pub(crate) mod serial;
pub(crate) mod slcan;
pub(crate) mod socketcan;
pub(crate) mod udp;

pub use memory::{mem_pipe, MemCanBus, MemCanPort, MemPort};
pub use serial::{SerialHardware, SerialOptions};
pub use slcan::{SlcanDialect, SlcanHardware, SlcanOpenError, SlcanOptions, SlcanStats};
pub use socketcan::{
    controller_state, from_socketcan, interface_up, realtime_offset_ns, to_socketcan,
    SocketCanHardware,
};
pub use udp::UdpHardware;
