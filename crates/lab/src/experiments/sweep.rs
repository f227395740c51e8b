//! `boucwen sweep`: the paper's two experiments over a range of drive frequencies, on the
//! virtual bimorph (or any scenario).
//!
//! First, once: **the structure** (like the paper's Fig. 7, a frequency-response
//! measurement): a broadband multisine record (1–200 Hz) is fitted with the extended model
//! by output error. A record at one drive frequency pins only one complex gain of the
//! structural IIR, so single-sine fits alone may put the resonance anywhere (a 3 Hz
//! resonance with a negative gain reproduces a 10 Hz record as well as the truth does, and
//! its inverse is useless); the per-frequency output-error fits start from this structure
//! and refine it.
//!
//! Then, for each frequency `f`:
//! 1. **Identification (section 3, Fig. 10).** Drive `u[k] = A·sin(2π f k Ts)` (eq. 13) for
//!    the record length; fit on the first half, report the free-run RMS error of each model
//!    on the second half (data not used for fitting). Two identification methods:
//!    the paper's RLS procedure ([`crate::fit::fit_paper_rls`]; the columns
//!    `rms_extended_um`, `rms_enhanced_um`) and the output-error fit ([`crate::fit::fit_oe`];
//!    the `_oe` columns).
//! 2. **Harmonic order.** The enhanced model gets a branch of order `n` where the data call
//!    for one: by default the odd harmonic holding the largest share of the residual of the
//!    extended output-error fit (on the fitting half), if that share is at least
//!    [`design::MIN_HARMONIC_SHARE`] and its amplitude at least [`MIN_HARMONIC_REL`] of the output's
//!    fundamental; with [`HarmonicChoice::Paper`],
//!    the paper's table (5th at 14 Hz, 3rd at 18–28 Hz). Where no branch is chosen the
//!    enhanced model *is* the extended model and the proposed controller *is* `u_f`, and the
//!    columns repeat the baseline (`harmonic_order` is 0).
//! 3. **Compensation (section 5, Fig. 16).** Track `d[k] = α sin(2π f k Ts)` with `α` from
//!    eq. (25), once with `u_f` alone (eqs. 16/17) and once with the proposed law (eqs.
//!    20/21), each with the models of both identification methods; the RMSE is taken after
//!    the settling time (the paper: after 20 s of 100 s). As in the paper, `u_f` alone is
//!    synthesised from the extended model. The proposed law cancels the harmonic that the
//!    tracking error under `u_f` shows ([`design::cancelled_harmonic`], the rule `boucwen
//!    hil` uses too); its `u_f` comes from the first two equations of the
//!    enhanced model when that model carries the same harmonic and is invertible, else from
//!    the extended model. Where no harmonic qualifies the proposed law is `u_f` itself.

use crate::design::closed_loop::{self, CompensationSettings, ExperimentError, Peer, Trace};
use crate::design::{self, PROBE_REL, PROBE_SECONDS, ResponseSource};
use crate::diagnose::checks;
use crate::fit::{self, Averaging, DelaySearch, FitError, LoopSearch, OeOptions, Samples, StructureSearch};
use crate::model::{HostModel, LoopShape, ModelSpec};
use crate::rules::Rules;
use crate::signal::analysis;
use boucwen_core::compensator::{HarmonicSpec, PhaseRule};
use boucwen_sim::{Bimorph, Scenario, SimError};
use rayon::prelude::*;
use serde::Serialize;
use std::fmt;
use std::path::PathBuf;

/// How the harmonic order of the enhanced model is chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HarmonicChoice {
    /// From the data: the dominant odd harmonic of the extended fit's residual.
    Auto,
    /// The paper's table: 5th at 14 Hz, 3rd at 18–28 Hz, none elsewhere.
    Paper,
}

/// Settings of a sweep.
#[derive(Clone, Debug)]
pub struct SweepOptions {
    /// Drive frequencies (Hz).
    pub freqs: Vec<f64>,
    /// Length of each record (identification and each tracking run), s.
    pub seconds: f64,
    /// The virtual actuator.
    pub scenario: Scenario,
    /// Identification drive amplitude (V); the paper uses 1.
    pub drive_amplitude: f64,
    /// How the harmonic order is chosen.
    pub harmonics: HarmonicChoice,
    /// Compensator settings.
    pub compensation: CompensationSettings,
    /// Where the cancellation takes the actuator's response at `n·f` from.
    pub response: ResponseSource,
    /// Frequencies whose traces are kept for plots.
    pub trace_freqs: Vec<f64>,
}

impl SweepOptions {
    /// The paper's sweep: 1..50 Hz in 1 Hz steps, `seconds` per record, the default scenario.
    pub fn paper(seconds: f64) -> Self {
        Self {
            freqs: (1..=50).map(f64::from).collect(),
            seconds,
            scenario: Scenario::default(),
            drive_amplitude: 1.0,
            harmonics: HarmonicChoice::Auto,
            compensation: CompensationSettings::default(),
            response: ResponseSource::Probe,
            trace_freqs: vec![1.0, 14.0, 15.0, 23.0],
        }
    }

    /// Seconds after which the tracking RMSE is taken: a fifth of the run as in the paper
    /// (20 s of 100 s), at least 1 s, at most half the run.
    pub fn settle_s(&self) -> f64 {
        (0.2 * self.seconds).max(1.0).min(0.5 * self.seconds)
    }
}

/// Length of the broadband structure record (s).
pub const STRUCTURE_SECONDS: f64 = 20.0;
/// Peak of the structure record relative to the drive amplitude: small, so the actuator is
/// nearly linear (the loop and the stiffening barely act).
pub const STRUCTURE_AMPLITUDE: f64 = 0.1;

/// Samples (from the record's start) of each frequency's output-error fit criterion.
pub const SWEEP_FIT_SAMPLES: usize = 4000;

/// Length of the quasi-static loop record (s) and its frequency (Hz).
pub const LOOP_SECONDS: f64 = 6.0;
/// Frequency of the quasi-static loop record (Hz): slow enough that the structure acts as
/// its static gain (the paper's Fig. 2 is such a loop).
pub const LOOP_HZ: f64 = 1.0;

/// The actuator characterised once: the structure from a broadband record and the loop
/// shape from a quasi-static one.
#[derive(Clone, Debug)]
pub struct Structure {
    /// The extended model fitted to the multisine record (its AR part is the structure).
    pub model: HostModel,
    /// The loop shape fitted to the quasi-static record with that structure.
    pub shape: LoopShape,
    /// Its fitting RMS (µm).
    pub rms_fit_um: f64,
    /// The resonance of its AR part (Hz), if the poles are complex.
    pub resonance_hz: Option<f64>,
}

/// A record's input (V) and output (µm).
pub type InOut = (Vec<f64>, Vec<f64>);

/// The two records the structure is identified from, on a fresh actuator: the broadband
/// multisine `(u, y)` ([`STRUCTURE_SECONDS`], peak [`STRUCTURE_AMPLITUDE`] of the drive
/// amplitude) and the quasi-static loop `(u, y)` ([`LOOP_HZ`], [`LOOP_SECONDS`], at the drive
/// amplitude). `boucwen sweep --measured` takes records like these from disk.
pub fn structure_records(scenario: &Scenario, drive_amplitude: f64) -> Result<[InOut; 2], SweepError> {
    let ts = scenario.sampling.ts_s;
    let seed = scenario.seed.wrapping_mul(1_000_003).wrapping_sub(1);
    // Structure and delay: a small broadband record, where the actuator is nearly linear.
    let n = (STRUCTURE_SECONDS / ts).round() as usize;
    let u =
        closed_loop::multisine(STRUCTURE_AMPLITUDE * drive_amplitude, 1.0, (0.2 / ts).min(200.0), 40, ts, n);
    let y = Bimorph::new(&scenario.clone().with_seed(seed))?.run(&u)?;
    let n_loop = (LOOP_SECONDS / ts).round() as usize;
    let u_loop =
        closed_loop::sine(drive_amplitude, LOOP_HZ, ts, n_loop).map_err(|e| SweepError::Core(LOOP_HZ, e))?;
    let y_loop = Bimorph::new(&scenario.clone().with_seed(seed.wrapping_sub(1)))?.run(&u_loop)?;
    Ok([(u, y), (u_loop, y_loop)])
}

/// Identifies the structure from a multisine record on a fresh actuator.
pub fn identify_structure(scenario: &Scenario, drive_amplitude: f64) -> Result<Structure, SweepError> {
    let [(u, y), (u_loop, y_loop)] = structure_records(scenario, drive_amplitude)?;
    let ts = scenario.sampling.ts_s;
    structure_from(&u, &y, LoopRecord { u: &u_loop, y: &y_loop, hz: LOOP_HZ, fit: u_loop.len() }, ts)
}

/// The record the loop shape is fitted on: a sine `(u, y)` at `hz`, fitted on its first
/// `fit` samples, starting with the drive.
#[derive(Clone, Copy, Debug)]
pub struct LoopRecord<'a> {
    /// The drive (V).
    pub u: &'a [f64],
    /// The output (µm).
    pub y: &'a [f64],
    /// Its frequency (Hz).
    pub hz: f64,
    /// The samples fitted, from the start.
    pub fit: usize,
}

/// The structure from a broadband record `(u, y)` (the extended model fitted by output error
/// with a linear loop: its AR part and delay) and the loop shape from `lp`, fitted with that
/// structure and delay. The broadband record starts with the drive.
pub fn structure_from(u: &[f64], y: &[f64], lp: LoopRecord<'_>, ts: f64) -> Result<Structure, SweepError> {
    let err = |e| SweepError::Fit(0.0, e);
    let opt = OeOptions {
        samples: Samples::First(8000),
        averaging: Averaging::Off,
        delay: DelaySearch::Fit,
        hysteresis: LoopSearch::Linear,
        ..OeOptions::default()
    };
    let fit = fit::fit_oe(u, y, ts, u.len(), &ModelSpec::extended(1.0), &[], &opt).map_err(err)?;
    structure_with(fit.model.ext.ar, fit.model.delay, fit.rms_fit, lp, ts)
}

/// The structure from sine records alone, when no broadband record is at hand: the linear
/// part and delay fitted to the fundamentals' complex gains `points` ([`fit::response`]),
/// then the loop shape from `lp` as in [`structure_from`]. Its `rms_fit_um` is the RMS
/// error of the output's fundamental over the records.
pub fn structure_from_sines(
    points: &[fit::response::Fundamental],
    lp: LoopRecord<'_>,
    ts: f64,
) -> Result<Structure, SweepError> {
    let r = fit::response::fit_response(points, ts).map_err(|e| SweepError::Fit(0.0, e))?;
    structure_with(r.ar, r.delay, r.rms, lp, ts)
}

/// The loop shape from `lp` with the linear part `ar` and the input delay `delay` fixed.
fn structure_with(
    ar: [f64; 2],
    delay: f64,
    rms_fit_um: f64,
    lp: LoopRecord<'_>,
    ts: f64,
) -> Result<Structure, SweepError> {
    let resonance_hz = crate::model::poles::resonance_hz(&ar, ts);
    // The loop: a quasi-static sine at the drive amplitude, with that structure and delay.
    let loop_opt = OeOptions {
        samples: Samples::First(lp.fit),
        averaging: Averaging::Off,
        structure: StructureSearch::Fixed(ar),
        delay: DelaySearch::Fixed(delay),
        ..OeOptions::default()
    };
    let loop_fit = fit::fit_oe(lp.u, lp.y, ts, lp.fit, &ModelSpec::extended(lp.hz), &[], &loop_opt)
        .map_err(|e| SweepError::Fit(lp.hz, e))?;
    let shape = loop_fit.model.shape().ok_or(SweepError::Fit(lp.hz, FitError::NoStableModel))?;
    let mut model = loop_fit.model;
    model.ext.ar = ar;
    Ok(Structure { model, shape, rms_fit_um, resonance_hz })
}

/// One frequency's results. `NaN` where a model or a loop was unstable in free run (`null`
/// in JSON, [`UNSTABLE`] in the tables and the CSV).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Row {
    /// Drive frequency (Hz).
    pub freq_hz: f64,
    /// Paper RLS, extended model: held-out free-run RMS error (µm).
    pub rms_extended_um: f64,
    /// Paper RLS, enhanced model (µm).
    pub rms_enhanced_um: f64,
    /// Tracking RMSE with `u_f` alone, paper-RLS model (µm).
    pub rmse_uf_um: f64,
    /// Tracking RMSE with the proposed law, paper-RLS model (µm).
    pub rmse_proposed_um: f64,
    /// The harmonic order of the enhanced model (0: none chosen).
    pub harmonic_order: u32,
    /// The harmonic the proposed law cancels with the paper-RLS model (0: none).
    pub cancel_order: u32,
    /// The harmonic the proposed law cancels with the output-error model (0: none).
    pub cancel_order_oe: u32,
    /// Reference amplitude `α` of eq. (25) (µm).
    pub alpha_um: f64,
    /// Output-error fit, extended model (µm).
    pub rms_extended_oe_um: f64,
    /// Output-error fit, enhanced model (µm).
    pub rms_enhanced_oe_um: f64,
    /// Tracking RMSE with `u_f` alone, output-error model (µm).
    pub rmse_uf_oe_um: f64,
    /// Tracking RMSE with the proposed law, output-error model (µm).
    pub rmse_proposed_oe_um: f64,
    /// Tracking RMSE in open loop, `u = d/G0` (µm).
    pub rmse_open_um: f64,
    /// Tracking RMSE under the PI feedback alone (µm).
    pub rmse_pi_um: f64,
    /// Tracking RMSE under Li et al.'s odd-harmonic repetitive controller on the PI (µm).
    pub rmse_orc_um: f64,
}

/// What the tables and the CSV say in place of an error whose model or loop was not stable
/// in free run (`NaN` in [`Row`], `null` in JSON).
pub const UNSTABLE: &str = "unstable";

/// An error (µm) for a table, to 4 decimals, or [`UNSTABLE`].
pub fn cell(x: f64) -> String {
    if x.is_finite() { format!("{x:.4}") } else { UNSTABLE.into() }
}

/// The CSV header: the paper's five columns first.
pub const CSV_HEADER: &str = "freq_hz,rms_extended_um,rms_enhanced_um,rmse_uf_um,rmse_proposed_um,\
rmse_open_um,rmse_pi_um,rmse_orc_um,harmonic_order,cancel_order,cancel_order_oe,alpha_um,rms_extended_oe_um,rms_enhanced_oe_um,rmse_uf_oe_um,\
rmse_proposed_oe_um";

impl Row {
    /// The row as CSV (same order as [`CSV_HEADER`]); an error that is `NaN` is written
    /// [`UNSTABLE`].
    pub fn csv(&self) -> String {
        self.csv_with(UNSTABLE)
    }

    /// The row as CSV with the tracking columns, where they are `NaN`, written `missing`
    /// (`nan` where no tracking was run, as in a sweep of measured records); the models'
    /// errors that are `NaN` are written [`UNSTABLE`].
    pub fn csv_with(&self, missing: &str) -> String {
        let f = |x: f64| if x.is_finite() { format!("{x:.6}") } else { UNSTABLE.into() };
        let t = |x: f64| if x.is_finite() { format!("{x:.6}") } else { missing.into() };
        let v =
            [f(self.rms_extended_um), f(self.rms_enhanced_um), t(self.rmse_uf_um), t(self.rmse_proposed_um)];
        let w = [
            f(self.rms_extended_oe_um),
            f(self.rms_enhanced_oe_um),
            t(self.rmse_uf_oe_um),
            t(self.rmse_proposed_oe_um),
        ];
        let peers = [self.rmse_open_um, self.rmse_pi_um, self.rmse_orc_um].map(t);
        format!(
            "{},{},{},{},{},{},{:.6},{}",
            self.freq_hz,
            v.join(","),
            peers.join(","),
            self.harmonic_order,
            self.cancel_order,
            self.cancel_order_oe,
            self.alpha_um,
            w.join(",")
        )
    }
}

/// Signals kept at a frequency, for plots.
#[derive(Clone, Debug, Default)]
pub struct Traces {
    /// Drive frequency (Hz).
    pub freq_hz: f64,
    /// Sample interval (s).
    pub ts: f64,
    /// First held-out sample of the identification record.
    pub split: usize,
    /// Identification input (V).
    pub u: Vec<f64>,
    /// Identification output (µm).
    pub y: Vec<f64>,
    /// Free runs of the output-error models on the identification input.
    pub y_extended: Vec<f64>,
    /// Free run of the enhanced model (equal to the extended if no branch was chosen).
    pub y_enhanced: Vec<f64>,
    /// Tracking with `u_f` alone (output-error model).
    pub track_uf: Trace,
    /// Tracking with the proposed law (output-error model).
    pub track_proposed: Trace,
}

/// Why a sweep failed.
#[derive(Debug)]
pub enum SweepError {
    /// The scenario is invalid or the simulator failed.
    Sim(SimError),
    /// A fit failed at a frequency.
    Fit(f64, FitError),
    /// A core error at a frequency (invalid frequency, compensator parameters).
    Core(f64, boucwen_core::Error),
    /// A tracking run failed at a frequency (the plant or the controller).
    Experiment(f64, ExperimentError),
    /// A probe of the actuator's response failed at a frequency.
    Probe(f64, design::DesignError),
    /// No frequency to sweep.
    NoFrequencies,
    /// The frequency range is unusable (not finite, not increasing, or too many).
    Range {
        /// Lowest frequency, Hz.
        from: f64,
        /// Highest frequency, Hz.
        to: f64,
        /// Step, Hz.
        step: f64,
    },
    /// The record length (s) is not a positive number.
    Seconds(f64),
    /// The record length (s) leaves fewer than 2 periods of the lowest frequency in the
    /// held-out half.
    TooShort(f64),
    /// The record length (s) gives fewer than 1000 samples.
    TooFewSamples(f64),
}

impl fmt::Display for SweepError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SweepError::Sim(e) => write!(f, "virtual bimorph: {e}"),
            SweepError::Fit(hz, e) => write!(f, "at {hz} Hz: {e}"),
            SweepError::Core(hz, e) => write!(f, "at {hz} Hz: {e}"),
            SweepError::Experiment(hz, e) => write!(f, "at {hz} Hz: {e}"),
            SweepError::Probe(hz, e) => write!(f, "at {hz} Hz: probe: {e}"),
            SweepError::NoFrequencies => f.write_str("no frequencies to sweep"),
            SweepError::Range { from, to, step } => write!(
                f,
                "need finite 0 < --from <= --to and --step > 0, at most {MAX_FREQUENCIES} frequencies \
                 (got --from {from} --to {to} --step {step})"
            ),
            SweepError::Seconds(s) => write!(f, "--seconds must be > 0 (got {s})"),
            SweepError::TooShort(s) => write!(
                f,
                "--seconds {s} is too short: the held-out half must hold at least 2 periods of the lowest frequency"
            ),
            SweepError::TooFewSamples(s) => write!(f, "--seconds {s} gives fewer than 1000 samples"),
        }
    }
}

impl std::error::Error for SweepError {}

impl From<SimError> for SweepError {
    fn from(e: SimError) -> Self {
        SweepError::Sim(e)
    }
}

/// The chosen harmonic for `f`.
fn choose_order(
    choice: HarmonicChoice,
    f: f64,
    ts: f64,
    u: &[f64],
    y: &[f64],
    extended: &HostModel,
    fit_end: usize,
) -> Result<(u32, f64), FitError> {
    match choice {
        HarmonicChoice::Paper => Ok((paper_order(f, ts), 0.0)),
        HarmonicChoice::Auto => {
            let sim = extended.simulate(&u[..fit_end], ts)?;
            let skip = (fit_end / 5).min(2000);
            let r: Vec<f64> = y[skip..fit_end].iter().zip(&sim[skip..fit_end]).map(|(a, b)| a - b).collect();
            let out_amp = analysis::harmonics(&y[skip..fit_end], f, ts, 1).first().map_or(0.0, |t| t.amp);
            Ok(analysis::dominant_odd_harmonic(
                &r,
                f,
                ts,
                design::MIN_HARMONIC_SHARE,
                MIN_HARMONIC_REL * out_amp,
            )
            .unwrap_or((0, 0.0)))
        }
    }
}

pub use crate::model::MIN_HARMONIC_REL;

/// The harmonic for the proposed law, from the tracking error under `u_f` alone.
fn cancel_order(choice: HarmonicChoice, f: f64, ts: f64, uf: &Trace, settle: usize, alpha: f64) -> u32 {
    match choice {
        HarmonicChoice::Paper => paper_order(f, ts),
        HarmonicChoice::Auto => {
            let e = uf.error();
            let from = settle.min(e.len());
            design::cancelled_harmonic(&e[from..], f, ts, alpha).unwrap_or(0)
        }
    }
}

/// The paper's table: 5th at 14 Hz, 3rd at 18–28 Hz (when below Nyquist).
fn paper_order(f: f64, ts: f64) -> u32 {
    let n = if (f - 14.0).abs() < 1e-9 {
        5
    } else if (18.0..=28.0).contains(&f) {
        3
    } else {
        0
    };
    if n as f64 * f < 0.5 / ts { n } else { 0 }
}

/// What one frequency of the sweep gives.
#[derive(Clone, Debug)]
pub struct FrequencyResult {
    /// The row of the table.
    pub row: Row,
    /// The signals, if they were kept.
    pub traces: Option<Traces>,
    /// Actuator time simulated (s).
    pub actuator_s: f64,
}

/// The models identified at one frequency and their held-out errors.
pub(crate) struct Identified {
    /// The enhanced model's harmonic order (0: none).
    pub(crate) order: u32,
    ext_oe: HostModel,
    enh_oe: HostModel,
    /// The enhanced output-error fit keeps its loop invertible over the record.
    enh_oe_invertible: bool,
    ext_rls: HostModel,
    enh_rls: HostModel,
    /// Held-out free-run RMS errors: RLS extended, RLS enhanced, OE extended, OE enhanced.
    pub(crate) rms: [f64; 4],
    /// Free runs of the OE models over the whole record.
    y_ext: Vec<f64>,
    y_enh: Vec<f64>,
}

/// Step 1 and 2 of the module docs at one frequency: the fits of both methods on the first
/// half of the record `(u, y)`, the harmonic order, the held-out errors.
pub(crate) fn identify_at(
    choice: HarmonicChoice,
    ts: f64,
    structure: &Structure,
    f: f64,
    u: &[f64],
    y: &[f64],
) -> Result<Identified, FitError> {
    let fit_end = u.len() / 2;
    // The first 4 s of the fitted half, sample by sample: the record starts from rest and the
    // lightly damped first mode is not in steady state after the skipped 0.2 s.
    let oe = OeOptions {
        samples: Samples::First(SWEEP_FIT_SAMPLES),
        averaging: Averaging::Off,
        structure: StructureSearch::Fixed(structure.model.ext.ar),
        delay: DelaySearch::Fixed(structure.model.delay),
        hysteresis: LoopSearch::Fixed(structure.shape),
        ..OeOptions::default()
    };
    let ext_fit = fit::fit_oe(u, y, ts, fit_end, &ModelSpec::extended(f), &[], &oe)?;
    let ext_oe = ext_fit.model.clone();
    let (order, _share) = choose_order(choice, f, ts, u, y, &ext_oe, fit_end)?;
    let orders: Vec<u32> = if order > 0 { vec![order] } else { vec![] };
    let enh_fit = if orders.is_empty() {
        ext_fit
    } else {
        fit::fit_oe(u, y, ts, fit_end, &ModelSpec::enhanced(f, &orders), std::slice::from_ref(&ext_oe), &oe)?
    };
    let ext_rls = fit::fit_paper_rls(u, y, ts, fit_end, &ModelSpec::extended(f))?;
    // The paper's RLS fits the branch by equation error; its free run can come out worse than
    // the extended model's. The branch is kept only if the free run on the fitted half (after
    // the start-up) improves: a choice made on the fitted data alone.
    let enh_rls = if orders.is_empty() {
        ext_rls.clone()
    } else {
        let cand = fit::fit_paper_rls(u, y, ts, fit_end, &ModelSpec::enhanced(f, &orders))?;
        let on_fit = |m: &HostModel| -> Result<f64, FitError> {
            let sim = m.simulate(&u[..fit_end], ts)?;
            let skip = (fit_end / 5).min(2000);
            Ok(analysis::rms_diff(&sim[skip..], &y[skip..fit_end]))
        };
        if on_fit(&cand)? < on_fit(&ext_rls)? { cand } else { ext_rls.clone() }
    };
    // A model whose free run is not stable (a pole outside the unit circle, a run out of the
    // physical range or away from the record's) gets no error (`NaN`, printed `unstable`):
    // the number it would give measures how fast it diverges, not how well it models.
    let checks = Rules::default().checks;
    let held_out = |m: &HostModel| -> Result<(f64, Vec<f64>), FitError> {
        let sim = m.simulate(u, ts)?;
        let unstable = checks::instability(&m.ext.ar, &sim, ts).is_some()
            || checks::runaway(&sim[fit_end..], &y[fit_end..], ts, &checks).is_some();
        let r = analysis::rms_diff(&sim[fit_end..], &y[fit_end..]);
        Ok((if r.is_finite() && !unstable { r } else { f64::NAN }, sim))
    };
    let (rms_ext_rls, _) = held_out(&ext_rls)?;
    let (rms_enh_rls, _) = held_out(&enh_rls)?;
    let (rms_ext_oe, y_ext) = held_out(&ext_oe)?;
    let (rms_enh_oe, y_enh) = held_out(&enh_fit.model)?;
    Ok(Identified {
        order,
        ext_oe,
        enh_oe_invertible: enh_fit.invertible,
        enh_oe: enh_fit.model,
        ext_rls,
        enh_rls,
        rms: [rms_ext_rls, rms_enh_rls, rms_ext_oe, rms_enh_oe],
        y_ext,
        y_enh,
    })
}

/// The identification record `(u, y)` of frequency `opts.freqs[index]`: the drive of eq. (13)
/// for `opts.seconds` from rest, with the noise of that frequency's first run.
/// `boucwen sweep --measured` takes records like these from disk.
pub fn identification_record(opts: &SweepOptions, index: usize) -> Result<InOut, SweepError> {
    let f = *opts.freqs.get(index).ok_or(SweepError::NoFrequencies)?;
    let ts = opts.scenario.sampling.ts_s;
    let n = (opts.seconds / ts).round() as usize;
    let seed = opts.scenario.seed.wrapping_mul(1_000_003).wrapping_add(index as u64 * 16);
    let u = closed_loop::sine(opts.drive_amplitude, f, ts, n).map_err(|e| SweepError::Core(f, e))?;
    let y = Bimorph::new(&opts.scenario.clone().with_seed(seed))?.run(&u)?;
    Ok((u, y))
}

/// One frequency of the sweep.
pub fn run_frequency(
    opts: &SweepOptions,
    structure: &Structure,
    index: usize,
    keep_traces: bool,
) -> Result<FrequencyResult, SweepError> {
    let f = opts.freqs[index];
    let ts = opts.scenario.sampling.ts_s;
    let n = (opts.seconds / ts).round() as usize;
    let fit_end = n / 2;
    let settle = (opts.settle_s() / ts).round() as usize;
    // Independent noise per frequency and run, reproducible from the scenario's seed.
    let seed = |run: u64| opts.scenario.seed.wrapping_mul(1_000_003).wrapping_add(index as u64 * 16 + run);
    let plant = |run: u64| Bimorph::new(&opts.scenario.clone().with_seed(seed(run)));

    // 1. Identification record, 2. fits.
    let (u, y) = identification_record(opts, index)?;
    let mut samples = n;
    let id = identify_at(opts.harmonics, ts, structure, f, &u, &y).map_err(|e| SweepError::Fit(f, e))?;

    // 3. Compensation: α from eq. (25) on the identification record.
    let alpha = closed_loop::eq25_amplitude(&u, &y);
    let set = &opts.compensation;
    // The actuator's response at n·f for the cancellation (probed once per order).
    let mut probed: Vec<(u32, nalgebra::Complex<f64>)> = vec![];
    let mut responses = |model: &HostModel, order: u32| -> Result<Vec<HarmonicSpec<f64>>, SweepError> {
        if order == 0 {
            return Ok(vec![]);
        }
        let rule = match opts.response {
            ResponseSource::Model => PhaseRule::Model,
            ResponseSource::Table { flip_hz } => PhaseRule::Table { flip_hz },
            ResponseSource::Probe => {
                let response = match probed.iter().find(|(o, _)| *o == order) {
                    Some((_, g)) => *g,
                    None => {
                        let m = ((PROBE_SECONDS / ts).round() as usize).min(n);
                        let eps = PROBE_REL * opts.drive_amplitude;
                        let g = design::probe_response_on(&mut plant(5)?, &u[..m], &y[..m], f, order, eps)
                            .map_err(|e| SweepError::Probe(f, e))?;
                        samples += m;
                        probed.push((order, g));
                        g
                    }
                };
                return Ok(vec![HarmonicSpec { order, response }]);
            }
        };
        Ok(closed_loop::model_harmonics(model, &[order], f, ts, rule))
    };
    let tracking = |model: &HostModel, h: &[HarmonicSpec<f64>], run: u64| -> Result<Trace, SweepError> {
        closed_loop::track(&mut plant(run)?, model, h, alpha, f, n, set)
            .map_err(|e| SweepError::Experiment(f, e))
    };
    let finite = |x: f64| if x.is_finite() { x } else { f64::NAN };
    // u_f alone is synthesised from the extended model. The proposed law cancels the
    // harmonic the tracking error under u_f shows (Fig. 13); its u_f comes from the first two
    // equations of the enhanced model (the paper's section 4) when that model carries the
    // same harmonic and is invertible, else from the extended model.
    let order = id.order;
    let uf_rls = tracking(&id.ext_rls, &[], 1)?;
    let n_rls = cancel_order(opts.harmonics, f, ts, &uf_rls, settle, alpha);
    let invertible = n_rls == order && fit::invertible_for(&id.enh_rls, &u);
    let base_rls = if invertible { &id.enh_rls } else { &id.ext_rls };
    let h_rls = responses(base_rls, n_rls)?;
    let prop_rls = if n_rls == 0 { uf_rls.clone() } else { tracking(base_rls, &h_rls, 2)? };
    let uf_oe = tracking(&id.ext_oe, &[], 3)?;
    let n_oe = cancel_order(opts.harmonics, f, ts, &uf_oe, settle, alpha);
    let base_oe = if n_oe == order && id.enh_oe_invertible { &id.enh_oe } else { &id.ext_oe };
    let h_oe = responses(base_oe, n_oe)?;
    let prop_oe = if n_oe == 0 { uf_oe.clone() } else { tracking(base_oe, &h_oe, 4)? };
    samples += 2 * n + usize::from(n_rls > 0) * n + usize::from(n_oe > 0) * n;
    // The peers, tuned from the output-error extended model by the core's rule.
    let peer = |p: Peer, run: u64| -> Result<Trace, SweepError> {
        closed_loop::track_peer(&mut plant(run)?, &id.ext_oe, p, alpha, f, n, set)
            .map_err(|e| SweepError::Experiment(f, e))
    };
    let open = peer(Peer::OpenLoop, 6)?;
    let pi = peer(Peer::Pi, 7)?;
    let orc = peer(Peer::Orc, 8)?;
    samples += 3 * n;

    let [rms_ext_rls, rms_enh_rls, rms_ext_oe, rms_enh_oe] = id.rms;
    let row = Row {
        freq_hz: f,
        rms_extended_um: rms_ext_rls,
        rms_enhanced_um: rms_enh_rls,
        rmse_uf_um: finite(uf_rls.rmse_after(settle)),
        rmse_proposed_um: finite(prop_rls.rmse_after(settle)),
        harmonic_order: order,
        cancel_order: n_rls,
        cancel_order_oe: n_oe,
        alpha_um: alpha,
        rms_extended_oe_um: rms_ext_oe,
        rms_enhanced_oe_um: rms_enh_oe,
        rmse_uf_oe_um: finite(uf_oe.rmse_after(settle)),
        rmse_proposed_oe_um: finite(prop_oe.rmse_after(settle)),
        rmse_open_um: finite(open.rmse_after(settle)),
        rmse_pi_um: finite(pi.rmse_after(settle)),
        rmse_orc_um: finite(orc.rmse_after(settle)),
    };
    let traces = keep_traces.then_some(Traces {
        freq_hz: f,
        ts,
        split: fit_end,
        u,
        y,
        y_extended: id.y_ext,
        y_enhanced: id.y_enh,
        track_uf: uf_oe,
        track_proposed: prop_oe,
    });
    Ok(FrequencyResult { row, traces, actuator_s: samples as f64 * ts })
}

/// Most frequencies one sweep runs.
pub const MAX_FREQUENCIES: usize = 10_000;

/// The frequencies `from, from + step, …` up to `to` (inclusive, up to rounding), each
/// rounded to 1 nHz.
pub fn frequencies(from: f64, to: f64, step: f64) -> Result<Vec<f64>, SweepError> {
    let range = SweepError::Range { from, to, step };
    if !(from.is_finite() && to.is_finite() && step.is_finite()) || from <= 0.0 || step <= 0.0 || to < from {
        return Err(range);
    }
    let n = ((to - from) / step + 1e-9).floor() as usize + 1;
    if n > MAX_FREQUENCIES {
        return Err(range);
    }
    Ok((0..n).map(|i| ((from + i as f64 * step) * 1e9).round() / 1e9).collect())
}

/// A finished sweep as `boucwen sweep --json` prints it.
#[derive(Clone, Debug, Serialize)]
pub struct SweepSummary<'a> {
    /// The structure's resonance (Hz), if its poles are complex.
    pub structure_resonance_hz: Option<f64>,
    /// One row per frequency.
    pub rows: &'a [Row],
    /// The files written.
    pub files: Vec<String>,
    /// Wall-clock time, s.
    pub wall_s: f64,
    /// Simulated actuator time, s.
    pub actuator_s: f64,
    /// Actuator time per wall-clock time.
    pub speedup: f64,
}

/// A finished sweep.
#[derive(Clone, Debug)]
pub struct SweepResult {
    /// The structure identified first.
    pub structure: Structure,
    /// One row per frequency, in frequency order.
    pub rows: Vec<Row>,
    /// Traces at the requested frequencies.
    pub traces: Vec<Traces>,
    /// Wall-clock time (s).
    pub wall_s: f64,
    /// Simulated actuator time (s).
    pub actuator_s: f64,
}

impl SweepResult {
    /// Actuator time per wall-clock time.
    pub fn speedup(&self) -> f64 {
        self.actuator_s / self.wall_s.max(1e-9)
    }

    /// The summary of `--json`, with the files written.
    pub fn summary(&self, files: &[PathBuf]) -> SweepSummary<'_> {
        SweepSummary {
            structure_resonance_hz: self.structure.resonance_hz,
            rows: &self.rows,
            files: files.iter().map(|p| p.display().to_string()).collect(),
            wall_s: self.wall_s,
            actuator_s: self.actuator_s,
            speedup: self.speedup(),
        }
    }

    /// The whole table as CSV.
    pub fn csv(&self) -> String {
        let mut s = String::from(CSV_HEADER);
        s.push('\n');
        for r in &self.rows {
            s.push_str(&r.csv());
            s.push('\n');
        }
        s
    }
}

/// Runs the sweep on all cores; `progress` is called after each frequency.
pub fn run(opts: &SweepOptions, progress: &(dyn Fn() + Sync)) -> Result<SweepResult, SweepError> {
    if opts.freqs.is_empty() {
        return Err(SweepError::NoFrequencies);
    }
    if !(opts.seconds.is_finite() && opts.seconds > 0.0) {
        return Err(SweepError::Seconds(opts.seconds));
    }
    opts.scenario.validate()?;
    let ts = opts.scenario.sampling.ts_s;
    let periods = opts.seconds * 0.5 * opts.freqs.iter().cloned().fold(f64::INFINITY, f64::min);
    if periods < 2.0 {
        return Err(SweepError::TooShort(opts.seconds));
    }
    if opts.seconds / ts < 1000.0 {
        return Err(SweepError::TooFewSamples(opts.seconds));
    }
    let t0 = std::time::Instant::now();
    let structure = identify_structure(&opts.scenario, opts.drive_amplitude)?;
    let results: Vec<Result<FrequencyResult, SweepError>> = (0..opts.freqs.len())
        .into_par_iter()
        .map(|i| {
            let keep = opts.trace_freqs.iter().any(|t| (t - opts.freqs[i]).abs() < 1e-9);
            let r = run_frequency(opts, &structure, i, keep);
            progress();
            r
        })
        .collect();
    let mut rows = vec![];
    let mut traces = vec![];
    let mut actuator_s = STRUCTURE_SECONDS + LOOP_SECONDS;
    for r in results {
        let r = r?;
        rows.push(r.row);
        traces.extend(r.traces);
        actuator_s += r.actuator_s;
    }
    Ok(SweepResult { structure, rows, traces, wall_s: t0.elapsed().as_secs_f64(), actuator_s })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frequency_lists() {
        assert_eq!(frequencies(1.0, 3.0, 1.0).unwrap(), vec![1.0, 2.0, 3.0]);
        assert_eq!(frequencies(1.0, 2.0, 0.3).unwrap(), vec![1.0, 1.3, 1.6, 1.9]);
        assert_eq!(frequencies(14.0, 23.0, 9.0).unwrap(), vec![14.0, 23.0]);
        assert!(frequencies(0.0, 3.0, 1.0).is_err());
        assert!(frequencies(3.0, 1.0, 1.0).is_err());
        assert!(frequencies(1.0, 3.0, f64::NAN).is_err());
        assert!(frequencies(1.0, 1e6, 1.0).is_err());
    }

    #[test]
    fn rows_serialize_with_the_csv_names_and_null_for_nan() {
        let row = Row {
            freq_hz: 23.0,
            rms_extended_um: f64::NAN,
            rms_enhanced_um: 0.2,
            rmse_uf_um: 3.5,
            rmse_proposed_um: 2.1,
            harmonic_order: 3,
            cancel_order: 3,
            cancel_order_oe: 3,
            alpha_um: 20.2,
            rms_extended_oe_um: 3.6,
            rms_enhanced_oe_um: 0.14,
            rmse_uf_oe_um: 3.56,
            rmse_proposed_oe_um: 0.24,
            rmse_open_um: 4.7,
            rmse_pi_um: 14.3,
            rmse_orc_um: 1.1,
        };
        let j = serde_json::to_value(&row).unwrap();
        let keys: Vec<&str> = j.as_object().unwrap().keys().map(String::as_str).collect();
        let mut csv: Vec<&str> = CSV_HEADER.split(',').collect();
        let mut sorted = keys.clone();
        sorted.sort_unstable();
        csv.sort_unstable();
        assert_eq!(sorted, csv);
        assert!(j["rms_extended_um"].is_null());
        assert_eq!(j["harmonic_order"], 3);
        // An unstable model is said to be one, in the CSV and the tables, not printed as a
        // number; tracking that was not run stays `nan` in a measured sweep's CSV.
        let cells = |line: String| -> Vec<String> { line.split(',').map(str::to_string).collect() };
        let c = cells(row.csv());
        assert_eq!(c[1], UNSTABLE);
        assert_eq!(c[2], "0.200000");
        assert_eq!(cell(row.rms_extended_um), "unstable");
        assert_eq!(cell(row.rms_enhanced_um), "0.2000");
        let untracked = Row { rmse_uf_um: f64::NAN, ..row };
        let c = cells(untracked.csv_with("nan"));
        assert_eq!((c[1].as_str(), c[3].as_str()), (UNSTABLE, "nan"));
        assert_eq!(c.len(), CSV_HEADER.split(',').count());
    }
}
