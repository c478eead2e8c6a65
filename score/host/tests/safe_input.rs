//! The host port takes any input safely (issue 18, item 3): the clock, `--run`, Ctrl-C during
//! a run, logs of non-finite values played back, byte-order marks, columns in script errors.
mod common;

use std::io::Write;
use std::process::{Command, Stdio};
use std::time::Duration;

use score_core::Real;
use score_host::{Session, SessionError, TimeMode};

use common::{score, score_in};
use conductor_testkit::{number_after, run_ok};

#[test]
fn run_never_moves_the_simulated_clock_past_its_end_or_backwards() {
    let dir = common::workdir("clock");
    let mut s = Session::new(TimeMode::Simulated, &dir);
    let mut out = String::new();
    for bad in ["1e30", "inf", "nan", "-5"] {
        let err = s.line(&format!("run {bad}"), &mut out).unwrap_err();
        assert_eq!(
            err.to_string(),
            format!("run: '{bad}' is not a duration in seconds from 0 to 1e9")
        );
        assert_eq!(s.now_us(), 0);
    }
    assert!(s.advance(f64::INFINITY).is_err() && s.advance(-1.0).is_err());
    assert!(s.advance(f64::NAN).is_err());
    // The clock holds u64::MAX µs (about 1.8e13 s): with nothing periodic, runs of the largest
    // duration reach its end quickly; the run that would pass it is refused, the clock stays.
    let mut runs = 0;
    let end = loop {
        match s.advance(1e9) {
            Ok(()) => runs += 1,
            Err(e) => break e,
        }
        assert!(runs < 20_000, "the clock never ended");
    };
    assert_eq!(runs, u64::MAX / 1_000_000_000_000_000);
    assert!(matches!(end, SessionError::ClockEnd { .. }), "{end}");
    assert_eq!(s.now_us(), runs * 1_000_000_000_000_000);
    assert!(end
        .to_string()
        .contains("would pass the end of the simulated clock"));
    // Smaller runs still fit up to the last microsecond.
    s.advance((u64::MAX - s.now_us()) as f64 / 1e6 - 1.0)
        .unwrap();
    assert!(s.now_us() > u64::MAX - 2_000_000);
}

#[test]
fn run_option_is_checked_like_the_command() {
    let dir = common::workdir_with("run-option", "a.score", "adc 0 100\n");
    for bad in ["inf", "-5", "nan", "1e30"] {
        let out = score_in(&dir, &["-q", "--script", "a.score", "--run", bad])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{bad}: {err}");
        assert!(
            err.contains(&format!(
                "run: '{bad}' is not a duration in seconds from 0 to 1e9"
            )),
            "{bad}: {err}"
        );
    }
}

/// Ctrl-C during a long simulated run stops it at the current instant; the session goes on
/// with the next line. (A 100 Hz variable and `run 1e9`: 10¹¹ updates, hours of CPU.)
#[test]
fn ctrl_c_stops_a_long_run_and_the_session_continues() {
    let (mut child, rx) = conductor_testkit::spawn_with_lines(
        score()
            .args(["--simulated"])
            .stdin(Stdio::piped())
            .stderr(Stdio::piped()),
    );
    let mut stdin = child.stdin.take().unwrap();
    stdin
        .write_all(b"adc 0 100\nrun 1e9\nprintv ADC0\nsim\n")
        .unwrap();
    let next = |what: &str| {
        rx.recv_timeout(Duration::from_secs(60))
            .unwrap_or_else(|_| panic!("no output while waiting for {what}"))
    };
    while next("the run") != "$> run 1e9" {}
    // The run has started (the echo is printed once the line is taken in hand); let it work.
    std::thread::sleep(Duration::from_millis(300));
    let kill = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    drop(stdin);
    let mut rest = Vec::new();
    while let Ok(l) = rx.recv_timeout(Duration::from_secs(60)) {
        rest.push(l);
    }
    let status = child.wait().unwrap();
    let text = rest.join("\n");
    let at: f64 = number_after(&text, "error: run: interrupted at t = ");
    assert!(at > 0.0 && at < 1e9, "{at}");
    // The next lines ran, at the instant where the run stopped.
    assert!(text.contains("ADC0 - "), "{text}");
    assert!(
        text.contains(&format!("time: {at:.6} s (Simulated)")),
        "{text}"
    );
    // An interrupted run is a failed line: a piped session exits 1, not killed by the signal.
    assert_eq!(status.code(), Some(1));
}

#[test]
fn a_log_of_non_finite_values_warns_and_plays_back() {
    let dir = common::workdir_with(
        "nonfinite-log",
        "inf.score",
        "var\ndefexp num 1\ndefexp den 1\ndefexp x num den /\nlog x 10 x.log\nrun 0.2\n\
         set den 0\nrun 0.2\nset num -1\nrun 0.1\nset num 0\nrun 0.1\n",
    );
    let out = run_ok(&mut score_in(&dir, &["-q", "--script", "inf.score"]));
    let err = String::from_utf8_lossy(&out.stderr);
    // Said once, where it first happened.
    assert_eq!(err.matches("warning: log:").count(), 1, "{err}");
    assert!(
        err.contains("x.log:3: the value is inf (not finite"),
        "{err}"
    );
    let log = std::fs::read_to_string(dir.join("x.log")).unwrap();
    assert_eq!(
        log.lines().collect::<Vec<_>>(),
        ["1", "1", "inf", "inf", "-inf", "NaN"]
    );
    // infile plays the log back value for value.
    let mut s = Session::new(TimeMode::Simulated, &dir);
    let mut o = String::new();
    s.line("infile p 10 x.log", &mut o).unwrap();
    let mut played = Vec::new();
    for _ in 0..6 {
        s.advance(0.1).unwrap();
        played.push(s.engine().value_of("p").unwrap().to_f64());
    }
    assert_eq!(
        &played[..5],
        [1.0, 1.0, f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY]
    );
    assert!(played[5].is_nan());
}

#[test]
fn a_script_with_a_byte_order_mark_runs_and_loads() {
    let dir = common::workdir_with("bom", "bom.score", "\u{feff}var\ndefexp k 2\n");
    run_ok(&mut score_in(&dir, &["-q", "--script", "bom.score"]));
    let mut s = Session::new(TimeMode::Simulated, &dir);
    s.line("load bom.score", &mut String::new()).unwrap();
    assert_eq!(s.engine().value_of("k"), Some(2.0));
    // A column after a byte-order mark counts what an editor shows.
    std::fs::write(dir.join("bad.score"), "\u{feff}adc 9 100\n").unwrap();
    let err = s.line("script bad.score", &mut String::new()).unwrap_err();
    assert!(
        err.to_string().starts_with("bad.score:1:5: adc: '9'"),
        "{err}"
    );
}

#[test]
fn errors_of_scripts_and_piped_lines_show_the_column() {
    let dir = common::workdir_with("column", "c.score", "var\ndefexp k 2\ndefexp x k 2 $ +\n");
    let out = score_in(&dir, &["-q", "--script", "c.score"])
        .output()
        .unwrap();
    assert_eq!(
        String::from_utf8_lossy(&out.stderr).trim(),
        "error: c.score:3:14: defexp: in the expression at '$': expected a number, a variable \
         name or an operator (+ - * / min max neg abs sqrt sin cos exp)"
    );
    // Typed or piped: a caret under the token, below the echoed line.
    let out = common::piped_session(&["--simulated"], b"  adc 0 100 extra\n");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("$> adc 0 100 extra\n             ^\nerror: adc: unexpected 'extra'"),
        "{text}"
    );
}

#[test]
fn simulated_inputs_must_be_finite() {
    let dir = common::workdir("sim");
    let mut s = Session::new(TimeMode::Simulated, &dir);
    for bad in ["nan", "inf", "-inf"] {
        let err = s
            .line(&format!("sim adc 0 {bad}"), &mut String::new())
            .unwrap_err();
        assert_eq!(err.to_string(), format!("sim: '{bad}' is not a voltage"));
    }
}
