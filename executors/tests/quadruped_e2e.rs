//! End to end over CAN: the quadruped-leg manifest (deploy/quadruped-leg-mit-slcan.toml) run by
//! `conductor-executor` against the SLCAN adapter simulator on a pseudo-terminal, with three
//! MIT-mode motors behind it. The executor talks SLCAN (CANable dialect) through the real serial
//! transport; the test checks the publish rate, one command frame per motor per tick, that a
//! command frame moves all three joints, and that SIGTERM leaves the motors out of motor mode.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use conductor_bus::{Bus, Controller, Domain, StateSubscriber};
use conductor_devices::protocol_stage::mit_limits;
use conductor_devices::sim::can_motors::MitMotorSim;
use conductor_devices::sim::runner::{run_slcan, Endpoint, Pty};
use conductor_devices::sim::slcan_adapter::SlcanAdapterSim;
use conductor_protocols::slcan::Dialect;

const JOINTS: [&str; 3] = ["hip_ab", "hip_fl", "knee"];

/// The executor process; SIGTERM (an orderly stop) when dropped, so a failing test leaves
/// nothing running.
struct Exec(Child);

impl Exec {
    fn stop(&mut self) -> bool {
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(self.0.id() as i32),
            nix::sys::signal::Signal::SIGTERM,
        );
        self.0.wait().is_ok_and(|s| s.success())
    }
}

impl Drop for Exec {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            self.stop();
        }
    }
}

#[test]
fn quadruped_leg_on_the_slcan_simulator() {
    let pty = Pty::open(None).unwrap();
    let port = pty.path().to_string();
    let nodes = MitMotorSim::bus(1..=3, mit_limits("ak80-9").unwrap());
    let sim = run_slcan(
        Endpoint::Pty(pty),
        SlcanAdapterSim::new(Dialect::CANABLE, nodes),
    );

    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let text = std::fs::read_to_string(root.join("deploy/quadruped-leg-mit-slcan.toml")).unwrap();
    assert!(text.contains("port = \"/tmp/conductor-can0\""));
    // Only the port changes, and the watchdog is relaxed: on a loaded 2-CPU machine the test's
    // own frames can be late, and this test is about behaviour, not timing.
    assert!(text.contains("watchdog_ms = 100 "));
    let text = text
        .replace(
            "port = \"/tmp/conductor-can0\"",
            &format!("port = \"{port}\""),
        )
        .replace("watchdog_ms = 100 ", "watchdog_ms = 5000 ");
    let manifest =
        std::env::temp_dir().join(format!("conductor-can-e2e-{}.toml", std::process::id()));
    std::fs::write(&manifest, text).unwrap();

    let d = Domain::unique("can-e2e").unwrap();
    // Normal scheduling: this test checks behaviour, not timing.
    let mut exec = Exec(
        Command::new(env!("CARGO_BIN_EXE_conductor-executor"))
            .arg("--manifest")
            .arg(&manifest)
            .args(["--subsystem", "front_left", "--domain", d.name(), "--no-rt"])
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut out = BufReader::new(exec.0.stdout.take().unwrap());
    let mut line = String::new();
    while !line.contains("READY") {
        line.clear();
        assert!(
            out.read_line(&mut line).unwrap() > 0,
            "executor exited before READY"
        );
    }
    let frames_in = |sim: &conductor_devices::sim::runner::Running<SlcanAdapterSim>| {
        sim.sim()
            .nodes()
            .iter()
            .map(|n| n.snapshot().frames_in)
            .collect::<Vec<_>>()
    };

    let bus = Bus::open(&d, "e2e").unwrap();
    let mut subs: Vec<StateSubscriber> = JOINTS
        .iter()
        .map(|j| StateSubscriber::with_buffer(&bus, &format!("front_left/{j}"), 1024).unwrap())
        .collect();
    let mut ctl = Controller::new(&bus);
    // A start pose inside the limits (the knee's exclude 0), refreshed while measuring rates.
    let pose = [0.0, 0.3, -1.0];
    let hold = |ctl: &mut Controller, p: &[f64; 3]| {
        for (j, v) in JOINTS.iter().zip(p) {
            ctl.add_ctrl(&format!("front_left/{j}"), *v).unwrap();
        }
        ctl.send_ctrl().unwrap();
    };
    hold(&mut ctl, &pose);
    std::thread::sleep(Duration::from_millis(300));
    for s in subs.iter_mut() {
        while s.receive().unwrap().is_some() {}
    }
    let before = frames_in(&sim);
    let t0 = Instant::now();
    let mut counts = [0u32; 3];
    while t0.elapsed() < Duration::from_secs(1) {
        for (i, s) in subs.iter_mut().enumerate() {
            while s.receive().unwrap().is_some() {
                counts[i] += 1;
            }
        }
        hold(&mut ctl, &pose);
        std::thread::sleep(Duration::from_millis(20));
    }
    let window = t0.elapsed().as_secs_f64();
    let after = frames_in(&sim);
    for (j, c) in JOINTS.iter().zip(counts) {
        // 500 Hz; without real-time scheduling on a 2-CPU machine, allow late ticks (the
        // executor counts them as misses) but not more samples than ticks.
        assert!(
            (350..=510).contains(&c),
            "{j}: {c} samples in {window:.2} s"
        );
    }
    for (i, j) in JOINTS.iter().enumerate() {
        // One command frame per motor per tick, whatever was written: frames ≈ samples.
        let frames = after[i] - before[i];
        let per_s = frames as f64 / window;
        assert!(
            (350.0..=520.0).contains(&per_s),
            "{j}: {frames} frames in {window:.2} s"
        );
    }

    // One command frame moves all three joints (kp 20, kd 1 on the simulated inertia).
    let targets = [0.2, -0.4, -1.5];
    let end = Instant::now() + Duration::from_millis(600);
    while Instant::now() < end {
        hold(&mut ctl, &targets);
        std::thread::sleep(Duration::from_millis(20));
    }
    {
        let s = sim.sim();
        for (i, n) in s.nodes().iter().enumerate() {
            let snap = n.snapshot();
            assert!(snap.enabled, "{} in motor mode", JOINTS[i]);
            assert!(
                (snap.position - targets[i]).abs() < 0.02,
                "{}: {}",
                JOINTS[i],
                snap.position
            );
        }
    }
    for (i, s) in subs.iter_mut().enumerate() {
        let mut last = None;
        while let Some(x) = s.receive().unwrap() {
            last = Some(x.value);
        }
        assert!((last.unwrap() - targets[i]).abs() < 0.02, "{}", JOINTS[i]);
    }

    // SIGTERM: the orderly stop puts every motor in its declared safe action (torque off).
    assert!(exec.stop(), "executor exited with an error");
    std::thread::sleep(Duration::from_millis(50));
    for (i, n) in sim.sim().nodes().iter().enumerate() {
        assert!(
            !n.snapshot().enabled,
            "{} still in motor mode after stop",
            JOINTS[i]
        );
    }
    let _ = std::fs::remove_file(&manifest);
}
