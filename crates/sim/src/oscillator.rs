//! The virtual Bouc–Wen oscillator: the true system of the hysteretic benchmark of Noël and
//! Schoukens (Workshop on Nonlinear System Identification Benchmarks, Brussels, 2016), with
//! the benchmark's integrator, its decimation and generators of its inputs.
//!
//! ```
//! use boucwen_sim::oscillator::{BoucWenOscillator, Multisine, UPSAMPLING};
//! let osc = BoucWenOscillator::default(); // the published parameters
//! let ms = Multisine::benchmark(7)?; // a random-phase realisation of the benchmark's spec
//! let rec = osc.multisine_record(&ms, 1)?; // one period from rest, 8,192 samples at 750 Hz
//! assert_eq!(rec.u.len(), 8192);
//! # Ok::<(), boucwen_sim::SimError>(())
//! ```
//!
//! ## The system
//! A single mass, force `u` (N) in, displacement `y` (m) out:
//! ```text
//! m ÿ + c ẏ + k y + z = u
//! ż = α ẏ − β (γ |ẏ| |z|^(ν−1) z + δ ẏ |z|^ν)
//! ```
//! with `m = 2`, `c = 10`, `k = 5·10⁴`, `α = 5·10⁴`, `β = 10³`, `γ = 0.8`, `δ = −1.1`,
//! `ν = 1` (SI units, [`BoucWenOscillator::default`]). The hysteresis `z` (N) is a restoring
//! force inside the structure; for small `z` it adds the stiffness `α`, so the linear mode is
//! at `√((k + α)/m)/2π = 35.59 Hz`.
//!
//! ## Integration ([`BoucWenOscillator::integrate`])
//! Newmark's average acceleration rule (`γ_N = 1/2`, `β_N = 1/4`, the benchmark's
//! `a = c = 0.5`, `b = 0.25`) at the fine step `h` (the benchmark's 1/15 kHz), which is the
//! trapezoidal rule on `(y, ẏ)`; the hysteresis is advanced by the trapezoidal rule too, and
//! the implicit step is solved by Newton–Raphson on `(ẏ', z')` (`y'` follows from
//! `y' = y + h(ẏ + ẏ')/2`) to a relative correction of 10⁻¹³:
//! ```text
//! ẏ' = ẏ + h/2 (a + a'),   a' = (u' − c ẏ' − k y' − z')/m
//! z' = z + h/2 (g(ẏ, z) + g(ẏ', z')),   g(v, z) = α v − β(γ|v||z|^(ν−1) z + δ v |z|^ν)
//! ```
//! The benchmark's integrator is distributed only in compiled form; this is our reading of
//! its documented scheme. Against `train.csv` (driven by that record's input, reconstructed
//! exactly, see [`interpolate_periodic`]) it reproduces the record's output to its noise:
//! `docs/oscillator-notes.md` gives the figures.
//!
//! ## Decimation ([`decimate_fir`], [`decimate_benchmark`])
//! The fine output is brought to 750 Hz as the benchmark does, by MATLAB's
//! `decimate(y, r, 'fir')` for `r = 2, 2, 5` in turn (`factor(20)`): a 31-tap FIR low-pass
//! (`fir1(30, 1/r)`, Hamming window, unit DC gain) applied with its 15-sample delay removed
//! (zero phase), both ends extended by odd reflection about the end sample
//! (`2x₀ − x_j`), then one sample in `r` kept from the first. Output `i` is centred on fine
//! sample `20 i`, the instant of the input sample `u[i] = u_fine[20 i]`.
//!
//! ## Inputs
//! - [`Multisine::benchmark`]: the benchmark's random-phase multisine, defined on the fine
//!   grid: one period of `N·20 = 163,840` fine samples, lines `54..=1639` of that grid's DFT
//!   (4.94–150.06 Hz at the line spacing 750/8192 Hz) with unit amplitudes and phases
//!   uniform in `[0, 2π)` from the project's seeded xoshiro256++, `2·Re(IDFT)`, scaled to a
//!   standard deviation (over the period, `N−1` normalised as MATLAB's `std`) of 50 N.
//! - [`sine_sweep`]: the sine-sweep test, a linear sweep
//!   `u(t) = A sin(2π(f₀ t + (f₁ − f₀) t²/(2T)))` from `f₀ = 20` to `f₁ = 50` Hz over the
//!   record's duration `T = n/750` s (153,000 samples: 204 s, 8.8 Hz/min) with `A = 40` N,
//!   evaluated on the fine grid for the integration and sampled at 750 Hz for the record.
//!   The benchmark's documents give the band, amplitude and length; that the sweep is
//!   linear over the whole record is our assumption.

use crate::SimError;
use crate::rng::Rng;
use rustfft::FftPlanner;
use rustfft::num_complex::Complex;
use serde::{Deserialize, Serialize};

/// The benchmark's sample rate (Hz).
pub const FS_HZ: f64 = 750.0;
/// Fine steps per sample: the benchmark integrates at `20 · 750 = 15,000` Hz.
pub const UPSAMPLING: usize = 20;
/// Samples per period of the benchmark's multisine at [`FS_HZ`].
pub const MULTISINE_PERIOD: usize = 8192;
/// The benchmark's multisine RMS (N).
pub const MULTISINE_RMS_N: f64 = 50.0;
/// First and last excited lines of the fine grid's DFT (`floor(5/Δf)`, `ceil(150/Δf)`,
/// `Δf = 750/8192` Hz).
pub const MULTISINE_LINES: (usize, usize) = (54, 1639);
/// Samples of the benchmark's sine-sweep test at [`FS_HZ`].
pub const SWEEP_SAMPLES: usize = 153_000;
/// Taps of MATLAB's `decimate(.., 'fir')` filter (`fir1(30, 1/r)`).
pub const FIR_TAPS: usize = 31;

/// Parameters of the Bouc–Wen oscillator (SI units), apart from its state.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BoucWenOscillator {
    /// Mass `m` (kg).
    pub mass_kg: f64,
    /// Viscous damping `c` (N·s/m).
    pub damping_n_s_per_m: f64,
    /// Linear stiffness `k` (N/m).
    pub stiffness_n_per_m: f64,
    /// Initial stiffness of the hysteresis `α` (N/m).
    pub alpha_n_per_m: f64,
    /// `β` (N^(−ν)·m⁻¹ scale of the loop; only `βγ` and `βδ` act).
    pub beta: f64,
    /// `γ`.
    pub gamma: f64,
    /// `δ`.
    pub delta: f64,
    /// Exponent `ν` (≥ 1 here, so that the loop is Lipschitz at `z = 0`).
    pub nu: f64,
}

impl Default for BoucWenOscillator {
    /// The benchmark's published parameters.
    fn default() -> Self {
        Self {
            mass_kg: 2.0,
            damping_n_s_per_m: 10.0,
            stiffness_n_per_m: 5e4,
            alpha_n_per_m: 5e4,
            beta: 1e3,
            gamma: 0.8,
            delta: -1.1,
            nu: 1.0,
        }
    }
}

/// The state `(y, ẏ, z)` of the oscillator.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OscillatorState {
    /// Displacement (m).
    pub y: f64,
    /// Velocity (m/s).
    pub v: f64,
    /// Hysteretic force (N).
    pub z: f64,
}

/// A record at [`FS_HZ`]: input (N) and output (m).
#[derive(Clone, Debug, PartialEq)]
pub struct BenchmarkRecord {
    /// Force at the sample instants (N).
    pub u: Vec<f64>,
    /// Displacement, decimated as the benchmark does (m).
    pub y: Vec<f64>,
}

impl BoucWenOscillator {
    /// Checks that every parameter is finite, `m > 0` and `ν ≥ 1`.
    pub fn validate(&self) -> Result<(), SimError> {
        let fields = [
            ("mass_kg", self.mass_kg),
            ("damping_n_s_per_m", self.damping_n_s_per_m),
            ("stiffness_n_per_m", self.stiffness_n_per_m),
            ("alpha_n_per_m", self.alpha_n_per_m),
            ("beta", self.beta),
            ("gamma", self.gamma),
            ("delta", self.delta),
            ("nu", self.nu),
        ];
        for (field, x) in fields {
            if !x.is_finite() {
                return Err(invalid(field, "must be finite"));
            }
        }
        if self.mass_kg <= 0.0 {
            return Err(invalid("mass_kg", "must be > 0"));
        }
        if self.nu < 1.0 {
            return Err(invalid("nu", "must be >= 1"));
        }
        Ok(())
    }

    /// The hysteresis rate `g(v, z) = α v − β(γ|v||z|^(ν−1) z + δ v |z|^ν)` and its partial
    /// derivatives `(∂g/∂v, ∂g/∂z)`.
    fn rate(&self, v: f64, z: f64) -> (f64, f64, f64) {
        let (a, b, nu) = (self.beta * self.gamma, self.beta * self.delta, self.nu);
        let az = z.abs();
        // |z|^(ν−1) with 0^0 = 1.
        let p = if nu == 1.0 { 1.0 } else { az.powf(nu - 1.0) };
        let g = self.alpha_n_per_m * v - a * v.abs() * p * z - b * v * p * az;
        let gv = self.alpha_n_per_m - a * v.signum() * p * z - b * p * az;
        let gz = -nu * p * (a * v.abs() + b * v * z.signum());
        (g, gv, gz)
    }

    /// Integrates from `start` over the fine input `u_fine` (N, one value per fine instant
    /// `j·h`, the first at the start), returning the displacement at every fine instant
    /// (the first is `start.y`) and the end state. See the module docs for the scheme.
    pub fn integrate(
        &self,
        u_fine: &[f64],
        h: f64,
        start: OscillatorState,
    ) -> Result<(Vec<f64>, OscillatorState), SimError> {
        self.validate()?;
        if !(h.is_finite() && h > 0.0) {
            return Err(invalid("h", "must be finite and > 0"));
        }
        let (m, c, k) = (self.mass_kg, self.damping_n_s_per_m, self.stiffness_n_per_m);
        let mut out = Vec::with_capacity(u_fine.len());
        let Some(&u0) = u_fine.first() else {
            return Ok((out, start));
        };
        if !u0.is_finite() {
            return Err(SimError::NonFiniteInput { sample: 0 });
        }
        let OscillatorState { mut y, mut v, mut z } = start;
        let mut acc = (u0 - c * v - k * y - z) / m;
        let mut g = self.rate(v, z).0;
        out.push(y);
        let hh = 0.5 * h;
        for (j, &u1) in u_fine.iter().enumerate().skip(1) {
            if !u1.is_finite() {
                return Err(SimError::NonFiniteInput { sample: j as u64 });
            }
            let (v1, z1) = corrector([m, c, k], h, [y, v, z, acc, g], u1, |v, z| self.rate(v, z));
            let y1 = y + hh * (v + v1);
            let a1 = (u1 - c * v1 - k * y1 - z1) / m;
            let g1 = self.rate(v1, z1).0;
            if !(y1.is_finite() && v1.is_finite() && z1.is_finite()) {
                return Err(SimError::Diverged { sample: j as u64 });
            }
            (y, v, z, acc, g) = (y1, v1, z1, a1, g1);
            out.push(y);
        }
        Ok((out, OscillatorState { y, v, z }))
    }

    /// The benchmark's measurement from rest: integrates the fine input (step
    /// `1/(FS_HZ·UPSAMPLING)`) and decimates the displacement by [`decimate_benchmark`]
    /// (`ceil(n/20)` samples).
    pub fn measure(&self, u_fine: &[f64]) -> Result<Vec<f64>, SimError> {
        let h = 1.0 / (FS_HZ * UPSAMPLING as f64);
        let (y, _) = self.integrate(u_fine, h, OscillatorState::default())?;
        decimate_benchmark(&y)
    }

    /// A training record as the benchmark makes one: `periods + 1` periods of the multisine
    /// from rest, decimated, the last period dropped (it only serves the filter's end), the
    /// input downsampled by [`UPSAMPLING`]. Noise-free: see [`add_noise`].
    pub fn multisine_record(&self, ms: &Multisine, periods: usize) -> Result<BenchmarkRecord, SimError> {
        if periods == 0 {
            return Err(invalid("periods", "must be >= 1"));
        }
        let u_fine = ms.repeat(periods + 1);
        let mut y = self.measure(&u_fine)?;
        let n = periods * ms.period_samples();
        y.truncate(n);
        let u = u_fine.iter().step_by(UPSAMPLING).take(n).copied().collect();
        Ok(BenchmarkRecord { u, y })
    }

    /// The multisine test: one period in steady state (the second of three simulated from
    /// rest; the transient decays as `e^(−ζωt)` with `1/(ζω) ≈ 0.4` s against a period of
    /// 10.9 s), noise-free.
    pub fn multisine_steady_period(&self, ms: &Multisine) -> Result<BenchmarkRecord, SimError> {
        let rec = self.multisine_record(ms, 2)?;
        let n = ms.period_samples();
        Ok(BenchmarkRecord { u: rec.u[n..].to_vec(), y: rec.y[n..].to_vec() })
    }

    /// The sine-sweep test from rest ([`sine_sweep`]), noise-free.
    pub fn sweep_record(
        &self,
        n: usize,
        f0_hz: f64,
        f1_hz: f64,
        amplitude_n: f64,
    ) -> Result<BenchmarkRecord, SimError> {
        let u_fine = sine_sweep(
            n * UPSAMPLING,
            FS_HZ * UPSAMPLING as f64,
            n as f64 / FS_HZ,
            f0_hz,
            f1_hz,
            amplitude_n,
        )?;
        let y = self.measure(&u_fine)?;
        let u = u_fine.iter().step_by(UPSAMPLING).copied().collect();
        Ok(BenchmarkRecord { u, y })
    }
}

fn invalid(field: &str, requirement: &str) -> SimError {
    SimError::Invalid { field: field.into(), requirement: requirement.into() }
}

/// A random-phase multisine defined on a fine grid: one period of `period_fine` samples.
#[derive(Clone, Debug, PartialEq)]
pub struct Multisine {
    period_fine: Vec<f64>,
    upsampling: usize,
}

impl Multisine {
    /// A realisation of the benchmark's multisine (module docs) for `seed`.
    pub fn benchmark(seed: u64) -> Result<Self, SimError> {
        Self::new(MULTISINE_PERIOD, UPSAMPLING, MULTISINE_LINES, MULTISINE_RMS_N, seed)
    }

    /// Lines `lines.0..=lines.1` of the DFT of a fine period of `period * upsampling`
    /// samples, unit amplitudes, phases uniform in `[0, 2π)` (seeded xoshiro256++), scaled to
    /// the standard deviation `rms` (`N−1` normalised).
    pub fn new(
        period: usize,
        upsampling: usize,
        lines: (usize, usize),
        rms: f64,
        seed: u64,
    ) -> Result<Self, SimError> {
        let nf = period * upsampling;
        if period < 2 || upsampling == 0 {
            return Err(invalid("period", "must be >= 2 with upsampling >= 1"));
        }
        if lines.0 == 0 || lines.0 > lines.1 || 2 * lines.1 >= period {
            return Err(invalid("lines", "must satisfy 1 <= first <= last < period/2"));
        }
        if !(rms.is_finite() && rms > 0.0) {
            return Err(invalid("rms", "must be finite and > 0"));
        }
        let mut rng = Rng::new(seed, 0x6d75_6c74_6973_696e);
        let mut spec = vec![Complex::new(0.0, 0.0); nf];
        for line in spec.iter_mut().take(lines.1 + 1).skip(lines.0) {
            let phase = core::f64::consts::TAU * (1.0 - rng.uniform_open0());
            *line = Complex::from_polar(1.0, phase);
        }
        FftPlanner::new().plan_fft_inverse(nf).process(&mut spec);
        // 2·Re(ifft): rustfft's inverse is unnormalised.
        let mut x: Vec<f64> = spec.iter().map(|c| 2.0 * c.re / nf as f64).collect();
        let mean = x.iter().sum::<f64>() / nf as f64;
        let std = (x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (nf - 1) as f64).sqrt();
        for v in &mut x {
            *v *= rms / std;
        }
        Ok(Self { period_fine: x, upsampling })
    }

    /// One period on the fine grid.
    pub fn period_fine(&self) -> &[f64] {
        &self.period_fine
    }

    /// Samples per period at the coarse rate.
    pub fn period_samples(&self) -> usize {
        self.period_fine.len() / self.upsampling
    }

    /// `periods` periods on the fine grid.
    pub fn repeat(&self, periods: usize) -> Vec<f64> {
        self.period_fine.repeat(periods)
    }
}

/// A linear sine sweep `A sin(2π(f₀ t + (f₁ − f₀) t²/(2T)))` at `t = j/fs_hz`, `j < n`.
pub fn sine_sweep(
    n: usize,
    fs_hz: f64,
    duration_s: f64,
    f0_hz: f64,
    f1_hz: f64,
    amplitude: f64,
) -> Result<Vec<f64>, SimError> {
    for (field, x) in [("fs_hz", fs_hz), ("duration_s", duration_s)] {
        if !(x.is_finite() && x > 0.0) {
            return Err(invalid(field, "must be finite and > 0"));
        }
    }
    if !(f0_hz.is_finite() && f1_hz.is_finite() && amplitude.is_finite()) {
        return Err(invalid("sweep", "frequencies and amplitude must be finite"));
    }
    let rate = (f1_hz - f0_hz) / (2.0 * duration_s);
    Ok((0..n)
        .map(|j| {
            let t = j as f64 / fs_hz;
            amplitude * (core::f64::consts::TAU * (f0_hz * t + rate * t * t)).sin()
        })
        .collect())
}

/// MATLAB's `fir1(30, 1/r)`: a Hamming-windowed sinc of [`FIR_TAPS`] taps, cut-off `1/r` of
/// Nyquist, scaled to unit DC gain.
pub fn fir_lowpass(r: usize) -> [f64; FIR_TAPS] {
    let mut b = [0.0; FIR_TAPS];
    let wn = 1.0 / r as f64;
    let centre = (FIR_TAPS - 1) as f64 / 2.0;
    for (i, bi) in b.iter_mut().enumerate() {
        let x = i as f64 - centre;
        let sinc = if x == 0.0 {
            1.0
        } else {
            (core::f64::consts::PI * wn * x).sin() / (core::f64::consts::PI * wn * x)
        };
        let window = 0.54 - 0.46 * (core::f64::consts::TAU * i as f64 / (FIR_TAPS - 1) as f64).cos();
        *bi = wn * sinc * window;
    }
    let sum: f64 = b.iter().sum();
    for bi in &mut b {
        *bi /= sum;
    }
    b
}

/// MATLAB's `decimate(x, r, 'fir')` (module docs): `ceil(n/r)` samples, output `i` the
/// zero-phase filtered signal at input sample `r i`, the ends extended by odd reflection.
/// Needs at least `2·FIR_TAPS + 1` samples when `r > 1`; `r = 1` returns `x`.
pub fn decimate_fir(x: &[f64], r: usize) -> Result<Vec<f64>, SimError> {
    if r == 0 {
        return Err(invalid("r", "must be >= 1"));
    }
    if r == 1 {
        return Ok(x.to_vec());
    }
    let n = x.len();
    if n <= 2 * FIR_TAPS {
        return Err(invalid("x", "needs more than 62 samples to decimate"));
    }
    let b = fir_lowpass(r);
    let half = (FIR_TAPS / 2) as isize;
    let last = n as isize - 1;
    let at = |j: isize| -> f64 {
        if j < 0 {
            2.0 * x[0] - x[(-j) as usize]
        } else if j > last {
            2.0 * x[last as usize] - x[(2 * last - j) as usize]
        } else {
            x[j as usize]
        }
    };
    let nout = n.div_ceil(r);
    let mut out = Vec::with_capacity(nout);
    for i in 0..nout {
        let c = (i * r) as isize;
        let s = if c >= half && c + half <= last {
            let w = &x[(c - half) as usize..=(c + half) as usize];
            b.iter().zip(w).map(|(bi, xi)| bi * xi).sum()
        } else {
            b.iter().enumerate().map(|(k, bk)| bk * at(c - half + k as isize)).sum()
        };
        out.push(s);
    }
    Ok(out)
}

/// The benchmark's decimation from the fine grid to [`FS_HZ`]: [`decimate_fir`] by 2, 2
/// and 5 in turn.
pub fn decimate_benchmark(y_fine: &[f64]) -> Result<Vec<f64>, SimError> {
    decimate_chain(y_fine, UPSAMPLING)
}

/// [`decimate_fir`] by each prime factor of `factor` in increasing order (MATLAB's
/// `factor`), as the benchmark decimates by its upsampling factor.
pub fn decimate_chain(y_fine: &[f64], factor: usize) -> Result<Vec<f64>, SimError> {
    let mut y = y_fine.to_vec();
    for r in prime_factors(factor) {
        y = decimate_fir(&y, r)?;
    }
    Ok(y)
}

/// Prime factors of `n` in increasing order, with multiplicity (`[]` for 0 and 1).
pub fn prime_factors(mut n: usize) -> Vec<usize> {
    let mut out = Vec::new();
    let mut p = 2;
    while n > 1 && p * p <= n {
        while n % p == 0 {
            out.push(p);
            n /= p;
        }
        p += 1;
    }
    if n > 1 {
        out.push(n);
    }
    out
}

/// Band-limited (DFT) interpolation of a periodic signal: `x` holds whole periods of
/// `period` samples (only the first is used); returns one period at `upsampling` times the
/// rate. Exact for a signal with no content at or above half the coarse rate, as the
/// benchmark's multisine; the Nyquist line of an even period is split evenly.
pub fn interpolate_periodic(x: &[f64], period: usize, upsampling: usize) -> Result<Vec<f64>, SimError> {
    if period < 2 || x.len() < period || upsampling == 0 {
        return Err(invalid("period", "must be >= 2, at most the record's length, upsampling >= 1"));
    }
    if x[..period].iter().any(|v| !v.is_finite()) {
        return Err(invalid("x", "must be finite"));
    }
    let nf = period * upsampling;
    let mut planner = FftPlanner::new();
    let mut spec: Vec<Complex<f64>> = x[..period].iter().map(|&v| Complex::new(v, 0.0)).collect();
    planner.plan_fft_forward(period).process(&mut spec);
    let mut fine = vec![Complex::new(0.0, 0.0); nf];
    let half = period / 2;
    for k in 0..period {
        if period % 2 == 0 && k == half {
            // The Nyquist line, split between +N/2 and −N/2.
            fine[half] += spec[k] * 0.5;
            fine[nf - half] += spec[k] * 0.5;
        } else if k < half || (period % 2 == 1 && k == half) {
            fine[k] = spec[k];
        } else {
            fine[nf - (period - k)] = spec[k];
        }
    }
    planner.plan_fft_inverse(nf).process(&mut fine);
    Ok(fine.iter().map(|c| c.re / period as f64).collect())
}

/// Adds white Gaussian noise of standard deviation `sigma` to `y` (seeded xoshiro256++).
pub fn add_noise(y: &mut [f64], sigma: f64, seed: u64) {
    let mut rng = Rng::new(seed, 0x6e_6f69_7365);
    for v in y {
        *v += sigma * rng.normal();
    }
}

/// One trapezoidal step's corrector (see the module docs): from the state at `t`,
/// `[y, v, z, ÿ, ż]`, and the input `u1` at `t + h`, the velocity and hysteretic force
/// `(v', z')` at `t + h`, by Newton's method on the two implicit equations started from an
/// explicit Euler predictor, to 10⁻¹³ relative (at most 30 iterations; it stops on a
/// non-finite step, which the caller sees in its state). `mck` is `[m, c, k]`; `rate(v, z)`
/// gives `ż = g(v, z)` with `∂g/∂v` and `∂g/∂z`. The virtual oscillator and the fitted
/// model's simulator (which also carries sensitivities) share it.
#[inline]
pub fn corrector(
    mck: [f64; 3],
    h: f64,
    at: [f64; 5],
    u1: f64,
    rate: impl Fn(f64, f64) -> (f64, f64, f64),
) -> (f64, f64) {
    let [m, c, k] = mck;
    let [y, v, z, acc, g] = at;
    let hh = 0.5 * h;
    // ∂R1/∂v' is constant: 1 + h/2 (c + k h/2)/m.
    let j11 = 1.0 + hh * (c + k * hh) / m;
    let j12 = hh / m;
    // Predictor: explicit Euler.
    let mut v1 = v + h * acc;
    let mut z1 = z + h * g;
    let mut iter = 0;
    loop {
        let y1 = y + hh * (v + v1);
        let a1 = (u1 - c * v1 - k * y1 - z1) / m;
        let (g1, gv, gz) = rate(v1, z1);
        let r1 = v1 - v - hh * (acc + a1);
        let r2 = z1 - z - hh * (g + g1);
        let (j21, j22) = (-hh * gv, 1.0 - hh * gz);
        let det = j11 * j22 - j12 * j21;
        let dv = (r1 * j22 - j12 * r2) / det;
        let dz = (j11 * r2 - j21 * r1) / det;
        v1 -= dv;
        z1 -= dz;
        iter += 1;
        let small = dv.abs() <= 1e-13 * (v1.abs() + 1e-12) && dz.abs() <= 1e-13 * (z1.abs() + 1e-9);
        if small || iter >= 30 || !(dv.is_finite() && dz.is_finite()) {
            return (v1, z1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fir_matches_matlab_fir1() {
        // fir1(30, 0.5): centre tap and first taps, from the closed form.
        let b = fir_lowpass(2);
        assert!((b.iter().sum::<f64>() - 1.0).abs() < 1e-14);
        // Odd taps away from the centre vanish for a half-band filter.
        assert!(b[16].abs() > 0.0 && b[17].abs() < 1e-15 && b[13].abs() < 1e-15);
        assert!((b[0] - b[30]).abs() < 1e-18);
    }

    #[test]
    fn decimation_keeps_a_slow_sine_and_its_phase() {
        let n = 4000;
        let x: Vec<f64> = (0..n).map(|j| (0.01 * j as f64).sin()).collect();
        let y = decimate_fir(&x, 5).expect("decimate");
        assert_eq!(y.len(), 800);
        for (i, v) in y.iter().enumerate().skip(10).take(700) {
            assert!((v - x[5 * i]).abs() < 1e-4, "{i}: {v} vs {}", x[5 * i]);
        }
    }

    #[test]
    fn multisine_has_the_benchmark_spec() {
        let ms = Multisine::benchmark(3).expect("multisine");
        let x = ms.period_fine();
        assert_eq!(x.len(), 163_840);
        let n = x.len() as f64;
        let std = (x.iter().map(|v| v * v).sum::<f64>() / (n - 1.0)).sqrt();
        assert!((std - 50.0).abs() < 1e-9);
        // Band-limited interpolation of the coarse samples gives back the fine period.
        let coarse: Vec<f64> = x.iter().step_by(UPSAMPLING).copied().collect();
        let fine = interpolate_periodic(&coarse, MULTISINE_PERIOD, UPSAMPLING).expect("interp");
        let err = fine.iter().zip(x).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(err < 1e-9, "{err}");
    }

    #[test]
    fn small_drive_is_the_linear_mode() {
        // At 1 mN the loop is linear: z ≈ α y, resonance at √((k+α)/m).
        let osc = BoucWenOscillator::default();
        let fs = FS_HZ * UPSAMPLING as f64;
        let f = 10.0;
        // 8 s: the start-up transient (time constant 0.4 s) is gone from the last 3 s.
        let n = (fs * 8.0) as usize;
        let u: Vec<f64> = (0..n).map(|j| 1e-3 * (core::f64::consts::TAU * f * j as f64 / fs).sin()).collect();
        let (y, _) = osc.integrate(&u, 1.0 / fs, OscillatorState::default()).expect("integrate");
        let w = core::f64::consts::TAU * f;
        let keff = osc.stiffness_n_per_m + osc.alpha_n_per_m;
        let gain = 1e-3 / ((keff - osc.mass_kg * w * w).powi(2) + (osc.damping_n_s_per_m * w).powi(2)).sqrt();
        let peak = y[5 * n / 8..].iter().fold(0.0f64, |a, v| a.max(v.abs()));
        assert!((peak / gain - 1.0).abs() < 2e-3, "{peak} vs {gain}");
    }

    #[test]
    fn bad_input_is_an_error() {
        let osc = BoucWenOscillator::default();
        let r = osc.integrate(&[0.0, f64::NAN], 1e-4, OscillatorState::default());
        assert_eq!(r.unwrap_err(), SimError::NonFiniteInput { sample: 1 });
        let bad = BoucWenOscillator { mass_kg: 0.0, ..osc };
        assert!(bad.validate().is_err());
    }
}
