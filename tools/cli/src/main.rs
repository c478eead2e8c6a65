//! `conductor`: see `conductor --help` and tools/cli/README.md.

use std::process::ExitCode;

use clap::Parser;
use conductor_cli::cli::Cli;

fn main() -> ExitCode {
    match conductor_cli::run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("conductor: {e}");
            ExitCode::FAILURE
        }
    }
}
