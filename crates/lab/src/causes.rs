//! The causes a sine diagnosis tries beyond harmonics and drift, and how each is fitted:
//! saturation of the drive or of the output, creep, and an input delay (see
//! [`crate::diagnose`] for how they enter the search, [`crate::terms`] for the model).
//!
//! ## Evidence
//! - **Saturation of the output** (a sensor's range, a mechanical stop): the output sits on
//!   a plateau at its largest or smallest value ([`plateaus`]): at least [`PLATEAU_SHARE`]
//!   of the samples within the noise of the extreme. The level is measured there.
//! - **Saturation of the drive** (an amplifier's rails): the output's odd harmonics form a
//!   series ([`clipping_series`]): at least three of the 3rd to 9th reach
//!   [`SERIES_REL`] of the fundamental, as a flattened sine's do; a stiffening shaped by a
//!   resonance forces one harmonic mostly.
//! - **Creep**: the residual's slow part, as for a drift line; the two compete and the one
//!   that lowers the held-out error more is kept.
//! - **Input delay**: a single sine cannot tell a delay from the structure's phase (the
//!   extended model bends its structure to absorb any delay at one frequency), but the step
//!   onto the drive excites every frequency: the delay is estimated by fitting the model with
//!   a delayed input over the start-up and the first periods after the step
//!   ([`delay_scan`]).
//!
//! ## Fits
//! A term whose model acts on the input only (a clamped drive, an extra delay) is fitted by
//! [`crate::fit::fit_oe`] on the transformed input: the clamp's level on a grid
//! ([`CLAMP_GRID`] of the drive's largest excursion), the best by its fitting error, then
//! refined with the rest of the model ([`crate::terms::refine`]). A clamped output and creep
//! are refined from the current model.

use crate::analysis::{self, Tone};
use crate::fit::{self, FitError, ModelSpec, OeOptions};
use crate::terms::{Criterion, Param, Relaxation, TermModel, refine};

/// Share of the samples on a plateau at the output's extreme for a saturation of the output.
pub const PLATEAU_SHARE: f64 = 0.05;
/// A sample is on the plateau within this many times the noise floor of the extreme (or
/// [`PLATEAU_REL`] of the output's range, if more).
pub const PLATEAU_NOISE: f64 = 2.0;
/// See [`PLATEAU_NOISE`].
pub const PLATEAU_REL: f64 = 5e-4;

/// The output's plateaus: the levels (µm) it sits at, top and bottom, and the share of the
/// samples on them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plateaus {
    /// The upper level, if the output sits there.
    pub top: Option<f64>,
    /// The lower level, if the output sits there.
    pub bottom: Option<f64>,
    /// Share of the samples on a plateau (both together).
    pub share: f64,
}

impl Plateaus {
    /// The clamp range `[lo, hi]` (µm) they make, the open side at ±[`crate::record::Y_LIMIT_UM`].
    pub fn range(&self) -> [f64; 2] {
        let big = crate::record::Y_LIMIT_UM;
        [self.bottom.unwrap_or(-big), self.top.unwrap_or(big)]
    }
}

/// The plateaus of `y` (see the module docs); `noise_um` is its noise floor. `None` when
/// it sits on neither extreme.
pub fn plateaus(y: &[f64], noise_um: f64) -> Option<Plateaus> {
    if y.len() < 16 {
        return None;
    }
    let (lo, hi) = y.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    let eps = (PLATEAU_NOISE * noise_um).max(PLATEAU_REL * (hi - lo));
    let n = y.len() as f64;
    let on = |level: f64| {
        let at: Vec<f64> = y.iter().copied().filter(|v| (v - level).abs() <= eps).collect();
        let share = at.len() as f64 / n;
        (share >= PLATEAU_SHARE).then(|| (analysis::mean(&at), share))
    };
    let top = on(hi);
    let bottom = on(lo);
    if top.is_none() && bottom.is_none() {
        return None;
    }
    Some(Plateaus {
        top: top.map(|t| t.0),
        bottom: bottom.map(|b| b.0),
        share: top.map_or(0.0, |t| t.1) + bottom.map_or(0.0, |b| b.1),
    })
}

/// A harmonic of a flattened sine counts in its series from this fraction of the
/// fundamental.
pub const SERIES_REL: f64 = 0.01;

/// Whether the output's harmonics `out` (fundamental first) form a clipping series: at
/// least three of the odd harmonics 3 to 9 reach [`SERIES_REL`] of the fundamental.
pub fn clipping_series(out: &[Tone]) -> bool {
    let Some(f1) = out.first().map(|t| t.amp).filter(|a| *a > 0.0) else { return false };
    [3usize, 5, 7, 9].iter().filter(|&&n| out.get(n - 1).is_some_and(|t| t.amp >= SERIES_REL * f1)).count() >= 3
}

/// The clamp levels tried, as fractions of the drive's largest excursion from 0 V.
pub const CLAMP_GRID: [f64; 7] = [0.6, 0.7, 0.75, 0.8, 0.85, 0.9, 0.95];

/// The criterion of a fit (`opt`'s window, at most up to `split`) as a refinement criterion.
pub fn criterion(opt: &OeOptions, split: usize, max_iter: usize) -> Criterion {
    Criterion { skip: opt.skip, end: opt.max_samples.min(split), max_iter }
}

/// Fits `spec` to the input as `model`'s terms transform it (clamp, extra delay), keeping
/// `model`'s own delay, from `model`'s host. Only for terms that act on the input.
pub fn fit_host(
    model: &TermModel,
    spec: &ModelSpec,
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
) -> Result<(TermModel, f64), FitError> {
    let ui = model.terms.input(u);
    let o = OeOptions { delay: Some(model.host.delay), ..opt.clone() };
    let f = fit::fit_oe(&ui, y, ts, split, spec, std::slice::from_ref(&model.host), &o)?;
    Ok((TermModel { host: f.model, terms: model.terms.clone() }, f.rms_fit))
}

/// The current model with its drive clamped: the level from [`CLAMP_GRID`] whose fit has
/// the lowest fitting error, refined with the rest of the model (both levels free).
pub fn fit_input_clamp(
    model: &TermModel,
    spec: &ModelSpec,
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
) -> Option<TermModel> {
    if !model.terms.input_only() || model.terms.input_clamp.is_some() {
        return None;
    }
    let peak = u[..split].iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let tried: Vec<(TermModel, f64)> = CLAMP_GRID
        .iter()
        .filter_map(|frac| {
            let mut m = model.clone();
            m.terms.input_clamp = Some([-frac * peak, frac * peak]);
            fit_host(&m, spec, u, y, ts, split, opt).ok()
        })
        .collect();
    let (best, _) = tried.into_iter().min_by(|a, b| a.1.total_cmp(&b.1))?;
    let mut free = best.host_params();
    free.extend([Param::InputClamp(0), Param::InputClamp(1)]);
    refine(&best, &free, u, y, ts, &criterion(opt, split, REFINE_ITER)).map(|r| r.0)
}

/// Levenberg–Marquardt iterations of a term's refinement.
pub const REFINE_ITER: usize = 30;

/// The current model with its output clamped at `range` (µm, measured on the plateaus),
/// refined: samples where the model is beyond the range no longer pull the fit.
pub fn fit_output_clamp(
    model: &TermModel,
    range: [f64; 2],
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
) -> Option<TermModel> {
    if model.terms.output_clamp.is_some() {
        return None;
    }
    let mut m = model.clone();
    m.terms.output_clamp = Some(range);
    let free = m.host_params();
    refine(&m, &free, u, y, ts, &criterion(opt, split, REFINE_ITER)).map(|r| r.0)
}

/// Creep states: two relaxations, starting at an eighth and a half of the fitted span, kept
/// between [`MIN_CREEP_TAU_S`] (or ten drive periods) and four times the fitted span.
pub fn fit_creep(
    model: &TermModel,
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
) -> Option<TermModel> {
    if !model.terms.creep.is_empty() {
        return None;
    }
    let span_s = (split - opt.skip.min(split)) as f64 * ts;
    let lo = MIN_CREEP_TAU_S.max(10.0 / model.host.drive_hz.max(1e-9));
    let hi = 4.0 * span_s;
    if hi <= lo {
        return None;
    }
    let mut m = model.clone();
    m.terms.creep_tau_range_s = [lo, hi];
    m.terms.creep = [span_s / 8.0, span_s / 2.0]
        .iter()
        .map(|&t| Relaxation { tau_s: t.clamp(lo, hi), gain: 0.0 })
        .collect();
    let mut free = m.host_params();
    for j in 0..m.terms.creep.len() {
        free.extend([Param::CreepGain(j), Param::CreepTau(j)]);
    }
    // A relaxation extrapolates from the longest base: the whole fitted part.
    let c = Criterion { skip: opt.skip, end: split, max_iter: REFINE_ITER };
    refine(&m, &free, u, y, ts, &c).map(|r| r.0)
}

/// Shortest creep time constant (s).
pub const MIN_CREEP_TAU_S: f64 = 0.1;

/// Longest input delay looked for (whole samples).
pub const MAX_DELAY_SHIFT: usize = 20;

/// Length of the delay's criterion after the step onto the drive (s): the start-up and a
/// few periods.
pub const DELAY_WINDOW_S: f64 = 1.0;

/// A delay found from the start-up.
#[derive(Clone, Debug)]
pub struct DelayScan {
    /// The model with the delay (its terms carry the whole samples, its host the fraction).
    pub model: TermModel,
    /// The delay (samples).
    pub samples: f64,
    /// RMS error over the delay's criterion (the start-up and the first periods) of the
    /// model fitted the same way without a delay, and with it (µm).
    pub rms_without_um: f64,
    /// See [`DelayScan::rms_without_um`].
    pub rms_with_um: f64,
}

/// Fits `spec` (with `model`'s input-side terms) over the step onto the drive and the
/// [`DELAY_WINDOW_S`] after it, for every whole delay `0..=`[`MAX_DELAY_SHIFT`], refines
/// the best with a fractional delay, and returns it with the fit without a delay (see the
/// module docs). `None` if no fit succeeds.
pub fn delay_scan(
    model: &TermModel,
    spec: &ModelSpec,
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
) -> Option<DelayScan> {
    if !model.terms.input_only() {
        return None;
    }
    let end = split.min(1 + (DELAY_WINDOW_S / ts).round() as usize);
    let o = OeOptions { skip: 1, max_samples: end, fit_delay: false, delay: Some(0.0), ..opt.clone() };
    let fits: Vec<(TermModel, f64)> = (0..=MAX_DELAY_SHIFT)
        .filter_map(|shift| {
            let mut m = model.clone();
            m.terms.extra_delay = shift;
            m.host.delay = 0.0;
            let f = fit::fit_oe(&m.terms.input(u), y, ts, split, spec, &[], &o).ok()?;
            Some((TermModel { host: f.model, terms: m.terms }, f.rms_fit))
        })
        .collect();
    let without = fits.iter().find(|f| f.0.terms.extra_delay == 0)?.1;
    let (best, at_best) = fits.into_iter().min_by(|a, b| a.1.total_cmp(&b.1))?;
    // The fraction of a sample: from half a sample before the best whole delay.
    let mut start = best.clone();
    start.terms.extra_delay = best.terms.extra_delay.saturating_sub(1);
    start.host.delay = if best.terms.extra_delay > 0 { 1.0 } else { 0.0 };
    let mut free = start.host_params();
    free.push(Param::Delay);
    let c = Criterion { skip: 1, end, max_iter: REFINE_ITER };
    let (model, with) = match refine(&start, &free, u, y, ts, &c) {
        Some((m, r)) if r < at_best => (m, r),
        _ => (best, at_best),
    };
    let samples = model.delay_samples();
    Some(DelayScan { model, samples, rms_without_um: without, rms_with_um: with })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_clipped_output_sits_on_plateaus_a_sine_does_not() {
        let y: Vec<f64> = (0..5000).map(|k| 10.0 * (std::f64::consts::TAU * 0.023 * k as f64).sin()).collect();
        assert_eq!(plateaus(&y, 0.01), None);
        let clipped: Vec<f64> = y.iter().map(|v| v.min(8.0)).collect();
        let p = plateaus(&clipped, 0.01).unwrap();
        assert_eq!(p.top, Some(8.0));
        assert_eq!(p.bottom, None);
        assert!((p.share - 0.205).abs() < 0.01, "{}", p.share);
        assert_eq!(p.range()[1], 8.0);
    }

    #[test]
    fn a_flattened_sine_has_a_series_of_odd_harmonics() {
        let ts = 1e-3;
        let x: Vec<f64> =
            (0..4000).map(|k| (std::f64::consts::TAU * 10.0 * k as f64 * ts).sin().clamp(-0.75, 0.75)).collect();
        let h = analysis::harmonics(&x, 10.0, ts, 9);
        assert!(clipping_series(&h), "{:?}", h.iter().map(|t| t.amp).collect::<Vec<_>>());
        let pure: Vec<f64> = (0..4000)
            .map(|k| {
                let th = std::f64::consts::TAU * 10.0 * k as f64 * ts;
                th.sin() + 0.1 * (3.0 * th).sin()
            })
            .collect();
        assert!(!clipping_series(&analysis::harmonics(&pure, 10.0, ts, 9)));
    }
}
