//! Shared code of the Conductor + Score benchmarks, and `conductor bench`'s suite.
//!
//! * [`percentiles`] — order statistics over raw samples. Criterion measures means and
//!   confidence intervals; real-time work needs the tail, so every latency benchmark records raw
//!   per-sample figures and summarises them with [`Percentiles`], which never filters outliers
//!   (the tail is the point).
//! * [`pingpong`] — one-way latency between two processes over raw iceoryx2 (the IPC floor) and
//!   over the Conductor bus; used by the `bus_latency` criterion bench and by the suite.
//! * [`publish_cost`] — CPU per published state: a raw iceoryx2 publish of the state payload
//!   with the states' own service settings beside `StatePublisher::publish`, in one process.
//! * [`suite`] — the thesis' stress test at 50 Hz – 10 kHz beside cyclictest and the IPC floor,
//!   with a Markdown/JSON report and plots (`conductor bench`).
//! * [`stress`] — the thesis' stress test itself: sine states launched through
//!   `conductor_executor::launcher`, the external logger and the command probe (the
//!   `conductor-stress` program; its command line is the `cli` feature).

pub mod percentiles;
pub mod periodic;
pub mod pingpong;
pub mod publish_cost;
pub mod stress;
pub mod suite;

pub use percentiles::Percentiles;
