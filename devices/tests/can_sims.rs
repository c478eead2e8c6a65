//! The CAN motor simulators are as strict as their firmware: an MIT-mode motor ignores
//! commands outside motor mode, starts motor mode with no torque, and goes limp and refuses
//! Enter on a fault; an ODrive axis with an error stays IDLE until Clear_Errors, and keeps an
//! input written while IDLE. Sans-IO: frames are fed with explicit times.

use conductor_devices::protocol_stage::mit_limits;
use conductor_devices::sim::can_motors::{CanNode, MitMotorSim, OdriveAxisSim};
use conductor_protocols::can::CanFrame;
use conductor_protocols::mit_can::{self, Command, Limits, Reply, SpecialCommand};
use conductor_protocols::odrive_can::{self, axis_state, CmdId, Message};
use embedded_can::Frame;

const MS: u64 = 1_000_000;
const S: u64 = 1_000_000_000;

fn limits() -> Limits {
    mit_limits("ak80-9").unwrap()
}

/// Feeds `f` to `node` at `t`; returns its answers.
fn send(node: &mut dyn CanNode, f: &CanFrame, t: u64) -> Vec<CanFrame> {
    let mut out = Vec::new();
    node.on_frame(f, t, &mut out);
    out
}

fn special(id: u16, which: SpecialCommand) -> CanFrame {
    mit_can::special_frame(id, which).unwrap()
}

fn cmd(id: u16, p: f32, kp: f32, kd: f32) -> CanFrame {
    let c = Command {
        p,
        v: 0.0,
        kp,
        kd,
        t: 0.0,
    };
    mit_can::command(id, &c, &limits()).unwrap()
}

/// The one reply to a frame, decoded.
fn reply(out: &[CanFrame]) -> (Reply, usize) {
    assert_eq!(out.len(), 1, "one reply per frame: {out:?}");
    (
        Reply::decode(out[0].data(), &limits()).unwrap(),
        out[0].data().len(),
    )
}

#[test]
fn mit_commands_are_ignored_until_enter_and_enter_starts_with_no_torque() {
    let mut m = MitMotorSim::new(1, limits(), 0, false);
    // Before Enter: every frame is answered, commands are ignored and counted.
    let (r, len) = reply(&send(&mut m, &cmd(1, 1.0, 20.0, 1.0), 0));
    assert_eq!((r.motor_id, len), (1, 6));
    reply(&send(&mut m, &cmd(1, 1.0, 20.0, 1.0), S));
    assert_eq!(m.ignored(), 2);
    assert_eq!(m.position(), 0.0, "1 s after a command outside motor mode");
    let snap = m.snapshot();
    assert_eq!((snap.enabled, snap.ignored, snap.fault), (false, 2, 0));
    // Enter: motor mode with a zero command, no torque.
    reply(&send(&mut m, &special(1, SpecialCommand::Enter), S));
    assert!(m.enabled());
    assert_eq!(m.command(), Command::default());
    // Polling with Enter 1 s later: it has not moved.
    let (r, _) = reply(&send(&mut m, &special(1, SpecialCommand::Enter), 2 * S));
    assert!(r.p.abs() < 1e-3, "{r:?}");
    // A command moves it (the reply shows the state before the frame is applied).
    reply(&send(&mut m, &cmd(1, 1.0, 20.0, 1.0), 2 * S));
    let (r, _) = reply(&send(&mut m, &cmd(1, 1.0, 20.0, 1.0), 4 * S));
    assert!((r.p - 1.0).abs() < 0.01, "{r:?}");
    assert_eq!(m.ignored(), 2);
    // Enter again does not keep the old command: a command towards 0 given 1 ms before it
    // is dropped; the joint coasts (no torque) on the ~1.8 rad/s that 1 ms of 18 N·m gave
    // it (0.36 rad at b/J = 5/s) and stops there, far from 0.
    reply(&send(&mut m, &cmd(1, 0.0, 20.0, 1.0), 4 * S));
    reply(&send(
        &mut m,
        &special(1, SpecialCommand::Enter),
        4 * S + MS,
    ));
    assert_eq!(m.command(), Command::default());
    let (r, _) = reply(&send(&mut m, &special(1, SpecialCommand::Enter), 6 * S));
    assert!(r.p > 0.5, "{r:?}");
    // Exit: limp, and commands are ignored again.
    reply(&send(&mut m, &special(1, SpecialCommand::Exit), 6 * S));
    reply(&send(&mut m, &cmd(1, -1.0, 20.0, 1.0), 6 * S));
    let (r2, _) = reply(&send(&mut m, &cmd(1, -1.0, 20.0, 1.0), 8 * S));
    assert!((r2.p - r.p).abs() < 0.01, "{r:?} {r2:?}");
    assert_eq!(m.ignored(), 4);
    assert!(!m.enabled());
}

#[test]
fn mit_fault_makes_it_limp_refuses_enter_and_shows_in_the_long_reply() {
    let mut m = MitMotorSim::new(2, limits(), 0, true);
    reply(&send(&mut m, &special(2, SpecialCommand::Enter), 0));
    reply(&send(&mut m, &cmd(2, 1.0, 20.0, 1.0), 0));
    let (r, len) = reply(&send(&mut m, &cmd(2, 1.0, 20.0, 1.0), S));
    assert_eq!(len, 8);
    let extra = r.extra.unwrap();
    assert_eq!((extra.temperature, extra.fault), (40, None));
    // FET over-temperature (5), at 95 °C.
    m.set_temperature(95);
    m.inject_fault(5);
    assert!(!m.enabled());
    assert_eq!(m.command(), Command::default());
    assert_eq!((m.snapshot().fault, m.fault()), (5, 5));
    let out = send(&mut m, &special(2, SpecialCommand::Enter), S);
    assert_eq!(out[0].data()[6..], [95, 5]);
    assert!(!m.enabled(), "Enter refused while faulted");
    let (r, _) = reply(&send(&mut m, &cmd(2, -1.0, 20.0, 1.0), 2 * S));
    assert_eq!(
        r.extra.unwrap().fault,
        Some(mit_can::Fault::FetOverTemperature)
    );
    assert_eq!(m.ignored(), 1);
    // Cleared: no code, still limp until Enter.
    m.clear_fault();
    let out = send(&mut m, &cmd(2, -1.0, 20.0, 1.0), 2 * S);
    assert_eq!(out[0].data()[7], 0);
    assert_eq!(m.ignored(), 2);
    reply(&send(&mut m, &special(2, SpecialCommand::Enter), 2 * S));
    assert!(m.enabled());
    // The 6-byte reply of Katz firmware cannot show a fault: only the limpness tells.
    let mut short = MitMotorSim::new(3, limits(), 0, false);
    reply(&send(&mut short, &special(3, SpecialCommand::Enter), 0));
    assert!(short.set_fault(1), "through the CanNode trait");
    let (r, len) = reply(&send(&mut short, &special(3, SpecialCommand::Enter), 0));
    assert_eq!((len, r.extra), (6, None));
    assert!(!short.enabled());
    assert!(!short.set_fault(300), "not a fault code");
    assert!(short.reset_fault());
    assert_eq!(short.snapshot().fault, 0);
}

fn od(node: u8, m: &Message) -> CanFrame {
    odrive_can::to_can_frame(node, m).unwrap()
}

fn ask(a: &mut OdriveAxisSim, cmd: CmdId, t: u64) -> Message {
    let f: CanFrame = odrive_can::request_frame(a.snapshot().id, cmd).unwrap();
    let out = send(a, &f, t);
    assert_eq!(out.len(), 1);
    odrive_can::decode_frame(&out[0]).unwrap().1
}

fn closed_loop() -> Message {
    Message::SetAxisState {
        requested_state: axis_state::CLOSED_LOOP_CONTROL,
    }
}

#[test]
fn odrive_error_idles_the_axis_until_clear_errors() {
    let mut a = OdriveAxisSim::new(3, 100, 0);
    assert_eq!(a.state(), axis_state::IDLE, "starts IDLE");
    assert!(send(&mut a, &od(3, &closed_loop()), 0).is_empty());
    assert_eq!(a.state(), axis_state::CLOSED_LOOP_CONTROL);
    a.inject_error(0x800);
    assert_eq!(a.state(), axis_state::IDLE);
    assert_eq!(a.snapshot().fault, 0x800);
    match ask(&mut a, CmdId::Heartbeat, MS) {
        Message::Heartbeat {
            axis_error,
            axis_state,
            ..
        } => assert_eq!((axis_error, axis_state), (0x800, 1)),
        other => panic!("{other:?}"),
    }
    match ask(&mut a, CmdId::GetError, MS) {
        Message::GetError { active_errors, .. } => assert_eq!(active_errors, 0x800),
        other => panic!("{other:?}"),
    }
    // The cyclic heartbeat reports it too.
    let mut out = Vec::new();
    a.poll(2 * MS, &mut out);
    let hb = odrive_can::decode_frame(&out[0]).unwrap().1;
    assert!(
        matches!(
            hb,
            Message::Heartbeat {
                axis_error: 0x800,
                ..
            }
        ),
        "{hb:?}"
    );
    // Closed loop is refused while the error is set.
    send(&mut a, &od(3, &closed_loop()), 3 * MS);
    assert_eq!(a.state(), axis_state::IDLE);
    assert_eq!((a.ignored(), a.snapshot().ignored), (1, 1));
    // Clear_Errors, then closed loop works.
    send(
        &mut a,
        &od(3, &Message::ClearErrors { identify: 0 }),
        4 * MS,
    );
    assert_eq!((a.axis_error(), a.state()), (0, axis_state::IDLE));
    send(&mut a, &od(3, &closed_loop()), 5 * MS);
    assert_eq!(a.state(), axis_state::CLOSED_LOOP_CONTROL);
    // Through the CanNode trait, as conductor-sim's `fault`/`clear` do.
    assert!(a.set_fault(0x1));
    assert!(!a.snapshot().enabled);
    assert!(a.reset_fault());
    assert_eq!(a.snapshot().fault, 0);
}

#[test]
fn odrive_input_written_while_idle_is_kept_and_followed_on_closed_loop() {
    let mut a = OdriveAxisSim::new(4, 0, 0);
    let input = Message::SetInputPos {
        pos: 2.0,
        vel_ff: 0.0,
        torque_ff: 0.0,
    };
    send(&mut a, &od(4, &input), 0);
    assert_eq!(a.input().0, 2.0);
    match ask(&mut a, CmdId::GetEncoderEstimates, S) {
        Message::GetEncoderEstimates { pos, .. } => assert_eq!(pos, 0.0, "IDLE: not moving"),
        other => panic!("{other:?}"),
    }
    send(&mut a, &od(4, &closed_loop()), S);
    match ask(&mut a, CmdId::GetEncoderEstimates, 2 * S) {
        Message::GetEncoderEstimates { pos, .. } => {
            assert!((pos - 2.0).abs() < 1e-3, "jumped to the stale input: {pos}")
        }
        other => panic!("{other:?}"),
    }
}
