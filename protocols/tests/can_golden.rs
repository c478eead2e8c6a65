//! Golden vectors for MIT mode (protocols.md §2.1) and ODrive CAN Simple (§2.2).

mod golden;

use conductor_protocols::can::CanFrame;
use conductor_protocols::mit_can::*;
use conductor_protocols::odrive_can::{self, *};
use embedded_can::Frame;
use golden::hex;

const AK80_9: Limits = Model::Ak80_9.limits();

#[test]
fn mit_command_vectors() {
    let cases = [
        (
            (0.0, 0.0, 0.0, 0.0, 0.0),
            (32767, 2047, 0, 0, 2047),
            "7F FF 7F F0 00 00 07 FF",
        ),
        (
            (1.0, 2.0, 10.0, 1.0, 0.5),
            (35388, 2129, 81, 819, 2104),
            "8A 3C 85 10 51 33 38 38",
        ),
        (
            (0.0, 0.0, 0.0, 1.0, 0.0),
            (32767, 2047, 0, 819, 2047),
            "7F FF 7F F0 00 33 37 FF",
        ),
        (
            (-1.0, 0.0, 20.0, 0.5, -2.0),
            (30146, 2047, 163, 409, 1820),
            "75 C2 7F F0 A3 19 97 1C",
        ),
    ];
    for ((p, v, kp, kd, t), (ip, iv, ikp, ikd, it), bytes) in cases {
        let c = Command { p, v, kp, kd, t };
        let ints = c.to_ints(&AK80_9).unwrap();
        assert_eq!(
            ints,
            CommandInts {
                p: ip,
                v: iv,
                kp: ikp,
                kd: ikd,
                t: it
            }
        );
        assert_eq!(c.encode(&AK80_9).unwrap().to_vec(), hex(bytes));
        assert_eq!(CommandInts::unpack(&ints.pack()), ints);
    }
}

#[test]
fn mit_extremes_and_clamping() {
    let max = Command {
        p: 12.5,
        v: 50.0,
        kp: 500.0,
        kd: 5.0,
        t: 18.0,
    };
    assert_eq!(max.encode(&AK80_9).unwrap(), [0xFF; 8]);
    let min = Command {
        p: -12.5,
        v: -50.0,
        kp: 0.0,
        kd: 0.0,
        t: -18.0,
    };
    assert_eq!(min.encode(&AK80_9).unwrap(), [0x00; 8]);
    let beyond = Command {
        p: 100.0,
        v: 1e9,
        kp: 1e4,
        kd: 99.0,
        t: 1e3,
    };
    assert_eq!(beyond.encode(&AK80_9).unwrap(), [0xFF; 8]);
    let nan = Command {
        p: f32::NAN,
        ..Default::default()
    };
    assert_eq!(nan.encode(&AK80_9), Err(MitError::NotFinite));
}

/// The CubeMars manual's float_to_uint uses (1<<bits)/span, so x_max maps to 2^bits and the
/// 12-bit field overflows to 0; Katz's (2^bits - 1) keeps it at 0xFFF.
#[test]
fn katz_mapping_does_not_overflow_where_the_manual_does() {
    let manual = |x: f32, min: f32, max: f32, bits: u32| {
        ((x - min) * ((1u32 << bits) as f32 / (max - min))) as u32
    };
    assert_eq!(manual(50.0, -50.0, 50.0, 12), 4096); // does not fit 12 bits
    assert_eq!(float_to_uint(50.0, AK80_9.v, 12), 4095);
}

#[test]
fn mit_special_frames_and_collision_guard() {
    let f: CanFrame = enter_frame(1).unwrap();
    assert_eq!(
        (f.raw_id(), f.data()),
        (1, &hex("FF FF FF FF FF FF FF FC")[..])
    );
    let f: CanFrame = exit_frame(1).unwrap();
    assert_eq!(f.data()[7], 0xFD);
    let f: CanFrame = zero_frame(1).unwrap();
    assert_eq!(f.data()[7], 0xFE);
    assert_eq!(
        decode_command(&hex("FF FF FF FF FF FF FF FC"), &AK80_9),
        Ok(MotorCommand::Special(SpecialCommand::Enter))
    );
    assert_eq!(
        decode_command(&hex("FF FF FF FF FF FF FF FD"), &AK80_9),
        Ok(MotorCommand::Special(SpecialCommand::Exit))
    );
    assert_eq!(
        decode_command(&hex("FF FF FF FF FF FF FF FE"), &AK80_9),
        Ok(MotorCommand::Special(SpecialCommand::Zero))
    );
    // All maxima with torque quantising into FFC..=FFE would alias a special frame.
    let l = AK80_9;
    for t_int in [0xFFCu16, 0xFFD, 0xFFE] {
        let t = uint_to_float(t_int, l.t, 12) + 0.001; // lands inside step t_int
        assert_eq!(float_to_uint(t, l.t, 12), t_int);
        let c = Command {
            p: 12.5,
            v: 50.0,
            kp: 500.0,
            kd: 5.0,
            t,
        };
        let data = c.encode(&l).unwrap();
        assert_eq!(data[..7], [0xFF; 7]);
        assert_eq!(data[7], 0xFB);
        assert!(matches!(
            decode_command(&data, &l),
            Ok(MotorCommand::Control(_))
        ));
    }
    assert!(matches!(
        enter_frame::<CanFrame>(0x800),
        Err(MitError::InvalidId(0x800))
    ));
}

#[test]
fn mit_reply_vector() {
    let r = Reply::decode(&hex("01 8A 3C 7A D8 38"), &AK80_9).unwrap();
    assert_eq!(r.motor_id, 1);
    assert_eq!(
        ReplyInts::unpack(&hex("01 8A 3C 7A D8 38")).unwrap(),
        ReplyInts {
            motor_id: 1,
            p: 35388,
            v: 1965,
            t: 2104
        }
    );
    // Expected values from protocols.md, printed to 5 decimals: half a unit in the last place.
    assert!((r.p - 0.99966).abs() <= 5e-6, "{}", r.p);
    assert!((r.v - -2.01465).abs() <= 5e-6, "{}", r.v);
    assert!((r.t - 0.49670).abs() <= 5e-6, "{}", r.t);
    assert_eq!(r.extra, None);
    let r8 = Reply::decode(&hex("01 8A 3C 7A D8 38 2D 06"), &AK80_9).unwrap();
    assert_eq!(
        r8.extra,
        Some(ReplyExtra {
            temperature: 0x2D,
            fault: Some(Fault::MotorOverTemperature)
        })
    );
    assert_eq!(
        Reply::decode(&hex("01 8A 3C 7A D8"), &AK80_9),
        Err(MitError::Length(5))
    );
    assert_eq!(
        Reply::decode(&hex("01 8A 3C 7A D8 38 00"), &AK80_9),
        Err(MitError::Length(7))
    );
}

#[test]
fn mit_reply_encode_matches_vector() {
    let ints = ReplyInts {
        motor_id: 1,
        p: 35388,
        v: 1965,
        t: 2104,
    };
    assert_eq!(ints.pack().to_vec(), hex("01 8A 3C 7A D8 38"));
    let r = Reply::decode(&hex("01 8A 3C 7A D8 38"), &AK80_9).unwrap();
    let f: CanFrame = reply_frame(0, &r, &AK80_9).unwrap();
    // Dequantised values sit on grid points, so re-encoding may fall one step low through f32
    // rounding of the truncating map; it must never land further away.
    let back = ReplyInts::unpack(f.data()).unwrap();
    assert!(
        back.p.abs_diff(35388) <= 1 && back.v.abs_diff(1965) <= 1 && back.t.abs_diff(2104) <= 1
    );
    assert_eq!(f.raw_id(), 0);
}

#[test]
fn model_table() {
    let rows = [
        (Model::Ak10_9, 50.0, 65.0),
        (Model::Ak60_6, 45.0, 15.0),
        (Model::Ak70_10, 50.0, 25.0),
        (Model::Ak80_6, 76.0, 12.0),
        (Model::Ak80_9, 50.0, 18.0),
        (Model::Ak80_64, 8.0, 144.0),
    ];
    for (m, v, t) in rows {
        let l = m.limits();
        assert_eq!(
            (l.p.max, l.v.max, l.t.max, l.kp.max, l.kd.max),
            (12.5, v, t, 500.0, 5.0)
        );
        assert_eq!(
            (l.p.min, l.v.min, l.t.min, l.kp.min, l.kd.min),
            (-12.5, -v, -t, 0.0, 0.0)
        );
    }
    let bad = Limits {
        p: Range { min: 1.0, max: 1.0 },
        ..AK80_9
    };
    assert_eq!(
        Command::default().encode(&bad),
        Err(MitError::InvalidLimits)
    );
}

fn odrive(node: u8, m: &Message) -> (u32, Vec<u8>) {
    let f = to_can_frame(node, m).unwrap();
    (f.raw_id(), f.data().to_vec())
}

#[test]
fn odrive_vectors() {
    assert_eq!(can_id(1, CmdId::SetInputPos), Ok(0x2C));
    assert_eq!(
        odrive(
            1,
            &Message::SetAxisState {
                requested_state: axis_state::CLOSED_LOOP_CONTROL
            }
        ),
        (0x027, hex("08 00 00 00 00 00 00 00"))
    );
    assert_eq!(
        odrive(
            1,
            &Message::SetControllerMode {
                control_mode: control_mode::POSITION,
                input_mode: input_mode::PASSTHROUGH
            }
        ),
        (0x02B, hex("03 00 00 00 01 00 00 00"))
    );
    assert_eq!(
        odrive(
            1,
            &Message::SetInputPos {
                pos: 1.5,
                vel_ff: 0.5,
                torque_ff: -0.25
            }
        ),
        (0x02C, hex("00 00 C0 3F F4 01 06 FF"))
    );
    assert_eq!(
        odrive(
            0,
            &Message::SetInputVel {
                vel: 3.0,
                torque_ff: 0.0
            }
        ),
        (0x00D, hex("00 00 40 40 00 00 00 00"))
    );
    assert_eq!(
        Message::decode(CmdId::GetEncoderEstimates, &hex("00 00 10 40 00 00 00 BF")),
        Ok(Message::GetEncoderEstimates {
            pos: 2.25,
            vel: -0.5
        })
    );
    assert_eq!(
        Message::decode(CmdId::Heartbeat, &hex("00 00 00 00 08 00 01 00")),
        Ok(Message::Heartbeat {
            axis_error: 0,
            axis_state: 8,
            procedure_result: 0,
            trajectory_done: true
        })
    );
}

/// protocols.md §0.8: truncating 0.5/0.001 gives F3 01 and -0.25/0.001 gives 07 FF.
#[test]
fn odrive_rounds_where_truncation_is_wrong() {
    assert_eq!((0.5f32 / 0.001) as i16, 499);
    assert_eq!(hex("F3 01"), 499i16.to_le_bytes().to_vec());
    let (_, d) = odrive(
        1,
        &Message::SetInputPos {
            pos: 0.0,
            vel_ff: 0.5,
            torque_ff: -0.25,
        },
    );
    assert_eq!(d[4..], hex("F4 01 06 FF")[..]);
    assert_eq!(
        to_can_frame(
            1,
            &Message::SetInputPos {
                pos: 0.0,
                vel_ff: 40.0,
                torque_ff: 0.0
            }
        ),
        Err(OdriveError::OutOfRange)
    );
    assert_eq!(
        to_can_frame(1, &Message::SetInputTorque { torque: f32::NAN }),
        Err(OdriveError::OutOfRange)
    );
    assert_eq!(
        to_can_frame(64, &Message::Estop),
        Err(OdriveError::NodeId(64))
    );
}

#[test]
fn odrive_frames_and_requests() {
    let req: CanFrame = request_frame(3, CmdId::GetEncoderEstimates).unwrap();
    assert!(req.is_remote_frame());
    assert_eq!(req.raw_id(), 3 << 5 | 0x09);
    assert_eq!(odrive_can::decode_frame(&req), Err(OdriveError::Remote));
    let f: CanFrame = odrive_can::frame(
        5,
        &Message::GetIq {
            setpoint: 1.0,
            measured: 0.75,
        },
    )
    .unwrap();
    assert_eq!(
        odrive_can::decode_frame(&f),
        Ok((
            5,
            Message::GetIq {
                setpoint: 1.0,
                measured: 0.75
            }
        ))
    );
    assert_eq!(odrive(1, &Message::Estop).1.len(), 0);
    assert_eq!(odrive(1, &Message::Reboot { action: 1 }).1, vec![1]);
    assert_eq!(odrive(1, &Message::ClearErrors { identify: 0 }).1, vec![0]);
    assert_eq!(
        odrive(1, &Message::SetInputTorque { torque: 1.0 }).1,
        hex("00 00 80 3F 00 00 00 00")
    );
    let odd = CanFrame::standard(1 << 5 | 0x08, &[]).unwrap();
    assert_eq!(
        odrive_can::decode_frame(&odd),
        Err(OdriveError::UnknownId(0x28))
    );
    let short = CanFrame::standard(1 << 5 | 0x09, &[0; 4]).unwrap();
    assert_eq!(
        odrive_can::decode_frame(&short),
        Err(OdriveError::Length { needed: 8, got: 4 })
    );
}
