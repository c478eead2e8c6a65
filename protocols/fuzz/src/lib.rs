//! The checks behind each fuzz target of `conductor-protocols`, one function per target taking
//! the raw input. The libFuzzer binaries in `fuzz_targets/` call them, and
//! `protocols/tests/fuzz_corpus.rs` includes this file to replay the committed seed and
//! regression corpora as an ordinary test, so the checks build (and run) in every `cargo test`.
//!
//! Each check asserts more than "no panic": the scanners' byte accounting, and that whatever
//! decodes re-encodes and decodes to the same thing.

use conductor_protocols::dynamixel1 as d1;
use conductor_protocols::dynamixel2 as d2;
use conductor_protocols::mit_can::{self, Model, Reply as MitReply};
use conductor_protocols::odrive_can::{CmdId, Message};
use conductor_protocols::score_link as link;
use conductor_protocols::slcan::{
    Command, CommandKind, DeviceScanner, Dialect, HostScanner, Line, PendingAcks, Response, BEL, CR,
};

/// A target's check: panics when the input shows a bug.
pub type Check = fn(&[u8]);

/// Every target: its name (the binary in `fuzz_targets/`, the folder under `seeds/` and
/// `regressions/`) and its check.
pub const TARGETS: &[(&str, Check)] = &[
    ("dxl2_scanner", dxl2_scanner),
    ("dxl2_decode", dxl2_decode),
    ("dxl1_scanner", dxl1_scanner),
    ("dxl1_decode", dxl1_decode),
    ("slcan_host_scanner", slcan_host_scanner),
    ("slcan_device_scanner", slcan_device_scanner),
    ("can_decode", can_decode),
    ("score_link_scanner", score_link_scanner),
    ("score_link_decode", score_link_decode),
];

/// Dynamixel 2.0 scanner on arbitrary bytes in chunks whose size comes from the first byte: the
/// accounting invariant holds after every chunk, every yielded packet re-checks, and nothing
/// stays buffered after expiry.
pub fn dxl2_scanner(input: &[u8]) {
    let Some((&seed, data)) = input.split_first() else {
        return;
    };
    let mut s = d2::Scanner::<256>::with_max_packet(16 + seed as usize);
    let step = 1 + (seed as usize % 37);
    for chunk in data.chunks(step) {
        s.feed(chunk, |p| {
            assert!(p.wire_len >= d2::OVERHEAD);
            let _ = d2::Status::from_packet(&p);
        });
        let st = s.stats();
        assert_eq!(
            st.bytes_in,
            st.packet_bytes + st.discarded_bytes() + s.buffered() as u64
        );
    }
    s.expire_with(|_| {});
    assert_eq!(s.buffered(), 0);
}

/// Dynamixel 2.0 one-packet decoders (check_frame, parse_in_place, Status, PingInfo, Request,
/// FastReply) agree with each other and stay inside the packet.
pub fn dxl2_decode(input: &[u8]) {
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
}

/// Dynamixel 1.0 scanner on chunked bytes: accounting, parameter bound, empty after expiry.
pub fn dxl1_scanner(input: &[u8]) {
    let Some((&seed, data)) = input.split_first() else {
        return;
    };
    let mut s = d1::Scanner::<300>::with_max_packet(6 + seed as usize);
    for chunk in data.chunks(1 + (seed as usize % 41)) {
        s.feed(chunk, |p| assert!(p.params.len() <= 253));
        let st = s.stats();
        assert_eq!(
            st.bytes_in,
            st.packet_bytes + st.discarded_bytes() + s.buffered() as u64
        );
    }
    s.expire_with(|_| {});
    assert_eq!(s.buffered(), 0);
}

/// Dynamixel 1.0 single-packet parser: the length it reports lies inside the input.
pub fn dxl1_decode(input: &[u8]) {
    if let Ok((p, n)) = d1::parse(input) {
        assert!(n <= input.len());
        let s = d1::Status::from_packet(&p);
        let _ = s.data_u16();
    }
}

/// SLCAN host-side scanner (adapter → host bytes), resolving acknowledgements as it goes.
pub fn slcan_host_scanner(input: &[u8]) {
    let Some((&seed, data)) = input.split_first() else {
        return;
    };
    let mut s = HostScanner::<48>::new();
    let mut acks = PendingAcks::<8>::new();
    for chunk in data.chunks(1 + (seed as usize % 29)) {
        let _ = acks.push(CommandKind::Transmit, 0);
        s.feed(chunk, |r| {
            let _ = acks.resolve(&r);
        });
        let st = s.stats();
        assert_eq!(
            st.bytes_in,
            st.line_bytes + st.discarded_bytes() + s.buffered() as u64
        );
    }
    s.expire();
    while s.next_response().is_some() {}
    assert_eq!(s.buffered(), 0);
}

/// SLCAN adapter-side scanner (host commands): accounting, and every decoded command re-encodes.
pub fn slcan_device_scanner(input: &[u8]) {
    let Some((&seed, data)) = input.split_first() else {
        return;
    };
    let dialect = if seed & 1 == 0 {
        Dialect::LAWICEL
    } else {
        Dialect::CANABLE
    };
    let mut s = DeviceScanner::<40>::new(dialect);
    for chunk in data.chunks(1 + (seed as usize % 23)) {
        s.feed(chunk, |c| {
            if let Ok(cmd) = c {
                let mut buf = [0u8; 40];
                cmd.encode(&dialect, &mut buf)
                    .expect("a decoded command re-encodes");
            }
        });
        let st = s.stats();
        assert_eq!(
            st.bytes_in,
            st.line_bytes + st.discarded_bytes() + s.buffered() as u64
        );
    }
}

/// CAN payload decoders: MIT-mode replies (finite values) and commands, ODrive messages (which
/// re-encode), SLCAN response lines (with and without timestamps) and command lines.
pub fn can_decode(input: &[u8]) {
    let l = Model::Ak80_9.limits();
    if let Ok(r) = MitReply::decode(input, &l) {
        assert!(r.p.is_finite() && r.v.is_finite() && r.t.is_finite());
    }
    let _ = mit_can::decode_command(input, &l);
    if let Some((&code, rest)) = input.split_first() {
        if let Some(cmd) = CmdId::from_code(code & 0x1F) {
            if let Ok(m) = Message::decode(cmd, rest) {
                let _ = m.encode();
            }
        }
    }
    for term in [CR, BEL] {
        for timestamps in [false, true] {
            let line = Line {
                body: input,
                terminator: term,
            };
            if let Ok(r) = Response::decode(line, timestamps) {
                let mut buf = [0u8; 128];
                let _ = r.encode(&mut buf);
            }
        }
    }
    let _ = Command::decode(input, &Dialect::default());
}

/// `score_link` frames on arbitrary bytes in chunks: the scanner's accounting holds, and every
/// message it yields is a valid frame's payload, so decoding it as a request or a reply, then
/// encoding and scanning that again, gives the same message.
pub fn score_link_scanner(input: &[u8]) {
    let Some((&seed, data)) = input.split_first() else {
        return;
    };
    let mut s = link::FrameScanner::<{ link::MAX_FRAME }>::new();
    let step = 1 + (seed as usize % 53);
    for chunk in data.chunks(step) {
        s.feed(chunk, |msg| {
            assert!(msg.len() <= link::MAX_FRAME);
            score_link_decode(msg);
        });
        let st = s.stats();
        assert_eq!(
            st.bytes_in,
            st.frame_bytes + st.discarded_bytes + s.buffered() as u64
        );
        assert!(st.frames + st.oversize + st.bad_cobs + st.bad_crc <= st.bytes_in);
    }
    s.reset();
    assert_eq!(s.buffered(), 0);
    let st = s.stats();
    assert_eq!(st.bytes_in, st.frame_bytes + st.discarded_bytes);
}

/// `score_link` message decoders on one checked message: whatever decodes (as a request from
/// the host or a reply from the board) encodes again, and that frame scans and decodes to the
/// same message.
pub fn score_link_decode(msg: &[u8]) {
    if let Ok((seq, req)) = link::decode_request(msg) {
        let mut frame = [0u8; link::MAX_FRAME];
        let n = link::encode_request(seq, &req, &mut frame).expect("a decoded request re-encodes");
        let again = rescan(&frame[..n]);
        let (seq2, req2) = link::decode_request(&again).expect("a re-encoded request decodes");
        assert_eq!(seq, seq2);
        assert_eq!(format!("{req:?}"), format!("{req2:?}"));
    }
    if let Ok((seq, reply)) = link::decode_reply(msg) {
        let mut frame = [0u8; link::MAX_FRAME];
        let n = link::encode_reply(seq, &reply, &mut frame).expect("a decoded reply re-encodes");
        let again = rescan(&frame[..n]);
        let (seq2, reply2) = link::decode_reply(&again).expect("a re-encoded reply decodes");
        assert_eq!(seq, seq2);
        assert_eq!(format!("{reply:?}"), format!("{reply2:?}"));
    }
}

/// The single message in one whole frame.
fn rescan(frame: &[u8]) -> Vec<u8> {
    let mut s = link::FrameScanner::<{ link::MAX_FRAME }>::new();
    let mut out = Vec::new();
    let mut count = 0;
    s.feed(frame, |m| {
        out = m.to_vec();
        count += 1;
    });
    assert_eq!(count, 1, "an encoded frame scans as exactly one message");
    out
}
