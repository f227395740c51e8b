//! The fit of the families other than the paper's actuator on one split of a record, scored
//! the same way: fitted on `start..split`, simulated from rest at sample 0, held out on
//! `split..`. `identify --model` and the diagnosis's comparison of where the hysteresis sits
//! both call it.
//!
//! - **Linear**: every order up to [`FamilyRules::linear_max_orders`] is fitted on the first
//!   [`FamilyRules::linear_select_share`] of the fitted samples and chosen on the rest
//!   ([`select_linear_oe`]'s rule), then fitted again on all of them.
//! - **Oscillator**: [`fit_oscillator`] with `⌈Ts / oscillator_step_s⌉` substeps (2 to
//!   `max_substeps`), the output read at the sample instants (a record's own anti-alias
//!   filter is not known), the input interpolated in the DFT domain for a periodic drive of
//!   a whole number of samples per period and by a cubic spline otherwise. The record's
//!   output (µm) is fitted in metres and the model's output returned in µm
//!   ([`crate::model::family`]).

use super::linear::{fit_linear_oe, select_linear_oe};
use super::oscillator::{OscillatorOptions, fit_oscillator};
use super::{FitError, Tolerances};
use crate::model::family::UM_PER_M;
use crate::model::linear::OeOrders;
use crate::model::oscillator::OscillatorModel;
use crate::model::oscillator::{InputReconstruction, OutputSampling};
use crate::model::{Family, Model, ModelError};
use crate::rules::FamilyRules;
use crate::signal::analysis::rms_diff;
use std::ops::Range;

/// A family fitted on one split.
#[derive(Clone, Debug)]
pub struct FamilyFit {
    /// The model.
    pub model: Model,
    /// Free-run RMS on the fitted samples (µm).
    pub fit_rms_um: f64,
    /// Free-run RMS held out (µm); `None` when the free run diverges.
    pub held_rms_um: Option<f64>,
    /// Wall time of the fit (s).
    pub seconds: f64,
}

/// The oscillator's substeps per sample at interval `ts` (module docs).
pub fn substeps(ts: f64, rules: &FamilyRules) -> usize {
    ((ts / rules.oscillator_step_s).ceil() as usize).clamp(2, rules.max_substeps.max(2))
}

/// A period (samples) within this of a whole number is one (an equality of floats, not a
/// decision).
const WHOLE: f64 = 1e-6;

/// The period in whole samples, when it is one.
pub fn whole_period(period: f64) -> Option<usize> {
    (period.is_finite() && period >= 2.0 && (period - period.round()).abs() < WHOLE)
        .then(|| period.round() as usize)
}

/// How the oscillator reads a drive: DFT interpolation for a periodic drive of `period`
/// whole samples, else a cubic spline.
fn reconstruction(period: Option<usize>, n: usize) -> InputReconstruction {
    match period {
        Some(p) if p >= 2 && p <= n => InputReconstruction::Periodic { period: p },
        _ => InputReconstruction::CubicSpline,
    }
}

/// Fits the oscillator (module docs) to `u`, `y` (µm) on the samples `scored`.
pub fn fit_oscillator_on(
    u: &[f64],
    y: &[f64],
    ts: f64,
    scored: Range<usize>,
    period: Option<usize>,
    rules: &FamilyRules,
) -> Result<OscillatorModel, FitError> {
    let n = u.len().min(y.len());
    let y_m: Vec<f64> = y[..n].iter().map(|v| v / UM_PER_M).collect();
    let opt = OscillatorOptions {
        substeps: substeps(ts, rules),
        output: OutputSampling::Instant,
        input: reconstruction(period, n),
        fit_nu: false,
        scored: vec![scored],
        coarse_substeps: None,
        tolerances: OscillatorOptions::benchmark(2).tolerances,
    };
    Ok(fit_oscillator(&u[..n], &y_m, ts, &opt)?.model)
}

/// A model's free run (µm) on `u`, the oscillator reading a periodic drive as fitted
/// ([`fit_oscillator_on`]).
pub fn simulate(model: &Model, u: &[f64], ts: f64, period: Option<usize>) -> Result<Vec<f64>, ModelError> {
    match model {
        Model::Oscillator(o) => {
            let y = o.simulate_with(u, ts, reconstruction(period, u.len()))?;
            Ok(y.into_iter().map(|v| v * UM_PER_M).collect())
        }
        m => m.simulate(u, ts),
    }
}

/// Fits `family` (not the actuator, whose fit is [`super::fit_oe`]) to `u`, `y` (µm) at
/// interval `ts` on `start..split`, and scores it on `split..`; `period` is the drive's
/// period in samples when it is periodic with a whole number of samples.
pub fn fit_family(
    family: Family,
    u: &[f64],
    y: &[f64],
    ts: f64,
    (start, split): (usize, usize),
    period: Option<usize>,
    rules: &FamilyRules,
) -> Result<FamilyFit, FitError> {
    let t0 = std::time::Instant::now();
    let n = u.len().min(y.len());
    if !(start < split && split < n) {
        return Err(FitError::TooFewSamples { have: n, need: split.max(start + 1) + 1 });
    }
    let tol = Tolerances::default();
    let model = match family {
        Family::Actuator => return Err(FitError::NoStableModel),
        Family::Linear => {
            let [nb, nf, nk] = rules.linear_max_orders;
            let inner = start + ((split - start) as f64 * rules.linear_select_share).round() as usize;
            let inner = inner.clamp(start + 1, split - 1);
            let sel = select_linear_oe(u, y, start..inner, inner..split, OeOrders { nb, nf, nk }, &tol)?;
            let orders = sel.scores[sel.chosen].orders;
            Model::Linear(fit_linear_oe(u, y, orders, start..split, &tol)?.model)
        }
        Family::Oscillator => {
            Model::Oscillator(fit_oscillator_on(&u[..n], &y[..n], ts, start..split, period, rules)?)
        }
    };
    let sim = simulate(&model, &u[..n], ts, period);
    let (fit_rms_um, held_rms_um) = match sim {
        Ok(s) if s.iter().all(|v| v.is_finite()) => {
            (rms_diff(&s[start..split], &y[start..split]), Some(rms_diff(&s[split..n], &y[split..n])))
        }
        _ => (f64::INFINITY, None),
    };
    Ok(FamilyFit { model, fit_rms_um, held_rms_um, seconds: t0.elapsed().as_secs_f64() })
}
