//! libFuzzer entry for [`score_core_fuzz::parse_line`].
#![no_main]
libfuzzer_sys::fuzz_target!(|input: &[u8]| score_core_fuzz::parse_line(input));
