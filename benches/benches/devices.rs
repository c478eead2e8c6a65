//! The Dynamixel protocol stage: CPU per bus cycle, and how fast a bus can cycle.
//!
//! 1. **CPU per cycle** (criterion): one full cycle of the stage for 6 (a mini-Hubo leg) and 41
//!    (the Hubo) X-series servos: every device samples and writes its goal, the stage bundles
//!    one SYNC WRITE and one SYNC READ (or FAST SYNC READ), then scans the replies and every
//!    device converts its value. The reply bytes were produced once by the bus simulator.
//! 2. **Bus utilisation** (computed, printed): the 41-DOF Hubo split over 1, 2 and 4 buses at
//!    1 and 4 Mbit/s. Bytes per cycle are what the stage emits and the simulator answers; the
//!    cycle time is the simulator's baud-accurate timing (instruction wire time, then each
//!    status packet's return delay and wire time); the achievable loop rate is its inverse.
//!    USB adapter latency (1 ms FTDI latency timer, or less with `low_latency`) is host side and
//!    not on the wire: it limits a request/response loop on top of these figures.
//! 3. **Read layout** (measured, printed): the Hubo reading Hardware Error Status (70, 1 B),
//!    Present Current (126, 2 B), Present Velocity (128, 4 B) and Present Position (132, 4 B)
//!    every cycle. The protocol stage runs against the in-process simulator
//!    (`support/dxl_reads.rs`), once with the layout the device chooses (indirect addressing,
//!    11 B per servo) and once with the registers' contiguous span (70..136, 66 B), each with
//!    SYNC READ and FAST SYNC READ; the simulator counts the bytes of every cycle. Beside them,
//!    what DynamixelSDK's group classes would send for the same registers, computed from the
//!    packet layouts, and its minimum. `tests/dxl_read_layout.rs` asserts the same figures.
//!
//!    The servos are set up directly (unmanaged devices; the stage writes the Indirect
//!    Addresses the devices report); the test checks that the devices' own bring-up leads to
//!    the same bytes per cycle. A FAST SYNC READ whose combined reply would exceed 1024 bytes
//!    (the contiguous span from 15 servos on) goes out as SYNC READ: those rows show its bytes.

use std::time::Duration;

#[path = "support/dxl_reads.rs"]
mod dxl_reads;

use conductor_devices::device::{x_channel, DxlXConfig, DynamixelX};
use conductor_devices::protocol_stage::{Dxl2Protocol, Dxl2ReadMode, Timing};
use conductor_devices::sim::dxl::{DxlBusSim, DxlSimConfig};
use conductor_devices::{Bounded, Credential, Device, Protocol, Reply, Request, TickCtx, Update};
use criterion::{black_box, Criterion};

/// What each cycle samples.
#[derive(Clone, Copy, Debug)]
enum Reads {
    /// Present Position (4 bytes).
    Position,
    /// Present Current, Velocity and Position (126..136, 10 bytes).
    PosVelCur,
}

impl Reads {
    fn channels(self) -> &'static [usize] {
        match self {
            Reads::Position => &[x_channel::POSITION],
            Reads::PosVelCur => &[x_channel::POSITION, x_channel::VELOCITY, x_channel::CURRENT],
        }
    }
}

struct Cycle {
    proto: Dxl2Protocol,
    devs: Vec<DynamixelX>,
    reqs: Bounded<Request>,
    tx: Bounded<u8>,
    replies: Bounded<Reply>,
    ups: Bounded<Update>,
    reads: Reads,
    k: u64,
}

const PERIOD_NS: u64 = 10_000_000;

impl Cycle {
    fn new(n: u8, mode: Dxl2ReadMode, reads: Reads, return_delay_us: u32, baud: u32) -> Self {
        let timing = Timing {
            baud,
            return_delay_ns: return_delay_us as u64 * 1000,
            timeout_ns: 1_000_000,
        };
        Self {
            proto: Dxl2Protocol::new(timing, mode, n as usize, 4 * n as usize),
            devs: (1..=n)
                .map(|id| DynamixelX::new(Credential::id(id as u32), DxlXConfig::default()))
                .collect(),
            reqs: Bounded::with_capacity(8 * n as usize),
            tx: Bounded::with_capacity(8192),
            replies: Bounded::with_capacity(8 * n as usize),
            ups: Bounded::with_capacity(8 * n as usize),
            reads,
            k: 0,
        }
    }

    fn ctx(&self) -> TickCtx {
        TickCtx {
            tick: self.k,
            now_ns: 1_000_000_000 + self.k * PERIOD_NS,
        }
    }

    /// Devices → requests → bundled bytes.
    fn downstream(&mut self) -> &[u8] {
        let ctx = self.ctx();
        self.reqs.clear();
        self.tx.clear();
        for (i, d) in self.devs.iter_mut().enumerate() {
            for &c in self.reads.channels() {
                d.sample(c, ctx, &mut self.reqs);
            }
            d.write(x_channel::POSITION, 0.1 * (i as f64 % 7.0) - 0.3, ctx);
            d.flush(ctx, &mut self.reqs);
        }
        self.proto.encode(self.reqs.as_slice(), &mut self.tx, ctx);
        self.tx.as_slice()
    }

    /// Reply bytes → replies → device updates; returns the number of values.
    fn upstream(&mut self, wire: &[u8]) -> usize {
        let ctx = TickCtx {
            tick: self.k,
            now_ns: self.ctx().now_ns + PERIOD_NS / 2,
        };
        self.replies.clear();
        self.proto.decode(wire, &[], &mut self.replies, ctx);
        self.proto.expire(&mut self.replies, ctx);
        let mut values = 0;
        for r in self.replies.as_slice() {
            let d = &mut self.devs[(r.cred.id - 1) as usize];
            self.ups.clear();
            d.reply(r, &mut self.ups);
            values += self
                .ups
                .as_slice()
                .iter()
                .filter(|u| u.value.is_some())
                .count();
        }
        self.k += 1;
        values
    }
}

/// The simulator's answer to one cycle's bytes: (reply bytes, time from the first instruction
/// byte to the last reply byte, ns).
fn simulate(n: u8, tx: &[u8], return_delay_us: u32, baud: u32) -> (Vec<u8>, u64) {
    let mut sim = DxlBusSim::new(DxlSimConfig {
        ids: (1..=n).collect(),
        baud,
        return_delay_us,
        baud_timing: true,
        ..DxlSimConfig::default()
    });
    let mut wire = Vec::new();
    let mut end = 0;
    sim.feed(tx, 0, |r| {
        wire.extend_from_slice(&r.bytes);
        end = end.max(r.ready_ns);
    });
    (wire, end)
}

fn cpu_per_cycle(c: &mut Criterion) {
    let mut g = c.benchmark_group("dxl2_cycle");
    g.measurement_time(Duration::from_secs(3));
    for n in [6u8, 41] {
        for (mode, name) in [
            (Dxl2ReadMode::Sync, "sync"),
            (Dxl2ReadMode::Fast, "fast_sync"),
        ] {
            for reads in [Reads::Position, Reads::PosVelCur] {
                let mut cyc = Cycle::new(n, mode, reads, 0, 1_000_000);
                let tx = cyc.downstream().to_vec();
                let (wire, _) = simulate(n, &tx, 0, 1_000_000);
                let expected = n as usize * reads.channels().len();
                assert_eq!(
                    cyc.upstream(&wire),
                    expected,
                    "the replies answer the requests"
                );
                let id = format!("{n}_servos/{name}/{reads:?}");
                g.bench_function(id, |b| {
                    b.iter(|| {
                        let out = cyc.downstream().len();
                        let v = cyc.upstream(black_box(&wire));
                        assert_eq!(v, expected);
                        black_box(out + v)
                    })
                });
            }
        }
    }
    g.finish();
}

fn utilisation() {
    println!();
    println!(
        "Bus utilisation, 41-DOF Hubo: goal positions written (one SYNC WRITE) and the reads below"
    );
    println!("(one SYNC READ or FAST SYNC READ) per cycle, per bus, at the simulator's baud-accurate timing.");
    println!("| buses | baud | read | return delay | servos/bus | bytes/cycle/bus | cycle µs | max loop Hz | busy at 250 Hz | busy at 1 kHz |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for buses in [1u8, 2, 4] {
        for baud in [1_000_000u32, 4_000_000] {
            for (mode, reads, label) in [
                (Dxl2ReadMode::Sync, Reads::Position, "sync pos"),
                (Dxl2ReadMode::Fast, Reads::Position, "fast pos"),
                (Dxl2ReadMode::Sync, Reads::PosVelCur, "sync pos+vel+cur"),
                (Dxl2ReadMode::Fast, Reads::PosVelCur, "fast pos+vel+cur"),
            ] {
                for rd in [0u32, 20] {
                    // The busiest bus carries ceil(41 / buses) servos.
                    let n = 41u8.div_ceil(buses);
                    let mut cyc = Cycle::new(n, mode, reads, rd, baud);
                    let tx = cyc.downstream().to_vec();
                    let (wire, ns) = simulate(n, &tx, rd, baud);
                    let bytes = tx.len() + wire.len();
                    let rate = 1e9 / ns as f64;
                    println!(
                        "| {buses} | {:.0}M | {label} | {rd} µs | {n} | {bytes} | {:.0} | {:.0} | {:.0} % | {:.0} % |",
                        baud as f64 / 1e6,
                        ns as f64 / 1e3,
                        rate,
                        ns as f64 * 250.0 / 1e7,
                        ns as f64 * 1000.0 / 1e7,
                    );
                }
            }
        }
    }
}

fn read_layout() {
    use dxl_reads::{measure, sdk_minimum, sdk_reads, wire_ns, Reading, Setup, REGISTERS};
    const CYCLES: u64 = 20;
    let splits = [(1u8, 41u8), (2, 21), (4, 11)];
    println!();
    println!(
        "Read layout, 41-DOF Hubo: Hardware Error Status (70, 1 B), Present Current (126, 2 B), \
         Present Velocity (128, 4 B)"
    );
    println!(
        "and Present Position (132, 4 B) read every cycle, per bus; the goal positions in one \
         SYNC WRITE beside them."
    );
    println!(
        "Measured: the protocol stage against the simulator, {CYCLES} cycles each, every one \
         the same bytes; return delay 0,"
    );
    println!("so the wire time is 10 bits per byte. SDK minimum: of the read mode (below).");
    println!(
        "| buses | servos/bus | baud | read | layout | B/servo | bytes/cycle | wire µs | max Hz \
         | SDK minimum | ours / SDK | with goal SYNC WRITE: bytes / µs / max Hz | values |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (buses, n) in splits {
        for baud in [1_000_000u32, 4_000_000] {
            for (mode, fast, read) in [
                (Dxl2ReadMode::Sync, false, "SYNC READ"),
                (Dxl2ReadMode::Fast, true, "FAST SYNC READ"),
            ] {
                let sdk = sdk_minimum(n, &REGISTERS, fast);
                for reading in [Reading::Chosen, Reading::Contiguous] {
                    let m = measure(n, mode, reading, Setup::Direct, baud, CYCLES);
                    let layout = match reading {
                        Reading::Chosen if m.layout.indirect > 0 => "chosen: indirect",
                        Reading::Chosen => "chosen: span",
                        Reading::Contiguous => "contiguous span",
                    };
                    let ns = wire_ns(m.read_bytes, baud);
                    let all = m.read_bytes + m.write_bytes;
                    let all_ns = wire_ns(all, baud);
                    let values = if m.complete(n) {
                        "all".to_string()
                    } else {
                        format!("{} of {} missing", m.missing, m.cycles * n as u64 * 4)
                    };
                    println!(
                        "| {buses} | {n} | {:.0}M | {read} | {layout} | {} | {} | {:.0} | {:.0} \
                         | {} | {:.2} | {all} / {:.0} / {:.0} | {values} |",
                        baud as f64 / 1e6,
                        m.per_servo(),
                        m.read_bytes,
                        ns / 1e3,
                        1e9 / ns,
                        sdk.bytes,
                        m.read_bytes as f64 / sdk.bytes as f64,
                        all_ns / 1e3,
                        1e9 / all_ns,
                    );
                }
            }
        }
    }
    println!();
    println!(
        "DynamixelSDK, the same registers, bytes per cycle (instruction(s) + status packets, \
         before byte stuffing), computed from"
    );
    println!("the packet layouts (protocols.md §1.2, §1.5, §1.7); max Hz at 1 Mbit/s in brackets:");
    let ns: Vec<u8> = splits.iter().map(|s| s.1).collect();
    let head: Vec<String> = ns.iter().map(|n| format!("{n} servos")).collect();
    println!("| DynamixelSDK read | {} |", head.join(" | "));
    println!("|---|{}", "---|".repeat(ns.len()));
    let ways: Vec<Vec<_>> = ns.iter().map(|&n| sdk_reads(n, &REGISTERS)).collect();
    for w in 0..ways[0].len() {
        let first = &ways[0][w];
        let tag = if first.name == sdk_minimum(ns[0], &REGISTERS, true).name {
            " **← SDK minimum**"
        } else if first.name == sdk_minimum(ns[0], &REGISTERS, false).name {
            " **← minimum without FAST SYNC READ**"
        } else {
            ""
        };
        let cells: Vec<String> = ways
            .iter()
            .map(|ws| {
                let b = ws[w].bytes;
                format!("{b} ({:.0})", 1e9 / wire_ns(b, 1_000_000))
            })
            .collect();
        println!("| {}{tag} | {} |", first.name, cells.join(" | "));
    }
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    cpu_per_cycle(&mut c);
    c.final_summary();
    utilisation();
    read_layout();
}
