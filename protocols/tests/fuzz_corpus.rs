//! The fuzz targets' checks (protocols/fuzz/src/lib.rs) on their committed seed and regression
//! corpora, without cargo-fuzz or nightly (conductor-testkit's `fuzz`).

#[allow(dead_code)]
#[path = "../fuzz/src/lib.rs"]
mod fuzz;

#[test]
fn every_fuzz_target_passes_its_seed_and_regression_corpora() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    conductor_testkit::fuzz::replay_corpora(&dir, fuzz::TARGETS);
}
