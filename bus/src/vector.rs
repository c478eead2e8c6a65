//! nalgebra helpers: many states as one vector, one control vector as one command frame.

use nalgebra::{DVector, SVector};

use crate::controller::Controller;
use crate::error::{BusError, Result};

impl Controller {
    /// The newest values of `names`, in order, as a `DVector` (the state vector x of a
    /// state-space controller).
    pub fn gather(&mut self, names: &[&str]) -> Result<DVector<f64>> {
        self.subscribe_all(names)?;
        let mut x = DVector::zeros(names.len());
        for (i, n) in names.iter().enumerate() {
            x[i] = self.get_surface(n)?;
        }
        Ok(x)
    }

    /// As [`gather`](Self::gather), into a fixed-size `SVector` (no allocation).
    pub fn gather_static<const N: usize>(&mut self, names: &[&str; N]) -> Result<SVector<f64, N>> {
        self.subscribe_all(names)?;
        let mut x = SVector::<f64, N>::zeros();
        for (i, n) in names.iter().enumerate() {
            x[i] = self.get_surface(n)?;
        }
        Ok(x)
    }

    /// Subscribes to every state first, so that one without a sample yet does not keep the
    /// others from receiving theirs.
    fn subscribe_all(&mut self, names: &[&str]) -> Result<()> {
        for n in names {
            self.state(n)?;
        }
        Ok(())
    }

    /// Buffers `u[i]` as the setpoint of `names[i]` and sends everything as one frame per
    /// subsystem. Returns the number of setpoints sent.
    pub fn scatter(&mut self, names: &[&str], u: &[f64]) -> Result<usize> {
        if names.len() != u.len() {
            return Err(BusError::DimensionMismatch {
                names: names.len(),
                values: u.len(),
            });
        }
        for (n, &v) in names.iter().zip(u) {
            self.add_ctrl(n, v)?;
        }
        self.send_ctrl()
    }
}
