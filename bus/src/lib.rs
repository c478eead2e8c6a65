//! # conductor-bus
//!
//! The Conductor state bus: every physical quantity of a robot is a named **State**, published as
//! an iceoryx2 zero-copy shared-memory service `conductor/<subsystem>/<state>`.
//!
//! * Owners (executors) use [`StatePublisher`], [`CommandReceiver`] and [`StatsPublisher`].
//! * Clients use [`State`] (history, interpolation, derivative, integral, filters, spectrum),
//!   [`StateSubscriber`] (raw samples with loss accounting), [`Controller`] (the thesis'
//!   `add_ctrl`/`send_ctrl`/`check_ctrl`/`get_surface`), [`TickWaiter`] and discovery
//!   ([`Bus::list_states`]).
//! * Everything lives in a [`Domain`] (`CONDUCTOR_DOMAIN`), so robots and test runs never mix.
//!
//! The payload layouts are the ABI in [`abi`], documented byte by byte in `bus/ABI.md`.
//!
//! ```no_run
//! use conductor_bus::{Bus, Controller, TickWaiter};
//! use std::time::Duration;
//!
//! let bus = Bus::from_env("my-controller")?;
//! let mut ctl = Controller::new(&bus);
//! let mut tick = TickWaiter::new(&bus, "leg")?;
//! loop {
//!     tick.wait(Duration::from_millis(100))?;
//!     let theta = ctl.state("leg/knee")?;
//!     let u = -10.0 * theta.value()? - 1.0 * theta.derivative()?;
//!     ctl.add_ctrl("leg/knee_torque", u)?;
//!     ctl.send_ctrl()?;
//! }
//! # Ok::<(), conductor_bus::BusError>(())
//! ```

#![warn(missing_docs)]

pub mod abi;
mod bus;
pub mod clock;
mod controller;
mod discovery;
pub mod domain;
mod error;
mod filter;
pub mod histogram;
mod history;
pub mod metadata;
pub mod naming;
mod owner;
mod spectrum;
mod state;
mod subscriber;
mod tick;
mod variant;
mod vector;

pub use abi::{
    status, CommandFrame, ExecutorStats, Setpoint, StateSample, ABI_VERSION, MAX_SETPOINTS,
};
pub use bus::Bus;
pub use clock::monotonic_ns;
pub use controller::{Controller, SURFACE_HISTORY};
pub use discovery::StateInfo;
pub use domain::Domain;
pub use error::{BusError, Result};
pub use filter::Filter;
pub use histogram::Histogram;
pub use history::{History, Interpolation};
pub use metadata::{ServiceKind, StateMeta};
pub use naming::StateRef;
pub use owner::{CommandReceiver, StatePublisher, StateSpec, StatsPublisher};
pub use spectrum::{spectrum, Spectrum};
pub use state::State;
pub use stats_sub::StatsSubscriber;
pub use subscriber::{StateSubscriber, DEFAULT_BUFFER};
pub use tick::TickWaiter;
pub use variant::{heap_fallbacks, prepare_thread, PooledRc, RtIpc};
mod stats_sub;
