//! # conductor-cli
//!
//! The `conductor` command line. Each subcommand is a module with a `run` function taking the
//! parsed arguments (see [`cli`]) and a [`Bus`] on the chosen domain:
//!
//! * inspection: [`list`], [`get_set`] (`get`, `set`), [`echo`] (with [`live_plot`] for
//!   `--plot`), [`top`];
//! * logging: [`record`] and [`replay`] over the MCAP layout in [`recording`], and [`plot`];
//! * the thesis' external interface: [`udp`] (`udp-gateway`);
//! * the live view in Foxglove: [`view`] (over `conductor-view`);
//! * other hosts: [`bridge`] (`bridge`, over `conductor_bridge`);
//! * the benchmark suite: [`bench`](mod@bench) (`bench`, over `conductor_benches::suite`).
//!
//! Long-running commands stop cleanly on Ctrl-C/SIGTERM (`conductor_bus::shutdown`).

pub mod bench;
pub mod bench_bridge;
pub mod bridge;
pub mod cli;
pub mod echo;
pub mod error;
pub mod get_set;
pub mod launch;
pub mod list;
pub mod live_plot;
pub mod netns;
pub mod out;
pub mod plot;
mod probe;
pub mod record;
pub mod recording;
pub mod replay;
pub mod select;
pub mod soak;
pub mod top;
pub mod udp;
pub mod view;

use clap::CommandFactory;
use conductor_bus::{Bus, Domain};

use cli::{Cli, Command};
pub use error::{CliError, Result};

/// The domain named by `--domain`, else `CONDUCTOR_DOMAIN`, else `default`.
pub fn domain(flag: Option<&str>) -> Result<Domain> {
    Ok(match flag {
        Some(d) => Domain::new(d)?,
        None => Domain::from_env()?,
    })
}

/// Long-running commands poll `conductor_bus::shutdown::requested()` and wind down cleanly on
/// Ctrl-C / SIGTERM (a recording is finalised, a gateway prints its counters).
fn install_stop() -> Result<()> {
    conductor_bus::shutdown::install().map_err(|source| CliError::Os {
        context: "installing the SIGINT/SIGTERM handler".into(),
        source,
    })
}

/// Runs one parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    let bus = |what: &str| -> Result<Bus> {
        let d = domain(cli.domain.as_deref())?;
        Ok(Bus::open(&d, &format!("conductor-cli/{what}"))?)
    };
    // Commands that run until Ctrl-C: the stop handler first, then the bus.
    let until_stopped = |what: &str| -> Result<Bus> {
        install_stop()?;
        bus(what)
    };
    match &cli.command {
        Command::Launch(_)
        | Command::Executor { .. }
        | Command::ScoreGateway { .. }
        | Command::Stress { .. }
        | Command::Soak { .. }
        | Command::PingPong => Err(CliError::Usage(
            "launch and the helper processes run from the conductor binary's main (they own \
             the process's signals)"
                .into(),
        )),
        Command::Bench(a) if a.bridge => bench::run_bridge(a),
        Command::Bench(a) if a.scaling => bench::run_scaling(a),
        Command::Bench(a) => bench::run(a),
        Command::BridgeBench { args } => bench_bridge::helper(args),
        Command::List(a) => list::run(&bus("list")?, a).map(drop),
        Command::Get(a) => get_set::get(&bus("get")?, a).map(drop),
        Command::Set(a) => get_set::set(&bus("set")?, a),
        Command::Echo(a) => echo::run(&until_stopped("echo")?, a).map(drop),
        Command::Top(a) => top::run(&until_stopped("top")?, a).map(drop),
        Command::Record(a) => record::run(&until_stopped("record")?, a).map(drop),
        Command::Replay(a) => replay::run(&until_stopped("replay")?, a).map(drop),
        Command::UdpGateway(a) => udp::run(&until_stopped("udp-gateway")?, a).map(drop),
        Command::View(a) => view::run(&until_stopped("view")?, a).map(drop),
        Command::Bridge(a) => {
            install_stop()?;
            bridge::run(cli.domain.as_deref(), a)
        }
        Command::Plot(a) => plot::run(a).map(drop),
        Command::Completions { shell } => {
            let mut cmd = Cli::command();
            clap_complete::generate(*shell, &mut cmd, "conductor", &mut std::io::stdout());
            Ok(())
        }
    }
}
