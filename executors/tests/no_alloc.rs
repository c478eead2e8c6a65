//! After start-up, the executor's tick (drain commands, run every stage, publish samples, notify
//! the tick, publish stats) allocates nothing: 10 000 ticks under a counting allocator.

mod support;

use conductor_bus::{prepare_thread, Bus, Controller, StateSubscriber, StatsSubscriber};
use conductor_executor::executor::Executor;
use conductor_executor::manifest::Manifest;
use conductor_executor::schedule::Wake;
use conductor_testkit::alloc::{measure as measured, Counting};

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn ten_thousand_ticks_allocate_nothing() {
    // The counter counts (a test that cannot fail proves nothing).
    let (_, n) = measured(|| Box::new(7u64));
    assert_eq!(n, 1);

    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/manifests/two-subsystems.toml"
    );
    let m = Manifest::load(path).unwrap();
    // A watchdog makes the safe-action path part of the measurement too.
    let mut sub = m.subsystem("arm").unwrap().clone();
    sub.watchdog_ns = Some(50_000_000);

    prepare_thread();
    let (domain, _guard) = support::private_domain("noalloc");
    let bus = Bus::open(&domain, "executor/arm").unwrap();
    let mut exec = Executor::new(&bus, &sub).unwrap();
    let mut ctl = Controller::new(&bus);
    let mut sub_j0 = StateSubscriber::with_buffer(&bus, "arm/j0", 64).unwrap();
    let mut stats = None;

    // Synthetic time: tick k at 5 ms steps (200 Hz), so 10 000 ticks span 50 s of executor time:
    // 500 stats publications and, with the controller silent in long stretches, watchdog trips.
    let t0 = conductor_bus::monotonic_ns();
    let mut k = 0u64;
    let tick = |exec: &mut Executor, k: u64| {
        let now = t0 + k * 5_000_000;
        let wake = Wake {
            slot: k,
            sched_ns: now,
            late_ns: k % 7 * 1000,
            skipped: 0,
        };
        measured(|| exec.tick(&wake, now)).1
    };
    // Warm-up: connections are set up lazily by the first sends and receives.
    for _ in 0..50 {
        for j in 0..6 {
            ctl.add_ctrl(&format!("arm/j{j}"), 0.1).unwrap();
        }
        ctl.send_ctrl().unwrap();
        tick(&mut exec, k);
        k += 1;
        sub_j0.drain(|_| {}).unwrap();
        if stats.is_none() {
            stats = StatsSubscriber::new(&bus, "arm").ok();
        }
    }
    let names: Vec<String> = (0..6).map(|j| format!("arm/j{j}")).collect();
    let mut allocations = 0;
    let mut received = 0;
    for i in 0..10_000u64 {
        // The controller talks for 100 ticks, then is silent for 100 (the watchdog fires).
        if (i / 100) % 2 == 0 && i % 4 == 0 {
            for (j, n) in names.iter().enumerate() {
                // Every 40th frame is out of limits (clamped).
                let v = if i % 40 == 0 { 5.0 } else { j as f64 * 0.3 };
                ctl.add_ctrl(n, v).unwrap();
            }
            ctl.send_ctrl().unwrap();
        }
        allocations += tick(&mut exec, k);
        k += 1;
        received += sub_j0.drain(|_| {}).unwrap();
    }
    assert_eq!(allocations, 0, "the tick allocated");
    // The work really happened.
    assert_eq!(received, 10_000, "one sample of j0 per tick");
    let s = stats.unwrap().latest().unwrap().unwrap();
    assert!(s.watchdog_trips >= 40, "{}", s.watchdog_trips);
    assert!(s.frames_applied >= 1_000);
    assert!(s.setpoints_clamped > 0);
    // Stats go out every 100 ms of executor time (20 ticks): the newest is at most 20 ticks old.
    assert!((10_030..=10_050).contains(&s.ticks), "{}", s.ticks);
}
