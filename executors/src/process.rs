//! The executor process: `conductor-executor --manifest M --subsystem S`.
//!
//! It loads and validates the manifest, joins the bus domain, builds the subsystem on its
//! real-time thread (the main thread), sets up real time, prints `READY` on stdout, runs the
//! deadline loop until SIGINT/SIGTERM, then puts every device in its safe state and exits 0.
//!
//! Before `READY` every device is brought up (probe, model check, configuration, enable from
//! where it is); a device that cannot be (missing, wrong model, configuration refused) is an
//! error naming it, unless the manifest marks it `optional`. On a stop every safe action is
//! confirmed on the wire before the executor says so.
//!
//! Exit status: 0 orderly stop (every safe action confirmed); 1 a runtime failure (worth a
//! restart); 2 a configuration error (bad arguments or manifest, unknown subsystem, the
//! subsystem already runs in the domain, a device that is not as the manifest says: restarting
//! cannot help); 3 real time required but not permitted; 4 a stop whose safe actions could not
//! all be confirmed (each device named on stderr).

#[cfg(feature = "cli")]
use std::ffi::OsString;
use std::io::Write as _;
use std::path::PathBuf;
#[cfg(feature = "cli")]
use std::process::ExitCode;

#[cfg(feature = "cli")]
use clap::Parser;
use conductor_bus::{prepare_thread, Bus, Domain};

use crate::executor::{run_from, Executor, StopReport};
use crate::rt::{self, RtRequest};
#[cfg(feature = "cli")]
use crate::signals;
use crate::signals::Stop;
use conductor_manifest::Manifest;

/// Exit status of an orderly stop.
pub const EXIT_OK: u8 = 0;
/// Exit status of a runtime failure.
pub const EXIT_FAILURE: u8 = 1;
/// Exit status of a configuration error.
pub const EXIT_CONFIG: u8 = 2;
/// Exit status when real time is required but not permitted.
pub const EXIT_NO_RT: u8 = 3;
/// Exit status of a stop whose safe actions could not all be confirmed on the wire.
pub const EXIT_UNSAFE: u8 = 4;

/// Time allowed for every device to be brought up before `READY` (ns).
pub const BRING_UP_NS: u64 = 5_000_000_000;
/// Time allowed for the safe actions of a stop to be confirmed (ns).
pub const STOP_CONFIRM_NS: u64 = 1_000_000_000;

/// The line printed on stdout once the executor's services exist and its loop starts.
pub const READY: &str = "READY";

/// Command line of the executor.
#[derive(Debug)]
#[cfg_attr(feature = "cli", derive(Parser))]
#[cfg_attr(
    feature = "cli",
    command(
        name = "conductor-executor",
        version,
        about = "Runs one subsystem of a Conductor manifest in real time"
    )
)]
pub struct ExecutorArgs {
    /// The manifest (TOML).
    #[cfg_attr(feature = "cli", arg(long))]
    pub manifest: PathBuf,
    /// The subsystem to run.
    #[cfg_attr(feature = "cli", arg(long))]
    pub subsystem: String,
    /// Bus domain (default: the manifest's `domain`, else $CONDUCTOR_DOMAIN, else "default").
    #[cfg_attr(feature = "cli", arg(long))]
    pub domain: Option<String>,
    /// Do not attempt real-time set-up (normal scheduling, no pinning, no memory lock).
    #[cfg_attr(feature = "cli", arg(long, conflicts_with = "require_rt"))]
    pub no_rt: bool,
    /// Refuse to run without real time, whatever the manifest says.
    #[cfg_attr(feature = "cli", arg(long))]
    pub require_rt: bool,
}

/// The domain to use: explicit choice, else the manifest's, else `CONDUCTOR_DOMAIN`, else the
/// default.
pub fn resolve_domain(explicit: Option<&str>, manifest: &Manifest) -> Result<Domain, String> {
    let d = match (explicit, manifest.domain.as_deref()) {
        (Some(d), _) | (None, Some(d)) => Domain::new(d),
        (None, None) => Domain::from_env(),
    };
    d.map_err(|e| e.to_string())
}

/// Runs the executor with `args` (program name first) and returns its exit status.
#[cfg(feature = "cli")]
pub fn main_with_args(args: impl IntoIterator<Item = OsString>) -> ExitCode {
    let args = match ExecutorArgs::try_parse_from(args) {
        Ok(a) => a,
        Err(e) => {
            let _ = e.print();
            return ExitCode::from(if e.use_stderr() { EXIT_CONFIG } else { 0 });
        }
    };
    let stop = Stop::new();
    if let Err(e) = signals::install(&stop) {
        note!("conductor-executor: cannot set up signal handling: {e}");
        return ExitCode::from(EXIT_FAILURE);
    }
    ExitCode::from(execute(&args, &stop))
}

/// Runs the subsystem `args` names until `stop` is requested (or it fails) and returns its exit
/// status (one of the `EXIT_*` codes). [`main_with_args`] is this after parsing the command line
/// and taking SIGINT/SIGTERM.
pub fn execute(args: &ExecutorArgs, stop: &Stop) -> u8 {
    let tag = format!("conductor-executor[{}]", args.subsystem);
    let manifest = match Manifest::load(&args.manifest) {
        Ok(m) => m,
        Err(e) => {
            note!("{tag}: {e}");
            return EXIT_CONFIG;
        }
    };
    let Some(sub) = manifest.subsystem(&args.subsystem) else {
        let names: Vec<&str> = manifest
            .subsystems
            .iter()
            .map(|s| s.name.as_str())
            .collect();
        note!(
            "{tag}: the manifest has no subsystem {:?}; expected one of: {}",
            args.subsystem,
            names.join(", ")
        );
        return EXIT_CONFIG;
    };
    let domain = match resolve_domain(args.domain.as_deref(), &manifest) {
        Ok(d) => d,
        Err(e) => {
            note!("{tag}: {e}");
            return EXIT_CONFIG;
        }
    };
    let require_rt = args.require_rt || sub.require_rt;
    if require_rt && args.no_rt {
        note!(
            "{tag}: subsystem {:?} requires real time (require_rt = true in the manifest) but \
             --no-rt was given; drop --no-rt or set require_rt = false",
            sub.name
        );
        return EXIT_CONFIG;
    }

    // One executor per subsystem and domain: a second one would publish on the same services.
    // (This also removes what dead processes left in the domain.)
    let node = crate::cleanup::executor_node_name(&sub.name);
    match crate::cleanup::scan_and_clean(&domain) {
        Ok(scan) => {
            if let Some(n) = scan.alive.iter().find(|n| n.name == node) {
                note!(
                    "{tag}: subsystem {:?} already runs in domain {:?} (process {}); stop it \
                     first or use another domain",
                    sub.name,
                    domain.name(),
                    n.pid.map_or("?".into(), |p| p.to_string())
                );
                return EXIT_CONFIG;
            }
        }
        Err(e) => note!("{tag}: warning: {e}"),
    }
    // The per-thread pool of the allocation-free bus variant, before any port exists.
    prepare_thread();
    let bus = match Bus::open(&domain, &node) {
        Ok(b) => b,
        Err(e) => {
            note!("{tag}: {e}");
            return EXIT_FAILURE;
        }
    };
    let mut exec = match Executor::new(&bus, sub) {
        Ok(x) => x,
        Err(e) => {
            note!("{tag}: {e}");
            return EXIT_FAILURE;
        }
    };

    let status = if args.no_rt {
        rt::RtStatus::default()
    } else {
        rt::setup(RtRequest {
            priority: Some(sub.priority),
            cpu: sub.cpu,
            lock_memory: true,
        })
    };
    if !status.problems.is_empty() {
        if require_rt {
            note!("{tag}: real time is required (require_rt) but not available:");
            for p in &status.problems {
                note!("  - {p}");
            }
            return EXIT_NO_RT;
        }
        for p in &status.problems {
            note!("{tag}: warning: running without full real-time guarantees: {p}");
        }
    }
    note!(
        "{tag}: {} states at {} Hz in domain {:?}, {}",
        sub.states.len(),
        sub.rate_hz,
        domain.name(),
        status.summary()
    );
    exec.set_rt_status(status);

    // Bring every device up (probe, model, configuration, enable from where it is) before
    // saying READY: a robot that is not as the manifest says does not run.
    let (last, up) = exec.bring_up(sub.period_ns, BRING_UP_NS, stop.flag());
    for line in &up.up {
        note!("{tag}: {line}");
    }
    for line in &up.missing {
        note!("{tag}: warning: optional {line}; its states stay STALE until it answers");
    }
    // Asked to stop while bringing the devices up: a stop, not a failure to run.
    if stop.flag().load(std::sync::atomic::Ordering::Relaxed) {
        let r = exec.shutdown(sub.period_ns, last + 1, STOP_CONFIRM_NS);
        return stopped(&tag, &exec, &r);
    }
    if !up.failed.is_empty() {
        for line in &up.failed {
            note!("{tag}: error: {line}");
        }
        let r = exec.shutdown(sub.period_ns, last + 1, STOP_CONFIRM_NS);
        for line in &r.unconfirmed {
            note!("{tag}: error: {line}");
        }
        note!(
            "{tag}: {} device(s) could not be brought up; not running",
            up.failed.len()
        );
        return EXIT_CONFIG;
    }

    let mut out = std::io::stdout();
    if writeln!(out, "{READY}").and_then(|_| out.flush()).is_err() {
        // Nobody reads our stdout any more (the launcher is gone): still run.
    }
    // Opt-in per-phase tick profile (benches/README.md): recorded over the run, not the
    // bring-up, and written when the run ends.
    let profile_to = std::env::var_os(PROFILE_ENV).filter(|p| !p.is_empty());
    exec.enable_profile(profile_to.is_some());
    let last = run_from(
        &mut exec,
        sub.period_ns,
        sub.spin_ns,
        stop.flag(),
        last + 1,
        |_| false,
    );
    if let Some(path) = &profile_to {
        let report = format!("states={}\n{}", sub.states.len(), exec.profile().report());
        if let Err(e) = std::fs::write(path, report) {
            note!("{tag}: warning: cannot write the tick profile to {path:?}: {e}");
        }
    }
    let r = exec.shutdown(sub.period_ns, last + 1, STOP_CONFIRM_NS);
    stopped(&tag, &exec, &r)
}

/// Environment variable naming a file: when set, the executor records how long each phase of
/// its ticks takes ([`crate::profile::TickProfile`]) and writes the totals there when it stops.
pub const PROFILE_ENV: &str = "CONDUCTOR_TICK_PROFILE";

/// Reports a stop: each device whose safe action could not be confirmed, loudly, and the exit
/// status (0 only when every safe action was confirmed on the wire).
fn stopped(tag: &str, exec: &Executor, r: &StopReport) -> u8 {
    let (ticks, misses) = exec.ticks_and_misses();
    let timing = format!(
        "stopped after {ticks} ticks ({misses} missed deadlines, lateness p99 {} µs)",
        exec.lateness().quantile(0.99) / 1000
    );
    if r.unconfirmed.is_empty() {
        let what = match (r.confirmed, r.sent) {
            (0, 0) => "devices in their safe state (none needed a safe action)".to_string(),
            (n, 0) => format!("devices in their safe state ({n} confirmed on the wire)"),
            (0, k) => format!("devices in their safe state ({k} simulated: sent)"),
            (n, k) => format!(
                "devices in their safe state ({n} confirmed on the wire, {k} simulated: sent)"
            ),
        };
        note!("{tag}: {timing}; {what}");
        EXIT_OK
    } else {
        for line in &r.unconfirmed {
            note!("{tag}: ERROR: {line}");
        }
        note!(
            "{tag}: {timing}; {} device(s) NOT confirmed in their safe state",
            r.unconfirmed.len()
        );
        EXIT_UNSAFE
    }
}
