//! `conductor-soak`: the fault campaign on the simulated robots of deploy/ (see
//! `conductor_executor::soak`; also `conductor soak`). Prints one table, writes JSON with
//! `--json`, exits 1 when a check failed.
//!
//! ```text
//! conductor-soak --duration 1h --json soak.json
//! conductor-soak --duration 5m --faults controller-kill,controller-stop   # safe states only
//! ```

use std::process::ExitCode;

use conductor_executor::soak::cli::{main_with_args, Context};

fn main() -> ExitCode {
    let me = std::env::current_exe()
        .map(|p| p.display().to_string())
        .unwrap_or_else(|_| "conductor-soak".into());
    main_with_args(
        std::env::args_os(),
        Context {
            controller: vec![me.clone(), "controller".into()],
            board_controller: vec![me.clone(), "score-controller".into()],
            gateway: vec![me, "score-gateway".into()],
            executor: conductor_executor::launcher::default_executor(),
            executor_args: Vec::new(),
        },
    )
}
