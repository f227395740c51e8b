//! The one Levenberg–Marquardt of the project, over a parameter vector, stopped by
//! criteria: every fit uses it (the extended model's outer parameters, the joint refinement
//! of terms, the linear output-error model, the Bouc–Wen oscillator).
//!
//! The caller's closure evaluates the cost `Σ r²` at a point with the Gauss–Newton matrix
//! `JᵀJ` and the gradient half `Jᵀr` ([`Quadratic`], or any [`Evaluation`] that carries
//! them), or `None` where the parameters are not admissible (an unstable model): such a step
//! is rejected as one that raises the cost. A parameter the cost does not see yet (a zero
//! column of `J`) is held.
//!
//! The damping follows Nielsen's rule (scaled by the Gauss–Newton matrix's diagonal, as
//! Marquardt's and MINPACK's), and the run stops, as MINPACK's `lmder` does, when
//! - an accepted step lowers the cost by less than [`Tolerances::cost`] of it, actual and
//!   predicted ([`Stop::CostDecrease`]);
//! - the scaled step falls below [`Tolerances::step`] of the scaled parameters, or no step
//!   lowers the cost however much it is damped ([`Stop::StepSize`]);
//! - the residual is orthogonal to every column of the Jacobian to within
//!   [`Tolerances::gradient`] (cosine; [`Stop::Gradient`]);
//! - or, as a safety net, after [`Tolerances::max_iter`] iterations ([`Stop::IterationLimit`]).

use super::options::Tolerances;
use nalgebra::{DMatrix, DVector};
use std::fmt;

/// Why a fit stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stop {
    /// An accepted step lowered the cost by less than the tolerance.
    CostDecrease,
    /// The step became negligible, or no damped step lowered the cost.
    StepSize,
    /// The gradient vanished (relative to the residual and the Jacobian).
    Gradient,
    /// The iteration limit was reached before any criterion held.
    IterationLimit,
    /// Nothing nonlinear to fit: one linear least-squares solve.
    LinearSolve,
}

impl Stop {
    /// The JSON name.
    pub fn as_str(&self) -> &'static str {
        match self {
            Stop::CostDecrease => "cost_decrease",
            Stop::StepSize => "step_size",
            Stop::Gradient => "gradient",
            Stop::IterationLimit => "iteration_limit",
            Stop::LinearSolve => "linear_solve",
        }
    }
}

impl fmt::Display for Stop {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Stop::CostDecrease => "the cost stopped decreasing",
            Stop::StepSize => "the step became negligible",
            Stop::Gradient => "the gradient vanished",
            Stop::IterationLimit => "iteration limit reached",
            Stop::LinearSolve => "linear solve",
        })
    }
}

/// What the closure returns at a point: its cost and the normal equations there.
pub trait Evaluation {
    /// `Σ r²`.
    fn cost(&self) -> f64;
    /// `(JᵀJ, Jᵀr)`; `None` for an evaluation without its Jacobian, which cannot be stepped
    /// from (the run then ends).
    fn normal(&self) -> Option<(&DMatrix<f64>, &DVector<f64>)>;
}

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

impl Evaluation for Quadratic {
    fn cost(&self) -> f64 {
        self.cost
    }
    fn normal(&self) -> Option<(&DMatrix<f64>, &DVector<f64>)> {
        Some((&self.jtj, &self.jtr))
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The end of a run.
#[derive(Clone, Debug)]
pub struct Run<E> {
    /// The parameters reached.
    pub x: Vec<f64>,
    /// The evaluation there.
    pub eval: E,
    /// Why the run stopped.
    pub stop: Stop,
    /// Accepted iterations.
    pub iterations: usize,
    /// Evaluations of the closure.
    pub evaluations: usize,
}

/// Minimises the cost from `x0`; `None` when the start itself is not admissible.
///
/// The damping follows Nielsen's rule, scaled by the largest diagonal of `JᵀJ` seen so far
/// (as MINPACK's `lmder`).
pub fn levenberg_marquardt<E: Evaluation>(
    x0: &[f64],
    tol: &Tolerances,
    eval: impl FnMut(&[f64]) -> Option<E>,
) -> Option<Run<E>> {
    levenberg_marquardt_within(x0, tol, |_| {}, eval)
}

/// [`levenberg_marquardt`] with every step projected onto the parameters' bounds by
/// `project` before it is evaluated (a delay kept in its range, a gain kept positive).
pub fn levenberg_marquardt_within<E: Evaluation>(
    x0: &[f64],
    tol: &Tolerances,
    project: impl Fn(&mut [f64]),
    mut eval: impl FnMut(&[f64]) -> Option<E>,
) -> Option<Run<E>> {
    let nf = x0.len();
    let mut x = x0.to_vec();
    let mut cur = eval(&x)?;
    let mut evaluations = 1;
    let mut mu = 1e-3;
    let mut nu = 2.0;
    let mut scale = DVector::<f64>::zeros(nf);
    for iter in 0..tol.max_iter {
        let (jtj, g) = cur.normal().map(|(a, b)| (a.clone(), b.clone()))?;
        if cur.cost() <= 0.0 || nf == 0 {
            return Some(Run { x, eval: cur, stop: Stop::Gradient, iterations: iter, evaluations });
        }
        for i in 0..nf {
            scale[i] = scale[i].max(jtj[(i, i)].max(0.0).sqrt());
        }
        let cosine = (0..nf)
            .filter(|&i| jtj[(i, i)] > 0.0)
            .map(|i| g[i].abs() / (jtj[(i, i)].sqrt() * cur.cost().sqrt()))
            .fold(0.0, f64::max);
        if cosine <= tol.gradient {
            return Some(Run { x, eval: cur, stop: Stop::Gradient, iterations: iter, evaluations });
        }
        let x_norm = (0..nf).map(|i| (scale[i] * x[i]).powi(2)).sum::<f64>().sqrt();
        loop {
            let mut a = jtj.clone();
            for i in 0..nf {
                // A parameter the cost does not see yet (a zero column) is held: its row is
                // made the identity, and its gradient is zero.
                a[(i, i)] += if scale[i] > 0.0 { mu * scale[i].powi(2) } else { 1.0 };
            }
            let stepped = a.cholesky().map(|ch| ch.solve(&(-&g)));
            let Some(delta) = stepped else {
                mu *= nu;
                nu *= 2.0;
                if !mu.is_finite() || mu > 1e300 {
                    return Some(Run { x, eval: cur, stop: Stop::StepSize, iterations: iter, evaluations });
                }
                continue;
            };
            let step_norm = (0..nf).map(|i| (scale[i] * delta[i]).powi(2)).sum::<f64>().sqrt();
            if step_norm <= tol.step * (x_norm + tol.step) {
                return Some(Run { x, eval: cur, stop: Stop::StepSize, iterations: iter, evaluations });
            }
            let mut cand: Vec<f64> = x.iter().zip(delta.iter()).map(|(a, d)| a + d).collect();
            project(&mut cand);
            // Predicted decrease of Σr² under the linearisation: −(2gᵀδ + δᵀJᵀJδ).
            let pred = -(2.0 * g.dot(&delta) + (&jtj * &delta).dot(&delta));
            evaluations += 1;
            match eval(&cand) {
                Some(next) if next.cost() < cur.cost() => {
                    let actual = cur.cost() - next.cost();
                    let rho = actual / pred.max(1e-300);
                    mu *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
                    nu = 2.0;
                    let (rel_actual, rel_pred) = (actual / cur.cost(), pred / cur.cost());
                    x = cand;
                    cur = next;
                    if rel_actual <= tol.cost && rel_pred <= tol.cost && rho <= 2.0 {
                        return Some(Run {
                            x,
                            eval: cur,
                            stop: Stop::CostDecrease,
                            iterations: iter + 1,
                            evaluations,
                        });
                    }
                    break;
                }
                _ => {
                    mu *= nu;
                    nu *= 2.0;
                    if !mu.is_finite() || mu > 1e300 {
                        return Some(Run {
                            x,
                            eval: cur,
                            stop: Stop::StepSize,
                            iterations: iter,
                            evaluations,
                        });
                    }
                }
            }
        }
    }
    Some(Run { x, eval: cur, stop: Stop::IterationLimit, iterations: tol.max_iter, evaluations })
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
