//! `conductor soak`: the fault campaign of `conductor_executor::soak` (also the
//! `conductor-soak` program), with this program as its executor (`conductor __executor`) and
//! its controllers (`conductor soak controller`).

use std::ffi::OsString;
use std::process::ExitCode;

use conductor_executor::soak::cli::{main_with_args, Context};

/// Runs the campaign with `args` (everything after `conductor soak`).
pub fn run(args: &[OsString]) -> ExitCode {
    let me = match std::env::current_exe() {
        Ok(p) => p,
        Err(e) => {
            eprintln!("conductor soak: where is this program? {e}");
            return ExitCode::FAILURE;
        }
    };
    let argv = std::iter::once(OsString::from("conductor soak")).chain(args.iter().cloned());
    main_with_args(
        argv,
        Context {
            controller: vec![me.display().to_string(), "soak".into(), "controller".into()],
            board_controller: vec![
                me.display().to_string(),
                "soak".into(),
                "score-controller".into(),
            ],
            gateway: vec![
                me.display().to_string(),
                "soak".into(),
                "score-gateway".into(),
            ],
            executor: me,
            executor_args: vec!["__executor".into()],
        },
    )
}
