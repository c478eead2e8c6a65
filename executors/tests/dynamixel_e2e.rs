//! End to end with real processes: the mini-Hubo right leg manifest
//! (deploy/minihubo-right-leg-dxl.toml) run by `conductor-executor` against the Dynamixel bus
//! simulator on a pseudo-terminal, whose servos power up as real X-series servos do: torque off,
//! goals ignored until enabled.
//!
//! * Bring-up: every servo is pinged, its configuration read, and its Goal Position set to
//!   where it is BEFORE its torque is enabled (checked on the simulator's instruction log);
//!   nothing moved.
//! * All 6 joint positions are published at 250 Hz; a command frame of 6 setpoints moves all 6
//!   servos with ONE SYNC WRITE, counted by the simulator.
//! * In steady state the bytes on the wire per cycle are the protocol minimum for what the
//!   manifest reads and writes.
//! * SIGTERM: each servo's hold is written and read back; the executor says so and exits 0.

mod support;

use std::time::{Duration, Instant};

use conductor_bus::{Bus, Controller, Domain, StateSubscriber};
use conductor_devices::sim::dxl::DxlSimConfig;
use conductor_devices::sim::runner::{run_dxl_faultless, Endpoint, Pty};
use support::edge::{shipped, Exec};

const JOINTS: [&str; 6] = ["RHY", "RHR", "RHP", "RKP", "RAP", "RAR"];

/// Torque Enable and Goal Position in the X-series control table.
const TORQUE: u16 = 64;
const GOAL: u16 = 116;

#[test]
fn minihubo_leg_on_the_dynamixel_simulator() {
    // The bus: 6 XM430 servos on a pty, in this process, baud-accurate reply timing; they power
    // up with torque off, as real servos do.
    let pty = Pty::open(None).unwrap();
    let port = pty.path().to_string();
    let cfg = DxlSimConfig::default();
    assert!(!cfg.torque_on, "the simulator powers up like the hardware");
    let sim = run_dxl_faultless(Endpoint::Pty(pty), cfg);
    sim.sim().start_log();

    // The shipped manifest; only the hardware's port changes (to this test's pty).
    let manifest = shipped(
        "minihubo-right-leg-dxl.toml",
        &[(
            "port = \"/tmp/conductor-dxl0\"",
            &format!("port = \"{port}\""),
        )],
    );
    let d = Domain::unique("dxl-e2e").unwrap();
    let exec =
        Exec::start(&manifest, "right_leg", &d).unwrap_or_else(|(s, log)| panic!("{s}: {log:#?}"));

    // Bring-up, on the wire: per servo a PING, then Goal Position = its present position
    // (2048), then Torque Enable = 1, in that order.
    {
        let s = sim.sim();
        let log = s.instruction_log();
        for id in 1..=6u8 {
            let mine: Vec<_> = log.iter().filter(|r| r.1 == id).collect();
            let ping = mine.iter().position(|r| r.2 == 0x01).expect("pinged");
            let torque_on = mine
                .iter()
                .position(|r| r.3 == TORQUE && r.4 == [1])
                .unwrap_or_else(|| panic!("servo {id}: torque never enabled: {mine:?}"));
            let goal = mine
                .iter()
                .position(|r| r.3 == GOAL && r.4 == 2048i32.to_le_bytes())
                .unwrap_or_else(|| panic!("servo {id}: goal never set where it is: {mine:?}"));
            assert!(ping < goal && goal < torque_on, "servo {id}: {mine:?}");
            let servo = s.servo(id).unwrap();
            assert!(servo.torque_on(), "servo {id}");
            assert_eq!(servo.present_position(), 2048, "servo {id}: nothing moved");
        }
    }
    // Each servo's bring-up is reported (stderr is read by another thread than READY: wait).
    let enabled = |log: &[String]| {
        log.iter()
            .filter(|l| l.contains("is enabled") && l.contains("xm430-w350 (model 1020)"))
            .count()
    };
    let end = Instant::now() + Duration::from_secs(2);
    while enabled(&exec.log()) < 6 && Instant::now() < end {
        std::thread::sleep(Duration::from_millis(10));
    }
    let log = exec.log();
    assert_eq!(
        enabled(&log),
        6,
        "each servo's bring-up is reported: {log:#?}"
    );

    let bus = Bus::open(&d, "e2e").unwrap();
    let mut subs: Vec<StateSubscriber> = JOINTS
        .iter()
        .map(|j| StateSubscriber::with_buffer(&bus, &format!("right_leg/{j}"), 1024).unwrap())
        .collect();
    // Publication: every joint on every tick the executor ran, none lost. Checked against the
    // samples' sequence and tick numbers, not the wall clock: on a loaded machine the executor
    // may miss deadlines and a reply may come a cycle late (the sample then repeats its bus
    // cycle's tick), but every tick that runs publishes all six joints.
    std::thread::sleep(Duration::from_millis(200));
    for s in subs.iter_mut() {
        while s.receive().unwrap().is_some() {}
    }
    let steady = sim.sim().stats();
    let window = Duration::from_secs(1);
    let t0 = Instant::now();
    let mut ticks: [Vec<u64>; 6] = Default::default();
    let mut seqs: [Vec<u64>; 6] = Default::default();
    while t0.elapsed() < window {
        for (i, s) in subs.iter_mut().enumerate() {
            while let Some(x) = s.receive().unwrap() {
                ticks[i].push(x.tick);
                seqs[i].push(x.seq);
                assert_eq!(x.value, 0.0, "servos at rest in the middle (2048)");
                assert_eq!(x.status & conductor_bus::status::DISABLED, 0, "enabled");
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let n0 = seqs[0].len();
    for (i, j) in JOINTS.iter().enumerate() {
        let n = seqs[i].len();
        assert!(n >= 10, "{j}: only {n} samples in 1 s");
        assert!(
            seqs[i].windows(2).all(|w| w[1] == w[0] + 1),
            "{j}: a sample was lost"
        );
        assert!(
            ticks[i].windows(2).all(|w| w[0] <= w[1]),
            "{j}: a tick went back"
        );
        // The window's edges may cut one tick's publication between joints.
        assert!(n.abs_diff(n0) <= 1, "{j}: {n} samples, {} {n0}", JOINTS[0]);
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

    // The wire in steady state, per cycle: SYNC READ of Present Position = 10 + 4 + 6 bytes
    // out, 6 × (11 + 4) back (positions near 2048 contain no FF FF FD: no stuffing); the only
    // other packet is the SYNC WRITE counted above.
    let s = sim.sim().stats();
    let (packets, reads) = (
        s.packets_in - steady.packets_in,
        s.sync_read - steady.sync_read,
    );
    let writes = s.sync_write - steady.sync_write;
    assert_eq!(packets, reads + writes, "nothing else was sent: {s:?}");
    assert_eq!(writes, 1);
    assert_eq!(
        s.bytes_in - steady.bytes_in,
        reads * 20 + (s.sync_write_bytes - steady.sync_write_bytes),
        "{s:?}"
    );
    assert_eq!(s.bytes_out - steady.bytes_out, reads * 90, "{s:?}");
    assert_eq!(s.discarded_in, 0);

    // SIGTERM: every servo holds where it is, read back before the executor says so.
    let mut exec = exec;
    exec.stop_confirmed(6);
    {
        let s = sim.sim();
        for (id, v) in (1..=6u8).zip(targets) {
            let servo = s.servo(id).unwrap();
            assert!(servo.torque_on(), "hold keeps torque on");
            let raw = (v / (2.0 * std::f64::consts::PI / 4096.0)).round() as i32 + 2048;
            assert!(
                (servo.goal_position() - raw).abs() <= 3,
                "holds where it is"
            );
        }
    }
    // An independent witness: ROBOTIS' DynamixelSDK opens the same port after the executor
    // exited and reads what each servo holds: torque on, no error, its goal where it is.
    let script = conductor_testkit::workspace().join("devices/tests/python/dxl_sdk_state.py");
    let out = conductor_testkit::run_ok(
        std::process::Command::new(conductor_testkit::python())
            .arg(&script)
            .arg(&port)
            .arg("1,2,3,4,5,6"),
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let rows: Vec<Vec<i64>> = text
        .lines()
        .map(|l| l.split_whitespace().map(|x| x.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 6, "{text}");
    for (row, id) in rows.iter().zip(1..) {
        let [rid, torque, hw, goal, present] = row[..] else {
            panic!("{text}")
        };
        assert_eq!((rid, torque, hw), (id, 1, 0), "servo {id}: {text}");
        assert!(
            (goal - present).abs() <= 3,
            "servo {id} holds where it is: {text}"
        );
    }
    let _ = std::fs::remove_file(&manifest);
}
