//! CPU cost of publishing states, in one process: a raw iceoryx2 publish of the 48-byte state
//! payload with the states' own service configuration (the denominator of the executor's
//! per-state cost, benches/README.md) beside `StatePublisher::publish`, and a whole tick of N
//! states plus the tick event both ways. The method is in [`conductor_benches::publish_cost`].
//!
//! Criterion times each case (drains between batches excluded); the summary prints the
//! interleaved medians and the Conductor / raw ratios of the same run.

use std::time::Duration;

use conductor_benches::publish_cost::{self, Path, PublishRig};
use criterion::Criterion;

fn main() {
    let mut c = Criterion::default()
        .configure_from_args()
        .measurement_time(Duration::from_secs(2))
        .warm_up_time(Duration::from_millis(500));
    for subscribers in [0usize, 1] {
        let mut g = c.benchmark_group(format!("publish_{subscribers}sub"));
        for states in [1usize, 41] {
            let mut rig = PublishRig::new(states, subscribers).unwrap_or_else(|e| panic!("{e}"));
            for path in Path::ALL {
                // One state: a bare publish (no tick event); N states: the whole tick + event.
                let notify = states > 1;
                let id = format!("{}/{states}", path.name());
                g.bench_function(id, |b| {
                    b.iter_custom(|iters| {
                        let ns = rig
                            .time(path, notify, iters)
                            .unwrap_or_else(|e| panic!("{e}"));
                        Duration::from_nanos(ns)
                    })
                });
            }
        }
        g.finish();
    }
    println!();
    println!("Interleaved medians (11 rounds of 5 000 ticks), same run; ratios to raw:");
    println!("| states | subscribers | path | ns/state | ratio | ns/tick incl. event | ratio |");
    println!("|---|---|---|---|---|---|---|");
    for subscribers in [0usize, 1, 4] {
        for states in [1usize, 41] {
            let costs = publish_cost::measure(states, subscribers, 5_000, 11)
                .unwrap_or_else(|e| panic!("{e}"));
            let raw = costs[0];
            for c in &costs {
                println!(
                    "| {states} | {subscribers} | {} | {:.1} | {:.2} | {:.0} | {:.2} |",
                    c.path.name(),
                    c.per_state_ns,
                    c.per_state_ns / raw.per_state_ns,
                    c.per_tick_ns,
                    c.per_tick_ns / raw.per_tick_ns
                );
            }
        }
    }
}
