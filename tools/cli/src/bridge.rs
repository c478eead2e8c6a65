//! `conductor bridge`: the command-line face of `conductor_bridge`.

use conductor_bridge::config::{ExportConfig, ImportConfig};
use conductor_bridge::BridgeConfig;

use crate::cli::BridgeArgs;
use crate::error::{CliError, Result};

fn read(path: &std::path::Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|source| CliError::Os {
        context: format!("reading {}", path.display()),
        source,
    })
}

/// The configuration: the file's (or the manifest's `[bridge]`), plus the flags.
pub fn config(args: &BridgeArgs) -> Result<BridgeConfig> {
    let bad = |e: conductor_bridge::BridgeError| CliError::Usage(e.to_string());
    let mut c = if let Some(p) = &args.config {
        toml_config(&read(p)?).map_err(bad)?
    } else if let Some(p) = &args.manifest {
        BridgeConfig::from_manifest(&read(p)?)
            .map_err(bad)?
            .ok_or_else(|| CliError::Usage(format!("{} has no [bridge] table", p.display())))?
    } else {
        BridgeConfig::default()
    };
    if args.host.is_some() {
        c.host = args.host.clone();
    }
    if args.heartbeat_ms.is_some() {
        c.heartbeat_ms = args.heartbeat_ms;
    }
    if !args.cpus.is_empty() {
        c.cpus = Some(args.cpus.clone());
    }
    c.zenoh.listen.extend(args.listen.iter().cloned());
    c.zenoh.connect.extend(args.connect.iter().cloned());
    if args.zenoh_config.is_some() {
        c.zenoh.config_file = args.zenoh_config.clone();
    }
    if !args.export.is_empty() || !args.commands.is_empty() || args.rate_hz.is_some() {
        let e = c.export.get_or_insert(ExportConfig {
            states: Vec::new(),
            rate_hz: None,
            commands: Vec::new(),
            domain: None,
            spin_us: conductor_bridge::config::DEFAULT_SPIN_US,
        });
        e.states.extend(args.export.iter().cloned());
        e.commands.extend(args.commands.iter().cloned());
        if args.rate_hz.is_some() {
            e.rate_hz = args.rate_hz;
        }
    }
    if let Some(us) = args.spin_us {
        match c.export.as_mut() {
            Some(e) => e.spin_us = us,
            None => {
                return Err(CliError::Usage(
                    "--spin-us is the export thread's: give states to --export".into(),
                ))
            }
        }
    }
    for d in &args.import {
        c.import.push(ImportConfig {
            domain: d.clone(),
            states: vec!["*".into()],
            prefix: args.prefix.clone(),
        });
    }
    c.check().map_err(bad)?;
    Ok(c)
}

// A bridge.toml may be incomplete until the flags are added: checked after merging.
fn toml_config(text: &str) -> conductor_bridge::Result<BridgeConfig> {
    match BridgeConfig::from_toml(text) {
        Err(conductor_bridge::BridgeError::NothingToDo) => Ok(BridgeConfig::default()),
        other => other,
    }
}

/// Runs until Ctrl-C/SIGTERM; prints `ready bridge <host> …` once running and the counters at
/// the end.
pub fn run(domain: Option<&str>, args: &BridgeArgs) -> Result<()> {
    let cfg = config(args)?;
    let d = crate::domain(domain)?;
    // Zenoh and the bridge log through tracing; RUST_LOG overrides.
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "warn,conductor_bridge=info".into()),
        )
        .try_init();
    let counters = conductor_bridge::run(&cfg, &d, conductor_bus::shutdown::requested, |r| {
        println!(
            "ready bridge {}: exporting {} state(s), importing {} domain(s), domain {:?}",
            r.host,
            r.exported,
            r.imports,
            d.name()
        );
    })
    .map_err(|e| CliError::Usage(e.to_string()))?;
    eprintln!("bridge stopped: {}", counters.summary());
    if let Some(p) = conductor_bridge::profile::report() {
        eprint!("{p}");
    }
    Ok(())
}
