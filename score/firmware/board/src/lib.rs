//! # score-board
//!
//! Everything of the Score RP2040 firmware that does not touch a register, so it runs (and is
//! tested) on the host as well:
//!
//! * [`pwm`]: the RP2040 PWM block as numbers: divider and TOP for a requested frequency,
//!   compare values for a duty, which slice and pins an output uses, shared-slice bookkeeping;
//! * [`pins`]: which GPIO is used by what (PWM, digital in/out, ADC);
//! * [`hal`]: score-core's HAL traits on top of a small register interface ([`hal::PortIo`]);
//! * [`adc`]: the software differential pairs built from the single-ended channels;
//! * [`board`]: the engine, the port's HAL and the link subscriptions in one place;
//! * [`sampler`]: which subscribed variables to send after a tick, stamped with the instant
//!   they were produced;
//! * [`link`]: the `score_link` server: requests in, reply frames out;
//! * [`terminal`]: the human terminal: echo, line editing, prompt, banner, commands;
//! * [`bench`](mod@bench): the Fig. 5.20 PID timed update by update against a cycle counter;
//! * [`out`]: fixed-capacity output buffers (text with CR LF, concatenated frames).
//!
//! The firmware (`score/firmware/src`) only adds Embassy tasks, USB and the registers.
#![no_std]
#![forbid(unsafe_code)]

#[cfg(test)]
extern crate std;

pub mod adc;
pub mod bench;
pub mod board;
pub mod hal;
pub mod link;
pub mod out;
pub mod pins;
pub mod pwm;
pub mod sampler;
pub mod terminal;

pub use board::{Board, BoardInfo};
