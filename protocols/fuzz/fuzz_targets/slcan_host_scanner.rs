//! SLCAN host scanner (adapter → host bytes) on arbitrary chunked input.
#![no_main]
use conductor_protocols::slcan::{HostScanner, PendingAcks, CommandKind};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: &[u8]| {
    let Some((&seed, data)) = input.split_first() else { return };
    let mut s = HostScanner::<48>::new();
    let mut acks = PendingAcks::<8>::new();
    for chunk in data.chunks(1 + (seed as usize % 29)) {
        let _ = acks.push(CommandKind::Transmit, 0);
        s.feed(chunk, |r| {
            let _ = acks.resolve(&r);
        });
        let st = s.stats();
        assert_eq!(st.bytes_in, st.line_bytes + st.discarded_bytes() + s.buffered() as u64);
    }
    s.expire();
    while s.next_response().is_some() {}
    assert_eq!(s.buffered(), 0);
});
