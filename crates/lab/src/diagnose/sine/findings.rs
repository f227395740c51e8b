//! Stage 7: the findings, as typed evidence. The kept terms first, in the order chosen (an
//! odd harmonic `n ≥ 3` is an odd harmonic oscillation, an even one an asymmetry, the trend
//! a drift, and the physical causes), then the delay, then the structure no term could
//! remove: a harmonic or trend that still holds `terms.unexplained_share` of the extended
//! model's residual power and `terms.min_term_rel` of the output, reported with
//! `kept: false`. Then what the record says of the structure's resonance and whether the
//! extended model holds at other amplitudes.

use super::baseline::{Baseline, Facts};
use super::candidates::Read;
use super::delay::Delayed;
use super::selection::{Kept, Selected, term_rms};
use super::{Context, Diagnosis};
use crate::diagnose::causes;
use crate::diagnose::checks::ModelCheck;
use crate::diagnose::error::DiagnoseError;
use crate::diagnose::evidence::{
    Candidate, CreepEvidence, DriveHarmonic, DriveSaturationEvidence, Evidence, Finding, HarmonicEvidence,
    Kind, NearResonance, OutputSaturationEvidence, ResidualReading, Resonance, Step, TrendEvidence,
    WithinRange,
};
use crate::diagnose::residual::{self, Residual};
use crate::model::terms::{TermModel, Terms};
use crate::record::Y_LIMIT_UM;
use crate::signal::analysis::Tone;

/// The diagnosis when the drive explains too little of the output: one finding, the
/// baseline as the model.
pub fn other_input(cx: &Context<'_>, base: Baseline, facts: Facts, finding: Finding) -> Diagnosis {
    let mut d = skeleton(cx, base, facts);
    d.findings = vec![finding];
    d.resonance = Resonance::NotAssessed;
    d
}

/// The diagnosis with the baseline only, before any term.
fn skeleton(cx: &Context<'_>, base: Baseline, facts: Facts) -> Diagnosis {
    let p = cx.plan;
    Diagnosis {
        drive_hz: p.drive.freq_hz,
        ts: cx.ts,
        split: p.split,
        baseline: base.model.clone(),
        baseline_rms_um: base.rms_um,
        baseline_sim: base.sim.clone(),
        residual: facts.residual.clone(),
        resonance: Resonance::NoneFitted,
        findings: vec![],
        trials: vec![],
        model: base.model,
        terms: Terms::default(),
        delay: None,
        model_rms_um: base.rms_um,
        model_sim: base.sim,
        model_residual: facts.residual,
        output_amplitude_um: facts.output_amplitude_um,
        window: p.window.clone(),
        drive: p.drive.clone(),
        t0: p.t0,
        periods: p.periods,
        baseline_check: base.check.clone(),
        model_check: base.check,
        noise_um: facts.noise_um,
        drive_note: None,
    }
}

/// The whole diagnosis from the stages' results.
pub fn assemble(
    cx: &Context<'_>,
    base: Baseline,
    facts: Facts,
    read: &Read,
    selected: Selected,
    delayed: Delayed,
) -> Result<Diagnosis, DiagnoseError> {
    let (u, ts, split) = (cx.u, cx.ts, cx.split());
    let model = delayed.model;
    let model_sim = model.simulate(u, ts)?;
    let model_residual = residual::decompose(&cx.held_out(&model_sim), cx.plan.drive.freq_hz, ts, cx.rules);
    let final_res = crate::model::poles::resonance_hz(&model.host.ext.ar, ts);
    let mut findings = kept_findings(cx, &base, &facts, read, &selected.kept, &model, final_res)?;
    findings.extend(delayed.finding);
    findings.extend(unexplained(cx, &model_residual, &selected.kept, &facts));
    let r = &cx.rules.checks;
    let mut model_check = ModelCheck::of(&model.host.ext.ar, &model_sim[split..], &cx.y[split..], ts, r);
    model_check
        .check_amplitudes(&model.host.ext.bw, &model.host.ext.ar, u, ts, r, |v| model.simulate(v, ts).ok());
    let resonance = resonance_support(cx, &facts);
    let mut d = skeleton(cx, base, facts);
    d.resonance = resonance;
    d.findings = findings;
    d.trials = selected.trials;
    d.model = model.host;
    d.terms = model.terms;
    d.delay = delayed.estimate;
    d.model_rms_um = delayed.model_rms;
    d.model_sim = model_sim;
    d.model_residual = model_residual;
    d.model_check = model_check;
    d.drive_note = selected.drive_note;
    Ok(d)
}

/// The kept terms' findings, each with the share of the baseline's residual power its step
/// removed and what it carries in the final model.
fn kept_findings(
    cx: &Context<'_>,
    base: &Baseline,
    facts: &Facts,
    read: &Read,
    kept: &[Kept],
    model: &TermModel,
    final_res: Option<f64>,
) -> Result<Vec<Finding>, DiagnoseError> {
    let (u, ts, split) = (cx.u, cx.ts, cx.split());
    let mut findings = vec![];
    let mut prev_rms = base.rms_um;
    for (i, &(c, rms, _)) in kept.iter().enumerate() {
        let term = term_rms(model, &c, u, ts, split)?;
        let explained = (prev_rms * prev_rms - rms * rms) / (base.rms_um * base.rms_um).max(1e-300);
        let step = Step { before_um: prev_rms, after_um: rms, first: i == 0 };
        prev_rms = rms;
        let evidence = match c.kind {
            Kind::Saturation => saturation(cx, facts, read, &c, model, step),
            Kind::Creep => Evidence::Creep(CreepEvidence {
                relaxations: model.terms.creep.iter().filter(|r| r.gain > 0.0).copied().collect(),
                trend: trend(&facts.residual, c.share, step),
            }),
            Kind::Drift => Evidence::Drift(trend(&facts.residual, c.share, step)),
            _ => Evidence::Harmonic(harmonic(cx, facts, read, &c, step, [final_res, facts.resonance_hz])),
        };
        findings.push(Finding {
            kind: c.kind,
            order: c.order,
            freq_hz: c.freq_hz,
            kept: true,
            residual_share: explained.clamp(0.0, 1.0),
            term_rms_um: term,
            rms_with_term_um: Some(rms),
            evidence,
        });
    }
    Ok(findings)
}

/// The residual's trend and what its term did.
fn trend(r: &Residual, share: f64, step: Step) -> TrendEvidence {
    TrendEvidence {
        share,
        rms_um: r.trend_rms_um,
        mean_um: r.trend_mean_um,
        slope_um_per_s: r.trend_slope_um_per_s,
        step,
    }
}

/// A harmonic branch's evidence: the harmonic in the output and in the residual, the drive's
/// own harmonic there, and a fitted resonance near it (of the final model, else of the
/// baseline: one sine places a resonance only roughly, hence `sine.near_resonance`).
fn harmonic(
    cx: &Context<'_>,
    facts: &Facts,
    read: &Read,
    c: &Candidate,
    step: Step,
    resonances: [Option<f64>; 2],
) -> HarmonicEvidence {
    let (s, order) = (&cx.rules.sine, c.order.unwrap_or(0));
    let f = c.freq_hz;
    let is_near = |r: &f64| (r - f).abs() <= s.near_resonance * f.max(*r);
    let output_um = facts.out_harmonics.get(order as usize - 1).map_or(0.0, |t| t.amp);
    let drive_rel = cx.plan.drive.harmonic_rel(order as usize);
    let reading = if c.share >= cx.rules.terms.unexplained_share {
        ResidualReading::Holds
    } else if step.first {
        ResidualReading::Imitated
    } else {
        ResidualReading::Plain
    };
    HarmonicEvidence {
        order,
        freq_hz: f,
        output_um,
        output_rel: if facts.output_amplitude_um > 0.0 { output_um / facts.output_amplitude_um } else { 0.0 },
        residual_um: c.amp,
        residual_share: c.share,
        reading,
        step,
        drive: (drive_rel >= s.drive_harmonic_note).then(|| DriveHarmonic {
            rel: drive_rel,
            part_um: read.drive_part.get(order.max(1) as usize - 1).map_or(0.0, |t| t.amp),
        }),
        resonance: resonances.iter().flatten().copied().find(is_near).map(|hz| NearResonance {
            hz,
            // Only the baseline's structure, which made the harmonic before the branch did,
            // has it there: one sine cannot tell a resonance that amplifies the harmonic from
            // a structure bent to make it.
            needs_confirming: !resonances[0].is_some_and(|r| is_near(&r)),
        }),
    }
}

/// A saturation's evidence: a clamped output (its plateaus, and the drive that keeps the
/// output inside the range) or a clamped drive (its levels and the series of odd harmonics
/// it puts in the output).
fn saturation(
    cx: &Context<'_>,
    facts: &Facts,
    read: &Read,
    c: &Candidate,
    model: &TermModel,
    step: Step,
) -> Evidence {
    let out = &facts.out_harmonics;
    match (c.output_range, model.terms.input_clamp) {
        (Some([lo, hi]), _) => {
            let steady = &cx.y[read.steady_from..];
            let share = causes::plateaus(steady, facts.noise_um.0, &cx.rules.causes).map_or(0.0, |p| p.share);
            let within =
                causes::drive_within_range(model, cx.u, cx.ts, cx.plan.window.start, &cx.rules.causes)
                    .map(|k| WithinRange { scale: k, amplitude_v: k * read.drive_amp_v });
            Evidence::OutputSaturation(OutputSaturationEvidence {
                top_um: (hi.abs() < Y_LIMIT_UM).then_some(hi),
                bottom_um: (lo.abs() < Y_LIMIT_UM).then_some(lo),
                share,
                step,
                within_range: within,
            })
        }
        (None, clamp) => {
            let f1 = out.first().map_or(0.0, |t| t.amp).max(1e-300);
            let series = cx
                .rules
                .causes
                .series_orders
                .iter()
                .filter_map(|&n| out.get(n as usize - 1).map(|t: &Tone| (n, t.amp / f1)))
                .collect();
            Evidence::DriveSaturation(DriveSaturationEvidence {
                levels_v: clamp.unwrap_or([f64::NAN; 2]),
                series,
                step,
            })
        }
    }
}

/// The structure the extended model still misses: a harmonic `2..=sine.max_term_order` (not
/// already a term) or the trend holding `terms.unexplained_share` of the extended model's
/// held-out residual power and carrying `terms.min_term_rel` of the output's fundamental
/// RMS, the largest first.
fn unexplained(cx: &Context<'_>, r: &Residual, kept: &[Kept], facts: &Facts) -> Vec<Finding> {
    let power = (r.rms_um * r.rms_um).max(1e-300);
    let (t, max_order) = (&cx.rules.terms, cx.rules.sine.max_term_order);
    let floor = t.min_term_rel * facts.output_amplitude_um / std::f64::consts::SQRT_2;
    let is_kept = |order: Option<u32>| match order {
        Some(_) => kept.iter().any(|(c, ..)| c.order == order),
        // The trend: a drift line or creep removed it.
        None => kept.iter().any(|(c, ..)| matches!(c.kind, Kind::Drift | Kind::Creep)),
    };
    let mut found = vec![];
    for (i, h) in r.harmonics.iter().enumerate().skip(1).take(max_order as usize - 1) {
        let order = (i + 1) as u32;
        let (rms, share) = (h.amp / std::f64::consts::SQRT_2, h.amp * h.amp / 2.0 / power);
        if is_kept(Some(order)) || share < t.unexplained_share || rms < floor {
            continue;
        }
        found.push(Finding {
            kind: Kind::of_order(order),
            order: Some(order),
            freq_hz: h.freq_hz,
            kept: false,
            residual_share: share,
            term_rms_um: rms,
            rms_with_term_um: None,
            evidence: Evidence::UnexplainedHarmonic { amp_um: h.amp, share },
        });
    }
    let share = r.trend_rms_um.powi(2) / power;
    if !is_kept(None) && share >= t.unexplained_share && r.trend_rms_um >= floor {
        found.push(Finding {
            kind: Kind::Drift,
            order: None,
            freq_hz: 0.0,
            kept: false,
            residual_share: share,
            term_rms_um: r.trend_rms_um,
            rms_with_term_um: None,
            evidence: Evidence::UnexplainedTrend {
                rms_um: r.trend_rms_um,
                slope_um_per_s: r.trend_slope_um_per_s,
                share,
            },
        });
    }
    found.sort_by(|a, b| b.term_rms_um.total_cmp(&a.term_rms_um));
    found
}

/// The baseline structure's resonance if the record supports it: a line the record excites
/// (the drive, or an output harmonic of `sine.resonance_line_rel` of the fundamental) within
/// `sine.near_resonance` of it, or a residual harmonic there holding
/// `terms.unexplained_share` of the residual power.
fn resonance_support(cx: &Context<'_>, facts: &Facts) -> Resonance {
    let Some(r) = facts.resonance_hz else {
        return Resonance::NoneFitted;
    };
    let (s, out, out_amp) = (&cx.rules.sine, &facts.out_harmonics, facts.output_amplitude_um);
    let near = |f: f64| (r - f).abs() <= s.near_resonance * r.max(f);
    let excited = |k: usize, t: &Tone| k == 0 || t.amp >= s.resonance_line_rel * out_amp;
    if let Some((k, t)) = out.iter().enumerate().find(|(k, t)| excited(*k, t) && near(t.freq_hz)) {
        return Resonance::Excited { order: k as u32 + 1, freq_hz: t.freq_hz };
    }
    let residual = &facts.residual;
    let power = (residual.rms_um * residual.rms_um).max(1e-300);
    let share = cx.rules.terms.unexplained_share;
    if let Some(t) =
        residual.harmonics.iter().find(|t| near(t.freq_hz) && t.amp * t.amp / 2.0 >= share * power)
    {
        return Resonance::InResidual { freq_hz: t.freq_hz };
    }
    let drive_hz = cx.plan.drive.freq_hz;
    let top_hz = out
        .iter()
        .enumerate()
        .filter(|(k, t)| excited(*k, t))
        .map(|(_, t)| t.freq_hz)
        .fold(drive_hz, f64::max);
    Resonance::NotIdentifiable { fitted_hz: r, drive_hz, top_hz }
}
