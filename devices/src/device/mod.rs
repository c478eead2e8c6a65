//! Devices: nodes on a bus. Each maps its registers or messages to channels in physical
//! units, tags its requests with its credential, interprets the replies that carry it (a
//! missing reply makes the channel stale), and declares the safe action it takes when commands
//! stop.
//!
//! | Type | Bus | Channels | Declared safe action |
//! |---|---|---|---|
//! | [`DynamixelX`] | Dynamixel 2.0 | position, velocity, current, goal_position, torque_enable, operating_mode, temperature, voltage | hold |
//! | [`Dynamixel1`] | Dynamixel 1.0 | position, velocity, load, torque_enable, temperature, voltage | hold |
//! | [`MitMotor`] | CAN (MIT mode) | position, velocity, torque, kp, kd, enable | torque off |
//! | [`OdriveAxis`] | CAN (ODrive) | position, velocity, torque, current, state, error, bus_voltage, temperature | torque off |

mod dynamixel;
mod mit;
mod odrive;
mod register;

pub use dynamixel::{
    dxl1_channel, x_channel, x_table, Dxl1Model, Dxl1Series, DxlXConfig, Dynamixel1, DynamixelX,
    XSeries,
};
pub use mit::{mit_channel, MitMotor};
pub use odrive::{odrive_channel, OdriveAxis, OdriveMode};
pub use register::{ControlTable, Encoding, RegChannel, RegDevice};
