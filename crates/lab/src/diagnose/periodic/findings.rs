//! Stage 5 of a periodic diagnosis: the findings ([`Kind::OddDistortion`],
//! [`Kind::EvenDistortion`]). A kept term, with the data's level at the lines of its parity
//! (or, for a triangle's odd lines, which are all excited, the level of what the term
//! accounts for there) and the band; or distortion of a parity the model leaves in its
//! held-out residual (`terms.unexplained_share` of its power at the distortion lines and
//! `terms.min_term_rel` of the output) with no term to remove it (`kept: false`), the parity
//! with more evidence first. Distortion the extended model accounts for is not a finding.

use super::ModelStep;
use super::data::Data;
use super::terms::{Kept, evidence};
use crate::diagnose::evidence::{DistortionEvidence, Evidence, Finding, Kind, Lines, Step};
use crate::model::terms::TermModel;
use crate::rules::Rules;
use crate::signal::distortion::{self, Level, Line, Parity};
use crate::signal::steady::DriveKind;

/// The findings of the kept terms, then of what no term removed.
pub fn findings(
    data: &Data,
    baseline: &ModelStep,
    kept: &Kept,
    out_rms: f64,
    ts: f64,
    r: &Rules,
) -> Vec<Finding> {
    let mut found: Vec<Finding> = kept_findings(data, baseline, kept, ts, r);
    let n_kept = found.len();
    let last = kept.steps.last().unwrap_or(baseline);
    let lines_power = (last.odd.rms_um.powi(2) + last.even.rms_um.powi(2)).max(1e-300);
    for p in [Parity::Odd, Parity::Even] {
        if kept.parities.contains(&p) {
            continue;
        }
        let lv = level_of(last, p);
        let share = lv.rms_um * lv.rms_um / lines_power;
        if lv.detected && share >= r.terms.unexplained_share && lv.rms_um >= r.terms.min_term_rel * out_rms {
            found.push(Finding {
                kind: Kind::of_parity(p),
                order: None,
                freq_hz: lv.band_hz.map_or(0.0, |b| 0.5 * (b[0] + b[1])),
                kept: false,
                residual_share: share,
                term_rms_um: lv.rms_um,
                rms_with_term_um: None,
                evidence: Evidence::UnexplainedDistortion {
                    parity: p,
                    level: lv,
                    share,
                    // A triangle's or a square's own harmonics (or every line of a drive that
                    // excites both parities): the model's response to them is what is off,
                    // not distortion the record shows by itself.
                    on_drive_lines: !data.odd_drive || (p == Parity::Odd && data.odd.is_none()),
                },
            });
        }
    }
    let parity = |f: &Finding| if f.kind == Kind::OddDistortion { Parity::Odd } else { Parity::Even };
    found[n_kept..]
        .sort_by(|a, b| evidence(data, baseline, parity(b)).total_cmp(&evidence(data, baseline, parity(a))));
    found
}

/// A model step's held-out level at a parity's lines.
fn level_of(s: &ModelStep, p: Parity) -> Level {
    match p {
        Parity::Odd => s.odd,
        Parity::Even => s.even,
    }
}

/// The findings of the kept terms.
fn kept_findings(data: &Data, baseline: &ModelStep, kept: &Kept, ts: f64, r: &Rules) -> Vec<Finding> {
    let residual_power = (baseline.rms_um * baseline.rms_um).max(1e-300);
    let mut out = vec![];
    for (n, &p) in kept.parities.iter().enumerate() {
        let before = if n == 0 { baseline } else { &kept.steps[n - 1] };
        let after = &kept.steps[n];
        let free = match p {
            Parity::Odd => data.odd,
            Parity::Even => data.even,
        };
        let contribution = term_level(&after.model, &before.model, data, ts, p, r);
        let e = DistortionEvidence {
            parity: p,
            lines: match (p, data.drive.kind) {
                (Parity::Even, _) => Lines::Even,
                (Parity::Odd, DriveKind::Multisine) => Lines::OddLeftOut,
                (Parity::Odd, _) => Lines::Odd,
            },
            data: free,
            contribution,
            drive: data.drive.kind,
            baseline: (baseline.label.clone(), level_of(baseline, p)),
            step: Step { before_um: before.rms_um, after_um: after.rms_um, first: n == 0 },
            after: level_of(after, p),
            stiffening: after
                .model
                .terms
                .stiffening
                .last()
                .map(|s| (s.power, s.coeff, after.model.terms.q_ref_um)),
        };
        let band = e.level().band_hz;
        let trial = kept.trials.iter().find(|t| t.kept && t.parity == p);
        out.push(Finding {
            kind: Kind::of_parity(p),
            order: None,
            freq_hz: band.map_or(0.0, |b| 0.5 * (b[0] + b[1])),
            kept: true,
            residual_share: ((before.rms_um.powi(2) - after.rms_um.powi(2)) / residual_power).clamp(0.0, 1.0),
            term_rms_um: trial.map_or(f64::NAN, |t| t.term_rms_um),
            rms_with_term_um: Some(after.rms_um),
            evidence: Evidence::Distortion(e),
        });
    }
    out
}

/// The level (dB above the output's noise) of what `with` adds to `without` at the lines of
/// parity `p` up to the distortion's top line, over the held-out parts.
fn term_level(with: &TermModel, without: &TermModel, data: &Data, ts: f64, p: Parity, r: &Rules) -> Level {
    let mut per: Vec<Vec<Line>> = vec![];
    for &(i, a, b) in &data.held {
        let s = &data.sets[i];
        let (Ok(x), Ok(z)) = (with.simulate(&s.u[..b], ts), without.simulate(&s.u[..b], ts)) else {
            continue;
        };
        let d: Vec<f64> = x[a..b].iter().zip(&z[a..b]).map(|(x, z)| x - z).collect();
        // The difference's lines, with the noise of the output's lines.
        let (Some(dl), Some(yl)) = (
            distortion::lines(&s.u[a..b], &d, data.period, ts, data.kmax, r),
            distortion::lines(&s.u[a..b], &s.y[a..b], data.period, ts, data.kmax, r),
        ) else {
            continue;
        };
        per.push(
            dl.lines
                .iter()
                .zip(&yl.lines)
                .filter(|(l, _)| p.has(l.k) && l.k <= data.top)
                .map(|(l, y)| Line { noise_var: y.noise_var, ..*l })
                .collect(),
        );
    }
    let refs: Vec<&[Line]> = per.iter().map(|v| v.as_slice()).collect();
    distortion::level(&refs, &r.periodic)
}
