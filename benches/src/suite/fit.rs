//! Ordinary least squares of a straight line, `y = intercept + slope · x`: the per-unit costs of
//! the scaling curves (µs per state per tick, per subscriber, per executor).

use serde::Serialize;

/// A fitted line and how well it fits.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LineFit {
    /// `y` at `x = 0`.
    pub intercept: f64,
    /// Change of `y` per unit of `x`: the per-unit cost.
    pub slope: f64,
    /// Coefficient of determination (1 = every point on the line; `None` when every `y` is the
    /// same, where it is undefined).
    pub r2: Option<f64>,
    /// Points fitted.
    pub points: usize,
}

impl LineFit {
    /// `y` on the line at `x`.
    pub fn at(&self, x: f64) -> f64 {
        self.intercept + self.slope * x
    }
}

/// Least-squares line through `points` `(x, y)`; points with a non-finite coordinate are left
/// out. `None` with fewer than two distinct `x`, where no slope is defined.
pub fn fit_line(points: &[(f64, f64)]) -> Option<LineFit> {
    let pts: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    let n = pts.len() as f64;
    if pts.len() < 2 {
        return None;
    }
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    if sxx <= f64::EPSILON * mx.abs().max(1.0) {
        return None;
    }
    let slope = sxy / sxx;
    let intercept = my - slope * mx;
    let ss_tot: f64 = pts.iter().map(|p| (p.1 - my).powi(2)).sum();
    let ss_res: f64 = pts
        .iter()
        .map(|p| (p.1 - intercept - slope * p.0).powi(2))
        .sum();
    Some(LineFit {
        intercept,
        slope,
        r2: (ss_tot > 0.0).then(|| 1.0 - ss_res / ss_tot),
        points: pts.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-9 * b.abs().max(1.0)
    }

    #[test]
    fn points_on_a_line_give_that_line() {
        // y = 3 + 0.7 x at the scaling curve's state counts.
        let pts: Vec<(f64, f64)> = [1.0, 10.0, 41.0, 200.0, 1000.0]
            .iter()
            .map(|&x| (x, 3.0 + 0.7 * x))
            .collect();
        let f = fit_line(&pts).unwrap();
        assert!(close(f.intercept, 3.0) && close(f.slope, 0.7), "{f:?}");
        assert!(close(f.r2.unwrap(), 1.0));
        assert_eq!(f.points, 5);
        assert!(close(f.at(100.0), 73.0));
    }

    #[test]
    fn symmetric_noise_leaves_the_line_and_lowers_r2() {
        // y = 1 + 2x with residuals +1, −1, −1, +1: the residuals are orthogonal to 1 and to x
        // (they sum to 0 and Σ x·r = 0 − 1 − 2 + 3 = 0), so the fit is exactly 1 + 2x.
        let pts = [(0.0, 2.0), (1.0, 2.0), (2.0, 4.0), (3.0, 8.0)];
        let f = fit_line(&pts).unwrap();
        assert!(close(f.intercept, 1.0) && close(f.slope, 2.0), "{f:?}");
        // SS_res = 4, SS_tot = Σ (y − 4)² = 4 + 4 + 0 + 16 = 24.
        assert!(close(f.r2.unwrap(), 1.0 - 4.0 / 24.0), "{f:?}");
    }

    #[test]
    fn a_known_regression_by_hand() {
        // x = 1, 2, 3; y = 2, 3, 7: mean x 2, mean y 4; Sxy = (−1)(−2) + 0 + 1·3 = 5, Sxx = 2:
        // slope 2.5, intercept 4 − 5 = −1.
        let f = fit_line(&[(1.0, 2.0), (2.0, 3.0), (3.0, 7.0)]).unwrap();
        assert!(close(f.slope, 2.5) && close(f.intercept, -1.0), "{f:?}");
    }

    #[test]
    fn no_slope_without_two_distinct_x() {
        assert_eq!(fit_line(&[]), None);
        assert_eq!(fit_line(&[(1.0, 2.0)]), None);
        assert_eq!(fit_line(&[(4.0, 2.0), (4.0, 3.0)]), None);
        // Non-finite points are left out, not fitted.
        assert_eq!(fit_line(&[(1.0, 2.0), (2.0, f64::NAN)]), None);
        let f = fit_line(&[(1.0, 1.0), (2.0, f64::INFINITY), (3.0, 3.0)]).unwrap();
        assert_eq!(f.points, 2);
        assert!(close(f.slope, 1.0));
        // A flat line: slope 0, R² undefined.
        let f = fit_line(&[(1.0, 5.0), (2.0, 5.0)]).unwrap();
        assert_eq!((f.slope, f.r2), (0.0, None));
    }
}
