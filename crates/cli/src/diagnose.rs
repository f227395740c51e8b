//! `diagnose`: given a record, show what the baseline model gets wrong, name the cause,
//! extend the model and measure the gain.
//!
//! 1. **Baseline.** The extended model is fitted (output error, [`crate::fit::fit_oe`]) on the
//!    first half of the record and simulated in free run over the whole record.
//! 2. **What it gets wrong.** The residual `y - ŷ` on the held-out half is split into the
//!    part periodic with the drive (harmonics `k·f`, measured over whole periods), a slow
//!    trend (a cubic in time fitted to what the harmonics leave), and the rest (noise).
//! 3. **Causes.** Each harmonic `k ≥ 2` and the trend is a candidate, ranked by its share of
//!    the residual power. A candidate needs a share of at least [`Thresholds::min_share`]
//!    and an amplitude of at least [`Thresholds::min_amplitude_rel`] of the output's
//!    fundamental (structure smaller than that is not worth a term); its cause is named
//!    with evidence: an odd harmonic near the identified resonance is an odd harmonic
//!    oscillation amplified by it; an even harmonic is an asymmetry; a trend not locked to
//!    the drive is drift.
//! 4. **Extension.** The term the cause calls for (a harmonic branch of order `n`, odd or
//!    even, or a drift term) is added and the model refitted. The term is kept if it
//!    lowers the held-out RMS by at least [`Thresholds::min_gain`]; otherwise the finding is
//!    dropped (it had no structure worth a term) and the baseline kept.

use crate::analysis::{self, Tone};
use crate::fit::{self, FitError, HostModel, ModelSpec, OeOptions};
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
}

impl Kind {
    /// The JSON name.
    pub fn as_str(&self) -> &'static str {
        match self {
            Kind::OddHarmonic => "odd_harmonic",
            Kind::EvenHarmonic => "even_harmonic",
            Kind::Drift => "drift",
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
    /// Share of the baseline's held-out residual power.
    pub residual_share: f64,
    /// Amplitude (µm): of the harmonic, or of the trend over the held-out part.
    pub amplitude_um: f64,
    /// The cause, in words, with its evidence.
    pub cause: String,
    /// Held-out RMS once the term is added (µm).
    pub rms_with_term_um: f64,
}

/// Decision thresholds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Thresholds {
    /// Smallest share of the residual power a candidate must hold.
    pub min_share: f64,
    /// Smallest amplitude, relative to the output's fundamental, of a harmonic or trend.
    pub min_amplitude_rel: f64,
    /// Smallest relative reduction of the held-out RMS for a term to be kept.
    pub min_gain: f64,
}

impl Default for Thresholds {
    fn default() -> Self {
        Self { min_share: 0.2, min_amplitude_rel: 0.005, min_gain: 0.2 }
    }
}

/// The residual decomposition of the baseline.
#[derive(Clone, Debug, PartialEq)]
pub struct Residual {
    /// Held-out residual RMS (µm).
    pub rms_um: f64,
    /// Harmonics `1..` of the residual (µm).
    pub harmonics: Vec<Tone>,
    /// RMS of the slow trend (µm).
    pub trend_rms_um: f64,
    /// Trend slope (µm/s, from the linear term).
    pub trend_slope_um_per_s: f64,
    /// RMS of what is neither periodic nor trend (µm).
    pub noise_rms_um: f64,
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
    /// The baseline's residual decomposition.
    pub residual: Residual,
    /// Resonance of the baseline's structure (Hz), if it has complex poles.
    pub resonance_hz: Option<f64>,
    /// What was found, most important first (only the terms that were kept).
    pub findings: Vec<Finding>,
    /// The extended model (the baseline if nothing was kept).
    pub model: HostModel,
    /// Its held-out free-run RMS (µm).
    pub model_rms_um: f64,
    /// Output fundamental amplitude (µm).
    pub output_amplitude_um: f64,
}

impl Diagnosis {
    /// `100·(1 - after/before)`.
    pub fn gain_pct(&self) -> f64 {
        if self.baseline_rms_um > 0.0 {
            100.0 * (1.0 - self.model_rms_um / self.baseline_rms_um)
        } else {
            0.0
        }
    }
}

/// Why a diagnosis could not be made.
#[derive(Debug)]
pub enum DiagnoseError {
    /// The input has no oscillating component to call a drive.
    NoDrive,
    /// The drive is too slow for the record (fewer than two periods in the held-out half).
    TooFewPeriods {
        /// Drive frequency found (Hz).
        drive_hz: f64,
        /// Record length (s).
        seconds: f64,
    },
    /// The fit failed.
    Fit(FitError),
}

impl std::fmt::Display for DiagnoseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DiagnoseError::NoDrive => {
                write!(f, "the input u has no oscillating component (no drive to analyse)")
            }
            DiagnoseError::TooFewPeriods { drive_hz, seconds } => write!(
                f,
                "the drive ({drive_hz:.3} Hz) completes fewer than 4 periods in the {seconds:.2} s record; record longer"
            ),
            DiagnoseError::Fit(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for DiagnoseError {}

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

/// Splits a held-out residual into harmonics of `f`, a slow trend and noise.
pub fn decompose(r: &[f64], f: f64, ts: f64) -> Residual {
    let n = analysis::whole_periods(r.len(), f, ts);
    let r = &r[..n];
    let kmax = ((0.5 / ts) / f).floor().min(40.0) as usize;
    let harmonics = analysis::harmonics(r, f, ts, kmax.max(1));
    // Remove the harmonics, then fit a cubic trend to what is left.
    let mut rest: Vec<f64> = r.to_vec();
    for h in &harmonics {
        let w = TAU * h.freq_hz * ts;
        for (k, v) in rest.iter_mut().enumerate() {
            *v -= h.amp * (w * k as f64 + h.phase).sin();
        }
    }
    let (trend, slope) = poly_fit(&rest, ts, 3);
    let trend_rms_um = analysis::rms(&trend.iter().map(|t| t - analysis::mean(&trend)).collect::<Vec<_>>());
    let noise: Vec<f64> = rest.iter().zip(&trend).map(|(a, b)| a - b).collect();
    Residual {
        rms_um: analysis::rms(r),
        harmonics,
        trend_rms_um,
        trend_slope_um_per_s: slope,
        noise_rms_um: analysis::rms(&noise),
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
    for (k, &v) in x.iter().enumerate() {
        let t = tau(k);
        let mut p = vec![1.0; m];
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

/// Diagnoses a record: `u` (V), `y` (µm), sample interval `ts` (s).
pub fn diagnose(u: &[f64], y: &[f64], ts: f64, th: &Thresholds) -> Result<Diagnosis, DiagnoseError> {
    let n = u.len().min(y.len());
    let drive_hz = analysis::estimate_drive(&u[..n], ts).ok_or(DiagnoseError::NoDrive)?;
    let split = n / 2;
    if (n - split) as f64 * ts * drive_hz < 4.0 {
        return Err(DiagnoseError::TooFewPeriods { drive_hz, seconds: n as f64 * ts });
    }
    let opt = OeOptions::default();
    let base_spec = ModelSpec::extended(drive_hz);
    let baseline = fit::fit_oe(u, y, ts, split, &base_spec, &[], &opt)?.model;
    let sim = baseline.simulate(&u[..n], ts)?;
    let resid: Vec<f64> = y[split..n].iter().zip(&sim[split..n]).map(|(a, b)| a - b).collect();
    let baseline_rms_um = analysis::rms(&resid);
    let residual = decompose(&resid, drive_hz, ts);
    let output_amplitude_um =
        analysis::harmonics(&y[split..n], drive_hz, ts, 1).first().map(|t| t.amp).unwrap_or(0.0);
    let res_hz = resonance_hz(baseline.ext.ar, ts);

    // Candidates, by share of the residual power.
    let power = residual.rms_um * residual.rms_um;
    let mut cands: Vec<(Kind, Option<u32>, f64, f64, f64)> = vec![]; // kind, order, freq, share, amplitude
    for (i, h) in residual.harmonics.iter().enumerate().skip(1) {
        let order = (i + 1) as u32;
        let kind = if order % 2 == 1 { Kind::OddHarmonic } else { Kind::EvenHarmonic };
        cands.push((kind, Some(order), h.freq_hz, h.amp * h.amp / 2.0 / power.max(1e-300), h.amp));
    }
    let trend_amp = residual.trend_rms_um * 3f64.sqrt();
    cands.push((Kind::Drift, None, 0.0, residual.trend_rms_um.powi(2) / power.max(1e-300), trend_amp));
    cands.sort_by(|a, b| b.3.total_cmp(&a.3));

    let mut findings = vec![];
    let mut model = baseline.clone();
    let mut model_rms = baseline_rms_um;
    for (kind, order, freq_hz, share, amp) in cands {
        if share < th.min_share || amp < th.min_amplitude_rel * output_amplitude_um {
            continue;
        }
        let mut spec = ModelSpec {
            drive_hz,
            harmonics: model.branches.iter().map(|b| b.order).collect(),
            drift_degree: if model.drift.is_empty() { None } else { Some(model.drift.len() - 1) },
        };
        match kind {
            Kind::Drift => spec.drift_degree = Some(1),
            _ => match order {
                Some(o) if o as f64 * drive_hz < 0.5 / ts && spec.harmonics.len() < fit::MAX_BRANCHES => {
                    spec.harmonics.push(o)
                }
                _ => continue,
            },
        }
        let Ok(cand) = fit::fit_oe(u, y, ts, split, &spec, std::slice::from_ref(&model), &opt) else {
            continue;
        };
        let rms = fit::free_run_rms(&cand.model, &u[..n], &y[..n], ts, split)?;
        if !(rms.is_finite() && rms <= model_rms * (1.0 - th.min_gain)) {
            continue;
        }
        let cause = explain(kind, order, freq_hz, share, amp, output_amplitude_um, res_hz, &residual);
        findings.push(Finding {
            kind,
            order,
            freq_hz,
            residual_share: share,
            amplitude_um: amp,
            cause,
            rms_with_term_um: rms,
        });
        model = cand.model;
        model_rms = rms;
    }
    Ok(Diagnosis {
        drive_hz,
        ts,
        split,
        baseline,
        baseline_rms_um,
        residual,
        resonance_hz: res_hz,
        findings,
        model,
        model_rms_um: model_rms,
        output_amplitude_um,
    })
}

#[allow(clippy::too_many_arguments)]
fn explain(
    kind: Kind,
    order: Option<u32>,
    freq_hz: f64,
    share: f64,
    amp: f64,
    out_amp: f64,
    resonance: Option<f64>,
    residual: &Residual,
) -> String {
    let pct = 100.0 * share;
    let rel = if out_amp > 0.0 { 100.0 * amp / out_amp } else { 0.0 };
    let near = |f: f64| resonance.filter(|r| (r - f).abs() <= 0.15 * f.max(*r));
    match kind {
        Kind::OddHarmonic => {
            let n = order.unwrap_or(0);
            let mut s = format!(
                "odd harmonic oscillation: the {} harmonic at {freq_hz:.1} Hz holds {pct:.0}% of the residual power \
                 ({amp:.3} µm, {rel:.1}% of the output's fundamental)",
                ordinal(n)
            );
            match near(freq_hz) {
                Some(r) => s.push_str(&format!(
                    "; the record shows a resonance near {r:.0} Hz, which amplifies the {} harmonic of the \
                     hysteresis and of any structural stiffening",
                    ordinal(n)
                )),
                None => s.push_str("; no resonance of the fitted structure is near it: a nonlinearity beyond the Bouc–Wen loop"),
            }
            s
        }
        Kind::EvenHarmonic => {
            let n = order.unwrap_or(0);
            let mut s = format!(
                "even harmonic: the {} harmonic at {freq_hz:.1} Hz holds {pct:.0}% of the residual power \
                 ({amp:.3} µm, {rel:.1}% of the output's fundamental); an even harmonic needs an asymmetry \
                 the model's loop lacks (an asymmetric bimorph's stiffness, an off-centre operating point)",
                ordinal(n)
            );
            if let Some(r) = near(freq_hz) {
                s.push_str(&format!(", amplified by the resonance near {r:.0} Hz"));
            }
            s
        }
        Kind::Drift => format!(
            "drift: a slow trend not locked to the drive holds {pct:.0}% of the residual power \
             ({:.3} µm RMS, slope {:.4} µm/s)",
            residual.trend_rms_um, residual.trend_slope_um_per_s
        ),
    }
}

fn ordinal(n: u32) -> String {
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
        assert!(d.noise_rms_um < 0.01);
    }
}
