//! The CLI against the real thing: `conductor launch` runs the two-subsystem test manifest (real
//! executor processes on simulated hardware), and `list`, `set`/`get`, `echo` and `top` work on
//! it; SIGINT stops everything cleanly.

mod support;

use std::time::{Duration, Instant};

use conductor_bus::Domain;
use support::*;

const STATES: usize = 9;

fn manifest() -> std::path::PathBuf {
    workspace().join("executors/tests/manifests/two-subsystems.toml")
}

/// `conductor list` rows (without the header) once all states are up.
fn listed(d: &Domain) -> Vec<Vec<String>> {
    let end = Instant::now() + Duration::from_secs(30);
    loop {
        let out = ok(conductor(d).arg("list"));
        let rows: Vec<Vec<String>> = out
            .lines()
            .skip(1)
            .map(|l| l.split_whitespace().map(str::to_string).collect())
            .collect();
        if rows.len() == STATES {
            return rows;
        }
        assert!(Instant::now() < end, "states never all appeared: {out}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn list_set_get_echo_top_against_a_launched_manifest() {
    let d = Domain::unique("launched").unwrap();
    let launcher = Bg::spawn(
        conductor(&d)
            .arg("launch")
            .arg(manifest())
            .args(["--no-rt", "--quiet"]),
    );

    // list: every state with the manifest's metadata, owned by its executor process.
    let rows = listed(&d);
    let row = |name: &str| rows.iter().find(|r| r[0] == name).unwrap().clone();
    for j in 0..6 {
        let r = row(&format!("arm/j{j}"));
        // r[6] is HOST (this machine).
        assert_eq!(
            [&r[1..6], &r[7..8]].concat(),
            [
                "rad",
                "200",
                "rw",
                "[-2,2]",
                &format!("m{j}"),
                "executor/arm"
            ]
        );
    }
    for (s, rate) in [("a", "250"), ("b", "125"), ("c", "50")] {
        let r = row(&format!("sensors/{s}"));
        assert_eq!(
            (r[2].as_str(), r[3].as_str(), r[7].as_str()),
            (rate, "ro", "executor/sensors")
        );
    }

    // set moves a joint (through a command frame the executor applies), get reads it back.
    ok(conductor(&d).args(["set", "arm/j3", "1.25"]));
    let got = ok(conductor(&d).args(["get", "arm/j3", "--raw"]));
    assert_eq!(got.trim(), "1.25");
    // The calibrated joint: the executor converts to device units and back.
    ok(conductor(&d).args(["set", "arm/j5", "-0.5"]));
    assert_eq!(
        ok(conductor(&d).args(["get", "arm/j5", "--raw"])).trim(),
        "-0.5"
    );
    // Out of the manifest's limits: refused without --clamp, clamped with it.
    let err = fails(conductor(&d).args(["set", "arm/j3", "5"]));
    assert!(err.contains("outside the limits [-2, 2]"), "{err}");
    ok(conductor(&d).args(["set", "arm/j3", "5", "--clamp"]));
    assert_eq!(
        ok(conductor(&d).args(["get", "arm/j3", "--raw"])).trim(),
        "2"
    );
    // Read-only sensors refuse setpoints.
    assert!(fails(conductor(&d).args(["set", "sensors/a", "0"])).contains("read-only"));

    // echo: a sine sensor's samples, in range and in time order.
    let out = ok(conductor(&d).args(["echo", "sensors/a", "--count", "20", "--json"]));
    let samples: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(samples.len(), 20);
    let mut last = 0.0;
    for s in &samples {
        let v = s["value"].as_f64().unwrap();
        assert!((-1.0..=1.0).contains(&v), "{s}");
        let t = s["t_sample"].as_f64().unwrap();
        assert!(t > last, "sample times go forward: {out}");
        last = t;
    }

    // top: one row per executor, at the manifest's base rates, normal scheduling (--no-rt).
    let out = ok(conductor(&d).args(["top", "--once", "--wide"]));
    let header: Vec<&str> = out.lines().nth(1).unwrap().split_whitespace().collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    for (sub, target, states) in [("arm", "200.0", "6"), ("sensors", "250.0", "3")] {
        let r: Vec<&str> = out
            .lines()
            .find(|l| l.starts_with(sub))
            .unwrap_or_else(|| panic!("no {sub} row: {out}"))
            .split_whitespace()
            .collect();
        assert_eq!(r[col("TARGET_HZ")], target, "{out}");
        assert!(r[col("STALE")].ends_with(&format!("/{states}")), "{out}");
        assert_eq!(r[col("RT")], "no", "{out}");
        // One device per state; nothing tripped, faulted or refused on simulated buses.
        assert!(r[col("ENABLED")].ends_with(&format!("/{states}")), "{out}");
        for c in ["TRIPPED", "FAULTED", "LINKS_DOWN", "OUTAGES", "REFUSED"] {
            assert_eq!(r[col(c)], "0", "{c}: {out}");
        }
        let achieved: f64 = r[col("RATE_HZ")].parse().unwrap();
        let target: f64 = target.parse().unwrap();
        assert!(achieved > 0.5 * target && achieved < 1.1 * target, "{out}");
    }

    // SIGINT: the launcher stops both executors in order and exits 0.
    let (ok_exit, stderr) = launcher.interrupt();
    assert!(ok_exit, "launcher failed: {stderr}");
    assert!(stderr.contains("2 executor(s) stopped"), "{stderr}");
}
