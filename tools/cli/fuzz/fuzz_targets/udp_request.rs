//! libFuzzer entry for [`conductor_cli_fuzz::udp_request`].
#![no_main]
libfuzzer_sys::fuzz_target!(|input: &[u8]| conductor_cli_fuzz::udp_request(input));
