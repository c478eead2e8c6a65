//! Shared helpers for the Conductor + Score benchmarks.
//!
//! Criterion measures means and confidence intervals; real-time work needs the tail. Every
//! latency benchmark therefore records raw per-sample figures and summarises them with
//! [`Percentiles`], which never filters outliers (the tail is the point).

pub mod percentiles;

pub use percentiles::Percentiles;
