//! Stage 2: the baseline (the extended model with an offset), its checks, and what the record
//! shows beside it (the residual's decomposition, the output's harmonics, the noise floor).

use super::Context;
use crate::diagnose::checks::{self, ModelCheck};
use crate::diagnose::error::DiagnoseError;
use crate::diagnose::evidence::{Evidence, Finding, Kind};
use crate::diagnose::residual::{self, Residual};
use crate::fit::{self, Averaging, FitError, OeOptions};
use crate::model::HostModel;
use crate::signal::analysis::{self, Tone};
use crate::signal::steady;

/// The baseline fitted on the first half.
#[derive(Clone, Debug)]
pub struct Baseline {
    /// The model.
    pub model: HostModel,
    /// Its free run over the analysed samples (µm).
    pub sim: Vec<f64>,
    /// Its held-out fit and stability.
    pub check: ModelCheck,
    /// Its held-out RMS (µm).
    pub rms_um: f64,
}

/// What the record shows beside the baseline.
#[derive(Clone, Debug)]
pub struct Facts {
    /// The baseline's held-out residual, decomposed.
    pub residual: Residual,
    /// The output's fundamental over the held-out part (µm peak).
    pub output_amplitude_um: f64,
    /// The output's harmonics `1..=sine.max_term_order` over the held-out part.
    pub out_harmonics: Vec<Tone>,
    /// The output's noise floor over the held-out part (µm) and how it was measured.
    pub noise_um: (f64, &'static str),
    /// The baseline structure's resonance (Hz), if its poles are complex.
    pub resonance_hz: Option<f64>,
}

impl Facts {
    /// RMS of the output's fundamental (µm).
    pub fn out_rms(&self) -> f64 {
        self.output_amplitude_um / std::f64::consts::SQRT_2
    }
}

/// Fits the baseline (from `starts` too) and checks it: a loop that does not close under a
/// distorted drive ([`DiagnoseError::Ratchets`]) or an unstable free run end the diagnosis.
pub fn fit(cx: &Context<'_>, starts: &[HostModel], depth: usize) -> Result<Baseline, DiagnoseError> {
    let model = fit::fit_oe_on(&cx.data, &cx.spec, starts, cx.opt())?.model;
    let sim = model.simulate(cx.u, cx.ts)?;
    let distorted = cx.plan.drive.thd >= cx.rules.sine.drive_distortion_floor;
    // Only a drive with distortion of its own (no half-wave symmetry) is known to make the
    // fitted loop ratchet; a slow settling of the loop after a step is not refused.
    if distorted {
        ratchet_check(cx, &sim)?;
        if depth == 0 {
            sample_fit_check(cx, &model, &sim)?;
        }
    }
    let s = cx.split();
    let check = ModelCheck::of(&model.ext.ar, &sim[s..], &cx.y[s..], cx.ts, &cx.rules.checks);
    if check.unstable.is_some() {
        return Err(DiagnoseError::Fit(FitError::NoStableModel));
    }
    let rms_um = analysis::rms(&cx.held_out(&sim));
    Ok(Baseline { model, sim, check, rms_um })
}

/// The output's fundamental over the held-out part (µm peak).
fn output_amplitude(cx: &Context<'_>) -> f64 {
    let s = cx.split();
    analysis::harmonics(&cx.y[s..], cx.plan.drive.freq_hz, cx.ts, 1).first().map_or(0.0, |t| t.amp)
}

/// Refuses a free run whose mean ratchets over the held-out half while the output does not
/// (a loop that ratchets to follow a drift of the output is the drift's business).
fn ratchet_check(cx: &Context<'_>, sim: &[f64]) -> Result<(), DiagnoseError> {
    let (s, period) = (cx.split(), cx.plan.drive.period_samples);
    let (Some(moves), Some(y_moves)) =
        (checks::ratchet_um(&sim[s..], period), checks::ratchet_um(&cx.y[s..], period))
    else {
        return Ok(());
    };
    if checks::ratchets(moves, y_moves, output_amplitude(cx), &cx.rules.checks) {
        return Err(DiagnoseError::Ratchets { moved_um: moves.abs(), thd_pct: 100.0 * cx.plan.drive.thd });
    }
    Ok(())
}

/// Under a drive with distortion of its own, the averaged fit keeps only loops that close
/// over the average period; the loop that fits the samples best may ratchet instead. Fitted
/// sample by sample from the baseline, if that loop fits the fitted half clearly better
/// (`checks.ratchet_fit_share`) and its free run ratchets over the held-out half, no loop
/// both fits and closes: the baseline's errors then say nothing about the actuator.
fn sample_fit_check(cx: &Context<'_>, baseline: &HostModel, base_sim: &[f64]) -> Result<(), DiagnoseError> {
    let off = OeOptions { averaging: Averaging::Off, ..cx.opt().clone() };
    let Ok(f) = fit::fit_oe_on(&cx.data, &cx.spec, std::slice::from_ref(baseline), &off) else {
        return Ok(());
    };
    let sim = f.model.simulate(cx.u, cx.ts)?;
    let s = cx.split();
    let fitted_rms = |x: &[f64]| analysis::rms_diff(&cx.y[..s], &x[..s]);
    let better = fitted_rms(&sim) < cx.rules.checks.ratchet_fit_share * fitted_rms(base_sim);
    let period = cx.plan.drive.period_samples;
    if let (true, Some(moves)) = (better, checks::ratchet_um(&sim[s..], period)) {
        let y_moves = checks::ratchet_um(&cx.y[s..], period).unwrap_or(0.0);
        if checks::ratchets(moves, y_moves, output_amplitude(cx), &cx.rules.checks) {
            return Err(DiagnoseError::Ratchets {
                moved_um: moves.abs(),
                thd_pct: 100.0 * cx.plan.drive.thd,
            });
        }
    }
    Ok(())
}

/// What the record shows beside the baseline.
pub fn facts(cx: &Context<'_>, base: &Baseline) -> Facts {
    let (s, f, ts, r) = (cx.split(), cx.plan.drive.freq_hz, cx.ts, cx.rules);
    Facts {
        residual: residual::decompose(&cx.held_out(&base.sim), f, ts, r),
        output_amplitude_um: output_amplitude(cx),
        out_harmonics: analysis::harmonics(&cx.y[s..], f, ts, r.sine.max_term_order as usize),
        noise_um: steady::noise_floor(&cx.y[s..], ts, &cx.plan.drive, r),
        resonance_hz: crate::model::poles::resonance_hz(&base.model.ext.ar, ts),
    }
}

/// The drive explains too little of the output (`checks.min_fit_pct`): another input
/// drives it, and no harmonic diagnosis is made on top of it.
pub fn other_input(cx: &Context<'_>, base: &Baseline, facts: &Facts) -> Option<Finding> {
    let fit = base.check.fit_pct.unwrap_or(f64::NAN);
    let min_fit_pct = cx.rules.checks.min_fit_pct;
    (fit.is_nan() || fit < min_fit_pct).then_some(Finding {
        kind: Kind::OtherInput,
        order: None,
        freq_hz: 0.0,
        kept: false,
        residual_share: 1.0,
        term_rms_um: facts.residual.rms_um,
        rms_with_term_um: None,
        evidence: Evidence::OtherInput { fit_pct: fit, min_fit_pct },
    })
}
