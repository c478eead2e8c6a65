//! Client-side API over a real bus: State fed by a publisher, TickWaiter, nalgebra gather/scatter.

use std::time::{Duration, Instant};

use conductor_bus::{
    Bus, CommandReceiver, Controller, Domain, Filter, Interpolation, State, StateMeta,
    StatePublisher, StateSpec, TickWaiter,
};

fn owner(bus: &Bus, names: &[&str]) -> (StatePublisher, CommandReceiver) {
    let specs = StateSpec::numbered(
        names.iter().copied(),
        &StateMeta {
            writable: true,
            rate_hz: 100.0,
            ..Default::default()
        },
    );
    (
        StatePublisher::create(bus, "sys", &specs).unwrap(),
        CommandReceiver::create(bus, "sys").unwrap(),
    )
}

#[test]
fn state_history_and_calculus_from_published_samples() {
    let d = Domain::unique("state").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    let (mut p, _rx) = owner(&bus, &["x"]);
    let mut x = State::new(&bus, "sys/x", 512)
        .unwrap()
        .with_filter(Filter::LowPass { cutoff_hz: 1.0 });
    // sin(t) sampled at 100 Hz for 3 s, stamped with synthetic sample times.
    let h = 0.01;
    for k in 0..=300u64 {
        let t = k as f64 * h;
        p.publish(0, k, 1_000_000_000 + k * 10_000_000, t.sin(), 0)
            .unwrap();
        if k % 100 == 0 {
            x.update().unwrap(); // drain periodically so the 256-deep queue never overflows
        }
    }
    x.update().unwrap();
    assert_eq!(x.history().len(), 301);
    assert_eq!(x.subscriber().missed(), 0);
    assert_eq!(x.value().unwrap(), 3.0f64.sin());
    // Same bounds as the History unit tests (method order): cubic h⁴/24, derivative h²/3,
    // trapezoid T·h²/12.
    let v = x.at(-0.505, Interpolation::Cubic).unwrap();
    assert!((v - (3.0f64 - 0.505).sin()).abs() < h.powi(4) / 24.0);
    assert!((x.derivative().unwrap() - 3.0f64.cos()).abs() < h * h / 3.0);
    assert!((x.integral() - (1.0 - 3.0f64.cos())).abs() < 3.0 * h * h / 12.0);
    let f = x.filtered().unwrap();
    assert!(
        f.abs() < 1.0 && f != x.value().unwrap(),
        "low-pass output {f}"
    );
    let s = x.spectrum(256).unwrap();
    assert!((s.resolution_hz - 100.0 / 256.0).abs() < 1e-9);
    assert!(x.age().unwrap() > 0.0);
}

#[test]
fn tick_waiter_wakes_on_ticks_and_times_out_without() {
    let d = Domain::unique("tick").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    let (mut p, _rx) = owner(&bus, &["x"]);
    let mut w = TickWaiter::new(&bus, "sys").unwrap();
    let t0 = Instant::now();
    assert_eq!(w.wait(Duration::from_millis(50)).unwrap(), 0);
    assert!(t0.elapsed() >= Duration::from_millis(45), "returned early");
    p.notify_tick().unwrap();
    p.notify_tick().unwrap();
    assert!(w.wait(Duration::from_secs(5)).unwrap() >= 1);
    assert_eq!(w.try_consume().unwrap(), 0, "notifications were consumed");
    assert!(w.raw_fd() >= 0);
}

#[test]
fn wait_any_wakes_for_whichever_subsystem_ticks() {
    let d = Domain::unique("anytick").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    let spec = || [StateSpec::new("x", StateMeta::default())];
    let mut left = StatePublisher::create(&bus, "left", &spec()).unwrap();
    let mut right = StatePublisher::create(&bus, "right", &spec()).unwrap();
    let mut ws = [
        TickWaiter::new(&bus, "left").unwrap(),
        TickWaiter::new(&bus, "right").unwrap(),
    ];
    let t0 = Instant::now();
    let none = TickWaiter::wait_any(&mut ws, Duration::from_millis(40)).unwrap();
    assert_eq!(none[..2], [0, 0]);
    assert!(t0.elapsed() >= Duration::from_millis(35));
    right.notify_tick().unwrap();
    let got = TickWaiter::wait_any(&mut ws, Duration::from_secs(5)).unwrap();
    assert_eq!((got[0], got[1] >= 1), (0, true));
    left.notify_tick().unwrap();
    let got = TickWaiter::wait_any(&mut ws, Duration::from_secs(5)).unwrap();
    assert_eq!((got[0] >= 1, got[1]), (true, 0));
}

#[test]
fn gather_and_scatter_move_vectors() {
    let d = Domain::unique("vec").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    let (mut p, mut rx) = owner(&bus, &["a", "b", "c"]);
    let mut ctl = Controller::new(&bus);
    let names = ["sys/a", "sys/b", "sys/c"];
    // Before the owner publishes anything there is no value to gather.
    assert!(ctl.gather(&names).is_err());
    for (i, v) in [1.5, -2.0, 0.25].into_iter().enumerate() {
        p.publish(i, 1, 1_000, v, 0).unwrap();
    }
    let x = ctl.gather(&names).unwrap();
    assert_eq!(x.as_slice(), [1.5, -2.0, 0.25]);
    let xs = ctl.gather_static(&names).unwrap();
    assert_eq!(xs, nalgebra::Vector3::new(1.5, -2.0, 0.25));
    assert_eq!(ctl.scatter(&names, &[0.1, 0.2, 0.3]).unwrap(), 3);
    let mut got = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(5);
    while got.is_empty() && Instant::now() < deadline {
        rx.drain(|f| got = f.setpoints().iter().map(|s| (s.index, s.value)).collect())
            .unwrap();
    }
    assert_eq!(
        got,
        [(0, 0.1), (1, 0.2), (2, 0.3)],
        "one frame with all three"
    );
    assert!(ctl.scatter(&names, &[1.0]).is_err());
}

#[test]
fn the_command_watchdog_is_read_from_the_commands_service() {
    let d = Domain::unique("wdog").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    // An owner that does not say, one without a watchdog, one with 250 ms.
    let _quiet = CommandReceiver::create(&bus, "quiet").unwrap();
    let _none = CommandReceiver::with_watchdog(&bus, "none", None).unwrap();
    let _some =
        CommandReceiver::with_watchdog(&bus, "some", Some(Duration::from_millis(250))).unwrap();
    let client = Bus::open(&d, "client").unwrap();
    assert_eq!(client.command_watchdog("quiet").unwrap(), None);
    assert_eq!(client.command_watchdog("none").unwrap(), Some(None));
    assert_eq!(
        client.command_watchdog("some").unwrap(),
        Some(Some(Duration::from_millis(250)))
    );
    assert!(client.command_watchdog("absent").is_err());
}

/// Both ways of publishing a tick leave one snapshot per tick: `publish` + `notify_tick`, and the
/// executor's `stage_at` + `flush_states` (snapshot before the states' own samples). A state not
/// yet published is `NOT_YET`; one not published this tick keeps its last sample.
#[test]
fn every_tick_leaves_one_snapshot_of_every_state() {
    use conductor_bus::{status, SnapshotReader, NOT_YET};

    let d = Domain::unique("snap").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    let (mut p, _rx) = owner(&bus, &["a", "b", "c"]);
    let mut snaps = SnapshotReader::new(&bus, "sys").unwrap();
    let mut b = conductor_bus::StateSubscriber::new(&bus, "sys/b").unwrap();
    assert!(
        snaps.latest().unwrap().is_none(),
        "nothing before the first tick"
    );

    p.publish(0, 1, 1_000, 0.5, 0).unwrap();
    p.notify_tick().unwrap();
    let s = snaps.wait(Duration::from_secs(5)).unwrap().expect("tick 1");
    assert_eq!((s.len(), s.tick(), s[0].value, s[0].seq), (3, 1, 0.5, 0));
    assert_eq!(s[1].status, status::STALE);
    assert!(s[1].value.is_nan() && s[2].t_sample_ns == NOT_YET.t_sample_ns);
    drop(s);

    // Tick 2, staged: `a` and `b`; `c` still never published. `b` staged twice sends its last.
    p.stage_at(0, 2, 2_000, 0.75, 0, 2_100).unwrap();
    p.stage_at(1, 2, 2_000, 9.0, 0, 2_100).unwrap();
    p.stage_at(1, 2, 2_000, -1.0, status::CLAMPED, 2_100)
        .unwrap();
    assert!(b.receive().unwrap().is_none(), "staged, not sent");
    let sent = p.flush_states();
    assert_eq!((sent.published, sent.errors), (2, 0));
    p.notify_tick().unwrap();
    let s = snaps.wait(Duration::from_secs(5)).unwrap().expect("tick 2");
    assert_eq!(s.tick(), 2);
    assert_eq!((s[0].value, s[0].seq, s[0].t_publish_ns), (0.75, 1, 2_100));
    let b2 = b.receive().unwrap().expect("b's own sample of tick 2");
    assert_eq!(s[1], b2, "the snapshot carries what b's service carries");
    assert_eq!((b2.value, b2.status, b2.seq), (-1.0, status::CLAMPED, 1));
    assert!(b.receive().unwrap().is_none(), "b was sent once");
    assert!(s[2].value.is_nan());
    drop(s);

    // Tick 3 publishes only `a`: `b` keeps its tick-2 sample.
    p.stage_at(0, 3, 3_000, 1.0, 0, 3_100).unwrap();
    assert_eq!(p.flush_states().published, 1);
    let s = snaps
        .latest()
        .unwrap()
        .expect("tick 3, sent before the tick event");
    assert_eq!((s.tick(), s[1]), (3, b2));
    // Nothing staged: no snapshot.
    assert_eq!(p.flush_states().published, 0);
    assert!(snaps.latest().unwrap().is_none());
}

/// A reader in its own event loop: `has_snapshots` sees a snapshot in shared memory without
/// taking it, and `try_consume` leaves the event descriptor readable only for a later one.
#[test]
fn a_snapshot_is_seen_before_it_is_taken_and_its_event_consumed() {
    use conductor_bus::SnapshotReader;

    let readable = |fd: i32| {
        let mut p = libc::pollfd {
            fd,
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd, zero timeout.
        unsafe { libc::poll(&mut p, 1, 0) == 1 }
    };
    let d = Domain::unique("snapfd").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    let (mut p, _rx) = owner(&bus, &["a"]);
    let mut snaps = SnapshotReader::with_buffer(&bus, "sys", 8).unwrap();
    assert!(!snaps.has_snapshots().unwrap());
    assert!(!readable(snaps.raw_fd()));

    p.publish(0, 1, 1_000, 0.5, 0).unwrap();
    p.notify_tick().unwrap();
    assert!(snaps.has_snapshots().unwrap());
    assert!(snaps.has_snapshots().unwrap(), "looking does not take it");
    assert!(readable(snaps.raw_fd()));
    snaps.try_consume().unwrap();
    assert!(!readable(snaps.raw_fd()), "consumed");
    assert!(
        snaps.has_snapshots().unwrap(),
        "consuming the event leaves the snapshot"
    );
    assert_eq!(snaps.receive().unwrap().expect("tick 1")[0].value, 0.5);
    assert!(!snaps.has_snapshots().unwrap());
}
