//! One evaluation of the output-error criterion: the simulation, the variable projection and,
//! in the same pass, the exact Jacobian by forward sensitivity equations.
//!
//! For outer parameters `φ` the prediction is `ŷ = Z(φ)·θ`, with the filtered columns
//! `z = G·x` of `x = (u_τ, -h₁, sin nθ, cos nθ)` and the unfiltered drift columns. `θ` is
//! solved exactly (variable projection) and the residual is `r = (I - P_Z)·y`. Its
//! Jacobian in Kaufman's form, `J = -(I - P_Z)·V` with `V = (∂Z/∂φ)·θ`, gives the exact
//! gradient `Jᵀr = -Vᵀr` (the term Kaufman drops is orthogonal to `r`) and the
//! Gauss–Newton matrix `JᵀJ = VᵀV - (ZᵀV)ᵀ(ZᵀZ)⁻¹(ZᵀV)`.
//!
//! The columns of `V` come from recursions run alongside the simulation:
//! - `∂z/∂a1 = G·z[k-1]` for each filtered column, and `∂z/∂a2 = G·z[k-2]`, the same
//!   sequence one sample later;
//! - `∂h₁/∂p` for `p = A0/A, γ', β, τ` by differentiating the Bouc–Wen recursion
//!   `h' = h + (1 - γ'|h|)Δu + (A0/A - βh)|Δu|`, each filtered by `G`;
//! - `∂u_τ/∂τ = u[k-m-1] - u[k-m]` (`τ = m + frac`, linear interpolation), filtered by `G`.

use super::options::{MIN_SLOPE, Outer, Param, operating_slope};
use crate::model::MAX_DELAY;
use crate::model::poles;
use crate::model::{HostModel, ModelSpec};
use boucwen_core::model::{BoucWenParams, ExtendedParams, HarmonicBranch};
use boucwen_core::signal::{Oscillator, sin_cos};
use nalgebra::{DMatrix, DVector};

/// The criterion's data and model columns.
pub(crate) struct Problem<'a> {
    pub require_invertible: bool,
    /// No hysteresis column.
    pub linear: bool,
    /// The output's sign: `A` has it, and so has `A1` for an invertible model. The model is
    /// odd in the output (`y → −y` is `A1, A, A0, γ → −A1, −A, −A0, −γ` with the loop's
    /// shape unchanged), so a sensor counting the stroke downwards is fitted with `−1`.
    pub sign: f64,
    u: &'a [f64],
    ts: f64,
    spec: &'a ModelSpec,
    /// Target output at samples `target_from..target_from + target.len()`.
    target: Vec<f64>,
    target_from: usize,
    /// Degree of the fitted drift polynomial (`None`: no drift columns).
    drift_degree: Option<usize>,
    /// Time scale of the drift columns (s): the columns are `(t/t_scale)^j`.
    t_scale: f64,
    /// Trend terms `t^1…` taken from the average period (added to the model, not fitted).
    fixed_trend: Vec<f64>,
    /// sin/cos of each branch, sample by sample from 0.
    branch_sc: Vec<Vec<(f64, f64)>>,
}

/// Samples scored: `[from, to)`; the simulation runs from 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Window {
    pub from: usize,
    pub to: usize,
}

/// One evaluation.
#[derive(Clone, Debug)]
pub(crate) struct Eval {
    pub theta: DVector<f64>,
    /// `Σ r²` over the window.
    pub cost: f64,
    /// Samples scored.
    pub samples: usize,
    /// `(JᵀJ, Jᵀr)` over the free parameters, when asked.
    pub jac: Option<(DMatrix<f64>, DVector<f64>)>,
}

impl super::lm::Evaluation for Eval {
    fn cost(&self) -> f64 {
        self.cost
    }
    fn normal(&self) -> Option<(&DMatrix<f64>, &DVector<f64>)> {
        self.jac.as_ref().map(|(a, b)| (a, b))
    }
}

fn sgn(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}

impl<'a> Problem<'a> {
    /// `target[i]` is the output wanted at sample `target_from + i`; `u` must reach the end of
    /// every window evaluated.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        u: &'a [f64],
        ts: f64,
        spec: &'a ModelSpec,
        target: Vec<f64>,
        target_from: usize,
        drift_degree: Option<usize>,
        fixed_trend: Vec<f64>,
    ) -> Result<Self, super::FitError> {
        let end = target_from + target.len();
        let drive = Oscillator::new(spec.drive_hz, ts)?;
        let branch_sc = spec
            .harmonics
            .iter()
            .map(|&n| {
                (0..end).map(|k| sin_cos::<f64>(drive.phase_at(k as u64).wrapping_mul(n as u64))).collect()
            })
            .collect();
        Ok(Self {
            require_invertible: false,
            linear: false,
            sign: 1.0,
            u,
            ts,
            spec,
            target,
            target_from,
            drift_degree,
            t_scale: (end as f64 * ts).max(ts),
            fixed_trend,
            branch_sc,
        })
    }

    fn filtered(&self) -> usize {
        1 + usize::from(!self.linear) + 2 * self.spec.harmonics.len()
    }

    fn columns(&self) -> usize {
        self.filtered() + self.drift_degree.map_or(0, |d| d + 1)
    }

    /// The free parameters this problem can differentiate.
    pub fn differentiable(&self, p: Param) -> bool {
        !(self.linear && matches!(p, Param::A0Ratio | Param::Gamma | Param::Beta))
    }

    /// Evaluates `φ` on `win`, with `(JᵀJ, Jᵀr)` for `free` when given. `None` if `φ` gives
    /// an unstable, degenerate or (when required) non-invertible model.
    pub fn eval(&self, phi: &Outer, win: Window, free: Option<&[Param]>) -> Option<Eval> {
        let [a1, a2] = phi.ar;
        if !poles::stable(&phi.ar) || !(0.0..=MAX_DELAY).contains(&phi.delay) {
            return None;
        }
        debug_assert!(win.from >= self.target_from && win.to <= self.target_from + self.target.len());
        let jac = free.is_some();
        let (dm, dfrac) = (phi.delay.floor() as usize, phi.delay - phi.delay.floor());
        let u_at = |i: usize| self.u.get(i).copied().unwrap_or(0.0);
        let (r0, g, b) = (phi.shape.a0_ratio, phi.shape.gamma, phi.shape.beta);
        let shape = BoucWenParams { a1: 0.0, a: 1.0, a0: r0, gamma: g, beta: b };
        let nf = self.filtered();
        let ncol = self.columns();
        // Row: z (ncol), ∂z/∂a1 (nf), ∂z/∂a2 (nf), G·∂h/∂(A0/A, γ', β, τ), G·∂u/∂τ.
        let width = if jac { ncol + 2 * nf + 5 } else { ncol };
        let (mut z1, mut z2) = (vec![0.0; nf], vec![0.0; nf]);
        let (mut s1, mut s2) = (vec![0.0; nf], vec![0.0; nf]);
        let mut gs = [[0.0f64; 2]; 5];
        let mut x = vec![0.0; nf];
        // Normal equations, lower triangle, row-major (flat for the inner loop).
        let mut gram = vec![0.0; ncol * ncol];
        let mut zty = vec![0.0; ncol];
        let mut rows: Vec<f64> = Vec::with_capacity((win.to - win.from) * width);
        let mut row = vec![0.0; width];
        let (mut h, mut u_prev, mut ut_prev) = (0.0, 0.0, 0.0);
        let mut dh = [0.0f64; 4]; // ∂h₁/∂(A0/A, γ', β, τ)
        let (mut h_lo, mut h_hi) = (0.0f64, 0.0f64);

        for k in 0..win.to {
            let (uk, ut) = {
                let a = if k >= dm { u_at(k - dm) } else { 0.0 };
                let b = if k > dm { u_at(k - dm - 1) } else { 0.0 };
                ((1.0 - dfrac) * a + dfrac * b, b - a)
            };
            x[0] = uk;
            let mut c = 1;
            let mut hin = [0.0f64; 4];
            if !self.linear {
                let du = uk - u_prev;
                if jac {
                    let dh_dh = 1.0 - g * sgn(h) * du - b * du.abs();
                    let dh_ddu = (1.0 - g * h.abs()) + (r0 - b * h) * sgn(du);
                    let ddu = ut - ut_prev;
                    dh[0] = dh_dh * dh[0] + du.abs();
                    dh[1] = dh_dh * dh[1] - h.abs() * du;
                    dh[2] = dh_dh * dh[2] - h * du.abs();
                    dh[3] = dh_dh * dh[3] + dh_ddu * ddu;
                    hin = dh;
                }
                h = shape.h_next(h, du);
                if !h.is_finite() || h.abs() > 1e12 {
                    return None;
                }
                h_lo = h_lo.min(h);
                h_hi = h_hi.max(h);
                x[1] = -h;
                c = 2;
            }
            for sc in &self.branch_sc {
                x[c] = sc[k].0;
                x[c + 1] = sc[k].1;
                c += 2;
            }
            for i in 0..nf {
                if jac {
                    let s = a1 * s1[i] + a2 * s2[i] + z1[i];
                    s2[i] = s1[i];
                    s1[i] = s;
                }
                let v = a1 * z1[i] + a2 * z2[i] + x[i];
                z2[i] = z1[i];
                z1[i] = v;
            }
            if jac {
                let inputs = [hin[0], hin[1], hin[2], hin[3], ut];
                for (gq, &inp) in gs.iter_mut().zip(&inputs) {
                    let v = a1 * gq[0] + a2 * gq[1] + inp;
                    gq[1] = gq[0];
                    gq[0] = v;
                }
            }
            u_prev = uk;
            ut_prev = ut;
            if k >= win.from {
                row[..nf].copy_from_slice(&z1);
                if let Some(d) = self.drift_degree {
                    let t = k as f64 * self.ts / self.t_scale;
                    let mut p = 1.0;
                    for j in 0..=d {
                        row[nf + j] = p;
                        p *= t;
                    }
                }
                let yk = self.target[k - self.target_from];
                for i in 0..ncol {
                    let zi = row[i];
                    zty[i] += zi * yk;
                    let g = &mut gram[i * ncol..i * ncol + i + 1];
                    for (gj, zj) in g.iter_mut().zip(&row[..=i]) {
                        *gj += zi * zj;
                    }
                }
                if jac {
                    for i in 0..nf {
                        row[ncol + i] = s1[i];
                        row[ncol + nf + i] = s2[i];
                    }
                    for q in 0..5 {
                        row[ncol + 2 * nf + q] = gs[q][0];
                    }
                }
                rows.extend_from_slice(&row);
            }
        }
        let mut xtx = DMatrix::<f64>::from_fn(ncol, ncol, |i, j| gram[i.max(j) * ncol + i.min(j)]);
        let xty = DVector::<f64>::from_vec(zty);
        // Tiny ridge relative to the diagonal keeps a nearly collinear column harmless.
        let scale = (0..ncol).map(|i| xtx[(i, i)]).fold(0.0, f64::max);
        for i in 0..ncol {
            xtx[(i, i)] += 1e-12 * scale + 1e-300;
        }
        let mut chol = xtx.clone().cholesky()?;
        let mut theta = chol.solve(&xty);
        let mut clamped = false;
        let sign = self.sign;
        if !self.linear && sign * theta[1] < 0.0 {
            // The loop's amplitude A has the output's sign (the loop lowers the gain): the
            // constrained optimum then lies on A = 0 (one bound, so this is the exact
            // non-negative least-squares solution).
            let mut reduced = xtx.clone();
            let mut rhs = xty.clone();
            for j in 0..ncol {
                reduced[(1, j)] = 0.0;
                reduced[(j, 1)] = 0.0;
            }
            reduced[(1, 1)] = 1.0;
            rhs[1] = 0.0;
            chol = reduced.cholesky()?;
            theta = chol.solve(&rhs);
            clamped = true;
        }
        if theta.iter().any(|t| !t.is_finite()) {
            return None;
        }
        let amp = if self.linear { 0.0 } else { theta[1] };
        if self.require_invertible {
            // Over the whole range h can reach, not only the fitted trajectory: the inverse
            // drives the model along other paths. An A of the other sign than A1 is a
            // non-physical loop. Checked on the model of the output counted upwards (the
            // inverse is odd in the output too).
            let (a1, a) = (sign * theta[0], sign * amp);
            let bw = BoucWenParams { a1, a, a0: r0 * a, gamma: g, beta: b };
            let ok = a1 > 0.0
                && a >= 0.0
                && operating_slope(&bw, a * h_lo, a * h_hi).is_some_and(|m| m >= MIN_SLOPE * a1);
            if !ok {
                return None;
            }
        }
        let samples = win.to - win.from;
        let mut cost = 0.0;
        let Some(free) = free else {
            for (r, k) in rows.chunks_exact(width).zip(win.from..) {
                let e = self.target[k - self.target_from] - dot(&r[..ncol], theta.as_slice());
                cost += e * e;
            }
            return Some(Eval { theta, cost, samples, jac: None });
        };
        let nfree = free.len();
        let mut vtv = vec![0.0; nfree * nfree];
        let mut ztv = vec![0.0; ncol * nfree];
        let mut vtr = vec![0.0; nfree];
        let mut v = vec![0.0; nfree];
        let th = theta.as_slice();
        for (r, k) in rows.chunks_exact(width).zip(win.from..) {
            let e = self.target[k - self.target_from] - dot(&r[..ncol], th);
            cost += e * e;
            let g0 = ncol + 2 * nf;
            for (vq, p) in v.iter_mut().zip(free) {
                *vq = match p {
                    Param::Ar1 => dot(&r[ncol..ncol + nf], &th[..nf]),
                    Param::Ar2 => dot(&r[ncol + nf..ncol + 2 * nf], &th[..nf]),
                    Param::A0Ratio => -amp * r[g0],
                    Param::Gamma => -amp * r[g0 + 1],
                    Param::Beta => -amp * r[g0 + 2],
                    Param::Delay => th[0] * r[g0 + 4] - amp * r[g0 + 3],
                };
            }
            for i in 0..nfree {
                let vi = v[i];
                vtr[i] += vi * e;
                for (g, vj) in vtv[i * nfree..i * nfree + i + 1].iter_mut().zip(&v[..=i]) {
                    *g += vi * vj;
                }
                for (g, zc) in ztv[i * ncol..(i + 1) * ncol].iter_mut().zip(&r[..ncol]) {
                    *g += zc * vi;
                }
            }
        }
        let vtv = DMatrix::<f64>::from_fn(nfree, nfree, |i, j| vtv[i.max(j) * nfree + i.min(j)]);
        let mut ztv = DMatrix::<f64>::from_fn(ncol, nfree, |c, i| ztv[i * ncol + c]);
        let vtr = DVector::<f64>::from_vec(vtr);
        if clamped {
            ztv.row_mut(1).fill(0.0);
        }
        let proj = chol.solve(&ztv);
        let jtj = vtv - ztv.transpose() * proj;
        Some(Eval { theta, cost, samples, jac: Some((jtj, -vtr)) })
    }

    /// The host model of `φ` and its linear parameters `θ`.
    pub fn model(&self, phi: &Outer, theta: &DVector<f64>) -> HostModel {
        let amp = if self.linear { 0.0 } else { theta[1] };
        let mut c = if self.linear { 1 } else { 2 };
        let sgn = if amp < 0.0 { -1.0 } else { 1.0 };
        let s = &phi.shape;
        let ext = ExtendedParams {
            bw: BoucWenParams {
                a1: theta[0],
                a: amp,
                a0: s.a0_ratio * amp,
                gamma: sgn * s.gamma,
                beta: s.beta,
            },
            ar: phi.ar,
        };
        let mut branches = vec![];
        for &order in &self.spec.harmonics {
            branches.push(HarmonicBranch { order, alpha_s: theta[c], alpha_c: theta[c + 1], ar: [0.0, 0.0] });
            c += 2;
        }
        let mut drift: Vec<f64> = match self.drift_degree {
            Some(d) => (0..=d).map(|i| theta[c + i] / self.t_scale.powi(i as i32)).collect(),
            None => vec![],
        };
        drift.extend_from_slice(&self.fixed_trend);
        HostModel { ext, drive_hz: self.spec.drive_hz, branches, drift, delay: phi.delay }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::LoopShape;

    /// The Jacobian from the sensitivity equations against central differences of the
    /// projected cost: `Jᵀr` is half the cost's gradient.
    #[test]
    fn the_sensitivity_gradient_matches_finite_differences() {
        let ts = 1e-3;
        let n = 3000;
        let u: Vec<f64> = (0..n).map(|k| (std::f64::consts::TAU * 23.0 * ts * k as f64).sin()).collect();
        let spec = ModelSpec { drive_hz: 23.0, harmonics: vec![3], drift_degree: Some(1) };
        let y: Vec<f64> = u
            .iter()
            .enumerate()
            .map(|(k, &v)| 10.0 * v + 2.0 * (v * 3.0).tanh() + 0.3 * (0.21 * k as f64).sin())
            .collect();
        let p = Problem::new(&u, ts, &spec, y.clone(), 0, Some(1), vec![]).unwrap();
        let phi =
            Outer { ar: [1.2, -0.5], shape: LoopShape { a0_ratio: 0.1, gamma: 0.4, beta: 0.9 }, delay: 0.6 };
        let free = [Param::Ar1, Param::Ar2, Param::A0Ratio, Param::Gamma, Param::Beta, Param::Delay];
        let win = Window { from: 200, to: n };
        let e = p.eval(&phi, win, Some(&free)).unwrap();
        let (_, g) = e.jac.unwrap();
        for (i, &q) in free.iter().enumerate() {
            let step = 1e-6 * phi.get(q).abs().max(1e-2);
            let at = |d: f64| {
                let mut o = phi;
                o.set(q, phi.get(q) + d);
                p.eval(&o, win, None).unwrap().cost
            };
            let fd = (at(step) - at(-step)) / (2.0 * step);
            assert!(
                (2.0 * g[i] - fd).abs() <= 1e-4 * fd.abs().max(1e-3 * e.cost),
                "{q:?}: {} vs {fd}",
                2.0 * g[i]
            );
        }
    }
}
