//! The mini-Hubo demo's mathematics: a walking-like joint trajectory and the thesis' PID
//! (Fig. 3.4) written on a State's value, derivative and integral.
//!
//! The controller commands each joint's goal position `u = r + Kp·e + Ki·∫e + Kd·ė` with
//! `e = r − θ`. It never differentiates or integrates anything itself: θ̇ is the State's
//! derivative, ∫θ the State's integral, and r, ṙ, ∫r are known in closed form.

use std::f64::consts::PI;

/// One joint's reference: `r(τ) = centre + amplitude · sin(ω τ + phase)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointTrajectory {
    /// Joint (state) name.
    pub joint: &'static str,
    /// Mean position (rad).
    pub centre: f64,
    /// Amplitude (rad).
    pub amplitude: f64,
    /// Phase (rad).
    pub phase: f64,
}

/// Gait frequency (Hz): a 2 s step cycle.
pub const GAIT_HZ: f64 = 0.5;

/// A slow walking pattern for the right leg (hip, knee and ankle pitch swing; roll and yaw
/// balance), inside every joint's limits in `deploy/minihubo-right-leg.toml`.
pub const GAIT: [JointTrajectory; 6] = [
    JointTrajectory {
        joint: "RAR",
        centre: 0.0,
        amplitude: -0.1,
        phase: 0.0,
    },
    JointTrajectory {
        joint: "RAP",
        centre: -0.3,
        amplitude: 0.3,
        phase: PI,
    },
    JointTrajectory {
        joint: "RKP",
        centre: 0.6,
        amplitude: 0.5,
        phase: -PI / 2.0,
    },
    JointTrajectory {
        joint: "RHR",
        centre: 0.0,
        amplitude: 0.1,
        phase: 0.0,
    },
    JointTrajectory {
        joint: "RHP",
        centre: -0.3,
        amplitude: 0.4,
        phase: 0.0,
    },
    JointTrajectory {
        joint: "RHY",
        centre: 0.0,
        amplitude: 0.05,
        phase: PI / 2.0,
    },
];

impl JointTrajectory {
    fn omega() -> f64 {
        2.0 * PI * GAIT_HZ
    }

    /// r(τ), τ seconds since the trajectory started.
    pub fn position(&self, tau: f64) -> f64 {
        self.centre + self.amplitude * (Self::omega() * tau + self.phase).sin()
    }

    /// ṙ(τ).
    pub fn velocity(&self, tau: f64) -> f64 {
        self.amplitude * Self::omega() * (Self::omega() * tau + self.phase).cos()
    }

    /// ∫ r dτ from `a` to `b`.
    pub fn integral(&self, a: f64, b: f64) -> f64 {
        let w = Self::omega();
        self.centre * (b - a)
            - self.amplitude / w * ((w * b + self.phase).cos() - (w * a + self.phase).cos())
    }
}

/// PID gains.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pid {
    /// On the error.
    pub kp: f64,
    /// On the error's integral.
    pub ki: f64,
    /// On the error's derivative.
    pub kd: f64,
}

/// Gains for the simulated servos (first-order lag τ = 50 ms). Error dynamics
/// `(τ + Kd)·ë + (1 + Kp)·ė + Ki·e = τ·r̈`: all coefficients positive, so stable without delay.
/// The feedback loop `(Kp + Ki/s + Kd·s)/(τs + 1)` crosses 0 dB near √(Kp² − 1)/τ ≈ 57 rad/s
/// with ≈ 100° of phase margin, so a bus-and-scheduling delay of 10–20 ms (33–65° at 57 rad/s)
/// leaves it well damped.
pub const GAINS: Pid = Pid {
    kp: 3.0,
    ki: 20.0,
    kd: 0.005,
};

impl Pid {
    /// The goal to command: reference plus PID correction.
    pub fn command(&self, r: f64, e: f64, integral_e: f64, derivative_e: f64) -> f64 {
        r + self.kp * e + self.ki * integral_e + self.kd * derivative_e
    }
}

/// Predicted steady tracking-error amplitude ratio |E/R| at the gait frequency for the lag
/// plant `P = 1/(τs + 1)` behind a pure delay `d` (bus, scheduling, read-back), commanded with
/// `u = r + C·e`, `C = Kp + Ki/s + Kd·s` (no PID: `C = 0`, the open loop):
/// `E/R = (1 − P e^{−sd}) / (1 + P e^{−sd} C)`. Without delay and with the PID this is
/// `τs² / ((τ + Kd)s² + (1 + Kp)s + Ki)`.
pub fn error_ratio(tau: f64, pid: Option<Pid>, delay_s: f64) -> f64 {
    let w = 2.0 * PI * GAIT_HZ;
    // Complex numbers as (re, im).
    let mul = |a: (f64, f64), b: (f64, f64)| (a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0);
    let div = |a: (f64, f64), b: (f64, f64)| {
        let n = b.0 * b.0 + b.1 * b.1;
        ((a.0 * b.0 + a.1 * b.1) / n, (a.1 * b.0 - a.0 * b.1) / n)
    };
    let plant = div((1.0, 0.0), (1.0, tau * w));
    let delayed = mul(plant, ((w * delay_s).cos(), -(w * delay_s).sin()));
    let c = pid.map_or((0.0, 0.0), |p| (p.kp, p.kd * w - p.ki / w));
    let num = (1.0 - delayed.0, -delayed.1);
    let den = {
        let pc = mul(delayed, c);
        (1.0 + pc.0, pc.1)
    };
    let e = div(num, den);
    (e.0 * e.0 + e.1 * e.1).sqrt()
}

/// RMS of the gait's joints' tracking errors when each joint's error is a sinusoid of
/// `ratio` times its amplitude (the RMS over joints and time of `ratio · A_j · sin`).
pub fn gait_rms(ratio: f64) -> f64 {
    let mean_sq: f64 =
        GAIT.iter().map(|j| j.amplitude * j.amplitude).sum::<f64>() / GAIT.len() as f64;
    ratio * (mean_sq / 2.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_forms_match_numerical_calculus() {
        for j in GAIT {
            // Central difference: error O(h²·|r'''|) ≈ 1e-8·A·ω³, far below 1e-6.
            let h = 1e-4;
            for tau in [0.0, 0.3, 1.7] {
                let d = (j.position(tau + h) - j.position(tau - h)) / (2.0 * h);
                assert!((d - j.velocity(tau)).abs() < 1e-6, "{}", j.joint);
            }
            // Trapezoid with 10 000 steps over 2.5 s: error ≤ (b−a)·h²·max|r''|/12 ≈ 1e-8.
            let (a, b, n) = (0.2, 2.7, 10_000);
            let h = (b - a) / n as f64;
            let mut s = 0.0;
            for i in 0..n {
                let t = a + i as f64 * h;
                s += (j.position(t) + j.position(t + h)) * h / 2.0;
            }
            assert!((s - j.integral(a, b)).abs() < 1e-7, "{}", j.joint);
        }
    }

    #[test]
    fn the_gait_stays_inside_the_joint_limits() {
        let limits = [
            (-0.8, 0.8),
            (-1.2, 1.2),
            (0.0, 2.4),
            (-0.8, 0.8),
            (-1.6, 1.6),
            (-1.0, 1.0),
        ];
        for (j, (lo, hi)) in GAIT.iter().zip(limits) {
            let (min, max) = (j.centre - j.amplitude.abs(), j.centre + j.amplitude.abs());
            assert!(min >= lo && max <= hi, "{}", j.joint);
        }
    }

    #[test]
    fn predicted_errors_match_the_closed_forms() {
        let (tau, w) = (0.05, 2.0 * PI * GAIT_HZ);
        // Open loop, no delay: τω/√(1 + τ²ω²).
        let open = error_ratio(tau, None, 0.0);
        assert!((open - tau * w / (1.0 + (tau * w).powi(2)).sqrt()).abs() < 1e-12);
        // PID, no delay: τω² / |Ki − (τ + Kd)ω² + j(1 + Kp)ω|.
        let g = GAINS;
        let re = g.ki - (tau + g.kd) * w * w;
        let im = (1.0 + g.kp) * w;
        let pid = error_ratio(tau, Some(g), 0.0);
        assert!((pid - tau * w * w / (re * re + im * im).sqrt()).abs() < 1e-12);
        assert!(pid < open / 4.0, "{pid} vs {open}");
        // Delay only makes tracking worse, gradually.
        assert!(error_ratio(tau, None, 0.02) > open);
        assert!(error_ratio(tau, Some(g), 0.02) > pid);
        assert!(error_ratio(tau, Some(g), 0.02) < open / 2.0);
    }
}
