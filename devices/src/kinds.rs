//! The component kinds a manifest can name, their parameters, and the factories that build them.
//!
//! Each kind declares its parameters as data ([`ParamSpec`]) so that the executor's manifest
//! validator can check every key, type and range (and report all errors with their location)
//! before anything is built, and so that the manifest reference lists exactly what the code
//! accepts.

use std::collections::BTreeMap;

use conductor_protocols::can::CanFrame;
use conductor_protocols::slcan::{Bitrate, Dialect};

use crate::device::{
    x_models, Dxl1Model, DxlXConfig, DxlXSetup, Dynamixel1, DynamixelX, MitMotor, OdriveAxis,
    OdriveMode,
};
use crate::hw::{
    interface_up, SerialHardware, SerialOptions, SlcanHardware, SlcanOptions, SocketCanHardware,
    UdpHardware,
};
use crate::link::{Link, LinkOf, Opener};
use crate::message::Credential;
use crate::protocol::{
    mit_limits, parse_model_table, CanMotorProtocol, Dxl1Protocol, Dxl1ReadMode, Dxl2Protocol,
    Dxl2ReadMode, Timing,
};
use crate::sim::can_motors::{CanNode, MitMotorSim, OdriveAxisSim};
use crate::sim::dxl::DxlSimConfig;
use crate::sim::fault::FaultConfig;
use crate::sim::hardware::{CanSimHardware, DxlSimHardware};
use crate::sim::{LoopbackHardware, SimDevice, SimProtocol, SineHardware};
use crate::stage::{Device, Hardware, Protocol, SafeAction};

/// Which stage a kind belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// A transport.
    Hardware,
    /// A packet format.
    Protocol,
    /// A bus node.
    Device,
}

/// The unit a hardware carries and a protocol speaks; they must match to be linked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Medium {
    /// Byte stream (UART, pty, UDP).
    Bytes,
    /// Classic CAN frames.
    Can,
    /// The built-in simulated bus.
    Sim,
}

impl Medium {
    /// Human name for messages.
    pub fn name(self) -> &'static str {
        match self {
            Medium::Bytes => "a byte stream",
            Medium::Can => "CAN frames",
            Medium::Sim => "simulated words",
        }
    }
}

/// Type of a parameter value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamType {
    /// Integer.
    Int,
    /// Number (an integer literal is accepted).
    Float,
    /// true/false.
    Bool,
    /// String.
    Str,
}

impl ParamType {
    /// Name for messages ("an integer", ...).
    pub fn expected(self) -> &'static str {
        match self {
            ParamType::Int => "an integer",
            ParamType::Float => "a number",
            ParamType::Bool => "true or false",
            ParamType::Str => "a string",
        }
    }
}

/// One parameter of a kind.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamSpec {
    /// Key in the manifest.
    pub name: &'static str,
    /// Value type.
    pub ty: ParamType,
    /// Default when absent; `None` means the key is required.
    pub default: Option<ParamDefault>,
    /// Inclusive numeric range, if any.
    pub range: Option<(f64, f64)>,
    /// Allowed string values, if restricted.
    pub choices: &'static [&'static str],
    /// One line for the reference.
    pub doc: &'static str,
}

/// A default value (const-constructible).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ParamDefault {
    /// Integer default.
    Int(i64),
    /// Number default.
    Float(f64),
    /// Bool default.
    Bool(bool),
    /// String default.
    Str(&'static str),
    /// Optional: absent means "leave it as the device has it" (a configuration register).
    Unset,
}

/// A component kind.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KindSpec {
    /// Stage.
    pub stage: Stage,
    /// `kind = "..."` in the manifest.
    pub kind: &'static str,
    /// For hardware and protocols: the medium.
    pub medium: Option<Medium>,
    /// For hardware: the parameter naming an exclusive OS resource (e.g. `port`), which two
    /// components anywhere in a manifest may not share.
    pub resource: Option<&'static str>,
    /// For devices: the protocol kinds it can sit on.
    pub protocols: &'static [&'static str],
    /// For devices: the safe actions it can carry out, its declared one first.
    pub safe_actions: &'static [&'static str],
    /// Parameters.
    pub params: &'static [ParamSpec],
    /// One paragraph for the reference.
    pub doc: &'static str,
}

/// A validated parameter value.
#[derive(Debug, Clone, PartialEq)]
pub enum ParamValue {
    /// Integer.
    Int(i64),
    /// Number.
    Float(f64),
    /// Bool.
    Bool(bool),
    /// String.
    Str(String),
}

/// Validated parameters of one component, with the spec's defaults filled in.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Params {
    values: BTreeMap<String, ParamValue>,
}

impl Params {
    /// Parameters from validated values; absent keys take the spec's default.
    pub fn new(spec: &KindSpec, given: BTreeMap<String, ParamValue>) -> Self {
        let mut values = given;
        for p in spec.params {
            if !values.contains_key(p.name) {
                if let Some(d) = p.default {
                    values.insert(
                        p.name.into(),
                        match d {
                            ParamDefault::Int(v) => ParamValue::Int(v),
                            ParamDefault::Float(v) => ParamValue::Float(v),
                            ParamDefault::Bool(v) => ParamValue::Bool(v),
                            ParamDefault::Str(v) => ParamValue::Str(v.into()),
                            ParamDefault::Unset => continue,
                        },
                    );
                }
            }
        }
        Self { values }
    }

    /// Integer parameter.
    pub fn int(&self, name: &str) -> Result<i64, BuildError> {
        match self.values.get(name) {
            Some(ParamValue::Int(v)) => Ok(*v),
            _ => Err(BuildError::Param(name.into())),
        }
    }

    /// Number parameter (integers widen).
    pub fn float(&self, name: &str) -> Result<f64, BuildError> {
        match self.values.get(name) {
            Some(ParamValue::Float(v)) => Ok(*v),
            Some(ParamValue::Int(v)) => Ok(*v as f64),
            _ => Err(BuildError::Param(name.into())),
        }
    }

    /// Bool parameter.
    pub fn bool(&self, name: &str) -> Result<bool, BuildError> {
        match self.values.get(name) {
            Some(ParamValue::Bool(v)) => Ok(*v),
            _ => Err(BuildError::Param(name.into())),
        }
    }

    /// String parameter.
    pub fn str(&self, name: &str) -> Result<&str, BuildError> {
        match self.values.get(name) {
            Some(ParamValue::Str(v)) => Ok(v),
            _ => Err(BuildError::Param(name.into())),
        }
    }

    /// Optional integer parameter (`None` when the manifest leaves it unset).
    pub fn opt_int(&self, name: &str) -> Option<i64> {
        match self.values.get(name) {
            Some(ParamValue::Int(v)) => Some(*v),
            _ => None,
        }
    }
}

/// Failure to build a component from validated parameters (opening a port, ...).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BuildError {
    /// No such kind for this stage.
    #[error("unknown {stage:?} kind {kind:?}")]
    UnknownKind {
        /// Stage asked for.
        stage: Stage,
        /// Kind asked for.
        kind: String,
    },
    /// Protocol and hardware carry different units.
    #[error("protocol {protocol:?} speaks {} but hardware {hardware:?} carries {}", .protocol_medium.name(), .hardware_medium.name())]
    MediumMismatch {
        /// Protocol kind.
        protocol: String,
        /// Its medium.
        protocol_medium: Medium,
        /// Hardware kind.
        hardware: String,
        /// Its medium.
        hardware_medium: Medium,
    },
    /// A parameter the validator should have guaranteed is missing or mistyped.
    #[error("parameter {0:?} missing or of the wrong type")]
    Param(String),
    /// The OS refused (port does not exist, permission, ...).
    #[error("{0}")]
    Open(String),
}

/// Sizes of the per-tick buffers, fixed at build time from the manifest.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Capacity {
    /// Words per tick each way between protocol and hardware.
    pub words: usize,
    /// Requests in flight on one link.
    pub in_flight: usize,
    /// Devices on one link.
    pub devices: usize,
}

const fn p_int(
    name: &'static str,
    default: Option<i64>,
    lo: f64,
    hi: f64,
    doc: &'static str,
) -> ParamSpec {
    ParamSpec {
        name,
        ty: ParamType::Int,
        default: match default {
            Some(v) => Some(ParamDefault::Int(v)),
            None => None,
        },
        range: Some((lo, hi)),
        choices: &[],
        doc,
    }
}

const fn p_float(
    name: &'static str,
    default: f64,
    lo: f64,
    hi: f64,
    doc: &'static str,
) -> ParamSpec {
    ParamSpec {
        name,
        ty: ParamType::Float,
        default: Some(ParamDefault::Float(default)),
        range: Some((lo, hi)),
        choices: &[],
        doc,
    }
}

const fn p_bool(name: &'static str, default: bool, doc: &'static str) -> ParamSpec {
    ParamSpec {
        name,
        ty: ParamType::Bool,
        default: Some(ParamDefault::Bool(default)),
        range: None,
        choices: &[],
        doc,
    }
}

const fn p_str(
    name: &'static str,
    default: Option<&'static str>,
    choices: &'static [&'static str],
    doc: &'static str,
) -> ParamSpec {
    ParamSpec {
        name,
        ty: ParamType::Str,
        default: match default {
            Some(v) => Some(ParamDefault::Str(v)),
            None => None,
        },
        range: None,
        choices,
        doc,
    }
}

const BAUD_DOC: &str = "line speed (bit/s); the protocol stage also times its transactions with it";
const TIMEOUT_US: ParamSpec = p_int(
    "timeout_us",
    Some(2_000),
    1.0,
    10_000_000.0,
    "margin after a transaction's expected end (wire time, return delays) before its replies count as missing (µs)",
);
const RETURN_DELAY_US: ParamSpec = p_int(
    "return_delay_us",
    Some(0),
    0.0,
    508.0,
    "the servos' Return Delay Time (address 9 × 2 µs); set the servos to 0 for the fastest bus",
);
const FAULT_PARAMS: [ParamSpec; 3] = [
    p_float(
        "corrupt",
        0.0,
        0.0,
        1.0,
        "probability that a byte is corrupted (both directions)",
    ),
    p_float(
        "drop",
        0.0,
        0.0,
        1.0,
        "probability that a byte is lost (both directions)",
    ),
    p_int("seed", Some(1), 0.0, 9.0e15, "seed of the fault generator"),
];
const MIT_MODEL_NAMES: &[&str] = &[
    "ak10-9",
    "ak60-6",
    "ak70-10",
    "ak80-6",
    "ak80-9",
    "ak80-64",
    "mini-cheetah",
];

const X_MODEL_NAMES: &[&str] = &[
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

/// Safe actions of the register-mapped servos.
const REGISTER_SAFE: &[&str] = &["hold", "torque_off", "setpoint"];

const fn p_opt(name: &'static str, lo: f64, hi: f64, doc: &'static str) -> ParamSpec {
    ParamSpec {
        name,
        ty: ParamType::Int,
        default: Some(ParamDefault::Unset),
        range: Some((lo, hi)),
        choices: &[],
        doc,
    }
}

const SIM_TIMEOUT: ParamSpec = ParamSpec {
    name: "timeout_us",
    ty: ParamType::Int,
    default: Some(ParamDefault::Int(10_000)),
    range: Some((1.0, 10_000_000.0)),
    choices: &[],
    doc: "a sample request unanswered after this long is reported missing (µs)",
};

/// Every kind this build knows.
pub const KINDS: &[KindSpec] = &[
    KindSpec {
        stage: Stage::Hardware,
        kind: "serial",
        medium: Some(Medium::Bytes),
        resource: Some("port"),
        protocols: &[],
        safe_actions: &[],
        params: &[
            p_str("port", None, &[], "serial device, e.g. /dev/ttyUSB0 or /dev/serial/by-id/usb-FTDI_..."),
            p_int("baud", Some(1_000_000), 1200.0, 12_000_000.0, BAUD_DOC),
            p_bool("low_latency", true, "ask the driver for ASYNC_LOW_LATENCY (FTDI: 1 ms latency timer); ignored where unsupported"),
        ],
        doc: "A serial port (USB adapter such as the ROBOTIS U2D2, RS-485 adapter, or a pty), raw 8N1, \
              read and written without blocking.",
    },
    KindSpec {
        stage: Stage::Hardware,
        kind: "udp",
        medium: Some(Medium::Bytes),
        resource: None,
        protocols: &[],
        safe_actions: &[],
        params: &[
            p_str("remote", None, &[], "peer address host:port (a serial-over-UDP bridge, conductor-sim --udp)"),
            p_str("local", Some("0.0.0.0:0"), &[], "local address to bind"),
            p_int("baud", Some(1_000_000), 1200.0, 12_000_000.0, "speed of the serial bus behind the bridge (bit/s), for the protocol's timing"),
        ],
        doc: "A byte stream over UDP datagrams (non-blocking, connected to one peer).",
    },
    KindSpec {
        stage: Stage::Hardware,
        kind: "dynamixel_sim",
        medium: Some(Medium::Bytes),
        resource: None,
        protocols: &[],
        safe_actions: &[],
        params: &[
            p_str("ids", Some("1,2,3,4,5,6"), &[], "servo IDs on the simulated bus, comma-separated"),
            p_int("baud", Some(1_000_000), 1200.0, 12_000_000.0, BAUD_DOC),
            RETURN_DELAY_US,
            p_bool("baud_timing", true, "replies take their wire time at `baud`"),
            p_float("tau_s", 0.05, 0.0, 100.0, "time constant of the servos' position response (s)"),
            FAULT_PARAMS[0],
            FAULT_PARAMS[1],
            FAULT_PARAMS[2],
        ],
        doc: "An in-process Dynamixel Protocol 2.0 bus of XM430 servos (the simulator of \
              `conductor-sim dxl`, without the pty), with optional fault injection.",
    },
    KindSpec {
        stage: Stage::Hardware,
        kind: "socketcan",
        medium: Some(Medium::Can),
        resource: Some("interface"),
        protocols: &[],
        safe_actions: &[],
        params: &[
            p_str("interface", None, &[], "CAN interface, e.g. can0 (bring it up first: ip link set can0 up type can bitrate 1000000)"),
            p_int("bitrate", Some(1_000_000), 10_000.0, 1_000_000.0, "the bitrate the interface was brought up with (bit/s), for the bus-load check"),
        ],
        doc: "A Linux SocketCAN interface, raw socket, non-blocking.",
    },
    KindSpec {
        stage: Stage::Hardware,
        kind: "slcan",
        medium: Some(Medium::Can),
        resource: Some("port"),
        protocols: &[],
        safe_actions: &[],
        params: &[
            p_str("port", None, &[], "serial device of the USB-CAN adapter, e.g. /dev/ttyACM0"),
            p_int("baud", Some(115_200), 1200.0, 12_000_000.0, "serial line speed (ignored by USB CDC adapters)"),
            p_int("bitrate", Some(1_000_000), 10_000.0, 1_000_000.0, "CAN bitrate (a standard Sn rate)"),
            p_str("dialect", Some("canable"), &["canable", "lawicel"], "SLCAN variant: canable (CR acks, S7 = 750k) or lawicel (z acks, S7 = 800k)"),
        ],
        doc: "An SLCAN (LAWICEL) USB-CAN adapter (CANable, CANUSB, ...) spoken in user space over \
              its serial port: no kernel CAN support needed.",
    },
    KindSpec {
        stage: Stage::Hardware,
        kind: "can_sim",
        medium: Some(Medium::Can),
        resource: None,
        protocols: &[],
        safe_actions: &[],
        params: &[
            p_str("mit", Some(""), &[], "MIT-mode motor IDs, comma-separated"),
            p_str("odrive", Some(""), &[], "ODrive node IDs, comma-separated"),
            p_str("model", Some("ak80-9"), MIT_MODEL_NAMES, "MIT motor model (ranges)"),
            p_int("latency_us", Some(150), 0.0, 1_000_000.0, "delay of the motors' answers (µs)"),
            p_int("heartbeat_ms", Some(100), 0.0, 100_000.0, "ODrive heartbeat period (ms, 0 = off)"),
        ],
        doc: "An in-process CAN bus with simulated MIT-mode motors and ODrive axes.",
    },
    KindSpec {
        stage: Stage::Protocol,
        kind: "dynamixel2",
        medium: Some(Medium::Bytes),
        resource: None,
        protocols: &[],
        safe_actions: &[],
        params: &[
            p_str("read", Some("sync"), &["sync", "fast_sync"], "one SYNC READ (a status packet per servo) or one FAST SYNC READ (one combined packet, X430/540 firmware ≥ 45) per transaction; servos reading different spans get a (FAST) BULK READ"),
            RETURN_DELAY_US,
            TIMEOUT_US,
        ],
        doc: "ROBOTIS Dynamixel Protocol 2.0: a tick's writes become one SYNC WRITE per register, its \
              reads one SYNC READ / FAST SYNC READ; status packets are matched to the requests by ID; \
              missing replies make the states stale. Bus timing comes from the hardware's `baud`.",
    },
    KindSpec {
        stage: Stage::Protocol,
        kind: "dynamixel1",
        medium: Some(Medium::Bytes),
        resource: None,
        protocols: &[],
        safe_actions: &[],
        params: &[
            p_str("read", Some("bulk"), &["bulk", "single"], "one BULK READ for all servos (MX series) or one READ per bus window, round robin (AX series)"),
            RETURN_DELAY_US,
            TIMEOUT_US,
        ],
        doc: "ROBOTIS Dynamixel Protocol 1.0 (AX/MX/RX): writes become SYNC WRITEs, reads one BULK \
              READ (or single READs in turn).",
    },
    KindSpec {
        stage: Stage::Protocol,
        kind: "can_motors",
        medium: Some(Medium::Can),
        resource: None,
        protocols: &[],
        safe_actions: &[],
        params: &[
            p_str("model", Some("ak80-9"), MIT_MODEL_NAMES, "ranges of the MIT-mode motors"),
            p_str("models", Some(""), &[], "per-motor overrides, e.g. \"1=ak80-9,2=ak10-9\""),
            p_int("master_id", Some(0), 0.0, 2047.0, "CAN ID the MIT motors reply on (CAN_MASTER)"),
            TIMEOUT_US,
        ],
        doc: "MIT-mode motors and ODrive axes (CAN Simple 0.6) on one classic CAN bus: one frame per \
              device and tick, all of a tick's frames sent together; MIT replies matched by the motor ID \
              in the payload, ODrive replies by node ID; cyclic ODrive messages are passed on.",
    },
    KindSpec {
        stage: Stage::Device,
        kind: "dynamixel_x",
        medium: None,
        resource: None,
        protocols: &["dynamixel2"],
        safe_actions: REGISTER_SAFE,
        params: &[
            p_int("zero", Some(2048), -1_048_575.0, 1_048_575.0, "raw position meaning 0 rad"),
            p_int("operating_mode", Some(3), 0.0, 16.0, "the servo's Operating Mode (3 position: goals 0..4095; 4/5 extended: ±256 rev)"),
            p_float("current_unit_ma", 2.69, 0.01, 100.0, "Present/Goal Current unit (mA)"),
            p_int("max_current_raw", Some(2047), 1.0, 32767.0, "largest |Present Current| accepted (raw); larger values are treated as damaged"),
            p_float("max_position_rev", 256.0, 1.0, 524_288.0, "largest |Present Position| accepted (revolutions)"),
            p_str("model", Some("xm430-w350"), X_MODEL_NAMES, "the model the servo must report at bring-up (its model number); \"any\": no check"),
            p_opt("return_delay_us", 0.0, 508.0, "Return Delay Time written at bring-up (µs, even; EEPROM: written with torque off); match the protocol's return_delay_us"),
            p_opt("status_return_level", 1.0, 2.0, "Status Return Level written at bring-up (1: reads answered, 2: every instruction)"),
            p_opt("min_position_limit", 0.0, 4095.0, "Min Position Limit written at bring-up (raw pulses, EEPROM)"),
            p_opt("max_position_limit", 0.0, 4095.0, "Max Position Limit written at bring-up (raw pulses, EEPROM)"),
            p_opt("velocity_limit", 0.0, 1023.0, "Velocity Limit written at bring-up (raw, 0.229 rpm, EEPROM)"),
            p_opt("current_limit", 0.0, 2047.0, "Current Limit written at bring-up (raw, ≈2.69 mA, EEPROM)"),
            p_opt("profile_velocity", 0.0, 32767.0, "Profile Velocity written at bring-up (raw, 0.229 rpm; 0 = unlimited)"),
            p_opt("profile_acceleration", 0.0, 32767.0, "Profile Acceleration written at bring-up (raw, 214.577 rev/min²; 0 = unlimited)"),
            p_bool("reboot_on_fault", false, "after a hardware error (the servo cut its torque), reboot it (back-off 1 s doubling to 30 s), bring it up again and re-enable it where it is"),
        ],
        doc: "A Dynamixel X-series servo (XM430/XM540/XH430/XH540 control table). Channels: position \
              (rad; reads Present Position, writes Goal Position), velocity (rad/s), current (A), \
              goal_position (rad), torque_enable, operating_mode, temperature (°C), voltage (V), \
              hardware_error (Hardware Error Status bits), enable. Brought up by PING (model number \
              checked), its configuration read and written (EEPROM with torque off) and read back, \
              Goal Position set to Present Position, then Torque Enable. Safe action: hold.",
    },
    KindSpec {
        stage: Stage::Device,
        kind: "dynamixel1",
        medium: None,
        resource: None,
        protocols: &["dynamixel1"],
        safe_actions: REGISTER_SAFE,
        params: &[
            p_str("model", Some("ax"), &["ax", "mx"], "ax: 1024 steps over 300°; mx: 4096 over 360°"),
            p_int("zero", Some(-1), -1.0, 4095.0, "raw position meaning 0 rad (-1: the middle, 512 or 2048)"),
            p_opt("return_delay_us", 0.0, 508.0, "Return Delay Time written at bring-up (µs, even)"),
        ],
        doc: "A Dynamixel AX/MX servo on Protocol 1.0. Channels: position (rad), velocity (rad/s), load \
              (fraction), torque_enable, temperature (°C), voltage (V), enable. Brought up by PING, \
              its model number read (AX-12A/AX-18A/AX-12W or MX-28/64/106), then Goal Position set to \
              the present one and Torque Enable. Overload, overheating and input voltage errors are \
              faults. Safe action: hold.",
    },
    KindSpec {
        stage: Stage::Device,
        kind: "mit_motor",
        medium: None,
        resource: None,
        protocols: &["can_motors"],
        safe_actions: &["torque_off", "damp", "hold", "setpoint"],
        params: &[
            p_float("kp", 0.0, 0.0, 500.0, "position gain until the kp channel is written"),
            p_float("kd", 0.0, 0.0, 5.0, "velocity gain until the kd channel is written"),
        ],
        doc: "An MIT-mode motor (Katz firmware, CubeMars AK). Channels: position (rad), velocity (rad/s), \
              torque (N·m), kp, kd (the gains in use), enable, temperature (°C) and fault (code), the \
              last two from 8-byte replies. A tick's writes form one command; the motor only answers \
              frames, so a sample re-sends the last command. Brought up by an exit-motor-mode frame \
              (it must answer), then enter motor mode and a command holding the present position. \
              Safe action: torque off (exit motor mode); `damp` commands kp = 0 and kd = `safe_value` \
              (default: the kd parameter).",
    },
    KindSpec {
        stage: Stage::Device,
        kind: "odrive_axis",
        medium: None,
        resource: None,
        protocols: &["can_motors"],
        safe_actions: &["torque_off", "hold", "setpoint"],
        params: &[
            p_str("control_mode", Some("position"), &["position", "velocity", "torque"], "which input the setpoints drive"),
            p_bool("poll", true, "request values with remote frames (false: use the axis's cyclic messages)"),
        ],
        doc: "An ODrive axis (CAN Simple, firmware 0.6). Channels: position (rad), velocity (rad/s), \
              torque (N·m), current (A), state, error, bus_voltage (V), temperature (°C), enable. \
              Brought up by a heartbeat request, the controller mode written, the input set to the \
              present position, then closed-loop control, confirmed by its heartbeat. Safe action: \
              torque off (idle).",
    },
    KindSpec {
        stage: Stage::Hardware,
        kind: "sine",
        medium: Some(Medium::Sim),
        resource: None,
        protocols: &[],
        safe_actions: &[],
        params: &[
            ParamSpec {
                name: "amplitude",
                ty: ParamType::Float,
                default: Some(ParamDefault::Float(1.0)),
                range: None,
                choices: &[],
                doc: "amplitude of the answered sine",
            },
            ParamSpec {
                name: "frequency_hz",
                ty: ParamType::Float,
                default: Some(ParamDefault::Float(1.0 / (2.0 * core::f64::consts::PI))),
                range: Some((0.0, 1e6)),
                choices: &[],
                doc: "frequency (default 1/2π Hz, i.e. sin(t) as in the thesis)",
            },
            ParamSpec {
                name: "phase_per_id",
                ty: ParamType::Float,
                default: Some(ParamDefault::Float(0.0)),
                range: None,
                choices: &[],
                doc: "phase offset added per device id (rad)",
            },
        ],
        doc: "Simulated hardware of the thesis' stress test: answers every sample request at time t \
              with amplitude·sin(2π·frequency·t + phase·id), t in seconds of CLOCK_MONOTONIC.",
    },
    KindSpec {
        stage: Stage::Hardware,
        kind: "loopback",
        medium: Some(Medium::Sim),
        resource: None,
        protocols: &[],
        safe_actions: &[],
        params: &[ParamSpec {
            name: "tau_s",
            ty: ParamType::Float,
            default: Some(ParamDefault::Float(0.0)),
            range: Some((0.0, 1e3)),
            choices: &[],
            doc: "first-order lag between setpoint and sampled value (s); 0 = immediate",
        }],
        doc: "Simulated hardware that answers a sample request with the last setpoint written to \
              the same device, optionally through a first-order lag (a stand-in for a servo). \
              Each device starts where its state reads a value inside the state's limits (0 when \
              the limits allow it, else their middle or the one finite limit), not at 0 in device \
              units.",
    },
    KindSpec {
        stage: Stage::Protocol,
        kind: "sim",
        medium: Some(Medium::Sim),
        resource: None,
        protocols: &[],
        safe_actions: &[],
        params: &[SIM_TIMEOUT],
        doc: "Protocol of the simulated hardware: one word per request, replies matched by device id.",
    },
    KindSpec {
        stage: Stage::Device,
        kind: "sim",
        medium: None,
        resource: None,
        protocols: &["sim"],
        safe_actions: &["hold", "torque_off", "setpoint"],
        params: &[],
        doc: "A device on the simulated bus with one read/write channel, `value`.",
    },
];

/// Looks up a kind.
pub fn find(stage: Stage, kind: &str) -> Option<&'static KindSpec> {
    KINDS.iter().find(|k| k.stage == stage && k.kind == kind)
}

/// Kinds of one stage.
pub fn of_stage(stage: Stage) -> impl Iterator<Item = &'static KindSpec> {
    KINDS.iter().filter(move |k| k.stage == stage)
}

fn spec(stage: Stage, kind: &str) -> Result<&'static KindSpec, BuildError> {
    find(stage, kind).ok_or_else(|| BuildError::UnknownKind {
        stage,
        kind: kind.into(),
    })
}

/// The safe action a device kind declares (what the executor does when commands stop, unless
/// the manifest says otherwise); `None` for unknown kinds.
pub fn safe_action(device_kind: &str) -> Option<SafeAction> {
    Some(match device_kind {
        "dynamixel_x" => DynamixelX::SAFE_ACTION,
        "dynamixel1" => Dynamixel1::SAFE_ACTION,
        "mit_motor" => MitMotor::SAFE_ACTION,
        "odrive_axis" => OdriveAxis::SAFE_ACTION,
        "sim" => SafeAction::Hold,
        _ => return None,
    })
}

fn ids(s: &str, what: &str) -> Result<Vec<u8>, BuildError> {
    s.split(',')
        .map(str::trim)
        .filter(|x| !x.is_empty())
        .map(|x| {
            x.parse::<u8>()
                .map_err(|_| BuildError::Open(format!("{what}: {x:?} is not an ID (0-253)")))
        })
        .collect()
}

fn open_err(what: &str, e: impl std::fmt::Display) -> BuildError {
    BuildError::Open(format!("{what}: {e}"))
}

fn addr(s: &str, key: &str) -> Result<std::net::SocketAddr, BuildError> {
    use std::net::ToSocketAddrs;
    s.to_socket_addrs()
        .map_err(|e| open_err(key, e))?
        .next()
        .ok_or_else(|| BuildError::Open(format!("{key}: {s:?} resolves to nothing")))
}

/// The line speed a byte hardware runs at (for the protocol's timing).
fn hardware_baud(hp: &Params) -> u32 {
    hp.int("baud")
        .map_or(1_000_000, |b| b.clamp(1, u32::MAX as i64) as u32)
}

fn link_bytes<P: Protocol<Word = u8> + 'static>(
    p: P,
    hardware: &str,
    hp: &Params,
    cap: Capacity,
) -> Result<Box<dyn Link>, BuildError> {
    fn boxed<P: Protocol<Word = u8> + 'static, H: Hardware<Word = u8> + 'static>(
        p: P,
        h: H,
        cap: Capacity,
    ) -> Box<dyn Link> {
        Box::new(LinkOf::new(p, h, cap.words))
    }
    Ok(match hardware {
        "serial" => {
            let port = hp.str("port")?.to_string();
            let opts = SerialOptions {
                baud: hardware_baud(hp),
                low_latency: hp.bool("low_latency")?,
                exclusive: true,
            };
            let hw = SerialHardware::open(&port, &opts).map_err(|e| open_err(&port, e))?;
            let (path, again) = (port.clone(), port.clone());
            let opener = Opener {
                open: Box::new(move || {
                    SerialHardware::open(&again, &opts).map_err(|e| e.to_string())
                }),
                present: Box::new(move || std::path::Path::new(&path).exists()),
            };
            Box::new(
                LinkOf::new(p, hw, cap.words)
                    .with_reopen(&port, opener)
                    .map_err(|e| open_err(&port, e))?,
            )
        }
        "udp" => {
            let (local, remote) = (
                addr(hp.str("local")?, "local")?,
                addr(hp.str("remote")?, "remote")?,
            );
            boxed(
                p,
                UdpHardware::open(local, remote).map_err(|e| open_err("udp", e))?,
                cap,
            )
        }
        "dynamixel_sim" => {
            let cfg = DxlSimConfig {
                ids: ids(hp.str("ids")?, "ids")?,
                baud: hardware_baud(hp),
                return_delay_us: hp.int("return_delay_us")? as u32,
                baud_timing: hp.bool("baud_timing")?,
                tau_s: hp.float("tau_s")?,
                ..DxlSimConfig::default()
            };
            let faults = FaultConfig {
                corrupt: hp.float("corrupt")?,
                drop: hp.float("drop")?,
                seed: hp.int("seed")? as u64,
                ..FaultConfig::default()
            };
            let up = FaultConfig {
                seed: faults.seed ^ 0x5EED,
                ..faults
            };
            boxed(p, DxlSimHardware::new(cfg, faults, up), cap)
        }
        other => {
            return Err(BuildError::UnknownKind {
                stage: Stage::Hardware,
                kind: other.into(),
            })
        }
    })
}

fn link_can(
    p: CanMotorProtocol,
    hardware: &str,
    hp: &Params,
    cap: Capacity,
) -> Result<Box<dyn Link>, BuildError> {
    let fill = CanFrame::standard(0, &[]).ok_or_else(|| BuildError::Open("CAN frame".into()))?;
    Ok(match hardware {
        "socketcan" => {
            let iface = hp.str("interface")?.to_string();
            let hw = SocketCanHardware::open(&iface).map_err(|e| open_err(&iface, e))?;
            let (name, again) = (iface.clone(), iface.clone());
            let opener = Opener {
                // A down interface opens but cannot send: wait until it is up.
                open: Box::new(move || {
                    if !interface_up(&again) {
                        return Err(format!("{again} is not up"));
                    }
                    SocketCanHardware::open(&again).map_err(|e| e.to_string())
                }),
                present: Box::new(move || interface_up(&name)),
            };
            Box::new(
                LinkOf::with_fill(p, hw, cap.words, fill)
                    .with_reopen(&iface, opener)
                    .map_err(|e| open_err(&iface, e))?,
            )
        }
        "slcan" => {
            let port = hp.str("port")?.to_string();
            let bitrate = u32::try_from(hp.int("bitrate")?)
                .ok()
                .and_then(Bitrate::from_bps)
                .ok_or_else(|| BuildError::Open("bitrate: not a standard SLCAN rate (10k, 20k, 50k, 100k, 125k, 250k, 500k, 750k/800k, 1M)".into()))?;
            let dialect = match hp.str("dialect")? {
                "lawicel" => Dialect::LAWICEL,
                "canable" => Dialect::CANABLE,
                _ => return Err(BuildError::Param("dialect".into())),
            };
            let baud = hardware_baud(hp);
            let open = move |port: &str| -> Result<SlcanHardware<SerialHardware>, String> {
                let serial = SerialHardware::open(
                    port,
                    &SerialOptions {
                        baud,
                        low_latency: true,
                        exclusive: true,
                    },
                )
                .map_err(|e| e.to_string())?;
                SlcanHardware::open(
                    serial,
                    SlcanOptions {
                        bitrate,
                        dialect,
                        ..SlcanOptions::default()
                    },
                )
                .map_err(|e| e.to_string())
            };
            let hw = open(&port).map_err(|e| open_err(&port, e))?;
            let (path, again) = (port.clone(), port.clone());
            let opener = Opener {
                open: Box::new(move || open(&again)),
                present: Box::new(move || std::path::Path::new(&path).exists()),
            };
            Box::new(
                LinkOf::with_fill(p, hw, cap.words, fill)
                    .with_reopen(&port, opener)
                    .map_err(|e| open_err(&port, e))?,
            )
        }
        "can_sim" => {
            let limits =
                mit_limits(hp.str("model")?).ok_or_else(|| BuildError::Param("model".into()))?;
            let mut nodes: Vec<Box<dyn CanNode>> = Vec::new();
            for id in ids(hp.str("mit")?, "mit")? {
                nodes.push(Box::new(MitMotorSim::new(id, limits, 0, false)));
            }
            for n in ids(hp.str("odrive")?, "odrive")? {
                nodes.push(Box::new(OdriveAxisSim::new(
                    n,
                    hp.int("heartbeat_ms")? as u64,
                    0,
                )));
            }
            let hw = CanSimHardware::new(nodes, hp.int("latency_us")? as u64 * 1000);
            Box::new(LinkOf::with_fill(p, hw, cap.words, fill))
        }
        other => {
            return Err(BuildError::UnknownKind {
                stage: Stage::Hardware,
                kind: other.into(),
            })
        }
    })
}

/// Builds a protocol bound to its hardware (opening OS resources: call at start-up).
pub fn build_link(
    protocol: &str,
    protocol_params: &Params,
    hardware: &str,
    hardware_params: &Params,
    cap: Capacity,
) -> Result<Box<dyn Link>, BuildError> {
    let ps = spec(Stage::Protocol, protocol)?;
    let hs = spec(Stage::Hardware, hardware)?;
    if ps.medium != hs.medium {
        return Err(BuildError::MediumMismatch {
            protocol: protocol.into(),
            protocol_medium: ps.medium.expect("protocols have a medium"),
            hardware: hardware.into(),
            hardware_medium: hs.medium.expect("hardware has a medium"),
        });
    }
    let pp = protocol_params;
    let hp = hardware_params;
    let timing = || -> Result<Timing, BuildError> {
        Ok(Timing {
            baud: hardware_baud(hp),
            return_delay_ns: pp.int("return_delay_us")? as u64 * 1000,
            timeout_ns: pp.int("timeout_us")? as u64 * 1000,
        })
    };
    match protocol {
        "sim" => {
            let p = SimProtocol::new(cap.in_flight, pp.int("timeout_us")? as u64 * 1000);
            Ok(match hardware {
                "sine" => Box::new(LinkOf::new(
                    p,
                    SineHardware::new(
                        hp.float("amplitude")?,
                        hp.float("frequency_hz")?,
                        hp.float("phase_per_id")?,
                        cap.words,
                    ),
                    cap.words,
                )),
                "loopback" => Box::new(LinkOf::new(
                    p,
                    LoopbackHardware::new(hp.float("tau_s")?, cap.devices, cap.words),
                    cap.words,
                )),
                other => {
                    return Err(BuildError::UnknownKind {
                        stage: Stage::Hardware,
                        kind: other.into(),
                    })
                }
            })
        }
        "dynamixel2" => {
            let mode = match pp.str("read")? {
                "fast_sync" => Dxl2ReadMode::Fast,
                "sync" => Dxl2ReadMode::Sync,
                _ => return Err(BuildError::Param("read".into())),
            };
            let p = Dxl2Protocol::new(timing()?, mode, cap.devices, cap.in_flight);
            link_bytes(p, hardware, hp, cap)
        }
        "dynamixel1" => {
            let mode = match pp.str("read")? {
                "single" => Dxl1ReadMode::Single,
                "bulk" => Dxl1ReadMode::Bulk,
                _ => return Err(BuildError::Param("read".into())),
            };
            let p = Dxl1Protocol::new(timing()?, mode, cap.devices, cap.in_flight);
            link_bytes(p, hardware, hp, cap)
        }
        "can_motors" => {
            let default =
                mit_limits(pp.str("model")?).ok_or_else(|| BuildError::Param("model".into()))?;
            let table = parse_model_table(pp.str("models")?)
                .map_err(|e| BuildError::Open(format!("models: {e}")))?;
            let p = CanMotorProtocol::new(
                default,
                table,
                pp.int("master_id")? as u16,
                pp.int("timeout_us")? as u64 * 1000,
                cap.in_flight,
            );
            link_can(p, hardware, hp, cap)
        }
        other => Err(BuildError::UnknownKind {
            stage: Stage::Protocol,
            kind: other.into(),
        }),
    }
}

/// Builds a device at `cred` (its bus address from the manifest).
pub fn build_device(
    kind: &str,
    params: &Params,
    cred: Credential,
) -> Result<Box<dyn Device>, BuildError> {
    spec(Stage::Device, kind)?;
    let p = params;
    Ok(match kind {
        "sim" => Box::new(SimDevice::new(cred)),
        "dynamixel_x" => {
            let opt = |k: &str| p.opt_int(k);
            let models =
                x_models(p.str("model")?).ok_or_else(|| BuildError::Param("model".into()))?;
            let cfg = DxlXConfig {
                zero: p.int("zero")?,
                operating_mode: p.int("operating_mode")? as u8,
                current_unit_ma: p.float("current_unit_ma")?,
                max_current_raw: p.int("max_current_raw")?,
                max_position_rev: p.float("max_position_rev")?,
                models,
                setup: DxlXSetup {
                    return_delay_us: opt("return_delay_us").map(|v| v as u32),
                    status_return_level: opt("status_return_level").map(|v| v as u8),
                    position_limits: (opt("min_position_limit"), opt("max_position_limit")),
                    velocity_limit: opt("velocity_limit"),
                    current_limit: opt("current_limit"),
                    profile: (opt("profile_acceleration"), opt("profile_velocity")),
                },
            };
            Box::new(DynamixelX::new(cred, cfg).reboot_on_fault(p.bool("reboot_on_fault")?))
        }
        "dynamixel1" => {
            let model = match p.str("model")? {
                "mx" => Dxl1Model::Mx,
                "ax" => Dxl1Model::Ax,
                _ => return Err(BuildError::Param("model".into())),
            };
            let zero = match (p.int("zero")?, model) {
                (z, _) if z >= 0 => z,
                (_, Dxl1Model::Ax) => 512,
                (_, Dxl1Model::Mx) => 2048,
            };
            let delay = p.opt_int("return_delay_us").map(|v| v as u32);
            Box::new(Dynamixel1::with_return_delay(cred, model, zero, delay))
        }
        "mit_motor" => Box::new(MitMotor::new(
            cred,
            p.float("kp")? as f32,
            p.float("kd")? as f32,
        )),
        "odrive_axis" => {
            let mode = match p.str("control_mode")? {
                "position" => OdriveMode::Position,
                "velocity" => OdriveMode::Velocity,
                "torque" => OdriveMode::Torque,
                _ => return Err(BuildError::Param("control_mode".into())),
            };
            Box::new(OdriveAxis::new(cred, mode, p.bool("poll")?))
        }
        other => {
            return Err(BuildError::UnknownKind {
                stage: Stage::Device,
                kind: other.into(),
            })
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_are_consistent() {
        for k in KINDS {
            assert_eq!(k.medium.is_some(), k.stage != Stage::Device, "{}", k.kind);
            for p in k.params {
                if let (Some(ParamDefault::Float(d)), Some((lo, hi))) = (p.default, p.range) {
                    assert!(
                        (lo..=hi).contains(&d),
                        "{}.{} default out of range",
                        k.kind,
                        p.name
                    );
                }
            }
            for proto in k.protocols {
                assert!(
                    find(Stage::Protocol, proto).is_some(),
                    "{} names {proto}",
                    k.kind
                );
            }
        }
    }

    #[test]
    fn defaults_fill_in_and_links_build() {
        let sine = find(Stage::Hardware, "sine").unwrap();
        let p = Params::new(sine, BTreeMap::new());
        assert_eq!(p.float("amplitude").unwrap(), 1.0);
        let sim = Params::new(find(Stage::Protocol, "sim").unwrap(), BTreeMap::new());
        let cap = Capacity {
            words: 8,
            in_flight: 8,
            devices: 2,
        };
        assert!(build_link("sim", &sim, "sine", &p, cap).is_ok());
        assert!(matches!(
            build_link("sim", &sim, "nope", &p, cap),
            Err(BuildError::UnknownKind { .. })
        ));
        assert!(build_device("sim", &Params::default(), Credential::id(1)).is_ok());
    }

    fn params(stage: Stage, kind: &str, given: &[(&str, ParamValue)]) -> Params {
        let spec = find(stage, kind).unwrap();
        Params::new(
            spec,
            given
                .iter()
                .map(|(k, v)| (k.to_string(), v.clone()))
                .collect(),
        )
    }

    fn cap() -> Capacity {
        Capacity {
            words: 4096,
            in_flight: 64,
            devices: 8,
        }
    }

    #[test]
    fn every_device_kind_builds_with_defaults_and_declares_a_safe_action() {
        for k in of_stage(Stage::Device) {
            let d = build_device(
                k.kind,
                &params(Stage::Device, k.kind, &[]),
                Credential::id(1),
            )
            .unwrap_or_else(|e| panic!("{}: {e}", k.kind));
            assert!(!d.channels().is_empty());
            assert!(safe_action(k.kind).is_some(), "{}", k.kind);
        }
        // A writable `position` channel on every actuator.
        for kind in ["dynamixel_x", "dynamixel1", "mit_motor", "odrive_axis"] {
            let d =
                build_device(kind, &params(Stage::Device, kind, &[]), Credential::id(1)).unwrap();
            let pos = d.channels().iter().find(|c| c.name == "position").unwrap();
            assert!(pos.readable && pos.writable, "{kind}");
        }
    }

    #[test]
    fn in_process_simulated_links_build() {
        let s = |v: &str| ParamValue::Str(v.into());
        for proto in ["dynamixel2", "dynamixel1"] {
            let pp = params(Stage::Protocol, proto, &[]);
            let hp = params(Stage::Hardware, "dynamixel_sim", &[]);
            assert!(
                build_link(proto, &pp, "dynamixel_sim", &hp, cap()).is_ok(),
                "{proto}"
            );
        }
        let pp = params(Stage::Protocol, "can_motors", &[("models", s("2=ak10-9"))]);
        let hp = params(
            Stage::Hardware,
            "can_sim",
            &[("mit", s("1,2")), ("odrive", s("3"))],
        );
        assert!(build_link("can_motors", &pp, "can_sim", &hp, cap()).is_ok());
        let bad = params(Stage::Protocol, "can_motors", &[("models", s("2=ak99"))]);
        assert!(matches!(
            build_link("can_motors", &bad, "can_sim", &hp, cap()),
            Err(BuildError::Open(m)) if m.contains("ak99")
        ));
    }

    #[test]
    fn os_resources_fail_with_a_message_not_a_panic() {
        let s = |v: &str| ParamValue::Str(v.into());
        let pp = params(Stage::Protocol, "dynamixel2", &[]);
        let hp = params(
            Stage::Hardware,
            "serial",
            &[("port", s("/dev/conductor-nonexistent"))],
        );
        match build_link("dynamixel2", &pp, "serial", &hp, cap()) {
            Err(BuildError::Open(m)) => assert!(m.contains("/dev/conductor-nonexistent"), "{m}"),
            other => panic!("{:?}", other.err()),
        }
        let pp = params(Stage::Protocol, "can_motors", &[]);
        let hp = params(
            Stage::Hardware,
            "socketcan",
            &[("interface", s("conductor-none0"))],
        );
        assert!(matches!(
            build_link("can_motors", &pp, "socketcan", &hp, cap()),
            Err(BuildError::Open(_))
        ));
        // A byte protocol on CAN hardware is refused before anything is opened.
        let pp = params(Stage::Protocol, "dynamixel2", &[]);
        assert!(matches!(
            build_link("dynamixel2", &pp, "socketcan", &hp, cap()),
            Err(BuildError::MediumMismatch { .. })
        ));
    }

    #[test]
    fn mit_model_choices_match_the_protocol_table() {
        let names: Vec<&str> = crate::protocol::MIT_MODELS.iter().map(|m| m.0).collect();
        assert_eq!(names, MIT_MODEL_NAMES);
    }

    #[test]
    fn exclusive_resources_are_declared() {
        for (kind, res) in [
            ("serial", "port"),
            ("slcan", "port"),
            ("socketcan", "interface"),
        ] {
            let k = find(Stage::Hardware, kind).unwrap();
            assert_eq!(k.resource, Some(res));
            assert!(k
                .params
                .iter()
                .any(|p| p.name == res && p.default.is_none()));
        }
    }
}
