//! libFuzzer entry for [`conductor_executor_fuzz::manifest`].
#![no_main]
libfuzzer_sys::fuzz_target!(|input: &[u8]| conductor_executor_fuzz::manifest(input));
