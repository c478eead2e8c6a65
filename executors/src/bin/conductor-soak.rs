//! `conductor-soak`: the fault campaign on the simulated robots of deploy/ (see
//! `conductor_executor::soak`). Prints one table, writes JSON with `--json`, exits 1 when a
//! check failed.
//!
//! ```text
//! conductor-soak --duration 1h --json soak.json
//! ```

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Args, Parser, Subcommand};
use conductor_executor::soak::{self, controller, rig, score_campaign};

#[derive(Parser)]
#[command(
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
    /// Write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// The workspace root holding deploy/ (default: found from here or from this program).
    #[arg(long)]
    root: Option<PathBuf>,
    /// The executor program (default: conductor-executor next to this program).
    #[arg(long)]
    executor: Option<PathBuf>,
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

fn main() -> ExitCode {
    // The launcher runs the board's gateway as `conductor-soak score-gateway <its arguments>`.
    if std::env::args().nth(1).as_deref() == Some("score-gateway") {
        return score_gateway::main_with_args(std::env::args().skip(1));
    }
    let cli = Cli::parse();
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
    let me = std::env::current_exe()
        .map(|p| p.display().to_string())
        .unwrap_or_else(|_| "conductor-soak".into());
    let opts = soak::Options {
        duration: r.duration,
        seed: r.seed,
        corrupt: r.corrupt,
        drop: r.drop,
        rate_hz: r.rate_hz,
        root,
        executor: r
            .executor
            .unwrap_or_else(conductor_executor::launcher::default_executor),
        controller: vec![me.clone(), "controller".into()],
        board: (!r.no_board).then(|| soak::BoardOptions {
            controller: vec![me.clone(), "score-controller".into()],
            gateway: vec![me, "score-gateway".into()],
            corrupt: r.board_corrupt,
            drop: r.board_drop,
        }),
    };
    let report = match soak::run(&opts) {
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
