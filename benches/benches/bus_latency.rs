//! One-way latency of the Conductor bus between two processes, against raw iceoryx2 measured in
//! the same run as the floor. The paths and the method are in [`conductor_benches::pingpong`]:
//! a parent sending on CPU 0, this binary re-executed as the receiving child on CPU 1, one
//! message in flight, one-way = receipt stamp − send stamp on CLOCK_MONOTONIC.
//!
//! Criterion times the round trip; the summary prints one-way p50/p99/p99.9/max and the ratio of
//! each Conductor path to its raw floor (busy-poll to `raw-busy`, event-woken to `raw-event`).

use std::time::Duration;

use conductor_benches::percentiles::fmt_ns;
use conductor_benches::pingpong::{self, Mode, PingPong};
use criterion::Criterion;

/// Extra round trips after criterion's, for stable tail percentiles.
const SAMPLES: usize = 50_000;

fn main() {
    if let Some(r) = pingpong::child_from_env() {
        if let Err(e) = r {
            eprintln!("bus_latency child: {e}");
            std::process::exit(1);
        }
        return;
    }
    pingpong::pin(0);
    let me = vec![std::env::current_exe().expect("own path").into_os_string()];
    let mut c = Criterion::default()
        .configure_from_args()
        .measurement_time(Duration::from_secs(3))
        .warm_up_time(Duration::from_secs(1));
    let mut results = Vec::new();
    {
        let mut g = c.benchmark_group("bus_round_trip");
        for mode in Mode::ALL {
            let mut s = PingPong::start(mode, &me).unwrap_or_else(|e| panic!("{e}"));
            g.bench_function(mode.name(), |b| {
                b.iter(|| s.round_trip().unwrap_or_else(|e| panic!("{e}")))
            });
            for _ in 0..SAMPLES {
                s.round_trip().unwrap_or_else(|e| panic!("{e}"));
            }
            results.push((mode, s.finish().unwrap_or_else(|e| panic!("{e}"))));
        }
        g.finish();
    }
    println!();
    println!(
        "One-way latency, publisher stamp → subscriber receipt, two processes on CPUs 0 and 1:"
    );
    println!("| path | samples | p50 | p99 | p99.9 | max | p50 / floor | p99 / floor |");
    println!("|---|---|---|---|---|---|---|---|");
    for (mode, p) in &results {
        let floor = &results
            .iter()
            .find(|(m, _)| *m == mode.floor())
            .expect("every floor is measured")
            .1;
        let r = p.ratio_to(floor);
        println!(
            "| {} | {} | {} | {} | {} | {} | {:.2} | {:.2} |",
            mode.name(),
            p.count,
            fmt_ns(p.p50),
            fmt_ns(p.p99),
            fmt_ns(p.p999),
            fmt_ns(p.max),
            r.p50,
            r.p99
        );
    }
    c.final_summary();
}
