//! Bus load: how much of its wire each bus of a subsystem needs, from its devices, the states
//! bound to them, their rates and the bus speed.
//!
//! The traffic is found by running the scheduler's pipeline on paper, tick by tick over one
//! hyperperiod (the least common multiple of the divisors involved), the way
//! `conductor_executor::stages::Stages` runs it: a state raises its channel's sample and write flags
//! at its ticks, a device turns the flags into requests at its ticks, and the protocol puts
//! everything queued since its last tick on the wire at its ticks. Assumptions:
//!
//! * every writable state is commanded at each of its ticks (a controller sending every frame),
//!   except channels that switch a mode ([`SWITCH_CHANNELS`]: enable, torque_enable,
//!   operating_mode, an ODrive's state), which are written now and then, not every cycle;
//! * the wire is what the protocol puts on it; the bus being busy (a protocol deferring a
//!   transaction) is not modelled: this is the demand on the wire.
//!
//! Per protocol cycle:
//!
//! * **Dynamixel 2.0** (UART, 8N1: 10 bits a byte at the hardware's `baud`): one SYNC WRITE per
//!   register written, 14 + n·(1 + len) bytes for n servos; one read transaction for the servos
//!   with queued reads, each reading the span from its lowest to its highest register end
//!   (L bytes; an X-series servo whose registers are far apart reads them through indirect
//!   addressing, L = the sum of their lengths, as the device itself decides): SYNC READ (14 + n bytes) when every servo reads the same span, else BULK READ
//!   (10 + 5n), answered by one status packet per servo (11 + L bytes) after the servos' Return
//!   Delay Time each; with `read = "fast_sync"` the same instructions in their FAST form,
//!   answered by one combined packet (8 + Σ(4 + L) bytes) after one return delay. Byte stuffing
//!   (an `FF FF FD` in the data) is rare and ignored.
//! * **Dynamixel 1.0**: SYNC WRITE (L + 1)·N + 8 bytes; BULK READ 3N + 7 bytes, a status packet
//!   of 6 + L bytes per servo; with `read = "single"` one READ (8 bytes) and its status packet
//!   per cycle, for one servo in turn.
//! * **CAN** (`can_motors`; the hardware's `bitrate`, else 1 Mbit/s): every frame counted at its
//!   worst-case length with bit stuffing, 11-bit ID: 8n + 47 + ⌊(34 + 8n − 1)/4⌋ bits for n data
//!   bytes (interframe space included). An MIT motor sends one 8-byte command per device tick
//!   with anything to write or sample, answered by a 6-byte reply. An ODrive axis with
//!   `poll = true` sends one remote frame per message its sampled states need (position and
//!   velocity share Get_Encoder_Estimates; state and error the heartbeat), each answered by an
//!   8-byte frame, and one 8-byte setpoint frame per tick with writes. Cyclic messages an axis
//!   sends by itself (the heartbeat; all of them with `poll = false`) are configured on the axis,
//!   not in the manifest, and are not counted.
//! * **Simulated** protocols (`sim`) have no wire; unknown kinds no model: no load.

use conductor_devices::device::{Dxl1Model, DxlXConfig, Dynamixel1, DynamixelX, RegChannel};
use conductor_devices::protocol_stage::{self, Dxl1ReadMode, Dxl2ReadMode};
use conductor_devices::Device as _;

use super::Subsystem;

/// A load above this fraction of the wire refuses the manifest.
pub const MAX_LOAD: f64 = 1.0;
/// A load above this fraction of the wire is warned about.
pub const WARN_LOAD: f64 = 0.8;
/// Writable channels that switch a mode: counted as written now and then, not every cycle.
pub const SWITCH_CHANNELS: &[&str] = &["enable", "torque_enable", "operating_mode", "state"];

/// Base-tick steps simulated at most; longer hyperperiods are estimated over this many.
const MAX_STEPS: u64 = 100_000;
/// Line speed or bitrate when the hardware does not say.
const DEFAULT_SPEED: u32 = 1_000_000;

/// What a bus's wire is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wire {
    /// A UART, 8N1 (10 bits a byte).
    Uart {
        /// Line speed (bit/s).
        baud: u32,
    },
    /// A classic CAN bus.
    Can {
        /// Bitrate (bit/s).
        bitrate: u32,
    },
}

impl Wire {
    /// Wire time (ns) of `size` bytes (UART) or bits (CAN).
    pub fn ns(self, size: usize) -> f64 {
        match self {
            Wire::Uart { baud } => size as f64 * 10.0 * 1e9 / f64::from(baud.max(1)),
            Wire::Can { bitrate } => size as f64 * 1e9 / f64::from(bitrate.max(1)),
        }
    }
}

/// Packets or frames of one kind in a cycle (or, with `size` 0, a wait on the wire).
#[derive(Debug, Clone, PartialEq)]
pub struct Part {
    /// What they are, singular: "SYNC READ", "status packet", "MIT command", "return delay".
    pub what: &'static str,
    /// How many in the cycle.
    pub count: usize,
    /// Their total size: bytes on a UART, bits on CAN; 0 for a wait.
    pub size: usize,
    /// Their total wire time (ns).
    pub ns: f64,
}

/// The traffic of one protocol cycle, in wire order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Cycle {
    /// Packets, frames and waits.
    pub parts: Vec<Part>,
}

impl Cycle {
    /// Bytes (UART) or bits (CAN) on the wire.
    pub fn size(&self) -> usize {
        self.parts.iter().map(|p| p.size).sum()
    }

    /// Wire time (ns), waits included.
    pub fn ns(&self) -> f64 {
        self.parts.iter().map(|p| p.ns).sum()
    }

    fn add(&mut self, wire: Wire, what: &'static str, count: usize, size: usize) {
        self.wait(what, count, size, wire.ns(size));
    }

    fn wait(&mut self, what: &'static str, count: usize, size: usize, ns: f64) {
        match self.parts.iter_mut().find(|p| p.what == what) {
            Some(p) => {
                p.count += count;
                p.size += size;
                p.ns += ns;
            }
            None => self.parts.push(Part {
                what,
                count,
                size,
                ns,
            }),
        }
    }
}

/// The load of one bus.
#[derive(Debug, Clone, PartialEq)]
pub struct BusLoad {
    /// Index of the protocol in [`Subsystem::protocols`].
    pub protocol: usize,
    /// The wire.
    pub wire: Wire,
    /// The protocol cycle with the longest wire time.
    pub busiest: Cycle,
    /// Whether every cycle with traffic carries the same (then `busiest` is each of them).
    pub uniform: bool,
    /// Protocol cycles with traffic, per second.
    pub cycles_per_s: f64,
    /// Wire time used per second (ns).
    pub busy_ns_per_s: f64,
    /// Whether the whole hyperperiod was simulated (else an estimate over a long window).
    pub exact: bool,
}

impl BusLoad {
    /// Fraction of the wire's time in use (1.0 = 100 %).
    pub fn fraction(&self) -> f64 {
        self.busy_ns_per_s / 1e9
    }
}

/// CAN frame length (bits) with `data` data bytes, 11-bit ID, worst-case bit stuffing, the
/// 3-bit interframe space included.
pub const fn can_frame_bits(data: usize) -> usize {
    8 * data + 47 + (34 + 8 * data - 1) / 4
}

// Packet lengths (bytes on the wire, before stuffing). protocols.md §1.2/§1.5 (2.0) and §1.11
// (1.0); the unit tests check them against the encoders of `conductor_protocols`.

/// Dynamixel 2.0 SYNC READ / FAST SYNC READ of `n` servos: header, ID, LEN, INST, addr, len,
/// the IDs, CRC.
fn dxl2_sync_read(n: usize) -> usize {
    14 + n
}
/// Dynamixel 2.0 BULK READ / FAST BULK READ: (ID, addr, len) per servo.
fn dxl2_bulk_read(n: usize) -> usize {
    10 + 5 * n
}
/// Dynamixel 2.0 SYNC WRITE of `len` bytes to `n` servos.
fn dxl2_sync_write(n: usize, len: usize) -> usize {
    14 + n * (1 + len)
}
/// Dynamixel 2.0 status packet carrying `len` data bytes.
fn dxl2_status(len: usize) -> usize {
    11 + len
}
/// Dynamixel 2.0 FAST read reply: one packet, a slice (ERR, ID, data, CRC) per servo: what the
/// protocol stage waits for; checked against the encoder by a test.
fn dxl2_fast_reply(lens: &[usize]) -> usize {
    protocol_stage::fast_reply_len(lens.iter().copied())
}
/// Dynamixel 1.0 SYNC WRITE: LEN = (L + 1)·N + 4, plus FF FF ID LEN.
fn dxl1_sync_write(n: usize, len: usize) -> usize {
    (len + 1) * n + 4 + 4
}
/// Dynamixel 1.0 BULK READ: LEN = 3N + 3, plus FF FF ID LEN.
fn dxl1_bulk_read(n: usize) -> usize {
    3 * n + 3 + 4
}
/// Dynamixel 1.0 READ.
const DXL1_READ: usize = 8;
/// Dynamixel 1.0 status packet carrying `len` data bytes.
fn dxl1_status(len: usize) -> usize {
    6 + len
}

/// MIT command and reply payloads (bytes).
const MIT_COMMAND: usize = 8;
const MIT_REPLY: usize = 6;
/// ODrive payloads (bytes): every message the device sends or asks for has DLC 8.
const ODRIVE_DATA: usize = 8;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Proto {
    Dxl2 { fast: bool },
    Dxl1 { single: bool },
    Can,
}

/// What a device does with its flags at its tick.
enum Dev {
    /// Register-mapped (Dynamixel): each channel's registers.
    Reg(Vec<Option<RegChannel>>),
    /// MIT motor: one command per tick with anything to do.
    Mit,
    /// ODrive axis: remote frames for samples (when polling), one setpoint for writes.
    Odrive { poll: bool },
}

/// The ODrive message that carries a channel (remote frames are per message).
fn odrive_message(channel: &str) -> &str {
    match channel {
        "position" | "velocity" => "encoder_estimates",
        "state" | "error" => "heartbeat",
        other => other,
    }
}

/// One CAN frame queued for the wire, and its answer.
struct Frame {
    what: &'static str,
    data: usize,
    reply: Option<(&'static str, usize)>,
}

/// The bus as the scheduler would drive it.
struct Bus<'a> {
    proto: Proto,
    wire: Wire,
    return_delay_ns: f64,
    devs: Vec<(u32, Dev, &'a [conductor_devices::Channel])>,
    sample: Vec<Vec<bool>>,
    write: Vec<Vec<bool>>,
    /// Register buses: per device, the span of its queued reads.
    reads: Vec<Option<(u16, u16)>>,
    /// Register buses: queued writes (addr, len, device), one per device and register.
    writes: Vec<(u16, u8, usize)>,
    /// CAN: queued frames.
    frames: Vec<Frame>,
    /// Dynamixel 1.0 single reads: the next ID in turn.
    rr: u32,
}

impl Bus<'_> {
    fn device_tick(&mut self, d: usize) {
        let (_, dev, channels) = &self.devs[d];
        let writes: Vec<usize> = (0..channels.len())
            .filter(|&c| std::mem::take(&mut self.write[d][c]))
            .collect();
        let samples: Vec<usize> = (0..channels.len())
            .filter(|&c| std::mem::take(&mut self.sample[d][c]))
            .collect();
        match dev {
            Dev::Reg(table) => {
                for &c in &writes {
                    let Some(r) = table[c] else { continue };
                    let Some(addr) = r.write else { continue };
                    if !self
                        .writes
                        .iter()
                        .any(|w| w.0 == addr && w.1 == r.len && w.2 == d)
                    {
                        self.writes.push((addr, r.len, d));
                    }
                }
                for &c in &samples {
                    let Some(r) = table[c] else { continue };
                    let Some(addr) = r.read else { continue };
                    let end = addr + u16::from(r.len);
                    self.reads[d] = Some(match self.reads[d] {
                        Some((lo, hi)) => (lo.min(addr), hi.max(end)),
                        None => (addr, end),
                    });
                }
            }
            Dev::Mit => {
                if !writes.is_empty() || !samples.is_empty() {
                    self.frames.push(Frame {
                        what: "MIT command",
                        data: MIT_COMMAND,
                        reply: Some(("MIT reply", MIT_REPLY)),
                    });
                }
            }
            Dev::Odrive { poll } => {
                if *poll {
                    let mut asked: Vec<&str> = Vec::new();
                    for &c in &samples {
                        let m = odrive_message(channels[c].name);
                        if !asked.contains(&m) {
                            asked.push(m);
                            self.frames.push(Frame {
                                what: "ODrive request",
                                data: 0,
                                reply: Some(("ODrive reply", ODRIVE_DATA)),
                            });
                        }
                    }
                }
                if !writes.is_empty() {
                    self.frames.push(Frame {
                        what: "ODrive setpoint",
                        data: ODRIVE_DATA,
                        reply: None,
                    });
                }
            }
        }
    }

    /// What the protocol puts on the wire at its tick.
    fn protocol_tick(&mut self) -> Cycle {
        let mut cy = Cycle::default();
        let wire = self.wire;
        if self.proto == Proto::Can {
            for f in std::mem::take(&mut self.frames) {
                cy.add(wire, f.what, 1, can_frame_bits(f.data));
                if let Some((what, data)) = f.reply {
                    cy.add(wire, what, 1, can_frame_bits(data));
                }
            }
            return cy;
        }
        // Writes: one SYNC WRITE per register (address and length), in order of first use.
        let mut writes = std::mem::take(&mut self.writes);
        while let Some(&(addr, len, _)) = writes.first() {
            let n = writes.iter().filter(|w| w.0 == addr && w.1 == len).count();
            writes.retain(|w| !(w.0 == addr && w.1 == len));
            let size = match self.proto {
                Proto::Dxl1 { .. } => dxl1_sync_write(n, usize::from(len)),
                _ => dxl2_sync_write(n, usize::from(len)),
            };
            cy.add(wire, "SYNC WRITE", 1, size);
        }
        // Reads: one transaction.
        let queued: Vec<usize> = (0..self.devs.len())
            .filter(|&d| self.reads[d].is_some())
            .collect();
        if queued.is_empty() {
            return cy;
        }
        let delay = self.return_delay_ns;
        match self.proto {
            Proto::Dxl1 { single: true } => {
                // One servo per transaction, the next ID in turn; the others wait.
                let id = |d: usize| self.devs[d].0;
                let pick = queued
                    .iter()
                    .copied()
                    .filter(|&d| id(d) >= self.rr)
                    .min_by_key(|&d| id(d))
                    .or_else(|| queued.iter().copied().min_by_key(|&d| id(d)));
                let Some(d) = pick else { return cy };
                self.rr = id(d) + 1;
                let (lo, hi) = self.reads[d].take().unwrap_or_default();
                cy.add(wire, "READ", 1, DXL1_READ);
                cy.add(wire, "status packet", 1, dxl1_status(usize::from(hi - lo)));
                cy.wait("return delay", 1, 0, delay);
            }
            _ => {
                let spans: Vec<(u16, u16)> = queued
                    .iter()
                    .filter_map(|&d| self.reads[d].take())
                    .collect();
                let lens: Vec<usize> = spans.iter().map(|(lo, hi)| usize::from(hi - lo)).collect();
                let n = spans.len();
                let uniform = spans.iter().all(|s| *s == spans[0]);
                match self.proto {
                    Proto::Dxl1 { .. } => {
                        cy.add(wire, "BULK READ", 1, dxl1_bulk_read(n));
                        let size = lens.iter().map(|&l| dxl1_status(l)).sum();
                        cy.add(wire, "status packet", n, size);
                        cy.wait("return delay", n, 0, n as f64 * delay);
                    }
                    Proto::Dxl2 { fast } => {
                        // As the stage does: a combined reply too long for one packet is
                        // read with SYNC / BULK READ instead.
                        let fast = fast && protocol_stage::fast_read_fits(lens.iter().copied());
                        let (what, size) = match (uniform, fast) {
                            (true, false) => ("SYNC READ", dxl2_sync_read(n)),
                            (true, true) => ("FAST SYNC READ", dxl2_sync_read(n)),
                            (false, false) => ("BULK READ", dxl2_bulk_read(n)),
                            (false, true) => ("FAST BULK READ", dxl2_bulk_read(n)),
                        };
                        cy.add(wire, what, 1, size);
                        if fast {
                            cy.add(wire, "combined status packet", 1, dxl2_fast_reply(&lens));
                            cy.wait("return delay", 1, 0, delay);
                        } else {
                            let size = lens.iter().map(|&l| dxl2_status(l)).sum();
                            cy.add(wire, "status packet", n, size);
                            cy.wait("return delay", n, 0, n as f64 * delay);
                        }
                    }
                    Proto::Can => {}
                }
            }
        }
        cy.parts.retain(|p| p.size > 0 || p.ns > 0.0);
        cy
    }
}

fn gcd(a: u128, b: u128) -> u128 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

impl Subsystem {
    /// The load of the bus of protocol `protocol` (an index into [`Subsystem::protocols`]);
    /// `None` for buses without a wire model (simulated protocols, kinds the model does not
    /// know). See the [module](self) for the model.
    pub fn bus_load(&self, protocol: usize) -> Option<BusLoad> {
        let p = self.protocols.get(protocol)?;
        let hw = &self.hardware[p.hardware];
        let speed = |key: &str| {
            hw.params
                .int(key)
                .ok()
                .and_then(|v| u32::try_from(v).ok())
                .filter(|v| *v > 0)
                .unwrap_or(DEFAULT_SPEED)
        };
        let (proto, wire) = match p.kind.as_str() {
            "dynamixel2" => (
                Proto::Dxl2 {
                    fast: p.params.choice("read").ok() == Some(Dxl2ReadMode::Fast),
                },
                Wire::Uart {
                    baud: speed("baud"),
                },
            ),
            "dynamixel1" => (
                Proto::Dxl1 {
                    single: p.params.choice("read").ok() == Some(Dxl1ReadMode::Single),
                },
                Wire::Uart {
                    baud: speed("baud"),
                },
            ),
            "can_motors" => (
                Proto::Can,
                Wire::Can {
                    bitrate: speed("bitrate"),
                },
            ),
            _ => return None,
        };
        let return_delay_ns = p.params.int("return_delay_us").unwrap_or(0).max(0) as f64 * 1e3;

        // The bus's devices, with what they do at their ticks.
        let mut index = vec![None; self.devices.len()];
        let mut devs = Vec::new();
        for (i, d) in self.devices.iter().enumerate() {
            if d.protocol != protocol {
                continue;
            }
            let table = match (d.kind.as_str(), proto) {
                ("dynamixel_x", Proto::Dxl2 { .. }) => {
                    // The device picks its read layout from what its states sample (indirect
                    // addressing when it reads fewer bytes than the registers' span): ask it.
                    let mut x = DynamixelX::new(d.credential, DxlXConfig::default());
                    let sampled: Vec<usize> = self
                        .states
                        .iter()
                        .filter(|s| s.device == i && s.readable)
                        .map(|s| s.channel)
                        .collect();
                    x.configure_reads(&sampled);
                    let mut t = x.table().to_vec();
                    for (k, r) in t.iter_mut().enumerate() {
                        if r.read.is_some() {
                            r.read = x.read_address(k);
                        }
                    }
                    Some(t)
                }
                ("dynamixel1", Proto::Dxl1 { .. }) => Some(
                    Dynamixel1::new(d.credential, Dxl1Model::Ax, 512)
                        .table()
                        .to_vec(),
                ),
                _ => None,
            };
            let dev = match (d.kind.as_str(), table) {
                (_, Some(t)) => Dev::Reg(
                    d.channels
                        .iter()
                        .map(|c| t.iter().find(|r| r.name == c.name).copied())
                        .collect(),
                ),
                ("mit_motor", None) if proto == Proto::Can => Dev::Mit,
                ("odrive_axis", None) if proto == Proto::Can => Dev::Odrive {
                    poll: d.params.bool("poll").unwrap_or(true),
                },
                _ => return None,
            };
            index[i] = Some(devs.len());
            devs.push((i, d.credential.id, dev));
        }
        // Its states: (device on the bus, channel, divisor, samples, is written every tick).
        let states: Vec<(usize, usize, u64, bool, bool)> = self
            .states
            .iter()
            .filter_map(|s| {
                let d = index[s.device]?;
                let name = self.devices[s.device].channels[s.channel].name;
                let written = s.writable && !SWITCH_CHANNELS.contains(&name);
                Some((d, s.channel, u64::from(s.divisor), s.readable, written))
            })
            .collect();

        // One hyperperiod of the divisors, stepping by their common divisor.
        let dev_divs: Vec<u64> = devs
            .iter()
            .map(|(i, _, _)| u64::from(self.devices[*i].divisor))
            .collect();
        let p_div = u64::from(p.divisor);
        let all = || {
            std::iter::once(p_div)
                .chain(dev_divs.iter().copied())
                .chain(states.iter().map(|s| s.2))
        };
        let step = all().map(u128::from).fold(0, gcd).max(1);
        let mut period: u128 = 1;
        for d in all().map(u128::from) {
            period = period / gcd(period, d) * d;
            if period / step > u128::from(MAX_STEPS) {
                break;
            }
        }
        let full = period / step;
        let steps = full.min(u128::from(MAX_STEPS)) as u64;
        let step = step as u64;

        let mut bus = Bus {
            proto,
            wire,
            return_delay_ns,
            sample: devs
                .iter()
                .map(|(i, _, _)| vec![false; self.devices[*i].channels.len()])
                .collect(),
            write: devs
                .iter()
                .map(|(i, _, _)| vec![false; self.devices[*i].channels.len()])
                .collect(),
            reads: vec![None; devs.len()],
            writes: Vec::new(),
            frames: Vec::new(),
            rr: 0,
            devs: devs
                .into_iter()
                .map(|(i, id, dev)| (id, dev, self.devices[i].channels.as_slice()))
                .collect(),
        };
        let mut busiest = Cycle::default();
        let mut first: Option<Cycle> = None;
        let mut uniform = true;
        let (mut cycles, mut busy_ns) = (0u64, 0.0);
        for k in 0..steps {
            let t = k * step;
            for &(d, c, div, samples, written) in &states {
                if t.is_multiple_of(div) {
                    bus.sample[d][c] |= samples;
                    bus.write[d][c] |= written;
                }
            }
            for (d, &div) in dev_divs.iter().enumerate() {
                if t.is_multiple_of(div) {
                    bus.device_tick(d);
                }
            }
            if !t.is_multiple_of(p_div) {
                continue;
            }
            let cy = bus.protocol_tick();
            if cy.parts.is_empty() {
                continue;
            }
            cycles += 1;
            busy_ns += cy.ns();
            match &first {
                None => first = Some(cy.clone()),
                Some(f) => uniform &= *f == cy,
            }
            if cy.ns() > busiest.ns() {
                busiest = cy;
            }
        }
        let window_s = (steps * step) as f64 / self.rate_hz;
        Some(BusLoad {
            protocol,
            wire,
            busiest,
            uniform,
            cycles_per_s: cycles as f64 / window_s,
            busy_ns_per_s: busy_ns / window_s,
            exact: full <= u128::from(MAX_STEPS),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Manifest;
    use conductor_protocols::{dynamixel1 as dxl1, dynamixel2 as dxl2};

    /// The packet lengths are those the encoders produce.
    #[test]
    fn packet_lengths_match_the_encoders() {
        let mut b = [0u8; 512];
        let ids = [1u8, 2, 3, 4, 5, 6];
        for n in 1..=ids.len() {
            let ids = &ids[..n];
            assert_eq!(
                dxl2::sync_read(&mut b, 132, 4, ids).unwrap(),
                dxl2_sync_read(n)
            );
            assert_eq!(
                dxl2::fast_sync_read(&mut b, 132, 4, ids).unwrap(),
                dxl2_sync_read(n)
            );
            let bulk = ids.iter().map(|&id| dxl2::BulkReadEntry {
                id,
                addr: 126,
                len: u16::from(id),
            });
            assert_eq!(
                dxl2::bulk_read(&mut b, bulk.clone()).unwrap(),
                dxl2_bulk_read(n)
            );
            assert_eq!(
                dxl2::fast_bulk_read(&mut b, bulk).unwrap(),
                dxl2_bulk_read(n)
            );
            // Values without FF FF FD: no stuffing.
            let data = [1u8, 2, 3, 4];
            for len in [1usize, 2, 4] {
                let entries = ids.iter().map(|&id| (id, &data[..len]));
                assert_eq!(
                    dxl2::sync_write(&mut b, 116, len as u16, entries).unwrap(),
                    dxl2_sync_write(n, len)
                );
                let entries = ids.iter().map(|&id| (id, &data[..len]));
                assert_eq!(
                    dxl1::sync_write(&mut b, 30, len as u8, entries).unwrap(),
                    dxl1_sync_write(n, len)
                );
                assert_eq!(
                    dxl2::status(&mut b, 1, 0, &data[..len]).unwrap(),
                    dxl2_status(len)
                );
                assert_eq!(
                    dxl1::status(&mut b, 1, dxl1::ErrorBits(0), &data[..len]).unwrap(),
                    dxl1_status(len)
                );
            }
            // A combined reply with slices of different lengths.
            let payload = [7u8; 16];
            let slices: Vec<dxl2::FastStatusSlice> = ids
                .iter()
                .map(|&id| dxl2::FastStatusSlice {
                    error: 0,
                    id,
                    data: &payload[..usize::from(id) + 1],
                })
                .collect();
            let lens: Vec<usize> = slices.iter().map(|s| s.data.len()).collect();
            assert_eq!(
                dxl2::fast_status(&mut b, &slices).unwrap(),
                dxl2_fast_reply(&lens)
            );
            let bulk1 = ids.iter().map(|&id| dxl1::BulkReadEntry {
                len: 2,
                id,
                addr: 36,
            });
            assert_eq!(dxl1::bulk_read(&mut b, bulk1).unwrap(), dxl1_bulk_read(n));
        }
        assert_eq!(dxl1::read(&mut b, 1, 36, 2).unwrap(), DXL1_READ);
        // protocols.md §1.5 / §1.8: SYNC READ of ids 1, 2 is 16 bytes, its status 15.
        assert_eq!(dxl2_sync_read(2), 16);
        assert_eq!(dxl2_status(4), dxl2::status_len(4));
    }

    /// Worst-case classic CAN frames, 11-bit ID, by hand: 47 bits of overhead and interframe
    /// space, 8 per data byte, one stuff bit per 4 of the 34 + 8n stuffable bits (less one).
    #[test]
    fn can_frames_at_worst_case_stuffing() {
        assert_eq!(can_frame_bits(0), 47 + 8); // remote frame: ⌊33/4⌋ = 8
        assert_eq!(can_frame_bits(6), 48 + 47 + 20); // ⌊81/4⌋ = 20
        assert_eq!(can_frame_bits(8), 64 + 47 + 24); // ⌊97/4⌋ = 24
        assert_eq!(can_frame_bits(8), 135);
    }

    fn dxl_bus(servos: usize, extra: &str, states: &str) -> String {
        let mut s = format!(
            "system = \"t\"\n[subsystems.leg]\nrate_hz = 250\n\
             [subsystems.leg.hardware.uart]\nkind = \"serial\"\nport = \"/dev/null\"\nbaud = 1000000\n\
             [subsystems.leg.protocols.robotis]\nkind = \"dynamixel2\"\nhardware = \"uart\"\n{extra}\n"
        );
        for i in 1..=servos {
            s += &format!(
                "[subsystems.leg.devices.s{i}]\nkind = \"dynamixel_x\"\nprotocol = \"robotis\"\nid = {i}\n"
            );
        }
        for i in 1..=servos {
            s += &states.replace("{i}", &i.to_string());
        }
        s
    }

    const POSITION: &str = "[subsystems.leg.states.p{i}]\ndevice = \"s{i}\"\nchannel = \"position\"\nwritable = true\n";

    fn load(text: &str, protocol: usize) -> BusLoad {
        let m = Manifest::parse(text, "t.toml").unwrap_or_else(|e| panic!("{e}"));
        m.subsystems[0].bus_load(protocol).unwrap()
    }

    /// As [`load`], with the base rate raised to `rate_hz` after validation (a manifest with a
    /// bus above 100 % is refused, so it is validated at a lower rate).
    fn load_at(text: &str, rate_hz: f64) -> BusLoad {
        let m = Manifest::parse(text, "t.toml").unwrap_or_else(|e| panic!("{e}"));
        let mut sub = m.subsystems[0].clone();
        sub.rate_hz = rate_hz;
        sub.bus_load(0).unwrap()
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-9 * b.abs().max(1.0)
    }

    fn sizes(c: &Cycle) -> Vec<(&str, usize, usize)> {
        c.parts.iter().map(|p| (p.what, p.count, p.size)).collect()
    }

    /// The leg of deploy/minihubo-right-leg-dxl.toml: 6 XM430 at 1 Mbit/s, 250 Hz, positions
    /// read and written: SYNC WRITE 14 + 6·5 = 44 B, SYNC READ 14 + 6 = 20 B, 6 status packets
    /// of 11 + 4 = 15 B: 154 B = 1.54 ms per cycle, 250 cycles/s, 38.5 %.
    #[test]
    fn six_servos_sync() {
        let l = load(&dxl_bus(6, "", POSITION), 0);
        assert_eq!(l.wire, Wire::Uart { baud: 1_000_000 });
        assert_eq!(
            sizes(&l.busiest),
            [
                ("SYNC WRITE", 1, 44),
                ("SYNC READ", 1, 20),
                ("status packet", 6, 90)
            ]
        );
        assert_eq!(l.busiest.size(), 154);
        assert!(close(l.busiest.ns(), 1_540_000.0));
        assert!(l.uniform && l.exact);
        assert!(close(l.cycles_per_s, 250.0));
        assert!(close(l.fraction(), 0.385), "{}", l.fraction());
    }

    /// FAST SYNC READ: one combined reply of 8 + 6·(4 + 4) = 56 B; 44 + 20 + 56 = 120 B → 30 %.
    /// A return delay of 20 µs waits once for it: 1.2 ms + 20 µs → 30.5 %.
    #[test]
    fn six_servos_fast_sync_with_return_delay() {
        let l = load(
            &dxl_bus(6, "read = \"fast_sync\"\nreturn_delay_us = 20", POSITION),
            0,
        );
        assert_eq!(
            sizes(&l.busiest),
            [
                ("SYNC WRITE", 1, 44),
                ("FAST SYNC READ", 1, 20),
                ("combined status packet", 1, 56),
                ("return delay", 1, 0)
            ]
        );
        assert!(close(l.busiest.ns(), 1_220_000.0));
        assert!(close(l.fraction(), 0.305), "{}", l.fraction());
        // With SYNC READ, six status packets wait six return delays: 1.54 + 0.12 ms → 41.5 %.
        let l = load(&dxl_bus(6, "return_delay_us = 20", POSITION), 0);
        assert!(close(l.fraction(), 0.415), "{}", l.fraction());
    }

    /// 150 servos reading their positions with `read = "fast_sync"`: a combined reply of
    /// 8 + 150·8 = 1208 B would not fit one packet, so the stage (and this estimate) reads with
    /// SYNC READ: 14 + 150 B, 150 status packets of 15 B.
    #[test]
    fn a_fast_read_too_long_for_one_packet_is_counted_as_sync_read() {
        let text =
            dxl_bus(150, "read = \"fast_sync\"", POSITION).replace("rate_hz = 250", "rate_hz = 10");
        let l = load(&text, 0);
        let parts = sizes(&l.busiest);
        assert!(parts.contains(&("SYNC READ", 1, 164)), "{parts:?}");
        assert!(parts.contains(&("status packet", 150, 2250)), "{parts:?}");
        // 64 servos still fit one combined reply: 8 + 64·8 = 520 B.
        let text =
            dxl_bus(64, "read = \"fast_sync\"", POSITION).replace("rate_hz = 250", "rate_hz = 10");
        let l = load(&text, 0);
        let parts = sizes(&l.busiest);
        assert!(
            parts.contains(&("combined status packet", 1, 520)),
            "{parts:?}"
        );
    }

    /// Servo 1 also reads its velocity (128..132): it reads the span 128..136 (8 B), the others
    /// 132..136: a BULK READ of 10 + 5·6 = 40 B, status packets 5·15 + 19 = 94 B; with the
    /// SYNC WRITE 44 B: 178 B per cycle → 44.5 %.
    #[test]
    fn different_spans_make_a_bulk_read() {
        let mut text = dxl_bus(6, "", POSITION);
        text += "[subsystems.leg.states.v1]\ndevice = \"s1\"\nchannel = \"velocity\"\n";
        let l = load(&text, 0);
        assert_eq!(
            sizes(&l.busiest),
            [
                ("SYNC WRITE", 1, 44),
                ("BULK READ", 1, 40),
                ("status packet", 6, 94)
            ]
        );
        assert!(close(l.fraction(), 0.445), "{}", l.fraction());
    }

    /// Servos 4–6 at 125 Hz: every other cycle carries the first three only (SYNC WRITE
    /// 14 + 3·5 = 29 B, SYNC READ 17 B, 3·15 = 45 B: 91 B). 125·1.54 + 125·0.91 ms = 306.25 ms/s.
    #[test]
    fn states_at_different_rates() {
        let mut text = dxl_bus(3, "", POSITION);
        for i in 4..=6 {
            text += &format!(
                "[subsystems.leg.devices.s{i}]\nkind = \"dynamixel_x\"\nprotocol = \"robotis\"\nid = {i}\n"
            );
            text += &POSITION.replace("{i}", &i.to_string());
            text += "rate_hz = 125\n";
        }
        let l = load(&text, 0);
        assert!(!l.uniform);
        assert_eq!(l.busiest.size(), 154);
        assert!(close(l.cycles_per_s, 250.0));
        assert!(close(l.busy_ns_per_s, 306_250_000.0), "{}", l.busy_ns_per_s);
    }

    fn can_bus(rate: u32, motors: &str, states: &str, hw: &str) -> String {
        format!(
            "system = \"t\"\n[subsystems.q]\nrate_hz = {rate}\n\
             [subsystems.q.hardware.can0]\n{hw}\n\
             [subsystems.q.protocols.mit]\nkind = \"can_motors\"\nhardware = \"can0\"\n{motors}{states}"
        )
    }

    fn mit(n: usize) -> (String, String) {
        let (mut devs, mut states) = (String::new(), String::new());
        for i in 1..=n {
            devs += &format!(
                "[subsystems.q.devices.m{i}]\nkind = \"mit_motor\"\nprotocol = \"mit\"\nid = {i}\n"
            );
            states += &format!(
                "[subsystems.q.states.p{i}]\ndevice = \"m{i}\"\nchannel = \"position\"\nwritable = true\n"
            );
        }
        (devs, states)
    }

    const SLCAN: &str = "kind = \"slcan\"\nport = \"/dev/null\"\nbitrate = 1000000";

    /// The user's report: 12 MIT motors at 1 kHz on one 1 Mbit/s bus. Each: a command of
    /// 8 bytes (135 bits) and a reply of 6 (115 bits): 12·250 = 3000 bits = 3 ms per 1 ms cycle.
    #[test]
    fn twelve_mit_motors_at_1khz_need_three_buses() {
        let (d, s) = mit(12);
        let l = load_at(&can_bus(100, &d, &s, SLCAN), 1000.0);
        assert_eq!(l.wire, Wire::Can { bitrate: 1_000_000 });
        assert_eq!(
            sizes(&l.busiest),
            [("MIT command", 12, 1620), ("MIT reply", 12, 1380)]
        );
        assert!(close(l.busiest.ns(), 3_000_000.0));
        assert!(close(l.fraction(), 3.0), "{}", l.fraction());
        // At 500 kbit/s, twice as long.
        let hw = SLCAN.replace("1000000", "500000");
        let l = load_at(&can_bus(100, &d, &s, &hw), 1000.0);
        assert!(close(l.fraction(), 6.0), "{}", l.fraction());
    }

    /// Without a `bitrate` (socketcan today; can_sim) the bus counts as 1 Mbit/s.
    #[test]
    fn can_without_a_bitrate_is_1_mbit() {
        let (d, s) = mit(3);
        let hw = "kind = \"can_sim\"\nmit = \"1,2,3\"";
        let l = load(&can_bus(500, &d, &s, hw), 0);
        assert_eq!(l.wire, Wire::Can { bitrate: 1_000_000 });
        // 3·250 bits at 500 Hz: 375 kbit/s.
        assert!(close(l.fraction(), 0.375), "{}", l.fraction());
    }

    /// An ODrive polled for position (and velocity: the same message), current and temperature,
    /// its position commanded: 3 remote frames (55 bits) and 3 replies (135), one setpoint (135):
    /// 705 bits per tick.
    #[test]
    fn odrive_requests_one_message_per_sampled_source() {
        let d = "[subsystems.q.devices.ax]\nkind = \"odrive_axis\"\nprotocol = \"mit\"\nid = 1\n";
        let mut s = String::new();
        for (name, ch, w) in [
            ("p", "position", true),
            ("v", "velocity", false),
            ("i", "current", false),
            ("t", "temperature", false),
            ("st", "state", false),
        ] {
            s += &format!(
                "[subsystems.q.states.{name}]\ndevice = \"ax\"\nchannel = \"{ch}\"\nwritable = {w}\n"
            );
        }
        let l = load(&can_bus(1000, d, &s, SLCAN), 0);
        assert_eq!(
            sizes(&l.busiest),
            [
                ("ODrive request", 4, 220),
                ("ODrive reply", 4, 540),
                ("ODrive setpoint", 1, 135)
            ]
        );
        // (the heartbeat for `state` is the fourth request)
        assert!(close(l.fraction(), 0.895), "{}", l.fraction());
        // poll = false: only the setpoint.
        let d = d.to_string() + "poll = false\n";
        let l = load(&can_bus(1000, &d, &s, SLCAN), 0);
        assert_eq!(sizes(&l.busiest), [("ODrive setpoint", 1, 135)]);
    }

    /// Divisors that are not multiples of each other: a device ticking every 2nd base tick, its
    /// states every 2nd and 3rd. Flags raised at ticks 0, 2, 3, 4 of each 6 are sent at the
    /// device's ticks 0, 2, 4: 3 frames per 6 ticks, not max(1/2, 1/3) nor their sum.
    #[test]
    fn rates_that_do_not_divide_each_other() {
        let d = "[subsystems.q.devices.m1]\nkind = \"mit_motor\"\nprotocol = \"mit\"\nid = 1\nrate_hz = 600\n";
        let s = "[subsystems.q.states.p]\ndevice = \"m1\"\nchannel = \"position\"\nrate_hz = 600\n\
                 [subsystems.q.states.v]\ndevice = \"m1\"\nchannel = \"velocity\"\nrate_hz = 400\n";
        let l = load(&can_bus(1200, d, s, SLCAN), 0);
        assert!(close(l.cycles_per_s, 600.0), "{}", l.cycles_per_s);
        // Now the device every tick: flags at 0, 2, 3, 4 → 4 frames per 6 ticks = 800/s.
        let d = d.replace("rate_hz = 600\n", "");
        let l = load(&can_bus(1200, &d, s, SLCAN), 0);
        assert!(close(l.cycles_per_s, 800.0), "{}", l.cycles_per_s);
        assert!(close(l.fraction(), 800.0 * 250.0 / 1e6), "{}", l.fraction());
    }

    fn dxl1_bus(read: &str) -> String {
        let mut s = format!(
            "system = \"t\"\n[subsystems.arm]\nrate_hz = 100\n\
             [subsystems.arm.hardware.uart]\nkind = \"serial\"\nport = \"/dev/null\"\nbaud = 1000000\n\
             [subsystems.arm.protocols.p1]\nkind = \"dynamixel1\"\nhardware = \"uart\"\nread = \"{read}\"\n"
        );
        for i in 1..=4 {
            s += &format!(
                "[subsystems.arm.devices.s{i}]\nkind = \"dynamixel1\"\nmodel = \"mx\"\nprotocol = \"p1\"\nid = {i}\n\
                 [subsystems.arm.states.j{i}]\ndevice = \"s{i}\"\nchannel = \"position\"\nwritable = true\n"
            );
        }
        s
    }

    /// Dynamixel 1.0, 4 MX servos at 100 Hz: SYNC WRITE (2 + 1)·4 + 8 = 20 B, BULK READ
    /// 3·4 + 7 = 19 B, 4 status packets of 6 + 2 = 8 B: 71 B = 0.71 ms → 7.1 %. With single
    /// reads one servo per cycle: 20 + 8 + 8 = 36 B → 3.6 %.
    #[test]
    fn dynamixel1_bulk_and_single() {
        let l = load(&dxl1_bus("bulk"), 0);
        assert_eq!(
            sizes(&l.busiest),
            [
                ("SYNC WRITE", 1, 20),
                ("BULK READ", 1, 19),
                ("status packet", 4, 32)
            ]
        );
        assert!(close(l.fraction(), 0.071), "{}", l.fraction());
        let l = load(&dxl1_bus("single"), 0);
        assert_eq!(
            sizes(&l.busiest),
            [
                ("SYNC WRITE", 1, 20),
                ("READ", 1, 8),
                ("status packet", 1, 8)
            ]
        );
        assert!(l.uniform);
        assert!(close(l.fraction(), 0.036), "{}", l.fraction());
    }

    /// Mode switches are not counted as written every cycle; simulated buses have no load.
    #[test]
    fn switches_and_simulated_buses() {
        let mut text = dxl_bus(6, "", POSITION);
        text +=
            "[subsystems.leg.states.te]\ndevice = \"s1\"\nchannel = \"enable\"\nwritable = true\n";
        let l = load(&text, 0);
        // `enable` is written now and then, not every cycle (and has no register).
        assert_eq!(
            l.busiest.parts[0],
            Part {
                what: "SYNC WRITE",
                count: 1,
                size: 44,
                ns: 440_000.0
            }
        );
        let sim = "system = \"t\"\n[subsystems.s]\nrate_hz = 1000\n\
                   [subsystems.s.hardware.h]\nkind = \"sine\"\n\
                   [subsystems.s.protocols.p]\nkind = \"sim\"\nhardware = \"h\"\n\
                   [subsystems.s.devices.d]\nkind = \"sim\"\nprotocol = \"p\"\nid = 1\n\
                   [subsystems.s.states.x]\ndevice = \"d\"\n";
        let m = Manifest::parse(sim, "t.toml").unwrap();
        assert!(m.subsystems[0].bus_load(0).is_none());
    }
}
