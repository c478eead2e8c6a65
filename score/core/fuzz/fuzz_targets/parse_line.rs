//! Fuzzes the command parser and engine: arbitrary bytes split into lines must never panic, and
//! a refused line must leave the table unchanged.
#![no_main]

use libfuzzer_sys::fuzz_target;
use score_core::{hal::DummyHal, Engine};

fuzz_target!(|data: &[u8]| {
    let mut engine: Engine<f64> = Engine::new();
    let mut hal = DummyHal::default();
    let text = String::from_utf8_lossy(data);
    let mut t = 0u64;
    for line in text.lines().take(64) {
        let before = format!("{engine:?}");
        let mut out = String::new();
        if engine.execute(line, &mut hal, &mut out).is_err() {
            assert_eq!(before, format!("{engine:?}"), "refused line changed the table: {line:?}");
        }
        t += 1_000;
        engine.tick(t, &mut hal);
        let mut saved = String::new();
        let _ = engine.save(&mut saved);
    }
});
