//! Linear output-error models of any order: MATLAB's `oe` form with orders `nb`, `nf` and
//! input delay `nk` ([`OeOrders`]):
//! ```text
//! y[k] = B(q)/F(q) · u[k],   B(q) = b₀ q^(−nk) + … + b_(nb−1) q^(−nk−nb+1),
//!                            F(q) = 1 + f₁ q⁻¹ + … + f_nf q^(−nf)
//! ```
//! simulated from rest (`u` and `y` zero before the record). Its fit is
//! [`crate::fit::linear`].

use super::ModelError;
use super::poles;
use serde::{Deserialize, Serialize};

/// Orders of an output-error model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct OeOrders {
    /// Coefficients of `B` (at least 1).
    pub nb: usize,
    /// Coefficients of `F` after its leading 1.
    pub nf: usize,
    /// Input delay (samples).
    pub nk: usize,
}

/// A linear output-error model `B(q)/F(q)` (module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinearModel {
    /// `b₀ … b_(nb−1)`.
    pub b: Vec<f64>,
    /// `f₁ … f_nf`.
    pub f: Vec<f64>,
    /// Input delay (samples).
    pub nk: usize,
}

impl LinearModel {
    /// The model's orders.
    pub fn orders(&self) -> OeOrders {
        OeOrders { nb: self.b.len(), nf: self.f.len(), nk: self.nk }
    }

    /// Whether every root of `F` is inside the unit circle.
    pub fn is_stable(&self) -> bool {
        poles::stable(&self.ar())
    }

    /// `F` in the AR convention of [`poles`]: `1 − a₁ q⁻¹ − …`, `a_j = −f_j`.
    pub fn ar(&self) -> Vec<f64> {
        self.f.iter().map(|f| -f).collect()
    }

    /// The output from rest for the input `u`.
    pub fn simulate(&self, u: &[f64]) -> Result<Vec<f64>, ModelError> {
        if u.iter().any(|v| !v.is_finite()) {
            return Err(ModelError::Core(boucwen_core::Error::NonFinite("u")));
        }
        let y = filter(&self.b, &self.f, self.nk, u);
        if y.iter().any(|v| !v.is_finite()) {
            return Err(ModelError::Diverges);
        }
        Ok(y)
    }

    /// The steady-state output over one period `u_period` of a periodic input: the period is
    /// simulated `warmup_periods + 1` times from rest and the last is returned.
    pub fn simulate_periodic(&self, u_period: &[f64], warmup_periods: usize) -> Result<Vec<f64>, ModelError> {
        let n = u_period.len();
        let y = self.simulate(&u_period.repeat(warmup_periods + 1))?;
        Ok(y[warmup_periods * n..].to_vec())
    }

    /// For `nf = 2` with complex poles: the continuous-time mode `(ω₀ (rad/s), ζ, static
    /// gain B(1)/F(1))` of the poles `z = e^(s·ts)`.
    pub fn mode(&self, ts: f64) -> Option<(f64, f64, f64)> {
        let [f1, f2] = self.f[..] else { return None };
        if f1 * f1 >= 4.0 * f2 || f2 <= 0.0 {
            return None;
        }
        let r = f2.sqrt();
        let theta = (-f1 / (2.0 * r)).clamp(-1.0, 1.0).acos();
        let sigma = r.ln() / ts;
        let wd = theta / ts;
        let w0 = (sigma * sigma + wd * wd).sqrt();
        let gain = self.b.iter().sum::<f64>() / (1.0 + f1 + f2);
        Some((w0, -sigma / w0, gain))
    }
}

/// `y = q^(−nk) B/F · u` from rest.
pub(crate) fn filter(b: &[f64], f: &[f64], nk: usize, u: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; u.len()];
    for k in 0..u.len() {
        let mut s = 0.0;
        for (i, bi) in b.iter().enumerate() {
            if k >= nk + i {
                s += bi * u[k - nk - i];
            }
        }
        for (j, fj) in f.iter().enumerate() {
            if k > j {
                s -= fj * y[k - 1 - j];
            }
        }
        y[k] = s;
    }
    y
}
