//! Behaviour of the command language and the scheduler.
mod common;

use common::{board, refused, refused_unchanged, run, run_until, MemBoard};
use score_core::{Engine, Error, Num, VarKind};

fn engine() -> (Engine<Num>, MemBoard) {
    let mut b = board();
    b.hw.adc_code = 330;
    (Engine::new(), b)
}

#[test]
fn adc_creates_raw_and_volts_pair_listed_in_ascii_order() {
    let (mut e, mut b) = engine();
    run(&mut e, &mut b, "adc 0 100\nadc A 1000\nvar");
    let mut out = String::new();
    e.execute("printvars", &mut b, &mut out).unwrap();
    let lines: Vec<&str> = out.lines().filter(|l| !l.is_empty()).collect();
    // 330 * 3 / 1023 = 0.967742 (single ended); minus 1.5 differential.
    assert_eq!(
        lines,
        [
            "ADC0 - 330.000000",
            "ADCA - 330.000000",
            "adc0 - 0.967742",
            "adca - -0.532258"
        ]
    );
    let volts = e.info(e.lookup("adc0").unwrap()).unwrap();
    assert_eq!(
        (volts.kind, volts.unit, volts.rate_hz),
        (VarKind::AdcVolts, Some("V"), Some(100.0))
    );
}

#[test]
fn defexp_echoes_the_tree_and_forward_references_resolve() {
    let (mut e, mut b) = engine();
    let out = run(&mut e, &mut b, "defexp target adca 1 \u{2212}");
    let echo: Vec<&str> = out.lines().map(str::trim).collect();
    assert_eq!(
        echo,
        [
            "-",
            "adca",
            "1.000000",
            "note: 'adca' is not defined yet; it reads 0 until it is"
        ]
    );
    // adca is a placeholder (reads 0) until the ADC exists, then the same slot is the channel.
    assert_eq!(e.value_of("target"), Some(-1.0));
    assert_eq!(
        e.info(e.lookup("adca").unwrap()).unwrap().kind,
        VarKind::Undefined
    );
    run(&mut e, &mut b, "adc A 1000");
    let v = e.value_of("target").unwrap();
    assert!((v - (330.0 * 3.0 / 1023.0 - 1.5 - 1.0)).abs() < 1e-12);
}

#[test]
fn cycles_through_bare_expressions_are_rejected_but_blocks_break_them() {
    let (mut e, mut b) = engine();
    run(&mut e, &mut b, "defexp a b 1 +\ndefexp b c 2 *");
    let before = e.clone();
    let mut out = String::new();
    let err = e.execute("defexp c a 1 -", &mut b, &mut out).unwrap_err();
    assert!(matches!(err, Error::Cycle { .. }), "{err}");
    assert!(
        err.to_string()
            .contains("'c' would depend on itself through 'a'"),
        "{err}"
    );
    assert_eq!(e, before);
    assert!(e.execute("defexp x x 1 +", &mut b, &mut out).is_err());
    // Through an integrator the loop is fine (Fig. 5.13 b: Isine reads pi which reads Isine).
    run(&mut e, &mut b, "defint c a 100");
}

#[test]
fn del_is_refused_with_the_list_of_users() {
    let (mut e, mut b) = engine();
    run(
        &mut e,
        &mut b,
        "adc 0 100\ndefint I adc0 100\ndefexp P adc0 2 *\ndefexp Q P 1 +",
    );
    assert_eq!(
        refused_unchanged(&mut e, &mut b, "del adc0"),
        "del: cannot delete 'adc0': it is used by I, P (delete or redefine those first)"
    );
    run(&mut e, &mut b, "del Q\ndel P\ndel I\ndel ADC0");
    assert!(e.is_empty());
}

#[test]
fn set_changes_constants_and_refuses_computed_values() {
    let (mut e, mut b) = engine();
    run(
        &mut e,
        &mut b,
        "defexp Kp 21\ndefexp u Kp 2 *\npwm 2 1000 25",
    );
    run(&mut e, &mut b, "set Kp 3\nset PWM2 40");
    assert_eq!(e.value_of("u"), Some(6.0));
    assert!((b.hw.duty[2] - 0.4).abs() < 1e-6);
    assert_eq!(
        refused(&mut e, &mut b, "set u 1"),
        "set: 'u' is an expression and cannot be set (constants, pwm duties and integrators can)"
    );
    let info = e.info(e.lookup("Kp").unwrap()).unwrap();
    assert!(info.writable && !e.info(e.lookup("u").unwrap()).unwrap().writable);
}

#[test]
fn scheduler_runs_higher_rates_first_and_producers_first_at_equal_rates() {
    let (mut e, mut b) = engine();
    // The log is defined before its source, and at a lower rate than the integrator.
    b.files.add_input("in", vec![1.0, 2.0, 3.0, 4.0]);
    run(
        &mut e,
        &mut b,
        "log L I 500 out\ndefint I x 1000\ninfile x 1000 in",
    );
    run_until(&mut e, &mut b, 4_000);
    // x: 1,2,3,4 at t = 0..3 ms; I(0)=0, I(1ms)=1.5e-3, I(2)=4e-3, I(3)=7.5e-3; logged at 0, 2 ms
    // after the 1 kHz updates of the same instant.
    assert_eq!(b.files.log("out"), [0.0, 0.004]);
}

#[test]
fn playback_loops_and_rates_do_not_drift() {
    let (mut e, mut b) = engine();
    b.files.add_input("in", vec![1.0, 2.0, 3.0]);
    run(&mut e, &mut b, "infile x 3 in\nlog x 3 out");
    run_until(&mut e, &mut b, 10_000_000);
    // 3 Hz for 10 s = 30 updates exactly (a rounded 333333 us period would drift).
    let log = b.files.log("out");
    assert_eq!(log.len(), 30);
    assert_eq!(&log[..7], [1.0, 2.0, 3.0, 1.0, 2.0, 3.0, 1.0]);
}

#[test]
fn late_ticks_skip_and_count_instead_of_bursting() {
    let (mut e, mut b) = engine();
    b.files.add_input("in", vec![0.0; 10]);
    run(&mut e, &mut b, "defint I one 100\ndefexp one 1");
    assert_eq!(e.tick(0, &mut b), 1);
    assert_eq!(e.tick(55_000, &mut b), 1, "one update, not five");
    let id = e.lookup("I").unwrap();
    assert_eq!(e.missed_updates(id), Some(4));
    // The integral still spans the real elapsed time: t = 50 ms (latest due instant).
    assert!((e.value(id).unwrap() - 0.05).abs() < 1e-12);
    assert_eq!(e.next_deadline(), Some(60_000));
}

#[test]
fn next_deadline_follows_definitions_rates_and_deletions_without_a_tick() {
    let (mut e, mut b) = engine();
    assert_eq!(e.next_deadline(), None, "nothing periodic");
    e.set_time(5_000);
    run(&mut e, &mut b, "defint I x 100");
    assert_eq!(e.next_deadline(), Some(5_000), "a new task is due at once");
    assert_eq!(e.tick(5_000, &mut b), 1);
    assert_eq!(e.next_deadline(), Some(15_000));
    e.set_time(7_000);
    run(&mut e, &mut b, "defdiff D x 1000");
    assert_eq!(e.next_deadline(), Some(7_000));
    assert_eq!(e.tick(7_000, &mut b), 1, "only D is due");
    assert_eq!(e.next_deadline(), Some(8_000));
    assert_eq!(e.tick(7_999, &mut b), 0, "nothing due before 8 ms");
    // A new rate keeps the next update where it was.
    run(
        &mut e,
        &mut b,
        "rate I 1000
del D",
    );
    assert_eq!(e.next_deadline(), Some(15_000));
    // 5 ms late at 1 kHz: one update at the latest due instant (20 ms), the next at 21 ms.
    assert_eq!(e.tick(20_500, &mut b), 1);
    assert_eq!(e.next_deadline(), Some(21_000));
    assert_eq!(e.missed_updates(e.lookup("I").unwrap()), Some(5));
    run(&mut e, &mut b, "del I");
    assert_eq!(e.next_deadline(), None);
}

#[test]
fn save_writes_a_script_that_recreates_the_table() {
    let (mut e, mut b) = engine();
    b.files.add_input("sig.txt", vec![0.5]);
    let script = "adc 1 5000\npwm A 250 25\nvar\ndefexp Kp 21\ndefdiff D adc1 500\ndefexp P adc1 Kp * D +\n\
                  defscale S P -1.5 1.5 0 100\ndefsat T S 10 90\ndefwind W adc1 100 1 P T\n\
                  defpid C adc1 1000 Kp 350 0.0788 -1 1\ndeflpf F adc1 100 5\ndefpwm pw2 T 100 2 1000\n\
                  infile sig 100 sig.txt\nlog LT T 10 t.log\nset Kp 7";
    run(&mut e, &mut b, script);
    let mut saved = String::new();
    e.save(&mut saved).unwrap();
    let (mut e2, mut b2) = engine();
    b2.files.add_input("sig.txt", vec![0.5]);
    let body: String = saved
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| format!("{l}\n"))
        .collect();
    run(&mut e2, &mut b2, &body);
    let mut saved2 = String::new();
    e2.save(&mut saved2).unwrap();
    assert_eq!(saved, saved2);
    assert!(
        saved.contains("defexp Kp 7\n") && saved.contains("defexp P adc1 Kp * D +\n"),
        "{saved}"
    );
    assert_eq!(e.len(), e2.len());
}

#[test]
fn redefinition_keeps_users_working() {
    let (mut e, mut b) = engine();
    run(&mut e, &mut b, "defexp k 2\ndefexp y k 3 *");
    assert_eq!(e.value_of("y"), Some(6.0));
    // Fig. 5.9 redefines pw2; here k becomes an expression and y follows.
    run(&mut e, &mut b, "defexp k 1 4 +");
    assert_eq!(e.value_of("y"), Some(15.0));
}

#[test]
fn rate_changes_the_update_frequency() {
    let (mut e, mut b) = engine();
    run(&mut e, &mut b, "defexp one 1\ndefint I one 10");
    run_until(&mut e, &mut b, 1_000_000);
    run(&mut e, &mut b, "rate I 100");
    let t0 = e.next_deadline().unwrap();
    e.tick(t0, &mut b);
    assert_eq!(e.next_deadline(), Some(t0 + 10_000));
    let err = refused(&mut e, &mut b, "rate one 5");
    assert!(err.contains("'one' is not a periodic variable"), "{err}");
}

#[test]
fn pwm_outputs_belong_to_one_variable() {
    let (mut e, mut b) = engine();
    run(&mut e, &mut b, "defexp x 50\ndefpwm pw2 x 100 2 1000");
    assert_eq!(
        refused(&mut e, &mut b, "pwm B 250 25"),
        "pwm: 'B' is already driven by 'pw2' ('del pw2' first)"
    );
    run_until(&mut e, &mut b, 1);
    assert_eq!(e.value_of("pw2"), Some(50.0));
    assert!((b.hw.duty[2] - 0.5).abs() < 1e-7);
}

#[test]
fn help_lists_menus_and_capacities() {
    let (mut e, mut b) = engine();
    let out = run(&mut e, &mut b, "var");
    assert!(out.contains("main : Return to the main menu\nprintv : Print value of a variable\nprintvars : Print the variable table\nhelp : Display list of commands\n"), "{out}");
    let out = run(&mut e, &mut b, "help");
    assert!(out.contains("capacities: 64 symbols"), "{out}");
    let out = run(&mut e, &mut b, "capacities");
    assert!(out.contains("table memory:"), "{out}");
    for c in score_core::help::COMMANDS {
        let out = run(&mut e, &mut b, &format!("help {}", c.name));
        assert!(out.contains(c.summary), "{}", c.name);
    }
}

#[test]
fn the_expression_capacity_counts_tokens_as_typed() {
    let (mut e, mut b) = engine();
    let cap = score_core::capacity::MAX_EXPR_OPS;
    let per = score_core::capacity::MAX_EXPR_TOKENS;
    // k 1 + 1 + ... abs: 32 tokens (stored compiled in fewer instructions; the limit is the
    // tokens).
    let long = format!("k{} abs", " 1 +".repeat((per - 2) / 2));
    assert_eq!(long.split(' ').count(), per);
    for i in 0..cap / per {
        run(&mut e, &mut b, &format!("defexp e{i} {long}"));
    }
    let out = run(&mut e, &mut b, "capacities");
    assert!(
        out.contains(&format!("{cap} of {cap} expression tokens")),
        "{out}"
    );
    assert_eq!(
        refused_unchanged(&mut e, &mut b, "defexp z k abs"),
        format!("defexp: no room: expression tokens (capacity {cap}; see 'capacities')")
    );
    // Redefining counts the new tokens instead of the old ones.
    run(&mut e, &mut b, &format!("defexp e0 {long}"));
    run(&mut e, &mut b, "defexp e0 k 1 +\ndefexp z k abs");
    assert_eq!(e.value_of("z"), Some(0.0));
    assert_eq!(e.value_of("e1"), Some(15.0));
}

#[test]
fn last_update_reports_the_scheduled_instant_of_the_latest_update() {
    let (mut e, mut b) = engine();
    e.set_time(1_000);
    run(
        &mut e,
        &mut b,
        "adc 0 100\ndefexp k 2\ndefexp twice adc0 k *",
    );
    let (raw, volts, lazy) = (
        e.lookup("ADC0").unwrap(),
        e.lookup("adc0").unwrap(),
        e.lookup("twice").unwrap(),
    );
    assert_eq!(e.last_update_us(raw), None, "not run yet");
    e.tick(1_000, &mut b);
    assert_eq!(e.last_update_us(raw), Some(1_000));
    // Ticked 3 ms late: the update runs at its due instant (11 000), which is what it reports.
    e.tick(14_000, &mut b);
    assert_eq!(e.last_update_us(raw), Some(11_000));
    assert_eq!(
        e.last_update_us(volts),
        Some(11_000),
        "volts share the raw task"
    );
    assert_eq!(
        e.last_update_us(lazy),
        None,
        "bare expressions have no schedule"
    );
}

#[test]
fn playback_board_plays_its_signal_for_fig_5_20_and_has_no_peripherals() {
    use score_core::hal::PlaybackHal;
    let signal = [0.0, 0.01, -0.02, 0.03];
    let mut hal = PlaybackHal::new(signal);
    let mut e: Engine<Num> = Engine::new();
    let mut out = String::new();
    for line in score_core::FIG_5_20_PID.lines() {
        e.execute(line, &mut hal, &mut out).expect(line);
    }
    // One sample per 1 kHz update, looping; the first is read when `infile` is typed.
    for k in 0..10u64 {
        e.tick(k * 1000, &mut hal);
        assert_eq!(
            e.value_of("sgnl"),
            Some(signal[k as usize % 4] as Num),
            "update {k}"
        );
    }
    for (line, message) in [
        (
            "adc 0 100",
            "adc: '0' is not an ADC channel of this board (expected none)",
        ),
        (
            "adc T 100",
            "adc: 'T' is not an ADC channel of this board (expected none)",
        ),
        (
            "pwm 0 1000 50",
            "pwm: '0' is not a PWM output of this board (expected none)",
        ),
        (
            "gpio 0 10",
            "gpio: '0' is not a GPIO pin number of this board",
        ),
        (
            "log PID 10 out",
            "log: not available on this port (the hardware or file system is missing)",
        ),
    ] {
        let err = e.execute(line, &mut hal, &mut out).unwrap_err();
        assert_eq!(err.to_string(), message);
    }
}
