//! A record that steps through several sines (a stepped sine: the same actuator at a series
//! of frequencies or amplitudes in one file, [`steady::sine_segments`]): each step is
//! diagnosed on its own (its own steady window, start-up and model), on all cores. The delay
//! is measured from the first step only: after it the actuator was not at rest.

use super::Outcome;
use super::error::DiagnoseError;
use super::plan::plan_in;
use super::sine::diagnose_planned;
use crate::rules::Rules;
use crate::signal::steady::{self, SineSegment};
use rayon::prelude::*;

/// One steady sine of a record that steps through several, and its diagnosis.
#[derive(Debug)]
pub struct SineStep {
    /// Where the sine is, its frequency and amplitude.
    pub segment: SineSegment,
    /// Its diagnosis, or why there is none.
    pub outcome: Result<Outcome, DiagnoseError>,
}

/// Each step of a stepped sine diagnosed; `None` if the record does not step through two
/// sines or more.
pub fn diagnose_steps(u: &[f64], y: &[f64], ts: f64, t0: f64, r: &Rules) -> Option<Vec<SineStep>> {
    let n = u.len().min(y.len());
    let segments = steady::sine_segments(&u[..n], ts, r);
    if segments.len() < 2 {
        return None;
    }
    Some(
        segments
            .par_iter()
            .map(|&segment| {
                let (a, b) = (segment.start, segment.end);
                let (u, y, t0) = (&u[a..b], &y[a..b], t0 + a as f64 * ts);
                let outcome = steady::steady_window(u, y, ts, None, r)
                    .map_err(DiagnoseError::Window)
                    .and_then(|(w, d)| plan_in(u, y, ts, t0, w, d, r))
                    .and_then(|mut plan| {
                        plan.from_rest = a == 0;
                        diagnose_planned(u, y, ts, &plan, r).map(|d| Outcome::Sine(Box::new(d)))
                    });
                SineStep { segment, outcome }
            })
            .collect(),
    )
}
