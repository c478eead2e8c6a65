//! Interop with an independent implementation: the official iceoryx2 Python package (PyPI,
//! same 0.10.0 as the crate) talks to this Rust process using only the ctypes mirror printed in
//! bus/ABI.md, which this test extracts from the document itself.

use conductor_testkit::{python, workspace};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use conductor_bus::{
    monotonic_ns, status, Bus, CommandReceiver, Domain, StateMeta, StatePublisher, StateSpec,
};

/// The ```python block after `<!-- conductor_abi.py -->` in bus/ABI.md.
fn abi_mirror_from_doc() -> String {
    let doc = std::fs::read_to_string(workspace().join("bus/ABI.md")).unwrap();
    let after = doc
        .split("<!-- conductor_abi.py -->")
        .nth(1)
        .expect("marker");
    let body = after.split("```python\n").nth(1).expect("python block");
    body.split("\n```").next().unwrap().to_string()
}

fn json_field<'a>(line: &'a str, key: &str) -> &'a str {
    let start = line.find(&format!("\"{key}\": ")).expect(key) + key.len() + 4;
    let rest = &line[start..];
    let end = if rest.starts_with('[') {
        rest.find(']').unwrap() + 1
    } else if rest.starts_with('{') {
        rest.find('}').unwrap() + 1
    } else {
        rest.find([',', '}']).unwrap()
    };
    &rest[..end]
}

fn numbers(list: &str) -> Vec<f64> {
    list.trim_matches(['[', ']'])
        .split(',')
        .map(|s| s.trim().parse().unwrap())
        .collect()
}

#[test]
fn python_subscribes_and_commands_through_the_documented_abi() {
    let dir = std::env::temp_dir().join(format!("conductor-abi-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("conductor_abi.py"), abi_mirror_from_doc()).unwrap();

    let d = Domain::unique("py").unwrap();
    let bus = Bus::open(&d, "rust-side").unwrap();
    let specs = StateSpec::numbered(
        ["counter", "b", "c"],
        &StateMeta {
            index: 0,
            units: "rad".into(),
            writable: true,
            rate_hz: 500.0,
            min: -5.0,
            max: 5.0,
            device: "dev".into(),
        },
    );
    let mut publisher = StatePublisher::create(&bus, "py", &specs).unwrap();
    let mut commands = CommandReceiver::create(&bus, "py").unwrap();

    let script = workspace().join("bus/tests/python/interop.py");
    let (mut child, rx) = conductor_testkit::spawn_with_lines(
        Command::new(python())
            .arg(&script)
            .arg(&dir)
            .arg(d.name())
            .stdin(Stdio::piped())
            .stderr(Stdio::inherit()),
    );

    // Publish the sample number at 500 Hz until Python has sent its frame and we received it.
    let mut lines = Vec::new();
    let mut frame = None;
    let start = Instant::now();
    let mut tick = 0u64;
    while frame.is_none() {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "timed out: {lines:?}"
        );
        publisher
            .publish(0, tick, monotonic_ns(), tick as f64, status::SIMULATED)
            .unwrap();
        publisher.notify_tick().unwrap();
        tick += 1;
        commands
            .drain(|f| {
                frame = Some(
                    f.setpoints()
                        .iter()
                        .map(|s| (s.index, s.value))
                        .collect::<Vec<_>>(),
                )
            })
            .unwrap();
        while let Ok(l) = rx.try_recv() {
            lines.push(l);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    assert_eq!(frame.unwrap(), [(0, 1.25), (1, -2.5), (2, 3.75)]);
    drop(child.stdin.take()); // lets the Python side exit
    assert!(child.wait().unwrap().success());
    while let Ok(l) = rx.recv_timeout(Duration::from_millis(200)) {
        lines.push(l);
    }

    let attrs = lines.iter().find(|l| l.contains("\"attributes\"")).unwrap();
    for kv in [
        "\"conductor.abi\": \"2\"",
        "\"conductor.kind\": \"state\"",
        "\"conductor.index\": \"0\"",
        "\"conductor.units\": \"rad\"",
        "\"conductor.limits\": \"-5,5\"",
        "\"conductor.writable\": \"true\"",
    ] {
        assert!(attrs.contains(kv), "{kv} missing in {attrs}");
    }
    let samples = lines.iter().find(|l| l.contains("\"samples\"")).unwrap();
    let seqs = numbers(json_field(samples, "seqs"));
    let values = numbers(json_field(samples, "values"));
    assert_eq!(seqs.len(), 50);
    for w in seqs.windows(2) {
        assert_eq!(w[1], w[0] + 1.0, "Python saw a gap: {seqs:?}");
    }
    // We published value == tick == seq for state 0.
    assert_eq!(seqs, values);
    assert_eq!(numbers(json_field(samples, "ticks")), values);
    let _ = std::fs::remove_dir_all(&dir);
}
