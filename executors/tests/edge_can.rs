//! The hardware edge on CAN, end to end: `conductor-executor` against the SLCAN adapter
//! simulator on a pseudo-terminal with MIT-mode motors (Katz firmware behaviour: commands are
//! ignored until the enter-motor-mode frame, which starts with no torque) and an ODrive axis
//! (idle until asked for closed loop) behind it.
//!
//! A stop through an adapter that lags is confirmed on the wire before the executor exits; a
//! tripped motor refuses setpoints and is enabled again from where it is, not towards a command
//! from before the trip; a motor fault trips it; garbage lines publish nothing; after the
//! adapter stalls, every sample keeps its true sample time; an adapter that never acknowledges
//! frames keeps one frame per motor per tick; the adapter unplugged and plugged back resumes.
//! The `cubemars_ak` kind runs with its model's ranges, as the simulated motor does.

mod support;

use std::time::{Duration, Instant};

use conductor_bus::{status, Bus, Controller, Domain, StateSample, StatsSubscriber};
use conductor_devices::device::cubemars_ak::AkModel;
use conductor_devices::protocol_stage::mit_limits;
use conductor_devices::sim::can_motors::{CanNode, MitMotorSim, OdriveAxisSim};
use conductor_devices::sim::runner::{run_slcan, Endpoint, Pty, Running};
use conductor_devices::sim::slcan_adapter::SlcanAdapterSim;
use conductor_protocols::mit_can::{decode_command, Limits, MotorCommand, SpecialCommand};
use conductor_protocols::slcan::Dialect;
use embedded_can::Frame;
use support::edge::{send, Exec, Watch};
use support::{eventually, temp_manifest};

/// An adapter with MIT motors `mit` (8-byte replies with `long`) and ODrive axes `odrive`.
fn adapter(tag: &str, mit: &[u8], long: bool, odrive: &[u8]) -> (Running<SlcanAdapterSim>, String) {
    adapter_of(tag, mit_limits("ak80-9").unwrap(), mit, long, odrive)
}

/// [`adapter`] with MIT motors of ranges `limits`.
fn adapter_of(
    tag: &str,
    limits: Limits,
    mit: &[u8],
    long: bool,
    odrive: &[u8],
) -> (Running<SlcanAdapterSim>, String) {
    let link = std::env::temp_dir().join(format!("conductor-edge-{tag}-{}", std::process::id()));
    let mut nodes: Vec<Box<dyn CanNode>> = Vec::new();
    for &id in mit {
        nodes.push(Box::new(MitMotorSim::new(id, limits, 0, long)));
    }
    for &n in odrive {
        nodes.push(Box::new(OdriveAxisSim::new(n, 100, 0)));
    }
    let sim = run_slcan(
        Endpoint::Pty(Pty::open(Some(&link)).unwrap()),
        SlcanAdapterSim::new(Dialect::CANABLE, nodes).with_log(),
    );
    (sim, link.display().to_string())
}

/// A manifest for MIT motors 1..=`n` at 500 Hz: per motor, position (and, with `gains`,
/// velocity, torque, kp, kd) writable, and its enable state.
fn manifest(port: &str, n: u8, top: &str, gains: bool) -> String {
    let mut s = format!(
        "system = \"edge\"\n[subsystems.leg]\nrate_hz = 500\n{top}\n\
         [subsystems.leg.hardware.can0]\nkind = \"slcan\"\nport = \"{port}\"\n\
         [subsystems.leg.protocols.mit]\nkind = \"can_motors\"\nhardware = \"can0\"\ntimeout_us = 1500\n"
    );
    for i in 1..=n {
        s += &format!(
            "[subsystems.leg.devices.m{i}]\nkind = \"mit_motor\"\nprotocol = \"mit\"\nid = {i}\nkp = 20.0\nkd = 1.0\n\
             [subsystems.leg.states.p{i}]\ndevice = \"m{i}\"\nchannel = \"position\"\nwritable = true\nmin = -3\nmax = 3\n\
             [subsystems.leg.states.e{i}]\ndevice = \"m{i}\"\nchannel = \"enable\"\nwritable = true\nmin = 0\nmax = 1\n"
        );
        if gains {
            for ch in ["velocity", "torque", "kp", "kd"] {
                s += &format!(
                    "[subsystems.leg.states.{ch}{i}]\ndevice = \"m{i}\"\nchannel = \"{ch}\"\nwritable = true\n"
                );
            }
        }
    }
    s
}

fn start(tag: &str, text: &str) -> (Exec, Domain) {
    let d = Domain::unique(tag).unwrap();
    let path = temp_manifest(tag, text);
    let exec = Exec::start(&path, "leg", &d).unwrap_or_else(|(s, log)| panic!("{s}: {log:#?}"));
    (exec, d)
}

/// The MIT data of an exit-motor-mode frame.
const EXIT: [u8; 8] = [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFD];

fn node(
    sim: &Running<SlcanAdapterSim>,
    i: usize,
) -> conductor_devices::sim::can_motors::NodeSnapshot {
    sim.sim().nodes()[i].snapshot()
}

#[test]
fn a_stop_through_a_lagging_adapter_is_confirmed_on_the_wire() {
    let (sim, port) = adapter("lag", &[1, 2, 3], false, &[]);
    let (mut exec, d) = start("lag", &manifest(&port, 3, "", false));
    for i in 0..3 {
        assert!(node(&sim, i).enabled, "motor {} in motor mode", i + 1);
        assert_eq!(node(&sim, i).ignored, 0, "no command before enter");
    }
    // The adapter falls behind: acknowledgements and answers come 60 ms late, frames queue up.
    sim.sim().set_latency(60_000_000);
    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    let end = Instant::now() + Duration::from_millis(500);
    while Instant::now() < end {
        send(
            &mut ctl,
            &[("leg/p1", 0.2), ("leg/p2", -0.2), ("leg/p3", 0.1)],
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    exec.stop_confirmed(3);
    std::thread::sleep(Duration::from_millis(100));
    for i in 0..3 {
        assert!(!node(&sim, i).enabled, "motor {} out of motor mode", i + 1);
    }
    // On the wire: after each motor's exit frame, nothing more for it from the host.
    let s = sim.sim();
    for id in 1..=3u16 {
        let to_it: Vec<&[u8]> = s
            .log()
            .iter()
            .filter(|(host, f)| {
                *host
                    && f.id()
                        == embedded_can::Id::Standard(embedded_can::StandardId::new(id).unwrap())
            })
            .map(|(_, f)| f.data())
            .collect();
        let last_exit = to_it
            .iter()
            .rposition(|d| *d == EXIT)
            .expect("an exit frame");
        assert_eq!(
            last_exit,
            to_it.len() - 1,
            "motor {id}: frames after its exit frame"
        );
    }
}

#[test]
fn a_tripped_motor_refuses_setpoints_and_is_enabled_again_from_where_it_is() {
    let (sim, port) = adapter("reenable", &[1], false, &[]);
    let (mut exec, d) = start("reenable", &manifest(&port, 1, "watchdog_ms = 200", true));
    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    let mut p1 = Watch::new(&bus, "leg/p1");
    // A command that keeps pushing: no stiffness, no damping, 0.05 N·m feed-forward.
    let end = Instant::now() + Duration::from_millis(400);
    while Instant::now() < end {
        send(
            &mut ctl,
            &[
                ("leg/kp1", 0.0),
                ("leg/kd1", 0.0),
                ("leg/torque1", 0.05),
                ("leg/p1", 0.0),
            ],
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // Silence: the watchdog takes it out of motor mode; it coasts to a stop (no torque).
    let s = p1.until(2.0, "tripped", |s| {
        s.status & (status::TRIPPED | status::DISABLED | status::WATCHDOG)
            == status::TRIPPED | status::DISABLED | status::WATCHDOG
    });
    assert!(s.value > 0.05, "it had moved: {s:?}");
    exec.wait_log(2, "tripped by the command watchdog");
    std::thread::sleep(Duration::from_millis(800));
    assert!(!node(&sim, 0).enabled);
    // Refused, not queued.
    send(&mut ctl, &[("leg/p1", 1.0)]);
    p1.until(1.0, "refused", |s| s.status & status::REJECTED != 0);

    // enable = 1: from where it is now, with the manifest's gains, never the command from
    // before the trip (which would push it away again).
    let here = node(&sim, 0).position;
    send(&mut ctl, &[("leg/e1", 1.0)]);
    p1.until(1.0, "enabled", |s| {
        s.status & (status::TRIPPED | status::DISABLED) == 0
    });
    assert!(node(&sim, 0).enabled);
    // It holds there (keep the watchdog fed), not accelerating with the old feed-forward.
    let end = Instant::now() + Duration::from_millis(400);
    while Instant::now() < end {
        send(&mut ctl, &[("leg/e1", 1.0)]);
        std::thread::sleep(Duration::from_millis(50));
    }
    let now = node(&sim, 0).position;
    assert!((now - here).abs() < 0.01, "moved on enable: {here} → {now}");
    exec.stop_ok();
}

#[test]
fn a_motor_fault_trips_it_and_is_reported_once() {
    let (sim, port) = adapter("mitfault", &[1, 2], true, &[]);
    let (mut exec, d) = start("mitfault", &manifest(&port, 2, "", false));
    let bus = Bus::open(&d, "t").unwrap();
    let mut p2 = Watch::new(&bus, "leg/p2");
    p2.until(2.0, "up", |s| s.status & status::DISABLED == 0);
    // Motor over-temperature (code 6): the motor leaves motor mode and says so in every reply.
    assert!(sim.sim().nodes_mut()[1].set_fault(6));
    let all = status::DEVICE_FAULT | status::TRIPPED | status::DISABLED;
    p2.until(2.0, "fault flags", |s| s.status & all == all);
    exec.wait_log(2, "reports a fault: 0x6");
    let mut stats = StatsSubscriber::new(&bus, "leg").unwrap();
    let st = eventually(2, "stats", || {
        stats.latest().unwrap().filter(|s| s.device_faults > 0)
    });
    assert_eq!(
        (st.devices_faulted, st.devices_tripped, st.devices_enabled),
        (1, 1, 1)
    );
    std::thread::sleep(Duration::from_millis(200));
    assert_eq!(
        exec.log()
            .iter()
            .filter(|l| l.contains("reports a fault"))
            .count(),
        1,
        "once per transition"
    );
    exec.stop_ok();
}

#[test]
fn a_garbled_reply_line_publishes_nothing() {
    let (sim, port) = adapter("garbage", &[1], false, &[]);
    let (mut exec, d) = start("garbage", &manifest(&port, 1, "", false));
    let bus = Bus::open(&d, "t").unwrap();
    let mut p1 = Watch::new(&bus, "leg/p1");
    p1.until(2.0, "up", |s| s.status & status::DISABLED == 0);
    // A reply from motor 1 saying 0.9997 rad, with 4 extra hex digits (timestamps were never
    // switched on): malformed, never a value.
    for _ in 0..20 {
        sim.sim().inject_to_host(b"t0006018A3C7AD838ABCD\r");
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(100));
    p1.poll();
    assert!(p1.all.len() > 50);
    for s in &p1.all {
        assert!(s.value.abs() < 0.01, "a wrong value was published: {s:?}");
    }
    exec.stop_ok();
}

/// Least squares fit of value = a + b·t (t in s).
fn fit(samples: &[StateSample]) -> (f64, f64) {
    let n = samples.len() as f64;
    let t0 = samples[0].t_sample_ns;
    let ts: Vec<f64> = samples
        .iter()
        .map(|s| (s.t_sample_ns - t0) as f64 * 1e-9)
        .collect();
    let (mt, mv) = (
        ts.iter().sum::<f64>() / n,
        samples.iter().map(|s| s.value).sum::<f64>() / n,
    );
    let b = ts
        .iter()
        .zip(samples)
        .map(|(t, s)| (t - mt) * (s.value - mv))
        .sum::<f64>()
        / ts.iter().map(|t| (t - mt) * (t - mt)).sum::<f64>();
    (mv - b * mt, b)
}

#[test]
fn after_a_stalled_adapter_every_sample_keeps_its_true_time() {
    let (sim, port) = adapter("stall", &[1], false, &[]);
    let (mut exec, d) = start("stall", &manifest(&port, 1, "", true));
    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    let mut p1 = Watch::new(&bus, "leg/p1");
    // A steady speed: velocity 2 rad/s with kd 1, no stiffness (≈ 1.9 rad/s in the sim).
    let drive = |ctl: &mut Controller| {
        send(
            ctl,
            &[
                ("leg/kp1", 0.0),
                ("leg/velocity1", 2.0),
                ("leg/torque1", 0.0),
            ],
        );
    };
    let phase = |ctl: &mut Controller, ms: u64| {
        let end = Instant::now() + Duration::from_millis(ms);
        while Instant::now() < end {
            drive(ctl);
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    phase(&mut ctl, 300);
    p1.poll();
    let skip = p1.all.len();
    phase(&mut ctl, 300);
    p1.poll();
    let before = p1.fresh_from(skip);
    let (a, v) = fit(&before);
    assert!((1.5..2.1).contains(&v), "steady speed {v}");
    // The adapter stalls for 0.3 s, then delivers its backlog: ack k, reply k, ack k+1, ...
    let until = sim.now_ns() + 300_000_000;
    sim.sim().stall_until(until);
    phase(&mut ctl, 500);
    p1.poll();
    let t_end_stall = before[0].t_sample_ns; // the fit's time origin
    let mark = p1.all.len();
    phase(&mut ctl, 300);
    p1.poll();
    let after = p1.fresh_from(mark);
    assert!(
        after.len() > 50,
        "{} fresh samples after the stall",
        after.len()
    );
    // The fresh samples lie on the same line as before the stall. A reply credited to the next
    // request would shift every later sample by one period (≈ 3.8 mrad at 1.9 rad/s) for
    // ever. A reply answered or read late (a loaded machine starves the simulator or the
    // executor) only ever lies below the line: its position is older than its stamp. So compare
    // the upper decile of the distances to the line before and after: it is the samples that
    // were answered and read at once.
    let residual = |s: &StateSample| {
        let t = (s.t_sample_ns - t_end_stall) as f64 * 1e-9;
        s.value - (a + v * t)
    };
    let upper_decile = |mut r: Vec<f64>| {
        r.sort_by(f64::total_cmp);
        r[r.len() * 9 / 10]
    };
    let shift = upper_decile(after.iter().map(residual).collect())
        - upper_decile(before.iter().map(residual).collect());
    assert!(
        shift.abs() < 0.0015,
        "after the stall the samples are {shift} rad off the line"
    );
    // The backlog's answers came too late to be true: counted and dropped.
    let mut stats = StatsSubscriber::new(&bus, "leg").unwrap();
    let st = eventually(2, "stats", || stats.latest().unwrap());
    assert!(st.late_replies > 0, "{st:?}");
    exec.stop_ok();
}

#[test]
fn an_adapter_that_never_acknowledges_keeps_one_frame_per_motor_per_tick() {
    let (sim, port) = adapter("noack", &[1, 2, 3], false, &[]);
    sim.sim().set_acks(false);
    let (mut exec, d) = start("noack", &manifest(&port, 3, "", false));
    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    // Detection takes 8 acknowledgement timeouts (100 ms each, overlapping).
    let settle = Instant::now() + Duration::from_millis(500);
    while Instant::now() < settle {
        send(&mut ctl, &[("leg/p1", 0.1)]);
        std::thread::sleep(Duration::from_millis(20));
    }
    // Frames each motor received against ticks the executor ran (a fresh stats message, then
    // the simulator's counters at once): one frame per motor per tick, neither a backlog nor
    // a stall waiting for acknowledgements that never come.
    let mut stats = StatsSubscriber::new(&bus, "leg").unwrap();
    let mut snap = || {
        let seq = stats.latest().unwrap().map_or(0, |s| s.seq);
        let st = eventually(2, "fresh stats", || {
            stats.latest().unwrap().filter(|s| s.seq > seq)
        });
        let frames: Vec<u64> = (0..3).map(|i| node(&sim, i).frames_in).collect();
        (st.ticks, frames)
    };
    let (t0, f0) = snap();
    std::thread::sleep(Duration::from_secs(2));
    let (t1, f1) = snap();
    let ticks = (t1 - t0) as f64;
    for (i, (a, b)) in f0.iter().zip(&f1).enumerate() {
        let per_tick = (b - a) as f64 / ticks;
        assert!(
            (0.9..=1.1).contains(&per_tick),
            "motor {}: {per_tick} frames per tick over {ticks} ticks",
            i + 1
        );
    }
    let st = eventually(2, "stats", || stats.latest().unwrap());
    assert!(
        st.bus_errors >= 8,
        "the missing acknowledgements are counted: {st:?}"
    );
    exec.stop_ok();
}

#[test]
fn an_odrive_axis_is_brought_to_closed_loop_where_it_is_and_idled_at_stop() {
    let (sim, port) = adapter("odrive", &[], false, &[4]);
    let text = format!(
        "system = \"edge\"\n[subsystems.leg]\nrate_hz = 250\n\
         [subsystems.leg.hardware.can0]\nkind = \"slcan\"\nport = \"{port}\"\n\
         [subsystems.leg.protocols.can]\nkind = \"can_motors\"\nhardware = \"can0\"\ntimeout_us = 3000\n\
         [subsystems.leg.devices.ax]\nkind = \"odrive_axis\"\nprotocol = \"can\"\nid = 4\n\
         [subsystems.leg.states.p]\ndevice = \"ax\"\nchannel = \"position\"\nwritable = true\nmin = -3\nmax = 3\n\
         [subsystems.leg.states.e]\ndevice = \"ax\"\nchannel = \"enable\"\nwritable = true\n"
    );
    assert!(!node(&sim, 0).enabled, "the axis starts idle");
    let (mut exec, d) = start("odrive", &text);
    assert!(node(&sim, 0).enabled, "closed loop after bring-up");
    assert!(node(&sim, 0).position.abs() < 1e-6, "nothing moved");
    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    let mut p = Watch::new(&bus, "leg/p");
    send(&mut ctl, &[("leg/p", 1.0)]);
    p.until(2.0, "moved", |s| (s.value - 1.0).abs() < 0.01);
    exec.stop_confirmed(1);
    assert!(!node(&sim, 0).enabled, "idle after the stop");
}

#[test]
fn the_adapter_unplugged_and_plugged_back_resumes_without_a_restart() {
    let (sim, port) = adapter("canplug", &[1], false, &[]);
    let (mut exec, d) = start("canplug", &manifest(&port, 1, "", false));
    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    let mut p1 = Watch::new(&bus, "leg/p1");
    send(&mut ctl, &[("leg/p1", 0.5)]);
    p1.until(2.0, "moved", |s| (s.value - 0.5).abs() < 0.01);
    sim.unplug();
    p1.until(1.0, "stale", |s| s.status & status::STALE != 0);
    exec.wait_log(2, "vanished");
    std::thread::sleep(Duration::from_millis(300));
    sim.replug().unwrap();
    let back = Instant::now();
    let s = p1.until(3.0, "fresh", |s| {
        s.status & (status::STALE | status::DISABLED) == 0
    });
    assert!(
        back.elapsed() < Duration::from_secs(1),
        "{:?}",
        back.elapsed()
    );
    assert!((s.value - 0.5).abs() < 0.02, "{s:?}");
    assert!(node(&sim, 0).enabled);
    send(&mut ctl, &[("leg/p1", -0.5)]);
    p1.until(2.0, "obeys again", |s| (s.value + 0.5).abs() < 0.01);
    exec.stop_ok();
}

#[test]
fn damp_keeps_motor_mode_with_no_stiffness_after_a_trip() {
    let (sim, port) = adapter("damp", &[1], false, &[]);
    let text = manifest(&port, 1, "watchdog_ms = 100", false).replace(
        "kp = 20.0\nkd = 1.0\n",
        "kp = 20.0\nkd = 1.0\nsafe_action = \"damp\"\nsafe_value = 0.5\n",
    );
    let (mut exec, d) = start("damp", &text);
    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    let mut p1 = Watch::new(&bus, "leg/p1");
    send(&mut ctl, &[("leg/p1", 0.3)]);
    // Silence: the watchdog trips it to damping: still in motor mode (not disabled), tripped.
    let s = p1.until(2.0, "tripped", |s| s.status & status::TRIPPED != 0);
    assert_eq!(
        s.status & status::DISABLED,
        0,
        "damping keeps motor mode: {s:?}"
    );
    std::thread::sleep(Duration::from_millis(100));
    assert!(node(&sim, 0).enabled);
    // Tripped: a setpoint is refused.
    send(&mut ctl, &[("leg/p1", -0.3)]);
    p1.until(1.0, "refused", |s| s.status & status::REJECTED != 0);
    // A stop carries out the declared action too: damping, confirmed by the motor's answer.
    exec.stop_confirmed(1);
    assert!(node(&sim, 0).enabled, "damping after the stop, as declared");
}

/// The host's frames to MIT motor `id`, in order.
fn frames_to(sim: &Running<SlcanAdapterSim>, id: u16) -> Vec<Vec<u8>> {
    let want = embedded_can::Id::Standard(embedded_can::StandardId::new(id).unwrap());
    sim.sim()
        .log()
        .iter()
        .filter(|(host, f)| *host && f.id() == want)
        .map(|(_, f)| f.data().to_vec())
        .collect()
}

/// The `cubemars_ak` kind, an AK70-10 (±25 N·m, where the default AK80-9 has ±18), against a
/// simulated motor with the AK70-10's ranges: enabled from where it is, a position setpoint
/// reached, a feed-forward beyond the model's torque range sent as the model's maximum, and
/// the stop confirmed on the wire.
#[test]
fn a_cubemars_ak70_10_reaches_its_setpoint_is_bounded_by_its_model_and_stops_on_the_wire() {
    let model = AkModel::Ak70_10;
    let limits = model.limits();
    let (sim, port) = adapter_of("ak70", limits, &[1], false, &[]);
    let text = manifest(&port, 1, "", true)
        .replace(
            "kind = \"mit_motor\"",
            "kind = \"cubemars_ak\"\nmodel = \"ak70-10\"",
        )
        .replace(
            "kind = \"can_motors\"",
            "kind = \"can_motors\"\nmodel = \"ak70-10\"",
        );
    let (mut exec, d) = start("ak70", &text);
    assert!(node(&sim, 0).enabled, "in motor mode");
    assert_eq!(node(&sim, 0).ignored, 0, "no command before enter");
    exec.wait_log(5, "is enabled: CubeMars AK70-10");

    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    // A position setpoint, reached.
    eventually(10, "at 0.5 rad", || {
        send(&mut ctl, &[("leg/p1", 0.5)]);
        std::thread::sleep(Duration::from_millis(20));
        ((node(&sim, 0).position - 0.5).abs() < 0.02).then_some(())
    });
    // The torque feed-forward of the last command on the wire after writing `t` for 200 ms.
    let mut torque_sent = |t: f64| {
        for _ in 0..10 {
            send(&mut ctl, &[("leg/p1", 0.5), ("leg/torque1", t)]);
            std::thread::sleep(Duration::from_millis(20));
        }
        frames_to(&sim, 1)
            .iter()
            .rev()
            .find_map(|f| match decode_command(f, &limits) {
                Ok(MotorCommand::Control(c)) => Some(c.t),
                _ => None,
            })
            .expect("a control command")
    };
    // 20 N·m: inside the AK70-10's ±25, beyond the AK80-9's ±18; it goes out as 20, so the
    // stage quantises with the AK70-10's ranges.
    let t = torque_sent(20.0);
    assert!((t - 20.0).abs() < 0.02, "{t}");
    assert!(20.0 > mit_limits("ak80-9").unwrap().t.max);
    // 100 N·m: beyond the model's range, clamped to its +25 (all ones on the wire).
    assert_eq!(torque_sent(100.0), limits.t.max);
    assert_eq!(torque_sent(-100.0), limits.t.min);

    exec.stop_confirmed(1);
    std::thread::sleep(Duration::from_millis(100));
    assert!(!node(&sim, 0).enabled, "out of motor mode");
    let to_it = frames_to(&sim, 1);
    assert_eq!(
        decode_command(to_it.last().expect("frames"), &limits),
        Ok(MotorCommand::Special(SpecialCommand::Exit)),
        "the last frame is the exit frame"
    );
}
