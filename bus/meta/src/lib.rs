//! # conductor-bus-meta
//!
//! Everything a client needs to know about a state besides its name ([`StateMeta`]), as a plain
//! value. `conductor-bus` carries it as iceoryx2 service attributes (its `metadata` module);
//! a recording (`conductor-cli-formats`) carries it as MCAP channel metadata. This crate has no
//! dependencies so that the recording reader's fuzz build stays free of iceoryx2.

use std::collections::BTreeMap;

/// Everything a client needs to know about a state besides its name.
#[derive(Debug, Clone, PartialEq)]
pub struct StateMeta {
    /// Index within the subsystem; setpoints address the state by it.
    pub index: u32,
    /// Units, e.g. `rad`.
    pub units: String,
    /// Whether the state accepts setpoints.
    pub writable: bool,
    /// Publish rate (Hz).
    pub rate_hz: f64,
    /// Lower limit for setpoints (setpoints below are clamped and flagged).
    pub min: f64,
    /// Upper limit for setpoints.
    pub max: f64,
    /// Owning device, for display.
    pub device: String,
}

impl Default for StateMeta {
    fn default() -> Self {
        Self {
            index: 0,
            units: String::new(),
            writable: false,
            rate_hz: 0.0,
            min: f64::NEG_INFINITY,
            max: f64::INFINITY,
            device: String::new(),
        }
    }
}

impl StateMeta {
    /// The metadata as strings, one entry per field plus `subsystem` and `state`: what a
    /// recording's channel and a live view's channel carry (numbers in Rust's shortest
    /// round-trip form, so `100.0` is `100` and `-inf` is `-inf`).
    pub fn strings(&self, subsystem: &str, state: &str) -> BTreeMap<String, String> {
        BTreeMap::from([
            ("subsystem".into(), subsystem.to_string()),
            ("state".into(), state.to_string()),
            ("index".into(), self.index.to_string()),
            ("units".into(), self.units.clone()),
            ("writable".into(), self.writable.to_string()),
            ("rate_hz".into(), self.rate_hz.to_string()),
            ("min".into(), self.min.to_string()),
            ("max".into(), self.max.to_string()),
            ("device".into(), self.device.clone()),
        ])
    }

    /// Clamps `v` to the limits; returns the value and whether it was clamped.
    pub fn clamp(&self, v: f64) -> (f64, bool) {
        let c = v.clamp(self.min, self.max);
        (c, c != v)
    }
}
