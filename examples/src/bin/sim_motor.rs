//! `sim-motor`: a simulated executor owning `motor/position`, `motor/velocity` and
//! `motor/command` (a first-order DC motor), for trying the examples without hardware.

use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use clap::Parser;
use conductor_bus::Domain;
use conductor_examples::{motor, sim};

#[derive(Parser)]
#[command(version, about = "A simulated first-order motor on the Conductor bus")]
struct Args {
    /// Domain to publish in (default: $CONDUCTOR_DOMAIN or "default").
    #[arg(long)]
    domain: Option<String>,
    /// Tick rate (Hz).
    #[arg(long, default_value_t = 500.0)]
    rate: f64,
    /// Run this many seconds (default: until killed, e.g. Ctrl-C).
    #[arg(long)]
    seconds: Option<f64>,
    /// Steady-state velocity per volt (rad/s/V).
    #[arg(long, default_value_t = 2.0)]
    gain: f64,
    /// Mechanical time constant (s).
    #[arg(long, default_value_t = 0.1)]
    tau: f64,
}

fn run(args: &Args) -> Result<(), sim::SimError> {
    let domain = args
        .domain
        .as_deref()
        .map_or_else(Domain::from_env, Domain::new)?;
    let stop = Arc::new(AtomicBool::new(false));
    if let Some(secs) = args.seconds {
        let stop = stop.clone();
        std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_secs_f64(secs));
            stop.store(true, Ordering::Relaxed);
        });
    }
    let mut plant = motor::Motor {
        gain: args.gain,
        tau: args.tau,
    };
    let spec = motor::spec(args.rate);
    let rep = sim::run(&domain, &spec, &mut plant, &stop, || {
        println!("READY domain={}", domain.name());
    })?;
    println!(
        "ticks {} frames {} rejected {} clamped {}",
        rep.ticks, rep.frames, rep.rejected, rep.clamped
    );
    Ok(())
}

fn main() -> ExitCode {
    conductor_examples::exit_code("sim-motor", run(&Args::parse()))
}
