#![doc = include_str!("../README.md")]

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
pub mod rt;
pub mod setpoint;
pub mod shutdown;
mod snapshot;
mod spectrum;
mod state;
mod subscriber;
mod tick;
mod variant;
mod vector;

pub use abi::{
    status, CommandFrame, ExecutorStats, Setpoint, StateSample, ABI_VERSION, MAX_SETPOINTS,
};
pub use bus::{qos, Bus};
pub use clock::monotonic_ns;
pub use controller::{CommandSender, Controller, SURFACE_HISTORY};
pub use discovery::StateInfo;
pub use domain::Domain;
pub use error::{BusError, IceoryxError, Result};
pub use filter::Filter;
pub use histogram::Histogram;
pub use history::{History, Interpolation};
pub use metadata::{ServiceKind, StateMeta};
pub use naming::StateRef;
pub use owner::{CommandReceiver, Flushed, StatePublisher, StateSpec, StatsPublisher};
pub use snapshot::{Snapshot, SnapshotReader, NOT_YET};
pub use spectrum::{spectrum, Spectrum};
pub use state::State;
pub use stats_sub::StatsSubscriber;
pub use subscriber::{StateSubscriber, DEFAULT_BUFFER};
pub use tick::TickWaiter;
pub use variant::{heap_fallbacks, prepare_thread, PooledRc, RtIpc};
mod stats_sub;
