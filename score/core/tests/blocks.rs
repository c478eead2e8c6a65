//! The blocks beyond the thesis' tests: low-pass, defpid with limits, GPIO, temperature, and the
//! static placement the firmware needs.
mod common;

use common::{board, engine_and_board, refused, run, run_until};
use score_core::{Engine, Num, Real, VarKind};

// A firmware keeps the engine in a static: `new` must be usable in a const context.
static _STATIC_ENGINE: Engine<f32> = Engine::new();

fn u() -> f64 {
    <Num as Real>::EPSILON.to_f64() / 2.0
}

#[test]
fn lpf_follows_its_discrete_recurrence() {
    let mut e: Engine<Num> = Engine::new();
    let mut data = vec![0.0; 10];
    data.extend(vec![1.0; 90]);
    let mut b = board();
    b.files.add_input("step", data);
    run(
        &mut e,
        &mut b,
        "infile x 100 step\ndeflpf y x 100 2\nlog y 100 y.log",
    );
    run_until(&mut e, &mut b, 1_000_000);
    let y = b.files.log("y.log");
    assert_eq!(y.len(), 100);
    // y_k = y_{k-1} + a (x_k - y_{k-1}), a = dt / (tau + dt), tau = 1/(2 pi fc): after the step at
    // k = 10, y_k = 1 - (1 - a)^(k - 9). Rounding: a few operations per step on values <= 1.
    let dt = 0.01;
    let tau = 1.0 / (2.0 * std::f64::consts::PI * 2.0);
    let a = dt / (tau + dt);
    for (k, v) in y.iter().enumerate() {
        let exact = if k < 10 {
            0.0
        } else {
            1.0 - (1.0 - a).powi(k as i32 - 9)
        };
        assert!(
            (v - exact).abs() <= 8.0 * (k as f64 + 1.0) * u(),
            "k={k}: {v} vs {exact}"
        );
    }
}

#[test]
fn pid_with_limits_does_not_wind_up() {
    let mut e: Engine<Num> = Engine::new();
    let mut data = vec![1.0; 100];
    data.extend(vec![-1.0; 100]);
    let mut b = board();
    b.files.add_input("err", data);
    run(
        &mut e,
        &mut b,
        "infile err 100 err\ndefpid held err 100 0 1 0 -0.5 0.5\ndefpid free err 100 0 1 0\n\
         log held 100 held.log\nlog free 100 free.log",
    );
    run_until(&mut e, &mut b, 2_000_000);
    let (held, free) = (b.files.log("held.log"), b.files.log("free.log"));
    // ki = 1, e = +1 for 1 s: the free integral reaches 0.99 at k = 99; the limited one stops
    // exactly at the limit 0.5 (k = 50) and holds. After the sign change (k = 100) the trapezoid's first step
    // averages +1 and -1, so the limited output leaves 0.5 at k = 101; the free one only when
    // its integral has come back below 0.5, near k = 149.
    // (100 steps of four roundings each on values <= 1.)
    assert!((free[99] - 0.99).abs() <= 400.0 * u() && held[99] == 0.5);
    let leave = |v: &[f64]| (100..200).find(|&k| v[k] < 0.5).unwrap();
    assert_eq!(leave(&held), 101);
    assert!(leave(&free) >= 149);
    assert!(held.iter().all(|v| (-0.5..=0.5).contains(v)));
}

#[test]
fn gpio_and_temperature_channels() {
    let (mut e, mut b) = engine_and_board();
    b.hw.adc_code = 200;
    run(
        &mut e,
        &mut b,
        "gpio 3 100\nadc T 10\ndefgpio led adct 100 5",
    );
    assert_eq!(e.value_of("GPIO3"), Some(1.0)); // the test board's pins read high
    let t = e.value_of("adct").unwrap();
    assert!((t - 200.0 * 3.0 / 1023.0).abs() < 1e-6);
    run_until(&mut e, &mut b, 1);
    assert_eq!(
        e.value_of("led"),
        Some(1.0),
        "adct = 0.59 V >= 0.5 drives the pin high"
    );
    let kinds: Vec<VarKind> = e.vars().map(|v| v.kind).collect();
    assert!(kinds.contains(&VarKind::GpioIn) && kinds.contains(&VarKind::GpioOut));
    assert_eq!(
        refused(&mut e, &mut b, "gpio 5 10"),
        "gpio: '5' is already driven by 'led' ('del led' first)"
    );
}

#[test]
fn variables_defined_later_start_at_the_time_they_are_typed() {
    let (mut e, mut b) = engine_and_board();
    run(&mut e, &mut b, "defexp one 1\ndefint A one 1000");
    run_until(&mut e, &mut b, 500);
    e.set_time(500);
    run(&mut e, &mut b, "defint B one 100");
    assert_eq!(e.next_deadline(), Some(500));
    run_until(&mut e, &mut b, 20_500);
    // B ran at 0.5, 10.5 and 20.5 ms? No: instants before 20.5 ms only: 0.5 and 10.5 ms.
    assert!((e.value_of("B").unwrap() - 0.01).abs() < 1e-12);
    let gen = e.generation();
    run(&mut e, &mut b, "rate B 50");
    assert_ne!(
        e.generation(),
        gen,
        "table changes are visible to a gateway"
    );
}
