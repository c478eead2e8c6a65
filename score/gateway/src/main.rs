//! `score-gateway --port <link tty>`: one Score board on the Conductor bus (see [`score_gateway::cli`]).

use std::process::ExitCode;

fn main() -> ExitCode {
    score_gateway::cli::main_with_args(std::env::args_os())
}
