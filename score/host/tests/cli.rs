//! The `score` binary: batch scripts, piped sessions, save/load, real time.
mod common;

use score_host::{Session, TimeMode};

use common::score_in;
use conductor_testkit::run_ok;

#[test]
fn every_thesis_script_runs_unchanged_in_batch_mode() {
    let dir = common::workdir("cli-scripts");
    let mut scripts: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
        .filter(|n| n.ends_with(".score"))
        .collect();
    scripts.sort();
    assert_eq!(scripts.len(), 6, "{scripts:?}"); // Fig. 4.5, 5.4, 5.13 a and b, 5.15, 5.20
    for s in &scripts {
        let out = run_ok(&mut score_in(&dir, &["--script", s, "--run", "2"]));
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            text.starts_with("$> var"),
            "{s}: transcript-style echo: {text}"
        );
    }
    // Fig. 5.4: 2 s at 100 Hz.
    assert_eq!(common::numbers(&dir.join("prop")).len(), 200);
}

#[test]
fn piped_session_prints_prompts_outputs_and_fails_on_errors() {
    let out = common::piped_session(
        &["--simulated", "-q"],
        "adc A 1000\nvar\ndefexp target adca 1 \u{2212}\nrun 0.1\nprintv target\nbogus\n"
            .as_bytes(),
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("-\n  adca\n  1.000000\n"), "{text}");
    assert!(text.contains("target - "), "{text}");
    assert!(text.contains("error: unknown command 'bogus'"), "{text}");
    assert!(!out.status.success());
}

#[test]
fn save_then_load_recreates_the_table_and_a_bad_file_changes_nothing() {
    let dir = common::workdir("save-load");
    let mut s = Session::new(TimeMode::Simulated, &dir);
    let mut out = String::new();
    s.script("fig5_20.score", &mut out).unwrap();
    s.line("set Kd 0.5", &mut out).unwrap();
    s.line("save cfg.score", &mut out).unwrap();
    let mut before = String::new();
    s.engine().save(&mut before).unwrap();
    s.line("clear", &mut out).unwrap();
    assert!(s.engine().is_empty());
    s.line("load cfg.score", &mut out).unwrap();
    let mut after = String::new();
    s.engine().save(&mut after).unwrap();
    assert_eq!(before, after);
    assert_eq!(s.engine().value_of("Kd"), Some(0.5));

    std::fs::write(dir.join("bad.score"), "defexp a 1\ndefexp b a +\n").unwrap();
    let snapshot = s.engine().clone();
    let err = s.line("load bad.score", &mut out).unwrap_err();
    assert_eq!(
        err.to_string(),
        "load: nothing changed: bad.score:2:12: defexp: in the expression at '+': this operator needs two \
         operands before it (postfix: 'a b +')"
    );
    assert!(*s.engine() == snapshot);
}

#[test]
fn script_errors_name_file_and_line() {
    let dir = common::workdir_with(
        "script-error",
        "s.score",
        "var\ndefexp k 2\nadc 9 100\ndefexp never 1\n",
    );
    let mut s = Session::new(TimeMode::Simulated, &dir);
    let err = s.line("script s.score", &mut String::new()).unwrap_err();
    assert_eq!(
        err.to_string(),
        "s.score:3:5: adc: '9' is not an ADC channel of this board (expected 0-3, A-B or T)"
    );
    assert!(s.engine().lookup("k").is_some() && s.engine().lookup("never").is_none());
}

#[test]
fn real_time_mode_updates_on_the_wall_clock() {
    let dir = common::workdir_with(
        "realtime",
        "rt.score",
        "infile x 100 100SIN.HZ\nlog x 100 rt.log\n",
    );
    run_ok(&mut score_in(
        &dir,
        &["--realtime", "-q", "--script", "rt.score", "--run", "0.3"],
    ));
    // 100 Hz for 0.3 s of wall time: 30 updates when on time; a slow machine skips (and counts)
    // late ones instead of bursting, so fewer, never more than 31.
    let n = common::numbers(&dir.join("rt.log")).len();
    assert!((3..=31).contains(&n), "{n} log lines");
}
