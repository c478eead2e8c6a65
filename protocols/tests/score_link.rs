//! score_link: every message round-trips through a frame; a golden frame pins the byte layout;
//! the scanner finds frames in any chunking, drops damaged ones and accounts for every byte.

use conductor_protocols::score_link::*;
use proptest::prelude::*;

fn frame_request(seq: u16, r: &Request<'_>) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let n = encode_request(seq, r, &mut out).unwrap();
    out[..n].to_vec()
}

fn frame_reply(seq: u16, r: &Reply<'_>) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let n = encode_reply(seq, r, &mut out).unwrap();
    out[..n].to_vec()
}

fn messages(bytes: &[u8]) -> (Vec<Vec<u8>>, LinkStats) {
    let mut s = FrameScanner::<MAX_FRAME>::new();
    let mut got = Vec::new();
    s.feed(bytes, |m| got.push(m.to_vec()));
    (got, *s.stats())
}

fn requests() -> Vec<Request<'static>> {
    vec![
        Request::Hello,
        Request::ListVars,
        Request::Subscribe {
            id: 7,
            period_us: 10_000,
            generation: 3,
        },
        Request::UnsubscribeAll,
        Request::Set {
            id: 3,
            value: -12.5,
            generation: 3,
        },
        Request::Exec {
            line: "defscale Padca adca -1.5 1.5 0 100",
        },
        Request::Time,
    ]
}

#[test]
fn every_request_round_trips() {
    for (i, r) in requests().iter().enumerate() {
        let f = frame_request(i as u16 + 100, r);
        assert_eq!(*f.last().unwrap(), 0);
        assert!(!f[..f.len() - 1].contains(&0), "0 inside a frame");
        let (msgs, _) = messages(&f);
        assert_eq!(msgs.len(), 1);
        assert_eq!(decode_request(&msgs[0]).unwrap(), (i as u16 + 100, *r));
    }
}

#[test]
fn every_reply_round_trips() {
    let entries = [(0u8, 1.25), (9, -3.0e-7), (63, f64::MAX)];
    let replies = [
        Reply::Hello(Hello {
            protocol: VERSION,
            firmware: "score-firmware 0.1.0",
            board: "rp2040",
            number_type: "f32",
            generation: 42,
            t_us: 123_456_789_012,
            max_subscriptions: 64,
        }),
        Reply::Var(VarEntry {
            generation: 42,
            index: 1,
            total: 2,
            id: 5,
            kind: "AdcVolts",
            writable: false,
            rate_hz: Some(100.0),
            unit: "V",
            name: "adc0",
        }),
        Reply::Var(VarEntry {
            generation: 42,
            index: 0,
            total: 2,
            id: 6,
            kind: "Expression",
            writable: true,
            rate_hz: None,
            unit: "",
            name: "k",
        }),
        Reply::ListEnd {
            generation: 42,
            count: 2,
        },
        Reply::Ack,
        Reply::SetDone { value: 0.5 },
        Reply::Output {
            text: "adc0 - 0.964809\n",
        },
        Reply::ExecDone {
            ok: false,
            generation: 7,
        },
        Reply::Time { t_us: u64::MAX },
        Reply::Error {
            code: ErrorCode::NotWritable,
            text: "adc0 is read-only",
        },
        Reply::Samples(SampleBatch::new(1_000_000, 3, &entries)),
        Reply::TableChanged { generation: 43 },
    ];
    for r in &replies {
        let f = frame_reply(9, r);
        let (msgs, _) = messages(&f);
        let (seq, back) = decode_reply(&msgs[0]).unwrap();
        assert_eq!(seq, 9);
        match (r, back) {
            (Reply::Samples(a), Reply::Samples(b)) => {
                assert_eq!((a.t_us, a.lost), (b.t_us, b.lost));
                assert_eq!(a.iter().collect::<Vec<_>>(), b.iter().collect::<Vec<_>>());
            }
            (a, b) => assert_eq!(*a, b),
        }
    }
}

/// The layout written out by hand: version 1, kind 0x05 (Set), seq 0x0102, id 3, 1.0 as f64
/// LE, generation 0x01020304 LE; CRC-16/UMTS of those 17 bytes; COBS: each zero byte of the
/// f64 ends a run (the run code counts the bytes up to it, plus one).
#[test]
fn golden_set_frame() {
    let msg = [
        0x01, 0x05, 0x02, 0x01, 0x03, 0, 0, 0, 0, 0, 0, 0xF0, 0x3F, 0x04, 0x03, 0x02, 0x01,
    ];
    let crc = conductor_protocols::dynamixel2::crc::crc16(&msg).to_le_bytes();
    let f = frame_request(
        0x0102,
        &Request::Set {
            id: 3,
            value: 1.0,
            generation: 0x0102_0304,
        },
    );
    let mut expected = vec![
        0x06, 0x01, 0x05, 0x02, 0x01, 0x03, 0x01, 0x01, 0x01, 0x01, 0x01,
    ];
    expected.push(0x09);
    expected.extend_from_slice(&[0xF0, 0x3F, 0x04, 0x03, 0x02, 0x01, crc[0], crc[1]]);
    expected.push(0x00);
    assert!(
        !crc.contains(&0),
        "this vector assumes a CRC without zero bytes"
    );
    assert_eq!(f, expected);
}

#[test]
fn max_samples_fill_one_message() {
    let entries: Vec<(u8, f64)> = (0..MAX_SAMPLES as u8).map(|i| (i, i as f64)).collect();
    let f = frame_reply(0, &Reply::Samples(SampleBatch::new(5, 0, &entries)));
    assert!(f.len() <= MAX_FRAME);
    let mut too_many = entries.clone();
    too_many.push((200, 0.0));
    let mut out = [0u8; MAX_FRAME];
    assert_eq!(
        encode_reply(
            0,
            &Reply::Samples(SampleBatch::new(5, 0, &too_many)),
            &mut out
        ),
        Err(FrameError::Message(MessageError::TooLong))
    );
}

#[test]
fn long_text_is_refused_not_cut() {
    let line = "x".repeat(MAX_TEXT + 1);
    let mut out = [0u8; MAX_FRAME];
    assert_eq!(
        encode_request(1, &Request::Exec { line: &line }, &mut out),
        Err(FrameError::Message(MessageError::TooLong))
    );
    let mut small = [0u8; 4];
    assert_eq!(
        encode_request(1, &Request::Hello, &mut small),
        Err(FrameError::BufferTooSmall)
    );
}

/// Found by the `score_link_decode` fuzz target (fuzz/regressions/score_link_decode/): a Hello
/// whose firmware name was 110 bytes decoded, though no conforming board can send it (the
/// encoder refuses names over 64 bytes). Every string field is now checked against the same
/// limit on both sides.
#[test]
fn strings_over_their_field_limit_are_refused_when_decoded_too() {
    let text = "t".repeat(MAX_TEXT);
    let hello = Hello {
        protocol: VERSION,
        firmware: "f",
        board: "b",
        number_type: "f32",
        generation: 1,
        t_us: 2,
        max_subscriptions: 3,
    };
    // Encodable at the limit: decodes.
    let (msgs, _) = messages(&frame_reply(1, &Reply::Output { text: &text }));
    assert!(decode_reply(&msgs[0]).is_ok());
    // One byte over each limit, written by hand (the encoder would refuse): refused.
    let with_long = |field: usize, limit: usize| {
        let (msgs, _) = messages(&frame_reply(1, &Reply::Hello(hello)));
        let mut m = msgs[0].clone();
        // Header (4), protocol (1), then firmware, board, number_type as length + bytes.
        let mut at = 5;
        for _ in 0..field {
            at += 1 + m[at] as usize;
        }
        let old = m[at] as usize;
        m.splice(
            at..at + 1 + old,
            [vec![(limit + 1) as u8], vec![b'x'; limit + 1]].concat(),
        );
        m
    };
    for (field, limit) in [(0, 64), (1, 64), (2, 16)] {
        assert_eq!(
            decode_reply(&with_long(field, limit)),
            Err(MessageError::TooLong),
            "field {field}"
        );
        // At the limit it decodes.
        let mut m = with_long(field, limit);
        let at = m.iter().position(|&b| b == (limit + 1) as u8).unwrap();
        m[at] = limit as u8;
        m.remove(at + 1);
        assert!(decode_reply(&m).is_ok(), "field {field}");
    }
    let (mut msgs, _) = messages(&frame_request(1, &Request::Exec { line: &text }));
    msgs[0][4] = (MAX_TEXT + 1) as u8;
    msgs[0].push(b'x');
    assert_eq!(decode_request(&msgs[0]), Err(MessageError::TooLong));
}

#[test]
fn other_version_and_unknown_kind_are_typed_errors() {
    let (msgs, _) = messages(&frame_request(1, &Request::Time));
    let mut m = msgs[0].clone();
    m[0] = 2;
    assert_eq!(decode_request(&m), Err(MessageError::Version { found: 2 }));
    m[0] = VERSION;
    m[1] = 0x7e;
    assert_eq!(decode_request(&m), Err(MessageError::UnknownKind(0x7e)));
    // A request is not a reply.
    assert_eq!(decode_reply(&msgs[0]), Err(MessageError::UnknownKind(0x07)));
    // Truncated and trailing bytes.
    let (msgs, _) = messages(&frame_request(
        1,
        &Request::Set {
            id: 1,
            value: 2.0,
            generation: 0,
        },
    ));
    assert_eq!(
        decode_request(&msgs[0][..msgs[0].len() - 1]),
        Err(MessageError::Truncated)
    );
    let mut longer = msgs[0].clone();
    longer.push(9);
    assert_eq!(
        decode_request(&longer),
        Err(MessageError::TrailingBytes { extra: 1 })
    );
}

#[test]
fn damaged_frames_are_dropped_and_the_next_one_found() {
    let good = frame_request(5, &Request::Hello);
    let mut bad = frame_request(6, &Request::Time);
    bad[2] ^= 0x40; // payload byte: CRC mismatch
    let mut stream = b"\x13garbage".to_vec(); // a reader joining mid-frame
    stream.push(0);
    stream.extend_from_slice(&bad);
    stream.extend_from_slice(&good);
    let (msgs, stats) = messages(&stream);
    assert_eq!(msgs.len(), 1);
    assert_eq!(decode_request(&msgs[0]).unwrap(), (5, Request::Hello));
    assert_eq!(stats.frames, 1);
    // "\x13garbage" + 0 decodes as invalid COBS (run 0x13 past the end) or a bad CRC: either
    // way one rejected frame, plus the damaged one.
    assert_eq!(stats.bad_cobs + stats.bad_crc, 2);
    assert_eq!(
        stats.bytes_in,
        stats.frame_bytes + stats.discarded_bytes,
        "{stats:?}"
    );
}

#[test]
fn oversize_frames_are_counted() {
    let mut s = FrameScanner::<16>::new();
    let f = frame_request(
        1,
        &Request::Exec {
            line: "a line longer than sixteen bytes",
        },
    );
    let mut n = 0;
    s.feed(&f, |_| n += 1);
    assert_eq!(n, 0);
    assert_eq!(s.stats().oversize, 1);
    assert_eq!(s.stats().discarded_bytes, f.len() as u64);
    s.feed(&frame_request(2, &Request::Time), |_| n += 1);
    assert_eq!(n, 1);
}

proptest! {
    /// Any split of a stream of frames gives the same messages and counters, and every byte is
    /// accounted for (the scanner holds nothing after the last terminator).
    #[test]
    fn chunking_does_not_matter(
        seqs in proptest::collection::vec(any::<u16>(), 1..12),
        cuts in proptest::collection::vec(1usize..40, 1..30),
        values in proptest::collection::vec(any::<f64>(), 12),
    ) {
        let mut stream = Vec::new();
        for (i, s) in seqs.iter().enumerate() {
            stream.extend(frame_request(*s, &Request::Set { id: i as u8, value: values[i], generation: 1 }));
        }
        let (whole, whole_stats) = messages(&stream);
        let mut sc = FrameScanner::<MAX_FRAME>::new();
        let mut parts = Vec::new();
        let mut rest: &[u8] = &stream;
        let mut k = 0;
        while !rest.is_empty() {
            let n = cuts[k % cuts.len()].min(rest.len());
            sc.feed(&rest[..n], |m| parts.push(m.to_vec()));
            rest = &rest[n..];
            k += 1;
        }
        prop_assert_eq!(&parts, &whole);
        prop_assert_eq!(*sc.stats(), whole_stats);
        prop_assert_eq!(whole.len(), seqs.len());
        for (i, m) in whole.iter().enumerate() {
            let (seq, r) = decode_request(m).unwrap();
            prop_assert_eq!(seq, seqs[i]);
            match r {
                Request::Set { id, value, .. } => {
                    prop_assert_eq!(id, i as u8);
                    prop_assert_eq!(value.to_bits(), values[i].to_bits());
                }
                other => prop_assert!(false, "{:?}", other),
            }
        }
        prop_assert_eq!(sc.buffered(), 0);
        prop_assert_eq!(whole_stats.bytes_in, whole_stats.frame_bytes + whole_stats.discarded_bytes);
    }

    /// Random bytes never panic the scanner or the decoders, and the accounting holds.
    #[test]
    fn random_bytes_are_harmless(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let mut sc = FrameScanner::<MAX_FRAME>::new();
        sc.feed(&bytes, |m| {
            let _ = decode_request(m);
            let _ = decode_reply(m);
        });
        let s = *sc.stats();
        prop_assert_eq!(s.bytes_in, s.frame_bytes + s.discarded_bytes + sc.buffered() as u64);
    }
}
