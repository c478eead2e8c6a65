//! The soak's controller: a separate process that commands one robot the way a user's
//! controller does, so it can be killed, stopped and flooded from outside.
//!
//! It enables every device (enable states to 1) until all of them drive, says `running` on
//! stdout, then sends one frame of joint setpoints per period (a slow sine inside each joint's
//! limits), now and then with values a buggy controller sends (out of limits, NaN, infinite).
//! A line `flood <ms>` on stdin makes it send frames back to back for that long. When it sees
//! a device tripped (after being stopped long enough for the watchdog to fire), it enables
//! again and says `running` once more.

use std::io::{BufRead, Write};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use conductor_bus::{
    monotonic_ns, status, Bus, CommandFrame, Controller, Domain, RtIpc, StateSubscriber,
    MAX_SETPOINTS,
};
use conductor_devices::sim::fault::Rng;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;

use super::rig::Joint;

/// What the controller process is told on its command line.
#[derive(Debug, Clone)]
pub struct ControllerArgs {
    /// Bus domain.
    pub domain: String,
    /// The robot's subsystem.
    pub subsystem: String,
    /// The robot's joints (`name:min:max`).
    pub joints: Vec<Joint>,
    /// Frames per second.
    pub rate_hz: f64,
    /// Seed of its bad values.
    pub seed: u64,
}

/// A writer of raw command frames, as a foreign program (another language through the ABI, a
/// buggy one) can send them: the client library refuses NaN and infinite values before they
/// leave, so this goes around it to see what the executor does with them.
pub(super) struct RawSender {
    _node: Node<RtIpc>,
    _service:
        iceoryx2::service::port_factory::publish_subscribe::PortFactory<RtIpc, CommandFrame, ()>,
    port: Publisher<RtIpc, CommandFrame, ()>,
}

impl RawSender {
    pub(super) fn open(
        domain: &Domain,
        subsystem: &str,
    ) -> Result<Self, Box<dyn std::error::Error>> {
        let name: NodeName = format!("soak-raw-{}", std::process::id())
            .as_str()
            .try_into()?;
        let node = NodeBuilder::new()
            .name(&name)
            .config(domain.iceoryx2_config())
            .create::<RtIpc>()?;
        let service_name: ServiceName = conductor_bus::naming::commands(subsystem)
            .as_str()
            .try_into()?;
        let service = node
            .service_builder(&service_name)
            .publish_subscribe::<CommandFrame>()
            .open()?;
        let port = service.publisher_builder().create()?;
        Ok(Self {
            _node: node,
            _service: service,
            port,
        })
    }

    pub(super) fn send(&self, frame: &CommandFrame) -> Result<(), Box<dyn std::error::Error>> {
        let sample = self.port.loan_uninit()?;
        sample.write_payload(*frame).send()?;
        Ok(())
    }
}

/// Runs the controller until it is killed (or its stdin closes).
pub fn run(args: &ControllerArgs) -> Result<(), Box<dyn std::error::Error>> {
    let domain = Domain::new(&args.domain)?;
    let bus = Bus::open(&domain, &format!("soak-controller-{}", std::process::id()))?;
    let mut ctl = Controller::new(&bus);
    let sub = &args.subsystem;
    let mut watch = Vec::new();
    for j in &args.joints {
        watch.push(StateSubscriber::new(&bus, &format!("{sub}/{}", j.name))?);
    }
    let raw = RawSender::open(&domain, sub)?;
    let indices: Vec<u32> = watch.iter().map(|w| w.info().meta.index).collect();
    let flood_until = flood_requests();
    let mut rng = Rng::new(args.seed);
    let period = Duration::from_secs_f64(1.0 / args.rate_hz);
    let t0 = Instant::now();
    let mut next = t0;
    let mut driving = false;
    let mut last_enable = None::<Instant>;
    // The newest flags of every joint (None: no sample yet).
    let mut flags: Vec<Option<u32>> = vec![None; watch.len()];
    let debug = std::env::var_os("CONDUCTOR_SOAK_DEBUG").is_some();
    let mut last_debug = Instant::now();
    let mut sent = 0u64;
    loop {
        for (w, f) in watch.iter_mut().zip(flags.iter_mut()) {
            if let Some(s) = w.latest()? {
                *f = Some(s.status);
            }
        }
        // Is any device not driving (or not heard of yet)?
        let blocked = flags
            .iter()
            .any(|f| f.is_none_or(|f| f & (status::DISABLED | status::TRIPPED) != 0));
        if debug && last_debug.elapsed() > Duration::from_secs(1) {
            last_debug = Instant::now();
            eprintln!("controller {sub}: flags {flags:x?} driving {driving} sent {sent}");
        }
        if blocked {
            driving = false;
        } else if !driving {
            driving = true;
            say("running");
        }
        if !driving {
            // Enable every 20 ms (the executor takes a few ticks to bring a device up).
            if last_enable.is_none_or(|t: Instant| t.elapsed() > Duration::from_millis(20)) {
                for j in &args.joints {
                    ctl.add_ctrl(&format!("{sub}/{}_enable", j.name), 1.0)?;
                }
                ctl.send_ctrl()?;
                last_enable = Some(Instant::now());
            }
            std::thread::sleep(Duration::from_millis(2));
            continue;
        }
        let t = t0.elapsed().as_secs_f64();
        let bad = rng.chance(0.002);
        if bad && rng.chance(0.5) {
            // What only a foreign writer can send: NaN, infinities, an unknown index, a count
            // beyond the frame.
            let mut f = CommandFrame::default();
            for &i in &indices {
                let v = match rng.below(3) {
                    0 => f64::NAN,
                    1 => f64::INFINITY,
                    _ => f64::NEG_INFINITY,
                };
                f.push(i, v);
            }
            f.push(MAX_SETPOINTS as u32 - 1, 0.0);
            if rng.chance(0.5) {
                f.count = u32::MAX;
            }
            f.t_send_ns = monotonic_ns();
            raw.send(&f)?;
        }
        for (i, j) in args.joints.iter().enumerate() {
            let mid = 0.5 * (j.min + j.max);
            let amp = 0.4 * (j.max - j.min);
            let mut v = mid + amp * (0.5 * t + i as f64).sin();
            if bad {
                // Out of limits, which the executor must clamp.
                v = if rng.chance(0.5) {
                    j.max + 1.0 + rng.unit() * 100.0
                } else {
                    j.min - 1.0 - rng.unit() * 100.0
                };
            }
            ctl.add_ctrl(&format!("{sub}/{}", j.name), v)?;
        }
        ctl.send_ctrl()?;
        sent += 1;
        pace(&mut next, period, &flood_until);
    }
}

/// Waits for a controller's next frame: none while a flood asked for by [`flood_requests`]
/// lasts (back to back, only yielding the CPU), else until `next` advanced by `period` (a late
/// frame moves `next` to now rather than bursting to catch up).
pub(super) fn pace(next: &mut Instant, period: Duration, flood_until: &AtomicU64) {
    if monotonic_ns() < flood_until.load(Ordering::Relaxed) {
        std::thread::yield_now();
        *next = Instant::now();
        return;
    }
    *next += period;
    let now = Instant::now();
    if *next > now {
        std::thread::sleep(*next - now);
    } else {
        *next = now;
    }
}

fn say(text: &str) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{text}");
    let _ = out.flush();
}

/// Reads the campaign's `flood <ms>` lines on stdin: the returned time (monotonic ns) is when
/// the flood asked for ends. When the campaign goes away (stdin closes), the controller exits.
pub(super) fn flood_requests() -> Arc<AtomicU64> {
    let flood_until = Arc::new(AtomicU64::new(0));
    let f2 = flood_until.clone();
    std::thread::spawn(move || {
        for line in std::io::stdin().lock().lines().map_while(Result::ok) {
            if let Some(ms) = line
                .strip_prefix("flood ")
                .and_then(|m| m.trim().parse::<u64>().ok())
            {
                f2.store(monotonic_ns() + ms * 1_000_000, Ordering::Relaxed);
            }
        }
        // The soak went away: so does its controller.
        std::process::exit(0);
    });
    flood_until
}
