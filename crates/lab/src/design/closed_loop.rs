//! The paper's two experiments on any plant: identification (section 3) and compensation
//! (section 5), as building blocks for `sweep`.
//!
//! A plant is any [`Plant`]: it takes `u[k]` (V) and returns `y[k]` (µm) at the end of the
//! sample interval (the virtual bimorph, a record, a board, a model); a controller is any
//! [`Controller`] (the compensator, [`Previewed`], or a [`Peer`]). [`closed_loop`] runs one
//! on the other; a plant's error ends the run with the sample it failed at.

use crate::model::HostModel;
use crate::signal::analysis;
use boucwen_core::Plant;
use boucwen_core::compensator::{
    AnyCompensator, CompensatorConfig, HarmonicSpec, PhaseRule, Saturation, harmonic_response,
};
use boucwen_core::controllers::{
    ControlOutput, Controller, ORC_CAPACITY, OpenLoop, OrcController, PiController, TuneOptions, tune,
};
use boucwen_core::rls::RlsConfig;
use boucwen_core::signal::{Oscillator, Sine, sin_cos};
use nalgebra::Complex;
use std::fmt;

/// The identification drive of eq. (13), `u[k] = amplitude·sin(2π f k Ts)`, `n` samples.
pub fn sine(amplitude: f64, freq_hz: f64, ts: f64, n: usize) -> Result<Vec<f64>, boucwen_core::Error> {
    let mut s = Sine::new(amplitude, Oscillator::new(freq_hz, ts)?);
    Ok((0..n).map(|_| s.next_sample()).collect())
}

/// A broadband record for identifying the structure (the paper's Fig. 7 measures the
/// frequency response the same way, tone by tone): `tones` log-spaced sines from `f_lo` to
/// `f_hi`, each on a whole number of cycles of the record, with Schroeder phases (low crest
/// factor), scaled to a peak of `amplitude`.
pub fn multisine(amplitude: f64, f_lo: f64, f_hi: f64, tones: usize, ts: f64, n: usize) -> Vec<f64> {
    let len_s = n as f64 * ts;
    let mut freqs: Vec<f64> = (0..tones)
        .map(|i| {
            let f = f_lo * (f_hi / f_lo).powf(i as f64 / (tones.max(2) - 1) as f64);
            (f * len_s).round().max(1.0) / len_s
        })
        .collect();
    freqs.dedup_by(|a, b| (*a - *b).abs() < 0.5 / len_s);
    let m = freqs.len() as f64;
    let mut x: Vec<f64> = (0..n)
        .map(|k| {
            let t = k as f64 * ts;
            freqs
                .iter()
                .enumerate()
                .map(|(i, f)| {
                    let phase = -std::f64::consts::PI * (i * (i + 1)) as f64 / m;
                    (std::f64::consts::TAU * f * t + phase).sin()
                })
                .sum()
        })
        .collect();
    let peak = x.iter().fold(0.0f64, |a, v| a.max(v.abs())).max(1e-300);
    x.iter_mut().for_each(|v| *v *= amplitude / peak);
    x
}

/// The reference amplitude of eq. (25): `α = Σ y u / Σ u²` over an identification record.
pub fn eq25_amplitude(u: &[f64], y: &[f64]) -> f64 {
    let num: f64 = u.iter().zip(y).map(|(a, b)| a * b).sum();
    let den: f64 = u.iter().map(|a| a * a).sum();
    if den > 0.0 { num / den } else { 0.0 }
}

/// Everything recorded in a tracking run.
#[derive(Clone, Debug, Default)]
pub struct Trace {
    /// Reference `d[k]` (µm).
    pub d: Vec<f64>,
    /// Applied input `u[k]` (V).
    pub u: Vec<f64>,
    /// Measured output `y[k]` (µm).
    pub y: Vec<f64>,
}

impl Trace {
    /// RMS of `y - d` from sample `from` on.
    pub fn rmse_after(&self, from: usize) -> f64 {
        let from = from.min(self.y.len());
        analysis::rms_diff(&self.y[from..], &self.d[from..])
    }

    /// The tracking error `y - d`.
    pub fn error(&self) -> Vec<f64> {
        self.y.iter().zip(&self.d).map(|(y, d)| y - d).collect()
    }
}

/// Settings shared by the compensation runs.
#[derive(Clone, Copy, Debug)]
pub struct CompensationSettings {
    /// The driver's input range (V).
    pub saturation: Saturation<f64>,
    /// Forgetting factor of the harmonic RLS.
    pub lambda: f64,
    /// Initial covariance of the harmonic RLS.
    pub p0: f64,
    /// Bound on each cancellation amplitude (V).
    pub uc_max: f64,
    /// How the plant's response at `n·f` is obtained.
    pub phase_rule: PhaseRule<f64>,
}

impl Default for CompensationSettings {
    fn default() -> Self {
        Self {
            saturation: Saturation::symmetric(10.0),
            lambda: 0.999,
            p0: 1e-2,
            uc_max: 2.0,
            phase_rule: PhaseRule::Model,
        }
    }
}

/// Length of the reference's fade-in (s).
pub const FADE_IN_S: f64 = 0.5;

/// The reference of every tracking run: `d[k] = α·fade(k)·sin(2π f k Ts)`, with a
/// raised-cosine fade over [`FADE_IN_S`].
#[derive(Clone, Copy, Debug)]
pub struct Reference {
    alpha: f64,
    drive: Oscillator,
    /// `2π f Ts`.
    w: f64,
    /// Fade-in length in samples (at least 1).
    fade: f64,
}

impl Reference {
    /// The reference of amplitude `alpha` at `freq_hz`, sample interval `ts`.
    pub fn new(alpha: f64, freq_hz: f64, ts: f64) -> Result<Self, boucwen_core::Error> {
        Ok(Self {
            alpha,
            drive: Oscillator::new(freq_hz, ts)?,
            w: std::f64::consts::TAU * freq_hz * ts,
            fade: (FADE_IN_S / ts).round().max(1.0),
        })
    }

    /// The envelope at (fractional) sample `k`: a raised cosine over the fade, then 1.
    fn envelope(&self, k: f64) -> f64 {
        if k < self.fade { 0.5 - 0.5 * (std::f64::consts::PI * k.max(0.0) / self.fade).cos() } else { 1.0 }
    }

    /// `d[k]`, its phase from the core's phase accumulator (as the board computes it).
    pub fn sample(&self, k: u64) -> f64 {
        self.alpha * self.envelope(k as f64) * sin_cos::<f64>(self.drive.phase_at(k)).0
    }

    /// `d` at a fractional sample `k` (the preview of a delayed plant).
    pub fn at(&self, k: f64) -> f64 {
        self.alpha * self.envelope(k) * (self.w * k).sin()
    }
}

/// Why a closed-loop run failed.
#[derive(Debug)]
pub enum ExperimentError {
    /// The core rejected a parameter (frequency, controller, tuning) or a step.
    Core(boucwen_core::Error),
    /// The plant failed.
    Plant {
        /// The plant's name.
        plant: String,
        /// The sample at which it failed.
        sample: usize,
        /// Its error.
        error: Box<dyn std::error::Error + Send + Sync>,
    },
}

impl fmt::Display for ExperimentError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ExperimentError::Core(e) => write!(f, "{e}"),
            ExperimentError::Plant { plant, sample, error } => {
                write!(f, "{plant} at sample {sample}: {error}")
            }
        }
    }
}

impl std::error::Error for ExperimentError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            ExperimentError::Core(e) => Some(e),
            ExperimentError::Plant { error, .. } => Some(error.as_ref()),
        }
    }
}

impl From<boucwen_core::Error> for ExperimentError {
    fn from(e: boucwen_core::Error) -> Self {
        ExperimentError::Core(e)
    }
}

/// The plant's response at each harmonic from the model: its frequency response at `n·f`
/// with the input delay (`e^{-i 2π n f τ Ts}`) under [`PhaseRule::Model`], the paper's table
/// under [`PhaseRule::Table`].
pub fn model_harmonics(
    model: &HostModel,
    orders: &[u32],
    freq_hz: f64,
    ts: f64,
    rule: PhaseRule<f64>,
) -> Vec<HarmonicSpec<f64>> {
    orders
        .iter()
        .map(|&n| {
            let g = harmonic_response(&model.ext, n, freq_hz, ts, rule);
            let response = match rule {
                PhaseRule::Model => {
                    let w = -std::f64::consts::TAU * n as f64 * freq_hz * ts * model.delay;
                    g * Complex::new(w.cos(), w.sin())
                }
                PhaseRule::Table { .. } => g,
            };
            HarmonicSpec { order: n, response }
        })
        .collect()
}

/// Measures the actuator's incremental response at `n·f` at its operating point: `y_probe`
/// is the response to `u_drive + eps·sin(2π n f k Ts)`, `y_drive` the response to
/// `u_drive` alone over the same samples; the `n·f` component of the difference over the
/// last half, divided by the probe's, is the response. Near a superharmonic resonance it
/// can differ by tens of degrees from a small-signal model's (the stiffened beam, driven
/// hard at `f`, answers a small input at `n·f` differently than at rest).
pub fn probe_response(
    y_drive: &[f64],
    y_probe: &[f64],
    freq_hz: f64,
    order: u32,
    eps: f64,
    ts: f64,
) -> Result<Complex<f64>, boucwen_core::Error> {
    let n = y_drive.len().min(y_probe.len());
    let fh = order as f64 * freq_hz;
    let probe = sine(eps, fh, ts, n)?;
    let from = n / 2;
    let diff: Vec<f64> = y_probe[from..n].iter().zip(&y_drive[from..n]).map(|(a, b)| a - b).collect();
    let t = analysis::tone(&diff, fh, ts);
    let p = analysis::tone(&probe[from..], fh, ts);
    if !(p.amp > 0.0 && t.amp.is_finite()) {
        return Err(boucwen_core::Error::OutOfRange("probe (no response measured)"));
    }
    Ok(Complex::from_polar(t.amp / p.amp, t.phase - p.phase))
}

/// The probe input: `u_drive + eps·sin(2π n f k Ts)`.
pub fn with_probe(
    u_drive: &[f64],
    freq_hz: f64,
    order: u32,
    eps: f64,
    ts: f64,
) -> Result<Vec<f64>, boucwen_core::Error> {
    let probe = sine(eps, order as f64 * freq_hz, ts, u_drive.len())?;
    Ok(u_drive.iter().zip(&probe).map(|(a, b)| a + b).collect())
}

/// The compensator of [`track`], previewing the reference by the model's input delay
/// ([`boucwen_core::compensator::Compensator::step_previewed`]): at its `k`-th step the
/// inverse works on `d` at `k + τ`, the tracking error on `d[k]`.
#[derive(Clone, Debug)]
pub struct Previewed {
    comp: AnyCompensator<f64, 2>,
    reference: Reference,
    delay: f64,
    k: u64,
}

impl Previewed {
    /// The compensator built from `model` (its extended part, its delay `τ`), cancelling
    /// `harmonics` (at most two), for `reference`.
    pub fn new(
        model: &HostModel,
        harmonics: &[HarmonicSpec<f64>],
        reference: Reference,
        set: &CompensationSettings,
    ) -> Result<Self, boucwen_core::Error> {
        let base = CompensatorConfig {
            model: model.ext,
            drive: reference.drive,
            harmonics: [],
            rls: RlsConfig::with_forgetting(set.lambda, set.p0),
            saturation: set.saturation,
            uc_max: set.uc_max,
        };
        Ok(Self { comp: AnyCompensator::new(base, harmonics)?, reference, delay: model.delay, k: 0 })
    }
}

impl Controller<f64> for Previewed {
    fn step(&mut self, d: f64, y_prev: Option<f64>) -> Result<ControlOutput<f64>, boucwen_core::Error> {
        let d_ahead = self.reference.at(self.k as f64 + self.delay);
        let out = self.comp.step_previewed(d, d_ahead, y_prev)?;
        self.k += 1;
        Ok(out.into())
    }

    fn reset(&mut self) {
        self.comp.reset();
        self.k = 0;
    }
}

/// Tracks `d[k] = α sin(2π f k Ts)` for `n` samples on `plant` (from its current state)
/// with the compensator built from `model`, cancelling the harmonics `harmonics` (empty:
/// `u_f` alone, eqs. 16/17; otherwise the proposed law, eqs. 20/21), each with the plant's
/// response at its frequency.
///
/// The reference is faded in over the first [`FADE_IN_S`] (a raised-cosine envelope on `α`).
/// The direct inverse is exact: started from rest on a full-amplitude sine it demands that
/// the resting actuator reach `d[1]` within one sample (for a lightly damped structure, many
/// times the steady input), which drives the model's hysteresis far outside the loop it was
/// identified on. The paper measures the RMSE after 20 s, long after start-up; the fade
/// changes nothing there.
pub fn track<P>(
    plant: &mut P,
    model: &HostModel,
    harmonics: &[HarmonicSpec<f64>],
    alpha: f64,
    freq_hz: f64,
    n: usize,
    set: &CompensationSettings,
) -> Result<Trace, ExperimentError>
where
    P: Plant<f64> + ?Sized,
    P::Error: std::error::Error + Send + Sync + 'static,
{
    let reference = Reference::new(alpha, freq_hz, plant.sample_interval_s())?;
    let mut comp = Previewed::new(model, harmonics, reference, set)?;
    closed_loop(plant, &mut comp, &reference, n)
}

/// The peer controllers of [`boucwen_core::controllers`], tuned by its rule from `model`.
#[derive(Clone, Copy, Debug)]
pub enum Peer {
    /// `u = d/G0`.
    OpenLoop,
    /// The PI feedback alone (no feedforward).
    Pi,
    /// Li et al.'s odd-harmonic repetitive controller on that PI.
    Orc,
}

impl Peer {
    /// The peer tuned from `model` by [`boucwen_core::controllers::tune`] (the model's input
    /// delay included, the default sensitivity bound and ORC placement, plain feedback) for
    /// a reference at `freq_hz`.
    pub fn tuned(
        self,
        model: &HostModel,
        freq_hz: f64,
        ts: f64,
        set: &CompensationSettings,
    ) -> Result<Box<dyn Controller<f64> + Send>, boucwen_core::Error> {
        let drive = Oscillator::new(freq_hz, ts)?;
        let opts = TuneOptions { input_delay_samples: model.delay, ..TuneOptions::default() };
        let tuning = tune(&model.ext, drive, ts, set.saturation, &opts)?;
        Ok(match self {
            Peer::OpenLoop => Box::new(OpenLoop::new(tuning.open_loop)?),
            Peer::Pi => Box::new(PiController::new(tuning.pi.pi)?),
            Peer::Orc => Box::new(OrcController::<f64, ORC_CAPACITY>::new(tuning.pi.pi, tuning.orc.orc)?),
        })
    }
}

/// Tracks the same faded-in reference as [`track`] with a peer controller
/// ([`Peer::tuned`] from `model`).
pub fn track_peer<P>(
    plant: &mut P,
    model: &HostModel,
    peer: Peer,
    alpha: f64,
    freq_hz: f64,
    n: usize,
    set: &CompensationSettings,
) -> Result<Trace, ExperimentError>
where
    P: Plant<f64> + ?Sized,
    P::Error: std::error::Error + Send + Sync + 'static,
{
    let ts = plant.sample_interval_s();
    let reference = Reference::new(alpha, freq_hz, ts)?;
    let mut ctrl = peer.tuned(model, freq_hz, ts, set)?;
    closed_loop(plant, ctrl.as_mut(), &reference, n)
}

/// Runs `n` samples of `controller` on `plant` tracking `reference`: at sample `k` the
/// controller gets `d[k]` and `y[k-1]` and its `u[k]` goes to the plant. The one
/// closed-loop runner of the compensator and the peers.
pub fn closed_loop<P>(
    plant: &mut P,
    controller: &mut dyn Controller<f64>,
    reference: &Reference,
    n: usize,
) -> Result<Trace, ExperimentError>
where
    P: Plant<f64> + ?Sized,
    P::Error: std::error::Error + Send + Sync + 'static,
{
    let mut t = Trace { d: Vec::with_capacity(n), u: Vec::with_capacity(n), y: Vec::with_capacity(n) };
    let mut y_prev = None;
    for k in 0..n {
        let d = reference.sample(k as u64);
        let u = controller.step(d, y_prev)?.u;
        let y = plant.step(u).map_err(|e| ExperimentError::Plant {
            plant: plant.name().to_owned(),
            sample: k,
            error: Box::new(e),
        })?;
        y_prev = Some(y);
        t.d.push(d);
        t.u.push(u);
        t.y.push(y);
    }
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Branch;
    use boucwen_core::model::{BoucWenParams, ExtendedParams};
    use boucwen_core::plant::ModelPlant;

    #[test]
    fn eq25_is_the_least_squares_gain() {
        let u = sine(1.0, 5.0, 1e-3, 1000).unwrap();
        let y: Vec<f64> = u.iter().map(|v| 17.0 * v + 3.0).collect();
        assert!((eq25_amplitude(&u, &y) - 17.0).abs() < 1e-9);
    }

    #[test]
    fn proposed_law_beats_uf_alone_on_a_model_with_a_harmonic() {
        let w0 = std::f64::consts::TAU * 0.07;
        let ext = ExtendedParams {
            bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
            ar: [2.0 * 0.97 * w0.cos(), -0.97 * 0.97],
        };
        let plant_model = HostModel {
            ext,
            drive_hz: 23.0,
            branches: vec![Branch { order: 3, alpha_s: 0.1, alpha_c: 0.05, ar: [0.0, 0.0] }],
            drift: vec![],
            delay: 0.0,
        };
        let controller_model = HostModel { branches: vec![], ..plant_model.clone() };
        let n = 15_000;
        let u_probe = sine(1.0, 23.0, 1e-3, n).unwrap();
        let y_probe = plant_model.simulate(&u_probe, 1e-3).unwrap();
        let alpha = eq25_amplitude(&u_probe, &y_probe) * 0.2;
        let set = CompensationSettings::default();
        let mut rmse = vec![];
        for orders in [&[][..], &[3][..]] {
            // The plant: the model itself, stepped sample by sample.
            let mut plant = ModelPlant::new(plant_model.enhanced_for_test(), 1e-3).unwrap();
            let h = model_harmonics(&controller_model, orders, 23.0, 1e-3, set.phase_rule);
            let t = track(&mut plant, &controller_model, &h, alpha, 23.0, n, &set).unwrap();
            rmse.push(t.rmse_after(5000) / alpha);
        }
        assert!(rmse[0] > 0.05 && rmse[1] < 0.01, "{rmse:?}");
    }

    /// A plant that passes `u` through and breaks at sample 7.
    struct Breaks {
        k: usize,
    }

    #[derive(Debug)]
    struct CableCut;

    impl fmt::Display for CableCut {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str("cable cut")
        }
    }

    impl std::error::Error for CableCut {}

    impl Plant<f64> for Breaks {
        type Error = CableCut;
        fn step(&mut self, u: f64) -> Result<f64, CableCut> {
            if self.k == 7 {
                return Err(CableCut);
            }
            self.k += 1;
            Ok(u)
        }
        fn sample_interval_s(&self) -> f64 {
            1e-3
        }
        fn reset(&mut self) -> Result<(), CableCut> {
            self.k = 0;
            Ok(())
        }
        fn name(&self) -> &str {
            "test plant"
        }
    }

    #[test]
    fn a_plant_error_ends_the_run_naming_the_sample() {
        let model = HostModel {
            ext: ExtendedParams {
                bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
                ar: [0.5, 0.0],
            },
            drive_hz: 10.0,
            branches: vec![],
            drift: vec![],
            delay: 0.0,
        };
        let set = CompensationSettings::default();
        for peer in [Peer::OpenLoop, Peer::Pi, Peer::Orc] {
            let e = track_peer(&mut Breaks { k: 0 }, &model, peer, 5.0, 10.0, 100, &set).unwrap_err();
            assert!(matches!(e, ExperimentError::Plant { sample: 7, .. }), "{e:?}");
            assert_eq!(e.to_string(), "test plant at sample 7: cable cut");
        }
        let e = track(&mut Breaks { k: 0 }, &model, &[], 5.0, 10.0, 100, &set).unwrap_err();
        assert_eq!(e.to_string(), "test plant at sample 7: cable cut");
        // Before it breaks, the run is the plain loop.
        let t = track(&mut Breaks { k: 0 }, &model, &[], 5.0, 10.0, 7, &set).unwrap();
        assert_eq!(t.d.len(), 7);
        assert_eq!(t.y, t.u);
    }
}
