//! The causes a sine diagnosis tries beyond harmonics and drift, and how each is fitted:
//! saturation of the drive or of the output, creep, and an input delay (see
//! [`crate::diagnose`] for how they enter the search, [`crate::model::terms`] for the model).
//!
//! ## Evidence
//! - **Saturation of the output** (a sensor's range, a mechanical stop): the output sits on
//!   a plateau at its largest or smallest value ([`plateaus`]): at least [`PLATEAU_SHARE`]
//!   of the samples within the noise of the extreme. The level is measured there.
//! - **Saturation of the drive** (an amplifier's rails): the output's odd harmonics form a
//!   series ([`clipping_series`]): at least two of the 3rd to 9th reach
//!   [`SERIES_REL`] of the fundamental, as a flattened sine's do; a stiffening shaped by a
//!   resonance forces one harmonic mostly. The clamp's series enters before the structure,
//!   whose resonance near one harmonic can raise it far above the rest and leave the others
//!   rolled off below the mark: the output's harmonics taken back through the baseline's
//!   structure ([`before_structure`]) count too.
//! - **Creep**: a drive that holds a level away from the rest (an offset): creep follows the
//!   drive's level, so it shows after a step of level; a drift line competes with it and the
//!   one that lowers the held-out error more is kept. Under a drive about 0 V a slow trend
//!   is drift.
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
//! refined with the rest of the model ([`crate::fit::refine`]). The host's delay is
//! fitted with the clamp: the clamp puts harmonics into the drive whose phases against the
//! fundamental the actuator's delay sets (a sampled actuator answers about a sample late),
//! and a single sine's structure absorbs the delay at the fundamental only (on saturation
//! seed 1008 of `crate::fixtures::effects` (feature `fixtures`) the fit at the true level leaves 0.21 µm with the delay
//! at 0 and 0.039 µm with it fitted, the noise). The delay freed with the clamp may also
//! carry what is not a clamp, so the clamp is kept only if it fits [`CLAMP_BEYOND_DELAY`]
//! better than the model with the delay alone, and with a delay below
//! [`MIN_DELAY_SAMPLES`] (a longer one is the delay term's, found from the step). A clamped
//! output is refined from the current model, from it enlarged, and from a fit to the output
//! with its clipped samples filled in; creep from the current model.

use crate::diagnose::{Candidate, Kind, Residual, ordinal};
use crate::fit::{self, Averaging, DelaySearch, FitError, OeOptions, Samples};
use crate::fit::{Criterion, refine};
use crate::model::terms::{Param, Relaxation, TermModel, Terms};
use crate::model::{Branch, HostModel, ModelSpec};
use crate::signal::analysis::{self, Tone};
use rayon::prelude::*;

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
    let (lo, hi) = analysis::extent(y);
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
pub const SERIES_REL: f64 = 0.005;

/// Whether the output's harmonics `out` (fundamental first) form a clipping series: at
/// least two of the odd harmonics 3 to 9 reach [`SERIES_REL`] of the fundamental.
pub fn clipping_series(out: &[Tone]) -> bool {
    let Some(f1) = out.first().map(|t| t.amp).filter(|a| *a > 0.0) else { return false };
    [3usize, 5, 7, 9].iter().filter(|&&n| out.get(n - 1).is_some_and(|t| t.amp >= SERIES_REL * f1)).count()
        >= 2
}

/// The output's harmonics `out` (fundamental first) as they were before the structure
/// `G = 1/(1 − a1 z⁻¹ − a2 z⁻²)` (`ar`, sample interval `ts`): each divided by `G`'s gain at
/// its frequency relative to the fundamental's. A clamped drive's series enters before the
/// structure, which may raise one harmonic at its resonance far above the others and roll
/// the rest off below [`SERIES_REL`].
pub fn before_structure(out: &[Tone], ar: [f64; 2], ts: f64) -> Vec<Tone> {
    let gain = |f_hz: f64| {
        let w = std::f64::consts::TAU * f_hz * ts;
        let (re, im) =
            (1.0 - ar[0] * w.cos() - ar[1] * (2.0 * w).cos(), ar[0] * w.sin() + ar[1] * (2.0 * w).sin());
        1.0 / re.hypot(im).max(1e-300)
    };
    let g1 = out.first().map_or(1.0, |t| gain(t.freq_hz));
    out.iter().map(|t| Tone { amp: t.amp * g1 / gain(t.freq_hz).max(1e-300), ..*t }).collect()
}

/// The saturation and creep terms a record calls for (see the module docs): a clamp of the
/// output where it sits on plateaus (`y` is the steady part of the output, `noise_um` its
/// noise floor), a clamp of the drive where its harmonics `out` form a series, creep where
/// (or the same harmonics taken back through the baseline's structure `ar`, see
/// [`before_structure`]), creep where
/// the drive `u` holds a level of at least [`CREEP_LEVEL_REL`] of its amplitude `amp_v` away
/// from the rest at 0 V (a step of level the creep follows; under a drive about 0 V the
/// actuator's level does not change, and a slow trend is drift). A saturation's evidence is
/// the RMS of the output's harmonics beyond the fundamental, creep's the trend's RMS.
pub fn candidates(
    residual: &Residual,
    out: &[Tone],
    y: &[f64],
    noise_um: f64,
    (u, amp_v): (&[f64], f64),
    (ar, ts): ([f64; 2], f64),
) -> Vec<Candidate> {
    let power = (residual.rms_um * residual.rms_um).max(1e-300);
    let distortion = (out.iter().skip(1).map(|t| t.amp * t.amp / 2.0).sum::<f64>()).sqrt();
    let periodic =
        (residual.harmonics.iter().skip(1).map(|t| t.amp * t.amp / 2.0).sum::<f64>() / power).min(1.0);
    let saturation = |output_range| Candidate {
        kind: Kind::Saturation,
        order: None,
        freq_hz: 0.0,
        share: periodic,
        amp: distortion,
        evidence_um: distortion,
        output_range,
    };
    let mut c = vec![];
    if let Some(p) = plateaus(y, noise_um) {
        c.push(saturation(Some(p.range())));
    }
    if clipping_series(out) || clipping_series(&before_structure(out, ar, ts)) {
        c.push(saturation(None));
    }
    if analysis::mean(u).abs() >= CREEP_LEVEL_REL * amp_v {
        c.push(Candidate {
            kind: Kind::Creep,
            order: None,
            freq_hz: 0.0,
            share: (residual.trend_rms_um.powi(2) / power).min(1.0),
            amp: residual.trend_rms_um,
            evidence_um: residual.trend_rms_um,
            output_range: None,
        });
    }
    c
}

/// A drive whose mean is this fraction of its amplitude away from 0 V has moved the
/// actuator's level: creep follows such a step.
pub const CREEP_LEVEL_REL: f64 = 0.1;

/// The spec a host model was fitted with: its drive, branches and drift degree.
pub fn spec_of(host: &HostModel) -> ModelSpec {
    ModelSpec {
        drive_hz: host.drive_hz,
        harmonics: host.branches.iter().map(|b| b.order).collect(),
        drift_degree: (!host.drift.is_empty()).then(|| host.drift.len() - 1),
    }
}

/// `model` with `spec`'s branches and drift degree (new weights and coefficients at 0),
/// refined jointly (for a model whose terms act inside or after it, which
/// [`crate::fit::fit_oe`] cannot fit), with its fitting cost.
pub fn refine_with(
    model: &TermModel,
    spec: &ModelSpec,
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
) -> Option<(TermModel, f64)> {
    let mut m = model.clone();
    for &order in &spec.harmonics {
        if !m.host.branches.iter().any(|b| b.order == order) {
            m.host.branches.push(Branch { order, alpha_s: 0.0, alpha_c: 0.0, ar: [0.0, 0.0] });
        }
    }
    if let Some(d) = spec.drift_degree {
        m.host.drift.resize(d + 1, 0.0);
    }
    let free = m.host_params();
    refine(&m, &free, u, y, ts, &criterion(opt, split, ts, REFINE_ITER))
}

/// The clamp levels tried, as fractions of the drive's largest excursion from 0 V.
pub const CLAMP_GRID: [f64; 7] = [0.6, 0.7, 0.75, 0.8, 0.85, 0.9, 0.95];

/// Longest stretch (s) from the fit's start-up the clamp's levels are fitted on: enough
/// periods to average, and a cost that does not grow with the record (the refinement that
/// follows runs on at most [`MAX_REFINE_S`]).
pub const CLAMP_FIT_S: f64 = 10.0;

/// The criterion of a refinement: `opt`'s samples from its start-up on, up to `split`, at
/// most [`MAX_REFINE_S`] of them (`ts` the sample interval).
pub fn criterion(opt: &OeOptions, split: usize, ts: f64, max_iter: usize) -> Criterion {
    let end = match opt.samples {
        Samples::All => split,
        Samples::First(n) => n.min(split),
    };
    Criterion { skip: opt.skip, end: end.min(opt.skip + (MAX_REFINE_S / ts).round() as usize), max_iter }
}

/// Longest criterion of a refinement (s): each of its evaluations is a free run.
pub const MAX_REFINE_S: f64 = 3.0;

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
    fit_host_as(model, spec, u, y, ts, split, opt, DelaySearch::Fixed(model.host.delay))
}

/// As [`fit_host`], with the host's delay fitted too (from `model`'s).
pub fn fit_host_delay(
    model: &TermModel,
    spec: &ModelSpec,
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
) -> Result<(TermModel, f64), FitError> {
    fit_host_as(model, spec, u, y, ts, split, opt, DelaySearch::Fit)
}

/// [`fit_host`] and [`fit_host_delay`]: `spec` fitted to the transformed input with `delay`.
#[allow(clippy::too_many_arguments)]
fn fit_host_as(
    model: &TermModel,
    spec: &ModelSpec,
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
    delay: DelaySearch,
) -> Result<(TermModel, f64), FitError> {
    let ui = model.terms.input(u);
    let o = OeOptions { delay, ..opt.clone() };
    let f = fit::fit_oe(&ui, y, ts, split, spec, std::slice::from_ref(&model.host), &o)?;
    Ok((TermModel { host: f.model, terms: model.terms.clone() }, f.rms_fit))
}

/// The current model with its drive clamped: the level from [`CLAMP_GRID`] whose fit (on at
/// most [`CLAMP_FIT_S`] of the fitted part, the host's delay fitted too) has the lowest
/// fitting error, refined with the rest of the model (both levels and the delay free).
/// `None` unless it fits [`CLAMP_BEYOND_DELAY`] better than the model with its delay fitted
/// and no clamp, with a delay below [`MIN_DELAY_SAMPLES`] (see the module docs).
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
    let o = capped(opt, ts);
    let mut tried: Vec<(TermModel, f64)> = CLAMP_GRID
        .iter()
        .filter_map(|frac| {
            let mut m = model.clone();
            m.terms.input_clamp = Some([-frac * peak, frac * peak]);
            fit_host_delay(&m, spec, u, y, ts, split, &o).ok()
        })
        .collect();
    // The fitting error of a clamped drive has local minima in the level: refine the best
    // few levels of the grid and keep the best.
    tried.sort_by(|a, b| a.1.total_cmp(&b.1));
    let c = criterion(opt, split, ts, REFINE_ITER);
    let (clamped, cost) = tried
        .iter()
        .take(CLAMP_STARTS)
        .filter_map(|(m, _)| {
            let mut free = m.host_params();
            free.extend([Param::InputClamp(0), Param::InputClamp(1), Param::Delay]);
            refine(m, &free, u, y, ts, &c)
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    // The delay the clamp's fit frees may carry what is not a clamp (a longer delay, which
    // changes the phase of the loop's own harmonics): the clamp is kept only if it fits
    // clearly better than the model with the delay alone, fitted the same way.
    let (alone, _) = fit_host_delay(model, spec, u, y, ts, split, &o).ok()?;
    let mut free = alone.host_params();
    free.push(Param::Delay);
    let delay_only = refine(&alone, &free, u, y, ts, &c).map_or(f64::INFINITY, |r| r.1);
    // A delay of [`MIN_DELAY_SAMPLES`] or more is beyond a sampled actuator's own: the delay
    // term's to find from the step onto the drive, not the clamp's to carry.
    (clamped.host.delay < MIN_DELAY_SAMPLES && cost <= (1.0 - CLAMP_BEYOND_DELAY) * delay_only)
        .then_some(clamped)
}

/// A clamp of the drive must lower the fitting error by this fraction beyond the model with
/// its delay fitted and no clamp (see [`fit_input_clamp`]): the share of a term's gain the
/// diagnosis asks for by default ([`crate::diagnose::Thresholds`]' `min_gain`).
pub const CLAMP_BEYOND_DELAY: f64 = 0.2;

/// `opt` on at most [`CLAMP_FIT_S`] from its start-up.
fn capped(opt: &OeOptions, ts: f64) -> OeOptions {
    let cap = opt.skip + (CLAMP_FIT_S / ts).round() as usize;
    let samples = match opt.samples {
        Samples::First(n) => Samples::First(n.min(cap)),
        Samples::All => Samples::First(cap),
    };
    OeOptions { samples, ..opt.clone() }
}

/// Levels of the grid a clamped drive is refined from.
pub const CLAMP_STARTS: usize = 3;

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
    // A model fitted to the clipped output is too small to reach the clamp, and its structure
    // may have bent to imitate the clipping's harmonics: from it, from it enlarged (its loop
    // scaled, see [`scaled`]) so that the clamp acts, and from a fit to the output with the
    // clipped samples filled in ([`unclipped_fit`]), the best fit.
    let c = criterion(opt, split, ts, REFINE_ITER);
    let mut starts: Vec<HostModel> =
        OUTPUT_CLAMP_SCALES.iter().filter_map(|&k| scaled(&model.host, k, u, ts)).collect();
    if model.terms.input_only() {
        starts.extend(unclipped_fit(model, range, u, y, ts, split, opt));
    }
    starts
        .into_iter()
        .filter_map(|host| {
            let mut m = TermModel { host, terms: model.terms.clone() };
            m.terms.output_clamp = Some(range);
            let free = m.host_params();
            refine(&m, &free, u, y, ts, &c)
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|r| r.0)
}

/// A fit (with the structure search) of `model`'s host to the output with the samples on the
/// plateaus of `range` filled in: on a plateau the output is at least as far out as the
/// plateau, so a sample there takes the model's value where the model is beyond it. From the
/// model enlarged by the largest of [`OUTPUT_CLAMP_SCALES`] (on at most [`CLAMP_FIT_S`] of
/// the fitted part). `None` if a fit fails.
pub fn unclipped_fit(
    model: &TermModel,
    range: [f64; 2],
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
) -> Option<HostModel> {
    let [lo, hi] = range;
    let (ymin, ymax) = analysis::extent(y);
    let tol = PLATEAU_REL * (ymax - ymin);
    let largest = OUTPUT_CLAMP_SCALES[OUTPUT_CLAMP_SCALES.len() - 1];
    let m = TermModel { host: scaled(&model.host, largest, u, ts)?, terms: model.terms.clone() };
    let sim = m.simulate(u, ts).ok()?;
    let filled: Vec<f64> = y
        .iter()
        .zip(&sim)
        .map(|(&v, &s)| {
            if v >= hi - tol {
                v.max(s)
            } else if v <= lo + tol {
                v.min(s)
            } else {
                v
            }
        })
        .collect();
    let m = fit_host(&m, &spec_of(&m.host), u, &filled, ts, split, &capped(opt, ts)).ok()?.0;
    Some(m.host)
}

/// The scales of the starts of a clamp of the output (see [`fit_output_clamp`]).
pub const OUTPUT_CLAMP_SCALES: [f64; 3] = [1.0, 1.25, 1.6];

/// `host` with its output about its mean on `u` scaled by `k`: the gain `A1`, the branches'
/// weights and the hysteresis `h` (A and A0 times `k`, γ and β divided by it, which scales
/// `h` exactly), and the offset moved so that the mean stays (the hysteresis' own mean, which
/// the offset balances, is scaled too). `None` if the model cannot run on `u`.
pub fn scaled(host: &HostModel, k: f64, u: &[f64], ts: f64) -> Option<HostModel> {
    let mut h = host.clone();
    let bw = &mut h.ext.bw;
    bw.a1 *= k;
    bw.a *= k;
    bw.a0 *= k;
    bw.gamma /= k;
    bw.beta /= k;
    for b in &mut h.branches {
        b.alpha_s *= k;
        b.alpha_c *= k;
    }
    let before = analysis::mean(&host.simulate(u, ts).ok()?);
    let after = analysis::mean(&h.simulate(u, ts).ok()?);
    if h.drift.is_empty() {
        h.drift.push(0.0);
    }
    h.drift[0] += before - after;
    Some(h)
}

/// Creep states: two relaxations (started as below), their time constants kept between [`MIN_CREEP_TAU_S`] (or ten drive periods) and four
/// times the fitted span, fitted over the whole fitted part.
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
    // From no creep, and from a creep of [`CREEP_START_GAIN`] per state with time constants
    // of an eighth and a half, or a half and twice, the fitted span (the model's loop can
    // imitate a relaxation by ratcheting under a drive with a level, a local optimum the
    // refinement from no creep may not leave); the best fit is kept.
    let c = Criterion { skip: opt.skip, end: split, max_iter: REFINE_ITER };
    let starts = [([0.125, 0.5], 0.0), ([0.125, 0.5], CREEP_START_GAIN), ([0.5, 2.0], CREEP_START_GAIN)];
    starts
        .iter()
        .filter_map(|&(taus, gain)| {
            let mut m = model.clone();
            m.terms.creep_tau_range_s = [lo, hi];
            m.terms.creep =
                taus.iter().map(|&t| Relaxation { tau_s: (t * span_s).clamp(lo, hi), gain }).collect();
            let mut free = m.host_params();
            for j in 0..m.terms.creep.len() {
                free.extend([Param::CreepGain(j), Param::CreepTau(j)]);
            }
            // A relaxation extrapolates from the longest base: the whole fitted part.
            let mut best = refine(&m, &free, u, y, ts, &c);
            if gain > 0.0 && m.terms.input_only_but_creep() {
                // The host refitted to the output less the creep's start: its loop fitted
                // without the relaxation.
                let with = m.simulate(u, ts).ok()?;
                let mut bare = m.clone();
                bare.terms.creep.clear();
                let without = bare.simulate(u, ts).ok()?;
                let target: Vec<f64> =
                    y.iter().zip(with.iter().zip(&without)).map(|(v, (a, b))| v - (a - b)).collect();
                let o = OeOptions { samples: Samples::All, ..opt.clone() };
                if let Ok((h, _)) = fit_host(&bare, &spec_of(&m.host), u, &target, ts, split, &o) {
                    let start = TermModel { host: h.host, terms: m.terms.clone() };
                    if let Some(r) = refine(&start, &free, u, y, ts, &c) {
                        if best.as_ref().is_none_or(|b| r.1 < b.1) {
                            best = Some(r);
                        }
                    }
                }
            }
            best
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|r| r.0)
}

/// The second start of the creep's gains.
pub const CREEP_START_GAIN: f64 = 0.05;

/// Shortest creep time constant (s).
pub const MIN_CREEP_TAU_S: f64 = 0.1;

/// Longest input delay looked for (whole samples).
pub const MAX_DELAY_SHIFT: usize = 20;

/// Length of the delay's criterion after the step onto the drive (s): the start-up and a
/// few periods.
pub const DELAY_WINDOW_S: f64 = 1.0;

/// Levenberg–Marquardt starts of each whole delay's fit in [`delay_scan`] (it ranks the
/// delays; the best is refined).
pub const DELAY_SCAN_STARTS: usize = 2;

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
    /// RMS of the difference of the two models' outputs over that criterion (µm): what the
    /// delay carries.
    pub change_rms_um: f64,
    /// Length of the criterion (s).
    pub window_s: f64,
}

/// Smallest delay named as a finding (samples): a sampled actuator answers about one sample
/// after the paper's instantaneous `A1·u[k]` from its zero-order hold (half a sample) and
/// its driver and transport (the virtual bimorph: 1.1 samples), which the extended model's
/// structure absorbs at one frequency; a delay of two samples or more is beyond that.
pub const MIN_DELAY_SAMPLES: f64 = 2.0;

/// The extended model keeps a delay if its held-out error with the delay is at most this
/// factor of the error without it.
pub const DELAY_HELD_OUT_SLACK: f64 = 1.1;

/// Fits `spec` (with `model`'s input-side terms) over the step onto the drive and the
/// [`DELAY_WINDOW_S`] after it, for every other whole delay `0..=`[`MAX_DELAY_SHIFT`] and the
/// two beside the best of those, refines the best with a fractional delay, and returns it with the fit without a delay (see the
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
    let o = OeOptions {
        skip: 1,
        samples: Samples::First(end),
        averaging: Averaging::Off,
        delay: DelaySearch::Fixed(0.0),
        lm_starts: DELAY_SCAN_STARTS,
        ..opt.clone()
    };
    let fit_at = |shift: usize| {
        let mut m = model.clone();
        m.terms.extra_delay = shift;
        m.host.delay = 0.0;
        // Only the criterion's samples: the transform and the fit do not touch the rest.
        let f = fit::fit_oe(&m.terms.input(&u[..end]), &y[..end], ts, end, spec, &[], &o).ok()?;
        Some((TermModel { host: f.model, terms: m.terms }, f.rms_fit))
    };
    // Every other whole delay, then the two beside the best of those.
    let mut fits: Vec<(TermModel, f64)> =
        (0..=MAX_DELAY_SHIFT).step_by(2).collect::<Vec<_>>().into_par_iter().filter_map(fit_at).collect();
    let coarse_best = fits.iter().min_by(|a, b| a.1.total_cmp(&b.1))?.0.terms.extra_delay;
    let beside: Vec<usize> = [coarse_best.checked_sub(1), Some(coarse_best + 1)]
        .into_iter()
        .flatten()
        .filter(|&s| s <= MAX_DELAY_SHIFT && s % 2 == 1)
        .collect();
    fits.extend(beside.into_par_iter().filter_map(fit_at).collect::<Vec<_>>());
    let (no_delay, without) = fits.iter().find(|f| f.0.terms.extra_delay == 0).cloned()?;
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
    let (a, b) = (model.simulate(&u[..end], ts).ok()?, no_delay.simulate(&u[..end], ts).ok()?);
    let change_rms_um = analysis::rms_diff(&a[1..], &b[1..]);
    Some(DelayScan {
        model,
        samples,
        rms_without_um: without,
        rms_with_um: with,
        change_rms_um,
        window_s: (end - 1) as f64 * ts,
    })
}

/// Share of the output's swing a drive kept within a sensor's range leaves to spare on each
/// side ([`drive_within_range`]).
pub const RANGE_MARGIN: f64 = 0.1;

/// The fraction `k < 1` of the drive's swing with which the output would stay inside the
/// range of `model`'s output clamp, with [`RANGE_MARGIN`] of the swing to spare on each side:
/// the drive a record should be measured with so that the sensor sees the whole loop. The
/// model, its clamp removed, is simulated under the record's drive `u`; from sample `from`
/// on, its excursion on each clamped side, measured from the middle of its swing, is scaled
/// down to the range. The deflection is taken to scale with the drive (the loop's shape
/// does not, hence the margin); the model is not simulated at the smaller drive, where a
/// loop fitted at one amplitude need not hold (a fit outside the Bouc–Wen model's bounded
/// class holds only the amplitude it was fitted at). `None` without an output clamp, or when
/// the model's output stays inside already.
pub fn drive_within_range(model: &TermModel, u: &[f64], ts: f64, from: usize) -> Option<f64> {
    let [lo, hi] = model.terms.output_clamp?;
    let mut open = model.clone();
    open.terms.output_clamp = None;
    let sim = open.simulate(u, ts).ok()?;
    let tail = sim.get(from..).filter(|t| !t.is_empty())?;
    let (a, b) = analysis::extent(tail);
    if !(a.is_finite() && b.is_finite() && b > a) {
        return None;
    }
    let centre = 0.5 * (a + b);
    let half = 0.5 * (b - a);
    // The half-swing each side allows, the margin of the whole swing kept free.
    let room = |limit: f64| (limit - centre).abs() / (1.0 + 2.0 * RANGE_MARGIN);
    let mut k: f64 = 1.0;
    if b > hi {
        k = k.min(room(hi) / half);
    }
    if a < lo {
        k = k.min(room(lo) / half);
    }
    (k < 1.0 && k > 0.0).then_some(k)
}

/// The cause of a saturation in words, and its level: a clamped drive (the levels in V of
/// `u`, the series of odd harmonics it puts in the output `out`) or a clamped output (the
/// level in µm and the share of the steady output `y` on it; `noise_um` its noise floor).
/// `step` says what the term did to the held-out RMS.
pub fn explain_saturation(
    terms: &Terms,
    c: &Candidate,
    step: &str,
    out: &[Tone],
    y: &[f64],
    noise_um: f64,
    within_range: Option<(f64, f64)>,
) -> (String, Option<(f64, &'static str)>) {
    match (c.output_range, terms.input_clamp) {
        (Some(range), _) => {
            let p = plateaus(y, noise_um);
            let big = crate::record::Y_LIMIT_UM;
            let sides: Vec<String> = [(range[1], "above"), (range[0], "below")]
                .iter()
                .filter(|(v, _)| v.abs() < big)
                .map(|(v, side)| format!("{v:.3} µm (nothing {side} it)"))
                .collect();
            let level = if range[1] < big { range[1] } else { range[0] };
            let share = p.map_or(0.0, |p| p.share);
            let advice = within_range.map_or(String::new(), |(k, amp)| {
                format!(
                    "; the rest of this diagnosis rests on the {:.0} % of the samples inside the range: a record \
                     driven with at most {:.3} V of amplitude ({:.0} % of this drive) keeps the model's output inside \
                     it and shows the whole loop",
                    100.0 * (1.0 - share),
                    k * amp,
                    100.0 * k
                )
            });
            (
                format!(
                    "saturation of the output: it sits flat at {} in {:.0} % of the samples, a sensor's range or a \
                     mechanical stop; the model should not be fitted across it: with the output clamped there the \
                     samples beyond it no longer pull the fit; {step}{advice}",
                    sides.join(" and "),
                    100.0 * share
                ),
                Some((level, "µm")),
            )
        }
        (None, Some([lo, hi])) => {
            let f1 = out.first().map_or(0.0, |t| t.amp).max(1e-300);
            let series: Vec<String> = [3usize, 5, 7, 9]
                .iter()
                .filter_map(|&n| {
                    out.get(n - 1).map(|t| format!("{} {:.1} %", ordinal(n as u32), 100.0 * t.amp / f1))
                })
                .collect();
            (
                format!(
                    "saturation of the drive: the actuator stops following it beyond {lo:.3} V and {hi:.3} V of u \
                     (an amplifier's rails; the level at which the model's drive, clamped, fits best), which puts a \
                     series of odd harmonics in the output ({}); the model should not be fitted across it: with the \
                     drive clamped there, {step}",
                    series.join(", ")
                ),
                Some((hi.abs().max(lo.abs()), "V")),
            )
        }
        (None, None) => (format!("saturation: {step}"), None),
    }
}

/// The cause of creep in words: its relaxations, and the trend of the baseline's residual
/// it replaces. `step` says what the term did to the held-out RMS.
pub fn explain_creep(terms: &Terms, residual: &Residual, step: &str) -> String {
    let states: Vec<String> = terms
        .creep
        .iter()
        .filter(|c| c.gain > 0.0)
        .map(|c| format!("{:.2} s ({:.1} % of the deflection the drive asks for)", c.tau_s, 100.0 * c.gain))
        .collect();
    format!(
        "creep: the output relaxes slowly after the drive, with time constants {}; the baseline's residual holds a \
         slow part of {:.3} µm RMS (mean {:.3} µm, slope {:.4} µm/s) that follows the drive's history rather than a \
         straight line; {step}",
        if states.is_empty() { "none left after the fit".to_string() } else { states.join(" and ") },
        residual.trend_rms_um,
        residual.trend_mean_um,
        residual.trend_slope_um_per_s,
    )
}

/// The cause of an input delay in words: the delay, its gain on the start-up, and the held-out
/// RMS of the extended model without and (if it was kept) with it.
pub fn explain_delay(
    scan: &DelayScan,
    ts: f64,
    held_out_before_um: f64,
    held_out_after_um: Option<f64>,
) -> String {
    let gain = 100.0 * (1.0 - scan.rms_with_um / scan.rms_without_um.max(1e-300));
    let held = match held_out_after_um {
        Some(a) => format!(
            "the extended model carries it: held-out RMS {a:.4} µm ({held_out_before_um:.4} µm without)"
        ),
        None => format!(
            "it is not added to the extended model: with it the held-out RMS would rise above {:.0} % of its \
             {held_out_before_um:.4} µm",
            100.0 * DELAY_HELD_OUT_SLACK
        ),
    };
    format!(
        "input delay: the output answers the step onto the drive {:.1} samples ({:.2} ms) after the drive, beyond \
         the {MIN_DELAY_SAMPLES:.0} samples a sampled actuator's hold and driver explain; a single sine cannot tell \
         a delay from the structure's phase (the model absorbs it by moving its resonance), but the step excites \
         every frequency: fitted over the start-up and the first {:.1} s with the delay, the model's RMS error \
         there falls from {:.4} to {:.4} µm ({gain:.0}%); {held}",
        scan.samples,
        1e3 * scan.samples * ts,
        scan.window_s,
        scan.rms_without_um,
        scan.rms_with_um,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_clipped_output_sits_on_plateaus_a_sine_does_not() {
        let y: Vec<f64> =
            (0..5000).map(|k| 10.0 * (std::f64::consts::TAU * 0.023 * k as f64).sin()).collect();
        assert_eq!(plateaus(&y, 0.01), None);
        let clipped: Vec<f64> = y.iter().map(|v| v.min(8.0)).collect();
        let p = plateaus(&clipped, 0.01).unwrap();
        assert_eq!(p.top, Some(8.0));
        assert_eq!(p.bottom, None);
        assert!((p.share - 0.205).abs() < 0.01, "{}", p.share);
        assert_eq!(p.range()[1], 8.0);
    }

    /// 4000 samples of a unit sine at `f_hz` flattened at ±0.75.
    fn flattened_sine(f_hz: f64, ts: f64) -> Vec<f64> {
        (0..4000).map(|k| (std::f64::consts::TAU * f_hz * k as f64 * ts).sin().clamp(-0.75, 0.75)).collect()
    }

    #[test]
    fn a_flattened_sine_has_a_series_of_odd_harmonics() {
        let ts = 1e-3;
        let x = flattened_sine(10.0, ts);
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

    #[test]
    fn a_series_seen_through_a_resonance_is_taken_back_before_it() {
        // A flattened sine's harmonics through a light resonance at its 3rd harmonic: the 3rd
        // is raised, the 5th to 9th rolled off; taken back through the same structure, the
        // series is the drive's again.
        let ts = 1e-3;
        let x = flattened_sine(20.0, ts);
        let drive = analysis::harmonics(&x, 20.0, ts, 9);
        let w = std::f64::consts::TAU * 60.0 * ts;
        let r = (-0.02 * w).exp();
        let ar = [2.0 * r * w.cos(), -r * r];
        // Through the structure: each harmonic times its gain relative to the fundamental's.
        let gain = |f: f64| {
            let w = std::f64::consts::TAU * f * ts;
            let (re, im) =
                (1.0 - ar[0] * w.cos() - ar[1] * (2.0 * w).cos(), ar[0] * w.sin() + ar[1] * (2.0 * w).sin());
            1.0 / re.hypot(im)
        };
        let through: Vec<Tone> =
            drive.iter().map(|t| Tone { amp: t.amp * gain(t.freq_hz) / gain(20.0), ..*t }).collect();
        assert!(through[2].amp > 5.0 * drive[2].amp);
        let back = before_structure(&through, ar, ts);
        for (b, d) in back.iter().zip(&drive) {
            assert!((b.amp - d.amp).abs() <= 1e-9 * (1.0 + d.amp), "{} vs {}", b.amp, d.amp);
        }
        assert!(clipping_series(&back));
    }
}
