//! The checks behind each fuzz target of `score-core`, one function per target taking the raw
//! input. The libFuzzer binaries in `fuzz_targets/` call them, and
//! `score/core/tests/fuzz_corpus.rs` includes this file to replay the committed seed and
//! regression corpora as an ordinary test.

use score_core::hal::{Board, DummyHal, PlaybackHal};
use score_core::line::{LineBuffer, LineEvent};
use score_core::Engine;

/// A target's check: panics when the input shows a bug.
pub type Check = fn(&[u8]);

/// Every target: its name (the binary in `fuzz_targets/`, the folder under `seeds/` and
/// `regressions/`) and its check.
pub const TARGETS: &[(&str, Check)] = &[("parse_line", parse_line), ("terminal", terminal)];

/// The lexer, parser and engine (f64): arbitrary bytes split into lines never panic, a refused
/// line leaves the table unchanged, and the periodic variables run between lines.
///
/// "Unchanged" is checked on a snapshot (`Engine: Clone + PartialEq`), which costs a copy and a
/// comparison per line instead of formatting the whole table with `{:?}` twice. The derived
/// `PartialEq` sees NaN ≠ NaN, so when it reports a difference the two tables are compared by
/// their `Debug` text as before (NaN prints equal to NaN): the property is the same one.
pub fn parse_line(data: &[u8]) {
    let mut engine: Engine<f64> = Engine::new();
    let mut hal = DummyHal::default();
    let text = String::from_utf8_lossy(data);
    let mut t = 0u64;
    let mut out = String::new();
    let mut saved = String::new();
    for line in text.lines().take(64) {
        let before = engine.clone();
        out.clear();
        if engine.execute(line, &mut hal, &mut out).is_err() && before != engine {
            assert_eq!(
                format!("{before:?}"),
                format!("{engine:?}"),
                "refused line changed the table: {line:?}"
            );
        }
        t += 1_000;
        engine.tick(t, &mut hal);
        saved.clear();
        let _ = engine.save(&mut saved);
    }
}

/// The board's terminal (f32, as the firmware): bytes through the line editor (backspace, CR/LF,
/// overlong lines) into the engine, time advancing between lines. Afterwards the table's `save`
/// text, typed into a fresh engine, is accepted line by line and saves the same lines.
pub fn terminal(data: &[u8]) {
    let mut engine: Engine<f32> = Engine::new();
    let mut hal = board();
    let mut editor = LineBuffer::new();
    let mut out = String::new();
    let mut t = 0u64;
    let mut lines = 0;
    for &b in data {
        if editor.push(b) != LineEvent::Line {
            continue;
        }
        out.clear();
        let _ = engine.execute(editor.line(), &mut hal, &mut out);
        t += 500 + 97 * editor.line().len() as u64;
        engine.tick(t, &mut hal);
        lines += 1;
        if lines == 48 {
            break;
        }
    }
    let mut saved = String::new();
    engine.save(&mut saved).expect("save writes to a String");
    let mut again: Engine<f32> = Engine::new();
    let mut hal2 = board();
    for line in saved.lines() {
        out.clear();
        if let Err(e) = again.execute(line, &mut hal2, &mut out) {
            panic!("saved line {line:?} is refused: {e}\nsaved text:\n{saved}");
        }
    }
    let mut resaved = String::new();
    again.save(&mut resaved).expect("save writes to a String");
    // The same definitions, not necessarily in the same order: `save` lists a group in slot
    // order, and a reload can give slots in another order when a line refers to a variable
    // defined further down (regressions/terminal/forward-reference-reorders-save).
    let sorted = |s: &str| {
        let mut v: Vec<String> = s.lines().map(str::to_string).collect();
        v.sort();
        v
    };
    assert_eq!(
        sorted(&saved),
        sorted(&resaved),
        "save → execute → save differs"
    );
}

/// The dummy board's peripherals beside a short played-back signal for `infile`.
fn board() -> Board<DummyHal, PlaybackHal<[f64; 4]>> {
    Board::new(
        DummyHal::default(),
        PlaybackHal::new([0.0, 0.25, -1.5, 3.0]),
    )
}
