//! A Dynamixel Protocol 2.0 bus of X-series servos (XM430-W350 control table) that speaks the
//! real wire protocol: it scans instruction packets (CRC, stuffing), answers with status
//! packets in the order and timing real servos use, and moves each servo through a first-order
//! motor model.
//!
//! The simulator is sans-IO: [`DxlBusSim::feed`] takes the bytes the host sent and the time
//! they arrived, and hands back each reply packet with the time its last byte would leave the
//! bus (return delay and, if enabled, the wire time at the baud rate). The in-process
//! [`super::hardware::DxlSimHardware`] and the pty/UDP runners deliver them at those times.

use std::f64::consts::PI;

use conductor_protocols::dynamixel2::{self as dxl, FastStatusSlice, Request, Scanner};

use crate::protocol::wire_ns;

/// Control-table size simulated (RAM and EEPROM up to the indirect data).
pub const TABLE_SIZE: usize = 256;

/// Simulator configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct DxlSimConfig {
    /// Servo IDs on the bus.
    pub ids: Vec<u8>,
    /// Line speed, for reply timing.
    pub baud: u32,
    /// Return Delay Time, µs (written to address 9 in 2 µs units).
    pub return_delay_us: u32,
    /// Whether replies take their wire time at `baud` (else only the return delay).
    pub baud_timing: bool,
    /// Time constant of the position response (s).
    pub tau_s: f64,
    /// Initial position (raw, 2048 = middle).
    pub initial_position: i32,
    /// Model number reported by PING (1020 = XM430-W350).
    pub model: u16,
    /// Firmware version reported by PING (≥ 45: Fast Sync Read supported).
    pub firmware: u8,
    /// Torque enabled at start.
    pub torque_on: bool,
}

impl Default for DxlSimConfig {
    fn default() -> Self {
        Self {
            ids: (1..=6).collect(),
            baud: 1_000_000,
            return_delay_us: 0,
            baud_timing: true,
            tau_s: 0.05,
            initial_position: 2048,
            model: 1020,
            firmware: 45,
            torque_on: true,
        }
    }
}

/// What the simulator received and sent, by kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DxlSimStats {
    /// Bytes received from the host.
    pub bytes_in: u64,
    /// Valid instruction packets received.
    pub packets_in: u64,
    /// Wire bytes of those packets.
    pub packet_bytes_in: u64,
    /// Bytes the scanner threw away (garbage, bad CRC, truncated, ...).
    pub discarded_in: u64,
    /// Candidate packets rejected (bad CRC, bad header, truncated, ...).
    pub rejected_in: u64,
    /// PING instructions.
    pub ping: u64,
    /// READ instructions.
    pub read: u64,
    /// WRITE and REG WRITE instructions.
    pub write: u64,
    /// SYNC READ instructions.
    pub sync_read: u64,
    /// FAST SYNC READ instructions.
    pub fast_sync_read: u64,
    /// SYNC WRITE instructions.
    pub sync_write: u64,
    /// Wire bytes of the SYNC WRITE instructions.
    pub sync_write_bytes: u64,
    /// BULK READ and FAST BULK READ instructions.
    pub bulk_read: u64,
    /// BULK WRITE instructions.
    pub bulk_write: u64,
    /// Other instructions (action, reboot, reset, clear, backup).
    pub other: u64,
    /// Status packets sent.
    pub packets_out: u64,
    /// Bytes sent.
    pub bytes_out: u64,
}

/// One simulated servo: a control table and a motor model.
#[derive(Debug, Clone)]
pub struct SimServo {
    /// The control table.
    pub table: [u8; TABLE_SIZE],
    pos: f64,
    vel: f64,
    t_ns: Option<u64>,
    registered: Option<(u16, Vec<u8>)>,
}

const VEL_UNIT: f64 = 0.229 * 2.0 * PI / 60.0;
const PULSE_RAD: f64 = 2.0 * PI / 4096.0;

impl SimServo {
    fn new(id: u8, cfg: &DxlSimConfig) -> Self {
        let mut t = [0u8; TABLE_SIZE];
        let mut put =
            |addr: usize, bytes: &[u8]| t[addr..addr + bytes.len()].copy_from_slice(bytes);
        put(0, &cfg.model.to_le_bytes());
        put(6, &[cfg.firmware]);
        put(7, &[id]);
        put(8, &[3]); // 1 Mbps
        put(9, &[(cfg.return_delay_us / 2).min(254) as u8]);
        put(11, &[3]); // position control
        put(13, &[2]);
        put(31, &[80]);
        put(32, &160u16.to_le_bytes());
        put(34, &95u16.to_le_bytes());
        put(36, &885u16.to_le_bytes());
        put(38, &1193u16.to_le_bytes());
        put(44, &350u32.to_le_bytes());
        put(48, &4095u32.to_le_bytes());
        put(52, &0u32.to_le_bytes());
        put(63, &[52]);
        put(64, &[cfg.torque_on as u8]);
        put(68, &[2]);
        put(84, &800u16.to_le_bytes());
        put(116, &cfg.initial_position.to_le_bytes());
        put(144, &120u16.to_le_bytes());
        put(146, &35u8.to_le_bytes());
        let mut s = Self {
            table: t,
            pos: cfg.initial_position as f64,
            vel: 0.0,
            t_ns: None,
            registered: None,
        };
        s.publish(0.0);
        s
    }

    fn i32_at(&self, addr: usize) -> i32 {
        i32::from_le_bytes(self.table[addr..addr + 4].try_into().unwrap_or([0; 4]))
    }

    /// Present Position (raw).
    pub fn present_position(&self) -> i32 {
        self.i32_at(132)
    }

    /// Goal Position (raw).
    pub fn goal_position(&self) -> i32 {
        self.i32_at(116)
    }

    /// Torque Enable.
    pub fn torque_on(&self) -> bool {
        self.table[64] != 0
    }

    /// Advances the motor model to `now_ns`.
    fn advance(&mut self, now_ns: u64, tau_s: f64) {
        let Some(t0) = self.t_ns.replace(now_ns) else {
            return;
        };
        if now_ns <= t0 {
            // No time has passed (instructions that arrived in one chunk share a time stamp):
            // only an instant response (tau 0) in a position mode has moved.
            if tau_s <= 0.0 && self.torque_on() && !matches!(self.table[11], 0 | 1 | 16) {
                self.pos = self.goal_position() as f64;
                self.publish(0.0);
            }
            return;
        }
        let dt = (now_ns - t0) as f64 * 1e-9;
        let before = self.pos;
        let mut err = 0.0;
        if self.torque_on() {
            match self.table[11] {
                // Velocity control: integrate Goal Velocity.
                1 => {
                    let goal_v = self.i32_at(104) as f64 * VEL_UNIT / PULSE_RAD;
                    self.pos += goal_v * dt;
                }
                // Current and PWM control: no load model, the shaft stays.
                0 | 16 => {}
                // Position modes: first-order response to Goal Position.
                _ => {
                    let goal = self.goal_position() as f64;
                    let k = if tau_s > 0.0 {
                        (-dt / tau_s).exp()
                    } else {
                        0.0
                    };
                    self.pos = goal + (self.pos - goal) * k;
                    err = goal - self.pos;
                }
            }
        }
        self.vel = (self.pos - before) / dt;
        self.publish(err);
    }

    /// Writes the model's state into the Present registers.
    fn publish(&mut self, err: f64) {
        let pos = self.pos.round().clamp(i32::MIN as f64, i32::MAX as f64) as i32;
        let vel = (self.vel * PULSE_RAD / VEL_UNIT)
            .round()
            .clamp(-1023.0, 1023.0) as i32;
        // Current grows with the tracking error, saturating at the current limit (1193).
        let cur = (err * 2.0).round().clamp(-1193.0, 1193.0) as i16;
        self.table[126..128].copy_from_slice(&cur.to_le_bytes());
        self.table[128..132].copy_from_slice(&vel.to_le_bytes());
        self.table[132..136].copy_from_slice(&pos.to_le_bytes());
        self.table[122] = (vel != 0) as u8;
    }

    /// Applies a write; returns the status error number (0 = ok).
    fn write(&mut self, addr: u16, data: &[u8]) -> u8 {
        let (a, end) = (addr as usize, addr as usize + data.len());
        if end > TABLE_SIZE || data.is_empty() {
            return 0x07;
        }
        // EEPROM (below Torque Enable) is writable only with torque off.
        if a < 64 && self.torque_on() {
            return 0x07;
        }
        // Read-only items: model, firmware, present values.
        if a < 7 || (a < 148 && end > 120) {
            return 0x07;
        }
        self.table[a..end].copy_from_slice(data);
        0
    }

    fn read(&self, addr: u16, len: u16) -> Option<&[u8]> {
        self.table.get(addr as usize..addr as usize + len as usize)
    }
}

/// A reply packet and the time its last byte is on the wire.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SimReply {
    /// When the host can have it (ns, the clock of `feed`'s `now_ns`).
    pub ready_ns: u64,
    /// The status packet.
    pub bytes: Vec<u8>,
    /// Replying servo (0xFE for a fast reply).
    pub id: u8,
    /// For read replies: the control-table address and the data, for ground truth.
    pub data: Option<(u16, Vec<u8>)>,
}

/// The simulated bus.
pub struct DxlBusSim {
    cfg: DxlSimConfig,
    servos: Vec<SimServo>,
    scanner: Box<Scanner<2048>>,
    stats: DxlSimStats,
    pkt: Vec<u8>,
    last_rx_ns: Option<u64>,
}

/// Longest gap between the bytes of one instruction packet (protocol2.md, 1.5 ms).
const BYTE_GAP_NS: u64 = 1_500_000;

impl std::fmt::Debug for DxlBusSim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DxlBusSim")
            .field("ids", &self.cfg.ids)
            .field("stats", &self.stats)
            .finish()
    }
}

/// One status packet to send: ID, error byte, parameters, ground truth of a read.
struct Answer(u8, u8, Vec<u8>, Option<(u16, Vec<u8>)>);

impl DxlBusSim {
    /// A bus with the servos of `cfg`.
    pub fn new(cfg: DxlSimConfig) -> Self {
        let servos = cfg.ids.iter().map(|&id| SimServo::new(id, &cfg)).collect();
        Self {
            servos,
            cfg,
            scanner: Box::new(Scanner::new()),
            stats: DxlSimStats::default(),
            pkt: vec![0; 4096],
            last_rx_ns: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &DxlSimConfig {
        &self.cfg
    }

    /// Counters since creation.
    pub fn stats(&self) -> DxlSimStats {
        let s = self.scanner.stats();
        DxlSimStats {
            bytes_in: s.bytes_in,
            discarded_in: s.discarded_bytes(),
            rejected_in: s.rejected_packets(),
            ..self.stats
        }
    }

    /// IDs of the servos, in bus order.
    pub fn ids(&self) -> Vec<u8> {
        self.servos.iter().map(|s| s.table[7]).collect()
    }

    /// The servo with `id`.
    pub fn servo(&self, id: u8) -> Option<&SimServo> {
        self.servos
            .iter()
            .position(|s| s.table[7] == id)
            .map(|i| &self.servos[i])
    }

    /// Advances every servo's model to `now_ns` (the motor moves between instructions too).
    pub fn advance(&mut self, now_ns: u64) {
        let tau = self.cfg.tau_s;
        for s in &mut self.servos {
            s.advance(now_ns, tau);
        }
    }

    fn index(&self, id: u8) -> Option<usize> {
        self.servos.iter().position(|s| s.table[7] == id)
    }

    /// Declares that the host has gone quiet (its instruction timeout): a partial packet is
    /// discarded, as a servo does after the 1.5 ms byte gap.
    pub fn expire(&mut self) {
        self.scanner.expire();
        while self.scanner.next_packet().is_some() {}
    }

    /// Takes bytes the host sent, arriving (last byte) at `now_ns`; calls `reply` for every
    /// status packet, in bus order. A partial packet left from more than 1.5 ms before is
    /// dropped first (the servos' byte-gap rule).
    pub fn feed(&mut self, bytes: &[u8], now_ns: u64, mut reply: impl FnMut(SimReply)) {
        if self.last_rx_ns.is_some_and(|t| now_ns > t + BYTE_GAP_NS) {
            self.expire();
        }
        self.last_rx_ns = Some(now_ns);
        let mut pending = Vec::new();
        let mut rest = bytes;
        loop {
            let n = self.scanner.push(rest);
            rest = &rest[n..];
            while let Some(p) = self.scanner.next_packet() {
                if p.is_status() {
                    continue;
                }
                self.stats.packets_in += 1;
                self.stats.packet_bytes_in += p.wire_len as u64;
                let id = p.id;
                let wire_len = p.wire_len;
                match Request::from_packet(&p) {
                    Ok(req) => {
                        // Owned copy: the packet borrows the scanner.
                        let owned = OwnedRequest::from(&req);
                        pending.push((id, wire_len, Ok(owned)));
                    }
                    Err(_) => pending.push((id, wire_len, Err(p.instruction))),
                }
            }
            if rest.is_empty() {
                break;
            }
        }
        // Replies start once the instruction is off the wire.
        let mut t = now_ns
            + if self.cfg.baud_timing {
                wire_ns(bytes.len(), self.cfg.baud)
            } else {
                0
            };
        for (id, wire_len, req) in pending {
            self.advance(now_ns);
            match req {
                Ok(r) => self.execute(id, wire_len, &r, &mut t, &mut reply),
                Err(_) => {
                    // Unknown or malformed instruction to one servo: Instruction Error.
                    if id != dxl::BROADCAST_ID && self.index(id).is_some() {
                        self.emit(Answer(id, 0x02, Vec::new(), None), &mut t, &mut reply);
                    }
                }
            }
        }
    }

    fn emit(&mut self, a: Answer, t: &mut u64, reply: &mut impl FnMut(SimReply)) {
        let Answer(id, err, params, data) = a;
        let Ok(n) = dxl::status(&mut self.pkt, id, err, &params) else {
            return;
        };
        self.send(n, id, data, t, reply);
    }

    fn send(
        &mut self,
        n: usize,
        id: u8,
        data: Option<(u16, Vec<u8>)>,
        t: &mut u64,
        reply: &mut impl FnMut(SimReply),
    ) {
        *t += self.cfg.return_delay_us as u64 * 1000;
        if self.cfg.baud_timing {
            *t += wire_ns(n, self.cfg.baud);
        }
        self.stats.packets_out += 1;
        self.stats.bytes_out += n as u64;
        reply(SimReply {
            ready_ns: *t,
            bytes: self.pkt[..n].to_vec(),
            id,
            data,
        });
    }

    fn execute(
        &mut self,
        id: u8,
        wire_len: usize,
        r: &OwnedRequest,
        t: &mut u64,
        reply: &mut impl FnMut(SimReply),
    ) {
        let targets: Vec<usize> = if id == dxl::BROADCAST_ID {
            (0..self.servos.len()).collect()
        } else {
            self.index(id).into_iter().collect()
        };
        let answers = id != dxl::BROADCAST_ID;
        match r {
            OwnedRequest::Ping => {
                self.stats.ping += 1;
                let mut order = targets;
                order.sort_by_key(|&i| self.servos[i].table[7]);
                for i in order {
                    let s = &self.servos[i];
                    let p = vec![s.table[0], s.table[1], s.table[6]];
                    let sid = s.table[7];
                    self.emit(Answer(sid, 0, p, None), t, reply);
                }
            }
            OwnedRequest::Read { addr, len } => {
                self.stats.read += 1;
                for i in targets {
                    let s = &self.servos[i];
                    let sid = s.table[7];
                    let a = match s.read(*addr, *len) {
                        Some(d) => Answer(sid, 0, d.to_vec(), Some((*addr, d.to_vec()))),
                        None => Answer(sid, 0x07, Vec::new(), None),
                    };
                    if answers {
                        self.emit(a, t, reply);
                    }
                }
            }
            OwnedRequest::Write { addr, data, reg } => {
                self.stats.write += 1;
                for i in targets {
                    let err = if *reg {
                        self.servos[i].registered = Some((*addr, data.clone()));
                        self.servos[i].table[69] = 1;
                        0
                    } else {
                        self.servos[i].write(*addr, data)
                    };
                    let sid = self.servos[i].table[7];
                    if answers && self.servos[i].table[68] >= 2 {
                        self.emit(Answer(sid, err, Vec::new(), None), t, reply);
                    }
                }
            }
            OwnedRequest::Action => {
                self.stats.other += 1;
                for i in targets {
                    let s = &mut self.servos[i];
                    let err = match s.registered.take() {
                        Some((a, d)) => {
                            s.table[69] = 0;
                            s.write(a, &d)
                        }
                        None => 0x02,
                    };
                    let sid = s.table[7];
                    if answers {
                        self.emit(Answer(sid, err, Vec::new(), None), t, reply);
                    }
                }
            }
            OwnedRequest::Other => {
                self.stats.other += 1;
                for i in targets {
                    let sid = self.servos[i].table[7];
                    if answers {
                        self.emit(Answer(sid, 0, Vec::new(), None), t, reply);
                    }
                }
            }
            OwnedRequest::SyncRead {
                fast,
                addr,
                len,
                ids,
            } => {
                if *fast {
                    self.stats.fast_sync_read += 1;
                    let entries: Vec<(u8, u16, u16)> =
                        ids.iter().map(|&i| (i, *addr, *len)).collect();
                    self.fast_reply(&entries, t, reply);
                } else {
                    self.stats.sync_read += 1;
                    for &sid in ids {
                        self.read_reply(sid, *addr, *len, t, reply);
                    }
                }
            }
            OwnedRequest::BulkRead { fast, entries } => {
                self.stats.bulk_read += 1;
                if *fast {
                    self.fast_reply(entries, t, reply);
                } else {
                    for &(sid, a, l) in entries {
                        self.read_reply(sid, a, l, t, reply);
                    }
                }
            }
            OwnedRequest::SyncWrite { addr, entries } => {
                self.stats.sync_write += 1;
                self.stats.sync_write_bytes += wire_len as u64;
                for (sid, data) in entries {
                    if let Some(i) = self.index(*sid) {
                        self.servos[i].write(*addr, data);
                    }
                }
            }
            OwnedRequest::BulkWrite { entries } => {
                self.stats.bulk_write += 1;
                for (sid, a, data) in entries {
                    if let Some(i) = self.index(*sid) {
                        self.servos[i].write(*a, data);
                    }
                }
            }
        }
    }

    fn read_reply(
        &mut self,
        sid: u8,
        addr: u16,
        len: u16,
        t: &mut u64,
        reply: &mut impl FnMut(SimReply),
    ) {
        // A servo that is not on the bus stays silent (the host times out).
        let Some(i) = self.index(sid) else { return };
        let a = match self.servos[i].read(addr, len) {
            Some(d) => Answer(sid, 0, d.to_vec(), Some((addr, d.to_vec()))),
            None => Answer(sid, 0x07, Vec::new(), None),
        };
        self.emit(a, t, reply);
    }

    fn fast_reply(
        &mut self,
        entries: &[(u8, u16, u16)],
        t: &mut u64,
        reply: &mut impl FnMut(SimReply),
    ) {
        // A fast read is answered only if every listed servo is present (each adds its slice
        // to the same packet; a missing one breaks the chain).
        let mut datas = Vec::new();
        for &(sid, a, l) in entries {
            let Some(i) = self.index(sid) else { return };
            let Some(d) = self.servos[i].read(a, l) else {
                return;
            };
            datas.push((sid, a, d.to_vec()));
        }
        let slices: Vec<FastStatusSlice<'_>> = datas
            .iter()
            .map(|(sid, _, d)| FastStatusSlice {
                error: 0,
                id: *sid,
                data: d,
            })
            .collect();
        let Ok(n) = dxl::fast_status(&mut self.pkt, &slices) else {
            return;
        };
        // Every servo waits its return delay before its slice.
        *t += self.cfg.return_delay_us as u64 * 1000 * (entries.len() as u64 - 1);
        let truth = datas.first().map(|(_, a, _)| *a);
        let all: Vec<u8> = datas
            .iter()
            .flat_map(|(_, _, d)| d.iter().copied())
            .collect();
        self.send(n, dxl::BROADCAST_ID, truth.map(|a| (a, all)), t, reply);
    }
}

/// An owned copy of a decoded instruction.
#[derive(Debug, Clone, PartialEq, Eq)]
enum OwnedRequest {
    Ping,
    Read {
        addr: u16,
        len: u16,
    },
    Write {
        addr: u16,
        data: Vec<u8>,
        reg: bool,
    },
    Action,
    Other,
    SyncRead {
        fast: bool,
        addr: u16,
        len: u16,
        ids: Vec<u8>,
    },
    SyncWrite {
        addr: u16,
        entries: Vec<(u8, Vec<u8>)>,
    },
    BulkRead {
        fast: bool,
        entries: Vec<(u8, u16, u16)>,
    },
    BulkWrite {
        entries: Vec<(u8, u16, Vec<u8>)>,
    },
}

impl From<&Request<'_>> for OwnedRequest {
    fn from(r: &Request<'_>) -> Self {
        match *r {
            Request::Ping => OwnedRequest::Ping,
            Request::Read { addr, len } => OwnedRequest::Read { addr, len },
            Request::Write { addr, data } => OwnedRequest::Write {
                addr,
                data: data.to_vec(),
                reg: false,
            },
            Request::RegWrite { addr, data } => OwnedRequest::Write {
                addr,
                data: data.to_vec(),
                reg: true,
            },
            Request::Action => OwnedRequest::Action,
            Request::FactoryReset(_)
            | Request::Reboot
            | Request::ClearMultiTurn
            | Request::ControlTableBackup(_) => OwnedRequest::Other,
            Request::SyncRead {
                fast,
                addr,
                len,
                ids,
            } => OwnedRequest::SyncRead {
                fast,
                addr,
                len,
                ids: ids.to_vec(),
            },
            Request::SyncWrite { addr, .. } => OwnedRequest::SyncWrite {
                addr,
                entries: r
                    .sync_write_entries()
                    .map(|(id, d)| (id, d.to_vec()))
                    .collect(),
            },
            Request::BulkRead { fast, .. } => OwnedRequest::BulkRead {
                fast,
                entries: r
                    .bulk_read_entries()
                    .map(|e| (e.id, e.addr, e.len))
                    .collect(),
            },
            Request::BulkWrite { .. } => OwnedRequest::BulkWrite {
                entries: r
                    .bulk_write_entries()
                    .map(|e| (e.id, e.addr, e.data.to_vec()))
                    .collect(),
            },
        }
    }
}
