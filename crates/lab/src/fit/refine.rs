//! The joint refinement of a model with terms ([`refine`]).
//!
//! The host model is fitted first, by output error; a term is then added and the whole
//! model (structure, loop, gains, offset and drift, branches, and the term's parameters) is
//! refined jointly by Levenberg–Marquardt on the free-run error over the fit's criterion
//! window, from the host's optimum. The Jacobian is taken by finite differences (a dozen
//! parameters, a few thousand samples: each evaluation is one free run).

use super::FitError;
use crate::model::terms::{Param, TermModel};
use crate::signal::analysis;
use nalgebra::{DMatrix, DVector};

/// The criterion of a refinement: the model runs from sample 0 over `u[..end]` and is
/// scored on `[skip, end)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Criterion {
    /// First scored sample.
    pub skip: usize,
    /// End of the scored samples.
    pub end: usize,
    /// Levenberg–Marquardt iterations at most.
    pub max_iter: usize,
}

/// Residual `y − ŷ` over the criterion, or `None` if the model is not admissible or its free
/// run is not finite.
fn residual(m: &TermModel, free: &[Param], u: &[f64], y: &[f64], ts: f64, c: &Criterion) -> Option<Vec<f64>> {
    if !m.admissible(free) {
        return None;
    }
    let sim = m.simulate(&u[..c.end], ts).ok()?;
    let r: Vec<f64> = y[c.skip..c.end].iter().zip(&sim[c.skip..]).map(|(a, b)| a - b).collect();
    r.iter().all(|v| v.is_finite() && v.abs() < crate::record::Y_LIMIT_UM).then_some(r)
}

/// Refines `start` by Levenberg–Marquardt over the parameters `free` on the free-run error
/// over the criterion (see the module docs), each step projected onto the parameters' bounds
/// (a delay in `[0, 3]` samples, creep gains at least 0, creep time constants in their
/// range). Returns the refined model and its RMS over the criterion, or `None` if `start`
/// itself cannot be evaluated.
pub fn refine(
    start: &TermModel,
    free: &[Param],
    u: &[f64],
    y: &[f64],
    ts: f64,
    c: &Criterion,
) -> Option<(TermModel, f64)> {
    let c = Criterion { end: c.end.min(u.len()).min(y.len()), ..*c };
    if c.end <= c.skip + free.len() {
        return None;
    }
    let mut model = start.clone();
    let mut r = residual(&model, free, u, y, ts, &c)?;
    let mut cost: f64 = r.iter().map(|v| v * v).sum();
    let np = free.len();
    // Finite-difference steps: relative to each parameter, with a floor of its own scale.
    let scale: Vec<f64> = free.iter().map(|&p| step_scale(start, p)).collect();
    let mut mu = 1e-3;
    for _ in 0..c.max_iter {
        let m = r.len();
        let mut jac = DMatrix::<f64>::zeros(m, np);
        for (col, &p) in free.iter().enumerate() {
            let v = model.get(p);
            let h = 1e-6 * (v.abs() + scale[col]);
            let mut q = model.clone();
            q.set(p, v + h);
            let (rq, hs) = match residual(&q, free, u, y, ts, &c) {
                Some(rq) => (rq, h),
                None => {
                    q.set(p, v - h);
                    (residual(&q, free, u, y, ts, &c)?, -h)
                }
            };
            for i in 0..m {
                // d(y − ŷ)/dp.
                jac[(i, col)] = (rq[i] - r[i]) / hs;
            }
        }
        let rv = DVector::from_column_slice(&r);
        let jtj = jac.transpose() * &jac;
        let g = jac.transpose() * rv;
        let mut improved = false;
        while mu < 1e12 {
            let mut a = jtj.clone();
            for i in 0..np {
                a[(i, i)] += mu * (jtj[(i, i)] + 1e-12);
            }
            let Some(ch) = a.cholesky() else {
                mu *= 4.0;
                continue;
            };
            let delta = ch.solve(&(-&g));
            let mut cand = model.clone();
            for (i, &p) in free.iter().enumerate() {
                cand.set(p, model.get(p) + delta[i]);
            }
            cand.project();
            match residual(&cand, free, u, y, ts, &c) {
                Some(rc) => {
                    let cc: f64 = rc.iter().map(|v| v * v).sum();
                    if cc < cost {
                        let rel = (cost - cc) / cost.max(1e-300);
                        (model, r, cost) = (cand, rc, cc);
                        mu = (mu / 3.0).max(1e-12);
                        improved = rel > 1e-9;
                        break;
                    }
                    mu *= 4.0;
                }
                None => mu *= 4.0,
            }
        }
        if !improved {
            break;
        }
    }
    let rms = (cost / r.len() as f64).sqrt();
    Some((model, rms))
}

/// The floor of the finite-difference step of a parameter: its scale in the start model.
fn step_scale(m: &TermModel, p: Param) -> f64 {
    let bw = &m.host.ext.bw;
    match p {
        Param::Ar(_) => 1e-3,
        Param::A1 | Param::A | Param::A0 => bw.a1.abs().max(bw.a.abs()).max(1e-9),
        Param::Gamma | Param::Beta => (bw.gamma.abs() + bw.beta.abs()).max(1e-6),
        Param::Delay => 1e-2,
        Param::Drift(_) | Param::BranchSin(_) | Param::BranchCos(_) => 1e-3,
        Param::InputClamp(_) => m.terms.input_clamp.map_or(1e-3, |[lo, hi]| 1e-2 * (hi - lo).abs().max(1e-6)),
        Param::OutputClamp(_) => {
            m.terms.output_clamp.map_or(1e-3, |[lo, hi]| 1e-2 * (hi - lo).abs().max(1e-6))
        }
        Param::CreepGain(_) => 1e-3,
        Param::CreepTau(j) => 1e-2 * m.terms.creep[j].tau_s,
        Param::Stiffening(_) => 1e-3,
    }
}

/// The held-out RMS of `m` (µm) on `y[from..]`, simulated from sample 0 over the whole of
/// `u`; non-finite if the model runs away.
pub fn held_out_rms(m: &TermModel, u: &[f64], y: &[f64], ts: f64, from: usize) -> Result<f64, FitError> {
    let sim = m.simulate(u, ts)?;
    Ok(analysis::rms_diff(&sim[from..], &y[from..]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::terms::{Relaxation, Stiffening};
    use crate::model::{Branch, HostModel};
    use boucwen_core::model::{BoucWenParams, ExtendedParams};
    use std::f64::consts::TAU;

    fn host() -> HostModel {
        let w0 = TAU * 0.07;
        HostModel {
            ext: ExtendedParams {
                bw: BoucWenParams { a1: 0.2, a: 0.06, a0: 0.005, gamma: 0.02, beta: 0.03 },
                ar: [2.0 * 0.97 * w0.cos(), -0.97 * 0.97],
            },
            drive_hz: 23.0,
            branches: vec![Branch { order: 3, alpha_s: 0.01, alpha_c: -0.005, ar: [0.0, 0.0] }],
            drift: vec![0.3],
            delay: 0.4,
        }
    }

    fn sine(n: usize, f: f64, amp: f64) -> Vec<f64> {
        (0..n).map(|k| amp * (TAU * f * k as f64 * 1e-3).sin()).collect()
    }

    #[test]
    fn a_term_is_recovered_by_refinement_from_the_host() {
        // Truth: the host with creep and a cubic stiffening; start: the host without them.
        let u: Vec<f64> = sine(6000, 11.0, 1.0).iter().map(|v| v + 0.5).collect();
        let mut truth = TermModel::from(host());
        truth.host.branches.clear();
        truth.terms.creep = vec![Relaxation { tau_s: 0.8, gain: 0.1 }];
        truth.terms.stiffening = vec![Stiffening { power: 3, coeff: 0.05 }];
        truth.terms.q_ref_um = 20.0;
        let y = truth.simulate(&u, 1e-3).unwrap();
        let mut start = truth.clone();
        start.terms.creep[0].gain = 0.0;
        start.terms.stiffening[0].coeff = 0.0;
        let c = Criterion { skip: 100, end: 3000, max_iter: 40 };
        let before = held_out_rms(&start, &u, &y, 1e-3, 3000).unwrap();
        let mut free = start.host_params();
        free.extend([Param::CreepGain(0), Param::CreepTau(0), Param::Stiffening(0)]);
        let (m, _) = refine(&start, &free, &u, &y, 1e-3, &c).unwrap();
        let after = held_out_rms(&m, &u, &y, 1e-3, 3000).unwrap();
        assert!(after < 1e-3 * before, "held-out {before} -> {after}: {:?}", m.terms);
        assert!((m.terms.creep[0].gain - 0.1).abs() < 1e-3, "{:?}", m.terms.creep);
        assert!((m.terms.stiffening[0].coeff - 0.05).abs() < 1e-3, "{:?}", m.terms.stiffening);
    }
}
