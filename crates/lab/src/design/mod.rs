//! Design: from an actuator (or a record of it) to the board's parameters.
//!
//! One place turns an identification into what the driver board runs, for `boucwen hil`,
//! `cargo xtask qemu` and the tests alike:
//!
//! * [`controller_params`]: a compensator designed on the host in `f64` (the identified
//!   extended model, the cancelled harmonics, RLS settings, the driver's range, the
//!   reference) rounded to the board's `f32` [`ControllerParams`] and validated as the board
//!   validates them;
//! * [`orc_params`]: the same for Li et al.'s repetitive controller on its PI;
//! * [`design_on_plant`]: the whole design against a plant the host can drive (the virtual
//!   bimorph, the board in its plant mode): identification record, output-error fit of the
//!   extended model with an invertible loop, α from eq. (25), a trial run of `u_f` alone,
//!   and the odd harmonic that stands out in its tracking error cancelled with the model's
//!   response at `n·f`.
//!
//! The rule that picks the cancelled harmonic ([`cancelled_harmonic`]) and the sources of
//! the actuator's response at `n·f` ([`ResponseSource`], [`probe_response_on`]) are the
//! same for `boucwen hil` and for every frequency of the sweep ([`crate::experiments::sweep`]).

pub mod board;
pub mod closed_loop;

use crate::fit::{self, Averaging, DelaySearch, FitError, OeOptions, Samples};
use crate::model::{HostModel, ModelSpec};
use crate::signal::analysis;
use boucwen_core::compensator::{HarmonicSpec, PhaseRule, Saturation};
use boucwen_core::controllers::{OrcConfig, PiConfig};
use boucwen_core::model::{BoucWenParams, ExtendedParams};
use boucwen_core::rls::RlsConfig;
use boucwen_core::signal::Oscillator;
use boucwen_core::{Error, Plant};
use boucwen_link::device::Controller;
use boucwen_link::message::{ControllerParams, MAX_AR, MAX_HARMONICS, OrcParams};
use nalgebra::Complex;
use std::error::Error as StdError;
use std::fmt;

/// The reference of a control run, as [`controller_params`] takes it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceSpec {
    /// Frequency `f`, Hz.
    pub freq_hz: f64,
    /// Amplitude `α`, µm.
    pub amplitude_um: f64,
    /// Raised-cosine fade-in, s (0: none).
    pub fade_s: f64,
    /// The preview `τ`, samples: the identified model's input delay
    /// ([`HostModel::delay`]); the board's inverse works on the reference `τ` samples ahead
    /// (0: none).
    pub preview_samples: f64,
}

/// The board's parameters for a compensator designed on the host in `f64`: the
/// identified `model` (AR order `P ≤` [`MAX_AR`], padded with zeros), the cancelled
/// `harmonics` (at most [`MAX_HARMONICS`]), RLS settings, the driver's range and the
/// reference, at sample interval `ts_s`. Values are rounded to `f32`; the result is
/// validated as the board validates it ([`ControllerParams::validate`]).
///
/// ```
/// use boucwen_core::compensator::Saturation;
/// use boucwen_core::model::{BoucWenParams, ExtendedParams};
/// use boucwen_core::rls::RlsConfig;
/// use boucwen_lab::design::{controller_params, ReferenceSpec};
/// let model = ExtendedParams {
///     bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
///     ar: [1.5, -0.6],
/// };
/// let reference = ReferenceSpec { freq_hz: 23.0, amplitude_um: 20.0, fade_s: 0.5, preview_samples: 0.0 };
/// let p = controller_params(&model, &[], RlsConfig::with_forgetting(0.999, 1e-2),
///     Saturation::symmetric(10.0), 2.0, reference, 1e-3)?;
/// assert_eq!((p.sample_period_us, p.fade_samples, p.model.ar), (1000, 500, [1.5, -0.6, 0.0]));
/// # Ok::<(), boucwen_core::Error>(())
/// ```
pub fn controller_params<const P: usize>(
    model: &ExtendedParams<f64, P>,
    harmonics: &[HarmonicSpec<f64>],
    rls: RlsConfig<f64>,
    saturation: Saturation<f64>,
    uc_max: f64,
    reference: ReferenceSpec,
    ts_s: f64,
) -> Result<ControllerParams, Error> {
    if P > MAX_AR {
        return Err(Error::OutOfRange("AR order (the board takes at most 3)"));
    }
    if harmonics.len() > MAX_HARMONICS {
        return Err(Error::OutOfRange("harmonic count (the board cancels at most 2)"));
    }
    if harmonics.iter().any(|h| h.order > u8::MAX as u32) {
        return Err(Error::OutOfRange("harmonic order (at most 255 on the wire)"));
    }
    let drive = Oscillator::new(reference.freq_hz, ts_s)?;
    let period_us = ts_s * 1e6;
    if !(period_us >= 1.0 && period_us <= u32::MAX as f64) {
        return Err(Error::OutOfRange("sample interval (1 µs to 4295 s)"));
    }
    let fade = reference.fade_s / ts_s;
    if !(fade >= 0.0 && fade <= u32::MAX as f64) {
        return Err(Error::OutOfRange("fade-in (must be >= 0)"));
    }
    let f = |x: f64| x as f32;
    let mut ar = [0.0f32; MAX_AR];
    for (a, &b) in ar.iter_mut().zip(&model.ar) {
        *a = f(b);
    }
    let bw = &model.bw;
    let p = ControllerParams {
        model: ExtendedParams {
            bw: BoucWenParams {
                a1: f(bw.a1),
                a: f(bw.a),
                a0: f(bw.a0),
                gamma: f(bw.gamma),
                beta: f(bw.beta),
            },
            ar,
        },
        drive,
        sample_period_us: (period_us + 0.5) as u32,
        amplitude_um: f(reference.amplitude_um),
        fade_samples: (fade + 0.5) as u32,
        harmonics: harmonics
            .iter()
            .map(|h| HarmonicSpec {
                order: h.order,
                response: Complex::new(f(h.response.re), f(h.response.im)),
            })
            .collect(),
        rls: RlsConfig { lambda: f(rls.lambda), p0: f(rls.p0), p_max: f(rls.p_max) },
        saturation: Saturation { u_min: f(saturation.u_min), u_max: f(saturation.u_max) },
        uc_max: f(uc_max),
        preview_samples: f(reference.preview_samples),
    };
    p.validate()?;
    Ok(p)
}

/// The wire form of a repetitive controller designed on the host (`f64`, rounded to
/// `f32`).
pub fn orc_params(pi: &PiConfig<f64>, orc: &OrcConfig<f64>) -> Result<OrcParams, Error> {
    let lead_samples = u16::try_from(orc.lead_samples)
        .map_err(|_| Error::OutOfRange("ORC lead (at most 65535 samples on the wire)"))?;
    Ok(OrcParams {
        kp: pi.kp as f32,
        ki_per_s: pi.ki_per_s as f32,
        feedforward_gain: pi.feedforward_gain as f32,
        q_coeff: orc.q_coeff as f32,
        learning_gain: orc.learning_gain as f32,
        lead_samples,
        limit: orc.limit as f32,
        placement: orc.placement,
    })
}

/// Smallest share of the error power a harmonic must hold to be chosen, for a model's
/// branch ([`crate::experiments::sweep`]) and for the cancellation alike.
pub const MIN_HARMONIC_SHARE: f64 = 0.2;
/// Smallest amplitude of a harmonic the proposed law cancels, relative to `α`: a change of
/// controller must be worth its side effects (the cancellation input passes through the
/// loop and leaves a little at other frequencies).
pub const MIN_CANCEL_REL: f64 = 0.05;

/// The harmonic the proposed law cancels, from the tracking error under `u_f` alone (the
/// paper's Fig. 13 reasoning): the odd harmonic (order ≥ 3) of `freq_hz` holding the
/// largest share of `error`'s power, if that share is at least [`MIN_HARMONIC_SHARE`] and
/// its amplitude at least [`MIN_CANCEL_REL`] of `|α|`.
pub fn cancelled_harmonic(error: &[f64], freq_hz: f64, ts: f64, alpha_um: f64) -> Option<u32> {
    analysis::dominant_odd_harmonic(error, freq_hz, ts, MIN_HARMONIC_SHARE, MIN_CANCEL_REL * alpha_um.abs())
        .map(|(n, _)| n)
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
    /// small probe at `n·f` ([`probe_response_on`]), for [`PROBE_SECONDS`].
    Probe,
}

/// Length of a probe run (s).
pub const PROBE_SECONDS: f64 = 3.0;
/// Probe amplitude relative to the drive amplitude.
pub const PROBE_REL: f64 = 0.01;

/// The actuator's incremental response at `order·f` at its operating point: `plant` (fresh,
/// or reset, so that it answers `u_drive` with `y_drive`) runs `u_drive` plus a probe of
/// amplitude `eps` at `order·f`; the difference from `y_drive` at that frequency over the
/// second half, divided by the probe, is the response
/// ([`closed_loop::probe_response`]).
pub fn probe_response_on<P>(
    plant: &mut P,
    u_drive: &[f64],
    y_drive: &[f64],
    freq_hz: f64,
    order: u32,
    eps: f64,
) -> Result<Complex<f64>, DesignError>
where
    P: Plant<f64> + ?Sized,
    P::Error: StdError + Send + Sync + 'static,
{
    let ts = plant.sample_interval_s();
    let up = closed_loop::with_probe(u_drive, freq_hz, order, eps, ts)?;
    let mut yp = vec![0.0; up.len()];
    plant.run_into(&up, &mut yp).map_err(|e| DesignError::plant(&*plant, e))?;
    Ok(closed_loop::probe_response(y_drive, &yp, freq_hz, order, eps, ts)?)
}

/// Why a design failed.
#[derive(Debug)]
pub enum DesignError {
    /// The plant failed during the identification record, a probe or the trial run.
    Plant {
        /// The plant's name.
        plant: String,
        /// Its error.
        error: Box<dyn StdError + Send + Sync>,
    },
    /// The identification did not give a usable model.
    Fit(FitError),
    /// A parameter was out of range (the board's or the core's validation).
    Params(Error),
}

impl DesignError {
    fn plant<P: Plant<f64> + ?Sized>(plant: &P, e: P::Error) -> Self
    where
        P::Error: StdError + Send + Sync + 'static,
    {
        DesignError::Plant { plant: plant.name().to_owned(), error: Box::new(e) }
    }
}

impl fmt::Display for DesignError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DesignError::Plant { plant, error } => write!(f, "plant: {plant}: {error}"),
            DesignError::Fit(e) => write!(f, "identification: {e}"),
            DesignError::Params(e) => write!(f, "compensator for the board: {e}"),
        }
    }
}

impl StdError for DesignError {
    fn source(&self) -> Option<&(dyn StdError + 'static)> {
        match self {
            DesignError::Plant { error, .. } => Some(error.as_ref()),
            DesignError::Fit(e) => Some(e),
            DesignError::Params(e) => Some(e),
        }
    }
}

impl From<Error> for DesignError {
    fn from(e: Error) -> Self {
        DesignError::Params(e)
    }
}

/// What [`design_on_plant`] designed.
#[derive(Clone, Debug)]
pub struct BoardDesign {
    /// The board's parameters.
    pub params: ControllerParams,
    /// The identified model.
    pub model: HostModel,
    /// The reference amplitude α (eq. 25), µm.
    pub alpha_um: f64,
    /// The cancelled harmonic's order, if one stood out.
    pub order: Option<u32>,
}

impl fmt::Display for BoardDesign {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let freq = self.model.drive_hz;
        write!(
            f,
            "compensator for {freq} Hz: extended model fitted (input delay {:.3} samples, previewed), alpha {:.2} µm, ",
            self.model.delay, self.alpha_um
        )?;
        match self.order {
            Some(o) => write!(f, "cancelling the harmonic of order {o} at {:.0} Hz", o as f64 * freq),
            None => f.write_str("no harmonic stands out: u_f alone"),
        }
    }
}

/// Settings of [`design_on_plant`].
#[derive(Clone, Copy, Debug)]
pub struct PlantDesign {
    /// Drive frequency f, Hz.
    pub freq_hz: f64,
    /// Drive amplitude of the identification record, V.
    pub amplitude_v: f64,
    /// Length of the identification record (and of the trial run), s.
    pub seconds: f64,
    /// The driver's range, V.
    pub saturation: Saturation<f64>,
}

/// Designs the board's compensator against `plant`, as `boucwen hil` does:
/// 1. a record of the drive `amplitude·sin(2π f t)` is fitted by the extended model with
///    its input delay `τ` (output error on its first half, an invertible loop); the board's
///    compensator previews the reference by `τ` ([`ReferenceSpec::preview_samples`]);
/// 2. the reference amplitude α is eq. (25) on that record;
/// 3. `u_f` alone runs on the plant (after a reset) with the board's own controller code;
///    the odd harmonic that stands out in its tracking error is the one cancelled, with the
///    identified model's response at `n·f` (none if no harmonic stands out).
///
/// The plant is reset before each run.
pub fn design_on_plant<P>(plant: &mut P, d: &PlantDesign) -> Result<BoardDesign, DesignError>
where
    P: Plant<f64> + ?Sized,
    P::Error: StdError + Send + Sync + 'static,
{
    let (f, ts) = (d.freq_hz, plant.sample_interval_s());
    let n = (d.seconds / ts).round() as usize;
    let u = closed_loop::sine(d.amplitude_v, f, ts, n)?;
    plant.reset().map_err(|e| DesignError::plant(&*plant, e))?;
    let mut y = vec![0.0; n];
    plant.run_into(&u, &mut y).map_err(|e| DesignError::plant(&*plant, e))?;
    // The first 4 s of the fitted half, sample by sample (the design record starts from rest).
    let opt = OeOptions {
        samples: Samples::First(4000),
        averaging: Averaging::Off,
        require_invertible: true,
        delay: DelaySearch::Fit,
        ..OeOptions::default()
    };
    let model =
        fit::fit_oe(&u, &y, ts, n / 2, &ModelSpec::extended(f), &[], &opt).map_err(DesignError::Fit)?.model;
    let alpha_um = closed_loop::eq25_amplitude(&u, &y);
    let settings = closed_loop::CompensationSettings::default();
    let params = |h: &[HarmonicSpec<f64>]| {
        controller_params(
            &model.ext,
            h,
            RlsConfig::with_forgetting(settings.lambda, settings.p0),
            d.saturation,
            settings.uc_max,
            ReferenceSpec {
                freq_hz: f,
                amplitude_um: alpha_um,
                fade_s: closed_loop::FADE_IN_S,
                preview_samples: model.delay,
            },
            ts,
        )
    };
    // u_f alone: which odd harmonic stands out in its tracking error?
    let uf = params(&[])?;
    let mut c = Controller::new(&uf)?;
    plant.reset().map_err(|e| DesignError::plant(&*plant, e))?;
    let (mut y_prev, mut err) = (None, Vec::with_capacity(n));
    for _ in 0..n {
        let s = c.step(y_prev)?;
        let yk = plant.step(s.out.u as f64).map_err(|e| DesignError::plant(&*plant, e))?;
        y_prev = Some(yk as f32);
        err.push(yk - s.d as f64);
    }
    let tail = &err[n / 2..];
    let m = analysis::whole_periods(tail.len(), f, ts);
    let order = cancelled_harmonic(&tail[..m], f, ts, alpha_um);
    let harmonics: Vec<HarmonicSpec<f64>> = order
        .into_iter()
        .flat_map(|o| closed_loop::model_harmonics(&model, &[o], f, ts, PhaseRule::Model))
        .collect();
    Ok(BoardDesign { params: params(&harmonics)?, model, alpha_um, order })
}
