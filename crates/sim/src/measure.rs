//! Measuring a record: least-squares fit of a constant and the first harmonics of a known
//! drive frequency.
//!
//! For samples `y[k]`, `k = first..first+len`, and a drive `u[k] = U·sin(2π f k Ts)` (time
//! index from the start of the drive), the fit minimises
//! ```text
//! Σ_k ( y[k] − c − Σ_{n=1..N} (a_n·sin(n θ_k) + b_n·cos(n θ_k)) )²,   θ_k = 2π f k Ts
//! ```
//! and reports each harmonic as `A_n·sin(n θ + φ_n)`, `A_n = √(a_n² + b_n²)`,
//! `φ_n = atan2(b_n, a_n)`: `φ_1` is the phase of the fundamental relative to the drive
//! (negative = lag). A least-squares fit, unlike a DFT bin, needs no whole number of
//! periods in the record.

use crate::SimError;

/// One harmonic `A·sin(n θ + φ)` of a fitted record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Harmonic {
    /// Order `n` (1 = the fundamental).
    pub order: usize,
    /// Amplitude `A` (units of the record).
    pub amplitude: f64,
    /// Phase `φ` relative to `sin(n θ)`, rad, in `(−π, π]`.
    pub phase_rad: f64,
}

/// A fitted constant and harmonics `1..=N`.
#[derive(Clone, Debug, PartialEq)]
pub struct HarmonicFit {
    /// The constant `c`.
    pub offset: f64,
    /// Harmonics `1..=N`, in order.
    pub harmonics: Vec<Harmonic>,
    /// RMS of the residual (what the constant and harmonics do not explain).
    pub residual_rms: f64,
}

impl HarmonicFit {
    /// Amplitude of harmonic `n` relative to the fundamental (`None` if `n` was not fitted
    /// or the fundamental is zero).
    pub fn relative(&self, n: usize) -> Option<f64> {
        let a1 = self.harmonics.first()?.amplitude;
        let an = self.harmonics.get(n.checked_sub(1)?)?.amplitude;
        if a1 > 0.0 { Some(an / a1) } else { None }
    }
}

/// Fits `y` (whose first element is sample `first` of the drive) with a constant and
/// harmonics `1..=orders` of `freq_hz`. Every harmonic must lie below the Nyquist
/// frequency and the record must have at least `4·(2·orders + 1)` samples.
pub fn harmonic_fit(
    y: &[f64],
    first: usize,
    freq_hz: f64,
    ts_s: f64,
    orders: usize,
) -> Result<HarmonicFit, SimError> {
    if orders == 0 {
        return Err(SimError::Analysis("at least one harmonic must be fitted"));
    }
    if !(freq_hz.is_finite() && freq_hz > 0.0 && ts_s.is_finite() && ts_s > 0.0) {
        return Err(SimError::Analysis("frequency and sample interval must be finite and > 0"));
    }
    if freq_hz * orders as f64 * ts_s >= 0.5 {
        return Err(SimError::Analysis("the highest harmonic must lie below the Nyquist frequency"));
    }
    let m = 2 * orders + 1;
    if y.len() < 4 * m {
        return Err(SimError::Analysis("record too short for the number of harmonics"));
    }
    if y.iter().any(|v| !v.is_finite()) {
        return Err(SimError::Analysis("record contains non-finite samples"));
    }
    // Normal equations G·x = r over the basis [1, sin θ, cos θ, sin 2θ, cos 2θ, …].
    let mut g = vec![0.0; m * m];
    let mut r = vec![0.0; m];
    let mut basis = vec![0.0; m];
    let w = core::f64::consts::TAU * freq_hz * ts_s;
    for (i, &yk) in y.iter().enumerate() {
        fill_basis(&mut basis, w * (first + i) as f64);
        for a in 0..m {
            r[a] += basis[a] * yk;
            for b in a..m {
                g[a * m + b] += basis[a] * basis[b];
            }
        }
    }
    for a in 0..m {
        for b in 0..a {
            g[a * m + b] = g[b * m + a];
        }
    }
    let x = solve(&mut g, &mut r, m).ok_or(SimError::Analysis("singular normal equations"))?;
    let mut ss = 0.0;
    for (i, &yk) in y.iter().enumerate() {
        fill_basis(&mut basis, w * (first + i) as f64);
        let model: f64 = basis.iter().zip(&x).map(|(b, c)| b * c).sum();
        ss += (yk - model) * (yk - model);
    }
    let harmonics = (1..=orders)
        .map(|n| {
            let (a, b) = (x[2 * n - 1], x[2 * n]);
            Harmonic { order: n, amplitude: a.hypot(b), phase_rad: b.atan2(a) }
        })
        .collect();
    Ok(HarmonicFit { offset: x[0], harmonics, residual_rms: (ss / y.len() as f64).sqrt() })
}

fn fill_basis(basis: &mut [f64], theta: f64) {
    basis[0] = 1.0;
    let orders = (basis.len() - 1) / 2;
    for n in 1..=orders {
        let (s, c) = (theta * n as f64).sin_cos();
        basis[2 * n - 1] = s;
        basis[2 * n] = c;
    }
}

/// Gaussian elimination with partial pivoting; `None` if singular.
fn solve(g: &mut [f64], r: &mut [f64], m: usize) -> Option<Vec<f64>> {
    let scale = (0..m).map(|i| g[i * m + i].abs()).fold(0.0, f64::max);
    for col in 0..m {
        let piv = (col..m).max_by(|&a, &b| g[a * m + col].abs().total_cmp(&g[b * m + col].abs()))?;
        if g[piv * m + col].abs() <= 1e-12 * scale {
            return None;
        }
        if piv != col {
            for k in 0..m {
                g.swap(piv * m + k, col * m + k);
            }
            r.swap(piv, col);
        }
        for row in col + 1..m {
            let f = g[row * m + col] / g[col * m + col];
            for k in col..m {
                g[row * m + k] -= f * g[col * m + k];
            }
            r[row] -= f * r[col];
        }
    }
    let mut x = vec![0.0; m];
    for row in (0..m).rev() {
        let mut acc = r[row];
        for k in row + 1..m {
            acc -= g[row * m + k] * x[k];
        }
        x[row] = acc / g[row * m + row];
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_synthetic_signal_over_a_fractional_number_of_periods() {
        let (f, ts) = (23.0, 1e-3);
        let first = 1234;
        let y: Vec<f64> = (first..first + 1777)
            .map(|k| {
                let th = core::f64::consts::TAU * f * k as f64 * ts;
                0.5 + 20.0 * (th - 0.3).sin() + 5.0 * (3.0 * th + 2.0).sin()
            })
            .collect();
        let fit = harmonic_fit(&y, first, f, ts, 5).unwrap();
        assert!((fit.offset - 0.5).abs() < 1e-9);
        assert!((fit.harmonics[0].amplitude - 20.0).abs() < 1e-9);
        assert!((fit.harmonics[0].phase_rad + 0.3).abs() < 1e-9);
        assert!((fit.harmonics[2].amplitude - 5.0).abs() < 1e-9);
        assert!((fit.harmonics[2].phase_rad - 2.0).abs() < 1e-9);
        assert!(fit.harmonics[1].amplitude < 1e-9 && fit.harmonics[4].amplitude < 1e-9);
        assert!((fit.relative(3).unwrap() - 0.25).abs() < 1e-9);
        assert!(fit.residual_rms < 1e-9);
    }

    #[test]
    fn rejects_harmonics_above_nyquist_and_short_records() {
        let y = vec![0.0; 1000];
        assert!(harmonic_fit(&y, 0, 100.0, 1e-3, 5).is_err());
        assert!(harmonic_fit(&y[..10], 0, 10.0, 1e-3, 3).is_err());
    }
}
