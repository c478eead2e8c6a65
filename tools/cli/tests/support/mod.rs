//! Shared by the CLI integration tests: the `conductor` binary, simulated executors (from
//! `conductor-examples`), background children killed on drop, and the test venv's Python.
#![allow(dead_code)]

use std::path::Path;
use std::path::PathBuf;
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use conductor_bus::{Domain, StateMeta, StateSpec};
use conductor_examples::sim::{self, SimHandle, SimSpec};
use serde_json::Value;

pub use conductor_testkit::workspace;

/// Runs `conductor bench ARGS --no-progress -o <a fresh directory>`; fails with its stderr
/// unless it succeeded. Returns the directory and what the run printed.
pub fn bench(tag: &str, args: &[&str]) -> (PathBuf, Output) {
    let out = std::env::temp_dir().join(format!("conductor-{tag}-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let run = Command::new(env!("CARGO_BIN_EXE_conductor"))
        .arg("bench")
        .args(args)
        .args(["--no-progress", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "conductor bench {} failed:\n{}",
        args.join(" "),
        String::from_utf8_lossy(&run.stderr)
    );
    (out, run)
}

/// `conductor --domain <d>`.
pub fn conductor(d: &Domain) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_conductor"));
    c.arg("--domain").arg(d.name());
    c
}

/// Runs to completion; panics with stderr when it fails.
pub fn ok(cmd: &mut Command) -> String {
    String::from_utf8(conductor_testkit::run_ok(cmd).stdout).unwrap()
}

/// Runs to completion and expects failure; returns stderr.
pub fn fails(cmd: &mut Command) -> String {
    let out: Output = cmd.output().expect("run conductor");
    assert!(
        !out.status.success(),
        "{cmd:?} should have failed; stdout: {}",
        String::from_utf8_lossy(&out.stdout)
    );
    String::from_utf8(out.stderr).unwrap()
}

/// A state spec.
pub fn state(
    index: u32,
    name: &str,
    units: &str,
    writable: bool,
    (min, max): (f64, f64),
    rate: f64,
    device: &str,
) -> StateSpec {
    StateSpec::new(
        name,
        StateMeta {
            index,
            units: units.into(),
            writable,
            rate_hz: rate,
            min,
            max,
            device: device.into(),
        },
    )
}

/// A simulated executor that holds whatever is commanded.
pub fn hold_sim(d: &Domain, subsystem: &str, rate: f64, states: Vec<StateSpec>) -> SimHandle {
    let n = states.len();
    sim::spawn(
        d,
        SimSpec {
            subsystem: subsystem.into(),
            rate_hz: rate,
            states,
            initial: vec![0.0; n],
            stats_hz: 10.0,
        },
        sim::hold,
    )
    .expect("simulator")
}

/// A fresh domain named after `tag`, with the simulated subsystem `leg` holding `states(rate)`
/// at `rate` Hz in it (keep the handle: dropping it stops the simulator).
pub fn domain_with_leg(
    tag: &str,
    rate: f64,
    states: fn(f64) -> Vec<StateSpec>,
) -> (Domain, SimHandle) {
    let d = Domain::unique(tag).unwrap();
    let sim = hold_sim(&d, "leg", rate, states(rate));
    (d, sim)
}

/// `conductor record <args> --no-progress -o <file>` on `d`.
pub fn record(d: &Domain, args: &[&str], file: &Path) -> Command {
    let mut cmd = conductor(d);
    cmd.arg("record")
        .args(args)
        .args(["--no-progress", "-o"])
        .arg(file);
    cmd
}

/// A child process killed (by its pid) when dropped, with its stdout lines on a channel.
pub struct Bg {
    pub child: Child,
    pub lines: mpsc::Receiver<String>,
}

impl Bg {
    pub fn spawn(cmd: &mut Command) -> Self {
        let (child, lines) = conductor_testkit::spawn_with_lines(cmd.stderr(Stdio::piped()));
        Self { child, lines }
    }

    /// Stdout lines up to and including the first that satisfies `pred`.
    pub fn until(&mut self, timeout: Duration, pred: impl Fn(&str) -> bool) -> Vec<String> {
        let end = Instant::now() + timeout;
        let mut seen = Vec::new();
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            match self.lines.recv_timeout(left) {
                Ok(l) => {
                    let done = pred(&l);
                    seen.push(l);
                    if done {
                        return seen;
                    }
                }
                Err(_) => break,
            }
        }
        if let Ok(Some(status)) = self.child.try_wait() {
            let mut err = String::new();
            use std::io::Read;
            if let Some(mut e) = self.child.stderr.take() {
                let _ = e.read_to_string(&mut err);
            }
            panic!("child exited ({status}) before the line; stdout {seen:?}; stderr: {err}");
        }
        panic!("timed out waiting for a line; got {seen:?}");
    }

    /// Sends SIGINT (to this child only) and waits; returns (success, stderr).
    pub fn interrupt(self) -> (bool, String) {
        // SAFETY: kill(2) on the pid of a child we spawned and have not reaped.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGINT) };
        self.finish()
    }

    /// Waits for exit (at most 30 s); returns (success, stderr).
    pub fn finish(mut self) -> (bool, String) {
        let end = Instant::now() + Duration::from_secs(30);
        let status = loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                break s;
            }
            assert!(Instant::now() < end, "child did not exit");
            std::thread::sleep(Duration::from_millis(10));
        };
        let mut err = String::new();
        use std::io::Read;
        self.child
            .stderr
            .take()
            .unwrap()
            .read_to_string(&mut err)
            .unwrap();
        (status.success(), err)
    }
}

impl Drop for Bg {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub use conductor_testkit::python;

/// A fresh temporary directory for one test.
pub fn tempdir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!(
        "conductor-cli-{tag}-{}-{}",
        std::process::id(),
        conductor_bus::monotonic_ns()
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `n` consecutive free UDP ports on 127.0.0.1 (free when checked; the gateway binds them next).
pub fn free_udp_ports(n: u16) -> u16 {
    // Different processes and different tests of one process start at different places.
    static CALLS: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let seed = std::process::id() % 997 * 23 + call * 401;
    for k in 0..200u32 {
        let base = (20000 + (seed + k * 97) % 40000) as u16;
        let socks: Vec<_> = (0..n)
            .map_while(|i| std::net::UdpSocket::bind(("127.0.0.1", base + i)).ok())
            .collect();
        if socks.len() == n as usize {
            return base;
        }
    }
    panic!("no block of {n} free UDP ports");
}

/// Adds, to a synthetic recording, the channel of state `subsystem/state` at `index` (rad,
/// writable, 100 Hz, limits ±3, device `d1`) in the documented layout, on `schema`.
pub fn add_state_channel<W: std::io::Write + std::io::Seek>(
    w: &mut mcap::Writer<W>,
    schema: u16,
    subsystem: &str,
    state: &str,
    index: u32,
) -> u16 {
    let md = StateMeta {
        index,
        units: "rad".into(),
        writable: true,
        rate_hz: 100.0,
        min: -3.0,
        max: 3.0,
        device: "d1".into(),
    }
    .strings(subsystem, state);
    let topic = conductor_cli::recording::topic(subsystem, state);
    w.add_channel(
        schema,
        &topic,
        conductor_cli::recording::MESSAGE_ENCODING,
        &md,
    )
    .unwrap()
}

/// Writes message `seq` of channel `ch` sampled (and published) at `t_ns`.
pub fn write_sample<W: std::io::Write + std::io::Seek>(
    w: &mut mcap::Writer<W>,
    ch: u16,
    seq: u64,
    t_ns: u64,
    body: &[u8],
) {
    let header = mcap::records::MessageHeader {
        channel_id: ch,
        sequence: seq as u32,
        log_time: t_ns,
        publish_time: t_ns,
    };
    w.write_to_known_channel(&header, body).unwrap();
}

/// Runs tests/python/check_mcap.py (official `mcap` reader + `jsonschema`) on a recording.
pub fn check_with_python(file: &Path) -> Value {
    let out = conductor_testkit::run_ok(
        Command::new(python())
            .arg(workspace().join("tools/cli/tests/python/check_mcap.py"))
            .arg(file),
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Three states of a leg at `rate`.
pub fn leg(rate: f64) -> Vec<conductor_bus::StateSpec> {
    vec![
        state(0, "knee", "rad", true, (-1.5, 2.0), rate, "dKnee"),
        state(1, "hip", "rad", true, (-1.0, 1.0), rate, "dHip"),
        state(2, "current", "A", false, (-5.0, 5.0), rate, ""),
    ]
}

/// A leg whose MIT-mode knee motor, on the simulated CAN bus, trips after 100 ms without a
/// command frame (`watchdog_ms`): once a first frame armed the watchdog and no controller sends
/// frames, the executor refuses the knee's setpoints until `knee_enable` is set again
/// (tests/refusals.rs, tests/view.rs).
pub const TRIPPING_LEG: &str = r#"
system = "tripping-leg"

[subsystems.leg]
rate_hz = 200
watchdog_ms = 100     # no command frame for 0.1 s: the motor leaves motor mode (tripped)

[subsystems.leg.hardware.can]
kind = "can_sim"
mit = "1"

[subsystems.leg.protocols.mit]
kind = "can_motors"
hardware = "can"

[subsystems.leg.devices.knee]
kind = "mit_motor"
protocol = "mit"
id = 1
kp = 20.0
kd = 1.0
safe_action = "torque_off"

[subsystems.leg.states.knee]
device = "knee"
channel = "position"
units = "rad"
writable = true
min = -1.0
max = 1.0

[subsystems.leg.states.knee_kp]
device = "knee"
channel = "kp"
writable = true
min = 0.0
max = 50.0

[subsystems.leg.states.knee_enable]
device = "knee"
channel = "enable"
writable = true
min = 0
max = 1
"#;
