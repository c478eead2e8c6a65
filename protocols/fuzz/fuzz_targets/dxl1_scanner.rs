//! Protocol 1.0 scanner on arbitrary chunked bytes.
#![no_main]
use conductor_protocols::dynamixel1::Scanner;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: &[u8]| {
    let Some((&seed, data)) = input.split_first() else { return };
    let mut s = Scanner::<300>::with_max_packet(6 + seed as usize);
    for chunk in data.chunks(1 + (seed as usize % 41)) {
        s.feed(chunk, |p| assert!(p.params.len() <= 253));
        let st = s.stats();
        assert_eq!(st.bytes_in, st.packet_bytes + st.discarded_bytes() + s.buffered() as u64);
    }
    s.expire_with(|_| {});
    assert_eq!(s.buffered(), 0);
});
