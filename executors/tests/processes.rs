//! The launcher and the executors as real processes, each test in its own bus domain: a frame
//! applied in one tick, restart after SIGKILL, orderly SIGTERM leaving nothing behind, the
//! command watchdog, launches that must fail, and restarted executors that inherit no descriptor
//! of the launcher. (Rates seen by an external subscriber process: benches/tests/stress_logger.rs,
//! beside the stress tool's logger.)
//!
//! Rates are modest (≤ 250 Hz) and sleep-based: the test machine has 2 CPUs.

mod support;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use conductor_bus::{status, Bus, Controller, SnapshotReader, StateSample, StatsSubscriber};
use conductor_executor::launcher::{Launch, LaunchError};
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;
use support::*;

#[test]
fn a_frame_of_six_setpoints_is_applied_in_one_tick() {
    let (d, _guard) = private_domain("frame");
    let launch = Launch::start(&test_manifest("two-subsystems.toml"), options(&d)).unwrap();
    let names = ["arm/j0", "arm/j1", "arm/j2", "arm/j3", "arm/j4", "arm/j5"];
    let rec = Recorder::start(&d, &names);
    let bus = Bus::open(&d, "test-controller").unwrap();
    let mut ctl = Controller::new(&bus);
    // Binary fractions: exact through j5's calibration (−2 · (device − 0.5)) and back.
    let targets = [0.125, 0.25, 0.375, 0.5, 0.625, 0.75];
    std::thread::sleep(Duration::from_millis(100));
    for (n, v) in names.iter().zip(targets) {
        ctl.add_ctrl(n, v).unwrap();
    }
    assert_eq!(ctl.send_ctrl().unwrap(), 6);
    std::thread::sleep(Duration::from_millis(300));
    let recs = rec.finish();
    let reflecting: Vec<(u64, u64)> = recs
        .iter()
        .zip(targets)
        .map(|(r, v)| {
            let s = r
                .samples
                .iter()
                .find(|s| s.value == v)
                .unwrap_or_else(|| panic!("no sample reached {v}: {:?}", r.samples.last()));
            assert_eq!(s.status, status::SIMULATED);
            (s.tick, s.t_sample_ns)
        })
        .collect();
    assert!(
        reflecting.iter().all(|x| *x == reflecting[0]),
        "the six samples that reflect the frame differ: {reflecting:?}"
    );
    drop(ctl);
    drop(bus);
    launch.stop();
    launch.wait().unwrap();
}

/// A subsystem's snapshot is its tick as one sample: one entry per state in index order, each
/// the very sample that state's own service carries (a slower state keeps its last one), woken
/// by the snapshot event, tick after tick.
#[test]
fn the_snapshot_carries_each_tick_of_every_state_as_their_services_do() {
    let (d, _guard) = private_domain("snapshot");
    let launch = Launch::start(&test_manifest("two-subsystems.toml"), options(&d)).unwrap();
    let bus = Bus::open(&d, "test-snapshot").unwrap();
    let mut infos: Vec<_> = bus
        .list_states()
        .unwrap()
        .into_iter()
        .filter(|s| s.subsystem == "sensors")
        .collect();
    infos.sort_by_key(|s| s.meta.index);
    let names: Vec<String> = infos.iter().map(|s| s.qualified_name()).collect();
    assert_eq!(names, ["sensors/a", "sensors/b", "sensors/c"]);
    let rec = Recorder::start(&d, &names.iter().map(String::as_str).collect::<Vec<_>>());
    let mut reader = SnapshotReader::new(&bus, "sensors").unwrap();

    // 250 Hz for about a second: every wake-up hands out the newest snapshot.
    let mut snaps: Vec<Vec<StateSample>> = Vec::new();
    let end = Instant::now() + Duration::from_secs(1);
    while Instant::now() < end {
        if let Some(s) = reader.wait(Duration::from_millis(100)).unwrap() {
            snaps.push(s.to_vec());
        }
    }
    std::thread::sleep(Duration::from_millis(50));
    let recs = rec.finish();
    launch.stop();
    launch.wait().unwrap();

    assert!(
        snaps.len() > 100,
        "only {} snapshots in 1 s at 250 Hz",
        snaps.len()
    );
    let mut slower_held = [0usize; 3];
    for pair in snaps.windows(2) {
        assert!(
            pair[1][0].tick > pair[0][0].tick,
            "ticks go forward: {pair:?}"
        );
    }
    for snap in &snaps {
        assert_eq!(snap.len(), 3, "one entry per state");
        let tick = snap[0].tick; // `a` runs at the base rate: published every tick
        for (i, entry) in snap.iter().enumerate() {
            assert!(
                entry.tick <= tick,
                "entry {i} is from a later tick: {snap:?}"
            );
            slower_held[i] += usize::from(entry.tick < tick);
            assert!(
                recs[i].samples.contains(entry),
                "{}'s entry in the snapshot of tick {tick} is not a sample its service \
                 carried: {entry:?}",
                names[i]
            );
        }
    }
    assert_eq!(slower_held[0], 0);
    assert!(
        slower_held[1] > 0 && slower_held[2] > slower_held[1],
        "the 125 Hz and 50 Hz states keep their last sample between their ticks: {slower_held:?}"
    );
}

#[test]
fn a_killed_executor_is_restarted_and_the_other_subsystem_never_stops() {
    let (d, _guard) = private_domain("restart");
    let launch = Launch::start(&test_manifest("two-subsystems.toml"), options(&d)).unwrap();
    let rec = Recorder::start(&d, &["sensors/a", "arm/j0"]);
    std::thread::sleep(Duration::from_millis(200));
    let victim = launch.pid("arm").unwrap();
    let killed_at = now_ns();
    kill(Pid::from_raw(victim as i32), Signal::SIGKILL).unwrap();
    let info = eventually(10, "arm restarted and ready", || {
        launch
            .executors()
            .into_iter()
            .find(|e| e.subsystem == "arm" && e.restarts == 1 && e.ready)
    });
    assert_ne!(info.pid, Some(victim));
    std::thread::sleep(Duration::from_millis(300));
    let recs = rec.finish();
    let (sensors, arm) = (&recs[0], &recs[1]);

    // The other subsystem never stopped: no lost or restarted sequence, no gap in sample time
    // beyond a couple of its 4 ms periods (the restart itself took ≥ 200 ms of back-off).
    assert_eq!((sensors.missed, sensors.restarts), (0, 0));
    let max_gap = sensors
        .samples
        .windows(2)
        .map(|w| w[1].t_sample_ns - w[0].t_sample_ns)
        .max()
        .unwrap();
    assert!(max_gap < 12_000_000, "sensors paused for {max_gap} ns");
    assert!(sensors.samples.last().unwrap().t_sample_ns > killed_at + 300_000_000);

    // The killed subsystem came back: a new owner (its sequence started over) publishing again.
    assert_eq!(arm.restarts, 1, "one new owner");
    let after: Vec<_> = arm
        .samples
        .iter()
        .filter(|s| s.t_sample_ns > killed_at)
        .collect();
    assert!(
        after.len() > 20,
        "only {} samples after the restart",
        after.len()
    );
    assert!(
        after[0].seq < 5,
        "the new executor's first samples: seq {}",
        after[0].seq
    );
    launch.stop();
    let report = launch.wait().unwrap();
    let arm_report = report
        .subsystems
        .iter()
        .find(|s| s.subsystem == "arm")
        .unwrap();
    assert_eq!((arm_report.restarts, arm_report.exit_code), (1, Some(0)));
}

#[test]
fn sigterm_stops_every_executor_cleanly_and_leaves_nothing_behind() {
    let (d, _guard) = private_domain("sigterm");
    let mut launcher = Command::new(LAUNCHER)
        .arg(test_manifest("two-subsystems.toml"))
        .args(["--domain", d.name(), "--quiet"])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(launcher.stderr.take().unwrap()).lines();
    let mut pids = Vec::new();
    while pids.len() < 2 {
        let line = lines.next().expect("launcher output").unwrap();
        if let Some(rest) = line.split("ready (pid ").nth(1) {
            pids.push(rest.trim_end_matches(')').parse::<u32>().unwrap());
        }
    }
    std::thread::sleep(Duration::from_millis(300));
    kill(Pid::from_raw(launcher.id() as i32), Signal::SIGTERM).unwrap();
    let status = launcher.wait().unwrap();
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    assert!(status.success(), "launcher: {status}; {rest:?}");
    assert_eq!(
        rest.iter()
            .filter(|l| l.contains("devices in their safe state"))
            .count(),
        2,
        "both executors stopped in order: {rest:?}"
    );
    for pid in pids {
        assert!(!alive(pid), "executor {pid} still runs");
    }
    let (shm, records) = leftovers(&d);
    // iceoryx2 keeps one 16-byte node counter per domain (`…_node.<version>.global_mgmt`),
    // persistent by design and reused by the next process of the domain; nothing else may stay.
    assert!(
        shm.iter().all(|f| f.ends_with(".global_mgmt")) && shm.len() <= 1,
        "shared memory left: {shm:?}"
    );
    assert!(records.is_empty(), "node/service records left: {records:?}");
    let scan = conductor_executor::cleanup::scan_and_clean(&d).unwrap();
    assert!(scan.alive.is_empty() && scan.removed == 0, "{scan:?}");
}

#[test]
fn the_watchdog_applies_the_safe_action_within_timeout_plus_one_tick() {
    // 200 Hz, watchdog 100 ms = 20 ticks; safe action: setpoint 0.
    let text = r#"
system = "wd"
[subsystems.arm]
rate_hz = 200
watchdog_ms = 100
[subsystems.arm.hardware.bus]
kind = "loopback"
[subsystems.arm.protocols.p]
kind = "sim"
hardware = "bus"
[subsystems.arm.devices.m]
kind = "sim"
protocol = "p"
id = 1
safe_action = "setpoint"
safe_value = 0.0
[subsystems.arm.states.q]
device = "m"
writable = true
min = -1.0
max = 1.0
"#;
    let path = temp_manifest("watchdog", text);
    let (d, _guard) = private_domain("watchdog");
    let launch = Launch::start(&path, options(&d)).unwrap();
    let rec = Recorder::start(&d, &["arm/q"]);
    let bus = Bus::open(&d, "test-controller").unwrap();
    let mut ctl = Controller::new(&bus);
    // A controller that sends a distinct value every 10 ms, then goes silent.
    let mut last = 0.0;
    for k in 0..30 {
        last = 0.5 + f64::from(k) / 1024.0;
        ctl.add_ctrl("arm/q", last).unwrap();
        ctl.send_ctrl().unwrap();
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(Duration::from_millis(400));
    let recs = rec.finish();
    let samples = &recs[0].samples;
    // The last frame was applied on the tick before its value first reads back (a loopback
    // write is sampled on the next bus cycle).
    let seen = samples
        .iter()
        .find(|s| s.value == last)
        .expect("last setpoint read back");
    let applied = seen.tick - 1;
    let trip = samples
        .iter()
        .find(|s| s.status & status::WATCHDOG != 0)
        .expect("the watchdog fired");
    assert_eq!(
        trip.value, 0.0,
        "the safe setpoint is in effect on the trip tick"
    );
    let ticks = trip.tick - applied;
    assert!(
        (20..=21).contains(&ticks),
        "safe action {ticks} ticks after the last frame (timeout = 20 ticks)"
    );
    assert!(samples
        .iter()
        .filter(|s| s.tick > trip.tick)
        .all(|s| s.value == 0.0));
    let mut stats = StatsSubscriber::new(&bus, "arm").unwrap();
    let s = eventually(5, "stats", || stats.latest().unwrap());
    assert_eq!(s.watchdog_trips, 1);
    drop((ctl, stats, bus));
    launch.stop();
    launch.wait().unwrap();
    let _ = std::fs::remove_file(path);
}

#[test]
fn crashing_more_often_than_allowed_ends_the_launch_with_the_reason() {
    let (d, _guard) = private_domain("crashes");
    let mut opts = options(&d);
    opts.only = vec!["sensors".into()];
    opts.max_restarts = 1;
    opts.backoff = Duration::from_millis(50);
    let launch = Launch::start(&test_manifest("two-subsystems.toml"), opts).unwrap();
    for round in 0..2 {
        let pid = eventually(10, "sensors ready", || {
            launch
                .executors()
                .into_iter()
                .find(|e| e.ready && e.restarts == round)
                .and_then(|e| e.pid)
        });
        kill(Pid::from_raw(pid as i32), Signal::SIGKILL).unwrap();
    }
    let started = Instant::now();
    let err = launch.wait().unwrap_err();
    assert!(started.elapsed() < Duration::from_secs(10));
    match &err {
        LaunchError::TooManyRestarts {
            subsystem, status, ..
        } => {
            assert_eq!(subsystem, "sensors");
            assert!(status.contains("SIGKILL"), "{status}");
        }
        other => panic!("unexpected: {other}"),
    }
}

#[test]
fn launches_that_cannot_run_fail_with_the_reason() {
    // An invalid manifest: nothing starts, every error is reported.
    let (d, _guard) = private_domain("cannot");
    let bad = temp_manifest("bad", "system = \"x\"\n[subsystems.a]\nrate_hz = 0\n");
    match Launch::start(&bad, options(&d)) {
        Err(LaunchError::Manifest(e)) => assert!(e.to_string().contains("rate_hz"), "{e}"),
        other => panic!("unexpected: {other:?}"),
    }
    // Real time required but refused (--no-rt): exit status 2, reported, not restarted.
    let text = std::fs::read_to_string(test_manifest("two-subsystems.toml"))
        .unwrap()
        .replace(
            "[subsystems.sensors]\nrate_hz = 250",
            "[subsystems.sensors]\nrate_hz = 250\nrequire_rt = true",
        );
    let rt = temp_manifest("rt", &text);
    let mut opts = options(&d);
    opts.no_rt = true;
    match Launch::start(&rt, opts) {
        Err(LaunchError::CannotRun {
            subsystem, output, ..
        }) => {
            assert_eq!(subsystem, "sensors");
            assert!(
                output.iter().any(|l| l.contains("require_rt")),
                "{output:?}"
            );
        }
        other => panic!("unexpected: {other:?}"),
    }
    // A missing executor program.
    let mut opts = options(&d);
    opts.executor = "/nonexistent/conductor-executor".into();
    assert!(matches!(
        Launch::start(&test_manifest("two-subsystems.toml"), opts),
        Err(LaunchError::Spawn { .. })
    ));
    // The same subsystem twice in one domain.
    let mut opts = options(&d);
    opts.only = vec!["sensors".into()];
    let first = Launch::start(&test_manifest("two-subsystems.toml"), opts.clone()).unwrap();
    match Launch::start(&test_manifest("two-subsystems.toml"), opts) {
        Err(LaunchError::AlreadyRunning { subsystem, pid, .. }) => {
            assert_eq!(subsystem, "sensors");
            assert_eq!(pid, first.pid("sensors").unwrap().to_string());
        }
        other => panic!("unexpected: {other:?}"),
    }
    // An executor started by hand refuses too (it would publish on the same services).
    let out = Command::new(EXECUTOR)
        .arg("--manifest")
        .arg(test_manifest("two-subsystems.toml"))
        .args(["--subsystem", "sensors", "--domain", d.name()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("already runs"));
    first.stop();
    first.wait().unwrap();
    let _ = std::fs::remove_file(bad);
    let _ = std::fs::remove_file(rt);
}

/// The descriptors of process `pid`, each with what it points at.
fn descriptors(pid: u32) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(format!("/proc/{pid}/fd"))
        .unwrap()
        .map_while(Result::ok)
        .map(|e| {
            let target = std::fs::read_link(e.path()).unwrap_or_default();
            format!(
                "{} -> {}",
                e.file_name().to_string_lossy(),
                target.display()
            )
        })
        .collect();
    v.sort();
    v
}

/// An executor restarted after SIGKILL holds as many descriptors at READY as the first did: the
/// launcher's own (its bus node, opened after the first start) are not inherited.
#[test]
fn a_restarted_executor_starts_with_the_descriptors_of_the_first() {
    // The launcher as its own process: its children can only inherit the launcher's descriptors.
    let (d, _guard) = private_domain("fds");
    let mut launcher = Command::new(LAUNCHER)
        .arg(test_manifest("two-subsystems.toml"))
        .args(["--domain", d.name(), "--only", "sensors", "--no-rt"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(launcher.stderr.take().unwrap()).lines();
    let mut next_ready = || loop {
        let line = lines.next().expect("launcher output").unwrap();
        if let Some(rest) = line.split("ready (pid ").nth(1) {
            return rest.trim_end_matches(')').parse::<u32>().unwrap();
        }
    };
    let mut counts = Vec::new();
    let mut first = Vec::new();
    for round in 0..5 {
        let pid = next_ready();
        let fds = descriptors(pid);
        counts.push(fds.len());
        if round == 0 {
            first = fds.clone();
        }
        assert_eq!(
            fds.len(),
            first.len(),
            "executor {round} (pid {pid}) starts with other descriptors than the first: \
             {fds:#?}\nthe first had {first:#?}"
        );
        kill(Pid::from_raw(pid as i32), Signal::SIGKILL).unwrap();
    }
    let pid = next_ready();
    kill(Pid::from_raw(launcher.id() as i32), Signal::SIGTERM).unwrap();
    let status = launcher.wait().unwrap();
    assert!(status.success(), "launcher: {status}");
    assert!(
        counts.iter().all(|&c| c == counts[0]),
        "{counts:?} (last pid {pid})"
    );
}

/// An executor restarted after a crash whose servo does not answer yet cannot bring it up
/// and exits "cannot run" (after its 5 s bring-up time); it ran before, so the launcher
/// retries it like a crash (within the same bounds) instead of ending the launch, and it runs
/// again once the servo answers.
#[test]
fn a_restarted_executor_whose_devices_do_not_answer_is_retried_until_they_do() {
    use conductor_devices::sim::dxl::DxlSimConfig;
    use conductor_devices::sim::fault::FaultConfig;
    use conductor_devices::sim::runner::{run_dxl, Endpoint, Pty};
    let (d, _guard) = private_domain("retry");
    let link = std::env::temp_dir().join(format!("conductor-retry-{}", std::process::id()));
    let sim = run_dxl(
        Endpoint::Pty(Pty::open(Some(&link)).unwrap()),
        DxlSimConfig {
            ids: vec![1],
            ..DxlSimConfig::default()
        },
        FaultConfig::default(),
        FaultConfig::default(),
    );
    let text = format!(
        "system = \"retry\"\n[subsystems.arm]\nrate_hz = 100\n\
         [subsystems.arm.hardware.uart]\nkind = \"serial\"\nport = \"{}\"\n\
         [subsystems.arm.protocols.robotis]\nkind = \"dynamixel2\"\nhardware = \"uart\"\n\
         [subsystems.arm.devices.j1]\nkind = \"dynamixel_x\"\nprotocol = \"robotis\"\nid = 1\n\
         [subsystems.arm.states.p1]\ndevice = \"j1\"\nchannel = \"position\"\n",
        link.display()
    );
    let launch = Launch::start(&temp_manifest("retry", &text), options(&d)).unwrap();
    let first = launch.pid("arm").unwrap();
    // The servo stops answering and the executor crashes: its successor cannot bring it up.
    sim.pause_reading(true);
    kill(Pid::from_raw(first as i32), Signal::SIGKILL).unwrap();
    eventually(
        30,
        "a restart after one that could not bring the servo up",
        || (launch.executors()[0].restarts >= 2).then_some(()),
    );
    sim.pause_reading(false);
    eventually(30, "an executor ready again once the servo answers", || {
        let e = &launch.executors()[0];
        (e.ready && e.pid.is_some_and(|p| p != first)).then_some(())
    });
    let bus = Bus::open(&d, "t").unwrap();
    let since = now_ns();
    // The state exists again once an executor runs.
    let mut p1 = None;
    eventually(20, "fresh samples once the servo answers", || {
        if p1.is_none() {
            p1 = conductor_bus::StateSubscriber::new(&bus, "arm/p1").ok();
        }
        let s = p1.as_mut()?.latest().ok().flatten()?;
        (s.t_sample_ns > since && s.status & status::STALE == 0).then_some(())
    });
    launch.stop();
    launch.wait().unwrap();
}
