//! The modal LFR: a Bouc–Wen restoring force in feedback on each mode, fitted by output
//! error in the time domain.
//!
//! ## The model
//! For each pair of poles `b` (the states `i, i + 1` of its block `A_b`) a channel closes the
//! loop on the mode's first state ([`Source::Feedback`]):
//! ```text
//! v_b[k]   = x_i[k] / s_b,   h_b[k] = h(v_b)[k]   (Bouc–Wen, A = 1, `shape`; hysteresis module)
//! w_b[k]   = h_b[k] − v_b[k]                      (the loop's nonlinear part)
//! x_b[k+1] = A_b x_b[k] + B_b u[k] + e_b w_b[k]
//! y[k]     = Σ_b C_b x_b[k] + D u[k]
//! ```
//! The mode's restoring force is split into the linear part (in `A_b`) and a hysteretic one:
//! a Bouc–Wen oscillator per mode. At small amplitude (`|v| ≪ 1`) `w` vanishes and the model is
//! `(A, B, C, D)`; as the amplitude grows `h` lags and saturates, `w` grows (for `γ = β`, in
//! proportion to the square of the amplitude over a cycle: the equivalent stiffness and
//! damping change in proportion to the amplitude, Rayleigh's law of ferroelectric
//! materials), so the mode's frequency and damping move with the level: the softening that one
//! linear model for all levels cannot follow. Each channel feeds its own mode, so the modes
//! stay uncoupled: the model is a sum of one- or two-state nonlinear systems, each simulated
//! (and differentiated) on its own.
//!
//! ## The fit ([`fit_feedback`]): output error in periodic steady state
//! The data are the period means of every kept realisation of every level (each level's
//! squared errors weighted as in the frequency-domain fit). A simulation runs the input
//! period once from rest as a warm-up, then once more, scored (as the benchmark's metric).
//! The parameters are, per mode, the pole (`σ, ω` or `λ`) and for a pair `e_b` (2) and
//! `ln s_b`; `B` stays that of the linear model. `C` and `D` enter the output linearly: for
//! given poles and channels they are the weighted least-squares solution on the simulated
//! states (variable projection). Levenberg–Marquardt on the rest with Kaufman's Jacobian:
//! with `Φ = [x, u]` the regressors of `(C, D)`, `J_o = ∂ŷ_o/∂θ` (at fixed `C, D`) and
//! `M_o = ΦᵀW J_o`, the reduced normal equations are
//! ```text
//! (Σ_o J_oᵀ W J_o − M_oᵀ (ΦᵀWΦ)⁻¹ M_o + μ diag) δ = Σ_o J_oᵀ W r_o
//! ```
//! `J_o` comes from the exact sensitivities (forward, a two-state recursion per parameter and
//! mode, with the Bouc–Wen step's exact derivatives [`Shape::step_grad`]). A step whose
//! poles leave the unit circle or whose simulation is not finite is refused.

use super::MimoError;
use super::hysteresis::Shape;
use super::linear::{Mode, solve_spd};
use super::model::{Branch, Channel, MimoModel, Source};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// Steady-state periods to fit: per realisation the mean input and output period and the
/// weight of its squared errors.
#[derive(Clone, Debug)]
pub struct Periods {
    /// Inputs `m`.
    pub inputs: usize,
    /// Outputs `p`.
    pub outputs: usize,
    /// Samples per period `N`.
    pub samples: usize,
    /// Per realisation, `m × N` channels-major.
    pub u: Vec<Vec<f64>>,
    /// Per realisation, `p × N` channels-major.
    pub y: Vec<Vec<f64>>,
    /// Per realisation, the weight of its squared errors.
    pub weight: Vec<f64>,
}

impl Periods {
    /// Checks the sizes and weights.
    pub fn validate(&self) -> Result<(), MimoError> {
        let (m, p, n) = (self.inputs, self.outputs, self.samples);
        if m == 0 || p == 0 || n < 2 || self.u.is_empty() {
            return Err(MimoError::Data("no period to fit".into()));
        }
        if self.u.len() != self.y.len()
            || self.u.len() != self.weight.len()
            || self.u.iter().any(|u| u.len() != m * n)
            || self.y.iter().any(|y| y.len() != p * n)
        {
            return Err(MimoError::Shape("periods: u, y and weights do not match".into()));
        }
        if self.weight.iter().any(|w| !(w.is_finite() && *w > 0.0)) {
            return Err(MimoError::Parameter("period weights"));
        }
        Ok(())
    }
}

/// How to fit the loop.
#[derive(Clone, Debug, PartialEq)]
pub struct FeedbackOptions {
    /// Levenberg–Marquardt iterations (Jacobians), at most.
    pub iterations: usize,
    /// The loops' shape (`A0`, `γ`, `β`; `A = 1`).
    pub shape: Shape,
    /// Initial `s_b` as a multiple of the RMS of the mode's first state on the data.
    pub initial_scale: f64,
    /// Fit `ln s_b` (otherwise it stays at its initial value).
    pub fit_scale: bool,
}

impl Default for FeedbackOptions {
    fn default() -> Self {
        Self { iterations: 20, shape: Shape::symmetric(0.5), initial_scale: 2.0, fit_scale: true }
    }
}

/// How the fit went.
#[derive(Clone, Debug, PartialEq)]
pub struct FeedbackReport {
    /// Weighted sum of squared errors of the starting linear model (with `C, D` refitted in the
    /// time domain) and of the result.
    pub cost: (f64, f64),
    /// Iterations (Jacobians) done.
    pub iterations: usize,
}

/// One mode's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
enum ModeParams {
    Real(f64),
    Pair { sigma: f64, omega: f64, e: [f64; 2], s: f64 },
}

impl ModeParams {
    fn size(&self) -> usize {
        match self {
            Self::Real(_) => 1,
            Self::Pair { .. } => 2,
        }
    }
    /// Parameters in θ.
    fn count(&self) -> usize {
        match self {
            Self::Real(_) => 1,
            Self::Pair { .. } => 5,
        }
    }
    fn radius(&self) -> f64 {
        match *self {
            Self::Real(l) => l.abs(),
            Self::Pair { sigma, omega, .. } => sigma.hypot(omega),
        }
    }
}

fn pack(ms: &[ModeParams]) -> Vec<f64> {
    let mut th = Vec::new();
    for m in ms {
        match *m {
            ModeParams::Real(l) => th.push(l),
            ModeParams::Pair { sigma, omega, e, s } => th.extend([sigma, omega, e[0], e[1], s.ln()]),
        }
    }
    th
}

fn unpack(template: &[ModeParams], th: &[f64]) -> Vec<ModeParams> {
    let mut i = 0;
    template
        .iter()
        .map(|m| match m {
            ModeParams::Real(_) => {
                i += 1;
                ModeParams::Real(th[i - 1])
            }
            ModeParams::Pair { .. } => {
                i += 5;
                ModeParams::Pair {
                    sigma: th[i - 5],
                    omega: th[i - 4],
                    e: [th[i - 3], th[i - 2]],
                    s: th[i - 1].exp(),
                }
            }
        })
        .collect()
}

/// One mode simulated over the warm-up and the scored period: its states over the scored
/// period and, when asked, their sensitivities to the mode's parameters.
struct ModeRun {
    /// `[state][k]`.
    x: [Vec<f64>; 2],
    /// Per parameter, `[state][k]`.
    dx: Vec<[Vec<f64>; 2]>,
}

/// Runs one mode on its drive `bu` (`B_b u`, `[state][k]`).
fn run_mode(mp: &ModeParams, bu: &[Vec<f64>; 2], shape: &Shape, grad: bool) -> Option<ModeRun> {
    let len = bu[0].len();
    let np = if grad { mp.count() } else { 0 };
    let mut out = ModeRun {
        x: [vec![0.0; len], if mp.size() == 2 { vec![0.0; len] } else { Vec::new() }],
        dx: (0..np).map(|_| [vec![0.0; len], if mp.size() == 2 { vec![0.0; len] } else { Vec::new() }]).collect(),
    };
    match *mp {
        ModeParams::Real(l) => {
            let (mut x, mut dx) = (0.0, 0.0);
            for pass in 0..2 {
                for k in 0..len {
                    if pass == 1 {
                        out.x[0][k] = x;
                        if grad {
                            out.dx[0][0][k] = dx;
                        }
                    }
                    dx = l * dx + x;
                    x = l * x + bu[0][k];
                }
            }
            x.is_finite().then_some(out)
        }
        ModeParams::Pair { sigma, omega, e, s } => {
            let (mut x0, mut x1, mut hv, mut vprev) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
            // Tangent per parameter: (dx0, dx1, dhv, dvprev).
            let mut t = [[0.0f64; 4]; 5];
            let inv_s = 1.0 / s;
            for pass in 0..2 {
                for k in 0..len {
                    let v = x0 * inv_s;
                    let (hn, a_k, b_k) = shape.step_grad(hv, v - vprev);
                    let w = hn - v;
                    if pass == 1 {
                        out.x[0][k] = x0;
                        out.x[1][k] = x1;
                    }
                    if grad {
                        for (j, tj) in t.iter_mut().enumerate() {
                            let [d0, d1, dh, dvp] = *tj;
                            if pass == 1 {
                                out.dx[j][0][k] = d0;
                                out.dx[j][1][k] = d1;
                            }
                            let dv = d0 * inv_s - if j == 4 { v } else { 0.0 };
                            let dhn = a_k * dh + b_k * (dv - dvp);
                            let dw = dhn - dv;
                            let (f0, f1) = match j {
                                0 => (x0, x1),
                                1 => (x1, -x0),
                                2 => (w, 0.0),
                                3 => (0.0, w),
                                _ => (0.0, 0.0),
                            };
                            *tj = [
                                sigma * d0 + omega * d1 + e[0] * dw + f0,
                                -omega * d0 + sigma * d1 + e[1] * dw + f1,
                                dhn,
                                dv,
                            ];
                        }
                    }
                    let n0 = sigma * x0 + omega * x1 + bu[0][k] + e[0] * w;
                    let n1 = -omega * x0 + sigma * x1 + bu[1][k] + e[1] * w;
                    x0 = n0;
                    x1 = n1;
                    hv = hn;
                    vprev = v;
                }
                if !(x0.is_finite() && x1.is_finite()) {
                    return None;
                }
            }
            Some(out)
        }
    }
}

/// The problem: data, the fixed `B`, and the shape.
struct Problem<'a> {
    data: &'a Periods,
    /// `B`, `n × m`.
    b: &'a DMatrix<f64>,
    shape: Shape,
    /// Which θ entries are fitted.
    free: Vec<bool>,
}

/// One realisation's pass: regressors and, with a Jacobian, its columns.
struct Pass {
    /// `Φ = [x, u]`, `N × (n + m)`.
    phi: DMatrix<f64>,
    /// Per mode, its run.
    runs: Vec<ModeRun>,
}

impl Problem<'_> {
    fn pass(&self, ms: &[ModeParams], r: usize, grad: bool) -> Option<Pass> {
        let (m, len) = (self.data.inputs, self.data.samples);
        let n: usize = ms.iter().map(ModeParams::size).sum();
        let u = &self.data.u[r];
        let mut phi = DMatrix::<f64>::zeros(len, n + m);
        let mut runs = Vec::with_capacity(ms.len());
        let mut at = 0;
        for mp in ms {
            let sz = mp.size();
            let drive = |i: usize| -> Vec<f64> {
                let mut d = vec![0.0; len];
                for c in 0..m {
                    let bic = self.b[(i, c)];
                    if bic != 0.0 {
                        for (dk, uk) in d.iter_mut().zip(&u[c * len..(c + 1) * len]) {
                            *dk += bic * uk;
                        }
                    }
                }
                d
            };
            let bu = [drive(at), if sz == 2 { drive(at + 1) } else { Vec::new() }];
            let run = run_mode(mp, &bu, &self.shape, grad)?;
            for i in 0..sz {
                phi.column_mut(at + i).copy_from_slice(&run.x[i]);
            }
            runs.push(run);
            at += sz;
        }
        for c in 0..m {
            phi.column_mut(n + c).copy_from_slice(&u[c * len..(c + 1) * len]);
        }
        Some(Pass { phi, runs })
    }

    /// `C, D` by weighted least squares, the cost and the passes (`None`: a simulation
    /// diverged).
    fn evaluate(&self, ms: &[ModeParams]) -> Result<Option<Evaluated>, MimoError> {
        let d = self.data;
        let p = d.outputs;
        let len = d.samples;
        let passes: Option<Vec<Pass>> = (0..d.u.len()).into_par_iter().map(|r| self.pass(ms, r, false)).collect();
        let Some(passes) = passes else { return Ok(None) };
        let k = passes[0].phi.ncols();
        let mut g = DMatrix::<f64>::zeros(k, k);
        let mut rhs = DMatrix::<f64>::zeros(k, p);
        for (r, ps) in passes.iter().enumerate() {
            let y = DMatrix::from_column_slice(len, p, &d.y[r]);
            g += ps.phi.tr_mul(&ps.phi) * d.weight[r];
            rhs += ps.phi.tr_mul(&y) * d.weight[r];
        }
        let theta = solve_spd(g.clone(), &rhs).ok_or(MimoError::Numerical("C, D least squares (time domain)"))?;
        let cost: f64 = passes
            .par_iter()
            .enumerate()
            .map(|(r, ps)| {
                let y = DMatrix::from_column_slice(len, p, &d.y[r]);
                d.weight[r] * (y - &ps.phi * &theta).norm_squared()
            })
            .sum();
        if !cost.is_finite() {
            return Ok(None);
        }
        Ok(Some(Evaluated { theta, gram: g, cost }))
    }

    /// The reduced normal equations at `ms` with `(C, D)` = `theta` (rows: states, inputs;
    /// columns: outputs).
    fn normal_equations(
        &self,
        ms: &[ModeParams],
        ev: &Evaluated,
    ) -> Result<Option<(DMatrix<f64>, DVector<f64>)>, MimoError> {
        let d = self.data;
        let (p, len) = (d.outputs, d.samples);
        let npar: usize = ms.iter().map(ModeParams::count).sum();
        let kk = ev.theta.nrows();
        let parts: Option<Vec<(DMatrix<f64>, Vec<DMatrix<f64>>, DVector<f64>)>> = (0..d.u.len())
            .into_par_iter()
            .map(|r| {
                let ps = self.pass(ms, r, true)?;
                let sw = d.weight[r].sqrt();
                let y = DMatrix::from_column_slice(len, p, &d.y[r]);
                let res = (y - &ps.phi * &ev.theta) * sw;
                // J: (p·N) × npar, rows o·N + k.
                let mut jac = DMatrix::<f64>::zeros(p * len, npar);
                let (mut col, mut at) = (0, 0);
                for (mp, run) in ms.iter().zip(&ps.runs) {
                    let sz = mp.size();
                    for dxj in &run.dx {
                        let mut cj = jac.column_mut(col);
                        for o in 0..p {
                            for i in 0..sz {
                                let c = ev.theta[(at + i, o)] * sw;
                                for (v, dv) in cj.rows_mut(o * len, len).iter_mut().zip(&dxj[i]) {
                                    *v += c * dv;
                                }
                            }
                        }
                        col += 1;
                    }
                    at += sz;
                }
                let jj = jac.tr_mul(&jac);
                let phi_w = &ps.phi * sw;
                let mo: Vec<DMatrix<f64>> =
                    (0..p).map(|o| phi_w.tr_mul(&jac.rows(o * len, len))).collect();
                let res_flat = DVector::from_column_slice(res.as_slice());
                let jr = jac.tr_mul(&res_flat);
                Some((jj, mo, jr))
            })
            .collect();
        let Some(parts) = parts else { return Ok(None) };
        let mut jj = DMatrix::<f64>::zeros(npar, npar);
        let mut mo = vec![DMatrix::<f64>::zeros(kk, npar); p];
        let mut jr = DVector::<f64>::zeros(npar);
        for (a, b, c) in parts {
            jj += a;
            for (x, y) in mo.iter_mut().zip(b) {
                *x += y;
            }
            jr += c;
        }
        for m in &mo {
            let gm = solve_spd(ev.gram.clone(), m).ok_or(MimoError::Numerical("variable projection"))?;
            jj -= m.tr_mul(&gm);
        }
        for (i, &f) in self.free.iter().enumerate() {
            if !f {
                jj.row_mut(i).fill(0.0);
                jj.column_mut(i).fill(0.0);
                jj[(i, i)] = 1.0;
                jr[i] = 0.0;
            }
        }
        Ok(Some((jj, jr)))
    }
}

struct Evaluated {
    /// `[Cᵀ; Dᵀ]`, `(n + m) × p`.
    theta: DMatrix<f64>,
    /// `ΦᵀWΦ`.
    gram: DMatrix<f64>,
    cost: f64,
}

/// The modal LFR (module docs) from the linear model `lin`, fitted on `data`;
/// `progress(iteration, cost)` after each iteration.
pub fn fit_feedback(
    lin: &MimoModel,
    data: &Periods,
    opts: &FeedbackOptions,
    progress: &(dyn Fn(usize, f64) + Sync),
) -> Result<(MimoModel, FeedbackReport), MimoError> {
    lin.validate()?;
    data.validate()?;
    opts.shape.validate()?;
    if data.inputs != lin.inputs || data.outputs != lin.outputs {
        return Err(MimoError::Shape("the periods do not match the model's channels".into()));
    }
    if !(opts.initial_scale.is_finite() && opts.initial_scale > 0.0) {
        return Err(MimoError::Parameter("initial scale of the feedback channels"));
    }
    let ss = lin.linear_part();
    let n = ss.order();
    // Start: the linear model with e = 0 and s from the states' RMS.
    let mut ms: Vec<ModeParams> = ss
        .modes
        .iter()
        .map(|md| match *md {
            Mode::Real(l) => ModeParams::Real(l),
            Mode::Pair { sigma, omega } => ModeParams::Pair { sigma, omega, e: [0.0, 0.0], s: 1.0 },
        })
        .collect();
    let mut prob = Problem { data, b: &ss.b, shape: opts.shape, free: vec![] };
    let sq: Option<Vec<Vec<f64>>> = (0..data.u.len())
        .into_par_iter()
        .map(|r| prob.pass(&ms, r, false).map(|p| (0..n).map(|i| p.phi.column(i).norm_squared()).collect()))
        .collect();
    let sq = sq.ok_or(MimoError::Numerical("simulation of the linear model"))?;
    let rms: Vec<f64> = (0..n)
        .map(|i| (sq.iter().map(|v| v[i]).sum::<f64>() / (data.u.len() * data.samples) as f64).sqrt())
        .collect();
    let mut at = 0;
    for mp in ms.iter_mut() {
        if let ModeParams::Pair { s, .. } = mp {
            *s = (opts.initial_scale * rms[at]).max(1e-300);
        }
        at += mp.size();
    }
    prob.free = ms
        .iter()
        .flat_map(|mp| match mp {
            ModeParams::Real(_) => vec![true],
            ModeParams::Pair { .. } => vec![true, true, true, true, opts.fit_scale],
        })
        .collect();
    let mut ev = prob.evaluate(&ms)?.ok_or(MimoError::Numerical("simulation of the linear model"))?;
    let cost0 = ev.cost;
    let mut th = pack(&ms);
    let npar = th.len();
    let mut mu = 1e-3;
    let mut done = 0;
    for it in 0..opts.iterations {
        let Some((jj, jr)) = prob.normal_equations(&ms, &ev)? else {
            return Err(MimoError::Numerical("sensitivities of the feedback model"));
        };
        done = it + 1;
        let dmax = (0..npar).map(|i| jj[(i, i)]).fold(0.0, f64::max).max(1e-300);
        let mut improved = false;
        while mu < 1e8 {
            let mut a = jj.clone();
            for i in 0..npar {
                a[(i, i)] += mu * jj[(i, i)].max(1e-9 * dmax);
            }
            let Some(step) = a.cholesky().map(|ch| ch.solve(&jr)) else {
                mu *= 10.0;
                continue;
            };
            let trial: Vec<f64> = th.iter().zip(step.iter()).map(|(a, b)| a + b).collect();
            let cand = unpack(&ms, &trial);
            if cand.iter().all(|m| m.radius() < 0.9999) && trial.iter().all(|v| v.is_finite()) {
                if let Some(e2) = prob.evaluate(&cand)? {
                    if e2.cost < ev.cost {
                        let rel = (ev.cost - e2.cost) / ev.cost;
                        th = trial;
                        ms = cand;
                        ev = e2;
                        mu = (mu / 3.0).max(1e-9);
                        improved = rel > 1e-6;
                        break;
                    }
                }
            }
            mu *= 4.0;
        }
        progress(done, ev.cost);
        if !improved {
            break;
        }
    }
    // The model.
    let m = data.inputs;
    let p = data.outputs;
    let mut model = lin.clone();
    model.modes = ms
        .iter()
        .map(|mp| match *mp {
            ModeParams::Real(l) => Mode::Real(l),
            ModeParams::Pair { sigma, omega, .. } => Mode::Pair { sigma, omega },
        })
        .collect();
    model.c = (0..p).flat_map(|o| (0..n).map(move |i| (o, i))).map(|(o, i)| ev.theta[(i, o)]).collect();
    model.d = (0..p).flat_map(|o| (0..m).map(move |c| (o, c))).map(|(o, c)| ev.theta[(n + c, o)]).collect();
    let mut channels = Vec::new();
    let mut cols: Vec<(usize, [f64; 2])> = Vec::new();
    let mut at = 0;
    for mp in &ms {
        if let ModeParams::Pair { e, s, .. } = *mp {
            channels.push(Channel { source: Source::Feedback(at), scale: s, shape: opts.shape });
            cols.push((at, e));
        }
        at += mp.size();
    }
    let q = channels.len();
    let mut e = vec![0.0; n * q];
    for (j, &(i, ej)) in cols.iter().enumerate() {
        e[i * q + j] = ej[0];
        e[(i + 1) * q + j] = ej[1];
    }
    model.branch = Some(Branch { channels, b0: lin.b.clone(), e, f: vec![0.0; p * q] });
    model.validate()?;
    Ok((model, FeedbackReport { cost: (cost0, ev.cost), iterations: done }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mimo::linear::ModalSs;
    use crate::mimo::model::Warmup;

    fn toy() -> (MimoModel, Periods) {
        let ss = ModalSs {
            modes: vec![
                Mode::Pair { sigma: 0.95 * 0.6f64.cos(), omega: 0.95 * 0.6f64.sin() },
                Mode::Real(0.5),
                Mode::Pair { sigma: 0.97 * 1.3f64.cos(), omega: 0.97 * 1.3f64.sin() },
            ],
            b: DMatrix::from_row_slice(5, 2, &[1.0, 0.2, -0.3, 0.5, 0.4, 0.1, 0.2, 0.9, 0.6, -0.4]),
            c: DMatrix::from_row_slice(2, 5, &[0.5, 0.1, 0.3, -0.2, 0.4, 0.2, -0.3, 0.1, 0.6, 0.1]),
            d: DMatrix::from_row_slice(2, 2, &[0.1, 0.0, 0.05, 0.2]),
        };
        let lin = MimoModel::linear(&ss, 1000.0);
        let len = 256;
        let u: Vec<Vec<f64>> = (0..3)
            .map(|r| {
                (0..2 * len)
                    .map(|i| {
                        let k = (i % len) as f64;
                        let c = (i / len) as f64;
                        (1.0 + r as f64) * ((0.37 + 0.1 * c) * k + r as f64).sin()
                            + 0.5 * ((1.1 + 0.2 * c) * k).cos()
                    })
                    .collect()
            })
            .collect();
        let y = vec![vec![0.0; 2 * len]; 3];
        (lin, Periods { inputs: 2, outputs: 2, samples: len, u, y, weight: vec![1.0, 0.5, 1.0] })
    }

    fn params() -> Vec<ModeParams> {
        vec![
            ModeParams::Pair { sigma: 0.95 * 0.6f64.cos(), omega: 0.95 * 0.6f64.sin(), e: [0.3, -0.2], s: 1.5 },
            ModeParams::Real(0.5),
            ModeParams::Pair { sigma: 0.97 * 1.3f64.cos(), omega: 0.97 * 1.3f64.sin(), e: [-0.02, 0.05], s: 0.8 },
        ]
    }

    #[test]
    fn mimo_feedback_sensitivities_match_finite_differences() {
        let (lin, data) = toy();
        let ss = lin.linear_part();
        let shape = Shape { a0: 0.1, gamma: 0.6, beta: 0.4 };
        let prob = Problem { data: &data, b: &ss.b, shape, free: vec![] };
        let ms = params();
        let base = prob.pass(&ms, 1, true).expect("pass");
        let th = pack(&ms);
        let mut j = 0;
        for (bi, mp) in ms.iter().enumerate() {
            for pj in 0..mp.count() {
                let h = 1e-6;
                let mut tp = th.clone();
                tp[j] += h;
                let mut tm = th.clone();
                tm[j] -= h;
                let a = prob.pass(&unpack(&ms, &tp), 1, false).expect("pass");
                let b = prob.pass(&unpack(&ms, &tm), 1, false).expect("pass");
                for st in 0..mp.size() {
                    for k in (0..data.samples).step_by(17) {
                        let fd = (a.runs[bi].x[st][k] - b.runs[bi].x[st][k]) / (2.0 * h);
                        let an = base.runs[bi].dx[pj][st][k];
                        assert!((fd - an).abs() < 1e-5 * (1.0 + an.abs()), "mode {bi} param {pj} state {st} k {k}: {an} vs {fd}");
                    }
                }
                j += 1;
            }
        }
    }

    #[test]
    fn mimo_feedback_model_simulates_as_the_fit_does() {
        let (lin, mut data) = toy();
        let ss = lin.linear_part();
        let shape = Shape::symmetric(0.5);
        // The scales the fit starts from: twice the RMS of the linear model's states.
        let mut ms = params();
        let prob = Problem { data: &data, b: &ss.b, shape, free: vec![] };
        let lin_ms: Vec<ModeParams> = ms
            .iter()
            .map(|mp| match *mp {
                ModeParams::Pair { sigma, omega, s, .. } => ModeParams::Pair { sigma, omega, e: [0.0; 2], s },
                r => r,
            })
            .collect();
        let rms = |i: usize| {
            let ss: f64 = (0..3).map(|r| prob.pass(&lin_ms, r, false).expect("pass").phi.column(i).norm_squared()).sum();
            (ss / (3 * data.samples) as f64).sqrt()
        };
        let scales = [2.0 * rms(0), 2.0 * rms(3)];
        for (mp, sc) in ms.iter_mut().filter(|m| m.size() == 2).zip(scales) {
            if let ModeParams::Pair { s, .. } = mp {
                *s = sc;
            }
        }
        let mut truth = lin.clone();
        let q = 2;
        let mut e = vec![0.0; 5 * q];
        let (ModeParams::Pair { e: e1, .. }, ModeParams::Pair { e: e2, .. }) = (ms[0], ms[2]) else { unreachable!() };
        e[0] = e1[0];
        e[q] = e1[1];
        e[3 * q + 1] = e2[0];
        e[4 * q + 1] = e2[1];
        truth.branch = Some(Branch {
            channels: vec![
                Channel { source: Source::Feedback(0), scale: scales[0], shape },
                Channel { source: Source::Feedback(3), scale: scales[1], shape },
            ],
            b0: truth.b.clone(),
            e,
            f: vec![0.0; 2 * q],
        });
        for r in 0..3 {
            data.y[r] = truth.simulate(&data.u[r], Warmup::Periods(1)).expect("simulation");
        }
        let prob = Problem { data: &data, b: &ss.b, shape, free: vec![] };
        let ev = prob.evaluate(&ms).expect("evaluate").expect("finite");
        let yy: f64 = data.y.iter().flatten().map(|v| v * v).sum();
        assert!(ev.cost < 1e-12 * yy, "the fit's simulation differs from MimoModel::simulate: {}", ev.cost);
        // From the linear model, the fit finds the loop again.
        let opts = FeedbackOptions { iterations: 30, shape, initial_scale: 2.0, fit_scale: true };
        let (fitted, rep) = fit_feedback(&lin, &data, &opts, &|_, _| {}).expect("fit");
        assert!(rep.cost.1 < 1e-8 * rep.cost.0, "{rep:?}");
        let y = fitted.simulate(&data.u[0], Warmup::Periods(1)).expect("simulation");
        let err: f64 = y.iter().zip(&data.y[0]).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
        assert!(err < 1e-8 * rep.cost.0, "{err} {rep:?}");
    }
}
