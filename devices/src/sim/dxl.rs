//! A Dynamixel Protocol 2.0 bus of X-series servos (XM430-W350 control table) that speaks the
//! real wire protocol: it scans instruction packets (CRC, stuffing), answers with status
//! packets in the order and timing real servos use, and moves each servo through a first-order
//! motor model.
//!
//! The servos are as strict as the e-Manual describes, never kinder:
//!
//! * **Power-on**: Torque Enable (64) = 0 and Goal Position (116) = Present Position. With
//!   torque off the shaft does not move, whatever goal is written; a goal written meanwhile is
//!   kept, and enabling torque sends the servo to it (a stale goal makes it jump).
//! * **Access rules**: EEPROM (< 64) and the Indirect Addresses (168–223) are writable only
//!   with torque off, read-only items (model, firmware, Registered Instruction, Hardware Error
//!   Status, Present values) never: Access Error (0x07) to a WRITE, silently ignored in a SYNC
//!   or BULK WRITE (which have no reply). Out-of-range values of Torque Enable, Status Return
//!   Level, Return Delay Time, Operating Mode and Indirect Address get Data Range Error (0x04);
//!   a Goal Position outside the Min/Max Position Limits (position mode) or a Goal Velocity
//!   beyond the Velocity Limit (velocity mode) gets Data Limit Error (0x06). A refused write
//!   changes nothing.
//! * **Indirect addressing**: Indirect Data n (224 + n − 1) reads and writes the byte at the
//!   address held in Indirect Address n (168 + 2(n − 1), default 224 + n − 1, i.e. itself),
//!   with the rules of the target address. Only Indirect Address/Data 1–28 exist here (the
//!   simulated table ends at [`TABLE_SIZE`]), so an Indirect Address must be in 64..256.
//! * **Hardware errors** ([`SimServo::inject_hardware_error`]): bits latch in Hardware Error
//!   Status (70); a bit also set in Shutdown (63) turns torque off and Torque Enable = 1 is
//!   refused (Access Error) until a REBOOT; while address 70 ≠ 0 every status packet of that
//!   servo carries the Alert bit (0x80).
//! * **REBOOT** is answered, then RAM (≥ 64) returns to its power-on values (torque off, errors
//!   cleared, Goal Position = Present Position, indirect addresses at their defaults); EEPROM
//!   is kept.
//! * **Status Return Level** (68): 0 answers PING only, 1 PING and reads, 2 everything. IDs
//!   that are not on the bus never answer.
//! * **Return Delay Time** is the servo's register 9 (2 µs units) at reply time.
//!
//! The simulator is sans-IO: [`DxlBusSim::feed`] takes the bytes the host sent and the time
//! they arrived, and hands back each reply packet with the time its last byte would leave the
//! bus (return delay and, if enabled, the wire time at the baud rate). The in-process
//! [`super::hardware::DxlSimHardware`] and the pty/UDP runners deliver them at those times.

use std::f64::consts::PI;

use conductor_protocols::dynamixel2::{
    self as dxl, FastStatusSlice, Instruction, Request, RequestError, Scanner,
};

/// Control-table size simulated (RAM and EEPROM up to Indirect Data 28).
pub const TABLE_SIZE: usize = 256;

/// Torque Enable.
const TORQUE_ENABLE: usize = 64;
/// Status Return Level.
const STATUS_RETURN_LEVEL: usize = 68;
/// Registered Instruction.
const REGISTERED: usize = 69;
/// Hardware Error Status.
const HARDWARE_ERROR: usize = 70;
/// Shutdown (error bits that cut torque).
const SHUTDOWN: usize = 63;
/// Indirect Address 1 (2 bytes each, 28 of them).
const INDIRECT_ADDRESS: usize = 168;
/// Indirect Data 1 (1 byte each, 28 of them).
const INDIRECT_DATA: usize = 224;
/// Indirect items 1–28 exist in the simulated table.
const INDIRECT_COUNT: usize = 28;

/// Status error numbers (protocols.md §1.6).
const ERR_INSTRUCTION: u8 = 0x02;
const ERR_DATA_RANGE: u8 = 0x04;
const ERR_DATA_LENGTH: u8 = 0x05;
const ERR_DATA_LIMIT: u8 = 0x06;
const ERR_ACCESS: u8 = 0x07;
/// The Alert bit of the status error byte.
const ALERT: u8 = 0x80;

/// Time on the wire of `bytes` 8N1 bytes at `baud` (10 bits each), rounded up. The simulator's
/// own, so that it does not lean on the protocol stage it is meant to test.
fn wire_ns(bytes: usize, baud: u32) -> u64 {
    (bytes as u64 * 10 * 1_000_000_000).div_ceil(baud.max(1) as u64)
}

/// Simulator configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct DxlSimConfig {
    /// Servo IDs on the bus.
    pub ids: Vec<u8>,
    /// Line speed, for reply timing.
    pub baud: u32,
    /// Power-on Return Delay Time, µs: written to register 9 in 2 µs units (odd values round
    /// down, at most 508). The host may change register 9 afterwards; replies follow it.
    pub return_delay_us: u32,
    /// Whether replies take their wire time at `baud` (else only the return delay).
    pub baud_timing: bool,
    /// Time constant of the position response (s).
    pub tau_s: f64,
    /// Initial position (raw, 2048 = middle); also the power-on Goal Position.
    pub initial_position: i32,
    /// Model number reported by PING (1020 = XM430-W350), for every servo; change one servo's
    /// with [`SimServo::set_model`].
    pub model: u16,
    /// Firmware version reported by PING (≥ 45: Fast Sync Read supported).
    pub firmware: u8,
    /// Torque enabled at power-on. A real X-series servo powers up with torque off (the
    /// default); `true` is for legacy uses that never write Torque Enable.
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
            torque_on: false,
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
    /// Servo restarts by REBOOT (a broadcast REBOOT counts every servo).
    pub reboot: u64,
    /// Other instructions (action, reset, clear, backup, malformed or unknown ones).
    pub other: u64,
    /// Status packets sent.
    pub packets_out: u64,
    /// Bytes sent.
    pub bytes_out: u64,
}

/// One entry of the instruction log ([`DxlBusSim::with_log`]): the time the instruction
/// arrived (`now_ns` of [`DxlBusSim::feed`]), the ID, the instruction code, the address (0 if
/// the instruction has none) and the data or parameters:
///
/// * READ: the address and the 2 length bytes; SYNC READ / FAST SYNC READ: the address, then
///   the 2 length bytes and the IDs;
/// * WRITE / REG WRITE: the address and the data;
/// * SYNC WRITE and BULK WRITE: one entry per servo entry, with that servo's ID, the address
///   and its data (ignored entries included);
/// * anything else (PING, ACTION, REBOOT, BULK READ, malformed or unknown instructions):
///   address 0 and the raw parameters.
pub type InstructionRecord = (u64, u8, u8, u16, Vec<u8>);

/// One simulated servo: a control table and a motor model.
#[derive(Debug, Clone)]
pub struct SimServo {
    /// The control table, as the servo holds it (indirect data bytes are the storage behind
    /// Indirect Data n only when Indirect Address n points at itself).
    pub table: [u8; TABLE_SIZE],
    pos: f64,
    vel: f64,
    t_ns: Option<u64>,
    registered: Option<(u16, Vec<u8>)>,
}

const VEL_UNIT: f64 = 0.229 * 2.0 * PI / 60.0;
const PULSE_RAD: f64 = 2.0 * PI / 4096.0;

fn put(t: &mut [u8; TABLE_SIZE], addr: usize, bytes: &[u8]) {
    t[addr..addr + bytes.len()].copy_from_slice(bytes);
}

/// Items the host can never write: model number and information, firmware version,
/// Registered Instruction, Hardware Error Status, Realtime Tick, Moving, Moving Status and the
/// Present values (124–147).
fn read_only(a: usize) -> bool {
    a < 7 || a == REGISTERED || a == HARDWARE_ERROR || (120..148).contains(&a)
}

fn is_indirect_address(a: usize) -> bool {
    (INDIRECT_ADDRESS..INDIRECT_ADDRESS + 2 * INDIRECT_COUNT).contains(&a)
}

fn is_indirect_data(a: usize) -> bool {
    (INDIRECT_DATA..INDIRECT_DATA + INDIRECT_COUNT).contains(&a)
}

impl SimServo {
    fn new(id: u8, cfg: &DxlSimConfig) -> Self {
        let mut t = [0u8; TABLE_SIZE];
        put(&mut t, 0, &cfg.model.to_le_bytes());
        put(&mut t, 6, &[cfg.firmware]);
        put(&mut t, 7, &[id]);
        put(&mut t, 8, &[3]); // 1 Mbps
        put(&mut t, 9, &[(cfg.return_delay_us / 2).min(254) as u8]);
        put(&mut t, 11, &[3]); // position control
        put(&mut t, 12, &[255]);
        put(&mut t, 13, &[2]);
        put(&mut t, 24, &10u32.to_le_bytes());
        put(&mut t, 31, &[80]);
        put(&mut t, 32, &160u16.to_le_bytes());
        put(&mut t, 34, &95u16.to_le_bytes());
        put(&mut t, 36, &885u16.to_le_bytes());
        put(&mut t, 38, &1193u16.to_le_bytes());
        put(&mut t, 40, &32767u32.to_le_bytes());
        put(&mut t, 44, &350u32.to_le_bytes());
        put(&mut t, 48, &4095u32.to_le_bytes());
        put(&mut t, 52, &0u32.to_le_bytes());
        put(&mut t, SHUTDOWN, &[52]);
        let mut s = Self {
            table: t,
            pos: cfg.initial_position as f64,
            vel: 0.0,
            t_ns: None,
            registered: None,
        };
        s.power_on_ram(cfg.torque_on);
        s
    }

    /// RAM (addresses ≥ 64) as at power-on: Goal Position at the shaft, defaults elsewhere.
    fn power_on_ram(&mut self, torque_on: bool) {
        let t = &mut self.table;
        t[TORQUE_ENABLE..].fill(0);
        put(t, TORQUE_ENABLE, &[torque_on as u8]);
        put(t, STATUS_RETURN_LEVEL, &[2]);
        put(t, 76, &1920u16.to_le_bytes());
        put(t, 78, &100u16.to_le_bytes());
        put(t, 84, &800u16.to_le_bytes());
        put(t, 144, &120u16.to_le_bytes());
        put(t, 146, &[35]);
        for n in 0..INDIRECT_COUNT {
            put(
                t,
                INDIRECT_ADDRESS + 2 * n,
                &((INDIRECT_DATA + n) as u16).to_le_bytes(),
            );
        }
        let goal = self.pos.round().clamp(i32::MIN as f64, i32::MAX as f64) as i32;
        put(t, 116, &goal.to_le_bytes());
        self.vel = 0.0;
        self.registered = None;
        self.publish(0.0);
    }

    /// Restarts the servo: RAM back to its power-on values (torque off whatever the power-on
    /// configuration was, Hardware Error Status cleared, Goal Position = Present Position,
    /// Status Return Level 2, indirect addresses at their defaults, no registered
    /// instruction); EEPROM and the shaft's position are kept.
    fn reboot(&mut self) {
        self.power_on_ram(false);
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
        self.table[TORQUE_ENABLE] != 0
    }

    /// Hardware Error Status (address 70): bit 0 input voltage, 2 overheating, 3 motor
    /// encoder, 4 electrical shock, 5 overload.
    pub fn hardware_error(&self) -> u8 {
        self.table[HARDWARE_ERROR]
    }

    /// Model number (address 0).
    pub fn model(&self) -> u16 {
        u16::from_le_bytes([self.table[0], self.table[1]])
    }

    /// Status Return Level (address 68).
    pub fn status_return_level(&self) -> u8 {
        self.table[STATUS_RETURN_LEVEL]
    }

    /// Return Delay Time as the servo applies it now (register 9 × 2 µs), ns.
    pub fn return_delay_ns(&self) -> u64 {
        self.table[9] as u64 * 2_000
    }

    /// Latches hardware error `bits` in Hardware Error Status (70). If any of them is also set
    /// in Shutdown (63, default 52 = overheating, electrical shock, overload), the servo turns
    /// its torque off and refuses Torque Enable = 1 until it is rebooted. While address 70 is
    /// non-zero every status packet of this servo carries the Alert bit.
    pub fn inject_hardware_error(&mut self, bits: u8) {
        self.table[HARDWARE_ERROR] |= bits;
        if bits & self.table[SHUTDOWN] != 0 {
            self.table[TORQUE_ENABLE] = 0;
        }
    }

    /// Whether a latched hardware error is one Shutdown acts on (torque refused).
    fn shutdown_latched(&self) -> bool {
        self.table[HARDWARE_ERROR] & self.table[SHUTDOWN] != 0
    }

    /// Sets the model number reported by PING and address 0.
    pub fn set_model(&mut self, model: u16) {
        put(&mut self.table, 0, &model.to_le_bytes());
    }

    /// Someone moved the shaft (a limp joint turned by hand): it is now at `raw`, at rest, and
    /// Present Position says so. With torque on the servo pulls back to its goal from there.
    pub fn set_present(&mut self, raw: i32) {
        self.pos = raw as f64;
        self.vel = 0.0;
        self.publish(0.0);
    }

    /// The status error byte for error number `err`: the Alert bit while a hardware error is
    /// latched.
    fn error_byte(&self, err: u8) -> u8 {
        if self.table[HARDWARE_ERROR] != 0 {
            err | ALERT
        } else {
            err
        }
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
                self.vel = 0.0;
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

    /// Where a byte at logical address `a` lives: Indirect Data n stands for the address held
    /// in Indirect Address n (a plain byte when that is Indirect Data itself).
    fn resolve(&self, a: usize) -> Option<usize> {
        if is_indirect_data(a) {
            let n = a - INDIRECT_DATA;
            let at = INDIRECT_ADDRESS + 2 * n;
            let target = u16::from_le_bytes([self.table[at], self.table[at + 1]]) as usize;
            return (target < TABLE_SIZE).then_some(target);
        }
        (a < TABLE_SIZE).then_some(a)
    }

    /// Applies a write; returns the status error number (0 = ok). A refused write changes
    /// nothing.
    fn write(&mut self, addr: u16, data: &[u8]) -> u8 {
        let a = addr as usize;
        if data.is_empty() || a + data.len() > TABLE_SIZE {
            return ERR_ACCESS;
        }
        let torque = self.torque_on();
        let mut next = self.table;
        let mut touched = [false; TABLE_SIZE];
        for (k, &b) in data.iter().enumerate() {
            let Some(p) = self.resolve(a + k) else {
                return ERR_ACCESS;
            };
            // EEPROM and the indirect addresses are locked while torque is on.
            if read_only(p) || (torque && (p < TORQUE_ENABLE || is_indirect_address(p))) {
                return ERR_ACCESS;
            }
            next[p] = b;
            touched[p] = true;
        }
        let i32_at = |t: &[u8; TABLE_SIZE], at: usize| {
            i32::from_le_bytes([t[at], t[at + 1], t[at + 2], t[at + 3]])
        };
        let any = |r: std::ops::Range<usize>| touched[r].iter().any(|&x| x);
        if touched[TORQUE_ENABLE] {
            if next[TORQUE_ENABLE] > 1 {
                return ERR_DATA_RANGE;
            }
            if next[TORQUE_ENABLE] == 1 && self.shutdown_latched() {
                return ERR_ACCESS;
            }
        }
        if touched[STATUS_RETURN_LEVEL] && next[STATUS_RETURN_LEVEL] > 2 {
            return ERR_DATA_RANGE;
        }
        if touched[9] && next[9] > 254 {
            return ERR_DATA_RANGE;
        }
        if touched[11] && !matches!(next[11], 0 | 1 | 3 | 4 | 5 | 16) {
            return ERR_DATA_RANGE;
        }
        for n in 0..INDIRECT_COUNT {
            let at = INDIRECT_ADDRESS + 2 * n;
            if any(at..at + 2) {
                let target = u16::from_le_bytes([next[at], next[at + 1]]) as usize;
                if !(TORQUE_ENABLE..TABLE_SIZE).contains(&target) {
                    return ERR_DATA_RANGE;
                }
            }
        }
        if any(116..120) && next[11] == 3 {
            let (max, min) = (i32_at(&next, 48), i32_at(&next, 52));
            if !(min..=max).contains(&i32_at(&next, 116)) {
                return ERR_DATA_LIMIT;
            }
        }
        if any(104..108) && next[11] == 1 {
            let limit = i32_at(&next, 44);
            if i32_at(&next, 104).unsigned_abs() > limit.unsigned_abs() {
                return ERR_DATA_LIMIT;
            }
        }
        self.table = next;
        0
    }

    /// The bytes at `addr..addr + len`, through the indirect mapping; `None` past the table.
    fn read(&self, addr: u16, len: u16) -> Option<Vec<u8>> {
        (addr as usize..addr as usize + len as usize)
            .map(|a| self.resolve(a).map(|p| self.table[p]))
            .collect()
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
    log: Option<Vec<InstructionRecord>>,
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

/// One status packet to send: servo index, error number, parameters, ground truth of a read.
struct Answer(usize, u8, Vec<u8>, Option<(u16, Vec<u8>)>);

/// An instruction as scanned: ID, wire length, instruction code, raw parameters, decoded.
type Pending = (u8, usize, u8, Vec<u8>, Result<OwnedRequest, RequestError>);

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
            log: None,
        }
    }

    /// Keeps a log of every instruction (see [`InstructionRecord`]; it grows without bound).
    pub fn with_log(mut self) -> Self {
        self.log = Some(Vec::new());
        self
    }

    /// Starts the instruction log now, on a simulator already built (e.g. one a runner owns).
    pub fn start_log(&mut self) {
        self.log.get_or_insert_with(Vec::new);
    }

    /// The instruction log, oldest first (empty without [`with_log`](Self::with_log)).
    pub fn instruction_log(&self) -> &[InstructionRecord] {
        self.log.as_deref().unwrap_or(&[])
    }

    /// Takes the instructions logged so far, leaving the log running and empty (a long run
    /// drains it as it goes, so it does not grow).
    pub fn take_log(&mut self) -> Vec<InstructionRecord> {
        self.log.as_mut().map(std::mem::take).unwrap_or_default()
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
        self.index(id).map(|i| &self.servos[i])
    }

    /// The servo with `id`, to change it behind the host's back (inject a hardware error, move
    /// its shaft, change its model).
    pub fn servo_mut(&mut self, id: u8) -> Option<&mut SimServo> {
        self.index(id).map(|i| &mut self.servos[i])
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

    fn record(&mut self, r: InstructionRecord) {
        if let Some(l) = &mut self.log {
            l.push(r);
        }
    }

    /// Takes bytes the host sent, arriving (last byte) at `now_ns`; calls `reply` for every
    /// status packet, in bus order. A partial packet left from more than 1.5 ms before is
    /// dropped first (the servos' byte-gap rule).
    pub fn feed(&mut self, bytes: &[u8], now_ns: u64, mut reply: impl FnMut(SimReply)) {
        if self.last_rx_ns.is_some_and(|t| now_ns > t + BYTE_GAP_NS) {
            self.expire();
        }
        self.last_rx_ns = Some(now_ns);
        let mut pending: Vec<Pending> = Vec::new();
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
                // Owned copies: the packet borrows the scanner.
                let req = Request::from_packet(&p).map(|r| OwnedRequest::from(&r));
                pending.push((p.id, p.wire_len, p.instruction, p.params.to_vec(), req));
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
        for (id, wire_len, inst, params, req) in pending {
            self.advance(now_ns);
            self.log_instruction(now_ns, id, inst, &params, req.as_ref().ok());
            match req {
                Ok(r) => self.execute(id, wire_len, &r, &mut t, &mut reply),
                Err(e) => {
                    self.stats.other += 1;
                    // Unknown or malformed instruction to one servo: Instruction Error, or
                    // Data Length Error for parameters that do not fit.
                    let err = match e {
                        RequestError::Length(_) => ERR_DATA_LENGTH,
                        _ => ERR_INSTRUCTION,
                    };
                    let level = if inst == Instruction::Read as u8 {
                        1
                    } else {
                        2
                    };
                    if let Some(i) = self.index(id).filter(|_| id != dxl::BROADCAST_ID) {
                        if self.servos[i].status_return_level() >= level {
                            self.emit(Answer(i, err, Vec::new(), None), &mut t, &mut reply);
                        }
                    }
                }
            }
        }
    }

    fn log_instruction(
        &mut self,
        now_ns: u64,
        id: u8,
        inst: u8,
        params: &[u8],
        req: Option<&OwnedRequest>,
    ) {
        if self.log.is_none() {
            return;
        }
        let at = |k: usize| u16::from_le_bytes([params[k], params[k + 1]]);
        match req {
            Some(OwnedRequest::SyncWrite { addr, entries }) => {
                for (sid, data) in entries {
                    self.record((now_ns, *sid, inst, *addr, data.clone()));
                }
            }
            Some(OwnedRequest::BulkWrite { entries }) => {
                for (sid, a, data) in entries {
                    self.record((now_ns, *sid, inst, *a, data.clone()));
                }
            }
            Some(
                OwnedRequest::Read { addr, .. }
                | OwnedRequest::Write { addr, .. }
                | OwnedRequest::SyncRead { addr, .. },
            ) => {
                debug_assert_eq!(at(0), *addr);
                self.record((now_ns, id, inst, *addr, params[2..].to_vec()));
            }
            _ => self.record((now_ns, id, inst, 0, params.to_vec())),
        }
    }

    fn emit(&mut self, a: Answer, t: &mut u64, reply: &mut impl FnMut(SimReply)) {
        let Answer(i, err, params, data) = a;
        let s = &self.servos[i];
        let (id, err, delay) = (s.table[7], s.error_byte(err), s.return_delay_ns());
        let Ok(n) = dxl::status(&mut self.pkt, id, err, &params) else {
            return;
        };
        self.send(n, id, data, delay, t, reply);
    }

    fn send(
        &mut self,
        n: usize,
        id: u8,
        data: Option<(u16, Vec<u8>)>,
        delay_ns: u64,
        t: &mut u64,
        reply: &mut impl FnMut(SimReply),
    ) {
        *t += delay_ns;
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
        let unicast = id != dxl::BROADCAST_ID;
        // Whether servo `i` answers an instruction that needs Status Return Level `level`.
        let answers =
            |s: &Self, i: usize, level: u8| unicast && s.servos[i].status_return_level() >= level;
        match r {
            OwnedRequest::Ping => {
                // PING is always answered, broadcast included (in ID order).
                self.stats.ping += 1;
                let mut order = targets;
                order.sort_by_key(|&i| self.servos[i].table[7]);
                for i in order {
                    let s = &self.servos[i];
                    let p = vec![s.table[0], s.table[1], s.table[6]];
                    self.emit(Answer(i, 0, p, None), t, reply);
                }
            }
            OwnedRequest::Read { addr, len } => {
                self.stats.read += 1;
                for i in targets {
                    if answers(self, i, 1) {
                        let a = self.read_answer(i, *addr, *len);
                        self.emit(a, t, reply);
                    }
                }
            }
            OwnedRequest::Write { addr, data, reg } => {
                self.stats.write += 1;
                for i in targets {
                    let err = if *reg {
                        self.servos[i].registered = Some((*addr, data.clone()));
                        self.servos[i].table[REGISTERED] = 1;
                        0
                    } else {
                        self.servos[i].write(*addr, data)
                    };
                    if answers(self, i, 2) {
                        self.emit(Answer(i, err, Vec::new(), None), t, reply);
                    }
                }
            }
            OwnedRequest::Action => {
                self.stats.other += 1;
                for i in targets {
                    let s = &mut self.servos[i];
                    let err = match s.registered.take() {
                        Some((a, d)) => {
                            s.table[REGISTERED] = 0;
                            s.write(a, &d)
                        }
                        None => ERR_INSTRUCTION,
                    };
                    if answers(self, i, 2) {
                        self.emit(Answer(i, err, Vec::new(), None), t, reply);
                    }
                }
            }
            OwnedRequest::Reboot => {
                for i in targets {
                    // The status goes out before the restart (with the Alert bit if set).
                    if answers(self, i, 2) {
                        self.emit(Answer(i, 0, Vec::new(), None), t, reply);
                    }
                    self.servos[i].reboot();
                    self.stats.reboot += 1;
                }
            }
            OwnedRequest::Other => {
                self.stats.other += 1;
                for i in targets {
                    if answers(self, i, 2) {
                        self.emit(Answer(i, 0, Vec::new(), None), t, reply);
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
                // No reply: a refused entry is silently ignored.
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

    fn read_answer(&self, i: usize, addr: u16, len: u16) -> Answer {
        match self.servos[i].read(addr, len) {
            Some(d) => Answer(i, 0, d.clone(), Some((addr, d))),
            None => Answer(i, ERR_ACCESS, Vec::new(), None),
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
        // A servo that is not on the bus, or set to answer PING only, stays silent (the host
        // times out).
        let Some(i) = self.index(sid) else { return };
        if self.servos[i].status_return_level() < 1 {
            return;
        }
        let a = self.read_answer(i, addr, len);
        self.emit(a, t, reply);
    }

    fn fast_reply(
        &mut self,
        entries: &[(u8, u16, u16)],
        t: &mut u64,
        reply: &mut impl FnMut(SimReply),
    ) {
        // A fast read is answered only if every listed servo is present and answers reads
        // (each adds its slice to the same packet; a missing one breaks the chain).
        let mut datas = Vec::new();
        let mut delay = 0;
        for &(sid, a, l) in entries {
            let Some(i) = self.index(sid) else { return };
            let s = &self.servos[i];
            if s.status_return_level() < 1 {
                return;
            }
            let Some(d) = s.read(a, l) else {
                return;
            };
            // Every servo waits its return delay before its slice.
            delay += s.return_delay_ns();
            datas.push((sid, s.error_byte(0), a, d));
        }
        let slices: Vec<FastStatusSlice<'_>> = datas
            .iter()
            .map(|(sid, err, _, d)| FastStatusSlice {
                error: *err,
                id: *sid,
                data: d,
            })
            .collect();
        let Ok(n) = dxl::fast_status(&mut self.pkt, &slices) else {
            return;
        };
        let truth = datas.first().map(|(_, _, a, _)| *a);
        let all: Vec<u8> = datas
            .iter()
            .flat_map(|(_, _, _, d)| d.iter().copied())
            .collect();
        self.send(
            n,
            dxl::BROADCAST_ID,
            truth.map(|a| (a, all)),
            delay,
            t,
            reply,
        );
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
    Reboot,
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
            Request::Reboot => OwnedRequest::Reboot,
            Request::FactoryReset(_) | Request::ClearMultiTurn | Request::ControlTableBackup(_) => {
                OwnedRequest::Other
            }
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
