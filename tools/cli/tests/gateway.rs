//! Score gateways named in a manifest, launched next to an executor (real processes, each test
//! in its own domain, the `conductor` binary as both executor and gateway):
//!
//! * with the firmware in the emulator, a subscriber sees the board's ADC as
//!   `conductor/board/adc0`; a SIGKILLed gateway is restarted and samples resume; the orderly
//!   stop ends every process with status 0;
//! * with no board (a path that does not exist, a PTY nobody answers) the executor starts and
//!   runs anyway, the gateways wait (not ready, not restarted) and stop cleanly;
//! * `conductor launch` itself, SIGTERMed while its gateway waits: exit 0, nothing left running.
//!
//! The emulator test needs the firmware ELF and the harness (see score/firmware/README.md); it
//! fails with a message saying how to get them.

mod support;

use std::os::fd::{FromRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::time::Duration;

use conductor_bus::{Bus, Domain, StateSubscriber};
use conductor_executor::launcher::{ExecutorInfo, Launch, LaunchOptions, ProcessKind};
use score_firmware_tools::emulator::{fresh_pty_paths, Emulator};
use score_firmware_tools::port::Port;
use support::*;

const WAIT: Duration = Duration::from_secs(30);
const CONDUCTOR: &str = env!("CARGO_BIN_EXE_conductor");

/// One simulated subsystem `sim` (a 100 Hz sine) and the given gateway tables.
fn manifest(tag: &str, gateways: &str) -> PathBuf {
    let text = format!(
        r#"
system = "gwtest"

[subsystems.sim]
rate_hz = 100
hardware.wave.kind = "sine"
protocols.p = {{ kind = "sim", hardware = "wave" }}
devices.d = {{ kind = "sim", protocol = "p", id = 1 }}
states.s.device = "d"

{gateways}
"#
    );
    let path = tempdir(tag).join("robot.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// The `conductor` binary as executor and gateway, no real-time set-up, no signal handling
/// (the test harness owns this process), no summary.
fn options(d: &Domain) -> LaunchOptions {
    LaunchOptions {
        executor: CONDUCTOR.into(),
        executor_args: vec!["__executor".into()],
        gateway: CONDUCTOR.into(),
        gateway_args: vec!["__score-gateway".into()],
        domain: Some(d.name().into()),
        no_rt: true,
        quiet: true,
        handle_signals: false,
        ..LaunchOptions::default()
    }
}

fn info(launch: &Launch, name: &str) -> ExecutorInfo {
    launch
        .executors()
        .into_iter()
        .find(|e| e.subsystem == name)
        .unwrap()
}

/// Polls `f` until it returns Some, or panics after [`WAIT`].
fn eventually<T>(what: &str, f: impl FnMut() -> Option<T>) -> T {
    conductor_testkit::eventually(WAIT, what, f)
}

/// A subscriber to `name`, once its service exists.
fn subscribe(bus: &Bus, name: &str) -> StateSubscriber {
    eventually(&format!("state {name}"), || {
        StateSubscriber::new(bus, name).ok()
    })
}

/// Waits for a sample whose value satisfies `ok`.
fn wait_for(sub: &mut StateSubscriber, what: &str, ok: impl Fn(f64) -> bool) {
    let mut last = None;
    eventually(what, || {
        while let Some(s) = sub.receive().unwrap() {
            last = Some(s.value);
            if ok(s.value) {
                return Some(());
            }
        }
        None
    });
}

/// ADC volts as the board computes them: code · 3.3 / 4095 in f32 (< 1e-6 V of rounding).
fn volts(code: u16) -> f64 {
    code as f64 * 3.3 / 4095.0
}

fn kill(pid: u32, sig: i32) {
    // SAFETY: kill(2) on a pid of a process this test started (directly or via the launcher),
    // read just before.
    assert_eq!(unsafe { libc::kill(pid as i32, sig) }, 0, "kill {pid}");
}

fn alive(pid: u32) -> bool {
    // SAFETY: signal 0 only checks that the process exists.
    unsafe { libc::kill(pid as i32, 0) == 0 }
}

#[test]
fn a_score_gateway_in_the_manifest_publishes_is_restarted_and_stops_cleanly() {
    let (term, link) = fresh_pty_paths().unwrap();
    let mut emu = Emulator::start_at(&term, &link).unwrap_or_else(|e| panic!("{e}"));
    {
        let mut t = Port::open(&emu.term, WAIT).unwrap();
        emu.dtr("term", true).unwrap();
        t.read_until_suffix("$> ", WAIT).unwrap();
        t.write_all(b"adc 0 100\r").unwrap();
        let out = t.read_until_suffix("$> ", WAIT).unwrap();
        assert!(!out.contains("error"), "{out}");
    }
    let d = Domain::unique("gwlaunch").unwrap();
    let m = manifest(
        "gwlaunch",
        &format!(
            "[gateways.board]\nkind = \"score\"\nport = \"{}\"\nretry_ms = 50\n",
            link.display()
        ),
    );
    let launch = Launch::start(&m, options(&d)).unwrap();
    let bus = Bus::open(&d, "gateway-test").unwrap();
    let mut sim = subscribe(&bus, "sim/s");
    let mut adc0 = subscribe(&bus, "board/adc0");
    let meta = &adc0.info().meta;
    assert_eq!((meta.units.as_str(), meta.writable), ("V", false));
    let gw = eventually("the gateway ready", || {
        Some(info(&launch, "board")).filter(|i| i.ready)
    });
    assert_eq!((gw.kind, gw.restarts), (ProcessKind::Gateway, 0));
    let code = emu.set_adc_volts(0, 1.5).unwrap();
    wait_for(&mut adc0, "adc0 = 1.5 V", |x| {
        (x - volts(code)).abs() < 2e-6
    });

    // SIGKILL: the launcher restarts the gateway, which reconnects to the board; the same
    // subscriber sees the board's next value.
    let victim = gw.pid.unwrap();
    kill(victim, libc::SIGKILL);
    // Reading on meanwhile, so the subscriber sees the new owner's first samples (its sequence
    // starting again) rather than only the newest of a full buffer.
    let back = eventually("the gateway restarted and ready", || {
        while adc0.receive().unwrap().is_some() {}
        Some(info(&launch, "board")).filter(|i| i.restarts == 1 && i.ready)
    });
    assert_ne!(back.pid, Some(victim));
    let code = emu.set_adc_volts(0, 2.5).unwrap();
    wait_for(&mut adc0, "adc0 = 2.5 V after the restart", |x| {
        (x - volts(code)).abs() < 2e-6
    });
    assert!(adc0.restarts() >= 1, "a new owner published the state");
    // The executor ran throughout.
    while sim.receive().unwrap().is_some() {}
    wait_for(&mut sim, "sim/s still published", |_| true);
    assert_eq!(info(&launch, "sim").restarts, 0);

    // The orderly stop (SIGTERM to every process): all exit 0.
    drop((adc0, sim, bus));
    let pids: Vec<u32> = launch.executors().iter().filter_map(|e| e.pid).collect();
    launch.stop();
    let report = launch.wait().unwrap();
    let ends: Vec<_> = report
        .subsystems
        .iter()
        .map(|r| (r.subsystem.as_str(), r.kind, r.restarts, r.exit_code))
        .collect();
    assert_eq!(
        ends,
        [
            ("sim", ProcessKind::Executor, 0, Some(0)),
            ("board", ProcessKind::Gateway, 1, Some(0))
        ]
    );
    assert!(pids.iter().all(|&p| !alive(p)), "{pids:?}");
}

/// A PTY pair: the test holds the controlling side and never answers; the gateway opens the
/// other side (its path).
fn silent_pty() -> (OwnedFd, OwnedFd, PathBuf) {
    let (mut m, mut s) = (-1, -1);
    // SAFETY: openpty(3) writes two new descriptors into the given ints; name, termios and
    // winsize may be null.
    let r = unsafe {
        libc::openpty(
            &mut m,
            &mut s,
            std::ptr::null_mut(),
            std::ptr::null(),
            std::ptr::null(),
        )
    };
    assert_eq!(r, 0, "openpty: {}", std::io::Error::last_os_error());
    // SAFETY: both descriptors were just returned by openpty and are owned by nobody else.
    let (m, s) = unsafe { (OwnedFd::from_raw_fd(m), OwnedFd::from_raw_fd(s)) };
    let path = std::fs::read_link(format!("/proc/self/fd/{}", {
        use std::os::fd::AsRawFd;
        s.as_raw_fd()
    }))
    .unwrap();
    (m, s, path)
}

fn absent_board_gateways(pty: &Path) -> String {
    format!(
        "[gateways.absent]\nkind = \"score\"\nport = \"/nonexistent/score-link-{}\"\nretry_ms = 50\n\n\
         [gateways.silent]\nkind = \"score\"\nport = \"{}\"\nretry_ms = 50\n",
        std::process::id(),
        pty.display()
    )
}

#[test]
fn without_a_board_the_robot_runs_and_the_gateways_wait() {
    let (_master, _slave, pty) = silent_pty();
    let d = Domain::unique("gwabsent").unwrap();
    let m = manifest("gwabsent", &absent_board_gateways(&pty));
    // Returns once the executor is ready, whatever the gateways do.
    let launch = Launch::start(&m, options(&d)).unwrap();
    let bus = Bus::open(&d, "gateway-test").unwrap();
    let mut sim = subscribe(&bus, "sim/s");
    wait_for(&mut sim, "sim/s published", |_| true);
    let first: Vec<ExecutorInfo> = launch.executors();
    // Half a second is ten retries of the missing board and the silent one's first request.
    std::thread::sleep(Duration::from_millis(500));
    for name in ["absent", "silent"] {
        let i = info(&launch, name);
        let before = first.iter().find(|e| e.subsystem == name).unwrap();
        assert_eq!(i.kind, ProcessKind::Gateway);
        assert!(!i.ready, "{name}: ready without a board");
        assert!(i.pid.is_some() && i.pid == before.pid, "{name}: {i:?}");
        assert_eq!((i.restarts, i.failed.as_deref()), (0, None), "{name}");
    }
    // Still publishing.
    while sim.receive().unwrap().is_some() {}
    wait_for(&mut sim, "sim/s still published", |_| true);
    assert!(info(&launch, "sim").ready);

    drop((sim, bus));
    launch.stop();
    let report = launch.wait().unwrap();
    assert!(
        report.subsystems.iter().all(|r| r.exit_code == Some(0)),
        "{report:?}"
    );
    assert_eq!(report.subsystems.len(), 3);
}

#[test]
fn conductor_launch_stops_cleanly_on_sigterm_while_its_gateway_waits() {
    let d = Domain::unique("gwcli").unwrap();
    let m = manifest(
        "gwcli",
        &format!(
            "[gateways.absent]\nkind = \"score\"\nport = \"/nonexistent/score-link-{}\"\n",
            std::process::id()
        ),
    );
    let launcher =
        Bg::spawn(
            conductor(&d)
                .arg("launch")
                .arg(&m)
                .args(["--no-rt", "--summary-secs", "0.2"]),
        );
    let bus = Bus::open(&d, "gateway-test").unwrap();
    let mut sim = subscribe(&bus, "sim/s");
    wait_for(&mut sim, "sim/s published", |_| true);
    // Two summaries' worth.
    std::thread::sleep(Duration::from_millis(500));
    drop((sim, bus));
    kill(launcher.child.id(), libc::SIGTERM);
    let (ok, err) = launcher.finish();
    assert!(ok, "conductor launch failed: {err}");
    let started = err
        .lines()
        .find_map(|l| l.strip_prefix("conductor: gateway absent started (pid "))
        .unwrap_or_else(|| panic!("no start note: {err}"));
    let pid: u32 = started.split(')').next().unwrap().parse().unwrap();
    assert!(
        err.lines()
            .any(|l| l.contains("absent") && l.ends_with("(waiting for its board)")),
        "the summary shows the gateway waiting: {err}"
    );
    assert!(
        err.contains("1 executor(s) and 1 gateway(s) stopped"),
        "{err}"
    );
    assert!(!alive(pid), "the gateway (pid {pid}) outlived the launcher");
}
