//! The Bouc–Wen oscillator: hysteresis as a restoring force inside a structure of order two.
//!
//! ## The model ([`OscillatorModel`])
//! ```text
//! m ÿ + c ẏ + k y + z = u
//! ż = α ẏ − (βγ) |ẏ| |z|^(ν−1) z − (βδ) ẏ |z|^ν
//! ```
//! force `u` (N) in, displacement `y` (m) out, from rest (`y = ẏ = z = 0`).
//!
//! ## Identifiable parameters ([`OscillatorParams`])
//! In the textbook form `β` multiplies both `γ` and `δ`, so `(β, γ, δ)` and
//! `(sβ, γ/s, δ/s)` give the same output for every `s`: only the products act. The model is
//! written with `βγ` and `βδ` as its parameters, which removes that direction. The scale of
//! `z` is fixed by its unit coefficient in the force balance (with `z = s·z'` the loop's
//! coefficients would change, but so would the force), and the input and output are in
//! physical units, so `m, c, k, α, βγ, βδ, ν` are all identifiable from input and output
//! (given a drive large enough for the loop to act: at small amplitude `z ≈ α y` and only
//! `k + α` is seen). `ν` is fitted or fixed (at 1, the benchmark's value;
//! [`OscillatorOptions::fit_nu`]).
//!
//! ## Integration between samples
//! `substeps` steps of `h = ts/substeps` per sample (20: the benchmark's 15 kHz at 750 Hz),
//! by the benchmark's own rule: Newmark's average acceleration (the trapezoidal rule on
//! `(y, ẏ)`) with the trapezoidal rule on `z`, the implicit step solved by Newton–Raphson
//! on `(ẏ', z')` to 10⁻¹³ ([`boucwen_sim::oscillator`]). Its error against the exact
//! solution is second order: the mode's frequency is read `(ωh)²/12 ≈ 1.9·10⁻⁵` too low at
//! 15 kHz, which moves the response near the resonance by about `1.9·10⁻⁵/ζ ≈ 0.17 %`; the
//! benchmark's data carry the same error, and a fit absorbs the rest into `m` (by
//! `(ωh)²/6`). The step's exact derivative (implicit function theorem on the converged
//! step) gives the sensitivities, so the Jacobian is that of the discrete simulation.
//!
//! ## Input reconstruction ([`InputReconstruction`])
//! The input is known only at the samples. A periodic record (the benchmark's multisine,
//! band-limited below half the sample rate) is interpolated in the DFT domain over one
//! period, which is exact; any other record by a natural cubic spline through the samples
//! (error `≈ (ωts)⁴/384` relative at frequency `ω`: 8·10⁻⁵ at 50 Hz and 750 Hz).
//!
//! ## Output ([`OutputSampling`])
//! The benchmark's output was low-pass filtered and decimated from the fine grid (MATLAB's
//! FIR `decimate` by the prime factors of 20, [`boucwen_sim::oscillator::decimate_chain`]);
//! the model does the same to its fine output ([`OutputSampling::FirDecimation`]), or reads
//! the fine output at the sample instants ([`OutputSampling::Instant`]). On the benchmark
//! the two differ by 0.18 µm RMS.
//!
//! ## Initial state
//! [`OscillatorModel::simulate`] starts from rest at the first sample. For a test made of one
//! steady-state period of a periodic input, [`OscillatorModel::simulate_periodic`] runs the
//! period `warmup_periods` times first (periodic warm-up) and returns the next one, its
//! decimation computed with the periodic continuation on both sides.
//!
//!
//! Its fit by output error is [`crate::fit::oscillator`].

use super::ModelError;
use boucwen_sim::oscillator::{FIR_TAPS, corrector, decimate_chain, interpolate_periodic};

use serde::{Deserialize, Serialize};

/// Names of the parameters in [`OscillatorModel::params`] order.
pub const PARAM_NAMES: [&str; 7] = ["m", "c", "k", "alpha", "beta_gamma", "beta_delta", "nu"];

/// The identifiable parameters of the oscillator (module docs), SI units.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct OscillatorParams {
    /// Mass `m` (kg).
    pub m: f64,
    /// Viscous damping `c` (N·s/m).
    pub c: f64,
    /// Linear stiffness `k` (N/m).
    pub k: f64,
    /// Initial stiffness of the loop `α` (N/m).
    pub alpha: f64,
    /// `βγ` (N^(−ν)/m).
    pub beta_gamma: f64,
    /// `βδ` (N^(−ν)/m).
    pub beta_delta: f64,
    /// `ν` (≥ 1).
    pub nu: f64,
}

impl OscillatorParams {
    /// The benchmark's published system (`βγ = 800`, `βδ = −1100`).
    pub const BENCHMARK: Self =
        Self { m: 2.0, c: 10.0, k: 5e4, alpha: 5e4, beta_gamma: 800.0, beta_delta: -1100.0, nu: 1.0 };

    pub(crate) fn to_vec(self) -> [f64; 7] {
        [self.m, self.c, self.k, self.alpha, self.beta_gamma, self.beta_delta, self.nu]
    }

    pub(crate) fn from_slice(x: &[f64], nu: f64) -> Self {
        Self {
            m: x[0],
            c: x[1],
            k: x[2],
            alpha: x[3],
            beta_gamma: x[4],
            beta_delta: x[5],
            nu: x.get(6).copied().unwrap_or(nu),
        }
    }

    /// Checks that every parameter is finite, `m > 0` and `ν ≥ 1`.
    pub fn validate(&self) -> Result<(), ModelError> {
        for (name, v) in PARAM_NAMES.iter().zip(self.to_vec()) {
            if !v.is_finite() {
                return Err(ModelError::Core(boucwen_core::Error::NonFinite(name)));
            }
        }
        if self.m <= 0.0 {
            return Err(ModelError::Core(boucwen_core::Error::OutOfRange("m")));
        }
        if self.nu < 1.0 {
            return Err(ModelError::Core(boucwen_core::Error::OutOfRange("nu")));
        }
        Ok(())
    }
}

/// How the model's output is read from its fine grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum OutputSampling {
    /// The fine displacement at the sample instants.
    Instant,
    /// MATLAB's FIR `decimate` by the prime factors of `substeps`, as the benchmark.
    FirDecimation,
}

/// How the input is reconstructed between samples (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum InputReconstruction {
    /// Periodic with this many samples per period: DFT interpolation of the first period.
    Periodic {
        /// Samples per period.
        period: usize,
    },
    /// A natural cubic spline through the samples.
    CubicSpline,
}

/// The Bouc–Wen oscillator model: parameters and how it is simulated (module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OscillatorModel {
    /// The parameters.
    pub params: OscillatorParams,
    /// Integration steps per sample.
    pub substeps: usize,
    /// How the output is sampled.
    pub output: OutputSampling,
}

/// Fine samples simulated past the last output sample so that the decimation filter's
/// support (`±15` taps at each stage of the cascade) lies inside the simulation.
fn tail(substeps: usize) -> usize {
    2 * FIR_TAPS * substeps
}

impl OscillatorModel {
    /// The benchmark's true system as the benchmark simulates and measures it.
    pub fn benchmark_truth() -> Self {
        Self { params: OscillatorParams::BENCHMARK, substeps: 20, output: OutputSampling::FirDecimation }
    }

    /// `(name, value)` of each parameter ([`PARAM_NAMES`]).
    pub fn params(&self) -> Vec<(&'static str, f64)> {
        PARAM_NAMES.iter().copied().zip(self.params.to_vec()).collect()
    }

    /// The output from rest for the input `u` at interval `ts` (s), the input reconstructed
    /// by a cubic spline ([`Self::simulate_with`] for a periodic record).
    pub fn simulate(&self, u: &[f64], ts: f64) -> Result<Vec<f64>, ModelError> {
        self.simulate_with(u, ts, InputReconstruction::CubicSpline)
    }

    /// The output from rest, the input reconstructed as asked.
    pub fn simulate_with(
        &self,
        u: &[f64],
        ts: f64,
        input: InputReconstruction,
    ) -> Result<Vec<f64>, ModelError> {
        let fine = self.fine_input(u, input)?;
        let (y, _) = run(&self.params, &fine, ts / self.substeps as f64, 0)?;
        self.to_samples(&y, u.len())
    }

    /// The steady-state output over one period `u_period` of a periodic input: the period
    /// (DFT-interpolated) is run `warmup_periods` times from rest, then once more, and that
    /// last period is returned (decimated with the periodic continuation on both sides when
    /// `warmup_periods ≥ 1`).
    pub fn simulate_periodic(
        &self,
        u_period: &[f64],
        ts: f64,
        warmup_periods: usize,
    ) -> Result<Vec<f64>, ModelError> {
        let n = u_period.len();
        let reps = warmup_periods + 1;
        let u = u_period.repeat(reps);
        let fine = self.fine_input(&u, InputReconstruction::Periodic { period: n })?;
        let (y, _) = run(&self.params, &fine, ts / self.substeps as f64, 0)?;
        let all = self.to_samples(&y, n * reps)?;
        Ok(all[warmup_periods * n..].to_vec())
    }

    fn check(&self, u: &[f64], ts: f64) -> Result<(), ModelError> {
        self.params.validate()?;
        if self.substeps == 0 {
            return Err(ModelError::Core(boucwen_core::Error::OutOfRange("substeps")));
        }
        if !(ts.is_finite() && ts > 0.0) {
            return Err(ModelError::Core(boucwen_core::Error::OutOfRange("ts")));
        }
        if u.iter().any(|v| !v.is_finite()) {
            return Err(ModelError::Core(boucwen_core::Error::NonFinite("u")));
        }
        if u.len() < 2 * FIR_TAPS + 2 {
            return Err(ModelError::TooFewSamples { have: u.len(), need: 2 * FIR_TAPS + 2 });
        }
        Ok(())
    }

    /// The input on the fine grid: `(n−1)·substeps + 1` samples for a spline, and for a
    /// periodic input `n·substeps` plus the decimation's tail.
    pub(crate) fn fine_input(&self, u: &[f64], input: InputReconstruction) -> Result<Vec<f64>, ModelError> {
        self.check(u, 1.0)?;
        fine_input(u, input, self.substeps)
    }

    pub(crate) fn to_samples(&self, fine: &[f64], n: usize) -> Result<Vec<f64>, ModelError> {
        to_samples(fine, n, self.substeps, self.output)
    }
}

pub(crate) fn fine_input(
    u: &[f64],
    input: InputReconstruction,
    substeps: usize,
) -> Result<Vec<f64>, ModelError> {
    let s = substeps;
    match input {
        InputReconstruction::Periodic { period } => {
            if period < 2 || period > u.len() {
                return Err(ModelError::Core(boucwen_core::Error::OutOfRange("period")));
            }
            let one = interpolate_periodic(u, period, s)
                .map_err(|_| ModelError::Core(boucwen_core::Error::NonFinite("u")))?;
            let len = u.len() * s + tail(s);
            Ok(one.iter().copied().cycle().take(len).collect())
        }
        InputReconstruction::CubicSpline => Ok(natural_spline(u, s)),
    }
}

pub(crate) fn to_samples(
    fine: &[f64],
    n: usize,
    substeps: usize,
    output: OutputSampling,
) -> Result<Vec<f64>, ModelError> {
    let mut y: Vec<f64> = match output {
        OutputSampling::Instant => fine.iter().step_by(substeps).copied().collect(),
        OutputSampling::FirDecimation => decimate_chain(fine, substeps)
            .map_err(|_| ModelError::TooFewSamples { have: n, need: 2 * FIR_TAPS + 2 })?,
    };
    if y.len() < n {
        return Err(ModelError::TooFewSamples { have: y.len(), need: n });
    }
    y.truncate(n);
    Ok(y)
}

/// A natural cubic spline through `u[i]` at `i·s`, evaluated at every fine instant up to
/// the last sample: `(n−1)·s + 1` values.
pub(crate) fn natural_spline(u: &[f64], s: usize) -> Vec<f64> {
    let n = u.len();
    if n < 3 {
        return u.iter().flat_map(|&v| std::iter::repeat_n(v, s)).take((n.max(1) - 1) * s + 1).collect();
    }
    // Second derivatives M (unit spacing): M[i−1] + 4M[i] + M[i+1] = 6(u[i+1] − 2u[i] + u[i−1]),
    // M[0] = M[n−1] = 0; Thomas algorithm.
    let mut mm = vec![0.0; n];
    let mut cp = vec![0.0; n];
    let mut dp = vec![0.0; n];
    for i in 1..n - 1 {
        let d = 6.0 * (u[i + 1] - 2.0 * u[i] + u[i - 1]);
        let denom = 4.0 - cp[i - 1];
        cp[i] = 1.0 / denom;
        dp[i] = (d - dp[i - 1]) / denom;
    }
    for i in (1..n - 1).rev() {
        mm[i] = dp[i] - cp[i] * mm[i + 1];
    }
    let mut out = Vec::with_capacity((n - 1) * s + 1);
    for i in 0..n - 1 {
        for j in 0..s {
            let t = j as f64 / s as f64;
            let r = 1.0 - t;
            out.push(r * u[i] + t * u[i + 1] + ((r * r * r - r) * mm[i] + (t * t * t - t) * mm[i + 1]) / 6.0);
        }
    }
    out.push(u[n - 1]);
    out
}

/// Simulates from rest on the fine grid; with `nsens > 0` also the sensitivities
/// `∂y/∂θ_j` of the first `nsens` parameters (order of [`PARAM_NAMES`]).
pub(crate) fn run(
    p: &OscillatorParams,
    u: &[f64],
    h: f64,
    nsens: usize,
) -> Result<(Vec<f64>, Vec<Vec<f64>>), ModelError> {
    p.validate()?;
    let ns = nsens.min(7);
    let (m, c, k, alpha, ba, bd, nu) = (p.m, p.c, p.k, p.alpha, p.beta_gamma, p.beta_delta, p.nu);
    // g(v, z), ∂g/∂v, ∂g/∂z and the explicit ∂g/∂(α, βγ, βδ, ν).
    let rate = |v: f64, z: f64| -> (f64, f64, f64, [f64; 4]) {
        let az = z.abs();
        let pw = if nu == 1.0 { 1.0 } else { az.powf(nu - 1.0) };
        let t_a = v.abs() * pw * z;
        let t_b = v * pw * az;
        let g = alpha * v - ba * t_a - bd * t_b;
        let gv = alpha - ba * v.signum() * pw * z - bd * pw * az;
        let gz = -nu * pw * (ba * v.abs() + bd * v * z.signum());
        let lnz = if az > 0.0 { az.ln() } else { 0.0 };
        (g, gv, gz, [v, -t_a, -t_b, -lnz * (ba * t_a + bd * t_b)])
    };
    let mut ys = Vec::with_capacity(u.len());
    let mut sens: Vec<Vec<f64>> = (0..ns).map(|_| Vec::with_capacity(u.len())).collect();
    let Some(&u0) = u.first() else { return Ok((ys, sens)) };
    let (mut y, mut v, mut z) = (0.0f64, 0.0f64, 0.0f64);
    let mut acc = u0 / m;
    let (mut g, mut gv, mut gz, mut gt) = rate(v, z);
    let (mut sy, mut sv, mut sz) = ([0.0f64; 7], [0.0f64; 7], [0.0f64; 7]);
    ys.push(y);
    for s in &mut sens {
        s.push(0.0);
    }
    let hh = 0.5 * h;
    // The Jacobian's constant row, for the sensitivities.
    let j11 = 1.0 + hh * (c + k * hh) / m;
    let j12 = hh / m;
    for &u1 in &u[1..] {
        let (v1, z1) = corrector([m, c, k], h, [y, v, z, acc, g], u1, |v, z| {
            let (g, gv, gz, _) = rate(v, z);
            (g, gv, gz)
        });
        let y1 = y + hh * (v + v1);
        let a1 = (u1 - c * v1 - k * y1 - z1) / m;
        let (g1, gv1, gz1, gt1) = rate(v1, z1);
        if !(y1.is_finite() && v1.is_finite() && z1.is_finite()) {
            return Err(ModelError::Core(boucwen_core::Error::NonFinite("simulated state")));
        }
        if ns > 0 {
            let (j21, j22) = (-hh * gv1, 1.0 - hh * gz1);
            let det = j11 * j22 - j12 * j21;
            let ea0 = [-acc / m, -v / m, -y / m];
            let ea1 = [-a1 / m, -v1 / m, -y1 / m];
            for j in 0..ns {
                let (e0, e1) = if j < 3 { (ea0[j], ea1[j]) } else { (0.0, 0.0) };
                let (t0, t1) = if j >= 3 { (gt[j - 3], gt1[j - 3]) } else { (0.0, 0.0) };
                let da0 = (-c * sv[j] - k * sy[j] - sz[j]) / m + e0;
                let rhs1 = sv[j] + hh * da0 + hh * (-k * (sy[j] + hh * sv[j]) / m + e1);
                let rhs2 = sz[j] + hh * (gv * sv[j] + gz * sz[j] + t0 + t1);
                let sv1 = (rhs1 * j22 - j12 * rhs2) / det;
                let sz1 = (j11 * rhs2 - j21 * rhs1) / det;
                sy[j] += hh * (sv[j] + sv1);
                sv[j] = sv1;
                sz[j] = sz1;
                sens[j].push(sy[j]);
            }
        }
        (y, v, z, acc) = (y1, v1, z1, a1);
        (g, gv, gz, gt) = (g1, gv1, gz1, gt1);
        ys.push(y);
    }
    Ok((ys, sens))
}
