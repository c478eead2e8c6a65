//! `conductor`: see `conductor --help` and tools/cli/README.md.

use std::process::ExitCode;

use clap::Parser;
use conductor_cli::cli::{Cli, Command};

fn main() -> ExitCode {
    let cli = Cli::parse();
    // These take over signal handling and must run before any other thread starts.
    match &cli.command {
        Command::Launch(a) => return conductor_cli::launch::run(cli.domain.as_deref(), a),
        Command::Executor { args } => return conductor_cli::launch::executor(args),
        Command::ScoreGateway { args } => return conductor_cli::launch::score_gateway(args),
        Command::Stress { args } => return conductor_cli::bench::stress_tool(args),
        Command::PingPong => return conductor_cli::bench::pingpong_child(),
        Command::Soak { args } => return conductor_cli::soak::run(args),
        _ => {}
    }
    match conductor_cli::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("conductor: {e}");
            ExitCode::FAILURE
        }
    }
}
