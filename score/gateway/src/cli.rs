//! The `score-gateway --port <link tty>` program: one Score board on the Conductor bus.
//!
//! The domain comes from `--domain` or `CONDUCTOR_DOMAIN` (like every Conductor process), so a
//! launcher starts it like an executor: `score-gateway --port /dev/score-link --subsystem board
//! --domain <d>` (what `conductor launch` does for a `[gateways.<name>]` table). Prints
//! `ready <subsystem> <n> states` on stdout once the states exist; logs go to stderr;
//! SIGINT/SIGTERM end it cleanly (exit 0); exit 2 on bad arguments, 1 on a fatal error (a
//! missing board is not one: the gateway waits for it).

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use clap::Parser;
use conductor_bus::{Bus, Domain};

use crate::{Gateway, Options};

#[derive(Parser, Debug)]
#[command(
    name = "score-gateway",
    version,
    about = "A Score board's variables as Conductor states"
)]
struct Cli {
    /// The board's link port (its second USB serial port, e.g. /dev/score-link or /dev/ttyACM1).
    #[arg(long)]
    port: PathBuf,
    /// Subsystem name (default: score-<board name>).
    #[arg(long)]
    subsystem: Option<String>,
    /// Domain (default: $CONDUCTOR_DOMAIN, else "default").
    #[arg(long)]
    domain: Option<String>,
    /// Highest publish rate per variable, Hz.
    #[arg(long, default_value_t = 1000.0)]
    max_rate: f64,
    /// Publish rate of bare expressions and constants, Hz.
    #[arg(long, default_value_t = 10.0)]
    lazy_rate: f64,
    /// Do not replay the last configuration onto a board that comes back empty.
    #[arg(long)]
    no_restore: bool,
    /// Milliseconds between reconnection attempts.
    #[arg(long, default_value_t = 200)]
    retry_ms: u64,
    /// Command watchdog (ms): once a controller has set variables, no command for this long
    /// sets them to their safe value (0, clamped into their limits) and flags them. Off unless
    /// given.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=60_000))]
    watchdog_ms: Option<u64>,
}

/// Bad arguments (the launcher does not restart a gateway that exits with it).
pub const EXIT_USAGE: u8 = 2;

/// The node a gateway runs as: `gateway/<subsystem>` when the subsystem is given (a launcher
/// looks for it to tell that the gateway already runs), else `score-gateway/<pid>`.
pub fn node_name(subsystem: Option<&str>) -> String {
    match subsystem {
        Some(s) => format!("gateway/{s}"),
        None => format!("score-gateway/{}", std::process::id()),
    }
}

/// The whole program: parses `args` (the first is the program's name), runs the gateway until
/// SIGINT/SIGTERM and returns the exit status. Another program can run it as a sub-command
/// (`conductor __score-gateway …`); call it before starting other threads, in a process of its
/// own (it installs SIGINT/SIGTERM handlers).
pub fn main_with_args<I, T>(args: I) -> ExitCode
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let cli = match Cli::try_parse_from(args) {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(EXIT_USAGE)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    if !(cli.max_rate > 0.0 && cli.lazy_rate > 0.0) {
        eprintln!("score-gateway: --max-rate and --lazy-rate must be above 0");
        return ExitCode::from(EXIT_USAGE);
    }
    let domain = match cli
        .domain
        .as_deref()
        .map(Domain::new)
        .unwrap_or_else(Domain::from_env)
    {
        Ok(d) => d,
        Err(e) => {
            eprintln!("score-gateway: {e}");
            return ExitCode::from(EXIT_USAGE);
        }
    };
    let node = node_name(cli.subsystem.as_deref());
    let bus = match Bus::open(&domain, &node) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("score-gateway: {e}");
            return ExitCode::FAILURE;
        }
    };
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        if let Err(e) = signal_hook::flag::register(sig, stop.clone()) {
            eprintln!("score-gateway: cannot handle signal {sig}: {e}");
        }
    }
    let opts = Options {
        port: cli.port,
        subsystem: cli.subsystem,
        max_rate_hz: cli.max_rate,
        lazy_rate_hz: cli.lazy_rate,
        restore: !cli.no_restore,
        retry: Duration::from_millis(cli.retry_ms.max(10)),
        watchdog: cli.watchdog_ms.map(Duration::from_millis),
        ..Options::default()
    };
    let mut gw = Gateway::new(opts, bus, stop);
    let ended = gw.run();
    let st = gw.stats;
    eprintln!(
        "score-gateway: connects={} published={} commands={} rejected={} restores={} \
         watchdog_trips={}",
        st.connects, st.published, st.commands, st.rejected, st.restores, st.watchdog_trips
    );
    match ended {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("score-gateway: {e}");
            ExitCode::FAILURE
        }
    }
}
