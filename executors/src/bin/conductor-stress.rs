//! `conductor-stress`: the thesis' stress test (§3.1, Fig. 3.1) and its external logger.
//!
//! * `conductor-stress run --rate 1000 --seconds 5` launches 3 sine states at the rate, runs the
//!   logger in a separate process, and prints the executor's tick lateness and misses, the
//!   end-to-end latency (sample request → external subscriber) and the thesis' error
//!   sin(t_L) − value.
//! * `conductor-stress log --domain D --states sub/a,sub/b --seconds 2` is that logger: it counts
//!   each state's samples whose sample time falls in a window and prints one `key=value` line
//!   per state (used by the executor's tests as the external subscriber process).

use std::io::{BufRead, BufReader};
use std::process::{Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

use clap::{Parser, Subcommand};
use conductor_bus::{monotonic_ns, Bus, Domain, StatsSubscriber};
use conductor_executor::launcher::{Launch, LaunchOptions};
use conductor_executor::stress::{self, Logger, StressConfig, SUBSYSTEM};

#[derive(Parser)]
#[command(
    version,
    about = "The thesis' stress test: sine states at a rate, and an external logger"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Launch the stress manifest and log it from another process.
    Run {
        /// Sample rate (Hz).
        #[arg(long, default_value_t = 1000.0)]
        rate: f64,
        /// Logged duration (s).
        #[arg(long, default_value_t = 5.0)]
        seconds: f64,
        /// Number of sine states.
        #[arg(long, default_value_t = 3)]
        states: usize,
        /// CPU for the executor.
        #[arg(long)]
        cpu: Option<usize>,
        /// SCHED_FIFO priority.
        #[arg(long, default_value_t = 80)]
        priority: i32,
        /// Spin this long before each deadline (µs).
        #[arg(long, default_value_t = 0.0)]
        spin_us: f64,
        /// Run the executor without real-time set-up.
        #[arg(long)]
        no_rt: bool,
        /// Keep the generated manifest here instead of a temporary file.
        #[arg(long)]
        manifest_out: Option<std::path::PathBuf>,
    },
    /// Subscribe to states and report what arrived (one `key=value` line per state).
    Log {
        /// Bus domain.
        #[arg(long)]
        domain: String,
        /// States to log, `subsystem/state`, comma-separated.
        #[arg(long, value_delimiter = ',', required = true)]
        states: Vec<String>,
        /// Window length (s) over which samples are counted by their sample time.
        #[arg(long, default_value_t = 2.0)]
        seconds: f64,
        /// Wait this long (ms) after subscribing before the window opens.
        #[arg(long, default_value_t = 200)]
        settle_ms: u64,
        /// The states carry sin(t_S): report the thesis' errors.
        #[arg(long)]
        sine: bool,
    },
}

fn main() -> ExitCode {
    match Cli::parse().cmd {
        Cmd::Log {
            domain,
            states,
            seconds,
            settle_ms,
            sine,
        } => match log(&domain, &states, seconds, settle_ms, sine) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("conductor-stress log: {e}");
                ExitCode::FAILURE
            }
        },
        Cmd::Run {
            rate,
            seconds,
            states,
            cpu,
            priority,
            spin_us,
            no_rt,
            manifest_out,
        } => {
            let cfg = StressConfig {
                rate_hz: rate,
                cpu,
                priority,
                spin_us,
                states,
            };
            match run(&cfg, seconds, no_rt, manifest_out) {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => {
                    eprintln!("conductor-stress: {e}");
                    ExitCode::FAILURE
                }
            }
        }
    }
}

fn log(
    domain: &str,
    states: &[String],
    seconds: f64,
    settle_ms: u64,
    sine: bool,
) -> Result<(), String> {
    let domain = Domain::new(domain).map_err(|e| e.to_string())?;
    let bus = Bus::open(&domain, "stress-logger").map_err(|e| e.to_string())?;
    // The states may still be coming up: retry for a while.
    let give_up = Instant::now() + Duration::from_secs(10);
    let mut logger = loop {
        match Logger::new(&bus, states, sine) {
            Ok(l) => break l,
            Err(e) if Instant::now() > give_up => return Err(e.to_string()),
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    };
    let t0 = monotonic_ns() + settle_ms * 1_000_000;
    let t1 = t0 + (seconds * 1e9) as u64;
    logger.set_window(t0, t1);
    // Samples of the window's last instants arrive a little after it closes.
    while monotonic_ns() < t1 + 100_000_000 {
        logger.poll().map_err(|e| e.to_string())?;
        logger
            .wait(Duration::from_millis(5))
            .map_err(|e| e.to_string())?;
    }
    logger.poll().map_err(|e| e.to_string())?;
    for r in logger.reports() {
        println!("{}", r.line());
    }
    Ok(())
}

fn run(
    cfg: &StressConfig,
    seconds: f64,
    no_rt: bool,
    manifest_out: Option<std::path::PathBuf>,
) -> Result<(), String> {
    let temporary = manifest_out.is_none();
    let path = manifest_out.unwrap_or_else(|| {
        std::env::temp_dir().join(format!("conductor-stress-{}.toml", std::process::id()))
    });
    std::fs::write(&path, stress::manifest(cfg)).map_err(|e| e.to_string())?;
    let domain = Domain::unique("stress").map_err(|e| e.to_string())?;
    let launch = Launch::start(
        &path,
        LaunchOptions {
            domain: Some(domain.name().into()),
            no_rt,
            quiet: true,
            ..LaunchOptions::default()
        },
    )
    .map_err(|e| e.to_string())?;
    let names: Vec<String> = (0..cfg.states)
        .map(|i| format!("{SUBSYSTEM}/s{i}"))
        .collect();
    let bus = Bus::open(&domain, "stress-report").map_err(|e| e.to_string())?;
    let mut stats_sub = StatsSubscriber::new(&bus, SUBSYSTEM).map_err(|e| e.to_string())?;
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let child = Command::new(exe)
        .args(["log", "--domain", domain.name(), "--sine", "--states"])
        .arg(names.join(","))
        .arg("--seconds")
        .arg(seconds.to_string())
        .stdout(Stdio::piped())
        .spawn()
        .map_err(|e| format!("starting the logger: {e}"))?;
    let out = child.wait_with_output().map_err(|e| e.to_string())?;
    let stats = stats_sub.latest().map_err(|e| e.to_string())?;
    drop(stats_sub);
    drop(bus);
    launch.stop();
    let ended = launch.wait();
    if temporary {
        let _ = std::fs::remove_file(&path);
    }
    ended.map_err(|e| e.to_string())?;
    println!(
        "stress test: {} sine states at {} Hz, logged for {seconds} s by a separate process",
        cfg.states, cfg.rate_hz
    );
    if let Some(s) = stats {
        println!(
            "executor: ticks={} misses={} rt={} cpu={} lateness_p50_us={:.1} lateness_p99_us={:.1} \
             lateness_p999_us={:.1} lateness_max_us={:.1} achieved_hz={:.1}",
            s.ticks,
            s.misses,
            s.rt_active,
            s.cpu,
            s.lateness_p50_ns as f64 / 1e3,
            s.lateness_p99_ns as f64 / 1e3,
            s.lateness_p999_ns as f64 / 1e3,
            s.lateness_max_ns as f64 / 1e3,
            s.achieved_rate_hz
        );
    }
    for line in BufReader::new(&out.stdout[..])
        .lines()
        .map_while(Result::ok)
    {
        println!("{line}");
    }
    if !out.status.success() {
        return Err(format!("the logger failed: {}", out.status));
    }
    Ok(())
}
