//! Golden vectors from protocols.md §1.11 (e-Manual protocol1.md examples, all verified).

mod golden;

use conductor_protocols::dynamixel1::*;
use golden::{enc, hex};

#[test]
fn checksum_worked_example() {
    // FF FF 01 05 03 0C 64 AA DC: sum 0x123 -> !0x23 = 0xDC.
    assert_eq!(checksum(&[0x01, 0x05, 0x03, 0x0C, 0x64, 0xAA]), 0xDC);
    assert_eq!(
        enc(|b| write(b, 1, 0x0C, &[0x64, 0xAA])),
        hex("FF FF 01 05 03 0C 64 AA DC")
    );
}

#[test]
fn instruction_examples() {
    assert_eq!(enc(|b| ping(b, 1)), hex("FF FF 01 02 01 FB"));
    assert_eq!(enc(|b| read(b, 1, 43, 1)), hex("FF FF 01 04 02 2B 01 CC"));
    assert_eq!(
        enc(|b| write(b, BROADCAST_ID, 3, &[1])),
        hex("FF FF FE 04 03 03 01 F6")
    );
    assert_eq!(
        enc(|b| reg_write(b, 1, 30, &500u16.to_le_bytes())),
        hex("FF FF 01 05 04 1E F4 01 E2")
    );
    assert_eq!(enc(|b| action(b, BROADCAST_ID)), hex("FF FF FE 02 05 FA"));
    let (g0, s0, g1, s1) = (
        0x010u16.to_le_bytes(),
        0x150u16.to_le_bytes(),
        0x220u16.to_le_bytes(),
        0x360u16.to_le_bytes(),
    );
    let d0 = [g0[0], g0[1], s0[0], s0[1]];
    let d1 = [g1[0], g1[1], s1[0], s1[1]];
    assert_eq!(
        enc(|b| sync_write(b, 0x1E, 4, [(0, &d0[..]), (1, &d1[..])])),
        hex("FF FF FE 0E 83 1E 04 00 10 00 50 01 01 20 02 60 03 67")
    );
    assert_eq!(
        enc(|b| sync_write(
            b,
            0x1E,
            2,
            [
                (1, &512u16.to_le_bytes()[..]),
                (2, &512u16.to_le_bytes()[..])
            ]
        )),
        hex("FF FF FE 0A 83 1E 02 01 00 02 02 00 02 4D")
    );
    assert_eq!(
        enc(|b| bulk_read(
            b,
            [
                BulkReadEntry {
                    len: 2,
                    id: 1,
                    addr: 0x1E
                },
                BulkReadEntry {
                    len: 2,
                    id: 2,
                    addr: 0x24
                }
            ]
        )),
        hex("FF FF FE 09 92 00 02 01 1E 02 02 24 1D")
    );
}

#[test]
fn status_examples() {
    let mut s = Scanner::<64>::new();
    let mut got = Vec::new();
    s.feed(
        &hex("FF FF 01 02 00 FC FF FF 01 03 00 20 DB FF FF 01 02 24 D8"),
        |p| {
            let st = Status::from_packet(&p);
            got.push((st.id, st.error, st.data_u16()));
        },
    );
    assert_eq!(
        got,
        vec![
            (1, ErrorBits(0), None),
            (1, ErrorBits(0), Some(0x20)),
            (1, ErrorBits(0x24), None)
        ]
    );
    let e = got[2].1;
    assert!(e.overload() && e.overheating());
    assert!(
        !(e.instruction() || e.checksum() || e.range() || e.angle_limit() || e.input_voltage())
    );
    assert_eq!(s.stats().discarded_bytes(), 0);
    assert_eq!(
        enc(|b| status(b, 1, ErrorBits(0), &[0x20])),
        hex("FF FF 01 03 00 20 DB")
    );
    assert_eq!(
        enc(|b| status(b, 1, ErrorBits(0x24), &[])),
        hex("FF FF 01 02 24 D8")
    );
}

#[test]
fn parse_reports_errors() {
    assert_eq!(
        parse(&hex("FF FF 01 02 01 FA")),
        Err(ParseError::Checksum {
            received: 0xFA,
            computed: 0xFB
        })
    );
    assert_eq!(parse(&hex("FF FF FF 02 01")), Err(ParseError::BadId(0xFF)));
    assert_eq!(parse(&hex("FF FF 01 01 01")), Err(ParseError::BadLength(1)));
    assert_eq!(
        parse(&hex("FF FF 01 04 02")),
        Err(ParseError::Incomplete { needed: 8, got: 5 })
    );
    let bytes = hex("FF FF 01 04 02 2B 01 CC 99");
    let (p, n) = parse(&bytes).unwrap();
    assert_eq!((p.id, p.code, p.params, n), (1, 0x02, &[0x2B, 0x01][..], 8));
}

#[test]
fn leading_ff_run_is_counted_as_bad_header() {
    let mut s = Scanner::<64>::new();
    let mut n = 0;
    s.feed(&hex("FF FF FF FF 01 02 00 FC"), |_| n += 1);
    assert_eq!(n, 1);
    assert_eq!(s.stats().bad_header.bytes, 2);
    assert_eq!(s.stats().bad_header.events, 2);
}

#[test]
fn encoder_rejects_bad_requests() {
    let mut b = [0u8; 64];
    // 1.0 device IDs run to 0xFD; 0xFE is broadcast, 0xFF is never an ID.
    // Checksum: !(0xFD + 0x02 + 0x01) = !0x00 (low byte) = 0xFF.
    assert_eq!(enc(|b| ping(b, 0xFD)), hex("FF FF FD 02 01 FF"));
    assert_eq!(ping(&mut b, 0xFF), Err(EncodeError::InvalidId(0xFF)));
    assert_eq!(
        read(&mut b, BROADCAST_ID, 36, 2),
        Err(EncodeError::InvalidId(0xFE))
    );
    let goal = [0u8, 2];
    assert_eq!(
        sync_write(
            &mut b,
            30,
            2,
            [(1, &goal[..]), (2, &goal[..]), (1, &goal[..])]
        ),
        Err(EncodeError::DuplicateId(1))
    );
    assert_eq!(
        sync_write(&mut b, 30, 2, [(BROADCAST_ID, &goal[..])]),
        Err(EncodeError::InvalidId(0xFE))
    );
    assert_eq!(
        sync_write(&mut b, 30, 2, [(1, &goal[..1])]),
        Err(EncodeError::DataLength {
            expected: 2,
            got: 1
        })
    );
    assert_eq!(
        sync_write(&mut b, 30, 2, core::iter::empty()),
        Err(EncodeError::NoEntries)
    );
    assert_eq!(bulk_read(&mut b, []), Err(EncodeError::NoEntries));
    // LEN is one byte: at most 253 parameter bytes after the instruction.
    let mut out = [0u8; 300];
    assert_eq!(write(&mut out, 1, 0, &[0u8; 251]).map(|n| n > 0), Ok(true));
    assert_eq!(
        write(&mut out, 1, 0, &[0u8; 253]),
        Err(EncodeError::TooLong)
    );
    assert_eq!(ping(&mut b[..5], 1), Err(EncodeError::BufferTooSmall));
}
