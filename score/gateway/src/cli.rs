//! The `score-gateway --port <link tty>` program: one Score board on the Conductor bus.
//!
//! The domain comes from `--domain` or `CONDUCTOR_DOMAIN` (like every Conductor process), so a
//! launcher starts it like an executor: `score-gateway --port /dev/score-link --subsystem board
//! --domain <d>` (what `conductor launch` does for a `[gateways.<name>]` table). Prints
//! `ready <subsystem> <n> states` on stdout once the states exist; logs go to stderr;
//! SIGINT/SIGTERM end it cleanly (exit 0); exit 2 on bad arguments, 1 on a fatal error (a
//! missing board is not one: the gateway waits for it).

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use clap::Parser;
use conductor_bus::rt::{self, RtRequest};
use conductor_bus::{Bus, Domain};
use conductor_manifest::{GatewayOptions, ScoreGatewayArgs};

use crate::{Gateway, Options};

#[derive(Parser, Debug)]
#[command(
    name = "score-gateway",
    version,
    about = "A Score board's variables as Conductor states"
)]
struct Cli {
    /// Everything the launcher passes (the same struct it builds the command line from).
    #[command(flatten)]
    args: ScoreGatewayArgs,
}

/// The gateway's [`Options`] from its command line: what is not given keeps its default.
pub fn options(port: PathBuf, subsystem: Option<String>, o: &GatewayOptions) -> Options {
    let d = Options::default();
    Options {
        port,
        subsystem,
        max_rate_hz: o.max_rate_hz.unwrap_or(d.max_rate_hz),
        lazy_rate_hz: o.lazy_rate_hz.unwrap_or(d.lazy_rate_hz),
        restore: o.restore,
        retry: o
            .retry_ms
            .map_or(d.retry, |ms| Duration::from_millis(ms.max(10))),
        watchdog: o.watchdog_ms.map(Duration::from_millis),
        ..d
    }
}

/// Bad arguments (the launcher does not restart a gateway that exits with it).
pub const EXIT_USAGE: u8 = 2;

/// The node a gateway runs as: `gateway/<subsystem>` when the subsystem is given (a launcher
/// looks for it to tell that the gateway already runs), else `score-gateway/<pid>`.
pub fn node_name(subsystem: Option<&str>) -> String {
    match subsystem {
        Some(s) => format!("gateway/{s}"),
        None => format!("score-gateway/{}", std::process::id()),
    }
}

/// The whole program: parses `args` (the first is the program's name), runs the gateway until
/// SIGINT/SIGTERM and returns the exit status. Another program can run it as a sub-command
/// (`conductor __score-gateway …`); call it before starting other threads, in a process of its
/// own (it installs SIGINT/SIGTERM handlers).
pub fn main_with_args<I, T>(args: I) -> ExitCode
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let cli = match Cli::try_parse_from(args) {
        Ok(c) => c.args,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(EXIT_USAGE)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    let opts = options(cli.port, cli.subsystem.clone(), &cli.options);
    if !(opts.max_rate_hz > 0.0 && opts.lazy_rate_hz > 0.0) {
        eprintln!("score-gateway: --max-rate and --lazy-rate must be above 0");
        return ExitCode::from(EXIT_USAGE);
    }
    let domain = match cli
        .domain
        .as_deref()
        .map(Domain::new)
        .unwrap_or_else(Domain::from_env)
    {
        Ok(d) => d,
        Err(e) => {
            eprintln!("score-gateway: {e}");
            return ExitCode::from(EXIT_USAGE);
        }
    };
    let node = node_name(opts.subsystem.as_deref());
    let bus = match Bus::open(&domain, &node) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("score-gateway: {e}");
            return ExitCode::FAILURE;
        }
    };
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        if let Err(e) = signal_hook::flag::register(sig, stop.clone()) {
            eprintln!("score-gateway: cannot handle signal {sig}: {e}");
        }
    }
    let mut gw = Gateway::new(opts, bus, stop);
    if let Some(priority) = cli.options.priority {
        // This thread runs the link loop, and with it the command watchdog.
        let st = rt::setup(RtRequest {
            priority: Some(priority),
            cpu: None,
            lock_memory: true,
        });
        for p in &st.problems {
            eprintln!("score-gateway: warning: running without full real-time guarantees: {p}");
        }
        eprintln!("score-gateway: link loop: {}", st.summary());
    }
    let ended = gw.run();
    let st = gw.stats;
    eprintln!(
        "score-gateway: connects={} published={} commands={} rejected={} restores={} \
         watchdog_trips={}",
        st.connects, st.published, st.commands, st.rejected, st.restores, st.watchdog_trips
    );
    match ended {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("score-gateway: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use conductor_manifest::{GatewayDef, GatewayKind};

    fn parse(args: &[OsString]) -> ScoreGatewayArgs {
        let argv = std::iter::once(OsString::from("score-gateway")).chain(args.iter().cloned());
        Cli::try_parse_from(argv).unwrap().args
    }

    /// What the launcher writes from a manifest's gateway is what the gateway reads back.
    #[test]
    fn the_launchers_command_line_reads_back_as_the_manifests_options() {
        let mut def = GatewayDef {
            name: "board".into(),
            kind: GatewayKind::Score,
            port: "/dev/score-link".into(),
            options: GatewayOptions::default(),
        };
        for options in [
            GatewayOptions::default(),
            GatewayOptions {
                max_rate_hz: Some(500.0),
                lazy_rate_hz: Some(2.5),
                restore: false,
                retry_ms: Some(50),
                watchdog_ms: Some(250),
                priority: Some(70),
            },
        ] {
            def.options = options;
            let args = ScoreGatewayArgs::for_gateway(&def, "d1");
            assert_eq!(parse(&args.to_args()), args);
        }
        let o = options("/dev/x".into(), None, &GatewayOptions::default());
        let d = Options::default();
        assert_eq!(
            (
                o.max_rate_hz,
                o.lazy_rate_hz,
                o.restore,
                o.retry,
                o.watchdog
            ),
            (d.max_rate_hz, d.lazy_rate_hz, true, d.retry, None)
        );
    }
}
