//! Score: cost of one update of the thesis' 10-line PID (Fig. 5.20) on the host, for f32 and
//! f64 numbers side by side, and the symbol-table memory footprint (64 symbols).
//!
//! One update = what the 1 kHz scheduler does per sample: the `infile` source, the derivative
//! and the integral blocks (`tick`), then reading the lazily evaluated `PID` expression, which
//! evaluates Pterm, Iterm, Dterm and PID. (The firmware issue measures the same on the RP2040 in
//! emulated cycles.)

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use score_core::hal::PlaybackHal;
use score_core::{Engine, Real, FIG_5_20_PID};

/// Fig. 5.20 (without its `log` line: the benchmark reads PID itself) on a board with one
/// in-memory playback signal (the PID's error input) and nothing else.
fn setup<N: Real>() -> (Engine<N>, PlaybackHal<Vec<f64>>, score_core::VarId) {
    let signal = (0..1500)
        .map(|k| 0.015 * (k as f64 * 0.025).sin())
        .collect();
    let mut board = PlaybackHal::new(signal);
    let mut e = Engine::<N>::new();
    let mut out = String::new();
    for line in FIG_5_20_PID.lines() {
        e.execute(line, &mut board, &mut out).expect(line);
    }
    let pid = e.lookup("PID").unwrap();
    (e, board, pid)
}

fn bench_update<N: Real>(c: &mut Criterion) {
    let (mut e, mut board, pid) = setup::<N>();
    let mut t = 0u64;
    c.bench_function(&format!("score_pid/{}/update", N::NAME), |b| {
        b.iter(|| {
            e.tick(t, &mut board);
            t += 1000;
            black_box(e.value(pid))
        })
    });
    let (mut e, _, pid) = setup::<N>();
    c.bench_function(&format!("score_pid/{}/evaluate_pid_only", N::NAME), |b| {
        b.iter(|| black_box(e.value(pid)))
    });
}

fn footprint(_: &mut Criterion) {
    let cap = score_core::CAPACITIES;
    println!(
        "score symbol table (capacity {} symbols, {} expression tokens): Engine<f32> = {} bytes, Engine<f64> = {} bytes",
        cap.symbols,
        cap.expr_ops,
        std::mem::size_of::<Engine<f32>>(),
        std::mem::size_of::<Engine<f64>>()
    );
}

// criterion_group! makes a `pub fn benches` without a doc comment: kept in a private module,
// it is not part of the crate's API that `missing_docs` checks.
mod group {
    use super::*;
    criterion_group!(benches, footprint, bench_update::<f64>, bench_update::<f32>);
}

criterion_main!(group::benches);
