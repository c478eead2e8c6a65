//! ROBOTIS Dynamixel servos: the X series on Protocol 2.0 (XM430 control table) and the
//! AX/MX series on Protocol 1.0.

use std::f64::consts::PI;

use super::control_table::{ConfigItem, ControlTable, Encoding, Indirect, RegChannel};
use super::reg_device::RegDevice;
use crate::component::SafeAction;
use crate::message::Credential;

/// X-series control table addresses (XM430, protocols.md §1.9).
pub mod x_table {
    /// Model Number (2 bytes).
    pub const MODEL_NUMBER: u16 = 0;
    /// Return Delay Time (1 byte, 2 µs, EEPROM).
    pub const RETURN_DELAY_TIME: u16 = 9;
    /// Operating Mode (1 byte, EEPROM).
    pub const OPERATING_MODE: u16 = 11;
    /// Current Limit (2 bytes, EEPROM).
    pub const CURRENT_LIMIT: u16 = 38;
    /// Velocity Limit (4 bytes, EEPROM).
    pub const VELOCITY_LIMIT: u16 = 44;
    /// Max Position Limit (4 bytes, EEPROM).
    pub const MAX_POSITION_LIMIT: u16 = 48;
    /// Min Position Limit (4 bytes, EEPROM).
    pub const MIN_POSITION_LIMIT: u16 = 52;
    /// Torque Enable (1 byte).
    pub const TORQUE_ENABLE: u16 = 64;
    /// Status Return Level (1 byte).
    pub const STATUS_RETURN_LEVEL: u16 = 68;
    /// Hardware Error Status (1 byte): 0 input voltage, 2 overheating, 3 motor encoder,
    /// 4 electrical shock, 5 overload.
    pub const HARDWARE_ERROR_STATUS: u16 = 70;
    /// Goal PWM (2 bytes, signed).
    pub const GOAL_PWM: u16 = 100;
    /// Goal Current (2 bytes, signed, ≈2.69 mA).
    pub const GOAL_CURRENT: u16 = 102;
    /// Goal Velocity (4 bytes, signed, 0.229 rpm).
    pub const GOAL_VELOCITY: u16 = 104;
    /// Profile Acceleration (4 bytes).
    pub const PROFILE_ACCELERATION: u16 = 108;
    /// Profile Velocity (4 bytes).
    pub const PROFILE_VELOCITY: u16 = 112;
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
    /// Indirect Address 1 (2 bytes each, 28 of them).
    pub const INDIRECT_ADDRESS: u16 = 168;
    /// Indirect Data 1 (1 byte each).
    pub const INDIRECT_DATA: u16 = 224;
}

/// X-series models with this control table (Present Current at 126), by model number as the
/// servos report it (ROBOTIS e-Manual).
pub const X_MODELS: &[(u16, &str)] = &[
    (1000, "xh430-w350"),
    (1010, "xh430-w210"),
    (1020, "xm430-w350"),
    (1030, "xm430-w210"),
    (1040, "xh430-v350"),
    (1050, "xh430-v210"),
    (1100, "xh540-w270"),
    (1110, "xh540-w150"),
    (1120, "xm540-w270"),
    (1130, "xm540-w150"),
    (1140, "xh540-v270"),
    (1150, "xh540-v150"),
];

/// Protocol 1.0 models by family: AX-12A, AX-18A, AX-12W; MX-28, MX-64, MX-106.
pub const AX_MODELS: &[(u16, &str)] = &[(12, "ax-12a"), (18, "ax-18a"), (300, "ax-12w")];
/// See [`AX_MODELS`].
pub const MX_MODELS: &[(u16, &str)] = &[(29, "mx-28"), (310, "mx-64"), (320, "mx-106")];

/// The model list a manifest's `model` names: one model, or `"any"` (no check).
pub fn x_models(name: &str) -> Option<&'static [(u16, &'static str)]> {
    if name == "any" {
        return Some(&[]);
    }
    let i = X_MODELS.iter().position(|(_, n)| *n == name)?;
    Some(&X_MODELS[i..=i])
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
    /// Model numbers the servo may report (empty: any).
    pub models: &'static [(u16, &'static str)],
    /// Configuration written at bring-up when set (raw register values).
    pub setup: DxlXSetup,
}

/// Registers of an X-series servo that bring-up sets when the manifest gives them (`None`:
/// left as the servo has them). Operating Mode is always set (from [`DxlXConfig`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DxlXSetup {
    /// Return Delay Time (µs; written in 2 µs units).
    pub return_delay_us: Option<u32>,
    /// Status Return Level (1: reads answered; 2: every instruction).
    pub status_return_level: Option<u8>,
    /// Min / Max Position Limit (raw pulses).
    pub position_limits: (Option<i64>, Option<i64>),
    /// Velocity Limit (raw, 0.229 rpm).
    pub velocity_limit: Option<i64>,
    /// Current Limit (raw, ≈2.69 mA).
    pub current_limit: Option<i64>,
    /// Profile Acceleration and Profile Velocity (raw).
    pub profile: (Option<i64>, Option<i64>),
}

impl Default for DxlXConfig {
    fn default() -> Self {
        Self {
            zero: 2048,
            operating_mode: 3,
            current_unit_ma: 2.69,
            max_current_raw: 2047,
            max_position_rev: 256.0,
            models: &X_MODELS[2..3],
            setup: DxlXSetup::default(),
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
    /// Hardware Error Status (bits).
    pub const HARDWARE_ERROR: usize = 8;
    /// 1 while enabled; write 1 to enable from where it is, 0 to switch torque off.
    pub const ENABLE: usize = 9;
}

const PULSE_RAD: f64 = 2.0 * PI / 4096.0;
const VEL_UNIT: f64 = 0.229 * 2.0 * PI / 60.0;

fn goal_range(mode: u8) -> (i64, i64) {
    match mode {
        3 => (0, 4095),
        _ => (-1_048_575, 1_048_575),
    }
}

/// The X-series control table (XM430/XM540/XH430) on Protocol 2.0, with the servo's
/// configuration. Its Operating Mode decides the Goal Position range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct XSeries {
    cfg: DxlXConfig,
}

impl ControlTable for XSeries {
    const SAFE_ACTION: SafeAction = SafeAction::Hold;
    const HOLD: Option<usize> = Some(x_channel::POSITION);
    const TORQUE: u16 = x_table::TORQUE_ENABLE;
    const PING_MODEL: bool = true;
    const HW_ERROR: Option<u16> = Some(x_table::HARDWARE_ERROR_STATUS);
    const REBOOT: bool = true;
    const INDIRECT: Option<Indirect> = Some(Indirect {
        addr: x_table::INDIRECT_ADDRESS,
        data: x_table::INDIRECT_DATA,
        slots: 28,
    });

    fn models(&self) -> &'static [(u16, &'static str)] {
        self.cfg.models
    }

    fn config(&self) -> Vec<ConfigItem> {
        use x_table::*;
        let c = self.cfg.setup;
        let item = |name, addr, len, value: Option<i64>| {
            value.map(|value| ConfigItem {
                name,
                addr,
                len,
                value,
            })
        };
        [
            item(
                "operating_mode",
                OPERATING_MODE,
                1,
                Some(self.cfg.operating_mode as i64),
            ),
            item(
                "return_delay_us",
                RETURN_DELAY_TIME,
                1,
                c.return_delay_us.map(|us| (us / 2) as i64),
            ),
            item("current_limit", CURRENT_LIMIT, 2, c.current_limit),
            item("velocity_limit", VELOCITY_LIMIT, 4, c.velocity_limit),
            item(
                "max_position_limit",
                MAX_POSITION_LIMIT,
                4,
                c.position_limits.1,
            ),
            item(
                "min_position_limit",
                MIN_POSITION_LIMIT,
                4,
                c.position_limits.0,
            ),
            item(
                "status_return_level",
                STATUS_RETURN_LEVEL,
                1,
                c.status_return_level.map(i64::from),
            ),
            item("profile_acceleration", PROFILE_ACCELERATION, 4, c.profile.0),
            item("profile_velocity", PROFILE_VELOCITY, 4, c.profile.1),
        ]
        .into_iter()
        .flatten()
        .collect()
    }

    fn needs_torque_off(&self, addr: u16) -> bool {
        addr < x_table::TORQUE_ENABLE
            || (x_table::INDIRECT_ADDRESS..x_table::INDIRECT_DATA).contains(&addr)
    }

    fn zero_goal(&self) -> Option<(u16, u8)> {
        match self.cfg.operating_mode {
            0 => Some((x_table::GOAL_CURRENT, 2)),
            1 => Some((x_table::GOAL_VELOCITY, 4)),
            16 => Some((x_table::GOAL_PWM, 2)),
            _ => None,
        }
    }

    fn channels(&self) -> Vec<RegChannel> {
        use x_table::*;
        use Encoding::{Signed, Unsigned};
        let cfg = self.cfg;
        let pos_max = (cfg.max_position_rev * 4096.0) as i64;
        let goal = goal_range(cfg.operating_mode);
        let current = (-cfg.max_current_raw, cfg.max_current_raw);
        vec![
            RegChannel::new("position", "rad", 4, Signed)
                .reads(PRESENT_POSITION, (-pos_max, pos_max))
                .writes(GOAL_POSITION, goal)
                .scaled(PULSE_RAD, cfg.zero)
                // No faster than Present Velocity can report (±1023 units).
                .bounded_rate(1023.0 * VEL_UNIT / PULSE_RAD),
            RegChannel::new("velocity", "rad/s", 4, Signed)
                .reads(PRESENT_VELOCITY, (-1023, 1023))
                .writes(GOAL_VELOCITY, (-1023, 1023))
                .scaled(VEL_UNIT, 0),
            RegChannel::new("current", "A", 2, Signed)
                .reads(PRESENT_CURRENT, current)
                .writes(GOAL_CURRENT, current)
                .scaled(cfg.current_unit_ma * 1e-3, 0),
            RegChannel::new("goal_position", "rad", 4, Signed)
                .reads(GOAL_POSITION, (-1_048_575, 1_048_575))
                .writes(GOAL_POSITION, goal)
                .scaled(PULSE_RAD, cfg.zero),
            // Torque and operating mode are read here; bring-up and the `enable` channel set
            // them (a raw write would bypass enabling from the present position).
            RegChannel::new("torque_enable", "", 1, Unsigned).reads(TORQUE_ENABLE, (0, 1)),
            RegChannel::new("operating_mode", "", 1, Unsigned).reads(OPERATING_MODE, (0, 16)),
            RegChannel::new("temperature", "degC", 1, Unsigned)
                .reads(PRESENT_TEMPERATURE, (0, 150)),
            RegChannel::new("voltage", "V", 2, Unsigned)
                .reads(PRESENT_INPUT_VOLTAGE, (0, 400))
                .scaled(0.1, 0),
            RegChannel::new("hardware_error", "", 1, Unsigned)
                .reads(HARDWARE_ERROR_STATUS, (0, 255)),
        ]
    }

    fn on_raw(&mut self, table: &mut [RegChannel], i: usize, raw: i64) {
        if i != x_channel::OPERATING_MODE {
            return;
        }
        let mode = raw as u8;
        self.cfg.operating_mode = mode;
        for c in [x_channel::POSITION, x_channel::GOAL_POSITION] {
            table[c].write_range = goal_range(mode);
        }
    }
}

/// A Dynamixel X-series servo (XM430/XM540/XH430 control table) on Protocol 2.0.
pub type DynamixelX = RegDevice<XSeries>;

impl RegDevice<XSeries> {
    /// The servo with ID `cred.id`.
    pub fn new(cred: Credential, cfg: DxlXConfig) -> Self {
        Self::with_table(cred, XSeries { cfg })
    }

    /// Raw position for `rad` (what the servo is sent).
    pub fn position_raw(&self, rad: f64) -> i64 {
        self.table()[x_channel::POSITION].to_raw(rad)
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
    /// 1 while enabled; write 1 to enable from where it is, 0 to switch torque off.
    pub const ENABLE: usize = 6;
}

/// The AX/MX control table on Protocol 1.0: model and the raw position meaning 0 rad.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dxl1Series {
    model: Dxl1Model,
    zero: i64,
    return_delay_us: Option<u32>,
}

impl ControlTable for Dxl1Series {
    const SAFE_ACTION: SafeAction = SafeAction::Hold;
    const HOLD: Option<usize> = Some(dxl1_channel::POSITION);
    const TORQUE: u16 = 24;
    const PING_MODEL: bool = false;
    // Input voltage, overheating, overload: reported in every status packet while they last.
    const FAULT_BITS: u8 = 0x01 | 0x04 | 0x20;

    fn models(&self) -> &'static [(u16, &'static str)] {
        match self.model {
            Dxl1Model::Ax => AX_MODELS,
            Dxl1Model::Mx => MX_MODELS,
        }
    }

    fn config(&self) -> Vec<ConfigItem> {
        self.return_delay_us
            .map(|us| ConfigItem {
                name: "return_delay_us",
                addr: 5,
                len: 1,
                value: (us / 2) as i64,
            })
            .into_iter()
            .collect()
    }

    fn needs_torque_off(&self, _addr: u16) -> bool {
        // Protocol 1.0 servos take EEPROM writes with torque on.
        false
    }

    fn channels(&self) -> Vec<RegChannel> {
        use Encoding::{SignMagnitude10, Unsigned};
        let (steps, span_rad, rpm) = match self.model {
            Dxl1Model::Ax => (1024i64, 300f64.to_radians(), 0.111),
            Dxl1Model::Mx => (4096, 2.0 * PI, 0.114),
        };
        let speed = rpm * 2.0 * PI / 60.0;
        vec![
            RegChannel::new("position", "rad", 2, Unsigned)
                .reads(36, (0, steps - 1))
                .writes(30, (0, steps - 1))
                .scaled(span_rad / steps as f64, self.zero)
                // No faster than Present Speed can report (1023 units).
                .bounded_rate(1023.0 * speed / (span_rad / steps as f64)),
            // Moving Speed 0 means "as fast as possible": the smallest magnitude written is 1.
            RegChannel::new("velocity", "rad/s", 2, SignMagnitude10)
                .reads(38, (-1023, 1023))
                .writes(32, (1, 1023))
                .scaled(speed, 0),
            RegChannel::new("load", "", 2, SignMagnitude10)
                .reads(40, (-1023, 1023))
                .scaled(1.0 / 1023.0, 0),
            RegChannel::new("torque_enable", "", 1, Unsigned).reads(24, (0, 1)),
            RegChannel::new("temperature", "degC", 1, Unsigned).reads(43, (0, 150)),
            RegChannel::new("voltage", "V", 1, Unsigned)
                .reads(42, (0, 250))
                .scaled(0.1, 0),
        ]
    }
}

/// A Dynamixel AX/MX servo on Protocol 1.0.
pub type Dynamixel1 = RegDevice<Dxl1Series>;

impl RegDevice<Dxl1Series> {
    /// The servo with ID `cred.id`; `zero` is the raw position meaning 0 rad (512 for AX, 2048
    /// for MX).
    pub fn new(cred: Credential, model: Dxl1Model, zero: i64) -> Self {
        Self::with_table(
            cred,
            Dxl1Series {
                model,
                zero,
                return_delay_us: None,
            },
        )
    }

    /// As [`new`](Self::new), writing Return Delay Time at bring-up.
    pub fn with_return_delay(
        cred: Credential,
        model: Dxl1Model,
        zero: i64,
        us: Option<u32>,
    ) -> Self {
        Self::with_table(
            cred,
            Dxl1Series {
                model,
                zero,
                return_delay_us: us,
            },
        )
    }
}

use crate::kinds::{Build, BuildError, Invalid, KindSpec, ParamSpec, Params, REGISTER_SAFE};

crate::choices!(Dxl1Model { Ax = "ax", Mx = "mx" });

/// The model names a `dynamixel_x` may be told to expect: those of [`X_MODELS`], and "any".
pub const X_MODEL_NAMES: &[&str] = &[
    "xm430-w350",
    "xm430-w210",
    "xh430-w350",
    "xh430-w210",
    "xh430-v350",
    "xh430-v210",
    "xm540-w270",
    "xm540-w150",
    "xh540-w270",
    "xh540-w150",
    "xh540-v270",
    "xh540-v150",
    "any",
];

/// The `dynamixel_x` device kind.
pub const DYNAMIXEL_X: KindSpec = KindSpec {
    kind: "dynamixel_x",
    params: &[
        ParamSpec::int("zero", Some(2048), -1_048_575.0, 1_048_575.0, "raw position meaning 0 rad"),
        ParamSpec::int("operating_mode", Some(3), 0.0, 16.0, "the servo's Operating Mode (3 position: goals 0..4095; 4/5 extended: ±256 rev)"),
        ParamSpec::float("current_unit_ma", 2.69, Some((0.01, 100.0)), "Present/Goal Current unit (mA)"),
        ParamSpec::int("max_current_raw", Some(2047), 1.0, 32767.0, "largest |Present Current| accepted (raw); larger values are treated as damaged"),
        ParamSpec::float("max_position_rev", 256.0, Some((1.0, 524_288.0)), "largest |Present Position| accepted (revolutions)"),
        ParamSpec::names("model", Some("xm430-w350"), X_MODEL_NAMES, "the model the servo must report at bring-up (its model number); \"any\": no check"),
        ParamSpec::unset_int("return_delay_us", 0.0, 508.0, "Return Delay Time written at bring-up (µs, even; EEPROM: written with torque off); match the protocol's return_delay_us"),
        ParamSpec::unset_int("status_return_level", 1.0, 2.0, "Status Return Level written at bring-up (1: reads answered, 2: every instruction)"),
        ParamSpec::unset_int("min_position_limit", 0.0, 4095.0, "Min Position Limit written at bring-up (raw pulses, EEPROM)"),
        ParamSpec::unset_int("max_position_limit", 0.0, 4095.0, "Max Position Limit written at bring-up (raw pulses, EEPROM)"),
        ParamSpec::unset_int("velocity_limit", 0.0, 1023.0, "Velocity Limit written at bring-up (raw, 0.229 rpm, EEPROM)"),
        ParamSpec::unset_int("current_limit", 0.0, 2047.0, "Current Limit written at bring-up (raw, ≈2.69 mA, EEPROM)"),
        ParamSpec::unset_int("profile_velocity", 0.0, 32767.0, "Profile Velocity written at bring-up (raw, 0.229 rpm; 0 = unlimited)"),
        ParamSpec::unset_int("profile_acceleration", 0.0, 32767.0, "Profile Acceleration written at bring-up (raw, 214.577 rev/min²; 0 = unlimited)"),
        ParamSpec::bool("reboot_on_fault", false, "after a hardware error (the servo cut its torque), reboot it (back-off 1 s doubling to 30 s), bring it up again and re-enable it where it is"),
    ],
    doc: "A Dynamixel X-series servo (XM430/XM540/XH430/XH540 control table). Channels: position \
          (rad; reads Present Position, writes Goal Position), velocity (rad/s), current (A), \
          goal_position (rad), torque_enable, operating_mode, temperature (°C), voltage (V), \
          hardware_error (Hardware Error Status bits), enable. Brought up by PING (model number \
          checked), its configuration read and written (EEPROM with torque off) and read back, \
          Goal Position set to Present Position, then Torque Enable. Safe action: hold.",
    build: Build::Device {
        protocols: &["dynamixel2"],
        safe_actions: REGISTER_SAFE,
        build: |p, cred| Ok(Box::new(dynamixel_x(p, cred)?)),
        agrees: None,
    },
};

fn dynamixel_x(p: &Params, cred: Credential) -> Result<DynamixelX, BuildError> {
    let opt = |k: &str| p.opt_int(k);
    let model = p.str("model")?;
    let models = x_models(model).ok_or_else(|| {
        BuildError::invalid(
            "model",
            Invalid::Name {
                value: model.into(),
                names: X_MODEL_NAMES,
            },
        )
    })?;
    let setup = DxlXSetup {
        return_delay_us: opt("return_delay_us").and_then(|v| u32::try_from(v).ok()),
        status_return_level: opt("status_return_level").and_then(|v| u8::try_from(v).ok()),
        position_limits: (opt("min_position_limit"), opt("max_position_limit")),
        velocity_limit: opt("velocity_limit"),
        current_limit: opt("current_limit"),
        profile: (opt("profile_acceleration"), opt("profile_velocity")),
    };
    let cfg = DxlXConfig {
        zero: p.int("zero")?,
        operating_mode: p.int_as("operating_mode")?,
        current_unit_ma: p.float("current_unit_ma")?,
        max_current_raw: p.int("max_current_raw")?,
        max_position_rev: p.float("max_position_rev")?,
        models,
        setup,
    };
    Ok(DynamixelX::new(cred, cfg).reboot_on_fault(p.bool("reboot_on_fault")?))
}

/// The `dynamixel1` device kind.
pub const DYNAMIXEL1: KindSpec = KindSpec {
    kind: "dynamixel1",
    params: &[
        ParamSpec::choice::<Dxl1Model>(
            "model",
            "ax",
            "ax: 1024 steps over 300°; mx: 4096 over 360°",
        ),
        ParamSpec::int(
            "zero",
            Some(-1),
            -1.0,
            4095.0,
            "raw position meaning 0 rad (-1: the middle, 512 or 2048)",
        ),
        ParamSpec::unset_int(
            "return_delay_us",
            0.0,
            508.0,
            "Return Delay Time written at bring-up (µs, even)",
        ),
    ],
    doc:
        "A Dynamixel AX/MX servo on Protocol 1.0. Channels: position (rad), velocity (rad/s), load \
          (fraction), torque_enable, temperature (°C), voltage (V), enable. Brought up by PING, \
          its model number read (AX-12A/AX-18A/AX-12W or MX-28/64/106), then Goal Position set to \
          the present one and Torque Enable. Overload, overheating and input voltage errors are \
          faults. Safe action: hold.",
    build: Build::Device {
        protocols: &["dynamixel1"],
        safe_actions: REGISTER_SAFE,
        build: |p, cred| {
            let model: Dxl1Model = p.choice("model")?;
            let zero = match (p.int("zero")?, model) {
                (z, _) if z >= 0 => z,
                (_, Dxl1Model::Ax) => 512,
                (_, Dxl1Model::Mx) => 2048,
            };
            let delay = p
                .opt_int("return_delay_us")
                .and_then(|v| u32::try_from(v).ok());
            Ok(Box::new(Dynamixel1::with_return_delay(
                cred, model, zero, delay,
            )))
        },
        agrees: None,
    },
};
