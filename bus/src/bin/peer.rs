//! `conductor-bus-peer`: a small standalone process on the bus.
//!
//! It exists so that tests (and curious users) can put a real second process on a domain:
//! publish simulated states, subscribe and count, own a command service, send frames, list
//! states. `demo` runs a publisher child process and prints its states from this one.
//! The domain comes from `CONDUCTOR_DOMAIN` or `--domain`.

use std::process::{Command, ExitCode, Stdio};
use std::thread::sleep;
use std::time::{Duration, Instant};

use clap::{Parser, Subcommand};
use conductor_bus::{
    monotonic_ns, status, Bus, CommandReceiver, Controller, Domain, StateMeta, StatePublisher,
    StateSpec, StateSubscriber, TickWaiter,
};

#[derive(Parser)]
#[command(version, about = "A standalone Conductor bus peer for tests and demos")]
struct Cli {
    /// Domain to join (default: $CONDUCTOR_DOMAIN or "default").
    #[arg(long, global = true)]
    domain: Option<String>,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Publish states of one subsystem: state k carries sin(t + k) (or the sample number).
    #[command(allow_negative_numbers = true)]
    Publish {
        #[arg(long)]
        subsystem: String,
        /// Comma-separated state names.
        #[arg(long, value_delimiter = ',')]
        states: Vec<String>,
        /// Ticks per second.
        #[arg(long, default_value_t = 100.0)]
        rate: f64,
        /// Ticks to publish (0 = until killed).
        #[arg(long, default_value_t = 0)]
        count: u64,
        /// Largest per-subscriber queue a client may ask for.
        #[arg(long, default_value_t = 256)]
        buffer: usize,
        /// Publish the sample number instead of sin(t).
        #[arg(long)]
        counter: bool,
        /// Units and limits for every state.
        #[arg(long, default_value = "rad")]
        units: String,
        #[arg(long, default_value_t = -1.0)]
        min: f64,
        #[arg(long, default_value_t = 1.0)]
        max: f64,
        /// Wait for this many subscribers on the first state before publishing.
        #[arg(long, default_value_t = 0)]
        wait_subscribers: usize,
        /// Keep the services alive this long after the last tick (ms).
        #[arg(long, default_value_t = 500)]
        linger_ms: u64,
    },
    /// Subscribe to one state and report what arrived: `received R missed M last_seq S`.
    Subscribe {
        state: String,
        /// Stop after this many samples.
        #[arg(long)]
        count: u64,
        #[arg(long, default_value_t = 64)]
        buffer: usize,
        /// Sleep this long after each sample (a slow subscriber).
        #[arg(long, default_value_t = 0)]
        slow_ms: u64,
        /// Give up after this many seconds without reaching `count`.
        #[arg(long, default_value_t = 20.0)]
        timeout: f64,
    },
    /// Own the command service of a subsystem and print every frame received.
    ReceiveCommands {
        #[arg(long)]
        subsystem: String,
        /// Exit after this many frames.
        #[arg(long, default_value_t = 1)]
        frames: u64,
        #[arg(long, default_value_t = 20.0)]
        timeout: f64,
    },
    /// Send one command frame: `--set leg/knee=0.5 --set leg/hip=0.1`.
    Send {
        #[arg(long = "set", value_parser = parse_kv)]
        set: Vec<(String, f64)>,
    },
    /// List the states of the domain with their metadata.
    List,
    /// Start a publisher process of 3 sine states and print them here, at every tick.
    Demo {
        #[arg(long, default_value_t = 50.0)]
        rate: f64,
        #[arg(long, default_value_t = 3.0)]
        seconds: f64,
    },
}

fn parse_kv(s: &str) -> Result<(String, f64), String> {
    let (k, v) = s
        .split_once('=')
        .ok_or_else(|| format!("expected state=value, got {s:?}"))?;
    let v: f64 = v
        .parse()
        .map_err(|_| format!("expected a number after '=' in {s:?}"))?;
    Ok((k.to_string(), v))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // SIGTERM/SIGINT end the loops below normally, so every port is dropped and the domain's
    // shared memory is released.
    if let Err(e) = conductor_bus::shutdown::install() {
        eprintln!("conductor-bus-peer: cannot install signal handlers: {e}");
        return ExitCode::FAILURE;
    }
    let domain = match cli.domain.as_deref() {
        Some(d) => Domain::new(d),
        None => Domain::from_env(),
    };
    let result = domain
        .map_err(|e| e.to_string())
        .and_then(|d| run(&d, cli.cmd));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("conductor-bus-peer: {e}");
            ExitCode::FAILURE
        }
    }
}

type Res = Result<(), String>;

fn stop() -> bool {
    conductor_bus::shutdown::requested()
}

fn run(domain: &Domain, cmd: Cmd) -> Res {
    let s = |e: conductor_bus::BusError| e.to_string();
    match cmd {
        Cmd::Publish {
            subsystem,
            states,
            rate,
            count,
            buffer,
            counter,
            units,
            min,
            max,
            wait_subscribers,
            linger_ms,
        } => {
            let bus = Bus::open(domain, &format!("peer-publish/{subsystem}")).map_err(s)?;
            let specs: Vec<StateSpec> = states
                .iter()
                .enumerate()
                .map(|(i, name)| StateSpec {
                    name: name.clone(),
                    meta: StateMeta {
                        index: i as u32,
                        units: units.clone(),
                        writable: true,
                        rate_hz: rate,
                        min,
                        max,
                        device: format!("sim{i}"),
                    },
                    buffer,
                })
                .collect();
            let mut publisher = StatePublisher::create(&bus, &subsystem, &specs).map_err(s)?;
            println!("READY");
            let wait_until = Instant::now() + Duration::from_secs(10);
            while wait_subscribers > 0 && Instant::now() < wait_until {
                let reached = publisher.subscribers(0);
                if reached >= wait_subscribers {
                    break;
                }
                sleep(Duration::from_millis(5));
            }
            let period = Duration::from_secs_f64(1.0 / rate);
            let start = Instant::now();
            let t0 = monotonic_ns();
            let mut tick = 0u64;
            while (count == 0 || tick < count) && !stop() {
                let deadline = start + period * tick as u32;
                if let Some(d) = deadline.checked_duration_since(Instant::now()) {
                    sleep(d);
                }
                let t = monotonic_ns();
                for k in 0..specs.len() {
                    let v = if counter {
                        tick as f64
                    } else {
                        ((t - t0) as f64 * 1e-9 + k as f64).sin()
                    };
                    publisher
                        .publish(k, tick, t, v, status::SIMULATED)
                        .map_err(s)?;
                }
                publisher.notify_tick().map_err(s)?;
                tick += 1;
            }
            if !stop() {
                sleep(Duration::from_millis(linger_ms));
            }
            Ok(())
        }
        Cmd::Subscribe {
            state,
            count,
            buffer,
            slow_ms,
            timeout,
        } => {
            let bus = Bus::open(domain, "peer-subscribe").map_err(s)?;
            let mut sub = StateSubscriber::with_buffer(&bus, &state, buffer).map_err(s)?;
            println!("READY");
            let deadline = Instant::now() + Duration::from_secs_f64(timeout);
            let mut last_seq = None;
            while sub.received() + sub.missed() < count && Instant::now() < deadline && !stop() {
                match sub.receive().map_err(s)? {
                    Some(sample) => {
                        last_seq = Some(sample.seq);
                        if slow_ms > 0 {
                            sleep(Duration::from_millis(slow_ms));
                        }
                    }
                    None => sleep(Duration::from_micros(200)),
                }
            }
            println!(
                "received {} missed {} last_seq {}",
                sub.received(),
                sub.missed(),
                last_seq.map_or("none".into(), |q| q.to_string())
            );
            Ok(())
        }
        Cmd::ReceiveCommands {
            subsystem,
            frames,
            timeout,
        } => {
            let bus = Bus::open(domain, &format!("peer-commands/{subsystem}")).map_err(s)?;
            let mut rx = CommandReceiver::create(&bus, &subsystem).map_err(s)?;
            println!("READY");
            let deadline = Instant::now() + Duration::from_secs_f64(timeout);
            let mut got = 0;
            while got < frames && Instant::now() < deadline && !stop() {
                got += rx
                    .drain(|f| {
                        let body: Vec<String> = f
                            .setpoints()
                            .iter()
                            .map(|sp| format!("{}={}", sp.index, sp.value))
                            .collect();
                        println!("frame seq={} count={} {}", f.seq, f.count, body.join(" "));
                    })
                    .map_err(s)? as u64;
                sleep(Duration::from_millis(1));
            }
            if got < frames && !stop() {
                return Err(format!("timed out with {got} of {frames} frames"));
            }
            Ok(())
        }
        Cmd::Send { set } => {
            let bus = Bus::open(domain, "peer-send").map_err(s)?;
            let mut ctl = Controller::new(&bus);
            for (k, v) in &set {
                ctl.add_ctrl(k, *v).map_err(s)?;
            }
            let n = ctl.send_ctrl().map_err(s)?;
            println!("sent {n}");
            // Let the receiver connect to our publisher before the sample is dropped with it.
            sleep(Duration::from_millis(200));
            Ok(())
        }
        Cmd::List => {
            let bus = Bus::open(domain, "peer-list").map_err(s)?;
            for st in bus.list_states().map_err(s)? {
                println!(
                    "{} index={} units={} writable={} rate_hz={} limits={},{} device={}",
                    st.qualified_name(),
                    st.meta.index,
                    st.meta.units,
                    st.meta.writable,
                    st.meta.rate_hz,
                    st.meta.min,
                    st.meta.max,
                    st.meta.device
                );
            }
            Ok(())
        }
        Cmd::Demo { rate, seconds } => demo(domain, rate, seconds),
    }
}

fn demo(domain: &Domain, rate: f64, seconds: f64) -> Res {
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let count = (rate * seconds) as u64;
    let mut child = Command::new(exe)
        .args(["--domain", domain.name(), "publish", "--subsystem", "demo"])
        .args([
            "--states",
            "joint0,joint1,joint2",
            "--rate",
            &rate.to_string(),
        ])
        .args(["--count", &count.to_string()])
        .stdout(Stdio::null())
        .spawn()
        .map_err(|e| format!("starting the publisher process: {e}"))?;
    let bus = Bus::open(domain, "peer-demo").map_err(|e| e.to_string())?;
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut subs = loop {
        let names = ["demo/joint0", "demo/joint1", "demo/joint2"];
        let subs: Result<Vec<_>, _> = names
            .iter()
            .map(|n| StateSubscriber::new(&bus, n))
            .collect();
        match subs {
            Ok(v) => break v,
            Err(_) if Instant::now() < deadline => sleep(Duration::from_millis(20)),
            Err(e) => return Err(e.to_string()),
        }
    };
    let mut tick = TickWaiter::new(&bus, "demo").map_err(|e| e.to_string())?;
    println!(
        "publisher pid {} on domain {:?}; printing its states:",
        child.id(),
        domain.name()
    );
    let mut seen = 0u64;
    while seen < count {
        if tick
            .wait(Duration::from_secs(1))
            .map_err(|e| e.to_string())?
            == 0
        {
            break;
        }
        let mut line = String::new();
        for sub in &mut subs {
            if let Some(sm) = sub.latest().map_err(|e| e.to_string())? {
                let lat = (monotonic_ns() - sm.t_publish_ns) as f64 * 1e-3;
                line += &format!(
                    "{}={:+.4} (seq {}, {:.0} µs)  ",
                    sub.info().name,
                    sm.value,
                    sm.seq,
                    lat
                );
                seen = seen.max(sm.seq + 1);
            }
        }
        println!("{line}");
    }
    child.wait().map_err(|e| e.to_string())?;
    Ok(())
}
