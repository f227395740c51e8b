//! The diagnosis of periodic drives that are not a sine (a triangle, a square) and for
//! multisines: what the model gets wrong, seen at the lines of whole periods.
//!
//! 1. **Where** ([`data`]). Each record's steady window ([`crate::signal::steady`]); the
//!    records given together are realisations of one drive (same period, same excited
//!    lines, new phases).
//! 2. **The data** ([`data`], [`crate::signal::distortion`]): the excited lines, the best linear approximation
//!    with its noise and distortion levels, and the output at the lines the drive does not
//!    excite: odd lines left out (odd distortion) and even lines (even distortion), each as
//!    a level in dB above the noise with the band where single lines stand out.
//! 3. **The models** ([`models`]), fitted on the first realisation (or the first half of the periods of
//!    the only one) and tested in free run on the others (or on the later periods): the linear
//!    model (no hysteresis), the hysteresis model with a symmetric loop (`A0 = 0`) and the
//!    extended model (its loop's asymmetric term free), which is the baseline. Their held-out
//!    residuals are measured at the same lines: what the hysteresis itself accounts for
//!    shows there.
//! 4. **Terms** ([`terms`]) beyond the extended model, each refined jointly with it
//!    ([`crate::fit::refine`]): a cubic stiffening of the structure (odd) and a quadratic
//!    one (even, an asymmetric stiffness). A term is kept when it lowers the held-out RMS by
//!    `terms.min_gain` and either carries `terms.min_term_rel` of the output's
//!    RMS or removes `periodic.noise_multiple` times the noise floor from the held-out residual
//!    (`√(before² − after²)`): a stiffening that the loop mostly imitates carries well under
//!    2 % of the output (0.8–1.6 % under the batch's triangles), yet what it leaves to the
//!    term is many times what the noise of held-out periods can account for; the one whose
//!    parity has the most evidence first, then the other on top.
//! 5. **Findings** ([`findings`]; [`crate::diagnose::evidence::Kind::OddDistortion`],
//!    [`crate::diagnose::evidence::Kind::EvenDistortion`]): a kept term, with
//!    the data's level at the lines of its parity (or, for a triangle's odd lines, which
//!    are all excited, the level of what the term accounts for there) and the band; or
//!    distortion of a parity the extended model leaves in its held-out residual (at least
//!    `terms.unexplained_share` of its power and `min_term_rel` of the output)
//!    with no term to remove it (`kept: false`). Distortion the extended model accounts for
//!    is not a finding: the summary says how much of it the hysteresis explains.
//!
//! With one realisation the held-out periods repeat the fitted ones but for the noise: the
//! held-out error then tests the fit against noise, not against new phases (the summary
//! says which it was).

pub mod data;
pub mod findings;
pub mod models;
pub mod placement;
pub mod terms;

use super::checks::ModelCheck;
use super::error::DiagnoseError;
use super::evidence::{Evidence, Finding, NotKept};
use crate::model::terms::TermModel;
use crate::rules::Rules;
use crate::signal::distortion::{BlaLine, Level, Lines, Parity};
use crate::signal::steady::{Drive, Window};

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

impl ModelStep {
    /// Whether its held-out error can be compared: its free run is stable and finite.
    pub fn usable(&self) -> bool {
        self.check.unstable.is_none() && self.rms_um.is_finite()
    }
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
    pub reason: Option<NotKept>,
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
    /// The linear model, the hysteresis model with a symmetric loop and the extended model.
    pub compared: Vec<ModelStep>,
    /// Which of them is the baseline: the extended model, unless a simpler one does better
    /// on the held-out data (a loop fitted to one realisation that does not carry over).
    pub baseline_step: usize,
    /// The baseline with each kept term, in order.
    pub with_terms: Vec<ModelStep>,
    /// Every term tried.
    pub trials: Vec<TermTrial>,
    /// What was found, most important first.
    pub findings: Vec<Finding>,
    /// The Bouc–Wen oscillator tried against the extended model, when the rules let it
    /// ([`placement`]).
    pub placement: Option<placement::Placement>,
    /// The output's noise floor (µm, from period to period, at least the sensor's steps').
    pub noise_um: f64,
    /// How it was measured: `period_to_period`, or `quantisation` (the sensor's steps).
    pub noise_method: &'static str,
    /// RMS of the output over the held-out part, its mean removed (µm).
    pub output_rms_um: f64,
}

impl PeriodicDiagnosis {
    /// The baseline (see [`PeriodicDiagnosis::baseline_step`]).
    pub fn baseline(&self) -> &ModelStep {
        &self.compared[self.baseline_step]
    }

    /// The baseline with its kept terms.
    pub fn model(&self) -> &ModelStep {
        self.with_terms.last().unwrap_or(self.baseline())
    }

    /// Every model, in order: the compared ones, then the baseline with each kept term.
    pub fn steps(&self) -> impl Iterator<Item = &ModelStep> {
        self.compared.iter().chain(&self.with_terms)
    }

    /// `100·(1 − after/before)` of the held-out RMS from the baseline to the extended model
    /// (to the oscillator, when it was kept).
    pub fn gain_pct(&self) -> f64 {
        let kept = self.placement.as_ref().filter(|p| p.kept).map(|p| p.evidence.restoring_um);
        let (b, m) = (self.baseline().rms_um, kept.unwrap_or(self.model().rms_um));
        if b > 0.0 { 100.0 * (1.0 - m / b) } else { 0.0 }
    }
}

/// Diagnoses one or more realisations of a periodic or multisine drive (see the module docs).
pub fn diagnose(records: &[Realisation<'_>], ts: f64, r: &Rules) -> Result<PeriodicDiagnosis, DiagnoseError> {
    let data = data::prepare(records, ts, r)?;
    let output_rms_um = data.output_rms();
    let (noise_um, noise_method) = data.noise(ts, r);
    let compared = models::compared(&data, ts, r)?;
    let baseline_step = models::baseline(&compared)?;
    let baseline = &compared[baseline_step];
    let kept = terms::select(&data, baseline, noise_um, output_rms_um, ts, r)?;
    let mut findings = findings::findings(&data, baseline, &kept, output_rms_um, ts, r);
    let best = kept.steps.last().unwrap_or(baseline);
    let placement = placement::restoring_force(&data, baseline, best, output_rms_um, noise_um, ts, r);
    if let Some(p) = placement.as_ref().filter(|p| p.kept) {
        // The distortion the terms took or left is the loop's, inside the structure.
        findings.retain(|f| {
            !matches!(f.evidence, Evidence::UnexplainedDistortion { .. } | Evidence::Distortion(_))
        });
        findings.insert(0, p.finding());
    }
    Ok(PeriodicDiagnosis {
        ts,
        bla: data.bla(r),
        odd: data.odd,
        even: data.even,
        odd_drive: data.odd_drive,
        drive: data.drive,
        windows: data.windows,
        periods: data.periods,
        held_out: data.held_out,
        lines: data.lines,
        compared,
        baseline_step,
        with_terms: kept.steps,
        trials: kept.trials,
        findings,
        placement,
        noise_um,
        noise_method,
        output_rms_um,
    })
}
