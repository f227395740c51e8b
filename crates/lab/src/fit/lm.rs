//! Levenberg–Marquardt over the outer parameters, stopped by criteria.
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

use super::options::{Outer, Param, Tolerances};
use super::problem::Eval;
use nalgebra::DVector;
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

/// The end of one run.
#[derive(Clone, Debug)]
pub(crate) struct Run {
    pub phi: Outer,
    pub eval: Eval,
    pub stop: Stop,
    pub iterations: usize,
    pub evaluations: usize,
}

/// Minimises `eval(φ).cost` over the parameters `free` from `start`. `eval(φ, true)` must
/// return `(JᵀJ, Jᵀr)` over `free` in that order.
pub(crate) fn levenberg_marquardt(
    start: Outer,
    free: &[Param],
    tol: &Tolerances,
    eval: impl Fn(&Outer) -> Option<Eval>,
) -> Option<Run> {
    let mut phi = start;
    let mut cur = eval(&phi)?;
    let mut evaluations = 1;
    let nf = free.len();
    let mut mu: Option<f64> = None;
    let mut nu = 2.0;
    let mut scale = DVector::<f64>::zeros(nf);
    let finish =
        |phi, cur, stop, iterations, evaluations| Some(Run { phi, eval: cur, stop, iterations, evaluations });
    for iter in 0..tol.max_iter {
        // Every evaluation of a run carries its Jacobian; one without cannot be stepped.
        let (jtj, g) = cur.jac.clone()?;
        if cur.cost <= 0.0 {
            return finish(phi, cur, Stop::Gradient, iter, evaluations);
        }
        for i in 0..nf {
            scale[i] = scale[i].max(jtj[(i, i)].max(0.0).sqrt());
        }
        let cosine = (0..nf)
            .filter(|&i| jtj[(i, i)] > 0.0)
            .map(|i| g[i].abs() / (jtj[(i, i)].sqrt() * cur.cost.sqrt()))
            .fold(0.0, f64::max);
        if cosine <= tol.gradient {
            return finish(phi, cur, Stop::Gradient, iter, evaluations);
        }
        let mut mu_now = *mu.get_or_insert(1e-3);
        let x_norm = (0..nf).map(|i| (scale[i] * phi.get(free[i])).powi(2)).sum::<f64>().sqrt();
        loop {
            let mut a = jtj.clone();
            for i in 0..nf {
                a[(i, i)] += mu_now * scale[i].powi(2).max(1e-300);
            }
            let Some(ch) = a.cholesky() else {
                mu_now *= nu;
                nu *= 2.0;
                if !mu_now.is_finite() || mu_now > 1e300 {
                    return finish(phi, cur, Stop::StepSize, iter, evaluations);
                }
                continue;
            };
            let delta = ch.solve(&(-&g));
            let step_norm = (0..nf).map(|i| (scale[i] * delta[i]).powi(2)).sum::<f64>().sqrt();
            if step_norm <= tol.step * (x_norm + tol.step) {
                return finish(phi, cur, Stop::StepSize, iter, evaluations);
            }
            let mut cand = phi;
            for (i, &p) in free.iter().enumerate() {
                cand.set(p, phi.get(p) + delta[i]);
            }
            // Predicted decrease of Σr² under the linearisation: -(2gᵀδ + δᵀJᵀJδ).
            let pred = -(2.0 * g.dot(&delta) + (&jtj * &delta).dot(&delta));
            evaluations += 1;
            match eval(&cand) {
                Some(next) if next.cost < cur.cost => {
                    let actual = cur.cost - next.cost;
                    let rho = actual / pred.max(1e-300);
                    mu_now *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
                    nu = 2.0;
                    let rel_actual = actual / cur.cost;
                    let rel_pred = pred / cur.cost;
                    phi = cand;
                    cur = next;
                    mu = Some(mu_now);
                    if rel_actual <= tol.cost && rel_pred <= tol.cost && rho <= 2.0 {
                        return finish(phi, cur, Stop::CostDecrease, iter + 1, evaluations);
                    }
                    break;
                }
                _ => {
                    mu_now *= nu;
                    nu *= 2.0;
                    if !mu_now.is_finite() || mu_now > 1e300 {
                        return finish(phi, cur, Stop::StepSize, iter, evaluations);
                    }
                }
            }
        }
    }
    finish(phi, cur, Stop::IterationLimit, tol.max_iter, evaluations)
}
