//! The fit of a linear output-error model of any order ([`crate::model::linear`]), and the
//! choice of its orders.
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
//! 2. Levenberg–Marquardt ([`super::levenberg_marquardt`]) on the simulation error with its exact
//!    Jacobian: `∂ŷ/∂b_i = q^(−nk−i) u/F` and `∂ŷ/∂f_j = −q^(−j) ŷ/F`, two filtered signals
//!    and their shifts. Unstable candidates are rejected ([`crate::model::poles::stable`]).
//!
//! ## Choosing the orders ([`select_linear_oe`])
//! Every `nb ≤ max.nb`, `nf ≤ max.nf`, `nk ≤ max.nk` is fitted on the fitting samples and
//! simulated over the held-out ones. **Rule**: among the models whose held-out RMS is within
//! [`ORDER_TOLERANCE`] (2 %) of the best, the one with the fewest parameters `nb + nf`, then
//! the lowest held-out RMS.

use super::lm::{self, Quadratic};
use super::{FitError, Stop, Tolerances};
use crate::model::linear::{LinearModel, OeOrders, filter};
use crate::model::poles;
use std::ops::Range;

/// Held-out RMS within this fraction of the best counts as equally good when choosing
/// orders.
pub const ORDER_TOLERANCE: f64 = 0.02;

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

/// Moves the roots of `F` toward the origin (`f_j ← 0.98^j f_j`, i.e. roots × 0.98) until
/// stable.
fn contract_to_stable(f: &mut [f64]) {
    for _ in 0..400 {
        if poles::stable(&f.iter().map(|x| -x).collect::<Vec<_>>()) {
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
        return Err(FitError::from(boucwen_core::Error::NonFinite("record")));
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
        if !poles::stable(&f.iter().map(|x| -x).collect::<Vec<_>>()) {
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
    let run = lm::levenberg_marquardt(&x0, tol, eval).ok_or(FitError::NoStableModel)?;
    let (b, f) = run.x.split_at(orders.nb);
    let model = LinearModel { b: b.to_vec(), f: f.to_vec(), nk: orders.nk };
    Ok(LinearFit {
        model,
        rms_fit: (run.eval.cost / scored.len() as f64).sqrt(),
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
        let rms_held_out = crate::signal::analysis::rms_diff(&sim[held_out.clone()], &y[held_out.clone()]);
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
        assert!(poles::stable(&[1.8, -0.81]));
        assert!(!poles::stable(&[2.0, -1.01]));
        assert!(!poles::stable(&[1.5]));
    }
}
