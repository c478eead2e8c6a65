//! `conductor-demo`: the simulated mini-Hubo right leg (thesis Fig. 3.2/3.3) walking.
//!
//! It launches the leg's manifest (one executor process, running this same program as
//! `conductor-demo executor ...`), then runs the thesis' PID (Fig. 3.4) as an external controller
//! process on the bus: each joint's State gives θ, θ̇ (derivative) and ∫θ (integral); all six
//! goal positions go out as one command frame per tick. First the leg settles into the start
//! pose, then it follows the gait with the reference alone (open loop) and then with the PID,
//! printing the tracking error every second and a comparison at the end.

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Parser;
use conductor_bus::{monotonic_ns, Bus, Controller, Domain, StatsSubscriber, TickWaiter};
use conductor_examples::minihubo::{error_ratio, gait_rms, GAINS, GAIT};
use conductor_executor::launcher::{Launch, LaunchOptions};
use conductor_executor::process;

const SUBSYSTEM: &str = "right_leg";

#[derive(Parser)]
#[command(
    version,
    about = "The simulated mini-Hubo right leg tracking a gait under a PID controller"
)]
struct Cli {
    /// The leg's manifest.
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../deploy/minihubo-right-leg.toml"))]
    manifest: PathBuf,
    /// Seconds of tracking (half with the reference alone, half with the PID).
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Bus domain (default: the manifest's).
    #[arg(long)]
    domain: Option<String>,
    /// Run the executor without real-time set-up.
    #[arg(long)]
    no_rt: bool,
}

fn main() -> ExitCode {
    let mut args: Vec<OsString> = std::env::args_os().collect();
    // The launcher runs this program as the executor.
    if args.get(1).is_some_and(|a| a == "executor") {
        args.remove(1);
        return process::main_with_args(args);
    }
    conductor_examples::exit_code("conductor-demo", run(&Cli::parse_from(args)))
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Mode {
    Settle,
    OpenLoop,
    Pid,
}

impl Mode {
    fn name(self) -> &'static str {
        match self {
            Mode::Settle => "settle",
            Mode::OpenLoop => "open loop",
            Mode::Pid => "PID",
        }
    }
}

/// Squared errors of one period of the run.
#[derive(Default, Clone, Copy)]
struct ErrStats {
    sum_sq: f64,
    n: u64,
    max: f64,
}

impl ErrStats {
    fn add(&mut self, e: f64) {
        self.sum_sq += e * e;
        self.n += 1;
        self.max = self.max.max(e.abs());
    }
    fn rms(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            (self.sum_sq / self.n as f64).sqrt()
        }
    }
}

const SETTLE_S: f64 = 1.0;
/// Each phase's first second is left out of its totals (the transient of the switch).
const TRANSIENT_S: f64 = 1.0;
/// The servo time constant of the manifest (loopback `tau_s`).
const TAU_S: f64 = 0.05;

fn run(cli: &Cli) -> Result<(), String> {
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let launch = Launch::start(
        &cli.manifest,
        LaunchOptions {
            executor: exe,
            executor_args: vec!["executor".into()],
            domain: cli.domain.clone(),
            no_rt: cli.no_rt,
            quiet: true,
            ..LaunchOptions::default()
        },
    )
    .map_err(|e| e.to_string())?;
    let stop = launch.stop_handle();
    let domain = Domain::new(launch.domain()).map_err(|e| e.to_string())?;
    let result = control(cli, &domain, &stop);
    launch.stop();
    let ended = launch.wait();
    let summary = result?;
    ended.map_err(|e| e.to_string())?;
    println!("{summary}");
    Ok(())
}

fn control(
    cli: &Cli,
    domain: &Domain,
    stop: &conductor_executor::signals::Stop,
) -> Result<String, String> {
    let s = |e: conductor_bus::BusError| e.to_string();
    let bus = Bus::open(domain, "minihubo-demo").map_err(s)?;
    let mut ctl = Controller::new(&bus);
    let mut tick = TickWaiter::new(&bus, SUBSYSTEM).map_err(s)?;
    let mut stats = StatsSubscriber::new(&bus, SUBSYSTEM).map_err(s)?;
    let names: Vec<String> = GAIT
        .iter()
        .map(|j| format!("{SUBSYSTEM}/{}", j.joint))
        .collect();
    let fz = format!("{SUBSYSTEM}/Fz");
    for n in names.iter().chain([&fz]) {
        ctl.state(n).map_err(s)?;
    }
    println!(
        "conductor-demo: mini-Hubo right leg on simulated servos (τ = 50 ms) and a simulated F/T \
         sensor, domain {:?}; PID Kp = {}, Ki = {}, Kd = {}",
        domain.name(),
        GAINS.kp,
        GAINS.ki,
        GAINS.kd
    );
    println!("    t  mode         rms error   max error        Fz   executor");

    let track = cli.seconds.max(0.2);
    let t_start = monotonic_ns();
    let secs = |t: u64| t.saturating_sub(t_start) as f64 * 1e-9;
    // τ: seconds since the gait started (after the settling phase).
    let tau_of = |t: u64| secs(t) - SETTLE_S;
    let pid_from = SETTLE_S + track / 2.0;
    let mut mode = Mode::Settle;
    let mut integral_from = [0.0; GAIT.len()];
    let mut last_seen = [0u64; GAIT.len()];
    let mut window = ErrStats::default();
    // Steady tracking per phase: open loop, PID.
    let mut totals = [ErrStats::default(); 2];
    let mut next_print = 1.0;
    let deadline = Instant::now() + Duration::from_secs_f64(SETTLE_S + track + 0.05);
    while !stop.requested() && Instant::now() < deadline {
        tick.wait(Duration::from_millis(20)).map_err(s)?;
        let now = monotonic_ns();
        let t = secs(now);
        let new_mode = if t < SETTLE_S {
            Mode::Settle
        } else if t < pid_from {
            Mode::OpenLoop
        } else {
            Mode::Pid
        };
        if new_mode == Mode::Pid && mode != Mode::Pid {
            // ∫e = ∫r − ∫θ from here on: restart each State's integral and note from when.
            for (i, n) in names.iter().enumerate() {
                let st = ctl.state(n).map_err(s)?;
                st.reset_integral();
                integral_from[i] = st.sample().map_or(tau_of(now), |x| tau_of(x.t_sample_ns));
            }
        }
        mode = new_mode;
        let steady = match mode {
            Mode::Settle => None,
            Mode::OpenLoop if t >= SETTLE_S + TRANSIENT_S => Some(0),
            Mode::Pid if t >= pid_from + TRANSIENT_S => Some(1),
            _ => None,
        };
        for (i, (j, n)) in GAIT.iter().zip(&names).enumerate() {
            let st = ctl.state(n).map_err(s)?;
            let Some(sample) = st.sample() else { continue };
            let tau_s = tau_of(sample.t_sample_ns);
            let e = j.position(tau_s) - sample.value;
            let u = match mode {
                Mode::Settle => j.position(0.0),
                Mode::OpenLoop => j.position(tau_of(now)),
                Mode::Pid => {
                    // Thesis Fig. 3.4: the State's value, derivative and integral.
                    let de = j.velocity(tau_s) - st.derivative().unwrap_or(0.0);
                    let ie = j.integral(integral_from[i], tau_s) - st.integral();
                    GAINS.command(j.position(tau_of(now)), e, ie, de)
                }
            };
            if mode != Mode::Settle && sample.t_sample_ns != last_seen[i] {
                window.add(e);
                if let Some(k) = steady {
                    totals[k].add(e);
                }
            }
            last_seen[i] = sample.t_sample_ns;
            ctl.add_ctrl(n, u).map_err(s)?;
        }
        ctl.send_ctrl().map_err(s)?;
        if t >= next_print {
            let force = ctl.get_surface(&fz).unwrap_or(f64::NAN);
            let exec = stats.latest().ok().flatten().map_or_else(
                || "-".to_string(),
                |x| {
                    format!(
                        "{:.1} Hz, lateness p99 {:.0} µs, {} misses",
                        x.achieved_rate_hz,
                        x.lateness_p99_ns as f64 / 1e3,
                        x.misses
                    )
                },
            );
            let (rms, max) = if window.n == 0 {
                ("-".to_string(), "-".to_string())
            } else {
                (
                    format!("{:.4} rad", window.rms()),
                    format!("{:.4} rad", window.max),
                )
            };
            println!(
                "{t:5.1}  {:<10} {rms:>11} {max:>11} {force:7.1} N   {exec}",
                mode.name()
            );
            window = ErrStats::default();
            next_print += 1.0;
        }
    }
    let (open, pid) = (totals[0], totals[1]);
    Ok(format!(
        "summary: open_loop_rms={:.5} open_loop_max={:.5} pid_rms={:.5} pid_max={:.5} \
         improvement={:.1}x theory_open_loop_rms={:.5} theory_pid_rms={:.5} (no bus delay)",
        open.rms(),
        open.max,
        pid.rms(),
        pid.max,
        if pid.rms() > 0.0 {
            open.rms() / pid.rms()
        } else {
            0.0
        },
        gait_rms(error_ratio(TAU_S, None, 0.0)),
        gait_rms(error_ratio(TAU_S, Some(GAINS), 0.0)),
    ))
}
