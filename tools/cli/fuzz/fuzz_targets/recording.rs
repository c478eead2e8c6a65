//! libFuzzer entry for [`conductor_cli_fuzz::recording`].
//!
//! `Recording::from_bytes` catches a panic of the `mcap` reader and refuses the file, but
//! libfuzzer-sys's panic hook aborts before anything can catch; the default hook is restored
//! so that such a panic is handled as in `conductor replay`. A panic nothing catches still
//! aborts at the `extern "C"` boundary and is reported as a crash.
#![no_main]
libfuzzer_sys::fuzz_target!(
    init: {
        let _ = std::panic::take_hook();
    },
    |input: &[u8]| conductor_cli_fuzz::recording(input)
);
