//! `diagnose`: given a record of a sine drive, show what the baseline model gets wrong, name
//! the cause, extend the model and measure the gain.
//!
//! 1. **Baseline.** The extended model is fitted (output error, [`crate::fit::fit_oe`]) on
//!    the first half of the record and simulated in free run over the whole record; the
//!    second half is held out. If a constant output offset lowers the held-out RMS by
//!    [`Thresholds::min_gain`], the baseline carries it ("extended+offset"): a sensor's zero
//!    is arbitrary, and the model's loop starts from `h = 0` wherever the actuator was. An
//!    offset is not a finding; the model's name shows it. The fit criterion skips the start-up (a fifth of the half, at most
//!    [`MAX_SKIP_S`]) and, under a periodic drive, fits the average of the half's remaining
//!    periods once a trend is separated ([`crate::fit::Averaging::PeriodsAndTrend`]).
//! 2. **What it gets wrong.** The held-out residual `r = y − ŷ` is split ([`decompose`]) into
//!    the part periodic with the drive (harmonics `k·f`, measured over whole periods), a
//!    slow trend (a cubic in time, its mean included, fitted to what the harmonics leave),
//!    and the rest (noise).
//! 3. **Candidates.** A harmonic `2 ≤ n ≤` [`MAX_TERM_ORDER`] is a candidate term when its RMS
//!    in the output or in the residual reaches [`Thresholds::min_candidate_rel`] of the RMS of
//!    the output's fundamental; the trend when its RMS does, or reaches
//!    [`DRIFT_NOISE_FACTOR`] times the residual's noise (a drift does not scale with the
//!    drive: over a few periods it is small beside the output). Both places count: the extended
//!    model can reproduce one resonant harmonic through its own loop (it places its resonance
//!    on `n·f`), and then the harmonic is large in the output but small in the residual, while
//!    the model pays for it elsewhere.
//! 4. **Extension.** Forward selection: every candidate's term (a harmonic branch of order
//!    `n`, odd or even, or a drift line `c0 + c1·t`) is added to the current model and the
//!    model refitted (a search over structures and loop shapes, and from the current model).
//!    A term qualifies if it lowers the held-out RMS by at least [`Thresholds::min_gain`]
//!    and carries at least [`Thresholds::min_term_rel`] of the output's fundamental RMS
//!    (smaller structure is not worth a term; a drift line, at most [`DRIFT_NOISE_FACTOR`]
//!    times the residual's noise). Of the qualifying terms the one with the most
//!    evidence in the record wins ([`Candidate::evidence_um`]: a harmonic's RMS in the output,
//!    the trend's in the residual), not the one with the lowest RMS: the extended model can
//!    imitate one resonant harmonic with its loop, and a branch at another order then
//!    cancels what the bent loop does there, fitting as well while standing for a harmonic
//!    the record hardly has. The search repeats with the rest. Before the first term is
//!    kept, the baseline is refitted from the winner's structure (its term removed); if that
//!    alone lowers the baseline's RMS by [`BASELINE_REFIT_GAIN`] the diagnosis restarts from
//!    it (a term's fit may find the structure the baseline's fit missed). A harmonic
//!    term does not qualify at an order the drive itself carries (at least
//!    [`DRIVE_DISTORTION_FLOOR`]) when the drive's harmonic accounts, through the baseline,
//!    for [`DRIVE_SHARE_MAX`] of the output's there: the record cannot tell the actuator's
//!    harmonic from its response to the drive's ([`Diagnosis::drive_note`] says so).
//! 5. **Findings.** The kept terms, in the order chosen: an odd harmonic `n ≥ 3` is an odd
//!    harmonic oscillation, an even one an asymmetry, the trend a drift. Then the structure
//!    no term could remove: a harmonic or trend that still holds at least a quarter of the
//!    extended model's residual power and [`Thresholds::min_term_rel`] of the output,
//!    reported with `kept = false`.
//!
//! The held-out half serves both to choose terms and to report the gain, so the gain of a
//! chosen term is measured on the data that chose it (a validation, not a test, gain).
//!
//! 6. **Beyond the record.** The extended model is run again at [`OTHER_AMPLITUDES`] of the
//!    drive, and its loop's class is checked ([`amplitude_note`]): a fit to one sine may hold
//!    that amplitude only. An output saturation's finding gives the drive amplitude that
//!    would keep the output inside the range ([`causes::drive_within_range`]).
//!
//! ## What a record cannot tell
//! With the output on a sensor's plateaus for a third to a half of the samples, a 3rd
//! harmonic the extended model imitates with its loop on the rest is not named: its branch
//! gains under [`Thresholds::min_gain`], and a lower rule would not help, since on clipped
//! records with no harmonic a branch tried after the clamp gains as much (up to 19 % in the
//! batch, against 2–14 % on the records where a harmonic was hidden; see the book's
//! "How often it is right", `docs/book/src/diagnosis/accuracy.md`). The finding says on what
//! share the diagnosis rests and which drive shows the whole loop.
//!
//! ## Thresholds
//! The defaults ([`Thresholds::default`]) were set on records of the virtual bimorph with
//! hidden effects (`crate::fixtures::hidden`, feature `fixtures`); what they give over a batch of records is measured by
//! `cargo bench --bench diagnose_batch`. Over 480 records (`-- --per-effect 60`), the
//! largest term any candidate carried on the 120 clean records was 1.67 % of the output's
//! fundamental RMS; the term of the hidden effect carried 3.65 % or more in 95 % of the
//! effect records (1.70 % at least), hence 2 %. Misses are mostly a hidden 3rd or 2nd
//! harmonic the extended model imitates to within twice the noise floor, where no term can
//! gain the 50 % the batch asks for (the shares: `docs/book/src/diagnosis/accuracy.md`).

pub mod causes;
pub mod periodic;

use crate::fit::refine;
use crate::fit::{self, Averaging, FitData, FitError, OeOptions};
use crate::model::terms::{TermModel, Terms};
use crate::model::{HostModel, ModelSpec};
use crate::record::Y_LIMIT_UM;
use crate::signal::analysis::{self, Tone};
use crate::signal::steady::{self, Drive, DriveKind, NoResponse, Window, WindowError};
use rayon::prelude::*;
use std::f64::consts::TAU;

/// What a finding is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// An odd harmonic of the drive (order ≥ 3).
    OddHarmonic,
    /// An even harmonic of the drive.
    EvenHarmonic,
    /// A slow trend not locked to the drive.
    Drift,
    /// The drive explains less than [`MIN_FIT_PCT`] of the output: another input or a
    /// disturbance drives it.
    OtherInput,
    /// The drive or the output is flattened at a level (an amplifier's rails, a sensor's
    /// range).
    Saturation,
    /// A slow relaxation that follows the drive's history.
    Creep,
    /// The output answers the drive later than the model does.
    InputDelay,
    /// Odd nonlinear distortion under a periodic or multisine drive.
    OddDistortion,
    /// Even nonlinear distortion under a periodic or multisine drive.
    EvenDistortion,
}

impl Kind {
    /// The JSON name.
    pub fn as_str(&self) -> &'static str {
        match self {
            Kind::OddHarmonic => "odd_harmonic",
            Kind::EvenHarmonic => "even_harmonic",
            Kind::Drift => "drift",
            Kind::OtherInput => "other_input",
            Kind::Saturation => "saturation",
            Kind::Creep => "creep",
            Kind::InputDelay => "input_delay",
            Kind::OddDistortion => "odd_distortion",
            Kind::EvenDistortion => "even_distortion",
        }
    }
}

/// One named cause, with its evidence.
#[derive(Clone, Debug, PartialEq)]
pub struct Finding {
    /// What it is.
    pub kind: Kind,
    /// Harmonic order (harmonics only).
    pub order: Option<u32>,
    /// Frequency (Hz): the harmonic's, or 0 for drift.
    pub freq_hz: f64,
    /// A kept term: the share of the baseline's held-out residual power its term removed
    /// (when it was added). Not kept: its share of the extended model's residual power.
    pub residual_share: f64,
    /// Its amplitude in the baseline's held-out residual (µm): the harmonic's peak, or the
    /// trend's RMS.
    pub amplitude_um: f64,
    /// Its amplitude in the output relative to the fundamental (harmonics; 0 for drift).
    pub output_rel: f64,
    /// The cause, in words, with its evidence.
    pub cause: String,
    /// Whether its term is in the extended model.
    pub kept: bool,
    /// Held-out RMS of the model once its term was added (µm); `NaN` if not kept.
    pub rms_with_term_um: f64,
    /// What the term carries in the extended model: the held-out RMS of the change of the
    /// model's output when the term is removed (µm; a drift line counted from its level in
    /// the middle of the fitted half; creep, which relaxes mostly before the held-out half,
    /// over the whole run after the start-up, from its last level; an input delay, over the
    /// start-up it was found on), at most the held-out RMS of the model's output about its
    /// mean (a model may leave its range without its term: a drive clamp's, fitted to the
    /// clamped drive, then driven by the whole drive). Not kept: the RMS of the structure in
    /// the residual.
    pub term_rms_um: f64,
    /// A level and its unit where one applies: a saturation's (V of the drive, or µm of the
    /// output), an input delay's (samples), a distortion's (dB above the noise).
    pub level: Option<(f64, &'static str)>,
    /// The band (Hz) a distortion shows in.
    pub band_hz: Option<[f64; 2]>,
    /// A sensor's range (output saturation): the drive amplitude (V, about the drive's mean)
    /// with which the model, its output clamp removed, stays inside the range
    /// ([`causes::drive_within_range`]): the drive to measure the whole loop with.
    pub drive_within_range_v: Option<f64>,
}

/// Decision thresholds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Thresholds {
    /// A harmonic is tried as a term only if its RMS in the output or in the baseline's
    /// residual reaches this fraction of the RMS of the output's fundamental; the drift
    /// only if the residual's trend RMS does. A term that is to carry
    /// [`Thresholds::min_term_rel`] shows in one of them.
    pub min_candidate_rel: f64,
    /// Smallest relative reduction of the held-out RMS for a term to be kept.
    pub min_gain: f64,
    /// Smallest RMS a kept term must carry in the model (see [`Finding::term_rms_um`]),
    /// relative to the RMS of the output's fundamental: structure below it is not worth a
    /// term.
    pub min_term_rel: f64,
}

impl Default for Thresholds {
    fn default() -> Self {
        Self { min_candidate_rel: 0.01, min_gain: 0.2, min_term_rel: 0.02 }
    }
}

/// The residual decomposition of a model's held-out error.
#[derive(Clone, Debug, PartialEq)]
pub struct Residual {
    /// Held-out residual RMS (µm).
    pub rms_um: f64,
    /// Harmonics `1..` of the residual (µm), over whole drive periods.
    pub harmonics: Vec<Tone>,
    /// RMS of the slow trend, its mean included (µm).
    pub trend_rms_um: f64,
    /// Mean of the trend (µm).
    pub trend_mean_um: f64,
    /// Trend slope (µm/s, from the linear term).
    pub trend_slope_um_per_s: f64,
    /// RMS of what is neither periodic nor trend (µm).
    pub noise_rms_um: f64,
    /// RMS of the part periodic with the drive above the harmonics analysed (µm): what the
    /// average period holds beyond them when a period is a whole number of samples (a
    /// converter's steps, sharp corners); else 0.
    pub above_um: f64,
}

/// The whole diagnosis.
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
    /// Resonance of the baseline's structure (Hz), if it has complex poles.
    pub resonance_hz: Option<f64>,
    /// What was found, most important first.
    pub findings: Vec<Finding>,
    /// Every term tried, round by round.
    pub trials: Vec<Trial>,
    /// The extended model's host (the baseline if no term was kept).
    pub model: HostModel,
    /// The extended model's terms beyond its host (saturation, creep, delay).
    pub terms: Terms,
    /// The input delay the step onto the drive shows (see [`crate::diagnose::causes::delay_scan`]),
    /// when the record holds the step.
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
    /// What the record says about the structure's resonance.
    pub resonance_note: String,
    /// A harmonic term that would have been kept but stands for the drive's own harmonic
    /// as much as for the actuator ([`DRIVE_SHARE_MAX`]): why it was not, and what would tell.
    pub drive_note: Option<String>,
}

/// A model's measure on the held-out part: its fit and whether its free run stays stable.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelCheck {
    /// `100·(1 − ‖y − ŷ‖/‖y − mean(y)‖)` on the held-out part; `None` if not stable.
    pub fit_pct: Option<f64>,
    /// Why the model is not stable (`None`: stable).
    pub unstable: Option<String>,
    /// Why the model holds this record's amplitude only ([`amplitude_note`]; `None`: not
    /// checked, or it holds at the others too).
    pub narrow: Option<String>,
}

impl ModelCheck {
    /// Checks a free run `sim` against the held-out output `y` (both over the held-out part)
    /// and the model's structure: a pole on or outside the unit circle, a non-finite value or
    /// one beyond [`Y_LIMIT_UM`], or a free run that leaves the output's range by
    /// [`RUNAWAY_SPANS`] times its span ([`runaway`]) make it unstable.
    pub fn of(model: &HostModel, sim: &[f64], y: &[f64], ts: f64) -> ModelCheck {
        let unstable = instability(model.ext.ar, sim, ts).or_else(|| runaway(sim, y, ts));
        let fit_pct = unstable.is_none().then(|| fit_pct(y, sim));
        ModelCheck { fit_pct, unstable, narrow: None }
    }

    /// Sets [`Self::narrow`] for a stable model of loop `bw` and structure `ar`: its free run
    /// under the record's drive `u` at [`OTHER_AMPLITUDES`] ([`amplitude_note`]).
    pub fn check_amplitudes(
        &mut self,
        bw: &boucwen_core::model::BoucWenParams<f64>,
        ar: [f64; 2],
        u: &[f64],
        ts: f64,
        simulate: impl Fn(&[f64]) -> Option<Vec<f64>>,
    ) {
        if self.unstable.is_none() {
            self.narrow = amplitude_note(bw, ar, ts, |k| simulate(&scaled_about_mean(u, k)));
        }
    }
}

/// The drive scales, about the drive's mean, at which a fitted model is run again
/// ([`amplitude_note`]).
pub const OTHER_AMPLITUDES: [f64; 2] = [0.5, 1.5];

/// Whether a model fitted at one amplitude holds at others. The Bouc–Wen loop of eq. (3) is
/// bounded for every input only when `γ + β > 0` ([`boucwen_core::model::BoucWenParams::h_range`]);
/// with `γ + β ≤ 0` the state `h` grows by a factor `e^{|γ+β|·ΔU}` over a swing `ΔU` on one
/// branch, and the loop closes at the amplitude it was fitted at only. `simulate_at(k)` is the
/// model's free run under the record's drive scaled by `k` about its mean; each of
/// [`OTHER_AMPLITUDES`] is checked by [`instability`]. `None` when the loop is bounded and
/// every run stays in range.
pub fn amplitude_note(
    bw: &boucwen_core::model::BoucWenParams<f64>,
    ar: [f64; 2],
    ts: f64,
    simulate_at: impl Fn(f64) -> Option<Vec<f64>>,
) -> Option<String> {
    let diverges: Vec<String> = OTHER_AMPLITUDES
        .iter()
        .filter(|&&k| simulate_at(k).is_none_or(|sim| instability(ar, &sim, ts).is_some()))
        .map(|k| format!("{k}×"))
        .collect();
    let unbounded = bw.h_range().is_none();
    if !unbounded && diverges.is_empty() {
        return None;
    }
    let shape = format!(
        "its loop is outside the Bouc–Wen model's bounded class (γ + β = {:.4} ≤ 0: the hysteresis state grows \
         exponentially along one branch)",
        bw.gamma + bw.beta
    );
    Some(if diverges.is_empty() {
        format!(
            "{shape}; its free run at {} this drive stays in range, but a larger swing makes it grow \
             exponentially: check it at the amplitudes it is to be used at before compensating with it",
            join_scales()
        )
    } else {
        format!(
            "the model holds near this record's amplitude only: its free run at {} this drive diverges{}; measure \
             at the amplitudes it is to be used at before compensating with it",
            diverges.join(" and "),
            if unbounded { format!(", and {shape}") } else { String::new() }
        )
    })
}

fn join_scales() -> String {
    OTHER_AMPLITUDES.iter().map(|k| format!("{k}×")).collect::<Vec<_>>().join(" and ")
}

/// `u` scaled by `k` about its mean.
fn scaled_about_mean(u: &[f64], k: f64) -> Vec<f64> {
    let m = analysis::mean(u);
    u.iter().map(|v| m + k * (v - m)).collect()
}

/// `100·(1 − ‖y − ŷ‖/‖y − mean(y)‖)`: 100 % a perfect model, 0 % no better than the mean,
/// negative worse.
pub fn fit_pct(y: &[f64], yhat: &[f64]) -> f64 {
    let m = analysis::mean(y);
    let den = y.iter().map(|v| (v - m) * (v - m)).sum::<f64>().sqrt();
    let num = y.iter().zip(yhat).map(|(a, b)| (a - b) * (a - b)).sum::<f64>().sqrt();
    if den > 0.0 { 100.0 * (1.0 - num / den) } else { f64::NAN }
}

/// Why a model with AR part `ar` and free run `sim` is not stable, if it is not.
pub fn instability(ar: [f64; 2], sim: &[f64], ts: f64) -> Option<String> {
    let (a1, a2) = (ar[0], ar[1]);
    // Poles of z² − a1 z − a2: the largest modulus.
    let disc = a1 * a1 + 4.0 * a2;
    let radius = if disc >= 0.0 { (a1.abs() + disc.sqrt()) / 2.0 } else { (-a2).sqrt() };
    if radius.is_nan() || radius >= 1.0 {
        return Some(format!(
            "the structure has a pole of modulus {radius:.6} (a1 = {a1:.6}, a2 = {a2:.6}; stable needs every pole inside \
             the unit circle)"
        ));
    }
    if let Some(k) = sim.iter().position(|v| !v.is_finite() || v.abs() > Y_LIMIT_UM) {
        let when = if k == 0 {
            "from its first sample".to_string()
        } else {
            format!("{} s after its first sample", fmt_s(k as f64 * ts))
        };
        return Some(format!(
            "its free run leaves the physical range (±{Y_LIMIT_UM} µm) {when} over the held-out part: it diverges"
        ));
    }
    None
}

/// A free run this many times the output's span beyond the output's range has run away
/// from the record (see [`runaway`]).
pub const RUNAWAY_SPANS: f64 = 10.0;

/// Why a free run `sim` has run away from the output `y` it models, if it has: it leaves
/// `y`'s range by [`RUNAWAY_SPANS`] times `y`'s span. A model that does so is not a model of
/// the record, even inside the physical range: its held-out error would be a number that
/// means nothing (a symmetric loop fitted to a square drive once left 2,879 µm held out on a
/// 12 µm output).
pub fn runaway(sim: &[f64], y: &[f64], ts: f64) -> Option<String> {
    let (lo, hi) = analysis::extent(y);
    let span = hi - lo;
    if span.is_nan() || span <= 0.0 {
        return None;
    }
    let (a, b) = (lo - RUNAWAY_SPANS * span, hi + RUNAWAY_SPANS * span);
    let k = sim.iter().position(|v| *v < a || *v > b)?;
    Some(format!(
        "its free run leaves {RUNAWAY_SPANS} times the output's span beyond its range ([{lo:.3}, {hi:.3}] µm) {} s after \
         the held-out part's first sample: it runs away from the record",
        fmt_s(k as f64 * ts)
    ))
}

/// How far (µm, signed) the mean of a signal moves from its first to its last whole period
/// of `period` samples; `None` with fewer than two periods. Under a periodic drive a model
/// whose loop closes repeats itself; a baseline is refused when its free run moves by more
/// than [`RATCHET_REL`] of the output's fundamental and the output does not move with it.
pub fn ratchet_um(sim: &[f64], period: Option<f64>) -> Option<f64> {
    let p = period.filter(|p| *p >= 1.0)?;
    let n = sim.len();
    if (n as f64) < 2.0 * p {
        return None;
    }
    let pw = p.round() as usize;
    Some(analysis::mean(&sim[n - pw..]) - analysis::mean(&sim[..pw]))
}

/// A baseline whose free run's mean moves by more than this fraction of the output's
/// fundamental amplitude over the held-out part does not close its loop (see
/// [`DiagnoseError::Ratchets`]).
pub const RATCHET_REL: f64 = 0.05;

/// Smallest held-out fit (%) of the baseline for a harmonic diagnosis: below it the drive
/// explains too little of the output.
pub const MIN_FIT_PCT: f64 = 50.0;

/// One finding as JSON: `kind`, `order` (harmonics), `freq_hz`, `band_hz` (distortion),
/// `level` and `level_unit` (where one applies), `residual_share`, `cause`, `kept`,
/// `term_rms_um`.
pub fn finding_json(f: &Finding) -> serde_json::Value {
    use serde_json::json;
    let mut o = json!({
        "kind": f.kind.as_str(),
        "freq_hz": f.freq_hz,
        "residual_share": f.residual_share,
        "cause": f.cause,
        "kept": f.kept,
        "term_rms_um": f.term_rms_um,
    });
    if let Some(n) = f.order {
        o["order"] = json!(n);
    }
    if let Some((v, unit)) = f.level {
        o["level"] = json!(v);
        o["level_unit"] = json!(unit);
    }
    if let Some(b) = f.band_hz {
        o["band_hz"] = json!(b);
    }
    if let Some(v) = f.drive_within_range_v {
        o["drive_within_range_v"] = json!(v);
    }
    o
}

/// A diagnosis of any drive (see [`diagnose_drive`]).
#[derive(Clone, Debug)]
pub enum Outcome {
    /// A sine drive.
    Sine(Box<Diagnosis>),
    /// A periodic drive that is not a sine, or a multisine.
    Periodic(Box<crate::diagnose::periodic::PeriodicDiagnosis>),
}

impl Outcome {
    /// The findings, most important first.
    pub fn findings(&self) -> &[Finding] {
        match self {
            Outcome::Sine(d) => &d.findings,
            Outcome::Periodic(d) => &d.findings,
        }
    }

    /// The JSON object (see [`Diagnosis::json`] and
    /// [`crate::diagnose::periodic::PeriodicDiagnosis::json`]), with `analysis`: `sine` or `periodic`.
    pub fn json(&self) -> serde_json::Value {
        let (mut j, kind) = match self {
            Outcome::Sine(d) => (d.json(), "sine"),
            Outcome::Periodic(d) => (d.json(), "periodic"),
        };
        j["analysis"] = serde_json::json!(kind);
        j
    }

    /// The terminal report.
    pub fn summary(&self, source: &str) -> String {
        match self {
            Outcome::Sine(d) => d.summary(source),
            Outcome::Periodic(d) => d.summary(source),
        }
    }
}

/// Diagnoses the records of one drive, choosing the analysis by the drive found in the first:
/// a sine (one record: [`diagnose_record`]), or a periodic drive that is not a sine or a
/// multisine (one record, or several realisations: [`crate::diagnose::periodic::diagnose`]). A drive
/// that does not repeat, or none, is one sentence.
pub fn diagnose_drive(
    records: &[crate::diagnose::periodic::Realisation<'_>],
    ts: f64,
    th: &Thresholds,
) -> Result<Outcome, DiagnoseError> {
    let first = records.first().ok_or(DiagnoseError::Realisations("no record given".into()))?;
    let n = first.u.len().min(first.y.len());
    let (u, y) = (&first.u[..n], &first.y[..n]);
    let (w, d) = steady::steady_window(u, y, ts, first.given).map_err(DiagnoseError::Window)?;
    match d.kind {
        DriveKind::None => Err(DiagnoseError::NoDrive { std_v: d.std_v }),
        DriveKind::Sine if records.len() == 1 => {
            let plan = plan_in(u, y, ts, first.t0, w, d)?;
            diagnose_planned(u, y, ts, &plan, th).map(|d| Outcome::Sine(Box::new(d)))
        }
        DriveKind::Sine => Err(DiagnoseError::Realisations(format!(
            "the drive is {}: a sine record is diagnosed on its own, not as one of several realisations (they are for \
             multisines)",
            d.describe()
        ))),
        DriveKind::Periodic | DriveKind::Multisine => {
            crate::diagnose::periodic::diagnose(records, ts, th).map(|d| Outcome::Periodic(Box::new(d)))
        }
        DriveKind::Aperiodic => {
            steady::check_response(&u[w.start..w.end], &y[w.start..w.end], ts, &d)
                .map_err(DiagnoseError::NoResponse)?;
            Err(DiagnoseError::Aperiodic { drive: d.describe() })
        }
    }
}

/// One steady sine of a record that steps through several, and its diagnosis.
#[derive(Debug)]
pub struct SineStep {
    /// Where the sine is, its frequency and amplitude.
    pub segment: steady::SineSegment,
    /// Its diagnosis, or why there is none.
    pub outcome: Result<Outcome, DiagnoseError>,
}

impl SineStep {
    /// One line of what changes across the steps: "  14.000 Hz   1.000 V: baseline 0.2854 µm,
    /// extended 0.0149 µm (enhanced(5,3)+offset), findings: odd_harmonic 5, odd_harmonic 3",
    /// or the step's sentence.
    pub fn line(&self) -> String {
        let (f, a) = (self.segment.freq_hz, self.segment.amplitude_v);
        let d = match &self.outcome {
            Ok(d) => d,
            Err(e) => return format!("  {f:8.3} Hz {a:7.3} V: {e}"),
        };
        let findings: Vec<String> = d
            .findings()
            .iter()
            .filter(|f| f.kept)
            .map(|f| match f.order {
                Some(n) => format!("{} {n}", f.kind.as_str()),
                None => f.kind.as_str().to_string(),
            })
            .collect();
        let j = d.json();
        format!(
            "  {f:8.3} Hz {a:7.3} V: baseline {:.4} µm, extended {:.4} µm ({}), findings: {}",
            j["baseline"]["rms_um"].as_f64().unwrap_or(f64::NAN),
            j["extended"]["rms_um"].as_f64().unwrap_or(f64::NAN),
            j["extended"]["model"].as_str().unwrap_or("?"),
            if findings.is_empty() { "none".to_string() } else { findings.join(", ") }
        )
    }
}

/// A record that steps through several sines (a stepped sine: the same actuator at a series
/// of frequencies or amplitudes in one file, [`steady::sine_segments`]), each diagnosed on
/// its own (its own steady window, start-up and model), on all cores; `None` if the record
/// does not step through two sines or more.
pub fn diagnose_steps(u: &[f64], y: &[f64], ts: f64, t0: f64, th: &Thresholds) -> Option<Vec<SineStep>> {
    let n = u.len().min(y.len());
    let segments = steady::sine_segments(&u[..n], ts);
    if segments.len() < 2 {
        return None;
    }
    Some(
        segments
            .par_iter()
            .map(|&segment| {
                let (a, b) = (segment.start, segment.end);
                let (u, y, t0) = (&u[a..b], &y[a..b], t0 + a as f64 * ts);
                let outcome = steady::steady_window(u, y, ts, None)
                    .map_err(DiagnoseError::Window)
                    .and_then(|(w, d)| plan_in(u, y, ts, t0, w, d))
                    .and_then(|mut plan| {
                        // After the first step the actuator was not at rest: no delay from it.
                        plan.from_rest = a == 0;
                        diagnose_planned(u, y, ts, &plan, th).map(|d| Outcome::Sine(Box::new(d)))
                    });
                SineStep { segment, outcome }
            })
            .collect(),
    )
}

/// The sentence that introduces a stepped sine's diagnoses: "the drive steps through 4
/// sines: 5.000 Hz 1.000 V (0 to 3.75 s), …; each is diagnosed on its own".
pub fn steps_sentence(steps: &[SineStep], ts: f64, t0: f64) -> String {
    let list: Vec<String> = steps
        .iter()
        .map(|s| {
            format!(
                "{:.3} Hz {:.3} V ({} to {} s)",
                s.segment.freq_hz,
                s.segment.amplitude_v,
                fmt_s(t0 + s.segment.start as f64 * ts),
                fmt_s(t0 + s.segment.end as f64 * ts)
            )
        })
        .collect();
    format!(
        "the drive steps through {} sines: {}; each is diagnosed on its own",
        steps.len(),
        list.join(", ")
    )
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

    /// `100·(1 - after/before)`.
    pub fn gain_pct(&self) -> f64 {
        if self.baseline_rms_um > 0.0 {
            100.0 * (1.0 - self.model_rms_um / self.baseline_rms_um)
        } else {
            0.0
        }
    }
}

impl Diagnosis {
    /// The samples of `x` (the whole record) the diagnosis covers: its free runs and
    /// `split` count from the first of them.
    pub fn analysed<'a>(&self, x: &'a [f64]) -> &'a [f64] {
        &x[self.window.drive_on..self.window.end]
    }

    /// The window analysed, `[start, end]` in the record's time (s).
    pub fn window_s(&self) -> [f64; 2] {
        self.window.seconds(self.t0, self.ts)
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

    /// The JSON object of `boucwen diagnose --json` (every field is in the book,
    /// `docs/book/src/diagnosis/json-and-identify.md`):
    /// `drive_hz`, `window_s`, `window_why`, `drive`, `periods`, `noise_um`, `baseline
    /// {model, rms_um, fit_pct, stable}`, `findings [{kind, order (harmonics only), freq_hz,
    /// residual_share, cause, kept, term_rms_um}]` (most important first; kept terms before
    /// structure no term removed), `extended {…}`, `gain_pct`, `not_kept [{kind, order,
    /// freq_hz, round, gain_pct, reason}]`, the residual decomposition, every term tried
    /// (`trials [{round, kind, order, freq_hz, rms_um, term_rms_um, gain_pct, kept, reason}]`)
    /// and `resonance_hz` (null unless the record supports it) with `resonance_note`, and
    /// `drive_note` (null, or why a harmonic term the drive's own harmonic confounds was not
    /// kept).
    pub fn json(&self) -> serde_json::Value {
        use serde_json::json;
        let findings: Vec<serde_json::Value> = self.findings.iter().map(finding_json).collect();
        let model = |name: String, rms: f64, c: &ModelCheck| {
            let mut o = json!({
                "model": name,
                "rms_um": if c.unstable.is_none() { json!(rms) } else { json!(null) },
                "fit_pct": c.fit_pct,
                "stable": c.unstable.is_none(),
            });
            if let Some(why) = &c.unstable {
                o["unstable_reason"] = json!(why);
            }
            if let Some(why) = &c.narrow {
                o["narrow"] = json!(why);
            }
            o
        };
        let trial = |t: &Trial| {
            let mut o = json!({
                "round": t.round,
                "kind": t.candidate.kind.as_str(),
                "freq_hz": t.candidate.freq_hz,
                "rms_um": t.rms_um,
                "term_rms_um": t.term_rms_um,
                "gain_pct": t.gain_pct,
                "kept": t.kept,
                "reason": t.reason,
            });
            if let Some(n) = t.candidate.order {
                o["order"] = json!(n);
            }
            o
        };
        let r = &self.residual;
        json!({
            "drive_hz": self.drive_hz,
            "window_s": self.window_s(),
            "window_why": self.window.why,
            "drive": {
                "kind": self.drive.kind.as_str(),
                "freq_hz": self.drive.freq_hz,
                "thd_pct": 100.0 * self.drive.thd,
                "harmonics_rel": (1..=MAX_TERM_ORDER as usize).map(|k| self.drive.harmonic_rel(k)).collect::<Vec<_>>(),
            },
            "periods": {"fitted": self.periods.0, "held_out": self.periods.1},
            "noise_um": self.noise_um.0,
            "noise_method": self.noise_um.1,
            "baseline": model(self.baseline.name(), self.baseline_rms_um, &self.baseline_check),
            "findings": findings,
            "extended": model(self.model_name(), self.model_rms_um, &self.model_check),
            "delay": self.delay.as_ref().map(|d| json!({
                "samples": d.samples,
                "startup_rms_without_um": d.rms_without_um,
                "startup_rms_with_um": d.rms_with_um,
            })),
            "gain_pct": self.gain_pct(),
            "not_kept": self.not_kept().into_iter().map(|t| {
                let mut o = json!({
                    "kind": t.candidate.kind.as_str(),
                    "freq_hz": t.candidate.freq_hz,
                    "round": t.round,
                    "gain_pct": t.gain_pct,
                    "reason": t.reason,
                });
                if let Some(n) = t.candidate.order {
                    o["order"] = json!(n);
                }
                o
            }).collect::<Vec<_>>(),
            "residual": {
                "rms_um": r.rms_um,
                "periodic_rms_um": r.periodic_rms_um(),
                "trend_rms_um": r.trend_rms_um,
                "noise_rms_um": r.noise_rms_um,
                "above_harmonics_um": r.above_um,
                "harmonics_um": r.harmonics.iter().map(|h| h.amp).collect::<Vec<_>>(),
            },
            "trials": self.trials.iter().map(trial).collect::<Vec<_>>(),
            "resonance_hz": self.resonance_hz,
            "resonance_note": self.resonance_note,
            "drive_note": self.drive_note,
            "fit_samples": self.split - self.plan_skip(),
            "held_out_samples": self.baseline_sim.len() - self.split,
        })
    }

    /// First sample of the fitted part, counted from `window.drive_on`.
    fn plan_skip(&self) -> usize {
        self.window.start - self.window.drive_on
    }

    /// The terminal report: the window and the drive, the baseline and what it gets wrong,
    /// the findings with their evidence, the terms that gained but were not kept, and the
    /// extended model's gain.
    pub fn summary(&self, source: &str) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let n = self.baseline_sim.len();
        let r = &self.residual;
        let [w0, w1] = self.window_s();
        let fitted_s = (self.split - self.plan_skip()) as f64 * self.ts;
        let _ = writeln!(s, "{source}: drive {}, sampled every {} s", self.drive.describe(), self.ts);
        let _ = writeln!(s, "window {} to {} s: {}", fmt_s(w0), fmt_s(w1), self.window.why);
        let _ = writeln!(
            s,
            "fitted on {} periods ({} s), tested on the {} periods after them ({} s)",
            self.periods.0,
            fmt_s(fitted_s),
            self.periods.1,
            fmt_s((n - self.split) as f64 * self.ts),
        );
        let fit = |c: &ModelCheck| match (&c.unstable, c.fit_pct) {
            (Some(why), _) => format!("not stable: {why}"),
            (None, Some(f)) => format!("fit {f:.1} %"),
            (None, None) => "fit not measured".into(),
        };
        let _ = writeln!(
            s,
            "output fundamental {:.3} µm, noise floor {:.4} µm{}; baseline {} (free run): held-out RMS {:.4} µm, {}",
            self.output_amplitude_um,
            self.noise_um.0,
            if self.noise_um.1 == "quantisation" {
                " (the sensor's resolution: its steps' RMS error)"
            } else {
                ""
            },
            self.baseline.name(),
            self.baseline_rms_um,
            fit(&self.baseline_check),
        );
        match self.resonance_hz {
            Some(f) => {
                let _ = writeln!(s, "structure resonance {f:.1} Hz ({})", self.resonance_note);
            }
            None => {
                let _ = writeln!(s, "{}", self.resonance_note);
            }
        }
        if self.findings.first().is_some_and(|f| f.kind == Kind::OtherInput) {
            let _ = writeln!(s, "\nfinding: {}", self.findings[0].cause);
            return s;
        }
        let _ = writeln!(s, "\nwhat the baseline gets wrong (held-out residual, RMS {:.4} µm):", r.rms_um);
        let p = (r.rms_um * r.rms_um).max(1e-300);
        let pct = |x: f64| 100.0 * x * x / p;
        let _ = writeln!(
            s,
            "  periodic with the drive {:.4} µm ({:.0}% of the power), slow trend {:.4} µm ({:.0}%), noise {:.4} µm ({:.0}%)",
            r.periodic_rms_um(),
            pct(r.periodic_rms_um()),
            r.trend_rms_um,
            pct(r.trend_rms_um),
            r.noise_rms_um,
            pct(r.noise_rms_um),
        );
        if pct(r.above_um) >= 5.0 {
            let _ = writeln!(
                s,
                "  periodic above harmonic {} ({:.1} Hz): {:.4} µm ({:.0}% of the power), faster than the harmonics analysed (sharp corners, a converter's steps)",
                r.harmonics.len(),
                r.harmonics.last().map_or(0.0, |h| h.freq_hz),
                r.above_um,
                pct(r.above_um)
            );
        }
        let mut top: Vec<(usize, &Tone)> = r.harmonics.iter().enumerate().collect();
        top.sort_by(|a, b| b.1.amp.total_cmp(&a.1.amp));
        for (i, h) in top.iter().take(4) {
            let _ = writeln!(
                s,
                "  harmonic {:>2} ({:6.1} Hz): {:.4} µm peak, {:4.1}% of the residual power",
                i + 1,
                h.freq_hz,
                h.amp,
                100.0 * h.amp * h.amp / 2.0 / p
            );
        }
        let not_kept = self.not_kept();
        if self.findings.is_empty() && r.rms_um > crate::diagnose::periodic::NOISE_MULTIPLE * self.noise_um.0
        {
            // Not "the model accounts for the record": say what it misses.
            let top = r.harmonics.iter().enumerate().max_by(|a, b| a.1.amp.total_cmp(&b.1.amp));
            let parts = [
                (
                    r.above_um,
                    format!(
                        "periodic with the drive above its {} harmonic (faster than the model follows: sharp corners, a converter's steps)",
                        ordinal(r.harmonics.len() as u32)
                    ),
                ),
                (
                    top.map_or(0.0, |(_, h)| h.amp / std::f64::consts::SQRT_2),
                    top.map_or(String::new(), |(i, h)| {
                        format!("its {} harmonic at {:.1} Hz", ordinal(i as u32 + 1), h.freq_hz)
                    }),
                ),
                (r.trend_rms_um, "a slow trend".to_string()),
                (r.noise_rms_um, "what does not repeat with the drive".to_string()),
            ];
            let (rms, what) = parts.iter().max_by(|a, b| a.0.total_cmp(&b.0)).cloned().unwrap_or_default();
            let _ = writeln!(
                s,
                "\nfindings: none that can be named; the baseline leaves {:.4} µm held out, {:.0} times the noise floor, \
                 and no term tried removed it by enough to keep; most of it ({rms:.4} µm RMS) is {what}{}",
                r.rms_um,
                r.rms_um / self.noise_um.0.max(1e-300),
                if not_kept.is_empty() { "" } else { "; the terms below gained but were not kept" }
            );
        } else if self.findings.is_empty() {
            let _ = writeln!(
                s,
                "\nfindings: none; no term was kept (residual noise {:.4} µm of {:.4} µm){}",
                r.noise_rms_um,
                r.rms_um,
                if not_kept.is_empty() { "" } else { "; the terms below gained but were not kept" }
            );
        } else {
            let _ = writeln!(s, "\nfindings (most important first):");
            for (i, f) in self.findings.iter().enumerate() {
                let _ = writeln!(s, "  {}. {}", i + 1, f.cause);
            }
        }
        if !not_kept.is_empty() {
            let _ = writeln!(
                s,
                "\nterms that lowered the held-out RMS by {:.0}% or more but were not kept:",
                100.0 * Thresholds::default().min_gain
            );
            for t in not_kept {
                let _ = writeln!(
                    s,
                    "  - {} (round {}): {:.0}% lower, to {:.4} µm; {}",
                    describe_term(&t.candidate),
                    t.round,
                    t.gain_pct,
                    t.rms_um,
                    t.reason.as_deref().unwrap_or("")
                );
            }
        }
        if let Some(d) = &self.delay {
            let _ = writeln!(
                s,
                "\nthe output answers the step onto the drive {:.1} samples ({:.2} ms) late (the model fitted over the \
                 start-up: {:.4} µm without a delay, {:.4} µm with it)",
                d.samples,
                1e3 * d.samples * self.ts,
                d.rms_without_um,
                d.rms_with_um
            );
        }
        let _ = writeln!(
            s,
            "\nextended model: {} (free run): held-out RMS {:.4} µm, {}; {:.4} µm before: {:.1}% lower{}",
            self.model_name(),
            self.model_rms_um,
            fit(&self.model_check),
            self.baseline_rms_um,
            self.gain_pct(),
            if self.findings.iter().any(|f| f.kept) { "" } else { " (no term kept: the baseline stays)" }
        );
        if let Some(why) = &self.model_check.narrow {
            let _ = writeln!(s, "note: {why}");
        }
        s
    }
}

fn fmt_s(x: f64) -> String {
    let s = format!("{x:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

impl Residual {
    /// RMS of the part periodic with the drive (all harmonics measured, and what repeats
    /// above them).
    pub fn periodic_rms_um(&self) -> f64 {
        (self.harmonics.iter().map(|h| h.amp * h.amp / 2.0).sum::<f64>() + self.above_um * self.above_um)
            .sqrt()
    }
}

/// Why a diagnosis could not be made. Each is one sentence naming the rule applied and the
/// numbers.
#[derive(Debug)]
pub enum DiagnoseError {
    /// The input has no oscillating component to call a drive.
    NoDrive {
        /// Standard deviation of `u` (V).
        std_v: f64,
    },
    /// The drive is not a sine (for the sine analysis: [`diagnose_record`]).
    NotSine {
        /// The drive, described.
        drive: String,
    },
    /// The drive does not repeat (a chirp, noise): distortion cannot be told from noise.
    Aperiodic {
        /// The drive, described.
        drive: String,
    },
    /// The drive is a sine or none (for the periodic analysis: [`crate::diagnose::periodic`]).
    NotPeriodic {
        /// The drive, described.
        drive: String,
    },
    /// The records given as realisations of one drive are not.
    Realisations(String),
    /// No steady window, or `--window` outside the record.
    Window(WindowError),
    /// The output does not respond.
    NoResponse(NoResponse),
    /// Fewer than [`MIN_PERIODS`] whole periods of the drive in the steady window.
    TooFewPeriods {
        /// Drive frequency (Hz).
        drive_hz: f64,
        /// Whole periods in the window.
        periods: usize,
        /// The window (s).
        window_s: [f64; 2],
    },
    /// Fewer than [`MIN_SAMPLES`] samples in the steady window.
    TooFewSamples {
        /// Samples in the window.
        samples: usize,
        /// The window (s).
        window_s: [f64; 2],
    },
    /// The drive's harmonics cannot be analysed: its second harmonic is at or above Nyquist.
    DriveTooFast {
        /// Drive frequency found (Hz).
        drive_hz: f64,
        /// Nyquist frequency (Hz).
        nyquist_hz: f64,
    },
    /// The fitted baseline's loop does not close under this drive: its free run's mean
    /// moves from period to period (a Bouc–Wen loop can ratchet under a drive without
    /// half-wave symmetry), so what it gets wrong says nothing about the actuator.
    Ratchets {
        /// How far its mean moves over the held-out part (µm).
        moved_um: f64,
        /// The drive's own harmonic distortion (%).
        thd_pct: f64,
    },
    /// The fit failed.
    Fit(FitError),
}

/// Fewest samples of the steady window to diagnose or identify: the fit and the held-out
/// test each need some hundreds.
pub const MIN_SAMPLES: usize = 400;

/// Fewest whole drive periods in the steady window: half of them (rounded up) are fitted,
/// the rest held out.
pub const MIN_PERIODS: usize = 4;

impl std::fmt::Display for DiagnoseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let span = |w: &[f64; 2]| format!("{:.3}–{:.3} s", w[0], w[1]);
        match self {
            DiagnoseError::NoDrive { std_v } => write!(
                f,
                "the input u does not vary (standard deviation {std_v:.2e} V): there is no drive to analyse"
            ),
            DiagnoseError::NotSine { drive } => write!(
                f,
                "the drive is {drive}; the sine analysis takes a sine drive (a periodic or multisine drive has its own \
                 analysis, boucwen diagnose chooses it)"
            ),
            DiagnoseError::Aperiodic { drive } => write!(
                f,
                "the drive is {drive}; diagnose needs a drive that repeats (a sine, a triangle or square, a multisine) \
                 to tell distortion from noise over whole periods (boucwen identify fits a model to any drive)"
            ),
            DiagnoseError::NotPeriodic { drive } => write!(
                f,
                "the drive is {drive}; the periodic analysis takes a periodic drive that is not a sine, or a multisine"
            ),
            DiagnoseError::Realisations(why) => write!(f, "{why}"),
            DiagnoseError::Window(e) => write!(f, "{e}"),
            DiagnoseError::NoResponse(e) => write!(f, "{e}"),
            DiagnoseError::TooFewPeriods { drive_hz, periods, window_s } => write!(
                f,
                "the steady window {} holds {periods} whole periods of the {drive_hz:.3} Hz drive; diagnose needs at \
                 least {MIN_PERIODS} (half fitted, half held out): record more periods",
                span(window_s)
            ),
            DiagnoseError::TooFewSamples { samples, window_s } => write!(
                f,
                "the steady window {} holds {samples} samples; diagnose needs at least {MIN_SAMPLES}: record longer \
                 or sample faster",
                span(window_s)
            ),
            DiagnoseError::DriveTooFast { drive_hz, nyquist_hz } => write!(
                f,
                "the drive ({drive_hz:.1} Hz) is above half the Nyquist frequency ({nyquist_hz:.1} Hz): \
                 no harmonic of it can be seen"
            ),
            DiagnoseError::Ratchets { moved_um, thd_pct } => write!(
                f,
                "the fitted extended model does not close its loop under this drive: its free run's mean moves by \
                 {moved_um:.3} µm over the held-out part (the Bouc–Wen loop ratchets; the drive's own distortion is \
                 {thd_pct:.2} %), so no diagnosis is made on top of it"
            ),
            DiagnoseError::Fit(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for DiagnoseError {}

impl From<crate::model::ModelError> for DiagnoseError {
    fn from(e: crate::model::ModelError) -> Self {
        DiagnoseError::Fit(e.into())
    }
}

impl From<FitError> for DiagnoseError {
    fn from(e: FitError) -> Self {
        DiagnoseError::Fit(e)
    }
}

/// The resonance of an AR(2) structure: the pole angle, if the poles are complex.
pub fn resonance_hz(ar: [f64; 2], ts: f64) -> Option<f64> {
    let (a1, a2) = (ar[0], ar[1]);
    // z² - a1 z - a2 = 0: complex when a1² + 4 a2 < 0.
    let disc = a1 * a1 + 4.0 * a2;
    if disc >= 0.0 || a2 >= 0.0 {
        return None;
    }
    let r = (-a2).sqrt();
    let c = (a1 / (2.0 * r)).clamp(-1.0, 1.0);
    Some(c.acos() / (TAU * ts))
}

/// Highest harmonic order analysed.
pub const MAX_ORDER: usize = 40;

/// Splits a held-out residual into harmonics of `f`, a slow trend and noise.
pub fn decompose(r: &[f64], f: f64, ts: f64) -> Residual {
    let n = analysis::whole_periods(r.len(), f, ts);
    let r = &r[..n];
    let kmax = ((0.5 / ts) / f).ceil() as usize;
    let harmonics = analysis::harmonics(r, f, ts, kmax.clamp(1, MAX_ORDER));
    // Remove the harmonics, then fit a cubic trend to what is left.
    let mut rest: Vec<f64> = r.to_vec();
    for h in &harmonics {
        // amp·sin(wk + phase) by a rotating phasor, re-anchored every 1024 samples.
        let w = TAU * h.freq_hz * ts;
        let (dw_s, dw_c) = w.sin_cos();
        let (mut s, mut c) = (0.0f64, 1.0f64);
        for (k, v) in rest.iter_mut().enumerate() {
            if k % 1024 == 0 {
                (s, c) = (w * k as f64 + h.phase).sin_cos();
            }
            *v -= h.amp * s;
            (s, c) = (s * dw_c + c * dw_s, c * dw_c - s * dw_s);
        }
    }
    let (trend, slope) = poly_fit(&rest, ts, 3);
    let mut noise: Vec<f64> = rest.iter().zip(&trend).map(|(a, b)| a - b).collect();
    // Over whole-sample periods, what still repeats is periodic too, above the harmonics.
    let mut above_um = 0.0;
    if let Some(p) = analysis::whole_sample_period(f, ts, n) {
        let (avg, m) = analysis::average_period(&noise, p);
        // The average of m periods holds 1/m of the noise's power: it counts when it holds
        // twice that.
        let (avg_power, noise_share) =
            (analysis::rms(&avg).powi(2), analysis::rms(&noise).powi(2) / m as f64);
        if avg_power > 2.0 * noise_share {
            above_um = (avg_power - noise_share).sqrt();
            for (k, v) in noise.iter_mut().enumerate().take(m * p) {
                *v -= avg[k % p];
            }
            // The deviation from a mean of m periods underestimates by √((m−1)/m).
            let scale = (m as f64 / (m as f64 - 1.0)).sqrt();
            noise.iter_mut().for_each(|v| *v *= scale);
        }
    }
    Residual {
        rms_um: analysis::rms(r),
        harmonics,
        trend_rms_um: analysis::rms(&trend),
        trend_mean_um: analysis::mean(&trend),
        trend_slope_um_per_s: slope,
        noise_rms_um: analysis::rms(&noise),
        above_um,
    }
}

/// Least-squares polynomial of `degree` in time (scaled to [-1, 1]); returns the fitted
/// values and the slope of the linear part in units per second.
fn poly_fit(x: &[f64], ts: f64, degree: usize) -> (Vec<f64>, f64) {
    let n = x.len();
    if n < degree + 2 {
        return (vec![analysis::mean(x); n], 0.0);
    }
    let half = (n - 1) as f64 / 2.0;
    let tau = |k: usize| (k as f64 - half) / half.max(1.0);
    let m = degree + 1;
    let mut ata = nalgebra::DMatrix::<f64>::zeros(m, m);
    let mut atb = nalgebra::DVector::<f64>::zeros(m);
    let mut p = vec![1.0; m];
    for (k, &v) in x.iter().enumerate() {
        let t = tau(k);
        for i in 1..m {
            p[i] = p[i - 1] * t;
        }
        for i in 0..m {
            atb[i] += p[i] * v;
            for j in 0..m {
                ata[(i, j)] += p[i] * p[j];
            }
        }
    }
    let Some(c) = ata.cholesky().map(|ch| ch.solve(&atb)) else {
        return (vec![analysis::mean(x); n], 0.0);
    };
    let fitted = (0..n).map(|k| (0..m).rev().fold(0.0, |acc, i| acc * tau(k) + c[i])).collect();
    (fitted, c[1] / (half * ts))
}

/// A candidate term.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// What it would model.
    pub kind: Kind,
    /// Harmonic order (harmonics only).
    pub order: Option<u32>,
    /// Frequency (Hz; 0 for drift).
    pub freq_hz: f64,
    /// Its share of the baseline's held-out residual power (from [`decompose`]).
    pub share: f64,
    /// Its amplitude in the baseline's residual (µm; harmonic peak or trend RMS).
    pub amp: f64,
    /// How much of the record it accounts for (µm RMS): a harmonic's RMS in the output, the
    /// trend's RMS in the baseline's residual. What orders the terms that would be kept:
    /// the extended model can imitate one harmonic with its own loop and then needs a branch
    /// to cancel what its loop does elsewhere, a branch that carries much in the model but
    /// stands for little in the record.
    pub evidence_um: f64,
    /// A saturation of the output: the range `[lo, hi]` (µm) its plateaus show (`None`: of
    /// the drive, or not a saturation).
    pub output_range: Option<[f64; 2]>,
}

/// One term tried in one round of the forward selection.
#[derive(Clone, Debug, PartialEq)]
pub struct Trial {
    /// Round (0: added to the baseline).
    pub round: usize,
    /// The term.
    pub candidate: Candidate,
    /// Held-out RMS with it (µm).
    pub rms_um: f64,
    /// What the term carries in that model (µm, see [`Finding::term_rms_um`]).
    pub term_rms_um: f64,
    /// How much it lowered the held-out RMS of the round's model (%).
    pub gain_pct: f64,
    /// Whether this trial's term was kept.
    pub kept: bool,
    /// Why a trial that gained at least [`Thresholds::min_gain`] was not kept.
    pub reason: Option<String>,
}

/// A trend is a candidate, and a drift line qualifies, when it carries this many times the
/// RMS of the baseline residual's noise, even if that is less than
/// [`Thresholds::min_candidate_rel`] or [`Thresholds::min_term_rel`] of the output: a trend
/// does not grow with the drive, and over a few periods a real drift is small beside the
/// output. On the messy batch (`cargo bench --bench diagnose_messy -- --per-mess 24`) the
/// held-out trend of the 60 clean records stayed under 0.6 times the noise, that of the 24
/// drift records was 1.9 times it or more (few periods of a slow drive) and up to 67 times.
pub const DRIFT_NOISE_FACTOR: f64 = 1.5;

/// A harmonic is "near" a fitted resonance within this fraction of the higher of the two.
pub const NEAR_RESONANCE: f64 = 0.15;

/// Levenberg–Marquardt starts of the fit of each term.
pub const TERM_STARTS: usize = 5;

/// Highest harmonic order tried as a term.
pub const MAX_TERM_ORDER: u32 = 9;

/// The fit settings of the diagnosis: the loop need not be invertible (the model explains a
/// record, it is not used to compensate).
///
/// The criterion covers the whole first half but its first fifth (at most
/// [`MAX_SKIP_S`]): the record starts from rest (or from wherever the actuator was), and the
/// start-up transient of a lightly damped resonance is not what the diagnosis is about.
/// Under a periodic drive the fit separates a trend and averages the periods of that part
/// first ([`Averaging::PeriodsAndTrend`]), so its cost does not grow with the record; the
/// trend is the drift term's to explain.
pub fn fit_options(split: usize, ts: f64) -> OeOptions {
    let skip = (split / 5).min((MAX_SKIP_S / ts) as usize).max(OeOptions::default().skip);
    OeOptions {
        require_invertible: false,
        skip,
        averaging: Averaging::PeriodsAndTrend,
        ..OeOptions::default()
    }
}

/// Longest start-up left out of the fit criterion (s).
pub const MAX_SKIP_S: f64 = 1.0;

/// Diagnoses a record: `u` (V), `y` (µm), sample interval `ts` (s), its first sample at
/// `t = 0`, in its steady window.
pub fn diagnose(u: &[f64], y: &[f64], ts: f64, th: &Thresholds) -> Result<Diagnosis, DiagnoseError> {
    diagnose_record(u, y, ts, 0.0, None, th)
}

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

/// Plans the diagnosis of a record (see [`Plan`]): finds the steady window (or takes
/// `given`, in samples), the drive, checks that the output responds, that the drive is a
/// sine, and that the window holds [`MIN_PERIODS`] whole periods and [`MIN_SAMPLES`]
/// samples. Every refusal is one sentence with the rule and the numbers.
pub fn plan(
    u: &[f64],
    y: &[f64],
    ts: f64,
    t0: f64,
    given: Option<(usize, usize)>,
) -> Result<Plan, DiagnoseError> {
    let (window, drive) = steady::steady_window(u, y, ts, given).map_err(DiagnoseError::Window)?;
    plan_in(u, y, ts, t0, window, drive)
}

/// [`plan`] in a steady window already found (by [`steady::steady_window`] on `u`, `y`).
pub fn plan_in(
    u: &[f64],
    y: &[f64],
    ts: f64,
    t0: f64,
    window: Window,
    drive: Drive,
) -> Result<Plan, DiagnoseError> {
    let window_s = window.seconds(t0, ts);
    if drive.kind == DriveKind::None {
        return Err(DiagnoseError::NoDrive { std_v: drive.std_v });
    }
    let (start, end) = (window.start, window.end);
    steady::check_response(&u[start..end], &y[start..end], ts, &drive).map_err(DiagnoseError::NoResponse)?;
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
    let periods = ((samples as f64 + 0.5) / p).floor() as usize;
    if periods < MIN_PERIODS {
        return Err(DiagnoseError::TooFewPeriods { drive_hz, periods, window_s });
    }
    if samples < MIN_SAMPLES {
        return Err(DiagnoseError::TooFewSamples { samples, window_s });
    }
    let p_fit = periods.div_ceil(2);
    let split = start + (p_fit as f64 * p).round() as usize - window.drive_on;
    let start_rel = start - window.drive_on;
    let mut opt = OeOptions { lm_starts: TERM_STARTS, ..fit_options(split, ts) };
    opt.skip = start_rel.max(opt.skip.min(split.saturating_sub(FIT_MIN_SAMPLES)));
    Ok(Plan { window, drive, split, periods: (p_fit, periods - p_fit), opt, t0, from_rest: true })
}

/// Fewest samples in the fit's criterion.
pub const FIT_MIN_SAMPLES: usize = 200;

/// Diagnoses a record whose first sample is at `t0` (s), in its steady window or in `given`
/// (samples): [`plan`], then [`diagnose_planned`].
pub fn diagnose_record(
    u: &[f64],
    y: &[f64],
    ts: f64,
    t0: f64,
    given: Option<(usize, usize)>,
    th: &Thresholds,
) -> Result<Diagnosis, DiagnoseError> {
    let n = u.len().min(y.len());
    let plan = plan(&u[..n], &y[..n], ts, t0, given)?;
    diagnose_planned(&u[..n], &y[..n], ts, &plan, th)
}

/// Diagnoses a record as planned.
pub fn diagnose_planned(
    u: &[f64],
    y: &[f64],
    ts: f64,
    plan: &Plan,
    th: &Thresholds,
) -> Result<Diagnosis, DiagnoseError> {
    let w = &plan.window;
    diagnose_from(&u[w.drive_on..w.end], &y[w.drive_on..w.end], ts, plan, th, &[], 0)
}

/// Most times the baseline is refitted from a better structure a term's fit found.
pub const MAX_BASELINE_REFITS: usize = 2;
/// The baseline is refitted when the first round's winner, its term removed and refitted,
/// lowers the baseline's held-out RMS by at least this fraction.
pub const BASELINE_REFIT_GAIN: f64 = 0.05;

/// [`diagnose_planned`] on the window's samples (`u`, `y` from `drive_on`) with extra start
/// models for the baseline; `depth` counts refits.
///
/// A term's fit searches structures again and may find one the baseline's fit missed (a
/// local minimum). The first round's winner is then checked: with its term removed and the
/// baseline refitted from it, if the baseline alone gains [`BASELINE_REFIT_GAIN`], the
/// whole diagnosis restarts from that better baseline, so a term is credited only with
/// what the baseline cannot do.
fn diagnose_from(
    u: &[f64],
    y: &[f64],
    ts: f64,
    plan: &Plan,
    th: &Thresholds,
    starts: &[HostModel],
    depth: usize,
) -> Result<Diagnosis, DiagnoseError> {
    let drive_hz = plan.drive.freq_hz;
    let split = plan.split;
    let opt = plan.opt.clone();
    // The baseline carries an output offset: a sensor's zero is arbitrary.
    let spec = ModelSpec { drift_degree: Some(0), ..ModelSpec::extended(drive_hz) };
    // The fitted half's average periods, computed once for all fits (with a trend for the
    // drift term's).
    let data = FitData::new(u, y, ts, split);
    data.prepare(&spec, &opt);
    data.prepare(&ModelSpec { drift_degree: Some(1), ..spec.clone() }, &opt);
    let baseline = fit::fit_oe_on(&data, &spec, starts, &opt)?.model;
    let baseline_sim = baseline.simulate(u, ts)?;
    let held_out =
        |sim: &[f64]| -> Vec<f64> { y[split..].iter().zip(&sim[split..]).map(|(a, b)| a - b).collect() };
    let period = plan.drive.period_samples;
    if let (Some(sim_moves), Some(y_moves)) =
        (ratchet_um(&baseline_sim[split..], period), ratchet_um(&y[split..], period))
    {
        // A loop that ratchets to follow a drift of the output is the drift's business.
        let amp = analysis::harmonics(&y[split..], drive_hz, ts, 1).first().map_or(0.0, |t| t.amp);
        // Only a drive with distortion of its own (no half-wave symmetry) is known to make
        // the fitted loop ratchet; a slow settling of the loop after a step is not refused.
        let distorted = plan.drive.thd >= DRIVE_DISTORTION_FLOOR;
        if distorted
            && sim_moves.abs() > RATCHET_REL * amp
            && (sim_moves - y_moves).abs() > 0.5 * sim_moves.abs()
        {
            return Err(DiagnoseError::Ratchets {
                moved_um: sim_moves.abs(),
                thd_pct: 100.0 * plan.drive.thd,
            });
        }
    }
    if plan.drive.thd >= DRIVE_DISTORTION_FLOOR && depth == 0 {
        // Under a drive with distortion of its own, the averaged fit keeps only loops that
        // close over the average period; the loop that fits the samples best may ratchet
        // instead. Fitted sample by sample from the baseline, if that loop fits the fitted
        // half clearly better and its free run ratchets over the held-out half, no loop
        // both fits and closes: the baseline's errors then say nothing about the actuator.
        let off = OeOptions { averaging: Averaging::Off, ..opt.clone() };
        if let Ok(f) = fit::fit_oe_on(&data, &spec, std::slice::from_ref(&baseline), &off) {
            let sim = f.model.simulate(u, ts)?;
            let fitted_rms = |s: &[f64]| {
                let e: Vec<f64> = y[..split].iter().zip(&s[..split]).map(|(a, b)| a - b).collect();
                analysis::rms(&e)
            };
            let better = fitted_rms(&sim) < 0.5 * fitted_rms(&baseline_sim);
            if let (true, Some(moves)) = (better, ratchet_um(&sim[split..], period)) {
                let amp = analysis::harmonics(&y[split..], drive_hz, ts, 1).first().map_or(0.0, |t| t.amp);
                let y_moves = ratchet_um(&y[split..], period).unwrap_or(0.0);
                if moves.abs() > RATCHET_REL * amp && (moves - y_moves).abs() > 0.5 * moves.abs() {
                    return Err(DiagnoseError::Ratchets {
                        moved_um: moves.abs(),
                        thd_pct: 100.0 * plan.drive.thd,
                    });
                }
            }
        }
    }
    let baseline_check = ModelCheck::of(&baseline, &baseline_sim[split..], &y[split..], ts);
    if baseline_check.unstable.is_some() {
        return Err(DiagnoseError::Fit(FitError::NoStableModel));
    }
    let resid = held_out(&baseline_sim);
    let baseline_rms_um = analysis::rms(&resid);
    let residual = decompose(&resid, drive_hz, ts);
    let output_amplitude_um =
        analysis::harmonics(&y[split..], drive_hz, ts, 1).first().map_or(0.0, |t| t.amp);
    let res_hz = resonance_hz(baseline.ext.ar, ts);
    let out_rms = output_amplitude_um / std::f64::consts::SQRT_2;
    let out_harmonics = analysis::harmonics(&y[split..], drive_hz, ts, MAX_TERM_ORDER as usize);
    let noise_um = steady::noise_floor(&y[split..], ts, &plan.drive);
    let base = Diagnosis {
        drive_hz,
        ts,
        split,
        baseline: baseline.clone(),
        baseline_rms_um,
        baseline_sim: baseline_sim.clone(),
        residual: residual.clone(),
        resonance_hz: None,
        findings: vec![],
        trials: vec![],
        model: baseline.clone(),
        terms: Terms::default(),
        delay: None,
        model_rms_um: baseline_rms_um,
        model_sim: baseline_sim.clone(),
        model_residual: residual.clone(),
        output_amplitude_um,
        window: plan.window.clone(),
        drive: plan.drive.clone(),
        t0: plan.t0,
        periods: plan.periods,
        baseline_check: baseline_check.clone(),
        model_check: baseline_check.clone(),
        noise_um,
        resonance_note: String::new(),
        drive_note: None,
    };
    // The drive explains too little: another input drives the output. No harmonic
    // diagnosis on top of it.
    let fit = baseline_check.fit_pct.unwrap_or(f64::NAN);
    if fit.is_nan() || fit < MIN_FIT_PCT {
        let cause = format!(
            "another input or a disturbance drives the output: the baseline explains only {fit:.1} % of the held-out \
             output (fit), less than {MIN_FIT_PCT:.0} %; a second actuator or signal, vibration, or a thermal or \
             sensor effect the record does not carry. No harmonic diagnosis is made on top of it"
        );
        let finding = Finding {
            kind: Kind::OtherInput,
            order: None,
            freq_hz: 0.0,
            residual_share: 1.0,
            amplitude_um: residual.rms_um,
            output_rel: 0.0,
            cause,
            kept: false,
            rms_with_term_um: f64::NAN,
            term_rms_um: residual.rms_um,
            level: None,
            band_hz: None,
            drive_within_range_v: None,
        };
        let note =
            "the structure's resonance is not reported: the model explains too little of the output".into();
        return Ok(Diagnosis { findings: vec![finding], resonance_note: note, ..base });
    }
    // What the drive's own harmonics account for in the output: the baseline's response to
    // them (its free run with the drive's harmonics minus without).
    let drive_part = drive_harmonic_part(&baseline, u, &baseline_sim, ts, split, &plan.drive)?;
    let evidence: Vec<Tone> = out_harmonics
        .iter()
        .enumerate()
        .map(|(i, t)| match drive_part.get(i) {
            Some(d) if i > 0 => {
                let (a, b) = (
                    t.amp * t.phase.cos() - d.amp * d.phase.cos(),
                    t.amp * t.phase.sin() - d.amp * d.phase.sin(),
                );
                Tone { freq_hz: t.freq_hz, amp: (a * a + b * b).sqrt(), phase: b.atan2(a) }
            }
            _ => *t,
        })
        .collect();

    // What a term must carry: `min_term_rel` of the output, or for a drift, which does not
    // scale with the drive, DRIFT_NOISE_FACTOR times the residual's noise if that is less.
    let min_term = |c: &Candidate| {
        let t = th.min_term_rel * out_rms;
        if matches!(c.kind, Kind::Drift | Kind::Creep) {
            t.min(DRIFT_NOISE_FACTOR * residual.noise_rms_um)
        } else {
            t
        }
    };
    // A harmonic the drive itself carries enough of to account (through the baseline) for
    // DRIVE_SHARE_MAX of the output's harmonic of that order: its share.
    let drive_share = |c: &Candidate| -> Option<f64> {
        let i = c.order? as usize - 1;
        // Only at an order the drive itself carries: its other harmonics' mixing products
        // through the model are the model's business (a resonance the baseline bends onto a
        // hidden 5th harmonic amplifies the mixing of the drive's 2nd and 3rd there).
        if !matches!(c.kind, Kind::OddHarmonic | Kind::EvenHarmonic)
            || i == 0
            || plan.drive.harmonic_rel(i + 1) < DRIVE_DISTORTION_FLOOR
        {
            return None;
        }
        let (d, o) = (drive_part.get(i)?.amp, out_harmonics.get(i)?.amp);
        let share = d / o.max(1e-300);
        (share >= DRIVE_SHARE_MAX).then_some(share)
    };
    let mut drive_note = None;
    // Forward selection of terms.
    // A trend is a candidate by the same measure as a term: `min_candidate_rel` of the output,
    // or DRIFT_NOISE_FACTOR times the residual's noise if that is less (a drift does not scale
    // with the drive, and over a few periods it is small beside the output).
    let floor = th.min_candidate_rel * out_rms;
    let drift_floor = floor.min(DRIFT_NOISE_FACTOR * residual.noise_rms_um);
    let mut remaining = candidates(&residual, &evidence, drive_hz, ts, floor, drift_floor);
    let steady_y = &y[(plan.window.start - plan.window.drive_on).min(y.len())..];
    let drive_amp = plan.drive.harmonics.first().map_or(0.0, |t| t.amp);
    remaining.extend(causes::candidates(
        &residual,
        &out_harmonics,
        steady_y,
        noise_um.0,
        (u, drive_amp),
        (baseline.ext.ar, ts),
    ));
    let mut model = TermModel::from(baseline.clone());
    let mut model_rms = baseline_rms_um;
    let mut kept: Vec<(Candidate, f64, f64)> = vec![];
    let mut trials = vec![];
    // Each candidate's model of the last round: a second start for it in the next one.
    let mut previous: Vec<(Candidate, TermModel)> = vec![];
    for round in 0.. {
        // Every term, refitted with a search over structures and loop shapes and from the
        // current model (in parallel).
        let tried: Vec<(usize, TermModel, f64, f64)> = remaining
            .par_iter()
            .enumerate()
            .filter_map(|(i, c)| {
                let prev = previous.iter().find(|(p, _)| p == c).map(|(_, m)| m);
                let m = try_term(&model, c, prev, &data, u, y, ts, split, &opt)?;
                let sim = m.simulate(u, ts).ok()?;
                if instability(m.host.ext.ar, &sim, ts).is_some() {
                    return None;
                }
                let rms = analysis::rms_diff(&sim[split..], &y[split..]);
                let term = term_rms(&m, c, u, ts, split).ok()?;
                (rms.is_finite() && term.is_finite()).then_some((i, m, rms, term))
            })
            .collect();
        let first_trial = trials.len();
        trials.extend(tried.iter().map(|(i, _, rms, term)| Trial {
            round,
            candidate: remaining[*i],
            rms_um: *rms,
            term_rms_um: *term,
            gain_pct: 100.0 * (1.0 - rms / model_rms.max(1e-300)),
            kept: false,
            reason: None,
        }));
        // Of the harmonic and drift terms that would be kept, the one with the most evidence
        // in the record; a saturation or creep term that would be kept replaces it when it
        // lowers the held-out RMS further (a clamped drive explains a whole series of
        // harmonics, creep a trend that is not a line).
        let gains = |t: &(usize, TermModel, f64, f64)| t.2 <= model_rms * (1.0 - th.min_gain);
        let carries = |t: &(usize, TermModel, f64, f64)| gains(t) && t.3 >= min_term(&remaining[t.0]);
        let qualifies =
            |t: &(usize, TermModel, f64, f64)| carries(t) && drive_share(&remaining[t.0]).is_none();
        let physical = |c: &Candidate| matches!(c.kind, Kind::Saturation | Kind::Creep);
        let by_evidence = tried
            .iter()
            .enumerate()
            .filter(|(_, t)| qualifies(t) && !physical(&remaining[t.0]))
            .max_by(|a, b| remaining[a.1.0].evidence_um.total_cmp(&remaining[b.1.0].evidence_um))
            .map(|(pos, _)| pos);
        // An output that sits on plateaus is clipped where it is measured: its clamp, when it
        // qualifies, goes before a clamp of the drive (which the structure would smooth).
        let plateau = |c: &Candidate| c.output_range.is_some();
        let by_rms = tried
            .iter()
            .enumerate()
            .filter(|(_, t)| qualifies(t) && physical(&remaining[t.0]))
            .min_by(|a, b| {
                plateau(&remaining[b.1.0]).cmp(&plateau(&remaining[a.1.0])).then(a.1.2.total_cmp(&b.1.2))
            })
            .map(|(pos, _)| pos);
        let winner = match (by_evidence, by_rms) {
            (Some(e), Some(r)) if tried[r].2 < tried[e].2 => Some(r),
            (Some(e), _) => Some(e),
            (None, r) => r,
        };
        // Why each term that gained enough is not kept this round.
        for (pos, t) in tried.iter().enumerate() {
            if !gains(t) || Some(pos) == winner {
                continue;
            }
            let c = &remaining[t.0];
            let need = min_term(c);
            let reason = if let (true, Some(share)) = (carries(t), drive_share(c)) {
                let n = c.order.unwrap_or(0);
                let why = format!(
                    "the drive itself carries {:.2}% at the {} harmonic, which accounts (through the baseline) for {:.0}% \
                     of the output's {} harmonic: a {} harmonic branch would lower the held-out RMS by {:.0}%, but this \
                     record cannot tell a harmonic of the actuator from its response to the drive's own (a purer drive \
                     would: one under {:.1}% at the {} harmonic, where the diagnosis leaves the drive's harmonics out)",
                    100.0 * plan.drive.harmonic_rel(n as usize),
                    ordinal(n),
                    100.0 * share,
                    ordinal(n),
                    ordinal(n),
                    100.0 * (1.0 - t.2 / model_rms.max(1e-300)),
                    100.0 * DRIVE_DISTORTION_FLOOR,
                    ordinal(n),
                );
                drive_note.get_or_insert_with(|| why.clone());
                why
            } else if t.3 < need {
                format!(
                    "its term carries only {:.4} µm in the model, less than the {need:.4} µm a term must carry ({:.0} % \
                     of the output's fundamental RMS{})",
                    t.3,
                    100.0 * th.min_term_rel,
                    if matches!(c.kind, Kind::Drift | Kind::Creep) {
                        format!(", or {DRIFT_NOISE_FACTOR} times the residual's noise")
                    } else {
                        String::new()
                    }
                )
            } else if let Some(w) = winner {
                let wc = &remaining[tried[w].0];
                if physical(wc) || physical(c) {
                    format!(
                        "the {} lowered the held-out RMS further ({:.4} µm against {:.4} µm) and was kept in round \
                         {round}",
                        describe_term(wc),
                        tried[w].2,
                        t.2
                    )
                } else {
                    format!(
                        "the {} had more evidence in the record ({:.4} µm against {:.4} µm) and was kept in round \
                         {round}",
                        describe_term(wc),
                        wc.evidence_um,
                        c.evidence_um
                    )
                }
            } else {
                continue;
            };
            trials[first_trial + pos].reason = Some(reason);
        }
        let Some(pos) = winner else {
            break;
        };
        previous = tried.iter().map(|(i, m, _, _)| (remaining[*i], m.clone())).collect();
        let Some((i, m, rms, term)) = tried.into_iter().nth(pos) else { break };
        if round == 0 && depth < MAX_BASELINE_REFITS {
            let stripped = without(&m, &remaining[i]).host;
            let refit = fit::fit_oe_on(&data, &spec, &[stripped], &opt).map(|f| f.model);
            if let Ok(b) = refit {
                if fit::free_run_rms(&b, u, y, ts, split)
                    .is_ok_and(|r| r < baseline_rms_um * (1.0 - BASELINE_REFIT_GAIN))
                {
                    return diagnose_from(u, y, ts, plan, th, &[b], depth + 1);
                }
            }
        }
        trials[first_trial + pos].kept = true;
        kept.push((remaining.remove(i), rms, term));
        model = m;
        model_rms = rms;
        // A clamp of the drive acts before everything else (the loop, the structure, the
        // branches) and is tried against the baseline only: added after another term, whose
        // model was fitted without it, it reshapes the loop to imitate what that term's form
        // leaves (the default actuator at 23 Hz, `docs/book/src/figures/diagnose-23hz`: a clamp
        // at 75 % of the drive's peak lowers the held-out RMS of the model with the 3rd
        // harmonic's branch by 31 %, a saturation the actuator does not have).
        remaining.retain(|c| !(c.kind == Kind::Saturation && c.output_range.is_none()));
    }
    // The delay, from the step onto the drive: a record that holds the step (an idle part
    // before it, or a drive starting from 0 V) and a start-up after it.
    let holds_step = plan.from_rest
        && plan.window.start > plan.window.drive_on
        && (plan.window.drive_on > 0 || u.first().is_some_and(|u0| u0.abs() <= STEP_FROM_REST * drive_amp));
    let mut delay = None;
    let mut delay_finding = None;
    if holds_step {
        if let Some(scan) = causes::delay_scan(&model, &causes::spec_of(&model.host), u, y, ts, split, &opt) {
            let est = DelayEstimate {
                samples: scan.samples,
                rms_without_um: scan.rms_without_um,
                rms_with_um: scan.rms_with_um,
            };
            delay = Some(est);
            let gain = 1.0 - scan.rms_with_um / scan.rms_without_um.max(1e-300);
            if scan.samples >= causes::MIN_DELAY_SAMPLES && gain >= th.min_gain {
                // The extended model with the delay, fitted on the usual criterion; kept if its
                // held-out error is no worse than without.
                let mut dm = model.clone();
                dm.terms.extra_delay = scan.model.terms.extra_delay;
                dm.host.delay = scan.model.host.delay;
                let with = causes::fit_host(&dm, &causes::spec_of(&dm.host), u, y, ts, split, &opt)
                    .ok()
                    .and_then(|(m, _)| {
                        let sim = m.simulate(u, ts).ok()?;
                        let r = analysis::rms_diff(&sim[split..], &y[split..]);
                        (instability(m.host.ext.ar, &sim, ts).is_none() && r.is_finite()).then_some((m, r))
                    });
                let kept_delay =
                    with.as_ref().is_some_and(|(_, r)| *r <= model_rms * causes::DELAY_HELD_OUT_SLACK);
                let held_out_before = model_rms;
                if let (true, Some((m, r))) = (kept_delay, with) {
                    model = m;
                    model_rms = r;
                }
                let before = scan.rms_without_um;
                delay_finding = Some(Finding {
                    kind: Kind::InputDelay,
                    order: None,
                    freq_hz: 0.0,
                    residual_share: ((before * before - scan.rms_with_um * scan.rms_with_um)
                        / (before * before).max(1e-300))
                    .clamp(0.0, 1.0),
                    amplitude_um: scan.change_rms_um,
                    output_rel: 0.0,
                    cause: causes::explain_delay(&scan, ts, held_out_before, kept_delay.then_some(model_rms)),
                    kept: kept_delay,
                    rms_with_term_um: if kept_delay { model_rms } else { f64::NAN },
                    term_rms_um: scan.change_rms_um,
                    level: Some((scan.samples, "samples")),
                    band_hz: None,
                    drive_within_range_v: None,
                });
            }
        }
    }
    let model_sim = model.simulate(u, ts)?;
    let model_residual = decompose(&held_out(&model_sim), drive_hz, ts);
    let final_res = resonance_hz(model.host.ext.ar, ts);
    // Importance: what each term carries in the final model.
    let mut findings: Vec<Finding> = vec![];
    let mut prev_rms = baseline_rms_um;
    for (i, &(c, rms, _)) in kept.iter().enumerate() {
        let term = term_rms(&model, &c, u, ts, split)?;
        let explained = (prev_rms * prev_rms - rms * rms) / (baseline_rms_um * baseline_rms_um).max(1e-300);
        let step = Step { before_um: prev_rms, after_um: rms, first: i == 0 };
        prev_rms = rms;
        let within = (c.kind == Kind::Saturation && c.output_range.is_some())
            .then(|| causes::drive_within_range(&model, u, ts, plan.window.start))
            .flatten()
            .map(|k| (k, drive_amp));
        let (cause, level) = match c.kind {
            Kind::Saturation => causes::explain_saturation(
                &model.terms,
                &c,
                &step.describe(&describe_term(&c)),
                &out_harmonics,
                steady_y,
                noise_um.0,
                within,
            ),
            Kind::Creep => {
                (causes::explain_creep(&model.terms, &residual, &step.describe("creep states")), None)
            }
            _ => (
                explain(
                    &c,
                    step,
                    &out_harmonics,
                    output_amplitude_um,
                    &[final_res, res_hz],
                    &residual,
                    (
                        plan.drive.harmonic_rel(c.order.unwrap_or(0) as usize),
                        drive_part.get(c.order.unwrap_or(1) as usize - 1).map_or(0.0, |t| t.amp),
                    ),
                ),
                None,
            ),
        };
        findings.push(Finding {
            kind: c.kind,
            order: c.order,
            freq_hz: c.freq_hz,
            residual_share: explained.clamp(0.0, 1.0),
            amplitude_um: c.amp,
            cause,
            rms_with_term_um: rms,
            term_rms_um: term,
            output_rel: out_harmonics
                .get(c.order.map_or(usize::MAX, |o| o as usize - 1))
                .map_or(0.0, |t| t.amp / output_amplitude_um.max(1e-300)),
            kept: true,
            level,
            band_hz: None,
            drive_within_range_v: within.map(|(k, amp)| k * amp),
        });
    }
    // Kept terms were chosen by their evidence, most first; the delay, found on the
    // start-up, after them.
    findings.extend(delay_finding);
    findings.extend(unexplained(&model_residual, &kept, &out_harmonics, output_amplitude_um, th));
    let mut model_check = ModelCheck::of(&model.host, &model_sim[split..], &y[split..], ts);
    model_check
        .check_amplitudes(&model.host.ext.bw, model.host.ext.ar, u, ts, |v| model.simulate(v, ts).ok());
    let (resonance_hz, resonance_note) =
        resonance_support(res_hz, drive_hz, &out_harmonics, output_amplitude_um, &residual);
    Ok(Diagnosis {
        resonance_hz,
        resonance_note,
        findings,
        trials,
        model: model.host,
        terms: model.terms,
        delay,
        model_rms_um: model_rms,
        model_sim,
        model_residual,
        model_check,
        drive_note,
        ..base
    })
}

/// A drive that starts within this fraction of its amplitude from 0 V starts from rest: its
/// first samples are the step onto the drive.
pub const STEP_FROM_REST: f64 = 0.05;

/// Fits the candidate's term onto `model` (see [`crate::diagnose::causes`]): a harmonic branch or a
/// drift line by [`fit::fit_oe_on`] (on the record prepared as `data`, or on the input as the
/// model's terms transform it), or by a joint refinement when the model has terms inside or
/// after it; a saturation or creep by its own fit.
///
/// `prev` is the candidate's model of the last round. When the term kept since then acts
/// inside or after the model (a clamp of the output, creep), a joint refinement from the
/// current model with the new term at zero can stay where the current model's loop already
/// imitates the term; the candidate's own fit of the last round with the kept term added is
/// then a second start, and the start that ends with the lower fitting error is taken.
#[allow(clippy::too_many_arguments)]
fn try_term(
    model: &TermModel,
    c: &Candidate,
    prev: Option<&TermModel>,
    data: &FitData<'_>,
    u: &[f64],
    y: &[f64],
    ts: f64,
    split: usize,
    opt: &OeOptions,
) -> Option<TermModel> {
    match c.kind {
        Kind::Saturation => match c.output_range {
            Some(range) => causes::fit_output_clamp(model, range, u, y, ts, split, opt),
            None => causes::fit_input_clamp(model, &causes::spec_of(&model.host), u, y, ts, split, opt),
        },
        Kind::Creep => causes::fit_creep(model, u, y, ts, split, opt),
        Kind::OddHarmonic | Kind::EvenHarmonic | Kind::Drift => {
            let spec = with_term(&model.host, c, ts)?;
            if model.terms.is_empty() {
                let f = fit::fit_oe_on(data, &spec, std::slice::from_ref(&model.host), opt).ok()?;
                Some(TermModel::from(f.model))
            } else if model.terms.input_only() {
                causes::fit_host(model, &spec, u, y, ts, split, opt).ok().map(|r| r.0)
            } else {
                let from_model = causes::refine_with(model, &spec, u, y, ts, split, opt);
                let warm = prev
                    .filter(|p| p.terms != model.terms && p.host.branches.len() >= model.host.branches.len());
                let from_prev = warm.and_then(|p| {
                    let mut start = p.clone();
                    start.terms = model.terms.clone();
                    let free = start.host_params();
                    refine(&start, &free, u, y, ts, &causes::criterion(opt, split, ts, causes::REFINE_ITER))
                });
                match (from_model, from_prev) {
                    (Some(a), Some(b)) => Some(if b.1 < a.1 { b.0 } else { a.0 }),
                    (a, b) => a.or(b).map(|r| r.0),
                }
            }
        }
        Kind::OtherInput | Kind::InputDelay | Kind::OddDistortion | Kind::EvenDistortion => None,
    }
}

/// The output's harmonics (µm, phases from sample `split`) that the drive's own harmonics
/// account for through `model`: its free run on `u` minus its free run on `u` without the
/// drive's harmonics `k ≥ 2`. Empty when the drive carries none worth it (distortion under
/// [`DRIVE_DISTORTION_FLOOR`]).
fn drive_harmonic_part(
    model: &HostModel,
    u: &[f64],
    sim: &[f64],
    ts: f64,
    split: usize,
    drive: &Drive,
) -> Result<Vec<Tone>, FitError> {
    if drive.thd < DRIVE_DISTORTION_FLOOR {
        return Ok(vec![]);
    }
    let n = analysis::whole_periods(u.len(), drive.freq_hz, ts);
    let h = analysis::harmonics(&u[..n], drive.freq_hz, ts, MAX_TERM_ORDER as usize);
    let mut pure = u.to_vec();
    for t in h.iter().skip(1) {
        analysis::add_tone(&mut pure, &Tone { amp: -t.amp, ..*t }, ts, 0.0);
    }
    let sim_pure = model.simulate(&pure, ts)?;
    if instability(model.ext.ar, &sim_pure, ts).is_some() {
        // The model's loop runs away on the cleaned drive: no correction can be measured.
        return Ok(vec![]);
    }
    let d: Vec<f64> = sim[split..].iter().zip(&sim_pure[split..]).map(|(a, b)| a - b).collect();
    Ok(analysis::harmonics(&d, drive.freq_hz, ts, MAX_TERM_ORDER as usize))
}

/// The share of an output harmonic that the drive's own harmonic of that order may account
/// for (through the baseline, in amplitude) before a harmonic branch there is not kept: the
/// record then cannot tell the actuator's harmonic from its response to the drive's. Set on
/// the messy records of `diagnose_messy` whose drives carry 0.5–3 % at the 2nd and 3rd
/// harmonic (`--per-mess 24`): 0.10–0.33 on the 8 with a 3rd or 2nd harmonic hidden, 0.49 and
/// 1.14 on the two clean ones a 3rd harmonic branch was kept on.
pub const DRIVE_SHARE_MAX: f64 = 0.4;

/// A drive's own harmonic distortion below which it is not taken into account: the
/// distortion measured on a pure sine is about 10⁻⁴ (the drive frequency is estimated).
pub const DRIVE_DISTORTION_FLOOR: f64 = 2e-3;

/// "3rd harmonic branch", "drift line", "clamp of the drive".
fn describe_term(c: &Candidate) -> String {
    match (c.kind, c.order) {
        (Kind::Drift, _) => "drift line".into(),
        (Kind::Saturation, _) if c.output_range.is_some() => "clamp of the output".into(),
        (Kind::Saturation, _) => "clamp of the drive".into(),
        (Kind::Creep, _) => "creep states".into(),
        (_, Some(n)) => format!("{} harmonic branch", ordinal(n)),
        _ => "term".into(),
    }
}

/// The structure's resonance if the record supports it: a line the record excites (the
/// drive or an output harmonic of at least 1 % of the fundamental) within
/// [`NEAR_RESONANCE`] of it, or a residual harmonic there holding [`UNEXPLAINED_SHARE`] of
/// the residual power. Returns the resonance to report and a sentence saying why or why not.
fn resonance_support(
    res_hz: Option<f64>,
    drive_hz: f64,
    out: &[Tone],
    out_amp: f64,
    residual: &Residual,
) -> (Option<f64>, String) {
    let Some(r) = res_hz else {
        return (None, "the fitted structure has no resonance (its poles are real)".into());
    };
    let near = |f: f64| (r - f).abs() <= NEAR_RESONANCE * r.max(f);
    if let Some((k, t)) =
        out.iter().enumerate().find(|(k, t)| (*k == 0 || t.amp >= 0.01 * out_amp) && near(t.freq_hz))
    {
        let what = if k == 0 {
            "the drive".to_string()
        } else {
            format!("the output's {} harmonic", ordinal(k as u32 + 1))
        };
        return (Some(r), format!("excited: {what} at {:.1} Hz lies near it", t.freq_hz));
    }
    let power = (residual.rms_um * residual.rms_um).max(1e-300);
    if let Some(t) = residual
        .harmonics
        .iter()
        .find(|t| near(t.freq_hz) && t.amp * t.amp / 2.0 >= UNEXPLAINED_SHARE * power)
    {
        return (Some(r), format!("shown in the residual: its harmonic at {:.1} Hz lies near it", t.freq_hz));
    }
    let top = out
        .iter()
        .enumerate()
        .filter(|(k, t)| *k == 0 || t.amp >= 0.01 * out_amp)
        .map(|(_, t)| t.freq_hz)
        .fold(drive_hz, f64::max);
    (
        None,
        format!(
            "the structure's resonance is not identifiable from this record: the fit puts one at {r:.0} Hz, but \
             nothing the record excites lies near it (the drive at {drive_hz:.1} Hz and output harmonics up to \
             {top:.1} Hz)"
        ),
    )
}

/// The structure the extended model still misses: a harmonic `2..=`[`MAX_TERM_ORDER`] (not
/// already a term) or the trend holding at least [`UNEXPLAINED_SHARE`] of the extended
/// model's held-out residual power and carrying at least `min_term_rel` of the output's
/// fundamental RMS. No term could remove it (it was tried, or it was not a candidate).
fn unexplained(
    r: &Residual,
    kept: &[(Candidate, f64, f64)],
    out: &[Tone],
    out_amp: f64,
    th: &Thresholds,
) -> Vec<Finding> {
    let power = (r.rms_um * r.rms_um).max(1e-300);
    let floor = th.min_term_rel * out_amp / std::f64::consts::SQRT_2;
    let is_kept = |order: Option<u32>| match order {
        Some(_) => kept.iter().any(|(c, ..)| c.order == order),
        // The trend: a drift line or creep removed it.
        None => kept.iter().any(|(c, ..)| matches!(c.kind, Kind::Drift | Kind::Creep)),
    };
    let mut found = vec![];
    for (i, h) in r.harmonics.iter().enumerate().skip(1).take(MAX_TERM_ORDER as usize - 1) {
        let order = (i + 1) as u32;
        let (rms, share) = (h.amp / std::f64::consts::SQRT_2, h.amp * h.amp / 2.0 / power);
        if is_kept(Some(order)) || share < UNEXPLAINED_SHARE || rms < floor {
            continue;
        }
        let kind = if order % 2 == 1 { Kind::OddHarmonic } else { Kind::EvenHarmonic };
        let output_rel = out.get(i).map_or(0.0, |t| t.amp / out_amp.max(1e-300));
        found.push(Finding {
            kind,
            order: Some(order),
            freq_hz: h.freq_hz,
            residual_share: share,
            amplitude_um: h.amp,
            output_rel,
            cause: format!(
                "unexplained {} harmonic at {:.1} Hz: {:.3} µm, {:.0}% of the extended model's residual power; no \
                 term removed it by enough to keep",
                ordinal(order),
                h.freq_hz,
                h.amp,
                100.0 * share
            ),
            kept: false,
            rms_with_term_um: f64::NAN,
            term_rms_um: rms,
            level: None,
            band_hz: None,
            drive_within_range_v: None,
        });
    }
    let share = r.trend_rms_um.powi(2) / power;
    if !is_kept(None) && share >= UNEXPLAINED_SHARE && r.trend_rms_um >= floor {
        found.push(Finding {
            kind: Kind::Drift,
            order: None,
            freq_hz: 0.0,
            residual_share: share,
            amplitude_um: r.trend_rms_um,
            output_rel: 0.0,
            cause: format!(
                "unexplained slow trend: {:.3} µm RMS (slope {:.4} µm/s), {:.0}% of the extended model's residual \
                 power; a drift line did not remove it by enough to keep",
                r.trend_rms_um,
                r.trend_slope_um_per_s,
                100.0 * share
            ),
            kept: false,
            rms_with_term_um: f64::NAN,
            term_rms_um: r.trend_rms_um,
            level: None,
            band_hz: None,
            drive_within_range_v: None,
        });
    }
    found.sort_by(|a, b| b.term_rms_um.total_cmp(&a.term_rms_um));
    found
}

/// Smallest share of the extended model's residual power for structure no term removed to
/// be reported (see [`Finding::kept`]).
pub const UNEXPLAINED_SHARE: f64 = 0.25;

/// The terms to try: every harmonic `2..=`[`MAX_TERM_ORDER`] below Nyquist whose RMS in the
/// output or in the residual reaches `floor` (µm), and the drift if the trend's RMS does.
fn candidates(
    r: &Residual,
    out: &[Tone],
    drive_hz: f64,
    ts: f64,
    floor: f64,
    drift_floor: f64,
) -> Vec<Candidate> {
    let power = (r.rms_um * r.rms_um).max(1e-300);
    let rms = |t: &Tone| t.amp / std::f64::consts::SQRT_2;
    let mut c: Vec<Candidate> = r
        .harmonics
        .iter()
        .enumerate()
        .skip(1)
        .filter(|(i, h)| rms(h) >= floor || out.get(*i).is_some_and(|o| rms(o) >= floor))
        .map(|(i, h)| {
            let order = (i + 1) as u32;
            let kind = if order % 2 == 1 { Kind::OddHarmonic } else { Kind::EvenHarmonic };
            Candidate {
                kind,
                order: Some(order),
                freq_hz: h.freq_hz,
                share: h.amp * h.amp / 2.0 / power,
                amp: h.amp,
                evidence_um: out.get(i).map_or(0.0, rms),
                output_range: None,
            }
        })
        .filter(|c| c.order.is_some_and(|o| o <= MAX_TERM_ORDER && o as f64 * drive_hz < 0.5 / ts))
        .collect();
    if r.trend_rms_um >= drift_floor {
        c.push(Candidate {
            kind: Kind::Drift,
            order: None,
            freq_hz: 0.0,
            share: r.trend_rms_um.powi(2) / power,
            amp: r.trend_rms_um,
            evidence_um: r.trend_rms_um,
            output_range: None,
        });
    }
    c
}

/// The held-out RMS (µm) of what the term of `c` carries in `model`: the change of its free
/// run when the term is removed.
fn term_rms(model: &TermModel, c: &Candidate, u: &[f64], ts: f64, split: usize) -> Result<f64, FitError> {
    let a = model.simulate(u, ts)?;
    let b = without(model, c).simulate(u, ts)?;
    let d: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
    if c.kind == Kind::Creep {
        // Creep relaxes mostly before the held-out half: what it carries is its relaxation
        // towards its last level over the whole run after the start-up.
        let last = d.last().copied().unwrap_or(0.0);
        let from = (split / 5).min(d.len());
        return Ok(analysis::rms(&d[from..].iter().map(|v| v - last).collect::<Vec<_>>()));
    }
    // A drift line's level is traded against the loop's offset: count its change from the
    // middle of the fitted half.
    let level = if c.kind == Kind::Drift { d[split / 2] } else { 0.0 };
    let carried = analysis::rms(&d[split..].iter().map(|v| v - level).collect::<Vec<_>>());
    // Without its term a model may leave the range it was fitted in (a drive clamp's, fitted
    // to the clamped drive, driven by the whole drive): the term then carries the whole
    // output, no more.
    let held = &a[split..];
    let centre = analysis::mean(held);
    let whole = analysis::rms(&held.iter().map(|v| v - centre).collect::<Vec<_>>());
    Ok(carried.min(whole))
}

/// `model` without the candidate's term.
fn without(model: &TermModel, c: &Candidate) -> TermModel {
    let mut m = model.clone();
    match c.kind {
        // The offset stays; the drift is the rest of the polynomial.
        Kind::Drift => m.host.drift.truncate(1),
        Kind::Saturation if c.output_range.is_some() => m.terms.output_clamp = None,
        Kind::Saturation => m.terms.input_clamp = None,
        Kind::Creep => m.terms.creep.clear(),
        _ => m.host.branches.retain(|b| Some(b.order) != c.order),
    }
    m
}

/// The current model's spec with the candidate's term added (`None` if it cannot be).
fn with_term(model: &HostModel, c: &Candidate, ts: f64) -> Option<ModelSpec> {
    let mut spec = ModelSpec {
        drive_hz: model.drive_hz,
        harmonics: model.branches.iter().map(|b| b.order).collect(),
        drift_degree: (!model.drift.is_empty()).then(|| model.drift.len() - 1),
    };
    match c.kind {
        Kind::Drift if spec.drift_degree.is_none_or(|d| d == 0) => spec.drift_degree = Some(1),
        Kind::OddHarmonic | Kind::EvenHarmonic => {
            let o = c.order?;
            if spec.harmonics.contains(&o)
                || spec.harmonics.len() >= crate::model::MAX_BRANCHES
                || o as f64 * model.drive_hz >= 0.5 / ts
            {
                return None;
            }
            spec.harmonics.push(o);
        }
        _ => return None,
    }
    Some(spec)
}

/// A term's step in the forward selection: the held-out RMS before and after it, and whether
/// it was added to the baseline itself.
#[derive(Clone, Copy)]
struct Step {
    before_um: f64,
    after_um: f64,
    first: bool,
}

impl Step {
    fn describe(&self, term: &str) -> String {
        let pct = 100.0 * (1.0 - self.after_um / self.before_um.max(1e-300));
        let to = if self.first { "the baseline" } else { "the model with the terms above" };
        format!(
            "{term} added to {to} lowers the held-out RMS from {:.4} to {:.4} µm ({pct:.0}%)",
            self.before_um, self.after_um
        )
    }
}

fn explain(
    c: &Candidate,
    step: Step,
    out: &[Tone],
    out_amp: f64,
    resonances: &[Option<f64>],
    residual: &Residual,
    (drive_rel, drive_part_um): (f64, f64),
) -> String {
    let share = 100.0 * c.share;
    let f = c.freq_hz;
    // A single-sine record places the structure's resonance only roughly (the fit bends it to
    // imitate harmonics), hence a wide window.
    let is_near = |r: &f64| (r - f).abs() <= NEAR_RESONANCE * f.max(*r);
    let near = resonances.iter().flatten().copied().find(is_near);
    // Only the baseline's structure, which made the harmonic before the branch did, has it
    // there: one sine cannot tell a resonance that amplifies the harmonic from a structure
    // bent to make it (a quasi-static stiffening at 5 Hz had its "resonance" at 15 Hz).
    let only_baseline = !resonances.first().copied().flatten().is_some_and(|r| is_near(&r));
    let confirm = |r: f64| -> String {
        if only_baseline {
            format!(
                " (the model with the branch leaves it elsewhere; one sine places a resonance only through the \
                 harmonics it makes: a multisine or a sweep through {r:.0} Hz tells whether it is there)"
            )
        } else {
            String::new()
        }
    };
    let harmonic = |n: u32| -> String {
        let in_out = out.get(n as usize - 1).map_or(0.0, |t| t.amp);
        let rel = if out_amp > 0.0 { 100.0 * in_out / out_amp } else { 0.0 };
        let mut s = format!(
            "the output's {} harmonic at {f:.1} Hz is {in_out:.3} µm ({rel:.1}% of the fundamental); {}",
            ordinal(n),
            step.describe(&format!("a {} harmonic branch", ordinal(n)))
        );
        if c.share >= UNEXPLAINED_SHARE {
            s.push_str(&format!(" (in the baseline's residual the harmonic holds {share:.0}% of the power)"));
        } else if step.first {
            s.push_str(&format!(
                " (the baseline imitates the harmonic, {:.3} µm left, {share:.0}% of its residual power, by bending \
                 its structure, and pays at other harmonics)",
                c.amp
            ));
        }
        if drive_rel >= 1e-3 {
            s.push_str(&format!(
                "; the drive itself carries {:.2}% at this harmonic, which accounts for {drive_part_um:.3} µm of it \
                 through the model",
                100.0 * drive_rel
            ));
        }
        s
    };
    match c.kind {
        Kind::OddHarmonic => {
            let n = c.order.unwrap_or(0);
            let mut s = format!("odd harmonic oscillation: {}", harmonic(n));
            match near {
                Some(r) => s.push_str(&format!(
                    "; the fitted structure has a resonance near {r:.0} Hz{}, which amplifies the {} harmonic of \
                     a nonlinearity the Bouc–Wen loop does not hold (e.g. a stiffening of the actuator or its mechanism)",
                    confirm(r),
                    ordinal(n)
                )),
                None => s.push_str("; a nonlinearity beyond the Bouc–Wen loop"),
            }
            s
        }
        Kind::EvenHarmonic => {
            let n = c.order.unwrap_or(0);
            let mut s = format!(
                "even harmonic: {}; an even harmonic needs an asymmetry the model's loop lacks (an asymmetric \
                 stiffness, an off-centre operating point)",
                harmonic(n)
            );
            if let Some(r) = near {
                s.push_str(&format!(", amplified by the resonance near {r:.0} Hz{}", confirm(r)));
            }
            s
        }
        Kind::Drift => format!(
            "drift: a slow trend not locked to the drive holds {share:.0}% of the baseline's residual power ({:.3} µm \
             RMS, mean {:.3} µm, slope {:.4} µm/s); {}",
            residual.trend_rms_um,
            residual.trend_mean_um,
            residual.trend_slope_um_per_s,
            step.describe("a drift line")
        ),
        Kind::OtherInput => "another input drives the output".into(),
        Kind::Saturation | Kind::Creep | Kind::InputDelay | Kind::OddDistortion | Kind::EvenDistortion => {
            format!("{}: {}", c.kind.as_str(), step.describe(&describe_term(c)))
        }
    }
}

/// "1st", "2nd", "3rd", "11th", …
pub(crate) fn ordinal(n: u32) -> String {
    let suffix = match (n % 10, n % 100) {
        (1, r) if r != 11 => "st",
        (2, r) if r != 12 => "nd",
        (3, r) if r != 13 => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_loop_outside_the_bounded_class_or_a_run_that_diverges_is_noted() {
        use boucwen_core::model::BoucWenParams;
        let ar = [0.5, -0.2];
        let ts = 1e-3;
        let bounded = BoucWenParams { a1: 10.0, a: 3.0, a0: 0.1, gamma: 0.01, beta: 0.15 };
        let unbounded = BoucWenParams { gamma: -0.2, ..bounded };
        let fine = |_: f64| Some(vec![1.0; 100]);
        // In range at 0.5×, beyond Y_LIMIT_UM at 1.5×.
        let blows_up = |k: f64| Some(vec![if k > 1.0 { 2.0 * Y_LIMIT_UM } else { 1.0 }; 100]);
        assert_eq!(amplitude_note(&bounded, ar, ts, fine), None);
        let shape = amplitude_note(&unbounded, ar, ts, fine).expect("an unbounded loop is noted");
        assert!(shape.contains("γ + β = -0.0500") && shape.contains("stays in range"), "{shape}");
        let runs = amplitude_note(&bounded, ar, ts, blows_up).expect("a diverging run is noted");
        assert!(runs.contains("1.5× this drive diverges") && !runs.contains("0.5×"), "{runs}");
        assert!(amplitude_note(&bounded, ar, ts, |_| None).is_some_and(|n| n.contains("0.5× and 1.5×")));
    }

    #[test]
    fn ordinals() {
        assert_eq!(ordinal(3), "3rd");
        assert_eq!(ordinal(5), "5th");
        assert_eq!(ordinal(2), "2nd");
        assert_eq!(ordinal(11), "11th");
        assert_eq!(ordinal(21), "21st");
    }

    #[test]
    fn resonance_of_an_ar2() {
        let w = TAU * 70.0 * 1e-3;
        let r = resonance_hz([2.0 * 0.97 * w.cos(), -0.97 * 0.97], 1e-3).unwrap();
        assert!((r - 70.0).abs() < 1e-9);
        assert_eq!(resonance_hz([1.5, -0.5], 1e-3), None); // real poles
    }

    #[test]
    fn decomposition_separates_harmonic_trend_and_noise() {
        let ts = 1e-3;
        let mut g = 1u64;
        let mut noise = || {
            g ^= g << 13;
            g ^= g >> 7;
            g ^= g << 17;
            (g >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let r: Vec<f64> = (0..10_000)
            .map(|k| {
                let t = k as f64 * ts;
                0.5 * (TAU * 69.0 * t + 0.2).sin() + 0.05 * t + 0.01 * noise()
            })
            .collect();
        let d = decompose(&r, 23.0, ts);
        assert!((d.harmonics[2].amp - 0.5).abs() < 1e-3, "{:?}", d.harmonics[2]);
        assert!((d.trend_slope_um_per_s - 0.05).abs() < 2e-3, "{}", d.trend_slope_um_per_s);
        assert!((d.trend_mean_um - 0.25).abs() < 2e-3, "{}", d.trend_mean_um);
        assert!(d.noise_rms_um < 0.01);
    }
}
