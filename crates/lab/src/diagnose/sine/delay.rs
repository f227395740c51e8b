//! Stage 6: the input delay, from the step onto the drive. A single sine cannot tell a delay
//! from the structure's phase (the model absorbs it by moving its resonance), but the step
//! excites every frequency: fitted over the start-up and the first periods with and without
//! a delay ([`causes::delay_scan`]), a delay of `causes.min_delay_samples` or more that
//! gains `terms.min_gain` there is a finding, and the extended model carries it when its
//! held-out error rises by at most `causes.delay_held_out_slack`.

use super::candidates::Read;
use super::{Context, DelayEstimate};
use crate::diagnose::causes;
use crate::diagnose::checks;
use crate::diagnose::error::DiagnoseError;
use crate::diagnose::evidence::{DelayEvidence, Evidence, Finding, Kind};
use crate::model::terms::TermModel;
use crate::signal::analysis;

/// The model after the delay stage.
#[derive(Clone, Debug)]
pub struct Delayed {
    /// The model, with the delay if it carries it.
    pub model: TermModel,
    /// Its held-out RMS (µm).
    pub model_rms: f64,
    /// The delay the step shows, if the record holds the step.
    pub estimate: Option<DelayEstimate>,
    /// The finding, if the delay is one.
    pub finding: Option<Finding>,
}

/// Whether the record holds the step onto the drive: the actuator at rest before it (the
/// record's own start), an idle part before the drive or a drive that starts within
/// `sine.step_from_rest` of its amplitude from 0 V, and a start-up after it.
fn holds_step(cx: &Context<'_>, read: &Read) -> bool {
    let (p, w) = (cx.plan, &cx.plan.window);
    p.from_rest
        && w.start > w.drive_on
        && (w.drive_on > 0
            || cx.u.first().is_some_and(|u0| u0.abs() <= cx.rules.sine.step_from_rest * read.drive_amp_v))
}

/// The delay stage on the selected model.
pub fn stage(
    cx: &Context<'_>,
    read: &Read,
    model: TermModel,
    model_rms: f64,
) -> Result<Delayed, DiagnoseError> {
    let mut out = Delayed { model, model_rms, estimate: None, finding: None };
    if !holds_step(cx, read) {
        return Ok(out);
    }
    let (u, y, ts, split, opt) = (cx.u, cx.y, cx.ts, cx.split(), cx.opt());
    let Some(scan) =
        causes::delay_scan(&out.model, &causes::spec_of(&out.model.host), u, y, ts, split, opt, cx.rules)
    else {
        return Ok(out);
    };
    out.estimate = Some(DelayEstimate {
        samples: scan.samples,
        rms_without_um: scan.rms_without_um,
        rms_with_um: scan.rms_with_um,
    });
    let gain = 1.0 - scan.rms_with_um / scan.rms_without_um.max(1e-300);
    let c = &cx.rules.causes;
    if scan.samples < c.min_delay_samples || gain < cx.rules.terms.min_gain {
        return Ok(out);
    }
    // The extended model with the delay, fitted on the usual criterion; kept if its held-out
    // error is no worse than without (to within the slack).
    let mut dm = out.model.clone();
    dm.terms.extra_delay = scan.model.terms.extra_delay;
    dm.host.delay = scan.model.host.delay;
    let with =
        causes::fit_host(&dm, &causes::spec_of(&dm.host), u, y, ts, split, opt).ok().and_then(|(m, _)| {
            let sim = m.simulate(u, ts).ok()?;
            let r = analysis::rms_diff(&sim[split..], &y[split..]);
            (checks::instability(&m.host.ext.ar, &sim, ts).is_none() && r.is_finite()).then_some((m, r))
        });
    let before = out.model_rms;
    let kept = with.as_ref().is_some_and(|(_, r)| *r <= before * c.delay_held_out_slack);
    if let (true, Some((m, r))) = (kept, with) {
        (out.model, out.model_rms) = (m, r);
    }
    let b = scan.rms_without_um;
    out.finding = Some(Finding {
        kind: Kind::InputDelay,
        order: None,
        freq_hz: 0.0,
        kept,
        residual_share: ((b * b - scan.rms_with_um * scan.rms_with_um) / (b * b).max(1e-300)).clamp(0.0, 1.0),
        term_rms_um: scan.change_rms_um,
        rms_with_term_um: kept.then_some(out.model_rms),
        evidence: Evidence::InputDelay(DelayEvidence {
            samples: scan.samples,
            ts,
            window_s: scan.window_s,
            startup_without_um: scan.rms_without_um,
            startup_with_um: scan.rms_with_um,
            held_out_before_um: before,
            held_out_after_um: kept.then_some(out.model_rms),
            min_samples: c.min_delay_samples,
            held_out_slack: c.delay_held_out_slack,
        }),
    });
    Ok(out)
}
