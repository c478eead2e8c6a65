//! `conductor bench`: the benchmark suite of `conductor_benches::suite`, with this same binary
//! as every helper process — the executor (`__executor`), the stress logger and command probe
//! (`__stress`) and the ping-pong child (`__pingpong`) — so `conductor` alone runs it.

use std::ffi::OsString;
use std::process::ExitCode;

use conductor_benches::pingpong;
use conductor_benches::stress::tool::{self, ToolContext};
use conductor_benches::suite::{self, scaling, CyclicChoice, Helpers};
use conductor_executor::launcher::LaunchOptions;

use crate::cli::BenchArgs;
use crate::error::{CliError, Result};

fn me() -> Result<OsString> {
    std::env::current_exe()
        .map(|p| p.into_os_string())
        .map_err(|e| CliError::os("finding my own program to run the helpers", e))
}

fn executor_launch(me: &OsString) -> LaunchOptions {
    LaunchOptions {
        executor: me.into(),
        executor_args: vec!["__executor".into()],
        quiet: true,
        handle_signals: false,
        ..LaunchOptions::default()
    }
}

/// This binary as every helper process.
fn helpers() -> Result<Helpers> {
    let me = me()?;
    Ok(Helpers {
        launch: executor_launch(&me),
        stress_tool: vec![me.clone(), "__stress".into()],
        pingpong_child: vec![me, "__pingpong".into()],
    })
}

/// `conductor bench --scaling`: the scaling curves; prints the Markdown report and where the
/// files are. `--states`, `--seconds`, `--cpu`, `--priority` and `--rates` (its first rate)
/// change the plan.
pub fn run_scaling(a: &BenchArgs) -> Result<()> {
    let mut cfg = suite::Config::new(a.quick, helpers()?);
    if !a.readers.is_empty() {
        cfg.readers = a.readers.clone();
    }
    let mut plan = scaling::Plan::new(a.quick);
    if let Some(&r) = a.rates.first() {
        plan.rate_hz = r;
    }
    if !a.states.is_empty() {
        plan.states = a.states.clone();
    }
    cfg.seconds = a.seconds.unwrap_or(if a.quick {
        scaling::QUICK_SECONDS
    } else {
        scaling::FULL_SECONDS
    });
    if let Some(c) = a.cpu {
        cfg.cpu = c;
    }
    cfg.priority = a.priority;
    cfg.out = a.out.clone();
    cfg.progress = !a.no_progress;
    cfg.command = std::env::args().collect::<Vec<_>>().join(" ");
    let report =
        scaling::run(&cfg, &plan).map_err(|e| CliError::Usage(format!("bench --scaling: {e}")))?;
    wrote(&report.markdown(), &cfg.out, report.plots.len());
    Ok(())
}

/// Prints a run's Markdown report and where its files are.
fn wrote(markdown: &str, out: &std::path::Path, plots: usize) {
    println!("{markdown}");
    eprintln!(
        "bench: wrote {0}/report.md, {0}/report.json and {plots} plots",
        out.display()
    );
}

/// Runs the suite; prints the Markdown report and where the files are.
pub fn run(a: &BenchArgs) -> Result<()> {
    let mut cfg = suite::Config::new(a.quick, helpers()?);
    if !a.readers.is_empty() {
        cfg.readers = a.readers.clone();
    }
    if !a.rates.is_empty() {
        cfg.rates_hz = a.rates.clone();
    }
    if !a.states.is_empty() {
        cfg.states = a.states.clone();
    }
    if let Some(s) = a.seconds {
        cfg.seconds = s;
    }
    if let Some(c) = a.cpu {
        cfg.cpu = c;
    }
    if let Some(n) = a.ipc_samples {
        cfg.ipc_samples = n;
    }
    cfg.priority = a.priority;
    cfg.out = a.out.clone();
    cfg.progress = !a.no_progress;
    cfg.cyclictest = match (a.no_cyclictest, a.no_install) {
        (true, _) => CyclicChoice::Skip,
        (false, true) => CyclicChoice::IfInstalled,
        (false, false) => CyclicChoice::Install,
    };
    cfg.command = std::env::args().collect::<Vec<_>>().join(" ");
    let report = suite::run(&cfg).map_err(|e| CliError::Usage(format!("bench: {e}")))?;
    wrote(&report.markdown(), &cfg.out, report.plots.len());
    Ok(())
}

/// `conductor bench --bridge`: only the bridge benchmark; prints Markdown, writes
/// `<out>/bridge.md` and `<out>/bridge.json`.
pub fn run_bridge(a: &BenchArgs) -> Result<()> {
    let o = crate::bench_bridge::Options {
        states: a.bridge_states.max(1),
        rate_hz: a.bridge_rate,
        seconds: a.seconds.unwrap_or(if a.quick { 3.0 } else { 10.0 }),
        latency_samples: a
            .bridge_samples
            .unwrap_or(if a.quick { 1000 } else { 5000 }),
        latency_hz: 1000.0,
        loopback: a.bridge_loopback,
        spin_us: a.bridge_spin_us,
        unpinned: a.bridge_unpinned,
    };
    let r = crate::bench_bridge::run(&o)?;
    let md = r.markdown();
    println!("{md}");
    std::fs::create_dir_all(&a.out)
        .map_err(|e| CliError::os("creating the output directory", e))?;
    std::fs::write(a.out.join("bridge.md"), &md)
        .and_then(|()| {
            std::fs::write(
                a.out.join("bridge.json"),
                serde_json::to_string_pretty(&r).expect("serialisable"),
            )
        })
        .map_err(|e| CliError::os("writing the bridge report", e))?;
    eprintln!(
        "bench: wrote {0}/bridge.md and {0}/bridge.json",
        a.out.display()
    );
    Ok(())
}

/// `conductor __stress ...`: the stress test's logger and probe processes.
pub fn stress_tool(args: &[OsString]) -> ExitCode {
    let me = match me() {
        Ok(m) => m,
        Err(e) => {
            eprintln!("conductor: {e}");
            return ExitCode::FAILURE;
        }
    };
    let ctx = ToolContext {
        tool: vec![me.clone(), "__stress".into()],
        launch: executor_launch(&me),
    };
    let argv = std::iter::once(OsString::from("conductor __stress")).chain(args.iter().cloned());
    tool::main_with_args(argv, ctx)
}

/// `conductor __pingpong`: the receiving side of the IPC ping-pong.
pub fn pingpong_child() -> ExitCode {
    match pingpong::child_from_env() {
        Some(Ok(())) => ExitCode::SUCCESS,
        Some(Err(e)) => {
            eprintln!("conductor __pingpong: {e}");
            ExitCode::FAILURE
        }
        None => {
            eprintln!(
                "conductor __pingpong: {} is not set (this is a helper of `conductor bench`)",
                pingpong::ROLE_ENV
            );
            ExitCode::from(2)
        }
    }
}
