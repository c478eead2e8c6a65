//! The fuzz targets' checks on their committed corpora, as an ordinary test: every crate with a
//! `fuzz/` folder (cargo-fuzz layout) keeps the minimised corpus of a campaign in
//! `fuzz/seeds/<target>/` and every input that once failed in `fuzz/regressions/<target>/`.
//! Replaying them keeps the checks compiling and the bugs they found fixed, without cargo-fuzz or
//! nightly; `cargo xtask fuzz` runs the real campaigns.

use std::path::{Path, PathBuf};

/// A target's check: panics on an input that shows a bug.
pub type Check = fn(&[u8]);

/// The files of `dir`, sorted; none when it does not exist.
pub fn files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| rd.map(|e| e.unwrap().path()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

/// Runs every target of `targets` over its seeds and regressions under `fuzz_dir`, after checking
/// that the table names exactly the libFuzzer binaries of `fuzz_dir/fuzz_targets/` (so a target
/// cannot silently drop out of the table). Panics naming the target and the input that failed.
pub fn replay_corpora(fuzz_dir: &Path, targets: &[(&str, Check)]) {
    let mut bins: Vec<String> = files(&fuzz_dir.join("fuzz_targets"))
        .iter()
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    bins.sort();
    let mut names: Vec<String> = targets.iter().map(|(n, _)| n.to_string()).collect();
    names.sort();
    assert_eq!(bins, names, "fuzz_targets/ and TARGETS disagree");
    for (name, check) in targets {
        let seeds = files(&fuzz_dir.join("seeds").join(name));
        assert!(!seeds.is_empty(), "{name} has no seed corpus");
        for path in seeds
            .iter()
            .chain(&files(&fuzz_dir.join("regressions").join(name)))
        {
            let data = std::fs::read(path).unwrap();
            let r = std::panic::catch_unwind(|| check(&data));
            assert!(r.is_ok(), "{name} fails on {}", path.display());
        }
    }
}

/// The test every crate with a `fuzz/` folder runs: includes `../fuzz/src/lib.rs` (the targets'
/// checks and their `TARGETS` table) as module `fuzz` and replays its corpora with
/// [`replay_corpora`]. Invoke it at the top level of a file in the crate's `tests/`.
#[macro_export]
macro_rules! fuzz_corpus_test {
    () => {
        #[allow(dead_code)]
        #[path = "../fuzz/src/lib.rs"]
        mod fuzz;

        #[test]
        fn every_fuzz_target_passes_its_seed_and_regression_corpora() {
            let dir = ::std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
            $crate::fuzz::replay_corpora(&dir, fuzz::TARGETS);
        }
    };
}
