//! The fuzz targets' checks (executors/fuzz/src/lib.rs) on their committed seed and regression
//! corpora, without cargo-fuzz or nightly (conductor-testkit's `fuzz`).

conductor_testkit::fuzz_corpus_test!();
