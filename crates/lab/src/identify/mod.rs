//! `identify`: a model fitted on the first part of a record's steady window, its free-run
//! error and fit on the rest, and whether it is stable. Any drive: sine, periodic,
//! multisine, aperiodic.
//!
//! The window is found as for the diagnosis ([`crate::signal::steady::steady_window`]); the
//! model runs from the start of the steady drive, and `fit_fraction` of the window (whole
//! periods of a periodic drive) is fitted, the rest held out. The output-error fit
//! ([`crate::fit::fit_oe`]) averages the periods of a periodic drive in steady state (the
//! model has no drift term); the paper's RLS procedure ([`crate::fit::fit_paper_rls`]) runs
//! over the fitted samples.

use crate::diagnose::checks::{self, ModelCheck};
use crate::diagnose::error::DiagnoseError;
use crate::diagnose::plan::fit_options;
use crate::fit::{self, Averaging, Fit, OeOptions};
use crate::model::{HostModel, ModelSpec};
use crate::record::Record;
use crate::rules::Rules;
use crate::signal::analysis;
use crate::signal::steady::{self, Drive, DriveKind, Window};
use std::fmt;

pub mod compare;
pub mod families;

/// The model to fit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Structure {
    /// Bouc–Wen hysteresis, asymmetric term and structure (eq. 3 in the AR form of eq. 9).
    Extended,
    /// The extended model plus harmonic branches of the drive (eqs. 6/7).
    Enhanced,
}

/// The identification method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Output-error fit: minimises the free-run error.
    Oe,
    /// The paper's RLS identification (running-sum regressors, section 3).
    Rls,
}

impl Method {
    /// "output error", "paper RLS".
    pub fn name(self) -> &'static str {
        match self {
            Method::Oe => "output error",
            Method::Rls => "paper RLS",
        }
    }
}

/// What to identify and how.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// The model.
    pub structure: Structure,
    /// The enhanced model's branches (empty: the odd harmonic that stands out).
    pub harmonics: Vec<u32>,
    /// The method.
    pub method: Method,
    /// Share of the steady window fitted (0.1 to 0.9).
    pub fit_fraction: f64,
    /// The drive frequency of the branches (Hz; found in `u` if `None`).
    pub drive_hz: Option<f64>,
    /// Accept only a loop the direct inverse (eqs. 16/17) can invert.
    pub invertible: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            structure: Structure::Extended,
            harmonics: vec![],
            method: Method::Oe,
            fit_fraction: 0.5,
            drive_hz: None,
            invertible: false,
        }
    }
}

/// Why a record could not be identified.
#[derive(Debug)]
pub enum IdentifyError {
    /// An option out of range (named, with what it must be).
    Option(String),
    /// The record's window, drive or response (see [`DiagnoseError`]).
    Record(DiagnoseError),
    /// The branches need a drive frequency the drive does not have.
    NoDriveFrequency {
        /// The drive, described.
        drive: String,
    },
    /// Too few samples in the steady window.
    TooFewSamples {
        /// Samples in the window.
        samples: usize,
        /// Samples needed (`sine.min_samples`).
        need: usize,
        /// The window (s).
        window_s: [f64; 2],
    },
}

impl fmt::Display for IdentifyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            IdentifyError::Option(why) => f.write_str(why),
            IdentifyError::Record(e) => write!(f, "{e}"),
            IdentifyError::NoDriveFrequency { drive } => write!(
                f,
                "the drive is {drive}; the enhanced model's branches need a drive frequency (give --drive-hz)"
            ),
            IdentifyError::TooFewSamples { samples, need, window_s } => write!(
                f,
                "the steady window {:.3}–{:.3} s holds {samples} samples; identify needs at least {need}",
                window_s[0], window_s[1]
            ),
        }
    }
}

impl std::error::Error for IdentifyError {}

impl<E: Into<DiagnoseError>> From<E> for IdentifyError {
    fn from(e: E) -> Self {
        IdentifyError::Record(e.into())
    }
}

/// What identify measured.
#[derive(Clone, Debug)]
pub struct Identified {
    /// The model.
    pub model: HostModel,
    /// How it was fitted.
    pub method: Method,
    /// The output-error fit's run and its wall time (s); `None` for the RLS.
    pub fit: Option<(Fit, f64)>,
    /// The drive in the window.
    pub drive: Drive,
    /// The branches' drive frequency (Hz).
    pub drive_hz: f64,
    /// The window (s) and why it is there.
    pub window_s: [f64; 2],
    /// Why the window is where it is.
    pub why: String,
    /// Samples fitted and held out.
    pub samples: (usize, usize),
    /// Free-run RMS on the fitted part after the start-up (µm); `None` if the fitted part's
    /// free run is not stable.
    pub fit_rms_um: Option<f64>,
    /// Free-run RMS held out (µm).
    pub held_rms_um: f64,
    /// The held-out check.
    pub check: ModelCheck,
    /// The output's noise floor held out (µm) and how it was measured.
    pub noise_um: (f64, &'static str),
    /// The sample interval (s).
    pub ts: f64,
}

/// The odd harmonic (3..=`sine.max_term_order`) that stands out in `y`, else 3.
fn standing_out(y: &[f64], f: f64, ts: f64, r: &Rules) -> u32 {
    let n = analysis::whole_periods(y.len(), f, ts);
    let amp = analysis::harmonics(&y[..n], f, ts, 1).first().map_or(0.0, |t| t.amp);
    let min = crate::model::MIN_HARMONIC_REL * amp;
    analysis::dominant_odd_harmonic(&y[..n], f, ts, 0.0, min)
        .map(|(order, _)| order)
        .filter(|&o| o <= r.sine.max_term_order && f64::from(o) * f < 0.5 / ts)
        .unwrap_or(3)
}

/// The first held-out sample (from `drive_on`): `fit_fraction` of the window from `start`, at
/// a whole period for a periodic drive.
fn split_at(drive: &Drive, start: usize, len: usize, fit_fraction: f64) -> usize {
    let mut fitted = (fit_fraction * len as f64).round() as usize;
    if let (true, Some(p)) = (drive.is_periodic(), drive.period_samples) {
        let periods = ((len as f64 + 0.5) / p).floor();
        let k = (fit_fraction * periods).round().clamp(1.0, (periods - 1.0).max(1.0));
        if periods >= 2.0 {
            fitted = (k * p).round() as usize;
        }
    }
    start + fitted.clamp(1, len - 1)
}

/// A record made ready for a fit: its steady window, the drive there, and where the fitted
/// part ends. Every family is fitted and held out on the same samples.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// The window in the record.
    pub window: Window,
    /// The drive in the window.
    pub drive: Drive,
    /// The window (s).
    pub window_s: [f64; 2],
    /// First fitted sample, relative to `window.drive_on`.
    pub start: usize,
    /// First held-out sample, relative to `window.drive_on`.
    pub split: usize,
}

impl Prepared {
    /// The drive and output from the start of the steady drive to the window's end.
    pub fn signals<'a>(&self, r: &'a Record) -> (&'a [f64], &'a [f64]) {
        (&r.u[self.window.drive_on..self.window.end], &r.y[self.window.drive_on..self.window.end])
    }
}

/// Finds the steady window and the split of `fit_fraction` (see the module docs); `given`
/// is `--window` in samples.
pub fn prepare(
    r: &Record,
    given: Option<(usize, usize)>,
    fit_fraction: f64,
    rules: &Rules,
) -> Result<Prepared, IdentifyError> {
    if !(fit_fraction.is_finite() && (0.1..=0.9).contains(&fit_fraction)) {
        return Err(IdentifyError::Option(format!(
            "--fit-fraction {fit_fraction}: must be between 0.1 and 0.9"
        )));
    }
    let ts = r.ts;
    let (w, drive) = steady::steady_window(&r.u, &r.y, ts, given, rules)?;
    if drive.kind == DriveKind::None {
        return Err(DiagnoseError::NoDrive { std_v: drive.std_v }.into());
    }
    steady::check_response(&r.u[w.start..w.end], &r.y[w.start..w.end], ts, &drive, rules)?;
    let window_s = w.seconds(r.t0, ts);
    let need = rules.sine.min_samples;
    if w.end - w.start < need {
        return Err(IdentifyError::TooFewSamples { samples: w.end - w.start, need, window_s });
    }
    let start = w.start - w.drive_on;
    let split = split_at(&drive, start, w.end - w.start, fit_fraction);
    Ok(Prepared { window: w, drive, window_s, start, split })
}

/// Identifies a record (see the module docs); `given` is `--window` in samples.
pub fn identify(
    r: &Record,
    given: Option<(usize, usize)>,
    o: &Options,
    rules: &Rules,
) -> Result<Identified, IdentifyError> {
    let ts = r.ts;
    let Prepared { window: w, drive, window_s, start, split } = prepare(r, given, o.fit_fraction, rules)?;
    let (u, y) = (&r.u[w.drive_on..w.end], &r.y[w.drive_on..w.end]);
    let drive_hz = match o.drive_hz {
        Some(f) if f.is_finite() && f > 0.0 && f < 0.5 / ts => f,
        Some(f) => {
            return Err(IdentifyError::Option(format!(
                "--drive-hz {f}: must be above 0 and below {} Hz",
                0.5 / ts
            )));
        }
        None => drive.freq_hz,
    };
    let harmonics = match o.structure {
        Structure::Extended if !o.harmonics.is_empty() => {
            return Err(IdentifyError::Option("--harmonics needs --model enhanced".into()));
        }
        Structure::Extended => vec![],
        Structure::Enhanced => {
            if !matches!(drive.kind, DriveKind::Sine | DriveKind::Periodic) && o.drive_hz.is_none() {
                return Err(IdentifyError::NoDriveFrequency { drive: drive.describe() });
            }
            if o.harmonics.is_empty() {
                vec![standing_out(&y[start..split], drive_hz, ts, rules)]
            } else {
                o.harmonics.clone()
            }
        }
    };
    let spec = ModelSpec { drive_hz: drive_hz.max(1e-3), harmonics, drift_degree: None };
    // The output is averaged over periods only in steady state: the model has no drift term.
    let mut opt = OeOptions {
        require_invertible: o.invertible,
        averaging: Averaging::Periods,
        ..fit_options(split, ts, rules)
    };
    opt.skip = start.max(opt.skip.min(split.saturating_sub(rules.sine.fit_min_samples)));
    let (model, fit) = match o.method {
        Method::Oe => {
            let t0 = std::time::Instant::now();
            let fit = fit::fit_oe(u, y, ts, split, &spec, &[], &opt).map_err(DiagnoseError::Fit)?;
            (fit.model.clone(), Some((fit, t0.elapsed().as_secs_f64())))
        }
        Method::Rls => (fit::fit_paper_rls(u, y, ts, split, &spec).map_err(DiagnoseError::Fit)?, None),
    };
    let sim = model.simulate(u, ts)?;
    let mut check = ModelCheck::of(&model.ext.ar, &sim[split..], &y[split..], ts, &rules.checks);
    check
        .check_amplitudes(&model.ext.bw, &model.ext.ar, u, ts, &rules.checks, |v| model.simulate(v, ts).ok());
    let fitted_stable = checks::instability(&model.ext.ar, &sim[..split], ts).is_none();
    Ok(Identified {
        fit_rms_um: fitted_stable.then(|| analysis::rms_diff(&y[opt.skip..split], &sim[opt.skip..split])),
        held_rms_um: analysis::rms_diff(&y[split..], &sim[split..]),
        noise_um: steady::noise_floor(&y[split..], ts, &drive, rules),
        samples: (split - start, y.len() - split),
        why: w.why,
        model,
        method: o.method,
        fit,
        drive,
        drive_hz,
        window_s,
        check,
        ts,
    })
}
