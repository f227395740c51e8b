//! Stage 5: forward selection of terms. Each round every remaining candidate's term is
//! added to the current model and the model refitted (in parallel, [`try_term`]); the
//! winner ([`winner`]) is kept, and every other term that gained enough is told why it was
//! not ([`reasons`]).

use super::Context;
use super::baseline::{Baseline, Facts};
use super::candidates::Read;
use crate::diagnose::causes;
use crate::diagnose::checks;
use crate::diagnose::error::DiagnoseError;
use crate::diagnose::evidence::{Candidate, Kind, NotKept, Trial};
use crate::fit::{self, refine};
use crate::model::terms::TermModel;
use crate::model::{HostModel, ModelSpec};
use crate::signal::analysis;
use rayon::prelude::*;

/// A term kept: its candidate, the held-out RMS once it was added and what it carried then.
pub type Kept = (Candidate, f64, f64);

/// What the selection kept.
#[derive(Clone, Debug)]
pub struct Selected {
    /// The model with the kept terms.
    pub model: TermModel,
    /// Its held-out RMS (µm).
    pub model_rms: f64,
    /// The terms kept, in order.
    pub kept: Vec<Kept>,
    /// Every term tried.
    pub trials: Vec<Trial>,
    /// The first harmonic term the drive's own harmonic confounded.
    pub drive_note: Option<NotKept>,
}

/// How the selection ended.
#[derive(Debug)]
pub enum Outcome {
    /// The first round's winner, its term removed, gave a baseline better by
    /// `sine.baseline_refit_gain`: the diagnosis restarts from it.
    Restart(HostModel),
    /// The terms kept.
    Done(Box<Selected>),
}

/// One term tried: its index in the remaining candidates, the refitted model, its held-out
/// RMS and what the term carries.
type Tried = (usize, TermModel, f64, f64);

/// Runs the rounds until no term qualifies.
pub fn select(
    cx: &Context<'_>,
    base: &Baseline,
    facts: &Facts,
    read: &Read,
    depth: usize,
) -> Result<Outcome, DiagnoseError> {
    let mut s = Selected {
        model: TermModel::from(base.model.clone()),
        model_rms: base.rms_um,
        kept: vec![],
        trials: vec![],
        drive_note: None,
    };
    let mut remaining = read.candidates.clone();
    // Each candidate's model of the last round: a second start for it in the next one.
    let mut previous: Vec<(Candidate, TermModel)> = vec![];
    for round in 0.. {
        let tried = try_all(cx, &s.model, &remaining, &previous);
        let first = s.trials.len();
        s.trials.extend(tried.iter().map(|(i, _, rms, term)| Trial {
            round,
            candidate: remaining[*i],
            rms_um: *rms,
            term_rms_um: *term,
            gain_pct: 100.0 * (1.0 - rms / s.model_rms.max(1e-300)),
            kept: false,
            reason: None,
        }));
        let winner = winner(cx, facts, read, &remaining, &tried, s.model_rms);
        for (pos, reason) in reasons(cx, facts, read, &remaining, &tried, winner, s.model_rms, round) {
            if let NotKept::DriveHarmonic { .. } = reason {
                s.drive_note.get_or_insert_with(|| reason.clone());
            }
            s.trials[first + pos].reason = Some(reason);
        }
        let Some(pos) = winner else { break };
        previous = tried.iter().map(|(i, m, _, _)| (remaining[*i], m.clone())).collect();
        let Some((i, m, rms, term)) = tried.into_iter().nth(pos) else { break };
        if round == 0 && depth < cx.rules.sine.max_baseline_refits {
            if let Some(b) = better_baseline(cx, base, &m, &remaining[i]) {
                return Ok(Outcome::Restart(b));
            }
        }
        s.trials[first + pos].kept = true;
        s.kept.push((remaining.remove(i), rms, term));
        (s.model, s.model_rms) = (m, rms);
        // A clamp of the drive acts before everything else and is tried against the
        // baseline only: added after another term, whose model was fitted without it, it
        // reshapes the loop to imitate what that term's form leaves (the default actuator at
        // 23 Hz: a clamp at 75 % of the drive's peak lowers the held-out RMS of the model with
        // the 3rd harmonic's branch by 31 %, a saturation the actuator does not have).
        remaining.retain(|c| !(c.kind == Kind::Saturation && c.output_range.is_none()));
    }
    Ok(Outcome::Done(Box::new(s)))
}

/// Every remaining term added to `model` and refitted, in parallel; the stable ones.
fn try_all(
    cx: &Context<'_>,
    model: &TermModel,
    remaining: &[Candidate],
    previous: &[(Candidate, TermModel)],
) -> Vec<Tried> {
    let (u, y, ts, split) = (cx.u, cx.y, cx.ts, cx.split());
    remaining
        .par_iter()
        .enumerate()
        .filter_map(|(i, c)| {
            let prev = previous.iter().find(|(p, _)| p == c).map(|(_, m)| m);
            let m = try_term(cx, model, c, prev)?;
            let sim = m.simulate(u, ts).ok()?;
            if checks::instability(&m.host.ext.ar, &sim, ts).is_some() {
                return None;
            }
            let rms = analysis::rms_diff(&sim[split..], &y[split..]);
            let term = term_rms(&m, c, u, ts, split).ok()?;
            (rms.is_finite() && term.is_finite()).then_some((i, m, rms, term))
        })
        .collect()
}

/// Whether a tried term lowers the round's held-out RMS by `terms.min_gain`.
fn gains(cx: &Context<'_>, t: &Tried, model_rms: f64) -> bool {
    t.2 <= model_rms * (1.0 - cx.rules.terms.min_gain)
}

/// The round's winner (a position in `tried`): of the harmonic and drift terms that would be
/// kept, the one with the most evidence in the record; a saturation or creep term that would
/// be kept replaces it when it lowers the held-out RMS further (a clamped drive explains a
/// whole series of harmonics, creep a trend that is not a line). An output on plateaus is
/// clipped where it is measured: its clamp goes before a clamp of the drive.
fn winner(
    cx: &Context<'_>,
    facts: &Facts,
    read: &Read,
    remaining: &[Candidate],
    tried: &[Tried],
    model_rms: f64,
) -> Option<usize> {
    let qualifies = |t: &Tried| {
        let c = &remaining[t.0];
        gains(cx, t, model_rms)
            && t.3 >= read.min_term(cx, facts, c)
            && read.drive_share(cx, facts, c).is_none()
    };
    let by_evidence = tried
        .iter()
        .enumerate()
        .filter(|(_, t)| qualifies(t) && !remaining[t.0].physical())
        .max_by(|a, b| remaining[a.1.0].evidence_um.total_cmp(&remaining[b.1.0].evidence_um))
        .map(|(pos, _)| pos);
    let plateau = |c: &Candidate| c.output_range.is_some();
    let by_rms = tried
        .iter()
        .enumerate()
        .filter(|(_, t)| qualifies(t) && remaining[t.0].physical())
        .min_by(|a, b| {
            plateau(&remaining[b.1.0]).cmp(&plateau(&remaining[a.1.0])).then(a.1.2.total_cmp(&b.1.2))
        })
        .map(|(pos, _)| pos);
    match (by_evidence, by_rms) {
        (Some(e), Some(r)) if tried[r].2 < tried[e].2 => Some(r),
        (Some(e), _) => Some(e),
        (None, r) => r,
    }
}

/// Why each term of the round that gained enough was not kept (positions in `tried`).
#[allow(clippy::too_many_arguments)]
fn reasons(
    cx: &Context<'_>,
    facts: &Facts,
    read: &Read,
    remaining: &[Candidate],
    tried: &[Tried],
    winner: Option<usize>,
    model_rms: f64,
    round: usize,
) -> Vec<(usize, NotKept)> {
    let mut out = vec![];
    for (pos, t) in tried.iter().enumerate() {
        if !gains(cx, t, model_rms) || Some(pos) == winner {
            continue;
        }
        let c = &remaining[t.0];
        let need = read.min_term(cx, facts, c);
        let reason = if let (true, Some(share)) = (t.3 >= need, read.drive_share(cx, facts, c)) {
            let order = c.order.unwrap_or(0);
            NotKept::DriveHarmonic {
                order,
                drive_rel: cx.plan.drive.harmonic_rel(order as usize),
                share,
                gain_pct: 100.0 * (1.0 - t.2 / model_rms.max(1e-300)),
                floor: cx.rules.sine.drive_distortion_floor,
            }
        } else if t.3 < need {
            NotKept::CarriesTooLittle {
                carried_um: t.3,
                need_um: need,
                min_term_rel: cx.rules.terms.min_term_rel,
                noise_factor: matches!(c.kind, Kind::Drift | Kind::Creep)
                    .then_some(cx.rules.sine.drift_noise_factor),
                removed: None,
            }
        } else if let Some(w) = winner {
            let wc = &remaining[tried[w].0];
            if wc.physical() || c.physical() {
                NotKept::LowerRms { winner: wc.term(), winner_um: tried[w].2, this_um: t.2, round }
            } else {
                NotKept::MoreEvidence {
                    winner: wc.term(),
                    winner_evidence: wc.evidence_um,
                    this_evidence: c.evidence_um,
                    db: false,
                    round,
                }
            }
        } else {
            continue;
        };
        out.push((pos, reason));
    }
    out
}

/// The first round's winner with its term removed, refitted as a baseline: kept when it
/// lowers the baseline's held-out RMS by `sine.baseline_refit_gain` (a term's fit searches
/// structures again and may find one the baseline's fit missed, so that a term is credited
/// only with what the baseline cannot do).
fn better_baseline(cx: &Context<'_>, base: &Baseline, m: &TermModel, c: &Candidate) -> Option<HostModel> {
    let stripped = without(m, c).host;
    let b = fit::fit_oe_on(&cx.data, &cx.spec, &[stripped], cx.opt()).ok()?.model;
    let gain = cx.rules.sine.baseline_refit_gain;
    fit::free_run_rms(&b, cx.u, cx.y, cx.ts, cx.split())
        .is_ok_and(|r| r < base.rms_um * (1.0 - gain))
        .then_some(b)
}

/// Fits the candidate's term onto `model`: a harmonic branch or a drift line by
/// [`fit::fit_oe_on`] (on the record prepared in `cx`, or on the input as the model's terms
/// transform it), or by a joint refinement when the model has terms inside or after it; a
/// saturation or creep by its own fit ([`causes`]).
///
/// `prev` is the candidate's model of the last round. When the term kept since then acts
/// inside or after the model (a clamp of the output, creep), a joint refinement from the
/// current model with the new term at zero can stay where the current model's loop already
/// imitates the term; the candidate's own fit of the last round with the kept term added is
/// then a second start, and the start that ends with the lower fitting error is taken.
fn try_term(
    cx: &Context<'_>,
    model: &TermModel,
    c: &Candidate,
    prev: Option<&TermModel>,
) -> Option<TermModel> {
    let (u, y, ts, split, opt) = (cx.u, cx.y, cx.ts, cx.split(), cx.opt());
    let terms = &cx.rules.terms;
    match c.kind {
        Kind::Saturation => match c.output_range {
            Some(range) => causes::fit_output_clamp(model, range, u, y, ts, split, opt, cx.rules),
            None => {
                causes::fit_input_clamp(model, &causes::spec_of(&model.host), u, y, ts, split, opt, cx.rules)
            }
        },
        Kind::Creep => causes::fit_creep(model, u, y, ts, split, opt, cx.rules),
        Kind::OddHarmonic | Kind::EvenHarmonic | Kind::Drift => {
            let spec = with_term(&model.host, c, ts)?;
            if model.terms.is_empty() {
                let f = fit::fit_oe_on(&cx.data, &spec, std::slice::from_ref(&model.host), opt).ok()?;
                return Some(TermModel::from(f.model));
            }
            if model.terms.input_only() {
                return causes::fit_host(model, &spec, u, y, ts, split, opt).ok().map(|r| r.0);
            }
            let from_model = causes::refine_with(model, &spec, u, y, ts, split, opt, terms);
            let warm =
                prev.filter(|p| p.terms != model.terms && p.host.branches.len() >= model.host.branches.len());
            let from_prev = warm.and_then(|p| {
                let mut start = p.clone();
                start.terms = model.terms.clone();
                let free = start.host_params();
                refine(&start, &free, u, y, ts, &causes::criterion(opt, split, ts, terms))
            });
            match (from_model, from_prev) {
                (Some(a), Some(b)) => Some(if b.1 < a.1 { b.0 } else { a.0 }),
                (a, b) => a.or(b).map(|r| r.0),
            }
        }
        Kind::OtherInput
        | Kind::InputDelay
        | Kind::OddDistortion
        | Kind::EvenDistortion
        | Kind::RestoringForce => None,
    }
}

/// The held-out RMS (µm) of what the term of `c` carries in `model`: the change of its free
/// run when the term is removed.
pub fn term_rms(
    model: &TermModel,
    c: &Candidate,
    u: &[f64],
    ts: f64,
    split: usize,
) -> Result<f64, DiagnoseError> {
    let a = model.simulate(u, ts)?;
    let b = without(model, c).simulate(u, ts)?;
    let d: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
    if c.kind == Kind::Creep {
        // Creep relaxes mostly before the held-out half: what it carries is its relaxation
        // towards its last level over the whole run after the start-up (the first fifth of
        // the fitted half).
        let last = d.last().copied().unwrap_or(0.0);
        let from = (split / START_UP_SHARE).min(d.len());
        return Ok(analysis::rms(&d[from..].iter().map(|v| v - last).collect::<Vec<_>>()));
    }
    // A drift line's level is traded against the loop's offset: count its change from the
    // middle of the fitted half.
    let level = if c.kind == Kind::Drift { d[split / 2] } else { 0.0 };
    let carried = analysis::rms(&d[split..].iter().map(|v| v - level).collect::<Vec<_>>());
    // Without its term a model may leave the range it was fitted in (a drive clamp's, fitted
    // to the clamped drive, driven by the whole drive): the term then carries the whole
    // output, no more.
    let held = &a[split..];
    let centre = analysis::mean(held);
    let whole = analysis::rms(&held.iter().map(|v| v - centre).collect::<Vec<_>>());
    Ok(carried.min(whole))
}

/// What creep carries is counted after the start-up: the first part of the fitted half, one
/// in this many of its samples.
const START_UP_SHARE: usize = 5;

/// `model` without the candidate's term.
pub fn without(model: &TermModel, c: &Candidate) -> TermModel {
    let mut m = model.clone();
    match c.kind {
        // The offset stays; the drift is the rest of the polynomial.
        Kind::Drift => m.host.drift.truncate(1),
        Kind::Saturation if c.output_range.is_some() => m.terms.output_clamp = None,
        Kind::Saturation => m.terms.input_clamp = None,
        Kind::Creep => m.terms.creep.clear(),
        _ => m.host.branches.retain(|b| Some(b.order) != c.order),
    }
    m
}

/// The current model's spec with the candidate's term added (`None` if it cannot be).
fn with_term(model: &HostModel, c: &Candidate, ts: f64) -> Option<ModelSpec> {
    let mut spec = causes::spec_of(model);
    match c.kind {
        Kind::Drift if spec.drift_degree.is_none_or(|d| d == 0) => spec.drift_degree = Some(1),
        Kind::OddHarmonic | Kind::EvenHarmonic => {
            let o = c.order?;
            if spec.harmonics.contains(&o)
                || spec.harmonics.len() >= crate::model::MAX_BRANCHES
                || o as f64 * model.drive_hz >= 0.5 / ts
            {
                return None;
            }
            spec.harmonics.push(o);
        }
        _ => return None,
    }
    Some(spec)
}
