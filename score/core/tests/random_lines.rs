//! Property: no line panics, and a refused line leaves the table unchanged. Lines are drawn from
//! the language's own vocabulary so that most reach deep into the checks (the cargo-fuzz target
//! in score/core/fuzz covers arbitrary bytes).
mod common;

use common::engine_and_board;
use proptest::prelude::*;

fn token() -> impl Strategy<Value = String> {
    prop_oneof![
        prop::sample::select(vec![
            "adc",
            "pwm",
            "gpio",
            "defexp",
            "defscale",
            "defsat",
            "defint",
            "defwind",
            "defdiff",
            "deflpf",
            "defpid",
            "defpwm",
            "defgpio",
            "set",
            "del",
            "rate",
            "infile",
            "log",
            "printv",
            "printvars",
            "show",
            "help",
            "var",
            "main",
            "save",
            "clear",
            "capacities",
            "+",
            "-",
            "*",
            "/",
            "neg",
            "abs",
            "min",
            "sqrt",
            "\u{2212}",
            "a",
            "b",
            "c",
            "adc0",
            "ADC0",
            "adca",
            "PWM2",
            "I",
            "0",
            "1",
            "2",
            "A",
            "B",
            "T",
            "100",
            "1000",
            "-1.5",
            "0.5",
            "1e3",
            "(",
            "#",
            "in.txt",
        ])
        .prop_map(str::to_string),
        "[ -~]{0,6}",
        (-1.0e6f64..1.0e6).prop_map(|v| v.to_string()),
    ]
}

fn line() -> impl Strategy<Value = String> {
    prop::collection::vec(token(), 0..9).prop_map(|t| t.join(" "))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn lines_never_panic_and_failures_change_nothing(lines in prop::collection::vec(line(), 1..24)) {
        let (mut e, mut b) = engine_and_board();
        b.files.add_input("in.txt", vec![1.0, -1.0]);
        let mut t = 0u64;
        for l in &lines {
            let before = e.clone();
            let mut out = String::new();
            if e.execute(l, &mut b, &mut out).is_err() {
                // Debug text, not ==: a NaN computed earlier must compare equal to itself.
                prop_assert_eq!(format!("{e:?}"), format!("{before:?}"), "refused line changed the table: {:?}", l);
            }
            t += 7_000;
            e.tick(t, &mut b);
            for v in e.vars().map(|v| v.id).collect::<Vec<_>>() {
                let _ = e.value(v);
            }
            let mut saved = String::new();
            e.save(&mut saved).unwrap();
        }
    }
}
