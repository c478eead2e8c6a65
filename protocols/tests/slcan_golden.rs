//! SLCAN vectors from protocols.md §3 (kernel examples, MIT and ODrive lines) and the device
//! variants (CR vs z/Z acks, BEL, S7).

use conductor_protocols::can::CanFrame;
use conductor_protocols::mit_can::{self, Command as MitCommand, Model};
use conductor_protocols::odrive_can::{self, Message};
use conductor_protocols::slcan::*;
use embedded_can::Frame;

fn line(cmd: Command, d: &Dialect) -> String {
    let mut buf = [0u8; 64];
    let n = cmd.encode(d, &mut buf).unwrap();
    String::from_utf8(buf[..n].to_vec()).unwrap()
}

fn tx(f: CanFrame) -> String {
    line(Command::Transmit(f), &Dialect::default())
}

#[test]
fn kernel_examples_encode_and_decode() {
    let cases = [
        ("t1230", CanFrame::standard(0x123, &[]).unwrap()),
        (
            "t4563112233",
            CanFrame::standard(0x456, &[0x11, 0x22, 0x33]).unwrap(),
        ),
        (
            "T12ABCDEF2AA55",
            CanFrame::extended(0x12AB_CDEF, &[0xAA, 0x55]).unwrap(),
        ),
        (
            "r1230",
            CanFrame::new_remote(embedded_can::StandardId::new(0x123).unwrap(), 0).unwrap(),
        ),
    ];
    for (text, frame) in cases {
        assert_eq!(tx(frame), format!("{text}\r"));
        // Adapter side reads the command back.
        assert_eq!(
            Command::decode(text.as_bytes(), &Dialect::default()),
            Ok(Command::Transmit(frame))
        );
        // Host side reads the same line as a received frame.
        let got = Response::decode(
            Line {
                body: text.as_bytes(),
                terminator: CR,
            },
            true,
        )
        .unwrap();
        assert_eq!(
            got,
            Response::Frame {
                frame,
                timestamp: None
            }
        );
    }
}

#[test]
fn longest_line_is_slc_mtu() {
    let body = b"T1111222281122334455667788EA5F";
    let r = Response::decode(
        Line {
            body,
            terminator: CR,
        },
        true,
    )
    .unwrap();
    let frame = CanFrame::extended(
        0x1111_2222,
        &[0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88],
    )
    .unwrap();
    assert_eq!(
        r,
        Response::Frame {
            frame,
            timestamp: Some(0xEA5F)
        }
    );
    let mut buf = [0u8; 40];
    assert_eq!(
        Response::Frame {
            frame,
            timestamp: Some(0xEA5F)
        }
        .encode(&mut buf),
        Ok(MAX_FRAME_LINE)
    );
    assert_eq!(&buf[..MAX_FRAME_LINE], b"T1111222281122334455667788EA5F\r");
}

#[test]
fn mit_and_odrive_lines() {
    let enter: CanFrame = mit_can::enter_frame(1).unwrap();
    assert_eq!(tx(enter), "t0018FFFFFFFFFFFFFFFC\r");
    let l = Model::Ak80_9.limits();
    let zero: CanFrame = mit_can::command_frame(1, &MitCommand::default(), &l).unwrap();
    assert_eq!(tx(zero), "t00187FFF7FF0000007FF\r");
    let c = MitCommand {
        p: 1.0,
        v: 2.0,
        kp: 10.0,
        kd: 1.0,
        t: 0.5,
    };
    let f: CanFrame = mit_can::command_frame(1, &c, &l).unwrap();
    assert_eq!(tx(f), "t00188A3C851051333838\r");
    let pos: CanFrame = odrive_can::frame(
        1,
        &Message::SetInputPos {
            pos: 1.5,
            vel_ff: 0.5,
            torque_ff: -0.25,
        },
    )
    .unwrap();
    assert_eq!(tx(pos), "t02C80000C03FF40106FF\r");
    let st: CanFrame = odrive_can::frame(1, &Message::SetAxisState { requested_state: 8 }).unwrap();
    assert_eq!(tx(st), "t02780800000000000000\r");
}

#[test]
fn s7_is_explicit_per_dialect() {
    let (law, can) = (Dialect::LAWICEL, Dialect::CANABLE);
    let mut buf = [0u8; 8];
    assert_eq!(line(Command::Bitrate(Bitrate::K800), &law), "S7\r");
    assert_eq!(line(Command::Bitrate(Bitrate::K750), &can), "S7\r");
    assert_eq!(
        Command::Bitrate(Bitrate::K750).encode(&law, &mut buf),
        Err(SlcanError::Bitrate)
    );
    assert_eq!(
        Command::Bitrate(Bitrate::K800).encode(&can, &mut buf),
        Err(SlcanError::Bitrate)
    );
    assert_eq!(
        Command::decode(b"S7", &law),
        Ok(Command::Bitrate(Bitrate::K800))
    );
    assert_eq!(
        Command::decode(b"S7", &can),
        Ok(Command::Bitrate(Bitrate::K750))
    );
    assert_eq!(Dialect::default(), Dialect::LAWICEL);
    let expected = [
        10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 0, 1_000_000,
    ];
    for (code, bps) in expected.iter().enumerate() {
        if *bps == 0 {
            continue;
        }
        let b = Bitrate::from_bps(*bps).unwrap();
        assert_eq!(b.code(&law), Some(code as u8));
        assert_eq!(b.code(&can), Some(code as u8));
    }
    assert_eq!(Command::decode(b"SA", &law), Err(SlcanError::Bitrate));
}

#[test]
fn open_sequence_matches_linux_and_python_can() {
    let mut buf = [0u8; 16];
    let n = open_sequence(Bitrate::K500, false, &Dialect::default(), &mut buf).unwrap();
    assert_eq!(&buf[..n], b"C\rS6\rO\r");
    let n = open_sequence(Bitrate::M1, true, &Dialect::default(), &mut buf).unwrap();
    assert_eq!(&buf[..n], b"C\rS8\rL\r");
    assert_eq!(
        open_sequence(Bitrate::M1, true, &Dialect::default(), &mut buf[..5]),
        Err(SlcanError::BufferTooSmall)
    );
}

#[test]
fn other_commands_round_trip() {
    let d = Dialect::default();
    let cases = [
        (Command::Open, "O\r"),
        (Command::ListenOnly, "L\r"),
        (Command::Close, "C\r"),
        (
            Command::Btr {
                btr0: 0x03,
                btr1: 0x1C,
            },
            "s031C\r",
        ),
        (Command::ReadStatus, "F\r"),
        (Command::Version, "V\r"),
        (Command::SerialNumber, "N\r"),
        (Command::Timestamps(true), "Z1\r"),
        (Command::Timestamps(false), "Z0\r"),
        (Command::AcceptanceCode(0x1234_ABCD), "M1234ABCD\r"),
        (Command::AcceptanceMask(0xFFFF_FFFF), "mFFFFFFFF\r"),
    ];
    for (cmd, text) in cases {
        assert_eq!(line(cmd, &d), text);
        assert_eq!(Command::decode(text.trim_end().as_bytes(), &d), Ok(cmd));
    }
    // Lower-case hex is accepted on input.
    assert_eq!(
        Command::decode(b"t1ab2cafe", &d),
        Ok(Command::Transmit(
            CanFrame::standard(0x1AB, &[0xCA, 0xFE]).unwrap()
        ))
    );
}

#[test]
fn acknowledgement_variants_interleaved_with_frames() {
    // CANable: CR for everything, BEL on error. LAWICEL: z/Z after t/T. Kernel extensions e/s.
    let wire = b"\r\r\rt1230\r\rz\rt0018FFFFFFFFFFFFFFFC0A1B\rZ\r\x07F04\rVsome-git-id\rN1234\re1a\rsa057033\r";
    let mut s = HostScanner::<64>::new();
    s.set_timestamps(true);
    let mut got = Vec::new();
    s.feed(wire, |r| got.push(format!("{r:?}")));
    let enter: CanFrame = mit_can::enter_frame(1).unwrap();
    let expected = [
        format!("{:?}", Response::Ok),
        format!("{:?}", Response::Ok),
        format!("{:?}", Response::Ok),
        format!(
            "{:?}",
            Response::Frame {
                frame: CanFrame::standard(0x123, &[]).unwrap(),
                timestamp: None
            }
        ),
        format!("{:?}", Response::Ok),
        format!("{:?}", Response::TxAck { extended: false }),
        format!(
            "{:?}",
            Response::Frame {
                frame: enter,
                timestamp: Some(0x0A1B)
            }
        ),
        format!("{:?}", Response::TxAck { extended: true }),
        format!("{:?}", Response::Error),
        format!("{:?}", Response::Status(0x04)),
        format!("{:?}", Response::Version(b"some-git-id")),
        format!("{:?}", Response::Serial(b"1234")),
        format!("{:?}", Response::ErrorFrame(b"1a")),
        format!("{:?}", Response::BusState(b"a057033")),
    ];
    assert_eq!(got, expected);
    assert_eq!(s.stats().discarded_bytes(), 0);
    assert_eq!(s.stats().line_bytes, wire.len() as u64);
}

#[test]
fn pending_acks_follow_the_fifo() {
    let mut q = PendingAcks::<4>::new();
    q.push(CommandKind::Control, 1).unwrap();
    q.push(CommandKind::Transmit, 2).unwrap();
    q.push(CommandKind::Query, 3).unwrap();
    let frame = Response::Frame {
        frame: CanFrame::standard(1, &[]).unwrap(),
        timestamp: None,
    };
    assert_eq!(q.resolve(&frame), None);
    assert_eq!(
        q.resolve(&Response::Version(b"x")),
        None,
        "a query reply cannot ack a control command"
    );
    assert_eq!(
        q.resolve(&Response::Ok),
        Some(Acked {
            kind: CommandKind::Control,
            tag: 1,
            ok: true
        })
    );
    assert_eq!(
        q.resolve(&Response::TxAck { extended: false }),
        Some(Acked {
            kind: CommandKind::Transmit,
            tag: 2,
            ok: true
        })
    );
    assert_eq!(
        q.resolve(&Response::Version(b"x")),
        Some(Acked {
            kind: CommandKind::Query,
            tag: 3,
            ok: true
        })
    );
    assert_eq!(q.resolve(&Response::Error), None);
    for t in 0..4 {
        q.push(CommandKind::Transmit, t).unwrap();
    }
    assert_eq!(q.push(CommandKind::Transmit, 9), Err(QueueFull));
    assert_eq!(
        q.resolve(&Response::Error),
        Some(Acked {
            kind: CommandKind::Transmit,
            tag: 0,
            ok: false
        })
    );
    assert_eq!(q.pop(), Some((CommandKind::Transmit, 1)));
    assert_eq!(q.len(), 2);
    assert_eq!(CommandKind::of(&Command::Version), CommandKind::Query);
}

#[test]
fn adapter_side_replies_per_dialect() {
    let mut buf = [0u8; 8];
    let n = Response::TxAck { extended: true }.encode(&mut buf).unwrap();
    assert_eq!(&buf[..n], b"Z\r");
    let n = Response::Error.encode(&mut buf).unwrap();
    assert_eq!(&buf[..n], b"\x07");
    let n = Response::Ok.encode(&mut buf).unwrap();
    assert_eq!(&buf[..n], b"\r");
    assert_eq!(
        Response::Version(b"a\rb").encode(&mut buf),
        Err(SlcanError::Length)
    );
    assert_eq!(Dialect::CANABLE.tx_ack, TxAck::Cr);
    assert_eq!(Dialect::LAWICEL.tx_ack, TxAck::Z);
}

#[test]
fn device_scanner_reports_bad_lines_for_bel() {
    let mut s = DeviceScanner::<64>::new(Dialect::CANABLE);
    let mut got = Vec::new();
    s.feed(b"C\rS7\rO\rt12\rx\rt0018FFFFFFFFFFFFFFFC\r", |c| {
        got.push(c)
    });
    let enter: CanFrame = mit_can::enter_frame(1).unwrap();
    assert_eq!(
        got,
        vec![
            Ok(Command::Close),
            Ok(Command::Bitrate(Bitrate::K750)),
            Ok(Command::Open),
            Err(SlcanError::Length),
            Err(SlcanError::Unknown(b'x')),
            Ok(Command::Transmit(enter)),
        ]
    );
    assert_eq!(s.stats().malformed.bytes, 4);
    assert_eq!(s.stats().unknown.bytes, 2);
}

#[test]
fn malformed_frames_are_rejected() {
    let bad: [&[u8]; 9] = [
        b"t123",       // no DLC
        b"t1239",      // DLC 9
        b"t12G0",      // bad hex
        b"t8000",      // standard ID > 0x7FF
        b"T200000000", // extended ID > 29 bits
        b"t123200",    // one data byte missing
        b"t1231001",   // odd digits
        b"t12310011A", // 5 extra digits
        b"r1238AA",    // RTR with data
    ];
    for b in bad {
        assert!(
            Response::decode(
                Line {
                    body: b,
                    terminator: CR
                },
                true
            )
            .is_err(),
            "{}",
            String::from_utf8_lossy(b)
        );
        assert!(Command::decode(b, &Dialect::default()).is_err());
    }
    // Commands never carry a timestamp.
    assert_eq!(
        Command::decode(b"t12300001", &Dialect::default()),
        Err(SlcanError::Length)
    );
}

/// Timestamps are taken only when the host switched them on: otherwise 4 extra hex digits make
/// the line malformed (counted, skipped), never a timestamp and never a value.
#[test]
fn extra_digits_without_timestamps_are_malformed() {
    let line = b"t0006018A3C7AD838ABCD\r";
    let mut s = HostScanner::<64>::new();
    let mut got = Vec::new();
    s.feed(line, |r| got.push(format!("{r:?}")));
    assert!(got.is_empty(), "{got:?}");
    assert_eq!(s.stats().malformed.bytes, line.len() as u64);
    // The same bytes with timestamps on: a frame and its timestamp.
    let mut s = HostScanner::<64>::new();
    s.set_timestamps(true);
    let mut n = 0;
    s.feed(line, |r| {
        assert!(matches!(
            r,
            Response::Frame {
                timestamp: Some(0xABCD),
                ..
            }
        ));
        n += 1;
    });
    assert_eq!(n, 1);
    // And a well-formed frame line without timestamp is a frame either way.
    let mut s = HostScanner::<64>::new();
    s.feed(b"t0006018A3C7AD838\r", |r| {
        assert!(matches!(
            r,
            Response::Frame {
                timestamp: None,
                ..
            }
        ));
        n += 1;
    });
    assert_eq!(n, 2);
}
