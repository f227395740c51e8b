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
use super::model::{Branch, Channel, Envelope, MimoModel, Schedule, ScheduledMode, Source};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// Normal equations `(JᵀJ, Jᵀr)` of the free parameters.
type Normal = (DMatrix<f64>, DVector<f64>);

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
    /// A hysteresis channel on each input (the piezo's own hysteresis, Hammerstein):
    /// `u_eff = u + κ_c (s_c h(u/s_c) − u)` drives the modes through `B`.
    pub input_channels: bool,
    /// Initial `s_c` as a multiple of the input's RMS on the data.
    pub input_scale: f64,
    /// The Bouc–Wen restoring force on each mode (otherwise `e_b = 0`).
    pub mode_hysteresis: bool,
    /// Each mode's stiffness scheduled by the inputs' envelope ([`Schedule`]).
    pub schedule: bool,
    /// The envelope's time constant, samples.
    pub envelope_samples: f64,
    /// Stop when an iteration lowers the cost by less than this fraction.
    pub tolerance: f64,
    /// The Gauss–Newton matrix `JᵀJ` from every `stride`-th sample (the gradient `Jᵀr` and
    /// the cost from all): `stride` times less of the fit's largest product.
    pub stride: usize,
}

impl Default for FeedbackOptions {
    fn default() -> Self {
        Self {
            iterations: 20,
            shape: Shape::symmetric(0.5),
            initial_scale: 2.0,
            fit_scale: true,
            input_channels: true,
            input_scale: 2.0,
            mode_hysteresis: true,
            schedule: true,
            envelope_samples: 64.0,
            tolerance: 1e-3,
            stride: 2,
        }
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
    /// `k`: the scheduled stiffness, `[ρ → state 0, ρ → state 1, ρ² → state 0, ρ² → state 1]`.
    Pair {
        sigma: f64,
        omega: f64,
        e: [f64; 2],
        s: f64,
        k: [f64; 4],
    },
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
            Self::Pair { .. } => 9,
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
            ModeParams::Pair { sigma, omega, e, s, k } => {
                th.extend([sigma, omega, e[0], e[1], s.ln()]);
                th.extend(k);
            }
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
                i += 9;
                ModeParams::Pair {
                    sigma: th[i - 9],
                    omega: th[i - 8],
                    e: [th[i - 7], th[i - 6]],
                    s: th[i - 5].exp(),
                    k: [th[i - 4], th[i - 3], th[i - 2], th[i - 1]],
                }
            }
        })
        .collect()
}

/// One mode simulated over the warm-up and the scored period: its states over the scored
/// period and, when asked, their sensitivities to the mode's own parameters, then to the
/// extra forcings.
struct ModeRun {
    /// `[state][k]`.
    x: [Vec<f64>; 2],
    /// Per parameter, `[state][k]`.
    dx: Vec<[Vec<f64>; 2]>,
}

/// A forcing of a tangent: `coef[i]·sig[k]` into state `i` (warm-up and scored period).
struct Forcing<'a> {
    coef: [f64; 2],
    sig: &'a [f64],
}

/// Runs one mode on its drive `bu` (`B_b u`, `[state][k]` over the warm-up and the scored
/// period, `2N`), with the sensitivities to its own parameters (when `grad`) and to `extra`.
#[allow(clippy::needless_range_loop)] // k indexes the input and, past the warm-up, the outputs
fn run_mode(
    mp: &ModeParams,
    bu: &[Vec<f64>; 2],
    rho: &[f64],
    shape: &Shape,
    grad: bool,
    skip: &[bool],
    extra: &[Forcing],
) -> Option<ModeRun> {
    let len = bu[0].len() / 2;
    let own = if grad { mp.count() } else { 0 };
    let nt = own + extra.len();
    let two = mp.size() == 2;
    let mut out = ModeRun {
        x: [vec![0.0; len], if two { vec![0.0; len] } else { Vec::new() }],
        dx: (0..nt).map(|_| [vec![0.0; len], if two { vec![0.0; len] } else { Vec::new() }]).collect(),
    };
    match *mp {
        ModeParams::Real(l) => {
            let mut x = 0.0;
            let mut t = vec![0.0; nt];
            for k in 0..2 * len {
                if k >= len {
                    out.x[0][k - len] = x;
                    for (j, tj) in t.iter().enumerate() {
                        out.dx[j][0][k - len] = *tj;
                    }
                }
                for (j, tj) in t.iter_mut().enumerate() {
                    let f = if j < own { x } else { extra[j - own].coef[0] * extra[j - own].sig[k] };
                    *tj = l * *tj + f;
                }
                x = l * x + bu[0][k];
            }
            x.is_finite().then_some(out)
        }
        ModeParams::Pair { sigma, omega, e, s, k: kk } => {
            let (mut x0, mut x1, mut hv, mut vprev) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
            // Tangent per parameter: (dx0, dx1, dhv, dvprev).
            let mut t = vec![[0.0f64; 4]; nt];
            let inv_s = 1.0 / s;
            for k in 0..2 * len {
                let v = x0 * inv_s;
                let (hn, a_k, b_k) = shape.step_grad(hv, v - vprev);
                let w = hn - v;
                let r = rho[k];
                let (g0, g1) = (kk[0] * r + kk[2] * r * r, kk[1] * r + kk[3] * r * r);
                let scored = k >= len;
                if scored {
                    out.x[0][k - len] = x0;
                    out.x[1][k - len] = x1;
                }
                for (j, tj) in t.iter_mut().enumerate() {
                    if j < own && skip[j] {
                        continue;
                    }
                    let [d0, d1, dh, dvp] = *tj;
                    if scored {
                        out.dx[j][0][k - len] = d0;
                        out.dx[j][1][k - len] = d1;
                    }
                    let dv = d0 * inv_s - if j == 4 && j < own { v } else { 0.0 };
                    let dhn = a_k * dh + b_k * (dv - dvp);
                    let dw = dhn - dv;
                    let (f0, f1) = if j < own {
                        match j {
                            0 => (x0, x1),
                            1 => (x1, -x0),
                            2 => (w, 0.0),
                            3 => (0.0, w),
                            5 => (r * x0, 0.0),
                            6 => (0.0, r * x0),
                            7 => (r * r * x0, 0.0),
                            8 => (0.0, r * r * x0),
                            _ => (0.0, 0.0),
                        }
                    } else {
                        let fx = &extra[j - own];
                        (fx.coef[0] * fx.sig[k], fx.coef[1] * fx.sig[k])
                    };
                    *tj = [
                        sigma * d0 + omega * d1 + e[0] * dw + g0 * d0 + f0,
                        -omega * d0 + sigma * d1 + e[1] * dw + g1 * d0 + f1,
                        dhn,
                        dv,
                    ];
                }
                let n0 = sigma * x0 + omega * x1 + bu[0][k] + e[0] * w + g0 * x0;
                let n1 = -omega * x0 + sigma * x1 + bu[1][k] + e[1] * w + g1 * x0;
                x0 = n0;
                x1 = n1;
                hv = hn;
                vprev = v;
            }
            (x0.is_finite() && x1.is_finite()).then_some(out)
        }
    }
}

/// One input's hysteresis (Hammerstein): `u_eff = u + κ (s·h(u/s) − u)`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct InputParams {
    kappa: f64,
    s: f64,
}

/// All parameters of the loop fit.
#[derive(Clone, Debug, PartialEq)]
struct Params {
    modes: Vec<ModeParams>,
    inputs: Vec<InputParams>,
}

impl Params {
    fn pack(&self) -> Vec<f64> {
        let mut th = pack(&self.modes);
        for ip in &self.inputs {
            th.extend([ip.kappa, ip.s.ln()]);
        }
        th
    }
    fn unpack(&self, th: &[f64]) -> Self {
        let nm: usize = self.modes.iter().map(ModeParams::count).sum();
        let modes = unpack(&self.modes, &th[..nm]);
        let inputs = th[nm..].chunks(2).map(|c| InputParams { kappa: c[0], s: c[1].exp() }).collect();
        Self { modes, inputs }
    }
    fn mode_count(&self) -> usize {
        self.modes.iter().map(ModeParams::count).sum()
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
    /// The scheduling signal.
    envelope: Envelope,
    /// The Gauss–Newton matrix from every `stride`-th sample.
    stride: usize,
}

/// One realisation's pass: regressors and, with a Jacobian, its columns.
struct Pass {
    /// `Φ = [x, u]`, `N × (n + m)`.
    phi: DMatrix<f64>,
    /// Per mode, its run.
    runs: Vec<ModeRun>,
}

/// The input channels over the warm-up and the scored period (`2N`): `u_eff`, and per input
/// `w = s·h(u/s) − u` and `∂w/∂ln s`.
fn input_signals(
    u: &[f64],
    m: usize,
    len: usize,
    inputs: &[InputParams],
    shape: &Shape,
) -> [Vec<Vec<f64>>; 3] {
    let mut ueff = Vec::with_capacity(m);
    let mut ws = Vec::with_capacity(m);
    let mut dws = Vec::with_capacity(m);
    for c in 0..m {
        let uc = &u[c * len..(c + 1) * len];
        let mut ue: Vec<f64> = uc.iter().chain(uc).copied().collect();
        if let Some(ip) = inputs.get(c) {
            let (mut h, mut dh, mut vprev, mut dvprev) = (0.0, 0.0, 0.0, 0.0);
            let mut w = vec![0.0; 2 * len];
            let mut dw = vec![0.0; 2 * len];
            for k in 0..2 * len {
                let x = ue[k];
                let v = x / ip.s;
                let (hn, a_k, b_k) = shape.step_grad(h, v - vprev);
                let dv = -v;
                let dhn = a_k * dh + b_k * (dv - dvprev);
                w[k] = ip.s * hn - x;
                dw[k] = ip.s * (hn + dhn);
                h = hn;
                dh = dhn;
                vprev = v;
                dvprev = dv;
            }
            for (a, b) in ue.iter_mut().zip(&w) {
                *a += ip.kappa * b;
            }
            ws.push(w);
            dws.push(dw);
        }
        ueff.push(ue);
    }
    [ueff, ws, dws]
}

impl Problem<'_> {
    fn pass(&self, pr: &Params, r: usize, grad: bool) -> Option<Pass> {
        let (m, len) = (self.data.inputs, self.data.samples);
        let ms = &pr.modes;
        let n: usize = ms.iter().map(ModeParams::size).sum();
        let u = &self.data.u[r];
        let [ueff, ws, dws] = input_signals(u, m, len, &pr.inputs, &self.shape);
        let rho = self.envelope.rho(u, m, len);
        let kdws: Vec<Vec<f64>> =
            dws.iter().zip(&pr.inputs).map(|(d, ip)| d.iter().map(|v| ip.kappa * v).collect()).collect();
        let mut phi = DMatrix::<f64>::zeros(len, n + m);
        let mut runs = Vec::with_capacity(ms.len());
        let mut at = 0;
        let mut theta_at = 0;
        for mp in ms {
            let sz = mp.size();
            let drive = |i: usize| -> Vec<f64> {
                let mut d = vec![0.0; 2 * len];
                for (c, ue) in ueff.iter().enumerate() {
                    let bic = self.b[(i, c)];
                    if bic != 0.0 {
                        for (dk, uk) in d.iter_mut().zip(ue) {
                            *dk += bic * uk;
                        }
                    }
                }
                d
            };
            let bu = [drive(at), if sz == 2 { drive(at + 1) } else { Vec::new() }];
            let mut extra = Vec::new();
            if grad {
                for c in 0..pr.inputs.len() {
                    let coef = [self.b[(at, c)], if sz == 2 { self.b[(at + 1, c)] } else { 0.0 }];
                    extra.push(Forcing { coef, sig: &ws[c] });
                    extra.push(Forcing { coef, sig: &kdws[c] });
                }
            }
            let skip: Vec<bool> =
                (0..mp.count()).map(|j| !self.free.get(theta_at + j).copied().unwrap_or(true)).collect();
            theta_at += mp.count();
            let run = run_mode(mp, &bu, &rho, &self.shape, grad, &skip, &extra)?;
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
    fn evaluate(&self, pr: &Params) -> Result<Option<Evaluated>, MimoError> {
        let d = self.data;
        let p = d.outputs;
        let len = d.samples;
        let passes: Option<Vec<Pass>> =
            (0..d.u.len()).into_par_iter().map(|r| self.pass(pr, r, false)).collect();
        let Some(passes) = passes else { return Ok(None) };
        let k = passes[0].phi.ncols();
        let mut g = DMatrix::<f64>::zeros(k, k);
        let mut rhs = DMatrix::<f64>::zeros(k, p);
        for (r, ps) in passes.iter().enumerate() {
            let y = DMatrix::from_column_slice(len, p, &d.y[r]);
            let pt = ps.phi.transpose() * d.weight[r];
            g += &pt * &ps.phi;
            rhs += &pt * y;
        }
        let theta = solve_spd(g, &rhs).ok_or(MimoError::Numerical("C, D least squares (time domain)"))?;
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
        Ok(Some(Evaluated { theta, cost }))
    }

    /// The reduced normal equations at `pr` with `(C, D)` = `ev.theta` (rows: states, inputs;
    /// columns: outputs).
    fn normal_equations(&self, pr: &Params, ev: &Evaluated) -> Result<Option<Normal>, MimoError> {
        let d = self.data;
        let (p, len) = (d.outputs, d.samples);
        let nmode = pr.mode_count();
        let npar = nmode + 2 * pr.inputs.len();
        let kk = ev.theta.nrows();
        let free_idx: Vec<usize> = (0..npar).filter(|&i| self.free.get(i).copied().unwrap_or(true)).collect();
        let stride = self.stride.max(1);
        type Part = (DMatrix<f64>, Vec<DMatrix<f64>>, DVector<f64>, DMatrix<f64>);
        let parts: Option<Vec<Part>> = (0..d.u.len())
            .into_par_iter()
            .map(|r| {
                let ps = self.pass(pr, r, true)?;
                let sw = d.weight[r].sqrt();
                let y = DMatrix::from_column_slice(len, p, &d.y[r]);
                let res = (y - &ps.phi * &ev.theta) * sw;
                // J: (p·N) × npar, rows o·N + k.
                let mut jac = DMatrix::<f64>::zeros(p * len, npar);
                let (mut col, mut at) = (0, 0);
                for (mp, run) in pr.modes.iter().zip(&ps.runs) {
                    let sz = mp.size();
                    for (j, dxj) in run.dx.iter().enumerate() {
                        let target = if j < mp.count() { col + j } else { nmode + j - mp.count() };
                        let mut cj = jac.column_mut(target);
                        for o in 0..p {
                            for (i, dxji) in dxj.iter().enumerate().take(sz) {
                                let c = ev.theta[(at + i, o)] * sw;
                                for (v, dv) in cj.rows_mut(o * len, len).iter_mut().zip(dxji) {
                                    *v += c * dv;
                                }
                            }
                        }
                    }
                    col += mp.count();
                    at += sz;
                }
                // Only the free columns; `transpose() *` is the blocked product
                // (matrixmultiply), `tr_mul` is not.
                let jac = jac.select_columns(free_idx.iter());
                let res_flat = DVector::from_column_slice(res.as_slice());
                let jr = jac.tr_mul(&res_flat);
                // The Gauss–Newton matrix from every `stride`-th sample (the gradient from all).
                let rows: Vec<usize> = (0..len).step_by(stride).collect();
                let f = stride as f64;
                let phi_s = ps.phi.select_rows(rows.iter()) * (sw * f.sqrt());
                let all_rows: Vec<usize> =
                    (0..p).flat_map(|o| rows.iter().map(move |&k| o * len + k)).collect();
                let js = jac.select_rows(all_rows.iter()) * f.sqrt();
                let jt = js.transpose();
                let jj = &jt * &js;
                let phi_t = phi_s.transpose();
                let ns = rows.len();
                let mo: Vec<DMatrix<f64>> = (0..p).map(|o| &phi_t * js.rows(o * ns, ns)).collect();
                let gram = &phi_t * &phi_s;
                Some((jj, mo, jr, gram))
            })
            .collect();
        let Some(parts) = parts else { return Ok(None) };
        let nf = free_idx.len();
        let mut jj = DMatrix::<f64>::zeros(nf, nf);
        let mut mo = vec![DMatrix::<f64>::zeros(kk, nf); p];
        let mut jr = DVector::<f64>::zeros(nf);
        let mut gram = DMatrix::<f64>::zeros(kk, kk);
        for (a, b, c, g) in parts {
            jj += a;
            gram += g;
            for (x, y) in mo.iter_mut().zip(b) {
                *x += y;
            }
            jr += c;
        }
        for m in &mo {
            let gm = solve_spd(gram.clone(), m).ok_or(MimoError::Numerical("variable projection"))?;
            jj -= m.transpose() * gm;
        }
        // Back to every parameter: a fixed one gets a unit diagonal and no gradient.
        let mut full = DMatrix::<f64>::identity(npar, npar);
        let mut full_r = DVector::<f64>::zeros(npar);
        for (a, &i) in free_idx.iter().enumerate() {
            full_r[i] = jr[a];
            for (b, &j) in free_idx.iter().enumerate() {
                full[(i, j)] = jj[(a, b)];
            }
        }
        Ok(Some((full, full_r)))
    }
}

struct Evaluated {
    /// `[Cᵀ; Dᵀ]`, `(n + m) × p`.
    theta: DMatrix<f64>,
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
    if !(opts.input_scale.is_finite() && opts.input_scale > 0.0) {
        return Err(MimoError::Parameter("initial scale of the input channels"));
    }
    let ss = lin.linear_part();
    let (n, m) = (ss.order(), data.inputs);
    // Start: the linear model with e = 0, κ = 0 and the scales from the RMS of the states and
    // inputs.
    let mut pr = Params {
        modes: ss
            .modes
            .iter()
            .map(|md| match *md {
                Mode::Real(l) => ModeParams::Real(l),
                Mode::Pair { sigma, omega } => {
                    ModeParams::Pair { sigma, omega, e: [0.0, 0.0], s: 1.0, k: [0.0; 4] }
                }
            })
            .collect(),
        inputs: Vec::new(),
    };
    if !(opts.envelope_samples.is_finite() && opts.envelope_samples >= 0.0) {
        return Err(MimoError::Parameter("the envelope's time constant"));
    }
    let mean_abs =
        data.u.iter().flatten().map(|v| v.abs()).sum::<f64>() / (data.u.len() * data.samples * m) as f64;
    let envelope = Envelope {
        pole: if opts.envelope_samples > 0.0 { (-1.0 / opts.envelope_samples).exp() } else { 0.0 },
        scale: mean_abs.max(1e-300),
    };
    envelope.validate()?;
    let mut prob = Problem { data, b: &ss.b, shape: opts.shape, free: vec![], envelope, stride: opts.stride };
    let sq: Option<Vec<Vec<f64>>> = (0..data.u.len())
        .into_par_iter()
        .map(|r| {
            prob.pass(&pr, r, false).map(|p| (0..n + m).map(|i| p.phi.column(i).norm_squared()).collect())
        })
        .collect();
    let sq = sq.ok_or(MimoError::Numerical("simulation of the linear model"))?;
    let rms: Vec<f64> = (0..n + m)
        .map(|i| (sq.iter().map(|v| v[i]).sum::<f64>() / (data.u.len() * data.samples) as f64).sqrt())
        .collect();
    let mut at = 0;
    for mp in pr.modes.iter_mut() {
        if let ModeParams::Pair { s, .. } = mp {
            *s = (opts.initial_scale * rms[at]).max(1e-300);
        }
        at += mp.size();
    }
    if opts.input_channels {
        pr.inputs = (0..m)
            .map(|c| InputParams { kappa: 0.0, s: (opts.input_scale * rms[n + c]).max(1e-300) })
            .collect();
    }
    prob.free = pr
        .modes
        .iter()
        .flat_map(|mp| match mp {
            ModeParams::Real(_) => vec![true],
            ModeParams::Pair { .. } => {
                let (h, k) = (opts.mode_hysteresis, opts.schedule);
                vec![true, true, h, h, h && opts.fit_scale, k, k, k, k]
            }
        })
        .chain(pr.inputs.iter().flat_map(|_| [true, opts.fit_scale]))
        .collect();
    let mut ev = prob.evaluate(&pr)?.ok_or(MimoError::Numerical("simulation of the linear model"))?;
    let cost0 = ev.cost;
    let mut th = pr.pack();
    let npar = th.len();
    // The scales stay within e^±6 of their start (beyond, a channel is linear or a relay).
    let mut bounds = vec![(f64::NEG_INFINITY, f64::INFINITY); npar];
    let mut at = 0;
    for mp in &pr.modes {
        if let ModeParams::Pair { s, .. } = mp {
            bounds[at + 4] = (s.ln() - 6.0, s.ln() + 6.0);
        }
        at += mp.count();
    }
    for ip in &pr.inputs {
        bounds[at + 1] = (ip.s.ln() - 6.0, ip.s.ln() + 6.0);
        at += 2;
    }
    let mut mu = 1e-3;
    let mut done = 0;
    for it in 0..opts.iterations {
        let Some((jj, jr)) = prob.normal_equations(&pr, &ev)? else {
            return Err(MimoError::Numerical("sensitivities of the feedback model"));
        };
        done = it + 1;
        let dmax = (0..npar).filter(|&i| prob.free[i]).map(|i| jj[(i, i)]).fold(0.0, f64::max).max(1e-300);
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
            let trial: Vec<f64> = th
                .iter()
                .zip(step.iter())
                .zip(&bounds)
                .map(|((a, b), &(lo, hi))| (a + b).clamp(lo, hi))
                .collect();
            let cand = pr.unpack(&trial);
            if cand.modes.iter().all(|m| m.radius() < 0.9999) && trial.iter().all(|v| v.is_finite()) {
                if let Some(e2) = prob.evaluate(&cand)? {
                    if e2.cost < ev.cost {
                        let rel = (ev.cost - e2.cost) / ev.cost;
                        th = trial;
                        pr = cand;
                        ev = e2;
                        mu = (mu / 3.0).max(1e-9);
                        improved = rel > opts.tolerance;
                        break;
                    }
                }
            }
            mu *= 4.0;
            if std::env::var("FB_DEBUG").is_ok() {
                eprintln!("  rejected, mu {mu:.2e}");
            }
        }
        if std::env::var("FB_DEBUG").is_ok() {
            eprintln!("  mu {mu:.2e}");
        }
        progress(done, ev.cost);
        if !improved {
            break;
        }
    }
    let model =
        assemble(lin, &pr, &ev.theta, &opts.shape, opts.mode_hysteresis, opts.schedule.then_some(envelope))?;
    Ok((model, FeedbackReport { cost: (cost0, ev.cost), iterations: done }))
}

/// The [`MimoModel`] of fitted parameters: `B·diag(1 − κ)` and an input channel with the
/// column `κ_c s_c B_c` of `E` per input, a feedback channel per pair of poles.
fn assemble(
    lin: &MimoModel,
    pr: &Params,
    theta: &DMatrix<f64>,
    shape: &Shape,
    mode_hysteresis: bool,
    envelope: Option<Envelope>,
) -> Result<MimoModel, MimoError> {
    let (n, m, p) = (lin.order(), lin.inputs, lin.outputs);
    let mut model = lin.clone();
    model.modes = pr
        .modes
        .iter()
        .map(|mp| match *mp {
            ModeParams::Real(l) => Mode::Real(l),
            ModeParams::Pair { sigma, omega, .. } => Mode::Pair { sigma, omega },
        })
        .collect();
    model.c = (0..p).flat_map(|o| (0..n).map(move |i| (o, i))).map(|(o, i)| theta[(i, o)]).collect();
    model.d = (0..p).flat_map(|o| (0..m).map(move |c| (o, c))).map(|(o, c)| theta[(n + c, o)]).collect();
    let mut channels = Vec::new();
    // Per channel, its column of E.
    let mut cols: Vec<Vec<f64>> = Vec::new();
    for (c, ip) in pr.inputs.iter().enumerate() {
        channels.push(Channel { source: Source::Input(c), scale: ip.s, shape: *shape });
        cols.push((0..n).map(|i| ip.kappa * ip.s * lin.b[i * m + c]).collect());
        for i in 0..n {
            model.b[i * m + c] = lin.b[i * m + c] * (1.0 - ip.kappa);
        }
    }
    let mut at = 0;
    let mut scheduled = Vec::new();
    for mp in &pr.modes {
        if let ModeParams::Pair { e, s, k, .. } = *mp {
            if mode_hysteresis {
                channels.push(Channel { source: Source::Feedback(at), scale: s, shape: *shape });
                let mut col = vec![0.0; n];
                col[at] = e[0];
                col[at + 1] = e[1];
                cols.push(col);
            }
            scheduled.push(ScheduledMode { state: at, k });
        }
        at += mp.size();
    }
    let q = channels.len();
    let e = (0..n).flat_map(|i| cols.iter().map(move |col| col[i])).collect();
    model.branch = (q > 0).then(|| Branch { channels, b0: lin.b.clone(), e, f: vec![0.0; p * q] });
    model.schedule = envelope.map(|envelope| Schedule { envelope, modes: scheduled });
    model.validate()?;
    Ok(model)
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

    /// The envelope the fit makes for `data` with the default options.
    fn env(data: &Periods) -> Envelope {
        let mean_abs =
            data.u.iter().flatten().map(|v| v.abs()).sum::<f64>() / (data.u.len() * data.u[0].len()) as f64;
        Envelope { pole: (-1.0f64 / FeedbackOptions::default().envelope_samples).exp(), scale: mean_abs }
    }

    fn params() -> Params {
        Params {
            modes: vec![
                ModeParams::Pair {
                    sigma: 0.95 * 0.6f64.cos(),
                    omega: 0.95 * 0.6f64.sin(),
                    e: [0.3, -0.2],
                    s: 1.5,
                    k: [0.01, -0.02, 0.005, 0.003],
                },
                ModeParams::Real(0.5),
                ModeParams::Pair {
                    sigma: 0.97 * 1.3f64.cos(),
                    omega: 0.97 * 1.3f64.sin(),
                    e: [-0.02, 0.05],
                    s: 0.8,
                    k: [-0.01, 0.015, 0.002, -0.004],
                },
            ],
            inputs: vec![InputParams { kappa: 0.2, s: 1.2 }, InputParams { kappa: -0.1, s: 0.7 }],
        }
    }

    #[test]
    fn mimo_feedback_sensitivities_match_finite_differences() {
        let (lin, data) = toy();
        let ss = lin.linear_part();
        let shape = Shape { a0: 0.1, gamma: 0.6, beta: 0.4 };
        let prob = Problem { data: &data, b: &ss.b, shape, free: vec![], envelope: env(&data), stride: 1 };
        let pr = params();
        let base = prob.pass(&pr, 1, true).expect("pass");
        let th = pr.pack();
        let nmode = pr.mode_count();
        for j in 0..th.len() {
            let h = 1e-6;
            let mut tp = th.clone();
            tp[j] += h;
            let mut tm = th.clone();
            tm[j] -= h;
            let a = prob.pass(&pr.unpack(&tp), 1, false).expect("pass");
            let b = prob.pass(&pr.unpack(&tm), 1, false).expect("pass");
            let mut off = 0;
            for (bi, mp) in pr.modes.iter().enumerate() {
                let an_idx = if j >= nmode {
                    Some(mp.count() + j - nmode)
                } else if (off..off + mp.count()).contains(&j) {
                    Some(j - off)
                } else {
                    None
                };
                for st in 0..mp.size() {
                    for k in (0..data.samples).step_by(17) {
                        let fd = (a.runs[bi].x[st][k] - b.runs[bi].x[st][k]) / (2.0 * h);
                        let an = an_idx.map_or(0.0, |i| base.runs[bi].dx[i][st][k]);
                        assert!(
                            (fd - an).abs() < 1e-4 * (1.0 + an.abs()),
                            "θ {j} mode {bi} state {st} k {k}: {an} vs {fd}"
                        );
                    }
                }
                off += mp.count();
            }
        }
    }

    #[test]
    fn mimo_feedback_model_simulates_as_the_fit_does() {
        let (lin, mut data) = toy();
        let ss = lin.linear_part();
        let shape = Shape::symmetric(0.5);
        // The truth: the scales the fit starts from (twice the RMS of the linear model's
        // states and of the inputs), known e and κ.
        let mut pr = params();
        let prob = Problem { data: &data, b: &ss.b, shape, free: vec![], envelope: env(&data), stride: 1 };
        let lin_pr = Params {
            modes: pr
                .modes
                .iter()
                .map(|mp| match *mp {
                    ModeParams::Pair { sigma, omega, s, .. } => {
                        ModeParams::Pair { sigma, omega, e: [0.0; 2], s, k: [0.0; 4] }
                    }
                    r => r,
                })
                .collect(),
            inputs: vec![],
        };
        let rms = |i: usize| {
            let ss: f64 = (0..3)
                .map(|r| prob.pass(&lin_pr, r, false).expect("pass").phi.column(i).norm_squared())
                .sum();
            (ss / (3 * data.samples) as f64).sqrt()
        };
        let scales = [2.0 * rms(0), 2.0 * rms(3)];
        for (mp, sc) in pr.modes.iter_mut().filter(|m| m.size() == 2).zip(scales) {
            if let ModeParams::Pair { s, .. } = mp {
                *s = sc;
            }
        }
        for (c, ip) in pr.inputs.iter_mut().enumerate() {
            let ms: f64 = data
                .u
                .iter()
                .map(|u| u[c * data.samples..(c + 1) * data.samples].iter().map(|v| v * v).sum::<f64>())
                .sum();
            ip.s = 2.0 * (ms / (3 * data.samples) as f64).sqrt();
        }
        let mut theta = DMatrix::zeros(7, 2);
        for o in 0..2 {
            for i in 0..5 {
                theta[(i, o)] = ss.c[(o, i)];
            }
            for c in 0..2 {
                theta[(5 + c, o)] = ss.d[(o, c)];
            }
        }
        let truth = assemble(&lin, &pr, &theta, &shape, true, Some(env(&data))).expect("model");
        for r in 0..3 {
            data.y[r] = truth.simulate(&data.u[r], Warmup::Periods(1)).expect("simulation");
        }
        let prob = Problem { data: &data, b: &ss.b, shape, free: vec![], envelope: env(&data), stride: 1 };
        let ev = prob.evaluate(&pr).expect("evaluate").expect("finite");
        let yy: f64 = data.y.iter().flatten().map(|v| v * v).sum();
        assert!(ev.cost < 1e-12 * yy, "the fit's simulation differs from MimoModel::simulate: {}", ev.cost);
        // From the linear model, the fit finds the loop again.
        let opts = FeedbackOptions { iterations: 40, shape, tolerance: 1e-9, ..FeedbackOptions::default() };
        let (fitted, rep) = fit_feedback(&lin, &data, &opts, &|_, _| {}).expect("fit");
        assert!(rep.cost.1 < 1e-8 * rep.cost.0, "{rep:?}");
        let y = fitted.simulate(&data.u[0], Warmup::Periods(1)).expect("simulation");
        let err: f64 = y.iter().zip(&data.y[0]).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
        assert!(err < 1e-8 * rep.cost.0, "{err} {rep:?}");
    }
}
