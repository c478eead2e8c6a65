//! The fault campaign for one minute, as CI runs it: `conductor-soak` drives the simulated
//! robots of deploy/ (the Dynamixel leg, the MIT leg over SLCAN, the Score board under its
//! gateway) through byte faults on every bus, unplugs, executor, gateway and controller kills,
//! controller stalls and command floods, and checks them from outside. Every check must pass:
//! no wrong value published or written, every safe state in time, every fault counted, nothing
//! growing.

use std::process::{Command, Stdio};

mod support;

#[test]
fn a_minute_of_faults_passes_every_check() {
    let dir = std::env::temp_dir();
    let json = dir.join(format!("conductor-soak-test-{}.json", std::process::id()));
    let log = dir.join(format!("conductor-soak-test-{}.log", std::process::id()));
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_conductor-soak"));
    // As in production (the manifests' SCHED_FIFO, the campaign's threads just below) where
    // that is allowed; elsewhere at normal scheduling.
    if !nix::unistd::geteuid().is_root() {
        cmd.arg("--no-rt");
    }
    let out = cmd
        .args(["--duration", "60s", "--seed", "7"])
        .arg("--json")
        .arg(&json)
        .arg("--root")
        .arg(support::edge::root())
        .arg("--executor")
        .arg(support::EXECUTOR)
        // The executors' and the campaign's running commentary: kept for a failure.
        .stderr(Stdio::from(std::fs::File::create(&log).unwrap()))
        .output()
        .expect("conductor-soak runs");
    let table = String::from_utf8_lossy(&out.stdout).into_owned();
    let tail = || {
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        lines[lines.len().saturating_sub(60)..].join("\n")
    };
    assert!(out.status.success(), "{table}\n{}", tail());
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(report["passed"], true, "{table}");
    let robots = report["robots"].as_array().unwrap();
    assert_eq!(robots.len(), 2);
    for r in robots {
        let name = r["subsystem"].as_str().unwrap();
        assert_eq!(r["wrong_published"], 0, "{name}: {table}");
        assert_eq!(r["wrong_written"], 0, "{name}: {table}");
        assert!(
            r["samples_checked"].as_u64().unwrap() > 1000,
            "{name}: {table}"
        );
        // Every controller death timed from its last command and judged, none late or unsafe
        // (late only by a trip tick the executor measured as late is counted apart, and kept
        // whole in the report).
        let safe = &r["safe_state"];
        assert!(safe["episodes"].as_u64().unwrap() > 0, "{name}: {table}");
        assert_eq!(
            safe["in_time"].as_u64().unwrap()
                + safe["resent"].as_u64().unwrap()
                + safe["late_tick"].as_u64().unwrap(),
            safe["episodes"].as_u64().unwrap(),
            "{name}: {table}"
        );
        for e in safe["bad"].as_array().unwrap() {
            assert_eq!(e["verdict"], "late_tick", "{name}: {table}");
        }
        for kind in [
            "byte_faults",
            "unplug",
            "executor_kill",
            "controller_kill",
            "controller_stall",
            "flood",
        ] {
            let k = &r["faults"][kind];
            assert!(
                k["injected"].as_u64().unwrap_or(0) > 0,
                "{name}: no {kind}: {table}"
            );
        }
    }
    // The Score board: its own rows, every kind injected, nothing wrong, every death safe.
    let b = &report["board"];
    assert_eq!(b["subsystem"], "score-rp2040", "{table}");
    assert_eq!(b["wrong_published"], 0, "{table}");
    assert_eq!(b["wrong_written"], 0, "{table}");
    assert_eq!(b["unsafe_events"], 0, "{table}");
    assert!(b["samples_checked"].as_u64().unwrap() > 1000, "{table}");
    assert!(b["writes_checked"].as_u64().unwrap() > 1000, "{table}");
    assert_eq!(b["safe_in_time"], b["controller_deaths"], "{table}");
    for kind in [
        "unplug",
        "gateway_kill",
        "controller_kill",
        "controller_stall",
        "flood",
    ] {
        let k = &b["faults"][kind];
        assert!(
            k["injected"].as_u64().unwrap_or(0) > 0 && k["recovered"] == k["injected"],
            "score-rp2040: {kind}: {table}"
        );
    }
    // Damaged frames were sent both ways, and the board's CRC check dropped those it got.
    assert!(b["damaged_to_host"].as_u64().unwrap() > 0, "{table}");
    assert!(b["rejected_by_board"].as_u64().unwrap() > 0, "{table}");
    let _ = std::fs::remove_file(&json);
    let _ = std::fs::remove_file(&log);
}
