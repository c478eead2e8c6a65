//! The checks behind the fuzz target of the manifest reader, taking the raw input. The libFuzzer
//! binary in `fuzz_targets/` calls it, and `executors/tests/fuzz_corpus.rs` includes this file
//! to replay the committed seed and regression corpora as an ordinary test.

use conductor_manifest::Manifest;

/// A target's check: panics when the input shows a bug.
pub type Check = fn(&[u8]);

/// Every target: its name (the binary in `fuzz_targets/`, the folder under `seeds/` and
/// `regressions/`) and its check.
pub const TARGETS: &[(&str, Check)] = &[("manifest", manifest)];

/// TOML text through the whole reader (syntax, schema, kinds, links, limits, bus load): it
/// never panics; a refusal lists at least one error with its position; an accepted manifest's
/// cross-references all resolve and its rates and periods are usable.
pub fn manifest(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match Manifest::parse(text, "fuzz.toml") {
        Err(e) => {
            let msg = e.to_string();
            assert!(
                msg.contains("fuzz.toml:"),
                "error without a position: {msg}"
            );
            assert!(msg.contains("error"), "refusal without an error: {msg}");
        }
        Ok(m) => {
            let _ = m.render_warnings();
            for s in &m.subsystems {
                assert!(s.rate_hz.is_finite() && s.rate_hz > 0.0, "{}", s.rate_hz);
                assert!(s.period_ns > 0);
                for p in &s.protocols {
                    assert!(p.hardware < s.hardware.len());
                    assert!(p.divisor > 0);
                }
                for d in &s.devices {
                    assert!(d.protocol < s.protocols.len());
                    assert!(d.divisor > 0);
                    let c = &d.calibration;
                    assert!(c.scale.is_finite() && c.scale != 0.0);
                    assert!(c.offset.is_finite());
                    assert!(c.direction == 1.0 || c.direction == -1.0);
                }
                for (i, st) in s.states.iter().enumerate() {
                    assert!(st.device < s.devices.len());
                    assert!(st.channel < s.devices[st.device].channels.len());
                    assert!(st.divisor > 0);
                    assert!(s.rate_of(st.divisor) > 0.0);
                    let _ = s.state_is_simulated(i);
                }
                for p in 0..s.protocols.len() {
                    if let Some(load) = s.bus_load(p) {
                        assert!(load.fraction() >= 0.0, "{}", load.fraction());
                    }
                }
            }
        }
    }
}
