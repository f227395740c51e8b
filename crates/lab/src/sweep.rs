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
//!    [`MIN_HARMONIC_SHARE`] and its amplitude at least [`MIN_HARMONIC_REL`] of the output's
//!    fundamental; with [`HarmonicChoice::Paper`],
//!    the paper's table (5th at 14 Hz, 3rd at 18–28 Hz). Where no branch is chosen the
//!    enhanced model *is* the extended model and the proposed controller *is* `u_f`, and the
//!    columns repeat the baseline (`harmonic_order` is 0).
//! 3. **Compensation (section 5, Fig. 16).** Track `d[k] = α sin(2π f k Ts)` with `α` from
//!    eq. (25), once with `u_f` alone (eqs. 16/17) and once with the proposed law (eqs.
//!    20/21), each with the models of both identification methods; the RMSE is taken after
//!    the settling time (the paper: after 20 s of 100 s). As in the paper, `u_f` alone is
//!    synthesised from the extended model. The proposed law cancels the harmonic that the
//!    tracking error under `u_f` shows (the paper's Fig. 13 reasoning: the odd harmonic
//!    holding the largest share of that error, at least [`MIN_HARMONIC_SHARE`] of its power
//!    and [`MIN_CANCEL_REL`] of `α`); its `u_f` comes from the first two equations of the
//!    enhanced model when that model carries the same harmonic and is invertible, else from
//!    the extended model. Where no harmonic qualifies the proposed law is `u_f` itself.

use crate::analysis;
use crate::experiment::{self, CompensationSettings, Peer, Trace};
use crate::fit::{
    self, Averaging, DelaySearch, FitError, HostModel, LoopSearch, LoopShape, ModelSpec, OeOptions, Samples,
    StructureSearch,
};
use boucwen_core::compensator::{HarmonicSpec, PhaseRule};
use boucwen_sim::{Bimorph, Scenario, SimError};
use rayon::prelude::*;
use std::fmt;

/// How the harmonic order of the enhanced model is chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HarmonicChoice {
    /// From the data: the dominant odd harmonic of the extended fit's residual.
    Auto,
    /// The paper's table: 5th at 14 Hz, 3rd at 18–28 Hz, none elsewhere.
    Paper,
}

/// Where the harmonic cancellation takes the actuator's response at `n·f` from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ResponseSource {
    /// The identified model's frequency response (small-signal structure, with the delay).
    Model,
    /// The paper's table (eqs. 22/23): 0 below the flip frequency, π above.
    Table {
        /// The flip frequency (Hz; 66 in the paper).
        flip_hz: f64,
    },
    /// The response identified at the operating point: the identification drive plus a
    /// small probe at `n·f`, for [`PROBE_SECONDS`].
    Probe,
}

/// Length of a probe run (s).
pub const PROBE_SECONDS: f64 = 3.0;
/// Probe amplitude relative to the drive amplitude.
pub const PROBE_REL: f64 = 0.01;

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

/// Identifies the structure from a multisine record on a fresh actuator.
pub fn identify_structure(scenario: &Scenario, drive_amplitude: f64) -> Result<Structure, SweepError> {
    let ts = scenario.sampling.ts_s;
    let err = |e| SweepError::Fit(0.0, e);
    let seed = scenario.seed.wrapping_mul(1_000_003).wrapping_sub(1);
    // Structure and delay: a small broadband record, where the actuator is nearly linear.
    let n = (STRUCTURE_SECONDS / ts).round() as usize;
    let u =
        experiment::multisine(STRUCTURE_AMPLITUDE * drive_amplitude, 1.0, (0.2 / ts).min(200.0), 40, ts, n);
    let y = Bimorph::new(&scenario.clone().with_seed(seed))?.run(&u)?;
    let opt = OeOptions {
        samples: Samples::First(8000),
        averaging: Averaging::Off,
        delay: DelaySearch::Fit,
        hysteresis: LoopSearch::Linear,
        ..OeOptions::default()
    };
    let fit = fit::fit_oe(&u, &y, ts, n, &ModelSpec::extended(1.0), &[], &opt).map_err(err)?;
    let resonance_hz = crate::diagnose::resonance_hz(fit.model.ext.ar, ts);
    // The loop: a quasi-static sine at the drive amplitude, with that structure and delay.
    let n_loop = (LOOP_SECONDS / ts).round() as usize;
    let u_loop =
        experiment::sine(drive_amplitude, LOOP_HZ, ts, n_loop).map_err(|e| SweepError::Core(LOOP_HZ, e))?;
    let y_loop = Bimorph::new(&scenario.clone().with_seed(seed.wrapping_sub(1)))?.run(&u_loop)?;
    let loop_opt = OeOptions {
        samples: Samples::First(n_loop),
        averaging: Averaging::Off,
        structure: StructureSearch::Fixed(fit.model.ext.ar),
        delay: DelaySearch::Fixed(fit.model.delay),
        ..OeOptions::default()
    };
    let loop_fit = fit::fit_oe(&u_loop, &y_loop, ts, n_loop, &ModelSpec::extended(LOOP_HZ), &[], &loop_opt)
        .map_err(err)?;
    let shape = loop_fit.model.shape().ok_or(SweepError::Fit(LOOP_HZ, FitError::NoStableModel))?;
    let mut model = loop_fit.model;
    model.ext.ar = fit.model.ext.ar;
    Ok(Structure { model, shape, rms_fit_um: fit.rms_fit, resonance_hz })
}

/// One frequency's results. `NaN` where a model was unstable in free run.
#[derive(Clone, Debug, PartialEq)]
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

/// The CSV header: the paper's five columns first.
pub const CSV_HEADER: &str = "freq_hz,rms_extended_um,rms_enhanced_um,rmse_uf_um,rmse_proposed_um,\
rmse_open_um,rmse_pi_um,rmse_orc_um,harmonic_order,cancel_order,cancel_order_oe,alpha_um,rms_extended_oe_um,rms_enhanced_oe_um,rmse_uf_oe_um,\
rmse_proposed_oe_um";

impl Row {
    /// The row as CSV (same order as [`CSV_HEADER`]).
    pub fn csv(&self) -> String {
        let v = [self.rms_extended_um, self.rms_enhanced_um, self.rmse_uf_um, self.rmse_proposed_um];
        let w =
            [self.rms_extended_oe_um, self.rms_enhanced_oe_um, self.rmse_uf_oe_um, self.rmse_proposed_oe_um];
        let peers = [self.rmse_open_um, self.rmse_pi_um, self.rmse_orc_um];
        let f = |x: f64| if x.is_finite() { format!("{x:.6}") } else { "nan".into() };
        format!(
            "{},{},{},{},{},{},{:.6},{}",
            self.freq_hz,
            v.map(f).join(","),
            peers.map(f).join(","),
            self.harmonic_order,
            self.cancel_order,
            self.cancel_order_oe,
            self.alpha_um,
            w.map(f).join(",")
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
    /// The options are unusable.
    Options(String),
}

impl fmt::Display for SweepError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SweepError::Sim(e) => write!(f, "virtual bimorph: {e}"),
            SweepError::Fit(hz, e) => write!(f, "at {hz} Hz: {e}"),
            SweepError::Core(hz, e) => write!(f, "at {hz} Hz: {e}"),
            SweepError::Options(s) => write!(f, "{s}"),
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
            Ok(dominant_odd_harmonic(&r, f, ts, MIN_HARMONIC_SHARE, MIN_HARMONIC_REL * out_amp)
                .unwrap_or((0, 0.0)))
        }
    }
}

/// Smallest share of the error power a harmonic must hold to be chosen.
pub const MIN_HARMONIC_SHARE: f64 = 0.2;
/// Smallest amplitude of a harmonic the model gets a branch for, relative to the output's
/// fundamental: below this a term is not worth it.
pub const MIN_HARMONIC_REL: f64 = 0.02;
/// Smallest amplitude of a harmonic the proposed law cancels, relative to `α`: a change of
/// controller must be worth its side effects (the cancellation input passes through the
/// loop and leaves a little at other frequencies).
pub const MIN_CANCEL_REL: f64 = 0.05;

/// The dominant odd harmonic (order ≥ 3, below Nyquist) of `x`, if it holds at least
/// `min_share` of `x`'s power and has an amplitude of at least `min_amp`.
pub fn dominant_odd_harmonic(x: &[f64], f: f64, ts: f64, min_share: f64, min_amp: f64) -> Option<(u32, f64)> {
    let power = analysis::rms(x).powi(2);
    let kmax = ((0.5 / ts) / f).floor() as usize;
    analysis::harmonics(x, f, ts, kmax.min(40))
        .iter()
        .enumerate()
        .map(|(i, t)| ((i + 1) as u32, t.amp))
        .filter(|(n, _)| n % 2 == 1 && *n >= 3)
        .map(|(n, amp)| (n, amp * amp / 2.0 / power.max(1e-300), amp))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .filter(|&(_, share, amp)| share >= min_share && amp >= min_amp)
        .map(|(n, share, _)| (n, share))
}

/// The harmonic for the proposed law, from the tracking error under `u_f` alone.
fn cancel_order(choice: HarmonicChoice, f: f64, ts: f64, uf: &Trace, settle: usize, alpha: f64) -> u32 {
    match choice {
        HarmonicChoice::Paper => paper_order(f, ts),
        HarmonicChoice::Auto => {
            let e = uf.error();
            let from = settle.min(e.len());
            dominant_odd_harmonic(&e[from..], f, ts, MIN_HARMONIC_SHARE, MIN_CANCEL_REL * alpha.abs())
                .map_or(0, |(n, _)| n)
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

/// One frequency of the sweep.
pub fn run_frequency(
    opts: &SweepOptions,
    structure: &Structure,
    index: usize,
    keep_traces: bool,
) -> Result<(Row, Option<Traces>, f64), SweepError> {
    let f = opts.freqs[index];
    let ts = opts.scenario.sampling.ts_s;
    let n = (opts.seconds / ts).round() as usize;
    let fit_end = n / 2;
    let settle = (opts.settle_s() / ts).round() as usize;
    let core = |e| SweepError::Core(f, e);
    let fit_err = |e| SweepError::Fit(f, e);
    // Independent noise per frequency and run, reproducible from the scenario's seed.
    let seed = |run: u64| opts.scenario.seed.wrapping_mul(1_000_003).wrapping_add(index as u64 * 16 + run);
    let plant = |run: u64| Bimorph::new(&opts.scenario.clone().with_seed(seed(run)));

    // 1. Identification record.
    let u = experiment::sine(opts.drive_amplitude, f, ts, n).map_err(core)?;
    let y = plant(0)?.run(&u)?;
    let mut samples = n;

    // 2. Fits.
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
    let ext_fit = fit::fit_oe(&u, &y, ts, fit_end, &ModelSpec::extended(f), &[], &oe).map_err(fit_err)?;
    let ext_oe = ext_fit.model.clone();
    let (order, _share) = choose_order(opts.harmonics, f, ts, &u, &y, &ext_oe, fit_end).map_err(fit_err)?;
    let orders: Vec<u32> = if order > 0 { vec![order] } else { vec![] };
    let enh_fit = if orders.is_empty() {
        ext_fit.clone()
    } else {
        fit::fit_oe(&u, &y, ts, fit_end, &ModelSpec::enhanced(f, &orders), std::slice::from_ref(&ext_oe), &oe)
            .map_err(fit_err)?
    };
    let enh_oe = enh_fit.model.clone();
    let ext_rls = fit::fit_paper_rls(&u, &y, ts, fit_end, &ModelSpec::extended(f)).map_err(fit_err)?;
    // The paper's RLS fits the branch by equation error; its free run can come out worse than
    // the extended model's. The branch is kept only if the free run on the fitted half (after
    // the start-up) improves: a choice made on the fitted data alone.
    let enh_rls = if orders.is_empty() {
        ext_rls.clone()
    } else {
        let cand =
            fit::fit_paper_rls(&u, &y, ts, fit_end, &ModelSpec::enhanced(f, &orders)).map_err(fit_err)?;
        let on_fit = |m: &HostModel| -> Result<f64, SweepError> {
            let sim = m.simulate(&u[..fit_end], ts).map_err(fit_err)?;
            let skip = (fit_end / 5).min(2000);
            Ok(analysis::rms_diff(&sim[skip..], &y[skip..fit_end]))
        };
        let (c, e) = (on_fit(&cand)?, on_fit(&ext_rls)?);
        if c < e { cand } else { ext_rls.clone() }
    };
    let held_out = |m: &HostModel| -> Result<(f64, Vec<f64>), SweepError> {
        let sim = m.simulate(&u, ts).map_err(fit_err)?;
        let r = analysis::rms_diff(&sim[fit_end..], &y[fit_end..]);
        Ok((if r.is_finite() { r } else { f64::NAN }, sim))
    };
    let (rms_ext_rls, _) = held_out(&ext_rls)?;
    let (rms_enh_rls, _) = held_out(&enh_rls)?;
    let (rms_ext_oe, y_ext) = held_out(&ext_oe)?;
    let (rms_enh_oe, y_enh) = held_out(&enh_oe)?;

    // 3. Compensation: α from eq. (25) on the identification record.
    let alpha = experiment::eq25_amplitude(&u, &y);
    let set = &opts.compensation;
    // The actuator's response at n·f for the cancellation (probed once per order).
    let mut probed: Vec<(u32, nalgebra::Complex<f64>)> = vec![];
    let mut responses = |model: &HostModel, order: u32| -> Result<Vec<HarmonicSpec<f64>>, SweepError> {
        if order == 0 {
            return Ok(vec![]);
        }
        let response = match opts.response {
            ResponseSource::Model => {
                experiment::model_harmonics(model, &[order], f, ts, PhaseRule::Model)[0].response
            }
            ResponseSource::Table { flip_hz } => {
                experiment::model_harmonics(model, &[order], f, ts, PhaseRule::Table { flip_hz })[0].response
            }
            ResponseSource::Probe => match probed.iter().find(|(o, _)| *o == order) {
                Some((_, g)) => *g,
                None => {
                    let m = ((PROBE_SECONDS / ts).round() as usize).min(n);
                    let eps = PROBE_REL * opts.drive_amplitude;
                    let up = experiment::with_probe(&u[..m], f, order, eps, ts).map_err(core)?;
                    let yp = plant(5)?.run(&up)?;
                    samples += m;
                    let g = experiment::probe_response(&y[..m], &yp, f, order, eps, ts).map_err(core)?;
                    probed.push((order, g));
                    g
                }
            },
        };
        Ok(vec![HarmonicSpec { order, response }])
    };
    let tracking = |model: &HostModel, h: &[HarmonicSpec<f64>], run: u64| -> Result<Trace, SweepError> {
        let mut b = plant(run)?;
        let mut p = |uk: f64| b.step(uk).unwrap_or(f64::NAN);
        experiment::track(&mut p, model, h, alpha, f, ts, n, set).map_err(core)
    };
    let finite = |x: f64| if x.is_finite() { x } else { f64::NAN };
    // u_f alone is synthesised from the extended model. The proposed law cancels the
    // harmonic the tracking error under u_f shows (Fig. 13); its u_f comes from the first two
    // equations of the enhanced model (the paper's section 4) when that model carries the
    // same harmonic and is invertible, else from the extended model.
    let invertible = |m: &HostModel| fit::invertible_for(m, &u);
    let uf_rls = tracking(&ext_rls, &[], 1)?;
    let n_rls = cancel_order(opts.harmonics, f, ts, &uf_rls, settle, alpha);
    let base_rls = if n_rls == order && invertible(&enh_rls) { &enh_rls } else { &ext_rls };
    let h_rls = responses(base_rls, n_rls)?;
    let prop_rls = if n_rls == 0 { uf_rls.clone() } else { tracking(base_rls, &h_rls, 2)? };
    let uf_oe = tracking(&ext_oe, &[], 3)?;
    let n_oe = cancel_order(opts.harmonics, f, ts, &uf_oe, settle, alpha);
    let base_oe = if n_oe == order && enh_fit.invertible { &enh_oe } else { &ext_oe };
    let h_oe = responses(base_oe, n_oe)?;
    let prop_oe = if n_oe == 0 { uf_oe.clone() } else { tracking(base_oe, &h_oe, 4)? };
    samples += 2 * n + usize::from(n_rls > 0) * n + usize::from(n_oe > 0) * n;
    // The peers, tuned from the output-error extended model by the core's rule.
    let peer = |p: Peer, run: u64| -> Result<Trace, SweepError> {
        let mut b = plant(run)?;
        let mut step = |uk: f64| b.step(uk).unwrap_or(f64::NAN);
        experiment::track_peer(&mut step, &ext_oe, p, alpha, f, ts, n, set).map_err(core)
    };
    let open = peer(Peer::OpenLoop, 6)?;
    let pi = peer(Peer::Pi, 7)?;
    let orc = peer(Peer::Orc, 8)?;
    samples += 3 * n;

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
    let traces = keep_traces.then(|| Traces {
        freq_hz: f,
        ts,
        split: fit_end,
        u,
        y,
        y_extended: y_ext,
        y_enhanced: y_enh,
        track_uf: uf_oe,
        track_proposed: prop_oe,
    });
    Ok((row, traces, samples as f64 * ts))
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
        return Err(SweepError::Options("no frequencies to sweep".into()));
    }
    if !(opts.seconds.is_finite() && opts.seconds > 0.0) {
        return Err(SweepError::Options(format!("--seconds must be > 0 (got {})", opts.seconds)));
    }
    opts.scenario.validate()?;
    let ts = opts.scenario.sampling.ts_s;
    let periods = opts.seconds * 0.5 * opts.freqs.iter().cloned().fold(f64::INFINITY, f64::min);
    if periods < 2.0 {
        return Err(SweepError::Options(format!(
            "--seconds {} is too short: the held-out half must hold at least 2 periods of the lowest frequency",
            opts.seconds
        )));
    }
    if opts.seconds / ts < 1000.0 {
        return Err(SweepError::Options(format!("--seconds {} gives fewer than 1000 samples", opts.seconds)));
    }
    let t0 = std::time::Instant::now();
    let structure = identify_structure(&opts.scenario, opts.drive_amplitude)?;
    let results: Vec<Result<(Row, Option<Traces>, f64), SweepError>> = (0..opts.freqs.len())
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
        let (row, tr, secs) = r?;
        rows.push(row);
        traces.extend(tr);
        actuator_s += secs;
    }
    Ok(SweepResult { structure, rows, traces, wall_s: t0.elapsed().as_secs_f64(), actuator_s })
}
