//! A first-order DC motor, the plant every example controls.
//!
//! Voltage `u` drives the velocity ω towards `gain · u` with time constant `tau`; the position θ
//! integrates ω:  τ·dω/dt = gain·u − ω,  dθ/dt = ω.  The step is the exact solution for `u` held
//! over the tick (zero-order hold), so the simulation adds no integration error.

use conductor_bus::{StateMeta, StateSpec};

use crate::sim::{Plant, SimSpec};

/// Subsystem of the simulated motor.
pub const SUBSYSTEM: &str = "motor";
/// Index of `motor/position` (rad, read-only).
pub const POSITION: usize = 0;
/// Index of `motor/velocity` (rad/s, read-only).
pub const VELOCITY: usize = 1;
/// Index of `motor/command` (V, writable, limits ±[`VOLTAGE_LIMIT`]).
pub const COMMAND: usize = 2;
/// Limit of the command voltage.
pub const VOLTAGE_LIMIT: f64 = 12.0;

/// Motor parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Motor {
    /// Steady-state velocity per volt (rad/s/V).
    pub gain: f64,
    /// Mechanical time constant (s).
    pub tau: f64,
}

impl Default for Motor {
    /// gain 2 rad/s/V, τ = 0.1 s.
    fn default() -> Self {
        Self {
            gain: 2.0,
            tau: 0.1,
        }
    }
}

impl Plant for Motor {
    fn step(&mut self, dt: f64, values: &mut [f64]) {
        let u = values[COMMAND];
        let w = values[VELOCITY];
        let w_inf = self.gain * u;
        let a = (-dt / self.tau).exp();
        values[POSITION] += w_inf * dt + (w - w_inf) * self.tau * (1.0 - a);
        values[VELOCITY] = w_inf + (w - w_inf) * a;
    }
}

/// The motor's subsystem: `position`, `velocity`, `command`, published at `rate_hz`.
pub fn spec(rate_hz: f64) -> SimSpec {
    let state = |index: u32, name: &str, units: &str, writable: bool, limit: f64| {
        StateSpec::new(
            name,
            StateMeta {
                index,
                units: units.into(),
                writable,
                rate_hz,
                min: -limit,
                max: limit,
                device: "motor0".into(),
            },
        )
    };
    SimSpec {
        subsystem: SUBSYSTEM.into(),
        rate_hz,
        states: vec![
            state(POSITION as u32, "position", "rad", false, f64::INFINITY),
            state(VELOCITY as u32, "velocity", "rad/s", false, f64::INFINITY),
            state(COMMAND as u32, "command", "V", true, VOLTAGE_LIMIT),
        ],
        initial: vec![0.0; 3],
        stats_hz: 10.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_matches_the_closed_form_solution() {
        // From rest with u held: ω(t) = g·u·(1 − e^{−t/τ}), θ(t) = g·u·(t − τ(1 − e^{−t/τ})).
        let mut m = Motor::default();
        let mut v = [0.0, 0.0, 3.0];
        for _ in 0..1000 {
            m.step(1e-3, &mut v);
        }
        let (g, tau, u, t) = (m.gain, m.tau, 3.0, 1.0);
        let e = (-t / tau).exp();
        // Exact per step; only rounding accumulates over 1000 steps.
        assert!((v[VELOCITY] - g * u * (1.0 - e)).abs() < 1e-9);
        assert!((v[POSITION] - g * u * (t - tau * (1.0 - e))).abs() < 1e-9);
    }
}
