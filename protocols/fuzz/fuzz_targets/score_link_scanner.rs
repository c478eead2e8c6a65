//! libFuzzer entry for [`conductor_protocols_fuzz::score_link_scanner`].
#![no_main]
libfuzzer_sys::fuzz_target!(|input: &[u8]| conductor_protocols_fuzz::score_link_scanner(input));
