//! Stage 6 of a periodic diagnosis: where the hysteresis sits. When the extended model
//! (hysteresis at the drive) leaves at least `families.min_residual_share` of the output's
//! RMS held out, the Bouc–Wen oscillator
//! (hysteresis as a restoring force inside the structure, [`crate::model::oscillator`]) is
//! fitted on the same samples ([`crate::fit::family::fit_oscillator_on`]) and tested on the
//! same held-out data. It is a finding ([`Kind::RestoringForce`]) when it lowers the held-out
//! RMS of the best model with hysteresis at the drive (the extended model and the terms kept)
//! by `families.min_gain` and leaves at most `families.max_noise_ratio` times the noise
//! floor (it explains the record, not only more of it than the extended model); the
//! distortion findings (terms kept, distortion left unexplained) are then superseded: the
//! oscillator accounts for them.

use super::ModelStep;
use super::data::Data;
use crate::diagnose::evidence::{Evidence, Finding, Kind, PlacementEvidence};
use crate::fit::family::{fit_oscillator_on, simulate, substeps, whole_period};
use crate::model::Model;
use crate::rules::Rules;
use crate::signal::analysis;

/// The oscillator tried against the extended model.
#[derive(Clone, Debug, PartialEq)]
pub struct Placement {
    /// The facts.
    pub evidence: PlacementEvidence,
    /// Whether it is a finding (gain at least `families.min_gain`).
    pub kept: bool,
}

impl Placement {
    /// The finding it makes.
    pub fn finding(&self) -> Finding {
        Finding {
            kind: Kind::RestoringForce,
            order: None,
            freq_hz: 0.0,
            kept: self.kept,
            residual_share: self.evidence.gain(),
            term_rms_um: 0.0,
            rms_with_term_um: Some(self.evidence.restoring_um),
            evidence: Evidence::RestoringForce(self.evidence),
        }
    }
}

/// Tries the oscillator when the rules let it (module docs); `None` when they do not, or
/// when it cannot be fitted or diverges held out.
pub fn restoring_force(
    data: &Data,
    baseline: &ModelStep,
    best: &ModelStep,
    output_rms_um: f64,
    noise_um: f64,
    ts: f64,
    r: &Rules,
) -> Option<Placement> {
    let f = &r.families;
    if !baseline.usable() || !best.usable() || baseline.rms_um < f.min_residual_share * output_rms_um {
        return None;
    }
    let period = whole_period(data.period);
    let s0 = &data.sets[0];
    let end = data.fit_end.min(s0.u.len());
    let osc = fit_oscillator_on(&s0.u[..end], &s0.y[..end], ts, s0.start..end, period, f).ok()?;
    let model = Model::Oscillator(osc);
    let (mut err, mut count) = (0.0, 0usize);
    for &(i, a, b) in &data.held {
        let s = &data.sets[i];
        let sim = simulate(&model, &s.u[..b], ts, period).ok()?;
        let rms = analysis::rms_diff(&sim[a..b], &s.y[a..b]);
        err += rms * rms * (b - a) as f64;
        count += b - a;
    }
    let restoring_um = (err / count.max(1) as f64).sqrt();
    if !restoring_um.is_finite() {
        return None;
    }
    let Model::Oscillator(o) = model else { return None };
    let evidence = PlacementEvidence {
        at_drive_um: best.rms_um,
        restoring_um,
        min_gain: f.min_gain,
        noise_um,
        max_noise_ratio: f.max_noise_ratio,
        params: o.params,
        substeps: substeps(ts, f),
    };
    Some(Placement { kept: evidence.meets_rules(), evidence })
}
