//! libFuzzer entry for [`conductor_cli_fuzz::recording`].
//!
//! `Recording::from_bytes` catches a panic of the `mcap` reader and refuses the file, but
//! libfuzzer-sys's panic hook aborts before anything can catch; it is replaced so that such a
//! panic is handled as in `conductor replay`, by a hook that prints the message alone (the
//! default one symbolises a backtrace when `RUST_BACKTRACE` is set, at every caught panic). A
//! panic nothing catches still aborts at the `extern "C"` boundary and is reported as a crash.
#![no_main]
libfuzzer_sys::fuzz_target!(
    init: {
        std::panic::set_hook(Box::new(|info| eprintln!("{info}")));
    },
    |input: &[u8]| conductor_cli_fuzz::recording(input)
);
