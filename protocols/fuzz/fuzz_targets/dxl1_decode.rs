//! Protocol 1.0 single-packet parser.
#![no_main]
use conductor_protocols::dynamixel1 as d1;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: &[u8]| {
    if let Ok((p, n)) = d1::parse(input) {
        assert!(n <= input.len());
        let s = d1::Status::from_packet(&p);
        let _ = s.data_u16();
    }
});
