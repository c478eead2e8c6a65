//! `pid-controller`: the thesis' Fig. 3.4 PID controller, on today's bus.
//!
//! The Orocos script of the thesis read a state's value, derivative ("diff") and integral from
//! the State itself, computed `Kp·θ + Ki·∫θ + Kd·θ'`, and applied it with `addCtrl`/`sendCtrl`
//! once per tick. Here the State ([`conductor_bus::State`]) keeps the history, the derivative
//! (second-order difference over the newest samples) and the running trapezoid integral, and
//! the controller works on the tracking error e = r − θ, whose integral and derivative follow
//! from the state's: ∫e = r·(t − t₀) − ∫θ and ė = −θ̇ (constant target r).
//!
//! Defaults hold `sim-motor` at 1 rad: gains place the three closed-loop poles at −8 s⁻¹ for
//! the motor's model (τ = 0.1 s, gain 2 rad/s/V): 0.1 s³ + (1 + 2Kd) s² + 2Kp s + 2Ki = 0.1 (s + 8)³.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Parser;
use conductor_bus::{Bus, BusError, Controller, Domain, State, TickWaiter};

#[derive(Parser)]
#[command(
    version,
    about = "PID from a state's derivative and integral (thesis Fig. 3.4)"
)]
struct Args {
    /// Domain (default: $CONDUCTOR_DOMAIN or "default").
    #[arg(long)]
    domain: Option<String>,
    /// The measured state.
    #[arg(long, default_value = "motor/position")]
    measure: String,
    /// The commanded state.
    #[arg(long, default_value = "motor/command")]
    command: String,
    /// Target value of the measured state.
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    target: f64,
    #[arg(long, default_value_t = 9.6)]
    kp: f64,
    #[arg(long, default_value_t = 25.6)]
    ki: f64,
    #[arg(long, default_value_t = 0.7)]
    kd: f64,
    /// Run this long (s).
    #[arg(long, default_value_t = 3.0)]
    seconds: f64,
}

fn run(args: &Args) -> Result<(), BusError> {
    let domain = match &args.domain {
        Some(d) => Domain::new(d)?,
        None => Domain::from_env()?,
    };
    let bus = Bus::open(&domain, "pid-controller")?;
    let out = bus.resolve(&args.command)?;
    let mut ctl = Controller::new(&bus);
    let mut tick = TickWaiter::new(&bus, &out.subsystem)?;
    let mut theta = State::new(&bus, &args.measure, 64)?;
    let mut t0: Option<u64> = None;
    let mut frames = 0u64;
    let end = Instant::now() + Duration::from_secs_f64(args.seconds);
    while Instant::now() < end {
        tick.wait(Duration::from_millis(100))?;
        theta.update()?;
        let Some(s) = theta.sample() else { continue };
        let t_start = *t0.get_or_insert_with(|| {
            // ∫θ counts from here on, like the error's integral.
            theta.reset_integral();
            s.t_sample_ns
        });
        // The derivative needs three samples.
        let Ok(d_theta) = theta.derivative() else {
            continue;
        };
        let t = (s.t_sample_ns - t_start) as f64 * 1e-9;
        let e = args.target - s.value;
        let int_e = args.target * t - theta.integral();
        let d_e = -d_theta;
        let u = args.kp * e + args.ki * int_e + args.kd * d_e;
        let (u, _) = out.meta.clamp(u);
        ctl.add_ctrl(&args.command, u)?;
        ctl.send_ctrl()?;
        frames += 1;
    }
    println!(
        "{{\"frames\": {frames}, \"position\": {}, \"target\": {}}}",
        theta.value()?,
        args.target
    );
    // The last frame lives in our shared memory until the executor's next tick reads it.
    std::thread::sleep(Duration::from_millis(100));
    Ok(())
}

fn main() -> ExitCode {
    conductor_examples::exit_code("pid-controller", run(&Args::parse()))
}
