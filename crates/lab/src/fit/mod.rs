//! Identification on the host: the paper's RLS procedure and an output-error fit.
//!
//! Both produce a [`HostModel`]: the extended model (AR order 2, eq. 9's form) plus
//! harmonic branches of the drive (eqs. 6/7) and, for `diagnose`, an optional drift term
//! (a polynomial in time added at the output). Models are simulated by the core's own
//! [`Model::step`](boucwen_core::model::Model::step) of [`boucwen_core::model::EnhancedParams`], so what is fitted here is exactly what the
//! compensator and the firmware run.
//!
//! ## The paper's procedure ([`fit_paper_rls`])
//! Section 3 as published: running-sum regressors (eq. 10), `P(0) = I`, no forgetting,
//! `A1 = 0.01, A = 0.005, γ = β = 0.001` at the start, one pass over the fitting data
//! ([`boucwen_core::ident::Mode::Paper`]). It minimises the one-step (equation) error, not
//! the free-run error the paper reports, and its `A1`/`A` pair is collinear (see the core's
//! docs).
//!
//! ## Output-error fit ([`fit_oe`])
//! Minimises the free-run simulation error directly, which the paper does not do. By the
//! homogeneity of the Bouc–Wen equation, `h(A, A0, γ, β) = A·h₁` with `h₁` the hysteresis
//! of `A = 1`, `A0/A`, `γ', β` (`γ' = sgn(A)·γ`, [`LoopShape`]), so for fixed *outer*
//! parameters ([`Outer`]: the AR part, the loop shape and the input delay) the output
//! ```text
//! ŷ = G(z)·[A1·u - A·h₁ + Σ_n (α_s sin nθ + α_c cos nθ)] + drift(t),   G = 1/(1 - a1 z⁻¹ - a2 z⁻²)
//! ```
//! is linear in `(A1, A, α, drift)`: they are solved exactly by least squares for every
//! outer point (variable projection), with `A` of the output's sign (the loop lowers the
//! gain; `A = 0` when the unconstrained solution has the other sign). The model is odd in
//! the output (`y → −y` is `A1, A, A0, γ → −A1, −A, −A0, −γ`, the shape `A0/A, γ', β` and
//! the AR part unchanged), so a sensor that counts the stroke downwards gets the mirrored
//! fit: the output's sign is found by [`fit_oe_on`] (from the covariance of drive and
//! output, then the fit of each sign), and invertibility is checked on the model counted
//! upwards ([`upwards`]). (Holding `A ≥ 0` for every record, as this fit first did, left
//! such a record's baseline 3.4 times worse.) The outer
//! parameters are ranked on a coarse grid
//! (AR resonance, loop saturation, delay), and Levenberg–Marquardt refines the best few, in
//! parallel, with the exact Jacobian from forward sensitivity equations computed in the same
//! pass as the simulation ([`problem`](self) module docs) and stops by criteria ([`Stop`]).
//! Unstable AR parts are rejected.
//!
//! ## The data
//! Under a periodic drive in steady state ([`Averaging::Periods`], the default) the fit does
//! not score the record sample by sample: the output's periods after the start-up are
//! averaged first
//! (least squares on the drive's harmonics and a trend of the spec's drift degree over every
//! whole period of the fitted part, so the noise drops by the square root of the number of
//! periods), and the model is scored on that average period. The model is simulated from
//! rest with the record's own drive through a start-up long enough for its transient to die
//! (the skipped start-up, three periods, and the decay of its AR part to 10⁻⁴, at most
//! [`MAX_WARMUP_S`]), and its next whole periods (at least two and
//! [`MIN_WINDOW_SAMPLES`]) are compared with the average period. The cost is then flat in
//! the record's length once the record is long enough to average, and a drift's slope comes
//! from the whole fitted part. An average period cannot show a model whose own output is
//! not periodic (a loop that keeps creeping, a slow pole): each refined model is simulated
//! over the fitted samples (at most [`STEADY_CHECK_S`]) and kept only if its RMS there is
//! within [`STEADY_FACTOR`] of what its criterion and the averaged-out noise and trend
//! predict; if no start passes, the fit is done on those samples. Otherwise (a drive that is not periodic, too few periods) the
//! fit scores every sample of `[skip, fit_end)`, and so it does when the output drifts by
//! more than its noise and the model has no drift term to follow it
//! ([`Averaging::Periods`]); a diagnosis separates the trend instead
//! ([`Averaging::PeriodsAndTrend`]) and models it by a term of its own.

mod error;
pub mod family;
pub mod linear;
mod lm;
mod options;
pub mod oscillator;
mod periodic;
mod problem;
mod refine;
pub mod response;
mod rls;

pub use error::FitError;
pub use lm::{Evaluation, Quadratic, Run, Stop, levenberg_marquardt, levenberg_marquardt_within};
pub use options::{
    Averaging, DelaySearch, LoopSearch, MIN_SLOPE, OeOptions, Outer, Param, Samples, StructureSearch,
    Tolerances, invertible_for, operating_slope, slope_rel, upwards,
};
pub use periodic::{MAX_DRIVE_APERIODIC, MAX_TEMPLATE_ORDER, MIN_PERIODS};
pub use refine::{Criterion, held_out_rms, refine};
pub use rls::fit_paper_rls;

use crate::model::{HostModel, LoopShape, ModelSpec};
use crate::signal::analysis;
use periodic::Template;
use problem::{Eval, Problem, Window};
use rayon::prelude::*;
use std::sync::{Arc, Mutex};

/// Longest start-up simulated before the scored periods (s).
pub const MAX_WARMUP_S: f64 = 10.0;
/// The start-up lasts until the AR part's transient has decayed to this.
const DECAY_TO: f64 = 1e-4;
/// Fewest samples scored against the average period.
pub const MIN_WINDOW_SAMPLES: usize = 500;

/// What the criterion was computed on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DataUsed {
    /// Every sample of `[from, to)`.
    Samples {
        /// First scored sample.
        from: usize,
        /// End of the scored samples.
        to: usize,
    },
    /// The average of the whole periods in `[from, to)`.
    Periods {
        /// First averaged sample.
        from: usize,
        /// End of the averaged samples.
        to: usize,
        /// Periods averaged.
        periods: f64,
        /// Samples of the model's steady state scored against the average period.
        scored: usize,
    },
}

/// The result of a fit: the model, its fitting cost and how the fit ended.
#[derive(Clone, Debug)]
pub struct Fit {
    /// The model.
    pub model: HostModel,
    /// RMS of the free-run error over the criterion (µm): against the samples, or against
    /// the average period (then without the noise the averaging removed).
    pub rms_fit: f64,
    /// The model met the invertibility requirement (always `false` when it was not asked:
    /// not checked). When asked and no invertible model fitted (with the structure fixed,
    /// then free), the best unconstrained model is returned with this `false`.
    pub invertible: bool,
    /// Why the best start's Levenberg–Marquardt run stopped.
    pub stop: Stop,
    /// Its iterations.
    pub iterations: usize,
    /// Criterion evaluations of the whole fit (grid, starts and every run).
    pub evaluations: usize,
    /// What the criterion was computed on.
    pub data: DataUsed,
}

type TemplateKey = (u64, usize, usize, usize);

/// A record prepared for fitting: the fitted part `u[..fit_end]`, `y[..fit_end]` and the
/// average periods computed so far (one per drive frequency, start-up and drift degree),
/// shared by every fit on it.
pub struct FitData<'a> {
    u: &'a [f64],
    y: &'a [f64],
    ts: f64,
    fit_end: usize,
    templates: Mutex<Vec<(TemplateKey, Option<Arc<Template>>)>>,
}

impl<'a> FitData<'a> {
    /// The record `u`, `y` at interval `ts`, fitted on `[..fit_end]`.
    pub fn new(u: &'a [f64], y: &'a [f64], ts: f64, fit_end: usize) -> Self {
        Self { u, y, ts, fit_end, templates: Mutex::new(vec![]) }
    }

    fn end(&self, opt: &OeOptions) -> usize {
        let end = match opt.samples {
            Samples::All => self.fit_end,
            Samples::First(n) => n.min(self.fit_end),
        };
        end.min(self.u.len()).min(self.y.len())
    }

    /// Computes now the average period a fit of `spec` with `opt` will use (a fit computes
    /// it when first needed; preparing it before fits run in parallel computes it once).
    pub fn prepare(&self, spec: &ModelSpec, opt: &OeOptions) {
        let _ = self.template(spec, opt);
    }

    fn template(&self, spec: &ModelSpec, opt: &OeOptions) -> Option<Arc<Template>> {
        if opt.averaging == Averaging::Off || spec.drive_hz.is_nan() || spec.drive_hz <= 0.0 {
            return None;
        }
        let end = self.end(opt);
        let spec_degree = spec.drift_degree.unwrap_or(0);
        // At least a line: its size tells whether the output is in steady state.
        let degree = spec_degree.max(1);
        let key = (spec.drive_hz.to_bits(), opt.skip, end, degree);
        let cached = self
            .templates
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .iter()
            .find(|(k, _)| *k == key)
            .map(|(_, t)| t.clone());
        let t = match cached {
            Some(t) => t,
            None => {
                // Computed outside the lock: it runs in parallel itself.
                let t = Template::new(self.u, self.y, opt.skip, end, spec.drive_hz, self.ts, degree)
                    .map(Arc::new);
                self.templates
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner)
                    .push((key, t.clone()));
                t
            }
        }?;
        let unmodelled_trend =
            t.trend_rms.get(spec_degree..).unwrap_or(&[]).iter().map(|r| r * r).sum::<f64>().sqrt();
        (opt.averaging == Averaging::PeriodsAndTrend || unmodelled_trend <= t.noise_rms).then_some(t)
    }
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
    fit_oe_on(&FitData::new(u, y, ts, fit_end), spec, starts, opt)
}

/// The output's sign of the given start models (a refit keeps the sign it refines).
fn start_sign(starts: &[HostModel]) -> Option<f64> {
    starts.iter().map(|m| m.ext.bw.a1).find(|a| *a != 0.0 && a.is_finite()).map(f64::signum)
}

/// For an output that runs against its drive, the RMS error (over the fitted data) the fit
/// counted upwards must come under, as a share of the fit counted downwards, to be taken
/// ([`fit_oe_on`]).
pub const SIGN_RMS_RATIO: f64 = 0.7;

/// [`fit_oe`] on a prepared record (its average periods are shared between fits).
///
/// The output's sign ([`OeOptions::output_sign`], [`upwards`]): given, or the start
/// models', or upwards, unless the output runs against the drive (their covariance over the
/// fitted part is negative: an output counted downwards, driven below its resonance); then
/// downwards, unless the fit counted upwards leaves under [`SIGN_RMS_RATIO`] of the error
/// of the fit counted downwards (an output counted upwards, driven above its resonance).
/// Records counted upwards and driven below their resonance are fitted as they always
/// were; one counted downwards is fitted as its mirror.
pub fn fit_oe_on(
    data: &FitData<'_>,
    spec: &ModelSpec,
    starts: &[HostModel],
    opt: &OeOptions,
) -> Result<Fit, FitError> {
    if opt.output_sign.is_some() || start_sign(starts).is_some() || opt.hysteresis == LoopSearch::Linear {
        return fit_oe_signed(data, spec, starts, opt);
    }
    let end = data.end(opt).min(data.u.len()).min(data.y.len());
    let from = opt.skip.min(end);
    let (uu, yy) = (&data.u[from..end], &data.y[from..end]);
    let (mu, my) = (analysis::mean(uu), analysis::mean(yy));
    let covariance: f64 = uu.iter().zip(yy).map(|(a, b)| (a - mu) * (b - my)).sum();
    let up = fit_oe_signed(data, spec, starts, &OeOptions { output_sign: Some(1.0), ..opt.clone() });
    if covariance >= 0.0 {
        return up;
    }
    let down = fit_oe_signed(data, spec, starts, &OeOptions { output_sign: Some(-1.0), ..opt.clone() });
    match (up, down) {
        (Ok(u), Ok(d)) => {
            let evaluations = u.evaluations + d.evaluations;
            let mut f = if u.rms_fit < SIGN_RMS_RATIO * d.rms_fit { u } else { d };
            f.evaluations = evaluations;
            Ok(f)
        }
        (Err(_), Ok(d)) => Ok(d),
        (u, _) => u,
    }
}

/// [`fit_oe_on`] with the output's sign as `opt` or the start models give it.
fn fit_oe_signed(
    data: &FitData<'_>,
    spec: &ModelSpec,
    starts: &[HostModel],
    opt: &OeOptions,
) -> Result<Fit, FitError> {
    let mut evaluations = 0;
    if opt.require_invertible {
        // Invertible first; if a fixed loop or structure admits no invertible model, let the
        // loop, then the structure (from the given one), move before giving up invertibility.
        let mut tries = vec![opt.clone()];
        if matches!(opt.hysteresis, LoopSearch::Fixed(_)) {
            tries.push(OeOptions { hysteresis: LoopSearch::Grid, ..opt.clone() });
        }
        if let StructureSearch::Fixed(ar) = opt.structure {
            let hysteresis =
                if opt.hysteresis == LoopSearch::Linear { LoopSearch::Linear } else { LoopSearch::Grid };
            tries.push(OeOptions { structure: StructureSearch::From(ar), hysteresis, ..opt.clone() });
        }
        for o in &tries {
            match fit_once(data, spec, starts, o) {
                Ok(mut fit) => {
                    fit.invertible = true;
                    fit.evaluations += evaluations;
                    return Ok(fit);
                }
                Err((FitError::NoStableModel, n)) => evaluations += n,
                Err((e, _)) => return Err(e),
            }
        }
    }
    let mut fit = fit_once(data, spec, starts, &OeOptions { require_invertible: false, ..opt.clone() })
        .map_err(|(e, _)| e)?;
    fit.evaluations += evaluations;
    Ok(fit)
}

/// How the scored window is placed.
enum Scoring {
    /// `[skip, end)`.
    Samples(Window),
    /// After a start-up from `min_warmup` to `max_warmup` samples (by the AR part's decay),
    /// `len` samples.
    Periods { min_warmup: usize, max_warmup: usize, len: usize },
}

impl Scoring {
    fn window(&self, phi: &Outer) -> Window {
        match *self {
            Scoring::Samples(w) => w,
            Scoring::Periods { min_warmup, max_warmup, len } => {
                let from =
                    crate::model::poles::decay_samples(&phi.ar, DECAY_TO).max(min_warmup).min(max_warmup);
                Window { from, to: from + len }
            }
        }
    }
}

/// One fit with the given options; the error carries the evaluations spent.
fn fit_once(
    data: &FitData<'_>,
    spec: &ModelSpec,
    starts: &[HostModel],
    opt: &OeOptions,
) -> Result<Fit, (FitError, usize)> {
    let (u, y, ts) = (data.u, data.y, data.ts);
    spec.check(ts).map_err(|e| (e.into(), 0))?;
    let end = data.end(opt);
    let need = opt.skip + 200;
    if end < need {
        return Err((FitError::TooFewSamples { have: end, need }, 0));
    }
    let linear = opt.hysteresis == LoopSearch::Linear;
    let mut free = vec![];
    if !matches!(opt.structure, StructureSearch::Fixed(_)) {
        free.extend([Param::Ar1, Param::Ar2]);
    }
    if opt.hysteresis == LoopSearch::Grid {
        free.extend([Param::A0Ratio, Param::Gamma, Param::Beta]);
    }
    if opt.delay == DelaySearch::Fit {
        free.push(Param::Delay);
    }

    // The data: the average period, or the samples.
    let periodic = data.template(spec, opt).and_then(|t| {
        let per = t.period();
        let periods = (2.0f64).max(MIN_WINDOW_SAMPLES as f64 / per).ceil();
        let len = (periods * per).round() as usize;
        let min_warmup = opt.skip.max((3.0 * per).ceil() as usize);
        let max_warmup = (end.checked_sub(len)?).min(opt.skip + (MAX_WARMUP_S / ts) as usize);
        (max_warmup >= min_warmup).then_some((t, min_warmup, max_warmup, len))
    });
    // Under averaging: what the samples must come to in steady state (the noise and the trend
    // the model cannot follow), and how far they are checked.
    let mut steady_check: Option<(f64, usize)> = None;
    let (prob, scoring, used) = match periodic {
        Some((t, min_warmup, max_warmup, len)) => {
            let spec_degree = spec.drift_degree.unwrap_or(0);
            let check_end = end.min(opt.skip + (STEADY_CHECK_S / ts) as usize);
            let unmodelled = t.unmodelled_trend_rms(spec_degree, opt.skip, check_end, ts);
            steady_check = Some((t.noise_rms.hypot(unmodelled), check_end));
            // The trend terms the spec has, beyond the fitted offset.
            let degree = spec.drift_degree.unwrap_or(0);
            let target = t.values(min_warmup, max_warmup + len, degree);
            let trend = t.trend.get(1..=degree).unwrap_or(&[]).to_vec();
            let drift = spec.drift_degree.map(|_| 0);
            let prob = Problem::new(u, ts, spec, target, min_warmup, drift, trend).map_err(|e| (e, 0))?;
            let used = DataUsed::Periods { from: t.from, to: t.to, periods: t.periods, scored: len };
            (prob, Scoring::Periods { min_warmup, max_warmup, len }, used)
        }
        None => {
            let target = y[opt.skip..end].to_vec();
            let prob =
                Problem::new(u, ts, spec, target, opt.skip, spec.drift_degree, vec![]).map_err(|e| (e, 0))?;
            let win = Window { from: opt.skip, to: end };
            (prob, Scoring::Samples(win), DataUsed::Samples { from: opt.skip, to: end })
        }
    };
    let mut prob = prob;
    prob.require_invertible = opt.require_invertible;
    prob.linear = linear;
    prob.sign = opt.output_sign.or_else(|| start_sign(starts)).unwrap_or(1.0);
    let prob = &prob;
    let eval = |phi: &Outer| prob.eval(phi, scoring.window(phi), None);
    let done = |phi: &Outer, e: Eval, stop, iterations, evaluations| Fit {
        model: prob.model(phi, &e.theta),
        rms_fit: (e.cost / e.samples as f64).sqrt(),
        invertible: false,
        stop,
        iterations,
        evaluations,
        data: used,
    };

    let u_amp = u[..end].iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-9);
    let zero_shape = LoopShape { a0_ratio: 0.0, gamma: 0.0, beta: 0.0 };
    let fixed_delay = match opt.delay {
        DelaySearch::Fixed(d) => Some(d),
        DelaySearch::Fit => None,
    };
    let fixed_shape = match opt.hysteresis {
        LoopSearch::Fixed(s) => Some(s),
        LoopSearch::Linear => Some(zero_shape),
        LoopSearch::Grid => None,
    };
    if free.is_empty() {
        // Everything nonlinear is known: one linear solve.
        let phi = Outer {
            ar: opt.structure.ar().unwrap_or([0.0, 0.0]),
            shape: fixed_shape.unwrap_or(zero_shape),
            delay: fixed_delay.unwrap_or(0.0),
        };
        let e = eval(&phi).ok_or((FitError::NoStableModel, 1))?;
        return Ok(done(&phi, e, Stop::LinearSolve, 0, 1));
    }

    // Stage A: structures. A single-frequency record pins only one complex gain of G,
    // which many resonances match, so structures are ranked with a loop present (a middle
    // shape): the loop's harmonics, passing through G, tell them apart.
    let nyq = 0.5 / ts;
    let delays: Vec<f64> = match fixed_delay {
        Some(d) => vec![d],
        None => vec![0.0, 0.5, 1.0, 1.5],
    };
    let mid_shape =
        fixed_shape.unwrap_or(LoopShape { a0_ratio: 0.0, gamma: 0.75 / u_amp, beta: 2.25 / u_amp });
    let ars: Vec<[f64; 2]> = match opt.structure.ar() {
        Some(ar) => vec![ar],
        None => (0..16)
            .flat_map(|i| {
                let f_r = 5.0 * (nyq * 0.9 / 5.0f64).powf(i as f64 / 15.0);
                [0.01, 0.03, 0.1, 0.3, 1.0, 3.0].map(|zeta| crate::model::poles::ar2_of(f_r, zeta, ts))
            })
            .collect(),
    };
    let structures: Vec<Outer> = ars
        .iter()
        .flat_map(|&ar| delays.iter().map(move |&delay| Outer { ar, shape: mid_shape, delay }))
        .collect();
    let mut evaluations = structures.len();
    let mut ranked: Vec<(f64, Outer)> =
        structures.par_iter().filter_map(|phi| eval(phi).map(|e| (e.cost, *phi))).collect();
    ranked.sort_by(|a, b| a.0.total_cmp(&b.0));

    // Stage B: loop shapes on the best structures, and the given start models.
    let shapes: Vec<LoopShape> = match fixed_shape {
        Some(s) => vec![s],
        None => [0.3, 1.0, 3.0, 10.0]
            .into_iter()
            .flat_map(|kappa: f64| {
                [-0.5, 0.5].map(|q| {
                    let sum = kappa / u_amp;
                    LoopShape { a0_ratio: 0.0, gamma: sum * q / 2.0, beta: sum * (1.0 - q / 2.0) }
                })
            })
            .collect(),
    };
    let mut points: Vec<(Outer, f64)> = ranked
        .iter()
        .take(6)
        .flat_map(|&(_, s)| shapes.iter().map(move |&shape| (Outer { shape, ..s }, 1.0)))
        .collect();
    for m in starts {
        let shape = match fixed_shape {
            Some(s) => s,
            None => match m.shape() {
                Some(s) => s,
                None => continue,
            },
        };
        let ar = match opt.structure {
            StructureSearch::Fixed(ar) => ar,
            _ => m.ext.ar,
        };
        // Prefer a given start on ties.
        points.push((Outer { ar, shape, delay: fixed_delay.unwrap_or(m.delay) }, 0.999));
    }
    evaluations += points.len();
    let mut cands: Vec<(f64, Outer)> =
        points.par_iter().filter_map(|(phi, w)| eval(phi).map(|e| (e.cost * w, *phi))).collect();
    cands.sort_by(|a, b| a.0.total_cmp(&b.0));

    // Stage C: Levenberg–Marquardt from the best few, in parallel.
    let free: Vec<Param> = free.into_iter().filter(|&p| prob.differentiable(p)).collect();
    let runs: Vec<(Outer, lm::Run<Eval>)> = cands
        .par_iter()
        .take(opt.lm_starts.max(1))
        .filter_map(|&(_, start)| {
            let win = scoring.window(&start);
            let at = |x: &[f64]| {
                let mut phi = start;
                for (&p, &v) in free.iter().zip(x) {
                    phi.set(p, v);
                }
                phi
            };
            let x0: Vec<f64> = free.iter().map(|&p| start.get(p)).collect();
            let run = lm::levenberg_marquardt(&x0, &opt.tolerances, |x| prob.eval(&at(x), win, Some(&free)))?;
            Some((at(&run.x), run))
        })
        .collect();
    evaluations += runs.iter().map(|r| r.1.evaluations).sum::<usize>();
    let mut runs = runs;
    runs.sort_by(|a, b| a.1.eval.cost.total_cmp(&b.1.eval.cost));
    let Some((floor, check_end)) = steady_check else {
        let (phi, best) = runs.into_iter().next().ok_or((FitError::NoStableModel, evaluations))?;
        return Ok(done(&phi, best.eval, best.stop, best.iterations, evaluations));
    };
    // The average period cannot show a model whose output is not periodic (a loop still
    // creeping, a slow pole): the best run whose free run on the fitted samples comes to what
    // its criterion and the noise predict, else the fit on the samples.
    for (phi, run) in runs {
        let fit = done(&phi, run.eval, run.stop, run.iterations, evaluations);
        let expected = (fit.rms_fit.powi(2) + floor.powi(2)).sqrt();
        let steady = fit.model.simulate(&u[..check_end], ts).is_ok_and(|sim| {
            analysis::rms_diff(&sim[opt.skip..], &y[opt.skip..check_end]) <= STEADY_FACTOR * expected
        });
        if steady {
            return Ok(fit);
        }
    }
    // On the checked stretch: a fit on every sample of a long record would cost as much as
    // the record is long.
    let on_samples =
        OeOptions { averaging: Averaging::Off, samples: Samples::First(check_end), ..opt.clone() };
    let mut fit = fit_once(data, spec, starts, &on_samples).map_err(|(e, n)| (e, n + evaluations))?;
    fit.evaluations += evaluations;
    Ok(fit)
}

/// A fit on the average period is checked on the fitted samples over at most this long (s)
/// after the start-up.
pub const STEADY_CHECK_S: f64 = 20.0;
/// ... and accepted when the free run's RMS there is at most this many times what the
/// criterion and the averaged-out noise and trend predict.
pub const STEADY_FACTOR: f64 = 1.5;

/// Free-run RMS error of `model` on `y[from..]` (simulated from sample 0). Non-finite if
/// the model is unstable.
pub fn free_run_rms(model: &HostModel, u: &[f64], y: &[f64], ts: f64, from: usize) -> Result<f64, FitError> {
    let sim = model.simulate(u, ts)?;
    Ok(analysis::rms_diff(&sim[from..], &y[from..]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Branch;
    use boucwen_core::model::{BoucWenParams, ExtendedParams};
    use boucwen_core::signal::{Oscillator, Sine};

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
        let opt = OeOptions { averaging: Averaging::Off, ..OeOptions::default() };
        let fit = fit_oe(&u, &y, 1e-3, 4000, &ModelSpec::enhanced(23.0, &[3]), &[], &opt).unwrap();
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

    /// Deterministic noise, uniform in ±`amp`.
    fn noise(n: usize, amp: f64) -> Vec<f64> {
        let mut s = 7u64;
        (0..n)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((s >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 2.0 * amp
            })
            .collect()
    }

    #[test]
    fn under_a_periodic_drive_the_average_period_is_fitted_and_the_fit_stops_by_a_criterion() {
        let mut t = truth();
        t.branches.clear();
        t.drift = vec![0.2];
        let u = drive(17.3, 20_000);
        let e = noise(u.len(), 0.05);
        let y: Vec<f64> = t.simulate(&u, 1e-3).unwrap().iter().zip(&e).map(|(a, b)| a + b).collect();
        let spec = ModelSpec { drive_hz: 17.3, harmonics: vec![], drift_degree: Some(0) };
        let opt = OeOptions { skip: 1000, require_invertible: false, lm_starts: 5, ..OeOptions::default() };
        let fit = fit_oe(&u, &y, 1e-3, 10_000, &spec, &[], &opt).unwrap();
        assert!(matches!(fit.data, DataUsed::Periods { periods, .. } if periods > 150.0), "{:?}", fit.data);
        assert!(matches!(fit.stop, Stop::CostDecrease | Stop::StepSize | Stop::Gradient), "{:?}", fit.stop);
        // Held out, the model is as good as the noise allows (uniform ±0.05: RMS 0.029).
        let held_out = free_run_rms(&fit.model, &u, &y, 1e-3, 10_000).unwrap();
        assert!(held_out < 0.0295, "held-out {held_out}");
        // Levenberg–Marquardt started again from the result finds nothing more.
        let again =
            OeOptions { structure: StructureSearch::From(fit.model.ext.ar), lm_starts: 1, ..opt.clone() };
        let refit = fit_oe(&u, &y, 1e-3, 10_000, &spec, std::slice::from_ref(&fit.model), &again).unwrap();
        assert!(refit.rms_fit >= 0.995 * fit.rms_fit, "{} vs {}", refit.rms_fit, fit.rms_fit);
    }

    #[test]
    fn a_drive_that_is_not_periodic_is_fitted_sample_by_sample() {
        let mut t = truth();
        t.branches.clear();
        // A chirp from 5 to 40 Hz.
        let u: Vec<f64> = (0..8000)
            .map(|k| (std::f64::consts::PI * (5.0 + 35.0 * k as f64 / 8000.0) * k as f64 * 1e-3).sin())
            .collect();
        let y = t.simulate(&u, 1e-3).unwrap();
        let fit = fit_oe(&u, &y, 1e-3, 6000, &ModelSpec::extended(20.0), &[], &OeOptions::default()).unwrap();
        assert_eq!(fit.data, DataUsed::Samples { from: 200, to: 6000 });
        let held_out = free_run_rms(&fit.model, &u, &y, 1e-3, 6000).unwrap();
        assert!(held_out < 1e-3 * analysis::rms(&y), "held-out {held_out}");
    }

    #[test]
    fn bad_specs_are_rejected() {
        let u = drive(23.0, 5000);
        let y = u.clone();
        let e = fit_oe(&u, &y, 1e-3, 4000, &ModelSpec::enhanced(23.0, &[25]), &[], &OeOptions::default());
        assert_eq!(e.err(), Some(FitError::Model(crate::model::ModelError::BadHarmonic(25))));
        let e = fit_oe(&u, &y, 1e-3, 100, &ModelSpec::extended(23.0), &[], &OeOptions::default());
        assert!(matches!(e, Err(FitError::TooFewSamples { .. })));
    }
}
