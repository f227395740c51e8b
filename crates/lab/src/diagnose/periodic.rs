//! `diagnose` for periodic drives that are not a sine (a triangle, a square) and for
//! multisines: what the model gets wrong, seen at the lines of whole periods.
//!
//! 1. **Where.** Each record's steady window ([`crate::signal::steady`]); the records given together
//!    are realisations of one drive (same period, same excited lines, new phases).
//! 2. **The data** ([`crate::signal::distortion`]): the excited lines, the best linear approximation
//!    with its noise and distortion levels, and the output at the lines the drive does not
//!    excite: odd lines left out (odd distortion) and even lines (even distortion), each as
//!    a level in dB above the noise with the band where single lines stand out.
//! 3. **The models**, fitted on the first realisation (or the first half of the periods of
//!    the only one) and tested in free run on the others (or on the later periods): the linear
//!    model (no hysteresis), the hysteresis model with a symmetric loop (`A0 = 0`) and the
//!    extended model (its loop's asymmetric term free), which is the baseline. Their held-out
//!    residuals are measured at the same lines: what the hysteresis itself accounts for
//!    shows there.
//! 4. **Terms** beyond the extended model, each refined jointly with it
//!    ([`crate::fit::refine`]): a cubic stiffening of the structure (odd) and a quadratic
//!    one (even, an asymmetric stiffness). A term is kept when it lowers the held-out RMS by
//!    [`Thresholds::min_gain`] and either carries [`Thresholds::min_term_rel`] of the output's
//!    RMS or removes [`NOISE_MULTIPLE`] times the noise floor from the held-out residual
//!    (`√(before² − after²)`): a stiffening that the loop mostly imitates carries well under
//!    2 % of the output (0.8–1.6 % under the batch's triangles), yet what it leaves to the
//!    term is many times what the noise of held-out periods can account for; the one whose
//!    parity has the most evidence first, then the other on top.
//! 5. **Findings** ([`Kind::OddDistortion`], [`Kind::EvenDistortion`]): a kept term, with
//!    the data's level at the lines of its parity (or, for a triangle's odd lines, which
//!    are all excited, the level of what the term accounts for there) and the band; or
//!    distortion of a parity the extended model leaves in its held-out residual (at least
//!    [`crate::diagnose::UNEXPLAINED_SHARE`] of its power and `min_term_rel` of the output)
//!    with no term to remove it (`kept: false`). Distortion the extended model accounts for
//!    is not a finding: the summary says how much of it the hysteresis explains.
//!
//! With one realisation the held-out periods repeat the fitted ones but for the noise: the
//! held-out error then tests the fit against noise, not against new phases (the summary
//! says which it was).

use crate::diagnose::{self, DiagnoseError, Finding, Kind, ModelCheck, Thresholds, instability};
use crate::fit::refine;
use crate::fit::{self, DelaySearch, LoopSearch, OeOptions, Samples};
use crate::model::ModelSpec;
use crate::model::terms::{Param, Stiffening, TermModel};
use crate::signal::analysis;
use crate::signal::distortion::{self, BlaLine, Level, Line, Lines, Parity};
use crate::signal::steady::{self, Drive, DriveKind, Window};
use rayon::prelude::*;

/// One record of a periodic drive: its samples, its first sample's time and the window a
/// user gave (samples), if any.
#[derive(Clone, Copy, Debug)]
pub struct Realisation<'a> {
    /// Input (V).
    pub u: &'a [f64],
    /// Output (µm).
    pub y: &'a [f64],
    /// Time of the first sample (s).
    pub t0: f64,
    /// `--window` in samples.
    pub given: Option<(usize, usize)>,
}

/// What the held-out error was measured on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HeldOut {
    /// The other realisations (new phases): a test of the model.
    Realisations,
    /// The later periods of the only realisation: a test against noise.
    Periods,
}

/// One model fitted and tested, and its held-out residual at the lines.
#[derive(Clone, Debug)]
pub struct ModelStep {
    /// What it is ("linear", "hysteresis, symmetric loop", "extended", …).
    pub label: String,
    /// The model.
    pub model: TermModel,
    /// Held-out RMS (µm).
    pub rms_um: f64,
    /// Held-out fit and stability.
    pub check: ModelCheck,
    /// Its held-out residual at the odd lines the drive leaves out (or, for a triangle, at
    /// every odd line), pooled over the held-out sets.
    pub odd: Level,
    /// The same at the even lines.
    pub even: Level,
}

/// One term tried.
#[derive(Clone, Debug, PartialEq)]
pub struct TermTrial {
    /// Round (0: added to the extended model).
    pub round: usize,
    /// The parity it addresses.
    pub parity: Parity,
    /// Held-out RMS with it (µm).
    pub rms_um: f64,
    /// What it carries (µm): the held-out RMS of the change of the model's output when it is
    /// removed.
    pub term_rms_um: f64,
    /// Gain over the round's model (%).
    pub gain_pct: f64,
    /// Whether it was kept.
    pub kept: bool,
    /// Why a term that gained at least the threshold was not kept.
    pub reason: Option<String>,
}

/// The whole diagnosis of a periodic or multisine drive.
#[derive(Clone, Debug)]
pub struct PeriodicDiagnosis {
    /// Sample interval (s).
    pub ts: f64,
    /// The drive (of the first realisation).
    pub drive: Drive,
    /// Each realisation's window and first sample's time.
    pub windows: Vec<(Window, f64)>,
    /// Whole periods analysed per realisation.
    pub periods: Vec<usize>,
    /// What the held-out error was measured on.
    pub held_out: HeldOut,
    /// The lines of each realisation over its window.
    pub lines: Vec<Lines>,
    /// The best linear approximation.
    pub bla: Vec<BlaLine>,
    /// The data's level at the odd lines the drive leaves out (`None`: it leaves none, e.g. a
    /// triangle).
    pub odd: Option<Level>,
    /// The data's level at the even lines (`None`: the drive excites even lines).
    pub even: Option<Level>,
    /// Whether the drive excites odd lines only (else odd and even distortion cannot be told
    /// apart at the lines).
    pub odd_drive: bool,
    /// The linear model, the hysteresis model with a symmetric loop, the extended model, then
    /// the baseline with each kept term.
    pub steps: Vec<ModelStep>,
    /// Which of the first three is the baseline: the extended model, unless a simpler one
    /// does better on the held-out data (a loop fitted to one realisation that does not
    /// carry over to another).
    pub baseline_step: usize,
    /// Every term tried.
    pub trials: Vec<TermTrial>,
    /// What was found, most important first.
    pub findings: Vec<Finding>,
    /// The output's noise floor (µm, from period to period, at least the sensor's steps').
    pub noise_um: f64,
    /// How it was measured: `period_to_period`, or `quantisation` (the sensor's steps).
    pub noise_method: &'static str,
    /// RMS of the output over the held-out part, its mean removed (µm).
    pub output_rms_um: f64,
}

/// Longest fit criterion (s), at least two periods.
pub const MAX_FIT_S: f64 = 3.0;
/// Fewest whole periods per realisation when there are several.
pub const MIN_REALISATION_PERIODS: usize = 2;
/// Most lines analysed.
pub const MAX_LINES: u32 = 4000;
/// A term whose share of the output is under [`Thresholds::min_term_rel`] is still kept
/// when it removes this many times the noise floor's RMS from the held-out residual.
pub const NOISE_MULTIPLE: f64 = 3.0;

/// A realisation prepared: its samples from the step onto the drive, where the steady part
/// starts and ends in them, and its period.
struct Set {
    u: Vec<f64>,
    y: Vec<f64>,
    /// First steady sample (from `drive_on`).
    start: usize,
    /// End of the whole periods analysed (from `drive_on`).
    end: usize,
}

impl PeriodicDiagnosis {
    /// The baseline (see [`PeriodicDiagnosis::baseline_step`]).
    pub fn baseline(&self) -> &ModelStep {
        &self.steps[self.baseline_step]
    }

    /// The baseline with its kept terms.
    pub fn model(&self) -> &ModelStep {
        if self.steps.len() > 3 { &self.steps[self.steps.len() - 1] } else { self.baseline() }
    }

    /// `100·(1 − after/before)` of the held-out RMS from the baseline to the extended model.
    pub fn gain_pct(&self) -> f64 {
        let (b, m) = (self.baseline().rms_um, self.model().rms_um);
        if b > 0.0 { 100.0 * (1.0 - m / b) } else { 0.0 }
    }
}

fn window_error(e: steady::WindowError) -> DiagnoseError {
    DiagnoseError::Window(e)
}

/// Diagnoses one or more realisations of a periodic or multisine drive (see the module docs).
pub fn diagnose(
    records: &[Realisation<'_>],
    ts: f64,
    th: &Thresholds,
) -> Result<PeriodicDiagnosis, DiagnoseError> {
    let first = records.first().ok_or(DiagnoseError::Realisations("no record given".into()))?;
    let mut windows = vec![];
    let mut drives: Vec<Drive> = vec![];
    for r in records {
        let n = r.u.len().min(r.y.len());
        let (w, d) = steady::steady_window(&r.u[..n], &r.y[..n], ts, r.given).map_err(window_error)?;
        if d.kind == DriveKind::None {
            return Err(DiagnoseError::NoDrive { std_v: d.std_v });
        }
        steady::check_response(&r.u[w.start..w.end], &r.y[w.start..w.end], ts, &d)
            .map_err(DiagnoseError::NoResponse)?;
        if !matches!(d.kind, DriveKind::Periodic | DriveKind::Multisine) {
            return Err(DiagnoseError::NotPeriodic { drive: d.describe() });
        }
        windows.push((w, r.t0));
        drives.push(d);
    }
    let drive = drives[0].clone();
    let period = drive.period_samples.unwrap_or(0.0);
    for (i, d) in drives.iter().enumerate().skip(1) {
        let p = d.period_samples.unwrap_or(0.0);
        if (p - period).abs() > 1e-3 * period {
            return Err(DiagnoseError::Realisations(format!(
                "record {} repeats every {:.2} samples, the first every {period:.2}: they are not realisations of one \
                 drive",
                i + 1,
                p
            )));
        }
    }
    let min_periods = if records.len() >= 2 { MIN_REALISATION_PERIODS } else { diagnose::MIN_PERIODS };
    let mut sets = vec![];
    let mut periods = vec![];
    for (r, (w, t0)) in records.iter().zip(&windows) {
        let m = (((w.end - w.start) as f64 + 0.49) / period).floor() as usize;
        if m < min_periods {
            return Err(DiagnoseError::TooFewPeriods {
                drive_hz: drive.freq_hz,
                periods: m,
                window_s: w.seconds(*t0, ts),
            });
        }
        let end = w.start + (m as f64 * period).round() as usize;
        sets.push(Set {
            u: r.u[w.drive_on..end].to_vec(),
            y: r.y[w.drive_on..end].to_vec(),
            start: w.start - w.drive_on,
            end: end - w.drive_on,
        });
        periods.push(m);
    }
    let f0 = drive.freq_hz;
    let kmax = ((0.5 / ts / f0).floor() as u32).saturating_sub(1).clamp(1, MAX_LINES);
    let lines: Vec<Lines> = sets
        .iter()
        .map(|s| distortion::lines(&s.u[s.start..s.end], &s.y[s.start..s.end], period, ts, kmax))
        .collect::<Option<_>>()
        .ok_or(DiagnoseError::TooFewPeriods {
            drive_hz: f0,
            periods: 1,
            window_s: windows[0].0.seconds(first.t0, ts),
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
    let odd_drive = distortion::odd_drive(&lines[0]);
    let top = distortion::distortion_top(&lines[0], ts);
    let k_excited_top = excited.iter().copied().max().unwrap_or(1);
    // The lines of each parity the data can show distortion at.
    let parity_lines = |l: &Lines, p: Parity| -> Vec<Line> {
        match p {
            Parity::Odd => distortion::non_excited(l, Parity::Odd, k_excited_top),
            Parity::Even => distortion::non_excited(l, Parity::Even, top),
        }
    };
    let pooled = |sets: &[Lines], p: Parity| -> Option<Level> {
        let per: Vec<Vec<Line>> = sets.iter().map(|l| parity_lines(l, p)).collect();
        let refs: Vec<&[Line]> = per.iter().map(|v| v.as_slice()).collect();
        let lv = distortion::level(&refs);
        (lv.lines >= distortion::MIN_LINES).then_some(lv)
    };
    let (odd, even) =
        if odd_drive { (pooled(&lines, Parity::Odd), pooled(&lines, Parity::Even)) } else { (None, None) };
    let bla = distortion::bla(&lines);

    // Fitted and held-out parts.
    let held_out = if sets.len() >= 2 { HeldOut::Realisations } else { HeldOut::Periods };
    let (fit_end, held): (usize, Vec<(usize, usize, usize)>) = match held_out {
        HeldOut::Realisations => {
            (sets[0].end, (1..sets.len()).map(|i| (i, sets[i].start, sets[i].end)).collect())
        }
        HeldOut::Periods => {
            let s = &sets[0];
            let p_fit = periods[0].div_ceil(2);
            let split = s.start + (p_fit as f64 * period).round() as usize;
            (split, vec![(0, split, s.end)])
        }
    };
    let s0 = &sets[0];
    let skip = s0.start.max(OeOptions::default().skip.min(fit_end.saturating_sub(diagnose::FIT_MIN_SAMPLES)));
    let window = ((MAX_FIT_S / ts) as usize).max((2.0 * period).round() as usize);
    // A broadband drive pins the structure's phase over a band: the input delay is fitted
    // with it (a sampled actuator answers about a sample late, which one resonance cannot
    // absorb over a band).
    let opt = OeOptions {
        lm_starts: diagnose::TERM_STARTS,
        require_invertible: false,
        skip,
        samples: Samples::First(fit_end.min(skip + window)),
        delay: DelaySearch::Fit,
        ..OeOptions::default()
    };
    let spec = ModelSpec { drift_degree: Some(0), ..ModelSpec::extended(f0) };
    let (u0, y0) = (&s0.u[..], &s0.y[..]);
    let output_rms_um = {
        let ys: Vec<f64> = held.iter().flat_map(|&(i, a, b)| sets[i].y[a..b].iter().copied()).collect();
        let m = analysis::mean(&ys);
        (ys.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / ys.len().max(1) as f64).sqrt()
    };
    let (noise_um, noise_method) = {
        let per: Vec<(f64, &'static str)> =
            sets.iter().map(|s| steady::noise_floor(&s.y[s.start..s.end], ts, &drive)).collect();
        let how = if per.iter().any(|p| p.1 == "quantisation") { "quantisation" } else { "period_to_period" };
        ((per.iter().map(|v| v.0 * v.0).sum::<f64>() / per.len() as f64).sqrt(), how)
    };
    // A model's held-out residual: RMS, check, levels at the lines.
    let evaluate = |label: &str, m: TermModel| -> Result<ModelStep, DiagnoseError> {
        let mut all_r = vec![];
        let mut all_y = vec![];
        let mut sims = vec![];
        let mut res_lines = vec![];
        for &(i, a, b) in &held {
            let s = &sets[i];
            let sim = m.simulate(&s.u[..b], ts)?;
            let r: Vec<f64> = s.y[a..b].iter().zip(&sim[a..b]).map(|(y, p)| y - p).collect();
            if let Some(l) = distortion::lines(&s.u[a..b], &r, period, ts, kmax) {
                res_lines.push(l);
            }
            all_r.extend_from_slice(&r);
            all_y.extend_from_slice(&s.y[a..b]);
            sims.extend_from_slice(&sim[a..b]);
        }
        let rms_um = analysis::rms(&all_r);
        let check = ModelCheck::of(&m.host, &sims, &all_y, ts);
        let lv = |p: Parity| -> Level {
            let per: Vec<Vec<Line>> = res_lines
                .iter()
                .map(|l| match (p, odd_drive) {
                    (Parity::Odd, true) if odd.is_some() => parity_lines(l, p),
                    (Parity::Even, true) => parity_lines(l, p),
                    // A triangle's odd lines are all excited: its distortion falls on them.
                    (p, _) => l.lines.iter().filter(|x| p.has(x.k) && x.k <= top).copied().collect(),
                })
                .collect();
            let refs: Vec<&[Line]> = per.iter().map(|v| v.as_slice()).collect();
            distortion::level(&refs)
        };
        Ok(ModelStep {
            label: label.into(),
            rms_um,
            check,
            odd: lv(Parity::Odd),
            even: lv(Parity::Even),
            model: m,
        })
    };

    // The linear model, the extended model (baseline), the symmetric loop between them.
    let linear = fit::fit_oe(
        u0,
        y0,
        ts,
        fit_end,
        &spec,
        &[],
        &OeOptions { hysteresis: LoopSearch::Linear, ..opt.clone() },
    )?
    .model;
    let extended = fit::fit_oe(u0, y0, ts, fit_end, &spec, &[], &opt)?.model;
    let crit = crate::diagnose::causes::criterion(&opt, fit_end, ts, crate::diagnose::causes::REFINE_ITER);
    let mut symmetric = TermModel::from(extended.clone());
    symmetric.host.ext.bw.a0 = 0.0;
    let free: Vec<Param> = symmetric.host_params().into_iter().filter(|p| *p != Param::A0).collect();
    let symmetric = refine(&symmetric, &free, u0, y0, ts, &crit).map_or(symmetric, |r| r.0);
    let mut steps = vec![
        evaluate("linear", TermModel::from(linear))?,
        evaluate("hysteresis, symmetric loop", symmetric)?,
        evaluate("extended (hysteresis with its asymmetric term)", TermModel::from(extended))?,
    ];
    // The baseline: the extended model, or a simpler one that does better held out.
    let score = |s: &ModelStep| if usable(s) { s.rms_um } else { f64::INFINITY };
    let baseline_step = if score(&steps[2]) <= score(&steps[1]).min(score(&steps[0])) {
        2
    } else if score(&steps[1]) <= score(&steps[0]) {
        1
    } else {
        0
    };
    if !score(&steps[baseline_step]).is_finite() {
        return Err(DiagnoseError::Fit(fit::FitError::NoStableModel));
    }

    // Terms on top of the baseline. A parity's evidence: the data's level at its free lines,
    // or where the drive leaves none (a triangle's odd lines), the baseline's held-out
    // residual's level at its lines.
    let (base_odd, base_even) = (steps[baseline_step].odd.db, steps[baseline_step].even.db);
    let evidence = |p: Parity| -> f64 {
        match (p, odd, even) {
            (Parity::Odd, Some(l), _) | (Parity::Even, _, Some(l)) => l.db,
            (Parity::Odd, None, _) => base_odd,
            (Parity::Even, _, None) => base_even,
        }
    };
    let out_rms = output_rms_um;
    let mut trials: Vec<TermTrial> = vec![];
    let mut kept: Vec<Parity> = vec![];
    let mut remaining = vec![Parity::Odd, Parity::Even];
    for round in 0.. {
        let current =
            if steps.len() > 3 { steps[steps.len() - 1].clone() } else { steps[baseline_step].clone() };
        let tried: Vec<(Parity, TermModel, f64, f64)> = remaining
            .par_iter()
            .filter_map(|&p| {
                let m = with_stiffening(&current.model, p, u0, ts)?;
                let mut free = m.host_params();
                free.push(Param::Stiffening(m.terms.stiffening.len() - 1));
                let (m, _) = refine(&m, &free, u0, y0, ts, &crit)?;
                let mut rms = 0.0;
                let mut count = 0usize;
                let mut change = 0.0;
                let without = current.model.clone();
                for &(i, a, b) in &held {
                    let s = &sets[i];
                    let sim = m.simulate(&s.u[..b], ts).ok()?;
                    if instability(m.host.ext.ar, &sim[a..b], ts).is_some() {
                        return None;
                    }
                    let base = without.simulate(&s.u[..b], ts).ok()?;
                    rms += sim[a..b].iter().zip(&s.y[a..b]).map(|(p, y)| (y - p) * (y - p)).sum::<f64>();
                    change += sim[a..b].iter().zip(&base[a..b]).map(|(p, q)| (p - q) * (p - q)).sum::<f64>();
                    count += b - a;
                }
                let rms = (rms / count.max(1) as f64).sqrt();
                let change = (change / count.max(1) as f64).sqrt();
                (rms.is_finite() && change.is_finite()).then_some((p, m, rms, change))
            })
            .collect();
        let before = current.rms_um;
        let first = trials.len();
        for (p, _, rms, term) in &tried {
            trials.push(TermTrial {
                round,
                parity: *p,
                rms_um: *rms,
                term_rms_um: *term,
                gain_pct: 100.0 * (1.0 - rms / before.max(1e-300)),
                kept: false,
                reason: None,
            });
        }
        let gains = |t: &(Parity, TermModel, f64, f64)| t.2 <= before * (1.0 - th.min_gain);
        let need = th.min_term_rel * out_rms;
        // What a term removes from the held-out residual (µm, RMS): the noise of held-out
        // periods cannot remove NOISE_MULTIPLE times its own RMS.
        let removed = |t: &(Parity, TermModel, f64, f64)| (before * before - t.2 * t.2).max(0.0).sqrt();
        let carries =
            |t: &(Parity, TermModel, f64, f64)| t.3 >= need || removed(t) >= NOISE_MULTIPLE * noise_um;
        // Of the terms that would be kept, the one whose parity has the most evidence.
        let winner = tried
            .iter()
            .enumerate()
            .filter(|(_, t)| gains(t) && carries(t))
            .max_by(|a, b| evidence(a.1.0).total_cmp(&evidence(b.1.0)))
            .map(|(i, _)| i);
        for (i, t) in tried.iter().enumerate() {
            if !gains(t) || Some(i) == winner {
                continue;
            }
            trials[first + i].reason = Some(if !carries(t) {
                format!(
                    "its term carries only {:.4} µm in the model, less than the {need:.4} µm a term must carry ({:.0} % \
                     of the output's RMS), and removes {:.4} µm from the held-out residual, less than {NOISE_MULTIPLE} \
                     times its noise ({:.4} µm)",
                    t.3,
                    100.0 * th.min_term_rel,
                    removed(t),
                    noise_um
                )
            } else {
                let w = winner.map_or(i, |w| w);
                format!(
                    "the {} stands for more evidence ({:.1} dB against {:.1} dB) and was kept in round {round}",
                    term_name(tried[w].0),
                    evidence(tried[w].0),
                    evidence(t.0)
                )
            });
        }
        let Some(w) = winner else { break };
        trials[first + w].kept = true;
        let Some((p, m, ..)) = tried.into_iter().nth(w) else { break };
        steps.push(evaluate(&format!("extended + {}", term_name(p)), m)?);
        kept.push(p);
        remaining.retain(|q| *q != p);
        if remaining.is_empty() {
            break;
        }
    }

    // Findings.
    let baseline = &steps[baseline_step];
    let mut findings = vec![];
    let residual_power = (baseline.rms_um * baseline.rms_um).max(1e-300);
    for (n, &p) in kept.iter().enumerate() {
        let before = if n == 0 { baseline } else { &steps[2 + n] };
        let after = &steps[3 + n];
        let data = match p {
            Parity::Odd => odd,
            Parity::Even => even,
        };
        // The level: the data's at the lines the drive leaves free, else what the term
        // accounts for at the lines of its parity (a triangle's odd lines).
        let contribution = term_level(&after.model, &before.model, &sets, &held, period, ts, kmax, p, top);
        let (level, band) = match data {
            Some(l) => (l.db, l.band_hz),
            None => (contribution.db, contribution.band_hz),
        };
        let trial = trials.iter().find(|t| t.kept && t.parity == p).cloned();
        let cause = explain(p, data.as_ref(), &contribution, before, after, baseline, odd_drive, &drive);
        findings.push(Finding {
            kind: kind_of(p),
            order: None,
            freq_hz: band.map_or(0.0, |b| 0.5 * (b[0] + b[1])),
            residual_share: ((before.rms_um.powi(2) - after.rms_um.powi(2)) / residual_power).clamp(0.0, 1.0),
            amplitude_um: contribution.rms_um,
            output_rel: contribution.rms_um / out_rms.max(1e-300),
            cause,
            kept: true,
            rms_with_term_um: after.rms_um,
            term_rms_um: trial.map_or(f64::NAN, |t| t.term_rms_um),
            level: Some((level, "dB above noise")),
            band_hz: band,
            drive_within_range_v: None,
        });
    }
    // Distortion the model (with its terms) still leaves and no term removed: its share of
    // the held-out residual's power at the distortion lines of both parities.
    let last = if steps.len() > 3 { &steps[steps.len() - 1] } else { baseline };
    let lines_power = (last.odd.rms_um.powi(2) + last.even.rms_um.powi(2)).max(1e-300);
    for p in [Parity::Odd, Parity::Even] {
        if kept.contains(&p) {
            continue;
        }
        let lv = match p {
            Parity::Odd => last.odd,
            Parity::Even => last.even,
        };
        let share = lv.rms_um * lv.rms_um / lines_power;
        if lv.detected() && share >= diagnose::UNEXPLAINED_SHARE && lv.rms_um >= th.min_term_rel * out_rms {
            findings.push(Finding {
                kind: kind_of(p),
                order: None,
                freq_hz: lv.band_hz.map_or(0.0, |b| 0.5 * (b[0] + b[1])),
                residual_share: share,
                amplitude_um: lv.rms_um,
                output_rel: lv.rms_um / out_rms.max(1e-300),
                cause: format!(
                    "unexplained {} distortion: the model's held-out residual holds {:.3} µm at the {} lines ({:.0} % \
                     of its power at the {}, {:.1} dB above their noise{}); no term removed it by enough to keep",
                    p.as_str(),
                    lv.rms_um,
                    p.as_str(),
                    100.0 * share,
                    if p == Parity::Odd && odd_drive {
                        // A triangle's or a square's own harmonics: the model's response to
                        // them is what is off, not distortion the record shows by itself.
                        "odd and even lines; the odd ones are the drive's own harmonics, so this is what the model \
                         gets wrong of its response to them"
                    } else {
                        "lines the drive leaves free"
                    },
                    lv.db,
                    lv.band_hz.map_or(String::new(), |b| format!(", {:.1} to {:.1} Hz", b[0], b[1]))
                ),
                kept: false,
                rms_with_term_um: f64::NAN,
                term_rms_um: lv.rms_um,
                level: Some((lv.db, "dB above noise")),
                band_hz: lv.band_hz,
                drive_within_range_v: None,
            });
        }
    }
    // Unexplained distortion after the kept terms, the parity with more evidence first.
    let n_kept = kept.len();
    findings[n_kept..].sort_by(|a, b| {
        let e =
            |f: &Finding| evidence(if f.kind == Kind::OddDistortion { Parity::Odd } else { Parity::Even });
        e(b).total_cmp(&e(a))
    });
    Ok(PeriodicDiagnosis {
        ts,
        drive,
        windows,
        periods,
        held_out,
        lines,
        bla,
        odd,
        even,
        odd_drive,
        steps,
        baseline_step,
        trials,
        findings,
        noise_um,
        noise_method,
        output_rms_um,
    })
}

/// Whether a model step's held-out error can be compared: its free run is stable and finite.
fn usable(st: &ModelStep) -> bool {
    st.check.unstable.is_none() && st.rms_um.is_finite()
}

fn kind_of(p: Parity) -> Kind {
    match p {
        Parity::Odd => Kind::OddDistortion,
        Parity::Even => Kind::EvenDistortion,
    }
}

/// "cubic stiffening", "quadratic (asymmetric) stiffness".
pub fn term_name(p: Parity) -> &'static str {
    match p {
        Parity::Odd => "cubic stiffening",
        Parity::Even => "quadratic (asymmetric) stiffness",
    }
}

/// `model` with a stiffening power of `p`'s parity added at 0 (cubic for odd, quadratic for
/// even), its reference deflection the largest excursion of the model's output from its mean
/// over `u`. `None` if the model already has that power.
fn with_stiffening(model: &TermModel, p: Parity, u: &[f64], ts: f64) -> Option<TermModel> {
    let power = match p {
        Parity::Odd => 3,
        Parity::Even => 2,
    };
    if model.terms.stiffening.iter().any(|s| s.power == power) {
        return None;
    }
    let mut m = model.clone();
    if m.terms.q_ref_um <= 0.0 {
        let sim = model.host.simulate(u, ts).ok()?;
        let mean = analysis::mean(&sim);
        m.terms.q_ref_um = sim.iter().fold(0.0f64, |a, v| a.max((v - mean).abs())).max(1e-6);
    }
    m.terms.stiffening.push(Stiffening { power, coeff: 0.0 });
    Some(m)
}

/// The level (dB above the output's noise) of what `with` adds to `without` at the lines of
/// parity `p` up to line `top`, over the held-out sets.
#[allow(clippy::too_many_arguments)]
fn term_level(
    with: &TermModel,
    without: &TermModel,
    sets: &[Set],
    held: &[(usize, usize, usize)],
    period: f64,
    ts: f64,
    kmax: u32,
    p: Parity,
    top: u32,
) -> Level {
    let mut per: Vec<Vec<Line>> = vec![];
    for &(i, a, b) in held {
        let s = &sets[i];
        let (Ok(x), Ok(z)) = (with.simulate(&s.u[..b], ts), without.simulate(&s.u[..b], ts)) else {
            continue;
        };
        let d: Vec<f64> = x[a..b].iter().zip(&z[a..b]).map(|(x, z)| x - z).collect();
        // The difference's lines, with the noise of the output's lines.
        let (Some(dl), Some(yl)) = (
            distortion::lines(&s.u[a..b], &d, period, ts, kmax),
            distortion::lines(&s.u[a..b], &s.y[a..b], period, ts, kmax),
        ) else {
            continue;
        };
        per.push(
            dl.lines
                .iter()
                .zip(&yl.lines)
                .filter(|(l, _)| p.has(l.k) && l.k <= top)
                .map(|(l, y)| Line { noise_var: y.noise_var, ..*l })
                .collect(),
        );
    }
    let refs: Vec<&[Line]> = per.iter().map(|v| v.as_slice()).collect();
    distortion::level(&refs)
}

fn band_text(b: Option<[f64; 2]>) -> String {
    b.map_or(String::new(), |b| format!(" from {:.1} to {:.1} Hz", b[0], b[1]))
}

/// The cause of a kept term in words.
#[allow(clippy::too_many_arguments)]
fn explain(
    p: Parity,
    data: Option<&Level>,
    contribution: &Level,
    before: &ModelStep,
    after: &ModelStep,
    baseline: &ModelStep,
    odd_drive: bool,
    drive: &Drive,
) -> String {
    let gain = 100.0 * (1.0 - after.rms_um / before.rms_um.max(1e-300));
    let lv = |s: &ModelStep| match p {
        Parity::Odd => s.odd,
        Parity::Even => s.even,
    };
    let (what, lines) = match p {
        Parity::Odd => (
            "odd",
            if drive.kind == DriveKind::Multisine { "odd lines the drive leaves out" } else { "odd lines" },
        ),
        Parity::Even => ("even", "even lines"),
    };
    let evidence = match data {
        Some(d) => format!(
            "the output's {lines} stand {:.1} dB above their noise{} ({:.3} µm)",
            d.db,
            band_text(d.band_hz),
            d.rms_um
        ),
        None => format!(
            "the drive excites every odd line (a {} drive's own harmonics), so odd distortion falls on excited lines and \
             shows only against a model: the term accounts for {:.3} µm there, {:.1} dB above their noise{}",
            drive.kind.as_str(),
            contribution.rms_um,
            contribution.db,
            band_text(contribution.band_hz)
        ),
    };
    let s = after.model.terms.stiffening.last().copied();
    let term = match (p, s) {
        (Parity::Odd, Some(s)) => format!(
            "a cubic stiffening of the structure ({} by {:.1} % of the linear stiffness at {:.2} µm)",
            if s.coeff >= 0.0 { "hardening" } else { "softening" },
            100.0 * s.coeff.abs(),
            after.model.terms.q_ref_um
        ),
        (Parity::Even, Some(s)) => format!(
            "a quadratic stiffness ({:.1} % of the linear stiffness at {:.2} µm, {} on the positive side)",
            100.0 * s.coeff.abs(),
            after.model.terms.q_ref_um,
            if s.coeff >= 0.0 { "stiffer" } else { "softer" }
        ),
        _ => term_name(p).to_string(),
    };
    let meaning = match p {
        Parity::Odd => {
            "a symmetric stiffening of the actuator or its mechanism that the hysteresis loop does not hold"
        }
        Parity::Even => {
            "an asymmetry beyond the loop's own (an asymmetric stiffness: layers or a clamp that differ, an off-centre \
             operating point)"
        }
    };
    let _ = odd_drive;
    format!(
        "{what} nonlinear distortion: {evidence}; the baseline ({}) leaves {:.1} dB there in its held-out residual \
         ({:.3} µm); {term} lowers the held-out RMS from {:.4} to {:.4} µm ({gain:.0}%) and leaves {:.1} dB: \
         {meaning}",
        baseline.label,
        lv(baseline).db,
        lv(baseline).rms_um,
        before.rms_um,
        after.rms_um,
        lv(after).db
    )
}

fn level_json(l: &Level) -> serde_json::Value {
    serde_json::json!({
        "level_db": l.db,
        "lines": l.lines,
        "rms_um": l.rms_um,
        "band_hz": l.band_hz,
    })
}

impl PeriodicDiagnosis {
    /// The JSON object of `boucwen diagnose --json` for a periodic or multisine drive:
    /// `drive`, `realisations`, `windows_s`, `periods`, `held_out` (`realisations` or
    /// `periods`), `noise_um`, `output_rms_um`, `lines {odd, even}` (the data's levels,
    /// `null` where the drive leaves no such lines), `bla [{freq_hz, gain_um_per_v,
    /// phase_deg, noise_db, distortion_db}]` (relative to `|G|`), `models [{label, model,
    /// rms_um, fit_pct, stable, odd_db, even_db}]` (linear, symmetric loop, extended, then
    /// with each kept term), `baseline`, `findings` (as for a sine), `extended`, `gain_pct`
    /// and `trials [{round, term, parity, rms_um, term_rms_um, gain_pct, kept, reason}]`.
    pub fn json(&self) -> serde_json::Value {
        use serde_json::json;
        let model = |s: &ModelStep| {
            json!({
                "label": s.label,
                "model": s.model.name(),
                "rms_um": if s.check.unstable.is_none() { json!(s.rms_um) } else { json!(null) },
                "fit_pct": s.check.fit_pct,
                "stable": s.check.unstable.is_none(),
                "odd_db": s.odd.db,
                "even_db": s.even.db,
            })
        };
        let db = |x: f64, g: f64| 10.0 * (x / (g * g).max(1e-300)).max(1e-30).log10();
        json!({
            "drive": {
                "kind": self.drive.kind.as_str(),
                "period_s": 1.0 / self.drive.freq_hz,
                "line_spacing_hz": self.drive.freq_hz,
                "excited_lines": self.lines[0].lines.iter().filter(|l| l.excited).count(),
                "odd_lines_only": self.odd_drive,
            },
            "realisations": self.windows.len(),
            "windows_s": self.windows.iter().map(|(w, t0)| w.seconds(*t0, self.ts)).collect::<Vec<_>>(),
            "periods": self.periods,
            "held_out": match self.held_out { HeldOut::Realisations => "realisations", HeldOut::Periods => "periods" },
            "noise_um": self.noise_um,
            "noise_method": self.noise_method,
            "output_rms_um": self.output_rms_um,
            "lines": {
                "odd": self.odd.as_ref().map(level_json),
                "even": self.even.as_ref().map(level_json),
            },
            "bla": self.bla.iter().map(|b| json!({
                "freq_hz": b.freq_hz,
                "gain_um_per_v": b.g.norm(),
                "phase_deg": b.g.arg().to_degrees(),
                "noise_db": db(b.noise_var, b.g.norm()),
                "distortion_db": db(b.distortion_var, b.g.norm()),
            })).collect::<Vec<_>>(),
            "models": self.steps.iter().map(model).collect::<Vec<_>>(),
            "baseline": model(self.baseline()),
            "findings": self.findings.iter().map(diagnose::finding_json).collect::<Vec<_>>(),
            "extended": model(self.model()),
            "gain_pct": self.gain_pct(),
            "trials": self.trials.iter().map(|t| json!({
                "round": t.round,
                "term": term_name(t.parity),
                "parity": t.parity.as_str(),
                "rms_um": t.rms_um,
                "term_rms_um": t.term_rms_um,
                "gain_pct": t.gain_pct,
                "kept": t.kept,
                "reason": t.reason,
            })).collect::<Vec<_>>(),
        })
    }

    /// The terminal report: the drive and the windows, the data's distortion, the BLA, the
    /// models and what each leaves, the findings and the gain.
    pub fn summary(&self, source: &str) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(s, "{source}: drive {}, sampled every {} s", self.drive.describe(), self.ts);
        for (i, ((w, t0), m)) in self.windows.iter().zip(&self.periods).enumerate() {
            let [a, b] = w.seconds(*t0, self.ts);
            let which =
                if self.windows.len() > 1 { format!("realisation {}: ", i + 1) } else { String::new() };
            let _ = writeln!(s, "{which}window {a:.3} to {b:.3} s, {m} whole periods: {}", w.why);
        }
        let _ = writeln!(
            s,
            "models fitted on {}, tested in free run on {}",
            if self.held_out == HeldOut::Realisations {
                "the first realisation"
            } else {
                "the first half of the periods"
            },
            if self.held_out == HeldOut::Realisations {
                "the other realisations (new phases)"
            } else {
                "the later periods (the same phases: this tests the fit against noise, not against a new realisation)"
            }
        );
        let _ = writeln!(
            s,
            "output {:.3} µm RMS, noise floor {:.4} µm ({})",
            self.output_rms_um,
            self.noise_um,
            if self.noise_method == "quantisation" {
                "the sensor's resolution: its steps' RMS error"
            } else {
                "from period to period"
            }
        );
        let lv = |l: &Option<Level>, what: &str| match l {
            Some(l) => format!(
                "{what}: {:.1} dB above the noise over {} lines ({:.4} µm){}{}",
                l.db,
                l.lines,
                l.rms_um,
                band_text(l.band_hz),
                if l.detected() { "" } else { ": noise" }
            ),
            None => format!("{what}: none free of the drive"),
        };
        if self.odd_drive {
            let _ = writeln!(s, "\nthe output at the lines the drive does not excite:");
            let _ = writeln!(s, "  {}", lv(&self.odd, "odd lines left out (odd distortion)"));
            let _ = writeln!(s, "  {}", lv(&self.even, "even lines (even distortion)"));
        } else {
            let _ = writeln!(
                s,
                "\nthe drive excites odd and even lines: odd and even distortion cannot be told apart at the lines"
            );
        }
        if !self.bla.is_empty() {
            let rel = |v: f64, g: f64| 10.0 * (v / (g * g).max(1e-300)).max(1e-30).log10();
            let med = |mut v: Vec<f64>| {
                v.sort_by(f64::total_cmp);
                v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
            };
            let noise = med(self.bla.iter().map(|b| rel(b.noise_var, b.g.norm())).collect());
            let dist = med(self.bla.iter().map(|b| rel(b.distortion_var, b.g.norm())).collect());
            let (lo, hi) = (self.bla[0].freq_hz, self.bla[self.bla.len() - 1].freq_hz);
            let _ = writeln!(
                s,
                "best linear approximation over {} excited lines ({lo:.2} to {hi:.2} Hz, |G| {:.2} to {:.2} µm/V): \
                 noise {noise:.1} dB, nonlinear distortion {dist:.1} dB relative to |G| (median; distortion from {})",
                self.bla.len(),
                self.bla.iter().map(|b| b.g.norm()).fold(f64::INFINITY, f64::min),
                self.bla.iter().map(|b| b.g.norm()).fold(0.0, f64::max),
                if self.windows.len() > 1 {
                    "the spread over realisations"
                } else {
                    "the non-excited lines nearby"
                }
            );
        }
        let _ = writeln!(
            s,
            "\nmodels (held-out RMS; held-out residual at the odd and even lines, dB above the noise):"
        );
        for st in &self.steps {
            let fit = match (&st.check.unstable, st.check.fit_pct) {
                (Some(why), _) => format!("not stable: {why}"),
                (None, Some(f)) => format!("fit {f:.1} %"),
                (None, None) => "fit not measured".into(),
            };
            let label = format!("{} ({})", st.label, st.model.name());
            let _ = if usable(st) {
                writeln!(
                    s,
                    "  {label:<48} {:.4} µm, {fit}; odd {:.1} dB, even {:.1} dB",
                    st.rms_um, st.odd.db, st.even.db
                )
            } else {
                writeln!(s, "  {label:<48} {fit}")
            };
        }
        let (lin, sym, ext) = (&self.steps[0], &self.steps[1], &self.steps[2]);
        let pct = |a: f64, b: f64| 100.0 * (1.0 - b / a.max(1e-300));
        let _ = match (usable(lin), usable(sym), usable(ext)) {
            (true, true, true) => writeln!(
                s,
                "the hysteresis loop lowers the linear model's held-out RMS by {:.0} % (odd lines {:.1} -> {:.1} dB), \
                 its asymmetric term by {:.0} % more (even lines {:.1} -> {:.1} dB)",
                pct(lin.rms_um, sym.rms_um),
                lin.odd.db,
                sym.odd.db,
                pct(sym.rms_um, ext.rms_um),
                sym.even.db,
                ext.even.db
            ),
            (true, false, true) => writeln!(
                s,
                "the symmetric loop's free run is not stable; the extended model lowers the linear model's held-out \
                 RMS by {:.0} % (odd lines {:.1} -> {:.1} dB, even lines {:.1} -> {:.1} dB)",
                pct(lin.rms_um, ext.rms_um),
                lin.odd.db,
                ext.odd.db,
                lin.even.db,
                ext.even.db
            ),
            _ => writeln!(
                s,
                "not every one of these models runs stably on the held-out data: they are not compared"
            ),
        };
        let base = self.baseline();
        if self.findings.is_empty() && base.rms_um > NOISE_MULTIPLE * self.noise_um {
            let _ = writeln!(
                s,
                "\nfindings: none that can be named; the {} model leaves {:.4} µm held out, {:.0} times the noise \
                 floor, and no term tried (a cubic stiffening, a quadratic stiffness) lowered it by enough to keep: \
                 what it misses is not one of these",
                base.label,
                base.rms_um,
                base.rms_um / self.noise_um.max(1e-300)
            );
        } else if self.findings.is_empty() {
            let _ = writeln!(
                s,
                "\nfindings: none; the extended model accounts for the distortion the record shows (no term lowered \
                 its held-out RMS by enough to keep)"
            );
        } else {
            let _ = writeln!(s, "\nfindings (most important first):");
            for (i, f) in self.findings.iter().enumerate() {
                let _ = writeln!(s, "  {}. {}", i + 1, f.cause);
            }
        }
        let not_kept: Vec<&TermTrial> = self.trials.iter().filter(|t| t.reason.is_some()).collect();
        if !not_kept.is_empty() {
            let _ = writeln!(s, "\nterms that lowered the held-out RMS by enough but were not kept:");
            for t in not_kept {
                let _ = writeln!(
                    s,
                    "  - {} (round {}): {:.0}% lower, to {:.4} µm; {}",
                    term_name(t.parity),
                    t.round,
                    t.gain_pct,
                    t.rms_um,
                    t.reason.as_deref().unwrap_or("")
                );
            }
        }
        let (b, m) = (self.baseline(), self.model());
        let _ = writeln!(
            s,
            "\nextended model: {} (free run): held-out RMS {:.4} µm; {:.4} µm before: {:.1}% lower",
            m.model.name(),
            m.rms_um,
            b.rms_um,
            self.gain_pct()
        );
        s
    }
}
