//! `score-gateway --port <link tty>`: one Score board on the Conductor bus.
//!
//! The domain comes from `--domain` or `CONDUCTOR_DOMAIN` (like every Conductor process), so a
//! launcher starts it like an executor: `CONDUCTOR_DOMAIN=<d> score-gateway --port /dev/score-link`.
//! Prints `ready <subsystem> <n> states` on stdout once the states exist; logs go to stderr;
//! SIGINT/SIGTERM end it cleanly.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use clap::Parser;
use conductor_bus::{Bus, Domain};
use score_gateway::{Gateway, Options};

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
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if !(cli.max_rate > 0.0 && cli.lazy_rate > 0.0) {
        eprintln!("score-gateway: --max-rate and --lazy-rate must be above 0");
        return ExitCode::from(2);
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
            return ExitCode::from(2);
        }
    };
    let node = format!("score-gateway/{}", std::process::id());
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
        ..Options::default()
    };
    let mut gw = Gateway::new(opts, bus, stop);
    match gw.run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("score-gateway: {e}");
            ExitCode::FAILURE
        }
    }
}
