//! The diagnosis of a sine record: show what the baseline model gets wrong, name the cause,
//! extend the model and measure the gain. Stages, each a module over typed data:
//!
//! 1. **Plan** ([`crate::diagnose::plan`]): the steady window, the drive, the fitted and
//!    held-out periods.
//! 2. **Baseline** ([`baseline`]): the extended model fitted (output error,
//!    [`crate::fit::fit_oe`]) on the first half of the record and simulated in free run over
//!    the whole of it; the second half is held out. It carries a constant output offset (a
//!    sensor's zero is arbitrary; an offset is not a finding, the model's name shows it).
//!    The criterion skips the start-up and, under a periodic drive, fits the average of the
//!    half's remaining periods once a trend is separated. A baseline whose loop does not
//!    close under the drive, or that explains less than `checks.min_fit_pct` of the output,
//!    ends the diagnosis here.
//! 3. **What it gets wrong** ([`crate::diagnose::residual`]): the held-out residual split
//!    into harmonics `k·f`, a slow trend and noise.
//! 4. **Candidates** ([`candidates`]): a harmonic `2 ≤ n ≤ sine.max_term_order` whose RMS in
//!    the output or in the residual reaches `terms.min_candidate_rel` of the output's
//!    fundamental; the trend when its RMS does, or reaches `sine.drift_noise_factor` times
//!    the residual's noise; a saturation and creep where the record shows their signs
//!    ([`crate::diagnose::causes`]). Both places count for a harmonic: the extended model can
//!    reproduce one resonant harmonic through its own loop (it places its resonance on
//!    `n·f`), and then the harmonic is large in the output but small in the residual.
//! 5. **Selection** ([`selection`]): forward selection. Every candidate's term is added to
//!    the current model and the model refitted; a term qualifies if it lowers the held-out
//!    RMS by `terms.min_gain` and carries `terms.min_term_rel` of the output's fundamental.
//!    Of the qualifying terms the one with the most evidence in the record wins (a
//!    saturation or creep term that lowers the held-out RMS further replaces it). Before the
//!    first term is kept, the baseline is refitted from the winner's structure; if that alone
//!    gains `sine.baseline_refit_gain` the diagnosis restarts from it. A harmonic term does
//!    not qualify at an order the drive itself carries when the drive's harmonic accounts for
//!    `sine.drive_share_max` of the output's there.
//! 6. **Delay** ([`delay`]): from the step onto the drive, when the record holds it.
//! 7. **Findings** ([`findings`]): the kept terms, with their evidence, then the structure
//!    no term could remove (`kept: false`), the resonance the record supports, and the
//!    extended model's checks at other amplitudes.
//!
//! The held-out half serves both to choose terms and to report the gain, so the gain of a
//! chosen term is measured on the data that chose it (a validation, not a test, gain).
//!
//! ## What a record cannot tell
//! With the output on a sensor's plateaus for a third to a half of the samples, a 3rd
//! harmonic the extended model imitates with its loop on the rest is not named: its branch
//! gains under `terms.min_gain`, and a lower rule would not help, since on clipped records
//! with no harmonic a branch tried after the clamp gains as much (up to 19 % in the batch,
//! against 2–14 % on the records where a harmonic was hidden; see the book's "How often it
//! is right"). The finding says on what share the diagnosis rests and which drive shows the
//! whole loop.

pub mod baseline;
pub mod candidates;
pub mod delay;
pub mod findings;
pub mod selection;

use super::checks::ModelCheck;
use super::error::DiagnoseError;
use super::evidence::{Finding, NotKept, Resonance, Trial};
use super::plan::Plan;
use super::residual::Residual;
use crate::fit::{FitData, OeOptions};
use crate::model::terms::{TermModel, Terms};
use crate::model::{HostModel, ModelSpec};
use crate::rules::Rules;
use crate::signal::steady::{Drive, Window};

/// The whole diagnosis of a sine record.
#[derive(Clone, Debug)]
pub struct Diagnosis {
    /// The drive frequency found in `u` (Hz).
    pub drive_hz: f64,
    /// Sample interval (s).
    pub ts: f64,
    /// First held-out sample.
    pub split: usize,
    /// The baseline model.
    pub baseline: HostModel,
    /// Its held-out free-run RMS (µm).
    pub baseline_rms_um: f64,
    /// Its free run over the whole record (µm).
    pub baseline_sim: Vec<f64>,
    /// The baseline's residual decomposition.
    pub residual: Residual,
    /// What the record says of the baseline's resonance.
    pub resonance: Resonance,
    /// What was found, most important first.
    pub findings: Vec<Finding>,
    /// Every term tried, round by round.
    pub trials: Vec<Trial>,
    /// The extended model's host (the baseline if no term was kept).
    pub model: HostModel,
    /// The extended model's terms beyond its host (saturation, creep, delay).
    pub terms: Terms,
    /// The input delay the step onto the drive shows, when the record holds the step.
    pub delay: Option<DelayEstimate>,
    /// Its held-out free-run RMS (µm).
    pub model_rms_um: f64,
    /// Its free run over the whole record (µm).
    pub model_sim: Vec<f64>,
    /// The extended model's residual decomposition.
    pub model_residual: Residual,
    /// Output fundamental amplitude over the held-out part (µm).
    pub output_amplitude_um: f64,
    /// The part of the record analysed; the free runs cover `window.drive_on..window.end`
    /// and `split` counts from `window.drive_on`.
    pub window: Window,
    /// The drive found in the window.
    pub drive: Drive,
    /// Time of the record's first sample (s).
    pub t0: f64,
    /// Whole drive periods fitted and held out.
    pub periods: (usize, usize),
    /// The baseline's held-out fit and stability.
    pub baseline_check: ModelCheck,
    /// The extended model's held-out fit and stability.
    pub model_check: ModelCheck,
    /// The output's noise floor over the held-out part (µm) and how it was measured.
    pub noise_um: (f64, &'static str),
    /// A harmonic term that would have been kept but stands for the drive's own harmonic as
    /// much as for the actuator (`sine.drive_share_max`): why it was not.
    pub drive_note: Option<NotKept>,
}

/// The input delay a record's step onto the drive shows.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DelayEstimate {
    /// The delay (samples).
    pub samples: f64,
    /// RMS error over the start-up and the first periods of the model fitted there without
    /// a delay (µm).
    pub rms_without_um: f64,
    /// The same with the delay (µm).
    pub rms_with_um: f64,
}

impl Diagnosis {
    /// The extended model's name, its terms included ("enhanced(3)+offset+saturation(u)").
    pub fn model_name(&self) -> String {
        TermModel { host: self.model.clone(), terms: self.terms.clone() }.name()
    }

    /// `100·(1 − after/before)`.
    pub fn gain_pct(&self) -> f64 {
        if self.baseline_rms_um > 0.0 {
            100.0 * (1.0 - self.model_rms_um / self.baseline_rms_um)
        } else {
            0.0
        }
    }

    /// The resonance of the baseline's structure the record supports (Hz).
    pub fn resonance_hz(&self) -> Option<f64> {
        match self.resonance {
            Resonance::Excited { .. } | Resonance::InResidual { .. } => {
                crate::model::poles::resonance_hz(&self.baseline.ext.ar, self.ts)
            }
            _ => None,
        }
    }

    /// The samples of `x` (the whole record) the diagnosis covers: its free runs and
    /// `split` count from the first of them.
    pub fn analysed<'a>(&self, x: &'a [f64]) -> &'a [f64] {
        &x[self.window.drive_on..self.window.end]
    }

    /// The window analysed, `[start, end]` in the record's time (s).
    pub fn window_s(&self) -> [f64; 2] {
        self.window.seconds(self.t0, self.ts)
    }

    /// First sample of the fitted part, counted from `window.drive_on`.
    pub fn fit_start(&self) -> usize {
        self.window.start - self.window.drive_on
    }

    /// The trials that lowered the held-out RMS by at least the threshold but whose term was
    /// not kept, each candidate once (its last such trial), with the reason.
    pub fn not_kept(&self) -> Vec<&Trial> {
        let key = |t: &Trial| (t.candidate.kind, t.candidate.order);
        let kept: Vec<_> = self.trials.iter().filter(|t| t.kept).map(key).collect();
        let mut out: Vec<&Trial> = vec![];
        for t in self.trials.iter().filter(|t| t.reason.is_some() && !kept.contains(&key(t))) {
            out.retain(|o| key(o) != key(t));
            out.push(t);
        }
        out
    }
}

/// What every stage reads: the record's analysed samples (from the step onto the drive),
/// the plan, the rules, and the fitted half prepared once for every fit.
pub struct Context<'a> {
    /// Drive (V), from `window.drive_on`.
    pub u: &'a [f64],
    /// Output (µm), from `window.drive_on`.
    pub y: &'a [f64],
    /// Sample interval (s).
    pub ts: f64,
    /// The plan.
    pub plan: &'a Plan,
    /// The rules.
    pub rules: &'a Rules,
    /// The fitted half, its average periods computed once.
    pub data: FitData<'a>,
    /// The baseline's spec: the extended model with an offset.
    pub spec: ModelSpec,
}

impl<'a> Context<'a> {
    /// The context of a plan on the window's samples `u`, `y`.
    pub fn new(u: &'a [f64], y: &'a [f64], ts: f64, plan: &'a Plan, rules: &'a Rules) -> Self {
        let spec = ModelSpec { drift_degree: Some(0), ..ModelSpec::extended(plan.drive.freq_hz) };
        let data = FitData::new(u, y, ts, plan.split);
        data.prepare(&spec, &plan.opt);
        data.prepare(&ModelSpec { drift_degree: Some(1), ..spec.clone() }, &plan.opt);
        Context { u, y, ts, plan, rules, data, spec }
    }

    /// First held-out sample.
    pub fn split(&self) -> usize {
        self.plan.split
    }

    /// The fit's settings.
    pub fn opt(&self) -> &OeOptions {
        &self.plan.opt
    }

    /// `y − sim` over the held-out part.
    pub fn held_out(&self, sim: &[f64]) -> Vec<f64> {
        let s = self.split();
        self.y[s..].iter().zip(&sim[s..]).map(|(a, b)| a - b).collect()
    }
}

/// Diagnoses a record as planned.
pub fn diagnose_planned(
    u: &[f64],
    y: &[f64],
    ts: f64,
    plan: &Plan,
    r: &Rules,
) -> Result<Diagnosis, DiagnoseError> {
    let w = &plan.window;
    run(&Context::new(&u[w.drive_on..w.end], &y[w.drive_on..w.end], ts, plan, r), &[], 0)
}

/// The stages on a context, with extra start models for the baseline; `depth` counts the
/// restarts from a better baseline ([`selection::Outcome::Restart`]).
fn run(cx: &Context<'_>, starts: &[HostModel], depth: usize) -> Result<Diagnosis, DiagnoseError> {
    let base = baseline::fit(cx, starts, depth)?;
    let facts = baseline::facts(cx, &base);
    if let Some(finding) = baseline::other_input(cx, &base, &facts) {
        return Ok(findings::other_input(cx, base, facts, finding));
    }
    let record = candidates::read(cx, &base, &facts)?;
    let selected = match selection::select(cx, &base, &facts, &record, depth)? {
        selection::Outcome::Restart(b) => return run(cx, &[b], depth + 1),
        selection::Outcome::Done(s) => *s,
    };
    let delayed = delay::stage(cx, &record, selected.model.clone(), selected.model_rms)?;
    findings::assemble(cx, base, facts, &record, selected, delayed)
}
