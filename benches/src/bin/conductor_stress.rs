//! `conductor-stress`: the thesis' stress test (§3.1, Fig. 3.1), its external logger and the
//! command probe. See [`conductor_benches::stress::tool`].
//!
//! * `conductor-stress run --rate 1000 --seconds 5 [--probe]` launches 3 sine states at the
//!   rate, runs the logger (and the probe) in separate processes, and prints the executor's tick
//!   lateness, misses and CPU use, the end-to-end latency (sample request → external subscriber),
//!   the thesis' error sin(t_L) − value, and with `--probe` command → hardware write.
//! * `conductor-stress log --domain D --states sub/a,sub/b --seconds 2` is that logger.
//! * `conductor-stress probe --domain D --state stress/cmd` is the probe.

use std::ffi::OsString;
use std::process::ExitCode;

use conductor_benches::stress::tool::{main_with_args, ToolContext};
use conductor_executor::launcher::LaunchOptions;

fn main() -> ExitCode {
    // A floor's receiving process (`conductor_benches::pingpong::ROLE_ENV` set).
    if let Some(r) = conductor_benches::pingpong::child_from_env() {
        return match r {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("conductor-stress: {e}");
                ExitCode::FAILURE
            }
        };
    }
    let mut args: Vec<OsString> = std::env::args_os().collect();
    // The launcher runs this program as the executor (`conductor-stress executor …`), so the
    // stress test needs no other binary.
    if args.get(1).is_some_and(|a| a == EXECUTOR) {
        args.remove(1);
        return conductor_executor::process::main_with_args(args);
    }
    let me = std::env::current_exe().ok();
    let tool = me
        .clone()
        .map(|p| vec![p.into_os_string()])
        .unwrap_or_else(|| vec!["conductor-stress".into()]);
    let ctx = ToolContext {
        tool,
        launch: LaunchOptions {
            quiet: true,
            executor: me.unwrap_or_else(|| "conductor-stress".into()),
            executor_args: vec![EXECUTOR.into()],
            ..LaunchOptions::default()
        },
    };
    main_with_args(args, ctx)
}

/// The sub-command under which this program is the executor.
const EXECUTOR: &str = "executor";
