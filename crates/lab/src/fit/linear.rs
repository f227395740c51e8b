//! Linear output-error models of any order, their fit and the choice of orders.
//!
//! ## The model ([`LinearModel`])
//! MATLAB's `oe` form with orders `nb`, `nf` and input delay `nk` ([`OeOrders`]):
//! ```text
//! y[k] = B(q)/F(q) · u[k],   B(q) = b₀ q^(−nk) + … + b_(nb−1) q^(−nk−nb+1),
//!                            F(q) = 1 + f₁ q⁻¹ + … + f_nf q^(−nf)
//! ```
//! simulated from rest (`u` and `y` zero before the record). Only the input is filtered: the
//! noise is not modelled, so the fit minimises the free-run (simulation) error.
//!
//! ## The fit ([`fit_linear_oe`])
//! 1. ARX least squares on the scored samples, then five Steiglitz–McBride passes (the ARX
//!    problem on `u` and `y` filtered by the last `1/F`), which converge toward the
//!    output-error solution for white noise; an unstable `F` is contracted
//!    (`f_j ← ρ^j f_j`) until stable.
//! 2. Levenberg–Marquardt ([`lsq`]) on the simulation error with its exact
//!    Jacobian: `∂ŷ/∂b_i = q^(−nk−i) u/F` and `∂ŷ/∂f_j = −q^(−j) ŷ/F`, two filtered signals
//!    and their shifts. Unstable candidates are rejected (Schur–Cohn step-down test).
//!
//! ## Choosing the orders ([`select_linear_oe`])
//! Every `nb ≤ max.nb`, `nf ≤ max.nf`, `nk ≤ max.nk` is fitted on the fitting samples and
//! simulated over the held-out ones. **Rule**: among the models whose held-out RMS is within
//! [`ORDER_TOLERANCE`] (2 %) of the best, the one with the fewest parameters `nb + nf`, then
//! the lowest held-out RMS.

use super::lsq::{self, Quadratic};
use super::{FitError, Stop, Tolerances};
use serde::{Deserialize, Serialize};
use std::ops::Range;

/// Held-out RMS within this fraction of the best counts as equally good when choosing
/// orders.
pub const ORDER_TOLERANCE: f64 = 0.02;

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

/// A fitted linear model.
#[derive(Clone, Debug)]
pub struct LinearFit {
    /// The model.
    pub model: LinearModel,
    /// RMS of the simulation error over the scored samples.
    pub rms_fit: f64,
    /// Why Levenberg–Marquardt stopped.
    pub stop: Stop,
    /// Its iterations.
    pub iterations: usize,
}

/// One candidate of the order selection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrderScore {
    /// The orders.
    pub orders: OeOrders,
    /// RMS over the fitting samples.
    pub rms_fit: f64,
    /// RMS over the held-out samples.
    pub rms_held_out: f64,
}

/// The order selection's result.
#[derive(Clone, Debug)]
pub struct OrderSelection {
    /// The chosen model (fitted on the fitting samples).
    pub model: LinearModel,
    /// Every candidate's scores.
    pub scores: Vec<OrderScore>,
    /// Index of the chosen one in `scores`.
    pub chosen: usize,
}

impl LinearModel {
    /// The model's orders.
    pub fn orders(&self) -> OeOrders {
        OeOrders { nb: self.b.len(), nf: self.f.len(), nk: self.nk }
    }

    /// Whether every root of `F` is inside the unit circle.
    pub fn is_stable(&self) -> bool {
        schur_cohn_stable(&self.f)
    }

    /// The output from rest for the input `u`.
    pub fn simulate(&self, u: &[f64]) -> Result<Vec<f64>, FitError> {
        if u.iter().any(|v| !v.is_finite()) {
            return Err(FitError::Core(boucwen_core::Error::NonFinite("u")));
        }
        let y = filter(&self.b, &self.f, self.nk, u);
        if y.iter().any(|v| !v.is_finite()) {
            return Err(FitError::NoStableModel);
        }
        Ok(y)
    }

    /// The steady-state output over one period `u_period` of a periodic input: the period is
    /// simulated `warmup_periods + 1` times from rest and the last is returned.
    pub fn simulate_periodic(&self, u_period: &[f64], warmup_periods: usize) -> Result<Vec<f64>, FitError> {
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
fn filter(b: &[f64], f: &[f64], nk: usize, u: &[f64]) -> Vec<f64> {
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

/// Schur–Cohn (step-down) test of `1 + f₁z⁻¹ + … + f_n z⁻ⁿ`: stable iff every reflection
/// coefficient is below 1 in magnitude.
fn schur_cohn_stable(f: &[f64]) -> bool {
    let mut a: Vec<f64> = std::iter::once(1.0).chain(f.iter().copied()).collect();
    while a.len() > 1 {
        let n = a.len() - 1;
        let k = a[n];
        if !k.is_finite() || k.abs() >= 1.0 {
            return false;
        }
        let d = 1.0 - k * k;
        a = (0..n).map(|j| (a[j] - k * a[n - j]) / d).collect();
    }
    true
}

/// Moves the roots of `F` toward the origin (`f_j ← 0.98^j f_j`, i.e. roots × 0.98) until
/// stable.
fn contract_to_stable(f: &mut [f64]) {
    for _ in 0..400 {
        if schur_cohn_stable(f) {
            return;
        }
        for (j, fj) in f.iter_mut().enumerate() {
            *fj *= 0.98f64.powi(j as i32 + 1);
        }
    }
}

/// ARX least squares `y[k] + Σ f_j y[k−j] = Σ b_i u[k−nk−i]` over `k ∈ rows`.
fn arx(u: &[f64], y: &[f64], o: OeOrders, rows: Range<usize>) -> Option<(Vec<f64>, Vec<f64>)> {
    let np = o.nb + o.nf;
    let mut a = nalgebra::DMatrix::<f64>::zeros(np, np);
    let mut g = nalgebra::DVector::<f64>::zeros(np);
    let mut phi = vec![0.0; np];
    for k in rows {
        for (i, p) in phi.iter_mut().take(o.nb).enumerate() {
            *p = if k >= o.nk + i { u[k - o.nk - i] } else { 0.0 };
        }
        for j in 0..o.nf {
            phi[o.nb + j] = if k > j { -y[k - 1 - j] } else { 0.0 };
        }
        for i in 0..np {
            g[i] += phi[i] * y[k];
            for j in 0..=i {
                a[(i, j)] += phi[i] * phi[j];
            }
        }
    }
    for i in 0..np {
        for j in 0..i {
            a[(j, i)] = a[(i, j)];
        }
        a[(i, i)] += 1e-12 * a[(i, i)].abs() + 1e-300;
    }
    let x = a.cholesky()?.solve(&g);
    Some((x.iter().take(o.nb).copied().collect(), x.iter().skip(o.nb).copied().collect()))
}

/// Fits `B/F` of orders `orders` by output error on the samples `scored` (the simulation runs
/// from sample 0 at rest). See the module docs.
pub fn fit_linear_oe(
    u: &[f64],
    y: &[f64],
    orders: OeOrders,
    scored: Range<usize>,
    tol: &Tolerances,
) -> Result<LinearFit, FitError> {
    let np = orders.nb + orders.nf;
    if orders.nb == 0 || scored.end > u.len().min(y.len()) || scored.start >= scored.end {
        return Err(FitError::TooFewSamples { have: u.len().min(y.len()), need: scored.end.max(1) });
    }
    if scored.len() < 4 * np + 10 {
        return Err(FitError::TooFewSamples { have: scored.len(), need: 4 * np + 10 });
    }
    if u[..scored.end].iter().chain(&y[..scored.end]).any(|v| !v.is_finite()) {
        return Err(FitError::Core(boucwen_core::Error::NonFinite("record")));
    }
    let end = scored.end;
    let (u, y) = (&u[..end], &y[..end]);
    // 1. ARX, then Steiglitz–McBride.
    let (mut b, mut f) = arx(u, y, orders, scored.clone()).ok_or(FitError::NoStableModel)?;
    contract_to_stable(&mut f);
    for _ in 0..5 {
        let uf = filter(&[1.0], &f, 0, u);
        let yf = filter(&[1.0], &f, 0, y);
        let Some((b2, mut f2)) = arx(&uf, &yf, orders, scored.clone()) else { break };
        contract_to_stable(&mut f2);
        (b, f) = (b2, f2);
    }
    // 2. Levenberg–Marquardt on the simulation error.
    let x0: Vec<f64> = b.iter().chain(&f).copied().collect();
    let eval = |x: &[f64]| -> Option<Quadratic> {
        let (b, f) = x.split_at(orders.nb);
        if !schur_cohn_stable(f) {
            return None;
        }
        let yhat = filter(b, f, orders.nk, u);
        let xu = filter(&[1.0], f, 0, u);
        let xw = filter(&[1.0], f, 0, &yhat);
        let r: Vec<f64> = scored.clone().map(|k| yhat[k] - y[k]).collect();
        let shifted = |s: &[f64], d: usize, sign: f64| -> Vec<f64> {
            scored.clone().map(|k| if k >= d { sign * s[k - d] } else { 0.0 }).collect()
        };
        let mut cols = Vec::with_capacity(np);
        for i in 0..orders.nb {
            cols.push(shifted(&xu, orders.nk + i, 1.0));
        }
        for j in 0..orders.nf {
            cols.push(shifted(&xw, j + 1, -1.0));
        }
        let q = Quadratic::from_columns(&r, &cols);
        q.cost.is_finite().then_some(q)
    };
    let run = lsq::levenberg_marquardt(&x0, tol, eval).ok_or(FitError::NoStableModel)?;
    let (b, f) = run.x.split_at(orders.nb);
    let model = LinearModel { b: b.to_vec(), f: f.to_vec(), nk: orders.nk };
    Ok(LinearFit {
        model,
        rms_fit: (run.cost / scored.len() as f64).sqrt(),
        stop: run.stop,
        iterations: run.iterations,
    })
}

/// Fits every order up to `max` (`nb ≥ 1`, `nf ≥ 1`, `nk ≥ 0`) on `fit`, scores each on
/// `held_out` (simulated from rest over the record up to its end) and chooses by the rule of
/// the module docs. Candidates run in parallel.
pub fn select_linear_oe(
    u: &[f64],
    y: &[f64],
    fit: Range<usize>,
    held_out: Range<usize>,
    max: OeOrders,
    tol: &Tolerances,
) -> Result<OrderSelection, FitError> {
    use rayon::prelude::*;
    if held_out.end > u.len().min(y.len()) || held_out.is_empty() {
        return Err(FitError::TooFewSamples { have: u.len().min(y.len()), need: held_out.end.max(1) });
    }
    let mut grid = Vec::new();
    for nf in 1..=max.nf {
        for nb in 1..=max.nb {
            for nk in 0..=max.nk {
                grid.push(OeOrders { nb, nf, nk });
            }
        }
    }
    let fits: Vec<(OeOrders, Result<LinearFit, FitError>)> =
        grid.into_par_iter().map(|o| (o, fit_linear_oe(u, y, o, fit.clone(), tol))).collect();
    let mut scores = Vec::new();
    let mut models = Vec::new();
    for (orders, r) in fits {
        let Ok(lf) = r else { continue };
        let Ok(sim) = lf.model.simulate(&u[..held_out.end]) else { continue };
        let rms_held_out = rms_diff(&sim[held_out.clone()], &y[held_out.clone()]);
        if rms_held_out.is_finite() {
            scores.push(OrderScore { orders, rms_fit: lf.rms_fit, rms_held_out });
            models.push(lf.model);
        }
    }
    let best = scores.iter().map(|s| s.rms_held_out).fold(f64::INFINITY, f64::min);
    let chosen = (0..scores.len())
        .filter(|&i| scores[i].rms_held_out <= best * (1.0 + ORDER_TOLERANCE))
        .min_by(|&i, &j| {
            let (a, b) = (&scores[i], &scores[j]);
            (a.orders.nb + a.orders.nf)
                .cmp(&(b.orders.nb + b.orders.nf))
                .then(a.rms_held_out.total_cmp(&b.rms_held_out))
        })
        .ok_or(FitError::NoStableModel)?;
    Ok(OrderSelection { model: models[chosen].clone(), scores, chosen })
}

/// RMS of `a − b`.
pub fn rms_diff(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    if n == 0 {
        return f64::NAN;
    }
    (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / n as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_third_order_system() {
        let truth = LinearModel { b: vec![0.0, 0.5, 0.2], f: vec![-1.2, 0.5, -0.1], nk: 1 };
        assert!(truth.is_stable());
        let mut s = 1u64;
        let u: Vec<f64> = (0..3000)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            })
            .collect();
        let y = truth.simulate(&u).expect("sim");
        let fit = fit_linear_oe(&u, &y, OeOrders { nb: 3, nf: 3, nk: 1 }, 0..3000, &Tolerances::default())
            .expect("fit");
        assert!(fit.rms_fit < 1e-9, "{}", fit.rms_fit);
        for (a, b) in fit.model.f.iter().zip(&truth.f) {
            assert!((a - b).abs() < 1e-8);
        }
    }

    #[test]
    fn stability_test() {
        assert!(schur_cohn_stable(&[-1.8, 0.81]));
        assert!(!schur_cohn_stable(&[-2.0, 1.01]));
        assert!(!schur_cohn_stable(&[-1.5]));
    }
}
