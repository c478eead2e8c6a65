//! The Dynamixel 2.0 protocol stage against the bus simulator, in process: bundling (one SYNC
//! WRITE and one SYNC READ / FAST SYNC READ per cycle), bytes on the wire equal to the
//! protocol minimum computed here independently, and fault injection reconciled reply by reply
//! with the simulator's ground truth.

use std::collections::HashMap;
use std::f64::consts::PI;

use conductor_devices::device::{x_channel, DxlXConfig, DynamixelX};
use conductor_devices::protocol_stage::{Dxl2Protocol, Dxl2ReadMode, Timing};
use conductor_devices::sim::dxl::DxlSimConfig;
use conductor_devices::sim::fault::{FaultConfig, Rng};
use conductor_devices::sim::hardware::{DxlSimHardware, ReplyRecord};
use conductor_devices::{
    Bounded, Credential, Device, Link, LinkOf, Reply, Request, TickCtx, Update,
};

const PERIOD_NS: u64 = 4_000_000; // 250 Hz
const BAUD: u32 = 1_000_000;

struct Rig {
    link: LinkOf<Dxl2Protocol, DxlSimHardware>,
    devs: Vec<DynamixelX>,
    reqs: Bounded<Request>,
    replies: Bounded<Reply>,
    ups: Bounded<Update>,
}

impl Rig {
    fn new(n: u8, mode: Dxl2ReadMode, down: FaultConfig, up: FaultConfig) -> Self {
        let timing = Timing {
            baud: BAUD,
            return_delay_ns: 0,
            timeout_ns: 1_000_000,
        };
        let sim = DxlSimConfig {
            ids: (1..=n).collect(),
            baud: BAUD,
            // These tests are about bundling, not power-on: the servos follow their goals.
            torque_on: true,
            ..DxlSimConfig::default()
        };
        let hw = DxlSimHardware::new(sim, down, up).with_log();
        let link = LinkOf::new(
            Dxl2Protocol::new(timing, mode, n as usize, 8 * n as usize),
            hw,
            4096,
        );
        Self {
            link,
            devs: (1..=n)
                .map(|id| DynamixelX::new(Credential::id(id as u32), DxlXConfig::default()))
                .collect(),
            reqs: Bounded::with_capacity(64 * n as usize),
            replies: Bounded::with_capacity(64 * n as usize),
            ups: Bounded::with_capacity(64 * n as usize),
        }
    }

    /// One executor tick: sample `channels` of every servo, write `goals` (rad), bundle,
    /// exchange, decode. Returns the updates as (servo index, update).
    fn cycle(&mut self, k: u64, channels: &[usize], goals: Option<&[f64]>) -> Vec<(usize, Update)> {
        let ctx = TickCtx {
            tick: k,
            now_ns: 1_000_000_000 + k * PERIOD_NS,
        };
        self.reqs.clear();
        for (i, d) in self.devs.iter_mut().enumerate() {
            for &c in channels {
                d.sample(c, ctx, &mut self.reqs);
            }
            if let Some(g) = goals {
                d.write(x_channel::POSITION, g[i], ctx);
            }
            d.flush(ctx, &mut self.reqs);
        }
        // What arrived since the last tick, before anything new is sent.
        self.link.receive(ctx);
        self.link.encode(self.reqs.as_slice(), ctx);
        self.link.exchange(ctx).unwrap();
        self.replies.clear();
        self.link.decode(&mut self.replies, ctx);
        let mut out = Vec::new();
        for r in self.replies.as_slice() {
            let i = (r.cred.id - 1) as usize;
            self.ups.clear();
            self.devs[i].reply(r, &mut self.ups);
            out.extend(self.ups.as_slice().iter().map(|u| (i, *u)));
        }
        out
    }
}

/// Independent count of the bytes byte stuffing adds to an instruction's parameters.
fn stuffing(params: &[u8]) -> usize {
    params
        .windows(3)
        .filter(|w| w == &[0xFF, 0xFF, 0xFD])
        .count()
}

fn goal_raw(rad: f64) -> i32 {
    (rad / (2.0 * PI / 4096.0)).round() as i32 + 2048
}

/// Per cycle, exactly: SYNC WRITE = 10 + 4 + n·(1 + 4) (+ stuffing), SYNC READ = 10 + 4 + n,
/// replies n·(11 + len) for SYNC READ, 8 + n·(4 + len) for FAST SYNC READ.
#[test]
fn one_sync_write_and_one_read_per_cycle_at_the_wire_minimum() {
    for mode in [Dxl2ReadMode::Sync, Dxl2ReadMode::Fast] {
        let n = 6usize;
        let mut rig = Rig::new(
            n as u8,
            mode,
            FaultConfig::default(),
            FaultConfig::default(),
        );
        let mut rng = Rng::new(42);
        let mut prev = rig.link.hardware().expect("the bus is up").stats();
        let channels = [x_channel::POSITION, x_channel::VELOCITY];
        let span = 8; // Present Velocity (128, 4) + Present Position (132, 4)
        let mut delivered = 0;
        for k in 0..300u64 {
            let goals: Vec<f64> = (0..n).map(|_| (rng.unit() - 0.5) * PI).collect();
            let ups = rig.cycle(k, &channels, Some(&goals));
            let s = rig.link.hardware().expect("the bus is up").stats();
            assert_eq!(
                s.sync_write - prev.sync_write,
                1,
                "cycle {k}: one SYNC WRITE"
            );
            let reads = match mode {
                Dxl2ReadMode::Sync => s.sync_read - prev.sync_read,
                Dxl2ReadMode::Fast => s.fast_sync_read - prev.fast_sync_read,
            };
            assert_eq!(reads, 1, "cycle {k}: one read instruction");
            assert_eq!(s.packets_in - prev.packets_in, 2, "cycle {k}: nothing else");
            let mut params = vec![0x74, 0x00, 0x04, 0x00];
            for (i, g) in goals.iter().enumerate() {
                params.push(i as u8 + 1);
                params.extend_from_slice(&goal_raw(*g).to_le_bytes());
            }
            let sync_write = 10 + params.len() + stuffing(&params);
            let read = 10 + 4 + n;
            assert_eq!(
                s.bytes_in - prev.bytes_in,
                (sync_write + read) as u64,
                "cycle {k}"
            );
            // Status packets are stuffed like instructions (a negative velocity followed by a
            // position like 0x07FD gives FF FF FD); the combined fast reply is not.
            let t = 1_000_000_000 + k * PERIOD_NS;
            let stuffed: usize = rig
                .link
                .hardware()
                .expect("the bus is up")
                .reply_log()
                .iter()
                .filter(|r| r.t_request_ns == t)
                .map(|r| {
                    let mut p = vec![0u8];
                    p.extend_from_slice(&r.data.as_ref().unwrap().1);
                    stuffing(&p)
                })
                .sum();
            let replies = match mode {
                Dxl2ReadMode::Sync => n * (11 + span) + stuffed,
                Dxl2ReadMode::Fast => 8 + n * (4 + span),
            };
            assert_eq!(s.bytes_out - prev.bytes_out, replies as u64, "cycle {k}");
            assert_eq!(s.discarded_in, 0);
            prev = s;
            if k > 0 {
                // The replies to the previous cycle's read: every servo, both channels.
                assert_eq!(ups.len(), 2 * n, "cycle {k}");
                assert!(ups.iter().all(|(_, u)| u.value.is_some() && !u.fault));
                delivered += ups.len();
            }
        }
        let c = rig.link.counters();
        assert_eq!(c.protocol.missing_replies, 0);
        assert_eq!(c.protocol.rejected_packets, 0);
        assert_eq!(c.protocol.discarded_words, 0);
        assert_eq!(delivered, 299 * 2 * n);
        // Hold one goal for 100 cycles (0.4 s = 8 τ): the first-order model settles to within
        // e^-8 of its initial error (< 4096 pulses), i.e. below 2 pulses.
        let goal = [0.5f64; 6];
        for k in 300..400u64 {
            rig.cycle(k, &channels, Some(&goal));
        }
        let sim = rig.link.hardware().expect("the bus is up").sim();
        for id in 1..=n as u8 {
            let s = sim.servo(id).unwrap();
            assert_eq!(s.goal_position(), goal_raw(0.5));
            assert!((s.present_position() - s.goal_position()).abs() <= 2);
        }
        let last = rig.devs[0].last(x_channel::POSITION).unwrap();
        assert!((last - 0.5).abs() < 3.0 * 2.0 * PI / 4096.0, "{last}");
    }
}

#[test]
fn different_spans_use_one_bulk_read() {
    let mut rig = Rig::new(
        3,
        Dxl2ReadMode::Sync,
        FaultConfig::default(),
        FaultConfig::default(),
    );
    for k in 0..5 {
        let ctx = TickCtx {
            tick: k,
            now_ns: 1_000_000_000 + k * PERIOD_NS,
        };
        rig.reqs.clear();
        rig.devs[0].sample(x_channel::POSITION, ctx, &mut rig.reqs);
        rig.devs[1].sample(x_channel::CURRENT, ctx, &mut rig.reqs);
        rig.devs[2].sample(x_channel::TEMPERATURE, ctx, &mut rig.reqs);
        rig.link.receive(ctx);
        rig.link.encode(rig.reqs.as_slice(), ctx);
        rig.link.exchange(ctx).unwrap();
        rig.replies.clear();
        rig.link.decode(&mut rig.replies, ctx);
        if k > 0 {
            assert_eq!(rig.replies.len(), 3);
            let mut ups = Bounded::with_capacity(8);
            for r in rig.replies.as_slice() {
                rig.devs[(r.cred.id - 1) as usize].reply(r, &mut ups);
            }
            let temp = ups
                .as_slice()
                .iter()
                .find(|u| u.channel == x_channel::TEMPERATURE);
            assert_eq!(temp.unwrap().value, Some(35.0));
        }
    }
    let s = rig.link.hardware().expect("the bus is up").stats();
    assert_eq!((s.bulk_read, s.sync_read), (5, 0));
}

/// What the simulator sent for each (request time, servo): the raw (position, velocity), whether
/// the injector damaged that status packet, and whether it damaged the packet before it on the
/// wire (a dropped or corrupted byte at a boundary can spill into the neighbour, or be healed
/// by it: a lost leading FF is restored by a preceding FF).
type Truth = HashMap<(u64, usize), ([i32; 2], bool, bool)>;

fn truth(records: &[ReplyRecord], n: usize) -> Truth {
    let mut t = HashMap::new();
    let mut prev_damaged = false;
    for r in records {
        let Some((addr, data)) = &r.data else {
            continue;
        };
        assert_eq!(*addr, 128);
        let vals = |d: &[u8]| {
            [
                i32::from_le_bytes(d[4..8].try_into().unwrap()),
                i32::from_le_bytes(d[0..4].try_into().unwrap()),
            ]
        };
        let dmg = r.fault.damaged();
        if r.id == 0xFE {
            for i in 0..n {
                t.insert(
                    (r.t_request_ns, i),
                    (vals(&data[8 * i..8 * i + 8]), dmg, prev_damaged),
                );
            }
        } else {
            t.insert(
                (r.t_request_ns, r.id as usize - 1),
                (vals(data), dmg, prev_damaged),
            );
        }
        prev_damaged = dmg;
    }
    t
}

/// A request's answer: its sample time and value (`None`: stale).
type Answer = (u64, Option<f64>);

/// 1 % corrupted and 1 % dropped bytes in both directions for `cycles` cycles: no value is
/// ever wrong (each one delivered equals what the simulator sent for that request), a value is
/// stale only where the injector damaged its status packet (or its instruction, or, at a packet
/// boundary, its neighbour), and the protocol's missing-reply counter equals the stale values.
fn fault_run(mode: Dxl2ReadMode, cycles: u64, seed: u64) {
    let n = 6usize;
    let rate = FaultConfig {
        corrupt: 0.01,
        drop: 0.01,
        seed,
        ..FaultConfig::default()
    };
    let up = FaultConfig {
        seed: seed ^ 0xA5A5,
        ..rate
    };
    let mut rig = Rig::new(n as u8, mode, rate, up);
    // Per request (its tick, servo): the sample time and value of each channel. After missing
    // replies the stage keeps the line quiet for a while, so a cycle's requests may be answered
    // by the next cycle's read (their sample time is that read's).
    let mut got: HashMap<(u64, usize), [Option<Answer>; 2]> = HashMap::new();
    let mut rng = Rng::new(seed);
    let channels = [x_channel::POSITION, x_channel::VELOCITY];
    let mut stale = 0u64;
    for k in 0..cycles {
        let goals: Vec<f64> = (0..n).map(|_| (rng.unit() - 0.5) * PI).collect();
        for (i, u) in rig.cycle(k, &channels, Some(&goals)) {
            let slot = got.entry((u.tick, i)).or_insert([None, None]);
            let c = usize::from(u.channel != x_channel::POSITION);
            assert!(slot[c].is_none(), "one update per request");
            slot[c] = Some((u.t_sample_ns, u.value));
            stale += u.value.is_none() as u64;
        }
    }
    let hw = rig.link.hardware().expect("the bus is up");
    let truth = truth(hw.reply_log(), n);
    let damaged_out = hw.host_log().iter().filter(|c| c.fault.damaged()).count();
    let damaged_back = hw.reply_log().iter().filter(|r| r.fault.damaged()).count();
    assert!(
        damaged_out > 100 && damaged_back > 100,
        "{damaged_out} {damaged_back}"
    );
    let vel_unit = 0.229 * 2.0 * PI / 60.0;
    let (mut stale_values, mut healed, mut spilled, mut no_reply) = (0u64, 0u64, 0u64, 0u64);
    // The last cycle's replies are still on the wire when the loop ends.
    let mut deferred = 0u64;
    for k in 0..cycles - 1 {
        for i in 0..n {
            let have = got.get(&(k, i)).copied().unwrap_or([None, None]);
            let [Some((t, pos)), Some((tv, vel))] = have else {
                // A request of the last cycles may still be waiting for the line to be quiet.
                assert!(
                    k + 3 >= cycles,
                    "cycle {k} servo {i}: no update at all: {have:?}"
                );
                continue;
            };
            assert_eq!(t, tv, "one read answers both channels");
            deferred += (t != 1_000_000_000 + k * PERIOD_NS) as u64;
            match (truth.get(&(t, i)), pos, vel) {
                // The simulator never answered (damaged instruction): stale.
                (None, None, None) => {
                    stale_values += 2;
                    no_reply += 1;
                }
                (None, ..) => panic!("cycle {k} servo {i}: a value with no reply sent"),
                (Some(&(_, dmg, prev)), None, None) => {
                    assert!(
                        dmg || prev,
                        "cycle {k} servo {i}: stale without a fault; t {t}; truth {:?}; counters {:?}; log {:?}",
                        (0..n).map(|j| truth.get(&(t, j))).collect::<Vec<_>>(),
                        rig.link.counters(),
                        hw.host_log().iter().filter(|h| h.t_ns + 20_000_000 > t && h.t_ns < t + 20_000_000).collect::<Vec<_>>()
                    );
                    stale_values += 2;
                    spilled += !dmg as u64;
                }
                (Some(&([p, v], dmg, _)), Some(pos), Some(vel)) => {
                    let p_rad = (p - 2048) as f64 * (2.0 * PI / 4096.0);
                    let v_rad = v as f64 * vel_unit;
                    assert_eq!(pos, p_rad, "cycle {k} servo {i}: position");
                    assert_eq!(vel, v_rad, "cycle {k} servo {i}: velocity");
                    healed += dmg as u64;
                }
                other => panic!("cycle {k} servo {i}: half a reply {other:?}"),
            }
        }
    }
    assert_eq!(stale, stale_values);
    let c = rig.link.counters();
    assert_eq!(c.protocol.missing_replies, stale_values, "{c:?}");
    assert_eq!(c.protocol.device_errors, 0);
    assert!(rig.devs.iter().all(|d| d.range_rejects() == 0));
    // Boundary effects are rare: each needs a lost/corrupted byte at a packet edge that
    // happens to match its neighbour (about 1/19 · 1/256 of the damaged packets).
    assert!(
        healed + spilled <= 2 + damaged_back as u64 / 200,
        "{healed} healed, {spilled} spilled of {damaged_back}"
    );
    eprintln!(
        "{mode:?}: {cycles} cycles; damaged: {damaged_out} instruction chunks, {damaged_back} \
         status packets; {no_reply} requests unanswered, {stale_values} stale values, {healed} \
         healed, {spilled} spilled, {deferred} answered by a later read; counters {c:?}"
    );
}

#[test]
fn fault_injection_sync_read() {
    fault_run(Dxl2ReadMode::Sync, 10_000, 1);
}

#[test]
fn fault_injection_fast_sync_read() {
    fault_run(Dxl2ReadMode::Fast, 3_000, 2);
}
