//! Golden vectors from protocols.md §1.4, §1.7 and §1.8 (e-Manual examples with the two wrong
//! CRCs corrected, plus the derived vectors).

mod golden;

use conductor_protocols::dynamixel2::{self as dxl, *};
use golden::{enc, hex};

#[test]
fn instruction_examples_from_the_manual() {
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("FF FF FD 00 01 03 00 01 19 4E", enc(|b| ping(b, 1))),
        (
            "FF FF FD 00 FE 03 00 01 31 42",
            enc(|b| ping(b, BROADCAST_ID)),
        ),
        (
            "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15",
            enc(|b| read(b, 1, 132, 4)),
        ),
        (
            "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89",
            enc(|b| write(b, 1, 116, &512u32.to_le_bytes())),
        ),
        (
            "FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E",
            enc(|b| reg_write(b, 1, 104, &200u32.to_le_bytes())),
        ),
        ("FF FF FD 00 01 03 00 05 02 CE", enc(|b| action(b, 1))),
        (
            "FF FF FD 00 01 04 00 06 01 A1 E6",
            enc(|b| factory_reset(b, 1, FactoryResetMode::ExceptId)),
        ),
        ("FF FF FD 00 01 03 00 08 2F 4E", enc(|b| reboot(b, 1))),
        (
            "FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC",
            enc(|b| clear_multi_turn(b, 1)),
        ),
        (
            "FF FF FD 00 01 08 00 20 01 43 54 52 4C 16 F5",
            enc(|b| control_table_backup(b, 1, BackupOp::Store)),
        ),
        (
            "FF FF FD 00 01 08 00 20 02 43 54 52 4C 9E F5",
            enc(|b| control_table_backup(b, 1, BackupOp::Restore)),
        ),
        (
            "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA",
            enc(|b| sync_read(b, 132, 4, &[1, 2])),
        ),
        (
            "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87",
            enc(|b| {
                sync_write(
                    b,
                    116,
                    4,
                    [
                        (1, &150u32.to_le_bytes()[..]),
                        (2, &170u32.to_le_bytes()[..]),
                    ],
                )
            }),
        ),
        (
            "FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05",
            enc(|b| {
                bulk_read(
                    b,
                    [
                        BulkReadEntry {
                            id: 1,
                            addr: 144,
                            len: 2,
                        },
                        BulkReadEntry {
                            id: 2,
                            addr: 146,
                            len: 1,
                        },
                    ],
                )
            }),
        ),
        (
            "FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50 B7 68",
            enc(|b| {
                bulk_write(
                    b,
                    [
                        BulkWriteEntry {
                            id: 1,
                            addr: 32,
                            data: &160u16.to_le_bytes(),
                        },
                        BulkWriteEntry {
                            id: 2,
                            addr: 31,
                            data: &[80],
                        },
                    ],
                )
            }),
        ),
        (
            "FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2",
            enc(|b| fast_sync_read(b, 132, 4, &[3, 7, 4])),
        ),
        (
            "FF FF FD 00 FE 12 00 9A 03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00 DA 2D",
            enc(|b| {
                fast_bulk_read(
                    b,
                    [
                        BulkReadEntry {
                            id: 3,
                            addr: 132,
                            len: 4,
                        },
                        BulkReadEntry {
                            id: 7,
                            addr: 124,
                            len: 2,
                        },
                        BulkReadEntry {
                            id: 4,
                            addr: 146,
                            len: 1,
                        },
                    ],
                )
            }),
        ),
    ];
    for (want, got) in cases {
        assert_eq!(got, hex(want), "{want}");
    }
}

#[test]
fn derived_vectors() {
    let cases: Vec<(&str, Vec<u8>)> = vec![
        (
            "FF FF FD 00 01 06 00 03 40 00 01 DB 66",
            enc(|b| write(b, 1, 64, &[1])),
        ),
        (
            "FF FF FD 00 01 06 00 03 40 00 00 DE E6",
            enc(|b| write(b, 1, 64, &[0])),
        ),
        (
            "FF FF FD 00 01 06 00 03 0B 00 03 48 E3",
            enc(|b| write(b, 1, 11, &[3])),
        ),
        (
            "FF FF FD 00 01 07 00 02 7E 00 0A 00 36 F9",
            enc(|b| read(b, 1, 126, 10)),
        ),
        (
            "FF FF FD 00 FE 11 00 83 74 00 04 00 01 00 08 00 00 02 00 08 00 00 68 4C",
            enc(|b| {
                sync_write(
                    b,
                    116,
                    4,
                    [
                        (1, &2048u32.to_le_bytes()[..]),
                        (2, &2048u32.to_le_bytes()[..]),
                    ],
                )
            }),
        ),
        (
            "FF FF FD 00 FE 09 00 8A 7E 00 0A 00 01 02 BB 1A",
            enc(|b| fast_sync_read(b, 126, 10, &[1, 2])),
        ),
        (
            "FF FF FD 00 01 04 00 55 80 A2 8F",
            enc(|b| status(b, 1, 0x80, &[])),
        ),
        (
            "FF FF FD 00 01 0A 00 03 74 00 FF FF FD FD 00 21 E7",
            enc(|b| write(b, 1, 0x74, &[0xFF, 0xFF, 0xFD, 0x00])),
        ),
    ];
    for (want, got) in cases {
        assert_eq!(got, hex(want), "{want}");
    }
}

/// The e-Manual prints `92 F5` for Backup restore and `20 F2` (copied from Fast Sync Read) for
/// Fast Bulk Read. Both fail the CRC check; the corrected packets pass.
#[test]
fn the_manuals_two_wrong_crcs_fail_and_the_fixed_ones_pass() {
    let wrong_restore = hex("FF FF FD 00 01 08 00 20 02 43 54 52 4C 92 F5");
    let wrong_fast_bulk =
        hex("FF FF FD 00 FE 12 00 9A 03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00 20 F2");
    assert!(matches!(
        check_frame(&wrong_restore),
        Err(ParseError::Crc {
            received: 0xF592,
            computed: 0xF59E
        })
    ));
    assert!(matches!(
        check_frame(&wrong_fast_bulk),
        Err(ParseError::Crc {
            received: 0xF220,
            computed: 0x2DDA
        })
    ));
    let mut s = Scanner::<256>::new();
    let mut n = 0;
    s.feed(&wrong_restore, |_| n += 1);
    s.feed(&wrong_fast_bulk, |_| n += 1);
    assert_eq!(n, 0);
    assert_eq!(s.stats().bad_crc.events, 2);
    assert_eq!(
        check_frame(&hex("FF FF FD 00 01 08 00 20 02 43 54 52 4C 9E F5")),
        Ok(15)
    );
}

fn scan_one(bytes: &[u8], f: impl FnOnce(Packet<'_>)) {
    let mut s = Scanner::<256>::new();
    let mut f = Some(f);
    let mut count = 0;
    s.feed(bytes, |p| {
        count += 1;
        if let Some(f) = f.take() {
            f(p)
        }
    });
    assert_eq!(count, 1);
    assert_eq!(s.stats().discarded_bytes(), 0);
}

#[test]
fn status_examples_decode() {
    scan_one(&hex("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D"), |p| {
        let st = Status::from_packet(&p).unwrap();
        assert_eq!(
            PingInfo::from_status(&st).unwrap(),
            PingInfo {
                id: 1,
                model: 1030,
                firmware: 0x26
            }
        );
        assert!(st.error.is_ok());
    });
    scan_one(&hex("FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D"), |p| {
        let st = Status::from_packet(&p).unwrap();
        assert_eq!(PingInfo::from_status(&st).unwrap().id, 2);
    });
    scan_one(&hex("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0"), |p| {
        assert_eq!(Status::from_packet(&p).unwrap().data_u32(), Some(166));
    });
    scan_one(&hex("FF FF FD 00 01 04 00 55 00 A1 0C"), |p| {
        let st = Status::from_packet(&p).unwrap();
        assert_eq!((st.id, st.data.len(), st.error.error()), (1, 0, None));
    });
    scan_one(&hex("FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE"), |p| {
        assert_eq!(Status::from_packet(&p).unwrap().data_u32(), Some(2079));
    });
    scan_one(&hex("FF FF FD 00 01 06 00 55 00 77 00 C3 69"), |p| {
        assert_eq!(Status::from_packet(&p).unwrap().data_u32(), Some(119));
    });
    scan_one(&hex("FF FF FD 00 02 05 00 55 00 24 8B A9"), |p| {
        assert_eq!(Status::from_packet(&p).unwrap().data, &[0x24]);
    });
    scan_one(&hex("FF FF FD 00 01 04 00 55 80 A2 8F"), |p| {
        let st = Status::from_packet(&p).unwrap();
        assert!(st.error.alert());
        assert_eq!(st.error.error(), None);
    });
}

#[test]
fn status_encoder_reproduces_the_manuals_replies() {
    assert_eq!(
        enc(|b| status(b, 1, 0, &[0x06, 0x04, 0x26])),
        hex("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D")
    );
    assert_eq!(
        enc(|b| status(b, 1, 0, &166u32.to_le_bytes())),
        hex("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0")
    );
    assert_eq!(
        enc(|b| status(b, 2, 0, &[0x24])),
        hex("FF FF FD 00 02 05 00 55 00 24 8B A9")
    );
}

#[test]
fn stuffed_write_is_unstuffed_by_the_scanner() {
    scan_one(
        &hex("FF FF FD 00 01 0A 00 03 74 00 FF FF FD FD 00 21 E7"),
        |p| {
            assert_eq!((p.id, p.instruction), (1, 0x03));
            assert_eq!(p.params, &[0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00]);
            assert_eq!(p.wire_len, 17);
        },
    );
}

#[test]
fn fast_sync_read_reply_with_running_crcs() {
    let wire = hex(
        "FF FF FD 00 FE 19 00 55 00 03 A6 00 00 00 84 08 00 07 1F 08 00 00 16 CA 00 04 FF 03 00 00 D1 9E",
    );
    // The embedded CRCs are the running CRC of the packet so far.
    assert_eq!(dxl::crc::crc16(&wire[..14]), 0x0884);
    assert_eq!(dxl::crc::crc16(&wire[..22]), 0xCA16);
    scan_one(&wire, |p| {
        let reply = FastReply::from_packet(&p).unwrap();
        let got: Vec<_> = reply
            .slices(core::iter::repeat(4))
            .map(|s| s.unwrap())
            .collect();
        let ids: Vec<_> = got
            .iter()
            .map(|s| (s.id, u32::from_le_bytes(s.data.try_into().unwrap())))
            .collect();
        assert_eq!(ids, vec![(3, 166), (7, 2079), (4, 1023)]);
        assert!(got.iter().all(|s| s.error.is_ok()));
    });
    let slices = [
        FastStatusSlice {
            error: 0,
            id: 3,
            data: &166u32.to_le_bytes(),
        },
        FastStatusSlice {
            error: 0,
            id: 7,
            data: &2079u32.to_le_bytes(),
        },
        FastStatusSlice {
            error: 0,
            id: 4,
            data: &1023u32.to_le_bytes(),
        },
    ];
    assert_eq!(enc(|b| fast_status(b, &slices)), wire);
}

#[test]
fn fast_bulk_read_reply() {
    let wire =
        hex("FF FF FD 00 FE 14 00 55 00 03 A6 00 00 00 67 A4 00 07 A5 01 24 74 00 04 1F D9 C1");
    scan_one(&wire, |p| {
        let reply = FastReply::from_packet(&p).unwrap();
        let got: Vec<_> = reply.slices([4, 2, 1]).map(|s| s.unwrap()).collect();
        assert_eq!((got[0].id, got[0].data), (3, &[0xA6, 0, 0, 0][..]));
        assert_eq!((got[1].id, got[1].data), (7, &[0xA5, 0x01][..]));
        assert_eq!((got[2].id, got[2].data), (4, &[0x1F][..]));
    });
}

#[test]
fn fast_reply_with_corrupted_embedded_crc_is_reported() {
    let slices = [
        FastStatusSlice {
            error: 0,
            id: 3,
            data: &[1, 2],
        },
        FastStatusSlice {
            error: 0,
            id: 7,
            data: &[3, 4],
        },
    ];
    let mut wire = enc(|b| fast_status(b, &slices));
    // Corrupt the first embedded CRC, then fix the packet CRC so the scanner passes it.
    wire[12] ^= 0x01;
    let n = wire.len();
    let c = dxl::crc::crc16(&wire[..n - 2]).to_le_bytes();
    wire[n - 2..].copy_from_slice(&c);
    scan_one(&wire, |p| {
        let mut it = FastReply::from_packet(&p)
            .unwrap()
            .slices(core::iter::repeat(2));
        assert_eq!(it.next(), Some(Err(FastReplyError::EmbeddedCrc { id: 3 })));
        assert_eq!(it.next(), None);
    });
}

#[test]
fn error_byte_numbers() {
    let expect = [
        (1, DeviceError::ResultFail),
        (2, DeviceError::Instruction),
        (3, DeviceError::Crc),
        (4, DeviceError::DataRange),
        (5, DeviceError::DataLength),
        (6, DeviceError::DataLimit),
        (7, DeviceError::Access),
        (0x15, DeviceError::Unknown(0x15)),
    ];
    for (code, e) in expect {
        assert_eq!(ErrorByte(code).error(), Some(e));
        assert!(!ErrorByte(code).alert());
        assert_eq!(ErrorByte(code | 0x80).error(), Some(e));
        assert!(ErrorByte(code | 0x80).alert());
    }
}

#[test]
fn encoder_rejects_bad_requests() {
    let mut b = [0u8; 64];
    assert_eq!(read(&mut b, 0xFD, 0, 1), Err(EncodeError::InvalidId(0xFD)));
    assert_eq!(
        read(&mut b, BROADCAST_ID, 0, 1),
        Err(EncodeError::InvalidId(0xFE))
    );
    assert_eq!(
        sync_read(&mut b, 0, 1, &[1, 2, 1]),
        Err(EncodeError::DuplicateId(1))
    );
    assert_eq!(sync_read(&mut b, 0, 1, &[]), Err(EncodeError::NoEntries));
    assert_eq!(
        sync_write(&mut b, 116, 4, [(1, &[0u8, 0, 0][..])]),
        Err(EncodeError::DataLength {
            expected: 4,
            got: 3
        })
    );
    assert_eq!(ping(&mut b[..9], 1), Err(EncodeError::BufferTooSmall));
    assert_eq!(ping(&mut b[..10], 1), Ok(10));
    let big = [0u8; 70_000];
    let mut out = vec![0u8; 80_000];
    assert_eq!(write(&mut out, 1, 0, &big), Err(EncodeError::TooLong));
}

#[test]
fn manual_instructions_decode_as_requests() {
    let check = |wire: &str, f: &dyn Fn(Request<'_>)| {
        let mut b = hex(wire);
        let p = parse_in_place(&mut b).unwrap();
        f(Request::from_packet(&p).unwrap());
    };
    check("FF FF FD 00 01 03 00 01 19 4E", &|r| {
        assert_eq!(r, Request::Ping)
    });
    check("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15", &|r| {
        assert_eq!(r, Request::Read { addr: 132, len: 4 })
    });
    check("FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89", &|r| {
        assert_eq!(
            r,
            Request::Write {
                addr: 116,
                data: &[0, 2, 0, 0]
            }
        )
    });
    check("FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E", &|r| {
        assert_eq!(
            r,
            Request::RegWrite {
                addr: 104,
                data: &[200, 0, 0, 0]
            }
        )
    });
    check("FF FF FD 00 01 03 00 05 02 CE", &|r| {
        assert_eq!(r, Request::Action)
    });
    check("FF FF FD 00 01 04 00 06 01 A1 E6", &|r| {
        assert_eq!(r, Request::FactoryReset(1))
    });
    check("FF FF FD 00 01 03 00 08 2F 4E", &|r| {
        assert_eq!(r, Request::Reboot)
    });
    check("FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC", &|r| {
        assert_eq!(r, Request::ClearMultiTurn)
    });
    check("FF FF FD 00 01 08 00 20 02 43 54 52 4C 9E F5", &|r| {
        assert_eq!(r, Request::ControlTableBackup(2))
    });
    check("FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA", &|r| {
        assert_eq!(
            r,
            Request::SyncRead {
                fast: false,
                addr: 132,
                len: 4,
                ids: &[1, 2]
            }
        )
    });
    check("FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2", &|r| {
        assert_eq!(
            r,
            Request::SyncRead {
                fast: true,
                addr: 132,
                len: 4,
                ids: &[3, 7, 4]
            }
        )
    });
    check(
        "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87",
        &|r| {
            let e: Vec<_> = r.sync_write_entries().collect();
            assert_eq!(
                e,
                vec![(1, &[0x96, 0, 0, 0][..]), (2, &[0xAA, 0, 0, 0][..])]
            );
        },
    );
    check(
        "FF FF FD 00 FE 12 00 9A 03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00 DA 2D",
        &|r| {
            assert!(matches!(r, Request::BulkRead { fast: true, .. }));
            let e: Vec<_> = r
                .bulk_read_entries()
                .map(|e| (e.id, e.addr, e.len))
                .collect();
            assert_eq!(e, vec![(3, 132, 4), (7, 124, 2), (4, 146, 1)]);
        },
    );
    check(
        "FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50 B7 68",
        &|r| {
            let e: Vec<_> = r
                .bulk_write_entries()
                .map(|e| (e.id, e.addr, e.data.to_vec()))
                .collect();
            assert_eq!(e, vec![(1, 32, vec![0xA0, 0]), (2, 31, vec![0x50])]);
        },
    );
}

#[test]
fn malformed_requests_are_typed_errors() {
    let req = |id: u8, inst: u8, params: &[u8]| {
        let mut w = vec![0xFF, 0xFF, 0xFD, 0x00, id, 0, 0, inst];
        w.extend_from_slice(params);
        let len = (params.len() + 3) as u16;
        w[5..7].copy_from_slice(&len.to_le_bytes());
        let c = dxl::crc::crc16(&w).to_le_bytes();
        w.extend_from_slice(&c);
        let p = parse_in_place(&mut w).unwrap();
        Request::from_packet(&p).map(|_| ())
    };
    assert_eq!(
        req(1, 0x02, &[0x84, 0x00, 0x04]),
        Err(RequestError::Length(3))
    );
    assert_eq!(
        req(1, 0x77, &[]),
        Err(RequestError::UnknownInstruction(0x77))
    );
    assert_eq!(req(1, 0x55, &[0]), Err(RequestError::Status));
    assert_eq!(
        req(1, 0x82, &[0x84, 0, 4, 0, 1]),
        Err(RequestError::NotBroadcast)
    );
    assert_eq!(
        req(0xFE, 0x83, &[0x74, 0, 4, 0, 1, 0, 0, 0]),
        Err(RequestError::Length(8))
    );
    assert_eq!(
        req(0xFE, 0x93, &[1, 0x20, 0, 5, 0, 1]),
        Err(RequestError::Length(6))
    );
    assert_eq!(
        req(1, 0x10, &[1, 0x44, 0x58, 0x4C, 0x23]),
        Err(RequestError::Key)
    );
    assert_eq!(req(0xFE, 0x92, &[]), Err(RequestError::Length(0)));
}

#[test]
fn wire_length_helpers_match_the_encoders() {
    assert_eq!(instruction_len(0), 10);
    assert_eq!(status_len(4), 15); // SDK: len + 11
    assert_eq!(fast_reply_len(3, 4), 32); // the manual's fast sync read reply
    assert_eq!(fast_reply_len(0, 4), 0);
}
