//! ROBOTIS Dynamixel servos: the X series on Protocol 2.0 (XM430 control table) and the
//! AX/MX series on Protocol 1.0.

use std::f64::consts::PI;

use super::register::{Encoding, RegChannel, RegDevice};
use crate::message::{Credential, Reply, Request, Update};
use crate::queue::Bounded;
use crate::stage::{Channel, Device, SafeAction, TickCtx};

/// X-series control table addresses (XM430, protocols.md §1.9).
pub mod x_table {
    /// Operating Mode (1 byte, EEPROM).
    pub const OPERATING_MODE: u16 = 11;
    /// Torque Enable (1 byte).
    pub const TORQUE_ENABLE: u16 = 64;
    /// Goal Current (2 bytes, signed, ≈2.69 mA).
    pub const GOAL_CURRENT: u16 = 102;
    /// Goal Velocity (4 bytes, signed, 0.229 rpm).
    pub const GOAL_VELOCITY: u16 = 104;
    /// Goal Position (4 bytes, signed, 4096 per revolution).
    pub const GOAL_POSITION: u16 = 116;
    /// Present Current (2 bytes, signed).
    pub const PRESENT_CURRENT: u16 = 126;
    /// Present Velocity (4 bytes, signed).
    pub const PRESENT_VELOCITY: u16 = 128;
    /// Present Position (4 bytes, signed).
    pub const PRESENT_POSITION: u16 = 132;
    /// Present Input Voltage (2 bytes, 0.1 V).
    pub const PRESENT_INPUT_VOLTAGE: u16 = 144;
    /// Present Temperature (1 byte, °C).
    pub const PRESENT_TEMPERATURE: u16 = 146;
}

/// Parameters of an X-series servo.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DxlXConfig {
    /// Raw position that means 0 rad (2048: the middle of a turn).
    pub zero: i64,
    /// Operating mode the servo is configured in (3 position, 4 extended position, 5
    /// current-based position, 1 velocity, 0 current, 16 PWM): decides the goal position range.
    pub operating_mode: u8,
    /// Current unit in mA (2.69 for XM430/XM540).
    pub current_unit_ma: f64,
    /// Largest |Present Current| a healthy servo reports (raw).
    pub max_current_raw: i64,
    /// Largest |Present Position| in revolutions (multi-turn range, 256 on X series).
    pub max_position_rev: f64,
}

impl Default for DxlXConfig {
    fn default() -> Self {
        Self {
            zero: 2048,
            operating_mode: 3,
            current_unit_ma: 2.69,
            max_current_raw: 2047,
            max_position_rev: 256.0,
        }
    }
}

/// Channel indices of [`DynamixelX`].
pub mod x_channel {
    /// Reads Present Position, writes Goal Position (rad).
    pub const POSITION: usize = 0;
    /// Reads Present Velocity, writes Goal Velocity (rad/s).
    pub const VELOCITY: usize = 1;
    /// Reads Present Current, writes Goal Current (A).
    pub const CURRENT: usize = 2;
    /// Goal Position, read and write (rad).
    pub const GOAL_POSITION: usize = 3;
    /// Torque Enable (0/1).
    pub const TORQUE_ENABLE: usize = 4;
    /// Operating Mode.
    pub const OPERATING_MODE: usize = 5;
    /// Present Temperature (°C).
    pub const TEMPERATURE: usize = 6;
    /// Present Input Voltage (V).
    pub const VOLTAGE: usize = 7;
}

const PULSE_RAD: f64 = 2.0 * PI / 4096.0;
const VEL_UNIT: f64 = 0.229 * 2.0 * PI / 60.0;

fn goal_range(mode: u8) -> (i64, i64) {
    match mode {
        3 => (0, 4095),
        _ => (-1_048_575, 1_048_575),
    }
}

/// A Dynamixel X-series servo (XM430/XM540/XH430 control table) on Protocol 2.0.
#[derive(Debug)]
pub struct DynamixelX {
    dev: RegDevice,
    cfg: DxlXConfig,
}

impl DynamixelX {
    /// The servo with ID `cred.id`.
    pub fn new(cred: Credential, cfg: DxlXConfig) -> Self {
        use x_table::*;
        let pos_max = (cfg.max_position_rev * 4096.0) as i64;
        let goal = goal_range(cfg.operating_mode);
        let table = vec![
            RegChannel {
                name: "position",
                units: "rad",
                read: Some(PRESENT_POSITION),
                write: Some(GOAL_POSITION),
                len: 4,
                encoding: Encoding::Signed,
                scale: PULSE_RAD,
                offset: cfg.zero,
                read_range: (-pos_max, pos_max),
                write_range: goal,
            },
            RegChannel {
                name: "velocity",
                units: "rad/s",
                read: Some(PRESENT_VELOCITY),
                write: Some(GOAL_VELOCITY),
                len: 4,
                encoding: Encoding::Signed,
                scale: VEL_UNIT,
                offset: 0,
                read_range: (-1023, 1023),
                write_range: (-1023, 1023),
            },
            RegChannel {
                name: "current",
                units: "A",
                read: Some(PRESENT_CURRENT),
                write: Some(GOAL_CURRENT),
                len: 2,
                encoding: Encoding::Signed,
                scale: cfg.current_unit_ma * 1e-3,
                offset: 0,
                read_range: (-cfg.max_current_raw, cfg.max_current_raw),
                write_range: (-cfg.max_current_raw, cfg.max_current_raw),
            },
            RegChannel {
                name: "goal_position",
                units: "rad",
                read: Some(GOAL_POSITION),
                write: Some(GOAL_POSITION),
                len: 4,
                encoding: Encoding::Signed,
                scale: PULSE_RAD,
                offset: cfg.zero,
                read_range: (-1_048_575, 1_048_575),
                write_range: goal,
            },
            RegChannel {
                name: "torque_enable",
                units: "",
                read: Some(TORQUE_ENABLE),
                write: Some(TORQUE_ENABLE),
                len: 1,
                encoding: Encoding::Unsigned,
                scale: 1.0,
                offset: 0,
                read_range: (0, 1),
                write_range: (0, 1),
            },
            RegChannel {
                name: "operating_mode",
                units: "",
                read: Some(OPERATING_MODE),
                write: Some(OPERATING_MODE),
                len: 1,
                encoding: Encoding::Unsigned,
                scale: 1.0,
                offset: 0,
                read_range: (0, 16),
                write_range: (0, 16),
            },
            RegChannel {
                name: "temperature",
                units: "degC",
                read: Some(PRESENT_TEMPERATURE),
                write: None,
                len: 1,
                encoding: Encoding::Unsigned,
                scale: 1.0,
                offset: 0,
                read_range: (0, 150),
                write_range: (0, 0),
            },
            RegChannel {
                name: "voltage",
                units: "V",
                read: Some(PRESENT_INPUT_VOLTAGE),
                write: None,
                len: 2,
                encoding: Encoding::Unsigned,
                scale: 0.1,
                offset: 0,
                read_range: (0, 400),
                write_range: (0, 0),
            },
        ];
        Self {
            dev: RegDevice::new(
                cred,
                table,
                Some(x_channel::POSITION),
                Some((TORQUE_ENABLE, 1, 0)),
            ),
            cfg,
        }
    }

    /// The safe action this kind declares: hold the present position.
    pub const SAFE_ACTION: SafeAction = SafeAction::Hold;

    /// Values rejected by the range check (damaged packets that passed the CRC).
    pub fn range_rejects(&self) -> u64 {
        self.dev.range_rejects()
    }

    /// Last good value of a channel.
    pub fn last(&self, channel: usize) -> Option<f64> {
        self.dev.last(channel)
    }

    /// Raw position for `rad` (what the servo is sent).
    pub fn position_raw(&self, rad: f64) -> i64 {
        self.dev.table()[x_channel::POSITION].to_raw(rad)
    }

    fn set_mode(&mut self, mode: u8) {
        self.cfg.operating_mode = mode;
        let r = goal_range(mode);
        self.dev.set_write_range(x_channel::POSITION, r);
        self.dev.set_write_range(x_channel::GOAL_POSITION, r);
    }
}

impl Device for DynamixelX {
    fn credential(&self) -> Credential {
        self.dev.credential()
    }

    fn channels(&self) -> &[Channel] {
        self.dev.channels()
    }

    fn sample(&mut self, channel: usize, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.dev.sample(channel, ctx, out);
    }

    fn write(&mut self, channel: usize, value: f64, _ctx: TickCtx) {
        if let Some(raw) = self.dev.write(channel, value) {
            if channel == x_channel::OPERATING_MODE {
                self.set_mode(raw as u8);
            }
        }
    }

    fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.dev.flush(ctx, out);
    }

    fn reply(&mut self, reply: &Reply, out: &mut Bounded<Update>) {
        let mut mode = None;
        self.dev.reply(reply, out, |i, raw| {
            if i == x_channel::OPERATING_MODE {
                mode = Some(raw as u8);
            }
        });
        if let Some(m) = mode {
            self.set_mode(m);
        }
    }

    fn safe(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.dev.safe(action, ctx, out);
    }
}

/// Protocol 1.0 servo family: decides resolution and units.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dxl1Model {
    /// AX-12/AX-18: 1024 steps over 300°, 0.111 rpm speed unit.
    Ax,
    /// MX-28/64/106 on Protocol 1.0: 4096 steps over 360°, 0.114 rpm.
    Mx,
}

/// Channel indices of [`Dynamixel1`].
pub mod dxl1_channel {
    /// Reads Present Position (36), writes Goal Position (30) (rad).
    pub const POSITION: usize = 0;
    /// Reads Present Speed (38), writes Moving Speed (32) (rad/s; in joint mode the speed
    /// limit of the move, magnitude only).
    pub const VELOCITY: usize = 1;
    /// Present Load (40), fraction of maximum torque (−1…1).
    pub const LOAD: usize = 2;
    /// Torque Enable (24).
    pub const TORQUE_ENABLE: usize = 3;
    /// Present Temperature (43, °C).
    pub const TEMPERATURE: usize = 4;
    /// Present Voltage (42, V).
    pub const VOLTAGE: usize = 5;
}

/// A Dynamixel AX/MX servo on Protocol 1.0.
#[derive(Debug)]
pub struct Dynamixel1 {
    dev: RegDevice,
}

impl Dynamixel1 {
    /// The servo with ID `cred.id`; `zero` is the raw position meaning 0 rad (512 for AX, 2048
    /// for MX).
    pub fn new(cred: Credential, model: Dxl1Model, zero: i64) -> Self {
        let (steps, span_rad, rpm) = match model {
            Dxl1Model::Ax => (1024i64, 300f64.to_radians(), 0.111),
            Dxl1Model::Mx => (4096, 2.0 * PI, 0.114),
        };
        let speed = rpm * 2.0 * PI / 60.0;
        let reg = |name, units, read, write, len, encoding, scale, offset, rr, wr| RegChannel {
            name,
            units,
            read,
            write,
            len,
            encoding,
            scale,
            offset,
            read_range: rr,
            write_range: wr,
        };
        let table = vec![
            reg(
                "position",
                "rad",
                Some(36),
                Some(30),
                2,
                Encoding::Unsigned,
                span_rad / steps as f64,
                zero,
                (0, steps - 1),
                (0, steps - 1),
            ),
            // Moving Speed 0 means "as fast as possible": the smallest magnitude written is 1.
            reg(
                "velocity",
                "rad/s",
                Some(38),
                Some(32),
                2,
                Encoding::SignMagnitude10,
                speed,
                0,
                (-1023, 1023),
                (1, 1023),
            ),
            reg(
                "load",
                "",
                Some(40),
                None,
                2,
                Encoding::SignMagnitude10,
                1.0 / 1023.0,
                0,
                (-1023, 1023),
                (0, 0),
            ),
            reg(
                "torque_enable",
                "",
                Some(24),
                Some(24),
                1,
                Encoding::Unsigned,
                1.0,
                0,
                (0, 1),
                (0, 1),
            ),
            reg(
                "temperature",
                "degC",
                Some(43),
                None,
                1,
                Encoding::Unsigned,
                1.0,
                0,
                (0, 150),
                (0, 0),
            ),
            reg(
                "voltage",
                "V",
                Some(42),
                None,
                1,
                Encoding::Unsigned,
                0.1,
                0,
                (0, 250),
                (0, 0),
            ),
        ];
        Self {
            dev: RegDevice::new(cred, table, Some(dxl1_channel::POSITION), Some((24, 1, 0))),
        }
    }

    /// The safe action this kind declares: hold the present position.
    pub const SAFE_ACTION: SafeAction = SafeAction::Hold;

    /// Values rejected by the range check.
    pub fn range_rejects(&self) -> u64 {
        self.dev.range_rejects()
    }
}

impl Device for Dynamixel1 {
    fn credential(&self) -> Credential {
        self.dev.credential()
    }

    fn channels(&self) -> &[Channel] {
        self.dev.channels()
    }

    fn sample(&mut self, channel: usize, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.dev.sample(channel, ctx, out);
    }

    fn write(&mut self, channel: usize, value: f64, _ctx: TickCtx) {
        self.dev.write(channel, value);
    }

    fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.dev.flush(ctx, out);
    }

    fn reply(&mut self, reply: &Reply, out: &mut Bounded<Update>) {
        self.dev.reply(reply, out, |_, _| {});
    }

    fn safe(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.dev.safe(action, ctx, out);
    }
}
