//! The output-error fit of the Bouc–Wen oscillator ([`crate::model::oscillator`]).
//!
//! 1. A linear output-error model of orders `nb = 3, nf = 2, nk = 0`
//!    ([`fit_linear_oe`]) gives one mode: `ω₀`, `ζ` and the
//!    static gain `K`, so `k + α = 1/K`, `m = (k + α)/ω₀²`, `c = 2ζω₀m`; the start splits the
//!    stiffness evenly between `k` and `α` with the loop off (`βγ = βδ = 0`, `ν = 1`).
//! 2. Levenberg–Marquardt ([`super::levenberg_marquardt`]) on the simulation error of the scored
//!    samples, with the exact Jacobian from the forward sensitivity equations integrated
//!    alongside the simulation (above); a first pass at [`OscillatorOptions::coarse_substeps`]
//!    steps per sample without the decimation, then the full model, both with `ν = 1`;
//!    with [`OscillatorOptions::fit_nu`] a last pass frees `ν` (kept `≥ 1`).

use super::linear::fit_linear_oe;
use super::lm::{self, Quadratic};
use super::{FitError, Stop, Tolerances};
use crate::model::linear::{LinearModel, OeOrders};
use crate::model::oscillator::*;
use crate::signal::analysis::rms_diff;
use rayon::prelude::*;
use std::ops::Range;

/// Options of [`fit_oscillator`].
#[derive(Clone, Debug, PartialEq)]
pub struct OscillatorOptions {
    /// Integration steps per sample of the fitted model.
    pub substeps: usize,
    /// How the fitted model's output is sampled.
    pub output: OutputSampling,
    /// How the record's input is reconstructed between samples.
    pub input: InputReconstruction,
    /// Fit `ν` (otherwise fixed at 1).
    pub fit_nu: bool,
    /// Ranges of samples scored (empty: all), e.g. every period but one held out; the
    /// simulation always runs from rest at sample 0 through the whole record.
    pub scored: Vec<Range<usize>>,
    /// Steps per sample of a first, cheaper pass (output read at the instants); `None`: no
    /// such pass.
    pub coarse_substeps: Option<usize>,
    /// When Levenberg–Marquardt stops.
    pub tolerances: Tolerances,
}

impl OscillatorOptions {
    /// The benchmark's setting: 20 substeps, FIR decimation, a periodic input of `period`
    /// samples, `ν = 1`, every sample scored, a first pass at 5 substeps.
    ///
    /// ```
    /// use boucwen_lab::fit::oscillator::OscillatorOptions;
    /// use boucwen_lab::model::oscillator::InputReconstruction;
    /// let opt = OscillatorOptions::benchmark(8192);
    /// assert_eq!(opt.input, InputReconstruction::Periodic { period: 8192 });
    /// ```
    pub fn benchmark(period: usize) -> Self {
        Self {
            substeps: 20,
            output: OutputSampling::FirDecimation,
            input: InputReconstruction::Periodic { period },
            fit_nu: false,
            scored: Vec::new(),
            coarse_substeps: Some(5),
            tolerances: Tolerances { cost: 1e-9, step: 1e-9, gradient: 1e-7, max_iter: 100 },
        }
    }
}

/// A fitted oscillator.
#[derive(Clone, Debug)]
pub struct OscillatorFit {
    /// The model.
    pub model: OscillatorModel,
    /// The linear model of one mode it started from.
    pub linear: LinearModel,
    /// RMS of the simulation error over the scored samples (m).
    pub rms_fit: f64,
    /// Why the last Levenberg–Marquardt pass stopped.
    pub stop: Stop,
    /// Iterations of all passes.
    pub iterations: usize,
    /// Simulations (with sensitivities) of all passes.
    pub evaluations: usize,
}

/// The cost and its quadratic model for parameters `x` (first `x.len()` of
/// [`PARAM_NAMES`], `ν = 1` when not among them).
fn evaluate(
    x: &[f64],
    u_fine: &[f64],
    y: &[f64],
    scored: &[Range<usize>],
    h: f64,
    substeps: usize,
    output: OutputSampling,
) -> Option<Quadratic> {
    let p = OscillatorParams::from_slice(x, 1.0);
    if p.m <= 0.0 || p.nu < 1.0 || p.m + p.c + p.k + p.alpha <= 0.0 {
        return None;
    }
    let (yf, sens) = run(&p, u_fine, h, x.len()).ok()?;
    let n = y.len();
    let mut signals = vec![yf];
    signals.extend(sens);
    let sampled: Vec<Vec<f64>> =
        signals.par_iter().map(|s| to_samples(s, n, substeps, output)).collect::<Result<_, _>>().ok()?;
    let idx = || scored.iter().flat_map(|r| r.clone());
    let r: Vec<f64> = idx().map(|i| sampled[0][i] - y[i]).collect();
    let cols: Vec<Vec<f64>> = sampled[1..].iter().map(|s| idx().map(|i| s[i]).collect()).collect();
    let q = Quadratic::from_columns(&r, &cols);
    q.cost.is_finite().then_some(q)
}

/// Fits the oscillator to the record `u` (N), `y` (m) at interval `ts` (s) by output error
/// (module docs).
pub fn fit_oscillator(
    u: &[f64],
    y: &[f64],
    ts: f64,
    opt: &OscillatorOptions,
) -> Result<OscillatorFit, FitError> {
    let n = u.len().min(y.len());
    let (u, y) = (&u[..n], &y[..n]);
    let full = 0..n;
    let scored: &[Range<usize>] =
        if opt.scored.is_empty() { std::slice::from_ref(&full) } else { &opt.scored };
    let count: usize = scored.iter().map(|r| r.len()).sum();
    if scored.iter().any(|r| r.end > n) || count < 100 {
        return Err(FitError::TooFewSamples { have: count.min(n), need: 100 });
    }
    // The linear start is fitted on the longest scored range.
    let longest = scored.iter().max_by_key(|r| r.len()).cloned().unwrap_or(0..n);
    if y.iter().any(|v| !v.is_finite()) {
        return Err(FitError::from(boucwen_core::Error::NonFinite("y")));
    }
    // 1. One linear mode.
    let lin = fit_linear_oe(u, y, OeOrders { nb: 3, nf: 2, nk: 0 }, longest, &opt.tolerances)?;
    let (w0, zeta, gain) = lin.model.mode(ts).ok_or(FitError::NoStableModel)?;
    if !(gain > 0.0 && w0 > 0.0) {
        return Err(FitError::NoStableModel);
    }
    let keff = 1.0 / gain;
    let m = keff / (w0 * w0);
    let mut x: Vec<f64> = vec![m, 2.0 * zeta * w0 * m, 0.5 * keff, 0.5 * keff, 0.0, 0.0];
    // 2. Output error: a coarse pass, then the full model, with ν = 1; then, if asked, the
    //    full model with ν free from there (∂ŷ/∂ν vanishes while the loop is off).
    let mut passes = Vec::new();
    if let Some(cs) = opt.coarse_substeps.filter(|&cs| cs != opt.substeps) {
        passes.push((cs, OutputSampling::Instant, false));
    }
    passes.push((opt.substeps, opt.output, false));
    if opt.fit_nu {
        passes.push((opt.substeps, opt.output, true));
    }
    let (mut iterations, mut evaluations, mut stop, mut cost) = (0, 0, Stop::IterationLimit, f64::NAN);
    for (substeps, output, nu_free) in passes {
        if nu_free {
            x.push(1.0);
        }
        let probe = OscillatorModel { params: OscillatorParams::BENCHMARK, substeps, output };
        // For a periodic input the fine grid reaches past the record (the filter's tail).
        let u_fine = probe.fine_input(u, opt.input)?;
        let h = ts / substeps as f64;
        let eval = |x: &[f64]| evaluate(x, &u_fine, y, scored, h, substeps, output);
        let r = lm::levenberg_marquardt(&x, &opt.tolerances, eval).ok_or(FitError::NoStableModel)?;
        x = r.x;
        iterations += r.iterations;
        evaluations += r.evaluations;
        stop = r.stop;
        cost = r.eval.cost;
    }
    let model = OscillatorModel {
        params: OscillatorParams::from_slice(&x, 1.0),
        substeps: opt.substeps,
        output: opt.output,
    };
    Ok(OscillatorFit {
        model,
        linear: lin.model,
        rms_fit: (cost / count as f64).sqrt(),
        stop,
        iterations,
        evaluations,
    })
}

/// RMS of the model's error on a record simulated from rest, over `scored`.
pub fn free_run_rms(
    model: &OscillatorModel,
    u: &[f64],
    y: &[f64],
    ts: f64,
    input: InputReconstruction,
    scored: Range<usize>,
) -> Result<f64, FitError> {
    let sim = model.simulate_with(u, ts, input)?;
    if scored.end > sim.len().min(y.len()) {
        return Err(FitError::TooFewSamples { have: sim.len().min(y.len()), need: scored.end });
    }
    Ok(rms_diff(&sim[scored.clone()], &y[scored]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sensitivities are the derivatives of the discrete simulation (central
    /// differences agree).
    #[test]
    fn sensitivities_match_finite_differences() {
        let fs = 15_000.0;
        let u: Vec<f64> = (0..6000)
            .map(|j| {
                let t = j as f64 / fs;
                60.0 * (std::f64::consts::TAU * 30.0 * t).sin()
                    + 20.0 * (std::f64::consts::TAU * 71.0 * t).sin()
            })
            .collect();
        let p = OscillatorParams { nu: 1.3, ..OscillatorParams::BENCHMARK };
        let (_, sens) = run(&p, &u, 1.0 / fs, 7).expect("run");
        let base = p.to_vec();
        for j in 0..7 {
            let d = 1e-6 * base[j].abs().max(1.0);
            let mut xp = base;
            let mut xm = base;
            xp[j] += d;
            xm[j] -= d;
            let (yp, _) = run(&OscillatorParams::from_slice(&xp, 1.0), &u, 1.0 / fs, 0).expect("run");
            let (ym, _) = run(&OscillatorParams::from_slice(&xm, 1.0), &u, 1.0 / fs, 0).expect("run");
            let scale = sens[j].iter().fold(0.0f64, |a, v| a.max(v.abs()));
            let err =
                (0..u.len()).map(|i| ((yp[i] - ym[i]) / (2.0 * d) - sens[j][i]).abs()).fold(0.0, f64::max);
            assert!(err < 1e-4 * scale, "{}: {err} vs {scale}", PARAM_NAMES[j]);
        }
    }

    #[test]
    fn spline_reproduces_a_cubic() {
        let u: Vec<f64> = (0..20).map(|i| i as f64 * 0.5).collect();
        let f = natural_spline(&u, 4);
        assert_eq!(f.len(), 19 * 4 + 1);
        for (j, v) in f.iter().enumerate() {
            assert!((v - j as f64 * 0.125).abs() < 1e-12);
        }
    }
}
