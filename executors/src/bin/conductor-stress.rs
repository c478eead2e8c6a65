//! `conductor-stress`: the thesis' stress test (§3.1, Fig. 3.1), its external logger and the
//! command probe. See [`conductor_executor::stress::tool`].
//!
//! * `conductor-stress run --rate 1000 --seconds 5 [--probe]` launches 3 sine states at the
//!   rate, runs the logger (and the probe) in separate processes, and prints the executor's tick
//!   lateness, misses and CPU use, the end-to-end latency (sample request → external subscriber),
//!   the thesis' error sin(t_L) − value, and with `--probe` command → hardware write.
//! * `conductor-stress log --domain D --states sub/a,sub/b --seconds 2` is that logger.
//! * `conductor-stress probe --domain D --state stress/cmd` is the probe.

use std::process::ExitCode;

use conductor_executor::launcher::LaunchOptions;
use conductor_executor::stress::tool::{main_with_args, ToolContext};

fn main() -> ExitCode {
    let tool = std::env::current_exe()
        .map(|p| vec![p.into_os_string()])
        .unwrap_or_else(|_| vec!["conductor-stress".into()]);
    let ctx = ToolContext {
        tool,
        launch: LaunchOptions {
            quiet: true,
            ..LaunchOptions::default()
        },
    };
    main_with_args(std::env::args_os(), ctx)
}
