//! Round-trip property tests for every encoder/decoder pair, and no-panic tests on arbitrary
//! input for every decoder.

use conductor_protocols::can::CanFrame;
use conductor_protocols::dynamixel1 as d1;
use conductor_protocols::dynamixel2::{self as d2, stuffing};
use conductor_protocols::mit_can::{
    self, Command as MitCommand, CommandInts, Limits, Model, Reply, ReplyInts,
};
use conductor_protocols::odrive_can::{self, CmdId, Message};
use conductor_protocols::slcan::{self, Bitrate, Command, Dialect, Line, Response};
use embedded_can::{ExtendedId, Frame, StandardId};
use proptest::prelude::*;

/// Bytes biased towards the stuffing pattern's values.
fn stuffy_bytes(max: usize) -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(
        prop_oneof![3 => Just(0xFFu8), 2 => Just(0xFD), 1 => Just(0x00), 4 => any::<u8>()],
        0..max,
    )
}

fn device_id() -> impl Strategy<Value = u8> {
    0u8..=d2::MAX_DEVICE_ID
}

fn can_frame() -> impl Strategy<Value = CanFrame> {
    let id = prop_oneof![
        (0u16..=0x7FF).prop_map(|i| embedded_can::Id::from(StandardId::new(i).unwrap())),
        (0u32..=0x1FFF_FFFF).prop_map(|i| embedded_can::Id::from(ExtendedId::new(i).unwrap())),
    ];
    (id, any::<bool>(), prop::collection::vec(any::<u8>(), 0..=8)).prop_map(|(id, remote, data)| {
        if remote {
            CanFrame::new_remote(id, data.len()).unwrap()
        } else {
            CanFrame::new(id, &data).unwrap()
        }
    })
}

proptest! {
    #[test]
    fn stuffing_round_trips(src in stuffy_bytes(64)) {
        let mut out = vec![0u8; 2 * src.len() + 1];
        let n = stuffing::stuff(&src, &mut out).unwrap();
        prop_assert_eq!(n, stuffing::stuffed_len(&src));
        // After stuffing, every FF FF FD is followed by FD.
        for w in 0..n.saturating_sub(2) {
            if out[w..w + 3] == [0xFF, 0xFF, 0xFD] {
                prop_assert_eq!(out.get(w + 3), Some(&0xFD));
            }
        }
        let m = stuffing::unstuff_in_place(&mut out[..n]);
        prop_assert_eq!(&out[..m], &src[..]);
    }

    #[test]
    fn dxl2_write_round_trips(id in device_id(), addr in any::<u16>(), data in stuffy_bytes(40)) {
        let mut buf = [0u8; 128];
        let n = d2::write(&mut buf, id, addr, &data).unwrap();
        prop_assert_eq!(d2::check_frame(&buf[..n]), Ok(n));
        let p = d2::parse_in_place(&mut buf[..n]).unwrap();
        prop_assert_eq!((p.id, p.instruction, p.wire_len), (id, 0x03, n));
        prop_assert_eq!(&p.params[..2], &addr.to_le_bytes()[..]);
        prop_assert_eq!(&p.params[2..], &data[..]);
    }

    #[test]
    fn dxl2_status_round_trips(id in device_id(), err in any::<u8>(), data in stuffy_bytes(40)) {
        let mut buf = [0u8; 128];
        let n = d2::status(&mut buf, id, err, &data).unwrap();
        let p = d2::parse_in_place(&mut buf[..n]).unwrap();
        let s = d2::Status::from_packet(&p).unwrap();
        prop_assert_eq!((s.id, s.error, s.data), (id, d2::ErrorByte(err), &data[..]));
    }

    #[test]
    fn dxl2_sync_write_round_trips(addr in any::<u16>(), entries in prop::collection::btree_map(device_id(), any::<[u8; 4]>(), 1..20)) {
        let mut buf = [0u8; 512];
        let list: Vec<(u8, &[u8])> = entries.iter().map(|(i, d)| (*i, &d[..])).collect();
        let n = d2::sync_write(&mut buf, addr, 4, list.iter().copied()).unwrap();
        let p = d2::parse_in_place(&mut buf[..n]).unwrap();
        prop_assert_eq!((p.id, p.instruction), (d2::BROADCAST_ID, 0x83));
        prop_assert_eq!(&p.params[..4], &[addr.to_le_bytes(), 4u16.to_le_bytes()].concat()[..]);
        let body: Vec<u8> = entries.iter().flat_map(|(i, d)| std::iter::once(*i).chain(d.iter().copied())).collect();
        prop_assert_eq!(&p.params[4..], &body[..]);
        let req = d2::Request::from_packet(&p).unwrap();
        prop_assert_eq!(req.sync_write_entries().collect::<Vec<_>>(), list);
    }

    #[test]
    fn dxl2_bulk_write_round_trips(entries in prop::collection::btree_map(device_id(), (any::<u16>(), stuffy_bytes(12)), 1..12)) {
        let list: Vec<_> = entries.iter().map(|(&id, (addr, data))| d2::BulkWriteEntry { id, addr: *addr, data }).collect();
        let mut buf = [0u8; 512];
        let n = d2::bulk_write(&mut buf, list.iter().copied()).unwrap();
        let p = d2::parse_in_place(&mut buf[..n]).unwrap();
        let req = d2::Request::from_packet(&p).unwrap();
        prop_assert_eq!(req.bulk_write_entries().collect::<Vec<_>>(), list);
    }

    #[test]
    fn dxl2_bulk_read_round_trips(entries in prop::collection::btree_map(device_id(), (any::<u16>(), any::<u16>()), 1..20)) {
        let mut buf = [0u8; 512];
        let list: Vec<_> = entries.iter().map(|(&id, &(addr, len))| d2::BulkReadEntry { id, addr, len }).collect();
        let n = d2::fast_bulk_read(&mut buf, list.iter().copied()).unwrap();
        let p = d2::parse_in_place(&mut buf[..n]).unwrap();
        prop_assert_eq!(p.instruction, 0x9A);
        let decoded: Vec<_> = p.params.chunks(5).map(|c| d2::BulkReadEntry {
            id: c[0], addr: u16::from_le_bytes([c[1], c[2]]), len: u16::from_le_bytes([c[3], c[4]]),
        }).collect();
        prop_assert_eq!(&decoded, &list);
        let req = d2::Request::from_packet(&p).unwrap();
        prop_assert_eq!(req.bulk_read_entries().collect::<Vec<_>>(), list);
    }

    #[test]
    fn dxl2_fast_reply_round_trips(slices in prop::collection::btree_map(device_id(), (any::<u8>(), stuffy_bytes(8)), 1..12)) {
        let list: Vec<_> = slices.iter().map(|(&id, (e, d))| d2::FastStatusSlice { error: *e, id, data: d }).collect();
        let mut buf = [0u8; 512];
        let n = d2::fast_status(&mut buf, &list).unwrap();
        let p = d2::parse_in_place(&mut buf[..n]).unwrap();
        let reply = d2::FastReply::from_packet(&p).unwrap();
        let got: Vec<_> = reply.slices(list.iter().map(|s| s.data.len())).collect::<Result<_, _>>().unwrap();
        prop_assert_eq!(got.len(), list.len());
        for (g, s) in got.iter().zip(&list) {
            prop_assert_eq!((g.id, g.error.0, g.data), (s.id, s.error, s.data));
        }
    }

    #[test]
    fn dxl1_round_trips(id in 0u8..=d1::MAX_DEVICE_ID, addr in any::<u8>(), data in prop::collection::vec(any::<u8>(), 0..100)) {
        let mut buf = [0u8; 128];
        let n = d1::write(&mut buf, id, addr, &data).unwrap();
        let (p, m) = d1::parse(&buf[..n]).unwrap();
        prop_assert_eq!((p.id, p.code, m), (id, 0x03, n));
        prop_assert_eq!(p.params[0], addr);
        prop_assert_eq!(&p.params[1..], &data[..]);
        let n = d1::status(&mut buf, id, d1::ErrorBits(0x24), &data).unwrap();
        let (p, _) = d1::parse(&buf[..n]).unwrap();
        let s = d1::Status::from_packet(&p);
        prop_assert_eq!((s.id, s.error, s.data), (id, d1::ErrorBits(0x24), &data[..]));
    }

    #[test]
    fn mit_ints_pack_round_trip(p in any::<u16>(), v in 0u16..4096, kp in 0u16..4096, kd in 0u16..4096, t in 0u16..4096, id in any::<u8>()) {
        let c = CommandInts { p, v, kp, kd, t };
        prop_assert_eq!(CommandInts::unpack(&c.pack()), c);
        let r = ReplyInts { motor_id: id, p, v, t };
        prop_assert_eq!(ReplyInts::unpack(&r.pack()).unwrap(), r);
    }

    /// Quantisation error of the truncating map is below one step, span/(2^bits - 1), plus the
    /// f32 rounding of the two conversions (a few ulps of the range end, bounded by 1e-5·span).
    #[test]
    fn mit_command_quantisation_error_is_below_one_step(
        p in -12.5f32..=12.5, v in -50f32..=50.0, kp in 0f32..=500.0, kd in 0f32..=5.0, t in -18f32..=18.0,
    ) {
        let l = Model::Ak80_9.limits();
        let c = MitCommand { p, v, kp, kd, t };
        let data = c.encode(&l).unwrap();
        let mit_can::MotorCommand::Control(back) = mit_can::decode_command(&data, &l).unwrap() else {
            return Err(TestCaseError::fail("decoded as a special frame"));
        };
        let step = |r: mit_can::Range, bits: u32| (r.max - r.min) / ((1u32 << bits) - 1) as f32 + 1e-5 * (r.max - r.min);
        prop_assert!((back.p - p).abs() <= step(l.p, 16));
        prop_assert!((back.v - v).abs() <= step(l.v, 12));
        prop_assert!((back.kp - kp).abs() <= step(l.kp, 12));
        prop_assert!((back.kd - kd).abs() <= step(l.kd, 12));
        prop_assert!((back.t - t).abs() <= step(l.t, 12));
    }

    #[test]
    fn mit_reply_round_trip(id in any::<u8>(), p in -12.5f32..=12.5, v in -76f32..=76.0, t in -12f32..=12.0, extra in prop::option::of((any::<u8>(), 0u8..=10))) {
        let l = Model::Ak80_6.limits();
        let r = Reply { motor_id: id, p, v, t, extra: extra.map(|(temperature, code)| mit_can::ReplyExtra { temperature, fault: mit_can::Fault::from_code(code) }) };
        let f: CanFrame = mit_can::reply_frame(0, &r, &l).unwrap();
        let back = Reply::decode(f.data(), &l).unwrap();
        let step = |r: mit_can::Range, bits: u32| (r.max - r.min) / ((1u32 << bits) - 1) as f32 + 1e-5 * (r.max - r.min);
        prop_assert_eq!((back.motor_id, back.extra), (id, r.extra));
        prop_assert!((back.p - p).abs() <= step(l.p, 16));
        prop_assert!((back.v - v).abs() <= step(l.v, 12));
        prop_assert!((back.t - t).abs() <= step(l.t, 12));
    }

    #[test]
    fn odrive_round_trips(node in 0u8..64, a in -1e6f32..1e6, b in -1e6f32..1e6, ff1 in -32.0f32..32.0, ff2 in -32.0f32..32.0, u in any::<u32>(), w in any::<u32>(), byte in any::<u8>()) {
        let msgs = [
            Message::SetAxisState { requested_state: u },
            Message::SetControllerMode { control_mode: u, input_mode: w },
            Message::SetInputVel { vel: a, torque_ff: b },
            Message::SetInputTorque { torque: a },
            Message::GetEncoderEstimates { pos: a, vel: b },
            Message::GetError { active_errors: u, disarm_reason: w },
            Message::Heartbeat { axis_error: u, axis_state: byte, procedure_result: byte ^ 0x55, trajectory_done: u & 1 == 1 },
            Message::Reboot { action: byte },
            Message::Address { node_id: byte, serial_number: (u as u64) << 16 | (w as u64 & 0xFFFF) },
            Message::TxSdo { opcode: byte, endpoint_id: w as u16, value: u.to_le_bytes() },
            Message::GetPowers { electrical: a, mechanical: b },
            Message::Estop,
        ];
        for m in msgs {
            let f: CanFrame = odrive_can::frame(node, &m).unwrap();
            prop_assert_eq!(odrive_can::decode_frame(&f).unwrap(), (node, m));
        }
        // Feed-forward fields: rounded to the nearest 0.001 (error ≤ half a step plus f32 rounding).
        let m = Message::SetInputPos { pos: a, vel_ff: ff1, torque_ff: ff2 };
        let f: CanFrame = odrive_can::frame(node, &m).unwrap();
        let (_, Message::SetInputPos { pos, vel_ff, torque_ff }) = odrive_can::decode_frame(&f).unwrap() else {
            return Err(TestCaseError::fail("wrong message"));
        };
        prop_assert_eq!(pos, a);
        prop_assert!((vel_ff - ff1).abs() <= 0.0005 + 1e-5);
        prop_assert!((torque_ff - ff2).abs() <= 0.0005 + 1e-5);
    }

    #[test]
    fn slcan_frames_round_trip(f in can_frame(), ts in prop::option::of(0u16..60000)) {
        let d = Dialect::default();
        let mut buf = [0u8; 40];
        let n = Command::Transmit(f).encode(&d, &mut buf).unwrap();
        prop_assert_eq!(buf[n - 1], slcan::CR);
        prop_assert_eq!(Command::decode(&buf[..n - 1], &d), Ok(Command::Transmit(f)));
        let n = Response::Frame { frame: f, timestamp: ts }.encode(&mut buf).unwrap();
        prop_assert!(n <= slcan::MAX_FRAME_LINE);
        let r = Response::decode(Line { body: &buf[..n - 1], terminator: slcan::CR }, true).unwrap();
        prop_assert_eq!(r, Response::Frame { frame: f, timestamp: ts });
    }

    #[test]
    fn slcan_commands_round_trip(code in 0u8..=9, lawicel in any::<bool>(), v in any::<u32>(), b0 in any::<u8>(), b1 in any::<u8>()) {
        let d = if lawicel { Dialect::LAWICEL } else { Dialect::CANABLE };
        let rate = Bitrate::from_code(code, &d).unwrap();
        prop_assert_eq!(rate.code(&d), Some(code));
        prop_assert_eq!(Bitrate::from_bps(rate.bps()), Some(rate));
        for cmd in [Command::Bitrate(rate), Command::AcceptanceCode(v), Command::AcceptanceMask(v), Command::Btr { btr0: b0, btr1: b1 }] {
            let mut buf = [0u8; 16];
            let n = cmd.encode(&d, &mut buf).unwrap();
            prop_assert_eq!(Command::decode(&buf[..n - 1], &d), Ok(cmd));
        }
    }

    #[test]
    fn decoders_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..80), lens in prop::collection::vec(0usize..20, 0..8)) {
        let mut copy = bytes.clone();
        let _ = d2::check_frame(&bytes);
        if let Ok(p) = d2::parse_in_place(&mut copy) {
            let _ = d2::Status::from_packet(&p).map(|s| d2::PingInfo::from_status(&s));
        }
        // Arbitrary parameters under every instruction code, as a simulator would see them.
        for inst in [0x01u8, 0x02, 0x03, 0x04, 0x06, 0x10, 0x20, 0x82, 0x83, 0x8A, 0x92, 0x93, 0x9A] {
            let p = d2::Packet { id: d2::BROADCAST_ID, instruction: inst, params: &bytes, wire_len: 0 };
            if let Ok(r) = d2::Request::from_packet(&p) {
                let _ = (r.sync_write_entries().count(), r.bulk_read_entries().count(), r.bulk_write_entries().count());
            }
        }
        // Fast reply splitting on arbitrary bodies (built as a checked packet first).
        let mut buf = [0u8; 256];
        if let Ok(n) = d2::status(&mut buf, 1, 0, &bytes) {
            buf[4] = d2::BROADCAST_ID;
            let c = d2::crc::crc16(&buf[..n - 2]).to_le_bytes();
            buf[n - 2..n].copy_from_slice(&c);
            if let Ok(p) = d2::parse_in_place(&mut buf[..n]) {
                let reply = d2::FastReply::from_packet(&p).unwrap();
                for _ in reply.slices(lens.iter().copied()) {}
            }
        }
        let _ = d1::parse(&bytes);
        let _ = Reply::decode(&bytes, &Model::Ak10_9.limits());
        let _ = mit_can::decode_command(&bytes, &Model::Ak10_9.limits());
        for code in 0..32 {
            if let Some(cmd) = CmdId::from_code(code) {
                let _ = Message::decode(cmd, &bytes);
            }
        }
        for d in [Dialect::LAWICEL, Dialect::CANABLE] {
            let _ = Command::decode(&bytes, &d);
        }
        let _ = Response::decode(Line { body: &bytes, terminator: slcan::CR }, true);
        let _ = Response::decode(Line { body: &bytes, terminator: slcan::BEL }, true);
        if bytes.len() >= 13 {
            let f = |i: usize| f32::from_le_bytes(bytes[i..i + 4].try_into().unwrap());
            let r = mit_can::Range { min: f(4), max: f(8) };
            let n = mit_can::float_to_uint(f(0), r, u32::from(bytes[12]));
            let _ = mit_can::uint_to_float(n, r, u32::from(bytes[12]));
        }
        let l = Limits { p: mit_can::Range { min: f32::NAN, max: 1.0 }, ..Model::Ak10_9.limits() };
        prop_assert_eq!(Reply::decode(&[0; 6], &l), Err(mit_can::MitError::InvalidLimits));
    }
}
