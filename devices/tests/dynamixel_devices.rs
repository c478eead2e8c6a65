//! The Dynamixel device stages on their own: what they request, how they read replies (units,
//! range checks, faults), how the X series' operating mode re-ranges the goal position, and
//! their safe actions.

use std::f64::consts::PI;

use conductor_devices::device::{
    dxl1_channel, x_channel, Dxl1Model, DxlXConfig, Dynamixel1, DynamixelX,
};
use conductor_devices::{
    Bounded, Credential, Device, Op, Reply, ReplyData, Request, SafeAction, TickCtx, Update,
};

const CTX: TickCtx = TickCtx {
    tick: 7,
    now_ns: 1_000,
};

fn ops(f: impl FnOnce(&mut Bounded<Request>)) -> Vec<Op> {
    let mut out = Bounded::with_capacity(16);
    f(&mut out);
    assert!(out.as_slice().iter().all(|r| r.cred == Credential::id(1)
        && r.tick == CTX.tick
        && r.t_request_ns == CTX.now_ns));
    out.as_slice().iter().map(|r| r.op).collect()
}

fn register(addr: u16, len: u8, value: i64) -> Reply {
    Reply::answer(
        Credential::id(1),
        Op::Read { addr, len },
        ReplyData::Register { addr, len, value },
        CTX.tick,
        500,
    )
}

fn updates(d: &mut impl Device, r: &Reply) -> Vec<Update> {
    let mut out = Bounded::with_capacity(8);
    d.reply(r, &mut out);
    out.as_slice().to_vec()
}

fn write(addr: u16, len: u8, value: i64) -> Op {
    Op::Write { addr, len, value }
}

#[test]
fn x_series_operating_mode_decides_the_goal_range() {
    let extended = DxlXConfig {
        operating_mode: 4,
        ..DxlXConfig::default()
    };
    // 10 rad = 6519 steps of 2π/4096 from the zero at 2048.
    let d = DynamixelX::new(Credential::id(1), DxlXConfig::default());
    assert_eq!(d.position_raw(10.0), 4095, "position mode: one turn");
    let mut d = DynamixelX::new(Credential::id(1), extended);
    assert_eq!(d.position_raw(10.0), 2048 + 6519, "extended position mode");
    // The servo reports position mode: the range follows what it reads.
    let u = updates(&mut d, &register(11, 1, 3));
    assert_eq!(u.len(), 1);
    assert_eq!(
        (u[0].channel, u[0].value),
        (x_channel::OPERATING_MODE, Some(3.0))
    );
    assert_eq!(d.position_raw(10.0), 4095);
    d.write(x_channel::GOAL_POSITION, 10.0, CTX);
    assert_eq!(ops(|o| d.flush(CTX, o)), [write(116, 4, 4095)]);
}

#[test]
fn x_series_reads_in_units_rejects_the_impossible_and_holds_the_last_position() {
    let mut d = DynamixelX::new(Credential::id(1), DxlXConfig::default());
    assert_eq!(
        ops(|o| d.safe(SafeAction::Hold, CTX, o)),
        [write(64, 1, 0)],
        "nothing to hold yet: torque off"
    );
    assert_eq!(
        ops(|o| d.sample(x_channel::POSITION, CTX, o)),
        [Op::Read { addr: 132, len: 4 }]
    );
    let u = updates(&mut d, &register(132, 4, 3072));
    assert_eq!(u.len(), 1);
    assert_eq!(
        (u[0].channel, u[0].fault, u[0].tick, u[0].t_sample_ns),
        (x_channel::POSITION, false, CTX.tick, 500)
    );
    // A quarter turn; the conversion is one multiplication, exact to an ulp or two.
    assert!((u[0].value.unwrap() - PI / 2.0).abs() < 1e-12);
    assert!((d.last(x_channel::POSITION).unwrap() - PI / 2.0).abs() < 1e-12);
    // -2 000 000 steps (two's complement, zero-extended) is past the 256-turn range: stale.
    let u = updates(&mut d, &register(132, 4, 0xFFE1_7B80));
    assert_eq!((u.len(), u[0].value), (1, None));
    assert_eq!(d.range_rejects(), 1);
    assert_eq!(
        ops(|o| d.safe(SafeAction::Hold, CTX, o)),
        [write(116, 4, 3072)],
        "hold writes the last good position as the goal"
    );
    // A device error marks the tick's values as faulty; a missing read makes them stale.
    updates(
        &mut d,
        &Reply {
            data: ReplyData::DeviceError { code: 0x80 },
            ..register(0, 0, 0)
        },
    );
    let u = updates(&mut d, &register(146, 1, 40));
    assert_eq!(
        (u[0].channel, u[0].value, u[0].fault),
        (x_channel::TEMPERATURE, Some(40.0), true)
    );
    let missing = Reply {
        data: ReplyData::Missing {
            op: Op::Read { addr: 128, len: 4 },
        },
        ..register(0, 0, 0)
    };
    let u = updates(&mut d, &missing);
    assert_eq!((u[0].channel, u[0].value), (x_channel::VELOCITY, None));
}

/// A position read at `t_ns` (the request's time).
fn position_at(raw: i64, t_ns: u64) -> Reply {
    Reply {
        t_sample_ns: t_ns,
        ..register(132, 4, raw)
    }
}

#[test]
fn a_position_the_servo_cannot_have_reached_is_held_back_until_the_next_reading_confirms_it() {
    let mut d = DynamixelX::new(Credential::id(1), DxlXConfig::default());
    let ms = 1_000_000;
    let value = |d: &mut DynamixelX, raw: i64, t: u64| {
        let u = updates(d, &position_at(raw, t));
        assert_eq!(u.len(), 1);
        u[0].value
    };
    assert!(value(&mut d, 3072, 0).is_some());
    // 80 turns in 4 ms: inside the register's ±256-turn range, but a status packet damaged
    // beyond what its CRC caught, not a servo that turns at 1 200 000 rpm.
    let damaged = 3072 + 80 * 4096 + 5;
    assert_eq!(value(&mut d, damaged, 4 * ms), None, "held back: stale");
    assert_eq!(d.range_rejects(), 1, "counted with the range rejects");
    // The next reading does not confirm it: it was damaged; the servo moved 8 steps.
    assert!(value(&mut d, 3080, 8 * ms).is_some());
    assert_eq!(
        ops(|o| d.safe(SafeAction::Hold, CTX, o)),
        [write(116, 4, 3080)],
        "the hold is where the servo is, never the damaged reading"
    );
    // At its top speed (±1023 × 0.229 rpm ≈ 16 000 steps/s) it travels 64 steps in 4 ms.
    assert!(value(&mut d, 3080 + 60, 12 * ms).is_some());
    // A real jump (turned by hand while limp and not read, say) is believed at the second
    // reading that agrees with it: one reading lost, none wrong.
    assert_eq!(value(&mut d, 9000, 16 * ms), None);
    assert!(value(&mut d, 9010, 20 * ms).is_some());
    assert_eq!(d.range_rejects(), 2);
    // A reading dated earlier than the last one (a late reply) gets the slack, not more.
    assert!(value(&mut d, 9010 - 300, 19 * ms).is_some());
    assert_eq!(value(&mut d, 9010 - 300 - 700, 21 * ms), None);
}

#[test]
fn protocol_1_servo_speaks_sign_magnitude_and_its_own_addresses() {
    let mut d = Dynamixel1::new(Credential::id(1), Dxl1Model::Ax, 512);
    let speed = 0.111 * 2.0 * PI / 60.0;
    assert_eq!(
        ops(|o| d.sample(dxl1_channel::VELOCITY, CTX, o)),
        [Op::Read { addr: 38, len: 2 }]
    );
    // Bit 10 set: 100 steps the other way.
    let u = updates(&mut d, &register(38, 2, 0x400 | 100));
    assert!((u[0].value.unwrap() + 100.0 * speed).abs() < 1e-12);
    // Moving Speed 0 means "full speed": the smallest speed written is 1 step.
    d.write(dxl1_channel::VELOCITY, 0.0, CTX);
    d.write(dxl1_channel::POSITION, 0.0, CTX);
    assert_eq!(
        ops(|o| d.flush(CTX, o)),
        [write(30, 2, 512), write(32, 2, 1)]
    );
    assert_eq!(
        ops(|o| d.safe(
            SafeAction::Setpoint {
                channel: dxl1_channel::POSITION,
                value: 0.0
            },
            CTX,
            o
        )),
        [write(30, 2, 512)]
    );
    // AX positions run 0..=1023 (300°): 1024 is damaged.
    let u = updates(&mut d, &register(36, 2, 1024));
    assert_eq!((u[0].channel, u[0].value), (dxl1_channel::POSITION, None));
    assert_eq!(d.range_rejects(), 1);
    assert_eq!(ops(|o| d.safe(SafeAction::Hold, CTX, o)), [write(24, 1, 0)]);
}

/// With the indirect layout the hardware_error channel comes back at an Indirect Data address:
/// its value still sets the device's fault status, in the same reply.
#[test]
fn hardware_error_read_through_indirect_data_sets_the_fault() {
    let mut d = DynamixelX::new(Credential::id(1), DxlXConfig::default());
    d.configure_reads(&[x_channel::POSITION, x_channel::HARDWARE_ERROR]);
    let at = d
        .read_address(x_channel::HARDWARE_ERROR)
        .expect("hardware_error is read");
    assert_ne!(at, 70, "read through Indirect Data");
    assert_eq!(d.status().fault, 0);
    // Overload (bit 5).
    let u = updates(&mut d, &register(at, 1, 0x20));
    assert_eq!(
        (u[0].channel, u[0].value),
        (x_channel::HARDWARE_ERROR, Some(32.0))
    );
    assert_eq!(d.status().fault, 0x20);
}

/// A servo on a perfect line, as the protocol stage hands its answers to the device: every
/// request answered at once from its registers, writes applied in order. `lose_torque_reads`
/// makes the line lose every reply that reads Torque Enable.
struct Servo {
    regs: std::collections::HashMap<u16, i64>,
    lose_torque_reads: bool,
    /// Unplugged: every read comes back missing, no write arrives.
    unplugged: bool,
}

impl Servo {
    fn new() -> Self {
        Self {
            // Where it stands, and Goal Position there (its power-on state: torque off).
            regs: [(132, 2300), (116, 2300)].into(),
            lose_torque_reads: false,
            unplugged: false,
        }
    }

    /// One tick `t` of `d` against the servo; `trip` trips it with a hold first.
    fn tick(&mut self, d: &mut DynamixelX, t: u64, trip: bool) -> Vec<Op> {
        let ctx = TickCtx {
            tick: t,
            now_ns: t * 4_000_000,
        };
        let mut out = Bounded::with_capacity(128);
        if trip {
            d.trip(SafeAction::Hold, ctx, &mut out);
        }
        d.flush(ctx, &mut out);
        let requests = out.as_slice().to_vec();
        let mut updates = Bounded::with_capacity(128);
        for r in &requests {
            let data = match r.op {
                _ if self.unplugged => ReplyData::Missing { op: r.op },
                Op::Ping => ReplyData::Ping {
                    model: Some(1020),
                    firmware: Some(45),
                },
                Op::Write { addr, value, .. } => {
                    self.regs.insert(addr, value);
                    continue;
                }
                Op::Read { addr: 64, .. } if self.lose_torque_reads => {
                    ReplyData::Missing { op: r.op }
                }
                Op::Read { addr, len } => ReplyData::Register {
                    addr,
                    len,
                    value: self.regs.get(&addr).copied().unwrap_or(0),
                },
                _ => continue,
            };
            d.reply(
                &Reply::answer(r.cred, r.op, data, ctx.tick, ctx.now_ns),
                &mut updates,
            );
        }
        requests.iter().map(|r| r.op).collect()
    }
}

/// An enable whose confirmation the line lost may still have switched the servo on: a trip
/// with a `hold` then holds it where it is (and the read-back says whether it is powered),
/// never lets go of a joint that may be carrying a load.
#[test]
fn a_trip_after_an_unconfirmed_enable_holds_rather_than_letting_go() {
    use conductor_devices::{Failure, Phase, SafeProgress};
    let mut d = DynamixelX::new(Credential::id(1), DxlXConfig::default());
    let mut servo = Servo::new();
    // The watchdog trips it (holding), then it is enabled again while the line loses every
    // read of Torque Enable: the servo switches on, the device cannot tell.
    let mut t = tripped(&mut d, &mut servo);
    assert_eq!(servo.regs[&64], 1, "torque on");
    servo.lose_torque_reads = true;
    d.write(d.enable_channel(), 1.0, CTX);
    while d.status().failure != Some(Failure::EnableRefused) {
        servo.tick(&mut d, t, false);
        t += 1;
        assert!(t < 1_000, "the enable is given up: {:?}", d.status());
    }
    assert_eq!(servo.regs[&64], 1, "the servo did switch on");
    // The controller goes silent: the trip holds it where it stands.
    servo.regs.insert(132, 2310);
    servo.lose_torque_reads = false;
    let first = servo.tick(&mut d, t, true);
    assert!(
        !first.contains(&write(64, 1, 0)),
        "a joint that may carry a load is not let go: {first:?}"
    );
    for _ in 0..5 {
        t += 1;
        servo.tick(&mut d, t, false);
    }
    assert_eq!(servo.regs[&64], 1, "still powered");
    assert_eq!(servo.regs[&116], 2310, "holding where it stands");
    let st = d.status();
    assert_eq!(
        (st.phase, st.safe),
        (Phase::Holding, SafeProgress::Confirmed)
    );
}

/// A servo still moving when it is brought up again (after its bus came back, it goes on
/// towards its last goal) is enabled and held where it is when the write lands, not where it
/// was read rounds earlier: an enable whose confirmation the line lost reads the position again
/// before it writes it once more, and a hold never takes a reading older than
/// `HOLD_FRESH_NS` for a fresh one.
#[test]
fn a_moving_servo_is_enabled_and_held_where_it_is_after_lost_rounds() {
    use conductor_devices::{Phase, Startup};
    let mut d = DynamixelX::new(Credential::id(1), DxlXConfig::default());
    let mut servo = Servo::new();
    let mut t = enabled(&mut d, &mut servo);
    // The bus goes and comes back; the servo, torque on, moves 3 steps a tick (4 ms)
    // throughout, and the line loses every read of Torque Enable for 20 ticks of the enable.
    d.bus_lost();
    d.bring_up(Startup::Enable, CTX);
    let mut lost = 0;
    while d.status().phase != Phase::Enabled {
        *servo.regs.get_mut(&132).unwrap() += 3;
        servo.lose_torque_reads = d.status().phase == Phase::Enabling && lost < 20;
        lost += servo.lose_torque_reads as u32;
        servo.tick(&mut d, t, false);
        t += 1;
        assert!(t < 300, "enabled again: {:?}", d.status());
    }
    assert_eq!(lost, 20);
    let (goal, here) = (servo.regs[&116], servo.regs[&132]);
    // At most HOLD_FRESH_NS (5 ticks, 15 steps) plus one tick behind; the reading of the
    // first round was 60 steps behind by then.
    assert!(
        (here - goal).abs() <= 18,
        "enabled at {goal} where the servo stood at {here}"
    );
    // The controller goes silent at once: the hold is where the servo is.
    *servo.regs.get_mut(&132).unwrap() += 3;
    servo.tick(&mut d, t, true);
    for _ in 0..3 {
        t += 1;
        servo.tick(&mut d, t, false);
    }
    let (goal, here) = (servo.regs[&116], servo.regs[&132]);
    assert!(
        (here - goal).abs() <= 18,
        "held at {goal} where the servo stood at {here}"
    );
    assert_eq!(d.status().phase, Phase::Holding);
}

/// Brought up and enabled on a perfect line; returns the next tick.
fn enabled(d: &mut DynamixelX, servo: &mut Servo) -> u64 {
    use conductor_devices::{Phase, Startup};
    d.bring_up(Startup::Enable, CTX);
    let mut t = 1;
    while d.status().phase != Phase::Enabled {
        servo.tick(d, t, false);
        t += 1;
        assert!(t < 100, "brought up and enabled: {:?}", d.status());
    }
    t
}

/// Brought up and enabled, then tripped by a watchdog (holding, confirmed); returns the next
/// tick.
fn tripped(d: &mut DynamixelX, servo: &mut Servo) -> u64 {
    let t = enabled(d, servo);
    servo.tick(d, t, true);
    servo.tick(d, t + 1, false);
    assert_eq!(d.status().phase, conductor_devices::Phase::Holding);
    t + 2
}

/// An enable asked for while the bus is gone is remembered, not sent to a bus that is not
/// there (where it would be given up: "did not switch on"); the servo is enabled once the bus
/// is back and it has been brought up again.
#[test]
fn an_enable_while_the_bus_is_gone_waits_for_the_bus() {
    use conductor_devices::{Phase, Startup};
    let mut d = DynamixelX::new(Credential::id(1), DxlXConfig::default());
    let mut servo = Servo::new();
    // The controller dies: the trip holds it; then the bus goes.
    let mut t = tripped(&mut d, &mut servo);
    d.bus_lost();
    servo.unplugged = true;
    // A new controller enables it meanwhile.
    d.write(d.enable_channel(), 1.0, CTX);
    for _ in 0..200 {
        t += 1;
        servo.tick(&mut d, t, false);
    }
    assert_eq!(d.status().phase, Phase::Offline);
    assert_eq!(d.status().failure, None, "nothing was given up");
    // The bus is back: brought up again, and enabled as asked.
    servo.unplugged = false;
    d.bring_up(Startup::Enable, CTX);
    while d.status().phase != Phase::Enabled {
        t += 1;
        servo.tick(&mut d, t, false);
        assert!(t < 400, "enabled once the bus is back: {:?}", d.status());
    }
    assert!(!d.status().tripped);
}

/// An enable asked for during a bring-up lets the bring-up run its course (model check,
/// configuration read and verified) and end enabled; it does not jump to enabling a servo
/// whose configuration has not been read.
#[test]
fn an_enable_during_bring_up_does_not_skip_the_configuration() {
    use conductor_devices::{Phase, Startup};
    let mut d = DynamixelX::new(Credential::id(1), DxlXConfig::default());
    let mut servo = Servo::new();
    let mut t = tripped(&mut d, &mut servo);
    // The bus went and came back: a tripped device is brought up again, to hold.
    d.bus_lost();
    d.bring_up(Startup::Enable, CTX);
    assert_eq!(d.status().phase, Phase::Probing);
    d.write(d.enable_channel(), 1.0, CTX);
    let mut ops = Vec::new();
    while d.status().phase != Phase::Enabled {
        t += 1;
        ops.extend(servo.tick(&mut d, t, false));
        assert!(t < 200, "enabled: {:?}", d.status());
    }
    let first = |op: Op| ops.iter().position(|o| *o == op);
    let torque_on = first(write(64, 1, 1)).expect("torque switched on");
    let ping = first(Op::Ping).expect("probed");
    let mode = first(Op::Read { addr: 11, len: 1 }).expect("operating mode read");
    assert!(
        ping < mode && mode < torque_on,
        "probe, configuration, then enable: {ops:?}"
    );
}
