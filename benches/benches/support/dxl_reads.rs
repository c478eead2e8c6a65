//! Bytes on the wire per cycle when X-series servos read Hardware Error Status (70, 1 B),
//! Present Current (126, 2 B), Present Velocity (128, 4 B) and Present Position (132, 4 B):
//!
//! * [`measure`] runs the Dynamixel 2.0 protocol stage against the in-process bus simulator:
//!   the servos are set up (by the devices' bring-up, or directly: see [`Setup`]; with the
//!   layout the device chose, its indirect addresses are written then), and then every cycle
//!   samples the four channels and writes a goal position. The simulator counts the bytes;
//!   every value delivered is checked against what the simulated servo holds.
//! * [`sdk_reads`] computes, independently of the stage, what ROBOTIS DynamixelSDK's group
//!   classes would put on the wire for the same read, from the packet layouts of protocols.md
//!   §1.2 (instruction 10 bytes + parameters, status 11 bytes + data), §1.5 (SYNC READ
//!   parameters: address, length, one ID per servo; BULK READ: ID, address, length per servo)
//!   and §1.7 (FAST reply: 8 bytes + ERR, ID, data, CRC per servo).
//!
//! Shared by `benches/devices.rs` (which prints the figures) and `tests/dxl_read_layout.rs`
//! (which asserts them); each uses part of it.
#![allow(dead_code)]

use conductor_devices::device::{x_channel, x_table, DxlXConfig, DynamixelX, Layout};
use conductor_devices::protocol_stage::{Dxl2Protocol, Dxl2ReadMode, Timing};
use conductor_devices::sim::dxl::DxlSimConfig;
use conductor_devices::sim::fault::FaultConfig;
use conductor_devices::sim::hardware::DxlSimHardware;
use conductor_devices::{
    Bounded, Credential, Device, Link, LinkOf, Op, Phase, Reply, Request, Startup, TickCtx, Update,
};

/// The channels every cycle samples.
pub const CHANNELS: [usize; 4] = [
    x_channel::HARDWARE_ERROR,
    x_channel::CURRENT,
    x_channel::VELOCITY,
    x_channel::POSITION,
];

/// Their registers: (address, bytes).
pub const REGISTERS: [(u16, u16); 4] = [
    (x_table::HARDWARE_ERROR_STATUS, 1),
    (x_table::PRESENT_CURRENT, 2),
    (x_table::PRESENT_VELOCITY, 4),
    (x_table::PRESENT_POSITION, 4),
];

/// How the devices lay out their reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reading {
    /// What the device chooses (`configure_reads` with the sampled channels).
    Chosen,
    /// The registers themselves (`configure_reads` not called): the stage reads their
    /// contiguous span.
    Contiguous,
}

/// One configuration's bytes per cycle, as the simulator counted them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Measured {
    /// The layout the devices report.
    pub layout: Layout,
    /// Read instruction + status packets, per cycle.
    pub read_bytes: u64,
    /// The goal-position SYNC WRITE, per cycle.
    pub write_bytes: u64,
    /// Cycles run; every one that sent anything carried exactly these bytes.
    pub cycles: u64,
    /// Cycles in which the stage sent nothing, keeping the line quiet after missing replies.
    pub deferred: u64,
    /// Values delivered to the devices over the measured cycles (each one checked against the
    /// simulator).
    pub delivered: u64,
    /// Read requests the stage reported missing over them.
    pub missing: u64,
}

impl Measured {
    /// Every read of every cycle delivered all channels of every servo.
    pub fn complete(&self, n: u8) -> bool {
        self.missing == 0
            && self.deferred == 0
            && self.delivered == self.cycles * CHANNELS.len() as u64 * n as u64
    }

    /// Bytes each servo returns per read: the indirect bytes, else the registers' span.
    pub fn per_servo(&self) -> u16 {
        if self.layout.indirect > 0 {
            self.layout.indirect
        } else {
            span(&REGISTERS).1
        }
    }
}

/// The contiguous span of `regs`: (first address, bytes).
pub fn span(regs: &[(u16, u16)]) -> (u16, u16) {
    let lo = regs.iter().map(|r| r.0).min().unwrap_or(0);
    let hi = regs.iter().map(|r| r.0 + r.1).max().unwrap_or(0);
    (lo, hi - lo)
}

/// Wire time of `bytes` 8N1 bytes at `baud` (10 bits each), ns. With Return Delay Time 0 this
/// is the simulator's cycle time: it adds nothing between packets.
pub fn wire_ns(bytes: u64, baud: u32) -> f64 {
    bytes as f64 * 10.0 * 1e9 / baud as f64
}

/// A tick long enough for any cycle measured here to finish on the wire (the largest, 41
/// servos reading 66 B each with SYNC READ at 1 Mbit/s, takes 35 ms).
const PERIOD_NS: u64 = 100_000_000;
/// Ticks bring-up may take before the run gives up.
const BRING_UP_TICKS: u64 = 1000;

/// Raw position servo `i` (0-based) rests at: a different one each, so that a read that
/// delivered another servo's bytes, or other bytes, shows.
fn rest_raw(i: usize) -> i32 {
    2048 + 10 * (i as i32 + 1)
}

/// The same, in rad (0 rad = raw 2048, 4096 pulses a turn).
fn rest_rad(i: usize) -> f64 {
    (rest_raw(i) - 2048) as f64 * (2.0 * std::f64::consts::PI / 4096.0)
}

struct Rig {
    link: LinkOf<Dxl2Protocol, DxlSimHardware>,
    devs: Vec<DynamixelX>,
    reqs: Bounded<Request>,
    replies: Bounded<Reply>,
    ups: Bounded<Update>,
    k: u64,
}

impl Rig {
    fn ctx(&self) -> TickCtx {
        TickCtx {
            tick: self.k,
            now_ns: 1_000_000_000 + self.k * PERIOD_NS,
        }
    }

    /// One executor tick: on every servo, if `drive`, sample [`CHANNELS`] and write its rest
    /// position as goal; flush; run the link. Returns the updates that carried a value.
    fn tick(&mut self, drive: bool) -> Vec<(usize, Update)> {
        let ctx = self.ctx();
        self.reqs.clear();
        for (i, d) in self.devs.iter_mut().enumerate() {
            if drive {
                for &c in &CHANNELS {
                    d.sample(c, ctx, &mut self.reqs);
                }
                d.write(x_channel::POSITION, rest_rad(i), ctx);
            }
            d.flush(ctx, &mut self.reqs);
        }
        self.link.receive(ctx);
        self.link.encode(self.reqs.as_slice(), ctx);
        self.link.exchange(ctx).expect("the simulated bus stays up");
        self.replies.clear();
        self.link.decode(&mut self.replies, ctx);
        let mut out = Vec::new();
        for r in self.replies.as_slice() {
            let i = (r.cred.id - 1) as usize;
            self.ups.clear();
            self.devs[i].reply(r, &mut self.ups);
            out.extend(
                self.ups
                    .as_slice()
                    .iter()
                    .filter(|u| u.value.is_some())
                    .map(|u| (i, *u)),
            );
        }
        self.k += 1;
        out
    }
}

/// How the servos get ready for the measured cycles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Setup {
    /// The devices' own bring-up (probe, configuration incl. the indirect addresses of the
    /// chosen layout, enable): the executor's path.
    BringUp,
    /// Unmanaged devices, torque off as at power-on; with the chosen layout the stage writes
    /// the Indirect Addresses the devices report (`read_address`) as SYNC WRITEs first. For
    /// configurations whose bring-up the FAST stage cannot receive (see the module notes in
    /// `devices.rs`); the test checks it reads the same bytes as [`Setup::BringUp`].
    Direct,
}

/// Brings `n` servos up on one simulated bus at `baud`, then runs `cycles` cycles and counts
/// the bytes of each. Panics if the set-up fails, if a cycle is anything but one SYNC WRITE and
/// one read instruction of `mode` (or, after missing replies, nothing), if the cycles differ in
/// bytes, or if a value delivered is not the one the simulator holds.
pub fn measure(
    n: u8,
    mode: Dxl2ReadMode,
    reading: Reading,
    setup: Setup,
    baud: u32,
    cycles: u64,
) -> Measured {
    let n_us = n as usize;
    let timing = Timing {
        baud,
        return_delay_ns: 0,
        timeout_ns: 1_000_000,
    };
    let sim = DxlSimConfig {
        ids: (1..=n).collect(),
        baud,
        return_delay_us: 0,
        baud_timing: true,
        // As real X-series servos: torque off at power-on.
        torque_on: false,
        ..DxlSimConfig::default()
    };
    let mut hw = DxlSimHardware::new(sim, FaultConfig::default(), FaultConfig::default());
    for i in 0..n_us {
        let s = hw.sim_mut().servo_mut(i as u8 + 1).expect("on the bus");
        s.set_present(rest_raw(i));
    }
    let mut devs: Vec<DynamixelX> = (1..=n)
        .map(|id| DynamixelX::new(Credential::id(id as u32), DxlXConfig::default()))
        .collect();
    if reading == Reading::Chosen {
        for d in &mut devs {
            d.configure_reads(&CHANNELS);
        }
    }
    let mut rig = Rig {
        link: LinkOf::new(
            Dxl2Protocol::new(timing, mode, n_us, 64 * n_us),
            hw,
            1 << 16,
        ),
        devs,
        reqs: Bounded::with_capacity(64 * n_us),
        replies: Bounded::with_capacity(64 * n_us),
        ups: Bounded::with_capacity(64),
        k: 0,
    };
    match setup {
        Setup::BringUp => {
            let ctx = rig.ctx();
            for d in &mut rig.devs {
                d.bring_up(Startup::Enable, ctx);
            }
            while rig.devs.iter().any(|d| d.status().phase != Phase::Enabled) {
                assert!(
                    rig.k < BRING_UP_TICKS,
                    "bring-up did not finish: {:?}",
                    rig.devs.iter().map(|d| d.status()).collect::<Vec<_>>()
                );
                rig.tick(false);
            }
        }
        Setup::Direct => {
            let ctx = rig.ctx();
            rig.reqs.clear();
            for d in &rig.devs {
                for &c in &CHANNELS {
                    let reg = d.table()[c];
                    let (Some(at), Some(from)) = (d.read_address(c), reg.read) else {
                        continue;
                    };
                    if at == from {
                        continue;
                    }
                    for b in 0..reg.len as u16 {
                        let slot = at + b - x_table::INDIRECT_DATA;
                        let op = Op::Write {
                            addr: x_table::INDIRECT_ADDRESS + 2 * slot,
                            len: 2,
                            value: (from + b) as i64,
                        };
                        let _ = rig.reqs.push(Request::new(d.credential(), op, ctx));
                    }
                }
            }
            rig.link.receive(ctx);
            rig.link.encode(rig.reqs.as_slice(), ctx);
            rig.link.exchange(ctx).expect("the simulated bus stays up");
            rig.k += 1;
        }
    }
    let layout = rig.devs[0].layout();
    assert!(rig.devs.iter().all(|d| d.layout() == layout));
    // The first driven cycle's replies arrive at the second: measure from the third on.
    rig.tick(true);
    rig.tick(true);
    let stats = |rig: &Rig| rig.link.hardware().expect("the bus is up").stats();
    let missing_before = rig.link.counters().protocol.missing_replies;
    let mut prev = stats(&rig);
    let mut per_cycle = None;
    let mut delivered = 0;
    let mut deferred = 0;
    for _ in 0..cycles {
        let ups = rig.tick(true);
        let s = stats(&rig);
        let k = rig.k - 1;
        // A FAST read whose combined reply would not fit one packet goes out as SYNC READ.
        let reads = (s.sync_read + s.fast_sync_read) - (prev.sync_read + prev.fast_sync_read);
        let writes = s.sync_write - prev.sync_write;
        if reads == 0 && rig.link.counters().protocol.missing_replies > missing_before {
            // The stage keeps the line quiet after missing replies (a reply it could not
            // receive): nothing of this cycle went out.
            assert_eq!(s.bytes_in, prev.bytes_in, "cycle {k}: quiet");
            deferred += 1;
            prev = s;
            continue;
        }
        assert_eq!(
            (reads, writes),
            (1, 1),
            "cycle {k}: one read, one SYNC WRITE"
        );
        assert_eq!(s.packets_in - prev.packets_in, 2, "cycle {k}: nothing else");
        let write = s.sync_write_bytes - prev.sync_write_bytes;
        let read = s.bytes_in - prev.bytes_in - write + (s.bytes_out - prev.bytes_out);
        match per_cycle {
            None => per_cycle = Some((read, write)),
            Some(p) => assert_eq!(p, (read, write), "cycle {k}: the same bytes every cycle"),
        }
        // What the previous cycle's read delivered must be what the simulator holds (each
        // servo at rest at its own position, no error): a wrong indirect mapping would not be.
        for (i, u) in &ups {
            let want = if u.channel == x_channel::POSITION {
                rest_rad(*i)
            } else {
                0.0
            };
            assert_eq!(u.value, Some(want), "cycle {k}: servo {} {u:?}", i + 1);
        }
        delivered += ups.len() as u64;
        prev = s;
    }
    let c = rig.link.counters();
    let (read_bytes, write_bytes) = per_cycle.expect("at least one cycle with a read");
    Measured {
        layout,
        read_bytes,
        write_bytes,
        cycles,
        deferred,
        delivered,
        missing: c.protocol.missing_replies - missing_before,
    }
}

/// One way DynamixelSDK can read the registers of `n` servos every cycle.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SdkRead {
    /// The group calls, e.g. `GroupFastSyncRead(224, 11)`.
    pub name: String,
    /// Needs FAST SYNC READ (X430/540 firmware ≥ 45).
    pub fast: bool,
    /// Needs indirect addresses written once at set-up.
    pub indirect: bool,
    /// Instruction(s) + status packet(s), per cycle, before byte stuffing.
    pub bytes: u64,
}

/// Protocol 2.0 packet lengths (protocols.md §1.2, §1.5, §1.7), computed here so that the SDK
/// figures lean on nothing of the stage's.
mod wire {
    /// Instruction packet with `params` parameter bytes: header (4), ID, LEN (2), INST, CRC (2).
    pub fn instruction(params: u64) -> u64 {
        10 + params
    }
    /// Status packet carrying `data` bytes: as an instruction, plus the error byte.
    pub fn status(data: u64) -> u64 {
        11 + data
    }
    /// SYNC READ / FAST SYNC READ instruction: address (2), length (2), one ID per servo.
    pub fn sync_read(n: u64) -> u64 {
        instruction(4 + n)
    }
    /// BULK READ instruction: ID, address (2), length (2) per servo.
    pub fn bulk_read(n: u64) -> u64 {
        instruction(5 * n)
    }
    /// FAST reply: header (4), ID, LEN (2), INST, then ERR, ID, data, CRC (2) per servo.
    pub fn fast_reply(n: u64, data: u64) -> u64 {
        8 + n * (4 + data)
    }
}

/// What DynamixelSDK would send and receive per cycle to read `regs` (address, bytes) from
/// `n` servos, every way its group classes allow. A GroupSyncRead / GroupFastSyncRead reads
/// one (address, length) from every servo; a GroupBulkRead one (address, length) per servo
/// (an ID appears once per BULK READ). So the registers are read either as their contiguous
/// span, or as one group per contiguous run, or, with Indirect Address n ← each byte's
/// address written once, as one run at Indirect Data (224) of exactly their bytes.
pub fn sdk_reads(n: u8, regs: &[(u16, u16)]) -> Vec<SdkRead> {
    let n = n as u64;
    let mut sorted = regs.to_vec();
    sorted.sort_unstable();
    sorted.dedup();
    let (lo, span) = span(&sorted);
    let span = span as u64;
    let sum: u64 = sorted.iter().map(|r| r.1 as u64).sum();
    // Contiguous runs of registers: (address, bytes).
    let mut runs: Vec<(u16, u16)> = Vec::new();
    for &(a, l) in &sorted {
        match runs.last_mut() {
            Some((ra, rl)) if *ra + *rl >= a => *rl = (*rl).max(a + l - *ra),
            _ => runs.push((a, l)),
        }
    }
    let sync = |data: u64| wire::sync_read(n) + n * wire::status(data);
    let fast = |data: u64| wire::sync_read(n) + wire::fast_reply(n, data);
    let names = |class: &str| {
        runs.iter()
            .map(|(a, l)| format!("{class}({a}, {l})"))
            .collect::<Vec<_>>()
            .join(" + ")
    };
    let ind = x_table::INDIRECT_DATA;
    let mut out = vec![
        SdkRead {
            name: format!("GroupFastSyncRead({ind}, {sum}), indirect"),
            fast: true,
            indirect: true,
            bytes: fast(sum),
        },
        SdkRead {
            name: format!("GroupSyncRead({ind}, {sum}), indirect"),
            fast: false,
            indirect: true,
            bytes: sync(sum),
        },
        SdkRead {
            name: format!("GroupBulkRead(id, {ind}, {sum}) per servo, indirect"),
            fast: false,
            indirect: true,
            bytes: wire::bulk_read(n) + n * wire::status(sum),
        },
    ];
    if runs.len() > 1 {
        out.push(SdkRead {
            name: names("GroupFastSyncRead"),
            fast: true,
            indirect: false,
            bytes: runs.iter().map(|r| fast(r.1 as u64)).sum(),
        });
        out.push(SdkRead {
            name: names("GroupSyncRead"),
            fast: false,
            indirect: false,
            bytes: runs.iter().map(|r| sync(r.1 as u64)).sum(),
        });
    }
    out.extend([
        SdkRead {
            name: format!("GroupFastSyncRead({lo}, {span}), the span"),
            fast: true,
            indirect: false,
            bytes: fast(span),
        },
        SdkRead {
            name: format!("GroupSyncRead({lo}, {span}), the span"),
            fast: false,
            indirect: false,
            bytes: sync(span),
        },
        SdkRead {
            name: format!("GroupBulkRead(id, {lo}, {span}) per servo, the span"),
            fast: false,
            indirect: false,
            bytes: wire::bulk_read(n) + n * wire::status(span),
        },
    ]);
    out
}

/// The fewest bytes of [`sdk_reads`]; with `fast` false, among those without FAST SYNC READ
/// (servos whose firmware lacks it, the stage's `read = "sync"`).
pub fn sdk_minimum(n: u8, regs: &[(u16, u16)], fast: bool) -> SdkRead {
    sdk_reads(n, regs)
        .into_iter()
        .filter(|r| fast || !r.fast)
        .min_by_key(|r| r.bytes)
        .expect("at least one way")
}
