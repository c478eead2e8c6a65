//! Tools that tell the truth (issue 15, part C): each test here failed on the behaviour before
//! it. `set` with nobody listening fails; `record --duration` keeps exactly the samples published
//! in its window; a recording round-trips every double bit for bit; a recording whose writer
//! was SIGKILLed still replays and plots; replaying into a domain with live owners names them;
//! `list PATTERN` without a match fails.

mod support;

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use conductor_bus::{
    status, Bus, CommandReceiver, Controller, Domain, StatePublisher, StateSubscriber,
};
use conductor_testkit::number_after;
use support::*;

#[test]
fn set_without_a_listening_executor_fails_and_says_so() {
    let d = Domain::unique("nolisten").unwrap();
    let bus = Bus::open(&d, "test-owner").unwrap();
    // A writable state whose owner takes no commands: the commands service exists (held open by
    // another controller, as while an executor restarts) but nobody receives on it.
    let mut owner = StatePublisher::create(&bus, "leg", &leg(100.0)).unwrap();
    owner
        .publish(0, 0, conductor_bus::monotonic_ns(), 0.0, 0)
        .unwrap();
    let receiver = CommandReceiver::create(&bus, "leg").unwrap();
    let mut other = Controller::new(&bus);
    other.add_ctrl("leg/knee", 0.1).unwrap();
    other.clear_ctrl();
    drop(receiver);

    let err = fails(conductor(&d).args(["set", "leg/knee", "0.5"]));
    assert!(err.contains("not delivered"), "{err}");
    assert!(
        err.contains("no executor listens for commands of subsystem \"leg\""),
        "{err}"
    );
    // Also without waiting for the verdict: nothing was delivered, whatever --wait says.
    let err = fails(conductor(&d).args(["set", "leg/knee", "0.5", "--wait", "0"]));
    assert!(err.contains("not delivered"), "{err}");

    // With a receiver it is delivered (the verdict is unknown: nobody publishes after it).
    // The frame lives in the sender's shared memory: take it while `set` is still there.
    let mut receiver = CommandReceiver::create(&bus, "leg").unwrap();
    let set = Bg::spawn(conductor(&d).args(["set", "leg/knee", "0.5", "--wait", "0"]));
    let mut frames = Vec::new();
    let end = Instant::now() + Duration::from_secs(10);
    while frames.is_empty() && Instant::now() < end {
        receiver
            .drain(|f| frames.push(f.setpoints().to_vec()))
            .unwrap();
        std::thread::sleep(Duration::from_millis(1));
    }
    let (success, stderr) = set.finish();
    assert!(success, "{stderr}");
    assert_eq!(frames.len(), 1, "{stderr}");
    assert_eq!((frames[0][0].index, frames[0][0].value), (0, 0.5));
}

#[test]
fn list_with_a_pattern_that_matches_nothing_fails() {
    let (d, _leg) = domain_with_leg("listnone", 100.0, leg);
    let err = fails(conductor(&d).args(["list", "arm/*"]));
    assert!(err.contains("no state matches \"arm/*\""), "{err}");
    assert!(err.contains("leg/knee"), "{err}");
    // A matching pattern and no pattern still succeed.
    ok(conductor(&d).args(["list", "leg/*"]));
    ok(conductor(&d).arg("list"));
}

/// `(log_time, publish_time, sequence)` per topic, and the metadata records, of an MCAP file.
type Messages = BTreeMap<String, Vec<(u64, u64, u32)>>;
fn read_file(file: &Path) -> (Messages, BTreeMap<String, BTreeMap<String, String>>) {
    let buf = std::fs::read(file).unwrap();
    let mut out: Messages = BTreeMap::new();
    for m in mcap::MessageStream::new(&buf).unwrap() {
        let m = m.unwrap();
        out.entry(m.channel.topic.clone()).or_default().push((
            m.log_time,
            m.publish_time,
            m.sequence,
        ));
    }
    let summary = mcap::Summary::read(&buf).unwrap().unwrap();
    let mut meta = BTreeMap::new();
    for idx in &summary.metadata_indexes {
        let md = mcap::read::metadata(&buf, idx).unwrap();
        meta.insert(md.name.clone(), md.metadata);
    }
    (out, meta)
}

#[test]
fn record_duration_keeps_exactly_the_samples_published_in_its_window() {
    let (d, _leg) = domain_with_leg("window", 250.0, leg);
    // An independent observer of leg/knee, to know every sample and its publish time.
    let bus = Bus::open(&d, "test-observer").unwrap();
    let mut obs = StateSubscriber::with_buffer(&bus, "leg/knee", 256).unwrap();
    // Let samples be published before the recorder starts (the one it would be handed first).
    std::thread::sleep(Duration::from_millis(300));
    let dir = tempdir("window");
    let file = dir.join("w.mcap");
    let rec = Bg::spawn(&mut record(&d, &["leg/*", "--duration", "3"], &file));
    let mut seen = Vec::new();
    let end = Instant::now() + Duration::from_secs(60);
    while !std::fs::read(&file).is_ok_and(|b| mcap::read::footer(&b).is_ok()) {
        assert!(Instant::now() < end, "the recording did not finish");
        obs.drain(|s| seen.push((s.t_publish_ns, s.seq))).unwrap();
        std::thread::sleep(Duration::from_millis(5));
    }
    let (success, stderr) = rec.finish();
    assert!(success, "{stderr}");
    obs.drain(|s| seen.push((s.t_publish_ns, s.seq))).unwrap();
    assert_eq!(obs.missed(), 0, "the observer lost samples");

    let (msgs, meta) = read_file(&file);
    let ws: u64 = meta["conductor"]["start_monotonic_ns"].parse().unwrap();
    let we = ws + 3_000_000_000;
    // Exactly the knee samples the observer saw published in [start, start + 3 s).
    let want: Vec<(u64, u32)> = seen
        .iter()
        .filter(|(t, _)| (ws..we).contains(t))
        .map(|&(t, seq)| (t, seq as u32))
        .collect();
    let got: Vec<(u64, u32)> = msgs["/leg/knee"].iter().map(|m| (m.1, m.2)).collect();
    assert_eq!(got, want);
    // 3 s at 250 Hz: about 750 (not 760), the same for every state.
    assert!((700..=752).contains(&got.len()), "{}", got.len());
    for (topic, m) in &msgs {
        assert!(
            m.iter().all(|m| (ws..we).contains(&m.1)),
            "{topic}: a sample outside the window"
        );
        assert!(m.len().abs_diff(got.len()) <= 1, "{topic}: {}", m.len());
    }
    // The summary states the window.
    let s = &meta["conductor.summary"];
    assert_eq!(s["stopped_by"], "duration");
    assert_eq!(s["window_start_monotonic_ns"], ws.to_string());
    assert_eq!(s["window_end_monotonic_ns"], we.to_string());
    assert!(s["published_before_start"].parse::<u64>().unwrap() >= 3);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Classes of values states carry, each with its own flags: a joint, an enable, a counter, a
/// force sensor over many magnitudes, and a faulting sensor (NaN, infinities, signed zero).
fn value_of(class: usize, i: u64, x: &mut u64) -> (f64, u32) {
    *x ^= *x << 13;
    *x ^= *x >> 7;
    *x ^= *x << 17;
    let unit = (*x >> 11) as f64 / (1u64 << 53) as f64;
    // `flag` when `i` is a multiple of `every`.
    let every = |every: u64, flag: u32| if i.is_multiple_of(every) { flag } else { 0 };
    match class {
        0 => (
            unit * 3.2 - 1.6,
            status::SIMULATED | every(2, status::CLAMPED),
        ),
        1 => ((i % 2) as f64, every(3, status::DISABLED)),
        2 => ((i * 7_919 + (1 << 52)) as f64, 0),
        3 => (
            (unit - 0.5) * 10f64.powi((i % 40) as i32 - 20),
            every(4, status::STALE),
        ),
        _ => {
            let v = [
                f64::NAN,
                f64::INFINITY,
                f64::NEG_INFINITY,
                -0.0,
                f64::from_bits(*x),
                f64::from_bits(1),
            ][(i % 6) as usize];
            let flags = status::DEVICE_FAULT | status::REJECTED | status::TRIPPED;
            (v, flags | every(2, status::WATCHDOG))
        }
    }
}

#[test]
fn record_and_replay_round_trip_every_double_bit_for_bit() {
    let d = Domain::unique("bits-src").unwrap();
    let names = ["joint", "enable", "counter", "force", "fault"];
    let specs: Vec<_> = names
        .iter()
        .enumerate()
        .map(|(i, n)| {
            state(
                i as u32,
                n,
                "",
                false,
                (f64::NEG_INFINITY, f64::INFINITY),
                500.0,
                "",
            )
        })
        .collect();
    // The publisher, on its own thread; it returns every (tick, value bits, flags) it sent.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let pub_thread = {
        let (d, stop) = (d.clone(), stop.clone());
        std::thread::spawn(move || {
            let bus = Bus::open(&d, "test-publisher").unwrap();
            let mut p = StatePublisher::create(&bus, "bits", &specs).unwrap();
            ready_tx.send(()).unwrap();
            let mut sent = vec![BTreeMap::new(); 5];
            let mut x = 0x2545_f491_4f6c_dd1d_u64;
            let mut tick = 0;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                let t = conductor_bus::monotonic_ns();
                for (class, sent) in sent.iter_mut().enumerate() {
                    let (v, flags) = value_of(class, tick, &mut x);
                    p.publish(class, tick, t, v, flags).unwrap();
                    sent.insert(tick, (v.to_bits(), flags));
                }
                p.notify_tick().unwrap();
                tick += 1;
                std::thread::sleep(Duration::from_millis(2));
            }
            sent
        })
    };
    ready_rx.recv().unwrap();
    let dir = tempdir("bits");
    let file = dir.join("bits.mcap");
    ok(conductor(&d)
        .args([
            "record",
            "bits/*",
            "--duration",
            "1.5",
            "--no-progress",
            "-o",
        ])
        .arg(&file));
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let sent = pub_thread.join().unwrap();

    // Replay into another domain and read every sample back from the bus.
    let d2 = Domain::unique("bits-dst").unwrap();
    let mut cmd = conductor(&d2);
    cmd.args(["replay", "--rate-scale", "4", "--wait-subscribers", "1"])
        .arg("--no-progress")
        .arg(&file);
    let replay = Bg::spawn(&mut cmd);
    let bus = Bus::open(&d2, "test-subscriber").unwrap();
    let end = Instant::now() + Duration::from_secs(20);
    let mut subs = Vec::new();
    for n in names {
        subs.push(loop {
            match StateSubscriber::with_buffer(&bus, &format!("bits/{n}"), 256) {
                Ok(s) => break s,
                Err(e) => {
                    assert!(Instant::now() < end, "{e}");
                    std::thread::sleep(Duration::from_millis(10));
                }
            }
        });
    }
    let mut got = vec![Vec::new(); names.len()];
    loop {
        // Peek without reaping: /proc says whether the child is a zombie (exited) yet.
        let exited = std::fs::read_to_string(format!("/proc/{}/stat", replay.child.id()))
            .map_or(true, |s| s.split_whitespace().nth(2) == Some("Z"));
        for (sub, g) in subs.iter_mut().zip(&mut got) {
            sub.drain(|s| g.push((s.tick, s.value.to_bits(), s.status)))
                .unwrap();
        }
        if exited {
            break;
        }
        assert!(Instant::now() < end, "replay did not end");
        std::thread::sleep(Duration::from_millis(1));
    }
    let (success, stderr) = replay.finish();
    assert!(success, "{stderr}");
    for ((name, g), sent) in names.iter().zip(&got).zip(&sent) {
        assert!(g.len() > 300, "{name}: {} samples", g.len());
        let mut off = 0;
        for &(tick, bits, flags) in g {
            let (want_bits, want_flags) = sent[&tick];
            off += usize::from(bits != want_bits);
            assert_eq!(flags, want_flags | status::REPLAYED, "{name} tick {tick}");
        }
        assert_eq!(off, 0, "{name}: {off} of {} values changed", g.len());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_recording_cut_by_sigkill_still_replays_and_plots() {
    let (d, _leg) = domain_with_leg("killed", 500.0, leg);
    let dir = tempdir("killed");
    let file = dir.join("killed.mcap");
    let mut rec = Bg::spawn(&mut record(&d, &["leg/*"], &file));
    std::thread::sleep(Duration::from_millis(2600));
    rec.child.kill().unwrap(); // SIGKILL: no footer, no summary, an open chunk lost
    rec.child.wait().unwrap();
    let buf = std::fs::read(&file).unwrap();
    assert!(mcap::read::footer(&buf).is_err(), "the file has no end");

    let d2 = Domain::unique("killed-dst").unwrap();
    let out = conductor(&d2)
        .args(["replay", "--rate-scale", "20", "--no-progress"])
        .arg(&file)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("ends early"), "{stderr}");
    // At least the chunks closed each second: 1 s of 3 states at 500 Hz.
    let published: u64 = number_after(&stderr, "replayed ");
    assert!(published >= 3 * 450, "{stderr}");

    let png = dir.join("killed.png");
    let out = conductor(&d2)
        .arg("plot")
        .arg(&file)
        .args(["leg/*", "-o"])
        .arg(&png)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("ends early"), "{stderr}");
    assert_eq!(&std::fs::read(&png).unwrap()[1..4], b"PNG");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn replay_into_a_domain_with_live_owners_names_them_and_the_way_out() {
    let (d, _leg) = domain_with_leg("clash", 200.0, leg);
    let dir = tempdir("clash");
    let file = dir.join("leg.mcap");
    ok(conductor(&d)
        .args([
            "record",
            "leg/*",
            "--duration",
            "0.3",
            "--no-progress",
            "-o",
        ])
        .arg(&file));
    let err = fails(conductor(&d).arg("replay").arg(&file).arg("--no-progress"));
    assert!(!err.contains("IncompatibleAttributes"), "{err}");
    assert!(
        err.contains("3 recorded state(s) are live there (leg/knee, leg/hip, leg/current)"),
        "{err}"
    );
    assert!(err.contains("written by executor/leg"), "{err}");
    assert!(err.contains("conductor --domain replay replay"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn simulated_states_of_the_shipped_manifests_start_inside_their_limits() {
    use conductor_manifest::Manifest;
    let mut checked = Vec::new();
    let mut manifests: Vec<_> = std::fs::read_dir(workspace().join("deploy"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    manifests.sort();
    for path in manifests {
        let m = Manifest::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        // Subsystems on simulated hardware only: the others need their robot.
        let sims: Vec<_> = m
            .subsystems
            .iter()
            .filter(|s| {
                !s.states.is_empty() && (0..s.states.len()).all(|i| s.state_is_simulated(i))
            })
            .collect();
        if sims.is_empty() {
            continue;
        }
        let d = Domain::unique("limits").unwrap();
        let mut cmd = conductor(&d);
        cmd.arg("launch").arg(&path).args(["--no-rt", "--quiet"]);
        for s in &sims {
            cmd.args(["--only", &s.name]);
        }
        let _launcher = Bg::spawn(&mut cmd);
        let bus = Bus::open(&d, "test-limits").unwrap();
        for sub in &sims {
            for st in &sub.states {
                let name = format!("{}/{}", sub.name, st.name);
                let end = Instant::now() + Duration::from_secs(30);
                let mut s = loop {
                    match StateSubscriber::with_buffer(&bus, &name, 64) {
                        Ok(s) => break s,
                        Err(e) => {
                            assert!(Instant::now() < end, "{}: {name}: {e}", path.display());
                            std::thread::sleep(Duration::from_millis(20));
                        }
                    }
                };
                // The first samples it hands out, from the executor's first ticks on.
                let mut values = Vec::new();
                while values.len() < 20 {
                    assert!(Instant::now() < end, "{name}: only {values:?}");
                    s.drain(|x| values.push(x.value)).unwrap();
                    std::thread::sleep(Duration::from_millis(2));
                }
                for v in &values {
                    assert!(
                        (st.min..=st.max).contains(v),
                        "{}: {name} = {v}, outside its limits [{}, {}]",
                        path.display(),
                        st.min,
                        st.max
                    );
                }
                checked.push(name);
            }
        }
    }
    // The mini-Hubo leg's six joints are among them.
    for j in ["RAR", "RAP", "RKP", "RHR", "RHP", "RHY"] {
        assert!(checked.contains(&format!("right_leg/{j}")), "{checked:?}");
    }
}
