//! The causes a sine diagnosis tries beyond harmonics and drift, and how each is fitted:
//! saturation of the drive or of the output, creep, and an input delay (see
//! [`crate::diagnose::sine`] for how they enter the search, [`crate::model::terms`] for the model).
//!
//! ## Evidence
//! - **Saturation of the output** (a sensor's range, a mechanical stop): the output sits on
//!   a plateau at its largest or smallest value ([`plateaus`]): at least `causes.plateau_share`
//!   of the samples within the noise of the extreme. The level is measured there.
//! - **Saturation of the drive** (an amplifier's rails): the output's odd harmonics form a
//!   series ([`clipping_series`]): at least two of the 3rd to 9th reach
//!   `causes.series_rel` of the fundamental, as a flattened sine's do; a stiffening shaped by a
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
//! (`causes.clamp_grid` of the drive's largest excursion), the best by its fitting error, then
//! refined with the rest of the model ([`crate::fit::refine`]). The host's delay is
//! fitted with the clamp: the clamp puts harmonics into the drive whose phases against the
//! fundamental the actuator's delay sets (a sampled actuator answers about a sample late),
//! and a single sine's structure absorbs the delay at the fundamental only (on saturation
//! seed 1008 of `crate::fixtures::effects` (feature `fixtures`) the fit at the true level leaves 0.21 µm with the delay
//! at 0 and 0.039 µm with it fitted, the noise). The delay freed with the clamp may also
//! carry what is not a clamp, so the clamp is kept only if it fits `causes.clamp_beyond_delay`
//! better than the model with the delay alone, and with a delay below
//! `causes.min_delay_samples` (a longer one is the delay term's, found from the step). A clamped
//! output is refined from the current model, from it enlarged, and from a fit to the output
//! with its clipped samples filled in; creep from the current model.

use super::evidence::{Candidate, Kind};
use super::residual::Residual;
use crate::fit::{self, Averaging, DelaySearch, FitError, OeOptions, Samples};
use crate::fit::{Criterion, refine};
use crate::model::terms::{Param, Relaxation, TermModel};
use crate::model::{Branch, HostModel, ModelSpec};
use crate::rules::{CauseRules, Rules, TermRules};
use crate::signal::analysis::{self, Tone};
use rayon::prelude::*;

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
pub fn plateaus(y: &[f64], noise_um: f64, r: &CauseRules) -> Option<Plateaus> {
    if y.len() < r.min_plateau_samples {
        return None;
    }
    let (lo, hi) = analysis::extent(y);
    let eps = (r.plateau_noise * noise_um).max(r.plateau_rel * (hi - lo));
    let n = y.len() as f64;
    let on = |level: f64| {
        let at: Vec<f64> = y.iter().copied().filter(|v| (v - level).abs() <= eps).collect();
        let share = at.len() as f64 / n;
        (share >= r.plateau_share).then(|| (analysis::mean(&at), share))
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

/// Whether the output's harmonics `out` (fundamental first) form a clipping series: at
/// least two of the odd harmonics `causes.series_orders` reach `causes.series_rel` of the
/// fundamental.
pub fn clipping_series(out: &[Tone], r: &CauseRules) -> bool {
    let Some(f1) = out.first().map(|t| t.amp).filter(|a| *a > 0.0) else { return false };
    let counts = |&n: &u32| out.get(n as usize - 1).is_some_and(|t| t.amp >= r.series_rel * f1);
    r.series_orders.iter().filter(|n| counts(n)).count() >= 2
}

/// The output's harmonics `out` (fundamental first) as they were before the structure
/// `G = 1/(1 − a1 z⁻¹ − a2 z⁻²)` (`ar`, sample interval `ts`): each divided by `G`'s gain at
/// its frequency relative to the fundamental's. A clamped drive's series enters before the
/// structure, which may raise one harmonic at its resonance far above the others and roll
/// the rest off below `causes.series_rel`.
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
/// the drive `u` holds a level of at least `causes.creep_level_rel` of its amplitude `amp_v` away
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
    r: &CauseRules,
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
    if let Some(p) = plateaus(y, noise_um, r) {
        c.push(saturation(Some(p.range())));
    }
    if clipping_series(out, r) || clipping_series(&before_structure(out, ar, ts), r) {
        c.push(saturation(None));
    }
    if analysis::mean(u).abs() >= r.creep_level_rel * amp_v {
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
#[allow(clippy::too_many_arguments)]
pub fn refine_with(
    model: &TermModel,
    spec: &ModelSpec,
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
    t: &TermRules,
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
    refine(&m, &free, u, y, ts, &criterion(opt, split, ts, t))
}

/// The criterion of a refinement: `opt`'s samples from its start-up on, up to `split`, at
/// most `terms.max_refine_s` of them (`ts` the sample interval), `terms.refine_iter`
/// iterations.
pub fn criterion(opt: &OeOptions, split: usize, ts: f64, t: &TermRules) -> Criterion {
    let end = match opt.samples {
        Samples::All => split,
        Samples::First(n) => n.min(split),
    };
    let end = end.min(opt.skip + (t.max_refine_s / ts).round() as usize);
    Criterion { skip: opt.skip, end, max_iter: t.refine_iter }
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

/// The current model with its drive clamped: the level from `causes.clamp_grid` whose fit (on at
/// most `causes.clamp_fit_s` of the fitted part, the host's delay fitted too) has the lowest
/// fitting error, refined with the rest of the model (both levels and the delay free).
/// `None` unless it fits `causes.clamp_beyond_delay` better than the model with its delay fitted
/// and no clamp, with a delay below `causes.min_delay_samples` (see the module docs).
#[allow(clippy::too_many_arguments)]
pub fn fit_input_clamp(
    model: &TermModel,
    spec: &ModelSpec,
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
    rules: &Rules,
) -> Option<TermModel> {
    if !model.terms.input_only() || model.terms.input_clamp.is_some() {
        return None;
    }
    let r = &rules.causes;
    let peak = u[..split].iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let o = capped(opt, ts, r);
    let mut tried: Vec<(TermModel, f64)> = r
        .clamp_grid
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
    let c = criterion(opt, split, ts, &rules.terms);
    let (clamped, cost) = tried
        .iter()
        .take(r.clamp_starts)
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
    // A delay of `causes.min_delay_samples` or more is beyond a sampled actuator's own: the
    // delay term's to find from the step onto the drive, not the clamp's to carry.
    (clamped.host.delay < r.min_delay_samples && cost <= (1.0 - r.clamp_beyond_delay) * delay_only)
        .then_some(clamped)
}

/// `opt` on at most `causes.clamp_fit_s` from its start-up.
fn capped(opt: &OeOptions, ts: f64, r: &CauseRules) -> OeOptions {
    let cap = opt.skip + (r.clamp_fit_s / ts).round() as usize;
    let samples = match opt.samples {
        Samples::First(n) => Samples::First(n.min(cap)),
        Samples::All => Samples::First(cap),
    };
    OeOptions { samples, ..opt.clone() }
}

/// The current model with its output clamped at `range` (µm, measured on the plateaus),
/// refined: samples where the model is beyond the range no longer pull the fit.
#[allow(clippy::too_many_arguments)]
pub fn fit_output_clamp(
    model: &TermModel,
    range: [f64; 2],
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
    rules: &Rules,
) -> Option<TermModel> {
    if model.terms.output_clamp.is_some() {
        return None;
    }
    // A model fitted to the clipped output is too small to reach the clamp, and its structure
    // may have bent to imitate the clipping's harmonics: from it, from it enlarged (its loop
    // scaled, see [`scaled`]) so that the clamp acts, and from a fit to the output with the
    // clipped samples filled in ([`unclipped_fit`]), the best fit.
    let c = criterion(opt, split, ts, &rules.terms);
    let mut starts: Vec<HostModel> =
        rules.causes.output_clamp_scales.iter().filter_map(|&k| scaled(&model.host, k, u, ts)).collect();
    if model.terms.input_only() {
        starts.extend(unclipped_fit(model, range, u, y, ts, split, opt, &rules.causes));
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
/// model enlarged by the largest of `causes.output_clamp_scales` (on at most `causes.clamp_fit_s` of
/// the fitted part). `None` if a fit fails.
#[allow(clippy::too_many_arguments)]
pub fn unclipped_fit(
    model: &TermModel,
    range: [f64; 2],
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
    r: &CauseRules,
) -> Option<HostModel> {
    let [lo, hi] = range;
    let (ymin, ymax) = analysis::extent(y);
    let tol = r.plateau_rel * (ymax - ymin);
    let largest = r.output_clamp_scales.iter().copied().fold(f64::NEG_INFINITY, f64::max);
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
    let m = fit_host(&m, &spec_of(&m.host), u, &filled, ts, split, &capped(opt, ts, r)).ok()?.0;
    Some(m.host)
}

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

/// Creep states: two relaxations (started as below), their time constants kept between
/// `causes.min_creep_tau_s` (or `causes.creep_tau_min_periods` drive periods) and
/// `causes.creep_tau_max_spans` times the fitted span, fitted over the whole fitted part.
#[allow(clippy::too_many_arguments)]
pub fn fit_creep(
    model: &TermModel,
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
    rules: &Rules,
) -> Option<TermModel> {
    if !model.terms.creep.is_empty() {
        return None;
    }
    let r = &rules.causes;
    let span_s = (split - opt.skip.min(split)) as f64 * ts;
    let lo = r.min_creep_tau_s.max(r.creep_tau_min_periods / model.host.drive_hz.max(1e-9));
    let hi = r.creep_tau_max_spans * span_s;
    if hi <= lo {
        return None;
    }
    // From no creep, and from a creep of `causes.creep_start_gain` per state with the time
    // constants of `causes.creep_start_taus` (of the fitted span) (the model's loop can
    // imitate a relaxation by ratcheting under a drive with a level, a local optimum the
    // refinement from no creep may not leave); the best fit is kept.
    let c = Criterion { skip: opt.skip, end: split, max_iter: rules.terms.refine_iter };
    let [short, long] = r.creep_start_taus;
    let starts = [(short, 0.0), (short, r.creep_start_gain), (long, r.creep_start_gain)];
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

/// Fits `spec` (with `model`'s input-side terms) over the step onto the drive and the
/// `causes.delay_window_s` after it, for every other whole delay `0..=``causes.max_delay_shift` and the
/// two beside the best of those, refines the best with a fractional delay, and returns it with the fit without a delay (see the
/// module docs). `None` if no fit succeeds.
#[allow(clippy::too_many_arguments)]
pub fn delay_scan(
    model: &TermModel,
    spec: &ModelSpec,
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
    rules: &Rules,
) -> Option<DelayScan> {
    if !model.terms.input_only() {
        return None;
    }
    let r = &rules.causes;
    let end = split.min(1 + (r.delay_window_s / ts).round() as usize);
    let o = OeOptions {
        skip: 1,
        samples: Samples::First(end),
        averaging: Averaging::Off,
        delay: DelaySearch::Fixed(0.0),
        lm_starts: r.delay_scan_starts,
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
        (0..=r.max_delay_shift).step_by(2).collect::<Vec<_>>().into_par_iter().filter_map(fit_at).collect();
    let coarse_best = fits.iter().min_by(|a, b| a.1.total_cmp(&b.1))?.0.terms.extra_delay;
    let beside: Vec<usize> = [coarse_best.checked_sub(1), Some(coarse_best + 1)]
        .into_iter()
        .flatten()
        .filter(|&s| s <= r.max_delay_shift && s % 2 == 1)
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
    let c = Criterion { skip: 1, end, max_iter: rules.terms.refine_iter };
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

/// The fraction `k < 1` of the drive's swing with which the output would stay inside the
/// range of `model`'s output clamp, with `causes.range_margin` of the swing to spare on each side:
/// the drive a record should be measured with so that the sensor sees the whole loop. The
/// model, its clamp removed, is simulated under the record's drive `u`; from sample `from`
/// on, its excursion on each clamped side, measured from the middle of its swing, is scaled
/// down to the range. The deflection is taken to scale with the drive (the loop's shape
/// does not, hence the margin); the model is not simulated at the smaller drive, where a
/// loop fitted at one amplitude need not hold (a fit outside the Bouc–Wen model's bounded
/// class holds only the amplitude it was fitted at). `None` without an output clamp, or when
/// the model's output stays inside already.
pub fn drive_within_range(model: &TermModel, u: &[f64], ts: f64, from: usize, r: &CauseRules) -> Option<f64> {
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
    let room = |limit: f64| (limit - centre).abs() / (1.0 + 2.0 * r.range_margin);
    let mut k: f64 = 1.0;
    if b > hi {
        k = k.min(room(hi) / half);
    }
    if a < lo {
        k = k.min(room(lo) / half);
    }
    (k < 1.0 && k > 0.0).then_some(k)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_clipped_output_sits_on_plateaus_a_sine_does_not() {
        let y: Vec<f64> =
            (0..5000).map(|k| 10.0 * (std::f64::consts::TAU * 0.023 * k as f64).sin()).collect();
        let r = CauseRules::default();
        assert_eq!(plateaus(&y, 0.01, &r), None);
        let clipped: Vec<f64> = y.iter().map(|v| v.min(8.0)).collect();
        let p = plateaus(&clipped, 0.01, &r).unwrap();
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
        assert!(
            clipping_series(&h, &CauseRules::default()),
            "{:?}",
            h.iter().map(|t| t.amp).collect::<Vec<_>>()
        );
        let pure: Vec<f64> = (0..4000)
            .map(|k| {
                let th = std::f64::consts::TAU * 10.0 * k as f64 * ts;
                th.sin() + 0.1 * (3.0 * th).sin()
            })
            .collect();
        assert!(!clipping_series(&analysis::harmonics(&pure, 10.0, ts, 9), &CauseRules::default()));
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
        assert!(clipping_series(&back, &CauseRules::default()));
    }
}
