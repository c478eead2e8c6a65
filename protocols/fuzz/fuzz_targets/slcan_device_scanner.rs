//! SLCAN adapter-side scanner (host commands) on arbitrary chunked input; every decoded
//! command re-encodes.
#![no_main]
use conductor_protocols::slcan::{DeviceScanner, Dialect};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: &[u8]| {
    let Some((&seed, data)) = input.split_first() else { return };
    let dialect = if seed & 1 == 0 { Dialect::LAWICEL } else { Dialect::CANABLE };
    let mut s = DeviceScanner::<40>::new(dialect);
    for chunk in data.chunks(1 + (seed as usize % 23)) {
        s.feed(chunk, |c| {
            if let Ok(cmd) = c {
                let mut buf = [0u8; 40];
                cmd.encode(&dialect, &mut buf).expect("a decoded command re-encodes");
            }
        });
        let st = s.stats();
        assert_eq!(st.bytes_in, st.line_bytes + st.discarded_bytes() + s.buffered() as u64);
    }
});
