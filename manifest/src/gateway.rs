//! What a Score gateway process is started with, written once: the manifest's
//! `[gateways.<name>]` table fills [`ScoreGatewayArgs`], the launcher turns it into the gateway's
//! command line ([`ScoreGatewayArgs::to_args`]) and `score-gateway` parses that command line back
//! into the same struct (it derives `clap::Args` with this crate's `clap` feature).

use std::ffi::OsString;
use std::path::PathBuf;

use crate::GatewayDef;

/// A Score gateway's tunables; `None` leaves the gateway's own default.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct GatewayOptions {
    /// Highest publish rate per variable, Hz (default 1000).
    #[cfg_attr(feature = "clap", arg(long = "max-rate", value_name = "HZ"))]
    pub max_rate_hz: Option<f64>,
    /// Publish rate of bare expressions and constants, which have no rate of their own, Hz
    /// (default 10).
    #[cfg_attr(feature = "clap", arg(long = "lazy-rate", value_name = "HZ"))]
    pub lazy_rate_hz: Option<f64>,
    /// Replay the last configuration onto a board that comes back empty (`--no-restore`: do not).
    #[cfg_attr(
        feature = "clap",
        arg(long = "no-restore", action = clap::ArgAction::SetFalse)
    )]
    pub restore: bool,
    /// Milliseconds between reconnection attempts (default 200).
    #[cfg_attr(feature = "clap", arg(long = "retry-ms", value_name = "MS"))]
    pub retry_ms: Option<u64>,
    /// Command watchdog (ms): once a controller has set variables, no command for this long
    /// sets them to their safe value (0, clamped into their limits) and flags them. Off unless
    /// given.
    #[cfg_attr(
        feature = "clap",
        arg(long = "watchdog-ms", value_name = "MS", value_parser = clap::value_parser!(u64).range(1..=60_000))
    )]
    pub watchdog_ms: Option<u64>,
    /// SCHED_FIFO priority (1–99) of the gateway's link loop, which carries the command
    /// watchdog, with its memory locked; normal scheduling unless given.
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "PRIO", value_parser = clap::value_parser!(i32).range(1..=99))
    )]
    pub priority: Option<i32>,
}

impl Default for GatewayOptions {
    fn default() -> Self {
        Self {
            max_rate_hz: None,
            lazy_rate_hz: None,
            restore: true,
            retry_ms: None,
            watchdog_ms: None,
            priority: None,
        }
    }
}

impl GatewayOptions {
    /// The command-line flags for what is set (nothing for a default).
    pub fn to_args(&self) -> Vec<OsString> {
        let mut a: Vec<OsString> = Vec::new();
        if let Some(r) = self.max_rate_hz {
            a.extend(["--max-rate".into(), r.to_string().into()]);
        }
        if let Some(r) = self.lazy_rate_hz {
            a.extend(["--lazy-rate".into(), r.to_string().into()]);
        }
        if !self.restore {
            a.push("--no-restore".into());
        }
        if let Some(ms) = self.retry_ms {
            a.extend(["--retry-ms".into(), ms.to_string().into()]);
        }
        if let Some(ms) = self.watchdog_ms {
            a.extend(["--watchdog-ms".into(), ms.to_string().into()]);
        }
        if let Some(p) = self.priority {
            a.extend(["--priority".into(), p.to_string().into()]);
        }
        a
    }
}

/// The whole command line of `score-gateway` (after its program name).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct ScoreGatewayArgs {
    /// The board's link port (its second USB serial port, e.g. /dev/score-link or /dev/ttyACM1).
    #[cfg_attr(feature = "clap", arg(long))]
    pub port: PathBuf,
    /// Subsystem name (default: `score-<board name>`).
    #[cfg_attr(
        feature = "clap",
        arg(long, help = "Subsystem name (default: score-<board name>)")
    )]
    pub subsystem: Option<String>,
    /// Domain (default: $CONDUCTOR_DOMAIN, else "default").
    #[cfg_attr(feature = "clap", arg(long))]
    pub domain: Option<String>,
    /// The tunables.
    #[cfg_attr(feature = "clap", command(flatten))]
    pub options: GatewayOptions,
}

impl ScoreGatewayArgs {
    /// What the launcher starts the gateway of `def` with, in `domain`: it publishes subsystem
    /// `def.name`.
    pub fn for_gateway(def: &GatewayDef, domain: &str) -> Self {
        Self {
            port: def.port.clone(),
            subsystem: Some(def.name.clone()),
            domain: Some(domain.into()),
            options: def.options.clone(),
        }
    }

    /// The command line: `--port`, then `--subsystem` and `--domain` when given, then the
    /// options that are set.
    pub fn to_args(&self) -> Vec<OsString> {
        let mut a: Vec<OsString> = vec!["--port".into(), self.port.clone().into()];
        if let Some(s) = &self.subsystem {
            a.extend(["--subsystem".into(), s.into()]);
        }
        if let Some(d) = &self.domain {
            a.extend(["--domain".into(), d.into()]);
        }
        a.extend(self.options.to_args());
        a
    }
}
