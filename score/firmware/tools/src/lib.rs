//! # score-firmware-tools
//!
//! The host side of the Score firmware:
//!
//! * [`image`]: the firmware ELF as flash and RAM figures, and its UF2 for the RP2040's USB
//!   bootloader (drag-and-drop flashing);
//! * [`emulator`]: starts the rp2040js harness (`score/firmware/emulator`) on the firmware ELF
//!   and drives it: PTY paths of the two USB serial ports, ADC inputs, PWM duty measured at
//!   the pins, emulated time;
//! * [`port`]: a serial port (PTY or `/dev/ttyACM*`) with line and frame helpers for tests.
//!
//! The `score-fw` binary wraps them: `score-fw build` (firmware, UF2, flash/RAM report),
//! `score-fw uf2`, `score-fw size`, `score-fw emulate`.

pub mod emulator;
pub mod image;
pub mod paths;
pub mod port;
