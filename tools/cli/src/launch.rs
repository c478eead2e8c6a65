//! `conductor launch`: the launcher from `conductor-executor`, with this same binary as the
//! executor program (a hidden `__executor` sub-command), as the Score gateway (a hidden
//! `__score-gateway` sub-command) and as the view (`view`), so `conductor` alone runs a robot,
//! its Score boards and its live view.

use std::ffi::OsString;
use std::process::ExitCode;
use std::time::Duration;

use conductor_executor::launcher::{check_manifest, launch, launch_exit, LaunchOptions};

use crate::cli::LaunchArgs;

/// Validates and launches; returns when every executor has stopped. Call it from `main` before
/// any other thread exists: the launcher takes SIGINT/SIGTERM over with a `sigwait` thread.
pub fn run(domain: Option<&str>, a: &LaunchArgs) -> ExitCode {
    if a.check {
        return check_manifest(&a.manifest);
    }
    let exe = match std::env::current_exe() {
        Ok(p) => p,
        Err(e) => {
            eprintln!("conductor: cannot find my own program to run executors: {e}");
            return ExitCode::FAILURE;
        }
    };
    let opts = LaunchOptions {
        executor: exe.clone(),
        executor_args: vec!["__executor".into()],
        gateway: exe.clone(),
        gateway_args: vec!["__score-gateway".into()],
        // A manifest's `[view]`: `conductor view` of this same binary.
        view: exe.clone(),
        view_args: vec!["view".into()],
        bridge: exe,
        bridge_args: vec!["bridge".into()],
        domain: domain.map(str::to_string),
        only: a.only.clone(),
        no_rt: a.no_rt,
        quiet: a.quiet,
        summary_interval: a.summary_secs.map(Duration::from_secs_f64),
        handle_signals: true,
        ..LaunchOptions::default()
    };
    launch_exit(launch(&a.manifest, opts))
}

/// Runs one executor with its own arguments (what `launch` spawns).
pub fn executor(args: &[OsString]) -> ExitCode {
    let argv = std::iter::once(OsString::from("conductor __executor")).chain(args.iter().cloned());
    conductor_executor::process::main_with_args(argv)
}

/// Runs one Score gateway with its own arguments (what `launch` spawns per Score gateway).
pub fn score_gateway(args: &[OsString]) -> ExitCode {
    let argv =
        std::iter::once(OsString::from("conductor __score-gateway")).chain(args.iter().cloned());
    score_gateway::main_with_args(argv)
}
