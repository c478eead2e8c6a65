//! Every terminal transcript of the thesis (Fig. 5.1, 5.2, 5.6, 5.9, 5.16, 5.25), typed into the
//! host port unchanged. Whitespace, the typographic minus/quotes of the print and annotations in
//! parentheses are tolerated; values read from the (simulated) ADC differ from the thesis' board,
//! so variable lines are matched by name and format, and the tied relations between the values
//! (volts of a raw code, scale, expression, PWM following a variable) are checked exactly.
mod common;

use std::collections::BTreeMap;

use score_host::{Session, TimeMode};
use score_transcript::Transcript;

type Check = fn(&BTreeMap<String, f64>);

/// `a` = f(inputs) where f has gain `gain` from its printed inputs: every printed value carries
/// at most 5e-7 of rounding (six decimals), so |a - f| <= 5e-7 (1 + gain); the engine computed f
/// in its number type with at most four roundings, 4u|a| more (u: unit roundoff of `Num`).
fn close(a: f64, b: f64, gain: f64, what: &str) {
    let tol = 5e-7 * (1.0 + gain) + 4.0 * common::unit_roundoff() * a.abs().max(b.abs()) + 1e-12;
    assert!(
        (a - b).abs() <= tol,
        "{what}: {a} vs {b} (tolerance {tol:e})"
    );
}

/// A PWM variable reports the duty the HAL produced; the HAL takes the duty as an f32 fraction
/// (<= 2^-25 absolute rounding below 1, i.e. 3e-6 %), on top of the printing rounding.
fn close_duty(duty: f64, source: f64, what: &str) {
    let tol = 1e-6 + 100.0 * 2f64.powi(-25) + 4.0 * common::unit_roundoff() * duty.abs();
    assert!(
        (duty - source).abs() <= tol,
        "{what}: {duty} vs {source} (tolerance {tol:e})"
    );
}

/// Types the transcript into a fresh session (score_transcript checks the output's structure)
/// and hands every variable listing to `check`.
fn run_transcript(file: &str, check: Check) {
    let transcript = Transcript::load(file).unwrap();
    let mut banner = String::new();
    score_core::write_banner(&mut banner).unwrap();
    let mut session = Session::new(TimeMode::Simulated, common::workdir(file));
    let listings = transcript
        .check(&banner, |command| {
            let mut out = String::new();
            session
                .line(command, &mut out)
                .unwrap_or_else(|e| panic!("{file}: {command}: {e}"));
            // A person types: let simulated time pass between lines so the variables update.
            session.advance(0.25).unwrap();
            out
        })
        .unwrap_or_else(|m| panic!("{m}"));
    for listing in listings {
        check(&listing.into_iter().collect());
    }
}

/// adcN = ADCN x 3.0 / 1023 (single-ended) or minus 1.5 (differential), thesis §5.1.1.
fn adc_pairs(v: &BTreeMap<String, f64>) {
    for (name, raw) in v.iter().filter(|(n, _)| n.starts_with("ADC")) {
        let suffix = &name[3..];
        let volts = v[&format!("adc{}", suffix.to_lowercase())];
        let offset = if suffix.chars().all(|c| c.is_ascii_digit()) {
            0.0
        } else {
            1.5
        };
        close(volts, raw * 3.0 / 1023.0 - offset, 0.0, name);
    }
}

#[test]
fn fig5_1_adc_initialisation() {
    run_transcript("fig5_1.transcript", |v| {
        adc_pairs(v);
        // The ladder of the simulated board, like the thesis' (0.96, 2.68, 1.83, 0.98 V).
        for (n, volts) in [
            ("adc0", 0.97),
            ("adc1", 2.68),
            ("adc2", 1.83),
            ("adc3", 0.98),
        ] {
            assert!((v[n] - volts).abs() < 0.01, "{n} = {}", v[n]);
        }
    });
}

#[test]
fn fig5_2_pwm_sessions() {
    run_transcript("fig5_2a.transcript", |_| {});
    run_transcript("fig5_2b.transcript", |_| {});
}

#[test]
fn fig5_6_proportional_configuration() {
    run_transcript("fig5_6.transcript", |v| {
        adc_pairs(v);
        close(
            v["Padca"],
            ((v["adca"] + 1.5) / 3.0 * 100.0).clamp(0.0, 100.0),
            100.0 / 3.0,
            "Padca",
        );
        // pw2 follows Padca at 1 kHz, the rate of the ADC: sampled at the same instant.
        close_duty(v["pw2"], v["Padca"], "pw2");
    });
}

#[test]
fn fig5_9_integral_configuration() {
    run_transcript("fig5_9.transcript", |v| {
        adc_pairs(v);
        let scale = |x: f64, a: f64, b: f64| ((x - a) / (b - a) * 100.0).clamp(0.0, 100.0);
        close(
            v["SIadca"],
            scale(v["Iadca"], -1.8, -1.2),
            100.0 / 0.6,
            "SIadca",
        );
        close(v["SIIadca"], scale(v["Iadca"], -0.5, 0.5), 100.0, "SIIadca");
        // The second defpwm replaced the first: pw2 follows SIIadca, but at 100 Hz while Iadca
        // moves at 1 kHz: pw2 lags by up to 10 ms, in which Iadca moves at most 10 ms x |adca|
        // <= 0.015 (|adca| <= 1.5 V), i.e. 1.5 % after the x100 scale.
        assert!(
            (v["pw2"] - v["SIIadca"]).abs() <= 1.5,
            "pw2 {} vs SIIadca {}",
            v["pw2"],
            v["SIIadca"]
        );
    });
}

#[test]
fn fig5_16_derivative_configuration() {
    run_transcript("fig5_16.transcript", |v| {
        adc_pairs(v);
        // pw2 samples Dadc1 at 100 Hz, Dadc1 changes at 500 Hz: only the duty range is certain.
        assert!((0.0..=100.0).contains(&v["pw2"]) && v["Dadc1"].is_finite());
    });
}

#[test]
fn fig5_25_negative_feedback_configuration() {
    run_transcript("fig5_25.transcript", |v| {
        adc_pairs(v);
        close(v["target"], v["adca"] - 1.0, 1.0, "target");
        if let Some(s) = v.get("Starget") {
            close(
                *s,
                ((v["target"] + 1.5) / 3.0 * 100.0).clamp(0.0, 100.0),
                100.0 / 3.0,
                "Starget",
            );
        }
    });
}
