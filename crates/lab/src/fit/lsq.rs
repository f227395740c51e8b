//! A generic Levenberg–Marquardt for nonlinear least squares over a plain parameter vector,
//! for the fits whose parameters are not the extended model's [`Outer`](super::Outer): the
//! linear output-error model ([`linear`](super::linear)) and the Bouc–Wen oscillator
//! ([`oscillator`](super::oscillator)).
//!
//! The caller's closure evaluates the cost `Σ r²` with the Gauss–Newton matrix `JᵀJ` and
//! the gradient half `Jᵀr` ([`Quadratic`]), or `None` where the parameters are not admissible
//! (an unstable model, a negative mass): such a step is rejected as one that raises the cost.
//! The iteration, the damping (Nielsen's rule, scaled by the largest diagonal of `JᵀJ` seen,
//! as MINPACK; a parameter whose column has been zero so far is held) and the stopping criteria ([`Stop`], [`Tolerances`]) are those of the project's
//! fit of the extended model (`fit::lm`), written over a vector instead of
//! [`Outer`](super::Outer).

use super::{Stop, Tolerances};
use nalgebra::{DMatrix, DVector};

/// The local quadratic model of the cost at a point.
#[derive(Clone, Debug)]
pub struct Quadratic {
    /// `Σ r²`.
    pub cost: f64,
    /// `JᵀJ` (Gauss–Newton matrix).
    pub jtj: DMatrix<f64>,
    /// `Jᵀr`.
    pub jtr: DVector<f64>,
}

impl Quadratic {
    /// Accumulates `JᵀJ`, `Jᵀr` and `Σ r²` from a residual and its Jacobian's columns
    /// (`cols[i][k] = ∂r[k]/∂x_i`).
    pub fn from_columns(r: &[f64], cols: &[Vec<f64>]) -> Self {
        let n = cols.len();
        let mut jtj = DMatrix::zeros(n, n);
        let mut jtr = DVector::zeros(n);
        for i in 0..n {
            jtr[i] = dot(&cols[i], r);
            for j in 0..=i {
                let v = dot(&cols[i], &cols[j]);
                jtj[(i, j)] = v;
                jtj[(j, i)] = v;
            }
        }
        Self { cost: dot(r, r), jtj, jtr }
    }
}

pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The end of a run.
#[derive(Clone, Debug)]
pub struct LsqRun {
    /// The parameters reached.
    pub x: Vec<f64>,
    /// The cost `Σ r²` there.
    pub cost: f64,
    /// Why the run stopped.
    pub stop: Stop,
    /// Accepted and rejected iterations.
    pub iterations: usize,
    /// Evaluations of the closure.
    pub evaluations: usize,
}

/// Minimises the cost from `x0`; `None` when the start itself is not admissible.
pub fn levenberg_marquardt(
    x0: &[f64],
    tol: &Tolerances,
    mut eval: impl FnMut(&[f64]) -> Option<Quadratic>,
) -> Option<LsqRun> {
    let nf = x0.len();
    let mut x = x0.to_vec();
    let mut cur = eval(&x)?;
    let mut evaluations = 1;
    let mut mu = 1e-3;
    let mut nu = 2.0;
    let mut scale = DVector::<f64>::zeros(nf);
    let finish = |x: Vec<f64>, cur: &Quadratic, stop, iterations, evaluations| {
        Some(LsqRun { x, cost: cur.cost, stop, iterations, evaluations })
    };
    for iter in 0..tol.max_iter {
        if cur.cost <= 0.0 || nf == 0 {
            return finish(x, &cur, Stop::Gradient, iter, evaluations);
        }
        for i in 0..nf {
            scale[i] = scale[i].max(cur.jtj[(i, i)].max(0.0).sqrt());
        }
        let cosine = (0..nf)
            .filter(|&i| cur.jtj[(i, i)] > 0.0)
            .map(|i| cur.jtr[i].abs() / (cur.jtj[(i, i)].sqrt() * cur.cost.sqrt()))
            .fold(0.0, f64::max);
        if cosine <= tol.gradient {
            return finish(x, &cur, Stop::Gradient, iter, evaluations);
        }
        let x_norm = (0..nf).map(|i| (scale[i] * x[i]).powi(2)).sum::<f64>().sqrt();
        loop {
            let mut a = cur.jtj.clone();
            for i in 0..nf {
                // A parameter the cost does not see yet (a zero column) is held: its row is
                // made the identity, and its gradient is zero.
                a[(i, i)] += if scale[i] > 0.0 { mu * scale[i].powi(2) } else { 1.0 };
            }
            let Some(ch) = a.cholesky() else {
                mu *= nu;
                nu *= 2.0;
                if !mu.is_finite() || mu > 1e300 {
                    return finish(x, &cur, Stop::StepSize, iter, evaluations);
                }
                continue;
            };
            let delta = ch.solve(&(-&cur.jtr));
            let step_norm = (0..nf).map(|i| (scale[i] * delta[i]).powi(2)).sum::<f64>().sqrt();
            if step_norm <= tol.step * (x_norm + tol.step) {
                return finish(x, &cur, Stop::StepSize, iter, evaluations);
            }
            let cand: Vec<f64> = x.iter().zip(delta.iter()).map(|(a, d)| a + d).collect();
            // Predicted decrease of Σr² under the linearisation: −(2gᵀδ + δᵀJᵀJδ).
            let pred = -(2.0 * cur.jtr.dot(&delta) + (&cur.jtj * &delta).dot(&delta));
            evaluations += 1;
            match eval(&cand) {
                Some(next) if next.cost < cur.cost => {
                    let actual = cur.cost - next.cost;
                    let rho = actual / pred.max(1e-300);
                    mu *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
                    nu = 2.0;
                    let (rel_actual, rel_pred) = (actual / cur.cost, pred / cur.cost);
                    x = cand;
                    cur = next;
                    if rel_actual <= tol.cost && rel_pred <= tol.cost && rho <= 2.0 {
                        return finish(x, &cur, Stop::CostDecrease, iter + 1, evaluations);
                    }
                    break;
                }
                _ => {
                    mu *= nu;
                    nu *= 2.0;
                    if !mu.is_finite() || mu > 1e300 {
                        return finish(x, &cur, Stop::StepSize, iter, evaluations);
                    }
                }
            }
        }
    }
    finish(x, &cur, Stop::IterationLimit, tol.max_iter, evaluations)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_an_exponential() {
        // r_k = a·e^{b t_k} − y_k with a = 2, b = −0.7.
        let t: Vec<f64> = (0..50).map(|k| k as f64 * 0.1).collect();
        let y: Vec<f64> = t.iter().map(|t| 2.0 * (-0.7 * t).exp()).collect();
        let run = levenberg_marquardt(&[1.0, 0.0], &Tolerances::default(), |x| {
            let r: Vec<f64> = t.iter().zip(&y).map(|(t, y)| x[0] * (x[1] * t).exp() - y).collect();
            let c0: Vec<f64> = t.iter().map(|t| (x[1] * t).exp()).collect();
            let c1: Vec<f64> = t.iter().map(|t| x[0] * t * (x[1] * t).exp()).collect();
            Some(Quadratic::from_columns(&r, &[c0, c1]))
        })
        .expect("run");
        assert!((run.x[0] - 2.0).abs() < 1e-8 && (run.x[1] + 0.7).abs() < 1e-8, "{:?}", run.x);
    }
}
