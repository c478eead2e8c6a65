//! Arbitrary bytes in chunks whose sizes come from the input: no panic, the accounting
//! invariant holds, every yielded packet re-checks, and nothing stays buffered after expire.
#![no_main]
use conductor_protocols::dynamixel2::{self as d2, Scanner};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: &[u8]| {
    let Some((&seed, data)) = input.split_first() else { return };
    let mut s = Scanner::<256>::with_max_packet(16 + seed as usize);
    let step = 1 + (seed as usize % 37);
    for chunk in data.chunks(step) {
        s.feed(chunk, |p| {
            assert!(p.wire_len >= d2::OVERHEAD);
            let _ = d2::Status::from_packet(&p);
        });
        let st = s.stats();
        assert_eq!(st.bytes_in, st.packet_bytes + st.discarded_bytes() + s.buffered() as u64);
    }
    s.expire_with(|_| {});
    assert_eq!(s.buffered(), 0);
});
