//! `state-observer`: the thesis' Fig. 3.5 state-observer pattern, in Rust with nalgebra.
//!
//! Only the motor's position is measured. A discrete Luenberger observer, built on the exact
//! zero-order-hold model of the motor at the executor's tick, estimates x = [θ, ω]; the control
//! law is state feedback on the estimate, u = K·(r − x̂). The true velocity (which `sim-motor`
//! also publishes) is read only to report how good the estimate was.
//!
//! Model (τ·ω' = g·u − ω, θ' = ω), sampled with period h, a = e^{−h/τ}:
//!   A = [[1, τ(1 − a)], [0, a]],  B = [g(h − τ(1 − a)), g(1 − a)],  C = [1, 0].
//! Filter-form observer: x̂⁻ = A·x̂ + B·u,  x̂ = x̂⁻ + L·(y − C·x̂⁻); the error evolves with
//! (I − L·C)·A, whose two eigenvalues are placed at p = e^{−h·ω_o}.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Parser;
use conductor_bus::{Bus, BusError, Controller, Domain, TickWaiter};
use nalgebra::{Matrix1x2, Matrix2, Vector2};

#[derive(Parser)]
#[command(
    version,
    about = "Observer + state feedback with nalgebra (thesis Fig. 3.5)"
)]
struct Args {
    /// Domain (default: $CONDUCTOR_DOMAIN or "default").
    #[arg(long)]
    domain: Option<String>,
    /// Subsystem of the motor (states position, velocity, command).
    #[arg(long, default_value = "motor")]
    subsystem: String,
    /// Target position (rad).
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    target: f64,
    /// Model: steady-state velocity per volt (rad/s/V).
    #[arg(long, default_value_t = 2.0)]
    gain: f64,
    /// Model: time constant (s).
    #[arg(long, default_value_t = 0.1)]
    tau: f64,
    /// Observer bandwidth ω_o (rad/s).
    #[arg(long, default_value_t = 60.0)]
    observer: f64,
    /// Run this long (s).
    #[arg(long, default_value_t = 3.0)]
    seconds: f64,
}

/// The discrete model and observer gain for tick period `h`.
struct Observer {
    a: Matrix2<f64>,
    b: Vector2<f64>,
    c: Matrix1x2<f64>,
    l: Vector2<f64>,
    x: Vector2<f64>,
}

impl Observer {
    fn new(h: f64, gain: f64, tau: f64, omega_o: f64) -> Self {
        let a = (-h / tau).exp();
        let am = Matrix2::new(1.0, tau * (1.0 - a), 0.0, a);
        let b = Vector2::new(gain * (h - tau * (1.0 - a)), gain * (1.0 - a));
        // (I − L·C)·A has determinant (1 − l₁)·a and trace 1 − l₁ + a − l₂·A₁₂; a double
        // eigenvalue p needs determinant p² and trace 2p.
        let p = (-h * omega_o).exp();
        let l1 = 1.0 - p * p / a;
        let l2 = (1.0 - l1 + a - 2.0 * p) / am[(0, 1)];
        Self {
            a: am,
            b,
            c: Matrix1x2::new(1.0, 0.0),
            l: Vector2::new(l1, l2),
            x: Vector2::zeros(),
        }
    }

    /// One tick: `u` was applied over it, `y` is the position measured at its end.
    fn step(&mut self, u: f64, y: f64) {
        let prior = self.a * self.x + self.b * u;
        let innovation = y - (self.c * prior)[0];
        self.x = prior + self.l * innovation;
    }
}

fn run(args: &Args) -> Result<(), BusError> {
    let domain = match &args.domain {
        Some(d) => Domain::new(d)?,
        None => Domain::from_env()?,
    };
    let bus = Bus::open(&domain, "state-observer")?;
    let sub = &args.subsystem;
    let (pos, vel, cmd) = (
        format!("{sub}/position"),
        format!("{sub}/velocity"),
        format!("{sub}/command"),
    );
    let cmd_info = bus.resolve(&cmd)?;
    let h = 1.0 / cmd_info.meta.rate_hz;
    let mut obs = Observer::new(h, args.gain, args.tau, args.observer);
    // Feedback gains: double closed-loop pole at −10 s⁻¹ for the default motor.
    let k = Matrix1x2::new(5.0, 0.5);
    let r = Vector2::new(args.target, 0.0);

    let mut ctl = Controller::new(&bus);
    let mut tick = TickWaiter::new(&bus, sub)?;
    let mut last_tick: Option<u64> = None;
    let (mut sq_err, mut n, mut peak) = (0.0, 0u64, 0.0f64);
    let end = Instant::now() + Duration::from_secs_f64(args.seconds);
    while Instant::now() < end {
        tick.wait(Duration::from_millis(100))?;
        // y and the command applied over the same tick (the executor publishes both per tick).
        let y = match ctl.gather(&[pos.as_str(), cmd.as_str()]) {
            Ok(y) => y,
            // Subscribed on first use: the first sample comes with the executor's next tick.
            Err(BusError::NotEnoughSamples { .. }) => continue,
            Err(e) => return Err(e),
        };
        let Some(s) = ctl.state(&pos)?.sample() else {
            continue;
        };
        let ticks = last_tick.map_or(1, |t| s.tick.saturating_sub(t).max(1));
        last_tick = Some(s.tick);
        if n == 0 {
            // The motor starts at rest where it is.
            obs.x = Vector2::new(y[0], 0.0);
        } else {
            // Ticks we slept through ran with the same command (we send at most one per tick).
            for _ in 1..ticks {
                obs.x = obs.a * obs.x + obs.b * y[1];
            }
            obs.step(y[1], y[0]);
        }
        // Report only: how far the estimated velocity is from the measured one.
        let w = match ctl.get_surface(&vel) {
            Ok(w) => w,
            Err(BusError::NotEnoughSamples { .. }) => continue,
            Err(e) => return Err(e),
        };
        sq_err += (obs.x[1] - w).powi(2);
        peak = peak.max(w.abs());
        n += 1;

        let u = (k * (r - obs.x))[0];
        let (u, _) = cmd_info.meta.clamp(u);
        ctl.scatter(&[cmd.as_str()], &[u])?;
    }
    let rms = if n > 0 {
        (sq_err / n as f64).sqrt()
    } else {
        f64::NAN
    };
    println!(
        "{{\"steps\": {n}, \"position\": {}, \"estimate\": [{}, {}], \"velocity_rms_error\": {rms}, \"peak_velocity\": {peak}}}",
        ctl.get_surface(&pos)?,
        obs.x[0],
        obs.x[1]
    );
    std::thread::sleep(Duration::from_millis(100));
    Ok(())
}

fn main() -> ExitCode {
    conductor_examples::exit_code("state-observer", run(&Args::parse()))
}
