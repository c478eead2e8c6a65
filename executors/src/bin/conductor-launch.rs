//! `conductor-launch MANIFEST`: the launcher as a standalone program (the `conductor` CLI's
//! `launch` sub-command calls the same library function).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use conductor_executor::launcher::{check_manifest, launch, launch_exit, LaunchOptions};

#[derive(Parser)]
#[command(
    version,
    about = "Launch one real-time executor per subsystem (and one process per gateway) of a Conductor manifest"
)]
struct Cli {
    /// The manifest (TOML).
    manifest: PathBuf,
    /// Bus domain (default: the manifest's `domain`, else $CONDUCTOR_DOMAIN, else "default").
    #[arg(long)]
    domain: Option<String>,
    /// Launch only these subsystems and gateways (repeatable).
    #[arg(long = "only")]
    only: Vec<String>,
    /// Run without real-time set-up (normal scheduling, no pinning, no memory lock).
    #[arg(long)]
    no_rt: bool,
    /// No live summary.
    #[arg(long, short)]
    quiet: bool,
    /// Seconds between summaries (default: 1 on a terminal, 10 otherwise).
    #[arg(long)]
    summary_secs: Option<f64>,
    /// The executor program (default: conductor-executor next to this program, else on PATH).
    #[arg(long)]
    executor: Option<PathBuf>,
    /// The Score gateway program (default: score-gateway next to this program, else on PATH).
    #[arg(long)]
    gateway: Option<PathBuf>,
    /// Only validate the manifest and exit.
    #[arg(long)]
    check: bool,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if cli.check {
        return check_manifest(&cli.manifest);
    }
    let mut opts = LaunchOptions {
        domain: cli.domain,
        only: cli.only,
        no_rt: cli.no_rt,
        quiet: cli.quiet,
        summary_interval: cli.summary_secs.map(Duration::from_secs_f64),
        ..LaunchOptions::default()
    };
    if let Some(e) = cli.executor {
        opts.executor = e;
    }
    if let Some(g) = cli.gateway {
        opts.gateway = g;
    }
    launch_exit(launch(&cli.manifest, opts))
}
