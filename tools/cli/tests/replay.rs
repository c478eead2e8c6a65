//! A recording cut by SIGINT is finalised; `replay` reproduces the recorded values on the bus;
//! `plot` draws them.

mod support;

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use conductor_bus::{status, Bus, Domain, StateSubscriber};
use conductor_examples::{motor, sim};
use serde_json::Value;
use support::*;

#[test]
fn a_recording_cut_by_sigint_is_finalised_and_reads() {
    let d = Domain::unique("sigint").unwrap();
    let _leg = hold_sim(&d, "leg", 500.0, leg(500.0));
    let dir = tempdir("sigint");
    let file = dir.join("cut.mcap");
    let mut cmd = conductor(&d);
    cmd.args(["record", "*", "--no-progress", "-o"]).arg(&file);
    let rec = Bg::spawn(&mut cmd);
    std::thread::sleep(Duration::from_millis(1500));
    let (success, stderr) = rec.interrupt();
    assert!(success, "{stderr}");
    assert!(stderr.contains("stopped by signal"), "{stderr}");

    let r = check_with_python(&file);
    assert_eq!(r["metadata"]["conductor.summary"]["stopped_by"], "signal");
    // A summary section exists (the file was finished, not merely flushed).
    assert!(r["chunks"].as_u64().unwrap() >= 1);
    let channels = r["channels"].as_object().unwrap();
    assert_eq!(channels.len(), 3);
    for (topic, c) in channels {
        let count = c["count"].as_u64().unwrap();
        assert!(count > 100, "{topic}: {count}");
        let span = c["last_seq"].as_u64().unwrap() - c["first_seq"].as_u64().unwrap() + 1;
        assert_eq!(span, count, "{topic}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `(t_ns, value, status)` per topic, straight from the file with the mcap crate.
fn read_mcap(file: &Path) -> BTreeMap<String, Vec<(u64, f64, u32)>> {
    let buf = std::fs::read(file).unwrap();
    let mut out: BTreeMap<String, Vec<(u64, f64, u32)>> = BTreeMap::new();
    for m in mcap::MessageStream::new(&buf).unwrap() {
        let m = m.unwrap();
        let v: Value = serde_json::from_slice(&m.data).unwrap();
        out.entry(m.channel.topic.clone()).or_default().push((
            m.log_time,
            v["value"].as_f64().unwrap(),
            v["status"].as_u64().unwrap() as u32,
        ));
    }
    out
}

#[test]
fn replay_reproduces_the_recorded_values_on_the_bus() {
    // Record a motor whose command changes, so the values are not constant.
    let d = Domain::unique("replay-src").unwrap();
    let sim = sim::spawn(&d, motor::spec(500.0), motor::Motor::default()).unwrap();
    let dir = tempdir("replay");
    let file = dir.join("motor.mcap");
    let mut cmd = conductor(&d);
    cmd.args([
        "record",
        "motor/*",
        "--duration",
        "1.2",
        "--no-progress",
        "-o",
    ])
    .arg(&file);
    let rec = Bg::spawn(&mut cmd);
    std::thread::sleep(Duration::from_millis(300));
    ok(conductor(&d).args(["set", "motor/command", "3"]));
    std::thread::sleep(Duration::from_millis(300));
    ok(conductor(&d).args(["set", "motor/command", "-20", "--clamp"]));
    let (success, stderr) = rec.finish();
    assert!(success, "{stderr}");
    drop(sim);
    let recorded = read_mcap(&file);
    assert_eq!(recorded.len(), 3);

    // Replay into another domain at twice the speed, and subscribe there.
    let d2 = Domain::unique("replay-dst").unwrap();
    let mut cmd = conductor(&d2);
    cmd.args([
        "replay",
        "--rate-scale",
        "2",
        "--wait-subscribers",
        "1",
        "--no-progress",
    ])
    .arg(&file);
    let replay = Bg::spawn(&mut cmd);
    let bus = Bus::open(&d2, "test-subscriber").unwrap();
    let names = ["motor/position", "motor/velocity", "motor/command"];
    let end = Instant::now() + Duration::from_secs(10);
    let mut subs = loop {
        let s: Result<Vec<_>, _> = names
            .iter()
            .map(|n| StateSubscriber::with_buffer(&bus, n, 256))
            .collect();
        match s {
            Ok(s) => break s,
            Err(e) => {
                assert!(Instant::now() < end, "replayed states never appeared: {e}");
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    };
    // Replayed states keep their metadata but are read-only.
    let info = subs[2].info().clone();
    assert_eq!(
        (info.meta.units.as_str(), info.meta.min, info.meta.max),
        ("V", -12.0, 12.0)
    );
    assert!(!info.meta.writable);

    let mut got: Vec<Vec<(u64, f64, u32)>> = vec![Vec::new(); 3];
    let mut done = false;
    while !done {
        done = replay_exited(&replay);
        for (sub, g) in subs.iter_mut().zip(&mut got) {
            sub.drain(|s| g.push((s.t_sample_ns, s.value, s.status)))
                .unwrap();
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let (success, stderr) = replay.finish();
    assert!(success, "{stderr}");
    for (name, g) in names.iter().zip(&got) {
        let want = &recorded[&format!("/{name}")];
        assert_eq!(g.len(), want.len(), "{name}: sample count");
        for (i, (a, b)) in g.iter().zip(want).enumerate() {
            // Bit-identical values; the recorded flags plus REPLAYED.
            assert_eq!(a.1.to_bits(), b.1.to_bits(), "{name}[{i}]");
            assert_eq!(a.2, b.2 | status::REPLAYED, "{name}[{i}]");
        }
        // The timeline is the recording's, compressed by the rate scale: every interval is half
        // the recorded one (f64 arithmetic on ns offsets: well under 1 ns of rounding, ±1 ns
        // for truncation to integer ns on each end).
        for (a, b) in g.windows(2).zip(want.windows(2)) {
            let replayed = a[1].0 as i64 - a[0].0 as i64;
            let expected = (b[1].0 - b[0].0) as f64 / 2.0;
            assert!(
                (replayed as f64 - expected).abs() <= 2.0,
                "{replayed} vs {expected}"
            );
        }
    }
    // The command's step is in the data: it went to 3, then was clamped at -12.
    let cmds: Vec<f64> = got[2].iter().map(|s| s.1).collect();
    assert!(
        cmds.contains(&3.0) && cmds.last() == Some(&-12.0),
        "{cmds:?}"
    );

    // And the same file plots.
    let png = dir.join("motor.png");
    let mut cmd = conductor(&d2);
    cmd.arg("plot")
        .arg(&file)
        .args(["motor/*", "--title", "Motor", "-o"])
        .arg(&png);
    ok(&mut cmd);
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[1..4], b"PNG");
    let _ = std::fs::remove_dir_all(&dir);
}

fn replay_exited(bg: &Bg) -> bool {
    // Peek without reaping: /proc says whether the child is a zombie (exited) yet.
    let stat = std::fs::read_to_string(format!("/proc/{}/stat", bg.child.id())).unwrap_or_default();
    stat.split_whitespace().nth(2).is_none_or(|s| s == "Z")
}
