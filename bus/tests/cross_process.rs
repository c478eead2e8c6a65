//! Cross-process behaviour of the bus, with real separate processes on private domains.

mod support;

use std::time::Duration;

use conductor_bus::{Bus, Controller, Domain, StateSubscriber, MAX_SETPOINTS};
use support::{parse_report, Peer};

/// Polls `f` until it returns Some or `secs` pass.
fn eventually<T>(secs: u64, f: impl FnMut() -> Option<T>) -> T {
    conductor_testkit::eventually(Duration::from_secs(secs), "condition", f)
}

/// A peer publishing `count` counter samples of `arm/q` at `rate` Hz through a `buffer`-deep
/// queue, starting once one subscriber is there.
fn counting_publisher(d: &Domain, rate: u32, count: u32, buffer: usize) -> Peer {
    let (rate, count, buffer) = (rate.to_string(), count.to_string(), buffer.to_string());
    Peer::start(
        d,
        &[
            "publish",
            "--subsystem",
            "arm",
            "--states",
            "q",
            "--rate",
            &rate,
            "--count",
            &count,
            "--counter",
            "--buffer",
            &buffer,
            "--wait-subscribers",
            "1",
        ],
    )
    .ready()
}

#[test]
fn ten_thousand_samples_cross_processes_without_loss() {
    let d = Domain::unique("noloss").unwrap();
    // Paced at 10 kHz with a 2048-deep queue: the subscriber may stall up to 200 ms and lose
    // nothing, which is the configured buffer's promise.
    let publisher = counting_publisher(&d, 10000, 10000, 2048);
    let sub = Peer::start(
        &d,
        &["subscribe", "arm/q", "--count", "10000", "--buffer", "2048"],
    )
    .ready();
    let (ok, lines) = sub.finish();
    assert!(ok);
    let (received, missed, last) = parse_report(&lines[0]);
    assert_eq!((received, missed, last), (10_000, 0, Some(9_999)));
    drop(publisher);
}

#[test]
fn slow_subscriber_sees_sequence_gaps() {
    let d = Domain::unique("gaps").unwrap();
    let publisher = counting_publisher(&d, 2000, 2000, 8);
    // 8-deep queue, 5 ms per sample against 0.5 ms publishing: most samples are overwritten.
    let sub = Peer::start(
        &d,
        &[
            "subscribe",
            "arm/q",
            "--count",
            "2000",
            "--buffer",
            "8",
            "--slow-ms",
            "5",
        ],
    )
    .ready();
    let (ok, lines) = sub.finish();
    assert!(ok);
    let (received, missed, last) = parse_report(&lines[0]);
    assert!(missed > 1000, "expected heavy loss, got {lines:?}");
    // Every sample is either received or accounted for as missed, up to the last one read.
    assert_eq!(received + missed, last.unwrap() + 1);
    drop(publisher);
}

#[test]
fn a_frame_of_twenty_setpoints_arrives_whole() {
    let d = Domain::unique("frame").unwrap();
    let names: Vec<String> = (0..20).map(|i| format!("j{i}")).collect();
    let publisher = Peer::start(
        &d,
        &[
            "publish",
            "--subsystem",
            "body",
            "--states",
            &names.join(","),
            "--rate",
            "50",
            "--min",
            "-100",
            "--max",
            "100",
        ],
    )
    .ready();
    let receiver = Peer::start(&d, &["receive-commands", "--subsystem", "body"]).ready();
    // This test process is the sender.
    let bus = Bus::open(&d, "test-sender").unwrap();
    let mut ctl = Controller::new(&bus);
    for (i, n) in names.iter().enumerate() {
        ctl.add_ctrl(&format!("body/{n}"), i as f64 * 1.5).unwrap();
    }
    assert_eq!(ctl.check_ctrl("body/j3"), Some(4.5));
    assert_eq!(ctl.send_ctrl().unwrap(), 20);
    assert_eq!(ctl.check_ctrl("body/j3"), None);
    let line = receiver.line(10);
    let expect: Vec<String> = (0..20).map(|i| format!("{i}={}", i as f64 * 1.5)).collect();
    assert_eq!(line, format!("frame seq=1 count=20 {}", expect.join(" ")));
    drop(publisher);
}

#[test]
fn discovery_lists_states_with_metadata() {
    let d = Domain::unique("disc").unwrap();
    let _p = Peer::start(
        &d,
        &[
            "publish",
            "--subsystem",
            "leg",
            "--states",
            "hip,knee,ankle",
            "--rate",
            "250",
            "--units",
            "rad",
            "--min",
            "-2.5",
            "--max",
            "2.5",
        ],
    )
    .ready();
    let lister = Peer::start(&d, &["list"]);
    let (ok, lines) = lister.finish();
    assert!(ok);
    assert_eq!(
        lines,
        [
            "leg/hip index=0 units=rad writable=true rate_hz=250 limits=-2.5,2.5 device=sim0",
            "leg/knee index=1 units=rad writable=true rate_hz=250 limits=-2.5,2.5 device=sim1",
            "leg/ankle index=2 units=rad writable=true rate_hz=250 limits=-2.5,2.5 device=sim2",
        ]
    );
    // The API sees the owner's node too.
    let bus = Bus::open(&d, "test-lister").unwrap();
    let states = bus.list_states().unwrap();
    assert!(states[0].nodes.iter().any(|n| n == "peer-publish/leg"));
}

#[test]
fn two_domains_do_not_see_each_other() {
    let a = Domain::unique("doma").unwrap();
    let b = Domain::unique("domb").unwrap();
    let _pa = Peer::start(&a, &["publish", "--subsystem", "leg", "--states", "knee"]).ready();
    let _pb = Peer::start(&b, &["publish", "--subsystem", "arm", "--states", "elbow"]).ready();
    let bus_a = Bus::open(&a, "test-a").unwrap();
    let bus_b = Bus::open(&b, "test-b").unwrap();
    let names = |bus: &Bus| -> Vec<String> {
        bus.list_states()
            .unwrap()
            .iter()
            .map(|s| s.qualified_name())
            .collect()
    };
    assert_eq!(names(&bus_a), ["leg/knee"]);
    assert_eq!(names(&bus_b), ["arm/elbow"]);
    assert!(StateSubscriber::new(&bus_a, "arm/elbow").is_err());
    // And a subscriber in its own domain does receive.
    let mut s = StateSubscriber::new(&bus_b, "arm/elbow").unwrap();
    eventually(10, || s.receive().unwrap());
}

#[test]
fn frame_capacity_is_enforced_with_a_typed_error() {
    let d = Domain::unique("full").unwrap();
    let names: Vec<String> = (0..MAX_SETPOINTS + 1).map(|i| format!("s{i}")).collect();
    let _p = Peer::start(
        &d,
        &[
            "publish",
            "--subsystem",
            "big",
            "--states",
            &names.join(","),
            "--rate",
            "10",
        ],
    )
    .ready();
    let _rx = Peer::start(&d, &["receive-commands", "--subsystem", "big"]).ready();
    let bus = Bus::open(&d, "test-full").unwrap();
    let mut ctl = Controller::new(&bus);
    for n in &names[..MAX_SETPOINTS] {
        ctl.add_ctrl(&format!("big/{n}"), 0.1).unwrap();
    }
    // Re-setting a state already in the frame replaces it and still fits.
    ctl.add_ctrl("big/s0", 0.2).unwrap();
    let err = ctl
        .add_ctrl(&format!("big/{}", names[MAX_SETPOINTS]), 0.1)
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        format!("command frame for subsystem \"big\" is full ({MAX_SETPOINTS} setpoints); send_ctrl() first")
    );
}
