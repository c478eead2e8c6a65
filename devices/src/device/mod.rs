//! Devices: nodes on a bus. Each maps its registers or messages to channels in physical
//! units, tags its requests with its credential, interprets the replies that carry it (a
//! missing reply makes the channel stale), and declares the safe action it takes when commands
//! stop.
//!
//! | Type | Bus | Channels | Declared safe action |
//! |---|---|---|---|
//! | [`DynamixelX`] | Dynamixel 2.0 | position, velocity, current, goal_position, torque_enable, operating_mode, temperature, voltage, hardware_error, enable | hold |
//! | [`Dynamixel1`] | Dynamixel 1.0 | position, velocity, load, torque_enable, temperature, voltage, enable | hold |
//! | [`MitMotor`] | CAN (MIT mode) | position, velocity, torque, kp, kd, enable, temperature, fault | torque off |
//! | [`OdriveAxis`] | CAN (ODrive) | position, velocity, torque, current, state, error, bus_voltage, temperature, enable | torque off |
//!
//! Every actuator has an `enable` channel and a lifecycle ([`crate::lifecycle`]): brought up by
//! the executor (probe, model check, configuration, enable from the present position), tripped
//! by the watchdog or a fault, re-enabled through `enable`.

mod control_table;
pub mod cubemars_ak;
pub(crate) mod dynamixel;
pub(crate) mod mit;
pub(crate) mod odrive;
mod reg_device;

pub use control_table::{ConfigItem, ControlTable, Encoding, Indirect, RegChannel};
pub use dynamixel::{
    dxl1_channel, x_channel, x_models, x_table, Dxl1Model, Dxl1Series, DxlXConfig, DxlXSetup,
    Dynamixel1, DynamixelX, XSeries, AX_MODELS, MX_MODELS, X_MODELS, X_MODEL_NAMES,
};
pub use mit::{mit_channel, MitMotor};
pub use odrive::{odrive_channel, OdriveAxis, OdriveMode};
pub use reg_device::{Layout, RegDevice};
