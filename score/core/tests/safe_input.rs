//! Any input is taken safely (issue 18, item 3): non-finite values have a defined, documented
//! effect on every block; `run` refuses what no clock can hold; a byte-order mark is not a
//! character of the command; errors point at a column and show invisible characters; a name
//! used before its definition is pointed out.
mod common;

use common::{engine_and_board, refused, run, run_until, MemBoard};
use score_core::{Engine, Error, Num, Outcome, Real};

/// `x = num / den`, an input that the test makes finite, infinite or NaN with `set`.
fn with_input(extra: &str) -> (Engine<Num>, MemBoard) {
    let (mut e, mut b) = engine_and_board();
    run(
        &mut e,
        &mut b,
        &format!("defexp num 1\ndefexp den 1\ndefexp x num den /\n{extra}"),
    );
    (e, b)
}

fn set(e: &mut Engine<Num>, b: &mut MemBoard, num: f64, den: f64) {
    run(e, b, &format!("set num {num}\nset den {den}"));
}

fn value(e: &mut Engine<Num>, name: &str) -> f64 {
    e.value_of(name)
        .unwrap_or_else(|| panic!("{name} exists"))
        .to_f64()
}

#[test]
fn saturation_and_scale_never_pass_nan() {
    let (mut e, mut b) = with_input(
        "defsat s x -1 1\ndefsat above x 2 3\ndefscale c x 0 1 10 20\ndefscale r x 0 1 5 -5",
    );
    // NaN: the point of the limits nearest 0.
    set(&mut e, &mut b, 0.0, 0.0);
    assert!(value(&mut e, "x").is_nan());
    assert_eq!(value(&mut e, "s"), 0.0);
    assert_eq!(value(&mut e, "above"), 2.0);
    assert_eq!(value(&mut e, "c"), 10.0);
    assert_eq!(value(&mut e, "r"), 0.0);
    // ±inf: the limit on its side.
    set(&mut e, &mut b, 1.0, 0.0);
    assert_eq!(value(&mut e, "x"), f64::INFINITY);
    assert_eq!(value(&mut e, "s"), 1.0);
    assert_eq!(value(&mut e, "c"), 20.0);
    assert_eq!(value(&mut e, "r"), -5.0);
    set(&mut e, &mut b, -1.0, 0.0);
    assert_eq!(value(&mut e, "s"), -1.0);
    assert_eq!(value(&mut e, "c"), 10.0);
    // Finite again: the ordinary mapping.
    set(&mut e, &mut b, 1.0, 2.0);
    assert_eq!(value(&mut e, "s"), 0.5);
    assert_eq!(value(&mut e, "c"), 15.0);
}

#[test]
fn blocks_hold_through_non_finite_input_and_resume() {
    let (mut e, mut b) = with_input(
        "defint I x 100\ndefwind W x 100 0.5 x x\ndefdiff D x 100\ndeflpf F x 100 5\n\
         defpid P x 100 2 1 0.01\ndefpid Q x 100 1 1 0 -10 10",
    );
    // 1 s of x = 1 (updates at 0, 10 ms, ..., 990 ms).
    run_until(&mut e, &mut b, 1_000_000);
    let names = ["I", "W", "D", "F", "P", "Q"];
    let before: Vec<f64> = names.iter().map(|n| value(&mut e, n)).collect();
    assert!((before[0] - 0.99).abs() < 1e-5, "{before:?}");
    // 0.5 s of NaN, then 0.5 s of +inf: every block keeps its value and counts the updates.
    set(&mut e, &mut b, 0.0, 0.0);
    run_until(&mut e, &mut b, 1_500_000);
    set(&mut e, &mut b, 1.0, 0.0);
    run_until(&mut e, &mut b, 2_000_000);
    for (n, v) in names.iter().zip(&before) {
        assert_eq!(value(&mut e, n), *v, "{n} held");
        let id = e.lookup(n).unwrap();
        assert_eq!(e.held_updates(id), Some(100), "{n}");
    }
    let mut shown = String::new();
    run(&mut e, &mut b, "show I").lines().for_each(|l| {
        shown.push_str(l);
        shown.push('\n');
    });
    assert!(shown.contains("100 held (input not finite)"), "{shown}");
    // Finite again at 2 s: the integral restarts from its held value; the first finite sample
    // only starts a new interval (the gap adds nothing), so 1 s adds 0.99 again.
    set(&mut e, &mut b, 1.0, 1.0);
    run_until(&mut e, &mut b, 3_000_000);
    assert!((value(&mut e, "I") - 1.98).abs() < 1e-5);
    for n in names {
        assert!(value(&mut e, n).is_finite(), "{n} recovered");
    }
    // A result that overflows is held too, from finite inputs: x = the largest number, so
    // from the second update on the trapezoid's x1 + x2 overflows.
    run(&mut e, &mut b, &format!("set num {:e}", Num::MAX));
    run_until(&mut e, &mut b, 3_100_000);
    assert_eq!(value(&mut e, "x"), Num::MAX.to_f64());
    assert!(value(&mut e, "I").is_finite());
    assert_eq!(e.held_updates(e.lookup("I").unwrap()), Some(100 + 9));
}

#[test]
fn outputs_go_to_rest_on_nan() {
    let (mut e, mut b) = with_input("defpwm pw x 100 2 1000\ndefgpio pin x 100 5");
    set(&mut e, &mut b, 0.0, 0.0);
    run_until(&mut e, &mut b, 100_000);
    assert_eq!(value(&mut e, "pw"), 0.0);
    assert_eq!(value(&mut e, "pin"), 0.0);
}

#[test]
fn a_non_finite_definition_and_a_forward_reference_are_pointed_out() {
    let (mut e, mut b) = engine_and_board();
    let out = run(&mut e, &mut b, "defexp z 1 0 /");
    assert!(
        out.contains("note: 'z' is inf now (a division by zero"),
        "{out}"
    );
    let out = run(&mut e, &mut b, "adc 0 100\ndefint I adcO 100");
    assert!(
        out.contains(
            "note: 'adcO' is not defined yet; it reads 0 until it is (did you mean 'adc0'?)"
        ),
        "{out}"
    );
    // The thesis' forward reference (a gain defined after its use) is noted once, without a
    // suggestion when nothing resembles it, and defining it says nothing more.
    let out = run(&mut e, &mut b, "defexp P Kgain I *\ndefexp Kgain 2");
    assert_eq!(
        out.lines()
            .filter(|l| l.starts_with("note:"))
            .collect::<Vec<_>>(),
        ["note: 'Kgain' is not defined yet; it reads 0 until it is"]
    );
}

#[test]
fn run_refuses_durations_no_clock_can_hold() {
    let (mut e, mut b) = engine_and_board();
    let mut out = String::new();
    for bad in ["1e30", "inf", "-inf", "nan", "-5", "1000000001", "1e999"] {
        let line = format!("run {bad}");
        assert_eq!(
            e.execute(&line, &mut b, &mut out).unwrap_err().to_string(),
            format!("run: '{bad}' is not a duration in seconds from 0 to 1e9"),
        );
    }
    for (good, s) in [("0", 0.0), ("-0", 0.0), ("1e9", 1e9), ("2.5", 2.5)] {
        assert_eq!(
            e.execute(&format!("run {good}"), &mut b, &mut out),
            Ok(Outcome::Run(s))
        );
    }
    assert_eq!(
        score_core::capacity::MAX_RUN_SECONDS.to_string(),
        "1000000000",
        "RUN_EXPECTED names the bound"
    );
}

#[test]
fn a_byte_order_mark_is_not_part_of_the_command() {
    let (mut e, mut b) = engine_and_board();
    run(&mut e, &mut b, "\u{feff}defexp k 2");
    assert_eq!(e.value_of("k"), Some(2.0));
}

#[test]
fn invisible_characters_are_shown_in_messages() {
    let (mut e, mut b) = engine_and_board();
    assert_eq!(
        refused(&mut e, &mut b, "def\u{200b}exp k 2"),
        "unknown command 'def\\u{200b}exp' (type 'help' for the list of commands)"
    );
    let err = refused(&mut e, &mut b, "defexp k 2 \u{7}");
    assert!(err.contains("at '\\u{7}'"), "{err}");
}

#[test]
fn errors_point_at_their_column() {
    let (mut e, mut b) = engine_and_board();
    let mut out = String::new();
    run(&mut e, &mut b, "defexp Kp 1\ndefexp a Kp 1 +");
    let mut column = |line: &str| -> (Option<usize>, Error) {
        let err = e.execute(line, &mut b, &mut out).unwrap_err();
        (err.column(line), err)
    };
    // The token quoted (the second 'x', not the first: the position, not the text).
    assert_eq!(column("defexp x x $ *").0, Some(12));
    assert_eq!(column("  adc 9 100").0, Some(7));
    assert_eq!(column("bogus").0, Some(1));
    // Columns count characters, not bytes.
    assert_eq!(column("defexp é 1").0, Some(8));
    // A missing argument: just past the last token.
    assert_eq!(column("adc 0").0, Some(7));
    // An error about a name, not a token: the command word.
    let (col, err) = column("  del Kp");
    assert!(matches!(err, Error::InUse { .. }), "{err}");
    assert_eq!(col, Some(3));
    // Asked about another line, a token is not found there: the command word of that line.
    let (_, err) = column("adc 9 100");
    assert_eq!(err.column(" adc 9 100"), Some(2));
    assert_eq!(err.column(""), None);
}
