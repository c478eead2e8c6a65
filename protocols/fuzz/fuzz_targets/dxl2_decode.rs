//! One-packet decoders: check_frame, parse_in_place, Status, PingInfo, Request, FastReply.
#![no_main]
use conductor_protocols::dynamixel2 as d2;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: &[u8]| {
    let checked = d2::check_frame(input);
    let mut buf = input.to_vec();
    match d2::parse_in_place(&mut buf) {
        Ok(p) => {
            assert_eq!(checked, Ok(p.wire_len));
            if let Ok(s) = d2::Status::from_packet(&p) {
                let _ = d2::PingInfo::from_status(&s);
            }
            if let Ok(r) = d2::Request::from_packet(&p) {
                let n = r.sync_write_entries().count() + r.bulk_read_entries().count();
                let m = r.bulk_write_entries().map(|e| e.data.len()).sum::<usize>();
                assert!(n + m <= p.params.len());
            }
            if let Ok(r) = d2::FastReply::from_packet(&p) {
                let lens = input.iter().map(|&b| (b % 9) as usize);
                for _ in r.slices(lens) {}
            }
        }
        Err(e) => assert_eq!(checked, Err(e)),
    }
});
