//! Identification on the host: the paper's RLS procedure and an output-error fit.
//!
//! Both produce a [`HostModel`]: the extended model (AR order 2, eq. 9's form) plus
//! harmonic branches of the drive (eqs. 6/7) and, for `diagnose`, an optional drift term
//! (a polynomial in time added at the output). Models are simulated by the core's own
//! [`EnhancedParams::step`], so what is fitted here is exactly what the compensator and
//! the firmware run.
//!
//! ## The paper's procedure ([`fit_paper_rls`])
//! Section 3 as published: running-sum regressors (eq. 10), `P(0) = I`, no forgetting,
//! `A1 = 0.01, A = 0.005, γ = β = 0.001` at the start, one pass over the fitting data
//! ([`boucwen_core::ident::Mode::Paper`]). It minimises the one-step (equation) error, not
//! the free-run error the paper reports, and its `A1`/`A` pair is collinear (see the core's
//! docs).
//!
//! ## Output-error fit ([`fit_oe`])
//! Minimises the free-run simulation error directly. By the homogeneity of the Bouc–Wen
//! equation, `h(A, A0, γ, β) = A·h₁` with `h₁` the hysteresis of `A = 1`, `A0/A`, `γ', β`
//! (`γ' = sgn(A)·γ`), so for fixed *outer* parameters `φ = (a1, a2, A0/A, γ', β)` the output
//! ```text
//! ŷ = G(z)·[A1·u - A·h₁ + Σ_n (α_s sin nθ + α_c cos nθ)] + drift(t),   G = 1/(1 - a1 z⁻¹ - a2 z⁻²)
//! ```
//! is linear in `(A1, A, α, drift)`: they are solved exactly by least squares for every `φ`
//! (variable projection), and `φ` is found by a coarse grid (AR resonance, loop saturation)
//! followed by Levenberg–Marquardt. Unstable AR parts are rejected.

use crate::analysis;
use boucwen_core::ident::{IdentConfig, Identifier};
use boucwen_core::model::{
    BoucWenParams, EnhancedParams, ExtendedParams, HarmonicBranch, Model, ar_is_stable,
};
use boucwen_core::signal::{Oscillator, sin_cos};
use nalgebra::{DMatrix, DVector};
use std::fmt;

/// A harmonic branch of a host model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Branch {
    /// Harmonic order `n ≥ 2`.
    pub order: u32,
    /// Weight of `sin(2π n f k Ts)`.
    pub alpha_s: f64,
    /// Weight of `cos(2π n f k Ts)`.
    pub alpha_c: f64,
    /// The branch's AR part (`Q = 2`; zero except in the paper's RLS procedure).
    pub ar: [f64; 2],
}

/// A model identified on the host.
#[derive(Clone, Debug, PartialEq)]
pub struct HostModel {
    /// The extended model (`P = 2`).
    pub ext: ExtendedParams<f64, 2>,
    /// Drive frequency `f` of the branches (Hz).
    pub drive_hz: f64,
    /// Harmonic branches.
    pub branches: Vec<Branch>,
    /// Drift: coefficients of `1, t, t², …` (t in s from the record's start) added to the output.
    pub drift: Vec<f64>,
    /// Input delay `τ` (samples, ≥ 0, fractional): the model is driven by `u` delayed by `τ`
    /// (linear interpolation between samples). 0 is the paper's form; a sampled actuator
    /// (zero-order hold, driver, transport) applies its input later than the paper's
    /// instantaneous `A1·u[k]`, and `τ` says by how much. The compensator compensates it by
    /// preview ([`boucwen_core::compensator::Compensator::step_previewed`]).
    pub delay: f64,
}

/// `u` delayed by `delay` samples (linear interpolation, zero before the start).
pub fn delayed(u: &[f64], delay: f64) -> Vec<f64> {
    if delay <= 0.0 {
        return u.to_vec();
    }
    let m = delay.floor() as usize;
    let frac = delay - m as f64;
    let at = |i: isize| if i < 0 { 0.0 } else { u.get(i as usize).copied().unwrap_or(0.0) };
    (0..u.len() as isize).map(|k| (1.0 - frac) * at(k - m as isize) + frac * at(k - m as isize - 1)).collect()
}

/// Why a fit failed.
#[derive(Clone, Debug, PartialEq)]
pub enum FitError {
    /// Fewer samples than the fit needs.
    TooFewSamples {
        /// Samples available for fitting.
        have: usize,
        /// Samples needed.
        need: usize,
    },
    /// A harmonic at or above Nyquist, or an order below 2.
    BadHarmonic(u32),
    /// More branches than supported.
    TooManyBranches(usize),
    /// A core error (parameters, frequencies).
    Core(boucwen_core::Error),
    /// No candidate gave a stable model that could be solved.
    NoStableModel,
}

impl fmt::Display for FitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FitError::TooFewSamples { have, need } => {
                write!(f, "too few samples to fit: {have} available, at least {need} needed")
            }
            FitError::BadHarmonic(n) => write!(f, "harmonic order {n} is below 2 or at/above Nyquist"),
            FitError::TooManyBranches(m) => {
                write!(f, "{m} harmonic branches: at most {MAX_BRANCHES} are supported")
            }
            FitError::Core(e) => write!(f, "{e}"),
            FitError::NoStableModel => write!(f, "no stable model fits the data"),
        }
    }
}

impl std::error::Error for FitError {}

impl From<boucwen_core::Error> for FitError {
    fn from(e: boucwen_core::Error) -> Self {
        FitError::Core(e)
    }
}

/// The most branches a host model may have.
pub const MAX_BRANCHES: usize = 4;

impl HostModel {
    /// The number of free parameters (AR, hysteresis, branch weights and AR, drift).
    pub fn parameter_count(&self) -> usize {
        7 + self.branches.iter().map(|b| if b.ar == [0.0, 0.0] { 2 } else { 4 }).sum::<usize>()
            + self.drift.len()
    }

    /// A short name: "extended", "enhanced(3)", "extended+offset" (a constant output
    /// offset), "enhanced(3)+drift" (an offset and a trend), ….
    pub fn name(&self) -> String {
        let mut s = if self.branches.is_empty() {
            "extended".to_string()
        } else {
            let orders: Vec<String> = self.branches.iter().map(|b| b.order.to_string()).collect();
            format!("enhanced({})", orders.join(","))
        };
        if self.drift.len() == 1 {
            s.push_str("+offset");
        } else if self.drift.len() > 1 {
            s.push_str("+drift");
        }
        s
    }

    fn enhanced<const M: usize>(&self, ts: f64) -> Result<EnhancedParams<f64, 2, 2, M>, FitError> {
        let drive = Oscillator::new(self.drive_hz, ts)?;
        Ok(EnhancedParams {
            base: self.ext,
            branches: core::array::from_fn(|m| {
                let b = &self.branches[m];
                HarmonicBranch { order: b.order, alpha_s: b.alpha_s, alpha_c: b.alpha_c, ar: b.ar }
            }),
            drive,
        })
    }

    /// The model with one branch as a core enhanced model (tests).
    #[cfg(test)]
    pub(crate) fn enhanced_for_test(&self) -> EnhancedParams<f64, 2, 2, 1> {
        self.enhanced::<1>(1e-3).expect("valid test model")
    }

    /// Free-run simulation from rest (`h = 0`, past outputs 0, phase 0) for the input `u`.
    /// An unstable model's output grows without bound; it is returned as computed.
    pub fn simulate(&self, u: &[f64], ts: f64) -> Result<Vec<f64>, FitError> {
        fn run<const M: usize>(m: &HostModel, u: &[f64], ts: f64) -> Result<Vec<f64>, FitError> {
            let p = m.enhanced::<M>(ts)?;
            let mut s = p.initial_state();
            Ok(u.iter().map(|&uk| p.step(&mut s, uk)).collect())
        }
        let ud = delayed(u, self.delay);
        let u = ud.as_slice();
        let mut y = match self.branches.len() {
            0 => run::<0>(self, u, ts)?,
            1 => run::<1>(self, u, ts)?,
            2 => run::<2>(self, u, ts)?,
            3 => run::<3>(self, u, ts)?,
            4 => run::<4>(self, u, ts)?,
            m => return Err(FitError::TooManyBranches(m)),
        };
        if !self.drift.is_empty() {
            for (k, v) in y.iter_mut().enumerate() {
                *v += poly(&self.drift, k as f64 * ts);
            }
        }
        Ok(y)
    }
}

fn poly(c: &[f64], t: f64) -> f64 {
    c.iter().rev().fold(0.0, |acc, &ci| acc * t + ci)
}

/// What to fit.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelSpec {
    /// Drive frequency (needed for branches).
    pub drive_hz: f64,
    /// Orders of the harmonic branches (empty: the extended model).
    pub harmonics: Vec<u32>,
    /// Degree of the drift polynomial (`None`: no drift term).
    pub drift_degree: Option<usize>,
}

impl ModelSpec {
    /// The extended model.
    pub fn extended(drive_hz: f64) -> Self {
        Self { drive_hz, harmonics: vec![], drift_degree: None }
    }

    /// The enhanced model with the given branches.
    pub fn enhanced(drive_hz: f64, harmonics: &[u32]) -> Self {
        Self { drive_hz, harmonics: harmonics.to_vec(), drift_degree: None }
    }

    fn check(&self, ts: f64) -> Result<(), FitError> {
        if self.harmonics.len() > MAX_BRANCHES {
            return Err(FitError::TooManyBranches(self.harmonics.len()));
        }
        for &n in &self.harmonics {
            if n < 2 || n as f64 * self.drive_hz >= 0.5 / ts {
                return Err(FitError::BadHarmonic(n));
            }
        }
        Oscillator::new(self.drive_hz, ts)?;
        Ok(())
    }
}

/// The paper's section 3 identification: one pass of RLS with the running-sum regressors
/// over `u[..fit_end]`, `y[..fit_end]`. At most one branch (the paper's models (6)/(7),
/// branch AR order 2 on `y_n[k-1], y_n[k-2]`).
pub fn fit_paper_rls(
    u: &[f64],
    y: &[f64],
    ts: f64,
    fit_end: usize,
    spec: &ModelSpec,
) -> Result<HostModel, FitError> {
    spec.check(ts)?;
    let need = 100;
    if fit_end < need || u.len() < fit_end || y.len() < fit_end {
        return Err(FitError::TooFewSamples { have: fit_end.min(u.len()).min(y.len()), need });
    }
    let drive = Oscillator::new(spec.drive_hz, ts)?;
    let (ext, branches) = match spec.harmonics.as_slice() {
        [] => {
            let mut id = Identifier::<f64, 2, 0, 0, 7>::new(IdentConfig::paper::<2>(), drive, [])?;
            for k in 0..fit_end {
                id.update(u[k], y[k])?;
            }
            (id.extended(), vec![])
        }
        [n] => {
            let mut id = Identifier::<f64, 2, 2, 1, 11>::new(IdentConfig::paper::<2>(), drive, [*n])?;
            for k in 0..fit_end {
                id.update(u[k], y[k])?;
            }
            let e = id.enhanced();
            let b = e.branches[0];
            (e.base, vec![Branch { order: b.order, alpha_s: b.alpha_s, alpha_c: b.alpha_c, ar: b.ar }])
        }
        more => return Err(FitError::TooManyBranches(more.len())),
    };
    Ok(HostModel { ext, drive_hz: spec.drive_hz, branches, drift: vec![], delay: 0.0 })
}

impl HostModel {
    /// The loop shape `[A0/A, γ', β]` (`γ' = sgn(A)·γ`) of the output-error parametrisation.
    pub fn shape(&self) -> Option<[f64; 3]> {
        let a = self.ext.bw.a;
        (a != 0.0).then(|| [self.ext.bw.a0 / a, a.signum() * self.ext.bw.gamma, self.ext.bw.beta])
    }
}

/// Options of the output-error fit.
#[derive(Clone, Debug, PartialEq)]
pub struct OeOptions {
    /// At most this many samples (from the start) enter the criterion; the fit simulates
    /// from sample 0 to the end of that window.
    pub max_samples: usize,
    /// Samples at the start left out of the criterion (start-up transient).
    pub skip: usize,
    /// Levenberg–Marquardt iterations per start.
    pub max_iter: usize,
    /// Levenberg–Marquardt starts: the best this many (at least 1) of the grid's candidates
    /// and the given start models.
    pub lm_starts: usize,
    /// A known structure (AR part, e.g. from a broadband record): the search over
    /// resonances is skipped and the fit refines from this structure. A record at one drive
    /// frequency pins only one complex gain of the structure, so without it the structure of
    /// a single-sine fit is whatever reproduces that record best, physical or not.
    pub structure: Option<[f64; 2]>,
    /// Keep the given structure fixed (fit only the loop, gains, branches and drift). A
    /// single-sine record lets a free structure bend to absorb harmonics it does not cause
    /// (moving its resonance far away), which helps that record's fit and ruins the model's
    /// inverse; a model meant for compensation keeps the measured structure.
    pub fix_structure: bool,
    /// Accept only models whose loop is invertible: on both branches and over the operating
    /// range of `h` (see [`operating_slope`]), the slope of `A1·u - h` stays above
    /// [`MIN_SLOPE`]·`A1` > 0 (a bimorph's deflection rises with voltage on each branch). The
    /// direct inverse (eqs. 16/17) needs it, and it drives the model along paths near but not
    /// on the fitted one; a free fit may reach a locally decreasing loop that reproduces a
    /// record as well.
    pub require_invertible: bool,
    /// A known loop shape `[A0/A, γ, β]` (e.g. from a quasi-static record): with a fixed
    /// structure too, nothing nonlinear is left and the fit is one linear least-squares
    /// solve for the gains `A1`, `A`, the branch weights and the drift.
    pub shape: Option<[f64; 3]>,
    /// The input delay `τ` (samples) to use, or to start from when `fit_delay` (`None`: 0).
    /// With `fix_structure` the delay counts as part of the structure and stays fixed.
    pub delay: Option<f64>,
    /// Fit the delay (from a small grid, then with the other outer parameters). A record at
    /// one frequency cannot tell a delay from the structure's phase; a broadband one can.
    pub fit_delay: bool,
    /// Fit a linear model (no hysteresis: `A = 0`), e.g. to a small-amplitude broadband
    /// record that characterises the structure and the delay.
    pub linear: bool,
}

/// The smallest slope of `A1·u - h` over the operating range of `h`: the range `[lo, hi]` a
/// record reached, widened by half its width on each side (room for the compensator's
/// excursions) and capped at the loop's saturation range. `None` when `h` is unbounded.
pub fn operating_slope(bw: &BoucWenParams<f64>, lo: f64, hi: f64) -> Option<f64> {
    let (sat_lo, sat_hi) = bw.h_range()?;
    let margin = 0.5 * (hi - lo);
    Some(bw.min_output_slope_over((lo - margin).max(sat_lo), (hi + margin).min(sat_hi)))
}

/// Whether `model` is invertible on the operating range its hysteresis reaches for the
/// input `u` (see [`operating_slope`]), with the margin [`MIN_SLOPE`].
pub fn invertible_for(model: &HostModel, u: &[f64]) -> bool {
    let bw = &model.ext.bw;
    let mut s = boucwen_core::model::HysteresisState::default();
    let (mut lo, mut hi) = (0.0f64, 0.0f64);
    for &uk in &delayed(u, model.delay) {
        let h = s.step(bw, uk);
        lo = lo.min(h);
        hi = hi.max(h);
    }
    bw.a1 > 0.0 && operating_slope(bw, lo, hi).is_some_and(|m| m >= MIN_SLOPE * bw.a1)
}

/// Smallest branch slope of `A1·u - h`, relative to `A1`, of an invertible model.
pub const MIN_SLOPE: f64 = 0.05;

impl Default for OeOptions {
    fn default() -> Self {
        Self {
            max_samples: 4000,
            skip: 200,
            max_iter: 40,
            lm_starts: 3,
            structure: None,
            fix_structure: false,
            require_invertible: true,
            shape: None,
            delay: None,
            fit_delay: false,
            linear: false,
        }
    }
}

/// The outer parameters: AR (a1, a2), the loop shape (A0/A, γ', β) and the input delay τ.
type Phi = [f64; 6];

/// Largest input delay the fit considers (samples).
pub const MAX_DELAY: f64 = 3.0;

struct Problem<'a> {
    require_invertible: bool,
    linear: bool,
    u: &'a [f64],
    y: &'a [f64],
    ts: f64,
    end: usize,
    skip: usize,
    spec: &'a ModelSpec,
    /// sin/cos of each branch, sample by sample.
    branch_sc: Vec<Vec<(f64, f64)>>,
}

struct Solution {
    theta: DVector<f64>,
    residual: Vec<f64>,
    cost: f64,
}

impl<'a> Problem<'a> {
    fn new(
        u: &'a [f64],
        y: &'a [f64],
        ts: f64,
        end: usize,
        skip: usize,
        spec: &'a ModelSpec,
    ) -> Result<Self, FitError> {
        let drive = Oscillator::new(spec.drive_hz, ts)?;
        let branch_sc = spec
            .harmonics
            .iter()
            .map(|&n| {
                (0..end).map(|k| sin_cos::<f64>(drive.phase_at(k as u64).wrapping_mul(n as u64))).collect()
            })
            .collect();
        Ok(Self { require_invertible: false, linear: false, u, y, ts, end, skip, spec, branch_sc })
    }

    fn columns(&self) -> usize {
        2 - usize::from(self.linear)
            + 2 * self.spec.harmonics.len()
            + self.spec.drift_degree.map_or(0, |d| d + 1)
    }

    /// Projected solution for `φ`, or `None` if `φ` gives an unstable or degenerate model.
    fn solve(&self, phi: &Phi) -> Option<Solution> {
        let (a1, a2) = (phi[0], phi[1]);
        if !ar_is_stable(&[a1, a2]) || !(0.0..=MAX_DELAY).contains(&phi[5]) {
            return None;
        }
        let (dm, dfrac) = (phi[5].floor() as usize, phi[5] - phi[5].floor());
        let u_at = |i: usize| if i < self.u.len() { self.u[i] } else { 0.0 };
        let shape = BoucWenParams { a1: 0.0, a: 1.0, a0: phi[2], gamma: phi[3], beta: phi[4] };
        let ncol = self.columns();
        let n = self.end;
        // Filtered columns, built sample by sample: G·u, -G·h₁, G·sin, G·cos, drift basis.
        let mut z1 = vec![0.0; ncol];
        let mut z2 = vec![0.0; ncol];
        let mut xtx = DMatrix::<f64>::zeros(ncol, ncol);
        let mut xty = DVector::<f64>::zeros(ncol);
        let mut rows: Vec<f64> = Vec::with_capacity((n - self.skip) * ncol);
        let (mut h, mut u_prev) = (0.0, 0.0);
        let (mut h_lo, mut h_hi) = (0.0f64, 0.0f64);
        let mut x = vec![0.0; ncol];

        for k in 0..n {
            // The delayed input (linear interpolation between samples).
            let uk = (1.0 - dfrac) * if k >= dm { u_at(k - dm) } else { 0.0 }
                + dfrac * if k > dm { u_at(k - dm - 1) } else { 0.0 };
            let mut c = 0;
            x[c] = uk;
            c += 1;
            if !self.linear {
                h = shape.h_next(h, uk - u_prev);
                if !h.is_finite() || h.abs() > 1e12 {
                    return None;
                }
                h_lo = h_lo.min(h);
                h_hi = h_hi.max(h);
                x[c] = -h;
                c += 1;
            }
            for sc in &self.branch_sc {
                x[c] = sc[k].0;
                x[c + 1] = sc[k].1;
                c += 2;
            }
            let nfilt = c;
            for i in 0..nfilt {
                let v = a1 * z1[i] + a2 * z2[i] + x[i];
                z2[i] = z1[i];
                z1[i] = v;
            }
            if let Some(d) = self.spec.drift_degree {
                let t = k as f64 * self.ts;
                let mut p = 1.0;
                for _ in 0..=d {
                    z1[c] = p;
                    p *= t;
                    c += 1;
                }
            }
            u_prev = uk;
            if k >= self.skip {
                let yk = self.y[k];
                for i in 0..ncol {
                    let zi = z1[i];
                    xty[i] += zi * yk;
                    for j in 0..=i {
                        xtx[(i, j)] += zi * z1[j];
                    }
                }
                rows.extend_from_slice(&z1[..ncol]);
            }
        }
        for i in 0..ncol {
            for j in 0..i {
                xtx[(j, i)] = xtx[(i, j)];
            }
        }
        // Tiny ridge relative to the diagonal keeps a nearly collinear column harmless.
        let scale = (0..ncol).map(|i| xtx[(i, i)]).fold(0.0, f64::max);
        for i in 0..ncol {
            xtx[(i, i)] += 1e-12 * scale + 1e-300;
        }
        let mut theta = xtx.clone().cholesky()?.solve(&xty);
        if !self.linear && theta[1] < 0.0 {
            // The loop's amplitude A is physically ≥ 0: the constrained optimum then lies on
            // A = 0 (one bound, so this is the exact non-negative least-squares solution).
            let mut reduced = xtx.clone();
            let mut rhs = xty.clone();
            for j in 0..ncol {
                reduced[(1, j)] = 0.0;
                reduced[(j, 1)] = 0.0;
            }
            reduced[(1, 1)] = 1.0;
            rhs[1] = 0.0;
            theta = reduced.cholesky()?.solve(&rhs);
        }
        if theta.iter().any(|t| !t.is_finite()) {
            return None;
        }
        if self.require_invertible {
            // Over the whole range h can reach, not only the fitted trajectory: the inverse
            // drives the model along other paths. A negative A is a non-physical loop.
            let (a1, amp) = (theta[0], if self.linear { 0.0 } else { theta[1] });
            let bw = BoucWenParams { a1, a: amp, a0: phi[2] * amp, gamma: phi[3], beta: phi[4] };
            let ok = a1 > 0.0
                && amp >= 0.0
                && operating_slope(&bw, amp * h_lo, amp * h_hi).is_some_and(|m| m >= MIN_SLOPE * a1);
            if !ok {
                return None;
            }
        }
        let mut residual = Vec::with_capacity(n - self.skip);
        let mut cost = 0.0;
        for (r, k) in rows.chunks_exact(ncol).zip(self.skip..n) {
            let e = self.y[k] - r.iter().zip(theta.iter()).map(|(a, b)| a * b).sum::<f64>();
            cost += e * e;
            residual.push(e);
        }
        Some(Solution { theta, residual, cost })
    }

    fn model(&self, phi: &Phi, theta: &DVector<f64>) -> HostModel {
        let a1_gain = theta[0];
        let (amp, mut c) = if self.linear { (0.0, 1) } else { (theta[1], 2) };
        let sgn = if amp < 0.0 { -1.0 } else { 1.0 };
        let ext = ExtendedParams {
            bw: BoucWenParams { a1: a1_gain, a: amp, a0: phi[2] * amp, gamma: sgn * phi[3], beta: phi[4] },
            ar: [phi[0], phi[1]],
        };
        let mut branches = vec![];
        for &order in &self.spec.harmonics {
            branches.push(Branch { order, alpha_s: theta[c], alpha_c: theta[c + 1], ar: [0.0, 0.0] });
            c += 2;
        }
        let drift = match self.spec.drift_degree {
            Some(d) => (0..=d).map(|i| theta[c + i]).collect(),
            None => vec![],
        };
        HostModel { ext, drive_hz: self.spec.drive_hz, branches, drift, delay: phi[5] }
    }

    /// Levenberg–Marquardt over the outer parameters listed in `free`.
    fn levenberg_marquardt(&self, mut phi: Phi, max_iter: usize, free: &[usize]) -> Option<(Phi, Solution)> {
        let mut sol = self.solve(&phi)?;
        let mut mu = 1e-3;
        let nf = free.len();
        for _ in 0..max_iter {
            let m = sol.residual.len();
            let mut jac = DMatrix::<f64>::zeros(m, nf);
            for (col, &p) in free.iter().enumerate() {
                let step = 1e-7 * phi[p].abs().max(1e-2);
                let mut q = phi;
                q[p] += step;
                let Some(s) = self.solve(&q) else {
                    // At the stability boundary: differentiate backwards instead.
                    q[p] = phi[p] - step;
                    let s = self.solve(&q)?;
                    for i in 0..m {
                        jac[(i, col)] = (sol.residual[i] - s.residual[i]) / step;
                    }
                    continue;
                };
                for i in 0..m {
                    jac[(i, col)] = (s.residual[i] - sol.residual[i]) / step;
                }
            }
            let r = DVector::from_column_slice(&sol.residual);
            let jtj = jac.transpose() * &jac;
            let g = jac.transpose() * r;
            let mut improved = false;
            while mu < 1e12 {
                let mut a = jtj.clone();
                for i in 0..nf {
                    a[(i, i)] += mu * (jtj[(i, i)] + 1e-12);
                }
                let Some(ch) = a.cholesky() else {
                    mu *= 4.0;
                    continue;
                };
                let delta = ch.solve(&(-&g));
                let mut cand = phi;
                for (i, &p) in free.iter().enumerate() {
                    cand[p] += delta[i];
                }
                match self.solve(&cand) {
                    Some(s) if s.cost < sol.cost => {
                        let rel = (sol.cost - s.cost) / sol.cost.max(1e-300);
                        phi = cand;
                        sol = s;
                        mu = (mu / 3.0).max(1e-12);
                        improved = rel > 1e-10;
                        break;
                    }
                    _ => mu *= 4.0,
                }
            }
            if !improved {
                break;
            }
        }
        Some((phi, sol))
    }
}

/// AR coefficients of a resonance at `f_hz` with damping ratio `zeta` at interval `ts`.
fn resonance_ar(f_hz: f64, zeta: f64, ts: f64) -> [f64; 2] {
    let w = std::f64::consts::TAU * f_hz * ts;
    if zeta < 1.0 {
        let r = (-zeta * w).exp();
        [2.0 * r * (w * (1.0 - zeta * zeta).sqrt()).cos(), -r * r]
    } else {
        let s = (zeta * zeta - 1.0).sqrt();
        let (r1, r2) = ((-(zeta - s) * w).exp(), (-(zeta + s) * w).exp());
        [r1 + r2, -r1 * r2]
    }
}

/// The result of a fit: the model and its fitting cost (RMS over the criterion window).
#[derive(Clone, Debug)]
pub struct Fit {
    /// The model.
    pub model: HostModel,
    /// RMS of the free-run error over the criterion window (µm).
    pub rms_fit: f64,
    /// The model met the invertibility requirement (always `false` when it was not asked:
    /// not checked). When asked and no invertible model fitted (with the structure fixed,
    /// then free), the best unconstrained model is returned with this `false`.
    pub invertible: bool,
}

/// Output-error (simulation-error) fit on `u[..fit_end]`, `y[..fit_end]`; `starts` are extra
/// models to start from (e.g. the extended fit when fitting an enhanced model).
pub fn fit_oe(
    u: &[f64],
    y: &[f64],
    ts: f64,
    fit_end: usize,
    spec: &ModelSpec,
    starts: &[HostModel],
    opt: &OeOptions,
) -> Result<Fit, FitError> {
    if opt.require_invertible {
        // Invertible first; if a fixed structure admits no invertible loop, let the
        // structure move (from the given one) before giving up invertibility.
        let mut tries = vec![opt.clone()];
        if opt.shape.is_some() {
            tries.push(OeOptions { shape: None, ..opt.clone() });
        }
        if opt.fix_structure {
            tries.push(OeOptions { fix_structure: false, shape: None, ..opt.clone() });
        }
        for o in &tries {
            match fit_oe_once(u, y, ts, fit_end, spec, starts, o) {
                Ok(mut fit) => {
                    fit.invertible = true;
                    return Ok(fit);
                }
                Err(FitError::NoStableModel) => {}
                Err(e) => return Err(e),
            }
        }
    }
    fit_oe_once(u, y, ts, fit_end, spec, starts, &OeOptions { require_invertible: false, ..opt.clone() })
}

fn fit_oe_once(
    u: &[f64],
    y: &[f64],
    ts: f64,
    fit_end: usize,
    spec: &ModelSpec,
    starts: &[HostModel],
    opt: &OeOptions,
) -> Result<Fit, FitError> {
    spec.check(ts)?;
    let end = fit_end.min(opt.max_samples).min(u.len()).min(y.len());
    let need = opt.skip + 200;
    if end < need {
        return Err(FitError::TooFewSamples { have: end, need });
    }
    let mut prob = Problem::new(u, y, ts, end, opt.skip, spec)?;
    prob.require_invertible = opt.require_invertible;
    prob.linear = opt.linear;
    if let (Some(ar), Some(sh), true) = (opt.structure, opt.shape, opt.fix_structure) {
        // Everything nonlinear is known: one linear solve.
        let phi = [ar[0], ar[1], sh[0], sh[1], sh[2], opt.delay.unwrap_or(0.0)];
        let sol = prob.solve(&phi).ok_or(FitError::NoStableModel)?;
        let model = prob.model(&phi, &sol.theta);
        return Ok(Fit { model, rms_fit: (sol.cost / sol.residual.len() as f64).sqrt(), invertible: false });
    }
    let u_amp = u[..end].iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-9);

    // Stage A: structures. A single-frequency record pins only one complex gain of G,
    // which many resonances match, so structures are ranked with a loop present (a middle
    // shape): the loop's harmonics, passing through G, tell them apart.
    let nyq = 0.5 / ts;
    let delays: Vec<f64> = if opt.fit_delay && !opt.fix_structure {
        vec![0.0, 0.5, 1.0, 1.5]
    } else {
        vec![opt.delay.unwrap_or(0.0)]
    };
    let mid_shape = |ar: [f64; 2], tau: f64| -> Phi { [ar[0], ar[1], 0.0, 0.75 / u_amp, 2.25 / u_amp, tau] };
    let mut ar_cands: Vec<(f64, [f64; 2], f64)> = vec![];
    for &tau in &delays {
        match opt.structure {
            Some(ar) => ar_cands.extend(prob.solve(&mid_shape(ar, tau)).map(|s| (s.cost, ar, tau))),
            None => {
                for i in 0..16 {
                    let f_r = 5.0 * (nyq * 0.9 / 5.0f64).powf(i as f64 / 15.0);
                    for zeta in [0.01, 0.03, 0.1, 0.3, 1.0, 3.0] {
                        let ar = resonance_ar(f_r, zeta, ts);
                        if let Some(s) = prob.solve(&mid_shape(ar, tau)) {
                            ar_cands.push((s.cost, ar, tau));
                        }
                    }
                }
            }
        }
    }
    ar_cands.sort_by(|a, b| a.0.total_cmp(&b.0));

    // Stage B: loop shapes on the best structures.
    let mut cands: Vec<(f64, Phi)> = vec![];
    for &(_, ar, tau) in ar_cands.iter().take(6) {
        for kappa in [0.3, 1.0, 3.0, 10.0] {
            for q in [-0.5, 0.5] {
                let sum = kappa / u_amp;
                let phi = [ar[0], ar[1], 0.0, sum * q / 2.0, sum * (1.0 - q / 2.0), tau];
                if let Some(s) = prob.solve(&phi) {
                    cands.push((s.cost, phi));
                }
            }
        }
    }
    for m in starts {
        let amp = m.ext.bw.a;
        if amp != 0.0 {
            let sgn = amp.signum();
            let ar = match (opt.fix_structure, opt.structure) {
                (true, Some(ar)) => ar,
                _ => m.ext.ar,
            };
            let tau = match (opt.fix_structure, opt.structure) {
                (true, Some(_)) => opt.delay.unwrap_or(0.0),
                _ => m.delay,
            };
            let phi = [ar[0], ar[1], m.ext.bw.a0 / amp, sgn * m.ext.bw.gamma, m.ext.bw.beta, tau];
            if let Some(s) = prob.solve(&phi) {
                cands.push((s.cost * 0.999, phi)); // prefer a given start on ties
            }
        }
    }
    cands.sort_by(|a, b| a.0.total_cmp(&b.0));

    // Stage C: Levenberg–Marquardt from the best few.
    let mut best: Option<(Phi, Solution)> = None;
    for &(_, phi) in cands.iter().take(opt.lm_starts.max(1)) {
        let structure_fixed = opt.fix_structure && opt.structure.is_some();
        let mut free: Vec<usize> = if structure_fixed { vec![2, 3, 4] } else { vec![0, 1, 2, 3, 4] };
        if opt.fit_delay && !structure_fixed {
            free.push(5);
        }
        if let Some((p, s)) = prob.levenberg_marquardt(phi, opt.max_iter, &free) {
            if best.as_ref().is_none_or(|b| s.cost < b.1.cost) {
                best = Some((p, s));
            }
        }
    }
    let (phi, sol) = best.ok_or(FitError::NoStableModel)?;
    let model = prob.model(&phi, &sol.theta);
    Ok(Fit { model, rms_fit: (sol.cost / sol.residual.len() as f64).sqrt(), invertible: false })
}

/// Free-run RMS error of `model` on `y[from..]` (simulated from sample 0). Non-finite if
/// the model is unstable.
pub fn free_run_rms(model: &HostModel, u: &[f64], y: &[f64], ts: f64, from: usize) -> Result<f64, FitError> {
    let sim = model.simulate(u, ts)?;
    Ok(analysis::rms_diff(&sim[from..], &y[from..]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use boucwen_core::signal::Sine;

    fn truth() -> HostModel {
        let w0 = std::f64::consts::TAU * 0.07;
        HostModel {
            ext: ExtendedParams {
                bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
                ar: [2.0 * 0.97 * w0.cos(), -0.97 * 0.97],
            },
            drive_hz: 23.0,
            branches: vec![Branch { order: 3, alpha_s: 0.8, alpha_c: -0.5, ar: [0.0, 0.0] }],
            drift: vec![],
            delay: 0.0,
        }
    }

    fn drive(f: f64, n: usize) -> Vec<f64> {
        let mut s = Sine::new(1.0, Oscillator::new(f, 1e-3).unwrap());
        (0..n).map(|_| s.next_sample()).collect()
    }

    #[test]
    fn the_projected_prediction_is_the_core_simulation() {
        // The VarPro prediction for the fitted φ must equal the core model's free run.
        let t = truth();
        let u = drive(23.0, 6000);
        let y = t.simulate(&u, 1e-3).unwrap();
        let fit =
            fit_oe(&u, &y, 1e-3, 4000, &ModelSpec::enhanced(23.0, &[3]), &[], &OeOptions::default()).unwrap();
        let sim = fit.model.simulate(&u, 1e-3).unwrap();
        let rms_crit = analysis::rms_diff(&sim[200..4000], &y[200..4000]);
        assert!((rms_crit - fit.rms_fit).abs() < 1e-9 * (1.0 + fit.rms_fit), "{rms_crit} vs {}", fit.rms_fit);
    }

    #[test]
    fn output_error_fit_reproduces_the_model_it_was_given_in_free_run() {
        let t = truth();
        let u = drive(23.0, 10_000);
        let y = t.simulate(&u, 1e-3).unwrap();
        let amp = analysis::rms(&y[5000..]);
        let fit =
            fit_oe(&u, &y, 1e-3, 5000, &ModelSpec::enhanced(23.0, &[3]), &[], &OeOptions::default()).unwrap();
        let held_out = free_run_rms(&fit.model, &u, &y, 1e-3, 5000).unwrap();
        assert!(held_out < 1e-3 * amp, "held-out free-run RMS {held_out} of {amp}");
        // Without the branch, the harmonic cannot be explained.
        let ext = fit_oe(&u, &y, 1e-3, 5000, &ModelSpec::extended(23.0), &[], &OeOptions::default()).unwrap();
        let held_out_ext = free_run_rms(&ext.model, &u, &y, 1e-3, 5000).unwrap();
        assert!(held_out_ext > 10.0 * held_out, "{held_out_ext} vs {held_out}");
    }

    #[test]
    fn drift_term_is_fitted() {
        let mut t = truth();
        t.branches.clear();
        t.drift = vec![0.5, 0.3];
        let u = drive(11.0, 8000);
        let y = t.simulate(&u, 1e-3).unwrap();
        let spec = ModelSpec { drive_hz: 11.0, harmonics: vec![], drift_degree: Some(1) };
        let fit = fit_oe(&u, &y, 1e-3, 4000, &spec, &[], &OeOptions::default()).unwrap();
        assert!((fit.model.drift[1] - 0.3).abs() < 1e-3, "{:?}", fit.model.drift);
        let r = free_run_rms(&fit.model, &u, &y, 1e-3, 4000).unwrap();
        assert!(r < 1e-2, "held-out {r} fit {} model {:?}", fit.rms_fit, fit.model);
    }

    #[test]
    fn bad_specs_are_rejected() {
        let u = drive(23.0, 5000);
        let y = u.clone();
        let e = fit_oe(&u, &y, 1e-3, 4000, &ModelSpec::enhanced(23.0, &[25]), &[], &OeOptions::default());
        assert_eq!(e.err(), Some(FitError::BadHarmonic(25)));
        let e = fit_oe(&u, &y, 1e-3, 100, &ModelSpec::extended(23.0), &[], &OeOptions::default());
        assert!(matches!(e, Err(FitError::TooFewSamples { .. })));
    }
}
