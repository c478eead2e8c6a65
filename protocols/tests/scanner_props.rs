//! Stream-scanner properties: arbitrary chunking, exact accounting of injected garbage, faults
//! (corrupted and dropped bytes) never producing a packet that was not sent, and no panics.

use conductor_protocols::dynamixel1 as d1;
use conductor_protocols::dynamixel2 as d2;
use conductor_protocols::scan::ScanStats;
use conductor_protocols::slcan::{self, HostScanner, LineStats, Response};
use proptest::prelude::*;
use proptest::test_runner::{Config, RngSeed};

/// Fault-injection tests compare against the sent packets; a damaged candidate passes a
/// CRC-16 by chance with probability 2^-16, so they run from a fixed seed to be reproducible.
fn fixed_seed() -> Config {
    Config {
        rng_seed: RngSeed::Fixed(0x5eed_c0de),
        ..Config::default()
    }
}

/// A status packet's fields.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Pkt {
    id: u8,
    err: u8,
    data: Vec<u8>,
}

fn pkt() -> impl Strategy<Value = Pkt> {
    let byte = prop_oneof![3 => Just(0xFFu8), 1 => Just(0xFD), 1 => Just(0x00), 4 => any::<u8>()];
    (
        0u8..=0xFC,
        prop_oneof![Just(0u8), any::<u8>()],
        prop::collection::vec(byte, 0..24),
    )
        .prop_map(|(id, err, data)| Pkt { id, err, data })
}

fn dxl2_wire(p: &Pkt) -> Vec<u8> {
    let mut buf = [0u8; 128];
    let n = d2::status(&mut buf, p.id, p.err, &p.data).unwrap();
    buf[..n].to_vec()
}

/// Garbage that cannot contain a header (no 0xFF).
fn garbage() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(0u8..0xFF, 0..12)
}

/// Splits `bytes` at the given cut points.
fn chunks<'a>(bytes: &'a [u8], cuts: &[usize]) -> Vec<&'a [u8]> {
    let mut pts: Vec<usize> = cuts.iter().map(|c| c % (bytes.len() + 1)).collect();
    pts.sort_unstable();
    let mut out = Vec::new();
    let mut last = 0;
    for p in pts.into_iter().chain([bytes.len()]) {
        out.push(&bytes[last..p]);
        last = p;
    }
    out
}

fn scan_dxl2(stream: &[u8], cuts: &[usize]) -> (Vec<Vec<u8>>, ScanStats, usize) {
    let mut s = d2::Scanner::<256>::new();
    let mut got = Vec::new();
    for c in chunks(stream, cuts) {
        s.feed(c, |p| {
            let st = d2::Status::from_packet(&p).unwrap();
            let mut v = vec![st.id, st.error.0];
            v.extend_from_slice(st.data);
            got.push(v);
        });
    }
    s.expire_with(|p| {
        let st = d2::Status::from_packet(&p).unwrap();
        let mut v = vec![st.id, st.error.0];
        v.extend_from_slice(st.data);
        got.push(v);
    });
    (got, *s.stats(), s.buffered())
}

fn flat(p: &Pkt) -> Vec<u8> {
    let mut v = vec![p.id, p.err];
    v.extend_from_slice(&p.data);
    v
}

type Fault = (prop::sample::Index, bool, u8);

/// Applies faults (drop, or XOR with a non-zero mask) to the concatenated packets; returns the
/// damaged stream and which packets were hit.
fn inject(pkts: &[Pkt], faults: &[Fault]) -> (Vec<u8>, Vec<bool>) {
    let mut stream = Vec::new();
    let mut owner = Vec::new();
    for (i, p) in pkts.iter().enumerate() {
        let w = dxl2_wire(p);
        owner.extend(std::iter::repeat_n(i, w.len()));
        stream.extend(w);
    }
    let mut damaged = vec![false; pkts.len()];
    for (at, drop, xor) in faults {
        if stream.is_empty() {
            break;
        }
        let k = at.index(stream.len());
        damaged[owner[k]] = true;
        if *drop {
            stream.remove(k);
            owner.remove(k);
        } else {
            stream[k] ^= xor;
        }
    }
    (stream, damaged)
}

fn check_invariant(s: &ScanStats, buffered: usize) -> Result<(), TestCaseError> {
    prop_assert_eq!(
        s.bytes_in,
        s.packet_bytes + s.discarded_bytes() + buffered as u64
    );
    Ok(())
}

proptest! {
    /// Garbage between packets, any chunking: every packet out in order, exactly the garbage
    /// bytes counted as garbage, one garbage event per non-empty run, nothing else discarded.
    #[test]
    fn dxl2_garbage_is_counted_exactly(items in prop::collection::vec((garbage(), pkt()), 1..12), tail in garbage(), cuts in prop::collection::vec(any::<usize>(), 0..20)) {
        let mut stream = Vec::new();
        let mut runs = 0;
        let mut garbage_bytes = 0;
        for (g, p) in &items {
            runs += usize::from(!g.is_empty());
            garbage_bytes += g.len();
            stream.extend_from_slice(g);
            stream.extend(dxl2_wire(p));
        }
        runs += usize::from(!tail.is_empty());
        garbage_bytes += tail.len();
        stream.extend_from_slice(&tail);
        let (got, stats, buffered) = scan_dxl2(&stream, &cuts);
        prop_assert_eq!(got, items.iter().map(|(_, p)| flat(p)).collect::<Vec<_>>());
        prop_assert_eq!(stats.garbage.bytes, garbage_bytes as u64);
        prop_assert_eq!(stats.garbage.events, runs as u64);
        prop_assert_eq!(stats.rejected_packets(), 0);
        prop_assert_eq!(stats.packets, items.len() as u64);
        prop_assert_eq!(buffered, 0);
        check_invariant(&stats, buffered)?;
    }

    /// Bytes corrupted or dropped anywhere, any chunking: no panic, the accounting invariant
    /// holds, everything is resolved after `expire`, and chunking changes nothing. (What is
    /// yielded is checked against what was sent in `dxl2_faults_fixed_seed`.)
    #[test]
    fn dxl2_faults_any_chunking(
        pkts in prop::collection::vec(pkt(), 1..12),
        faults in prop::collection::vec((any::<prop::sample::Index>(), any::<bool>(), 1u8..=255), 0..4),
        cuts in prop::collection::vec(any::<usize>(), 0..20),
    ) {
        let (stream, _) = inject(&pkts, &faults);
        let (got, stats, buffered) = scan_dxl2(&stream, &cuts);
        let (whole, whole_stats, _) = scan_dxl2(&stream, &[]);
        prop_assert_eq!(&got, &whole);
        prop_assert_eq!(stats, whole_stats);
        prop_assert_eq!(buffered, 0);
        check_invariant(&stats, buffered)?;
        prop_assert_eq!(stats.packets, got.len() as u64);
    }

    /// Arbitrary bytes in arbitrary chunks: no panic, invariant, chunking-independent, and
    /// every yielded packet re-checks with an independent parse.
    #[test]
    fn dxl2_arbitrary_input(bytes in prop::collection::vec(prop_oneof![Just(0xFFu8), Just(0xFD), Just(0x00), any::<u8>()], 0..300), cuts in prop::collection::vec(any::<usize>(), 0..20), max in 10usize..300) {
        let run = |cuts: &[usize]| {
            let mut s = d2::Scanner::<128>::with_max_packet(max);
            let mut n = 0u64;
            for c in chunks(&bytes, cuts) {
                s.feed(c, |p| { n += 1; assert!(p.wire_len <= max.min(125)); });
            }
            s.expire_with(|_| n += 1);
            (n, *s.stats(), s.buffered())
        };
        let (n, stats, buffered) = run(&cuts);
        prop_assert_eq!((n, stats, buffered), run(&[]));
        prop_assert_eq!(stats.packets, n);
        check_invariant(&stats, buffered)?;
    }

    #[test]
    fn dxl1_chunking_and_garbage(items in prop::collection::vec((prop::collection::vec(0u8..0xFF, 0..8), 0u8..=0xFD, prop::collection::vec(any::<u8>(), 0..20)), 1..10), cuts in prop::collection::vec(any::<usize>(), 0..20)) {
        let mut stream = Vec::new();
        let mut garbage_bytes = 0;
        let mut expected = Vec::new();
        for (g, id, data) in &items {
            stream.extend_from_slice(g);
            garbage_bytes += g.len();
            let mut buf = [0u8; 64];
            let n = d1::status(&mut buf, *id, d1::ErrorBits(0), data).unwrap();
            stream.extend_from_slice(&buf[..n]);
            expected.push((*id, data.clone()));
        }
        let run = |cuts: &[usize]| {
            let mut s = d1::Scanner::<300>::new();
            let mut got = Vec::new();
            for c in chunks(&stream, cuts) {
                s.feed(c, |p| got.push((p.id, p.params.to_vec())));
            }
            s.expire_with(|p| got.push((p.id, p.params.to_vec())));
            (got, *s.stats())
        };
        let (got, stats) = run(&cuts);
        // A data byte of 0xFF directly followed by 0xFF inside a packet cannot fool the scanner
        // here: candidates are only tried where the previous packet ended.
        prop_assert_eq!(&got, &expected);
        prop_assert_eq!(stats.garbage.bytes, garbage_bytes as u64);
        prop_assert_eq!((got, stats), run(&[]));
    }

    #[test]
    fn dxl1_arbitrary_input(bytes in prop::collection::vec(prop_oneof![Just(0xFFu8), any::<u8>()], 0..300), cuts in prop::collection::vec(any::<usize>(), 0..20)) {
        let run = |cuts: &[usize]| {
            let mut s = d1::Scanner::<64>::new();
            let mut n = 0u64;
            for c in chunks(&bytes, cuts) {
                s.feed(c, |_| n += 1);
            }
            s.expire_with(|_| n += 1);
            (n, *s.stats(), s.buffered())
        };
        let (n, stats, buffered) = run(&cuts);
        prop_assert_eq!((n, stats, buffered), run(&[]));
        prop_assert_eq!(stats.bytes_in, stats.packet_bytes + stats.discarded_bytes() + buffered as u64);
    }
}

fn slcan_lines() -> impl Strategy<Value = Vec<u8>> {
    let frame = (0u16..=0x7FF, prop::collection::vec(any::<u8>(), 0..=8)).prop_map(|(id, d)| {
        let f = conductor_protocols::can::CanFrame::standard(id, &d).unwrap();
        let mut buf = [0u8; 40];
        let n = Response::Frame {
            frame: f,
            timestamp: None,
        }
        .encode(&mut buf)
        .unwrap();
        buf[..n].to_vec()
    });
    prop_oneof![
        frame,
        Just(b"\r".to_vec()),
        Just(b"z\r".to_vec()),
        Just(b"\x07".to_vec()),
        Just(b"F00\r".to_vec())
    ]
}

fn scan_slcan(stream: &[u8], cuts: &[usize]) -> (Vec<String>, LineStats, usize) {
    let mut s = HostScanner::<32>::new();
    let mut got = Vec::new();
    for c in chunks(stream, cuts) {
        s.feed(c, |r| got.push(format!("{r:?}")));
    }
    s.expire();
    while let Some(r) = s.next_response() {
        got.push(format!("{r:?}"));
    }
    (got, *s.stats(), s.buffered())
}

proptest! {
    /// Unknown lines and overlong lines between valid ones, any chunking: every valid line out
    /// in order, the injected bytes counted exactly by cause.
    #[test]
    fn slcan_injected_lines_are_counted_exactly(
        items in prop::collection::vec((prop::option::of(prop_oneof![
            prop::collection::vec(b'w'..=b'y', 1..10).prop_map(|v| (false, v)),
            prop::collection::vec(b'a'..=b'd', 32..60).prop_map(|v| (true, v)),
        ]), slcan_lines()), 1..15),
        partial in prop::collection::vec(b'0'..=b'9', 0..5),
        cuts in prop::collection::vec(any::<usize>(), 0..20),
    ) {
        let mut stream = Vec::new();
        let (mut unknown, mut overlong, mut unknown_n, mut overlong_n) = (0u64, 0u64, 0u64, 0u64);
        let mut expected = Vec::new();
        for (inject, line) in &items {
            if let Some((long, text)) = inject {
                stream.extend_from_slice(text);
                stream.push(slcan::CR);
                let n = text.len() as u64 + 1;
                if *long { overlong += n; overlong_n += 1 } else { unknown += n; unknown_n += 1 }
            }
            stream.extend_from_slice(line);
            let term = *line.last().unwrap();
            let r = Response::decode(slcan::Line { body: &line[..line.len() - 1], terminator: term }, true).unwrap();
            expected.push(format!("{r:?}"));
        }
        stream.extend_from_slice(&partial);
        let (got, stats, buffered) = scan_slcan(&stream, &cuts);
        prop_assert_eq!(&got, &expected);
        prop_assert_eq!((stats.unknown.bytes, stats.unknown.events), (unknown, unknown_n));
        prop_assert_eq!((stats.overlong.bytes, stats.overlong.events), (overlong, overlong_n));
        prop_assert_eq!((stats.truncated.bytes, stats.malformed.bytes), (partial.len() as u64, 0));
        prop_assert_eq!(buffered, 0);
        prop_assert_eq!(stats.bytes_in, stats.line_bytes + stats.discarded_bytes());
        prop_assert_eq!((got, stats), { let (g, s, _) = scan_slcan(&stream, &[]); (g, s) });
    }

    #[test]
    fn slcan_arbitrary_input(bytes in prop::collection::vec(prop_oneof![Just(b'\r'), Just(7u8), Just(b't'), any::<u8>()], 0..300), cuts in prop::collection::vec(any::<usize>(), 0..20)) {
        let (got, stats, buffered) = scan_slcan(&bytes, &cuts);
        prop_assert_eq!(buffered, 0);
        prop_assert_eq!(stats.bytes_in, stats.line_bytes + stats.discarded_bytes());
        prop_assert_eq!(stats.lines, got.len() as u64);
        let (g2, s2, _) = scan_slcan(&bytes, &[]);
        prop_assert_eq!((got, stats), (g2, s2));
        let mut dev = slcan::DeviceScanner::<32>::new(slcan::Dialect::default());
        for c in chunks(&bytes, &cuts) {
            dev.feed(c, |_| {});
        }
        let st = dev.stats();
        prop_assert_eq!(st.bytes_in, st.line_bytes + st.discarded_bytes() + dev.buffered() as u64);
    }
}

proptest! {
    #![proptest_config(fixed_seed())]
    /// Faults never yield a packet that was not sent, and never cost a packet that was not
    /// damaged. Both hold up to CRC-16 collisions: a damaged candidate passes with probability
    /// about 2^-16 (measured: 5e-6 per single dropped byte), i.e. a few percent over this
    /// test's ~1500 faults for an arbitrary seed; the seed is fixed so the run is reproducible
    /// (see `crc_collision_after_a_dropped_byte` for such a case).
    #[test]
    fn dxl2_faults_fixed_seed(
        pkts in prop::collection::vec(pkt(), 1..16),
        faults in prop::collection::vec((any::<prop::sample::Index>(), any::<bool>(), 1u8..=255), 1..6),
    ) {
        let (stream, damaged) = inject(&pkts, &faults);
        let (got, stats, buffered) = scan_dxl2(&stream, &[]);
        check_invariant(&stats, buffered)?;
        let sent: Vec<Vec<u8>> = pkts.iter().map(flat).collect();
        for g in &got {
            prop_assert!(sent.contains(g), "foreign packet {:02X?}", g);
        }
        for (i, p) in pkts.iter().enumerate() {
            if !damaged[i] {
                prop_assert!(got.contains(&flat(p)), "lost undamaged packet {}", i);
            }
        }
        // Every damaged packet that is missing left a trace in the counters.
        let missing = sent.iter().filter(|p| !got.contains(p)).count() as u64;
        prop_assert!(stats.rejected_packets() + stats.garbage.events >= missing.min(1));
    }
}

/// The limit of any CRC-16: a dropped byte shifts the CRC window, and here the shifted bytes
/// happen to check (probability ~2^-16). The scanner yields that packet because its CRC checks;
/// nothing at this layer can tell. Found by `dxl2_faults_*` from a random seed.
#[test]
fn crc_collision_after_a_dropped_byte() {
    let pkts = [
        Pkt {
            id: 158,
            err: 0,
            data: vec![
                0, 255, 94, 253, 255, 228, 255, 255, 70, 64, 235, 246, 120, 255, 10, 198,
            ],
        },
        Pkt {
            id: 0,
            err: 0,
            data: vec![255; 5],
        },
    ];
    let mut stream: Vec<u8> = pkts.iter().flat_map(dxl2_wire).collect();
    stream.remove(13); // the 0xFF after 0xFD in the first packet's data
    let (got, stats, _) = scan_dxl2(&stream, &[]);
    // id, err, the data without the dropped byte, then the first packet's CRC low byte.
    let foreign = [
        158, 0, 0, 255, 94, 253, 228, 255, 255, 70, 64, 235, 246, 120, 255, 10, 198, 0x28,
    ];
    assert_eq!(got, vec![foreign.to_vec()]);
    assert_eq!(stats.bad_crc.events, 0);
}
