//! Stage 1 of a sine diagnosis: where it is made. The steady window, the drive, the split
//! into fitted and held-out periods, and the fit's criterion ([`Plan`]).

use super::error::DiagnoseError;
use crate::fit::{Averaging, OeOptions};
use crate::rules::Rules;
use crate::signal::steady::{self, Drive, DriveKind, Window, whole_periods_in};

/// Where a diagnosis is made (the front end for measured records): the window, the drive,
/// the split into fitted and held-out periods, and the fit's criterion.
#[derive(Clone, Debug)]
pub struct Plan {
    /// The window analysed.
    pub window: Window,
    /// The drive in it.
    pub drive: Drive,
    /// First held-out sample, counted from `window.drive_on`.
    pub split: usize,
    /// Whole periods fitted and held out.
    pub periods: (usize, usize),
    /// The fit's settings (criterion from `skip`, counted from `window.drive_on`).
    pub opt: OeOptions,
    /// Time of the record's first sample (s).
    pub t0: f64,
    /// Whether the actuator was at rest before the drive came on (a record's own start; not
    /// a step of a stepped sine after the first), so that the step onto the drive measures
    /// the delay.
    pub from_rest: bool,
}

/// The fit settings of the diagnosis: the loop need not be invertible (the model explains a
/// record, it is not used to compensate).
///
/// The criterion covers the whole first half but its first `sine.skip_share` (at most
/// `sine.max_skip_s`): the record starts from rest (or from wherever the actuator was), and
/// the start-up transient of a lightly damped resonance is not what the diagnosis is about.
/// Under a periodic drive the fit separates a trend and averages the periods of that part
/// first ([`Averaging::PeriodsAndTrend`]), so its cost does not grow with the record; the
/// trend is the drift term's to explain.
pub fn fit_options(split: usize, ts: f64, r: &Rules) -> OeOptions {
    let share = (split as f64 * r.sine.skip_share) as usize;
    let skip = share.min((r.sine.max_skip_s / ts) as usize).max(OeOptions::default().skip);
    OeOptions {
        require_invertible: false,
        skip,
        averaging: Averaging::PeriodsAndTrend,
        lm_starts: r.terms.term_starts,
        ..OeOptions::default()
    }
}

/// Plans the diagnosis of a record (see [`Plan`]): finds the steady window (or takes
/// `given`, in samples), the drive, checks that the output responds, that the drive is a
/// sine, and that the window holds `sine.min_periods` whole periods and `sine.min_samples`
/// samples. Every refusal is one sentence with the rule and the numbers.
pub fn plan(
    u: &[f64],
    y: &[f64],
    ts: f64,
    t0: f64,
    given: Option<(usize, usize)>,
    r: &Rules,
) -> Result<Plan, DiagnoseError> {
    let (window, drive) = steady::steady_window(u, y, ts, given, r)?;
    plan_in(u, y, ts, t0, window, drive, r)
}

/// [`plan`] in a steady window already found (by [`steady::steady_window`] on `u`, `y`).
pub fn plan_in(
    u: &[f64],
    y: &[f64],
    ts: f64,
    t0: f64,
    window: Window,
    drive: Drive,
    r: &Rules,
) -> Result<Plan, DiagnoseError> {
    let window_s = window.seconds(t0, ts);
    if drive.kind == DriveKind::None {
        return Err(DiagnoseError::NoDrive { std_v: drive.std_v });
    }
    let (start, end) = (window.start, window.end);
    steady::check_response(&u[start..end], &y[start..end], ts, &drive, r)?;
    if drive.kind != DriveKind::Sine {
        return Err(DiagnoseError::NotSine { drive: drive.describe() });
    }
    let drive_hz = drive.freq_hz;
    if 2.0 * drive_hz >= 0.5 / ts {
        return Err(DiagnoseError::DriveTooFast { drive_hz, nyquist_hz: 0.5 / ts });
    }
    let samples = end - start;
    let p = drive.period_samples.unwrap_or(1.0 / (drive_hz * ts));
    // The window ends on a whole period rounded to a sample.
    let periods = whole_periods_in(samples, p, 0.5);
    if periods < r.sine.min_periods {
        return Err(DiagnoseError::TooFewPeriods { drive_hz, periods, need: r.sine.min_periods, window_s });
    }
    if samples < r.sine.min_samples {
        return Err(DiagnoseError::TooFewSamples { samples, need: r.sine.min_samples, window_s });
    }
    let p_fit = periods.div_ceil(2);
    let split = start + (p_fit as f64 * p).round() as usize - window.drive_on;
    let start_rel = start - window.drive_on;
    let mut opt = fit_options(split, ts, r);
    opt.skip = start_rel.max(opt.skip.min(split.saturating_sub(r.sine.fit_min_samples)));
    Ok(Plan { window, drive, split, periods: (p_fit, periods - p_fit), opt, t0, from_rest: true })
}
