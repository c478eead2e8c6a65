//! The stress test's external logger (`conductor-stress log`, a process of its own) sees every
//! state of a launched manifest at its rate, without losses, whether it subscribes to each state
//! or reads the subsystems' snapshots; the one-way floor of the executor's shape measures what it
//! publishes.

use std::collections::HashMap;
use std::process::Command;
use std::time::Duration;

use conductor_benches::stress::parse_line;
use conductor_bus::{Bus, Domain, RtIpc, StatsSubscriber};
use conductor_executor::launcher::{Launch, LaunchOptions};
use conductor_testkit::{eventually, workspace};
use iceoryx2::testing::remove_global_mgmt_segment;

const STRESS: &str = env!("CARGO_BIN_EXE_conductor-stress");

/// Deadline misses of a subsystem so far, from its stats (within 5 s).
fn misses(bus: &Bus, subsystem: &str) -> u64 {
    let mut s = StatsSubscriber::new(bus, subsystem).unwrap();
    eventually(Duration::from_secs(5), "stats", || {
        s.latest().unwrap().map(|stats| stats.misses)
    })
}

#[test]
fn an_external_subscriber_sees_every_state_at_its_rate() {
    let d = Domain::unique("rates").unwrap();
    let manifest = workspace().join("executors/tests/manifests/two-subsystems.toml");
    let options = LaunchOptions {
        // This build's stress tool is its own executor.
        executor: STRESS.into(),
        executor_args: vec!["executor".into()],
        domain: Some(d.name().into()),
        quiet: true,
        handle_signals: false,
        ..LaunchOptions::default()
    };
    let launch = Launch::start(&manifest, options).unwrap();
    let states = [
        "arm/j0",
        "arm/j1",
        "arm/j2",
        "arm/j3",
        "arm/j4",
        "arm/j5",
        "sensors/a",
        "sensors/b",
        "sensors/c",
    ];
    // Two loggers over the same 2 s: one subscribed to every state, one reading the two
    // subsystems' snapshots. Both must see every sample, each once.
    let logger = |snapshot: bool| {
        let mut c = Command::new(STRESS);
        c.args(["log", "--domain", d.name(), "--seconds", "2", "--states"])
            .arg(states.join(","));
        if snapshot {
            c.arg("--snapshot");
        }
        std::thread::spawn(move || conductor_testkit::run_ok(&mut c))
    };
    let (per_state, snapshots) = (logger(false), logger(true));
    let outs = [per_state.join().unwrap(), snapshots.join().unwrap()];
    let bus = Bus::open(&d, "test").unwrap();
    let skipped = misses(&bus, "arm") + misses(&bus, "sensors");
    for (out, how) in outs.iter().zip(["per-state subscribers", "snapshots"]) {
        let text = String::from_utf8(out.stdout.clone()).unwrap();
        let rows: Vec<HashMap<String, String>> = text.lines().map(parse_line).collect();
        assert_eq!(rows.len(), states.len(), "{how}: {text}");
        let expected_rates = [200.0, 200.0, 200.0, 200.0, 200.0, 200.0, 250.0, 125.0, 50.0];
        for (row, (name, rate)) in rows.iter().zip(states.iter().zip(expected_rates)) {
            assert_eq!(row["state"], *name);
            assert_eq!(row["rate_hz"].parse::<f64>().unwrap(), rate, "{name}");
            assert_eq!(row["missed"], "0", "{name}: {how} lost samples");
            assert_eq!(row["repeats"], "0", "{name}: {how} saw a sample twice");
            // Samples are counted by their sample time over a 2 s window: one per period, ±1
            // for where the window's edges fall. A deadline the executor missed (its slot
            // skipped, reported in its stats) publishes nothing, so it may lower the count.
            let count: f64 = row["count"].parse().unwrap();
            let want = rate * 2.0;
            assert!(
                count <= want + 1.0 && count >= want - 1.0 - skipped as f64,
                "{name}: {how}: {count} samples in 2 s at {rate} Hz ({skipped} deadline \
                 misses): {text}"
            );
        }
    }
    drop(bus);
    launch.stop();
    launch.wait().unwrap();
    // SAFETY: the domain is private to this test and no process of it is alive any more, which
    // is the precondition of removing its node counter.
    let _ = unsafe { remove_global_mgmt_segment::<RtIpc>(d.iceoryx2_config()) };
    let _ = std::fs::remove_dir_all(d.root_path());
}

/// The periodic floor ([`conductor_benches::periodic`]) reads every tick it publishes, in both
/// shapes, and reports each sample's latency once.
#[test]
fn the_periodic_floor_reads_every_published_sample() {
    use conductor_benches::periodic::{measure, Periodic};
    for snapshot in [false, true] {
        let p = Periodic {
            rate_hz: 200.0,
            states: 3,
            snapshot,
            seconds: 0.5,
            cpu: 0,
            priority: 10,
            buffer: 64,
        };
        let r = measure(&p, &[STRESS.into()]).unwrap();
        // 0.5 s measured at 200 Hz: 100 ticks of 3 samples, each read once.
        assert_eq!(r.count, 300, "snapshot={snapshot}");
        assert!(r.min > 0 && r.p50 >= r.min && r.max >= r.p99, "{r:?}");
    }
}
