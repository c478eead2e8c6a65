//! # conductor-executor
//!
//! The manifest, the real-time executor (one process per subsystem) and the launcher.
#![warn(missing_docs)]

pub mod manifest;
