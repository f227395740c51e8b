//! Stages 1 and 2 of a periodic diagnosis: where (each realisation's steady window, whole
//! periods of one drive) and what the data show at the lines of whole periods (the excited
//! lines, the BLA, the levels at the odd lines left out and the even lines, the noise).

use super::{HeldOut, Realisation};
use crate::diagnose::error::DiagnoseError;
use crate::rules::Rules;
use crate::signal::distortion::{self, BlaLine, Level, Line, Lines, Parity};
use crate::signal::steady::{self, Drive, DriveKind, Window, whole_periods_in};

/// A realisation prepared: its samples from the step onto the drive, where the steady part
/// starts and ends in them.
pub struct Set {
    /// Drive (V) from `drive_on`.
    pub u: Vec<f64>,
    /// Output (µm) from `drive_on`.
    pub y: Vec<f64>,
    /// First steady sample (from `drive_on`).
    pub start: usize,
    /// End of the whole periods analysed (from `drive_on`).
    pub end: usize,
}

/// The realisations of one drive, their windows and lines, and how the models are tested.
pub struct Data {
    /// The drive (of the first realisation).
    pub drive: Drive,
    /// Samples per period.
    pub period: f64,
    /// Each realisation's window and first sample's time.
    pub windows: Vec<(Window, f64)>,
    /// Whole periods per realisation.
    pub periods: Vec<usize>,
    /// The realisations.
    pub sets: Vec<Set>,
    /// Their lines over their windows.
    pub lines: Vec<Lines>,
    /// Highest line analysed.
    pub kmax: u32,
    /// Highest line distortion is looked for at.
    pub top: u32,
    /// Highest excited line.
    pub k_excited_top: u32,
    /// The drive excites odd lines only.
    pub odd_drive: bool,
    /// The data's level at the odd lines the drive leaves out (`None`: it leaves none, e.g.
    /// a triangle, or it excites even lines too).
    pub odd: Option<Level>,
    /// The data's level at the even lines (`None`: the drive excites even lines).
    pub even: Option<Level>,
    /// What the held-out error is measured on.
    pub held_out: HeldOut,
    /// End of the fitted part of the first realisation.
    pub fit_end: usize,
    /// The held-out parts: (realisation, first sample, end).
    pub held: Vec<(usize, usize, usize)>,
}

impl Data {
    /// The lines of a parity the data can show distortion at: the odd lines the drive leaves
    /// out (up to its highest excited line), the even lines up to `top`.
    pub fn parity_lines(&self, l: &Lines, p: Parity) -> Vec<Line> {
        match p {
            Parity::Odd => distortion::non_excited(l, Parity::Odd, self.k_excited_top),
            Parity::Even => distortion::non_excited(l, Parity::Even, self.top),
        }
    }

    /// The level of a parity's free lines pooled over the realisations; `None` under
    /// `periodic.min_lines` lines.
    fn pooled(&self, p: Parity, r: &Rules) -> Option<Level> {
        let per: Vec<Vec<Line>> = self.lines.iter().map(|l| self.parity_lines(l, p)).collect();
        let refs: Vec<&[Line]> = per.iter().map(|v| v.as_slice()).collect();
        let lv = distortion::level(&refs, &r.periodic);
        (lv.lines >= r.periodic.min_lines).then_some(lv)
    }

    /// The BLA over the realisations.
    pub fn bla(&self, r: &Rules) -> Vec<BlaLine> {
        distortion::bla(&self.lines, &r.periodic)
    }

    /// RMS of the output over the held-out parts, its mean removed (µm).
    pub fn output_rms(&self) -> f64 {
        let ys: Vec<f64> =
            self.held.iter().flat_map(|&(i, a, b)| self.sets[i].y[a..b].iter().copied()).collect();
        let m = crate::signal::analysis::mean(&ys);
        (ys.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / ys.len().max(1) as f64).sqrt()
    }

    /// The output's noise floor (µm, RMS over the realisations) and how it was measured.
    pub fn noise(&self, ts: f64, r: &Rules) -> (f64, &'static str) {
        let per: Vec<(f64, &'static str)> =
            self.sets.iter().map(|s| steady::noise_floor(&s.y[s.start..s.end], ts, &self.drive, r)).collect();
        let how = if per.iter().any(|p| p.1 == "quantisation") { "quantisation" } else { "period_to_period" };
        ((per.iter().map(|v| v.0 * v.0).sum::<f64>() / per.len() as f64).sqrt(), how)
    }
}

/// Each record's steady window and drive, checked to be a periodic or multisine drive the
/// output responds to.
fn windows(
    records: &[Realisation<'_>],
    ts: f64,
    r: &Rules,
) -> Result<Vec<(Window, f64, Drive)>, DiagnoseError> {
    let mut out = vec![];
    for rec in records {
        let n = rec.u.len().min(rec.y.len());
        let (w, d) = steady::steady_window(&rec.u[..n], &rec.y[..n], ts, rec.given, r)?;
        if d.kind == DriveKind::None {
            return Err(DiagnoseError::NoDrive { std_v: d.std_v });
        }
        steady::check_response(&rec.u[w.start..w.end], &rec.y[w.start..w.end], ts, &d, r)?;
        if !matches!(d.kind, DriveKind::Periodic | DriveKind::Multisine) {
            return Err(DiagnoseError::NotPeriodic { drive: d.describe() });
        }
        out.push((w, rec.t0, d));
    }
    Ok(out)
}

/// The realisations prepared (see [`Data`]): one period for all (`periodic.period_tolerance`),
/// enough whole periods each, the same excited lines.
pub fn prepare(records: &[Realisation<'_>], ts: f64, r: &Rules) -> Result<Data, DiagnoseError> {
    let found = windows(records, ts, r)?;
    let drive =
        found.first().map(|f| f.2.clone()).ok_or(DiagnoseError::Realisations("no record given".into()))?;
    let period = drive.period_samples.unwrap_or(0.0);
    for (i, (_, _, d)) in found.iter().enumerate().skip(1) {
        let p = d.period_samples.unwrap_or(0.0);
        if (p - period).abs() > r.periodic.period_tolerance * period {
            return Err(DiagnoseError::Realisations(format!(
                "record {} repeats every {:.2} samples, the first every {period:.2}: they are not realisations of one \
                 drive",
                i + 1,
                p
            )));
        }
    }
    let need = if records.len() >= 2 { r.periodic.min_realisation_periods } else { r.periodic.min_periods };
    let (mut sets, mut periods) = (vec![], vec![]);
    for (rec, (w, t0, _)) in records.iter().zip(&found) {
        let m = whole_periods_in(w.end - w.start, period, r.drive.period_slack_samples);
        if m < need {
            return Err(DiagnoseError::TooFewPeriods {
                drive_hz: drive.freq_hz,
                periods: m,
                need,
                window_s: w.seconds(*t0, ts),
            });
        }
        let end = w.start + (m as f64 * period).round() as usize;
        sets.push(Set {
            u: rec.u[w.drive_on..end].to_vec(),
            y: rec.y[w.drive_on..end].to_vec(),
            start: w.start - w.drive_on,
            end: end - w.drive_on,
        });
        periods.push(m);
    }
    let windows: Vec<(Window, f64)> = found.into_iter().map(|(w, t0, _)| (w, t0)).collect();
    lines_of(drive, period, windows, periods, sets, ts, r)
}

/// The lines of each realisation, checked to excite the same lines, and the split into
/// fitted and held-out parts.
fn lines_of(
    drive: Drive,
    period: f64,
    windows: Vec<(Window, f64)>,
    periods: Vec<usize>,
    sets: Vec<Set>,
    ts: f64,
    r: &Rules,
) -> Result<Data, DiagnoseError> {
    let f0 = drive.freq_hz;
    let kmax = ((0.5 / ts / f0).floor() as u32).saturating_sub(1).clamp(1, r.periodic.max_lines);
    let lines: Vec<Lines> = sets
        .iter()
        .map(|s| distortion::lines(&s.u[s.start..s.end], &s.y[s.start..s.end], period, ts, kmax, r))
        .collect::<Option<_>>()
        .ok_or_else(|| DiagnoseError::TooFewPeriods {
            drive_hz: f0,
            periods: 1,
            need: r.periodic.min_periods,
            window_s: windows[0].0.seconds(windows[0].1, ts),
        })?;
    let excited: Vec<u32> = lines[0].lines.iter().filter(|l| l.excited).map(|l| l.k).collect();
    for (i, l) in lines.iter().enumerate().skip(1) {
        let e: Vec<u32> = l.lines.iter().filter(|l| l.excited).map(|l| l.k).collect();
        if e != excited {
            return Err(DiagnoseError::Realisations(format!(
                "record {} excites {} lines, the first {}: they are not realisations of one drive",
                i + 1,
                e.len(),
                excited.len()
            )));
        }
    }
    let held_out = if sets.len() >= 2 { HeldOut::Realisations } else { HeldOut::Periods };
    let (fit_end, held) = match held_out {
        HeldOut::Realisations => {
            (sets[0].end, (1..sets.len()).map(|i| (i, sets[i].start, sets[i].end)).collect())
        }
        HeldOut::Periods => {
            let s = &sets[0];
            let split = s.start + (periods[0].div_ceil(2) as f64 * period).round() as usize;
            (split, vec![(0, split, s.end)])
        }
    };
    let mut data = Data {
        odd_drive: distortion::odd_drive(&lines[0]),
        odd: None,
        even: None,
        top: distortion::distortion_top(&lines[0], ts, r),
        k_excited_top: excited.iter().copied().max().unwrap_or(1),
        drive,
        period,
        windows,
        periods,
        sets,
        lines,
        kmax,
        held_out,
        fit_end,
        held,
    };
    if data.odd_drive {
        (data.odd, data.even) = (data.pooled(Parity::Odd, r), data.pooled(Parity::Even, r));
    }
    Ok(data)
}
