//! MIT-mode motors and ODrive axes through the CAN protocol stage: on an in-process CAN bus and
//! through the SLCAN codec against the SLCAN adapter simulator.

use conductor_devices::device::{mit_channel, odrive_channel, MitMotor, OdriveAxis, OdriveMode};
use conductor_devices::hw::{SlcanHardware, SlcanOptions};
use conductor_devices::protocol_stage::{mit_limits, CanMotorProtocol};
use conductor_devices::sim::can_motors::{CanNode, MitMotorSim, OdriveAxisSim};
use conductor_devices::sim::hardware::{CanSimHardware, SlcanSimPort};
use conductor_devices::sim::slcan_adapter::SlcanAdapterSim;
use conductor_devices::{
    Bounded, Credential, Device, Hardware, Link, LinkOf, Reply, Request, TickCtx, Update,
};
use conductor_protocols::can::CanFrame;
use conductor_protocols::slcan::Dialect;

const PERIOD_NS: u64 = 2_000_000; // 500 Hz

fn blank() -> CanFrame {
    CanFrame::standard(0, &[]).unwrap()
}

fn protocol() -> CanMotorProtocol {
    CanMotorProtocol::new(mit_limits("ak80-9").unwrap(), vec![], 0, 1_000_000, 64)
}

/// Runs one tick over any CAN link; returns the updates per device index.
fn tick<H: Hardware<Word = CanFrame>>(
    link: &mut LinkOf<CanMotorProtocol, H>,
    devs: &mut [Box<dyn Device>],
    k: u64,
    prep: impl Fn(usize, &mut dyn Device, TickCtx, &mut Bounded<Request>),
) -> Vec<(usize, Update)> {
    let ctx = TickCtx {
        tick: k,
        now_ns: 1_000_000_000 + k * PERIOD_NS,
    };
    let mut reqs = Bounded::<Request>::with_capacity(64);
    for (i, d) in devs.iter_mut().enumerate() {
        prep(i, d.as_mut(), ctx, &mut reqs);
        d.flush(ctx, &mut reqs);
    }
    // What arrived since the last tick, before anything new is sent.
    link.receive(ctx);
    link.encode(reqs.as_slice(), ctx);
    link.exchange(ctx).unwrap();
    let mut replies = Bounded::<Reply>::with_capacity(64);
    link.decode(&mut replies, ctx);
    let mut ups = Bounded::with_capacity(64);
    let mut out = Vec::new();
    for r in replies.as_slice() {
        let Some(i) = devs.iter().position(|d| d.credential() == r.cred) else {
            continue;
        };
        ups.clear();
        devs[i].reply(r, &mut ups);
        out.extend(ups.as_slice().iter().map(|u| (i, *u)));
    }
    out
}

fn mit_devices(ids: &[u32]) -> Vec<Box<dyn Device>> {
    ids.iter()
        .map(|&id| Box::new(MitMotor::new(Credential::id(id), 20.0, 1.0)) as Box<dyn Device>)
        .collect()
}

fn mit_nodes(ids: &[u8]) -> Vec<Box<dyn CanNode>> {
    MitMotorSim::bus(ids.iter().copied(), mit_limits("ak80-9").unwrap())
}

/// Each motor gets exactly one frame per tick however many of its channels were written, and
/// the motors follow the targets.
#[test]
fn mit_writes_of_a_tick_combine_into_one_command() {
    let hw = CanSimHardware::new(mit_nodes(&[1, 2, 3]), 150_000);
    let mut link = LinkOf::with_fill(protocol(), hw, 64, blank());
    let mut devs = mit_devices(&[1, 2, 3]);
    let mut seen = 0;
    for k in 0..1000 {
        let before = link.hardware().expect("the bus is up").frames_from_host();
        let ups = tick(&mut link, &mut devs, k, |i, d, ctx, q| {
            d.sample(mit_channel::POSITION, ctx, q);
            if k == 0 {
                // These are bare (unmanaged) drivers: enter motor mode through `enable`.
                d.write(mit_channel::ENABLE, 1.0, ctx);
            } else {
                d.write(mit_channel::POSITION, 0.5 * (i as f64 + 1.0), ctx);
                d.write(mit_channel::KP, 20.0, ctx);
                d.write(mit_channel::KD, 1.0, ctx);
            }
        });
        let frames = link.hardware().expect("the bus is up").frames_from_host() - before;
        // Tick 0 only enters motor mode; then one command.
        assert_eq!(frames, 3, "tick {k}");
        seen += ups.iter().filter(|(_, u)| u.value.is_some()).count();
        assert!(
            ups.iter().all(|(_, u)| u.value.is_some()),
            "tick {k}: {ups:?}"
        );
    }
    // Replies arrive 0.15 ms after the command, i.e. in the next tick's exchange.
    assert_eq!(seen, 999 * 3);
    let c = link.counters();
    assert_eq!(
        (c.protocol.missing_replies, c.protocol.rejected_packets),
        (0, 0)
    );
    for s in link.hardware().expect("the bus is up").snapshots() {
        let target = 0.5 * s.id as f64;
        // 2 s of a kp = 20, kd = 1 servo on J = 0.01, b = 0.05: settled to the quantisation
        // of the position field (25 rad / 65 535 ≈ 4e-4) plus damping residue.
        assert!((s.position - target).abs() < 2e-3, "{s:?}");
        assert!(s.enabled);
    }
}

#[test]
fn an_absent_motor_goes_stale_and_is_counted() {
    let hw = CanSimHardware::new(mit_nodes(&[1]), 150_000);
    let mut link = LinkOf::with_fill(protocol(), hw, 64, blank());
    let mut devs = mit_devices(&[1, 9]);
    let mut stale = 0;
    for k in 0..10 {
        for (i, u) in tick(&mut link, &mut devs, k, |_, d, ctx, q| {
            d.sample(mit_channel::POSITION, ctx, q);
        }) {
            if i == 1 {
                assert_eq!(u.value, None);
                stale += 1;
            } else {
                assert!(u.value.is_some());
            }
        }
    }
    // Tick k's frame expires 1 ms later, i.e. at tick k + 1: 9 expired in 10 ticks.
    assert_eq!(stale, 9);
    assert_eq!(link.counters().protocol.missing_replies, 9);
}

/// The same motors through the SLCAN codec and the adapter simulator (CANable dialect, then
/// LAWICEL's z acks).
#[test]
fn mit_over_slcan() {
    for dialect in [Dialect::CANABLE, Dialect::LAWICEL] {
        let adapter = SlcanAdapterSim::new(dialect, mit_nodes(&[1, 2, 3]));
        let port = SlcanSimPort::new(adapter);
        let hw = SlcanHardware::open(
            port,
            SlcanOptions {
                dialect,
                ..SlcanOptions::default()
            },
        )
        .unwrap();
        let mut link = LinkOf::with_fill(protocol(), hw, 64, blank());
        let mut devs = mit_devices(&[1, 2, 3]);
        let mut values = 0;
        for k in 0..200 {
            let ups = tick(&mut link, &mut devs, k, |i, d, ctx, q| {
                d.sample(mit_channel::POSITION, ctx, q);
                d.sample(mit_channel::VELOCITY, ctx, q);
                if k == 0 {
                    d.write(mit_channel::ENABLE, 1.0, ctx);
                }
                d.write(mit_channel::POSITION, -0.3 * (i as f64 + 1.0), ctx);
            });
            values += ups.iter().filter(|(_, u)| u.value.is_some()).count();
        }
        // The simulated adapter answers at once: replies are decoded in the same tick. Every
        // reply (the 3 enables' included) updates both sampled channels.
        assert_eq!(values, (200 * 3 + 3) * 2, "{dialect:?}");
        let s = link.hardware().expect("the bus is up").stats();
        assert_eq!(
            s.frames_out,
            200 * 3 + 3,
            "{dialect:?}: one frame per motor and tick, plus the enables"
        );
        assert_eq!(s.frames_in, s.frames_out);
        assert_eq!(
            (s.nacks, s.ack_timeouts, s.stray_acks, s.discarded_bytes),
            (0, 0, 0, 0)
        );
        let a = link.hardware().expect("the adapter is open").port().stats();
        assert_eq!(a.frames_from_host, 603);
        // The open sequence's `C` on a closed channel is refused (BEL), harmlessly.
        assert_eq!(a.nacks, 1);
        for snap in link
            .hardware()
            .expect("the adapter is open")
            .port()
            .adapter()
            .nodes()
            .iter()
            .map(|n| n.snapshot())
        {
            assert!(
                (snap.position + 0.3 * snap.id as f64).abs() < 0.01,
                "{snap:?}"
            );
        }
    }
}

#[test]
fn odrive_polled_and_cyclic() {
    for poll in [true, false] {
        // Polled: no cyclic messages at all, every value must come from a request.
        let (hb, enc) = if poll { (0, 0) } else { (100, 10) };
        let nodes: Vec<Box<dyn CanNode>> = vec![Box::new(OdriveAxisSim::new(3, hb, enc))];
        let hw = CanSimHardware::new(nodes, 150_000);
        let mut link = LinkOf::with_fill(protocol(), hw, 64, blank());
        let mut devs: Vec<Box<dyn Device>> = vec![Box::new(OdriveAxis::new(
            Credential::id(3),
            OdriveMode::Position,
            poll,
        ))];
        let mut last = None;
        let mut states = Vec::new();
        for k in 0..500 {
            for (_, u) in tick(&mut link, &mut devs, k, |_, d, ctx, q| {
                // Position and velocity share one request; state is the heartbeat's.
                let before = q.len();
                d.sample(odrive_channel::POSITION, ctx, q);
                d.sample(odrive_channel::VELOCITY, ctx, q);
                d.sample(odrive_channel::STATE, ctx, q);
                assert_eq!(q.len() - before, if poll { 2 } else { 0 });
                if k == 0 {
                    // A bare (unmanaged) driver: closed loop through `enable`.
                    d.write(odrive_channel::ENABLE, 1.0, ctx);
                }
                d.write(odrive_channel::POSITION, 2.0, ctx);
            }) {
                if u.channel == odrive_channel::POSITION {
                    last = u.value;
                }
                if u.channel == odrive_channel::STATE {
                    states.push(u.value);
                }
            }
        }
        let snap = link.hardware().expect("the bus is up").snapshots()[0];
        assert!(snap.enabled, "closed loop after enable");
        assert!((snap.position - 2.0).abs() < 1e-3, "{snap:?}");
        assert!((last.unwrap() - 2.0).abs() < 0.05, "{last:?}");
        assert!(states.contains(&Some(8.0)), "heartbeat state closed loop");
    }
}

/// A lifecycle request that is answered by nothing — its frame dropped unsent (a newer one for
/// the same motor superseded it), so neither a reply nor a `Missing` ever comes — is sent again
/// once the round is overdue, instead of leaving the motor probing (or enabling) for ever.
#[test]
fn a_round_answered_by_nothing_is_sent_again() {
    use conductor_devices::{MitSpecial, Op, Phase, Startup};
    let mut d = MitMotor::new(Credential::id(1), 20.0, 1.0);
    let at = |tick: u64| TickCtx {
        tick,
        now_ns: tick * PERIOD_NS,
    };
    d.bring_up(Startup::Enable, at(0));
    let flush = |d: &mut MitMotor, tick| {
        let mut out = Bounded::with_capacity(8);
        d.flush(at(tick), &mut out);
        out.as_slice().iter().map(|r| r.op).collect::<Vec<Op>>()
    };
    let poll = Op::MitSpecial(MitSpecial::Exit);
    assert_eq!(flush(&mut d, 0), [poll], "the probe polls the motor");
    // Nothing comes back, not even word of the request missing: the round waits a while...
    for tick in 1..100 {
        assert!(
            flush(&mut d, tick).is_empty(),
            "tick {tick}: nothing sent yet"
        );
    }
    assert_eq!(d.status().phase, Phase::Probing);
    // ... and after 250 ms (125 ticks) is lost, and sent again (a probe after its 50 ms
    // spacing).
    let again: Vec<Op> = (100..=160).flat_map(|t| flush(&mut d, t)).collect();
    assert_eq!(
        again,
        [poll],
        "the poll is sent again once the round is overdue"
    );
}

/// An enable sent again after lost rounds holds where the motor is, not where it was read
/// before the losses: a limp joint may still be coasting (after a watchdog trip), and holding
/// an old reading would pull it back there. Once the reading is older than `HOLD_FRESH_NS`,
/// the motor is polled again first.
#[test]
fn an_enable_resent_after_lost_rounds_polls_the_coasting_joint_again() {
    use conductor_devices::{MitSpecial, Op, Phase, ReplyData, Startup};
    let cred = Credential::id(1);
    let mut d = MitMotor::new(cred, 20.0, 1.0);
    let at = |tick: u64| TickCtx {
        tick,
        now_ns: tick * PERIOD_NS,
    };
    let flush = |d: &mut MitMotor, tick| {
        let mut out = Bounded::with_capacity(8);
        d.flush(at(tick), &mut out);
        out.as_slice().iter().map(|r| r.op).collect::<Vec<Op>>()
    };
    let state = |d: &mut MitMotor, op: Op, tick: u64, p: f32| {
        let mut ups = Bounded::with_capacity(8);
        let data = ReplyData::Mit {
            p,
            v: 5.0,
            t: 0.0,
            temperature: None,
        };
        d.reply(
            &Reply::answer(cred, op, data, tick, at(tick).now_ns),
            &mut ups,
        );
    };
    let poll = Op::MitSpecial(MitSpecial::Exit);
    let enter = Op::MitSpecial(MitSpecial::Enter);
    d.bring_up(Startup::Enable, at(0));
    assert_eq!(flush(&mut d, 0), [poll]);
    // The joint coasts at 5 rad/s: read at 1.0 rad.
    state(&mut d, poll, 0, 1.0);
    let hold_at = |p: f32| Op::Mit {
        p,
        v: 0.0,
        kp: 20.0,
        kd: 1.0,
        t: 0.0,
    };
    assert_eq!(flush(&mut d, 1), [enter, hold_at(1.0)]);
    // Every enable round is lost on the line (word of it missing comes each time).
    let mut tick = 1;
    let sent = loop {
        let mut ups = Bounded::with_capacity(8);
        d.reply(
            &Reply::missing(cred, hold_at(1.0), tick, at(tick).now_ns),
            &mut ups,
        );
        tick += 1;
        let ops = flush(&mut d, tick);
        if ops != [enter, hold_at(1.0)] || tick > 40 {
            break ops;
        }
        assert!(
            at(tick).now_ns <= 20_000_000 + PERIOD_NS,
            "tick {tick}: a hold at a reading {} ms old",
            at(tick).now_ns / 1_000_000
        );
    };
    assert_eq!(sent, [poll], "tick {tick}: polled again before enabling");
    assert_eq!(d.status().phase, Phase::Enabling);
    // Read again where it has coasted to; enabled there.
    state(&mut d, poll, tick, 1.12);
    assert_eq!(flush(&mut d, tick + 1), [enter, hold_at(1.12)]);
    state(&mut d, hold_at(1.12), tick + 1, 1.12);
    assert_eq!(d.status().phase, Phase::Enabled);
}
