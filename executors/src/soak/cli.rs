//! The command line of the fault campaign, shared by `conductor-soak` and `conductor soak`:
//! run a campaign (table on stdout, `--json`, exit 1 when a check failed), or be one of its
//! controller processes (the hidden `controller` sub-command the campaign starts).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Args, Parser, Subcommand};

use super::{controller, rig, score_campaign, BoardOptions, Fault, EVENTS};

#[derive(Parser)]
#[command(
    name = "conductor-soak",
    version,
    about = "Fault campaign on the simulated robots of deploy/: byte faults, unplugs, executor and controller kills, stalls and floods, checked from outside"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Option<Cmd>,
    #[command(flatten)]
    run: RunArgs,
}

#[derive(Args)]
struct RunArgs {
    /// How long: seconds, or with a unit (90s, 10m, 1h).
    #[arg(long, default_value = "60s", value_parser = duration)]
    duration: Duration,
    /// Seed of the faults and their schedule.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Probability that a byte on a wire is corrupted.
    #[arg(long, default_value_t = 0.005)]
    corrupt: f64,
    /// Probability that a byte on a wire is lost.
    #[arg(long, default_value_t = 0.005)]
    drop: f64,
    /// Command frames per second of each controller.
    #[arg(long, default_value_t = 1000.0)]
    rate_hz: f64,
    /// Write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// The workspace root holding deploy/ (default: found from here or from this program).
    #[arg(long)]
    root: Option<PathBuf>,
    /// The executor program (default: conductor-executor next to this program; for
    /// `conductor soak`, the conductor binary itself).
    #[arg(long)]
    executor: Option<PathBuf>,
    /// The faults injected one at a time, comma-separated: unplug, executor-kill,
    /// controller-kill, controller-stop, flood (default: all). Byte faults and bad setpoints
    /// are always on. `--faults controller-kill,controller-stop` is the focused safe-state
    /// campaign: many controller deaths a minute.
    #[arg(long, value_parser = faults, default_value = "all")]
    faults: FaultList,
    /// Run everything at normal scheduling: the executors without their manifests' real-time
    /// settings, the campaign's threads without SCHED_FIFO (then the load of the machine
    /// decides the timings).
    #[arg(long)]
    no_rt: bool,
    /// Probability that a byte on the Score board's USB link is corrupted (USB's own CRC makes
    /// this rare on a real link; at the legs' 0.5 % the gateway's configuration handling fails,
    /// see RELIABILITY.md).
    #[arg(long, default_value_t = 0.0001)]
    board_corrupt: f64,
    /// Probability that a byte on the Score board's USB link is lost.
    #[arg(long, default_value_t = 0.0001)]
    board_drop: f64,
    /// Leave the Score board out (the two legs only).
    #[arg(long)]
    no_board: bool,
}

/// The fault kinds of `--faults`.
#[derive(Debug, Clone)]
struct FaultList(Vec<Fault>);

fn faults(s: &str) -> Result<FaultList, String> {
    if s == "all" {
        return Ok(FaultList(EVENTS.to_vec()));
    }
    let mut v = Vec::new();
    for name in s.split(',').map(str::trim) {
        let f = match name {
            "unplug" => Fault::Unplug,
            "executor-kill" => Fault::ExecutorKill,
            "controller-kill" => Fault::ControllerKill,
            "controller-stop" => Fault::ControllerStall,
            "flood" => Fault::Flood,
            _ => {
                return Err(format!(
                    "unknown fault {name:?} (unplug, executor-kill, controller-kill, controller-stop, flood, or all)"
                ))
            }
        };
        if !v.contains(&f) {
            v.push(f);
        }
    }
    Ok(FaultList(v))
}

#[derive(Subcommand)]
enum Cmd {
    /// One controller process (what the campaign starts per robot).
    #[command(hide = true)]
    Controller {
        #[arg(long)]
        domain: String,
        #[arg(long)]
        subsystem: String,
        #[arg(long)]
        rate_hz: f64,
        #[arg(long)]
        seed: u64,
        /// `name:min:max`, repeated.
        #[arg(long = "joint", value_parser = rig::Joint::from_arg)]
        joints: Vec<rig::Joint>,
    },
    /// The Score board's controller process.
    #[command(hide = true)]
    ScoreController {
        #[arg(long)]
        domain: String,
        #[arg(long)]
        rate_hz: f64,
        #[arg(long)]
        seed: u64,
    },
}

fn duration(s: &str) -> Result<Duration, String> {
    let (num, unit) = match s.find(|c: char| c.is_ascii_alphabetic()) {
        Some(i) => s.split_at(i),
        None => (s, "s"),
    };
    let n: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("not a duration: {s:?}"))?;
    let scale = match unit {
        "s" => 1.0,
        "m" | "min" => 60.0,
        "h" => 3600.0,
        _ => return Err(format!("unknown unit {unit:?} (s, m, h)")),
    };
    if !(n.is_finite() && n > 0.0) {
        return Err(format!("not a positive duration: {s:?}"));
    }
    Ok(Duration::from_secs_f64(n * scale))
}

/// How the campaign starts its helper processes.
#[derive(Debug, Clone)]
pub struct Context {
    /// The program and arguments that run one controller (`… controller`).
    pub controller: Vec<String>,
    /// The executor program (unless `--executor` is given) and the arguments before its own.
    pub executor: PathBuf,
    /// See `executor`.
    pub executor_args: Vec<std::ffi::OsString>,
    /// The program and arguments that run the Score board's controller (`… score-controller`).
    pub board_controller: Vec<String>,
    /// The program and arguments that run the board's gateway (`… score-gateway`): the
    /// launcher appends the gateway's own arguments.
    pub gateway: Vec<String>,
}

/// `conductor-soak` / `conductor soak` with `argv` (its first item is the program's name).
pub fn main_with_args(
    argv: impl IntoIterator<Item = std::ffi::OsString>,
    ctx: Context,
) -> ExitCode {
    let argv: Vec<std::ffi::OsString> = argv.into_iter().collect();
    // The launcher runs the board's gateway as `<program> score-gateway <its arguments>`.
    if argv.get(1).is_some_and(|a| a == "score-gateway") {
        return score_gateway::main_with_args(argv[1..].iter().cloned());
    }
    let cli = match Cli::try_parse_from(argv) {
        Ok(c) => c,
        Err(e) => e.exit(),
    };
    if let Some(Cmd::ScoreController {
        domain,
        rate_hz,
        seed,
    }) = cli.cmd
    {
        let args = score_campaign::ControllerArgs {
            domain,
            rate_hz,
            seed,
        };
        return match score_campaign::run_controller(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("soak score controller: {e}");
                ExitCode::from(2)
            }
        };
    }
    if let Some(Cmd::Controller {
        domain,
        subsystem,
        rate_hz,
        seed,
        joints,
    }) = cli.cmd
    {
        let args = controller::ControllerArgs {
            domain,
            subsystem,
            joints,
            rate_hz,
            seed,
        };
        return match controller::run(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("soak controller: {e}");
                ExitCode::from(2)
            }
        };
    }
    let r = cli.run;
    let Some(root) = rig::find_root(r.root) else {
        eprintln!("conductor-soak: cannot find deploy/ (run it in the workspace, or give --root)");
        return ExitCode::from(2);
    };
    let (executor, executor_args) = match r.executor {
        Some(e) => (e, Vec::new()),
        None => (ctx.executor, ctx.executor_args),
    };
    let opts = super::Options {
        duration: r.duration,
        seed: r.seed,
        corrupt: r.corrupt,
        drop: r.drop,
        rate_hz: r.rate_hz,
        root,
        executor,
        executor_args,
        controller: ctx.controller,
        faults: r.faults.0,
        rt: !r.no_rt,
        board: (!r.no_board).then_some(BoardOptions {
            controller: ctx.board_controller,
            gateway: ctx.gateway,
            corrupt: r.board_corrupt,
            drop: r.board_drop,
        }),
    };
    let report = match super::run(&opts) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("conductor-soak: {e}");
            return ExitCode::from(2);
        }
    };
    print!("{}", report.table());
    if let Some(path) = r.json {
        let text = serde_json::to_string_pretty(&report).expect("a report serialises");
        if let Err(e) = std::fs::write(&path, text) {
            eprintln!("conductor-soak: {}: {e}", path.display());
            return ExitCode::from(2);
        }
    }
    if report.passed {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}
