//! `diagnose`: given a record, show what the baseline model gets wrong, name the cause,
//! extend the model and measure the gain.
//!
//! One dispatcher ([`diagnose_drive`]) picks the analysis by the drive found in the record:
//! a sine ([`sine`]), a periodic drive that is not a sine or a multisine ([`periodic`]), or
//! a record that steps through several sines ([`steps`]). Each analysis is a chain of stages
//! over typed data, and decides by the rules table ([`crate::rules::Rules`]) alone:
//!
//! | module | what |
//! |---|---|
//! | [`plan`] | the sine analysis's window, drive and fitted and held-out periods |
//! | [`sine`] | the sine analysis: baseline, residual, candidates, selection, delay, findings |
//! | [`periodic`] | the periodic and multisine analysis: data at the lines, models, terms, findings |
//! | [`steps`] | a stepped sine, each step diagnosed on its own |
//! | [`causes`] | saturation, creep and input delay: their signs in the record and their fits |
//! | [`residual`] | a held-out residual split into harmonics, trend and noise |
//! | [`checks`] | what a fitted model must pass: stability, a loop that closes, other amplitudes |
//! | [`evidence`] | findings as data: kinds, evidence per kind, trials and why a term was not kept |
//! | [`error`] | why a diagnosis could not be made |
//!
//! Nothing here writes a sentence: [`crate::report::diagnosis`] renders the findings as text
//! and JSON.

pub mod causes;
pub mod checks;
pub mod error;
pub mod evidence;
pub mod periodic;
pub mod plan;
pub mod residual;
pub mod sine;
pub mod steps;

pub use error::DiagnoseError;
pub use evidence::{Evidence, Finding, Kind};
pub use sine::Diagnosis;

use crate::rules::Rules;
use crate::signal::steady::{self, DriveKind};
use periodic::{PeriodicDiagnosis, Realisation};

/// A diagnosis of any drive (see [`diagnose_drive`]).
#[derive(Clone, Debug)]
pub enum Outcome {
    /// A sine drive.
    Sine(Box<Diagnosis>),
    /// A periodic drive that is not a sine, or a multisine.
    Periodic(Box<PeriodicDiagnosis>),
}

impl Outcome {
    /// The findings, most important first.
    pub fn findings(&self) -> &[Finding] {
        match self {
            Outcome::Sine(d) => &d.findings,
            Outcome::Periodic(d) => &d.findings,
        }
    }

    /// How much the extended model lowers the baseline's held-out RMS (%).
    pub fn gain_pct(&self) -> f64 {
        match self {
            Outcome::Sine(d) => d.gain_pct(),
            Outcome::Periodic(d) => d.gain_pct(),
        }
    }
}

/// Diagnoses the records of one drive, choosing the analysis by the drive found in the first:
/// a sine (one record: [`sine::diagnose_planned`]), or a periodic drive that is not a sine or a
/// multisine (one record, or several realisations: [`periodic::diagnose`]). A drive that
/// does not repeat, or none, is one sentence.
pub fn diagnose_drive(records: &[Realisation<'_>], ts: f64, r: &Rules) -> Result<Outcome, DiagnoseError> {
    let first = records.first().ok_or(DiagnoseError::Realisations("no record given".into()))?;
    let n = first.u.len().min(first.y.len());
    let (u, y) = (&first.u[..n], &first.y[..n]);
    let (w, d) = steady::steady_window(u, y, ts, first.given, r)?;
    match d.kind {
        DriveKind::None => Err(DiagnoseError::NoDrive { std_v: d.std_v }),
        DriveKind::Sine if records.len() == 1 => {
            let plan = plan::plan_in(u, y, ts, first.t0, w, d, r)?;
            sine::diagnose_planned(u, y, ts, &plan, r).map(|d| Outcome::Sine(Box::new(d)))
        }
        DriveKind::Sine => Err(DiagnoseError::Realisations(format!(
            "the drive is {}: a sine record is diagnosed on its own, not as one of several realisations (they are for \
             multisines)",
            d.describe()
        ))),
        DriveKind::Periodic | DriveKind::Multisine => {
            periodic::diagnose(records, ts, r).map(|d| Outcome::Periodic(Box::new(d)))
        }
        DriveKind::Aperiodic => {
            steady::check_response(&u[w.start..w.end], &y[w.start..w.end], ts, &d, r)?;
            Err(DiagnoseError::Aperiodic { drive: d.describe() })
        }
    }
}

/// Diagnoses a sine record: `u` (V), `y` (µm), sample interval `ts` (s), its first sample at
/// `t = 0`, in its steady window.
pub fn diagnose(u: &[f64], y: &[f64], ts: f64, r: &Rules) -> Result<Diagnosis, DiagnoseError> {
    diagnose_record(u, y, ts, 0.0, None, r)
}

/// Diagnoses a sine record whose first sample is at `t0` (s), in its steady window or in
/// `given` (samples): [`plan::plan`], then [`sine::diagnose_planned`].
pub fn diagnose_record(
    u: &[f64],
    y: &[f64],
    ts: f64,
    t0: f64,
    given: Option<(usize, usize)>,
    r: &Rules,
) -> Result<Diagnosis, DiagnoseError> {
    let n = u.len().min(y.len());
    let plan = plan::plan(&u[..n], &y[..n], ts, t0, given, r)?;
    sine::diagnose_planned(&u[..n], &y[..n], ts, &plan, r)
}
