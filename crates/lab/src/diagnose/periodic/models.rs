//! Stage 3 of a periodic diagnosis: the models, fitted on the first realisation (or the
//! first half of the periods of the only one) and tested in free run on the others (or on
//! the later periods): the linear model (no hysteresis), the hysteresis model with a
//! symmetric loop (`A0 = 0`) and the extended model (its loop's asymmetric term free).
//! Their held-out residuals are measured at the lines: what the hysteresis itself accounts
//! for shows there. The baseline is the extended model, unless a simpler one does better on
//! the held-out data.

use super::ModelStep;
use super::data::Data;
use crate::diagnose::causes;
use crate::diagnose::checks::ModelCheck;
use crate::diagnose::error::DiagnoseError;
use crate::fit::{self, DelaySearch, LoopSearch, OeOptions, Samples, refine};
use crate::model::ModelSpec;
use crate::model::terms::{Param, TermModel};
use crate::rules::Rules;
use crate::signal::analysis;
use crate::signal::distortion::{self, Level, Line, Parity};

/// The fit's settings: on at most `periodic.max_fit_s` (at least two periods) of the fitted
/// part after the start-up; a broadband drive pins the structure's phase over a band, so the
/// input delay is fitted with it (a sampled actuator answers about a sample late, which one
/// resonance cannot absorb over a band).
pub fn options(data: &Data, ts: f64, r: &Rules) -> OeOptions {
    let s0 = &data.sets[0];
    let skip =
        s0.start.max(OeOptions::default().skip.min(data.fit_end.saturating_sub(r.sine.fit_min_samples)));
    let window = ((r.periodic.max_fit_s / ts) as usize).max((2.0 * data.period).round() as usize);
    OeOptions {
        lm_starts: r.terms.term_starts,
        require_invertible: false,
        skip,
        samples: Samples::First(data.fit_end.min(skip + window)),
        delay: DelaySearch::Fit,
        ..OeOptions::default()
    }
}

/// A model's held-out residual: RMS, check, levels at the lines of each parity.
pub fn evaluate(
    label: &str,
    m: TermModel,
    data: &Data,
    ts: f64,
    r: &Rules,
) -> Result<ModelStep, DiagnoseError> {
    let (mut all_r, mut all_y, mut sims, mut res_lines) = (vec![], vec![], vec![], vec![]);
    for &(i, a, b) in &data.held {
        let s = &data.sets[i];
        let sim = m.simulate(&s.u[..b], ts)?;
        let res: Vec<f64> = s.y[a..b].iter().zip(&sim[a..b]).map(|(y, p)| y - p).collect();
        if let Some(l) = distortion::lines(&s.u[a..b], &res, data.period, ts, data.kmax, r) {
            res_lines.push(l);
        }
        all_r.extend_from_slice(&res);
        all_y.extend_from_slice(&s.y[a..b]);
        sims.extend_from_slice(&sim[a..b]);
    }
    let lv = |p: Parity| -> Level {
        let per: Vec<Vec<Line>> = res_lines
            .iter()
            .map(|l| match (p, data.odd_drive) {
                (Parity::Odd, true) if data.odd.is_some() => data.parity_lines(l, p),
                (Parity::Even, true) => data.parity_lines(l, p),
                // A triangle's odd lines are all excited: its distortion falls on them.
                (p, _) => l.lines.iter().filter(|x| p.has(x.k) && x.k <= data.top).copied().collect(),
            })
            .collect();
        let refs: Vec<&[Line]> = per.iter().map(|v| v.as_slice()).collect();
        distortion::level(&refs, &r.periodic)
    };
    Ok(ModelStep {
        label: label.into(),
        rms_um: analysis::rms(&all_r),
        check: ModelCheck::of(&m.host.ext.ar, &sims, &all_y, ts, &r.checks),
        odd: lv(Parity::Odd),
        even: lv(Parity::Even),
        model: m,
    })
}

/// The linear model, the hysteresis model with a symmetric loop and the extended model,
/// evaluated.
pub fn compared(data: &Data, ts: f64, r: &Rules) -> Result<Vec<ModelStep>, DiagnoseError> {
    let opt = options(data, ts, r);
    let spec = ModelSpec { drift_degree: Some(0), ..ModelSpec::extended(data.drive.freq_hz) };
    let (u0, y0, fit_end) = (&data.sets[0].u[..], &data.sets[0].y[..], data.fit_end);
    let lin_opt = OeOptions { hysteresis: LoopSearch::Linear, ..opt.clone() };
    let linear = fit::fit_oe(u0, y0, ts, fit_end, &spec, &[], &lin_opt)?.model;
    let extended = fit::fit_oe(u0, y0, ts, fit_end, &spec, &[], &opt)?.model;
    let crit = causes::criterion(&opt, fit_end, ts, &r.terms);
    let mut symmetric = TermModel::from(extended.clone());
    symmetric.host.ext.bw.a0 = 0.0;
    let free: Vec<Param> = symmetric.host_params().into_iter().filter(|p| *p != Param::A0).collect();
    let symmetric = refine(&symmetric, &free, u0, y0, ts, &crit).map_or(symmetric, |r| r.0);
    Ok(vec![
        evaluate("linear", TermModel::from(linear), data, ts, r)?,
        evaluate("hysteresis, symmetric loop", symmetric, data, ts, r)?,
        evaluate("extended (hysteresis with its asymmetric term)", TermModel::from(extended), data, ts, r)?,
    ])
}

/// Which of the compared models is the baseline: the extended model (the last), or a
/// simpler one that does better held out (a loop fitted to one realisation that does not
/// carry over to another). An error if none runs stably.
pub fn baseline(compared: &[ModelStep]) -> Result<usize, DiagnoseError> {
    let score = |s: &ModelStep| if s.usable() { s.rms_um } else { f64::INFINITY };
    let (lin, sym, ext) = (score(&compared[0]), score(&compared[1]), score(&compared[2]));
    let b = if ext <= sym.min(lin) {
        2
    } else if sym <= lin {
        1
    } else {
        0
    };
    if !score(&compared[b]).is_finite() {
        return Err(DiagnoseError::Fit(fit::FitError::NoStableModel));
    }
    Ok(b)
}
