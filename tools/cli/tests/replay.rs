//! A recording cut by SIGINT is finalised; `replay` reproduces the recorded values on the bus;
//! `plot` draws them.

mod support;

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use conductor_bus::{status, Bus, Domain, StateSubscriber};
use conductor_examples::{motor, sim};
use conductor_testkit::number_after;
use serde_json::Value;
use support::*;

#[test]
fn a_recording_cut_by_sigint_is_finalised_and_reads() {
    let (d, _leg) = domain_with_leg("sigint", 500.0, leg);
    let dir = tempdir("sigint");
    let file = dir.join("cut.mcap");
    let rec = Bg::spawn(&mut record(&d, &["*"], &file));
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

/// A small recording written directly with the mcap crate in the documented layout: one state
/// `arm/elbow` whose value is the sample number, `n` samples at 100 Hz.
fn synthetic(path: &Path, n: u64) {
    use conductor_cli::recording as r;
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::Writer::new(f).unwrap();
    let schema = w
        .add_schema(r::SCHEMA_NAME, r::SCHEMA_ENCODING, r::SCHEMA.as_bytes())
        .unwrap();
    let ch = add_state_channel(&mut w, schema, "arm", "elbow", 4);
    for i in 0..n {
        let t = 1_000_000_000 + i * 10_000_000;
        let body = serde_json::json!({"value": i as f64, "status": 0, "t_sample": t as f64 * 1e-9, "seq": i, "tick": i});
        write_sample(&mut w, ch, i, t, body.to_string().as_bytes());
    }
    w.finish().unwrap();
}

#[test]
fn replay_loops_until_interrupted() {
    let dir = tempdir("loop");
    let file = dir.join("elbow.mcap");
    synthetic(&file, 20);
    let d = Domain::unique("loop").unwrap();
    let mut cmd = conductor(&d);
    cmd.args([
        "replay",
        "--loop",
        "--wait-subscribers",
        "1",
        "--no-progress",
    ])
    .arg(&file);
    let replay = Bg::spawn(&mut cmd);
    let bus = Bus::open(&d, "test-subscriber").unwrap();
    let end = Instant::now() + Duration::from_secs(10);
    let mut sub = loop {
        match StateSubscriber::with_buffer(&bus, "arm/elbow", 256) {
            Ok(s) => break s,
            Err(e) => {
                assert!(Instant::now() < end, "{e}");
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    };
    // Index renumbered from 0, read-only; the rest of the metadata as recorded.
    let m = &sub.info().meta;
    assert_eq!(
        (m.index, m.writable, m.units.as_str(), m.rate_hz),
        (0, false, "rad", 100.0)
    );
    let mut values = Vec::new();
    while values.len() < 50 {
        assert!(Instant::now() < end, "only {values:?}");
        sub.drain(|s| values.push(s.value)).unwrap();
        std::thread::sleep(Duration::from_millis(2));
    }
    let (success, stderr) = replay.interrupt();
    assert!(success, "{stderr}");
    // 0..19, 0..19, ...: at least two passes finished before the interrupt.
    let want: Vec<f64> = (0..values.len()).map(|i| (i % 20) as f64).collect();
    assert_eq!(values, want);
    let passes: u64 = number_after(&stderr, "sample(s) in ");
    assert!(passes >= 2, "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn replay_and_plot_refuse_files_that_are_not_conductor_recordings() {
    let dir = tempdir("foreign");
    let d = Domain::unique("foreign").unwrap();
    // Not MCAP at all.
    let junk = dir.join("junk.mcap");
    std::fs::write(&junk, b"definitely not an mcap file").unwrap();
    let err = fails(conductor(&d).arg("replay").arg(&junk));
    assert!(err.contains("junk.mcap: MCAP:"), "{err}");
    // MCAP, but a foreign channel.
    let foreign = dir.join("foreign.mcap");
    let mut w = mcap::Writer::new(std::io::BufWriter::new(
        std::fs::File::create(&foreign).unwrap(),
    ))
    .unwrap();
    let ch = w
        .add_channel(0, "/camera", "cdr", &BTreeMap::new())
        .unwrap();
    w.write_to_known_channel(
        &mcap::records::MessageHeader {
            channel_id: ch,
            sequence: 0,
            log_time: 1,
            publish_time: 1,
        },
        b"\x00\x01",
    )
    .unwrap();
    w.finish().unwrap();
    drop(w);
    let err = fails(conductor(&d).arg("replay").arg(&foreign));
    assert!(
        err.contains("\"/camera\" is not a Conductor state channel"),
        "{err}"
    );
    let err = fails(
        conductor(&d)
            .arg("plot")
            .arg(&foreign)
            .args(["*", "-o"])
            .arg(dir.join("x.png")),
    );
    assert!(err.contains("not a Conductor state channel"), "{err}");
    // A missing file names the file.
    let err = fails(conductor(&d).args(["replay", "/nonexistent/run.mcap"]));
    assert!(err.contains("/nonexistent/run.mcap: No such file"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
