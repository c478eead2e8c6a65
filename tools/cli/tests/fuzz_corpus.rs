//! The fuzz targets' checks (tools/cli/fuzz/src/lib.rs) on their committed seed and regression
//! corpora, without cargo-fuzz or nightly (conductor-testkit's `fuzz`), and the synthetic
//! recordings the `recording` target starts from.

conductor_testkit::fuzz_corpus_test!();

mod support;

use std::path::Path;

/// Small recordings in the documented layout (two states; unchunked, chunked and zstd-chunked),
/// the starting points of the `recording` target. `UPDATE_FUZZ_SEEDS=1` writes them into
/// `fuzz/seeds/recording/`; either way each must load with all its samples and pass the check.
#[test]
fn synthetic_recordings_load_and_pass_the_recording_check() {
    use conductor_cli::recording::{self as r, Recording};
    let make = |chunked: bool, zstd: bool| -> Vec<u8> {
        let mut buf = std::io::Cursor::new(Vec::new());
        let mut w = mcap::WriteOptions::new()
            .use_chunks(chunked)
            .compression(zstd.then_some(mcap::Compression::Zstd))
            .profile(r::PROFILE)
            .create(&mut buf)
            .unwrap();
        let schema = w
            .add_schema(r::SCHEMA_NAME, r::SCHEMA_ENCODING, r::SCHEMA.as_bytes())
            .unwrap();
        for (n, state) in ["knee", "hip"].into_iter().enumerate() {
            let ch = support::add_state_channel(&mut w, schema, "leg", state, n as u32);
            for i in 0..3u64 {
                let t = 1_000_000_000 + i * 10_000_000 + n as u64;
                let value = if i == 2 { "null" } else { "0.5" };
                let body = format!(
                    r#"{{"value":{value},"status":{i},"t_sample":{},"seq":{i},"tick":{i}}}"#,
                    t as f64 * 1e-9
                );
                support::write_sample(&mut w, ch, i, t, body.as_bytes());
            }
        }
        w.finish().unwrap();
        drop(w);
        buf.into_inner()
    };
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/seeds/recording");
    for (name, chunked, zstd) in [
        ("plain.mcap", false, false),
        ("chunked.mcap", true, false),
        ("zstd.mcap", true, true),
    ] {
        let bytes = make(chunked, zstd);
        let rec = Recording::from_bytes(Path::new(name), &bytes).unwrap();
        assert_eq!((rec.channels.len(), rec.samples.len()), (2, 6), "{name}");
        assert!(!rec.truncated, "{name}");
        fuzz::recording(&bytes);
        if std::env::var_os("UPDATE_FUZZ_SEEDS").is_some() {
            std::fs::create_dir_all(&dir).unwrap();
            std::fs::write(dir.join(name), &bytes).unwrap();
        }
    }
}
