//! The fuzz targets' checks (score/core/fuzz/src/lib.rs) on their committed corpora: the minimised
//! corpus a campaign left in `fuzz/seeds/<target>/` and every input that once failed, kept in
//! `fuzz/regressions/<target>/`. This keeps the checks compiling and the bugs they found fixed
//! without cargo-fuzz or nightly; `cargo xtask fuzz` runs the real campaigns.

#[allow(dead_code)]
#[path = "../fuzz/src/lib.rs"]
mod fuzz;

use std::path::{Path, PathBuf};

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| rd.map(|e| e.unwrap().path()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

#[test]
fn every_fuzz_target_passes_its_seed_and_regression_corpora() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    // The table of checks names exactly the libFuzzer binaries.
    let mut bins: Vec<String> = files(&root.join("fuzz_targets"))
        .iter()
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    bins.sort();
    let mut names: Vec<String> = fuzz::TARGETS.iter().map(|(n, _)| n.to_string()).collect();
    names.sort();
    assert_eq!(bins, names, "fuzz_targets/ and TARGETS disagree");
    for (name, check) in fuzz::TARGETS {
        let seeds = files(&root.join("seeds").join(name));
        assert!(!seeds.is_empty(), "{name} has no seed corpus");
        for path in seeds
            .iter()
            .chain(&files(&root.join("regressions").join(name)))
        {
            let data = std::fs::read(path).unwrap();
            let r = std::panic::catch_unwind(|| check(&data));
            assert!(r.is_ok(), "{name} fails on {}", path.display());
        }
    }
}
