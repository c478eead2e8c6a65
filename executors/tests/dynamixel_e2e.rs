//! End to end with real processes: the mini-Hubo right leg manifest
//! (deploy/minihubo-right-leg-dxl.toml) run by `conductor-executor` against the Dynamixel bus
//! simulator on a pseudo-terminal. All 6 joint positions are published at 250 Hz; a command frame
//! of 6 setpoints moves all 6 servos with ONE SYNC WRITE, counted by the simulator; and the bytes
//! on the wire per cycle are the protocol minimum for what the manifest reads and writes.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use conductor_bus::{Bus, Controller, Domain, StateSubscriber};
use conductor_devices::sim::dxl::DxlSimConfig;
use conductor_devices::sim::fault::FaultConfig;
use conductor_devices::sim::runner::{run_dxl, Endpoint, Pty};

const JOINTS: [&str; 6] = ["RHY", "RHR", "RHP", "RKP", "RAP", "RAR"];

struct Exec(Child);

impl Drop for Exec {
    fn drop(&mut self) {
        // SIGTERM: an orderly stop (devices to their safe state); the test waits for it.
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(self.0.id() as i32),
            nix::sys::signal::Signal::SIGTERM,
        );
        let _ = self.0.wait();
    }
}

#[test]
fn minihubo_leg_on_the_dynamixel_simulator() {
    // The bus: 6 XM430 servos on a pty, in this process, baud-accurate reply timing.
    let pty = Pty::open(None).unwrap();
    let port = pty.path().to_string();
    let sim = run_dxl(
        Endpoint::Pty(pty),
        DxlSimConfig::default(),
        FaultConfig::default(),
        FaultConfig::default(),
    );

    // The shipped manifest; only the hardware's port changes (to this test's pty).
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let text = std::fs::read_to_string(root.join("deploy/minihubo-right-leg-dxl.toml")).unwrap();
    assert!(text.contains("port = \"/tmp/conductor-dxl0\""));
    let text = text.replace(
        "port = \"/tmp/conductor-dxl0\"",
        &format!("port = \"{port}\""),
    );
    let manifest =
        std::env::temp_dir().join(format!("conductor-dxl-e2e-{}.toml", std::process::id()));
    std::fs::write(&manifest, text).unwrap();

    let d = Domain::unique("dxl-e2e").unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_conductor-executor"))
        .arg("--manifest")
        .arg(&manifest)
        .args(["--subsystem", "right_leg", "--domain", d.name()])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let exec = Exec(child);
    let mut line = String::new();
    while !line.contains("READY") {
        line.clear();
        assert!(
            out.read_line(&mut line).unwrap() > 0,
            "executor exited before READY"
        );
    }

    let bus = Bus::open(&d, "e2e").unwrap();
    let mut subs: Vec<StateSubscriber> = JOINTS
        .iter()
        .map(|j| StateSubscriber::with_buffer(&bus, &format!("right_leg/{j}"), 1024).unwrap())
        .collect();
    // Publication rate: every joint, one sample per 4 ms tick.
    std::thread::sleep(Duration::from_millis(200));
    for s in subs.iter_mut() {
        while s.receive().unwrap().is_some() {}
    }
    let window = Duration::from_secs(1);
    let t0 = Instant::now();
    let mut counts = [0u32; 6];
    while t0.elapsed() < window {
        for (i, s) in subs.iter_mut().enumerate() {
            while let Some(x) = s.receive().unwrap() {
                counts[i] += 1;
                assert_eq!(x.value, 0.0, "servos at rest in the middle (2048)");
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    for (j, c) in JOINTS.iter().zip(counts) {
        // 250 ± 3 (window edges, scheduling on a 2-CPU machine).
        assert!((247..=253).contains(&c), "{j}: {c} samples in 1 s");
    }

    // One frame of six setpoints → ONE SYNC WRITE on the wire.
    let before = sim.sim().stats();
    let targets = [0.25, -0.25, 0.5, 1.0, -0.5, 0.125];
    let mut ctl = Controller::new(&bus);
    for (j, v) in JOINTS.iter().zip(targets) {
        ctl.add_ctrl(&format!("right_leg/{j}"), v).unwrap();
    }
    assert_eq!(ctl.send_ctrl().unwrap(), 6);
    // Less than the manifest's 500 ms watchdog, whose hold would be the next SYNC WRITE.
    std::thread::sleep(Duration::from_millis(300));
    let after = sim.sim().stats();
    assert_eq!(
        after.sync_write - before.sync_write,
        1,
        "one SYNC WRITE moved all 6"
    );
    // 10 + addr/len 4 + 6 × (id + 4 bytes).
    assert_eq!(after.sync_write_bytes - before.sync_write_bytes, 44);
    {
        let s = sim.sim();
        for (id, v) in (1..=6u8).zip(targets) {
            let raw = (v / (2.0 * std::f64::consts::PI / 4096.0)).round() as i32 + 2048;
            assert_eq!(s.servo(id).unwrap().goal_position(), raw);
            // ≥ 0.29 s = 5.8 τ after a step of at most 652 pulses: within 652·e^-5.8 ≈ 2.
            assert!((s.servo(id).unwrap().present_position() - raw).abs() <= 3);
        }
    }
    for (i, s) in subs.iter_mut().enumerate() {
        let mut last = None;
        while let Some(x) = s.receive().unwrap() {
            last = Some(x.value);
        }
        let v = last.expect("samples after the frame");
        // The last published sample is at most a tick older than the servo's state above.
        let pulse = 2.0 * std::f64::consts::PI / 4096.0;
        assert!((v - targets[i]).abs() <= 4.0 * pulse, "{}: {v}", JOINTS[i]);
    }

    // The wire, per cycle: SYNC READ of Present Position = 10 + 4 + 6 bytes out, 6 × (11 + 4)
    // back (positions near 2048 contain no FF FF FD: no stuffing); the only other packets are
    // the SYNC WRITEs counted above.
    drop(exec);
    let s = sim.sim().stats();
    assert_eq!(
        s.packets_in,
        s.sync_read + s.sync_write,
        "nothing else was sent: {s:?}"
    );
    assert_eq!(s.bytes_in, s.sync_read * 20 + s.sync_write_bytes, "{s:?}");
    assert_eq!(s.bytes_out, s.sync_read * 90, "{s:?}");
    assert_eq!(s.discarded_in, 0);
    let _ = std::fs::remove_file(&manifest);
}
