//! libFuzzer entry for [`score_core_fuzz::terminal`].
#![no_main]
libfuzzer_sys::fuzz_target!(|input: &[u8]| score_core_fuzz::terminal(input));
