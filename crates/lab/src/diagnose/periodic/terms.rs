//! Stage 4 of a periodic diagnosis: terms beyond the baseline, each refined jointly with it
//! ([`crate::fit::refine`]): a cubic stiffening of the structure (odd) and a quadratic one
//! (even, an asymmetric stiffness). A term is kept when it lowers the held-out RMS by
//! `terms.min_gain` and either carries `terms.min_term_rel` of the output's RMS or removes
//! `periodic.noise_multiple` times the noise floor from the held-out residual
//! (`√(before² − after²)`): a stiffening that the loop mostly imitates carries well under
//! 2 % of the output, yet what it leaves to the term is many times what the noise of
//! held-out periods can account for. The parity with the most evidence first, then the
//! other on top.

use super::data::Data;
use super::models::{evaluate, options};
use super::{ModelStep, TermTrial};
use crate::diagnose::causes;
use crate::diagnose::checks;
use crate::diagnose::error::DiagnoseError;
use crate::diagnose::evidence::{NotKept, Term};
use crate::fit::refine;
use crate::model::terms::{Param, Stiffening, TermModel};
use crate::rules::Rules;
use crate::signal::analysis;
use crate::signal::distortion::Parity;
use rayon::prelude::*;

/// The terms kept, each with the model it made.
pub struct Kept {
    /// The models with each kept term, in order.
    pub steps: Vec<ModelStep>,
    /// The parities kept, in order.
    pub parities: Vec<Parity>,
    /// Every term tried.
    pub trials: Vec<TermTrial>,
}

/// One term tried: its parity, the refined model, its held-out RMS and what it carries.
type Tried = (Parity, TermModel, f64, f64);

/// A parity's evidence: the data's level at its free lines, or where the drive leaves none
/// (a triangle's odd lines), the baseline's held-out residual's level at its lines.
pub fn evidence(data: &Data, baseline: &ModelStep, p: Parity) -> f64 {
    match (p, data.odd, data.even) {
        (Parity::Odd, Some(l), _) | (Parity::Even, _, Some(l)) => l.db,
        (Parity::Odd, None, _) => baseline.odd.db,
        (Parity::Even, _, None) => baseline.even.db,
    }
}

/// The forward selection of stiffening terms on top of `baseline`.
pub fn select(
    data: &Data,
    baseline: &ModelStep,
    noise_um: f64,
    out_rms: f64,
    ts: f64,
    r: &Rules,
) -> Result<Kept, DiagnoseError> {
    let mut kept = Kept { steps: vec![], parities: vec![], trials: vec![] };
    let mut remaining = vec![Parity::Odd, Parity::Even];
    for round in 0.. {
        let current = kept.steps.last().unwrap_or(baseline).clone();
        let tried = try_all(data, &current, &remaining, ts, r);
        let before = current.rms_um;
        let first = kept.trials.len();
        kept.trials.extend(tried.iter().map(|(p, _, rms, term)| TermTrial {
            round,
            parity: *p,
            rms_um: *rms,
            term_rms_um: *term,
            gain_pct: 100.0 * (1.0 - rms / before.max(1e-300)),
            kept: false,
            reason: None,
        }));
        let gains = |t: &Tried| t.2 <= before * (1.0 - r.terms.min_gain);
        let need = r.terms.min_term_rel * out_rms;
        // What a term removes from the held-out residual (µm, RMS): the noise of held-out
        // periods cannot remove `periodic.noise_multiple` times its own RMS.
        let removed = |t: &Tried| (before * before - t.2 * t.2).max(0.0).sqrt();
        let carries = |t: &Tried| t.3 >= need || removed(t) >= r.periodic.noise_multiple * noise_um;
        let ev = |p: Parity| evidence(data, baseline, p);
        let winner = tried
            .iter()
            .enumerate()
            .filter(|(_, t)| gains(t) && carries(t))
            .max_by(|a, b| ev(a.1.0).total_cmp(&ev(b.1.0)))
            .map(|(i, _)| i);
        for (i, t) in tried.iter().enumerate() {
            if !gains(t) || Some(i) == winner {
                continue;
            }
            kept.trials[first + i].reason = Some(if !carries(t) {
                NotKept::CarriesTooLittle {
                    carried_um: t.3,
                    need_um: need,
                    min_term_rel: r.terms.min_term_rel,
                    noise_factor: None,
                    removed: Some((removed(t), r.periodic.noise_multiple, noise_um)),
                }
            } else {
                let w = winner.map_or(t.0, |w| tried[w].0);
                NotKept::MoreEvidence {
                    winner: Term::Stiffening(w),
                    winner_evidence: ev(w),
                    this_evidence: ev(t.0),
                    db: true,
                    round,
                }
            });
        }
        let Some(w) = winner else { break };
        kept.trials[first + w].kept = true;
        let Some((p, m, ..)) = tried.into_iter().nth(w) else { break };
        kept.steps.push(evaluate(&format!("extended + {}", term_name(p)), m, data, ts, r)?);
        kept.parities.push(p);
        remaining.retain(|q| *q != p);
        if remaining.is_empty() {
            break;
        }
    }
    Ok(kept)
}

/// Each remaining parity's stiffening added to the current model and refined, in parallel;
/// its held-out RMS and what it carries (the held-out RMS of the change of the model's
/// output), over the held-out parts.
fn try_all(data: &Data, current: &ModelStep, remaining: &[Parity], ts: f64, r: &Rules) -> Vec<Tried> {
    let s0 = &data.sets[0];
    let (u0, y0) = (&s0.u[..], &s0.y[..]);
    let crit = causes::criterion(&options(data, ts, r), data.fit_end, ts, &r.terms);
    remaining
        .par_iter()
        .filter_map(|&p| {
            let m = with_stiffening(&current.model, p, u0, ts)?;
            let mut free = m.host_params();
            free.push(Param::Stiffening(m.terms.stiffening.len() - 1));
            let (m, _) = refine(&m, &free, u0, y0, ts, &crit)?;
            let (mut sq, mut change, mut count) = (0.0, 0.0, 0usize);
            for &(i, a, b) in &data.held {
                let s = &data.sets[i];
                let sim = m.simulate(&s.u[..b], ts).ok()?;
                if checks::instability(&m.host.ext.ar, &sim[a..b], ts).is_some() {
                    return None;
                }
                let base = current.model.simulate(&s.u[..b], ts).ok()?;
                sq += sim[a..b].iter().zip(&s.y[a..b]).map(|(p, y)| (y - p) * (y - p)).sum::<f64>();
                change += sim[a..b].iter().zip(&base[a..b]).map(|(p, q)| (p - q) * (p - q)).sum::<f64>();
                count += b - a;
            }
            let rms = (sq / count.max(1) as f64).sqrt();
            let change = (change / count.max(1) as f64).sqrt();
            (rms.is_finite() && change.is_finite()).then_some((p, m, rms, change))
        })
        .collect()
}

/// "cubic stiffening", "quadratic (asymmetric) stiffness".
pub fn term_name(p: Parity) -> &'static str {
    match p {
        Parity::Odd => "cubic stiffening",
        Parity::Even => "quadratic (asymmetric) stiffness",
    }
}

/// The power of a parity's stiffening: a cubic for odd, a quadratic for even.
pub fn power(p: Parity) -> u32 {
    match p {
        Parity::Odd => 3,
        Parity::Even => 2,
    }
}

/// `model` with a stiffening power of `p`'s parity added at 0, its reference deflection the
/// largest excursion of the model's output from its mean over `u`. `None` if the model
/// already has that power.
fn with_stiffening(model: &TermModel, p: Parity, u: &[f64], ts: f64) -> Option<TermModel> {
    let power = power(p);
    if model.terms.stiffening.iter().any(|s| s.power == power) {
        return None;
    }
    let mut m = model.clone();
    if m.terms.q_ref_um <= 0.0 {
        let sim = model.host.simulate(u, ts).ok()?;
        let mean = analysis::mean(&sim);
        m.terms.q_ref_um = sim.iter().fold(0.0f64, |a, v| a.max((v - mean).abs())).max(MIN_Q_REF_UM);
    }
    m.terms.stiffening.push(Stiffening { power, coeff: 0.0 });
    Some(m)
}

/// The smallest reference deflection of a stiffening (µm): a guard for a model at rest.
const MIN_Q_REF_UM: f64 = 1e-6;
