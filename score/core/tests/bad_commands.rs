//! A corpus of bad command lines: each is refused with its message and leaves the table (and the
//! menu, the expression arena, the schedule) exactly as it was.
mod common;

use common::{engine_and_board, refused_unchanged, run};

const SETUP: &str = "adc 0 100\nadc A 1000\npwm 4 1000 50\nvar\ndefexp Kp 21\ndefexp a b 1 +\n\
                     defexp b adc0 2 *\ndefint I adc0 100\ndefpwm pw2 b 100 2 1000\ninfile one 100 sin.txt\n\
                     log Lone one 100 one.log";

const CORPUS: &[(&str, &str)] = &[
    ("frobnicate 1 2", "unknown command 'frobnicate' (type 'help' for the list of commands)"),
    ("adc 7 100", "adc: '7' is not an ADC channel of this board (expected 0-3, A-B or T)"),
    ("adc 0", "adc: missing frequency (usage: adc channel frequency)"),
    ("adc 0 0", "adc: '0' is not a frequency in Hz between 0.001 and 100000"),
    ("adc 0 200000", "adc: '200000' is not a frequency in Hz between 0.001 and 100000"),
    ("adc 0 100 extra", "adc: unexpected 'extra' after the last argument (usage: adc channel frequency)"),
    ("pwm 9 1000 50", "pwm: '9' is not a PWM output of this board (expected 0-7, A-D)"),
    ("pwm 4 1000 150", "pwm: '150' is not a duty cycle in percent (0-100)"),
    ("pwm 4 -5 50", "pwm: '-5' is not a PWM frequency in Hz (above 0, at most 100000000)"),
    ("pwm B 1000 50", "pwm: 'B' is already driven by 'pw2' ('del pw2' first)"),
    ("defexp x 1 +", "defexp: in the expression at '+': this operator needs two operands before it (postfix: 'a b +')"),
    ("defexp x 1 2", "defexp: in the expression at '2': the expression must leave exactly one value (operators missing?)"),
    ("defexp x Kp $ *", "defexp: in the expression at '$': expected a number, a variable name or an operator (+ - * / min max neg abs sqrt sin cos exp)"),
    ("defexp x", "defexp: missing a postfix expression (usage: defexp varname postfix...)"),
    ("defexp 9x 1", "defexp: '9x' is not a variable name (a letter or _, then letters, digits or _; at most 15 characters)"),
    ("defexp adc0 1", "defexp: 'adc0' is an ADC channel (volts); choose another name or 'del adc0' first"),
    ("defexp x 1 1e999 +", "defexp: in the expression at '1e999': expected a number, a variable name or an operator (+ - * / min max neg abs sqrt sin cos exp)"),
    ("defexp b a 1 +", "defexp: 'b' would depend on itself through 'a' (a loop must pass through a periodic block such as defint, defwind, defdiff or deflpf)"),
    ("defexp abcdefghijklmnopq 1", "defexp: 'abcdefghijklmnopq' is not a variable name (a letter or _, then letters, digits or _; at most 15 characters)"),
    ("defscale S b 1 1 0 100", "defscale: '1' is not an input bound different from a (the interval [a,b] is empty)"),
    ("defscale S b 0 1 0", "defscale: missing the upper output bound d (usage: defscale varname basename a b c d)"),
    ("defsat S b 1 -1", "defsat: '-1' is not an upper limit at least the lower limit"),
    ("defint J b fast", "defint: 'fast' is not a frequency in Hz between 0.001 and 100000"),
    ("defwind W b 100 1 pre", "defwind: missing postsat (the control after saturation) (usage: defwind varname basename refreshFreq gain presat postsat)"),
    ("defpid C b 1000 1 2", "defpid: missing kd (a number or variable) (usage: defpid varname error refreshFreq kp ki kd [low high])"),
    ("defpid C b 1000 1 2 3 -1", "defpid: missing the upper output limit (usage: defpid varname error refreshFreq kp ki kd [low high])"),
    ("deflpf F b 100 0", "deflpf: '0' is not a cutoff frequency above 0 Hz"),
    ("defpwm p3 b 100 Z 1000", "defpwm: 'Z' is not a PWM output of this board (expected 0-7, A-D)"),
    ("defint one b 100", "defint: 'one' is a file playback; choose another name or 'del one' first"),
    ("set a 3", "set: 'a' is an expression and cannot be set (constants, pwm duties and integrators can)"),
    ("set Kp many", "set: 'many' is not a number"),
    ("set nope 1", "set: no variable named 'nope' (type 'printvars' to list them)"),
    ("set PWM4 101", "set: '101' is not a duty cycle in percent (0-100)"),
    ("del adc0", "del: cannot delete 'adc0': it is used by b, I (delete or redefine those first)"),
    ("del one", "del: cannot delete 'one': it is used by Lone (delete or redefine those first)"),
    ("del ghost", "del: no variable named 'ghost' (type 'printvars' to list them)"),
    ("rate Kp 10", "rate: 'Kp' is not a periodic variable (bare expressions, constants and pwm duties have no rate)"),
    ("printv ghost", "printv: no variable named 'ghost' (type 'printvars' to list them)"),
    ("help frob", "help: 'frob' is not a command name (type 'help' for the list)"),
    ("infile two 100 missing.txt", "infile: 'missing.txt' refused by the hardware: file could not be opened, read or parsed"),
    ("log Lx I 100", "log: missing filename (usage: log [logname] varname frequency filename)"),
    ("run -1", "run: '-1' is not a duration in seconds from 0 to 1e9"),
    ("run 1e30", "run: '1e30' is not a duration in seconds from 0 to 1e9"),
    ("run inf", "run: 'inf' is not a duration in seconds from 0 to 1e9"),
    ("run nan", "run: 'nan' is not a duration in seconds from 0 to 1e9"),
    ("gpio 99 10", "gpio: '99' is not a GPIO pin number of this board"),
    ("var now", "var: unexpected 'now' after the last argument (usage: var)"),
];

#[test]
fn every_bad_line_is_refused_with_its_message_and_changes_nothing() {
    assert!(CORPUS.len() >= 20);
    let (mut e, mut b) = engine_and_board();
    b.files.add_input("sin.txt", vec![0.0, 0.5, 1.0]);
    run(&mut e, &mut b, SETUP);
    let mut saved = String::new();
    e.save(&mut saved).unwrap();
    for (line, expected) in CORPUS {
        let before = e.clone();
        let mut out = String::new();
        let err = e.execute(line, &mut b, &mut out).expect_err(line);
        assert_eq!(err.to_string(), *expected, "for line {line:?}");
        assert_eq!(e, before, "table changed by {line:?}");
        assert!(out.is_empty(), "{line:?} printed {out:?}");
    }
    let mut after = String::new();
    e.save(&mut after).unwrap();
    assert_eq!(saved, after);
}

#[test]
fn command_prints_the_error_line() {
    let (mut e, mut b) = engine_and_board();
    let mut out = String::new();
    assert!(e.command("adc 0", &mut b, &mut out).is_err());
    assert_eq!(
        out,
        "error: adc: missing frequency (usage: adc channel frequency)\n"
    );
}

#[test]
fn full_table_is_refused_without_partial_changes() {
    let (mut e, mut b) = engine_and_board();
    for i in 0..score_core::capacity::MAX_SYMBOLS - 1 {
        run(&mut e, &mut b, &format!("defexp c{i} {i}"));
    }
    // Needs the target and two placeholders: only one slot is left.
    assert_eq!(
        refused_unchanged(&mut e, &mut b, "defexp z p q +"),
        "defexp: no room: variables (capacity 64; see 'capacities')"
    );
    run(&mut e, &mut b, "defexp z c1 c2 +");
    assert_eq!(e.len(), 64);
}
