//! Score: cost of one update of the thesis' 10-line PID (Fig. 5.20) on the host, for f32 and
//! f64 numbers side by side, and the symbol-table memory footprint (64 symbols).
//!
//! One update = what the 1 kHz scheduler does per sample: the `infile` source, the derivative
//! and the integral blocks (`tick`), then reading the lazily evaluated `PID` expression, which
//! evaluates Pterm, Iterm, Dterm and PID. (The firmware issue measures the same on the RP2040 in
//! emulated cycles.)

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use score_core::hal::{Adc, AdcInput, DataFiles, Gpio, HalError, Pwm, PwmOutput, StreamId};
use score_core::{Engine, Real};

/// A board with one in-memory playback signal (the PID's error input) and nothing else.
struct Bench {
    signal: Vec<f64>,
}

impl Adc for Bench {
    fn adc_channels(&self) -> u8 {
        0
    }
    fn adc_differential_pairs(&self) -> u8 {
        0
    }
    fn adc_has_temperature(&self) -> bool {
        false
    }
    fn adc_full_scale(&self) -> u16 {
        4095
    }
    fn adc_reference_volts(&self) -> f32 {
        3.3
    }
    fn adc_configure(&mut self, _: AdcInput, _: f32) -> Result<(), HalError> {
        Err(HalError::NoSuchChannel)
    }
    fn adc_release(&mut self, _: AdcInput) {}
    fn adc_read(&mut self, _: AdcInput) -> Result<u16, HalError> {
        Err(HalError::NoSuchChannel)
    }
}
impl Pwm for Bench {
    fn pwm_outputs(&self) -> u8 {
        0
    }
    fn pwm_configure(&mut self, _: PwmOutput, _: f32) -> Result<f32, HalError> {
        Err(HalError::NoSuchChannel)
    }
    fn pwm_set_duty(&mut self, _: PwmOutput, d: f32) -> f32 {
        d
    }
    fn pwm_release(&mut self, _: PwmOutput) {}
}
impl Gpio for Bench {
    fn gpio_pins(&self) -> u8 {
        0
    }
    fn gpio_configure(&mut self, _: u8, _: bool) -> Result<(), HalError> {
        Err(HalError::NoSuchChannel)
    }
    fn gpio_read(&mut self, _: u8) -> bool {
        false
    }
    fn gpio_write(&mut self, _: u8, _: bool) {}
    fn gpio_release(&mut self, _: u8) {}
}
impl DataFiles for Bench {
    fn open_input(&mut self, _: &str) -> Result<StreamId, HalError> {
        Ok(StreamId(0))
    }
    fn input_len(&self, _: StreamId) -> u32 {
        self.signal.len() as u32
    }
    fn input_sample(&self, _: StreamId, i: u32) -> f64 {
        self.signal[i as usize]
    }
}

/// Fig. 5.20 without its `log` line (the benchmark reads PID itself).
const FIG_5_20: &str = "var
defdiff Dsgnl sgnl 1000
defint Isgnl sgnl 1000
defexp Iterm Isgnl Ki *
defexp Dterm Dsgnl Kd *
defexp Pterm sgnl Kp *
defexp PID Pterm Iterm + Dterm +
defexp Kp 21
defexp Ki 350
defexp Kd 0.0788
infile sgnl 1000 mpidin.log";

fn setup<N: Real>() -> (Engine<N>, Bench, score_core::VarId) {
    let signal = (0..1500)
        .map(|k| 0.015 * (k as f64 * 0.025).sin())
        .collect();
    let mut board = Bench { signal };
    let mut e = Engine::<N>::new();
    let mut out = String::new();
    for line in FIG_5_20.lines() {
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

criterion_group!(benches, footprint, bench_update::<f64>, bench_update::<f32>);
criterion_main!(benches);
