//! Scanner resynchronisation cases with exact counts.

use conductor_protocols::dynamixel2::{self as d2, Scanner};

fn status(id: u8, data: &[u8]) -> Vec<u8> {
    let mut buf = [0u8; 64];
    let n = d2::status(&mut buf, id, 0, data).unwrap();
    buf[..n].to_vec()
}

fn ids(s: &mut Scanner<128>, bytes: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    s.feed(bytes, |p| out.push(p.id));
    out
}

#[test]
fn truncated_packet_then_complete_one_resolves_on_expire() {
    let a = status(1, &[1, 2, 3, 4]);
    let b = status(2, &[5, 6, 7, 8]);
    let mut stream = a[..9].to_vec(); // A lost its last 6 bytes
    stream.extend(&b);
    let mut s = Scanner::<128>::new();
    // A claims 15 bytes; B's 15 bytes complete that span, A's CRC fails, B is found inside it.
    assert_eq!(ids(&mut s, &stream), vec![2]);
    assert_eq!((s.stats().bad_crc.bytes, s.stats().bad_crc.events), (9, 1));

    // A truncated tail with nothing behind it waits until expire.
    let mut s = Scanner::<128>::new();
    assert_eq!(ids(&mut s, &a[..9]), Vec::<u8>::new());
    assert_eq!(s.buffered(), 9);
    let mut late = Vec::new();
    s.expire_with(|p| late.push(p.id));
    assert!(late.is_empty());
    assert_eq!(
        (
            s.stats().truncated.bytes,
            s.stats().truncated.events,
            s.buffered()
        ),
        (9, 1, 0)
    );
}

#[test]
fn expire_yields_packets_behind_a_long_truncated_candidate() {
    // A's length field was corrupted upwards: its claimed span swallows B and C.
    let mut a = status(1, &[1, 2, 3, 4]);
    a[5] = 0x60;
    let mut stream = a.clone();
    stream.extend(status(2, &[9]));
    stream.extend(status(3, &[8]));
    let mut s = Scanner::<128>::new();
    assert!(
        ids(&mut s, &stream).is_empty(),
        "still waiting for A's claimed 103 bytes"
    );
    let mut got = Vec::new();
    s.expire_with(|p| got.push(p.id));
    assert_eq!(got, vec![2, 3]);
    assert_eq!(
        (s.stats().truncated.bytes, s.stats().truncated.events),
        (a.len() as u64, 1)
    );
}

#[test]
fn oversize_and_bad_header_discard_only_the_header_fields() {
    let mut big = status(1, &[1, 2]);
    big[5..7].copy_from_slice(&500u16.to_le_bytes()); // 507 bytes > 125
    let mut bad_id = status(1, &[1, 2]);
    bad_id[4] = 0xFD;
    let good = status(7, &[1]);
    let mut stream = big.clone();
    stream.extend(&bad_id);
    stream.extend(&good);
    let mut s = Scanner::<128>::new();
    assert_eq!(ids(&mut s, &stream), vec![7]);
    let st = s.stats();
    assert_eq!((st.oversize.bytes, st.oversize.events), (7, 1));
    assert_eq!((st.bad_header.bytes, st.bad_header.events), (7, 1));
    // The rest of the two damaged 13-byte packets (6 bytes each) is one garbage run each.
    assert_eq!((st.garbage.bytes, st.garbage.events), (12, 2));
    assert_eq!(st.bytes_in, st.packet_bytes + st.discarded_bytes());
}

#[test]
fn input_larger_than_the_buffer_is_taken_in_pieces() {
    let stream: Vec<u8> = (0..40u8).flat_map(|i| status(i, &[i; 6])).collect();
    assert!(stream.len() > 600);
    let mut s = Scanner::<32>::new();
    assert_eq!(s.push(&stream), 32, "push takes what fits");
    let mut got = Vec::new();
    while let Some(p) = s.next_packet() {
        got.push(p.id);
    }
    s.feed(&stream[32..], |p| got.push(p.id));
    assert_eq!(got, (0..40).collect::<Vec<u8>>());
    assert_eq!(s.stats().discarded_bytes(), 0);
}

#[test]
fn max_packet_is_clamped_to_the_buffer() {
    assert_eq!(Scanner::<64>::new().max_packet(), 61);
    assert_eq!(Scanner::<64>::with_max_packet(20).max_packet(), 20);
    assert_eq!(Scanner::<64>::with_max_packet(1).max_packet(), 10);
}
