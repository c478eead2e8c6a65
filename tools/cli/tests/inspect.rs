//! `list`, `get`, `set`, `echo`, `top` against simulated executors, each test in its own domain.

mod support;

use std::time::{Duration, Instant};

use conductor_bus::{monotonic_ns, Bus, Domain, StatePublisher, StatsPublisher};
use support::*;

fn leg_states(rate: f64) -> Vec<conductor_bus::StateSpec> {
    vec![
        state(0, "knee", "rad", true, (-1.5, 2.0), rate, "dKnee"),
        state(
            1,
            "hip",
            "rad",
            true,
            (f64::NEG_INFINITY, f64::INFINITY),
            rate,
            "dHip",
        ),
        state(2, "current", "A", false, (-5.0, 5.0), rate, ""),
    ]
}

#[test]
fn list_shows_every_state_with_metadata() {
    let (d, _leg) = domain_with_leg("list", 200.0, leg_states);
    let _arm = hold_sim(
        &d,
        "arm",
        50.0,
        vec![state(0, "grip", "", true, (0.0, 1.0), 50.0, "")],
    );
    let out = ok(conductor(&d).arg("list"));
    let rows: Vec<Vec<&str>> = out
        .lines()
        .map(|l| l.split_whitespace().collect())
        .collect();
    assert_eq!(
        rows[0],
        ["STATE", "UNITS", "RATE_HZ", "RW", "LIMITS", "DEVICE", "HOST", "WRITER", "VALUE", "AGE"]
    );
    // Sorted by subsystem, then index. AGE is "<number> <unit>", so rows have 11 fields; HOST
    // is this machine for states of its own executors.
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap();
    let host = host.trim();
    let expect = [
        [
            "arm/grip",
            "-",
            "50",
            "rw",
            "[0,1]",
            "-",
            host,
            "executor/arm",
            "0",
        ],
        [
            "leg/knee",
            "rad",
            "200",
            "rw",
            "[-1.5,2]",
            "dKnee",
            host,
            "executor/leg",
            "0",
        ],
        [
            "leg/hip",
            "rad",
            "200",
            "rw",
            "[-inf,inf]",
            "dHip",
            host,
            "executor/leg",
            "0",
        ],
        [
            "leg/current",
            "A",
            "200",
            "ro",
            "[-5,5]",
            "-",
            host,
            "executor/leg",
            "0",
        ],
    ];
    assert_eq!(rows.len(), 1 + expect.len(), "{out}");
    for (row, want) in rows[1..].iter().zip(expect) {
        assert_eq!(row[..9], want, "{out}");
        assert_eq!(row.len(), 11, "{out}");
        // The simulators publish every tick, so the newest sample is at most a few periods old
        // (generous: a loaded CI machine may stall a thread for a while).
        let age: f64 = row[9].parse().unwrap();
        let secs = age
            * match row[10] {
                "ns" => 1e-9,
                "µs" => 1e-6,
                "ms" => 1e-3,
                "s" => 1.0,
                u => panic!("unit {u}"),
            };
        assert!((0.0..2.0).contains(&secs), "{out}");
    }
    // A pattern narrows the list.
    let out = ok(conductor(&d).args(["list", "leg/k*"]));
    assert_eq!(out.lines().count(), 2, "{out}");
}

#[test]
fn set_moves_a_state_and_get_reads_it_back() {
    let (d, leg) = domain_with_leg("setget", 200.0, leg_states);
    let get = || {
        ok(conductor(&d).args(["get", "leg/knee", "--raw"]))
            .trim()
            .to_string()
    };
    assert_eq!(get(), "0");

    let out = ok(conductor(&d).args(["set", "leg/knee", "0.75"]));
    assert!(out.starts_with("sent leg/knee <- 0.75\n"), "{out}");
    // `set` waits for the first sample of a tick that began after the frame was sent.
    assert!(out.contains("now  leg/knee = 0.75 rad"), "{out}");
    assert_eq!(get(), "0.75");

    // Outside the limits: refused, nothing sent.
    let err = fails(conductor(&d).args(["set", "leg/knee", "5"]));
    assert!(err.contains("outside the limits [-1.5, 2]"), "{err}");
    assert_eq!(get(), "0.75");
    // With --clamp: the nearest limit is sent.
    let out = ok(conductor(&d).args(["set", "knee", "5", "--clamp"]));
    assert!(out.contains("sent leg/knee <- 2 (clamped from 5)"), "{out}");
    assert_eq!(get(), "2");
    // Negative values are values, not options.
    ok(conductor(&d).args(["set", "leg/knee", "-1.25"]));
    assert_eq!(get(), "-1.25");

    let err = fails(conductor(&d).args(["set", "leg/knee", "NaN"]));
    assert!(err.contains("not finite"), "{err}");
    let err = fails(conductor(&d).args(["set", "leg/current", "1"]));
    assert!(err.contains("read-only"), "{err}");
    let err = fails(conductor(&d).args(["set", "leg/nope", "1"]));
    assert!(err.contains("unknown state"), "{err}");
    assert_eq!(get(), "-1.25");

    // The executor saw exactly the three accepted frames, none clamped or rejected on its side.
    let report = leg.stop().unwrap();
    assert_eq!((report.frames, report.rejected, report.clamped), (3, 0, 0));
}

#[test]
fn get_describes_the_sample() {
    let (d, _leg) = domain_with_leg("get", 100.0, leg_states);
    let out = ok(conductor(&d).args(["get", "current"]));
    assert!(out.starts_with("leg/current = 0 A  (seq "), "{out}");
    assert!(out.contains("flags simulated)"), "{out}");
    let err = fails(conductor(&d).args(["get", "leg/none", "--timeout", "0.2"]));
    assert!(err.contains("unknown state \"leg/none\""), "{err}");
}

#[test]
fn echo_prints_at_the_requested_rate() {
    let (d, _leg) = domain_with_leg("echo", 200.0, leg_states);
    let out = ok(conductor(&d).args(["echo", "leg/knee", "--rate", "20", "--duration", "2"]));
    let times: Vec<f64> = out
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            assert_eq!(f[1..], ["leg/knee", "0", "rad", "simulated"], "{l}");
            f[0].parse().unwrap()
        })
        .collect();
    // At 20 lines/s from a 200 Hz state: consecutive lines are at least 1/20 s apart in sample
    // time (the decimation rule), so 2 s hold at most 41 lines (plus the first, older history
    // sample); a stalled simulator can only lower the count.
    assert!(
        (30..=42).contains(&times.len()),
        "{} lines:\n{out}",
        times.len()
    );
    let mut gaps: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(gaps.iter().all(|g| *g >= 0.05 - 1e-6), "{gaps:?}");
    gaps.sort_by(f64::total_cmp);
    // Typical gap: 1/20 s rounded up to the next 5 ms sample.
    let median = gaps[gaps.len() / 2];
    assert!(
        (0.05..0.0551).contains(&median),
        "median gap {median}: {gaps:?}"
    );

    // Globs and JSON: every state of the subsystem, each at about 20 lines/s over 0.5 s.
    let out = ok(conductor(&d).args([
        "echo",
        "leg/*",
        "--json",
        "--rate",
        "20",
        "--duration",
        "0.5",
    ]));
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    for name in ["leg/current", "leg/hip", "leg/knee"] {
        let n = lines.iter().filter(|v| v["state"] == name).count();
        // ≤ 0.5 s / 0.05 s + 1 (+1 history sample); ≥ 5 leaves room for a slow start.
        assert!((5..=12).contains(&n), "{name}: {n} lines\n{out}");
    }
    assert!(lines.iter().all(|v| v["status"] == 64 && v["value"] == 0.0));
    // --count stops after exactly that many lines.
    let out = ok(conductor(&d).args(["echo", "leg/*", "--count", "9"]));
    assert_eq!(out.lines().count(), 9, "{out}");
}

#[test]
fn top_prints_the_stats_service_figures() {
    let d = Domain::unique("top").unwrap();
    // A fake executor: one state (so discovery finds the subsystem) and fixed stats figures.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flag = stop.clone();
    let dom = d.clone();
    let (tx, rx) = std::sync::mpsc::channel();
    let fake = std::thread::spawn(move || {
        let bus = Bus::open(&dom, "executor/arm").unwrap();
        let specs = vec![state(0, "elbow", "rad", true, (-1.0, 1.0), 1000.0, "")];
        let mut states = StatePublisher::create(&bus, "arm", &specs).unwrap();
        let mut stats = StatsPublisher::create(&bus, "arm").unwrap();
        tx.send(()).unwrap();
        let mut seq = 0;
        while !flag.load(std::sync::atomic::Ordering::Relaxed) {
            seq += 1;
            states.publish(0, seq, monotonic_ns(), 0.0, 0).unwrap();
            stats
                .publish(|s| {
                    s.seq = seq;
                    s.t_ns = monotonic_ns();
                    s.ticks = 123_456;
                    s.misses = 3;
                    s.base_rate_hz = 1000.0;
                    s.achieved_rate_hz = 999.54;
                    s.lateness_p50_ns = 12_340;
                    s.lateness_p99_ns = 45_660;
                    s.lateness_max_ns = 789_000;
                    s.bus_errors = 7;
                    s.frames_applied = 11;
                    s.setpoints_rejected = 2;
                    s.setpoints_clamped = 5;
                    s.watchdog_trips = 1;
                    s.stale_states = 1;
                    s.states = 4;
                    s.rt_active = 1;
                    s.cpu = 1;
                    s.bus_outages = 2;
                    s.device_faults = 3;
                    s.late_replies = 4;
                    s.setpoints_refused = 6;
                    s.devices = 3;
                    s.devices_enabled = 2;
                    s.devices_tripped = 1;
                    s.devices_faulted = 1;
                    s.links_down = 1;
                })
                .unwrap();
            std::thread::sleep(Duration::from_millis(50));
        }
    });
    rx.recv().unwrap();
    let motor = hold_sim(
        &d,
        "motor",
        500.0,
        vec![state(0, "u", "V", true, (-1.0, 1.0), 500.0, "")],
    );

    let table = |out: &str| -> Vec<Vec<String>> {
        out.lines()
            .map(|l| l.split_whitespace().map(str::to_string).collect())
            .collect()
    };
    let find = |rows: &[Vec<String>], name: &str| -> Vec<String> {
        rows.iter().find(|r| r[0] == name).expect(name).clone()
    };

    // The default table: the health summary, within 100 columns.
    let out = ok(conductor(&d).args(["top", "--once"]));
    let rows = table(&out);
    assert_eq!(rows[0], ["domain", d.name()]);
    assert_eq!(rows[1], conductor_cli::top::header(false), "{out}");
    assert_eq!(
        rows[1],
        [
            "SUBSYSTEM",
            "HZ",
            "P99_US",
            "MISS",
            "STALE",
            "DEV",
            "TRIP",
            "FAULT",
            "BUS_ERR",
            "OUTAGE",
            "LATE",
            "REFUSED",
            "AGE"
        ]
    );
    assert!(out.lines().all(|l| l.chars().count() <= 100), "{out}");
    let arm = find(&rows, "arm");
    // Rates with one decimal, lateness in µs with one decimal, counters verbatim, devices
    // enabled/all; AGE is one word (no space before its unit).
    assert_eq!(
        arm[..12],
        ["arm", "999.5", "45.7", "3", "1/4", "2/3", "1", "1", "7", "2", "4", "6"],
        "{out}"
    );
    assert_eq!(arm.len(), 13, "{out}");
    // The simulator's own figures: it ticks at 500 Hz, publishes one state, has no devices.
    let m = find(&rows, "motor");
    assert_eq!((m[4].as_str(), m[5].as_str()), ("0/1", "-"), "{out}");
    let achieved: f64 = m[1].parse().unwrap();
    assert!(achieved > 0.0 && achieved < 600.0, "{out}");

    // --wide: every figure, full names.
    let out = ok(conductor(&d).args(["top", "--once", "--wide"]));
    let rows = table(&out);
    assert_eq!(rows[1], conductor_cli::top::header(true), "{out}");
    assert_eq!(
        rows[1],
        [
            "SUBSYSTEM",
            "RATE_HZ",
            "TARGET_HZ",
            "LATE_P50_US",
            "LATE_P99_US",
            "LATE_MAX_US",
            "MISSES",
            "STALE",
            "ENABLED",
            "TRIPPED",
            "FAULTED",
            "LINKS_DOWN",
            "BUS_ERR",
            "OUTAGES",
            "LATE_REPLIES",
            "FRAMES",
            "REJECTED",
            "REFUSED",
            "CLAMPED",
            "WATCHDOG",
            "FAULTS",
            "RT",
            "AGE"
        ]
    );
    let arm = find(&rows, "arm");
    assert_eq!(
        arm[..22],
        [
            "arm", "999.5", "1000.0", "12.3", "45.7", "789.0", "3", "1/4", "2/3", "1", "1", "1",
            "7", "2", "4", "11", "2", "6", "5", "1", "3", "fifo@1"
        ],
        "{out}"
    );
    let m = find(&rows, "motor");
    assert_eq!((m[2].as_str(), m[21].as_str()), ("500.0", "no"), "{out}");

    // --count prints that many tables.
    let out = ok(conductor(&d).args(["top", "--count", "2", "--interval", "0.2"]));
    assert_eq!(out.matches("SUBSYSTEM").count(), 2, "{out}");
    drop(motor);
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    fake.join().unwrap();
}

#[test]
fn help_has_examples_and_completions_generate() {
    let d = Domain::unique("help").unwrap();
    let out = ok(conductor(&d).arg("--help"));
    assert!(
        out.contains("Examples:") && out.contains("conductor record"),
        "{out}"
    );
    for shell in ["bash", "zsh", "fish"] {
        let out = ok(conductor(&d).args(["completions", shell]));
        assert!(out.contains("udp-gateway"), "{shell}: {out}");
    }
    // Wait for nothing: an empty domain lists nothing, quickly.
    let t = Instant::now();
    let out = conductor(&d).arg("list").output().unwrap();
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no states"));
    assert!(t.elapsed() < Duration::from_secs(5));
}
