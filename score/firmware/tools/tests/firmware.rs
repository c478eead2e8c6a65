//! The firmware ELF in the rp2040js emulator, driven like a person and a lab bench would:
//! the thesis' terminal sessions typed into the terminal PTY, ADC inputs set and PWM duty
//! measured at the pins, the UF2 image booting like the ELF.
//!
//! Needs the firmware ELF (`score-fw build`) and the harness (`npm ci` in
//! score/firmware/emulator); a test fails with a message saying how to get them.

use std::path::PathBuf;
use std::time::Duration;

use score_firmware_tools::emulator::Emulator;
use score_firmware_tools::port::Port;
use score_transcript::{normalize, Listing, Transcript};

const PROMPT: &str = "$> ";
const WAIT: Duration = Duration::from_secs(20);

fn start() -> Emulator {
    Emulator::start().unwrap_or_else(|e| panic!("{e}"))
}

/// The terminal, opened and greeted (DTR raised, banner read up to the first prompt).
fn terminal(emu: &mut Emulator) -> (Port, String) {
    let mut t = Port::open(&emu.term, WAIT).expect("terminal PTY");
    emu.dtr("term", true).unwrap();
    let banner = t.read_until_suffix(PROMPT, WAIT).expect("banner");
    (t, banner)
}

/// Types `line` and returns the output lines up to the next prompt, without the echo.
fn type_line(t: &mut Port, line: &str) -> Vec<String> {
    t.write_all(format!("{line}\r").as_bytes()).unwrap();
    let text = t.read_until_suffix(PROMPT, WAIT).unwrap();
    let mut lines: Vec<String> = text
        .trim_end_matches(PROMPT)
        .split("\r\n")
        .map(normalize)
        .collect();
    assert_eq!(
        lines.first().map(String::as_str),
        Some(normalize(line).as_str()),
        "echo"
    );
    lines.remove(0);
    lines.retain(|l| !l.is_empty());
    lines
}

/// Types every command of a thesis transcript into the terminal; score_transcript holds the
/// output to the transcript's structure (see `Transcript::check`). Returns the variable
/// listings for the caller's value checks.
fn run_transcript(emu: &mut Emulator, file: &str) -> Vec<Listing> {
    let transcript = Transcript::load(file).unwrap();
    let (mut t, banner) = terminal(emu);
    transcript
        .check(&banner, |command| {
            let out = type_line(&mut t, command).join("\n");
            // A person types: let some time pass so the variables update.
            std::thread::sleep(Duration::from_millis(50));
            out
        })
        .unwrap_or_else(|m| panic!("{m}"))
}

/// Volts of a 12-bit code with the board's f32 arithmetic: code · 3.3 / 4095 rounded to f32
/// (at most 3 roundings of 2^-24 relative: < 1e-6 V), printed with six decimals (5e-7).
fn close_volts(volts: f64, raw: f64, offset: f64, what: &str) {
    let expect = raw * 3.3 / 4095.0 - offset;
    assert!(
        (volts - expect).abs() <= 2e-6,
        "{what}: {volts} V for code {raw} (expected {expect})"
    );
}

#[test]
fn fig5_1_adc_initialisation_on_the_terminal() {
    let mut emu = start();
    // A resistor ladder like the thesis' (0.96, 2.68, 1.83, 0.98 V).
    let ladder = [0.96, 2.68, 1.83, 0.98];
    for (ch, v) in ladder.iter().enumerate() {
        emu.set_adc_volts(ch as u8, *v).unwrap();
    }
    let listings = run_transcript(&mut emu, "fig5_1.transcript");
    assert_eq!(listings.len(), 3);
    for l in &listings {
        let v: std::collections::BTreeMap<_, _> = l.iter().cloned().collect();
        for ch in 0..4 {
            let raw = v[&format!("ADC{ch}")];
            assert_eq!(raw, (ladder[ch] / 3.3 * 4095.0_f64).round(), "ADC{ch}");
            close_volts(v[&format!("adc{ch}")], raw, 0.0, "adc");
        }
    }
}

#[test]
fn fig5_6_proportional_configuration_on_the_terminal() {
    let mut emu = start();
    // Pair A = ADC0 - ADC1 (software differential): 0.25 V apart.
    emu.set_adc_volts(0, 1.90).unwrap();
    emu.set_adc_volts(1, 1.65).unwrap();
    let listings = run_transcript(&mut emu, "fig5_6.transcript");
    assert_eq!(listings.len(), 2);
    for l in &listings {
        let v: std::collections::BTreeMap<_, _> = l.iter().cloned().collect();
        // Offset-binary code of the difference: 2048 + 2358 - 2048 = 2358.
        assert_eq!(
            v["ADCA"],
            2048.0 + (1.90f64 / 3.3 * 4095.0).round() - (1.65f64 / 3.3 * 4095.0).round()
        );
        close_volts(v["adca"], v["ADCA"], 1.65, "adca");
        // Padca = (adca + 1.5) / 3 * 100 (printed values carry 5e-7 each; gain 100/3; f32 math
        // adds < 1e-5 at this magnitude).
        let p = ((v["adca"] + 1.5) / 3.0 * 100.0).clamp(0.0, 100.0);
        assert!(
            (v["Padca"] - p).abs() <= 5e-7 * (1.0 + 100.0 / 3.0) + 1e-5,
            "Padca {} vs {p}",
            v["Padca"]
        );
        // pw2 is the duty actually produced: Padca quantised to the 1 kHz timer's 62 500
        // counts (half a count = 8e-4 %).
        assert!(
            (v["pw2"] - v["Padca"]).abs() <= 100.0 * 0.5 / 62_500.0 + 1e-5,
            "pw2 {} vs Padca {}",
            v["pw2"],
            v["Padca"]
        );
    }
}

#[test]
fn adc_to_pwm_chain_gives_the_duty_at_the_pin_within_one_count() {
    let mut emu = start();
    let (mut t, _) = terminal(&mut emu);
    for line in [
        "adc 0 1000",
        "defscale P adc0 0 3.3 0 100",
        "defpwm pw P 1000 2 20000",
    ] {
        let out = type_line(&mut t, line);
        assert!(
            !out.iter().any(|l| l.starts_with("error")),
            "{line}: {out:?}"
        );
    }
    // 20 kHz at 125 MHz: DIV 1, TOP 6249, so one count is 1/6250 of the period.
    let counts = 6250.0;
    for volts in [0.4, 1.65, 2.9] {
        let code = emu.set_adc_volts(0, volts).unwrap();
        let expected = code as f64 / 4095.0; // P = adc0 / 3.3 * 100 %
                                             // The first measurement may straddle the update; the second sees the settled duty.
        emu.measure_pwm(2, 4).unwrap();
        let m = emu.measure_pwm(2, 8).unwrap();
        assert_eq!(m.periods, 8, "{volts} V: no PWM at GPIO 2");
        let period = m.period_ns.unwrap();
        assert!((period - 50_000.0).abs() < 1.0, "period {period} ns");
        let err_counts = (m.duty - expected).abs() * counts;
        assert!(
            err_counts <= 1.0,
            "{volts} V: duty {} vs {expected} ({err_counts} counts)",
            m.duty
        );
    }
}

#[test]
fn pwm_pairs_gpio_and_firmware_commands() {
    let mut emu = start();
    let (mut t, _) = terminal(&mut emu);
    // Complementary pair B (slice 1: GPIO 2 and 3) at 25 %: GPIO 3 is the inverse.
    assert!(type_line(&mut t, "pwm B 10000 25").is_empty());
    let a = emu.measure_pwm(2, 4).unwrap();
    let b = emu.measure_pwm(3, 4).unwrap();
    assert!(
        (a.duty - 0.25).abs() < 1e-9 && (b.duty - 0.75).abs() < 1e-9,
        "{a:?} {b:?}"
    );
    // GPIO 2 belongs to the pair now.
    let out = type_line(&mut t, "gpio 2 10");
    assert!(
        out.iter().any(|l| l.contains("no free hardware resource")),
        "{out:?}"
    );
    // A digital output follows its source.
    type_line(&mut t, "defexp on 1");
    type_line(&mut t, "defgpio led on 100 7");
    let m = emu.measure_pwm(7, 2).unwrap();
    assert_eq!((m.duty, m.periods), (1.0, 0), "GPIO 7 high");
    let out = type_line(&mut t, "board");
    assert!(
        out[0].starts_with("board 'rp2040', score-firmware"),
        "{out:?}"
    );
    let out = type_line(&mut t, "bench 20");
    assert_eq!(out.len(), 3, "{out:?}");
    for (line, name) in out[1..].iter().zip(["f32", "f64"]) {
        let mean: f64 = line
            .split_whitespace()
            .skip_while(|w| *w != "mean")
            .nth(1)
            .and_then(|w| w.parse().ok())
            .unwrap_or_else(|| panic!("{line}"));
        assert!(
            line.starts_with(&format!("bench {name}: min")) && mean > 100.0,
            "{line}"
        );
    }
}

#[test]
fn uf2_image_boots_like_the_elf() {
    let elf = score_firmware_tools::paths::firmware_elf().unwrap_or_else(|e| panic!("{e}"));
    let bytes = std::fs::read(&elf).unwrap();
    let uf2 = score_firmware_tools::image::uf2(&bytes).unwrap();
    let usage = score_firmware_tools::image::usage(&bytes).unwrap();
    // Every flash byte is in a 256-byte page of its own block; pages are 256-aligned.
    assert_eq!(uf2.len() % 512, 0);
    let blocks = uf2.len() / 512;
    assert!(
        blocks as u64 * 256 >= usage.flash && (blocks as u64 - 2) * 256 < usage.flash + 256 * 4
    );
    let dir = std::env::temp_dir().join(format!("score-uf2-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path: PathBuf = dir.join("fw.uf2");
    std::fs::write(&path, &uf2).unwrap();
    let mut emu = Emulator::start_image(&path).unwrap_or_else(|e| panic!("{e}"));
    let (mut t, banner) = terminal(&mut emu);
    assert!(banner.contains("Welcome to Score"), "{banner}");
    assert!(type_line(&mut t, "adc 0 100").is_empty());
}
